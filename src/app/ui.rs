//! Drawing. Functions end in `_ui`; they read the app and push [`Command`]s.

use super::{Command, StudioApp, View};
use crate::plane::{Channel, LensSetting};
use crate::psf::Gaussian2;
use crate::session::StageStatus;
use crate::simulate::VirtualLens;
use egui::{Color32, Key, KeyboardShortcut, Modifiers, Pos2, Rect, Sense, Stroke, Vec2};

pub const TIP_CXX: &str = "C_xx: standard deviation σx of the Gaussian blur along the sensor's x axis, in full-resolution sensor pixels (includes the pixel's own 1-px integration).";
pub const TIP_CYY: &str = "C_yy: standard deviation σy of the Gaussian blur along the sensor's y axis, in full-resolution sensor pixels.";
pub const TIP_COR: &str = "C_or: correlation ρ = C_xy / (C_xx·C_yy) of the Gaussian, between −1 and 1; it tilts the blur ellipse.";
pub const TIP_ALPHA: &str = "α: polynomial order of the model over the sensor position (x, y).";
pub const TIP_BETA: &str = "β: polynomial order of the model over focal length f and aperture a; it must stay below the number of distinct settings shot.";

pub(super) fn root_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    shortcuts(app, ui.ctx());
    dropped_files(app, ui.ctx());
    egui::Panel::top("top").show(ui, |ui| top_bar_ui(app, ui));
    egui::Panel::bottom("status").show(ui, |ui| status_ui(app, ui));
    egui::Panel::left("session")
        .default_size(300.0)
        .resizable(true)
        .show(ui, |ui| {
            egui::ScrollArea::vertical().show(ui, |ui| session_panel_ui(app, ui));
        });
    egui::CentralPanel::default().show(ui, |ui| match app.view {
        View::Shot => shot_view_ui(app, ui),
        View::KernelField => kernel_field_ui(app, ui),
        View::Sweeps => sweeps_ui(app, ui),
        View::Models => models_ui(app, ui),
        View::Deblur => deblur_ui(app, ui),
    });
}

fn shortcuts(app: &mut StudioApp, ctx: &egui::Context) {
    let cmd = |k| KeyboardShortcut::new(Modifiers::COMMAND, k);
    let mut out = Vec::new();
    ctx.input_mut(|i| {
        if i.consume_shortcut(&cmd(Key::O)) {
            out.push(Command::OpenSessionDialog);
        }
        if i.consume_shortcut(&KeyboardShortcut::new(
            Modifiers::COMMAND | Modifiers::SHIFT,
            Key::A,
        )) {
            out.push(Command::AddShotsDialog);
        }
        if i.consume_shortcut(&cmd(Key::D)) {
            out.push(Command::RunDetect(None));
        }
        if i.consume_shortcut(&cmd(Key::K)) {
            out.push(Command::RunKernels(None));
        }
        if i.consume_shortcut(&cmd(Key::M)) {
            out.push(Command::RunCalibrate);
        }
        if i.consume_shortcut(&cmd(Key::T)) {
            out.push(Command::SetDark(!app.dark));
        }
        if i.consume_key(Modifiers::NONE, Key::Escape) {
            out.push(Command::CancelAll);
        }
        for (k, v) in [Key::Num1, Key::Num2, Key::Num3, Key::Num4, Key::Num5]
            .into_iter()
            .zip(View::ALL)
        {
            if i.consume_shortcut(&KeyboardShortcut::new(Modifiers::ALT, k)) {
                out.push(Command::SelectView(v));
            }
        }
    });
    app.commands.extend(out);
}

fn dropped_files(app: &mut StudioApp, ctx: &egui::Context) {
    let files: Vec<_> = ctx.input(|i| {
        i.raw
            .dropped_files
            .iter()
            .map(|f| f.path().to_path_buf())
            .filter(|p| !p.as_os_str().is_empty())
            .collect()
    });
    if !files.is_empty() {
        app.commands.push(Command::AddShots(files));
    }
}

fn top_bar_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        ui.strong("lensblur studio");
        ui.separator();
        for (k, v) in View::ALL.into_iter().enumerate() {
            if ui
                .selectable_label(app.view == v, v.label())
                .on_hover_text(format!("Alt+{}", k + 1))
                .clicked()
            {
                app.commands.push(Command::SelectView(v));
            }
        }
        ui.separator();
        ui.label("Channel");
        for c in [Channel::R, Channel::G, Channel::B] {
            if ui.selectable_label(app.channel == c, c.name()).clicked() {
                app.commands.push(Command::SelectChannel(c));
            }
        }
        ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
            let label = if app.dark {
                "Light theme"
            } else {
                "Dark theme"
            };
            if ui.button(label).on_hover_text("Ctrl+T").clicked() {
                app.commands.push(Command::SetDark(!app.dark));
            }
            if ui
                .button("Open session…")
                .on_hover_text("Open or create a session folder (Ctrl+O)")
                .clicked()
            {
                app.commands.push(Command::OpenSessionDialog);
            }
        });
    });
}

fn status_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    for h in &app.jobs.running {
        ui.horizontal(|ui| {
            let (stage, frac, counts) = match h.progress() {
                Some(p) if p.total > 0 => (
                    p.stage.clone(),
                    p.done as f32 / p.total as f32,
                    format!("{}/{}", p.done, p.total),
                ),
                Some(p) => (p.stage.clone(), 0.0, String::new()),
                None => ("starting".into(), 0.0, String::new()),
            };
            ui.label(format!("{}: {stage}", h.name));
            ui.add(
                egui::ProgressBar::new(frac)
                    .desired_width(240.0)
                    .text(counts),
            );
            ui.label(format!("{:.0} s", h.started.elapsed().as_secs_f32()));
            let cancel = if h.is_cancelled() {
                "Cancelling…"
            } else {
                "Cancel"
            };
            if ui
                .button(cancel)
                .on_hover_text("Stop this job (Esc stops all)")
                .clicked()
            {
                app.commands.push(Command::Cancel(h.id));
            }
        });
    }
    let mut dismiss = None;
    for (i, m) in app.messages.iter().enumerate().rev().take(4) {
        ui.horizontal(|ui| {
            let color = if m.is_error {
                ui.visuals().error_fg_color
            } else {
                ui.visuals().text_color()
            };
            if ui.small_button("x").on_hover_text("Dismiss").clicked() {
                dismiss = Some(i);
            }
            ui.colored_label(color, &m.text);
        });
    }
    if let Some(i) = dismiss {
        app.commands.push(Command::DismissMessage(i));
    }
    if app.jobs.running.is_empty() && app.messages.is_empty() {
        ui.label("Ready.");
    }
}

