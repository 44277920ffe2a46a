//! The Geometry view: the lens's distortion, lateral colour and fall-off as lensfun
//! models them, per focal length, measured from the session's chart shots: the
//! distortion as a regular grid warped (exaggerated, its factor shown), the lateral
//! colour as red and blue arrows against green, the fall-off as a map in stops with its
//! colour bar per aperture, the fits' numbers, and the export of the lensfun entry.
//!
//! Draws what `view_data` made of the project's geometry; computes nothing.

use super::super::Command;
use super::field::colour_bar_ui;
use super::image_backdrop;
use crate::app::view_data::GeometryData;
use crate::app::{DialogCommand, ViewCommand};
use crate::project::GeometryStatus;
use egui::{Color32, Pos2, Rect, Sense, Stroke, Vec2};

const TIP_GRID: &str = "A regular grid of ideal (pinhole) points, pushed through the fitted distortion: grey where a perfect lens would draw it, white where this lens does, the displacement exaggerated by the factor shown. Bowed out at the edges (corners pulled in): barrel; corners pushed out: pincushion.";
const TIP_ARROWS: &str = "Where red (and blue) lie against green at points over the frame, from the lateral-colour fit, exaggerated by the factor shown. Outward red and inward blue: red imaged larger than green.";
const TIP_MAP: &str = "The light the lens loses toward the corners at this aperture (lensfun's pa model fitted to the chart's white squares, assuming the chart was evenly lit), in stops: 1 stop is half the light.";

/// The view, from the project's geometry (`status`: absent until the session has
/// detections) and what its view data draws of it at the chosen setting (`data`).
pub(super) fn geometry_ui(
    status: GeometryStatus<'_>,
    data: Option<&GeometryData>,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) {
    ui.heading("Lens geometry");
    let measuring = matches!(status, GeometryStatus::Waiting);
    let why = match status {
        GeometryStatus::NoShots => Some(
            "The Geometry view measures distortion, lateral colour and fall-off from the chart's corners and white squares: it needs the chart detected (Detect, Ctrl+D) in shots whose focal length and aperture are known — ideally at several focal lengths, under even light.".to_owned(),
        ),
        GeometryStatus::Waiting => Some("measuring the lens's geometry…".to_owned()),
        GeometryStatus::Measured(Err(e)) => Some(e.clone()),
        GeometryStatus::Measured(Ok(_)) => None,
    };
    let Some(data) = data.filter(|_| why.is_none()) else {
        ui.add_space(24.0);
        ui.vertical_centered(|ui| ui.weak(why.unwrap_or_else(|| "preparing the view…".to_owned())));
        return;
    };
    ui.horizontal_wrapped(|ui| {
        ui.label("Focal length");
        for &f in &data.focal_mm {
            if ui
                .selectable_label(f == data.focal, format!("{f} mm"))
                .clicked()
            {
                out.push(Command::View(ViewCommand::SetGeometryFocal(f)));
            }
        }
        ui.separator();
        ui.label("Aperture");
        let shown = data.falloff.as_ref().map(|f| f.f_number);
        for &a in &data.f_numbers {
            if ui
                .selectable_label(Some(a) == shown, format!("f/{a}"))
                .on_hover_text("The fall-off map at this aperture")
                .clicked()
            {
                out.push(Command::View(ViewCommand::SetGeometryAperture(a)));
            }
        }
        ui.separator();
        if ui
            .add_enabled(!measuring, egui::Button::new("Export lensfun XML…"))
            .on_hover_text("Write the lens's entry for lensfun (distortion, lateral colour and fall-off at every focal length and aperture): copy it to ~/.local/share/lensfun/ and darktable, RawTherapee, digiKam and Hugin correct the lens")
            .clicked()
        {
            out.push(Command::Dialog(DialogCommand::ExportLensfunDialog));
        }
    });
    if let Some(w) = &data.warning {
        ui.colored_label(ui.visuals().warn_fg_color, w);
    }
    let text_room = 24.0 + 18.0 * data.fit_lines.len() as f32;
    let avail = ui.available_size() - Vec2::new(0.0, text_room + 80.0);
    let aspect = data.sensor.0 as f32 / data.sensor.1.max(1) as f32;
    // Three panels side by side, each the frame's shape.
    let gap = 12.0;
    let pw = ((avail.x - 2.0 * gap) / 3.0).min(avail.y.max(60.0) * aspect);
    let panel = Vec2::new(pw.max(60.0), pw.max(60.0) / aspect);
    ui.horizontal_top(|ui| {
        ui.spacing_mut().item_spacing.x = gap;
        panel_ui(
            ui,
            panel,
            "Distortion",
            &grid_caption(data),
            TIP_GRID,
            |p, r| {
                draw_grid(p, r, data);
            },
        );
        panel_ui(
            ui,
            panel,
            "Lateral colour",
            &arrows_caption(data),
            TIP_ARROWS,
            |p, r| draw_arrows(p, r, data),
        );
        let map_caption = data.falloff.as_ref().map_or_else(
            || "no fall-off measured at this focal length".to_owned(),
            |f| {
                format!(
                    "f/{}: {:.2} stops at the corners",
                    f.f_number, f.fit.corner_stops
                )
            },
        );
        panel_ui(ui, panel, "Fall-off", &map_caption, TIP_MAP, |p, r| {
            if let Some(f) = &data.falloff {
                p.image(
                    f.texture.id(),
                    r,
                    Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                    Color32::WHITE,
                );
            }
        });
    });
    if let Some(f) = &data.falloff {
        ui.add_space(4.0);
        colour_bar_ui(ui, &f.scale, 0, TIP_MAP);
    }
    ui.add_space(6.0);
    for line in &data.fit_lines {
        ui.label(line);
    }
}

