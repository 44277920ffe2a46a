//! The session: opening one (or the demo), adding and removing shots, the chart and
//! stage settings, and the results a reopened session already has.

use super::CV_FILE;
use super::save;
use super::stages::spawn_dataset;
use crate::app::jobs::{JobKind, JobScope};
use crate::app::view_data;
use crate::app::{Command, Confirm, JobOutput, StudioApp};
use crate::app::{DeblurCommand, SessionCommand, SessionOutput, StageCommand};
use crate::job::JobContext;
use crate::project::Project;
use crate::session::{Session, ShotId};
use std::path::PathBuf;
use std::sync::Arc;

/// The session: its shots, their settings, the chart and stage settings, opening one.
pub(super) fn apply_session(app: &mut StudioApp, command: SessionCommand) {
    match command {
        SessionCommand::AddShots(files) => add_shots(app, &files),
        SessionCommand::RemoveShot(id) => remove_shot(app, id),
        SessionCommand::SetShotSetting {
            shot,
            focal_mm,
            f_number,
        } => {
            if let Some(shot) = app.session_mut().and_then(|s| s.shot_mut(shot)) {
                shot.focal_mm = focal_mm;
                shot.f_number = f_number;
                save(app);
                spawn_dataset(app);
            }
        }
        SessionCommand::ApplySettings { chart, settings } => {
            // A new chart discards what was measured with the old one: ask first.
            let has_results = app.detections().next().is_some() || app.measured().next().is_some();
            let chart_changed = app.session().is_some_and(|s| s.chart != chart);
            if chart_changed && has_results {
                app.window.confirm = Some(Confirm::ReplaceChart { chart, settings });
            } else {
                apply_settings(app, chart, settings);
            }
        }
        SessionCommand::LoadChart(path) => match crate::chart::ChartSpec::load(&path) {
            Ok(spec) => {
                let settings = app
                    .views
                    .session
                    .settings_edit
                    .as_ref()
                    .map(|e| e.1.clone())
                    .or_else(|| app.session().map(|s| s.settings.clone()))
                    .unwrap_or_default();
                app.views.session.settings_edit = Some((spec, settings));
                app.info(format!(
                    "chart spec {} read: press Apply to use it",
                    app.shown_path(&path)
                ));
            }
            Err(e) => app.error(e.to_string()),
        },
        SessionCommand::EditSettings(edit) => app.views.session.settings_edit = edit,
        SessionCommand::OpenSession(path) => match crate::session::Session::open(&path) {
            Ok(s) => {
                let plain_folder = s.shots.is_empty() && path.is_dir();
                if app.set_session(s) {
                    if plain_folder {
                        take_in_folder(app);
                    }
                    save(app);
                }
            }
            Err(e) => app.error(e.to_string()),
        },
    }
}

/// The demo session as it is made, and results a reopened session already has.
pub(super) fn session_output(app: &mut StudioApp, output: SessionOutput) {
    match output {
        SessionOutput::DemoShot(s) => {
            if app.session().is_none() {
                if app.set_session(*s) {
                    app.info("demo session: showing each simulated shot as soon as it is made");
                }
            } else {
                merge_demo(app, &s);
            }
        }
        SessionOutput::DemoReady(s) => {
            let n = s.shots.len();
            if app.session().is_none() {
                if !app.set_session(*s) {
                    return;
                }
            } else if !merge_demo(app, &s) {
                // The user opened another session meanwhile: the demo waits in its
                // folder for the next launch.
                return;
            }
            save(app);
            app.info(format!(
                "demo session ready: {n} simulated shots of the virtual lens, and a photo it blurred"
            ));
            calibrate_demo(app);
        }
        SessionOutput::ResultsRead { survey, cv } => {
            // The cache decides what is done: results measured elsewhere (another
            // front end, an earlier version of the session) count, and a status whose
            // result has gone is pending again.
            let dropped = match app.project.as_mut() {
                Some(p) => p.apply_survey(*survey),
                None => return,
            };
            save(app);
            for line in dropped {
                app.info(line);
            }
            if let Some(p) = app.project.as_mut() {
                p.read_cv(cv);
            }
            spawn_dataset(app);
            calibrate_demo(app);
        }
    }
}

