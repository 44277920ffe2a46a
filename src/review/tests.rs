use super::*;
use crate::job::JobContext;
use crate::kernel::file::KernelsFile;
use crate::model::{BlurSample, Dataset, KernelModel, ShotInfo, relative_l2};
use crate::plane::{CameraIdentity, Capture, Channel, ChannelPlane, LensSetting, Plane};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Kernel};

/// A comet lens's session with measured kernels, calibrated with and without shape
/// models, and one shot's samples as a kernels file.
fn comet_profiles() -> (Profile, Profile, KernelsFile) {
    use crate::calibrate::{CalibrateOptions, Families, calibrate};
    use crate::kernel::file::{KERNELS, KernelData, KernelSample};
    use crate::simulate::{PsfShape, SimulatedSession, VirtualLens};
    let lens = VirtualLens {
        shape: PsfShape::Comet,
        ..VirtualLens::demo()
    };
    let mut settings = Vec::new();
    for focal_mm in [24.0, 60.0, 105.0] {
        for f_number in [4.0, 10.0] {
            settings.push(LensSetting { focal_mm, f_number });
        }
    }
    let ds = SimulatedSession {
        cols: 6,
        rows: 4,
        kernel_noise: Some(0.01),
        seed: 3,
        ..SimulatedSession::new(240, 160)
    }
    .dataset(&lens, &settings);
    let opts = CalibrateOptions {
        families: crate::calibrate::Families::Global,
        alpha: Some(2),
        beta: Some(1),
        ..CalibrateOptions::default()
    };
    let job = JobContext::silent();
    let (with_shape, _) = calibrate(&ds, None, &opts, &job).expect("calibrate");
    let (without, _) = calibrate(
        &ds,
        None,
        &CalibrateOptions {
            shape: None,
            families: Families::Global,
            ..opts
        },
        &job,
    )
    .expect("calibrate");
    let shot = &ds.shots[0];
    let samples = ds
        .samples
        .iter()
        .filter(|s| s.shot == 0)
        .map(|s| KernelSample {
            x: s.x,
            y: s.y,
            channel: s.channel,
            cxx: Some(s.gaussian.sigma_x),
            cyy: Some(s.gaussian.sigma_y),
            cor: Some(s.gaussian.rho),
            row: None,
            col: None,
            ml: None,
            kernel: s.kernel.as_ref().map(|k| KernelData {
                size: k.size,
                data: k.data.clone(),
            }),
        })
        .collect();
    let file = KernelsFile {
        schema: KERNELS.tag(),
        width: ds.width,
        height: ds.height,
        focal_mm: Some(shot.focal_mm),
        f_number: Some(shot.f_number),
        focus_distance_m: None,
        oversample: 3,
        identity: None,
        source: None,
        picture: None,
        samples,
        failed: Vec::new(),
    };
    (with_shape, without, file)
}

