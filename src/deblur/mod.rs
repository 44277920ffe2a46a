//! Deblurring: non-blind deconvolution of each channel plane with the lens's spatially
//! varying kernels.
//!
//! A plane is cut into tiles sized from its kernels and its own size; each tile is
//! deconvolved inside an FFT block (the tile plus a margin, read with reflection past
//! the image border and edge-tapered) with the kernel at its centre, then blended with
//! its neighbours by windows that are flat inside the tile and cross-fade over a short
//! ramp at each shared border; the windows sum to one, so no seam shows. Tiles are
//! independent: every tile of every plane runs in one parallel pass ([`tiles`]), each
//! worker reusing its own solver (the FFT plans are shared by the whole process).

pub mod chroma;
pub mod gpu;
pub mod noise;
pub mod output;
pub mod solve;
pub mod source;
mod tiles;

pub use gpu::{Device, GpuError};
pub use solve::{HqsParams, IrlsParams, Method, WienerParams};
pub use source::{
    ConstantKernel, KernelSource, KernelsFile, PlacedGaussian, ProfileKernels, ScatteredKernels,
    ShapedKernel, SourceError,
};

use crate::fft::good_size;
use crate::job::{Cancelled, JobContext};
use crate::plane::{Capture, ChannelPlane, Plane};
use crate::psf::Kernel;
use crate::timings::{Stage, Timings};
use rayon::prelude::*;
use tiles::PlaneWork;

#[derive(Debug, thiserror::Error)]
pub enum DeblurError {
    #[error("cancelled")]
    Cancelled(#[from] Cancelled),
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error("empty image")]
    Empty,
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// How to deblur.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeblurOptions {
    pub method: Method,
    /// Tile step (the distance between tile centres) in plane pixels; `None` picks it
    /// from the kernel size and the plane size ([`TileGrid::for_plane`]).
    pub tile_step_px: Option<usize>,
    /// Where to run: the CPU (the reference), the GPU, or the GPU when a hardware one
    /// is there.
    pub device: Device,
    /// How much of the deconvolution to keep: the photographer's control.
    pub amount: Amount,
    /// Whether colour the deconvolution adds at edges is cut back ([`chroma`]).
    pub fringes: Fringes,
}

/// What happens to colour the per-channel deconvolution adds at edges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Fringes {
    /// Each pixel's chroma held inside the photo's own around it ([`chroma::clamp_chroma`]),
    /// for RGB photos (a RAW photo's Bayer planes sit a pixel apart, and the clamp
    /// would mix positions).
    #[default]
    Suppress,
    /// Every channel as its deconvolution left it.
    Keep,
}

/// How strongly to deblur, as a fraction of the method's own result: 0 leaves the photo
/// as it was, 1 (100 %, the default) is the method at its tuned strength, between them
/// a blend, above 1 (to 2, 200 %) the change carried further. A blend rather than a
/// rescaled regulariser, so that 0 % is the photo itself and every amount costs one
/// deconvolution.
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
pub struct Amount(f64);

impl Amount {
    pub const FULL: Self = Self(1.0);
    /// The largest amount: past it the change mostly amplifies noise and ringing.
    pub const MAX_PERCENT: f64 = 200.0;

    /// `percent` of the method's result, clamped to 0–200 %.
    #[must_use]
    pub fn percent(percent: f64) -> Self {
        Self(if percent.is_finite() {
            percent.clamp(0.0, Self::MAX_PERCENT) / 100.0
        } else {
            1.0
        })
    }

    #[must_use]
    pub fn as_percent(self) -> f64 {
        self.0 * 100.0
    }

    /// `deblurred` becomes original + amount · (deblurred − original).
    pub fn apply(self, original: &Plane, deblurred: &mut Plane) {
        if self == Self::FULL {
            return;
        }
        let a = self.0 as f32;
        deblurred
            .data
            .par_chunks_mut(1 << 16)
            .zip(original.data.par_chunks(1 << 16))
            .for_each(|(d, o)| {
                for (d, &o) in d.iter_mut().zip(o) {
                    *d = o + a * (*d - o);
                }
            });
    }
}

