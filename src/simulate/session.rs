//! A calibration session measured directly from a virtual lens's truth: the samples
//! simulate → detect → kernels → Gaussians would give, with measurement error shaped
//! like that chain's, in seconds instead of hours. Tests and benchmarks of the models,
//! cross-validation and profiles stand on it.

use super::lens::VirtualLens;
use crate::model::{BlurSample, Dataset, ShotInfo};
use crate::plane::{CameraIdentity, Channel, LensSetting};
use crate::psf::Gaussian2;

/// Measurement error of simulated samples, shaped like that of the measured chain
/// (simulated shots → detection → kernels → robust Gaussians), whose errors against the
/// truth are about 0.5–1 % median and 2–3 % at the 95th percentile on σ, and 0.003–0.006
/// median on ρ. Every default here is at or above the top of those figures:
/// - independent errors per square and channel: relative on σ (std `sigma_rel`),
///   absolute on ρ (std `rho_abs`);
/// - a heavier tail: a fraction `outlier_fraction` of samples (squares with a poor
///   fit) has `outlier_scale`× larger errors;
/// - per shot, a smooth error field over the sensor (a constant plus a tilt, random per
///   shot): what a refocus between shots, a chart that is not quite flat or one shot's
///   registration does. On σ it is relative and shared by both axes and every channel
///   (RMS `shot_sigma_rel` over the sensor); on ρ it is absolute and per channel (RMS
///   `shot_rho_abs`). Cross-validation holds out whole shots, so it sees this error as
///   a real calibration would;
/// - systematic estimator bias, the same in every shot: a relative σ error
///   `sigma_bias_per_px · (σ − 1.2 px)` (small kernels come out too wide, large ones too
///   narrow) and ρ shrunk toward 0 by `rho_shrink`. Kernels measured from small
///   simulated shots (600 × 400, 12 × 8 chart) show about −6 %/px and 9 %; the improved
///   estimator's medians above bound them near the defaults. No cross-validation can
///   see this error and it cancels in test errors against measured values; only the
///   error against the truth shows it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleNoise {
    pub sigma_rel: f64,
    pub rho_abs: f64,
    pub outlier_fraction: f64,
    pub outlier_scale: f64,
    pub shot_sigma_rel: f64,
    pub shot_rho_abs: f64,
    pub sigma_bias_per_px: f64,
    pub rho_shrink: f64,
}

impl SampleNoise {
    /// Exact samples: the truth itself.
    #[must_use]
    pub fn none() -> Self {
        Self {
            sigma_rel: 0.0,
            rho_abs: 0.0,
            outlier_fraction: 0.0,
            outlier_scale: 1.0,
            shot_sigma_rel: 0.0,
            shot_rho_abs: 0.0,
            sigma_bias_per_px: 0.0,
            rho_shrink: 0.0,
        }
    }
}

impl Default for SampleNoise {
    /// σ: 1.5 % independent, 1 % per shot, a bias of −1.5 %/px; ρ: 0.008 independent,
    /// 0.004 per shot, 2 % shrinkage; 2 % of samples with 4× errors. Together: σ about
    /// 1.2 % median and 3.5 % p95 of |error|, ρ about 0.007 median (a test checks).
    fn default() -> Self {
        Self {
            sigma_rel: 0.015,
            rho_abs: 0.008,
            outlier_fraction: 0.02,
            outlier_scale: 4.0,
            shot_sigma_rel: 0.01,
            shot_rho_abs: 0.004,
            sigma_bias_per_px: -0.015,
            rho_shrink: 0.02,
        }
    }
}

