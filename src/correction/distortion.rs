//! Radial distortion fitted jointly with each shot's chart pose: the chart is a plane,
//! so every square corner's ideal (pinhole) position is the shot's homography applied
//! to its chart coordinates, and the lens moves it radially about the frame's centre
//! by lensfun's model. All shots at one focal length share the model; each has its
//! own pose. Levenberg–Marquardt on the normal equations (the model's few terms plus
//! eight per shot), one round of outlier rejection, and the terms' standard errors
//! from the final normal equations.

use super::frame::LensfunFrame;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// lensfun's distortion models, mapping an undistorted radius r (lensfun's distortion
/// units) to the distorted one r·g(r).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Hash)]
#[serde(rename_all = "lowercase")]
pub enum DistortionModel {
    /// g = 1 − k₁ + k₁r² (Hugin's, r = 1 fixed).
    Poly3,
    /// g = 1 + k₁r² + k₂r⁴.
    Poly5,
    /// g = a r³ + b r² + c r + 1 − a − b − c (PanoTools', r = 1 fixed).
    PtLens,
}

impl DistortionModel {
    pub const ALL: [DistortionModel; 3] = [Self::Poly3, Self::Poly5, Self::PtLens];

    /// The name lensfun's XML gives it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Poly3 => "poly3",
            Self::Poly5 => "poly5",
            Self::PtLens => "ptlens",
        }
    }

    /// Names of its terms, as lensfun's XML attributes.
    #[must_use]
    pub fn terms(self) -> &'static [&'static str] {
        match self {
            Self::Poly3 => &["k1"],
            Self::Poly5 => &["k1", "k2"],
            Self::PtLens => &["a", "b", "c"],
        }
    }

    /// g(r), g'(r) and ∂g/∂term (zero past the model's terms).
    #[must_use]
    pub fn eval(self, t: &[f64], r: f64) -> (f64, f64, [f64; 3]) {
        match self {
            Self::Poly3 => (
                1.0 - t[0] + t[0] * r * r,
                2.0 * t[0] * r,
                [r * r - 1.0, 0.0, 0.0],
            ),
            Self::Poly5 => {
                let r2 = r * r;
                (
                    1.0 + t[0] * r2 + t[1] * r2 * r2,
                    2.0 * t[0] * r + 4.0 * t[1] * r2 * r,
                    [r2, r2 * r2, 0.0],
                )
            }
            Self::PtLens => {
                let (a, b, c) = (t[0], t[1], t[2]);
                (
                    a * r.powi(3) + b * r * r + c * r + 1.0 - a - b - c,
                    3.0 * a * r * r + 2.0 * b * r + c,
                    [r.powi(3) - 1.0, r * r - 1.0, r - 1.0],
                )
            }
        }
    }

    /// The undistorted radius whose image lies at distorted radius `rd` (Newton).
    #[must_use]
    pub fn undistort_radius(self, t: &[f64], rd: f64) -> f64 {
        let mut ru = rd;
        for _ in 0..50 {
            let (g, gp, _) = self.eval(t, ru);
            let f = ru * g - rd;
            let df = g + ru * gp;
            if df.abs() < 1e-12 {
                break;
            }
            let step = f / df;
            ru -= step;
            if step.abs() < 1e-14 {
                break;
            }
        }
        ru
    }

    /// How far the lens moves the image at distorted radius `rd` (distortion units)
    /// from where a distortion-free lens of the same central magnification puts it, in
    /// the same units: positive outward (pincushion), negative inward (barrel). Free of
    /// the scale the model's own normalisation picks, so models and lenses compare.
    #[must_use]
    pub fn displacement(self, t: &[f64], rd: f64) -> f64 {
        let ru = self.undistort_radius(t, rd);
        let (g0, _, _) = self.eval(t, 0.0);
        rd - ru * g0
    }
}

/// One corner seen in one shot: its chart coordinates and where the shot shows it.
#[derive(Clone, Copy, Debug)]
pub struct Corner {
    pub shot: usize,
    pub chart: [f64; 2],
    pub sensor: [f64; 2],
}

