//! The paper's Gaussian-approximation experiment (Fig. 2): blur a natural-statistics
//! image and a hard-edge synthetic one with many non-parametric kernels, deconvolve each
//! with the kernel itself, its robust Gaussian fit and its maximum-likelihood Gaussian,
//! and compare by the SSIM error ratio of Eq. 1, (SSIM_non + 2) / (SSIM_gau + 2).

use crate::deblur::solve::{Deconvolver, Method};
use crate::fft::Fft2;
use crate::gaussian::fit_gaussians;
use crate::job::{Cancelled, JobContext};
use crate::metrics::{SsimParams, ssim_f64};
use crate::plane::{Channel, LensSetting, Plane};
use crate::psf::{Gaussian2, Kernel};
use crate::simulate::lens::{PsfShape, VirtualLens};
use crate::simulate::scene::{blur_varying, dead_leaves, hard_edges};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicUsize, Ordering};

/// One kernel of the experiment with its two Gaussian approximations (pixel-level, in
/// sensor pixels).
#[derive(Clone, Debug, PartialEq)]
pub struct ExperimentKernel {
    pub kernel: Kernel,
    pub robust: Gaussian2,
    pub ml: Gaussian2,
}

/// Pixel-level kernels from the virtual lens in each of its PSF shapes at spread-out
/// positions and settings, with a moments (ML) Gaussian and a least-squares (robust)
/// Gaussian fitted to each: the stand-in for kernels measured on calibration shots.
#[must_use]
pub fn simulated_kernels(count: usize, oversample: usize) -> Vec<ExperimentKernel> {
    let mut lens = VirtualLens::demo();
    let mut rng = Pcg64::seed_from_u64(0x5eed);
    let shapes = [PsfShape::Gaussian, PsfShape::Disc, PsfShape::Comet];
    (0..count)
        .map(|i| {
            lens.shape = shapes[i % shapes.len()];
            let u = rng.random_range(-1.0..1.0);
            let v = rng.random_range(-1.0..1.0);
            let focal_mm = rng.random_range(lens.focal_range_mm[0]..lens.focal_range_mm[1]);
            let f_number = rng.random_range(lens.f_number_range[0]..lens.f_number_range[1]);
            let ch = [Channel::R, Channel::G, Channel::B][i % 3];
            let optical =
                lens.optical_kernel_uv(ch, u, v, LensSetting { focal_mm, f_number }, oversample);
            let kernel = with_pixel_box(&optical);
            let (robust, ml) = fit_gaussians(&kernel);
            ExperimentKernel { kernel, robust, ml }
        })
        .collect()
}

/// Convolves a kernel with the 1-pixel box (pixel integration), at its own oversample.
#[must_use]
pub fn with_pixel_box(k: &Kernel) -> Kernel {
    k.pixel_integrated()
}

/// How [`measured_kernels`] shoots its simulated calibration session.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeasureOptions {
    /// How many kernels to collect.
    pub count: usize,
    /// PSF shape of the virtual lens.
    pub shape: PsfShape,
    pub seed: u64,
    /// Shot size, sensor pixels.
    pub width: usize,
    pub height: usize,
    /// Chart squares across and down.
    pub cols: usize,
    pub rows: usize,
    /// How the kernel estimate weights the up-sampled observation. The paper's kernels
    /// for deblurring, those of its Fig. 2, are estimated with W = I
    /// ([`Weighting::Uniform`](crate::kernel::Weighting::Uniform)), "to account for the
    /// interpolant when deblurring".
    pub weighting: crate::kernel::Weighting,
    /// The f-numbers the shots are taken at (within the lens's range); `None` takes
    /// the lens's whole range.
    pub f_numbers: Option<[f64; 2]>,
}

impl MeasureOptions {
    /// `count` kernels of the demo lens in `shape`, on 640 × 427 shots of a 12 × 8 chart
    /// (squares about 45 px wide), estimated with W = I as the paper's.
    #[must_use]
    pub fn new(count: usize, shape: PsfShape, seed: u64) -> Self {
        Self {
            count,
            shape,
            seed,
            width: 640,
            height: 427,
            cols: 12,
            rows: 8,
            weighting: crate::kernel::Weighting::Uniform,
            f_numbers: None,
        }
    }
}

