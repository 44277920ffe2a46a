//! Non-blind deconvolution of one periodic block with one 1× kernel: half-quadratic
//! splitting with a hyper-Laplacian prior (Krishnan & Fergus 2009), IRLS on the same
//! sparse prior (Levin et al. 2007), and a regularised Wiener filter.
//!
//! All three minimise (or, for Wiener, the quadratic cousin of)
//! λ/2 ‖k ∗ x − y‖² + Σ |∇x|^α with circular boundaries; the tiler makes blocks periodic
//! (reflection padding plus an edge taper) before they get here.

use crate::fft::{Fft2, Precision};
use crate::psf::Kernel;
use crate::timings::{Clock, Stage};
use rustfft::num_complex::Complex;
use rustfft::num_traits::{Float, NumAssign};
use serde::{Deserialize, Serialize};

/// Half-quadratic splitting parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HqsParams {
    /// Data weight λ for images in [0, 1].
    pub lambda: f64,
    /// Exponent of the gradient prior (2/3 or 0.8 in the papers).
    pub alpha: f64,
    pub beta_start: f64,
    pub beta_max: f64,
    /// β grows by this factor per outer step (2√2 in Krishnan & Fergus).
    pub beta_rate: f64,
}

impl Default for HqsParams {
    fn default() -> Self {
        Self {
            lambda: 3000.0,
            alpha: 2.0 / 3.0,
            beta_start: 1.0,
            beta_max: 256.0,
            beta_rate: 2.0 * std::f64::consts::SQRT_2,
        }
    }
}

/// Iteratively reweighted least squares parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct IrlsParams {
    pub lambda: f64,
    pub alpha: f64,
    pub outer: usize,
    pub cg_iterations: usize,
    /// Gradients below this magnitude get the weight of this magnitude, which keeps the
    /// reweighted system bounded.
    pub epsilon: f64,
}

impl Default for IrlsParams {
    fn default() -> Self {
        Self {
            lambda: 3000.0,
            alpha: 0.8,
            outer: 4,
            cg_iterations: 25,
            epsilon: 0.01,
        }
    }
}

/// Regularised Wiener filter: X = K̄Y / (|K|² + nsr·|D|²) with D the gradient.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WienerParams {
    pub nsr: f64,
}

impl Default for WienerParams {
    fn default() -> Self {
        Self {
            nsr: crate::model::WIENER_NSR,
        }
    }
}

/// The deconvolution method and its parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    Hqs(HqsParams),
    Irls(IrlsParams),
    Wiener(WienerParams),
}

impl Default for Method {
    fn default() -> Self {
        Self::Hqs(HqsParams::default())
    }
}

impl Method {
    /// The method named `hqs`, `irls` or `wiener`, with default parameters.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "hqs" => Some(Self::Hqs(HqsParams::default())),
            "irls" => Some(Self::Irls(IrlsParams::default())),
            "wiener" => Some(Self::Wiener(WienerParams::default())),
            _ => None,
        }
    }

    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::Hqs(_) => "hqs",
            Self::Irls(_) => "irls",
            Self::Wiener(_) => "wiener",
        }
    }
}

/// The precisions the deconvolver runs in: `f32` for the tiler's HQS and Wiener (the
/// GPU's precision, which agrees with double to SSIM 1.0000), `f64` for IRLS's
/// conjugate gradients and for the reference solves.
pub trait Real:
    Precision + Float + NumAssign + std::iter::Sum + Send + Sync + Default + 'static
{
    /// `v` rounded to this precision.
    fn of(v: f64) -> Self;
    fn of_f32(v: f32) -> Self;
    fn of_i64(v: i64) -> Self;
    fn as_f32(self) -> f32;
    fn as_f64(self) -> f64;
    /// Truncated toward zero (one instruction, unlike `usize`'s conversion).
    fn trunc_i64(self) -> i64;
    /// The shrinkage table's nodes in this precision.
    #[doc(hidden)]
    fn nodes(lut: &ShrinkLut) -> &[[Self; 2]];
    /// The slice as single precision, when this is single precision: the shrinkage's
    /// vector form is written for it.
    #[doc(hidden)]
    fn as_f32_slice(v: &[Self]) -> Option<&[f32]>;
    #[doc(hidden)]
    fn as_f32_slice_mut(v: &mut [Self]) -> Option<&mut [f32]>;
}

