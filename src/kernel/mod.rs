//! Super-resolved non-parametric kernels per chart square and channel (paper §2.2.2),
//! and their Gaussian fits (paper §2.3, in [`crate::gaussian`]).
//!
//! For one square and channel we solve min ‖W(A_r k − U b)‖² by conjugate gradients on
//! the normal equations. W weighs the observed pixel centres; a clipped pixel (at or
//! above [`KernelParams::clip_level`]) is a censored observation, not a value: it says
//! only that the value there would have been at least the clip level, so with the
//! default operator it enters as its expected value given that under the current fit
//! (EM on a Tobit model, see `solve_edges`), and a square whose whites touch the top of
//! the range keeps the rest of its edges. (Weighing it nothing leaves its unclipped
//! neighbours, those whose truth lies within the noise of the top, a sample biased
//! low.) A_r convolves with the sharp chart rasterised at `oversample`× from the
//! square's refined homography; every product with A_r or A_rᵀ is an FFT (never a
//! matrix). The raster extends past the observed region by the kernel radius, so the
//! convolution is the valid part of a linear one: the FFT side is at least the
//! raster's, and the circular wrap only touches outputs we never read.
//!
//! Levels: rather than trusting a black/white estimate, the unknowns are an
//! unnormalised kernel k′ = (white − black)·k plus a constant offset (= black), so each
//! channel of a RAW capture fits its own gain and black point exactly; k is k′ / Σk′.
//!
//! Sub-pixel grid: with odd s = `oversample`, sub-sample n along x sits at sensor
//! `x_start + n / s`, so every real pixel centre is a sub-sample. A raster cell
//! integrates the chart over 1/s px, hence the recovered k satisfies
//! k ⊛ box(1/s) ≈ PSF ⊛ box(1): its variance is short by 1/(12 s²) px² per axis, which
//! the Gaussian fit adds back.

pub mod edges;
pub mod file;
pub mod packed;
mod solve;

use crate::chart::{self, ChartSpec};
use crate::gaussian::{FitError, FitParams, GaussianFit, fit_gaussian};
use crate::geometry::Homography;
use crate::plane::{Capture, Channel};
use crate::psf::Kernel;
use serde::{Deserialize, Serialize};

pub use solve::{CgSolution, LeastSquares, LinearOperator, NormalEquations, cg_solve, cgls_solve};

/// Which sub-samples carry observations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Weighting {
    /// Only the sub-samples that are real pixel centres of the channel's planes (weight
    /// 1), none in between: no interpolated data enters the fit.
    #[default]
    PixelCentres,
    /// Every sub-sample, with the observation bilinearly up-sampled (the paper's W = I).
    Uniform,
}

/// How products with A_r and A_rᵀ are computed. Both give the same operator (tested to
/// rounding); they differ in speed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Operator {
    /// With pixel-centre weighting, products over the observed pixels only, exploiting
    /// the chart's uniform areas ([`edges`]); with W = I, the FFT form.
    #[default]
    Auto,
    /// Every product a 2-D FFT over the whole oversampled raster ([`LeastSquares`]).
    Fft,
}

/// Parameters of the kernel estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelParams {
    /// Sub-samples per pixel (odd, so pixel centres are sub-samples).
    pub oversample: usize,
    pub weighting: Weighting,
    pub operator: Operator,
    /// Kernel half-width in pixels; `None` chooses it from the blur (first pass).
    pub support_px: Option<f64>,
    /// Most conjugate-gradient iterations of the final estimate. CG stopped early is the
    /// regulariser here: on 3× super-resolved kernels from simulated 10 MP shots, 30
    /// iterations gave the smallest σ error (20 under-resolve the core, +1.7 %; 40 and
    /// more start fitting noise into the tails).
    pub cg_iterations: usize,
    /// Relative residual of the normal equations at which CG stops early.
    pub cg_tolerance: f64,
    /// Weight of a gradient (smoothness) penalty on the kernel, relative to the data
    /// term's typical diagonal; 0 (the default) disables it, since any weight that
    /// visibly smooths also widens the kernel (0.03 biased σ by +3–4 %).
    pub smoothness: f64,
    /// Samples below this fraction of the kernel's peak are set to zero.
    pub threshold: f64,
    /// Largest half-width the automatic support may grow to, in pixels.
    pub max_support_px: f64,
    /// A kernel with more than this fraction of its mass in its outermost pixel-wide
    /// ring is reported as clipped by its support.
    pub clipped_fraction: f64,
    /// An observed value at or above this (white = 1) is clipped: it bounds the blurred
    /// edge from below and no more (a censored observation with the default operator,
    /// zero weight in Kee's W with the others).
    pub clip_level: f64,
}

