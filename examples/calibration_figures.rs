//! The blur-model figures on the real chain: simulated calibration shots → detection →
//! kernels → robust Gaussians → cross-validated models → errors at novel settings.
//!
//! ```sh
//! cargo run --release --example calibration_figures -- --out target/figures
//! ```
//!
//! By default: the demo lens, 2400 × 1600 Bayer shots of the 24 × 16 chart at the
//! paper's 5 × 5 settings (24, 44, 65, 85, 105 mm × f/4, 5, 6.3, 8, 10), two shots
//! each, and one test shot at each of 16 novel settings between them (34, 54.5, 75,
//! 95 mm × f/4.5, 5.6, 7.1, 9). It prints and writes to `OUT/figures.json`:
//! - the measured Gaussians' error against the simulator's truth (σ relative, ρ
//!   absolute), how much of it is shared within a shot, and how it correlates between
//!   neighbouring squares;
//! - the cross-validation curves over α and β (Fig. 5, also `OUT/cv.json.curves.csv`),
//!   the chosen models, and the mean CV error of L_{1,3} and G_{8,3};
//! - each model's error at the novel settings against the measured Gaussians (the
//!   paper's measure, Fig. 6, `OUT/cv.json.test_cdf.csv`) and against the truth, with
//!   the 95th percentiles the bar is set on (< 10 % of range);
//! - profile sizes, and the calibration wall time of the 50-shot set (detect + kernels
//!   per shot, then cross-validation and fits).
//!
//! Measured kernels and the shots' truth are kept in `OUT/kernels/` and reused by a
//! re-run (delete the folder to measure again). `--save-shots` also writes the shots as
//! DNGs with manifests, so the command line can be timed on the same set:
//! `lensblur calibrate --manifest OUT/shots/calibration.json --out profile.json`.
//! A quick proof run: `--width 600 --height 400 --cols 12 --rows 8 --shots-per-setting 1`.

use anyhow::{Context, Result};
use clap::Parser;
use lensblur::calibrate::{CalibrateOptions, calibrate};
use lensblur::chart::ChartSpec;
use lensblur::crossval::{
    CvOptions, CvReport, Ranges, TestReport, cross_validate_fixed, evaluate_test_set,
    paper_test_models, percentile_sorted,
};
use lensblur::job::JobContext;
use lensblur::kernel::KernelParams;
use lensblur::kernel::file::KernelsFile;
use lensblur::model::{BlurSample, Dataset, GlobalModel, LocalModel, LocalOptions, ModelKind};
use lensblur::pipeline;
use lensblur::plane::LensSetting;
use lensblur::profile::Profile;
use lensblur::simulate::{CaptureParams, Pose, ShotTruth, VirtualLens, simulate_shot};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Parser)]
struct Args {
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 2400)]
    width: usize,
    #[arg(long, default_value_t = 1600)]
    height: usize,
    #[arg(long, default_value_t = 2)]
    shots_per_setting: usize,
    /// Chart squares across and down (the figures use the default 24 × 16; a smaller
    /// chart keeps squares measurable on small proof-run shots).
    #[arg(long, default_value_t = 24)]
    cols: usize,
    #[arg(long, default_value_t = 16)]
    rows: usize,
    /// Three full colour planes instead of a Bayer mosaic.
    #[arg(long)]
    rgb: bool,
    /// Also write the (Bayer) shots as DNGs with calibration and test manifests.
    #[arg(long)]
    save_shots: bool,
    #[arg(long, default_value_t = 11)]
    seed: u64,
}

const CAL_FOCAL_MM: [f64; 5] = [24.0, 44.0, 65.0, 85.0, 105.0];
const CAL_F_NUMBER: [f64; 5] = [4.0, 5.0, 6.3, 8.0, 10.0];
const TEST_FOCAL_MM: [f64; 4] = [34.0, 54.5, 75.0, 95.0];
const TEST_F_NUMBER: [f64; 4] = [4.5, 5.6, 7.1, 9.0];