#[test]
fn predicted_kernel_errors_favour_shapes_on_a_comet_lens() {
    let (with_shape, without, file) = comet_profiles();
    assert!(with_shape.shape.is_some(), "the comet's shapes were kept");
    assert_eq!(no_shape_reason(&with_shape), None);
    let reason = no_shape_reason(&without).expect("no shape model");
    assert!(reason.contains("no shape cross-validation"), "{reason}");

    let errors = kernel_errors(&with_shape, &file, Channel::G);
    assert_eq!(errors.len(), file.samples.len());
    let judged: Vec<KernelError> = errors.iter().flatten().copied().collect();
    let greens = file
        .samples
        .iter()
        .filter(|s| s.channel == Channel::G)
        .count();
    assert_eq!(judged.len(), greens, "every green sample judged");
    let mean =
        |f: &dyn Fn(&KernelError) -> f64| judged.iter().map(f).sum::<f64>() / judged.len() as f64;
    let gaussian = mean(&|e| e.gaussian);
    let shape = mean(&|e| e.shape.unwrap_or(f64::NAN));
    assert!(shape < gaussian, "shapes {shape} vs Gaussian {gaussian}");
    // Without a shape model only the Gaussian is judged, and identically.
    let plain = kernel_errors(&without, &file, Channel::G);
    assert!(plain.iter().flatten().all(|e| e.shape.is_none()));

    let points = [[40.0, 30.0], [120.0, 80.0]];
    let s = LensSetting {
        focal_mm: file.focal_mm.unwrap_or(24.0),
        f_number: file.f_number.unwrap_or(4.0),
    };
    let shapes = predicted_kernels(&with_shape, KernelModel::Shape, Channel::G, &points, s)
        .expect("shape kernels");
    let gaussians = predicted_kernels(&with_shape, KernelModel::Gaussian, Channel::G, &points, s)
        .expect("Gaussian kernels");
    assert_eq!(shapes.len(), 2);
    assert_eq!((shapes[1].x, shapes[1].y), (120.0, 80.0));
    assert!(relative_l2(&shapes[0].kernel, &gaussians[0].kernel) > 1e-3);
    assert!(
        predicted_kernels(&without, KernelModel::Shape, Channel::G, &points, s).is_err(),
        "no shape model, no shape kernels"
    );
}

#[test]
fn regions_stay_inside_and_even() {
    let r = Region::around(5.0, 3.0, 64, 100, 80);
    assert_eq!((r.x0, r.y0, r.width, r.height), (0, 0, 64, 64));
    let r = Region::around(99.0, 79.0, 64, 101, 80);
    assert_eq!((r.x0 + r.width <= 101, r.y0 + r.height <= 80), (true, true));
    assert_eq!((r.x0 % 2, r.y0 % 2), (0, 0));
    let r = Region::around(50.0, 40.0, 500, 100, 80);
    assert_eq!((r.width, r.height), (100, 80));
    let g = Region::around(50.0, 40.0, 20, 100, 80).grown(13, 100, 80);
    assert_eq!((g.x0 % 2, g.y0 % 2, g.width % 2), (0, 0, 0));
    assert!(g.x0 + g.width <= 100 && g.y0 + g.height <= 80);
}

#[test]
fn crops_keep_sensor_positions() {
    // A Bayer-like capture: an R plane at even sites, values = sensor x + 1000 y.
    let (w, h) = (40, 30);
    let plane = Plane::from_fn(w / 2, h / 2, |i, j| (2 * i + 1000 * 2 * j) as f32);
    let cap = Capture {
        width: w,
        height: h,
        planes: vec![ChannelPlane {
            channel: Channel::R,
            plane,
            step: 2,
            offset_x: 0,
            offset_y: 0,
        }],
        setting_focal_mm: None,
        setting_f_number: None,
        setting_focus_m: None,
        identity: CameraIdentity::default(),
        is_raw: true,
        raw: None,
    };
    let r = Region::around(20.0, 15.0, 10, w, h);
    let c = crop_capture(&cap, r);
    let cp = &c.planes[0];
    let [x, y] = cp.sensor_from_plane(1.0, 2.0);
    let v = cp.plane.get(1, 2);
    assert_eq!(v, (x as usize + r.x0 + 1000 * (y as usize + r.y0)) as f32);
}

#[test]
fn truth_field_and_curve_are_the_pixel_truth_at_their_points() {
    let lens = crate::simulate::VirtualLens::demo();
    let size = (120, 80);
    let s = LensSetting {
        focal_mm: lens.focal_range_mm[0],
        f_number: lens.f_number_range[0],
    };
    let field = truth_field(&lens, Channel::G, size, (3, 2), s);
    let grid = field_grid(size.0, size.1, 3, 2);
    assert_eq!(field.len(), grid.len());
    for ((x, y, g), [gx, gy]) in field.iter().zip(&grid) {
        assert_eq!((*x, *y), (*gx, *gy));
        assert_eq!(
            *g,
            truth_pixel_gaussian(&lens, Channel::G, (*x, *y), size, s)
        );
    }
    let settings = sweep_settings(lens.f_number_range, s.focal_mm, true, 4);
    let curve = truth_curve(&lens, Channel::R, (10.0, 20.0), size, &settings);
    assert_eq!(curve.len(), settings.len());
    assert!(curve.iter().zip(&settings).all(|((a, _), b)| a == b));
}

