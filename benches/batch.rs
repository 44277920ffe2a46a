//! A batch: simulated 24 MP RAW photos (6000 × 4000 RGGB, 14-bit, lossless-JPEG DNGs
//! as cameras and Adobe's converter write them, their camera, lens and setting in EXIF)
//! deblurred with a profile library and written back as DNGs with their previews, as
//! `lensblur deblur DIR --out-dir OUT --profiles LIB` does (decoded in this process).
//! Criterion times the whole batch; its throughput in photos a second, times 60, is the
//! photos per minute. Before it, each stage of one photo is timed alone (decode, deblur,
//! write), so the batch can be compared with their sum (stages one after another) and
//! with the slowest (stages overlapping).
//!
//! `LENSBLUR_BENCH_BATCH_MP` (24) and `LENSBLUR_BENCH_BATCH_PHOTOS` (4) set the photos'
//! size and count. `LENSBLUR_BENCH_REPS=N` replaces criterion by N timed batches, a
//! line on the CPU, one with one photo in flight at a time (the stages one after
//! another) and one on the GPU (`scripts/device_bench.sh`). The GPU case runs on a
//! hardware adapter, on a software one only with `LENSBLUR_BENCH_SOFTWARE_GPU=1`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use lensblur::batch::{
    BatchOptions, LibraryProfile, Outcome, OutputFormat, ProfileLibrary, deblur_photos,
};
use lensblur::deblur::output::write_deblurred;
use lensblur::deblur::{DeblurOptions, Device, ProfileKernels, deblur_capture};
use lensblur::dng::{DngCompression, DngInfo, DngLayout, write_dng};
use lensblur::job::JobContext;
use lensblur::model::{GlobalModel, ModelKind, spaced};
use lensblur::plane::{CameraIdentity, LensSetting};
use lensblur::profile::Profile;
use lensblur::simulate::{SimulatedSession, VirtualLens, camera_like_mosaic};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&v| v > 0)
        .unwrap_or(default)
}

fn identity() -> CameraIdentity {
    CameraIdentity {
        make: Some("Virtual".into()),
        model: Some("Sim 24".into()),
        lens_model: Some("Zoom 24-70".into()),
        ..CameraIdentity::default()
    }
}

const SETTING: LensSetting = LensSetting {
    focal_mm: 35.0,
    f_number: 4.5,
};

/// The demo lens's global profile on a `w × h` sensor (24–70 mm, f/4–8).
fn profile(w: usize, h: usize) -> Profile {
    let mut settings = Vec::new();
    for f in spaced(24.0, 70.0, 3, false) {
        for a in spaced(4.0, 8.0, 3, true) {
            settings.push(LensSetting {
                focal_mm: f,
                f_number: a,
            });
        }
    }
    let ds = SimulatedSession::new(w, h).dataset(&VirtualLens::demo(), &settings);
    let global = GlobalModel::fit(&ds, 2, 2).expect("fit");
    Profile::new(
        identity(),
        None,
        settings,
        Some(global),
        None,
        None,
        ModelKind::Global,
    )
    .expect("profile")
}

/// `n` RAW photos of `w × h` in `dir`, the same mosaic under different names.
fn photos(dir: &Path, n: usize, w: usize, h: usize) -> Vec<PathBuf> {
    let cfa = camera_like_mosaic(w, h);
    let mut info = DngInfo::simulated(
        "Virtual",
        "Sim 24",
        512,
        16383,
        Some(SETTING),
        DngLayout {
            tile: Some(256),
            compression: DngCompression::LosslessJpeg,
        },
    );
    info.identity = identity();
    (0..n)
        .map(|i| {
            let path = dir.join(format!("photo{i:02}.dng"));
            write_dng(&path, &cfa, w, h, &info).expect("write photo");
            path
        })
        .collect()
}

/// One batch into a fresh output folder; its seconds.
fn batch(photos: &[PathBuf], library: &ProfileLibrary, opts: &BatchOptions) -> f64 {
    let out = tempfile::tempdir().expect("temp dir");
    let opts = BatchOptions {
        out_dir: out.path().to_path_buf(),
        ..opts.clone()
    };
    let started = Instant::now();
    let report = deblur_photos(photos, library, &opts, &JobContext::silent());
    let seconds = started.elapsed().as_secs_f64();
    for o in &report.outcomes {
        assert!(matches!(o.outcome, Outcome::Done { .. }), "{o:?}");
    }
    seconds
}

