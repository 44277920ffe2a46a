//! The Kernel field view: measured kernels or Gaussian ellipses at their sensor
//! positions, coloured by σ; the field a profile predicts at any setting; the demo
//! lens's truth; two lens units side by side.
//!
//! Colours come from the data's range (or one the user fixes) on a labelled colour bar;
//! difference maps (measured − predicted, unit A − unit B, R − B) use a diverging
//! palette, white at 0. Hover names a square's Gaussian and MTF50, a click opens its
//! inspector, and kernels the core finds too noisy to trust are hatched.
//!
//! Draws the panels `view_data` made (the fields, the kernel atlas, the colour scale)
//! and the controls that choose them; computes nothing.

use super::super::view_data::{
    ColourScale, FieldData, FieldPanel, FieldPoint, KernelAtlas, PanelContent, PanelOf,
};
use super::super::{
    ColourRange, Command, Difference, FieldOptions, FieldShow, FieldSource, FieldViewState, View,
    ViewerContext,
};
use super::{Frame, Sliders, TIP_CXX, TIP_CYY, ellipse_points, setting_sliders_ui};
use crate::app::{DialogCommand, ViewCommand};
use crate::model::KernelModel;
use crate::plane::{Channel, LensSetting};
use crate::session::ShotId;
use crate::simulate::VirtualLens;
use egui::{Color32, Rect, Sense, Stroke, Vec2};

/// What the Kernel field view draws from: its own state, the panels and the kernel
/// atlas made for it, and the shot and profiles they come from.
pub(super) struct FieldContext<'a> {
    cx: ViewerContext<'a>,
    state: &'a FieldViewState,
    field: Option<&'a FieldData>,
    atlas: Option<&'a KernelAtlas>,
    /// How many shots the measured field holds (the selected and the others at its
    /// setting).
    field_shots: usize,
    sliders: Sliders<'a>,
    selected: Option<ShotId>,
    channel: Channel,
    sensor: (usize, usize),
}

impl<'a> FieldContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            cx: f.cx,
            state: &f.views.field,
            field: f.data.field.as_ref(),
            atlas: f.data.kernel_atlas.as_ref(),
            field_shots: f.data.field_kernels.as_ref().map_or(0, |k| k.shots),
            sliders: Sliders::of(f),
            selected: f.views.shot.selected,
            channel: f.views.shot.channel,
            sensor: f.sensor,
        }
    }
}

pub(super) fn kernel_field_ui(c: &FieldContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.heading("Kernel field");
    source_and_show_ui(c.state, out, ui);
    options_ui(c.state.options, out, ui);
    let s = LensSetting {
        focal_mm: c.state.focal_mm,
        f_number: c.state.f_number,
    };
    let size = c.sensor;
    if !source_controls_ui(c, out, ui) {
        return;
    }
    let Some(field) = c.field else {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label("preparing the field…");
        });
        return;
    };
    let title = |p: &FieldPanel| panel_title(c, p, s);
    let panels = &field.panels;
    if let Some(colours) = &field.scale {
        colour_bar_ui(ui, colours, field.noisy, &format!("{TIP_CXX}\n{TIP_CYY}"));
    }
    let avail = ui.available_size();
    let cols = panels.len().max(1) as f32;
    let w = ((avail.x - 16.0 * cols) / cols)
        .min((avail.y - 48.0) * size.0 as f32 / size.1 as f32)
        .max(100.0);
    let panel_size = Vec2::new(w, w * size.1 as f32 / size.0 as f32);
    // One magnification for every panel so compared fields are comparable: the largest
    // 1-σ radius fills 45 % of a twelfth of the sensor width.
    let scale = 0.45 * (panel_size.x / 12.0) / field.max_sigma as f32;
    let atlas = c.atlas.map(|a| a.texture.id());
    let mut clicked = None;
    ui.horizontal(|ui| {
        for p in panels {
            ui.vertical(|ui| {
                ui.label(title(p));
                match (&p.content, &field.scale) {
                    (Ok(content), Some(colours)) => {
                        clicked = clicked.or(field_panel_ui(
                            ui,
                            content,
                            (&p.points, &p.failed),
                            size,
                            (scale, colours),
                            panel_size,
                            atlas,
                        ));
                    }
                    (Ok(_), None) => {
                        ui.label("Nothing to show here.");
                    }
                    (Err(reason), _) => {
                        ui.label(reason);
                    }
                }
            });
        }
    });
    // The square's inspector lives in the Shot view, beside the shot it was measured on.
    if let Some((shot, square)) = clicked {
        out.push(Command::View(ViewCommand::SelectView(View::Shot)));
        // A square of another shot at the setting: that shot, then its square.
        if let Some(shot) = shot.filter(|&s| Some(s) != c.selected) {
            out.push(Command::View(ViewCommand::SelectShot(shot)));
        }
        out.push(Command::View(ViewCommand::SelectSquare(square)));
    }
}

