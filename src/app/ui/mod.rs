//! Drawing. Functions end in `_ui`; they read the app (its state and the view data
//! `view_data` keeps current) and push [`Command`]s, and never compute what a view
//! shows: where its view data is absent they show a placeholder.

mod coverage;
mod deblur;
mod deblur_controls;
mod field;
mod geometry;
mod help;
mod menu;
mod models;
mod session_panel;
mod sharpness;
mod shot;
mod sweeps;

use super::jobs::Jobs;
use super::view_data::ViewData;
use super::{Command, JobOutput, PlotId, View, ViewerContext, Views, Window};
use crate::app::{DeblurCommand, DialogCommand, SessionCommand, ViewCommand, WindowCommand};
use crate::plane::Channel;
use crate::psf::Gaussian2;
use egui::{Color32, Pos2, Rect, Vec2};
use std::path::Path;

pub const TIP_CXX: &str = "C_xx: standard deviation σx of the Gaussian blur along the sensor's x axis, in full-resolution sensor pixels (includes the pixel's own 1-px integration).";
pub const TIP_CYY: &str = "C_yy: standard deviation σy of the Gaussian blur along the sensor's y axis, in full-resolution sensor pixels.";
pub const TIP_COR: &str = "C_or: correlation ρ = C_xy / (C_xx·C_yy) of the Gaussian, between −1 and 1; it tilts the blur ellipse.";
pub const TIP_ALPHA: &str = "α: polynomial order of the model over the sensor position (x, y). Higher α follows finer variation across the frame but needs more squares.";
pub const TIP_BETA: &str = "β: polynomial order of the model over focal length f and aperture a; it must stay below the number of distinct settings shot (N = min(N_f, N_a)).";

/// What a frame draws from, borrowed from the app for the frame: the project and the
/// loaded shots, the view shown, each view's state and data, the window around them and
/// the running jobs. Only this module's layout reads it whole; each view draws from a
/// context of its own made of it.
pub(super) struct Frame<'a> {
    pub cx: ViewerContext<'a>,
    pub view: View,
    pub views: &'a Views,
    pub data: &'a ViewData,
    pub window: &'a Window,
    pub jobs: &'a Jobs<JobOutput>,
    /// How long a notice stays in the status line (`AppOptions::notice_lifetime`).
    pub notice_lifetime: Option<std::time::Duration>,
    /// Where *Export ▸ Lens profile to the library* saves.
    pub profile_library: &'a Path,
    /// The Deblur view's method: its own, else the session's.
    pub deblur_method: crate::deblur::Method,
    /// The sensor the views draw on (`view_data::sensor_size`).
    pub sensor: (usize, usize),
    /// The focal length and aperture ranges the setting sliders span
    /// (`view_data::setting_ranges`).
    pub setting_ranges: ([f64; 2], [f64; 2]),
}

/// Draws the frame; what it asks for is queued on `out`, which the app applies after
/// the frame (draw code only reads).
pub(super) fn root_ui(f: &Frame<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    draw(f, out, ui);
}

/// A panel's frame, without its background where the window is cleared to that colour.
fn panel_frame(window: &Window, frame: egui::Frame) -> egui::Frame {
    if window.cleared_to_panel_fill {
        frame.fill(egui::Color32::TRANSPARENT)
    } else {
        frame
    }
}

