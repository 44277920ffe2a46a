//! The kernel's least-squares problem over the observed pixel centres, applied
//! directly rather than by FFT.
//!
//! With the default weighting only real pixel centres are observed: one sub-sample in
//! s² (s² · 4 for a Bayer plane), so an FFT over the whole oversampled grid computes
//! mostly outputs nobody reads. Here each observation is the dot product of the kernel
//! with the K × K patch of the sharp raster under it, and only observations whose patch
//! holds an edge are visited each iteration: a patch that is uniformly white or black
//! sees only the kernel's sum and the offset, so all of those together are a few running
//! sums (`FlatSums`). The work per iteration is (edge observations) × K², and patches
//! are contiguous raster rows, so the inner loops are plain dot products and AXPYs.
//!
//! Precision: everything is `f64`. The iteration count is the regulariser here, and
//! conjugate gradients on this ill-conditioned problem amplify an operator's rounding
//! once its directions lose orthogonality: with the products in `f32` (even with `f64`
//! accumulation across rows and blocks of observations) the estimated σ moved by 1–3 %.
//!
//! Unknowns, as for the FFT form: the K × K kernel (row-major) then one offset. The model
//! at an observation whose patch starts at raster index p₀ is
//! y = Σ_u k(K−1−u) X(p₀ + u) + c: a convolution read as a correlation with the flipped
//! kernel.

use super::solve::LinearOperator;

/// Observations whose kernel patch is uniformly black (0) or white (1): each group is
/// one repeated design row, (0, …, 0, 1) or (1, …, 1, 1), so it enters the least squares
/// as that row weighted by √n with its mean as the target.
#[derive(Clone, Copy, Debug, Default)]
struct FlatSums {
    /// Count and sum of the observed values, per group.
    n: [f64; 2],
    y: [f64; 2],
}

impl FlatSums {
    fn weight(&self, g: usize) -> f64 {
        self.n[g].sqrt()
    }

    fn target(&self, g: usize) -> f64 {
        if self.n[g] > 0.0 {
            self.y[g] / self.n[g].sqrt()
        } else {
            0.0
        }
    }
}

/// The problem of one square and channel at one kernel size.
pub struct EdgeProblem<'a> {
    /// The raster, each row padded with zeros to `stride` samples so a patch row can be
    /// read `kp` samples wide.
    raster: Vec<f64>,
    stride: usize,
    nx: usize,
    k: usize,
    /// K rounded up to the SIMD width: kernel rows are stored `kp` wide, zero-padded,
    /// so the inner loops have no remainder.
    kp: usize,
    /// Raster index of each edge observation's patch (its top-left sample), and the
    /// observed value.
    patches: Vec<usize>,
    values: Vec<f64>,
    flat: FlatSums,
    smoothness: f64,
    /// Rows of the gradient penalty √λ·D k in the observation vector (0 without one).
    smooth_rows: usize,
    /// Scratch: the flipped kernel and the correlation accumulator.
    flipped: Vec<f64>,
    acc: Vec<f64>,
    predicted: Vec<f64>,
    _life: std::marker::PhantomData<&'a ()>,
}

/// Which patches of a raster are uniform: counts of exactly-0 and exactly-1 samples in
/// every K × K window, from summed-area tables (exact integer arithmetic).
pub struct Uniformity {
    nx: usize,
    k: usize,
    zeros: Vec<u32>,
    ones: Vec<u32>,
}

impl Uniformity {
    /// Summed-area tables of `raster` (`nx × ny`).
    #[must_use]
    pub fn new(raster: &[f32], nx: usize, ny: usize, k: usize) -> Self {
        let w = nx + 1;
        let mut zeros = vec![0u32; w * (ny + 1)];
        let mut ones = vec![0u32; w * (ny + 1)];
        for y in 0..ny {
            let (mut rz, mut ro) = (0u32, 0u32);
            for x in 0..nx {
                let v = raster[y * nx + x];
                rz += u32::from(v == 0.0);
                ro += u32::from(v == 1.0);
                zeros[(y + 1) * w + x + 1] = zeros[y * w + x + 1] + rz;
                ones[(y + 1) * w + x + 1] = ones[y * w + x + 1] + ro;
            }
        }
        Self { nx, k, zeros, ones }
    }