/// Which field (measured, predicted, truth) and how (ellipses, kernel shapes).
fn source_and_show_ui(state: &FieldViewState, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        for (src, label, tip) in [
            (
                FieldSource::Measured,
                "Measured",
                "The kernels measured on the selected shot, and on the other shots at its setting (a small chart shot at several positions), with their robust Gaussian fits",
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
                .selectable_label(state.source == src, label)
                .on_hover_text(tip)
                .clicked()
            {
                out.push(Command::View(ViewCommand::SetFieldSource(src)));
            }
        }
        ui.separator();
        if state.source != FieldSource::Truth {
            let predicted = state.source == FieldSource::Predicted;
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
                    .selectable_label(state.show == show, label)
                    .on_hover_text(tip)
                    .clicked()
                {
                    out.push(Command::View(ViewCommand::SetFieldShow(show)));
                }
            }
        }
    });
}

/// The controls of the chosen field: the setting's sliders, a second profile or unit to
/// compare. False where there is nothing to show (truth outside the demo).
fn source_controls_ui(c: &FieldContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) -> bool {
    match c.state.source {
        FieldSource::Measured => {}
        FieldSource::Predicted => {
            setting_sliders_ui(&c.sliders, out, ui);
            ui.horizontal(|ui| {
                if ui
                    .button("Compare with a second profile…")
                    .on_hover_text("Two copies of one lens model blur differently (the paper's two 17–40 mm units): load the other unit's profile")
                    .clicked()
                {
                    out.push(Command::Dialog(DialogCommand::LoadCompareProfileDialog));
                }
            });
        }
        FieldSource::Truth => {
            if !c.cx.is_demo() {
                ui.label("Ground truth exists only for the demo session's simulated lens.");
                return false;
            }
            setting_sliders_ui(&c.sliders, out, ui);
            let mut compare = c.state.compare_units;
            if ui
                .checkbox(&mut compare, "Compare with a second unit")
                .on_hover_text("Two copies of one lens model blur differently (the paper's two 17–40 mm units).")
                .changed()
            {
                out.push(Command::View(ViewCommand::SetCompareUnits(compare)));
            }
            ui.label("Ground truth of the demo's virtual lens: pixel-level Gaussians (optical blur plus the 1-px pixel integration).");
        }
    }
    true
}

