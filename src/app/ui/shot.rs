//! The Shot view: one shot per channel with zoom and pan, the detection's overlays, and
//! the inspector of a clicked square.
//!
//! Draws the textures made when the shot loaded and the view data `view_data` keeps
//! (the plane the viewer maps, the inspector's crops, kernel and truth); computes
//! nothing.

use super::super::view_data::{Inspecting, ShotPlane};
use super::super::{Command, ShotViewState, ViewerContext, ViewerState};
use super::{Frame, caption, ellipse_points};
use crate::app::ViewCommand;
use crate::detect::{Detection, SquareStatus};
use crate::plane::ChannelPlane;
use crate::session::{Session, Shot, StageStatus};
use egui::{Color32, Pos2, Rect, Sense, Stroke, Vec2};
use std::sync::Arc;

/// Sensor-to-screen mapping of the shot viewer.
struct SensorView {
    rect: Rect,
    points_per_px: f32,
    centre: [f32; 2],
}

impl SensorView {
    fn to_screen(&self, x: f64, y: f64) -> Pos2 {
        self.rect.center()
            + Vec2::new(
                (x as f32 - self.centre[0]) * self.points_per_px,
                (y as f32 - self.centre[1]) * self.points_per_px,
            )
    }
    fn to_sensor(&self, p: Pos2) -> [f32; 2] {
        let d = (p - self.rect.center()) / self.points_per_px;
        [self.centre[0] + d.x, self.centre[1] + d.y]
    }
}

/// Width the inspector takes beside the viewer.
const INSPECTOR_W: f32 = 270.0;

/// What the Shot view draws from: the selection and the viewer, the shot as loaded with
/// its detection and kernels, the plane the viewer maps and the square's inspection.
pub(super) struct ShotContext<'a> {
    cx: ViewerContext<'a>,
    state: &'a ShotViewState,
    plane: Option<&'a ShotPlane>,
    inspection: Option<&'a Inspecting>,
}

impl<'a> ShotContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            cx: f.cx,
            state: &f.views.shot,
            plane: f.data.shot_plane.as_ref(),
            inspection: f.data.inspection.as_ref(),
        }
    }
}

pub(super) fn shot_view_ui(c: &ShotContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    // Zoom, pan and overlays change on a copy, handed back as one command.
    let mut viewer = c.state.viewer;
    shot_body_ui(c, out, ui, &mut viewer);
    if viewer != c.state.viewer {
        out.push(Command::View(ViewCommand::SetViewer(viewer)));
    }
}

