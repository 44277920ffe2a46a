//! The whole chain on the command line, against the simulator's truth: simulated
//! calibration shots → `lensblur calibrate` (detect + kernels per shot, cached) →
//! `lensblur predict` at a setting between the calibrated ones.

use lensblur::job::JobContext;
use lensblur::kernel::file::KernelsFile;
use lensblur::plane::{Channel, LensSetting};
use lensblur::session::{DemoSpec, make_demo};
use lensblur::simulate::{ShotTruth, VirtualLens};
use std::path::Path;
use std::process::Command;

fn lensblur(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(args)
        .output()
        .expect("run lensblur")
}

fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[test]
fn calibrate_on_simulated_shots_and_predict_a_novel_setting() {
    let dir = tempfile::tempdir().expect("temp dir");
    // 3 × 3 settings: enough for β = 2, the least that follows the lens's curvature in
    // f and a; small shots keep the test quick.
    let spec = DemoSpec::grid(480, 320, &[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0]);
    make_demo(dir.path(), &spec, &JobContext::silent()).expect("demo shots");
    let manifest = dir.path().join("manifest.json");
    let profile = dir.path().join("profile.json");
    let out = lensblur(&[
        "calibrate",
        "--manifest",
        manifest.to_str().expect("utf-8 path"),
        "--out",
        profile.to_str().expect("utf-8 path"),
        "--alpha",
        "2",
        "--beta",
        "2",
    ]);
    assert!(
        out.status.success(),
        "calibrate failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );

    // The kernels measured on the way (cached beside the manifest) against the truth.
    let cache = dir.path().join(lensblur::pipeline::RESULTS_DIR);
    let mut sigma_err = Vec::new();
    let mut rho_err = Vec::new();
    for setting in &spec.settings {
        let name = DemoSpec::shot_name(*setting);
        let truth: ShotTruth = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(format!("{name}.truth.json"))).expect("truth"),
        )
        .expect("truth json");
        let cached = std::fs::read_dir(&cache)
            .expect("cache")
            .filter_map(Result::ok)
            .map(|e| e.path())
            .find(|p| {
                KernelsFile::load(p).is_ok_and(|k| {
                    k.focal_mm == Some(setting.focal_mm) && k.f_number == Some(setting.f_number)
                })
            })
            .expect("kernels of the shot cached");
        let k = KernelsFile::load(&cached).expect("kernels file");
        for s in &k.samples {
            let sq = truth
                .squares
                .iter()
                .find(|t| Some(t.row) == s.row && Some(t.col) == s.col)
                .expect("square in truth");
            let g = sq.pixel_of(s.channel).expect("channel in truth");
            sigma_err.push((s.cxx.expect("cxx") / g.sigma_x - 1.0).abs());
            sigma_err.push((s.cyy.expect("cyy") / g.sigma_y - 1.0).abs());
            rho_err.push((s.cor.expect("cor") - g.rho).abs());
        }
    }
    let (s50, s95) = (
        percentile(sigma_err.clone(), 0.5),
        percentile(sigma_err, 0.95),
    );
    let (r50, r95) = (percentile(rho_err.clone(), 0.5), percentile(rho_err, 0.95));
    eprintln!("σ rel error median {s50:.4} p95 {s95:.4}; ρ error median {r50:.4} p95 {r95:.4}");
    assert!(s50 <= 0.02 && s95 <= 0.06, "σ: median {s50}, p95 {s95}");
    assert!(r50 <= 0.02 && r95 <= 0.06, "ρ: median {r50}, p95 {r95}");

    // Predict between the calibrated settings and compare with the lens itself.
    let (w, h) = (spec.width, spec.height);
    let mut pts = Vec::new();
    for j in 0..5 {
        for i in 0..7 {
            pts.push([
                40.0 + i as f64 * (w as f64 - 80.0) / 6.0,
                40.0 + j as f64 * (h as f64 - 80.0) / 4.0,
            ]);
        }
    }
    let points = dir.path().join("points.json");
    std::fs::write(&points, serde_json::to_vec(&pts).expect("json")).expect("write points");
    let novel = LensSetting {
        focal_mm: 35.0,
        f_number: 4.8,
    };
    let pred_path = dir.path().join("pred.json");
    let out = lensblur(&[
        "predict",
        "--profile",
        profile.to_str().expect("utf-8"),
        "--focal",
        "35",
        "--aperture",
        "4.8",
        "--points",
        points.to_str().expect("utf-8"),
        "--out",
        pred_path.to_str().expect("utf-8"),
    ]);
    assert!(
        out.status.success(),
        "predict failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pred: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&pred_path).expect("pred")).expect("json");
    let lens = VirtualLens::demo();
    // Error as % of the parameter's range over the calibrated field (the paper's measure).
    let truth_at = |ch: Channel, x: f64, y: f64, s: LensSetting| {
        lens.gaussian_at(ch, x, y, w, h, s)
            .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
    };
    let mut all = [Vec::new(), Vec::new(), Vec::new()];
    for s in &spec.settings {
        for p in &pts {
            let g = truth_at(Channel::G, p[0], p[1], *s);
            all[0].push(g.sigma_x);
            all[1].push(g.sigma_y);
            all[2].push(g.rho);
        }
    }
    let range: Vec<f64> = all
        .iter()
        .map(|v| percentile(v.clone(), 0.995) - percentile(v.clone(), 0.005))
        .collect();
    let mut errs = [Vec::new(), Vec::new(), Vec::new()];
    let samples = pred["samples"].as_array().expect("samples");
    assert!(!samples.is_empty());
    for s in samples {
        let ch: Channel = serde_json::from_value(s["channel"].clone()).expect("channel");
        let (x, y) = (s["x"].as_f64().expect("x"), s["y"].as_f64().expect("y"));
        let g = truth_at(ch, x, y, novel);
        let got = [
            s["cxx"].as_f64().expect("cxx"),
            s["cyy"].as_f64().expect("cyy"),
            s["cor"].as_f64().expect("cor"),
        ];
        let want = [g.sigma_x, g.sigma_y, g.rho];
        for k in 0..3 {
            errs[k].push(100.0 * (got[k] - want[k]).abs() / range[k]);
        }
    }
    for (k, name) in ["C_xx", "C_yy", "C_or"].iter().enumerate() {
        let p95 = percentile(errs[k].clone(), 0.95);
        eprintln!("{name}: p95 error at the novel setting {p95:.2} % of range");
        assert!(p95 < 10.0, "{name}: p95 {p95} % of range");
    }
    assert!(Path::new(&profile).is_file());
}
