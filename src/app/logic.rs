//! Applies commands, drains finished jobs and keeps the session saved: owns every
//! change to the app's state, and makes the textures of results when they arrive
//! (shot previews, the photo, deblurred crops). What the views derive from that state
//! is `view_data`'s. Never draws.

use super::jobs::{Emitter, JobEvent, JobScope};
use super::view_data;
use super::{
    Command, ComparisonView, Confirm, DeblurResult, DeblurZoom, JobOutput, PendingPlotPng, Photo,
    PlotId, ShotPreview, StudioApp,
};
use crate::deblur::{DeblurOptions, KernelSource, Method};
use crate::detect::Detection;
use crate::develop::Developed;
use crate::job::JobContext;
use crate::kernel::file::KernelsFile;
use crate::pipeline::{self, GivenSetting, MeasuredShot, ShotFile};
use crate::plane::{Capture, Channel, ChannelPlane, Plane};
use crate::review::PlotTable;
use crate::session::{Session, ShotId, StageStatus};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Commands made by the answers of file dialogs that have closed.
pub(super) fn drain_dialogs(app: &mut StudioApp) {
    while let Ok(commands) = app.dialog_rx.try_recv() {
        app.dialog_open = false;
        app.commands.extend(commands);
    }
}

/// Runs a file dialog on its own thread: `dialog` makes the dialog's future there (a
/// portal dialog is a D-Bus conversation that would otherwise hold the window's
/// frames), and the commands its answer makes come back through the app's channel.
fn spawn_dialog<F>(app: &mut StudioApp, dialog: impl FnOnce() -> F + Send + 'static)
where
    F: std::future::Future<Output = Vec<Command>>,
{
    if app.dialog_open {
        app.info("a file dialog is already open: answer it first");
        return;
    }
    let tx = app.dialog_tx.clone();
    let ctx = app.ctx.clone();
    let started = std::thread::Builder::new()
        .name("file dialog".into())
        .spawn(move || {
            let commands = pollster::block_on(dialog());
            // The app may have closed meanwhile; then nobody needs the answer.
            let _ = tx.send(commands);
            ctx.request_repaint();
        });
    match started {
        Ok(_) => app.dialog_open = true,
        Err(e) => app.error(format!("cannot open the file dialog: {e}")),
    }
}

/// The path a dialog answered, or no command when it was cancelled.
fn answer(
    handle: Option<rfd::FileHandle>,
    command: impl FnOnce(PathBuf) -> Command,
) -> Vec<Command> {
    handle
        .map(|h| command(h.path().to_path_buf()))
        .into_iter()
        .collect()
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
            JobEvent::Finished { job, name, result } => {
                let tally = app.tallies.remove(&job);
                match result {
                    // A preview cancelled by a newer one (a control being dragged) is
                    // not news: the newer one's result follows.
                    Err(e) if e == "cancelled" && name == "deblur preview" => {}
                    Err(e) if e == "cancelled" => {
                        let done = tally.map_or(String::new(), |t| match t.ok + t.failed.len() {
                            1 => " after 1 shot".to_owned(),
                            n => format!(" after {n} shots"),
                        });
                        app.info(format!("{name}: cancelled{done}"));
                    }
                    Err(e) => app.error(e),
                    Ok(()) => {
                        if let Some(t) = tally {
                            finished_message(app, &name, &t);
                        }
                    }
                }
                if name == "kernels" {
                    spawn_dataset(app);
                }
                if name == "deblur preview"
                    && let Some(centre) = app.deblur.pending.take()
                {
                    run_deblur_preview(app, centre);
                }
            }
        }
    }
}

/// Counts a detect or kernels job's shots as they come back.
fn tally(app: &mut StudioApp, job: u64, output: &JobOutput) {
    let (id, failure) = match output {
        JobOutput::Detected { shot, result } => (*shot, result.as_ref().err()),
        JobOutput::KernelsMeasured { shot, result } => (*shot, result.as_ref().err()),
        _ => return,
    };
    let name = app
        .session
        .as_ref()
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
        Some(r) => t.failed.push((name, r)),
        None => t.ok += 1,
    }
}

