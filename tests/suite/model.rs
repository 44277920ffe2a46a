//! Blur models, cross-validation and profiles against the virtual lens's truth.
//!
//! The datasets here are built directly from the lens truth (pixel-level Gaussians at
//! the square centres of a posed 24×16 chart) plus measurement error shaped like the
//! measured chain's ([`SampleNoise`]: independent and heavy-tailed per square, smooth
//! per shot), which keeps these tests to seconds. The same figures on kernels measured
//! from simulated shots come from `examples/calibration_figures.rs`.

use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::crossval::{
    CvOptions, HoldOut, cross_validate, cross_validate_fixed, param_ranges, percentile_sorted,
    prediction_errors,
};
use lensblur::job::JobContext;
use lensblur::model::{
    CentreGrid, Dataset, FittedModel, GlobalModel, LateralColour, LocalModel, LocalOptions,
    ModelError, ModelKind, fit_model, local_coords, spaced, terms,
};
use lensblur::plane::{CameraIdentity, Channel, LensSetting};
use lensblur::profile::{Profile, ProfileError};
use lensblur::simulate::{SampleNoise, SimulatedSession, VirtualLens};

const W: usize = 2400;
const H: usize = 1600;

fn grid_settings(nf: usize, na: usize) -> Vec<LensSetting> {
    let mut out = Vec::new();
    for f in spaced(24.0, 105.0, nf, false) {
        for a in spaced(4.0, 10.0, na, true) {
            out.push(LensSetting {
                focal_mm: f,
                f_number: a,
            });
        }
    }
    out
}

/// 16 novel settings between the calibration grid's (midpoints in f and in stops).
fn novel_settings() -> Vec<LensSetting> {
    let fs = spaced(24.0, 105.0, 5, false);
    let as_ = spaced(4.0, 10.0, 5, true);
    let mut out = Vec::new();
    for i in 0..4 {
        for j in 0..4 {
            out.push(LensSetting {
                focal_mm: 0.5 * (fs[i] + fs[i + 1]),
                f_number: (as_[j] * as_[j + 1]).sqrt(),
            });
        }
    }
    out
}

fn session(shots_per_setting: usize, seed: u64) -> SimulatedSession {
    SimulatedSession {
        shots_per_setting,
        seed,
        ..SimulatedSession::new(W, H)
    }
}

/// 5 × 5 settings, two shots each; like the paper, every other square is sampled.
fn calibration_set() -> Dataset {
    SimulatedSession {
        alternate_squares: true,
        ..session(2, 7)
    }
    .dataset(&VirtualLens::demo(), &grid_settings(5, 5))
}

fn p95(e: &[Vec<f64>; 3]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for k in 0..3 {
        let mut s = e[k].clone();
        s.sort_by(f64::total_cmp);
        out[k] = percentile_sorted(&s, 95.0);
    }
    out
}

fn mean(e: &[Vec<f64>; 3]) -> f64 {
    e.iter()
        .map(|v| v.iter().sum::<f64>() / v.len() as f64)
        .sum::<f64>()
        / 3.0
}

#[test]
fn sample_noise_is_no_smaller_than_the_measured_chains() {
    // The same seed draws the same poses and random numbers; only their scale differs.
    let lens = VirtualLens::demo();
    let settings = grid_settings(3, 3);
    let noisy = session(1, 5).dataset(&lens, &settings);
    let exact = SimulatedSession {
        noise: SampleNoise::none(),
        ..session(1, 5)
    }
    .dataset(&lens, &settings);
    assert_eq!(noisy.samples.len(), exact.samples.len());
    let mut sigma = Vec::new();
    let mut rho = Vec::new();
    for (n, e) in noisy.samples.iter().zip(&exact.samples) {
        assert_eq!((n.x, n.y, n.channel), (e.x, e.y, e.channel));
        sigma.push((n.gaussian.sigma_x / e.gaussian.sigma_x - 1.0).abs());
        sigma.push((n.gaussian.sigma_y / e.gaussian.sigma_y - 1.0).abs());
        rho.push((n.gaussian.rho - e.gaussian.rho).abs());
    }
    sigma.sort_by(f64::total_cmp);
    rho.sort_by(f64::total_cmp);
    let (s50, s95) = (
        percentile_sorted(&sigma, 50.0),
        percentile_sorted(&sigma, 95.0),
    );
    let (r50, r95) = (percentile_sorted(&rho, 50.0), percentile_sorted(&rho, 95.0));
    eprintln!(
        "simulated measurement error: σ median {s50:.4} p95 {s95:.4}; ρ median {r50:.4} p95 {r95:.4}"
    );
    // Kernels measured on simulated shots: σ ≈ 0.5–1 % median, 2–3 % p95; ρ ≈
    // 0.003–0.006 median. The stand-in must be at least that bad.
    assert!(s50 >= 0.01 && s95 >= 0.03, "σ: {s50} {s95}");
    assert!(r50 >= 0.006, "ρ: {r50}");

    // The per-shot part is shared within a shot: a shot's mean σ error is its field's
    // constant, RMS 1 % / √2 by design (the independent part averages out over ~1000
    // samples). 100 shots pin the RMS to about ±10 %.
    let settings = grid_settings(10, 10);
    let noisy = session(1, 5).dataset(&lens, &settings);
    let exact = SimulatedSession {
        noise: SampleNoise::none(),
        ..session(1, 5)
    }
    .dataset(&lens, &settings);
    let shot_mean = |shot: usize| {
        let (mut acc, mut n) = (0.0, 0.0);
        for (a, b) in noisy.samples.iter().zip(&exact.samples) {
            if a.shot == shot {
                acc += a.gaussian.sigma_x / b.gaussian.sigma_x - 1.0;
                n += 1.0;
            }
        }
        acc / n
    };
    let means: Vec<f64> = (0..noisy.shots.len()).map(shot_mean).collect();
    let spread = (means.iter().map(|m| m * m).sum::<f64>() / means.len() as f64).sqrt();
    eprintln!("RMS of per-shot mean σ error: {spread:.4}");
    assert!((0.005..0.009).contains(&spread), "{spread}");
}

#[test]
fn global_terms_follow_the_definition() {
    let g31 = terms(3, 1, true, true);
    // Every monomial of total order ≤ 3 with at most one power of f or a …
    for i in 0..=3u8 {
        for j in 0..=3u8 {
            for k in 0..=1u8 {
                for l in 0..=1u8 {
                    let t = [i, j, k, l];
                    let expected = i + j <= 3 && k + l <= 1 && i + j + k + l <= 3;
                    assert_eq!(g31.contains(&t), expected, "{t:?}");
                }
            }
        }
    }
    // … and nothing like a²x or f·a·x.
    assert!(!g31.iter().any(|t| t[2] + t[3] >= 2));
    assert!(
        g31.contains(&[3, 0, 0, 0])
            && g31.contains(&[0, 3, 0, 0])
            && g31.contains(&[2, 0, 1, 0])
            && g31.contains(&[1, 1, 0, 1])
    );
    assert_eq!(terms(8, 3, true, true).len(), 285);
    // No duplicates.
    let mut t = terms(8, 3, true, true);
    t.sort_unstable();
    t.dedup();
    assert_eq!(t.len(), 285);
    // A session at one focal length has no f terms; at one setting, spatial terms only.
    assert!(terms(4, 2, false, true).iter().all(|t| t[2] == 0));
    assert_eq!(terms(4, 2, false, false).len(), 15);
}