/// Each stage of one photo alone, one after another: decode, deblur, write.
fn stages(photo: &Path, profile: &Profile, deblur: &DeblurOptions, dir: &Path) -> [f64; 3] {
    let t = Instant::now();
    let capture = lensblur::raw::load_capture(photo, &Default::default()).expect("decode");
    let decode = t.elapsed().as_secs_f64();
    let source = ProfileKernels::new(profile.clone(), SETTING);
    let t = Instant::now();
    let deblurred =
        deblur_capture(&capture, &source, deblur, &JobContext::silent()).expect("deblur");
    let deblur = t.elapsed().as_secs_f64();
    let t = Instant::now();
    write_deblurred(&dir.join("stage.dng"), None, &deblurred, "bench").expect("write");
    [decode, deblur, t.elapsed().as_secs_f64()]
}

fn print_stages(label: &str, [decode, deblur, write]: [f64; 3]) {
    eprintln!(
        "{label}: one photo's stages alone: decode {decode:.2} s, deblur {deblur:.2} s, \
         write {write:.2} s; one after another {:.1} photos/min, the slowest alone {:.1}",
        60.0 / (decode + deblur + write),
        60.0 / decode.max(deblur).max(write)
    );
}

/// The GPU's deblur options where a GPU case runs (a hardware adapter, or a software one
/// when asked), or why not.
fn gpu_options(deblur: &DeblurOptions) -> Result<DeblurOptions, String> {
    let gpu = lensblur::deblur::gpu::shared().map_err(|e| e.to_string())?;
    if gpu.adapter().software && std::env::var_os("LENSBLUR_BENCH_SOFTWARE_GPU").is_none() {
        return Err(format!("{} is a software adapter", gpu.adapter()));
    }
    Ok(DeblurOptions {
        device: Device::Gpu,
        ..*deblur
    })
}

fn bench(c: &mut Criterion) {
    let mp = env_or("LENSBLUR_BENCH_BATCH_MP", 24);
    let n = env_or("LENSBLUR_BENCH_BATCH_PHOTOS", 4);
    // 3:2, both sides even (the mosaic's 2 × 2 pattern).
    let h = ((mp as f64 * 1e6 / 1.5).sqrt() / 2.0).round() as usize * 2;
    let w = (h * 3 / 2).div_ceil(2) * 2;
    let dir = tempfile::tempdir().expect("temp dir");
    let photos = photos(dir.path(), n, w, h);
    let profile = profile(w, h);
    let mut library = ProfileLibrary::default();
    library.add(LibraryProfile {
        path: dir.path().join("profile.json"),
        profile: profile.clone(),
    });
    let opts = BatchOptions {
        format: OutputFormat::Dng,
        ..BatchOptions::default()
    };
    let name = format!("batch_{mp}mp_raw_dng_{n}_photos");
    eprintln!(
        "{name}: {w} × {h}, {} threads",
        rayon::current_num_threads()
    );
    print_stages(
        "CPU",
        stages(&photos[0], &profile, &opts.deblur, dir.path()),
    );
    let on_gpu = gpu_options(&opts.deblur);

    if let Some(reps) = std::env::var("LENSBLUR_BENCH_REPS")
        .ok()
        .and_then(|r| r.parse::<usize>().ok())
    {
        let line = |device: &str, opts: &BatchOptions| {
            let mut t: Vec<f64> = (0..reps.max(1))
                .map(|_| batch(&photos, &library, opts))
                .collect();
            t.sort_by(f64::total_cmp);
            let median = t[t.len() / 2];
            println!(
                "{name} {device} threads={} median_s={median:.2} photos_per_min={:.1}",
                rayon::current_num_threads(),
                n as f64 * 60.0 / median
            );
        };
        line("cpu", &opts);
        // The same batch with one photo in flight at a time (a memory budget smaller
        // than a photo): the stages one after another, what the overlap is measured by.
        line(
            "cpu_one_at_a_time",
            &BatchOptions {
                memory_budget: Some(1),
                ..opts.clone()
            },
        );
        match &on_gpu {
            Ok(deblur) => {
                print_stages("GPU", stages(&photos[0], &profile, deblur, dir.path()));
                let deblur = *deblur;
                line("gpu", &BatchOptions { deblur, ..opts });
            }
            Err(e) => println!("{name} gpu skipped=\"{e}\""),
        }
        return;
    }
    let mut g = c.benchmark_group("batch");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(60));
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function(&name, |b| {
        b.iter_custom(|iters| {
            (0..iters)
                .map(|_| Duration::from_secs_f64(black_box(batch(&photos, &library, &opts))))
                .sum()
        });
    });
    match on_gpu {
        Ok(deblur) => {
            print_stages("GPU", stages(&photos[0], &profile, &deblur, dir.path()));
            let opts = BatchOptions { deblur, ..opts };
            g.bench_function(format!("{name}_gpu"), |b| {
                b.iter_custom(|iters| {
                    (0..iters)
                        .map(|_| Duration::from_secs_f64(batch(&photos, &library, &opts)))
                        .sum()
                });
            });
        }
        Err(e) => eprintln!("GPU case skipped: {e}"),
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
