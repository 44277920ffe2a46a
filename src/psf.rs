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
        crate::plane::bilinear_zero_outside(&self.data, self.size, dx * s + c, dy * s + c)
    }

    /// |K(ν u)|: the modulus of the kernel's Fourier transform at `nu` cycles per px
    /// along the unit direction at `angle_rad` from +x towards +y, the kernel's samples
    /// taken as point values at their offsets (what an FFT of the array samples on its
    /// grid, evaluated here on the line itself rather than between bins).
    #[must_use]
    pub fn mtf_along(&self, angle_rad: f64, nu: f64) -> f64 {
        let (s, c) = angle_rad.sin_cos();
        let half = (self.size / 2) as f64;
        let os = self.oversample as f64;
        let (mut re, mut im, mut sum) = (0.0, 0.0, 0.0);
        for j in 0..self.size {
            for i in 0..self.size {
                let w = self.at(i, j);
                let along = ((i as f64 - half) * c + (j as f64 - half) * s) / os;
                let phase = -std::f64::consts::TAU * nu * along;
                re += w * phase.cos();
                im += w * phase.sin();
                sum += w;
            }
        }
        if sum > 0.0 { re.hypot(im) / sum } else { 0.0 }
    }

    /// The lowest frequency (cycles per px) at which [`Kernel::mtf_along`] falls to
    /// one half, found on steps of 0.005 cycles/px and refined by bisection; `None` if
    /// it stays above one half up to the kernel's Nyquist frequency.
    #[must_use]
    pub fn mtf50_along(&self, angle_rad: f64) -> Option<f64> {
        let nyquist = 0.5 * self.oversample as f64;
        let step = 0.005;
        let mut lo = 0.0;
        while lo < nyquist {
            let hi = lo + step;
            if self.mtf_along(angle_rad, hi) <= 0.5 {
                let (mut a, mut b) = (lo, hi);
                for _ in 0..40 {
                    let m = 0.5 * (a + b);
                    if self.mtf_along(angle_rad, m) > 0.5 {
                        a = m;
                    } else {
                        b = m;
                    }
                }
                return Some(0.5 * (a + b));
            }
            lo = hi;
        }
        None
    }

    /// The same PSF moved by (dx, dy) px: its bilinear interpolant read at p − d on a
    /// grid grown by the shift, so nothing falls off its edge; sums to 1. A shift of
    /// zero returns the kernel as it is (bilinear reading would blur it slightly).
    #[must_use]
    pub fn shifted(&self, dx: f64, dy: f64) -> Kernel {
        if dx == 0.0 && dy == 0.0 {
            return self.clone();
        }
        let os = self.oversample as f64;
        let grow = (dx.abs().max(dy.abs()) * os).ceil() as usize + 1;
        Kernel::from_fn(self.size + 2 * grow, self.oversample, |x, y| {
            self.sample_px(x - dx, y - dy)
        })
    }

    /// The PSF integrated over a pixel's area: convolved with the 1-pixel box at its own
    /// oversampling (an odd number of samples per pixel: exactly; an even one: the box
    /// one sample wider).
    #[must_use]
    pub fn pixel_integrated(&self) -> Kernel {
        let os = self.oversample;
        let n = self.size + os - 1 + usize::from(os.is_multiple_of(2));
        let size = n | 1;
        let off = (size - self.size) / 2;
        let half = os as isize / 2;
        let mut data = vec![0.0; size * size];
        for j in 0..self.size {
            for i in 0..self.size {
                let v = self.at(i, j);
                for b in -half..=half {
                    for a in -half..=half {
                        let x = (i + off) as isize + a;
                        let y = (j + off) as isize + b;
                        if x >= 0 && y >= 0 && (x as usize) < size && (y as usize) < size {
                            data[y as usize * size + x as usize] += v;
                        }
                    }
                }
            }
        }
        let mut out = Kernel {
            size,
            oversample: os,
            data,
        };
        out.normalise();
        out
    }

    /// The same kernel centred in an `n × n` array of zeros (or as it is, if it is
    /// that large already): two kernels on one grid.
    #[must_use]
    pub fn padded(&self, n: usize) -> Kernel {
        if self.size >= n {
            return self.clone();
        }
        let off = (n - self.size) / 2;
        let mut data = vec![0.0; n * n];
        for j in 0..self.size {
            for i in 0..self.size {
                data[(j + off) * n + i + off] = self.at(i, j);
            }
        }
        Kernel {
            size: n,
            oversample: self.oversample,
            data,
        }
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
    /// σx, σy (px) and the correlation ρ.
    #[must_use]
    pub const fn new(sigma_x: f64, sigma_y: f64, rho: f64) -> Self {
        Self {
            sigma_x,
            sigma_y,
            rho,
        }
    }

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

    /// σ = √(C_xx·C_yy), the one number the studio colours blur by (px).
    #[must_use]
    pub fn sigma(&self) -> f64 {
        (self.sigma_x * self.sigma_y).sqrt()
    }

    /// The variance (px²) along the unit direction at `angle_rad` from +x towards +y:
    /// uᵀCu.
    #[must_use]
    pub fn variance_along(&self, angle_rad: f64) -> f64 {
        let (s, c) = angle_rad.sin_cos();
        c * c * self.sigma_x.powi(2) + 2.0 * c * s * self.cov_xy() + s * s * self.sigma_y.powi(2)
    }

    /// MTF50 along the worst and best directions and of the isotropic equivalent
    /// ([`Mtf50`]); `None` for a degenerate Gaussian (C not positive definite, or not
    /// finite).
    #[must_use]
    pub fn mtf50(&self) -> Option<Mtf50> {
        let (a, c, b) = (self.sigma_x.powi(2), self.sigma_y.powi(2), self.cov_xy());
        let half_diff = 0.5 * (a - c);
        let radius = half_diff.hypot(b);
        let mean = 0.5 * (a + c);
        let (largest, smallest) = (mean + radius, mean - radius);
        let det = a * c - b * b;
        let worst_deg = (0.5 * (2.0 * b).atan2(a - c))
            .to_degrees()
            .rem_euclid(180.0);
        Some(Mtf50 {
            worst: mtf50_of_variance(largest)?,
            best: mtf50_of_variance(smallest)?,
            isotropic: mtf50_of_variance(det.max(0.0).sqrt())?,
            worst_deg,
        })
    }

    /// Point-sampled kernel at `oversample`×, wide enough for 4σ.
    #[must_use]
    pub fn kernel(&self, oversample: usize) -> Kernel {
        self.kernel_at(oversample, [0.0, 0.0])
    }

    /// As [`Gaussian2::kernel`] with the Gaussian's mean at `mean` px, the grid grown
    /// so the 4σ support stays on it. Rendered at its place rather than moved after,
    /// because interpolating a sharp kernel widens it.
    #[must_use]
    pub fn kernel_at(&self, oversample: usize, mean: [f64; 2]) -> Kernel {
        let reach = self.radius_px(4.0) + mean[0].abs().max(mean[1].abs());
        let half = (reach * oversample as f64).ceil() as usize;
        Kernel::from_fn(2 * half + 1, oversample, |dx, dy| {
            self.density(dx - mean[0], dy - mean[1])
        })
    }
}

