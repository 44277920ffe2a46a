//! Fields: predicted and true Gaussians on a grid over the sensor, the difference of
//! two fields, and the colour range a map of one is drawn with.

use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::psf::Gaussian2;

/// `nx` × `ny` points spread evenly over a `width` × `height` sensor (cell centres),
/// row-major: where the Kernel field view shows a predicted or true field.
#[must_use]
pub fn field_grid(width: usize, height: usize, nx: usize, ny: usize) -> Vec<[f64; 2]> {
    let (w, h) = (width.max(1) as f64 - 1.0, height.max(1) as f64 - 1.0);
    (0..ny)
        .flat_map(|j| {
            (0..nx).map(move |i| {
                [
                    (i as f64 + 0.5) / nx as f64 * w,
                    (j as f64 + 0.5) / ny as f64 * h,
                ]
            })
        })
        .collect()
}

/// The pixel-level Gaussian of a virtual lens at a sensor point: its optical blur plus
/// the 1-px box of the pixel's own integration (what kernels measure).
#[must_use]
pub fn truth_pixel_gaussian(
    lens: &crate::simulate::VirtualLens,
    channel: Channel,
    (x, y): (f64, f64),
    (width, height): (usize, usize),
    setting: LensSetting,
) -> Gaussian2 {
    lens.gaussian_at(channel, x, y, width, height, setting)
        .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
}

/// A profile's predicted Gaussians on the `grid` (`nx`, `ny`) of a `width` × `height`
/// sensor at `setting`, each with its sensor position; or why the profile has none
/// there (the first failure, one line).
///
/// # Errors
/// The profile cannot predict at some grid point (channel or setting outside it).
pub fn predicted_field(
    profile: &Profile,
    channel: Channel,
    (width, height): (usize, usize),
    (nx, ny): (usize, usize),
    setting: LensSetting,
) -> Result<Vec<(f64, f64, Gaussian2)>, String> {
    predicted_at(
        profile,
        channel,
        &field_grid(width, height, nx, ny),
        setting,
    )
}

/// A virtual lens's pixel-level Gaussians on the same grid as [`predicted_field`].
#[must_use]
pub fn truth_field(
    lens: &crate::simulate::VirtualLens,
    channel: Channel,
    size: (usize, usize),
    (nx, ny): (usize, usize),
    setting: LensSetting,
) -> Vec<(f64, f64, Gaussian2)> {
    field_grid(size.0, size.1, nx, ny)
        .into_iter()
        .map(|[x, y]| {
            (
                x,
                y,
                truth_pixel_gaussian(lens, channel, (x, y), size, setting),
            )
        })
        .collect()
}

/// One point of a difference map: the Gaussians of field A and field B at (about) the
/// same sensor position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldDifference {
    pub x: f64,
    pub y: f64,
    pub a: Gaussian2,
    pub b: Gaussian2,
}

impl FieldDifference {
    /// σ(A) − σ(B), px: what the difference map colours.
    #[must_use]
    pub fn delta_sigma(&self) -> f64 {
        self.a.sigma() - self.b.sigma()
    }
}

/// Pairs each point of field `a` with the nearest point of field `b` within
/// `max_distance` px (points of `a` with none are left out): the difference map of A
/// − B, at A's positions.
#[must_use]
pub fn field_difference(
    a: &[(f64, f64, Gaussian2)],
    b: &[(f64, f64, Gaussian2)],
    max_distance: f64,
) -> Vec<FieldDifference> {
    a.iter()
        .filter_map(|&(x, y, ga)| {
            let d2 = |p: &(f64, f64, Gaussian2)| (p.0 - x).powi(2) + (p.1 - y).powi(2);
            let nearest = b.iter().min_by(|p, q| d2(p).total_cmp(&d2(q)))?;
            (d2(nearest) <= max_distance * max_distance).then_some(FieldDifference {
                x,
                y,
                a: ga,
                b: nearest.2,
            })
        })
        .collect()
}

