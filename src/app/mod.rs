//! The studio: one window over the headless core (DESIGN.md §4).
//!
//! Split as `logic` (apply [`Command`]s, drain finished jobs, keep the session saved),
//! `view_data` (what the views show that takes computing: made when its inputs change,
//! cached keyed by them, long work on a job thread) and `ui` (draw; every drawing
//! function ends in `_ui`, only reads the app and emits commands, and shows a
//! placeholder where view data is absent). Every computation is a call into the core;
//! the app only shows and drives.

pub mod jobs;
mod logic;
mod ui;
pub mod view_data;

use crate::chart::ChartSpec;
use crate::crossval::CvReport;
use crate::detect::Detection;
use crate::develop::Developed;
use crate::job::JobContext;
use crate::kernel::file::KernelsFile;
use crate::model::Dataset;
use crate::plane::{Capture, Channel};
use crate::profile::Profile;
use crate::review::DeblurComparison;
use crate::session::{DemoSpec, Session, ShotId, StageSettings};
use jobs::Jobs;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
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

/// Which deblurred result a slider compares with the original, or an export writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeblurResult {
    /// With the Gaussians the profile predicts at the photo's setting.
    Predicted,
    /// With the non-parametric kernels measured on the session's shot at that setting.
    Measured,
}

impl DeblurResult {
    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            DeblurResult::Predicted => "predicted Gaussians",
            DeblurResult::Measured => "measured kernels",
        }
    }
}

/// How the Deblur view lays out its crops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeblurLayout {
    SideBySide,
    /// One crop, original left of a movable divider and a result right of it.
    Slider,
}

/// Everything a panel can ask for; applied by `logic` after the frame is drawn.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    SelectView(View),
    SelectShot(ShotId),
    SelectChannel(Channel),
    /// A chart square in the Shot view: (row, col).
    SelectSquare((usize, usize)),
    ClearSquare,
    /// Opens the file dialog for shots.
    AddShotsDialog,
    AddShots(Vec<PathBuf>),
    RemoveShot(ShotId),
    SetShotSetting {
        shot: ShotId,
        focal_mm: Option<f64>,
        f_number: Option<f64>,
    },
    /// The chart and the stage settings; results they make stale are reset.
    ApplySettings {
        chart: ChartSpec,
        settings: StageSettings,
    },
    /// Reads a chart spec file into the settings being edited.
    LoadChartDialog,
    /// Detection on one shot, or on every shot without a result.
    RunDetect(Option<ShotId>),
    RunKernels(Option<ShotId>),
    RunCalibrate,
    OpenPhotoDialog,
    OpenPhoto(PathBuf),
    SetPhotoSetting {
        focal_mm: Option<f64>,
        f_number: Option<f64>,
    },
    /// Deblur a crop around this sensor point with both kernel sources.
    DeblurAt([f64; 2]),
    SetDeblurLayout(DeblurLayout),
    /// The compared panes' magnification; the region follows the panes' size.
    SetDeblurZoom(DeblurZoom),
    /// The region (sensor px) the panes show at their zoom, as laid out this frame.
    SetDeblurViewport([usize; 2]),
    /// The region's side at Fit.
    SetDeblurCrop(usize),
    /// The view's own method and strength, applied live to the region.
    SetDeblurMethod(crate::deblur::Method),
    SetDeblurDevice(crate::deblur::Device),
    /// Drag of the compared panes in progress (sensor px), drawn as a shift.
    DragDeblur([f32; 2]),
    /// The drag ended: the region moves by it and is deblurred there.
    EndDragDeblur,
    SetSliderResult(DeblurResult),
    ExportDeblurDialog(DeblurResult),
    ExportDeblur {
        path: PathBuf,
        result: DeblurResult,
    },
    /// Choose photos and a folder, then export them deblurred with the profile.
    ExportPhotosDialog {
        dng: bool,
    },
    /// Deblur a set of photos with the open profile into `out_dir`, as the command
    /// line's batch does: 16-bit TIFF, or with `dng` RAW photos as DNGs (others skipped).
    ExportPhotos {
        photos: Vec<PathBuf>,
        out_dir: PathBuf,
        dng: bool,
    },
    LoadProfileDialog,
    /// Load a second profile to show beside the first (two lens units).
    LoadCompareProfileDialog,
    LoadProfile {
        path: PathBuf,
        compare: bool,
    },
    SaveProfileDialog,
    SetFieldSource(FieldSource),
    SetFieldShow(FieldShow),
    SetSweepAxis(SweepAxis),
    /// Asks where to save a plot, as a PNG of it on screen or as CSV of its data.
    SavePlotDialog {
        plot: PlotId,
        png: bool,
    },
    SavePlotCsv {
        plot: PlotId,
        path: PathBuf,
    },
    /// Takes a screenshot and saves the plot's part of it once it arrives.
    SavePlotPng {
        plot: PlotId,
        path: PathBuf,
    },
    /// The setting of the predicted and true fields and of the sweeps (the sliders).
    SetFieldSetting {
        focal_mm: f64,
        f_number: f64,
    },
    /// Show the demo lens's second unit beside the first.
    SetCompareUnits(bool),
    /// The Kernel field view's colour range and difference map.
    SetFieldOptions(view_data::FieldOptions),
    OpenSessionDialog,
    /// Opens (or creates) the session in a folder, or from a session file or manifest.
    OpenSession(PathBuf),
    /// The shot viewer's zoom, pan and overlays, as the user moved them.
    SetViewer(ViewerState),
    /// The slider layout's divider, 0 (all result) to 1 (all original).
    SetSlider(f32),
    /// The chart and stage settings being edited (not yet applied); `None` reverts.
    EditSettings(Option<(ChartSpec, StageSettings)>),
    Cancel(u64),
    CancelAll,
    SetDark(bool),
    DismissMessage(usize),
    /// Reads a chart spec file into the settings being edited (the dialog's answer).
    LoadChart(PathBuf),
    /// Saves the profile in use to a file (the dialog's answer).
    SaveProfile(PathBuf),
    /// Asks the user before doing something that loses work.
    AskConfirm(Confirm),
    /// The answer to the question asked: do it, or not.
    ConfirmAnswer(bool),
    /// Shows or hides the log panel (every message of this run, timestamped).
    SetLogOpen(bool),
    ShowHelp(bool),
    ShowAbout(bool),
    /// Closes the window (the session is saved on the way out).
    Quit,
}

