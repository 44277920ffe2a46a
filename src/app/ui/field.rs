//! The Kernel field view: measured kernels or Gaussian ellipses at their sensor
//! positions, coloured by σ; the field a profile predicts at any setting; the demo
//! lens's truth; two lens units side by side.
//!
//! Draws the panels `view_data` made (the fields, the kernel atlas) and the controls
//! that choose them; computes nothing.

use super::super::view_data::{FieldPanel, FieldPoint, PanelContent, PanelOf};
use super::super::{Command, FieldShow, FieldSource, StudioApp};
use super::{ellipse_points, setting_sliders_ui, sigma_color, sigma_legend_ui};
use crate::model::KernelModel;
use crate::plane::LensSetting;
use crate::simulate::VirtualLens;
use egui::{Color32, Rect, Sense, Stroke, Vec2};

pub(super) fn kernel_field_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    ui.heading("Kernel field");
    let is_demo = app.session.as_ref().is_some_and(|s| s.is_demo);
    let lens = VirtualLens::demo();
    ui.horizontal(|ui| {
        for (src, label, tip) in [
            (
                FieldSource::Measured,
                "Measured",
                "The kernels measured on the selected shot and their robust Gaussian fits",
            ),
            (
                FieldSource::Predicted,
                "Predicted",
                "The profile's prediction at the focal length and aperture of the sliders",
            ),
            (
                FieldSource::Truth,
                "Ground truth",
                "The demo lens's exact blur (demo session only)",
            ),
        ] {
            if ui
                .selectable_label(app.field_source == src, label)
                .on_hover_text(tip)
                .clicked()
            {
                app.commands.push(Command::SetFieldSource(src));
            }
        }
        ui.separator();
        if app.field_source != FieldSource::Truth {
            let predicted = app.field_source == FieldSource::Predicted;
            for (show, label, tip) in [
                (
                    FieldShow::Ellipses,
                    "Ellipses",
                    if predicted {
                        "The 1-σ ellipse of each predicted Gaussian"
                    } else {
                        "The 1-σ ellipse of each kernel's Gaussian fit"
                    },
                ),
                (
                    FieldShow::Kernels,
                    "Kernel shapes",
                    if predicted {
                        "The profile's predicted kernels (its shape model where it holds one) at the selected shot's measured squares, on tiles coloured by their σ; hover a square for its error against the measured kernel"
                    } else {
                        "The measured non-parametric kernels themselves, on tiles coloured by their σ; hover a square for the profile's predicted kernel error there"
                    },
                ),
            ] {
                if ui
                    .selectable_label(app.field_show == show, label)
                    .on_hover_text(tip)
                    .clicked()
                {
                    app.commands.push(Command::SetFieldShow(show));
                }
            }
            ui.separator();
        }
        sigma_legend_ui(ui);
    });
    let s = LensSetting {
        focal_mm: app.field_focal_mm,
        f_number: app.field_f_number,
    };
    let size = super::sensor_size(app);
    let ch = app.channel;
    match app.field_source {
        FieldSource::Measured => {}
        FieldSource::Predicted => {
            setting_sliders_ui(app, ui, &lens);
            ui.horizontal(|ui| {
                if ui
                    .button("Compare with a second profile…")
                    .on_hover_text("Two copies of one lens model blur differently (the paper's two 17–40 mm units): load the other unit's profile")
                    .clicked()
                {
                    app.commands.push(Command::LoadCompareProfileDialog);
                }
            });
        }
        FieldSource::Truth => {
            if !is_demo {
                ui.label("Ground truth exists only for the demo session's simulated lens.");
                return;
            }
            setting_sliders_ui(app, ui, &lens);
            let mut compare = app.compare_units;
            if ui
                .checkbox(&mut compare, "Compare with a second unit")
                .on_hover_text("Two copies of one lens model blur differently (the paper's two 17–40 mm units).")
                .changed()
            {
                app.commands.push(Command::SetCompareUnits(compare));
            }
            ui.label("Ground truth of the demo's virtual lens: pixel-level Gaussians (optical blur plus the 1-px pixel integration).");
        }
    }
    let Some(field) = &app.views.field else {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label("preparing the field…");
        });
        return;
    };
    let title = |p: &FieldPanel| match p.of {
        PanelOf::Measured => {
            let name = app
                .selected_shot
                .and_then(|id| app.session.as_ref()?.shot(id))
                .map_or_else(String::new, |s| {
                    let setting = s.setting().map_or_else(String::new, |v| {
                        format!(" ({:.0} mm f/{:.1})", v.focal_mm, v.f_number)
                    });
                    format!("{}{setting}", s.stem())
                });
            format!("measured on {name} — channel {ch}")
        }
        PanelOf::Profile => match &app.profile {
            Some((path, _)) => {
                let atlas = app.views.kernel_atlas.as_ref();
                let shapes = match atlas.and_then(|a| a.model) {
                    Some(KernelModel::Shape) if app.field_show == FieldShow::Kernels => {
                        " — predicted kernel shapes (Gaussian + shape model)".to_owned()
                    }
                    Some(KernelModel::Gaussian) if app.field_show == FieldShow::Kernels => {
                        format!(
                            " — predicted Gaussian kernels; no shape model: {}",
                            atlas.and_then(|a| a.no_shape.as_deref()).unwrap_or("")
                        )
                    }
                    _ => String::new(),
                };
                format!(
                    "{} — {:.0} mm f/{:.1}, channel {ch}{shapes}",
                    app.shown_path(path),
                    s.focal_mm,
                    s.f_number
                )
            }
            None => "predicted".into(),
        },
        PanelOf::NoProfile => "predicted".into(),
        PanelOf::CompareProfile => match &app.compare_profile {
            Some((path, _)) => format!("{} — channel {ch}", app.shown_path(path)),
            None => String::new(),
        },
        PanelOf::Truth { second_unit } => {
            let unit = if second_unit {
                VirtualLens::demo_second_unit()
            } else {
                VirtualLens::demo()
            };
            format!("{} {} — channel {ch}", unit.model, unit.serial)
        }
    };
    let panels = &field.panels;
    let avail = ui.available_size();
    let cols = panels.len().max(1) as f32;
    let w = ((avail.x - 16.0 * cols) / cols)
        .min((avail.y - 48.0) * size.0 as f32 / size.1 as f32)
        .max(100.0);
    let panel_size = Vec2::new(w, w * size.1 as f32 / size.0 as f32);
    // One magnification for every panel so compared fields are comparable: the largest
    // 1-σ radius fills 45 % of a twelfth of the sensor width.
    let scale = 0.45 * (panel_size.x / 12.0) / field.max_sigma as f32;
    let atlas = app.views.kernel_atlas.as_ref().map(|a| a.texture.id());
    ui.horizontal(|ui| {
        for p in panels {
            ui.vertical(|ui| {
                ui.label(title(p));
                match &p.content {
                    Ok(content) => field_panel_ui(
                        ui,
                        content,
                        (&p.points, &p.failed),
                        size,
                        scale,
                        panel_size,
                        atlas,
                    ),
                    Err(reason) => {
                        ui.label(reason);
                    }
                }
            });
        }
    });
}

