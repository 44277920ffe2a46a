//! The kernel's least-squares problem as FFT operators, and conjugate gradients on its
//! normal equations.
//!
//! Unknowns: the `K × K` kernel (row-major), one constant offset c and the light's
//! slope (a, b) across the window. The model at convolution-output sample n is
//! y(n) = Σ_i k(i) X(n − i) + c + (a u(n) + b v(n)) (g ⊛ X)(n), valid for n in
//! `[K − 1, N − 1]` along each axis, where (u, v) is the position across the raster
//! (−1 to 1) and g a guess at the blur: the slope scales the blurred chart, and with
//! the guess in place of the kernel the model stays linear, wrong only by the slope
//! times the guess's error. Without a guess the slope's columns are zero and stay so.
//! Observations carry a weight w(n) (how many fall there) and a sum t(n), so
//! ‖W(Ax − b)‖² has normal equations Aᵀ diag(w) A x = Aᵀ t.

use crate::fft::{Fft2, good_size};
use rustfft::num_complex::Complex;

/// A symmetric positive semi-definite system `N x = r` given by its action.
pub trait NormalEquations {
    fn dim(&self) -> usize;
    /// `out = N x`.
    fn apply(&mut self, x: &[f64], out: &mut [f64]);
    /// The right-hand side r.
    fn rhs(&mut self) -> Vec<f64>;
}

/// The kernel problem of one square and channel.
pub struct LeastSquares {
    m: usize,
    k_size: usize,
    fft: Fft2,
    sharp_spectrum: Vec<Complex<f64>>,
    weight: Vec<f64>,
    target: Vec<f64>,
    rows_lo: usize,
    rows_hi: usize,
    sharp_mean_square: f64,
    smoothness: f64,
    /// Shading regressors per output sample (see `EdgeProblem::set_shading_reference`):
    /// zero until a reference is set.
    shade: [Vec<f64>; 2],
    nx: usize,
    ny: usize,
    image: Vec<f64>,
    spectrum: Vec<Complex<f64>>,
}

impl LeastSquares {
    /// A problem for a `k_size × k_size` kernel over the sharp raster `sharp`
    /// (`nx × ny`, row-major), with no observations yet.
    ///
    /// # Panics
    /// If the raster is smaller than the kernel or wrongly sized.
    #[must_use]
    pub fn new(sharp: &[f32], nx: usize, ny: usize, k_size: usize) -> Self {
        assert!(
            sharp.len() == nx * ny && nx >= k_size && ny >= k_size,
            "raster smaller than the kernel"
        );
        let m = good_size(nx.max(ny));
        let mut fft = Fft2::new(m, m);
        let mut padded = vec![0.0; m * m];
        for y in 0..ny {
            for x in 0..nx {
                padded[y * m + x] = f64::from(sharp[y * nx + x]);
            }
        }
        let mut sharp_spectrum = fft.new_spectrum();
        fft.forward_rows(&padded, 0..ny, &mut sharp_spectrum);
        let spectrum = fft.new_spectrum();
        Self {
            m,
            k_size,
            fft,
            sharp_spectrum,
            weight: vec![0.0; m * m],
            target: vec![0.0; m * m],
            rows_lo: usize::MAX,
            rows_hi: 0,
            sharp_mean_square: sharp.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>()
                / sharp.len() as f64,
            smoothness: 0.0,
            shade: [vec![0.0; m * m], vec![0.0; m * m]],
            nx,
            ny,
            image: vec![0.0; m * m],
            spectrum,
        }
    }

    /// The shading regressors from a guess at the blur (`K × K`), as
    /// `EdgeProblem::set_shading_reference` sets them: at each observed output sample,
    /// its position across the raster (−1 to 1) times the chart blurred by the guess.
    /// Call it after the observations.
    pub fn set_shading_reference(&mut self, kernel: &[f64]) {
        let (m, k) = (self.m, self.k_size);
        self.convolve_into_image(kernel);
        let r = k / 2;
        let across = |end: usize, len: usize| {
            let half = (len as f64 - 1.0) / 2.0;
            (end as f64 + 1.0 - k as f64 + r as f64 - half) / half.max(1.0)
        };
        for row in 0..m {
            for col in 0..m {
                let i = row * m + col;
                let (sx, sy) = if self.weight[i] > 0.0 {
                    let v = self.image[i];
                    (across(col, self.nx) * v, across(row, self.ny) * v)
                } else {
                    (0.0, 0.0)
                };
                self.shade[0][i] = sx;
                self.shade[1][i] = sy;
            }
        }
    }

