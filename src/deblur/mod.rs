//! Deblurring: non-blind deconvolution of each channel plane with the lens's spatially
//! varying kernels (DESIGN.md §1.9).
//!
//! The image is cut into overlapping tiles on a 50 %-overlap grid; each tile (plus a
//! margin) is deconvolved with the kernel at its centre and blended back with squared-sine
//! windows, which sum to one, so no seam shows. Tiles are independent: they run in
//! parallel and only one row of tiles is held at a time.

pub mod fft;
pub mod solve;
pub mod source;

pub use solve::{HqsParams, IrlsParams, Method, WienerParams};
pub use source::{
    ConstantKernel, KernelSource, KernelsFile, ProfileKernels, ScatteredKernels, SourceError,
};

use crate::job::{Cancelled, JobContext};
use crate::plane::{Capture, ChannelPlane, Plane};
use crate::psf::Kernel;
use fft::{Fft2, fast_size};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

#[derive(Debug, thiserror::Error)]
pub enum DeblurError {
    #[error("cancelled")]
    Cancelled(#[from] Cancelled),
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error("empty image")]
    Empty,
}

/// How to deblur.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeblurOptions {
    pub method: Method,
    /// Tile core size in plane pixels (even); `None` picks it from the kernel size.
    pub tile_core: Option<usize>,
}

/// The tile grid of one plane: cores of `core` pixels every `core / 2`, each read with a
/// `margin` on every side into an FFT block of `block` pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGrid {
    pub core: usize,
    pub margin: usize,
    pub block: usize,
}

impl TileGrid {
    /// Tiles for kernels of at most `radius_px` plane pixels: the margin holds the
    /// deconvolution's ringing from the block's own edges (a few kernel radii), the core
    /// is large enough that the margin is not most of the work.
    #[must_use]
    pub fn for_radius(radius_px: usize, core: Option<usize>) -> Self {
        let margin = (4 * radius_px + 8).max(16);
        let want_core = core.unwrap_or((12 * radius_px).clamp(96, 512));
        let block = fast_size(want_core + 2 * margin);
        let core = (block - 2 * margin) & !1;
        Self {
            core,
            margin,
            block,
        }
    }

    #[must_use]
    pub fn step(&self) -> usize {
        self.core / 2
    }

    /// Core origins along an axis of `n` pixels: from −step so the first pixel sits at
    /// a window's peak.
    #[must_use]
    pub fn origins(&self, n: usize) -> Vec<isize> {
        let s = self.step() as isize;
        let mut v = Vec::new();
        let mut x0 = -s;
        while x0 < n as isize {
            v.push(x0);
            x0 += s;
        }
        v
    }

    /// Blend window over a core: sin²(π t / core); shifted copies a half core apart sum
    /// to exactly one.
    #[must_use]
    pub fn window(&self) -> Vec<f64> {
        (0..self.core)
            .map(|t| {
                (std::f64::consts::PI * t as f64 / self.core as f64)
                    .sin()
                    .powi(2)
            })
            .collect()
    }
}

/// Half-sample symmetric reflection of an index into [0, n), repeated as needed.
#[inline]
fn reflect(i: isize, n: usize) -> usize {
    let n2 = 2 * n as isize;
    let m = i.rem_euclid(n2);
    if m >= n as isize {
        (n2 - 1 - m) as usize
    } else {
        m as usize
    }
}

/// The kernel as seen on a plane whose pixels are `step` sensor pixels apart, at 1×:
/// each plane-pixel weight averages the sensor kernel over that pixel's footprint.
#[must_use]
pub fn plane_kernel(k: &Kernel, step: usize) -> Kernel {
    if step <= 1 {
        return k.resampled(1);
    }
    let s = step as f64;
    let half = (k.radius_px() / s).ceil() as usize;
    let sub = 4 * step;
    Kernel::from_fn(2 * half + 1, 1, |dx, dy| {
        let mut acc = 0.0;
        for b in 0..sub {
            for a in 0..sub {
                let ox = (a as f64 + 0.5) / sub as f64 - 0.5;
                let oy = (b as f64 + 0.5) / sub as f64 - 0.5;
                acc += k.sample_px((dx + ox) * s, (dy + oy) * s);
            }
        }
        acc
    })
}