impl Default for KernelParams {
    fn default() -> Self {
        Self {
            oversample: 3,
            weighting: Weighting::PixelCentres,
            operator: Operator::Auto,
            support_px: None,
            cg_iterations: 30,
            cg_tolerance: 1e-7,
            smoothness: 0.0,
            threshold: crate::gaussian::CLEAN_THRESHOLD,
            max_support_px: 40.0,
            clipped_fraction: 0.02,
            clip_level: crate::plane::CLIPPED_FROM,
        }
    }
}

/// What the kernel stage needs of an aligned square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SquareGeometry {
    pub row: usize,
    pub col: usize,
    pub image_from_chart: Homography,
}

/// Why one square/channel gave no kernel. Reported, never silently dropped.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum KernelFailure {
    #[error("no {0} pixels observed in the square")]
    NoObservations(Channel),
    #[error("square does not map to a finite region of the image")]
    BadHomography,
    #[error(
        "kernel clipped by its support ({fraction_pct:.1} % of its mass on the border at half-width {support_px:.1} px)"
    )]
    Clipped { fraction_pct: f64, support_px: f64 },
    #[error("blur wider than the largest support ({0:.1} px)")]
    TooWide(f64),
    #[error("kernel has no positive mass")]
    Empty,
    #[error("Gaussian fit failed: {0}")]
    Fit(#[from] FitError),
}

/// One square's kernel for one channel, with its Gaussian fits.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelEstimate {
    pub channel: Channel,
    /// Square centre, sensor px.
    pub centre: [f64; 2],
    pub kernel: Kernel,
    pub fit: GaussianFit,
    /// CG iterations run and relative normal-equation residual reached.
    pub cg_iterations: usize,
    pub cg_residual: f64,
}

/// All channels of one square.
#[derive(Clone, Debug)]
pub struct SquareKernels {
    pub row: usize,
    pub col: usize,
    pub centre: [f64; 2],
    /// One per channel of the capture, in [`Capture::channels`] order.
    pub estimates: Vec<(Channel, Result<KernelEstimate, KernelFailure>)>,
}

/// Every square of a shot.
#[derive(Clone, Debug)]
pub struct ShotKernels {
    pub width: usize,
    pub height: usize,
    pub oversample: usize,
    pub squares: Vec<SquareKernels>,
}