    /// Adds λ·‖∇k‖² to the objective, λ = `relative` × the typical diagonal of AᵀWA
    /// (so the setting does not depend on the number of observations or the levels).
    pub fn set_smoothness(&mut self, relative: f64) {
        self.smoothness = relative.max(0.0);
    }

    /// Adds an observation `value` at convolution-output sample (n_x, n_y), which must
    /// be a valid one (≥ K − 1 and inside the raster along each axis).
    pub fn observe(&mut self, n_x: usize, n_y: usize, value: f64) {
        let idx = n_y * self.m + n_x;
        self.weight[idx] += 1.0;
        self.target[idx] += value;
        self.rows_lo = self.rows_lo.min(n_y);
        self.rows_hi = self.rows_hi.max(n_y + 1);
    }

    /// λ of the gradient penalty (see [`LeastSquares::set_smoothness`]).
    fn penalty_weight(&self) -> f64 {
        let total_weight: f64 = self.weight.iter().sum();
        self.smoothness * total_weight * self.sharp_mean_square
    }

    fn penalty_rows(&self) -> usize {
        if self.smoothness > 0.0 {
            2 * self.k_size * (self.k_size - 1)
        } else {
            0
        }
    }

    fn obs_rows(&self) -> std::ops::Range<usize> {
        if self.rows_lo >= self.rows_hi {
            0..0
        } else {
            self.rows_lo..self.rows_hi
        }
    }

    /// `self.image` = the sharp raster convolved with the `K × K` kernel, on the
    /// observed rows (the rest is not meaningful).
    fn convolve_into_image(&mut self, kernel: &[f64]) {
        let (m, k) = (self.m, self.k_size);
        self.image.iter_mut().for_each(|v| *v = 0.0);
        for j in 0..k {
            self.image[j * m..j * m + k].copy_from_slice(&kernel[j * k..(j + 1) * k]);
        }
        self.fft.forward_rows(&self.image, 0..k, &mut self.spectrum);
        for (s, x) in self.spectrum.iter_mut().zip(&self.sharp_spectrum) {
            *s *= x;
        }
        let rows = self.obs_rows();
        self.fft
            .inverse_rows(&mut self.spectrum, rows, &mut self.image);
    }

    /// `out_k = Aᵀ z` for the image in `self.image` (zero outside the observed rows).
    fn correlate_into(&mut self, out: &mut [f64]) {
        let m = self.m;
        let rows = self.obs_rows();
        self.fft.forward_rows(&self.image, rows, &mut self.spectrum);
        for (s, x) in self.spectrum.iter_mut().zip(&self.sharp_spectrum) {
            *s *= x.conj();
        }
        let k = self.k_size;
        self.fft
            .inverse_rows(&mut self.spectrum, 0..k, &mut self.image);
        for j in 0..k {
            out[j * k..(j + 1) * k].copy_from_slice(&self.image[j * m..j * m + k]);
        }
    }
}

impl NormalEquations for LeastSquares {
    fn dim(&self) -> usize {
        self.k_size * self.k_size + 3
    }

