//! What a newcomer sees in the first ten minutes, measured: the studio's demo session
//! made, calibrated by *Calibrate all* (the same project job the studio runs), and its
//! photo deblurred with the profile it made, against the sharp photo it was blurred
//! from:
//!
//! - SSIM (mean over R, G, B) at amounts 0, 50, 100, 150 and 200 %;
//! - the colour error at edges (RMS of R − G and B − G against the sharp photo's, over
//!   its strongest 10 % of edges) blurry and deblurred, and on a chart shot (neutral:
//!   every colour difference at its edges is a fringe) before and after;
//! - `before_after.png`: the photo's centre, blurry left and deblurred right, at 200 %;
//! - the sharpness map (MTF50 worst direction, G) against the lens's own: predicted at
//!   the photo's setting and between the shots (35 mm f/4.8), and measured on the chart
//!   shot at the photo's setting (median relative error over the frame), the predicted
//!   one written as `sharpness_predicted.png`.
//!
//! `cargo run --release --example first_ten_minutes -- [OUT_DIR]` (default
//! `target/first_ten_minutes`; a demo already there is reused).

use anyhow::{Context, Result};
use lensblur::calibrate::CalibrateOptions;
use lensblur::deblur::{Amount, DeblurOptions, Fringes, ProfileKernels, deblur_capture};
use lensblur::job::JobContext;
use lensblur::metrics::{SsimParams, edge_colour_error, ssim};
use lensblur::plane::{Capture, Channel, LensSetting, Plane};
use lensblur::project::Project;
use lensblur::simulate::demo::{DemoSpec, make_demo, sharp_demo_photo};
use std::path::PathBuf;
use std::time::Instant;

fn rgb(c: &Capture) -> Result<[&Plane; 3]> {
    let plane = |ch| {
        c.planes
            .iter()
            .find(|p| p.channel == ch)
            .map(|p| &p.plane)
            .context("an RGB capture")
    };
    Ok([plane(Channel::R)?, plane(Channel::G)?, plane(Channel::B)?])
}

