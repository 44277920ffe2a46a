//! The kernel-shape model: what a 2-D Gaussian leaves out of a lens's PSF (the comet tail
//! of coma, the halo of spherical aberration), predicted anywhere on the sensor at any
//! focal length and aperture.
//!
//! Each measured 3× kernel is first normalised by its own fitted Gaussian: resampled in
//! *whitened* coordinates w = Σ^{−½} p (Σ the Gaussian's covariance, its symmetric square
//! root), where that Gaussian becomes the unit normal φ(w). What remains, r(w) = k_w(w) −
//! φ(w) on a fixed grid, is the kernel's shape with its size and orientation taken out,
//! so kernels of 0.7 px and 3 px, round and elongated, are comparable. A low-dimensional
//! basis of these residuals (their leading right singular vectors, uncentred: the
//! coefficient fields carry the mean) is learnt from the session, and each coefficient is
//! modelled over (x, y, f, a) with the same normalised Legendre basis as the global
//! Gaussian model G_{α,β}.
//!
//! A prediction is the Gaussian model's Gaussian at the point, with the predicted
//! residual added in whitened coordinates and mapped back: a full kernel that is clipped
//! at zero and sums to one. With no components it *is* the Gaussian (sampled to 5σ).
//! Beyond the area the chart covered, the coefficients are held at their value on its
//! border (a shape continued linearly could grow without bound).

use super::basis::{Basis, Normalisation, model_basis, solve_lsq};
use super::{Dataset, ModelError, find_channel, global_coords};
use crate::plane::{Channel, LensSetting};
use crate::psf::{Gaussian2, Kernel};
use nalgebra::DMatrix;
use rand::SeedableRng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Half-width of the whitened grid, in σ of the kernel's Gaussian along each principal
/// axis.
pub const WHITENED_RADIUS: f64 = 5.0;
/// Whitened grid samples per σ.
pub const WHITENED_PER_SIGMA: usize = 3;
/// Samples per side of the whitened grid.
pub const WHITENED_SIDE: usize = 2 * (WHITENED_RADIUS as usize) * WHITENED_PER_SIGMA + 1;
/// Values in one whitened residual.
pub const WHITENED_LEN: usize = WHITENED_SIDE * WHITENED_SIDE;
/// Half-width of the pixel-space grid, px: as far as measured 3× kernels reach.
pub const PIXEL_RADIUS_PX: usize = 6;
/// Samples per side of the pixel-space grid (the kernels' own 3×).
pub const PIXEL_SIDE: usize = 2 * PIXEL_RADIUS_PX * 3 + 1;

/// Where a kernel's shape beyond its Gaussian is described. Cross-validation tries
/// both and keeps the better per lens.
///
/// Whitened: in the Gaussian's own coordinates, so shapes that scale with the blur
/// (a comet tail as long as the core is wide) are one component at every size; but a
/// halo much wider than the core (spherical aberration wide open, around a sharp
/// core) falls outside ±5σ of that core. Pixel: the residual on the 3× grid in sensor
/// pixels, ±6 px, whatever the core's size: it keeps such halos, at the price of more
/// components where shapes scale with the blur.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ShapeSpace {
    #[default]
    Whitened,
    Pixel,
}

impl ShapeSpace {
    pub const ALL: [ShapeSpace; 2] = [ShapeSpace::Whitened, ShapeSpace::Pixel];

    /// Samples per side of this space's grid.
    #[must_use]
    pub fn side(self) -> usize {
        match self {
            Self::Whitened => WHITENED_SIDE,
            Self::Pixel => PIXEL_SIDE,
        }
    }

    /// Values in one residual.
    #[must_use]
    pub fn values(self) -> usize {
        self.side() * self.side()
    }

    /// Grid samples per unit (σ or px).
    #[must_use]
    pub fn per_unit(self) -> usize {
        match self {
            Self::Whitened => WHITENED_PER_SIGMA,
            Self::Pixel => 3,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Whitened => "whitened",
            Self::Pixel => "pixel",
        }
    }
}
/// The most shape components a model holds.
pub const MAX_COMPONENTS: usize = 12;
/// Residuals the basis is learnt from, at most (an even subsample of the session's): a
/// basis of a dozen components is settled long before this many.
const BASIS_SAMPLES: usize = 6000;

/// Which kernel a profile predicts for deblurring.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum KernelModel {
    /// The Gaussian model's 2-D Gaussian.
    Gaussian,
    /// The Gaussian with the shape model's predicted residual.
    #[default]
    Shape,
}

impl KernelModel {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Gaussian => "gaussian",
            Self::Shape => "shape",
        }
    }
}

/// The symmetric square root A = Σ^{½} of a Gaussian's covariance and what goes with it.
#[derive(Clone, Copy, Debug)]
pub struct Whitening {
    /// p = A w.
    a: [[f64; 2]; 2],
    /// w = A⁻¹ p.
    a_inv: [[f64; 2]; 2],
    det_a: f64,
    /// Largest σ along a principal axis, px.
    sigma_max: f64,
}

