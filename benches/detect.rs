//! Detection and alignment on a 24-megapixel shot: a 6000 × 4000 RGGB Bayer shot of the
//! 24 × 16 chart filling the frame (squares about 225 px), simulated at 24 mm f/4 through
//! the demo lens with a slight turn and tilt. What a full-frame camera of today hands
//! to `lensblur detect`, and the size at which the lattice search, the board's
//! placement on the spec and the per-square registration cost the most.

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::chart::ChartSpec;
use lensblur::detect::{DetectParams, detect};
use lensblur::job::JobContext;
use lensblur::plane::LensSetting;
use lensblur::simulate::{CaptureParams, VirtualLens, simulate_shot};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let spec = ChartSpec::default();
    let setting = LensSetting {
        focal_mm: 24.0,
        f_number: 4.0,
    };
    let mut cp = CaptureParams::new(6000, 4000, setting);
    cp.pose.rotation_deg = 1.5;
    cp.pose.tilt_x = 0.02;
    let job = JobContext::silent();
    let shot = simulate_shot(&spec, &VirtualLens::demo(), &cp, &job).expect("simulate");
    let params = DetectParams::default();
    let found = detect(&shot.capture, &spec, &params, &job).expect("detect");
    assert_eq!(
        found.ok_squares().count(),
        spec.rows * spec.cols,
        "every square of the 24 MP shot aligns"
    );

    let mut g = c.benchmark_group("detect_24mp_raw");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(40));
    g.bench_function("detect_align_6000x4000", |b| {
        b.iter(|| black_box(detect(&shot.capture, &spec, &params, &job).expect("detect")))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
