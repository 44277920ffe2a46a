//! Cross-validation of the kernel-shape model: the Gaussian models' folds (whole
//! shots), the Gaussian model, shape basis and coefficient fields fitted without each
//! fold, every held-out measured kernel against its prediction, by relative L2 and by
//! the error the prediction leaves in a deblurred photo
//! ([`crate::model::RestorationError`]), which chooses the model by default.
//!
//! Nothing is refitted from the samples per fold where the fit is linear least squares:
//! the Gaussian model's and the coefficient fields' normal equations are accumulated
//! once, split by fold, and a fold's training system is the total minus the fold's
//! (the grouped form of PRESS). The coefficient fields' right-hand sides are kept
//! against the residuals themselves (basis terms × grid values), so a fold's own shape
//! components, learnt from its training residuals by the randomised SVD, turn them
//! into the fold's right-hand sides with one small product; the orders tried are
//! sub-blocks of the largest. Each held-out kernel's grid is prepared once per fold
//! and space ([`crate::model::PreparedKernels`]), so each model it is judged against
//! costs a weighted sum per grid sample. The refitting form is kept in the tests as
//! the oracle these must equal.

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
    /// What the model is chosen by.
    pub criterion: ShapeCriterion,
}

impl Default for ShapeCvOptions {
    fn default() -> Self {
        Self {
            alphas: vec![1, 2, 3, 4, 6],
            components: vec![0, 1, 2, 3, 4, 6, 8],
            spaces: vec![crate::model::ShapeSpace::Whitened],
            criterion: ShapeCriterion::default(),
        }
    }
}

/// What the kernel-shape model (its space, order and number of components, and
/// whether to keep one at all) is chosen by, over the held-out kernels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ShapeCriterion {
    /// The mean error the predicted kernel leaves in a deblurred photo
    /// ([`crate::model::RestorationError`]).
    #[default]
    Restoration,
    /// The mean relative L2 of the 3× kernels (how profiles before the restoration
    /// error chose).
    HeldOutL2,
}

impl ShapeCriterion {
    /// What a profile that does not say was chosen by.
    fn held_out_l2() -> Self {
        Self::HeldOutL2
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Restoration => "restoration error",
            Self::HeldOutL2 => "held-out L2",
        }
    }

    /// A point's figure under this criterion, in words: "restoration error 0.012".
    #[must_use]
    pub fn describe(self, p: &ShapeCvPoint) -> String {
        match (self, p.restoration_rms) {
            (Self::Restoration, Some(r)) => format!("restoration error {r:.4}"),
            _ => format!("relative L2 {:.3}", p.mean_rel_l2),
        }
    }

    /// A point's figure under this criterion (lower is better); infinite where the
    /// point has none.
    #[must_use]
    pub fn score(self, p: &ShapeCvPoint) -> f64 {
        match self {
            Self::Restoration => p.restoration_rms.unwrap_or(f64::INFINITY),
            Self::HeldOutL2 => p.mean_rel_l2,
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
    /// √(mean restoration error) over the held-out kernels: the RMS error the
    /// predicted kernels leave in a deblurred photo of unit gradient RMS
    /// ([`crate::model::RestorationError`]). Absent in profiles made before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restoration_rms: Option<f64>,
}

/// The held-out errors at one aperture: the Gaussian's and the best shape model's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ApertureError {
    pub f_number: f64,
    pub kernels: usize,
    pub gaussian_mean_rel_l2: f64,
    pub shape_mean_rel_l2: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gaussian_restoration_rms: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape_restoration_rms: Option<f64>,
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
    /// What the model was chosen by (held-out L2 in profiles that do not say).
    #[serde(default = "ShapeCriterion::held_out_l2")]
    pub criterion: ShapeCriterion,
    /// The shape model with the lowest error by `criterion`.
    pub best_shape: Option<ShapeCvPoint>,
    /// The shape model held-out L2 alone would choose, for comparison.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_by_l2: Option<ShapeCvPoint>,
    /// Whether `best_shape` beats the Gaussian by `criterion`: the profile then holds it.
    pub shape_chosen: bool,
    /// Per aperture: the Gaussian's and `best_shape`'s errors.
    pub per_aperture: Vec<ApertureError>,
}