fn draw(f: &Frame<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let menu = menu::MenuContext::of(f);
    menu::shortcuts(&menu, out, ui.ctx());
    dropped_files(f.view, out, ui.ctx());
    let side = panel_frame(f.window, egui::Frame::side_top_panel(ui.style()));
    egui::Panel::top("menu")
        .frame(side)
        .show(ui, |ui| menu::menu_bar_ui(&menu, out, ui));
    egui::Panel::top("top")
        .frame(side)
        .show(ui, |ui| top_bar_ui(f, out, ui));
    egui::Panel::bottom("status")
        .frame(side)
        .show(ui, |ui| status_ui(f, out, ui));
    if f.window.log_open {
        egui::Panel::bottom("log")
            .frame(side)
            .resizable(true)
            .default_size(180.0)
            .show(ui, |ui| log_ui(f.window, out, ui));
    }
    if f.views.session.open {
        egui::Panel::left("session")
            .frame(side)
            .default_size(300.0)
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| {
                    session_panel::session_panel_ui(
                        &session_panel::SessionPanelContext::of(f),
                        out,
                        ui,
                    );
                });
            });
    }
    egui::CentralPanel::default()
        .frame(panel_frame(
            f.window,
            egui::Frame::central_panel(ui.style()),
        ))
        .show(ui, |ui| match f.view {
            View::Shot => shot::shot_view_ui(&shot::ShotContext::of(f), out, ui),
            View::KernelField => field::kernel_field_ui(&field::FieldContext::of(f), out, ui),
            View::Sharpness => sharpness::sharpness_ui(
                f.views.sharpness,
                f.data.sharpness.as_ref(),
                &Sliders::of(f),
                out,
                ui,
            ),
            View::Sweeps => sweeps::sweeps_ui(&sweeps::SweepsContext::of(f), out, ui),
            View::Models => models::models_ui(&models::ModelsContext::of(f), out, ui),
            View::Deblur => deblur::deblur_ui(&deblur::DeblurContext::of(f), out, ui),
            View::Geometry => geometry::geometry_ui(
                f.cx.project.map_or(
                    crate::project::GeometryStatus::NoShots,
                    crate::project::Project::geometry_status,
                ),
                f.data.geometry.as_ref(),
                out,
                ui,
            ),
        });
    let ctx = ui.ctx().clone();
    confirm_ui(f.window.confirm.as_ref(), f.cx.session(), out, &ctx);
    help::help_ui(f.window, out, &ctx);
    help::about_ui(f.window, out, &ctx);
    help::guide_ui(f.window, out, &ctx);
}

/// The question asked before losing work, over a dimmed window.
fn confirm_ui(
    confirm: Option<&super::Confirm>,
    session: Option<&crate::session::Session>,
    out: &mut Vec<Command>,
    ctx: &egui::Context,
) {
    let Some(confirm) = confirm else {
        return;
    };
    let (title, text, yes) = match confirm {
        super::Confirm::RemoveShot(id) => {
            let name = session
                .and_then(|s| s.shot(*id))
                .map_or_else(|| "this shot".into(), crate::session::Shot::name);
            (
                "Remove the shot?".to_owned(),
                format!(
                    "{name} leaves the session, with its detection and kernels. The file and its cached results stay on disk: adding the file again brings them back."
                ),
                "Remove",
            )
        }
        super::Confirm::ReplaceChart { chart, .. } => (
            "Replace the chart?".to_owned(),
            format!(
                "A chart of {} × {} squares replaces the session's. Every shot's detection and kernels, measured with the old chart, are set aside and must be measured again (Detect, then Kernels).",
                chart.cols, chart.rows
            ),
            "Replace the chart",
        ),
    };
    let mut answer = None;
    let modal = egui::Modal::new(egui::Id::unique("confirm")).show(ctx, |ui| {
        ui.set_max_width(380.0);
        ui.heading(title);
        ui.add_space(6.0);
        ui.label(text);
        ui.add_space(10.0);
        ui.horizontal(|ui| {
            if ui.button(yes).clicked() {
                answer = Some(true);
            }
            if ui.button("Cancel").clicked() {
                answer = Some(false);
            }
        });
    });
    if answer.is_none() && modal.should_close() {
        answer = Some(false);
    }
    if let Some(yes) = answer {
        out.push(Command::Dialog(DialogCommand::ConfirmAnswer(yes)));
    }
}

/// Every message of this run with its time, newest at the bottom; errors in red.
fn log_ui(window: &Window, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        ui.strong("Log");
        ui.label(match window.log.len() {
            1 => "1 message".to_owned(),
            n => format!("{n} messages"),
        });
        ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
            if ui.small_button("Close").on_hover_text("Ctrl+L").clicked() {
                out.push(Command::Window(WindowCommand::SetLogOpen(false)));
            }
        });
    });
    ui.separator();
    egui::ScrollArea::vertical()
        .auto_shrink([false, false])
        .stick_to_bottom(true)
        .show(ui, |ui| {
            if window.log.is_empty() {
                ui.label(egui::RichText::new("Nothing yet.").weak());
            }
            for m in &window.log {
                ui.horizontal_wrapped(|ui| {
                    ui.monospace(&m.time);
                    let text = egui::RichText::new(&m.text);
                    ui.label(if m.is_error {
                        text.color(ui.visuals().error_fg_color)
                    } else {
                        text
                    });
                });
            }
        });
}