fn grid_caption(d: &GeometryData) -> String {
    let kind = if d.grid.corner_px < 0.0 {
        "barrel"
    } else {
        "pincushion"
    };
    format!(
        "×{} · {:+.1} px at the corners ({kind})",
        d.grid.factor, d.grid.corner_px
    )
}

fn arrows_caption(d: &GeometryData) -> String {
    d.colour.as_ref().map_or_else(
        || "not measured: a single-channel capture".to_owned(),
        |c| {
            format!(
                "×{} · corners: red {:+.2} px, blue {:+.2} px",
                c.factor, c.red_corner_px, c.blue_corner_px
            )
        },
    )
}

/// A titled panel the frame's shape, its caption under it.
fn panel_ui(
    ui: &mut egui::Ui,
    size: Vec2,
    title: &str,
    caption: &str,
    tip: &str,
    draw: impl FnOnce(&egui::Painter, Rect),
) {
    ui.vertical(|ui| {
        ui.set_width(size.x);
        ui.strong(title).on_hover_text(tip);
        let (rect, response) = ui.allocate_exact_size(size, Sense::hover());
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 0.0, image_backdrop(ui));
        draw(&painter, rect);
        painter.rect_stroke(
            rect,
            0.0,
            Stroke::new(1.0, ui.visuals().weak_text_color()),
            egui::StrokeKind::Inside,
        );
        response.on_hover_text(tip);
        ui.label(caption);
    });
}

/// Sensor px to the panel.
fn to_screen(rect: Rect, sensor: (usize, usize)) -> impl Fn([f32; 2]) -> Pos2 {
    let (w, h) = (sensor.0 as f32, sensor.1 as f32);
    move |p| {
        Pos2::new(
            rect.left() + p[0] / w * rect.width(),
            rect.top() + p[1] / h * rect.height(),
        )
    }
}

fn draw_grid(painter: &egui::Painter, rect: Rect, d: &GeometryData) {
    let at = to_screen(rect, d.sensor);
    let ideal = Stroke::new(1.0, Color32::from_gray(90));
    let warped = Stroke::new(1.5, Color32::from_gray(235));
    for line in &d.grid.ideal {
        painter.line(line.iter().map(|&p| at(p)).collect(), ideal);
    }
    for line in &d.grid.warped {
        painter.line(line.iter().map(|&p| at(p)).collect(), warped);
    }
}

fn draw_arrows(painter: &egui::Painter, rect: Rect, d: &GeometryData) {
    let Some(c) = &d.colour else {
        return;
    };
    let at = to_screen(rect, d.sensor);
    let red = Color32::from_rgb(255, 90, 80);
    let blue = Color32::from_rgb(90, 150, 255);
    for [g, r, b] in &c.arrows {
        let origin = at(*g);
        painter.circle_filled(origin, 2.0, Color32::from_rgb(80, 220, 100));
        for (tip, colour) in [(at(*r), red), (at(*b), blue)] {
            painter.arrow(origin, tip - origin, Stroke::new(1.5, colour));
        }
    }
}
