//! A virtual zoom lens: smooth, asymmetric fields of σx, σy and ρ over the sensor
//! position (x, y), focal length f and aperture a, per colour channel.
//!
//! The fields are built so they look like the paper's measurements: blur grows toward
//! the corners but neither radially nor left–right symmetrically, varies slowly and
//! smoothly with f and a, differs by channel, and spans σ ≈ 0.7–3 px of *optical* blur
//! over the calibrated range. Positions are normalised, u = 2x/(W−1) − 1 and
//! v = 2y/(H−1) − 1, so a lens applies to any sensor size.

use super::distortion::LensGeometry;
use crate::plane::{Channel, LensSetting};
use crate::psf::{Gaussian2, Kernel};
use serde::{Deserialize, Serialize};

/// The PSF family the lens draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PsfShape {
    /// A 2-D Gaussian with the field's σx, σy, ρ.
    #[default]
    Gaussian,
    /// A defocus disc (uniform ellipse) with the field's second moments.
    Disc,
    /// A coma-like comet: a bright core with a tail pointing away from the centre, with
    /// (about) the field's second moments.
    Comet,
}

/// Coefficients of one channel's fields; see [`VirtualLens::gaussian`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelField {
    pub channel: Channel,
    /// Overall scale of this channel's blur.
    pub scale: f64,
    /// Where the field is sharpest, in normalised (u, v): the lens is decentred.
    pub sweet_spot: [f64; 2],
    /// Anisotropy of the corner blur: σx gains `1 + aniso`, σy `1 − aniso`, along u.
    pub aniso: f64,
    /// Correlation amplitude (|ρ| stays below it).
    pub rho_amp: f64,
    /// Phase of the correlation pattern.
    pub rho_phase: f64,
}

/// A virtual lens. `focal_range_mm` and `f_number_range` are the settings it can take.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VirtualLens {
    pub name: String,
    pub make: String,
    pub model: String,
    pub serial: String,
    pub focal_range_mm: [f64; 2],
    pub f_number_range: [f64; 2],
    pub shape: PsfShape,
    pub channels: Vec<ChannelField>,
    /// Distortion, lateral colour and vignetting; none unless described.
    #[serde(default)]
    pub geometry: LensGeometry,
}

impl VirtualLens {
    /// The built-in demo lens: a 24–105 mm f/4 zoom with soft, decentred corners.
    #[must_use]
    pub fn demo() -> Self {
        Self {
            name: "demo".into(),
            make: "Virtual".into(),
            model: "VZ 24-105mm f/4".into(),
            serial: "VZ-0001".into(),
            focal_range_mm: [24.0, 105.0],
            f_number_range: [4.0, 10.0],
            shape: PsfShape::Gaussian,
            channels: vec![
                ChannelField {
                    channel: Channel::R,
                    scale: 1.06,
                    sweet_spot: [0.10, -0.06],
                    aniso: 0.22,
                    rho_amp: 0.45,
                    rho_phase: 0.3,
                },
                ChannelField {
                    channel: Channel::G,
                    scale: 0.94,
                    sweet_spot: [0.08, -0.04],
                    aniso: 0.18,
                    rho_amp: 0.40,
                    rho_phase: 0.1,
                },
                ChannelField {
                    channel: Channel::B,
                    scale: 1.12,
                    sweet_spot: [0.12, -0.08],
                    aniso: 0.26,
                    rho_amp: 0.48,
                    rho_phase: -0.2,
                },
            ],
            geometry: LensGeometry::default(),
        }
    }

    /// A second copy of the same model: same design, different decentring and
    /// tilt, as the paper's two Canon 17–40 mm units.
    #[must_use]
    pub fn demo_second_unit() -> Self {
        let mut l = Self::demo();
        l.serial = "VZ-0002".into();
        for c in &mut l.channels {
            c.sweet_spot = [-c.sweet_spot[0] * 1.5, c.sweet_spot[1] + 0.15];
            c.aniso = -c.aniso * 0.8;
            c.rho_phase += 1.1;
        }
        l
    }

