//! The chart under a lens that bends the image: rasterised in small blocks, each under
//! the homography that follows the bent mapping closely over it, once per frame strip by
//! strip, and cut into the PSF windows.

use super::super::distortion::SensorMapping;
use crate::chart::{ChartSpec, rasterize};
use crate::geometry::Homography;
use crate::plane::Plane;
use rayon::prelude::*;

/// The largest error (px) allowed between a render block's local homography and the
/// exact bent mapping anywhere in the block.
pub const BLOCK_MAPPING_TOLERANCE_PX: f64 = 0.005;

/// Side (px) of the square blocks each rendered under its own homography, for a
/// mapping over a `width × height` region about its centre: a smooth map deviates from
/// its best local fit over a block of side B by at most κ B² / 4, κ the largest second
/// derivative of the radial displacement there; the blocks keep that under
/// [`BLOCK_MAPPING_TOLERANCE_PX`].
pub(super) fn block_px(map: &SensorMapping, width: f64, height: f64) -> usize {
    let kappa = map.radial_curvature(0.5 * width.hypot(height));
    if !(kappa > 0.0) {
        return 64;
    }
    ((4.0 * BLOCK_MAPPING_TOLERANCE_PX / kappa).sqrt().floor() as usize).clamp(1, 64)
}

/// The homography from chart units to window sub-pixels, relative to the block whose
/// top-left sub-pixel is (a0, b0) and size `bw × bh`, fitted by least squares to the
/// exact mapping chart → ideal image → `map` → sensor → window at a 3 × 3 grid over the
/// block's area.
#[must_use]
pub fn block_homography(
    chart_from_ideal: &Homography,
    map: &SensorMapping,
    sensor_from_sub: &Homography,
    origin: [f64; 2],
    size: [f64; 2],
) -> Option<Homography> {
    let mut from = Vec::with_capacity(9);
    let mut to = Vec::with_capacity(9);
    for j in 0..3 {
        for i in 0..3 {
            let local = [
                -0.5 + size[0] * f64::from(i) / 2.0,
                -0.5 + size[1] * f64::from(j) / 2.0,
            ];
            let sensor = sensor_from_sub.apply([origin[0] + local[0], origin[1] + local[1]]);
            from.push(chart_from_ideal.apply(map.ideal_from_sensor(sensor)));
            to.push(local);
        }
    }
    Homography::from_correspondences(&from, &to)
}

/// The chart rasterised onto a `width × height` raster of sub-pixels under the bent
/// mapping: in blocks of `block × block` sub-pixels, each exactly under its local
/// homography. Rows of blocks are rendered in parallel.
pub(super) fn rasterize_bent(
    spec: &ChartSpec,
    chart_from_ideal: &Homography,
    map: &SensorMapping,
    sensor_from_sub: &Homography,
    (width, height): (usize, usize),
    block: usize,
    background: f32,
) -> Plane {
    let mut out = Plane::filled(width, height, background);
    out.data
        .par_chunks_mut(block * width)
        .enumerate()
        .for_each(|(bj, rows)| {
            let b0 = bj * block;
            let bh = rows.len() / width;
            for a0 in (0..width).step_by(block) {
                let bw = block.min(width - a0);
                let Some(h) = block_homography(
                    chart_from_ideal,
                    map,
                    sensor_from_sub,
                    [a0 as f64, b0 as f64],
                    [bw as f64, bh as f64],
                ) else {
                    continue;
                };
                let part = rasterize(spec, &h, bw, bh, background);
                for j in 0..bh {
                    rows[j * width + a0..j * width + a0 + bw]
                        .copy_from_slice(&part.data[j * bw..(j + 1) * bw]);
                }
            }
        });
    out
}

/// The sharp chart under each distinct bent mapping, rendered once for the whole
/// frame rather than once per PSF window: the windows overlap three times over along
/// each axis, so rendering each one's own nine-fold repeats the costliest part of a
/// bent shot. The frame is rendered in strips of one tile's rows, each strip as soon
/// as a window row first reaches it and dropped once the rows above no longer do, so
/// only a window's height of strips is held at a time.
pub(super) struct BentStrips<'a> {
    pub(super) spec: &'a ChartSpec,
    pub(super) chart_from_ideal: &'a Homography,
    pub(super) maps: &'a [SensorMapping],
    pub(super) block: usize,
    pub(super) background: f32,
    pub(super) s: usize,
    /// Sensor position of the raster's first sub-pixel column's pixel, and of strip
    /// 0's first row's pixel.
    pub(super) origin: [i64; 2],
    /// Sensor rows per strip.
    pub(super) tile: usize,
    /// Sub-pixel columns of every strip.
    pub(super) width_sub: usize,
    /// The strips held, from `first` on; each has one plane per distinct mapping.
    pub(super) first: usize,
    pub(super) held: std::collections::VecDeque<Vec<Plane>>,
}

impl BentStrips<'_> {
    /// The strip holding sensor row `y0` (a strip's first row), and how many follow it
    /// in an `n`-sub-pixel-high window from there.
    fn strips_of(&self, y0: i64, n: usize) -> (usize, usize) {
        let first = usize::try_from((y0 - self.origin[1]) / self.tile as i64).unwrap_or(0);
        (first, first + (n - 1) / (self.tile * self.s))
    }

    /// Renders the strips a row of `n × n` windows starting at sensor row `y0` covers,
    /// and drops those above it.
    pub(super) fn reach_row(&mut self, y0: i64, n: usize) {
        let s = self.s;
        let (first, last) = self.strips_of(y0, n);
        while self.first < first && !self.held.is_empty() {
            self.held.pop_front();
            self.first += 1;
        }
        if self.held.is_empty() {
            self.first = first;
        }
        while self.first + self.held.len() <= last {
            let k = self.first + self.held.len();
            let off = (s as f64 - 1.0) / (2.0 * s as f64);
            let top = self.origin[1] + (k * self.tile) as i64;
            let sensor_from_sub =
                Homography::translation(self.origin[0] as f64 - off, top as f64 - off)
                    .compose(&Homography::scaling(1.0 / s as f64, 1.0 / s as f64));
            let planes = self
                .maps
                .iter()
                .map(|map| {
                    rasterize_bent(
                        self.spec,
                        self.chart_from_ideal,
                        map,
                        &sensor_from_sub,
                        (self.width_sub, self.tile * s),
                        self.block,
                        self.background,
                    )
                })
                .collect();
            self.held.push_back(planes);
        }
    }

    /// The `n × n` sub-pixel window whose top-left pixel is sensor (x0, y0), under each
    /// distinct mapping, from the strips [`Self::reach_row`] rendered for row `y0`.
    pub(super) fn window(&self, x0: i64, y0: i64, n: usize) -> Vec<Plane> {
        let s = self.s;
        let rows_sub = self.tile * s;
        let (first, _) = self.strips_of(y0, n);
        let a0 = usize::try_from(x0 - self.origin[0]).unwrap_or(0) * s;
        (0..self.maps.len())
            .map(|d| {
                let mut out = Plane::new(n, n);
                for (b, row) in out.data.chunks_exact_mut(n).enumerate() {
                    let strip = &self.held[first + b / rows_sub - self.first][d];
                    let j = b % rows_sub;
                    let start = j * self.width_sub + a0;
                    row.copy_from_slice(&strip.data[start..start + n]);
                }
                out
            })
            .collect()
    }
}