#[derive(Debug, thiserror::Error)]
pub enum KernelError {
    #[error(transparent)]
    Cancelled(#[from] crate::job::Cancelled),
    #[error("invalid kernel parameters: {0}")]
    Params(String),
}

/// Checks parameters once, before any square.
///
/// # Errors
/// A description of the first invalid parameter.
pub fn validate(params: &KernelParams) -> Result<(), KernelError> {
    if params.oversample == 0 || params.oversample.is_multiple_of(2) || params.oversample > 9 {
        return Err(KernelError::Params(format!(
            "oversample must be odd, 1–9 (got {})",
            params.oversample
        )));
    }
    if params.cg_iterations == 0 {
        return Err(KernelError::Params("cg_iterations must be positive".into()));
    }
    if let Some(s) = params.support_px
        && !(s.is_finite() && s > 0.0 && s <= 200.0)
    {
        return Err(KernelError::Params(format!(
            "support must be 0–200 px (got {s})"
        )));
    }
    if !(0.0..1.0).contains(&params.threshold) {
        return Err(KernelError::Params(format!(
            "threshold must be in [0, 1) (got {})",
            params.threshold
        )));
    }
    Ok(())
}

/// Square centre in sensor pixels.
#[must_use]
pub fn square_centre(square: &SquareGeometry) -> [f64; 2] {
    square
        .image_from_chart
        .apply([square.col as f64 + 0.5, square.row as f64 + 0.5])
}

/// Half-width (pixels) of the first, coarse pass that measures the blur.
const FIRST_PASS_SUPPORT_PX: f64 = 5.0;

/// Kernel half-width (pixels) for a channel whose blur beyond the pixel area is about
/// `sigma_px` (the alignment's isotropic estimate): 3.5 σ of the pixel-level PSF, with
/// 15 % more for the major axis of an anisotropic blur. Past 2.8 σ a Gaussian is below
/// the 2 % threshold, so nothing measured is lost; a kernel that still reaches the
/// border is re-estimated with a larger support.
#[must_use]
pub fn support_for_sigma(sigma_px: f64) -> f64 {
    let pixel_level = (sigma_px.max(0.0).powi(2) + 1.0 / 12.0).sqrt();
    (3.5 * 1.15 * pixel_level + 1.0).ceil().max(3.0)
}

/// Estimates the kernel of one square and channel.
///
/// # Errors
/// A [`KernelFailure`] saying why this square/channel has no kernel.
pub fn estimate_square_geometry(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    params: &KernelParams,
    channel: Channel,
) -> Result<KernelEstimate, KernelFailure> {
    estimate_square(capture, square, spec, params, &[channel], &[])
        .pop()
        .map_or(Err(KernelFailure::NoObservations(channel)), |(_, r)| r)
}

/// Estimates the kernels of one square in every channel of `channels`, sharing the sharp
/// raster between channels that need the same support. `sigma_hints_px` (the
/// alignment's blur estimate per channel) sets each channel's kernel support; for a
/// channel without one, a first, 1× pass measures its blur.
#[must_use]
pub fn estimate_square(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    params: &KernelParams,
    channels: &[Channel],
    sigma_hints_px: &[(Channel, f64)],
) -> Vec<(Channel, Result<KernelEstimate, KernelFailure>)> {
    let mut prepared: Vec<Prepared> = Vec::new();
    channels
        .iter()
        .map(|&channel| {
            let hint = sigma_hints_px
                .iter()
                .find(|(c, _)| *c == channel)
                .map(|(_, s)| *s);
            let hint = hint.filter(|s| s.is_finite() && *s >= 0.0);
            let first = match (params.support_px, hint) {
                (Some(s), _) => Ok((s, hint)),
                (None, Some(sigma)) => Ok((support_for_sigma(sigma), hint)),
                (None, None) => measure_support(capture, square, spec, params, channel)
                    .map(|(support, sigma)| (support, Some(sigma))),
            };
            let r = first.and_then(|(support, sigma)| {
                estimate_with_support(
                    capture,
                    square,
                    spec,
                    params,
                    channel,
                    (support, sigma),
                    &mut prepared,
                )
            });
            (channel, r)
        })
        .collect()
}

/// Estimates at `support_px`, growing the support while the kernel is clipped by it.
fn estimate_with_support(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    params: &KernelParams,
    channel: Channel,
    (mut support_px, sigma_px): (f64, Option<f64>),
    prepared: &mut Vec<Prepared>,
) -> Result<KernelEstimate, KernelFailure> {
    let os = params.oversample;
    let mut previous_clipped = None;
    loop {
        let r_px = support_px.ceil().max(1.0) as usize;
        let prep = match prepared.iter().position(|p| p.r_px == r_px && p.os == os) {
            Some(i) => &prepared[i],
            None => {
                let p = prepare(capture, square, spec, os, r_px, params, channel)?;
                prepared.push(p);
                &prepared[prepared.len() - 1]
            }
        };
        let raw = solve(
            capture,
            prep,
            channel,
            params,
            (params.cg_iterations, params.cg_tolerance),
            sigma_px,
        )?;
        let kernel = clean(&raw.kernel, params.threshold)?;
        let fit = fit_gaussian(
            &kernel,
            &FitParams {
                threshold: params.threshold,
                add_variance_px2: 1.0 / (12.0 * (os * os) as f64),
            },
        )?;
        let clipped = clipped_fraction(&kernel, &fit, params.threshold, r_px as f64);
        // A PSF's tail thins outwards: with the support grown by half, the ring at the
        // new border holds well under half the mass the old one did (a tail falling as
        // steeply as 1/r³ leaves 44 %). Border mass that does not fall is not the PSF's
        // (the fall-off's slope across the square, noise the solve spread outwards), and
        // growing further would only chase it.
        let not_the_psf = previous_clipped.is_some_and(|before| clipped > 0.5 * before);
        if clipped <= params.clipped_fraction || not_the_psf {
            return Ok(KernelEstimate {
                channel,
                centre: square_centre(square),
                kernel,
                fit,
                cg_iterations: raw.iterations,
                cg_residual: raw.residual,
            });
        }
        if r_px as f64 >= params.max_support_px {
            return Err(KernelFailure::Clipped {
                fraction_pct: 100.0 * clipped,
                support_px: r_px as f64,
            });
        }
        previous_clipped = Some(clipped);
        support_px = (r_px as f64 * 1.5).ceil().min(params.max_support_px);
    }
}

/// How much of the kernel the support cuts off: the larger of the central region's
/// mass on the outermost pixel-wide ring (isolated noise specks near the border are not
/// PSF mass and the fit ignores them too) and the fitted Gaussian's mass outside the
/// support, which a noisy border cannot fake.
fn clipped_fraction(kernel: &Kernel, fit: &GaussianFit, threshold: f64, support_px: f64) -> f64 {
    let central = Kernel {
        data: crate::gaussian::central_region(kernel, threshold),
        ..kernel.clone()
    };
    let border = border_fraction(&central);
    let tail = |sigma: f64| 1.0 - crate::psf::erf(support_px / (std::f64::consts::SQRT_2 * sigma));
    let outside = tail(fit.robust.sigma_x) + tail(fit.robust.sigma_y);
    // Both are evidence of clipping only when the kernel truly reaches the border: a
    // Gaussian tail beyond the support alone (a kernel the fit made wider than it is)
    // or noise on the border alone (a well-contained kernel) is not.
    border.min(outside.max(border * 0.5))
}

/// First pass: a 1× estimate with a growing support until the kernel fits inside it;
/// its spread sets the final half-width.
fn measure_support(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    params: &KernelParams,
    channel: Channel,
) -> Result<(f64, f64), KernelFailure> {
    let mut support = FIRST_PASS_SUPPORT_PX;
    loop {
        let r_px = support.ceil() as usize;
        let prep = prepare(capture, square, spec, 1, r_px, params, channel)?;
        let raw = solve(capture, &prep, channel, params, (40, 1e-6), None)?;
        let kernel = clean(&raw.kernel, params.threshold)?;
        let central = Kernel {
            data: crate::gaussian::central_region(&kernel, params.threshold),
            ..kernel
        };
        let border = border_fraction(&central);
        if border <= params.clipped_fraction {
            let m = central.moments();
            // The 1× kernel misses the 1/12 px² of its pixel-sized raster cells; the
            // support rule adds the pixel's own 1/12 back.
            let sigma = m.var_x.max(m.var_y).max(0.0).sqrt();
            let r = support_for_sigma(sigma);
            if r > params.max_support_px {
                return Err(KernelFailure::TooWide(params.max_support_px));
            }
            return Ok((r, sigma));
        }
        if support >= params.max_support_px {
            return Err(KernelFailure::TooWide(params.max_support_px));
        }
        support = (support * 2.0).min(params.max_support_px);
    }
}

/// A `k_size × k_size` isotropic Gaussian of `sigma_px` sensor pixels at `os`
/// sub-samples per pixel, summing to one: the blur's guess the shading regressors use.
fn gaussian_guess(k_size: usize, os: usize, sigma_px: f64) -> Vec<f64> {
    let r = (k_size / 2) as f64;
    let s = (sigma_px.powi(2) + 1.0 / 12.0).sqrt() * os as f64;
    let mut g: Vec<f64> = (0..k_size * k_size)
        .map(|i| {
            let (x, y) = ((i % k_size) as f64 - r, (i / k_size) as f64 - r);
            (-(x * x + y * y) / (2.0 * s * s)).exp()
        })
        .collect();
    let sum: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= sum);
    g
}