#[test]
fn sweep_points_follow_the_fixed_setting() {
    let mut ds = Dataset::new(100, 100, CameraIdentity::default());
    let g = |s: f64| Gaussian2::isotropic(s);
    for (f, a) in [(24.0, 4.0), (24.0, 8.0), (50.0, 4.0)] {
        let samples = [(10.0, 10.0, 1.0), (90.0, 90.0, 2.0)].map(|(x, y, s)| BlurSample {
            shot: 0,
            x,
            y,
            focal_mm: 0.0,
            f_number: 0.0,
            channel: Channel::G,
            gaussian: g(s * a / 4.0),
            square: None,
            kernel: None,
        });
        ds.push_shot(
            ShotInfo {
                name: format!("{f}-{a}"),
                focal_mm: f,
                f_number: a,
                focus_distance_m: None,
            },
            samples,
        );
    }
    let p = sweep_points(&ds, Channel::G, (80.0, 85.0), true, 24.0);
    assert_eq!(p.len(), 2);
    assert_eq!(p[0].setting.f_number, 4.0);
    assert_eq!((p[1].x, p[1].gaussian.sigma_x), (90.0, 4.0));
    let q = sweep_points(&ds, Channel::G, (0.0, 0.0), false, 4.0);
    assert_eq!(
        q.iter().map(|p| p.setting.focal_mm).collect::<Vec<_>>(),
        [24.0, 50.0]
    );
    assert!(sweep_points(&ds, Channel::R, (0.0, 0.0), false, 4.0).is_empty());
    // The squares are 113 px apart: a point 155 px from the nearest is another place
    // of the lens, and no shot has a sample there.
    assert!(sweep_points(&ds, Channel::G, (-100.0, -100.0), true, 24.0).is_empty());
    assert_eq!(p.iter().map(|p| p.shot).collect::<Vec<_>>(), [0, 1]);
    assert_eq!(nearest_value(&[4.0, 5.6, 10.0], 6.0), Some(5.6));
}

/// The tail fraction of the simulator's true kernels (each shape, over the field and
/// the settings, clean and with the simulated measurement noise) and of the same
/// clean kernels with striped tails added: the numbers behind
/// [`NOISY_TAIL_FRACTION`] (shown with --nocapture).
fn truth_tail_fractions(shape: crate::simulate::PsfShape, noise: f64, stripes: f64) -> (f64, f64) {
    use crate::simulate::VirtualLens;
    let lens = VirtualLens {
        shape,
        ..VirtualLens::demo()
    };
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    let mut seed = 7u64;
    for (u, v) in [(0.0, 0.0), (0.9, 0.0), (-0.9, 0.6), (0.7, -0.7)] {
        for focal_mm in [24.0, 105.0] {
            for f_number in [4.0, 10.0] {
                let s = LensSetting { focal_mm, f_number };
                let mut k = Kernel::padded(
                    &lens
                        .optical_kernel_uv(Channel::G, u, v, s, 3)
                        .pixel_integrated(),
                    MEASURED_SIZE,
                );
                let peak = k.data.iter().copied().fold(0.0, f64::max);
                let fit = crate::gaussian::fit_gaussians(&k).0;
                let c = (k.size / 2) as f64;
                for j in 0..k.size {
                    for i in 0..k.size {
                        let (dx, dy) = ((i as f64 - c) / 3.0, (j as f64 - c) / 3.0);
                        // A fixed pseudo-random draw per sample (uniform, the
                        // simulator's 1 % of the peak as its standard deviation).
                        seed = seed
                            .wrapping_mul(6_364_136_223_846_793_005)
                            .wrapping_add(1_442_695_040_888_963_407);
                        let r = ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 12f64.sqrt();
                        let d = (dx / fit.sigma_x).hypot(dy / fit.sigma_y);
                        // Stripes across x, 2 px apart (the sensor's Nyquist),
                        // beyond 2σ: the ringing of a poorly constrained solve.
                        let stripe = if d > 2.0 {
                            stripes * peak * 0.5 * (1.0 + (std::f64::consts::PI * dx).cos())
                        } else {
                            0.0
                        };
                        let v = &mut k.data[j * k.size + i];
                        *v += noise * peak * r + stripe;
                        // As the measurement cleans a kernel: negatives and samples
                        // under 2 % of the peak are zeroed.
                        if *v < 0.02 * peak {
                            *v = 0.0;
                        }
                    }
                }
                k.normalise();
                let tails =
                    kernel_tails(&k, &crate::gaussian::fit_gaussians(&k).0).expect("a fraction");
                let t = tails.rising;
                lo = lo.min(t);
                hi = hi.max(t);
            }
        }
    }
    eprintln!("{shape:?} noise {noise} stripes {stripes}: tail fraction {lo:.4}–{hi:.4}");
    (lo, hi)
}