/// Reads a `block × block` region with top-left plane pixel (x0, y0) (may lie outside:
/// reflected), then tapers its borders toward the kernel-blurred copy so the block is
/// consistent with a circular blur and the solver does not ring at its edges.
fn read_block(
    plane: &Plane,
    x0: isize,
    y0: isize,
    grid: &TileGrid,
    fft: &Fft2,
    k: &Kernel,
) -> Vec<f64> {
    let n = grid.block;
    let mut b = vec![0.0; n * n];
    for j in 0..n {
        let sy = reflect(y0 + j as isize, plane.height);
        let row = &plane.data[sy * plane.width..(sy + 1) * plane.width];
        for i in 0..n {
            b[j * n + i] = f64::from(row[reflect(x0 + i as isize, plane.width)]);
        }
    }
    let blurred = fft.convolve(&b, k);
    let taper = (k.size + 4).min(grid.margin);
    let ramp = |t: usize| -> f64 {
        let d = t.min(n - 1 - t);
        if d >= taper {
            1.0
        } else {
            (std::f64::consts::FRAC_PI_2 * d as f64 / taper as f64)
                .sin()
                .powi(2)
        }
    };
    for j in 0..n {
        let ry = ramp(j);
        for i in 0..n {
            let a = ry * ramp(i);
            let idx = j * n + i;
            b[idx] = a * b[idx] + (1.0 - a) * blurred[idx];
        }
    }
    b
}