    fn apply(&mut self, x: &[f64], out: &mut [f64]) {
        let (m, k) = (self.m, self.k_size);
        let (kernel, rest) = x.split_at(k * k);
        let (offset, a, b) = (rest[0], rest[1], rest[2]);
        self.convolve_into_image(kernel);
        let rows = self.obs_rows();
        let (mut sum, mut sum_x, mut sum_y) = (0.0, 0.0, 0.0);
        for row in 0..m {
            let r = row * m..(row + 1) * m;
            let line = &mut self.image[r.clone()];
            if rows.contains(&row) {
                for (((v, w), sx), sy) in line
                    .iter_mut()
                    .zip(&self.weight[r.clone()])
                    .zip(&self.shade[0][r.clone()])
                    .zip(&self.shade[1][r.clone()])
                {
                    *v = w * (*v + offset + a * sx + b * sy);
                    sum += *v;
                    sum_x += *v * sx;
                    sum_y += *v * sy;
                }
            } else {
                line.iter_mut().for_each(|v| *v = 0.0);
            }
        }
        let (out_k, out_c) = out.split_at_mut(k * k);
        out_c.copy_from_slice(&[sum, sum_x, sum_y]);
        self.correlate_into(out_k);
        if self.smoothness > 0.0 {
            add_gradient_penalty(kernel, k, self.penalty_weight(), out_k);
        }
    }

    fn rhs(&mut self) -> Vec<f64> {
        let k = self.k_size;
        self.image.copy_from_slice(&self.target);
        let mut out = vec![0.0; k * k + 3];
        out[k * k] = self.target.iter().sum();
        for axis in 0..2 {
            out[k * k + 1 + axis] = self
                .target
                .iter()
                .zip(&self.shade[axis])
                .map(|(t, s)| t * s)
                .sum();
        }
        self.correlate_into(&mut out[..k * k]);
        out
    }
}

/// `out += λ · Dᵀ D k` for forward differences along x and y of the `k × k` kernel
/// (free boundary): the normal-equation term of λ‖∇k‖².
pub fn add_gradient_penalty(kernel: &[f64], k: usize, lambda: f64, out: &mut [f64]) {
    for j in 0..k {
        for i in 0..k {
            let v = kernel[j * k + i];
            let mut acc = 0.0;
            if i > 0 {
                acc += v - kernel[j * k + i - 1];
            }
            if i + 1 < k {
                acc += v - kernel[j * k + i + 1];
            }
            if j > 0 {
                acc += v - kernel[(j - 1) * k + i];
            }
            if j + 1 < k {
                acc += v - kernel[(j + 1) * k + i];
            }
            out[j * k + i] += lambda * acc;
        }
    }
}

/// √λ times the forward differences of the kernel, along x then along y.
pub(super) fn gradient_rows(kernel: &[f64], k: usize, scale: f64, out: &mut [f64]) {
    let mut o = 0;
    for j in 0..k {
        for i in 0..k - 1 {
            out[o] = scale * (kernel[j * k + i + 1] - kernel[j * k + i]);
            o += 1;
        }
    }
    for j in 0..k - 1 {
        for i in 0..k {
            out[o] = scale * (kernel[(j + 1) * k + i] - kernel[j * k + i]);
            o += 1;
        }
    }
}

/// out += the transpose of [`gradient_rows`] applied to `r`.
pub(super) fn gradient_rows_adjoint(r: &[f64], k: usize, scale: f64, out: &mut [f64]) {
    let mut o = 0;
    for j in 0..k {
        for i in 0..k - 1 {
            out[j * k + i + 1] += scale * r[o];
            out[j * k + i] -= scale * r[o];
            o += 1;
        }
    }
    for j in 0..k - 1 {
        for i in 0..k {
            out[(j + 1) * k + i] += scale * r[o];
            out[j * k + i] -= scale * r[o];
            o += 1;
        }
    }
}

/// A linear least-squares operator A with its target b: min ‖A x − b‖².
pub trait LinearOperator {
    /// Unknowns.
    fn dim(&self) -> usize;
    /// Rows (observations).
    fn rows(&self) -> usize;
    /// `out = A x`.
    fn forward(&mut self, x: &[f64], out: &mut [f64]);
    /// `out = Aᵀ r`.
    fn adjoint(&mut self, r: &[f64], out: &mut [f64]);
    fn target(&self) -> Vec<f64>;
}

/// The same problem as a least-squares operator for [`cgls_solve`]: one row per
/// observed output sample n, scaled by √w(n) with target t(n)/√w(n) (so that
/// ‖A x − b‖² equals ‖W(A k − b)‖² up to a constant), then the penalty rows.
impl LinearOperator for LeastSquares {
    fn dim(&self) -> usize {
        self.k_size * self.k_size + 3
    }

