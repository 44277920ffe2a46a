//! A photo of another kind than its profile's shots: a camera's developed JPEG, and an
//! honestly sRGB-encoded 8-bit JPEG of a linear photo, each deblurred with a profile
//! measured on RAW files. Each is warned about once, and the deblur, held back by the
//! noise, quantisation and blocks it finds in the photo, never makes either worse.

use lensblur::deblur::{DeblurOptions, ProfileKernels, deblur_channel_plane};
use lensblur::develop::{Orient, develop};
use lensblur::dng::{DngInfo, write_dng};
use lensblur::job::JobContext;
use lensblur::metrics::{SsimParams, ssim};
use lensblur::model::spaced;
use lensblur::plane::{Channel, LensSetting, PictureKind, Plane, srgb_decode, srgb_encode};
use lensblur::profile::Profile;
use lensblur::raw::{LoadOptions, load_capture};
use lensblur::simulate::capture::rggb_channel;
use lensblur::simulate::lens::VirtualLens;
use lensblur::simulate::{SimulatedSession, blur_varying, dead_leaves};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::path::Path;

const W: usize = 192;
const H: usize = 128;
const SETTING: LensSetting = LensSetting {
    focal_mm: 40.0,
    f_number: 5.0,
};

/// The sharp scene (a dead-leaves plane per channel) and the demo lens's blur of it at
/// [`SETTING`], with a clean RAW file's noise (σ 0.003).
fn scene() -> ([Plane; 3], [Plane; 3]) {
    let lens = VirtualLens::demo();
    let pad = 24;
    let channels = [Channel::R, Channel::G, Channel::B];
    let mut rng = rand_pcg::Pcg64::seed_from_u64(50);
    let noise = Normal::new(0.0, 0.003).expect("σ > 0");
    let planes = channels.map(|ch| {
        let big = dead_leaves(W + 2 * pad, H + 2 * pad, 500 + ch as u64);
        let mut blurry = blur_varying(&big, pad, W, H, 8, &|x, y| {
            lens.gaussian_at(ch, x, y, W, H, SETTING)
                .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
                .kernel(1)
        });
        for v in &mut blurry.data {
            *v += noise.sample(&mut rng) as f32;
        }
        (big.crop(pad, pad, W, H), blurry)
    });
    let [(s0, b0), (s1, b1), (s2, b2)] = planes;
    ([s0, s1, s2], [b0, b1, b2])
}

/// `planes` as the camera's RAW file: an RGGB mosaic in a DNG with the setting in EXIF.
fn write_raw(path: &Path, planes: &[Plane; 3]) {
    let (black, white) = (512u16, 16383u16);
    let cfa: Vec<u16> = (0..W * H)
        .map(|i| {
            let (x, y) = (i % W, i / W);
            let v = f64::from(planes[rggb_channel(x, y)].get(x, y).clamp(0.0, 1.0));
            (f64::from(black) + v * f64::from(white - black)).round() as u16
        })
        .collect();
    let lens = VirtualLens::demo();
    let info = DngInfo::simulated(
        &lens.make,
        &lens.model,
        black,
        white,
        Some(SETTING),
        lensblur::dng::DngLayout::default(),
    );
    write_dng(path, &cfa, W, H, &info).expect("write dng");
}

/// A RAW file developed as a camera or a RAW editor does (demosaiced, white-balanced,
/// tone-mapped, sRGB): its 8-bit RGB.
fn developed(raw: &Path) -> Vec<u8> {
    let cap = load_capture(raw, &LoadOptions::default()).expect("load dng");
    let d = develop(&cap, None, Orient::Sensor).expect("develop");
    assert_eq!((d.width, d.height), (W, H));
    d.rgb
}

fn write_jpeg(path: &Path, rgb: &[u8], quality: u8) {
    let file = std::fs::File::create(path).expect("create jpeg");
    image::codecs::jpeg::JpegEncoder::new_with_quality(file, quality)
        .encode(rgb, W as u32, H as u32, image::ExtendedColorType::Rgb8)
        .expect("encode jpeg");
}

