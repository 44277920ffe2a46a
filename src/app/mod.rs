//! The studio: one window over the headless core (DESIGN.md §4).
//!
//! Split as `logic` (apply [`Command`]s, drain finished jobs, keep the session saved) and
//! `ui` (draw; every drawing function ends in `_ui` and only emits commands). Every
//! computation is a call into the core on a job thread; the app only shows and drives.

pub mod jobs;
mod logic;
mod ui;

use crate::detect::Detection;
use crate::job::JobContext;
use crate::plane::{Capture, Channel};
use crate::session::{DemoSpec, Session};
use jobs::Jobs;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

/// The studio's views (DESIGN.md §4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    Shot,
    KernelField,
    Sweeps,
    Models,
    Deblur,
}

impl View {
    pub const ALL: [View; 5] = [
        View::Shot,
        View::KernelField,
        View::Sweeps,
        View::Models,
        View::Deblur,
    ];

    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            View::Shot => "Shot",
            View::KernelField => "Kernel field",
            View::Sweeps => "Sweeps",
            View::Models => "Models",
            View::Deblur => "Deblur",
        }
    }
}

/// Everything a panel can ask for; applied by `logic` after the frame is drawn.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    SelectView(View),
    SelectShot(usize),
    SelectChannel(Channel),
    /// A chart square in the Shot view: (row, col).
    SelectSquare((usize, usize)),
    ClearSquare,
    /// Opens the file dialog for shots.
    AddShotsDialog,
    AddShots(Vec<PathBuf>),
    RemoveShot(usize),
    SetShotSetting {
        index: usize,
        focal_mm: Option<f64>,
        f_number: Option<f64>,
    },
    /// Detection on one shot, or on every shot without a result.
    RunDetect(Option<usize>),
    RunKernels(Option<usize>),
    RunCalibrate,
    OpenPhotoDialog,
    OpenPhoto(PathBuf),
    LoadProfileDialog,
    /// Load a second profile to show beside the first (two lens units).
    LoadCompareProfileDialog,
    LoadProfile {
        path: PathBuf,
        compare: bool,
    },
    SaveProfileDialog,
    SetFieldSource(FieldSource),
    OpenSessionDialog,
    Cancel(u64),
    CancelAll,
    SetDark(bool),
    DismissMessage(usize),
}

/// What jobs hand back.
pub enum JobOutput {
    DemoReady(Session),
    ShotLoaded {
        index: usize,
        capture: Arc<Capture>,
    },
    PhotoLoaded {
        path: PathBuf,
        capture: Arc<Capture>,
    },
    /// A shot's kernels finished (or failed).
    KernelsMeasured {
        index: usize,
        result: Result<(Vec<MeasuredSample>, usize), String>,
    },
    /// Calibration finished: the measurements it used, the profile and the
    /// cross-validation report (absent when α, β were fixed).
    Calibrated {
        dataset: Arc<crate::model::Dataset>,
        profile: Arc<crate::profile::Profile>,
        cv: Option<Arc<crate::crossval::CvReport>>,
        path: PathBuf,
    },
    ProfileLoaded {
        profile: Arc<crate::profile::Profile>,
        path: PathBuf,
        compare: bool,
    },
    /// A shot's detection finished (or failed: `Err` carries the one-line reason).
    Detected {
        index: usize,
        result: Result<Arc<Detection>, String>,
    },
}

/// How the app starts.
#[derive(Clone, Debug)]
pub struct AppOptions {
    /// A session folder or manifest; `None` opens the demo session.
    pub session: Option<PathBuf>,
    /// Where the demo session is cached.
    pub demo_dir: PathBuf,
    pub demo_spec: DemoSpec,
    /// Write the first-frame time, readiness and frame-time statistics to stderr
    /// (`LENSBLUR_FRAME_LOG=1`; what scripts/xvfb_screenshot.sh reads).
    pub log_frame_times: bool,
    /// Stages to run by themselves once the session's shots are loaded, e.g.
    /// `LENSBLUR_AUTORUN=detect,kernels` (for measuring frame times under load).
    pub autorun: Vec<String>,
    /// When the process started, for the first-frame time.
    pub started: Instant,
}

