//! Snapshot tests of the studio: every view rendered on a small demo session, and the
//! flow driven by clicks through AccessKit labels. Snapshots live in `screenshots/`
//! (kittest.toml); `UPDATE_SNAPSHOTS=1` rewrites them.
#![cfg(feature = "gui")]

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use lensblur::app::{AppOptions, Command, StudioApp, View};
use lensblur::session::DemoSpec;
use std::path::Path;
use std::time::{Duration, Instant};

fn new_harness(demo_dir: &Path, session: Option<&Path>) -> Harness<'static, StudioApp> {
    // Pin the software Vulkan renderer (lavapipe) so snapshots match across machines.
    // SAFETY: set before any renderer or thread reads it; tests in this file set the same value.
    unsafe { std::env::set_var("WGPU_BACKEND", "vulkan") };
    let options = AppOptions {
        session: session.map(Path::to_path_buf),
        demo_dir: demo_dir.to_path_buf(),
        demo_spec: DemoSpec::small(),
        log_frame_times: false,
        autorun: Vec::new(),
        started: Instant::now(),
    };
    Harness::builder()
        .with_size(egui::Vec2::new(1280.0, 800.0))
        .wgpu()
        .build_eframe(move |cc| StudioApp::new(&cc.egui_ctx, options))
}

/// Steps the UI (in real time, so job threads progress) until `done` holds.
fn step_until(
    h: &mut Harness<'_, StudioApp>,
    what: &str,
    timeout: Duration,
    done: impl Fn(&StudioApp) -> bool,
) {
    let start = Instant::now();
    while !done(h.state()) {
        assert!(
            start.elapsed() < timeout,
            "timed out after {timeout:?} waiting for {what}; messages: {:?}",
            h.state().messages
        );
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(20));
    }
    // Where the test's time goes (shown with --nocapture).
    eprintln!("{what}: {:.1} s", start.elapsed().as_secs_f32());
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

/// A snapshot without the pointer: a button left hovered after a click (and the tooltip
/// that appears once the pointer rests long enough) would depend on how many frames ran.
fn snapshot(h: &mut Harness<'_, StudioApp>, name: &str) {
    h.remove_cursor();
    h.run_steps(2);
    h.snapshot(name);
}

fn demo_ready(app: &StudioApp) -> bool {
    app.session
        .as_ref()
        .is_some_and(|s| !s.shots.is_empty() && app.previews.len() == s.shots.len())
        && app.jobs.running.is_empty()
}

