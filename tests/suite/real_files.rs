//! Real camera files (tests/data/real/, SOURCES.md there) against LibRaw's reading of
//! them (`libraw.tsv`, written by scripts/libraw_reading.py): every file LibRaw decodes
//! to a picture, lensblur reads with the same size, CFA and levels; every file without
//! its picture (stripped, zeroed, cut short) is refused in one line that says why. And
//! the refusals a photographer meets, each made from a real file in the test.

use lensblur::raw::{Decoder, LoadError, decode_raw_with, inspect, inspect_bytes};
use std::path::{Path, PathBuf};

fn real(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/real")
        .join(name)
}

/// One row of `libraw.tsv`.
struct Reading {
    file: String,
    status: String,
    size: Option<(usize, usize)>,
    cfa: Option<String>,
    black: Option<[u16; 4]>,
    white: Option<u16>,
}

fn libraw_readings() -> Vec<Reading> {
    let text = std::fs::read_to_string(real("libraw.tsv")).expect("libraw.tsv");
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("file\t"))
        .map(|l| {
            let f: Vec<&str> = l.split('\t').collect();
            assert_eq!(f.len(), 7, "libraw.tsv row: {l}");
            let dash = |s: &str| (s != "-").then(|| s.to_string());
            Reading {
                file: f[0].into(),
                status: f[1].into(),
                size: dash(f[2]).map(|w| (w.parse().unwrap(), f[3].parse().unwrap())),
                cfa: dash(f[4]),
                black: dash(f[5]).map(|b| {
                    let v: Vec<u16> = b.split(' ').map(|x| x.parse().unwrap()).collect();
                    [v[0], v[1], v[2], v[3]]
                }),
                white: dash(f[6]).map(|w| w.parse().unwrap()),
            }
        })
        .collect()
}

/// An error as the command line prints it: one line, naming the file.
fn one_line(e: &LoadError, file: &Path) -> String {
    let m = e.to_string();
    assert!(!m.contains('\n'), "{m}");
    assert!(m.starts_with(&file.display().to_string()), "{m}");
    assert!(!m.to_lowercase().contains("panic"), "{m}");
    m
}

#[test]
fn every_file_libraw_reads_lensblur_reads_alike_and_the_rest_are_refused_saying_why() {
    let readings = libraw_readings();
    assert!(readings.len() >= 10, "{} rows", readings.len());
    let mut pictures = 0;
    for r in &readings {
        let path = real(&r.file);
        let got = inspect(&path);
        if r.status == "image" {
            pictures += 1;
            let info =
                got.unwrap_or_else(|e| panic!("{}: LibRaw reads it, we do not: {e}", r.file));
            assert_eq!(Some((info.width, info.height)), r.size, "{}", r.file);
            assert_eq!(info.cfa, r.cfa, "{}", r.file);
            assert_eq!(info.black, r.black, "{}", r.file);
            assert_eq!(info.white, r.white, "{}", r.file);
        } else {
            let e = got.expect_err(&r.file);
            let m = one_line(&e, &path);
            // LibRaw decodes a blank: we say there is no picture, or locate the damage.
            assert!(
                matches!(e, LoadError::NoImage { .. } | LoadError::Damaged { .. })
                    || (r.status.starts_with("refused") && matches!(e, LoadError::Corrupt { .. })),
                "{}: LibRaw {}, we: {m}",
                r.file,
                r.status
            );
        }
    }
    assert_eq!(pictures, 2);
}

#[test]
fn decoders_compared_on_the_real_files() {
    // Which decoder reads which picture, alone: rawler reads both; rawloader neither
    // (it knows no 14-bit uncompressed DNG, nor lossy DNG's compression 34892); our
    // own reader neither (16-bit uncompressed only).
    let mut reads = std::collections::BTreeMap::new();
    for r in libraw_readings() {
        let bytes = std::fs::read(real(&r.file)).unwrap();
        for d in [Decoder::Rawler, Decoder::Rawloader, Decoder::Lensblur] {
            match decode_raw_with(d, &real(&r.file), &bytes) {
                Ok(_) => reads
                    .entry(d.name())
                    .or_insert_with(Vec::new)
                    .push(r.file.clone()),
                Err(e) => eprintln!("{}: {e}", d.name()),
            }
        }
    }
    eprintln!("{reads:?}");
    assert_eq!(
        reads.get("rawler").map(Vec::len),
        Some(2),
        "rawler: {:?}",
        reads.get("rawler")
    );
    assert_eq!(reads.get("rawloader"), None);
    assert_eq!(reads.get("lensblur"), None);
}

