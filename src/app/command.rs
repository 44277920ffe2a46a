//! What panels ask the app to do ([`Command`], applied by `logic` after the frame is
//! drawn), what the studio asks the user first ([`Confirm`]) and what jobs hand back
//! ([`JobOutput`]).

use super::state::{Confirm, FieldOptions, InspectKey, InspectedSquare};
use super::{
    DeblurLayout, DeblurResult, DeblurZoom, FieldShow, FieldSource, PlotId, SharpnessChoice,
    SweepAxis, View, ViewerState,
};
use crate::chart::ChartSpec;
use crate::crossval::CvReport;
use crate::develop::Developed;
use crate::model::Dataset;
use crate::plane::{Capture, Channel};
use crate::profile::Profile;
use crate::review::DeblurComparison;
use crate::session::{Session, ShotId, StageSettings};
use std::path::PathBuf;
use std::sync::Arc;

/// Everything a panel can ask for, one group per concern; `logic::apply` hands each
/// group to its handler, which matches it whole.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    View(ViewCommand),
    Window(WindowCommand),
    Session(SessionCommand),
    Stage(StageCommand),
    Deblur(DeblurCommand),
    Plot(PlotCommand),
    Geometry(GeometryCommand),
    Dialog(DialogCommand),
}

/// Selections and view options: what the views show, not what is measured.
#[derive(Clone, Debug, PartialEq)]
pub enum ViewCommand {
    SelectView(View),
    SelectShot(ShotId),
    SelectChannel(Channel),
    ClearSquare,
    /// A chart square in the Shot view: (row, col).
    SelectSquare((usize, usize)),
    SetFieldSource(FieldSource),
    SetFieldShow(FieldShow),
    SetSweepAxis(SweepAxis),
    /// What the Sharpness view maps.
    SetSharpness(SharpnessChoice),
    /// The setting of the predicted and true fields and of the sweeps (the sliders).
    SetFieldSetting {
        focal_mm: f64,
        f_number: f64,
    },
    /// Show the demo lens's second unit beside the first.
    SetCompareUnits(bool),
    /// The Kernel field view's colour range and difference map.
    SetFieldOptions(FieldOptions),
    /// The shot viewer's zoom, pan and overlays, as the user moved them.
    SetViewer(ViewerState),
    /// The Geometry view's focal length and aperture (its fall-off map).
    SetGeometryFocal(f64),
    SetGeometryAperture(f64),
    /// The lens's range the shooting plan is made for.
    SetPlanRange(crate::review::LensRange),
}

/// The window around the views: jobs cancelled, theme, messages, panels, quitting.
#[derive(Clone, Debug, PartialEq)]
pub enum WindowCommand {
    Cancel(u64),
    CancelAll,
    SetDark(bool),
    DismissMessage(usize),
    /// Shows or hides the log panel (every message of this run, timestamped).
    SetLogOpen(bool),
    /// Shows or folds the session panel.
    SetSessionPanel(bool),
    ShowHelp(bool),
    /// The guide to calibrating your own lens.
    ShowGuide(bool),
    ShowAbout(bool),
    /// Closes the window (the session is saved on the way out).
    Quit,
}

/// The session's shots and settings, and opening a session.
#[derive(Clone, Debug, PartialEq)]
pub enum SessionCommand {
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
    /// Reads a chart spec file into the settings being edited (the dialog's answer).
    LoadChart(PathBuf),
    /// The chart and stage settings being edited (not yet applied); `None` reverts.
    EditSettings(Option<(ChartSpec, StageSettings)>),
    /// Opens (or creates) the session in a folder, or from a session file or manifest.
    OpenSession(PathBuf),
}

