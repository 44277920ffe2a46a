//! Physically based PSFs: a Seidel wavefront through a slightly imperfect pupil,
//! PSF = |FT(P · exp(i 2π W))|², sampled onto a kernel grid.
//!
//! The wavefront, in waves, at normalised pupil position ρ (|ρ| ≤ 1) for a field point
//! at normalised height h along the unit radial direction r̂:
//!
//! W = (W020 + W220 h²) ρ² + W040 ρ⁴ + W131 h ρ² (ρ·r̂) + W222 h² (ρ·r̂)²
//!
//! Coefficients are optical path differences expressed in waves of the green
//! reference wavelength at the reference f-number. At another f-number N each term
//! scales with the pupil radius to the power of its ρ exponent (W040 ∝ N⁻⁴,
//! W131 ∝ N⁻³, the ρ² terms ∝ N⁻²), and at another wavelength with 1/λ. The image
//! scale follows from Fourier optics: a pupil of diameter D samples on an M-point grid
//! gives image samples λN·D/M apart.

use crate::psf::Kernel;
use rustfft::num_complex::Complex64;
use serde::{Deserialize, Serialize};

/// Seidel wavefront coefficients in waves (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Seidel {
    /// Defocus of the whole field (the focus the camera chose).
    pub w020: f64,
    /// Spherical aberration.
    pub w040: f64,
    /// Coma.
    pub w131: f64,
    /// Field curvature (sagittal focal surface).
    pub w220: f64,
    /// Astigmatism.
    pub w222: f64,
}

impl Seidel {
    fn lerp(&self, other: &Self, t: f64) -> Self {
        let l = |a: f64, b: f64| a + (b - a) * t;
        Self {
            w020: l(self.w020, other.w020),
            w040: l(self.w040, other.w040),
            w131: l(self.w131, other.w131),
            w220: l(self.w220, other.w220),
            w222: l(self.w222, other.w222),
        }
    }

    fn all(&self) -> [f64; 5] {
        [self.w020, self.w040, self.w131, self.w220, self.w222]
    }
}

/// The optical design behind [`PsfShape::Aberrated`](super::lens::PsfShape::Aberrated).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Aberrations {
    /// Sensor pixel pitch, µm.
    pub pixel_pitch_um: f64,
    /// Wavelengths of R, G, B in µm; G's is the one the coefficients are given in.
    pub wavelength_um: [f64; 3],
    /// The f-number the coefficients are given at.
    pub reference_f_number: f64,
    /// Coefficients at the short end of the zoom.
    pub wide: Seidel,
    /// Coefficients at the long end; in between they are interpolated linearly.
    pub tele: Seidel,
    /// Extra defocus of R, G, B in waves at the reference f-number: longitudinal colour.
    pub chromatic_defocus: [f64; 3],
    /// Relative difference of the pupil's semi-axes (0 = circular).
    pub pupil_ellipticity: f64,
    /// Direction of the pupil's longer semi-axis, radians.
    pub pupil_angle_rad: f64,
    /// Offset of the aperture stop from the wavefront's axis, in pupil radii: with
    /// spherical aberration it adds a little coma everywhere, so no point is perfectly
    /// symmetric.
    pub pupil_decentre: [f64; 2],
    /// Width of the pupil's soft edge as a fraction of its radius: the amplitude falls
    /// as a raised cosine to zero at the rim. A hard edge's diffraction halo falls only
    /// as r⁻³, so the second moments of its PSF would grow with the kernel's window;
    /// a real camera's colour bands and the sensor's angular response soften it.
    pub pupil_edge_taper: f64,
}

