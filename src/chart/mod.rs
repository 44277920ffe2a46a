//! The calibration chart: a checkerboard whose squares each hold five circles of the
//! opposite colour, as the five on a die (its spec: docs/formats.md, "Chart spec"), and its exact rasterisation.
//!
//! Chart units: one square = 1.0, origin at the checkerboard's top-left corner, x right,
//! y down. The white margin extends `margin` squares beyond the checkerboard.
//!
//! Rasterisation is exact rather than supersampled: a projective map takes lines to
//! lines and conics to conics, so every chart square becomes a convex quadrilateral in
//! the image and every circle an ellipse. A pixel's value is the exact area of the pixel
//! square covered by white, by polygon clipping for quadrilaterals and, for ellipses, an
//! affine map to the unit circle (affine maps keep area ratios) and the exact
//! polygon–disc intersection area.

pub mod export;

use crate::geometry::Homography;
use crate::plane::Plane;
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What was printed. Field names are part of the file contract (docs/formats.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChartSpec {
    #[serde(default = "default_cols")]
    pub cols: usize,
    #[serde(default = "default_rows")]
    pub rows: usize,
    /// White border around the checkerboard, in squares.
    #[serde(default = "default_margin")]
    pub margin: f64,
    /// Printed side of one square, in millimetres.
    #[serde(default = "default_square_mm")]
    pub square_mm: f64,
    /// Circle radius as a fraction of the square side.
    #[serde(default = "default_circle_radius")]
    pub circle_radius: f64,
    /// Circle centres within a square, in square units.
    #[serde(default = "default_circle_centres")]
    pub circle_centres: Vec<[f64; 2]>,
    #[serde(default = "default_black_top_left")]
    pub black_top_left: bool,
}

fn default_cols() -> usize {
    24
}
fn default_rows() -> usize {
    16
}
fn default_margin() -> f64 {
    1.0
}
fn default_square_mm() -> f64 {
    20.0
}
fn default_circle_radius() -> f64 {
    0.1
}
fn default_circle_centres() -> Vec<[f64; 2]> {
    vec![
        [0.5, 0.5],
        [0.25, 0.25],
        [0.75, 0.25],
        [0.25, 0.75],
        [0.75, 0.75],
    ]
}
fn default_black_top_left() -> bool {
    true
}

impl Default for ChartSpec {
    fn default() -> Self {
        Self {
            cols: default_cols(),
            rows: default_rows(),
            margin: default_margin(),
            square_mm: default_square_mm(),
            circle_radius: default_circle_radius(),
            circle_centres: default_circle_centres(),
            black_top_left: default_black_top_left(),
        }
    }
}

/// The chart spec file's version. A spec written by hand, or inline in a manifest or
/// session, has no schema and is version 1.
pub const CHART_SCHEMA: crate::format::Schema = crate::format::Schema {
    kind: "chart",
    current: 1,
    unversioned: Some(1),
};

#[derive(Debug, thiserror::Error)]
pub enum ChartError {
    #[error("{reason}")]
    Read { path: String, reason: String },
    #[error("{path}: not a chart spec: {reason}")]
    Parse { path: String, reason: String },
    #[error("invalid chart spec: {0}")]
    Invalid(String),
}

impl ChartSpec {
    /// Reads and validates a chart spec file.
    ///
    /// # Errors
    /// Unreadable file, malformed JSON, or a spec that [`ChartSpec::validate`] refuses.
    pub fn load(path: &Path) -> Result<Self, ChartError> {
        let text = crate::io::read_json_text(path).map_err(|e| ChartError::Read {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::from_json(&path.display().to_string(), &text)
    }

    /// Parses and validates a chart spec file's text; `origin` names it in errors.
    ///
    /// # Errors
    /// As [`ChartSpec::load`].
    pub fn from_json(origin: &str, text: &str) -> Result<Self, ChartError> {
        let parse = |reason: String| ChartError::Parse {
            path: origin.into(),
            reason,
        };
        CHART_SCHEMA
            .version_of_json(text)
            .map_err(|e| parse(e.to_string()))?;
        let spec: ChartSpec = serde_json::from_str(text).map_err(|e| parse(e.to_string()))?;
        spec.validate().map_err(|e| parse(e.to_string()))?;
        Ok(spec)
    }

    /// Writes the spec as a chart spec file (with its schema), atomically.
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn save(&self, path: &Path) -> Result<(), crate::io::WriteError> {
        #[derive(Serialize)]
        struct File<'a> {
            schema: String,
            #[serde(flatten)]
            spec: &'a ChartSpec,
        }
        crate::io::write_json(
            path,
            &File {
                schema: CHART_SCHEMA.tag(),
                spec: self,
            },
        )
    }

    /// Checks that the chart is one we can print and detect.
    ///
    /// # Errors
    /// A description of the first problem found.
    pub fn validate(&self) -> Result<(), ChartError> {
        if !(2..=200).contains(&self.cols) || !(2..=200).contains(&self.rows) {
            return Err(ChartError::Invalid(format!(
                "cols and rows must be between 2 and 200 (got {} × {})",
                self.cols, self.rows
            )));
        }
        if !(self.margin.is_finite() && (0.25..=20.0).contains(&self.margin)) {
            return Err(ChartError::Invalid(format!(
                "margin must be 0.25–20 squares (got {})",
                self.margin
            )));
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.5 && self.square_mm < 1000.0) {
            return Err(ChartError::Invalid(format!(
                "square_mm must be 0.5–1000 (got {})",
                self.square_mm
            )));
        }
        if !(self.circle_radius.is_finite() && self.circle_radius > 0.0 && self.circle_radius < 0.5)
        {
            return Err(ChartError::Invalid(format!(
                "circle_radius must be in (0, 0.5) (got {})",
                self.circle_radius
            )));
        }
        for c in &self.circle_centres {
            let r = self.circle_radius;
            if !(c[0] - r > 0.0 && c[0] + r < 1.0 && c[1] - r > 0.0 && c[1] + r < 1.0) {
                return Err(ChartError::Invalid(format!(
                    "circle at ({}, {}) with radius {r} leaves its square",
                    c[0], c[1]
                )));
            }
        }
        Ok(())
    }

    /// True when square (col, row) is black.
    #[must_use]
    pub fn is_black(&self, col: usize, row: usize) -> bool {
        (col + row).is_multiple_of(2) == self.black_top_left
    }

    /// Corners of square (col, row) in chart units, in chart order: top-left,
    /// top-right, bottom-right, bottom-left.
    #[must_use]
    pub fn square_corners(&self, col: usize, row: usize) -> [[f64; 2]; 4] {
        let (x, y) = (col as f64, row as f64);
        [[x, y], [x + 1.0, y], [x + 1.0, y + 1.0], [x, y + 1.0]]
    }

    /// The paper's outline (checkerboard plus margin) in chart units.
    #[must_use]
    pub fn paper_corners(&self) -> [[f64; 2]; 4] {
        let m = self.margin;
        let (w, h) = (self.cols as f64, self.rows as f64);
        [[-m, -m], [w + m, -m], [w + m, h + m], [-m, h + m]]
    }

    /// Printed size of the paper in millimetres (width, height).
    #[must_use]
    pub fn paper_mm(&self) -> (f64, f64) {
        let m = 2.0 * self.margin;
        (
            (self.cols as f64 + m) * self.square_mm,
            (self.rows as f64 + m) * self.square_mm,
        )
    }

    /// The largest square side, in whole half-millimetres, at which this chart's paper
    /// (its squares and white border) fits on `paper` in landscape, inside the
    /// [`PRINTER_MARGIN_MM`] most printers leave blank at each edge.
    #[must_use]
    pub fn square_to_fill(&self, paper: Paper) -> f64 {
        let (w, h) = paper.landscape_mm();
        let m = 2.0 * self.margin;
        let across = (w - 2.0 * PRINTER_MARGIN_MM) / (self.cols as f64 + m);
        let down = (h - 2.0 * PRINTER_MARGIN_MM - NOTES_MM) / (self.rows as f64 + m);
        (across.min(down) * 2.0).floor() / 2.0
    }

    /// Whether the chart's paper, with the notes strip the PDF prints below it, fits
    /// on `paper` in landscape inside the printer's margins.
    #[must_use]
    pub fn fits(&self, paper: Paper) -> bool {
        let (w, h) = self.paper_mm();
        let (pw, ph) = paper.landscape_mm();
        // A hundredth of a millimetre for the rounding of the sheets' sizes.
        w <= pw - 2.0 * PRINTER_MARGIN_MM + 0.01
            && h + NOTES_MM <= ph - 2.0 * PRINTER_MARGIN_MM + 0.01
    }

    /// The first sheet of [`Paper::ALL`] the chart fits on ([`ChartSpec::fits`]);
    /// `None` where it fits none.
    #[must_use]
    pub fn sheet(&self) -> Option<Paper> {
        Paper::ALL.into_iter().find(|&p| self.fits(p))
    }

    /// Whether the chart point is white; `None` outside the paper. The reference
    /// against which the exact rasteriser is tested.
    #[must_use]
    pub fn is_white_at(&self, p: [f64; 2]) -> Option<bool> {
        let m = self.margin;
        let (w, h) = (self.cols as f64, self.rows as f64);
        if p[0] < -m || p[1] < -m || p[0] > w + m || p[1] > h + m {
            return None;
        }
        if p[0] < 0.0 || p[1] < 0.0 || p[0] >= w || p[1] >= h {
            return Some(true);
        }
        let (col, row) = (p[0].floor() as usize, p[1].floor() as usize);
        let square_black = self.is_black(col, row);
        let (u, v) = (p[0] - col as f64, p[1] - row as f64);
        let in_circle = self
            .circle_centres
            .iter()
            .any(|c| (u - c[0]).powi(2) + (v - c[1]).powi(2) <= self.circle_radius.powi(2));
        Some(square_black == in_circle)
    }
}

/// Rasterises the chart through `image_from_chart` into a `width × height` plane. Pixel
/// (i, j) covers `[i − ½, i + ½] × [j − ½, j + ½]` in image coordinates; its value is the
/// exact fraction of that area that is white (white = 1, black = 0); area outside the
/// paper takes `background`. For a crop or an oversampled grid, compose the homography
/// with the translation/scaling first.
///
/// Large images are cut into bands of rows rasterised in parallel; each band sees every
/// shape but skips those whose bounding box misses it.
#[must_use]
pub fn rasterize(
    spec: &ChartSpec,
    image_from_chart: &Homography,
    width: usize,
    height: usize,
    background: f32,
) -> Plane {
    const BAND_ROWS: usize = 128;
    if height <= BAND_ROWS || width * height < 1 << 18 {
        return rasterize_serial(spec, image_from_chart, (width, height), background);
    }
    use rayon::prelude::*;
    let bands: Vec<Plane> = (0..height.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|b| {
            let y0 = b * BAND_ROWS;
            let rows = BAND_ROWS.min(height - y0);
            let band_from_chart =
                Homography::translation(0.0, -(y0 as f64)).compose(image_from_chart);
            rasterize_serial(spec, &band_from_chart, (width, rows), background)
        })
        .collect();
    let mut data = Vec::with_capacity(width * height);
    for band in bands {
        data.extend_from_slice(&band.data);
    }
    Plane {
        width,
        height,
        data,
    }
}

fn rasterize_serial(
    spec: &ChartSpec,
    image_from_chart: &Homography,
    (width, height): (usize, usize),
    background: f32,
) -> Plane {
    let mut acc = vec![0.0f64; width * height];
    let bg = f64::from(background);
    // Outside the paper: background; inside: white, then black squares carved out.
    let paper = project_quad(image_from_chart, &spec.paper_corners());
    let mut covered = vec![0.0f64; width * height];
    add_quad_coverage(&mut covered, width, height, &paper, 1.0);
    for (a, c) in acc.iter_mut().zip(&covered) {
        *a = c + (1.0 - c) * bg;
    }
    let Some(chart_from_image) = image_from_chart.inverse() else {
        return Plane::filled(width, height, background);
    };
    let (cols, rows) = visible_cells(spec, &chart_from_image, width, height);
    for row in rows {
        for col in cols.clone() {
            let black = spec.is_black(col, row);
            if black {
                let q = project_quad(image_from_chart, &spec.square_corners(col, row));
                add_quad_coverage(&mut acc, width, height, &q, -1.0);
            }
            for c in &spec.circle_centres {
                let centre = [col as f64 + c[0], row as f64 + c[1]];
                let sign = if black { 1.0 } else { -1.0 };
                add_circle_coverage(
                    &mut acc,
                    width,
                    height,
                    &chart_from_image,
                    centre,
                    spec.circle_radius,
                    sign,
                );
            }
        }
    }
    Plane {
        width,
        height,
        data: acc.into_iter().map(|v| v.clamp(0.0, 1.0) as f32).collect(),
    }
}

/// The chart squares (columns, rows) that can touch the window: the window's corners
/// mapped to the chart bound what it sees, as long as the horizon (where the projective
/// map sends points to infinity) stays out of the window; otherwise every square.
fn visible_cells(
    spec: &ChartSpec,
    chart_from_image: &Homography,
    width: usize,
    height: usize,
) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
    let all = (0..spec.cols, 0..spec.rows);
    let (w, h) = (width as f64 - 0.5, height as f64 - 0.5);
    let m = &chart_from_image.0;
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    let mut sign = 0.0f64;
    for p in [[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]] {
        let z = m[(2, 0)] * p[0] + m[(2, 1)] * p[1] + m[(2, 2)];
        if sign == 0.0 {
            sign = z.signum();
        }
        if !(z.abs() > 1e-12) || z.signum() != sign {
            return all;
        }
        let c = chart_from_image.apply(p);
        for k in 0..2 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let span = |lo: f64, hi: f64, n: usize| -> std::ops::Range<usize> {
        if !(lo.is_finite() && hi.is_finite()) {
            return 0..n;
        }
        let a = lo.floor().clamp(0.0, n as f64) as usize;
        let b = (hi.floor() + 1.0).clamp(0.0, n as f64) as usize;
        a..b.max(a)
    };
    (span(lo[0], hi[0], spec.cols), span(lo[1], hi[1], spec.rows))
}

fn project_quad(h: &Homography, q: &[[f64; 2]; 4]) -> [[f64; 2]; 4] {
    [h.apply(q[0]), h.apply(q[1]), h.apply(q[2]), h.apply(q[3])]
}

/// Pixels of row `y` that a convex shape touches, and those it covers whole, from the
/// shape's horizontal chords at the row's top and bottom edges and its extreme points
/// within the row. `any` is the x-extent of the shape within the row; `full` the
/// x-interval inside the shape all the way from top to bottom (empty when a chord is
/// missing). By convexity a pixel whose x-extent lies in `full` is covered whole.
struct RowSpan {
    any: (f64, f64),
    full: (f64, f64),
}

impl RowSpan {
    fn new(top: Option<(f64, f64)>, bottom: Option<(f64, f64)>, inside: &[f64]) -> Option<Self> {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for c in [top, bottom].into_iter().flatten() {
            lo = lo.min(c.0);
            hi = hi.max(c.1);
        }
        for &x in inside {
            lo = lo.min(x);
            hi = hi.max(x);
        }
        if !(lo <= hi) {
            return None;
        }
        let full = match (top, bottom) {
            (Some(t), Some(b)) => (t.0.max(b.0), t.1.min(b.1)),
            _ => (f64::INFINITY, f64::NEG_INFINITY),
        };
        Some(Self {
            any: (lo, hi),
            full,
        })
    }

    /// Pixel columns touched, clipped to the image.
    fn columns(&self, width: usize) -> std::ops::RangeInclusive<usize> {
        let a = (self.any.0 + 0.5).floor().max(0.0);
        let b = (self.any.1 + 0.5).floor().min(width as f64 - 1.0);
        if b < a {
            #[allow(clippy::reversed_empty_ranges)]
            return 1..=0;
        }
        a as usize..=b as usize
    }

    fn covers(&self, x: usize) -> bool {
        let x = x as f64;
        x - 0.5 >= self.full.0 && x + 0.5 <= self.full.1
    }
}

/// Rows `[y0, y1]` of the image a shape spanning `[top, bottom]` touches.
fn rows_touched(top: f64, bottom: f64, height: usize) -> Option<(usize, usize)> {
    if !(top.is_finite() && bottom.is_finite()) || height == 0 {
        return None;
    }
    let a = (top + 0.5).floor().max(0.0);
    let b = (bottom + 0.5).floor().min(height as f64 - 1.0);
    (b >= a).then_some((a as usize, b as usize))
}

/// The x-interval where the horizontal line at `t` meets the convex polygon.
fn polygon_chord(poly: &[[f64; 2]; 4], t: f64) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for i in 0..4 {
        let (a, b) = (poly[i], poly[(i + 1) % 4]);
        let (ylo, yhi) = (a[1].min(b[1]), a[1].max(b[1]));
        if t < ylo || t > yhi {
            continue;
        }
        if yhi > ylo {
            let x = a[0] + (t - a[1]) * (b[0] - a[0]) / (b[1] - a[1]);
            lo = lo.min(x);
            hi = hi.max(x);
        } else {
            lo = lo.min(a[0].min(b[0]));
            hi = hi.max(a[0].max(b[0]));
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Adds `sign ×` the exact area of each pixel covered by the convex quad: whole pixels
/// by their row spans, boundary pixels by polygon clipping.
fn add_quad_coverage(
    acc: &mut [f64],
    width: usize,
    height: usize,
    quad: &[[f64; 2]; 4],
    sign: f64,
) {
    if quad.iter().any(|p| !(p[0].is_finite() && p[1].is_finite())) {
        return;
    }
    // Orient counter-clockwise in a y-up sense (positive shoelace area) so "inside" is
    // the left of every edge.
    let mut q = *quad;
    if shoelace(&q) < 0.0 {
        q.reverse();
    }
    let edges: [([f64; 2], [f64; 2]); 4] = std::array::from_fn(|i| (q[i], q[(i + 1) % 4]));
    let top = q.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
    let bottom = q.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max);
    let Some((y0, y1)) = rows_touched(top, bottom, height) else {
        return;
    };
    for y in y0..=y1 {
        let (yt, yb) = (y as f64 - 0.5, y as f64 + 0.5);
        let inside: Vec<f64> = q
            .iter()
            .filter(|p| p[1] > yt && p[1] < yb)
            .map(|p| p[0])
            .collect();
        let Some(span) = RowSpan::new(polygon_chord(&q, yt), polygon_chord(&q, yb), &inside) else {
            continue;
        };
        let row = &mut acc[y * width..(y + 1) * width];
        for x in span.columns(width) {
            if span.covers(x) {
                row[x] += sign;
                continue;
            }
            let fx = x as f64;
            let corners = [
                [fx - 0.5, yt],
                [fx + 0.5, yt],
                [fx + 0.5, yb],
                [fx - 0.5, yb],
            ];
            row[x] += sign * clip_area(&corners, &edges);
        }
    }
}

#[inline]
fn cross(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

fn shoelace(poly: &[[f64; 2]]) -> f64 {
    let n = poly.len();
    let mut s = 0.0;
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + 1) % n]);
        s += a[0] * b[1] - b[0] * a[1];
    }
    0.5 * s
}

