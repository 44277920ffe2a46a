//! Two-dimensional FFTs and the circular convolutions the solvers are built on.
//!
//! Everything here works on one `width × height` block in f64; a plan is made once per
//! block size and reused for every tile of that size.

use crate::psf::Kernel;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// Forward and inverse 2-D complex FFT plans for one block size.
#[derive(Clone)]
pub struct Fft2 {
    pub width: usize,
    pub height: usize,
    row_fwd: Arc<dyn Fft<f64>>,
    row_inv: Arc<dyn Fft<f64>>,
    col_fwd: Arc<dyn Fft<f64>>,
    col_inv: Arc<dyn Fft<f64>>,
}

impl std::fmt::Debug for Fft2 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fft2({}×{})", self.width, self.height)
    }
}

impl Fft2 {
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        let mut p = FftPlanner::new();
        Self {
            width,
            height,
            row_fwd: p.plan_fft_forward(width),
            row_inv: p.plan_fft_inverse(width),
            col_fwd: p.plan_fft_forward(height),
            col_inv: p.plan_fft_inverse(height),
        }
    }

    fn run(&self, data: &mut [Complex64], inverse: bool) {
        let (w, h) = (self.width, self.height);
        debug_assert_eq!(data.len(), w * h);
        let (rows, cols) = if inverse {
            (&self.row_inv, &self.col_inv)
        } else {
            (&self.row_fwd, &self.col_fwd)
        };
        rows.process(data);
        // Columns through a transpose: contiguous rows are what the plans are fast on.
        let mut t = vec![Complex64::new(0.0, 0.0); w * h];
        transpose(data, &mut t, w, h);
        cols.process(&mut t);
        transpose(&t, data, h, w);
        if inverse {
            let s = 1.0 / (w * h) as f64;
            for v in data.iter_mut() {
                *v *= s;
            }
        }
    }

    pub fn forward(&self, data: &mut [Complex64]) {
        self.run(data, false);
    }

    /// Inverse transform, normalised so `inverse(forward(x)) = x`.
    pub fn inverse(&self, data: &mut [Complex64]) {
        self.run(data, true);
    }

    /// Spectrum of a real block.
    #[must_use]
    pub fn forward_real(&self, data: &[f64]) -> Vec<Complex64> {
        let mut c: Vec<Complex64> = data.iter().map(|&v| Complex64::new(v, 0.0)).collect();
        self.forward(&mut c);
        c
    }

    /// Real part of the inverse transform.
    #[must_use]
    pub fn inverse_real(&self, mut spec: Vec<Complex64>) -> Vec<f64> {
        self.inverse(&mut spec);
        spec.into_iter().map(|c| c.re).collect()
    }

    /// Optical transfer function of a 1× kernel on this block: the kernel placed with its
    /// centre at (0, 0), wrapped around, transformed.
    ///
    /// # Panics
    /// If the kernel is larger than the block.
    #[must_use]
    pub fn otf(&self, k: &Kernel) -> Vec<Complex64> {
        assert!(
            k.size <= self.width && k.size <= self.height,
            "kernel larger than block"
        );
        let c = (k.size / 2) as isize;
        let mut buf = vec![Complex64::new(0.0, 0.0); self.width * self.height];
        for j in 0..k.size {
            for i in 0..k.size {
                let x = (i as isize - c).rem_euclid(self.width as isize) as usize;
                let y = (j as isize - c).rem_euclid(self.height as isize) as usize;
                buf[y * self.width + x].re += k.at(i, j);
            }
        }
        self.forward(&mut buf);
        buf
    }

    /// Spectra of the forward differences x(i+1) − x(i) along x and y, as circular
    /// convolutions: (d ∗ x)(i) = Σ d(m) x(i − m), so the +1 tap sits at m = −1 (the
    /// last index), matching the spatial `grad_x`/`grad_y` the solvers pair it with.
    #[must_use]
    pub fn gradient_otfs(&self) -> (Vec<Complex64>, Vec<Complex64>) {
        let (w, h) = (self.width, self.height);
        let mut dx = vec![Complex64::new(0.0, 0.0); w * h];
        let mut dy = dx.clone();
        dx[0].re = -1.0;
        dx[(w - 1) % w].re += 1.0;
        dy[0].re = -1.0;
        dy[((h - 1) % h) * w].re += 1.0;
        self.forward(&mut dx);
        self.forward(&mut dy);
        (dx, dy)
    }

    /// Circular convolution of a real block with a 1× kernel (centred).
    #[must_use]
    pub fn convolve(&self, data: &[f64], k: &Kernel) -> Vec<f64> {
        let otf = self.otf(k);
        let mut s = self.forward_real(data);
        for (a, b) in s.iter_mut().zip(&otf) {
            *a *= b;
        }
        self.inverse_real(s)
    }
}

fn transpose(src: &[Complex64], dst: &mut [Complex64], w: usize, h: usize) {
    // Blocked so both sides stay in cache on large planes.
    const B: usize = 32;
    for y0 in (0..h).step_by(B) {
        for x0 in (0..w).step_by(B) {
            for y in y0..(y0 + B).min(h) {
                for x in x0..(x0 + B).min(w) {
                    dst[x * h + y] = src[y * w + x];
                }
            }
        }
    }
}

/// Direct circular convolution, the oracle the FFT version is tested against.
#[must_use]
pub fn convolve_direct_circular(data: &[f64], width: usize, height: usize, k: &Kernel) -> Vec<f64> {
    let c = (k.size / 2) as isize;
    let mut out = vec![0.0; width * height];
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0.0;
            for j in 0..k.size {
                for i in 0..k.size {
                    let sx = (x as isize - (i as isize - c)).rem_euclid(width as isize) as usize;
                    let sy = (y as isize - (j as isize - c)).rem_euclid(height as isize) as usize;
                    acc += k.at(i, j) * data[sy * width + sx];
                }
            }
            out[y * width + x] = acc;
        }
    }
    out
}

/// Smallest size ≥ `n` whose only prime factors are 2, 3 and 5 (fast for the FFT).
#[must_use]
pub fn fast_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5] {
            while r % p == 0 {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::Gaussian2;

    #[test]
    fn fft_convolution_matches_direct() {
        let (w, h) = (24, 18);
        let data: Vec<f64> = (0..w * h)
            .map(|i| ((i * 37 % 101) as f64) / 100.0)
            .collect();
        let mut k = Gaussian2 {
            sigma_x: 1.3,
            sigma_y: 0.8,
            rho: 0.4,
        }
        .kernel(1);
        // An asymmetric kernel catches flipped conventions.
        k.data[0] += 0.2;
        k.normalise();
        let fft = Fft2::new(w, h);
        let a = fft.convolve(&data, &k);
        let b = convolve_direct_circular(&data, w, h, &k);
        let err = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-12, "max error {err}");
    }

    #[test]
    fn fast_sizes() {
        assert_eq!(fast_size(7), 8);
        assert_eq!(fast_size(97), 100);
        assert_eq!(fast_size(256), 256);
    }
}
