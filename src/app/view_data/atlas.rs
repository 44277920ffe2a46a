//! The Kernel field view's kernel atlas: measured or predicted kernels packed into one
//! texture.

use super::sensor_size;
use super::{FIELD_GRID, Same};
use crate::app::{FieldShow, FieldSource, StudioApp};
use crate::kernel::file::{KernelSample, KernelsFile};
use crate::model::KernelModel;
use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::psf::Gaussian2;
use crate::session::ShotId;

/// Kernels packed into one texture for the Kernel field view, measured (one shot and
/// channel) or predicted (the profile's, at the measured squares of the selected shot
/// or on the field grid): each cell holds the central ±`extent_px` of one kernel,
/// scaled to its peak.
pub struct KernelAtlas {
    key: AtlasKey,
    pub texture: egui::TextureHandle,
    pub cells: Vec<AtlasCell>,
    /// Half the side every cell shows, sensor px.
    pub extent_px: f64,
    /// The model of a predicted atlas; `None` for measured kernels.
    pub model: Option<KernelModel>,
    /// Why a predicted atlas holds no kernel (the profile cannot predict there).
    pub error: Option<String>,
    /// Why the profile of a predicted atlas holds no shape model.
    pub no_shape: Option<String>,
}

/// One kernel of an atlas.
#[derive(Clone, Copy, Debug)]
pub struct AtlasCell {
    /// Sensor position.
    pub x: f64,
    pub y: f64,
    /// The Gaussian whose σ tints its tile (measured fit or predicted).
    pub gaussian: Gaussian2,
    /// The selected shot's kernels-file sample on that square, where it sits on one.
    pub sample: Option<usize>,
    /// Its cell's UV rectangle in the texture.
    pub uv: egui::Rect,
}

#[derive(Clone, Debug, PartialEq)]
enum AtlasKey {
    Measured {
        shot: ShotId,
        channel: Channel,
        file: Same<KernelsFile>,
    },
    Predicted {
        profile: Same<Profile>,
        file: Same<KernelsFile>,
        channel: Channel,
        setting: [f64; 2],
        size: (usize, usize),
    },
}