/// The pipeline's stages (detect, kernels, calibrate) and the profile in use.
#[derive(Clone, Debug, PartialEq)]
pub enum StageCommand {
    /// Detection on one shot, or on every shot without a result.
    RunDetect(Option<ShotId>),
    RunKernels(Option<ShotId>),
    RunCalibrate,
    /// Whatever is missing (detect, kernels) then calibration, as one job; with
    /// `then_deblur`, the Deblur view opens on the before/after once the profile exists.
    CalibrateAll {
        then_deblur: bool,
    },
    LoadProfile {
        path: PathBuf,
        compare: bool,
    },
    /// Saves the profile in use to a file (the dialog's answer).
    SaveProfile(PathBuf),
    /// Saves the profile in use into the profile library (`AppOptions::profile_library`).
    SaveProfileToLibrary,
    /// Makes a folder the profile library, remembered for the next launch and the
    /// batch (the dialog's answer).
    SetProfileLibrary(PathBuf),
}

/// The Deblur view: the photo, its before/after and exports.
#[derive(Clone, Debug, PartialEq)]
pub enum DeblurCommand {
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
    /// The amount, in percent of the method's result (0–200).
    SetDeblurAmount(f64),
    /// Whether colour the deconvolution adds at edges is cut back.
    SetDeblurFringes(crate::deblur::Fringes),
    /// Whether deblurring corrects the lens's lateral colour or leaves it for lensfun.
    SetDeblurLateral(crate::model::LateralColour),
    /// Shows or hides the whole photo above the compared panes.
    SetDeblurOverview(bool),
    SetDeblurDevice(crate::deblur::Device),
    /// Drag of the compared panes in progress (sensor px), drawn as a shift.
    DragDeblur([f32; 2]),
    /// The drag ended: the region moves by it and is deblurred there.
    EndDragDeblur,
    SetSliderResult(DeblurResult),
    /// The slider layout's divider, 0 (all result) to 1 (all original).
    SetSlider(f32),
    ExportDeblur {
        path: PathBuf,
        result: DeblurResult,
    },
    /// Deblur a set of photos with the open profile into `out_dir`, as the command
    /// line's batch does: 16-bit TIFF, or with `dng` RAW photos as DNGs (others skipped).
    ExportPhotos {
        photos: Vec<PathBuf>,
        out_dir: PathBuf,
        dng: bool,
    },
}

/// Plots and maps saved to files.
#[derive(Clone, Debug, PartialEq)]
pub enum PlotCommand {
    SavePlotCsv {
        plot: PlotId,
        path: PathBuf,
    },
    /// Takes a screenshot and saves the plot's part of it once it arrives.
    SavePlotPng {
        plot: PlotId,
        path: PathBuf,
    },
    SaveSharpness {
        path: PathBuf,
        png: bool,
    },
}

/// The lens's geometry: its lensfun export.
#[derive(Clone, Debug, PartialEq)]
pub enum GeometryCommand {
    /// Writes the lensfun entry (XML) of the project's measured geometry, on a job.
    ExportLensfun(PathBuf),
}

/// File dialogs and questions asked before a command runs.
#[derive(Clone, Debug, PartialEq)]
pub enum DialogCommand {
    /// Opens the file dialog for shots.
    AddShotsDialog,
    /// Reads a chart spec file into the settings being edited.
    LoadChartDialog,
    OpenPhotoDialog,
    ExportDeblurDialog(DeblurResult),
    /// Choose photos and a folder, then export them deblurred with the profile.
    ExportPhotosDialog {
        dng: bool,
    },
    LoadProfileDialog,
    SaveProfileDialog,
    /// Asks where to save a plot, as a PNG of it on screen or as CSV of its data.
    SavePlotDialog {
        plot: PlotId,
        png: bool,
    },
    /// Asks where to save the sharpness map shown, as a PNG with its colour bar or as
    /// CSV.
    SaveSharpnessDialog {
        png: bool,
    },
    /// Asks where to write the lens's lensfun entry (the project's measured geometry).
    ExportLensfunDialog,
    OpenSessionDialog,
    /// Asks the user before doing something that loses work.
    AskConfirm(Confirm),
    /// The answer to the question asked: do it, or not.
    ConfirmAnswer(bool),
    /// Load a second profile to show beside the first (two lens units).
    LoadCompareProfileDialog,
    /// Asks for the folder to use as the profile library.
    ChooseProfileLibraryDialog,
}

