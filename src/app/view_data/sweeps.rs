//! The Sweeps view's series: measured points, model and truth curves per location, and
//! each plot's data as a table.

use super::{Same, is_demo};
use super::{sensor_size, setting_ranges};
use crate::app::{StudioApp, SweepAxis};
use crate::model::Dataset;
use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Mtf50};
use crate::review::SharpnessUnit;
use crate::review::{PlotTable, SweepPoint};
use crate::simulate::VirtualLens;

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
    /// The parameter, an MTF50 in cycles per pixel.
    pub get: fn(&Gaussian2, Option<&Mtf50>) -> f64,
    /// An MTF50, plotted in line pairs per picture height (what [`Self::get`] gives
    /// times the sensor's height), as the Sharpness view maps it.
    pub per_picture_height: bool,
}

/// The three plots of each sweep for an axis choice, in the view's order.
#[must_use]
pub fn sweep_params(axis: SweepAxis) -> [SweepParam; 3] {
    let p = |name, unit, get| SweepParam {
        name,
        unit,
        get,
        per_picture_height: unit == SharpnessUnit::LpPerPictureHeight.label(),
    };
    match axis {
        SweepAxis::Sigma => [
            p("C_xx", "σ, px", |g, _| g.sigma_x),
            p("C_yy", "σ, px", |g, _| g.sigma_y),
            p("C_or", "ρ", |g, _| g.rho),
        ],
        SweepAxis::Mtf50 => [
            p("MTF50 worst", "lp/ph", |_, m| {
                m.map_or(f64::NAN, |m| m.worst)
            }),
            p("MTF50 best", "lp/ph", |_, m| m.map_or(f64::NAN, |m| m.best)),
            p("MTF50 isotropic", "lp/ph", |_, m| {
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

impl SweepData {
    /// The height of the sensor the sweeps are for, px: what turns cycles per pixel
    /// into line pairs per picture height.
    #[must_use]
    pub fn sensor_height_px(&self) -> usize {
        self.key.size.1
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
    // Apertures in stops, as the plot spaces them (its ticks name the f-numbers).
    let abscissa = |s: LensSetting| {
        if vs_aperture {
            crate::review::aperture_stops(s.f_number)
        } else {
            s.focal_mm
        }
    };
    let (get, per_ph, height) = (param.get, param.per_picture_height, data.key.size.1);
    let get = move |g: &Gaussian2, m: Option<&Mtf50>| {
        let v = get(g, m);
        if per_ph {
            SharpnessUnit::LpPerPictureHeight.from_cycles_per_px(v, height)
        } else {
            v
        }
    };
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
        // The CSV gives f-numbers, not the plot's stops.
        series: sweep_series(data, vs_aperture, &param)
            .into_iter()
            .map(|s| {
                let points = s
                    .points
                    .into_iter()
                    .map(|[x, y]| {
                        [
                            if vs_aperture {
                                crate::review::f_number_at_stops(x)
                            } else {
                                x
                            },
                            y,
                        ]
                    })
                    .collect();
                (s.name, points)
            })
            .collect(),
    })
}

pub(super) fn refresh_sweeps(app: &mut StudioApp) {
    let lens = VirtualLens::demo();
    let key = SweepKey {
        dataset: Same::of(app.dataset()),
        profile: Same::of(app.profile().map(|p| &p.1)),
        is_demo: is_demo(app),
        channel: app.views.shot.channel,
        setting: [app.views.field.focal_mm, app.views.field.f_number],
        ranges: setting_ranges(app, &lens),
        size: sensor_size(app),
    };
    if app.data.sweeps.as_ref().is_some_and(|s| s.key == key) {
        return;
    }
    let ch = key.channel;
    let (w, h) = key.size;
    let (f_range, a_range) = key.ranges;
    let (focals, apertures) = app
        .dataset()
        .map(|d| d.distinct_settings())
        .unwrap_or_default();
    // Measured points only exist at shot settings: the sweep holds the other setting at
    // the calibrated value nearest the slider.
    let fixed_f = crate::review::nearest_value(&focals, app.views.field.focal_mm)
        .unwrap_or(app.views.field.focal_mm);
    let fixed_a = crate::review::nearest_value(&apertures, app.views.field.f_number)
        .unwrap_or(app.views.field.f_number);
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
                let measured = app.dataset().map(|ds| {
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
                        .profile()
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
    app.data.sweeps = Some(SweepData {
        key,
        fixed_f,
        fixed_a,
        sweeps,
    });
}