/// One held-out kernel's errors under one model: relative L2 of the 3× kernels and
/// the restoration error ([`crate::model::RestorationError`]); NaN where the model
/// predicts none.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct KernelErrors {
    pub(super) rel_l2: f64,
    pub(super) restoration: f64,
}

impl KernelErrors {
    pub(super) const NONE: Self = Self {
        rel_l2: f64::NAN,
        restoration: f64::NAN,
    };

    fn is_finite(self) -> bool {
        self.rel_l2.is_finite() && self.restoration.is_finite()
    }
}

fn error_point(
    space: crate::model::ShapeSpace,
    alpha: usize,
    beta: usize,
    components: usize,
    errors: &[KernelErrors],
) -> ShapeCvPoint {
    let mut l2: Vec<f64> = errors.iter().map(|e| e.rel_l2).collect();
    l2.sort_by(f64::total_cmp);
    let n = errors.len().max(1) as f64;
    let mean = l2.iter().sum::<f64>() / n;
    let restoration = errors.iter().map(|e| e.restoration).sum::<f64>() / n;
    ShapeCvPoint {
        space,
        alpha,
        beta,
        components,
        mean_rel_l2: mean,
        median_rel_l2: percentile_sorted(&l2, 50.0),
        p95_rel_l2: percentile_sorted(&l2, 95.0),
        restoration_rms: Some(restoration.sqrt()),
    }
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
    let tried = Tried::new(opts, residuals.iter().map(|r| r.0).collect(), beta);
    let (combos, k_max) = (&tried.combos, tried.k_max);
    // The held-out kernels of each fold; a fold with none, or with no training
    // samples, is not judged.
    let tests: Vec<Vec<usize>> = (0..folds)
        .map(|fold| {
            (0..ds.samples.len())
                .filter(|&i| fold_of_shot[ds.samples[i].shot] == fold && has_kernel(i))
                .collect()
        })
        .collect();
    let judged = |fold: usize| {
        !tests[fold].is_empty() && ds.samples.iter().any(|s| fold_of_shot[s.shot] != fold)
    };
    let gaussian_models = fold_gaussian_models(
        ds,
        kind,
        (alpha, beta),
        &cv.local,
        &fold_of_shot,
        folds,
        judged,
    )?;
    job.check()?;
    let systems: Vec<ShapeSystems> = residuals
        .iter()
        .enumerate()
        .map(|(si, (_, res))| {
            let alphas = combos.iter().filter(|c| c.0 == si).map(|c| c.1);
            ShapeSystems::build(
                ds,
                res,
                alphas.max().unwrap_or(0),
                beta,
                &fold_of_shot,
                folds,
            )
        })
        .collect();
    let mut usable = vec![true; combos.len()];
    let mut held: Held = Vec::new();
    let fold_bases = fold_bases(ds, residuals, &fold_of_shot, &gaussian_models, k_max);
    for fold in 0..folds {
        job.check()?;
        job.report("kernel shapes", fold, folds);
        let Some(gaussian_model) = gaussian_models[fold].as_ref() else {
            continue;
        };
        let bases = &fold_bases[fold];
        let norm = shots_subset(ds, |s| fold_of_shot[s] != fold)
            .0
            .normalisation();
        let models: Vec<Option<crate::model::ShapeModel>> = combos
            .iter()
            .map(|&(si, a)| {
                let (space, _) = residuals[si];
                systems[si].model(space, bases[si].as_ref()?, &norm, a, beta, fold)
            })
            .collect();
        for (u, m) in usable.iter_mut().zip(&models) {
            *u &= m.is_some();
        }
        let judge = FoldJudge {
            residuals,
            bases,
            tried: &tried,
            models: &models,
            gaussian_model: gaussian_model.as_ref(),
        };
        let scored: Held = tests[fold]
            .par_iter()
            .filter_map(|&i| judge.held_kernel(&ds.samples[i]))
            .collect();
        held.extend(scored);
    }
    job.report("kernel shapes", folds, folds);
    report(&tried, &held, &usable, kind, (alpha, beta), folds)
}

