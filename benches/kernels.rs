//! Every kernel of one shot (`lensblur kernels`, the studio's Kernels) on a lens with a
//! typical zoom's geometry: distortion, lateral colour and a stop of fall-off to the
//! corners wide open, as every real lens has some of.
//!
//! Two shots of the demo lens at 24 mm f/4, each in RGB as the studio's demo writes it:
//! the studio demo's first shot (720 × 480, 12 × 8 chart, 96 squares, 288 kernels) and
//! a 2400 × 1600 shot of the 24 × 16 chart (384 squares, 1152 kernels). Detection runs
//! once, outside the timing.

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::chart::ChartSpec;
use lensblur::detect::{DetectParams, detect};
use lensblur::job::JobContext;
use lensblur::kernel::{KernelParams, estimate_shot};
use lensblur::plane::LensSetting;
use lensblur::raw::{LoadOptions, load_capture};
use lensblur::simulate::demo::DemoSpec;
use lensblur::simulate::{
    CaptureParams, LensGeometry, Pose, ShotFormat, VirtualLens, simulate_shot, write_shot,
};
use std::hint::black_box;
use std::time::Duration;

fn bench_shot(c: &mut Criterion, name: &str, spec: &ChartSpec, (width, height): (usize, usize)) {
    let setting = LensSetting {
        focal_mm: 24.0,
        f_number: 4.0,
    };
    let lens = VirtualLens {
        geometry: LensGeometry::typical_zoom(),
        ..VirtualLens::demo()
    };
    let mut cp = CaptureParams::new(width, height, setting);
    // The studio demo's first pose.
    cp.pose = Pose {
        rotation_deg: 1.5 * 0.3f64.sin(),
        tilt_x: 0.02,
        tilt_y: 0.015 * 1.0f64.sin(),
        fill: 0.86,
        shift_px: [0.0, 3.0],
    };
    cp.bayer = false;
    let job = JobContext::silent();
    let shot = simulate_shot(spec, &lens, &cp, &job).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("shot.tiff");
    write_shot(&path, &shot, ShotFormat::Tiff).expect("write");
    let capture = load_capture(&path, &LoadOptions::default()).expect("load");
    let detection = detect(&capture, spec, &DetectParams::default(), &job).expect("detect");
    let kp = KernelParams::default();

    let mut g = c.benchmark_group("kernels_per_shot");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(30));
    g.bench_function(name, |b| {
        b.iter(|| black_box(estimate_shot(&capture, &detection, spec, &kp, &job).expect("kernels")))
    });
    g.finish();
}

fn bench(c: &mut Criterion) {
    bench_shot(
        c,
        "demo_720x480_12x8_geometry",
        &DemoSpec::studio().chart(),
        (720, 480),
    );
    bench_shot(
        c,
        "2400x1600_24x16_geometry",
        &ChartSpec::default(),
        (2400, 1600),
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
