//! The studio: one window over the headless core (ARCHITECTURE.md, Studio).
//!
//! Split as `state` (the app's state types), `command` (what panels ask for and what
//! jobs hand back), `logic` (apply [`Command`]s, drain finished jobs, keep the session
//! saved), `view_data` (what the views show that takes computing: made when its inputs
//! change, cached keyed by them, long work on a job thread), `textures` (images made
//! into textures, for both `logic` and `view_data`) and `ui` (draw; every drawing
//! function ends in `_ui`, only reads the app and emits commands, and shows a
//! placeholder where view data is absent). Every computation is a call into the core;
//! the app only shows and drives.

mod command;
pub mod jobs;
mod logic;
mod state;
mod textures;
mod ui;
pub mod view_data;

pub use command::{Command, Confirm, JobOutput};
pub(crate) use state::Tally;
pub use state::{
    AppOptions, ColourRange, ComparisonView, DeblurLayout, DeblurResult, DeblurState, DeblurZoom,
    Difference, FieldOptions, FieldShow, FieldSource, FrameLog, Message, PendingPlotPng, Photo,
    PlotId, SharpnessChoice, ShotPreview, ShotView, SweepAxis, View, ViewerState, clock_now,
};

use crate::chart::ChartSpec;
use crate::crossval::CvReport;
use crate::detect::Detection;
use crate::kernel::file::KernelsFile;
use crate::model::Dataset;
use crate::plane::Channel;
use crate::profile::Profile;
use crate::project::Project;
use crate::session::{Session, ShotId, StageSettings};
use jobs::Jobs;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// How long a notice takes to fade out of the status line, at the end of its lifetime.
const NOTICE_FADE: std::time::Duration = std::time::Duration::from_secs(1);

/// How often the window repaints while only a job's progress changes.
const PROGRESS_REPAINT: std::time::Duration = std::time::Duration::from_millis(250);

/// The studio app.
pub struct StudioApp {
    /// The open calibration project: the session, its folder's lock, and each shot's
    /// record (file, settings, status, detection, kernels).
    project: Option<Project>,
    pub jobs: Jobs<JobOutput>,
    pub view: View,
    pub selected_shot: Option<ShotId>,
    channel: Channel,
    /// The session's shots as the window has them: loading, loaded, or unreadable (a
    /// shot has an entry once its loading has started).
    shots: BTreeMap<ShotId, ShotView>,
    /// The status line's messages (dismissable), newest last.
    pub messages: Vec<Message>,
    /// Every message of this run, newest last: the log panel.
    pub log: Vec<Message>,
    log_open: bool,
    /// The session panel on the left; folded, the views have the whole width.
    session_panel_open: bool,
    /// The question being asked, in a modal dialog.
    pub confirm: Option<Confirm>,
    show_help: bool,
    show_guide: bool,
    show_about: bool,
    /// Recently opened session folders, most recent first.
    recent: Vec<PathBuf>,
    pub commands: Vec<Command>,
    pub viewer: ViewerState,
    /// Setting for the predicted / ground-truth field and the sweeps.
    field_focal_mm: f64,
    field_f_number: f64,
    pub compare_units: bool,
    /// The square clicked in the Shot view: (row, col).
    pub selected_square: Option<(usize, usize)>,
    /// What the Kernel field view shows.
    pub field_source: FieldSource,
    field_show: FieldShow,
    pub field_options: FieldOptions,
    pub sweep_axis: SweepAxis,
    /// What the Sharpness view maps.
    pub sharpness: SharpnessChoice,
    /// The Geometry view's focal length and aperture; `None`: the session's first.
    pub geometry_focal_mm: Option<f64>,
    pub geometry_f_number: Option<f64>,
    pub plot_png: Option<PendingPlotPng>,
    /// What the views show that takes computing, cached by what it depends on.
    pub views: view_data::ViewData,
    pub deblur: DeblurState,
    /// Settings being edited in the session panel, applied by its Apply button.
    settings_edit: Option<(ChartSpec, StageSettings)>,
    pub dark: bool,
    frames: FrameLog,
    options: AppOptions,
    ctx: egui::Context,
    /// Counts the sessions opened: results of jobs started for an earlier one are
    /// dropped when they arrive.
    session_generation: u64,
    first_frame_logged: bool,
    /// Frames left of the autorun's strength drag.
    drag_frames: usize,
    first_shot_logged: bool,
    before_after_logged: bool,
    ready_logged: bool,
    /// File dialogs run on their own threads (a portal dialog's future, blocked on
    /// there) and send back the commands their answer makes; the window never waits.
    dialog_tx: std::sync::mpsc::Sender<Vec<Command>>,
    dialog_rx: std::sync::mpsc::Receiver<Vec<Command>>,
    /// One file dialog at a time: a second would stack on the first.
    dialog_open: bool,
    /// Per running detect or kernels job (by id): how its shots went so far.
    tallies: BTreeMap<u64, Tally>,
    /// The lens's range typed for the shooting plan; `None`: the session's.
    plan_range: Option<crate::review::LensRange>,
    /// A running *Calibrate all* opens the Deblur view on the photo once it ends (the
    /// first launch's demo).
    deblur_when_calibrated: bool,
}

