//! Deblurring: a 10-megapixel RGB photo (3872 × 2592, three full planes: dead-leaves
//! scenes blurred by a σ = 1.5 px Gaussian) with the spatially varying field a lens
//! profile predicts, by HQS (the default) on the CPU and on the GPU; and one tile of
//! that photo by each solver (in single precision), the unit the whole is made of.
//!
//! The GPU case (in criterion and in the sweep) runs on a hardware adapter; on a
//! software one (llvmpipe) only with `LENSBLUR_BENCH_SOFTWARE_GPU=1` (minutes per run),
//! and not at all without an adapter.
//!
//! Each case's per-stage breakdown ([`lensblur::timings`]) is printed once before
//! it is timed. `LENSBLUR_BENCH_SWEEP=1,2,4,8,16` replaces criterion by a thread sweep:
//! the photo deblurred in a rayon pool of each size (`LENSBLUR_BENCH_REPS` times, 3 by
//! default), then on the GPU, one line each and the breakdowns (`scripts/device_bench.sh`).

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::deblur::solve::Deconvolver;
use lensblur::deblur::{
    DeblurOptions, Device, KernelSource, Method, ProfileKernels, deblur_capture, plane_tile_grid,
};
use lensblur::job::JobContext;
use lensblur::model::spaced;
use lensblur::plane::{Capture, Channel, ChannelPlane, LensSetting};
use lensblur::simulate::dead_leaves;
use lensblur::simulate::{SimulatedSession, VirtualLens};
use lensblur::timings::Timings;
use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// One deblur of `capture` with its stage times noted, and the table printed.
fn breakdown(
    label: &str,
    capture: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) {
    let timings = Arc::new(Timings::new());
    black_box(
        deblur_capture(
            capture,
            source,
            opts,
            &job.with_timings(Arc::clone(&timings)),
        )
        .expect("deblur"),
    );
    eprintln!(
        "{label}, {} threads:\n{}\n",
        rayon::current_num_threads(),
        timings.table()
    );
}

/// The sweep `LENSBLUR_BENCH_SWEEP` asks for, or `None`.
fn sweep_threads() -> Option<Vec<usize>> {
    let list = std::env::var("LENSBLUR_BENCH_SWEEP").ok()?;
    Some(
        list.split(',')
            .filter_map(|t| t.trim().parse().ok())
            .filter(|&t| t > 0)
            .collect(),
    )
}

/// Whether the GPU case should run on a software adapter too (minutes a run).
fn software_gpu_asked() -> bool {
    std::env::var_os("LENSBLUR_BENCH_SOFTWARE_GPU").is_some()
}

/// Seconds of each of `reps` runs of `f`, sorted.
fn times(reps: usize, mut f: impl FnMut()) -> Vec<f64> {
    let mut out: Vec<f64> = (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    out.sort_by(f64::total_cmp);
    out
}

/// The thread sweep: one line per pool size (and the GPU), then the breakdowns.
fn sweep(threads: &[usize], capture: &Capture, source: &dyn KernelSource, job: &JobContext) {
    let reps: usize = std::env::var("LENSBLUR_BENCH_REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(3)
        .max(1);
    let opts = DeblurOptions::default();
    let run = |o: &DeblurOptions| {
        black_box(deblur_capture(capture, source, o, job).expect("deblur"));
    };
    let mut one_thread = None;
    for &n in threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let t = times(reps, || run(&opts));
            let median = t[t.len() / 2];
            let base = *one_thread.get_or_insert(if n == 1 { median } else { f64::NAN });
            println!(
                "deblur_10mp_rgb_hqs cpu threads={n} median_s={median:.3} min_s={:.3} speedup_vs_1={:.2}",
                t[0],
                base / median
            );
            breakdown("CPU", capture, source, &opts, job);
        });
    }
    let on_gpu = DeblurOptions {
        device: Device::Gpu,
        ..opts
    };
    match lensblur::deblur::gpu::shared() {
        Ok(gpu) if gpu.adapter().software && !software_gpu_asked() => println!(
            "deblur_10mp_rgb_hqs gpu skipped=\"{} is a software adapter (LENSBLUR_BENCH_SOFTWARE_GPU=1 runs it)\"",
            gpu.adapter()
        ),
        Ok(gpu) => {
            run(&on_gpu);
            let t = times(reps, || run(&on_gpu));
            println!(
                "deblur_10mp_rgb_hqs gpu adapter=\"{}\" median_s={:.3} min_s={:.3}",
                gpu.adapter(),
                t[t.len() / 2],
                t[0]
            );
            breakdown("GPU", capture, source, &on_gpu, job);
        }
        Err(e) => println!("deblur_10mp_rgb_hqs gpu skipped=\"{e}\""),
    }
}

