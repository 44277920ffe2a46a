//! A lens's geometry beyond its blur: radial distortion that turns from barrel to
//! pincushion along the zoom, lateral colour (red and blue imaged at a slightly
//! different magnification than green), and illumination fall-off toward the corners.
//!
//! Radii are normalised about the optical centre (the frame centre) by the half
//! diagonal, r = |p − c| / √(((W−1)/2)² + ((H−1)/2)²), so r = 1 at the frame corners
//! and a description applies to any sensor size. The ideal (pinhole) image point p at
//! radius r lands on the sensor at c + (p − c) · (1 + k₁ r² + k₂ r⁴) · (1 + m_ch),
//! where m_ch is the channel's relative magnification against green.

use crate::plane::Channel;
use serde::{Deserialize, Serialize};

/// Distortion, lateral colour and vignetting; the default is an ideal lens (none).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct LensGeometry {
    /// (k₁, k₂) of the radial polynomial at the short end of the focal range: the
    /// relative displacement at the frame corner is k₁ + k₂ (−0.03 is 3 % barrel).
    #[serde(default)]
    pub distortion_wide: [f64; 2],
    /// The same at the long end; linear in focal length in between.
    #[serde(default)]
    pub distortion_long: [f64; 2],
    /// Relative magnification of red and of blue against green (e.g. 3e-4 moves red
    /// outward by 3e-4 · r, about 1.1 px at the corners of a 6000 × 4000 sensor).
    #[serde(default)]
    pub lateral_colour: [f64; 2],
    /// Light lost at the frame corners, in stops, wide open and at the smallest
    /// aperture of the range; linear in stops in between. The profile is the cos⁴ law's
    /// shape, (1 + c r²)⁻², with c set by the corner loss.
    #[serde(default)]
    pub vignetting_stops: [f64; 2],
}

/// The largest normalised radius the mapping must stay invertible at: the simulator
/// renders windows a PSF margin beyond the frame.
const MAX_RADIUS: f64 = 1.6;

impl LensGeometry {
    /// A typical mid-range zoom: 3 % barrel at the wide end turning to 1.5 % pincushion
    /// at the long end, red and blue at ±3 × 10⁻⁴ magnification against green (about
    /// 1.1 px at the corners of a 6000 × 4000 sensor, 0.12 px on a 640 × 427 frame),
    /// one stop of fall-off in the corners wide open and a third of a stop stopped down.
    #[must_use]
    pub fn typical_zoom() -> Self {
        Self {
            distortion_wide: [-0.03, 0.0],
            distortion_long: [0.015, 0.0],
            lateral_colour: [3e-4, -3e-4],
            vignetting_stops: [1.0, 0.33],
        }
    }

    /// Whether this is an ideal lens: the simulator then takes its exact,
    /// homography-only path.
    #[must_use]
    pub fn is_none(&self) -> bool {
        *self == Self::default()
    }

    /// Whether the pinhole mapping needs bending (distortion or lateral colour).
    #[must_use]
    pub fn bends(&self) -> bool {
        self.distortion_wide != [0.0; 2]
            || self.distortion_long != [0.0; 2]
            || self.lateral_colour != [0.0; 2]
    }

    /// Checks finite coefficients, a radial mapping that stays monotonic out to beyond
    /// the frame corners, |magnification| < 1 %, and a fall-off of 0–6 stops.
    ///
    /// # Errors
    /// A description of the first problem.
    pub fn validate(&self) -> Result<(), String> {
        let all = [
            self.distortion_wide[0],
            self.distortion_wide[1],
            self.distortion_long[0],
            self.distortion_long[1],
            self.lateral_colour[0],
            self.lateral_colour[1],
            self.vignetting_stops[0],
            self.vignetting_stops[1],
        ];
        if !all.iter().all(|v| v.is_finite()) {
            return Err("geometry: non-finite coefficients".into());
        }
        for (name, [k1, k2]) in [
            ("wide", self.distortion_wide),
            ("long", self.distortion_long),
        ] {
            // d(r·(1 + k₁r² + k₂r⁴))/dr must stay well above 0 for the inverse to exist.
            for i in 0..=32 {
                let r = MAX_RADIUS * f64::from(i) / 32.0;
                let slope = 1.0 + 3.0 * k1 * r * r + 5.0 * k2 * r.powi(4);
                if slope < 0.5 {
                    return Err(format!(
                        "geometry: {name} distortion ({k1}, {k2}) folds the image at radius {r:.2}"
                    ));
                }
            }
        }
        if self.lateral_colour.iter().any(|m| m.abs() >= 0.01) {
            return Err("geometry: |lateral colour| must be below 1 %".into());
        }
        if self
            .vignetting_stops
            .iter()
            .any(|s| !(0.0..=6.0).contains(s))
        {
            return Err("geometry: vignetting must be 0–6 stops".into());
        }
        Ok(())
    }

