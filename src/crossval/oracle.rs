//! The refitting forms of cross-validation, kept as the oracle the fast forms must
//! equal: every fold's models fitted again from its training samples (QR, as the final
//! fits are), for the Gaussian families and for the kernel-shape model, on small
//! synthetic sessions.

#[allow(clippy::wildcard_imports)]
use super::*;
use crate::model::{BlurSample, ShapeSpace, ShotInfo, session_residuals};
use crate::plane::CameraIdentity;
use crate::psf::{Gaussian2, Kernel};
use shape::{Held, HeldKernel, KernelErrors, Tried, report};

/// Held-out errors of G/L_{α,β} with every fold's model refitted to its training shots
/// by [`fit_model`], in the order the fast engine scores them (channel by channel,
/// samples in session order). The fold models keep the session's normalisation, as the
/// fast engine's do.
fn gaussian_refit_errors(
    ds: &Dataset,
    kind: ModelKind,
    (alpha, beta): (usize, usize),
    opts: &CvOptions,
) -> [Vec<f64>; 3] {
    let (fold_of_shot, folds) = assign_folds(ds, opts.folds, opts.hold_out, opts.seed);
    let ranges = param_ranges(ds).as_array();
    let norm = ds.normalisation();
    let models: Vec<Box<dyn FittedModel>> = (0..folds)
        .map(|k| {
            let (train, _) = shots_subset(ds, |s| fold_of_shot[s] != k);
            let model: Box<dyn FittedModel> = match kind {
                ModelKind::Global => {
                    let mut m = GlobalModel::fit(&train, alpha, beta).expect("global refit");
                    m.norm = norm.clone();
                    Box::new(m)
                }
                ModelKind::Local => {
                    let mut m =
                        LocalModel::fit(&train, alpha, beta, &opts.local).expect("local refit");
                    m.norm = norm.clone();
                    Box::new(m)
                }
            };
            model
        })
        .collect();
    let mut out: [Vec<f64>; 3] = Default::default();
    for channel in ds.channels() {
        for s in ds.samples.iter().filter(|s| s.channel == channel) {
            let p = models[fold_of_shot[s.shot]]
                .predict(channel, s.x, s.y, s.setting())
                .expect("channel fitted");
            push_errors(&mut out, p, s.params(), ranges);
        }
    }
    out
}

