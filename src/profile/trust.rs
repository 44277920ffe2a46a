//! Where a profile is trusted (issue 25, item 4): the preferred Gaussian model's
//! held-out error as cross-validation found it, per calibrated setting and per zone of
//! the frame, recorded in the profile (version 3); and the warnings a photo's setting
//! (or a point of it) earns against that record and against the settings shot.
//!
//! The command line prints them and the studio shows them; both take the text from
//! here.

use super::Profile;
use crate::crossval::HeldOutError;
use crate::plane::LensSetting;
use serde::{Deserialize, Serialize};

/// Zones across and down the frame the error is summarised over: coarse enough that
/// each zone of a 24 × 16 chart shot holds dozens of squares, fine enough to tell the
/// corners (where the chart's outer squares give the noisiest kernels) from the centre.
pub const TRUST_ZONES: usize = 3;

/// A zone's mean held-out error, % of range (the mean over C_xx, C_yy and C_or), above
/// which the profile warns. The chain's models reach p95 errors of 1.4–3 % of range at
/// settings between the shots (README, "How well it works"); a zone whose *mean* is
/// above 5 % is one where the shots and the model disagree (noisy kernels, a shot
/// unlike its neighbours, too few squares), not the usual scatter. Chosen from those
/// figures, not tuned to a simulated session.
pub const LARGE_ERROR_PCT: f64 = 5.0;

/// The held-out error of one calibrated setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SettingTrust {
    pub focal_mm: f64,
    pub f_number: f64,
    /// Held-out kernels (all channels) at this setting.
    pub kernels: usize,
    /// Their mean error, % of range.
    pub mean_error_pct: f64,
    /// Per zone, row-major from the top-left: the mean error of the kernels measured
    /// there, % of range; `None` where the chart did not reach.
    pub zones: Vec<Option<f64>>,
}

/// Where the profile is trusted: its preferred model's held-out errors by setting and
/// zone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trust {
    /// The model the errors are of, e.g. "G_{6,3}".
    pub model: String,
    /// Zones across and down the frame.
    pub zones: [usize; 2],
    /// Mean error over every held-out kernel, % of range.
    pub mean_error_pct: f64,
    pub settings: Vec<SettingTrust>,
}

impl Trust {
    /// The record of held-out errors (`errors`, as cross-validation found them) on a
    /// `width × height` sensor, by setting (the one rule for "the same setting") and by
    /// zone. `None` without errors.
    #[must_use]
    pub fn from_errors(
        model: String,
        errors: &[HeldOutError],
        (width, height): (usize, usize),
    ) -> Option<Self> {
        if errors.is_empty() || width == 0 || height == 0 {
            return None;
        }
        let n = TRUST_ZONES;
        // Per setting: its sums per zone and overall.
        struct Sums {
            setting: LensSetting,
            zones: Vec<(f64, usize)>,
            sum: f64,
            count: usize,
        }
        let mut settings: Vec<Sums> = Vec::new();
        for e in errors {
            let zone = zone_of(e.x, e.y, (width, height), [n, n]);
            let i = match settings.iter().position(|s| s.setting.same_as(e.setting)) {
                Some(i) => i,
                None => {
                    settings.push(Sums {
                        setting: e.setting,
                        zones: vec![(0.0, 0); n * n],
                        sum: 0.0,
                        count: 0,
                    });
                    settings.len() - 1
                }
            };
            let s = &mut settings[i];
            s.zones[zone].0 += e.error_pct;
            s.zones[zone].1 += 1;
            s.sum += e.error_pct;
            s.count += 1;
        }
        settings.sort_by(|a, b| {
            a.setting
                .focal_mm
                .total_cmp(&b.setting.focal_mm)
                .then(a.setting.f_number.total_cmp(&b.setting.f_number))
        });
        let total: f64 = errors.iter().map(|e| e.error_pct).sum();
        // Two decimals (0.01 % of range, far below the bar the warnings use): the
        // record is for reading, and full doubles would double a G_{8,3} profile.
        let round = |v: f64| (v * 100.0).round() / 100.0;
        Some(Self {
            model,
            zones: [n, n],
            mean_error_pct: round(total / errors.len() as f64),
            settings: settings
                .into_iter()
                .map(|s| SettingTrust {
                    focal_mm: s.setting.focal_mm,
                    f_number: s.setting.f_number,
                    kernels: s.count,
                    mean_error_pct: round(s.sum / s.count as f64),
                    zones: s
                        .zones
                        .into_iter()
                        .map(|(sum, count)| (count > 0).then(|| round(sum / count as f64)))
                        .collect(),
                })
                .collect(),
        })
    }