fn status_text(s: &StageStatus) -> String {
    match s {
        StageStatus::Pending => "—".into(),
        StageStatus::Done { summary } => summary.clone(),
        StageStatus::Failed { reason } => format!("failed: {reason}"),
    }
}

fn session_panel_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    let Some(session) = &app.session else {
        ui.heading("Session");
        if app.jobs.is_running("demo session") {
            ui.label("Making the demo session: simulated calibration shots of the virtual lens…");
            ui.spinner();
        } else {
            ui.label("No session open. Open a session folder (Ctrl+O).");
        }
        return;
    };
    ui.heading(&session.name)
        .on_hover_text(format!("Session folder: {}", session.folder().display()));
    if session.is_demo {
        ui.label("Demo: shots simulated from the virtual lens, whose true blur is known.");
    }
    ui.horizontal_wrapped(|ui| {
        if ui
            .button("Add shots…")
            .on_hover_text(
                "RAW, DNG, TIFF, PNG or JPEG; or drop files on the window (Ctrl+Shift+A)",
            )
            .clicked()
        {
            app.commands.push(Command::AddShotsDialog);
        }
        if ui
            .button("Detect")
            .on_hover_text("Find and align the chart's squares in every shot (Ctrl+D)")
            .clicked()
        {
            app.commands.push(Command::RunDetect(None));
        }
        if ui
            .button("Kernels")
            .on_hover_text("Estimate the blur kernel at every square (Ctrl+K)")
            .clicked()
        {
            app.commands.push(Command::RunKernels(None));
        }
        if ui
            .button("Calibrate")
            .on_hover_text("Cross-validate and fit the blur model; write the profile (Ctrl+M)")
            .clicked()
        {
            app.commands.push(Command::RunCalibrate);
        }
    });
    ui.separator();
    ui.label(format!("{} shots", session.shots.len()));
    let mut set = None;
    for (i, shot) in session.shots.iter().enumerate() {
        let selected = app.selected_shot == Some(i);
        let frame = egui::Frame::group(ui.style()).fill(if selected {
            ui.visuals().selection.bg_fill.gamma_multiply(0.35)
        } else {
            Color32::TRANSPARENT
        });
        let r = frame.show(ui, |ui| {
            ui.horizontal(|ui| {
                match app.previews.get(&i).and_then(|p| p.thumbnail.as_ref()) {
                    Some(t) => {
                        let size = t.size_vec2() * (72.0 / t.size_vec2().x.max(1.0));
                        ui.image((t.id(), size));
                    }
                    None => {
                        ui.add_sized([72.0, 48.0], egui::Spinner::new());
                    }
                }
                ui.vertical(|ui| {
                    let name = shot.path.file_name().map_or_else(
                        || shot.path.display().to_string(),
                        |n| n.to_string_lossy().into_owned(),
                    );
                    if ui.selectable_label(selected, name).clicked() {
                        app.commands.push(Command::SelectShot(i));
                    }
                    ui.horizontal(|ui| {
                        // Unknown settings show as "?" (0 internally) until the user drags.
                        let mut f = shot.focal_mm.unwrap_or(0.0);
                        let mut a = shot.f_number.unwrap_or(0.0);
                        let lf = ui
                            .label("f")
                            .on_hover_text("focal length, mm (from EXIF; editable)");
                        let rf = ui.add(egui::DragValue::new(&mut f).speed(0.5).custom_formatter(
                            |v, _| {
                                if v > 0.0 {
                                    format!("{v:.0} mm")
                                } else {
                                    "? mm".into()
                                }
                            },
                        ));
                        let rf = rf.labelled_by(lf.id);
                        let la = ui
                            .label("a")
                            .on_hover_text("aperture, f-number (from EXIF; editable)");
                        let ra = ui.add(egui::DragValue::new(&mut a).speed(0.05).custom_formatter(
                            |v, _| {
                                if v > 0.0 {
                                    format!("f/{v:.1}")
                                } else {
                                    "f/?".into()
                                }
                            },
                        ));
                        let ra = ra.labelled_by(la.id);
                        if rf.changed() || ra.changed() {
                            set = Some(Command::SetShotSetting {
                                index: i,
                                focal_mm: (f > 0.0).then_some(f.min(5000.0)),
                                f_number: (a > 0.0).then_some(a.min(128.0)),
                            });
                        }
                    });
                    ui.label(
                        egui::RichText::new(format!(
                            "detect: {}   kernels: {}",
                            status_text(&shot.detect),
                            status_text(&shot.kernels)
                        ))
                        .small(),
                    );
                });
            });
        });
        if r.response.interact(Sense::click()).clicked() {
            app.commands.push(Command::SelectShot(i));
        }
    }
    if let Some(c) = set {
        app.commands.push(c);
    }
    ui.separator();
    egui::CollapsingHeader::new("Settings")
        .default_open(false)
        .show(ui, |ui| {
            let s = &session.settings;
            ui.label(format!(
                "Chart: {} × {} squares, {} mm",
                session.chart.cols, session.chart.rows, session.chart.square_mm
            ));
            ui.label(format!("Kernel oversampling: {}×", s.oversample));
            ui.label(format!(
                "Weights: {}",
                if s.weight_all_subpixels {
                    "every sub-pixel (W = I)"
                } else {
                    "pixel centres"
                }
            ));
            ui.label(format!("Deblur method: {}", s.deblur_method));
        });
}

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

