//! The tiles' kernels as the GPU gets them: a kernel that is a Gaussian goes up as six
//! numbers and the device makes its taps (`deblur.wgsl`'s `kernel_sum` and `load`);
//! any other goes up as its taps.

use super::super::{DeblurError, KernelSource, PlacedGaussian, cropped, plane_kernel_at};
use crate::plane::ChannelPlane;
use crate::psf::Kernel;

/// One tile's kernel at plane resolution, cropped to the block's margin.
pub(crate) enum TileKernel {
    Taps(Kernel),
    Gaussian(GaussianTaps),
}

/// The taps the CPU path makes of a [`PlacedGaussian`] on a plane of step 1: the
/// Gaussian's density at each whole-pixel offset d with |dx|, |dy| ≤ `half`, less its
/// mean, normalised to sum 1. The CPU renders it at its oversampling, resamples it to
/// 1× (whole-pixel offsets land on its samples, so the density is read exactly) and
/// crops it to the block's margin; so the taps reach as far as both the rendering
/// and the crop do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct GaussianTaps {
    /// The exponent's coefficients: tap ∝ exp(−(a·u² + b·u·v + c·v²)), (u, v) = d − mean.
    pub quadratic: [f64; 3],
    pub mean: [f64; 2],
    pub half: usize,
}

impl GaussianTaps {
    /// Numbers per tile in the kernels buffer.
    pub const LEN: usize = 6;

    /// The taps of `g` cropped to `max_size` a side; `None` for a degenerate Gaussian
    /// (the CPU path's kernel of one is not a Gaussian's).
    #[must_use]
    pub fn of(g: &PlacedGaussian, max_size: usize) -> Option<Self> {
        let (sx, sy, r) = (g.gaussian.sigma_x, g.gaussian.sigma_y, g.gaussian.rho);
        let q = 1.0 - r * r;
        if !(sx > 0.0 && sy > 0.0 && q > 0.0 && g.oversample > 0 && max_size > 0) {
            return None;
        }
        let os = g.oversample;
        // `Gaussian2::kernel_at`'s half side at its oversampling.
        let reach = g.gaussian.radius_px(4.0) + g.mean[0].abs().max(g.mean[1].abs());
        let rendered = (reach * os as f64).ceil() as usize;
        // `cropped` keeps the largest odd side within `max_size`.
        let crop = (max_size - 1) / 2;
        Some(Self {
            quadratic: [
                1.0 / (2.0 * q * sx * sx),
                -r / (q * sx * sy),
                1.0 / (2.0 * q * sy * sy),
            ],
            mean: g.mean,
            half: (rendered / os).min(crop),
        })
    }

    /// What the kernels buffer holds of it.
    #[must_use]
    pub fn packed(&self) -> [f32; Self::LEN] {
        let [a, b, c] = self.quadratic;
        [
            a as f32,
            b as f32,
            c as f32,
            self.mean[0] as f32,
            self.mean[1] as f32,
            self.half as f32,
        ]
    }
}

/// The kernel of the tile centred at plane point (i, j): six numbers where the source's
/// kernel there is a Gaussian and the plane is not a mosaic's (whose kernels are
/// integrated over its coarser pixels), else its taps.
///
/// # Errors
/// A source that cannot supply a kernel.
pub(crate) fn tile_kernel(
    cp: &ChannelPlane,
    sensor: (usize, usize),
    source: &dyn KernelSource,
    [i, j]: [f64; 2],
    max_size: usize,
) -> Result<TileKernel, DeblurError> {
    if cp.step <= 1 {
        let [x, y] = super::super::sensor_point(cp, sensor, i, j);
        if let Some(t) = source
            .placed_gaussian(cp.channel, x, y)?
            .and_then(|g| GaussianTaps::of(&g, max_size))
        {
            return Ok(TileKernel::Gaussian(t));
        }
    }
    let k = plane_kernel_at(cp, sensor.0, sensor.1, source, i, j)?;
    Ok(TileKernel::Taps(cropped(k, max_size).resampled(1)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::Gaussian2;

    /// The taps as the shaders make them, in double precision.
    fn taps(t: &GaussianTaps) -> Kernel {
        let [a, b, c] = t.quadratic;
        Kernel::from_fn(2 * t.half + 1, 1, |dx, dy| {
            let (u, v) = (dx - t.mean[0], dy - t.mean[1]);
            (-(a * u * u + b * u * v + c * v * v)).exp()
        })
    }

    /// The kernel the CPU path deblurs a step-1 plane's tile with, taps of zero trimmed
    /// from its edges (they change no convolution).
    fn cpu_kernel(g: &PlacedGaussian, max_size: usize) -> Kernel {
        let k = crate::deblur::plane_kernel(&g.gaussian.kernel_at(g.oversample, g.mean), 1);
        let mut k = cropped(k, max_size).resampled(1);
        while k.size > 1 && (0..k.size).all(|i| k.at(i, 0) == 0.0 && k.at(0, i) == 0.0) {
            k = cropped(k.clone(), k.size - 2);
        }
        k
    }

    #[test]
    fn gaussian_taps_are_the_cpu_paths_kernel() {
        let cases = [
            (Gaussian2::new(1.2, 0.9, 0.3), [0.0, 0.0], 99),
            (Gaussian2::new(0.4, 0.3, 0.0), [0.0, 0.0], 99),
            (Gaussian2::new(2.5, 1.7, -0.6), [0.7, -1.3], 99),
            // Wider than the margin: cropped.
            (Gaussian2::new(3.0, 2.2, 0.4), [0.2, 0.1], 9),
            (Gaussian2::new(3.0, 2.2, 0.4), [0.2, 0.1], 8),
        ];
        for (gaussian, mean, max_size) in cases {
            for oversample in [1, 3] {
                let g = PlacedGaussian {
                    gaussian,
                    mean,
                    oversample,
                };
                let t = GaussianTaps::of(&g, max_size).expect("a Gaussian");
                let (made, cpu) = (taps(&t), cpu_kernel(&g, max_size));
                assert_eq!(made.size, cpu.size, "{g:?} cropped to {max_size}");
                for (p, q) in made.data.iter().zip(&cpu.data) {
                    assert!((p - q).abs() < 1e-12, "{g:?}: {p} against {q}");
                }
            }
        }
        let flat = PlacedGaussian {
            gaussian: Gaussian2::new(1.0, 1.0, 1.0),
            mean: [0.0; 2],
            oversample: 3,
        };
        assert_eq!(GaussianTaps::of(&flat, 99), None);
    }
}
