//! A virtual zoom lens: smooth, asymmetric fields of σx, σy and ρ over the sensor
//! position (x, y), focal length f and aperture a, per colour channel.
//!
//! The fields are built so they look like the paper's measurements: blur grows toward
//! the corners but neither radially nor left–right symmetrically, varies slowly and
//! smoothly with f and a, differs by channel, and spans σ ≈ 0.7–3 px of *optical* blur
//! over the calibrated range. Positions are normalised, u = 2x/(W−1) − 1 and
//! v = 2y/(H−1) − 1, so a lens applies to any sensor size.

pub use super::aberration::{Aberrations, Seidel, Wavefront};
use super::distortion::{LensGeometry, SensorMapping};
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
    /// Diffraction through the lens's [`Aberrations`]: defocus, spherical aberration,
    /// coma and astigmatism over the field. The field's Gaussian is not used; the
    /// aberration centre is each channel's `sweet_spot`.
    Aberrated,
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
    /// The optical design [`PsfShape::Aberrated`] draws; `None` takes
    /// [`Aberrations::default`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aberrations: Option<Aberrations>,
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
            aberrations: None,
            geometry: LensGeometry::default(),
        }
    }

    /// The demo lens's ranges with physically based PSFs ([`PsfShape::Aberrated`]):
    /// comatic, astigmatic corners with a spherical halo wide open, compact and close
    /// to Gaussian stopped down.
    #[must_use]
    pub fn aberrated() -> Self {
        Self {
            name: "aberrated".into(),
            model: "VZ-A 24-105mm f/4".into(),
            serial: "VZA-0001".into(),
            shape: PsfShape::Aberrated,
            aberrations: Some(Aberrations::default()),
            ..Self::demo()
        }
    }

    /// The design [`PsfShape::Aberrated`] draws.
    #[must_use]
    pub fn aberration_design(&self) -> std::borrow::Cow<'_, Aberrations> {
        match &self.aberrations {
            Some(a) => std::borrow::Cow::Borrowed(a),
            None => std::borrow::Cow::Owned(Aberrations::default()),
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
        if let Some(a) = &self.aberrations {
            a.validate()?;
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

    /// The lens's geometry (distortion, lateral colour, vignetting) for one channel at
    /// one setting on a `width × height` sensor.
    #[must_use]
    pub fn sensor_mapping(
        &self,
        channel: Channel,
        s: LensSetting,
        width: usize,
        height: usize,
    ) -> SensorMapping {
        let (tf, ta) = self.setting_coords(s);
        self.geometry.mapping(channel, tf, ta, width, height)
    }

    /// The optical (pre-pixel) Gaussian of `channel` at normalised sensor position
    /// (u, v) ∈ [−1, 1]² for a setting. For [`PsfShape::Aberrated`] it is the second
    /// moments of the PSF itself (computed at 4×), not an analytic field.
    #[must_use]
    pub fn gaussian_uv(&self, channel: Channel, u: f64, v: f64, s: LensSetting) -> Gaussian2 {
        if self.shape == PsfShape::Aberrated {
            let m = self.aberrated_kernel_uv(channel, (u, v), s, 4).moments();
            return Gaussian2::from_covariance(m.var_x, m.var_y, m.cov_xy);
        }
        self.field_gaussian(channel, u, v, s)
    }

    fn field_gaussian(&self, channel: Channel, u: f64, v: f64, s: LensSetting) -> Gaussian2 {
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

    /// The lens's pixel-level kernel at 3× at sensor pixel (x, y): its optical PSF
    /// integrated over the pixel, moved by the lateral colour of its geometry against
    /// green ([`LensGeometry::lateral_shift_px`]). What a chart square measures there,
    /// and what blurs a photo there.
    #[must_use]
    pub fn pixel_kernel_at(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        (width, height): (usize, usize),
        s: LensSetting,
    ) -> Kernel {
        let (u, v) = Self::normalised(x, y, width, height);
        let k = self
            .optical_kernel_uv(channel, u, v, s, 3)
            .pixel_integrated();
        let centre = [(width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0];
        let [dx, dy] = self
            .geometry
            .lateral_shift_px(channel, [x - centre[0], y - centre[1]]);
        k.shifted(dx, dy)
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
        let g = self.field_gaussian(channel, u, v, s);
        match self.shape {
            PsfShape::Aberrated => self.aberrated_kernel_uv(channel, (u, v), s, oversample),
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

impl VirtualLens {
    /// The optical PSF of [`PsfShape::Aberrated`] at (u, v) at `oversample`× (cell
    /// integrals, sum 1), whatever this lens's `shape`: diffraction through
    /// [`Self::aberration_design`], centred on the channel's `sweet_spot`.
    #[must_use]
    pub fn aberrated_kernel_uv(
        &self,
        channel: Channel,
        (u, v): (f64, f64),
        s: LensSetting,
        oversample: usize,
    ) -> Kernel {
        let c = self.field(channel);
        let ci = match c.channel {
            Channel::R => 0,
            Channel::B => 2,
            Channel::G | Channel::Y => 1,
        };
        let (tf, _) = self.setting_coords(s);
        self.aberration_design().kernel(
            ci,
            u - c.sweet_spot[0],
            v - c.sweet_spot[1],
            tf,
            s.f_number,
            oversample,
        )
    }
}

/// A flat field at `setting`: an evenly lit white surface (a diffuser over the lens)
/// as a `width × height` linear plane, 0.8 at the centre and falling off as the lens's
/// vignetting does; no blur (a flat surface stays flat) and no noise.
#[must_use]
pub fn flat_field(
    lens: &VirtualLens,
    setting: LensSetting,
    width: usize,
    height: usize,
) -> crate::plane::Plane {
    let map = lens.sensor_mapping(Channel::G, setting, width, height);
    let mut plane = crate::plane::Plane::new(width, height);
    for y in 0..height {
        for x in 0..width {
            plane.data[y * width + x] = (0.8 * map.illumination([x as f64, y as f64])) as f32;
        }
    }
    plane
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

#[cfg(test)]
mod aberrated_tests {
    use super::*;

    /// Centroid, covariance, standardised third moment along the unit direction `dir`,
    /// and the Mardia kurtosis E[q²] (8 for a 2-D Gaussian) of a kernel.
    struct Shape {
        var: [f64; 3],
        skew_along: f64,
        kurtosis: f64,
        /// ‖k − g‖ / ‖k‖ for g the Gaussian with the kernel's mean and covariance.
        rel_l2: f64,
    }

    fn shape_of(k: &Kernel, dir: [f64; 2]) -> Shape {
        let m = k.moments();
        let c = (k.size / 2) as f64;
        let s = k.oversample as f64;
        let n = dir[0].hypot(dir[1]);
        let (ru, rv) = (dir[0] / n, dir[1] / n);
        let det = m.var_x * m.var_y - m.cov_xy * m.cov_xy;
        let g = Gaussian2::from_covariance(m.var_x, m.var_y, m.cov_xy);
        let (mut m2, mut m3, mut q2, mut diff, mut norm, mut gsum) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut gauss = Vec::with_capacity(k.data.len());
        for j in 0..k.size {
            for i in 0..k.size {
                let dx = (i as f64 - c) / s - m.mean_x;
                let dy = (j as f64 - c) / s - m.mean_y;
                let gv = g.density(dx, dy);
                gsum += gv;
                gauss.push(gv);
            }
        }
        for j in 0..k.size {
            for i in 0..k.size {
                let w = k.at(i, j);
                let dx = (i as f64 - c) / s - m.mean_x;
                let dy = (j as f64 - c) / s - m.mean_y;
                let a = dx * ru + dy * rv;
                m2 += w * a * a;
                m3 += w * a * a * a;
                let q = (m.var_y * dx * dx - 2.0 * m.cov_xy * dx * dy + m.var_x * dy * dy) / det;
                q2 += w * q * q;
                let gv = gauss[j * k.size + i] / gsum;
                diff += (w - gv).powi(2);
                norm += w * w;
            }
        }
        Shape {
            var: [m.var_x, m.var_y, m.cov_xy],
            skew_along: m3 / m2.powf(1.5),
            kurtosis: q2,
            rel_l2: (diff / norm).sqrt(),
        }
    }

    fn at(f_number: f64) -> LensSetting {
        LensSetting {
            focal_mm: 24.0,
            f_number,
        }
    }

    /// The bottom-right corner, and its radial direction from the aberration centre.
    fn corner(l: &VirtualLens) -> ([f64; 2], [f64; 2]) {
        let c = l.field(Channel::G).sweet_spot;
        ([1.0, 1.0], [1.0 - c[0], 1.0 - c[1]])
    }

    #[test]
    fn aberrated_psfs_are_distributions() {
        let l = VirtualLens::aberrated();
        assert!(l.validate().is_ok());
        for (ch, (u, v), a, os) in [
            (Channel::G, (1.0, 1.0), 4.0, 4),
            (Channel::B, (-1.0, 0.3), 4.0, 3),
            (Channel::R, (0.0, 0.0), 10.0, 12),
        ] {
            let k = l.optical_kernel_uv(ch, u, v, at(a), os);
            assert_eq!(k.oversample, os);
            assert_eq!(k.size % 2, 1);
            let sum: f64 = k.data.iter().sum();
            assert!((sum - 1.0).abs() < 1e-9, "{ch:?} sum {sum}");
            assert!(k.data.iter().all(|&v| v >= 0.0 && v.is_finite()));
        }
    }

    #[test]
    fn aberrated_corner_wide_open_has_an_outward_heavy_tail() {
        let l = VirtualLens::aberrated();
        let (p, radial) = corner(&l);
        let k = l.optical_kernel_uv(Channel::G, p[0], p[1], at(4.0), 4);
        let s = shape_of(&k, radial);
        // Positive along the outward radius: the tail points away from the centre.
        assert!(s.skew_along > 0.5, "radial skewness {}", s.skew_along);
        assert!(
            s.kurtosis > 10.0,
            "kurtosis {} (a Gaussian's is 8)",
            s.kurtosis
        );
    }

    #[test]
    fn aberrated_centre_is_nearly_symmetric() {
        let l = VirtualLens::aberrated();
        let c = l.field(Channel::G).sweet_spot;
        let k = l.optical_kernel_uv(Channel::G, c[0], c[1], at(4.0), 4);
        // The decentred pupil leaves a little coma on the axis (skewness about 0.19,
        // against 1.6 in the corner wide open): near-symmetric, not perfectly so.
        for dir in [[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, -1.0]] {
            let s = shape_of(&k, dir);
            assert!(
                s.skew_along.abs() < 0.25,
                "skewness {} along {dir:?}",
                s.skew_along
            );
        }
    }

    #[test]
    fn aberrated_corner_stopped_down_is_smaller_and_closer_to_gaussian() {
        let l = VirtualLens::aberrated();
        let (p, radial) = corner(&l);
        let open = shape_of(
            &l.optical_kernel_uv(Channel::G, p[0], p[1], at(4.0), 4),
            radial,
        );
        let shut = shape_of(
            &l.optical_kernel_uv(Channel::G, p[0], p[1], at(10.0), 4),
            radial,
        );
        assert!(
            shut.var[0] < 0.5 * open.var[0],
            "var x {:?} → {:?}",
            open.var,
            shut.var
        );
        assert!(
            shut.var[1] < 0.5 * open.var[1],
            "var y {:?} → {:?}",
            open.var,
            shut.var
        );
        assert!(
            shut.rel_l2 < 0.6 * open.rel_l2,
            "distance from the Gaussian {} → {}",
            open.rel_l2,
            shut.rel_l2
        );
        assert!(shut.skew_along.abs() < open.skew_along.abs());
    }

    #[test]
    fn old_lens_files_load_without_aberrations() {
        let mut json: serde_json::Value =
            serde_json::to_value(VirtualLens::demo()).expect("serialise");
        assert!(json.get("aberrations").is_none());
        json.as_object_mut().map(|o| o.remove("aberrations"));
        let l: VirtualLens = serde_json::from_value(json).expect("old form loads");
        assert_eq!(l, VirtualLens::demo());
        let mut bad = VirtualLens::aberrated();
        if let Some(a) = &mut bad.aberrations {
            a.pupil_ellipticity = 0.7;
        }
        assert!(bad.validate().is_err());
        let back: VirtualLens =
            serde_json::from_str(&serde_json::to_string(&VirtualLens::aberrated()).expect("json"))
                .expect("round trip");
        assert_eq!(back, VirtualLens::aberrated());
    }
}
