//! Cross-validation and model selection.
//!
//! Whole shots are held out (the paper's holdout-10: each fold holds about 10 % of the
//! shots, assigned by a fixed seeded shuffle so runs are repeatable); optionally every
//! shot of a setting together ([`HoldOut::Setting`]), which on the simulated 5 × 5 × 2
//! session chose models that predicted novel settings worse (smaller α, mostly), so it
//! is not the default. The error of a
//! parameter is |predicted − measured| / range × 100 %, where the range is the width of
//! the 0.5–99.5 percentile interval of that parameter over the whole dataset, all
//! channels pooled. Selection is two-staged: α with β = N − 1, then β with that α.
//!
//! Every fold's fit solves the normal equations of the largest candidate model once
//! accumulated per fold: the training Gram matrix of a fold is the total minus the
//! held-out fold's, and a smaller candidate is the matching sub-block. In the Legendre
//! basis these systems are well conditioned (the final fit uses QR; a unit test checks
//! the two agree). Each fold's fits are scored through [`FittedModel::predict`], the
//! prediction a profile makes.

use crate::job::JobContext;
use crate::model::design_system;
use crate::model::{
    Basis, CentreGrid, ChannelCoeffs, Dataset, FittedModel, GlobalModel, LocalModel, LocalOptions,
    ModelError, ModelKind, Normalisation, fit_model, global_coords, local_coords, local_grid,
    local_members, model_basis, solve_normal, split_coeffs,
};
use crate::plane::{Channel, LensSetting};
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

mod shape;
pub use shape::{
    ApertureError, ShapeCriterion, ShapeCvOptions, ShapeCvPoint, ShapeCvReport,
    cross_validate_shape,
};

/// What a fold holds out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HoldOut {
    /// Whole shots, assigned to folds independently (the paper's holdout).
    #[default]
    Shot,
    /// Every shot of a setting together, so each fold predicts settings the fit has not
    /// seen at all.
    Setting,
}

/// What to cross-validate.
#[derive(Clone, Debug)]
pub struct CvOptions {
    /// Number of folds; each holds out about 1/folds of the shots (10 = holdout-10).
    pub folds: usize,
    pub hold_out: HoldOut,
    pub global_alphas: Vec<usize>,
    pub local_alphas: Vec<usize>,
    pub local: LocalOptions,
    pub run_global: bool,
    pub run_local: bool,
    pub seed: u64,
}

impl Default for CvOptions {
    fn default() -> Self {
        Self {
            folds: 10,
            hold_out: HoldOut::Shot,
            global_alphas: (1..=8).collect(),
            local_alphas: vec![1, 2],
            local: LocalOptions::default(),
            run_global: true,
            run_local: true,
            seed: 0x1e45_b1a2,
        }
    }
}

/// The mean and 95th percentile of the errors of one (α, β), in % of range.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CvPoint {
    pub alpha: usize,
    pub beta: usize,
    pub terms: usize,
    /// Mean error per parameter (C_xx, C_yy, C_or).
    pub mean_error_pct: [f64; 3],
    /// 95th percentile of the error per parameter.
    pub p95_error_pct: [f64; 3],
    /// Mean over the three parameters: what selection minimises.
    pub mean_pct: f64,
}

/// Error distributions as quantiles: `cxx[i]` is the `percentiles[i]`-th percentile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorCdf {
    pub percentiles: Vec<f64>,
    pub cxx: Vec<f64>,
    pub cyy: Vec<f64>,
    pub cor: Vec<f64>,
}

impl ErrorCdf {
    #[must_use]
    pub fn from_errors(errors: &[Vec<f64>; 3]) -> Self {
        let percentiles: Vec<f64> = (0..=100).map(f64::from).collect();
        let q = |e: &Vec<f64>| {
            let mut s = e.clone();
            s.sort_by(f64::total_cmp);
            percentiles
                .iter()
                .map(|&p| percentile_sorted(&s, p))
                .collect()
        };
        Self {
            cxx: q(&errors[0]),
            cyy: q(&errors[1]),
            cor: q(&errors[2]),
            percentiles,
        }
    }
}

/// The selection of one model family: both stages' curves (Fig. 5), the choice, and
/// the chosen model's error distribution (Fig. 6).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    pub kind: ModelKind,
    pub alpha_curve: Vec<CvPoint>,
    pub beta_curve: Vec<CvPoint>,
    pub alpha: usize,
    pub beta: usize,
    pub chosen: CvPoint,
    pub error_cdf: ErrorCdf,
}

/// Parameter ranges (0.5–99.5 percentile widths) the errors are relative to.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ranges {
    pub cxx: f64,
    pub cyy: f64,
    pub cor: f64,
}

impl Ranges {
    #[must_use]
    pub fn as_array(&self) -> [f64; 3] {
        [self.cxx, self.cyy, self.cor]
    }
}

