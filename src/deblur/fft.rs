//! Real two-dimensional FFTs of one `width × height` block, and the circular
//! convolutions the solvers are built on.
//!
//! A real block's spectrum is Hermitian, so only its `width / 2 + 1` non-negative
//! x-frequencies are kept, stored column by column (`height` complex values per
//! column) so the column pass runs as one batched transform over contiguous memory.
//! The forward transform is unnormalised; [`Fft2::inverse`] scales by
//! `1 / (width · height)`, so `inverse(forward(x)) = x`.
//!
//! Plans are shared (`Arc`); each [`Fft2`] value owns its scratch buffers, so a worker
//! thread clones one and reuses it for every block it handles.

use crate::psf::Kernel;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// Forward and inverse real 2-D FFT plans for one block size, with scratch space.
#[derive(Clone)]
pub struct Fft2 {
    pub width: usize,
    pub height: usize,
    row_forward: Arc<dyn RealToComplex<f64>>,
    row_inverse: Arc<dyn ComplexToReal<f64>>,
    col_forward: Arc<dyn Fft<f64>>,
    col_inverse: Arc<dyn Fft<f64>>,
    row_real: Vec<f64>,
    /// Half spectra of `ROWS_PER_PASS` rows: moving them to and from the column-major
    /// spectrum a few rows at a time touches each cache line once, not once per row.
    row_specs: Vec<Complex64>,
    real_scratch: Vec<Complex64>,
    col_scratch: Vec<Complex64>,
}

const ROWS_PER_PASS: usize = 8;

impl std::fmt::Debug for Fft2 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fft2({}×{})", self.width, self.height)
    }
}

