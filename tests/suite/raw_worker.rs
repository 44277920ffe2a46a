//! RAW decoding in the worker process (`lensblur::raw::Decoding`), end to end through
//! the real `lensblur` executable: the same answers as in process, and a worker that
//! runs out of memory or time turned into one line while the caller goes on.

use lensblur::dng::{DngCompression, DngInfo, DngLayout, dng_bytes};
use lensblur::raw::{Decoding, LoadError, WorkerLimits, decode_raw, with_decoding};
use std::path::Path;
use std::time::Duration;

/// Workers of the command line's executable, with its limits.
pub(crate) fn cli_worker() -> Decoding {
    Decoding::Worker(WorkerLimits::new(env!("CARGO_BIN_EXE_lensblur").into()))
}

/// A simulated lossless-JPEG DNG, `w × h`.
fn dng(w: usize, h: usize) -> Vec<u8> {
    let cfa = lensblur::simulate::camera_like_mosaic(w, h);
    let layout = DngLayout {
        tile: Some(64),
        compression: DngCompression::LosslessJpeg,
    };
    let info = DngInfo::simulated("Lensblur", "Worker", 512, 16383, None, layout);
    dng_bytes(&cfa, w, h, &info)
}

#[test]
fn a_raw_file_decodes_through_the_worker_as_it_does_in_process() {
    let bytes = dng(320, 240);
    let path = Path::new("shot.dng");
    let here = decode_raw(path, &bytes).unwrap();
    let there = with_decoding(&cli_worker(), || decode_raw(path, &bytes)).unwrap();
    assert_eq!((there.width, there.height), (here.width, here.height));
    assert_eq!(there.planes, here.planes);
    assert_eq!((there.identity, there.raw), (here.identity, here.raw));

    // The command line decodes in its worker: `info` says what the library says.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("shot.dng");
    std::fs::write(&file, &bytes).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(["info", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cli: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let lib = serde_json::to_value(lensblur::raw::inspect(&file).unwrap()).unwrap();
    assert_eq!(cli, lib);
}

/// One line naming the file, and a reason that says what became of the decoder.
fn stopped(e: &LoadError, name: &str, what: &str) {
    let m = e.to_string();
    assert!(matches!(e, LoadError::DecoderStopped { .. }), "{m}");
    assert!(
        m.starts_with(name) && m.contains(what) && !m.contains('\n'),
        "{m}"
    );
}

#[test]
fn a_worker_out_of_memory_or_time_is_one_line_and_the_next_file_decodes() {
    let bytes = dng(640, 480);
    let program = env!("CARGO_BIN_EXE_lensblur");
    // A megabyte of address space: the worker's first large allocation fails, which
    // aborts it (no unwinding, nothing a process could catch in itself).
    let starved = Decoding::Worker(WorkerLimits {
        memory_bytes: 1 << 20,
        memory_per_file_byte: 0,
        ..WorkerLimits::new(program.into())
    });
    let e = with_decoding(&starved, || decode_raw(Path::new("big.dng"), &bytes)).unwrap_err();
    stopped(&e, "big.dng", "the RAW decoder ran out of memory on it");

    // No time at all: stopped, and said in seconds.
    let hurried = Decoding::Worker(WorkerLimits {
        time: Duration::ZERO,
        bytes_per_second: u64::MAX,
        ..WorkerLimits::new(program.into())
    });
    let e = with_decoding(&hurried, || decode_raw(Path::new("slow.dng"), &bytes)).unwrap_err();
    stopped(&e, "slow.dng", "took longer than 0 s");

    // The caller goes on: the next file decodes in a fresh worker.
    let c = with_decoding(&cli_worker(), || decode_raw(Path::new("next.dng"), &bytes)).unwrap();
    assert_eq!((c.width, c.height), (640, 480));
}