fn shot_body_ui(
    c: &ShotContext<'_>,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
    viewer: &mut ViewerState,
) {
    let Some(session) = c.cx.session() else {
        ui.label("No session yet.");
        return;
    };
    let Some(shot) = c.state.selected.and_then(|id| session.shot(id)) else {
        ui.label("No shots in this session: add shots (Ctrl+Shift+A) or drop files on the window.");
        return;
    };
    let index = shot.id;
    let detected = c.cx.detection(index).cloned();
    shot_header_ui(c.cx, session, shot, &detected, viewer, ui);
    let Some(preview) = c.cx.preview(index) else {
        match c.cx.unreadable(index) {
            Some(reason) => {
                ui.colored_label(ui.visuals().error_fg_color, reason);
            }
            None => {
                ui.horizontal(|ui| {
                    ui.spinner();
                    ui.label("loading shot…");
                });
            }
        }
        return;
    };
    if let Some(Err(reason)) = &preview.developed {
        ui.colored_label(
            ui.visuals().warn_fg_color,
            format!("cannot develop this RAW ({reason}): showing its linear plane"),
        );
    }
    let developed = match &preview.developed {
        Some(Ok(t)) if viewer.developed => Some(t),
        _ => None,
    };
    let Some(texture) = developed.or_else(|| {
        preview
            .textures
            .get(&c.state.channel)
            .or_else(|| preview.textures.values().next())
    }) else {
        ui.label("this shot has no image planes");
        return;
    };
    let cap = &preview.capture;
    let Some(shot_plane) = c.plane.filter(|p| p.shot() == index) else {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label("preparing the shot…");
        });
        return;
    };
    let plane = shot_plane.index.and_then(|i| cap.planes.get(i));
    // The developed image is full resolution; a CFA plane covers every other pixel.
    let (step, ox, oy) = match plane {
        Some(p) if developed.is_none() => (p.step as f64, p.offset_x as f64, p.offset_y as f64),
        _ => (1.0, 0.0, 0.0),
    };

    // The inspector stands beside the viewer while its crops are made, so the viewer
    // keeps its size when they arrive.
    let inspecting = match c.inspection {
        Some(Inspecting::Running(k)) => k.shot == index,
        Some(Inspecting::Ready(i)) => i.shot == index,
        Some(Inspecting::Empty(_)) | None => false,
    };
    let inspector_w = if inspecting { INSPECTOR_W } else { 0.0 };
    let avail = ui.available_size();
    let (rect, response) = ui.allocate_exact_size(
        Vec2::new((avail.x - inspector_w).max(100.0), avail.y),
        Sense::click_and_drag(),
    );
    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "shot viewer"));
    if inspecting {
        let side = Rect::from_min_size(
            Pos2::new(rect.right() + 8.0, rect.top()),
            Vec2::new(inspector_w - 8.0, rect.height()),
        );
        let command = ui
            .scope_builder(egui::UiBuilder::new().max_rect(side), |ui| {
                egui::ScrollArea::vertical()
                    .id_salt("inspector")
                    .show(ui, |ui| inspector_ui(c, ui))
                    .inner
            })
            .inner;
        out.extend(command);
    }
    let view = navigate(ui, &response, rect, (cap.width, cap.height), viewer);
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 0.0, super::image_backdrop(ui));
    let tex_size = texture.size_vec2();
    // Plane pixel (i, j) covers sensor [step·i + ox ± step/2]: the texture's outer edges.
    let min = view.to_screen(ox - step / 2.0, oy - step / 2.0);
    let max = view.to_screen(
        ox + step * (f64::from(tex_size.x) - 0.5),
        oy + step * (f64::from(tex_size.y) - 0.5),
    );
    painter.image(
        texture.id(),
        Rect::from_min_max(min, max),
        Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
        Color32::WHITE,
    );
    if let Some(det) = &detected {
        let clicked = response
            .clicked()
            .then(|| response.interact_pointer_pos())
            .flatten()
            .map(|p| view.to_sensor(p));
        let overlay = Overlay {
            squares: viewer.show_squares,
            circles: viewer.show_circles,
            grid: viewer.show_grid,
        };
        if let Some(sq) = detection_overlay(
            &painter,
            &view,
            det,
            &session.chart,
            overlay,
            c.state.square,
            clicked,
        ) {
            out.push(Command::View(ViewCommand::SelectSquare(sq)));
        }
    }
    captions(
        c.state.channel,
        &painter,
        &view,
        plane,
        response.hover_pos(),
    );
}

