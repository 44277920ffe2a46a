//! Loading the session's shots for display, one at a time, and their textures.

use super::save;
use crate::app::ShotOutput;
use crate::app::ShotView;
use crate::app::jobs::{JobKind, JobScope};
use crate::app::textures::{channel_texture, developed_texture, encode};
use crate::app::{JobOutput, ShotPreview, StudioApp};
use crate::develop::Developed;
use crate::pipeline::{self};
use crate::plane::{Capture, Channel};
use crate::session::ShotId;
use std::path::Path;
use std::sync::Arc;

/// A shot loaded for display, or why it cannot be read.
pub(super) fn shot_output(app: &mut StudioApp, output: ShotOutput) {
    match output {
        ShotOutput::ShotLoaded {
            shot: id,
            capture,
            developed,
        } => {
            if !app.has_shot(id) {
                return;
            }
            let preview = make_preview(&app.ctx, id, &capture, developed);
            if let Some(shot) = app.session_mut().and_then(|s| s.shot_mut(id)) {
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
            app.shots.insert(id, ShotView::Loaded(preview));
        }
        ShotOutput::ShotUnreadable { shot, reason } => {
            if app.has_shot(shot) {
                app.error(reason.clone());
                app.shots.insert(shot, ShotView::Unreadable(reason));
            }
        }
    }
}

pub(in crate::app) fn ensure_preview(app: &mut StudioApp) {
    let Some(s) = app.session() else { return };
    if app.jobs.is_running(JobKind::LoadShot) {
        return;
    }
    let order = app
        .views
        .shot
        .selected
        .into_iter()
        .chain(s.shots.iter().map(|shot| shot.id));
    let Some(id) = order
        .filter(|id| s.shot(*id).is_some())
        .find(|id| !app.shots.contains_key(id))
    else {
        return;
    };
    let Some(path) = s.shot(id).map(|shot| s.path_of(shot)) else {
        return;
    };
    app.shots.insert(id, ShotView::Loading);
    let scope = JobScope::shots(app.session_generation, vec![id]);
    let r = app
        .jobs
        .spawn_scoped(JobKind::LoadShot, scope, move |ctx, out| {
            ctx.report("loading shot", 0, 1);
            match load_capture(&path) {
                Ok(capture) => {
                    ctx.check().map_err(|e| e.to_string())?;
                    let developed = develop_for_display(&capture);
                    out.emit(JobOutput::Shots(ShotOutput::ShotLoaded {
                        shot: id,
                        capture: Arc::new(capture),
                        developed,
                    }));
                }
                Err(reason) => out.emit(JobOutput::Shots(ShotOutput::ShotUnreadable {
                    shot: id,
                    reason,
                })),
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

/// A RAW capture developed at full resolution in sensor orientation (overlays are
/// drawn in sensor pixels), or why it could not be; `None` for an RGB image.
pub(super) fn develop_for_display(capture: &Capture) -> Option<Result<Developed, String>> {
    capture.is_raw.then(|| {
        crate::develop::develop(capture, None, crate::develop::Orient::Sensor)
            .map_err(|e| e.to_string())
    })
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
