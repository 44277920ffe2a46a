//! Applies commands and drains finished jobs. Never draws.

use super::jobs::JobEvent;
use super::{Command, JobOutput, ShotPreview, StudioApp};
use crate::detect::{DetectFile, DetectParams, Detection};
use crate::kernel::file::KernelsFile;
use crate::plane::{Capture, Channel, ChannelPlane, Plane};
use crate::session::{Session, StageStatus};
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub(super) fn drain_jobs(app: &mut StudioApp) {
    for event in app.jobs.drain() {
        match event {
            JobEvent::Output { output, .. } => match output {
                JobOutput::DemoReady(s) => {
                    let n = s.shots.len();
                    app.set_session(s);
                    app.info(format!(
                        "demo session ready: {n} simulated shots of the virtual lens"
                    ));
                }
                JobOutput::ShotLoaded { index, capture } => {
                    let preview = make_preview(&app.ctx, index, &capture);
                    if let Some(s) = app.session.as_mut() {
                        if let Some(shot) = s.shots.get_mut(index) {
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
                    }
                    app.previews.insert(index, preview);
                }
                JobOutput::Calibrated {
                    dataset,
                    profile,
                    cv,
                    path,
                } => {
                    let kind = format!("{:?}", profile.preferred).to_lowercase();
                    app.info(format!(
                        "calibrated on {} samples from {} shots; {kind} model preferred; profile saved to {}",
                        dataset.samples.len(),
                        dataset.shots.len(),
                        app.shown_path(&path)
                    ));
                    if let Some(s) = app.session.as_mut() {
                        s.profile = Some(path.clone());
                    }
                    app.dataset = Some(dataset);
                    app.profile = Some((path, profile));
                    app.cv = cv;
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
                    }
                }
                JobOutput::KernelsMeasured { index, result } => {
                    let status = match &result {
                        Ok((samples, failed)) => StageStatus::Done {
                            summary: format!("{} kernels, {failed} failed", samples.len()),
                        },
                        Err(reason) => StageStatus::Failed {
                            reason: reason.clone(),
                        },
                    };
                    if let Some(shot) = app.session.as_mut().and_then(|s| s.shots.get_mut(index)) {
                        shot.kernels = status;
                    }
                    match result {
                        Ok((samples, _)) => {
                            app.measured.insert(index, samples);
                        }
                        Err(e) => app.error(e),
                    }
                    save(app);
                }
                JobOutput::Detected { index, result } => {
                    let status = match &result {
                        Ok(d) => StageStatus::Done {
                            summary: format!(
                                "{} of {} squares aligned",
                                d.ok_squares().count(),
                                d.squares.len()
                            ),
                        },
                        Err(reason) => StageStatus::Failed {
                            reason: reason.clone(),
                        },
                    };
                    if let Some(shot) = app.session.as_mut().and_then(|s| s.shots.get_mut(index)) {
                        shot.detect = status;
                    }
                    match result {
                        Ok(d) => {
                            app.detections.insert(index, d);
                        }
                        Err(e) => app.error(e),
                    }
                    save(app);
                }
                JobOutput::PhotoLoaded { path, capture } => {
                    let tex = channel_texture(&app.ctx, "photo", &capture, None);
                    app.photo = Some((path, capture, tex));
                }
            },
            JobEvent::Finished { result: Err(e), .. } => app.error(e),
            JobEvent::Finished { result: Ok(()), .. } => {}
        }
    }
}

fn save(app: &mut StudioApp) {
    if let Some(s) = &app.session {
        if let Err(e) = s.save() {
            app.error(e.to_string());
        }
    }
}

