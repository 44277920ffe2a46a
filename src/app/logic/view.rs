//! Commands that change what the views show and the window around them.

use crate::app::StudioApp;
use crate::app::{ViewCommand, WindowCommand};

/// Selections and view options: what is shown, not what is measured.
pub(super) fn apply_view(app: &mut StudioApp, command: ViewCommand) {
    match command {
        ViewCommand::SelectView(v) => app.view = v,
        ViewCommand::SelectShot(i) => {
            app.views.shot.selected = Some(i);
            app.views.shot.square = None;
            app.views.shot.viewer.sensor_px_per_point = None;
        }
        ViewCommand::SelectChannel(c) => app.views.shot.channel = c,
        ViewCommand::ClearSquare => app.views.shot.square = None,
        ViewCommand::SelectSquare(sq) => app.views.shot.square = Some(sq),
        ViewCommand::SetFieldSource(f) => app.views.field.source = f,
        ViewCommand::SetFieldShow(f) => app.views.field.show = f,
        ViewCommand::SetSweepAxis(a) => app.views.sweeps.axis = a,
        ViewCommand::SetSharpness(s) => app.views.sharpness = s,
        ViewCommand::SetPlanRange(r) => app.views.session.plan_range = Some(r),
        ViewCommand::SetFieldSetting { focal_mm, f_number } => {
            app.views.field.focal_mm = focal_mm;
            app.views.field.f_number = f_number;
        }
        ViewCommand::SetCompareUnits(on) => app.views.field.compare_units = on,
        ViewCommand::SetFieldOptions(o) => app.views.field.options = o,
        ViewCommand::SetViewer(v) => app.views.shot.viewer = v,
        ViewCommand::SetGeometryFocal(f) => {
            app.views.geometry.focal_mm = Some(f);
            app.views.geometry.f_number = None;
        }
        ViewCommand::SetGeometryAperture(a) => app.views.geometry.f_number = Some(a),
    }
}

/// The window itself: jobs cancelled, theme, messages, panels, quitting.
pub(super) fn apply_window(app: &mut StudioApp, command: WindowCommand) {
    match command {
        WindowCommand::Cancel(id) => app.jobs.cancel(id),
        WindowCommand::CancelAll => {
            for h in &app.jobs.running {
                h.cancel();
            }
        }
        WindowCommand::SetDark(dark) => {
            app.window.dark = dark;
            app.ctx.set_theme(if dark {
                egui::Theme::Dark
            } else {
                egui::Theme::Light
            });
        }
        WindowCommand::DismissMessage(i) => {
            if i < app.window.messages.len() {
                app.window.messages.remove(i);
            }
        }
        WindowCommand::SetLogOpen(open) => app.window.log_open = open,
        WindowCommand::SetSessionPanel(open) => app.views.session.open = open,
        WindowCommand::ShowHelp(open) => app.window.show_help = open,
        WindowCommand::ShowGuide(open) => app.window.show_guide = open,
        WindowCommand::ShowAbout(open) => app.window.show_about = open,
        WindowCommand::Quit => app.ctx.send_viewport_cmd(egui::ViewportCommand::Close),
    }
}

/// Notices leave the status line once their lifetime is over; errors stay until
/// dismissed, and the log keeps both.
pub(in crate::app) fn expire_notices(app: &mut StudioApp) {
    if let Some(life) = app.options.notice_lifetime {
        app.window
            .messages
            .retain(|m| m.is_error || m.said.elapsed() < life);
    }
}
