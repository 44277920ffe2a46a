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
mod plots;
mod session;
mod shots;
mod stages;
mod view;

use super::jobs::{JobEnd, JobEvent, JobKind};
use super::view_data;
use super::{Command, JobOutput, StudioApp};
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

/// Applies one command, in the function of its concern.
pub(super) fn apply(app: &mut StudioApp, command: Command) {
    match command {
        Command::SelectView(_)
        | Command::SelectShot(_)
        | Command::SelectChannel(_)
        | Command::ClearSquare
        | Command::SelectSquare(_)
        | Command::SetFieldSource(_)
        | Command::SetFieldShow(_)
        | Command::SetSweepAxis(_)
        | Command::SetSharpness(_)
        | Command::SetFieldSetting { .. }
        | Command::SetCompareUnits(_)
        | Command::SetFieldOptions(_)
        | Command::SetViewer(_)
        | Command::SetGeometryFocal(_)
        | Command::SetGeometryAperture(_)
        | Command::SetPlanRange(_) => view::apply_view(app, command),
        Command::Cancel(_)
        | Command::CancelAll
        | Command::SetDark(_)
        | Command::DismissMessage(_)
        | Command::SetLogOpen(_)
        | Command::SetSessionPanel(_)
        | Command::ShowHelp(_)
        | Command::ShowGuide(_)
        | Command::ShowAbout(_)
        | Command::Quit => view::apply_window(app, command),
        Command::AddShots(_)
        | Command::RemoveShot(_)
        | Command::SetShotSetting { .. }
        | Command::ApplySettings { .. }
        | Command::LoadChart(_)
        | Command::EditSettings(_)
        | Command::OpenSession(_) => session::apply_session(app, command),
        Command::RunDetect(_)
        | Command::RunKernels(_)
        | Command::RunCalibrate
        | Command::CalibrateAll { .. }
        | Command::LoadProfile { .. }
        | Command::SaveProfile(_)
        | Command::SaveProfileToLibrary => stages::apply_stage(app, command),
        Command::OpenPhoto(_)
        | Command::SetPhotoSetting { .. }
        | Command::DeblurAt(_)
        | Command::SetDeblurLayout(_)
        | Command::SetDeblurZoom(_)
        | Command::SetDeblurViewport(_)
        | Command::SetDeblurCrop(_)
        | Command::SetDeblurMethod(_)
        | Command::SetDeblurAmount(_)
        | Command::SetDeblurFringes(_)
        | Command::SetDeblurLateral(_)
        | Command::SetDeblurOverview(_)
        | Command::SetDeblurDevice(_)
        | Command::DragDeblur(_)
        | Command::EndDragDeblur
        | Command::SetSliderResult(_)
        | Command::SetSlider(_)
        | Command::ExportDeblur { .. }
        | Command::ExportPhotos { .. } => deblur::apply_deblur(app, command),
        Command::SavePlotCsv { .. }
        | Command::SavePlotPng { .. }
        | Command::SaveSharpness { .. } => plots::apply_plot(app, command),
        Command::ExportLensfun(_) => geometry::apply_geometry(app, command),
        Command::AddShotsDialog
        | Command::LoadChartDialog
        | Command::OpenPhotoDialog
        | Command::ExportDeblurDialog(_)
        | Command::ExportPhotosDialog { .. }
        | Command::LoadProfileDialog
        | Command::SaveProfileDialog
        | Command::SavePlotDialog { .. }
        | Command::SaveSharpnessDialog { .. }
        | Command::ExportLensfunDialog
        | Command::OpenSessionDialog
        | Command::AskConfirm(_)
        | Command::ConfirmAnswer(_)
        | Command::LoadCompareProfileDialog => dialogs::apply_dialog(app, command),
    }
}

/// Applies one job's output, in the function of its job's concern.
fn apply_output(app: &mut StudioApp, output: JobOutput) {
    match output {
        JobOutput::DemoShot(_) | JobOutput::DemoReady(_) | JobOutput::ResultsRead { .. } => {
            session::session_output(app, output)
        }
        JobOutput::ShotLoaded { .. } | JobOutput::ShotUnreadable { .. } => {
            shots::shot_output(app, output)
        }
        JobOutput::Shot(_)
        | JobOutput::DatasetReady(_)
        | JobOutput::Calibrated { .. }
        | JobOutput::ProfileLoaded { .. } => stages::stage_output(app, output),
        JobOutput::PhotoLoaded { .. }
        | JobOutput::DeblurCompared { .. }
        | JobOutput::DeblurExported(_)
        | JobOutput::PhotosExported(_) => deblur::deblur_output(app, output),
        JobOutput::SquareInspected { key, result } => view_data::inspected(app, key, result),
        JobOutput::GeometryMeasured { .. } | JobOutput::LensfunExported { .. } => {
            geometry::geometry_output(app, output);
        }
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
                match end {
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
                    JobEnd::Failed(e) => app.error(e),
                    JobEnd::Done => {
                        if let Some(t) = tally {
                            finished_message(app, kind, &t);
                        }
                    }
                }
                match kind {
                    JobKind::Kernels => spawn_dataset(app),
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

/// Counts a detect or kernels job's shots as they come back.
fn tally(app: &mut StudioApp, job: u64, output: &JobOutput) {
    let (id, failure) = match output {
        JobOutput::Shot(ShotEvent::Detected { id, .. } | ShotEvent::Measured { id, .. }) => {
            (*id, None)
        }
        JobOutput::Shot(ShotEvent::Failed { id, reason, .. }) => (*id, Some(reason)),
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