/// Why kernels could not be measured on the simulated session.
#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
    #[error("simulating shot {shot}: {reason}")]
    Simulate { shot: usize, reason: String },
    #[error("{failed} shots in a row gave no kernel; the last, {last}")]
    NoKernels { failed: usize, last: String },
}

/// Kernels measured on a simulated session, and the shots that gave none.
#[derive(Clone, Debug)]
pub struct MeasuredKernels {
    pub kernels: Vec<ExperimentKernel>,
    /// One line per shot that yielded no kernel (its setting and why).
    pub skipped_shots: Vec<String>,
}

/// Shots in a row that may yield no kernel before the session is abandoned: the odd
/// shot a pose defeats is skipped, but a pipeline that fails on every shot stops the
/// run within seconds instead of shooting on.
pub const MAX_FAILED_SHOTS_IN_A_ROW: usize = 3;

/// The virtual lens an experiment shoots: the demo zoom with `opts`' PSF shape (the
/// aberrated shape is a design of its own, over the demo lens's ranges), its apertures
/// narrowed to `opts.f_numbers` where that range is a range.
fn experiment_lens(opts: &MeasureOptions) -> VirtualLens {
    let mut lens = if opts.shape == PsfShape::Aberrated {
        VirtualLens::aberrated()
    } else {
        VirtualLens::demo()
    };
    lens.shape = opts.shape;
    if let Some([lo, hi]) = opts.f_numbers {
        let [a0, a1] = lens.f_number_range;
        let (lo, hi) = (lo.clamp(a0, a1), hi.clamp(a0, a1));
        // An empty or reversed range keeps the lens's own.
        if lo.is_finite() && hi.is_finite() && lo < hi {
            lens.f_number_range = [lo, hi];
        }
    }
    lens
}