/// The demo without a profile (a first launch, or one closed before its calibration
/// ended) is calibrated by itself once all its shots exist, and then shows its photo
/// before and after: a newcomer sees what lensblur does without a click.
///
/// Asked when the demo's shots are ready and again when its job has finished: the job
/// still counts as running when its last output arrives in an earlier batch of events
/// than its end, and the first launch must not wait on that.
pub(super) fn calibrate_demo(app: &mut StudioApp) {
    let wanted = app.options.calibrate_demo
        && app
            .session()
            .is_some_and(|s| s.is_demo && s.profile.is_none() && !s.shots.is_empty())
        && !app.jobs.is_running(JobKind::DemoSession)
        && !app.jobs.is_running(JobKind::CalibrateAll)
        && !app
            .commands
            .iter()
            .any(|c| matches!(c, Command::Stage(StageCommand::CalibrateAll { .. })));
    if wanted {
        app.info("calibrating the demo lens: detect, kernels and calibrate, then its photo before and after");
        app.commands
            .push(Command::Stage(StageCommand::CalibrateAll {
                then_deblur: true,
            }));
    }
}

fn add_shots(app: &mut StudioApp, files: &[PathBuf]) {
    if app.session().is_none() {
        app.error("open or create a session folder before adding shots (Ctrl+O)");
        return;
    }
    let mut errors = Vec::new();
    let mut added = None;
    if let Some(p) = app.project.as_mut() {
        for f in files {
            match p.add_shot(f) {
                Ok(id) => added = Some(id),
                Err(e) => errors.push(e.to_string()),
            }
        }
    }
    for e in errors {
        app.error(e);
    }
    if let Some(id) = added {
        app.views.shot.selected = Some(id);
        app.views.shot.viewer.sensor_px_per_point = None;
        save(app);
    }
}

/// A folder of shots opened as a session takes its shots in, as the command line
/// does, saying which files it skipped.
fn take_in_folder(app: &mut StudioApp) {
    let Some(p) = app.project.as_mut() else {
        return;
    };
    match p.take_in_folder(crate::pipeline::GivenSetting::default()) {
        Ok(taken) if taken.added > 0 || !taken.skipped.is_empty() => {
            let first = p.session().shots.first().map(|shot| shot.id);
            let mut line = format!("took in the folder's {} shots", taken.added);
            if !taken.skipped.is_empty() {
                line.push_str(&format!(
                    "; skipped {} (not shots)",
                    taken.skipped.join(", ")
                ));
            }
            if !taken.no_setting.is_empty() {
                line.push_str(&format!(
                    "; no focal length or aperture in the EXIF of {}: type them in the shot panel",
                    taken.no_setting.join(", ")
                ));
            }
            app.info(line);
            app.views.shot.selected = first;
            read_results(app);
        }
        Ok(_) => {}
        Err(e) => app.error(e.to_string()),
    }
}

/// Removes a shot from the session (its file and cached results stay on disk): work on
/// it stops, and whatever it still sends is dropped since the shot is gone.
pub(super) fn remove_shot(app: &mut StudioApp, id: ShotId) {
    let Some(p) = app.project.as_mut() else {
        return;
    };
    let Some(i) = p.session().index_of(id) else {
        return;
    };
    p.remove_shot(id);
    app.jobs.cancel_shot(id);
    let shots = &p.session().shots;
    let next = shots.get(i).or_else(|| shots.last()).map(|shot| shot.id);
    app.shots.remove(&id);
    if app.views.shot.selected == Some(id) {
        app.views.shot.selected = next;
        app.views.shot.square = None;
    }
    save(app);
    spawn_dataset(app);
}