fn dropped_files(view: View, out: &mut Vec<Command>, ctx: &egui::Context) {
    let files: Vec<_> = ctx.input(|i| {
        i.raw
            .dropped_files
            .iter()
            .map(|f| f.path().to_path_buf())
            .filter(|p| !p.as_os_str().is_empty())
            .collect()
    });
    if files.is_empty() {
        return;
    }
    // A photo dropped on the Deblur view is opened there; anywhere else files are shots.
    if view == View::Deblur
        && let [one] = files.as_slice()
    {
        out.push(Command::Deblur(DeblurCommand::OpenPhoto(one.clone())));
    } else {
        out.push(Command::Session(SessionCommand::AddShots(files)));
    }
}

fn top_bar_ui(f: &Frame<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        if ui
            .selectable_label(f.views.session.open, "Session")
            .on_hover_text("Show or fold the session panel (Ctrl+B)")
            .clicked()
        {
            out.push(Command::Window(WindowCommand::SetSessionPanel(
                !f.views.session.open,
            )));
        }
        ui.strong("lensblur studio");
        ui.separator();
        for (k, v) in View::ALL.into_iter().enumerate() {
            if ui
                .selectable_label(f.view == v, v.label())
                .on_hover_text(format!("Alt+{}", k + 1))
                .clicked()
            {
                out.push(Command::View(ViewCommand::SelectView(v)));
            }
        }
        ui.separator();
        ui.label("Channel");
        for c in [Channel::R, Channel::G, Channel::B] {
            if ui
                .selectable_label(f.views.shot.channel == c, c.name())
                .on_hover_text(format!("Alt+{}", c.name()))
                .clicked()
            {
                out.push(Command::View(ViewCommand::SelectChannel(c)));
            }
        }
    });
}

fn status_ui(f: &Frame<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    for h in &f.jobs.running {
        ui.horizontal(|ui| {
            let (stage, frac, counts) = match h.progress() {
                Some(p) if p.total > 0 => (
                    p.stage.clone(),
                    p.done as f32 / p.total as f32,
                    format!("{} / {}", p.done, p.total),
                ),
                Some(p) => (p.stage.clone(), 0.0, String::new()),
                None => ("starting".into(), 0.0, String::new()),
            };
            ui.label(format!("{}: {stage}", h.kind));
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
                out.push(Command::Window(WindowCommand::Cancel(h.id)));
            }
        });
    }
    let mut dismiss = None;
    for (i, m) in f.window.messages.iter().enumerate().rev().take(4) {
        ui.horizontal(|ui| {
            let color = if m.is_error {
                ui.visuals().error_fg_color
            } else {
                ui.visuals().text_color()
            };
            // A notice fades over the last second of its lifetime.
            let color = match f.notice_lifetime {
                Some(life) if !m.is_error => {
                    let left = life.saturating_sub(m.said.elapsed());
                    color.gamma_multiply(
                        (left.as_secs_f32() / super::NOTICE_FADE.as_secs_f32()).min(1.0),
                    )
                }
                _ => color,
            };
            if ui.small_button("×").on_hover_text("Dismiss").clicked() {
                dismiss = Some(i);
            }
            ui.add(egui::Label::new(egui::RichText::new(&m.text).color(color)).truncate())
                .on_hover_text(&m.text);
        });
    }
    if let Some(i) = dismiss {
        out.push(Command::Window(WindowCommand::DismissMessage(i)));
    }
    ui.horizontal(|ui| {
        if f.jobs.running.is_empty() && f.window.messages.is_empty() {
            ui.label("Ready.");
        }
        ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
            let errors = f.window.log.iter().filter(|m| m.is_error).count();
            let label = match errors {
                0 => format!("Log ({})", f.window.log.len()),
                1 => format!("Log ({}, 1 error)", f.window.log.len()),
                e => format!("Log ({}, {e} errors)", f.window.log.len()),
            };
            if ui
                .selectable_label(f.window.log_open, label)
                .on_hover_text("Every message of this run, with its time (Ctrl+L)")
                .clicked()
            {
                out.push(Command::Window(WindowCommand::SetLogOpen(
                    !f.window.log_open,
                )));
            }
        });
    });
}

/// An x axis whose tick labels may stand 28 points apart: egui_plot's default wants 60,
/// which leaves a 300-point plot of f-numbers or model orders with a single label.
fn x_axis<'a>(label: &str) -> egui_plot::AxisHints<'a> {
    egui_plot::AxisHints::new_x()
        .label(label.to_owned())
        .label_spacing(28.0..=40.0)
}