/// A panel's title: whose field it is, at which setting and channel.
fn panel_title(c: &FieldContext<'_>, p: &FieldPanel, s: LensSetting) -> String {
    let ch = c.channel;
    match &p.of {
        PanelOf::Measured => {
            let name = c
                .selected
                .and_then(|id| c.cx.session()?.shot(id))
                .map_or_else(String::new, |s| {
                    let setting = s.setting().map_or_else(String::new, |v| {
                        format!(" ({:.0} mm f/{:.1})", v.focal_mm, v.f_number)
                    });
                    format!("{}{setting}", s.stem())
                });
            // The other shots at the setting whose kernels the field shows too.
            let others = match c.field_shots.saturating_sub(1) {
                0 => String::new(),
                1 => " and 1 other shot at its setting".to_owned(),
                n => format!(" and {n} other shots at its setting"),
            };
            format!("measured on {name}{others} — channel {ch}")
        }
        PanelOf::Profile => match c.cx.profile() {
            Some((path, _)) => {
                let atlas = c.atlas;
                let shapes = match atlas.and_then(|a| a.model) {
                    Some(KernelModel::Shape) if c.state.show == FieldShow::Kernels => {
                        " — predicted kernel shapes (Gaussian + shape model)".to_owned()
                    }
                    Some(KernelModel::Gaussian) if c.state.show == FieldShow::Kernels => {
                        format!(
                            " — predicted Gaussian kernels; no shape model: {}",
                            atlas.and_then(|a| a.no_shape.as_deref()).unwrap_or("")
                        )
                    }
                    _ => String::new(),
                };
                format!(
                    "{} — {:.0} mm f/{:.1}, channel {ch}{shapes}",
                    c.cx.shown_path(path),
                    s.focal_mm,
                    s.f_number
                )
            }
            None => "predicted".into(),
        },
        PanelOf::NoProfile => "predicted".into(),
        PanelOf::CompareProfile => match c.cx.compare_profile() {
            Some((path, _)) => format!("{} — channel {ch}", c.cx.shown_path(path)),
            None => String::new(),
        },
        PanelOf::Difference { of, a, b } => {
            let what = super::super::view_data::difference_words(*of);
            if a.is_empty() {
                format!("{what}, σ")
            } else {
                format!("{what}, σ: {a} − {b}; channel {ch}")
            }
        }
        PanelOf::Truth { second_unit } => {
            let unit = if *second_unit {
                VirtualLens::demo_second_unit()
            } else {
                VirtualLens::demo()
            };
            format!("{} {} — channel {ch}", unit.model, unit.serial)
        }
    }
}

/// The map and colour-range choices: the fields or a difference map, the colours from
/// the data or a range the user fixes.
fn options_ui(options: FieldOptions, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let mut set = |o: FieldOptions| out.push(Command::View(ViewCommand::SetFieldOptions(o)));
    ui.horizontal_wrapped(|ui| {
        ui.label("Map:");
        for (d, label, tip) in [
            (None, "σ", "Each square coloured by its σ = √(C_xx·C_yy)"),
            (
                Some(Difference::MeasuredMinusPredicted),
                "measured − predicted",
                "The measured σ (the selected shot's, and the other shots' at its setting) minus the profile's prediction at the same square and that setting: where the model misses",
            ),
            (
                Some(Difference::UnitAMinusB),
                "unit A − unit B",
                "The profile minus the second profile loaded (or, on the demo session, the demo lens minus its second unit) at the sliders' setting: how two copies of one lens differ",
            ),
            (
                Some(Difference::RedMinusBlue),
                "R − B",
                "Channel R minus channel B of the source shown: the blur's colour fringing",
            ),
        ] {
            if ui
                .selectable_label(options.difference == d, label)
                .on_hover_text(tip)
                .clicked()
            {
                set(FieldOptions {
                    difference: d,
                    ..options
                });
            }
        }
        ui.separator();
        if let Some(d) = options.difference {
            let words = super::super::view_data::difference_words(d);
            let first = words.split(" − ").next().unwrap_or(words);
            ui.weak(format!("{words}: blue where the {first} blur is smaller (sharper), red where it is larger, white at 0; the range is symmetric about 0 and spans the largest difference."));
            return;
        }
        ui.label("Colours:");
        let fixed = matches!(options.range, ColourRange::Fixed { .. });
        if ui
            .selectable_label(!fixed, "from the data")
            .on_hover_text("The palette spans the smallest to the largest σ shown")
            .clicked()
        {
            set(FieldOptions {
                range: ColourRange::Data,
                ..options
            });
        }
        if ui
            .selectable_label(fixed, "fixed range")
            .on_hover_text("The palette spans a range you set, kept across shots, channels and settings so that fields compare by eye")
            .clicked()
            && !fixed
        {
            set(FieldOptions {
                range: ColourRange::Fixed { min: 0.5, max: 3.5 },
                ..options
            });
        }
        if let ColourRange::Fixed { mut min, mut max } = options.range {
            let a = ui.add(
                egui::DragValue::new(&mut min)
                    .speed(0.02)
                    .range(0.0..=max - 0.05)
                    .fixed_decimals(2)
                    .suffix(" px"),
            );
            ui.label("to");
            let b = ui.add(
                egui::DragValue::new(&mut max)
                    .speed(0.02)
                    .range(min + 0.05..=50.0)
                    .fixed_decimals(2)
                    .suffix(" px"),
            );
            if a.changed() || b.changed() {
                set(FieldOptions {
                    range: ColourRange::Fixed { min, max },
                    ..options
                });
            }
        }
    });
}