pub(super) fn apply(app: &mut StudioApp, command: Command) {
    match command {
        Command::SelectView(v) => app.view = v,
        Command::SelectShot(i) => {
            app.selected_shot = Some(i);
            app.selected_square = None;
            app.inspection = None;
            app.viewer.sensor_px_per_point = None;
        }
        Command::SelectChannel(c) => {
            app.channel = c;
            update_inspection(app);
        }
        Command::ClearSquare => {
            app.selected_square = None;
            app.inspection = None;
        }
        Command::SelectSquare(sq) => {
            app.selected_square = Some(sq);
            update_inspection(app);
        }
        Command::AddShotsDialog => {
            if let Some(files) = rfd::FileDialog::new()
                .set_title("Add calibration shots")
                .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                .pick_files()
            {
                apply(app, Command::AddShots(files));
            }
        }
        Command::AddShots(files) => add_shots(app, &files),
        Command::RemoveShot(i) => {
            if let Some(s) = app.session.as_mut() {
                if i < s.shots.len() {
                    s.shots.remove(i);
                    app.previews.clear();
                    app.loading.clear();
                    app.selected_shot = if s.shots.is_empty() {
                        None
                    } else {
                        Some(i.min(s.shots.len() - 1))
                    };
                    save(app);
                }
            }
        }
        Command::SetShotSetting {
            index,
            focal_mm,
            f_number,
        } => {
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shots.get_mut(index)) {
                shot.focal_mm = focal_mm;
                shot.f_number = f_number;
                save(app);
            }
        }
        Command::RunDetect(which) => run_detect(app, which),
        Command::RunKernels(which) => run_kernels(app, which),
        Command::RunCalibrate => run_calibrate(app),
        Command::SetFieldSource(f) => app.field_source = f,
        Command::OpenPhotoDialog => {
            if let Some(p) = rfd::FileDialog::new()
                .set_title("Open a photo to deblur")
                .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                .pick_file()
            {
                apply(app, Command::OpenPhoto(p));
            }
        }
        Command::OpenPhoto(path) => {
            let p2 = path.clone();
            let r = app.jobs.spawn("open photo", move |ctx, out| {
                ctx.report("loading", 0, 1);
                let capture = load_capture(&p2)?;
                ctx.report("loading", 1, 1);
                out.emit(JobOutput::PhotoLoaded {
                    path: p2,
                    capture: Arc::new(capture),
                });
                Ok(())
            });
            if let Err(e) = r {
                app.error(e);
            }
        }
        Command::LoadProfileDialog | Command::LoadCompareProfileDialog => {
            let compare = command == Command::LoadCompareProfileDialog;
            if let Some(path) = rfd::FileDialog::new()
                .set_title(if compare {
                    "Load a second lens profile to compare"
                } else {
                    "Load a lens profile"
                })
                .add_filter("lens profile", &["json"])
                .pick_file()
            {
                apply(app, Command::LoadProfile { path, compare });
            }
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
            let Some((_, profile)) = app.profile.clone() else {
                app.error("no profile to save: calibrate first (Ctrl+M) or load one");
                return;
            };
            if let Some(path) = rfd::FileDialog::new()
                .set_title("Save the lens profile")
                .set_file_name("profile.json")
                .save_file()
            {
                match profile.save(&path) {
                    Ok(()) => app.info(format!("profile saved to {}", app.shown_path(&path))),
                    Err(e) => app.error(e.to_string()),
                }
            }
        }
        Command::OpenSessionDialog => {
            if let Some(dir) = rfd::FileDialog::new()
                .set_title("Open or create a session folder")
                .pick_folder()
            {
                match crate::session::Session::open(&dir) {
                    Ok(s) => {
                        app.set_session(s);
                        save(app);
                    }
                    Err(e) => app.error(e.to_string()),
                }
            }
        }
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
                Ok(i) => added = Some(i),
                Err(e) => errors.push(e.to_string()),
            }
        }
    }
    for e in errors {
        app.error(e);
    }
    if let Some(i) = added {
        app.selected_shot = Some(i);
        save(app);
    }
}

