//! Kernels: a profile's predicted kernels at sensor points and their error against
//! measured ones, the noisy-kernel criterion (a measured kernel's tails), and the
//! numbers behind one aligned square.

use crate::detect::SquareAlignment;
use crate::kernel::file::KernelsFile;
use crate::model::{KernelModel, LateralColour, relative_l2};
use crate::plane::{Channel, LensSetting, bilinear_zero_outside};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Kernel};

/// One kernel a profile predicts: its sensor position, the Gaussian it is built
/// around and the 3× kernel itself.
#[derive(Clone, Debug)]
pub struct PredictedKernel {
    pub x: f64,
    pub y: f64,
    pub gaussian: Gaussian2,
    pub kernel: Kernel,
}

/// A profile's predicted kernels in `model` at sensor `points` and `setting`, so the
/// studio can lay them beside the measured ones cell for cell.
///
/// # Errors
/// The profile cannot predict at some point (channel or setting outside it, or no
/// shape model for [`KernelModel::Shape`]): the first failure, one line.
pub fn predicted_kernels(
    profile: &Profile,
    model: KernelModel,
    channel: Channel,
    points: &[[f64; 2]],
    setting: LensSetting,
) -> Result<Vec<PredictedKernel>, String> {
    points
        .iter()
        .map(|&[x, y]| {
            let gaussian = profile
                .predict(channel, x, y, setting)
                .map_err(|e| e.to_string())?;
            let kernel = profile
                .predict_kernel(model, LateralColour::Correct, channel, x, y, setting)
                .map_err(|e| e.to_string())?;
            Ok(PredictedKernel {
                x,
                y,
                gaussian,
                kernel,
            })
        })
        .collect()
}

/// How far a profile's predictions miss one measured kernel: relative L2 of the
/// predicted kernel against the measured one, for the Gaussian alone and, where the
/// profile holds a shape model, for the Gaussian with its predicted shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelError {
    pub gaussian: f64,
    pub shape: Option<f64>,
}

/// Per sample of a shot's kernels file (in the file's order), the error of `profile`'s
/// predicted kernels against the measured kernel at the shot's setting; `None` where
/// the sample is of another channel, holds no kernel array, or the profile cannot
/// predict there (the file names no setting, or one outside the profile).
#[must_use]
pub fn kernel_errors(
    profile: &Profile,
    file: &KernelsFile,
    channel: Channel,
) -> Vec<Option<KernelError>> {
    let setting = match (file.focal_mm, file.f_number) {
        (Some(focal_mm), Some(f_number)) => Some(LensSetting { focal_mm, f_number }),
        _ => None,
    };
    file.samples
        .iter()
        .map(|s| {
            let setting = setting?;
            if s.channel != channel {
                return None;
            }
            let measured = s.kernel_at(file.oversample)?;
            let error = |model| {
                profile
                    .predict_kernel(model, LateralColour::Keep, channel, s.x, s.y, setting)
                    .ok()
                    .map(|k| relative_l2(&k, &measured))
            };
            Some(KernelError {
                gaussian: error(KernelModel::Gaussian)?,
                shape: profile
                    .shape
                    .is_some()
                    .then(|| error(KernelModel::Shape))
                    .flatten(),
            })
        })
        .collect()
}

/// Why a profile holds no kernel-shape model, in a few words; `None` where it holds
/// one.
#[must_use]
pub fn no_shape_reason(profile: &Profile) -> Option<String> {
    if profile.shape.is_some() {
        return None;
    }
    Some(match &profile.shape_cv {
        Some(cv) => match &cv.best_shape {
            Some(best) => format!(
                "cross-validation kept the Gaussians (held-out {} for the Gaussian, {} for the best shapes)",
                cv.criterion.describe(&cv.gaussian),
                cv.criterion.describe(best)
            ),
            None => "cross-validation kept the Gaussians (no shape model could be fitted)".into(),
        },
        None => "the profile holds no shape cross-validation (calibrated without measured kernels, or written before shape models)".into(),
    })
}

/// The numbers the inspector shows for one aligned square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SquareFacts {
    /// The square's centre through its refined homography, sensor px.
    pub centre: [f64; 2],
    /// How far refinement moved the bootstrap corners (the largest of the four), px.
    pub corner_shift_px: f64,
    /// Side lengths of the refined square (mean of opposite sides), px.
    pub side_px: [f64; 2],
}

