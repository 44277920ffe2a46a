//! Commands that change what the views show and the window around them.

use crate::app::{Command, StudioApp};

/// Selections and view options: what is shown, not what is measured.
pub(super) fn apply_view(app: &mut StudioApp, command: Command) {
    match command {
        Command::SelectView(v) => app.view = v,
        Command::SelectShot(i) => {
            app.views.shot.selected = Some(i);
            app.views.shot.square = None;
            app.views.shot.viewer.sensor_px_per_point = None;
        }
        Command::SelectChannel(c) => app.views.shot.channel = c,
        Command::ClearSquare => app.views.shot.square = None,
        Command::SelectSquare(sq) => app.views.shot.square = Some(sq),
        Command::SetFieldSource(f) => app.views.field.source = f,
        Command::SetFieldShow(f) => app.views.field.show = f,
        Command::SetSweepAxis(a) => app.views.sweeps.axis = a,
        Command::SetSharpness(s) => app.views.sharpness = s,
        Command::SetPlanRange(r) => app.views.session.plan_range = Some(r),
        Command::SetFieldSetting { focal_mm, f_number } => {
            app.views.field.focal_mm = focal_mm;
            app.views.field.f_number = f_number;
        }
        Command::SetCompareUnits(on) => app.views.field.compare_units = on,
        Command::SetFieldOptions(o) => app.views.field.options = o,
        Command::SetViewer(v) => app.views.shot.viewer = v,
        Command::SetGeometryFocal(f) => {
            app.views.geometry.focal_mm = Some(f);
            app.views.geometry.f_number = None;
        }
        Command::SetGeometryAperture(a) => app.views.geometry.f_number = Some(a),
        // `apply` routes only this group's commands here.
        other => unreachable!("not routed to apply_view: {other:?}"),
    }
}

/// The window itself: jobs cancelled, theme, messages, panels, quitting.
pub(super) fn apply_window(app: &mut StudioApp, command: Command) {
    match command {
        Command::Cancel(id) => app.jobs.cancel(id),
        Command::CancelAll => {
            for h in &app.jobs.running {
                h.cancel();
            }
        }
        Command::SetDark(dark) => {
            app.window.dark = dark;
            app.ctx.set_theme(if dark {
                egui::Theme::Dark
            } else {
                egui::Theme::Light
            });
        }
        Command::DismissMessage(i) => {
            if i < app.window.messages.len() {
                app.window.messages.remove(i);
            }
        }
        Command::SetLogOpen(open) => app.window.log_open = open,
        Command::SetSessionPanel(open) => app.views.session.open = open,
        Command::ShowHelp(open) => app.window.show_help = open,
        Command::ShowGuide(open) => app.window.show_guide = open,
        Command::ShowAbout(open) => app.window.show_about = open,
        Command::Quit => app.ctx.send_viewport_cmd(egui::ViewportCommand::Close),
        // `apply` routes only this group's commands here.
        other => unreachable!("not routed to apply_window: {other:?}"),
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
