//! Fall-off from the chart's white: every aligned square's fitted white level, per
//! colour channel, across the frame. Under even light the white paper reflects the
//! same everywhere, so what varies is the lens's illumination, fitted as lensfun's
//! `pa` model c(r) = 1 + k₁r² + k₂r⁴ + k₃r⁶ (r = 1 at the frame corner) with one gain
//! per channel. Light that is not even shows as a gradient across the chart that no
//! radial fall-off explains: fitted beside the model, and reported.

use super::frame::LensfunFrame;
use crate::plane::{Channel, LensSetting};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// One white measurement: a square's centre and a channel's white level there.
#[derive(Clone, Copy, Debug)]
pub struct WhiteSample {
    pub channel: Channel,
    pub sensor: [f64; 2],
    pub white: f64,
}

/// A gradient across the chart larger than this, in stops, is light that was not
/// even: about where an uncorrected tilt in a flat sky starts to show. Chosen before
/// measuring; the check reports the figure either way.
pub const UNEVEN_LIGHT_STOPS: f64 = 0.15;

/// The fall-off at one setting.
#[derive(Clone, Debug, Serialize)]
pub struct VignettingFit {
    pub setting: LensSetting,
    /// lensfun's pa terms k₁, k₂, k₃.
    pub k: [f64; 3],
    pub std_errors: [f64; 3],
    /// Light lost at the frame corner, stops (positive: darker).
    pub corner_stops: f64,
    /// RMS of the whites' relative residual against the fitted model.
    pub rms_relative: f64,
    /// The largest radius the chart's squares reached (1 = the frame corner): beyond
    /// it the model is extrapolated.
    pub max_radius: f64,
    /// The gradient across the chart's squares that the radial model leaves, stops
    /// (fitted beside it); above [`UNEVEN_LIGHT_STOPS`] the light was not even.
    pub gradient_stops: f64,
    pub samples: usize,
}

impl VignettingFit {
    /// Relative illumination c(r) at vignetting radius `r`.
    #[must_use]
    pub fn illumination(&self, r: f64) -> f64 {
        let r2 = r * r;
        1.0 + self.k[0] * r2 + self.k[1] * r2 * r2 + self.k[2] * r2 * r2 * r2
    }

    /// Whether the light looked even enough to trust the fit.
    #[must_use]
    pub fn light_even(&self) -> bool {
        self.gradient_stops <= UNEVEN_LIGHT_STOPS
    }
}

/// Least squares of the whites on one gain per channel times c(r), and optionally a
/// multiplicative gradient (1 + gₓx + g_y y) inside it: Gauss–Newton on the gains and
/// the shared terms together (a handful of unknowns). Returns the shared terms, the
/// gains, the terms' block of the final normal equations and the relative residuals'
/// sum of squares.
fn solve(
    frame: &LensfunFrame,
    samples: &[WhiteSample],
    channels: &[Channel],
    gradient: bool,
) -> (Vec<f64>, Vec<f64>, DMatrix<f64>, f64) {
    let nk = if gradient { 5 } else { 3 };
    let nc = channels.len();
    let basis = |s: &WhiteSample| -> [f64; 5] {
        let v = frame.to_vignetting(s.sensor);
        let r2 = v[0] * v[0] + v[1] * v[1];
        [r2, r2 * r2, r2 * r2 * r2, v[0], v[1]]
    };
    let rows: Vec<(usize, [f64; 5], f64)> = samples
        .iter()
        .filter_map(|s| {
            let ci = channels.iter().position(|&c| c == s.channel)?;
            Some((ci, basis(s), s.white))
        })
        .collect();
    let mut p: Vec<f64> = (0..nc)
        .map(|ci| {
            rows.iter()
                .filter(|r| r.0 == ci)
                .map(|r| r.2)
                .fold(0.0, f64::max)
        })
        .chain(std::iter::repeat_n(0.0, nk))
        .collect();
    let model = |p: &[f64], phi: &[f64; 5]| 1.0 + (0..nk).map(|i| p[nc + i] * phi[i]).sum::<f64>();
    let mut a = DMatrix::<f64>::zeros(nc + nk, nc + nk);
    for _ in 0..30 {
        a = DMatrix::<f64>::zeros(nc + nk, nc + nk);
        let mut b = DVector::<f64>::zeros(nc + nk);
        for (ci, phi, w) in &rows {
            let m = model(&p, phi);
            let r = w - p[*ci] * m;
            let mut j = vec![0.0; nc + nk];
            j[*ci] = m;
            for i in 0..nk {
                j[nc + i] = p[*ci] * phi[i];
            }
            for u in 0..nc + nk {
                b[u] += j[u] * r;
                for v in 0..nc + nk {
                    a[(u, v)] += j[u] * j[v];
                }
            }
        }
        let Some(step) = a.clone().cholesky().map(|c| c.solve(&b)) else {
            break;
        };
        for (x, d) in p.iter_mut().zip(step.iter()) {
            *x += d;
        }
        if step.iter().map(|d| d.abs()).fold(0.0, f64::max) < 1e-13 {
            break;
        }
    }
    let ss = rows
        .iter()
        .map(|(ci, phi, w)| {
            let m = p[*ci] * model(&p, phi);
            ((w - m) / m).powi(2)
        })
        .sum();
    let terms = a.view((nc, nc), (nk, nk)).into_owned();
    // The terms' covariance is the inverse's block, not the block's inverse: keep the
    // whole matrix's inverse block.
    let block = a
        .clone()
        .try_inverse()
        .map_or(terms, |inv| inv.view((nc, nc), (nk, nk)).into_owned());
    (p[nc..].to_vec(), p[..nc].to_vec(), block, ss)
}

