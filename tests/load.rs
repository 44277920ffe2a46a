//! Loading: simulated DNGs round-trip bit-exactly (strips and tiles), settings come from
//! EXIF, and every kind of bad file is a one-line error naming it.

use lensblur::chart::ChartSpec;
use lensblur::job::JobContext;
use lensblur::plane::{Capture, LensSetting};
use lensblur::raw::{LoadOptions, load_capture};
use lensblur::simulate::dng::{DngInfo, write_dng};
use lensblur::simulate::{CaptureParams, VirtualLens, simulate_shot};

fn shot() -> (lensblur::simulate::SimulatedShot, CaptureParams) {
    let spec = ChartSpec {
        cols: 6,
        rows: 4,
        ..ChartSpec::default()
    };
    let params = CaptureParams::new(
        200,
        134,
        LensSetting {
            focal_mm: 35.0,
            f_number: 5.6,
        },
    );
    let s = simulate_shot(&spec, &VirtualLens::demo(), &params, &JobContext::silent())
        .expect("simulate");
    (s, params)
}

fn assert_same(a: &Capture, b: &Capture) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    assert_eq!(a.planes.len(), b.planes.len());
    for (p, q) in a.planes.iter().zip(&b.planes) {
        assert_eq!(p.channel, q.channel);
        assert_eq!(
            (p.step, p.offset_x, p.offset_y),
            (q.step, q.offset_x, q.offset_y)
        );
        assert_eq!(p.plane.data.len(), q.plane.data.len());
        // Bit-exact: the same values through the same arithmetic.
        assert!(
            p.plane
                .data
                .iter()
                .zip(&q.plane.data)
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "plane {:?} differs",
            p.channel
        );
    }
}

#[test]
fn simulated_dng_round_trips_bit_exactly() {
    let (s, params) = shot();
    let dir = tempfile::tempdir().expect("temp dir");
    for tile in [None, Some(32)] {
        let path = dir.path().join(format!("shot_{tile:?}.dng"));
        let info = DngInfo {
            make: "lensblur".into(),
            model: "virtual camera".into(),
            black: params.black_level,
            white: params.white_level,
            setting: Some(params.setting),
            tile,
        };
        write_dng(&path, &s.cfa, params.width, params.height, &info).expect("write dng");
        let c = load_capture(&path, &LoadOptions::default())
            .unwrap_or_else(|e| panic!("tiles {tile:?}: {e}"));
        assert!(c.is_raw);
        assert_same(&s.capture, &c);
        assert_eq!(
            c.setting_focal_mm,
            Some(35.0),
            "focal length from EXIF in IFD0"
        );
        assert_eq!(c.setting_f_number, Some(5.6), "f-number from EXIF in IFD0");
        assert_eq!(c.identity.make.as_deref(), Some("lensblur"));
    }
}

#[test]
fn bad_files_are_one_line_errors_naming_the_file() {
    let (s, params) = shot();
    let dir = tempfile::tempdir().expect("temp dir");
    let good = dir.path().join("good.dng");
    let info = DngInfo {
        make: "lensblur".into(),
        model: "virtual camera".into(),
        black: params.black_level,
        white: params.white_level,
        setting: None,
        tile: None,
    };
    write_dng(&good, &s.cfa, params.width, params.height, &info).expect("write");
    let bytes = std::fs::read(&good).expect("read");
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty.dng", Vec::new()),
        (
            "noise.cr2",
            (0..4096u32)
                .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
                .collect(),
        ),
        ("truncated.dng", bytes[..bytes.len() / 3].to_vec()),
        ("header_only.dng", bytes[..64].to_vec()),
        ("truncated.png", {
            let mut png = Vec::new();
            image::GrayImage::new(64, 64)
                .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .expect("png");
            png.truncate(png.len() / 2);
            png
        }),
        ("huge.png", {
            // A valid PNG header claiming 200000 × 200000 pixels.
            let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
            png.extend_from_slice(&200_000u32.to_be_bytes());
            png.extend_from_slice(&200_000u32.to_be_bytes());
            png.extend_from_slice(&[8, 0, 0, 0, 0]);
            png.extend_from_slice(&[0, 0, 0, 0]);
            png
        }),
    ];
    for (name, content) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, content).expect("write case");
        let e = load_capture(&p, &LoadOptions::default())
            .err()
            .unwrap_or_else(|| panic!("{name} loaded"));
        let msg = e.to_string();
        assert!(msg.contains(name), "{name}: '{msg}' does not name the file");
        assert!(!msg.contains('\n'), "{name}: '{msg}' is not one line");
    }
    let missing = dir.path().join("missing.dng");
    assert!(load_capture(&missing, &LoadOptions::default()).is_err());
    // The command line too: non-zero exit and one line on stderr.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args([
            "detect",
            dir.path().join("truncated.dng").to_str().expect("utf-8"),
            "--out",
        ])
        .arg(dir.path().join("d.json"))
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("truncated.dng"), "{err}");
    assert!(
        !dir.path().join("d.json").exists(),
        "nothing written on failure"
    );
}
