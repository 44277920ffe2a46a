//! The tiles' kernels as the GPU gets them: a kernel that is a Gaussian goes up as six
//! numbers, one a kernel-shape model predicts as its Gaussian's numbers and its shape's
//! coefficients (the model's components go up once a photo), and the device makes
//! their taps (`deblur.wgsl`'s `kernel_sum` and `load`); any other goes up as its taps.

use super::super::{
    DeblurError, KernelSource, PlacedGaussian, ShapedKernel, cropped, plane_kernel_at,
};
use crate::model::{PlacedShape, ShapeModel, ShapeSpace, Whitening, deployed_kernel_side};
use crate::plane::ChannelPlane;
use crate::psf::Kernel;

/// One tile's kernel at plane resolution, cropped to the block's margin.
pub(crate) enum TileKernel<'a> {
    Taps(Kernel),
    Gaussian(GaussianTaps),
    Shape(ShapeTaps<'a>),
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

/// The taps the CPU path makes of a [`ShapedKernel`] on a plane of step 1: at each
/// whole-pixel offset d with |dx|, |dy| ≤ `half`, p = d − offset, the value
/// `kernel_with_shape_at` renders there,
///
///   max(0, s · N(A⁻¹p) + R(G p)),   R = Σ cᵢ · componentᵢ read bilinearly,
///
/// normalised to sum 1; N is the unit normal, A the square root of the Gaussian's
/// covariance, and (s, G) are (1, A⁻¹) for a residual in whitened coordinates and
/// (1 / det A, I) for one in pixels. Whole-pixel offsets land on the 3× rendering's
/// samples, so its resampling to 1× reads these values exactly.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ShapeTaps<'a> {
    /// A⁻¹, symmetric: [xx, xy, yy].
    pub white: [f64; 3],
    /// s, the normal density's factor in the residual's units.
    pub normal_scale: f64,
    /// G, symmetric: [xx, xy, yy].
    pub to_grid: [f64; 3],
    pub offset: [f64; 2],
    pub half: usize,
    /// The residual grid's samples a side, and per unit (σ or px).
    pub side: usize,
    pub per_unit: usize,
    /// The model's components (uploaded once a photo) and this tile's coefficients.
    pub components: &'a [Vec<f64>],
    pub coefficients: Vec<f64>,
}

impl<'a> ShapeTaps<'a> {
    /// The taps of `k` cropped to `max_size` a side; `None` for a degenerate Gaussian
    /// (the CPU path's kernel of one is none at all).
    #[must_use]
    pub fn of(k: ShapedKernel<'a>, max_size: usize) -> Option<Self> {
        let model: &'a ShapeModel = k.model;
        Self::of_parts(
            model.space,
            &model.components,
            k.placed,
            k.oversample,
            max_size,
        )
    }

    /// [`Self::of`] for a shape in `space` over `components`; `None` also for more
    /// coefficients than components.
    #[must_use]
    pub fn of_parts(
        space: ShapeSpace,
        components: &'a [Vec<f64>],
        placed: PlacedShape,
        oversample: usize,
        max_size: usize,
    ) -> Option<Self> {
        let wh = Whitening::of(&placed.gaussian)?;
        let os = oversample.max(1);
        if max_size == 0 || placed.coefficients.len() > components.len() {
            return None;
        }
        // `kernel_with_shape_at`'s half side at its oversampling, grown by the move.
        let [ox, oy] = placed.offset;
        let grow = (ox.abs().max(oy.abs()) * os as f64).ceil() as usize;
        let rendered = (deployed_kernel_side(space, &placed.gaussian, os)? + 2 * grow) / 2;
        let white = wh.inverse();
        let (normal_scale, to_grid) = match space {
            ShapeSpace::Whitened => (1.0, white),
            ShapeSpace::Pixel => (1.0 / wh.det(), [1.0, 0.0, 1.0]),
        };
        Some(Self {
            white,
            normal_scale,
            to_grid,
            offset: placed.offset,
            half: (rendered / os).min((max_size - 1) / 2),
            side: space.side(),
            per_unit: space.per_unit(),
            components,
            coefficients: placed.coefficients,
        })
    }