/// A whole cross-validation run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CvReport {
    pub schema: String,
    pub folds: usize,
    #[serde(default)]
    pub hold_out: HoldOut,
    pub shots: usize,
    pub n_f: usize,
    pub n_a: usize,
    pub ranges: Ranges,
    pub global: Option<Selection>,
    pub local: Option<Selection>,
    /// Errors at a separate test set's settings (the paper's Fig. 6), when one was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test: Option<TestReport>,
}

impl CvReport {
    /// The family with the lower cross-validation error, with its α, β.
    #[must_use]
    pub fn best(&self) -> Option<(ModelKind, usize, usize)> {
        let mut best: Option<&Selection> = None;
        for s in [&self.global, &self.local].into_iter().flatten() {
            if best.is_none_or(|b| s.chosen.mean_pct < b.chosen.mean_pct) {
                best = Some(s);
            }
        }
        best.map(|s| (s.kind, s.alpha, s.beta))
    }
}

/// Linear-interpolated percentile of sorted values (p in 0–100).
#[must_use]
pub fn percentile_sorted(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = (p / 100.0).clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let i = pos.floor() as usize;
    let f = pos - i as f64;
    if i + 1 < sorted.len() {
        sorted[i] * (1.0 - f) + sorted[i + 1] * f
    } else {
        sorted[i]
    }
}

/// The 0.5–99.5 percentile width of each parameter over the dataset.
#[must_use]
pub fn param_ranges(ds: &Dataset) -> Ranges {
    let r = |p: usize| {
        let mut v: Vec<f64> = ds.samples.iter().map(|s| s.params()[p]).collect();
        v.sort_by(f64::total_cmp);
        (percentile_sorted(&v, 99.5) - percentile_sorted(&v, 0.5)).max(1e-9)
    };
    Ranges {
        cxx: r(0),
        cyy: r(1),
        cor: r(2),
    }
}

/// Deterministic fold of each shot: a seeded shuffle, then round robin.
#[must_use]
pub fn shot_folds(n_shots: usize, folds: usize, seed: u64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..n_shots).collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    order.shuffle(&mut rng);
    let mut fold = vec![0; n_shots];
    for (rank, &shot) in order.iter().enumerate() {
        fold[shot] = rank % folds.max(1);
    }
    fold
}

/// The fold of every shot of `ds` and the number of folds: shots (or, with
/// [`HoldOut::Setting`], the settings with all their shots) shuffled with `seed` and
/// dealt round robin into at most `folds` folds.
#[must_use]
pub fn assign_folds(
    ds: &Dataset,
    folds: usize,
    hold_out: HoldOut,
    seed: u64,
) -> (Vec<usize>, usize) {
    match hold_out {
        HoldOut::Setting if ds.distinct_setting_pairs().len() >= 2 => {
            let settings = ds.distinct_setting_pairs();
            let group: Vec<usize> = ds
                .shots
                .iter()
                .map(|s| {
                    settings
                        .iter()
                        .position(|o| o.same_as(s.setting()))
                        .unwrap_or(0)
                })
                .collect();
            let k = folds.clamp(2, settings.len());
            let fold_of_group = shot_folds(settings.len(), k, seed);
            (group.iter().map(|&g| fold_of_group[g]).collect(), k)
        }
        // One setting only: its shots are the only units there are.
        HoldOut::Shot | HoldOut::Setting => {
            let k = folds.clamp(2, ds.shots.len().max(2));
            (shot_folds(ds.shots.len(), k, seed), k)
        }
    }
}

/// Errors (% of range) of a model's predictions at every sample of a dataset, per
/// parameter. Samples of a channel the model lacks are left out.
#[must_use]
pub fn prediction_errors(ds: &Dataset, ranges: &Ranges, model: &dyn FittedModel) -> [Vec<f64>; 3] {
    let r = ranges.as_array();
    let mut out: [Vec<f64>; 3] = Default::default();
    for s in &ds.samples {
        if let Some(p) = model.predict(s.channel, s.x, s.y, s.setting()) {
            push_errors(&mut out, p, s.params(), r);
        }
    }
    out
}

/// Appends |predicted − measured| / range × 100 % per parameter.
fn push_errors(out: &mut [Vec<f64>; 3], predicted: [f64; 3], measured: [f64; 3], r: [f64; 3]) {
    for k in 0..3 {
        out[k].push((predicted[k] - measured[k]).abs() / r[k] * 100.0);
    }
}

/// Summary of per-parameter errors.
#[must_use]
pub fn summarise(alpha: usize, beta: usize, terms: usize, errors: &[Vec<f64>; 3]) -> CvPoint {
    let mut mean = [0.0; 3];
    let mut p95 = [0.0; 3];
    for k in 0..3 {
        let mut s = errors[k].clone();
        s.sort_by(f64::total_cmp);
        mean[k] = if s.is_empty() {
            f64::NAN
        } else {
            s.iter().sum::<f64>() / s.len() as f64
        };
        p95[k] = percentile_sorted(&s, 95.0);
    }
    CvPoint {
        alpha,
        beta,
        terms,
        mean_error_pct: mean,
        p95_error_pct: p95,
        mean_pct: (mean[0] + mean[1] + mean[2]) / 3.0,
    }
}