impl Default for AppOptions {
    fn default() -> Self {
        Self {
            session: None,
            demo_dir: crate::session::default_demo_dir(),
            demo_spec: DemoSpec::studio(),
            log_frame_times: std::env::var_os("LENSBLUR_FRAME_LOG").is_some(),
            autorun: std::env::var("LENSBLUR_AUTORUN")
                .map(|v| {
                    v.split(',')
                        .map(|s| s.trim().to_owned())
                        .filter(|s| !s.is_empty())
                        .collect()
                })
                .unwrap_or_default(),
            started: Instant::now(),
        }
    }
}

/// A message shown in the status area: errors name the file and the reason.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    pub is_error: bool,
    pub text: String,
}

/// One measured kernel's fit at its square centre (sensor px).
#[derive(Clone, Debug)]
pub struct MeasuredSample {
    pub x: f64,
    pub y: f64,
    pub channel: Channel,
    pub gaussian: crate::psf::Gaussian2,
    pub kernel: Option<crate::psf::Kernel>,
}

/// Where the Kernel field view's ellipses come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldSource {
    /// Measured on the selected shot.
    Measured,
    /// Predicted by the profile at the sliders' setting.
    Predicted,
    /// The demo lens's exact blur (demo sessions only).
    Truth,
}

/// The inspector's square: which one, its crops and their textures (observed,
/// synthetic, residual).
pub struct Inspection {
    pub shot: usize,
    pub square: (usize, usize),
    pub channel: Channel,
    pub crops: crate::detect::inspect::SquareInspection,
    pub textures: [egui::TextureHandle; 3],
}

/// A loaded shot and its display textures per channel.
pub struct ShotPreview {
    pub capture: Arc<Capture>,
    pub textures: BTreeMap<Channel, egui::TextureHandle>,
    pub thumbnail: Option<egui::TextureHandle>,
}

/// Zoom and pan of the shot viewer: sensor pixel per screen point and the sensor point
/// at the viewer's centre.
#[derive(Clone, Copy, Debug)]
pub struct ViewerState {
    pub sensor_px_per_point: Option<f32>,
    pub centre_sensor: [f32; 2],
}

/// Frame intervals while jobs run, to show the UI stays responsive.
#[derive(Default)]
pub struct FrameLog {
    last: Option<Instant>,
    pub busy_intervals_ms: Vec<f32>,
    /// Names of the jobs that ran while these frames were drawn.
    pub busy_jobs: std::collections::BTreeSet<String>,
}

impl FrameLog {
    /// (count, median, 95th percentile, max) of frame intervals in ms while jobs ran.
    #[must_use]
    pub fn stats(&self) -> Option<(usize, f32, f32, f32)> {
        if self.busy_intervals_ms.is_empty() {
            return None;
        }
        let mut v = self.busy_intervals_ms.clone();
        v.sort_by(f32::total_cmp);
        let q = |p: f32| v[((v.len() - 1) as f32 * p).round() as usize];
        Some((v.len(), q(0.5), q(0.95), v[v.len() - 1]))
    }
}