impl Fft2 {
    /// Plans for a `width × height` block (use [`fast_size`] for fast sides).
    ///
    /// # Panics
    /// If a side is zero.
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        assert!(width > 0 && height > 0, "FFT of an empty block");
        let mut real = RealFftPlanner::<f64>::new();
        let mut complex = FftPlanner::<f64>::new();
        let row_forward = real.plan_fft_forward(width);
        let row_inverse = real.plan_fft_inverse(width);
        let col_forward = complex.plan_fft_forward(height);
        let col_inverse = complex.plan_fft_inverse(height);
        let real_scratch = row_forward
            .get_scratch_len()
            .max(row_inverse.get_scratch_len());
        let col_scratch = col_forward
            .get_inplace_scratch_len()
            .max(col_inverse.get_inplace_scratch_len());
        Self {
            width,
            height,
            row_real: vec![0.0; width],
            row_specs: vec![Complex64::default(); ROWS_PER_PASS * (width / 2 + 1)],
            real_scratch: vec![Complex64::default(); real_scratch],
            col_scratch: vec![Complex64::default(); col_scratch],
            row_forward,
            row_inverse,
            col_forward,
            col_inverse,
        }
    }

    /// Columns of the half spectrum: the x-frequencies 0..=width/2.
    #[must_use]
    pub fn half_width(&self) -> usize {
        self.width / 2 + 1
    }

    /// Complex values in a half spectrum.
    #[must_use]
    pub fn spectrum_len(&self) -> usize {
        self.half_width() * self.height
    }

    /// A zeroed half spectrum for this block.
    #[must_use]
    pub fn new_spectrum(&self) -> Vec<Complex64> {
        vec![Complex64::default(); self.spectrum_len()]
    }

    /// Forward transform of the real block `input` (row-major) into `spectrum`
    /// (column-major half spectrum: entry `c · height + r` is x-frequency c,
    /// y-frequency r).
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn forward(&mut self, input: &[f64], spectrum: &mut [Complex64]) {
        let (w, h) = (self.width, self.height);
        assert!(
            input.len() == w * h && spectrum.len() == self.spectrum_len(),
            "FFT buffer sizes"
        );
        let half = self.half_width();
        for r0 in (0..h).step_by(ROWS_PER_PASS) {
            let rows = ROWS_PER_PASS.min(h - r0);
            for k in 0..rows {
                let r = r0 + k;
                self.row_real.copy_from_slice(&input[r * w..(r + 1) * w]);
                // Lengths are right by construction, so the transform cannot fail.
                let _ = self.row_forward.process_with_scratch(
                    &mut self.row_real,
                    &mut self.row_specs[k * half..(k + 1) * half],
                    &mut self.real_scratch,
                );
            }
            for c in 0..half {
                let col = &mut spectrum[c * h + r0..c * h + r0 + rows];
                for (k, v) in col.iter_mut().enumerate() {
                    *v = self.row_specs[k * half + c];
                }
            }
        }
        self.col_forward
            .process_with_scratch(spectrum, &mut self.col_scratch);
    }

    /// Inverse transform (normalised by `1 / (width · height)`) of `spectrum`, which is
    /// consumed as scratch, into the real block `output`.
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn inverse(&mut self, spectrum: &mut [Complex64], output: &mut [f64]) {
        let (w, h) = (self.width, self.height);
        let half = self.half_width();
        assert!(
            output.len() == w * h && spectrum.len() == self.spectrum_len(),
            "FFT buffer sizes"
        );
        self.col_inverse
            .process_with_scratch(spectrum, &mut self.col_scratch);
        let scale = 1.0 / (w * h) as f64;
        for r0 in (0..h).step_by(ROWS_PER_PASS) {
            let rows = ROWS_PER_PASS.min(h - r0);
            for c in 0..half {
                let col = &spectrum[c * h + r0..c * h + r0 + rows];
                for (k, v) in col.iter().enumerate() {
                    self.row_specs[k * half + c] = *v;
                }
            }
            for k in 0..rows {
                let r = r0 + k;
                let spec = &mut self.row_specs[k * half..(k + 1) * half];
                // A real row's DC (and, for even widths, Nyquist) bins are real; rounding
                // in the products leaves tiny imaginary parts the real inverse refuses.
                spec[0].im = 0.0;
                if w % 2 == 0 {
                    spec[half - 1].im = 0.0;
                }
                let _ = self.row_inverse.process_with_scratch(
                    spec,
                    &mut self.row_real,
                    &mut self.real_scratch,
                );
                for (o, v) in output[r * w..(r + 1) * w].iter_mut().zip(&self.row_real) {
                    *o = v * scale;
                }
            }
        }
    }

    /// Optical transfer function of a 1× kernel on this block: the kernel placed with
    /// its centre at (0, 0), wrapped around, transformed. `block` is scratch of
    /// `width × height` values.
    ///
    /// # Panics
    /// If the kernel is larger than the block, or on wrongly sized buffers.
    pub fn otf_into(&mut self, k: &Kernel, block: &mut [f64], otf: &mut [Complex64]) {
        let (w, h) = (self.width, self.height);
        assert!(k.size <= w && k.size <= h, "kernel larger than block");
        block.fill(0.0);
        let c = (k.size / 2) as isize;
        for j in 0..k.size {
            let y = (j as isize - c).rem_euclid(h as isize) as usize;
            for i in 0..k.size {
                let x = (i as isize - c).rem_euclid(w as isize) as usize;
                block[y * w + x] += k.at(i, j);
            }
        }
        self.forward(block, otf);
    }

    /// [`Self::otf_into`] with its own buffers.
    #[must_use]
    pub fn otf(&mut self, k: &Kernel) -> Vec<Complex64> {
        let mut block = vec![0.0; self.width * self.height];
        let mut otf = self.new_spectrum();
        self.otf_into(k, &mut block, &mut otf);
        otf
    }

    /// |D_x|² + |D_y|² of the forward differences x(i+1) − x(i) along x and y, per
    /// half-spectrum entry: |e^{iω} − 1|² = 2 − 2 cos ω at each axis's frequency ω.
    #[must_use]
    pub fn gradient_energy(&self) -> Vec<f64> {
        let (w, h) = (self.width, self.height);
        let tau = std::f64::consts::TAU;
        let col: Vec<f64> = (0..h)
            .map(|r| 2.0 - 2.0 * (tau * r as f64 / h as f64).cos())
            .collect();
        let mut out = Vec::with_capacity(self.spectrum_len());
        for c in 0..self.half_width() {
            let gx = 2.0 - 2.0 * (tau * c as f64 / w as f64).cos();
            out.extend(col.iter().map(|gy| gx + gy));
        }
        out
    }

    /// Circular convolution of a real block with a 1× kernel (centred).
    #[must_use]
    pub fn convolve(&mut self, data: &[f64], k: &Kernel) -> Vec<f64> {
        let otf = self.otf(k);
        let mut s = self.new_spectrum();
        self.forward(data, &mut s);
        for (a, b) in s.iter_mut().zip(&otf) {
            *a *= b;
        }
        let mut out = vec![0.0; self.width * self.height];
        self.inverse(&mut s, &mut out);
        out
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
    crate::fft::good_size(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::Gaussian2;

    fn asymmetric_kernel() -> Kernel {
        let mut k = Gaussian2 {
            sigma_x: 1.3,
            sigma_y: 0.8,
            rho: 0.4,
        }
        .kernel(1);
        // An asymmetric kernel catches flipped conventions.
        k.data[0] += 0.2;
        k.normalise();
        k
    }

    #[test]
    fn fft_convolution_matches_direct() {
        // Odd and even sides, wider and taller than high: every layout path.
        for (w, h) in [(24, 18), (17, 30), (15, 15)] {
            let data: Vec<f64> = (0..w * h)
                .map(|i| ((i * 37 % 101) as f64) / 100.0)
                .collect();
            let k = asymmetric_kernel();
            let mut fft = Fft2::new(w, h);
            let a = fft.convolve(&data, &k);
            let b = convolve_direct_circular(&data, w, h, &k);
            let err = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-12, "{w}×{h}: max error {err}");
        }
    }

    #[test]
    fn forward_then_inverse_is_identity() {
        let (w, h) = (30, 20);
        let data: Vec<f64> = (0..w * h).map(|i| ((i * 53 % 97) as f64).sin()).collect();
        let mut fft = Fft2::new(w, h);
        let mut s = fft.new_spectrum();
        fft.forward(&data, &mut s);
        let mut back = vec![0.0; w * h];
        fft.inverse(&mut s, &mut back);
        let err = data
            .iter()
            .zip(&back)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-12, "{err}");
    }

    #[test]
    fn gradient_energy_matches_the_spatial_differences() {
        // ‖∇x‖² by Parseval on the half spectrum must equal the spatial sum.
        let (w, h) = (12, 10);
        let x: Vec<f64> = (0..w * h).map(|i| ((i * 29 % 31) as f64) / 31.0).collect();
        let mut spatial = 0.0;
        for r in 0..h {
            for c in 0..w {
                let gx = x[r * w + (c + 1) % w] - x[r * w + c];
                let gy = x[((r + 1) % h) * w + c] - x[r * w + c];
                spatial += gx * gx + gy * gy;
            }
        }
        let mut fft = Fft2::new(w, h);
        let mut s = fft.new_spectrum();
        fft.forward(&x, &mut s);
        let g = fft.gradient_energy();
        let mut spectral = 0.0;
        for c in 0..fft.half_width() {
            // Columns 1..w/2 (exclusive of Nyquist) stand for their mirror too.
            let mult = if c == 0 || (w % 2 == 0 && c == w / 2) {
                1.0
            } else {
                2.0
            };
            for r in 0..h {
                spectral += mult * g[c * h + r] * s[c * h + r].norm_sqr();
            }
        }
        spectral /= (w * h) as f64;
        assert!(
            (spatial - spectral).abs() < 1e-9 * spatial,
            "{spatial} vs {spectral}"
        );
    }

    #[test]
    fn fast_sizes() {
        assert_eq!(fast_size(7), 8);
        assert_eq!(fast_size(97), 100);
        assert_eq!(fast_size(256), 256);
    }
}
