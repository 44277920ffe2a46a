//! Homographies and their estimation.
//!
//! A homography is named for the spaces it joins, `target_from_source`: the detector's
//! `image_from_chart` maps chart units (one square = 1.0, origin at the checkerboard's
//! top-left corner) to sensor pixels.

use nalgebra::{DMatrix, Matrix3};
use serde::{Deserialize, Serialize};

/// A 2-D projective transform, stored row-major and normalised so `h[8] = 1` where possible.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homography(pub Matrix3<f64>);

impl Homography {
    #[must_use]
    pub fn identity() -> Self {
        Self(Matrix3::identity())
    }

    #[must_use]
    pub fn from_row_major(h: [f64; 9]) -> Self {
        Self(Matrix3::from_row_slice(&h))
    }

    #[must_use]
    pub fn to_row_major(&self) -> [f64; 9] {
        let m = &self.0;
        [
            m[(0, 0)],
            m[(0, 1)],
            m[(0, 2)],
            m[(1, 0)],
            m[(1, 1)],
            m[(1, 2)],
            m[(2, 0)],
            m[(2, 1)],
            m[(2, 2)],
        ]
    }

    /// Translation by (tx, ty).
    #[must_use]
    pub fn translation(tx: f64, ty: f64) -> Self {
        Self(Matrix3::new(1.0, 0.0, tx, 0.0, 1.0, ty, 0.0, 0.0, 1.0))
    }

    /// Scaling about the origin.
    #[must_use]
    pub fn scaling(sx: f64, sy: f64) -> Self {
        Self(Matrix3::new(sx, 0.0, 0.0, 0.0, sy, 0.0, 0.0, 0.0, 1.0))
    }

    /// Maps a point. Points at infinity map to non-finite coordinates.
    #[inline]
    #[must_use]
    pub fn apply(&self, p: [f64; 2]) -> [f64; 2] {
        let m = &self.0;
        let w = m[(2, 0)] * p[0] + m[(2, 1)] * p[1] + m[(2, 2)];
        [
            (m[(0, 0)] * p[0] + m[(0, 1)] * p[1] + m[(0, 2)]) / w,
            (m[(1, 0)] * p[0] + m[(1, 1)] * p[1] + m[(1, 2)]) / w,
        ]
    }

    /// `self ∘ other`: first `other`, then `self`.
    #[must_use]
    pub fn compose(&self, other: &Homography) -> Homography {
        Homography(self.0 * other.0).normalised()
    }

    #[must_use]
    pub fn inverse(&self) -> Option<Homography> {
        self.0.try_inverse().map(|m| Homography(m).normalised())
    }

    #[must_use]
    pub fn normalised(self) -> Homography {
        let s = self.0[(2, 2)];
        if s.abs() > 1e-12 {
            Homography(self.0 / s)
        } else {
            self
        }
    }

    /// Jacobian of the map at `p`: [[dx'/dx, dx'/dy], [dy'/dx, dy'/dy]].
    #[must_use]
    pub fn jacobian(&self, p: [f64; 2]) -> [[f64; 2]; 2] {
        let m = &self.0;
        let w = m[(2, 0)] * p[0] + m[(2, 1)] * p[1] + m[(2, 2)];
        let u = m[(0, 0)] * p[0] + m[(0, 1)] * p[1] + m[(0, 2)];
        let v = m[(1, 0)] * p[0] + m[(1, 1)] * p[1] + m[(1, 2)];
        let w2 = w * w;
        [
            [
                (m[(0, 0)] * w - u * m[(2, 0)]) / w2,
                (m[(0, 1)] * w - u * m[(2, 1)]) / w2,
            ],
            [
                (m[(1, 0)] * w - v * m[(2, 0)]) / w2,
                (m[(1, 1)] * w - v * m[(2, 1)]) / w2,
            ],
        ]
    }

