//! The photographer's end of the chain, beside the deblurring itself: writing a
//! deblurred 24-megapixel RAW photo (6000 × 4000 RGGB, 14-bit) as a DNG with its
//! metadata against writing it as a 16-bit linear TIFF, and developing it through
//! imagepipe (the preview written beside it, and what the studio shows).

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::deblur::output::write_deblurred;
use lensblur::develop::{Orient, develop};
use lensblur::plane::{CameraIdentity, Capture, Channel, ChannelPlane, RawMeta};
use lensblur::simulate::dead_leaves;
use std::hint::black_box;
use std::time::Duration;

fn raw_photo(w: usize, h: usize) -> Capture {
    let sites = [
        (0, 0, Channel::R),
        (1, 0, Channel::G),
        (0, 1, Channel::G),
        (1, 1, Channel::B),
    ];
    let planes = sites
        .iter()
        .enumerate()
        .map(|(i, &(ox, oy, channel))| ChannelPlane {
            channel,
            plane: dead_leaves(w / 2, h / 2, 7 + i as u64),
            step: 2,
            offset_x: ox,
            offset_y: oy,
        })
        .collect();
    Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: Some(35.0),
        setting_f_number: Some(4.5),
        setting_focus_m: None,
        identity: CameraIdentity {
            make: Some("Virtual".into()),
            model: Some("Sim 14".into()),
            ..CameraIdentity::default()
        },
        is_raw: true,
        raw: Some(RawMeta::rggb(512, 16383)),
    }
}

fn bench(c: &mut Criterion) {
    let photo = raw_photo(6000, 4000);
    let dir = tempfile::tempdir().expect("temp dir");
    let mut g = c.benchmark_group("photo_out_24mp");
    g.sample_size(10).measurement_time(Duration::from_secs(40));
    for ext in ["dng", "tiff"] {
        let out = dir.path().join(format!("out.{ext}"));
        g.bench_function(format!("write_{ext}_with_preview"), |b| {
            b.iter(|| write_deblurred(black_box(&out), None, &photo, "bench").expect("write"));
        });
    }
    g.bench_function("dng_bytes", |b| {
        let cfa = lensblur::dng::mosaic(&photo).expect("mosaic");
        let info = lensblur::dng::DngInfo::simulated(
            "Virtual",
            "Sim 14",
            512,
            16383,
            None,
            lensblur::dng::DngLayout::default(),
        );
        b.iter(|| lensblur::dng::dng_bytes(black_box(&cfa), 6000, 4000, &info).len());
    });
    g.bench_function("develop_imagepipe", |b| {
        b.iter(|| {
            develop(black_box(&photo), None, Orient::AsShot)
                .expect("develop")
                .width
        });
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
