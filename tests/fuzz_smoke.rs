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
