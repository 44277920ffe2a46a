//! Sessions on the command line as a photographer brings them: a session with bad shots
//! among the good calibrates from the good ones, listing every failed shot with its
//! own reason.

use lensblur::job::JobContext;
use lensblur::simulate::demo::{DemoSpec, make_demo};
use std::path::Path;
use std::process::Command;

fn lensblur(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(args)
        .output()
        .expect("run lensblur")
}

fn utf8(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Good simulated shots, plus a file that is not there, a damaged RAW and a picture
/// with no chart: every failure is listed with its own reason, the profile is made
/// from the good shots, the setting only the missing file had is named as lost, and
/// `--strict` stops instead.
#[test]
fn a_session_with_bad_shots_calibrates_from_the_good_ones() {
    let dir = tempfile::tempdir().expect("temp dir");
    let spec = DemoSpec::grid(480, 320, &[24.0, 50.0], &[4.0, 8.0]);
    make_demo(dir.path(), &spec, &JobContext::silent()).expect("demo shots");
    let real = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real");
    std::fs::copy(
        real.join("canon-350d-stripped.cr2"),
        dir.path().join("damaged.cr2"),
    )
    .expect("copy the damaged RAW");
    // A grey ramp: an image, but of no chart.
    image::GrayImage::from_fn(480, 320, |x, y| image::Luma([((x + y) / 4) as u8]))
        .save(dir.path().join("notachart.png"))
        .expect("write a picture with no chart");
    let manifest = dir.path().join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&manifest).expect("manifest"))
            .expect("manifest json");
    let shots = m["shots"].as_array_mut().expect("shots");
    let good = shots.len();
    for (path, f, a) in [
        ("missing.dng", 105.0, 4.0),
        ("damaged.cr2", 50.0, 8.0),
        ("notachart.png", 24.0, 4.0),
    ] {
        shots.push(serde_json::json!({"path": path, "focal_mm": f, "f_number": a}));
    }
    let mixed = dir.path().join("mixed.json");
    std::fs::write(&mixed, serde_json::to_vec(&m).expect("json")).expect("write manifest");

    let profile = dir.path().join("profile.json");
    let calibrate = |extra: &[&str]| {
        let mut args = vec![
            "calibrate",
            "--manifest",
            utf8(&mixed),
            "--out",
            utf8(&profile),
            "--model",
            "global",
            "--alpha",
            "1",
            "--beta",
            "1",
            "--no-shape-model",
        ];
        args.extend_from_slice(extra);
        let out = lensblur(&args);
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        (out.status.success(), stderr)
    };
    let (ok, stderr) = calibrate(&[]);
    eprintln!("{stderr}");
    assert!(ok, "calibrate stopped on the bad shots: {stderr}");
    let failed: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("failed: "))
        .collect();
    assert_eq!(failed.len(), 3, "one line per failed shot: {stderr}");
    for name in ["missing.dng", "damaged.cr2", "notachart.png"] {
        assert_eq!(
            failed.iter().filter(|l| l.contains(name)).count(),
            1,
            "{name}: not listed once among {failed:?}"
        );
    }
    // Named as failed, not also in a note before it.
    assert!(
        !stderr
            .lines()
            .any(|l| l.starts_with("note:") && l.contains("missing.dng")),
        "{stderr}"
    );
    // Each with its own reason, not one reason repeated.
    let reasons: std::collections::BTreeSet<String> = failed
        .iter()
        .map(|l| l.split_once(": ").map_or("", |x| x.1).to_string())
        .collect();
    assert_eq!(reasons.len(), 3, "{failed:?}");
    assert!(
        stderr.contains("no shot left at 105 mm f/4"),
        "the lost setting is not named: {stderr}"
    );
    assert!(
        stderr.contains("3 of 7 failed and left out"),
        "no count of the shots left out: {stderr}"
    );
    let p = lensblur::profile::Profile::load(&profile).expect("the profile written");
    assert_eq!(p.calibrated_settings.len(), good, "{stderr}");

    std::fs::remove_file(&profile).expect("remove the profile");
    let (ok, stderr) = calibrate(&["--strict"]);
    assert!(!ok, "--strict went on past the bad shots: {stderr}");
    assert!(stderr.contains("--strict"), "{stderr}");
    assert!(!profile.exists(), "--strict wrote a profile");

    // Nothing usable: a non-zero exit, every shot still listed.
    let bad = dir.path().join("bad.json");
    let only_bad = serde_json::json!({"shots": [
        {"path": "missing.dng", "focal_mm": 50.0, "f_number": 4.0},
        {"path": "notachart.png", "focal_mm": 24.0, "f_number": 4.0},
    ]});
    std::fs::write(&bad, only_bad.to_string()).expect("write manifest");
    let out = lensblur(&[
        "calibrate",
        "--manifest",
        utf8(&bad),
        "--out",
        utf8(&profile),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert_eq!(
        stderr.lines().filter(|l| l.starts_with("failed: ")).count(),
        2,
        "{stderr}"
    );
}
