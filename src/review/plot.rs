//! Plot helpers: cross-validation curves as points, and round tick values for a colour
//! bar.

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
