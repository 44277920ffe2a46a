//! The sharpness map: MTF50 over the whole frame as a colour map, the way MTF Mapper's
//! lens map shows a lens: from one shot's measured kernels, from a profile's prediction
//! at any focal length and aperture, or from a virtual lens's exact blur. Along the
//! worst or best direction or of the isotropic equivalent, in line pairs per picture
//! height or cycles per pixel; written as CSV and as a PNG with a labelled colour bar.
//!
//! Every MTF50 here is that of a Gaussian (see [`Mtf50`]): the pixel-level blur the
//! kernels measure and the models predict, so the pixel's aperture is in it and
//! sampling, the Bayer pattern and demosaicing are not.

use super::fields::{colour_range, field_grid, palette_rgb, truth_pixel_gaussian};
use super::plot::nice_ticks;
use crate::kernel::file::KernelsFile;
use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Mtf50};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Which MTF50 of an elliptical blur a map shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mtf50Direction {
    /// Along the direction the blur is widest: what every direction resolves at least.
    #[default]
    Worst,
    /// Along the narrowest direction.
    Best,
    /// Of the round blur with the same area (the geometric mean of worst and best).
    Isotropic,
}

impl Mtf50Direction {
    pub const ALL: [Self; 3] = [Self::Worst, Self::Best, Self::Isotropic];

    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::Worst => "worst",
            Self::Best => "best",
            Self::Isotropic => "isotropic",
        }
    }

    #[must_use]
    pub fn of(self, m: &Mtf50) -> f64 {
        match self {
            Self::Worst => m.worst,
            Self::Best => m.best,
            Self::Isotropic => m.isotropic,
        }
    }
}

/// The unit a map's MTF50 is shown in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum SharpnessUnit {
    /// Line pairs per picture height: comparable between cameras of different
    /// resolution, as photographers and MTF Mapper quote it.
    #[default]
    LpPerPictureHeight,
    /// Cycles per sensor pixel (0.5 is the Nyquist frequency).
    CyclesPerPixel,
}

impl SharpnessUnit {
    pub const ALL: [Self; 2] = [Self::LpPerPictureHeight, Self::CyclesPerPixel];

    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::LpPerPictureHeight => "lp/ph",
            Self::CyclesPerPixel => "cycles/px",
        }
    }

    /// `cycles_per_px` in this unit, for a picture `height_px` tall.
    #[must_use]
    pub fn from_cycles_per_px(self, cycles_per_px: f64, height_px: usize) -> f64 {
        match self {
            Self::LpPerPictureHeight => Mtf50::lp_per_picture_height(cycles_per_px, height_px),
            Self::CyclesPerPixel => cycles_per_px,
        }
    }
}

/// Cells along the long side of a map: fine enough to show how sharpness falls
/// towards the corners, coarse enough that a measured map interpolates between a
/// chart's squares rather than inventing detail between them.
pub const MAP_CELLS_LONG_SIDE: usize = 48;

/// The map's grid for a sensor: [`MAP_CELLS_LONG_SIDE`] along the long side, square
/// cells.
#[must_use]
pub fn map_grid((width, height): (usize, usize)) -> (usize, usize) {
    let (w, h) = (width.max(1) as f64, height.max(1) as f64);
    let short = |a: f64, b: f64| ((MAP_CELLS_LONG_SIDE as f64 * a / b).round() as usize).max(2);
    if w >= h {
        (MAP_CELLS_LONG_SIDE, short(h, w))
    } else {
        (short(w, h), MAP_CELLS_LONG_SIDE)
    }
}

/// Where a measured map has no value: cells farther from every measured square than
/// this many times the squares' typical spacing (the chart did not reach there).
const MEASURED_REACH_SPACINGS: f64 = 1.5;

/// The measured squares a measured map's cell interpolates between.
const MEASURED_NEIGHBOURS: usize = 4;

/// MTF50 over a sensor on a grid of cells (their centres as [`field_grid`] places
/// them), row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct SharpnessMap {
    /// The sensor, px.
    pub sensor: (usize, usize),
    /// Cells across and down.
    pub grid: (usize, usize),
    pub channel: Channel,
    pub direction: Mtf50Direction,
    /// What the map is of, one line of ASCII ("predicted at 50 mm f/5.6").
    pub title: String,
    /// MTF50 in cycles per pixel per cell; NaN where the map has no value.
    pub cycles_per_px: Vec<f64>,
}