impl Default for Aberrations {
    /// A 24–105 mm f/4 zoom on a 4.3 µm sensor: soft, comatic, astigmatic corners wide
    /// open at the wide end, some spherical halo everywhere at f/4, close to the
    /// diffraction limit stopped down.
    fn default() -> Self {
        Self {
            pixel_pitch_um: 4.3,
            wavelength_um: [0.61, 0.53, 0.46],
            reference_f_number: 4.0,
            wide: Seidel {
                w020: -1.3,
                w040: 2.2,
                w131: 4.8,
                w220: 2.7,
                w222: 3.5,
            },
            tele: Seidel {
                w020: -1.1,
                w040: 1.8,
                w131: 2.7,
                w220: 1.5,
                w222: 1.9,
            },
            chromatic_defocus: [0.4, 0.0, -0.5],
            pupil_ellipticity: 0.04,
            pupil_angle_rad: 0.6,
            pupil_decentre: [0.012, -0.008],
            pupil_edge_taper: 1.0,
        }
    }
}

/// Largest kernel half-width, pixels: beyond it the halo is cut off (and the FFT
/// stays a reasonable size whatever a lens file says).
const MAX_RADIUS_PX: f64 = 24.0;
/// Fewest pupil samples across the diameter: fewer and the pupil's edge is too coarse
/// for its diffraction ring to be right.
const MIN_PUPIL_SAMPLES: f64 = 24.0;
/// Period of the computed amplitude over the kernel's width: the halo that wraps
/// around the period lands outside the kernel's window.
const PERIOD_OVER_WIDTH: f64 = 1.25;

impl Aberrations {
    /// Checks the design can be simulated.
    ///
    /// # Errors
    /// A description of the first problem.
    pub fn validate(&self) -> Result<(), String> {
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !(self.pixel_pitch_um.is_finite() && (0.5..=50.0).contains(&self.pixel_pitch_um)) {
            return Err(format!(
                "aberrations: pixel pitch {} µm out of 0.5–50",
                self.pixel_pitch_um
            ));
        }
        if !self.wavelength_um.iter().all(|l| (0.2..=2.0).contains(l)) {
            return Err("aberrations: wavelengths must be 0.2–2 µm".into());
        }
        if !(self.reference_f_number.is_finite() && (0.5..=64.0).contains(&self.reference_f_number))
        {
            return Err("aberrations: reference f-number out of 0.5–64".into());
        }
        for s in [&self.wide, &self.tele] {
            if !s.all().iter().all(|w| w.is_finite() && w.abs() <= 10.0) {
                return Err(
                    "aberrations: Seidel coefficients must be finite, |w| ≤ 10 waves".into(),
                );
            }
        }
        if !self
            .chromatic_defocus
            .iter()
            .all(|w| w.is_finite() && w.abs() <= 10.0)
        {
            return Err("aberrations: chromatic defocus must be finite, |w| ≤ 10 waves".into());
        }
        if !(self.pupil_ellipticity.is_finite() && self.pupil_ellipticity.abs() < 0.5) {
            return Err("aberrations: |pupil ellipticity| must be below 0.5".into());
        }
        if !(self.pupil_edge_taper.is_finite() && (0.0..=1.0).contains(&self.pupil_edge_taper)) {
            return Err("aberrations: pupil edge taper must be 0–1".into());
        }
        if !(finite(&self.pupil_decentre)
            && self.pupil_angle_rad.is_finite()
            && self.pupil_decentre[0].hypot(self.pupil_decentre[1]) < 0.3)
        {
            return Err("aberrations: pupil decentre must be finite and below 0.3".into());
        }
        Ok(())
    }

    /// The wavefront (waves at this channel's wavelength) of channel `ci` (0 = R,
    /// 1 = G, 2 = B) at field offset (du, dv) from the aberration centre, in normalised
    /// sensor coordinates, focal position `tf` ∈ [0, 1], f-number `f_number`.
    #[must_use]
    pub fn wavefront(&self, ci: usize, du: f64, dv: f64, tf: f64, f_number: f64) -> Wavefront {
        let s = self.wide.lerp(&self.tele, tf.clamp(0.0, 1.0));
        let waves = self.wavelength_um[1] / self.wavelength_um[ci];
        let k = self.reference_f_number / f_number;
        let (k2, k3, k4) = (k * k, k * k * k, k * k * k * k);
        // The corner of a 3:2 frame is at |(u, v)| = √2: the Seidel field height 1.
        let r = du.hypot(dv);
        let h = r / std::f64::consts::SQRT_2;
        let radial = if r > 1e-9 {
            [du / r, dv / r]
        } else {
            [1.0, 0.0]
        };
        Wavefront {
            defocus: waves * k2 * (s.w020 + self.chromatic_defocus[ci] + s.w220 * h * h),
            spherical: waves * k4 * s.w040,
            coma: waves * k3 * s.w131 * h,
            astigmatism: waves * k2 * s.w222 * h * h,
            radial,
        }
    }

