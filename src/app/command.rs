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
    /// Whatever is missing (detect, kernels) then calibration, as one job; with
    /// `then_deblur`, the Deblur view opens on the before/after once the profile exists.
    CalibrateAll {
        then_deblur: bool,
    },
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
    /// The lens's range the shooting plan is made for.
    SetPlanRange(crate::review::LensRange),
    /// Shows or hides the whole photo above the compared panes.
    SetDeblurOverview(bool),
    /// The amount, in percent of the method's result (0–200).
    SetDeblurAmount(f64),
    /// Whether colour the deconvolution adds at edges is cut back.
    SetDeblurFringes(crate::deblur::Fringes),
    /// Whether deblurring corrects the lens's lateral colour or leaves it for lensfun.
    SetDeblurLateral(crate::model::LateralColour),
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
    /// What the Sharpness view maps.
    SetSharpness(SharpnessChoice),
    /// Asks where to save the sharpness map shown, as a PNG with its colour bar or as
    /// CSV.
    SaveSharpnessDialog {
        png: bool,
    },
    SaveSharpness {
        path: PathBuf,
        png: bool,
    },
    /// The Geometry view's focal length and aperture (its fall-off map).
    SetGeometryFocal(f64),
    SetGeometryAperture(f64),
    /// Asks where to write the lens's lensfun entry (the Geometry view's measurement).
    ExportLensfunDialog,
    /// Writes the lensfun entry (XML) of the Geometry view's measurement, on a job.
    ExportLensfun(PathBuf),
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
    SetFieldOptions(FieldOptions),
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
    /// Saves the profile in use into the profile library (`AppOptions::profile_library`).
    SaveProfileToLibrary,
    /// Asks the user before doing something that loses work.
    AskConfirm(Confirm),
    /// The answer to the question asked: do it, or not.
    ConfirmAnswer(bool),
    /// Shows or hides the log panel (every message of this run, timestamped).
    /// Shows or folds the session panel.
    SetSessionPanel(bool),
    SetLogOpen(bool),
    ShowHelp(bool),
    /// The guide to calibrating your own lens.
    ShowGuide(bool),
    ShowAbout(bool),
    /// Closes the window (the session is saved on the way out).
    Quit,
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
    /// A step of a detect or kernels job on one shot.
    Shot(crate::project::ShotEvent),
    /// The session's measured Gaussians, gathered from its kernels files.
    DatasetReady(Option<Arc<Dataset>>),
    /// Results a reopened session already has in its cache.
    ResultsRead {
        survey: Box<crate::project::Survey>,
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
    /// Deblurred crops of the open photo; `measured_from` names the shot whose kernels
    /// were used.
    DeblurCompared {
        comparison: Arc<DeblurComparison>,
        measured_from: Option<String>,
    },
    DeblurExported(PathBuf),
    /// A set of photos exported: what became of each.
    PhotosExported(crate::batch::BatchReport),
    /// The lens's geometry measured from the session's detections (the Geometry
    /// view's), for the request it answers.
    GeometryMeasured {
        request: u64,
        result: Result<Arc<crate::correction::LensCorrection>, String>,
    },
    /// A lensfun entry written: where, and the lens and camera it is for.
    LensfunExported {
        path: PathBuf,
        lens: String,
    },
    /// The crops of an inspected square (`None`: the square has none in that channel).
    SquareInspected {
        key: InspectKey,
        result: Option<Box<InspectedSquare>>,
    },
}
