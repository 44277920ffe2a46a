//! The kernel-shape model's figures: a 5 × 5 × 2 calibration session of a lens whose
//! PSFs are not Gaussian (measured kernels stood in for by the lens's true pixel-level
//! kernels plus estimation noise), its cross-validated shape model (held-out kernel
//! error per aperture against the Gaussians alone), the profile's size, and deblurring
//! at settings between the calibrated ones with the true kernels, the predicted
//! Gaussians and the predicted shapes.
//!
//! With `measured`, the session is the real chain instead: every shot simulated (a
//! 12 × 8 chart unless `cols=`/`rows=` say otherwise, RAW Bayer, realistic noise),
//! detected, and its kernels estimated;
//! `cache=DIR` keeps each shot's kernels file there and reads it back on the next run
//! (of the same lens, size, chart and lateral colour: the files do not say which).
//!
//! With `colour`, the demo's photo (RGB) is blurred through the lens's true kernels per
//! channel and deblurred the three ways at a wide-open and a stopped-down setting
//! between the calibrated ones, and each of five crops scored by the colour error at
//! edges and SSIM; a neutral dead-leaves scene too, where every colour is a fringe.
//! `lateral=M` gives the lens lateral colour: red magnified by M against green, blue by
//! −M. Each crop's second line, `held`, scores the same deblurs as a user gets them,
//! with the default fringe hold (each pixel's chroma kept inside the blurry photo's
//! around it). `centred` deblurs with every kernel centred on its pixel, as profiles did
//! before they kept where each channel's kernels sit.
//!
//! With `truth` (and `measured`), the measured kernels are first compared with the
//! lens's true ones at five settings.
//!
//! `cargo run --release --example kernel_shapes -- [aberrated|comet] [W H] [measured
//! [truth]] [cols=12] [rows=8] [shots=2] [pixel] [colour [centred]] [lateral=M]
//! [holdout=setting] [cache=DIR]`
//! (`pixel`: the pixel space among the candidates; `holdout=setting`: cross-validation
//! holds out whole settings)

