//! View data: everything a view shows that takes arranging, made here when its inputs
//! change and cached on the app keyed by exactly those inputs.
//!
//! Owns the shot viewer's plane choice, the Kernel field view's panels (measured
//! ellipses, the kernel atlas texture, predicted and true fields), the Sharpness view's
//! map, the Sweeps view's measured points and model and truth curves, the Geometry
//! view's drawing of the project's measured geometry, and what the square inspector
//! shows beside its crops (the measured kernel's texture, the truth); the crops are a
//! job's, which `logic` asks for and keeps here. [`refresh`] runs once per frame from
//! the app's logic step and recomputes only what is stale; the draw code reads these
//! caches and shows a placeholder where one is absent, never computing. The numbers
//! come from the core (`crate::review`, `crate::detect::inspect`); this module only
//! arranges them and makes textures.

use super::{StudioApp, View};
use crate::kernel::file::KernelsFile;
use crate::plane::LensSetting;
use crate::review::{LensRange, PlannedSetting, SettingCoverage, ShootingAdvice};
use crate::session::ShotId;
use crate::simulate::VirtualLens;
use atlas::refresh_kernel_atlas;
use field::refresh_field;
use geometry::refresh_geometry;
use inspector::refresh_inspection_details;
use sharpness::refresh_sharpness;
use shot_plane::refresh_shot_plane;
use std::sync::Arc;
use sweeps::refresh_sweeps;

mod atlas;
mod field;
mod geometry;
mod inspector;
mod sharpness;
mod shot_plane;
mod sweeps;

pub(crate) use super::state::Same;
pub use atlas::{AtlasCell, KernelAtlas};
pub use field::{
    ColourScale, FieldData, FieldPanel, FieldPoint, PanelContent, PanelOf, difference_words,
};
pub use geometry::{ColourArrows, Falloff, GeometryData, WarpedGrid};
pub use inspector::{Inspecting, Inspection};
pub use sharpness::SharpnessData;
pub use shot_plane::ShotPlane;
pub use sweeps::{
    CurvePoint, LocationSweep, SWEEP_LOCATIONS, SweepData, SweepKind, SweepParam, SweepSeries,
    sweep_params, sweep_series, sweep_table, sweep_x_label, sweep_y_label,
};

/// Grid of the predicted and true fields.
const FIELD_GRID: (usize, usize) = (12, 8);

/// Every view's cached data.
#[derive(Default)]
pub struct ViewData {
    pub shot_plane: Option<ShotPlane>,
    pub kernel_atlas: Option<KernelAtlas>,
    pub field: Option<FieldData>,
    pub sharpness: Option<SharpnessData>,
    pub sweeps: Option<SweepData>,
    pub inspection: Option<Inspecting>,
    /// What the Geometry view draws of the project's geometry at its focal length and
    /// aperture.
    pub geometry: Option<GeometryData>,
    /// The session's settings with shots and what they allow the model.
    pub calibrated: Option<Calibrated>,
    /// Where on the sensor the chart has been, per setting (the Models view's coverage
    /// maps), keyed by each measured shot's setting and kernels.
    pub coverage: Option<(CoverageKey, Vec<SettingCoverage>)>,
    /// The measured kernels the Kernel field view shows: the selected shot's and those
    /// of the other shots at its setting, as one field.
    pub field_kernels: Option<FieldKernels>,
}

/// The kernels of every shot at the selected shot's setting as one field: a small
/// chart shot at several positions measures the frame a part per shot.
pub struct FieldKernels {
    key: Vec<(ShotId, Same<KernelsFile>)>,
    /// The selected shot's own file where it is the only one, else the merge.
    pub file: Arc<KernelsFile>,
    /// Per sample of `file`, the shot it was measured on.
    pub shot_of: Vec<ShotId>,
    /// How many shots `file` holds.
    pub shots: usize,
}

/// What the coverage maps are made from: each measured shot's setting and kernels.
pub type CoverageKey = Vec<(LensSetting, Same<KernelsFile>)>;