/// The shot's name and setting, its detection's outcome and what it skipped, and the
/// viewer's switches.
fn shot_header_ui(
    cx: ViewerContext<'_>,
    session: &Session,
    shot: &Shot,
    detected: &Option<Arc<Detection>>,
    viewer: &mut ViewerState,
    ui: &mut egui::Ui,
) {
    let index = shot.id;
    ui.horizontal(|ui| {
        ui.heading(cx.shown_path(&session.path_of(shot)));
        match shot.setting() {
            Some(s) => ui.label(format!("{:.0} mm  f/{:.1}", s.focal_mm, s.f_number)),
            None => ui.colored_label(
                ui.visuals().warn_fg_color,
                "settings unknown: type f and a in the shot list",
            ),
        };
    });
    ui.horizontal_wrapped(|ui| {
        match &shot.detect {
            StageStatus::Pending => {
                ui.label("No detection yet — press Detect (Ctrl+D) to overlay squares, corners and the chart grid.");
            }
            StageStatus::Failed { reason } => {
                ui.colored_label(
                    ui.visuals().error_fg_color,
                    format!("Detection failed: {reason}"),
                );
            }
            StageStatus::Done { summary } => {
                ui.label(format!("Detection: {summary}."));
            }
        }
        if let Some(det) = &detected {
            let reasons = crate::review::skip_reasons(det);
            if !reasons.is_empty() {
                let text = reasons
                    .iter()
                    .map(|(r, n)| format!("{r} ({n})"))
                    .collect::<Vec<_>>()
                    .join(", ");
                ui.colored_label(ui.visuals().warn_fg_color, format!("skipped: {text}"));
            }
        }
        if cx.preview(index).is_some_and(|p| p.developed.is_some()) {
            ui.separator();
            ui.checkbox(&mut viewer.developed, "developed")
                .on_hover_text("The RAW as a RAW editor shows it (imagepipe: demosaic, white balance, colour, tone); off: the selected channel's linear CFA plane, which is what is measured");
        }
        if detected.is_some() {
            ui.separator();
            ui.checkbox(&mut viewer.show_squares, "squares")
                .on_hover_text("Each square's refined outline, coloured by its alignment residual");
            ui.checkbox(&mut viewer.show_circles, "circles & corners")
                .on_hover_text("The chart's circles projected through each square's own homography, and its corners (when zoomed in, or on the selected square)");
            ui.checkbox(&mut viewer.show_grid, "chart grid")
                .on_hover_text("The whole chart's grid projected through the global homography");
            residual_legend_ui(ui);
        }
    });
}

/// Zoom about the pointer (scroll), pan (drag) and fit (double-click): where the viewer
/// now looks, kept in `viewer` for the next frame.
fn navigate(
    ui: &egui::Ui,
    response: &egui::Response,
    rect: Rect,
    (width, height): (usize, usize),
    viewer: &mut ViewerState,
) -> SensorView {
    let fit = (rect.width() / width as f32).min(rect.height() / height as f32);
    let sensor_centre = [(width as f32 - 1.0) / 2.0, (height as f32 - 1.0) / 2.0];
    let fitted = viewer.sensor_px_per_point.is_none();
    let mut view = SensorView {
        rect,
        points_per_px: viewer.sensor_px_per_point.map_or(fit, |s| 1.0 / s),
        centre: if fitted {
            sensor_centre
        } else {
            viewer.centre_sensor
        },
    };
    let mut moved = false;
    if response.dragged() {
        let d = response.drag_delta() / view.points_per_px;
        view.centre = [view.centre[0] - d.x, view.centre[1] - d.y];
        moved = d != Vec2::ZERO;
    }
    if response.hovered() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if scroll != 0.0 {
            let factor = (scroll * 0.002).exp();
            let new_ppp = (view.points_per_px * factor).clamp(fit * 0.5, 64.0);
            if let Some(p) = response.hover_pos() {
                // Zoom about the cursor: the sensor point under it stays put.
                let under = view.to_sensor(p);
                let d = (p - rect.center()) / new_ppp;
                view.centre = [under[0] - d.x, under[1] - d.y];
            }
            view.points_per_px = new_ppp;
            moved = true;
        }
    }
    if response.double_clicked() {
        view.points_per_px = fit;
        view.centre = sensor_centre;
        viewer.sensor_px_per_point = None;
    } else if moved || !fitted {
        viewer.sensor_px_per_point = Some(1.0 / view.points_per_px);
    }
    viewer.centre_sensor = view.centre;
    view
}

/// The value under the pointer, and the channel, zoom and controls in the corner.
fn captions(
    channel: crate::plane::Channel,
    painter: &egui::Painter,
    view: &SensorView,
    plane: Option<&ChannelPlane>,
    hover: Option<Pos2>,
) {
    let rect = view.rect;
    if let Some(p) = hover {
        let [x, y] = view.to_sensor(p);
        let v = plane.and_then(|cp| {
            let [i, j] = cp.plane_from_sensor(f64::from(x), f64::from(y));
            cp.plane.get_checked(i.round() as i64, j.round() as i64)
        });
        let text = match v {
            Some(v) => format!("x {x:.1}  y {y:.1}  {channel} {v:.4}"),
            None => format!("x {x:.1}  y {y:.1}"),
        };
        caption(
            painter,
            rect.left_bottom() + Vec2::new(6.0, -6.0),
            egui::Align2::LEFT_BOTTOM,
            text,
        );
    }
    caption(
        painter,
        rect.right_top() + Vec2::new(-6.0, 6.0),
        egui::Align2::RIGHT_TOP,
        format!(
            "{}  {:.0}%  (scroll: zoom, drag: pan, double-click: fit, click a square: inspect)",
            channel,
            view.points_per_px * 100.0
        ),
    );
}