/// Area of the pixel square clipped by the convex polygon whose edges keep their left
/// side (Sutherland–Hodgman).
fn clip_area(square: &[[f64; 2]; 4], edges: &[([f64; 2], [f64; 2])]) -> f64 {
    let mut poly: Vec<[f64; 2]> = square.to_vec();
    if shoelace(&poly) < 0.0 {
        poly.reverse();
    }
    let mut next = Vec::with_capacity(12);
    for (a, b) in edges {
        next.clear();
        let n = poly.len();
        for i in 0..n {
            let p = poly[i];
            let q = poly[(i + 1) % n];
            let dp = cross(*a, *b, p);
            let dq = cross(*a, *b, q);
            if dp >= 0.0 {
                next.push(p);
            }
            if (dp >= 0.0) != (dq >= 0.0) {
                let t = dp / (dp - dq);
                next.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
            }
        }
        std::mem::swap(&mut poly, &mut next);
        if poly.len() < 3 {
            return 0.0;
        }
    }
    shoelace(&poly).abs()
}

/// The image of a chart circle: the ellipse (p − c)ᵀ M (p − c) = 1, with the affine map
/// T (Tᵀ T = M) that takes it to the unit disc.
struct Ellipse {
    centre: [f64; 2],
    m11: f64,
    m12: f64,
    m22: f64,
    /// T = [[l11, l21], [0, l22]].
    l11: f64,
    l21: f64,
    l22: f64,
}