/// MTF50 of a Gaussian PSF, in cycles per full-resolution sensor pixel.
///
/// The MTF of a Gaussian with covariance C along a unit direction u is
/// exp(−2π² ν² uᵀCu), so it falls to one half at ν50 = √(ln 2 / (2π² uᵀCu)). The
/// Gaussians lensblur measures and predicts are of the pixel-level PSF, so this
/// includes the pixel's own aperture (as the 1/12 px² of variance it adds per axis)
/// but not sampling: aliasing, the Bayer pattern and demosaicing are outside it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Mtf50 {
    /// Along the direction the PSF is widest (the largest eigenvalue of C): the
    /// lowest MTF50 over all directions, so every direction resolves at least this.
    pub worst: f64,
    /// Along the narrowest direction (the smallest eigenvalue): the highest.
    pub best: f64,
    /// Of the isotropic Gaussian with the same determinant, σ_eff = det(C)^¼: the
    /// geometric mean of `worst` and `best`.
    pub isotropic: f64,
    /// The worst direction, degrees from +x towards +y (y points down), in [0, 180).
    pub worst_deg: f64,
}

/// The frequency (cycles per px) at which a Gaussian of variance `var_px2` (px²) along
/// a direction has an MTF of one half; `None` unless the variance is positive.
#[must_use]
pub fn mtf50_of_variance(var_px2: f64) -> Option<f64> {
    (var_px2.is_finite() && var_px2 > 0.0)
        .then(|| (std::f64::consts::LN_2 / (2.0 * std::f64::consts::PI.powi(2) * var_px2)).sqrt())
}

