//! Where each channel's kernel sits: the place model.
//!
//! A kernel's place is as much the lens's as its shape. Green's kernels sit where coma
//! and other odd aberrations put their light, and red's and blue's also where lateral
//! colour images those channels against green. Deconvolution moves a channel back by
//! where its kernel sits, so a red kernel placed a fraction of a pixel away from where
//! the lens put red is a colour fringe the photo never had, and one placed where the
//! lens put red removes the lens's own fringe. A kernel's place here is its centroid
//! ([`centroid_px`], which says why not its core).
//!
//! Two parts are measured at every square of every shot:
//! - the kernel's centroid against its channel's registration of the square (`kernel`);
//! - where that registration lies against green's (`registration`): the lateral colour
//!   detection found, zero wherever the kernels kept one registration for all channels
//!   (their centroids then carry it instead).
//!
//! Each part's x and y offsets are fitted per channel by the polynomial fields of the
//! blur models, G_{α,β} over (x, y, f, a) in their Legendre basis: a lens's lateral
//! colour (a radial magnification, linear and cubic in the radius) is a field of order
//! 3, and decentring, tilt or a coma pattern need no other form. α and β are chosen by
//! holding out whole shots, the folds of the blur models' cross-validation, on the two
//! parts' sum (what deblurring moves a channel by). The fit is linear least squares, so
//! every fold's system is the session's normal equations minus the fold's, and every
//! order's is a sub-block of the largest's. Beyond the area the chart covered the fields
//! continue linearly from its border, as the blur models do.

use super::{Basis, Dataset, ModelError, Normalisation, global_coords, model_basis};
use crate::plane::{Channel, LensSetting};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The highest spatial order tried: lateral colour's cubic radial term is order 3, and
/// one order beyond it leaves room for a fifth-order term.
pub const MAX_PLACE_ALPHA: usize = 5;

/// The highest order over focal length and aperture tried (a further bound is what the
/// settings shot can determine).
pub const MAX_PLACE_BETA: usize = 3;

/// What deblurring does with the lens's lateral colour.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LateralColour {
    /// Red and blue kernels sit where the lens images those channels against green, so
    /// deblurring moves them back onto green: the photo's colour fringes go with its
    /// blur.
    #[default]
    Correct,
    /// Each kernel keeps only its own place against its channel's image, so the
    /// channels stay where the lens put them, for lensfun's lateral-colour correction
    /// (`tca`) to move afterwards; correcting here too would move them twice.
    Keep,
}

impl LateralColour {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Correct => "correct",
            Self::Keep => "keep",
        }
    }
}

/// One channel's fields: the x and y offsets (px) of each part, as coefficients over
/// the G_{α,β} basis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelPlace {
    pub channel: Channel,
    /// The kernel's centroid against its channel's registration.
    pub kernel: [Vec<f64>; 2],
    /// The channel's registration against green's (zero for green).
    pub registration: [Vec<f64>; 2],
}

/// Held-out error of one pair of orders: RMS over held-out kernels and both axes of the
/// measured centroid against the predicted one, px.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlaceCv {
    pub alpha: usize,
    pub beta: usize,
    pub rms_px: f64,
}

/// Where a session's kernels sit.
#[derive(Clone, Debug)]
pub struct PlaceModel {
    pub norm: Normalisation,
    pub alpha: usize,
    pub beta: usize,
    pub channels: Vec<ChannelPlace>,
    /// Held-out error per pair of orders tried (empty when no shot could be held out).
    pub cv: Vec<PlaceCv>,
    /// RMS of the measured offsets themselves, px: the error of centring every
    /// kernel on its pixel, as the Gaussians alone do.
    pub centred_rms_px: f64,
    basis: Basis,
}

/// One sample's two measured offsets (px): its kernel's centroid, and its registration
/// against green's at the same square of the same shot.
struct Measured {
    shot: usize,
    coords: [f64; 4],
    kernel: [f64; 2],
    registration: [f64; 2],
}

