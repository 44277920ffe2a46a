//! The Sweeps view (the paper's Fig. 4): C_xx, C_yy, C_or against aperture at a fixed
//! focal length and against focal length at a fixed aperture, one colour per sensor
//! location: measured points, the profile's model curves, the demo lens's truth.

use super::super::StudioApp;
use super::{TIP_COR, TIP_CXX, TIP_CYY, setting_ranges, setting_sliders_ui, truth_gaussian};
use crate::plane::LensSetting;
use crate::psf::Gaussian2;
use crate::simulate::VirtualLens;
use egui::Color32;

/// A plotted parameter: its name, its tooltip and how to read it from a Gaussian.
type Param = (&'static str, &'static str, fn(&Gaussian2) -> f64);

/// Points on each model and truth curve.
const CURVE_STEPS: usize = 40;

pub(super) fn sweeps_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    use egui_plot::{Line, LineStyle, MarkerShape, Plot, PlotPoints, Points};
    ui.heading("Sweeps");
    let is_demo = app.session.as_ref().is_some_and(|s| s.is_demo);
    let lens = VirtualLens::demo();
    if app.dataset.is_none() && app.profile.is_none() && !is_demo {
        ui.label("Measured points appear here after Kernels (Ctrl+K); model curves after Calibrate (Ctrl+M).");
        return;
    }
    let (f_range, a_range) = setting_ranges(app, &lens);
    setting_sliders_ui(app, ui, &lens);
    let (w, h) = super::sensor_size(app);
    let locations: [(&str, f64, f64, Color32); 5] = [
        ("centre", 0.5, 0.5, Color32::from_rgb(240, 200, 60)),
        ("top-left", 0.15, 0.15, Color32::from_rgb(90, 170, 255)),
        ("top-right", 0.85, 0.15, Color32::from_rgb(240, 100, 90)),
        ("bottom-left", 0.15, 0.85, Color32::from_rgb(120, 210, 120)),
        ("bottom-right", 0.85, 0.85, Color32::from_rgb(200, 120, 230)),
    ];
    // One colour per location across the six plots, named once here rather than in six
    // legends that would cover the curves; the glyphs say which series is which.
    ui.horizontal_wrapped(|ui| {
        ui.label("Locations:");
        for (loc, _, _, c) in locations {
            ui.colored_label(c, format!("— {loc}"));
        }
    });
    ui.horizontal_wrapped(|ui| {
        ui.label(if is_demo {
            "Dots: measured at the square nearest each location. Solid: the profile's model and dashed: the demo lens's truth, both at that square."
        } else {
            "Dots: measured at the square nearest each location. Solid: the profile's model at that square."
        });
        if app.dataset.is_none() {
            ui.weak("No measured points yet: run Kernels (Ctrl+K).");
        } else if app.profile.is_none() {
            ui.weak("No model yet: run Calibrate (Ctrl+M).");
        }
    });
    let ch = app.channel;
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
    let params: [Param; 3] = [
        ("C_xx", TIP_CXX, |g| g.sigma_x),
        ("C_yy", TIP_CYY, |g| g.sigma_y),
        ("C_or", TIP_COR, |g| g.rho),
    ];
    let avail = ui.available_size();
    let plot_w = (avail.x - 24.0) / 3.0;
    let plot_h = ((avail.y - 72.0) / 2.0).max(120.0);
    for vs_aperture in [true, false] {
        ui.horizontal(|ui| {
            for (name, tip, get) in params {
                ui.vertical(|ui| {
                    let title = if vs_aperture {
                        format!("{name} vs aperture at {fixed_f:.0} mm, channel {ch}")
                    } else {
                        format!("{name} vs focal length at f/{fixed_a:.1}, channel {ch}")
                    };
                    ui.label(title).on_hover_text(tip);
                    let unit = if name == "C_or" { "ρ" } else { "σ, px" };
                    let x_label = if vs_aperture {
                        "aperture (f-number)"
                    } else {
                        "focal length (mm)"
                    };
                    let settings: Vec<LensSetting> = if vs_aperture {
                        crate::review::sweep_settings(a_range, fixed_f, true, CURVE_STEPS)
                    } else {
                        crate::review::sweep_settings(f_range, fixed_a, false, CURVE_STEPS)
                    };
                    let abscissa =
                        |s: LensSetting| if vs_aperture { s.f_number } else { s.focal_mm };
                    Plot::new(format!("sweep-{name}-{vs_aperture}"))
                        .width(plot_w)
                        .height(plot_h)
                        .custom_x_axes(vec![super::x_axis(x_label)])
                        .custom_y_axes(vec![super::y_axis(&format!("{name} ({unit})"))])
                        .allow_scroll(false)
                        .show(ui, |plot| {
                            for (loc, fx, fy, color) in locations {
                                let nominal = (fx * (w as f64 - 1.0), fy * (h as f64 - 1.0));
                                let measured = app.dataset.as_ref().map(|ds| {
                                    let fixed = if vs_aperture { fixed_f } else { fixed_a };
                                    crate::review::sweep_points(ds, ch, nominal, vs_aperture, fixed)
                                });
                                // Curves where the points were measured (the square
                                // nearest the location), so the two compare.
                                let (x, y) = measured
                                    .as_ref()
                                    .and_then(|m| m.first())
                                    .map_or(nominal, |p| (p.x, p.y));
                                if let Some(m) = &measured {
                                    let pts: Vec<[f64; 2]> = m
                                        .iter()
                                        .map(|p| [abscissa(p.setting), get(&p.gaussian)])
                                        .collect();
                                    plot.points(
                                        Points::new(
                                            format!("measured {loc}"),
                                            PlotPoints::from(pts),
                                        )
                                        .shape(MarkerShape::Circle)
                                        .filled(true)
                                        .color(color)
                                        .radius(3.5),
                                    );
                                }
                                if let Some((_, p)) = &app.profile {
                                    let pts: Vec<[f64; 2]> = settings
                                        .iter()
                                        .filter_map(|&s| {
                                            p.predict(ch, x, y, s)
                                                .ok()
                                                .map(|g| [abscissa(s), get(&g)])
                                        })
                                        .collect();
                                    plot.line(
                                        Line::new(format!("model {loc}"), PlotPoints::from(pts))
                                            .color(color)
                                            .width(1.5),
                                    );
                                }
                                if is_demo {
                                    let pts: Vec<[f64; 2]> = settings
                                        .iter()
                                        .map(|&s| {
                                            let g = truth_gaussian(&lens, ch, x, y, (w, h), s);
                                            [abscissa(s), get(&g)]
                                        })
                                        .collect();
                                    plot.line(
                                        Line::new(format!("truth {loc}"), PlotPoints::from(pts))
                                            .color(color.gamma_multiply(0.7))
                                            .style(LineStyle::dashed_loose())
                                            .width(1.0),
                                    );
                                }
                            }
                        });
                });
            }
        });
    }
}
