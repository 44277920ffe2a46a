//! Batch deblurring with a profile library (`lensblur deblur PHOTO|DIR... --out-dir
//! --profiles`): each photo gets its own lens unit's profile from its EXIF, photos that
//! cannot be matched are skipped with their reasons, a re-run redoes nothing, and a
//! photo that fails makes the exit status non-zero.

use lensblur::model::{GlobalModel, ModelKind, spaced};
use lensblur::plane::{CameraIdentity, LensSetting};
use lensblur::profile::Profile;
use lensblur::simulate::SimulatedSession;
use lensblur::simulate::lens::VirtualLens;
use std::path::{Path, PathBuf};
use tiff::encoder::{Rational, TiffEncoder, colortype};
use tiff::tags::Tag;

const W: usize = 96;
const H: usize = 64;

fn unit(serial: &str) -> CameraIdentity {
    CameraIdentity {
        make: Some("Acme".into()),
        model: Some("A1".into()),
        lens_model: Some("Zoom 24-70".into()),
        lens_serial: Some(serial.into()),
        body_serial: None,
    }
}

/// A profile of the demo lens on a `W × H` sensor, calibrated over 24–70 mm, f/4–8,
/// recorded as `identity`'s.
fn profile(identity: CameraIdentity, seed: u64) -> Profile {
    profile_on(identity, seed, (W, H))
}

/// A global profile of the demo lens for `identity` on a `w × h` sensor, fitted to a
/// simulated session at 3 × 3 settings (24–70 mm, f/4–f/8).
pub(crate) fn profile_on(identity: CameraIdentity, seed: u64, (w, h): (usize, usize)) -> Profile {
    let mut settings = Vec::new();
    for f in spaced(24.0, 70.0, 3, false) {
        for a in spaced(4.0, 8.0, 3, true) {
            settings.push(LensSetting {
                focal_mm: f,
                f_number: a,
            });
        }
    }
    let ds = SimulatedSession {
        seed,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&VirtualLens::demo(), &settings);
    let global = GlobalModel::fit(&ds, 2, 2).expect("fit");
    Profile::new(
        identity,
        None,
        settings,
        Some(global),
        None,
        None,
        ModelKind::Global,
    )
    .expect("profile")
}

/// A 16-bit linear RGB TIFF with the camera, lens and setting in its first directory,
/// where cameras' TIFFs and DNGs keep them.
fn tiff_photo(path: &Path, identity: &CameraIdentity, focal_mm: u32, f_number_x10: u32) {
    let data: Vec<u16> = (0..W * H * 3)
        .map(|i| {
            let (x, y) = ((i / 3) % W, (i / 3) / W);
            if (x / 8 + y / 8) % 2 == 0 {
                12000
            } else {
                50000
            }
        })
        .collect();
    let file = std::fs::File::create(path).expect("create");
    let mut enc = TiffEncoder::new(file).expect("encoder");
    let mut img = enc
        .new_image::<colortype::RGB16>(W as u32, H as u32)
        .expect("image");
    let dir = img.encoder();
    let text = |v: &Option<String>| v.clone().expect("identity field");
    dir.write_tag(Tag::Make, text(&identity.make).as_str())
        .expect("tag");
    dir.write_tag(Tag::Model, text(&identity.model).as_str())
        .expect("tag");
    dir.write_tag(Tag::Unknown(42036), text(&identity.lens_model).as_str())
        .expect("tag");
    dir.write_tag(Tag::Unknown(42037), text(&identity.lens_serial).as_str())
        .expect("tag");
    dir.write_tag(Tag::Unknown(37386), Rational { n: focal_mm, d: 1 })
        .expect("tag");
    dir.write_tag(
        Tag::Unknown(33437),
        Rational {
            n: f_number_x10,
            d: 10,
        },
    )
    .expect("tag");
    img.write_data(&data).expect("write");
}