/// Deconvolves a whole plane with one kernel (already at plane resolution, 1×) through
/// the same tiler: the spatially invariant baseline.
///
/// # Errors
/// Only on cancellation.
pub fn deblur_plane_invariant(
    plane: &Plane,
    k: &Kernel,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Plane, DeblurError> {
    let k = k.resampled(1);
    deblur_plane_with(
        plane,
        &|_x: f64, _y: f64| Ok(k.clone()),
        k.size / 2,
        opts,
        job,
    )
}

/// Deblurs one channel plane of a capture with the kernels of `source` (asked in sensor
/// coordinates, at each tile's centre).
///
/// # Errors
/// When the source cannot supply a kernel, or on cancellation.
pub fn deblur_channel_plane(
    cp: &ChannelPlane,
    sensor_width: usize,
    sensor_height: usize,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Plane, DeblurError> {
    let plane = &cp.plane;
    if plane.width == 0 || plane.height == 0 {
        return Err(DeblurError::Empty);
    }
    // Largest kernel over the plane: probe centre, edges and corners.
    let mut radius = 1usize;
    for &(fx, fy) in &[
        (0.5, 0.5),
        (0.0, 0.0),
        (1.0, 0.0),
        (0.0, 1.0),
        (1.0, 1.0),
        (0.5, 0.0),
        (0.0, 0.5),
        (1.0, 0.5),
        (0.5, 1.0),
    ] {
        let x = fx * (sensor_width.max(1) - 1) as f64;
        let y = fy * (sensor_height.max(1) - 1) as f64;
        let k = plane_kernel(&source.kernel_at(cp.channel, x, y)?, cp.step);
        radius = radius.max(k.size / 2);
    }
    let at = |i: f64, j: f64| -> Result<Kernel, DeblurError> {
        let [x, y] = cp.sensor_from_plane(i, j);
        let x = x.clamp(0.0, (sensor_width.max(1) - 1) as f64);
        let y = y.clamp(0.0, (sensor_height.max(1) - 1) as f64);
        Ok(plane_kernel(&source.kernel_at(cp.channel, x, y)?, cp.step))
    };
    deblur_plane_with(plane, &at, radius, opts, job)
}

type KernelAt<'a> = dyn Fn(f64, f64) -> Result<Kernel, DeblurError> + Sync + 'a;

fn deblur_plane_with(
    plane: &Plane,
    kernel_at: &KernelAt<'_>,
    radius: usize,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Plane, DeblurError> {
    let (w, h) = (plane.width, plane.height);
    if w == 0 || h == 0 {
        return Err(DeblurError::Empty);
    }
    let grid = TileGrid::for_radius(radius, opts.tile_core);
    let fft = Fft2::new(grid.block, grid.block);
    let window = grid.window();
    let xs = grid.origins(w);
    let ys = grid.origins(h);
    let total = xs.len() * ys.len();
    let done = AtomicUsize::new(0);
    let mut out = vec![0.0f64; w * h];
    let core = grid.core;
    for &y0 in &ys {
        let row: Vec<Vec<f64>> = xs
            .par_iter()
            .map(|&x0| -> Result<Vec<f64>, DeblurError> {
                job.check()?;
                let cx = (x0 as f64 + (core as f64 - 1.0) / 2.0).clamp(0.0, (w - 1) as f64);
                let cy = (y0 as f64 + (core as f64 - 1.0) / 2.0).clamp(0.0, (h - 1) as f64);
                let mut k = kernel_at(cx, cy)?;
                if k.size > grid.block / 2 {
                    // A kernel wider than the margin can hold would wrap: crop it.
                    let keep = (grid.block / 2) | 1;
                    let off = (k.size - keep) / 2;
                    let mut data = Vec::with_capacity(keep * keep);
                    for j in 0..keep {
                        for i in 0..keep {
                            data.push(k.at(i + off, j + off));
                        }
                    }
                    k = Kernel {
                        size: keep,
                        oversample: 1,
                        data,
                    };
                    k.normalise();
                }
                let m = grid.margin as isize;
                let block = read_block(plane, x0 - m, y0 - m, &grid, &fft, &k);
                let x = solve::deconvolve_block(&fft, &block, &k, &opts.method);
                let mut tile = vec![0.0; core * core];
                for j in 0..core {
                    for i in 0..core {
                        tile[j * core + i] = x[(j + grid.margin) * grid.block + i + grid.margin]
                            * window[i]
                            * window[j];
                    }
                }
                let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                job.report("deblur", n, total);
                Ok(tile)
            })
            .collect::<Result<_, _>>()?;
        for (tile, &x0) in row.iter().zip(&xs) {
            for j in 0..core {
                let y = y0 + j as isize;
                if y < 0 || y >= h as isize {
                    continue;
                }
                for i in 0..core {
                    let x = x0 + i as isize;
                    if x < 0 || x >= w as isize {
                        continue;
                    }
                    out[y as usize * w + x as usize] += tile[j * core + i];
                }
            }
        }
    }
    Ok(Plane {
        width: w,
        height: h,
        data: out.into_iter().map(|v| v as f32).collect(),
    })
}

/// Deblurs every plane of a capture (each CFA plane on its own for RAW, before any
/// colour processing).
///
/// # Errors
/// As [`deblur_channel_plane`].
pub fn deblur_capture(
    cap: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Capture, DeblurError> {
    let mut out = cap.clone();
    for cp in &mut out.planes {
        cp.plane = deblur_channel_plane(cp, cap.width, cap.height, source, opts, job)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_sum_to_one() {
        let g = TileGrid::for_radius(5, Some(64));
        let win = g.window();
        let n = 300;
        let mut acc = vec![0.0; n];
        for x0 in g.origins(n) {
            for (t, &wv) in win.iter().enumerate() {
                let x = x0 + t as isize;
                if (0..n as isize).contains(&x) {
                    acc[x as usize] += wv;
                }
            }
        }
        for v in acc {
            assert!((v - 1.0).abs() < 1e-12, "{v}");
        }
    }

    #[test]
    fn reflection() {
        assert_eq!(reflect(-1, 5), 0);
        assert_eq!(reflect(5, 5), 4);
        // Half-sample symmetric: … 3 4 4 3 2 1 0 | 0 1 2 3 4 | 4 3 …
        assert_eq!(reflect(-7, 5), 3);
        assert_eq!(reflect(12, 5), 2);
    }
}