/// A map's figures, in the unit asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapSummary {
    /// The cell at the frame's centre.
    pub centre: f64,
    /// The mean over the frame's four corners of the cell nearest each that has a
    /// value (a measured map stops where the chart did).
    pub corners: f64,
    pub min: f64,
    pub median: f64,
    pub max: f64,
}

impl SharpnessMap {
    /// A map of the Gaussians at the cells of `grid` (row-major, one per cell).
    #[must_use]
    pub fn from_gaussians(
        sensor: (usize, usize),
        grid: (usize, usize),
        channel: Channel,
        direction: Mtf50Direction,
        title: String,
        gaussians: impl IntoIterator<Item = Option<Gaussian2>>,
    ) -> Self {
        let cycles_per_px = gaussians
            .into_iter()
            .map(|g| {
                g.and_then(|g| g.mtf50())
                    .map_or(f64::NAN, |m| direction.of(&m))
            })
            .collect();
        Self {
            sensor,
            grid,
            channel,
            direction,
            title,
            cycles_per_px,
        }
    }

    /// What a profile predicts at `setting` over its whole sensor.
    ///
    /// # Errors
    /// The profile cannot predict there (channel or setting outside it), one line.
    pub fn predicted(
        profile: &Profile,
        channel: Channel,
        setting: LensSetting,
        direction: Mtf50Direction,
    ) -> Result<Self, String> {
        let sensor = (profile.norm.width, profile.norm.height);
        let grid = map_grid(sensor);
        let field = super::fields::predicted_field(profile, channel, sensor, grid, setting)?;
        Ok(Self::from_gaussians(
            sensor,
            grid,
            channel,
            direction,
            format!("predicted at {}", setting_label(setting)),
            field.into_iter().map(|(_, _, g)| Some(g)),
        ))
    }

    /// A virtual lens's exact blur at `setting` on a `sensor`.
    #[must_use]
    pub fn truth(
        lens: &crate::simulate::VirtualLens,
        channel: Channel,
        sensor: (usize, usize),
        setting: LensSetting,
        direction: Mtf50Direction,
    ) -> Self {
        let grid = map_grid(sensor);
        Self::from_gaussians(
            sensor,
            grid,
            channel,
            direction,
            format!("true blur at {}", setting_label(setting)),
            field_grid(sensor.0, sensor.1, grid.0, grid.1)
                .into_iter()
                .map(|[x, y]| Some(truth_pixel_gaussian(lens, channel, (x, y), sensor, setting))),
        )
    }

    /// What one shot's kernels measured: each cell the inverse-distance-weighted mean
    /// covariance of the nearest measured squares (covariances average as blurs do; an
    /// MTF50 would not), none where the chart did not reach.
    ///
    /// # Errors
    /// The file has no measured Gaussian of `channel`.
    pub fn measured(
        file: &KernelsFile,
        channel: Channel,
        direction: Mtf50Direction,
        title: String,
    ) -> Result<Self, String> {
        let samples: Vec<([f64; 2], [f64; 3])> = file
            .samples
            .iter()
            .filter(|k| k.channel == channel)
            .filter_map(|k| {
                let g = Gaussian2 {
                    sigma_x: k.cxx?,
                    sigma_y: k.cyy?,
                    rho: k.cor?,
                };
                let cov = [g.sigma_x.powi(2), g.sigma_y.powi(2), g.cov_xy()];
                (k.x.is_finite() && k.y.is_finite() && cov.iter().all(|c| c.is_finite()))
                    .then_some(([k.x, k.y], cov))
            })
            .collect();
        if samples.is_empty() {
            return Err(format!("no measured kernel of channel {channel:?} to map"));
        }
        let sensor = (file.width, file.height);
        let grid = map_grid(sensor);
        let reach = MEASURED_REACH_SPACINGS * typical_spacing(&samples);
        let cells = field_grid(sensor.0, sensor.1, grid.0, grid.1);
        let gaussians = cells.into_iter().map(|p| {
            let d = |s: &([f64; 2], [f64; 3])| (s.0[0] - p[0]).hypot(s.0[1] - p[1]);
            let mut near: Vec<(f64, [f64; 3])> = samples.iter().map(|s| (d(s), s.1)).collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            near.truncate(MEASURED_NEIGHBOURS);
            if near.first().is_none_or(|n| n.0 > reach) {
                return None;
            }
            // A cell on a square takes that square's blur exactly.
            let weights: Vec<f64> = near.iter().map(|n| 1.0 / (n.0 * n.0).max(1e-6)).collect();
            let total: f64 = weights.iter().sum();
            let mean = |i: usize| {
                near.iter()
                    .zip(&weights)
                    .map(|(n, w)| n.1[i] * w)
                    .sum::<f64>()
                    / total
            };
            Some(Gaussian2::from_covariance(mean(0), mean(1), mean(2)))
        });
        Ok(Self::from_gaussians(
            sensor, grid, channel, direction, title, gaussians,
        ))
    }