impl Real for f32 {
    fn of(v: f64) -> Self {
        v as f32
    }
    fn of_f32(v: f32) -> Self {
        v
    }
    fn of_i64(v: i64) -> Self {
        v as f32
    }
    fn as_f32(self) -> f32 {
        self
    }
    fn as_f64(self) -> f64 {
        f64::from(self)
    }
    fn trunc_i64(self) -> i64 {
        self as i64
    }
    fn nodes(lut: &ShrinkLut) -> &[[Self; 2]] {
        &lut.nodes32
    }
    fn as_f32_slice(v: &[Self]) -> Option<&[f32]> {
        Some(v)
    }
    fn as_f32_slice_mut(v: &mut [Self]) -> Option<&mut [f32]> {
        Some(v)
    }
}

impl Real for f64 {
    fn of(v: f64) -> Self {
        v
    }
    fn of_f32(v: f32) -> Self {
        f64::from(v)
    }
    fn of_i64(v: i64) -> Self {
        v as f64
    }
    fn as_f32(self) -> f32 {
        self as f32
    }
    fn as_f64(self) -> f64 {
        self
    }
    fn trunc_i64(self) -> i64 {
        self as i64
    }
    fn nodes(lut: &ShrinkLut) -> &[[Self; 2]] {
        &lut.nodes
    }
    fn as_f32_slice(_: &[Self]) -> Option<&[f32]> {
        None
    }
    fn as_f32_slice_mut(_: &mut [Self]) -> Option<&mut [f32]> {
        None
    }
}

/// Deconvolves periodic blocks of one size: FFT plans, the gradient spectrum and every
/// buffer a solve needs, allocated once and reused block after block. One per worker
/// thread.
#[derive(Clone, Debug)]
pub struct Deconvolver<T: Real = f64> {
    fft: Fft2<T>,
    /// |D_x|² + |D_y|² per half-spectrum entry: the same for every block of this size.
    grad_energy: Vec<T>,
    otf: Vec<Complex<T>>,
    spec: Vec<Complex<T>>,
    num: Vec<Complex<T>>,
    den: Vec<T>,
    real_a: Vec<T>,
    real_b: Vec<T>,
    real_c: Vec<T>,
    row_a: Vec<T>,
    row_b: Vec<T>,
    row_c: Vec<T>,
    row_d: Vec<T>,
    /// This worker's stage times (off unless the deblur is timed).
    pub clock: Clock,
}

/// Runs `f` with `clock` on `stage`.
fn timed<R>(clock: &mut Clock, stage: Stage, f: impl FnOnce() -> R) -> R {
    let started = clock.start();
    let r = f();
    clock.stop(stage, started);
    r
}

