//! Loading: simulated DNGs round-trip bit-exactly in every layout real writers use
//! (strips or tiles, uncompressed or lossless JPEG, strips out of order), settings come
//! from EXIF, and every kind of bad file is a one-line error naming it.

use lensblur::chart::ChartSpec;
use lensblur::dng::{DngCompression, DngInfo, DngLayout, dng_bytes, write_dng};
use lensblur::job::JobContext;
use lensblur::plane::{Capture, LensSetting};
use lensblur::raw::{LoadOptions, load_capture};
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

fn info(params: &CaptureParams, layout: DngLayout) -> DngInfo {
    DngInfo::simulated(
        "lensblur",
        "virtual camera",
        params.black_level,
        params.white_level,
        Some(params.setting),
        layout,
    )
}

#[test]
fn simulated_dng_round_trips_bit_exactly() {
    let (s, params) = shot();
    let dir = tempfile::tempdir().expect("temp dir");
    let mut sizes = Vec::new();
    for compression in [DngCompression::Uncompressed, DngCompression::LosslessJpeg] {
        // 200 × 134 in 32-px tiles: the last column and row of tiles are partial.
        for tile in [None, Some(32)] {
            let layout = DngLayout { tile, compression };
            let path = dir
                .path()
                .join(format!("shot_{tile:?}_{compression:?}.dng"));
            write_dng(
                &path,
                &s.cfa,
                params.width,
                params.height,
                &info(&params, layout),
            )
            .expect("write dng");
            let c = load_capture(&path, &LoadOptions::default())
                .unwrap_or_else(|e| panic!("{layout:?}: {e}"));
            assert!(c.is_raw);
            assert_same(&s.capture, &c);
            assert_eq!(
                c.setting_focal_mm,
                Some(35.0),
                "focal length from EXIF in IFD0"
            );
            assert_eq!(c.setting_f_number, Some(5.6), "f-number from EXIF in IFD0");
            assert_eq!(c.identity.make.as_deref(), Some("lensblur"));
            sizes.push((layout, std::fs::metadata(&path).expect("stat").len()));
        }
    }
    // The lossless-JPEG files are really compressed, not stored.
    let raw_size = (2 * params.width * params.height) as u64;
    for (layout, size) in sizes {
        if layout.compression == DngCompression::LosslessJpeg {
            assert!(size < raw_size, "{layout:?}: {size} bytes, {raw_size} raw");
        }
    }
}

/// Little-endian u32 at `at`.
fn u32_le(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

#[test]
fn strips_out_of_order_are_read_where_they_are() {
    let (s, params) = shot();
    let bytes = dng_bytes(
        &s.cfa,
        params.width,
        params.height,
        &info(&params, DngLayout::default()),
    );
    // Find StripOffsets (273) and StripByteCounts (279) in IFD0: three strips of at most
    // 64 rows, so both are arrays stored out of line.
    let ifd = u32_le(&bytes, 4) as usize;
    let n = usize::from(u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]));
    let entry = |tag: u16| {
        (0..n)
            .map(|e| ifd + 2 + 12 * e)
            .find(|&at| u16::from_le_bytes([bytes[at], bytes[at + 1]]) == tag)
            .map(|at| {
                (
                    u32_le(&bytes, at + 4) as usize,
                    u32_le(&bytes, at + 8) as usize,
                )
            })
            .expect("tag present")
    };
    let (strips, offsets_at) = entry(273);
    let (_, counts_at) = entry(279);
    assert_eq!(strips, 3);
    // Move the first strip to the end of the file and overwrite where it was: a reader
    // that assumes strips follow one another reads garbage.
    let (first, count) = (
        u32_le(&bytes, offsets_at) as usize,
        u32_le(&bytes, counts_at) as usize,
    );
    let mut moved = bytes.clone();
    let new_offset = moved.len() as u32;
    moved.extend_from_slice(&bytes[first..first + count]);
    moved[offsets_at..offsets_at + 4].copy_from_slice(&new_offset.to_le_bytes());
    moved[first..first + count].fill(0xAB);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("moved.dng");
    std::fs::write(&path, moved).expect("write");
    let c = load_capture(&path, &LoadOptions::default()).expect("load");
    assert_same(&s.capture, &c);
}

#[test]
fn bad_files_are_one_line_errors_naming_the_file() {
    let (s, params) = shot();
    let dir = tempfile::tempdir().expect("temp dir");
    let good = dir.path().join("good.dng");
    write_dng(
        &good,
        &s.cfa,
        params.width,
        params.height,
        &info(&params, DngLayout::default()),
    )
    .expect("write");
    let bytes = std::fs::read(&good).expect("read");
    let tiles_of = |compression| {
        let layout = DngLayout {
            tile: Some(32),
            compression,
        };
        dng_bytes(&s.cfa, params.width, params.height, &info(&params, layout))
    };
    let ljpeg = tiles_of(DngCompression::LosslessJpeg);
    let tiled = tiles_of(DngCompression::Uncompressed);
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
        // The directory sits after the samples; cutting into it or into the samples.
        (
            "truncated_ljpeg.dng",
            ljpeg[..ljpeg.len() * 9 / 10].to_vec(),
        ),
        ("ljpeg_samples_cut.dng", {
            // Keep the directory, zero the second half of the coded tiles.
            let mut b = ljpeg.clone();
            let ifd = u32_le(&b, 4) as usize;
            b[ifd / 2..ifd].fill(0);
            b
        }),
        ("truncated_tiles.dng", {
            let mut b = tiled.clone();
            let ifd = u32_le(&b, 4) as usize;
            // Point the directory at a copy placed early, then drop the samples after it.
            let dir_and_values = b[ifd..].to_vec();
            b.truncate(ifd / 2);
            let new_ifd = b.len() as u32;
            // Offsets of out-of-line values move with the directory.
            let shift = ifd as i64 - i64::from(new_ifd);
            let mut d = dir_and_values;
            let n = usize::from(u16::from_le_bytes([d[0], d[1]]));
            for e in 0..n {
                let at = 2 + 12 * e;
                let typ = u16::from_le_bytes([d[at + 2], d[at + 3]]);
                let count = u32_le(&d, at + 4) as usize;
                let size = [0, 1, 1, 2, 4, 8, 1, 1, 2, 4, 8][usize::from(typ).min(10)];
                if size * count > 4 {
                    let v = (i64::from(u32_le(&d, at + 8)) - shift) as u32;
                    d[at + 8..at + 12].copy_from_slice(&v.to_le_bytes());
                }
            }
            b.extend_from_slice(&d);
            b[4..8].copy_from_slice(&new_ifd.to_le_bytes());
            b
        }),
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