impl StudioApp {
    /// Builds the app and starts whatever the first frame needs (opening the session, or
    /// making the demo session in the background).
    #[must_use]
    pub fn new(ctx: &egui::Context, options: AppOptions) -> Self {
        let wake_ctx = ctx.clone();
        let progress_ctx = ctx.clone();
        let (dialog_tx, dialog_rx) = std::sync::mpsc::channel();
        let recent = options
            .recent_file
            .as_deref()
            .map(crate::recent::read_recent)
            .unwrap_or_default();
        let mut app = Self {
            project: None,
            jobs: Jobs::new(options.job_threads, move || wake_ctx.request_repaint())
                .with_progress_wake(move || progress_ctx.request_repaint_after(PROGRESS_REPAINT)),
            view: View::Shot,
            selected_shot: None,
            channel: Channel::G,
            shots: BTreeMap::new(),
            messages: Vec::new(),
            log: Vec::new(),
            log_open: false,
            session_panel_open: true,
            confirm: None,
            show_help: false,
            show_guide: false,
            show_about: false,
            recent,
            commands: Vec::new(),
            viewer: ViewerState::fitted(),
            field_focal_mm: 50.0,
            field_f_number: 5.6,
            compare_units: false,
            selected_square: None,
            field_source: FieldSource::Measured,
            field_show: FieldShow::Ellipses,
            field_options: FieldOptions::default(),
            sweep_axis: SweepAxis::Sigma,
            sharpness: SharpnessChoice::default(),
            geometry_focal_mm: None,
            geometry_f_number: None,
            plot_png: None,
            views: view_data::ViewData::default(),
            deblur: DeblurState::default(),
            settings_edit: None,
            dark: true,
            frames: FrameLog::default(),
            options: options.clone(),
            ctx: ctx.clone(),
            session_generation: 0,
            first_frame_logged: false,
            drag_frames: 0,
            first_shot_logged: false,
            before_after_logged: false,
            ready_logged: false,
            dialog_tx,
            dialog_rx,
            dialog_open: false,
            tallies: BTreeMap::new(),
            deblur_when_calibrated: false,
            plan_range: None,
        };
        ctx.set_theme(egui::Theme::Dark);
        match &options.session {
            Some(path) => match Session::open(path) {
                Ok(s) => {
                    if app.set_session(s) {
                        logic::save(&mut app);
                    }
                }
                Err(e) => app.error(e.to_string()),
            },
            None => app.open_or_make_demo(),
        }
        app
    }

    /// The open session.
    #[must_use]
    pub fn session(&self) -> Option<&Session> {
        self.project.as_ref().map(Project::session)
    }

    /// The open calibration project.
    #[must_use]
    pub fn project(&self) -> Option<&Project> {
        self.project.as_ref()
    }

    /// The open session, to change what the user changes (its shots go through the
    /// project).
    pub(crate) fn session_mut(&mut self) -> Option<&mut Session> {
        self.project.as_mut().map(Project::session_mut)
    }

    /// The session's measured Gaussians over every shot with kernels and a setting.
    #[must_use]
    pub fn dataset(&self) -> Option<&Arc<Dataset>> {
        self.project.as_ref()?.dataset()
    }

    /// The lens profile in use (calibrated here or loaded) and where it lies.
    #[must_use]
    pub fn profile(&self) -> Option<&(PathBuf, Arc<Profile>)> {
        self.project.as_ref()?.profile()
    }

    /// A second profile shown beside the first (another unit of the lens).
    #[must_use]
    pub fn compare_profile(&self) -> Option<&(PathBuf, Arc<Profile>)> {
        self.project.as_ref()?.compare_profile()
    }

    /// The cross-validation report of the profile's fit.
    #[must_use]
    pub fn cv(&self) -> Option<&Arc<CvReport>> {
        self.project.as_ref()?.cv()
    }

    /// The shot's detection, this run's or read back from the session's results.
    #[must_use]
    pub fn detection(&self, id: ShotId) -> Option<&Arc<Detection>> {
        self.project.as_ref()?.detection(id)
    }