/// The side the measured chain gives kernels of the demo's σ (±6 px at 3×): the
/// support a measured kernel's stripes and speckle can spread over.
const MEASURED_SIZE: usize = 37;

#[test]
fn clean_simulated_kernels_pass_and_striped_tails_are_flagged() {
    use crate::simulate::PsfShape;
    for shape in [
        PsfShape::Gaussian,
        PsfShape::Disc,
        PsfShape::Comet,
        PsfShape::Aberrated,
    ] {
        let (_, clean) = truth_tail_fractions(shape, 0.0, 0.0);
        assert!(clean < NOISY_TAIL_FRACTION / 2.0, "{shape:?}: {clean}");
        let (_, noisy) = truth_tail_fractions(shape, 0.01, 0.0);
        assert!(noisy < NOISY_TAIL_FRACTION, "{shape:?} with noise: {noisy}");
    }
    let (striped, _) = truth_tail_fractions(PsfShape::Gaussian, 0.0, 0.1);
    assert!(striped > NOISY_TAIL_FRACTION, "striped: {striped}");
    // One kernel, both ways, through the reason the studio shows.
    let g = Gaussian2 {
        sigma_x: 1.2,
        sigma_y: 0.9,
        rho: 0.2,
    };
    let clean = g.kernel(3).padded(MEASURED_SIZE);
    assert_eq!(noisy_kernel_reason(&clean, &g), None);
    let mut striped = clean.clone();
    let peak = striped.data.iter().copied().fold(0.0, f64::max);
    let c = (striped.size / 2) as f64;
    for j in 0..striped.size {
        for i in 0..striped.size {
            let dx = (i as f64 - c) / 3.0;
            let dy = (j as f64 - c) / 3.0;
            if (dx / 1.2).hypot(dy / 0.9) > 2.0 {
                striped.data[j * striped.size + i] +=
                    0.1 * peak * 0.5 * (1.0 + (std::f64::consts::PI * dx).cos());
            }
        }
    }
    striped.normalise();
    let reason = noisy_kernel_reason(&striped, &g).expect("flagged");
    assert!(reason.contains("rise again"), "{reason}");
}