impl<T: Real> Deconvolver<T> {
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        let fft = Fft2::new(width, height);
        let n = width * height;
        let zero = T::zero();
        Self {
            grad_energy: fft.gradient_energy(),
            otf: fft.new_spectrum(),
            spec: fft.new_spectrum(),
            num: fft.new_spectrum(),
            den: vec![zero; fft.spectrum_len()],
            real_a: vec![zero; n],
            real_b: vec![zero; n],
            real_c: vec![zero; n],
            row_a: vec![zero; width],
            row_b: vec![zero; width],
            row_c: vec![zero; width],
            row_d: vec![zero; width],
            clock: Clock::default(),
            fft,
        }
    }

    #[must_use]
    pub fn width(&self) -> usize {
        self.fft.width()
    }

    #[must_use]
    pub fn height(&self) -> usize {
        self.fft.height()
    }

    fn set_kernel(&mut self, k: &Kernel) {
        let k1;
        let k = if k.oversample == 1 {
            k
        } else {
            k1 = k.resampled(1);
            &k1
        };
        let (fft, real_a, otf) = (&mut self.fft, &mut self.real_a, &mut self.otf);
        timed(&mut self.clock, Stage::Spectra, || {
            fft.otf_into(k, real_a, otf)
        });
    }

    /// Deconvolves the periodic block `y` (row-major, `width × height`) with the kernel
    /// `k` (resampled to 1× if need be) into `x`.
    ///
    /// # Panics
    /// On wrongly sized buffers, or a kernel larger than the block.
    pub fn deconvolve(&mut self, y: &[T], k: &Kernel, method: &Method, x: &mut [T]) {
        self.set_kernel(k);
        self.solve(y, method, x);
    }

    /// Deconvolves a block cut from a larger image: its outer `taper_px` pixels are
    /// first blended toward the block blurred by `k` (circularly), which makes the
    /// block consistent with a periodic blur so the solver does not ring at its edges.
    /// `block` is modified in place.
    ///
    /// # Panics
    /// As [`Self::deconvolve`].
    pub fn deconvolve_tapered(
        &mut self,
        block: &mut [T],
        k: &Kernel,
        taper_px: usize,
        method: &Method,
        x: &mut [T],
    ) {
        self.set_kernel(k);
        let (w, h) = (self.width(), self.height());
        let taper = taper_px.min(w / 2).min(h / 2);
        if taper > 0 {
            let (fft, spec) = (&mut self.fft, &mut self.spec);
            timed(&mut self.clock, Stage::ForwardFft, || {
                fft.forward(block, spec)
            });
            let started = self.clock.start();
            for (s, o) in self.spec.iter_mut().zip(&self.otf) {
                *s *= o;
            }
            self.clock.stop(Stage::Taper, started);
            let (fft, spec, real_b) = (&mut self.fft, &mut self.spec, &mut self.real_b);
            timed(&mut self.clock, Stage::InverseFft, || {
                fft.inverse(spec, real_b)
            });
            let started = self.clock.start();
            let ramp = |t: usize, n: usize| -> T {
                let d = t.min(n - 1 - t);
                if d >= taper {
                    T::one()
                } else {
                    T::of(
                        (std::f64::consts::FRAC_PI_2 * (d as f64 + 0.5) / taper as f64)
                            .sin()
                            .powi(2),
                    )
                }
            };
            // The ramp along a row, once per block rather than once per pixel.
            let row_ramp = &mut self.row_a;
            for (i, r) in row_ramp.iter_mut().enumerate() {
                *r = ramp(i, w);
            }
            for j in 0..h {
                let ry = ramp(j, h);
                let row = j * w..(j + 1) * w;
                for ((b, &blurred), &rx) in block[row.clone()]
                    .iter_mut()
                    .zip(&self.real_b[row])
                    .zip(row_ramp.iter())
                {
                    let a = ry * rx;
                    *b = a * *b + (T::one() - a) * blurred;
                }
            }
            self.clock.stop(Stage::Taper, started);
        }
        self.solve(block, method, x);
    }

    fn solve(&mut self, y: &[T], method: &Method, x: &mut [T]) {
        let n = self.width() * self.height();
        assert!(y.len() == n && x.len() == n, "block sizes");
        match method {
            Method::Wiener(p) => self.wiener(y, T::of(p.nsr), x),
            Method::Hqs(p) => self.hqs(y, p, x),
            Method::Irls(p) => self.irls(y, p, x),
        }
    }

    /// The forward transform of `y` into `spec`, timed.
    fn forward(&mut self, y: &[T]) {
        let (fft, spec) = (&mut self.fft, &mut self.spec);
        timed(&mut self.clock, Stage::ForwardFft, || fft.forward(y, spec));
    }

    /// The inverse transform of `spec` into `x`, timed.
    fn inverse(&mut self, x: &mut [T]) {
        let (fft, spec) = (&mut self.fft, &mut self.spec);
        timed(&mut self.clock, Stage::InverseFft, || fft.inverse(spec, x));
    }

    fn wiener(&mut self, y: &[T], nsr: T, x: &mut [T]) {
        self.forward(y);
        let started = self.clock.start();
        for ((s, o), &g) in self.spec.iter_mut().zip(&self.otf).zip(&self.grad_energy) {
            *s = o.conj() * *s / (o.norm_sqr() + nsr * g);
        }
        self.clock.stop(Stage::Solve, started);
        self.inverse(x);
    }

    /// Krishnan & Fergus: alternate the per-pixel shrinkage of the gradients (w-step)
    /// with the quadratic x-step, solved exactly in the Fourier domain:
    /// X = (λ K̄Y + β Σ D̄ W) / (λ|K|² + β Σ|D|²). Σ D̄ W is the spectrum of the
    /// divergence Σ Dᵀw, formed in space, so each step costs one forward and one
    /// inverse transform.
    fn hqs(&mut self, y: &[T], p: &HqsParams, x: &mut [T]) {
        let (w, h) = (self.width(), self.height());
        self.forward(y);
        let started = self.clock.start();
        let lambda = T::of(p.lambda);
        for ((num, s), o) in self.num.iter_mut().zip(&self.spec).zip(&self.otf) {
            *num = o.conj() * s * lambda;
        }
        for (d, o) in self.den.iter_mut().zip(&self.otf) {
            *d = lambda * o.norm_sqr();
        }
        x.copy_from_slice(y);
        self.clock.stop(Stage::Solve, started);
        let mut beta = p.beta_start;
        while beta <= p.beta_max * (1.0 + 1e-9) {
            let started = self.clock.start();
            let lut = shared_lut(beta, p.alpha);
            let lut = Lookup::<T>::new(&lut);
            // w-step and divergence Dxᵀwx + Dyᵀwy in one pass over the rows, with
            // (Dᵀg)(i) = g(i − 1) − g(i): a row's divergence needs its own shrunk
            // gradients and the previous row's wy, which wraps to the last row's.
            // Each row's differences are formed first and shrunk as one slice, which
            // the table's vector form reads eight at a time.
            let (wx, wy, wy_prev, diff) = (
                &mut self.row_a,
                &mut self.row_b,
                &mut self.row_c,
                &mut self.row_d,
            );
            {
                let (last, first) = (&x[(h - 1) * w..], &x[..w]);
                for ((d, &a), &b) in diff.iter_mut().zip(last).zip(first) {
                    *d = b - a;
                }
                lut.eval_row(diff, wy_prev);
            }
            for r in 0..h {
                let rn = if r + 1 == h { 0 } else { r + 1 };
                let row = &x[r * w..(r + 1) * w];
                let next = &x[rn * w..(rn + 1) * w];
                for (d, p) in diff.iter_mut().zip(row.windows(2)) {
                    *d = p[1] - p[0];
                }
                diff[w - 1] = row[0] - row[w - 1];
                lut.eval_row(diff, wx);
                for ((d, &a), &b) in diff.iter_mut().zip(row).zip(next) {
                    *d = b - a;
                }
                lut.eval_row(diff, wy);
                let div = &mut self.real_c[r * w..(r + 1) * w];
                div[0] = wx[w - 1] - wx[0] + wy_prev[0] - wy[0];
                for c in 1..w {
                    div[c] = wx[c - 1] - wx[c] + wy_prev[c] - wy[c];
                }
                std::mem::swap(wy, wy_prev);
            }
            self.clock.stop(Stage::Solve, started);
            let (fft, real_c, spec) = (&mut self.fft, &self.real_c, &mut self.spec);
            timed(&mut self.clock, Stage::ForwardFft, || {
                fft.forward(real_c, spec)
            });
            let started = self.clock.start();
            let b = T::of(beta);
            for (((s, &num), &den), &g) in self
                .spec
                .iter_mut()
                .zip(&self.num)
                .zip(&self.den)
                .zip(&self.grad_energy)
            {
                *s = (num + *s * b) * (T::one() / (den + b * g));
            }
            self.clock.stop(Stage::Solve, started);
            self.inverse(x);
            beta *= p.beta_rate;
        }
    }

    /// Applies KᵀK + μ Σ Dᵀ W D to `v` (into `out`), W the IRLS weights.
    fn irls_apply(&mut self, v: &[T], wx: &[T], wy: &[T], mu: T, out: &mut [T]) {
        let (w, h) = (self.width(), self.height());
        self.fft.forward(v, &mut self.spec);
        for (s, o) in self.spec.iter_mut().zip(&self.otf) {
            *s *= o.norm_sqr();
        }
        self.fft.inverse(&mut self.spec, out);
        // Weighted gradients in real_a (x) and real_b (y), then their divergence.
        for r in 0..h {
            let rn = if r + 1 == h { 0 } else { r + 1 };
            for c in 0..w {
                let cn = if c + 1 == w { 0 } else { c + 1 };
                let i = r * w + c;
                self.real_a[i] = wx[i] * (v[r * w + cn] - v[i]);
                self.real_b[i] = wy[i] * (v[rn * w + c] - v[i]);
            }
        }
        for r in 0..h {
            let rp = if r == 0 { h - 1 } else { r - 1 };
            for c in 0..w {
                let cp = if c == 0 { w - 1 } else { c - 1 };
                let i = r * w + c;
                let div = self.real_a[r * w + cp] - self.real_a[i] + self.real_b[rp * w + c]
                    - self.real_b[i];
                out[i] += mu * div;
            }
        }
    }

    /// Levin et al.: minimise λ/2‖k ∗ x − y‖² + Σ|∇x|^α by reweighted least squares,
    /// each reweighted system (KᵀK + (α/λ) Σ Dᵀ W D) x = Kᵀy solved by conjugate
    /// gradients from the previous estimate.
    fn irls(&mut self, y: &[T], p: &IrlsParams, x: &mut [T]) {
        let (w, h) = (self.width(), self.height());
        let n = w * h;
        // Kᵀy.
        self.forward(y);
        for (s, o) in self.spec.iter_mut().zip(&self.otf) {
            *s *= o.conj();
        }
        let zero = T::zero();
        let mut rhs = vec![zero; n];
        self.inverse(&mut rhs);
        // A mildly regularised Wiener estimate starts the iterations near the answer.
        self.wiener(y, T::of(0.01), x);
        // The conjugate gradients, their transforms included, are the solver's passes.
        let started = self.clock.start();
        let mu = T::of(p.alpha / p.lambda);
        let (eps, power) = (T::of(p.epsilon), T::of(p.alpha - 2.0));
        let (mut wx, mut wy) = (vec![zero; n], vec![zero; n]);
        let (mut r, mut d, mut ad) = (vec![zero; n], vec![zero; n], vec![zero; n]);
        for _ in 0..p.outer {
            let weight = |g: T| g.abs().max(eps).powf(power);
            for row in 0..h {
                let rn = if row + 1 == h { 0 } else { row + 1 };
                for c in 0..w {
                    let cn = if c + 1 == w { 0 } else { c + 1 };
                    let i = row * w + c;
                    wx[i] = weight(x[row * w + cn] - x[i]);
                    wy[i] = weight(x[rn * w + c] - x[i]);
                }
            }
            self.irls_apply(x, &wx, &wy, mu, &mut ad);
            for i in 0..n {
                r[i] = rhs[i] - ad[i];
            }
            d.copy_from_slice(&r);
            let mut rr: T = r.iter().map(|&v| v * v).sum();
            for _ in 0..p.cg_iterations {
                if rr < T::of(1e-20) {
                    break;
                }
                self.irls_apply(&d, &wx, &wy, mu, &mut ad);
                let dad: T = d.iter().zip(&ad).map(|(&a, &b)| a * b).sum();
                if dad <= zero {
                    break;
                }
                let step = rr / dad;
                for i in 0..n {
                    x[i] += step * d[i];
                    r[i] -= step * ad[i];
                }
                let rr_new: T = r.iter().map(|&v| v * v).sum();
                let b = rr_new / rr;
                rr = rr_new;
                for i in 0..n {
                    d[i] = r[i] + b * d[i];
                }
            }
        }
        self.clock.stop(Stage::Solve, started);
    }
}

