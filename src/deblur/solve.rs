//! Non-blind deconvolution of one periodic block with one 1× kernel: half-quadratic
//! splitting with a hyper-Laplacian prior (Krishnan & Fergus 2009), IRLS on the same
//! sparse prior (Levin et al. 2007), and a regularised Wiener filter.
//!
//! All three minimise (or, for Wiener, the quadratic cousin of)
//! λ/2 ‖k ∗ x − y‖² + Σ |∇x|^α with circular boundaries; the tiler makes blocks periodic
//! (reflection padding plus an edge taper) before they get here.

use super::fft::Fft2;
use crate::psf::Kernel;
use rustfft::num_complex::Complex64;
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
        Self { nsr: 0.003 }
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

/// Deconvolves one periodic `fft.width × fft.height` block `y` with the 1× kernel `k`.
#[must_use]
pub fn deconvolve_block(fft: &Fft2, y: &[f64], k: &Kernel, method: &Method) -> Vec<f64> {
    let k1;
    let k = if k.oversample == 1 {
        k
    } else {
        k1 = k.resampled(1);
        &k1
    };
    match method {
        Method::Wiener(p) => wiener(fft, y, k, p.nsr),
        Method::Hqs(p) => hqs(fft, y, k, p),
        Method::Irls(p) => irls(fft, y, k, p),
    }
}

fn wiener(fft: &Fft2, y: &[f64], k: &Kernel, nsr: f64) -> Vec<f64> {
    let otf = fft.otf(k);
    let (dx, dy) = fft.gradient_otfs();
    let mut s = fft.forward_real(y);
    for i in 0..s.len() {
        let d2 = dx[i].norm_sqr() + dy[i].norm_sqr();
        s[i] = otf[i].conj() * s[i] / (otf[i].norm_sqr() + nsr * d2);
    }
    fft.inverse_real(s)
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
    static CACHE: OnceLock<Mutex<HashMap<(u64, u64), Arc<ShrinkLut>>>> = OnceLock::new();
    let key = (beta.to_bits(), alpha.to_bits());
    let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
    if let Some(l) = cache.lock().ok().and_then(|m| m.get(&key).cloned()) {
        return l;
    }
    let lut = Arc::new(ShrinkLut::new(beta, alpha));
    if let Ok(mut m) = cache.lock() {
        m.insert(key, Arc::clone(&lut));
    }
    lut
}

struct ShrinkLut {
    step: f64,
    range: f64,
    table: Vec<f64>,
    beta: f64,
    alpha: f64,
}

impl ShrinkLut {
    fn new(beta: f64, alpha: f64) -> Self {
        let range = 1.5;
        let n = 6000;
        let step = 2.0 * range / n as f64;
        let table = (0..=n)
            .map(|i| shrink_hyper_laplacian(-range + i as f64 * step, beta, alpha))
            .collect();
        Self {
            step,
            range,
            table,
            beta,
            alpha,
        }
    }

    fn eval(&self, v: f64) -> f64 {
        if v.abs() >= self.range {
            return shrink_hyper_laplacian(v, self.beta, self.alpha);
        }
        let t = (v + self.range) / self.step;
        let i = (t as usize).min(self.table.len() - 2);
        let f = t - i as f64;
        self.table[i] * (1.0 - f) + self.table[i + 1] * f
    }
}

fn grad_x(x: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut g = vec![0.0; w * h];
    for r in 0..h {
        let row = &x[r * w..(r + 1) * w];
        for c in 0..w {
            g[r * w + c] = row[(c + 1) % w] - row[c];
        }
    }
    g
}

fn grad_y(x: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut g = vec![0.0; w * h];
    for r in 0..h {
        let rn = (r + 1) % h;
        for c in 0..w {
            g[r * w + c] = x[rn * w + c] - x[r * w + c];
        }
    }
    g
}

/// Adjoint of `grad_x`: (Dᵀg)(c) = g(c−1) − g(c).
fn grad_x_t(g: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut o = vec![0.0; w * h];
    for r in 0..h {
        for c in 0..w {
            o[r * w + c] = g[r * w + (c + w - 1) % w] - g[r * w + c];
        }
    }
    o
}

fn grad_y_t(g: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut o = vec![0.0; w * h];
    for r in 0..h {
        let rp = (r + h - 1) % h;
        for c in 0..w {
            o[r * w + c] = g[rp * w + c] - g[r * w + c];
        }
    }
    o
}

