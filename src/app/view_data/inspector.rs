//! The square inspector: the selected square's crops and their textures (asked for and
//! made by `logic`), and what is shown beside them, made here: its measured kernel's
//! texture and, on the demo session, the true Gaussian.

use super::{Same, is_demo};
use crate::app::StudioApp;
use crate::app::state::InspectKey;
use crate::detect::inspect::SquareInspection;
use crate::kernel::file::KernelsFile;
use crate::plane::{Channel, LensSetting};
use crate::psf::Gaussian2;
use crate::review::SquareFacts;
use crate::session::ShotId;
use crate::simulate::VirtualLens;

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

impl Inspection {
    /// A square's crops and their textures; its kernel and truth follow.
    pub(in crate::app) fn new(
        key: InspectKey,
        crops: SquareInspection,
        facts: Option<SquareFacts>,
        textures: [egui::TextureHandle; 3],
    ) -> Self {
        Self {
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
        }
    }
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
