//! The calibration chart: a checkerboard whose squares each hold five circles of the
//! opposite colour, as the five on a die (DESIGN.md §1.1), and its exact rasterisation.
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

/// What was printed. Field names are part of the file contract (DESIGN.md §3).
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

#[derive(Debug, thiserror::Error)]
pub enum ChartError {
    #[error("{path}: cannot read chart spec: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
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
        let text = std::fs::read_to_string(path).map_err(|source| ChartError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let spec: ChartSpec = serde_json::from_str(&text).map_err(|e| ChartError::Parse {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        spec.validate().map_err(|e| ChartError::Parse {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Ok(spec)
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
        ((col + row) % 2 == 0) == self.black_top_left
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
        return rasterize_serial(spec, image_from_chart, width, height, background);
    }
    use rayon::prelude::*;
    let bands: Vec<Plane> = (0..height.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|b| {
            let y0 = b * BAND_ROWS;
            let rows = BAND_ROWS.min(height - y0);
            let band_from_chart =
                Homography::translation(0.0, -(y0 as f64)).compose(image_from_chart);
            rasterize_serial(spec, &band_from_chart, width, rows, background)
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
    width: usize,
    height: usize,
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
    for row in 0..spec.rows {
        for col in 0..spec.cols {
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
                    image_from_chart,
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

fn project_quad(h: &Homography, q: &[[f64; 2]; 4]) -> [[f64; 2]; 4] {
    [h.apply(q[0]), h.apply(q[1]), h.apply(q[2]), h.apply(q[3])]
}

fn bbox(points: &[[f64; 2]], width: usize, height: usize) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for p in points {
        if !p[0].is_finite() || !p[1].is_finite() {
            return Some((0, 0, width.saturating_sub(1), height.saturating_sub(1)));
        }
        x0 = x0.min(p[0]);
        y0 = y0.min(p[1]);
        x1 = x1.max(p[0]);
        y1 = y1.max(p[1]);
    }
    let lo_x = (x0 + 0.5).floor().max(0.0);
    let lo_y = (y0 + 0.5).floor().max(0.0);
    let hi_x = (x1 + 0.5).ceil().min(width as f64 - 1.0);
    let hi_y = (y1 + 0.5).ceil().min(height as f64 - 1.0);
    if hi_x < lo_x || hi_y < lo_y || width == 0 || height == 0 {
        return None;
    }
    Some((lo_x as usize, lo_y as usize, hi_x as usize, hi_y as usize))
}

/// Adds `sign ×` the exact area of each pixel covered by the convex quad.
fn add_quad_coverage(
    acc: &mut [f64],
    width: usize,
    height: usize,
    quad: &[[f64; 2]; 4],
    sign: f64,
) {
    let Some((x0, y0, x1, y1)) = bbox(quad, width, height) else {
        return;
    };
    // Orient counter-clockwise in a y-up sense (positive shoelace area) so "inside" is
    // the left of every edge.
    let mut q = *quad;
    if shoelace(&q) < 0.0 {
        q.reverse();
    }
    let edges: Vec<([f64; 2], [f64; 2])> = (0..4).map(|i| (q[i], q[(i + 1) % 4])).collect();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (fx, fy) = (x as f64, y as f64);
            let corners = [
                [fx - 0.5, fy - 0.5],
                [fx + 0.5, fy - 0.5],
                [fx + 0.5, fy + 0.5],
                [fx - 0.5, fy + 0.5],
            ];
            let mut all_inside = true;
            let mut outside = false;
            for (a, b) in &edges {
                let mut n_in = 0;
                for c in &corners {
                    if cross(*a, *b, *c) >= 0.0 {
                        n_in += 1;
                    }
                }
                if n_in == 0 {
                    outside = true;
                    break;
                }
                if n_in < 4 {
                    all_inside = false;
                }
            }
            if outside {
                continue;
            }
            let area = if all_inside {
                1.0
            } else {
                clip_area(&corners, &edges)
            };
            acc[y * width + x] += sign * area;
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

/// Adds `sign ×` the exact area of each pixel covered by the image of the chart circle.
#[allow(clippy::too_many_arguments)]
fn add_circle_coverage(
    acc: &mut [f64],
    width: usize,
    height: usize,
    image_from_chart: &Homography,
    chart_from_image: &Homography,
    centre: [f64; 2],
    radius: f64,
    sign: f64,
) {
    // Conic of the circle in chart coordinates: [x y 1] C [x y 1]ᵀ = 0; in the image,
    // C' = H⁻ᵀ C H⁻¹.
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
    // Ellipse: A x² + 2B xy + C y² + 2D x + 2E y + F = 0.
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
        return;
    }
    // Centre, then the quadratic form M with (p − c)ᵀ M (p − c) = 1.
    let ex = (b * e - cc * d) / det2;
    let ey = (b * d - a * e) / det2;
    let k = -(a * ex * ex + 2.0 * b * ex * ey + cc * ey * ey + 2.0 * d * ex + 2.0 * e * ey + f);
    if k.abs() < 1e-300 {
        return;
    }
    let (m11, m12, m22) = (a / k, b / k, cc / k);
    if !(m11 > 0.0 && m11 * m22 - m12 * m12 > 0.0) {
        return; // not an ellipse: the circle crosses the horizon; nothing sensible to draw
    }
    // Affine T with Tᵀ T = M (Cholesky), mapping the ellipse to the unit circle.
    let l11 = m11.sqrt();
    let l21 = m12 / l11;
    let l22 = (m22 - l21 * l21).sqrt();
    // T = Lᵀ = [[l11, l21], [0, l22]].
    let det_t = l11 * l22;
    let to_unit = |p: [f64; 2]| -> [f64; 2] {
        let (u, v) = (p[0] - ex, p[1] - ey);
        [l11 * u + l21 * v, l22 * v]
    };
    // Bounding box of the ellipse: half-widths sqrt(M⁻¹ diagonal).
    let inv_det = 1.0 / (m11 * m22 - m12 * m12);
    let hw = (m22 * inv_det).sqrt();
    let hh = (m11 * inv_det).sqrt();
    let _ = image_from_chart;
    let Some((x0, y0, x1, y1)) = bbox(&[[ex - hw, ey - hh], [ex + hw, ey + hh]], width, height)
    else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (fx, fy) = (x as f64, y as f64);
            let corners = [
                to_unit([fx - 0.5, fy - 0.5]),
                to_unit([fx + 0.5, fy - 0.5]),
                to_unit([fx + 0.5, fy + 0.5]),
                to_unit([fx - 0.5, fy + 0.5]),
            ];
            let inside = corners.iter().all(|p| p[0] * p[0] + p[1] * p[1] <= 1.0);
            let area_unit = if inside {
                shoelace(&corners).abs()
            } else {
                let mid = [
                    0.25 * (corners[0][0] + corners[1][0] + corners[2][0] + corners[3][0]),
                    0.25 * (corners[0][1] + corners[1][1] + corners[2][1] + corners[3][1]),
                ];
                let reach = corners
                    .iter()
                    .map(|p| ((p[0] - mid[0]).powi(2) + (p[1] - mid[1]).powi(2)).sqrt())
                    .fold(0.0, f64::max);
                if (mid[0] * mid[0] + mid[1] * mid[1]).sqrt() - reach >= 1.0 {
                    continue;
                }
                polygon_unit_disc_area(&corners)
            };
            acc[y * width + x] += sign * area_unit / det_t;
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

#[cfg(test)]
mod tests {
    use super::*;

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
            cols: 2,
            rows: 2,
            circle_centres: vec![],
            ..ChartSpec::default()
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
        let spec = ChartSpec {
            cols: 2,
            rows: 2,
            ..ChartSpec::default()
        };
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
            let (x0, y0, x1, y1) = bbox(&q, 140, 130).unwrap();
            let mut s = 0.0;
            let mut mask = vec![0.0; 140 * 130];
            add_quad_coverage(&mut mask, 140, 130, &q, 1.0);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    s += mask[y * 140 + x] * 0.0
                        + f64::from(img.get(x, y))
                            * if mask[y * 140 + x] >= 1.0 { 1.0 } else { 0.0 };
                }
            }
            s
        };
        assert!(
            (crop_white - 5.0 * circle).abs() < 1e-4 * 5.0 * circle,
            "{crop_white} vs {}",
            5.0 * circle
        );
    }

    #[test]
    fn coverage_matches_point_sampling() {
        let spec = ChartSpec {
            cols: 3,
            rows: 2,
            ..ChartSpec::default()
        };
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
        let ser = rasterize_serial(&spec, &h, w, ht, 0.4);
        let worst = par
            .data
            .iter()
            .zip(&ser.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "bands differ by {worst}");
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
