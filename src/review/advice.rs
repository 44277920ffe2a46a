//! Shooting advice: what the settings a session shot allow the model, what to shoot
//! next, and the whole shooting plan for a lens's range as a checklist.

use crate::plane::LensSetting;

/// How serious a piece of shooting advice is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdviceLevel {
    /// The session cannot determine the model asked for (or any that follows a
    /// setting).
    Warning,
    /// The model is determined but limited by the settings shot.
    Note,
}

/// What the session's settings allow the model, and what to shoot next.
#[derive(Clone, Debug, PartialEq)]
pub struct ShootingAdvice {
    pub level: AdviceLevel,
    pub text: String,
}

/// Where one more value of a setting tells the model most: the middle of the widest gap
/// between the values shot (in stops for apertures, as the slider moves).
fn widest_gap(values: &[f64], aperture: bool) -> Option<(f64, f64)> {
    values.windows(2).map(|w| (w[0], w[1])).max_by(|a, b| {
        let span = |(lo, hi): (f64, f64)| if aperture { (hi / lo).ln() } else { hi - lo };
        span(*a).total_cmp(&span(*b))
    })
}

/// What the settings shot (the distinct focal lengths and f-numbers, sorted) allow the
/// model in focal length and aperture, for a β fixed by the session's settings or
/// chosen by cross-validation (`None`): the model's β-order polynomial in f and a needs
/// β + 1 distinct values of each setting that varies (β < N = min(N_f, N_a)), and a
/// setting shot at one value only cannot be followed at all. Each problem comes with
/// what to shoot next.
#[must_use]
pub fn shooting_advice(
    focals: &[f64],
    f_numbers: &[f64],
    beta: Option<usize>,
) -> Vec<ShootingAdvice> {
    let mut out = Vec::new();
    if focals.is_empty() || f_numbers.is_empty() {
        return out;
    }
    let fmt_f = |v: f64| format!("{v:.0} mm");
    let fmt_a = |v: f64| format!("f/{v:.1}");
    // Name, values shot, whether in stops (apertures), how a value reads.
    type Dim<'a> = (&'a str, &'a [f64], bool, &'a dyn Fn(f64) -> String);
    let dims: [Dim; 2] = [
        ("focal length", focals, false, &fmt_f),
        ("aperture", f_numbers, true, &fmt_a),
    ];
    for (name, values, _, fmt) in dims {
        if values.len() == 1 {
            out.push(ShootingAdvice {
                level: AdviceLevel::Warning,
                text: format!(
                    "Every shot is at {}: the model cannot follow the {name}, and the profile predicts nowhere else. Shoot at least one more {name} (the range's other end first).",
                    fmt(values[0])
                ),
            });
        }
    }
    let varying: Vec<_> = dims.iter().filter(|d| d.1.len() > 1).collect();
    let n = varying.iter().map(|d| d.1.len()).min().unwrap_or(1);
    let need = beta.map_or(2, |b| b + 1);
    for (name, values, aperture, fmt) in &varying {
        if values.len() >= need.max(3) {
            continue;
        }
        let Some((lo, hi)) = widest_gap(values, *aperture) else {
            continue;
        };
        let more = need.max(3) - values.len();
        let shoot = format!(
            "shoot at least {more} more {name}{} between {} and {}",
            if more == 1 { "" } else { "s" },
            fmt(lo),
            fmt(hi)
        );
        match beta {
            Some(b) if values.len() <= b => out.push(ShootingAdvice {
                level: AdviceLevel::Warning,
                text: format!(
                    "β = {b} (the session's setting) needs {} distinct {name}s, the session has {}: the model is not determined; {shoot}, or lower β.",
                    b + 1,
                    values.len()
                ),
            }),
            _ if values.len() == 2 && n == 2 => out.push(ShootingAdvice {
                level: AdviceLevel::Note,
                text: format!(
                    "With 2 {name}s the model is at most linear in {name} (β ≤ 1); to let it curve, {shoot}."
                ),
            }),
            _ => {}
        }
    }
    out
}

/// A lens's range as the photographer states it: its focal lengths (equal for a prime)
/// and the f-numbers worth calibrating (wide open to the smallest they use).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensRange {
    pub focal_mm: [f64; 2],
    pub f_number: [f64; 2],
}

/// One setting of a shooting plan and how many shots the session has at it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedSetting {
    pub setting: LensSetting,
    pub wanted: usize,
    pub shot: usize,
    /// On the plan's grid; `false`: a setting the session has shots at that the plan
    /// does not list (it counts all the same: the model is fitted to every shot).
    pub on_plan: bool,
}

/// How far a shooting plan has got, counted over every setting it lists, those the
/// session holds off its grid included.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlanProgress {
    /// Settings with at least one shot.
    pub settings_shot: usize,
    /// Settings with the shots wanted ([`SHOTS_PER_SETTING`]).
    pub complete: usize,
    /// Settings on the plan's grid, and how many of those have a shot.
    pub planned: usize,
    pub planned_shot: usize,
    /// Settings the session has shots at off the plan's grid.
    pub off_plan: usize,
}