/// Kernels measured the way calibration measures them: simulated chart shots of the
/// virtual lens at settings spread over its range, squares detected and aligned, each
/// square's 3× kernel and robust/ML Gaussians estimated. Squares are taken spread over
/// each shot until `count` kernels are collected.
///
/// # Errors
/// [`MeasureError`]: [`MAX_FAILED_SHOTS_IN_A_ROW`] shots in a row gave no kernel (the
/// last one's reason, with the count), the simulator failed, or cancellation.
pub fn measured_kernels(
    opts: &MeasureOptions,
    job: &JobContext,
) -> Result<MeasuredKernels, MeasureError> {
    use crate::chart::ChartSpec;
    use crate::kernel::{KernelParams, SquareGeometry, estimate_square_geometry};
    use crate::simulate::{CaptureParams, Pose, simulate_shot};
    let count = opts.count;
    let lens = experiment_lens(opts);
    let spec = ChartSpec {
        cols: opts.cols,
        rows: opts.rows,
        ..ChartSpec::default()
    };
    let params = KernelParams {
        weighting: opts.weighting,
        ..KernelParams::default()
    };
    let mut rng = Pcg64::seed_from_u64(opts.seed);
    let mut out: Vec<ExperimentKernel> = Vec::with_capacity(count);
    let mut skipped_shots: Vec<String> = Vec::new();
    let mut failed_in_a_row = 0usize;
    let mut shot = 0usize;
    while out.len() < count {
        job.check()?;
        let setting = LensSetting {
            focal_mm: rng.random_range(lens.focal_range_mm[0]..lens.focal_range_mm[1]),
            f_number: rng.random_range(lens.f_number_range[0]..lens.f_number_range[1]),
        };
        let mut cp = CaptureParams::new(opts.width, opts.height, setting);
        cp.bayer = false;
        cp.seed = opts.seed.wrapping_add(shot as u64);
        cp.pose = Pose {
            rotation_deg: rng.random_range(-1.5..1.5),
            fill: 0.86,
            ..Pose::default()
        };
        shot += 1;
        let mut skip = |reason: String| -> Result<(), MeasureError> {
            let line = format!(
                "shot {shot} (f = {:.1} mm, f/{:.1}): {reason}",
                setting.focal_mm, setting.f_number
            );
            failed_in_a_row += 1;
            if failed_in_a_row >= MAX_FAILED_SHOTS_IN_A_ROW {
                return Err(MeasureError::NoKernels {
                    failed: failed_in_a_row,
                    last: line,
                });
            }
            skipped_shots.push(line);
            Ok(())
        };
        let sim = simulate_shot(&spec, &lens, &cp, job).map_err(|e| MeasureError::Simulate {
            shot,
            reason: e.to_string(),
        })?;
        let det = match crate::detect::detect(
            &sim.capture,
            &spec,
            &crate::detect::DetectParams::default(),
            job,
        ) {
            Ok(d) => d,
            Err(e) => {
                job.check()?;
                skip(format!("detection: {e}"))?;
                continue;
            }
        };
        let squares: Vec<SquareGeometry> = det
            .ok_squares()
            .map(|s| SquareGeometry {
                row: s.row,
                col: s.col,
                image_from_chart: s.image_from_chart,
            })
            .collect();
        if squares.is_empty() {
            skip(format!(
                "detection kept none of {} squares ({})",
                det.squares.len(),
                skip_reasons(det.squares.iter().filter_map(|s| s.reason.as_deref()))
            ))?;
            continue;
        }
        let want = count - out.len();
        // Spread the squares taken over the frame, one channel each in turn.
        let stride = (squares.len() / want.max(1)).max(1);
        let picks: Vec<(usize, Channel)> = squares
            .iter()
            .enumerate()
            .step_by(stride)
            .take(want)
            .map(|(i, _)| (i, [Channel::R, Channel::G, Channel::B][i % 3]))
            .collect();
        let results: Vec<Result<ExperimentKernel, String>> = picks
            .par_iter()
            .map(|&(i, ch)| {
                job.check().map_err(|e| e.to_string())?;
                let e = estimate_square_geometry(&sim.capture, &squares[i], &spec, &params, ch)
                    .map_err(|f| f.to_string())?;
                // The fits are pixel-level (they add the 1/(12 s²) px² of the 3× cells
                // the kernel lacks); compared with the kernel itself they must not.
                let cell = -1.0 / (12.0 * (params.oversample * params.oversample) as f64);
                Ok(ExperimentKernel {
                    kernel: e.kernel,
                    robust: e.fit.robust.convolved_variance(cell, cell, 0.0),
                    ml: e.fit.ml.convolved_variance(cell, cell, 0.0),
                })
            })
            .collect();
        job.check()?;
        let before = out.len();
        let mut failures = Vec::new();
        for r in results {
            match r {
                Ok(k) => out.push(k),
                Err(reason) => failures.push(reason),
            }
        }
        if out.len() == before {
            skip(format!(
                "no kernel from {} aligned squares ({})",
                picks.len(),
                skip_reasons(failures.iter().map(String::as_str))
            ))?;
            continue;
        }
        failed_in_a_row = 0;
        job.report("measuring kernels", out.len().min(count), count);
    }
    out.truncate(count);
    Ok(MeasuredKernels {
        kernels: out,
        skipped_shots,
    })
}

/// The distinct reasons among `reasons`, most frequent first, with their counts.
fn skip_reasons<'a>(reasons: impl Iterator<Item = &'a str>) -> String {
    let mut counts: Vec<(&str, usize)> = Vec::new();
    for r in reasons {
        match counts.iter_mut().find(|(s, _)| *s == r) {
            Some(c) => c.1 += 1,
            None => counts.push((r, 1)),
        }
    }
    counts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
    if counts.is_empty() {
        return "no reason given".into();
    }
    counts
        .iter()
        .take(3)
        .map(|(r, n)| format!("{n}× {r}"))
        .collect::<Vec<_>>()
        .join("; ")
}

/// Experiment settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExperimentOptions {
    /// Side of the square test images in pixels.
    pub image_px: usize,
    /// Standard deviation of the Gaussian noise added to each blurred image.
    pub noise_sigma: f64,
    pub method: Method,
    pub seed: u64,
}

