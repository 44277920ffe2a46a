//! The Geometry view's data: what the view draws, at the chosen focal length and
//! aperture, of the lens's distortion, lateral colour and fall-off as the project
//! measured them (`crate::project`'s geometry stage): a regular grid pushed through the
//! distortion, lateral-colour arrows, the fall-off map's texture and colour scale, and
//! the fits' numbers.

use super::{ColourScale, Same, StudioApp};
use crate::correction::{FocalGeometry, LensCorrection, LensfunFrame, TcaModel, VignettingFit};
use crate::plane::LensSetting;
pub use crate::review::{ColourArrows, WarpedGrid};

/// The fall-off at one aperture as a map in stops.
pub struct Falloff {
    pub f_number: f64,
    pub texture: egui::TextureHandle,
    pub scale: ColourScale,
    pub fit: VignettingFit,
}

/// What the Geometry view draws at its focal length and aperture.
pub struct GeometryData {
    key: DisplayKey,
    pub sensor: (usize, usize),
    pub focal_mm: Vec<f64>,
    pub focal: f64,
    /// The apertures with a fall-off fit at this focal length.
    pub f_numbers: Vec<f64>,
    pub grid: WarpedGrid,
    pub colour: Option<ColourArrows>,
    pub falloff: Option<Falloff>,
    /// The fits' models, coefficients with their standard errors, and residuals.
    pub fit_lines: Vec<String>,
    /// The light was not even at this aperture: the fall-off is not the lens's.
    pub warning: Option<String>,
}

#[derive(Clone, Debug, PartialEq)]
struct DisplayKey {
    correction: Same<LensCorrection>,
    focal: Option<f64>,
    f_number: Option<f64>,
}

/// The drawing at the chosen focal length and aperture of the project's measured
/// geometry (measured by `logic`, on a job, when the detections change).
pub(super) fn refresh_geometry(app: &mut StudioApp) {
    let correction = app
        .project
        .as_ref()
        .and_then(|p| p.geometry()?.as_ref().ok().cloned());
    let Some(correction) = correction else {
        app.data.geometry = None;
        return;
    };
    let key = DisplayKey {
        correction: Same::of(Some(&correction)),
        focal: app.views.geometry.focal_mm,
        f_number: app.views.geometry.f_number,
    };
    if app.data.geometry.as_ref().is_some_and(|d| d.key == key) {
        return;
    }
    let Some(focal) = key
        .focal
        .and_then(|f| correction.at_focal(f))
        .or_else(|| correction.focal.first())
    else {
        app.data.geometry = None;
        return;
    };
    let frame = correction.frame;
    let sensor = (correction.width, correction.height);
    let vignetting: Vec<&VignettingFit> = correction
        .vignetting
        .iter()
        .filter(|v| LensSetting::same_value(v.setting.focal_mm, focal.focal_mm))
        .collect();
    let vig = key
        .f_number
        .and_then(|a| {
            vignetting
                .iter()
                .find(|v| LensSetting::same_value(v.setting.f_number, a))
        })
        .or_else(|| vignetting.first())
        .copied();
    let falloff = vig.map(|v| falloff(app, &frame, v));
    let mut fit_lines = fit_lines(&correction, focal);
    if let Some(v) = vig {
        fit_lines.push(falloff_line(v));
    }
    let warning = vig.filter(|v| !v.light_even()).map(|v| {
        format!(
            "The light on the chart was not even at f/{}: a gradient of {:.2} stops across it that no lens fall-off explains (more than {} stops). The map is not the lens's fall-off, and the lensfun export refuses it: light the chart evenly and shoot again.",
            v.setting.f_number,
            v.gradient_stops,
            crate::correction::UNEVEN_LIGHT_STOPS
        )
    });
    let data = GeometryData {
        sensor,
        focal_mm: correction.focal.iter().map(|f| f.focal_mm).collect(),
        focal: focal.focal_mm,
        f_numbers: vignetting.iter().map(|v| v.setting.f_number).collect(),
        grid: crate::review::warped_grid(&correction, focal),
        colour: crate::review::colour_arrows(&correction, focal),
        falloff,
        fit_lines,
        warning,
        key,
    };
    app.data.geometry = Some(data);
}

/// The fall-off over the frame (`review::falloff_map`), one texel per cell, in the
/// core's palette.
fn falloff(app: &StudioApp, frame: &LensfunFrame, v: &VignettingFit) -> Falloff {
    let map = crate::review::falloff_map(frame, v, 60);
    let scale = ColourScale {
        range: map.range,
        diverging: false,
        title: format!("light lost at f/{}, stops", v.setting.f_number),
        ticks: crate::review::nice_ticks(map.range, 5),
    };
    let pixels: Vec<egui::Color32> = map
        .stops
        .iter()
        .map(|&s| {
            let [r, g, b] = crate::review::palette_rgb(scale.position(s), false);
            egui::Color32::from_rgb(r, g, b)
        })
        .collect();
    let image = egui::ColorImage::new(map.cells, pixels);
    let texture = app
        .ctx
        .load_texture("fall-off map", image, egui::TextureOptions::LINEAR);
    Falloff {
        f_number: v.setting.f_number,
        texture,
        scale,
        fit: v.clone(),
    }
}

fn terms(names: &[&str], values: &[f64], errors: &[f64]) -> String {
    names
        .iter()
        .zip(values.iter().zip(errors))
        .map(|(n, (v, e))| format!("{n} = {v:.5} ± {e:.5}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The distortion and lateral-colour fits written at this focal length.
fn fit_lines(c: &LensCorrection, focal: &FocalGeometry) -> Vec<String> {
    let d = focal.distortion_fit(c.distortion_model);
    let mut lines = vec![format!(
        "Distortion ({}, {} shots): {}; RMS {:.3} px, largest {:.2} px over {} corners{}",
        d.model.name(),
        focal.shots,
        terms(d.model.terms(), &d.coefficients, &d.std_errors),
        d.rms_px,
        d.max_px,
        d.corners,
        if d.outliers > 0 {
            format!(" ({} set aside)", d.outliers)
        } else {
            String::new()
        }
    )];
    match focal.tca_fit(c.tca_model) {
        Some(t) => {
            let names: &[&str] = match t.model {
                TcaModel::Linear => &["k"],
                TcaModel::Poly3 => &["v", "c", "b"],
            };
            lines.push(format!(
                "Lateral colour ({}): red {}, RMS {:.3} px; blue {}, RMS {:.3} px",
                t.model.name(),
                terms(names, &t.red.terms, &t.red.std_errors),
                t.red.rms_px,
                terms(names, &t.blue.terms, &t.blue.std_errors),
                t.blue.rms_px
            ));
        }
        None => lines.push("Lateral colour: not measured (a single-channel capture)".into()),
    }
    lines
}

fn falloff_line(v: &VignettingFit) -> String {
    format!(
        "Fall-off (pa) at f/{}: {}; {:.2} stops at the corners, residual {:.2} %, chart reached r = {:.2}, light gradient {:.2} stops",
        v.setting.f_number,
        terms(&["k1", "k2", "k3"], &v.k, &v.std_errors),
        v.corner_stops,
        100.0 * v.rms_relative,
        v.max_radius,
        v.gradient_stops
    )
}