    fn window(table: &[u32], w: usize, x0: usize, y0: usize, k: usize) -> u32 {
        table[(y0 + k) * w + x0 + k] + table[y0 * w + x0]
            - table[y0 * w + x0 + k]
            - table[(y0 + k) * w + x0]
    }

    /// The uniform value of the patch whose top-left sample is (x0, y0), if it has one.
    #[must_use]
    pub fn value(&self, x0: usize, y0: usize) -> Option<f32> {
        let (w, k) = (self.nx + 1, self.k);
        let full = (k * k) as u32;
        if Self::window(&self.zeros, w, x0, y0, k) == full {
            Some(0.0)
        } else if Self::window(&self.ones, w, x0, y0, k) == full {
            Some(1.0)
        } else {
            None
        }
    }
}

impl<'a> EdgeProblem<'a> {
    /// A problem for a `k × k` kernel over `raster` (`nx` samples per row), with no
    /// observations yet.
    #[must_use]
    pub fn new(raster: &'a [f32], nx: usize, k: usize) -> Self {
        let kp = k.div_ceil(LANES) * LANES;
        let stride = nx + (kp - k);
        let rows = raster.len() / nx.max(1);
        let mut padded = vec![0.0; stride * rows];
        for (dst, src) in padded.chunks_exact_mut(stride).zip(raster.chunks_exact(nx)) {
            for (d, &v) in dst.iter_mut().zip(src) {
                *d = f64::from(v);
            }
        }
        Self {
            raster: padded,
            stride,
            _life: std::marker::PhantomData,
            nx,
            k,
            kp,
            patches: Vec::new(),
            values: Vec::new(),
            flat: FlatSums::default(),
            smoothness: 0.0,
            smooth_rows: 0,
            flipped: vec![0.0; kp * k],
            acc: vec![0.0; kp * k],
            predicted: Vec::new(),
        }
    }

    /// Adds an observation whose patch starts at raster sample (x0, y0); `uniform` is
    /// the patch's value when it is uniform (see [`Uniformity`]).
    ///
    /// # Panics
    /// If the patch leaves the raster.
    pub fn observe(&mut self, x0: usize, y0: usize, value: f64, uniform: Option<f32>) {
        assert!(
            x0 + self.k <= self.nx && (y0 + self.k) * self.stride <= self.raster.len(),
            "patch outside the raster"
        );
        match uniform {
            Some(v) => {
                let g = usize::from(v > 0.5);
                self.flat.n[g] += 1.0;
                self.flat.y[g] += value;
            }
            None => {
                self.patches.push(y0 * self.stride + x0);
                self.values.push(value);
            }
        }
    }

    /// Number of observations (edge and flat).
    #[must_use]
    pub fn observations(&self) -> usize {
        self.patches.len() + (self.flat.n[0] + self.flat.n[1]) as usize
    }

    /// Adds λ·‖∇k‖² with λ = `relative` × the typical diagonal of AᵀA.
    pub fn set_smoothness(&mut self, relative: f64) {
        let diag: f64 = self
            .patches
            .iter()
            .map(|&p| {
                (0..self.k)
                    .map(|r| {
                        let row = &self.raster[p + r * self.stride..p + r * self.stride + self.k];
                        row.iter().map(|&v| v * v).sum::<f64>()
                    })
                    .sum::<f64>()
            })
            .sum::<f64>()
            + self.flat.n[1] * (self.k * self.k) as f64;
        self.smoothness = relative.max(0.0) * diag / (self.k * self.k) as f64;
        self.smooth_rows = if self.smoothness > 0.0 {
            2 * self.k * (self.k - 1)
        } else {
            0
        };
    }