fn lensblur(args: &[&Path]) -> (bool, String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(args)
        .output()
        .expect("run lensblur");
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

/// Every file of a folder with its modification time and contents.
fn snapshot(dir: &Path) -> Vec<(PathBuf, std::time::SystemTime, Vec<u8>)> {
    let mut out: Vec<_> = std::fs::read_dir(dir)
        .expect("list")
        .map(|e| {
            let p = e.expect("entry").path();
            let m = std::fs::metadata(&p)
                .and_then(|m| m.modified())
                .expect("mtime");
            let bytes = std::fs::read(&p).expect("read");
            (p, m, bytes)
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// The stderr line about one photo.
fn line_of<'a>(stderr: &'a str, name: &str) -> &'a str {
    stderr
        .lines()
        .find(|l| l.contains(&format!("{name}: ")))
        .unwrap_or_else(|| panic!("no line for {name} in:\n{stderr}"))
}

#[test]
fn batch_picks_each_photos_profile_skips_with_reasons_and_resumes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = |p: &str| dir.path().join(p);
    for f in ["photos", "profiles"] {
        std::fs::create_dir(d(f)).expect("mkdir");
    }
    profile(unit("1001"), 3)
        .save(&d("profiles/zoom-1001.json"))
        .expect("save");
    profile(unit("1002"), 4)
        .save(&d("profiles/zoom-1002.json"))
        .expect("save");
    std::fs::write(
        d("profiles/damaged.json"),
        r#"{"schema": "lensblur.profile/1"}"#,
    )
    .expect("write");
    std::fs::write(d("profiles/readme.txt"), "not a profile").expect("write");

    tiff_photo(&d("photos/a.tif"), &unit("1001"), 35, 56);
    tiff_photo(&d("photos/b.tif"), &unit("1002"), 50, 45);
    tiff_photo(&d("photos/far.tif"), &unit("1001"), 135, 56);
    // A PNG without EXIF: no settings, no camera.
    image::ImageBuffer::<image::Rgb<u16>, _>::from_pixel(W as u32, H as u32, image::Rgb([9000; 3]))
        .save(d("photos/plain.png"))
        .expect("png");
    std::fs::write(d("photos/a.xmp"), "sidecar").expect("write");

    let args = [
        Path::new("deblur"),
        &d("photos"),
        Path::new("--out-dir"),
        &d("out"),
        Path::new("--profiles"),
        &d("profiles"),
    ];
    let (ok, err) = lensblur(&args);
    assert!(ok, "{err}");
    eprintln!("{err}");
    assert!(
        err.lines()
            .any(|l| l.starts_with("lensblur: warning:") && l.contains("damaged.json")),
        "{err}"
    );
    let a = line_of(&err, "a.tif");
    assert!(
        a.contains("deblurred with") && a.contains("zoom-1001.json"),
        "{a}"
    );
    let b = line_of(&err, "b.tif");
    assert!(
        b.contains("deblurred with") && b.contains("zoom-1002.json"),
        "{b}"
    );
    let far = line_of(&err, "far.tif");
    assert!(
        far.contains("skipped") && far.contains("zoom-1001.json") && far.contains("135"),
        "{far}"
    );
    let plain = line_of(&err, "plain.png");
    assert!(
        plain.contains("skipped") && plain.contains("no focal length and aperture"),
        "{plain}"
    );
    assert!(!err.contains("a.xmp"), "a sidecar is not a photo: {err}");
    for summary in [
        "done: 2",
        "skipped: 2",
        "no focal length or aperture in EXIF: 1",
        "outside the calibrated range: 1",
        "failed: 0",
    ] {
        assert!(err.lines().any(|l| l.trim() == summary), "{summary}: {err}");
    }
    // By default each photo comes out in its own format and colour: a 16-bit TIFF in,
    // a 16-bit TIFF out.
    for name in ["a", "b"] {
        let out = image::open(d(&format!("out/{name}.tif"))).expect("output");
        assert!(matches!(out, image::DynamicImage::ImageRgb16(_)));
        assert_eq!((out.width(), out.height()), (W as u32, H as u32));
    }
    let before = snapshot(&d("out"));
    assert_eq!(before.len(), 2, "{before:?}");

    // Run again: both outputs are complete, nothing is written.
    let (ok, err) = lensblur(&args);
    assert!(ok, "{err}");
    assert!(line_of(&err, "a.tif").contains("already complete"), "{err}");
    assert!(err.lines().any(|l| l.trim() == "done: 0"), "{err}");
    assert!(err.lines().any(|l| l.trim() == "already done: 2"), "{err}");
    assert_eq!(snapshot(&d("out")), before, "a re-run rewrote an output");

    // A photo that cannot be written is a failure, and the exit status says so.
    std::fs::create_dir_all(d("blocked/a.tif")).expect("mkdir");
    let (ok, err) = lensblur(&[
        Path::new("deblur"),
        &d("photos/a.tif"),
        Path::new("--out-dir"),
        &d("blocked"),
        Path::new("--profiles"),
        &d("profiles"),
    ]);
    assert!(!ok, "{err}");
    assert!(line_of(&err, "a.tif").contains("failed"), "{err}");
    assert!(err.lines().any(|l| l.trim() == "failed: 1"), "{err}");

    // Allowed to extrapolate, the far photo is deblurred, and warned about as one photo
    // would be.
    let (ok, err) = lensblur(&[
        Path::new("deblur"),
        &d("photos/far.tif"),
        Path::new("--out-dir"),
        &d("extrapolated"),
        Path::new("--profiles"),
        &d("profiles"),
        Path::new("--allow-extrapolation"),
    ]);
    assert!(ok, "{err}");
    assert!(
        err.lines()
            .any(|l| l.contains("far.tif: warning:") && l.contains("outside the calibrated range")),
        "{err}"
    );

    // Without --profiles, the profile library the studio saves into: none yet is one
    // line saying how to fill it; the folder chosen in the studio is read.
    let home = d("home");
    let from_library = |out: &str| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
            .arg("deblur")
            .arg(d("photos/a.tif"))
            .arg("--out-dir")
            .arg(d(out))
            .env("HOME", &home)
            .env("XDG_DATA_HOME", home.join("data"))
            .output()
            .expect("run lensblur");
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (ok, err) = from_library("no-library");
    assert!(!ok, "{err}");
    let library = home.join("lensblur").join("profiles");
    assert!(
        err.contains(&library.display().to_string())
            && err.contains("Lens profile to the library")
            && err.contains("--profiles"),
        "{err}"
    );
    lensblur::recent::choose_profile_library(
        &home.join("data").join("lensblur").join("settings.json"),
        &d("profiles"),
    )
    .expect("choose the library");
    let (ok, err) = from_library("library-out");
    assert!(ok, "{err}");
    assert!(line_of(&err, "a.tif").contains("zoom-1001.json"), "{err}");
}

#[test]
fn a_photos_header_says_what_its_decode_will() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = dir.path().join("a.tif");
    tiff_photo(&p, &unit("1001"), 35, 56);
    let h = lensblur::raw::read_header(&p).expect("header");
    let c = lensblur::raw::load_capture(&p, &Default::default()).expect("load");
    assert_eq!((h.width, h.height, h.is_raw), (c.width, c.height, c.is_raw));
    assert_eq!(h.exif.identity, c.identity);
    assert_eq!((h.exif.focal_mm, h.exif.f_number), (Some(35.0), Some(5.6)));
    // A RAW photo, read by the RAW decoder (strips) and by our own reader (tiles).
    for tile in [None, Some(16)] {
        let dng = dir.path().join("a.dng");
        let info = lensblur::dng::DngInfo::simulated(
            "Acme",
            "A1",
            0,
            65535,
            None,
            lensblur::dng::DngLayout {
                tile,
                ..Default::default()
            },
        );
        // Not one value throughout: that is a file without its picture, refused.
        let cfa: Vec<u16> = (0..W * H).map(|k| 1000 + (k % 7) as u16).collect();
        lensblur::dng::write_dng(&dng, &cfa, W, H, &info).expect("dng");
        let h = lensblur::raw::read_header(&dng).expect("header");
        let c = lensblur::raw::load_capture(&dng, &Default::default()).expect("load");
        assert_eq!((h.width, h.height, h.is_raw), (c.width, c.height, true));
        assert_eq!(h.exif.identity.model, c.identity.model);
    }
}