fn bench(c: &mut Criterion) {
    let (w, h) = (3872, 2592);
    let mut settings = Vec::new();
    for f in spaced(24.0, 105.0, 4, false) {
        for a in spaced(4.0, 10.0, 4, true) {
            settings.push(LensSetting {
                focal_mm: f,
                f_number: a,
            });
        }
    }
    let ds = SimulatedSession {
        seed: 11,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&VirtualLens::demo(), &settings);
    let opts = CalibrateOptions {
        families: Families::Global,
        alpha: Some(6),
        beta: Some(3),
        ..CalibrateOptions::default()
    };
    let (profile, _) = calibrate(&ds, None, &opts, &JobContext::silent()).expect("calibrate");
    // Between the calibrated settings, near the wide open end where blur is largest.
    let source = ProfileKernels::new(
        profile,
        LensSetting {
            focal_mm: 35.0,
            f_number: 4.5,
        },
    );
    let planes: Vec<ChannelPlane> = [Channel::R, Channel::G, Channel::B]
        .into_iter()
        .enumerate()
        .map(|(i, channel)| ChannelPlane {
            channel,
            plane: gaussian_blur(&dead_leaves(w, h, 100 + i as u64), 1.5),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        })
        .collect();
    let capture = Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: Some(35.0),
        setting_f_number: Some(4.5),
        setting_focus_m: None,
        identity: Default::default(),
        is_raw: false,
        raw: None,
    };
    let deblur_opts = DeblurOptions::default();
    let job = JobContext::silent();
    for cp in &capture.planes {
        let grid = plane_tile_grid(cp, w, h, &source, &deblur_opts).expect("grid");
        eprintln!(
            "{}: {} × {} tiles, step {} × {} px, blocks {} × {} px, taper {} px",
            cp.channel,
            grid.x.count,
            grid.y.count,
            grid.x.step,
            grid.y.step,
            grid.x.block,
            grid.y.block,
            grid.taper
        );
    }

    if let Some(threads) = sweep_threads() {
        sweep(&threads, &capture, &source, &job);
        return;
    }
    breakdown("CPU", &capture, &source, &deblur_opts, &job);
    let mut g = c.benchmark_group("deblur");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(60));
    g.bench_function("hqs_10mp_rgb_varying_field", |b| {
        b.iter(|| {
            black_box(deblur_capture(&capture, &source, &deblur_opts, &job).expect("deblur"))
        });
    });
    match lensblur::deblur::gpu::shared() {
        Ok(gpu) if !gpu.adapter().software || software_gpu_asked() => {
            eprintln!("GPU: {}", gpu.adapter());
            let on_gpu = DeblurOptions {
                device: Device::Gpu,
                ..deblur_opts
            };
            // Pipelines are built and the first buffers made before timing starts.
            black_box(deblur_capture(&capture, &source, &on_gpu, &job).expect("deblur"));
            breakdown("GPU", &capture, &source, &on_gpu, &job);
            g.bench_function("hqs_10mp_rgb_varying_field_gpu", |b| {
                b.iter(|| {
                    black_box(deblur_capture(&capture, &source, &on_gpu, &job).expect("deblur"))
                });
            });
        }
        Ok(gpu) => eprintln!("GPU case skipped: {} is a software adapter", gpu.adapter()),
        Err(e) => eprintln!("GPU case skipped: {e}"),
    }
    g.finish();

    // One tile of the green plane at the top-left corner (the widest kernel), as the
    // tiler runs it: read, edge taper, solve.
    let cp = &capture.planes[1];
    let grid = plane_tile_grid(cp, w, h, &source, &deblur_opts).expect("grid");
    let (bw, bh) = (grid.x.block, grid.y.block);
    let kernel = source
        .kernel_at(Channel::G, 0.0, 0.0)
        .expect("kernel")
        .resampled(1);
    // In single precision, as the tiler runs HQS and Wiener (IRLS runs in double there).
    let block: Vec<f32> = (0..bw * bh).map(|i| cp.plane.get(i % bw, i / bw)).collect();
    let mut dec = Deconvolver::<f32>::new(bw, bh);
    let mut scratch = block.clone();
    let mut x = vec![0.0; bw * bh];
    let mut g = c.benchmark_group("deblur_tile");
    g.sample_size(20);
    for name in ["hqs", "wiener", "irls"] {
        let method = Method::from_name(name).expect("method");
        g.bench_function(format!("{name}_{bw}x{bh}"), |b| {
            b.iter(|| {
                scratch.copy_from_slice(&block);
                dec.deconvolve_tapered(&mut scratch, &kernel, grid.taper, &method, &mut x);
                black_box(x[0])
            });
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

/// A separable Gaussian blur (edges clamped): photo-like input, whose deconvolution
/// does not overshoot as a sharp image's would.
fn gaussian_blur(p: &lensblur::plane::Plane, sigma_px: f64) -> lensblur::plane::Plane {
    let r = (3.0 * sigma_px).ceil() as isize;
    let taps: Vec<f32> = (-r..=r)
        .map(|d| (-0.5 * (d * d) as f64 / (sigma_px * sigma_px)).exp() as f32)
        .collect();
    let sum: f32 = taps.iter().sum();
    let (w, h) = (p.width as isize, p.height as isize);
    let pass = |src: &lensblur::plane::Plane, dx: isize, dy: isize| {
        lensblur::plane::Plane::from_fn(p.width, p.height, |x, y| {
            let mut acc = 0.0;
            for (k, t) in taps.iter().enumerate() {
                let d = k as isize - r;
                let sx = (x as isize + d * dx).clamp(0, w - 1) as usize;
                let sy = (y as isize + d * dy).clamp(0, h - 1) as usize;
                acc += t * src.get(sx, sy);
            }
            acc / sum
        })
    };
    pass(&pass(p, 1, 0), 0, 1)
}