/// "Measured kernels for 9 shots (1 failed: IMG_3.png — no chart found)".
fn finished_message(app: &mut StudioApp, job: &str, t: &super::Tally) {
    let n = t.ok + t.failed.len();
    let shots = if n == 1 {
        "1 shot".to_owned()
    } else {
        format!("{n} shots")
    };
    let what = match job {
        "detect" => format!("Detected the chart in {shots}"),
        "kernels" => format!("Measured kernels for {shots}"),
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

fn apply_output(app: &mut StudioApp, output: JobOutput) {
    match output {
        JobOutput::DemoShot(s) => {
            if app.session.is_none() {
                if app.set_session(*s) {
                    app.info("demo session: showing each simulated shot as soon as it is made");
                }
            } else {
                merge_demo(app, &s);
            }
        }
        JobOutput::DemoReady(s) => {
            let n = s.shots.len();
            if app.session.is_none() {
                if !app.set_session(*s) {
                    return;
                }
            } else if !merge_demo(app, &s) {
                // The user opened another session meanwhile: the demo waits in its
                // folder for the next launch.
                return;
            }
            save(app);
            app.info(format!(
                "demo session ready: {n} simulated shots of the virtual lens, and a photo it blurred"
            ));
        }
        JobOutput::ShotLoaded {
            shot: id,
            capture,
            developed,
        } => {
            if !app.has_shot(id) {
                return;
            }
            let preview = make_preview(&app.ctx, id, &capture, developed);
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shot_mut(id)) {
                // EXIF fills what the user has not typed.
                let mut changed = false;
                if shot.focal_mm.is_none() && capture.setting_focal_mm.is_some() {
                    shot.focal_mm = capture.setting_focal_mm;
                    changed = true;
                }
                if shot.f_number.is_none() && capture.setting_f_number.is_some() {
                    shot.f_number = capture.setting_f_number;
                    changed = true;
                }
                if changed {
                    save(app);
                }
            }
            app.previews.insert(id, preview);
        }
        JobOutput::ShotUnreadable { shot, reason } => {
            if app.has_shot(shot) {
                app.error(reason.clone());
                app.unreadable.insert(shot, reason);
            }
        }
        JobOutput::Calibrated {
            dataset,
            profile,
            cv,
            path,
        } => {
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
        JobOutput::ResultsRead { survey, cv } => {
            // The cache decides what is done: results measured elsewhere (another
            // front end, an earlier version of the session) count, and a status whose
            // result has gone is pending again.
            if let Some(s) = app.session.as_mut() {
                s.settle(&survey);
            }
            save(app);
            for line in &survey.dropped {
                app.info(line.clone());
            }
            app.detections = survey
                .detections
                .into_iter()
                .map(|(id, d)| (id, Arc::new(d)))
                .collect();
            app.measured = survey
                .kernels
                .into_iter()
                .map(|(id, k)| (id, Arc::new(k)))
                .collect();
            if app.cv.is_none() {
                app.cv = cv;
            }
            spawn_dataset(app);
        }
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
        JobOutput::PhotoLoaded {
            path,
            capture,
            developed,
        } => {
            let texture = rgb_texture(&app.ctx, "photo", &crate::raw::full_planes(&capture), None);
            let developed =
                developed.map(|d| d.map(|d| developed_texture(&app.ctx, "photo-developed", &d)));
            if let Some(Err(reason)) = &developed {
                app.error(format!(
                    "{}: cannot develop it ({reason}); showing the linear planes",
                    app.shown_path(&path)
                ));
            }
            // Settings: EXIF first, then the session's record of the same file.
            let recorded = app.session.as_ref().and_then(|s| {
                s.shots
                    .iter()
                    .find(|shot| s.path_of(shot) == path)
                    .map(|shot| (shot.focal_mm, shot.f_number))
            });
            // The demo's photo is a PNG: its setting is in the session instead.
            let demo = app.session.as_ref().and_then(|s| {
                s.demo_photo
                    .as_ref()
                    .filter(|p| s.folder().join(&p.path) == path)
                    .map(|p| (Some(p.focal_mm), Some(p.f_number)))
            });
            let (rf, ra) = recorded.or(demo).unwrap_or((None, None));
            let centre = [
                (capture.width as f64 - 1.0) / 2.0,
                (capture.height as f64 - 1.0) / 2.0,
            ];
            app.deblur.photo = Some(Photo {
                path,
                focal_mm: capture.setting_focal_mm.or(rf),
                f_number: capture.setting_f_number.or(ra),
                capture,
                texture,
                developed,
            });
            app.deblur.comparison = None;
            apply(app, Command::DeblurAt(centre));
        }
        JobOutput::DeblurCompared {
            comparison,
            measured_from,
        } => {
            let textures = [
                Some(&comparison.original),
                comparison.predicted.as_ref().ok(),
                comparison.measured.as_ref().ok(),
            ];
            // One display scale for the three crops: the original's white points, so a
            // result that overshoots shows it rather than being stretched back.
            let whites = crate::review::display_whites(&comparison.original);
            let textures = textures.map(|planes| {
                planes.and_then(|p| rgb_texture(&app.ctx, "deblur-crop", p, Some(&whites)))
            });
            let developed = match &comparison.developed {
                Some(Ok(crops)) => crops.each_ref().map(|d| {
                    d.as_ref()
                        .map(|d| developed_texture(&app.ctx, "deblur-crop-developed", d))
                }),
                _ => [None, None, None],
            };
            app.deblur.comparison = Some(ComparisonView {
                comparison,
                measured_from,
                textures,
                developed,
            });
        }
        JobOutput::SquareInspected { key, result } => {
            super::view_data::inspected(app, key, result);
        }
        JobOutput::DeblurExported(path) => {
            app.info(format!(
                "deblurred photo written to {}",
                app.shown_path(&path)
            ));
        }
        JobOutput::PhotosExported(report) => {
            for o in &report.outcomes {
                let name = app.shown_path(&o.photo);
                match &o.outcome {
                    crate::batch::Outcome::Skipped(reason) => {
                        app.info(format!("{name}: skipped: {reason}"));
                    }
                    crate::batch::Outcome::Failed(reason) => app.error(format!("{name}: {reason}")),
                    _ => {}
                }
            }
            app.info(format!(
                "photos exported: {}",
                report
                    .summary()
                    .iter()
                    .map(|l| l.trim())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
    }
}

/// Adds to the open demo session the shots the demo job has made since (and at the end
/// its photo). False when the open session is another one.
fn merge_demo(app: &mut StudioApp, made: &Session) -> bool {
    let Some(s) = app
        .session
        .as_mut()
        .filter(|s| s.is_demo && s.folder() == made.folder())
    else {
        return false;
    };
    // Each shot is added once, by id: one the user removed meanwhile stays removed.
    let known = s.next_shot_id;
    s.shots
        .extend(made.shots.iter().filter(|shot| shot.id.0 >= known).cloned());
    s.next_shot_id = s.next_shot_id.max(made.next_shot_id);
    if s.demo_photo.is_none() && made.demo_photo.is_some() {
        s.demo_photo.clone_from(&made.demo_photo);
        let opened = s.clone();
        app.open_demo_photo(&opened);
    }
    true
}

pub(super) fn save(app: &mut StudioApp) {
    if let Some(s) = &app.session
        && let Err(e) = s.save()
    {
        app.error(e.to_string());
    }
}

pub(super) fn apply(app: &mut StudioApp, command: Command) {
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
        Command::AddShotsDialog => spawn_dialog(app, || async {
            rfd::AsyncFileDialog::new()
                .set_title("Add calibration shots")
                .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                .pick_files()
                .await
                .map(|files| {
                    Command::AddShots(files.iter().map(|f| f.path().to_path_buf()).collect())
                })
                .into_iter()
                .collect()
        }),
        Command::AddShots(files) => add_shots(app, &files),
        Command::RemoveShot(id) => remove_shot(app, id),
        Command::SetShotSetting {
            shot,
            focal_mm,
            f_number,
        } => {
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shot_mut(shot)) {
                shot.focal_mm = focal_mm;
                shot.f_number = f_number;
                save(app);
                spawn_dataset(app);
            }
        }
        Command::ApplySettings { chart, settings } => {
            // A new chart discards what was measured with the old one: ask first.
            let has_results = !app.detections.is_empty() || !app.measured.is_empty();
            let chart_changed = app.session.as_ref().is_some_and(|s| s.chart != chart);
            if chart_changed && has_results {
                app.confirm = Some(Confirm::ReplaceChart { chart, settings });
            } else {
                apply_settings(app, chart, settings);
            }
        }
        Command::AskConfirm(c) => app.confirm = Some(c),
        Command::ConfirmAnswer(yes) => match app.confirm.take() {
            Some(Confirm::RemoveShot(id)) if yes => remove_shot(app, id),
            Some(Confirm::ReplaceChart { chart, settings }) if yes => {
                apply_settings(app, chart, settings);
            }
            _ => {}
        },
        Command::LoadChartDialog => spawn_dialog(app, || async {
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Load a chart spec")
                    .add_filter("chart spec", &["json"])
                    .pick_file()
                    .await,
                Command::LoadChart,
            )
        }),
        Command::LoadChart(path) => match crate::chart::ChartSpec::load(&path) {
            Ok(spec) => {
                let settings = app
                    .settings_edit
                    .as_ref()
                    .map(|e| e.1.clone())
                    .or_else(|| app.session.as_ref().map(|s| s.settings.clone()))
                    .unwrap_or_default();
                app.settings_edit = Some((spec, settings));
                app.info(format!(
                    "chart spec {} read: press Apply to use it",
                    app.shown_path(&path)
                ));
            }
            Err(e) => app.error(e.to_string()),
        },
        Command::RunDetect(which) => run_detect(app, which),
        Command::RunKernels(which) => run_kernels(app, which),
        Command::RunCalibrate => run_calibrate(app),
        Command::SetFieldSource(f) => app.field_source = f,
        Command::SetFieldShow(f) => app.field_show = f,
        Command::SetSweepAxis(a) => app.sweep_axis = a,
        Command::SetFieldSetting { focal_mm, f_number } => {
            app.field_focal_mm = focal_mm;
            app.field_f_number = f_number;
        }
        Command::SetCompareUnits(on) => app.compare_units = on,
        Command::SetFieldOptions(o) => app.field_options = o,
        Command::OpenPhotoDialog => spawn_dialog(app, || async {
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Open a photo to deblur")
                    .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                    .pick_file()
                    .await,
                Command::OpenPhoto,
            )
        }),
        Command::OpenPhoto(path) => {
            let r = app.jobs.spawn("open photo", move |ctx, out| {
                ctx.report("loading", 0, 1);
                let capture = load_capture(&path)?;
                let developed = develop_for_display(&capture);
                ctx.report("loading", 1, 1);
                out.emit(JobOutput::PhotoLoaded {
                    path,
                    capture: Arc::new(capture),
                    developed,
                });
                Ok(())
            });
            if let Err(e) = r {
                app.error(e);
            }
        }
        Command::SetPhotoSetting { focal_mm, f_number } => {
            if let Some(p) = app.deblur.photo.as_mut() {
                p.focal_mm = focal_mm;
                p.f_number = f_number;
            }
        }
        Command::DeblurAt(centre) => run_deblur_preview(app, centre),
        Command::SetDeblurLayout(l) => {
            app.deblur.layout = l;
            app.deblur.viewport = None;
        }
        Command::SetDeblurZoom(z) => {
            app.deblur.zoom = z;
            app.deblur.viewport = None;
            if z == DeblurZoom::Fit {
                redeblur(app);
            }
        }
        Command::SetDeblurViewport(v) => {
            if app.deblur.viewport != Some(v) {
                app.deblur.viewport = Some(v);
                redeblur(app);
            }
        }
        Command::SetDeblurCrop(px) => {
            app.deblur.crop_px = px.clamp(32, 4096);
            redeblur(app);
        }
        Command::SetDeblurMethod(m) => {
            app.deblur.method = Some(m);
            redeblur(app);
        }
        Command::SetDeblurDevice(d) => {
            app.deblur.device = d;
            app.deblur.device_note = None;
            redeblur(app);
        }
        Command::DragDeblur(d) => {
            app.deblur.drag[0] += d[0];
            app.deblur.drag[1] += d[1];
        }
        Command::EndDragDeblur => {
            let d = std::mem::take(&mut app.deblur.drag);
            if let Some(c) = app.deblur.comparison.as_ref() {
                let [cx, cy] = c.comparison.region.centre();
                run_deblur_preview(app, [cx - f64::from(d[0]), cy - f64::from(d[1])]);
            }
        }
        Command::SetSliderResult(r) => app.deblur.slider_result = r,
        Command::ExportDeblurDialog(result) => {
            let Some(photo) = &app.deblur.photo else {
                app.error("open a photo first");
                return;
            };
            let stem = photo
                .path
                .file_stem()
                .map_or_else(|| "photo".into(), |s| s.to_string_lossy().into_owned());
            let which = match result {
                DeblurResult::Predicted => "predicted",
                DeblurResult::Measured => "measured",
            };
            // A RAW photo goes back to a RAW editor as a DNG; TIFF/PNG stay offered.
            let raw = photo.capture.raw.is_some();
            let mut dialog = rfd::AsyncFileDialog::new().set_title(if raw {
                "Export the deblurred photo (DNG for a RAW editor, or 16-bit linear)"
            } else {
                "Export the deblurred photo (16-bit linear)"
            });
            if raw {
                dialog = dialog.add_filter("DNG", &["dng"]);
            }
            dialog = dialog
                .add_filter("TIFF or PNG", &["tiff", "tif", "png"])
                .set_file_name(format!(
                    "{stem}.deblurred-{which}.{}",
                    if raw { "dng" } else { "tiff" }
                ));
            if let Some(dir) = photo.path.parent() {
                dialog = dialog.set_directory(dir);
            }
            spawn_dialog(app, move || async move {
                answer(dialog.save_file().await, |path| Command::ExportDeblur {
                    path,
                    result,
                })
            });
        }
        Command::ExportDeblur { path, result } => run_export(app, path, result),
        Command::ExportPhotosDialog { dng } => spawn_dialog(app, move || async move {
            let Some(photos) = rfd::AsyncFileDialog::new()
                .set_title(if dng {
                    "RAW photos to deblur (written as DNGs)"
                } else {
                    "Photos to deblur (written as 16-bit TIFFs)"
                })
                .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                .pick_files()
                .await
            else {
                return Vec::new();
            };
            let photos: Vec<PathBuf> = photos.iter().map(|f| f.path().to_path_buf()).collect();
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Folder for the deblurred photos")
                    .pick_folder()
                    .await,
                |out_dir| Command::ExportPhotos {
                    photos,
                    out_dir,
                    dng,
                },
            )
        }),
        Command::ExportPhotos {
            photos,
            out_dir,
            dng,
        } => run_export_photos(app, photos, out_dir, dng),
        Command::LoadProfileDialog | Command::LoadCompareProfileDialog => {
            let compare = command == Command::LoadCompareProfileDialog;
            spawn_dialog(app, move || async move {
                answer(
                    rfd::AsyncFileDialog::new()
                        .set_title(if compare {
                            "Load a second lens profile to compare"
                        } else {
                            "Load a lens profile"
                        })
                        .add_filter("lens profile", &["json"])
                        .pick_file()
                        .await,
                    |path| Command::LoadProfile { path, compare },
                )
            });
        }
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
        Command::SaveProfileDialog => {
            if app.profile.is_none() {
                app.error("no profile to save: calibrate first (Ctrl+M) or load one");
                return;
            }
            spawn_dialog(app, || async {
                answer(
                    rfd::AsyncFileDialog::new()
                        .set_title("Save the lens profile")
                        .add_filter("lens profile", &["json"])
                        .set_file_name("profile.json")
                        .save_file()
                        .await,
                    Command::SaveProfile,
                )
            });
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
        Command::SavePlotDialog { plot, png } => {
            let (what, ext) = if png { ("PNG", "png") } else { ("CSV", "csv") };
            let name = format!("{}.{ext}", plot.file_stem(app.sweep_axis));
            spawn_dialog(app, move || async move {
                answer(
                    rfd::AsyncFileDialog::new()
                        .set_title(format!("Save the plot as {what}"))
                        .add_filter(what, &[ext])
                        .set_file_name(name)
                        .save_file()
                        .await,
                    |path| {
                        if png {
                            Command::SavePlotPng { plot, path }
                        } else {
                            Command::SavePlotCsv { plot, path }
                        }
                    },
                )
            });
        }
        Command::SavePlotCsv { plot, path } => {
            let written = plot_table(app, plot).and_then(|t| {
                crate::io::write_atomic(&path, crate::review::plot_csv(&t).as_bytes())
                    .map_err(|e| e.to_string())
            });
            match written {
                Ok(()) => app.info(format!("plot data saved to {}", app.shown_path(&path))),
                Err(e) => app.error(format!("cannot save the plot's data: {e}")),
            }
        }
        Command::SavePlotPng { plot, path } => request_plot_png(app, plot, path),
        Command::OpenSessionDialog => spawn_dialog(app, || async {
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Open or create a session folder")
                    .pick_folder()
                    .await,
                Command::OpenSession,
            )
        }),
        Command::SetViewer(v) => app.viewer = v,
        Command::SetSlider(t) => app.deblur.slider = t.clamp(0.0, 1.0),
        Command::EditSettings(edit) => app.settings_edit = edit,
        Command::OpenSession(path) => match crate::session::Session::open(&path) {
            Ok(s) => {
                if app.set_session(s) {
                    save(app);
                }
            }
            Err(e) => app.error(e.to_string()),
        },
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
        Command::ShowHelp(open) => app.show_help = open,
        Command::ShowAbout(open) => app.show_about = open,
        Command::Quit => app.ctx.send_viewport_cmd(egui::ViewportCommand::Close),
    }
}

