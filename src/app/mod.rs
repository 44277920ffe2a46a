//! The studio: one window over the headless core (ARCHITECTURE.md, Studio).
//!
//! `StudioApp` is plumbing: the core's `Project` (the session and every result made of
//! it), the jobs, the command queue, each view's own state (`state::Views`) and the
//! view data. Split as `state` (the types of what the app holds, importing nothing of
//! the app), `command` (what panels ask for and what jobs hand back), `logic` (apply
//! [`Command`]s, drain finished jobs, keep the session saved), `view_data` (what the
//! views show that takes computing: made when its inputs change, cached keyed by them,
//! long work on a job thread), `textures` (images made into textures, for both `logic`
//! and `view_data`) and `ui` (draw; every drawing function ends in `_ui`, only reads
//! and emits commands, and shows a placeholder where view data is absent). Every
//! computation is a call into the core; the app only shows and drives.

mod command;
pub mod jobs;
mod logic;
mod state;
mod textures;
mod ui;
pub mod view_data;

pub use command::{
    Command, DeblurCommand, DeblurOutput, DialogCommand, GeometryCommand, GeometryOutput,
    JobOutput, PlotCommand, SessionCommand, SessionOutput, ShotOutput, StageCommand, StageOutput,
    ViewCommand, WindowCommand,
};
pub(crate) use state::Tally;
pub use state::{
    AppOptions, Autorun, ColourRange, ComparisonView, Confirm, DeblurLayout, DeblurResult,
    DeblurState, DeblurZoom, Difference, FieldOptions, FieldShow, FieldSource, FieldViewState,
    FrameLog, GeometryViewState, Message, PendingPlotPng, Photo, PlotId, PreviewScope,
    SessionPanelState, SharpnessChoice, ShotPreview, ShotView, ShotViewState, SweepAxis,
    SweepsViewState, Trace, View, ViewerContext, ViewerState, Views, Window, clock_now,
};

use crate::crossval::CvReport;
use crate::detect::Detection;
use crate::kernel::file::KernelsFile;
use crate::model::Dataset;
use crate::profile::Profile;
use crate::project::Project;
use crate::session::{Session, ShotId};
use jobs::Jobs;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// How long a notice takes to fade out of the status line, at the end of its lifetime.
const NOTICE_FADE: std::time::Duration = std::time::Duration::from_secs(1);

/// How often the window repaints while only a job's progress changes: under a software
/// rasteriser a frame costs about as much CPU as a job gets between two quick frames,
/// so faster progress would take the cores from the jobs it shows (the measurements
/// are in docs/performance.md).
const PROGRESS_REPAINT: std::time::Duration = std::time::Duration::from_millis(1000);
/// How soon a job's result reaches the screen while the user works the window: results
/// that arrive together (a shot's detection, its kernels, its thumbnail) share one
/// frame, each costing about 0.2 s of CPU under a software rasteriser.
const RESULT_REPAINT: std::time::Duration = std::time::Duration::from_millis(250);
/// How long after the user's last input the window still counts as watched closely.
const ATTENDED: std::time::Duration = std::time::Duration::from_secs(3);

/// When the user last touched the window, shared with the job threads' wakes: a result
/// that arrives while the user works the window is drawn within [`RESULT_REPAINT`]; the
/// results that stream in while nobody touches it (the demo's shots as they are made,
/// every shot's detection and kernels in *Calibrate all*) share the progress line's
/// frame a second: drawn one by one under a software rasteriser, they take the cores the
/// jobs need. A job's end still wakes the window within [`RESULT_REPAINT`]: what follows
/// it (the next stage, the before/after) starts then.
#[derive(Clone)]
struct Attention {
    start: Instant,
    /// Milliseconds from `start` to the last input.
    last_input_ms: Arc<std::sync::atomic::AtomicU64>,
}