/// A calibration session measured directly from a virtual lens's truth, standing in for
/// simulate → detect → kernels → Gaussians in tests and benchmarks (seconds instead of
/// hours): a `cols × rows` chart whose checkerboard spans `fill` of the sensor width,
/// posed per shot with random shift and rotation; at the centre of every square wholly
/// inside the frame, the pixel-level Gaussian (optical ∗ pixel box) of each of R, G, B
/// plus [`SampleNoise`].
#[derive(Clone, Debug, PartialEq)]
pub struct SimulatedSession {
    pub width: usize,
    pub height: usize,
    pub cols: usize,
    pub rows: usize,
    /// Fraction of the sensor width the checkerboard spans (the demo shots use 0.86).
    pub fill: f64,
    /// Per-shot pose jitter: uniform in ±`shift_px` per axis and ±`rotation_rad`.
    pub shift_px: f64,
    pub rotation_rad: f64,
    /// Measure every other square only, as the paper did.
    pub alternate_squares: bool,
    pub shots_per_setting: usize,
    pub noise: SampleNoise,
    pub seed: u64,
    /// Keep a measured kernel with every sample: the lens's pixel-level kernel at 3×
    /// (its optical PSF in the lens's own shape, integrated over the pixel, moved by
    /// its lateral colour as one registration for all channels measures it) plus white
    /// noise of this standard deviation relative to the kernel's peak, clipped at zero
    /// and renormalised as the estimator's constraints do; each sample's Gaussian is
    /// then the robust fit of that kernel, as the measured chain's is (and
    /// [`SampleNoise`] is not used). `None`: Gaussians only.
    pub kernel_noise: Option<f64>,
}