    fn radial(&self, tf: f64) -> [f64; 2] {
        let [w, l] = [self.distortion_wide, self.distortion_long];
        [w[0] + (l[0] - w[0]) * tf, w[1] + (l[1] - w[1]) * tf]
    }

    fn magnification(&self, channel: Channel) -> f64 {
        match channel {
            Channel::R => self.lateral_colour[0],
            Channel::B => self.lateral_colour[1],
            _ => 0.0,
        }
    }

    /// How far lateral colour moves a channel's image against green's at sensor (x, y),
    /// px: m_ch · (p − c), the magnification about the frame centre without the
    /// distortion's (second-order) share.
    #[must_use]
    pub fn lateral_shift_px(&self, channel: Channel, offset_from_centre: [f64; 2]) -> [f64; 2] {
        let m = self.magnification(channel);
        offset_from_centre.map(|d| m * d)
    }

    /// The mapping of one channel at one setting on a `width × height` sensor.
    /// `tf` and `ta` are the setting's normalised focal and aperture coordinates
    /// ([`VirtualLens::setting_coords`](super::VirtualLens::setting_coords)).
    #[must_use]
    pub fn mapping(
        &self,
        channel: Channel,
        tf: f64,
        ta: f64,
        width: usize,
        height: usize,
    ) -> SensorMapping {
        let c = [(width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0];
        let stops =
            self.vignetting_stops[0] + (self.vignetting_stops[1] - self.vignetting_stops[0]) * ta;
        SensorMapping {
            centre: c,
            half_diagonal: c[0].hypot(c[1]).max(1.0),
            k: self.radial(tf),
            magnification: 1.0 + self.magnification(channel),
            falloff: 2f64.powf(stops / 2.0) - 1.0,
        }
    }
}

/// One channel's ideal-to-sensor mapping and illumination at one setting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorMapping {
    centre: [f64; 2],
    half_diagonal: f64,
    k: [f64; 2],
    magnification: f64,
    falloff: f64,
}

impl SensorMapping {
    /// Where the ideal (pinhole) image point `p` lands on the sensor, px.
    #[must_use]
    pub fn sensor_from_ideal(&self, p: [f64; 2]) -> [f64; 2] {
        let d = [p[0] - self.centre[0], p[1] - self.centre[1]];
        let r2 = (d[0] * d[0] + d[1] * d[1]) / (self.half_diagonal * self.half_diagonal);
        let g = (1.0 + self.k[0] * r2 + self.k[1] * r2 * r2) * self.magnification;
        [self.centre[0] + d[0] * g, self.centre[1] + d[1] * g]
    }

    /// The ideal point that lands on sensor point `q`: Newton on the radius, which
    /// [`LensGeometry::validate`] keeps monotonic; converged to 1e-12 of the half
    /// diagonal.
    #[must_use]
    pub fn ideal_from_sensor(&self, q: [f64; 2]) -> [f64; 2] {
        let d = [q[0] - self.centre[0], q[1] - self.centre[1]];
        let rd = d[0].hypot(d[1]) / self.half_diagonal;
        if rd == 0.0 {
            return q;
        }
        let [k1, k2] = self.k;
        let m = self.magnification;
        let mut r = rd / m;
        for _ in 0..20 {
            let f = r * (1.0 + k1 * r * r + k2 * r.powi(4)) * m - rd;
            let df = (1.0 + 3.0 * k1 * r * r + 5.0 * k2 * r.powi(4)) * m;
            let step = f / df;
            r -= step;
            if step.abs() < 1e-13 {
                break;
            }
        }
        let g = r / rd;
        [self.centre[0] + d[0] * g, self.centre[1] + d[1] * g]
    }

