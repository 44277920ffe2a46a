//! The crate's one 2-D FFT, its one plan cache and its one choice of fast lengths, and
//! the convolutions the kernel estimator, the deconvolvers and the simulator build on.
//!
//! Real blocks: a real `width × height` block is row-major. Its spectrum is Hermitian,
//! so only the `width / 2 + 1` non-negative x-frequencies are kept, stored column by
//! column (`height` complex values per column), which lets the column pass run as one
//! batched transform over contiguous memory. The forward transform is unnormalised;
//! the inverse scales by `1 / (width · height)`, so `inverse(forward(x)) = x`.
//!
//! Complex blocks (the simulator's, whose spectra are resampled by folding and so need
//! every frequency) are row-major and transformed in place, unnormalised both ways: the
//! caller folds the scale into its own resampling factor.
//!
//! Plans: planning a length costs far more than one transform, and a run transforms
//! thousands of tiles of a handful of sizes, so each length and precision is planned
//! once per process and the (immutable) plans are shared. Scratch buffers belong to an
//! [`Fft2`] value, so a worker thread clones one and reuses it for every block.

use crate::psf::Kernel;
use realfft::{ComplexToReal, RealToComplex};
use rustfft::Fft;
use rustfft::num_complex::Complex;
use rustfft::num_traits::Zero;
use std::ops::Range;
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

pub use sealed::Precision;

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

/// The process's planners, one pair per precision. A planner memoises every length it
/// has planned, so asking again for a length hands back the same plan.
struct PlanCache {
    single: Mutex<sealed::Planners<f32>>,
    double: Mutex<sealed::Planners<f64>>,
}

fn plan_cache() -> &'static PlanCache {
    static CACHE: OnceLock<PlanCache> = OnceLock::new();
    CACHE.get_or_init(|| PlanCache {
        single: Mutex::new(sealed::Planners::new()),
        double: Mutex::new(sealed::Planners::new()),
    })
}

// Private, so the cache's two slots are the only precisions there can be.
mod sealed {
    use super::plan_cache;
    use realfft::RealFftPlanner;
    use rustfft::{FftNum, FftPlanner};
    use std::sync::Mutex;

    pub struct Planners<T: FftNum> {
        pub(super) real: RealFftPlanner<T>,
        pub(super) complex: FftPlanner<T>,
    }

    impl<T: FftNum> Planners<T> {
        pub(super) fn new() -> Self {
            Self {
                real: RealFftPlanner::new(),
                complex: FftPlanner::new(),
            }
        }
    }

    /// A precision the plan cache holds planners for: `f64` for measurement and
    /// deblurring, `f32` for the simulator.
    pub trait Precision: FftNum {
        #[doc(hidden)]
        fn planners() -> &'static Mutex<Planners<Self>>;
        /// `1 / n`, computed in this precision.
        #[doc(hidden)]
        fn recip(n: usize) -> Self;
        /// `v` rounded to this precision.
        #[doc(hidden)]
        fn of_f64(v: f64) -> Self;
    }

    impl Precision for f32 {
        fn planners() -> &'static Mutex<Planners<Self>> {
            &plan_cache().single
        }
        fn recip(n: usize) -> Self {
            1.0 / n as f32
        }
        fn of_f64(v: f64) -> Self {
            v as f32
        }
    }

    impl Precision for f64 {
        fn planners() -> &'static Mutex<Planners<Self>> {
            &plan_cache().double
        }
        fn recip(n: usize) -> Self {
            1.0 / n as f64
        }
        fn of_f64(v: f64) -> Self {
            v
        }
    }
}

/// A 1-D forward complex transform of length `n` from the process-wide cache, for a
/// caller that transforms only some rows or columns of a block itself (the simulator's
/// pupil-to-PSF step keeps a window of the columns).
#[must_use]
pub fn complex_forward_plan<T: Precision>(n: usize) -> Arc<dyn Fft<T>> {
    // As in `Fft2::new`: a poisoned lock still holds good planners.
    let mut p = T::planners().lock().unwrap_or_else(PoisonError::into_inner);
    p.complex.plan_fft_forward(n)
}

