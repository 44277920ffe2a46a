//! The stages run on job threads (detect, kernels, calibrate, the dataset the sweeps
//! read) and what they hand back.

use super::save;
use crate::app::jobs::{JobKind, JobScope};
use crate::app::{Command, JobOutput, StudioApp};
use crate::app::{DeblurCommand, StageCommand, StageOutput, ViewCommand};
use crate::project::{CV_FILE, MeasurePlan, PROFILE_FILE, Project, ShotEvent, Stages};
use crate::session::ShotId;
use std::path::PathBuf;
use std::sync::Arc;

/// The stages: detect, kernels, calibrate, and the profile they make.
pub(super) fn apply_stage(app: &mut StudioApp, command: StageCommand) {
    match command {
        StageCommand::RunDetect(which) => run_detect(app, which),
        StageCommand::RunKernels(which) => run_kernels(app, which),
        StageCommand::RunCalibrate => run_calibrate(app),
        StageCommand::CalibrateAll { then_deblur } => calibrate_all(app, then_deblur),
        StageCommand::LoadProfile { path, compare } => {
            let r = app.jobs.spawn(JobKind::LoadProfile, move |_ctx, out| {
                let profile = crate::profile::Profile::load(&path).map_err(|e| e.to_string())?;
                out.emit(JobOutput::Stage(StageOutput::ProfileLoaded {
                    profile: Arc::new(profile),
                    path,
                    compare,
                }));
                Ok(())
            });
            if let Err(e) = r {
                app.error(e);
            }
        }
        StageCommand::SaveProfile(path) => {
            let Some((_, profile)) = app.profile().cloned() else {
                app.error("no profile to save: calibrate first (Ctrl+M) or load one");
                return;
            };
            match profile.save(&path) {
                Ok(()) => app.info(format!("profile saved to {}", app.shown_path(&path))),
                Err(e) => app.error(e.to_string()),
            }
        }
        StageCommand::SaveProfileToLibrary => {
            let Some((_, profile)) = app.profile().cloned() else {
                app.error("no profile to save: calibrate first (Ctrl+M) or load one");
                return;
            };
            let dir = app.profile_library().to_path_buf();
            match crate::batch::ProfileLibrary::save_into(&dir, &profile) {
                Ok(saved) => app.info(format!(
                    "profile saved to the library: {}{}; a batch finds it there (lensblur deblur PHOTOS --out-dir OUT --profiles {})",
                    app.shown_path(&saved.path),
                    if saved.replaced {
                        " (this lens's previous profile kept beside it as .previous)"
                    } else {
                        ""
                    },
                    dir.display()
                )),
                Err(e) => app.error(format!("{}: {e}", app.shown_path(&dir))),
            }
        }
        StageCommand::SetProfileLibrary(dir) => {
            let remembered = app
                .options
                .settings_file
                .as_deref()
                .map(|file| crate::recent::choose_profile_library(file, &dir));
            let shown = app.shown_path(&dir);
            match remembered {
                Some(Err(e)) => app.error(format!("{shown}: the profile library is used, but {e}")),
                _ => app.info(format!(
                    "profile library: {shown}; a batch reads it (lensblur deblur PHOTOS --out-dir OUT)"
                )),
            }
            app.options.profile_library = dir;
        }
    }
}

/// Results of the stages, shot by shot, and of calibration.
pub(super) fn stage_output(app: &mut StudioApp, output: StageOutput) {
    match output {
        StageOutput::Shot(event) => shot_event(app, &event),
        StageOutput::DatasetReady(ds) => {
            if let Some(p) = app.project.as_mut() {
                p.set_dataset(ds);
            }
        }
        StageOutput::Calibrated {
            dataset,
            profile,
            cv,
            path,
        } => calibrated(app, dataset, profile, cv, path),
        StageOutput::ProfileLoaded {
            profile,
            path,
            compare,
        } => {
            let shown = app.shown_path(&path);
            let Some(p) = app.project.as_mut() else {
                return;
            };
            p.use_profile(path, profile, compare);
            app.info(format!("profile {shown} loaded"));
            if !compare {
                super::deblur::redeblur(app);
            }
        }
    }
}