/// What the studio asks before doing it, because it cannot be undone from the window.
#[derive(Clone, Debug, PartialEq)]
pub enum Confirm {
    /// Remove a shot from the session (its file and cached results stay on disk).
    RemoveShot(ShotId),
    /// Apply a new chart: every detection and kernel measured with the old one is
    /// discarded from the session's view and must be measured again.
    ReplaceChart {
        chart: ChartSpec,
        settings: StageSettings,
    },
}

/// What jobs hand back.
pub enum JobOutput {
    /// The demo session so far, each time another of its shots is on disk.
    DemoShot(Box<Session>),
    DemoReady(Box<Session>),
    ShotLoaded {
        shot: ShotId,
        capture: Arc<Capture>,
        /// A RAW shot developed for display (or why not); `None` for RGB.
        developed: Option<Result<Developed, String>>,
    },
    /// A shot that cannot be read: the one-line reason names the file.
    ShotUnreadable {
        shot: ShotId,
        reason: String,
    },
    PhotoLoaded {
        path: PathBuf,
        capture: Arc<Capture>,
        developed: Option<Result<Developed, String>>,
    },
    /// A shot's kernels finished (or failed).
    KernelsMeasured {
        shot: ShotId,
        result: Result<Arc<KernelsFile>, String>,
    },
    /// The session's measured Gaussians, gathered from its kernels files.
    DatasetReady(Option<Arc<Dataset>>),
    /// Results a reopened session already has in its cache.
    ResultsRead {
        survey: crate::session::Survey,
        cv: Option<Arc<CvReport>>,
    },
    /// Calibration finished: the measurements it used, the profile and the
    /// cross-validation report (absent when α, β were fixed).
    Calibrated {
        dataset: Arc<Dataset>,
        profile: Arc<Profile>,
        cv: Option<Arc<CvReport>>,
        path: PathBuf,
    },
    ProfileLoaded {
        profile: Arc<Profile>,
        path: PathBuf,
        compare: bool,
    },
    /// A shot's detection finished (or failed: `Err` carries the one-line reason).
    Detected {
        shot: ShotId,
        result: Result<Arc<Detection>, String>,
    },
    /// Deblurred crops of the open photo; `measured_from` names the shot whose kernels
    /// were used.
    DeblurCompared {
        comparison: Arc<DeblurComparison>,
        measured_from: Option<String>,
    },
    DeblurExported(PathBuf),
    /// A set of photos exported: what became of each.
    PhotosExported(crate::batch::BatchReport),
    /// The crops of an inspected square (`None`: the square has none in that channel).
    SquareInspected {
        key: view_data::InspectKey,
        result: Option<Box<view_data::InspectedSquare>>,
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
    /// `LENSBLUR_AUTORUN=detect,kernels` (for measuring frame times under load);
    /// `deblur,drag-strength` opens LENSBLUR_PHOTO (else the first shot) in the Deblur
    /// view at 100 % and drags the strength control.
    pub autorun: Vec<String>,
    /// Threads jobs compute on; 0: every core but one, so the UI thread (and a software
    /// renderer) always has one.
    pub job_threads: usize,
    /// When the process started, for the first-frame time.
    pub started: Instant,
    /// The list of recently opened sessions (File ▸ Recent sessions); `None` keeps none.
    pub recent_file: Option<PathBuf>,
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
            job_threads: 0,
            started: Instant::now(),
            recent_file: Some(crate::session::default_recent_file()),
        }
    }
}