impl Default for ExperimentOptions {
    fn default() -> Self {
        Self {
            image_px: 160,
            noise_sigma: 0.002,
            method: Method::default(),
            seed: 7,
        }
    }
}

/// SSIMs and error ratios of one kernel on one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RatioRow {
    pub image: String,
    pub kernel_index: usize,
    pub robust: Gaussian2,
    pub ml: Gaussian2,
    pub ssim_blurry: f64,
    pub ssim_nonparametric: f64,
    pub ssim_robust: f64,
    pub ssim_ml: f64,
    pub ratio_robust: f64,
    pub ratio_ml: f64,
}

/// Distribution summary of one image's ratios.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RatioSummary {
    pub image: String,
    pub count: usize,
    pub robust_p50: f64,
    pub robust_p99: f64,
    pub robust_max: f64,
    pub ml_p50: f64,
    pub ml_p99: f64,
    pub ml_max: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExperimentReport {
    pub options: ExperimentOptions,
    pub rows: Vec<RatioRow>,
    pub summary: Vec<RatioSummary>,
}

/// The p-quantile (0..=1) of values, by nearest rank on the sorted list.
#[must_use]
pub fn quantile(values: &[f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let idx = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[idx]
}

/// A 1× kernel from a Gaussian, sampled the way the non-parametric kernels are (at
/// their oversample, then resampled), so the comparison differs only in shape.
fn gaussian_kernel_1x(g: &Gaussian2, oversample: usize) -> Kernel {
    g.kernel(oversample).resampled(1)
}

/// Runs the experiment on the natural (dead-leaves) and synthetic (hard-edge) images.
///
/// # Errors
/// On cancellation.
pub fn gaussian_approx(
    kernels: &[ExperimentKernel],
    opts: &ExperimentOptions,
    job: &JobContext,
) -> Result<ExperimentReport, Cancelled> {
    let n = opts.image_px;
    let images = [
        ("natural", dead_leaves(n, n, opts.seed)),
        ("synthetic", hard_edges(n, n, opts.seed + 1)),
    ];
    let fft = Fft2::new(n, n);
    let proto = Deconvolver::new(n, n);
    let total = kernels.len() * images.len();
    let done = AtomicUsize::new(0);
    let params = SsimParams::default();
    let mut rows = Vec::with_capacity(total);
    for (name, img) in &images {
        let sharp: Vec<f64> = img.data.iter().map(|&v| f64::from(v)).collect();
        let part: Vec<RatioRow> = kernels
            .par_iter()
            .enumerate()
            .map_init(
                || (fft.clone(), proto.clone(), vec![0.0; n * n]),
                |(fft, dec, x), (idx, ek)| -> Result<RatioRow, Cancelled> {
                    job.check()?;
                    let k1 = ek.kernel.resampled(1);
                    // The image is periodic here, so a circular blur is the exact model
                    // and the comparison measures only the kernel's shape.
                    let mut blurry = fft.convolve(&sharp, &k1);
                    let mut rng =
                        Pcg64::seed_from_u64(opts.seed ^ (idx as u64).wrapping_mul(0x9e37_79b9));
                    if opts.noise_sigma > 0.0
                        && let Ok(noise) = Normal::new(0.0, opts.noise_sigma)
                    {
                        for v in &mut blurry {
                            *v += noise.sample(&mut rng);
                        }
                    }
                    let s = |x: &[f64]| ssim_f64(x, &sharp, n, n, &params);
                    let mut ssim_with = |k: &Kernel| {
                        dec.deconvolve(&blurry, k, &opts.method, x);
                        s(x)
                    };
                    let sn = ssim_with(&k1);
                    let sr = ssim_with(&gaussian_kernel_1x(&ek.robust, ek.kernel.oversample));
                    let sm = ssim_with(&gaussian_kernel_1x(&ek.ml, ek.kernel.oversample));
                    let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                    job.report("experiment", d, total);
                    Ok(RatioRow {
                        image: (*name).to_owned(),
                        kernel_index: idx,
                        robust: ek.robust,
                        ml: ek.ml,
                        ssim_blurry: s(&blurry),
                        ssim_nonparametric: sn,
                        ssim_robust: sr,
                        ssim_ml: sm,
                        ratio_robust: (sn + 2.0) / (sr + 2.0),
                        ratio_ml: (sn + 2.0) / (sm + 2.0),
                    })
                },
            )
            .collect::<Result<_, _>>()?;
        rows.extend(part);
    }
    let summary = images
        .iter()
        .map(|(name, _)| {
            let rob: Vec<f64> = rows
                .iter()
                .filter(|r| r.image == *name)
                .map(|r| r.ratio_robust)
                .collect();
            let ml: Vec<f64> = rows
                .iter()
                .filter(|r| r.image == *name)
                .map(|r| r.ratio_ml)
                .collect();
            RatioSummary {
                image: (*name).to_owned(),
                count: rob.len(),
                robust_p50: quantile(&rob, 0.5),
                robust_p99: quantile(&rob, 0.99),
                robust_max: quantile(&rob, 1.0),
                ml_p50: quantile(&ml, 0.5),
                ml_p99: quantile(&ml, 0.99),
                ml_max: quantile(&ml, 1.0),
            }
        })
        .collect();
    Ok(ExperimentReport {
        options: *opts,
        rows,
        summary,
    })
}

/// The error-ratio CDFs as CSV: one row per (image, fit) and ratio, sorted, with its
/// cumulative fraction — the curves of the paper's Fig. 2 (bottom).
#[must_use]
pub fn cdf_csv(report: &ExperimentReport) -> String {
    let mut out = String::from("image,fit,ratio,cumulative_fraction\n");
    for s in &report.summary {
        for fit in ["robust", "ml"] {
            let mut v: Vec<f64> = report
                .rows
                .iter()
                .filter(|r| r.image == s.image)
                .map(|r| {
                    if fit == "robust" {
                        r.ratio_robust
                    } else {
                        r.ratio_ml
                    }
                })
                .collect();
            v.sort_by(f64::total_cmp);
            let n = v.len();
            for (i, r) in v.iter().enumerate() {
                out.push_str(&format!(
                    "{},{},{:.6},{:.6}\n",
                    s.image,
                    fit,
                    r,
                    (i + 1) as f64 / n as f64
                ));
            }
        }
    }
    out
}

/// SSIM against the sharp photo of one deblurring comparison: the blurry photo, and
/// HQS with the true kernels, with a profile's predicted Gaussians and with its
/// predicted kernel shapes; whole frame and the mean of its four corner crops.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelModelSsim {
    pub blurry: f64,
    pub truth: f64,
    pub gaussian: f64,
    pub shape: f64,
    pub corners_truth: f64,
    pub corners_gaussian: f64,
    pub corners_shape: f64,
    /// Mean over five crops (the centre and the four corners, each a quarter of the
    /// shorter side) of [blurry, true kernels, Gaussians, shapes]: as they are, and
    /// each crop aligned first ([`crate::metrics::registered_ssim`], within ±1.5 px).
    pub crops: [f64; 4],
    pub crops_registered: [f64; 4],
    /// The largest alignment found over the crops, px, per [blurry, true, Gaussians,
    /// shapes].
    pub largest_shift_px: [f64; 4],
}