/// Per channel, the samples whose offsets are known: a kept kernel, and for red and
/// blue, green measured at the same square.
fn measured(ds: &Dataset, norm: &Normalisation, channel: Channel) -> Vec<Measured> {
    use std::collections::HashMap;
    let green: HashMap<(usize, [usize; 2]), [f64; 2]> = ds
        .samples
        .iter()
        .filter(|s| s.channel == Channel::G)
        .filter_map(|s| Some(((s.shot, s.square?), [s.x, s.y])))
        .collect();
    ds.samples
        .iter()
        .filter(|s| s.channel == channel)
        .filter_map(|s| {
            let centroid = centroid_px(s.kernel.as_ref()?);
            let registration = match channel {
                // Files without square indices were measured on one registration.
                Channel::R | Channel::B => match s.square {
                    Some(square) => {
                        let g = green.get(&(s.shot, square))?;
                        [s.x - g[0], s.y - g[1]]
                    }
                    None => [0.0, 0.0],
                },
                Channel::G | Channel::Y => [0.0, 0.0],
            };
            Some(Measured {
                shot: s.shot,
                coords: global_coords(norm, s.x, s.y, s.focal_mm, s.f_number),
                kernel: centroid,
                registration,
            })
        })
        .collect()
}

/// A kernel's samples below this fraction of its peak are left out of its centroid:
/// the kernel estimator's own cleaning threshold, so a floor of noise spread over the
/// kernel's grid does not pull the centroid towards the grid's centre.
const CENTROID_THRESHOLD: f64 = crate::gaussian::CLEAN_THRESHOLD;

/// Where a kernel's light lies, px from its centre sample: the mean of its samples
/// above [`CENTROID_THRESHOLD`] of its peak.
///
/// The centroid, not the core: a chart square's registration is where the blurred
/// square's light is, so measured kernels are centred about their means, and a common
/// shift of all channels is the chart's geometry as much as the blur's. On the measured
/// chain, Gaussians placed at the kernels' centroids deblurred the aberrated lens
/// better than centred ones at every setting tried (31 mm f/4.5: 0.9553 against 0.9526
/// SSIM), and placed at their cores (the half-maximum region) far worse (0.9126),
/// though on exact kernels the cores did best: the measured place of a core is off
/// by what the registration took for the blur's mean.
#[must_use]
pub fn centroid_px(k: &crate::psf::Kernel) -> [f64; 2] {
    let peak = k.data.iter().copied().fold(0.0f64, f64::max);
    let light = crate::psf::Kernel {
        data: k
            .data
            .iter()
            .map(|&v| {
                if v > CENTROID_THRESHOLD * peak {
                    v
                } else {
                    0.0
                }
            })
            .collect(),
        ..k.clone()
    };
    let m = light.moments();
    [m.mean_x, m.mean_y]
}

/// Columns of the right-hand sides: each part's x and y, then their sums.
const KERNEL: [usize; 2] = [0, 1];
const REGISTRATION: [usize; 2] = [2, 3];
const SUM: [usize; 2] = [4, 5];

/// One shot's normal equations: Gram, right-hand sides and the sums' squares, so a
/// fold's held-out error needs no pass over its samples.
struct ShotSystem {
    gram: DMatrix<f64>,
    rhs: DMatrix<f64>,
    sum_squares: f64,
    rows: usize,
}

impl ShotSystem {
    fn new(n: usize) -> Self {
        Self {
            gram: DMatrix::zeros(n, n),
            rhs: DMatrix::zeros(n, 6),
            sum_squares: 0.0,
            rows: 0,
        }
    }
}

/// The indices of `small`'s terms within `large`'s.
fn sub_terms(large: &Basis, small: &Basis) -> Vec<usize> {
    small
        .terms()
        .iter()
        .filter_map(|t| large.terms().iter().position(|l| l == t))
        .collect()
}

fn sub_block(m: &DMatrix<f64>, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(rows.len(), cols.len(), |i, j| m[(rows[i], cols[j])])
}

