//! Snapshot tests of the studio: every view rendered on a small demo session, and the
//! flow driven by clicks through AccessKit labels and pointer events. Snapshots live in
//! `screenshots/` (kittest.toml); `UPDATE_SNAPSHOTS=1` rewrites them.
//!
//! Every test makes its own session folders under a temporary directory, so what the
//! snapshots show depends on nothing outside the test (no cached demo, no home folder).
#![cfg(feature = "gui")]

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use lensblur::app::jobs::JobKind;
use lensblur::app::{
    AppOptions, ColourRange, Command, FieldOptions, FieldShow, FieldSource, PlotId,
    SharpnessChoice, StudioApp, SweepAxis, View,
};
use lensblur::app::{
    DeblurCommand, DialogCommand, GeometryCommand, PlotCommand, SessionCommand, StageCommand,
    ViewCommand, WindowCommand,
};
use lensblur::job::JobContext;
use lensblur::pipeline::ShotFile;
use lensblur::project::{Project, ShotEvent};
use lensblur::session::{Session, ShotId, StageStatus};
use lensblur::simulate::demo::{ChartPlacement, DemoSpec, make_demo};
use std::path::Path;
use std::time::{Duration, Instant};

/// The demo the tests make: small shots of a chart of 8 × 6 squares at a 2 × 2 grid of
/// settings (both sweeps, and cross-validation that holds a shot out and still has a
/// setting on each side for a β = 1 model); its kernels take most of the test's time.
fn test_demo() -> DemoSpec {
    DemoSpec::grid(400, 280, &[24.0, 105.0], &[4.0, 10.0]).with_chart(8, 6)
}

/// The demo the README's and screenshots/' pictures come from: the studio's own
/// 3 × 3 grid of settings (so sweeps are curves and β has more than two points) on the
/// tests' small shots.
fn nine_shot_demo() -> DemoSpec {
    DemoSpec::grid(400, 280, &[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0]).with_chart(8, 6)
}

fn new_harness(demo_dir: &Path, session: Option<&Path>) -> Harness<'static, StudioApp> {
    new_harness_with(demo_dir, session, test_demo())
}

fn new_harness_with(
    demo_dir: &Path,
    session: Option<&Path>,
    demo_spec: DemoSpec,
) -> Harness<'static, StudioApp> {
    harness(options(demo_dir, session, demo_spec))
}

fn options(demo_dir: &Path, session: Option<&Path>, demo_spec: DemoSpec) -> AppOptions {
    // Pin the software Vulkan renderer (lavapipe) so snapshots match across machines.
    // SAFETY: set before any renderer or thread reads it; tests in this file set the same value.
    unsafe { std::env::set_var("WGPU_BACKEND", "vulkan") };
    // RAW files decode in workers of the command line's executable, as the program's
    // `main` sets it for the studio (the test binary itself serves no workers).
    lensblur::raw::set_decoding(lensblur::raw::Decoding::Worker(
        lensblur::raw::WorkerLimits::new(env!("CARGO_BIN_EXE_lensblur").into()),
    ));
    AppOptions {
        session: session.map(Path::to_path_buf),
        demo_dir: demo_dir.to_path_buf(),
        demo_spec,
        log_frame_times: false,
        autorun: Vec::new(),
        // The test's UI thread mostly sleeps between steps: jobs may have every core.
        job_threads: std::thread::available_parallelism().map_or(2, std::num::NonZeroUsize::get),
        started: Instant::now(),
        // In the test's own demo folder: no test sees another's list.
        recent_file: Some(demo_dir.join("recent.json")),
        // The library in the test's folder, never the user's.
        profile_library: demo_dir.join("profiles"),
        settings_file: Some(demo_dir.join("settings.json")),
        // The first-launch calibration is driven where a test asks for it.
        calibrate_demo: false,
        // Notices stay until dismissed, so what a snapshot shows never depends on how
        // long a step took; their fading is tested on its own.
        notice_lifetime: None,
    }
}

fn harness(options: AppOptions) -> Harness<'static, StudioApp> {
    Harness::builder()
        .with_size(egui::Vec2::new(1280.0, 800.0))
        .wgpu()
        .build_eframe(move |cc| StudioApp::new(&cc.egui_ctx, options))
}

/// Waits until the studio's saves so far are on disk: it writes `session.json` on a
/// thread of its own, and a test reading the file must not race it.
fn flush_saves(h: &Harness<'_, StudioApp>) {
    if let Some(p) = h.state().project() {
        p.flush().expect("the session is saved");
    }
}

/// How long a wait may last before the test calls it a hang. Only a guard, never a
/// measure of speed: a machine slower than ours (or busier) must not fail a test, so
/// it is far beyond what any wait takes, and the time each wait took is printed.
const HANG_GUARD: Duration = Duration::from_secs(30 * 60);

/// Steps the UI (in real time, so job threads progress) until `done` holds.
fn step_until(h: &mut Harness<'_, StudioApp>, what: &str, done: impl Fn(&StudioApp) -> bool) {
    let start = Instant::now();
    while !done(h.state()) {
        assert!(
            start.elapsed() < HANG_GUARD,
            "no end after {HANG_GUARD:?} waiting for {what}; jobs running: {:?}; messages: {:?}",
            h.state()
                .jobs()
                .running
                .iter()
                .map(|j| (j.kind, j.progress()))
                .collect::<Vec<_>>(),
            h.state().window().messages
        );
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(20));
    }
    // Where the test's time goes (shown with --nocapture).
    eprintln!("{what}: {:.1} s", start.elapsed().as_secs_f32());
    h.run_steps(2);
}

fn idle(app: &StudioApp) -> bool {
    app.jobs().running.is_empty()
}

/// A snapshot without the pointer: a button left hovered after a click (and the tooltip
/// that appears once the pointer rests long enough) would depend on how many frames ran.
fn snapshot(h: &mut Harness<'_, StudioApp>, name: &str) {
    h.remove_cursor();
    h.run_steps(2);
    h.snapshot(name);
}

/// Saves a plot's CSV and PNG as the dialogs would, and waits for both files.
fn save_plot(h: &mut Harness<'_, StudioApp>, plot: PlotId, csv: &Path, png: &Path) {
    let dir = csv.parent().expect("a folder");
    let path = csv.to_path_buf();
    h.state_mut()
        .push(Command::Plot(PlotCommand::SavePlotCsv { plot, path }));
    let path = png.to_path_buf();
    h.state_mut()
        .push(Command::Plot(PlotCommand::SavePlotPng { plot, path }));
    step_until(h, "the plot's files", |a| {
        csv.is_file() && png.is_file() && a.window().plot_png.is_none()
    });
    assert!(
        h.state()
            .window()
            .messages
            .iter()
            .any(|m| m.text.contains("plot saved to")),
        "{:?}",
        h.state().window().messages
    );
    // The messages name the temporary folder, which differs between runs: off the
    // snapshots that follow.
    h.state_mut()
        .window_mut()
        .messages
        .retain(|m| !m.text.contains(&*dir.to_string_lossy()));
    // The plot and its axes: a third of the window's width, less than half its height
    // in the Sweeps view.
    let img = image::open(png).expect("the plot's PNG decodes");
    assert!(
        (200..=1280).contains(&img.width()) && (100..=800).contains(&img.height()),
        "{} × {}",
        img.width(),
        img.height()
    );
}

/// The CSV has this header and `rows` rows of a series name and two numbers.
fn assert_plot_csv(path: &Path, header: &str, rows: usize) {
    let text = std::fs::read_to_string(path).expect("the plot's CSV");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(header));
    let body: Vec<&str> = lines.collect();
    assert_eq!(body.len(), rows);
    for line in body {
        let fields: Vec<&str> = line.rsplitn(3, ',').collect();
        assert_eq!(fields.len(), 3, "{line}");
        for v in &fields[..2] {
            assert!(v.parse::<f64>().is_ok_and(f64::is_finite), "{line}");
        }
    }
}

/// A primary click at a screen position, as the window would deliver it.
fn click_at(h: &mut Harness<'_, StudioApp>, pos: egui::Pos2) {
    h.hover_at(pos);
    h.run_steps(1);
    for pressed in [true, false] {
        h.event(egui::Event::PointerButton {
            pos,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: egui::Modifiers::NONE,
        });
    }
    h.run_steps(2);
}

#[derive(Debug)]
struct DroppedPath(std::path::PathBuf);

impl egui::DroppedFile for DroppedPath {
    fn path(&self) -> &Path {
        &self.0
    }
    fn bytes(&self) -> Result<Vec<u8>, String> {
        std::fs::read(&self.0).map_err(|e| e.to_string())
    }
}

fn dropped(p: &Path) -> egui::DroppedFileHandle {
    std::sync::Arc::new(DroppedPath(p.to_path_buf()))
}

/// The predicted deblurred region's first plane, as the preview holds it.
fn deblurred_region(app: &StudioApp) -> Vec<f32> {
    app.views()
        .deblur
        .comparison
        .as_ref()
        .and_then(|c| c.comparison.predicted.as_ref().ok())
        .and_then(|p| p.first())
        .map(|(_, plane)| plane.data.clone())
        .unwrap_or_default()
}

fn demo_ready(app: &StudioApp) -> bool {
    app.session()
        .is_some_and(|s| !s.shots.is_empty() && app.previews().count() == s.shots.len())
        && idle(app)
}

