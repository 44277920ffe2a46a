//! The studio's state types: views, options, messages, the loaded shots, the shot
//! viewer, the Deblur view and the frame-time log. `StudioApp` (in the parent module)
//! holds them.

use crate::plane::{Capture, Channel};
use crate::review::DeblurComparison;
use crate::simulate::demo::DemoSpec;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

mod context;
mod field;
mod inspect;
mod views;

pub use context::ViewerContext;
pub use field::{ColourRange, Difference, FieldOptions};
pub use inspect::{InspectKey, InspectedSquare, Same};
pub use views::{
    Autorun, Confirm, FieldViewState, GeometryViewState, SessionPanelState, ShotViewState,
    SweepsViewState, Trace, Views, Window,
};

/// The studio's views (ARCHITECTURE.md, Studio).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    Shot,
    KernelField,
    Sharpness,
    Sweeps,
    Models,
    Deblur,
    /// Distortion, lateral colour and fall-off per focal length (lensfun's models).
    Geometry,
}

impl View {
    pub const ALL: [View; 7] = [
        View::Shot,
        View::KernelField,
        View::Sharpness,
        View::Sweeps,
        View::Models,
        View::Deblur,
        View::Geometry,
    ];

    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            View::Shot => "Shot",
            View::KernelField => "Kernel field",
            View::Sharpness => "Sharpness",
            View::Sweeps => "Sweeps",
            View::Models => "Models",
            View::Deblur => "Deblur",
            View::Geometry => "Geometry",
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
    /// Threads jobs compute on; 0: one per core, at a lower priority than the window.
    pub job_threads: usize,
    /// When the process started, for the first-frame time.
    pub started: Instant,
    /// The list of recently opened sessions (File ▸ Recent sessions); `None` keeps none.
    pub recent_file: Option<PathBuf>,
    /// The profile library *Export ▸ Lens profile to the library* saves into: the
    /// folder a batch reads without `--profiles`.
    pub profile_library: PathBuf,
    /// Where a profile library chosen in the studio is remembered (the batch reads the
    /// same file); `None` keeps the choice for this run only.
    pub settings_file: Option<PathBuf>,
    /// Run *Calibrate all* on the demo session while it has no profile, then open its
    /// photo's before/after: what a first launch shows without a click.
    pub calibrate_demo: bool,
    /// How long a notice stays in the status line (errors stay until dismissed; the
    /// log keeps everything); `None`: until dismissed, as errors.
    pub notice_lifetime: Option<std::time::Duration>,
}

impl Default for AppOptions {
    fn default() -> Self {
        Self {
            session: None,
            demo_dir: crate::recent::default_demo_dir(),
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
            recent_file: Some(crate::recent::default_recent_file()),
            profile_library: crate::recent::profile_library(&crate::recent::default_settings_file()),
            settings_file: Some(crate::recent::default_settings_file()),
            calibrate_demo: true,
            notice_lifetime: Some(std::time::Duration::from_secs(6)),
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
    /// When it was said: a notice leaves the status line a few seconds later.
    pub said: Instant,
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
    /// The shots whose every stage so far succeeded (a shot detected and then
    /// measured counts once).
    pub ok: std::collections::BTreeSet<crate::session::ShotId>,
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

/// What the Sharpness view maps: from where, which MTF50, in which unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SharpnessChoice {
    pub source: FieldSource,
    pub direction: crate::review::Mtf50Direction,
    pub unit: crate::review::SharpnessUnit,
}

impl Default for SharpnessChoice {
    /// What the profile predicts: the map a photographer asks for first, at any setting.
    fn default() -> Self {
        Self {
            source: FieldSource::Predicted,
            direction: crate::review::Mtf50Direction::Worst,
            unit: crate::review::SharpnessUnit::LpPerPictureHeight,
        }
    }
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
    /// the sweeps' parameters of the axis shown.
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

/// A shot of the session as the window has it, from the moment its loading starts.
pub enum ShotView {
    Loading,
    Loaded(ShotPreview),
    /// The shot cannot be read: the one-line reason names the file.
    Unreadable(String),
}

impl ShotView {
    #[must_use]
    pub fn preview(&self) -> Option<&ShotPreview> {
        match self {
            Self::Loaded(p) => Some(p),
            _ => None,
        }
    }

    #[must_use]
    pub fn unreadable(&self) -> Option<&str> {
        match self {
            Self::Unreadable(reason) => Some(reason),
            _ => None,
        }
    }
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

impl ViewerState {
    /// The shot fitted to the viewer, with squares and circles drawn and RAW shots
    /// developed: how the viewer opens.
    #[must_use]
    pub fn fitted() -> Self {
        Self {
            sensor_px_per_point: None,
            centre_sensor: [0.0, 0.0],
            show_squares: true,
            show_circles: true,
            show_grid: false,
            developed: true,
        }
    }
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
    /// What the photo is (RAW, linear or developed 8-bit), read once when it opened:
    /// the view warns, in the command line's words, when the profile was measured on
    /// the other kind.
    pub kind: crate::plane::PictureKind,
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

/// What the Deblur view's preview deblurs (`logic::deblur::preview_scope` decides).
#[derive(Clone, Debug, PartialEq)]
pub enum PreviewScope {
    /// A hardware GPU: the next preview deblurs the whole photo, and its time decides.
    Trial,
    /// The whole photo as the controls move; the first preview took `ms`.
    Whole { ms: f64 },
    /// Crops, and why not the whole photo (one short line).
    Crops(String),
}

impl PreviewScope {
    /// Whether the preview deblurs the whole photo (at Fit: a zoomed pane holds less).
    #[must_use]
    pub fn whole(&self) -> bool {
        matches!(self, Self::Trial | Self::Whole { .. })
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
    /// How strongly to deblur (the photographer's control).
    pub amount: crate::deblur::Amount,
    /// Colour the deconvolution adds at edges: cut back (the default) or kept.
    pub fringes: crate::deblur::Fringes,
    /// The lens's lateral colour: corrected with the blur (the default) or kept for
    /// lensfun.
    pub lateral: crate::model::LateralColour,
    /// Whether the whole photo and the notes show above the compared panes; closed,
    /// the before/after has the view to itself.
    pub overview_open: bool,
    /// Where the preview runs and, when not where asked, why (said once per change).
    pub device_note: Option<String>,
    /// Whether the preview deblurs the whole photo or crops; `None` until the next
    /// preview decides (after the photo, the device or the method changed).
    pub scope: Option<PreviewScope>,
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

/// No photo yet, side by side at Fit.
impl Default for DeblurState {
    fn default() -> Self {
        Self {
            photo: None,
            crop_px: 160,
            zoom: DeblurZoom::Fit,
            viewport: None,
            method: None,
            device: crate::deblur::Device::Auto,
            amount: crate::deblur::Amount::FULL,
            fringes: crate::deblur::Fringes::Suppress,
            lateral: crate::model::LateralColour::Correct,
            overview_open: true,
            device_note: None,
            scope: None,
            drag: [0.0; 2],
            pending: None,
            comparison: None,
            layout: DeblurLayout::SideBySide,
            slider: 0.5,
            slider_result: DeblurResult::Predicted,
        }
    }
}

/// Frame intervals while jobs run, to show the UI stays responsive.
#[derive(Default)]
pub struct FrameLog {
    pub(super) last: Option<Instant>,
    pub(super) last_report: Option<Instant>,
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
    pub(super) fn record_app_time(&mut self, busy: bool, ms: f32) {
        if busy {
            self.busy_app_ms.push(ms);
        }
    }
}