#[must_use]
pub fn square_facts(sq: &SquareAlignment) -> SquareFacts {
    let centre = crate::kernel::square_centre(&crate::kernel::SquareGeometry {
        row: sq.row,
        col: sq.col,
        image_from_chart: sq.image_from_chart,
    });
    let dist = |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    let corner_shift_px = sq
        .corners
        .iter()
        .zip(&sq.bootstrap_corners)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max);
    let c = &sq.corners;
    let side_px = [
        0.5 * (dist(c[0], c[1]) + dist(c[3], c[2])),
        0.5 * (dist(c[0], c[3]) + dist(c[1], c[2])),
    ];
    SquareFacts {
        centre,
        corner_shift_px,
        side_px,
    }
}

/// Why a detection skipped squares: each reason with how many squares it covers, most
/// frequent first.
#[must_use]
pub fn skip_reasons(det: &crate::detect::Detection) -> Vec<(String, usize)> {
    let mut counts: std::collections::BTreeMap<String, usize> = std::collections::BTreeMap::new();
    for sq in det
        .squares
        .iter()
        .filter(|s| s.status != crate::detect::SquareStatus::Ok)
    {
        let reason = sq
            .reason
            .clone()
            .unwrap_or_else(|| "no reason given".into());
        *counts.entry(reason).or_default() += 1;
    }
    let mut out: Vec<(String, usize)> = counts.into_iter().collect();
    out.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    out
}

/// Largest rise of a measured kernel's tails (a fraction of its weight) before the
/// studio marks the kernel as a noisy estimate.
///
/// Criterion ([`kernel_tails`]): seen at the sensor's resolution (the kernel averaged
/// over a 1-px box), walk outwards from the kernel's core (the centroid of its samples
/// at or above half the peak) along rays, and add up every rise — how much each sample
/// outside the 3σ ellipse of the kernel's robust Gaussian fit exceeds the sample one px
/// nearer the core — as a fraction of the kernel's weight Σ|k|. A lens's blur falls
/// off away from its core: a Gaussian, a defocus disc, a comet's tail and a diffraction
/// halo all do, however much weight they carry out there (the aberrated lens keeps up to
/// 30 % of its weight outside 3σ). Stripes and speckle rise and fall, and every rise
/// counts.
///
/// Why 0.06, on the simulator (`clean_simulated_kernels_pass_and_striped_tails_are_flagged`:
/// 16 true kernels per shape over the field and the settings' corners, on a measured
/// kernel's support, cleaned as the measurement cleans them):
/// - every shape's true kernels rise by 0.0000, and by at most 0.0030 with the
///   simulator's measured-kernel noise (1 % of the peak per sample);
/// - the measured chain itself (simulated 1200 × 800 shots of the 24 × 16 chart at
///   24 mm and 105 mm, f/4; detected and measured, 2 × 1152 kernels) leaves speckle in
///   the tails: median 0.024, 95th percentile 0.043 and 0.038, largest 0.0625 and
///   0.0775; 3 of the 2304 lie above 0.06;
/// - the true Gaussian kernels with stripes of 10 % of the peak, 2 px apart, beyond
///   2σ rise by 0.062 to 0.18 (5 % stripes: 0.044 to 0.19).
///
/// So a flag means the estimate is worse than the measurement's own speckle on a clean
/// shot, as badly as visibly striped tails.
pub const NOISY_TAIL_FRACTION: f64 = 0.06;

/// What the noisy-kernel criterion measures of one kernel (see
/// [`NOISY_TAIL_FRACTION`]): fractions of its absolute weight Σ|k|.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelTails {
    /// Outside the 3σ ellipse of the fit.
    pub outside: f64,
    /// How much the kernel rises outside that ellipse, walking outwards from its core:
    /// Σ max(0, k(p) − k(p′)) over the samples p outside, with p′ one sample nearer the
    /// core along the ray through p. A lens's blur falls off away from its core (a
    /// halo, a comet's tail, a disc's edge all do); stripes and speckle rise and fall.
    pub rising: f64,
}