/// Per fold and space: the shape components learnt without the fold, as the
/// session's are (from its training residuals, in session order). Not linear in the
/// residuals, so learnt per fold; the folds in parallel. Empty for a fold not judged.
fn fold_bases(
    ds: &Dataset,
    residuals: &[(crate::model::ShapeSpace, Vec<Option<Vec<f32>>>)],
    fold_of_shot: &[usize],
    gaussian_models: &[Option<Box<dyn crate::model::FittedModel>>],
    k_max: usize,
) -> Vec<Vec<Option<Vec<Vec<f64>>>>> {
    use rayon::prelude::*;
    (0..gaussian_models.len())
        .into_par_iter()
        .map(|fold| {
            if gaussian_models[fold].is_none() {
                return Vec::new();
            }
            residuals
                .iter()
                .map(|(_, res)| {
                    let rows: Vec<&[f32]> = ds
                        .samples
                        .iter()
                        .zip(res)
                        .filter(|(s, _)| fold_of_shot[s.shot] != fold)
                        .filter_map(|(_, r)| r.as_deref())
                        .collect();
                    (!rows.is_empty()).then(|| crate::model::shape_basis(&rows, k_max))
                })
                .collect()
        })
        .collect()
}

/// What one fold judges its held-out kernels with: the fold's Gaussian model, its shape
/// bases per space and the shape models tried.
struct FoldJudge<'a> {
    residuals: &'a [(crate::model::ShapeSpace, Vec<Option<Vec<f32>>>)],
    bases: &'a [Option<Vec<Vec<f64>>>],
    tried: &'a Tried,
    models: &'a [Option<crate::model::ShapeModel>],
    gaussian_model: &'a dyn crate::model::FittedModel,
}