impl Ellipse {
    /// `None` when the circle's image is not an ellipse (it crosses the horizon).
    fn of_circle(chart_from_image: &Homography, centre: [f64; 2], radius: f64) -> Option<Self> {
        // Conic of the circle in chart coordinates: [x y 1] C [x y 1]ᵀ = 0; in the
        // image, C' = H⁻ᵀ C H⁻¹.
        let (cx, cy, r) = (centre[0], centre[1], radius);
        let c = Matrix3::new(
            1.0,
            0.0,
            -cx,
            0.0,
            1.0,
            -cy,
            -cx,
            -cy,
            cx * cx + cy * cy - r * r,
        );
        let hinv = chart_from_image.0;
        let ci = hinv.transpose() * c * hinv;
        // A x² + 2B xy + C y² + 2D x + 2E y + F = 0.
        let (a, b, cc, d, e, f) = (
            ci[(0, 0)],
            ci[(0, 1)],
            ci[(1, 1)],
            ci[(0, 2)],
            ci[(1, 2)],
            ci[(2, 2)],
        );
        let det2 = a * cc - b * b;
        if det2.abs() < 1e-300 {
            return None;
        }
        let ex = (b * e - cc * d) / det2;
        let ey = (b * d - a * e) / det2;
        let k = -(a * ex * ex + 2.0 * b * ex * ey + cc * ey * ey + 2.0 * d * ex + 2.0 * e * ey + f);
        if k.abs() < 1e-300 {
            return None;
        }
        let (m11, m12, m22) = (a / k, b / k, cc / k);
        if !(m11 > 0.0 && m11 * m22 - m12 * m12 > 0.0) {
            return None;
        }
        let l11 = m11.sqrt();
        let l21 = m12 / l11;
        let l22 = (m22 - l21 * l21).sqrt();
        Some(Self {
            centre: [ex, ey],
            m11,
            m12,
            m22,
            l11,
            l21,
            l22,
        })
    }