fn grid(fs: &[f64], as_: &[f64]) -> Vec<LensSetting> {
    fs.iter()
        .flat_map(|&f| {
            as_.iter().map(move |&a| LensSetting {
                focal_mm: f,
                f_number: a,
            })
        })
        .collect()
}

/// One shot to simulate and measure.
struct ShotPlan {
    name: String,
    setting: LensSetting,
    index: u64,
}

/// What measuring one shot cost.
#[derive(Default, Serialize, Clone, Copy)]
struct ShotTimes {
    simulate_s: f64,
    detect_s: f64,
    kernels_s: f64,
}

/// Simulates and measures a shot, or takes both from `dir` when a previous run left
/// them there.
fn measure(
    plan: &ShotPlan,
    args: &Args,
    chart: &ChartSpec,
    lens: &VirtualLens,
    dir: &Path,
) -> Result<(KernelsFile, ShotTruth, Option<ShotTimes>)> {
    let kernels_path = dir.join(format!("{}.kernels.json", plan.name));
    let truth_path = dir.join(format!("{}.truth.json", plan.name));
    if kernels_path.is_file() && truth_path.is_file() {
        let k = KernelsFile::load(&kernels_path)?;
        let t: ShotTruth = serde_json::from_slice(&std::fs::read(&truth_path)?)
            .with_context(|| truth_path.display().to_string())?;
        return Ok((k, t, None));
    }
    let job = JobContext::silent();
    let t0 = Instant::now();
    let mut params = CaptureParams::new(args.width, args.height, plan.setting);
    // A hand-held series: each shot posed a little differently, as in the demo session.
    let t = plan.index as f64;
    params.pose = Pose {
        rotation_deg: 1.5 * (0.9 * t + 0.3).sin(),
        tilt_x: 0.02 * (1.3 * t).cos(),
        tilt_y: 0.015 * (0.7 * t + 1.0).sin(),
        fill: 0.86,
        shift_px: [
            0.002 * args.width as f64 * (t * 0.5).sin(),
            0.002 * args.width as f64 * (t * 0.8).cos(),
        ],
    };
    params.bayer = !args.rgb;
    params.seed = args.seed.wrapping_mul(1000).wrapping_add(plan.index);
    let shot = simulate_shot(chart, lens, &params, &job)?;
    let simulate_s = t0.elapsed().as_secs_f64();
    if args.save_shots && !args.rgb {
        let shots = args.out.join("shots");
        std::fs::create_dir_all(&shots)?;
        let info = lensblur::dng::DngInfo::simulated(
            &lens.make,
            &lens.model,
            params.black_level,
            params.white_level,
            Some(plan.setting),
            lensblur::dng::DngLayout::default(),
        );
        lensblur::dng::write_dng(
            &shots.join(format!("{}.dng", plan.name)),
            &shot.cfa,
            args.width,
            args.height,
            &info,
        )?;
    }
    // The shot is measured in memory through the same pipeline as every front end.
    let m = pipeline::Measurement::new(chart.clone(), KernelParams::default());
    let name = Path::new(&plan.name);
    let t1 = Instant::now();
    let det = pipeline::detect(&shot.capture, name, &m, &job)?;
    let detect_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let given = pipeline::GivenSetting {
        focal_mm: Some(plan.setting.focal_mm),
        f_number: Some(plan.setting.f_number),
    };
    let file = pipeline::estimate(&shot.capture, &det, name, given, &m, false, &job)?;
    let kernels_s = t2.elapsed().as_secs_f64();
    lensblur::io::write_json(&kernels_path, &file)?;
    lensblur::io::write_json(&truth_path, &shot.truth)?;
    Ok((
        file,
        shot.truth,
        Some(ShotTimes {
            simulate_s,
            detect_s,
            kernels_s,
        }),
    ))
}