fn shot_view_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    let Some(session) = &app.session else {
        ui.label("No session yet.");
        return;
    };
    let Some(index) = app.selected_shot.filter(|i| *i < session.shots.len()) else {
        ui.label("No shots in this session: add shots (Ctrl+Shift+A) or drop files on the window.");
        return;
    };
    let shot = &session.shots[index];
    ui.horizontal(|ui| {
        ui.heading(app.shown_path(&session.shot_path(index)));
        match shot.setting() {
            Some(s) => ui.label(format!("{:.0} mm  f/{:.1}", s.focal_mm, s.f_number)),
            None => ui.colored_label(
                ui.visuals().warn_fg_color,
                "settings unknown: type f and a in the shot list",
            ),
        };
    });
    let detect_note = match &shot.detect {
        StageStatus::Pending => "No detection yet — press Detect (Ctrl+D) to overlay squares, corners and the chart grid.".to_owned(),
        StageStatus::Failed { reason } => format!("Detection failed: {reason}"),
        StageStatus::Done { summary } => format!("Detection: {summary}"),
    };
    ui.label(detect_note);
    let Some(preview) = app.previews.get(&index) else {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label("loading shot…");
        });
        return;
    };
    let Some(texture) = preview
        .textures
        .get(&app.channel)
        .or_else(|| preview.textures.values().next())
    else {
        ui.label("this shot has no image planes");
        return;
    };
    let cap = &preview.capture;
    let plane =
        super::logic::pooled_plane(cap, app.channel).or_else(|| cap.planes.first().cloned());
    let (step, ox, oy) = plane.as_ref().map_or((1.0, 0.0, 0.0), |p| {
        (p.step as f64, p.offset_x as f64, p.offset_y as f64)
    });

    let inspector_w = if app.inspection.as_ref().is_some_and(|i| i.shot == index) {
        240.0
    } else {
        0.0
    };
    let avail = ui.available_size();
    let (rect, response) = ui.allocate_exact_size(
        Vec2::new((avail.x - inspector_w).max(100.0), avail.y),
        Sense::click_and_drag(),
    );
    if inspector_w > 0.0 {
        let side = Rect::from_min_size(
            Pos2::new(rect.right() + 8.0, rect.top()),
            Vec2::new(inspector_w - 8.0, rect.height()),
        );
        let command = ui
            .scope_builder(egui::UiBuilder::new().max_rect(side), |ui| {
                inspector_ui(app, ui)
            })
            .inner;
        app.commands.extend(command);
    }
    let fit = (rect.width() / cap.width as f32).min(rect.height() / cap.height as f32);
    let ppp = app.viewer.sensor_px_per_point.map_or(fit, |s| 1.0 / s);
    if app.viewer.sensor_px_per_point.is_none() {
        app.viewer.centre_sensor = [
            (cap.width as f32 - 1.0) / 2.0,
            (cap.height as f32 - 1.0) / 2.0,
        ];
    }
    let mut view = SensorView {
        rect,
        points_per_px: ppp,
        centre: app.viewer.centre_sensor,
    };
    if response.dragged() {
        let d = response.drag_delta() / ppp;
        view.centre = [view.centre[0] - d.x, view.centre[1] - d.y];
    }
    if response.hovered() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if scroll != 0.0 {
            let factor = (scroll * 0.002).exp();
            let new_ppp = (ppp * factor).clamp(fit * 0.5, 64.0);
            if let Some(p) = response.hover_pos() {
                // Zoom about the cursor: the sensor point under it stays put.
                let under = view.to_sensor(p);
                let d = (p - rect.center()) / new_ppp;
                view.centre = [under[0] - d.x, under[1] - d.y];
            }
            view.points_per_px = new_ppp;
        }
    }
    if response.double_clicked() {
        view.points_per_px = fit;
        view.centre = [
            (cap.width as f32 - 1.0) / 2.0,
            (cap.height as f32 - 1.0) / 2.0,
        ];
    }
    app.viewer.centre_sensor = view.centre;
    app.viewer.sensor_px_per_point = Some(1.0 / view.points_per_px);

    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 0.0, Color32::from_gray(20));
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
    if let Some(det) = app.detections.get(&index) {
        let clicked = response
            .clicked()
            .then(|| response.interact_pointer_pos())
            .flatten()
            .map(|p| view.to_sensor(p));
        if let Some(sq) = detection_overlay(
            &painter,
            &view,
            det,
            &session.chart,
            app.selected_square,
            clicked,
        ) {
            app.commands.push(Command::SelectSquare(sq));
        }
    }
    if let Some(p) = response.hover_pos() {
        let [x, y] = view.to_sensor(p);
        let v = plane.as_ref().and_then(|cp| {
            let [i, j] = cp.plane_from_sensor(f64::from(x), f64::from(y));
            cp.plane.get_checked(i.round() as i64, j.round() as i64)
        });
        let text = match v {
            Some(v) => format!("x {x:.1}  y {y:.1}  {} {v:.4}", app.channel),
            None => format!("x {x:.1}  y {y:.1}"),
        };
        caption(
            &painter,
            rect.left_bottom() + Vec2::new(6.0, -6.0),
            egui::Align2::LEFT_BOTTOM,
            text,
        );
    }
    caption(
        &painter,
        rect.right_top() + Vec2::new(-6.0, 6.0),
        egui::Align2::RIGHT_TOP,
        format!(
            "{}  {:.0}%  (scroll: zoom, drag: pan, double-click: fit)",
            app.channel,
            view.points_per_px * 100.0
        ),
    );
}

