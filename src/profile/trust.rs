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
use crate::raw::FocusDistance;
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

/// How far beyond the calibrated focus distances a photo may be focused before the
/// profile warns: a factor in distance either way, with every distance past
/// [`FOCUS_AS_INFINITY_M`] counted as that distance.
///
/// Why in ratio, not in metres: what changes a lens's blur with focus is where its
/// focusing group sits, and that moves as 1/distance (the extension beyond infinity
/// focus is f²/(s − f)): 1 m to 2 m moves a 50 mm lens about as far as 2 m to
/// infinity. The factor 2 is a chart session's own span (1.5–3 m is usual): a photo
/// within that factor beyond either end is taken as near enough to what was measured;
/// beyond it the blur was not measured, and the line says so. A judgement from those
/// numbers, not tuned to any session.
pub const FOCUS_FACTOR: f64 = 2.0;

/// Beyond this distance, metres, focus counts as this distance (infinity included):
/// the focusing group has less than f²/10 m left to travel to infinity, a quarter
/// of a millimetre for a 50 mm lens and under 1 % of the focal length for any lens
/// up to 100 mm, so a session at 10 m or beyond covers a photo at infinity. A range
/// ending under 10 / [`FOCUS_FACTOR`] = 5 m does not.
pub const FOCUS_AS_INFINITY_M: f64 = 10.0;

/// The focus distances a profile's shots were taken at, where they record one.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FocusRange {
    pub nearest_m: FocusDistance,
    pub farthest_m: FocusDistance,
}

impl FocusRange {
    /// The focus distances of a dataset's shots that record one, nearest to
    /// farthest; `None` where none does.
    #[must_use]
    pub fn of_dataset(ds: &crate::model::Dataset) -> Option<Self> {
        Self::of(
            ds.shots
                .iter()
                .filter_map(|s| s.focus_distance_m.map(crate::raw::FocusDistance::metres)),
        )
    }

    /// The range of `distances` (metres, infinite for infinity; zero, negative and NaN
    /// left out), `None` without any.
    #[must_use]
    pub fn of(distances: impl IntoIterator<Item = f64>) -> Option<Self> {
        let found: Vec<FocusDistance> = distances
            .into_iter()
            .filter_map(FocusDistance::from_metres)
            .collect();
        let nearest = found
            .iter()
            .copied()
            .min_by(|a, b| a.metres().total_cmp(&b.metres()))?;
        let farthest = found
            .iter()
            .copied()
            .max_by(|a, b| a.metres().total_cmp(&b.metres()))?;
        Some(Self {
            nearest_m: nearest,
            farthest_m: farthest,
        })
    }

    /// Whether a photo focused at `metres` (infinite for infinity) is far outside this
    /// range: more than [`FOCUS_FACTOR`] nearer than its nearest or farther than its
    /// farthest, distances past [`FOCUS_AS_INFINITY_M`] counted as that. A distance
    /// that is no distance (0, negative, not a number) is not judged.
    #[must_use]
    pub fn far_outside(&self, metres: f64) -> bool {
        if metres.is_nan() || metres <= 0.0 {
            return false;
        }
        let d = |m: f64| m.min(FOCUS_AS_INFINITY_M);
        let (near, far) = (d(self.nearest_m.metres()), d(self.farthest_m.metres()));
        d(metres) < near / FOCUS_FACTOR || d(metres) > far * FOCUS_FACTOR
    }

    /// Checks what a loaded range claims.
    ///
    /// # Errors
    /// Not a distance, or the nearest beyond the farthest, as a sentence.
    pub fn validate(&self) -> Result<(), String> {
        let (n, f) = (self.nearest_m.metres(), self.farthest_m.metres());
        if !(n > 0.0 && f > 0.0) || n > f {
            return Err(format!(
                "focus range: {} to {} is not a range of distances",
                distance_words(n),
                distance_words(f)
            ));
        }
        Ok(())
    }
}