fn palette(t: f32, diverging: bool) -> Color32 {
    let [r, g, b] = crate::review::palette_rgb(t, diverging);
    Color32::from_rgb(r, g, b)
}

fn scale_color(colours: &ColourScale, v: f64) -> Color32 {
    palette(colours.position(v), colours.diverging)
}

/// The colour bar: its title with the unit, the palette, ticks and their values, and
/// the hatching's meaning where kernels are flagged.
pub(super) fn colour_bar_ui(ui: &mut egui::Ui, colours: &ColourScale, noisy: usize, tip: &str) {
    ui.horizontal(|ui| {
        ui.label(&colours.title).on_hover_text(tip);
        let (rect, _) = ui.allocate_exact_size(Vec2::new(320.0, 30.0), Sense::hover());
        let p = ui.painter_at(rect.expand(2.0));
        let bar = Rect::from_min_size(rect.min, Vec2::new(rect.width(), 12.0));
        let n = 64;
        for k in 0..n {
            let t = (k as f32 + 0.5) / n as f32;
            let r = Rect::from_min_size(
                bar.min + Vec2::new(k as f32 / n as f32 * bar.width(), 0.0),
                Vec2::new(bar.width() / n as f32 + 0.5, bar.height()),
            );
            p.rect_filled(r, 0.0, palette(t, colours.diverging));
        }
        let text = ui.visuals().text_color();
        p.rect_stroke(bar, 0.0, Stroke::new(1.0, text), egui::StrokeKind::Outside);
        for &v in &colours.ticks {
            let x = bar.left() + colours.position(v) * bar.width();
            p.line_segment(
                [egui::pos2(x, bar.bottom()), egui::pos2(x, bar.bottom() + 4.0)],
                Stroke::new(1.0, text),
            );
            // Ticks are round numbers: three decimals, trailing zeros dropped.
            let label = format!("{v:.3}")
                .trim_end_matches('0')
                .trim_end_matches('.')
                .replace("-0", "−0")
                .replace('-', "−");
            let label = if label == "−0" || label.is_empty() {
                "0".to_owned()
            } else {
                label
            };
            p.text(
                egui::pos2(x, bar.bottom() + 4.0),
                egui::Align2::CENTER_TOP,
                label,
                egui::FontId::proportional(11.0),
                text,
            );
        }
        ui.label(format!(
            "{:.2} to {:.2}",
            colours.range[0], colours.range[1]
        ));
        if noisy > 0 {
            ui.separator();
            let (r, _) = ui.allocate_exact_size(Vec2::splat(14.0), Sense::hover());
            hatch(&ui.painter_at(r), r);
            ui.label(format!("noisy kernel ({noisy}): hover for why"))
                .on_hover_text(format!(
                    "Hatched: the kernel's tails beyond its Gaussian's 3σ ellipse rise again, walking away from its core, by more than {:.1} % of its weight. A lens's blur only falls off there; stripes and speckle of the estimate do not. Its Gaussian is drawn but not to be trusted.",
                    100.0 * crate::review::NOISY_TAIL_FRACTION
                ));
        }
    });
}