impl SimulatedSession {
    /// The default 24 × 16 chart at the demo's framing, one shot per setting, realistic
    /// noise.
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            cols: 24,
            rows: 16,
            fill: 0.86,
            shift_px: 0.01 * width as f64,
            rotation_rad: 0.02,
            alternate_squares: false,
            shots_per_setting: 1,
            noise: SampleNoise::default(),
            seed: 1,
            kernel_noise: None,
        }
    }

    /// The session's samples at `settings` (each shot `shots_per_setting` times).
    #[must_use]
    pub fn dataset(&self, lens: &VirtualLens, settings: &[LensSetting]) -> Dataset {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(self.seed);
        let identity = CameraIdentity {
            make: Some(lens.make.clone()),
            model: Some(lens.model.clone()),
            body_serial: None,
            lens_model: Some(lens.model.clone()),
            lens_serial: Some(lens.serial.clone()),
        };
        let (w, h) = (self.width as f64, self.height as f64);
        let mut ds = Dataset::new(self.width, self.height, identity);
        // The Gaussians a RAW session's CFA planes give.
        ds.picture = Some(crate::plane::PictureKind::Raw);
        let square_px = self.fill * w / self.cols as f64;
        let (cx, cy) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
        let noise = &self.noise;
        for (si, &setting) in settings.iter().enumerate() {
            for rep in 0..self.shots_per_setting {
                let dx = self.shift_px * (2.0 * rng.random::<f64>() - 1.0);
                let dy = self.shift_px * (2.0 * rng.random::<f64>() - 1.0);
                let th = self.rotation_rad * (2.0 * rng.random::<f64>() - 1.0);
                let mut n = || standard_normal(&mut rng);
                // A smooth field c0 + c1 u + c2 v has RMS √(c0² + (c1² + c2²)/3) over
                // the sensor; these spreads make its expected square `rms²`.
                let mut field = |rms: f64| {
                    [
                        rms * std::f64::consts::FRAC_1_SQRT_2 * n(),
                        rms * 0.75f64.sqrt() * n(),
                        rms * 0.75f64.sqrt() * n(),
                    ]
                };
                let shot_sigma = field(noise.shot_sigma_rel);
                let shot_rho = [
                    field(noise.shot_rho_abs),
                    field(noise.shot_rho_abs),
                    field(noise.shot_rho_abs),
                ];
                let at = |c: &[f64; 3], u: f64, v: f64| c[0] + c[1] * u + c[2] * v;
                let (s, c) = th.sin_cos();
                let mut samples = Vec::new();
                for r in 0..self.rows {
                    for q in 0..self.cols {
                        if self.alternate_squares && (r + q) % 2 == 1 {
                            continue;
                        }
                        let px = (q as f64 + 0.5 - self.cols as f64 / 2.0) * square_px;
                        let py = (r as f64 + 0.5 - self.rows as f64 / 2.0) * square_px;
                        let x = cx + c * px - s * py + dx;
                        let y = cy + s * px + c * py + dy;
                        let half = 0.5 * square_px;
                        if x < half || y < half || x > w - 1.0 - half || y > h - 1.0 - half {
                            continue;
                        }
                        let (u, v) = (2.0 * x / (w - 1.0) - 1.0, 2.0 * y / (h - 1.0) - 1.0);
                        for (k, ch) in [Channel::R, Channel::G, Channel::B].into_iter().enumerate()
                        {
                            let g = lens
                                .gaussian_at(ch, x, y, self.width, self.height, setting)
                                .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
                            let scale = if rng.random::<f64>() < noise.outlier_fraction {
                                noise.outlier_scale
                            } else {
                                1.0
                            };
                            let mut n = || scale * standard_normal(&mut rng);
                            let common = at(&shot_sigma, u, v);
                            let bias = |sigma: f64| noise.sigma_bias_per_px * (sigma - 1.2);
                            let gaussian = Gaussian2 {
                                sigma_x: g.sigma_x
                                    * (1.0 + bias(g.sigma_x) + common + noise.sigma_rel * n()),
                                sigma_y: g.sigma_y
                                    * (1.0 + bias(g.sigma_y) + common + noise.sigma_rel * n()),
                                rho: (g.rho * (1.0 - noise.rho_shrink)
                                    + at(&shot_rho[k], u, v)
                                    + noise.rho_abs * n())
                                .clamp(-0.99, 0.99),
                            };
                            samples.push(BlurSample {
                                shot: 0,
                                x,
                                y,
                                square: Some([r, q]),
                                focal_mm: 0.0,
                                f_number: 0.0,
                                channel: ch,
                                gaussian,
                                kernel: None,
                            });
                        }
                    }
                }
                ds.push_shot(
                    ShotInfo {
                        name: format!("sim-{si:02}-{rep}"),
                        focal_mm: setting.focal_mm,
                        f_number: setting.f_number,
                        focus_distance_m: None,
                    },
                    samples,
                );
            }
        }
        if let Some(level) = self.kernel_noise {
            self.measure_kernels(&mut ds, lens, level);
        }
        ds
    }

    /// Replaces every sample's Gaussian by the robust fit of its noisy true kernel,
    /// which it keeps (see [`SimulatedSession::kernel_noise`]).
    fn measure_kernels(&self, ds: &mut Dataset, lens: &VirtualLens, level: f64) {
        use rand::SeedableRng;
        use rayon::prelude::*;
        let (w, h) = (self.width, self.height);
        let seed = self.seed;
        ds.samples.par_iter_mut().enumerate().for_each(|(i, s)| {
            // Lateral colour moves red's and blue's kernels off the square's centre,
            // which one registration for all channels puts at green's.
            let mut k = lens.pixel_kernel_at(s.channel, s.x, s.y, (w, h), s.setting());
            let mut rng = rand_pcg::Pcg64::seed_from_u64(
                seed ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
            );
            let peak = k.data.iter().copied().fold(0.0, f64::max);
            if level > 0.0 {
                for value in &mut k.data {
                    *value = (*value + level * peak * standard_normal(&mut rng)).max(0.0);
                }
                k.normalise();
            }
            s.gaussian = crate::gaussian::fit_gaussians(&k).0;
            s.kernel = Some(std::sync::Arc::new(k));
        });
    }
}

/// One draw of N(0, 1).
fn standard_normal(rng: &mut impl rand::Rng) -> f64 {
    rng.sample(rand_distr::StandardNormal)
}