impl Attention {
    fn new() -> Self {
        Self {
            start: Instant::now(),
            last_input_ms: Arc::new(std::sync::atomic::AtomicU64::new(0)),
        }
    }

    fn touched(&self) {
        let ms = u64::try_from(self.start.elapsed().as_millis()).unwrap_or(u64::MAX);
        self.last_input_ms
            .store(ms, std::sync::atomic::Ordering::Relaxed);
    }

    /// How soon a result handed over now should be drawn.
    fn result_delay(&self) -> std::time::Duration {
        let last = std::time::Duration::from_millis(
            self.last_input_ms
                .load(std::sync::atomic::Ordering::Relaxed),
        );
        if self.start.elapsed().saturating_sub(last) < ATTENDED {
            RESULT_REPAINT
        } else {
            PROGRESS_REPAINT
        }
    }
}

/// The studio app: plumbing only. The project owns the session and its results, each
/// view its own state (`views`), `data` what the views show that takes computing; the
/// app holds them, the jobs and the command queue, and applies commands between frames.
pub struct StudioApp {
    /// The open calibration project: the session, its folder's lock, each shot's
    /// record (file, settings, status, detection, kernels) and the results made of them
    /// (dataset, profile, cross-validation).
    project: Option<Project>,
    jobs: Jobs<JobOutput>,
    /// Per running detect or kernels job (by id): how its shots went so far.
    tallies: BTreeMap<u64, Tally>,
    /// Counts the sessions opened: results of jobs started for an earlier one are
    /// dropped when they arrive.
    session_generation: u64,
    /// The session's shots as the window has them: loading, loaded, or unreadable (a
    /// shot has an entry once its loading has started).
    shots: BTreeMap<ShotId, ShotView>,
    commands: Vec<Command>,
    /// The view shown.
    view: View,
    /// Each view's own state: what it shows and how.
    views: Views,
    /// What the views show that takes computing, cached by what it depends on.
    data: view_data::ViewData,
    /// The window around the views: messages, log, dialogs shown, theme.
    window: Window,
    dialogs: logic::Dialogs,
    trace: Trace,
    autorun: Autorun,
    options: AppOptions,
    attention: Attention,
    ctx: egui::Context,
}

impl StudioApp {
    /// Builds the app and starts whatever the first frame needs (opening the session, or
    /// making the demo session in the background).
    #[must_use]
    pub fn new(ctx: &egui::Context, options: AppOptions) -> Self {
        let wake_ctx = ctx.clone();
        let output_ctx = ctx.clone();
        let progress_ctx = ctx.clone();
        let attention = Attention::new();
        let watched = attention.clone();
        let recent = options
            .recent_file
            .as_deref()
            .map(crate::recent::read_recent)
            .unwrap_or_default();
        let mut app = Self {
            project: None,
            jobs: Jobs::new(options.job_threads, move || {
                wake_ctx.request_repaint_after(RESULT_REPAINT);
            })
            .with_output_wake(move || output_ctx.request_repaint_after(watched.result_delay()))
            .with_progress_wake(move || progress_ctx.request_repaint_after(PROGRESS_REPAINT)),
            tallies: BTreeMap::new(),
            session_generation: 0,
            shots: BTreeMap::new(),
            commands: Vec::new(),
            view: View::Shot,
            views: Views::default(),
            data: view_data::ViewData::default(),
            window: Window::new(recent),
            dialogs: logic::Dialogs::new(),
            trace: Trace::default(),
            autorun: Autorun::default(),
            options: options.clone(),
            attention,
            ctx: ctx.clone(),
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

    /// The jobs running.
    #[must_use]
    pub fn jobs(&self) -> &Jobs<JobOutput> {
        &self.jobs
    }

    /// The view shown.
    #[must_use]
    pub fn view(&self) -> View {
        self.view
    }

    /// Each view's own state.
    #[must_use]
    pub fn views(&self) -> &Views {
        &self.views
    }

    /// What the views show that takes computing.
    #[must_use]
    pub fn data(&self) -> &view_data::ViewData {
        &self.data
    }

    /// The window around the views: messages, log, dialogs shown, theme.
    #[must_use]
    pub fn window(&self) -> &Window {
        &self.window
    }

    /// The window, to change what it shows directly (a snapshot fixes its log's times).
    pub fn window_mut(&mut self) -> &mut Window {
        &mut self.window
    }

    /// Queues a command: applied at the next logic step, as a panel's are.
    pub fn push(&mut self, command: impl Into<Command>) {
        self.commands.push(command.into());
    }

    /// What the views may read: the project and the loaded shots, borrowed.
    #[must_use]
    pub fn viewer(&self) -> ViewerContext<'_> {
        ViewerContext {
            project: self.project.as_ref(),
            shots: &self.shots,
        }
    }

    /// What a frame draws from, borrowed for the frame.
    fn frame(&self) -> ui::Frame<'_> {
        ui::Frame {
            cx: self.viewer(),
            view: self.view,
            views: &self.views,
            data: &self.data,
            window: &self.window,
            jobs: &self.jobs,
            notice_lifetime: self.options.notice_lifetime,
            profile_library: &self.options.profile_library,
            deblur_method: logic::deblur_method(self),
            sensor: view_data::sensor_size(self),
            setting_ranges: view_data::setting_ranges(self, &crate::simulate::VirtualLens::demo()),
        }
    }