    /// Normalised DLT (Hartley & Zisserman, Alg. 4.2): the homography mapping each
    /// `from[i]` to `to[i]`, least squares for more than four pairs. `None` for fewer
    /// than four pairs or a degenerate (e.g. collinear) configuration.
    #[must_use]
    pub fn from_correspondences(from: &[[f64; 2]], to: &[[f64; 2]]) -> Option<Homography> {
        let n = from.len();
        if n < 4 || to.len() != n {
            return None;
        }
        let t_from = normalising_transform(from)?;
        let t_to = normalising_transform(to)?;
        let mut a = DMatrix::<f64>::zeros(2 * n.max(5), 9);
        for (i, (p, q)) in from.iter().zip(to).enumerate() {
            let p = t_from.apply(*p);
            let q = t_to.apply(*q);
            let (x, y, u, v) = (p[0], p[1], q[0], q[1]);
            let r = 2 * i;
            a.row_mut(r)
                .copy_from_slice(&[0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
            a.row_mut(r + 1)
                .copy_from_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u]);
        }
        // The null vector is the right singular vector of the smallest singular value.
        let svd = a.svd(false, true);
        let vt = svd.v_t?;
        let (imin, smin) = svd
            .singular_values
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))?;
        // A second (near-)zero singular value means the points do not fix H.
        let mut sorted: Vec<f64> = svd.singular_values.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        if sorted.len() >= 2 && sorted[1] < 1e-9 * sorted[sorted.len() - 1].max(1e-300) {
            return None;
        }
        let _ = smin;
        let h = vt.row(imin);
        let hn = Matrix3::from_row_slice(h.transpose().as_slice());
        let t_to_inv = t_to.0.try_inverse()?;
        let m = t_to_inv * hn * t_from.0;
        if !m.iter().all(|v| v.is_finite()) || m.determinant().abs() < 1e-300 {
            return None;
        }
        Some(Homography(m).normalised())
    }
}

impl Serialize for Homography {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.to_row_major().serialize(s)
    }
}

impl<'de> Deserialize<'de> for Homography {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let h = <[f64; 9]>::deserialize(d)?;
        Ok(Homography::from_row_major(h))
    }
}

/// Similarity that moves the centroid to the origin and the mean distance to √2.
fn normalising_transform(pts: &[[f64; 2]]) -> Option<Homography> {
    let n = pts.len() as f64;
    let cx = pts.iter().map(|p| p[0]).sum::<f64>() / n;
    let cy = pts.iter().map(|p| p[1]).sum::<f64>() / n;
    let d = pts
        .iter()
        .map(|p| ((p[0] - cx).powi(2) + (p[1] - cy).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    if !(d > 1e-12) || !d.is_finite() {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / d;
    Some(Homography(Matrix3::new(
        s,
        0.0,
        -s * cx,
        0.0,
        s,
        -s * cy,
        0.0,
        0.0,
        1.0,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_h() -> Homography {
        Homography::from_row_major([80.0, 3.0, 200.0, -2.5, 79.0, 150.0, 1e-4, -2e-4, 1.0])
    }

    #[test]
    fn dlt_recovers_a_known_homography_on_a_grid() {
        let h = sample_h();
        let from: Vec<[f64; 2]> = (0..5)
            .flat_map(|j| (0..6).map(move |i| [i as f64, j as f64]))
            .collect();
        let to: Vec<[f64; 2]> = from.iter().map(|&p| h.apply(p)).collect();
        let est = Homography::from_correspondences(&from, &to).unwrap();
        for p in &from {
            let a = h.apply(*p);
            let b = est.apply(*p);
            assert!((a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6);
        }
    }

    #[test]
    fn dlt_from_four_points_is_exact() {
        let h = sample_h();
        let from = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let to: Vec<[f64; 2]> = from.iter().map(|&p| h.apply(p)).collect();
        let est = Homography::from_correspondences(&from, &to).unwrap();
        let a = est.to_row_major();
        let b = h.to_row_major();
        for k in 0..9 {
            assert!(
                (a[k] - b[k]).abs() < 1e-6 * b[k].abs().max(1.0),
                "{a:?} vs {b:?}"
            );
        }
    }

    #[test]
    fn dlt_rejects_collinear_points() {
        let from = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]];
        let to = [[0.0, 0.0], [2.0, 2.0], [4.0, 4.0], [6.0, 6.0]];
        assert!(Homography::from_correspondences(&from, &to).is_none());
        assert!(Homography::from_correspondences(&from[..3], &to[..3]).is_none());
    }

    #[test]
    fn inverse_and_compose() {
        let h = sample_h();
        let hi = h.inverse().unwrap();
        let id = h.compose(&hi);
        let p = [12.3, -4.5];
        let q = id.apply(p);
        assert!((q[0] - p[0]).abs() < 1e-9 && (q[1] - p[1]).abs() < 1e-9);
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let h = sample_h();
        let p = [3.2, 1.7];
        let j = h.jacobian(p);
        let e = 1e-6;
        let dx = h.apply([p[0] + e, p[1]]);
        let dy = h.apply([p[0], p[1] + e]);
        let c = h.apply(p);
        assert!(((dx[0] - c[0]) / e - j[0][0]).abs() < 1e-3);
        assert!(((dy[1] - c[1]) / e - j[1][1]).abs() < 1e-3);
        assert!(((dy[0] - c[0]) / e - j[0][1]).abs() < 1e-3);
    }
}