impl Whitening {
    /// `None` for a degenerate covariance.
    #[must_use]
    pub fn of(g: &Gaussian2) -> Option<Self> {
        let (vx, vy, c) = (g.sigma_x * g.sigma_x, g.sigma_y * g.sigma_y, g.cov_xy());
        let det = vx * vy - c * c;
        if !(det.is_finite() && det > 1e-12 && vx > 0.0 && vy > 0.0) {
            return None;
        }
        // √M = (M + √det I) / √(tr M + 2√det) for a 2 × 2 symmetric positive definite M.
        let s = det.sqrt();
        let t = (vx + vy + 2.0 * s).sqrt();
        let a = [[(vx + s) / t, c / t], [c / t, (vy + s) / t]];
        let det_a = a[0][0] * a[1][1] - a[0][1] * a[1][0];
        let a_inv = [
            [a[1][1] / det_a, -a[0][1] / det_a],
            [-a[1][0] / det_a, a[0][0] / det_a],
        ];
        let half_tr = 0.5 * (vx + vy);
        let lambda_max = half_tr + (half_tr * half_tr - det).max(0.0).sqrt();
        Some(Self {
            a,
            a_inv,
            det_a,
            sigma_max: lambda_max.sqrt(),
        })
    }

    /// A⁻¹, symmetric: [xx, xy, yy].
    pub(crate) fn inverse(self) -> [f64; 3] {
        [self.a_inv[0][0], self.a_inv[0][1], self.a_inv[1][1]]
    }

    /// det A.
    pub(crate) fn det(self) -> f64 {
        self.det_a
    }

    fn to_px(self, w: [f64; 2]) -> [f64; 2] {
        [
            self.a[0][0] * w[0] + self.a[0][1] * w[1],
            self.a[1][0] * w[0] + self.a[1][1] * w[1],
        ]
    }

    fn to_white(self, p: [f64; 2]) -> [f64; 2] {
        [
            self.a_inv[0][0] * p[0] + self.a_inv[0][1] * p[1],
            self.a_inv[1][0] * p[0] + self.a_inv[1][1] * p[1],
        ]
    }
}

/// The unit normal density in whitened coordinates.
fn unit_normal(w: [f64; 2]) -> f64 {
    (-0.5 * (w[0] * w[0] + w[1] * w[1])).exp() / std::f64::consts::TAU
}

/// Coordinates (σ or px) of grid sample (i, j) of a space.
fn grid_point(space: ShapeSpace, i: usize, j: usize) -> [f64; 2] {
    let h = (space.side() / 2) as f64;
    let s = space.per_unit() as f64;
    [(i as f64 - h) / s, (j as f64 - h) / s]
}

/// Bilinear value of a space's grid at w (0 outside it).
fn grid_sample(space: ShapeSpace, grid: &[f64], w: [f64; 2]) -> f64 {
    let side = space.side();
    let h = (side / 2) as f64;
    let s = space.per_unit() as f64;
    crate::plane::bilinear_zero_outside(grid, side, w[0] * s + h, w[1] * s + h)
}

/// The part of a measured kernel the shape model describes: its central region (the
/// connected region above the estimator's cleaning threshold that holds the centre,
/// which is what its Gaussian was fitted to), normalised.
///
/// Specks apart from the core are noise the threshold let through, and all of it
/// positive (the estimator clips at zero), so it does not average out: kept, a
/// session's specks add up to a pedestal the shape components learn as a halo that no
/// lens made, larger in red and blue (half as many Bayer samples as green) than in
/// green. On the comet lens's measured chain that halo made the predicted kernels'
/// second moments 1.7 (green) to 2.5 times the true ones in the frame's centre and moved the
/// colour channels' sharpness apart: a fringe at every strong edge.
#[must_use]
pub fn psf_mass(kernel: &Kernel) -> Kernel {
    let mut k = Kernel {
        size: kernel.size,
        oversample: kernel.oversample,
        data: crate::gaussian::central_region(kernel, crate::gaussian::CLEAN_THRESHOLD),
    };
    k.normalise();
    k
}

/// A measured kernel's shape beyond its Gaussian, on a space's grid (row-major):
/// whitened, its density in the Gaussian's whitened coordinates minus the unit normal;
/// pixel, its density minus the Gaussian's, per px². Of the kernel's [`psf_mass`].
/// `None` when the Gaussian is degenerate.
#[must_use]
pub fn shape_residual(
    space: ShapeSpace,
    kernel: &Kernel,
    gaussian: &Gaussian2,
) -> Option<Vec<f64>> {
    let wh = Whitening::of(gaussian)?;
    let kernel = &psf_mass(kernel);
    // Kernel weights are per sample; per px² they are os² times larger.
    let os2 = (kernel.oversample * kernel.oversample) as f64;
    let side = space.side();
    let mut out = Vec::with_capacity(side * side);
    for j in 0..side {
        for i in 0..side {
            let q = grid_point(space, i, j);
            out.push(match space {
                ShapeSpace::Whitened => {
                    let p = wh.to_px(q);
                    wh.det_a * kernel.sample_px(p[0], p[1]) * os2 - unit_normal(q)
                }
                ShapeSpace::Pixel => {
                    kernel.sample_px(q[0], q[1]) * os2 - gaussian.density(q[0], q[1])
                }
            });
        }
    }
    Some(out)
}

