//! The stages run on job threads (detect, kernels, calibrate, the dataset the sweeps
//! read) and what they hand back.

use super::CV_FILE;
use super::save;
use crate::app::jobs::{Emitter, JobScope};
use crate::app::{Command, JobOutput, StudioApp};
use crate::detect::Detection;
use crate::job::JobContext;
use crate::kernel::file::KernelsFile;
use crate::pipeline::{self, GivenSetting, MeasuredShot, ShotFile};
use crate::plane::Capture;
use crate::session::{ShotId, StageStatus};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The stages: detect, kernels, calibrate, and the profile they make.
pub(super) fn apply_stage(app: &mut StudioApp, command: Command) {
    match command {
        Command::RunDetect(which) => run_detect(app, which),
        Command::RunKernels(which) => run_kernels(app, which),
        Command::RunCalibrate => run_calibrate(app),
        Command::LoadProfile { path, compare } => {
            let r = app.jobs.spawn("load profile", move |_ctx, out| {
                let profile = crate::profile::Profile::load(&path).map_err(|e| e.to_string())?;
                out.emit(JobOutput::ProfileLoaded {
                    profile: Arc::new(profile),
                    path,
                    compare,
                });
                Ok(())
            });
            if let Err(e) = r {
                app.error(e);
            }
        }
        Command::SaveProfile(path) => {
            let Some((_, profile)) = app.profile.clone() else {
                app.error("no profile to save: calibrate first (Ctrl+M) or load one");
                return;
            };
            match profile.save(&path) {
                Ok(()) => app.info(format!("profile saved to {}", app.shown_path(&path))),
                Err(e) => app.error(e.to_string()),
            }
        }
        // `apply` routes only this group's commands here.
        other => unreachable!("not routed to apply_stage: {other:?}"),
    }
}

/// Results of the stages, shot by shot, and of calibration.
pub(super) fn stage_output(app: &mut StudioApp, output: JobOutput) {
    match output {
        JobOutput::Detected { shot: id, result } => {
            if !app.has_shot(id) {
                return;
            }
            let result = result.map_err(|e| app.shorten_paths(e));
            let status = match &result {
                Ok(d) => StageStatus::Done {
                    summary: crate::session::detect_summary(d),
                },
                Err(reason) => StageStatus::Failed {
                    reason: reason.clone(),
                },
            };
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shot_mut(id)) {
                shot.detect = status;
            }
            match result {
                Ok(d) => {
                    app.detections.insert(id, d);
                }
                Err(e) => app.error(e),
            }
            save(app);
        }
        JobOutput::KernelsMeasured { shot: id, result } => {
            if !app.has_shot(id) {
                return;
            }
            let result = result.map_err(|e| app.shorten_paths(e));
            let status = match &result {
                Ok(file) => StageStatus::Done {
                    summary: crate::session::kernels_summary(file),
                },
                Err(reason) => StageStatus::Failed {
                    reason: reason.clone(),
                },
            };
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shot_mut(id)) {
                shot.kernels = status;
            }
            match result {
                Ok(file) => {
                    app.measured.insert(id, file);
                }
                Err(e) => app.error(e),
            }
            save(app);
        }
        JobOutput::DatasetReady(ds) => app.dataset = ds,
        JobOutput::Calibrated {
            dataset,
            profile,
            cv,
            path,
        } => calibrated(app, dataset, profile, cv, path),
        JobOutput::ProfileLoaded {
            profile,
            path,
            compare,
        } => {
            app.info(format!("profile {} loaded", app.shown_path(&path)));
            if compare {
                app.compare_profile = Some((path, profile));
            } else {
                app.profile = Some((path, profile));
                app.deblur.comparison = None;
            }
        }
        // `apply_output` routes only this group's outputs here.
        _ => unreachable!("an output not routed to stage_output"),
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
    if let Some(s) = app.session.as_mut() {
        s.profile = Some(
            path.strip_prefix(s.folder())
                .map_or_else(|_| path.clone(), Path::to_path_buf),
        );
    }
    app.dataset = Some(dataset);
    app.profile = Some((path, profile));
    app.cv = cv;
    app.deblur.comparison = None;
    save(app);
}