/// A focus distance for people: "1.5 m", "infinity".
fn distance_words(m: f64) -> String {
    if m.is_infinite() {
        "infinity".into()
    } else {
        format!("{} m", (m * 100.0).round() / 100.0)
    }
}

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
    /// Focused far outside the distances the shots were taken at
    /// ([`FocusRange::far_outside`]).
    FocusFar {
        /// Metres, infinite for infinity.
        focus_m: f64,
        range: FocusRange,
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
            Self::FocusFar { focus_m, range } => {
                let (near, far) = (range.nearest_m.metres(), range.farthest_m.metres());
                let calibrated = if near == far {
                    distance_words(near)
                } else {
                    format!("{}–{}", distance_words(near), distance_words(far))
                };
                write!(
                    f,
                    "the photo was focused at {}, far from the focus distances the shots were taken at ({calibrated}): blur changes with focus, and there it was not measured",
                    distance_words(*focus_m)
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
    /// Where this profile is less well trusted for a photo at `setting`, focused at
    /// `focus_m` where known (and, given a point, there): outside the calibrated ranges
    /// or settings, far from any shot, beyond the chart, where its recorded held-out
    /// error is large ([`LARGE_ERROR_PCT`]) at the nearest calibrated setting (in the
    /// point's zone, or any zone for a whole photo), or focused far outside the focus
    /// distances of its shots ([`FocusRange::far_outside`]). Empty where it is trusted,
    /// or where a profile recorded nothing to judge by (a profile before version 3 has
    /// no held-out errors, one from shots without a focus distance no focus range; the
    /// setting checks still apply).
    #[must_use]
    pub fn trust_warnings(
        &self,
        setting: LensSetting,
        focus_m: Option<f64>,
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
        if let (Some(range), Some(focus_m)) = (self.focus_range, focus_m)
            && range.far_outside(focus_m)
        {
            out.push(TrustWarning::FocusFar { focus_m, range });
        }
        out
    }

    /// [`Profile::trust_warnings`] as one line, `None` where there is nothing to say.
    #[must_use]
    pub fn trust_line(
        &self,
        setting: LensSetting,
        focus_m: Option<f64>,
        point: Option<(f64, f64)>,
    ) -> Option<String> {
        warning_line(&self.trust_warnings(setting, focus_m, point))
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

    fn range(near: f64, far: f64) -> FocusRange {
        FocusRange::of([near, far]).unwrap()
    }

    #[test]
    fn focus_far_outside_the_range_is_more_than_twice_beyond_it_with_10_m_as_infinity() {
        let chart = range(1.5, 3.0);
        // Within a factor 2 either way: no warning.
        for m in [0.75, 1.0, 1.5, 2.2, 3.0, 6.0] {
            assert!(!chart.far_outside(m), "{m} m");
        }
        for m in [0.7, 6.1, 30.0, f64::INFINITY] {
            assert!(chart.far_outside(m), "{m} m");
        }
        // A range reaching 5 m covers infinity (10 m and beyond count as 10 m).
        assert!(!range(2.0, 5.0).far_outside(f64::INFINITY));
        assert!(range(2.0, 4.9).far_outside(f64::INFINITY));
        // A session at infinity covers anything from 5 m out.
        let far = range(f64::INFINITY, f64::INFINITY);
        assert_eq!(far.nearest_m.metres(), f64::INFINITY);
        assert!(!far.far_outside(5.0) && !far.far_outside(250.0));
        assert!(far.far_outside(4.9));
        // No distance, no judgement.
        assert!(!chart.far_outside(0.0) && !chart.far_outside(f64::NAN));
        assert_eq!(FocusRange::of([0.0, f64::NAN]), None);
    }

    #[test]
    fn a_focus_warning_says_where_and_against_what() {
        let w = TrustWarning::FocusFar {
            focus_m: f64::INFINITY,
            range: range(1.5, 3.0),
        };
        let line = warning_line(&[w]).unwrap();
        assert!(
            line.contains("focused at infinity") && line.contains("(1.5 m–3 m)"),
            "{line}"
        );
        assert!(range(2.0, 1.0).validate().is_ok(), "of() orders them");
        let backwards = FocusRange {
            nearest_m: FocusDistance::Metres(3.0),
            farthest_m: FocusDistance::Metres(1.0),
        };
        assert!(backwards.validate().is_err());
    }
}