/// Rows moved between the row pass and the column-major spectrum at a time: a few rows
/// together touch each cache line of the spectrum once, not once per row.
const ROWS_PER_PASS: usize = 8;

/// A 2-D FFT of `width × height` blocks: shared plans plus this value's own scratch.
/// One value per thread; clone it for another.
#[derive(Clone)]
pub struct Fft2<T: Precision = f64> {
    width: usize,
    height: usize,
    row_forward: Arc<dyn RealToComplex<T>>,
    row_inverse: Arc<dyn ComplexToReal<T>>,
    row_complex_forward: Arc<dyn Fft<T>>,
    row_complex_inverse: Arc<dyn Fft<T>>,
    col_forward: Arc<dyn Fft<T>>,
    col_inverse: Arc<dyn Fft<T>>,
    row_real: Vec<T>,
    /// Half spectra of `ROWS_PER_PASS` rows.
    row_specs: Vec<Complex<T>>,
    real_scratch: Vec<Complex<T>>,
    complex_scratch: Vec<Complex<T>>,
    /// A complex block's columns as rows while they are transformed; empty until one is.
    transposed: Vec<Complex<T>>,
}

impl<T: Precision> std::fmt::Debug for Fft2<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fft2({}×{})", self.width, self.height)
    }
}

impl<T: Precision> Fft2<T> {
    /// Plans for `width × height` blocks (use [`good_size`] for fast sides), taken from
    /// the process-wide cache.
    ///
    /// # Panics
    /// If a side is zero.
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        assert!(width > 0 && height > 0, "FFT of an empty block");
        let (row_forward, row_inverse, row_complex_forward, row_complex_inverse, cols) = {
            // Planners hold no invariant a panicking holder could have broken halfway
            // (a plan is inserted whole or not at all), so a poisoned lock is still good.
            let mut p = T::planners().lock().unwrap_or_else(PoisonError::into_inner);
            let rows = (
                p.real.plan_fft_forward(width),
                p.real.plan_fft_inverse(width),
                p.complex.plan_fft_forward(width),
                p.complex.plan_fft_inverse(width),
            );
            let cols = (
                p.complex.plan_fft_forward(height),
                p.complex.plan_fft_inverse(height),
            );
            (rows.0, rows.1, rows.2, rows.3, cols)
        };
        let (col_forward, col_inverse) = cols;
        let real_scratch = row_forward
            .get_scratch_len()
            .max(row_inverse.get_scratch_len());
        let complex_scratch = [
            &row_complex_forward,
            &row_complex_inverse,
            &col_forward,
            &col_inverse,
        ]
        .iter()
        .map(|p| p.get_inplace_scratch_len())
        .max()
        .unwrap_or(0);
        let zero = Complex::zero();
        Self {
            width,
            height,
            row_real: vec![T::zero(); width],
            row_specs: vec![zero; ROWS_PER_PASS * (width / 2 + 1)],
            real_scratch: vec![zero; real_scratch],
            complex_scratch: vec![zero; complex_scratch],
            transposed: Vec::new(),
            row_forward,
            row_inverse,
            row_complex_forward,
            row_complex_inverse,
            col_forward,
            col_inverse,
        }
    }

    #[must_use]
    pub fn width(&self) -> usize {
        self.width
    }

    #[must_use]
    pub fn height(&self) -> usize {
        self.height
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
    pub fn new_spectrum(&self) -> Vec<Complex<T>> {
        vec![Complex::zero(); self.spectrum_len()]
    }

    /// Forward transform of the real block `input` (row-major) into `spectrum`
    /// (column-major half spectrum: entry `c · height + r` is x-frequency c,
    /// y-frequency r).
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn forward(&mut self, input: &[T], spectrum: &mut [Complex<T>]) {
        self.forward_rows(input, 0..self.height, spectrum);
    }

    /// [`Self::forward`] of a block whose rows outside `nonzero_rows` are zero: those
    /// rows are not read, and their transforms are known to be zero.
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn forward_rows(
        &mut self,
        input: &[T],
        nonzero_rows: Range<usize>,
        spectrum: &mut [Complex<T>],
    ) {
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
                let spec = &mut self.row_specs[k * half..(k + 1) * half];
                if nonzero_rows.contains(&r) {
                    self.row_real.copy_from_slice(&input[r * w..(r + 1) * w]);
                    // Lengths are right by construction, so the transform cannot fail.
                    let _ = self.row_forward.process_with_scratch(
                        &mut self.row_real,
                        spec,
                        &mut self.real_scratch,
                    );
                } else {
                    spec.fill(Complex::zero());
                }
            }
            for c in 0..half {
                let col = &mut spectrum[c * h + r0..c * h + r0 + rows];
                for (k, v) in col.iter_mut().enumerate() {
                    *v = self.row_specs[k * half + c];
                }
            }
        }
        self.col_forward
            .process_with_scratch(spectrum, &mut self.complex_scratch);
    }

    /// Inverse transform (normalised by `1 / (width · height)`) of `spectrum`, which is
    /// consumed as scratch, into the real block `output`.
    ///
    /// # Panics
    /// On wrongly sized buffers.
    pub fn inverse(&mut self, spectrum: &mut [Complex<T>], output: &mut [T]) {
        self.inverse_rows(spectrum, 0..self.height, output);
    }

    /// [`Self::inverse`] that writes only the rows in `rows` of `output`, leaving the
    /// others as they were.
    ///
    /// # Panics
    /// On wrongly sized buffers, or rows past the block.
    pub fn inverse_rows(
        &mut self,
        spectrum: &mut [Complex<T>],
        rows: Range<usize>,
        output: &mut [T],
    ) {
        let (w, h) = (self.width, self.height);
        let half = self.half_width();
        assert!(
            output.len() == w * h && spectrum.len() == self.spectrum_len() && rows.end <= h,
            "FFT buffer sizes"
        );
        self.col_inverse
            .process_with_scratch(spectrum, &mut self.complex_scratch);
        let scale = T::recip(w * h);
        for r0 in rows.clone().step_by(ROWS_PER_PASS) {
            let n = ROWS_PER_PASS.min(rows.end - r0);
            for c in 0..half {
                let col = &spectrum[c * h + r0..c * h + r0 + n];
                for (k, v) in col.iter().enumerate() {
                    self.row_specs[k * half + c] = *v;
                }
            }
            for k in 0..n {
                let r = r0 + k;
                let spec = &mut self.row_specs[k * half..(k + 1) * half];
                // A real row's DC (and, for even widths, Nyquist) bins are real; rounding
                // in the products leaves tiny imaginary parts the real inverse refuses.
                spec[0].im = T::zero();
                if w.is_multiple_of(2) {
                    spec[half - 1].im = T::zero();
                }
                let _ = self.row_inverse.process_with_scratch(
                    spec,
                    &mut self.row_real,
                    &mut self.real_scratch,
                );
                for (o, v) in output[r * w..(r + 1) * w].iter_mut().zip(&self.row_real) {
                    *o = *v * scale;
                }
            }
        }
    }

    /// In-place forward transform of the complex block `data` (row-major, full
    /// spectrum out, same layout), unnormalised.
    ///
    /// # Panics
    /// On a wrongly sized buffer.
    pub fn forward_complex(&mut self, data: &mut [Complex<T>]) {
        let rows = Arc::clone(&self.row_complex_forward);
        let cols = Arc::clone(&self.col_forward);
        self.complex_2d(data, &*rows, &*cols);
    }

    /// In-place inverse of [`Self::forward_complex`], also unnormalised: the result
    /// is `width · height` times the block transformed.
    ///
    /// # Panics
    /// On a wrongly sized buffer.
    pub fn inverse_complex(&mut self, data: &mut [Complex<T>]) {
        let rows = Arc::clone(&self.row_complex_inverse);
        let cols = Arc::clone(&self.col_inverse);
        self.complex_2d(data, &*rows, &*cols);
    }

    /// Rows by one batched transform, then columns: transposed into a block of their
    /// own (so each is contiguous), transformed the same way, and transposed back. The
    /// transposes are the `transpose` crate's tiled ones: a plain double loop writes
    /// every value to a new cache line, and on the simulator's windows it took as long
    /// as the transforms themselves.
    fn complex_2d(&mut self, data: &mut [Complex<T>], rows: &dyn Fft<T>, cols: &dyn Fft<T>) {
        let (w, h) = (self.width, self.height);
        assert!(data.len() == w * h, "FFT buffer sizes");
        rows.process_with_scratch(data, &mut self.complex_scratch);
        self.transposed.resize(w * h, Complex::zero());
        transpose::transpose(data, &mut self.transposed, w, h);
        cols.process_with_scratch(&mut self.transposed, &mut self.complex_scratch);
        transpose::transpose(&self.transposed, data, h, w);
    }
}

