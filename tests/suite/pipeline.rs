//! The whole chain on the command line, against the simulator's truth: simulated
//! calibration shots → `lensblur calibrate` (detect + kernels per shot, cached) →
//! `lensblur predict` at a setting between the calibrated ones (points, and a grid as
//! CSV with MTF50), and the same calibration fanned out as a batch system runs it
//! (`scripts/slurm_kernels.sh`: `lensblur kernels` per shot, then `calibrate
//! --kernels`).

use lensblur::job::JobContext;
use lensblur::kernel::file::KernelsFile;
use lensblur::plane::{Channel, LensSetting};
use lensblur::simulate::demo::{DemoSpec, make_demo};
use lensblur::simulate::{ShotTruth, VirtualLens};
use std::path::Path;
use std::process::Command;

fn lensblur(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(args)
        .output()
        .expect("run lensblur")
}

use super::positions::percentile;

#[test]
fn calibrate_on_simulated_shots_and_predict_a_novel_setting() {
    let dir = tempfile::tempdir().expect("temp dir");
    // 3 × 3 settings: enough for β = 2, the least that follows the lens's curvature in
    // f and a; small shots keep the test quick.
    let spec = DemoSpec::grid(480, 320, &[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0]);
    make_demo(dir.path(), &spec, &JobContext::silent()).expect("demo shots");
    let manifest = dir.path().join("manifest.json");
    let profile = dir.path().join("profile.json");
    super::positions::calibrate(dir.path());

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
        let cached = cached_kernels_at(&cache, *setting);
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
    let novel = LensSetting {
        focal_mm: 35.0,
        f_number: 4.8,
    };
    let p95 = super::positions::prediction_p95(dir.path(), &spec, novel);
    for (name, p95) in ["C_xx", "C_yy", "C_or"].iter().zip(p95) {
        eprintln!("{name}: p95 error at the novel setting {p95:.2} % of range");
        assert!(p95 < 10.0, "{name}: p95 {p95} % of range");
    }
    assert!(Path::new(&profile).is_file());

    predicted_grid_as_csv(dir.path(), &profile, &spec, novel);
    sharpness_maps_against_the_truth(dir.path(), &profile, &spec, novel);
    fanned_out_like_a_batch_system(dir.path(), &manifest, &profile);
}

/// `predict --grid NX,NY --csv`: one row per channel and cell centre; each row's MTF50
/// is the closed form of its own Gaussian and matches the JSON's, and against the
/// lens's truth it is as close as the σs are.
fn predicted_grid_as_csv(dir: &Path, profile: &Path, spec: &DemoSpec, novel: LensSetting) {
    let pred = dir.join("grid.json");
    let out = lensblur(&[
        "predict",
        "--profile",
        profile.to_str().expect("utf-8"),
        "--focal",
        "35",
        "--aperture",
        "4.8",
        "--grid",
        "6,4",
        "--out",
        pred.to_str().expect("utf-8"),
        "--csv",
    ]);
    assert!(
        out.status.success(),
        "predict --grid failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&pred).expect("pred")).expect("json");
    let samples = json["samples"].as_array().expect("samples");
    let csv = std::fs::read_to_string(dir.join("grid.json.csv")).expect("csv beside --out");
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("x,y,channel,cxx,cyy,cor,sigma,mtf50,mtf50_best,mtf50_isotropic,mtf50_lp_ph")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 6 * 4 * 3, "6 × 4 points × R, G, B");
    assert_eq!(rows.len(), samples.len());
    let (w, h) = (spec.width as f64, spec.height as f64);
    let lens = VirtualLens::demo();
    let mut err = Vec::new();
    for (row, s) in rows.iter().zip(samples) {
        let num = |i: usize| row[i].parse::<f64>().expect("a number");
        let g = lensblur::psf::Gaussian2 {
            sigma_x: num(3),
            sigma_y: num(4),
            rho: num(5),
        };
        let m = g.mtf50().expect("mtf50");
        assert!((num(6) - g.sigma()).abs() < 1e-4, "{row:?}");
        assert!((num(7) - m.worst).abs() < 1e-4, "{row:?}");
        assert!((num(8) - m.best).abs() < 1e-4 && (num(9) - m.isotropic).abs() < 1e-4);
        assert!(
            (num(10) - m.worst * h).abs() < 0.1,
            "lp/ph is cycles/px × {h} px"
        );
        assert!((s["mtf50"]["worst"].as_f64().expect("mtf50 in JSON") - num(7)).abs() < 1e-5);
        // Cell centres of a 6 × 4 grid over the sensor.
        let (x, y) = (num(0), num(1));
        let (i, j) = (x / (w - 1.0) * 6.0 - 0.5, y / (h - 1.0) * 4.0 - 0.5);
        assert!(
            (i - i.round()).abs() < 1e-3 && (j - j.round()).abs() < 1e-3,
            "{x}, {y}"
        );
        let ch: Channel = row[2].parse().expect("channel");
        let truth = lens
            .gaussian_at(ch, x, y, spec.width, spec.height, novel)
            .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
        err.push((m.worst / truth.mtf50().expect("truth").worst - 1.0).abs());
    }
    let (e50, e95) = (percentile(err.clone(), 0.5), percentile(err, 0.95));
    eprintln!(
        "predicted MTF50 (worst direction) against the truth at the novel setting: median {:.2} %, p95 {:.2} %",
        100.0 * e50,
        100.0 * e95
    );
    assert!(e50 <= 0.03 && e95 <= 0.08, "median {e50}, p95 {e95}");
}