#[test]
fn measuring_and_calibrating_the_demo_by_clicking() {
    let dir = tempfile::tempdir().expect("temp dir");
    let demo_dir = dir.path().join("demo");
    let spec = nine_shot_demo();
    let n_shots = spec.settings.len();
    let n_squares = spec.chart.cols * spec.chart.rows;
    let mut h = new_harness_with(&demo_dir, None, spec.clone());
    // The first frame comes before the demo exists: the panel says what is happening
    // and the status bar shows the job's progress.
    h.run_steps(1);
    assert!(h.state().session().is_none());
    h.get_by_label_contains("Making the demo session");
    assert!(h.state().jobs().is_running(JobKind::DemoSession));
    step_until(&mut h, "the demo session", demo_ready);
    let n = h.state().session().map_or(0, |s| s.shots.len());
    assert_eq!(n, n_shots);
    flush_saves(&h);
    assert!(
        demo_dir.join("session.json").is_file(),
        "the demo session is cached"
    );
    snapshot(&mut h, "studio_shot");

    // Detect by clicking; results arrive shot by shot, and Cancel stops the job.
    h.get_by_label("Detect").click();
    step_until(&mut h, "the first detection", |a| {
        a.detections().next().is_some()
    });
    // Stopped before its end (how soon is printed, not tested: a slower machine
    // takes longer).
    h.get_by_label("Cancel").click();
    step_until(&mut h, "the cancelled job", idle);
    let kept = h.state().detections().count();
    assert!(
        (1..n_shots).contains(&kept),
        "{kept} shots detected before the cancel"
    );
    assert!(
        h.state()
            .window()
            .messages
            .iter()
            .any(|m| m.text.contains("detect: cancelled"))
    );
    // Detect again: only the shots without results run; every square is aligned.
    h.get_by_label("Detect").click();
    step_until(&mut h, "detection", |a| {
        a.detections().count() == n_shots && idle(a)
    });
    for (i, d) in h.state().detections() {
        let skipped: Vec<_> = d
            .squares
            .iter()
            .filter(|s| s.status != lensblur::detect::SquareStatus::Ok)
            .map(|s| (s.row, s.col, s.reason.clone()))
            .collect();
        assert!(
            skipped.is_empty(),
            "every square of the demo chart is aligned; shot {i}: {skipped:?}"
        );
        assert_eq!(d.squares.len(), n_squares);
    }
    snapshot(&mut h, "studio_shot_detected");

    // Click a square in the viewer (fit zoom: the viewer's rect maps onto the sensor).
    let (row, col) = (2usize, 3usize);
    let viewer = h.get_by_label("shot viewer").rect();
    let (centre, (w, hgt)) = {
        let app = h.state();
        let first = app.session().expect("session").shots[0].id;
        let det = app.detection(first).expect("detected");
        let sq = det
            .squares
            .iter()
            .find(|s| (s.row, s.col) == (row, col))
            .expect("square detected");
        let c = lensblur::review::square_facts(sq).centre;
        (c, (det.width as f32, det.height as f32))
    };
    let fit = (viewer.width() / w).min(viewer.height() / hgt);
    let pos = viewer.center()
        + egui::Vec2::new(
            (centre[0] as f32 - (w - 1.0) / 2.0) * fit,
            (centre[1] as f32 - (hgt - 1.0) / 2.0) * fit,
        );
    click_at(&mut h, pos);
    // The crops are made on a job thread.
    step_until(&mut h, "the inspector", |a| a.data().inspection().is_some());
    let rms = h
        .state()
        .data()
        .inspection()
        .filter(|i| i.square == (row, col))
        .map(|i| i.crops.residual_rms)
        .expect("the inspector opens on the clicked square");
    assert!(
        rms < 0.05,
        "aligned square explains the pixels: residual rms {rms}"
    );

    // Kernels on every detected shot by clicking.
    h.get_by_label("Kernels").click();
    step_until(&mut h, "kernels", |a| {
        a.measured().count() == n_shots && a.dataset().is_some() && idle(a)
    });
    let session = h.state().session().cloned().expect("session");
    for (id, m) in h.state().measured() {
        // Every square and channel is measured or reported with its reason, and
        // nearly all are measured on clean simulated shots.
        let shot = session.shot(id).expect("measured shot is in the session");
        let shot_file = ShotFile::read(&session.path_of(shot)).expect("shot readable");
        let file = session
            .cache()
            .kernels(&shot_file, &session.measurement())
            .expect("kernels file readable")
            .expect("kernels file written");
        assert_eq!(m.samples.len(), file.samples.len());
        assert_eq!(file.samples.len() + file.failed.len(), 3 * n_squares);
        assert!(file.failed.iter().all(|f| !f.reason.is_empty()));
        assert!(
            file.samples.len() * 100 >= 97 * 3 * n_squares,
            "{} measured",
            file.samples.len()
        );
    }
    // The inspector now shows the square's kernel and its Gaussian's numbers.
    assert!(
        h.state()
            .data()
            .inspection()
            .is_some_and(|i| i.kernel.is_some())
    );
    h.get_by_label_contains("robust fit");
    snapshot(&mut h, "studio_square_inspector");

    h.get_by_label("Kernel field").click();
    h.run_steps(3);
    assert_eq!(h.state().view(), View::KernelField);
    snapshot(&mut h, "studio_kernel_field");
    // The colour range from the data spans the measured σ; fixed, it is what was set.
    {
        let scale = h
            .state()
            .data()
            .field
            .as_ref()
            .and_then(|f| f.scale.clone());
        let [lo, hi] = scale.expect("a colour scale").range;
        assert!(0.3 < lo && lo < hi && hi < 3.0, "{lo}–{hi}");
    }
    h.state_mut()
        .push(Command::View(ViewCommand::SetFieldOptions(FieldOptions {
            range: ColourRange::Fixed { min: 0.5, max: 3.5 },
            difference: None,
        })));
    h.run_steps(2);
    assert_eq!(
        h.state()
            .data()
            .field
            .as_ref()
            .and_then(|f| f.scale.as_ref())
            .map(|s| s.range),
        Some([0.5, 3.5])
    );
    h.state_mut()
        .push(Command::View(ViewCommand::SetFieldOptions(
            FieldOptions::default(),
        )));
    h.run_steps(2);
    h.get_by_label("Kernel shapes").click();
    h.run_steps(3);
    assert!(h.state().data().kernel_atlas.is_some());
    snapshot(&mut h, "studio_kernel_field_kernels");
    noisy_kernel_is_hatched_and_a_click_inspects_it(&mut h, (row, col));

    // Measured points appear in the sweeps before any model exists.
    h.get_by_label("Sweeps").click();
    h.run_steps(3);
    assert!(h.state().profile().is_none());

    // Calibrate by clicking: cross-validation chooses α and β, the profile is written.
    h.get_by_label("Models").click();
    h.run_steps(2);
    h.get_by_label("Calibrate").click();
    step_until(&mut h, "calibration", |a| a.profile().is_some() && idle(a));
    assert!(h.state().cv().is_some(), "cross-validation ran");
    assert!(
        demo_dir.join("profile.json").is_file() && demo_dir.join("crossval.json").is_file(),
        "profile and cross-validation saved in the session"
    );
    // The command line calibrates the studio's session from the same cache, measuring
    // nothing again, to the same profile: on a copy of the folder, since the open
    // session's folder is the studio's while it is open (it refuses a second writer).
    let cli_profile = dir.path().join("cli-profile.json");
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(["calibrate", "--manifest"])
        .arg(&demo_dir)
        .arg("--out")
        .arg(&cli_profile)
        .output()
        .expect("run lensblur calibrate");
    assert!(!refused.status.success() && !cli_profile.exists());
    let copy = dir.path().join("copy");
    flush_saves(&h);
    copy_folder(&demo_dir, &copy);
    let cli = calibrate_on_the_command_line(&copy, &cli_profile);
    assert!(
        cli.contains(&format!("0 shots measured, {n_shots} from the cache")),
        "{cli}"
    );
    assert_same_profile(&cli_profile, &demo_dir.join("profile.json"));
}

/// The nine-shot demo detected, measured and calibrated once per run of these tests,
/// by the core alone as the studio's *Calibrate all* does it (same options, same
/// files): the views' tests each open a copy of it, so each checks one thing and they
/// run side by side, none waiting on another's failure.
fn calibrated_demo() -> &'static Path {
    static DEMO: std::sync::OnceLock<(tempfile::TempDir, std::path::PathBuf)> =
        std::sync::OnceLock::new();
    &DEMO
        .get_or_init(|| {
            let dir = tempfile::tempdir().expect("temp dir");
            let folder = dir.path().join("demo");
            let ctx = JobContext::silent();
            lensblur::simulate::demo::make_demo_streaming(
                &folder,
                &nine_shot_demo(),
                &ctx,
                &mut |_| {},
            )
            .expect("demo");
            let (mut project, _) = Project::open(&folder, "the studio tests").expect("open");
            project.survey(&ctx).expect("survey");
            let options = lensblur::calibrate::CalibrateOptions {
                alpha: project.session().settings.alpha,
                beta: project.session().settings.beta,
                ..Default::default()
            };
            let mut events = Vec::new();
            let cal = project
                .calibrate_all_job(options)
                .run(&ctx, &|_| Some(JobContext::silent()), &mut |e| {
                    events.push(e)
                })
                .expect("calibrate");
            for e in &events {
                project.record(e);
            }
            let profile = folder.join(lensblur::project::PROFILE_FILE);
            cal.write(&profile, Some(&folder.join(lensblur::project::CV_FILE)))
                .expect("write the profile");
            project.set_profile(&profile);
            project.save().expect("save");
            project.flush().expect("flush");
            (dir, folder)
        })
        .1
}

/// The studio on a copy of [`calibrated_demo`] (in `dir`, as the demo folder), once it
/// has read every result back: shots, detections, kernels, dataset, profile and
/// cross-validation.
fn calibrated_studio(dir: &Path) -> (std::path::PathBuf, Harness<'static, StudioApp>) {
    let demo_dir = dir.join("demo");
    copy_folder(calibrated_demo(), &demo_dir);
    let spec = nine_shot_demo();
    let n = spec.settings.len();
    let mut h = new_harness_with(&demo_dir, None, spec);
    step_until(&mut h, "the calibrated demo's results", |a| {
        demo_ready(a)
            && a.measured().count() == n
            && a.dataset().is_some()
            && a.profile().is_some()
            && a.cv().is_some()
    });
    (demo_dir, h)
}

/// The Models view after calibration, and its error CDF saved as CSV and PNG.
#[test]
fn the_models_view_shows_the_fit_and_saves_its_plots() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (_, mut h) = calibrated_studio(dir.path());
    h.get_by_label("Models").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_models");
    // Save the error CDF's data and picture without the dialogs.
    let cdf = (dir.path().join("cdf.csv"), dir.path().join("cdf.png"));
    save_plot(&mut h, PlotId::CvCdf, &cdf.0, &cdf.1);
    // A header naming the axes, then 101 percentiles of three parameters per family.
    let families = h.state().cv().map_or(0, |cv| {
        usize::from(cv.global.is_some()) + usize::from(cv.local.is_some())
    });
    assert_plot_csv(
        &cdf.0,
        "series,error (% of range),held-out samples (%)",
        families * 3 * 101,
    );
}