/// [`cross_validate_shape`] as it was written first: per fold, the Gaussian model,
/// the shape basis and the coefficient fields refitted to the training shots, and every
/// held-out kernel rendered whole for every model.
#[allow(clippy::too_many_arguments)]
fn cross_validate_shape_refit(
    ds: &Dataset,
    residuals: &[(ShapeSpace, Vec<Option<Vec<f32>>>)],
    kind: ModelKind,
    alpha: usize,
    beta: usize,
    cv: &CvOptions,
    opts: &ShapeCvOptions,
) -> ShapeCvReport {
    use crate::model::{
        RestorationError, ShapeFit, kernel_with_residual, kernel_with_shape, relative_l2,
        to_gaussian,
    };
    let has_kernel = |i: usize| residuals.iter().all(|(_, r)| r[i].is_some());
    let (fold_of_shot, folds) = assign_folds(ds, cv.folds, cv.hold_out, cv.seed);
    let tried = Tried::new(opts, residuals.iter().map(|r| r.0).collect(), beta);
    let (components, combos, k_max) = (&tried.components, &tried.combos, tried.k_max);
    let mut usable = vec![true; combos.len()];
    let mut held: Held = Vec::new();
    for fold in 0..folds {
        let (train, train_idx) = shots_subset(ds, |s| fold_of_shot[s] != fold);
        let test: Vec<usize> = (0..ds.samples.len())
            .filter(|&i| fold_of_shot[ds.samples[i].shot] == fold && has_kernel(i))
            .collect();
        if test.is_empty() || train.samples.is_empty() {
            continue;
        }
        let gaussian_model = fit_model(&train, kind, alpha, beta, &cv.local).expect("refit");
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
        for &i in &test {
            let s = &ds.samples[i];
            let Some(measured) = s.kernel.as_ref() else {
                continue;
            };
            let setting = s.setting();
            let Some(p) = gaussian_model.predict(s.channel, s.x, s.y, setting) else {
                continue;
            };
            let g = to_gaussian(p);
            let os = measured.oversample;
            // Every kernel rendered as deblurring renders it, then compared on the
            // common grid.
            let Some((grid, measured)) = shape::judged_grid(measured, &g, &tried.spaces) else {
                continue;
            };
            let Some(plain) = kernel_with_residual(&g, None, os, None) else {
                continue;
            };
            let Some(mut restoration) = RestorationError::new(&measured, crate::model::WIENER_NSR)
            else {
                continue;
            };
            let mut judge = |k: &crate::psf::Kernel| {
                let k = k.padded(grid);
                KernelErrors {
                    rel_l2: relative_l2(&k, &measured),
                    restoration: restoration.of_kernel(&k),
                }
            };
            let e_gauss = judge(&plain);
            let per_combo = models
                .iter()
                .map(|m| {
                    let Some(m) = m else {
                        return vec![KernelErrors::NONE; components.len()];
                    };
                    let Some(c) = m.coefficients(s.channel, s.x, s.y, setting) else {
                        return vec![KernelErrors::NONE; components.len()];
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
                            kernel_with_shape(m.space, &g, Some(&r), os, None)
                                .map_or(KernelErrors::NONE, |k| judge(&k))
                        })
                        .collect()
                })
                .collect();
            held.push(HeldKernel {
                f_number: s.f_number,
                gaussian: e_gauss,
                per_combo,
            });
        }
    }
    report(&tried, &held, &usable, kind, (alpha, beta), folds).expect("report")
}

/// A 3 × 3-setting session of `shots_per_setting` shots, a `cols × rows` grid of
/// squares each shifted a little per shot, with smooth σ and ρ fields plus a fixed
/// pseudo-random scatter; with `kernels`, each sample keeps a 3× kernel: its Gaussian
/// with a comet tail that grows towards the corners and wide open.
fn synthetic_session(cols: usize, rows: usize, shots_per_setting: usize, kernels: bool) -> Dataset {
    let (width, height) = (600usize, 400usize);
    let mut ds = Dataset::new(width, height, CameraIdentity::default());
    let square = 0.9 * width as f64 / cols as f64;
    // A fixed scatter in [−1, 1], the same on every run.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut scatter = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    };
    for focal_mm in [24.0, 50.0, 105.0] {
        for f_number in [4.0, 5.6, 8.0] {
            for rep in 0..shots_per_setting {
                let (dx, dy) = (4.0 * scatter(), 4.0 * scatter());
                let (tf, ta) = ((focal_mm - 24.0) / 81.0, (8.0f64 / f_number).ln());
                let mut samples = Vec::new();
                for r in 0..rows {
                    for q in 0..cols {
                        let x = (width as f64 - cols as f64 * square) / 2.0
                            + (q as f64 + 0.5) * square
                            + dx;
                        let y = (height as f64 - rows as f64 * square) / 2.0
                            + (r as f64 + 0.5) * square
                            + dy;
                        let (u, v) = (2.0 * x / width as f64 - 1.0, 2.0 * y / height as f64 - 1.0);
                        for (ci, channel) in
                            [Channel::R, Channel::G, Channel::B].into_iter().enumerate()
                        {
                            let c = 1.0 + 0.08 * ci as f64;
                            let g = Gaussian2::new(
                                c * (0.8 + 0.3 * u * u + 0.2 * v * v + 0.3 * ta + 0.1 * tf)
                                    * (1.0 + 0.02 * scatter()),
                                c * (0.75 + 0.2 * u * u + 0.35 * v * v + 0.25 * ta)
                                    * (1.0 + 0.02 * scatter()),
                                0.3 * u * v + 0.1 * tf * u + 0.02 * scatter(),
                            );
                            let kernel = kernels.then(|| {
                                let tail = 0.15 + 0.25 * (u * u + v * v) * (0.5 + ta);
                                let core = Gaussian2::isotropic(0.6);
                                let (ox, oy) = (1.5 * u, 1.5 * v);
                                let mut k = Kernel::from_fn(31, 3, |px, py| {
                                    g.density(px, py) + tail * core.density(px - ox, py - oy)
                                });
                                for value in &mut k.data {
                                    *value = (*value * (1.0 + 0.05 * scatter())).max(0.0);
                                }
                                k.normalise();
                                std::sync::Arc::new(k)
                            });
                            samples.push(BlurSample {
                                shot: 0,
                                x,
                                y,
                                square: Some([r, q]),
                                focal_mm: 0.0,
                                f_number: 0.0,
                                channel,
                                gaussian: g,
                                kernel,
                            });
                        }
                    }
                }
                ds.push_shot(
                    ShotInfo {
                        name: format!("f{focal_mm}-a{f_number}-{rep}"),
                        focal_mm,
                        f_number,
                        focus_distance_m: None,
                    },
                    samples,
                );
            }
        }
    }
    ds
}