/// [`shape_residual`] in the whitened space.
#[must_use]
pub fn whitened_residual(kernel: &Kernel, gaussian: &Gaussian2) -> Option<Vec<f64>> {
    shape_residual(ShapeSpace::Whitened, kernel, gaussian)
}

/// The kernel of a Gaussian with a whitened residual added (none: the Gaussian itself),
/// sampled at `oversample`× on a `size`-sample grid (`None`: wide enough for the grid's
/// 5σ), clipped at zero and normalised. `None` when the Gaussian is degenerate.
#[must_use]
pub fn kernel_with_residual(
    gaussian: &Gaussian2,
    residual: Option<&[f64]>,
    oversample: usize,
    size: Option<usize>,
) -> Option<Kernel> {
    kernel_with_shape(ShapeSpace::Whitened, gaussian, residual, oversample, size)
}

/// The side of the kernel [`kernel_with_shape`] renders when given no size (what
/// deblurring uses): ±5σ along the Gaussian's widest axis, at least ±6 px for a
/// pixel-space residual, within the largest kernel allowed.
fn deployed_side(space: ShapeSpace, wh: &Whitening, residual: bool, oversample: usize) -> usize {
    let limit = (crate::limits::MAX_KERNEL_RADIUS_PX * oversample as f64) as usize;
    let mut radius = WHITENED_RADIUS * wh.sigma_max;
    if space == ShapeSpace::Pixel && residual {
        radius = radius.max(PIXEL_RADIUS_PX as f64);
    }
    let half = (radius * oversample as f64).ceil() as usize;
    2 * half.min(limit) + 1
}

/// [`deployed_side`] of a shape model's kernels around `gaussian` (`None` when it is
/// degenerate).
pub(crate) fn deployed_kernel_side(
    space: ShapeSpace,
    gaussian: &Gaussian2,
    oversample: usize,
) -> Option<usize> {
    Some(deployed_side(
        space,
        &Whitening::of(gaussian)?,
        true,
        oversample.max(1),
    ))
}

/// [`kernel_with_residual`] for a residual in either space.
#[must_use]
pub fn kernel_with_shape(
    space: ShapeSpace,
    gaussian: &Gaussian2,
    residual: Option<&[f64]>,
    oversample: usize,
    size: Option<usize>,
) -> Option<Kernel> {
    kernel_with_shape_at(space, gaussian, residual, oversample, size, [0.0, 0.0])
}

/// [`kernel_with_shape`] with the whole predicted PSF moved by `offset` px: rendered at
/// its place (the Gaussian exactly, the residual read where it lands), the deployed
/// grid grown by the offset.
#[must_use]
pub fn kernel_with_shape_at(
    space: ShapeSpace,
    gaussian: &Gaussian2,
    residual: Option<&[f64]>,
    oversample: usize,
    size: Option<usize>,
    offset: [f64; 2],
) -> Option<Kernel> {
    let wh = Whitening::of(gaussian)?;
    let os = oversample.max(1);
    let size = size.unwrap_or_else(|| {
        let grow = (offset[0].abs().max(offset[1].abs()) * os as f64).ceil() as usize;
        deployed_side(space, &wh, residual.is_some(), os) + 2 * grow
    });
    let size = size | 1;
    let c = (size / 2) as f64;
    let mut data = Vec::with_capacity(size * size);
    for j in 0..size {
        for i in 0..size {
            let p = [
                (i as f64 - c) / os as f64 - offset[0],
                (j as f64 - c) / os as f64 - offset[1],
            ];
            // Both spaces' values are densities in their own units; the kernel is
            // normalised below, so the whitened space's 1/det A drops out.
            let value = match space {
                ShapeSpace::Whitened => {
                    let w = wh.to_white(p);
                    unit_normal(w) + residual.map_or(0.0, |r| grid_sample(space, r, w))
                }
                ShapeSpace::Pixel => {
                    gaussian.density(p[0], p[1])
                        + residual.map_or(0.0, |r| grid_sample(space, r, p))
                }
            };
            data.push(value.max(0.0));
        }
    }
    let mut k = Kernel {
        size,
        oversample: os,
        data,
    };
    k.normalise();
    Some(k)
}

