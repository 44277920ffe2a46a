//! The lens's geometry: measured from the project's detections on a job of low
//! priority, recorded in the project as it comes back, and the lensfun entry written
//! from it on a job of its own (the shot's EXIF is read there; the names and the checks
//! are the core's, as `lensblur lensfun` makes them).

use crate::app::jobs::{JobKind, JobScope};
use crate::app::{GeometryCommand, GeometryOutput};
use crate::app::{JobOutput, StudioApp};
use crate::correction::lensfun::{NameOverrides, checked_entry};
use crate::correction::{LensCorrection, LensfunNames};
use std::path::PathBuf;
use std::sync::Arc;

pub(super) fn apply_geometry(app: &mut StudioApp, command: GeometryCommand) {
    match command {
        GeometryCommand::ExportLensfun(path) => export_lensfun(app, path),
    }
}

pub(super) fn geometry_output(app: &mut StudioApp, output: GeometryOutput) {
    match output {
        GeometryOutput::GeometryMeasured(measured) => {
            if let Some(p) = app.project.as_mut() {
                p.record_geometry(*measured);
            }
        }
        GeometryOutput::LensfunExported { path, lens } => {
            let shown = app.shown_path(&path);
            app.info(format!(
                "Wrote the lensfun entry for {lens} to {shown}: copy it to ~/.local/share/lensfun/ for darktable and RawTherapee"
            ));
        }
    }
}

/// Measures the lens's geometry where the project's detections or settings changed
/// since it was measured, whichever view is open. It comes last: only when no other
/// job runs and no command waits, so it never holds back the stages (the demo's first
/// calibration and its photo included), and a run of detections is measured once,
/// after the last.
pub(super) fn measure_geometry(app: &mut StudioApp) {
    if !app.jobs.running.is_empty() || !app.commands.is_empty() {
        return;
    }
    let Some(job) = app
        .project
        .as_mut()
        .and_then(crate::project::Project::geometry_job)
    else {
        return;
    };
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped(JobKind::Geometry, scope, move |_ctx, out| {
            // Its failure is its result: the view says why.
            out.emit(JobOutput::Geometry(GeometryOutput::GeometryMeasured(
                Box::new(job.run()),
            )));
            Ok(())
        });
    if let Err(e) = r
        && let Some(p) = app.project.as_mut()
    {
        p.geometry_abandoned(e);
    }
}

/// The names the demo's entry is written under: its shots are PNGs without EXIF, so the
/// simulated camera's and lens's names stand in, as its DNGs would carry them.
fn demo_names() -> NameOverrides {
    let lens = crate::simulate::VirtualLens::demo();
    NameOverrides {
        camera_maker: Some("Virtual".into()),
        camera_model: Some("Sim 14".into()),
        lens_maker: Some(lens.make),
        lens_model: Some(lens.model),
        mount: None,
        crop_factor: Some(crate::simulate::capture::SIM_CROP_FACTOR),
        focal_range_mm: Some(lens.focal_range_mm),
    }
}

/// Writes the measured geometry as a lensfun entry on a job: the first detected shot's
/// EXIF names the camera and lens; what the core refuses (no lens name, one focal
/// length, uneven light) is said as an error.
fn export_lensfun(app: &mut StudioApp, path: PathBuf) {
    let Some(correction) = measured_geometry(app) else {
        app.error("nothing to export yet: the lens's geometry is not measured");
        return;
    };
    let Some(session) = app.session() else {
        return;
    };
    let is_demo = session.is_demo;
    let first = session
        .shots
        .iter()
        .find(|s| s.setting().is_some() && app.detection(s.id).is_some())
        .map(|s| session.folder().join(&s.path));
    let Some(first) = first else {
        app.error("nothing to export: no shot has a detected chart");
        return;
    };
    let provenance = format!(
        "written by lensblur {} studio from the session '{}' ({} × {} px); distortion {}, lateral colour {}",
        env!("CARGO_PKG_VERSION"),
        session.name,
        correction.width,
        correction.height,
        correction.distortion_model.name(),
        correction.tca_model.name()
    );
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped(JobKind::LensfunExport, scope, move |_ctx, out| {
            let lens = write_entry(&correction, &first, is_demo, &path, &provenance)
                .map_err(|e| format!("cannot export the lensfun entry: {e}"))?;
            out.emit(JobOutput::Geometry(GeometryOutput::LensfunExported {
                path,
                lens,
            }));
            Ok(())
        });
    if let Err(e) = r {
        app.error(e);
    }
}

fn write_entry(
    correction: &Arc<LensCorrection>,
    first_shot: &std::path::Path,
    is_demo: bool,
    path: &std::path::Path,
    provenance: &str,
) -> Result<String, String> {
    let (exif, overrides) = if is_demo {
        (crate::raw::ExifInfo::default(), demo_names())
    } else {
        let header = crate::raw::read_header(first_shot).map_err(|e| e.to_string())?;
        (header.exif, NameOverrides::default())
    };
    let focals: Vec<f64> = correction.focal.iter().map(|f| f.focal_mm).collect();
    let names = LensfunNames::resolve(&exif, &overrides, &focals)
        .map_err(|e| format!("{}: {e}", first_shot.display()))?;
    let xml = checked_entry(&names, correction, false, provenance).map_err(|e| e.to_string())?;
    crate::io::write_atomic(path, xml.as_bytes()).map_err(|e| e.to_string())?;
    Ok(format!(
        "{} {} on {} {}",
        names.lens_maker, names.lens_model, names.camera_maker, names.camera_model
    ))
}

/// The project's measured geometry, once there is one for its present detections.
pub(super) fn measured_geometry(app: &StudioApp) -> Option<Arc<LensCorrection>> {
    app.project.as_ref()?.geometry()?.as_ref().ok().cloned()
}