impl Mtf50 {
    /// `cycles_per_px` as line pairs per picture height (one line pair is one cycle).
    #[must_use]
    pub fn lp_per_picture_height(cycles_per_px: f64, height_px: usize) -> f64 {
        cycles_per_px * height_px as f64
    }

    /// This MTF50 as files report it, with line pairs per picture height for an image
    /// `height_px` tall.
    #[must_use]
    pub fn record(&self, height_px: usize) -> Mtf50Record {
        let lp = |v| Self::lp_per_picture_height(v, height_px);
        Mtf50Record {
            worst: self.worst,
            best: self.best,
            isotropic: self.isotropic,
            worst_deg: self.worst_deg,
            worst_lp_ph: lp(self.worst),
            best_lp_ph: lp(self.best),
            isotropic_lp_ph: lp(self.isotropic),
        }
    }
}

/// The `mtf50` object of the kernels file and the predictions (docs/formats.md): the
/// three MTF50s in cycles/px and in line pairs per picture height.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Mtf50Record {
    pub worst: f64,
    pub best: f64,
    pub isotropic: f64,
    pub worst_deg: f64,
    pub worst_lp_ph: f64,
    pub best_lp_ph: f64,
    pub isotropic_lp_ph: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_kernel_has_its_moments() {
        let g = Gaussian2::new(1.6, 0.9, 0.4);
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
        let g = Gaussian2::new(2.0, 1.5, -0.3);
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
        let g = Gaussian2::new(0.7, 0.7, 0.0).convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
        assert!((g.sigma_x - (0.49f64 + 1.0 / 12.0).sqrt()).abs() < 1e-12);
    }
    #[test]
    fn mtf50_of_a_gaussian_is_where_its_sampled_kernel_transform_crosses_one_half() {
        let g = Gaussian2::new(1.7, 0.8, 0.45);
        let m = g.mtf50().expect("positive definite");
        // The worst direction is the one of largest variance.
        let worst = m.worst_deg.to_radians();
        for k in 0..180 {
            let a = f64::from(k).to_radians();
            assert!(
                g.variance_along(a) <= g.variance_along(worst) + 1e-12,
                "{k}°"
            );
        }
        assert!(m.worst < m.isotropic && m.isotropic < m.best);
        assert!((m.isotropic - (m.worst * m.best).sqrt()).abs() < 1e-12);
        // Against the transform of the point-sampled 3× kernel: only its truncation
        // at 4σ and aliasing (both far below 1e-3 here) separate the two.
        let k = g.kernel(3);
        for (angle, want) in [
            (worst, m.worst),
            (worst + std::f64::consts::FRAC_PI_2, m.best),
        ] {
            let got = k.mtf50_along(angle).expect("crosses");
            assert!((got / want - 1.0).abs() < 1e-3, "{got} vs {want}");
        }
    }

    #[test]
    fn isotropic_mtf50_and_degenerate_gaussians() {
        // σ = 1 px: ν50 = √(ln 2 / 2) / π.
        let m = Gaussian2::isotropic(1.0).mtf50().expect("mtf");
        assert!((m.worst - 0.187_390).abs() < 1e-6, "{}", m.worst);
        assert!((m.best - m.worst).abs() < 1e-12);
        let r = m.record(1000);
        assert!((r.worst_lp_ph - 187.390).abs() < 1e-3);
        assert!(Gaussian2::isotropic(0.0).mtf50().is_none());
        assert!(Gaussian2::isotropic(f64::NAN).mtf50().is_none());
        let line = Gaussian2::new(1.0, 1.0, 1.0);
        assert!(line.mtf50().is_none(), "a line PSF has no best direction");
    }
}
