//! Point-spread functions as the rest of the pipeline passes them around: sampled
//! kernels and 2-D Gaussians.
//!
//! Everything is in full-resolution sensor pixels. A [`Kernel`] is stored at
//! `oversample`× resolution: sample (i, j) sits at offset
//! `((i − c) / oversample, (j − c) / oversample)` pixels from the kernel centre, with
//! c = (size − 1) / 2. Kernels are odd-sized and sum to 1.

use serde::{Deserialize, Serialize};

/// The error function, to 1.5 × 10⁻⁷ (Abramowitz & Stegun 7.1.26): enough for the
/// tail masses it is used to bound.
#[must_use]
pub fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let y = 1.0 - poly * (-x * x).exp();
    if x < 0.0 { -y } else { y }
}

/// A sampled PSF, odd-sized, centred, summing to 1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Kernel {
    pub size: usize,
    pub oversample: usize,
    /// `size × size` values, row-major.
    pub data: Vec<f64>,
}

/// Second moments of a PSF, in sensor pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Moments {
    pub mean_x: f64,
    pub mean_y: f64,
    pub var_x: f64,
    pub var_y: f64,
    pub cov_xy: f64,
}

impl Kernel {
    /// Samples `f(dx, dy)` (offsets in sensor pixels) on a `size × size` grid at
    /// `oversample`× resolution and normalises to sum 1.
    ///
    /// # Panics
    /// If `size` is even or zero, or `oversample` is zero.
    #[must_use]
    pub fn from_fn(size: usize, oversample: usize, f: impl Fn(f64, f64) -> f64) -> Kernel {
        assert!(size % 2 == 1 && oversample > 0, "kernels are odd-sized");
        let c = (size / 2) as f64;
        let s = oversample as f64;
        let mut data = Vec::with_capacity(size * size);
        for j in 0..size {
            for i in 0..size {
                data.push(f((i as f64 - c) / s, (j as f64 - c) / s).max(0.0));
            }
        }
        let mut k = Kernel {
            size,
            oversample,
            data,
        };
        k.normalise();
        k
    }

    /// Rescales to sum 1 (no-op for an all-zero kernel).
    pub fn normalise(&mut self) {
        let s: f64 = self.data.iter().sum();
        if s > 0.0 {
            for v in &mut self.data {
                *v /= s;
            }
        }
    }

    #[inline]
    #[must_use]
    pub fn at(&self, i: usize, j: usize) -> f64 {
        self.data[j * self.size + i]
    }

    /// Half-width of the support in sensor pixels.
    #[must_use]
    pub fn radius_px(&self) -> f64 {
        (self.size / 2) as f64 / self.oversample as f64
    }

    /// Mean and (co)variance, in sensor pixels, of the kernel as a distribution of its
    /// sample weights. Note a kernel sampled at `oversample`× represents a PSF whose
    /// variance is this plus nothing: samples are point values, not cell integrals.
    #[must_use]
    pub fn moments(&self) -> Moments {
        let c = (self.size / 2) as f64;
        let s = self.oversample as f64;
        let (mut m0, mut mx, mut my) = (0.0, 0.0, 0.0);
        for j in 0..self.size {
            for i in 0..self.size {
                let w = self.at(i, j);
                m0 += w;
                mx += w * (i as f64 - c) / s;
                my += w * (j as f64 - c) / s;
            }
        }
        if m0 <= 0.0 {
            return Moments {
                mean_x: 0.0,
                mean_y: 0.0,
                var_x: 0.0,
                var_y: 0.0,
                cov_xy: 0.0,
            };
        }
        let (mx, my) = (mx / m0, my / m0);
        let (mut vx, mut vy, mut cxy) = (0.0, 0.0, 0.0);
        for j in 0..self.size {
            for i in 0..self.size {
                let w = self.at(i, j);
                let dx = (i as f64 - c) / s - mx;
                let dy = (j as f64 - c) / s - my;
                vx += w * dx * dx;
                vy += w * dy * dy;
                cxy += w * dx * dy;
            }
        }
        Moments {
            mean_x: mx,
            mean_y: my,
            var_x: vx / m0,
            var_y: vy / m0,
            cov_xy: cxy / m0,
        }
    }

    /// Bilinear sample of the kernel's continuous interpolant at an offset in pixels,
    /// in units of kernel weight per sample (0 outside the support).
    #[must_use]
    pub fn sample_px(&self, dx: f64, dy: f64) -> f64 {
        let c = (self.size / 2) as f64;
        let s = self.oversample as f64;
        let (u, v) = (dx * s + c, dy * s + c);
        let (u0, v0) = (u.floor(), v.floor());
        let (fu, fv) = (u - u0, v - v0);
        let get = |i: f64, j: f64| -> f64 {
            if i < 0.0 || j < 0.0 || i >= self.size as f64 || j >= self.size as f64 {
                0.0
            } else {
                self.at(i as usize, j as usize)
            }
        };
        (get(u0, v0) * (1.0 - fu) + get(u0 + 1.0, v0) * fu) * (1.0 - fv)
            + (get(u0, v0 + 1.0) * (1.0 - fu) + get(u0 + 1.0, v0 + 1.0) * fu) * fv
    }

