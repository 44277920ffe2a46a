//! The Deblur view: the photo, the preview of a region deblurred with both kernel
//! sources, and exports of whole photos.

use super::apply;
use super::shots::{develop_for_display, load_capture};
use crate::app::jobs::JobKind;
use crate::app::textures::{developed_texture, rgb_texture};
use crate::app::{
    Command, ComparisonView, DeblurResult, DeblurZoom, JobOutput, Photo, PreviewScope, StudioApp,
};
use crate::app::{DeblurCommand, DeblurOutput};
use crate::deblur::{DeblurOptions, KernelSource, Method};
use crate::develop::Developed;
use crate::plane::Capture;
use std::path::PathBuf;
use std::sync::Arc;

/// The Deblur view: its photo, its region and controls, exports.
pub(super) fn apply_deblur(app: &mut StudioApp, command: DeblurCommand) {
    match command {
        DeblurCommand::OpenPhoto(path) => {
            let r = app.jobs.spawn(JobKind::OpenPhoto, move |ctx, out| {
                ctx.report("loading", 0, 1);
                let capture = load_capture(&path)?;
                let developed = develop_for_display(&capture);
                ctx.report("loading", 1, 1);
                out.emit(JobOutput::Deblur(DeblurOutput::PhotoLoaded {
                    path,
                    capture: Arc::new(capture),
                    developed,
                }));
                Ok(())
            });
            if let Err(e) = r {
                app.error(e);
            }
        }
        DeblurCommand::SetPhotoSetting { focal_mm, f_number } => {
            if let Some(p) = app.views.deblur.photo.as_mut() {
                p.focal_mm = focal_mm;
                p.f_number = f_number;
            }
        }
        DeblurCommand::DeblurAt(centre) => run_deblur_preview(app, centre),
        DeblurCommand::SetDeblurLayout(l) => {
            app.views.deblur.layout = l;
            app.views.deblur.viewport = None;
        }
        DeblurCommand::SetDeblurZoom(z) => {
            app.views.deblur.zoom = z;
            app.views.deblur.viewport = None;
            if z == DeblurZoom::Fit {
                redeblur(app);
            }
        }
        DeblurCommand::SetDeblurViewport(v) => {
            if app.views.deblur.viewport != Some(v) {
                app.views.deblur.viewport = Some(v);
                redeblur(app);
            }
        }
        DeblurCommand::SetDeblurCrop(px) => {
            app.views.deblur.crop_px = px.clamp(32, 4096);
            redeblur(app);
        }
        DeblurCommand::SetDeblurMethod(m) => {
            app.views.deblur.method = Some(m);
            app.views.deblur.scope = None;
            redeblur(app);
        }
        DeblurCommand::SetDeblurOverview(open) => {
            app.views.deblur.overview_open = open;
            // The panes' size changes: at 100 % and more, the region follows it.
            app.views.deblur.viewport = None;
        }
        DeblurCommand::SetDeblurAmount(percent) => {
            app.views.deblur.amount = crate::deblur::Amount::percent(percent);
            redeblur(app);
        }
        DeblurCommand::SetDeblurFringes(f) => {
            app.views.deblur.fringes = f;
            redeblur(app);
        }
        DeblurCommand::SetDeblurLateral(l) => {
            app.views.deblur.lateral = l;
            redeblur(app);
        }
        DeblurCommand::SetDeblurDevice(d) => {
            app.views.deblur.device = d;
            app.views.deblur.device_note = None;
            app.views.deblur.scope = None;
            redeblur(app);
        }
        DeblurCommand::DragDeblur(d) => {
            app.views.deblur.drag[0] += d[0];
            app.views.deblur.drag[1] += d[1];
        }
        DeblurCommand::EndDragDeblur => {
            let d = std::mem::take(&mut app.views.deblur.drag);
            if let Some(c) = app.views.deblur.comparison.as_ref() {
                let [cx, cy] = c.comparison.region.centre();
                run_deblur_preview(app, [cx - f64::from(d[0]), cy - f64::from(d[1])]);
            }
        }
        DeblurCommand::SetSliderResult(r) => app.views.deblur.slider_result = r,
        DeblurCommand::SetSlider(t) => app.views.deblur.slider = t.clamp(0.0, 1.0),
        DeblurCommand::ExportDeblur { path, result } => run_export(app, path, result),
        DeblurCommand::ExportPhotos {
            photos,
            out_dir,
            dng,
        } => run_export_photos(app, photos, out_dir, dng),
    }
}

