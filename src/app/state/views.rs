//! Each view's own state (what it shows and how, as the user set it), and the window's
//! around them. The app holds one [`Views`] and one [`Window`]; commands change them.

use super::{
    DeblurState, FieldOptions, FieldShow, FieldSource, FrameLog, Message, PendingPlotPng,
    SharpnessChoice, SweepAxis, ViewerState,
};
use crate::chart::ChartSpec;
use crate::plane::Channel;
use crate::session::{ShotId, StageSettings};
use std::path::PathBuf;

/// Every view's state.
#[derive(Default)]
pub struct Views {
    pub shot: ShotViewState,
    pub field: FieldViewState,
    pub sweeps: SweepsViewState,
    /// What the Sharpness view maps.
    pub sharpness: SharpnessChoice,
    pub geometry: GeometryViewState,
    pub deblur: DeblurState,
    pub session: SessionPanelState,
}

/// The Shot view: the shot, channel and square selected (the other views follow
/// them) and the viewer's zoom, pan and overlays.
pub struct ShotViewState {
    pub selected: Option<ShotId>,
    pub channel: Channel,
    /// The square clicked: (row, col).
    pub square: Option<(usize, usize)>,
    pub viewer: ViewerState,
}

impl Default for ShotViewState {
    fn default() -> Self {
        Self {
            selected: None,
            channel: Channel::G,
            square: None,
            viewer: ViewerState::fitted(),
        }
    }
}

/// The Kernel field view: what it shows, how it colours it, and the setting of the
/// predicted and true fields (the sweeps' sliders share it).
pub struct FieldViewState {
    pub source: FieldSource,
    pub show: FieldShow,
    pub options: FieldOptions,
    pub focal_mm: f64,
    pub f_number: f64,
    /// The demo lens's second unit shown beside the first.
    pub compare_units: bool,
}

impl Default for FieldViewState {
    fn default() -> Self {
        Self {
            source: FieldSource::Measured,
            show: FieldShow::Ellipses,
            options: FieldOptions::default(),
            focal_mm: 50.0,
            f_number: 5.6,
            compare_units: false,
        }
    }
}

/// The Sweeps view: what it plots against the settings.
pub struct SweepsViewState {
    pub axis: SweepAxis,
}

impl Default for SweepsViewState {
    fn default() -> Self {
        Self {
            axis: SweepAxis::Sigma,
        }
    }
}

/// The Geometry view's focal length and aperture; `None`: the session's first.
#[derive(Default)]
pub struct GeometryViewState {
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
}

/// The session panel on the left.
pub struct SessionPanelState {
    /// Folded, the views have the whole width.
    pub open: bool,
    /// Settings being edited, applied by its Apply button.
    pub settings_edit: Option<(ChartSpec, StageSettings)>,
    /// The lens's range typed for the shooting plan; `None`: the session's.
    pub plan_range: Option<crate::review::LensRange>,
}

impl Default for SessionPanelState {
    fn default() -> Self {
        Self {
            open: true,
            settings_edit: None,
            plan_range: None,
        }
    }
}

/// The window around the views.
pub struct Window {
    /// The status line's messages (dismissable), newest last.
    pub messages: Vec<Message>,
    /// Every message of this run, newest last: the log panel.
    pub log: Vec<Message>,
    pub log_open: bool,
    /// The question being asked, in a modal dialog.
    pub confirm: Option<Confirm>,
    pub show_help: bool,
    pub show_guide: bool,
    pub show_about: bool,
    /// Recently opened session folders, most recent first.
    pub recent: Vec<PathBuf>,
    pub dark: bool,
    /// A plot being saved as PNG, waiting for its screenshot.
    pub plot_png: Option<PendingPlotPng>,
    /// Whether whatever draws the window clears it to the panels' colour first (the
    /// studio's own window does; a test harness clears to transparent), so that the
    /// panels need not paint their background: under a software rasteriser a frame costs
    /// the pixels it fills, and that fill covers the whole window.
    pub cleared_to_panel_fill: bool,
}

impl Window {
    /// The window as it opens: dark, nothing said yet.
    #[must_use]
    pub fn new(recent: Vec<PathBuf>) -> Self {
        Self {
            messages: Vec::new(),
            log: Vec::new(),
            log_open: false,
            confirm: None,
            show_help: false,
            show_guide: false,
            show_about: false,
            recent,
            dark: true,
            plot_png: None,
            cleared_to_panel_fill: false,
        }
    }
}

/// What the window has said on stderr for the scripts that time it
/// (`LENSBLUR_FRAME_LOG=1`): each milestone once, and the frame times while jobs run.
#[derive(Default)]
pub struct Trace {
    pub frames: FrameLog,
    pub first_frame_logged: bool,
    pub first_shot_logged: bool,
    pub before_after_logged: bool,
    pub ready_logged: bool,
}

/// What the studio does by itself, once what it waits for has happened.
#[derive(Default)]
pub struct Autorun {
    /// Frames left of the autorun's strength drag.
    pub drag_frames: usize,
    /// A running *Calibrate all* opens the Deblur view on the photo once it ends (the
    /// first launch's demo).
    pub deblur_when_calibrated: bool,
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
