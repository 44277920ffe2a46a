//! View data: everything a view shows that takes computing, made here (or on a job
//! thread) when its inputs change and cached on the app keyed by exactly those inputs.
//!
//! Owns the shot viewer's plane choice, the Kernel field view's panels (measured
//! ellipses, the kernel atlas texture, predicted and true fields), the Sweeps view's
//! measured points and model and truth curves, and the square inspector (its crops come
//! from a job; their textures, the kernel's texture and the truth beside it are made
//! here when they arrive). [`refresh`] runs once per frame from the app's logic step and
//! recomputes only what is stale; the draw code reads these caches and shows a
//! placeholder where one is absent, never computing. The numbers come from the core
//! (`crate::review`, `crate::detect::inspect`); this module only arranges them and
//! makes textures.

use super::jobs::JobScope;
use super::{FieldShow, FieldSource, JobOutput, StudioApp, SweepAxis, View};
use crate::detect::Detection;
use crate::detect::inspect::SquareInspection;
use crate::kernel::file::{KernelSample, KernelsFile};
use crate::model::Dataset;
use crate::model::KernelModel;
use crate::plane::{Capture, Channel, LensSetting, Plane};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Mtf50, Mtf50Record};
use crate::review::{
    FieldDifference, KernelError, PlotTable, ShootingAdvice, SquareFacts, SweepPoint,
};
use crate::session::ShotId;
use crate::simulate::VirtualLens;
use std::sync::Arc;

/// Grid of the predicted and true fields.
const FIELD_GRID: (usize, usize) = (12, 8);

/// Points on each model and truth curve of the sweeps.
const CURVE_STEPS: usize = 40;

/// The sensor locations the sweeps follow: name and position as fractions of the
/// sensor's width and height (the Sweeps view gives each its colour, in this order).
pub const SWEEP_LOCATIONS: [(&str, f64, f64); 5] = [
    ("centre", 0.5, 0.5),
    ("top-left", 0.15, 0.15),
    ("top-right", 0.85, 0.15),
    ("bottom-left", 0.15, 0.85),
    ("bottom-right", 0.85, 0.85),
];

/// An `Arc`'s identity as part of a cache key. The key holds the `Arc`, so the value
/// stays alive and an equal pointer always means the same value.
pub struct Same<T>(Option<Arc<T>>);

impl<T> Same<T> {
    fn of(v: Option<&Arc<T>>) -> Self {
        Self(v.cloned())
    }
}

impl<T> Clone for Same<T> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

impl<T> PartialEq for Same<T> {
    fn eq(&self, other: &Self) -> bool {
        match (&self.0, &other.0) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (None, None) => true,
            _ => false,
        }
    }
}

impl<T> std::fmt::Debug for Same<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            Some(a) => write!(f, "Same({:p})", Arc::as_ptr(a)),
            None => write!(f, "Same(none)"),
        }
    }
}

/// Every view's cached data.
#[derive(Default)]
pub struct ViewData {
    pub shot_plane: Option<ShotPlane>,
    pub kernel_atlas: Option<KernelAtlas>,
    pub field: Option<FieldData>,
    pub sweeps: Option<SweepData>,
    pub inspection: Option<Inspecting>,
    /// The session's settings with shots and what they allow the model.
    pub calibrated: Option<Calibrated>,
}

/// The focal lengths and f-numbers the session has shots at (sorted, distinct), marked
/// on the sliders and the sweeps, and what they allow the model (the Models and Sweeps
/// views' warnings).
pub struct Calibrated {
    pub focal_mm: Vec<f64>,
    pub f_number: Vec<f64>,
    pub advice: Vec<ShootingAdvice>,
}

/// How the Kernel field view colours its squares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColourRange {
    /// From the smallest to the largest value shown (over every panel, so compared
    /// fields share one scale).
    Data,
    /// A range the user set (σ, px), kept across shots and settings so that fields
    /// compare by eye.
    Fixed { min: f64, max: f64 },
}

/// The difference maps of the Kernel field view: σ(A) − σ(B) at each square.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Difference {
    /// The selected shot's measured Gaussians − the profile's prediction there, at the
    /// shot's setting.
    MeasuredMinusPredicted,
    /// Unit A − unit B: the profile − the second profile loaded, else the demo lens −
    /// its second unit, at the sliders' setting.
    UnitAMinusB,
    /// Channel R − channel B of the source shown (lateral colour, in blur).
    RedMinusBlue,
}

/// The Kernel field view's colouring choices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldOptions {
    pub range: ColourRange,
    /// A difference map instead of the fields, or `None`.
    pub difference: Option<Difference>,
}

impl Default for FieldOptions {
    fn default() -> Self {
        Self {
            range: ColourRange::Data,
            difference: None,
        }
    }
}

/// The colour scale of the Kernel field view's panels: the value range the palette
/// spans (values outside take its ends), whether it is the diverging one (blue, white
/// at 0, red), the bar's title and its ticks.
#[derive(Clone, Debug, PartialEq)]
pub struct ColourScale {
    pub range: [f64; 2],
    pub diverging: bool,
    pub title: String,
    pub ticks: Vec<f64>,
}

impl ColourScale {
    /// Where `v` lies on the scale, 0 to 1 (clamped).
    #[must_use]
    pub fn position(&self, v: f64) -> f32 {
        let [lo, hi] = self.range;
        (((v - lo) / (hi - lo).max(1e-12)).clamp(0.0, 1.0)) as f32
    }
}

impl ViewData {
    /// The inspector's square once its crops are ready.
    #[must_use]
    pub fn inspection(&self) -> Option<&Inspection> {
        match &self.inspection {
            Some(Inspecting::Ready(i)) => Some(i),
            _ => None,
        }
    }
}

/// Which plane of the selected shot the viewer maps onto the sensor (its step and
/// offset) and reads hovered values from: the channel's first plane (G1 for a Bayer
/// G), else the capture's first.
pub struct ShotPlane {
    key: (ShotId, Channel, Same<Capture>),
    /// Index into the capture's planes.
    pub index: Option<usize>,
}

impl ShotPlane {
    #[must_use]
    pub fn shot(&self) -> ShotId {
        self.key.0
    }
}

/// Kernels packed into one texture for the Kernel field view, measured (one shot and
/// channel) or predicted (the profile's, at the measured squares of the selected shot
/// or on the field grid): each cell holds the central ±`extent_px` of one kernel,
/// scaled to its peak.
pub struct KernelAtlas {
    key: AtlasKey,
    pub texture: egui::TextureHandle,
    pub cells: Vec<AtlasCell>,
    /// Half the side every cell shows, sensor px.
    pub extent_px: f64,
    /// The model of a predicted atlas; `None` for measured kernels.
    pub model: Option<KernelModel>,
    /// Why a predicted atlas holds no kernel (the profile cannot predict there).
    pub error: Option<String>,
    /// Why the profile of a predicted atlas holds no shape model.
    pub no_shape: Option<String>,
}