/// Grey diagonal hatching over `r`: a kernel not to be trusted.
fn hatch(painter: &egui::Painter, r: Rect) {
    let painter = painter.with_clip_rect(r.intersect(painter.clip_rect()));
    painter.rect_filled(r, 1.0, Color32::from_black_alpha(120));
    let stroke = Stroke::new(1.2, Color32::from_gray(200));
    let step = 4.0;
    let mut d = -r.height();
    while d < r.width() {
        painter.line_segment(
            [
                egui::pos2(r.left() + d, r.bottom()),
                egui::pos2(r.left() + d + r.height(), r.top()),
            ],
            stroke,
        );
        d += step;
    }
}

/// One panel: ellipses (1 σ), kernels (on tiles) or difference tiles, each coloured by
/// its value on the shared scale, at their sensor positions magnified by `scale` screen
/// points per px of σ; red crosses where a kernel failed; hatching over a kernel too
/// noisy to trust. Hovering a square names its Gaussian, MTF50 and flags; hovering a
/// cross the reason. Returns the chart square clicked, to inspect, and the shot it
/// was measured on.
fn field_panel_ui(
    ui: &mut egui::Ui,
    content: &PanelContent,
    (points, failed): (&[FieldPoint], &[(f64, f64, String)]),
    (w, h): (usize, usize),
    (scale, colours): (f32, &ColourScale),
    size: Vec2,
    atlas: Option<egui::TextureId>,
) -> Option<(Option<ShotId>, (usize, usize))> {
    let (rect, response) = ui.allocate_exact_size(size, Sense::click());
    // Named, so that a screen reader (and a test) finds the field.
    response
        .widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "kernel field panel"));
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 2.0, super::image_backdrop(ui));
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
    // Hatching goes over a square as wide as what is drawn there.
    let mut hatch_side = 10.0;
    match content {
        PanelContent::Ellipses(samples) => {
            // A light rim keeps the dark end of the palette visible on the dark panel.
            let rim = Stroke::new(1.0, Color32::from_white_alpha(110));
            for ((x, y, g), q) in samples.iter().zip(points) {
                let fill = if q.noisy.is_some() {
                    Color32::from_gray(110)
                } else {
                    scale_color(colours, q.value)
                };
                painter.add(egui::Shape::convex_polygon(
                    ellipse_points(at(*x, *y), g, scale),
                    fill,
                    rim,
                ));
            }
            hatch_side = 2.0 * scale * points.iter().map(|q| q.sigma as f32).fold(1.0, f32::max);
            count = samples.len();
            what = format!("ellipses: 1 σ, magnified {:.1}×", scale / points_per_px);
        }
        PanelContent::Kernels {
            cells,
            extent_px,
            pitch_px,
        } => {
            // Each kernel fills 85 % of the pitch between squares, so neighbours never
            // overlap: drawn white on a tile of its value's colour, the shape reads on
            // any colour of the palette.
            let side = 0.85 * *pitch_px as f32 * points_per_px;
            for (c, q) in cells.iter().zip(points) {
                let r = Rect::from_center_size(at(c.x, c.y), Vec2::splat(side));
                painter.rect_filled(r, 2.0, scale_color(colours, q.value));
                if let Some(id) = atlas {
                    painter.image(id, r, c.uv, Color32::WHITE);
                }
            }
            hatch_side = side;
            count = cells.len();
            what = format!(
                "kernels, each ±{extent_px:.1} px around its centre scaled to its peak, magnified {:.1}×",
                side / (2.0 * *extent_px as f32 * points_per_px)
            );
        }
        PanelContent::Difference {
            points: diffs,
            pitch_px,
        } => {
            let side = 0.85 * *pitch_px as f32 * points_per_px;
            for (d, q) in diffs.iter().zip(points) {
                let r = Rect::from_center_size(at(d.x, d.y), Vec2::splat(side));
                painter.rect_filled(r, 2.0, scale_color(colours, q.value));
            }
            count = diffs.len();
            what = "squares: Δσ, as the colour bar says".to_owned();
        }
    }
    for q in points.iter().filter(|q| q.noisy.is_some()) {
        hatch(
            &painter,
            Rect::from_center_size(at(q.x, q.y), Vec2::splat(hatch_side)),
        );
    }
    let red = Stroke::new(1.5, Color32::from_rgb(230, 60, 60));
    for (x, y, _) in failed {
        let c = at(*x, *y);
        let d = 4.0;
        painter.line_segment([c + Vec2::new(-d, -d), c + Vec2::new(d, d)], red);
        painter.line_segment([c + Vec2::new(-d, d), c + Vec2::new(d, -d)], red);
    }
    let mut clicked = None;
    if let Some(p) = response.hover_pos() {
        let distance = |x: f64, y: f64| (at(x, y) - p).length();
        let near_failed = failed
            .iter()
            .min_by(|a, b| distance(a.0, a.1).total_cmp(&distance(b.0, b.1)))
            .filter(|f| distance(f.0, f.1) < 8.0);
        let near_point = points
            .iter()
            .min_by(|a, b| distance(a.x, a.y).total_cmp(&distance(b.x, b.y)))
            .filter(|q| distance(q.x, q.y) < 16.0_f32.max(0.5 * hatch_side));
        if let Some((x, y, reason)) = near_failed {
            response.on_hover_text(format!("x {x:.0}, y {y:.0}: {reason}"));
        } else if let Some(q) = near_point {
            if response.clicked() {
                clicked = q.square.map(|sq| (q.shot, sq));
            }
            response.on_hover_text(point_hover(q));
        }
    }
    let failed_note = if failed.is_empty() {
        String::new()
    } else {
        format!("; {} failed (red ×, hover for the reason)", failed.len())
    };
    let click_note = if points.iter().any(|q| q.square.is_some()) {
        "; click a square to inspect it"
    } else {
        ""
    };
    ui.label(
        egui::RichText::new(format!(
            "{count} {what} (sensor {w} × {h} px){failed_note}{click_note}"
        ))
        .small(),
    );
    clicked
}