/// White text on a dark box, readable over any image.
fn caption(painter: &egui::Painter, pos: Pos2, align: egui::Align2, text: String) {
    let galley = painter.layout_no_wrap(text, egui::FontId::proportional(12.0), Color32::WHITE);
    let rect = align.anchor_size(pos, galley.size());
    painter.rect_filled(rect.expand(3.0), 3.0, Color32::from_black_alpha(170));
    painter.galley(rect.min, galley, Color32::WHITE);
}

/// Viridis-like colour for σ in px over [0.5, 3.5].
fn sigma_color(sigma_px: f64) -> Color32 {
    const STOPS: [[u8; 3]; 5] = [
        [68, 1, 84],
        [59, 82, 139],
        [33, 145, 140],
        [94, 201, 98],
        [253, 231, 37],
    ];
    let t = ((sigma_px - 0.5) / 3.0).clamp(0.0, 1.0) * 4.0;
    let k = (t.floor() as usize).min(3);
    let f = (t - k as f64) as f32;
    let [a, b] = [STOPS[k], STOPS[k + 1]];
    let mix = |i: usize| (f32::from(a[i]) * (1.0 - f) + f32::from(b[i]) * f) as u8;
    Color32::from_rgb(mix(0), mix(1), mix(2))
}

/// The 1-σ ellipse of `g` scaled by `scale` screen points per px, as a closed polyline.
fn ellipse_points(centre: Pos2, g: &Gaussian2, scale: f32) -> Vec<Pos2> {
    let (sx, sy, r) = (g.sigma_x, g.sigma_y, g.rho.clamp(-0.999, 0.999));
    // Cholesky factor of the covariance maps the unit circle onto the 1-σ ellipse.
    let l21 = r * sy;
    let l22 = sy * (1.0 - r * r).sqrt();
    (0..=40)
        .map(|k| {
            let t = f64::from(k) / 40.0 * std::f64::consts::TAU;
            let (c, s) = (t.cos(), t.sin());
            centre + Vec2::new((sx * c) as f32, (l21 * c + l22 * s) as f32) * scale
        })
        .collect()
}

/// Pixel-level truth of the virtual lens: the optical Gaussian plus the 1-px box.
fn truth_gaussian(
    lens: &VirtualLens,
    ch: Channel,
    x: f64,
    y: f64,
    w: usize,
    h: usize,
    s: LensSetting,
) -> Gaussian2 {
    lens.gaussian_at(ch, x, y, w, h, s)
        .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
}

fn sensor_size(app: &StudioApp) -> (usize, usize) {
    if let Some(p) = app.selected_shot.and_then(|i| app.previews.get(&i)) {
        return (p.capture.width, p.capture.height);
    }
    (app.options.demo_spec.width, app.options.demo_spec.height)
}

fn setting_sliders_ui(app: &mut StudioApp, ui: &mut egui::Ui, lens: &VirtualLens) {
    ui.horizontal(|ui| {
        ui.add(
            egui::Slider::new(
                &mut app.field_focal_mm,
                lens.focal_range_mm[0]..=lens.focal_range_mm[1],
            )
            .suffix(" mm")
            .text("focal length"),
        );
        ui.add_space(12.0);
        ui.add(
            egui::Slider::new(
                &mut app.field_f_number,
                lens.f_number_range[0]..=lens.f_number_range[1],
            )
            .prefix("f/")
            .logarithmic(true)
            .text("aperture"),
        );
    });
}

/// Gaussian ellipses at their sensor positions, coloured by σ = √(C_xx·C_yy), magnified
/// by `scale` screen points per pixel of σ (shared between panels that are compared).
fn ellipse_panel_ui(
    ui: &mut egui::Ui,
    title: &str,
    samples: &[(f64, f64, Gaussian2)],
    (w, h): (usize, usize),
    scale: f32,
    size: Vec2,
) {
    ui.vertical(|ui| {
        ui.label(title);
        let (rect, _) = ui.allocate_exact_size(size, Sense::hover());
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
        painter.rect_stroke(
            rect,
            2.0,
            Stroke::new(1.0, ui.visuals().weak_text_color()),
            egui::StrokeKind::Inside,
        );
        let points_per_px = rect.width() / w as f32;
        for (x, y, g) in samples {
            let c = rect.min + Vec2::new(*x as f32 * points_per_px, *y as f32 * points_per_px);
            let color = sigma_color((g.sigma_x * g.sigma_y).sqrt());
            painter.add(egui::Shape::convex_polygon(
                ellipse_points(c, g, scale),
                color,
                Stroke::NONE,
            ));
        }
        ui.label(
            egui::RichText::new(format!(
                "{} ellipses: 1 σ, magnified {:.1}× (sensor {w}×{h} px)",
                samples.len(),
                scale / points_per_px
            ))
            .small(),
        );
    });
}

/// The demo lens's exact field on a 12 × 8 grid.
fn truth_field(
    lens: &VirtualLens,
    ch: Channel,
    (w, h): (usize, usize),
    s: LensSetting,
) -> Vec<(f64, f64, Gaussian2)> {
    let (nx, ny) = (12usize, 8usize);
    let mut out = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            let x = (i as f64 + 0.5) / nx as f64 * (w as f64 - 1.0);
            let y = (j as f64 + 0.5) / ny as f64 * (h as f64 - 1.0);
            out.push((x, y, truth_gaussian(lens, ch, x, y, w, h, s)));
        }
    }
    out
}

/// A profile's predicted field on a 12 × 8 grid, or why it has none at this setting.
fn predicted_field(
    p: &crate::profile::Profile,
    ch: Channel,
    (w, h): (usize, usize),
    s: LensSetting,
) -> Result<Vec<(f64, f64, Gaussian2)>, String> {
    let (nx, ny) = (12usize, 8usize);
    let mut out = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            let x = (i as f64 + 0.5) / nx as f64 * (w as f64 - 1.0);
            let y = (j as f64 + 0.5) / ny as f64 * (h as f64 - 1.0);
            out.push((x, y, p.predict(ch, x, y, s).map_err(|e| e.to_string())?));
        }
    }
    Ok(out)
}