/// Shots a stage should run on: the one asked for, or every readable shot without a
/// result.
fn targets(app: &StudioApp, which: Option<ShotId>, done: impl Fn(ShotId) -> bool) -> Vec<ShotId> {
    let Some(s) = app.session.as_ref() else {
        return Vec::new();
    };
    match which {
        Some(id) => s.shot(id).map(|shot| shot.id).into_iter().collect(),
        None => s
            .shots
            .iter()
            .map(|shot| shot.id)
            .filter(|&id| !done(id) && app.unreadable(id).is_none())
            .collect(),
    }
}

/// One shot of a stage run over several: its id, its file, its capture where the
/// preview already holds it, and what the stage needs besides.
type ShotWork<W> = (ShotId, PathBuf, Option<Arc<Capture>>, W);

/// Runs a stage on each shot in turn. Each shot has its own context, cancelled alone
/// when the shot is removed (it is then skipped); its file is fingerprinted for the
/// cache and loaded unless the preview holds it; `emit` makes each shot's result (a
/// failure in words) the job's output for that shot.
fn each_shot<W, T>(
    work: Vec<ShotWork<W>>,
    ctx: &JobContext,
    out: &Emitter<JobOutput>,
    stage: impl Fn(&Capture, &ShotFile, W, &JobContext) -> Result<T, pipeline::PipelineError>,
    emit: impl Fn(ShotId, Result<T, String>) -> JobOutput,
) -> Result<(), String> {
    let n = work.len();
    for (k, (id, path, capture, extra)) in work.into_iter().enumerate() {
        ctx.check().map_err(|e| e.to_string())?;
        let Some(shot_ctx) = out.shot_context(ctx, id) else {
            continue;
        };
        let shot_ctx = shot_ctx.prefixed(&format!("shot {} of {n}: ", k + 1));
        let result = ShotFile::read(&path).and_then(|file| {
            let capture = match capture {
                Some(c) => c,
                None => Arc::new(pipeline::load(&path)?),
            };
            stage(&capture, &file, extra, &shot_ctx)
        });
        match result {
            Ok(v) => out.emit(emit(id, Ok(v))),
            // The shot was removed; if the whole job was cancelled, the next check ends it.
            Err(e) if e.is_cancelled() => {}
            Err(e) => out.emit(emit(id, Err(e.to_string()))),
        }
    }
    Ok(())
}