/// Calibration finished: the profile saved in the session and in use.
fn calibrated(
    app: &mut StudioApp,
    dataset: Arc<crate::model::Dataset>,
    profile: Arc<crate::profile::Profile>,
    cv: Option<Arc<crate::crossval::CvReport>>,
    path: PathBuf,
) {
    let kind = match profile.preferred {
        crate::model::ModelKind::Global => "global",
        crate::model::ModelKind::Local => "local",
    };
    app.info(format!(
        "calibrated on {} samples from {} shots; {kind} model preferred; profile saved to {}",
        dataset.samples.len(),
        dataset.shots.len(),
        app.shown_path(&path)
    ));
    if let Some(p) = app.project.as_mut() {
        p.use_calibration(path, dataset, profile, cv);
    }
    // The open photo's region, deblurred with the new profile.
    super::deblur::redeblur(app);
    if std::mem::take(&mut app.autorun.deblur_when_calibrated) {
        // The photo before and after at 100 %, one pane as large as the window allows.
        app.commands.extend([
            Command::View(ViewCommand::SelectView(crate::app::View::Deblur)),
            Command::Deblur(DeblurCommand::SetDeblurLayout(
                crate::app::DeblurLayout::Slider,
            )),
            Command::Deblur(DeblurCommand::SetDeblurZoom(crate::app::DeblurZoom::Times(
                1,
            ))),
            Command::Deblur(DeblurCommand::SetDeblurOverview(false)),
        ]);
    }
    save(app);
}

/// One shot's step in a detect or kernels job: recorded in the project (a removed
/// shot's is dropped), its failure said, the session saved.
pub(in crate::app) fn shot_event(app: &mut StudioApp, event: &ShotEvent) {
    let Some(p) = app.project.as_mut() else {
        return;
    };
    if !p.record(event) {
        return;
    }
    match event {
        ShotEvent::Failed { reason, .. } => {
            let reason = app.shorten_paths(reason.clone());
            app.error(reason);
        }
        ShotEvent::Detected { .. } | ShotEvent::Measured { .. } => {}
        ShotEvent::Started { .. } | ShotEvent::Cancelled { .. } => return,
    }
    save(app);
}

/// Runs the stages of `plan` on a job thread, shot after shot (each shot's work is
/// itself parallel), leaving out shots the window could not read; each shot's steps
/// come back as they happen. `what` is the job: detection or kernels.
fn run_measure(app: &mut StudioApp, what: JobKind, plan: &MeasurePlan) -> usize {
    let Some(p) = app.project.as_ref() else {
        return 0;
    };
    let job = p
        .measure_job(plan)
        .retain(|id| plan.only.is_some() || app.unreadable(id).is_none())
        .with_captures(|id| app.preview(id).map(|v| Arc::clone(&v.capture)));
    let ids = job.shots();
    if ids.is_empty() {
        return 0;
    }
    let scope = JobScope::shots(app.session_generation, ids.clone());
    let r = app.jobs.spawn_scoped(what, scope, move |ctx, out| {
        job.run(ctx, &|id| out.shot_context(ctx, id), &mut |e| {
            out.emit(JobOutput::Stage(StageOutput::Shot(e)));
        })
        .map_err(|e| e.to_string())
    });
    if let Err(e) = r {
        app.error(e);
    }
    ids.len()
}

/// Detection of the chosen shot (again), or of every shot not yet detected.
fn run_detect(app: &mut StudioApp, which: Option<ShotId>) {
    if app.jobs.is_running(JobKind::Detect) {
        app.info("detection is already running");
        return;
    }
    let plan = match which {
        Some(id) => MeasurePlan::again(Stages::Detect, vec![id]),
        None => MeasurePlan::missing(Stages::Detect),
    };
    if run_measure(app, JobKind::Detect, &plan) == 0 {
        app.info(
            "every shot is already detected (right-click a shot and choose Detect this shot again to redo it)",
        );
    }
}

