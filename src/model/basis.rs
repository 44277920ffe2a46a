//! The normalised Legendre basis: how raw coordinates map to [−1, 1], which monomials a
//! model of orders (α, β) has, their evaluation as Legendre products, the least-squares
//! solvers the fits use, and the fold of a model's terms at one setting into a spatial
//! polynomial.

use super::ModelError;
use crate::plane::LensSetting;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// The highest polynomial order, in any coordinate, a model may have: the basis tables
/// are sized for it, and a profile asking for more is refused.
pub const MAX_ORDER: usize = crate::limits::MAX_MODEL_ORDER;

/// Refuses orders the basis cannot evaluate.
///
/// # Errors
/// [`ModelError::OrderTooHigh`].
pub fn check_order(alpha: usize, beta: usize) -> Result<(), ModelError> {
    if alpha.max(beta) > MAX_ORDER {
        return Err(ModelError::OrderTooHigh { alpha, beta });
    }
    Ok(())
}

/// How raw coordinates map to the [−1, 1] ranges the basis is evaluated on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    pub width: usize,
    pub height: usize,
    /// Calibrated focal range; f maps linearly to [−1, 1] over it.
    pub focal_range_mm: [f64; 2],
    /// Calibrated f-number range; a maps to [−1, 1] linearly in stops (log a).
    pub f_number_range: [f64; 2],
    /// Bounding box `[x0, y0, x1, y1]` (pixels) of the measured squares' centres. The
    /// chart rarely covers the whole sensor, and a polynomial evaluated beyond its data
    /// grows without bound (an order-8 one by tens of % of range at the corners, a
    /// local quadratic by far more), so outside this box the models extrapolate
    /// linearly from its border instead; see [`Normalisation::extrapolate`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampled_extent_px: Option<[f64; 4]>,
}

impl Normalisation {
    #[must_use]
    pub fn uses_focal(&self) -> bool {
        self.focal_range_mm[1] > self.focal_range_mm[0] * (1.0 + 1e-6)
    }

    #[must_use]
    pub fn uses_aperture(&self) -> bool {
        self.f_number_range[1] > self.f_number_range[0] * (1.0 + 1e-6)
    }

    /// Sensor position to [−1, 1]².
    #[must_use]
    pub fn uv(&self, x: f64, y: f64) -> (f64, f64) {
        (
            2.0 * x / (self.width.max(2) as f64 - 1.0) - 1.0,
            2.0 * y / (self.height.max(2) as f64 - 1.0) - 1.0,
        )
    }

    /// Setting to [−1, 1]² (0 along a setting that does not vary).
    #[must_use]
    pub fn fa(&self, s: LensSetting) -> (f64, f64) {
        let [f0, f1] = self.focal_range_mm;
        let [a0, a1] = self.f_number_range;
        let nf = if self.uses_focal() {
            2.0 * (s.focal_mm - f0) / (f1 - f0) - 1.0
        } else {
            0.0
        };
        let na = if self.uses_aperture() {
            2.0 * (s.f_number.ln() - a0.ln()) / (a1.ln() - a0.ln()) - 1.0
        } else {
            0.0
        };
        (nf, na)
    }

    /// Whether a sensor point lies inside the area the calibration measured.
    #[must_use]
    pub fn in_sampled_extent(&self, x: f64, y: f64) -> bool {
        self.sampled_extent_px
            .is_none_or(|e| x >= e[0] && x <= e[2] && y >= e[1] && y <= e[3])
    }

    /// `eval` at (x, y) inside the sampled extent; outside it, the value at the nearest
    /// point of the extent's box plus the slope there (a one-sided difference over 2 %
    /// of the sensor, taken inwards) times the distance. Continuous across the border,
    /// and growing at most linearly where nothing was measured.
    pub fn extrapolate(&self, x: f64, y: f64, eval: impl Fn(f64, f64) -> [f64; 3]) -> [f64; 3] {
        let Some(e) = self.sampled_extent_px else {
            return eval(x, y);
        };
        let (cx, cy) = (x.clamp(e[0], e[2]), y.clamp(e[1], e[3]));
        if cx == x && cy == y {
            return eval(x, y);
        }
        let base = eval(cx, cy);
        let mut out = base;
        let step = 0.02 * self.width.max(self.height) as f64;
        let mut add_slope = |d: f64, lo: f64, hi: f64, at: &dyn Fn(f64) -> [f64; 3]| {
            let h = step.min(hi - lo);
            if d == 0.0 || h <= 0.0 {
                return;
            }
            // Inwards from the border the point was clamped to.
            let inner = at(if d < 0.0 { h } else { -h });
            for k in 0..3 {
                out[k] += (base[k] - inner[k]) / h * d.abs();
            }
        };
        add_slope(x - cx, e[0], e[2], &|dx| eval(cx + dx, cy));
        add_slope(y - cy, e[1], e[3], &|dy| eval(cx, cy + dy));
        out
    }

