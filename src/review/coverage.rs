//! Where on the sensor the chart has been, per setting: the map a photographer reads to
//! see which parts of the frame a small chart shot at several positions has covered,
//! and the words that name the parts still missing.
//!
//! A shot covers the region the squares whose kernels it measured span: the convex
//! hull of those squares (each taken as its centre widened by half the chart's pitch
//! there; the chart is flat, so what lies between two measured squares is chart too,
//! a clipped or set-aside square inside it included). A setting's coverage is the
//! union over its shots, on a raster of [`COVERAGE_CELLS`] cells; the frame's nine
//! parts (top-left … bottom-right, as the trust zones name them) each count as covered
//! when [`PART_COVERED`] of their area is.

use crate::kernel::file::KernelsFile;
use crate::model::Dataset;
use crate::plane::{Channel, LensSetting};
use crate::profile::trust::{zone_name, zone_of};
use std::collections::HashMap;

/// Cells across and down the coverage map: fine enough to show a small chart's
/// footprint at 3 × 3 positions (each a ninth of the frame spans 4 × 3 cells with
/// room to show the overlaps), coarse enough to draw small beside each setting.
pub const COVERAGE_CELLS: [usize; 2] = [24, 16];

/// The frame is named in 3 × 3 parts (top-left, top, …), as the trust zones are.
pub const COVERAGE_PARTS: [usize; 2] = [3, 3];

/// The share of a part's area the chart must have covered for the part to count.
/// A chart filling 86 % of the frame, its outermost squares set aside, still covers
/// about a third of each corner part; a 3 × 3 series with its corner position left
/// out covers well under a tenth of that corner (the neighbouring positions' overlap).
pub const PART_COVERED: f64 = 0.25;

/// Where the chart has been at one setting.
#[derive(Clone, Debug, PartialEq)]
pub struct SettingCoverage {
    pub setting: LensSetting,
    /// Shots at the setting whose chart was found.
    pub shots: usize,
    /// Row-major, [`COVERAGE_CELLS`]: the share (0–1) of each cell the chart covered
    /// in at least one shot.
    pub cells: Vec<f32>,
    /// Row-major, [`COVERAGE_PARTS`]: the share of each part of the frame covered.
    pub parts: Vec<f64>,
}

impl SettingCoverage {
    /// The share of the whole frame the chart covered.
    #[must_use]
    pub fn frame_share(&self) -> f64 {
        self.cells.iter().map(|&c| f64::from(c)).sum::<f64>() / self.cells.len().max(1) as f64
    }

    /// The parts of the frame (top-left, top, …) not yet covered, in reading order.
    #[must_use]
    pub fn missing_parts(&self) -> Vec<String> {
        self.parts
            .iter()
            .enumerate()
            .filter(|&(_, &share)| share < PART_COVERED)
            .map(|(k, _)| zone_name(k, COVERAGE_PARTS))
            .collect()
    }

    /// One line for people, e.g. "24 mm f/4.0: top-left and bottom-right not yet
    /// covered (the chart has been over 81 % of the frame in 7 shots)"; `None` when
    /// every part is covered.
    #[must_use]
    pub fn missing_line(&self) -> Option<String> {
        let missing = self.missing_parts();
        if missing.is_empty() {
            return None;
        }
        let parts = match missing.as_slice() {
            [one] => one.clone(),
            [init @ .., last] => format!("{} and {last}", init.join(", ")),
            [] => String::new(),
        };
        Some(format!(
            "{:.0} mm f/{:.1}: {parts} not yet covered (the chart has been over {:.0} % of the frame in {} shot{}); put the chart there next",
            self.setting.focal_mm,
            self.setting.f_number,
            100.0 * self.frame_share(),
            self.shots,
            if self.shots == 1 { "" } else { "s" }
        ))
    }
}

/// Samples per cell side when a shot's footprint is rasterised: a cell's share is the
/// fraction of its 4 × 4 sample points inside the footprint.
const SAMPLES_PER_CELL: usize = 4;