#[test]
fn a_real_photo_without_a_chart_reaches_the_detector() {
    let path = real("canon-550d-magic-lantern.dng");
    let capture = lensblur::raw::load_capture(&path, &Default::default()).unwrap();
    let spec = lensblur::chart::ChartSpec::default();
    let job = lensblur::job::JobContext::default();
    let err = lensblur::detect::detect(
        &capture,
        &spec,
        &lensblur::detect::DetectParams::default(),
        &job,
    )
    .expect_err("a colour chart is not lensblur's chart");
    assert!(err.to_string().contains("no chart"), "{err}");
}

#[test]
fn a_cut_short_copy_says_where_it_was_cut() {
    let path = real("canon-550d-magic-lantern.dng");
    let bytes = std::fs::read(&path).unwrap();
    let cut = &bytes[..2_000_000];
    let e = inspect_bytes(&path, cut).unwrap_err();
    let m = one_line(&e, &path);
    assert!(matches!(e, LoadError::Damaged { .. }), "{m}");
    assert!(m.contains("truncated at byte 2000000"), "{m}");
    assert!(m.contains(&format!("runs to byte {}", bytes.len())), "{m}");
    assert!(
        m.ends_with("copy it again from the card or the camera"),
        "{m}"
    );
}

#[test]
fn a_tag_past_the_end_is_named() {
    let path = real("canon-550d-magic-lantern.dng");
    let mut bytes = std::fs::read(&path).unwrap();
    // Point IFD0's Make (tag 271, an ASCII string of more than 4 bytes) past the end.
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes(bytes[ifd..ifd + 2].try_into().unwrap()) as usize;
    let entry = (0..n)
        .map(|k| ifd + 2 + 12 * k)
        .find(|&e| u16::from_le_bytes(bytes[e..e + 2].try_into().unwrap()) == 271)
        .expect("a Make tag");
    let past = (bytes.len() as u32 + 1000).to_le_bytes();
    bytes[entry + 8..entry + 12].copy_from_slice(&past);
    let e = inspect_bytes(&path, &bytes).unwrap_err();
    let m = one_line(&e, &path);
    assert!(matches!(e, LoadError::Damaged { .. }), "{m}");
    assert!(m.contains("tag 271 points past the end"), "{m}");
}

/// The Magic Lantern DNG with its one strip's samples all zero: what a DNG whose data
/// was never written decodes to.
fn zeroed_dng() -> Vec<u8> {
    let mut bytes = std::fs::read(real("canon-550d-magic-lantern.dng")).unwrap();
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes(bytes[ifd..ifd + 2].try_into().unwrap()) as usize;
    let tag = |want: u16| {
        (0..n)
            .map(|k| ifd + 2 + 12 * k)
            .find(|&e| u16::from_le_bytes(bytes[e..e + 2].try_into().unwrap()) == want)
            .map(|e| u32::from_le_bytes(bytes[e + 8..e + 12].try_into().unwrap()) as usize)
            .unwrap()
    };
    let (offset, count) = (tag(273), tag(279));
    bytes[offset..offset + count].fill(0);
    bytes
}

#[test]
fn a_dng_whose_image_is_zeros_or_missing_is_refused() {
    let path = real("canon-550d-magic-lantern.dng");
    let e = inspect_bytes(&path, &zeroed_dng()).unwrap_err();
    let m = one_line(&e, &path);
    assert!(matches!(e, LoadError::NoImage { .. }), "{m}");
    assert!(m.contains("same value"), "{m}");
    // Loading it for measurement refuses it the same way.
    assert!(matches!(
        lensblur::raw::decode_capture(&path, &zeroed_dng(), &Default::default()),
        Err(LoadError::NoImage { .. })
    ));
    // A DNG whose tiles were cut out (LibRaw decodes it to zeros).
    let path = real("canon-350d-zero-image.dng");
    let e = inspect(&path).unwrap_err();
    let m = one_line(&e, &path);
    assert!(matches!(e, LoadError::NoImage { .. }), "{m}");
    assert!(m.contains("1 of the 140 tiles"), "{m}");
}

#[test]
fn an_unknown_camera_is_named_with_what_to_do() {
    // The D70's NEF with its model renamed to a camera that does not exist.
    let path = real("nikon-d70-stripped.nef");
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes
        .windows(9)
        .position(|w| w == b"NIKON D70")
        .expect("the model string");
    bytes[at..at + 9].copy_from_slice(b"NIKON Z99");
    let e = inspect_bytes(&path, &bytes).unwrap_err();
    let m = one_line(&e, &path);
    assert!(matches!(e, LoadError::Unsupported { .. }), "{m}");
    assert!(m.contains("NIKON Z99"), "{m}");
    assert!(
        m.contains("Adobe DNG Converter") && m.contains("dnglab convert"),
        "{m}"
    );
}