/// A profile's predicted Gaussians at sensor `points` and `setting`.
///
/// # Errors
/// The profile cannot predict at some point: the first failure, one line.
pub fn predicted_at(
    profile: &Profile,
    channel: Channel,
    points: &[[f64; 2]],
    setting: LensSetting,
) -> Result<Vec<(f64, f64, Gaussian2)>, String> {
    points
        .iter()
        .map(|&[x, y]| {
            profile
                .predict(channel, x, y, setting)
                .map(|g| (x, y, g))
                .map_err(|e| e.to_string())
        })
        .collect()
}

/// The palette at `t` in 0–1: viridis for a quantity (σ, MTF50), blue–white–red for a
/// difference, white at the middle (0 on a symmetric range). Every map the studio
/// draws and every map picture written uses it.
#[must_use]
pub fn palette_rgb(t: f32, diverging: bool) -> [u8; 3] {
    const VIRIDIS: [[u8; 3]; 5] = [
        [68, 1, 84],
        [59, 82, 139],
        [33, 145, 140],
        [94, 201, 98],
        [253, 231, 37],
    ];
    const BWR: [[u8; 3]; 5] = [
        [33, 102, 172],
        [146, 197, 222],
        [247, 247, 247],
        [244, 165, 130],
        [178, 24, 43],
    ];
    let stops = if diverging { &BWR } else { &VIRIDIS };
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let k = (t.floor() as usize).min(3);
    let f = t - k as f32;
    let [a, b] = [stops[k], stops[k + 1]];
    let mix = |i: usize| (f32::from(a[i]) * (1.0 - f) + f32::from(b[i]) * f) as u8;
    [mix(0), mix(1), mix(2)]
}

/// The colour range of a map from its finite `values`: [min, max], or for a difference
/// map (`symmetric`) [−m, m] with m the largest magnitude, so that white is exactly 0.
/// Never empty: a constant field gets a small span around its value.
#[must_use]
pub fn colour_range(values: impl IntoIterator<Item = f64>, symmetric: bool) -> Option<[f64; 2]> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.into_iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return None;
    }
    if symmetric {
        let m = lo.abs().max(hi.abs()).max(1e-3);
        return Some([-m, m]);
    }
    if hi - lo < 1e-3 {
        return Some([lo - 0.05, hi + 0.05]);
    }
    Some([lo, hi])
}

/// The 1-σ ellipse of `g` as `points` + 1 offsets from its centre, px, the first repeated
/// last so it closes: the Cholesky factor of the covariance maps the unit circle onto it
/// (ρ held inside ±0.999, where the factor stays real).
#[must_use]
pub fn ellipse_outline(g: &Gaussian2, points: usize) -> Vec<[f64; 2]> {
    let (sx, sy, r) = (g.sigma_x, g.sigma_y, g.rho.clamp(-0.999, 0.999));
    let l21 = r * sy;
    let l22 = sy * (1.0 - r * r).sqrt();
    let n = points.max(3);
    (0..=n)
        .map(|k| {
            let t = k as f64 / n as f64 * std::f64::consts::TAU;
            let (c, s) = (t.cos(), t.sin());
            [sx * c, l21 * c + l22 * s]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every point of the outline lies on the 1-σ contour: xᵀ Σ⁻¹ x = 1.
    #[test]
    fn the_outline_is_the_one_sigma_contour() {
        for (sx, sy, rho) in [(1.0, 1.0, 0.0), (2.5, 0.7, 0.6), (0.9, 1.8, -0.85)] {
            let g = Gaussian2 {
                sigma_x: sx,
                sigma_y: sy,
                rho,
            };
            let pts = ellipse_outline(&g, 40);
            assert_eq!(pts.len(), 41);
            assert!((pts[0][0] - pts[40][0]).abs() < 1e-12, "closed");
            let (a, b, d) = (sx * sx, rho * sx * sy, sy * sy);
            let det = a * d - b * b;
            for [x, y] in pts {
                let q = (d * x * x - 2.0 * b * x * y + a * y * y) / det;
                assert!((q - 1.0).abs() < 1e-9, "{q} for {sx} {sy} {rho}");
            }
        }
    }
}