/// 8-bit sRGB values as lensblur reads them: linear light.
fn decoded(rgb: &[u8]) -> [Plane; 3] {
    [0, 1, 2].map(|c| {
        Plane::from_fn(W, H, |x, y| {
            srgb_decode(f32::from(rgb[3 * (y * W + x) + c]) / 255.0)
        })
    })
}

/// The R, G, B planes of an image file as lensblur loads it.
fn loaded(path: &Path) -> [Plane; 3] {
    let cap = load_capture(path, &LoadOptions::default()).expect("load");
    let plane = |ch| {
        cap.planes
            .iter()
            .find(|p| p.channel == ch)
            .expect("channel")
            .plane
            .clone()
    };
    [plane(Channel::R), plane(Channel::G), plane(Channel::B)]
}

fn mean_ssim(a: &[Plane; 3], b: &[Plane; 3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ssim(x, y, &SsimParams::default()))
        .sum::<f64>()
        / 3.0
}

/// The demo lens's profile from a simulated RAW session of this sensor.
fn raw_profile() -> Profile {
    let settings: Vec<LensSetting> = spaced(24.0, 105.0, 4, false)
        .into_iter()
        .flat_map(|f| {
            spaced(4.0, 10.0, 4, true)
                .into_iter()
                .map(move |a| LensSetting {
                    focal_mm: f,
                    f_number: a,
                })
        })
        .collect();
    let ds = SimulatedSession {
        seed: 17,
        ..SimulatedSession::new(W, H)
    }
    .dataset(&VirtualLens::demo(), &settings);
    crate::global_profile(&ds, 3, 2)
}

/// `lensblur deblur photo --profile profile` at [`SETTING`] into a 16-bit PNG: its
/// planes and what it said on stderr.
fn deblur_command(photo: &Path, profile: &Path, out: &Path) -> ([Plane; 3], String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .arg("deblur")
        .arg(photo)
        .arg("--out")
        .arg(out)
        .arg("--profile")
        .arg(profile)
        .args(["--focal", "40", "--aperture", "5"])
        .output()
        .expect("run lensblur");
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{stderr}");
    (loaded(out), stderr)
}

/// The same photo deblurred at the method's tuned strength, whatever its noise: what
/// the noise rule is measured against.
fn at_tuned_strength(photo: &Path, profile: &Profile) -> [Plane; 3] {
    let cap = load_capture(photo, &LoadOptions::default()).expect("load");
    let source = ProfileKernels::new(profile.clone(), SETTING);
    let job = JobContext::silent();
    [Channel::R, Channel::G, Channel::B].map(|ch| {
        let cp = cap.planes.iter().find(|p| p.channel == ch).expect("plane");
        deblur_channel_plane(cp, W, H, &source, &DeblurOptions::default(), &job).expect("deblur")
    })
}

/// The warnings about the kind of picture (a JPEG without EXIF is also warned about
/// for the camera it does not record).
fn warnings(stderr: &str) -> Vec<&str> {
    stderr
        .lines()
        .filter(|l| l.starts_with("lensblur: warning:") && l.contains("was measured on"))
        .collect()
}

