//! The coverage maps: where on the sensor the chart has been at each setting, one
//! small map per setting, and the parts of the frame still to cover in words. The
//! maps and the words come from the core (`review::coverage`); this only draws them.

use crate::review::{COVERAGE_CELLS, PART_COVERED, SettingCoverage};
use egui::{Color32, Rect, Sense, Vec2, pos2, vec2};

/// A map's width on screen, points; its height follows the sensor's aspect.
const MAP_W: f32 = 120.0;

/// One map per setting with measured shots, in a wrapping row, and a line per setting
/// with parts not yet covered.
/// `maps` are the view data's (`view_data::ViewData::coverage`), on a sensor of
/// `(w, h)` px.
pub(super) fn coverage_ui(
    maps: Option<&[SettingCoverage]>,
    (w, h): (usize, usize),
    ui: &mut egui::Ui,
) {
    let Some(maps) = maps else {
        return;
    };
    if maps.is_empty() {
        ui.label("Where the chart has been shows here once shots have kernels.");
        return;
    }
    ui.add_space(6.0);
    ui.strong("Where the chart has been, per setting")
        .on_hover_text(format!(
            "Each map is the frame; shaded where the squares whose kernels were measured lie, in any shot at that setting. A small chart shot at several positions covers the frame together. A part of the frame (top-left, top, …, a ninth of it) counts as covered once {:.0} % of it is.",
            100.0 * PART_COVERED
        ));
    let map_h = MAP_W * h as f32 / w.max(1) as f32;
    let visuals = ui.visuals();
    let (covered, empty, warn) = (
        visuals.selection.bg_fill,
        visuals.extreme_bg_color,
        visuals.warn_fg_color,
    );
    ui.horizontal_wrapped(|ui| {
        for c in maps {
            // Each map in a box of its own width, so the row wraps between maps.
            let item = vec2(
                MAP_W,
                map_h + 2.0 * ui.text_style_height(&egui::TextStyle::Body),
            );
            ui.allocate_ui_with_layout(item, egui::Layout::top_down(egui::Align::Min), |ui| {
                ui.label(format!(
                    "{:.0} mm f/{:.1}",
                    c.setting.focal_mm, c.setting.f_number
                ));
                ui.small(format!(
                    "{} shot{}",
                    c.shots,
                    if c.shots == 1 { "" } else { "s" }
                ));
                let (rect, response) = ui.allocate_exact_size(vec2(MAP_W, map_h), Sense::hover());
                draw_map(ui, rect, c, covered, empty);
                let stroke_colour = if c.missing_parts().is_empty() {
                    ui.visuals().widgets.noninteractive.fg_stroke.color
                } else {
                    warn
                };
                ui.painter().rect_stroke(
                    rect,
                    0.0,
                    egui::Stroke::new(1.0, stroke_colour),
                    egui::StrokeKind::Inside,
                );
                response.on_hover_text(c.missing_line().unwrap_or_else(|| {
                    format!(
                        "Every part of the frame covered ({:.0} % of it)",
                        100.0 * c.frame_share()
                    )
                }));
            });
        }
    });
    for line in maps.iter().filter_map(SettingCoverage::missing_line) {
        ui.colored_label(warn, line);
    }
}

/// The map's cells, each shaded by the share of it the chart covered.
fn draw_map(ui: &egui::Ui, rect: Rect, c: &SettingCoverage, covered: Color32, empty: Color32) {
    let [cx, cy] = COVERAGE_CELLS;
    let cell = Vec2::new(rect.width() / cx as f32, rect.height() / cy as f32);
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 0.0, empty);
    for j in 0..cy {
        for i in 0..cx {
            let share = c.cells.get(j * cx + i).copied().unwrap_or(0.0);
            if share <= 0.0 {
                continue;
            }
            let min = pos2(
                rect.min.x + i as f32 * cell.x,
                rect.min.y + j as f32 * cell.y,
            );
            painter.rect_filled(
                Rect::from_min_size(min, cell),
                0.0,
                empty.lerp_to_gamma(covered, share.clamp(0.0, 1.0)),
            );
        }
    }
    // The nine parts the words name.
    let grid = ui.visuals().widgets.noninteractive.bg_stroke;
    for k in 1..3 {
        let x = rect.min.x + rect.width() * k as f32 / 3.0;
        let y = rect.min.y + rect.height() * k as f32 / 3.0;
        painter.line_segment([pos2(x, rect.min.y), pos2(x, rect.max.y)], grid);
        painter.line_segment([pos2(rect.min.x, y), pos2(rect.max.x, y)], grid);
    }
}
