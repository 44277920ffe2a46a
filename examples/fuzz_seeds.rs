//! Writes the seed corpora, one folder per target, from the simulator's own files: a
//! small demo session (DNG, PNG and TIFF shots with EXIF) measured through the
//! pipeline, so every JSON seed is a file lensblur really wrote.
//!
//! Usage: cargo run --example fuzz_seeds -- fuzz/seeds
use lensblur::dng::{DngCompression, DngInfo, DngLayout, dng_bytes};
use lensblur::fuzz::Target;
use lensblur::job::JobContext;
use lensblur::pipeline::{self, GivenSetting, MeasuredShot, ShotFile};
use lensblur::simulate::demo::{DemoSpec, make_demo};
use std::path::{Path, PathBuf};

fn main() -> anyhow::Result<()> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "seeds".into()));
    let work = out.join(".work");
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work)?;
    let put = |target: Target, name: &str, bytes: &[u8]| -> anyhow::Result<()> {
        let dir = out.join(target.name());
        std::fs::create_dir_all(&dir)?;
        std::fs::write(dir.join(name), bytes)?;
        Ok(())
    };

    // RAW layouts our reader and the RAW decoder take: strips, tiles, lossless JPEG.
    let (w, h) = (64usize, 48usize);
    let cfa: Vec<u16> = (0..w * h)
        .map(|i| 600 + ((i % w) * 97 + (i / w) * 31) as u16 % 9000)
        .collect();
    for (name, tile, compression) in [
        ("strips.dng", None, DngCompression::Uncompressed),
        ("tiles.dng", Some(16), DngCompression::Uncompressed),
        ("ljpeg.dng", None, DngCompression::LosslessJpeg),
        ("ljpeg-tiles.dng", Some(16), DngCompression::LosslessJpeg),
    ] {
        let info = DngInfo::simulated(
            "Simulated",
            "Fuzz",
            512,
            16383,
            Some(lensblur::plane::LensSetting {
                focal_mm: 35.0,
                f_number: 5.6,
            }),
            DngLayout { tile, compression },
        );
        let bytes = dng_bytes(&cfa, w, h, &info);
        for t in [Target::Dng, Target::Load, Target::Exif] {
            put(t, name, &bytes)?;
        }
    }

    // A tiny demo session, measured: its shots, detections, kernels, session, profile.
    let spec = DemoSpec::grid(240, 160, &[24.0, 70.0], &[4.0, 8.0]);
    let job = JobContext::silent();
    let session = make_demo(&work, &spec, &job)?;
    session.save()?;
    let m = session.measurement();
    let cache = session.cache();
    let mut measured = Vec::new();
    for shot in &session.shots {
        let path = session.path_of(shot);
        let file = ShotFile::read(&path)?;
        let (kernels, _) =
            pipeline::measure_shot(&file, shot.given_setting(), true, &m, &cache, &job)?;
        measured.push(MeasuredShot {
            name: shot.name(),
            kernels,
            given: GivenSetting::default(),
        });
    }
    // Images small enough for the fuzzer to mutate quickly: a crop of a demo shot as
    // 16-bit PNG and TIFF, 8-bit PNG and JPEG.
    let shot_file = session.path_of(&session.shots[0]);
    let capture = lensblur::raw::load_capture(&shot_file, &Default::default())?;
    let crop: Vec<_> = lensblur::raw::full_planes(&capture)
        .into_iter()
        .map(|(c, p)| {
            (
                c,
                lensblur::plane::Plane::from_fn(64, 48, |x, y| p.get(x + 88, y + 56)),
            )
        })
        .collect();
    for (name, srgb) in [
        ("shot16.png", false),
        ("shot16.tif", false),
        ("preview8.png", true),
    ] {
        let p = work.join(name);
        lensblur::raw::save_planes(&p, &crop, srgb)?;
        put(Target::Load, name, &std::fs::read(&p)?)?;
    }
    let jpeg = work.join("preview.jpg");
    image::open(work.join("preview8.png"))?.save(&jpeg)?;
    put(Target::Load, "preview.jpg", &std::fs::read(&jpeg)?)?;

    // One detection and one kernels file, cut to a few squares: a fuzzer mutates a few
    // kB thousands of times faster than the hundreds of kB of a whole shot's.
    let mut results: Vec<PathBuf> = std::fs::read_dir(work.join(lensblur::pipeline::RESULTS_DIR))?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    results.sort();
    if let Some(p) = results
        .iter()
        .find(|p| file_name(p).ends_with(".detect.json"))
    {
        let mut d = lensblur::detect::DetectFile::from_json(&std::fs::read_to_string(p)?)
            .map_err(anyhow::Error::msg)?;
        d.squares.truncate(3);
        put(
            Target::Detect,
            "shot.detect.json",
            &serde_json::to_vec_pretty(&d)?,
        )?;
    }
    if let Some(p) = results
        .iter()
        .find(|p| file_name(p).ends_with(".kernels.json"))
    {
        let mut k = lensblur::kernel::file::KernelsFile::load(p).map_err(anyhow::Error::msg)?;
        k.samples.truncate(4);
        // One small kernel array (the centre 5 × 5 of a measured one, renormalised).
        for (i, sample) in k.samples.iter_mut().enumerate() {
            sample.kernel = sample.kernel.take().filter(|_| i == 0).map(|mut a| {
                let (n, c) = (a.size, a.size / 2);
                let data: Vec<f64> = (0..25)
                    .map(|j| a.data[(c + j / 5 - 2) * n + c + j % 5 - 2])
                    .collect();
                let sum: f64 = data.iter().sum();
                a.size = 5;
                a.data = data.iter().map(|v| v / sum).collect();
                a
            });
        }
        k.failed.truncate(1);
        put(
            Target::Kernels,
            "shot.kernels.json",
            &serde_json::to_vec_pretty(&k)?,
        )?;
    }
    put(
        Target::Session,
        "session.json",
        &std::fs::read(work.join("session.json"))?,
    )?;
    let manifest = session.write_manifest()?;
    let manifest_bytes = std::fs::read(&manifest)?;
    put(Target::Manifest, "manifest.json", &manifest_bytes)?;
    put(Target::Session, "manifest.json", &manifest_bytes)?;
    let chart = work.join("chart.json");
    session.chart.save(&chart)?;
    put(Target::Chart, "chart.json", &std::fs::read(&chart)?)?;

    let ds = pipeline::dataset(&measured)?;
    let opts = lensblur::calibrate::CalibrateOptions {
        alpha: Some(1),
        beta: Some(1),
        ..Default::default()
    };
    let (profile, _) =
        lensblur::calibrate::calibrate(&ds, Some(session.chart.clone()), &opts, &job)?;
    put(Target::Profile, "profile.json", &profile.to_json()?)?;

    std::fs::remove_dir_all(&work)?;
    eprintln!("seeds written to {}", out.display());
    Ok(())
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}