    /// The optical PSF of channel `ci` at field offset (du, dv), focal position `tf`,
    /// f-number `f_number`, as a kernel at `oversample`× (cell integrals, sum 1).
    #[must_use]
    pub fn kernel(
        &self,
        ci: usize,
        du: f64,
        dv: f64,
        tf: f64,
        f_number: f64,
        oversample: usize,
    ) -> Kernel {
        // Outside any real lens's range the FFT would only grow or the pupil vanish.
        let f_number = if f_number.is_finite() {
            f_number.clamp(0.5, 64.0)
        } else {
            self.reference_f_number
        };
        let ci = ci.min(2);
        let w = self.wavefront(ci, du, dv, tf, f_number);
        // λN in pixels: the diffraction scale.
        let lambda_n = self.wavelength_um[ci] * f_number / self.pixel_pitch_um;
        self.render(&w, lambda_n, oversample.max(1))
    }

    fn render(&self, w: &Wavefront, lambda_n: f64, oversample: usize) -> Kernel {
        // A ray through pupil point ρ lands 2N·λ·∇W(ρ) from the chief ray, so this
        // bounds the geometric spot; the diffraction halo needs a few λN more.
        let slope = 2.0 * (w.defocus.abs() + w.astigmatism.abs())
            + 4.0 * w.spherical.abs()
            + 3.0 * w.coma.abs();
        let radius = (2.0 * lambda_n * slope * 1.1 + 5.0 * lambda_n + 1.0).min(MAX_RADIUS_PX);
        let os = oversample as f64;
        // Fine samples per kernel cell (odd, so cells stay centred): fine enough that
        // the intensity, band-limited to 1/(λN), is sampled at least twice per period.
        let mut sub = 1usize;
        while 1.0 / (os * sub as f64) > lambda_n / 2.0 && sub < 9 {
            sub += 2;
        }
        let dx = 1.0 / (os * sub as f64);
        let half = (radius * os).ceil() as usize;
        let fine_half = half * sub + sub / 2;
        let width_px = (2 * fine_half + 1) as f64 * dx;
        let period_px = (width_px * PERIOD_OVER_WIDTH).max(MIN_PUPIL_SAMPLES * lambda_n);
        let m = crate::fft::good_size((period_px / dx).ceil() as usize);
        // Pupil diameter in samples, from the sample spacing dx = λN·D/M.
        let diameter = m as f64 * dx / lambda_n;
        let field = self.pupil_field(w, m, diameter);
        let fine = amplitude_to_intensity(field, m, fine_half);
        let size = 2 * half + 1;
        let fsize = 2 * fine_half + 1;
        let mut data = vec![0.0; size * size];
        for (j, row) in fine.chunks_exact(fsize).enumerate() {
            let b = j / sub;
            for (i, &v) in row.iter().enumerate() {
                data[b * size + i / sub] += v;
            }
        }
        let mut k = Kernel {
            size,
            oversample,
            data,
        };
        k.normalise();
        k
    }