/// Counts what a [`shooting_plan`] says was shot.
#[must_use]
pub fn plan_progress(plan: &[PlannedSetting]) -> PlanProgress {
    let on: Vec<&PlannedSetting> = plan.iter().filter(|p| p.on_plan).collect();
    PlanProgress {
        settings_shot: plan.iter().filter(|p| p.shot > 0).count(),
        complete: plan.iter().filter(|p| p.shot >= p.wanted).count(),
        planned: on.len(),
        planned_shot: on.iter().filter(|p| p.shot > 0).count(),
        off_plan: plan.iter().filter(|p| !p.on_plan).count(),
    }
}

/// A shooting plan laid out as a table: its focal lengths (rows) and f-numbers
/// (columns), each ascending and once, and at each row and column the planned setting
/// there, if any.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanGrid {
    pub focals: Vec<f64>,
    pub apertures: Vec<f64>,
    pub cells: Vec<Vec<Option<PlannedSetting>>>,
}

/// Lays `plan` out as a [`PlanGrid`].
#[must_use]
pub fn plan_grid(plan: &[PlannedSetting]) -> PlanGrid {
    let axis = |value: fn(&PlannedSetting) -> f64| {
        let mut v: Vec<f64> = plan.iter().map(value).collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };
    let focals = axis(|p| p.setting.focal_mm);
    let apertures = axis(|p| p.setting.f_number);
    let cells = focals
        .iter()
        .map(|&f| {
            apertures
                .iter()
                .map(|&a| {
                    plan.iter()
                        .find(|p| p.setting.focal_mm == f && p.setting.f_number == a)
                        .copied()
                })
                .collect()
        })
        .collect();
    PlanGrid {
        focals,
        apertures,
        cells,
    }
}

/// Shots wanted at each planned setting: two, so cross-validation can hold one out
/// and still have the setting.
pub const SHOTS_PER_SETTING: usize = 2;

/// Whole stops from f/1 (√2 apart), as lenses mark them.
const FULL_STOPS: [f64; 10] = [1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0, 11.0, 16.0, 22.0];

/// Past f/11, diffraction blurs every lens alike and deblurring gains little.
const SMALLEST_USEFUL_APERTURE: f64 = 11.0;

/// The settings to shoot for a lens's `range`, each with the count of `shots` at it:
/// focal lengths from end to end, evenly spaced in their logarithm (five on a zoom of
/// 2× or more, three on a shorter one, one on a prime), rounded to whole millimetres;
/// f-numbers wide open, then the whole stops more than half a stop above it up to f/11
/// (or the range's end), five at most. A shot counts at a setting within 4 % of its focal length and a sixth
/// of a stop of its f-number (cameras round both). The settings shot that lie off
/// that grid are listed too (`on_plan: false`), so that the plan accounts for every
/// shot. Sorted by focal length, then f-number.
#[must_use]
pub fn shooting_plan(range: &LensRange, shots: &[LensSetting]) -> Vec<PlannedSetting> {
    let [f0, f1] = sorted(range.focal_mm);
    let focals: Vec<f64> = if f1 / f0 < 1.04 {
        vec![f0.round()]
    } else {
        let n = if f1 / f0 >= 2.0 { 5 } else { 3 };
        let mut v: Vec<f64> = (0..n)
            .map(|i| {
                (f0.ln() + (f1 / f0).ln() * i as f64 / (n - 1) as f64)
                    .exp()
                    .round()
            })
            .collect();
        v.dedup();
        v
    };
    let [a0, a1] = sorted(range.f_number);
    let stop = a1.min(SMALLEST_USEFUL_APERTURE.max(a0));
    let mut apertures = vec![a0];
    apertures.extend(
        FULL_STOPS
            .iter()
            .copied()
            .filter(|&a| a > a0 * 2f64.powf(0.25) && a <= stop * 1.01),
    );
    apertures.truncate(5);
    let near = |s: &LensSetting, f: f64, a: f64| {
        (s.focal_mm / f - 1.0).abs() <= 0.04 && (s.f_number / a).log2().abs() * 2.0 <= 1.0 / 6.0
    };
    let mut plan: Vec<PlannedSetting> = focals
        .iter()
        .flat_map(|&f| apertures.iter().map(move |&a| (f, a)))
        .map(|(f, a)| PlannedSetting {
            setting: LensSetting {
                focal_mm: f,
                f_number: a,
            },
            wanted: SHOTS_PER_SETTING,
            shot: shots.iter().filter(|s| near(s, f, a)).count(),
            on_plan: true,
        })
        .collect();
    // Each shot off the grid joins the first off-grid setting it is near, or starts one.
    let planned = plan.len();
    for s in shots {
        let at = |p: &PlannedSetting| near(s, p.setting.focal_mm, p.setting.f_number);
        if plan[..planned].iter().any(at) {
            continue;
        }
        if let Some(p) = plan[planned..].iter_mut().find(|p| at(p)) {
            p.shot += 1;
            continue;
        }
        plan.push(PlannedSetting {
            setting: *s,
            wanted: SHOTS_PER_SETTING,
            shot: 1,
            on_plan: false,
        });
    }
    plan.sort_by(|a, b| {
        a.setting
            .focal_mm
            .total_cmp(&b.setting.focal_mm)
            .then(a.setting.f_number.total_cmp(&b.setting.f_number))
    });
    plan
}

fn sorted([a, b]: [f64; 2]) -> [f64; 2] {
    if a <= b { [a, b] } else { [b, a] }
}
