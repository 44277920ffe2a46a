//! Every file lensblur reads carries a version. A file of each earlier version, kept in
//! `tests/formats/`, is read and migrated; a file of each current version (the seed
//! corpus in `fuzz/seeds/`, written by lensblur) is read; the same file claiming the
//! next version is refused naming both versions. When a format's version goes up, its
//! current file is copied here as the earlier version it has become.

use lensblur::chart::ChartSpec;
use lensblur::detect::DetectFile;
use lensblur::kernel::file::KernelsFile;
use lensblur::manifest::Manifest;
use lensblur::profile::Profile;
use lensblur::session::{SESSION, Session, ShotId, StageStatus};
use std::path::{Path, PathBuf};

fn kept(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/formats")
        .join(name)
}

fn text(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap()
}

/// The current-version file of a format, as lensblur wrote it.
fn current(folder: &str, name: &str) -> String {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/seeds")
        .join(folder);
    let path = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().ends_with(name))
        .min()
        .unwrap_or_else(|| panic!("no {name} in {}", dir.display()));
    text(&path)
}

/// The text with its schema's version raised by one, and that version.
fn next_version(text: &str) -> (String, u32) {
    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    let schema = v["schema"].as_str().unwrap().to_string();
    let (kind, n) = schema.rsplit_once('/').unwrap();
    let next = n.parse::<u32>().unwrap() + 1;
    v["schema"] = format!("{kind}/{next}").into();
    (v.to_string(), next)
}

fn assert_newer_refused(e: impl std::fmt::Display, next: u32) {
    let e = e.to_string();
    assert!(
        e.contains(&format!("version {next} is newer"))
            && e.contains(&format!("up to version {}", next - 1)),
        "{e}"
    );
    assert_eq!(e.lines().count(), 1, "{e}");
}

#[test]
fn each_current_format_is_read_and_its_next_version_refused() {
    let p = Path::new("x.json");
    let t = current("session", "session.json");
    Session::from_json(p, &t).unwrap();
    let (n, v) = next_version(&t);
    assert_newer_refused(Session::from_json(p, &n).unwrap_err(), v);

    let t = current("manifest", "manifest.json");
    Manifest::from_json(p, &t).unwrap();
    let (n, v) = next_version(&t);
    assert_newer_refused(Manifest::from_json(p, &n).unwrap_err(), v);

    let t = current("chart", "chart.json");
    ChartSpec::from_json("x.json", &t).unwrap();
    let (n, v) = next_version(&t);
    assert_newer_refused(ChartSpec::from_json("x.json", &n).unwrap_err(), v);

    let t = current("kernels", ".kernels.json");
    KernelsFile::from_json(&t).unwrap();
    let (n, v) = next_version(&t);
    assert_newer_refused(KernelsFile::from_json(&n).unwrap_err(), v);

    let t = current("detect", ".detect.json");
    DetectFile::from_json(&t).unwrap();
    let (n, v) = next_version(&t);
    assert_newer_refused(DetectFile::from_json(&n).unwrap_err(), v);

    let t = current("profile", "profile.json");
    Profile::from_json(&t, "x.json").unwrap();
    let (n, v) = next_version(&t);
    assert_newer_refused(Profile::from_json(&n, "x.json").unwrap_err(), v);
}

#[test]
fn a_version_2_profile_reads_without_a_trust_record_and_warns_only_by_setting() {
    let path = kept("profile-v2.json");
    let p = Profile::from_json(&text(&path), "profile-v2.json").unwrap();
    assert!(p.trust.is_none());
    // Its settings still bound what it is trusted for.
    let [f0, f1] = p.norm.focal_range_mm;
    let a = p.norm.f_number_range[0];
    let beyond = lensblur::plane::LensSetting {
        focal_mm: f1 * 1.5,
        f_number: a,
    };
    assert!(p.trust_line(beyond, None, None).is_some());
    let shot = p
        .calibrated_settings
        .first()
        .copied()
        .unwrap_or(lensblur::plane::LensSetting {
            focal_mm: f0,
            f_number: a,
        });
    assert_eq!(p.trust_line(shot, None, None), None);
    // Written again, it is a version-4 file.
    let again = String::from_utf8(p.to_json().unwrap()).unwrap();
    assert!(again.contains("lensblur.profile/4"));
}

#[test]
fn a_version_1_profile_reads_with_its_gaussians_and_no_shape_model() {
    let path = kept("profile-v1.json");
    let p = Profile::from_json(&text(&path), "profile-v1.json").unwrap();
    assert!(p.shape.is_none() && p.shape_cv.is_none());
    assert_eq!(p.kernel_model(), lensblur::model::KernelModel::Gaussian);
    assert!(p.global.is_some() || p.local.is_some());
    // Written again, it is a version-4 file that reads back the same.
    let again = String::from_utf8(p.to_json().unwrap()).unwrap();
    assert!(again.contains("lensblur.profile/4"));
    let q = Profile::from_json(&again, "again.json").unwrap();
    assert_eq!(q.calibrated_settings, p.calibrated_settings);
}