#[test]
fn a_jpeg_deblurred_with_a_raw_profile_is_warned_about_and_never_made_worse() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (sharp, blurry) = scene();
    let profile = raw_profile();
    assert_eq!(profile.measured_on, Some(PictureKind::Raw));
    let profile_path = dir.path().join("raw.profile.json");
    profile.save(&profile_path).expect("save profile");

    // The camera's JPEG: its RAW file developed, then compressed; the sharp scene
    // developed the same way is what it should come back to.
    let (raw, sharp_raw) = (dir.path().join("shot.dng"), dir.path().join("sharp.dng"));
    write_raw(&raw, &blurry);
    write_raw(&sharp_raw, &sharp);
    let camera_jpeg = dir.path().join("camera.jpg");
    write_jpeg(&camera_jpeg, &developed(&raw), 90);
    let sharp_developed = decoded(&developed(&sharp_raw));
    // A linear photo honestly sRGB-encoded into a JPEG, against the linear scene.
    let encoded_jpeg = dir.path().join("encoded.jpg");
    let rgb: Vec<u8> = (0..W * H * 3)
        .map(|i| {
            let v = blurry[i % 3].data[i / 3].clamp(0.0, 1.0);
            (srgb_encode(v) * 255.0).round() as u8
        })
        .collect();
    write_jpeg(&encoded_jpeg, &rgb, 95);

    let mut figures = Vec::new();
    for (name, photo, truth) in [
        ("camera JPEG", &camera_jpeg, &sharp_developed),
        ("sRGB-encoded JPEG", &encoded_jpeg, &sharp),
    ] {
        let out = dir.path().join(format!("{}.png", name.replace(' ', "_")));
        let (result, stderr) = deblur_command(photo, &profile_path, &out);
        let said = warnings(&stderr);
        assert_eq!(said.len(), 1, "{name}: one warning: {stderr}");
        for words in [
            "developed 8-bit picture",
            "measured on RAW files",
            "calibrate from its JPEGs of the chart",
        ] {
            assert!(said[0].contains(words), "{name}: '{words}' in {}", said[0]);
        }
        let before = mean_ssim(&loaded(photo), truth);
        let after = mean_ssim(&result, truth);
        let tuned = mean_ssim(&at_tuned_strength(photo, &profile), truth);
        eprintln!("{name}: SSIM {before:.4} -> {after:.4} (at the tuned strength {tuned:.4})");
        eprintln!("  {}", said[0]);
        figures.push((name, before, after));
        // At the tuned strength the camera's JPEG came out worse than it went in
        // (its zipper and blocks amplified); held back, it does not.
        assert!(
            after > tuned,
            "{name}: {after} at its own noise vs {tuned} tuned"
        );
        assert!(
            after >= before,
            "{name}: made worse, SSIM {before} -> {after}"
        );
    }
    // The honest encoding keeps the lens's blur: it is deblurred for real.
    let (_, before, after) = figures[1];
    assert!(
        after > before + 0.03,
        "sRGB-encoded JPEG: SSIM {before} -> {after}"
    );

    // The same photo's RAW file is what the profile is for: no warning.
    let (_, stderr) = deblur_command(&raw, &profile_path, &dir.path().join("raw.png"));
    assert!(warnings(&stderr).is_empty(), "{stderr}");
}

#[test]
fn a_profile_from_before_it_recorded_its_shots_is_taken_for_a_raw_one() {
    let mut json: serde_json::Value =
        serde_json::from_slice(&raw_profile().to_json().expect("json")).expect("parse");
    assert_eq!(json["measured_on"], "raw");
    json.as_object_mut().expect("object").remove("measured_on");
    let old = Profile::from_json(&json.to_string(), "old.json").expect("an old profile loads");
    assert_eq!(old.measured_on, None);
    assert_eq!(old.measured_on(), PictureKind::Raw);
    let w = old
        .picture_warning(PictureKind::Developed, "p.jpg", "old.json")
        .expect("a JPEG is warned about");
    assert!(w.contains("taken for a RAW profile"), "{w}");
    assert!(
        old.picture_warning(PictureKind::Linear, "p.png", "old.json")
            .is_none()
    );
    // A profile of developed pictures warns about RAW files the other way round.
    let jpeg_profile = Profile {
        measured_on: Some(PictureKind::Developed),
        ..old
    };
    let w = jpeg_profile
        .picture_warning(PictureKind::Raw, "p.dng", "jpeg.json")
        .expect("a RAW file is warned about");
    assert!(w.contains("calibrate from RAW files"), "{w}");
}

/// `planes` with a sensor's shot and read noise added: Gaussian of variance
/// v / full well + (read / full well)², white 1, in electrons at white.
fn with_sensor_noise(planes: &[Plane; 3], full_well_e: f64, read_e: f64, seed: u64) -> [Plane; 3] {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).expect("σ > 0");
    planes.clone().map(|mut p| {
        for v in &mut p.data {
            let var = f64::from(v.max(0.0)) / full_well_e + (read_e / full_well_e).powi(2);
            *v += (var.sqrt() * unit.sample(&mut rng)) as f32;
        }
        p
    })
}