/// A message shown in the status area: errors name the file and the reason.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    pub is_error: bool,
    pub text: String,
    /// The local time it was said, `HH:MM:SS`, as the log panel shows it.
    pub time: String,
}

/// The wall clock as `HH:MM:SS`, local time where the system says which zone it is in.
#[must_use]
pub fn clock_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    #[cfg(unix)]
    {
        if let Ok(t) = libc::time_t::try_from(secs) {
            // SAFETY: localtime_r reads `t` and writes only into `tm`, which it owns.
            let mut tm: libc::tm = unsafe { std::mem::zeroed() };
            if !unsafe { libc::localtime_r(&t, &mut tm) }.is_null() {
                return format!("{:02}:{:02}:{:02}", tm.tm_hour, tm.tm_min, tm.tm_sec);
            }
        }
    }
    let day = secs % 86_400;
    format!(
        "{:02}:{:02}:{:02} UTC",
        day / 3600,
        day % 3600 / 60,
        day % 60
    )
}

/// What a shot-by-shot job (detect, kernels) has handed back so far, for the message
/// that says how it went once it ends.
#[derive(Default)]
pub(crate) struct Tally {
    pub ok: usize,
    /// Each failed shot's name and the reason.
    pub failed: Vec<(String, String)>,
}

/// Where the Kernel field view's samples come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldSource {
    /// Measured on the selected shot.
    Measured,
    /// Predicted by the profile at the sliders' setting.
    Predicted,
    /// The demo lens's exact blur (demo sessions only).
    Truth,
}

/// What the Kernel field view draws at each position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldShow {
    /// The 1-σ ellipses of the Gaussians.
    Ellipses,
    /// The measured non-parametric kernels themselves.
    Kernels,
}

/// A plot of the studio, for saving it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PlotId {
    /// A Sweeps plot: against aperture or focal length; the index of its parameter in
    /// [`view_data::sweep_params`] (for the axis shown).
    Sweep {
        vs_aperture: bool,
        param: usize,
    },
    /// The Models view's cross-validation error against α, against β, and the error CDF.
    CvAlpha,
    CvBeta,
    CvCdf,
}