fn hqs(fft: &Fft2, y: &[f64], k: &Kernel, p: &HqsParams) -> Vec<f64> {
    let (w, h) = (fft.width, fft.height);
    let otf = fft.otf(k);
    let (dx, dy) = fft.gradient_otfs();
    let ys = fft.forward_real(y);
    // λ K̄Y and λ|K|² are fixed across β.
    let num_data: Vec<Complex64> = otf
        .iter()
        .zip(&ys)
        .map(|(kk, yy)| kk.conj() * yy * p.lambda)
        .collect();
    let den_data: Vec<f64> = otf.iter().map(|kk| p.lambda * kk.norm_sqr()).collect();
    let den_grad: Vec<f64> = dx
        .iter()
        .zip(&dy)
        .map(|(a, b)| a.norm_sqr() + b.norm_sqr())
        .collect();
    let mut x = y.to_vec();
    let mut beta = p.beta_start;
    while beta <= p.beta_max * (1.0 + 1e-9) {
        let lut = shared_lut(beta, p.alpha);
        let wx: Vec<f64> = grad_x(&x, w, h).into_iter().map(|v| lut.eval(v)).collect();
        let wy: Vec<f64> = grad_y(&x, w, h).into_iter().map(|v| lut.eval(v)).collect();
        let sx = fft.forward_real(&wx);
        let sy = fft.forward_real(&wy);
        let mut s = vec![Complex64::new(0.0, 0.0); w * h];
        for i in 0..s.len() {
            let num = num_data[i] + beta * (dx[i].conj() * sx[i] + dy[i].conj() * sy[i]);
            s[i] = num / (den_data[i] + beta * den_grad[i]);
        }
        x = fft.inverse_real(s);
        beta *= p.beta_rate;
    }
    x
}

fn irls(fft: &Fft2, y: &[f64], k: &Kernel, p: &IrlsParams) -> Vec<f64> {
    let (w, h) = (fft.width, fft.height);
    let otf = fft.otf(k);
    let k2: Vec<f64> = otf.iter().map(Complex64::norm_sqr).collect();
    let apply_ktk = |x: &[f64]| -> Vec<f64> {
        let mut s = fft.forward_real(x);
        for (a, &b) in s.iter_mut().zip(&k2) {
            *a *= b;
        }
        fft.inverse_real(s)
    };
    // Right-hand side Kᵀy.
    let rhs = {
        let mut s = fft.forward_real(y);
        for (a, b) in s.iter_mut().zip(&otf) {
            *a *= b.conj();
        }
        fft.inverse_real(s)
    };
    let mut x = wiener(fft, y, k, 0.01);
    let mu = p.alpha / p.lambda;
    for _ in 0..p.outer {
        let weight = |g: Vec<f64>| -> Vec<f64> {
            g.into_iter()
                .map(|v| v.abs().max(p.epsilon).powf(p.alpha - 2.0))
                .collect()
        };
        let wx = weight(grad_x(&x, w, h));
        let wy = weight(grad_y(&x, w, h));
        let apply = |v: &[f64]| -> Vec<f64> {
            let mut out = apply_ktk(v);
            let gx: Vec<f64> = grad_x(v, w, h)
                .iter()
                .zip(&wx)
                .map(|(a, b)| a * b)
                .collect();
            let gy: Vec<f64> = grad_y(v, w, h)
                .iter()
                .zip(&wy)
                .map(|(a, b)| a * b)
                .collect();
            let tx = grad_x_t(&gx, w, h);
            let ty = grad_y_t(&gy, w, h);
            for i in 0..out.len() {
                out[i] += mu * (tx[i] + ty[i]);
            }
            out
        };
        // Conjugate gradients from the current estimate.
        let ax = apply(&x);
        let mut r: Vec<f64> = rhs.iter().zip(&ax).map(|(a, b)| a - b).collect();
        let mut d = r.clone();
        let mut rr: f64 = r.iter().map(|v| v * v).sum();
        for _ in 0..p.cg_iterations {
            if rr < 1e-20 {
                break;
            }
            let ad = apply(&d);
            let dad: f64 = d.iter().zip(&ad).map(|(a, b)| a * b).sum();
            if dad <= 0.0 {
                break;
            }
            let step = rr / dad;
            for i in 0..x.len() {
                x[i] += step * d[i];
                r[i] -= step * ad[i];
            }
            let rr_new: f64 = r.iter().map(|v| v * v).sum();
            let b = rr_new / rr;
            rr = rr_new;
            for i in 0..d.len() {
                d[i] = r[i] + b * d[i];
            }
        }
    }
    x
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
}