    /// The shot's measured kernels and their Gaussians (all channels).
    #[must_use]
    pub fn kernels(&self, id: ShotId) -> Option<&Arc<KernelsFile>> {
        self.project.as_ref()?.kernels(id)
    }

    /// The shots with a detection, in session order.
    pub fn detections(&self) -> impl Iterator<Item = (ShotId, &Arc<Detection>)> {
        self.project.iter().flat_map(|p| {
            p.shots()
                .filter_map(|s| Some((s.shot.id, s.state.detection.as_ref()?)))
        })
    }

    /// The shots with measured kernels, in session order.
    pub fn measured(&self) -> impl Iterator<Item = (ShotId, &Arc<KernelsFile>)> {
        self.project.iter().flat_map(|p| {
            p.shots()
                .filter_map(|s| Some((s.shot.id, s.state.kernels.as_ref()?)))
        })
    }

    /// Takes one shot's step of a measurement as a job hands it back: recorded in the
    /// project, the session saved (tests stand in for a measurement with it).
    pub fn record_shot_event(&mut self, event: crate::project::ShotEvent) {
        logic::shot_event(self, &event);
    }

    /// Whether the open session still has this shot (a job's result may arrive after
    /// the shot was removed).
    #[must_use]
    pub fn has_shot(&self, id: ShotId) -> bool {
        self.session().is_some_and(|s| s.shot(id).is_some())
    }

    /// The shot loaded for display, once it is.
    #[must_use]
    pub fn preview(&self, id: ShotId) -> Option<&ShotPreview> {
        self.shots.get(&id).and_then(ShotView::preview)
    }

    /// The shots loaded for display, in id order.
    pub fn previews(&self) -> impl Iterator<Item = (ShotId, &ShotPreview)> {
        self.shots
            .iter()
            .filter_map(|(id, v)| Some((*id, v.preview()?)))
    }

    /// Why the shot cannot be read, if it cannot.
    #[must_use]
    pub fn unreadable(&self, id: ShotId) -> Option<&str> {
        self.shots.get(&id).and_then(ShotView::unreadable)
    }

    /// The shots that cannot be read, with the reason, in id order.
    pub fn unreadable_shots(&self) -> impl Iterator<Item = (ShotId, &str)> {
        self.shots
            .iter()
            .filter_map(|(id, v)| Some((*id, v.unreadable()?)))
    }

    /// How many shots are loaded or known unreadable (no longer loading).
    #[must_use]
    pub fn shots_shown(&self) -> usize {
        self.shots
            .values()
            .filter(|v| !matches!(v, ShotView::Loading))
            .count()
    }

    pub fn error(&mut self, text: impl Into<String>) {
        let text = self.shorten_paths(text.into());
        self.say(true, text);
    }

    pub fn info(&mut self, text: impl Into<String>) {
        let text = self.shorten_paths(text.into());
        self.say(false, text);
    }

    /// The status line shows the latest messages until dismissed; the log keeps them all.
    fn say(&mut self, is_error: bool, text: String) {
        let m = Message {
            is_error,
            text,
            time: clock_now(),
            said: Instant::now(),
        };
        self.log.push(m.clone());
        self.messages.push(m);
    }

    /// A path as the UI shows it: relative to the session folder when it lies inside,
    /// `~/…` under the home folder, absolute otherwise. Where the session lives is one
    /// hover away (the session name's tooltip); repeating it in every line would crowd
    /// the window and tie what it shows to where the folder happens to be.
    #[must_use]
    pub fn shown_path(&self, path: &Path) -> String {
        if let Some(s) = self.session()
            && let Ok(rel) = path.strip_prefix(s.folder())
            && !rel.as_os_str().is_empty()
        {
            return rel.display().to_string();
        }
        if let Some(home) = std::env::var_os("HOME").map(PathBuf::from)
            && let Ok(rel) = path.strip_prefix(&home)
        {
            return format!("~/{}", rel.display());
        }
        path.display().to_string()
    }

    /// Messages from the core name files by their full paths; inside the session folder
    /// the relative name says the same in less space.
    pub(crate) fn shorten_paths(&self, text: String) -> String {
        match self.session() {
            Some(s) if !s.folder().as_os_str().is_empty() => {
                let prefix = format!("{}{}", s.folder().display(), std::path::MAIN_SEPARATOR);
                text.replace(&prefix, "")
            }
            _ => text,
        }
    }

    /// Runs one frame's logic without drawing (also what tests call between steps).
    pub fn logic_step(&mut self) {
        logic::drain_dialogs(self);
        logic::drain_jobs(self);
        logic::finish_plot_png(self);
        let commands = std::mem::take(&mut self.commands);
        for c in commands {
            logic::apply(self, c);
        }
        logic::ensure_preview(self);
        view_data::refresh(self);
        logic::autorun_step(self);
        logic::expire_notices(self);
    }
}