#[test]
fn a_version_1_session_is_migrated() {
    let path = kept("session-v1.json");
    let s = Session::from_json(&path, &text(&path)).unwrap();
    assert_eq!(s.schema, SESSION.tag());
    assert_eq!(s.name, "bench test, January");
    let ids: Vec<ShotId> = s.shots.iter().map(|x| x.id).collect();
    assert_eq!(ids, vec![ShotId(1), ShotId(2), ShotId(3)]);
    assert_eq!(s.next_shot_id, 4);
    assert_eq!(
        (s.shots[0].focal_mm, s.shots[0].f_number),
        (Some(24.0), Some(4.0))
    );
    assert_eq!(s.shots[2].focal_mm, None);
    // Version 1 kept results by list position: they are found again by content.
    assert_eq!(s.shots[0].detect, StageStatus::Pending);
    assert_eq!((s.chart.cols, s.chart.rows), (8, 6));
    // Opened in a folder and saved, it is the current version and reads back the same.
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(&path, dir.path().join("session.json")).unwrap();
    let opened = Session::open(dir.path()).unwrap();
    assert_eq!(opened.shots, s.shots);
    opened.save().unwrap();
    assert!(text(&dir.path().join("session.json")).contains(&SESSION.tag()));
    let back = Session::open(dir.path()).unwrap();
    assert_eq!(back.shots, s.shots);
}

#[test]
fn unversioned_manifests_charts_and_kernels_files_are_version_1() {
    let p = kept("manifest-v1-unversioned.json");
    let m = Manifest::from_json(&p, &text(&p)).unwrap();
    assert_eq!(m.shots.len(), 2);
    assert_eq!(m.shots[0].setting().map(|s| s.focal_mm), Some(24.0));
    // Opened as a session: the shots, numbered.
    let s = Session::from_json(&p, &text(&p)).unwrap();
    assert_eq!(s.shots.len(), 2);
    assert_eq!(s.chart.cols, 8);

    let p = kept("chart-v1-unversioned.json");
    let c = ChartSpec::from_json("chart", &text(&p)).unwrap();
    assert_eq!((c.cols, c.rows, c.square_mm), (10, 7, 15.0));

    let p = kept("kernels-v1-unversioned.json");
    let k = KernelsFile::load(&p).unwrap();
    assert_eq!(k.samples.len(), 2);
    assert_eq!(k.oversample, 3);
    assert_eq!(k.samples[1].kernel.as_ref().map(|d| d.size), Some(3));
}

#[test]
fn a_file_of_another_kind_is_named_as_such() {
    let t = current("profile", "profile.json");
    let e = KernelsFile::from_json(&t).unwrap_err();
    assert!(
        e.contains("lensblur.profile/4") && e.contains("not a lensblur.kernels file"),
        "{e}"
    );
    let t = current("kernels", ".kernels.json");
    let e = Profile::from_json(&t, "k.json").unwrap_err().to_string();
    assert!(e.contains("not a lensblur.profile file"), "{e}");
}

/// Issue 36: where the shots were focused goes from a kernels file through the dataset
/// into the profile, and back out of its file; a profile without one (every profile
/// calibrated before it was kept) reads as having none.
#[test]
fn the_focus_distances_of_the_shots_travel_into_the_profile_and_back() {
    use lensblur::model::Dataset;
    use lensblur::profile::FocusRange;
    use lensblur::raw::FocusDistance;
    let mut near = KernelsFile::from_json(&current("kernels", ".kernels.json")).unwrap();
    near.focus_distance_m = FocusDistance::from_metres(1.5);
    let mut far = near.clone();
    far.focus_distance_m = FocusDistance::from_metres(f64::INFINITY);
    let text_of = |k: &KernelsFile| serde_json::to_string(k).unwrap();
    assert!(text_of(&far).contains("\"focus_distance_m\":\"infinity\""));
    let (near, far) = (
        KernelsFile::from_json(&text_of(&near)).unwrap(),
        KernelsFile::from_json(&text_of(&far)).unwrap(),
    );
    let ds = Dataset::from_kernels(&[("near", &near, None), ("far", &far, None)]).unwrap();
    let range = lensblur::profile::FocusRange::of_dataset(&ds).expect("both shots say");
    assert_eq!(range, FocusRange::of([1.5, f64::INFINITY]).unwrap());

    let old = Profile::from_json(&text(&kept("profile-v2.json")), "profile-v2.json").unwrap();
    assert_eq!(old.focus_range, None);
    let mut p = old.clone();
    p.focus_range = Some(range);
    let json = String::from_utf8(p.to_json().unwrap()).unwrap();
    assert!(json.contains("\"focus_range_m\""), "{json}");
    let back = Profile::from_json(&json, "p.json").unwrap();
    assert_eq!(back.focus_range, Some(range));
    // A range that is no range is refused, naming the file.
    let bad = json.replacen("\"nearest_m\": 1.5", "\"nearest_m\": -1.5", 1);
    assert_ne!(bad, json);
    let e = Profile::from_json(&bad, "bad.json")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("bad.json") && e.contains("focus range"),
        "{e}"
    );
}