impl FoldJudge<'_> {
    /// The errors of the Gaussian and of every model tried on held-out sample `s`.
    fn held_kernel(&self, s: &crate::model::BlurSample) -> Option<HeldKernel> {
        use crate::model::{
            PreparedKernels, RestorationError, deployed_kernel_side, kernel_with_residual,
            relative_l2, to_gaussian,
        };
        let (tried, residuals, bases) = (self.tried, self.residuals, self.bases);
        let components = &tried.components;
        let measured = s.kernel.as_ref()?;
        let setting = s.setting();
        let g = to_gaussian(self.gaussian_model.predict(s.channel, s.x, s.y, setting)?);
        let (os, size) = (measured.oversample, measured.size);
        if size % 2 == 0 {
            // Not a kernel the measured chain makes (they are odd-sized, and the
            // prepared grids are the measured one); judged as the Gaussian alone.
            let plain = kernel_with_residual(&g, None, os, Some(size))?;
            let row = vec![KernelErrors::NONE; components.len()];
            return Some(HeldKernel {
                f_number: s.f_number,
                gaussian: KernelErrors {
                    rel_l2: relative_l2(&plain, measured),
                    restoration: f64::NAN,
                },
                per_combo: vec![row; tried.combos.len()],
            });
        }
        let (grid, measured) = judged_grid(measured, &g, &tried.spaces)?;
        let mut restoration = RestorationError::new(&measured, crate::model::WIENER_NSR)?;
        // Each space's kernels as deblurring renders them, on the common grid, prepared
        // once for every model.
        let prepared: Vec<PreparedKernels> = residuals
            .iter()
            .zip(bases)
            .map(|((space, _), b)| {
                let deployed = deployed_kernel_side(*space, &g, os)?;
                let b = b.as_deref().unwrap_or(&[]);
                PreparedKernels::new(*space, &g, b, os, grid, deployed)
            })
            .collect::<Option<_>>()?;
        // The Gaussian alone: its density on its own support, which is the whitened
        // space's base where that space is tried.
        let whitened = crate::model::ShapeSpace::Whitened;
        let plain: std::borrow::Cow<'_, [f64]> =
            match residuals.iter().position(|(space, _)| *space == whitened) {
                Some(i) => prepared[i].base().into(),
                None => {
                    let deployed = deployed_kernel_side(whitened, &g, os)?;
                    PreparedKernels::new(whitened, &g, &[], os, grid, deployed)?
                        .base()
                        .to_vec()
                        .into()
                }
            };
        let gaussian = KernelErrors {
            rel_l2: PreparedKernels::relative_l2(&plain, &measured),
            restoration: restoration.of_values(&plain),
        };
        let linear: Vec<Linear1x> = prepared
            .iter()
            .map(|p| Linear1x::new(&mut restoration, p))
            .collect();
        let mut values = Vec::new();
        let per_combo = self
            .models
            .iter()
            .zip(&tried.combos)
            .map(|(m, &(si, _))| {
                let none = || vec![KernelErrors::NONE; components.len()];
                let Some(c) = m
                    .as_ref()
                    .and_then(|m| m.coefficients(s.channel, s.x, s.y, setting))
                else {
                    return none();
                };
                let (p, lin) = (&prepared[si], &linear[si]);
                values.clear();
                values.extend_from_slice(p.base());
                let (mut samples, mut spectrum) = lin.base.clone();
                let mut used = 0;
                components
                    .iter()
                    .map(|&k| {
                        if k > c.len() {
                            return KernelErrors::NONE;
                        }
                        p.add(&mut values, used..k, &c);
                        lin.add(&mut samples, &mut spectrum, used..k, &c);
                        used = k;
                        // Where clipping at zero changes nothing, the kernel's spectrum
                        // is the weighted sum already at hand.
                        let restoration = if samples.iter().all(|v| *v >= 0.0) {
                            restoration.of_spectrum(&spectrum)
                        } else {
                            restoration.of_values(&values)
                        };
                        KernelErrors {
                            rel_l2: PreparedKernels::relative_l2(&values, &measured),
                            restoration,
                        }
                    })
                    .collect()
            })
            .collect();
        Some(HeldKernel {
            f_number: s.f_number,
            gaussian,
            per_combo,
        })
    }
}

/// One space's prepared kernels ([`crate::model::PreparedKernels`]) at 1×, the base and each
/// component with its spectrum: a model's kernel is a weighted sum of them, and so is
/// its spectrum, as long as clipping at zero changes nothing. Each model judged then
/// costs a weighted sum instead of a transform.
struct Linear1x {
    base: (Vec<f64>, Vec<rustfft::num_complex::Complex64>),
    components: Vec<(Vec<f64>, Vec<rustfft::num_complex::Complex64>)>,
}

impl Linear1x {
    fn new(r: &mut crate::model::RestorationError, p: &crate::model::PreparedKernels) -> Self {
        let mut at_1x = |values: &[f64]| {
            let samples = r.samples(values);
            let spectrum = r.spectrum_of(&samples);
            (samples, spectrum)
        };
        Self {
            base: at_1x(p.base()),
            components: (0..p.components()).map(|k| at_1x(p.component(k))).collect(),
        }
    }

    /// Adds components `range` with their `coeffs` to 1× `samples` and their `spectrum`.
    fn add(
        &self,
        samples: &mut [f64],
        spectrum: &mut [rustfft::num_complex::Complex64],
        range: std::ops::Range<usize>,
        coeffs: &[f64],
    ) {
        for k in range {
            let (ck, (s, f)) = (coeffs[k], &self.components[k]);
            for (a, b) in samples.iter_mut().zip(s) {
                *a += ck * b;
            }
            for (a, b) in spectrum.iter_mut().zip(f) {
                *a += b * ck;
            }
        }
    }
}