/// Clamps negatives, zeroes samples below `threshold`·peak, renormalises.
fn clean(kernel: &Kernel, threshold: f64) -> Result<Kernel, KernelFailure> {
    let peak = kernel.data.iter().copied().fold(0.0f64, f64::max);
    if !(peak > 0.0) {
        return Err(KernelFailure::Empty);
    }
    let data = kernel
        .data
        .iter()
        .map(|&v| if v > threshold * peak { v } else { 0.0 })
        .collect();
    let mut k = Kernel {
        size: kernel.size,
        oversample: kernel.oversample,
        data,
    };
    k.normalise();
    Ok(k)
}

/// Fraction of the kernel's mass in its outermost pixel-wide ring.
#[must_use]
pub fn border_fraction(kernel: &Kernel) -> f64 {
    let n = kernel.size;
    let ring = kernel.oversample.min(n / 2).max(1);
    let (mut edge, mut total) = (0.0, 0.0);
    for j in 0..n {
        for i in 0..n {
            let v = kernel.at(i, j);
            total += v;
            if i < ring || j < ring || i >= n - ring || j >= n - ring {
                edge += v;
            }
        }
    }
    if total > 0.0 { edge / total } else { 0.0 }
}

struct RawKernel {
    /// Normalised to sum 1 but not yet clamped.
    kernel: Kernel,
    iterations: usize,
    residual: f64,
}