/// The photo opened, its deblurred crops, and exports done.
pub(super) fn deblur_output(app: &mut StudioApp, output: DeblurOutput) {
    match output {
        DeblurOutput::PhotoLoaded {
            path,
            capture,
            developed,
        } => photo_loaded(app, path, capture, developed),
        DeblurOutput::DeblurCompared {
            comparison,
            measured_from,
            whole_ms,
        } => {
            if let (Some(ms), Some(PreviewScope::Trial)) = (whole_ms, &app.views.deblur.scope) {
                app.views.deblur.scope = Some(preview_scope(Ok(()), Some(ms)));
            }
            deblur_compared(app, comparison, measured_from);
        }
        DeblurOutput::DeblurExported(path) => {
            app.info(format!(
                "deblurred photo written to {}",
                app.shown_path(&path)
            ));
        }
        DeblurOutput::PhotosExported(report) => {
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

/// Deblurred crops of the region: their textures, on one display scale.
fn deblur_compared(
    app: &mut StudioApp,
    comparison: Arc<crate::review::DeblurComparison>,
    measured_from: Option<String>,
) {
    let textures = [
        Some(&comparison.original),
        comparison.predicted.as_ref().ok(),
        comparison.measured.as_ref().ok(),
    ];
    // One display scale for the three crops: the original's white points, so a
    // result that overshoots shows it rather than being stretched back.
    let whites = crate::review::display_whites(&comparison.original);
    let textures = textures
        .map(|planes| planes.and_then(|p| rgb_texture(&app.ctx, "deblur-crop", p, Some(&whites))));
    let developed = match &comparison.developed {
        Some(Ok(crops)) => crops.each_ref().map(|d| {
            d.as_ref()
                .map(|d| developed_texture(&app.ctx, "deblur-crop-developed", d))
        }),
        _ => [None, None, None],
    };
    app.views.deblur.comparison = Some(ComparisonView {
        comparison,
        measured_from,
        textures,
        developed,
    });
}

/// The photo opened: its textures, its setting, and a first preview at its centre.
fn photo_loaded(
    app: &mut StudioApp,
    path: PathBuf,
    capture: Arc<Capture>,
    developed: Option<Result<Developed, String>>,
) {
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
    let recorded = app.session().and_then(|s| {
        s.shots
            .iter()
            .find(|shot| s.path_of(shot) == path)
            .map(|shot| (shot.focal_mm, shot.f_number))
    });
    // The demo's photo is a PNG: its setting is in the session instead.
    let demo = app.session().and_then(|s| {
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
    app.views.deblur.photo = Some(Photo {
        path,
        focal_mm: capture.setting_focal_mm.or(rf),
        f_number: capture.setting_f_number.or(ra),
        kind: capture.picture_kind(),
        capture,
        texture,
        developed,
    });
    app.views.deblur.comparison = None;
    app.views.deblur.scope = None;
    apply(app, Command::Deblur(DeblurCommand::DeblurAt(centre)));
}

/// The method the Deblur view uses: its own once changed there, else the session's.
pub(crate) fn deblur_method(app: &StudioApp) -> Method {
    app.views.deblur.method.unwrap_or_else(|| {
        app.session()
            .and_then(|s| Method::from_name(&s.settings.deblur_method))
            .unwrap_or_default()
    })
}

fn deblur_options(app: &StudioApp) -> DeblurOptions {
    DeblurOptions {
        method: deblur_method(app),
        device: app.views.deblur.device,
        amount: app.views.deblur.amount,
        fringes: app.views.deblur.fringes,
        ..DeblurOptions::default()
    }
}

/// Deblurs the region again where it is (after a control or the profile changed).
pub(super) fn redeblur(app: &mut StudioApp) {
    let centre = match (&app.views.deblur.comparison, &app.views.deblur.photo) {
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
    let predicted = match app.profile() {
        Some((_, p)) => crate::review::profile_source(p, cap, setting)
            .map(|s| s.with_lateral(app.views.deblur.lateral)),
        None => Err("no profile yet: Calibrate (Ctrl+M) or load one in Models".into()),
    };
    let found = match (app.session(), setting) {
        (Some(s), Some(set)) => s.shots.iter().find_map(|shot| {
            let file = app.kernels(shot.id)?;
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

/// The longest a preview of the whole photo may take for the view to redo it live as a
/// control moves: beyond it, dragging the amount would lag behind the hand.
pub const WHOLE_PHOTO_MS: f64 = 150.0;

/// The one rule for what the preview deblurs: the whole photo only where it runs on a
/// hardware GPU (`gpu`: `Err` with why not) and, once a first whole-photo preview has
/// been timed (`first_ms`), only when that took under [`WHOLE_PHOTO_MS`]; else crops,
/// with why in one short sentence.
#[must_use]
pub fn preview_scope(gpu: Result<(), String>, first_ms: Option<f64>) -> PreviewScope {
    match (gpu, first_ms) {
        (Err(why), _) => PreviewScope::Crops(why),
        (Ok(()), None) => PreviewScope::Trial,
        (Ok(()), Some(ms)) if ms < WHOLE_PHOTO_MS => PreviewScope::Whole { ms },
        (Ok(()), Some(ms)) => PreviewScope::Crops(format!(
            "The whole photo took {ms:.0} ms on the GPU (over {WHOLE_PHOTO_MS:.0}); showing crops."
        )),
    }
}

/// Whether `opts` deblur on a hardware GPU, else why the whole photo is not previewed.
fn hardware_gpu(opts: &DeblurOptions) -> Result<(), String> {
    match crate::deblur::gpu::resolve(opts.device, &opts.method) {
        Ok(Some(g)) if !g.adapter().software => Ok(()),
        _ => Err("Whole-photo preview needs a hardware GPU; showing crops.".into()),
    }
}

/// Deblurs the open photo around `centre` with both sources: a crop, or the whole
/// photo where [`preview_scope`] allows it and the panes fit the photo.
pub(super) fn run_deblur_preview(app: &mut StudioApp, centre: [f64; 2]) {
    let Some(photo) = &app.views.deblur.photo else {
        return;
    };
    // A newer preview replaces one still running: that one is cancelled and this one
    // waits for it to stop. One preview at a time, the latest request kept, so a
    // control dragged over many frames never queues a preview per frame.
    let mut busy = false;
    for h in &app.jobs.running {
        if h.kind == JobKind::DeblurPreview {
            h.cancel();
            busy = true;
        }
    }
    if busy {
        app.views.deblur.pending = Some(centre);
        return;
    }
    let cap = Arc::clone(&photo.capture);
    let opts = deblur_options(app);
    let scope = app
        .views
        .deblur
        .scope
        .get_or_insert_with(|| preview_scope(hardware_gpu(&opts), None));
    let whole = scope.whole() && app.views.deblur.zoom == DeblurZoom::Fit;
    let region = match (app.views.deblur.zoom, app.views.deblur.viewport) {
        _ if whole => crate::review::Region::around_size(
            cap.width as f64 / 2.0,
            cap.height as f64 / 2.0,
            cap.width,
            cap.height,
            cap.width,
            cap.height,
        ),
        (DeblurZoom::Times(_), Some([w, h])) => {
            crate::review::Region::around_size(centre[0], centre[1], w, h, cap.width, cap.height)
        }
        _ => crate::review::Region::around(
            centre[0],
            centre[1],
            app.views.deblur.crop_px,
            cap.width,
            cap.height,
        ),
    };
    let (predicted, measured, from) = photo_sources(app, photo);
    if app.views.deblur.device_note.is_none() {
        // Where the preview runs, said once per choice (opening a device is the core's).
        let note = crate::deblur::gpu::describe(opts.device, &opts.method);
        app.views.deblur.device_note = Some(note);
    }
    let r = app.jobs.spawn(JobKind::DeblurPreview, move |ctx, out| {
        let started = std::time::Instant::now();
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
        out.emit(JobOutput::Deblur(DeblurOutput::DeblurCompared {
            comparison: Arc::new(comparison),
            measured_from: from,
            whole_ms: whole.then(|| started.elapsed().as_secs_f64() * 1e3),
        }));
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Deblurs a set of photos with the open profile, each at its own EXIF setting, as the
/// command line's batch does (skips and failures reported photo by photo).
fn run_export_photos(app: &mut StudioApp, photos: Vec<PathBuf>, out_dir: PathBuf, dng: bool) {
    let Some((path, profile)) = app.profile() else {
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
        lateral_colour: app.views.deblur.lateral,
        memory_budget: None,
        max_parallel: None,
    };
    let r = app.jobs.spawn(JobKind::ExportPhotos, move |ctx, out| {
        let report = crate::batch::deblur_photos(&photos, &library, &opts, ctx);
        out.emit(JobOutput::Deblur(DeblurOutput::PhotosExported(report)));
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

/// Deblurs the whole open photo with one source and writes it.
fn run_export(app: &mut StudioApp, path: PathBuf, result: DeblurResult) {
    let Some(photo) = &app.views.deblur.photo else {
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
    let r = app.jobs.spawn(JobKind::ExportPhoto, move |ctx, out| {
        crate::deblur::output::deblur_and_write(
            &cap,
            source.as_ref(),
            &opts,
            &path,
            original,
            &note,
            ctx,
        )
        .map_err(|e| e.to_string())?;
        out.emit(JobOutput::Deblur(DeblurOutput::DeblurExported(path)));
        Ok(())
    });
    if let Err(e) = r {
        app.error(e);
    }
}

#[cfg(test)]
mod tests {
    use super::{PreviewScope, WHOLE_PHOTO_MS, preview_scope};

    #[test]
    fn the_whole_photo_is_previewed_only_on_a_hardware_gpu_fast_enough() {
        let why = "Whole-photo preview needs a hardware GPU; showing crops.".to_owned();
        // A software rasteriser or the CPU: crops, whatever a time says.
        assert_eq!(
            preview_scope(Err(why.clone()), None),
            PreviewScope::Crops(why.clone())
        );
        assert_eq!(
            preview_scope(Err(why.clone()), Some(1.0)),
            PreviewScope::Crops(why)
        );
        // A hardware GPU: the first preview is of the whole photo, and its time decides.
        assert_eq!(preview_scope(Ok(()), None), PreviewScope::Trial);
        assert!(PreviewScope::Trial.whole());
        assert_eq!(
            preview_scope(Ok(()), Some(40.0)),
            PreviewScope::Whole { ms: 40.0 }
        );
        let slow = preview_scope(Ok(()), Some(WHOLE_PHOTO_MS));
        assert!(!slow.whole());
        assert!(
            matches!(&slow, PreviewScope::Crops(w) if w.contains("150 ms")),
            "{slow:?}"
        );
    }
}
