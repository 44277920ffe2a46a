//! The Sharpness view: MTF50 over the whole frame as a colour map, as MTF Mapper's lens
//! map shows a lens: measured on the selected shot, predicted at the sliders' setting,
//! or the demo lens's truth; along the worst or best direction or isotropic, in line
//! pairs per picture height or cycles per pixel. Hover reads the map; PNG and CSV save
//! it.
//!
//! Draws the map `view_data` made; computes nothing.

use super::super::view_data::SharpnessData;
use super::super::{Command, FieldSource, SharpnessChoice};
use super::field::colour_bar_ui;
use super::{Sliders, caption, setting_sliders_ui};
use crate::app::{DialogCommand, ViewCommand};
use crate::review::{Mtf50Direction, SharpnessUnit};
use egui::{Color32, Rect, Sense, Vec2};

const TIP_MAP: &str = "MTF50: the spatial frequency at which the lens keeps half its contrast, from the blur's Gaussian (the pixel's own aperture included; demosaicing and sharpening not). Higher is sharper. Worst: along the direction the blur is widest, what every direction resolves at least; best: along the narrowest; isotropic: the round blur of the same area.";

/// The view, from its own state (`choice`), its view data (`data`: the map, absent
/// while it is made) and the setting sliders' inputs.
pub(super) fn sharpness_ui(
    choice: SharpnessChoice,
    data: Option<&SharpnessData>,
    sliders: &Sliders<'_>,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) {
    ui.heading("Sharpness map");
    let next = choices_ui(choice, data.is_some_and(|d| d.map.is_ok()), out, ui);
    if next != choice {
        out.push(Command::View(ViewCommand::SetSharpness(next)));
    }
    if choice.source != FieldSource::Measured {
        setting_sliders_ui(sliders, out, ui);
    }
    let Some(data) = data else {
        ui.weak("preparing the map…");
        return;
    };
    let map = match &data.map {
        Ok(map) => map,
        Err(why) => {
            ui.add_space(24.0);
            ui.vertical_centered(|ui| ui.weak(why));
            return;
        }
    };
    let unit = choice.unit.label();
    let digits = if choice.unit == SharpnessUnit::CyclesPerPixel {
        3
    } else {
        0
    };
    ui.horizontal_wrapped(|ui| {
        ui.label(format!("{} ({})", map.title, map.channel.name()));
        if let Some(s) = &data.summary {
            ui.separator();
            ui.label(format!(
                "centre {:.digits$} {unit} · corners {:.digits$} ({:+.0} %) · {:.digits$} to {:.digits$}",
                s.centre,
                s.corners,
                100.0 * (s.corners / s.centre - 1.0),
                s.min,
                s.max
            ))
            .on_hover_text("Centre: the cell at the frame's centre; corners: the mean of the four corner cells, and how far they fall from the centre; then the lowest and highest cell.");
        }
    });
    let bar_room = 64.0;
    let avail = ui.available_size() - Vec2::new(0.0, bar_room);
    let aspect = map.sensor.0 as f32 / map.sensor.1.max(1) as f32;
    let size = if avail.x / avail.y.max(1.0) > aspect {
        Vec2::new(avail.y * aspect, avail.y)
    } else {
        Vec2::new(avail.x, avail.x / aspect)
    }
    .max(Vec2::splat(16.0));
    let (rect, response) = ui.allocate_exact_size(size, Sense::hover());
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 0.0, super::image_backdrop(ui));
    if let Some(tex) = &data.texture {
        painter.image(
            tex.id(),
            rect,
            Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
            Color32::WHITE,
        );
    }
    painter.rect_stroke(
        rect,
        0.0,
        egui::Stroke::new(1.0, ui.visuals().weak_text_color()),
        egui::StrokeKind::Inside,
    );
    if let Some(pos) = response.hover_pos() {
        let to_px = |p: egui::Pos2| {
            (
                f64::from((p.x - rect.left()) / rect.width()) * map.sensor.0 as f64,
                f64::from((p.y - rect.top()) / rect.height()) * map.sensor.1 as f64,
            )
        };
        let (x, y) = to_px(pos);
        let text = match map.at(x, y, choice.unit) {
            Some(v) => format!("MTF50 {v:.digits$} {unit} at ({x:.0}, {y:.0}) px"),
            None => format!("no measurement at ({x:.0}, {y:.0}) px: the chart did not reach here"),
        };
        caption(
            &painter,
            pos + Vec2::new(14.0, 14.0),
            egui::Align2::LEFT_TOP,
            text,
        );
    }
    if let Some(scale) = &data.scale {
        ui.add_space(6.0);
        colour_bar_ui(ui, scale, 0, TIP_MAP);
    }
}

/// Where the map comes from, which MTF50 and unit (the choice as changed this frame),
/// and its saving (`ready`: there is a map to save).
fn choices_ui(
    choice: SharpnessChoice,
    ready: bool,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) -> SharpnessChoice {
    let mut next = choice;
    ui.horizontal_wrapped(|ui| {
        for (src, label, tip) in [
            (
                FieldSource::Measured,
                "Measured",
                "What the selected shot's kernels measured, interpolated between the chart's squares",
            ),
            (
                FieldSource::Predicted,
                "Predicted",
                "What the profile predicts at the focal length and aperture of the sliders",
            ),
            (
                FieldSource::Truth,
                "Ground truth",
                "The demo lens's exact blur (demo session only)",
            ),
        ] {
            if ui
                .selectable_label(choice.source == src, label)
                .on_hover_text(tip)
                .clicked()
            {
                next.source = src;
            }
        }
        ui.separator();
        for d in Mtf50Direction::ALL {
            if ui
                .selectable_label(choice.direction == d, d.label())
                .on_hover_text(TIP_MAP)
                .clicked()
            {
                next.direction = d;
            }
        }
        ui.separator();
        for (u, tip) in [
            (
                SharpnessUnit::LpPerPictureHeight,
                "Line pairs per picture height: comparable between cameras of different resolution",
            ),
            (
                SharpnessUnit::CyclesPerPixel,
                "Cycles per pixel: 0.5 is the sensor's Nyquist frequency",
            ),
        ] {
            if ui
                .selectable_label(choice.unit == u, u.label())
                .on_hover_text(tip)
                .clicked()
            {
                next.unit = u;
            }
        }
        ui.separator();
        for (png, label, tip) in [
            (
                true,
                "Save PNG…",
                "Save the map as a PNG with its title and colour bar",
            ),
            (
                false,
                "Save CSV…",
                "Save the map as CSV: each cell's sensor position and MTF50 in both units",
            ),
        ] {
            if ui
                .add_enabled(ready, egui::Button::new(label))
                .on_hover_text(tip)
                .clicked()
            {
                out.push(Command::Dialog(DialogCommand::SaveSharpnessDialog { png }));
            }
        }
    });
    next
}