fn sigma_legend_ui(ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        ui.label("σ = √(C_xx·C_yy)")
            .on_hover_text(format!("{TIP_CXX}\n{TIP_CYY}"));
        ui.label("0.5 px");
        let (rect, _) = ui.allocate_exact_size(Vec2::new(160.0, 12.0), Sense::hover());
        let p = ui.painter_at(rect);
        for k in 0..32 {
            let t = k as f32 / 32.0;
            let r = Rect::from_min_size(
                rect.min + Vec2::new(t * rect.width(), 0.0),
                Vec2::new(rect.width() / 32.0 + 0.5, rect.height()),
            );
            p.rect_filled(r, 0.0, sigma_color(0.5 + 3.0 * f64::from(t)));
        }
        ui.label("3.5 px");
    });
}

fn kernel_field_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    use super::FieldSource;
    ui.heading("Kernel field");
    let is_demo = app.session.as_ref().is_some_and(|s| s.is_demo);
    let lens = VirtualLens::demo();
    ui.horizontal(|ui| {
        for (src, label, tip) in [
            (
                FieldSource::Measured,
                "Measured",
                "Robust Gaussian fits of the kernels measured on the selected shot",
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
        sigma_legend_ui(ui);
    });
    let s = LensSetting {
        focal_mm: app.field_focal_mm,
        f_number: app.field_f_number,
    };
    let size = sensor_size(app);
    let ch = app.channel;
    // Panels: (title, samples or the reason there are none).
    let mut panels: Vec<(String, Result<Vec<(f64, f64, Gaussian2)>, String>)> = Vec::new();
    match app.field_source {
        FieldSource::Measured => {
            let shot = app.selected_shot;
            let name = shot
                .and_then(|i| app.session.as_ref()?.shots.get(i))
                .map_or_else(String::new, |s| s.stem());
            let samples = shot
                .and_then(|i| app.measured.get(&i))
                .map(|m| {
                    m.iter()
                        .filter(|k| k.channel == ch)
                        .map(|k| (k.x, k.y, k.gaussian))
                        .collect::<Vec<_>>()
                })
                .ok_or_else(|| {
                    "No kernels measured on this shot yet — press Kernels (Ctrl+K) after Detect."
                        .to_owned()
                });
            panels.push((format!("measured on {name} — channel {ch}"), samples));
        }
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
            match &app.profile {
                Some((path, p)) => panels.push((
                    format!(
                        "{} — {:.0} mm f/{:.1}, channel {ch}",
                        app.shown_path(path),
                        s.focal_mm,
                        s.f_number
                    ),
                    predicted_field(p, ch, size, s),
                )),
                None => panels.push((
                    "predicted".into(),
                    Err("No profile yet: Calibrate (Ctrl+M) or load one in Models.".into()),
                )),
            }
            if let Some((path, p)) = &app.compare_profile {
                panels.push((
                    format!("{} — channel {ch}", app.shown_path(path)),
                    predicted_field(p, ch, size, s),
                ));
            }
        }
        FieldSource::Truth => {
            if !is_demo {
                ui.label("Ground truth exists only for the demo session's simulated lens.");
                return;
            }
            setting_sliders_ui(app, ui, &lens);
            ui.checkbox(&mut app.compare_units, "Compare with a second unit")
                .on_hover_text("Two copies of one lens model blur differently (the paper's two 17–40 mm units).");
            ui.label("GROUND TRUTH of the demo's virtual lens (pixel-level Gaussians: optical blur plus the 1-px pixel integration).");
            panels.push((
                format!("{} {} — channel {ch}", lens.model, lens.serial),
                Ok(truth_field(&lens, ch, size, s)),
            ));
            if app.compare_units {
                let other = VirtualLens::demo_second_unit();
                panels.push((
                    format!("{} {} — channel {ch}", other.model, other.serial),
                    Ok(truth_field(&other, ch, size, s)),
                ));
            }
        }
    }
    let avail = ui.available_size();
    let cols = panels.len().max(1) as f32;
    let w = ((avail.x - 16.0 * cols) / cols)
        .min((avail.y - 40.0) * size.0 as f32 / size.1 as f32)
        .max(100.0);
    let panel = Vec2::new(w, w * size.1 as f32 / size.0 as f32);
    // One magnification for every panel so compared fields are comparable: the largest
    // 1-σ radius fills 45 % of a twelfth of the sensor width.
    let max_sigma = panels
        .iter()
        .filter_map(|(_, r)| r.as_ref().ok())
        .flatten()
        .map(|(_, _, g)| g.sigma_x.max(g.sigma_y))
        .fold(1e-6, f64::max);
    let scale = 0.45 * (panel.x / 12.0) / max_sigma as f32;
    ui.horizontal(|ui| {
        for (title, samples) in &panels {
            match samples {
                Ok(samples) => ellipse_panel_ui(ui, title, samples, size, scale, panel),
                Err(reason) => {
                    ui.vertical(|ui| {
                        ui.label(title);
                        ui.label(reason);
                    });
                }
            }
        }
    });
}

fn nearest(values: &[f64], v: f64) -> Option<f64> {
    values
        .iter()
        .copied()
        .min_by(|a, b| (a - v).abs().total_cmp(&(b - v).abs()))
}