/// The kernels the Kernel field view shows as shapes, packed into one texture: the
/// selected shot's measured ones, or the profile's predicted ones in its recommended
/// model at that shot's measured squares (else on the field grid), so the two compare
/// cell for cell.
pub(super) fn refresh_kernel_atlas(app: &mut StudioApp) {
    if app.views.field.show != FieldShow::Kernels || app.views.field.source == FieldSource::Truth {
        return;
    }
    let channel = app.views.shot.channel;
    let file = super::field_kernels(app).cloned();
    let file = file.as_ref();
    let key = match app.views.field.source {
        FieldSource::Predicted => {
            let Some((_, profile)) = app.profile() else {
                app.data.kernel_atlas = None;
                return;
            };
            AtlasKey::Predicted {
                profile: Same::of(Some(profile)),
                file: Same::of(file),
                channel,
                setting: [app.views.field.focal_mm, app.views.field.f_number],
                size: sensor_size(app),
            }
        }
        _ => {
            let Some(shot) = app.views.shot.selected else {
                app.data.kernel_atlas = None;
                return;
            };
            AtlasKey::Measured {
                shot,
                channel,
                file: Same::of(file),
            }
        }
    };
    if app.data.kernel_atlas.as_ref().is_some_and(|a| a.key == key) {
        return;
    }
    app.data.kernel_atlas = None;
    fn channel_samples(f: &KernelsFile, channel: Channel) -> Vec<(usize, &KernelSample)> {
        f.samples
            .iter()
            .enumerate()
            .filter(|(_, s)| s.channel == channel)
            .collect()
    }
    let (kernels, max_sigma, model, error) = match &key {
        AtlasKey::Measured { .. } => {
            let Some(file) = file else {
                return;
            };
            let samples = channel_samples(file, channel);
            let kernels: Vec<_> = samples
                .iter()
                .filter_map(|&(i, s)| {
                    let g = Gaussian2 {
                        sigma_x: s.cxx.unwrap_or(1.0),
                        sigma_y: s.cyy.unwrap_or(1.0),
                        rho: s.cor.unwrap_or(0.0),
                    };
                    Some((s.x, s.y, g, Some(i), s.kernel_at(file.oversample)?))
                })
                .collect();
            if kernels.is_empty() {
                return;
            }
            let max_sigma = samples
                .iter()
                .filter_map(|(_, s)| Some(s.cxx?.max(s.cyy?)))
                .fold(0.5, f64::max);
            (kernels, max_sigma, None, None)
        }
        AtlasKey::Predicted { size, .. } => {
            let Some((_, profile)) = app.profile() else {
                return;
            };
            let model = profile.kernel_model();
            let (points, samples): (Vec<[f64; 2]>, Vec<Option<usize>>) = match file {
                Some(f) if f.samples.iter().any(|s| s.channel == channel) => {
                    channel_samples(f, channel)
                        .into_iter()
                        .map(|(i, s)| ([s.x, s.y], Some(i)))
                        .unzip()
                }
                _ => crate::review::field_grid(size.0, size.1, FIELD_GRID.0, FIELD_GRID.1)
                    .into_iter()
                    .map(|p| (p, None))
                    .unzip(),
            };
            let setting = LensSetting {
                focal_mm: app.views.field.focal_mm,
                f_number: app.views.field.f_number,
            };
            match crate::review::predicted_kernels(profile, model, channel, &points, setting) {
                Ok(predicted) => {
                    let max_sigma = predicted
                        .iter()
                        .map(|k| k.gaussian.sigma_x.max(k.gaussian.sigma_y))
                        .fold(0.5, f64::max);
                    let kernels = predicted
                        .into_iter()
                        .zip(samples)
                        .map(|(k, i)| (k.x, k.y, k.gaussian, i, k.kernel))
                        .collect();
                    (kernels, max_sigma, Some(model), None)
                }
                Err(e) => (Vec::new(), 0.5, Some(model), Some(e)),
            }
        }
    };
    let mut atlas = pack_atlas(&app.ctx, key, &kernels, max_sigma, model, error);
    if model.is_some() {
        atlas.no_shape = app
            .profile()
            .and_then(|(_, p)| crate::review::no_shape_reason(p));
    }
    app.data.kernel_atlas = Some(atlas);
}

/// Packs kernels into one texture: the central ±R px of each (R = 2.5 × `max_sigma`,
/// the largest σ of the field, so every kernel shows the same extent and shapes
/// compare), each scaled to its own peak (σ is in the tint).
fn pack_atlas(
    ctx: &egui::Context,
    key: AtlasKey,
    kernels: &[(f64, f64, Gaussian2, Option<usize>, crate::psf::Kernel)],
    max_sigma: f64,
    model: Option<KernelModel>,
    error: Option<String>,
) -> KernelAtlas {
    let extent_px = (2.5 * max_sigma).max(2.0);
    let os = kernels.first().map_or(3, |k| k.4.oversample.max(1));
    let half = (extent_px * os as f64).ceil() as usize;
    let cell = 2 * half + 1;
    let per_row = (kernels.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = kernels.len().div_ceil(per_row).max(1);
    let (w, h) = (per_row * cell, rows * cell);
    let mut img = egui::ColorImage::filled([w, h], egui::Color32::TRANSPARENT);
    let mut cells = Vec::with_capacity(kernels.len());
    for (n, (x, y, gaussian, sample, k)) in kernels.iter().enumerate() {
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
        cells.push(AtlasCell {
            x: *x,
            y: *y,
            gaussian: *gaussian,
            sample: *sample,
            uv,
        });
    }
    let texture = ctx.load_texture("kernel-atlas", img, egui::TextureOptions::NEAREST);
    KernelAtlas {
        key,
        texture,
        cells,
        extent_px: half as f64 / os as f64,
        model,
        error,
        no_shape: None,
    }
}