fn add_shots(app: &mut StudioApp, files: &[PathBuf]) {
    if app.session.is_none() {
        app.error("open or create a session folder before adding shots (Ctrl+O)");
        return;
    }
    let mut errors = Vec::new();
    let mut added = None;
    if let Some(s) = app.session.as_mut() {
        for f in files {
            match s.add_shot(f) {
                Ok(id) => added = Some(id),
                Err(e) => errors.push(e.to_string()),
            }
        }
    }
    for e in errors {
        app.error(e);
    }
    if let Some(id) = added {
        app.selected_shot = Some(id);
        app.viewer.sensor_px_per_point = None;
        save(app);
    }
}

/// Removes a shot from the session (its file and cached results stay on disk): work on
/// it stops, and whatever it still sends is dropped since the shot is gone.
fn remove_shot(app: &mut StudioApp, id: ShotId) {
    let Some(s) = app.session.as_mut() else {
        return;
    };
    let Some(i) = s.index_of(id) else {
        return;
    };
    s.remove_shot(id);
    app.jobs.cancel_shot(id);
    let next = s
        .shots
        .get(i)
        .or_else(|| s.shots.last())
        .map(|shot| shot.id);
    app.previews.remove(&id);
    app.unreadable.remove(&id);
    app.detections.remove(&id);
    app.measured.remove(&id);
    app.loading.remove(&id);
    if app.selected_shot == Some(id) {
        app.selected_shot = next;
        app.selected_square = None;
    }
    save(app);
    spawn_dataset(app);
}

