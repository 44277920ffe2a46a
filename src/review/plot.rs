//! Plot helpers: cross-validation curves as points and their axes' extents, and round
//! tick values for a colour bar.

/// A cross-validation curve's points: mean error against α, or against β.
#[must_use]
pub fn cv_curve(sel: &crate::crossval::Selection, by_alpha: bool) -> Vec<[f64; 2]> {
    let curve = if by_alpha {
        &sel.alpha_curve
    } else {
        &sel.beta_curve
    };
    curve
        .iter()
        .map(|p| [if by_alpha { p.alpha } else { p.beta } as f64, p.mean_pct])
        .collect()
}

/// The error CDF's curves of one chosen model, one per parameter: (error, percentile).
#[must_use]
pub fn cv_cdf_curves(sel: &crate::crossval::Selection) -> [(&'static str, Vec<[f64; 2]>); 3] {
    let cdf = &sel.error_cdf;
    let curve = |q: &[f64]| -> Vec<[f64; 2]> {
        q.iter()
            .zip(&cdf.percentiles)
            .map(|(&e, &p)| [e, p])
            .collect()
    };
    [
        ("C_xx", curve(&cdf.cxx)),
        ("C_yy", curve(&cdf.cyy)),
        ("C_or", curve(&cdf.cor)),
    ]
}

/// The mean-error axis of the cross-validation curves (by α or β) of `sels`: its top,
/// and whether some point lies above it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CvCurveAxis {
    pub top: f64,
    pub points_above: bool,
}

/// High orders overfit wildly (hundreds of %): the axis stops at four times the best
/// mean error (taken as at least 0.25 %) so the minimum stays readable, 5 % above the
/// highest point below that. With no points, 0–1.
#[must_use]
pub fn cv_curve_axis<'a>(
    sels: impl IntoIterator<Item = &'a crate::crossval::Selection>,
    by_alpha: bool,
) -> CvCurveAxis {
    let values: Vec<f64> = sels
        .into_iter()
        .flat_map(|sel| {
            if by_alpha {
                &sel.alpha_curve
            } else {
                &sel.beta_curve
            }
            .iter()
            .map(|p| p.mean_pct)
        })
        .collect();
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(0.0, f64::max);
    let top = if lo.is_finite() {
        hi.min(4.0 * lo.max(0.25)) * 1.05
    } else {
        1.0
    };
    CvCurveAxis {
        top,
        points_above: values.iter().any(|&v| v > top),
    }
}

/// The end of the error CDF plot's error axis over `sels`: 2 % past the largest 99th
/// percentile of any parameter (the worst few samples would stretch the axis until the
/// curves are a wall at zero); a small positive end when there is none.
#[must_use]
pub fn cv_cdf_axis_end<'a>(sels: impl IntoIterator<Item = &'a crate::crossval::Selection>) -> f64 {
    sels.into_iter()
        .flat_map(|sel| {
            let c = &sel.error_cdf;
            let at99 = c.percentiles.iter().position(|&p| p >= 99.0);
            [&c.cxx, &c.cyy, &c.cor]
                .into_iter()
                .filter_map(move |q| q.get(at99?).copied())
        })
        .fold(1e-6, f64::max)
        * 1.02
}

/// Round tick values (1, 2 or 5 × 10ⁿ apart) inside `range`, about `n` of them: a
/// colour bar's labels.
#[must_use]
pub fn nice_ticks(range: [f64; 2], n: usize) -> Vec<f64> {
    let [lo, hi] = range;
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Vec::new();
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last)
        // Ticks at multiples of the step, so 0 is exact on a symmetric bar.
        .map(|k| k as f64 * step)
        .collect()
}

/// Stops from f/1, 2·log₂ N: the unit an aperture is stepped in, so an aperture axis
/// spaces f/4, f/5.6 and f/8 evenly as a lens's ring does.
#[must_use]
pub fn aperture_stops(f_number: f64) -> f64 {
    2.0 * f_number.log2()
}

/// The f-number `stops` stops from f/1.
#[must_use]
pub fn f_number_at_stops(stops: f64) -> f64 {
    2f64.powf(stops / 2.0)
}

/// The f-numbers lenses mark at every third of a stop from f/1 to f/32.
const MARKED_F_NUMBERS: [f64; 31] = [
    1.0, 1.1, 1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.5, 2.8, 3.2, 3.5, 4.0, 4.5, 5.0, 5.6, 6.3, 7.1, 8.0,
    9.0, 10.0, 11.0, 13.0, 14.0, 16.0, 18.0, 20.0, 22.0, 25.0, 29.0, 32.0,
];

/// An aperture axis's label at `stops` from f/1: the f-number a lens marks there where
/// it is a third of a stop (f/5.6, not f/5.66), else the exact one.
#[must_use]
pub fn f_number_label(stops: f64) -> String {
    let thirds = stops * 3.0;
    let nearest = thirds.round();
    let marked = usize::try_from(nearest as i64)
        .ok()
        .filter(|_| (thirds - nearest).abs() < 1e-6)
        .and_then(|i| MARKED_F_NUMBERS.get(i));
    let n = marked.copied().unwrap_or_else(|| f_number_at_stops(stops));
    let text = format!("{n:.1}");
    format!("f/{}", text.strip_suffix(".0").unwrap_or(&text))
}