/// Colour of a square's outline by its alignment residual (normalised units): green
/// when the synthetic square explains the observed one to noise level, red when not.
fn residual_color(rms: f64) -> Color32 {
    let t = ((rms - 0.005) / 0.03).clamp(0.0, 1.0) as f32;
    Color32::from_rgb((60.0 + 195.0 * t) as u8, (220.0 - 160.0 * t) as u8, 80)
}

fn residual_legend_ui(ui: &mut egui::Ui) {
    ui.label("alignment residual, % of white")
        .on_hover_text("How well the square lines up with the chart after alignment: the RMS of the observed square minus the synthetic one (the chart through the square's homography, blurred), in percent of the chart's white. Green: to the noise level; red: misaligned, or a blur the Gaussian does not describe.");
    ui.label("0.5 %");
    let (rect, _) = ui.allocate_exact_size(Vec2::new(80.0, 10.0), Sense::hover());
    let p = ui.painter_at(rect);
    for k in 0..16 {
        let t = k as f32 / 16.0;
        let r = Rect::from_min_size(
            rect.min + Vec2::new(t * rect.width(), 0.0),
            Vec2::new(rect.width() / 16.0 + 0.5, rect.height()),
        );
        p.rect_filled(r, 0.0, residual_color(0.005 + 0.03 * f64::from(t)));
    }
    ui.label("3.5 %");
}

#[derive(Clone, Copy)]
struct Overlay {
    squares: bool,
    circles: bool,
    grid: bool,
}

/// Draws every square's refined outline and corners, the chart's circles projected
/// through that square's own homography (so a misaligned square shows its circles off
/// the imaged ones), and the whole chart grid through the global homography. Skipped
/// squares get a red cross. Returns the square under a click.
fn detection_overlay(
    painter: &egui::Painter,
    view: &SensorView,
    det: &Detection,
    chart: &crate::chart::ChartSpec,
    overlay: Overlay,
    selected: Option<(usize, usize)>,
    clicked: Option<[f32; 2]>,
) -> Option<(usize, usize)> {
    if overlay.grid {
        let stroke = Stroke::new(1.0, Color32::from_rgba_unmultiplied(0, 200, 255, 140));
        for [a, b] in crate::review::chart_grid(det, chart) {
            painter.line_segment(
                [view.to_screen(a[0], a[1]), view.to_screen(b[0], b[1])],
                stroke,
            );
        }
    }
    let mut hit = None;
    // Circles only once a square spans enough screen to show them; at fit zoom on a
    // large chart they would be thousands of tiny polylines per frame.
    let zoomed_in = view.points_per_px > 1.2;
    for sq in &det.squares {
        let pts: Vec<Pos2> = sq
            .corners
            .iter()
            .map(|c| view.to_screen(c[0], c[1]))
            .collect();
        if sq.status != SquareStatus::Ok {
            if overlay.squares
                && sq.corners.iter().flatten().all(|v| v.is_finite())
                && pts[0] != pts[2]
            {
                let red = Stroke::new(1.5, Color32::from_rgb(230, 60, 60));
                painter.line_segment([pts[0], pts[2]], red);
                painter.line_segment([pts[1], pts[3]], red);
            }
            continue;
        }
        let is_selected = selected == Some((sq.row, sq.col));
        if is_selected {
            painter.add(egui::Shape::closed_line(
                pts.clone(),
                Stroke::new(2.5, Color32::from_rgb(255, 210, 0)),
            ));
        } else if overlay.squares {
            painter.add(egui::Shape::closed_line(
                pts.clone(),
                Stroke::new(1.0, residual_color(sq.residual_rms)),
            ));
        }
        if overlay.circles && (zoomed_in || is_selected) {
            for ring in
                crate::review::square_circles(&sq.image_from_chart, (sq.row, sq.col), chart, 24)
            {
                let ring: Vec<Pos2> = ring.iter().map(|p| view.to_screen(p[0], p[1])).collect();
                painter.add(egui::Shape::closed_line(
                    ring,
                    Stroke::new(1.0, Color32::from_rgb(80, 170, 255)),
                ));
            }
            for p in &pts {
                painter.circle_stroke(*p, 3.0, Stroke::new(1.0, Color32::from_rgb(255, 120, 0)));
            }
        }
        if let Some([x, y]) = clicked
            && crate::review::point_in_quad([f64::from(x), f64::from(y)], &sq.corners)
        {
            hit = Some((sq.row, sq.col));
        }
    }
    hit
}