impl Default for Amount {
    fn default() -> Self {
        Self::FULL
    }
}

/// One axis of the tile grid: `count` tiles, tile t owning [t·step, (t+1)·step) and
/// blending with its neighbours over `ramp` pixels centred on each shared border;
/// its FFT block reads `margin_before` pixels before its window and fills `block`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileAxis {
    pub len: usize,
    pub step: usize,
    pub count: usize,
    pub ramp: usize,
    pub margin_before: usize,
    pub block: usize,
}

impl TileAxis {
    fn new(len: usize, step_wanted: usize, ramp: usize, margin: usize) -> Self {
        // Even tiles, none smaller than asked: the last one is not a sliver.
        let count = (len / step_wanted.max(1)).max(1);
        let step = len.div_ceil(count).max(ramp).max(1);
        let count = len.div_ceil(step).max(1);
        let block = good_size(step + ramp + 2 * margin);
        Self {
            len,
            step,
            count,
            ramp,
            margin_before: (block - step - ramp) / 2,
            block,
        }
    }

    /// Window length: the tile's own pixels plus half a ramp on each side.
    #[must_use]
    pub fn window_len(&self) -> usize {
        self.step + self.ramp
    }

    /// First pixel of tile t's window (may be negative).
    #[must_use]
    pub fn window_start(&self, t: usize) -> isize {
        (t * self.step) as isize - (self.ramp / 2) as isize
    }

    /// First pixel of tile t's FFT block (may be negative: read reflected).
    #[must_use]
    pub fn block_start(&self, t: usize) -> isize {
        self.window_start(t) - self.margin_before as isize
    }

    /// Centre of tile t's own pixels, clamped into the axis.
    #[must_use]
    pub fn centre(&self, t: usize) -> f64 {
        let c = t as f64 * self.step as f64 + (self.step as f64 - 1.0) / 2.0;
        c.clamp(0.0, (self.len.max(1) - 1) as f64)
    }

    /// Blend window of tile t over its window: flat, with a sin² ramp where it meets a
    /// neighbour, which that neighbour's cos² ramp mirrors so the two sum to one. The
    /// first and last tiles stay flat toward the image border.
    #[must_use]
    pub fn window(&self, t: usize) -> Vec<f64> {
        let n = self.window_len();
        let r = self.ramp;
        let rise = |i: usize| -> f64 {
            (std::f64::consts::FRAC_PI_2 * (i as f64 + 0.5) / r as f64)
                .sin()
                .powi(2)
        };
        (0..n)
            .map(|i| {
                let mut v = 1.0;
                if i < r && t > 0 {
                    v *= rise(i);
                }
                if i + r >= n && t + 1 < self.count {
                    v *= rise(n - 1 - i);
                }
                v
            })
            .collect()
    }
}

/// The tile grid of one plane. Each tile is deconvolved in one FFT block with the
/// kernel at its centre; its window, a partition of unity, blends it with its
/// neighbours.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGrid {
    pub x: TileAxis,
    pub y: TileAxis,
    /// Pixels at each block edge blended toward the blurred block (the edge taper).
    pub taper: usize,
}

impl TileGrid {
    /// The margin a block needs around its window for kernels of at most `radius_px`
    /// plane pixels: the edge taper plus room for the deconvolution's response to what
    /// remains of the block's own edges to die out before the window.
    #[must_use]
    pub fn margin_for(radius_px: usize) -> usize {
        3 * radius_px + 12
    }