/// New chart or stage settings; results they make stale go back to pending (their
/// files stay until the stage runs again).
fn apply_settings(
    app: &mut StudioApp,
    chart: crate::chart::ChartSpec,
    settings: crate::session::StageSettings,
) {
    if let Err(e) = chart.validate() {
        app.error(format!("chart spec: {e}"));
        return;
    }
    let Some(s) = app.session.as_mut() else {
        return;
    };
    let chart_changed = s.chart != chart;
    let kernels_changed = chart_changed
        || s.settings.oversample != settings.oversample
        || s.settings.weight_all_subpixels != settings.weight_all_subpixels;
    s.chart = chart;
    s.settings = settings;
    for shot in &mut s.shots {
        if chart_changed {
            shot.detect = StageStatus::Pending;
        }
        if kernels_changed {
            shot.kernels = StageStatus::Pending;
        }
    }
    if chart_changed {
        app.detections.clear();
        app.selected_square = None;
    }
    if kernels_changed {
        app.measured.clear();
        app.dataset = None;
    }
    app.settings_edit = None;
    app.info(match (chart_changed, kernels_changed) {
        (true, _) => "settings applied: detection and kernels run again with the new chart",
        (false, true) => "settings applied: kernels run again with the new settings",
        _ => "settings applied",
    });
    save(app);
}