/// Measured shots as a dataset, and the same squares with the truth's Gaussians.
fn datasets(shots: &[(String, KernelsFile, ShotTruth)]) -> Result<(Dataset, Dataset)> {
    let first = &shots.first().context("no shots")?.1;
    let identity = first.identity.clone().unwrap_or_default();
    let mut measured = Dataset::new(first.width, first.height, identity.clone());
    let mut truth = Dataset::new(first.width, first.height, identity);
    for (name, k, t) in shots {
        let info = lensblur::model::ShotInfo {
            name: name.clone(),
            focal_mm: t.setting.focal_mm,
            f_number: t.setting.f_number,
            focus_distance_m: k.focus_distance_m,
        };
        let mut meas = Vec::new();
        let mut tru = Vec::new();
        for s in &k.samples {
            let (Some(cxx), Some(cyy), Some(cor), Some(row), Some(col)) =
                (s.cxx, s.cyy, s.cor, s.row, s.col)
            else {
                continue;
            };
            let Some(g) = t
                .squares
                .iter()
                .find(|q| q.row == row && q.col == col)
                .and_then(|q| q.pixel_of(s.channel))
            else {
                continue;
            };
            let sample = |gaussian| BlurSample {
                shot: 0,
                x: s.x,
                y: s.y,
                square: Some([row, col]),
                focal_mm: 0.0,
                f_number: 0.0,
                channel: s.channel,
                gaussian,
                kernel: None,
            };
            meas.push(sample(lensblur::psf::Gaussian2 {
                sigma_x: cxx,
                sigma_y: cyy,
                rho: cor,
            }));
            tru.push(sample(g));
        }
        measured.push_shot(info.clone(), meas);
        truth.push_shot(info, tru);
    }
    Ok((measured, truth))
}

/// How the measured Gaussians differ from the truth.
#[derive(Serialize)]
struct MeasurementError {
    samples: usize,
    sigma_rel_median: f64,
    sigma_rel_p95: f64,
    rho_abs_median: f64,
    rho_abs_p95: f64,
    /// RMS over shots of a shot's mean relative σ error: the part shared by a shot.
    per_shot_mean_sigma_rel_rms: f64,
    /// Correlation of relative σ errors of horizontally neighbouring squares (same
    /// shot and channel).
    neighbour_sigma_correlation: f64,
    /// Mean relative σ error: a bias of the estimator.
    sigma_rel_mean: f64,
}

