//! The fuzz targets' smoke pass: each reader over its seed corpus (files lensblur wrote,
//! `fuzz/seeds/`), every finding the fuzzer made (`fuzz/regressions/`, each fixed),
//! and a bounded set of deterministic mutations of them. The long coverage-guided run
//! is `scripts/fuzz.sh`; this keeps its findings fixed in CI.

use crate::raw_worker::cli_worker;
use lensblur::fuzz::{Target, mutants};
use lensblur::raw::{
    Decoding, LoadError, LoadOptions, WorkerLimits, decode_capture, decode_raw, with_decoding,
};
use std::collections::BTreeMap;
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

/// The RAW targets decode in the command line's worker, as the program does: in
/// process, a mutant that makes a decoder abort would take the test binary with it.
#[test]
fn every_seed_is_accepted_and_no_mutant_or_finding_panics() {
    with_decoding(&cli_worker(), every_seed_and_mutant);
}

fn every_seed_and_mutant() {
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

/// The RAW readers' inputs beyond lensblur's own DNGs, each with its container (its
/// extension): the real camera files small enough to mutate by the thousand
/// (tests/data/real/, every format there: CR2, CR3, CRW, NEF, RAF, MRW, RW2, ARW, DNG),
/// and the DNG seeds.
fn raw_inputs() -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<PathBuf> = files(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real"))
        .into_iter()
        .filter(|p| !p.extension().is_some_and(|e| e == "md" || e == "tsv"))
        .filter(|p| std::fs::metadata(p).is_ok_and(|m| m.len() < 200_000))
        .collect();
    v.extend(corpus("seeds", Target::Dng));
    v.into_iter()
        .map(|p| {
            let ext = p.extension().unwrap().to_string_lossy().to_lowercase();
            (ext, std::fs::read(p).unwrap())
        })
        .collect()
}

/// What became of one container's mutants.
#[derive(Debug, Default)]
struct Tally {
    mutants: usize,
    decoded: usize,
    refused: usize,
    /// Refusals that were a worker's death (memory, time, crash) said in one line.
    worker_stopped: usize,
}

/// `per_container` mutants of each container's inputs through `targets`' readers, in
/// `decoding`'s worker: each is decoded, or refused in one line naming the file.
/// `LENSBLUR_FUZZ_TRACE` prints each refusal as it comes; `LENSBLUR_FUZZ_ONLY=raf,nef`
/// keeps those containers, so a long run can be split over processes.
fn mutate_raw_inputs(
    decoding: &Decoding,
    targets: &[Target],
    per_container: usize,
) -> BTreeMap<String, Tally> {
    let only = std::env::var("LENSBLUR_FUZZ_ONLY").ok();
    let inputs: Vec<(String, Vec<u8>)> = raw_inputs()
        .into_iter()
        .filter(|(ext, _)| {
            only.as_deref()
                .is_none_or(|o| o.split(',').any(|x| x == ext))
        })
        .collect();
    let mut tallies: BTreeMap<String, Tally> = BTreeMap::new();
    let trace = std::env::var_os("LENSBLUR_FUZZ_TRACE").is_some();
    with_decoding(decoding, || {
        for (k, (ext, bytes)) in inputs.iter().enumerate() {
            let of_kind = inputs.iter().filter(|(e, _)| e == ext).count();
            let n = per_container.div_ceil(of_kind);
            for (j, m) in mutants(bytes, n, 0x5eed + k as u64).enumerate() {
                for &target in targets {
                    let name = format!("mutant-{}-{k}-{j}.{ext}", target.name());
                    let path = Path::new(&name);
                    let result = match target {
                        Target::Dng => decode_raw(path, &m).map(drop),
                        _ => decode_capture(path, &m, &LoadOptions::default()).map(drop),
                    };
                    let t = tallies.entry(ext.clone()).or_default();
                    t.mutants += 1;
                    match result {
                        Ok(()) => t.decoded += 1,
                        Err(e) => {
                            let line = e.to_string();
                            assert!(line.starts_with(&name) && !line.contains('\n'), "{line}");
                            t.refused += 1;
                            t.worker_stopped +=
                                usize::from(matches!(e, LoadError::DecoderStopped { .. }));
                            if trace {
                                eprintln!("{line}");
                            }
                        }
                    }
                }
            }
        }
    });
    tallies
}

/// Mutants of the real files through the command line's worker: each decoded or
/// refused in one line, this process alive at the end whatever they did to the worker
/// (some once made rawler loop, or allocate past the machine's memory, or abort).
#[test]
fn mutated_real_camera_files_are_decoded_or_refused_in_one_line() {
    let tallies = mutate_raw_inputs(&cli_worker(), &[Target::Dng, Target::Load], 24);
    for (ext, t) in &tallies {
        assert!(
            t.mutants >= 48 && t.decoded + t.refused == t.mutants,
            "{ext}: {t:?}"
        );
    }
    assert!(tallies.len() >= 9, "{:?}", tallies.keys());
}

/// The long run: `LENSBLUR_FUZZ_N` mutants per container (2.5 × 10⁵ unless said)
/// through the whole load path, in workers under the command line's 4 GB limit and a
/// time limit of `LENSBLUR_FUZZ_SECONDS` (10 unless said). Prints each container's
/// tally; the parent's abort would end the run without it.
/// `cargo test --test suite -- --ignored --nocapture mutated_real_camera_files_at_length`.
#[test]
#[ignore = "hours: run by hand"]
fn mutated_real_camera_files_at_length() {
    let number = |name: &str, default: u64| {
        std::env::var(name)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let n = number("LENSBLUR_FUZZ_N", 250_000) as usize;
    let mut limits = WorkerLimits::new(env!("CARGO_BIN_EXE_lensblur").into());
    limits.time = std::time::Duration::from_secs(number("LENSBLUR_FUZZ_SECONDS", 10));
    let tallies = mutate_raw_inputs(&Decoding::Worker(limits), &[Target::Load], n);
    for (ext, t) in &tallies {
        eprintln!(
            "{ext}: {} mutants, {} decoded, {} refused in one line ({} of them a worker stopped), parent alive",
            t.mutants, t.decoded, t.refused, t.worker_stopped
        );
        assert!(t.mutants >= n);
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

/// The files that once made rawler allocate past the machine's memory or read the same
/// bytes forever, inside its own parsing (an abort or a hang: nothing a process can
/// catch in itself). Through the command line's worker (with 5 s for a decode, far
/// more than these few-kB files need) each is one line naming the file, whatever the
/// decoder did; and the next file decodes.
#[test]
fn files_that_once_took_the_process_down_are_one_line_each_through_the_worker() {
    let mut hazards = Vec::new();
    // The first track's stsz: one size for its one sample. Made a table of 2^32 - 1
    // sizes (16 GiB for rawler to reserve) in its 12 bytes.
    let mut b = real("canon-m50-stripped.cr3");
    let at = b.windows(4).position(|w| w == b"stsz").unwrap() + 4;
    b[at + 4..at + 8].copy_from_slice(&0u32.to_be_bytes());
    b[at + 8..at + 12].copy_from_slice(&u32::MAX.to_be_bytes());
    hazards.push(("sizes.cr3", b));
    // A box inside the moov of no size at all.
    let mut b = real("canon-m50-stripped.cr3");
    let at = b.windows(4).position(|w| w == b"mvhd").unwrap() - 4;
    b[at..at + 4].copy_from_slice(&0u32.to_be_bytes());
    hazards.push(("empty.cr3", b));
    // The D70's NEF, its first directory's link to the next pointed back at itself.
    let mut b = real("nikon-d70-stripped.nef");
    let ifd = u32::from_le_bytes([b[4], b[5], b[6], b[7]]) as usize;
    let n = u16::from_le_bytes([b[ifd], b[ifd + 1]]) as usize;
    let next = ifd + 2 + 12 * n;
    b[next..next + 4].copy_from_slice(&(ifd as u32).to_le_bytes());
    hazards.push(("loop.nef", b));

    let mut limits = WorkerLimits::new(env!("CARGO_BIN_EXE_lensblur").into());
    limits.time = std::time::Duration::from_secs(5);
    with_decoding(&Decoding::Worker(limits), || {
        for (name, bytes) in &hazards {
            let e = decode_raw(Path::new(name), bytes).map(drop).unwrap_err();
            let m = e.to_string();
            eprintln!("{m}");
            assert!(m.starts_with(name) && !m.contains('\n'), "{m}");
        }
        let whole = real("nikon-d70-stripped.nef");
        let next = decode_capture(Path::new("next.nef"), &whole, &LoadOptions::default());
        // Whatever the stripped file decodes to, it is answered, not lost with a worker.
        assert!(
            !matches!(next, Err(LoadError::DecoderStopped { .. })),
            "{next:?}"
        );
    });
}