impl PlotId {
    /// The view the plot is drawn in.
    #[must_use]
    pub fn view(self) -> View {
        match self {
            Self::Sweep { .. } => View::Sweeps,
            Self::CvAlpha | Self::CvBeta | Self::CvCdf => View::Models,
        }
    }

    /// A file name stem the save dialog proposes.
    #[must_use]
    pub fn file_stem(self, axis: SweepAxis) -> String {
        match self {
            Self::Sweep { vs_aperture, param } => {
                let name = view_data::sweep_params(axis)
                    .get(param)
                    .map_or("sweep", |p| p.name)
                    .replace(' ', "-");
                let against = if vs_aperture { "aperture" } else { "focal" };
                format!("sweep-{name}-vs-{against}")
            }
            Self::CvAlpha => "cv-alpha".into(),
            Self::CvBeta => "cv-beta".into(),
            Self::CvCdf => "cv-error-cdf".into(),
        }
    }

    /// Where the draw code keeps the plot's last screen rectangle, in egui's memory.
    #[must_use]
    pub fn rect_id(self) -> egui::Id {
        egui::Id::unique(("plot rect", self))
    }
}

/// A plot PNG waiting for the screenshot it is cut from.
pub struct PendingPlotPng {
    pub path: PathBuf,
    /// The plot's rectangle, in points.
    pub rect: egui::Rect,
    pub image: std::sync::mpsc::Receiver<Arc<egui::ColorImage>>,
}

/// What the Sweeps view plots against the settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SweepAxis {
    /// C_xx, C_yy, C_or.
    Sigma,
    /// MTF50 along the worst and best directions and of the isotropic equivalent.
    Mtf50,
}

/// A loaded shot and its display textures per channel.
pub struct ShotPreview {
    pub capture: Arc<Capture>,
    pub textures: BTreeMap<Channel, egui::TextureHandle>,
    /// A RAW shot developed, at full resolution, or why it could not be.
    pub developed: Option<Result<egui::TextureHandle, String>>,
    pub thumbnail: Option<egui::TextureHandle>,
}

/// Zoom and pan of the shot viewer: sensor pixel per screen point and the sensor point
/// at the viewer's centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewerState {
    /// `None` while the shot is fitted to the viewer (it stays fitted as the viewer
    /// resizes); set once the user zooms or pans.
    pub sensor_px_per_point: Option<f32>,
    pub centre_sensor: [f32; 2],
    /// Overlays: square outlines, circles and corners, the global chart grid.
    pub show_squares: bool,
    pub show_circles: bool,
    pub show_grid: bool,
    /// RAW shots and photos shown as imagepipe develops them; off, as the linear CFA
    /// planes that are measured (the Deblur view's crops follow the same switch).
    pub developed: bool,
}

/// The photo open in the Deblur view.
pub struct Photo {
    pub path: PathBuf,
    pub capture: Arc<Capture>,
    pub texture: Option<egui::TextureHandle>,
    /// A RAW photo developed, or why it could not be; `None` for an RGB photo.
    pub developed: Option<Result<egui::TextureHandle, String>>,
    /// From EXIF, the session's record of the shot, or typed.
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
}

impl Photo {
    /// The texture to show: developed where asked and available.
    #[must_use]
    pub fn shown(&self, developed: bool) -> Option<&egui::TextureHandle> {
        match &self.developed {
            Some(Ok(t)) if developed => Some(t),
            _ => self.texture.as_ref(),
        }
    }

    #[must_use]
    pub fn setting(&self) -> Option<crate::plane::LensSetting> {
        Some(crate::plane::LensSetting {
            focal_mm: self.focal_mm?,
            f_number: self.f_number?,
        })
    }
}

/// Deblurred crops and their textures: original, predicted, measured.
pub struct ComparisonView {
    pub comparison: Arc<DeblurComparison>,
    pub measured_from: Option<String>,
    pub textures: [Option<egui::TextureHandle>; 3],
    /// The same crops developed (a RAW photo's).
    pub developed: [Option<egui::TextureHandle>; 3],
}

