//! Commands that change what the views show and the window around them.

use crate::app::{Command, StudioApp};

/// Selections and view options: what is shown, not what is measured.
pub(super) fn apply_view(app: &mut StudioApp, command: Command) {
    match command {
        Command::SelectView(v) => app.view = v,
        Command::SelectShot(i) => {
            app.selected_shot = Some(i);
            app.selected_square = None;
            app.viewer.sensor_px_per_point = None;
        }
        Command::SelectChannel(c) => app.channel = c,
        Command::ClearSquare => app.selected_square = None,
        Command::SelectSquare(sq) => app.selected_square = Some(sq),
        Command::SetFieldSource(f) => app.field_source = f,
        Command::SetFieldShow(f) => app.field_show = f,
        Command::SetSweepAxis(a) => app.sweep_axis = a,
        Command::SetSharpness(s) => app.sharpness = s,
        Command::SetPlanRange(r) => app.plan_range = Some(r),
        Command::SetFieldSetting { focal_mm, f_number } => {
            app.field_focal_mm = focal_mm;
            app.field_f_number = f_number;
        }
        Command::SetCompareUnits(on) => app.compare_units = on,
        Command::SetFieldOptions(o) => app.field_options = o,
        Command::SetViewer(v) => app.viewer = v,
        Command::SetGeometryFocal(f) => {
            app.geometry_focal_mm = Some(f);
            app.geometry_f_number = None;
        }
        Command::SetGeometryAperture(a) => app.geometry_f_number = Some(a),
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
            app.dark = dark;
            app.ctx.set_theme(if dark {
                egui::Theme::Dark
            } else {
                egui::Theme::Light
            });
        }
        Command::DismissMessage(i) => {
            if i < app.messages.len() {
                app.messages.remove(i);
            }
        }
        Command::SetLogOpen(open) => app.log_open = open,
        Command::SetSessionPanel(open) => app.session_panel_open = open,
        Command::ShowHelp(open) => app.show_help = open,
        Command::ShowGuide(open) => app.show_guide = open,
        Command::ShowAbout(open) => app.show_about = open,
        Command::Quit => app.ctx.send_viewport_cmd(egui::ViewportCommand::Close),
        // `apply` routes only this group's commands here.
        other => unreachable!("not routed to apply_window: {other:?}"),
    }
}

/// Notices leave the status line once their lifetime is over; errors stay until
/// dismissed, and the log keeps both.
pub(in crate::app) fn expire_notices(app: &mut StudioApp) {
    if let Some(life) = app.options.notice_lifetime {
        app.messages
            .retain(|m| m.is_error || m.said.elapsed() < life);
    }
}