/// One row of a least-squares problem: normalised coordinates, the measured C_xx, C_yy,
/// C_or, and the fold that holds the sample out.
struct Row {
    coords: [f64; 4],
    params: [f64; 3],
    fold: usize,
}

/// Normal equations of one least-squares problem, split by fold.
struct FoldedSystem {
    gram_total: DMatrix<f64>,
    rhs_total: DMatrix<f64>,
    gram_fold: Vec<DMatrix<f64>>,
    rhs_fold: Vec<DMatrix<f64>>,
}

impl FoldedSystem {
    fn build(basis: &Basis, rows: &[Row], folds: usize) -> Self {
        let n = basis.len();
        let mut gram_fold = Vec::with_capacity(folds);
        let mut rhs_fold = Vec::with_capacity(folds);
        for k in 0..folds {
            let mine: Vec<&Row> = rows.iter().filter(|r| r.fold == k).collect();
            let (a, y) = design_system(basis, mine.iter().map(|r| (r.coords, r.params)));
            // Aᵀ made once, so both products are blocked matrix products (tr_mul takes
            // a dot product per entry).
            let at = a.transpose();
            gram_fold.push(&at * &a);
            rhs_fold.push(&at * &y);
        }
        let mut gram_total = DMatrix::zeros(n, n);
        let mut rhs_total = DMatrix::zeros(n, 3);
        for k in 0..folds {
            gram_total += &gram_fold[k];
            rhs_total += &rhs_fold[k];
        }
        Self {
            gram_total,
            rhs_total,
            gram_fold,
            rhs_fold,
        }
    }

    /// Coefficients of C_xx, C_yy, C_or over the `subset` of the union's terms, fitted
    /// without fold `k` (or with all data when `k` is `None`).
    fn solve(&self, k: Option<usize>, subset: &[usize]) -> [Vec<f64>; 3] {
        let mut g = self.gram_total.select_rows(subset).select_columns(subset);
        let mut b = self.rhs_total.select_rows(subset);
        if let Some(k) = k {
            g -= self.gram_fold[k].select_rows(subset).select_columns(subset);
            b -= self.rhs_fold[k].select_rows(subset);
        }
        split_coeffs(&solve_normal(g, &b))
    }
}

fn subset_of(union: &Basis, sub: &Basis) -> Vec<usize> {
    sub.terms()
        .iter()
        .map(|t| union.terms().iter().position(|u| u == t).unwrap_or(0))
        .collect()
}

/// One measured sample as cross-validation sees it.
struct CvSample {
    x: f64,
    y: f64,
    setting: LensSetting,
    /// Measured C_xx, C_yy, C_or.
    params: [f64; 3],
    /// The fold that holds its shot out.
    fold: usize,
}

/// The samples of one channel.
struct ChannelData {
    channel: Channel,
    samples: Vec<CvSample>,
}

/// A channel's samples as rows of the global model: coordinates, parameters, fold.
fn global_rows(norm: &Normalisation, cd: &ChannelData) -> Vec<Row> {
    cd.samples
        .iter()
        .map(|s| Row {
            coords: global_coords(norm, s.x, s.y, s.setting.focal_mm, s.setting.f_number),
            params: s.params,
            fold: s.fold,
        })
        .collect()
}

fn channel_data(ds: &Dataset, fold_of_shot: &[usize]) -> Vec<ChannelData> {
    ds.channels()
        .into_iter()
        .map(|channel| ChannelData {
            channel,
            samples: ds
                .samples
                .iter()
                .filter(|s| s.channel == channel)
                .map(|s| CvSample {
                    x: s.x,
                    y: s.y,
                    setting: s.setting(),
                    params: s.params(),
                    fold: fold_of_shot[s.shot],
                })
                .collect(),
        })
        .collect()
}

/// One held-out sample's error as cross-validation found it: where and at which
/// setting it was measured, and the mean over C_xx, C_yy and C_or of its error in % of
/// range, predicted by the model fitted without its shot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldOutError {
    pub channel: Channel,
    pub x: f64,
    pub y: f64,
    pub setting: LensSetting,
    pub error_pct: f64,
}

/// Errors of every sample of `cd` as predicted by the model fitted without its fold
/// (`fold_models[k]` is the fit without fold k), appended to `out`, and each sample's
/// record to `at`.
fn score_held_out<M: FittedModel>(
    cd: &ChannelData,
    fold_models: &[M],
    r: [f64; 3],
    out: &mut [Vec<f64>; 3],
    at: &mut Vec<HeldOutError>,
) {
    use rayon::prelude::*;
    // Every held-out sample's prediction evaluates the model's basis there: in
    // parallel, then scored in sample order.
    let predicted: Vec<Option<[f64; 3]>> = cd
        .samples
        .par_iter()
        .map(|s| fold_models[s.fold].predict(cd.channel, s.x, s.y, s.setting))
        .collect();
    for (s, p) in cd.samples.iter().zip(predicted) {
        if let Some(p) = p {
            push_errors(out, p, s.params, r);
            let error_pct = (0..3).map(|k| out[k][out[k].len() - 1]).sum::<f64>() / 3.0;
            at.push(HeldOutError {
                channel: cd.channel,
                x: s.x,
                y: s.y,
                setting: s.setting,
                error_pct,
            });
        }
    }
}