    /// `predicted[o]` = the kernel part of the model at every edge observation, for the
    /// kernel in `self.flipped`.
    fn predict_edges(&mut self) {
        self.predicted.resize(self.patches.len(), 0.0);
        let rows = Rows {
            raster: &self.raster,
            stride: self.stride,
            k: self.k,
            kp: self.kp,
        };
        rows.predict(&self.patches, &self.flipped, &mut self.predicted);
    }

    /// `acc` = Σ_o w_o · patch_o (the flipped correlation), for weights `w`.
    fn correlate(&mut self, weights: &[f64]) {
        self.acc.iter_mut().for_each(|v| *v = 0.0);
        let rows = Rows {
            raster: &self.raster,
            stride: self.stride,
            k: self.k,
            kp: self.kp,
        };
        rows.correlate(&self.patches, weights, &mut self.acc);
    }

    /// Writes `acc` (flipped) into a kernel-shaped output, adding `also` to every entry.
    fn unflip_into(&self, out: &mut [f64], also: f64) {
        // Out of the f64 accumulator `acc`.
        let (k, kp) = (self.k, self.kp);
        for j in 0..k {
            for i in 0..k {
                out[(k - 1 - j) * k + (k - 1 - i)] = self.acc[j * kp + i] + also;
            }
        }
    }
}

impl LinearOperator for EdgeProblem<'_> {
    fn dim(&self) -> usize {
        self.k * self.k + 1
    }

    fn rows(&self) -> usize {
        self.patches.len() + 2 + self.smooth_rows
    }

    /// Edge observations, the two flat rows, then the penalty rows.
    fn forward(&mut self, x: &[f64], out: &mut [f64]) {
        let (k, kp) = (self.k, self.kp);
        let n = k * k;
        let (kernel, offset) = x.split_at(n);
        let c = offset[0];
        for j in 0..k {
            for i in 0..k {
                self.flipped[j * kp + i] = kernel[(k - 1 - j) * k + (k - 1 - i)];
            }
        }
        self.predict_edges();
        let e = self.patches.len();
        for (o, p) in out[..e].iter_mut().zip(&self.predicted) {
            *o = p + c;
        }
        let sum_k: f64 = kernel.iter().sum();
        out[e] = self.flat.weight(0) * c;
        out[e + 1] = self.flat.weight(1) * (sum_k + c);
        if self.smooth_rows > 0 {
            gradient_rows(kernel, k, self.smoothness.sqrt(), &mut out[e + 2..]);
        }
    }

    fn adjoint(&mut self, r: &[f64], out: &mut [f64]) {
        let n = self.k * self.k;
        let e = self.patches.len();
        self.correlate(&r[..e]);
        let (w0, w1) = (self.flat.weight(0) * r[e], self.flat.weight(1) * r[e + 1]);
        self.unflip_into(out, w1);
        out[n] = r[..e].iter().sum::<f64>() + w0 + w1;
        if self.smooth_rows > 0 {
            gradient_rows_adjoint(&r[e + 2..], self.k, self.smoothness.sqrt(), &mut out[..n]);
        }
    }

    fn target(&self) -> Vec<f64> {
        let mut b = self.values.clone();
        b.push(self.flat.target(0));
        b.push(self.flat.target(1));
        b.resize(self.rows(), 0.0);
        b
    }
}