fn sweeps_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    use egui_plot::{Line, LineStyle, Plot, PlotPoints, Points};
    ui.heading("Sweeps");
    let is_demo = app.session.as_ref().is_some_and(|s| s.is_demo);
    let lens = VirtualLens::demo();
    if app.dataset.is_none() {
        ui.label("Measured points appear here after Kernels (Ctrl+K) and Calibrate (Ctrl+M); model curves come from the profile.");
    }
    if app.dataset.is_none() && app.profile.is_none() && !is_demo {
        return;
    }
    ui.label(
        "Points: measured at the square nearest each location. Solid lines: the profile's model. Dashed: the demo lens's ground truth.",
    );
    let (f_range, a_range) = match &app.profile {
        Some((_, p)) => (p.norm.focal_range_mm, p.norm.f_number_range),
        None => (lens.focal_range_mm, lens.f_number_range),
    };
    setting_sliders_ui(app, ui, &lens);
    let (w, h) = sensor_size(app);
    let locations: [(&str, f64, f64, Color32); 5] = [
        ("centre", 0.5, 0.5, Color32::from_rgb(240, 200, 60)),
        ("top-left", 0.1, 0.1, Color32::from_rgb(90, 170, 255)),
        ("top-right", 0.9, 0.1, Color32::from_rgb(240, 100, 90)),
        ("bottom-left", 0.1, 0.9, Color32::from_rgb(120, 210, 120)),
        ("bottom-right", 0.9, 0.9, Color32::from_rgb(200, 120, 230)),
    ];
    // One colour per location across the six plots, named once here rather than in
    // six legends that would cover the curves.
    ui.horizontal(|ui| {
        ui.label("Locations:");
        for (loc, _, _, c) in locations {
            ui.colored_label(c, format!("— {loc}"));
        }
    });
    let ch = app.channel;
    let (focals, apertures) = app
        .dataset
        .as_ref()
        .map(|d| d.distinct_settings())
        .unwrap_or_default();
    // Measured points only exist at shot settings: the sweep holds the other setting at
    // the calibrated value nearest the slider.
    let fixed_f = nearest(&focals, app.field_focal_mm).unwrap_or(app.field_focal_mm);
    let fixed_a = nearest(&apertures, app.field_f_number).unwrap_or(app.field_f_number);
    let params: [(&str, &str, fn(&Gaussian2) -> f64); 3] = [
        ("C_xx", TIP_CXX, |g| g.sigma_x),
        ("C_yy", TIP_CYY, |g| g.sigma_y),
        ("C_or", TIP_COR, |g| g.rho),
    ];
    let avail = ui.available_size();
    let plot_w = (avail.x - 24.0) / 3.0;
    let plot_h = ((avail.y - 60.0) / 2.0).max(120.0);
    for vs_aperture in [true, false] {
        ui.horizontal(|ui| {
            for (name, tip, get) in params {
                ui.vertical(|ui| {
                    let title = if vs_aperture {
                        format!("{name} vs aperture at {fixed_f:.0} mm, channel {ch}")
                    } else {
                        format!("{name} vs focal length at f/{fixed_a:.1}, channel {ch}")
                    };
                    ui.label(title).on_hover_text(tip);
                    let unit = if name == "C_or" {
                        "ρ (unitless)"
                    } else {
                        "σ (px)"
                    };
                    let x_label = if vs_aperture {
                        "aperture (f-number)"
                    } else {
                        "focal length (mm)"
                    };
                    let setting_at = |t: f64| {
                        if vs_aperture {
                            let [a0, a1] = a_range;
                            LensSetting {
                                focal_mm: fixed_f,
                                f_number: a0 * (a1 / a0).powf(t),
                            }
                        } else {
                            let [f0, f1] = f_range;
                            LensSetting {
                                focal_mm: f0 + (f1 - f0) * t,
                                f_number: fixed_a,
                            }
                        }
                    };
                    let abscissa =
                        |s: LensSetting| if vs_aperture { s.f_number } else { s.focal_mm };
                    Plot::new(format!("sweep-{name}-{vs_aperture}"))
                        .width(plot_w)
                        .height(plot_h)
                        .x_axis_label(x_label)
                        .y_axis_label(format!("{name}: {unit}"))
                        .allow_scroll(false)
                        .show(ui, |plot| {
                            for (loc, fx, fy, color) in locations {
                                let (x, y) = (fx * (w as f64 - 1.0), fy * (h as f64 - 1.0));
                                if let Some(ds) = &app.dataset {
                                    let mut pts = Vec::new();
                                    for (k, info) in ds.shots.iter().enumerate() {
                                        let on_sweep = if vs_aperture {
                                            (info.focal_mm - fixed_f).abs() < 1e-6
                                        } else {
                                            (info.f_number - fixed_a).abs() < 1e-6
                                        };
                                        if !on_sweep {
                                            continue;
                                        }
                                        let near = ds
                                            .samples
                                            .iter()
                                            .filter(|s| s.shot == k && s.channel == ch)
                                            .min_by(|a, b| {
                                                let da = (a.x - x).powi(2) + (a.y - y).powi(2);
                                                let db = (b.x - x).powi(2) + (b.y - y).powi(2);
                                                da.total_cmp(&db)
                                            });
                                        if let Some(s) = near {
                                            let v =
                                                if vs_aperture { s.f_number } else { s.focal_mm };
                                            pts.push([v, get(&s.gaussian)]);
                                        }
                                    }
                                    plot.points(
                                        Points::new(
                                            format!("measured {loc}"),
                                            PlotPoints::from(pts),
                                        )
                                        .radius(3.5),
                                    );
                                }
                                if let Some((_, p)) = &app.profile {
                                    let pts: Vec<[f64; 2]> = (0..=40)
                                        .filter_map(|k| {
                                            let s = setting_at(f64::from(k) / 40.0);
                                            p.predict(ch, x, y, s)
                                                .ok()
                                                .map(|g| [abscissa(s), get(&g)])
                                        })
                                        .collect();
                                    plot.line(Line::new(
                                        format!("model {loc}"),
                                        PlotPoints::from(pts),
                                    ));
                                }
                                if is_demo {
                                    let pts: Vec<[f64; 2]> = (0..=40)
                                        .map(|k| {
                                            let s = setting_at(f64::from(k) / 40.0);
                                            let g = truth_gaussian(&lens, ch, x, y, w, h, s);
                                            [abscissa(s), get(&g)]
                                        })
                                        .collect();
                                    plot.line(
                                        Line::new(format!("truth {loc}"), PlotPoints::from(pts))
                                            .color(color.gamma_multiply(0.7))
                                            .style(LineStyle::dashed_loose())
                                            .width(1.0),
                                    );
                                }
                            }
                        });
                });
            }
        });
    }
}