/// The five crops the deblurring comparisons score, each `c` px square in a `w × h`
/// frame: the centre, then the four corners.
fn five_crops(w: usize, h: usize, c: usize) -> [(&'static str, usize, usize); 5] {
    [
        ("centre", (w - c) / 2, (h - c) / 2),
        ("top-left", 0, 0),
        ("top-right", w - c, 0),
        ("bottom-left", 0, h - c),
        ("bottom-right", w - c, h - c),
    ]
}

/// Most a crop is moved to align it in [`KernelModelSsim::crops_registered`], px: a
/// lopsided PSF's centroid lies up to about a pixel from its core on these lenses.
const REGISTRATION_REACH_PX: f64 = 1.5;

/// Deblurs a dead-leaves photo seen through `lens` at `setting` (one channel, `w × h`,
/// Gaussian noise of `noise_sigma`) three ways — the lens's true pixel-level kernels,
/// `profile`'s Gaussians, `profile`'s kernel shapes — and scores each by SSIM. The
/// photo is blurred per 8 × 8 block with the true kernel at the block's centre.
///
/// # Errors
/// The profile's prediction errors (no shape model, a setting it refuses) or
/// cancellation, as one line.
#[allow(clippy::too_many_arguments)]
pub fn compare_kernel_models(
    profile: &crate::profile::Profile,
    lens: &VirtualLens,
    channel: Channel,
    setting: LensSetting,
    (w, h): (usize, usize),
    seed: u64,
    noise_sigma: f64,
    job: &JobContext,
) -> Result<KernelModelSsim, String> {
    use crate::deblur::{DeblurOptions, deblur_channel_plane, plane_kernel};
    use crate::plane::ChannelPlane;
    let true_kernel = |x: f64, y: f64| {
        let (u, v) = VirtualLens::normalised(x, y, w, h);
        lens.optical_kernel_uv(channel, u, v, setting, 3)
            .pixel_integrated()
    };
    let pad = [
        (0.0, 0.0),
        ((w - 1) as f64, 0.0),
        (0.0, (h - 1) as f64),
        ((w - 1) as f64, (h - 1) as f64),
    ]
    .iter()
    .map(|&(x, y)| plane_kernel(&true_kernel(x, y), 1).size / 2)
    .max()
    .unwrap_or(0)
        + 4;
    let big = dead_leaves(w + 2 * pad, h + 2 * pad, seed);
    let sharp = big.crop(pad, pad, w, h);
    let mut blurry = blur_varying(&big, pad, w, h, 8, &|x, y| {
        plane_kernel(&true_kernel(x, y), 1)
    });
    drop(big);
    if noise_sigma > 0.0
        && let Ok(noise) = Normal::new(0.0, noise_sigma)
    {
        let mut rng = Pcg64::seed_from_u64(seed ^ 0x51a9);
        for v in &mut blurry.data {
            *v += noise.sample(&mut rng) as f32;
        }
    }
    let cp = ChannelPlane {
        channel,
        plane: blurry,
        step: 1,
        offset_x: 0,
        offset_y: 0,
    };
    let hqs = DeblurOptions::default();
    let run = |source: &dyn crate::deblur::KernelSource| {
        deblur_channel_plane(&cp, w, h, source, &hqs, job).map_err(|e| e.to_string())
    };
    let truth_source = |_c: Channel, x: f64, y: f64| true_kernel(x, y);
    let [x_true, x_gauss, x_shape] = three_ways(profile, setting, &truth_source, run)?;
    let params = SsimParams::default();
    let s = |x: &Plane| crate::metrics::ssim(x, &sharp, &params);
    let c = (w.min(h) / 4).max(16);
    let five = five_crops(w, h, c);
    let corners = |x: &Plane| {
        five[1..]
            .iter()
            .map(|&(_, x0, y0)| {
                crate::metrics::ssim(&x.crop(x0, y0, c, c), &sharp.crop(x0, y0, c, c), &params)
            })
            .sum::<f64>()
            / 4.0
    };
    let (mut crops, mut crops_registered, mut largest_shift_px) = ([0.0; 4], [0.0; 4], [0.0; 4]);
    for (i, x) in [&cp.plane, &x_true, &x_gauss, &x_shape]
        .into_iter()
        .enumerate()
    {
        for &(_, x0, y0) in &five {
            let r = crate::metrics::registered_ssim(
                &[x],
                &[&sharp],
                (x0, y0),
                (c, c),
                REGISTRATION_REACH_PX,
                &params,
            );
            crops[i] += r.unmoved / five.len() as f64;
            crops_registered[i] += r.ssim / five.len() as f64;
            largest_shift_px[i] = f64::max(largest_shift_px[i], r.shift_px[0].hypot(r.shift_px[1]));
        }
    }
    Ok(KernelModelSsim {
        blurry: s(&cp.plane),
        truth: s(&x_true),
        gaussian: s(&x_gauss),
        shape: s(&x_shape),
        corners_truth: corners(&x_true),
        corners_gaussian: corners(&x_gauss),
        corners_shape: corners(&x_shape),
        crops,
        crops_registered,
        largest_shift_px,
    })
}

/// One crop's figures in [`compare_colour`], each for the blurry photo and HQS with the
/// true kernels, the profile's Gaussians and its kernel shapes: the deconvolution alone,
/// and as a user gets it, each deblur's chroma held inside the blurry photo's
/// ([`Fringes::Suppress`], the default; the blurry photo's figures are the same in
/// both).
///
/// [`Fringes::Suppress`]: crate::deblur::Fringes::Suppress
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CropColour {
    /// "centre", "top-left", "top-right", "bottom-left", "bottom-right".
    pub name: String,
    pub alone: CropScores,
    pub held: CropScores,
}

/// A crop's colour error at edges ([`crate::metrics::edge_colour_error`], strongest
/// 10 %) and SSIM (mean over R, G, B) against the sharp photo, each
/// [blurry, true kernels, Gaussians, shapes].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CropScores {
    pub colour: [f64; 4],
    pub ssim: [f64; 4],
    /// SSIM with the crop's three channels first moved together by the translation that
    /// best aligns them ([`crate::metrics::registered_ssim`]).
    pub ssim_registered: [f64; 4],
}