/// A candidate's held-out errors: per parameter, the number of terms, and per sample.
type HeldOut = ([Vec<f64>; 3], usize, Vec<HeldOutError>);

/// What both families' engines hold: the session's normalisation, the basis of the
/// largest candidate (every smaller one's terms are a subset of it), the samples by
/// channel and the number of folds.
struct CvCommon {
    norm: Normalisation,
    union: Basis,
    data: Vec<ChannelData>,
    folds: usize,
}

impl CvCommon {
    fn new(
        ds: &Dataset,
        data: Vec<ChannelData>,
        max_alpha: usize,
        max_beta: usize,
        folds: usize,
    ) -> Self {
        let norm = ds.normalisation();
        let union = model_basis(&norm, max_alpha, max_beta);
        Self {
            norm,
            union,
            data,
            folds,
        }
    }

    /// The held-out errors of candidate (α, β) and its number of terms:
    /// `fold_models(c, basis, subset)` gives channel `c`'s models fitted without each
    /// fold (`subset`: the candidate's terms among the union's).
    fn errors<M: FittedModel>(
        &self,
        alpha: usize,
        beta: usize,
        ranges: &Ranges,
        fold_models: impl Fn(usize, &Basis, &[usize]) -> Vec<M>,
    ) -> HeldOut {
        let basis = model_basis(&self.norm, alpha, beta);
        let subset = subset_of(&self.union, &basis);
        let mut out: [Vec<f64>; 3] = Default::default();
        let mut at = Vec::new();
        for (c, cd) in self.data.iter().enumerate() {
            let models = fold_models(c, &basis, &subset);
            score_held_out(cd, &models, ranges.as_array(), &mut out, &mut at);
        }
        (out, basis.len(), at)
    }
}

/// The cross-validation engine of one family.
enum FamilyCv {
    Global(GlobalCv),
    Local(LocalCv),
}

impl FamilyCv {
    fn new(
        kind: ModelKind,
        ds: &Dataset,
        data: Vec<ChannelData>,
        local: &LocalOptions,
        (max_alpha, max_beta): (usize, usize),
        folds: usize,
    ) -> Self {
        let common = CvCommon::new(ds, data, max_alpha, max_beta, folds);
        match kind {
            ModelKind::Global => Self::Global(GlobalCv::new(common)),
            ModelKind::Local => Self::Local(LocalCv::new(ds, common, local)),
        }
    }

    fn errors(&self, alpha: usize, beta: usize, ranges: &Ranges) -> HeldOut {
        match self {
            Self::Global(cv) => cv.errors(alpha, beta, ranges),
            Self::Local(cv) => cv.errors(alpha, beta, ranges),
        }
    }
}

/// Cross-validation engine for the global family.
struct GlobalCv {
    common: CvCommon,
    systems: Vec<FoldedSystem>,
}

impl GlobalCv {
    fn new(common: CvCommon) -> Self {
        let systems = {
            use rayon::prelude::*;
            let (norm, union, folds) = (&common.norm, &common.union, common.folds);
            common
                .data
                .par_iter()
                .map(|cd| {
                    let rows = global_rows(norm, cd);
                    FoldedSystem::build(union, &rows, folds)
                })
                .collect()
        };
        Self { common, systems }
    }

    fn errors(&self, alpha: usize, beta: usize, ranges: &Ranges) -> HeldOut {
        use rayon::prelude::*;
        let cv = &self.common;
        cv.errors(alpha, beta, ranges, |c, basis, subset| {
            let (cd, sys) = (&cv.data[c], &self.systems[c]);
            (0..cv.folds)
                .into_par_iter()
                .map(|k| GlobalModel {
                    norm: cv.norm.clone(),
                    alpha,
                    beta,
                    basis: basis.clone(),
                    channels: vec![ChannelCoeffs {
                        channel: cd.channel,
                        coeffs: sys.solve(Some(k), subset),
                    }],
                })
                .collect()
        })
    }
}

/// The samples of `ds` whose shot `keep` accepts, with every shot's record (the
/// normalisation's ranges stay the session's, as in the Gaussian models' folds), and
/// their indices in `ds.samples`.
fn shots_subset(ds: &Dataset, keep: impl Fn(usize) -> bool) -> (Dataset, Vec<usize>) {
    let idx: Vec<usize> = (0..ds.samples.len())
        .filter(|&i| keep(ds.samples[i].shot))
        .collect();
    let sub = Dataset {
        width: ds.width,
        height: ds.height,
        identity: ds.identity.clone(),
        picture: ds.picture,
        samples: idx.iter().map(|&i| ds.samples[i].clone()).collect(),
        shots: ds.shots.clone(),
    };
    (sub, idx)
}