impl ComparisonView {
    /// The crops to show: developed where asked and the photo was.
    #[must_use]
    pub fn shown(&self, developed: bool) -> &[Option<egui::TextureHandle>; 3] {
        if developed && self.developed[0].is_some() {
            &self.developed
        } else {
            &self.textures
        }
    }
}

/// Magnification of the compared panes: the region fitted to them, or shown with one
/// sensor pixel on 1, 2 or 4 screen pixels (the region is then what the panes hold).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeblurZoom {
    Fit,
    Times(u8),
}

impl DeblurZoom {
    pub const ALL: [Self; 4] = [Self::Fit, Self::Times(1), Self::Times(2), Self::Times(4)];

    #[must_use]
    pub fn label(self) -> String {
        match self {
            Self::Fit => "Fit".into(),
            Self::Times(z) => format!("{} %", 100 * u32::from(z)),
        }
    }
}

/// The Deblur view's state.
pub struct DeblurState {
    pub photo: Option<Photo>,
    /// Side of the compared crop at Fit, sensor px.
    pub crop_px: usize,
    pub zoom: DeblurZoom,
    /// The region the panes hold at a zoom other than Fit, sensor px (set by the layout).
    pub viewport: Option<[usize; 2]>,
    /// The view's method and strength; `None` until changed here: the session's method.
    pub method: Option<crate::deblur::Method>,
    pub device: crate::deblur::Device,
    /// Where the preview runs and, when not where asked, why (said once per change).
    pub device_note: Option<String>,
    /// The panes' drag in progress, sensor px.
    pub drag: [f32; 2],
    /// A preview asked for while one was still stopping: started when it has.
    pub pending: Option<[f64; 2]>,
    pub comparison: Option<ComparisonView>,
    pub layout: DeblurLayout,
    /// Divider position in the slider layout, 0 (all result) to 1 (all original).
    pub slider: f32,
    pub slider_result: DeblurResult,
}

/// Frame intervals while jobs run, to show the UI stays responsive.
#[derive(Default)]
pub struct FrameLog {
    last: Option<Instant>,
    last_report: Option<Instant>,
    pub busy_intervals_ms: Vec<f32>,
    /// Time the app's own logic and drawing took in those frames (the rest of an
    /// interval is egui's tessellation, the renderer and the wait for the display).
    pub busy_app_ms: Vec<f32>,
    /// Names of the jobs that ran while these frames were drawn.
    pub busy_jobs: std::collections::BTreeSet<String>,
}

impl FrameLog {
    /// (count, median, 95th percentile, max) of frame intervals in ms while jobs ran.
    #[must_use]
    pub fn stats(&self) -> Option<(usize, f32, f32, f32)> {
        summary(&self.busy_intervals_ms)
    }

    /// Median of the app's own time per frame, ms.
    #[must_use]
    pub fn app_median_ms(&self) -> Option<f32> {
        summary(&self.busy_app_ms).map(|s| s.1)
    }
}

fn summary(values: &[f32]) -> Option<(usize, f32, f32, f32)> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f32::total_cmp);
    let q = |p: f32| v[((v.len() - 1) as f32 * p).round() as usize];
    Some((v.len(), q(0.5), q(0.95), v[v.len() - 1]))
}

impl FrameLog {
    fn record_app_time(&mut self, busy: bool, ms: f32) {
        if busy {
            self.busy_app_ms.push(ms);
        }
    }
}

