//! Robust 2-D Gaussian fits to non-parametric kernels (paper §2.3).
//!
//! The kernel is thresholded, its 8-connected regions labelled and the central one kept,
//! so isolated noise blobs far from the PSF cannot drag the fit. Maximum-likelihood
//! moments of that region give the ML Gaussian; Levenberg–Marquardt then minimises the
//! SSD between the region and a sampled Gaussian (σx, σy, ρ, mean, amplitude), which is
//! the robust fit. The ML moments of a thresholded kernel miss its tails, so the two
//! differ most for heavy-tailed or non-Gaussian PSFs.

use crate::psf::{Gaussian2, Kernel};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{Dyn, OMatrix, OVector, U6, Vector6};

/// How a kernel is fitted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitParams {
    /// Samples below this fraction of the kernel's peak are background for labelling.
    pub threshold: f64,
    /// Variance (px², per axis) added to both fits before they are reported: the
    /// estimator's kernel misses the 1/(12 s²) of the sub-pixel cells its sharp image was
    /// integrated over, and the pipeline reports the pixel-level PSF.
    pub add_variance_px2: f64,
}

/// Samples below this fraction of a kernel's peak are noise to the kernel estimator (it
/// zeroes them) and background to everything that reads its kernels.
pub const CLEAN_THRESHOLD: f64 = 0.02;

impl Default for FitParams {
    fn default() -> Self {
        Self {
            threshold: CLEAN_THRESHOLD,
            add_variance_px2: 0.0,
        }
    }
}

/// Both fits of one kernel, in sensor pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianFit {
    /// Levenberg–Marquardt fit to the central region (the one reported).
    pub robust: Gaussian2,
    /// Maximum-likelihood moments of the central region.
    pub ml: Gaussian2,
    /// Kernel mean relative to its centre sample, in pixels (ML).
    pub mean_px: [f64; 2],
    /// SSD between the (cleaned) kernel and each fitted Gaussian, in kernel-weight units.
    pub ssd_robust: f64,
    pub ssd_ml: f64,
    /// Whether Levenberg–Marquardt reported convergence.
    pub converged: bool,
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("kernel is empty (no positive weight)")]
    Empty,
    #[error("degenerate Gaussian fit: {0}")]
    Degenerate(String),
}

/// Labels the 8-connected regions of `mask` (`size × size`); returns per-sample labels
/// (0 = background, regions numbered from 1) and the number of regions.
#[must_use]
pub fn label_regions(mask: &[bool], size: usize) -> (Vec<u32>, u32) {
    use imageproc::region_labelling::{Connectivity, connected_components};
    let side = u32::try_from(size).unwrap_or(u32::MAX);
    let image = image::GrayImage::from_fn(side, side, |x, y| {
        image::Luma([u8::from(mask[y as usize * size + x as usize]) * 255])
    });
    let labelled = connected_components(&image, Connectivity::Eight, image::Luma([0u8]));
    let labels = labelled.into_raw();
    let count = labels.iter().copied().max().unwrap_or(0);
    (labels, count)
}

/// The kernel with everything outside its central region set to zero: the region that
/// holds the centre sample, or failing that the one with the most weight.
#[must_use]
pub fn central_region(kernel: &Kernel, threshold: f64) -> Vec<f64> {
    let n = kernel.size;
    let peak = kernel.data.iter().copied().fold(0.0f64, f64::max);
    let above = |v: f64| v > threshold * peak && v > 0.0;
    let centre = (n / 2) * n + n / 2;
    if kernel.data.get(centre).is_some_and(|&v| above(v)) {
        return region_of(&kernel.data, above, n, centre);
    }
    let mask: Vec<bool> = kernel.data.iter().map(|&v| above(v)).collect();
    let (labels, count) = label_regions(&mask, n);
    let chosen = if labels[centre] != 0 {
        labels[centre]
    } else {
        let mut mass = vec![0.0f64; count as usize + 1];
        for (l, v) in labels.iter().zip(&kernel.data) {
            mass[*l as usize] += v;
        }
        (1..=count)
            .max_by(|&a, &b| mass[a as usize].total_cmp(&mass[b as usize]))
            .unwrap_or(0)
    };
    kernel
        .data
        .iter()
        .zip(&labels)
        .map(|(&v, &l)| if l == chosen && l != 0 { v } else { 0.0 })
        .collect()
}