/// Relative L2 distance ‖predicted − measured‖ / ‖measured‖ on the measured kernel's
/// grid (both summing to one): the error the shape model is judged by.
#[must_use]
pub fn relative_l2(predicted: &Kernel, measured: &Kernel) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    let half_m = (measured.size / 2) as isize;
    let half_p = (predicted.size / 2) as isize;
    for j in 0..measured.size {
        for i in 0..measured.size {
            let m = measured.at(i, j);
            let (pi, pj) = (i as isize - half_m + half_p, j as isize - half_m + half_p);
            let p = if pi >= 0
                && pj >= 0
                && (pi as usize) < predicted.size
                && (pj as usize) < predicted.size
            {
                predicted.at(pi as usize, pj as usize)
            } else {
                0.0
            };
            num += (p - m) * (p - m);
            den += m * m;
        }
    }
    // Predicted mass outside the measured grid counts as error too.
    let inside: f64 = (0..measured.size)
        .flat_map(|j| (0..measured.size).map(move |i| (i, j)))
        .map(|(i, j)| {
            let (pi, pj) = (i as isize - half_m + half_p, j as isize - half_m + half_p);
            if pi >= 0
                && pj >= 0
                && (pi as usize) < predicted.size
                && (pj as usize) < predicted.size
            {
                predicted.at(pi as usize, pj as usize).powi(2)
            } else {
                0.0
            }
        })
        .sum();
    let outside = (predicted.data.iter().map(|v| v * v).sum::<f64>() - inside).max(0.0);
    if den > 0.0 {
        ((num + outside) / den).sqrt()
    } else {
        f64::INFINITY
    }
}

/// One Gaussian's kernels as [`kernel_with_shape`] renders them on one grid, prepared
/// for many residuals that are sums of the same components: each grid sample's density
/// of the Gaussian, and each component's value there. Rendering then costs a weighted
/// sum per sample instead of a whitening, an exponential and a bilinear look-up per
/// sample and residual; cross-validation renders every held-out kernel for every
/// model it tries. Bilinear sampling is linear in the grid's values, so this is
/// [`kernel_with_shape`] of the combined residual up to rounding.
pub(crate) struct PreparedKernels {
    base: Vec<f64>,
    /// Per component, its value at every sample of the kernel's grid.
    sampled: Vec<Vec<f64>>,
}

impl PreparedKernels {
    /// The `size`-sample grid (made odd, as [`kernel_with_shape`] does) at `oversample`×
    /// around `gaussian`, with `components` residuals of `space`, zero outside the
    /// centred `deployed`-sample window: the kernel deblurring renders, on a grid it
    /// can be compared on. `None` when the Gaussian is degenerate.
    pub(crate) fn new(
        space: ShapeSpace,
        gaussian: &Gaussian2,
        components: &[Vec<f64>],
        oversample: usize,
        size: usize,
        deployed: usize,
    ) -> Option<Self> {
        let wh = Whitening::of(gaussian)?;
        let os = oversample.max(1) as f64;
        let size = size | 1;
        let c = (size / 2) as f64;
        let side = space.side();
        let h = (side / 2) as f64;
        let per_unit = space.per_unit() as f64;
        let mut base = Vec::with_capacity(size * size);
        let mut sampled = vec![Vec::with_capacity(size * size); components.len()];
        let reach = (deployed / 2) as f64;
        for j in 0..size {
            for i in 0..size {
                if (i as f64 - c).abs() > reach || (j as f64 - c).abs() > reach {
                    base.push(0.0);
                    for out in &mut sampled {
                        out.push(0.0);
                    }
                    continue;
                }
                let p = [(i as f64 - c) / os, (j as f64 - c) / os];
                let (q, density) = match space {
                    ShapeSpace::Whitened => {
                        let w = wh.to_white(p);
                        (w, unit_normal(w))
                    }
                    ShapeSpace::Pixel => (p, gaussian.density(p[0], p[1])),
                };
                base.push(density);
                let (u, w) = (q[0] * per_unit + h, q[1] * per_unit + h);
                // Beyond the components' grid (most of a wide kernel's samples) every
                // tap weighs nothing.
                if u < -1.0 || w < -1.0 || u >= side as f64 || w >= side as f64 {
                    for out in &mut sampled {
                        out.push(0.0);
                    }
                    continue;
                }
                let taps = bilinear_taps(side, u, w);
                for (out, comp) in sampled.iter_mut().zip(components) {
                    out.push(taps.iter().map(|&(idx, w)| w * comp[idx]).sum());
                }
            }
        }
        Some(Self { base, sampled })
    }

    /// The Gaussian's values on the grid: a residual of no components.
    pub(crate) fn base(&self) -> &[f64] {
        &self.base
    }

    /// How many components were prepared.
    pub(crate) fn components(&self) -> usize {
        self.sampled.len()
    }

    /// Component `k`'s values on the grid.
    pub(crate) fn component(&self, k: usize) -> &[f64] {
        &self.sampled[k]
    }