fn main() -> Result<()> {
    let out = std::env::args()
        .nth(1)
        .map_or_else(|| PathBuf::from("target/first_ten_minutes"), PathBuf::from);
    let spec = DemoSpec::studio();
    let ctx = JobContext::silent();
    let t0 = Instant::now();
    let session = make_demo(&out, &spec, &ctx)?;
    println!("demo made in {:.1} s", t0.elapsed().as_secs_f64());
    let photo = session.demo_photo.clone().context("the demo's photo")?;

    let t1 = Instant::now();
    let (mut project, _) = Project::open(&out, "first_ten_minutes")?;
    project.survey(&ctx)?;
    let opts = CalibrateOptions {
        alpha: project.session().settings.alpha,
        beta: project.session().settings.beta,
        ..Default::default()
    };
    let mut failed = 0;
    let cal = project
        .calibrate_all_job(opts)
        .run(&ctx, &|_| Some(ctx.clone()), &mut |e| {
            if let lensblur::project::ShotEvent::Failed { reason, .. } = &e {
                eprintln!("{reason}");
                failed += 1;
            }
            project_event(&e);
        })?;
    cal.write(&out.join("profile.json"), None)?;
    println!(
        "calibrate all: {} shots ({failed} failed) in {:.1} s",
        cal.dataset.shots.len(),
        t1.elapsed().as_secs_f64()
    );
    drop(project);

    let setting = LensSetting {
        focal_mm: photo.focal_mm,
        f_number: photo.f_number,
    };
    let blurry = lensblur::pipeline::load(&out.join(&photo.path))?;
    let sharp = sharp_demo_photo(&spec).map_err(anyhow::Error::msg)?;
    let truth = [&sharp[0], &sharp[1], &sharp[2]];
    let source = ProfileKernels::new(cal.profile.clone(), setting);
    let t2 = Instant::now();
    let full = deblur_capture(&blurry, &source, &DeblurOptions::default(), &ctx)?;
    println!(
        "photo {} x {} deblurred in {:.1} s",
        blurry.width,
        blurry.height,
        t2.elapsed().as_secs_f64()
    );
    let p = SsimParams::default();
    let mean_ssim = |c: [&Plane; 3]| (0..3).map(|i| ssim(c[i], truth[i], &p)).sum::<f64>() / 3.0;
    let before = rgb(&blurry)?;
    println!("amount %  SSIM (mean of R, G, B, against the sharp photo)");
    for percent in [0.0, 50.0, 100.0, 150.0, 200.0] {
        let mut planes = rgb(&full)?.map(Clone::clone);
        for (p, b) in planes.iter_mut().zip(before) {
            Amount::percent(percent).apply(b, p);
        }
        println!(
            "{percent:>8.0}  {:.4}",
            mean_ssim([&planes[0], &planes[1], &planes[2]])
        );
    }
    // The same solver given the lens's true kernels: what the profile is measured against.
    let lens = lensblur::simulate::VirtualLens::demo();
    let true_kernels = |ch: Channel, x: f64, y: f64| {
        let (u, v) = lensblur::simulate::VirtualLens::normalised(x, y, blurry.width, blurry.height);
        lens.optical_kernel_uv(ch, u, v, setting, 3)
            .pixel_integrated()
    };
    let ideal = deblur_capture(&blurry, &true_kernels, &DeblurOptions::default(), &ctx)?;
    println!("true kernels, 100 %: SSIM {:.4}", mean_ssim(rgb(&ideal)?));
    println!(
        "colour error at the photo's edges: blurry {:.4}, profile {:.4}, true kernels {:.4}",
        edge_colour_error(before, truth, 0.1),
        edge_colour_error(rgb(&full)?, truth, 0.1),
        edge_colour_error(rgb(&ideal)?, truth, 0.1)
    );
    // The same without the fringe suppression: what it changes.
    let keep = DeblurOptions {
        fringes: Fringes::Keep,
        ..DeblurOptions::default()
    };
    let full_keep = deblur_capture(&blurry, &source, &keep, &ctx)?;
    let ideal_keep = deblur_capture(&blurry, &true_kernels, &keep, &ctx)?;
    println!(
        "without fringe suppression: SSIM profile {:.4}, true kernels {:.4}; colour error profile {:.4}, true kernels {:.4}",
        mean_ssim(rgb(&full_keep)?),
        mean_ssim(rgb(&ideal_keep)?),
        edge_colour_error(rgb(&full_keep)?, truth, 0.1),
        edge_colour_error(rgb(&ideal_keep)?, truth, 0.1)
    );

    // A chart shot at the photo's setting: neutral, so its truth has no colour.
    let shot = session
        .shots
        .iter()
        .find(|s| s.focal_mm == Some(photo.focal_mm) && s.f_number == Some(photo.f_number))
        .context("a shot at the photo's setting")?;
    let chart = lensblur::pipeline::load(&out.join(&shot.path))?;
    let chart_out = deblur_capture(&chart, &source, &DeblurOptions::default(), &ctx)?;
    let chart_ideal = deblur_capture(&chart, &true_kernels, &DeblurOptions::default(), &ctx)?;
    let grey = rgb(&chart)?[1].clone();
    let neutral = [&grey, &grey, &grey];
    println!(
        "colour at the chart's edges ({}): blurry {:.4}, profile {:.4}, true kernels {:.4}",
        shot.path.display(),
        edge_colour_error(rgb(&chart)?, neutral, 0.1),
        edge_colour_error(rgb(&chart_out)?, neutral, 0.1),
        edge_colour_error(rgb(&chart_ideal)?, neutral, 0.1)
    );
    println!(
        "  without fringe suppression: profile {:.4}, true kernels {:.4}",
        edge_colour_error(
            rgb(&deblur_capture(&chart, &source, &keep, &ctx)?)?,
            neutral,
            0.1
        ),
        edge_colour_error(
            rgb(&deblur_capture(&chart, &true_kernels, &keep, &ctx)?)?,
            neutral,
            0.1
        )
    );

    let path = out.join("before_after.png");
    write_before_after(&path, before, rgb(&full)?)?;
    println!("{} written", path.display());

    sharpness_maps(
        &out,
        &cal.profile,
        &lens,
        (blurry.width, blurry.height),
        setting,
    )?;
    Ok(())
}