    /// Reads a lens description (the JSON form of this struct) and checks it.
    ///
    /// # Errors
    /// Unreadable file, malformed JSON, or a lens [`VirtualLens::validate`] refuses.
    pub fn load(path: &std::path::Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
        let lens: Self = serde_json::from_str(&text)
            .map_err(|e| format!("{}: not a lens description: {e}", path.display()))?;
        lens.validate()
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(lens)
    }

    /// Checks that the lens can be simulated: increasing positive ranges, a field for
    /// every colour, finite positive scales, |ρ amplitude| < 1.
    ///
    /// # Errors
    /// A description of the first problem.
    pub fn validate(&self) -> Result<(), String> {
        let [f0, f1] = self.focal_range_mm;
        let [a0, a1] = self.f_number_range;
        if !(f0.is_finite() && f1.is_finite() && f0 > 0.0 && f1 >= f0) {
            return Err(format!("focal range {f0}–{f1} mm is not a positive range"));
        }
        if !(a0.is_finite() && a1.is_finite() && a0 > 0.0 && a1 >= a0) {
            return Err(format!("f-number range {a0}–{a1} is not a positive range"));
        }
        for ch in [Channel::R, Channel::G, Channel::B] {
            let Some(c) = self.channels.iter().find(|c| c.channel == ch) else {
                return Err(format!("no field for channel {ch}"));
            };
            if !(c.scale.is_finite() && c.scale > 0.0 && c.scale < 20.0) {
                return Err(format!("channel {ch}: scale {} out of (0, 20)", c.scale));
            }
            if !(c.rho_amp.is_finite() && c.rho_amp.abs() < 1.0) {
                return Err(format!("channel {ch}: |rho_amp| must be below 1"));
            }
            if !(c.aniso.is_finite() && c.aniso.abs() < 0.9) {
                return Err(format!("channel {ch}: |aniso| must be below 0.9"));
            }
            if !(c.sweet_spot.iter().all(|v| v.is_finite()) && c.rho_phase.is_finite()) {
                return Err(format!("channel {ch}: non-finite coefficients"));
            }
        }
        self.geometry.validate()
    }

    /// The settings a `nf × na` calibration grid takes over this lens's range: focal
    /// lengths evenly spaced, apertures evenly spaced in stops (log f-number).
    #[must_use]
    pub fn setting_grid(&self, nf: usize, na: usize) -> Vec<LensSetting> {
        let fs = crate::plane::spaced(self.focal_range_mm[0], self.focal_range_mm[1], nf, false);
        let as_ = crate::plane::spaced(self.f_number_range[0], self.f_number_range[1], na, true);
        fs.iter()
            .flat_map(|&f| {
                as_.iter().map(move |&a| LensSetting {
                    focal_mm: f,
                    f_number: a,
                })
            })
            .collect()
    }

    fn field(&self, channel: Channel) -> &ChannelField {
        let wanted = if channel == Channel::Y {
            Channel::G
        } else {
            channel
        };
        self.channels
            .iter()
            .find(|c| c.channel == wanted)
            .unwrap_or(&self.channels[0])
    }

    /// Normalised focal and aperture coordinates in [0, 1] over the lens's range
    /// (aperture on a log scale, as stops).
    #[must_use]
    pub fn setting_coords(&self, s: LensSetting) -> (f64, f64) {
        let [f0, f1] = self.focal_range_mm;
        let [a0, a1] = self.f_number_range;
        let tf = ((s.focal_mm - f0) / (f1 - f0)).clamp(0.0, 1.0);
        let ta = ((s.f_number.ln() - a0.ln()) / (a1.ln() - a0.ln())).clamp(0.0, 1.0);
        (tf, ta)
    }