impl eframe::App for StudioApp {
    fn logic(&mut self, ctx: &egui::Context, _frame: &mut eframe::Frame) {
        self.logic_step();
        if self.drag_frames > 0 {
            ctx.request_repaint();
        }
        // A notice fades out over its last second: frames until it has gone.
        if let Some(life) = self.options.notice_lifetime
            && let Some(m) = self.messages.iter().find(|m| !m.is_error)
        {
            let left = life.saturating_sub(m.said.elapsed());
            ctx.request_repaint_after(left.min(NOTICE_FADE / 10));
        }
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let now = Instant::now();
        if !self.first_frame_logged {
            self.first_frame_logged = true;
            if self.options.log_frame_times {
                eprintln!(
                    "studio: first frame after {:.2} s",
                    self.options.started.elapsed().as_secs_f32()
                );
            }
        }
        if !self.jobs.running.is_empty() {
            for j in &self.jobs.running {
                self.frames.busy_jobs.insert(j.name.clone());
            }
            if let Some(last) = self.frames.last {
                self.frames
                    .busy_intervals_ms
                    .push(now.duration_since(last).as_secs_f32() * 1000.0);
            }
            self.frames.last = Some(now);
            // A running figure every 10 s, so a long job can be measured without
            // waiting for its end.
            let since = *self.frames.last_report.get_or_insert(now);
            let due = now.duration_since(since).as_secs_f32() >= 10.0;
            if self.options.log_frame_times && due {
                if let Some((n, med, p95, max)) = self.frames.stats() {
                    let progress: Vec<String> = self
                        .jobs
                        .running
                        .iter()
                        .map(|h| match h.progress() {
                            Some(p) => format!("{}: {} {}/{}", h.name, p.stage, p.done, p.total),
                            None => h.name.clone(),
                        })
                        .collect();
                    eprintln!(
                        "frame times so far while jobs run ({}): {n} frames, median {med:.1} ms, p95 {p95:.1} ms, max {max:.1} ms; the app's own drawing median {:.1} ms",
                        progress.join("; "),
                        self.frames.app_median_ms().unwrap_or(0.0)
                    );
                }
                self.frames.last_report = Some(now);
            }
        } else {
            if self.options.log_frame_times && !self.frames.busy_intervals_ms.is_empty() {
                if let Some((n, med, p95, max)) = self.frames.stats() {
                    eprintln!(
                        "frame times while jobs ran ({}): {n} frames, median {med:.1} ms, p95 {p95:.1} ms, max {max:.1} ms; the app's own drawing median {:.1} ms",
                        self.frames
                            .busy_jobs
                            .iter()
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", "),
                        self.frames.app_median_ms().unwrap_or(0.0)
                    );
                }
                self.frames.busy_intervals_ms.clear();
                self.frames.busy_app_ms.clear();
                self.frames.busy_jobs.clear();
            }
            self.frames.last = None;
            self.frames.last_report = None;
        }
        let busy = !self.jobs.running.is_empty();
        ui::root_ui(self, ui);
        self.frames
            .record_app_time(busy, now.elapsed().as_secs_f32() * 1000.0);
        if !self.jobs.running.is_empty() {
            // The progress line moves a few times a second; results wake the window
            // at once. Repainting every frame would take a core from the jobs (all of
            // one under a software rasteriser).
            ui.ctx().request_repaint_after(PROGRESS_REPAINT);
        }
    }

    fn on_exit(&mut self) {
        if let Some(s) = self.session()
            && let Err(e) = s.save()
        {
            eprintln!("lensblur: {e}");
        }
    }
}

/// Opens the studio window.
///
/// # Errors
/// The window or its renderer could not be created.
pub fn run(options: AppOptions) -> Result<(), String> {
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("lensblur studio")
            .with_inner_size([1400.0, 900.0])
            .with_drag_and_drop(true),
        renderer: eframe::Renderer::Wgpu,
        ..Default::default()
    };
    eframe::run_native(
        "lensblur studio",
        native,
        Box::new(move |cc| {
            // The preview deblurs on the device the window draws with, not a second one.
            if let Some(rs) = &cc.wgpu_render_state {
                let _ = crate::deblur::gpu::lend(
                    rs.device.clone(),
                    rs.queue.clone(),
                    &rs.adapter.get_info(),
                );
            }
            Ok(Box::new(StudioApp::new(&cc.egui_ctx, options)))
        }),
    )
    .map_err(|e| format!("cannot open the studio window: {e}"))
}