/// The Sweeps of σ and of MTF50, and a sweep saved as CSV.
#[test]
fn the_sweeps_show_measured_points_the_model_and_the_truth() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (_, mut h) = calibrated_studio(dir.path());
    h.get_by_label("Sweeps").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_sweeps");
    let sweep = (dir.path().join("sweep.csv"), dir.path().join("sweep.png"));
    let plot = PlotId::Sweep {
        vs_aperture: true,
        param: 0,
    };
    save_plot(&mut h, plot, &sweep.0, &sweep.1);
    // Per location: both measured apertures, and the model's and the truth's curves.
    let rows = std::fs::read_to_string(&sweep.0)
        .expect("sweep CSV")
        .lines()
        .count()
        - 1;
    assert_plot_csv(
        &sweep.0,
        "series,aperture (f-number),\"C_xx (σ, px)\"",
        rows,
    );
    assert!(rows >= 5 * 2, "{rows} rows");
    // The same sweeps as MTF50.
    h.get_by_label("MTF50").click();
    h.run_steps(3);
    assert_eq!(h.state().views().sweeps.axis, SweepAxis::Mtf50);
    snapshot(&mut h, "studio_sweeps_mtf50");
}

/// The Kernel field's predicted kernels and ellipses, its difference maps and the
/// demo lens's two units.
#[test]
fn the_kernel_field_predicts_and_subtracts() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (_, mut h) = calibrated_studio(dir.path());
    h.get_by_label("Kernel field").click();
    h.run_steps(2);
    h.get_by_label("Kernel shapes").click();
    h.run_steps(3);
    // Predict: the profile's field at the sliders' setting.
    h.get_by_label("Predicted").click();
    h.run_steps(3);
    assert_eq!(h.state().views().field.source, FieldSource::Predicted);
    // Kernel shapes stay chosen: the profile's predicted kernels, in its recommended
    // model, at the selected shot's measured squares, each with its error against the
    // measured kernel there (shapes too where the profile holds them).
    {
        let app = h.state();
        let profile = &app.profile().expect("profile").1;
        let atlas = app.data().kernel_atlas.as_ref().expect("predicted atlas");
        assert_eq!(atlas.model, Some(profile.kernel_model()));
        assert_eq!(atlas.no_shape.is_some(), profile.shape.is_none());
        let field = app.data().field.as_ref().expect("field");
        let points = &field.panels[0].points;
        assert!(!points.is_empty());
        assert!(points.iter().all(|p| p.kernel_error.is_some_and(|e| {
            e.shape.is_some() == profile.shape.is_some() && e.gaussian > 0.0 && e.gaussian < 1.0
        })));
    }
    snapshot(&mut h, "studio_kernel_field_predicted_kernels");
    h.get_by_label("Ellipses").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_kernel_field_predicted");
    // Difference maps: measured − predicted at the shot's setting, on one diverging
    // scale symmetric about 0; R − B of the predicted field.
    h.get_by_label("measured − predicted").click();
    h.run_steps(3);
    {
        let field = h.state().data().field.as_ref().expect("field");
        let scale = field.scale.as_ref().expect("a colour scale");
        assert!(scale.diverging && scale.range[0] == -scale.range[1]);
        assert!(scale.ticks.contains(&0.0), "{:?}", scale.ticks);
        let points = &field.panels[0].points;
        assert!(!points.is_empty() && points.iter().all(|p| p.other.is_some()));
        // A good model misses the demo's measured σ by a small fraction of it.
        assert!(scale.range[1] < 1.0, "{:?}", scale.range);
    }
    snapshot(&mut h, "studio_kernel_field_difference");
    h.get_by_label("R − B").click();
    h.run_steps(3);
    assert!(
        h.state()
            .data()
            .field
            .as_ref()
            .is_some_and(|f| !f.panels[0].points.is_empty())
    );
    h.get_by_label("σ").click();
    h.run_steps(2);
    assert_eq!(h.state().views().field.options.difference, None);
    h.get_by_label("Ground truth").click();
    h.run_steps(2);
    h.get_by_label("Compare with a second unit").click();
    h.run_steps(3);
    assert!(h.state().views().field.compare_units);
    snapshot(&mut h, "studio_kernel_field_compare");
    // Unit A − unit B of the demo lens: one difference panel, each grid point paired.
    h.get_by_label("unit A − unit B").click();
    h.run_steps(3);
    {
        let field = h.state().data().field.as_ref().expect("field");
        assert_eq!(field.panels.len(), 1);
        assert_eq!(field.panels[0].points.len(), 12 * 8);
        assert!(field.scale.as_ref().is_some_and(|s| s.diverging));
    }
    h.get_by_label("σ").click();
    h.run_steps(2);
}

/// The Deblur view's previews (side by side, slider, GPU, zoomed, stronger) and its
/// exports, of one photo and of a set.
#[test]
fn the_deblur_view_compares_previews_and_exports() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (demo_dir, mut h) = calibrated_studio(dir.path());
    let spec = nine_shot_demo();
    // Deblur preview: the selected shot as the photo, a region deblurred with the
    // predicted Gaussians and with the shot's own measured kernels.
    h.get_by_label("Deblur").click();
    h.run_steps(2);
    let shot_path = {
        let app = h.state();
        let s = app.session().expect("session");
        let id = app.views().shot.selected.expect("a selected shot");
        s.path_of(s.shot(id).expect("the shot"))
    };
    h.get_by_label("Deblur the selected shot").click();
    // The demo's photo is open with its own preview: wait for the shot's.
    step_until(&mut h, "the deblur preview", |a| {
        a.views()
            .deblur
            .photo
            .as_ref()
            .is_some_and(|p| p.path == shot_path)
            && a.views().deblur.comparison.is_some()
            && idle(a)
    });
    {
        let c = &h
            .state()
            .views()
            .deblur
            .comparison
            .as_ref()
            .expect("comparison")
            .comparison;
        assert!(
            c.predicted.is_ok(),
            "predicted: {:?}",
            c.predicted.as_ref().err()
        );
        assert!(
            c.measured.is_ok(),
            "measured: {:?}",
            c.measured.as_ref().err()
        );
    }
    {
        // Software Vulkan here: crops, not the whole photo, and the view says why.
        let d = &h.state().views().deblur;
        assert_eq!(
            d.scope,
            Some(lensblur::app::PreviewScope::Crops(
                "Whole-photo preview needs a hardware GPU; showing crops.".into()
            ))
        );
        let r = d.comparison.as_ref().expect("comparison").comparison.region;
        assert_eq!((r.width, r.height), (160, 160), "a crop, not the photo");
        h.get_by_label("Whole-photo preview needs a hardware GPU; showing crops.");
    }
    snapshot(&mut h, "studio_deblur");
    h.get_by_label("Slider").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_deblur_slider");
    h.get_by_label("Side by side").click();
    h.run_steps(2);
    // The preview on the GPU path (the software Vulkan here: asked for explicitly, as
    // Auto keeps to the CPU on a software adapter), then back to Auto.
    // A small region: the software Vulkan takes about a minute for the default one.
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::SetDeblurCrop(64)));
    h.run_steps(2);
    step_until(&mut h, "the small region", |a| {
        idle(a) && a.views().deblur.comparison.is_some()
    });
    let before = deblurred_region(h.state());
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::SetDeblurDevice(
            lensblur::deblur::Device::Gpu,
        )));
    h.run_steps(2);
    assert!(
        h.state().jobs().is_running(JobKind::DeblurPreview),
        "a new device deblurs the region again"
    );
    step_until(&mut h, "the GPU preview", |a| {
        idle(a) && a.views().deblur.comparison.is_some()
    });
    {
        let note = h
            .state()
            .views()
            .deblur
            .device_note
            .clone()
            .unwrap_or_default();
        assert!(note.starts_with("GPU: "), "{note}");
        let on_gpu = deblurred_region(h.state());
        assert_eq!(on_gpu.len(), before.len());
        let worst = on_gpu
            .iter()
            .zip(&before)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0_f32, f32::max);
        // The tolerance of tests/deblur.rs's GPU-against-CPU test: half an 8-bit level.
        assert!(
            worst <= 1.0 / 510.0,
            "GPU preview differs from the CPU's by {worst}"
        );
    }
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::SetDeblurDevice(
            lensblur::deblur::Device::Auto,
        )));
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::SetDeblurCrop(160)));
    // 100 %: the region is what the panes hold, one photo pixel per screen pixel, the
    // three panes showing the same region (synced).
    h.get_by_label("100 %").click();
    let region_fills_viewport = |a: &StudioApp| {
        let (Some([vw, vh]), Some(c), Some(p)) = (
            a.views().deblur.viewport,
            a.views().deblur.comparison.as_ref(),
            a.views().deblur.photo.as_ref(),
        ) else {
            return false;
        };
        let r = c.comparison.region;
        r.width == vw.min(p.capture.width) & !1 && r.height == vh.min(p.capture.height) & !1
    };
    step_until(&mut h, "the 100 % preview", |a| {
        idle(a) && region_fills_viewport(a)
    });
    // Settled: a few more frames change nothing.
    h.run_steps(3);
    step_until(&mut h, "the 100 % preview, settled", |a| {
        idle(a) && region_fills_viewport(a)
    });
    assert!(
        h.state()
            .views()
            .deblur
            .device_note
            .as_deref()
            .is_some_and(|n| n.starts_with("CPU")),
        "Auto on a software adapter runs on the CPU"
    );
    snapshot(&mut h, "studio_deblur_100");
    // Live strength: a new λ deblurs the same region again, sharper.
    let soft = deblurred_region(h.state());
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::SetDeblurMethod(
            lensblur::deblur::Method::Hqs(lensblur::deblur::HqsParams {
                lambda: 30_000.0,
                ..Default::default()
            }),
        )));
    h.run_steps(2);
    assert!(
        h.state().jobs().is_running(JobKind::DeblurPreview),
        "a new strength deblurs the region again"
    );
    step_until(&mut h, "the stronger preview", |a| {
        idle(a) && a.views().deblur.comparison.is_some()
    });
    let sharp = deblurred_region(h.state());
    assert_eq!(soft.len(), sharp.len(), "the region stays where it was");
    assert!(soft != sharp, "a new strength must change the preview");
    h.get_by_label("200 %").click();
    h.run_steps(2);
    step_until(&mut h, "the 200 % preview", |a| {
        idle(a)
            && a.views().deblur.zoom == lensblur::app::DeblurZoom::Times(2)
            && region_fills_viewport(a)
    });
    {
        // Half the 100 % region's width: the same panes hold half as many pixels.
        let r = h
            .state()
            .views()
            .deblur
            .comparison
            .as_ref()
            .expect("comparison")
            .comparison
            .region;
        let [vw, _] = h.state().views().deblur.viewport.expect("viewport");
        assert!(r.width <= vw && r.width < 200, "{r:?}");
    }
    snapshot(&mut h, "studio_deblur_200_strength");
    h.get_by_label("Fit").click();
    h.run_steps(2);
    step_until(&mut h, "the fitted preview", |a| {
        idle(a)
            && a.views()
                .deblur
                .comparison
                .as_ref()
                .is_some_and(|c| c.comparison.region.width == 160)
    });
    // Export the whole photo deblurred with the predicted Gaussians.
    let out = dir.path().join("deblurred.tiff");
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::ExportDeblur {
            path: out.clone(),
            result: lensblur::app::DeblurResult::Predicted,
        }));
    step_until(&mut h, "the export", |a| {
        idle(a)
            && a.window()
                .messages
                .iter()
                .any(|m| m.text.contains("deblurred photo written"))
    });
    let written = lensblur::raw::load_capture(&out, &Default::default()).expect("export readable");
    assert_eq!((written.width, written.height), (spec.width, spec.height));

    // A set of photos with the profile, as the command line's batch: a RAW photo at a
    // calibrated setting becomes a DNG; a demo shot (an RGB PNG) is skipped, with why.
    let raw = dir.path().join("IMG_0002.dng");
    let cfa: Vec<u16> = (0..spec.width * spec.height)
        .map(|i| 512 + ((i * 7919) % 12000) as u16)
        .collect();
    lensblur::dng::write_dng(
        &raw,
        &cfa,
        spec.width,
        spec.height,
        &lensblur::dng::DngInfo::simulated(
            "Virtual",
            "Sim 14",
            512,
            16383,
            Some(spec.settings[0]),
            lensblur::dng::DngLayout::default(),
        ),
    )
    .expect("write a RAW photo");
    let png = demo_dir.join(DemoSpec::shot_name(spec.settings[0]));
    let exported = dir.path().join("exported");
    std::fs::create_dir(&exported).expect("mkdir");
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::ExportPhotos {
            photos: vec![raw, png],
            out_dir: exported.clone(),
            dng: true,
        }));
    step_until(&mut h, "the photos' export", |a| {
        idle(a)
            && a.window()
                .messages
                .iter()
                .any(|m| m.text.contains("photos exported"))
    });
    let summary = h
        .state()
        .window()
        .messages
        .iter()
        .find(|m| m.text.contains("photos exported"))
        .map(|m| m.text.clone())
        .unwrap_or_default();
    assert!(
        summary.contains("done: 1") && summary.contains("skipped: 1"),
        "{summary}"
    );
    assert!(
        h.state()
            .window()
            .messages
            .iter()
            .any(|m| m.text.contains("skipped: not a RAW photo"))
    );
    let dng = lensblur::raw::load_capture(&exported.join("IMG_0002.dng"), &Default::default())
        .expect("exported DNG");
    assert!(dng.is_raw);
    let note = dng.raw.and_then(|r| r.description).unwrap_or_default();
    assert!(note.contains("profile.json"), "{note}");
}