#[test]
fn a_dng_batch_writes_raw_photos_back_as_dngs_and_skips_the_others() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = |p: &str| dir.path().join(p);
    for f in ["photos", "profiles"] {
        std::fs::create_dir(d(f)).expect("mkdir");
    }
    profile(unit("1001"), 3)
        .save(&d("profiles/zoom-1001.json"))
        .expect("save");
    // A RAW photo of that lens unit, its EXIF in its own directory as cameras write it.
    let mut info = lensblur::dng::DngInfo::simulated(
        "Acme",
        "A1",
        512,
        16383,
        Some(LensSetting {
            focal_mm: 35.0,
            f_number: 5.6,
        }),
        lensblur::dng::DngLayout::default(),
    );
    info.identity = unit("1001");
    info.exif_in_ifd0 = false;
    let cfa: Vec<u16> = (0..W * H)
        .map(|i| 512 + ((i * 7919) % 9000) as u16)
        .collect();
    lensblur::dng::write_dng(&d("photos/raw.dng"), &cfa, W, H, &info).expect("dng");
    tiff_photo(&d("photos/rgb.tif"), &unit("1001"), 35, 56);

    let args = [
        "deblur".into(),
        d("photos"),
        "--out-dir".into(),
        d("out"),
        "--profiles".into(),
        d("profiles"),
        "--format".into(),
        "dng".into(),
    ];
    let args: Vec<&Path> = args.iter().map(PathBuf::as_path).collect();
    let (ok, stderr) = lensblur(&args);
    assert!(ok, "{stderr}");
    assert!(
        line_of(&stderr, "rgb.tif").contains("not a RAW photo"),
        "{stderr}"
    );
    assert!(!d("out/rgb.dng").exists());
    let out = lensblur::raw::load_capture(&d("out/raw.dng"), &Default::default()).expect("DNG");
    assert!(out.is_raw);
    assert_eq!(out.identity, unit("1001"));
    assert_eq!(
        (out.setting_focal_mm, out.setting_f_number),
        (Some(35.0), Some(5.6))
    );
    let note = out.raw.and_then(|r| r.description).unwrap_or_default();
    assert!(note.contains("zoom-1001.json"), "{note}");
    assert!(d("out/raw.preview.png").is_file());
}