    /// Whether a setting lies in the calibrated range, widened by the tolerance under
    /// which two values are the same setting ([`LensSetting::RELATIVE_TOLERANCE`]).
    #[must_use]
    pub fn contains(&self, s: LensSetting) -> bool {
        let tol = LensSetting::RELATIVE_TOLERANCE;
        let inside = |v: f64, r: [f64; 2]| v >= r[0] * (1.0 - tol) && v <= r[1] * (1.0 + tol);
        inside(s.focal_mm, self.focal_range_mm) && inside(s.f_number, self.f_number_range)
    }
}

/// The monomials x^i y^j f^k a^l of G_{α,β} (or L_{α,β}) as exponent quadruples, in a
/// fixed order. Terms in a setting that does not vary (`use_f`/`use_a` false) are left
/// out, which makes a single-focal session a model over a only, and a single-setting
/// session spatial only.
#[must_use]
pub fn terms(alpha: usize, beta: usize, use_f: bool, use_a: bool) -> Vec<[u8; 4]> {
    let total = alpha.max(beta);
    let mut out = Vec::new();
    for s in 0..=alpha {
        for t in 0..=beta {
            if s + t > total {
                continue;
            }
            for i in 0..=s {
                let j = s - i;
                for k in 0..=t {
                    let l = t - k;
                    if (k > 0 && !use_f) || (l > 0 && !use_a) {
                        continue;
                    }
                    out.push([i as u8, j as u8, k as u8, l as u8]);
                }
            }
        }
    }
    out
}

/// P_0(t) … P_n(t) by the three-term recurrence.
fn legendre(n: usize, t: f64, out: &mut [f64]) {
    out[0] = 1.0;
    if n >= 1 {
        out[1] = t;
    }
    for m in 1..n {
        let mf = m as f64;
        out[m + 1] = ((2.0 * mf + 1.0) * t * out[m] - mf * out[m - 1]) / (mf + 1.0);
    }
}

/// A Legendre product basis over a term list.
#[derive(Clone, Debug)]
pub struct Basis {
    terms: Vec<[u8; 4]>,
    max_deg: usize,
}

impl Basis {
    #[must_use]
    pub fn new(terms: Vec<[u8; 4]>) -> Self {
        let max_deg = terms
            .iter()
            .flat_map(|t| t.iter().copied())
            .max()
            .unwrap_or(0) as usize;
        Self { terms, max_deg }
    }