/// The Gaussian model `kind` G/L_{α,β} fitted without each fold: what [`fit_model`]
/// fits to the fold's training shots (with their samples' extent, and for the local
/// family the grid and each centre's members that the training samples give), solved
/// from normal equations accumulated once and split by fold, a fold's training system
/// being the total minus the fold's. A local centre whose training members are not the
/// session's members less the fold's (its circle widened, or the grid changed with the
/// fold) is fitted from its members directly. `None` for a fold that leaves no
/// training samples or that `wanted` declines (not fitted, so never an error).
///
/// # Errors
/// As [`fit_model`] on a fold's training shots.
fn fold_gaussian_models(
    ds: &Dataset,
    kind: ModelKind,
    (alpha, beta): (usize, usize),
    local: &LocalOptions,
    fold_of_shot: &[usize],
    folds: usize,
    wanted: impl Fn(usize) -> bool,
) -> Result<Vec<Option<Box<dyn FittedModel>>>, ModelError> {
    use rayon::prelude::*;
    // The training sets share the session's shots, so what fit_setup checks of them
    // (settings, orders, β against the settings) is the session's.
    let (norm, basis) = crate::model::fit_setup(ds, alpha, beta)?;
    let data = channel_data(ds, fold_of_shot);
    let all: Vec<usize> = (0..basis.len()).collect();
    let too_few = |channel: Channel, samples: usize| ModelError::TooFewSamples {
        model: format!("{} ({channel})", kind.model_name(alpha, beta)),
        samples,
        terms: basis.len(),
    };
    // Per fold, per channel: the training samples (indices into the channel's).
    let train_of = |k: usize, cd: &ChannelData| -> Vec<usize> {
        (0..cd.samples.len())
            .filter(|&i| cd.samples[i].fold != k)
            .collect()
    };
    let mut out = Vec::with_capacity(folds);
    match kind {
        ModelKind::Global => {
            let systems: Vec<FoldedSystem> = data
                .par_iter()
                .map(|cd| {
                    let rows = global_rows(&norm, cd);
                    FoldedSystem::build(&basis, &rows, folds)
                })
                .collect();
            for k in 0..folds {
                let (train, _) = shots_subset(ds, |s| fold_of_shot[s] != k);
                if train.samples.is_empty() || !wanted(k) {
                    out.push(None);
                    continue;
                }
                let mut channels = Vec::new();
                for (cd, sys) in data.iter().zip(&systems) {
                    let n = cd.samples.iter().filter(|s| s.fold != k).count();
                    if n == 0 {
                        continue;
                    }
                    if n < basis.len() {
                        return Err(too_few(cd.channel, n));
                    }
                    channels.push(ChannelCoeffs {
                        channel: cd.channel,
                        coeffs: sys.solve(Some(k), &all),
                    });
                }
                out.push(Some(Box::new(GlobalModel {
                    norm: train.normalisation(),
                    alpha,
                    beta,
                    basis: basis.clone(),
                    channels,
                }) as Box<dyn FittedModel>));
            }
        }
        ModelKind::Local => {
            let grid = local_grid(ds, local);
            // Per channel, per centre: the session's members and their folded system.
            let systems: Vec<Vec<(Vec<usize>, FoldedSystem)>> = data
                .iter()
                .map(|cd| {
                    let pts: Vec<[f64; 2]> = cd.samples.iter().map(|s| [s.x, s.y]).collect();
                    (0..grid.len())
                        .into_par_iter()
                        .map(|idx| {
                            let members = local_members(&grid, idx, &pts, basis.len());
                            let rows = local_rows(cd, &grid, &norm, idx, &members);
                            (members, FoldedSystem::build(&basis, &rows, folds))
                        })
                        .collect()
                })
                .collect();
            for k in 0..folds {
                let (train, _) = shots_subset(ds, |s| fold_of_shot[s] != k);
                if train.samples.is_empty() || !wanted(k) {
                    out.push(None);
                    continue;
                }
                let fold_grid = local_grid(&train, local);
                let mut channels = Vec::new();
                for (cd, centres) in data.iter().zip(&systems) {
                    let train_idx = train_of(k, cd);
                    if train_idx.is_empty() {
                        continue;
                    }
                    if train_idx.len() < basis.len() {
                        return Err(too_few(cd.channel, train_idx.len()));
                    }
                    let pts: Vec<[f64; 2]> = train_idx
                        .iter()
                        .map(|&i| [cd.samples[i].x, cd.samples[i].y])
                        .collect();
                    let coeffs: Vec<[Vec<f64>; 3]> = (0..fold_grid.len())
                        .into_par_iter()
                        .map(|idx| {
                            let members: Vec<usize> =
                                local_members(&fold_grid, idx, &pts, basis.len())
                                    .into_iter()
                                    .map(|m| train_idx[m])
                                    .collect();
                            if fold_grid == grid {
                                let (session, sys) = &centres[idx];
                                if session
                                    .iter()
                                    .filter(|&&m| cd.samples[m].fold != k)
                                    .eq(members.iter())
                                {
                                    return sys.solve(Some(k), &all);
                                }
                            }
                            let rows = local_rows(cd, &fold_grid, &norm, idx, &members);
                            let (a, y) =
                                design_system(&basis, rows.iter().map(|r| (r.coords, r.params)));
                            split_coeffs(&crate::model::solve_lsq(a, &y))
                        })
                        .collect();
                    channels.push((cd.channel, coeffs));
                }
                out.push(Some(Box::new(LocalModel {
                    norm: train.normalisation(),
                    alpha,
                    beta,
                    grid: fold_grid,
                    basis: basis.clone(),
                    channels,
                }) as Box<dyn FittedModel>));
            }
        }
    }
    Ok(out)
}