#[test]
fn local_blend_is_a_partition_of_unity_without_seams() {
    let grid = CentreGrid::new(W, H, 300.0, std::f64::consts::FRAC_1_SQRT_2);
    for k in 0..500 {
        let (x, y) = ((k as f64 * 37.3) % W as f64, (k as f64 * 53.1) % H as f64);
        let s: f64 = grid.blend(x, y).iter().map(|b| b.1).sum();
        assert!((s - 1.0).abs() < 1e-12);
    }
    let ds = session(1, 3).dataset(&VirtualLens::demo(), &grid_settings(3, 3));
    let model = LocalModel::fit(&ds, 1, 2, &LocalOptions::default()).unwrap();
    let s = LensSetting {
        focal_mm: 50.0,
        f_number: 5.6,
    };
    let (_, per_centre) = model.channels.iter().find(|c| c.0 == Channel::G).unwrap();
    // What a field that took the nearest centre's polynomial would predict.
    let nearest = |x: f64, y: f64| {
        let idx = (0..model.grid.len())
            .min_by(|&a, &b| {
                let (ca, cb) = (model.grid.centre(a), model.grid.centre(b));
                (ca[0] - x)
                    .hypot(ca[1] - y)
                    .total_cmp(&(cb[0] - x).hypot(cb[1] - y))
            })
            .unwrap();
        model.basis.eval3(
            local_coords(&model.grid, &model.norm, idx, x, y, s.focal_mm, s.f_number),
            &per_centre[idx],
        )
    };
    // Cross every cell border and every nearest-centre border (half-way between centres)
    // along a row and a column: the jump over ±1e-6 px must be of the order of the
    // slope times 2e-6 px, where a seam would jump by the fits' disagreement.
    let eps = 1e-6;
    let jump = |f: &dyn Fn(f64, f64) -> [f64; 3], (x0, y0): (f64, f64), (x1, y1): (f64, f64)| {
        let (a, b) = (f(x0, y0), f(x1, y1));
        (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max)
    };
    let blended = |x: f64, y: f64| model.predict(Channel::G, x, y, s).unwrap();
    let (sx, sy) = (
        (W - 1) as f64 / (model.grid.nx - 1) as f64,
        (H - 1) as f64 / (model.grid.ny - 1) as f64,
    );
    let (mut worst_blend, mut worst_nearest) = (0.0f64, 0.0f64);
    let y_row = 0.37 * H as f64;
    let x_col = 0.61 * W as f64;
    for i in 1..(2 * (model.grid.nx - 1)) {
        let x = 0.5 * i as f64 * sx;
        worst_blend = worst_blend.max(jump(&blended, (x - eps, y_row), (x + eps, y_row)));
        if i % 2 == 1 {
            worst_nearest = worst_nearest.max(jump(&nearest, (x - eps, y_row), (x + eps, y_row)));
        }
    }
    for j in 1..(2 * (model.grid.ny - 1)) {
        let y = 0.5 * j as f64 * sy;
        worst_blend = worst_blend.max(jump(&blended, (x_col, y - eps), (x_col, y + eps)));
        if j % 2 == 1 {
            worst_nearest = worst_nearest.max(jump(&nearest, (x_col, y - eps), (x_col, y + eps)));
        }
    }
    eprintln!(
        "largest jump across a border: blended {worst_blend:.2e}, nearest centre {worst_nearest:.2e}"
    );
    // The slope is below 1e-2 per px, so continuity allows ~2e-8; a nearest-centre field
    // (the control) jumps by the fits' disagreement, orders of magnitude more.
    assert!(
        worst_blend < 1e-7,
        "seam in the blended field: {worst_blend}"
    );
    assert!(
        worst_nearest > 1e-4,
        "control: the nearest-centre field should show seams ({worst_nearest})"
    );

    // And the blended field's slope has no kinks either: walk a diagonal in 0.05 px
    // steps; no step may change it by more than its smooth slope allows.
    let step = 0.05;
    let mut worst = 0.0f64;
    let mut prev = blended(0.0, 0.0);
    let n = (W as f64 / step) as usize;
    for i in 1..n {
        let x = i as f64 * step;
        let y = x * (H as f64 - 1.0) / (W as f64 - 1.0);
        let p = blended(x, y);
        for k in 0..3 {
            worst = worst.max((p[k] - prev[k]).abs());
        }
        prev = p;
    }
    eprintln!("largest change per 0.05 px step along the diagonal: {worst:.2e}");
    assert!(worst < 2e-4, "seam: {worst}");
}