impl<T: Precision> Fft2<T> {
    /// Optical transfer function of a 1× kernel on this block: the kernel placed with
    /// its centre at (0, 0), wrapped around, transformed. `block` is scratch of
    /// `width × height` values.
    ///
    /// # Panics
    /// If the kernel is larger than the block, or on wrongly sized buffers.
    pub fn otf_into(&mut self, k: &Kernel, block: &mut [T], otf: &mut [Complex<T>]) {
        let (w, h) = (self.width, self.height);
        assert!(k.size <= w && k.size <= h, "kernel larger than block");
        block.fill(T::zero());
        let c = (k.size / 2) as isize;
        for j in 0..k.size {
            let y = (j as isize - c).rem_euclid(h as isize) as usize;
            for i in 0..k.size {
                let x = (i as isize - c).rem_euclid(w as isize) as usize;
                block[y * w + x] = block[y * w + x] + T::of_f64(k.at(i, j));
            }
        }
        self.forward(block, otf);
    }

    /// [`Self::otf_into`] with its own buffers.
    #[must_use]
    pub fn otf(&mut self, k: &Kernel) -> Vec<Complex<T>> {
        let mut block = vec![T::zero(); self.width * self.height];
        let mut otf = self.new_spectrum();
        self.otf_into(k, &mut block, &mut otf);
        otf
    }

