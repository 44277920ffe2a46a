//! The error a predicted kernel leaves in a deblurred photo: what the kernel-shape
//! model's size and orders are chosen by.
//!
//! Held-out relative L2 of 3× kernels weighs every sample of the kernel alike, and on
//! an aberrated lens it did not rank kernel models by how well they deblur. A photo is
//! deconvolved with the 1× kernel (the 3× kernel read at whole-pixel offsets, as the
//! deblurring reads it). With the measured kernel K standing in for the truth, a photo
//! X blurred by K and restored with the predicted kernel K̂ is W(K̂)·K·X, where
//! W(K) = K̄ / (|K|² + nsr·|D|²) is the regularised Wiener filter (the quadratic cousin
//! of the deblurring's hyper-Laplacian prior, `deblur::WienerParams`) and D the
//! gradient; restored with K itself it is W(K)·K·X. A natural photo's gradients have
//! about the same power at every frequency, |X|² = 1 / |D|². The error energy per
//! pixel the prediction adds, for a photo of unit gradient power, is then
//! (1 / F²) Σ_{ω ≠ 0} |W(K̂)·K − W(K)·K|² / |D|² over an F × F grid of frequencies.
//!
//! To first order in Δ = K̂ − K the difference is |W(K)|·|Δ|: a kernel centred a
//! little off, which moves the whole photo, weighs by the photo's gradients, and an
//! error where the deconvolution cannot lift the kernel above its regularisation
//! weighs little. Far from first order (a Gaussian standing for a sharp core with a
//! halo) the difference stays bounded, as the restored photo does.

use crate::fft::Fft2;
use crate::psf::Kernel;
use rustfft::num_complex::Complex64;

/// Frequencies per 1× sample of the kernel along each axis: the sum over them stands
/// for an integral whose weight grows as 1/|ω|² towards ω = 0, so one frequency per
/// sample (the DFT's own grid) is too coarse for wide kernels.
const FREQUENCY_OVERSAMPLING: usize = 2;

/// The regularised Wiener filter's noise-to-signal ratio per unit gradient energy:
/// the deblurring's default (`deblur::WienerParams`) and what the restoration error
/// models the deconvolution with.
pub const WIENER_NSR: f64 = 0.003;

/// The restoration error of kernels predicted on one measured kernel's grid, prepared
/// once per measured kernel: its 1× spectrum and the weight of every frequency.
pub struct RestorationError {
    fft: Fft2,
    /// The measured kernel's side at its own oversampling.
    grid: usize,
    /// The 1× kernel's side.
    side: usize,
    /// Per 1× sample (row-major, centre at `side / 2`): its index in the 3× grid.
    taps: Vec<usize>,
    /// Per half-spectrum entry: 1 / |D|² times the entry's multiplicity in the full
    /// spectrum, over F²; zero at ω = 0, where both kernels are 1.
    weight: Vec<f64>,
    /// Per half-spectrum entry: the regularisation nsr·|D|².
    regularisation: Vec<f64>,
    /// The measured 1× kernel's spectrum, normalised to 1 at ω = 0.
    measured: Vec<Complex64>,
    /// Per half-spectrum entry: W(K)·K, the restoration's response with the measured
    /// kernel itself.
    response: Vec<f64>,
    /// Scratch: the F × F block a spectrum is taken of.
    block: Vec<f64>,
}