    /// The optical (pre-pixel) Gaussian of `channel` at normalised sensor position
    /// (u, v) ∈ [−1, 1]² for a setting.
    #[must_use]
    pub fn gaussian_uv(&self, channel: Channel, u: f64, v: f64, s: LensSetting) -> Gaussian2 {
        let c = self.field(channel);
        let (tf, ta) = self.setting_coords(s);
        let (du, dv) = (u - c.sweet_spot[0], v - c.sweet_spot[1]);
        // Off-axis aberration: grows toward the corners, stronger on the right and
        // bottom (odd terms), with a saddle; every term is a low-order polynomial in
        // (u, v) times smooth functions of f and a.
        let r2 = du * du + dv * dv;
        let off_axis =
            0.55 * r2 + 0.18 * du * du * du + 0.12 * dv * dv * dv - 0.10 * du * dv + 0.10 * r2 * r2;
        // Wide end and wide open are worst; stopping down helps, with diffraction
        // slowly adding back at small apertures.
        let zoom = 0.75 + 0.5 * (tf - 0.45).powi(2) * 2.0;
        let stop = 1.0 - 0.45 * ta + 0.12 * ta * ta;
        let centre = 0.62 + 0.10 * tf + 0.10 * ta * ta;
        let amount = (zoom * stop * off_axis.max(0.0)).max(0.0);
        let sx = c.scale * (centre + amount * (1.0 + c.aniso * (0.6 + 0.4 * u)));
        let sy = c.scale * (centre + amount * (1.0 - c.aniso * (0.6 + 0.4 * v)) * (1.0 + 0.15 * v));
        let rho =
            c.rho_amp * (1.3 * du * dv + c.rho_phase * 0.3 * u + 0.25 * (tf - 0.5) * du).tanh();
        Gaussian2 {
            sigma_x: sx,
            sigma_y: sy,
            rho,
        }
    }

    /// Normalised position of sensor pixel (x, y) on a `width × height` sensor.
    #[must_use]
    pub fn normalised(x: f64, y: f64, width: usize, height: usize) -> (f64, f64) {
        (
            2.0 * x / (width as f64 - 1.0) - 1.0,
            2.0 * y / (height as f64 - 1.0) - 1.0,
        )
    }

    /// The optical Gaussian at sensor pixel (x, y).
    #[must_use]
    pub fn gaussian_at(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        width: usize,
        height: usize,
        s: LensSetting,
    ) -> Gaussian2 {
        let (u, v) = Self::normalised(x, y, width, height);
        self.gaussian_uv(channel, u, v, s)
    }