    /// The same PSF resampled at another oversampling (area-preserving: the result sums
    /// to 1). Going from 3× to 1× gives the pixel-level kernel a deconvolver uses.
    #[must_use]
    pub fn resampled(&self, oversample: usize) -> Kernel {
        if oversample == self.oversample {
            return self.clone();
        }
        let radius = self.radius_px();
        let half = (radius * oversample as f64).ceil() as usize;
        let size = 2 * half + 1;
        Kernel::from_fn(size, oversample, |dx, dy| self.sample_px(dx, dy))
    }
}

/// A zero-mean 2-D Gaussian in the paper's parameters: `sigma_x` = C_xx and
/// `sigma_y` = C_yy are standard deviations in sensor pixels, `rho` = C_or =
/// C_xy / (C_xx·C_yy) the correlation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Gaussian2 {
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
}

impl Gaussian2 {
    #[must_use]
    pub fn isotropic(sigma: f64) -> Self {
        Self {
            sigma_x: sigma,
            sigma_y: sigma,
            rho: 0.0,
        }
    }

    /// From a covariance matrix's entries.
    #[must_use]
    pub fn from_covariance(var_x: f64, var_y: f64, cov_xy: f64) -> Self {
        let sx = var_x.max(0.0).sqrt();
        let sy = var_y.max(0.0).sqrt();
        let rho = if sx > 0.0 && sy > 0.0 {
            (cov_xy / (sx * sy)).clamp(-0.999, 0.999)
        } else {
            0.0
        };
        Self {
            sigma_x: sx,
            sigma_y: sy,
            rho,
        }
    }

    #[must_use]
    pub fn cov_xy(&self) -> f64 {
        self.rho * self.sigma_x * self.sigma_y
    }

    /// The Gaussian convolved with another (covariances add): e.g. an optical PSF with
    /// the pixel's box, whose variance is 1/12 px² per axis.
    #[must_use]
    pub fn convolved_variance(&self, add_var_x: f64, add_var_y: f64, add_cov: f64) -> Self {
        Self::from_covariance(
            self.sigma_x.powi(2) + add_var_x,
            self.sigma_y.powi(2) + add_var_y,
            self.cov_xy() + add_cov,
        )
    }

    /// Density at an offset (dx, dy) pixels; 0 for a degenerate Gaussian.
    #[must_use]
    pub fn density(&self, dx: f64, dy: f64) -> f64 {
        let (sx, sy, r) = (self.sigma_x, self.sigma_y, self.rho);
        let q = 1.0 - r * r;
        if !(sx > 0.0 && sy > 0.0 && q > 0.0) {
            return 0.0;
        }
        let (u, v) = (dx / sx, dy / sy);
        let e = (u * u - 2.0 * r * u * v + v * v) / (2.0 * q);
        (-e).exp() / (2.0 * std::f64::consts::PI * sx * sy * q.sqrt())
    }

    /// Support radius (in pixels) that holds all but a negligible tail: `n_sigma` times
    /// the largest standard deviation, at least one pixel.
    #[must_use]
    pub fn radius_px(&self, n_sigma: f64) -> f64 {
        (n_sigma * self.sigma_x.max(self.sigma_y)).max(1.0)
    }

    /// Point-sampled kernel at `oversample`×, wide enough for 4σ.
    #[must_use]
    pub fn kernel(&self, oversample: usize) -> Kernel {
        let half = (self.radius_px(4.0) * oversample as f64).ceil() as usize;
        Kernel::from_fn(2 * half + 1, oversample, |dx, dy| self.density(dx, dy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_kernel_has_its_moments() {
        let g = Gaussian2 {
            sigma_x: 1.6,
            sigma_y: 0.9,
            rho: 0.4,
        };
        let k = g.kernel(3);
        assert_eq!(k.size % 2, 1);
        let m = k.moments();
        assert!(m.mean_x.abs() < 1e-9 && m.mean_y.abs() < 1e-9);
        assert!((m.var_x.sqrt() - 1.6).abs() < 0.01, "{}", m.var_x.sqrt());
        assert!((m.var_y.sqrt() - 0.9).abs() < 0.01);
        let back = Gaussian2::from_covariance(m.var_x, m.var_y, m.cov_xy);
        assert!((back.rho - 0.4).abs() < 0.01);
    }

    #[test]
    fn resampling_keeps_the_moments() {
        let g = Gaussian2 {
            sigma_x: 2.0,
            sigma_y: 1.5,
            rho: -0.3,
        };
        let k3 = g.kernel(3);
        let k1 = k3.resampled(1);
        assert_eq!(k1.oversample, 1);
        assert!((k1.data.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let m = k1.moments();
        assert!((m.var_x.sqrt() - 2.0).abs() < 0.05, "{}", m.var_x.sqrt());
        assert!((m.var_y.sqrt() - 1.5).abs() < 0.05);
    }

    #[test]
    fn box_convolution_adds_a_twelfth() {
        let g = Gaussian2 {
            sigma_x: 0.7,
            sigma_y: 0.7,
            rho: 0.0,
        }
        .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
        assert!((g.sigma_x - (0.49f64 + 1.0 / 12.0).sqrt()).abs() < 1e-12);
    }
}
