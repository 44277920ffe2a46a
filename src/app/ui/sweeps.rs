//! The Sweeps view (the paper's Fig. 4): C_xx, C_yy, C_or against aperture at a fixed
//! focal length and against focal length at a fixed aperture, one colour per sensor
//! location: measured points, the profile's model curves, the demo lens's truth; or,
//! switched, the MTF50 of the same Gaussians. The settings the session has shots at are
//! marked on the sliders and as dotted vertical lines on the plots; a warning says when
//! they cannot determine the model, and what to shoot next.
//!
//! Plots the series `view_data` made for the sliders' setting; computes nothing.

use super::super::view_data::{
    Calibrated, SWEEP_LOCATIONS, SweepData, SweepKind, SweepSeries, sweep_params, sweep_series,
    sweep_x_label, sweep_y_label,
};
use super::super::{Command, PlotId, SweepAxis, SweepsViewState};
use super::{Frame, Sliders, TIP_COR, TIP_CXX, TIP_CYY, setting_sliders_ui};
use crate::app::ViewCommand;
use crate::plane::Channel;
use egui::Color32;

const TIP_MTF50: &str = "MTF50 in line pairs per picture height (lp/ph: cycles per sensor pixel times the sensor's height in pixels, as the Sharpness view maps it), from the Gaussian: the frequency at which its contrast falls to one half, √(ln 2 / (2π² uᵀCu)) along a direction u. The Gaussian is the pixel-level PSF, so the pixel's aperture is in it; sampling and demosaicing are not.";

/// Each location's colour, in the order of [`SWEEP_LOCATIONS`].
const LOCATION_COLORS: [Color32; 5] = [
    Color32::from_rgb(240, 200, 60),
    Color32::from_rgb(90, 170, 255),
    Color32::from_rgb(240, 100, 90),
    Color32::from_rgb(120, 210, 120),
    Color32::from_rgb(200, 120, 230),
];

/// What the Sweeps view draws from.
pub(super) struct SweepsContext<'a> {
    state: &'a SweepsViewState,
    data: Option<&'a SweepData>,
    calibrated: Option<&'a Calibrated>,
    sliders: Sliders<'a>,
    channel: Channel,
    is_demo: bool,
    has_dataset: bool,
    has_profile: bool,
}

impl<'a> SweepsContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            state: &f.views.sweeps,
            data: f.data.sweeps.as_ref(),
            calibrated: f.data.calibrated.as_ref(),
            sliders: Sliders::of(f),
            channel: f.views.shot.channel,
            is_demo: f.cx.is_demo(),
            has_dataset: f.cx.dataset().is_some(),
            has_profile: f.cx.profile().is_some(),
        }
    }
}

pub(super) fn sweeps_ui(cx: &SweepsContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    use egui_plot::Plot;
    ui.heading("Sweeps");
    let is_demo = cx.is_demo;
    if !cx.has_dataset && !cx.has_profile && !is_demo {
        ui.label("Measured points appear here after Kernels (Ctrl+K); model curves after Calibrate (Ctrl+M).");
        return;
    }
    setting_sliders_ui(&cx.sliders, out, ui);
    super::models::advice_ui(cx.calibrated, ui);
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
            "Dots: measured at the square nearest each location. Solid: the profile's model and dashed: the demo lens's truth, both at that square. Dotted verticals: settings with shots."
        } else {
            "Dots: measured at the square nearest each location. Solid: the profile's model at that square. Dotted verticals: settings with shots."
        });
        if !cx.has_dataset {
            ui.weak("No measured points yet: run Kernels (Ctrl+K).");
        } else if !cx.has_profile {
            ui.weak("No model yet: run Calibrate (Ctrl+M).");
        }
    });
    let Some(data) = cx.data else {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label("preparing the sweeps…");
        });
        return;
    };
    let ch = cx.channel;
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
                .selectable_label(cx.state.axis == axis, label)
                .on_hover_text(tip)
                .clicked()
            {
                out.push(Command::View(ViewCommand::SetSweepAxis(axis)));
            }
        }
    });
    let params = sweep_params(cx.state.axis);
    let tips = match cx.state.axis {
        SweepAxis::Sigma => [TIP_CXX, TIP_CYY, TIP_COR],
        SweepAxis::Mtf50 => [TIP_MTF50; 3],
    };
    let height_px = data.sensor_height_px();

    // Vertical lines at the settings with shots: the model is measured there and
    // interpolates between them.
    let (shot_f, shot_a) = cx
        .calibrated
        .map(|c| (c.focal_mm.clone(), c.f_number.clone()))
        .unwrap_or_default();
    let avail = ui.available_size();
    let plot_w = (avail.x - 24.0) / 3.0;
    let plot_h = ((avail.y - 72.0) / 2.0).max(120.0);
    for vs_aperture in [true, false] {
        ui.horizontal(|ui| {
            for (param, (p, tip)) in params.iter().zip(tips).enumerate() {
                let id = PlotId::Sweep { vs_aperture, param };
                let series = sweep_series(data, vs_aperture, p);
                let shot_at = if vs_aperture {
                    shot_a.clone()
                } else {
                    shot_f.clone()
                };
                let mark = ui.visuals().weak_text_color();
                ui.vertical(|ui| {
                    let name = p.name;
                    let title = if vs_aperture {
                        format!("{name} vs aperture at {fixed_f:.0} mm, channel {ch}")
                    } else {
                        format!("{name} vs focal length at f/{fixed_a:.1}, channel {ch}")
                    };
                    super::plot_title_ui(out, ui, id, title, tip, plot_w);
                    let plot = Plot::new(format!("sweep-{name}-{vs_aperture}"))
                        .width(plot_w)
                        .height(plot_h)
                        .custom_x_axes(vec![if vs_aperture {
                            super::aperture_axis(sweep_x_label(vs_aperture))
                        } else {
                            super::x_axis(sweep_x_label(vs_aperture))
                        }])
                        .custom_y_axes(vec![super::y_axis(&sweep_y_label(p))])
                        .allow_scroll(false);
                    let per_ph = p.per_picture_height.then_some(height_px);
                    let plot =
                        plot.label_formatter(move |pos| sweep_hover(pos, vs_aperture, per_ph));
                    let plot = if vs_aperture {
                        plot.x_grid_spacer(super::stops_grid())
                    } else {
                        plot
                    };
                    super::show_plot(ui, id, plot, move |plot| {
                        draw_sweep(plot, shot_at, series, vs_aperture, mark);
                    });
                });
            }
        });
    }
}