/// The cached demo opens at once on the next launch, with its results.
#[test]
fn the_cached_demo_reopens_with_its_results() {
    let dir = tempfile::tempdir().expect("temp dir");
    let demo_dir = dir.path().join("demo");
    copy_folder(calibrated_demo(), &demo_dir);
    let spec = nine_shot_demo();
    let n_shots = spec.settings.len();
    let mut again = new_harness_with(&demo_dir, None, spec);
    again.run_steps(1);
    assert!(
        again.state().session().is_some(),
        "cached demo session opens without remaking it"
    );
    step_until(&mut again, "the reopened session's results", |a| {
        a.measured().count() == n_shots
            && a.detections().count() == n_shots
            && a.profile().is_some()
            && a.cv().is_some()
            && idle(a)
    });
}

/// On the measured Kernel field (kernel shapes) of the first shot: the demo's clean
/// kernels pass the core's noisy-kernel criterion; the kernel of `square` given striped
/// tails is hatched, its hover says why, and a click on it opens the square's
/// inspector in the Shot view. The shot's kernels are restored afterwards.
fn noisy_kernel_is_hatched_and_a_click_inspects_it(
    h: &mut Harness<'_, StudioApp>,
    square: (usize, usize),
) {
    let natural = h.state().data().field.as_ref().map_or(0, |f| f.noisy);
    let shot = h.state().views().shot.selected.expect("a selected shot");
    let original = std::sync::Arc::clone(h.state().kernels(shot).expect("kernels"));
    let total = original
        .samples
        .iter()
        .filter(|s| s.kernel.is_some())
        .count();
    eprintln!("noisy kernels on the demo's shot: {natural} of {total} in the channel shown");
    assert!(natural * 10 <= total, "{natural} of {total} flagged");
    let mut striped = (*original).clone();
    let os = striped.oversample as f64;
    let sample = striped
        .samples
        .iter_mut()
        .find(|s| {
            s.channel == lensblur::plane::Channel::G
                && (s.row, s.col) == (Some(square.0), Some(square.1))
        })
        .expect("the square's kernel");
    let (x, y) = (sample.x, sample.y);
    let k = sample.kernel.as_mut().expect("a kernel array");
    let peak = k.data.iter().copied().fold(0.0, f64::max);
    let c = (k.size / 2) as f64;
    let sigma = sample.cxx.unwrap_or(1.0).max(sample.cyy.unwrap_or(1.0));
    // Stripes 2 px apart, a fifth of the peak, beyond 2σ: the ringing of a poor solve.
    for j in 0..k.size {
        for i in 0..k.size {
            let (dx, dy) = ((i as f64 - c) / os, (j as f64 - c) / os);
            if dx.hypot(dy) > 2.0 * sigma {
                k.data[j * k.size + i] +=
                    0.2 * peak * 0.5 * (1.0 + (std::f64::consts::PI * dx).cos());
            }
        }
    }
    let file = h
        .state()
        .project()
        .and_then(|p| p.state(shot)?.file.clone())
        .expect("the shot's file");
    h.state_mut().record_shot_event(ShotEvent::Measured {
        id: shot,
        file: file.clone(),
        kernels: std::sync::Arc::new(striped),
    });
    h.run_steps(3);
    let field = h.state().data().field.as_ref().expect("field");
    assert!(field.noisy > natural, "the striped kernel is flagged");
    let point = field.panels[0]
        .points
        .iter()
        .find(|p| p.square == Some(square))
        .expect("the square is drawn");
    assert!(point.noisy.is_some());
    // Hover the square until its tooltip shows (the harness steps a quarter second).
    let panel = h.get_by_label("kernel field panel").rect();
    let sensor_w = original.width as f32;
    let scale = panel.width() / sensor_w;
    let pos = panel.min + egui::Vec2::new(x as f32 * scale, y as f32 * scale);
    h.hover_at(pos);
    h.run_steps(4);
    h.get_by_label_contains("noisy estimate");
    h.get_by_label_contains("in the worst direction");
    h.snapshot("studio_kernel_field_noisy");
    click_at(h, pos);
    h.run_steps(2);
    assert_eq!(h.state().view(), View::Shot);
    assert_eq!(h.state().views().shot.square, Some(square));
    h.state_mut().record_shot_event(ShotEvent::Measured {
        id: shot,
        file,
        kernels: original,
    });
    h.state_mut()
        .push(Command::View(ViewCommand::SelectView(View::KernelField)));
    h.run_steps(3);
    assert_eq!(
        h.state().data().field.as_ref().map(|f| f.noisy),
        Some(natural)
    );
    step_until(h, "the inspector after the click", |a| {
        idle(a) && a.data().inspection().is_some()
    });
}

/// A simulated RAW shot (384 × 256, Bayer) of a 6 × 4 chart at 35 mm f/8, written as
/// a DNG at `path`; the chart.
fn write_raw_shot(path: &Path, seed: u64) -> lensblur::chart::ChartSpec {
    use lensblur::simulate::{
        CaptureParams, ShotFormat, VirtualLens, simulate_shot, write_shot_as,
    };
    let chart = DemoSpec::grid(384, 256, &[35.0], &[8.0])
        .with_chart(6, 4)
        .chart();
    let setting = lensblur::plane::LensSetting {
        focal_mm: 35.0,
        f_number: 8.0,
    };
    let mut params = CaptureParams::new(384, 256, setting);
    params.bayer = true;
    params.seed = seed;
    let shot = simulate_shot(&chart, &VirtualLens::demo(), &params, &JobContext::silent())
        .expect("simulated RAW shot");
    write_shot_as(path, &shot, ShotFormat::Dng, Default::default()).expect("write DNG");
    chart
}

/// A RAW session: a DNG shot is shown developed (imagepipe) and, at the switch, as the
/// linear CFA plane that is measured; opened as a photo, its compared crops are
/// developed too, and it exports as a DNG with its metadata.
#[test]
fn raw_shots_and_photos_are_developed_and_export_as_dng() {
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    let folder = parent.path().join("raw session");
    std::fs::create_dir(&folder).expect("session folder");
    let raw = folder.join("IMG_0001.dng");
    let chart = write_raw_shot(&raw, 5);

    let mut h = new_harness(demo.path(), Some(&folder));
    h.run_steps(2);
    flush_saves(&h);
    let settings = lensblur::session::Session::open(&folder)
        .expect("session")
        .settings;
    h.state_mut()
        .push(Command::Session(SessionCommand::ApplySettings {
            chart,
            settings,
        }));
    h.input_mut().dropped_files.push(dropped(&raw));
    step_until(&mut h, "the RAW shot", |a| {
        a.previews().count() == 1 && idle(a)
    });
    {
        let app = h.state();
        let preview = app.previews().next().map(|(_, p)| p).expect("the shot");
        assert!(preview.capture.is_raw);
        assert!(
            matches!(preview.developed, Some(Ok(_))),
            "developed: {:?}",
            preview.developed.as_ref().map(|d| d.as_ref().err())
        );
        assert!(app.views().shot.viewer.developed);
    }
    snapshot(&mut h, "studio_shot_raw_developed");
    h.get_by_label("developed").click();
    h.run_steps(2);
    assert!(!h.state().views().shot.viewer.developed);
    snapshot(&mut h, "studio_shot_raw_linear");
    h.get_by_label("developed").click();
    h.run_steps(2);

    // Its own kernels, so the photo's comparison has a measured result.
    h.get_by_label("Detect").click();
    step_until(&mut h, "detection", |a| {
        a.detections().count() == 1 && idle(a)
    });
    h.get_by_label("Kernels").click();
    step_until(&mut h, "kernels", |a| a.measured().count() == 1 && idle(a));
    h.get_by_label("Deblur").click();
    h.run_steps(2);
    h.get_by_label("Deblur the selected shot").click();
    step_until(&mut h, "the deblur preview", |a| {
        a.views().deblur.comparison.is_some() && idle(a)
    });
    {
        let view = h
            .state()
            .views()
            .deblur
            .comparison
            .as_ref()
            .expect("comparison");
        let c = &view.comparison;
        assert!(
            c.measured.is_ok(),
            "measured: {:?}",
            c.measured.as_ref().err()
        );
        let developed = match &c.developed {
            Some(Ok(d)) => d,
            other => panic!(
                "the RAW photo's crops are developed: {:?}",
                other.as_ref().map(|r| r.as_ref().err())
            ),
        };
        // The original and the measured result (no profile yet: no predicted one).
        assert!(developed[0].is_some() && developed[2].is_some());
        assert!(view.developed[0].is_some() && view.developed[2].is_some());
    }
    snapshot(&mut h, "studio_deblur_raw_developed");
    h.get_by_label("developed").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_deblur_raw_linear");

    // The whole photo, deblurred with its measured kernels, as a DNG.
    let out = parent.path().join("IMG_0001.deblurred.dng");
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::ExportDeblur {
            path: out.clone(),
            result: lensblur::app::DeblurResult::Measured,
        }));
    step_until(&mut h, "the export", |a| {
        idle(a)
            && a.window()
                .messages
                .iter()
                .any(|m| m.text.contains("deblurred photo written"))
    });
    let written = lensblur::raw::load_capture(&out, &Default::default()).expect("export readable");
    let photo = &h
        .state()
        .views()
        .deblur
        .photo
        .as_ref()
        .expect("photo")
        .capture;
    assert!(written.is_raw);
    assert_eq!((written.width, written.height), (photo.width, photo.height));
    assert_eq!(written.identity, photo.identity);
    assert_eq!(written.setting_f_number, Some(8.0));
    let (a, b) = (
        photo.raw.as_ref().expect("photo metadata"),
        written.raw.as_ref().expect("written metadata"),
    );
    assert_eq!((a.cfa, a.black, a.white), (b.cfa, b.black, b.white));
    let note = b.description.clone().unwrap_or_default();
    assert!(note.contains("measured"), "{note}");
    assert!(
        parent
            .path()
            .join("IMG_0001.deblurred.preview.png")
            .is_file()
    );
}

