//! Real 2-D FFTs with cached plans and reusable buffers, and the linear convolution /
//! correlation helpers the kernel estimator and the deconvolvers build on.
//!
//! Layout: a real `m × m` image is row-major; its half spectrum is stored column by
//! column (`m/2 + 1` columns of `m` complex values each), which keeps the column pass
//! contiguous. The forward transform is unnormalised; [`Fft2::inverse`] scales by
//! `1 / m²`, so `inverse(forward(x)) = x`.

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use std::ops::Range;
use std::sync::{Arc, Mutex, OnceLock};

/// The smallest length ≥ `n` whose prime factors are all 2, 3 or 5 (fast FFT lengths).
#[must_use]
pub fn good_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

struct Planners {
    real: RealFftPlanner<f64>,
    complex: FftPlanner<f64>,
}

fn planners() -> &'static Mutex<Planners> {
    static PLANNERS: OnceLock<Mutex<Planners>> = OnceLock::new();
    PLANNERS.get_or_init(|| {
        Mutex::new(Planners {
            real: RealFftPlanner::new(),
            complex: FftPlanner::new(),
        })
    })
}

/// A square real 2-D FFT of side `m`: plans (shared process-wide, planned once per
/// length) plus this instance's scratch buffers. One instance per thread and task.
pub struct Fft2 {
    m: usize,
    row_forward: Arc<dyn RealToComplex<f64>>,
    row_inverse: Arc<dyn ComplexToReal<f64>>,
    col_forward: Arc<dyn Fft<f64>>,
    col_inverse: Arc<dyn Fft<f64>>,
    row_real: Vec<f64>,
    row_spec: Vec<Complex<f64>>,
    real_scratch: Vec<Complex<f64>>,
    col_scratch: Vec<Complex<f64>>,
}

impl Fft2 {
    /// Plans for side `m` (use [`good_size`] to choose it).
    ///
    /// # Panics
    /// If `m` is zero.
    #[must_use]
    pub fn new(m: usize) -> Self {
        assert!(m > 0, "FFT of side 0");
        let (row_forward, row_inverse, col_forward, col_inverse) = {
            let mut p = planners()
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let rf = p.real.plan_fft_forward(m);
            let ri = p.real.plan_fft_inverse(m);
            let cf = p.complex.plan_fft_forward(m);
            let ci = p.complex.plan_fft_inverse(m);
            (rf, ri, cf, ci)
        };
        let real_scratch_len = row_forward
            .get_scratch_len()
            .max(row_inverse.get_scratch_len());
        let col_scratch_len = col_forward
            .get_inplace_scratch_len()
            .max(col_inverse.get_inplace_scratch_len());
        Self {
            m,
            row_real: vec![0.0; m],
            row_spec: vec![Complex::default(); m / 2 + 1],
            real_scratch: vec![Complex::default(); real_scratch_len],
            col_scratch: vec![Complex::default(); col_scratch_len],
            row_forward,
            row_inverse,
            col_forward,
            col_inverse,
        }
    }

    #[must_use]
    pub fn side(&self) -> usize {
        self.m
    }

    /// Number of complex values of a half spectrum.
    #[must_use]
    pub fn spectrum_len(&self) -> usize {
        (self.m / 2 + 1) * self.m
    }

    /// Forward transform of the `m × m` real image `input` into `spectrum`
    /// (length [`Self::spectrum_len`]). Rows outside `nonzero_rows` must be zero in the
    /// input; they are skipped.
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn forward(
        &mut self,
        input: &[f64],
        nonzero_rows: Range<usize>,
        spectrum: &mut [Complex<f64>],
    ) {
        let m = self.m;
        let half = m / 2 + 1;
        assert!(
            input.len() == m * m && spectrum.len() == half * m,
            "FFT buffer sizes"
        );
        for row in 0..m {
            if nonzero_rows.contains(&row) {
                self.row_real
                    .copy_from_slice(&input[row * m..(row + 1) * m]);
                // Lengths are right by construction, so the transform cannot fail.
                let _ = self.row_forward.process_with_scratch(
                    &mut self.row_real,
                    &mut self.row_spec,
                    &mut self.real_scratch,
                );
                for (c, v) in self.row_spec.iter().enumerate() {
                    spectrum[c * m + row] = *v;
                }
            } else {
                for c in 0..half {
                    spectrum[c * m + row] = Complex::default();
                }
            }
        }
        self.col_forward
            .process_with_scratch(spectrum, &mut self.col_scratch);
    }

