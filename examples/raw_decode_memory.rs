//! The peak memory of decoding one 24 MP DNG, for `/usr/bin/time -v`: writing the file
//! and reading it are separate runs, so the reading run holds only what decoding it
//! takes (the file's bytes, the decoder's image, the planes). `chain` and `worker=`
//! load the file as the command line does (`load_capture`: in a worker, the worker
//! reads the file itself and hands back the 16-bit mosaic).
//!
//! Usage:
//!   cargo run --example raw_decode_memory -- write FILE.dng uncompressed|ljpeg
//!   /usr/bin/time -v target/debug/examples/raw_decode_memory read FILE.dng chain|rawloader
//!   target/debug/examples/raw_decode_memory read FILE.dng worker=target/debug/lensblur
//!
//! The mosaic is the one `benches/raw_decode.rs` times; `chain` is what `load_capture`
//! runs (rawler first), `rawloader` the decoder alone (the chain before rawler),
//! `worker=PROGRAM` the chain in a worker process of that `lensblur` executable (what
//! the command line and the studio do). Each read prints this process's own peak
//! resident memory (VmHWM): `time -v` would report the worker's where it is larger.
use anyhow::{Context, bail};
use lensblur::dng::{DngCompression, DngInfo, DngLayout, dng_bytes};
use lensblur::raw::{
    Decoder, Decoding, LoadOptions, WorkerLimits, decode_raw_with, load_capture, with_decoding,
};
use std::path::Path;

/// The 6000 × 4000 RGGB mosaic both the decoding benchmark and the memory example use.
fn mosaic_24mp() -> (Vec<u16>, usize, usize) {
    let (w, h) = (6000, 4000);
    (lensblur::simulate::camera_like_mosaic(w, h), w, h)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [mode, file, kind] = args.as_slice() else {
        bail!("usage: raw_decode_memory write|read FILE.dng uncompressed|ljpeg|chain|rawloader");
    };
    let path = Path::new(file);
    match (mode.as_str(), kind.as_str()) {
        ("write", layout) => {
            let layout = match layout {
                "uncompressed" => DngLayout {
                    tile: None,
                    compression: DngCompression::Uncompressed,
                },
                "ljpeg" => DngLayout {
                    tile: Some(256),
                    compression: DngCompression::LosslessJpeg,
                },
                other => bail!("unknown layout {other}"),
            };
            let (cfa, w, h) = mosaic_24mp();
            let info = DngInfo::simulated("Lensblur", "Bench", 512, 16383, None, layout);
            std::fs::write(path, dng_bytes(&cfa, w, h, &info))
                .with_context(|| path.display().to_string())?;
        }
        ("read", decoder) => {
            let options = LoadOptions::default();
            let capture = match decoder {
                "chain" => load_capture(path, &options)?,
                "rawloader" => {
                    let bytes = std::fs::read(path).with_context(|| path.display().to_string())?;
                    decode_raw_with(Decoder::Rawloader, path, &bytes)?
                }
                other => match other.strip_prefix("worker=") {
                    Some(program) => {
                        let worker = Decoding::Worker(WorkerLimits::new(program.into()));
                        with_decoding(&worker, || load_capture(path, &options))?
                    }
                    None => bail!("unknown decoder {other}"),
                },
            };
            println!(
                "{}: {} × {}, {} planes",
                path.display(),
                capture.width,
                capture.height,
                capture.planes.len()
            );
            let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
            if let Some(peak) = status.lines().find(|l| l.starts_with("VmHWM:")) {
                println!("this process's peak resident memory: {}", peak[6..].trim());
            }
        }
        (other, _) => bail!("unknown mode {other}"),
    }
    Ok(())
}
