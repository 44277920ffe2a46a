//! Stage 7: the lens's geometry from the same chart shots the blur is measured on —
//! distortion, lateral colour and fall-off — in lensfun's models, for the editors that
//! correct lenses through lensfun (darktable, RawTherapee, digiKam, Hugin, GIMP).
//! lensfun has no sharpness field: the blur profile stays lensblur's.
//!
//! Per focal length, every shot's aligned squares give corners: distortion is fitted
//! jointly with each shot's chart pose ([`distortion`]), and lateral colour from the
//! corners' per-channel registration ([`tca`]). Per focal length and aperture, the
//! squares' white levels give the fall-off ([`vignetting`]) under the assumption that
//! the chart was evenly lit, which is checked. [`lensfun`] owns the XML, and [`frame`]
//! the coordinate conventions the coefficients are in.

pub mod distortion;
pub mod frame;
pub mod lensfun;
pub mod tca;
pub mod vignetting;

pub use distortion::{DistortionFit, DistortionModel};
pub use frame::LensfunFrame;
pub use lensfun::LensfunNames;
pub use tca::{TcaFit, TcaModel};
pub use vignetting::{UNEVEN_LIGHT_STOPS, VignettingFit};

use crate::chart::ChartSpec;
use crate::detect::Detection;
use crate::plane::{Channel, LensSetting};
use serde::Serialize;

/// One shot's detection and setting.
#[derive(Clone, Copy, Debug)]
pub struct GeometryShot<'a> {
    pub name: &'a str,
    pub setting: LensSetting,
    pub detection: &'a Detection,
}

#[derive(Debug, thiserror::Error)]
pub enum CorrectionError {
    #[error("no shots with a detected chart and a known focal length and aperture")]
    NoShots,
    #[error(
        "{shot}: {width} × {height} px, the other shots {w0} × {h0} px: one sensor size per lens entry"
    )]
    SizesDiffer {
        shot: String,
        width: usize,
        height: usize,
        w0: usize,
        h0: usize,
    },
}

/// Which models to write; `None` picks (see [`LensCorrection::distortion_model`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct CorrectionOptions {
    pub distortion_model: Option<DistortionModel>,
    pub tca_model: Option<TcaModel>,
}

/// Geometry at one focal length.
#[derive(Clone, Debug, Serialize)]
pub struct FocalGeometry {
    pub focal_mm: f64,
    pub shots: usize,
    /// Every distortion model, fitted to the same corners.
    pub distortion: Vec<DistortionFit>,
    /// Both lateral-colour models; empty for a single-channel capture.
    pub tca: Vec<TcaFit>,
}

impl FocalGeometry {
    /// The fit of one model (every model is fitted).
    #[must_use]
    pub fn distortion_fit(&self, model: DistortionModel) -> &DistortionFit {
        self.distortion
            .iter()
            .find(|d| d.model == model)
            .unwrap_or(&self.distortion[0])
    }

    #[must_use]
    pub fn tca_fit(&self, model: TcaModel) -> Option<&TcaFit> {
        self.tca.iter().find(|t| t.model == model)
    }
}

/// The lens's geometry over a session.
#[derive(Clone, Debug, Serialize)]
pub struct LensCorrection {
    #[serde(skip)]
    pub frame: LensfunFrame,
    pub width: usize,
    pub height: usize,
    /// Sorted by focal length.
    pub focal: Vec<FocalGeometry>,
    /// Per setting, sorted by focal length then f-number.
    pub vignetting: Vec<VignettingFit>,
    /// The distortion model written: the one asked for, else the model with the fewest
    /// terms whose residual is within [`MODEL_RMS_MARGIN`] of the best's at every
    /// focal length.
    pub distortion_model: DistortionModel,
    /// The lateral-colour model written: the one asked for, else linear unless poly3
    /// lowers the residual by more than [`MODEL_RMS_MARGIN`].
    pub tca_model: TcaModel,
}

/// A model with more terms is chosen only when it lowers the corners' RMS residual by
/// more than this fraction (plus [`MODEL_RMS_FLOOR_PX`]): less is the alignment's noise
/// being fitted. Chosen before measuring.
pub const MODEL_RMS_MARGIN: f64 = 0.05;
pub const MODEL_RMS_FLOOR_PX: f64 = 0.002;

impl LensCorrection {
    /// The geometry at a focal length the session has (same-setting tolerance).
    #[must_use]
    pub fn at_focal(&self, focal_mm: f64) -> Option<&FocalGeometry> {
        self.focal
            .iter()
            .find(|f| LensSetting::same_value(f.focal_mm, focal_mm))
    }

    /// Settings whose light was not even enough to measure the fall-off.
    pub fn uneven_light(&self) -> impl Iterator<Item = &VignettingFit> {
        self.vignetting.iter().filter(|v| !v.light_even())
    }
}