impl From<ViewCommand> for Command {
    fn from(c: ViewCommand) -> Self {
        Self::View(c)
    }
}

impl From<WindowCommand> for Command {
    fn from(c: WindowCommand) -> Self {
        Self::Window(c)
    }
}

impl From<SessionCommand> for Command {
    fn from(c: SessionCommand) -> Self {
        Self::Session(c)
    }
}

impl From<StageCommand> for Command {
    fn from(c: StageCommand) -> Self {
        Self::Stage(c)
    }
}

impl From<DeblurCommand> for Command {
    fn from(c: DeblurCommand) -> Self {
        Self::Deblur(c)
    }
}

impl From<PlotCommand> for Command {
    fn from(c: PlotCommand) -> Self {
        Self::Plot(c)
    }
}

impl From<GeometryCommand> for Command {
    fn from(c: GeometryCommand) -> Self {
        Self::Geometry(c)
    }
}

impl From<DialogCommand> for Command {
    fn from(c: DialogCommand) -> Self {
        Self::Dialog(c)
    }
}

/// What jobs hand back, one group per concern (the square inspector's is view data).
pub enum JobOutput {
    Session(SessionOutput),
    Shots(ShotOutput),
    Stage(StageOutput),
    Deblur(DeblurOutput),
    Geometry(GeometryOutput),
    /// The crops of an inspected square (`None`: the square has none in that channel).
    SquareInspected {
        key: InspectKey,
        result: Option<Box<InspectedSquare>>,
    },
}

/// The demo session as it is made, and results read back from a reopened session.
pub enum SessionOutput {
    /// The demo session so far, each time another of its shots is on disk.
    DemoShot(Box<Session>),
    DemoReady(Box<Session>),
    /// Results a reopened session already has in its cache.
    ResultsRead {
        survey: Box<crate::project::Survey>,
        cv: Option<Arc<CvReport>>,
    },
}

/// A shot loaded for display, or why it cannot be.
pub enum ShotOutput {
    ShotLoaded {
        shot: ShotId,
        capture: Arc<Capture>,
        /// A RAW shot developed for display (or why not); `None` for RGB.
        developed: Option<Result<Developed, String>>,
    },
    /// A shot that cannot be read: the one-line reason names the file.
    ShotUnreadable { shot: ShotId, reason: String },
}

/// The stages' results: each shot's step, the dataset, the profile.
pub enum StageOutput {
    /// A step of a detect or kernels job on one shot.
    Shot(crate::project::ShotEvent),
    /// The session's measured Gaussians, gathered from its kernels files.
    DatasetReady(Option<Arc<Dataset>>),
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
}

/// The Deblur view's photo, previews and exports.
pub enum DeblurOutput {
    PhotoLoaded {
        path: PathBuf,
        capture: Arc<Capture>,
        developed: Option<Result<Developed, String>>,
    },
    /// Deblurred crops of the open photo; `measured_from` names the shot whose kernels
    /// were used.
    DeblurCompared {
        comparison: Arc<DeblurComparison>,
        measured_from: Option<String>,
        /// For a preview of the whole photo, how long it took, ms.
        whole_ms: Option<f64>,
    },
    DeblurExported(PathBuf),
    /// A set of photos exported: what became of each.
    PhotosExported(crate::batch::BatchReport),
}

/// The lens's geometry measured, and its lensfun entry written.
pub enum GeometryOutput {
    /// The lens's geometry measured from the session's detections, with what it was
    /// measured from (the project keeps it where that is still what it holds).
    GeometryMeasured(Box<crate::project::MeasuredGeometry>),
    /// A lensfun entry written: where, and the lens and camera it is for.
    LensfunExported { path: PathBuf, lens: String },
}