/// The grid a held-out kernel and the kernels predicted for it are compared on: the
/// measured kernel's, grown to hold the largest kernel deblurring would render around
/// `g` in any of `spaces` (a pixel-space shape reaches ±6 px however sharp the core);
/// with the measured kernel's [`crate::model::psf_mass`], which the shapes are learnt
/// from, on it. A prediction judged only where the measured kernel was would hide what
/// it puts beyond.
pub(super) fn judged_grid(
    measured: &crate::psf::Kernel,
    g: &crate::psf::Gaussian2,
    spaces: &[crate::model::ShapeSpace],
) -> Option<(usize, crate::psf::Kernel)> {
    let mut grid = measured.size;
    for &space in spaces
        .iter()
        .chain(std::iter::once(&crate::model::ShapeSpace::Whitened))
    {
        grid = grid.max(crate::model::deployed_kernel_side(
            space,
            g,
            measured.oversample,
        )?);
    }
    Some((grid, crate::model::psf_mass(measured).padded(grid)))
}

/// The models a shape cross-validation tries: the numbers of components (ascending;
/// each fold learns the largest) and every (space index, α).
pub(super) struct Tried {
    pub(super) components: Vec<usize>,
    pub(super) k_max: usize,
    pub(super) combos: Vec<(usize, usize)>,
    /// The spaces of the residual sets, in their order.
    pub(super) spaces: Vec<crate::model::ShapeSpace>,
    pub(super) criterion: ShapeCriterion,
}

impl Tried {
    pub(super) fn new(
        opts: &ShapeCvOptions,
        spaces: Vec<crate::model::ShapeSpace>,
        beta: usize,
    ) -> Self {
        let mut components: Vec<usize> = opts
            .components
            .iter()
            .copied()
            .filter(|&k| k > 0 && k <= crate::model::MAX_COMPONENTS)
            .collect();
        components.sort_unstable();
        components.dedup();
        let k_max = components.last().copied().unwrap_or(0);
        let combos = (0..spaces.len())
            .flat_map(|si| {
                opts.alphas
                    .iter()
                    .copied()
                    .filter(|&a| crate::model::check_order(a, beta).is_ok())
                    .map(move |a| (si, a))
            })
            .collect();
        Self {
            components,
            k_max,
            combos,
            spaces,
            criterion: opts.criterion,
        }
    }
}

/// One held-out kernel: its f-number, the Gaussian's errors, and `[combo][count]` the
/// errors of each model tried (NaN where it could not be predicted).
pub(super) struct HeldKernel {
    pub(super) f_number: f64,
    pub(super) gaussian: KernelErrors,
    pub(super) per_combo: Vec<Vec<KernelErrors>>,
}

pub(super) type Held = Vec<HeldKernel>;

