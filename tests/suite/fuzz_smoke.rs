//! The fuzz targets' smoke pass: each reader over its seed corpus (files lensblur wrote,
//! `fuzz/seeds/`), every finding the fuzzer made (`fuzz/regressions/`, each fixed),
//! and a bounded set of deterministic mutations of them. The long coverage-guided run
//! is `scripts/fuzz.sh`; this keeps its findings fixed in CI.

use lensblur::fuzz::{Target, mutants};
use std::path::{Path, PathBuf};

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

fn corpus(kind: &str, target: Target) -> Vec<PathBuf> {
    files(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fuzz")
            .join(kind)
            .join(target.name()),
    )
}

#[test]
fn every_seed_is_accepted_and_no_mutant_or_finding_panics() {
    for target in Target::ALL {
        let seeds = corpus("seeds", target);
        assert!(!seeds.is_empty(), "{}: no seed corpus", target.name());
        for (k, seed) in seeds.iter().enumerate() {
            let bytes = std::fs::read(seed).unwrap();
            // A seed is a file lensblur wrote: refusing it is a regression too.
            assert!(
                target.run(&bytes),
                "{}: seed {} refused",
                target.name(),
                seed.display()
            );
            // The heavy image decoders get fewer mutants; the run stays in seconds.
            let n = if matches!(target, Target::Load | Target::Dng) {
                400
            } else {
                1500
            };
            for m in mutants(&bytes, n, k as u64) {
                let _ = target.run(&m);
            }
        }
        for finding in corpus("regressions", target) {
            let _ = target.run(&std::fs::read(&finding).unwrap());
        }
    }
}

/// The fuzzer's one finding: a few-kB lossless-JPEG DNG declaring a huge image made the
/// decoder allocate all of it before finding the data missing. It is now refused
/// first, as truncated, with its size.
#[test]
fn a_compressed_raw_claiming_more_samples_than_it_has_bits_is_refused_before_decoding() {
    let seed = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds/dng/ljpeg.dng");
    let mut b = std::fs::read(seed).unwrap();
    let ifd = u32::from_le_bytes([b[4], b[5], b[6], b[7]]) as usize;
    let n = u16::from_le_bytes([b[ifd], b[ifd + 1]]) as usize;
    for e in 0..n {
        let at = ifd + 2 + 12 * e;
        let tag = u16::from_le_bytes([b[at], b[at + 1]]);
        let typ = u16::from_le_bytes([b[at + 2], b[at + 3]]);
        if tag == 256 || tag == 257 {
            // 16 000 × 16 000: 256 MP, inside the limits, in a 4 kB file.
            let v: u32 = 16_000;
            if typ == 3 {
                b[at + 8..at + 10].copy_from_slice(&(v as u16).to_le_bytes());
            } else {
                b[at + 8..at + 12].copy_from_slice(&v.to_le_bytes());
            }
        }
    }
    let e = lensblur::raw::decode_raw(Path::new("claims.dng"), &b)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("claims.dng") && e.contains("cannot be coded in"),
        "{e}"
    );
}