    /// Exact area of pixel (x, y) inside the ellipse: affine maps keep area ratios, so
    /// it is the pixel's image under T intersected with the unit disc, over det T.
    fn pixel_area(&self, x: f64, y: f64) -> f64 {
        let to_unit = |p: [f64; 2]| -> [f64; 2] {
            let (u, v) = (p[0] - self.centre[0], p[1] - self.centre[1]);
            [self.l11 * u + self.l21 * v, self.l22 * v]
        };
        let corners = [
            to_unit([x - 0.5, y - 0.5]),
            to_unit([x + 0.5, y - 0.5]),
            to_unit([x + 0.5, y + 0.5]),
            to_unit([x - 0.5, y + 0.5]),
        ];
        polygon_unit_disc_area(&corners) / (self.l11 * self.l22)
    }

    /// The x-interval where the horizontal line at `t` meets the ellipse.
    fn chord(&self, t: f64) -> Option<(f64, f64)> {
        let v = t - self.centre[1];
        let disc = self.m12 * self.m12 * v * v - self.m11 * (self.m22 * v * v - 1.0);
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        let ex = self.centre[0];
        Some((
            ex + (-self.m12 * v - s) / self.m11,
            ex + (-self.m12 * v + s) / self.m11,
        ))
    }
}

/// Adds `sign ×` the exact area of each pixel covered by the image of the chart circle:
/// whole pixels by their row spans, boundary pixels exactly.
fn add_circle_coverage(
    acc: &mut [f64],
    width: usize,
    height: usize,
    chart_from_image: &Homography,
    centre: [f64; 2],
    radius: f64,
    sign: f64,
) {
    let Some(el) = Ellipse::of_circle(chart_from_image, centre, radius) else {
        return;
    };
    let [ex, ey] = el.centre;
    // Half-widths of the bounding box: sqrt of M⁻¹'s diagonal; the leftmost and
    // rightmost points sit at v = ∓(M12/M22)·hw from the centre.
    let inv_det = 1.0 / (el.m11 * el.m22 - el.m12 * el.m12);
    let hw = (el.m22 * inv_det).sqrt();
    let hh = (el.m11 * inv_det).sqrt();
    let v_extreme = el.m12 / el.m22 * hw;
    let Some((y0, y1)) = rows_touched(ey - hh, ey + hh, height) else {
        return;
    };
    for y in y0..=y1 {
        let (yt, yb) = (y as f64 - 0.5, y as f64 + 0.5);
        let mut inside = Vec::with_capacity(2);
        if ey + v_extreme > yt && ey + v_extreme < yb {
            inside.push(ex - hw);
        }
        if ey - v_extreme > yt && ey - v_extreme < yb {
            inside.push(ex + hw);
        }
        let Some(span) = RowSpan::new(el.chord(yt), el.chord(yb), &inside) else {
            continue;
        };
        let row = &mut acc[y * width..(y + 1) * width];
        for x in span.columns(width) {
            row[x] += sign
                * if span.covers(x) {
                    1.0
                } else {
                    el.pixel_area(x as f64, y as f64)
                };
        }
    }
}