    /// The map's values in `unit`, row-major (NaN where none).
    #[must_use]
    pub fn values(&self, unit: SharpnessUnit) -> Vec<f64> {
        self.cycles_per_px
            .iter()
            .map(|&v| unit.from_cycles_per_px(v, self.sensor.1))
            .collect()
    }

    /// The value in `unit` of the cell holding sensor point (x, y), px; `None` off the
    /// sensor or where the map has no value.
    #[must_use]
    pub fn at(&self, x: f64, y: f64, unit: SharpnessUnit) -> Option<f64> {
        let (w, h) = (self.sensor.0 as f64, self.sensor.1 as f64);
        if !(x >= 0.0 && y >= 0.0 && x < w && y < h) {
            return None;
        }
        let i = ((x / w * self.grid.0 as f64) as usize).min(self.grid.0 - 1);
        let j = ((y / h * self.grid.1 as f64) as usize).min(self.grid.1 - 1);
        let v = *self.cycles_per_px.get(j * self.grid.0 + i)?;
        v.is_finite()
            .then(|| unit.from_cycles_per_px(v, self.sensor.1))
    }

    /// The colour range of the map in `unit`.
    #[must_use]
    pub fn range(&self, unit: SharpnessUnit) -> Option<[f64; 2]> {
        colour_range(self.values(unit), false)
    }

    /// Centre, corners, minimum, median and maximum in `unit`; `None` for a map with no
    /// value at all.
    #[must_use]
    pub fn summary(&self, unit: SharpnessUnit) -> Option<MapSummary> {
        let values = self.values(unit);
        let mut finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        if finite.is_empty() {
            return None;
        }
        finite.sort_by(f64::total_cmp);
        let (nx, ny) = self.grid;
        let corner_values: Vec<f64> = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
            .into_iter()
            .filter_map(|(cx, cy)| {
                // Distances in cells, from the corner to each cell's centre.
                let d = |k: usize| {
                    let (i, j) = ((k % nx) as f64 + 0.5, (k / nx) as f64 + 0.5);
                    (i - cx * nx as f64).hypot(j - cy * ny as f64)
                };
                (0..values.len())
                    .filter(|&k| values[k].is_finite())
                    .min_by(|&a, &b| d(a).total_cmp(&d(b)))
                    .map(|k| values[k])
            })
            .collect();
        let centre = self
            .at(self.sensor.0 as f64 / 2.0, self.sensor.1 as f64 / 2.0, unit)
            .unwrap_or(f64::NAN);
        Some(MapSummary {
            centre,
            corners: if corner_values.is_empty() {
                f64::NAN
            } else {
                corner_values.iter().sum::<f64>() / corner_values.len() as f64
            },
            min: finite[0],
            median: super::super::crossval::percentile_sorted(&finite, 50.0),
            max: finite[finite.len() - 1],
        })
    }

    /// The median over the cells of |self − truth| / truth: how far a measured or
    /// predicted map is from the exact one. `None` unless the grids agree and some
    /// cell has both.
    #[must_use]
    pub fn median_relative_error(&self, truth: &SharpnessMap) -> Option<f64> {
        if self.grid != truth.grid || self.sensor != truth.sensor {
            return None;
        }
        let mut errors: Vec<f64> = self
            .cycles_per_px
            .iter()
            .zip(&truth.cycles_per_px)
            .filter(|(a, t)| a.is_finite() && t.is_finite() && **t > 0.0)
            .map(|(a, t)| (a - t).abs() / t)
            .collect();
        if errors.is_empty() {
            return None;
        }
        errors.sort_by(f64::total_cmp);
        Some(super::super::crossval::percentile_sorted(&errors, 50.0))
    }