/// A square set up for estimation at one oversampling and kernel half-width: the
/// observation window (sensor px) and the sharp chart rasterised over it plus the
/// kernel radius, so every observation's model is a valid (not circular) convolution.
struct Prepared {
    os: usize,
    r_px: usize,
    /// Observed window, inclusive, sensor px.
    bx0: usize,
    by0: usize,
    bx1: usize,
    by1: usize,
    k_size: usize,
    nx: usize,
    ny: usize,
    raster: Vec<f32>,
    /// Which kernel patches are uniform (pixel-centre weighting by the direct operator).
    uniform: Option<edges::Uniformity>,
}

fn prepare(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    os: usize,
    r_px: usize,
    params: &KernelParams,
    // Only for the failure: what is prepared is the same for every channel.
    channel: Channel,
) -> Result<Prepared, KernelFailure> {
    let r_sub = r_px * os;
    let k_size = 2 * r_sub + 1;
    // Observed region: the square's bounding box plus a margin of one kernel radius, so
    // the blurred outer edges are seen whole; clipped to the frame.
    let corners = spec
        .square_corners(square.col, square.row)
        .map(|c| square.image_from_chart.apply(c));
    if corners
        .iter()
        .any(|c| !(c[0].is_finite() && c[1].is_finite()))
    {
        return Err(KernelFailure::BadHomography);
    }
    let margin = r_px as f64;
    let lo = |k: usize| corners.iter().map(|c| c[k]).fold(f64::INFINITY, f64::min) - margin;
    let hi = |k: usize| {
        corners
            .iter()
            .map(|c| c[k])
            .fold(f64::NEG_INFINITY, f64::max)
            + margin
    };
    let bx0 = lo(0).ceil().max(0.0);
    let by0 = lo(1).ceil().max(0.0);
    let bx1 = hi(0).floor().min(capture.width as f64 - 1.0);
    let by1 = hi(1).floor().min(capture.height as f64 - 1.0);
    if !(bx1 > bx0 + 2.0 && by1 > by0 + 2.0) || bx1 - bx0 > 4000.0 || by1 - by0 > 4000.0 {
        return Err(KernelFailure::NoObservations(channel));
    }
    let (bx0, by0, bx1, by1) = (bx0 as usize, by0 as usize, bx1 as usize, by1 as usize);
    let nx = (bx1 - bx0) * os + 1 + 2 * r_sub;
    let ny = (by1 - by0) * os + 1 + 2 * r_sub;
    // With odd s, sub-sample n along x sits at sensor x_start + n / s, so every real
    // pixel centre is a sub-sample.
    let s = os as f64;
    let x_start = bx0 as f64 - r_sub as f64 / s;
    let y_start = by0 as f64 - r_sub as f64 / s;
    let sub_from_image =
        Homography::scaling(s, s).compose(&Homography::translation(-x_start, -y_start));
    let raster = chart::rasterize(
        spec,
        &sub_from_image.compose(&square.image_from_chart),
        nx,
        ny,
        1.0,
    )
    .data;
    let uniform = (params.weighting == Weighting::PixelCentres
        && params.operator == Operator::Auto)
        .then(|| edges::Uniformity::new(&raster, nx, ny, k_size));
    Ok(Prepared {
        os,
        r_px,
        bx0,
        by0,
        bx1,
        by1,
        k_size,
        nx,
        ny,
        raster,
        uniform,
    })
}