/// The issue's bars on a 5 × 5 × 2 calibration set and a test set at 16 novel settings:
/// p95 error < 10 % of range for both models and every parameter, the mean
/// cross-validation error, and the cross-validated choice no worse than G_{8,3} and
/// L_{1,3} on the test set.
#[test]
fn models_meet_the_bars_at_novel_settings() {
    let t0 = std::time::Instant::now();
    let lens = VirtualLens::demo();
    let cal = calibration_set();
    let ranges = param_ranges(&cal);
    // The test shots as measured (with error), their truth at the same squares, and
    // what an estimator with the same systematic bias but no random error would have
    // measured there: the best any model fitted to biased measurements can do, so the
    // fairest ground for comparing models.
    let test_measured = session(1, 1234).dataset(&lens, &novel_settings());
    let test_truth = SimulatedSession {
        noise: SampleNoise::none(),
        ..session(1, 1234)
    }
    .dataset(&lens, &novel_settings());
    let bias = SampleNoise::default();
    let test_expected = SimulatedSession {
        noise: SampleNoise {
            sigma_bias_per_px: bias.sigma_bias_per_px,
            rho_shrink: bias.rho_shrink,
            ..SampleNoise::none()
        },
        ..session(1, 1234)
    }
    .dataset(&lens, &novel_settings());
    let report = cross_validate(&cal, &CvOptions::default(), &JobContext::silent()).unwrap();
    eprintln!(
        "{} samples, {} shots; ranges {ranges:?}; CV took {:.1} s",
        cal.samples.len(),
        cal.shots.len(),
        t0.elapsed().as_secs_f64()
    );
    let g = report.global.as_ref().unwrap();
    let l = report.local.as_ref().unwrap();
    for (name, sel) in [("G", g), ("L", l)] {
        for p in sel.alpha_curve.iter().chain(&sel.beta_curve) {
            eprintln!(
                "{name}_{{{},{}}} ({} terms): CV mean {:.2} %, per param {:.2?}, p95 {:.2?}",
                p.alpha, p.beta, p.terms, p.mean_pct, p.mean_error_pct, p.p95_error_pct
            );
        }
    }
    let (l13_cv, _) =
        cross_validate_fixed(&cal, ModelKind::Local, 1, 3, &CvOptions::default()).unwrap();
    eprintln!(
        "chosen G_{{{},{}}} (CV {:.2} %), L_{{{},{}}} (CV {:.2} %); L_{{1,3}} CV mean {:.2} % {:.2?} (paper: 3.4–4.0 %)",
        g.alpha,
        g.beta,
        g.chosen.mean_pct,
        l.alpha,
        l.beta,
        l.chosen.mean_pct,
        l13_cv.mean_pct,
        l13_cv.mean_error_pct
    );
    let (best_kind, _, _) = report.best().unwrap();

    let t1 = std::time::Instant::now();
    let fit = |kind: ModelKind, a: usize, b: usize| {
        fit_model(&cal, kind, a, b, &LocalOptions::default()).unwrap()
    };
    let models = [
        ("chosen global", ModelKind::Global, g.alpha, g.beta),
        ("chosen local", ModelKind::Local, l.alpha, l.beta),
        ("G_{8,3}", ModelKind::Global, 8, 3),
        ("L_{1,3}", ModelKind::Local, 1, 3),
    ];
    let mut results = Vec::new();
    for (name, kind, a, b) in models {
        let model = fit(kind, a, b);
        let vs_truth = prediction_errors(&test_truth, &ranges, model.as_ref());
        let vs_meas = prediction_errors(&test_measured, &ranges, model.as_ref());
        let vs_expected = prediction_errors(&test_expected, &ranges, model.as_ref());
        eprintln!(
            "{name} ({kind:?} {a},{b}): test error vs measured p95 {:.2?} % mean {:.2} %; vs truth p95 {:.2?} % mean {:.2} %; vs bias-only {:.3} %",
            p95(&vs_meas),
            mean(&vs_meas),
            p95(&vs_truth),
            mean(&vs_truth),
            mean(&vs_expected)
        );
        results.push((
            name,
            kind,
            p95(&vs_meas),
            mean(&vs_meas),
            p95(&vs_truth),
            mean(&vs_expected),
        ));
    }
    eprintln!("fits and test took {:.1} s", t1.elapsed().as_secs_f64());
    for (name, _, meas95, _, truth95, _) in &results {
        for k in 0..3 {
            assert!(meas95[k] < 10.0, "{name}: p95 error vs measured {meas95:?}");
            assert!(truth95[k] < 10.0, "{name}: p95 error vs truth {truth95:?}");
        }
    }
    // The family cross-validation prefers, at its chosen (α, β), against the paper's
    // fixed models, on the error against the bias-only measurement (random test-set
    // error and the shared estimator bias would only add the same to every model).
    // Across calibration seeds 7–14 the choice beat both on seven (by 6–10 % against
    // G_{8,3}); on seed 12 cross-validation preferred L_{2,3} by 0.02 points and it
    // came out at 0.355 % against G_{8,3}'s 0.315 % of range. L_{1,3} is always far
    // behind (0.84–1.06 %).
    let chosen = results
        .iter()
        .find(|r| r.1 == best_kind && r.0.starts_with("chosen"))
        .unwrap();
    for fixed in &results[2..] {
        assert!(
            chosen.5 <= fixed.5,
            "{} ({:.3} %) is worse than {} ({:.3} %) on the test set",
            chosen.0,
            chosen.5,
            fixed.0,
            fixed.5
        );
    }
    // Cross-validation errors sit near the measurement noise (the paper: 3.4–4.0 %).
    assert!(
        g.chosen.mean_pct < 5.0 && l.chosen.mean_pct < 5.0,
        "{} {}",
        g.chosen.mean_pct,
        l.chosen.mean_pct
    );
    eprintln!("total {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn a_field_at_one_setting_matches_pointwise_prediction() {
    let ds = session(1, 8).dataset(&VirtualLens::demo(), &grid_settings(4, 4));
    let g = GlobalModel::fit(&ds, 6, 2).unwrap();
    let l = LocalModel::fit(&ds, 1, 3, &LocalOptions::default()).unwrap();
    let s = LensSetting {
        focal_mm: 71.0,
        f_number: 4.7,
    };
    let mut worst = 0.0f64;
    for ch in [Channel::R, Channel::G, Channel::B] {
        let (fg, fl) = (g.at_setting(ch, s).unwrap(), l.at_setting(ch, s).unwrap());
        // Inside and outside the chart's coverage, corners included.
        for k in 0..400 {
            let (x, y) = ((k as f64 * 61.7) % W as f64, (k as f64 * 37.9) % H as f64);
            for (a, b) in [
                (fg.predict(x, y), g.predict(ch, x, y, s).unwrap()),
                (fl.predict(x, y), l.predict(ch, x, y, s).unwrap()),
            ] {
                for p in 0..3 {
                    worst = worst.max((a[p] - b[p]).abs());
                }
            }
        }
    }
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn profile_round_trip_and_validation() {
    let ds = session(1, 5).dataset(&VirtualLens::demo(), &grid_settings(4, 4));
    let opts = CalibrateOptions {
        families: Families::Both,
        alpha: Some(1),
        beta: Some(3),
        ..CalibrateOptions::default()
    };
    let (mut profile, _) = calibrate(&ds, None, &opts, &JobContext::silent()).unwrap();
    // Replace the global by the paper's G_{8,3} to measure its size.
    profile.global = Some(GlobalModel::fit(&ds, 8, 3).unwrap());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("profile.json");
    profile.save(&path).unwrap();
    let size_both = std::fs::metadata(&path).unwrap().len();
    let loaded = Profile::load(&path).unwrap();
    let s = LensSetting {
        focal_mm: 60.0,
        f_number: 6.3,
    };
    for (x, y) in [
        (0.0, 0.0),
        (1200.0, 800.0),
        (2399.0, 1599.0),
        (333.0, 1444.0),
    ] {
        for kind in [ModelKind::Global, ModelKind::Local] {
            let a = profile.predict_with(kind, Channel::B, x, y, s).unwrap();
            let b = loaded.predict_with(kind, Channel::B, x, y, s).unwrap();
            assert!(
                (a.sigma_x - b.sigma_x).abs() < 1e-4 && (a.rho - b.rho).abs() < 1e-4,
                "{a:?} {b:?}"
            );
        }
    }
    let mut global_only = loaded.clone();
    global_only.local = None;
    global_only.preferred = ModelKind::Global;
    let with_trust = global_only.to_json().unwrap().len();
    // The bar is the model's (the paper's ≈ 12 kB); the trust record comes on top.
    global_only.trust = None;
    let g_len = global_only.to_json().unwrap().len();
    eprintln!("G_{{8,3}} with its trust record: {with_trust} B");
    let mut local_only = loaded.clone();
    local_only.global = None;
    local_only.preferred = ModelKind::Local;
    let l_len = local_only.to_json().unwrap().len();
    eprintln!(
        "profile sizes: G_{{8,3}} only {g_len} B, L_{{1,3}} only {l_len} B, both {size_both} B"
    );
    assert!(g_len < 20_000, "{g_len}");

    // Outside the calibrated range: an error, unless extrapolation is asked for.
    let far = LensSetting {
        focal_mm: 150.0,
        f_number: 5.6,
    };
    assert!(matches!(
        loaded.predict(Channel::G, 10.0, 10.0, far),
        Err(ProfileError::OutOfRange { .. })
    ));
    let mut lenient = loaded.clone();
    lenient.allow_extrapolation = true;
    assert!(lenient.predict(Channel::G, 10.0, 10.0, far).is_ok());
    // Inside both ranges but never calibrated: a zoom that only reaches f/5.6 at the
    // long end has no 105 mm f/4 among its settings.
    let mut staircase = loaded.clone();
    staircase
        .calibrated_settings
        .retain(|c| !(c.focal_mm > 100.0 && c.f_number < 5.0));
    let corner = LensSetting {
        focal_mm: 105.0,
        f_number: 4.0,
    };
    assert!(loaded.predict(Channel::G, 10.0, 10.0, corner).is_ok());
    let e = staircase
        .predict(Channel::G, 10.0, 10.0, corner)
        .unwrap_err();
    assert!(matches!(e, ProfileError::BetweenRanges { .. }), "{e}");
    assert!(staircase.predict(Channel::G, 10.0, 10.0, s).is_ok());

    // Another camera.
    let other = CameraIdentity {
        lens_serial: Some("VZ-0002".into()),
        ..ds.identity.clone()
    };
    let e = loaded.check_identity(&other, false).unwrap_err();
    assert!(e.to_string().contains("VZ-0002"), "{e}");
    assert!(!loaded.check_identity(&other, true).unwrap().is_empty());
    assert!(
        loaded
            .check_identity(&ds.identity, false)
            .unwrap()
            .is_empty()
    );

    // Wrong schema / version, and a truncated coefficient array.
    let text = std::fs::read_to_string(&path).unwrap();
    let bad = text.replace("lensblur.profile/4", "lensblur.profile/5");
    assert!(matches!(
        Profile::from_json(&bad, "p.json"),
        Err(ProfileError::Schema { .. })
    ));
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["global"]["alpha"] = serde_json::json!(7);
    assert!(matches!(
        Profile::from_json(&v.to_string(), "p.json"),
        Err(ProfileError::Invalid { .. })
    ));

    // The field every 64 px.
    let field = loaded.predict_field(s, 64).unwrap();
    assert_eq!(field.len(), 3 * 39 * 26);

    // The chart covered only part of the sensor: the extent survives the round trip,
    // and beyond it the field continues linearly (continuous at the border, no
    // polynomial blow-up at the corners).
    let e = loaded.norm.sampled_extent_px.unwrap();
    let saved = profile.norm.sampled_extent_px.unwrap();
    assert!(
        (0..4).all(|k| (e[k] - saved[k]).abs() < 1e-9),
        "{e:?} {saved:?}"
    );
    assert!(e[0] > 50.0 && e[2] < W as f64 - 50.0, "{e:?}");
    let lens = VirtualLens::demo();
    for kind in [ModelKind::Global, ModelKind::Local] {
        let at = |x: f64, y: f64| loaded.predict_with(kind, Channel::R, x, y, s).unwrap();
        let (a, b) = (at(e[0] + 1e-6, 700.0), at(e[0] - 1e-6, 700.0));
        assert!(
            (a.sigma_x - b.sigma_x).abs() < 1e-6,
            "{kind:?}: {a:?} {b:?}"
        );
        let corner = at(0.0, 0.0);
        let truth = lens
            .gaussian_at(Channel::R, 0.0, 0.0, W, H, s)
            .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
        eprintln!("{kind:?} at the corner (0, 0): {corner:?}, truth {truth:?}");
        assert!(
            (corner.sigma_x / truth.sigma_x - 1.0).abs() < 0.25,
            "{kind:?}: {corner:?} vs {truth:?}"
        );
    }
}

/// Damaged or hostile numbers in a profile file (sizes that overflow or are negative or
/// not numbers, ranges that are not intervals, orders and counts that do not match,
/// coefficient arrays of the wrong length): each is refused with one line naming the
/// file, never a panic, a wrapped size or an allocation sized by the file.
#[test]
fn hostile_profiles_are_refused_naming_the_file() {
    use serde_json::{Value, json};
    let ds = session(1, 9).dataset(&VirtualLens::demo(), &grid_settings(3, 3));
    let profile = Profile::new(
        ds.identity.clone(),
        Some(lensblur::chart::ChartSpec::default()),
        ds.distinct_setting_pairs(),
        Some(GlobalModel::fit(&ds, 2, 1).unwrap()),
        Some(LocalModel::fit(&ds, 1, 1, &LocalOptions::default()).unwrap()),
        None,
        ModelKind::Local,
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.json");
    profile.save(&good).unwrap();
    assert!(Profile::load(&good).is_ok());
    let original: Value = serde_json::from_str(&std::fs::read_to_string(&good).unwrap()).unwrap();
    let global_cxx = original["global"]["channels"][0]["cxx"].clone();
    let first_global_channel = original["global"]["channels"][0].clone();
    type Tamper = Box<dyn Fn(&mut Value)>;
    let cases: Vec<(&str, Tamper)> = vec![
        (
            "grid-product-overflows",
            Box::new(|v| {
                v["local"]["centres_x"] = json!(1u64 << 32);
                v["local"]["centres_y"] = json!((1u64 << 32) + 1);
            }),
        ),
        (
            "grid-beyond-the-sensor",
            Box::new(|v| v["local"]["centres_x"] = json!(1_000_000_000u64)),
        ),
        (
            "grid-negative",
            Box::new(|v| v["local"]["centres_x"] = json!(-3)),
        ),
        (
            "grid-of-one",
            Box::new(|v| v["local"]["centres_y"] = json!(1)),
        ),
        (
            "radius-nan",
            Box::new(|v| v["local"]["radius_px"] = json!(f64::NAN)),
        ),
        (
            "radius-negative",
            Box::new(|v| v["local"]["radius_px"] = json!(-40.0)),
        ),
        (
            "radius-zero",
            Box::new(|v| v["local"]["radius_px"] = json!(0.0)),
        ),
        ("width-negative", Box::new(|v| v["width"] = json!(-2400))),
        ("width-zero", Box::new(|v| v["width"] = json!(0))),
        ("width-huge", Box::new(|v| v["width"] = json!(u64::MAX))),
        (
            "height-fractional",
            Box::new(|v| v["height"] = json!(1600.5)),
        ),
        (
            "focal-range-nan",
            Box::new(|v| v["focal_range_mm"] = json!([f64::NAN, 105.0])),
        ),
        (
            "focal-range-negative",
            Box::new(|v| v["focal_range_mm"] = json!([-24.0, 105.0])),
        ),
        (
            "focal-range-reversed",
            Box::new(|v| v["focal_range_mm"] = json!([105.0, 24.0])),
        ),
        (
            "f-number-range-zero",
            Box::new(|v| v["f_number_range"] = json!([0.0, 10.0])),
        ),
        (
            "extent-inverted",
            Box::new(|v| v["sampled_extent_px"] = json!([2000.0, 10.0, 100.0, 1500.0])),
        ),
        (
            "calibrated-setting-negative",
            Box::new(|v| v["calibrated_settings"][0]["focal_mm"] = json!(-50.0)),
        ),
        (
            "alpha-huge",
            Box::new(|v| v["global"]["alpha"] = json!(u64::MAX)),
        ),
        (
            "beta-too-high",
            Box::new(|v| v["global"]["beta"] = json!(16)),
        ),
        (
            "term-count-huge",
            Box::new(|v| v["global"]["terms"] = json!(1_000_000_000_000u64)),
        ),
        (
            "local-term-count-zero",
            Box::new(|v| v["local"]["terms"] = json!(0)),
        ),
        (
            "coefficients-empty",
            Box::new(|v| v["local"]["channels"][0]["cyy"] = json!("")),
        ),
        (
            "coefficients-of-another-model",
            Box::new(move |v| v["local"]["channels"][1]["cor"] = global_cxx.clone()),
        ),
        (
            "coefficients-not-base64",
            Box::new(|v| v["global"]["channels"][2]["cxx"] = json!("!!!!")),
        ),
        (
            "channel-stored-twice",
            Box::new(move |v| v["global"]["channels"][1] = first_global_channel.clone()),
        ),
        (
            "chart-huge",
            Box::new(|v| v["chart"]["cols"] = json!(1_000_000_000u64)),
        ),
    ];
    for (name, tamper) in cases {
        let mut v = original.clone();
        tamper(&mut v);
        let path = dir.path().join(format!("{name}.json"));
        std::fs::write(&path, v.to_string()).unwrap();
        let Err(e) = Profile::load(&path) else {
            panic!("{name}: accepted");
        };
        let msg = e.to_string();
        eprintln!("{msg}");
        assert!(
            msg.contains(&path.display().to_string()),
            "{name}: the error does not name the file: {msg}"
        );
        assert!(!msg.contains('\n'), "{name}: more than one line: {msg}");
    }
}

#[test]
fn degenerate_sessions() {
    let lens = VirtualLens::demo();
    // One setting only: a spatial model; β = 1 is refused with the counts.
    let one = session(2, 1).dataset(
        &lens,
        &[LensSetting {
            focal_mm: 50.0,
            f_number: 5.6,
        }],
    );
    assert_eq!(one.setting_resolution(), 1);
    let m = GlobalModel::fit(&one, 6, 0).unwrap();
    assert!(m.basis.terms().iter().all(|t| t[2] == 0 && t[3] == 0));
    let e = GlobalModel::fit(&one, 6, 1).unwrap_err();
    assert!(
        matches!(
            e,
            ModelError::BetaTooLarge {
                beta: 1,
                n_f: 1,
                n_a: 1,
                ..
            }
        ),
        "{e}"
    );
    // Predicting at that setting reproduces the truth within the noise.
    let truth = lens
        .gaussian_at(
            Channel::G,
            1000.0,
            700.0,
            W,
            H,
            LensSetting {
                focal_mm: 50.0,
                f_number: 5.6,
            },
        )
        .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
    let p = m
        .predict(
            Channel::G,
            1000.0,
            700.0,
            LensSetting {
                focal_mm: 50.0,
                f_number: 5.6,
            },
        )
        .unwrap();
    assert!(
        (p[0] - truth.sigma_x).abs() < 0.02 * truth.sigma_x,
        "{p:?} {truth:?}"
    );

    // A single focal length: β over a only.
    let settings: Vec<LensSetting> = spaced(4.0, 10.0, 4, true)
        .into_iter()
        .map(|a| LensSetting {
            focal_mm: 35.0,
            f_number: a,
        })
        .collect();
    let fixed_f = session(1, 2).dataset(&lens, &settings);
    assert_eq!(fixed_f.setting_resolution(), 4);
    let m = GlobalModel::fit(&fixed_f, 3, 3).unwrap();
    assert!(m.basis.terms().iter().all(|t| t[2] == 0) && m.basis.terms().iter().any(|t| t[3] == 3));
    // Too few settings for β.
    let two = session(1, 4).dataset(&lens, &grid_settings(2, 3));
    let e = LocalModel::fit(&two, 1, 2, &LocalOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("N_f = 2") && msg.contains("N_a = 3") && msg.contains("β = 2"),
        "{msg}"
    );

    // Cross-validation of a single shot is refused with the count.
    let single = session(1, 1).dataset(
        &lens,
        &[LensSetting {
            focal_mm: 50.0,
            f_number: 5.6,
        }],
    );
    assert!(matches!(
        cross_validate(&single, &CvOptions::default(), &JobContext::silent()),
        Err(ModelError::TooFewShots { shots: 1 })
    ));
    // ... and so is calibrating it without orders, with the way out in the message;
    // with them it is a spatial-only profile.
    let e = calibrate(
        &single,
        None,
        &CalibrateOptions::default(),
        &JobContext::silent(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("--alpha"), "{e}");
    let (p, _) = calibrate(
        &single,
        None,
        &CalibrateOptions {
            alpha: Some(4),
            families: Families::Global,
            ..CalibrateOptions::default()
        },
        &JobContext::silent(),
    )
    .unwrap();
    let g = p.global.as_ref().unwrap();
    assert_eq!((g.alpha, g.beta), (4, 0));

    // One setting, two shots: cross-validation over α alone (β = 0), by shot even when
    // asked to hold out settings (there is only one).
    let cv = cross_validate(
        &one,
        &CvOptions {
            hold_out: HoldOut::Setting,
            local_alphas: vec![1],
            global_alphas: vec![2, 4],
            ..CvOptions::default()
        },
        &JobContext::silent(),
    )
    .unwrap();
    assert_eq!(cv.folds, 2);
    let sel = cv.global.as_ref().unwrap();
    assert_eq!(sel.beta_curve.len(), 1);
    assert!(sel.chosen.mean_pct.is_finite() && sel.chosen.mean_pct < 10.0);

    // Settings that cannot determine the terms in f and a: three shots on a diagonal
    // have N_f = N_a = 3, yet β = 2 has six such terms.
    let diagonal: Vec<LensSetting> = [(24.0, 4.0), (50.0, 5.6), (105.0, 10.0)]
        .iter()
        .map(|&(f, a)| LensSetting {
            focal_mm: f,
            f_number: a,
        })
        .collect();
    let diag = session(1, 6).dataset(&lens, &diagonal);
    assert_eq!(diag.setting_resolution(), 3);
    let e = GlobalModel::fit(&diag, 4, 2).unwrap_err();
    assert!(
        matches!(
            e,
            ModelError::SettingsTooSparse {
                beta: 2,
                terms: 6,
                settings: 3
            }
        ),
        "{e}"
    );
    // β = 1 (1, f, a) is determined by three settings off a line.
    assert!(GlobalModel::fit(&diag, 4, 1).is_ok());
    // Cross-validation keeps β to what the settings determine.
    let cv = cross_validate(
        &diag,
        &CvOptions {
            local_alphas: vec![],
            global_alphas: vec![2],
            ..CvOptions::default()
        },
        &JobContext::silent(),
    )
    .unwrap();
    assert_eq!(cv.global.as_ref().unwrap().beta_curve.len(), 2);

    // Orders the basis cannot evaluate are refused, not a panic.
    assert!(matches!(
        GlobalModel::fit(&one, 16, 0),
        Err(ModelError::OrderTooHigh { alpha: 16, .. })
    ));
}

#[test]
fn kernels_files_are_read_and_unknown_settings_named() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("a.kernels.json");
    std::fs::write(
        &good,
        r#"{"schema":"lensblur.kernels/1","width":640,"height":480,"focal_mm":35,"f_number":5.6,"oversample":3,
           "samples":[{"x":10,"y":20,"channel":"G","cxx":1.1,"cyy":1.2,"cor":0.1},
                      {"x":30,"y":20,"channel":"R","status":"failed","reason":"saturated"},
                      {"x":50,"y":20,"channel":"B","cxx":1.3,"cyy":1.4,"cor":-0.2,"kernel":{"size":1,"data":[1]}}]}"#,
    )
    .unwrap();
    let nosetting = dir.path().join("b.kernels.json");
    std::fs::write(
        &nosetting,
        r#"{"schema":"lensblur.kernels/1","width":640,"height":480,"samples":[]}"#,
    )
    .unwrap();
    let ds = Dataset::from_kernels_files(&[good.as_path()], &[None]).unwrap();
    assert_eq!(ds.samples.len(), 2);
    assert_eq!(ds.shots[0].focal_mm, 35.0);
    let e = Dataset::from_kernels_files(&[good.as_path(), nosetting.as_path()], &[]).unwrap_err();
    assert!(
        matches!(&e, ModelError::UnknownSetting { shot } if shot.contains("b.kernels.json")),
        "{e}"
    );
    // A manifest's setting fills the gap.
    let given = Some(LensSetting {
        focal_mm: 50.0,
        f_number: 8.0,
    });
    let ds = Dataset::from_kernels_files(&[good.as_path(), nosetting.as_path()], &[None, given])
        .unwrap();
    assert_eq!(ds.shots[1].f_number, 8.0);

    // Identity from EXIF: completed across shots, and a session that mixes lens units
    // is refused, naming the field and the shot.
    let with_id = |name: &str, id: &str| {
        let p = dir.path().join(name);
        std::fs::write(
            &p,
            format!(
                r#"{{"schema":"lensblur.kernels/1","width":640,"height":480,"focal_mm":35,"f_number":5.6,
                   "identity":{{"make":"Virtual",{id}}},
                   "samples":[{{"x":10,"y":20,"channel":"G","cxx":1.1,"cyy":1.2,"cor":0.1}}]}}"#
            ),
        )
        .unwrap();
        p
    };
    let a = with_id("c.kernels.json", r#""model":"VZ 24-105mm f/4""#);
    let b = with_id("d.kernels.json", r#""lens_serial":"VZ-0001""#);
    let c = with_id("e.kernels.json", r#""lens_serial":"VZ-0002""#);
    let ds = Dataset::from_kernels_files(&[a.as_path(), b.as_path()], &[]).unwrap();
    assert_eq!(ds.identity.model.as_deref(), Some("VZ 24-105mm f/4"));
    assert_eq!(ds.identity.lens_serial.as_deref(), Some("VZ-0001"));
    let e = Dataset::from_kernels_files(&[a.as_path(), b.as_path(), c.as_path()], &[]).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("lens serial") && msg.contains("VZ-0002") && msg.contains("e.kernels.json"),
        "{msg}"
    );
}

fn write_kernels_files(dir: &std::path::Path, ds: &Dataset) -> Vec<std::path::PathBuf> {
    let mut paths = Vec::new();
    for (i, shot) in ds.shots.iter().enumerate() {
        let samples: Vec<serde_json::Value> = ds
            .samples
            .iter()
            .filter(|s| s.shot == i)
            .map(|s| {
                serde_json::json!({"x": s.x, "y": s.y, "channel": s.channel, "cxx": s.gaussian.sigma_x,
                                   "cyy": s.gaussian.sigma_y, "cor": s.gaussian.rho})
            })
            .collect();
        let doc = serde_json::json!({"schema": "lensblur.kernels/1", "width": ds.width, "height": ds.height,
            "focal_mm": shot.focal_mm, "f_number": shot.f_number, "oversample": 3, "samples": samples});
        let p = dir.join(format!("shot{i:02}.kernels.json"));
        std::fs::write(&p, serde_json::to_vec(&doc).unwrap()).unwrap();
        paths.push(p);
    }
    paths
}

#[test]
fn command_line_calibrate_crossval_predict_sweeps() {
    let exe = env!("CARGO_BIN_EXE_lensblur");
    let (w, h) = (960, 640);
    let ds = SimulatedSession {
        seed: 21,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&VirtualLens::demo(), &grid_settings(3, 3));
    let dir = tempfile::tempdir().unwrap();
    let kernels = write_kernels_files(dir.path(), &ds);
    let run = |args: &[&str]| {
        let out = std::process::Command::new(exe).args(args).output().unwrap();
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let d = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let ks: Vec<String> = kernels
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let mut args = vec!["calibrate", "--out"];
    let profile = d("profile.json");
    let cv = d("cv.json");
    args.push(&profile);
    args.extend(["--cv-out", &cv, "--kernels"]);
    args.extend(ks.iter().map(String::as_str));
    let log = run(&args);
    eprintln!("{log}");
    let p = Profile::load(std::path::Path::new(&profile)).unwrap();
    assert!(p.global.is_some() && p.local.is_some() && p.cv.is_some());

    let pts = d("pts.json");
    std::fs::write(&pts, "[[100, 100], [480, 320], [900, 600]]").unwrap();
    let pred = d("pred.json");
    run(&[
        "predict",
        "--profile",
        &profile,
        "--focal",
        "50",
        "--aperture",
        "5.6",
        "--points",
        &pts,
        "--out",
        &pred,
    ]);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&pred).unwrap()).unwrap();
    assert_eq!(v["samples"].as_array().unwrap().len(), 9);
    let truth = VirtualLens::demo()
        .gaussian_at(
            Channel::R,
            480.0,
            320.0,
            w,
            h,
            LensSetting {
                focal_mm: 50.0,
                f_number: 5.6,
            },
        )
        .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
    let r = v["samples"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["channel"] == "R" && s["x"] == 480.0)
        .unwrap();
    assert!(
        (r["cxx"].as_f64().unwrap() - truth.sigma_x).abs() < 0.05 * truth.sigma_x,
        "{r} vs {truth:?}"
    );

    // Outside the calibrated range: a one-line error naming the range.
    let out = std::process::Command::new(exe)
        .args([
            "predict",
            "--profile",
            &profile,
            "--focal",
            "200",
            "--aperture",
            "5.6",
            "--points",
            &pts,
            "--out",
            &pred,
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside the calibrated range"));

    // A point off the sensor is refused; one beyond the chart's coverage is predicted
    // with a warning.
    std::fs::write(&pts, "[[-5, 100]]").unwrap();
    let out = std::process::Command::new(exe)
        .args([
            "predict",
            "--profile",
            &profile,
            "--focal",
            "50",
            "--aperture",
            "5.6",
            "--points",
            &pts,
            "--out",
            &pred,
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside the profile's 960×640 sensor"));
    std::fs::write(&pts, "[[0, 0], [480, 320]]").unwrap();
    let log = run(&[
        "predict",
        "--profile",
        &profile,
        "--focal",
        "50",
        "--aperture",
        "5.6",
        "--points",
        &pts,
        "--out",
        &pred,
    ]);
    assert!(
        log.contains("1 of 2 points lie outside the area the chart covered"),
        "{log}"
    );

    // Cross-validation curves (Fig. 5) and, with a test session at novel settings, the
    // test errors (Fig. 6).
    let test = SimulatedSession {
        seed: 22,
        ..SimulatedSession::new(w, h)
    }
    .dataset(
        &VirtualLens::demo(),
        &[
            LensSetting {
                focal_mm: 35.0,
                f_number: 4.8,
            },
            LensSetting {
                focal_mm: 80.0,
                f_number: 7.1,
            },
        ],
    );
    let test_dir = dir.path().join("test");
    std::fs::create_dir_all(&test_dir).unwrap();
    let tks: Vec<String> = write_kernels_files(&test_dir, &test)
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let cvo = d("cv2.json");
    let mut args = vec![
        "crossval",
        "--csv",
        "--out",
        &cvo,
        "--global-alphas",
        "2,4",
        "--kernels",
    ];
    args.extend(ks.iter().map(String::as_str));
    args.push("--test-kernels");
    args.extend(tks.iter().map(String::as_str));
    let log = run(&args);
    eprintln!("{log}");
    assert!(
        std::fs::read_to_string(format!("{cvo}.curves.csv"))
            .unwrap()
            .lines()
            .count()
            > 4
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cvo).unwrap()).unwrap();
    let models = v["test"]["models"].as_array().unwrap();
    // The two chosen models and the paper's G_{8,1} and L_{1,1}; β = 3 needs N ≥ 4.
    assert_eq!(models.len(), 4, "{}", v["test"]);
    for m in models.iter().filter(|m| m["label"] == "chosen") {
        for k in 0..3 {
            assert!(m["p95_error_pct"][k].as_f64().unwrap() < 10.0, "{m}");
        }
    }
    assert_eq!(v["test"]["skipped"].as_array().unwrap().len(), 2);
    let test_csv = std::fs::read_to_string(format!("{cvo}.test.csv")).unwrap();
    assert_eq!(test_csv.lines().count(), 5, "{test_csv}");
    assert_eq!(
        std::fs::read_to_string(format!("{cvo}.test_cdf.csv"))
            .unwrap()
            .lines()
            .count(),
        1 + 4 * 101
    );
    let sw = d("sweeps.json");
    let mut args = vec![
        "sweeps",
        "--csv",
        "--out",
        &sw,
        "--profile",
        &profile,
        "--kernels",
    ];
    args.extend(ks.iter().map(String::as_str));
    run(&args);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&sw).unwrap()).unwrap();
    let series = v["vs_aperture"]["series"].as_array().unwrap();
    assert_eq!(series.len(), 15);
    assert!(
        series
            .iter()
            .all(|s| s["model"].as_array().unwrap().len() == 25)
    );
    assert!(
        series
            .iter()
            .any(|s| s["measured"].as_array().unwrap().len() == 3)
    );

    // A photo whose setting neither the manifest nor its EXIF knows is refused before
    // it is measured, naming it.
    let photo = dir.path().join("no_exif.png");
    image::GrayImage::from_pixel(64, 48, image::Luma([128u8]))
        .save(&photo)
        .unwrap();
    let manifest = d("manifest.json");
    std::fs::write(
        &manifest,
        r#"{"shots": [{"path": "no_exif.png", "focal_mm": 35}]}"#,
    )
    .unwrap();
    let out = std::process::Command::new(exe)
        .args(["calibrate", "--manifest", &manifest, "--out", &d("p2.json")])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        msg.contains("no_exif.png") && msg.contains("no f-number") && msg.lines().count() == 1,
        "{msg}"
    );

    // β too large for a 3 × 3 session.
    let mut args = vec![
        "calibrate",
        "--out",
        &profile,
        "--alpha",
        "2",
        "--beta",
        "3",
        "--kernels",
    ];
    args.extend(ks.iter().map(String::as_str));
    let out = std::process::Command::new(exe)
        .args(&args)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(msg.contains("N_f = 3") && msg.lines().count() == 1, "{msg}");
}

/// A small session of a lens with coma-like comet PSFs that kept its measured kernels
/// (the true pixel-level kernels plus 1 % estimation noise), and its profile with the
/// kernel-shape model chosen by cross-validation.
fn comet_session_and_profile() -> &'static (VirtualLens, Dataset, Profile) {
    static CELL: std::sync::OnceLock<(VirtualLens, Dataset, Profile)> = std::sync::OnceLock::new();
    CELL.get_or_init(|| {
        let lens = VirtualLens {
            shape: lensblur::simulate::PsfShape::Comet,
            ..VirtualLens::demo()
        };
        let ds = SimulatedSession {
            cols: 8,
            rows: 6,
            kernel_noise: Some(0.01),
            seed: 5,
            ..SimulatedSession::new(360, 240)
        }
        .dataset(&lens, &grid_settings(3, 3));
        let profile = crate::global_profile(&ds, 3, 2);
        (lens, ds, profile)
    })
}