/// A model fitted to one focal length's corners.
#[derive(Clone, Debug, Serialize)]
pub struct DistortionFit {
    pub model: DistortionModel,
    /// lensfun's terms in its order (k1; k1 k2; a b c).
    pub coefficients: Vec<f64>,
    /// Their standard errors.
    pub std_errors: Vec<f64>,
    /// RMS distance of the corners from the fitted model, px.
    pub rms_px: f64,
    /// The largest, px.
    pub max_px: f64,
    /// Corners used, and those set aside as outliers.
    pub corners: usize,
    pub outliers: usize,
    /// The lens's displacement at the frame corner, px (see
    /// [`DistortionModel::displacement`]).
    pub corner_displacement_px: f64,
    /// Each shot's chart pose, row-major with h₃₃ = 1 (ideal pixels from chart units).
    #[serde(skip)]
    pub poses: Vec<[f64; 8]>,
}

impl DistortionFit {
    /// Where the lens puts ideal pixel `u` of this focal length, px.
    #[must_use]
    pub fn distort(&self, frame: &LensfunFrame, u: [f64; 2]) -> [f64; 2] {
        let n = frame.to_norm(u);
        let (g, _, _) = self.model.eval(&self.coefficients, n[0].hypot(n[1]));
        frame.from_norm([n[0] * g, n[1] * g])
    }

    /// The lens's displacement at sensor point `p`, px, radial from the centre
    /// (positive outward).
    #[must_use]
    pub fn displacement_px(&self, frame: &LensfunFrame, p: [f64; 2]) -> f64 {
        let n = frame.to_norm(p);
        self.model
            .displacement(&self.coefficients, n[0].hypot(n[1]))
            / frame.norm_scale
    }
}

fn apply_pose(h: &[f64; 8], x: [f64; 2]) -> ([f64; 2], f64) {
    let w = h[6] * x[0] + h[7] * x[1] + 1.0;
    (
        [
            (h[0] * x[0] + h[1] * x[1] + h[2]) / w,
            (h[3] * x[0] + h[4] * x[1] + h[5]) / w,
        ],
        w,
    )
}

/// The residual (predicted − seen, px) of one corner and its Jacobian: columns
/// 0..n for the model's terms, n..n+8 for its shot's pose.
fn corner_residual(
    model: DistortionModel,
    t: &[f64],
    pose: &[f64; 8],
    frame: &LensfunFrame,
    c: &Corner,
) -> ([f64; 2], [[f64; 11]; 2]) {
    let n = model.terms().len();
    let (u, w) = apply_pose(pose, c.chart);
    let centre = frame.centre();
    let d = [u[0] - centre[0], u[1] - centre[1]];
    let rho = d[0].hypot(d[1]);
    let ns = frame.norm_scale;
    let (g, gp, dg) = model.eval(t, rho * ns);
    let pred = [centre[0] + d[0] * g, centre[1] + d[1] * g];
    let res = [pred[0] - c.sensor[0], pred[1] - c.sensor[1]];
    // ∂pred/∂u = g I + (g′ ns / ρ) d dᵀ.
    let s = if rho > 0.0 { gp * ns / rho } else { 0.0 };
    let dp = [
        [g + s * d[0] * d[0], s * d[0] * d[1]],
        [s * d[1] * d[0], g + s * d[1] * d[1]],
    ];
    let (x, y) = (c.chart[0], c.chart[1]);
    // ∂u/∂h, rows u_x and u_y over h₀…h₇.
    let du = [
        [
            x / w,
            y / w,
            1.0 / w,
            0.0,
            0.0,
            0.0,
            -u[0] * x / w,
            -u[0] * y / w,
        ],
        [
            0.0,
            0.0,
            0.0,
            x / w,
            y / w,
            1.0 / w,
            -u[1] * x / w,
            -u[1] * y / w,
        ],
    ];
    let mut j = [[0.0; 11]; 2];
    for row in 0..2 {
        for k in 0..n {
            j[row][k] = d[row] * dg[k];
        }
        for k in 0..8 {
            j[row][n + k] = dp[row][0] * du[0][k] + dp[row][1] * du[1][k];
        }
    }
    (res, j)
}

/// The sum of squared residuals of every corner.
fn cost(
    model: DistortionModel,
    t: &[f64],
    poses: &[[f64; 8]],
    frame: &LensfunFrame,
    corners: &[Corner],
) -> f64 {
    corners
        .iter()
        .map(|c| {
            let (r, _) = corner_residual(model, t, &poses[c.shot], frame, c);
            r[0] * r[0] + r[1] * r[1]
        })
        .sum()
}