/// Each CFA plane of `cap` against the same plane of `truth` (the same sites).
fn cfa_ssim(
    cap: &lensblur::plane::Capture,
    planes: &[Plane],
    truth: &lensblur::plane::Capture,
) -> f64 {
    planes
        .iter()
        .zip(&truth.planes)
        .map(|(p, t)| ssim(p, &t.plane, &SsimParams::default()))
        .sum::<f64>()
        / cap.planes.len() as f64
}

/// A RAW photo's regularisation follows the noise measured on its own CFA planes: a
/// clean one (σ 0.003, base ISO) keeps the tuned strength and so exactly the result it
/// had, a noisy one (a high ISO's shot and read noise) is held back and comes out
/// closer to the sharp scene than at the tuned strength.
#[test]
fn a_noisy_raw_photo_is_held_back_and_a_clean_one_keeps_its_strength() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (sharp, blurry) = scene();
    let profile = raw_profile();
    let truth_path = dir.path().join("sharp.dng");
    write_raw(&truth_path, &sharp);
    let truth = load_capture(&truth_path, &LoadOptions::default()).expect("load");
    // About ISO 6400 on a full-frame sensor: 500 electrons at white, 2 e⁻ read noise.
    let grainy = with_sensor_noise(&blurry, 500.0, 2.0, 51);
    let job = JobContext::silent();
    for (name, planes) in [("clean RAW", &blurry), ("noisy RAW", &grainy)] {
        let path = dir.path().join(format!("{}.dng", name.replace(' ', "_")));
        write_raw(&path, planes);
        let cap = load_capture(&path, &LoadOptions::default()).expect("load");
        assert!(cap.is_raw && cap.planes.len() == 4);
        // The noise as added, over the CFA sites: what the estimate should find.
        let added = planes
            .iter()
            .zip(&blurry)
            .flat_map(|(p, b)| p.data.iter().zip(&b.data).map(|(x, y)| f64::from(x - y)))
            .map(|d| d * d)
            .sum::<f64>();
        let true_sigma = (0.003f64.powi(2) + added / (3 * W * H) as f64).sqrt();
        let noise = lensblur::deblur::noise::estimate(&cap);
        let source = ProfileKernels::new(profile.clone(), SETTING);
        let held = lensblur::deblur::deblur_capture(&cap, &source, &DeblurOptions::default(), &job)
            .expect("deblur");
        let held: Vec<Plane> = held.planes.into_iter().map(|p| p.plane).collect();
        // What a RAW photo got before its noise was measured: the tuned strength.
        let tuned: Vec<Plane> = cap
            .planes
            .iter()
            .map(|cp| {
                deblur_channel_plane(cp, W, H, &source, &DeblurOptions::default(), &job)
                    .expect("deblur")
            })
            .collect();
        let original: Vec<Plane> = cap.planes.iter().map(|p| p.plane.clone()).collect();
        let before = cfa_ssim(&cap, &original, &truth);
        let (after, at_tuned) = (
            cfa_ssim(&cap, &held, &truth),
            cfa_ssim(&cap, &tuned, &truth),
        );
        eprintln!(
            "{name}: σ {true_sigma:.4}, estimated {:.4} (data weight {:.3}); SSIM {before:.4} -> {after:.4} (at the tuned strength {at_tuned:.4})",
            noise.random,
            noise.data_weight()
        );
        if name == "clean RAW" {
            // Read below the tuned level, so the tuned strength, as before.
            assert_eq!(noise.data_weight(), 1.0, "{name}: {noise:?}");
            assert!(
                (after - at_tuned).abs() < 1e-6,
                "{name}: {after} vs {at_tuned}"
            );
            assert!(after > before + 0.03, "{name}: SSIM {before} -> {after}");
        } else {
            assert!(
                (noise.random / true_sigma - 1.0).abs() < 0.15,
                "{name}: estimated {noise:?} for σ {true_sigma}"
            );
            assert!(
                after > at_tuned + 0.02,
                "{name}: {after} at its own noise vs {at_tuned} tuned"
            );
            assert!(
                after >= before,
                "{name}: made worse, SSIM {before} -> {after}"
            );
        }
    }
}