#[test]
fn cross_validation_keeps_a_shape_model_where_kernels_are_not_gaussian() {
    let (_, ds, profile) = comet_session_and_profile();
    let cv = profile
        .shape_cv
        .as_ref()
        .expect("the session kept its kernels");
    let best = cv.best_shape.as_ref().expect("shape models were tried");
    eprintln!(
        "held-out kernels {}: Gaussian {:.4}, shapes ({} components, α {}) {:.4}",
        cv.kernels, cv.gaussian.mean_rel_l2, best.components, best.alpha, best.mean_rel_l2
    );
    assert_eq!(
        cv.kernels,
        ds.samples.len(),
        "every kernel is held out once"
    );
    assert!(cv.shape_chosen && profile.shape.is_some());
    assert!(
        best.mean_rel_l2 < 0.6 * cv.gaussian.mean_rel_l2,
        "shapes {} vs Gaussians {}",
        best.mean_rel_l2,
        cv.gaussian.mean_rel_l2
    );
    assert_eq!(cv.per_aperture.len(), 3);
    for a in &cv.per_aperture {
        assert!(
            a.shape_mean_rel_l2 < a.gaussian_mean_rel_l2,
            "f/{}",
            a.f_number
        );
    }
    // Round trip through the file: the same kernels (coefficients are stored as f32).
    let json = profile.to_json().expect("serialise");
    assert!(json.len() < 1_000_000, "{} bytes", json.len());
    let text = String::from_utf8(json).expect("utf-8");
    assert!(text.contains("\"lensblur.profile/4\""));
    let back = Profile::from_json(&text, "profile.json").expect("reads back");
    let s = LensSetting {
        focal_mm: 40.0,
        f_number: 5.0,
    };
    let model = lensblur::model::KernelModel::Shape;
    let a = profile
        .predict_kernel(model, LateralColour::Correct, Channel::B, 30.0, 200.0, s)
        .expect("predicts");
    let b = back
        .predict_kernel(model, LateralColour::Correct, Channel::B, 30.0, 200.0, s)
        .expect("predicts");
    assert!(lensblur::model::relative_l2(&b, &a) < 1e-5);
}