    fn rows(&self) -> usize {
        self.weight.iter().filter(|&&w| w > 0.0).count() + self.penalty_rows()
    }

    fn forward(&mut self, x: &[f64], out: &mut [f64]) {
        let k = self.k_size;
        let (kernel, rest) = x.split_at(k * k);
        self.convolve_into_image(kernel);
        let mut o = 0;
        for (i, (v, &w)) in self.image.iter().zip(&self.weight).enumerate() {
            if w > 0.0 {
                let shading = rest[1] * self.shade[0][i] + rest[2] * self.shade[1][i];
                out[o] = w.sqrt() * (v + rest[0] + shading);
                o += 1;
            }
        }
        if self.smoothness > 0.0 {
            let lambda = self.penalty_weight();
            gradient_rows(kernel, k, lambda.sqrt(), &mut out[o..]);
        }
    }

    fn adjoint(&mut self, r: &[f64], out: &mut [f64]) {
        let k = self.k_size;
        let mut o = 0;
        let (mut sum, mut sum_x, mut sum_y) = (0.0, 0.0, 0.0);
        for (i, (v, &w)) in self.image.iter_mut().zip(&self.weight).enumerate() {
            *v = if w > 0.0 {
                let z = w.sqrt() * r[o];
                o += 1;
                sum += z;
                sum_x += z * self.shade[0][i];
                sum_y += z * self.shade[1][i];
                z
            } else {
                0.0
            };
        }
        let (out_k, out_c) = out.split_at_mut(k * k);
        out_c.copy_from_slice(&[sum, sum_x, sum_y]);
        self.correlate_into(out_k);
        if self.smoothness > 0.0 {
            let lambda = self.penalty_weight();
            gradient_rows_adjoint(&r[o..], k, lambda.sqrt(), out_k);
        }
    }

    fn target(&self) -> Vec<f64> {
        let mut b: Vec<f64> = self
            .weight
            .iter()
            .zip(&self.target)
            .filter(|&(&w, _)| w > 0.0)
            .map(|(&w, &t)| t / w.sqrt())
            .collect();
        b.resize(b.len() + self.penalty_rows(), 0.0);
        b
    }
}

/// CGLS (Björck): conjugate gradients on the normal equations, carried out with A and
/// Aᵀ separately and the residual kept in observation space, from zero, for at most
/// `max_iterations`, stopping when ‖Aᵀr‖ ≤ `tolerance`·‖Aᵀb‖. In exact arithmetic its
/// iterates are those of [`cg_solve`] on AᵀA; in floating point it does not square the
/// operator's rounding, which matters when the iteration count is the regulariser.
pub fn cgls_solve(
    problem: &mut impl LinearOperator,
    max_iterations: usize,
    tolerance: f64,
) -> CgSolution {
    let (n, m) = (problem.dim(), problem.rows());
    let r = problem.target();
    let mut s = vec![0.0; n];
    problem.adjoint(&r, &mut s);
    let mut descent = Residual {
        problem,
        r,
        q: vec![0.0; m],
    };
    iterate(&mut descent, s, max_iterations, tolerance)
}

/// What conjugate gradients reached.
#[derive(Clone, Debug)]
pub struct CgSolution {
    pub x: Vec<f64>,
    pub iterations: usize,
    /// ‖r‖ / ‖b‖ of the normal equations at the end.
    pub relative_residual: f64,
}

/// Conjugate gradients from zero on `N x = r`, at most `max_iterations`, stopping when
/// ‖r‖ ≤ `tolerance`·‖b‖.
pub fn cg_solve(
    problem: &mut impl NormalEquations,
    max_iterations: usize,
    tolerance: f64,
) -> CgSolution {
    let b = problem.rhs();
    let mut descent = Normal {
        q: vec![0.0; problem.dim()],
        problem,
    };
    iterate(&mut descent, b, max_iterations, tolerance)
}

/// Conjugate gradients as [`cg_solve`] and [`cgls_solve`] share them: the curvature of a
/// search direction, and the gradient after a step along it.
trait Descent {
    /// pᵀ N p of the direction p, keeping what [`Descent::step`] needs.
    fn curvature(&mut self, p: &[f64]) -> f64;
    /// Moves the gradient `g` by a step `alpha` along the direction last measured.
    fn step(&mut self, alpha: f64, g: &mut [f64]);
}