/// The RAW readers' inputs beyond lensblur's own DNGs: the real camera files small
/// enough to mutate by the thousand (tests/data/real/, every format there: CR2, CR3,
/// CRW, NEF, RAF, MRW, RW2, ARW, DNG), and the DNG seeds.
fn raw_inputs() -> Vec<Vec<u8>> {
    let mut v: Vec<Vec<u8>> = files(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real"))
        .into_iter()
        .filter(|p| !p.extension().is_some_and(|e| e == "md" || e == "tsv"))
        .filter(|p| std::fs::metadata(p).is_ok_and(|m| m.len() < 200_000))
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    v.extend(
        corpus("seeds", Target::Dng)
            .iter()
            .map(|p| std::fs::read(p).unwrap()),
    );
    v
}

/// Mutants of every RAW input through both RAW targets (rawler first, then the
/// fallbacks); `per_target` mutants a target in all. Returns how many each accepted.
fn mutate_raw_inputs(per_target: usize) -> Vec<(Target, usize, usize)> {
    let inputs = raw_inputs();
    let per_input = per_target.div_ceil(inputs.len());
    [Target::Dng, Target::Load]
        .into_iter()
        .map(|target| {
            let (mut ran, mut accepted) = (0, 0);
            for (k, bytes) in inputs.iter().enumerate() {
                for (j, m) in mutants(bytes, per_input, 0x5eed + k as u64)
                    .into_iter()
                    .enumerate()
                {
                    if std::env::var_os("LENSBLUR_FUZZ_TRACE").is_some() {
                        eprintln!("{} input {k} mutant {j}", target.name());
                    }
                    ran += 1;
                    accepted += usize::from(target.run(&m));
                }
            }
            (target, ran, accepted)
        })
        .collect()
}

/// Mutants of the real files once made rawler loop or allocate past the machine's
/// memory inside its own header parsing (an abort, no panic to catch): a box smaller
/// than its header, a table counting more entries than its box holds, a TIFF's chain of
/// directories linking back into itself. Such files are now refused before rawler
/// reads them (`raw::damage::before_decoding`).
#[test]
fn mutated_real_camera_files_never_panic() {
    for (target, ran, _) in mutate_raw_inputs(400) {
        assert!(ran >= 400, "{}: {ran}", target.name());
    }
}

/// The long run: at least 10⁵ mutants per RAW target (`LENSBLUR_FUZZ_N` to change it).
/// `cargo test --release --test suite -- --ignored mutated_real_camera_files_at_length`.
#[test]
#[ignore = "minutes: run by hand"]
fn mutated_real_camera_files_at_length() {
    let n = std::env::var("LENSBLUR_FUZZ_N")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000);
    for (target, ran, accepted) in mutate_raw_inputs(n) {
        eprintln!(
            "{}: {ran} mutants, {accepted} accepted, no panic",
            target.name()
        );
        assert!(ran >= n);
    }
}

fn real(name: &str) -> Vec<u8> {
    std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/real")
            .join(name),
    )
    .unwrap()
}

/// A damaged-file refusal, in one line naming the file and what is wrong.
fn refusal(name: &str, bytes: &[u8]) -> String {
    let e = lensblur::raw::decode_raw(Path::new(name), bytes)
        .map(|_| ())
        .unwrap_err();
    assert!(matches!(e, lensblur::raw::LoadError::Damaged { .. }), "{e}");
    let m = e.to_string();
    assert!(m.starts_with(name) && !m.contains('\n'), "{m}");
    m
}

#[test]
fn a_cr3_whose_sample_table_counts_more_than_its_box_holds_is_refused_naming_the_box() {
    let mut b = real("canon-m50-stripped.cr3");
    // The first track's stsz: one size for its one sample. Made a table of 2^32 - 1
    // sizes (16 GiB for rawler to reserve) in its 12 bytes.
    let at = b.windows(4).position(|w| w == b"stsz").unwrap() + 4;
    b[at + 4..at + 8].copy_from_slice(&0u32.to_be_bytes());
    b[at + 8..at + 12].copy_from_slice(&u32::MAX.to_be_bytes());
    let m = refusal("sizes.cr3", &b);
    assert!(
        m.contains("the 'stsz' box at byte 9321 lists 4294967295 entries"),
        "{m}"
    );
    // A box inside the moov of no size at all: rawler would read it forever.
    let mut b = real("canon-m50-stripped.cr3");
    let at = b.windows(4).position(|w| w == b"mvhd").unwrap() - 4;
    b[at..at + 4].copy_from_slice(&0u32.to_be_bytes());
    let m = refusal("empty.cr3", &b);
    assert!(
        m.contains("'mvhd' box at byte 8788 declares a size of 0 bytes"),
        "{m}"
    );
}

#[test]
fn a_tiff_raw_whose_directories_link_in_a_loop_is_refused() {
    // The D70's NEF, its first directory's link to the next pointed back at itself.
    let mut b = real("nikon-d70-stripped.nef");
    assert_eq!(&b[..2], b"II");
    let ifd = u32::from_le_bytes([b[4], b[5], b[6], b[7]]) as usize;
    let n = u16::from_le_bytes([b[ifd], b[ifd + 1]]) as usize;
    let next = ifd + 2 + 12 * n;
    b[next..next + 4].copy_from_slice(&(ifd as u32).to_le_bytes());
    let m = refusal("loop.nef", &b);
    assert!(
        m.contains(&format!("links back to the one at byte {ifd}")),
        "{m}"
    );
}