/// The kernel averaged over a 1-px box (`oversample` samples a side, rounded up to odd),
/// zero outside.
fn box_1px(kernel: &Kernel) -> Vec<f64> {
    let n = kernel.size;
    let r = (kernel.oversample / 2) as isize;
    let pass = |src: &[f64], along_x: bool| -> Vec<f64> {
        let mut out = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let mut acc = 0.0;
                for d in -r..=r {
                    let (ii, jj) = if along_x {
                        (i as isize + d, j as isize)
                    } else {
                        (i as isize, j as isize + d)
                    };
                    if ii >= 0 && jj >= 0 && (ii as usize) < n && (jj as usize) < n {
                        acc += src[jj as usize * n + ii as usize];
                    }
                }
                out[j * n + i] = acc / (2 * r + 1) as f64;
            }
        }
        out
    };
    pass(&pass(&kernel.data, true), false)
}

/// The tails of `kernel` against the 3σ ellipse of `fit` (see [`NOISY_TAIL_FRACTION`]);
/// `None` for an empty kernel or a degenerate fit.
#[must_use]
pub fn kernel_tails(kernel: &Kernel, fit: &Gaussian2) -> Option<KernelTails> {
    let (vx, vy, cxy) = (
        fit.sigma_x * fit.sigma_x,
        fit.sigma_y * fit.sigma_y,
        fit.cov_xy(),
    );
    let det = vx * vy - cxy * cxy;
    let n = kernel.size;
    if !(det.is_finite() && det > 0.0)
        || n == 0
        || kernel.oversample == 0
        || kernel.data.len() != n * n
    {
        return None;
    }
    let c = (n / 2) as f64;
    let os = kernel.oversample as f64;
    let peak = kernel.data.iter().copied().fold(0.0, f64::max);
    if peak <= 0.0 {
        return None;
    }
    // The core's centroid: the tails themselves must not move the ellipse they are
    // measured against.
    let (mut w0, mut mx, mut my) = (0.0, 0.0, 0.0);
    for j in 0..n {
        for i in 0..n {
            let v = kernel.at(i, j);
            if v >= 0.5 * peak {
                w0 += v;
                mx += v * (i as f64 - c) / os;
                my += v * (j as f64 - c) / os;
            }
        }
    }
    let (mx, my) = (mx / w0, my / w0);
    // Seen at the sensor's resolution (a 1-px box): sample noise averages down, while
    // stripes the sensor resolves (2 px apart or more) stay.
    let smooth = box_1px(kernel);
    let (mut total, mut outside, mut rising) = (0.0, 0.0, 0.0);
    for j in 0..n {
        for i in 0..n {
            let v = kernel.at(i, j);
            let (dx, dy) = ((i as f64 - c) / os - mx, (j as f64 - c) / os - my);
            let d2 = (vy * dx * dx - 2.0 * cxy * dx * dy + vx * dy * dy) / det;
            total += v.abs();
            if d2 > 9.0 {
                outside += v.abs();
                // One px nearer the core along the ray (bilinear between samples).
                let r = dx.hypot(dy);
                let (u, w) = (i as f64 - dx / r * os, j as f64 - dy / r * os);
                let inward = bilinear_zero_outside(&smooth, n, u, w);
                rising += (smooth[j * n + i] - inward).max(0.0);
            }
        }
    }
    (total > 0.0).then(|| KernelTails {
        outside: outside / total,
        rising: rising / total,
    })
}

/// The fraction the criterion compares with [`NOISY_TAIL_FRACTION`].
#[must_use]
pub fn kernel_tail_fraction(kernel: &Kernel, fit: &Gaussian2) -> Option<f64> {
    kernel_tails(kernel, fit).map(|t| t.rising)
}

/// Why a measured kernel is not to be trusted, in one line, or `None` where it passes
/// (see [`NOISY_TAIL_FRACTION`]).
#[must_use]
pub fn noisy_kernel_reason(kernel: &Kernel, fit: &Gaussian2) -> Option<String> {
    let t = kernel_tail_fraction(kernel, fit)?;
    (t > NOISY_TAIL_FRACTION).then(|| {
        format!(
            "noisy estimate: its tails beyond 3σ rise again by {:.1} % of its weight (a lens's blur only falls off there; flagged above {:.1} %): stripes or speckle, not the lens",
            100.0 * t,
            100.0 * NOISY_TAIL_FRACTION
        )
    })
}
