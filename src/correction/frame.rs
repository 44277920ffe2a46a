//! lensfun's coordinate conventions, which every coefficient the correction stage fits
//! is expressed in.
//!
//! lensfun (its `lfModifier`) puts the origin at the frame's centre, pixel
//! ((W − 1)/2, (H − 1)/2), and uses two radii:
//! - distortion and lateral colour: r = 1 at half the shorter side, measured between
//!   pixel centres ((min(W, H) − 1)/2 px), scaled by the ratio of the calibration's
//!   diagonal to the image's (1 when the image has the aspect ratio and crop factor the
//!   entry states);
//! - vignetting: r = 1 at the corner of a frame of the entry's aspect ratio.
//!
//! [`LensfunFrame`] reproduces those scales exactly, so a coefficient fitted here means
//! in lensfun what it meant in the fit. The fits ([`super::distortion`], [`super::tca`],
//! [`super::vignetting`]) and the entry's writer ([`super::lensfun`]) all stand on it.

/// lensfun's coordinate systems on a `width × height` image whose entry states the
/// aspect ratio `entry_aspect` (long side over short) and the image's own crop factor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensfunFrame {
    pub width: usize,
    pub height: usize,
    /// The aspect ratio written into the entry, long side over short.
    pub entry_aspect: f64,
    /// Pixels → distortion/TCA units.
    pub norm_scale: f64,
    /// lensfun's `AspectRatioCorrection`, √(aspect² + 1): distortion units → vignetting
    /// units divide by it.
    pub aspect_correction: f64,
}

impl LensfunFrame {
    /// The frame of an image of this size whose entry states its own aspect ratio
    /// (`width / height` or its inverse, long over short) and crop factor.
    #[must_use]
    pub fn of_image(width: usize, height: usize) -> Self {
        let (long, short) = (width.max(height) as f64, width.min(height).max(1) as f64);
        Self::with_entry_aspect(width, height, long / short)
    }

    /// As lensfun's `lfModifier` constructor computes it (libs/lensfun/modifier.cpp,
    /// 0.3.x), with the calibration's crop factor equal to the image's.
    #[must_use]
    pub fn with_entry_aspect(width: usize, height: usize, entry_aspect: f64) -> Self {
        let w = if width >= 2 { width - 1 } else { 1 } as f64;
        let h = if height >= 2 { height - 1 } else { 1 } as f64;
        let size = w.min(h);
        let image_aspect = w.max(h) / size;
        let aspect_correction = entry_aspect.hypot(1.0);
        let coordinate_correction = aspect_correction / image_aspect.hypot(1.0);
        Self {
            width,
            height,
            entry_aspect,
            norm_scale: 2.0 / size * coordinate_correction,
            aspect_correction,
        }
    }

    /// The frame's centre, px.
    #[must_use]
    pub fn centre(&self) -> [f64; 2] {
        [
            (self.width as f64 - 1.0) / 2.0,
            (self.height as f64 - 1.0) / 2.0,
        ]
    }

    /// A pixel position in distortion/TCA units (origin at the centre).
    #[must_use]
    pub fn to_norm(&self, p: [f64; 2]) -> [f64; 2] {
        let c = self.centre();
        [
            (p[0] - c[0]) * self.norm_scale,
            (p[1] - c[1]) * self.norm_scale,
        ]
    }

    /// Back from distortion/TCA units to pixels.
    #[must_use]
    pub fn from_norm(&self, u: [f64; 2]) -> [f64; 2] {
        let c = self.centre();
        [c[0] + u[0] / self.norm_scale, c[1] + u[1] / self.norm_scale]
    }

    /// A pixel position in vignetting units (r = 1 at the corner of the entry's frame).
    #[must_use]
    pub fn to_vignetting(&self, p: [f64; 2]) -> [f64; 2] {
        let u = self.to_norm(p);
        [u[0] / self.aspect_correction, u[1] / self.aspect_correction]
    }

    /// The frame corner's radius in distortion/TCA units.
    #[must_use]
    pub fn corner_radius(&self) -> f64 {
        let u = self.to_norm([0.0, 0.0]);
        u[0].hypot(u[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frame_matches_lensfuns_units() {
        // A 3:2 image whose entry states 3:2: r = 1 at half the height between pixel
        // centres and vignetting's r = 1 at the corner, each 1.2e-4 short: lensfun
        // takes the image's aspect between pixel centres, 2999 / 1999, against the
        // entry's 1.5 (the value checked here is lensfun's own arithmetic).
        let f = LensfunFrame::of_image(3000, 2000);
        let cc = 1.5f64.hypot(1.0) / (2999.0f64 / 1999.0).hypot(1.0);
        let top = f.to_norm([1499.5, 0.0]);
        assert!((top[1] + cc).abs() < 1e-12, "{top:?}");
        assert!((cc - 1.0).abs() < 2e-4);
        let corner = f.to_vignetting([0.0, 0.0]);
        let corner_r = 1499.5f64.hypot(999.5) * 2.0 / 1999.0 * cc / 1.5f64.hypot(1.0);
        assert!(
            (corner[0].hypot(corner[1]) - corner_r).abs() < 1e-12,
            "{corner:?}"
        );
        let p = [123.0, 1700.5];
        let back = f.from_norm(f.to_norm(p));
        assert!((back[0] - p[0]).abs() < 1e-9 && (back[1] - p[1]).abs() < 1e-9);
    }
}