/// An aperture axis: the plot's x is in stops from f/1 and its ticks name the
/// f-numbers a lens marks (f/4, f/4.5, f/5, f/5.6 …).
fn aperture_axis<'a>(label: &str) -> egui_plot::AxisHints<'a> {
    x_axis(label).formatter(|mark, _| crate::review::f_number_label(mark.value))
}

/// Grid lines of an aperture axis in stops: every third of a stop, every stop, every
/// three stops.
fn stops_grid() -> impl Fn(egui_plot::GridInput) -> Vec<egui_plot::GridMark> {
    egui_plot::uniform_grid_spacer(|_| [1.0 / 3.0, 1.0, 3.0])
}

/// A y axis whose tick labels may stand 16 points apart (egui_plot's default, 20, drops
/// every label of a short plot whose range is just over a power of ten).
fn y_axis<'a>(label: &str) -> egui_plot::AxisHints<'a> {
    egui_plot::AxisHints::new_y()
        .label(label.to_owned())
        .label_spacing(16.0..=24.0)
}

/// A plot's title row: the "PNG" and "CSV" save buttons (short, so the title keeps the
/// room), then the title, cut short to the plot's width so that the row never pushes
/// the plots beside it off the window.
fn plot_title_ui(
    commands: &mut Vec<Command>,
    ui: &mut egui::Ui,
    plot: PlotId,
    title: String,
    tip: &str,
    width: f32,
) {
    ui.horizontal_wrapped(|ui| {
        ui.set_max_width(width);
        plot_save_buttons(commands, ui, plot);
        // Whole, on a second line where it must; the hover says what it means.
        ui.add(egui::Label::new(title.clone()).wrap())
            .on_hover_text(format!("{title}\n\n{tip}"));
    });
}

fn plot_save_buttons(commands: &mut Vec<Command>, ui: &mut egui::Ui, plot: PlotId) {
    for (png, label, tip) in [
        (
            true,
            "PNG",
            "Save the plot as it appears here, as a PNG image…",
        ),
        (
            false,
            "CSV",
            "Save the plot's data as CSV: every series' points, with the axes named in the header…",
        ),
    ] {
        if ui.small_button(label).on_hover_text(tip).clicked() {
            commands.push(Command::Dialog(DialogCommand::SavePlotDialog { plot, png }));
        }
    }
}

/// Shows a plot within a scope whose rectangle (plot and axes) is kept in egui's memory:
/// a PNG of the plot is cut from a later screenshot at that place.
fn show_plot<'a, R>(
    ui: &mut egui::Ui,
    id: PlotId,
    plot: egui_plot::Plot<'a>,
    build: impl FnOnce(&mut egui_plot::PlotUi<'a>) -> R + 'a,
) -> R {
    let shown = ui.scope(|ui| plot.show(ui, build).inner);
    let rect = shown.response.rect;
    ui.ctx().data_mut(|d| d.insert_temp(id.rect_id(), rect));
    shown.inner
}

/// White text on a dark box, readable over any image.
fn caption(painter: &egui::Painter, pos: Pos2, align: egui::Align2, text: String) {
    let galley = painter.layout_no_wrap(text, egui::FontId::proportional(12.0), Color32::WHITE);
    let rect = align.anchor_size(pos, galley.size());
    painter.rect_filled(rect.expand(3.0), 3.0, Color32::from_black_alpha(170));
    painter.galley(rect.min, galley, Color32::WHITE);
}

/// The 1-σ ellipse of `g` scaled by `scale` screen points per px, as a closed polyline.
fn ellipse_points(centre: Pos2, g: &Gaussian2, scale: f32) -> Vec<Pos2> {
    crate::review::ellipse_outline(g, 40)
        .into_iter()
        .map(|[x, y]| centre + Vec2::new(x as f32, y as f32) * scale)
        .collect()
}

/// The sliders of the setting the predicted and true fields and the sweeps show, with a
/// tick under each rail at every setting the session has shots at.
/// A shot's or photo's focal length and f-number as two labelled drag values, "?" while
/// unknown (0); `tips` says where each comes from.
fn setting_drag_values(
    ui: &mut egui::Ui,
    (f, a): (&mut f64, &mut f64),
    tips: [&str; 2],
) -> (egui::Response, egui::Response) {
    let value = |ui: &mut egui::Ui, label: &str, tip: &str, v: &mut f64, focal: bool| {
        let l = ui.label(label).on_hover_text(tip);
        let (speed, max) = if focal { (0.5, 5000.0) } else { (0.05, 128.0) };
        ui.add(
            egui::DragValue::new(v)
                .speed(speed)
                .range(0.0..=max)
                .custom_formatter(move |v, _| match (v > 0.0, focal) {
                    (true, true) => format!("{v:.0} mm"),
                    (true, false) => format!("f/{v:.1}"),
                    (false, true) => "? mm".into(),
                    (false, false) => "f/?".into(),
                }),
        )
        .labelled_by(l.id)
    };
    let rf = value(ui, "f", tips[0], f, true);
    let ra = value(ui, "a", tips[1], a, false);
    (rf, ra)
}