fn models_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    use egui_plot::{Legend, Line, Plot, PlotPoints, Points};
    ui.heading("Models");
    ui.horizontal(|ui| {
        if ui
            .button("Run calibration")
            .on_hover_text("Fit global and local models over every shot with kernels; cross-validation picks α and β (Ctrl+M)")
            .clicked()
        {
            app.commands.push(Command::RunCalibrate);
        }
        if ui.button("Load profile…").clicked() {
            app.commands.push(Command::LoadProfileDialog);
        }
        if ui.button("Save profile…").clicked() {
            app.commands.push(Command::SaveProfileDialog);
        }
        ui.label("α").on_hover_text(TIP_ALPHA);
        ui.label("β").on_hover_text(TIP_BETA);
    });
    if let Some((path, p)) = &app.profile {
        let kind = format!("{:?}", p.preferred).to_lowercase();
        let orders = |g: Option<(usize, usize)>| {
            g.map_or("—".to_owned(), |(a, b)| format!("α {a}, β {b}"))
        };
        ui.label(format!(
            "Profile {}: preferred {kind} model; global {}; local {}; calibrated {:.0}–{:.0} mm, f/{:.1}–f/{:.1}",
            app.shown_path(path),
            orders(p.global.as_ref().map(|g| (g.alpha, g.beta))),
            orders(p.local.as_ref().map(|l| (l.alpha, l.beta))),
            p.norm.focal_range_mm[0],
            p.norm.focal_range_mm[1],
            p.norm.f_number_range[0],
            p.norm.f_number_range[1],
        ));
    } else {
        ui.label("No profile yet — press Calibrate once kernels are measured on the shots, or load a profile.");
    }
    let Some(cv) = app.cv.clone() else {
        ui.label("Cross-validation curves over α and β (paper Fig. 5) and the error distributions (Fig. 6) appear after a calibration that selects α and β.");
        return;
    };
    ui.label(format!(
        "Cross-validation: {} shots in {} folds (whole shots held out); errors in % of each parameter's 99 % range (C_xx {:.3} px, C_yy {:.3} px, C_or {:.3}).",
        cv.shots, cv.folds, cv.ranges.cxx, cv.ranges.cyy, cv.ranges.cor
    ));
    let families: Vec<(&str, &crate::crossval::Selection)> =
        [("global", cv.global.as_ref()), ("local", cv.local.as_ref())]
            .into_iter()
            .filter_map(|(n, s)| s.map(|s| (n, s)))
            .collect();
    for (name, sel) in &families {
        ui.label(format!(
            "{name}: chosen α {}, β {} ({} terms): mean error C_xx {:.2} %, C_yy {:.2} %, C_or {:.2} %; 95th percentile {:.2} / {:.2} / {:.2} %",
            sel.alpha,
            sel.beta,
            sel.chosen.terms,
            sel.chosen.mean_error_pct[0],
            sel.chosen.mean_error_pct[1],
            sel.chosen.mean_error_pct[2],
            sel.chosen.p95_error_pct[0],
            sel.chosen.p95_error_pct[1],
            sel.chosen.p95_error_pct[2],
        ));
    }
    let avail = ui.available_size();
    let plot_w = (avail.x - 24.0) / 3.0;
    let plot_h = (avail.y - 40.0).max(140.0);
    ui.horizontal(|ui| {
        for (title, tip, by_alpha) in [
            ("CV error vs α (β = N − 1)", TIP_ALPHA, true),
            ("CV error vs β (chosen α)", TIP_BETA, false),
        ] {
            ui.vertical(|ui| {
                ui.label(title).on_hover_text(tip);
                Plot::new(format!("cv-{by_alpha}"))
                    .width(plot_w)
                    .height(plot_h)
                    .x_axis_label(if by_alpha {
                        "α (spatial order)"
                    } else {
                        "β (order in f, a)"
                    })
                    .y_axis_label("mean error (% of range)")
                    .legend(Legend::default())
                    .allow_scroll(false)
                    .show(ui, |plot| {
                        for (name, sel) in &families {
                            let curve = if by_alpha {
                                &sel.alpha_curve
                            } else {
                                &sel.beta_curve
                            };
                            let pts: Vec<[f64; 2]> = curve
                                .iter()
                                .map(|p| {
                                    [if by_alpha { p.alpha } else { p.beta } as f64, p.mean_pct]
                                })
                                .collect();
                            plot.line(Line::new(format!("{name}"), PlotPoints::from(pts.clone())));
                            plot.points(
                                Points::new(format!("{name}"), PlotPoints::from(pts)).radius(3.0),
                            );
                        }
                    });
            });
        }
        ui.vertical(|ui| {
            ui.label("Error CDF of the chosen models (Fig. 6)");
            Plot::new("cv-cdf")
                .width(plot_w)
                .height(plot_h)
                .x_axis_label("error (% of range)")
                .y_axis_label("fraction of samples (%)")
                .legend(Legend::default())
                .allow_scroll(false)
                .show(ui, |plot| {
                    for (name, sel) in &families {
                        let cdf = &sel.error_cdf;
                        for (param, q) in
                            [("C_xx", &cdf.cxx), ("C_yy", &cdf.cyy), ("C_or", &cdf.cor)]
                        {
                            let pts: Vec<[f64; 2]> = q
                                .iter()
                                .zip(&cdf.percentiles)
                                .map(|(&e, &p)| [e, p])
                                .collect();
                            plot.line(Line::new(format!("{name} {param}"), PlotPoints::from(pts)));
                        }
                    }
                });
        });
    });
}