/// Measures the lens's geometry from `shots` (any order; shots without an aligned
/// square are left out).
///
/// # Errors
/// No usable shot; shots of different sizes.
pub fn measure(
    shots: &[GeometryShot<'_>],
    chart: &ChartSpec,
    options: CorrectionOptions,
) -> Result<LensCorrection, CorrectionError> {
    let shots: Vec<&GeometryShot<'_>> = shots
        .iter()
        .filter(|s| s.detection.ok_squares().count() >= 4)
        .collect();
    let first = shots.first().ok_or(CorrectionError::NoShots)?;
    let (width, height) = (first.detection.width, first.detection.height);
    if let Some(s) = shots
        .iter()
        .find(|s| (s.detection.width, s.detection.height) != (width, height))
    {
        return Err(CorrectionError::SizesDiffer {
            shot: s.name.to_string(),
            width: s.detection.width,
            height: s.detection.height,
            w0: width,
            h0: height,
        });
    }
    let frame = LensfunFrame::of_image(width, height);
    let focals = LensSetting::distinct_values(shots.iter().map(|s| s.setting.focal_mm));
    let focal: Vec<FocalGeometry> = focals
        .iter()
        .map(|&f| {
            let at: Vec<&GeometryShot<'_>> = shots
                .iter()
                .filter(|s| LensSetting::same_value(s.setting.focal_mm, f))
                .copied()
                .collect();
            focal_geometry(f, &at, chart, &frame)
        })
        .collect();
    let mut settings: Vec<LensSetting> = Vec::new();
    for s in &shots {
        if !settings.iter().any(|t| t.same_as(s.setting)) {
            settings.push(s.setting);
        }
    }
    settings.sort_by(|a, b| {
        a.focal_mm
            .total_cmp(&b.focal_mm)
            .then(a.f_number.total_cmp(&b.f_number))
    });
    let vignetting = settings
        .iter()
        .filter_map(|&setting| {
            let samples: Vec<vignetting::WhiteSample> = shots
                .iter()
                .filter(|s| s.setting.same_as(setting))
                .flat_map(|s| white_samples(s.detection))
                .collect();
            vignetting::fit(setting, &frame, &samples)
        })
        .collect();
    let distortion_model = options
        .distortion_model
        .unwrap_or_else(|| choose_distortion(&focal));
    let tca_model = options.tca_model.unwrap_or_else(|| choose_tca(&focal));
    Ok(LensCorrection {
        frame,
        width,
        height,
        focal,
        vignetting,
        distortion_model,
        tca_model,
    })
}

fn within_margin(rms: f64, best: f64) -> bool {
    rms <= best * (1.0 + MODEL_RMS_MARGIN) + MODEL_RMS_FLOOR_PX
}

fn choose_distortion(focal: &[FocalGeometry]) -> DistortionModel {
    DistortionModel::ALL
        .into_iter()
        .find(|&m| {
            focal.iter().all(|f| {
                let best = f
                    .distortion
                    .iter()
                    .map(|d| d.rms_px)
                    .fold(f64::INFINITY, f64::min);
                within_margin(f.distortion_fit(m).rms_px, best)
            })
        })
        .unwrap_or(DistortionModel::PtLens)
}

fn choose_tca(focal: &[FocalGeometry]) -> TcaModel {
    let linear_enough =
        focal.iter().all(
            |f| match (f.tca_fit(TcaModel::Linear), f.tca_fit(TcaModel::Poly3)) {
                (Some(l), Some(p)) => {
                    within_margin(l.red.rms_px, p.red.rms_px)
                        && within_margin(l.blue.rms_px, p.blue.rms_px)
                }
                _ => true,
            },
        );
    if linear_enough {
        TcaModel::Linear
    } else {
        TcaModel::Poly3
    }
}

/// The corners of every aligned square, and the squares' per-channel corner pairs.
fn focal_geometry(
    focal_mm: f64,
    shots: &[&GeometryShot<'_>],
    chart: &ChartSpec,
    frame: &LensfunFrame,
) -> FocalGeometry {
    let mut corners = Vec::new();
    let mut poses = Vec::new();
    let mut red = Vec::new();
    let mut blue = Vec::new();
    for (i, s) in shots.iter().enumerate() {
        let mut from = Vec::new();
        let mut to = Vec::new();
        for sq in s.detection.ok_squares() {
            let quad = chart.square_corners(sq.col, sq.row);
            for (x, q) in quad.iter().zip(&sq.corners) {
                corners.push(distortion::Corner {
                    shot: i,
                    chart: *x,
                    sensor: *q,
                });
                from.push(*x);
                to.push(*q);
            }
            let of = |ch: Channel| sq.channel_registration.iter().find(|(c, _)| *c == ch);
            if let (Some((_, g)), Some((_, r)), Some((_, b))) =
                (of(Channel::G), of(Channel::R), of(Channel::B))
            {
                for x in &quad {
                    let green = g.apply(*x);
                    red.push(tca::ChannelPair {
                        green,
                        other: r.apply(*x),
                    });
                    blue.push(tca::ChannelPair {
                        green,
                        other: b.apply(*x),
                    });
                }
            }
        }
        let h = crate::geometry::Homography::from_correspondences(&from, &to)
            .unwrap_or(s.detection.global)
            .to_row_major();
        let n = if h[8].abs() > 1e-300 { h[8] } else { 1.0 };
        poses.push(std::array::from_fn(|k| h[k] / n));
    }
    let distortion = DistortionModel::ALL
        .iter()
        .map(|&m| distortion::fit(m, &poses, frame, &corners))
        .collect();
    let tca = if red.len() >= 16 {
        [TcaModel::Linear, TcaModel::Poly3]
            .into_iter()
            .map(|model| TcaFit {
                model,
                red: tca::fit_channel(model, frame, &red),
                blue: tca::fit_channel(model, frame, &blue),
                corners: red.len(),
            })
            .collect()
    } else {
        Vec::new()
    };
    FocalGeometry {
        focal_mm,
        shots: shots.len(),
        distortion,
        tca,
    }
}

/// Every aligned square's white level per channel, at the square's centre.
fn white_samples(d: &Detection) -> Vec<vignetting::WhiteSample> {
    d.ok_squares()
        .flat_map(|sq| {
            let centre = sq
                .image_from_chart
                .apply([sq.col as f64 + 0.5, sq.row as f64 + 0.5]);
            sq.levels_by_channel
                .iter()
                .map(move |&(channel, [_, white])| vignetting::WhiteSample {
                    channel,
                    sensor: centre,
                    white,
                })
        })
        .collect()
}