/// Exact area of a simple polygon ∩ the unit disc at the origin, as the sum over edges of
/// the signed area of triangle (origin, pᵢ, pᵢ₊₁) ∩ disc.
fn polygon_unit_disc_area(poly: &[[f64; 2]]) -> f64 {
    let n = poly.len();
    let mut s = 0.0;
    for i in 0..n {
        s += triangle_disc_area(poly[i], poly[(i + 1) % n]);
    }
    s.abs()
}

/// Signed area of triangle (0, a, b) ∩ unit disc.
fn triangle_disc_area(a: [f64; 2], b: [f64; 2]) -> f64 {
    let d = [b[0] - a[0], b[1] - a[1]];
    // Solve |a + t d|² = 1 for t.
    let qa = d[0] * d[0] + d[1] * d[1];
    if qa < 1e-300 {
        return 0.0;
    }
    let qb = 2.0 * (a[0] * d[0] + a[1] * d[1]);
    let qc = a[0] * a[0] + a[1] * a[1] - 1.0;
    let disc = qb * qb - 4.0 * qa * qc;
    let sector = |p: [f64; 2], q: [f64; 2]| -> f64 {
        // Signed sector area of unit disc between directions p and q: angle / 2.
        let ang = (p[0] * q[1] - p[1] * q[0]).atan2(p[0] * q[0] + p[1] * q[1]);
        0.5 * ang
    };
    let tri = |p: [f64; 2], q: [f64; 2]| -> f64 { 0.5 * (p[0] * q[1] - p[1] * q[0]) };
    if disc <= 0.0 {
        // The segment's line misses the disc.
        return sector(a, b);
    }
    let sq = disc.sqrt();
    let t0 = ((-qb - sq) / (2.0 * qa)).clamp(0.0, 1.0);
    let t1 = ((-qb + sq) / (2.0 * qa)).clamp(0.0, 1.0);
    let p0 = [a[0] + t0 * d[0], a[1] + t0 * d[1]];
    let p1 = [a[0] + t1 * d[0], a[1] + t1 * d[1]];
    // a→p0 outside (sector), p0→p1 inside (triangle), p1→b outside (sector).
    sector(a, p0) + tri(p0, p1) + sector(p1, b)
}