#[test]
fn every_view_on_the_demo_session() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut h = new_harness(dir.path(), None);
    // The first frame comes before the demo exists: the panel says what is happening.
    h.run_steps(1);
    assert!(h.state().session.is_none());
    h.get_by_label_contains("Making the demo session");
    step_until(
        &mut h,
        "the demo session",
        Duration::from_secs(120),
        demo_ready,
    );
    let n = h.state().session.as_ref().map_or(0, |s| s.shots.len());
    assert_eq!(n, DemoSpec::small().settings.len());
    assert!(
        dir.path().join("session.json").is_file(),
        "the demo session is cached"
    );
    snapshot(&mut h, "studio_shot");

    // Detect every shot by clicking, then the overlays line up with the squares.
    h.get_by_label("Detect").click();
    step_until(&mut h, "detection", Duration::from_secs(240), |a| {
        a.detections.len() == DemoSpec::small().settings.len() && a.jobs.running.is_empty()
    });
    for d in h.state().detections.values() {
        let spec = DemoSpec::small().chart();
        assert_eq!(
            d.ok_squares().count(),
            spec.cols * spec.rows,
            "every square of the demo chart is aligned"
        );
    }
    snapshot(&mut h, "studio_shot_detected");

    // Inspect one square: its crops appear beside the shot.
    h.state_mut().commands.push(Command::SelectSquare((3, 5)));
    h.run_steps(3);
    let rms = h
        .state()
        .inspection
        .as_ref()
        .map(|i| i.crops.residual_rms)
        .expect("the inspector opens on the clicked square");
    assert!(
        rms < 0.05,
        "aligned square explains the pixels: residual rms {rms}"
    );
    snapshot(&mut h, "studio_square_inspector");

    // Kernels on every detected shot, by clicking; the field shows the measured fits.
    h.get_by_label("Kernels").click();
    let n_shots = DemoSpec::small().settings.len();
    step_until(&mut h, "kernels", Duration::from_secs(600), |a| {
        a.measured.len() == n_shots && a.jobs.running.is_empty()
    });
    let spec = DemoSpec::small().chart();
    let session = h.state().session.clone().expect("session");
    for (i, m) in &h.state().measured {
        // Every square and channel is measured or reported with its reason, and
        // nearly all are measured on clean simulated shots.
        let file = lensblur::kernel::file::KernelsFile::load(&session.result_path(*i, "kernels"))
            .expect("kernels file written");
        assert_eq!(
            file.samples.len() + file.failed.len(),
            3 * spec.cols * spec.rows
        );
        assert!(file.failed.iter().all(|f| !f.reason.is_empty()));
        assert!(
            m.len() * 100 >= 97 * 3 * spec.cols * spec.rows,
            "{} measured",
            m.len()
        );
    }
    h.get_by_label("Kernel field").click();
    h.run_steps(3);
    assert_eq!(h.state().view, View::KernelField);
    snapshot(&mut h, "studio_kernel_field");

    // Calibrate: cross-validation chooses α and β, the profile is written.
    h.get_by_label("Models").click();
    h.run_steps(2);
    h.get_by_label("Calibrate").click();
    step_until(&mut h, "calibration", Duration::from_secs(300), |a| {
        a.profile.is_some() && a.jobs.running.is_empty()
    });
    assert!(h.state().cv.is_some(), "cross-validation ran");
    assert!(
        dir.path().join("profile.json").is_file(),
        "profile saved in the session"
    );
    snapshot(&mut h, "studio_models");

    h.get_by_label("Sweeps").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_sweeps");

    h.get_by_label("Kernel field").click();
    h.run_steps(2);
    h.get_by_label("Predicted").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_kernel_field_predicted");
    h.get_by_label("Ground truth").click();
    h.run_steps(2);
    h.get_by_label("Compare with a second unit").click();
    h.run_steps(3);
    assert!(h.state().compare_units);
    snapshot(&mut h, "studio_kernel_field_compare");

    h.get_by_label("Deblur").click();
    h.run_steps(3);
    snapshot(&mut h, "studio_deblur");

    // The cached demo opens at once on the next launch.
    drop(h);
    let mut again = new_harness(dir.path(), None);
    again.run_steps(1);
    assert!(
        again.state().session.is_some(),
        "cached demo session opens without remaking it"
    );
}

#[test]
fn light_theme_and_user_session() {
    let demo = tempfile::tempdir().expect("temp dir");
    let parent = tempfile::tempdir().expect("temp dir");
    // A named folder: the session takes its name from it, and the UI shows it.
    let folder_path = parent.path().join("my session");
    std::fs::create_dir(&folder_path).expect("session folder");
    let folder = &folder_path;
    // A user's shot: a PNG of the chart.
    let spec = lensblur::chart::ChartSpec {
        cols: 6,
        rows: 4,
        ..Default::default()
    };
    let h_img = lensblur::geometry::Homography::from_row_major([
        40.0, 0.0, 40.0, 0.0, 40.0, 40.0, 0.0, 0.0, 1.0,
    ]);
    let plane = lensblur::chart::rasterize(&spec, &h_img, 320, 240, 1.0);
    let img = image::GrayImage::from_fn(320, 240, |x, y| {
        image::Luma([(plane.get(x as usize, y as usize) * 255.0) as u8])
    });
    let shot = folder.join("my_shot.png");
    img.save(&shot).expect("write shot");

    let mut h = new_harness(demo.path(), Some(folder));
    h.run_steps(2);
    assert!(
        h.state()
            .session
            .as_ref()
            .is_some_and(|s| s.shots.is_empty())
    );
    h.get_by_label("Light theme").click();
    h.run_steps(2);
    assert!(!h.state().dark);
    // Drag and drop a file onto the window.
    h.input_mut().dropped_files.push(dropped(&shot));
    step_until(&mut h, "the dropped shot", Duration::from_secs(30), |a| {
        a.previews.len() == 1
    });
    let saved = lensblur::session::Session::open(folder).expect("session saved as it changes");
    assert_eq!(saved.shots.len(), 1);
    // A file of the wrong kind is refused with a message naming it.
    let bad = folder.join("notes.txt");
    std::fs::write(&bad, b"x").expect("write");
    h.input_mut().dropped_files.push(dropped(&bad));
    h.run_steps(2);
    assert!(
        h.state()
            .messages
            .iter()
            .any(|m| m.is_error && m.text.contains("notes.txt"))
    );
    snapshot(&mut h, "studio_user_session_light");
}
