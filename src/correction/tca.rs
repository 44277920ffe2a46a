//! Lateral colour: where each chart corner lies in the red and in the blue image
//! against where it lies in the green, from detection's per-channel registration, as
//! lensfun's `tca` models (a radial scaling of red and of blue about the frame's
//! centre, as a function of green's radius). Linear least squares.

use super::frame::LensfunFrame;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// lensfun's lateral-colour models: red (blue) at radius r·k(r) where green is at r.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Hash)]
#[serde(rename_all = "lowercase")]
pub enum TcaModel {
    /// k = kr (kb).
    Linear,
    /// k = v + c r + b r².
    Poly3,
}

impl TcaModel {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Linear => "linear",
            Self::Poly3 => "poly3",
        }
    }

    /// k(r) for these terms.
    #[must_use]
    pub fn scale(self, terms: &[f64], r: f64) -> f64 {
        match self {
            Self::Linear => terms[0],
            Self::Poly3 => terms[0] + terms[1] * r + terms[2] * r * r,
        }
    }
}

/// One chart corner in green and in another channel, sensor px.
#[derive(Clone, Copy, Debug)]
pub struct ChannelPair {
    pub green: [f64; 2],
    pub other: [f64; 2],
}

/// One channel's fit against green.
#[derive(Clone, Debug, Serialize)]
pub struct ChannelTca {
    /// kr (kb) for linear; v, c, b for poly3.
    pub terms: Vec<f64>,
    pub std_errors: Vec<f64>,
    /// RMS distance of the channel's corners from the fit, px.
    pub rms_px: f64,
    /// How far the channel lies from green at the frame corner, px (outward positive).
    pub corner_shift_px: f64,
}

/// Red and blue at one focal length.
#[derive(Clone, Debug, Serialize)]
pub struct TcaFit {
    pub model: TcaModel,
    pub red: ChannelTca,
    pub blue: ChannelTca,
    /// Corner pairs used per channel.
    pub corners: usize,
}

impl TcaFit {
    /// Where channel `blue` (else red) lies when green lies at sensor point `p`, px.
    #[must_use]
    pub fn channel_at(&self, frame: &LensfunFrame, p: [f64; 2], blue: bool) -> [f64; 2] {
        let t = if blue { &self.blue } else { &self.red };
        let n = frame.to_norm(p);
        let k = self.model.scale(&t.terms, n[0].hypot(n[1]));
        frame.from_norm([n[0] * k, n[1] * k])
    }
}

/// Fits one channel's terms to its corner pairs.
#[must_use]
pub fn fit_channel(model: TcaModel, frame: &LensfunFrame, pairs: &[ChannelPair]) -> ChannelTca {
    let cols = match model {
        TcaModel::Linear => 1,
        TcaModel::Poly3 => 3,
    };
    let mut a = Matrix3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    let basis = |g: [f64; 2], axis: usize| -> [f64; 3] {
        let r = g[0].hypot(g[1]);
        [g[axis], g[axis] * r, g[axis] * r * r]
    };
    for p in pairs {
        let (g, o) = (frame.to_norm(p.green), frame.to_norm(p.other));
        for (axis, target) in o.iter().enumerate() {
            let row = basis(g, axis);
            for i in 0..cols {
                b[i] += row[i] * target;
                for j in 0..cols {
                    a[(i, j)] += row[i] * row[j];
                }
            }
        }
    }
    for i in cols..3 {
        a[(i, i)] = 1.0;
    }
    let inverse = a.try_inverse().unwrap_or_else(Matrix3::zeros);
    let x = inverse * b;
    let terms: Vec<f64> = x.iter().take(cols).copied().collect();
    let mut ss = 0.0;
    for p in pairs {
        let (g, o) = (frame.to_norm(p.green), frame.to_norm(p.other));
        let k = model.scale(&terms, g[0].hypot(g[1]));
        for axis in 0..2 {
            let r = (o[axis] - g[axis] * k) / frame.norm_scale;
            ss += r * r;
        }
    }
    let n = pairs.len().max(1) as f64;
    // Residuals in px: the terms' variance in normalised units takes ns².
    let variance = ss / ((2 * pairs.len()).saturating_sub(cols).max(1) as f64)
        * frame.norm_scale
        * frame.norm_scale;
    let std_errors = (0..cols)
        .map(|i| (inverse[(i, i)] * variance).max(0.0).sqrt())
        .collect();
    let rc = frame.corner_radius();
    ChannelTca {
        corner_shift_px: (model.scale(&terms, rc) - 1.0) * rc / frame.norm_scale,
        terms,
        std_errors,
        rms_px: (ss / n).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_magnified_channel_is_measured_as_its_magnification() {
        let frame = LensfunFrame::of_image(2400, 1600);
        let m = 1.0 + 3e-4;
        let mut pairs = Vec::new();
        for i in 0..20 {
            for j in 0..14 {
                let g = [60.0 + 120.0 * f64::from(i), 50.0 + 110.0 * f64::from(j)];
                let n = frame.to_norm(g);
                let other = frame.from_norm([n[0] * m, n[1] * m]);
                pairs.push(ChannelPair { green: g, other });
            }
        }
        let lin = fit_channel(TcaModel::Linear, &frame, &pairs);
        assert!((lin.terms[0] - m).abs() < 1e-12, "{:?}", lin.terms);
        let corner = 1199.5f64.hypot(799.5) * 3e-4;
        assert!(
            (lin.corner_shift_px - corner).abs() < 1e-6,
            "{}",
            lin.corner_shift_px
        );
        let p3 = fit_channel(TcaModel::Poly3, &frame, &pairs);
        assert!(
            (p3.terms[0] - m).abs() < 1e-9 && p3.terms[1].abs() < 1e-9,
            "{:?}",
            p3.terms
        );
    }
}
