//! Sweeps: the settings along a focal-length or aperture sweep, the measured points on
//! one, and the model and truth curves beside them (the paper's Fig. 4).

use super::fields::truth_pixel_gaussian;
use crate::model::Dataset;
use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::psf::Gaussian2;

/// The value of `values` nearest `wanted` (the calibrated setting a sweep holds fixed).
#[must_use]
pub fn nearest_value(values: &[f64], wanted: f64) -> Option<f64> {
    values
        .iter()
        .copied()
        .min_by(|a, b| (a - wanted).abs().total_cmp(&(b - wanted).abs()))
}

/// `n` + 1 settings along a sweep for drawing model curves: the f-number from
/// `range[0]` to `range[1]` evenly in stops at focal length `fixed` (`vs_aperture`), or
/// the focal length evenly in mm at f-number `fixed`.
#[must_use]
pub fn sweep_settings(
    range: [f64; 2],
    fixed: f64,
    vs_aperture: bool,
    n: usize,
) -> Vec<LensSetting> {
    let n = n.max(1);
    (0..=n)
        .map(|k| {
            let t = k as f64 / n as f64;
            if vs_aperture {
                LensSetting {
                    focal_mm: fixed,
                    f_number: range[0] * (range[1] / range[0]).powf(t),
                }
            } else {
                LensSetting {
                    focal_mm: range[0] + (range[1] - range[0]) * t,
                    f_number: fixed,
                }
            }
        })
        .collect()
}

/// A profile's model curve at sensor point (x, y) over `settings` (from
/// [`sweep_settings`]); settings it cannot predict at are left out.
#[must_use]
pub fn model_curve(
    profile: &Profile,
    channel: Channel,
    (x, y): (f64, f64),
    settings: &[LensSetting],
) -> Vec<(LensSetting, Gaussian2)> {
    settings
        .iter()
        .filter_map(|&s| Some((s, profile.predict(channel, x, y, s).ok()?)))
        .collect()
}

/// A virtual lens's pixel-level truth at sensor point (x, y) over `settings`.
#[must_use]
pub fn truth_curve(
    lens: &crate::simulate::VirtualLens,
    channel: Channel,
    at: (f64, f64),
    size: (usize, usize),
    settings: &[LensSetting],
) -> Vec<(LensSetting, Gaussian2)> {
    settings
        .iter()
        .map(|&s| (s, truth_pixel_gaussian(lens, channel, at, size, s)))
        .collect()
}

/// One measured point of a sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepPoint {
    /// The shot it was measured in (an index into the dataset's shots).
    pub shot: usize,
    pub setting: LensSetting,
    /// Where the square it was measured on lies, sensor px.
    pub x: f64,
    pub y: f64,
    pub gaussian: Gaussian2,
}

/// How far from the asked point a sample may lie, in widths of the dataset's largest
/// square. Where the chart covers the point, the nearest square's centre is at most
/// half a diagonal (0.71 widths) away; a sample farther off was measured at another
/// place of the lens, and the blur changes across the frame, so it is not shown there.
pub const SWEEP_REACH_SQUARES: f64 = 0.75;

/// Measured points of one sweep: for every shot on the sweep (its focal length equals
/// `fixed` when `vs_aperture`, its f-number otherwise), the `channel` sample nearest
/// sensor point (x, y), if one lies within [`SWEEP_REACH_SQUARES`]. Sorted by the
/// varying setting. The studio's Sweeps view and `lensblur sweeps` both use it.
#[must_use]
pub fn sweep_points(
    ds: &Dataset,
    channel: Channel,
    (x, y): (f64, f64),
    vs_aperture: bool,
    fixed: f64,
) -> Vec<SweepPoint> {
    let reach = SWEEP_REACH_SQUARES * ds.largest_square_px();
    let mut out: Vec<SweepPoint> = ds
        .shots
        .iter()
        .enumerate()
        .filter(|(_, info)| {
            if vs_aperture {
                LensSetting::same_value(info.focal_mm, fixed)
            } else {
                LensSetting::same_value(info.f_number, fixed)
            }
        })
        .filter_map(|(k, info)| {
            let (distance, s) = ds
                .samples
                .iter()
                .filter(|s| s.shot == k && s.channel == channel)
                .map(|s| ((s.x - x).hypot(s.y - y), s))
                .min_by(|a, b| a.0.total_cmp(&b.0))?;
            (distance <= reach).then_some(SweepPoint {
                shot: k,
                setting: LensSetting {
                    focal_mm: info.focal_mm,
                    f_number: info.f_number,
                },
                x: s.x,
                y: s.y,
                gaussian: s.gaussian,
            })
        })
        .collect();
    let key = |p: &SweepPoint| {
        if vs_aperture {
            p.setting.f_number
        } else {
            p.setting.focal_mm
        }
    };
    out.sort_by(|a, b| key(a).total_cmp(&key(b)));
    out
}