/// Deconvolves one periodic `width × height` block `y` with the kernel `k`: a one-off
/// convenience over [`Deconvolver`].
#[must_use]
pub fn deconvolve_block(
    y: &[f64],
    width: usize,
    height: usize,
    k: &Kernel,
    method: &Method,
) -> Vec<f64> {
    let mut d = Deconvolver::new(width, height);
    let mut x = vec![0.0; width * height];
    d.deconvolve(y, k, method, &mut x);
    x
}

/// argmin_w β/2 (w − v)² + |w|^α for α ∈ (0, 1): the larger stationary point found by
/// Newton from w = |v| (the derivative is convex there, so Newton descends monotonically
/// onto it), kept only when it beats w = 0.
#[must_use]
pub fn shrink_hyper_laplacian(v: f64, beta: f64, alpha: f64) -> f64 {
    let a = v.abs();
    if a == 0.0 {
        return 0.0;
    }
    let mut w = a;
    for _ in 0..30 {
        let f = beta * (w - a) + alpha * w.powf(alpha - 1.0);
        let df = beta + alpha * (alpha - 1.0) * w.powf(alpha - 2.0);
        if df <= 0.0 {
            return 0.0;
        }
        let next = w - f / df;
        if next <= 0.0 {
            return 0.0;
        }
        if (next - w).abs() < 1e-10 * a {
            w = next;
            break;
        }
        w = next;
    }
    let e_w = 0.5 * beta * (w - a).powi(2) + w.powf(alpha);
    let e_0 = 0.5 * beta * a * a;
    if e_w < e_0 { w.copysign(v) } else { 0.0 }
}