/// Cross-validation engine for the local family. Each centre's normal equations are
/// accumulated once for the largest candidate; a smaller candidate whose centre takes
/// the same samples (the radius widens with the number of terms, as in
/// [`LocalModel::fit`]) reuses their sub-block, one that takes fewer gets its own.
struct LocalCv {
    common: CvCommon,
    grid: CentreGrid,
    /// Per channel: sample positions, and per centre the members and their system.
    pts: Vec<Vec<[f64; 2]>>,
    systems: Vec<Vec<(usize, FoldedSystem)>>,
}

fn local_rows(
    cd: &ChannelData,
    grid: &CentreGrid,
    norm: &Normalisation,
    idx: usize,
    members: &[usize],
) -> Vec<Row> {
    members
        .iter()
        .map(|&m| {
            let s = &cd.samples[m];
            Row {
                coords: local_coords(
                    grid,
                    norm,
                    idx,
                    s.x,
                    s.y,
                    s.setting.focal_mm,
                    s.setting.f_number,
                ),
                params: s.params,
                fold: s.fold,
            }
        })
        .collect()
}

impl LocalCv {
    fn new(ds: &Dataset, common: CvCommon, opts: &LocalOptions) -> Self {
        let (norm, union, folds) = (&common.norm, &common.union, common.folds);
        let grid = local_grid(ds, opts);
        let pts: Vec<Vec<[f64; 2]>> = common
            .data
            .iter()
            .map(|cd| cd.samples.iter().map(|s| [s.x, s.y]).collect())
            .collect();
        let systems = common
            .data
            .iter()
            .zip(&pts)
            .map(|(cd, pts)| {
                use rayon::prelude::*;
                (0..grid.len())
                    .into_par_iter()
                    .map(|idx| {
                        let members = local_members(&grid, idx, pts, union.len());
                        let rows = local_rows(cd, &grid, norm, idx, &members);
                        (members.len(), FoldedSystem::build(union, &rows, folds))
                    })
                    .collect()
            })
            .collect();
        Self {
            common,
            grid,
            pts,
            systems,
        }
    }

    fn errors(&self, alpha: usize, beta: usize, ranges: &Ranges) -> HeldOut {
        use rayon::prelude::*;
        let cv = &self.common;
        cv.errors(alpha, beta, ranges, |c, basis, subset| {
            let (cd, centres, pts) = (&cv.data[c], &self.systems[c], &self.pts[c]);
            let all: Vec<usize> = (0..basis.len()).collect();
            // Centres whose members differ from the union's get their own system.
            let own: Vec<Option<FoldedSystem>> = (0..centres.len())
                .into_par_iter()
                .map(|idx| {
                    let members = local_members(&self.grid, idx, pts, basis.len());
                    (members.len() != centres[idx].0).then(|| {
                        let rows = local_rows(cd, &self.grid, &cv.norm, idx, &members);
                        FoldedSystem::build(basis, &rows, cv.folds)
                    })
                })
                .collect();
            (0..cv.folds)
                .into_par_iter()
                .map(|k| LocalModel {
                    norm: cv.norm.clone(),
                    alpha,
                    beta,
                    grid: self.grid.clone(),
                    basis: basis.clone(),
                    channels: vec![(
                        cd.channel,
                        centres
                            .iter()
                            .zip(&own)
                            .map(|((_, sys), own)| match own {
                                Some(o) => o.solve(Some(k), &all),
                                None => sys.solve(Some(k), subset),
                            })
                            .collect(),
                    )],
                })
                .collect()
        })
    }
}

