//! The square inspector's crops: asked for on a job when the selected square (its shot,
//! channel or detection) changes, and made into textures when they arrive. The kernel
//! and the truth shown beside them are `view_data`'s.

use crate::app::jobs::{JobKind, JobScope};
use crate::app::state::{InspectKey, InspectedSquare, Same};
use crate::app::view_data::{Inspecting, Inspection};
use crate::app::{JobOutput, StudioApp};
use crate::detect::inspect::SquareInspection;
use crate::plane::Plane;
use std::sync::Arc;

/// The inspection the selection asks for, if the shot is loaded and detected and has
/// that square: in the selected channel, else the capture's first.
fn wanted_inspection(app: &StudioApp) -> Option<InspectKey> {
    let (shot, square) = (app.views.shot.selected?, app.views.shot.square?);
    let preview = app.preview(shot)?;
    let det = app.detection(shot)?;
    app.session()?;
    if !det.squares.iter().any(|s| (s.row, s.col) == square) {
        return None;
    }
    let planes = &preview.capture.planes;
    let channel = if planes.iter().any(|p| p.channel == app.views.shot.channel) {
        app.views.shot.channel
    } else {
        planes.first()?.channel
    };
    Some(InspectKey {
        session: app.session_generation,
        shot,
        square,
        channel,
        detection: Same::of(Some(det)),
    })
}

/// Asks for the crops of the square the selection names, where they are not those
/// asked for last.
pub(super) fn request_inspection(app: &mut StudioApp) {
    let wanted = wanted_inspection(app);
    let current = app.data.inspection.as_ref().map(Inspecting::key);
    if wanted.as_ref() != current {
        app.data.inspection = wanted.map(|key| spawn_inspection(app, key));
    }
}

/// Starts the crops of a square on a job thread (the core's inspection resamples the
/// chart through the square's homography and blurs it: too slow for a frame).
fn spawn_inspection(app: &mut StudioApp, key: InspectKey) -> Inspecting {
    let (Some(preview), Some(det), Some(session)) = (
        app.preview(key.shot),
        app.detection(key.shot),
        app.session(),
    ) else {
        return Inspecting::Empty(key);
    };
    let capture = Arc::clone(&preview.capture);
    let det = Arc::clone(det);
    let chart = session.chart.clone();
    let scope = JobScope::shots(key.session, vec![key.shot]);
    let job_key = key.clone();
    let r = app
        .jobs
        .spawn_scoped(JobKind::InspectSquare, scope, move |_ctx, out| {
            let result = det
                .squares
                .iter()
                .find(|s| (s.row, s.col) == job_key.square)
                .and_then(|square| {
                    let crops = crate::detect::inspect::inspect_square(
                        &capture,
                        square,
                        &chart,
                        job_key.channel,
                    )?;
                    let facts = (square.status == crate::detect::SquareStatus::Ok)
                        .then(|| crate::review::square_facts(square));
                    let images = crop_images(&crops);
                    Some(Box::new(InspectedSquare {
                        crops,
                        facts,
                        images,
                    }))
                });
            out.emit(JobOutput::SquareInspected {
                key: job_key,
                result,
            });
            // Never an error: a cancelled inspection (its shot removed, its session
            // closed) has nothing to report.
            Ok(())
        });
    match r {
        Ok(_) => Inspecting::Running(key),
        Err(e) => {
            app.error(e);
            Inspecting::Empty(key)
        }
    }
}

/// Grey images of the crops: observed and synthetic encoded for display; the residual
/// signed and small, so mid-grey is zero and ±25 % of the square's contrast spans the
/// grey range.
fn crop_images(crops: &SquareInspection) -> [egui::ColorImage; 3] {
    let img = |plane: &Plane, map: &dyn Fn(f32) -> u8| {
        egui::ColorImage::from_gray_iter(
            [plane.width, plane.height],
            plane.data.iter().map(|&v| map(v)),
        )
    };
    let contrast = {
        let mut v = crops.observed.data.clone();
        v.sort_by(f32::total_cmp);
        v.get(v.len() * 98 / 100)
            .zip(v.get(v.len() * 2 / 100))
            .map_or(1e-3, |(hi, lo)| (hi - lo).max(1e-3))
    };
    let encode = crate::app::textures::encode;
    [
        img(&crops.observed, &encode),
        img(&crops.synthetic, &encode),
        img(&crops.residual, &|r: f32| {
            ((0.5 + 2.0 * r / contrast).clamp(0.0, 1.0) * 255.0) as u8
        }),
    ]
}

/// A finished inspection job: kept when it is still the one the selection asks for,
/// its textures made now; dropped otherwise.
pub(super) fn inspected(
    app: &mut StudioApp,
    key: InspectKey,
    result: Option<Box<InspectedSquare>>,
) {
    let running = matches!(&app.data.inspection, Some(Inspecting::Running(k)) if *k == key);
    if !running {
        return;
    }
    let Some(done) = result else {
        app.data.inspection = Some(Inspecting::Empty(key));
        return;
    };
    let InspectedSquare {
        crops,
        facts,
        images,
    } = *done;
    let [observed, synthetic, residual] = images;
    let tex = |name: &str, img: egui::ColorImage| {
        app.ctx
            .load_texture(name, img, egui::TextureOptions::NEAREST)
    };
    let textures = [
        tex("inspect-observed", observed),
        tex("inspect-synthetic", synthetic),
        tex("inspect-residual", residual),
    ];
    // Its kernel and truth are view data's, made in the same step.
    app.data.inspection = Some(Inspecting::Ready(Box::new(Inspection::new(
        key, crops, facts, textures,
    ))));
}