/// The session's measured Gaussians over every shot with kernels and known settings,
/// for the sweeps (rebuilt when kernels or settings change).
pub(super) fn spawn_dataset(app: &mut StudioApp) {
    let Some(job) = app.project.as_mut().and_then(Project::dataset_job) else {
        return;
    };
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped(JobKind::GatherMeasurements, scope, move |_ctx, out| {
            match job.run() {
                Ok(ds) => out.emit(JobOutput::Stage(StageOutput::DatasetReady(Some(Arc::new(
                    ds,
                ))))),
                Err(e) => {
                    out.emit(JobOutput::Stage(StageOutput::DatasetReady(None)));
                    return Err(e.to_string());
                }
            }
            Ok(())
        });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Fits the models over every shot with measured kernels and writes the profile into
/// the session folder; cross-validation chooses α and β unless the settings fix them.
fn run_calibrate(app: &mut StudioApp) {
    if app.jobs.is_running(JobKind::Calibrate) {
        app.info("calibration is already running");
        return;
    }
    let Some(p) = app.project.as_ref() else {
        return;
    };
    let opts = crate::calibrate::CalibrateOptions {
        alpha: p.session().settings.alpha,
        beta: p.session().settings.beta,
        ..Default::default()
    };
    let job = match p.calibration_job(opts) {
        Ok(job) => job,
        Err(_) => {
            app.error("calibration needs kernels on at least two shots: run Detect (Ctrl+D) and Kernels (Ctrl+K) first");
            return;
        }
    };
    let folder = p.folder().to_path_buf();
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped(JobKind::Calibrate, scope, move |ctx, out| {
            let cal = job.run(ctx).map_err(|e| e.to_string())?;
            hand_over(cal, &folder, out)
        });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Writes what calibration made into the session folder and hands it to the window.
fn hand_over(
    cal: crate::project::Calibration,
    folder: &std::path::Path,
    out: &crate::app::jobs::Emitter<JobOutput>,
) -> Result<(), String> {
    let path = folder.join(PROFILE_FILE);
    // A fixed α, β has no curves: an old report would describe another fit.
    cal.write(&path, Some(&folder.join(CV_FILE)))
        .map_err(|e| e.to_string())?;
    out.emit(JobOutput::Stage(StageOutput::Calibrated {
        dataset: Arc::new(cal.dataset),
        profile: Arc::new(cal.profile),
        cv: cal.cv.map(Arc::new),
        path,
    }));
    Ok(())
}

/// *Calibrate all*: every shot still missing a result detected and measured, then the
/// models fitted over every shot with kernels, as one job with one progress line and
/// one cancel; its end message says what it measured and what failed.
fn calibrate_all(app: &mut StudioApp, then_deblur: bool) {
    if [
        JobKind::CalibrateAll,
        JobKind::Detect,
        JobKind::Kernels,
        JobKind::Calibrate,
    ]
    .into_iter()
    .any(|j| app.jobs.is_running(j))
    {
        app.info("a stage is already running: wait for it or cancel it (Esc)");
        return;
    }
    let Some(p) = app.project.as_ref() else {
        return;
    };
    if p.session().shots.is_empty() {
        app.info("no shots yet: add shots of the chart first (Ctrl+Shift+A)");
        return;
    }
    let opts = crate::calibrate::CalibrateOptions {
        alpha: p.session().settings.alpha,
        beta: p.session().settings.beta,
        ..Default::default()
    };
    let job = p
        .calibrate_all_job(opts)
        .retain(|id| app.unreadable(id).is_none())
        .with_captures(|id| app.preview(id).map(|v| Arc::clone(&v.capture)));
    let folder = p.folder().to_path_buf();
    let scope = JobScope::shots(app.session_generation, job.shots());
    let r = app
        .jobs
        .spawn_scoped(JobKind::CalibrateAll, scope, move |ctx, out| {
            let cal = job
                .run(ctx, &|id| out.shot_context(ctx, id), &mut |e| {
                    out.emit(JobOutput::Stage(StageOutput::Shot(e)));
                })
                .map_err(|e| e.to_string())?;
            hand_over(cal, &folder, out)
        });
    match r {
        Ok(_) => app.autorun.deblur_when_calibrated = then_deblur,
        Err(e) => app.error(e),
    }
}

/// Kernels of the chosen shot (again), or of every detected shot without them.
fn run_kernels(app: &mut StudioApp, which: Option<ShotId>) {
    if app.jobs.is_running(JobKind::Kernels) {
        app.info("kernel estimation is already running");
        return;
    }
    let plan = match which {
        Some(id) if app.detection(id).is_some() => MeasurePlan::again(Stages::Kernels, vec![id]),
        Some(id) => {
            let name = app
                .session()
                .and_then(|s| s.shot(id))
                .map_or_else(|| "the shot".into(), crate::session::Shot::name);
            app.info(format!(
                "{name}: detect the chart in it first (right-click it, Detect this shot again)"
            ));
            return;
        }
        None => MeasurePlan::missing(Stages::Kernels),
    };
    if run_measure(app, JobKind::Kernels, &plan) == 0 {
        app.info(if app.detections().next().is_none() {
            "no shot is detected yet: run Detect (Ctrl+D) first"
        } else {
            "every detected shot already has kernels (right-click a shot and choose Estimate its kernels again to redo it)"
        });
    }
}