/// Solves the least-squares problem of one channel over a prepared square.
fn solve(
    capture: &Capture,
    prep: &Prepared,
    channel: Channel,
    params: &KernelParams,
    (iterations, tolerance): (usize, f64),
    reference_sigma_px: Option<f64>,
) -> Result<RawKernel, KernelFailure> {
    let (os, k_size) = (prep.os, prep.k_size);
    let planes = || capture.planes.iter().filter(|p| p.channel == channel);
    // The channel's real pixel centres in the observed window: where each one's kernel
    // patch starts in the raster, and its value. The patch under pixel x is centred on
    // its raster sample (x − bx0)·s + r_sub, so it starts at (x − bx0)·s.
    let centres = || {
        planes().flat_map(move |cp| {
            // The plane's pixels inside the window [b·0, b·1] along one axis.
            let span = move |lo: usize, hi: usize, offset: usize, n: usize| {
                let first = lo.saturating_sub(offset).div_ceil(cp.step);
                let end = if hi < offset {
                    0
                } else {
                    ((hi - offset) / cp.step + 1).min(n)
                };
                first..end.max(first)
            };
            span(prep.by0, prep.by1, cp.offset_y, cp.plane.height).flat_map(move |j| {
                span(prep.bx0, prep.bx1, cp.offset_x, cp.plane.width).map(move |i| {
                    let (x, y) = (cp.step * i + cp.offset_x, cp.step * j + cp.offset_y);
                    (
                        (x - prep.bx0) * os,
                        (y - prep.by0) * os,
                        f64::from(cp.plane.get(i, j)),
                    )
                })
            })
        })
    };
    // A clipped pixel is not a value: it says only that the value would have been at
    // least the clip level (see `solve_edges`).
    let pixel_centres = || centres().filter(|&(_, _, v)| v < params.clip_level);
    // The FFT forms decide on the shading unknowns as the direct one does.
    let fft_shading = |problem: &mut LeastSquares| {
        let Some(sigma) = reference_sigma_px else {
            return;
        };
        let own;
        let uniform = match &prep.uniform {
            Some(u) => u,
            None => {
                own = edges::Uniformity::new(&prep.raster, prep.nx, prep.ny, k_size);
                &own
            }
        };
        if edges::light_slopes(uniform, (prep.nx, prep.ny), pixel_centres()) {
            problem.set_shading_reference(&gaussian_guess(k_size, os, sigma));
        }
    };
    let solution = match (&prep.uniform, params.weighting) {
        (Some(uniform), _) => {
            let clipped: Vec<(usize, usize)> = centres()
                .filter(|&(_, _, v)| v >= params.clip_level)
                .map(|(x0, y0, _)| (x0, y0))
                .collect();
            let data = Observations {
                kept: pixel_centres,
                clipped: &clipped,
            };
            solve_edges(
                prep,
                uniform,
                params,
                &data,
                reference_sigma_px,
                (iterations, tolerance),
            )
            .ok_or(KernelFailure::NoObservations(channel))?
        }
        (None, Weighting::PixelCentres) => {
            let mut problem = LeastSquares::new(&prep.raster, prep.nx, prep.ny, k_size);
            problem.set_smoothness(params.smoothness);
            // The FFT form indexes a sample by where its patch ends.
            let mut count = 0usize;
            for (x0, y0, v) in pixel_centres() {
                problem.observe(x0 + k_size - 1, y0 + k_size - 1, v);
                count += 1;
            }
            if count < k_size {
                return Err(KernelFailure::NoObservations(channel));
            }
            fft_shading(&mut problem);
            // CGLS, as for the default operator: the iteration count is the
            // regulariser, and CG on the normal equations squares the rounding.
            cgls_solve(&mut problem, iterations, tolerance)
        }
        (None, Weighting::Uniform) => {
            let mut problem = LeastSquares::new(&prep.raster, prep.nx, prep.ny, k_size);
            problem.set_smoothness(params.smoothness);
            let r_sub = k_size / 2;
            let s = os as f64;
            let mut count = 0usize;
            for cp in planes() {
                for q_y in 0..=(prep.by1 - prep.by0) * os {
                    let y = prep.by0 as f64 + q_y as f64 / s;
                    for q_x in 0..=(prep.bx1 - prep.bx0) * os {
                        let x = prep.bx0 as f64 + q_x as f64 / s;
                        let [pi, pj] = cp.plane_from_sensor(x, y);
                        if let Some(v) = cp.plane.bilinear(pi, pj)
                            && !touches_clipped(&cp.plane, pi, pj, params.clip_level)
                        {
                            problem.observe(q_x + 2 * r_sub, q_y + 2 * r_sub, f64::from(v));
                            count += 1;
                        }
                    }
                }
            }
            if count < k_size {
                return Err(KernelFailure::NoObservations(channel));
            }
            fft_shading(&mut problem);
            cg_solve(&mut problem, iterations, tolerance)
        }
    };
    let (k, _offset) = solution.x.split_at(k_size * k_size);
    let sum: f64 = k.iter().sum();
    if !(sum.is_finite() && sum > 0.0) {
        return Err(KernelFailure::Empty);
    }
    Ok(RawKernel {
        kernel: Kernel {
            size: k_size,
            oversample: os,
            data: k.iter().map(|v| v / sum).collect(),
        },
        iterations: solution.iterations,
        residual: solution.relative_residual,
    })
}

/// Most rounds of the censored term in [`solve_edges`].
const CENSORED_ROUNDS: usize = 6;

/// A channel's pixel centres in a square's window, as (patch x, patch y, value): those
/// below the clip level, and the positions of those at or above it.
struct Observations<'a, F> {
    kept: F,
    clipped: &'a [(usize, usize)],
}