#[test]
fn a_file_no_decoder_recognises_says_what_to_do() {
    // The D70's NEF with its TIFF header overwritten: no format any decoder knows.
    let path = real("nikon-d70-stripped.nef");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[..8].copy_from_slice(b"NOTARAW!");
    let e = lensblur::raw::decode_raw(&path, &bytes).unwrap_err();
    let m = one_line(&e, &path);
    assert!(matches!(e, LoadError::Corrupt { .. }), "{m}");
    assert!(m.contains("not a RAW format lensblur knows"), "{m}");
    assert!(
        m.contains("Adobe DNG Converter") && m.contains("dnglab convert"),
        "{m}"
    );
}

/// A decoder that stops on a file (it panicked) says what is wrong and what to do,
/// naming the file: the 300D's CRW with one header byte corrupted, not cut short.
fn assert_says_corrupt_header(e: &LoadError, path: &Path) {
    let m = one_line(e, path);
    assert!(matches!(e, LoadError::Corrupt { .. }), "{m}");
    assert!(
        m.contains("its headers hold values that contradict each other")
            && m.contains("copy it from the card again")
            && m.contains("dnglab convert"),
        "{m}"
    );
    assert!(!m.contains("malformed"), "{m}");
}

#[test]
fn a_crw_whose_header_length_is_corrupt_says_so_and_what_to_do() {
    // Its header length's top byte flipped: rawler stops reading the heap it points to.
    let path = real("canon-300d-stripped.crw");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[3] ^= 0xFF;
    assert_says_corrupt_header(&inspect_bytes(&path, &bytes).unwrap_err(), &path);
    let alone = decode_raw_with(Decoder::Rawler, &path, &bytes).unwrap_err();
    assert_says_corrupt_header(&alone, &path);
}

#[test]
fn a_crw_whose_signature_is_corrupt_says_so_and_what_to_do() {
    // "HEAPCCDR" made "\xB7EAPCCDR": rawler no longer knows the format, rawloader still
    // takes it for a CRW and stops in its header.
    let path = real("canon-300d-stripped.crw");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[6] ^= 0xFF;
    assert_says_corrupt_header(&inspect_bytes(&path, &bytes).unwrap_err(), &path);
    let alone = decode_raw_with(Decoder::Rawloader, &path, &bytes).unwrap_err();
    assert_says_corrupt_header(&alone, &path);
}

#[test]
fn info_on_the_command_line() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(["info", "--json"])
        .arg(real("canon-6d-linear-lossy.dng"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["schema"], "lensblur.info/1");
    assert_eq!(v["decoder"], "rawler");
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(1224), Some(816))
    );
    assert_eq!(v["cfa"], serde_json::Value::Null);
    assert_eq!(v["make"], "Canon");

    let dir = tempfile::tempdir().unwrap();
    let zeroed = dir.path().join("zeroed.dng");
    std::fs::write(&zeroed, zeroed_dng()).unwrap();
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .arg("info")
        .arg(&zeroed)
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(bad.stdout.is_empty());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("no image"), "{err}");
}

/// A minimal little-endian TIFF-structured EXIF blob naming the camera (Make, Model).
fn exif_blob(make: &str, model: &str) -> Vec<u8> {
    let mut b = b"II*\0\x08\0\0\0".to_vec();
    let strings = [(271u16, make), (272, model)];
    b.extend_from_slice(&(strings.len() as u16).to_le_bytes());
    let mut data_at = 8 + 2 + 12 * strings.len() + 4;
    let mut data = Vec::new();
    for (tag, s) in strings {
        let bytes = [s.as_bytes(), b"\0"].concat();
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&2u16.to_le_bytes());
        b.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
        b.extend_from_slice(&(data_at as u32).to_le_bytes());
        data_at += bytes.len();
        data.extend_from_slice(&bytes);
    }
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&data);
    b
}

fn channel_means(bytes: &[u8]) -> (u32, u32, [f64; 3]) {
    let img = image::load_from_memory(bytes).unwrap().to_rgb8();
    let mut sum = [0.0; 3];
    for p in img.pixels() {
        for c in 0..3 {
            sum[c] += f64::from(p[c]);
        }
    }
    let n = f64::from(img.width() * img.height());
    (img.width(), img.height(), sum.map(|s| s / n))
}