/// The shrinkage as a lookup table over v ∈ [−range, range] for one β: the per-pixel
/// solve costs tens of `powf`, the table two loads and a lerp.
/// Tables are shared by every tile: they depend only on (β, α).
fn shared_lut(beta: f64, alpha: f64) -> std::sync::Arc<ShrinkLut> {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex, OnceLock};
    type Cache = Mutex<HashMap<(u64, u64), Arc<ShrinkLut>>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let key = (beta.to_bits(), alpha.to_bits());
    let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
    if let Some(l) = cache.lock().ok().and_then(|m| m.get(&key).cloned()) {
        return l;
    }
    let lut = Arc::new(ShrinkLut::new(beta, alpha));
    if let Ok(mut m) = cache.lock() {
        // A default solve uses six tables; a studio slider sweeping α or β must not
        // grow the cache without bound (each table is 128 kB).
        if m.len() >= 64 {
            m.clear();
        }
        m.insert(key, Arc::clone(&lut));
    }
    lut
}

/// The table the CPU solver interpolates the shrinkage from at (β, α), for the GPU
/// path to interpolate the same one: (range, 1 / node spacing, the values at the nodes
/// from −range to range). Past the range both solve exactly.
pub(crate) fn shrink_table(beta: f64, alpha: f64) -> (f64, f64, Vec<f64>) {
    let lut = shared_lut(beta, alpha);
    let mut values: Vec<f64> = lut.nodes.iter().map(|n| n[0]).collect();
    if let Some(last) = lut.nodes.last() {
        values.push(last[0] + last[1]);
    }
    (lut.range, lut.inv_step, values)
}