/// Starts loading the selected shot (and then the others, for thumbnails), one at a
/// time so the machine is not flooded.
pub(super) fn ensure_preview(app: &mut StudioApp) {
    let Some(s) = &app.session else { return };
    if app.jobs.is_running("load shot") {
        return;
    }
    let order = app.selected_shot.into_iter().chain(0..s.shots.len());
    let Some(index) = order
        .filter(|i| *i < s.shots.len())
        .find(|i| !app.loading.contains(i))
    else {
        return;
    };
    let path = s.shot_path(index);
    app.loading.insert(index);
    let r = app.jobs.spawn("load shot", move |ctx, out| {
        ctx.report("loading shot", 0, 1);
        let capture = load_capture(&path)?;
        ctx.check().map_err(|e| e.to_string())?;
        ctx.report("loading shot", 1, 1);
        out.emit(JobOutput::ShotLoaded {
            index,
            capture: Arc::new(capture),
        });
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Loads a shot or photo through the core's loader; the error is already one line
/// naming the file.
pub(crate) fn load_capture(path: &Path) -> Result<Capture, String> {
    crate::raw::load_capture(path, &crate::raw::LoadOptions::default()).map_err(|e| e.to_string())
}

/// Display value of a linear sample: sRGB-like encoding so mid-greys look right.
fn encode(v: f32) -> u8 {
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

/// The first plane of a channel (G1 for a Bayer G): enough for display.
pub(crate) fn pooled_plane(capture: &Capture, channel: Channel) -> Option<ChannelPlane> {
    capture
        .planes
        .iter()
        .find(|p| p.channel == channel)
        .cloned()
}

fn make_preview(ctx: &egui::Context, index: usize, capture: &Arc<Capture>) -> ShotPreview {
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
    ShotPreview {
        capture: Arc::clone(capture),
        textures,
        thumbnail,
    }
}

/// Shots a stage should run on: the one asked for, or every shot without a result.
fn targets(app: &StudioApp, which: Option<usize>, done: impl Fn(usize) -> bool) -> Vec<usize> {
    let n = app.session.as_ref().map_or(0, |s| s.shots.len());
    match which {
        Some(i) if i < n => vec![i],
        Some(_) => Vec::new(),
        None => (0..n).filter(|&i| !done(i)).collect(),
    }
}

/// Detection of the chosen shots on one job thread (each detection is itself parallel),
/// results written beside the session and handed back shot by shot.
fn run_detect(app: &mut StudioApp, which: Option<usize>) {
    if app.jobs.is_running("detect") {
        app.info("detection is already running");
        return;
    }
    let indices = targets(app, which, |i| app.detections.contains_key(&i));
    let Some(session) = app.session.as_ref() else {
        return;
    };
    if indices.is_empty() {
        app.info("every shot is already detected (select one and press Detect to redo it)");
        return;
    }
    let spec = session.chart.clone();
    let work: Vec<(usize, PathBuf, PathBuf, Option<Arc<Capture>>)> = indices
        .iter()
        .map(|&i| {
            (
                i,
                session.shot_path(i),
                session.result_path(i, "detect"),
                app.previews.get(&i).map(|p| Arc::clone(&p.capture)),
            )
        })
        .collect();
    let r = app.jobs.spawn("detect", move |ctx, out| {
        for (index, shot, result_path, capture) in work {
            ctx.check().map_err(|e| e.to_string())?;
            let capture = match capture {
                Some(c) => c,
                None => match load_capture(&shot) {
                    Ok(c) => Arc::new(c),
                    Err(e) => {
                        out.emit(JobOutput::Detected {
                            index,
                            result: Err(e),
                        });
                        continue;
                    }
                },
            };
            let result = match crate::detect::detect(&capture, &spec, &DetectParams::default(), ctx)
            {
                Ok(d) => write_result(&result_path, &d.to_file()).map(|()| Arc::new(d)),
                Err(crate::detect::DetectError::Cancelled(c)) => return Err(c.to_string()),
                Err(e) => Err(format!("{}: {e}", shot.display())),
            };
            out.emit(JobOutput::Detected { index, result });
        }
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

fn write_result<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), String> {
    let text = serde_json::to_vec_pretty(value).map_err(|e| format!("{}: {e}", path.display()))?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text).map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path).map_err(|e| format!("{}: {e}", path.display()))
}

/// Detections a reopened session already has on disk.
pub(super) fn read_detections(
    session: &Session,
) -> std::collections::BTreeMap<usize, Arc<Detection>> {
    (0..session.shots.len())
        .filter(|&i| session.shots[i].detect.is_done())
        .filter_map(|i| {
            let text = std::fs::read_to_string(session.result_path(i, "detect")).ok()?;
            let file: DetectFile = serde_json::from_str(&text).ok()?;
            Some((i, Arc::new(Detection::from_file(&file))))
        })
        .collect()
}

/// Recomputes the inspector's crops for the selected shot, square and channel.
fn update_inspection(app: &mut StudioApp) {
    app.inspection = None;
    let (Some(shot), Some(sq)) = (app.selected_shot, app.selected_square) else {
        return;
    };
    let (Some(preview), Some(det), Some(session)) = (
        app.previews.get(&shot),
        app.detections.get(&shot),
        app.session.as_ref(),
    ) else {
        return;
    };
    let Some(square) = det.squares.iter().find(|s| (s.row, s.col) == sq) else {
        return;
    };
    let channel = if preview
        .capture
        .planes
        .iter()
        .any(|p| p.channel == app.channel)
    {
        app.channel
    } else {
        match preview.capture.planes.first() {
            Some(p) => p.channel,
            None => return,
        }
    };
    let Some(crops) =
        crate::detect::inspect::inspect_square(&preview.capture, square, &session.chart, channel)
    else {
        return;
    };
    let tex = |name: &str, plane: &Plane, map: &dyn Fn(f32) -> u8| {
        let img = egui::ColorImage::from_gray_iter(
            [plane.width, plane.height],
            plane.data.iter().map(|&v| map(v)),
        );
        app.ctx
            .load_texture(name, img, egui::TextureOptions::NEAREST)
    };
    // The residual is signed and small: mid-grey is zero, ±25 % of the square's
    // contrast spans the grey range.
    let contrast = {
        let mut v = crops.observed.data.clone();
        v.sort_by(f32::total_cmp);
        (v[v.len() * 98 / 100] - v[v.len() * 2 / 100]).max(1e-3)
    };
    let textures = [
        tex("inspect-observed", &crops.observed, &encode),
        tex("inspect-synthetic", &crops.synthetic, &encode),
        tex("inspect-residual", &crops.residual, &|r: f32| {
            ((0.5 + 2.0 * r / contrast).clamp(0.0, 1.0) * 255.0) as u8
        }),
    ];
    app.inspection = Some(super::Inspection {
        shot,
        square: sq,
        channel,
        crops,
        textures,
    });
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
    let done: Vec<usize> = (0..session.shots.len())
        .filter(|&i| session.shots[i].kernels.is_done())
        .collect();
    if done.len() < 2 {
        app.error("calibration needs kernels on at least two shots: run Detect (Ctrl+D) and Kernels (Ctrl+K) first");
        return;
    }
    let paths: Vec<PathBuf> = done
        .iter()
        .map(|&i| session.result_path(i, "kernels"))
        .collect();
    let settings: Vec<_> = done.iter().map(|&i| session.shots[i].setting()).collect();
    let names: Vec<String> = done
        .iter()
        .map(|&i| session.shots[i].path.display().to_string())
        .collect();
    let chart = session.chart.clone();
    let out_path = session.folder().join("profile.json");
    let opts = crate::profile::CalibrateOptions {
        alpha: session.settings.alpha,
        beta: session.settings.beta,
        ..Default::default()
    };
    let r = app.jobs.spawn("calibrate", move |ctx, out| {
        let refs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
        let mut ds = crate::model::Dataset::from_kernels_files(&refs, &settings)
            .map_err(|e| e.to_string())?;
        for (info, name) in ds.shots.iter_mut().zip(names) {
            info.name = name;
        }
        let (profile, cv) = crate::profile::calibrate(&ds, Some(chart), &opts, ctx)
            .map_err(|e| format!("calibration: {e}"))?;
        profile.save(&out_path).map_err(|e| e.to_string())?;
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

/// The samples the studio shows, from a kernels file.
pub(super) fn measured_samples(file: &KernelsFile) -> Vec<super::MeasuredSample> {
    file.samples
        .iter()
        .filter_map(|s| {
            Some(super::MeasuredSample {
                x: s.x,
                y: s.y,
                channel: s.channel,
                gaussian: crate::psf::Gaussian2 {
                    sigma_x: s.cxx?,
                    sigma_y: s.cyy?,
                    rho: s.cor?,
                },
                kernel: s.kernel_at(file.oversample),
            })
        })
        .collect()
}

/// Kernels of the chosen shots (those detected), one shot after another, each shot's
/// squares in parallel; results written beside the session as kernels files.
fn run_kernels(app: &mut StudioApp, which: Option<usize>) {
    if app.jobs.is_running("kernels") {
        app.info("kernel estimation is already running");
        return;
    }
    let Some(session) = app.session.as_ref() else {
        return;
    };
    let indices: Vec<usize> = targets(app, which, |i| app.measured.contains_key(&i))
        .into_iter()
        .filter(|i| app.detections.contains_key(i))
        .collect();
    if indices.is_empty() {
        app.info("no detected shot without kernels: run Detect (Ctrl+D) first");
        return;
    }
    let spec = session.chart.clone();
    let params = crate::kernel::KernelParams {
        oversample: session.settings.oversample,
        weighting: if session.settings.weight_all_subpixels {
            crate::kernel::Weighting::Uniform
        } else {
            crate::kernel::Weighting::PixelCentres
        },
        ..Default::default()
    };
    type Work = (
        usize,
        PathBuf,
        PathBuf,
        Option<Arc<Capture>>,
        Arc<Detection>,
        Option<crate::plane::LensSetting>,
    );
    let work: Vec<Work> = indices
        .iter()
        .filter_map(|&i| {
            Some((
                i,
                session.shot_path(i),
                session.result_path(i, "kernels"),
                app.previews.get(&i).map(|p| Arc::clone(&p.capture)),
                Arc::clone(app.detections.get(&i)?),
                session.shots[i].setting(),
            ))
        })
        .collect();
    let r = app.jobs.spawn("kernels", move |ctx, out| {
        for (index, shot, result_path, capture, det, setting) in work {
            ctx.check().map_err(|e| e.to_string())?;
            let capture = match capture {
                Some(c) => c,
                None => match load_capture(&shot) {
                    Ok(c) => Arc::new(c),
                    Err(e) => {
                        out.emit(JobOutput::KernelsMeasured {
                            index,
                            result: Err(e),
                        });
                        continue;
                    }
                },
            };
            let result = match crate::kernel::estimate_shot(&capture, &det, &spec, &params, ctx) {
                Ok(k) => {
                    let file = KernelsFile::from_shot(
                        &k,
                        setting.map(|s| s.focal_mm).or(capture.setting_focal_mm),
                        setting.map(|s| s.f_number).or(capture.setting_f_number),
                        Some(capture.identity.clone()),
                        true,
                    );
                    write_result(&result_path, &file)
                        .map(|()| (measured_samples(&file), file.failed.len()))
                }
                Err(crate::kernel::KernelError::Cancelled(c)) => return Err(c.to_string()),
                Err(e) => Err(format!("{}: {e}", shot.display())),
            };
            out.emit(JobOutput::KernelsMeasured { index, result });
        }
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Kernels a reopened session already has on disk.
pub(super) fn read_measured(
    session: &Session,
) -> std::collections::BTreeMap<usize, Vec<super::MeasuredSample>> {
    (0..session.shots.len())
        .filter(|&i| session.shots[i].kernels.is_done())
        .filter_map(|i| {
            let file = KernelsFile::load(&session.result_path(i, "kernels")).ok()?;
            Some((i, measured_samples(&file)))
        })
        .collect()
}
