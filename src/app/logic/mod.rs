//! Applies commands, drains finished jobs and keeps the session saved: owns every
//! change to the app's state, and makes the textures of results when they arrive
//! (shot previews, the photo, deblurred crops). What the views derive from that state
//! is `view_data`'s. Never draws.
//!
//! [`apply`] routes each command to the function of its concern, as [`drain_jobs`] does
//! each job's output: `view` (selections, the window), `session` (shots, settings,
//! opening), `shots` (loading them for display), `stages` (detect, kernels, calibrate),
//! `deblur` (the Deblur view and exports), `plots` (saving plots) and `dialogs` (file
//! dialogs and confirmations).

mod autorun;
mod deblur;
mod dialogs;
mod geometry;
mod inspect;
mod plots;
mod session;
mod shots;
mod stages;
mod view;

use super::jobs::{JobEnd, JobEvent, JobKind};
use super::{Command, JobOutput, StudioApp};
use crate::app::StageOutput;
use deblur::run_deblur_preview;
use stages::spawn_dataset;

pub(super) use autorun::autorun_step;
pub(crate) use deblur::deblur_method;
pub(super) use dialogs::{Dialogs, drain_dialogs};
pub(super) use plots::finish_plot_png;
pub(super) use shots::ensure_preview;
pub(super) use stages::shot_event;
pub(super) use view::expire_notices;

use crate::project::{CV_FILE, ShotEvent};

/// Applies one command, in the handler of its group (each matches its group whole).
pub(super) fn apply(app: &mut StudioApp, command: Command) {
    match command {
        Command::View(c) => view::apply_view(app, c),
        Command::Window(c) => view::apply_window(app, c),
        Command::Session(c) => session::apply_session(app, c),
        Command::Stage(c) => stages::apply_stage(app, c),
        Command::Deblur(c) => deblur::apply_deblur(app, c),
        Command::Plot(c) => plots::apply_plot(app, c),
        Command::Geometry(c) => geometry::apply_geometry(app, c),
        Command::Dialog(c) => dialogs::apply_dialog(app, c),
    }
}

/// Applies one job's output, in the handler of its group.
fn apply_output(app: &mut StudioApp, output: JobOutput) {
    match output {
        JobOutput::Session(o) => session::session_output(app, o),
        JobOutput::Shots(o) => shots::shot_output(app, o),
        JobOutput::Stage(o) => stages::stage_output(app, o),
        JobOutput::Deblur(o) => deblur::deblur_output(app, o),
        JobOutput::Geometry(o) => geometry::geometry_output(app, o),
        JobOutput::SquareInspected { key, result } => inspect::inspected(app, key, result),
    }
}

pub(super) fn drain_jobs(app: &mut StudioApp) {
    for event in app.jobs.drain() {
        match event {
            JobEvent::Output {
                job,
                session,
                output,
            } => {
                // A result for a session that has since been closed is not this one's.
                if session.is_none_or(|g| g == app.session_generation) {
                    tally(app, job, &output);
                    apply_output(app, output);
                }
            }
            JobEvent::Finished { job, kind, end } => {
                let tally = app.tallies.remove(&job);
                match &end {
                    // A preview cancelled by a newer one (a control being dragged) is
                    // not news: the newer one's result follows.
                    JobEnd::Cancelled if kind == JobKind::DeblurPreview => {}
                    JobEnd::Cancelled => {
                        let done =
                            tally.map_or(String::new(), |t| match t.ok.len() + t.failed.len() {
                                1 => " after 1 shot".to_owned(),
                                n => format!(" after {n} shots"),
                            });
                        app.info(format!("{kind}: cancelled{done}"));
                    }
                    JobEnd::Failed(e) => app.error(e.clone()),
                    JobEnd::Done => {
                        if let Some(t) = tally {
                            finished_message(app, kind, &t);
                        }
                    }
                }
                match kind {
                    JobKind::Kernels => spawn_dataset(app),
                    JobKind::Geometry => geometry_ended(app, end),
                    JobKind::DemoSession => session::calibrate_demo(app),
                    JobKind::DeblurPreview => {
                        if let Some(centre) = app.views.deblur.pending.take() {
                            run_deblur_preview(app, centre);
                        }
                    }
                    _ => {}
                }
            }
        }
    }
}

/// The jobs the app starts of itself once a step's commands and job outputs are
/// applied: the crops of the square the selection names, and the lens's geometry of
/// new detections.
pub(super) fn follow_up(app: &mut StudioApp) {
    inspect::request_inspection(app);
    geometry::measure_geometry(app);
}

/// A geometry job that ended without handing its result back leaves its reason as the
/// result, so it is not run again until the detections change.
fn geometry_ended(app: &mut StudioApp, end: JobEnd) {
    let reason = match end {
        JobEnd::Done => return,
        JobEnd::Cancelled => "the measurement of the lens's geometry was cancelled".to_owned(),
        JobEnd::Failed(e) => e,
    };
    if let Some(p) = app.project.as_mut() {
        p.geometry_abandoned(reason);
    }
}

/// Counts a detect or kernels job's shots as they come back.
fn tally(app: &mut StudioApp, job: u64, output: &JobOutput) {
    let (id, failure) = match output {
        JobOutput::Stage(StageOutput::Shot(
            ShotEvent::Detected { id, .. } | ShotEvent::Measured { id, .. },
        )) => (*id, None),
        JobOutput::Stage(StageOutput::Shot(ShotEvent::Failed { id, reason, .. })) => {
            (*id, Some(reason))
        }
        _ => return,
    };
    let name = app
        .session()
        .and_then(|s| s.shot(id))
        .map_or_else(|| format!("shot {}", id.0), crate::session::Shot::name);
    let reason = failure.map(|e| {
        let e = app.shorten_paths(e.clone());
        // The core names the file first; the message names it once.
        e.strip_prefix(&format!("{name}: "))
            .map_or_else(|| e.clone(), str::to_owned)
    });
    let t = app.tallies.entry(job).or_default();
    match reason {
        Some(r) => {
            t.ok.remove(&id);
            t.failed.push((name, r));
        }
        None => {
            t.ok.insert(id);
        }
    }
}

/// "Measured kernels for 9 shots (1 failed: IMG_3.png — no chart found)".
fn finished_message(app: &mut StudioApp, job: JobKind, t: &super::Tally) {
    let n = t.ok.len() + t.failed.len();
    let shots = if n == 1 {
        "1 shot".to_owned()
    } else {
        format!("{n} shots")
    };
    let what = match job {
        JobKind::Detect => format!("Detected the chart in {shots}"),
        JobKind::Kernels => format!("Measured kernels for {shots}"),
        JobKind::CalibrateAll if n == 0 => return,
        JobKind::CalibrateAll => format!("Calibrate all: measured {shots}"),
        _ => return,
    };
    if t.failed.is_empty() {
        app.info(what);
    } else {
        let failed: Vec<String> = t
            .failed
            .iter()
            .map(|(name, reason)| format!("{name} — {reason}"))
            .collect();
        app.error(format!(
            "{what} ({} failed: {})",
            t.failed.len(),
            failed.join("; ")
        ));
    }
}

/// Hands the session to the project's writer (it is written off this thread); an
/// earlier write that failed is said.
pub(super) fn save(app: &mut StudioApp) {
    if let Some(p) = &app.project
        && let Err(e) = p.save()
    {
        app.error(e.to_string());
    }
}