#[test]
fn predicted_shapes_follow_the_true_kernels_at_novel_settings() {
    let (lens, _, profile) = comet_session_and_profile();
    let (w, h) = (360, 240);
    let (mut gauss, mut placed, mut shape) = (Vec::new(), Vec::new(), Vec::new());
    for s in [
        LensSetting {
            focal_mm: 40.0,
            f_number: 4.5,
        },
        LensSetting {
            focal_mm: 90.0,
            f_number: 8.0,
        },
    ] {
        for (x, y) in [(60.0, 50.0), (300.0, 60.0), (180.0, 120.0), (70.0, 190.0)] {
            for ch in [Channel::R, Channel::G, Channel::B] {
                let (u, v) = VirtualLens::normalised(x, y, w, h);
                let truth = lens.optical_kernel_uv(ch, u, v, s, 3).pixel_integrated();
                let predict = |model| {
                    profile
                        .predict_kernel(model, LateralColour::Correct, ch, x, y, s)
                        .expect("predicts")
                };
                // The Gaussian alone, centred, as cross-validation judges the shapes
                // against; and as deblurring uses it, where the centroid model puts it.
                let g = profile.predict(ch, x, y, s).expect("predicts").kernel(3);
                let p = predict(lensblur::model::KernelModel::Gaussian);
                let k = predict(lensblur::model::KernelModel::Shape);
                assert!((k.data.iter().sum::<f64>() - 1.0).abs() < 1e-9);
                assert!(k.data.iter().all(|&v| v >= 0.0));
                gauss.push(lensblur::model::relative_l2(&g, &truth));
                placed.push(lensblur::model::relative_l2(&p, &truth));
                shape.push(lensblur::model::relative_l2(&k, &truth));
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    eprintln!(
        "relative L2 to the true kernels: Gaussians {:.4} (placed by the centroid model {:.4}), shapes {:.4}",
        mean(&gauss),
        mean(&placed),
        mean(&shape)
    );
    // The same bar as held-out kernels at calibrated settings (measured: 0.55×).
    assert!(mean(&shape) < 0.6 * mean(&gauss));
    let worse = gauss.iter().zip(&shape).filter(|(g, s)| s > g).count();
    assert_eq!(
        worse, 0,
        "a predicted shape further from the truth than its Gaussian"
    );
    // A comet's light sits off its pixel: the Gaussian placed where the kernels' light
    // was measured is closer to the truth than the centred one, and the shape closer
    // still.
    assert!(mean(&placed) < mean(&gauss));
    assert!(mean(&shape) < mean(&placed));
}

#[test]
fn a_profile_of_version_1_reads_as_one_without_a_shape_model() {
    let (_, _, profile) = comet_session_and_profile();
    let mut old = profile.clone();
    old.shape = None;
    old.shape_cv = None;
    old.place = None;
    let text = String::from_utf8(old.to_json().expect("serialise"))
        .expect("utf-8")
        .replace("lensblur.profile/4", "lensblur.profile/1");
    let p = Profile::from_json(&text, "old.json").expect("version 1 reads");
    assert!(p.shape.is_none());
    assert_eq!(p.kernel_model(), lensblur::model::KernelModel::Gaussian);
    let s = LensSetting {
        focal_mm: 40.0,
        f_number: 5.0,
    };
    assert!(matches!(
        p.predict_kernel(
            lensblur::model::KernelModel::Shape,
            LateralColour::Correct,
            Channel::G,
            10.0,
            10.0,
            s
        ),
        Err(ProfileError::NoShapeModel)
    ));
    // A damaged shape model is refused with the reason, not half-read.
    let text = String::from_utf8(profile.to_json().expect("serialise")).expect("utf-8");
    let damaged = text.replacen("\"grid_side\": 31", "\"grid_side\": 33", 1);
    let err = Profile::from_json(&damaged, "damaged.json").expect_err("refused");
    assert!(err.to_string().contains("damaged.json"), "{err}");
}

/// Issue 25, "no colour the lens did not make": on exact simulator truth (noise-free
/// kernels of a comet lens with strong lateral colour), each channel's predicted shape
/// kernel sits against green where the lens's own kernels do, over the area the chart
/// covered, between the calibrated settings. A shape model that moved the channels
/// against each other (through its components, its per-channel coefficients or the
/// clipping at zero) would put a fringe at every edge.
#[test]
fn predicted_channel_kernels_keep_the_measured_centroid_against_green() {
    let mut lens = VirtualLens {
        shape: lensblur::simulate::PsfShape::Comet,
        ..VirtualLens::demo()
    };
    // Red 0.3 px out and blue 0.3 px in at the frame's corners (half-diagonal 216 px).
    lens.geometry.lateral_colour = [1.4e-3, -1.4e-3];
    let (w, h) = (360, 240);
    let ds = SimulatedSession {
        cols: 8,
        rows: 6,
        kernel_noise: Some(0.0),
        seed: 9,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&lens, &grid_settings(3, 3));
    let profile = crate::global_profile(&ds, 3, 2);
    assert!(
        profile.shape.is_some(),
        "a comet lens keeps its shape model"
    );
    let extent = profile.norm.sampled_extent_px.expect("the chart's extent");
    // Between the calibrated settings, over the area the chart covered.
    let s = LensSetting {
        focal_mm: 52.0,
        f_number: 5.6,
    };
    let centroid = |k: &lensblur::psf::Kernel| {
        let m = k.moments();
        [m.mean_x, m.mean_y]
    };
    let worst_drift = |p: &Profile| {
        let mut worst = 0.0f64;
        for fy in [0.0, 0.5, 1.0] {
            for fx in [0.0, 0.3, 1.0] {
                let x = extent[0] + fx * (extent[2] - extent[0]);
                let y = extent[1] + fy * (extent[3] - extent[1]);
                let predicted = |ch| {
                    centroid(
                        &p.predict_kernel(
                            lensblur::model::KernelModel::Shape,
                            LateralColour::Correct,
                            ch,
                            x,
                            y,
                            s,
                        )
                        .expect("predicts"),
                    )
                };
                let truth = |ch| centroid(&lens.pixel_kernel_at(ch, x, y, (w, h), s));
                let (pg, tg) = (predicted(Channel::G), truth(Channel::G));
                for ch in [Channel::R, Channel::B] {
                    let (pc, tc) = (predicted(ch), truth(ch));
                    for axis in 0..2 {
                        let drift = (pc[axis] - pg[axis]) - (tc[axis] - tg[axis]);
                        worst = worst.max(drift.abs());
                    }
                }
            }
        }
        worst
    };
    // 0.05 px, chosen before measuring: a twentieth of a pixel between two channels is
    // about a twentieth of an edge's contrast in chroma over one pixel, well under the
    // noise a deblur leaves there.
    let drift = worst_drift(&profile);
    assert!(drift < 0.05, "relative centroid drifts {drift:.4} px");
    eprintln!("relative centroid drift: {drift:.4} px");
}

/// Issue 25, "where the profile is trusted": a profile records its preferred model's
/// held-out error per calibrated setting and zone, keeps it through its file, and
/// warns for a photo's setting beyond the shots' range but not for one among them.
#[test]
fn a_profile_records_where_it_is_trusted_and_warns_outside_it() {
    let ds = SimulatedSession {
        cols: 8,
        rows: 6,
        seed: 12,
        ..SimulatedSession::new(360, 240)
    }
    .dataset(&VirtualLens::demo(), &grid_settings(3, 3));
    let profile = crate::global_profile(&ds, 3, 2);
    let trust = profile.trust.as_ref().expect("a trust record");
    assert_eq!(trust.zones, [3, 3]);
    assert_eq!(trust.settings.len(), 9, "one entry per calibrated setting");
    assert_eq!(
        trust.settings.iter().map(|s| s.kernels).sum::<usize>(),
        ds.samples.len(),
        "every kernel held out once"
    );
    assert!(trust.mean_error_pct > 0.0 && trust.mean_error_pct < 5.0);
    // Among the shots (between them, inside their hull): nothing to say about the
    // setting (a zone's recorded error may still be above the bar; it is said so).
    let inside = LensSetting {
        focal_mm: 52.0,
        f_number: 5.6,
    };
    let about_setting = |w: &lensblur::profile::TrustWarning| {
        !matches!(w, lensblur::profile::TrustWarning::LargeError { .. })
    };
    let said = profile.trust_warnings(inside, None, None);
    assert!(!said.iter().any(about_setting), "{said:?}");
    // Beyond the longest focal length shot.
    let outside = LensSetting {
        focal_mm: 135.0,
        f_number: 5.6,
    };
    let warnings = profile.trust_warnings(outside, None, None);
    assert!(
        matches!(
            warnings.first(),
            Some(lensblur::profile::TrustWarning::OutsideRange { .. })
        ),
        "{warnings:?}"
    );
    let line = profile.trust_line(outside, None, None).expect("a warning");
    assert!(
        line.starts_with("warning: ")
            && line.contains("outside the calibrated range")
            && !line.contains('\n'),
        "{line}"
    );
    // A point the chart never reached is named.
    let corner = profile.trust_warnings(inside, None, Some((0.0, 0.0)));
    assert!(
        corner
            .iter()
            .any(|w| matches!(w, lensblur::profile::TrustWarning::OutsideChart { .. })),
        "{corner:?}"
    );
    // Through the file and back.
    let text = String::from_utf8(profile.to_json().expect("serialise")).expect("utf-8");
    let back = Profile::from_json(&text, "p.json").expect("reads back");
    let t2 = back.trust.as_ref().expect("kept");
    assert_eq!(t2.settings.len(), 9);
    assert!((t2.mean_error_pct - trust.mean_error_pct).abs() < 1e-9);
    assert_eq!(back.trust_line(outside, None, None), Some(line));
    // A damaged record is refused, naming the file.
    let damaged = text.replacen("\"zones\": [\n      3,", "\"zones\": [\n      0,", 1);
    if damaged != text {
        let err = Profile::from_json(&damaged, "damaged.json").expect_err("refused");
        assert!(err.to_string().contains("trust"), "{err}");
    }
}