/// The studio app.
pub struct StudioApp {
    pub session: Option<Session>,
    pub jobs: Jobs<JobOutput>,
    pub view: View,
    pub selected_shot: Option<ShotId>,
    pub channel: Channel,
    pub previews: BTreeMap<ShotId, ShotPreview>,
    /// Shots that could not be read, with the reason.
    pub unreadable: BTreeMap<ShotId, String>,
    /// The status line's messages (dismissable), newest last.
    pub messages: Vec<Message>,
    /// Every message of this run, newest last: the log panel.
    pub log: Vec<Message>,
    pub log_open: bool,
    /// The question being asked, in a modal dialog.
    pub confirm: Option<Confirm>,
    pub show_help: bool,
    pub show_about: bool,
    /// Recently opened session folders, most recent first.
    pub recent: Vec<PathBuf>,
    pub commands: Vec<Command>,
    pub viewer: ViewerState,
    /// Setting for the predicted / ground-truth field and the sweeps.
    pub field_focal_mm: f64,
    pub field_f_number: f64,
    pub compare_units: bool,
    /// Detection per shot, this run's or read back from the session's results.
    pub detections: BTreeMap<ShotId, Arc<Detection>>,
    /// The square clicked in the Shot view: (row, col).
    pub selected_square: Option<(usize, usize)>,
    /// Measured kernels and their Gaussians per shot (all channels).
    pub measured: BTreeMap<ShotId, Arc<KernelsFile>>,
    /// The session's measured Gaussians over every shot with kernels.
    pub dataset: Option<Arc<Dataset>>,
    /// The lens profile in use (calibrated here or loaded) and a second one to compare.
    pub profile: Option<(PathBuf, Arc<Profile>)>,
    pub compare_profile: Option<(PathBuf, Arc<Profile>)>,
    pub cv: Option<Arc<CvReport>>,
    /// What the Kernel field view shows.
    pub field_source: FieldSource,
    pub field_show: FieldShow,
    pub field_options: view_data::FieldOptions,
    pub sweep_axis: SweepAxis,
    pub plot_png: Option<PendingPlotPng>,
    /// What the views show that takes computing, cached by what it depends on.
    pub views: view_data::ViewData,
    pub deblur: DeblurState,
    /// Settings being edited in the session panel, applied by its Apply button.
    pub settings_edit: Option<(ChartSpec, StageSettings)>,
    pub dark: bool,
    pub frames: FrameLog,
    pub options: AppOptions,
    pub ctx: egui::Context,
    /// Shots whose loading has been started.
    loading: std::collections::BTreeSet<ShotId>,
    /// Counts the sessions opened: results of jobs started for an earlier one are
    /// dropped when they arrive.
    session_generation: u64,
    /// The open session folder's lock: one studio or command writes there at a time.
    session_lock: Option<crate::lock::FolderLock>,
    first_frame_logged: bool,
    /// Frames left of the autorun's strength drag.
    drag_frames: usize,
    first_shot_logged: bool,
    ready_logged: bool,
    /// File dialogs run on their own threads (a portal dialog's future, blocked on
    /// there) and send back the commands their answer makes; the window never waits.
    dialog_tx: std::sync::mpsc::Sender<Vec<Command>>,
    dialog_rx: std::sync::mpsc::Receiver<Vec<Command>>,
    /// One file dialog at a time: a second would stack on the first.
    dialog_open: bool,
    /// Per running detect or kernels job (by id): how its shots went so far.
    tallies: BTreeMap<u64, Tally>,
}