/// What printers leave blank at each edge of a sheet, at most.
pub const PRINTER_MARGIN_MM: f64 = 10.0;

/// The strip below the chart where the PDF prints how to print it and a 100 mm scale
/// bar to check the print with.
pub const NOTES_MM: f64 = 10.0;

/// Paper sizes a chart can be fitted to (`lensblur chart --paper`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Paper {
    #[default]
    A4,
    A3,
    A2,
    Letter,
    Tabloid,
}

impl Paper {
    /// The names `lensblur chart --paper` takes, in the order of [`Paper::ALL`].
    pub const NAMES: [&'static str; 5] = ["a4", "a3", "a2", "letter", "tabloid"];
    pub const ALL: [Paper; 5] = [
        Paper::A4,
        Paper::A3,
        Paper::A2,
        Paper::Letter,
        Paper::Tabloid,
    ];

    /// Width and height in millimetres, landscape.
    #[must_use]
    pub fn landscape_mm(self) -> (f64, f64) {
        match self {
            Paper::A4 => (297.0, 210.0),
            Paper::A3 => (420.0, 297.0),
            Paper::A2 => (594.0, 420.0),
            Paper::Letter => (279.4, 215.9),
            Paper::Tabloid => (431.8, 279.4),
        }
    }

    /// The sheet's name as printers' dialogs write it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Paper::A4 => "A4",
            Paper::A3 => "A3",
            Paper::A2 => "A2",
            Paper::Letter => "Letter",
            Paper::Tabloid => "Tabloid",
        }
    }
}

impl std::fmt::Display for Paper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Paper {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let lower = s.to_ascii_lowercase();
        Self::NAMES
            .iter()
            .position(|n| *n == lower)
            .map(|i| Self::ALL[i])
            .ok_or_else(|| format!("{s}: paper is one of {}", Self::NAMES.join(", ")))
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_default_chart_fills_each_sheet_inside_its_margins() {
        for (paper, want) in [
            (Paper::A4, 10.0),
            (Paper::A3, 14.5),
            (Paper::A2, 21.5),
            (Paper::Letter, 9.5),
            (Paper::Tabloid, 13.5),
        ] {
            let chart = ChartSpec::default();
            let s = chart.square_to_fill(paper);
            assert_eq!(s, want, "{paper:?}");
            let sized = |side: f64| ChartSpec {
                square_mm: side,
                ..ChartSpec::default()
            };
            assert!(sized(s).fits(paper), "{paper:?}");
            assert!(
                !sized(s + 0.5).fits(paper),
                "{paper:?}: half a millimetre more fits"
            );
            // The chart, its notes and the margins on the sheet, measured here
            // rather than through `fits`.
            let (w, h) = paper.landscape_mm();
            let (pw, ph) = sized(s).paper_mm();
            assert!(pw + 2.0 * PRINTER_MARGIN_MM <= w, "{paper:?}");
            assert!(ph + NOTES_MM + 2.0 * PRINTER_MARGIN_MM <= h, "{paper:?}");
        }
        // The default 20 mm chart (520 × 360 mm) fits A2 and no smaller sheet; a
        // metre-wide one fits none.
        assert_eq!(ChartSpec::default().sheet(), Some(Paper::A2));
        let metre = ChartSpec {
            square_mm: 40.0,
            ..ChartSpec::default()
        };
        assert_eq!(metre.sheet(), None);
        assert_eq!("A3".parse::<Paper>(), Ok(Paper::A3));
        assert!("b5".parse::<Paper>().is_err());
    }

    use super::*;

    /// The default chart cut to `cols` × `rows` squares.
    fn spec_of(cols: usize, rows: usize) -> ChartSpec {
        ChartSpec {
            cols,
            rows,
            ..ChartSpec::default()
        }
    }

    fn pose() -> Homography {
        Homography::from_row_major([30.0, 1.2, 40.0, -0.8, 29.5, 35.0, 2e-4, -1e-4, 1.0])
    }

