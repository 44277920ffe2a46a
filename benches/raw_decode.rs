//! Decoding a 24 MP RAW file: the decoder chain `load_capture` runs now (rawler first),
//! in this process and in the worker process the command line and the studio use (the
//! `lensblur` executable: it reads the file itself and hands the 16-bit mosaic back),
//! against rawloader alone (the chain before rawler came in), on the two DNG forms a
//! camera or Adobe's converter writes: uncompressed strips and lossless-JPEG tiles.
//! `load/*` reads the file (from the page cache: it was just written), EXIF included,
//! as the command line does; `new_chain/*` and `rawloader_alone` decode bytes already in
//! memory (through a worker, those bytes go through its pipe).

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::dng::{DngCompression, DngInfo, DngLayout, dng_bytes};
use lensblur::raw::{
    Decoder, Decoding, LoadOptions, WorkerLimits, decode_raw, decode_raw_with, load_capture,
    with_decoding,
};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

/// The 6000 × 4000 RGGB mosaic both the decoding benchmark and the memory example use.
fn mosaic_24mp() -> (Vec<u16>, usize, usize) {
    let (w, h) = (6000, 4000);
    (lensblur::simulate::camera_like_mosaic(w, h), w, h)
}

fn bench(c: &mut Criterion) {
    let (cfa, w, h) = mosaic_24mp();
    let path = Path::new("bench.dng");
    let dir = tempfile::tempdir().expect("temporary folder");
    let mut g = c.benchmark_group("raw_decode_24mp");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(20));
    for (name, layout) in [
        (
            "uncompressed_strips",
            DngLayout {
                tile: None,
                compression: DngCompression::Uncompressed,
            },
        ),
        (
            "ljpeg_tiles_256",
            DngLayout {
                tile: Some(256),
                compression: DngCompression::LosslessJpeg,
            },
        ),
    ] {
        let info = DngInfo::simulated("Lensblur", "Bench", 512, 16383, None, layout);
        let bytes = dng_bytes(&cfa, w, h, &info);
        let file = dir.path().join(format!("{name}.dng"));
        std::fs::write(&file, &bytes).expect("write the DNG");
        // The worker is started by the first decode and kept, as in a session.
        let worker = Decoding::Worker(WorkerLimits::new(env!("CARGO_BIN_EXE_lensblur").into()));
        let options = LoadOptions::default();
        g.bench_function(format!("{name}/load"), |b| {
            b.iter(|| black_box(load_capture(&file, &options).expect("load")))
        });
        g.bench_function(format!("{name}/load_in_worker"), |b| {
            with_decoding(&worker, || {
                b.iter(|| black_box(load_capture(&file, &options).expect("load")))
            })
        });
        g.bench_function(format!("{name}/new_chain"), |b| {
            b.iter(|| black_box(decode_raw(path, &bytes).expect("decode")))
        });
        g.bench_function(format!("{name}/new_chain_in_worker"), |b| {
            with_decoding(&worker, || {
                b.iter(|| black_box(decode_raw(path, &bytes).expect("decode")))
            })
        });
        // rawloader refuses tiled uncompressed DNGs; our own reader read those before.
        if decode_raw_with(Decoder::Rawloader, path, &bytes).is_ok() {
            g.bench_function(format!("{name}/rawloader_alone"), |b| {
                b.iter(|| {
                    black_box(decode_raw_with(Decoder::Rawloader, path, &bytes).expect("decode"))
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