    /// The map as CSV: one row per cell with its sensor position (px), channel,
    /// direction and MTF50 in both units; empty MTF50 cells where the map has none.
    #[must_use]
    pub fn csv(&self) -> String {
        let mut out = String::from("x,y,channel,direction,mtf50_cycles_px,mtf50_lp_ph\n");
        let cells = field_grid(self.sensor.0, self.sensor.1, self.grid.0, self.grid.1);
        for ([x, y], &v) in cells.iter().zip(&self.cycles_per_px) {
            let _ = write!(
                out,
                "{x:.1},{y:.1},{},{},",
                self.channel.name(),
                self.direction.label()
            );
            if v.is_finite() {
                let lp = SharpnessUnit::LpPerPictureHeight.from_cycles_per_px(v, self.sensor.1);
                let _ = writeln!(out, "{v:.6},{lp:.2}");
            } else {
                out.push_str(",\n");
            }
        }
        out
    }

    /// One RGBA pixel per cell, coloured over `range` in `unit` (transparent where the
    /// map has no value): what the studio draws, scaled up with smoothing.
    #[must_use]
    pub fn rgba_cells(&self, unit: SharpnessUnit, range: [f64; 2]) -> Vec<[u8; 4]> {
        self.values(unit)
            .into_iter()
            .map(|v| colour_of(v, range))
            .collect()
    }

    /// The map as a picture: the frame `width` px wide (values interpolated between
    /// cell centres), a title, and a colour bar with labelled ticks in `unit`.
    ///
    /// # Errors
    /// The map has no value to colour.
    pub fn picture(&self, unit: SharpnessUnit, width: u32) -> Result<image::RgbaImage, String> {
        let range = self.range(unit).ok_or("the map has no value to draw")?;
        let (nx, ny) = self.grid;
        let width = width.max(64);
        let map_h =
            ((f64::from(width) * self.sensor.1 as f64 / self.sensor.0.max(1) as f64).round()
                as u32)
                .max(1);
        let (title_h, bar_h, labels_h) = (2 * GLYPH + 12, 18, 2 * GLYPH + 10);
        let mut img = image::RgbaImage::from_pixel(
            width,
            title_h + map_h + 8 + bar_h + labels_h,
            image::Rgba([255, 255, 255, 255]),
        );
        let title = format!(
            "MTF50 {} ({}, {}), {}",
            self.direction.label(),
            self.channel.name(),
            unit.label(),
            self.title
        );
        // The title at the labels' size where it fits, else at half of it.
        let fits = title.len() as u32 * 2 * GLYPH + 12 <= width;
        draw_text(&mut img, &title, 6, 6, if fits { 2 } else { 1 });
        let values = self.values(unit);
        let cell = |i: usize, j: usize| values[j.min(ny - 1) * nx + i.min(nx - 1)];
        for py in 0..map_h {
            // Cell centres sit at (k + ½) / n of the frame.
            let gy = ((f64::from(py) + 0.5) / f64::from(map_h) * ny as f64 - 0.5).max(0.0);
            for px in 0..width {
                let gx = ((f64::from(px) + 0.5) / f64::from(width) * nx as f64 - 0.5).max(0.0);
                let (i, j) = (gx.floor() as usize, gy.floor() as usize);
                let (fx, fy) = (gx - i as f64, gy - j as f64);
                let corners = [
                    cell(i, j),
                    cell(i + 1, j),
                    cell(i, j + 1),
                    cell(i + 1, j + 1),
                ];
                let v = if corners.iter().all(|v| v.is_finite()) {
                    let top = corners[0] * (1.0 - fx) + corners[1] * fx;
                    let bottom = corners[2] * (1.0 - fx) + corners[3] * fx;
                    top * (1.0 - fy) + bottom * fy
                } else {
                    cell((gx + 0.5) as usize, (gy + 0.5) as usize)
                };
                let c = colour_of(v, range);
                // No value: a light grey, not the page's white.
                let c = if c[3] == 0 { [210, 210, 210, 255] } else { c };
                img.put_pixel(px, title_h + py, image::Rgba(c));
            }
        }
        let bar_top = title_h + map_h + 8;
        let (bar_left, bar_w) = (GLYPH * 2, width.saturating_sub(GLYPH * 4).max(1));
        for px in 0..bar_w {
            let t = (f64::from(px) + 0.5) / f64::from(bar_w);
            let c = palette_rgb(t as f32, false);
            for py in 0..bar_h {
                img.put_pixel(
                    bar_left + px,
                    bar_top + py,
                    image::Rgba([c[0], c[1], c[2], 255]),
                );
            }
        }
        let ticks = nice_ticks(range, 6);
        let step = match ticks.as_slice() {
            [a, b, ..] => b - a,
            _ => range[1] - range[0],
        };
        for &tick in &ticks {
            let t = (tick - range[0]) / (range[1] - range[0]);
            let x = bar_left + (t * f64::from(bar_w - 1)).round() as u32;
            for py in bar_top + bar_h..bar_top + bar_h + 5 {
                img.put_pixel(x, py, image::Rgba([0, 0, 0, 255]));
            }
            let label = tick_label(tick, step);
            let half = label.len() as u32 * GLYPH;
            draw_text(
                &mut img,
                &label,
                x.saturating_sub(half).min(width.saturating_sub(2 * half)),
                bar_top + bar_h + 7,
                2,
            );
        }
        Ok(img)
    }