impl StudioApp {
    /// Builds the app and starts whatever the first frame needs (opening the session, or
    /// making the demo session in the background).
    #[must_use]
    pub fn new(ctx: &egui::Context, options: AppOptions) -> Self {
        let wake_ctx = ctx.clone();
        let (dialog_tx, dialog_rx) = std::sync::mpsc::channel();
        let recent = options
            .recent_file
            .as_deref()
            .map(crate::session::read_recent)
            .unwrap_or_default();
        let mut app = Self {
            session: None,
            jobs: Jobs::new(options.job_threads, move || wake_ctx.request_repaint()),
            view: View::Shot,
            selected_shot: None,
            channel: Channel::G,
            previews: BTreeMap::new(),
            unreadable: BTreeMap::new(),
            messages: Vec::new(),
            log: Vec::new(),
            log_open: false,
            confirm: None,
            show_help: false,
            show_about: false,
            recent,
            commands: Vec::new(),
            viewer: ViewerState {
                sensor_px_per_point: None,
                centre_sensor: [0.0, 0.0],
                show_squares: true,
                show_circles: true,
                show_grid: false,
                developed: true,
            },
            field_focal_mm: 50.0,
            field_f_number: 5.6,
            compare_units: false,
            detections: BTreeMap::new(),
            selected_square: None,
            measured: BTreeMap::new(),
            dataset: None,
            profile: None,
            compare_profile: None,
            cv: None,
            field_source: FieldSource::Measured,
            field_show: FieldShow::Ellipses,
            field_options: view_data::FieldOptions::default(),
            sweep_axis: SweepAxis::Sigma,
            plot_png: None,
            views: view_data::ViewData::default(),
            deblur: DeblurState {
                photo: None,
                crop_px: 160,
                zoom: DeblurZoom::Fit,
                viewport: None,
                method: None,
                device: crate::deblur::Device::Auto,
                device_note: None,
                drag: [0.0; 2],
                pending: None,
                comparison: None,
                layout: DeblurLayout::SideBySide,
                slider: 0.5,
                slider_result: DeblurResult::Predicted,
            },
            settings_edit: None,
            dark: true,
            frames: FrameLog::default(),
            options: options.clone(),
            ctx: ctx.clone(),
            loading: std::collections::BTreeSet::new(),
            session_generation: 0,
            session_lock: None,
            first_frame_logged: false,
            drag_frames: 0,
            first_shot_logged: false,
            ready_logged: false,
            dialog_tx,
            dialog_rx,
            dialog_open: false,
            tallies: BTreeMap::new(),
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

    /// Whether the open session still has this shot (a job's result may arrive after
    /// the shot was removed).
    #[must_use]
    pub fn has_shot(&self, id: ShotId) -> bool {
        self.session.as_ref().is_some_and(|s| s.shot(id).is_some())
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
        if let Some(s) = &self.session
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
            .spawn_apart("demo session", move |ctx: &JobContext, out| {
                // Each shot is shown as soon as it is on disk: a newcomer sees a
                // session within seconds instead of waiting for all of them.
                let s = crate::session::make_demo_streaming(&dir, &spec, ctx, &mut |s| {
                    out.emit(JobOutput::DemoShot(Box::new(s.clone())));
                })
                .map_err(|e| e.to_string())?;
                out.emit(JobOutput::DemoReady(Box::new(s)));
                Ok(())
            });
        if let Err(e) = started {
            self.error(e);
        }
    }

    /// Opens a session in the window, holding its folder's lock while it is open.
    /// Returns false, keeping the session that was open, when another studio or
    /// command is working in that folder.
    pub(crate) fn set_session(&mut self, s: Session) -> bool {
        let same_folder = self
            .session_lock
            .as_ref()
            .is_some_and(|l| l.dir() == s.folder());
        if !same_folder {
            // Let go of the old folder first: a lock is per open file, so reopening the
            // same folder elsewhere would otherwise refuse itself.
            let old = self.session_lock.take();
            match s.lock("the lensblur studio") {
                Ok((lock, swept)) => {
                    drop(old);
                    self.session_lock = Some(lock);
                    if swept > 0 {
                        self.info(format!(
                            "{}: removed {swept} unfinished temporary files left by an interrupted write",
                            s.folder().display()
                        ));
                    }
                }
                Err(e @ crate::lock::LockError::Held { .. }) => {
                    self.session_lock = old;
                    self.error(e.to_string());
                    return false;
                }
                Err(e) => {
                    // A read-only folder: it is shown, and saving it will say why not.
                    self.info(format!("{e}: opened without a lock"));
                }
            }
        }
        // Work on the session being closed stops, and what it still sends is dropped.
        self.jobs.cancel_session_jobs();
        self.session_generation += 1;
        self.previews.clear();
        self.unreadable.clear();
        self.loading.clear();
        self.detections.clear();
        self.measured.clear();
        self.views = view_data::ViewData::default();
        self.dataset = None;
        self.cv = None;
        self.profile = None;
        self.settings_edit = None;
        self.deblur.comparison = None;
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
        self.selected_shot = s.shots.first().map(|shot| shot.id);
        self.viewer.sensor_px_per_point = None;
        if let Some((f, a)) = middle_setting(&s) {
            self.field_focal_mm = f;
            self.field_f_number = a;
        }
        logic::read_results(self, &s);
        if s.is_demo {
            self.open_demo_photo(&s);
        }
        // Every session the user opens is remembered, but not the built-in demo: it is
        // what the studio opens by itself.
        if s.folder() != self.options.demo_dir
            && let Some(file) = self.options.recent_file.clone()
        {
            match crate::session::remember_recent(&file, s.folder()) {
                Ok(list) => self.recent = list,
                Err(e) => self.error(format!("cannot remember the session as recent: {e}")),
            }
        }
        self.session = Some(s);
        true
    }

    /// Opens the demo's photo in the Deblur view, unless a photo is open already.
    pub(crate) fn open_demo_photo(&mut self, s: &Session) {
        if let Some(p) = &s.demo_photo
            && self.deblur.photo.is_none()
        {
            let path = s.folder().join(&p.path);
            if path.is_file() {
                self.commands.push(Command::OpenPhoto(path));
            }
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
        let ready = !self.jobs.is_running("demo session")
            && self.session.as_ref().is_some_and(|s| {
                !s.shots.is_empty() && self.previews.len() + self.unreadable.len() == s.shots.len()
            });
        if !self.first_shot_logged && !self.previews.is_empty() {
            self.first_shot_logged = true;
            if self.options.log_frame_times {
                eprintln!(
                    "studio: first shot shown after {:.2} s",
                    self.options.started.elapsed().as_secs_f32()
                );
            }
        }
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
                // The Deblur view at 100 % in the slider layout (one pane as large as
                // the window allows) on LENSBLUR_PHOTO, else the first shot.
                "deblur" => {
                    let photo = std::env::var_os("LENSBLUR_PHOTO")
                        .map(PathBuf::from)
                        .or_else(|| {
                            let s = self.session.as_ref()?;
                            Some(s.path_of(s.shots.first()?))
                        });
                    if let Some(p) = photo {
                        self.commands.push(Command::SelectView(View::Deblur));
                        self.commands
                            .push(Command::SetDeblurLayout(DeblurLayout::Slider));
                        self.commands
                            .push(Command::SetDeblurZoom(DeblurZoom::Times(1)));
                        self.commands.push(Command::OpenPhoto(p));
                    }
                }
                // The strength slider dragged for 300 frames, as a hand would: frame
                // times are then those of a live control.
                "drag-strength" => {
                    // Once the region fills the panes at 100 % (else next frame).
                    let filled = match (&self.deblur.comparison, &self.deblur.photo) {
                        (Some(c), Some(p)) => self.deblur.viewport.is_some_and(|[w, h]| {
                            let r = c.comparison.region;
                            r.width == w.min(p.capture.width) & !1
                                && r.height == h.min(p.capture.height) & !1
                        }),
                        _ => false,
                    };
                    if filled {
                        self.frames = FrameLog::default();
                        self.drag_frames = 300;
                        if let Some(c) = &self.deblur.comparison {
                            let r = c.comparison.region;
                            eprintln!(
                                "studio: dragging the strength on a {} × {} region",
                                r.width, r.height
                            );
                        }
                    } else {
                        self.options.autorun.insert(0, stage);
                    }
                }
                other => self.error(format!("LENSBLUR_AUTORUN: unknown stage '{other}'")),
            }
        }
        if self.drag_frames > 0 {
            self.drag_frames -= 1;
            let k = self.drag_frames as f64;
            let lambda = 3000.0 * 10f64.powf((k / 25.0).sin());
            self.commands
                .push(Command::SetDeblurMethod(crate::deblur::Method::Hqs(
                    crate::deblur::HqsParams {
                        lambda,
                        ..Default::default()
                    },
                )));
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

impl eframe::App for StudioApp {
    fn logic(&mut self, ctx: &egui::Context, _frame: &mut eframe::Frame) {
        self.logic_step();
        if self.drag_frames > 0 {
            ctx.request_repaint();
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
            // Keep the progress bar moving; also what the frame-time figure measures.
            ui.ctx().request_repaint();
        }
    }

    fn on_exit(&mut self) {
        if let Some(s) = &self.session
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