    /// The grid for a `width × height` plane and kernels of at most `radius_px` plane
    /// pixels. Without a step given, tiles are about a twelfth of the longer side, so a
    /// smooth lens field is followed closely at any image size, but never so small that
    /// the margin is most of the work (4 kernel radii) and never beyond 512 pixels.
    #[must_use]
    pub fn for_plane(
        width: usize,
        height: usize,
        radius_px: usize,
        step_px: Option<usize>,
    ) -> Self {
        let margin = Self::margin_for(radius_px);
        let ramp = (2 * radius_px).clamp(8, 32) & !1;
        let step =
            step_px.unwrap_or_else(|| (width.max(height) / 12).clamp((4 * radius_px).max(32), 512));
        let step = step.max(ramp);
        Self {
            x: TileAxis::new(width, step, ramp, margin),
            y: TileAxis::new(height, step, ramp, margin),
            taper: (2 * radius_px + 4).min(margin),
        }
    }

    #[must_use]
    pub fn tiles(&self) -> usize {
        self.x.count * self.y.count
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

/// Crops a kernel to at most `max_size` (odd) samples a side, renormalised: a kernel
/// wider than the block's margin could hold would wrap around the block.
pub(crate) fn cropped(k: Kernel, max_size: usize) -> Kernel {
    if k.size <= max_size {
        return k;
    }
    let keep = max_size | 1;
    let keep = if keep > max_size { keep - 2 } else { keep };
    let off = (k.size - keep) / 2;
    let mut data = Vec::with_capacity(keep * keep);
    for j in 0..keep {
        for i in 0..keep {
            data.push(k.at(i + off, j + off));
        }
    }
    let mut k = Kernel {
        size: keep,
        oversample: k.oversample,
        data,
    };
    k.normalise();
    k
}

/// Deconvolves a whole plane with one kernel (at plane resolution) through the same
/// tiler: the spatially invariant baseline.
///
/// # Errors
/// Only on cancellation.
pub fn deblur_plane_invariant(
    plane: &Plane,
    k: &Kernel,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Plane, DeblurError> {
    if plane.width == 0 || plane.height == 0 {
        return Err(DeblurError::Empty);
    }
    let k = k.resampled(1);
    let grid = TileGrid::for_plane(plane.width, plane.height, k.size / 2, opts.tile_step_px);
    let work = PlaneWork {
        plane,
        grid,
        kernel_at: &|_x: f64, _y: f64| Ok(k.clone()),
    };
    one_plane(tiles::deblur_planes(&[work], &opts.method, job)?)
}

/// The one plane of a one-plane deblur.
fn one_plane(mut planes: Vec<Plane>) -> Result<Plane, DeblurError> {
    planes.pop().ok_or(DeblurError::Empty)
}

/// The 1× plane-resolution kernel of `source` at plane pixel (i, j) of `cp`.
pub(crate) fn plane_kernel_at(
    cp: &ChannelPlane,
    sensor_width: usize,
    sensor_height: usize,
    source: &dyn KernelSource,
    i: f64,
    j: f64,
) -> Result<Kernel, DeblurError> {
    let [x, y] = sensor_point(cp, (sensor_width, sensor_height), i, j);
    Ok(plane_kernel(&source.kernel_at(cp.channel, x, y)?, cp.step))
}

/// The sensor point a tile centred at plane point (i, j) takes its kernel at: on the
/// sensor, where a plane's reflected border would reach past it.
pub(crate) fn sensor_point(cp: &ChannelPlane, (w, h): (usize, usize), i: f64, j: f64) -> [f64; 2] {
    let [x, y] = cp.sensor_from_plane(i, j);
    [
        x.clamp(0.0, (w.max(1) - 1) as f64),
        y.clamp(0.0, (h.max(1) - 1) as f64),
    ]
}

/// The tile grid [`deblur_channel_plane`] uses for a plane: the largest kernel sizes
/// the margins, found on a 5 × 5 grid of probes over the plane (lens fields are smooth,
/// so their extremes lie on or near it).
///
/// # Errors
/// An empty plane, or a source that cannot supply a kernel.
pub fn plane_tile_grid(
    cp: &ChannelPlane,
    sensor_width: usize,
    sensor_height: usize,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
) -> Result<TileGrid, DeblurError> {
    let plane = &cp.plane;
    if plane.width == 0 || plane.height == 0 {
        return Err(DeblurError::Empty);
    }
    let mut radius = 1usize;
    for b in 0..5 {
        for a in 0..5 {
            let i = a as f64 / 4.0 * (plane.width - 1) as f64;
            let j = b as f64 / 4.0 * (plane.height - 1) as f64;
            let k = plane_kernel_at(cp, sensor_width, sensor_height, source, i, j)?;
            radius = radius.max(k.size / 2);
        }
    }
    Ok(TileGrid::for_plane(
        plane.width,
        plane.height,
        radius,
        opts.tile_step_px,
    ))
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
    let started = Timings::start(job.timings());
    let grid = plane_tile_grid(cp, sensor_width, sensor_height, source, opts)?;
    Timings::stop(job.timings(), Stage::Grid, started);
    let at = |i: f64, j: f64| plane_kernel_at(cp, sensor_width, sensor_height, source, i, j);
    let work = PlaneWork {
        plane: &cp.plane,
        grid,
        kernel_at: &at,
    };
    one_plane(tiles::deblur_planes(&[work], &opts.method, job)?)
}

/// Each plane's tile grid (the kernels it is deblurred with), the planes in parallel:
/// the first step of the CPU and the GPU paths alike.
pub(crate) fn tile_grids(
    cap: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Vec<TileGrid>, DeblurError> {
    let (w, h) = (cap.width, cap.height);
    cap.planes
        .par_iter()
        .map(|cp| {
            let started = Timings::start(job.timings());
            let grid = plane_tile_grid(cp, w, h, source, opts);
            Timings::stop(job.timings(), Stage::Grid, started);
            grid
        })
        .collect()
}

/// Every plane of a capture on the CPU, all tiles of all planes in one pass.
fn deblur_planes_cpu(
    cap: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Vec<Plane>, DeblurError> {
    let (w, h) = (cap.width, cap.height);
    let grids = tile_grids(cap, source, opts, job)?;
    let kernels: Vec<_> = cap
        .planes
        .iter()
        .map(|cp| move |i: f64, j: f64| plane_kernel_at(cp, w, h, source, i, j))
        .collect();
    let work: Vec<PlaneWork<'_>> = cap
        .planes
        .iter()
        .zip(grids)
        .zip(&kernels)
        .map(|((cp, grid), at)| PlaneWork {
            plane: &cp.plane,
            grid,
            kernel_at: at,
        })
        .collect();
    tiles::deblur_planes(&work, &opts.method, job)
}

pub(crate) type KernelAt<'a> = dyn Fn(f64, f64) -> Result<Kernel, DeblurError> + Sync + 'a;

/// Deblurs every plane of a capture (each CFA plane on its own for RAW, before any
/// colour processing), on the device `opts` asks for, the method's regularisation
/// raised for the capture's own noise, quantisation and blocks ([`noise`]).
///
/// # Errors
/// As [`deblur_channel_plane`]; with [`Device::Gpu`], also when no adapter can run the
/// GPU path or it fails.
pub fn deblur_capture(
    cap: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Capture, DeblurError> {
    let wall = Timings::start(job.timings());
    // The method's strength is tuned for a clean RAW or linear photo; a noisier picture,
    // an 8-bit or a compressed one is held back as far as its own pixels say it must be.
    let opts = &DeblurOptions {
        method: noise::estimate(cap).regularised(&opts.method),
        ..*opts
    };
    let gpu = gpu::resolve(opts.device, &opts.method)?;
    let planes = match &gpu {
        Some(g) => g.deblur_planes(cap, source, opts, job)?,
        None => deblur_planes_cpu(cap, source, opts, job)?,
    };
    let started = Timings::start(job.timings());
    let mut out = with_planes(cap, planes);
    for (cp, original) in out.planes.iter_mut().zip(&cap.planes) {
        opts.amount.apply(&original.plane, &mut cp.plane);
    }
    Timings::stop(job.timings(), Stage::Finish, started);
    let started = Timings::start(job.timings());
    if opts.fringes == Fringes::Suppress && !cap.is_raw {
        suppress_fringes(cap, &mut out);
    }
    Timings::stop(job.timings(), Stage::Finish, started);
    if let (Some(t), Some(w)) = (job.timings(), wall) {
        t.add_wall(w.elapsed());
    }
    Ok(out)
}

/// `cap` with each plane's pixels replaced by `planes`' (the same sizes), without
/// copying its own.
fn with_planes(cap: &Capture, planes: Vec<Plane>) -> Capture {
    let Capture {
        width,
        height,
        planes: own,
        setting_focal_mm,
        setting_f_number,
        setting_focus_m,
        identity,
        is_raw,
        raw,
    } = cap;
    Capture {
        width: *width,
        height: *height,
        planes: own
            .iter()
            .zip(planes)
            .map(|(cp, plane)| ChannelPlane {
                plane,
                channel: cp.channel,
                step: cp.step,
                offset_x: cp.offset_x,
                offset_y: cp.offset_y,
            })
            .collect(),
        setting_focal_mm: *setting_focal_mm,
        setting_f_number: *setting_f_number,
        setting_focus_m: *setting_focus_m,
        identity: identity.clone(),
        is_raw: *is_raw,
        raw: raw.clone(),
    }
}

/// [`chroma::clamp_chroma`] on an RGB capture's R, G and B planes (nothing otherwise).
fn suppress_fringes(cap: &Capture, out: &mut Capture) {
    use crate::plane::Channel;
    let find = |c: &Capture, ch| c.planes.iter().position(|p| p.channel == ch);
    let (Some(r), Some(g), Some(b)) = (
        find(cap, Channel::R),
        find(cap, Channel::G),
        find(cap, Channel::B),
    ) else {
        return;
    };
    let input = [
        &cap.planes[r].plane,
        &cap.planes[g].plane,
        &cap.planes[b].plane,
    ];
    let mut planes: Vec<Option<&mut Plane>> =
        out.planes.iter_mut().map(|p| Some(&mut p.plane)).collect();
    let (Some(ro), Some(go), Some(bo)) = (
        planes.get_mut(r).and_then(Option::take),
        planes.get_mut(g).and_then(Option::take),
        planes.get_mut(b).and_then(Option::take),
    ) else {
        return;
    };
    chroma::clamp_chroma(input, [ro, go, bo], chroma::CHROMA_WINDOW_RADIUS);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_sum_to_one() {
        for (len, step, ramp) in [(300, 64, 16), (97, 20, 8), (1000, 333, 32), (40, 64, 16)] {
            let axis = TileAxis::new(len, step, ramp, 20);
            let mut acc = vec![0.0; len];
            for t in 0..axis.count {
                for (i, &wv) in axis.window(t).iter().enumerate() {
                    let x = axis.window_start(t) + i as isize;
                    if (0..len as isize).contains(&x) {
                        acc[x as usize] += wv;
                    }
                }
            }
            for (x, v) in acc.iter().enumerate() {
                assert!((v - 1.0).abs() < 1e-12, "len {len} step {step}: {v} at {x}");
            }
            // Every window sits inside its block, past the margin.
            for t in 0..axis.count {
                assert!(axis.margin_before >= 20);
                assert!(axis.block >= axis.margin_before + axis.window_len() + 20);
                assert_eq!(
                    axis.block_start(t) + axis.margin_before as isize,
                    axis.window_start(t)
                );
            }
        }
    }

    #[test]
    fn tiles_follow_the_plane_and_the_kernel() {
        let big = TileGrid::for_plane(3888, 2592, 12, None);
        assert!(big.x.count >= 8 && big.x.step <= 512, "{big:?}");
        let small = TileGrid::for_plane(384, 256, 10, None);
        assert!(small.x.step >= 40, "{small:?}");
        assert!(TileGrid::margin_for(10) > 2 * 10);
    }
}