#[test]
fn a_jpeg_photo_is_written_back_as_a_jpeg_that_looks_like_it() {
    use image::ImageEncoder;
    let (w, h) = (96u32, 64u32);
    let pixels: Vec<u8> = (0..w * h)
        .flat_map(|k| {
            let (x, y) = (k % w, k / w);
            [(40 + 2 * x) as u8, (30 + 3 * y) as u8, 200 - x as u8]
        })
        .collect();
    let mut jpeg = Vec::new();
    let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95);
    enc.set_exif_metadata(exif_blob("Fujifilm", "X-T5"))
        .unwrap();
    enc.write_image(&pixels, w, h, image::ExtendedColorType::Rgb8)
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("photo.jpg");
    std::fs::write(&photo, &jpeg).unwrap();
    let capture = lensblur::raw::load_capture(&photo, &Default::default()).unwrap();
    let out = dir.path().join("out.jpg");
    lensblur::raw::save_like_original(&out, &lensblur::raw::full_planes(&capture), &jpeg).unwrap();
    let written = std::fs::read(&out).unwrap();
    assert!(written.starts_with(&[0xFF, 0xD8]), "a JPEG");
    let exif = lensblur::raw::read_exif(&written);
    assert_eq!(exif.identity.make.as_deref(), Some("Fujifilm"));
    assert_eq!(exif.identity.model.as_deref(), Some("X-T5"));
    let (iw, ih, before) = channel_means(&jpeg);
    let (ow, oh, after) = channel_means(&written);
    assert_eq!((ow, oh), (iw, ih));
    for c in 0..3 {
        // Linear 16-bit written instead would put every mean far darker.
        assert!(
            (after[c] - before[c]).abs() < 0.02 * before[c],
            "{before:?} {after:?}"
        );
    }
}

/// A CinemaDNG frame as Blackmagic cameras record it at 3:1 and above: a CFA image in
/// JPEG tiles coded with the DCT (lossy) where the DNG specification has lossless JPEG.
/// Made here (no such frame is small enough to keep): a little-endian DNG whose first
/// directory is the mosaic, 64 × 32 in two 32 × 32 tiles, each a real baseline JPEG of
/// a mosaic-like pattern (Blackmagic's are 12-bit extended DCT frames: both are DCT).
fn lossy_cinema_dng() -> Vec<u8> {
    let tile = |shift: u32| {
        let px: Vec<u8> = (0..32 * 32)
            .map(|i: u32| ((i % 32) * 5 + (i / 32) * 3 + shift) as u8)
            .collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode(&px, 32, 32, image::ExtendedColorType::L8)
            .unwrap();
        jpeg
    };
    let tiles = [tile(0), tile(40)];
    // (tag, type, count, value or offset): SHORT 3, LONG 4, BYTE 1, ASCII 2.
    let make = b"Blackmagic Design\0";
    let model = b"Blackmagic Pocket Cinema Camera 4K\0";
    let n = 19u16;
    let ifd_end = 8 + 2 + 12 * usize::from(n) + 4;
    let make_at = ifd_end;
    let model_at = make_at + make.len();
    let offsets_at = model_at + model.len();
    let counts_at = offsets_at + 8;
    let first_tile = counts_at + 8;
    let second_tile = first_tile + tiles[0].len();
    let entries: [(u16, u16, u32, u32); 19] = [
        (254, 4, 1, 0),
        (256, 4, 1, 64),
        (257, 4, 1, 32),
        (258, 3, 1, 12),
        (259, 3, 1, 7),
        (262, 3, 1, 32803),
        (271, 2, make.len() as u32, make_at as u32),
        (272, 2, model.len() as u32, model_at as u32),
        (277, 3, 1, 1),
        (284, 3, 1, 1),
        (322, 4, 1, 32),
        (323, 4, 1, 32),
        (324, 4, 2, offsets_at as u32),
        (325, 4, 2, counts_at as u32),
        (33421, 3, 2, 2 | 2 << 16),
        (33422, 1, 4, u32::from_le_bytes([0, 1, 1, 2])),
        (50706, 1, 4, u32::from_le_bytes([1, 4, 0, 0])),
        (50708, 2, model.len() as u32, model_at as u32),
        (50717, 3, 1, 4095),
    ];
    let mut b = b"II*\0\x08\0\0\0".to_vec();
    b.extend(n.to_le_bytes());
    for (tag, kind, count, value) in entries {
        b.extend(tag.to_le_bytes());
        b.extend(kind.to_le_bytes());
        b.extend(count.to_le_bytes());
        b.extend(value.to_le_bytes());
    }
    b.extend(0u32.to_le_bytes());
    b.extend(make);
    b.extend(model);
    for v in [first_tile, second_tile, tiles[0].len(), tiles[1].len()] {
        b.extend((v as u32).to_le_bytes());
    }
    tiles.iter().for_each(|t| b.extend(t));
    b
}

#[test]
fn a_cinema_dng_of_lossy_jpeg_tiles_is_refused_in_plain_words() {
    let path = Path::new("A001_C001_000001.dng");
    let e = inspect_bytes(path, &lossy_cinema_dng()).unwrap_err();
    let m = one_line(&e, path);
    assert!(matches!(e, LoadError::Unsupported { .. }), "{m}");
    assert!(
        m.contains("lossy-compressed") && m.contains("uncompressed or lossless CinemaDNG"),
        "{m}"
    );
    // The decoders' own words stay inside.
    assert!(!m.contains("ljpeg") && !m.contains("DQT"), "{m}");
}