    /// What the kernels buffer holds of it, its components placed at `components_at`
    /// in the same buffer (an f32 holds the offset exactly below 2²⁴).
    #[must_use]
    pub fn packed(&self, components_at: usize) -> Vec<f32> {
        let head = [
            self.white[0],
            self.white[1],
            self.white[2],
            self.normal_scale,
            self.to_grid[0],
            self.to_grid[1],
            self.to_grid[2],
            self.offset[0],
            self.offset[1],
            self.half as f64,
            self.side as f64,
            self.per_unit as f64,
            components_at as f64,
            self.coefficients.len() as f64,
        ];
        head.iter()
            .chain(&self.coefficients)
            .map(|&v| v as f32)
            .collect()
    }
}

/// The kernel of the tile centred at plane point (i, j): a few numbers where the
/// source's kernel there is a Gaussian or a shape model's and the plane is not a
/// mosaic's (whose kernels are integrated over its coarser pixels), else its taps.
///
/// # Errors
/// A source that cannot supply a kernel.
pub(crate) fn tile_kernel<'a>(
    cp: &ChannelPlane,
    sensor: (usize, usize),
    source: &'a dyn KernelSource,
    [i, j]: [f64; 2],
    max_size: usize,
) -> Result<TileKernel<'a>, DeblurError> {
    if cp.step <= 1 {
        let [x, y] = super::super::sensor_point(cp, sensor, i, j);
        if let Some(t) = source
            .placed_gaussian(cp.channel, x, y)?
            .and_then(|g| GaussianTaps::of(&g, max_size))
        {
            return Ok(TileKernel::Gaussian(t));
        }
        if let Some(t) = source
            .shaped_kernel(cp.channel, x, y)?
            .and_then(|k| ShapeTaps::of(k, max_size))
        {
            return Ok(TileKernel::Shape(t));
        }
    }
    let k = plane_kernel_at(cp, sensor.0, sensor.1, source, i, j)?;
    Ok(TileKernel::Taps(cropped(k, max_size).resampled(1)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::Gaussian2;
    use std::f64::consts::TAU;

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
        trimmed(cropped(k, max_size).resampled(1))
    }

    /// `k` with its outer rings of zero taps cut (they change no convolution).
    fn trimmed(mut k: Kernel) -> Kernel {
        let ring_is_zero = |k: &Kernel| {
            let n = k.size - 1;
            (0..k.size).all(|i| [k.at(i, 0), k.at(0, i), k.at(i, n), k.at(n, i)] == [0.0; 4])
        };
        while k.size > 1 && ring_is_zero(&k) {
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

    /// The shape taps as the shaders make them (`shape_tap`), in double precision.
    fn shape_taps(t: &ShapeTaps<'_>) -> Kernel {
        let residual = |i: f64, j: f64| -> f64 {
            let n = t.side as f64;
            if i < 0.0 || j < 0.0 || i >= n || j >= n {
                return 0.0;
            }
            let e = j as usize * t.side + i as usize;
            t.coefficients
                .iter()
                .zip(t.components)
                .map(|(c, comp)| c * comp[e])
                .sum()
        };
        let [m0, m1, m2] = t.white;
        let [g0, g1, g2] = t.to_grid;
        Kernel::from_fn(2 * t.half + 1, 1, |dx, dy| {
            let (px, py) = (dx - t.offset[0], dy - t.offset[1]);
            let (wx, wy) = (m0 * px + m1 * py, m1 * px + m2 * py);
            let normal = t.normal_scale * (-0.5 * (wx * wx + wy * wy)).exp() / TAU;
            let h = (t.side / 2) as f64;
            let s = t.per_unit as f64;
            let (u, v) = ((g0 * px + g1 * py) * s + h, (g1 * px + g2 * py) * s + h);
            let (u0, v0) = (u.floor(), v.floor());
            let (fu, fv) = (u - u0, v - v0);
            let r = (1.0 - fu) * (1.0 - fv) * residual(u0, v0)
                + fu * (1.0 - fv) * residual(u0 + 1.0, v0)
                + (1.0 - fu) * fv * residual(u0, v0 + 1.0)
                + fu * fv * residual(u0 + 1.0, v0 + 1.0);
            normal + r
        })
    }

    /// Components like a lens's: a comet's tail along x and a ring, each a smooth bump
    /// on the space's grid.
    fn components(space: ShapeSpace) -> Vec<Vec<f64>> {
        let side = space.side();
        let h = (side / 2) as f64;
        let s = space.per_unit() as f64;
        let bump = |cx: f64, cy: f64, r: f64, a: f64| -> Vec<f64> {
            (0..side * side)
                .map(|e| {
                    let (x, y) = (((e % side) as f64 - h) / s, ((e / side) as f64 - h) / s);
                    a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * r * r)).exp()
                })
                .collect()
        };
        let ring: Vec<f64> = (0..side * side)
            .map(|e| {
                let (x, y) = (((e % side) as f64 - h) / s, ((e / side) as f64 - h) / s);
                let d = (x * x + y * y).sqrt() - 2.0;
                0.01 * (-d * d).exp()
            })
            .collect();
        vec![bump(1.5, 0.3, 0.8, 0.02), ring]
    }

    #[test]
    fn shape_taps_are_the_cpu_paths_kernel() {
        let cases = [
            (
                Gaussian2::new(1.2, 0.9, 0.3),
                [0.0, 0.0],
                vec![1.0, 0.5],
                99,
            ),
            (
                Gaussian2::new(0.5, 0.4, 0.0),
                [0.0, 0.0],
                vec![-0.8, 1.0],
                99,
            ),
            (
                Gaussian2::new(2.1, 1.6, -0.5),
                [0.7, -1.3],
                vec![2.0, -0.3],
                99,
            ),
            // Coefficients that cut into the core: taps clipped at zero.
            (
                Gaussian2::new(1.0, 1.0, 0.0),
                [0.2, 0.0],
                vec![-9.0, -6.0],
                99,
            ),
            // Wider than the margin: cropped.
            (Gaussian2::new(2.6, 2.2, 0.4), [0.2, 0.1], vec![1.0, 1.0], 9),
            (Gaussian2::new(2.6, 2.2, 0.4), [0.2, 0.1], vec![1.0, 1.0], 8),
        ];
        for space in ShapeSpace::ALL {
            let comps = components(space);
            let combined = |c: &[f64]| -> Vec<f64> {
                (0..space.values())
                    .map(|e| c.iter().zip(&comps).map(|(c, b)| c * b[e]).sum())
                    .collect()
            };
            for (gaussian, offset, coefficients, max_size) in cases.clone() {
                let r = combined(&coefficients);
                let rendered =
                    crate::model::kernel_with_shape_at(space, &gaussian, Some(&r), 3, None, offset)
                        .expect("a kernel");
                let cpu = trimmed(cropped(crate::deblur::plane_kernel(&rendered, 1), max_size));
                let placed = PlacedShape {
                    gaussian,
                    offset,
                    coefficients,
                };
                let t = ShapeTaps::of_parts(space, &comps, placed, 3, max_size).expect("a shape");
                let made = trimmed(shape_taps(&t));
                let what = format!("{space:?} {gaussian:?} at {offset:?} cropped to {max_size}");
                assert_eq!(made.size, cpu.size, "{what}");
                for (p, q) in made.data.iter().zip(&cpu.data) {
                    assert!((p - q).abs() < 1e-12, "{what}: {p} against {q}");
                }
            }
        }
        let flat = PlacedShape {
            gaussian: Gaussian2::new(1.0, 1.0, 1.0),
            offset: [0.0; 2],
            coefficients: vec![1.0],
        };
        let comps = components(ShapeSpace::Whitened);
        assert_eq!(
            ShapeTaps::of_parts(ShapeSpace::Whitened, &comps, flat, 3, 99),
            None
        );
    }
}