/// What hovering a drawn square says: where it is, its Gaussian's three parameters, σ
/// and MTF50; on a difference map both fields' σ; why its kernel is flagged; how far
/// the profile's kernels miss it; that a click inspects it.
fn point_hover(q: &FieldPoint) -> String {
    let g = q.gaussian;
    let gaussian = |g: &crate::psf::Gaussian2| {
        format!(
            "C_xx {:.2} px, C_yy {:.2} px, C_or {:+.2}; σ {:.2} px",
            g.sigma_x,
            g.sigma_y,
            g.rho,
            g.sigma()
        )
    };
    let mut text = format!("x {:.0}, y {:.0}", q.x, q.y);
    if let Some((row, col)) = q.square {
        text += &format!(", square row {row}, column {col}");
    }
    match &q.other {
        Some(b) => {
            text += &format!(
                "\nΔσ = {:+.3} px\nA: {}\nB: {}",
                q.value,
                gaussian(&g),
                gaussian(b)
            );
        }
        None => {
            text += &format!("\n{}", gaussian(&g));
            text += &q.mtf50.map_or_else(
                || "\nno MTF50 (degenerate Gaussian)".to_owned(),
                |m| {
                    format!(
                        "\nMTF50 {:.0} lp/ph ({:.3} cycles/px) in the worst direction ({:.0}°), {:.0} lp/ph ({:.3}) in the best, {:.0} lp/ph ({:.3}) isotropic",
                        m.worst_lp_ph, m.worst, m.worst_deg, m.best_lp_ph, m.best, m.isotropic_lp_ph, m.isotropic
                    )
                },
            );
        }
    }
    if let Some(reason) = &q.noisy {
        text += &format!("\nnot to be trusted, {reason}");
    }
    if let Some(e) = q.kernel_error {
        text += &match e.shape {
            Some(shape) => format!(
                "\npredicted kernel error: shapes {shape:.2}, Gaussian {:.2} (relative L2)",
                e.gaussian
            ),
            None => format!(
                "\npredicted kernel error: Gaussian {:.2} (relative L2; the profile holds no shape model)",
                e.gaussian
            ),
        };
    }
    if q.square.is_some() {
        text += "\nclick to open the square's inspector";
    }
    text
}
