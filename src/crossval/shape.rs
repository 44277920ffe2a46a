//! Cross-validation of the kernel-shape model: the Gaussian models' folds (whole
//! shots), the Gaussian model, shape basis and coefficient fields refitted without each
//! fold, every held-out measured kernel against its prediction (relative L2).

#[allow(clippy::wildcard_imports)]
use super::*;

/// What the kernel-shape cross-validation tries: the orders α of the coefficient
/// fields (β is the Gaussian model's) and the numbers of shape components (0: the
/// Gaussian alone).
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeCvOptions {
    pub alphas: Vec<usize>,
    pub components: Vec<usize>,
    /// The spaces shapes are described in. Whitened only by default: on the aberrated
    /// lens the pixel space predicted held-out kernels closer in L2 but deblurred worse
    /// than the Gaussians alone (see the README's kernel-shape figures).
    pub spaces: Vec<crate::model::ShapeSpace>,
}

impl Default for ShapeCvOptions {
    fn default() -> Self {
        Self {
            alphas: vec![1, 2, 3, 4, 6],
            components: vec![0, 1, 2, 3, 4, 6, 8],
            spaces: vec![crate::model::ShapeSpace::Whitened],
        }
    }
}

/// Held-out error of one kernel model: relative L2 of predicted against measured kernels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeCvPoint {
    /// Where the shape is described (the Gaussian alone: whitened, unused).
    #[serde(default)]
    pub space: crate::model::ShapeSpace,
    /// Order of the coefficient fields (0 for the Gaussian alone).
    pub alpha: usize,
    pub beta: usize,
    /// Shape components; 0 is the Gaussian model's kernel.
    pub components: usize,
    pub mean_rel_l2: f64,
    pub median_rel_l2: f64,
    pub p95_rel_l2: f64,
}

/// The held-out errors at one aperture: the Gaussian's and the best shape model's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ApertureError {
    pub f_number: f64,
    pub kernels: usize,
    pub gaussian_mean_rel_l2: f64,
    pub shape_mean_rel_l2: f64,
}

/// Cross-validation of the kernel-shape model: the same folds as the Gaussian models',
/// each held-out shot's measured kernels against the kernels predicted for it by the
/// Gaussian model and by shape models fitted without it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeCvReport {
    pub folds: usize,
    /// Held-out kernels judged.
    pub kernels: usize,
    /// The Gaussian model the kernels are predicted around, e.g. `G_{6,2}`.
    pub gaussian_model: String,
    /// The Gaussian model's own kernels (0 components).
    pub gaussian: ShapeCvPoint,
    /// Every shape model tried.
    pub points: Vec<ShapeCvPoint>,
    /// The shape model with the lowest error.
    pub best_shape: Option<ShapeCvPoint>,
    /// Whether that beats the Gaussian: the profile then holds it.
    pub shape_chosen: bool,
    /// Per aperture: the Gaussian's and `best_shape`'s errors.
    pub per_aperture: Vec<ApertureError>,
}

fn rel_l2_point(
    space: crate::model::ShapeSpace,
    alpha: usize,
    beta: usize,
    components: usize,
    errors: &mut [f64],
) -> ShapeCvPoint {
    errors.sort_by(f64::total_cmp);
    let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
    ShapeCvPoint {
        space,
        alpha,
        beta,
        components,
        mean_rel_l2: mean,
        median_rel_l2: percentile_sorted(errors, 50.0),
        p95_rel_l2: percentile_sorted(errors, 95.0),
    }
}

/// The samples of `ds` whose shot `keep` accepts, with every shot's record (the
/// normalisation stays the session's, as in the Gaussian models' folds).
fn shots_subset(ds: &Dataset, keep: impl Fn(usize) -> bool) -> (Dataset, Vec<usize>) {
    let idx: Vec<usize> = (0..ds.samples.len())
        .filter(|&i| keep(ds.samples[i].shot))
        .collect();
    let sub = Dataset {
        width: ds.width,
        height: ds.height,
        identity: ds.identity.clone(),
        samples: idx.iter().map(|&i| ds.samples[i].clone()).collect(),
        shots: ds.shots.clone(),
    };
    (sub, idx)
}