fn select(
    kind: ModelKind,
    alphas: &[usize],
    n: usize,
    job: &JobContext,
    done: &mut usize,
    total: usize,
    errors: impl Fn(usize, usize) -> ([Vec<f64>; 3], usize),
) -> Result<Selection, ModelError> {
    let stage = match kind {
        ModelKind::Global => "global CV",
        ModelKind::Local => "local CV",
    };
    let beta_max = n - 1;
    let mut alpha_curve = Vec::new();
    let mut best: Option<(CvPoint, [Vec<f64>; 3])> = None;
    for &alpha in alphas {
        job.check()?;
        let (e, terms) = errors(alpha, beta_max);
        let pt = summarise(alpha, beta_max, terms, &e);
        if best.as_ref().is_none_or(|b| pt.mean_pct < b.0.mean_pct) {
            best = Some((pt.clone(), e));
        }
        alpha_curve.push(pt);
        *done += 1;
        job.report(stage, *done, total);
    }
    let Some((a_best, a_err)) = best else {
        return Err(ModelError::Empty);
    };
    let alpha = a_best.alpha;
    let mut beta_curve = Vec::new();
    let mut best = (a_best.clone(), a_err);
    for beta in 0..=beta_max {
        job.check()?;
        if beta == beta_max {
            beta_curve.push(a_best.clone());
        } else {
            let (e, terms) = errors(alpha, beta);
            let pt = summarise(alpha, beta, terms, &e);
            if pt.mean_pct < best.0.mean_pct {
                best = (pt.clone(), e);
            }
            beta_curve.push(pt);
        }
        *done += 1;
        job.report(stage, *done, total);
    }
    Ok(Selection {
        kind,
        alpha_curve,
        beta_curve,
        alpha,
        beta: best.0.beta,
        chosen: best.0,
        error_cdf: ErrorCdf::from_errors(&best.1),
    })
}

/// Runs cross-validation and the two-stage selection for the requested families.
///
/// # Errors
/// Unknown settings, fewer than two shots, or cancellation.
pub fn cross_validate(
    ds: &Dataset,
    opts: &CvOptions,
    job: &JobContext,
) -> Result<CvReport, ModelError> {
    ds.validate()?;
    if ds.shots.len() < 2 {
        return Err(ModelError::TooFewShots {
            shots: ds.shots.len(),
        });
    }
    for &a in opts.global_alphas.iter().chain(&opts.local_alphas) {
        crate::model::check_order(a, 0)?;
    }
    let (fold_of_shot, folds) = assign_folds(ds, opts.folds, opts.hold_out, opts.seed);
    let ranges = param_ranges(ds);
    // β < N = min(N_f, N_a), and no larger than the settings shot can determine.
    let n = (0..ds.setting_resolution())
        .take_while(|&b| ds.check_beta(b).is_ok())
        .count()
        .max(1);
    let (fs, as_) = ds.distinct_settings();
    let total = usize::from(opts.run_global) * (opts.global_alphas.len() + n)
        + usize::from(opts.run_local) * (opts.local_alphas.len() + n);
    let mut done = 0;
    let mut run = |kind: ModelKind, wanted: bool, alphas: &[usize]| {
        if !wanted || alphas.is_empty() {
            return Ok(None);
        }
        let max_alpha = alphas.iter().copied().max().unwrap_or(1);
        let data = channel_data(ds, &fold_of_shot);
        let cv = FamilyCv::new(kind, ds, data, &opts.local, (max_alpha, n - 1), folds);
        select(kind, alphas, n, job, &mut done, total, |a, b| {
            let (e, terms, _) = cv.errors(a, b, &ranges);
            (e, terms)
        })
        .map(Some)
    };
    let global = run(ModelKind::Global, opts.run_global, &opts.global_alphas)?;
    let local = run(ModelKind::Local, opts.run_local, &opts.local_alphas)?;
    Ok(CvReport {
        schema: "lensblur.crossval/1".into(),
        folds,
        hold_out: opts.hold_out,
        shots: ds.shots.len(),
        n_f: fs.len(),
        n_a: as_.len(),
        ranges,
        global,
        local,
        test: None,
    })
}

/// Cross-validation errors of one fixed (α, β) of a family (no selection): for
/// reporting a named model such as L_{1,3} next to the chosen one.
///
/// # Errors
/// As [`cross_validate`], and β too large for the session.
pub fn cross_validate_fixed(
    ds: &Dataset,
    kind: ModelKind,
    alpha: usize,
    beta: usize,
    opts: &CvOptions,
) -> Result<(CvPoint, [Vec<f64>; 3]), ModelError> {
    let (e, terms, _) = fixed_errors(ds, kind, (alpha, beta), opts)?;
    Ok((summarise(alpha, beta, terms, &e), e))
}

/// Every sample's held-out error under one fixed (α, β) of a family, the same folds
/// and ranges as [`cross_validate`]'s: where the chosen model is trusted, per setting
/// and part of the frame (the profile's record of it).
///
/// # Errors
/// As [`cross_validate_fixed`].
pub fn held_out_errors(
    ds: &Dataset,
    kind: ModelKind,
    alpha: usize,
    beta: usize,
    opts: &CvOptions,
) -> Result<Vec<HeldOutError>, ModelError> {
    let (_, _, at) = fixed_errors(ds, kind, (alpha, beta), opts)?;
    Ok(at)
}