    /// The open session.
    #[must_use]
    pub fn session(&self) -> Option<&Session> {
        self.viewer().session()
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
        self.viewer().dataset()
    }

    /// The lens profile in use (calibrated here or loaded) and where it lies.
    #[must_use]
    pub fn profile(&self) -> Option<&(PathBuf, Arc<Profile>)> {
        self.viewer().profile()
    }

    /// The profile library the studio saves into: the folder a batch reads.
    #[must_use]
    pub fn profile_library(&self) -> &Path {
        &self.options.profile_library
    }

    /// A second profile shown beside the first (another unit of the lens).
    #[must_use]
    pub fn compare_profile(&self) -> Option<&(PathBuf, Arc<Profile>)> {
        self.viewer().compare_profile()
    }

    /// The cross-validation report of the profile's fit.
    #[must_use]
    pub fn cv(&self) -> Option<&Arc<CvReport>> {
        self.viewer().cv()
    }

    /// The shot's detection, this run's or read back from the session's results.
    #[must_use]
    pub fn detection(&self, id: ShotId) -> Option<&Arc<Detection>> {
        self.viewer().detection(id)
    }

    /// The shot's measured kernels and their Gaussians (all channels).
    #[must_use]
    pub fn kernels(&self, id: ShotId) -> Option<&Arc<KernelsFile>> {
        self.viewer().kernels(id)
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
        self.viewer().preview(id)
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
        self.viewer().unreadable(id)
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
        self.window.log.push(m.clone());
        self.window.messages.push(m);
    }

    /// A path as the UI shows it ([`ViewerContext::shown_path`]).
    #[must_use]
    pub fn shown_path(&self, path: &Path) -> String {
        self.viewer().shown_path(path)
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
        logic::follow_up(self);
        view_data::refresh(self);
        logic::autorun_step(self);
        logic::expire_notices(self);
    }
}