/// `values` kept on the 8-connected region of samples `above` holds that contains
/// `seed` (itself above), zero elsewhere: what labelling the whole grid gives for that
/// one region, at the cost of the region alone. Every kernel read for its shape or its
/// fit needs its centre's region, and labelling also converts the grid to an image and
/// labels every speck of noise. Samples above are positive, so a sample is taken once
/// its output is no longer zero.
fn region_of(values: &[f64], above: impl Fn(f64) -> bool, n: usize, seed: usize) -> Vec<f64> {
    let mut out = vec![0.0; values.len()];
    let mut stack = vec![seed];
    out[seed] = values[seed];
    while let Some(p) = stack.pop() {
        let (i, j) = (p % n, p / n);
        for b in j.saturating_sub(1)..=(j + 1).min(n - 1) {
            for a in i.saturating_sub(1)..=(i + 1).min(n - 1) {
                let q = b * n + a;
                if out[q] == 0.0 && above(values[q]) {
                    out[q] = values[q];
                    stack.push(q);
                }
            }
        }
    }
    out
}

struct GaussianSsd<'a> {
    target: &'a [f64],
    size: usize,
    oversample: f64,
    /// ln σx, ln σy, atanh ρ, mean x, mean y, amplitude.
    p: Vector6<f64>,
}

impl GaussianSsd<'_> {
    fn gaussian(p: &Vector6<f64>) -> (Gaussian2, [f64; 2], f64) {
        (
            Gaussian2 {
                sigma_x: p[0].exp(),
                sigma_y: p[1].exp(),
                rho: p[2].tanh(),
            },
            [p[3], p[4]],
            p[5],
        )
    }

    fn model(&self, p: &Vector6<f64>) -> Vec<f64> {
        self.evaluate(p, None)
    }

    /// The sampled Gaussian at `p` and, when asked, its derivatives with respect to the
    /// six parameters, from the same exponential per sample: the density's logarithm is
    /// a quadratic in the parameters' natural coordinates, so each derivative is the
    /// sample times a polynomial. A central-difference Jacobian costs twelve model
    /// evaluations per step, which made the fit a quarter of a shot's kernel time.
    fn evaluate(&self, p: &Vector6<f64>, mut jac: Option<&mut OMatrix<f64, Dyn, U6>>) -> Vec<f64> {
        let (g, mean, amp) = Self::gaussian(p);
        let c = (self.size / 2) as f64;
        // Density × cell area: samples of a kernel that sums to 1.
        let per_amp = 1.0 / (self.oversample * self.oversample);
        let cell = amp * per_amp;
        let (sx, sy, r) = (g.sigma_x, g.sigma_y, g.rho);
        let q = 1.0 - r * r;
        let mut out = Vec::with_capacity(self.size * self.size);
        for j in 0..self.size {
            for i in 0..self.size {
                let dx = (i as f64 - c) / self.oversample - mean[0];
                let dy = (j as f64 - c) / self.oversample - mean[1];
                let density = g.density(dx, dy);
                let value = cell * density;
                if let Some(jac) = jac.as_deref_mut() {
                    let row = out.len();
                    // ∂ ln(sample) / ∂ parameter, for ln σx, ln σy, atanh ρ, mean x, mean y.
                    let (u, v) = (dx / sx, dy / sy);
                    let (eu, ev) = ((u - r * v) / q, (v - r * u) / q);
                    let quad = u * u - 2.0 * r * u * v + v * v;
                    let dlog = [
                        u * eu - 1.0,
                        v * ev - 1.0,
                        u * v - r * quad / q + r,
                        eu / sx,
                        ev / sy,
                    ];
                    for (k, d) in dlog.iter().enumerate() {
                        jac[(row, k)] = value * d;
                    }
                    jac[(row, 5)] = per_amp * density;
                }
                out.push(value);
            }
        }
        out
    }
}

