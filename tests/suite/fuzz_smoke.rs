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
