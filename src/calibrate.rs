//! Calibration: from a session's measured samples to a lens
//! profile. Chooses the model orders by cross-validation (unless given), fits the
//! requested families, reports how well fixed orders cross-validate, and prefers the
//! family with the lower error.

use crate::chart::ChartSpec;
use crate::crossval::{
    CvOptions, CvReport, Selection, ShapeCvOptions, assign_folds, cross_validate,
    cross_validate_fixed, cross_validate_shape, held_out_errors, param_ranges,
};
use crate::job::JobContext;
use crate::model::{
    Dataset, GlobalModel, LocalModel, ModelError, ModelKind, PlaceModel, ShapeModel, ShapeSpace,
    check_order, session_residuals,
};
use crate::profile::{CvSummary, Profile, Trust};
use serde::{Deserialize, Serialize};

/// Which model families to fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Families {
    Global,
    Local,
    Both,
}

/// What `calibrate` fits.
#[derive(Clone, Debug)]
pub struct CalibrateOptions {
    pub families: Families,
    /// Fixed α (skips cross-validated selection); β defaults to N − 1.
    pub alpha: Option<usize>,
    pub beta: Option<usize>,
    pub cv: CvOptions,
    /// What the kernel-shape model's cross-validation tries; `None` fits none. Only a
    /// session that kept its measured kernels (and has two shots to hold out) has one.
    pub shape: Option<ShapeCvOptions>,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        Self {
            families: Families::Both,
            alpha: None,
            beta: None,
            cv: CvOptions::default(),
            shape: Some(ShapeCvOptions::default()),
        }
    }
}

/// Fits the requested families (α, β chosen by cross-validation unless given) and
/// assembles the profile. Returns the cross-validation report when one was run.
///
/// # Errors
/// Unknown settings, β too large for the session, too few shots for cross-validation,
/// too few samples, or cancellation.
pub fn calibrate(
    ds: &Dataset,
    chart: Option<ChartSpec>,
    opts: &CalibrateOptions,
    job: &JobContext,
) -> Result<(Profile, Option<CvReport>), ModelError> {
    ds.validate()?;
    if let Some(b) = opts.beta {
        ds.check_beta(b)?;
    }
    if let Some(a) = opts.alpha {
        check_order(a, opts.beta.unwrap_or(0))?;
    }
    let want = Wanted {
        global: opts.families != Families::Local,
        local: opts.families != Families::Global,
    };
    let (report, orders) = choose_orders(ds, opts, want, job)?;
    job.check()?;
    job.report("fitting", 0, 2);
    let global = if want.global {
        Some(GlobalModel::fit(ds, orders.global.0, orders.global.1)?)
    } else {
        None
    };
    job.report("fitting", 1, 2);
    let local = if want.local {
        Some(LocalModel::fit(
            ds,
            orders.local.0,
            orders.local.1,
            &opts.cv.local,
        )?)
    } else {
        None
    };
    job.report("fitting", 2, 2);
    let cv = match &report {
        Some(r) => Some(CvSummary::from_report(r)),
        None => fixed_orders_cv(ds, opts, want, orders, job)?,
    };
    let preferred = Profile::preferred_family(cv.as_ref(), want.local);
    let mut profile = Profile::new(
        ds.identity.clone(),
        chart,
        ds.distinct_setting_pairs(),
        global,
        local,
        cv,
        preferred,
    )
    .ok_or(ModelError::Empty)?;
    profile.focus_range = crate::profile::FocusRange::of_dataset(ds);
    profile.measured_on = ds.picture;
    let preferred_orders = orders.of(profile.preferred);
    if ds.shots.len() >= 2 {
        job.check()?;
        profile.trust = trust(ds, profile.preferred, preferred_orders, &opts.cv)?;
    }
    // Where each channel's kernels are centred: lateral colour and the kernels' own
    // cores, chosen over the same folds. Sessions without kernels keep every
    // kernel centred on its pixel.
    if ds.samples.iter().any(|s| s.kernel.is_some()) {
        job.check()?;
        let (fold_of_shot, folds) = if ds.shots.len() >= 2 {
            assign_folds(ds, opts.cv.folds, opts.cv.hold_out, opts.cv.seed)
        } else {
            (Vec::new(), 0)
        };
        profile.place = Some(PlaceModel::fit(ds, &fold_of_shot, folds)?);
    }
    if let Some(shape_opts) = &opts.shape
        && ds.shots.len() >= 2
        && ds.samples.iter().any(|s| s.kernel.is_some())
    {
        fit_shapes(ds, &mut profile, preferred_orders, opts, shape_opts, job)?;
    }
    Ok((profile, report))
}

