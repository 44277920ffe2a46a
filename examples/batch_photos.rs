//! A folder of RAW photos and a profile library for measuring batch deblurring: `N`
//! DNG photos of `W × H` (dead-leaves scenes as 14-bit RGGB mosaics, each at its own
//! focal length and aperture inside the calibration, EXIF in its own directory) and the
//! profile of the demo lens on that sensor, calibrated from the simulator's stand-in
//! session.
//!
//! Usage: cargo run --release --example batch_photos -- OUT_DIR W H N
//! then:  lensblur deblur OUT_DIR/photos --out-dir OUT_DIR/out --profiles OUT_DIR/profiles
use anyhow::{Context, Result};
use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::dng::{DngInfo, DngLayout, write_dng};
use lensblur::job::JobContext;
use lensblur::model::spaced;
use lensblur::plane::{CameraIdentity, LensSetting, RawMeta};
use lensblur::simulate::dead_leaves;
use lensblur::simulate::{SimulatedSession, VirtualLens};
use std::path::PathBuf;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [out, w, h, n] = args.as_slice() else {
        anyhow::bail!("usage: batch_photos OUT_DIR W H N");
    };
    let out = PathBuf::from(out);
    let (w, h, n): (usize, usize, usize) = (w.parse()?, h.parse()?, n.parse()?);
    let lens = VirtualLens::demo();
    let identity = CameraIdentity {
        make: Some(lens.make.clone()),
        model: Some(lens.model.clone()),
        lens_model: Some(lens.model.clone()),
        ..CameraIdentity::default()
    };
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
    .dataset(&lens, &settings);
    let opts = CalibrateOptions {
        families: Families::Global,
        alpha: Some(6),
        beta: Some(3),
        ..CalibrateOptions::default()
    };
    let (mut profile, _) = calibrate(&ds, None, &opts, &JobContext::silent())?;
    profile.identity = identity.clone();
    std::fs::create_dir_all(out.join("profiles"))?;
    std::fs::create_dir_all(out.join("photos"))?;
    profile.save(&out.join("profiles").join("demo-lens.json"))?;
    let planes: Vec<_> = (0..3).map(|c| dead_leaves(w, h, 40 + c)).collect();
    for k in 0..n {
        let setting = LensSetting {
            focal_mm: 30.0 + 50.0 * k as f64 / n.max(1) as f64,
            f_number: 5.0,
        };
        let raw = RawMeta::rggb(512, 16383);
        let cfa: Vec<u16> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let c = usize::from(raw.cfa[RawMeta::site(x, y)]);
                let v = planes[c].get((x + 97 * k) % w, y).clamp(0.0, 1.0);
                (512.0 + v * (16383.0 - 512.0)).round() as u16
            })
            .collect();
        let mut info = DngInfo::simulated("", "", 512, 16383, Some(setting), DngLayout::default());
        info.identity = identity.clone();
        info.exif_in_ifd0 = false;
        let path = out.join("photos").join(format!("IMG_{k:04}.dng"));
        write_dng(&path, &cfa, w, h, &info).with_context(|| path.display().to_string())?;
    }
    eprintln!("{n} photos of {w} × {h} in {}", out.display());
    Ok(())
}