/// One kernel of an atlas.
#[derive(Clone, Copy, Debug)]
pub struct AtlasCell {
    /// Sensor position.
    pub x: f64,
    pub y: f64,
    /// The Gaussian whose σ tints its tile (measured fit or predicted).
    pub gaussian: Gaussian2,
    /// The selected shot's kernels-file sample on that square, where it sits on one.
    pub sample: Option<usize>,
    /// Its cell's UV rectangle in the texture.
    pub uv: egui::Rect,
}

#[derive(Clone, Debug, PartialEq)]
enum AtlasKey {
    Measured {
        shot: ShotId,
        channel: Channel,
        file: Same<KernelsFile>,
    },
    Predicted {
        profile: Same<Profile>,
        file: Same<KernelsFile>,
        channel: Channel,
        setting: [f64; 2],
        size: (usize, usize),
    },
}

/// What one panel of the Kernel field view draws.
pub enum PanelContent {
    Ellipses(Vec<(f64, f64, Gaussian2)>),
    /// Kernels of the atlas (measured or predicted), every cell ±`extent_px` around its
    /// kernel's centre, drawn a fraction of the chart's square pitch wide.
    Kernels {
        cells: Vec<AtlasCell>,
        extent_px: f64,
        pitch_px: f64,
    },
    /// A difference map: one tile per point, `pitch_px` apart, coloured by σ(A) − σ(B).
    Difference {
        points: Vec<FieldDifference>,
        pitch_px: f64,
    },
}

/// Whose field a panel shows (the view names it).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PanelOf {
    /// The selected shot's measured kernels.
    Measured,
    /// The profile in use, or `NoProfile` when there is none.
    Profile,
    NoProfile,
    /// The second profile loaded to compare.
    CompareProfile,
    /// The demo lens, or its second unit.
    Truth {
        second_unit: bool,
    },
    /// A difference map, with the names of its two fields (A − B).
    Difference {
        of: Difference,
        a: String,
        b: String,
    },
}

/// What hovering a drawn Gaussian shows: its position, its Gaussian (C_xx, C_yy,
/// C_or), σ = √(C_xx·C_yy) and MTF50; what colours it; the chart square it was
/// measured on (a click opens the square's inspector) and why its kernel is not to be
/// trusted.
pub struct FieldPoint {
    pub x: f64,
    pub y: f64,
    pub gaussian: Gaussian2,
    pub sigma: f64,
    /// The value the colour shows: σ, or σ(A) − σ(B) on a difference map.
    pub value: f64,
    /// On a difference map: field B's Gaussian there (A's is `gaussian`).
    pub other: Option<Gaussian2>,
    /// The selected shot's chart square (row, col) it sits on.
    pub square: Option<(usize, usize)>,
    /// Why the measured kernel here is flagged as noisy
    /// ([`crate::review::noisy_kernel_reason`]).
    pub noisy: Option<String>,
    /// In cycles/px and line pairs per picture height of the sensor shown; absent for a
    /// degenerate Gaussian.
    pub mtf50: Option<Mtf50Record>,
    /// The profile's predicted kernels against the measured kernel on this square, where
    /// both exist.
    pub kernel_error: Option<KernelError>,
}

pub struct FieldPanel {
    pub of: PanelOf,
    pub content: Result<PanelContent, String>,
    /// Every drawn Gaussian's hover facts, made once with the panel.
    pub points: Vec<FieldPoint>,
    /// Squares where no kernel could be measured (sensor px), with the reason.
    pub failed: Vec<(f64, f64, String)>,
    /// Per sample of the selected shot's kernels file: the profile's predicted kernel
    /// errors there (empty without a profile or measured kernels).
    pub errors: Vec<Option<KernelError>>,
    /// Per drawn point, the selected shot's kernels-file sample it shows, where it
    /// sits on one (its square, its noise flag).
    pub samples: Vec<Option<usize>>,
}

/// What the Kernel field view's panels depend on, per source.
#[derive(Clone, Debug, PartialEq)]
enum FieldKey {
    Measured {
        shot: Option<ShotId>,
        file: Same<KernelsFile>,
        channel: Channel,
        show: FieldShow,
        size: (usize, usize),
        chart_cols: usize,
        /// The atlas the kernel cells point into.
        atlas: bool,
        /// The profile whose predicted kernels the hover compares.
        profile: Same<Profile>,
    },
    Predicted {
        profile: Same<Profile>,
        compare: Same<Profile>,
        channel: Channel,
        setting: [f64; 2],
        size: (usize, usize),
        show: FieldShow,
        /// The selected shot's kernels: where predicted kernels are drawn, and what
        /// they are compared with.
        file: Same<KernelsFile>,
        chart_cols: usize,
        atlas: bool,
    },
    Truth {
        is_demo: bool,
        compare_units: bool,
        channel: Channel,
        setting: [f64; 2],
        size: (usize, usize),
    },
}

/// The Kernel field view's panels.
pub struct FieldData {
    key: (FieldKey, FieldExtra),
    pub panels: Vec<FieldPanel>,
    /// The largest 1-σ radius over every panel, so compared fields share one
    /// magnification.
    pub max_sigma: f64,
    /// One colour scale for every panel; `None` with nothing drawn.
    pub scale: Option<ColourScale>,
    /// How many drawn kernels are flagged as noisy.
    pub noisy: usize,
}

/// What the colouring and the difference maps add to a field's key.
#[derive(Clone, Debug, PartialEq)]
struct FieldExtra {
    options: FieldOptions,
    compare: Same<Profile>,
    profile: Same<Profile>,
    is_demo: bool,
    setting: [f64; 2],
}

/// One location's series in one sweep.
pub struct LocationSweep {
    /// Measured at the square nearest the location (absent without measurements).
    pub measured: Option<Vec<(SweepPoint, Option<Mtf50>)>>,
    /// The profile's model at that square (absent without a profile).
    pub model: Option<Vec<CurvePoint>>,
    /// The demo lens's truth at that square (demo sessions only).
    pub truth: Option<Vec<CurvePoint>>,
}

/// One point of a model or truth curve, with the MTF50 of its Gaussian (absent for a
/// degenerate one).
pub type CurvePoint = (LensSetting, Gaussian2, Option<Mtf50>);

fn with_mtf50(curve: Vec<(LensSetting, Gaussian2)>) -> Vec<CurvePoint> {
    curve.into_iter().map(|(s, g)| (s, g, g.mtf50())).collect()
}

#[derive(Clone, Debug, PartialEq)]
struct SweepKey {
    dataset: Same<Dataset>,
    profile: Same<Profile>,
    is_demo: bool,
    channel: Channel,
    setting: [f64; 2],
    ranges: ([f64; 2], [f64; 2]),
    size: (usize, usize),
}