/// Where the chart has been at each setting, from the kernels measured on a session's
/// shots (each with its setting) on a `width × height` sensor; settings in the order
/// first met. Shots with no kernel add nothing and are not counted.
#[must_use]
pub fn coverage<'a>(
    size: (usize, usize),
    shots: impl IntoIterator<Item = (LensSetting, &'a KernelsFile)>,
) -> Vec<SettingCoverage> {
    coverage_of_points(
        size,
        shots.into_iter().map(|(setting, k)| {
            let measured = k.samples.iter().filter(|s| s.cxx.is_some());
            (
                setting,
                footprint(measured.filter_map(|s| Some(([s.row?, s.col?], s.channel, [s.x, s.y])))),
            )
        }),
    )
}

/// [`coverage`] of the samples a calibration fits, shot by shot.
#[must_use]
pub fn coverage_of_dataset(ds: &Dataset) -> Vec<SettingCoverage> {
    coverage_of_points(
        (ds.width, ds.height),
        ds.shots.iter().enumerate().map(|(i, shot)| {
            let samples = ds.samples.iter().filter(|s| s.shot == i);
            (
                LensSetting {
                    focal_mm: shot.focal_mm,
                    f_number: shot.f_number,
                },
                footprint(samples.filter_map(|s| Some((s.square?, s.channel, [s.x, s.y])))),
            )
        }),
    )
}

/// The points whose hull is the region a shot's measured squares (row and column,
/// channel, centre) span: each square's centre widened by half the pitch between
/// neighbouring squares (8 points around it).
fn footprint(squares: impl Iterator<Item = ([usize; 2], Channel, [f64; 2])>) -> Vec<[f64; 2]> {
    let at: HashMap<([usize; 2], Channel), [f64; 2]> =
        squares.map(|(rc, ch, p)| ((rc, ch), p)).collect();
    // Neighbours along a row or column are one pitch apart, diagonal ones √2 (a chart
    // measured every other square has only those).
    let mut pitches: Vec<f64> = Vec::new();
    for (&([r, c], ch), a) in &at {
        for (dr, dc, apart) in [(0, 1, 1.0), (1, 0, 1.0), (1, 1, std::f64::consts::SQRT_2)] {
            if let Some(b) = at.get(&([r + dr, c + dc], ch)) {
                pitches.push((a[0] - b[0]).hypot(a[1] - b[1]) / apart);
            }
        }
    }
    if pitches.is_empty() {
        return Vec::new();
    }
    pitches.sort_by(f64::total_cmp);
    let half = pitches[pitches.len() / 2] / 2.0;
    at.values()
        .flat_map(|p| {
            (0..8).map(move |i| {
                let a = f64::from(i) * std::f64::consts::FRAC_PI_4;
                [p[0] + half * a.cos(), p[1] + half * a.sin()]
            })
        })
        .collect()
}

/// [`coverage`] from the points whose hull is each shot's footprint, sensor px.
#[must_use]
pub fn coverage_of_points(
    (width, height): (usize, usize),
    shots: impl IntoIterator<Item = (LensSetting, Vec<[f64; 2]>)>,
) -> Vec<SettingCoverage> {
    let [cx, cy] = COVERAGE_CELLS;
    let (sx, sy) = (cx * SAMPLES_PER_CELL, cy * SAMPLES_PER_CELL);
    // One covered flag per sample point, per setting.
    let mut hits: Vec<(LensSetting, usize, Vec<bool>)> = Vec::new();
    for (setting, corners) in shots {
        let hull = convex_hull(corners);
        if hull.len() < 3 {
            continue;
        }
        let k = match hits.iter().position(|(s, _, _)| s.same_as(setting)) {
            Some(k) => k,
            None => {
                hits.push((setting, 0, vec![false; sx * sy]));
                hits.len() - 1
            }
        };
        hits[k].1 += 1;
        for j in 0..sy {
            let y = (j as f64 + 0.5) / sy as f64 * height as f64;
            for i in 0..sx {
                let x = (i as f64 + 0.5) / sx as f64 * width as f64;
                if !hits[k].2[j * sx + i] && inside_convex(&hull, [x, y]) {
                    hits[k].2[j * sx + i] = true;
                }
            }
        }
    }
    hits.into_iter()
        .map(|(setting, shots, hit)| {
            let mut cells = vec![0.0f32; cx * cy];
            let [px, py] = COVERAGE_PARTS;
            let mut parts = vec![(0usize, 0usize); px * py];
            for j in 0..sy {
                for i in 0..sx {
                    let covered = hit[j * sx + i];
                    if covered {
                        cells[(j / SAMPLES_PER_CELL) * cx + i / SAMPLES_PER_CELL] += 1.0;
                    }
                    let (x, y) = (
                        (i as f64 + 0.5) / sx as f64 * width as f64,
                        (j as f64 + 0.5) / sy as f64 * height as f64,
                    );
                    let part = &mut parts[zone_of(x, y, (width, height), COVERAGE_PARTS)];
                    part.0 += usize::from(covered);
                    part.1 += 1;
                }
            }
            let per_cell = (SAMPLES_PER_CELL * SAMPLES_PER_CELL) as f32;
            cells.iter_mut().for_each(|c| *c /= per_cell);
            SettingCoverage {
                setting,
                shots,
                cells,
                parts: parts
                    .iter()
                    .map(|&(n, of)| n as f64 / of.max(1) as f64)
                    .collect(),
            }
        })
        .collect()
}