    /// Writes [`picture`](Self::picture) as a PNG, atomically.
    ///
    /// # Errors
    /// The map has no value, or the file cannot be written.
    pub fn write_png(
        &self,
        path: &std::path::Path,
        unit: SharpnessUnit,
        width: u32,
    ) -> Result<(), String> {
        let img = self.picture(unit, width)?;
        let mut bytes = Vec::new();
        img.write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| format!("cannot encode the PNG: {e}"))?;
        crate::io::write_atomic(path, &bytes).map_err(|e| e.to_string())
    }
}

/// "50 mm f/5.6".
fn setting_label(s: LensSetting) -> String {
    format!("{:.0} mm f/{:.1}", s.focal_mm, s.f_number)
}

/// The median distance from a measured square to its nearest neighbour (1 px for a
/// lone square).
fn typical_spacing(samples: &[([f64; 2], [f64; 3])]) -> f64 {
    let mut nearest: Vec<f64> = samples
        .iter()
        .enumerate()
        .filter_map(|(i, a)| {
            samples
                .iter()
                .enumerate()
                .filter(|(j, b)| *j != i && b.0 != a.0)
                .map(|(_, b)| (a.0[0] - b.0[0]).hypot(a.0[1] - b.0[1]))
                .min_by(f64::total_cmp)
        })
        .collect();
    if nearest.is_empty() {
        return 1.0;
    }
    nearest.sort_by(f64::total_cmp);
    nearest[nearest.len() / 2]
}

/// The colour of `v` on `range` (transparent for no value).
fn colour_of(v: f64, [lo, hi]: [f64; 2]) -> [u8; 4] {
    if !v.is_finite() {
        return [0, 0, 0, 0];
    }
    let t = ((v - lo) / (hi - lo).max(1e-12)).clamp(0.0, 1.0);
    let [r, g, b] = palette_rgb(t as f32, false);
    [r, g, b, 255]
}

/// A tick's label with as many decimals as the ticks' `step` needs (20 → "60", 0.05 →
/// "0.25").
fn tick_label(v: f64, step: f64) -> String {
    let decimals = (-step.log10().floor()).clamp(0.0, 4.0) as usize;
    format!("{v:.decimals$}")
}

/// The font's glyph size, px (drawn at 1× or 2×).
const GLYPH: u32 = 8;