/// The report from the held-out errors; `usable[m]`: combo m could be fitted in every
/// fold.
pub(super) fn report(
    tried: &Tried,
    held: &Held,
    usable: &[bool],
    kind: ModelKind,
    (alpha, beta): (usize, usize),
    folds: usize,
) -> Result<ShapeCvReport, ModelError> {
    let (components, combos) = (&tried.components, &tried.combos);
    let (spaces, criterion) = (&tried.spaces, tried.criterion);
    // errors[m][c]: held-out errors of combo m, component count index c.
    let mut errors = vec![vec![Vec::new(); components.len()]; combos.len()];
    if held.is_empty() {
        return Err(ModelError::Empty);
    }
    for h in held {
        for (m, row) in h.per_combo.iter().enumerate() {
            for (c, &e) in row.iter().enumerate() {
                if e.is_finite() {
                    errors[m][c].push(e);
                }
            }
        }
    }
    // The Gaussian is judged on the kernels every model is: a kernel whose
    // restoration error is undefined (no 1× mass) is left out of both.
    let gauss: Vec<KernelErrors> = held
        .iter()
        .map(|h| h.gaussian)
        .filter(|e| e.rel_l2.is_finite())
        .collect();
    let mut gaussian = error_point(crate::model::ShapeSpace::Whitened, 0, beta, 0, &gauss);
    if gauss.iter().any(|e| !e.restoration.is_finite()) {
        gaussian.restoration_rms = None;
    }
    let mut points = Vec::new();
    for (m, &(si, alpha_s)) in combos.iter().enumerate() {
        if !usable[m] {
            continue;
        }
        for (c, &k) in components.iter().enumerate() {
            if errors[m][c].len() == held.len() {
                points.push((
                    m,
                    c,
                    error_point(spaces[si], alpha_s, beta, k, &errors[m][c]),
                ));
            }
        }
    }
    let best_by = |criterion: ShapeCriterion| {
        points
            .iter()
            .min_by(|x, y| criterion.score(&x.2).total_cmp(&criterion.score(&y.2)))
            .cloned()
    };
    let best = best_by(criterion);
    let best_by_l2 = best_by(ShapeCriterion::HeldOutL2).map(|b| b.2);
    let f_numbers = LensSetting::distinct_values(held.iter().map(|h| h.f_number));
    let per_aperture = match &best {
        Some((a, c, _)) => f_numbers
            .iter()
            .map(|&f| {
                let mine: Vec<&HeldKernel> = held
                    .iter()
                    .filter(|h| LensSetting::same_value(h.f_number, f))
                    .collect();
                let n = mine.len().max(1) as f64;
                let mean =
                    |e: &dyn Fn(&HeldKernel) -> f64| mine.iter().map(|h| e(h)).sum::<f64>() / n;
                let rms = |v: f64| v.is_finite().then(|| v.sqrt());
                ApertureError {
                    f_number: f,
                    kernels: mine.len(),
                    gaussian_mean_rel_l2: mean(&|h| h.gaussian.rel_l2),
                    shape_mean_rel_l2: mean(&|h| h.per_combo[*a][*c].rel_l2),
                    gaussian_restoration_rms: rms(mean(&|h| h.gaussian.restoration)),
                    shape_restoration_rms: rms(mean(&|h| h.per_combo[*a][*c].restoration)),
                }
            })
            .collect(),
        None => Vec::new(),
    };
    let best_shape = best.map(|b| b.2);
    let shape_chosen = best_shape
        .as_ref()
        .is_some_and(|b| criterion.score(b) < criterion.score(&gaussian));
    Ok(ShapeCvReport {
        folds,
        kernels: held.len(),
        gaussian_model: kind.model_name(alpha, beta),
        gaussian,
        points: points.into_iter().map(|p| p.2).collect(),
        criterion,
        best_shape,
        best_by_l2,
        shape_chosen,
        per_aperture,
    })
}

/// The coefficient fields' least-squares problems in one space, split by fold: per
/// channel and fold, over the samples with a residual, the Gram matrix of the largest
/// order's basis and that basis against the residuals themselves (terms × grid
/// values). A fold's components turn the latter into its right-hand sides: the
/// coordinates of a residual are linear in it.
struct ShapeSystems {
    union: Basis,
    channels: Vec<ShapeChannelSystem>,
}

struct ShapeChannelSystem {
    channel: Channel,
    /// Samples with a residual, per fold and in all.
    rows: Vec<usize>,
    rows_total: usize,
    gram: Vec<DMatrix<f64>>,
    gram_total: DMatrix<f64>,
    cross: Vec<DMatrix<f64>>,
    cross_total: DMatrix<f64>,
}