/// The Sweeps view's series.
pub struct SweepData {
    key: SweepKey,
    /// The focal length the aperture sweep holds (the measured one nearest the
    /// slider), and the aperture the focal-length sweep holds.
    pub fixed_f: f64,
    pub fixed_a: f64,
    /// Against aperture, then against focal length; one entry per
    /// [`SWEEP_LOCATIONS`].
    pub sweeps: [Vec<LocationSweep>; 2],
}

/// A parameter the Sweeps view plots: its name, its unit and how to read it from a
/// Gaussian and its MTF50 (NaN, left out of the plot, where a degenerate Gaussian has
/// no MTF50).
#[derive(Clone, Copy)]
pub struct SweepParam {
    pub name: &'static str,
    pub unit: &'static str,
    pub get: fn(&Gaussian2, Option<&Mtf50>) -> f64,
}

/// The three plots of each sweep for an axis choice, in the view's order.
#[must_use]
pub fn sweep_params(axis: SweepAxis) -> [SweepParam; 3] {
    let p = |name, unit, get| SweepParam { name, unit, get };
    match axis {
        SweepAxis::Sigma => [
            p("C_xx", "σ, px", |g, _| g.sigma_x),
            p("C_yy", "σ, px", |g, _| g.sigma_y),
            p("C_or", "ρ", |g, _| g.rho),
        ],
        SweepAxis::Mtf50 => [
            p("MTF50 worst", "cycles/px", |_, m| {
                m.map_or(f64::NAN, |m| m.worst)
            }),
            p("MTF50 best", "cycles/px", |_, m| {
                m.map_or(f64::NAN, |m| m.best)
            }),
            p("MTF50 isotropic", "cycles/px", |_, m| {
                m.map_or(f64::NAN, |m| m.isotropic)
            }),
        ],
    }
}

/// What a sweep series is: drawn as dots, a solid line or a dashed line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SweepKind {
    Measured,
    Model,
    Truth,
}

/// One series of one sweep plot, for the index of its location in [`SWEEP_LOCATIONS`].
pub struct SweepSeries {
    pub location: usize,
    pub kind: SweepKind,
    pub name: String,
    pub points: Vec<[f64; 2]>,
}

/// The x axis's title of the sweep against aperture, or against focal length.
#[must_use]
pub fn sweep_x_label(vs_aperture: bool) -> &'static str {
    if vs_aperture {
        "aperture (f-number)"
    } else {
        "focal length (mm)"
    }
}

/// The y axis's title of a sweep plot.
#[must_use]
pub fn sweep_y_label(param: &SweepParam) -> String {
    format!("{} ({})", param.name, param.unit)
}

/// The series one sweep plot draws, in drawing order: per location, the measured
/// points, the model and the truth (those that exist).
#[must_use]
pub fn sweep_series(data: &SweepData, vs_aperture: bool, param: &SweepParam) -> Vec<SweepSeries> {
    let sweep = &data.sweeps[usize::from(!vs_aperture)];
    let abscissa = |s: LensSetting| if vs_aperture { s.f_number } else { s.focal_mm };
    let get = param.get;
    let curve = |c: &[CurvePoint]| -> Vec<[f64; 2]> {
        c.iter()
            .map(|(s, g, m)| [abscissa(*s), get(g, m.as_ref())])
            .collect()
    };
    let mut out = Vec::new();
    for (location, ((loc, _, _), series)) in SWEEP_LOCATIONS.iter().zip(sweep).enumerate() {
        if let Some(m) = &series.measured {
            out.push(SweepSeries {
                location,
                kind: SweepKind::Measured,
                name: format!("measured {loc}"),
                points: m
                    .iter()
                    .map(|(p, m)| [abscissa(p.setting), get(&p.gaussian, m.as_ref())])
                    .collect(),
            });
        }
        for (kind, c) in [
            (SweepKind::Model, &series.model),
            (SweepKind::Truth, &series.truth),
        ] {
            if let Some(c) = c {
                let what = if kind == SweepKind::Model {
                    "model"
                } else {
                    "truth"
                };
                out.push(SweepSeries {
                    location,
                    kind,
                    name: format!("{what} {loc}"),
                    points: curve(c),
                });
            }
        }
    }
    out
}

/// One sweep plot's data, as drawn, for saving as CSV.
#[must_use]
pub fn sweep_table(
    data: &SweepData,
    axis: SweepAxis,
    vs_aperture: bool,
    param: usize,
) -> Option<PlotTable> {
    let param = sweep_params(axis).get(param).copied()?;
    Some(PlotTable {
        x_label: sweep_x_label(vs_aperture).to_owned(),
        y_label: sweep_y_label(&param),
        series: sweep_series(data, vs_aperture, &param)
            .into_iter()
            .map(|s| (s.name, s.points))
            .collect(),
    })
}

/// Which square's inspection, of what: results for another key are stale.
#[derive(Clone, Debug, PartialEq)]
pub struct InspectKey {
    pub session: u64,
    pub shot: ShotId,
    pub square: (usize, usize),
    pub channel: Channel,
    detection: Same<Detection>,
}

/// The inspector's state for the selected square.
pub enum Inspecting {
    /// The crops are being made on a job thread.
    Running(InspectKey),
    Ready(Box<Inspection>),
    /// The square has no crop in this channel.
    Empty(InspectKey),
}

impl Inspecting {
    #[must_use]
    pub fn key(&self) -> &InspectKey {
        match self {
            Inspecting::Running(k) | Inspecting::Empty(k) => k,
            Inspecting::Ready(i) => &i.key,
        }
    }
}

/// What an inspection job hands back: the crops, the square's numbers and the crops'
/// grey images (textures are made from them on the UI thread).
pub struct InspectedSquare {
    pub crops: SquareInspection,
    pub facts: Option<SquareFacts>,
    pub images: [egui::ColorImage; 3],
}

/// What the kernel texture and the truth beside it depend on.
#[derive(Clone, Debug, PartialEq)]
struct DetailsKey {
    file: Same<KernelsFile>,
    setting: Option<LensSetting>,
    is_demo: bool,
}

/// The inspector's square: which one, its crops and their textures (observed,
/// synthetic, residual), its measured kernel's texture and, on the demo session, the
/// lens's true Gaussian at its centre.
pub struct Inspection {
    key: InspectKey,
    pub shot: ShotId,
    pub square: (usize, usize),
    pub channel: Channel,
    pub crops: SquareInspection,
    pub facts: Option<SquareFacts>,
    pub textures: [egui::TextureHandle; 3],
    details: Option<DetailsKey>,
    pub kernel: Option<egui::TextureHandle>,
    pub truth: Option<Gaussian2>,
}