    /// |D_x|² + |D_y|² of the forward differences x(i+1) − x(i) along x and y, per
    /// half-spectrum entry: |e^{iω} − 1|² = 2 − 2 cos ω at each axis's frequency ω.
    #[must_use]
    pub fn gradient_energy(&self) -> Vec<T> {
        let (w, h) = (self.width, self.height);
        let tau = std::f64::consts::TAU;
        let col: Vec<f64> = (0..h)
            .map(|r| 2.0 - 2.0 * (tau * r as f64 / h as f64).cos())
            .collect();
        let mut out = Vec::with_capacity(self.spectrum_len());
        for c in 0..self.half_width() {
            let gx = 2.0 - 2.0 * (tau * c as f64 / w as f64).cos();
            out.extend(col.iter().map(|gy| T::of_f64(gx + gy)));
        }
        out
    }
}

impl Fft2<f64> {
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

/// Full linear convolution of `a` (`aw × ah`) with `b` (`bw × bh`), by FFT; the result
/// is `(aw + bw − 1) × (ah + bh − 1)`, row-major.
#[must_use]
pub fn convolve_full(a: &[f64], aw: usize, ah: usize, b: &[f64], bw: usize, bh: usize) -> Vec<f64> {
    let (ow, oh) = (aw + bw - 1, ah + bh - 1);
    let m = good_size(ow.max(oh));
    let mut fft = Fft2::new(m, m);
    let pad = |src: &[f64], w: usize, h: usize| {
        let mut out = vec![0.0; m * m];
        for y in 0..h {
            out[y * m..y * m + w].copy_from_slice(&src[y * w..(y + 1) * w]);
        }
        out
    };
    let (pa, pb) = (pad(a, aw, ah), pad(b, bw, bh));
    let mut fa = fft.new_spectrum();
    let mut fb = fa.clone();
    fft.forward_rows(&pa, 0..ah, &mut fa);
    fft.forward_rows(&pb, 0..bh, &mut fb);
    for (x, y) in fa.iter_mut().zip(&fb) {
        *x *= y;
    }
    let mut full = vec![0.0; m * m];
    fft.inverse_rows(&mut fa, 0..oh, &mut full);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::Gaussian2;
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
            let mut fft = Fft2::new(m, m);
            let mut s = fft.new_spectrum();
            fft.forward(&x, &mut s);
            let mut y = vec![0.0; m * m];
            fft.inverse(&mut s, &mut y);
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
    fn circular_convolution_matches_direct() {
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
    fn skipped_rows_and_partial_inverse_match_the_full_transforms() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let (w, h) = (18, 21);
        let mut x = vec![0.0; w * h];
        for v in &mut x[3 * w..13 * w] {
            *v = rng.random::<f64>() - 0.5;
        }
        let mut fft = Fft2::new(w, h);
        let (mut full, mut part) = (fft.new_spectrum(), fft.new_spectrum());
        fft.forward(&x, &mut full);
        fft.forward_rows(&x, 3..13, &mut part);
        assert_eq!(full, part);
        let mut all = vec![0.0; w * h];
        let mut some = vec![7.0; w * h];
        fft.inverse(&mut full, &mut all);
        fft.inverse_rows(&mut part, 2..11, &mut some);
        for (r, (a, b)) in all.chunks(w).zip(some.chunks(w)).enumerate() {
            if (2..11).contains(&r) {
                assert_eq!(a, b, "row {r}");
            } else {
                assert!(b.iter().all(|&v| v == 7.0), "row {r} written");
            }
        }
    }

    #[test]
    fn complex_transform_agrees_with_the_real_one_and_inverts() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        for (w, h) in [(12, 7), (9, 16), (10, 10)] {
            let x: Vec<f64> = (0..w * h).map(|_| rng.random::<f64>() - 0.5).collect();
            let mut fft = Fft2::new(w, h);
            let mut half = fft.new_spectrum();
            fft.forward(&x, &mut half);
            let mut z: Vec<Complex<f64>> = x.iter().map(|&v| Complex::new(v, 0.0)).collect();
            fft.forward_complex(&mut z);
            for c in 0..fft.half_width() {
                for r in 0..h {
                    let d = (z[r * w + c] - half[c * h + r]).norm();
                    assert!(d < 1e-12, "{w}×{h} ({c}, {r}): {d}");
                }
            }
            fft.inverse_complex(&mut z);
            let n = (w * h) as f64;
            for (a, b) in x.iter().zip(&z) {
                assert!((a - b.re / n).abs() < 1e-12 && b.im.abs() < 1e-9);
            }
        }
    }

    #[test]
    fn plans_are_planned_once_per_process() {
        let (a, b) = (Fft2::<f64>::new(48, 40), Fft2::<f64>::new(40, 48));
        assert!(Arc::ptr_eq(&a.col_forward, &b.row_complex_forward));
        assert!(Arc::ptr_eq(&a.row_complex_inverse, &b.col_inverse));
        let c = Fft2::<f64>::new(48, 40);
        assert!(Arc::ptr_eq(&a.row_forward, &c.row_forward));
        assert!(Arc::ptr_eq(&a.row_inverse, &c.row_inverse));
        // A clone shares the plans but not the scratch.
        let d = c.clone();
        assert!(Arc::ptr_eq(&d.col_inverse, &c.col_inverse));
        assert_ne!(d.row_real.as_ptr(), c.row_real.as_ptr());
    }
}