/// Which families a calibration fits.
#[derive(Clone, Copy)]
struct Wanted {
    global: bool,
    local: bool,
}

/// The orders (α, β) each family is fitted at.
#[derive(Clone, Copy)]
struct Orders {
    global: (usize, usize),
    local: (usize, usize),
}

impl Orders {
    fn of(self, kind: ModelKind) -> (usize, usize) {
        match kind {
            ModelKind::Global => self.global,
            ModelKind::Local => self.local,
        }
    }
}

/// The orders given, or chosen by cross-validation (whose report comes back with them).
fn choose_orders(
    ds: &Dataset,
    opts: &CalibrateOptions,
    want: Wanted,
    job: &JobContext,
) -> Result<(Option<CvReport>, Orders), ModelError> {
    if let Some(alpha) = opts.alpha {
        let beta = opts.beta.unwrap_or(ds.setting_resolution() - 1);
        let given = Orders {
            global: (alpha, beta),
            local: (alpha, beta),
        };
        return Ok((None, given));
    }
    let mut cv = opts.cv.clone();
    cv.run_global = want.global;
    cv.run_local = want.local;
    let r = cross_validate(ds, &cv, job)?;
    let pick = |s: &Option<Selection>| {
        s.as_ref()
            .map_or((1, 0), |s| (s.alpha, opts.beta.unwrap_or(s.beta)))
    };
    let orders = Orders {
        global: pick(&r.global),
        local: pick(&r.local),
    };
    Ok((Some(r), orders))
}

/// Fixed orders: still report how well they cross-validate, where there are shots to
/// hold out.
fn fixed_orders_cv(
    ds: &Dataset,
    opts: &CalibrateOptions,
    want: Wanted,
    orders: Orders,
    job: &JobContext,
) -> Result<Option<CvSummary>, ModelError> {
    if ds.shots.len() < 2 {
        return Ok(None);
    }
    let fixed = |kind: ModelKind| {
        let (a, b) = orders.of(kind);
        cross_validate_fixed(ds, kind, a, b, &opts.cv).map(|r| r.0)
    };
    let global = if want.global {
        Some(fixed(ModelKind::Global)?)
    } else {
        None
    };
    job.check()?;
    let local = if want.local {
        Some(fixed(ModelKind::Local)?)
    } else {
        None
    };
    Ok(Some(CvSummary {
        folds: assign_folds(ds, opts.cv.folds, opts.cv.hold_out, opts.cv.seed).1,
        ranges: param_ranges(ds),
        global,
        local,
    }))
}

/// Where the profile is trusted: the preferred model's held-out errors, by setting and
/// zone, from the same folds its orders were chosen by.
fn trust(
    ds: &Dataset,
    kind: ModelKind,
    (alpha, beta): (usize, usize),
    cv: &CvOptions,
) -> Result<Option<Trust>, ModelError> {
    let errors = held_out_errors(ds, kind, alpha, beta, cv)?;
    let name = match kind {
        ModelKind::Global => format!("G_{{{alpha},{beta}}}"),
        ModelKind::Local => format!("L_{{{alpha},{beta}}}"),
    };
    Ok(Trust::from_errors(name, &errors, (ds.width, ds.height)))
}

/// The kernel-shape model, cross-validated around the Gaussians deblurring will use
/// (the preferred family at its orders) and kept where it earns it.
fn fit_shapes(
    ds: &Dataset,
    profile: &mut Profile,
    (alpha, beta): (usize, usize),
    opts: &CalibrateOptions,
    shape_opts: &ShapeCvOptions,
    job: &JobContext,
) -> Result<(), ModelError> {
    // Reported before the residuals are taken, so the time that takes is the
    // shapes' (the command line's timings say where the time goes).
    job.report("kernel shapes", 0, 1);
    let residuals: Vec<(ShapeSpace, Vec<Option<Vec<f32>>>)> = shape_opts
        .spaces
        .iter()
        .map(|&space| (space, session_residuals(ds, space)))
        .collect();
    let shape_cv = cross_validate_shape(
        ds,
        &residuals,
        profile.preferred,
        alpha,
        beta,
        &opts.cv,
        shape_opts,
        job,
    )?;
    if shape_cv.shape_chosen
        && let Some(best) = &shape_cv.best_shape
    {
        let space_residuals = residuals
            .iter()
            .find(|(space, _)| *space == best.space)
            .map_or(&residuals[0].1, |(_, r)| r);
        profile.shape = Some(ShapeModel::fit(
            ds,
            best.space,
            space_residuals,
            best.alpha,
            best.beta,
            best.components,
        )?);
    }
    profile.shape_cv = Some(shape_cv);
    Ok(())
}