#[test]
fn light_theme_and_user_session() {
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    // A named folder: the session takes its name from it, and the UI shows it.
    let folder = parent.path().join("my session");
    std::fs::create_dir(&folder).expect("session folder");
    // A user's shot: a simulated photo of a 6 × 4 chart (16-bit PNG, no EXIF), made
    // elsewhere and copied in.
    let made = tempfile::tempdir().expect("temp dir");
    let shot_spec = DemoSpec::grid(320, 240, &[35.0], &[8.0]).with_chart(6, 4);
    let spec = shot_spec.chart();
    let made_session = lensblur::simulate::demo::make_demo(
        made.path(),
        &shot_spec,
        &lensblur::job::JobContext::silent(),
    )
    .expect("simulated shot");
    let shot = folder.join("my_shot.png");
    std::fs::copy(made_session.shot_path(0), &shot).expect("copy shot");

    let mut h = new_harness(demo.path(), Some(&folder));
    h.run_steps(2);
    assert!(h.state().session().is_some_and(|s| s.shots.is_empty()));
    flush_saves(&h);
    assert!(
        folder.join("session.json").is_file(),
        "a new session is saved at once"
    );
    h.get_by_label("View").click();
    h.run_steps(2);
    // The entry's label carries its shortcut.
    h.get_by_label_contains("Light theme").click();
    h.run_steps(2);
    assert!(!h.state().window().dark);
    // Drag and drop a file onto the window.
    h.input_mut().dropped_files.push(dropped(&shot));
    step_until(&mut h, "the dropped shot", |a| a.previews().count() == 1);
    flush_saves(&h);
    let saved = lensblur::session::Session::open(&folder).expect("session saved as it changes");
    assert_eq!(saved.shots.len(), 1);
    // Settings typed for the shot are saved too.
    let first = saved.shots[0].id;
    h.state_mut()
        .push(Command::Session(SessionCommand::SetShotSetting {
            shot: first,
            focal_mm: Some(35.0),
            f_number: Some(8.0),
        }));
    h.run_steps(2);
    flush_saves(&h);
    let saved = lensblur::session::Session::open(&folder).expect("session");
    assert_eq!(saved.shots[0].setting().map(|s| s.focal_mm), Some(35.0));
    // The chart of this shot, set in the session's settings.
    h.state_mut()
        .push(Command::Session(SessionCommand::ApplySettings {
            chart: spec.clone(),
            settings: saved.settings.clone(),
        }));
    h.run_steps(2);
    flush_saves(&h);
    assert_eq!(
        lensblur::session::Session::open(&folder)
            .expect("session")
            .chart,
        spec
    );
    // A file of the wrong kind is refused with a message naming it.
    let bad = folder.join("notes.txt");
    std::fs::write(&bad, b"x").expect("write");
    h.input_mut().dropped_files.push(dropped(&bad));
    h.run_steps(2);
    assert!(
        h.state()
            .window()
            .messages
            .iter()
            .any(|m| m.is_error && m.text.contains("notes.txt"))
    );
    // A shot that cannot be read: an error naming the file and the reason, no panic.
    let broken = folder.join("broken.png");
    std::fs::write(&broken, b"\x89PNG\r\n\x1a\n not really").expect("write");
    h.input_mut().dropped_files.push(dropped(&broken));
    step_until(&mut h, "the unreadable shot", |a| {
        a.unreadable_shots().count() == 1 && a.unreadable(first).is_none() && idle(a)
    });
    assert!(
        h.state()
            .window()
            .messages
            .iter()
            .any(|m| m.is_error && m.text.starts_with("broken.png"))
    );
    // Detect by its keyboard shortcut on the readable shot.
    h.state_mut()
        .push(Command::View(ViewCommand::SelectShot(first)));
    h.run_steps(2);
    h.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::D);
    step_until(&mut h, "detection of the user's shot", |a| {
        idle(a)
            && a.session()
                .is_some_and(|s| s.shots[0].detect != StageStatus::Pending)
    });
    snapshot(&mut h, "studio_user_session_light");
}

/// A folder with a file that kills its RAW decoder: a CR3 whose sample-size table
/// claims 2³² − 1 entries, for which rawler reserves 16 GiB, past the worker's 4 GiB
/// (this once aborted the whole program). The studio goes on: the shot is listed as
/// unreadable with its one-line reason, the folder's RAW shot beside it loads.
#[test]
fn a_file_that_kills_its_decoder_is_one_unreadable_shot() {
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    let folder = parent.path().join("odd files");
    std::fs::create_dir(&folder).expect("session folder");
    let good = folder.join("IMG_0001.dng");
    write_raw_shot(&good, 9);
    let real = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real");
    let mut b = std::fs::read(real.join("canon-m50-stripped.cr3")).expect("real CR3");
    let at = b.windows(4).position(|w| w == b"stsz").expect("stsz box") + 4;
    b[at + 4..at + 8].copy_from_slice(&0u32.to_be_bytes());
    b[at + 8..at + 12].copy_from_slice(&u32::MAX.to_be_bytes());
    let bad = folder.join("IMG_0002.cr3");
    std::fs::write(&bad, b).expect("write CR3");

    let mut h = new_harness(demo.path(), Some(&folder));
    h.run_steps(2);
    // Both dropped on the window at once, as a photographer drops a folder's files.
    h.input_mut().dropped_files.push(dropped(&good));
    h.input_mut().dropped_files.push(dropped(&bad));
    step_until(&mut h, "the folder's two shots", |a| {
        a.shots_shown() == 2 && idle(a)
    });
    let app = h.state();
    assert_eq!(app.previews().count(), 1, "the DNG loads");
    let dead: Vec<(ShotId, String)> = app
        .unreadable_shots()
        .map(|(id, r)| (id, r.to_string()))
        .collect();
    let [(_, reason)] = dead.as_slice() else {
        panic!("one unreadable shot: {dead:?}");
    };
    assert!(
        reason.contains("IMG_0002.cr3")
            && reason.contains("ran out of memory")
            && !reason.contains('\n'),
        "{reason}"
    );
    flush_saves(&h);
    let saved = Session::open(&folder).expect("session");
    assert_eq!(saved.shots.len(), 2, "both shots stay in the session");
    // The loaded shot shown; the list says the other is unreadable, the notice why.
    let good_id = h.state().previews().next().map(|(id, _)| id).expect("DNG");
    h.state_mut()
        .push(Command::View(ViewCommand::SelectShot(good_id)));
    h.run_steps(2);
    snapshot(&mut h, "studio_decoder_died");
}

/// The same measurements give the same profile in either front end: byte for byte.
fn assert_same_profile(a: &Path, b: &Path) {
    let read = |p: &Path| std::fs::read_to_string(p).expect("profile written");
    let (ta, tb) = (read(a), read(b));
    if ta != tb {
        let va: serde_json::Value = serde_json::from_str(&ta).expect("profile json");
        let vb: serde_json::Value = serde_json::from_str(&tb).expect("profile json");
        let differ: Vec<String> = va
            .as_object()
            .into_iter()
            .flatten()
            .filter(|(k, v)| vb.get(k.as_str()) != Some(v))
            .map(|(k, v)| format!("{k}: {} vs {}", short(v), short(&vb[k.as_str()])))
            .collect();
        panic!("{} and {} differ in {differ:?}", a.display(), b.display());
    }
}

fn short(v: &serde_json::Value) -> String {
    let t = v.to_string();
    t.chars().take(300).collect()
}

/// A session folder copied, results and all, without the open session's lock.
fn copy_folder(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("copy folder");
    for e in std::fs::read_dir(from).expect("read folder").flatten() {
        let (p, q) = (e.path(), to.join(e.file_name()));
        if p.is_dir() {
            copy_folder(&p, &q);
        } else if e.file_name() != lensblur::lock::LOCK_FILE {
            std::fs::copy(&p, &q).expect("copy file");
        }
    }
}

/// Runs `lensblur calibrate` on a session folder's manifest; returns its stderr.
fn calibrate_on_the_command_line(folder: &Path, out: &Path) -> String {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .arg("calibrate")
        .arg("--manifest")
        .arg(folder)
        .arg("--out")
        .arg(out)
        .output()
        .expect("run lensblur calibrate");
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "lensblur calibrate failed: {err}");
    err
}