impl PlaceModel {
    /// Fits every channel that kept kernels, choosing α and β by holding out the folds
    /// `fold_of_shot` (a fold index per shot; `folds` of them; fewer than two: the
    /// radial field's order 3 and the largest β the settings allow, unvalidated).
    ///
    /// # Errors
    /// [`ModelError::Empty`] when no sample kept its kernel.
    pub fn fit(ds: &Dataset, fold_of_shot: &[usize], folds: usize) -> Result<Self, ModelError> {
        let norm = ds.normalisation();
        let max_beta = (0..=MAX_PLACE_BETA)
            .take_while(|&b| ds.check_beta(b).is_ok())
            .last()
            .ok_or(ModelError::Empty)?;
        let largest = model_basis(&norm, MAX_PLACE_ALPHA, max_beta);
        let n = largest.len();
        // Channels in parallel: each sums its own shots' systems.
        let per_channel: Vec<(Channel, Vec<ShotSystem>)> = ds
            .channels()
            .into_par_iter()
            .filter_map(|channel| {
                let samples = measured(ds, &norm, channel);
                if samples.is_empty() {
                    return None;
                }
                let mut shots: Vec<ShotSystem> =
                    (0..ds.shots.len()).map(|_| ShotSystem::new(n)).collect();
                let mut row = DVector::zeros(n);
                for m in &samples {
                    largest.row(m.coords, row.as_mut_slice());
                    let sys = &mut shots[m.shot];
                    sys.gram.ger(1.0, &row, &row, 1.0);
                    for axis in 0..2 {
                        let (k, r) = (m.kernel[axis], m.registration[axis]);
                        for (c, v) in [
                            (KERNEL[axis], k),
                            (REGISTRATION[axis], r),
                            (SUM[axis], k + r),
                        ] {
                            sys.rhs.column_mut(c).axpy(v, &row, 1.0);
                        }
                        sys.sum_squares += (k + r) * (k + r);
                    }
                    sys.rows += 2;
                }
                Some((channel, shots))
            })
            .collect();
        if per_channel.is_empty() {
            return Err(ModelError::Empty);
        }
        let sum = |shots: &[ShotSystem]| -> (DMatrix<f64>, DMatrix<f64>) {
            (
                shots.iter().map(|s| &s.gram).sum(),
                shots.iter().map(|s| &s.rhs).sum(),
            )
        };
        let totals: Vec<(DMatrix<f64>, DMatrix<f64>)> =
            per_channel.iter().map(|(_, shots)| sum(shots)).collect();
        let (mut centred, mut rows) = (0.0, 0usize);
        for (_, shots) in &per_channel {
            centred += shots.iter().map(|s| s.sum_squares).sum::<f64>();
            rows += shots.iter().map(|s| s.rows).sum::<usize>();
        }
        let mut cv = Vec::new();
        if folds >= 2 && fold_of_shot.len() == ds.shots.len() {
            for alpha in 1..=MAX_PLACE_ALPHA {
                for beta in 0..=max_beta {
                    let idx = sub_terms(&largest, &model_basis(&norm, alpha, beta));
                    let mut sse = 0.0;
                    for ((_, shots), (gram, rhs)) in per_channel.iter().zip(&totals) {
                        for fold in 0..folds {
                            let held: Vec<&ShotSystem> = shots
                                .iter()
                                .zip(fold_of_shot)
                                .filter(|(s, f)| **f == fold && s.rows > 0)
                                .map(|(s, _)| s)
                                .collect();
                            if held.is_empty() {
                                continue;
                            }
                            let (mut g, mut h) = (gram.clone(), rhs.clone());
                            for s in &held {
                                g -= &s.gram;
                                h -= &s.rhs;
                            }
                            let theta = super::solve_normal(
                                sub_block(&g, &idx, &idx),
                                &sub_block(&h, &idx, &SUM),
                            );
                            for s in &held {
                                // Σ (y − Aθ)² = yᵀy − 2θᵀAᵀy + θᵀAᵀAθ over the held shot.
                                let gram_held = sub_block(&s.gram, &idx, &idx);
                                let rhs_held = sub_block(&s.rhs, &idx, &SUM);
                                sse += s.sum_squares;
                                for axis in 0..2 {
                                    let t = theta.column(axis);
                                    sse += (&gram_held * t).dot(&t)
                                        - 2.0 * t.dot(&rhs_held.column(axis));
                                }
                            }
                        }
                    }
                    cv.push(PlaceCv {
                        alpha,
                        beta,
                        rms_px: (sse.max(0.0) / rows.max(1) as f64).sqrt(),
                    });
                }
            }
        }
        let (alpha, beta) = cv
            .iter()
            .min_by(|a, b| a.rms_px.total_cmp(&b.rms_px))
            .map_or((3, max_beta), |c| (c.alpha, c.beta));
        let idx = sub_terms(&largest, &model_basis(&norm, alpha, beta));
        let channels = per_channel
            .iter()
            .zip(&totals)
            .map(|((channel, _), (gram, rhs))| {
                let all: Vec<usize> = (0..6).collect();
                let theta =
                    super::solve_normal(sub_block(gram, &idx, &idx), &sub_block(rhs, &idx, &all));
                let column = |c: usize| theta.column(c).iter().copied().collect::<Vec<f64>>();
                ChannelPlace {
                    channel: *channel,
                    kernel: KERNEL.map(column),
                    registration: REGISTRATION.map(column),
                }
            })
            .collect();
        let centred_rms_px = (centred / rows.max(1) as f64).sqrt();
        Ok(Self::new(norm, (alpha, beta), channels, cv, centred_rms_px))
    }