    /// Adds components `range` with their `coeffs` (indexed as the components) to
    /// `values`.
    pub(crate) fn add(&self, values: &mut [f64], range: std::ops::Range<usize>, coeffs: &[f64]) {
        for k in range {
            let ck = coeffs[k];
            for (v, s) in values.iter_mut().zip(&self.sampled[k]) {
                *v += ck * s;
            }
        }
    }

    /// [`relative_l2`] against `measured` (of the grid's size) of the kernel whose values
    /// before clipping and normalising are `values`. Its sums run over eight lanes, so
    /// they vectorise: the result differs from [`relative_l2`]'s in the last bits.
    pub(crate) fn relative_l2(values: &[f64], measured: &Kernel) -> f64 {
        let m = &measured.data[..values.len().min(measured.data.len())];
        let s = lane_sum(values, m, |v, _| v.max(0.0));
        let inv = if s > 0.0 { 1.0 / s } else { 1.0 };
        let num = lane_sum(values, m, |v, m| {
            let d = v.max(0.0) * inv - m;
            d * d
        });
        let den = lane_sum(m, m, |m, _| m * m);
        // Both grids are the same size, so no predicted mass lies outside the measured
        // one (relative_l2's margin term is zero).
        if den > 0.0 {
            (num / den).sqrt()
        } else {
            f64::INFINITY
        }
    }
}

/// Σ f(aᵢ, bᵢ) over eight interleaved partial sums, which the compiler keeps in vector
/// registers (one running sum is a chain of dependent additions).
#[inline]
fn lane_sum(a: &[f64], b: &[f64], f: impl Fn(f64, f64) -> f64) -> f64 {
    let mut lanes = [0.0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            lanes[l] += f(x[l], y[l]);
        }
    }
    for (l, (&x, &y)) in ra.iter().zip(rb).enumerate() {
        lanes[l] += f(x, y);
    }
    lanes.iter().sum()
}

/// The (index, weight) pairs of a bilinear look-up at grid coordinates (u, w) on a
/// `side × side` grid, as `plane::bilinear_zero_outside` weighs them: taps outside the
/// grid weigh nothing.
fn bilinear_taps(side: usize, u: f64, w: f64) -> [(usize, f64); 4] {
    let (u0, w0) = (u.floor(), w.floor());
    let (fx, fy) = (u - u0, w - w0);
    let n = side as f64;
    let tap = |i: f64, j: f64, weight: f64| {
        if i < 0.0 || j < 0.0 || i >= n || j >= n {
            (0, 0.0)
        } else {
            (j as usize * side + i as usize, weight)
        }
    };
    [
        tap(u0, w0, (1.0 - fx) * (1.0 - fy)),
        tap(u0 + 1.0, w0, fx * (1.0 - fy)),
        tap(u0, w0 + 1.0, (1.0 - fx) * fy),
        tap(u0 + 1.0, w0 + 1.0, fx * fy),
    ]
}

/// The whitened residual of every sample of a session that kept its kernel (aligned
/// with `ds.samples`; `None` where it has none or its Gaussian is degenerate), stored
/// as `f32`: a 50-shot session has tens of thousands.
#[must_use]
pub fn session_residuals(ds: &Dataset, space: ShapeSpace) -> Vec<Option<Vec<f32>>> {
    use rayon::prelude::*;
    ds.samples
        .par_iter()
        .map(|s| {
            let k = s.kernel.as_ref()?;
            let r = shape_residual(space, k, &s.gaussian)?;
            Some(r.iter().map(|&v| v as f32).collect())
        })
        .collect()
}

/// The leading `components` right singular vectors of the residuals (rows) picked by
/// `rows`: randomised subspace iteration (seeded, so deterministic) on at most
/// [`BASIS_SAMPLES`] of them, evenly spread. Orthonormal, each as long as a row.
#[must_use]
pub fn shape_basis(residuals: &[&[f32]], components: usize) -> Vec<Vec<f64>> {
    let k = components.min(MAX_COMPONENTS);
    if k == 0 || residuals.is_empty() {
        return Vec::new();
    }
    let stride = residuals.len().div_ceil(BASIS_SAMPLES).max(1);
    let rows: Vec<&[f32]> = residuals.iter().step_by(stride).copied().collect();
    let n = rows.len();
    let dims = rows[0].len();
    let x = DMatrix::from_fn(n, dims, |r, c| f64::from(rows[r][c]));
    let width = (k + 8).min(n).min(dims);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x5a4e_1b07);
    let omega = DMatrix::from_fn(dims, width, |_, _| {
        rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng)
    });
    let mut q = (&x * omega).qr().q();
    // Transposed once: the products below are then what they were with a transpose
    // each, without copying the matrix every time.
    let xt = x.transpose();
    // Power iterations sharpen the subspace where the spectrum decays slowly.
    for _ in 0..3 {
        let z = (&xt * &q).qr().q();
        q = (&x * z).qr().q();
    }
    let b = q.transpose() * &x;
    let svd = b.svd(false, true);
    let Some(vt) = svd.v_t else {
        return Vec::new();
    };
    // Singular values come unordered from nalgebra's SVD: take the largest first.
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    order
        .into_iter()
        .take(k)
        .map(|r| vt.row(r).iter().copied().collect())
        .collect()
}

