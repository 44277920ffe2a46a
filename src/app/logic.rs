//! Applies commands and drains finished jobs. Never draws.

use super::jobs::JobEvent;
use super::{
    Command, ComparisonView, DeblurResult, JobOutput, KernelAtlas, Photo, ShotPreview, StudioApp,
};
use crate::deblur::{DeblurOptions, KernelSource, Method};
use crate::detect::{DetectFile, DetectParams, Detection};
use crate::kernel::file::KernelsFile;
use crate::plane::{Capture, Channel, ChannelPlane, LensSetting, Plane};
use crate::session::{Session, StageStatus};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub(super) fn drain_jobs(app: &mut StudioApp) {
    for event in app.jobs.drain() {
        match event {
            JobEvent::Output { output, .. } => apply_output(app, output),
            JobEvent::Finished {
                name,
                result: Err(e),
                ..
            } => {
                if e == "cancelled" {
                    app.info(format!("{name}: cancelled"));
                } else {
                    app.error(e);
                }
                if name == "kernels" {
                    spawn_dataset(app);
                }
            }
            JobEvent::Finished {
                name,
                result: Ok(()),
                ..
            } => {
                if name == "kernels" {
                    spawn_dataset(app);
                }
            }
        }
    }
}

fn apply_output(app: &mut StudioApp, output: JobOutput) {
    match output {
        JobOutput::DemoReady(s) => {
            let n = s.shots.len();
            app.set_session(*s);
            app.info(format!(
                "demo session ready: {n} simulated shots of the virtual lens"
            ));
        }
        JobOutput::ShotLoaded { index, capture } => {
            let preview = make_preview(&app.ctx, index, &capture);
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shots.get_mut(index)) {
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
            app.previews.insert(index, preview);
            if app.selected_shot == Some(index) {
                update_inspection(app);
            }
        }
        JobOutput::ShotUnreadable { index, reason } => {
            app.error(reason.clone());
            app.unreadable.insert(index, reason);
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
        JobOutput::KernelsMeasured { index, result } => {
            let result = result.map_err(|e| app.shorten_paths(e));
            let status = match &result {
                Ok(file) => StageStatus::Done {
                    summary: format!(
                        "{} kernels, {} failed",
                        file.samples.len(),
                        file.failed.len()
                    ),
                },
                Err(reason) => StageStatus::Failed {
                    reason: reason.clone(),
                },
            };
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shots.get_mut(index)) {
                shot.kernels = status;
            }
            match result {
                Ok(file) => {
                    app.measured.insert(index, file);
                    app.measured_generation += 1;
                    update_inspection(app);
                }
                Err(e) => app.error(e),
            }
            save(app);
        }
        JobOutput::DatasetReady(ds) => app.dataset = ds,
        JobOutput::ResultsRead {
            detections,
            measured,
            cv,
        } => {
            app.detections = detections;
            app.measured = measured;
            app.measured_generation += 1;
            if app.cv.is_none() {
                app.cv = cv;
            }
            update_inspection(app);
            spawn_dataset(app);
        }
        JobOutput::Detected { index, result } => {
            let result = result.map_err(|e| app.shorten_paths(e));
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
            let texture = rgb_texture(&app.ctx, "photo", &crate::raw::full_planes(&capture), None);
            // Settings: EXIF first, then the session's record of the same file.
            let recorded = app.session.as_ref().and_then(|s| {
                (0..s.shots.len())
                    .find(|&i| s.shot_path(i) == path)
                    .map(|i| (s.shots[i].focal_mm, s.shots[i].f_number))
            });
            let (rf, ra) = recorded.unwrap_or((None, None));
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
            app.deblur.comparison = Some(ComparisonView {
                comparison,
                measured_from,
                textures,
            });
        }
        JobOutput::DeblurExported(path) => {
            app.info(format!(
                "deblurred photo written to {}",
                app.shown_path(&path)
            ));
        }
    }
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
        Command::RemoveShot(i) => remove_shot(app, i),
        Command::SetShotSetting {
            index,
            focal_mm,
            f_number,
        } => {
            if let Some(shot) = app.session.as_mut().and_then(|s| s.shots.get_mut(index)) {
                shot.focal_mm = focal_mm;
                shot.f_number = f_number;
                save(app);
                spawn_dataset(app);
            }
        }
        Command::ApplySettings { chart, settings } => apply_settings(app, chart, settings),
        Command::LoadChartDialog => {
            if let Some(path) = rfd::FileDialog::new()
                .set_title("Load a chart spec")
                .add_filter("chart spec", &["json"])
                .pick_file()
            {
                match crate::chart::ChartSpec::load(&path) {
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
                }
            }
        }
        Command::RunDetect(which) => run_detect(app, which),
        Command::RunKernels(which) => run_kernels(app, which),
        Command::RunCalibrate => run_calibrate(app),
        Command::SetFieldSource(f) => app.field_source = f,
        Command::SetFieldShow(f) => app.field_show = f,
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
            let r = app.jobs.spawn("open photo", move |ctx, out| {
                ctx.report("loading", 0, 1);
                let capture = load_capture(&path)?;
                ctx.report("loading", 1, 1);
                out.emit(JobOutput::PhotoLoaded {
                    path,
                    capture: Arc::new(capture),
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
        Command::SetDeblurLayout(l) => app.deblur.layout = l,
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
            let mut dialog = rfd::FileDialog::new()
                .set_title("Export the deblurred photo (16-bit linear)")
                .add_filter("TIFF or PNG", &["tiff", "tif", "png"])
                .set_file_name(format!("{stem}.deblurred-{which}.tiff"));
            if let Some(dir) = photo.path.parent() {
                dialog = dialog.set_directory(dir);
            }
            if let Some(path) = dialog.save_file() {
                apply(app, Command::ExportDeblur { path, result });
            }
        }
        Command::ExportDeblur { path, result } => run_export(app, path, result),
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
                .add_filter("lens profile", &["json"])
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
        app.viewer.sensor_px_per_point = None;
        save(app);
    }
}

/// Removes a shot from the session (its file and results stay on disk); every map keyed
/// by shot index moves the later shots down by one.
fn remove_shot(app: &mut StudioApp, i: usize) {
    let Some(s) = app.session.as_mut() else {
        return;
    };
    if i >= s.shots.len() {
        return;
    }
    s.shots.remove(i);
    let n = s.shots.len();
    fn shift<T>(map: &mut BTreeMap<usize, T>, removed: usize) {
        let old = std::mem::take(map);
        *map = old
            .into_iter()
            .filter(|(k, _)| *k != removed)
            .map(|(k, v)| (if k > removed { k - 1 } else { k }, v))
            .collect();
    }
    shift(&mut app.previews, i);
    shift(&mut app.unreadable, i);
    shift(&mut app.detections, i);
    shift(&mut app.measured, i);
    app.loading = app
        .loading
        .iter()
        .filter(|&&k| k != i)
        .map(|&k| if k > i { k - 1 } else { k })
        .collect();
    app.measured_generation += 1;
    app.selected_shot = if n == 0 { None } else { Some(i.min(n - 1)) };
    app.selected_square = None;
    app.inspection = None;
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
        app.inspection = None;
    }
    if kernels_changed {
        app.measured.clear();
        app.measured_generation += 1;
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
        match load_capture(&path) {
            Ok(capture) => {
                ctx.check().map_err(|e| e.to_string())?;
                out.emit(JobOutput::ShotLoaded {
                    index,
                    capture: Arc::new(capture),
                });
            }
            Err(reason) => out.emit(JobOutput::ShotUnreadable { index, reason }),
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
    crate::raw::load_capture(path, &crate::raw::LoadOptions::default()).map_err(|e| e.to_string())
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

/// Shots a stage should run on: the one asked for, or every readable shot without a
/// result.
fn targets(app: &StudioApp, which: Option<usize>, done: impl Fn(usize) -> bool) -> Vec<usize> {
    let n = app.session.as_ref().map_or(0, |s| s.shots.len());
    match which {
        Some(i) if i < n => vec![i],
        Some(_) => Vec::new(),
        None => (0..n)
            .filter(|&i| !done(i) && !app.unreadable.contains_key(&i))
            .collect(),
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
    let n = work.len();
    let r = app.jobs.spawn("detect", move |ctx, out| {
        for (k, (index, shot, result_path, capture)) in work.into_iter().enumerate() {
            ctx.check().map_err(|e| e.to_string())?;
            let shot_ctx = ctx.prefixed(&format!("shot {} of {n}: ", k + 1));
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
            let result =
                match crate::detect::detect(&capture, &spec, &DetectParams::default(), &shot_ctx) {
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
    if let Some(dir) = path.parent() {
        crate::io::create_dir_all(dir).map_err(|e| e.to_string())?;
    }
    crate::io::write_json(path, value).map_err(|e| e.to_string())
}

/// Reads the detections, kernels and cross-validation report a session already has on
/// disk, off the UI thread (kernels files with their arrays run to megabytes).
pub(super) fn read_results(app: &mut StudioApp, session: &Session) {
    let detect: Vec<(usize, PathBuf)> = (0..session.shots.len())
        .filter(|&i| session.shots[i].detect.is_done())
        .map(|i| (i, session.result_path(i, "detect")))
        .collect();
    let kernels: Vec<(usize, PathBuf)> = (0..session.shots.len())
        .filter(|&i| session.shots[i].kernels.is_done())
        .map(|i| (i, session.result_path(i, "kernels")))
        .collect();
    let cv_path = session.folder().join(CV_FILE);
    if detect.is_empty() && kernels.is_empty() && !cv_path.is_file() {
        return;
    }
    let r = app.jobs.spawn("read results", move |ctx, out| {
        let total = detect.len() + kernels.len();
        let mut detections = BTreeMap::new();
        for (k, (i, path)) in detect.into_iter().enumerate() {
            ctx.check().map_err(|e| e.to_string())?;
            ctx.report("reading results", k, total);
            let text =
                std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
            let file: DetectFile =
                serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
            detections.insert(i, Arc::new(Detection::from_file(&file)));
        }
        let n_detect = detections.len();
        let mut measured = BTreeMap::new();
        for (k, (i, path)) in kernels.into_iter().enumerate() {
            ctx.check().map_err(|e| e.to_string())?;
            ctx.report("reading results", n_detect + k, total);
            let file = KernelsFile::load(&path).map_err(|e| e.to_string())?;
            measured.insert(i, Arc::new(file));
        }
        let cv = std::fs::read_to_string(&cv_path)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .map(Arc::new);
        out.emit(JobOutput::ResultsRead {
            detections,
            measured,
            cv,
        });
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// The session's measured Gaussians over every shot with kernels and known settings,
/// for the sweeps (rebuilt when kernels or settings change).
fn spawn_dataset(app: &mut StudioApp) {
    let Some(session) = app.session.as_ref() else {
        return;
    };
    let done: Vec<usize> = (0..session.shots.len())
        .filter(|&i| session.shots[i].kernels.is_done() && session.shots[i].setting().is_some())
        .collect();
    if done.is_empty() {
        app.dataset = None;
        return;
    }
    let paths: Vec<PathBuf> = done
        .iter()
        .map(|&i| session.result_path(i, "kernels"))
        .collect();
    let settings: Vec<_> = done.iter().map(|&i| session.shots[i].setting()).collect();
    let names: Vec<String> = done.iter().map(|&i| session.shots[i].stem()).collect();
    let r = app.jobs.spawn("gather measurements", move |_ctx, out| {
        let refs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
        let ds = crate::model::Dataset::from_kernels_files(&refs, &settings).map(|mut ds| {
            for (info, name) in ds.shots.iter_mut().zip(names) {
                info.name = name;
            }
            Arc::new(ds)
        });
        match ds {
            Ok(ds) => out.emit(JobOutput::DatasetReady(Some(ds))),
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
    let facts = (square.status == crate::detect::SquareStatus::Ok)
        .then(|| crate::review::square_facts(square));
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
    let kernel = app
        .measured
        .get(&shot)
        .and_then(|file| {
            let s = file
                .samples
                .iter()
                .find(|s| s.channel == channel && s.row == Some(sq.0) && s.col == Some(sq.1))?;
            s.kernel_at(file.oversample)
        })
        .map(|k| {
            let peak = k.data.iter().copied().fold(1e-12, f64::max);
            let img = egui::ColorImage::from_gray_iter(
                [k.size, k.size],
                k.data
                    .iter()
                    .map(|&v| ((v / peak).clamp(0.0, 1.0) * 255.0) as u8),
            );
            app.ctx
                .load_texture("inspect-kernel", img, egui::TextureOptions::NEAREST)
        });
    app.inspection = Some(super::Inspection {
        shot,
        square: sq,
        channel,
        crops,
        facts,
        textures,
        kernel,
    });
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
    let done: Vec<usize> = (0..session.shots.len())
        .filter(|&i| session.shots[i].kernels.is_done())
        .collect();
    if done.len() < 2 {
        app.error("calibration needs kernels on at least two shots: run Detect (Ctrl+D) and Kernels (Ctrl+K) first");
        return;
    }
    let missing: Vec<String> = done
        .iter()
        .filter(|&&i| session.shots[i].setting().is_none())
        .map(|&i| session.shots[i].stem())
        .collect();
    if !missing.is_empty() {
        app.error(format!(
            "calibration needs the focal length and aperture of every shot: type them for {}",
            missing.join(", ")
        ));
        return;
    }
    let paths: Vec<PathBuf> = done
        .iter()
        .map(|&i| session.result_path(i, "kernels"))
        .collect();
    let settings: Vec<_> = done.iter().map(|&i| session.shots[i].setting()).collect();
    let names: Vec<String> = done.iter().map(|&i| session.shots[i].stem()).collect();
    let chart = session.chart.clone();
    let out_path = session.folder().join("profile.json");
    let cv_path = session.folder().join(CV_FILE);
    let opts = crate::calibrate::CalibrateOptions {
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
        let (profile, cv) = crate::calibrate::calibrate(&ds, Some(chart), &opts, ctx)
            .map_err(|e| format!("calibration: {e}"))?;
        profile.save(&out_path).map_err(|e| e.to_string())?;
        match &cv {
            Some(report) => write_result(&cv_path, report)?,
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
        Option<LensSetting>,
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
    let n = work.len();
    let r = app.jobs.spawn("kernels", move |ctx, out| {
        for (k, (index, shot, result_path, capture, det, setting)) in work.into_iter().enumerate() {
            ctx.check().map_err(|e| e.to_string())?;
            let shot_ctx = ctx.prefixed(&format!("shot {} of {n}: ", k + 1));
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
            let result =
                match crate::kernel::estimate_shot(&capture, &det, &spec, &params, &shot_ctx) {
                    Ok(k) => {
                        let file = KernelsFile::from_shot(
                            &k,
                            setting.map(|s| s.focal_mm).or(capture.setting_focal_mm),
                            setting.map(|s| s.f_number).or(capture.setting_f_number),
                            Some(capture.identity.clone()),
                            true,
                        );
                        write_result(&result_path, &file).map(|()| Arc::new(file))
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

fn deblur_options(app: &StudioApp) -> DeblurOptions {
    let method = app
        .session
        .as_ref()
        .and_then(|s| Method::from_name(&s.settings.deblur_method))
        .unwrap_or_default();
    DeblurOptions {
        method,
        ..DeblurOptions::default()
    }
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
        (Some(s), Some(set)) => crate::review::measured_kernels_for(s, cap.width, cap.height, set)
            .map(|(i, path)| (s.shots[i].stem(), path)),
        _ => None,
    };
    let (measured, from) = match (found, setting) {
        (Some((name, path)), _) => (crate::review::measured_source(&path), Some(name)),
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
    // A newer preview replaces one still running.
    for h in &app.jobs.running {
        if h.name == "deblur preview" {
            h.cancel();
        }
    }
    let cap = Arc::clone(&photo.capture);
    let region = crate::review::Region::around(
        centre[0],
        centre[1],
        app.deblur.crop_px,
        cap.width,
        cap.height,
    );
    let (predicted, measured, from) = photo_sources(app, photo);
    let opts = deblur_options(app);
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
    let r = app.jobs.spawn("export", move |ctx, out| {
        crate::review::export_deblurred(&cap, source.as_ref(), &opts, &path, ctx)?;
        out.emit(JobOutput::DeblurExported(path));
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// The measured kernels of the selected shot and channel packed into one texture: the
/// central ±R px of each (R = 2.5 × the largest σ of the field, so every kernel shows
/// the same extent and shapes compare), each scaled to its own peak (σ is in the tint).
pub(super) fn ensure_kernel_atlas(app: &mut StudioApp) {
    let Some(shot) = app.selected_shot else {
        app.kernel_atlas = None;
        return;
    };
    let key = (shot, app.channel, app.measured_generation);
    if app.kernel_atlas.as_ref().is_some_and(|a| a.key == key) {
        return;
    }
    app.kernel_atlas = None;
    let Some(file) = app.measured.get(&shot) else {
        return;
    };
    let samples: Vec<(usize, crate::psf::Kernel)> = file
        .samples
        .iter()
        .enumerate()
        .filter(|(_, s)| s.channel == app.channel)
        .filter_map(|(i, s)| Some((i, s.kernel_at(file.oversample)?)))
        .collect();
    if samples.is_empty() {
        return;
    }
    let max_sigma = file
        .samples
        .iter()
        .filter(|s| s.channel == app.channel)
        .filter_map(|s| Some(s.cxx?.max(s.cyy?)))
        .fold(0.5, f64::max);
    let extent_px = (2.5 * max_sigma).max(2.0);
    let os = file.oversample.max(1);
    let half = (extent_px * os as f64).ceil() as usize;
    let cell = 2 * half + 1;
    let per_row = (samples.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = samples.len().div_ceil(per_row);
    let (w, h) = (per_row * cell, rows * cell);
    let mut img = egui::ColorImage::filled([w, h], egui::Color32::TRANSPARENT);
    let mut cells = Vec::with_capacity(samples.len());
    for (n, (i, k)) in samples.iter().enumerate() {
        let (cx, cy) = ((n % per_row) * cell, (n / per_row) * cell);
        let c = (k.size / 2) as isize;
        let peak = k.data.iter().copied().fold(1e-12, f64::max);
        for j in 0..cell {
            for q in 0..cell {
                let (kx, ky) = (
                    c + q as isize - half as isize,
                    c + j as isize - half as isize,
                );
                if kx < 0 || ky < 0 || kx >= k.size as isize || ky >= k.size as isize {
                    continue;
                }
                let v = (k.at(kx as usize, ky as usize) / peak).clamp(0.0, 1.0);
                img[(cx + q, cy + j)] = egui::Color32::from_white_alpha((v * 255.0) as u8);
            }
        }
        let uv = egui::Rect::from_min_size(
            egui::Pos2::new(cx as f32 / w as f32, cy as f32 / h as f32),
            egui::Vec2::new(cell as f32 / w as f32, cell as f32 / h as f32),
        );
        cells.push((*i, uv));
    }
    let texture = app
        .ctx
        .load_texture("kernel-atlas", img, egui::TextureOptions::NEAREST);
    app.kernel_atlas = Some(KernelAtlas {
        key,
        texture,
        cells,
        extent_px: half as f64 / os as f64,
    });
}