    #[must_use]
    pub fn len(&self) -> usize {
        self.terms.len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    #[must_use]
    pub fn terms(&self) -> &[[u8; 4]] {
        &self.terms
    }

    /// The per-coordinate Legendre values at normalised (u, v, f, a).
    fn tables(&self, c: [f64; 4]) -> [[f64; 16]; 4] {
        let mut tab = [[0.0; 16]; 4];
        for (d, &cv) in c.iter().enumerate() {
            legendre(self.max_deg, cv, &mut tab[d]);
        }
        tab
    }

    /// Writes the basis row at normalised coordinates into `out`.
    pub fn row(&self, c: [f64; 4], out: &mut [f64]) {
        let tab = self.tables(c);
        for (o, t) in out.iter_mut().zip(&self.terms) {
            *o = tab[0][t[0] as usize]
                * tab[1][t[1] as usize]
                * tab[2][t[2] as usize]
                * tab[3][t[3] as usize];
        }
    }

    /// Σ coeffs[p][n] · basis_n for each of the three parameters.
    #[must_use]
    pub fn eval3(&self, c: [f64; 4], coeffs: &[Vec<f64>; 3]) -> [f64; 3] {
        let tab = self.tables(c);
        let mut out = [0.0; 3];
        for (n, t) in self.terms.iter().enumerate() {
            let b = tab[0][t[0] as usize]
                * tab[1][t[1] as usize]
                * tab[2][t[2] as usize]
                * tab[3][t[3] as usize];
            for p in 0..3 {
                out[p] += coeffs[p][n] * b;
            }
        }
        out
    }
}

/// Least squares for `y`'s right-hand sides (three for the Gaussians' C_xx, C_yy, C_or).
/// Returns `n × y.ncols()`.
///
/// A well-conditioned design (the Legendre bases here, on a session that spans its
/// coordinates) is solved by its normal equations, as blocked matrix products, with
/// one step of refinement against the design itself: that takes the error from about
/// κ(A)²·ε towards κ(A)·ε, and for a session's design (tens of thousands of rows by
/// hundreds of terms) costs a fraction of a Householder QR, which nalgebra takes a
/// column at a time. Where the Cholesky factor's diagonal spans more than
/// [`NORMAL_EQUATIONS_SPAN`] (κ(A) at least that), it is a tall-skinny QR
/// ([`solve_lsq_qr`]), or SVD where R is near singular.
#[must_use]
pub fn solve_lsq(a: DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let (m, n) = a.shape();
    if m >= n
        && n > 0
        && y.nrows() == m
        && let Some(x) = solve_by_normal_equations(&a, y)
    {
        return x;
    }
    solve_lsq_qr(a, y)
}

/// The largest ratio of the Cholesky factor's diagonal entries [`solve_lsq`] solves by
/// the normal equations: a lower bound on κ(A), so about 10⁻⁸ lost before the
/// refinement at most.
const NORMAL_EQUATIONS_SPAN: f64 = 1e4;

/// [`solve_lsq`]'s normal equations with one refinement step; `None` where they are
/// not well enough conditioned to trust.
fn solve_by_normal_equations(a: &DMatrix<f64>, y: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let at = a.transpose();
    let chol = (&at * a).cholesky()?;
    let l = chol.l_dirty();
    let (lo, hi) = (0..l.nrows()).fold((f64::INFINITY, 0.0f64), |(lo, hi), i| {
        (lo.min(l[(i, i)].abs()), hi.max(l[(i, i)].abs()))
    });
    if !(lo > 0.0 && hi.is_finite() && hi <= NORMAL_EQUATIONS_SPAN * lo) {
        return None;
    }
    let mut x = chol.solve(&(&at * y));
    let residual = y - a * &x;
    x += chol.solve(&(&at * residual));
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// [`solve_lsq`] by QR: Householder, or SVD where R is (near) singular.
///
/// The QR is taken by blocks of rows (a tall-skinny QR): each block of `[A | y]` is
/// reduced to its triangle, the triangles stacked and reduced again until one is left.
/// That triangle is R with Qᵀy beside it, as a QR of the whole would give (to
/// rounding), at a block's cost in memory traffic and with the blocks in parallel: a
/// session's design has tens of thousands of rows, and a column-at-a-time QR of it
/// streams the whole matrix once per column.
fn solve_lsq_qr(a: DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let (m, n) = a.shape();
    if m >= n && n > 0 && y.nrows() == m {
        let k = y.ncols();
        let augmented = DMatrix::from_fn(
            m,
            n + k,
            |i, j| {
                if j < n { a[(i, j)] } else { y[(i, j - n)] }
            },
        );
        let r = tall_skinny_r(augmented);
        let diag_max = (0..n).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
        let well_posed = (0..n).all(|i| r[(i, i)].abs() > 1e-10 * diag_max.max(1e-300));
        if well_posed {
            let top = r.view((0, n), (n, k)).into_owned();
            if let Some(x) = r.view((0, 0), (n, n)).solve_upper_triangular(&top) {
                return x;
            }
        }
    }
    let svd = a.svd(true, true);
    svd.solve(y, 1e-10 * svd.singular_values.max().max(1e-300))
        .unwrap_or_else(|_| DMatrix::zeros(n, y.ncols()))
}

/// The R factor of `m`'s QR (at most `m.ncols()` rows), block by block of rows.
fn tall_skinny_r(mut m: DMatrix<f64>) -> DMatrix<f64> {
    use rayon::prelude::*;
    let cols = m.ncols();
    // Blocks of a few triangles' height: small enough to stay in cache, tall enough
    // that each reduction removes most of its rows.
    let block = (4 * cols).max(256);
    while m.nrows() > block {
        let starts: Vec<usize> = (0..m.nrows()).step_by(block).collect();
        let triangles: Vec<DMatrix<f64>> = starts
            .par_iter()
            .map(|&r0| {
                let rows = block.min(m.nrows() - r0);
                m.rows(r0, rows).into_owned().qr().r()
            })
            .collect();
        let height = triangles.iter().map(DMatrix::nrows).sum();
        let mut stacked = DMatrix::zeros(height, cols);
        let mut at = 0;
        for t in &triangles {
            stacked.rows_mut(at, t.nrows()).copy_from(t);
            at += t.nrows();
        }
        m = stacked;
    }
    m.qr().r()
}

/// Solves the normal equations `gram · x = rhs` (Cholesky; SVD pseudo-inverse where the
/// Gram matrix is singular). Used by cross-validation, whose folds reuse per-shot Gram
/// sums; in the orthogonal basis these agree with [`solve_lsq`] to rounding.
#[must_use]
pub fn solve_normal(gram: DMatrix<f64>, rhs: &DMatrix<f64>) -> DMatrix<f64> {
    let n = gram.nrows();
    if let Some(ch) = gram.clone().cholesky() {
        let x = ch.solve(rhs);
        if x.iter().all(|v| v.is_finite()) {
            return x;
        }
    }
    let svd = gram.svd(true, true);
    svd.solve(rhs, 1e-12 * svd.singular_values.max().max(1e-300))
        .unwrap_or_else(|_| DMatrix::zeros(n, rhs.ncols()))
}

/// Three polynomials in (u, v) only: a model's terms at one fixed setting, with the
/// factors P_k(f) P_l(a) folded into the spatial coefficients. A whole field at one
/// setting then costs one small spatial polynomial per point instead of the full
/// four-dimensional basis.
#[derive(Clone, Debug)]
pub struct SpatialPoly {
    terms: Vec<[u8; 2]>,
    max_deg: usize,
    coeffs: [Vec<f64>; 3],
}

impl SpatialPoly {
    /// The terms of `basis` with coefficients `coeffs` at normalised setting (nf, na).
    pub(super) fn fold(basis: &Basis, coeffs: &[Vec<f64>; 3], nf: f64, na: f64) -> Self {
        let mut pf = [0.0; MAX_ORDER + 1];
        let mut pa = [0.0; MAX_ORDER + 1];
        legendre(basis.max_deg, nf, &mut pf);
        legendre(basis.max_deg, na, &mut pa);
        let mut index = [[usize::MAX; MAX_ORDER + 1]; MAX_ORDER + 1];
        let mut terms: Vec<[u8; 2]> = Vec::new();
        let mut out: [Vec<f64>; 3] = Default::default();
        for (n, t) in basis.terms.iter().enumerate() {
            let (i, j) = (t[0] as usize, t[1] as usize);
            if index[i][j] == usize::MAX {
                index[i][j] = terms.len();
                terms.push([t[0], t[1]]);
                for o in &mut out {
                    o.push(0.0);
                }
            }
            let w = pf[t[2] as usize] * pa[t[3] as usize];
            for p in 0..3 {
                out[p][index[i][j]] += coeffs[p][n] * w;
            }
        }
        let max_deg = terms
            .iter()
            .flat_map(|t| t.iter().copied())
            .max()
            .unwrap_or(0) as usize;
        Self {
            terms,
            max_deg,
            coeffs: out,
        }
    }

    #[must_use]
    pub fn eval(&self, u: f64, v: f64) -> [f64; 3] {
        let mut pu = [0.0; MAX_ORDER + 1];
        let mut pv = [0.0; MAX_ORDER + 1];
        legendre(self.max_deg, u, &mut pu);
        legendre(self.max_deg, v, &mut pv);
        let mut out = [0.0; 3];
        for (n, t) in self.terms.iter().enumerate() {
            let b = pu[t[0] as usize] * pv[t[1] as usize];
            for (o, c) in out.iter_mut().zip(&self.coeffs) {
                *o += c[n] * b;
            }
        }
        out
    }
}

/// The basis of G_{α,β} (or L_{α,β}) under a normalisation.
#[must_use]
pub fn model_basis(norm: &Normalisation, alpha: usize, beta: usize) -> Basis {
    Basis::new(terms(alpha, beta, norm.uses_focal(), norm.uses_aperture()))
}

/// One least-squares problem as matrices: a row of `basis` at each sample's normalised
/// coordinates (the design), and each sample's measured C_xx, C_yy, C_or (the right-hand
/// sides), in the order `rows` gives them.
pub(crate) fn design_system(
    basis: &Basis,
    rows: impl ExactSizeIterator<Item = ([f64; 4], [f64; 3])>,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let mut a = DMatrix::zeros(rows.len(), basis.len());
    let mut y = DMatrix::zeros(rows.len(), 3);
    let mut row = vec![0.0; basis.len()];
    for (r, (coords, params)) in rows.enumerate() {
        basis.row(coords, &mut row);
        for (c, v) in row.iter().enumerate() {
            a[(r, c)] = *v;
        }
        for (p, v) in params.iter().enumerate() {
            y[(r, p)] = *v;
        }
    }
    (a, y)
}

/// The columns of an `n × 3` solution as the coefficient vectors of C_xx, C_yy, C_or.
pub(crate) fn split_coeffs(x: &DMatrix<f64>) -> [Vec<f64>; 3] {
    [
        x.column(0).iter().copied().collect(),
        x.column(1).iter().copied().collect(),
        x.column(2).iter().copied().collect(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn legendre_matches_closed_forms() {
        let mut p = [0.0; 5];
        legendre(4, 0.3, &mut p);
        assert!((p[2] - 0.5 * (3.0 * 0.09 - 1.0)).abs() < 1e-12);
        assert!((p[3] - 0.5 * (5.0 * 0.027 - 3.0 * 0.3)).abs() < 1e-12);
        assert!((p[4] - (35.0 * 0.0081 - 30.0 * 0.09 + 3.0) / 8.0).abs() < 1e-12);
    }

    #[test]
    fn qr_and_normal_equations_agree() {
        let basis = Basis::new(terms(3, 2, true, true));
        let n = basis.len();
        // Tall enough that the QR is taken in blocks, and their triangles in blocks again.
        let m = 40 * (n + 3);
        let mut a = DMatrix::zeros(m, n);
        let mut y = DMatrix::zeros(m, 3);
        let mut row = vec![0.0; n];
        for r in 0..m {
            let t = r as f64;
            let c = [
                (t * 0.37).sin(),
                (t * 0.71).cos(),
                ((t * 0.13).sin()),
                (t * 0.29).cos(),
            ];
            basis.row(c, &mut row);
            for k in 0..n {
                a[(r, k)] = row[k];
            }
            for p in 0..3 {
                y[(r, p)] = c[0] * c[1] + (p as f64) * c[2] * c[3] * c[3] + 0.01 * (t * 1.7).sin();
            }
        }
        let x1 = solve_lsq(a.clone(), &y);
        let x2 = solve_normal(a.tr_mul(&a), &a.tr_mul(&y));
        assert!((&x1 - x2).abs().max() < 1e-8);
        // The same solution as one Householder QR of the whole design, by the normal
        // equations (this design is well conditioned) and by blocks of QR.
        assert!(solve_by_normal_equations(&a, &y).is_some());
        let x3 = one_qr(&a, &y);
        let scale = x3.abs().max().max(1.0);
        assert!((&x1 - &x3).abs().max() < 1e-12 * scale);
        let x4 = solve_lsq_qr(a.clone(), &y);
        assert!((&x4 - &x3).abs().max() < 1e-12 * scale);

        // A column a million times smaller than the rest: κ(A) too large for the
        // normal equations, so QR solves it, and as one QR would.
        let mut bad = a.clone();
        bad.column_mut(n - 1).scale_mut(1e-6);
        assert!(solve_by_normal_equations(&bad, &y).is_none());
        let x5 = solve_lsq(bad.clone(), &y);
        let x6 = one_qr(&bad, &y);
        let scale = x6.abs().max().max(1.0);
        assert!((x5 - &x6).abs().max() < 1e-9 * scale);
    }

    fn one_qr(a: &DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
        let n = a.ncols();
        let qr = a.clone().qr();
        let mut qty = y.clone();
        qr.q_tr_mul(&mut qty);
        qr.r()
            .solve_upper_triangular(&qty.rows(0, n).into_owned())
            .expect("well posed")
    }
}