    fn new(
        norm: Normalisation,
        (alpha, beta): (usize, usize),
        channels: Vec<ChannelPlace>,
        cv: Vec<PlaceCv>,
        centred_rms_px: f64,
    ) -> Self {
        Self {
            basis: model_basis(&norm, alpha, beta),
            norm,
            alpha,
            beta,
            channels,
            cv,
            centred_rms_px,
        }
    }

    /// A stored model, checked against the basis its orders imply.
    ///
    /// # Errors
    /// A message naming what does not fit.
    pub fn from_parts(
        norm: Normalisation,
        (alpha, beta): (usize, usize),
        channels: Vec<ChannelPlace>,
        cv: Vec<PlaceCv>,
        centred_rms_px: f64,
    ) -> Result<Self, String> {
        if alpha > MAX_PLACE_ALPHA || beta > MAX_PLACE_BETA {
            return Err(format!(
                "kernel place orders α = {alpha}, β = {beta} above {MAX_PLACE_ALPHA}, {MAX_PLACE_BETA}"
            ));
        }
        let basis = model_basis(&norm, alpha, beta);
        for c in &channels {
            let fields = c.kernel.iter().chain(&c.registration);
            if let Some(f) = fields.clone().find(|f| f.len() != basis.len()) {
                return Err(format!(
                    "kernel place field of {:?} has {} terms, orders {alpha}, {beta} have {}",
                    c.channel,
                    f.len(),
                    basis.len()
                ));
            }
            if fields.flatten().any(|v| !v.is_finite()) {
                return Err(format!(
                    "kernel place field of {:?} is not finite",
                    c.channel
                ));
            }
        }
        Ok(Self::new(norm, (alpha, beta), channels, cv, centred_rms_px))
    }

    /// Where `channel`'s kernel's centroid lies at sensor (x, y) for a setting, px against
    /// the pixel; `None` for a channel the model lacks.
    #[must_use]
    pub fn centroid(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
        lateral: LateralColour,
    ) -> Option<[f64; 2]> {
        let c = self.channels.iter().find(|c| c.channel == channel)?;
        let own = self.eval(&c.kernel, x, y, setting);
        let apart = match lateral {
            LateralColour::Correct => self.registration(channel, x, y, setting)?,
            LateralColour::Keep => [0.0, 0.0],
        };
        Some([own[0] + apart[0], own[1] + apart[1]])
    }

    /// Where `channel`'s registration lies against green's at sensor (x, y) for a
    /// setting, px: lateral colour that kernels centred on their own channel's image
    /// do not carry. `None` for a channel the model lacks.
    #[must_use]
    pub fn registration(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
    ) -> Option<[f64; 2]> {
        let c = self.channels.iter().find(|c| c.channel == channel)?;
        Some(self.eval(&c.registration, x, y, setting))
    }