pub(super) fn ensure_preview(app: &mut StudioApp) {
    let Some(s) = &app.session else { return };
    if app.jobs.is_running("load shot") {
        return;
    }
    let order = app
        .selected_shot
        .into_iter()
        .chain(s.shots.iter().map(|shot| shot.id));
    let Some(id) = order
        .filter(|id| s.shot(*id).is_some())
        .find(|id| !app.loading.contains(id))
    else {
        return;
    };
    let Some(path) = s.shot(id).map(|shot| s.path_of(shot)) else {
        return;
    };
    app.loading.insert(id);
    let scope = JobScope::shots(app.session_generation, vec![id]);
    let r = app.jobs.spawn_scoped("load shot", scope, move |ctx, out| {
        ctx.report("loading shot", 0, 1);
        match load_capture(&path) {
            Ok(capture) => {
                ctx.check().map_err(|e| e.to_string())?;
                let developed = develop_for_display(&capture);
                out.emit(JobOutput::ShotLoaded {
                    shot: id,
                    capture: Arc::new(capture),
                    developed,
                });
            }
            Err(reason) => out.emit(JobOutput::ShotUnreadable { shot: id, reason }),
        }
        ctx.report("loading shot", 1, 1);
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Loads a shot or photo through the core's loader; the error is already one line
/// naming the file.
pub(crate) fn load_capture(path: &Path) -> Result<Capture, String> {
    pipeline::load(path).map_err(|e| e.to_string())
}

/// Display value of a linear sample: sRGB-like encoding so mid-greys look right.
pub(super) fn encode(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let e = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (e * 255.0 + 0.5) as u8
}

/// A grey texture of one channel (the pooled grey when `channel` is `None`) at its
/// plane's own resolution.
pub(crate) fn channel_texture(
    ctx: &egui::Context,
    name: &str,
    capture: &Capture,
    channel: Option<Channel>,
) -> Option<egui::TextureHandle> {
    let plane: Plane = match channel {
        Some(c) => pooled_plane(capture, c)?.plane,
        None => capture.grey(),
    };
    let img = egui::ColorImage::from_gray_iter(
        [plane.width, plane.height],
        plane.data.iter().map(|&v| encode(v)),
    );
    Some(ctx.load_texture(name, img, egui::TextureOptions::NEAREST))
}

/// A colour texture of full-resolution planes (R, G, B; a lone plane as grey), each
/// plane's linear values divided by its white (default: the planes' own display whites).
pub(super) fn rgb_texture(
    ctx: &egui::Context,
    name: &str,
    planes: &[(Channel, Plane)],
    whites: Option<&[(Channel, f32)]>,
) -> Option<egui::TextureHandle> {
    let first = &planes.first()?.1;
    let (w, h) = (first.width, first.height);
    if w == 0 || h == 0 {
        return None;
    }
    let own;
    let whites = match whites {
        Some(w) => w,
        None => {
            own = crate::review::display_whites(planes);
            &own
        }
    };
    let white_of = |c: Channel| {
        whites
            .iter()
            .find(|(ch, _)| *ch == c)
            .map_or(1.0, |(_, v)| *v)
    };
    let get = |c: Channel| {
        planes
            .iter()
            .find(|(ch, _)| *ch == c)
            .map(|(_, p)| (p, white_of(c)))
    };
    let first = (first, white_of(planes[0].0));
    let [r, g, b] = match (get(Channel::R), get(Channel::G), get(Channel::B)) {
        (Some(r), Some(g), Some(b)) => [r, g, b],
        _ => [first, first, first],
    };
    let pixels: Vec<egui::Color32> = (0..w * h)
        .map(|k| {
            let v =
                |(p, white): (&Plane, f32)| encode(p.data.get(k).copied().unwrap_or(0.0) / white);
            egui::Color32::from_rgb(v(r), v(g), v(b))
        })
        .collect();
    let img = egui::ColorImage {
        size: [w, h],
        source_size: egui::Vec2::new(w as f32, h as f32),
        pixels,
    };
    Some(ctx.load_texture(name, img, egui::TextureOptions::NEAREST))
}

/// The first plane of a channel (G1 for a Bayer G): enough for display.
fn pooled_plane(capture: &Capture, channel: Channel) -> Option<ChannelPlane> {
    capture
        .planes
        .iter()
        .find(|p| p.channel == channel)
        .cloned()
}

/// A RAW capture developed at full resolution in sensor orientation (overlays are
/// drawn in sensor pixels), or why it could not be; `None` for an RGB image.
fn develop_for_display(capture: &Capture) -> Option<Result<Developed, String>> {
    capture.is_raw.then(|| {
        crate::develop::develop(capture, None, crate::develop::Orient::Sensor)
            .map_err(|e| e.to_string())
    })
}

/// A texture of a developed (8-bit sRGB) image.
fn developed_texture(ctx: &egui::Context, name: &str, image: &Developed) -> egui::TextureHandle {
    let img = egui::ColorImage::from_rgb([image.width, image.height], &image.rgb);
    ctx.load_texture(name, img, egui::TextureOptions::NEAREST)
}

fn make_preview(
    ctx: &egui::Context,
    id: ShotId,
    capture: &Arc<Capture>,
    developed: Option<Result<Developed, String>>,
) -> ShotPreview {
    let index = id.0;
    let mut textures = std::collections::BTreeMap::new();
    let mut channels: Vec<Channel> = capture.planes.iter().map(|p| p.channel).collect();
    channels.dedup();
    for c in channels {
        if let Some(t) = channel_texture(ctx, &format!("shot{index}-{c}"), capture, Some(c)) {
            textures.insert(c, t);
        }
    }
    let grey = capture.grey();
    let step = (grey.width / 96).max(1);
    let (tw, th) = (grey.width / step, grey.height / step);
    let thumb = egui::ColorImage::from_gray_iter(
        [tw, th],
        (0..th)
            .flat_map(|j| (0..tw).map(move |i| (i, j)))
            .map(|(i, j)| encode(grey.get(i * step, j * step))),
    );
    let thumbnail =
        Some(ctx.load_texture(format!("thumb{index}"), thumb, egui::TextureOptions::LINEAR));
    let developed =
        developed.map(|d| d.map(|d| developed_texture(ctx, &format!("shot{index}-developed"), &d)));
    ShotPreview {
        capture: Arc::clone(capture),
        textures,
        developed,
        thumbnail,
    }
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
            .filter(|&id| !done(id) && !app.unreadable.contains_key(&id))
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
                app.previews.get(&id).map(|p| Arc::clone(&p.capture)),
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

/// Finds the results a session already has in its cache (measured by the studio or by
/// `lensblur calibrate`), off the UI thread: shots are fingerprinted, and kernels files
/// with their arrays run to megabytes.
pub(super) fn read_results(app: &mut StudioApp, session: &Session) {
    let cv_path = session.folder().join(CV_FILE);
    if session.shots.is_empty() && !cv_path.is_file() {
        return;
    }
    let session = session.clone();
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped("read results", scope, move |ctx, out| {
            let survey = session.survey(ctx).map_err(|e| e.to_string())?;
            let cv = crate::io::read_json_text(&cv_path)
                .ok()
                .and_then(|t| serde_json::from_str(&t).ok())
                .map(Arc::new);
            out.emit(JobOutput::ResultsRead { survey, cv });
            Ok(())
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
fn spawn_dataset(app: &mut StudioApp) {
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

/// The cross-validation report beside the profile, so a reopened session shows its
/// curves without calibrating again.
const CV_FILE: &str = "crossval.json";

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
                app.previews.get(&id).map(|p| Arc::clone(&p.capture)),
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

/// The method the Deblur view uses: its own once changed there, else the session's.
pub(crate) fn deblur_method(app: &StudioApp) -> Method {
    app.deblur.method.unwrap_or_else(|| {
        app.session
            .as_ref()
            .and_then(|s| Method::from_name(&s.settings.deblur_method))
            .unwrap_or_default()
    })
}

fn deblur_options(app: &StudioApp) -> DeblurOptions {
    DeblurOptions {
        method: deblur_method(app),
        device: app.deblur.device,
        ..DeblurOptions::default()
    }
}

/// Deblurs the region again where it is (after a control changed).
fn redeblur(app: &mut StudioApp) {
    let centre = match (&app.deblur.comparison, &app.deblur.photo) {
        (Some(c), _) => c.comparison.region.centre(),
        (None, Some(p)) => [p.capture.width as f64 / 2.0, p.capture.height as f64 / 2.0],
        (None, None) => return,
    };
    run_deblur_preview(app, centre);
}

/// The two kernel sources of the open photo: the profile's prediction and the measured
/// kernels of the session shot at the photo's setting (each with the reason it is
/// missing), and the name of that shot.
type Sources = (
    Result<crate::deblur::ProfileKernels, String>,
    Result<crate::deblur::ScatteredKernels, String>,
    Option<String>,
);

fn photo_sources(app: &StudioApp, photo: &Photo) -> Sources {
    let cap = &photo.capture;
    let setting = photo.setting();
    let predicted = match &app.profile {
        Some((_, p)) => crate::review::profile_source(p, cap, setting),
        None => Err("no profile yet: Calibrate (Ctrl+M) or load one in Models".into()),
    };
    let found = match (app.session.as_ref(), setting) {
        (Some(s), Some(set)) => s.shots.iter().find_map(|shot| {
            let file = app.measured.get(&shot.id)?;
            crate::review::measured_at(shot.setting(), file, cap.width, cap.height, set)
                .then(|| (shot.stem(), Arc::clone(file)))
        }),
        _ => None,
    };
    let (measured, from) = match (found, setting) {
        (Some((name, file)), _) => (crate::review::measured_source(&file), Some(name)),
        (None, None) => (
            Err("focal length and aperture unknown: type them above".into()),
            None,
        ),
        (None, Some(s)) => (
            Err(format!(
                "no shot of this session at {:.0} mm f/{:.1} has measured kernels",
                s.focal_mm, s.f_number
            )),
            None,
        ),
    };
    (predicted, measured, from)
}

/// Deblurs a crop of the open photo around `centre` with both sources.
fn run_deblur_preview(app: &mut StudioApp, centre: [f64; 2]) {
    let Some(photo) = &app.deblur.photo else {
        return;
    };
    // A newer preview replaces one still running: that one is cancelled and this one
    // waits for it to stop. One preview at a time, the latest request kept, so a
    // control dragged over many frames never queues a preview per frame.
    let mut busy = false;
    for h in &app.jobs.running {
        if h.name == "deblur preview" {
            h.cancel();
            busy = true;
        }
    }
    if busy {
        app.deblur.pending = Some(centre);
        return;
    }
    let cap = Arc::clone(&photo.capture);
    let region = match (app.deblur.zoom, app.deblur.viewport) {
        (DeblurZoom::Times(_), Some([w, h])) => {
            crate::review::Region::around_size(centre[0], centre[1], w, h, cap.width, cap.height)
        }
        _ => crate::review::Region::around(
            centre[0],
            centre[1],
            app.deblur.crop_px,
            cap.width,
            cap.height,
        ),
    };
    let (predicted, measured, from) = photo_sources(app, photo);
    let opts = deblur_options(app);
    if app.deblur.device_note.is_none() {
        // Where the preview runs, said once per choice (opening a device is the core's).
        let note = crate::deblur::gpu::describe(opts.device, &opts.method);
        app.deblur.device_note = Some(note);
    }
    let r = app.jobs.spawn("deblur preview", move |ctx, out| {
        let comparison = crate::review::compare_deblur(
            &cap,
            region,
            predicted
                .as_ref()
                .map(|s| s as &dyn KernelSource)
                .map_err(Clone::clone),
            measured
                .as_ref()
                .map(|s| s as &dyn KernelSource)
                .map_err(Clone::clone),
            &opts,
            ctx,
        )
        .map_err(|e| e.to_string())?;
        out.emit(JobOutput::DeblurCompared {
            comparison: Arc::new(comparison),
            measured_from: from,
        });
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Deblurs a set of photos with the open profile, each at its own EXIF setting, as the
/// command line's batch does (skips and failures reported photo by photo).
fn run_export_photos(app: &mut StudioApp, photos: Vec<PathBuf>, out_dir: PathBuf, dng: bool) {
    let Some((path, profile)) = &app.profile else {
        app.error("calibrate or load a profile first: the photos are deblurred with it");
        return;
    };
    let library = crate::batch::ProfileLibrary::chosen(path.clone(), (**profile).clone());
    let opts = crate::batch::BatchOptions {
        out_dir,
        format: if dng {
            crate::batch::OutputFormat::Dng
        } else {
            crate::batch::OutputFormat::Tiff
        },
        allow_extrapolation: false,
        deblur: deblur_options(app),
        kernel_model: None,
        memory_budget: None,
        max_parallel: None,
    };
    let r = app.jobs.spawn("export photos", move |ctx, out| {
        let report = crate::batch::deblur_photos(&photos, &library, &opts, ctx);
        out.emit(JobOutput::PhotosExported(report));
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Deblurs the whole open photo with one source and writes it.
fn run_export(app: &mut StudioApp, path: PathBuf, result: DeblurResult) {
    let Some(photo) = &app.deblur.photo else {
        app.error("open a photo first");
        return;
    };
    let (predicted, measured, _) = photo_sources(app, photo);
    let source: Result<Box<dyn KernelSource + Send>, String> = match result {
        DeblurResult::Predicted => predicted.map(|s| Box::new(s) as Box<dyn KernelSource + Send>),
        DeblurResult::Measured => measured.map(|s| Box::new(s) as Box<dyn KernelSource + Send>),
    };
    let source = match source {
        Ok(s) => s,
        Err(reason) => {
            app.error(format!("cannot export with {}: {reason}", result.label()));
            return;
        }
    };
    let cap = Arc::clone(&photo.capture);
    let opts = deblur_options(app);
    let original = photo
        .path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned());
    let note = format!(
        "Deblurred by {} ({}) with {} in the studio",
        crate::dng::SOFTWARE,
        opts.method.name(),
        result.label()
    );
    let r = app.jobs.spawn("export", move |ctx, out| {
        crate::review::export_deblurred(&cap, source.as_ref(), &opts, &path, original, &note, ctx)?;
        out.emit(JobOutput::DeblurExported(path));
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// The data a plot draws, from the same view data and report its draw code reads.
fn plot_table(app: &StudioApp, plot: PlotId) -> Result<PlotTable, String> {
    match plot {
        PlotId::Sweep { vs_aperture, param } => {
            let data = app
                .views
                .sweeps
                .as_ref()
                .ok_or("the sweeps are not prepared yet: open the Sweeps view")?;
            view_data::sweep_table(data, app.sweep_axis, vs_aperture, param)
                .ok_or_else(|| format!("the sweeps have no plot {param}"))
        }
        PlotId::CvAlpha | PlotId::CvBeta | PlotId::CvCdf => {
            let cv = app
                .cv
                .as_ref()
                .ok_or("no cross-validation yet: calibrate first (Ctrl+M)")?;
            let families = [("global", cv.global.as_ref()), ("local", cv.local.as_ref())]
                .into_iter()
                .filter_map(|(n, s)| s.map(|s| (n, s)));
            let (x_label, series) = match plot {
                PlotId::CvCdf => (
                    "error (% of range)",
                    families
                        .flat_map(|(n, s)| {
                            crate::review::cv_cdf_curves(s)
                                .map(|(param, pts)| (format!("{n} {param}"), pts))
                        })
                        .collect(),
                ),
                _ => {
                    let by_alpha = plot == PlotId::CvAlpha;
                    (
                        if by_alpha {
                            "α (order in x, y)"
                        } else {
                            "β (order in f, a)"
                        },
                        families
                            .map(|(n, s)| (n.to_owned(), crate::review::cv_curve(s, by_alpha)))
                            .collect(),
                    )
                }
            };
            let y_label = if plot == PlotId::CvCdf {
                "held-out samples (%)"
            } else {
                "mean error (% of range)"
            };
            Ok(PlotTable {
                x_label: x_label.to_owned(),
                y_label: y_label.to_owned(),
                series,
            })
        }
    }
}

/// Asks for a screenshot of the next frame; the plot is cut out of it when it arrives
/// ([`finish_plot_png`]), so the PNG is the plot exactly as drawn.
fn request_plot_png(app: &mut StudioApp, plot: PlotId, path: PathBuf) {
    let rect = app
        .ctx
        .data(|d| d.get_temp::<egui::Rect>(plot.rect_id()))
        .filter(|_| app.view == plot.view());
    let Some(rect) = rect else {
        app.error("cannot save the plot: it is not on screen; open its view first");
        return;
    };
    if app.plot_png.is_some() {
        app.error("cannot save the plot: another plot is being saved");
        return;
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let wake = app.ctx.clone();
    app.ctx.request_screenshot(move |image| {
        // The app may have closed meanwhile; then nobody waits for the image.
        let _ = tx.send(image);
        wake.request_repaint();
    });
    app.plot_png = Some(PendingPlotPng {
        path,
        rect,
        image: rx,
    });
}

/// Writes the pending plot PNG once its screenshot has arrived.
pub(super) fn finish_plot_png(app: &mut StudioApp) {
    let Some(pending) = &app.plot_png else {
        return;
    };
    let image = match pending.image.try_recv() {
        Ok(image) => Ok(image),
        Err(std::sync::mpsc::TryRecvError::Empty) => return,
        Err(std::sync::mpsc::TryRecvError::Disconnected) => {
            Err("the window gave no screenshot".to_owned())
        }
    };
    let Some(pending) = app.plot_png.take() else {
        return;
    };
    let ppp = app.ctx.pixels_per_point();
    let r = pending.rect;
    let px = |v: f32| (v * ppp).round().max(0.0) as usize;
    let written = image.and_then(|image| {
        let [w, h] = image.size;
        let rgba: Vec<u8> = image
            .pixels
            .iter()
            .flat_map(|c| c.to_srgba_unmultiplied())
            .collect();
        crate::review::write_png_crop(
            &pending.path,
            rgba,
            w,
            h,
            [px(r.min.x), px(r.min.y), px(r.max.x), px(r.max.y)],
        )
    });
    match written {
        Ok(()) => app.info(format!("plot saved to {}", app.shown_path(&pending.path))),
        Err(e) => app.error(format!("cannot save the plot: {e}")),
    }
}