/// The sharpness maps against the lens's truth: predicted at the photo's setting and
/// between the shots, measured on the chart shot at the photo's setting.
fn sharpness_maps(
    out: &std::path::Path,
    profile: &lensblur::profile::Profile,
    lens: &lensblur::simulate::VirtualLens,
    sensor: (usize, usize),
    setting: LensSetting,
) -> Result<()> {
    use lensblur::review::{Mtf50Direction, SharpnessMap, SharpnessUnit};
    let dir = Mtf50Direction::Worst;
    let truth = |s| SharpnessMap::truth(lens, Channel::G, sensor, s, dir);
    let between = LensSetting {
        focal_mm: 35.0,
        f_number: 4.8,
    };
    for s in [setting, between] {
        let map =
            SharpnessMap::predicted(profile, Channel::G, s, dir).map_err(anyhow::Error::msg)?;
        let t = truth(s);
        let summary = |m: &SharpnessMap| {
            m.summary(SharpnessUnit::LpPerPictureHeight)
                .map_or_else(String::new, |x| {
                    format!("centre {:.1}, corners {:.1} lp/ph", x.centre, x.corners)
                })
        };
        println!(
            "sharpness map at {} mm f/{}: predicted median error {:.2} % ({}; truth {})",
            s.focal_mm,
            s.f_number,
            100.0 * map.median_relative_error(&t).context("comparable maps")?,
            summary(&map),
            summary(&t)
        );
        if s == setting {
            let png = out.join("sharpness_predicted.png");
            map.write_png(&png, SharpnessUnit::LpPerPictureHeight, 960)
                .map_err(anyhow::Error::msg)?;
            println!("{} written", png.display());
        }
    }
    let cache = out.join(lensblur::pipeline::RESULTS_DIR);
    let measured = std::fs::read_dir(&cache)?
        .filter_map(Result::ok)
        .filter_map(|e| lensblur::kernel::file::KernelsFile::load(&e.path()).ok())
        .find(|k| k.focal_mm == Some(setting.focal_mm) && k.f_number == Some(setting.f_number))
        .context("the chart shot's kernels in the cache")?;
    let map = SharpnessMap::measured(&measured, Channel::G, dir, "measured".into())
        .map_err(anyhow::Error::msg)?;
    let cells = map.cycles_per_px.iter().filter(|v| v.is_finite()).count();
    println!(
        "sharpness map measured on the chart shot: median error {:.2} % ({cells} of {} cells reached by the chart)",
        100.0
            * map
                .median_relative_error(&truth(setting))
                .context("comparable maps")?,
        map.cycles_per_px.len()
    );
    Ok(())
}

fn project_event(e: &lensblur::project::ShotEvent) {
    if let lensblur::project::ShotEvent::Started { index, total, .. } = e {
        eprintln!("shot {} of {total}", index + 1);
    }
}

/// The photo's centre (a third of its width, 60 % of its height), blurry left and
/// deblurred right, each pixel drawn 2 × 2, sRGB-encoded.
fn write_before_after(path: &std::path::Path, a: [&Plane; 3], b: [&Plane; 3]) -> Result<()> {
    let (w, h) = (a[1].width, a[1].height);
    let (cw, ch) = (w / 3, h * 3 / 5);
    let (x0, y0) = ((w - cw) / 2, (h - ch) / 2);
    let gap = 4;
    let mut img = image::RgbImage::new((2 * cw * 2 + gap) as u32, (ch * 2) as u32);
    for (side, planes) in [a, b].iter().enumerate() {
        for y in 0..ch * 2 {
            for x in 0..cw * 2 {
                let i = (y0 + y / 2) * w + x0 + x / 2;
                let px = image::Rgb(std::array::from_fn(|c| {
                    (lensblur::plane::srgb_encode(planes[c].data[i].clamp(0.0, 1.0)) * 255.0)
                        .round() as u8
                }));
                img.put_pixel((side * (cw * 2 + gap) + x) as u32, y as u32, px);
            }
        }
    }
    img.save(path)?;
    Ok(())
}