/// ASCII `text` in black at (x, y), each glyph `scale` × 8 px square; other characters
/// as '?'.
fn draw_text(img: &mut image::RgbaImage, text: &str, x: u32, y: u32, scale: u32) {
    for (k, c) in text.chars().enumerate() {
        let code = if c.is_ascii() {
            c as usize
        } else {
            '?' as usize
        };
        let rows = font8x8::legacy::BASIC_LEGACY[code];
        let gx = x + k as u32 * scale * GLYPH;
        for (r, bits) in rows.iter().enumerate() {
            for b in 0..8 {
                if bits >> b & 1 == 1 {
                    for (dx, dy) in (0..scale).flat_map(|dx| (0..scale).map(move |dy| (dx, dy))) {
                        let (px, py) = (gx + scale * b + dx, y + scale * r as u32 + dy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, image::Rgba([0, 0, 0, 255]));
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round(sigma: f64) -> Option<Gaussian2> {
        Some(Gaussian2::isotropic(sigma))
    }

    #[test]
    fn a_round_blur_maps_to_its_mtf50_in_both_units() {
        let sigma = 0.8;
        let map = SharpnessMap::from_gaussians(
            (300, 200),
            (3, 2),
            Channel::G,
            Mtf50Direction::Worst,
            "test".into(),
            (0..6).map(|_| round(sigma)),
        );
        let want = (std::f64::consts::LN_2 / (2.0 * std::f64::consts::PI.powi(2))).sqrt() / sigma;
        let v = map.at(10.0, 10.0, SharpnessUnit::CyclesPerPixel).unwrap();
        assert!((v - want).abs() < 1e-12, "{v} vs {want}");
        let lp = map
            .at(10.0, 10.0, SharpnessUnit::LpPerPictureHeight)
            .unwrap();
        assert!((lp - want * 200.0).abs() < 1e-9);
        assert_eq!(map.at(300.0, 10.0, SharpnessUnit::CyclesPerPixel), None);
    }

    #[test]
    fn worst_best_and_isotropic_follow_the_ellipse() {
        let g = Gaussian2::from_covariance(4.0, 1.0, 0.0);
        let of = |d| {
            SharpnessMap::from_gaussians((10, 10), (1, 1), Channel::G, d, String::new(), [Some(g)])
                .cycles_per_px[0]
        };
        let (w, b, i) = (
            of(Mtf50Direction::Worst),
            of(Mtf50Direction::Best),
            of(Mtf50Direction::Isotropic),
        );
        assert!(w < i && i < b, "{w} {i} {b}");
        assert!(
            (w * 2.0 - b).abs() < 1e-12,
            "σ 2 against 1: worst is half the best"
        );
        assert!((i - (w * b).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn a_measured_map_interpolates_the_squares_and_stops_where_the_chart_did() {
        use crate::kernel::file::KernelSample;
        // A chart covering the left half of a 400 × 100 frame: squares every 20 px,
        // blur growing to the right.
        let sample = |x: f64, y: f64| KernelSample {
            x,
            y,
            channel: Channel::G,
            cxx: Some(0.5 + x / 200.0),
            cyy: Some(0.5 + x / 200.0),
            cor: Some(0.0),
            row: None,
            col: None,
            ml: None,
            kernel: None,
        };
        let samples = (0..10)
            .flat_map(|i| {
                (0..5).map(move |j| sample(10.0 + 20.0 * f64::from(i), 10.0 + 20.0 * f64::from(j)))
            })
            .collect();
        let file = KernelsFile {
            schema: String::new(),
            width: 400,
            height: 100,
            focal_mm: None,
            f_number: None,
            focus_distance_m: None,
            oversample: 3,
            identity: None,
            source: None,
            samples,
            failed: Vec::new(),
        };
        let map =
            SharpnessMap::measured(&file, Channel::G, Mtf50Direction::Worst, "t".into()).unwrap();
        assert_eq!(map.grid, (48, 12));
        let at = |x| map.at(x, 50.0, SharpnessUnit::CyclesPerPixel);
        // Sharper on the left, where the blur is smaller; nothing beyond the chart.
        assert!(at(20.0).unwrap() > at(180.0).unwrap());
        assert_eq!(at(390.0), None);
        assert!(
            SharpnessMap::measured(&file, Channel::R, Mtf50Direction::Worst, "t".into()).is_err()
        );
        // Its own truth is itself.
        assert_eq!(map.median_relative_error(&map), Some(0.0));
        // Its corners are the nearest cells the chart reached: the left ones sharper
        // than the right ones, whose blur the chart's right edge set.
        let s = map.summary(SharpnessUnit::CyclesPerPixel).unwrap();
        assert!(s.corners.is_finite() && s.corners < s.max && s.corners > s.min);
    }

    #[test]
    fn the_csv_has_a_row_per_cell_and_the_picture_a_colour_bar() {
        let map = SharpnessMap::from_gaussians(
            (480, 320),
            map_grid((480, 320)),
            Channel::G,
            Mtf50Direction::Isotropic,
            "test".into(),
            (0..48 * 32).map(|k| round(0.5 + f64::from(k % 48) / 40.0)),
        );
        let csv = map.csv();
        assert_eq!(csv.lines().count(), 1 + 48 * 32);
        assert!(
            csv.lines()
                .nth(1)
                .unwrap()
                .starts_with("5.0,5.0,G,isotropic,")
        );
        let img = map.picture(SharpnessUnit::LpPerPictureHeight, 480).unwrap();
        assert_eq!(img.width(), 480);
        assert!(img.height() > 320);
        // Sharp on the left (yellow end of viridis), soft on the right (purple end).
        let left = img.get_pixel(3, 40 + 100).0;
        let right = img.get_pixel(476, 40 + 100).0;
        assert!(
            left[1] > right[1] && right[2] > right[1],
            "{left:?} {right:?}"
        );
    }
}