/// The default operator's solve, with the clipped pixels as censored observations (a
/// Tobit model): a clipped pixel says that its truth plus its noise reached the clip
/// level, and no more. Pure zero weight throws that away, and then the pixels kept
/// beside the clipped ones, those whose truth lies within the noise of the top, are a
/// sample biased low: their brighter draws are the ones that clipped. The model is
/// fitted by EM: each round gives every clipped pixel its expected value under the
/// current fit given that it clipped, μ + σ·φ(z)/(1 − Φ(z)) with z = (level − μ)/σ, and
/// solves again (σ: the noise of the kept pixels near the top, from their residuals).
/// Where too few pixels near the top are kept to tell σ, the term is one-sided
/// instead: a clipped pixel the fit predicts below the level joins at the level.
/// `None`: too few observations.
fn solve_edges<F, I>(
    prep: &Prepared,
    uniform: &edges::Uniformity,
    params: &KernelParams,
    data: &Observations<'_, F>,
    reference_sigma_px: Option<f64>,
    (iterations, tolerance): (usize, f64),
) -> Option<CgSolution>
where
    F: Fn() -> I,
    I: Iterator<Item = (usize, usize, f64)>,
{
    let (k_size, level) = (prep.k_size, params.clip_level);
    let problem_with = |censored: &[Option<f64>]| {
        let mut problem = edges::EdgeProblem::new(&prep.raster, prep.nx, k_size);
        for (x0, y0, v) in (data.kept)() {
            problem.observe(x0, y0, v, uniform.value(x0, y0));
        }
        for (&(x0, y0), t) in data.clipped.iter().zip(censored) {
            if let Some(t) = *t {
                problem.observe(x0, y0, t, uniform.value(x0, y0));
            }
        }
        problem
    };
    let mut censored = vec![None; data.clipped.len()];
    let mut problem = problem_with(&censored);
    if problem.observations() < k_size {
        return None;
    }
    // Decided once, on the unclipped data, so that the rounds solve the same model.
    let guess = reference_sigma_px
        .filter(|_| problem.light_slopes())
        .map(|sigma| gaussian_guess(k_size, prep.os, sigma));
    let finish = |problem: &mut edges::EdgeProblem| {
        problem.set_smoothness(params.smoothness);
        if let Some(g) = &guess {
            problem.set_shading_reference(g);
        }
        cgls_solve(problem, iterations, tolerance)
    };
    let mut solution = finish(&mut problem);
    if data.clipped.is_empty() {
        return Some(solution);
    }
    // The model at every clipped pixel, then at the kept ones near the top: each one
    // its own row.
    let top: Vec<(usize, usize, f64)> = (data.kept)()
        .filter(|&(_, _, v)| v >= 0.5 * level)
        .collect();
    let mut probe = edges::EdgeProblem::new(&prep.raster, prep.nx, k_size);
    for &(x0, y0) in data.clipped {
        probe.observe(x0, y0, 0.0, None);
    }
    for &(x0, y0, _) in &top {
        probe.observe(x0, y0, 0.0, None);
    }
    if let Some(g) = &guess {
        probe.set_shading_reference(g);
    }
    let mut predicted = vec![0.0; probe.rows()];
    let n = data.clipped.len();
    for _ in 0..CENSORED_ROUNDS {
        probe.forward(&solution.x, &mut predicted);
        let noise = top_noise(&predicted[n..n + top.len()], &top, level);
        let next: Vec<Option<f64>> = predicted[..n]
            .iter()
            .map(|&mu| match noise {
                Some(sigma) => Some(mu + sigma * inverse_mills((level - mu) / sigma)),
                None => (mu < level).then_some(level),
            })
            .collect();
        let settled = next.iter().zip(&censored).all(|(a, b)| match (a, b) {
            (Some(a), Some(b)) => (a - b).abs() <= 0.05 * noise.unwrap_or(0.0),
            (None, None) => true,
            _ => false,
        });
        if settled {
            break;
        }
        censored = next;
        solution = finish(&mut problem_with(&censored));
    }
    Some(solution)
}