/// The held-out errors of one fixed (α, β) of a family, over the session's folds: per
/// parameter, the term count, and per sample.
fn fixed_errors(
    ds: &Dataset,
    kind: ModelKind,
    (alpha, beta): (usize, usize),
    opts: &CvOptions,
) -> Result<HeldOut, ModelError> {
    ds.validate()?;
    crate::model::check_order(alpha, beta)?;
    ds.check_beta(beta)?;
    if ds.shots.len() < 2 {
        return Err(ModelError::TooFewShots {
            shots: ds.shots.len(),
        });
    }
    let (fold_of_shot, folds) = assign_folds(ds, opts.folds, opts.hold_out, opts.seed);
    let ranges = param_ranges(ds);
    let data = channel_data(ds, &fold_of_shot);
    Ok(
        FamilyCv::new(kind, ds, data, &opts.local, (alpha, beta), folds)
            .errors(alpha, beta, &ranges),
    )
}

/// One model's errors at a test set's samples (the paper's Fig. 6): fitted on the whole
/// calibration set, errors in % of the calibration set's ranges.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TestResult {
    /// How the model was picked: "chosen" by cross-validation, or "fixed".
    pub label: String,
    pub kind: ModelKind,
    pub alpha: usize,
    pub beta: usize,
    pub terms: usize,
    pub mean_error_pct: [f64; 3],
    pub p95_error_pct: [f64; 3],
    pub mean_pct: f64,
    pub error_cdf: ErrorCdf,
}

/// Errors of several models on a test set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TestReport {
    pub shots: usize,
    pub samples: usize,
    pub models: Vec<TestResult>,
    /// Models that could not be fitted to this calibration set, with the reason.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub skipped: Vec<String>,
}

/// A model to evaluate on a test set.
#[derive(Clone, Debug, PartialEq)]
pub struct TestModel {
    pub label: String,
    pub kind: ModelKind,
    pub alpha: usize,
    pub beta: usize,
}

/// Fits each model to the calibration set `cal` and measures its errors at the samples
/// of `test`, relative to `ranges` (normally the calibration set's). A model the
/// calibration set cannot support (β too large, too few samples) is listed in
/// `skipped`, not fatal.
///
/// # Errors
/// Unknown settings, a test set from a sensor of another size, or a test shot outside
/// the calibrated range (the profile would refuse to predict there).
pub fn evaluate_test_set(
    cal: &Dataset,
    test: &Dataset,
    models: &[TestModel],
    local: &LocalOptions,
    ranges: &Ranges,
) -> Result<TestReport, ModelError> {
    cal.validate()?;
    test.validate()?;
    if (cal.width, cal.height) != (test.width, test.height) {
        return Err(ModelError::SensorMismatch {
            a: format!("{}×{} (calibration)", cal.width, cal.height),
            b: format!("{}×{} (test)", test.width, test.height),
        });
    }
    let norm = cal.normalisation();
    for s in &test.shots {
        if !norm.contains(s.setting()) {
            return Err(ModelError::OutsideCalibratedRange {
                shot: s.name.clone(),
                focal_mm: s.focal_mm,
                f_number: s.f_number,
            });
        }
    }
    let mut results = Vec::new();
    let mut skipped = Vec::new();
    for m in models {
        match fit_model(cal, m.kind, m.alpha, m.beta, local) {
            Ok(model) => {
                let terms = model.terms();
                let e = prediction_errors(test, ranges, model.as_ref());
                let pt = summarise(m.alpha, m.beta, terms, &e);
                results.push(TestResult {
                    label: m.label.clone(),
                    kind: m.kind,
                    alpha: m.alpha,
                    beta: m.beta,
                    terms,
                    mean_error_pct: pt.mean_error_pct,
                    p95_error_pct: pt.p95_error_pct,
                    mean_pct: pt.mean_pct,
                    error_cdf: ErrorCdf::from_errors(&e),
                });
            }
            Err(ModelError::Cancelled) => return Err(ModelError::Cancelled),
            Err(e) => skipped.push(format!("{}: {e}", m.kind.model_name(m.alpha, m.beta))),
        }
    }
    Ok(TestReport {
        shots: test.shots.len(),
        samples: test.samples.len(),
        models: results,
        skipped,
    })
}

/// The models the paper compares on its test set (G_{8,3}, L_{1,3}, G_{8,1}, L_{1,1}),
/// preceded by the cross-validated choices of `report` where it has them.
#[must_use]
pub fn paper_test_models(report: Option<&CvReport>) -> Vec<TestModel> {
    let mut out = Vec::new();
    if let Some(r) = report {
        for s in [&r.global, &r.local].into_iter().flatten() {
            out.push(TestModel {
                label: "chosen".into(),
                kind: s.kind,
                alpha: s.alpha,
                beta: s.beta,
            });
        }
    }
    for (kind, alpha, beta) in [
        (ModelKind::Global, 8, 3),
        (ModelKind::Local, 1, 3),
        (ModelKind::Global, 8, 1),
        (ModelKind::Local, 1, 1),
    ] {
        out.push(TestModel {
            label: "fixed".into(),
            kind,
            alpha,
            beta,
        });
    }
    out
}

#[cfg(test)]
mod oracle;