/// The focal lengths and f-numbers the session has shots at (sorted, distinct), marked
/// on the sliders and the sweeps, and what they allow the model (the Models and Sweeps
/// views' warnings).
pub struct Calibrated {
    pub focal_mm: Vec<f64>,
    pub f_number: Vec<f64>,
    pub advice: Vec<ShootingAdvice>,
    /// The lens's range the shooting plan is for: the one typed, else the session's.
    pub plan_range: LensRange,
    /// Every setting to shoot for that range, with the shots the session has there.
    pub plan: Vec<PlannedSetting>,
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

/// Rebuilds the cached data that is stale; called once per frame after `logic` has
/// applied the commands and job results. It writes only `app.data` (and makes
/// textures): no job is started and no other state changed here.
pub(super) fn refresh(app: &mut StudioApp) {
    refresh_shot_plane(app);
    refresh_calibrated(app);
    refresh_coverage(app);
    refresh_inspection_details(app);
    match app.view {
        View::KernelField => {
            refresh_field_kernels(app);
            refresh_kernel_atlas(app);
            refresh_field(app);
        }
        View::Sharpness => refresh_sharpness(app),
        View::Sweeps => refresh_sweeps(app),
        View::Geometry => refresh_geometry(app),
        View::Shot | View::Models | View::Deblur => {}
    }
}

/// The sensor the views draw on: the selected shot's, else the measurements', else the
/// demo's.
pub(crate) fn sensor_size(app: &StudioApp) -> (usize, usize) {
    if let Some(p) = app.views.shot.selected.and_then(|i| app.preview(i)) {
        return (p.capture.width, p.capture.height);
    }
    if let Some(d) = app.dataset() {
        return (d.width, d.height);
    }
    (app.options.demo_spec.width, app.options.demo_spec.height)
}

/// Focal length and aperture ranges the sliders span: the profile's calibrated ones,
/// else the session's, else the demo lens's.
pub(crate) fn setting_ranges(app: &StudioApp, lens: &VirtualLens) -> ([f64; 2], [f64; 2]) {
    if let Some((_, p)) = app.profile() {
        return (p.norm.focal_range_mm, p.norm.f_number_range);
    }
    if let Some(s) = app.session() {
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
pub(super) fn refresh_calibrated(app: &mut StudioApp) {
    app.data.calibrated = app.session().map(|s| {
        let (focal_mm, f_number) = s.setting_grid();
        let advice = crate::review::shooting_advice(&focal_mm, &f_number, s.settings.beta);
        let plan_range = app.views.session.plan_range.unwrap_or_else(|| {
            // The range the shots span, where they span one; else the demo lens's.
            match (
                focal_mm.first(),
                focal_mm.last(),
                f_number.first(),
                f_number.last(),
            ) {
                (Some(&f0), Some(&f1), Some(&a0), Some(&a1)) => LensRange {
                    focal_mm: [f0, f1],
                    f_number: [a0, a1.max(a0)],
                },
                _ => {
                    let lens = VirtualLens::demo();
                    LensRange {
                        focal_mm: lens.focal_range_mm,
                        f_number: lens.f_number_range,
                    }
                }
            }
        });
        let shot: Vec<crate::plane::LensSetting> = s
            .shots
            .iter()
            .filter_map(|shot| {
                Some(crate::plane::LensSetting {
                    focal_mm: shot.focal_mm?,
                    f_number: shot.f_number?,
                })
            })
            .collect();
        Calibrated {
            plan: crate::review::shooting_plan(&plan_range, &shot),
            plan_range,
            focal_mm,
            f_number,
            advice,
        }
    });
}

/// The Kernel field's measured kernels, merged again when the selection, a shot's
/// setting or its kernels change.
fn refresh_field_kernels(app: &mut StudioApp) {
    let key: Vec<(ShotId, Same<KernelsFile>)> = match (app.views.shot.selected, app.session()) {
        (Some(selected), Some(s)) => {
            let setting_of = |id: ShotId| {
                let shot = s.shot(id)?;
                Some(LensSetting {
                    focal_mm: shot.focal_mm?,
                    f_number: shot.f_number?,
                })
            };
            let mine = setting_of(selected);
            let mut ids = vec![selected];
            if let Some(mine) = mine {
                ids.extend(s.shots.iter().map(|shot| shot.id).filter(|&id| {
                    id != selected && setting_of(id).is_some_and(|t| t.same_as(mine))
                }));
            }
            ids.into_iter()
                .filter_map(|id| Some((id, Same::of(Some(app.kernels(id)?)))))
                .collect()
        }
        _ => Vec::new(),
    };
    if app
        .data
        .field_kernels
        .as_ref()
        .is_some_and(|f| f.key == key)
    {
        return;
    }
    let files: Vec<(ShotId, &Arc<KernelsFile>)> = key
        .iter()
        .filter_map(|(id, f)| Some((*id, f.0.as_ref()?)))
        .collect();
    app.data.field_kernels = match files.as_slice() {
        [] => None,
        [(id, one)] => Some(FieldKernels {
            shot_of: vec![*id; one.samples.len()],
            file: Arc::clone(one),
            shots: 1,
            key,
        }),
        many => {
            let refs: Vec<&KernelsFile> = many.iter().map(|(_, f)| f.as_ref()).collect();
            // Files that cannot be one field (another sensor) leave the selected alone.
            let (file, shot_of, shots) = match KernelsFile::merged(&refs) {
                Some(m) => (
                    Arc::new(m),
                    many.iter()
                        .flat_map(|(id, f)| std::iter::repeat_n(*id, f.samples.len()))
                        .collect(),
                    many.len(),
                ),
                None => (
                    Arc::clone(many[0].1),
                    vec![many[0].0; many[0].1.samples.len()],
                    1,
                ),
            };
            Some(FieldKernels {
                key,
                file,
                shot_of,
                shots,
            })
        }
    };
}

/// The measured kernels the Kernel field view shows ([`FieldKernels`]).
pub(crate) fn field_kernels(app: &StudioApp) -> Option<&Arc<KernelsFile>> {
    app.data.field_kernels.as_ref().map(|f| &f.file)
}

/// The coverage maps, made again when a shot's kernels or setting change.
fn refresh_coverage(app: &mut StudioApp) {
    let key: CoverageKey = app.session().map_or_else(Vec::new, |s| {
        s.shots
            .iter()
            .filter_map(|shot| {
                let setting = LensSetting {
                    focal_mm: shot.focal_mm?,
                    f_number: shot.f_number?,
                };
                Some((setting, Same::of(Some(app.kernels(shot.id)?))))
            })
            .collect()
    });
    if app.data.coverage.as_ref().is_some_and(|(k, _)| *k == key) {
        return;
    }
    let size = key
        .iter()
        .find_map(|(_, k)| k.0.as_ref().map(|k| (k.width, k.height)))
        .unwrap_or((1, 1));
    let maps = crate::review::coverage(
        size,
        key.iter().filter_map(|(s, k)| Some((*s, k.0.as_deref()?))),
    );
    app.data.coverage = Some((key, maps));
}

fn is_demo(app: &StudioApp) -> bool {
    app.session().is_some_and(|s| s.is_demo)
}