impl RestorationError {
    /// Prepares `measured` (an odd-sized 3× kernel, or any oversampling) with the
    /// deconvolution's `nsr`. `None` when its 1× samples do not sum above zero.
    #[must_use]
    pub fn new(measured: &Kernel, nsr: f64) -> Option<Self> {
        let (size, os) = (measured.size, measured.oversample.max(1));
        let c = size / 2;
        let half = c / os;
        let side = 2 * half + 1;
        let taps: Vec<usize> = (0..side)
            .flat_map(|j| {
                (0..side).map(move |i| (c + j * os - half * os) * size + c + i * os - half * os)
            })
            .collect();
        let f = crate::fft::good_size(FREQUENCY_OVERSAMPLING * side);
        let fft = Fft2::new(f, f);
        let mut me = Self {
            grid: size,
            side,
            taps,
            weight: Vec::new(),
            regularisation: Vec::new(),
            measured: fft.new_spectrum(),
            response: Vec::new(),
            block: vec![0.0; f * f],
            fft,
        };
        let samples = me.samples(&measured.data);
        let spectrum = me.spectrum_of(&samples);
        let dc = spectrum[0].re;
        if dc <= 0.0 || !dc.is_finite() {
            return None;
        }
        me.measured = spectrum.iter().map(|v| v / dc).collect();
        let gradient = me.fft.gradient_energy();
        let (rows, f2) = (f, (f * f) as f64);
        me.weight = gradient
            .iter()
            .enumerate()
            .map(|(e, &g)| {
                let col = e / rows;
                if g <= 0.0 {
                    return 0.0;
                }
                let multiplicity = if col == 0 || 2 * col == f { 1.0 } else { 2.0 };
                multiplicity / g / f2
            })
            .collect();
        me.regularisation = gradient.iter().map(|g| nsr * g).collect();
        me.response = me
            .measured
            .iter()
            .zip(&me.regularisation)
            .map(|(m, r)| {
                let k2 = m.norm_sqr();
                k2 / (k2 + r)
            })
            .collect();
        Some(me)
    }

    /// The error of the kernel whose 3× values on the measured kernel's grid, before
    /// clipping at zero and normalising, are `values`:
    /// E = (1/F²) Σ |W(K̂)·K − W(K)·K|² / |D|², the error energy per pixel it adds to a
    /// restored photo of unit gradient power. NaN when the predicted 1× kernel has no
    /// positive mass.
    pub fn of_values(&mut self, values: &[f64]) -> f64 {
        let mut samples = self.samples(values);
        for v in &mut samples {
            *v = v.max(0.0);
        }
        let spectrum = self.spectrum_of(&samples);
        self.of_spectrum(&spectrum)
    }

    /// [`Self::of_values`] of a rendered kernel on the measured kernel's grid.
    ///
    /// # Panics
    /// If `predicted` is not on that grid.
    pub fn of_kernel(&mut self, predicted: &Kernel) -> f64 {
        assert_eq!(
            predicted.size, self.grid,
            "a kernel on the measured kernel's grid"
        );
        self.of_values(&predicted.data)
    }

    /// The 1× samples of 3× `values` (row-major, centre at `side / 2`), unclipped.
    pub(crate) fn samples(&self, values: &[f64]) -> Vec<f64> {
        self.taps
            .iter()
            .map(|&t| values.get(t).copied().unwrap_or(0.0))
            .collect()
    }

    /// The half spectrum of 1× `samples` (from [`Self::samples`]), centred at (0, 0).
    /// Linear in the samples: the spectrum of a sum of kernels is the sum of theirs.
    pub(crate) fn spectrum_of(&mut self, samples: &[f64]) -> Vec<Complex64> {
        let (side, half, f) = (self.side, self.side / 2, self.fft.width());
        // Only the taps' places are ever written, so the rest stays zero.
        for (n, &v) in samples.iter().enumerate() {
            let (i, j) = (n % side, n / side);
            self.block[((j + f - half) % f) * f + (i + f - half) % f] = v;
        }
        let mut spectrum = self.fft.new_spectrum();
        self.fft.forward(&self.block, &mut spectrum);
        spectrum
    }