#[test]
fn difference_maps_pair_points_and_ranges_are_symmetric() {
    let g = |s: f64| Gaussian2::isotropic(s);
    let a = [
        (0.0, 0.0, g(2.0)),
        (100.0, 0.0, g(1.0)),
        (500.0, 0.0, g(1.0)),
    ];
    let b = [(1.0, 1.0, g(1.5)), (100.0, 2.0, g(1.25))];
    let d = field_difference(&a, &b, 10.0);
    assert_eq!(d.len(), 2, "the far point has no partner");
    assert!((d[0].delta_sigma() - 0.5).abs() < 1e-12);
    assert!((d[1].delta_sigma() + 0.25).abs() < 1e-12);
    assert_eq!(
        colour_range(d.iter().map(FieldDifference::delta_sigma), true),
        Some([-0.5, 0.5])
    );
    assert_eq!(colour_range([1.0, 3.0, f64::NAN], false), Some([1.0, 3.0]));
    assert_eq!(colour_range([], false), None);
    assert_eq!(nice_ticks([-0.5, 0.5], 4), vec![-0.5, 0.0, 0.5]);
    assert_eq!(nice_ticks([0.93, 3.1], 5), vec![1.0, 1.5, 2.0, 2.5, 3.0]);
}

/// A setting, as the plan's tests write many.
fn setting(focal_mm: f64, f_number: f64) -> LensSetting {
    LensSetting { focal_mm, f_number }
}

/// A 24–105 mm zoom stopping down from f/4 to f/22.
fn zoom_24_105() -> LensRange {
    LensRange {
        focal_mm: [24.0, 105.0],
        f_number: [4.0, 22.0],
    }
}

#[test]
fn the_shooting_plan_spans_the_lens_and_ticks_what_was_shot() {
    let zoom = zoom_24_105();
    let shots = [
        setting(24.0, 4.0),
        setting(24.0, 4.0),
        // Cameras round: 49 mm and f/5.7 are the plan's 50 mm and f/5.6.
        setting(49.0, 5.7),
        // Not in the plan: f/16 is past f/11.
        setting(105.0, 16.0),
    ];
    let all = shooting_plan(&zoom, &shots);
    // The setting off the grid is listed, and counts as shot.
    let off: Vec<&PlannedSetting> = all.iter().filter(|p| !p.on_plan).collect();
    assert_eq!(off.len(), 1);
    assert_eq!(
        (off[0].setting.focal_mm, off[0].setting.f_number),
        (105.0, 16.0)
    );
    assert_eq!(off[0].shot, 1);
    let progress = plan_progress(&all);
    assert_eq!(
        progress,
        PlanProgress {
            settings_shot: 3,
            complete: 1,
            planned: 20,
            planned_shot: 2,
            off_plan: 1,
        }
    );
    let plan: Vec<PlannedSetting> = all.into_iter().filter(|p| p.on_plan).collect();
    let mut focals: Vec<f64> = plan.iter().map(|p| p.setting.focal_mm).collect();
    focals.dedup();
    assert_eq!(focals, vec![24.0, 35.0, 50.0, 73.0, 105.0]);
    let apertures: Vec<f64> = plan
        .iter()
        .filter(|p| p.setting.focal_mm == 24.0)
        .map(|p| p.setting.f_number)
        .collect();
    assert_eq!(apertures, vec![4.0, 5.6, 8.0, 11.0]);
    assert_eq!(plan.len(), 20);
    let at = |f: f64, a: f64| {
        plan.iter()
            .find(|p| p.setting.focal_mm == f && p.setting.f_number == a)
            .map(|p| p.shot)
    };
    assert_eq!(at(24.0, 4.0), Some(2));
    assert_eq!(at(50.0, 5.6), Some(1));
    assert_eq!(plan.iter().map(|p| p.shot).sum::<usize>(), 3);
    assert!(plan.iter().all(|p| p.wanted == SHOTS_PER_SETTING));
    // A prime opening at f/1.8: its one focal length, wide open then whole stops.
    let prime = shooting_plan(
        &LensRange {
            focal_mm: [50.0, 50.0],
            f_number: [1.8, 16.0],
        },
        &[],
    );
    let a: Vec<f64> = prime.iter().map(|p| p.setting.f_number).collect();
    // (f/2 is a third of a stop from f/1.8: too close to tell the model more.)
    assert_eq!(a, vec![1.8, 2.8, 4.0, 5.6, 8.0]);
    assert!(
        prime
            .iter()
            .all(|p| p.setting.focal_mm == 50.0 && p.shot == 0)
    );
}