/// The noise σ of the pixels kept near the clip level (predicted within its top
/// quarter), robustly from their residuals; `None` with too few of them.
fn top_noise(predicted: &[f64], top: &[(usize, usize, f64)], level: f64) -> Option<f64> {
    let mut residuals: Vec<f64> = predicted
        .iter()
        .zip(top)
        .filter(|&(&mu, _)| mu >= 0.75 * level && mu < level)
        .map(|(&mu, &(_, _, v))| v - mu)
        .collect();
    if residuals.len() < 30 {
        return None;
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let centre = median(&mut residuals);
    let mut spread: Vec<f64> = residuals.iter().map(|r| (r - centre).abs()).collect();
    let sigma = 1.4826 * median(&mut spread);
    (sigma > 0.0).then_some(sigma)
}

/// φ(z) / (1 − Φ(z)) for the standard normal: the mean of a normal variable beyond z,
/// in σ. Beyond z = 4 the asymptotic series (erf's absolute error would dominate the
/// tail there).
fn inverse_mills(z: f64) -> f64 {
    if z >= 4.0 {
        return z + 1.0 / z - 2.0 / z.powi(3);
    }
    let survival = 0.5 * (1.0 - crate::psf::erf(z / std::f64::consts::SQRT_2));
    (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt() / survival
}

/// Whether a bilinear sample at plane point (x, y) draws on a clipped pixel.
fn touches_clipped(plane: &crate::plane::Plane, x: f64, y: f64, clip_level: f64) -> bool {
    let (x0, y0) = (x.floor().max(0.0) as usize, y.floor().max(0.0) as usize);
    (y0..=(y0 + 1).min(plane.height - 1)).any(|j| {
        (x0..=(x0 + 1).min(plane.width - 1)).any(|i| f64::from(plane.get(i, j)) >= clip_level)
    })
}

/// Every aligned square × channel of a shot, in parallel. A RAW capture's two green
/// planes are one channel here: the solver observes every plane of the channel, so G1
/// and G2 pool into one G kernel per square.
///
/// # Errors
/// Invalid parameters, or the job was cancelled.
pub fn estimate_shot(
    capture: &Capture,
    detection: &crate::detect::Detection,
    spec: &ChartSpec,
    params: &KernelParams,
    job: &crate::job::JobContext,
) -> Result<ShotKernels, KernelError> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    validate(params)?;
    let channels = capture.channels();
    let aligned: Vec<&crate::detect::SquareAlignment> = detection.ok_squares().collect();
    let total = aligned.len() * channels.len();
    let done = AtomicUsize::new(0);
    job.report("kernels", 0, total);
    // A square at a time, all its channels together: they share the sharp raster, and
    // the alignment's blur estimate sets their support.
    let squares: Result<Vec<SquareKernels>, crate::job::Cancelled> = aligned
        .par_iter()
        .map(|a| {
            job.check()?;
            let sq = SquareGeometry {
                row: a.row,
                col: a.col,
                image_from_chart: a.image_from_chart,
            };
            // Where detection registered the channels apart (lateral colour), each
            // channel's kernel is measured against its own image of the square, or it
            // comes out off-centre by the channels' separation.
            let estimates = if a.channel_image_from_chart.is_empty() {
                estimate_square(capture, &sq, spec, params, &channels, &a.sigma_by_channel)
            } else {
                channels
                    .iter()
                    .flat_map(|&ch| {
                        let own = SquareGeometry {
                            image_from_chart: a.image_from_chart_of(ch),
                            ..sq
                        };
                        estimate_square(capture, &own, spec, params, &[ch], &a.sigma_by_channel)
                    })
                    .collect()
            };
            let n = done.fetch_add(channels.len(), Ordering::Relaxed) + channels.len();
            job.report("kernels", n, total);
            Ok(SquareKernels {
                row: sq.row,
                col: sq.col,
                centre: square_centre(&sq),
                estimates,
            })
        })
        .collect();
    let squares = squares?;
    Ok(ShotKernels {
        width: capture.width,
        height: capture.height,
        oversample: params.oversample,
        squares,
    })
}

#[cfg(test)]
mod tests {
    use super::inverse_mills;

    /// φ(z) / (1 − Φ(z)) against the mean of the standard normal beyond z by quadrature,
    /// on both sides of the switch to the asymptotic series.
    #[test]
    fn inverse_mills_is_the_mean_beyond_z() {
        for z in [-2.0f64, 0.0, 1.0, 2.5, 3.9, 4.1, 6.0] {
            let (mut mass, mut moment) = (0.0, 0.0);
            let h = 1e-4;
            let mut x = z + 0.5 * h;
            while x < z + 12.0 {
                let density = (-0.5 * x * x).exp();
                mass += density;
                moment += x * density;
                x += h;
            }
            let want = moment / mass;
            let got = inverse_mills(z);
            assert!(
                (got - want).abs() < 2e-3 * want.abs().max(1.0),
                "z {z}: {got} vs {want}"
            );
        }
    }
}