/// The normal equations JᵀJ and Jᵀr over every corner.
fn normal_equations(
    model: DistortionModel,
    t: &[f64],
    poses: &[[f64; 8]],
    frame: &LensfunFrame,
    corners: &[Corner],
) -> (DMatrix<f64>, DVector<f64>) {
    let n = model.terms().len();
    let dim = n + 8 * poses.len();
    let mut a = DMatrix::<f64>::zeros(dim, dim);
    let mut b = DVector::<f64>::zeros(dim);
    for c in corners {
        let (r, j) = corner_residual(model, t, &poses[c.shot], frame, c);
        let col = |k: usize| if k < n { k } else { n + 8 * c.shot + (k - n) };
        for row in 0..2 {
            for p in 0..n + 8 {
                let jp = j[row][p];
                if jp == 0.0 {
                    continue;
                }
                b[col(p)] += jp * r[row];
                for q in 0..n + 8 {
                    a[(col(p), col(q))] += jp * j[row][q];
                }
            }
        }
    }
    (a, b)
}

/// Levenberg–Marquardt from `poses` and zero distortion; returns the terms, poses and
/// the final normal equations.
fn solve(
    model: DistortionModel,
    mut poses: Vec<[f64; 8]>,
    frame: &LensfunFrame,
    corners: &[Corner],
) -> (Vec<f64>, Vec<[f64; 8]>, DMatrix<f64>) {
    let n = model.terms().len();
    let mut t = vec![0.0; n];
    let mut current = cost(model, &t, &poses, frame, corners);
    let mut lambda = 1e-3;
    for _ in 0..100 {
        let (a, b) = normal_equations(model, &t, &poses, frame, corners);
        let mut damped = a.clone();
        for d in 0..damped.nrows() {
            damped[(d, d)] += lambda * a[(d, d)].max(1e-12);
        }
        let Some(step) = damped.cholesky().map(|c| c.solve(&b)) else {
            lambda *= 10.0;
            if lambda > 1e12 {
                break;
            }
            continue;
        };
        let t_next: Vec<f64> = (0..n).map(|k| t[k] - step[k]).collect();
        let poses_next: Vec<[f64; 8]> = poses
            .iter()
            .enumerate()
            .map(|(s, h)| std::array::from_fn(|k| h[k] - step[n + 8 * s + k]))
            .collect();
        let next = cost(model, &t_next, &poses_next, frame, corners);
        if next.is_finite() && next <= current {
            let gain = current - next;
            t = t_next;
            poses = poses_next;
            current = next;
            lambda = (lambda * 0.3).max(1e-12);
            if gain <= 1e-12 * current.max(1e-300) {
                break;
            }
        } else {
            lambda *= 10.0;
            if lambda > 1e12 {
                break;
            }
        }
    }
    let (a, _) = normal_equations(model, &t, &poses, frame, corners);
    (t, poses, a)
}

/// A corner further than this many robust standard deviations from the fit (and
/// further than [`MIN_OUTLIER_PX`]) is set aside: a square whose alignment slipped.
const OUTLIER_SIGMAS: f64 = 5.0;
/// Never call a corner within this of the fit an outlier, px: the alignment's own noise.
const MIN_OUTLIER_PX: f64 = 0.1;