/// CG on the normal equations N x = b: the gradient is the residual b − N x.
struct Normal<'a, P> {
    problem: &'a mut P,
    /// N p.
    q: Vec<f64>,
}

impl<P: NormalEquations> Descent for Normal<'_, P> {
    fn curvature(&mut self, p: &[f64]) -> f64 {
        self.problem.apply(p, &mut self.q);
        dot(p, &self.q)
    }

    fn step(&mut self, alpha: f64, g: &mut [f64]) {
        add_scaled(g, -alpha, &self.q);
    }
}

/// CGLS: the residual r = b − A x kept in observation space, the gradient Aᵀ r.
struct Residual<'a, P> {
    problem: &'a mut P,
    r: Vec<f64>,
    /// A p.
    q: Vec<f64>,
}

impl<P: LinearOperator> Descent for Residual<'_, P> {
    fn curvature(&mut self, p: &[f64]) -> f64 {
        self.problem.forward(p, &mut self.q);
        dot(&self.q, &self.q)
    }

    fn step(&mut self, alpha: f64, g: &mut [f64]) {
        add_scaled(&mut self.r, -alpha, &self.q);
        self.problem.adjoint(&self.r, g);
    }
}

/// Conjugate gradients from x = 0 with the initial gradient `g`, for at most
/// `max_iterations`, stopping when ‖g‖ ≤ `tolerance`·‖g₀‖.
fn iterate(
    descent: &mut impl Descent,
    mut g: Vec<f64>,
    max_iterations: usize,
    tolerance: f64,
) -> CgSolution {
    let mut x = vec![0.0; g.len()];
    let mut gg = dot(&g, &g);
    let g0 = gg.sqrt();
    if !(g0 > 0.0) {
        return CgSolution {
            x,
            iterations: 0,
            relative_residual: 0.0,
        };
    }
    let mut p = g.clone();
    let mut iterations = 0;
    while iterations < max_iterations && gg.sqrt() > tolerance * g0 {
        let curvature = descent.curvature(&p);
        if !(curvature > 0.0) {
            break;
        }
        let alpha = gg / curvature;
        add_scaled(&mut x, alpha, &p);
        descent.step(alpha, &mut g);
        let gg_new = dot(&g, &g);
        next_direction(&mut p, &g, gg_new / gg);
        gg = gg_new;
        iterations += 1;
    }
    CgSolution {
        x,
        iterations,
        relative_residual: gg.sqrt() / g0,
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// y ← y + a·x, element by element (`y − a·x` is `y + (−a)·x` exactly, so the residual
/// updates round as they did written out).
fn add_scaled(y: &mut [f64], a: f64, x: &[f64]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

/// The next search direction p ← g + β·p from the new gradient (or residual) g.
fn next_direction(p: &mut [f64], g: &[f64], beta: f64) {
    for (p, g) in p.iter_mut().zip(g) {
        *p = g + beta * *p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use rand::{Rng, SeedableRng};

    /// The same model built as a dense matrix: rows are observations, columns the kernel
    /// samples, the offset and the two shading regressors for the blur guess `guess`
    /// (position across the raster times the chart blurred by the guess).
    fn dense(
        sharp: &[f32],
        (nx, ny): (usize, usize),
        k: usize,
        obs: &[(usize, usize, f64)],
        guess: &[f64],
    ) -> (DMatrix<f64>, DVector<f64>) {
        let mut a = DMatrix::zeros(obs.len(), k * k + 3);
        let mut b = DVector::zeros(obs.len());
        let across = |end: usize, len: usize| {
            let half = (len as f64 - 1.0) / 2.0;
            (end as f64 + 1.0 - k as f64 + (k / 2) as f64 - half) / half
        };
        for (row, &(n_x, n_y, v)) in obs.iter().enumerate() {
            let mut blurred = 0.0;
            for j in 0..k {
                for i in 0..k {
                    let x = f64::from(sharp[(n_y - j) * nx + (n_x - i)]);
                    a[(row, j * k + i)] = x;
                    blurred += guess[j * k + i] * x;
                }
            }
            a[(row, k * k)] = 1.0;
            a[(row, k * k + 1)] = across(n_x, nx) * blurred;
            a[(row, k * k + 2)] = across(n_y, ny) * blurred;
            b[row] = v;
        }
        (a, b)
    }

    #[test]
    fn fft_operator_and_cg_match_a_dense_solve() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let (nx, ny, k) = (14, 12, 3);
        let sharp: Vec<f32> = (0..nx * ny).map(|_| rng.random::<f32>()).collect();
        let mut obs = Vec::new();
        for n_y in (k - 1)..ny {
            for n_x in (k - 1)..nx {
                if rng.random::<f64>() < 0.6 {
                    obs.push((n_x, n_y, rng.random::<f64>()));
                }
            }
        }
        let mut problem = LeastSquares::new(&sharp, nx, ny, k);
        for &(x, y, v) in &obs {
            problem.observe(x, y, v);
        }
        let guess: Vec<f64> = (0..k * k).map(|_| rng.random::<f64>()).collect();
        problem.set_shading_reference(&guess);
        let (a, b) = dense(&sharp, (nx, ny), k, &obs, &guess);
        // The operator is AᵀWA.
        let ata = a.transpose() * &a;
        let probe: Vec<f64> = (0..k * k + 3).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut out = vec![0.0; k * k + 3];
        problem.apply(&probe, &mut out);
        let want = &ata * DVector::from_vec(probe);
        for (o, w) in out.iter().zip(want.iter()) {
            assert!((o - w).abs() < 1e-9 * (1.0 + w.abs()), "{o} vs {w}");
        }
        let rhs = problem.rhs();
        let want_rhs = a.transpose() * &b;
        for (o, w) in rhs.iter().zip(want_rhs.iter()) {
            assert!((o - w).abs() < 1e-9 * (1.0 + w.abs()));
        }
        let dense_x = ata.clone().lu().solve(&want_rhs).unwrap();
        let cg = cg_solve(&mut problem, 200, 1e-13);
        for (c, d) in cg.x.iter().zip(dense_x.iter()) {
            assert!((c - d).abs() < 1e-6 * (1.0 + d.abs()), "{c} vs {d}");
        }
    }

    #[test]
    fn least_squares_form_has_the_normal_equations() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
        let (nx, ny, k) = (16, 13, 3);
        let sharp: Vec<f32> = (0..nx * ny).map(|_| rng.random::<f32>()).collect();
        for smoothness in [0.0, 0.05] {
            let mut problem = LeastSquares::new(&sharp, nx, ny, k);
            problem.set_smoothness(smoothness);
            for n_y in (k - 1)..ny {
                for n_x in (k - 1)..nx {
                    // Some samples observed twice, as two planes of one channel can be.
                    for _ in 0..rng.random_range(0..3) {
                        problem.observe(n_x, n_y, rng.random::<f64>());
                    }
                }
            }
            if smoothness > 0.0 {
                let guess: Vec<f64> = (0..k * k).map(|_| rng.random::<f64>()).collect();
                problem.set_shading_reference(&guess);
            }
            let probe: Vec<f64> = (0..k * k + 3).map(|_| rng.random::<f64>() - 0.5).collect();
            let mut want = vec![0.0; k * k + 3];
            problem.apply(&probe, &mut want);
            let mut y = vec![0.0; LinearOperator::rows(&problem)];
            problem.forward(&probe, &mut y);
            let mut got = vec![0.0; k * k + 3];
            problem.adjoint(&y, &mut got);
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() < 1e-9 * (1.0 + w.abs()), "{g} vs {w}");
            }
            let want_rhs = problem.rhs();
            let mut got_rhs = vec![0.0; k * k + 3];
            problem.adjoint(&LinearOperator::target(&problem), &mut got_rhs);
            for (g, w) in got_rhs.iter().zip(&want_rhs) {
                assert!((g - w).abs() < 1e-9 * (1.0 + w.abs()), "{g} vs {w}");
            }
        }
    }
}