/// The shrinkage of one (β, α) at evenly spaced nodes, in both precisions.
#[doc(hidden)]
pub struct ShrinkLut {
    inv_step: f64,
    range: f64,
    /// Interpolation nodes as (value, slope to the next node): one load per lookup.
    nodes: Vec<[f64; 2]>,
    /// The same nodes rounded to single precision.
    nodes32: Vec<[f32; 2]>,
    /// Index of the last node, as a float: the lookup's bound.
    last: f64,
    beta: f64,
    alpha: f64,
}

impl ShrinkLut {
    fn new(beta: f64, alpha: f64) -> Self {
        // Gradients of [0, 1] images stay well inside ±2 even while HQS overshoots;
        // beyond, the exact solve.
        let range = 2.0;
        let n = 8000;
        let step = 2.0 * range / n as f64;
        let values: Vec<f64> = (0..=n)
            .map(|i| shrink_hyper_laplacian(-range + i as f64 * step, beta, alpha))
            .collect();
        let nodes: Vec<[f64; 2]> = values.windows(2).map(|p| [p[0], p[1] - p[0]]).collect();
        let nodes32 = nodes.iter().map(|&[a, b]| [a as f32, b as f32]).collect();
        Self {
            inv_step: 1.0 / step,
            range,
            nodes,
            nodes32,
            last: n as f64,
            beta,
            alpha,
        }
    }
}

/// A [`ShrinkLut`] read in one precision.
struct Lookup<'a, T: Real> {
    inv_step: T,
    range: T,
    last: T,
    nodes: &'a [[T; 2]],
    lut: &'a ShrinkLut,
}

impl<'a, T: Real> Lookup<'a, T> {
    fn new(lut: &'a ShrinkLut) -> Self {
        Self {
            inv_step: T::of(lut.inv_step),
            range: T::of(lut.range),
            last: T::of(lut.last),
            nodes: T::nodes(lut),
            lut,
        }
    }

