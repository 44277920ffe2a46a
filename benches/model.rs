//! Profile loading and kernel-field prediction: what deblur and the studio pay per
//! photo. The field: every 64 px of a 3872 × 2592 (10 MP) sensor, three channels
//! (62 × 42 points × 3 = 7812 Gaussians), from a profile file on disk, load included.
//! The models are the paper's G_{8,3} and L_{1,3}, fitted to a 5 × 5-setting session
//! of the 24 × 16 chart; "both" is what `lensblur calibrate` writes by default. The
//! last benchmark also samples every predicted Gaussian as the 3× kernel array the
//! deconvolver uses.

use criterion::{Criterion, criterion_group, criterion_main};
use lensblur::model::{GlobalModel, LocalModel, LocalOptions, ModelKind, spaced};
use lensblur::plane::LensSetting;
use lensblur::profile::Profile;
use lensblur::simulate::{SimulatedSession, VirtualLens};
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
    let profiles = [
        ("global G_8,3", Some(&global), None, ModelKind::Global),
        ("local L_1,3", None, Some(&local), ModelKind::Local),
        ("both", Some(&global), Some(&local), ModelKind::Local),
    ];
    for (name, g, l, preferred) in profiles {
        let profile = Profile::new(
            ds.identity.clone(),
            None,
            settings.clone(),
            g.cloned(),
            l.cloned(),
            None,
            preferred,
        )
        .expect("profile");
        let path = dir
            .path()
            .join(format!("{}.json", name.replace([' ', ','], "_")));
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
        if name == "both" {
            c.bench_function(
                "load + predict field 64 px 10 MP x3 + 3x kernel arrays, both",
                |b| {
                    b.iter(|| {
                        let p = Profile::load(black_box(&path)).expect("load");
                        let field = p.predict_field(setting, 64).expect("field");
                        let taps: usize =
                            field.iter().map(|s| s.gaussian.kernel(3).data.len()).sum();
                        black_box(taps)
                    });
                },
            );
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