impl CropScores {
    fn new(s: [(f64, f64, f64); 4]) -> Self {
        Self {
            colour: s.map(|v| v.0),
            ssim: s.map(|v| v.1),
            ssim_registered: s.map(|v| v.2),
        }
    }
}

/// Blurs an RGB photo through `lens` at `setting` (its true pixel-level kernels per
/// channel, lateral colour included, per 8 × 8 block; Gaussian noise of `noise_sigma`)
/// and deblurs each channel with HQS three ways — the true kernels, `profile`'s
/// Gaussians, `profile`'s kernel shapes — scoring five crops (the centre and the four
/// corners, each a quarter of the shorter side): where a kernel model moves the
/// channels against each other, the colour error at edges shows it as a fringe.
/// `sharp` is the photo `w + 2·pad` × `h + 2·pad`; the scored frame is its centre.
///
/// # Errors
/// A `pad` narrower than the widest true kernel, the profile's prediction errors, or
/// cancellation, as one line.
#[allow(clippy::too_many_arguments)]
pub fn compare_colour(
    profile: &crate::profile::Profile,
    lens: &VirtualLens,
    setting: LensSetting,
    sharp: &[Plane; 3],
    pad: usize,
    (w, h): (usize, usize),
    seed: u64,
    noise_sigma: f64,
    job: &JobContext,
) -> Result<Vec<CropColour>, String> {
    use crate::deblur::{DeblurOptions, deblur_channel_plane, plane_kernel};
    use crate::plane::ChannelPlane;
    const RGB: [Channel; 3] = [Channel::R, Channel::G, Channel::B];
    let true_kernel = |ch: Channel, x: f64, y: f64| lens.pixel_kernel_at(ch, x, y, (w, h), setting);
    let widest = RGB
        .iter()
        .flat_map(|&ch| {
            [
                (0.0, 0.0),
                ((w - 1) as f64, 0.0),
                (0.0, (h - 1) as f64),
                ((w - 1) as f64, (h - 1) as f64),
            ]
            .map(|(x, y)| plane_kernel(&true_kernel(ch, x, y), 1).size / 2)
        })
        .max()
        .unwrap_or(0);
    if widest > pad
        || sharp
            .iter()
            .any(|p| p.width != w + 2 * pad || p.height != h + 2 * pad)
    {
        return Err(format!(
            "the sharp photo must be {} × {} (pad {pad} ≥ the widest kernel's {widest})",
            w + 2 * pad,
            h + 2 * pad
        ));
    }
    let planes: Vec<ChannelPlane> = RGB
        .iter()
        .zip(sharp)
        .enumerate()
        .map(|(i, (&ch, big))| {
            let mut blurry = blur_varying(big, pad, w, h, 8, &|x, y| {
                plane_kernel(&true_kernel(ch, x, y), 1)
            });
            if noise_sigma > 0.0
                && let Ok(noise) = Normal::new(0.0, noise_sigma)
            {
                let mut rng = Pcg64::seed_from_u64(seed ^ 0x51a9 ^ ((i as u64) << 32));
                for v in &mut blurry.data {
                    *v += noise.sample(&mut rng) as f32;
                }
            }
            ChannelPlane {
                channel: ch,
                plane: blurry,
                step: 1,
                offset_x: 0,
                offset_y: 0,
            }
        })
        .collect();
    let truth: Vec<Plane> = sharp.iter().map(|p| p.crop(pad, pad, w, h)).collect();
    let hqs = DeblurOptions::default();
    let run = |source: &dyn crate::deblur::KernelSource| -> Result<Vec<Plane>, String> {
        planes
            .iter()
            .map(|cp| deblur_channel_plane(cp, w, h, source, &hqs, job).map_err(|e| e.to_string()))
            .collect()
    };
    let [x_true, x_gauss, x_shape] = three_ways(profile, setting, &true_kernel, run)?;
    let blurry: Vec<Plane> = planes.into_iter().map(|cp| cp.plane).collect();
    let hold = |x: &[Plane]| -> Vec<Plane> {
        use crate::deblur::chroma::{CHROMA_WINDOW_RADIUS, clamp_chroma};
        let mut out = x.to_vec();
        if let ([r, g, b], [ri, gi, bi]) = (out.as_mut_slice(), blurry.as_slice()) {
            clamp_chroma([ri, gi, bi], [r, g, b], CHROMA_WINDOW_RADIUS);
        }
        out
    };
    let held = [hold(&x_true), hold(&x_gauss), hold(&x_shape)];
    let c = (w.min(h) / 4).max(16);
    let crops = five_crops(w, h, c);
    let params = SsimParams::default();
    Ok(crops
        .iter()
        .map(|&(name, x0, y0)| {
            let cut =
                |p: &[Plane]| -> [Plane; 3] { std::array::from_fn(|i| p[i].crop(x0, y0, c, c)) };
            let t = cut(&truth);
            let score = |p: &[Plane]| {
                let x = cut(p);
                let colour = crate::metrics::edge_colour_error(
                    [&x[0], &x[1], &x[2]],
                    [&t[0], &t[1], &t[2]],
                    0.1,
                );
                let registered = crate::metrics::registered_ssim(
                    &[&p[0], &p[1], &p[2]],
                    &[&truth[0], &truth[1], &truth[2]],
                    (x0, y0),
                    (c, c),
                    REGISTRATION_REACH_PX,
                    &params,
                );
                (colour, registered.unmoved, registered.ssim)
            };
            let s = [
                score(&blurry),
                score(&x_true),
                score(&x_gauss),
                score(&x_shape),
            ];
            CropColour {
                name: name.into(),
                alone: CropScores::new(s),
                held: CropScores::new([s[0], score(&held[0]), score(&held[1]), score(&held[2])]),
            }
        })
        .collect())
}

/// `run` (a deblur) with the true kernels, the profile's Gaussians and its shapes, in
/// that order: the comparison every kernel-model experiment makes.
fn three_ways<T>(
    profile: &crate::profile::Profile,
    setting: LensSetting,
    truth: &dyn crate::deblur::KernelSource,
    run: impl Fn(&dyn crate::deblur::KernelSource) -> Result<T, String>,
) -> Result<[T; 3], String> {
    use crate::deblur::ProfileKernels;
    use crate::model::KernelModel;
    let model =
        |m| ProfileKernels::with_model(profile.clone(), setting, m).map_err(|e| e.to_string());
    // The third way is what the profile deblurs with: its shapes, or its Gaussians
    // where cross-validation kept no shape model.
    Ok([
        run(truth)?,
        run(&model(KernelModel::Gaussian)?)?,
        run(&model(profile.kernel_model())?)?,
    ])
}