    /// Inverse transform (normalised by `1/m²`) of `spectrum`, which is consumed as
    /// scratch; writes only the rows in `rows` of `output` (`m × m`).
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn inverse(
        &mut self,
        spectrum: &mut [Complex<f64>],
        rows: Range<usize>,
        output: &mut [f64],
    ) {
        let m = self.m;
        let half = m / 2 + 1;
        assert!(
            output.len() == m * m && spectrum.len() == half * m,
            "FFT buffer sizes"
        );
        self.col_inverse
            .process_with_scratch(spectrum, &mut self.col_scratch);
        let scale = 1.0 / (m * m) as f64;
        for row in rows {
            for c in 0..half {
                self.row_spec[c] = spectrum[c * m + row];
            }
            // A real signal's DC (and Nyquist, for even m) bins are real; rounding in the
            // products leaves tiny imaginary parts that the inverse must not see.
            self.row_spec[0].im = 0.0;
            if m.is_multiple_of(2) {
                self.row_spec[half - 1].im = 0.0;
            }
            let _ = self.row_inverse.process_with_scratch(
                &mut self.row_spec,
                &mut self.row_real,
                &mut self.real_scratch,
            );
            for (o, v) in output[row * m..(row + 1) * m]
                .iter_mut()
                .zip(&self.row_real)
            {
                *o = v * scale;
            }
        }
    }
}

/// Full linear convolution of `a` (`aw × ah`) with `b` (`bw × bh`), by FFT; the result
/// is `(aw + bw − 1) × (ah + bh − 1)`, row-major.
#[must_use]
pub fn convolve_full(a: &[f64], aw: usize, ah: usize, b: &[f64], bw: usize, bh: usize) -> Vec<f64> {
    let (ow, oh) = (aw + bw - 1, ah + bh - 1);
    let m = good_size(ow.max(oh));
    let mut fft = Fft2::new(m);
    let pad = |src: &[f64], w: usize, h: usize| {
        let mut out = vec![0.0; m * m];
        for y in 0..h {
            out[y * m..y * m + w].copy_from_slice(&src[y * w..(y + 1) * w]);
        }
        out
    };
    let (pa, pb) = (pad(a, aw, ah), pad(b, bw, bh));
    let mut fa = vec![Complex::default(); fft.spectrum_len()];
    let mut fb = fa.clone();
    fft.forward(&pa, 0..ah, &mut fa);
    fft.forward(&pb, 0..bh, &mut fb);
    for (x, y) in fa.iter_mut().zip(&fb) {
        *x *= y;
    }
    let mut full = vec![0.0; m * m];
    fft.inverse(&mut fa, 0..oh, &mut full);
    let mut out = Vec::with_capacity(ow * oh);
    for y in 0..oh {
        out.extend_from_slice(&full[y * m..y * m + ow]);
    }
    out
}

/// Direct (quadratic-time) full convolution: the reference the FFT path is tested against.
#[must_use]
pub fn convolve_full_direct(
    a: &[f64],
    aw: usize,
    ah: usize,
    b: &[f64],
    bw: usize,
    bh: usize,
) -> Vec<f64> {
    let (ow, oh) = (aw + bw - 1, ah + bh - 1);
    let mut out = vec![0.0; ow * oh];
    for ay in 0..ah {
        for ax in 0..aw {
            let va = a[ay * aw + ax];
            if va == 0.0 {
                continue;
            }
            for by in 0..bh {
                for bx in 0..bw {
                    out[(ay + by) * ow + ax + bx] += va * b[by * bw + bx];
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn good_sizes_have_small_factors() {
        assert_eq!(good_size(7), 8);
        assert_eq!(good_size(31), 32);
        assert_eq!(good_size(61), 64);
        assert_eq!(good_size(97), 100);
        assert_eq!(good_size(1), 1);
    }

    #[test]
    fn round_trip_is_identity() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for m in [5, 8, 9, 30] {
            let x: Vec<f64> = (0..m * m).map(|_| rng.random::<f64>() - 0.5).collect();
            let mut fft = Fft2::new(m);
            let mut s = vec![Complex::default(); fft.spectrum_len()];
            fft.forward(&x, 0..m, &mut s);
            let mut y = vec![0.0; m * m];
            fft.inverse(&mut s, 0..m, &mut y);
            for (a, b) in x.iter().zip(&y) {
                assert!((a - b).abs() < 1e-12, "m={m}");
            }
        }
    }

    #[test]
    fn fft_convolution_matches_direct() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        for (aw, ah, bw, bh) in [
            (7, 5, 3, 3),
            (20, 13, 9, 11),
            (1, 1, 4, 2),
            (33, 17, 15, 15),
        ] {
            let a: Vec<f64> = (0..aw * ah).map(|_| rng.random::<f64>() - 0.5).collect();
            let b: Vec<f64> = (0..bw * bh).map(|_| rng.random::<f64>() - 0.5).collect();
            let fast = convolve_full(&a, aw, ah, &b, bw, bh);
            let slow = convolve_full_direct(&a, aw, ah, &b, bw, bh);
            assert_eq!(fast.len(), slow.len());
            for (x, y) in fast.iter().zip(&slow) {
                assert!((x - y).abs() < 1e-10, "{x} vs {y}");
            }
        }
    }
}