#[test]
fn shooting_advice_says_what_to_shoot_next() {
    // One focal length: the model cannot follow it.
    let a = shooting_advice(&[50.0], &[4.0, 8.0, 16.0], None);
    assert!(
        a.iter()
            .any(|x| x.level == AdviceLevel::Warning && x.text.contains("Every shot is at 50 mm"))
    );
    // β fixed at 2 with two focal lengths: a third between them.
    let b = shooting_advice(&[24.0, 105.0], &[4.0, 5.6, 10.0], Some(2));
    let w = b
        .iter()
        .find(|x| x.level == AdviceLevel::Warning)
        .expect("warning");
    assert!(
        w.text
            .contains("shoot at least 1 more focal length between 24 mm and 105 mm"),
        "{}",
        w.text
    );
    // The demo's 2 × 2 grid: determined for β ≤ 1, with a note for a curve.
    let c = shooting_advice(&[24.0, 105.0], &[4.0, 10.0], None);
    assert!(c.iter().all(|x| x.level == AdviceLevel::Note), "{c:?}");
    assert!(
        c.iter()
            .any(|x| x.text.contains("between f/4.0 and f/10.0"))
    );
    // Enough of both.
    assert!(shooting_advice(&[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0], None).is_empty());
}

#[test]
fn plot_csv_quotes_axis_titles_and_leaves_out_undrawn_points() {
    let t = PlotTable {
        x_label: "aperture (f-number)".into(),
        y_label: "C_xx (σ, px)".into(),
        series: vec![(
            "model centre".into(),
            vec![[4.0, 1.5], [5.6, f64::NAN], [8.0, 2.0]],
        )],
    };
    assert_eq!(
        plot_csv(&t),
        "series,aperture (f-number),\"C_xx (σ, px)\"\nmodel centre,4,1.5\nmodel centre,8,2\n"
    );
}

#[test]
fn an_aperture_axis_is_in_stops_and_labelled_as_lenses_mark_it() {
    use super::{aperture_stops, f_number_at_stops, f_number_label};
    assert!((aperture_stops(4.0) - 4.0).abs() < 1e-12);
    // f/5.6 is 2^2.5 = 5.66 rounded: a stop from f/8 to within 3 %.
    assert!(
        (aperture_stops(8.0) - aperture_stops(5.6) - 1.0).abs() < 0.03,
        "one stop"
    );
    assert!((f_number_at_stops(aperture_stops(7.1)) - 7.1).abs() < 1e-12);
    let labels: Vec<String> = [4.0, 5.0, 16.0 / 3.0, 6.0, 7.0, 20.0 / 3.0]
        .into_iter()
        .map(f_number_label)
        .collect();
    assert_eq!(labels, ["f/4", "f/5.6", "f/6.3", "f/8", "f/11", "f/10"]);
    assert_eq!(
        f_number_label(4.5),
        "f/4.8",
        "between thirds: the exact value"
    );
}