    /// Checks what a loaded record claims before anything uses it.
    ///
    /// # Errors
    /// The first problem, as a sentence.
    pub fn validate(&self) -> Result<(), String> {
        let [zx, zy] = self.zones;
        if !(1..=16).contains(&zx) || !(1..=16).contains(&zy) {
            return Err(format!("trust: {zx} × {zy} zones (1 to 16 each)"));
        }
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        if !ok(self.mean_error_pct) {
            return Err("trust: the mean error is not a finite number ≥ 0".into());
        }
        for s in &self.settings {
            let positive = |v: f64| v.is_finite() && v > 0.0;
            if !(positive(s.focal_mm) && positive(s.f_number)) {
                return Err("trust: a setting that is not a focal length and f-number".into());
            }
            if s.zones.len() != zx * zy {
                return Err(format!(
                    "trust: {} zones at {} mm f/{}, expected {}",
                    s.zones.len(),
                    s.focal_mm,
                    s.f_number,
                    zx * zy
                ));
            }
            if !ok(s.mean_error_pct) || s.zones.iter().flatten().any(|&v| !ok(v)) {
                return Err("trust: an error that is not a finite number ≥ 0".into());
            }
        }
        Ok(())
    }
}

/// The zone (row-major) of sensor point (x, y) on a `width × height` sensor cut into
/// `zones` across and down.
pub(crate) fn zone_of(
    x: f64,
    y: f64,
    (width, height): (usize, usize),
    [zx, zy]: [usize; 2],
) -> usize {
    let cell = |v: f64, side: usize, n: usize| {
        let t = (v / side.max(1) as f64 * n as f64).floor();
        (t.max(0.0) as usize).min(n.max(1) - 1)
    };
    cell(y, height, zy) * zx + cell(x, width, zx)
}

/// A zone's name for people: by its place on a 3 × 3 grid, else its column and row.
pub(crate) fn zone_name(zone: usize, [zx, zy]: [usize; 2]) -> String {
    const NAMES: [&str; 9] = [
        "top-left",
        "top",
        "top-right",
        "left",
        "centre",
        "right",
        "bottom-left",
        "bottom",
        "bottom-right",
    ];
    match NAMES.get(zone) {
        Some(name) if [zx, zy] == [3, 3] => (*name).to_owned(),
        _ => format!("zone {}, {}", zone % zx.max(1) + 1, zone / zx.max(1) + 1),
    }
}

/// Why a photo's setting (or a point of it) is less well covered by the profile.
#[derive(Clone, Debug, PartialEq)]
pub enum TrustWarning {
    /// Focal length or f-number beyond the calibrated range.
    OutsideRange {
        setting: LensSetting,
        focal_range_mm: [f64; 2],
        f_number_range: [f64; 2],
    },
    /// Inside the ranges but outside the hull of the calibrated settings.
    OutsideHull { setting: LensSetting },
    /// Farther from every calibrated setting than the shots are from each other.
    FarFromShots {
        setting: LensSetting,
        nearest: LensSetting,
    },
    /// A point the chart never reached: the models continue from its border.
    OutsideChart { x: f64, y: f64 },
    /// Large held-out error at the nearest calibrated setting, in these zones.
    LargeError {
        nearest: LensSetting,
        /// (zone name, mean error % of range).
        zones: Vec<(String, f64)>,
    },
}

impl std::fmt::Display for TrustWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Two decimals at most: a grid's f-numbers are spaced in stops (f/6.32455…).
        let short = |v: f64| (v * 100.0).round() / 100.0;
        let setting = |s: &LensSetting| format!("{} mm f/{}", short(s.focal_mm), short(s.f_number));
        match self {
            Self::OutsideRange {
                setting: s,
                focal_range_mm: fr,
                f_number_range: ar,
            } => write!(
                f,
                "{} is outside the calibrated range {}–{} mm, f/{}–f/{}: the models extrapolate",
                setting(s),
                fr[0],
                fr[1],
                ar[0],
                ar[1]
            ),
            Self::OutsideHull { setting: s } => write!(
                f,
                "{} is inside the calibrated ranges but not among the calibrated settings: the models extrapolate",
                setting(s)
            ),
            Self::FarFromShots {
                setting: s,
                nearest,
            } => write!(
                f,
                "{} is farther from any shot than the shots are from each other (nearest {}): the models interpolate across a gap",
                setting(s),
                setting(nearest)
            ),
            Self::OutsideChart { x, y } => write!(
                f,
                "the chart did not reach ({x:.0}, {y:.0}): the models continue linearly from its border"
            ),
            Self::LargeError { nearest, zones } => {
                let list: Vec<String> = zones
                    .iter()
                    .map(|(name, e)| format!("{name} {e:.1} %"))
                    .collect();
                write!(
                    f,
                    "the model's held-out error at the nearest calibrated setting {} is large ({} of range, above {LARGE_ERROR_PCT} %): expect a weaker deblur there",
                    setting(nearest),
                    list.join(", ")
                )
            }
        }
    }
}