/// New chart or stage settings; results they make stale go back to pending (their
/// files stay until the stage runs again).
pub(super) fn apply_settings(
    app: &mut StudioApp,
    chart: crate::chart::ChartSpec,
    settings: crate::session::StageSettings,
) {
    if let Err(e) = chart.validate() {
        app.error(format!("chart spec: {e}"));
        return;
    }
    let Some(p) = app.project.as_mut() else {
        return;
    };
    let s = p.session();
    let chart_changed = s.chart != chart;
    let kernels_changed = chart_changed
        || s.settings.oversample != settings.oversample
        || s.settings.weight_all_subpixels != settings.weight_all_subpixels;
    let s = p.session_mut();
    s.chart = chart;
    s.settings = settings;
    p.forget_results(chart_changed, kernels_changed);
    if chart_changed {
        app.views.shot.square = None;
    }
    app.views.session.settings_edit = None;
    app.info(match (chart_changed, kernels_changed) {
        (true, _) => "settings applied: detection and kernels run again with the new chart",
        (false, true) => "settings applied: kernels run again with the new settings",
        _ => "settings applied",
    });
    save(app);
}

/// Adds to the open demo session the shots the demo job has made since (and at the end
/// its photo). False when the open session is another one.
fn merge_demo(app: &mut StudioApp, made: &Session) -> bool {
    let Some(p) = app
        .project
        .as_mut()
        .filter(|p| p.session().is_demo && p.folder() == made.folder())
    else {
        return false;
    };
    p.adopt_shots(made);
    let s = p.session_mut();
    if s.demo_photo.is_none() && made.demo_photo.is_some() {
        s.demo_photo.clone_from(&made.demo_photo);
        let opened = s.clone();
        app.open_demo_photo(&opened);
    }
    true
}

/// Finds the results a session already has in its cache (measured by the studio or by
/// `lensblur calibrate`), off the UI thread: shots are fingerprinted, and kernels files
/// with their arrays run to megabytes.
pub(in crate::app) fn read_results(app: &mut StudioApp) {
    let Some(p) = app.project.as_ref() else {
        return;
    };
    let cv_path = p.folder().join(CV_FILE);
    if p.session().shots.is_empty() && !cv_path.is_file() {
        return;
    }
    let survey = p.survey_job();
    let scope = JobScope::session(app.session_generation);
    let r = app
        .jobs
        .spawn_scoped(JobKind::ReadResults, scope, move |ctx, out| {
            let survey = Box::new(survey.run(ctx).map_err(|e| e.to_string())?);
            let cv = crate::io::read_json_text(&cv_path)
                .ok()
                .and_then(|t| serde_json::from_str(&t).ok())
                .map(Arc::new);
            out.emit(JobOutput::Session(SessionOutput::ResultsRead {
                survey,
                cv,
            }));
            Ok(())
        });
    if let Err(e) = r {
        app.error(e);
    }
}

impl StudioApp {
    /// Opens the demo session, or makes it in the background (each shot shown as soon
    /// as it is on disk).
    pub(in crate::app) fn open_or_make_demo(&mut self) {
        let dir = self.options.demo_dir.clone();
        if dir.join(crate::session::SESSION_FILE).is_file() {
            match Session::open(&dir) {
                // A demo left half made (the window closed while it streamed in) is
                // finished by make_demo, which keeps the shots already on disk.
                Ok(s)
                    if s.is_demo
                        && s.demo_key == Some(self.options.demo_spec.key())
                        && s.shots.len() == self.options.demo_spec.settings.len()
                        && s.demo_photo.is_some() =>
                {
                    self.set_session(s);
                    return;
                }
                Ok(_) => {}
                Err(e) => self.error(format!("{e} (making the demo session again)")),
            }
        }
        let spec = self.options.demo_spec.clone();
        let started = self
            .jobs
            .spawn_apart(JobKind::DemoSession, move |ctx: &JobContext, out| {
                // Each shot is shown as soon as it is on disk: a newcomer sees a
                // session within seconds instead of waiting for all of them.
                let s = crate::simulate::demo::make_demo_streaming(&dir, &spec, ctx, &mut |s| {
                    out.emit(JobOutput::Session(SessionOutput::DemoShot(Box::new(
                        s.clone(),
                    ))));
                })
                .map_err(|e| e.to_string())?;
                out.emit(JobOutput::Session(SessionOutput::DemoReady(Box::new(s))));
                Ok(())
            });
        if let Err(e) = started {
            self.error(e);
        }
    }

