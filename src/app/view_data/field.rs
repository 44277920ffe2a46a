//! The Kernel field view's panels: measured, predicted and true fields, their colour
//! scale and the difference maps.

use super::atlas::{AtlasCell, KernelAtlas};
use super::sensor_size;
use super::{FIELD_GRID, Same, is_demo};
use crate::app::state::{ColourRange, Difference, FieldOptions};
use crate::app::{FieldShow, FieldSource, StudioApp};
use crate::kernel::file::KernelsFile;
use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Mtf50Record};
use crate::review::{FieldDifference, KernelError};
use crate::session::ShotId;
use crate::simulate::VirtualLens;
use std::sync::Arc;

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
    /// The chart square (row, col) it sits on, and the shot (the selected one or
    /// another at its setting) that square was measured on.
    pub square: Option<(usize, usize)>,
    pub shot: Option<ShotId>,
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

fn field_key(app: &StudioApp) -> FieldKey {
    let channel = app.views.shot.channel;
    let size = sensor_size(app);
    let setting = [app.views.field.focal_mm, app.views.field.f_number];
    match app.views.field.source {
        FieldSource::Measured => FieldKey::Measured {
            shot: app.views.shot.selected,
            file: Same::of(super::field_kernels(app)),
            channel,
            show: app.views.field.show,
            size,
            chart_cols: app.session().map_or(10, |s| s.chart.cols),
            atlas: app.data.kernel_atlas.is_some(),
            profile: Same::of(app.profile().map(|p| &p.1)),
        },
        FieldSource::Predicted => FieldKey::Predicted {
            profile: Same::of(app.profile().map(|p| &p.1)),
            compare: Same::of(app.compare_profile().map(|p| &p.1)),
            channel,
            setting,
            size,
            show: app.views.field.show,
            file: Same::of(super::field_kernels(app)),
            chart_cols: app.session().map_or(10, |s| s.chart.cols),
            atlas: app.data.kernel_atlas.is_some(),
        },
        FieldSource::Truth => FieldKey::Truth {
            is_demo: is_demo(app),
            compare_units: app.views.field.compare_units,
            channel,
            setting,
            size,
        },
    }
}

pub(super) fn refresh_field(app: &mut StudioApp) {
    let key = (
        field_key(app),
        FieldExtra {
            options: app.views.field.options,
            compare: Same::of(app.compare_profile().map(|p| &p.1)),
            profile: Same::of(app.profile().map(|p| &p.1)),
            is_demo: is_demo(app),
            setting: [app.views.field.focal_mm, app.views.field.f_number],
        },
    );
    if app.data.field.as_ref().is_some_and(|f| f.key == key) {
        return;
    }
    let size = sensor_size(app);
    let file = super::field_kernels(app);
    // Squares of the chart are about this far apart on the sensor.
    let pitch_px = size.0 as f64 / app.session().map_or(12, |s| s.chart.cols + 2) as f64;
    let mut panels = match app.views.field.options.difference {
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
                    shot: sample
                        .and_then(|i| app.data.field_kernels.as_ref()?.shot_of.get(i).copied()),
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
    let diverging = app.views.field.options.difference.is_some();
    let range = match (app.views.field.options.range, diverging) {
        (ColourRange::Fixed { min, max }, false) if max > min => Some([min, max]),
        _ => crate::review::colour_range(
            panels.iter().flat_map(|p| &p.points).map(|q| q.value),
            diverging,
        ),
    };
    let scale = range.map(|range| ColourScale {
        range,
        diverging,
        title: if let Some(d) = app.views.field.options.difference {
            format!("Δσ, px ({})", difference_words(d))
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
    app.data.field = Some(FieldData {
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
    let ch = app.views.shot.channel;
    let s = LensSetting {
        focal_mm: app.views.field.focal_mm,
        f_number: app.views.field.f_number,
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
    let errors = match (app.profile(), file, app.views.field.show) {
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
    match app.views.field.source {
        FieldSource::Measured => {
            let mut samples = Vec::new();
            let content = match (file, app.views.field.show) {
                (None, _) => Err(
                    "No kernels measured on this shot yet — press Kernels (Ctrl+K) after Detect."
                        .to_owned(),
                ),
                (Some(f), FieldShow::Ellipses) => {
                    let (g, i) = measured_gaussians(f, ch);
                    samples = i.into_iter().map(Some).collect();
                    Ok(PanelContent::Ellipses(g))
                }
                (Some(_), FieldShow::Kernels) => match &app.data.kernel_atlas {
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
            panels.push(match app.profile() {
                Some((_, p)) => panel(
                    PanelOf::Profile,
                    match (app.views.field.show, &app.data.kernel_atlas) {
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
            if let Some((_, p)) = app.compare_profile() {
                panels.push(panel(PanelOf::CompareProfile, predicted(p), Vec::new()));
            }
        }
        FieldSource::Truth => {
            if is_demo(app) {
                let mut units = vec![(false, VirtualLens::demo())];
                if app.views.field.compare_units {
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
    let ch = app.views.shot.channel;
    let setting = LensSetting {
        focal_mm: app.views.field.focal_mm,
        f_number: app.views.field.f_number,
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
                .profile()
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
        Difference::UnitAMinusB => match (app.profile(), app.compare_profile()) {
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
                match app.views.field.source {
                    FieldSource::Measured => file
                        .map(|f| measured_gaussians(f, c).0)
                        .ok_or_else(no_kernels),
                    FieldSource::Predicted => match app.profile() {
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
            let pitch = if app.views.field.source == FieldSource::Measured {
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

/// What a difference map subtracts from what, as its legend says it.
#[must_use]
pub fn difference_words(d: Difference) -> &'static str {
    match d {
        Difference::MeasuredMinusPredicted => "measured − predicted",
        Difference::UnitAMinusB => "unit A − unit B",
        Difference::RedMinusBlue => "red − blue",
    }
}