/// Every stage the session records as done has its result in the cache under the
/// shot's own content, and that result names the shot's file and carries its setting.
fn assert_results_belong_to_their_shots(folder: &Path) -> Session {
    let s = Session::open(folder).expect("session reopens");
    let (m, cache) = (s.measurement(), s.cache());
    for shot in &s.shots {
        let file = ShotFile::read(&s.path_of(shot)).expect("shot readable");
        if shot.detect.is_done() {
            let path = cache.detect_path(&file, &m);
            let det: lensblur::detect::DetectFile =
                serde_json::from_str(&std::fs::read_to_string(&path).expect("detection cached"))
                    .expect("detection file");
            assert_eq!(det.source, Some(file.record()), "{}", path.display());
        }
        if shot.kernels.is_done() {
            let k = cache
                .kernels(&file, &m)
                .expect("kernels readable")
                .expect("kernels cached");
            assert_eq!(k.source, Some(file.record()), "{}", shot.name());
            assert_eq!((k.focal_mm, k.f_number), (shot.focal_mm, shot.f_number));
        }
    }
    s
}

fn first_unmeasured(app: &StudioApp, measured: impl Fn(&StudioApp, ShotId) -> bool) -> ShotId {
    let s = app.session().expect("session");
    s.shots
        .iter()
        .map(|shot| shot.id)
        .find(|&id| !measured(app, id))
        .unwrap_or_else(|| s.shots[s.shots.len() - 1].id)
}

#[test]
fn removing_shots_and_switching_sessions_while_jobs_run() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (a_dir, b_dir) = (dir.path().join("a"), dir.path().join("b"));
    let spec = test_demo();
    make_demo(&a_dir, &spec, &JobContext::silent()).expect("session A");
    let mut spec_b = test_demo();
    spec_b.seed = 99;
    make_demo(&b_dir, &spec_b, &JobContext::silent()).expect("session B");
    let n = spec.settings.len();

    let mut h = new_harness(&dir.path().join("demo"), Some(&a_dir));
    step_until(&mut h, "session A", demo_ready);
    h.state_mut()
        .push(Command::Stage(StageCommand::RunDetect(None)));
    step_until(&mut h, "a first detection", |a| {
        a.detections().next().is_some() || idle(a)
    });
    // A shot the job has not finished: removed while it runs (or waits its turn).
    let gone = first_unmeasured(h.state(), |a, id| a.detection(id).is_some());
    h.state_mut()
        .push(Command::Session(SessionCommand::RemoveShot(gone)));
    step_until(&mut h, "detection", idle);
    assert!(h.state().detection(gone).is_none());

    h.state_mut()
        .push(Command::Stage(StageCommand::RunKernels(None)));
    h.run_steps(1);
    let gone2 = first_unmeasured(h.state(), |a, id| a.kernels(id).is_some());
    h.state_mut()
        .push(Command::Session(SessionCommand::RemoveShot(gone2)));
    step_until(&mut h, "a first kernels result", |a| {
        a.measured().next().is_some() || idle(a)
    });
    // Another session while the kernels job may still run: its late results are
    // dropped, and session B's shots (with the same ids) get none of them.
    h.state_mut()
        .push(Command::Session(SessionCommand::OpenSession(b_dir.clone())));
    h.run_steps(1);
    h.state_mut()
        .push(Command::Stage(StageCommand::RunDetect(None)));
    step_until(&mut h, "session B detected", |a| {
        idle(a) && a.detections().count() == n
    });
    assert!(
        h.state().measured().next().is_none(),
        "no kernels were measured in session B"
    );
    drop(h);

    let a = assert_results_belong_to_their_shots(&a_dir);
    assert_eq!(a.shots.len(), n - 2);
    assert!(a.shot(gone).is_none() && a.shot(gone2).is_none());
    assert!(a.shots.iter().all(|s| s.detect.is_done()));
    let b = assert_results_belong_to_their_shots(&b_dir);
    assert_eq!(b.shots.len(), n);
    assert!(
        b.shots
            .iter()
            .all(|s| s.detect.is_done() && !s.kernels.is_done())
    );
}

#[test]
fn a_session_measured_on_the_command_line_calibrates_in_the_studio() {
    let dir = tempfile::tempdir().expect("temp dir");
    let folder = dir.path().join("session");
    let spec = test_demo();
    make_demo(&folder, &spec, &JobContext::silent()).expect("session");
    let cli_profile = dir.path().join("cli-profile.json");
    let cli = calibrate_on_the_command_line(&folder, &cli_profile);
    assert!(cli.contains("shots measured, 0 from the cache"), "{cli}");

    let mut h = new_harness(&dir.path().join("demo"), Some(&folder));
    let n = spec.settings.len();
    step_until(&mut h, "the cached results", |a| {
        a.measured().count() == n && a.detections().count() == n && idle(a)
    });
    assert!(
        h.state()
            .session()
            .is_some_and(|s| s.shots.iter().all(|s| s.kernels.is_done())),
        "results measured elsewhere count as done"
    );
    h.state_mut()
        .push(Command::Stage(StageCommand::RunCalibrate));
    step_until(&mut h, "calibration", |a| a.profile().is_some() && idle(a));
    assert_same_profile(&folder.join("profile.json"), &cli_profile);
}

#[test]
fn a_second_studio_on_an_open_session_is_refused_and_the_command_line_too() {
    let dir = tempfile::tempdir().expect("temp dir");
    let folder = dir.path().join("session");
    make_demo(&folder, &test_demo(), &JobContext::silent())
        .expect("session")
        .save()
        .expect("save");
    let mut first = new_harness(&dir.path().join("demo"), Some(&folder));
    first.run_steps(2);
    assert!(first.state().session().is_some());

    // A second window on the same folder: refused with who holds it, nothing opened.
    let mut second = new_harness(&dir.path().join("demo"), Some(&folder));
    second.run_steps(2);
    assert!(second.state().session().is_none());
    let refusal = second
        .state()
        .window()
        .messages
        .iter()
        .find(|m| m.is_error)
        .map(|m| m.text.clone())
        .unwrap_or_default();
    assert!(
        refusal.contains("in use by the lensblur studio"),
        "{:?}",
        second.state().window().messages
    );

    // The command line too, in one line, and it writes nothing.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(["calibrate", "--manifest"])
        .arg(&folder)
        .arg("--out")
        .arg(folder.join("profile.json"))
        .output()
        .expect("run lensblur");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("in use by the lensblur studio"),
        "{err}"
    );
    assert!(!folder.join("profile.json").exists());

    // Closed, the folder is free again.
    drop(first);
    let mut third = new_harness(&dir.path().join("demo"), Some(&folder));
    third.run_steps(2);
    assert!(
        third.state().session().is_some(),
        "{:?}",
        third.state().window().messages
    );
}

/// A profile of a lens whose kernels are not Gaussian (a comet) holds a shape model:
/// the Kernel field's predicted kernel shapes are its shapes, and the panel says so.
#[test]
fn predicted_kernel_shapes_of_a_profile_with_a_shape_model() {
    use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
    use lensblur::simulate::{PsfShape, SimulatedSession, VirtualLens};
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    // A named folder: the session takes its name from it, and the snapshot shows it.
    let folder = parent.path().join("comet lens");
    std::fs::create_dir(&folder).expect("session folder");
    let lens = VirtualLens {
        shape: PsfShape::Comet,
        ..VirtualLens::demo()
    };
    let spec = test_demo();
    let mut settings = Vec::new();
    for focal_mm in [24.0, 60.0, 105.0] {
        for f_number in [4.0, 10.0] {
            settings.push(lensblur::plane::LensSetting { focal_mm, f_number });
        }
    }
    // On the demo's sensor, so the field grid the empty session draws on is the
    // profile's.
    let ds = SimulatedSession {
        cols: 6,
        rows: 4,
        kernel_noise: Some(0.01),
        seed: 3,
        ..SimulatedSession::new(spec.width, spec.height)
    }
    .dataset(&lens, &settings);
    let opts = CalibrateOptions {
        families: Families::Global,
        alpha: Some(2),
        beta: Some(1),
        ..CalibrateOptions::default()
    };
    let (profile, _) = calibrate(&ds, None, &opts, &JobContext::silent()).expect("calibrate");
    assert!(profile.shape.is_some(), "the comet's shapes were kept");
    let path = folder.join("comet-profile.json");
    profile.save(&path).expect("profile saved");

    let mut h = new_harness(demo.path(), Some(&folder));
    h.run_steps(2);
    h.state_mut()
        .push(Command::Stage(StageCommand::LoadProfile {
            path,
            compare: false,
        }));
    step_until(&mut h, "the profile", |a| a.profile().is_some() && idle(a));
    let app = h.state_mut();
    app.push(Command::View(ViewCommand::SelectView(View::KernelField)));
    app.push(Command::View(ViewCommand::SetFieldSource(
        FieldSource::Predicted,
    )));
    app.push(Command::View(ViewCommand::SetFieldShow(FieldShow::Kernels)));
    app.push(Command::View(ViewCommand::SetFieldSetting {
        focal_mm: 60.0,
        f_number: 4.0,
    }));
    h.run_steps(3);
    {
        let atlas = h.state().data().kernel_atlas.as_ref().expect("atlas");
        assert_eq!(atlas.model, Some(lensblur::model::KernelModel::Shape));
        assert!(atlas.error.is_none(), "{:?}", atlas.error);
        assert_eq!(
            atlas.cells.len(),
            12 * 8,
            "the field grid, no shot selected"
        );
    }
    h.get_by_label_contains("predicted kernel shapes");
    snapshot(&mut h, "studio_kernel_field_predicted_shapes");

    // Saved into the library, where a batch finds it.
    h.state_mut()
        .push(Command::Stage(StageCommand::SaveProfileToLibrary));
    h.run_steps(2);
    let library = lensblur::batch::ProfileLibrary::load(&demo.path().join("profiles"))
        .expect("the library holds the profile");
    assert_eq!(library.profiles.len(), 1, "{:?}", library.warnings);
}