    /// Opens a session in the window, holding its folder's lock while it is open.
    /// Returns false, keeping the session that was open, when another studio or
    /// command is working in that folder.
    pub(in crate::app) fn set_session(&mut self, s: Session) -> bool {
        // Reopening the folder open now keeps its lock: a lock is per open file, so
        // taking it again would refuse itself. Another folder is locked before the old
        // one is let go, so a refusal keeps the session that was open.
        // The profile compared with stays: it is another unit of the lens, not a
        // result of the session.
        let compare = self.compare_profile().cloned();
        let same_folder = self
            .project
            .as_ref()
            .is_some_and(|p| p.folder() == s.folder());
        let lock = if same_folder {
            self.project.take().and_then(Project::into_lock)
        } else {
            None
        };
        let mut project = match Project::with_session(s, lock, "the lensblur studio") {
            Ok((project, opened)) => {
                if opened.swept > 0 {
                    self.info(format!(
                        "{}: removed {} unfinished temporary files left by an interrupted write",
                        project.folder().display(),
                        opened.swept
                    ));
                }
                if let Some(why) = opened.unlocked {
                    // A read-only folder: it is shown, and saving it will say why not.
                    self.info(format!("{why}: opened without a lock"));
                }
                project
            }
            Err(e) => {
                self.error(e.to_string());
                return false;
            }
        };
        if let Some((path, profile)) = compare {
            project.use_profile(path, profile, true);
        }
        let s = project.session().clone();
        // Work on the session being closed stops, and what it still sends is dropped.
        self.jobs.cancel_session_jobs();
        self.session_generation += 1;
        self.shots.clear();
        self.data = view_data::ViewData::default();
        self.views.session.settings_edit = None;
        self.views.deblur.comparison = None;
        if let Some(p) = &s.profile {
            let path = if p.is_absolute() {
                p.clone()
            } else {
                s.folder().join(p)
            };
            if path.is_file() {
                self.commands
                    .push(Command::Stage(StageCommand::LoadProfile {
                        path,
                        compare: false,
                    }));
            }
        }
        self.views.shot.square = None;
        self.views.shot.selected = s.shots.first().map(|shot| shot.id);
        self.views.shot.viewer.sensor_px_per_point = None;
        if let Some((f, a)) = middle_setting(&s) {
            self.views.field.focal_mm = f;
            self.views.field.f_number = a;
        }
        self.project = Some(project);
        read_results(self);
        if s.is_demo {
            self.open_demo_photo(&s);
        }
        // Every session the user opens is remembered, but not the built-in demo: it is
        // what the studio opens by itself.
        if s.folder() != self.options.demo_dir
            && let Some(file) = self.options.recent_file.clone()
        {
            match crate::recent::remember_recent(&file, s.folder()) {
                Ok(list) => self.window.recent = list,
                Err(e) => self.error(format!("cannot remember the session as recent: {e}")),
            }
        }
        true
    }

    /// Opens the demo's photo in the Deblur view, unless a photo is open already.
    pub(in crate::app) fn open_demo_photo(&mut self, s: &Session) {
        if let Some(p) = &s.demo_photo
            && self.views.deblur.photo.is_none()
        {
            let path = s.folder().join(&p.path);
            if path.is_file() {
                self.commands
                    .push(Command::Deblur(DeblurCommand::OpenPhoto(path)));
            }
        }
    }
}

/// The sliders' starting setting: the middle (lower middle) focal length and aperture
/// shot, so predicted fields and sweeps open on settings that were measured.
fn middle_setting(s: &Session) -> Option<(f64, f64)> {
    let (f, a) = s.setting_grid();
    Some((
        *f.get(f.len().saturating_sub(1) / 2)?,
        *a.get(a.len().saturating_sub(1) / 2)?,
    ))
}
