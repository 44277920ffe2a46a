//! A real camera's RAW photo deblurred as the guide says (`lensblur deblur PHOTOS
//! --out-dir DIR --profiles LIBRARY`, default options) and the result developed by an
//! independent reader, dcraw: the same size, and each colour's mean within 10 % of the
//! input's own development, so the DNG written opens as the photo it was.

use lensblur::raw::{LoadOptions, load_capture};
use std::path::Path;
use std::process::Command;

/// The Canon EOS 550D DNG of tests/data/real (SOURCES.md there).
const PHOTO: &str = "tests/data/real/canon-550d-magic-lantern.dng";

/// dcraw's development of `path` (camera white balance, sRGB, 8-bit PPM): width,
/// height and the mean of each colour.
fn dcraw_means(path: &Path) -> (usize, usize, [f64; 3]) {
    let out = Command::new("dcraw")
        .args(["-c", "-w"])
        .arg(path)
        .output()
        .expect("dcraw runs (apt install dcraw)");
    assert!(
        out.status.success(),
        "dcraw {}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let ppm = out.stdout;
    // P6 header: magic, width, height, maxval, each followed by whitespace.
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while ppm[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while !ppm[at].is_ascii_whitespace() {
            at += 1;
        }
        fields.push(String::from_utf8_lossy(&ppm[start..at]).into_owned());
    }
    at += 1;
    assert_eq!(fields[0], "P6");
    let (w, h): (usize, usize) = (fields[1].parse().expect("w"), fields[2].parse().expect("h"));
    assert_eq!(fields[3], "255", "8-bit");
    let pixels = &ppm[at..at + w * h * 3];
    let mut sums = [0.0f64; 3];
    for px in pixels.chunks_exact(3) {
        for c in 0..3 {
            sums[c] += f64::from(px[c]);
        }
    }
    (w, h, sums.map(|s| s / (w * h) as f64))
}

#[test]
fn a_real_raw_photo_deblurred_develops_as_the_photo_did() {
    let photo = Path::new(env!("CARGO_MANIFEST_DIR")).join(PHOTO);
    let capture = load_capture(&photo, &LoadOptions::default()).expect("the photo loads");
    let dir = tempfile::tempdir().expect("temp dir");
    let profile_path = dir.path().join("profile.json");
    // The demo lens on the photo's own sensor and camera: what `calibrate` would make
    // from that camera's chart shots (the lens is simulated; the photo and its
    // development are real).
    let profile =
        super::batch::profile_on(capture.identity.clone(), 5, (capture.width, capture.height));
    profile.save(&profile_path).expect("write profile");
    // The file records no focal length or aperture (a video frame), which a batch
    // takes from EXIF: a copy with them written in, by exiftool, as any camera records
    // them. The pixels are the camera's.
    let shot = dir
        .path()
        .join("photos")
        .join("canon-550d-magic-lantern.dng");
    std::fs::create_dir_all(shot.parent().expect("folder")).expect("photos folder");
    std::fs::copy(&photo, &shot).expect("copy");
    let tagged = Command::new("exiftool")
        .args([
            "-q",
            "-FocalLength=50",
            "-FNumber=5.6",
            "-overwrite_original",
        ])
        .arg(&shot)
        .status()
        .expect("exiftool runs (apt install libimage-exiftool-perl)");
    assert!(tagged.success(), "exiftool");
    let library = dir.path().join("profiles");
    std::fs::create_dir_all(&library).expect("library");
    std::fs::rename(&profile_path, library.join("canon-550d.profile.json")).expect("move");
    let out_dir = dir.path().join("out");
    let out = Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .arg("deblur")
        .arg(shot.parent().expect("folder"))
        .arg("--out-dir")
        .arg(&out_dir)
        .arg("--profiles")
        .arg(&library)
        .output()
        .expect("run lensblur");
    assert!(
        out.status.success(),
        "deblur: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let written = out_dir.join("canon-550d-magic-lantern.dng");
    assert!(written.is_file(), "a DNG by default for a RAW photo");
    let (w0, h0, before) = dcraw_means(&shot);
    let (w1, h1, after) = dcraw_means(&written);
    eprintln!(
        "dcraw: photo {w0} × {h0} means {before:.1?}; deblurred {w1} × {h1} means {after:.1?}"
    );
    assert_eq!((w1, h1), (w0, h0), "the same size");
    for c in 0..3 {
        let rel = (after[c] / before[c] - 1.0).abs();
        assert!(
            rel <= 0.10,
            "channel {c}: mean {:.1} against the photo's {:.1} ({:.1} %)",
            after[c],
            before[c],
            100.0 * rel
        );
    }
    // LENSBLUR_FIGURES_DIR: both developments kept, for the README's picture.
    if let Some(keep) = std::env::var_os("LENSBLUR_FIGURES_DIR") {
        for (from, name) in [
            (&shot, "real_raw_before.ppm"),
            (&written, "real_raw_after.ppm"),
        ] {
            let out = Command::new("dcraw")
                .args(["-c", "-w"])
                .arg(from)
                .output()
                .expect("dcraw");
            std::fs::write(Path::new(&keep).join(name), out.stdout).expect("keep");
        }
    }
}