/// Shots at one focal length and two apertures, with β fixed at 2 in the session's
/// settings: the Models view warns that the model cannot follow the focal length and
/// is not determined in aperture, and says what to shoot next.
#[test]
fn models_warn_what_to_shoot_when_the_settings_cannot_determine_the_model() {
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    let folder = parent.path().join("one focal length");
    std::fs::create_dir(&folder).expect("session folder");
    let made = tempfile::tempdir().expect("temp dir");
    let shot_spec = DemoSpec::grid(320, 240, &[35.0], &[4.0, 8.0]).with_chart(6, 4);
    let made_session =
        make_demo(made.path(), &shot_spec, &JobContext::silent()).expect("simulated shots");
    let shots: Vec<_> = (0..2)
        .map(|i| {
            let p = folder.join(format!("shot_{i}.png"));
            std::fs::copy(made_session.shot_path(i), &p).expect("copy shot");
            p
        })
        .collect();
    let mut h = new_harness(demo.path(), Some(&folder));
    h.run_steps(2);
    h.state_mut()
        .push(Command::Session(SessionCommand::AddShots(shots)));
    step_until(&mut h, "the shots", |a| {
        a.previews().count() == 2 && idle(a)
    });
    let session = h.state().session().cloned().expect("session");
    for (shot, f_number) in session.shots.iter().zip([4.0, 8.0]) {
        h.state_mut()
            .push(Command::Session(SessionCommand::SetShotSetting {
                shot: shot.id,
                focal_mm: Some(35.0),
                f_number: Some(f_number),
            }));
    }
    let mut settings = session.settings.clone();
    settings.beta = Some(2);
    let app = h.state_mut();
    app.push(Command::Session(SessionCommand::ApplySettings {
        chart: session.chart.clone(),
        settings,
    }));
    app.push(Command::View(ViewCommand::SelectView(View::Models)));
    h.run_steps(3);
    let advice = &h
        .state()
        .data()
        .calibrated
        .as_ref()
        .expect("the session's settings")
        .advice;
    assert_eq!(advice.len(), 2, "{advice:?}");
    assert!(
        advice
            .iter()
            .all(|a| a.level == lensblur::review::AdviceLevel::Warning)
    );
    h.get_by_label_contains("Every shot is at 35 mm");
    h.get_by_label_contains("shoot at least 1 more aperture between f/4.0 and f/8.0");
    snapshot(&mut h, "studio_models_warning");
}

/// A small chart shot at 7 of 3 × 3 positions at one setting (the top-left and
/// bottom-right ones left out), measured on the command line's path: the Models view's
/// shooting plan maps where the chart has been and names the two parts missing.
#[test]
fn the_shooting_plan_maps_where_a_small_chart_has_been() {
    use lensblur::project::{MeasurePlan, Stages};
    let dir = tempfile::tempdir().expect("temp dir");
    let folder = dir.path().join("positions");
    let spec = DemoSpec::grid(480, 320, &[24.0], &[4.0])
        .with_chart(6, 4)
        .with_placement(ChartPlacement::Positions {
            across: 3,
            down: 3,
            fill: 0.42,
        });
    make_demo(&folder, &spec, &JobContext::silent()).expect("session");
    {
        // The folder, so that the removals are saved in its session file.
        let (mut project, _) = Project::open(&folder, "test").expect("open the session");
        let left_out: Vec<ShotId> = project
            .session()
            .shots
            .iter()
            .filter(|s| {
                let name = s.path.to_string_lossy();
                name.contains("_p11") || name.contains("_p33")
            })
            .map(|s| s.id)
            .collect();
        for id in left_out {
            project.remove_shot(id);
        }
        project
            .measure_now(&MeasurePlan::missing(Stages::All), &JobContext::silent())
            .expect("measured");
        project.save().expect("saved");
        project.flush().expect("flushed");
    }
    let mut h = new_harness(&dir.path().join("demo"), Some(&folder));
    step_until(&mut h, "the cached results", |a| {
        a.measured().count() == 7 && idle(a)
    });
    h.state_mut()
        .push(Command::View(ViewCommand::SelectView(View::Models)));
    h.run_steps(3);
    let (_, maps) = h.state().data().coverage.as_ref().expect("coverage maps");
    assert_eq!(maps.len(), 1);
    assert_eq!(maps[0].missing_parts(), ["top-left", "bottom-right"]);
    h.get_by_label_contains("24 mm f/4.0: top-left and bottom-right not yet covered");
    snapshot(&mut h, "studio_models_coverage");

    // The Kernel field shows the seven shots' kernels as one field: every square of
    // every position, each hover and click naming the shot it was measured on.
    let first = h.state().session().expect("session").shots[0].id;
    let app = h.state_mut();
    app.push(Command::View(ViewCommand::SelectShot(first)));
    app.push(Command::View(ViewCommand::SelectView(View::KernelField)));
    h.run_steps(3);
    {
        let app = h.state();
        let field = app.data().field.as_ref().expect("field");
        let points = &field.panels[0].points;
        assert_eq!(
            points.len(),
            7 * 24,
            "a G kernel per square of each position"
        );
        let shots: std::collections::BTreeSet<ShotId> =
            points.iter().filter_map(|p| p.shot).collect();
        assert_eq!(shots.len(), 7, "each point names its own shot");
    }
    snapshot(&mut h, "studio_kernel_field_positions");
}

/// The demo is handed over shot by shot, so the studio shows the first shot while the
/// rest are simulated; the finished demo holds a natural photo blurred by the lens, at
/// one of its own settings and on its sensor, which the Deblur view opens.
#[test]
fn the_demo_streams_its_shots_and_blurs_a_photo() {
    let dir = tempfile::tempdir().expect("temp dir");
    // The demo a user sees (its size, chart and nine settings), so these snapshots are
    // what a first launch shows.
    let spec = DemoSpec::studio();
    let t0 = Instant::now();
    let mut seen = Vec::new();
    let made = lensblur::simulate::demo::make_demo_streaming(
        dir.path(),
        &spec,
        &JobContext::silent(),
        &mut |s| {
            seen.push(s.shots.len());
            if seen.len() == 1 {
                eprintln!("first demo shot after {:.2} s", t0.elapsed().as_secs_f32());
            }
        },
    )
    .expect("demo");
    eprintln!("whole demo after {:.2} s", t0.elapsed().as_secs_f32());
    let n = spec.settings.len();
    assert_eq!(seen, (1..=n).collect::<Vec<_>>());
    let photo = made.demo_photo.as_ref().expect("a demo photo");
    assert!(
        spec.settings
            .iter()
            .any(|s| s.focal_mm == photo.focal_mm && s.f_number == photo.f_number),
        "the photo is at a setting the demo measures"
    );
    let img = image::open(dir.path().join(&photo.path)).expect("the photo decodes");
    assert_eq!(
        (img.width() as usize, img.height() as usize),
        (spec.width, spec.height)
    );
    // Saved with the session, so a reopened demo still opens its photo.
    let reopened = Session::open(dir.path()).expect("reopen");
    assert_eq!(reopened.demo_photo.as_ref(), Some(photo));

    // The studio on that demo, as on a first launch: the photo opens at its setting,
    // *Calibrate all* runs by itself (detect, kernels, calibrate: one job), and the
    // Deblur view then shows the photo before and after with the profile it made.
    let mut h = harness(AppOptions {
        calibrate_demo: true,
        ..options(dir.path(), None, spec.clone())
    });
    step_until(&mut h, "the demo's photo", |a| {
        a.views().deblur.photo.is_some()
    });
    let p = h.state().views().deblur.photo.as_ref().expect("photo");
    assert_eq!(
        (p.focal_mm, p.f_number),
        (Some(photo.focal_mm), Some(photo.f_number))
    );
    step_until(&mut h, "calibrate all", |a| {
        a.jobs().is_running(JobKind::CalibrateAll)
            || a.profile().is_some()
            || a.window().messages.iter().any(|m| m.is_error)
    });
    let job_ids: Vec<JobKind> = h.state().jobs().running.iter().map(|j| j.kind).collect();
    assert!(
        !job_ids
            .iter()
            .any(|j| [JobKind::Detect, JobKind::Kernels, JobKind::Calibrate].contains(j)),
        "one job, not a stage each: {job_ids:?}"
    );
    step_until(&mut h, "the profile", |a| a.profile().is_some() && idle(a));
    let app = h.state();
    assert_eq!(app.measured().count(), n, "every shot measured");
    assert!(
        folder_has_profile(dir.path()),
        "the profile is written into the demo's folder"
    );
    assert_eq!(app.view(), View::Deblur, "the before/after opens by itself");
    assert!(
        app.window().messages.iter().any(|m| m
            .text
            .starts_with(&format!("Calibrate all: measured {n} shots"))),
        "{:?}",
        app.window().messages
    );
    assert!(
        !app.window().messages.iter().any(|m| m.is_error),
        "{:?}",
        app.window().messages
    );
    step_until(&mut h, "the photo's preview", |a| {
        idle(a)
            && a.views()
                .deblur
                .comparison
                .as_ref()
                .is_some_and(|c| c.comparison.predicted.is_ok())
    });
    snapshot(&mut h, "studio_deblur_demo_photo");

    // Hovering the before/after: a loupe of the same pixels before and after, and their
    // values in both; the divider stays where it was.
    let divider = h.get_by_label("divider").rect();
    let slider = h.state().views().deblur.slider;
    h.hover_at(divider.center() + egui::vec2(-120.0, -60.0));
    h.run_steps(2);
    assert_eq!(
        h.state().views().deblur.slider,
        slider,
        "hovering moves nothing"
    );
    h.get_by_label_contains("before R ");
    // With the pointer: the loupe is drawn at once where it rests (no tooltip delay).
    h.snapshot("studio_deblur_demo_loupe");
    h.hover_at(egui::pos2(2.0, 2.0));
    h.run_steps(1);

    // The sharpness map the profile predicts at the photo's setting, then the one the
    // photo's shot measured, and the lens's own: worse towards the corners in all three.
    h.state_mut()
        .push(Command::View(ViewCommand::SelectView(View::Sharpness)));
    let corners_fall = |a: &StudioApp| {
        a.data().sharpness.as_ref().is_some_and(|d| {
            d.summary
                .is_some_and(|s| s.corners < s.centre && s.min > 0.0)
        })
    };
    step_until(&mut h, "the predicted sharpness map", |a| {
        a.views().sharpness.source == FieldSource::Predicted && corners_fall(a)
    });
    snapshot(&mut h, "studio_sharpness_demo");
    for source in [FieldSource::Measured, FieldSource::Truth] {
        let choice = SharpnessChoice {
            source,
            ..h.state().views().sharpness
        };
        h.state_mut()
            .push(Command::View(ViewCommand::SetSharpness(choice)));
        step_until(&mut h, "the sharpness map", |a| {
            a.views().sharpness.source == source
                && a.data().sharpness.as_ref().is_some_and(|d| d.map.is_ok())
                && corners_fall(a)
        });
    }
    snapshot(&mut h, "studio_sharpness_truth");

    // The shooting plan of the demo's lens, every setting shot.
    h.state_mut()
        .push(Command::View(ViewCommand::SelectView(View::Models)));
    h.run_steps(2);
    h.get_by_label("Shooting plan").click();
    h.run_steps(2);
    // Every setting the demo holds counts, those off the plan's grid (f/10) too.
    h.get_by_label_contains(&format!("{} settings shot: ", spec.settings.len()));
    snapshot(&mut h, "studio_models_demo_plan");

    // The map shown last, saved as the dialog's answer would save it: the PNG, and
    // the CSV with one row per cell.
    for png in [true, false] {
        let path = dir.path().join(if png { "map.png" } else { "map.csv" });
        h.state_mut()
            .push(Command::Plot(PlotCommand::SaveSharpness {
                path: path.clone(),
                png,
            }));
        h.run_steps(2);
        if png {
            let img = image::open(&path).expect("the saved map opens");
            assert!(img.width() >= 960, "{}", img.width());
        } else {
            let csv = std::fs::read_to_string(&path).expect("the saved CSV");
            assert_eq!(
                csv.lines().count(),
                1 + 48 * 32,
                "a row per cell of 720 × 480"
            );
        }
    }

    // The Geometry view on the demo's detections: the demo lens's distortion (barrel at
    // the wide end), lateral colour and fall-off; then its lensfun entry, exported as the
    // dialog's answer would, with a distortion entry at each focal length.
    h.state_mut()
        .push(Command::View(ViewCommand::SelectView(View::Geometry)));
    step_until(&mut h, "the lens's geometry", |a| {
        a.data().geometry.is_some() && idle(a)
    });
    let d = h.state().data().geometry.as_ref().expect("geometry");
    assert_eq!(d.focal, 24.0, "the widest focal length first");
    assert!(
        d.grid.corner_px < -1.0,
        "barrel at 24 mm: {} px at the corners",
        d.grid.corner_px
    );
    assert!(d.colour.is_some(), "lateral colour measured");
    assert!(
        d.falloff.as_ref().is_some_and(|f| f.fit.corner_stops > 0.3),
        "fall-off measured"
    );
    assert!(d.warning.is_none(), "the demo's light is even");
    snapshot(&mut h, "studio_geometry_demo");
    let xml_path = dir.path().join("demo.lensfun.xml");
    h.state_mut()
        .push(Command::Geometry(GeometryCommand::ExportLensfun(
            xml_path.clone(),
        )));
    step_until(&mut h, "the lensfun entry", |a| {
        idle(a) && (xml_path.is_file() || a.window().messages.iter().any(|m| m.is_error))
    });
    assert!(
        !h.state().window().messages.iter().any(|m| m.is_error),
        "{:?}",
        h.state().window().messages
    );
    let xml = std::fs::read_to_string(&xml_path).expect("the lensfun entry");
    for f in [24, 50, 105] {
        assert!(
            xml.lines()
                .any(|l| l.contains("<distortion ") && l.contains(&format!("focal=\"{f}\""))),
            "a distortion entry at {f} mm:\n{xml}"
        );
    }
    assert_eq!(xml.matches("<distortion").count(), 3, "{xml}");
}

