//! Shooting advice: what the settings a session shot allow the model, and what to shoot
//! next.

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