/// The studio app.
pub struct StudioApp {
    pub session: Option<Session>,
    pub jobs: Jobs<JobOutput>,
    pub view: View,
    pub selected_shot: Option<usize>,
    pub channel: Channel,
    pub previews: BTreeMap<usize, ShotPreview>,
    pub messages: Vec<Message>,
    pub commands: Vec<Command>,
    pub viewer: ViewerState,
    /// Setting for the predicted / ground-truth field.
    pub field_focal_mm: f64,
    pub field_f_number: f64,
    pub compare_units: bool,
    pub show_ellipses: bool,
    pub photo: Option<(PathBuf, Arc<Capture>, Option<egui::TextureHandle>)>,
    /// Detection per shot index, this run's or read back from the session's results.
    pub detections: BTreeMap<usize, Arc<Detection>>,
    /// The square clicked in the Shot view: (row, col).
    pub selected_square: Option<(usize, usize)>,
    /// Measured robust Gaussians per shot index (all channels).
    pub measured: BTreeMap<usize, Vec<MeasuredSample>>,
    /// The session's measured Gaussians, as calibration used them.
    pub dataset: Option<Arc<crate::model::Dataset>>,
    /// The lens profile in use (calibrated here or loaded) and a second one to compare.
    pub profile: Option<(PathBuf, Arc<crate::profile::Profile>)>,
    pub compare_profile: Option<(PathBuf, Arc<crate::profile::Profile>)>,
    pub cv: Option<Arc<crate::crossval::CvReport>>,
    /// What the Kernel field view shows.
    pub field_source: FieldSource,
    /// Crops of the clicked square for the inspector.
    pub inspection: Option<Inspection>,
    pub dark: bool,
    pub frames: FrameLog,
    pub options: AppOptions,
    pub ctx: egui::Context,
    /// Shot indices whose loading has been started.
    loading: std::collections::BTreeSet<usize>,
    first_frame_logged: bool,
    ready_logged: bool,
}

impl StudioApp {
    /// Builds the app and starts whatever the first frame needs (opening the session, or
    /// making the demo session in the background).
    #[must_use]
    pub fn new(ctx: &egui::Context, options: AppOptions) -> Self {
        let wake_ctx = ctx.clone();
        let mut app = Self {
            session: None,
            jobs: Jobs::new(move || wake_ctx.request_repaint()),
            view: View::Shot,
            selected_shot: None,
            channel: Channel::G,
            previews: BTreeMap::new(),
            messages: Vec::new(),
            commands: Vec::new(),
            viewer: ViewerState {
                sensor_px_per_point: None,
                centre_sensor: [0.0, 0.0],
            },
            field_focal_mm: 50.0,
            field_f_number: 5.6,
            compare_units: false,
            show_ellipses: true,
            photo: None,
            detections: BTreeMap::new(),
            selected_square: None,
            inspection: None,
            measured: BTreeMap::new(),
            dataset: None,
            profile: None,
            compare_profile: None,
            cv: None,
            field_source: FieldSource::Measured,
            dark: true,
            frames: FrameLog::default(),
            options: options.clone(),
            ctx: ctx.clone(),
            loading: std::collections::BTreeSet::new(),
            first_frame_logged: false,
            ready_logged: false,
        };
        ctx.set_theme(egui::Theme::Dark);
        match &options.session {
            Some(path) => match Session::open(path) {
                Ok(s) => app.set_session(s),
                Err(e) => app.error(e.to_string()),
            },
            None => app.open_or_make_demo(),
        }
        app
    }

    pub fn error(&mut self, text: impl Into<String>) {
        let text = self.shorten_paths(text.into());
        self.messages.push(Message {
            is_error: true,
            text,
        });
    }

    pub fn info(&mut self, text: impl Into<String>) {
        let text = self.shorten_paths(text.into());
        self.messages.push(Message {
            is_error: false,
            text,
        });
    }

    /// A path as the UI shows it: relative to the session folder when it lies inside,
    /// `~/…` under the home folder, absolute otherwise. Where the session lives is one
    /// hover away (the session name's tooltip); repeating it in every line would crowd
    /// the window and tie what it shows to where the folder happens to be.
    #[must_use]
    pub fn shown_path(&self, path: &std::path::Path) -> String {
        if let Some(s) = &self.session {
            if let Ok(rel) = path.strip_prefix(s.folder()) {
                if !rel.as_os_str().is_empty() {
                    return rel.display().to_string();
                }
            }
        }
        if let Some(home) = std::env::var_os("HOME").map(PathBuf::from) {
            if let Ok(rel) = path.strip_prefix(&home) {
                return format!("~/{}", rel.display());
            }
        }
        path.display().to_string()
    }

    /// Messages from the core name files by their full paths; inside the session folder
    /// the relative name says the same in less space.
    fn shorten_paths(&self, text: String) -> String {
        match &self.session {
            Some(s) if !s.folder().as_os_str().is_empty() => {
                let prefix = format!("{}{}", s.folder().display(), std::path::MAIN_SEPARATOR);
                text.replace(&prefix, "")
            }
            _ => text,
        }
    }