/// Fits `model` to the corners of `shots` shots at one focal length, from each shot's
/// initial pose (ideal pixels from chart units, h₃₃ = 1).
#[must_use]
pub fn fit(
    model: DistortionModel,
    initial_poses: &[[f64; 8]],
    frame: &LensfunFrame,
    corners: &[Corner],
) -> DistortionFit {
    let (t, poses, _) = solve(model, initial_poses.to_vec(), frame, corners);
    let norms: Vec<f64> = corners
        .iter()
        .map(|c| {
            let (r, _) = corner_residual(model, &t, &poses[c.shot], frame, c);
            r[0].hypot(r[1])
        })
        .collect();
    let mut sorted = norms.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    // The median of a 2-D Gaussian residual's length is 1.1774 σ.
    let limit = (OUTLIER_SIGMAS * median / 1.1774).max(MIN_OUTLIER_PX);
    let kept: Vec<Corner> = corners
        .iter()
        .zip(&norms)
        .filter(|(_, n)| **n <= limit)
        .map(|(c, _)| *c)
        .collect();
    let outliers = corners.len() - kept.len();
    let (t, poses, a) = if outliers > 0 {
        solve(model, poses, frame, &kept)
    } else {
        let a = normal_equations(model, &t, &poses, frame, corners).0;
        (t, poses, a)
    };
    let residuals: Vec<f64> = kept
        .iter()
        .map(|c| {
            let (r, _) = corner_residual(model, &t, &poses[c.shot], frame, c);
            r[0].hypot(r[1])
        })
        .collect();
    let ss: f64 = residuals.iter().map(|r| r * r).sum();
    let dof = (2 * kept.len()).saturating_sub(a.nrows()).max(1) as f64;
    let variance = ss / dof;
    let inverse = a.clone().try_inverse();
    let n = model.terms().len();
    let std_errors = (0..n)
        .map(|k| {
            inverse
                .as_ref()
                .map_or(f64::NAN, |inv| (inv[(k, k)] * variance).max(0.0).sqrt())
        })
        .collect();
    let corner = frame.corner_radius();
    DistortionFit {
        model,
        corner_displacement_px: model.displacement(&t, corner) / frame.norm_scale,
        coefficients: t,
        std_errors,
        rms_px: (ss / kept.len().max(1) as f64).sqrt(),
        max_px: residuals.iter().copied().fold(0.0, f64::max),
        corners: kept.len(),
        outliers,
        poses,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Corners of a 12 × 8 chart seen through a known lensfun model by two poses.
    fn synthetic(model: DistortionModel, t: &[f64]) -> (LensfunFrame, Vec<[f64; 8]>, Vec<Corner>) {
        let frame = LensfunFrame::of_image(1200, 800);
        let poses = [
            [85.0, 1.5, 90.0, -1.2, 84.0, 70.0, 1e-5, -2e-5],
            [80.0, -2.0, 120.0, 2.5, 81.0, 80.0, -3e-5, 1e-5],
        ];
        let mut corners = Vec::new();
        for (s, h) in poses.iter().enumerate() {
            for row in 0..=8 {
                for col in 0..=12 {
                    let x = [col as f64, row as f64];
                    let (u, _) = apply_pose(h, x);
                    let n = frame.to_norm(u);
                    let (g, _, _) = model.eval(t, n[0].hypot(n[1]));
                    let q = frame.from_norm([n[0] * g, n[1] * g]);
                    corners.push(Corner {
                        shot: s,
                        chart: x,
                        sensor: q,
                    });
                }
            }
        }
        (frame, poses.to_vec(), corners)
    }

    #[test]
    fn every_model_recovers_its_own_terms_from_the_poses_alone() {
        for (model, t) in [
            (DistortionModel::Poly3, vec![-0.02]),
            (DistortionModel::Poly5, vec![-0.015, 0.002]),
            (DistortionModel::PtLens, vec![0.004, -0.012, 0.003]),
        ] {
            let (frame, poses, corners) = synthetic(model, &t);
            // Start from poses a little off, as a DLT on distorted corners gives them.
            let start: Vec<[f64; 8]> = poses
                .iter()
                .map(|h| std::array::from_fn(|k| h[k] * (1.0 + 0.01 * (k as f64 - 3.0) / 8.0)))
                .collect();
            let f = fit(model, &start, &frame, &corners);
            for (got, want) in f.coefficients.iter().zip(&t) {
                assert!(
                    (got - want).abs() < 1e-6,
                    "{model:?}: {:?} vs {t:?}",
                    f.coefficients
                );
            }
            assert!(f.rms_px < 1e-6, "{model:?} rms {}", f.rms_px);
            assert_eq!(f.outliers, 0);
        }
    }

    #[test]
    fn displacement_is_the_same_lens_whichever_model_describes_it() {
        // poly3 k₁ and the poly5 it equals after rescaling the ideal image: the
        // displacement at any radius agrees, although the terms differ.
        let k: f64 = -0.03;
        let p3 = DistortionModel::Poly3;
        let p5 = DistortionModel::Poly5;
        // r(1 − k + k r²) with r = s/(1 − k) is s(1 + k/(1 − k)³ s²).
        let k5 = k / (1.0 - k).powi(3);
        for rd in [0.3, 0.8, 1.2] {
            let a = p3.displacement(&[k], rd);
            let b = p5.displacement(&[k5, 0.0], rd);
            assert!((a - b).abs() < 1e-12, "{rd}: {a} {b}");
        }
        assert!(p3.displacement(&[k], 1.0) < 0.0, "barrel moves inward");
    }
}