impl LeastSquaresProblem<f64, Dyn, U6> for GaussianSsd<'_> {
    type ResidualStorage = nalgebra::storage::Owned<f64, Dyn>;
    type JacobianStorage = nalgebra::storage::Owned<f64, Dyn, U6>;
    type ParameterStorage = nalgebra::storage::Owned<f64, U6>;

    fn set_params(&mut self, x: &Vector6<f64>) {
        self.p = *x;
    }

    fn params(&self) -> Vector6<f64> {
        self.p
    }

    fn residuals(&self) -> Option<OVector<f64, Dyn>> {
        let m = self.model(&self.p);
        let r: Vec<f64> = m.iter().zip(self.target).map(|(a, b)| a - b).collect();
        r.iter()
            .all(|v| v.is_finite())
            .then(|| OVector::<f64, Dyn>::from_vec(r))
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U6>> {
        let mut jac = OMatrix::<f64, Dyn, U6>::zeros(self.size * self.size);
        self.evaluate(&self.p, Some(&mut jac));
        jac.iter().all(|v| v.is_finite()).then_some(jac)
    }
}

fn ssd(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum()
}

/// Fits the ML and robust Gaussians to `kernel`.
///
/// # Errors
/// [`FitError::Empty`] for a kernel without positive weight; [`FitError::Degenerate`]
/// when a fit has no finite, positive spread.
pub fn fit_gaussian(kernel: &Kernel, params: &FitParams) -> Result<GaussianFit, FitError> {
    let region = central_region(kernel, params.threshold);
    let mass: f64 = region.iter().sum();
    if !(mass > 0.0) {
        return Err(FitError::Empty);
    }
    let cleaned = Kernel {
        size: kernel.size,
        oversample: kernel.oversample,
        data: region,
    };
    let m = cleaned.moments();
    if !(m.var_x > 0.0 && m.var_y > 0.0) {
        return Err(FitError::Degenerate(
            "the central region is a single sample".into(),
        ));
    }
    let ml_raw = Gaussian2::from_covariance(m.var_x, m.var_y, m.cov_xy);
    let os = kernel.oversample as f64;
    let start = Vector6::new(
        ml_raw.sigma_x.ln(),
        ml_raw.sigma_y.ln(),
        ml_raw.rho.atanh(),
        m.mean_x,
        m.mean_y,
        mass,
    );
    let problem = GaussianSsd {
        target: &cleaned.data,
        size: kernel.size,
        oversample: os,
        p: start,
    };
    let ml_model = problem.model(&start);
    let ssd_ml = ssd(&ml_model, &cleaned.data);
    let (solved, report) = LevenbergMarquardt::new().minimize(problem);
    let p = solved.p;
    let (robust_raw, _, _) = GaussianSsd::gaussian(&p);
    if !(robust_raw.sigma_x.is_finite()
        && robust_raw.sigma_y.is_finite()
        && robust_raw.rho.abs() < 0.999)
    {
        return Err(FitError::Degenerate(format!(
            "Levenberg–Marquardt left σx {:.3}, σy {:.3}, ρ {:.3}",
            robust_raw.sigma_x, robust_raw.sigma_y, robust_raw.rho
        )));
    }
    let ssd_robust = ssd(&solved.model(&p), &cleaned.data);
    let add = params.add_variance_px2;
    Ok(GaussianFit {
        robust: robust_raw.convolved_variance(add, add, 0.0),
        ml: ml_raw.convolved_variance(add, add, 0.0),
        mean_px: [m.mean_x, m.mean_y],
        ssd_robust,
        ssd_ml,
        converged: report.termination.was_successful(),
    })
}