/// |a − b| ≤ tol · max(|a|, |b|), NaN only against NaN.
fn close(a: f64, b: f64, tol: f64) -> bool {
    (a.is_nan() && b.is_nan()) || (a - b).abs() <= tol * a.abs().max(b.abs())
}

/// Every held-out error equal to its refitted one within 1e-9 of the largest error (a
/// near-zero error has no digits of its own to compare: it is a difference of two
/// parameters of order one), and the summary selection reads (mean and 95th
/// percentile per parameter) equal to 1e-9 relative.
fn assert_errors_equal(fast: &[Vec<f64>; 3], refit: &[Vec<f64>; 3], what: &str) {
    for p in 0..3 {
        assert_eq!(fast[p].len(), refit[p].len(), "{what}: parameter {p}");
        let scale = refit[p].iter().fold(0.0f64, |m, e| m.max(e.abs()));
        for (i, (a, b)) in fast[p].iter().zip(&refit[p]).enumerate() {
            assert!(
                (a - b).abs() <= 1e-9 * scale,
                "{what}: parameter {p} sample {i}: {a} vs {b}"
            );
        }
    }
    let (f, r) = (summarise(0, 0, 0, fast), summarise(0, 0, 0, refit));
    for p in 0..3 {
        assert!(
            close(f.mean_error_pct[p], r.mean_error_pct[p], 1e-9),
            "{what}: mean {p}"
        );
        assert!(
            close(f.p95_error_pct[p], r.p95_error_pct[p], 1e-9),
            "{what}: p95 {p}"
        );
    }
}

/// Four folds over nine shots, so folds hold two or three shots and the downdate takes
/// several shots' systems at once.
fn four_folds() -> CvOptions {
    CvOptions {
        folds: 4,
        local: LocalOptions {
            // Wide enough that no centre's circle widens, with or without a fold: the
            // fast engine takes each centre's members from the whole session.
            radius_px: Some(300.0),
            ..LocalOptions::default()
        },
        ..CvOptions::default()
    }
}

#[test]
fn global_cv_equals_refitting_every_fold() {
    let ds = synthetic_session(10, 7, 1, false);
    let opts = four_folds();
    for (alpha, beta) in [(1, 0), (3, 1), (5, 2)] {
        let (_, fast) = cross_validate_fixed(&ds, ModelKind::Global, alpha, beta, &opts)
            .expect("cross-validates");
        let refit = gaussian_refit_errors(&ds, ModelKind::Global, (alpha, beta), &opts);
        assert_errors_equal(&fast, &refit, &format!("G_{{{alpha},{beta}}}"));
    }
}

#[test]
fn local_cv_equals_refitting_every_fold() {
    let ds = synthetic_session(10, 7, 1, false);
    let opts = four_folds();
    for (alpha, beta) in [(1, 1), (2, 2)] {
        let (_, fast) = cross_validate_fixed(&ds, ModelKind::Local, alpha, beta, &opts)
            .expect("cross-validates");
        let refit = gaussian_refit_errors(&ds, ModelKind::Local, (alpha, beta), &opts);
        assert_errors_equal(&fast, &refit, &format!("L_{{{alpha},{beta}}}"));
    }
}

