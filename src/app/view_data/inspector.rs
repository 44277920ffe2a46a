//! The square inspector: the selected square's crops (made on a job thread), their
//! textures, its measured kernel and, on the demo session, the true Gaussian.

use super::{Same, is_demo};
use crate::app::jobs::{JobKind, JobScope};
use crate::app::state::{InspectKey, InspectedSquare};
use crate::app::{JobOutput, StudioApp};
use crate::detect::inspect::SquareInspection;
use crate::kernel::file::KernelsFile;
use crate::plane::{Channel, LensSetting, Plane};
use crate::psf::Gaussian2;
use crate::review::SquareFacts;
use crate::session::ShotId;
use crate::simulate::VirtualLens;
use std::sync::Arc;

/// The inspector's state for the selected square.
pub enum Inspecting {
    /// The crops are being made on a job thread.
    Running(InspectKey),
    Ready(Box<Inspection>),
    /// The square has no crop in this channel.
    Empty(InspectKey),
}

impl Inspecting {
    #[must_use]
    pub fn key(&self) -> &InspectKey {
        match self {
            Inspecting::Running(k) | Inspecting::Empty(k) => k,
            Inspecting::Ready(i) => &i.key,
        }
    }
}

/// What the kernel texture and the truth beside it depend on.
#[derive(Clone, Debug, PartialEq)]
struct DetailsKey {
    file: Same<KernelsFile>,
    setting: Option<LensSetting>,
    is_demo: bool,
}

/// The inspector's square: which one, its crops and their textures (observed,
/// synthetic, residual), its measured kernel's texture and, on the demo session, the
/// lens's true Gaussian at its centre.
pub struct Inspection {
    key: InspectKey,
    pub shot: ShotId,
    pub square: (usize, usize),
    pub channel: Channel,
    pub crops: SquareInspection,
    pub facts: Option<SquareFacts>,
    pub textures: [egui::TextureHandle; 3],
    details: Option<DetailsKey>,
    pub kernel: Option<egui::TextureHandle>,
    pub truth: Option<Gaussian2>,
}

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

pub(super) fn refresh_inspection(app: &mut StudioApp) {
    let wanted = wanted_inspection(app);
    let current = app.data.inspection.as_ref().map(Inspecting::key);
    if wanted.as_ref() != current {
        app.data.inspection = wanted.map(|key| spawn_inspection(app, key));
    }
    refresh_inspection_details(app);
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
pub(in crate::app) fn inspected(
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
    app.data.inspection = Some(Inspecting::Ready(Box::new(Inspection {
        shot: key.shot,
        square: key.square,
        channel: key.channel,
        key,
        crops,
        facts,
        textures,
        details: None,
        kernel: None,
        truth: None,
    })));
    refresh_inspection_details(app);
}

/// The inspected square's measured kernel as a texture (scaled to its peak) and, on the
/// demo session, the lens's true Gaussian at the square's centre: remade when the
/// shot's kernels or setting change.
pub(super) fn refresh_inspection_details(app: &mut StudioApp) {
    let Some(Inspecting::Ready(ins)) = &app.data.inspection else {
        return;
    };
    let shot = app.session().and_then(|s| s.shot(ins.shot));
    let file = app.kernels(ins.shot);
    let key = DetailsKey {
        file: Same::of(file),
        setting: shot.and_then(crate::session::Shot::setting),
        is_demo: is_demo(app),
    };
    if ins.details.as_ref() == Some(&key) {
        return;
    }
    let (sq, channel) = (ins.square, ins.channel);
    let kernel = file
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
    let truth = key
        .is_demo
        .then_some(key.setting)
        .flatten()
        .zip(app.preview(ins.shot))
        .zip(ins.facts)
        .map(|((setting, p), f)| {
            crate::review::truth_pixel_gaussian(
                &VirtualLens::demo(),
                channel,
                (f.centre[0], f.centre[1]),
                (p.capture.width, p.capture.height),
                setting,
            )
        });
    if let Some(Inspecting::Ready(ins)) = &mut app.data.inspection {
        ins.kernel = kernel;
        ins.truth = truth;
        ins.details = Some(key);
    }
}