/// √λ times the forward differences of the kernel, along x then along y.
fn gradient_rows(kernel: &[f64], k: usize, scale: f64, out: &mut [f64]) {
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
fn gradient_rows_adjoint(r: &[f64], k: usize, scale: f64, out: &mut [f64]) {
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

/// Accumulators per dot product: two AVX registers of four, enough independent chains
/// to keep the FMA units busy.
const LANES: usize = 8;

/// The raster rows the kernel patches read, and the two products of the operator.
struct Rows<'r> {
    raster: &'r [f64],
    stride: usize,
    k: usize,
    kp: usize,
}

impl Rows<'_> {
    fn predict(&self, patches: &[usize], flipped: &[f64], out: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            unsafe { self.predict_avx2(patches, flipped, out) };
            return;
        }
        self.predict_body(patches, flipped, out);
    }

    fn correlate(&self, patches: &[usize], weights: &[f64], acc: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            unsafe { self.correlate_avx2(patches, weights, acc) };
            return;
        }
        self.correlate_body(patches, weights, acc);
    }

    /// The AVX2 form of [`Rows::predict_body`], in explicit 256-bit registers: the
    /// compiler does not vectorise the lane loop of the portable form by itself.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn predict_avx2(&self, patches: &[usize], flipped: &[f64], out: &mut [f64]) {
        use std::arch::x86_64::{
            _mm256_add_pd, _mm256_fmadd_pd, _mm256_loadu_pd, _mm256_setzero_pd, _mm256_storeu_pd,
        };
        let (k, kp, stride) = (self.k, self.kp, self.stride);
        assert!(flipped.len() >= k * kp && kp % LANES == 0, "kernel layout");
        for (o, &p) in out.iter_mut().zip(patches) {
            assert!(
                p + (k - 1) * stride + kp <= self.raster.len(),
                "patch outside the raster"
            );
            let (mut a0, mut a1) = (_mm256_setzero_pd(), _mm256_setzero_pd());
            for r in 0..k {
                let row = self.raster[p + r * stride..].as_ptr();
                let kr = flipped[r * kp..].as_ptr();
                for c in (0..kp).step_by(LANES) {
                    // SAFETY: c + 8 ≤ kp, and both the patch row (asserted above) and
                    // the kernel row (`flipped` holds k rows of kp) have kp samples.
                    unsafe {
                        a0 = _mm256_fmadd_pd(
                            _mm256_loadu_pd(row.add(c)),
                            _mm256_loadu_pd(kr.add(c)),
                            a0,
                        );
                        a1 = _mm256_fmadd_pd(
                            _mm256_loadu_pd(row.add(c + 4)),
                            _mm256_loadu_pd(kr.add(c + 4)),
                            a1,
                        );
                    }
                }
            }
            let mut lanes = [0.0f64; 4];
            // SAFETY: `lanes` holds four doubles.
            unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), _mm256_add_pd(a0, a1)) };
            *o = lanes.iter().sum();
        }
    }

    /// The AVX2 form of [`Rows::correlate_body`].
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn correlate_avx2(&self, patches: &[usize], weights: &[f64], acc: &mut [f64]) {
        use std::arch::x86_64::{
            _mm256_fmadd_pd, _mm256_loadu_pd, _mm256_set1_pd, _mm256_storeu_pd,
        };
        let (k, kp, stride) = (self.k, self.kp, self.stride);
        assert!(acc.len() >= k * kp && kp % 4 == 0, "accumulator layout");
        for (&p, &w) in patches.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            assert!(
                p + (k - 1) * stride + kp <= self.raster.len(),
                "patch outside the raster"
            );
            let wv = _mm256_set1_pd(w);
            for r in 0..k {
                let row = self.raster[p + r * stride..].as_ptr();
                let dst = acc[r * kp..].as_mut_ptr();
                for c in (0..kp).step_by(4) {
                    // SAFETY: c + 4 ≤ kp; the patch row and the accumulator row have kp
                    // samples (asserted above).
                    unsafe {
                        let v = _mm256_fmadd_pd(
                            _mm256_loadu_pd(row.add(c)),
                            wv,
                            _mm256_loadu_pd(dst.add(c)),
                        );
                        _mm256_storeu_pd(dst.add(c), v);
                    }
                }
            }
        }
    }

    /// Σ over the patch of raster × flipped kernel, for every patch (portable form).
    fn predict_body(&self, patches: &[usize], flipped: &[f64], out: &mut [f64]) {
        let (k, kp, stride) = (self.k, self.kp, self.stride);
        for (o, &p) in out.iter_mut().zip(patches) {
            let mut lanes = [0.0f64; LANES];
            for r in 0..k {
                let row = &self.raster[p + r * stride..p + r * stride + kp];
                let kr = &flipped[r * kp..(r + 1) * kp];
                for (x, y) in row.chunks_exact(LANES).zip(kr.chunks_exact(LANES)) {
                    for l in 0..LANES {
                        lanes[l] += x[l] * y[l];
                    }
                }
            }
            *o = lanes.iter().sum();
        }
    }

    /// acc += w_o · patch_o for every patch (portable form).
    fn correlate_body(&self, patches: &[usize], weights: &[f64], acc: &mut [f64]) {
        let (k, kp, stride) = (self.k, self.kp, self.stride);
        for (&p, &w) in patches.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            for r in 0..k {
                let row = &self.raster[p + r * stride..p + r * stride + kp];
                for (a, &x) in acc[r * kp..(r + 1) * kp].iter_mut().zip(row) {
                    *a += w * x;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::solve::{LeastSquares, NormalEquations, cg_solve, cgls_solve};
    use rand::{Rng, SeedableRng};

    /// A raster with uniform regions and edges, and observations on a lattice of step 3:
    /// the edge form must equal the FFT form (which is tested against a dense solve).
    #[test]
    fn edge_operator_equals_the_fft_operator() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let (nx, ny, k) = (40, 34, 5);
        let raster: Vec<f32> = (0..nx * ny)
            .map(|i| {
                let (x, y) = (i % nx, i / nx);
                if x < 15 && y < 20 {
                    0.0
                } else if x > 28 {
                    1.0
                } else {
                    rng.random::<f32>()
                }
            })
            .collect();
        let uniform = Uniformity::new(&raster, nx, ny, k);
        let mut fft = LeastSquares::new(&raster, nx, ny, k);
        let mut edges = EdgeProblem::new(&raster, nx, k);
        let mut flat = 0;
        for y0 in (0..=ny - k).step_by(3) {
            for x0 in (0..=nx - k).step_by(3) {
                let v = rng.random::<f64>();
                // Output index of the patch starting at (x0, y0) is (x0, y0) + K − 1.
                fft.observe(x0 + k - 1, y0 + k - 1, v);
                let u = uniform.value(x0, y0);
                flat += usize::from(u.is_some());
                edges.observe(x0, y0, v, u);
            }
        }
        assert!(flat > 5, "the test needs flat patches ({flat})");
        let probe: Vec<f64> = (0..k * k + 1).map(|_| rng.random::<f64>() - 0.5).collect();
        // AᵀA p by the edge form is adjoint(forward(p)).
        let (mut a, mut b) = (vec![0.0; k * k + 1], vec![0.0; k * k + 1]);
        fft.apply(&probe, &mut a);
        let mut y = vec![0.0; edges.rows()];
        edges.forward(&probe, &mut y);
        edges.adjoint(&y, &mut b);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-4 * (1.0 + x.abs()), "{x} vs {y}");
        }
        let ra = fft.rhs();
        let mut rb = vec![0.0; k * k + 1];
        edges.adjoint(&edges.target(), &mut rb);
        for (x, y) in ra.iter().zip(&rb) {
            assert!((x - y).abs() < 1e-4 * (1.0 + x.abs()), "{x} vs {y}");
        }
        let (sa, sb) = (
            cg_solve(&mut fft, 100, 1e-10),
            cgls_solve(&mut edges, 100, 1e-10),
        );
        for (x, y) in sa.x.iter().zip(&sb.x) {
            assert!((x - y).abs() < 1e-3 * (1.0 + x.abs()), "{x} vs {y}");
        }
    }
}