    #[test]
    fn default_spec_matches_the_design() {
        let s = ChartSpec::default();
        assert_eq!((s.cols, s.rows), (24, 16));
        assert!(s.validate().is_ok());
        assert!(s.is_black(0, 0));
        assert!(!s.is_black(1, 0));
        let json = serde_json::to_string(&s).unwrap();
        let back: ChartSpec = serde_json::from_str(&json).unwrap();
        assert_eq!(s, back);
        let partial: ChartSpec = serde_json::from_str(r#"{"cols": 10, "rows": 7}"#).unwrap();
        assert_eq!(partial.square_mm, 20.0);
    }

    #[test]
    fn a_square_covers_its_exact_area() {
        // One black square with no circles on a white page, under a rotation with
        // perspective: black coverage must sum to the square's exact image area.
        let spec = ChartSpec {
            circle_centres: vec![],
            ..spec_of(2, 2)
        };
        let h = pose();
        let (w, ht) = (150, 140);
        let img = rasterize(&spec, &h, w, ht, 1.0);
        let q = project_quad(&h, &spec.square_corners(0, 0));
        let q2 = project_quad(&h, &spec.square_corners(1, 1));
        let exact = shoelace(&q).abs() + shoelace(&q2).abs();
        let black: f64 = img.data.iter().map(|&v| 1.0 - f64::from(v)).sum();
        assert!(
            (black - exact).abs() < 1e-4 * 2.0_f64.max(1.0) && (black - exact).abs() < 1e-3,
            "{black} vs {exact}"
        );
    }

    #[test]
    fn a_circle_covers_its_exact_area() {
        // An affine pose maps the circle to an ellipse of area πr²|det A|.
        let spec = spec_of(2, 2);
        let h = Homography::from_row_major([40.0, 5.0, 30.0, -3.0, 38.0, 25.0, 0.0, 0.0, 1.0]);
        let det = 40.0 * 38.0 + 5.0 * 3.0;
        let img = rasterize(&spec, &h, 140, 130, 1.0);
        let black_sq: f64 = [(0usize, 0usize), (1, 1)]
            .iter()
            .map(|&(c, r)| shoelace(&project_quad(&h, &spec.square_corners(c, r))).abs())
            .sum();
        let circle = std::f64::consts::PI * 0.01 * det;
        // Black = two black squares − their 10 white circles + 10 black circles in white squares.
        let expected = black_sq;
        let black: f64 = img.data.iter().map(|&v| 1.0 - f64::from(v)).sum();
        assert!(
            (black - expected).abs() < 1e-6 * circle.max(1.0) * 20.0 + 1e-4,
            "{black} vs {expected}"
        );
        // Now count only the circles inside the first black square.
        let crop_white: f64 = {
            let q = project_quad(&h, &spec.square_corners(0, 0));
            let mut mask = vec![0.0; 140 * 130];
            add_quad_coverage(&mut mask, 140, 130, &q, 1.0);
            mask.iter()
                .zip(&img.data)
                .filter(|(m, _)| **m >= 1.0)
                .map(|(_, v)| f64::from(*v))
                .sum()
        };
        assert!(
            (crop_white - 5.0 * circle).abs() < 1e-4 * 5.0 * circle,
            "{crop_white} vs {}",
            5.0 * circle
        );
    }

    /// Every pixel of the shape's bounding box by exact clipping: the reference that the
    /// row-span rasteriser must equal.
    fn brute_quad(width: usize, height: usize, quad: &[[f64; 2]; 4]) -> Vec<f64> {
        let mut q = *quad;
        if shoelace(&q) < 0.0 {
            q.reverse();
        }
        let edges: Vec<([f64; 2], [f64; 2])> = (0..4).map(|i| (q[i], q[(i + 1) % 4])).collect();
        let mut out = vec![0.0; width * height];
        for y in 0..height {
            for x in 0..width {
                let (fx, fy) = (x as f64, y as f64);
                let px = [
                    [fx - 0.5, fy - 0.5],
                    [fx + 0.5, fy - 0.5],
                    [fx + 0.5, fy + 0.5],
                    [fx - 0.5, fy + 0.5],
                ];
                out[y * width + x] = clip_area(&px, &edges);
            }
        }
        out
    }

    #[test]
    fn row_spans_equal_clipping_every_pixel() {
        let (w, h) = (90, 80);
        let poses = [
            pose(),
            Homography::from_row_major([23.0, -9.0, 41.0, 7.5, 21.0, 12.0, 3e-3, -2e-3, 1.0]),
            Homography::from_row_major([0.0, 30.0, 60.0, -30.0, 0.0, 70.0, 0.0, 0.0, 1.0]),
        ];
        for hm in &poses {
            // A square straddling the image border, and one with a vertex inside a row.
            for corners in [
                [[-1.0, -1.0], [1.3, -0.7], [1.1, 1.9], [-0.8, 1.2]],
                [[0.1, 0.37], [2.0, 0.5], [1.7, 2.2], [0.05, 1.6]],
            ] {
                let q = project_quad(hm, &corners);
                let mut fast = vec![0.0; w * h];
                add_quad_coverage(&mut fast, w, h, &q, 1.0);
                let slow = brute_quad(w, h, &q);
                let worst = fast
                    .iter()
                    .zip(&slow)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(worst < 1e-12, "quad differs by {worst}");
            }
            // Circles of several sizes and places, against the exact area of every pixel.
            let inv = hm.inverse().unwrap();
            for (centre, radius) in [
                ([0.5, 0.5], 0.1),
                ([1.2, 0.9], 0.45),
                ([0.3, 1.4], 0.02),
                ([-0.1, 0.2], 0.3),
            ] {
                let mut fast = vec![0.0; w * h];
                add_circle_coverage(&mut fast, w, h, &inv, centre, radius, 1.0);
                let el = Ellipse::of_circle(&inv, centre, radius).unwrap();
                let mut worst = 0.0f64;
                for y in 0..h {
                    for x in 0..w {
                        let exact = el.pixel_area(x as f64, y as f64);
                        worst = worst.max((fast[y * w + x] - exact).abs());
                    }
                }
                assert!(worst < 1e-12, "circle differs by {worst}");
            }
        }
    }

    #[test]
    fn a_square_sums_to_its_exact_area_within_a_ten_thousandth_of_a_pixel() {
        let hm =
            Homography::from_row_major([31.0, 2.5, 17.3, -1.7, 29.2, 21.9, 2.1e-3, -1.4e-3, 1.0]);
        let q = project_quad(&hm, &[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]);
        let (w, h) = (80, 70);
        let mut acc = vec![0.0; w * h];
        add_quad_coverage(&mut acc, w, h, &q, 1.0);
        let total: f64 = acc.iter().sum();
        let exact = shoelace(&q).abs();
        assert!((total - exact).abs() < 1e-4, "{total} vs {exact}");
    }

    #[test]
    fn coverage_matches_point_sampling() {
        let spec = spec_of(3, 2);
        let h = pose();
        let img = rasterize(&spec, &h, 140, 110, 0.3);
        let inv = h.inverse().unwrap();
        let n = 24;
        for &(x, y) in &[
            (50usize, 50usize),
            (61, 47),
            (80, 60),
            (40, 70),
            (95, 55),
            (20, 20),
            (5, 5),
        ] {
            let mut s = 0.0;
            for j in 0..n {
                for i in 0..n {
                    let p = [
                        x as f64 - 0.5 + (i as f64 + 0.5) / n as f64,
                        y as f64 - 0.5 + (j as f64 + 0.5) / n as f64,
                    ];
                    s += match spec.is_white_at(inv.apply(p)) {
                        Some(true) => 1.0,
                        Some(false) => 0.0,
                        None => 0.3,
                    };
                }
            }
            s /= (n * n) as f64;
            assert!(
                (s - f64::from(img.get(x, y))).abs() < 0.02,
                "pixel ({x},{y}): {s} vs {}",
                img.get(x, y)
            );
        }
    }

    #[test]
    fn banded_rasterisation_equals_serial() {
        let spec = ChartSpec::default();
        let h = Homography::from_row_major([25.0, 0.8, 20.0, -0.6, 24.5, 30.0, 1e-5, -2e-5, 1.0]);
        let (w, ht) = (640, 460);
        let par = rasterize(&spec, &h, w, ht, 0.4);
        let ser = rasterize_serial(&spec, &h, (w, ht), 0.4);
        let worst = par
            .data
            .iter()
            .zip(&ser.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "bands differ by {worst}");
    }

    #[test]
    fn a_crop_equals_the_same_pixels_of_the_whole() {
        // Rasterising a window (which culls the squares it cannot see) gives the same
        // pixels as rasterising everything, wherever the window is.
        let spec = ChartSpec::default();
        let h = Homography::from_row_major([25.0, 0.8, 20.0, -0.6, 24.5, 30.0, 1e-4, -2e-4, 1.0]);
        let (w, ht) = (700, 520);
        let whole = rasterize_serial(&spec, &h, (w, ht), 0.4);
        for (x0, y0, cw, ch) in [
            (0, 0, 60, 50),
            (333, 217, 41, 37),
            (640, 470, 60, 50),
            (-20, 100, 50, 40),
        ] {
            let crop_from_image = Homography::translation(-(x0 as f64), -(y0 as f64));
            let crop = rasterize_serial(&spec, &crop_from_image.compose(&h), (cw, ch), 0.4);
            for y in 0..ch {
                for x in 0..cw {
                    let (gx, gy) = (x as i64 + x0, y as i64 + y0);
                    if gx < 0 || gy < 0 || gx >= w as i64 || gy >= ht as i64 {
                        continue;
                    }
                    let d = (crop.get(x, y) - whole.get(gx as usize, gy as usize)).abs();
                    assert!(d < 1e-6, "({gx},{gy}) differs by {d}");
                }
            }
        }
    }

    #[test]
    fn disc_area_of_polygons() {
        // A square much larger than the disc covers π.
        let big = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]];
        assert!((polygon_unit_disc_area(&big) - std::f64::consts::PI).abs() < 1e-12);
        // A half-plane square: the upper half disc.
        let half = [[-2.0, 0.0], [2.0, 0.0], [2.0, 2.0], [-2.0, 2.0]];
        assert!((polygon_unit_disc_area(&half) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // Wholly inside: its own area.
        let small = [[0.1, 0.1], [0.3, 0.1], [0.3, 0.2], [0.1, 0.2]];
        assert!((polygon_unit_disc_area(&small) - 0.02).abs() < 1e-12);
    }
}