/// The settings with shots as dotted verticals (unnamed: out of the legend and the
/// CSV), then each series: measured as dots, the model as a line, the truth dashed.
fn draw_sweep(
    plot: &mut egui_plot::PlotUi<'_>,
    shot_at: Vec<f64>,
    series: Vec<SweepSeries>,
    vs_aperture: bool,
    mark: Color32,
) {
    use egui_plot::{Line, LineStyle, MarkerShape, PlotPoints, Points, VLine};
    for v in shot_at {
        let v = if vs_aperture {
            crate::review::aperture_stops(v)
        } else {
            v
        };
        // Unnamed: out of the legend and the CSV.
        plot.vline(
            VLine::new("", v)
                .color(mark)
                .style(LineStyle::dotted_loose())
                .width(1.0),
        );
    }
    for s in series {
        let color = LOCATION_COLORS[s.location % LOCATION_COLORS.len()];
        let pts = PlotPoints::from(s.points);
        match s.kind {
            SweepKind::Measured => plot.points(
                Points::new(s.name, pts)
                    .shape(MarkerShape::Circle)
                    .filled(true)
                    .color(color)
                    .radius(3.5),
            ),
            SweepKind::Model => {
                plot.line(Line::new(s.name, pts).color(color).width(1.5));
            }
            SweepKind::Truth => plot.line(
                Line::new(s.name, pts)
                    .color(color.gamma_multiply(0.7))
                    .style(LineStyle::dashed_loose())
                    .width(1.0),
            ),
        }
    }
}

/// What hovering a sweep plot names: the f-number (not the plot's stops) or the focal
/// length, and the value; an MTF50 also in cycles per pixel (`per_ph`: the sensor's
/// height that turned it into lp/ph).
fn sweep_hover(
    pos: &egui_plot::HoverPosition<'_>,
    vs_aperture: bool,
    per_ph: Option<usize>,
) -> Option<String> {
    let (name, p) = match pos {
        egui_plot::HoverPosition::NearDataPoint {
            plot_name,
            position,
            ..
        } => (*plot_name, position),
        egui_plot::HoverPosition::Elsewhere { position } => ("", position),
    };
    let head = if name.is_empty() {
        String::new()
    } else {
        format!("{name}\n")
    };
    let at = if vs_aperture {
        format!("f/{:.1}", crate::review::f_number_at_stops(p.x))
    } else {
        format!("{:.0} mm", p.x)
    };
    let value = match per_ph {
        Some(h) if h > 0 => format!("{:.0} lp/ph ({:.3} cycles/px)", p.y, p.y / h as f64),
        _ => format!("{:.3}", p.y),
    };
    Some(format!("{head}{at}: {value}"))
}
