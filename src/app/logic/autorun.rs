//! What runs by itself: the frame log's first-shot and readiness lines
//! (`LENSBLUR_FRAME_LOG`), and the stages `LENSBLUR_AUTORUN` asks for, one after
//! another, for measuring frame times under load.

use crate::app::jobs::JobKind;
use crate::app::{Command, DeblurLayout, DeblurZoom, FrameLog, StudioApp, View};
use crate::app::{DeblurCommand, StageCommand, ViewCommand};
use std::path::PathBuf;

/// Once per frame, after the commands: logs readiness, starts the next autorun stage
/// once the previous job ended, and moves the autorun's strength drag on.
pub(in crate::app) fn autorun_step(app: &mut StudioApp) {
    log_readiness(app);
    if app.trace.ready_logged && app.jobs.running.is_empty() && !app.options.autorun.is_empty() {
        next_stage(app);
    }
    drag_strength(app);
}

/// The first shot shown, and every shot loaded (or found unreadable).
fn log_readiness(app: &mut StudioApp) {
    let ready = !app.jobs.is_running(JobKind::DemoSession)
        && app
            .session()
            .is_some_and(|s| !s.shots.is_empty() && app.shots_shown() == s.shots.len());
    if !app.trace.first_shot_logged && app.previews().next().is_some() {
        app.trace.first_shot_logged = true;
        if app.options.log_frame_times {
            eprintln!(
                "studio: first shot shown after {:.2} s",
                app.options.started.elapsed().as_secs_f32()
            );
        }
    }
    // The first launch's end: the demo calibrated and its photo before and after.
    let shown = app.view == crate::app::View::Deblur
        && app.profile().is_some()
        && app
            .views
            .deblur
            .comparison
            .as_ref()
            .is_some_and(|c| c.comparison.predicted.is_ok());
    if shown && !app.trace.before_after_logged {
        app.trace.before_after_logged = true;
        if app.options.log_frame_times {
            eprintln!(
                "studio: before/after shown after {:.2} s",
                app.options.started.elapsed().as_secs_f32()
            );
        }
    }
    if ready && !app.trace.ready_logged {
        app.trace.ready_logged = true;
        if app.options.log_frame_times {
            let n = app.session().map_or(0, |s| s.shots.len());
            eprintln!(
                "studio: ready: {n} shots loaded after {:.2} s",
                app.options.started.elapsed().as_secs_f32()
            );
        }
    }
}

/// Starts the autorun's next stage (or puts it back until it can start).
fn next_stage(app: &mut StudioApp) {
    let stage = app.options.autorun.remove(0);
    match stage.as_str() {
        "detect" => app
            .commands
            .push(Command::Stage(StageCommand::RunDetect(None))),
        "kernels" => app
            .commands
            .push(Command::Stage(StageCommand::RunKernels(None))),
        "calibrate" => app
            .commands
            .push(Command::Stage(StageCommand::RunCalibrate)),
        // The Deblur view at 100 % in the slider layout (one pane as large as
        // the window allows) on LENSBLUR_PHOTO, else the first shot.
        "deblur" => {
            let photo = std::env::var_os("LENSBLUR_PHOTO")
                .map(PathBuf::from)
                .or_else(|| {
                    let s = app.session()?;
                    Some(s.path_of(s.shots.first()?))
                });
            if let Some(p) = photo {
                app.commands
                    .push(Command::View(ViewCommand::SelectView(View::Deblur)));
                app.commands
                    .push(Command::Deblur(DeblurCommand::SetDeblurLayout(
                        DeblurLayout::Slider,
                    )));
                app.commands
                    .push(Command::Deblur(DeblurCommand::SetDeblurZoom(
                        DeblurZoom::Times(1),
                    )));
                app.commands
                    .push(Command::Deblur(DeblurCommand::OpenPhoto(p)));
            }
        }
        // The strength slider dragged for 300 frames, as a hand would: frame
        // times are then those of a live control.
        "drag-strength" => {
            // Once the region fills the panes at 100 % (else next frame).
            let filled = match (&app.views.deblur.comparison, &app.views.deblur.photo) {
                (Some(c), Some(p)) => app.views.deblur.viewport.is_some_and(|[w, h]| {
                    let r = c.comparison.region;
                    r.width == w.min(p.capture.width) & !1
                        && r.height == h.min(p.capture.height) & !1
                }),
                _ => false,
            };
            if filled {
                app.trace.frames = FrameLog::default();
                app.autorun.drag_frames = 300;
                if let Some(c) = &app.views.deblur.comparison {
                    let r = c.comparison.region;
                    eprintln!(
                        "studio: dragging the strength on a {} × {} region",
                        r.width, r.height
                    );
                }
            } else {
                app.options.autorun.insert(0, stage);
            }
        }
        other => app.error(format!("LENSBLUR_AUTORUN: unknown stage '{other}'")),
    }
}

/// The strength slider dragged for 300 frames, as a hand would.
fn drag_strength(app: &mut StudioApp) {
    if app.autorun.drag_frames > 0 {
        app.autorun.drag_frames -= 1;
        let k = app.autorun.drag_frames as f64;
        let lambda = 3000.0 * 10f64.powf((k / 25.0).sin());
        app.commands
            .push(Command::Deblur(DeblurCommand::SetDeblurMethod(
                crate::deblur::Method::Hqs(crate::deblur::HqsParams {
                    lambda,
                    ..Default::default()
                }),
            )));
    }
}