/// Fits the fall-off at one setting from its whites; `None` with fewer than ten.
#[must_use]
pub fn fit(
    setting: LensSetting,
    frame: &LensfunFrame,
    samples: &[WhiteSample],
) -> Option<VignettingFit> {
    let samples: Vec<WhiteSample> = samples
        .iter()
        .filter(|s| s.white.is_finite() && s.white > 0.0)
        .copied()
        .collect();
    if samples.len() < 10 {
        return None;
    }
    let mut channels: Vec<Channel> = samples.iter().map(|s| s.channel).collect();
    channels.sort();
    channels.dedup();
    let (k, gains, cov, ss) = solve(frame, &samples, &channels, false);
    let (kg, _, _, _) = solve(frame, &samples, &channels, true);
    let n = samples.len() as f64;
    let rms = (ss / n).sqrt();
    let variance = ss / (n - 3.0 - channels.len() as f64).max(1.0);
    // `cov` is already the inverse's block, in the whites' units: relative
    // residuals take the gains' scale back out.
    let mean_gain = gains.iter().sum::<f64>() / gains.len().max(1) as f64;
    let std_errors = std::array::from_fn(|i| {
        (cov[(i, i)] * variance * mean_gain * mean_gain)
            .max(0.0)
            .sqrt()
    });
    // The gradient's span over the squares, in stops.
    let span = samples
        .iter()
        .map(|s| {
            let v = frame.to_vignetting(s.sensor);
            1.0 + kg[3] * v[0] + kg[4] * v[1]
        })
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), g| {
            (lo.min(g), hi.max(g))
        });
    let gradient_stops = if span.0 > 0.0 {
        (span.1 / span.0).log2()
    } else {
        f64::INFINITY
    };
    let max_radius = samples
        .iter()
        .map(|s| {
            let v = frame.to_vignetting(s.sensor);
            v[0].hypot(v[1])
        })
        .fold(0.0, f64::max);
    let k = [k[0], k[1], k[2]];
    let c1 = 1.0 + k[0] + k[1] + k[2];
    Some(VignettingFit {
        setting,
        k,
        std_errors,
        corner_stops: if c1 > 0.0 { -c1.log2() } else { f64::INFINITY },
        rms_relative: rms,
        max_radius,
        gradient_stops,
        samples: samples.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(frame: &LensfunFrame, k: [f64; 3], tilt: f64) -> Vec<WhiteSample> {
        let mut out = Vec::new();
        for i in 0..24 {
            for j in 0..16 {
                let p = [40.0 + 100.0 * f64::from(i), 30.0 + 100.0 * f64::from(j)];
                let v = frame.to_vignetting(p);
                let r2 = v[0] * v[0] + v[1] * v[1];
                let c = 1.0 + k[0] * r2 + k[1] * r2 * r2 + k[2] * r2 * r2 * r2;
                for (ch, gain) in [(Channel::R, 0.5), (Channel::G, 0.8), (Channel::B, 0.6)] {
                    out.push(WhiteSample {
                        channel: ch,
                        sensor: p,
                        white: gain * c * (1.0 + tilt * v[0]),
                    });
                }
            }
        }
        out
    }

    #[test]
    fn fall_off_is_recovered_and_uneven_light_is_told_apart() {
        let frame = LensfunFrame::of_image(2400, 1600);
        let k = [-0.45, 0.1, -0.02];
        let s = LensSetting {
            focal_mm: 24.0,
            f_number: 4.0,
        };
        let even = fit(s, &frame, &samples(&frame, k, 0.0)).expect("fit");
        for (got, want) in even.k.iter().zip(&k) {
            assert!((got - want).abs() < 1e-6, "{:?}", even.k);
        }
        assert!(even.light_even() && even.gradient_stops < 1e-6);
        assert!((even.corner_stops + (1.0f64 + k[0] + k[1] + k[2]).log2()).abs() < 1e-6);
        let tilted = fit(s, &frame, &samples(&frame, k, 0.15)).expect("fit");
        assert!(!tilted.light_even(), "{}", tilted.gradient_stops);
    }
}