    /// P · exp(i 2π W) on an `m × m` grid, the pupil `diameter` samples across; only
    /// the rows the pupil touches are non-zero.
    fn pupil_field(&self, w: &Wavefront, m: usize, diameter: f64) -> PupilField {
        let r_px = diameter / 2.0;
        let e = self.pupil_ellipticity;
        let (sa, ca) = self.pupil_angle_rad.sin_cos();
        let [ox, oy] = self.pupil_decentre;
        let extent = (r_px * (1.0 + e.abs() + ox.hypot(oy)) + 2.0).ceil() as usize;
        let n_rows = (2 * extent + 1).min(m);
        let c = (n_rows / 2) as f64;
        let mut data = vec![Complex64::new(0.0, 0.0); n_rows * m];
        // Soft edge one sample wide, so the aperture's area (and so the PSF) changes
        // smoothly with the sampling.
        let edge = 1.0 / r_px;
        let taper = self.pupil_edge_taper.max(1e-9);
        for j in 0..n_rows {
            let py = (j as f64 - c) / r_px;
            for i in 0..n_rows.min(m) {
                let px = (i as f64 - c) / r_px;
                // The aperture: an ellipse, decentred from the wavefront's axis.
                let (qx, qy) = (px - ox, py - oy);
                let (a, b) = (ca * qx + sa * qy, -sa * qx + ca * qy);
                let re = ((a / (1.0 + e)).powi(2) + (b / (1.0 - e)).powi(2)).sqrt();
                let cover = ((1.0 - re) / edge + 0.5).clamp(0.0, 1.0);
                if cover == 0.0 {
                    continue;
                }
                let cover = if re > 1.0 - taper {
                    let t = ((re - (1.0 - taper)) / taper).min(1.0);
                    cover * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
                } else {
                    cover
                };
                let rho2 = px * px + py * py;
                let along = px * w.radial[0] + py * w.radial[1];
                let wave = w.defocus * rho2
                    + w.spherical * rho2 * rho2
                    + w.coma * rho2 * along
                    + w.astigmatism * along * along;
                let (s, c) = (std::f64::consts::TAU * wave).sin_cos();
                data[j * m + i] = Complex64::new(cover * c, cover * s);
            }
        }
        PupilField { data }
    }
}

/// The wavefront of one field point and setting, in waves of its wavelength.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wavefront {
    /// ρ² coefficient (focus, field curvature, colour).
    pub defocus: f64,
    /// ρ⁴ coefficient.
    pub spherical: f64,
    /// ρ² (ρ·r̂) coefficient.
    pub coma: f64,
    /// (ρ·r̂)² coefficient.
    pub astigmatism: f64,
    /// Unit radial direction of the field point in the sensor plane (x right, y down).
    pub radial: [f64; 2],
}

struct PupilField {
    /// `n_rows × m`, the pupil in its top-left `n_rows × n_rows` corner.
    data: Vec<Complex64>,
}

/// |FT|² of the pupil field at image offsets −half…half samples on each axis
/// (row-major, `(2 half + 1)²`). The pupil's position in the grid only multiplies the
/// amplitude by a phase ramp, so it does not move the PSF.
fn amplitude_to_intensity(mut field: PupilField, m: usize, half: usize) -> Vec<f64> {
    let fft = crate::fft::complex_forward_plan::<f64>(m);
    let mut scratch = vec![Complex64::new(0.0, 0.0); fft.get_inplace_scratch_len()];
    for row in field.data.chunks_exact_mut(m) {
        fft.process_with_scratch(row, &mut scratch);
    }
    let size = 2 * half + 1;
    let half = half.min((m - 1) / 2);
    let mut out = vec![0.0; size * size];
    let mut col = vec![Complex64::new(0.0, 0.0); m];
    let off = (size - (2 * half + 1)) / 2;
    for kx in 0..m {
        // Frequency index kx is image offset kx (or kx − m): keep only the window.
        let x = if kx <= half {
            kx as isize
        } else if kx >= m - half {
            kx as isize - m as isize
        } else {
            continue;
        };
        col.iter_mut().for_each(|c| *c = Complex64::new(0.0, 0.0));
        for (c, row) in col.iter_mut().zip(field.data.chunks_exact(m)) {
            *c = row[kx];
        }
        fft.process_with_scratch(&mut col, &mut scratch);
        let xi = (x + half as isize) as usize + off;
        for ky in (0..=half).chain(m - half..m) {
            let y = if ky <= half {
                ky as isize
            } else {
                ky as isize - m as isize
            };
            let yi = (y + half as isize) as usize + off;
            out[yi * size + xi] = col[ky].norm_sqr();
        }
    }
    out
}