/// The kernels file `calibrate --manifest` cached for the shot at `setting`.
fn cached_kernels_at(cache: &Path, setting: LensSetting) -> std::path::PathBuf {
    std::fs::read_dir(cache)
        .expect("cache")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .find(|p| {
            KernelsFile::load(p).is_ok_and(|k| {
                k.focal_mm == Some(setting.focal_mm) && k.f_number == Some(setting.f_number)
            })
        })
        .expect("kernels of the shot cached")
}

/// `lensblur sharpness`: the map a profile predicts at the novel setting and the map
/// one shot's kernels measured, each against the lens's own MTF50 over the frame
/// (median relative error over the cells), written as CSV and as a PNG.
fn sharpness_maps_against_the_truth(
    dir: &Path,
    profile: &Path,
    spec: &DemoSpec,
    novel: LensSetting,
) {
    use lensblur::review::{Mtf50Direction, SharpnessMap};
    let lens = VirtualLens::demo();
    let sensor = (spec.width, spec.height);
    // The CSV's MTF50 column in cycles/px, as a map on the truth's grid.
    let map_of_csv = |csv: &str| -> Vec<f64> {
        let mut lines = csv.lines();
        assert_eq!(
            lines.next(),
            Some("x,y,channel,direction,mtf50_cycles_px,mtf50_lp_ph")
        );
        lines
            .map(|l| {
                let cells: Vec<&str> = l.split(',').collect();
                assert_eq!(cells.len(), 6, "{l}");
                cells[4].parse::<f64>().unwrap_or(f64::NAN)
            })
            .collect()
    };
    let run = |what: &[&str], stem: &str| -> Vec<f64> {
        let (png, csv) = (
            dir.join(format!("{stem}.png")),
            dir.join(format!("{stem}.csv")),
        );
        let mut args = vec!["sharpness"];
        args.extend_from_slice(what);
        args.extend_from_slice(&[
            "--png",
            png.to_str().expect("utf-8"),
            "--csv",
            csv.to_str().expect("utf-8"),
        ]);
        let out = lensblur(&args);
        assert!(
            out.status.success(),
            "sharpness failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let img = image::open(&png).expect("the map's PNG opens");
        assert_eq!(img.width(), 960);
        map_of_csv(&std::fs::read_to_string(&csv).expect("csv"))
    };
    let error = |values: Vec<f64>, setting: LensSetting| {
        let truth = SharpnessMap::truth(&lens, Channel::G, sensor, setting, Mtf50Direction::Worst);
        assert_eq!(values.len(), truth.cycles_per_px.len());
        let got = SharpnessMap {
            cycles_per_px: values,
            ..truth.clone()
        };
        got.median_relative_error(&truth).expect("cells to compare")
    };

    let predicted = run(
        &[
            "--profile",
            profile.to_str().expect("utf-8"),
            "--focal",
            "35",
            "--aperture",
            "4.8",
        ],
        "predicted-map",
    );
    let e_predicted = error(predicted, novel);

    let measured_at = spec.settings[4];
    let kernels = cached_kernels_at(&dir.join(lensblur::pipeline::RESULTS_DIR), measured_at);
    let measured = run(
        &["--kernels", kernels.to_str().expect("utf-8")],
        "measured-map",
    );
    let covered = measured.iter().filter(|v| v.is_finite()).count();
    let e_measured = error(measured, measured_at);
    eprintln!(
        "sharpness map (MTF50 worst, G) against the truth: predicted at the novel setting median {:.2} %, measured on one shot median {:.2} % ({covered} cells with a value)",
        100.0 * e_predicted,
        100.0 * e_measured,
    );
    assert!(e_predicted <= 0.03, "predicted map: median {e_predicted}");
    assert!(e_measured <= 0.03, "measured map: median {e_measured}");
}

/// `scripts/slurm_kernels.sh` run as Slurm would run it: array tasks in their own
/// processes (`lensblur kernels` on one shot), then the dependent job (`calibrate
/// --kernels`). Each task's kernels are those `calibrate --manifest` cached for the
/// same shot, so three tasks (the first, middle and last shot) are run and the other
/// shots' kernels are taken from that cache; the profile is then the one `calibrate
/// --manifest` made, byte for byte. The submission itself runs against a stand-in
/// `sbatch` that records what it was asked.
fn fanned_out_like_a_batch_system(dir: &Path, manifest: &Path, profile: &Path) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm_kernels.sh");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(manifest).expect("manifest")).expect("json");
    let shots = m["shots"].as_array().expect("shots");
    // What the README's jq line makes of the manifest, with a comment and a blank line.
    let mut list = String::from("# shot\tfocal\taperture\n\n");
    for s in shots {
        list.push_str(&format!(
            "{}\t{}\t{}\n",
            dir.join(s["path"].as_str().expect("path")).display(),
            s["focal_mm"],
            s["f_number"]
        ));
    }
    let list_path = dir.join("shots.tsv");
    std::fs::write(&list_path, list).expect("list");
    // The demo's chart is not the default one: the script passes LENSBLUR_CHART on.
    let chart = dir.join("chart.json");
    std::fs::write(&chart, serde_json::to_vec(&m["chart"]).expect("chart json")).expect("chart");
    let out_dir = dir.join("kernels");
    let fanned = dir.join("fanned.json");
    let run = |args: &[&Path], env: &[(&str, &str)]| {
        let mut cmd = Command::new("bash");
        cmd.arg(&script)
            .args(args)
            .env("LENSBLUR", env!("CARGO_BIN_EXE_lensblur"))
            .env("LENSBLUR_CHART", &chart)
            .env("CALIBRATE_ARGS", "--alpha 2 --beta 2");
        for (k, v) in env {
            cmd.env(k, v);
        }
        let out = cmd.output().expect("bash");
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        out
    };
    let task = Path::new("task");
    let cache = dir.join(lensblur::pipeline::RESULTS_DIR);
    let without_source = |path: &Path| {
        let mut k = KernelsFile::load(path).expect("kernels file");
        k.source = None;
        k
    };
    let run_as_tasks = [0, shots.len() / 2, shots.len() - 1];
    for (i, s) in shots.iter().enumerate() {
        let (focal, aperture) = (s["focal_mm"].as_f64(), s["f_number"].as_f64());
        let cached = std::fs::read_dir(&cache)
            .expect("cache")
            .filter_map(Result::ok)
            .map(|e| e.path())
            .find(|p| {
                KernelsFile::load(p).is_ok_and(|k| k.focal_mm == focal && k.f_number == aperture)
            })
            .expect("the shot's kernels cached by calibrate --manifest");
        let name = Path::new(s["path"].as_str().expect("path"))
            .file_stem()
            .expect("a file name")
            .to_string_lossy()
            .into_owned();
        let out = out_dir.join(format!("{name}.kernels.json"));
        if run_as_tasks.contains(&i) {
            let id = i.to_string();
            run(
                &[task, &list_path, &out_dir],
                &[("SLURM_ARRAY_TASK_ID", &id)],
            );
            assert_eq!(
                without_source(&out),
                without_source(&cached),
                "task {i}: its kernels are not those calibrate --manifest measured"
            );
        } else {
            std::fs::create_dir_all(&out_dir).expect("out dir");
            std::fs::copy(&cached, &out).expect("cached kernels");
        }
    }
    run(
        &[Path::new("calibrate"), &list_path, &out_dir, &fanned],
        &[],
    );
    assert_eq!(
        std::fs::read_to_string(&fanned).expect("fanned-out profile"),
        std::fs::read_to_string(profile).expect("profile"),
        "calibrate --kernels on per-shot kernels files and calibrate --manifest differ"
    );

    // Submission: an array of one task per shot, then the calibration after it.
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).expect("bin");
    let sbatch = bin.join("sbatch");
    let log = dir.join("sbatch.log");
    std::fs::write(
        &sbatch,
        format!(
            "#!/usr/bin/env bash\necho \"$*\" >> '{}'\necho 4242\n",
            log.display()
        ),
    )
    .expect("sbatch");
    std::fs::set_permissions(&sbatch, std::os::unix::fs::PermissionsExt::from_mode(0o755))
        .expect("chmod");
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let out = run(
        &[Path::new("submit"), &list_path, &out_dir, &fanned],
        &[("PATH", &path)],
    );
    let calls = std::fs::read_to_string(&log).expect("sbatch called");
    let calls: Vec<&str> = calls.lines().collect();
    assert_eq!(calls.len(), 2, "{calls:?}");
    assert!(
        calls[0].contains(&format!("--array=0-{}", shots.len() - 1)) && calls[0].contains(" task "),
        "{}",
        calls[0]
    );
    assert!(
        calls[1].contains("--dependency=afterok:4242") && calls[1].contains(" calibrate "),
        "{}",
        calls[1]
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("4242"));
}