/// The clicked square: observed pixels, the synthetic square the alignment matched, and
/// their difference; its measured 3× kernel with the fitted Gaussian's ellipse; the
/// numbers behind them.
fn inspector_ui(c: &ShotContext<'_>, ui: &mut egui::Ui) -> Option<Command> {
    let ins = match c.inspection? {
        Inspecting::Ready(ins) => ins,
        Inspecting::Running(key) => {
            let mut out = None;
            ui.horizontal(|ui| {
                let (row, col) = key.square;
                ui.strong(format!("Square row {row}, column {col} — {}", key.channel));
                if ui
                    .small_button("×")
                    .on_hover_text("Close the inspector")
                    .clicked()
                {
                    out = Some(Command::View(ViewCommand::ClearSquare));
                }
            });
            ui.horizontal(|ui| {
                ui.spinner();
                ui.label("inspecting the square…");
            });
            return out;
        }
        Inspecting::Empty(_) => return None,
    };
    let (row, col) = ins.square;
    let mut out = None;
    ui.horizontal(|ui| {
        ui.strong(format!("Square row {row}, column {col} — {}", ins.channel));
        if ui
            .small_button("×")
            .on_hover_text("Close the inspector")
            .clicked()
        {
            out = Some(Command::View(ViewCommand::ClearSquare));
        }
    });
    if let Some(f) = &ins.facts {
        ui.label(format!(
            "centre x {:.1}, y {:.1} px; side {:.1} × {:.1} px",
            f.centre[0], f.centre[1], f.side_px[0], f.side_px[1]
        ));
        ui.label(format!(
            "refinement moved corners ≤ {:.3} px",
            f.corner_shift_px
        ));
    }
    ui.label(format!(
        "alignment residual {:.2} % of white (RMS)",
        100.0 * ins.crops.residual_rms
    ))
    .on_hover_text("Observed minus the synthetic square (the chart through this square's refined homography, blurred by the detection's blur estimate). Structure here means misalignment or a non-Gaussian blur.");
    let w = ui.available_width();
    let crop_w = ((w - 16.0) / 3.0).max(40.0);
    ui.horizontal(|ui| {
        for (k, title) in ["observed", "synthetic", "residual"].iter().enumerate() {
            ui.vertical(|ui| {
                ui.label(egui::RichText::new(*title).small());
                let t = &ins.textures[k];
                let size = t.size_vec2();
                let scale = crop_w / size.x.max(size.y);
                ui.image((t.id(), size * scale));
            });
        }
    });
    ui.label(egui::RichText::new("residual: grey = 0, ±25 % of the square's contrast").small());
    ui.separator();
    let sample = c.cx.kernels(ins.shot).and_then(|file| {
        file.samples
            .iter()
            .find(|s| s.channel == ins.channel && s.row == Some(row) && s.col == Some(col))
            .map(|s| (s, file.oversample))
    });
    let failed = c.cx.kernels(ins.shot).and_then(|file| {
        file.failed
            .iter()
            .find(|s| s.channel == ins.channel && (s.row, s.col) == (row, col))
    });
    match (sample, &ins.kernel) {
        (Some((s, oversample)), Some(t)) => measured_kernel_ui(s, oversample, t, ins.truth, w, ui),
        _ => match failed {
            Some(f) => {
                ui.colored_label(
                    ui.visuals().error_fg_color,
                    format!("kernel not measured: {}", f.reason),
                );
            }
            None => {
                ui.label("No kernel measured here yet — press Kernels (Ctrl+K).");
            }
        },
    }
    out
}