fn measurement_error(measured: &Dataset, truth: &Dataset) -> MeasurementError {
    let mut sigma = Vec::new();
    let mut signed = Vec::new();
    let mut rho = Vec::new();
    let mut per_shot = vec![(0.0, 0usize); measured.shots.len()];
    let mut by_square = std::collections::BTreeMap::new();
    for (m, t) in measured.samples.iter().zip(&truth.samples) {
        for (a, b) in [
            (m.gaussian.sigma_x, t.gaussian.sigma_x),
            (m.gaussian.sigma_y, t.gaussian.sigma_y),
        ] {
            let e = a / b - 1.0;
            sigma.push(e.abs());
            signed.push(e);
            per_shot[m.shot].0 += e;
            per_shot[m.shot].1 += 1;
        }
        rho.push((m.gaussian.rho - t.gaussian.rho).abs());
        if let Some(sq) = m.square {
            by_square.insert(
                (m.shot, m.channel, sq),
                m.gaussian.sigma_x / t.gaussian.sigma_x - 1.0,
            );
        }
    }
    let pairs: Vec<(f64, f64)> = by_square
        .iter()
        .filter_map(|(&(shot, ch, [r, c]), &e)| {
            by_square.get(&(shot, ch, [r, c + 1])).map(|&f| (e, f))
        })
        .collect();
    let correlation = {
        let n = pairs.len() as f64;
        let (ma, mb) = (
            pairs.iter().map(|p| p.0).sum::<f64>() / n,
            pairs.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
        let va: f64 = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum();
        let vb: f64 = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum();
        cov / (va * vb).sqrt()
    };
    let shot_means: Vec<f64> = per_shot
        .iter()
        .filter(|p| p.1 > 0)
        .map(|p| p.0 / p.1 as f64)
        .collect();
    sigma.sort_by(f64::total_cmp);
    rho.sort_by(f64::total_cmp);
    MeasurementError {
        samples: measured.samples.len(),
        sigma_rel_median: percentile_sorted(&sigma, 50.0),
        sigma_rel_p95: percentile_sorted(&sigma, 95.0),
        rho_abs_median: percentile_sorted(&rho, 50.0),
        rho_abs_p95: percentile_sorted(&rho, 95.0),
        per_shot_mean_sigma_rel_rms: (shot_means.iter().map(|m| m * m).sum::<f64>()
            / shot_means.len().max(1) as f64)
            .sqrt(),
        neighbour_sigma_correlation: correlation,
        sigma_rel_mean: signed.iter().sum::<f64>() / signed.len().max(1) as f64,
    }
}

#[derive(Serialize)]
struct Timings {
    /// Per calibration shot, as measured this run (absent for shots reused from disk).
    simulate_s_per_shot: Option<f64>,
    detect_s_per_shot: Option<f64>,
    kernels_s_per_shot: Option<f64>,
    /// Detection and kernels of the whole calibration set (shots measured this run
    /// only, scaled to the set).
    measure_s: Option<f64>,
    /// `calibrate`: cross-validation of both families and the final fits.
    models_s: f64,
    /// What `lensblur calibrate` on the set would take: measure + models.
    calibration_total_s: Option<f64>,
}

#[derive(Serialize)]
struct ProfileSizes {
    chosen_both_bytes: usize,
    global_g83_bytes: usize,
    local_l13_bytes: usize,
}

#[derive(Serialize)]
struct BarP95 {
    model: String,
    vs_measured: bool,
    vs_truth: bool,
}

#[derive(Serialize)]
struct Figures {
    width: usize,
    height: usize,
    calibration_shots: usize,
    test_shots: usize,
    measurement_error_calibration: MeasurementError,
    measurement_error_test: MeasurementError,
    ranges: Ranges,
    cv: CvReport,
    cv_l13_mean_pct: Option<[f64; 4]>,
    cv_g83_mean_pct: Option<[f64; 4]>,
    test_vs_measured: TestReport,
    test_vs_truth: TestReport,
    profile_sizes: ProfileSizes,
    timings: Timings,
    /// Per model, every parameter: p95 error at the novel settings < 10 % of range,
    /// against the measured Gaussians and against the truth.
    bar_p95_below_10_pct: Vec<BarP95>,
    /// The family CV prefers, at its chosen (α, β), against G_{8,3} and L_{1,3} on the
    /// test set (mean error against the truth).
    chosen_no_worse_than_g83_l13: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let chart = ChartSpec {
        cols: args.cols,
        rows: args.rows,
        ..ChartSpec::default()
    };
    let lens = VirtualLens::demo();
    let kernels_dir = args.out.join("kernels");
    std::fs::create_dir_all(&kernels_dir)
        .with_context(|| format!("{}: cannot create", kernels_dir.display()))?;

    let mut plans = Vec::new();
    for s in grid(&CAL_FOCAL_MM, &CAL_F_NUMBER) {
        for rep in 0..args.shots_per_setting {
            plans.push(ShotPlan {
                name: format!("cal_f{:05.1}_a{:04.1}_{rep}", s.focal_mm, s.f_number),
                setting: s,
                index: plans.len() as u64,
            });
        }
    }
    let n_cal = plans.len();
    for s in grid(&TEST_FOCAL_MM, &TEST_F_NUMBER) {
        plans.push(ShotPlan {
            name: format!("test_f{:05.1}_a{:04.1}", s.focal_mm, s.f_number),
            setting: s,
            index: plans.len() as u64,
        });
    }

    let mut measured = Vec::new();
    let mut times = Vec::new();
    for (i, plan) in plans.iter().enumerate() {
        let (k, t, time) = measure(plan, &args, &chart, &lens, &kernels_dir)?;
        match time {
            Some(tm) => eprintln!(
                "[{}/{}] {}: {} samples; simulate {:.1} s, detect {:.1} s, kernels {:.1} s",
                i + 1,
                plans.len(),
                plan.name,
                k.samples.len(),
                tm.simulate_s,
                tm.detect_s,
                tm.kernels_s
            ),
            None => eprintln!(
                "[{}/{}] {}: {} samples (from a previous run)",
                i + 1,
                plans.len(),
                plan.name,
                k.samples.len()
            ),
        }
        if i < n_cal
            && let Some(tm) = time
        {
            times.push(tm);
        }
        measured.push((plan.name.clone(), k, t));
    }
    if args.save_shots {
        write_manifests(&args.out.join("shots"), &chart, &plans, n_cal)?;
    }
    let (cal, cal_truth) = datasets(&measured[..n_cal])?;
    let (test, test_truth) = datasets(&measured[n_cal..])?;
    let err_cal = measurement_error(&cal, &cal_truth);
    let err_test = measurement_error(&test, &test_truth);
    eprintln!(
        "measured vs truth: σ relative error median {:.4}, p95 {:.4} (mean {:+.4}); ρ error median {:.4}, p95 {:.4}; per-shot share RMS {:.4}; neighbour correlation {:.2}",
        err_cal.sigma_rel_median,
        err_cal.sigma_rel_p95,
        err_cal.sigma_rel_mean,
        err_cal.rho_abs_median,
        err_cal.rho_abs_p95,
        err_cal.per_shot_mean_sigma_rel_rms,
        err_cal.neighbour_sigma_correlation
    );

    // What `lensblur calibrate` does after measuring: cross-validated selection of both
    // families, final fits, the profile.
    let t0 = Instant::now();
    let (profile, report) = calibrate(
        &cal,
        Some(chart.clone()),
        &CalibrateOptions::default(),
        &JobContext::silent(),
    )?;
    let models_s = t0.elapsed().as_secs_f64();
    let mut report = report.context("calibration ran no cross-validation")?;
    let ranges = report.ranges;
    for s in [&report.global, &report.local].into_iter().flatten() {
        for p in s.alpha_curve.iter().chain(&s.beta_curve) {
            eprintln!(
                "CV {:?} α = {}, β = {} ({} terms): mean {:.2} % (C_xx {:.2}, C_yy {:.2}, C_or {:.2})",
                s.kind,
                p.alpha,
                p.beta,
                p.terms,
                p.mean_pct,
                p.mean_error_pct[0],
                p.mean_error_pct[1],
                p.mean_error_pct[2]
            );
        }
        eprintln!(
            "CV chose {:?} α = {}, β = {}: mean {:.2} %",
            s.kind, s.alpha, s.beta, s.chosen.mean_pct
        );
    }
    let fixed_cv = |kind, a, b| {
        cross_validate_fixed(&cal, kind, a, b, &CvOptions::default())
            .ok()
            .map(|(p, _)| {
                [
                    p.mean_pct,
                    p.mean_error_pct[0],
                    p.mean_error_pct[1],
                    p.mean_error_pct[2],
                ]
            })
    };
    let cv_l13 = fixed_cv(ModelKind::Local, 1, 3);
    let cv_g83 = fixed_cv(ModelKind::Global, 8, 3);
    eprintln!(
        "mean CV error (all, C_xx, C_yy, C_or): L_{{1,3}} {cv_l13:.2?} (paper 3.6/3.7/3.4 and 4.0/3.5/3.7 %), G_{{8,3}} {cv_g83:.2?}"
    );

    let models = paper_test_models(Some(&report));
    let local = LocalOptions::default();
    let vs_measured = evaluate_test_set(&cal, &test, &models, &local, &ranges)?;
    let vs_truth = evaluate_test_set(&cal, &test_truth, &models, &local, &ranges)?;
    for (m, t) in vs_measured.models.iter().zip(&vs_truth.models) {
        eprintln!(
            "test {} {:?} α = {}, β = {}: p95 vs measured C_xx {:.2} C_yy {:.2} C_or {:.2} %, mean {:.2} %; vs truth p95 {:.2} {:.2} {:.2} %, mean {:.2} %",
            m.label,
            m.kind,
            m.alpha,
            m.beta,
            m.p95_error_pct[0],
            m.p95_error_pct[1],
            m.p95_error_pct[2],
            m.mean_pct,
            t.p95_error_pct[0],
            t.p95_error_pct[1],
            t.p95_error_pct[2],
            t.mean_pct
        );
    }
    let bar_p95: Vec<BarP95> = vs_measured
        .models
        .iter()
        .zip(&vs_truth.models)
        .map(|(m, t)| BarP95 {
            model: format!(
                "{} {}_{{{},{}}}",
                m.label,
                if m.kind == ModelKind::Global {
                    "G"
                } else {
                    "L"
                },
                m.alpha,
                m.beta
            ),
            vs_measured: m.p95_error_pct.iter().all(|&e| e < 10.0),
            vs_truth: t.p95_error_pct.iter().all(|&e| e < 10.0),
        })
        .collect();
    let best = report.best();
    let mean_of = |kind: ModelKind, a: usize, b: usize, label: &str| {
        vs_truth
            .models
            .iter()
            .find(|m| m.kind == kind && m.alpha == a && m.beta == b && m.label == label)
            .map(|m| m.mean_pct)
    };
    let no_worse = match best {
        Some((kind, a, b)) => {
            let chosen = mean_of(kind, a, b, "chosen");
            let g83 = mean_of(ModelKind::Global, 8, 3, "fixed");
            let l13 = mean_of(ModelKind::Local, 1, 3, "fixed");
            matches!((chosen, g83, l13), (Some(c), Some(g), Some(l)) if c <= g && c <= l)
        }
        None => false,
    };

    // Profile sizes: as calibrated (both families), and the paper's two models alone.
    let size = |p: &Profile| p.to_json().map(|j| j.len()).unwrap_or(0);
    let alone = |global: Option<GlobalModel>, local: Option<LocalModel>, kind| {
        Profile::new(
            cal.identity.clone(),
            Some(chart.clone()),
            profile.calibrated_settings.clone(),
            global,
            local,
            profile.cv.clone(),
            kind,
        )
        .map(|p| size(&p))
        .unwrap_or(0)
    };
    let sizes = ProfileSizes {
        chosen_both_bytes: size(&profile),
        global_g83_bytes: alone(Some(GlobalModel::fit(&cal, 8, 3)?), None, ModelKind::Global),
        local_l13_bytes: alone(
            None,
            Some(LocalModel::fit(&cal, 1, 3, &local)?),
            ModelKind::Local,
        ),
    };
    profile.save(&args.out.join("profile.json"))?;

    let avg = |f: fn(&ShotTimes) -> f64| {
        (!times.is_empty()).then(|| times.iter().map(f).sum::<f64>() / times.len() as f64)
    };
    let measure_s = avg(|t| t.detect_s + t.kernels_s).map(|s| s * n_cal as f64);
    let timings = Timings {
        simulate_s_per_shot: avg(|t| t.simulate_s),
        detect_s_per_shot: avg(|t| t.detect_s),
        kernels_s_per_shot: avg(|t| t.kernels_s),
        measure_s,
        models_s,
        calibration_total_s: measure_s.map(|m| m + models_s),
    };
    eprintln!(
        "profile sizes: as calibrated {} B, G_{{8,3}} alone {} B, L_{{1,3}} alone {} B",
        sizes.chosen_both_bytes, sizes.global_g83_bytes, sizes.local_l13_bytes
    );
    match (timings.measure_s, timings.calibration_total_s) {
        (Some(m), Some(t)) => eprintln!(
            "calibration of {n_cal} shots: detect + kernels {m:.1} s, models {models_s:.1} s, total {t:.1} s"
        ),
        _ => eprintln!(
            "calibration of {n_cal} shots: models {models_s:.1} s (shots measured by an earlier run: delete OUT/kernels to time them)"
        ),
    }
    for b in &bar_p95 {
        eprintln!(
            "bar p95 < 10 % of range, every parameter, {}: vs measured {}, vs truth {}",
            b.model, b.vs_measured, b.vs_truth
        );
    }
    eprintln!(
        "bar: the CV choice no worse than G_{{8,3}} and L_{{1,3}} (mean error vs truth): {no_worse}"
    );

    report.test = Some(vs_measured.clone());
    let cv_path = args.out.join("cv.json");
    lensblur::io::write_json(&cv_path, &report)?;
    write_csv(&cv_path, &report)?;
    let figures = Figures {
        width: args.width,
        height: args.height,
        calibration_shots: n_cal,
        test_shots: plans.len() - n_cal,
        measurement_error_calibration: err_cal,
        measurement_error_test: err_test,
        ranges,
        cv: report,
        cv_l13_mean_pct: cv_l13,
        cv_g83_mean_pct: cv_g83,
        test_vs_measured: vs_measured,
        test_vs_truth: vs_truth,
        profile_sizes: sizes,
        timings,
        bar_p95_below_10_pct: bar_p95,
        chosen_no_worse_than_g83_l13: no_worse,
    };
    let path = args.out.join("figures.json");
    lensblur::io::write_json(&path, &figures)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// Manifests of the saved DNG shots: the calibration set and the test set.
fn write_manifests(dir: &Path, chart: &ChartSpec, plans: &[ShotPlan], n_cal: usize) -> Result<()> {
    use lensblur::manifest::{ChartRef, Manifest, ManifestShot};
    let manifest = |plans: &[ShotPlan]| {
        Manifest::new(
            Some(ChartRef::Spec(chart.clone())),
            plans
                .iter()
                .map(|p| ManifestShot {
                    path: PathBuf::from(format!("{}.dng", p.name)),
                    focal_mm: Some(p.setting.focal_mm),
                    f_number: Some(p.setting.f_number),
                })
                .collect(),
        )
    };
    manifest(&plans[..n_cal]).save(&dir.join("calibration.json"))?;
    manifest(&plans[n_cal..]).save(&dir.join("test.json"))?;
    Ok(())
}

/// The Fig. 5 curves and Fig. 6 distributions as CSV beside `cv.json`.
fn write_csv(cv_path: &Path, report: &CvReport) -> Result<()> {
    use std::fmt::Write as _;
    let mut curves = String::from(
        "model,stage,alpha,beta,terms,mean_pct,cxx_mean_pct,cyy_mean_pct,cor_mean_pct\n",
    );
    for s in [&report.global, &report.local].into_iter().flatten() {
        for (stage, curve) in [("alpha", &s.alpha_curve), ("beta", &s.beta_curve)] {
            for p in curve {
                writeln!(
                    curves,
                    "{:?},{stage},{},{},{},{:.4},{:.4},{:.4},{:.4}",
                    s.kind,
                    p.alpha,
                    p.beta,
                    p.terms,
                    p.mean_pct,
                    p.mean_error_pct[0],
                    p.mean_error_pct[1],
                    p.mean_error_pct[2]
                )?;
            }
        }
    }
    let mut cdf = String::from("model,label,alpha,beta,percentile,cxx_pct,cyy_pct,cor_pct\n");
    if let Some(t) = &report.test {
        for m in &t.models {
            let c = &m.error_cdf;
            for i in 0..c.percentiles.len() {
                writeln!(
                    cdf,
                    "{:?},{},{},{},{},{:.4},{:.4},{:.4}",
                    m.kind,
                    m.label,
                    m.alpha,
                    m.beta,
                    c.percentiles[i],
                    c.cxx[i],
                    c.cyy[i],
                    c.cor[i]
                )?;
            }
        }
    }
    let with = |suffix: &str| {
        let mut s = cv_path.as_os_str().to_owned();
        s.push(suffix);
        PathBuf::from(s)
    };
    std::fs::write(with(".curves.csv"), curves)?;
    std::fs::write(with(".test_cdf.csv"), cdf)?;
    Ok(())
}