/// The convex hull of `points`, counter-clockwise in a y-down frame's maths sense
/// (Andrew's monotone chain); fewer than three points for a degenerate set.
fn convex_hull(mut points: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    points.retain(|p| p[0].is_finite() && p[1].is_finite());
    points.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    points.dedup();
    if points.len() < 3 {
        return points;
    }
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(2 * points.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(points.iter())
        } else {
            Box::new(points.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Whether `p` lies inside (or on) the convex polygon `hull` (as [`convex_hull`]
/// orders it).
fn inside_convex(hull: &[[f64; 2]], p: [f64; 2]) -> bool {
    hull.iter()
        .zip(hull.iter().cycle().skip(1))
        .all(|(a, b)| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hull_of_a_square_and_its_inside() {
        let hull = convex_hull(vec![
            [0.0, 0.0],
            [2.0, 0.0],
            [1.0, 1.0],
            [2.0, 2.0],
            [0.0, 2.0],
            [1.0, 0.0],
        ]);
        assert_eq!(hull.len(), 4, "{hull:?}");
        assert!(inside_convex(&hull, [1.0, 1.0]));
        assert!(inside_convex(&hull, [0.1, 1.9]));
        assert!(!inside_convex(&hull, [2.1, 1.0]));
        assert!(!inside_convex(&hull, [1.0, -0.1]));
        assert!(convex_hull(vec![[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]).len() < 3);
    }

    /// A rectangle's corners as a shot's footprint.
    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
        vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    }

    #[test]
    fn parts_left_out_of_a_series_are_named() {
        let (w, h) = (600.0, 400.0);
        let at = |f: f64| LensSetting {
            focal_mm: f,
            f_number: 4.0,
        };
        // A chart over a third of the frame at 3 × 3 positions tiling 86 % of it, the
        // top-left and bottom-right positions not shot; and a filling chart at 50 mm.
        let (cw, ch) = (0.36 * w, 0.36 * h);
        let mut shots = Vec::new();
        for r in 0..3 {
            for c in 0..3 {
                if (r, c) == (0, 0) || (r, c) == (2, 2) {
                    continue;
                }
                let x0 = 0.07 * w + c as f64 * (0.86 * w - cw) / 2.0;
                let y0 = 0.07 * h + r as f64 * (0.86 * h - ch) / 2.0;
                shots.push((at(24.0), rect(x0, y0, x0 + cw, y0 + ch)));
            }
        }
        // The filling chart with its outermost squares (a 12th of it) set aside.
        let m = 0.07 + 0.86 / 12.0;
        shots.push((at(50.0), rect(m * w, m * h, (1.0 - m) * w, (1.0 - m) * h)));
        let cov = coverage_of_points((600, 400), shots);
        assert_eq!(cov.len(), 2);
        assert_eq!(cov[0].shots, 7);
        assert_eq!(cov[0].missing_parts(), ["top-left", "bottom-right"]);
        let line = cov[0].missing_line().expect("a line");
        assert!(
            line.starts_with("24 mm f/4.0: top-left and bottom-right not yet covered"),
            "{line}"
        );
        assert!(cov[1].missing_parts().is_empty(), "{:?}", cov[1].parts);
        assert_eq!(cov[1].missing_line(), None);
        // The filling chart's share of the frame: (1 − 2m)².
        let share = (1.0 - 2.0 * m) * (1.0 - 2.0 * m);
        assert!(
            (cov[1].frame_share() - share).abs() < 0.02,
            "{}",
            cov[1].frame_share()
        );
        for c in &cov {
            assert!(c.cells.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}