/// A measured kernel, its central ±2.5σ at its own resolution with its Gaussian's 1σ
/// and 2σ ellipses, and the fits' numbers beside the truth where there is one.
fn measured_kernel_ui(
    s: &crate::kernel::file::KernelSample,
    oversample: usize,
    t: &egui::TextureHandle,
    truth: Option<crate::psf::Gaussian2>,
    w: f32,
    ui: &mut egui::Ui,
) {
    let n = t.size_vec2().x.max(1.0);
    // The kernel array spans the estimation's whole support; its central ±2.5σ
    // (at least ±2 px) is where the shape is.
    let sigma = s.cxx.unwrap_or(1.0).max(s.cyy.unwrap_or(1.0));
    let half_texels = ((2.5 * sigma).max(2.0) * oversample as f64).ceil() as f32;
    let shown = (2.0 * half_texels + 1.0).min(n);
    ui.label(format!(
        "measured kernel, {oversample}× resolution, central ±{:.1} px; 1σ and 2σ ellipses of its Gaussian fit",
        (shown - 1.0) / 2.0 / oversample as f32
    ));
    let side = w.min(150.0);
    let (rect, _) = ui.allocate_exact_size(Vec2::splat(side), Sense::hover());
    let painter = ui.painter_at(rect);
    let uv_half = shown / 2.0 / n;
    painter.image(
        t.id(),
        rect,
        Rect::from_center_size(Pos2::new(0.5, 0.5), Vec2::splat(2.0 * uv_half)),
        Color32::WHITE,
    );
    // Texels are 1/oversample px: σ px spans σ·oversample texels.
    let points_per_px = side / shown * oversample as f32;
    if let (Some(cxx), Some(cyy), Some(cor)) = (s.cxx, s.cyy, s.cor) {
        let g = crate::psf::Gaussian2 {
            sigma_x: cxx,
            sigma_y: cyy,
            rho: cor,
        };
        for (k, alpha) in [(1.0, 255), (2.0, 150)] {
            painter.add(egui::Shape::closed_line(
                ellipse_points(rect.center(), &g, points_per_px * k),
                Stroke::new(1.0, Color32::from_rgba_unmultiplied(255, 190, 0, alpha)),
            ));
        }
    }
    egui::Grid::new("inspector-numbers")
        .num_columns(4)
        .striped(true)
        .show(ui, |ui| {
            ui.label("");
            ui.label("C_xx px").on_hover_text(super::TIP_CXX);
            ui.label("C_yy px").on_hover_text(super::TIP_CYY);
            ui.label("C_or").on_hover_text(super::TIP_COR);
            ui.end_row();
            let row3 = |ui: &mut egui::Ui, name: &str, tip: &str, v: [Option<f64>; 3]| {
                ui.label(name).on_hover_text(tip);
                for x in v {
                    ui.monospace(x.map_or("—".into(), |x| format!("{x:.3}")));
                }
                ui.end_row();
            };
            row3(
                ui,
                "robust fit",
                "Levenberg–Marquardt fit of a Gaussian to the kernel's central region",
                [s.cxx, s.cyy, s.cor],
            );
            if let Some(ml) = &s.ml {
                row3(
                    ui,
                    "ML fit",
                    "Moments of the thresholded kernel (the fit's starting point)",
                    [Some(ml.cxx), Some(ml.cyy), Some(ml.cor)],
                );
            }
            if let Some(t) = truth {
                row3(
                    ui,
                    "truth",
                    "The demo lens's pixel-level Gaussian at the square's centre",
                    [Some(t.sigma_x), Some(t.sigma_y), Some(t.rho)],
                );
            }
        });
}