/// (robust, ML) Gaussians of a kernel by the pipeline's own fit ([`fit_gaussian`]) with
/// its default parameters, as calibration fits them (the Gaussian-approximation
/// experiment judges these; the simulated session's measured stand-in uses them). A
/// kernel the fit rejects falls back to its moments for both.
#[must_use]
pub fn fit_gaussians(k: &Kernel) -> (Gaussian2, Gaussian2) {
    match fit_gaussian(k, &FitParams::default()) {
        Ok(f) => (f.robust, f.ml),
        Err(_) => {
            let m = k.moments();
            let g = Gaussian2::from_covariance(m.var_x, m.var_y, m.cov_xy);
            (g, g)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labelling_is_eight_connected() {
        // Two diagonal neighbours join; a far sample is its own region.
        let size = 5;
        let mut mask = vec![false; 25];
        mask[6] = true;
        mask[12] = true;
        mask[24] = true;
        let (labels, n) = label_regions(&mask, size);
        assert_eq!(n, 2);
        assert_eq!(labels[6], labels[12]);
        assert_ne!(labels[6], labels[24]);
    }

    #[test]
    fn the_centre_region_is_the_one_labelling_finds() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
        let g = Gaussian2::new(1.3, 0.9, 0.3);
        for _ in 0..50 {
            // A core with noise around it: specks, some touching the core.
            let mut k = g.kernel(3);
            let peak = k.data.iter().copied().fold(0.0f64, f64::max);
            for v in &mut k.data {
                *v += peak * rng.random_range(-0.03..0.04);
            }
            let fast = central_region(&k, CLEAN_THRESHOLD);
            let peak = k.data.iter().copied().fold(0.0f64, f64::max);
            let mask: Vec<bool> = k
                .data
                .iter()
                .map(|&v| v > CLEAN_THRESHOLD * peak && v > 0.0)
                .collect();
            let (labels, count) = label_regions(&mask, k.size);
            let centre = labels[(k.size / 2) * k.size + k.size / 2];
            assert!(centre != 0 && count > 1, "{count} regions");
            let slow: Vec<f64> = k
                .data
                .iter()
                .zip(&labels)
                .map(|(&v, &l)| if l == centre { v } else { 0.0 })
                .collect();
            assert_eq!(fast, slow);
        }
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let target = vec![0.0; 21 * 21];
        for p in [
            Vector6::new(0.3f64, -0.2, 0.4, 0.15, -0.3, 0.9),
            Vector6::new(-0.5f64, 0.1, -1.2, -0.4, 0.2, 1.1),
            Vector6::new(0.9f64, 0.8, 0.0, 0.0, 0.0, 1.0),
        ] {
            let problem = GaussianSsd {
                target: &target,
                size: 21,
                oversample: 3.0,
                p,
            };
            let jac = problem.jacobian().unwrap();
            for k in 0..6 {
                let h = 1e-6;
                let (mut lo, mut hi) = (p, p);
                lo[k] -= h;
                hi[k] += h;
                let (ml, mh) = (problem.model(&lo), problem.model(&hi));
                let scale = mh.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                for i in 0..ml.len() {
                    let numeric = (mh[i] - ml[i]) / (2.0 * h);
                    assert!(
                        (jac[(i, k)] - numeric).abs() < 1e-6 * scale,
                        "parameter {k}, sample {i}: {} vs {numeric}",
                        jac[(i, k)]
                    );
                }
            }
        }
    }

    #[test]
    fn recovers_a_sampled_gaussian() {
        let g = Gaussian2::new(1.7, 1.1, -0.45);
        let k = g.kernel(3);
        let fit = fit_gaussian(
            &k,
            &FitParams {
                threshold: 0.0,
                add_variance_px2: 0.0,
            },
        )
        .unwrap();
        assert!((fit.robust.sigma_x - 1.7).abs() < 1e-3, "{:?}", fit.robust);
        assert!((fit.robust.sigma_y - 1.1).abs() < 1e-3);
        assert!((fit.robust.rho + 0.45).abs() < 1e-3);
        assert!(fit.converged);
    }

    #[test]
    fn robust_fit_ignores_an_isolated_blob_that_biases_ml() {
        let g = Gaussian2::new(1.2, 1.0, 0.2);
        let mut k = g.kernel(3);
        // A noise blob in the corner, separate from the PSF after thresholding.
        let n = k.size;
        k.data[n + 1] = 0.01;
        k.data[n + 2] = 0.01;
        k.normalise();
        let fit = fit_gaussian(&k, &FitParams::default()).unwrap();
        assert!(
            (fit.robust.sigma_x / 1.2 - 1.0).abs() < 0.01,
            "{:?}",
            fit.robust
        );
        assert!(fit.ssd_robust <= fit.ssd_ml);
    }

    #[test]
    fn adds_the_requested_variance() {
        let g = Gaussian2::new(0.8, 0.9, 0.0);
        let k = g.kernel(5);
        let add = 1.0 / 108.0;
        let fit = fit_gaussian(
            &k,
            &FitParams {
                threshold: 0.0,
                add_variance_px2: add,
            },
        )
        .unwrap();
        assert!(
            (fit.robust.sigma_x - (0.64f64 + add).sqrt()).abs() < 2e-3,
            "{:?}",
            fit.robust
        );
    }
}