fn deblur_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    ui.heading("Deblur");
    ui.horizontal(|ui| {
        if ui
            .button("Open photo…")
            .on_hover_text("A photo taken with the calibrated lens; its settings come from EXIF")
            .clicked()
        {
            app.commands.push(Command::OpenPhotoDialog);
        }
    });
    match &app.photo {
        None => {
            ui.label("No photo open.");
        }
        Some((path, cap, tex)) => {
            let setting = match (cap.setting_focal_mm, cap.setting_f_number) {
                (Some(f), Some(a)) => format!("{f:.0} mm f/{a:.1} (EXIF)"),
                _ => "settings not in EXIF".to_owned(),
            };
            ui.label(format!(
                "{} — {}×{} — {setting}",
                app.shown_path(path),
                cap.width,
                cap.height
            ));
            ui.label("No profile yet: the predicted-Gaussian and measured-kernel results appear beside the original after Calibrate.");
            if let Some(t) = tex {
                let avail = ui.available_size();
                let s = (avail.x / t.size_vec2().x)
                    .min(avail.y / t.size_vec2().y)
                    .min(1.0);
                ui.image((t.id(), t.size_vec2() * s));
            }
        }
    }
}

/// Colour of a square's outline by its alignment residual (normalised units): green
/// when the synthetic square explains the observed one to noise level, red when not.
fn residual_color(rms: f64) -> Color32 {
    let t = ((rms - 0.005) / 0.03).clamp(0.0, 1.0) as f32;
    Color32::from_rgb((60.0 + 195.0 * t) as u8, (220.0 - 160.0 * t) as u8, 80)
}

/// Draws every square's refined outline and corners, and the chart's circles projected
/// through that square's own homography (so a misaligned square shows its circles off
/// the imaged ones). Skipped squares get a red cross. Returns the square under a click.
fn detection_overlay(
    painter: &egui::Painter,
    view: &SensorView,
    det: &crate::detect::Detection,
    chart: &crate::chart::ChartSpec,
    selected: Option<(usize, usize)>,
    clicked: Option<[f32; 2]>,
) -> Option<(usize, usize)> {
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
        if sq.status != crate::detect::SquareStatus::Ok {
            if sq.corners.iter().flatten().all(|v| v.is_finite()) && pts[0] != pts[2] {
                let red = Stroke::new(1.5, Color32::from_rgb(230, 60, 60));
                painter.line_segment([pts[0], pts[2]], red);
                painter.line_segment([pts[1], pts[3]], red);
            }
            continue;
        }
        let is_selected = selected == Some((sq.row, sq.col));
        let stroke = if is_selected {
            Stroke::new(2.5, Color32::from_rgb(255, 210, 0))
        } else {
            Stroke::new(1.0, residual_color(sq.residual_rms))
        };
        painter.add(egui::Shape::closed_line(pts.clone(), stroke));
        if zoomed_in || is_selected {
            let h = &sq.image_from_chart;
            for c in &chart.circle_centres {
                let ring: Vec<Pos2> = (0..24)
                    .map(|k| {
                        let t = std::f64::consts::TAU * f64::from(k) / 24.0;
                        let p = h.apply([
                            sq.col as f64 + c[0] + chart.circle_radius * t.cos(),
                            sq.row as f64 + c[1] + chart.circle_radius * t.sin(),
                        ]);
                        view.to_screen(p[0], p[1])
                    })
                    .collect();
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
            && point_in_quad([f64::from(x), f64::from(y)], &sq.corners)
        {
            hit = Some((sq.row, sq.col));
        }
    }
    hit
}

fn point_in_quad(p: [f64; 2], q: &[[f64; 2]; 4]) -> bool {
    let mut sign = 0.0;
    for k in 0..4 {
        let a = q[k];
        let b = q[(k + 1) % 4];
        let cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        if cross != 0.0 {
            if sign != 0.0 && cross.signum() != sign {
                return false;
            }
            sign = cross.signum();
        }
    }
    true
}

/// The clicked square: observed pixels, the synthetic square the alignment matched, and
/// their difference, with the numbers behind them.
fn inspector_ui(app: &StudioApp, ui: &mut egui::Ui) -> Option<Command> {
    let ins = app.inspection.as_ref()?;
    let (row, col) = ins.square;
    ui.strong(format!("Square row {row}, column {col} — {}", ins.channel));
    let det_sq = app
        .detections
        .get(&ins.shot)
        .and_then(|d| d.squares.iter().find(|s| (s.row, s.col) == ins.square));
    if let Some(sq) = det_sq {
        let c = crate::kernel::square_centre(&crate::kernel::SquareGeometry {
            row,
            col,
            image_from_chart: sq.image_from_chart,
        });
        ui.label(format!("centre x {:.1}, y {:.1} px", c[0], c[1]));
        let moved = sq
            .corners
            .iter()
            .zip(&sq.bootstrap_corners)
            .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        ui.label(format!("refinement moved corners ≤ {moved:.3} px"));
    }
    ui.label(format!(
        "residual RMS {:.4} (white = 1)",
        ins.crops.residual_rms
    ))
    .on_hover_text("Observed minus the synthetic square (the chart through this square's refined homography, blurred by the detection's blur estimate). Structure here means misalignment or a non-Gaussian blur.");
    let w = ui.available_width();
    for (k, title) in ["observed", "synthetic", "residual (grey = 0)"]
        .iter()
        .enumerate()
    {
        ui.label(*title);
        let t = &ins.textures[k];
        let size = t.size_vec2();
        let scale = (w / size.x).min(150.0 / size.y);
        ui.image((t.id(), size * scale));
    }
    ui.button("Close inspector")
        .clicked()
        .then_some(Command::ClearSquare)
}