impl eframe::App for StudioApp {
    /// The panels' own colour: the panels then paint no background of their own (see
    /// `Window::cleared_to_panel_fill`).
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn logic(&mut self, ctx: &egui::Context, _frame: &mut eframe::Frame) {
        if ctx.input(|i| !i.events.is_empty()) {
            self.attention.touched();
        }
        self.logic_step();
        if self.autorun.drag_frames > 0 {
            ctx.request_repaint();
        }
        // A notice fades out over its last second: one wake when the fade starts, then
        // four frames until it has gone, not a frame every few milliseconds of its life
        // (each costs a software rasteriser a fifth of a second of CPU).
        if let Some(life) = self.options.notice_lifetime
            && let Some(m) = self.window.messages.iter().find(|m| !m.is_error)
        {
            let left = life.saturating_sub(m.said.elapsed());
            let until_fade = left.saturating_sub(NOTICE_FADE);
            ctx.request_repaint_after(if until_fade.is_zero() {
                left.min(NOTICE_FADE / 4)
            } else {
                until_fade
            });
        }
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let now = Instant::now();
        if !self.trace.first_frame_logged {
            self.trace.first_frame_logged = true;
            if self.options.log_frame_times {
                eprintln!(
                    "studio: first frame after {:.2} s",
                    self.options.started.elapsed().as_secs_f32()
                );
            }
        }
        if !self.jobs.running.is_empty() {
            for j in &self.jobs.running {
                self.trace.frames.busy_jobs.insert(j.kind.name().to_owned());
            }
            if let Some(last) = self.trace.frames.last {
                self.trace
                    .frames
                    .busy_intervals_ms
                    .push(now.duration_since(last).as_secs_f32() * 1000.0);
            }
            self.trace.frames.last = Some(now);
            // A running figure every 10 s, so a long job can be measured without
            // waiting for its end.
            let since = *self.trace.frames.last_report.get_or_insert(now);
            let due = now.duration_since(since).as_secs_f32() >= 10.0;
            if self.options.log_frame_times && due {
                if let Some((n, med, p95, max)) = self.trace.frames.stats() {
                    let progress: Vec<String> = self
                        .jobs
                        .running
                        .iter()
                        .map(|h| match h.progress() {
                            Some(p) => format!("{}: {} {}/{}", h.kind, p.stage, p.done, p.total),
                            None => h.kind.name().to_owned(),
                        })
                        .collect();
                    eprintln!(
                        "frame times so far while jobs run ({}): {n} frames, median {med:.1} ms, p95 {p95:.1} ms, max {max:.1} ms; the app's own drawing median {:.1} ms",
                        progress.join("; "),
                        self.trace.frames.app_median_ms().unwrap_or(0.0)
                    );
                }
                self.trace.frames.last_report = Some(now);
            }
        } else {
            if self.options.log_frame_times && !self.trace.frames.busy_intervals_ms.is_empty() {
                if let Some((n, med, p95, max)) = self.trace.frames.stats() {
                    eprintln!(
                        "frame times while jobs ran ({}): {n} frames, median {med:.1} ms, p95 {p95:.1} ms, max {max:.1} ms; the app's own drawing median {:.1} ms",
                        self.trace
                            .frames
                            .busy_jobs
                            .iter()
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", "),
                        self.trace.frames.app_median_ms().unwrap_or(0.0)
                    );
                }
                self.trace.frames.busy_intervals_ms.clear();
                self.trace.frames.busy_app_ms.clear();
                self.trace.frames.busy_jobs.clear();
            }
            self.trace.frames.last = None;
            self.trace.frames.last_report = None;
        }
        let busy = !self.jobs.running.is_empty();
        // Draw code only reads; what it asks for is queued, applied after the frame.
        let mut out = std::mem::take(&mut self.commands);
        ui::root_ui(&self.frame(), &mut out, ui);
        self.commands = out;
        self.trace
            .frames
            .record_app_time(busy, now.elapsed().as_secs_f32() * 1000.0);
        if !self.jobs.running.is_empty() {
            // The progress line moves once a second; results wake the window at once.
            // Under a software rasteriser a frame of the studio costs about 0.2 s of
            // CPU: at four a second the window took more CPU than the jobs it showed.
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
            let mut app = StudioApp::new(&cc.egui_ctx, options);
            app.window.cleared_to_panel_fill = true;
            Ok(Box::new(app))
        }),
    )
    .map_err(|e| format!("cannot open the studio window: {e}"))
}