    #[inline]
    fn eval(&self, v: T) -> T {
        let t = (v + self.range) * self.inv_step;
        // Written so NaN fails the test and takes the exact path (which maps it to 0).
        if t >= T::zero() && t < self.last {
            // Through i64: the conversions to and from it are single instructions on
            // every x86-64, those of usize are not.
            let i = t.trunc_i64();
            let [a, slope] = self.nodes[i as usize];
            a + slope * (t - T::of_i64(i))
        } else {
            self.exact(v)
        }
    }

    fn exact(&self, v: T) -> T {
        T::of(shrink_hyper_laplacian(
            v.as_f64(),
            self.lut.beta,
            self.lut.alpha,
        ))
    }

    /// [`Self::eval`] of every element of `v` into `out`, the same to the bit: eight
    /// lookups at a time where the CPU gathers (AVX2), which is most of an HQS step's
    /// time in scalar form.
    fn eval_row(&self, v: &[T], out: &mut [T]) {
        assert_eq!(v.len(), out.len(), "row lengths");
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2")
            && let (Some(v32), Some(out32)) = (T::as_f32_slice(v), T::as_f32_slice_mut(out))
            && let Some(nodes) = T::as_f32_slice(self.nodes.as_flattened())
        {
            let (range, inv_step, last) = (
                self.range.as_f32(),
                self.inv_step.as_f32(),
                self.last.as_f32(),
            );
            // The table's last node is `last − 1`: every index the vector form forms
            // from a position below `last` is inside it.
            assert!(
                last > 0.0 && nodes.len() >= 2 * last as usize,
                "shrinkage table bounds"
            );
            let whole = v32.len() / 8 * 8;
            // SAFETY: the CPU has AVX2 (checked above); the rows hold `whole` elements
            // and every gathered index lies in `nodes` (asserted above).
            let outside = unsafe {
                shrink_row_avx2(
                    range,
                    inv_step,
                    last,
                    nodes,
                    &v32[..whole],
                    &mut out32[..whole],
                )
            };
            for (o, &x) in out32[whole..].iter_mut().zip(&v32[whole..]) {
                *o = self.eval(T::of_f32(x)).as_f32();
            }
            if outside {
                // Past the table (rare): the exact solve, as the scalar form takes it.
                for (o, &x) in out32[..whole].iter_mut().zip(&v32[..whole]) {
                    let t = (x + range) * inv_step;
                    if !(t >= 0.0 && t < last) {
                        *o = self.exact(T::of_f32(x)).as_f32();
                    }
                }
            }
            return;
        }
        for (o, &x) in out.iter_mut().zip(v) {
            *o = self.eval(x);
        }
    }
}

/// The table's lerp of eight values at a time, rounded as [`Lookup::eval`] rounds
/// (a separate multiply and add, no fused one), so either form gives the same bits.
/// Positions outside the table read node 0 and are reported (`true`) for the caller to
/// redo exactly. `nodes` is the table's (value, slope) pairs, flattened.
///
/// # Safety
/// The CPU has AVX2; `v` and `out` have the same length, a multiple of 8; `nodes`
/// holds at least `2 · last` values (every position in [0, last) reads inside it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn shrink_row_avx2(
    range: f32,
    inv_step: f32,
    last: f32,
    nodes: &[f32],
    v: &[f32],
    out: &mut [f32],
) -> bool {
    use std::arch::x86_64::{
        _CMP_GE_OQ, _CMP_LT_OQ, _mm256_add_ps, _mm256_and_ps, _mm256_cmp_ps, _mm256_cvtepi32_ps,
        _mm256_cvttps_epi32, _mm256_i32gather_ps, _mm256_movemask_ps, _mm256_mul_ps,
        _mm256_set1_ps, _mm256_setzero_ps, _mm256_sub_ps,
    };
    let (range, inv_step, last, zero) = (
        _mm256_set1_ps(range),
        _mm256_set1_ps(inv_step),
        _mm256_set1_ps(last),
        _mm256_setzero_ps(),
    );
    let mut outside = 0;
    for (o, x) in out.chunks_exact_mut(8).zip(v.chunks_exact(8)) {
        let x = load8(x);
        let t = _mm256_mul_ps(_mm256_add_ps(x, range), inv_step);
        // Both comparisons are false for NaN, which then reads node 0 and is redone.
        let inside = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(t, zero),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, last),
        );
        outside |= _mm256_movemask_ps(inside) ^ 0xff;
        let t = _mm256_and_ps(t, inside);
        let i = _mm256_cvttps_epi32(t);
        // SAFETY: 0 ≤ i < last, so 2i + 1 < 2 · last ≤ nodes.len() (the contract).
        let (a, slope) = unsafe {
            (
                _mm256_i32gather_ps::<8>(nodes.as_ptr(), i),
                _mm256_i32gather_ps::<8>(nodes.as_ptr().add(1), i),
            )
        };
        let lerp = _mm256_add_ps(
            a,
            _mm256_mul_ps(slope, _mm256_sub_ps(t, _mm256_cvtepi32_ps(i))),
        );
        store8(o, lerp);
    }
    outside != 0
}