fn assert_points_equal(fast: &ShapeCvPoint, refit: &ShapeCvPoint, what: &str) {
    assert_eq!(
        (fast.space, fast.alpha, fast.beta, fast.components),
        (refit.space, refit.alpha, refit.beta, refit.components),
        "{what}"
    );
    for (a, b, stat) in [
        (fast.mean_rel_l2, refit.mean_rel_l2, "mean"),
        (fast.median_rel_l2, refit.median_rel_l2, "median"),
        (fast.p95_rel_l2, refit.p95_rel_l2, "p95"),
        (
            fast.restoration_rms.expect("restoration"),
            refit.restoration_rms.expect("restoration"),
            "restoration",
        ),
    ] {
        assert!(close(a, b, 1e-9), "{what} {stat}: {a} vs {b}");
    }
}

fn assert_shape_cv_equals_refit(kind: ModelKind, alpha: usize, beta: usize) {
    let ds = synthetic_session(8, 5, 1, true);
    let cv = four_folds();
    let opts = ShapeCvOptions {
        alphas: vec![1, 2],
        components: vec![0, 1, 2, 4],
        spaces: ShapeSpace::ALL.to_vec(),
        ..ShapeCvOptions::default()
    };
    let residuals: Vec<(ShapeSpace, Vec<Option<Vec<f32>>>)> = opts
        .spaces
        .iter()
        .map(|&space| (space, session_residuals(&ds, space)))
        .collect();
    let job = JobContext::silent();
    let fast = cross_validate_shape(&ds, &residuals, kind, alpha, beta, &cv, &opts, &job)
        .expect("cross-validates");
    let refit = cross_validate_shape_refit(&ds, &residuals, kind, alpha, beta, &cv, &opts);
    assert_eq!(fast.kernels, refit.kernels);
    assert_eq!(fast.kernels, ds.samples.len(), "every kernel judged");
    assert_points_equal(&fast.gaussian, &refit.gaussian, "Gaussian");
    assert_eq!(fast.points.len(), refit.points.len());
    assert_eq!(fast.points.len(), 2 * 2 * 3, "every model judged");
    for (a, b) in fast.points.iter().zip(&refit.points) {
        assert_points_equal(a, b, "shape model");
    }
    assert_eq!(fast.shape_chosen, refit.shape_chosen);
    assert!(fast.shape_chosen, "the comet tails are worth a shape model");
    assert_points_equal(
        fast.best_shape.as_ref().expect("best"),
        refit.best_shape.as_ref().expect("best"),
        "best",
    );
    assert_points_equal(
        fast.best_by_l2.as_ref().expect("best by L2"),
        refit.best_by_l2.as_ref().expect("best by L2"),
        "best by L2",
    );
    assert_eq!(fast.per_aperture.len(), refit.per_aperture.len());
    for (a, b) in fast.per_aperture.iter().zip(&refit.per_aperture) {
        assert_eq!((a.f_number, a.kernels), (b.f_number, b.kernels));
        assert!(close(a.gaussian_mean_rel_l2, b.gaussian_mean_rel_l2, 1e-9));
        assert!(close(a.shape_mean_rel_l2, b.shape_mean_rel_l2, 1e-9));
        for (x, y) in [
            (a.gaussian_restoration_rms, b.gaussian_restoration_rms),
            (a.shape_restoration_rms, b.shape_restoration_rms),
        ] {
            assert!(close(x.expect("fast"), y.expect("refit"), 1e-9));
        }
    }
}

#[test]
fn shape_cv_around_a_global_model_equals_refitting_every_fold() {
    assert_shape_cv_equals_refit(ModelKind::Global, 2, 1);
}

#[test]
fn shape_cv_around_a_local_model_equals_refitting_every_fold() {
    assert_shape_cv_equals_refit(ModelKind::Local, 1, 1);
}
