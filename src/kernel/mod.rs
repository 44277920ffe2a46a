//! Super-resolved non-parametric kernels per chart square and channel (DESIGN.md §1.4,
//! paper §2.2.2), and their Gaussian fits (§1.5, in [`crate::gaussian`]).
//!
//! For one square and channel we solve min ‖W(A_r k − U b)‖² by conjugate gradients on
//! the normal equations. A_r convolves with the sharp chart rasterised at `oversample`×
//! from the square's refined homography; every product with A_r or A_rᵀ is an FFT
//! (never a matrix). The raster extends past the observed region by the kernel radius,
//! so the convolution is the valid part of a linear one: the FFT side is at least the
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

pub mod file;
mod solve;

use crate::chart::{self, ChartSpec};
use crate::gaussian::{FitError, FitParams, GaussianFit, fit_gaussian};
use crate::geometry::Homography;
use crate::plane::{Capture, Channel};
use crate::psf::Kernel;
use serde::{Deserialize, Serialize};

pub use solve::{CgSolution, LeastSquares, NormalEquations, cg_solve};

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

/// Parameters of the kernel estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelParams {
    /// Sub-samples per pixel (odd, so pixel centres are sub-samples).
    pub oversample: usize,
    pub weighting: Weighting,
    /// Kernel half-width in pixels; `None` chooses it from the blur (first pass).
    pub support_px: Option<f64>,
    /// Most conjugate-gradient iterations of the final estimate.
    pub cg_iterations: usize,
    /// Relative residual of the normal equations at which CG stops early.
    pub cg_tolerance: f64,
    /// Weight of a gradient (smoothness) penalty on the kernel, relative to the data
    /// term's typical diagonal; 0 disables it.
    pub smoothness: f64,
    /// Samples below this fraction of the kernel's peak are set to zero.
    pub threshold: f64,
    /// Largest half-width the automatic support may grow to, in pixels.
    pub max_support_px: f64,
    /// A kernel with more than this fraction of its mass in its outermost pixel-wide
    /// ring is reported as clipped by its support.
    pub clipped_fraction: f64,
}