    fn open_or_make_demo(&mut self) {
        let dir = self.options.demo_dir.clone();
        if dir.join(crate::session::SESSION_FILE).is_file() {
            match Session::open(&dir) {
                Ok(s) if s.is_demo && s.shots.len() == self.options.demo_spec.settings.len() => {
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
            .spawn("demo session", move |ctx: &JobContext, out| {
                let s = crate::session::make_demo(&dir, &spec, ctx).map_err(|e| e.to_string())?;
                out.emit(JobOutput::DemoReady(s));
                Ok(())
            });
        if let Err(e) = started {
            self.error(e);
        }
    }

    pub(crate) fn set_session(&mut self, s: Session) {
        self.previews.clear();
        self.loading.clear();
        self.detections = logic::read_detections(&s);
        self.measured = logic::read_measured(&s);
        self.dataset = None;
        self.cv = None;
        self.profile = None;
        if let Some(p) = &s.profile {
            let path = if p.is_absolute() {
                p.clone()
            } else {
                s.folder().join(p)
            };
            if path.is_file() {
                self.commands.push(Command::LoadProfile {
                    path,
                    compare: false,
                });
            }
        }
        self.selected_square = None;
        self.selected_shot = if s.shots.is_empty() { None } else { Some(0) };
        self.viewer.sensor_px_per_point = None;
        self.session = Some(s);
    }

    /// Runs one frame's logic without drawing (also what tests call between steps).
    pub fn logic_step(&mut self) {
        logic::drain_jobs(self);
        let commands = std::mem::take(&mut self.commands);
        for c in commands {
            logic::apply(self, c);
        }
        logic::ensure_preview(self);
        let ready = self
            .session
            .as_ref()
            .is_some_and(|s| self.previews.len() == s.shots.len());
        if ready && !self.ready_logged {
            self.ready_logged = true;
            if self.options.log_frame_times {
                let n = self.session.as_ref().map_or(0, |s| s.shots.len());
                eprintln!(
                    "studio: ready: {n} shots loaded after {:.2} s",
                    self.options.started.elapsed().as_secs_f32()
                );
            }
        }
        // Autorun stages one after another: each starts once the previous job ended.
        if self.ready_logged && self.jobs.running.is_empty() && !self.options.autorun.is_empty() {
            let stage = self.options.autorun.remove(0);
            match stage.as_str() {
                "detect" => self.commands.push(Command::RunDetect(None)),
                "kernels" => self.commands.push(Command::RunKernels(None)),
                "calibrate" => self.commands.push(Command::RunCalibrate),
                other => self.error(format!("LENSBLUR_AUTORUN: unknown stage '{other}'")),
            }
        }
    }
}

impl eframe::App for StudioApp {
    fn logic(&mut self, _ctx: &egui::Context, _frame: &mut eframe::Frame) {
        self.logic_step();
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
        } else {
            if self.options.log_frame_times && !self.frames.busy_intervals_ms.is_empty() {
                if let Some((n, med, p95, max)) = self.frames.stats() {
                    eprintln!(
                        "frame times while jobs ran ({}): {n} frames, median {med:.1} ms, p95 {p95:.1} ms, max {max:.1} ms",
                        self.frames
                            .busy_jobs
                            .iter()
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", ")
                    );
                }
                self.frames.busy_intervals_ms.clear();
                self.frames.busy_jobs.clear();
            }
            self.frames.last = None;
        }
        ui::root_ui(self, ui);
        if !self.jobs.running.is_empty() {
            // Keep the progress bar moving; also what the frame-time figure measures.
            ui.ctx().request_repaint();
        }
    }

    fn on_exit(&mut self) {
        if let Some(s) = &self.session {
            if let Err(e) = s.save() {
                eprintln!("lensblur: {e}");
            }
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
        Box::new(move |cc| Ok(Box::new(StudioApp::new(&cc.egui_ctx, options)))),
    )
    .map_err(|e| format!("cannot open the studio window: {e}"))
}