/// Recomputes what is stale; called once per frame after commands and job results.
pub(super) fn refresh(app: &mut StudioApp) {
    refresh_shot_plane(app);
    refresh_calibrated(app);
    refresh_inspection(app);
    match app.view {
        View::KernelField => {
            refresh_kernel_atlas(app);
            refresh_field(app);
        }
        View::Sweeps => refresh_sweeps(app),
        View::Shot | View::Models | View::Deblur => {}
    }
}

/// The sensor the views draw on: the selected shot's, else the measurements', else the
/// demo's.
pub(crate) fn sensor_size(app: &StudioApp) -> (usize, usize) {
    if let Some(p) = app.selected_shot.and_then(|i| app.previews.get(&i)) {
        return (p.capture.width, p.capture.height);
    }
    if let Some(d) = app.dataset.as_ref() {
        return (d.width, d.height);
    }
    (app.options.demo_spec.width, app.options.demo_spec.height)
}

/// Focal length and aperture ranges the sliders span: the profile's calibrated ones,
/// else the session's, else the demo lens's.
pub(crate) fn setting_ranges(app: &StudioApp, lens: &VirtualLens) -> ([f64; 2], [f64; 2]) {
    if let Some((_, p)) = &app.profile {
        return (p.norm.focal_range_mm, p.norm.f_number_range);
    }
    if let Some(s) = &app.session {
        let (f, a) = s.setting_grid();
        if let (Some(f0), Some(f1), Some(a0), Some(a1)) = (f.first(), f.last(), a.first(), a.last())
            && f1 > f0
            && a1 > a0
        {
            return ([*f0, *f1], [*a0, *a1]);
        }
    }
    (lens.focal_range_mm, lens.f_number_range)
}

/// The settings with shots and the core's advice on them: a few dozen values, cheaper
/// to remake each frame than to key.
fn refresh_calibrated(app: &mut StudioApp) {
    app.views.calibrated = app.session.as_ref().map(|s| {
        let (focal_mm, f_number) = s.setting_grid();
        let advice = crate::review::shooting_advice(&focal_mm, &f_number, s.settings.beta);
        Calibrated {
            focal_mm,
            f_number,
            advice,
        }
    });
}

fn is_demo(app: &StudioApp) -> bool {
    app.session.as_ref().is_some_and(|s| s.is_demo)
}

fn refresh_shot_plane(app: &mut StudioApp) {
    let Some((shot, preview)) = app
        .selected_shot
        .and_then(|id| Some((id, app.previews.get(&id)?)))
    else {
        app.views.shot_plane = None;
        return;
    };
    let key = (shot, app.channel, Same::of(Some(&preview.capture)));
    if app.views.shot_plane.as_ref().is_some_and(|p| p.key == key) {
        return;
    }
    let planes = &preview.capture.planes;
    let index = planes
        .iter()
        .position(|p| p.channel == app.channel)
        .or_else(|| (!planes.is_empty()).then_some(0));
    app.views.shot_plane = Some(ShotPlane { key, index });
}

/// The kernels the Kernel field view shows as shapes, packed into one texture: the
/// selected shot's measured ones, or the profile's predicted ones in its recommended
/// model at that shot's measured squares (else on the field grid), so the two compare
/// cell for cell.
fn refresh_kernel_atlas(app: &mut StudioApp) {
    if app.field_show != FieldShow::Kernels || app.field_source == FieldSource::Truth {
        return;
    }
    let channel = app.channel;
    let file = app.selected_shot.and_then(|i| app.measured.get(&i));
    let key = match app.field_source {
        FieldSource::Predicted => {
            let Some((_, profile)) = &app.profile else {
                app.views.kernel_atlas = None;
                return;
            };
            AtlasKey::Predicted {
                profile: Same::of(Some(profile)),
                file: Same::of(file),
                channel,
                setting: [app.field_focal_mm, app.field_f_number],
                size: sensor_size(app),
            }
        }
        _ => {
            let Some(shot) = app.selected_shot else {
                app.views.kernel_atlas = None;
                return;
            };
            AtlasKey::Measured {
                shot,
                channel,
                file: Same::of(file),
            }
        }
    };
    if app
        .views
        .kernel_atlas
        .as_ref()
        .is_some_and(|a| a.key == key)
    {
        return;
    }
    app.views.kernel_atlas = None;
    fn channel_samples(f: &KernelsFile, channel: Channel) -> Vec<(usize, &KernelSample)> {
        f.samples
            .iter()
            .enumerate()
            .filter(|(_, s)| s.channel == channel)
            .collect()
    }
    let (kernels, max_sigma, model, error) = match &key {
        AtlasKey::Measured { .. } => {
            let Some(file) = file else {
                return;
            };
            let samples = channel_samples(file, channel);
            let kernels: Vec<_> = samples
                .iter()
                .filter_map(|&(i, s)| {
                    let g = Gaussian2 {
                        sigma_x: s.cxx.unwrap_or(1.0),
                        sigma_y: s.cyy.unwrap_or(1.0),
                        rho: s.cor.unwrap_or(0.0),
                    };
                    Some((s.x, s.y, g, Some(i), s.kernel_at(file.oversample)?))
                })
                .collect();
            if kernels.is_empty() {
                return;
            }
            let max_sigma = samples
                .iter()
                .filter_map(|(_, s)| Some(s.cxx?.max(s.cyy?)))
                .fold(0.5, f64::max);
            (kernels, max_sigma, None, None)
        }
        AtlasKey::Predicted { size, .. } => {
            let Some((_, profile)) = &app.profile else {
                return;
            };
            let model = profile.kernel_model();
            let (points, samples): (Vec<[f64; 2]>, Vec<Option<usize>>) = match file {
                Some(f) if f.samples.iter().any(|s| s.channel == channel) => {
                    channel_samples(f, channel)
                        .into_iter()
                        .map(|(i, s)| ([s.x, s.y], Some(i)))
                        .unzip()
                }
                _ => crate::review::field_grid(size.0, size.1, FIELD_GRID.0, FIELD_GRID.1)
                    .into_iter()
                    .map(|p| (p, None))
                    .unzip(),
            };
            let setting = LensSetting {
                focal_mm: app.field_focal_mm,
                f_number: app.field_f_number,
            };
            match crate::review::predicted_kernels(profile, model, channel, &points, setting) {
                Ok(predicted) => {
                    let max_sigma = predicted
                        .iter()
                        .map(|k| k.gaussian.sigma_x.max(k.gaussian.sigma_y))
                        .fold(0.5, f64::max);
                    let kernels = predicted
                        .into_iter()
                        .zip(samples)
                        .map(|(k, i)| (k.x, k.y, k.gaussian, i, k.kernel))
                        .collect();
                    (kernels, max_sigma, Some(model), None)
                }
                Err(e) => (Vec::new(), 0.5, Some(model), Some(e)),
            }
        }
    };
    let mut atlas = pack_atlas(&app.ctx, key, &kernels, max_sigma, model, error);
    if model.is_some() {
        atlas.no_shape = app
            .profile
            .as_ref()
            .and_then(|(_, p)| crate::review::no_shape_reason(p));
    }
    app.views.kernel_atlas = Some(atlas);
}

