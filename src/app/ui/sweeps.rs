//! The Sweeps view (the paper's Fig. 4): C_xx, C_yy, C_or against aperture at a fixed
//! focal length and against focal length at a fixed aperture, one colour per sensor
//! location: measured points, the profile's model curves, the demo lens's truth; or,
//! switched, the MTF50 of the same Gaussians.
//!
//! Plots the series `view_data` made for the sliders' setting; computes nothing.

use super::super::view_data::SWEEP_LOCATIONS;
use super::super::{Command, StudioApp, SweepAxis};
use super::{TIP_COR, TIP_CXX, TIP_CYY, setting_sliders_ui};
use crate::plane::LensSetting;
use crate::psf::{Gaussian2, Mtf50};
use crate::simulate::VirtualLens;
use egui::Color32;

/// A plotted parameter: its name, its tooltip, its unit and how to read it from a
/// Gaussian and its MTF50 (view data made both; NaN, left out of the plot, where a
/// degenerate Gaussian has no MTF50).
type Param = (
    &'static str,
    &'static str,
    &'static str,
    fn(&Gaussian2, Option<&Mtf50>) -> f64,
);

const TIP_MTF50: &str = "MTF50 in cycles per sensor pixel, from the Gaussian: the frequency at which its contrast falls to one half, √(ln 2 / (2π² uᵀCu)) along a direction u. The Gaussian is the pixel-level PSF, so the pixel's aperture is in it; sampling and demosaicing are not.";

/// Each location's colour, in the order of [`SWEEP_LOCATIONS`].
const LOCATION_COLORS: [Color32; 5] = [
    Color32::from_rgb(240, 200, 60),
    Color32::from_rgb(90, 170, 255),
    Color32::from_rgb(240, 100, 90),
    Color32::from_rgb(120, 210, 120),
    Color32::from_rgb(200, 120, 230),
];

pub(super) fn sweeps_ui(app: &mut StudioApp, ui: &mut egui::Ui) {
    use egui_plot::{Line, LineStyle, MarkerShape, Plot, PlotPoints, Points};
    ui.heading("Sweeps");
    let is_demo = app.session.as_ref().is_some_and(|s| s.is_demo);
    let lens = VirtualLens::demo();
    if app.dataset.is_none() && app.profile.is_none() && !is_demo {
        ui.label("Measured points appear here after Kernels (Ctrl+K); model curves after Calibrate (Ctrl+M).");
        return;
    }
    setting_sliders_ui(app, ui, &lens);
    // One colour per location across the six plots, named once here rather than in six
    // legends that would cover the curves; the glyphs say which series is which.
    ui.horizontal_wrapped(|ui| {
        ui.label("Locations:");
        for ((loc, _, _), c) in SWEEP_LOCATIONS.iter().zip(LOCATION_COLORS) {
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
    let Some(data) = &app.views.sweeps else {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label("preparing the sweeps…");
        });
        return;
    };
    let ch = app.channel;
    let (fixed_f, fixed_a) = (data.fixed_f, data.fixed_a);
    ui.horizontal(|ui| {
        ui.label("Plot:");
        for (axis, label, tip) in [
            (SweepAxis::Sigma, "σ (C_xx, C_yy, C_or)", "The Gaussian's parameters"),
            (
                SweepAxis::Mtf50,
                "MTF50",
                "MTF50 of the same Gaussians: along the worst and best directions and of the isotropic equivalent (σ = det(C)^¼)",
            ),
        ] {
            if ui
                .selectable_label(app.sweep_axis == axis, label)
                .on_hover_text(tip)
                .clicked()
            {
                app.commands.push(Command::SetSweepAxis(axis));
            }
        }
    });
    let params: [Param; 3] = match app.sweep_axis {
        SweepAxis::Sigma => [
            ("C_xx", TIP_CXX, "σ, px", |g, _| g.sigma_x),
            ("C_yy", TIP_CYY, "σ, px", |g, _| g.sigma_y),
            ("C_or", TIP_COR, "ρ", |g, _| g.rho),
        ],
        SweepAxis::Mtf50 => [
            ("MTF50 worst", TIP_MTF50, "cycles/px", |_, m| {
                m.map_or(f64::NAN, |m| m.worst)
            }),
            ("MTF50 best", TIP_MTF50, "cycles/px", |_, m| {
                m.map_or(f64::NAN, |m| m.best)
            }),
            ("MTF50 isotropic", TIP_MTF50, "cycles/px", |_, m| {
                m.map_or(f64::NAN, |m| m.isotropic)
            }),
        ],
    };

    let avail = ui.available_size();
    let plot_w = (avail.x - 24.0) / 3.0;
    let plot_h = ((avail.y - 72.0) / 2.0).max(120.0);
    for (vs_aperture, sweep) in [true, false].into_iter().zip(&data.sweeps) {
        ui.horizontal(|ui| {
            for (name, tip, unit, get) in params {
                ui.vertical(|ui| {
                    let title = if vs_aperture {
                        format!("{name} vs aperture at {fixed_f:.0} mm, channel {ch}")
                    } else {
                        format!("{name} vs focal length at f/{fixed_a:.1}, channel {ch}")
                    };
                    ui.label(title).on_hover_text(tip);
                    let x_label = if vs_aperture {
                        "aperture (f-number)"
                    } else {
                        "focal length (mm)"
                    };
                    let abscissa =
                        |s: LensSetting| if vs_aperture { s.f_number } else { s.focal_mm };
                    let curve = |c: &[(LensSetting, Gaussian2, Option<Mtf50>)]| -> Vec<[f64; 2]> {
                        c.iter()
                            .map(|(s, g, m)| [abscissa(*s), get(g, m.as_ref())])
                            .collect()
                    };
                    Plot::new(format!("sweep-{name}-{vs_aperture}"))
                        .width(plot_w)
                        .height(plot_h)
                        .custom_x_axes(vec![super::x_axis(x_label)])
                        .custom_y_axes(vec![super::y_axis(&format!("{name} ({unit})"))])
                        .allow_scroll(false)
                        .show(ui, |plot| {
                            for (((loc, _, _), color), series) in
                                SWEEP_LOCATIONS.iter().zip(LOCATION_COLORS).zip(sweep)
                            {
                                if let Some(m) = &series.measured {
                                    let pts: Vec<[f64; 2]> = m
                                        .iter()
                                        .map(|(p, m)| {
                                            [abscissa(p.setting), get(&p.gaussian, m.as_ref())]
                                        })
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
                                if let Some(model) = &series.model {
                                    plot.line(
                                        Line::new(
                                            format!("model {loc}"),
                                            PlotPoints::from(curve(model)),
                                        )
                                        .color(color)
                                        .width(1.5),
                                    );
                                }
                                if let Some(truth) = &series.truth {
                                    plot.line(
                                        Line::new(
                                            format!("truth {loc}"),
                                            PlotPoints::from(curve(truth)),
                                        )
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