/// Cross-validates kernel-shape models around the Gaussian model `kind` G/L_{α,β}:
/// per fold, that Gaussian model and, in each space, a shape basis with its
/// coefficient fields are fitted without the fold's shots, and every held-out measured
/// kernel is compared with the kernels predicted at its square (relative L2).
/// `residuals` are [`crate::model::session_residuals`] of `ds`, one set per space tried.
///
/// # Errors
/// Fewer than 2 shots, no measured kernels, the Gaussian model's own errors, or
/// cancellation.
#[allow(clippy::too_many_arguments)]
pub fn cross_validate_shape(
    ds: &Dataset,
    residuals: &[(crate::model::ShapeSpace, Vec<Option<Vec<f32>>>)],
    kind: ModelKind,
    alpha: usize,
    beta: usize,
    cv: &CvOptions,
    opts: &ShapeCvOptions,
    job: &JobContext,
) -> Result<ShapeCvReport, ModelError> {
    use crate::model::{
        ShapeFit, kernel_with_residual, kernel_with_shape, relative_l2, to_gaussian,
    };
    use rayon::prelude::*;
    ds.validate()?;
    if ds.shots.len() < 2 {
        return Err(ModelError::TooFewShots {
            shots: ds.shots.len(),
        });
    }
    if residuals.is_empty()
        || residuals.iter().any(|(_, r)| r.len() != ds.samples.len())
        || residuals[0].1.iter().all(Option::is_none)
    {
        return Err(ModelError::Empty);
    }
    let has_kernel = |i: usize| residuals.iter().all(|(_, r)| r[i].is_some());
    let (fold_of_shot, folds) = assign_folds(ds, cv.folds, cv.hold_out, cv.seed);
    let mut components: Vec<usize> = opts
        .components
        .iter()
        .copied()
        .filter(|&k| k > 0 && k <= crate::model::MAX_COMPONENTS)
        .collect();
    components.sort_unstable();
    components.dedup();
    let k_max = components.last().copied().unwrap_or(0);
    // Every (space, α) tried.
    let combos: Vec<(usize, usize)> = (0..residuals.len())
        .flat_map(|si| {
            opts.alphas
                .iter()
                .copied()
                .filter(|&a| crate::model::check_order(a, beta).is_ok())
                .map(move |a| (si, a))
        })
        .collect();
    // errors[m][c]: held-out errors of combo m, component count index c.
    let mut errors = vec![vec![Vec::new(); components.len()]; combos.len()];
    let mut usable = vec![true; combos.len()];
    // (f-number, Gaussian error, errors[m][c]) per held-out kernel.
    let mut held: Vec<(f64, f64, Vec<Vec<f64>>)> = Vec::new();
    for fold in 0..folds {
        job.check()?;
        job.report("kernel shapes", fold, folds);
        let (train, train_idx) = shots_subset(ds, |s| fold_of_shot[s] != fold);
        let test: Vec<usize> = (0..ds.samples.len())
            .filter(|&i| fold_of_shot[ds.samples[i].shot] == fold && has_kernel(i))
            .collect();
        if test.is_empty() || train.samples.is_empty() {
            continue;
        }
        let gaussian_model = fit_model(&train, kind, alpha, beta, &cv.local)?;
        let fits: Vec<Option<ShapeFit>> = residuals
            .iter()
            .map(|(space, res)| {
                let train_res: Vec<Option<Vec<f32>>> =
                    train_idx.iter().map(|&i| res[i].clone()).collect();
                ShapeFit::new(&train, *space, &train_res, k_max).ok()
            })
            .collect();
        let models: Vec<Option<crate::model::ShapeModel>> = combos
            .iter()
            .map(|&(si, a)| fits[si].as_ref()?.model(&train, a, beta).ok())
            .collect();
        for (u, m) in usable.iter_mut().zip(&models) {
            *u &= m.is_some();
        }
        let scored: Vec<(f64, f64, Vec<Vec<f64>>)> = test
            .par_iter()
            .filter_map(|&i| {
                let s = &ds.samples[i];
                let measured = s.kernel.as_ref()?;
                let setting = s.setting();
                let g = to_gaussian(gaussian_model.predict(s.channel, s.x, s.y, setting)?);
                let (os, size) = (measured.oversample, Some(measured.size));
                let plain = kernel_with_residual(&g, None, os, size)?;
                let e_gauss = relative_l2(&plain, measured);
                let per_combo = models
                    .iter()
                    .map(|m| {
                        let Some(m) = m else {
                            return vec![f64::NAN; components.len()];
                        };
                        let Some(c) = m.coefficients(s.channel, s.x, s.y, setting) else {
                            return vec![f64::NAN; components.len()];
                        };
                        let mut r = vec![0.0; m.space.values()];
                        let mut used = 0;
                        components
                            .iter()
                            .map(|&k| {
                                for (b, &ci) in m.components[used..k].iter().zip(&c[used..k]) {
                                    for (acc, v) in r.iter_mut().zip(b) {
                                        *acc += ci * v;
                                    }
                                }
                                used = k;
                                kernel_with_shape(m.space, &g, Some(&r), os, size)
                                    .map_or(f64::NAN, |k| relative_l2(&k, measured))
                            })
                            .collect()
                    })
                    .collect();
                Some((s.f_number, e_gauss, per_combo))
            })
            .collect();
        held.extend(scored);
    }
    job.report("kernel shapes", folds, folds);
    if held.is_empty() {
        return Err(ModelError::Empty);
    }
    for (_, _, per_combo) in &held {
        for (m, row) in per_combo.iter().enumerate() {
            for (c, &e) in row.iter().enumerate() {
                if e.is_finite() {
                    errors[m][c].push(e);
                }
            }
        }
    }
    let mut gauss: Vec<f64> = held.iter().map(|h| h.1).filter(|e| e.is_finite()).collect();
    let gaussian = rel_l2_point(crate::model::ShapeSpace::Whitened, 0, beta, 0, &mut gauss);
    let mut points = Vec::new();
    for (m, &(si, alpha_s)) in combos.iter().enumerate() {
        if !usable[m] {
            continue;
        }
        for (c, &k) in components.iter().enumerate() {
            let mut e = errors[m][c].clone();
            if e.len() == held.len() {
                points.push((
                    m,
                    c,
                    rel_l2_point(residuals[si].0, alpha_s, beta, k, &mut e),
                ));
            }
        }
    }
    let best = points
        .iter()
        .min_by(|x, y| x.2.mean_rel_l2.total_cmp(&y.2.mean_rel_l2))
        .cloned();
    let f_numbers = LensSetting::distinct_values(held.iter().map(|h| h.0));
    let per_aperture = match &best {
        Some((a, c, _)) => f_numbers
            .iter()
            .map(|&f| {
                let mine: Vec<&(f64, f64, Vec<Vec<f64>>)> = held
                    .iter()
                    .filter(|h| LensSetting::same_value(h.0, f))
                    .collect();
                let n = mine.len().max(1) as f64;
                ApertureError {
                    f_number: f,
                    kernels: mine.len(),
                    gaussian_mean_rel_l2: mine.iter().map(|h| h.1).sum::<f64>() / n,
                    shape_mean_rel_l2: mine.iter().map(|h| h.2[*a][*c]).sum::<f64>() / n,
                }
            })
            .collect(),
        None => Vec::new(),
    };
    let best_shape = best.map(|b| b.2);
    let shape_chosen = best_shape
        .as_ref()
        .is_some_and(|b| b.mean_rel_l2 < gaussian.mean_rel_l2);
    Ok(ShapeCvReport {
        folds,
        kernels: held.len(),
        gaussian_model: kind.model_name(alpha, beta),
        gaussian,
        points: points.into_iter().map(|p| p.2).collect(),
        best_shape,
        shape_chosen,
        per_aperture,
    })
}