/// A fitted kernel-shape model.
#[derive(Clone, Debug)]
pub struct ShapeModel {
    pub space: ShapeSpace,
    pub norm: Normalisation,
    /// Orders of the coefficient fields, as G_{α,β}'s.
    pub alpha: usize,
    pub beta: usize,
    pub basis: Basis,
    /// The shape components, each one residual on the space's grid.
    pub components: Vec<Vec<f64>>,
    /// Per channel, per component: coefficients over `basis`.
    pub channels: Vec<(Channel, Vec<Vec<f64>>)>,
}

impl ShapeModel {
    /// Fits the first `components` shape components of `ds`'s kernels and their
    /// coefficient fields of orders (α, β). `residuals` are [`session_residuals`] of `ds`
    /// in `space`.
    ///
    /// # Errors
    /// Orders the session cannot support, no kernels, or fewer kernels of a channel
    /// than terms.
    pub fn fit(
        ds: &Dataset,
        space: ShapeSpace,
        residuals: &[Option<Vec<f32>>],
        alpha: usize,
        beta: usize,
        components: usize,
    ) -> Result<Self, ModelError> {
        let fit = ShapeFit::new(ds, space, residuals, components)?;
        fit.model(ds, alpha, beta)
    }

    /// Number of shape components.
    #[must_use]
    pub fn len(&self) -> usize {
        self.components.len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.components.is_empty()
    }

    /// The predicted coefficients of a channel at a sensor point and setting; the
    /// point is held to the area the chart covered.
    #[must_use]
    pub fn coefficients(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        s: LensSetting,
    ) -> Option<Vec<f64>> {
        let (_, coeffs) = find_channel(&self.channels, channel, |c| c.0)?;
        let (x, y) = match self.norm.sampled_extent_px {
            Some(e) => (x.clamp(e[0], e[2]), y.clamp(e[1], e[3])),
            None => (x, y),
        };
        let mut row = vec![0.0; self.basis.len()];
        self.basis.row(
            global_coords(&self.norm, x, y, s.focal_mm, s.f_number),
            &mut row,
        );
        Some(
            coeffs
                .iter()
                .map(|c| c.iter().zip(&row).map(|(a, b)| a * b).sum())
                .collect(),
        )
    }

    /// The predicted whitened residual of a channel at a point and setting.
    #[must_use]
    pub fn residual(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<Vec<f64>> {
        let c = self.coefficients(channel, x, y, s)?;
        Some(combine(self.space.values(), &self.components, &c))
    }

    /// The predicted kernel: `gaussian` (the Gaussian model's prediction at the point)
    /// with the predicted shape, at `oversample`×.
    #[must_use]
    pub fn kernel(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        s: LensSetting,
        gaussian: &Gaussian2,
        oversample: usize,
    ) -> Option<Kernel> {
        self.kernel_moved(channel, [x, y], s, gaussian, oversample, [0.0, 0.0])
    }

    /// [`ShapeModel::kernel`] moved by `offset` px: rendered at its place, so the
    /// move neither blurs nor reshapes it.
    #[must_use]
    pub fn kernel_moved(
        &self,
        channel: Channel,
        [x, y]: [f64; 2],
        s: LensSetting,
        gaussian: &Gaussian2,
        oversample: usize,
        offset: [f64; 2],
    ) -> Option<Kernel> {
        let placed = self.placed(channel, [x, y], s, gaussian, offset)?;
        self.kernel_of(&placed, oversample)
    }

    /// The parts of [`ShapeModel::kernel_moved`]'s kernel: its Gaussian, its move and
    /// the predicted coefficients.
    #[must_use]
    pub fn placed(
        &self,
        channel: Channel,
        [x, y]: [f64; 2],
        s: LensSetting,
        gaussian: &Gaussian2,
        offset: [f64; 2],
    ) -> Option<PlacedShape> {
        Some(PlacedShape {
            gaussian: *gaussian,
            offset,
            coefficients: self.coefficients(channel, x, y, s)?,
        })
    }

    /// The kernel of a placed shape at `oversample`×: its Gaussian with the residual its
    /// coefficients combine, moved, on the deployed grid.
    #[must_use]
    pub fn kernel_of(&self, placed: &PlacedShape, oversample: usize) -> Option<Kernel> {
        let r = combine(self.space.values(), &self.components, &placed.coefficients);
        kernel_with_shape_at(
            self.space,
            &placed.gaussian,
            Some(&r),
            oversample,
            None,
            placed.offset,
        )
    }
}

/// A shape model's kernel at one place, as its parts: the Gaussian it shapes, how far
/// the whole is moved (px), and the shape's coefficients over the model's components.
/// [`ShapeModel::kernel_of`] renders it; a GPU makes the same taps from these numbers
/// and the components, uploaded once.
#[derive(Clone, Debug, PartialEq)]
pub struct PlacedShape {
    pub gaussian: Gaussian2,
    pub offset: [f64; 2],
    pub coefficients: Vec<f64>,
}

/// Σ c_i b_i.
fn combine(len: usize, components: &[Vec<f64>], coeffs: &[f64]) -> Vec<f64> {
    let mut r = vec![0.0; len];
    for (b, &c) in components.iter().zip(coeffs) {
        for (acc, v) in r.iter_mut().zip(b) {
            *acc += c * v;
        }
    }
    r
}

/// A shape basis learnt from a session and every sample's coordinates in it: fitting the
/// coefficient fields at several orders (cross-validation does) reuses both.
pub struct ShapeFit {
    /// The space of the residuals it was learnt from.
    pub space: ShapeSpace,
    pub components: Vec<Vec<f64>>,
    /// Per sample of the session (aligned with `ds.samples`): its coefficients, where
    /// it has a residual.
    pub coords: Vec<Option<Vec<f64>>>,
}

impl ShapeFit {
    /// Learns `components` components from the residuals.
    ///
    /// # Errors
    /// [`ModelError::Empty`] when no sample kept a kernel.
    pub fn new(
        ds: &Dataset,
        space: ShapeSpace,
        residuals: &[Option<Vec<f32>>],
        components: usize,
    ) -> Result<Self, ModelError> {
        let rows: Vec<&[f32]> = residuals.iter().flatten().map(Vec::as_slice).collect();
        if rows.is_empty() || residuals.len() != ds.samples.len() {
            return Err(ModelError::Empty);
        }
        let components = shape_basis(&rows, components);
        let coords = residuals
            .par_iter()
            .map(|r| {
                r.as_ref().map(|r| {
                    components
                        .iter()
                        .map(|b| b.iter().zip(r).map(|(a, &v)| a * f64::from(v)).sum())
                        .collect()
                })
            })
            .collect();
        Ok(Self {
            space,
            components,
            coords,
        })
    }