/// Eight floats at any address, read and written as one unaligned move each (see
/// `kernel::edges::segments::Unaligned` for why not `_mm256_loadu_ps`).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
#[repr(C, packed)]
struct Unaligned8(std::arch::x86_64::__m256);

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn load8(x: &[f32]) -> std::arch::x86_64::__m256 {
    assert!(x.len() >= 8, "eight floats");
    // SAFETY: eight floats are readable (asserted); `Unaligned8` has alignment 1.
    unsafe { x.as_ptr().cast::<Unaligned8>().read() }.0
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn store8(out: &mut [f32], v: std::arch::x86_64::__m256) {
    assert!(out.len() >= 8, "eight floats");
    // SAFETY: eight floats are writable (asserted); `Unaligned8` has alignment 1.
    unsafe { out.as_mut_ptr().cast::<Unaligned8>().write(Unaligned8(v)) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shrinkage_minimises_the_scalar_problem() {
        for &(v, beta) in &[
            (0.3, 4.0),
            (-0.05, 16.0),
            (0.8, 1.0),
            (0.01, 256.0),
            (1.2, 64.0),
        ] {
            let w = shrink_hyper_laplacian(v, beta, 2.0 / 3.0);
            let e = |w: f64| 0.5 * beta * (w - v) * (w - v) + w.abs().powf(2.0 / 3.0);
            let mut best = (f64::MAX, 0.0);
            for i in -4000..=4000 {
                let c = f64::from(i) * 1.5 / 4000.0;
                if e(c) < best.0 {
                    best = (e(c), c);
                }
            }
            assert!(
                e(w) <= best.0 + 1e-9,
                "v {v} β {beta}: w {w} E {} vs grid {} at {}",
                e(w),
                best.0,
                best.1
            );
        }
    }

    /// The row form gives the scalar lookup's bits for every value: inside the table,
    /// past either end, at its edges, NaN, and in a row whose length is no multiple of
    /// the vector width (where the CPU gathers, this compares its vector form).
    #[test]
    fn the_shrinkage_of_a_row_is_the_lookup_of_each_value_to_the_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let lut = ShrinkLut::new(22.6, 2.0 / 3.0);
        let (l32, l64) = (Lookup::<f32>::new(&lut), Lookup::<f64>::new(&lut));
        let mut v: Vec<f64> = (0..1003).map(|_| rng.random_range(-0.3..0.3)).collect();
        for (k, edge) in [-2.5, -2.0, -1.9999, 1.9999, 2.0, 3.0, 0.0, f64::NAN]
            .into_iter()
            .enumerate()
        {
            v[100 * k + 13] = edge;
        }
        let v32: Vec<f32> = v.iter().map(|&x| x as f32).collect();
        let mut out32 = vec![0.0f32; v.len()];
        l32.eval_row(&v32, &mut out32);
        let mut out64 = vec![0.0f64; v.len()];
        l64.eval_row(&v, &mut out64);
        for (i, (&x, &o)) in v32.iter().zip(&out32).enumerate() {
            assert_eq!(o.to_bits(), l32.eval(x).to_bits(), "f32 at {i}: {x}");
        }
        for (i, (&x, &o)) in v.iter().zip(&out64).enumerate() {
            assert_eq!(o.to_bits(), l64.eval(x).to_bits(), "f64 at {i}: {x}");
        }
        // The values past the table took the exact solve, not node 0 (about −1.98).
        assert!(
            out32[13] < -2.4 && out32[513] > 2.9,
            "{} {}",
            out32[13],
            out32[513]
        );
    }
}