use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::crossval::{CvOptions, HoldOut, ShapeCriterion, ShapeCvOptions, ShapeCvPoint};
use lensblur::experiment::compare_kernel_models;
use lensblur::job::JobContext;
use lensblur::model::ShapeSpace;
use lensblur::plane::{Channel, LensSetting};
use lensblur::simulate::SimulatedSession;
use lensblur::simulate::lens::{PsfShape, VirtualLens};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let lens = match args.first().map(String::as_str) {
        Some("aberrated") | None => VirtualLens::aberrated(),
        Some("comet") => VirtualLens {
            shape: PsfShape::Comet,
            ..VirtualLens::demo()
        },
        Some(other) => anyhow::bail!("unknown lens '{other}'"),
    };
    let mut lens = lens;
    if let Some(m) = args
        .iter()
        .find_map(|a| a.strip_prefix("lateral=")?.parse::<f64>().ok())
    {
        lens.geometry.lateral_colour = [m, -m];
    }
    let size = |i: usize, d: usize| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let (w, h) = (size(1, 960), size(2, 640));
    // name=value options: cols, rows (the chart), shots (per setting).
    let option = |name: &str, default: usize| {
        args.iter()
            .filter_map(|a| a.strip_prefix(name)?.strip_prefix('='))
            .find_map(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let settings = lens.setting_grid(5, 5);
    let t0 = std::time::Instant::now();
    let cache = args
        .iter()
        .find_map(|a| a.strip_prefix("cache="))
        .map(std::path::PathBuf::from);
    let ds = if args.iter().any(|a| a == "measured") {
        let chart = (option("cols", 12), option("rows", 8));
        measured_session(&lens, &settings, (w, h), chart, cache.as_deref())?
    } else {
        SimulatedSession {
            cols: option("cols", 12),
            rows: option("rows", 8),
            shots_per_setting: option("shots", 2),
            kernel_noise: Some(0.01),
            seed: 31,
            ..SimulatedSession::new(w, h)
        }
        .dataset(&lens, &settings)
    };
    eprintln!(
        "{} shots, {} kernels measured in {:.1} s",
        ds.shots.len(),
        ds.samples.len(),
        t0.elapsed().as_secs_f64()
    );
    if args.iter().any(|a| a == "truth") {
        measured_against_truth(&ds, &lens, &settings, (w, h));
    }
    let t1 = std::time::Instant::now();
    let spaces = if args.iter().any(|a| a == "pixel") {
        vec![ShapeSpace::Whitened, ShapeSpace::Pixel]
    } else {
        vec![ShapeSpace::Whitened]
    };
    // `holdout=setting`: every shot of a setting held out together, so the held-out
    // errors are those of settings the model has not seen (with two shots a setting,
    // holding out one shot leaves its twin in the training set).
    let hold_out = if args.iter().any(|a| a == "holdout=setting") {
        HoldOut::Setting
    } else {
        HoldOut::Shot
    };
    let opts = |criterion: ShapeCriterion| CalibrateOptions {
        families: Families::Global,
        cv: CvOptions {
            hold_out,
            ..CvOptions::default()
        },
        shape: Some(ShapeCvOptions {
            spaces: spaces.clone(),
            criterion,
            ..ShapeCvOptions::default()
        }),
        ..CalibrateOptions::default()
    };
    let (profile, _) = calibrate(
        &ds,
        None,
        &opts(ShapeCriterion::Restoration),
        &JobContext::silent(),
    )?;
    if let Some(c) = &profile.place {
        eprintln!(
            "place: α {} β {}, held out {:.4} px against {:.4} px centred",
            c.alpha,
            c.beta,
            c.cv.iter().map(|p| p.rms_px).fold(f64::INFINITY, f64::min),
            c.centred_rms_px
        );
        if args.iter().any(|a| a == "place") {
            place_figures(&profile, &lens, (w, h));
        }
    }
    let bytes = profile.to_json()?.len();
    eprintln!(
        "calibrated in {:.1} s; profile {:.1} kB",
        t1.elapsed().as_secs_f64(),
        bytes as f64 / 1000.0
    );
    if let Some(cv) = &profile.shape_cv {
        println!(
            "held-out kernels: {} (Gaussians from {}); Gaussian mean relative L2 {:.4} (p95 {:.4})",
            cv.kernels, cv.gaussian_model, cv.gaussian.mean_rel_l2, cv.gaussian.p95_rel_l2
        );
        let line = |what: &str, b: &ShapeCvPoint| {
            println!(
                "{what}: {} components ({} space), α = {}, β = {}: relative L2 mean {:.4} (p95 {:.4}), restoration error {:.5}",
                b.components,
                b.space.name(),
                b.alpha,
                b.beta,
                b.mean_rel_l2,
                b.p95_rel_l2,
                b.restoration_rms.unwrap_or(f64::NAN)
            );
        };
        line("Gaussians alone", &cv.gaussian);
        if let Some(b) = &cv.best_shape {
            line("chosen by restoration error", b);
        }
        if let Some(b) = &cv.best_by_l2 {
            line("chosen by held-out L2", b);
        }
        println!("kept: {}", cv.shape_chosen);
        println!("f-number  kernels  Gaussian  shape   | restoration: Gaussian shape");
        for a in &cv.per_aperture {
            println!(
                "f/{:<6.2}  {:>7}  {:.4}    {:.4}  |              {:.5}  {:.5}",
                a.f_number,
                a.kernels,
                a.gaussian_mean_rel_l2,
                a.shape_mean_rel_l2,
                a.gaussian_restoration_rms.unwrap_or(f64::NAN),
                a.shape_restoration_rms.unwrap_or(f64::NAN)
            );
        }
    }
    // The profile held-out L2 would have made, where it chooses another model.
    let same_choice = profile.shape_cv.as_ref().is_none_or(|cv| {
        let key = |p: &ShapeCvPoint| (p.space, p.alpha, p.components);
        cv.best_shape.as_ref().map(key) == cv.best_by_l2.as_ref().map(key)
    });
    let profile_l2 = if same_choice {
        None
    } else {
        let (p, _) = calibrate(
            &ds,
            None,
            &opts(ShapeCriterion::HeldOutL2),
            &JobContext::silent(),
        )?;
        Some(p)
    };
    if profile.shape.is_none() && profile_l2.is_none() {
        return Ok(());
    }
    if args.iter().any(|a| a == "colour") {
        let mut profile = profile;
        if args.iter().any(|a| a == "centred") {
            // Every kernel centred on its pixel, as profiles before the place model.
            profile.place = None;
        }
        return colour_figures(&profile, &lens, (w, h));
    }
    println!(
        "setting           channel  blurry  true    Gaussian shape  shape(L2) | corners: true Gaussian shape  shape(L2)"
    );
    let mut crops = Vec::new();
    for (i, (focal_mm, f_number, ch)) in [
        (31.0, 4.5, Channel::G),
        (62.0, 4.5, Channel::R),
        (88.0, 4.5, Channel::B),
        (45.0, 7.1, Channel::G),
        (75.0, 8.5, Channel::G),
    ]
    .into_iter()
    .enumerate()
    {
        let setting = LensSetting { focal_mm, f_number };
        let compare = |p: &lensblur::profile::Profile| {
            compare_kernel_models(
                p,
                &lens,
                ch,
                setting,
                (w, h),
                40 + i as u64,
                0.005,
                &JobContext::silent(),
            )
            .map_err(anyhow::Error::msg)
        };
        let r = compare(&profile)?;
        crops.push((focal_mm, f_number, ch, r));
        // The same photo and noise (same seed): only the shape model differs.
        let l2 = match &profile_l2 {
            Some(p) => Some(compare(p)?),
            None => None,
        };
        let (l2_all, l2_corners) =
            l2.map_or((r.shape, r.corners_shape), |l| (l.shape, l.corners_shape));
        println!(
            "{focal_mm:>5} mm f/{f_number:<4}  {ch}        {:.4}  {:.4}  {:.4}   {:.4}  {:.4}    |          {:.4} {:.4}   {:.4}  {:.4}",
            r.blurry,
            r.truth,
            r.gaussian,
            r.shape,
            l2_all,
            r.corners_truth,
            r.corners_gaussian,
            r.corners_shape,
            l2_corners
        );
    }
    println!(
        "five crops, SSIM as they are | each crop aligned first (largest shift, px): blurry true Gaussian shape"
    );
    for (focal_mm, f_number, ch, r) in crops {
        let [a, b] = [r.crops, r.crops_registered].map(|v| v.map(|x| format!("{x:.4}")).join(" "));
        let shifts = r.largest_shift_px.map(|x| format!("{x:.2}")).join(" ");
        println!("{focal_mm:>5} mm f/{f_number:<4}  {ch}   {a} | {b} ({shifts})");
    }
    Ok(())
}

/// The session's kernels against the lens's true ones at five of its settings (the
/// first shot of each): mean relative L2 of the kernels as stored, of their PSF mass
/// (what the shape model learns from) and of their robust Gaussians, and the ratio of
/// the stored kernels' second moments to the true ones per channel (kernels compared on
/// their grids as they are: a measured kernel's grid centre is its square's
/// registration, the truth's the lens's ideal image point). Then where the kernels sit:
/// over the squares beyond 0.6 of the frame's half-width, the mean radial position
/// (outward positive, px) of each kernel's peak and centroid, measured and true.
fn measured_against_truth(
    ds: &lensblur::model::Dataset,
    lens: &VirtualLens,
    settings: &[LensSetting],
    (w, h): (usize, usize),
) {
    use lensblur::model::{psf_mass, relative_l2};
    println!(
        "kernels against the truth: setting, relative L2 of stored / PSF mass / Gaussian, second moments ÷ true (R G B) stored; PSF mass"
    );
    for si in [0, 2, 4, 12, 24] {
        let Some(&st) = settings.get(si) else {
            continue;
        };
        let (mut sums, mut n) = ([0.0; 3], 0.0);
        let mut spread = [(0.0, 0.0, 0.0); 3];
        // Per channel: peak and centroid, measured then true, and the count.
        let mut radial = [[0.0; 5]; 3];
        for s in ds.samples.iter().filter(|s| s.shot == 2 * si) {
            let Some(k) = &s.kernel else { continue };
            let (u, v) = VirtualLens::normalised(s.x, s.y, w, h);
            let t = lens
                .optical_kernel_uv(s.channel, u, v, st, 3)
                .pixel_integrated();
            sums[0] += relative_l2(k, &t);
            sums[1] += relative_l2(&psf_mass(k), &t);
            sums[2] += relative_l2(&s.gaussian.kernel(3), &t);
            n += 1.0;
            let c = match s.channel {
                Channel::R => 0,
                Channel::B => 2,
                _ => 1,
            };
            let (mk, mp, mt) = (k.moments(), psf_mass(k).moments(), t.moments());
            spread[c].0 += mk.var_x + mk.var_y;
            spread[c].1 += mp.var_x + mp.var_y;
            spread[c].2 += mt.var_x + mt.var_y;
            let r = u.hypot(v);
            if r > 0.6 {
                let out = [u / r, v / r];
                let along = |p: [f64; 2]| p[0] * out[0] + p[1] * out[1];
                radial[c][0] += along(peak_px(k));
                radial[c][1] += along([mk.mean_x, mk.mean_y]);
                radial[c][2] += along(peak_px(&t));
                radial[c][3] += along([mt.mean_x, mt.mean_y]);
                radial[c][4] += 1.0;
            }
        }
        println!(
            "{:>5.1} mm f/{:<5.2}  {:.3} / {:.3} / {:.3}   {:.2} {:.2} {:.2}; {:.2} {:.2} {:.2}",
            st.focal_mm,
            st.f_number,
            sums[0] / n,
            sums[1] / n,
            sums[2] / n,
            spread[0].0 / spread[0].2,
            spread[1].0 / spread[1].2,
            spread[2].0 / spread[2].2,
            spread[0].1 / spread[0].2,
            spread[1].1 / spread[1].2,
            spread[2].1 / spread[2].2
        );
        let sits: Vec<String> = ["R", "G", "B"]
            .iter()
            .zip(&radial)
            .map(|(name, a)| {
                let m = a[4].max(1.0);
                format!(
                    "{name} {:+.2} {:+.2} / {:+.2} {:+.2}",
                    a[0] / m,
                    a[1] / m,
                    a[2] / m,
                    a[3] / m
                )
            })
            .collect();
        println!(
            "    outer squares, radial px, peak centroid measured / true: {}",
            sits.join("; ")
        );
    }
}

/// Where a kernel's largest sample lies, px from its grid centre.
fn peak_px(k: &lensblur::psf::Kernel) -> [f64; 2] {
    let best = k
        .data
        .iter()
        .enumerate()
        .fold((0, f64::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
    let half = (k.size / 2) as f64;
    let os = k.oversample as f64;
    [
        ((best.0 % k.size) as f64 - half) / os,
        ((best.0 / k.size) as f64 - half) / os,
    ]
}

/// Two shots per setting through simulate → detect → kernels, as `lensblur calibrate`
/// measures a session.
fn measured_session(
    lens: &VirtualLens,
    settings: &[LensSetting],
    (w, h): (usize, usize),
    (cols, rows): (usize, usize),
    cache: Option<&std::path::Path>,
) -> anyhow::Result<lensblur::model::Dataset> {
    use lensblur::chart::ChartSpec;
    use lensblur::kernel::KernelParams;
    use lensblur::pipeline::{self, GivenSetting, Measurement};
    use lensblur::simulate::{CaptureParams, Pose, simulate_shot};
    let chart = ChartSpec {
        cols,
        rows,
        ..ChartSpec::default()
    };
    let m = Measurement::new(chart.clone(), KernelParams::default());
    let job = JobContext::silent();
    let mut files = Vec::new();
    for (i, &setting) in settings.iter().enumerate() {
        for rep in 0..2 {
            let mut cp = CaptureParams::new(w, h, setting);
            cp.seed = 100 + (2 * i + rep) as u64;
            cp.pose = Pose {
                rotation_deg: if rep == 0 { 0.8 } else { -1.1 },
                fill: 0.86,
                shift_px: [rep as f64 * 7.0, rep as f64 * -5.0],
                ..Pose::default()
            };
            let name = std::path::PathBuf::from(format!("shot-{i:02}-{rep}"));
            let cached = cache.map(|d| d.join(format!("{}.kernels.json", name.display())));
            if let Some(path) = cached.as_ref().filter(|p| p.exists()) {
                let k = lensblur::kernel::file::KernelsFile::load(path)?;
                files.push((name.display().to_string(), k, Some(setting)));
                continue;
            }
            let sim = simulate_shot(&chart, lens, &cp, &job)?;
            let det = pipeline::detect(&sim.capture, &name, &m, &job)?;
            let given = GivenSetting {
                focal_mm: Some(setting.focal_mm),
                f_number: Some(setting.f_number),
            };
            let k = pipeline::estimate(&sim.capture, &det, &name, given, &m, true, &job)?;
            eprintln!("{}: {} kernels", name.display(), k.samples.len());
            if let Some(path) = &cached {
                lensblur::io::write_atomic(path, &serde_json::to_vec(&k)?)?;
            }
            files.push((name.display().to_string(), k, Some(setting)));
        }
    }
    let shots: Vec<(
        &str,
        &lensblur::kernel::file::KernelsFile,
        Option<LensSetting>,
    )> = files.iter().map(|(n, k, s)| (n.as_str(), k, *s)).collect();
    Ok(lensblur::model::Dataset::from_kernels(&shots)?)
}

/// The colour-at-edges and SSIM figures per crop (see the module's comment).
fn colour_figures(
    profile: &lensblur::profile::Profile,
    lens: &VirtualLens,
    (w, h): (usize, usize),
) -> anyhow::Result<()> {
    use lensblur::experiment::compare_colour;
    use lensblur::plane::Plane;
    use lensblur::simulate::scene::dead_leaves;
    // Wider than any kernel of these lenses at these sizes, lateral colour included.
    let pad = 40;
    let (pw, ph) = (w + 2 * pad, h + 2 * pad);
    let photo = lensblur::simulate::demo::sharp_photo(pw, ph).map_err(anyhow::Error::msg)?;
    let leaves = dead_leaves(pw, ph, 7);
    let neutral: [Plane; 3] = [leaves.clone(), leaves.clone(), leaves];
    println!(
        "colour error at edges (RMS of R-G, B-G vs sharp, strongest 10 %) and SSIM (mean RGB) per crop"
    );
    println!(
        "scene      setting        crop          colour: blurry true Gauss shape | SSIM: blurry true Gauss shape | aligned: blurry true Gauss shape"
    );
    for (scene, sharp) in [("astronaut", &photo), ("leaves", &neutral)] {
        for (i, (focal_mm, f_number)) in [(31.0, 4.5), (75.0, 7.1)].into_iter().enumerate() {
            let setting = LensSetting { focal_mm, f_number };
            let crops = compare_colour(
                profile,
                lens,
                setting,
                sharp,
                pad,
                (w, h),
                60 + i as u64,
                0.005,
                &JobContext::silent(),
            )
            .map_err(anyhow::Error::msg)?;
            // Four figures each: blurry, true kernels, Gaussians, shapes.
            let four = |v: [f64; 4]| v.map(|x| format!("{x:.4}")).join(" ");
            let scores = |s: &lensblur::experiment::CropScores| {
                format!(
                    "{} | {} | {}",
                    four(s.colour),
                    four(s.ssim),
                    four(s.ssim_registered)
                )
            };
            for c in &crops {
                println!(
                    "{scene:<10} {focal_mm:>4} mm f/{f_number:<4} {:<13} {}",
                    c.name,
                    scores(&c.alone)
                );
                // The same deblurs with the default fringe hold (chroma inside the
                // blurry photo's); the blurry column repeats the unheld figure.
                println!("{:<28}{:<14}{}", "", "held", scores(&c.held));
            }
        }
    }
    Ok(())
}

/// Predicted against true kernel centroids (px) at the frame's centre, the corner crops'
/// centres and the frame's corners, per channel, at the wide-open test setting.
fn place_figures(profile: &lensblur::profile::Profile, lens: &VirtualLens, (w, h): (usize, usize)) {
    use lensblur::model::LateralColour;
    let s = LensSetting {
        focal_mm: 31.0,
        f_number: 4.5,
    };
    let c = (w.min(h) / 4) as f64;
    let (wf, hf) = ((w - 1) as f64, (h - 1) as f64);
    for (name, x, y) in [
        ("centre", wf / 2.0, hf / 2.0),
        ("top-left crop", c / 2.0, c / 2.0),
        ("bottom-right crop", wf - c / 2.0, hf - c / 2.0),
        ("top-left corner", 0.0, 0.0),
    ] {
        for ch in [Channel::R, Channel::G, Channel::B] {
            let m = lens.pixel_kernel_at(ch, x, y, (w, h), s).moments();
            let t = [m.mean_x, m.mean_y];
            let p = profile
                .place
                .as_ref()
                .and_then(|m| m.centroid(ch, x, y, s, LateralColour::Correct));
            eprintln!(
                "{name:<18} {ch}: true {:+.3} {:+.3}  predicted {}",
                t[0],
                t[1],
                p.map_or("-".into(), |p| format!("{:+.3} {:+.3}", p[0], p[1]))
            );
        }
    }
}
