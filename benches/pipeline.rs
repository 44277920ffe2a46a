//! Detection and kernel estimation on a 10-megapixel RAW chart shot: a 3872 × 2592
//! RGGB Bayer shot of the 24 × 16 chart simulated at 24 mm f/4 (the demo lens, σ
//! 0.65–2.4 px; 384 squares, three pooled colours each), loaded from its DNG as a user's
//! file would be. Benchmarks: detect + align of the whole shot; the kernels of one
//! square (all three colours, 3×), by the default operator and by the FFT form; and
//! every kernel of the shot (1152), which is what `lensblur kernels` does.

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::chart::ChartSpec;
use lensblur::detect::{DetectParams, detect};
use lensblur::job::JobContext;
use lensblur::kernel::{KernelParams, Operator, SquareGeometry, estimate_shot, estimate_square};
use lensblur::plane::LensSetting;
use lensblur::raw::{LoadOptions, load_capture};
use lensblur::simulate::{CaptureParams, ShotFormat, VirtualLens, simulate_shot, write_shot};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let spec = ChartSpec::default();
    let setting = LensSetting {
        focal_mm: 24.0,
        f_number: 4.0,
    };
    let mut cp = CaptureParams::new(3872, 2592, setting);
    cp.pose.rotation_deg = 1.5;
    cp.pose.tilt_x = 0.02;
    let job = JobContext::silent();
    let shot = simulate_shot(&spec, &VirtualLens::demo(), &cp, &job).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("shot.dng");
    write_shot(&path, &shot, ShotFormat::Dng).expect("write");
    let capture = load_capture(&path, &LoadOptions::default()).expect("load");
    let params = DetectParams::default();

    let mut g = c.benchmark_group("pipeline_10mp_raw");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(20));
    g.bench_function("detect_align_3872x2592", |b| {
        b.iter(|| black_box(detect(&capture, &spec, &params, &job).expect("detect")))
    });

    let detection = detect(&capture, &spec, &params, &job).expect("detect");
    let kp = KernelParams::default();
    let channels = capture.channels();
    let mid = detection
        .ok_squares()
        .find(|s| s.row == spec.rows / 2 && s.col == spec.cols / 2)
        .expect("centre square");
    let square = SquareGeometry {
        row: mid.row,
        col: mid.col,
        image_from_chart: mid.image_from_chart,
    };
    g.bench_function("kernels_one_square_rgb_3x", |b| {
        b.iter(|| {
            black_box(estimate_square(
                &capture,
                &square,
                &spec,
                &kp,
                &channels,
                &mid.sigma_by_channel,
            ))
        })
    });
    // The same square with every product by FFT over the whole 3× raster: what the
    // default operator is measured against.
    let fft = KernelParams {
        operator: Operator::Fft,
        ..KernelParams::default()
    };
    g.bench_function("kernels_one_square_rgb_3x_fft_operator", |b| {
        b.iter(|| {
            black_box(estimate_square(
                &capture,
                &square,
                &spec,
                &fft,
                &channels,
                &mid.sigma_by_channel,
            ))
        })
    });
    g.measurement_time(Duration::from_secs(60));
    g.bench_function("kernels_all_1152_3x", |b| {
        b.iter(|| {
            black_box(estimate_shot(&capture, &detection, &spec, &kp, &job).expect("kernels"))
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