    /// The optical PSF at (u, v) sampled at `oversample`× (point samples, sum 1),
    /// in this lens's shape. Its second moments are those of [`Self::gaussian_uv`]
    /// for every shape (the comet's only approximately).
    #[must_use]
    pub fn optical_kernel_uv(
        &self,
        channel: Channel,
        u: f64,
        v: f64,
        s: LensSetting,
        oversample: usize,
    ) -> Kernel {
        let g = self.gaussian_uv(channel, u, v, s);
        match self.shape {
            PsfShape::Gaussian => g.kernel(oversample),
            PsfShape::Disc => {
                // A uniform ellipse with covariance Σ has Σ = R Rᵀ / 4 for the ellipse
                // {p : pᵀ (4Σ)⁻¹ p ≤ 1}; sampled with a soft edge to limit aliasing.
                let (a, b, c) = (
                    g.sigma_x.powi(2) * 4.0,
                    g.sigma_y.powi(2) * 4.0,
                    g.cov_xy() * 4.0,
                );
                let det = a * b - c * c;
                let half =
                    ((2.0 * g.sigma_x.max(g.sigma_y) + 1.0) * oversample as f64).ceil() as usize;
                let edge = 0.5 / oversample as f64;
                Kernel::from_fn(2 * half + 1, oversample, |dx, dy| {
                    let q = (b * dx * dx - 2.0 * c * dx * dy + a * dy * dy) / det;
                    let r = q.sqrt();
                    let scale = (a.max(b)).sqrt();
                    ((1.0 - r) * scale / edge + 0.5).clamp(0.0, 1.0)
                })
            }
            PsfShape::Comet => {
                // Core plus a tail along the radial direction: a sum of Gaussians along
                // the tail, tapered; the whole then has roughly the field's moments.
                let (ru, rv) = {
                    let n = (u * u + v * v).sqrt().max(1e-6);
                    (u / n, v / n)
                };
                let core = Gaussian2 {
                    sigma_x: 0.7 * g.sigma_x,
                    sigma_y: 0.7 * g.sigma_y,
                    rho: g.rho,
                };
                let tail_len = 1.6 * g.sigma_x.max(g.sigma_y);
                let half = ((3.0 * g.sigma_x.max(g.sigma_y) + tail_len + 1.0) * oversample as f64)
                    .ceil() as usize;
                Kernel::from_fn(2 * half + 1, oversample, |dx, dy| {
                    let mut acc = core.density(dx, dy);
                    for k in 1..=6 {
                        let t = tail_len * f64::from(k) / 6.0;
                        let w = 0.35 * (1.0 - f64::from(k) / 7.0);
                        let spread = Gaussian2 {
                            sigma_x: core.sigma_x * (1.0 + 0.12 * f64::from(k)),
                            sigma_y: core.sigma_y * (1.0 + 0.12 * f64::from(k)),
                            rho: core.rho,
                        };
                        acc += w * spread.density(dx - t * ru, dy - t * rv);
                    }
                    acc
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(l: &VirtualLens) -> Vec<LensSetting> {
        let mut v = Vec::new();
        for &f in &[l.focal_range_mm[0], l.focal_range_mm[1]] {
            for &a in &[l.f_number_range[0], l.f_number_range[1]] {
                v.push(LensSetting {
                    focal_mm: f,
                    f_number: a,
                });
            }
        }
        v
    }

    #[test]
    fn demo_lens_spans_the_intended_blur_range() {
        let l = VirtualLens::demo();
        let (mut lo, mut hi, mut rho_max) = (f64::MAX, 0.0f64, 0.0f64);
        for s in settings(&l) {
            for ch in [Channel::R, Channel::G, Channel::B] {
                for j in 0..=10 {
                    for i in 0..=10 {
                        let g = l.gaussian_uv(
                            ch,
                            -1.0 + 0.2 * f64::from(i),
                            -1.0 + 0.2 * f64::from(j),
                            s,
                        );
                        lo = lo.min(g.sigma_x.min(g.sigma_y));
                        hi = hi.max(g.sigma_x.max(g.sigma_y));
                        rho_max = rho_max.max(g.rho.abs());
                    }
                }
            }
        }
        assert!((0.55..=0.8).contains(&lo), "smallest σ {lo}");
        assert!((2.5..=3.3).contains(&hi), "largest σ {hi}");
        assert!((0.3..=0.5).contains(&rho_max), "largest |ρ| {rho_max}");
    }

    #[test]
    fn demo_lens_is_not_symmetric() {
        let l = VirtualLens::demo();
        let s = LensSetting {
            focal_mm: 24.0,
            f_number: 4.0,
        };
        let left = l.gaussian_uv(Channel::G, -0.9, 0.0, s);
        let right = l.gaussian_uv(Channel::G, 0.9, 0.0, s);
        let top = l.gaussian_uv(Channel::G, 0.0, -0.9, s);
        assert!(
            (left.sigma_x - right.sigma_x).abs() > 0.1,
            "left–right symmetric"
        );
        assert!(
            (top.sigma_x - right.sigma_x).abs() > 0.1,
            "radially symmetric"
        );
    }

    #[test]
    fn shapes_keep_the_field_moments() {
        let mut l = VirtualLens::demo();
        let s = LensSetting {
            focal_mm: 50.0,
            f_number: 5.6,
        };
        for shape in [PsfShape::Gaussian, PsfShape::Disc] {
            l.shape = shape;
            let g = l.gaussian_uv(Channel::G, 0.7, -0.6, s);
            let m = l.optical_kernel_uv(Channel::G, 0.7, -0.6, s, 5).moments();
            assert!(
                (m.var_x.sqrt() / g.sigma_x - 1.0).abs() < 0.05,
                "{shape:?} σx {} vs {}",
                m.var_x.sqrt(),
                g.sigma_x
            );
            assert!(
                (m.var_y.sqrt() / g.sigma_y - 1.0).abs() < 0.05,
                "{shape:?} σy"
            );
        }
    }
}