/// Detection of the chosen shots on one job thread (each detection is itself parallel),
/// results cached in the session and handed back shot by shot.
fn run_detect(app: &mut StudioApp, which: Option<ShotId>) {
    if app.jobs.is_running("detect") {
        app.info("detection is already running");
        return;
    }
    let ids = targets(app, which, |id| app.detections.contains_key(&id));
    let Some(session) = app.session.as_ref() else {
        return;
    };
    if ids.is_empty() {
        app.info(
            "every shot is already detected (right-click a shot and choose Detect this shot again to redo it)",
        );
        return;
    }
    let m = session.measurement();
    let cache = session.cache();
    let work: Vec<ShotWork<()>> = ids
        .iter()
        .filter_map(|&id| {
            Some((
                id,
                session.path_of(session.shot(id)?),
                app.preview(id).map(|p| Arc::clone(&p.capture)),
                (),
            ))
        })
        .collect();
    let scope = JobScope::shots(app.session_generation, ids);
    let r = app.jobs.spawn_scoped("detect", scope, move |ctx, out| {
        each_shot(
            work,
            ctx,
            out,
            |capture, file, (), shot_ctx| {
                pipeline::detect_shot(capture, file, &m, &cache, shot_ctx).map(Arc::new)
            },
            |shot, result| JobOutput::Detected { shot, result },
        )
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// The shots with measured kernels, in session order, as calibration takes them.
fn measured_shots(app: &StudioApp) -> Vec<MeasuredShot> {
    let Some(session) = app.session.as_ref() else {
        return Vec::new();
    };
    session
        .shots
        .iter()
        .filter_map(|shot| {
            Some(MeasuredShot {
                name: shot.name(),
                kernels: KernelsFile::clone(app.measured.get(&shot.id)?),
                given: shot.given_setting(),
            })
        })
        .collect()
}

/// The session's measured Gaussians over every shot with kernels and known settings,
/// for the sweeps (rebuilt when kernels or settings change).
pub(super) fn spawn_dataset(app: &mut StudioApp) {
    let shots: Vec<MeasuredShot> = measured_shots(app)
        .into_iter()
        .filter(|s| {
            s.given.focal_mm.or(s.kernels.focal_mm).is_some()
                && s.given.f_number.or(s.kernels.f_number).is_some()
        })
        .collect();
    if shots.is_empty() {
        app.dataset = None;
        return;
    }
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped("gather measurements", scope, move |_ctx, out| {
            match pipeline::dataset(&shots) {
                Ok(ds) => out.emit(JobOutput::DatasetReady(Some(Arc::new(ds)))),
                Err(e) => {
                    out.emit(JobOutput::DatasetReady(None));
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
    if app.jobs.is_running("calibrate") {
        app.info("calibration is already running");
        return;
    }
    let Some(session) = app.session.as_ref() else {
        return;
    };
    let shots = measured_shots(app);
    if shots.len() < 2 {
        app.error("calibration needs kernels on at least two shots: run Detect (Ctrl+D) and Kernels (Ctrl+K) first");
        return;
    }
    let chart = session.chart.clone();
    let out_path = session.folder().join("profile.json");
    let cv_path = session.folder().join(CV_FILE);
    let opts = crate::calibrate::CalibrateOptions {
        alpha: session.settings.alpha,
        beta: session.settings.beta,
        ..Default::default()
    };
    let scope = JobScope::session(app.session_generation);
    let r = app.jobs.spawn_scoped("calibrate", scope, move |ctx, out| {
        // Every shot needs its setting: the error names the ones without.
        let ds = pipeline::dataset(&shots).map_err(|e| format!("calibration: {e}"))?;
        let (profile, cv) = crate::calibrate::calibrate(&ds, Some(chart), &opts, ctx)
            .map_err(|e| format!("calibration: {e}"))?;
        profile.save(&out_path).map_err(|e| e.to_string())?;
        match &cv {
            Some(report) => crate::io::write_json(&cv_path, report).map_err(|e| e.to_string())?,
            None => {
                // A fixed α, β has no curves: an old report would describe another fit.
                let _ = std::fs::remove_file(&cv_path);
            }
        }
        out.emit(JobOutput::Calibrated {
            dataset: Arc::new(ds),
            profile: Arc::new(profile),
            cv: cv.map(Arc::new),
            path: out_path,
        });
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Kernels of the chosen shots (those detected), one shot after another, each shot's
/// squares in parallel; results cached in the session as kernels files.
fn run_kernels(app: &mut StudioApp, which: Option<ShotId>) {
    if app.jobs.is_running("kernels") {
        app.info("kernel estimation is already running");
        return;
    }
    let ids: Vec<ShotId> = targets(app, which, |id| app.measured.contains_key(&id))
        .into_iter()
        .filter(|id| app.detections.contains_key(id))
        .collect();
    if ids.is_empty() {
        let msg = match which {
            Some(id) => format!(
                "{}: detect the chart in it first (right-click it, Detect this shot again)",
                app.session
                    .as_ref()
                    .and_then(|s| s.shot(id))
                    .map_or_else(|| "the shot".into(), crate::session::Shot::name)
            ),
            None if app.detections.is_empty() => {
                "no shot is detected yet: run Detect (Ctrl+D) first".to_owned()
            }
            None => "every detected shot already has kernels (right-click a shot and choose Estimate its kernels again to redo it)".to_owned(),
        };
        app.info(msg);
        return;
    }
    let Some(session) = app.session.as_ref() else {
        return;
    };
    let m = session.measurement();
    let cache = session.cache();
    let work: Vec<ShotWork<(Arc<Detection>, GivenSetting)>> = ids
        .iter()
        .filter_map(|&id| {
            let shot = session.shot(id)?;
            Some((
                id,
                session.path_of(shot),
                app.preview(id).map(|p| Arc::clone(&p.capture)),
                (Arc::clone(app.detections.get(&id)?), shot.given_setting()),
            ))
        })
        .collect();
    let scope = JobScope::shots(app.session_generation, ids);
    let r = app.jobs.spawn_scoped("kernels", scope, move |ctx, out| {
        each_shot(
            work,
            ctx,
            out,
            |capture, file, (det, given), shot_ctx| {
                pipeline::kernels_of_shot(capture, &det, file, given, &m, &cache, shot_ctx)
                    .map(Arc::new)
            },
            |shot, result| JobOutput::KernelsMeasured { shot, result },
        )
    });
    if let Err(e) = r {
        app.error(e);
    }
}