/// The shooting plan's table: rows and columns ascending and once whatever the plan's
/// order, each cell the setting at its row and column, the setting off the grid in a
/// column of its own.
#[test]
fn the_plan_grid_lays_every_setting_at_its_row_and_column() {
    let zoom = zoom_24_105();
    let shots = [setting(24.0, 4.0), setting(105.0, 16.0)];
    let mut plan = shooting_plan(&zoom, &shots);
    plan.reverse();
    let grid = plan_grid(&plan);
    assert_eq!(grid.focals, vec![24.0, 35.0, 50.0, 73.0, 105.0]);
    assert_eq!(grid.apertures, vec![4.0, 5.6, 8.0, 11.0, 16.0]);
    assert_eq!(grid.cells.len(), grid.focals.len());
    let mut filled = 0;
    for (f, row) in grid.focals.iter().zip(&grid.cells) {
        assert_eq!(row.len(), grid.apertures.len());
        for (a, cell) in grid.apertures.iter().zip(row) {
            if let Some(p) = cell {
                assert_eq!((p.setting.focal_mm, p.setting.f_number), (*f, *a));
                filled += 1;
            }
        }
    }
    assert_eq!(filled, plan.len());
    assert_eq!(grid.cells[0][0].map(|p| p.shot), Some(1));
    assert!(
        grid.cells[0][4].is_none(),
        "f/16 is planned at no focal length"
    );
    let off = grid.cells[4][4].expect("the setting shot off the grid");
    assert!(!off.on_plan);
    assert_eq!(off.shot, 1);
    assert_eq!(
        plan_grid(&[]),
        PlanGrid {
            focals: vec![],
            apertures: vec![],
            cells: vec![],
        }
    );
}

/// A selection whose α and β curves have these mean errors and whose error CDF puts
/// each parameter's 99th percentile at `p99` (and its maximum far beyond).
fn selection(alpha: &[f64], beta: &[f64], p99: [f64; 3]) -> crate::crossval::Selection {
    let point = |mean_pct: f64| crate::crossval::CvPoint {
        alpha: 1,
        beta: 1,
        terms: 1,
        mean_error_pct: [mean_pct; 3],
        p95_error_pct: [mean_pct; 3],
        mean_pct,
    };
    let quantiles = |at99: f64| vec![0.0, at99 / 2.0, at99, 100.0 * at99];
    crate::crossval::Selection {
        kind: crate::model::ModelKind::Global,
        alpha_curve: alpha.iter().copied().map(point).collect(),
        beta_curve: beta.iter().copied().map(point).collect(),
        alpha: 1,
        beta: 1,
        chosen: point(alpha.first().copied().unwrap_or(0.0)),
        error_cdf: crate::crossval::ErrorCdf {
            percentiles: vec![0.0, 50.0, 99.0, 100.0],
            cxx: quantiles(p99[0]),
            cyy: quantiles(p99[1]),
            cor: quantiles(p99[2]),
        },
    }
}

/// The order plots' error axis stops at four times the best error over every family
/// (an overfitted order's hundreds of % above it, noted), or just above the highest
/// point when all lie below that; the CDF's error axis ends just past the largest 99th
/// percentile, not at the worst sample.
#[test]
fn cross_validation_axes_keep_the_minimum_and_the_bulk_readable() {
    let a = selection(&[3.0, 1.5, 2.0, 300.0], &[2.0, 1.6], [4.0, 5.0, 2.0]);
    let b = selection(&[2.0, 2.5], &[1.8, 2.2], [6.0, 1.0, 1.0]);
    let by_alpha = cv_curve_axis([&a, &b], true);
    assert!(
        (by_alpha.top - 4.0 * 1.5 * 1.05).abs() < 1e-12,
        "{by_alpha:?}"
    );
    assert!(by_alpha.points_above);
    let by_beta = cv_curve_axis([&a, &b], false);
    assert!((by_beta.top - 2.2 * 1.05).abs() < 1e-12, "{by_beta:?}");
    assert!(!by_beta.points_above);
    // A near-perfect fit does not shrink the axis below 1 % (4 × 0.25 %).
    let tiny = selection(&[0.01, 5.0], &[], [1.0; 3]);
    assert!((cv_curve_axis([&tiny], true).top - 1.05).abs() < 1e-12);
    let none = cv_curve_axis(std::iter::empty(), true);
    assert_eq!(
        none,
        CvCurveAxis {
            top: 1.0,
            points_above: false
        }
    );
    assert!((cv_cdf_axis_end([&a, &b]) - 6.0 * 1.02).abs() < 1e-12);
    assert!(cv_cdf_axis_end(std::iter::empty()) > 0.0);
}