fn folder_has_profile(folder: &Path) -> bool {
    lensblur::profile::Profile::load(&folder.join(lensblur::project::PROFILE_FILE)).is_ok()
}

/// Messages of this run in the log panel, the question asked before removing a shot,
/// the About window, and the session opened listed under File ▸ Recent sessions.
#[test]
fn log_panel_confirmation_about_and_recent_sessions() {
    let dir = tempfile::tempdir().expect("temp dir");
    let folder = dir.path().join("session");
    make_demo(&folder, &test_demo(), &JobContext::silent())
        .expect("session")
        .save()
        .expect("save");
    let demo_dir = dir.path().join("demo");
    // Notices that leave the status line at once: the log keeps them, errors stay.
    let mut h = harness(AppOptions {
        notice_lifetime: Some(Duration::ZERO),
        ..options(&demo_dir, Some(&folder), test_demo())
    });
    step_until(&mut h, "the session", demo_ready);
    let n = h.state().session().map_or(0, |s| s.shots.len());
    let first = h.state().session().expect("session").shots[0].id;

    // Removing a shot asks first; Cancel keeps it, Remove removes it.
    h.state_mut()
        .push(Command::Dialog(DialogCommand::AskConfirm(
            lensblur::app::Confirm::RemoveShot(first),
        )));
    h.run_steps(3);
    snapshot(&mut h, "studio_confirm_remove");
    h.get_by_label("Cancel").click();
    h.run_steps(2);
    assert!(h.state().window().confirm.is_none());
    assert_eq!(h.state().session().map(|s| s.shots.len()), Some(n));
    h.state_mut()
        .push(Command::Dialog(DialogCommand::AskConfirm(
            lensblur::app::Confirm::RemoveShot(first),
        )));
    h.run_steps(3);
    h.get_by_label("Remove").click();
    h.run_steps(2);
    assert_eq!(h.state().session().map(|s| s.shots.len()), Some(n - 1));

    // Detect on the rest: its end is said in words, with the count.
    h.state_mut()
        .push(Command::Stage(StageCommand::RunDetect(None)));
    h.run_steps(1);
    step_until(&mut h, "detection", idle);
    // Inside the session folder, so the message names it relative to it (the snapshot
    // of the log must not hold the test's temporary folder).
    let missing = folder.join("no such photo.png");
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::OpenPhoto(missing)));
    step_until(&mut h, "the photo's error", |a| {
        idle(a) && a.window().messages.iter().any(|m| m.is_error)
    });
    h.run_steps(3);
    assert!(
        h.state().window().messages.iter().all(|m| m.is_error)
            && h.state()
                .window()
                .messages
                .iter()
                .any(|m| m.text.contains("no such photo.png")),
        "notices gone from the status line, the error stays: {:?}",
        h.state().window().messages
    );
    let said = h.state().window().log.iter().any(|m| {
        m.text
            .starts_with(&format!("Detected the chart in {} shots", n - 1))
    });
    assert!(said, "{:?}", h.state().window().log);
    assert!(
        h.state()
            .window()
            .log
            .iter()
            .all(|m| !m.text.contains("{") && !m.text.contains("Some(")),
        "no debug dumps: {:?}",
        h.state().window().log
    );

    // The log: every message with its time (fixed here, so the snapshot is stable).
    h.state_mut().window_mut().messages.clear();
    for m in &mut h.state_mut().window_mut().log {
        m.time = "12:00:00".into();
    }
    h.state_mut()
        .push(Command::Window(WindowCommand::SetLogOpen(true)));
    h.run_steps(3);
    snapshot(&mut h, "studio_log");
    h.state_mut()
        .push(Command::Window(WindowCommand::SetLogOpen(false)));

    h.state_mut()
        .push(Command::Window(WindowCommand::ShowAbout(true)));
    h.run_steps(3);
    snapshot(&mut h, "studio_about");
    h.state_mut()
        .push(Command::Window(WindowCommand::ShowAbout(false)));
    h.run_steps(2);

    // The session is remembered, and listed under File ▸ Recent sessions.
    let recent = lensblur::recent::read_recent(&demo_dir.join("recent.json"));
    assert_eq!(recent.len(), 1, "{recent:?}");
    assert!(recent[0].ends_with("session"));
    h.get_by_label("File").click();
    h.run_steps(2);
    h.get_by_label("Recent sessions").hover();
    h.run_steps(3);
    h.snapshot("studio_menu_recent");
}

/// A developed 8-bit photo opened in the Deblur view with a profile measured on RAW
/// files: the view warns in the command line's own words. The profile library chosen
/// in the studio is where *Lens profile to the library* saves, and is remembered
/// where the batch reads it.
#[test]
fn the_deblur_view_warns_of_a_developed_photo_and_the_library_can_be_chosen() {
    use lensblur::plane::{LensSetting, PictureKind};
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    let folder = parent.path().join("lens");
    std::fs::create_dir(&folder).expect("session folder");
    // A profile of RAW files: the virtual lens's, from a stand-in session's kernels.
    let (w, h) = (320, 224);
    let settings: Vec<LensSetting> = [24.0, 50.0, 105.0]
        .into_iter()
        .flat_map(|focal_mm| [4.0, 5.6, 10.0].map(|f_number| LensSetting { focal_mm, f_number }))
        .collect();
    let ds = lensblur::simulate::SimulatedSession::new(w, h)
        .dataset(&lensblur::simulate::lens::VirtualLens::demo(), &settings);
    let opts = lensblur::calibrate::CalibrateOptions {
        families: lensblur::calibrate::Families::Global,
        alpha: Some(2),
        beta: Some(1),
        ..Default::default()
    };
    let (profile, _) =
        lensblur::calibrate::calibrate(&ds, None, &opts, &JobContext::silent()).expect("calibrate");
    assert_eq!(profile.measured_on(), PictureKind::Raw);
    let profile_path = folder.join("raw.profile.json");
    profile.save(&profile_path).expect("save the profile");
    // The photo: an 8-bit PNG, as an editor exports a developed picture.
    let photo = folder.join("developed.png");
    image::RgbImage::from_fn(w as u32, h as u32, |x, y| {
        let v = ((x * 3 + y * 5) % 256) as u8;
        image::Rgb([v, v / 2 + 60, 255 - v])
    })
    .save(&photo)
    .expect("write the photo");

    let mut h = new_harness(demo.path(), Some(&folder));
    h.run_steps(2);
    h.state_mut()
        .push(Command::Stage(StageCommand::LoadProfile {
            path: profile_path.clone(),
            compare: false,
        }));
    step_until(&mut h, "the profile", |a| a.profile().is_some());
    h.state_mut()
        .push(Command::Deblur(DeblurCommand::OpenPhoto(photo.clone())));
    step_until(&mut h, "the photo", |a| {
        a.views().deblur.photo.is_some() && idle(a)
    });
    h.state_mut()
        .push(Command::View(ViewCommand::SelectView(View::Deblur)));
    h.run_steps(3);
    let said = profile
        .picture_warning(PictureKind::Developed, "developed.png", "raw.profile.json")
        .expect("a developed photo with a RAW profile is warned about");
    h.get_by_label(&format!("warning: {said}"));
    snapshot(&mut h, "studio_deblur_developed_photo");

    // Another library: remembered for the next launch and the batch, and saved into.
    let library = parent.path().join("my profiles");
    h.state_mut()
        .push(Command::Stage(StageCommand::SetProfileLibrary(
            library.clone(),
        )));
    h.run_steps(2);
    assert_eq!(h.state().profile_library(), library.as_path());
    assert_eq!(
        lensblur::recent::profile_library(&demo.path().join("settings.json")),
        library
    );
    h.state_mut()
        .push(Command::Stage(StageCommand::SaveProfileToLibrary));
    h.run_steps(2);
    let saved = lensblur::batch::ProfileLibrary::load(&library).expect("saved into the library");
    assert_eq!(saved.profiles.len(), 1);
}