    /// [`Self::of_values`] of a kernel whose 1× samples are all ≥ 0 (so nothing is
    /// clipped), given their half spectrum. NaN when they do not sum above zero.
    pub(crate) fn of_spectrum(&self, spectrum: &[Complex64]) -> f64 {
        let dc = spectrum[0].re;
        if dc <= 0.0 || !dc.is_finite() {
            return f64::NAN;
        }
        let inv_dc = 1.0 / dc;
        let mut sum = 0.0;
        for ((((p, m), r), w), t) in spectrum
            .iter()
            .zip(&self.measured)
            .zip(&self.regularisation)
            .zip(&self.weight)
            .zip(&self.response)
        {
            let p = p * inv_dc;
            let restored = p.conj() * m / (p.norm_sqr() + r);
            sum += w * (restored - t).norm_sqr();
        }
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::Gaussian2;

    fn gaussian(sigma: f64, dx: f64) -> Kernel {
        Kernel::from_fn(61, 3, |x, y| {
            Gaussian2 {
                sigma_x: sigma,
                sigma_y: sigma,
                rho: 0.0,
            }
            .density(x - dx, y)
        })
    }

    #[test]
    fn the_measured_kernel_itself_leaves_no_error() {
        let k = gaussian(1.2, 0.0);
        let mut e = RestorationError::new(&k, WIENER_NSR).expect("prepared");
        assert!(e.of_kernel(&k) < 1e-24);
        // Scale does not matter: values are normalised as the kernel is.
        let scaled: Vec<f64> = k.data.iter().map(|v| 7.0 * v).collect();
        assert!(e.of_values(&scaled) < 1e-24);
    }

    /// The restored photo's error energy per pixel over its gradient power, when a
    /// periodic photo whose gradients are white noise is blurred by `truth` and
    /// deconvolved by the Wiener filter with `predicted` instead of `truth`.
    fn wiener_error(truth: &Kernel, predicted: &Kernel) -> f64 {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let n = 128;
        let mut fft = Fft2::new(n, n);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let normal = Normal::new(0.0, 1.0).expect("normal");
        let noise: Vec<f64> = (0..n * n).map(|_| normal.sample(&mut rng)).collect();
        let mut x = fft.new_spectrum();
        fft.forward(&noise, &mut x);
        let g = fft.gradient_energy();
        let (k, k_hat) = (
            fft.otf(&truth.resampled(1)),
            fft.otf(&predicted.resampled(1)),
        );
        let nsr = WIENER_NSR;
        let wiener = |o: Complex64, g: f64| o.conj() / (o.norm_sqr() + nsr * g);
        let (mut err, mut grad) = (0.0, 0.0);
        for e in 0..x.len() {
            if g[e] <= 0.0 {
                continue;
            }
            // The photo: white gradients, |X|² = |noise|² / |D|².
            let xe = x[e] / g[e].sqrt();
            let col = e / n;
            let m = if col == 0 || 2 * col == n { 1.0 } else { 2.0 };
            let diff = (wiener(k_hat[e], g[e]) - wiener(k[e], g[e])) * k[e] * xe;
            err += m * diff.norm_sqr();
            grad += m * g[e] * xe.norm_sqr();
        }
        err / grad
    }

    #[test]
    fn a_shift_costs_what_a_deconvolved_photo_shows() {
        // The criterion on its own coarse grid of frequencies is what deconvolving a
        // photo of white gradients shows on a fine one.
        let k = gaussian(0.8, 0.0);
        let mut e = RestorationError::new(&k, WIENER_NSR).expect("prepared");
        for d in [0.05, 0.1] {
            let shifted = gaussian(0.8, d);
            let (criterion, photo) = (e.of_kernel(&shifted), wiener_error(&k, &shifted));
            assert!(
                (criterion / photo - 1.0).abs() < 0.03,
                "{d} px: criterion {criterion}, photo {photo}"
            );
        }
        // Twice the shift, about four times the error.
        let ratio = e.of_kernel(&gaussian(0.8, 0.1)) / e.of_kernel(&gaussian(0.8, 0.05));
        assert!((ratio - 4.0).abs() < 0.1, "ratio {ratio}");
    }

    #[test]
    fn a_wrong_width_costs_what_a_deconvolved_photo_shows() {
        for sigma in [0.6, 1.5, 2.4] {
            let k = gaussian(sigma, 0.0);
            let mut e = RestorationError::new(&k, WIENER_NSR).expect("prepared");
            for wrong in [gaussian(sigma * 1.1, 0.0), gaussian(sigma * 0.5, 0.0)] {
                let (criterion, photo) = (e.of_kernel(&wrong), wiener_error(&k, &wrong));
                assert!(
                    (criterion / photo - 1.0).abs() < 0.05,
                    "σ {sigma}: criterion {criterion}, photo {photo}"
                );
            }
        }
    }
}