    /// The coefficient fields of orders (α, β) over the samples of `ds` that have
    /// coordinates, all components.
    ///
    /// # Errors
    /// Orders the session cannot support, or fewer kernels of a channel than terms.
    pub fn model(&self, ds: &Dataset, alpha: usize, beta: usize) -> Result<ShapeModel, ModelError> {
        super::check_order(alpha, beta)?;
        ds.check_beta(beta)?;
        let norm = ds.normalisation();
        let basis = model_basis(&norm, alpha, beta);
        let k = self.components.len();
        // Channels in parallel; each is its own least-squares problem.
        let fitted = ds.channels().into_par_iter().map(|ch| {
            let rows: Vec<(&super::BlurSample, &Vec<f64>)> = ds
                .samples
                .iter()
                .zip(&self.coords)
                .filter(|(s, _)| s.channel == ch)
                .filter_map(|(s, c)| c.as_ref().map(|c| (s, c)))
                .collect();
            if rows.is_empty() {
                return Ok(None);
            }
            if rows.len() < basis.len() {
                return Err(ModelError::TooFewSamples {
                    model: format!("the kernel-shape model of order {alpha}, {beta} ({ch})"),
                    samples: rows.len(),
                    terms: basis.len(),
                });
            }
            let mut a = DMatrix::zeros(rows.len(), basis.len());
            let mut y = DMatrix::zeros(rows.len(), k);
            let mut row = vec![0.0; basis.len()];
            for (r, (s, c)) in rows.iter().enumerate() {
                basis.row(
                    global_coords(&norm, s.x, s.y, s.focal_mm, s.f_number),
                    &mut row,
                );
                for (col, v) in row.iter().enumerate() {
                    a[(r, col)] = *v;
                }
                for (col, v) in c.iter().enumerate() {
                    y[(r, col)] = *v;
                }
            }
            let coeffs = if k == 0 {
                Vec::new()
            } else {
                let x = solve_lsq(a, &y);
                (0..k)
                    .map(|col| x.column(col).iter().copied().collect())
                    .collect()
            };
            Ok(Some((ch, coeffs)))
        });
        // The first channel's error in channel order, whichever thread met it first.
        let channels: Vec<(Channel, Vec<Vec<f64>>)> = fitted
            .collect::<Vec<Result<_, ModelError>>>()
            .into_iter()
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .flatten()
            .collect();
        if channels.is_empty() {
            return Err(ModelError::Empty);
        }
        Ok(ShapeModel {
            space: self.space,
            norm,
            alpha,
            beta,
            basis,
            components: self.components.clone(),
            channels,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gaussian_kernel_has_no_residual_and_comes_back_as_itself() {
        let g = Gaussian2::new(1.4, 0.9, 0.35);
        let k = g.kernel(3);
        let r = whitened_residual(&k, &g).expect("whitens");
        let peak = unit_normal([0.0, 0.0]);
        let worst = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // Bilinear resampling of the 3× samples is all that separates them.
        assert!(
            worst < 0.03 * peak,
            "largest residual {worst} of peak {peak}"
        );
        let back = kernel_with_residual(&g, None, 3, Some(k.size)).expect("renders");
        assert!(relative_l2(&back, &k) < 1e-9, "{}", relative_l2(&back, &k));
    }

    #[test]
    fn the_residual_carries_a_tail_back_into_the_kernel() {
        let g = Gaussian2::new(1.1, 1.0, -0.2);
        // A core with a tail to the right.
        let tail = Gaussian2::isotropic(0.8);
        let k = Kernel::from_fn(31, 3, |dx, dy| {
            g.density(dx, dy) + 0.3 * tail.density(dx - 2.5, dy)
        });
        let r = whitened_residual(&k, &g).expect("whitens");
        let back = kernel_with_residual(&g, Some(&r), 3, Some(k.size)).expect("renders");
        let plain = kernel_with_residual(&g, None, 3, Some(k.size)).expect("renders");
        let with = relative_l2(&back, &k);
        let without = relative_l2(&plain, &k);
        assert!(with < 0.05, "round trip error {with}");
        assert!(without > 0.2, "a Gaussian should miss the tail: {without}");
    }

    #[test]
    fn noise_apart_from_the_core_is_not_part_of_the_shape() {
        let g = Gaussian2::new(1.1, 1.0, -0.2);
        let tail = Gaussian2::isotropic(0.8);
        let mut k = Kernel::from_fn(31, 3, |dx, dy| {
            g.density(dx, dy) + 0.3 * tail.density(dx - 2.5, dy)
        });
        // As the estimator leaves it: nothing below its threshold.
        let peak = k.data.iter().copied().fold(0.0, f64::max);
        for v in &mut k.data {
            if *v <= crate::gaussian::CLEAN_THRESHOLD * peak {
                *v = 0.0;
            }
        }
        k.normalise();
        let clean = shape_residual(ShapeSpace::Whitened, &k, &g).expect("whitens");
        // Specks of noise above the threshold wherever the kernel is zero around them
        // (so apart from the core and its tail and from each other), every third
        // sample: the pedestal the estimator's clipped noise leaves.
        let mut specked = k.clone();
        let n = k.size;
        let zero_around = |i: usize, j: usize| {
            (i.saturating_sub(1)..=(i + 1).min(n - 1))
                .all(|a| (j.saturating_sub(1)..=(j + 1).min(n - 1)).all(|b| k.at(a, b) == 0.0))
        };
        let mut specks = 0;
        for j in (0..n).step_by(3) {
            for i in (0..n).step_by(3) {
                if zero_around(i, j) {
                    specked.data[j * n + i] = 0.04 * peak;
                    specks += 1;
                }
            }
        }
        assert!(specks > 20, "{specks} specks");
        specked.normalise();
        let with = shape_residual(ShapeSpace::Whitened, &specked, &g).expect("whitens");
        let worst = clean
            .iter()
            .zip(&with)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-12, "specks moved the residual by {worst}");
        // The PSF mass is the core and its tail, sample for sample.
        let mass = psf_mass(&specked);
        assert_eq!(
            mass.data.iter().filter(|&&v| v > 0.0).count(),
            k.data.iter().filter(|&&v| v > 0.0).count()
        );
        // And the specks are not too faint to matter: taken as PSF mass, they would
        // widen the kernel.
        let (before, after) = (k.moments(), specked.moments());
        let grown = (after.var_x + after.var_y) / (before.var_x + before.var_y);
        assert!(
            grown > 1.2,
            "the specks are too faint to test anything: {grown}"
        );
    }

    #[test]
    fn whitening_is_the_symmetric_square_root() {
        let g = Gaussian2::new(2.0, 0.7, 0.6);
        let wh = Whitening::of(&g).expect("positive definite");
        let a = wh.a;
        // A A = Σ.
        let s = [
            [
                a[0][0] * a[0][0] + a[0][1] * a[1][0],
                a[0][0] * a[0][1] + a[0][1] * a[1][1],
            ],
            [
                a[1][0] * a[0][0] + a[1][1] * a[1][0],
                a[1][0] * a[0][1] + a[1][1] * a[1][1],
            ],
        ];
        assert!((s[0][0] - 4.0).abs() < 1e-12);
        assert!((s[1][1] - 0.49).abs() < 1e-12);
        assert!((s[0][1] - g.cov_xy()).abs() < 1e-12);
        assert!((a[0][1] - a[1][0]).abs() < 1e-15);
        let p = wh.to_px(wh.to_white([0.3, -1.2]));
        assert!((p[0] - 0.3).abs() < 1e-12 && (p[1] + 1.2).abs() < 1e-12);
    }
}