    /// Relative illumination at sensor point `q` (1 at the centre).
    #[must_use]
    pub fn illumination(&self, q: [f64; 2]) -> f64 {
        let d = [q[0] - self.centre[0], q[1] - self.centre[1]];
        let r2 = (d[0] * d[0] + d[1] * d[1]) / (self.half_diagonal * self.half_diagonal);
        (1.0 + self.falloff * r2).powi(-2)
    }

    /// The largest second derivative (1/px) of the radial displacement within
    /// `radius_px` of the optical centre: what bounds how far the mapping strays from
    /// its best local homography over a small region.
    #[must_use]
    pub fn radial_curvature(&self, radius_px: f64) -> f64 {
        // Displacement D(ρ) = m ρ (k₁ (ρ/R)² + k₂ (ρ/R)⁴): D'' = m (6 k₁ ρ/R² + 20 k₂ ρ³/R⁴).
        let big_r = self.half_diagonal;
        let rho = radius_px.max(0.0);
        self.magnification
            * (6.0 * self.k[0].abs() * rho / (big_r * big_r)
                + 20.0 * self.k[1].abs() * rho.powi(3) / big_r.powi(4))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn typical_zoom_has_the_stated_corner_figures() {
        let g = LensGeometry::typical_zoom();
        g.validate().expect("valid");
        let (w, h) = (6000usize, 4000usize);
        let corner = [0.0, 0.0];
        let centre = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
        let radius = |p: [f64; 2]| (p[0] - centre[0]).hypot(p[1] - centre[1]);
        let wide = g.mapping(Channel::G, 0.0, 0.0, w, h);
        let long = g.mapping(Channel::G, 1.0, 0.0, w, h);
        let rel = |m: &SensorMapping| radius(m.sensor_from_ideal(corner)) / radius(corner) - 1.0;
        assert!((rel(&wide) + 0.03).abs() < 1e-9, "wide {}", rel(&wide));
        assert!((rel(&long) - 0.015).abs() < 1e-9, "long {}", rel(&long));
        let red = g.mapping(Channel::R, 0.0, 0.0, w, h);
        let shift = radius(red.sensor_from_ideal(corner)) - radius(wide.sensor_from_ideal(corner));
        assert!((0.9..1.2).contains(&shift), "red at the corner {shift} px");
        let stops = -wide.illumination(corner).log2();
        assert!((stops - 1.0).abs() < 1e-9, "corner fall-off {stops} stops");
        let closed = g.mapping(Channel::G, 0.0, 1.0, w, h);
        assert!(-closed.illumination(corner).log2() < 0.4);
    }

    #[test]
    fn the_inverse_inverts() {
        let g = LensGeometry::typical_zoom();
        for ch in [Channel::R, Channel::G, Channel::B] {
            for tf in [0.0, 0.5, 1.0] {
                let m = g.mapping(ch, tf, 0.0, 640, 427);
                for p in [
                    [0.0, 0.0],
                    [639.0, 426.0],
                    [-60.0, 500.0],
                    [319.5, 213.0],
                    [100.0, 7.0],
                ] {
                    let q = m.sensor_from_ideal(m.ideal_from_sensor(p));
                    assert!(
                        (q[0] - p[0]).hypot(q[1] - p[1]) < 1e-9,
                        "{ch} {tf} {p:?} {q:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn folding_distortion_is_refused() {
        let g = LensGeometry {
            distortion_wide: [-0.3, 0.0],
            ..LensGeometry::default()
        };
        assert!(g.validate().is_err());
        assert!(LensGeometry::default().validate().is_ok());
        assert!(LensGeometry::default().is_none());
    }
}
