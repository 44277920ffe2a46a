//! Profile loading and kernel-field prediction: what deblur and the studio pay per
//! photo. Field: every 64 px of a 3872 × 2592 (10 MP) sensor, three channels.

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::model::{GlobalModel, LocalModel, LocalOptions, SimulatedSession, spaced};
use lensblur::plane::LensSetting;
use lensblur::profile::Profile;
use lensblur::simulate::VirtualLens;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let (w, h) = (3872, 2592);
    let mut settings = Vec::new();
    for f in spaced(24.0, 105.0, 5, false) {
        for a in spaced(4.0, 10.0, 5, true) {
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
    let global = GlobalModel::fit(&ds, 8, 3).expect("fit");
    let local = LocalModel::fit(&ds, 1, 3, &LocalOptions::default()).expect("fit");
    let dir = tempfile::tempdir().expect("tempdir");
    let setting = LensSetting {
        focal_mm: 50.0,
        f_number: 5.6,
    };
    for (name, kind_global) in [("global G_8,3", true), ("local L_1,3", false)] {
        let profile = Profile::new(
            ds.identity.clone(),
            None,
            settings.clone(),
            kind_global.then(|| global.clone()),
            (!kind_global).then(|| local.clone()),
            None,
            if kind_global {
                lensblur::model::ModelKind::Global
            } else {
                lensblur::model::ModelKind::Local
            },
        )
        .expect("profile");
        let path = dir
            .path()
            .join(format!("{}.json", if kind_global { "g" } else { "l" }));
        profile.save(&path).expect("save");
        eprintln!(
            "{name}: profile {} bytes",
            std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0)
        );
        c.bench_function(
            &format!("load + predict field 64 px 10 MP x3, {name}"),
            |b| {
                b.iter(|| {
                    let p = Profile::load(black_box(&path)).expect("load");
                    black_box(p.predict_field(setting, 64).expect("field"))
                });
            },
        );
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