impl ShapeSystems {
    fn build(
        ds: &Dataset,
        residuals: &[Option<Vec<f32>>],
        max_alpha: usize,
        beta: usize,
        fold_of_shot: &[usize],
        folds: usize,
    ) -> Self {
        use rayon::prelude::*;
        let norm = ds.normalisation();
        let union = model_basis(&norm, max_alpha, beta);
        let values = residuals.iter().flatten().next().map_or(0, Vec::len);
        let channels = ds
            .channels()
            .into_iter()
            .map(|channel| {
                let per_fold: Vec<(usize, DMatrix<f64>, DMatrix<f64>)> = (0..folds)
                    .into_par_iter()
                    .map(|k| {
                        let mine: Vec<(&crate::model::BlurSample, &Vec<f32>)> = ds
                            .samples
                            .iter()
                            .zip(residuals)
                            .filter(|(s, _)| s.channel == channel && fold_of_shot[s.shot] == k)
                            .filter_map(|(s, r)| Some((s, r.as_ref()?)))
                            .collect();
                        // The design transposed (a column per sample), so both products
                        // are plain matrix products (blocked, unlike tr_mul's dot products).
                        let mut at = DMatrix::zeros(union.len(), mine.len());
                        let mut r = DMatrix::zeros(mine.len(), values);
                        let mut row = vec![0.0; union.len()];
                        for (n, (s, res)) in mine.iter().enumerate() {
                            union.row(
                                global_coords(&norm, s.x, s.y, s.focal_mm, s.f_number),
                                &mut row,
                            );
                            at.column_mut(n).copy_from_slice(&row);
                            for (col, v) in res.iter().enumerate().take(values) {
                                r[(n, col)] = f64::from(*v);
                            }
                        }
                        (mine.len(), &at * at.transpose(), &at * r)
                    })
                    .collect();
                let mut gram_total = DMatrix::zeros(union.len(), union.len());
                let mut cross_total = DMatrix::zeros(union.len(), values);
                for (_, g, c) in &per_fold {
                    gram_total += g;
                    cross_total += c;
                }
                let rows: Vec<usize> = per_fold.iter().map(|p| p.0).collect();
                let (gram, cross) = per_fold.into_iter().map(|p| (p.1, p.2)).unzip();
                ShapeChannelSystem {
                    channel,
                    rows_total: rows.iter().sum(),
                    rows,
                    gram,
                    gram_total,
                    cross,
                    cross_total,
                }
            })
            .collect();
        Self { union, channels }
    }

    /// The shape model of orders (α, β) with `components`, its coefficient fields
    /// fitted without `fold`; `norm` is the fold's training normalisation. `None`
    /// where a channel has fewer training residuals than terms, or no channel has any.
    fn model(
        &self,
        space: crate::model::ShapeSpace,
        components: &[Vec<f64>],
        norm: &Normalisation,
        alpha: usize,
        beta: usize,
        fold: usize,
    ) -> Option<crate::model::ShapeModel> {
        let basis = model_basis(norm, alpha, beta);
        let subset = subset_of(&self.union, &basis);
        let k = components.len();
        let mut channels = Vec::new();
        for c in &self.channels {
            let n = c.rows_total - c.rows[fold];
            if n == 0 {
                continue;
            }
            if n < basis.len() {
                return None;
            }
            let coeffs = if k == 0 {
                Vec::new()
            } else {
                let gram = (&c.gram_total - &c.gram[fold])
                    .select_rows(&subset)
                    .select_columns(&subset);
                let cross = (&c.cross_total - &c.cross[fold]).select_rows(&subset);
                let b = DMatrix::from_fn(cross.ncols(), k, |v, j| components[j][v]);
                let x = solve_normal(gram, &(cross * b));
                (0..k)
                    .map(|j| x.column(j).iter().copied().collect())
                    .collect()
            };
            channels.push((c.channel, coeffs));
        }
        (!channels.is_empty()).then(|| crate::model::ShapeModel {
            space,
            norm: norm.clone(),
            alpha,
            beta,
            basis,
            components: components.to_vec(),
            channels,
        })
    }
}
