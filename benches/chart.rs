//! Exact chart rasterisation: the inner loop of the simulator and of every alignment step.

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::chart::{ChartSpec, rasterize};
use lensblur::geometry::Homography;
use std::hint::black_box;

fn pose(width: usize, height: usize, spec: &ChartSpec) -> Homography {
    // Fill ~90 % of the width with a slight rotation and perspective.
    let s = 0.9 * width as f64 / spec.cols as f64;
    let (c, si) = (1.5f64.to_radians().cos(), 1.5f64.to_radians().sin());
    let cx = width as f64 / 2.0 - s * spec.cols as f64 / 2.0;
    let cy = height as f64 / 2.0 - s * spec.rows as f64 / 2.0;
    Homography::from_row_major([s * c, -s * si, cx, s * si, s * c, cy, 2e-5, -1e-5, 1.0])
}

fn bench(c: &mut Criterion) {
    let spec = ChartSpec::default();
    let mut g = c.benchmark_group("chart");
    g.sample_size(10);
    for &(w, h) in &[(2400usize, 1600usize), (3872, 2592)] {
        let hm = pose(w, h, &spec);
        g.bench_function(format!("rasterize_{w}x{h}"), |b| {
            b.iter(|| black_box(rasterize(&spec, &hm, w, h, 0.5)));
        });
    }
    // One square plus margin at 3× (what the kernel stage rasterises per square).
    let hm = Homography::scaling(3.0, 3.0).compose(&pose(2400, 1600, &spec));
    let crop = Homography::translation(-3.0 * 1100.0, -3.0 * 700.0).compose(&hm);
    g.bench_function("rasterize_square_3x", |b| {
        b.iter(|| black_box(rasterize(&spec, &crop, 360, 360, 0.5)));
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