    /// An offset's x and y fields at sensor (x, y) for a setting, continued linearly
    /// beyond the area the chart covered.
    fn eval(&self, field: &[Vec<f64>; 2], x: f64, y: f64, setting: LensSetting) -> [f64; 2] {
        let v = self.norm.extrapolate(x, y, |x, y| {
            let coords = global_coords(&self.norm, x, y, setting.focal_mm, setting.f_number);
            let mut row = vec![0.0; self.basis.len()];
            self.basis.row(coords, &mut row);
            let dot = |c: &Vec<f64>| c.iter().zip(&row).map(|(a, b)| a * b).sum::<f64>();
            // The extrapolation carries three outputs; the third is unused.
            [dot(&field[0]), dot(&field[1]), 0.0]
        });
        // A place past the widest kernel lensblur accepts is no lens's (a damaged
        // profile, or a field continued far past the chart): held there, so the kernel
        // rendered around it stays within the limits.
        let limit = crate::limits::MAX_KERNEL_RADIUS_PX;
        let held = |o: f64| {
            if o.is_finite() {
                o.clamp(-limit, limit)
            } else {
                0.0
            }
        };
        [held(v[0]), held(v[1])]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{PsfShape, SimulatedSession, VirtualLens};

    const SIZE: (usize, usize) = (480, 320);

    /// A lens of `shape` with lateral colour of ±3e-3 (about 0.9 px at the frame's
    /// corners), a stand-in session that kept its kernels (1 % noise) over 3 focal
    /// lengths × 2 apertures.
    fn session(shape: PsfShape) -> (VirtualLens, Dataset) {
        let mut lens = VirtualLens {
            shape,
            ..VirtualLens::demo()
        };
        lens.geometry.lateral_colour = [3e-3, -3e-3];
        let settings: Vec<LensSetting> = [24.0, 60.0, 105.0]
            .into_iter()
            .flat_map(|focal_mm| [4.0, 10.0].map(|f_number| LensSetting { focal_mm, f_number }))
            .collect();
        let ds = SimulatedSession {
            cols: 8,
            rows: 6,
            kernel_noise: Some(0.01),
            seed: 7,
            ..SimulatedSession::new(SIZE.0, SIZE.1)
        }
        .dataset(&lens, &settings);
        (lens, ds)
    }

    fn fit(ds: &Dataset) -> PlaceModel {
        let folds: Vec<usize> = (0..ds.shots.len()).map(|i| i % 3).collect();
        PlaceModel::fit(ds, &folds, 3).expect("fit")
    }

    /// Predicted against true centroids (the lens's pixel-level kernels, lateral colour
    /// included) at a setting between the shots, over the chart's area and to the
    /// frame's corners: the largest and the RMS error, and the largest true offset of
    /// red or blue against green, px.
    fn errors(lens: &VirtualLens, model: &PlaceModel, lateral: LateralColour) -> [f64; 3] {
        let s = LensSetting {
            focal_mm: 45.0,
            f_number: 6.3,
        };
        let (mut worst, mut sse, mut n, mut largest) = (0.0f64, 0.0, 0, 0.0f64);
        for j in 0..5 {
            for i in 0..7 {
                let x = 10.0 + i as f64 * 460.0 / 6.0;
                let y = 10.0 + j as f64 * 300.0 / 4.0;
                let truth = |ch| {
                    let m = lens.pixel_kernel_at(ch, x, y, SIZE, s).moments();
                    [m.mean_x, m.mean_y]
                };
                let g = truth(Channel::G);
                for ch in [Channel::R, Channel::G, Channel::B] {
                    let t = truth(ch);
                    let p = model.centroid(ch, x, y, s, lateral).expect("channel");
                    let e = (p[0] - t[0]).hypot(p[1] - t[1]);
                    worst = worst.max(e);
                    sse += e * e;
                    n += 1;
                    largest = largest.max((t[0] - g[0]).hypot(t[1] - g[1]));
                }
            }
        }
        [worst, (sse / n as f64).sqrt(), largest]
    }

    #[test]
    fn kernels_carrying_lateral_colour_are_centred_where_the_lens_puts_them() {
        let (lens, ds) = session(PsfShape::Gaussian);
        let model = fit(&ds);
        let [worst, rms, largest] = errors(&lens, &model, LateralColour::Correct);
        eprintln!(
            "α {} β {}: worst {worst:.4} px, RMS {rms:.4} px, of shifts up to {largest:.3} px",
            model.alpha, model.beta
        );
        assert!(largest > 0.8, "the test lens moves red by {largest} px");
        assert!(worst < 0.03, "worst error {worst} px");
    }

    /// The measured chain's form: each channel registered on its own (red and blue
    /// sampled where the lens images them) and its kernel centred there. Correcting
    /// puts the kernels where the lens put the channels; keeping, where each channel's
    /// own image has them.
    #[test]
    fn registration_apart_is_lateral_colour_the_kernels_then_omit() {
        let (lens, mut ds) = session(PsfShape::Gaussian);
        let centre = [(SIZE.0 as f64 - 1.0) / 2.0, (SIZE.1 as f64 - 1.0) / 2.0];
        for s in &mut ds.samples {
            let d = lens
                .geometry
                .lateral_shift_px(s.channel, [s.x - centre[0], s.y - centre[1]]);
            s.x += d[0];
            s.y += d[1];
            if let Some(k) = &s.kernel {
                s.kernel = Some(std::sync::Arc::new(k.shifted(-d[0], -d[1])));
            }
        }
        let model = fit(&ds);
        let [worst, _, largest] = errors(&lens, &model, LateralColour::Correct);
        eprintln!("registered apart: worst {worst:.4} px of shifts up to {largest:.3} px");
        assert!(worst < 0.03, "worst error {worst} px");
        // Kept, red and blue stay centred on their own images: off by the whole shift.
        let [keep_worst, ..] = errors(&lens, &model, LateralColour::Keep);
        assert!(
            keep_worst > 0.8,
            "keeping moved the kernels by {keep_worst} px"
        );
    }

    /// A damaged profile's place (finite, but of no lens) stays within the widest kernel
    /// lensblur accepts, so nothing is sized from it.
    #[test]
    fn a_place_of_no_lens_is_held_within_the_kernel_limit() {
        let (_, ds) = session(PsfShape::Gaussian);
        let mut model = fit(&ds);
        model.channels[0].kernel[0][0] = 1e300;
        model.channels[0].kernel[1][0] = -1e300;
        let s = LensSetting {
            focal_mm: 45.0,
            f_number: 6.3,
        };
        let ch = model.channels[0].channel;
        let p = model
            .centroid(ch, 100.0, 100.0, s, LateralColour::Correct)
            .expect("channel");
        let limit = crate::limits::MAX_KERNEL_RADIUS_PX;
        assert!(p.iter().all(|v| v.abs() <= limit), "{p:?}");
    }

    /// Coma moves every channel's kernels, and this lens's comet turns abruptly about
    /// the frame's centre, which no smooth field follows: held out, the model still
    /// takes most of the centroids' spread away, and against the truth it is far
    /// closer than centring every kernel.
    #[test]
    fn coma_and_lateral_colour_together() {
        let (lens, ds) = session(PsfShape::Comet);
        let model = fit(&ds);
        let best = model
            .cv
            .iter()
            .map(|c| c.rms_px)
            .fold(f64::INFINITY, f64::min);
        let [_, rms, largest] = errors(&lens, &model, LateralColour::Correct);
        let centred = PlaceModel {
            channels: model
                .channels
                .iter()
                .map(|c| ChannelPlace {
                    channel: c.channel,
                    kernel: [vec![0.0; model.basis.len()], vec![0.0; model.basis.len()]],
                    registration: [vec![0.0; model.basis.len()], vec![0.0; model.basis.len()]],
                })
                .collect(),
            ..model.clone()
        };
        let [_, rms_centred, _] = errors(&lens, &centred, LateralColour::Correct);
        eprintln!(
            "comet α {} β {}: held out {best:.4} px against {:.4} centred; RMS against truth {rms:.4} px against {rms_centred:.4} centred (shifts up to {largest:.3} px)",
            model.alpha, model.beta, model.centred_rms_px
        );
        assert!(best < 0.5 * model.centred_rms_px);
        assert!(
            rms < 0.4 * rms_centred,
            "RMS {rms} px against {rms_centred} px centred"
        );
    }
}