impl Default for KernelParams {
    fn default() -> Self {
        Self {
            oversample: 3,
            weighting: Weighting::PixelCentres,
            support_px: None,
            cg_iterations: 80,
            cg_tolerance: 1e-7,
            smoothness: 0.03,
            threshold: 0.02,
            max_support_px: 40.0,
            clipped_fraction: 0.02,
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
    /// One per channel of the capture, in [`channels_of`] order.
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

/// The channels a capture reports: R, G, B (G pooling every green plane), or Y.
#[must_use]
pub fn channels_of(capture: &Capture) -> Vec<Channel> {
    let mut out: Vec<Channel> = Vec::new();
    for ch in [Channel::R, Channel::G, Channel::B, Channel::Y] {
        if capture.planes.iter().any(|p| p.channel == ch) {
            out.push(ch);
        }
    }
    out
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
    let centre = square_centre(square);
    let support_px = match params.support_px {
        Some(s) => s,
        None => measure_support(capture, square, spec, params, channel)?,
    };
    let os = params.oversample;
    let raw = solve_kernel(
        capture,
        square,
        spec,
        channel,
        os,
        support_px,
        params.weighting,
        params.cg_iterations,
        params.cg_tolerance,
        params.smoothness,
    )?;
    let kernel = clean(&raw.kernel, params.threshold)?;
    // Only the central region counts: isolated noise specks near the border are not
    // PSF mass, and the Gaussian fit ignores them too.
    let central = Kernel {
        data: crate::gaussian::central_region(&kernel, params.threshold),
        ..kernel.clone()
    };
    let border = border_fraction(&central);
    if border > params.clipped_fraction {
        return Err(KernelFailure::Clipped {
            fraction_pct: 100.0 * border,
            support_px,
        });
    }
    let fit = fit_gaussian(
        &kernel,
        &FitParams {
            threshold: params.threshold,
            add_variance_px2: 1.0 / (12.0 * (os * os) as f64),
        },
    )?;
    Ok(KernelEstimate {
        channel,
        centre,
        kernel,
        fit,
        cg_iterations: raw.iterations,
        cg_residual: raw.residual,
    })
}

/// First pass: a 1× estimate with a growing support until the kernel fits inside it;
/// its spread sets the final half-width at ≈ 4σ plus a margin.
fn measure_support(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    params: &KernelParams,
    channel: Channel,
) -> Result<f64, KernelFailure> {
    let mut support = FIRST_PASS_SUPPORT_PX;
    loop {
        let raw = solve_kernel(
            capture,
            square,
            spec,
            channel,
            1,
            support,
            params.weighting,
            40,
            1e-6,
            params.smoothness,
        )?;
        let kernel = clean(&raw.kernel, params.threshold)?;
        let central = Kernel {
            data: crate::gaussian::central_region(&kernel, params.threshold),
            ..kernel
        };
        let border = border_fraction(&central);
        if border <= params.clipped_fraction {
            let m = central.moments();
            // The 1× kernel misses the 1/12 px² of its pixel-sized raster cells.
            let sigma = (m.var_x.max(m.var_y) + 1.0 / 12.0).sqrt();
            let r = (4.0 * sigma + 1.5).ceil().max(3.0);
            if r > params.max_support_px {
                return Err(KernelFailure::TooWide(params.max_support_px));
            }
            return Ok(r);
        }
        if support >= params.max_support_px {
            return Err(KernelFailure::TooWide(params.max_support_px));
        }
        support = (support * 2.0).min(params.max_support_px);
    }
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

/// Sets up and solves the least-squares problem at `os`× with half-width `support_px`.
#[allow(clippy::too_many_arguments)]
fn solve_kernel(
    capture: &Capture,
    square: &SquareGeometry,
    spec: &ChartSpec,
    channel: Channel,
    os: usize,
    support_px: f64,
    weighting: Weighting,
    iterations: usize,
    tolerance: f64,
    smoothness: f64,
) -> Result<RawKernel, KernelFailure> {
    let r_px = support_px.ceil().max(1.0) as usize;
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
    let lo_x = corners.iter().map(|c| c[0]).fold(f64::INFINITY, f64::min) - margin;
    let hi_x = corners
        .iter()
        .map(|c| c[0])
        .fold(f64::NEG_INFINITY, f64::max)
        + margin;
    let lo_y = corners.iter().map(|c| c[1]).fold(f64::INFINITY, f64::min) - margin;
    let hi_y = corners
        .iter()
        .map(|c| c[1])
        .fold(f64::NEG_INFINITY, f64::max)
        + margin;
    let bx0 = lo_x.ceil().max(0.0);
    let by0 = lo_y.ceil().max(0.0);
    let bx1 = hi_x.floor().min(capture.width as f64 - 1.0);
    let by1 = hi_y.floor().min(capture.height as f64 - 1.0);
    if !(bx1 > bx0 + 2.0 && by1 > by0 + 2.0) || bx1 - bx0 > 4000.0 || by1 - by0 > 4000.0 {
        return Err(KernelFailure::NoObservations(channel));
    }
    let (bx0, by0, bx1, by1) = (bx0 as usize, by0 as usize, bx1 as usize, by1 as usize);
    let nx = (bx1 - bx0) * os + 1 + 2 * r_sub;
    let ny = (by1 - by0) * os + 1 + 2 * r_sub;
    let s = os as f64;
    let x_start = bx0 as f64 - r_sub as f64 / s;
    let y_start = by0 as f64 - r_sub as f64 / s;
    let sub_from_image =
        Homography::scaling(s, s).compose(&Homography::translation(-x_start, -y_start));
    let sharp = chart::rasterize(
        spec,
        &sub_from_image.compose(&square.image_from_chart),
        nx,
        ny,
        1.0,
    );

    let mut problem = LeastSquares::new(&sharp.data, nx, ny, k_size);
    problem.set_smoothness(smoothness);
    // Observations in convolution-output coordinates: n = p + r_sub with p the
    // sub-sample index in the raster.
    let mut count = 0usize;
    for cp in capture.planes.iter().filter(|p| p.channel == channel) {
        match weighting {
            Weighting::PixelCentres => {
                for j in 0..cp.plane.height {
                    let y = cp.step * j + cp.offset_y;
                    if y < by0 || y > by1 {
                        continue;
                    }
                    for i in 0..cp.plane.width {
                        let x = cp.step * i + cp.offset_x;
                        if x < bx0 || x > bx1 {
                            continue;
                        }
                        let n_x = (x - bx0) * os + 2 * r_sub;
                        let n_y = (y - by0) * os + 2 * r_sub;
                        problem.observe(n_x, n_y, f64::from(cp.plane.get(i, j)));
                        count += 1;
                    }
                }
            }
            Weighting::Uniform => {
                for q_y in 0..=(by1 - by0) * os {
                    let y = by0 as f64 + q_y as f64 / s;
                    for q_x in 0..=(bx1 - bx0) * os {
                        let x = bx0 as f64 + q_x as f64 / s;
                        let [pi, pj] = cp.plane_from_sensor(x, y);
                        if let Some(v) = cp.plane.bilinear(pi, pj) {
                            problem.observe(q_x + 2 * r_sub, q_y + 2 * r_sub, f64::from(v));
                            count += 1;
                        }
                    }
                }
            }
        }
    }
    if count < k_size {
        return Err(KernelFailure::NoObservations(channel));
    }
    let solution = cg_solve(&mut problem, iterations, tolerance);
    let (k, _offset) = solution.x.split_at(k_size * k_size);
    let sum: f64 = k.iter().sum();
    if !(sum.is_finite() && sum > 0.0) {
        return Err(KernelFailure::Empty);
    }
    let kernel = Kernel {
        size: k_size,
        oversample: os,
        data: k.iter().map(|v| v / sum).collect(),
    };
    Ok(RawKernel {
        kernel,
        iterations: solution.iterations,
        residual: solution.relative_residual,
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
    let channels = channels_of(capture);
    let squares: Vec<SquareGeometry> = detection
        .ok_squares()
        .map(|s| SquareGeometry {
            row: s.row,
            col: s.col,
            image_from_chart: s.image_from_chart,
        })
        .collect();
    let units: Vec<(usize, Channel)> = (0..squares.len())
        .flat_map(|i| channels.iter().map(move |&c| (i, c)))
        .collect();
    let total = units.len();
    let done = AtomicUsize::new(0);
    job.report("kernels", 0, total);
    type Estimate = (Channel, Result<KernelEstimate, KernelFailure>);
    let results: Result<Vec<Estimate>, crate::job::Cancelled> = units
        .par_iter()
        .map(|&(i, ch)| {
            job.check()?;
            let r = estimate_square_geometry(capture, &squares[i], spec, params, ch);
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            job.report("kernels", n, total);
            Ok((ch, r))
        })
        .collect();
    let mut results = results?.into_iter();
    let squares = squares
        .iter()
        .map(|sq| SquareKernels {
            row: sq.row,
            col: sq.col,
            centre: square_centre(sq),
            estimates: results.by_ref().take(channels.len()).collect(),
        })
        .collect();
    Ok(ShotKernels {
        width: capture.width,
        height: capture.height,
        oversample: params.oversample,
        squares,
    })
}