/// What the setting sliders show: the ranges they span (the profile's, else the
/// session's, else the demo lens's), where they stand, and the focal lengths and
/// apertures shot (ticks on their rails).
pub(super) struct Sliders<'a> {
    ranges: ([f64; 2], [f64; 2]),
    setting: (f64, f64),
    shot_at: Option<(&'a [f64], &'a [f64])>,
}

impl<'a> Sliders<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            ranges: f.setting_ranges,
            setting: (f.views.field.focal_mm, f.views.field.f_number),
            shot_at: f
                .data
                .calibrated
                .as_ref()
                .filter(|c| !c.focal_mm.is_empty() || !c.f_number.is_empty())
                .map(|c| (c.focal_mm.as_slice(), c.f_number.as_slice())),
        }
    }
}

fn setting_sliders_ui(sliders: &Sliders<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let (f_range, a_range) = sliders.ranges;
    let (mut focal_mm, mut f_number) = sliders.setting;
    let mut changed = false;
    let shot_at = sliders.shot_at;
    ui.horizontal(|ui| {
        let rail_left = ui.cursor().left();
        let r = ui.add(
            egui::Slider::new(&mut focal_mm, f_range[0]..=f_range[1])
                .suffix(" mm")
                .fixed_decimals(0)
                .text("focal length"),
        );
        changed |= r.changed();
        if let Some((f, _)) = &shot_at {
            slider_ticks(ui, rail_left, r.rect, f, f_range, false);
        }
        ui.add_space(12.0);
        let rail_left = ui.cursor().left();
        let r = ui.add(
            egui::Slider::new(&mut f_number, a_range[0]..=a_range[1])
                .prefix("f/")
                .fixed_decimals(1)
                .logarithmic(true)
                .text("aperture"),
        );
        changed |= r.changed();
        if let Some((_, a)) = &shot_at {
            slider_ticks(ui, rail_left, r.rect, a, a_range, true);
        }
        if shot_at.is_some() {
            ui.weak("ticks: settings with shots")
                .on_hover_text("The ticks under the sliders mark the focal lengths and apertures the session has shots at: the model is measured there and interpolates between them.");
        }
    });
    if changed {
        out.push(Command::View(ViewCommand::SetFieldSetting {
            focal_mm,
            f_number,
        }));
    }
}

/// Ticks under a slider's rail (it starts at `rail_left` and is as wide as the style's
/// slider width) at `values`, placed as the slider places its handle (linear, or in
/// stops for a logarithmic one).
fn slider_ticks(
    ui: &egui::Ui,
    rail_left: f32,
    row: Rect,
    values: &[f64],
    range: [f64; 2],
    logarithmic: bool,
) {
    let width = ui.spacing().slider_width;
    // The handle's centre stays a handle's radius inside the rail's ends.
    let inset = row.height() / 2.5;
    let (lo, hi) = (rail_left + inset, rail_left + width - inset);
    let color = ui.visuals().strong_text_color();
    for &v in values {
        let t = if logarithmic {
            (v / range[0]).ln() / (range[1] / range[0]).ln()
        } else {
            (v - range[0]) / (range[1] - range[0])
        };
        if !(0.0..=1.0).contains(&t) {
            continue;
        }
        let x = lo + (hi - lo) * t as f32;
        let y = row.bottom();
        ui.painter().add(egui::Shape::convex_polygon(
            vec![
                Pos2::new(x, y - 4.0),
                Pos2::new(x - 3.5, y + 1.0),
                Pos2::new(x + 3.5, y + 1.0),
            ],
            color,
            egui::Stroke::NONE,
        ));
    }
}

/// Behind an image or a map: near black in the dark theme, near white in the light
/// one, so the frame reads as the window's own backdrop in either.
pub(super) fn image_backdrop(ui: &egui::Ui) -> egui::Color32 {
    if ui.visuals().dark_mode {
        egui::Color32::from_gray(20)
    } else {
        egui::Color32::from_gray(228)
    }
}
