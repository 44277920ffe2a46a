//! `lensblur lensfun` read back by lensfun itself (its C library through
//! `scripts/lensfun_check.py`, with exiftool reading the shots' names): the entry is
//! found by the held-out shot's EXIF names, and lensfun's own corrections straighten
//! the chart, bring red and blue onto green and flatten a flat field. And the entries
//! it refuses to write.

use lensblur::simulate::{LensGeometry, VirtualLens};
use std::path::Path;
use std::process::{Command, Output};

fn lensblur(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(args)
        .output()
        .expect("run lensblur")
}

fn ok(o: &Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "lensblur failed:\n{text}");
    text
}

/// The demo lens with a typical zoom's geometry, written as `lens.json` in `dir`.
fn geometry_lens(dir: &Path) -> String {
    let lens = VirtualLens {
        geometry: LensGeometry::typical_zoom(),
        ..VirtualLens::demo()
    };
    let path = dir.join("lens.json");
    let json = serde_json::to_string(&lensblur::format::Versioned::new(
        &lensblur::format::LENS,
        &lens,
    ))
    .expect("lens json");
    std::fs::write(&path, json).expect("write lens");
    path.display().to_string()
}

fn simulate(
    dir: &Path,
    lens: &str,
    size: [&str; 2],
    focal: &str,
    aperture: &str,
    extra: &[&str],
) -> String {
    let out = dir.display().to_string();
    let mut args = vec![
        "simulate",
        "--out",
        &out,
        "--lens",
        lens,
        "--width",
        size[0],
        "--height",
        size[1],
        "--focal",
        focal,
        "--aperture",
        aperture,
    ];
    args.extend_from_slice(extra);
    ok(&lensblur(&args));
    dir.join("manifest.json").display().to_string()
}

fn number(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut v = v;
    for p in path {
        v = &v[p];
    }
    v.as_f64()
        .unwrap_or_else(|| panic!("{path:?} missing in {v}"))
}

#[test]
fn lensfun_reads_the_entry_and_its_corrections_straighten_a_held_out_shot() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let lens = geometry_lens(tmp.path());
    let size = ["1200", "800"];
    let session = simulate(
        &tmp.path().join("session"),
        &lens,
        size,
        "24,105",
        "4,8",
        &[],
    );
    let xml = tmp.path().join("lens.xml").display().to_string();
    let report = tmp.path().join("report.json").display().to_string();
    ok(&lensblur(&[
        "lensfun",
        "--manifest",
        &session,
        "--out",
        &xml,
        "--report",
        &report,
    ]));
    let dtd = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/lensfun/lensfun-database.dtd");
    let valid = Command::new("xmllint")
        .args(["--noout", "--dtdvalid"])
        .arg(&dtd)
        .arg(&xml)
        .output()
        .expect("xmllint (the README's test command installs libxml2-utils)");
    assert!(
        valid.status.success(),
        "not valid against lensfun's DTD: {}",
        String::from_utf8_lossy(&valid.stderr)
    );
    // A shot the entry was not fitted to (another pose and noise), at a setting the
    // entry has, with a flat field at that setting.
    let held = tmp.path().join("held");
    simulate(
        &held,
        &lens,
        size,
        "105",
        "4",
        &["--seed", "9", "--flat-field"],
    );
    let shot = held.join("f105.0_a04.0_1.dng").display().to_string();
    let detect = held.join("detect.json").display().to_string();
    ok(&lensblur(&["detect", &shot, "--out", &detect]));
    let flat = held.join("flat_f105.0_a04.0.png").display().to_string();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/lensfun_check.py");
    let o = Command::new("python3")
        .arg(&script)
        .args([
            "--xml", &xml, "--shot", &shot, "--detect", &detect, "--flat", &flat,
        ])
        .output()
        .expect("python3 (the README's test command installs it, exiftool and liblensfun1)");
    assert!(
        o.status.success(),
        "lensfun check failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("check's json");
    eprintln!("{r}");
    assert_eq!(r["lens_found"], "VZ 24-105mm f/4", "{r}");
    assert_eq!(r["camera_found"], "Sim 14", "{r}");
    for c in ["distortion", "tca", "vignetting"] {
        assert_eq!(r["corrections"][c], true, "lensfun applies no {c}: {r}");
    }
    // 1.5 % pincushion at 105 mm bends the chart's rows by about a pixel at this size;
    // lensfun's correction leaves the alignment's own noise (a few hundredths).
    let (before, after) = (
        number(&r, &["straightness_rms_px", "before"]),
        number(&r, &["straightness_rms_px", "after"]),
    );
    assert!(
        before > 0.3 && after < 0.05,
        "straightness {before} -> {after} px"
    );
    for ch in ["red_to_green_rms_px", "blue_to_green_rms_px"] {
        let (b, a) = (number(&r, &[ch, "before"]), number(&r, &[ch, "after"]));
        assert!(b > 0.08 && a < b / 4.0, "{ch}: {b} -> {a} px");
    }
    let (b, a) = (
        number(&r, &["flat_field_spread_stops", "before"]),
        number(&r, &["flat_field_spread_stops", "after"]),
    );
    assert!(b > 0.6 && a < 0.1, "flat field {b} -> {a} stops");
}

#[test]
fn lensfun_refuses_to_write_a_wrong_entry() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let lens = geometry_lens(tmp.path());
    let size = ["720", "480"];
    let refused = |manifest: &str, extra: &[&str], words: &str| {
        let xml = tmp.path().join("refused.xml");
        let mut args = vec!["lensfun", "--manifest", manifest, "--out"];
        let xml_s = xml.display().to_string();
        args.push(&xml_s);
        args.extend_from_slice(extra);
        let o = lensblur(&args);
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(!o.status.success(), "wrote an entry: {err}");
        let last = err.lines().last().unwrap_or_default();
        assert!(last.contains(words), "expected '{words}' in: {last}");
        assert!(!xml.exists(), "a refused entry left a file");
    };
    // A zoom (its EXIF says 24–105 mm) shot at one focal length.
    let one = simulate(&tmp.path().join("one"), &lens, size, "50", "4", &[]);
    refused(
        &one,
        &[],
        "every shot is at 50 mm but the lens zooms 24–105 mm",
    );
    // Shots without EXIF (16-bit TIFFs): the camera named by hand, the lens not.
    let tiff = simulate(
        &tmp.path().join("tiff"),
        &lens,
        size,
        "24,105",
        "4",
        &["--format", "tiff"],
    );
    refused(
        &tiff,
        &["--camera-maker", "Virtual", "--camera-model", "Sim 14"],
        "EXIF names no lens: pass --lens-model",
    );
    // A lamp to one side: 0.5 stops per half diagonal across the frame.
    let uneven = simulate(
        &tmp.path().join("uneven"),
        &lens,
        size,
        "24,105",
        "4",
        &["--light-gradient", "0.5,0"],
    );
    refused(&uneven, &[], "the light on the chart was not even");
    let xml = tmp.path().join("geometry-only.xml").display().to_string();
    ok(&lensblur(&[
        "lensfun",
        "--manifest",
        &uneven,
        "--out",
        &xml,
        "--no-vignetting",
    ]));
    let text = std::fs::read_to_string(&xml).expect("entry");
    assert!(
        text.contains("<distortion") && !text.contains("<vignetting"),
        "{text}"
    );
}