/// Packs kernels into one texture: the central ±R px of each (R = 2.5 × `max_sigma`,
/// the largest σ of the field, so every kernel shows the same extent and shapes
/// compare), each scaled to its own peak (σ is in the tint).
fn pack_atlas(
    ctx: &egui::Context,
    key: AtlasKey,
    kernels: &[(f64, f64, Gaussian2, Option<usize>, crate::psf::Kernel)],
    max_sigma: f64,
    model: Option<KernelModel>,
    error: Option<String>,
) -> KernelAtlas {
    let extent_px = (2.5 * max_sigma).max(2.0);
    let os = kernels.first().map_or(3, |k| k.4.oversample.max(1));
    let half = (extent_px * os as f64).ceil() as usize;
    let cell = 2 * half + 1;
    let per_row = (kernels.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = kernels.len().div_ceil(per_row).max(1);
    let (w, h) = (per_row * cell, rows * cell);
    let mut img = egui::ColorImage::filled([w, h], egui::Color32::TRANSPARENT);
    let mut cells = Vec::with_capacity(kernels.len());
    for (n, (x, y, gaussian, sample, k)) in kernels.iter().enumerate() {
        let (cx, cy) = ((n % per_row) * cell, (n / per_row) * cell);
        let c = (k.size / 2) as isize;
        let peak = k.data.iter().copied().fold(1e-12, f64::max);
        for j in 0..cell {
            for q in 0..cell {
                let (kx, ky) = (
                    c + q as isize - half as isize,
                    c + j as isize - half as isize,
                );
                if kx < 0 || ky < 0 || kx >= k.size as isize || ky >= k.size as isize {
                    continue;
                }
                let v = (k.at(kx as usize, ky as usize) / peak).clamp(0.0, 1.0);
                img[(cx + q, cy + j)] = egui::Color32::from_white_alpha((v * 255.0) as u8);
            }
        }
        let uv = egui::Rect::from_min_size(
            egui::Pos2::new(cx as f32 / w as f32, cy as f32 / h as f32),
            egui::Vec2::new(cell as f32 / w as f32, cell as f32 / h as f32),
        );
        cells.push(AtlasCell {
            x: *x,
            y: *y,
            gaussian: *gaussian,
            sample: *sample,
            uv,
        });
    }
    let texture = ctx.load_texture("kernel-atlas", img, egui::TextureOptions::NEAREST);
    KernelAtlas {
        key,
        texture,
        cells,
        extent_px: half as f64 / os as f64,
        model,
        error,
        no_shape: None,
    }
}

fn field_key(app: &StudioApp) -> FieldKey {
    let channel = app.channel;
    let size = sensor_size(app);
    let setting = [app.field_focal_mm, app.field_f_number];
    match app.field_source {
        FieldSource::Measured => FieldKey::Measured {
            shot: app.selected_shot,
            file: Same::of(app.selected_shot.and_then(|i| app.measured.get(&i))),
            channel,
            show: app.field_show,
            size,
            chart_cols: app.session.as_ref().map_or(10, |s| s.chart.cols),
            atlas: app.views.kernel_atlas.is_some(),
            profile: Same::of(app.profile.as_ref().map(|p| &p.1)),
        },
        FieldSource::Predicted => FieldKey::Predicted {
            profile: Same::of(app.profile.as_ref().map(|p| &p.1)),
            compare: Same::of(app.compare_profile.as_ref().map(|p| &p.1)),
            channel,
            setting,
            size,
            show: app.field_show,
            file: Same::of(app.selected_shot.and_then(|i| app.measured.get(&i))),
            chart_cols: app.session.as_ref().map_or(10, |s| s.chart.cols),
            atlas: app.views.kernel_atlas.is_some(),
        },
        FieldSource::Truth => FieldKey::Truth {
            is_demo: is_demo(app),
            compare_units: app.compare_units,
            channel,
            setting,
            size,
        },
    }
}

fn refresh_field(app: &mut StudioApp) {
    let key = (
        field_key(app),
        FieldExtra {
            options: app.field_options,
            compare: Same::of(app.compare_profile.as_ref().map(|p| &p.1)),
            profile: Same::of(app.profile.as_ref().map(|p| &p.1)),
            is_demo: is_demo(app),
            setting: [app.field_focal_mm, app.field_f_number],
        },
    );
    if app.views.field.as_ref().is_some_and(|f| f.key == key) {
        return;
    }
    let size = sensor_size(app);
    let file = app.selected_shot.and_then(|i| app.measured.get(&i));
    // Squares of the chart are about this far apart on the sensor.
    let pitch_px = size.0 as f64 / app.session.as_ref().map_or(12, |s| s.chart.cols + 2) as f64;
    let mut panels = match app.field_options.difference {
        Some(d) => vec![difference_panel(app, d, file, size, pitch_px)],
        None => value_panels(app, file, size, pitch_px),
    };
    // Each drawn point's hover facts and, on measured kernels, its square and whether
    // its kernel is too noisy to trust (the core's criterion).
    for panel in &mut panels {
        // Position, Gaussian (A's on a difference map), B's, the sample it shows.
        type Drawn = (f64, f64, Gaussian2, Option<Gaussian2>, Option<usize>);
        let drawn: Vec<Drawn> = match &panel.content {
            Ok(PanelContent::Ellipses(v)) => v
                .iter()
                .zip(panel.samples.iter().chain(std::iter::repeat(&None)))
                .map(|(&(x, y, g), &i)| (x, y, g, None, i))
                .collect(),
            Ok(PanelContent::Kernels { cells, .. }) => cells
                .iter()
                .map(|c| (c.x, c.y, c.gaussian, None, c.sample))
                .collect(),
            Ok(PanelContent::Difference { points, .. }) => points
                .iter()
                .map(|d| (d.x, d.y, d.a, Some(d.b), None))
                .collect(),
            Err(_) => Vec::new(),
        };
        let measured = panel.of == PanelOf::Measured;
        panel.points = drawn
            .into_iter()
            .map(|(x, y, g, other, sample)| {
                let s = sample.and_then(|i| file?.samples.get(i));
                FieldPoint {
                    x,
                    y,
                    gaussian: g,
                    sigma: g.sigma(),
                    value: other.map_or(g.sigma(), |b| g.sigma() - b.sigma()),
                    other,
                    mtf50: g.mtf50().map(|m| m.record(size.1)),
                    kernel_error: sample.and_then(|i| *panel.errors.get(i)?),
                    square: s.and_then(|s| Some((s.row?, s.col?))),
                    noisy: s.filter(|_| measured).and_then(|s| {
                        let k = s.kernel_at(file?.oversample)?;
                        crate::review::noisy_kernel_reason(&k, &g)
                    }),
                }
            })
            .collect();
    }
    let max_sigma = panels
        .iter()
        .flat_map(|p| &p.points)
        .map(|q| q.gaussian.sigma_x.max(q.gaussian.sigma_y))
        .fold(1e-6, f64::max);
    let diverging = app.field_options.difference.is_some();
    let range = match (app.field_options.range, diverging) {
        (ColourRange::Fixed { min, max }, false) if max > min => Some([min, max]),
        _ => crate::review::colour_range(
            panels.iter().flat_map(|p| &p.points).map(|q| q.value),
            diverging,
        ),
    };
    let scale = range.map(|range| ColourScale {
        range,
        diverging,
        title: if diverging {
            "Δσ, px (A − B)".to_owned()
        } else {
            "σ = √(C_xx·C_yy), px".to_owned()
        },
        ticks: crate::review::nice_ticks(range, 5),
    });
    let noisy = panels
        .iter()
        .flat_map(|p| &p.points)
        .filter(|q| q.noisy.is_some())
        .count();
    app.views.field = Some(FieldData {
        key,
        panels,
        max_sigma,
        scale,
        noisy,
    });
}

/// The selected shot's measured Gaussians of one channel, with each one's sample index.
fn measured_gaussians(file: &KernelsFile, ch: Channel) -> (Vec<(f64, f64, Gaussian2)>, Vec<usize>) {
    file.samples
        .iter()
        .enumerate()
        .filter(|(_, k)| k.channel == ch)
        .filter_map(|(i, k)| {
            Some((
                (
                    k.x,
                    k.y,
                    Gaussian2 {
                        sigma_x: k.cxx?,
                        sigma_y: k.cyy?,
                        rho: k.cor?,
                    },
                ),
                i,
            ))
        })
        .unzip()
}

/// The panels of the fields themselves (measured, predicted or true; one or two).
fn value_panels(
    app: &StudioApp,
    file: Option<&Arc<KernelsFile>>,
    size: (usize, usize),
    pitch_px: f64,
) -> Vec<FieldPanel> {
    let ch = app.channel;
    let s = LensSetting {
        focal_mm: app.field_focal_mm,
        f_number: app.field_f_number,
    };
    let panel = |of, content, errors| FieldPanel {
        of,
        content,
        points: Vec::new(),
        failed: Vec::new(),
        errors,
        samples: Vec::new(),
    };
    let mut panels = Vec::new();
    let errors = match (&app.profile, file, app.field_show) {
        (Some((_, p)), Some(f), FieldShow::Kernels) => crate::review::kernel_errors(p, f, ch),
        _ => Vec::new(),
    };
    let atlas_cells = |atlas: &KernelAtlas| -> Result<PanelContent, String> {
        match &atlas.error {
            Some(e) => Err(e.clone()),
            None => Ok(PanelContent::Kernels {
                cells: atlas.cells.clone(),
                extent_px: atlas.extent_px,
                pitch_px,
            }),
        }
    };
    match app.field_source {
        FieldSource::Measured => {
            let mut samples = Vec::new();
            let content = match (file, app.field_show) {
                (None, _) => Err(
                    "No kernels measured on this shot yet — press Kernels (Ctrl+K) after Detect."
                        .to_owned(),
                ),
                (Some(f), FieldShow::Ellipses) => {
                    let (g, i) = measured_gaussians(f, ch);
                    samples = i.into_iter().map(Some).collect();
                    Ok(PanelContent::Ellipses(g))
                }
                (Some(_), FieldShow::Kernels) => match &app.views.kernel_atlas {
                    Some(atlas) if atlas.model.is_none() => atlas_cells(atlas),
                    _ => Err("This kernels file holds Gaussians only, no kernel arrays.".into()),
                },
            };
            let failed = file.map_or_else(Vec::new, |f| {
                f.failed
                    .iter()
                    .filter(|k| k.channel == ch)
                    .map(|k| (k.x, k.y, k.reason.clone()))
                    .collect()
            });
            panels.push(FieldPanel {
                failed,
                samples,
                ..panel(PanelOf::Measured, content, errors)
            });
        }
        FieldSource::Predicted => {
            let predicted = |p: &Profile| {
                crate::review::predicted_field(p, ch, size, FIELD_GRID, s)
                    .map(PanelContent::Ellipses)
            };
            panels.push(match &app.profile {
                Some((_, p)) => panel(
                    PanelOf::Profile,
                    match (app.field_show, &app.views.kernel_atlas) {
                        (FieldShow::Kernels, Some(atlas)) if atlas.model.is_some() => {
                            atlas_cells(atlas)
                        }
                        _ => predicted(p),
                    },
                    errors,
                ),
                None => panel(
                    PanelOf::NoProfile,
                    Err("No profile yet: Calibrate (Ctrl+M) or load one in Models.".into()),
                    Vec::new(),
                ),
            });
            // The one atlas is the profile's: a second profile compares as ellipses.
            if let Some((_, p)) = &app.compare_profile {
                panels.push(panel(PanelOf::CompareProfile, predicted(p), Vec::new()));
            }
        }
        FieldSource::Truth => {
            if is_demo(app) {
                let mut units = vec![(false, VirtualLens::demo())];
                if app.compare_units {
                    units.push((true, VirtualLens::demo_second_unit()));
                }
                for (second_unit, lens) in units {
                    panels.push(panel(
                        PanelOf::Truth { second_unit },
                        Ok(PanelContent::Ellipses(crate::review::truth_field(
                            &lens, ch, size, FIELD_GRID, s,
                        ))),
                        Vec::new(),
                    ));
                }
            }
        }
    }
    panels
}

/// The one panel of a difference map: A − B, each field as the core makes it, paired
/// square by square; or why this map cannot be made here.
fn difference_panel(
    app: &StudioApp,
    d: Difference,
    file: Option<&Arc<KernelsFile>>,
    size: (usize, usize),
    pitch_px: f64,
) -> FieldPanel {
    let ch = app.channel;
    let setting = LensSetting {
        focal_mm: app.field_focal_mm,
        f_number: app.field_f_number,
    };
    let grid_pitch = size.0 as f64 / FIELD_GRID.0 as f64;
    let no_kernels = || {
        "No kernels measured on the selected shot yet — press Kernels (Ctrl+K) after Detect."
            .to_owned()
    };
    type Field = Vec<(f64, f64, Gaussian2)>;
    let made: Result<(Field, Field, f64, String, String), String> = match d {
        Difference::MeasuredMinusPredicted => (|| {
            let f = file.ok_or_else(no_kernels)?;
            let (_, p) = app
                .profile
                .as_ref()
                .ok_or("No profile yet: Calibrate (Ctrl+M) or load one in Models.")?;
            let shot_setting = match (f.focal_mm, f.f_number) {
                (Some(focal_mm), Some(f_number)) => LensSetting { focal_mm, f_number },
                _ => return Err("The selected shot has no focal length and aperture: the profile cannot predict it.".to_owned()),
            };
            let (a, _) = measured_gaussians(f, ch);
            let points: Vec<[f64; 2]> = a.iter().map(|&(x, y, _)| [x, y]).collect();
            let b = crate::review::predicted_at(p, ch, &points, shot_setting)?;
            Ok((
                a,
                b,
                pitch_px,
                format!("measured ({:.0} mm f/{:.1})", shot_setting.focal_mm, shot_setting.f_number),
                "the profile's prediction there".to_owned(),
            ))
        })(),
        Difference::UnitAMinusB => match (&app.profile, &app.compare_profile) {
            (Some((pa, a)), Some((pb, b))) => (|| {
                Ok((
                    crate::review::predicted_field(a, ch, size, FIELD_GRID, setting)?,
                    crate::review::predicted_field(b, ch, size, FIELD_GRID, setting)?,
                    grid_pitch,
                    app.shown_path(pa),
                    app.shown_path(pb),
                ))
            })(),
            _ if is_demo(app) => {
                let (a, b) = (VirtualLens::demo(), VirtualLens::demo_second_unit());
                Ok((
                    crate::review::truth_field(&a, ch, size, FIELD_GRID, setting),
                    crate::review::truth_field(&b, ch, size, FIELD_GRID, setting),
                    grid_pitch,
                    format!("{} {}", a.model, a.serial),
                    format!("{} {}", b.model, b.serial),
                ))
            }
            _ => Err("Unit A − unit B needs a second unit: load a second profile (Predicted → Compare with a second profile…), or open the demo session.".to_owned()),
        },
        Difference::RedMinusBlue => {
            let of = |c: Channel| -> Result<Field, String> {
                match app.field_source {
                    FieldSource::Measured => file
                        .map(|f| measured_gaussians(f, c).0)
                        .ok_or_else(no_kernels),
                    FieldSource::Predicted => match &app.profile {
                        Some((_, p)) => crate::review::predicted_field(p, c, size, FIELD_GRID, setting),
                        None => Err("No profile yet: Calibrate (Ctrl+M) or load one in Models.".into()),
                    },
                    FieldSource::Truth if is_demo(app) => Ok(crate::review::truth_field(
                        &VirtualLens::demo(),
                        c,
                        size,
                        FIELD_GRID,
                        setting,
                    )),
                    FieldSource::Truth => Err("Ground truth exists only for the demo session's simulated lens.".into()),
                }
            };
            let pitch = if app.field_source == FieldSource::Measured {
                pitch_px
            } else {
                grid_pitch
            };
            (|| Ok((of(Channel::R)?, of(Channel::B)?, pitch, "channel R".to_owned(), "channel B".to_owned())))()
        }
    };
    let (content, of) = match made {
        Ok((a, b, pitch, name_a, name_b)) => (
            Ok(PanelContent::Difference {
                // Pairs lie on the same square (or grid point): within half a pitch.
                points: crate::review::field_difference(&a, &b, 0.5 * pitch),
                pitch_px: pitch,
            }),
            PanelOf::Difference {
                of: d,
                a: name_a,
                b: name_b,
            },
        ),
        Err(e) => (
            Err(e),
            PanelOf::Difference {
                of: d,
                a: String::new(),
                b: String::new(),
            },
        ),
    };
    FieldPanel {
        of,
        content,
        points: Vec::new(),
        failed: Vec::new(),
        errors: Vec::new(),
        samples: Vec::new(),
    }
}

fn refresh_sweeps(app: &mut StudioApp) {
    let lens = VirtualLens::demo();
    let key = SweepKey {
        dataset: Same::of(app.dataset.as_ref()),
        profile: Same::of(app.profile.as_ref().map(|p| &p.1)),
        is_demo: is_demo(app),
        channel: app.channel,
        setting: [app.field_focal_mm, app.field_f_number],
        ranges: setting_ranges(app, &lens),
        size: sensor_size(app),
    };
    if app.views.sweeps.as_ref().is_some_and(|s| s.key == key) {
        return;
    }
    let ch = key.channel;
    let (w, h) = key.size;
    let (f_range, a_range) = key.ranges;
    let (focals, apertures) = app
        .dataset
        .as_ref()
        .map(|d| d.distinct_settings())
        .unwrap_or_default();
    // Measured points only exist at shot settings: the sweep holds the other setting at
    // the calibrated value nearest the slider.
    let fixed_f =
        crate::review::nearest_value(&focals, app.field_focal_mm).unwrap_or(app.field_focal_mm);
    let fixed_a =
        crate::review::nearest_value(&apertures, app.field_f_number).unwrap_or(app.field_f_number);
    let sweep = |vs_aperture: bool| -> Vec<LocationSweep> {
        let settings = if vs_aperture {
            crate::review::sweep_settings(a_range, fixed_f, true, CURVE_STEPS)
        } else {
            crate::review::sweep_settings(f_range, fixed_a, false, CURVE_STEPS)
        };
        let fixed = if vs_aperture { fixed_f } else { fixed_a };
        SWEEP_LOCATIONS
            .iter()
            .map(|&(_, fx, fy)| {
                let nominal = (fx * (w as f64 - 1.0), fy * (h as f64 - 1.0));
                let measured = app.dataset.as_ref().map(|ds| {
                    crate::review::sweep_points(ds, ch, nominal, vs_aperture, fixed)
                        .into_iter()
                        .map(|p| {
                            let m = p.gaussian.mtf50();
                            (p, m)
                        })
                        .collect::<Vec<_>>()
                });
                // Curves where the points were measured (the square nearest the
                // location), so the two compare.
                let at = measured
                    .as_ref()
                    .and_then(|m| m.first())
                    .map_or(nominal, |(p, _)| (p.x, p.y));
                LocationSweep {
                    model: app
                        .profile
                        .as_ref()
                        .map(|(_, p)| with_mtf50(crate::review::model_curve(p, ch, at, &settings))),
                    truth: key.is_demo.then(|| {
                        with_mtf50(crate::review::truth_curve(&lens, ch, at, (w, h), &settings))
                    }),
                    measured,
                }
            })
            .collect()
    };
    let sweeps = [sweep(true), sweep(false)];
    app.views.sweeps = Some(SweepData {
        key,
        fixed_f,
        fixed_a,
        sweeps,
    });
}

/// The inspection the selection asks for, if the shot is loaded and detected and has
/// that square: in the selected channel, else the capture's first.
fn wanted_inspection(app: &StudioApp) -> Option<InspectKey> {
    let (shot, square) = (app.selected_shot?, app.selected_square?);
    let preview = app.previews.get(&shot)?;
    let det = app.detections.get(&shot)?;
    app.session.as_ref()?;
    if !det.squares.iter().any(|s| (s.row, s.col) == square) {
        return None;
    }
    let planes = &preview.capture.planes;
    let channel = if planes.iter().any(|p| p.channel == app.channel) {
        app.channel
    } else {
        planes.first()?.channel
    };
    Some(InspectKey {
        session: app.session_generation,
        shot,
        square,
        channel,
        detection: Same::of(Some(det)),
    })
}

fn refresh_inspection(app: &mut StudioApp) {
    let wanted = wanted_inspection(app);
    let current = app.views.inspection.as_ref().map(Inspecting::key);
    if wanted.as_ref() != current {
        app.views.inspection = wanted.map(|key| spawn_inspection(app, key));
    }
    refresh_inspection_details(app);
}

/// Starts the crops of a square on a job thread (the core's inspection resamples the
/// chart through the square's homography and blurs it: too slow for a frame).
fn spawn_inspection(app: &mut StudioApp, key: InspectKey) -> Inspecting {
    let (Some(preview), Some(det), Some(session)) = (
        app.previews.get(&key.shot),
        app.detections.get(&key.shot),
        app.session.as_ref(),
    ) else {
        return Inspecting::Empty(key);
    };
    let capture = Arc::clone(&preview.capture);
    let det = Arc::clone(det);
    let chart = session.chart.clone();
    let scope = JobScope::shots(key.session, vec![key.shot]);
    let job_key = key.clone();
    let r = app
        .jobs
        .spawn_scoped("inspect square", scope, move |_ctx, out| {
            let result = det
                .squares
                .iter()
                .find(|s| (s.row, s.col) == job_key.square)
                .and_then(|square| {
                    let crops = crate::detect::inspect::inspect_square(
                        &capture,
                        square,
                        &chart,
                        job_key.channel,
                    )?;
                    let facts = (square.status == crate::detect::SquareStatus::Ok)
                        .then(|| crate::review::square_facts(square));
                    let images = crop_images(&crops);
                    Some(Box::new(InspectedSquare {
                        crops,
                        facts,
                        images,
                    }))
                });
            out.emit(JobOutput::SquareInspected {
                key: job_key,
                result,
            });
            // Never an error: a cancelled inspection (its shot removed, its session
            // closed) has nothing to report.
            Ok(())
        });
    match r {
        Ok(_) => Inspecting::Running(key),
        Err(e) => {
            app.error(e);
            Inspecting::Empty(key)
        }
    }
}

/// Grey images of the crops: observed and synthetic encoded for display; the residual
/// signed and small, so mid-grey is zero and ±25 % of the square's contrast spans the
/// grey range.
fn crop_images(crops: &SquareInspection) -> [egui::ColorImage; 3] {
    let img = |plane: &Plane, map: &dyn Fn(f32) -> u8| {
        egui::ColorImage::from_gray_iter(
            [plane.width, plane.height],
            plane.data.iter().map(|&v| map(v)),
        )
    };
    let contrast = {
        let mut v = crops.observed.data.clone();
        v.sort_by(f32::total_cmp);
        v.get(v.len() * 98 / 100)
            .zip(v.get(v.len() * 2 / 100))
            .map_or(1e-3, |(hi, lo)| (hi - lo).max(1e-3))
    };
    let encode = super::logic::encode;
    [
        img(&crops.observed, &encode),
        img(&crops.synthetic, &encode),
        img(&crops.residual, &|r: f32| {
            ((0.5 + 2.0 * r / contrast).clamp(0.0, 1.0) * 255.0) as u8
        }),
    ]
}

/// A finished inspection job: kept when it is still the one the selection asks for,
/// its textures made now; dropped otherwise.
pub(super) fn inspected(
    app: &mut StudioApp,
    key: InspectKey,
    result: Option<Box<InspectedSquare>>,
) {
    let running = matches!(&app.views.inspection, Some(Inspecting::Running(k)) if *k == key);
    if !running {
        return;
    }
    let Some(done) = result else {
        app.views.inspection = Some(Inspecting::Empty(key));
        return;
    };
    let InspectedSquare {
        crops,
        facts,
        images,
    } = *done;
    let [observed, synthetic, residual] = images;
    let tex = |name: &str, img: egui::ColorImage| {
        app.ctx
            .load_texture(name, img, egui::TextureOptions::NEAREST)
    };
    let textures = [
        tex("inspect-observed", observed),
        tex("inspect-synthetic", synthetic),
        tex("inspect-residual", residual),
    ];
    app.views.inspection = Some(Inspecting::Ready(Box::new(Inspection {
        shot: key.shot,
        square: key.square,
        channel: key.channel,
        key,
        crops,
        facts,
        textures,
        details: None,
        kernel: None,
        truth: None,
    })));
    refresh_inspection_details(app);
}

/// The inspected square's measured kernel as a texture (scaled to its peak) and, on the
/// demo session, the lens's true Gaussian at the square's centre: remade when the
/// shot's kernels or setting change.
fn refresh_inspection_details(app: &mut StudioApp) {
    let Some(Inspecting::Ready(ins)) = &app.views.inspection else {
        return;
    };
    let shot = app.session.as_ref().and_then(|s| s.shot(ins.shot));
    let file = app.measured.get(&ins.shot);
    let key = DetailsKey {
        file: Same::of(file),
        setting: shot.and_then(crate::session::Shot::setting),
        is_demo: is_demo(app),
    };
    if ins.details.as_ref() == Some(&key) {
        return;
    }
    let (sq, channel) = (ins.square, ins.channel);
    let kernel = file
        .and_then(|file| {
            let s = file
                .samples
                .iter()
                .find(|s| s.channel == channel && s.row == Some(sq.0) && s.col == Some(sq.1))?;
            s.kernel_at(file.oversample)
        })
        .map(|k| {
            let peak = k.data.iter().copied().fold(1e-12, f64::max);
            let img = egui::ColorImage::from_gray_iter(
                [k.size, k.size],
                k.data
                    .iter()
                    .map(|&v| ((v / peak).clamp(0.0, 1.0) * 255.0) as u8),
            );
            app.ctx
                .load_texture("inspect-kernel", img, egui::TextureOptions::NEAREST)
        });
    let truth = key
        .is_demo
        .then_some(key.setting)
        .flatten()
        .zip(app.previews.get(&ins.shot))
        .zip(ins.facts)
        .map(|((setting, p), f)| {
            crate::review::truth_pixel_gaussian(
                &VirtualLens::demo(),
                channel,
                (f.centre[0], f.centre[1]),
                (p.capture.width, p.capture.height),
                setting,
            )
        });
    if let Some(Inspecting::Ready(ins)) = &mut app.views.inspection {
        ins.kernel = kernel;
        ins.truth = truth;
        ins.details = Some(key);
    }
}