/// One panel: ellipses (1 σ, coloured by σ = √(C_xx·C_yy)) or kernels (tinted by the
/// same colour) at their sensor positions, magnified by `scale` screen points per px
/// of σ, and red crosses where a kernel failed. Hovering a Gaussian shows its σ and
/// MTF50, hovering a cross the reason.
fn field_panel_ui(
    ui: &mut egui::Ui,
    content: &PanelContent,
    (points, failed): (&[FieldPoint], &[(f64, f64, String)]),
    (w, h): (usize, usize),
    scale: f32,
    size: Vec2,
    atlas: Option<egui::TextureId>,
) {
    let (rect, response) = ui.allocate_exact_size(size, Sense::hover());
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 2.0, Color32::from_gray(18));
    painter.rect_stroke(
        rect,
        2.0,
        Stroke::new(1.0, ui.visuals().weak_text_color()),
        egui::StrokeKind::Inside,
    );
    let points_per_px = rect.width() / w as f32;
    let at =
        |x: f64, y: f64| rect.min + Vec2::new(x as f32 * points_per_px, y as f32 * points_per_px);
    let count;
    let what;
    match content {
        PanelContent::Ellipses(samples) => {
            // A light rim keeps the dark end of the palette visible on the dark panel.
            let rim = Stroke::new(1.0, Color32::from_white_alpha(110));
            for (x, y, g) in samples {
                painter.add(egui::Shape::convex_polygon(
                    ellipse_points(at(*x, *y), g, scale),
                    sigma_color((g.sigma_x * g.sigma_y).sqrt()),
                    rim,
                ));
            }
            count = samples.len();
            what = format!("ellipses: 1 σ, magnified {:.1}×", scale / points_per_px);
        }
        PanelContent::Kernels {
            cells,
            extent_px,
            pitch_px,
        } => {
            // Each kernel fills 85 % of the pitch between squares, so neighbours never
            // overlap: drawn white on a tile of its σ's colour, the shape reads on any
            // colour of the palette.
            let side = 0.85 * *pitch_px as f32 * points_per_px;
            for c in cells {
                let g = c.gaussian;
                let r = Rect::from_center_size(at(c.x, c.y), Vec2::splat(side));
                painter.rect_filled(r, 2.0, sigma_color((g.sigma_x * g.sigma_y).sqrt()));
                if let Some(id) = atlas {
                    painter.image(id, r, c.uv, Color32::WHITE);
                }
            }
            count = cells.len();
            what = format!(
                "kernels, each ±{extent_px:.1} px around its centre scaled to its peak, magnified {:.1}×",
                side / (2.0 * *extent_px as f32 * points_per_px)
            );
        }
    }
    let red = Stroke::new(1.5, Color32::from_rgb(230, 60, 60));
    for (x, y, _) in failed {
        let c = at(*x, *y);
        let d = 4.0;
        painter.line_segment([c + Vec2::new(-d, -d), c + Vec2::new(d, d)], red);
        painter.line_segment([c + Vec2::new(-d, d), c + Vec2::new(d, -d)], red);
    }
    if let Some(p) = response.hover_pos() {
        let distance = |x: f64, y: f64| (at(x, y) - p).length();
        let near_failed = failed
            .iter()
            .min_by(|a, b| distance(a.0, a.1).total_cmp(&distance(b.0, b.1)))
            .filter(|f| distance(f.0, f.1) < 8.0);
        let near_point = points
            .iter()
            .min_by(|a, b| distance(a.x, a.y).total_cmp(&distance(b.x, b.y)))
            .filter(|q| distance(q.x, q.y) < 16.0);
        if let Some((x, y, reason)) = near_failed {
            response.on_hover_text(format!("x {x:.0}, y {y:.0}: {reason}"));
        } else if let Some(q) = near_point {
            let mtf = q.mtf50.map_or_else(
                || "no MTF50 (degenerate Gaussian)".to_owned(),
                |m| {
                    format!(
                        "MTF50 {:.3} cycles/px ({:.0} lp/ph) in the worst direction ({:.0}°), {:.3} in the best, {:.3} isotropic",
                        m.worst, m.worst_lp_ph, m.worst_deg, m.best, m.isotropic
                    )
                },
            );
            let error = q.kernel_error.map_or_else(String::new, |e| match e.shape {
                Some(shape) => format!(
                    "\npredicted kernel error: shapes {shape:.2}, Gaussian {:.2} (relative L2)",
                    e.gaussian
                ),
                None => format!(
                    "\npredicted kernel error: Gaussian {:.2} (relative L2; the profile holds no shape model)",
                    e.gaussian
                ),
            });
            response.on_hover_text(format!(
                "x {:.0}, y {:.0}: σ {:.2} px; {mtf}{error}",
                q.x, q.y, q.sigma
            ));
        }
    }
    let failed_note = if failed.is_empty() {
        String::new()
    } else {
        format!("; {} failed (red ×, hover for the reason)", failed.len())
    };
    ui.label(
        egui::RichText::new(format!("{count} {what} (sensor {w} × {h} px){failed_note}")).small(),
    );
}