/// The warnings as one line (`None` when there are none), as `predict`, `deblur` and
/// the studio show them.
#[must_use]
pub fn warning_line(warnings: &[TrustWarning]) -> Option<String> {
    (!warnings.is_empty()).then(|| {
        let parts: Vec<String> = warnings.iter().map(ToString::to_string).collect();
        format!("warning: {}", parts.join("; "))
    })
}

impl Profile {
    /// Where this profile is less well trusted for a photo at `setting` (and, given a
    /// point, there): outside the calibrated ranges or settings, far from any shot,
    /// beyond the chart, or where its recorded held-out error is large
    /// ([`LARGE_ERROR_PCT`]) at the nearest calibrated setting (in the point's zone, or
    /// any zone for a whole photo). Empty where it is trusted, or where a profile
    /// before version 3 recorded nothing to judge by (the setting checks still apply).
    #[must_use]
    pub fn trust_warnings(
        &self,
        setting: LensSetting,
        point: Option<(f64, f64)>,
    ) -> Vec<TrustWarning> {
        let mut out = Vec::new();
        if !self.norm.contains(setting) {
            out.push(TrustWarning::OutsideRange {
                setting,
                focal_range_mm: self.norm.focal_range_mm,
                f_number_range: self.norm.f_number_range,
            });
        } else if !self.in_calibrated_hull(setting) {
            out.push(TrustWarning::OutsideHull { setting });
        }
        let nearest = self.nearest_calibrated(setting);
        if let Some((nearest, d)) = nearest
            && out.is_empty()
            && d > self.design_spacing()
        {
            out.push(TrustWarning::FarFromShots { setting, nearest });
        }
        if let Some((x, y)) = point
            && !self.norm.in_sampled_extent(x, y)
        {
            out.push(TrustWarning::OutsideChart { x, y });
        }
        if let (Some(trust), Some((nearest, _))) = (&self.trust, nearest)
            && let Some(st) = trust.settings.iter().find(|s| {
                LensSetting {
                    focal_mm: s.focal_mm,
                    f_number: s.f_number,
                }
                .same_as(nearest)
            })
        {
            let grid = trust.zones;
            let wanted =
                point.map(|(x, y)| zone_of(x, y, (self.norm.width, self.norm.height), grid));
            let zones: Vec<(String, f64)> = st
                .zones
                .iter()
                .enumerate()
                .filter(|(z, _)| wanted.is_none_or(|w| w == *z))
                .filter_map(|(z, e)| {
                    e.filter(|&e| e > LARGE_ERROR_PCT)
                        .map(|e| (zone_name(z, grid), e))
                })
                .collect();
            if !zones.is_empty() {
                out.push(TrustWarning::LargeError { nearest, zones });
            }
        }
        out
    }

    /// [`Profile::trust_warnings`] as one line, `None` where there is nothing to say.
    #[must_use]
    pub fn trust_line(&self, setting: LensSetting, point: Option<(f64, f64)>) -> Option<String> {
        warning_line(&self.trust_warnings(setting, point))
    }

    /// The calibrated setting nearest `s` in the normalised (f, a) plane, and its
    /// distance there.
    fn nearest_calibrated(&self, s: LensSetting) -> Option<(LensSetting, f64)> {
        let (f, a) = self.norm.fa(s);
        self.calibrated_settings
            .iter()
            .map(|c| {
                let (cf, ca) = self.norm.fa(*c);
                (*c, (cf - f).hypot(ca - a))
            })
            .min_by(|x, y| x.1.total_cmp(&y.1))
    }

    /// The largest distance from a calibrated setting to its nearest other one, in the
    /// normalised (f, a) plane: a photo farther than this from every shot sits in a
    /// hole of the design. Infinite with fewer than two settings (the range checks say
    /// all there is to say).
    fn design_spacing(&self) -> f64 {
        let pts: Vec<(f64, f64)> = self
            .calibrated_settings
            .iter()
            .map(|c| self.norm.fa(*c))
            .collect();
        if pts.len() < 2 {
            return f64::INFINITY;
        }
        pts.iter()
            .enumerate()
            .map(|(i, p)| {
                pts.iter()
                    .enumerate()
                    .filter(|(j, _)| *j != i)
                    .map(|(_, q)| (p.0 - q.0).hypot(p.1 - q.1))
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zones_cover_the_frame_row_major() {
        let g = [3, 3];
        assert_eq!(zone_of(0.0, 0.0, (300, 200), g), 0);
        assert_eq!(zone_of(299.0, 0.0, (300, 200), g), 2);
        assert_eq!(zone_of(150.0, 100.0, (300, 200), g), 4);
        assert_eq!(zone_of(0.0, 199.0, (300, 200), g), 6);
        // Beyond the frame: the nearest zone.
        assert_eq!(zone_of(-5.0, 500.0, (300, 200), g), 6);
        assert_eq!(zone_name(6, g), "bottom-left");
        assert_eq!(zone_of(299.0, 199.0, (300, 200), [4, 2]), 7);
        assert_eq!(zone_name(7, [4, 2]), "zone 4, 2");
    }
}
