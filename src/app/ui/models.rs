//! The Models view: cross-validation over α and β (the paper's Fig. 5), the error
//! distributions of the chosen models (Fig. 6), the profile in use; load and save; and
//! what the session's settings allow the model, with what to shoot next.

use super::super::view_data::Calibrated;
use super::super::{Command, PlotId, ViewerContext};
use super::{Frame, TIP_ALPHA, TIP_BETA, TIP_COR, TIP_CXX, TIP_CYY};
use crate::app::{DialogCommand, StageCommand, ViewCommand};
use crate::review::SettingCoverage;
use egui::Color32;

/// What the Models view draws from: the profile and its cross-validation, the settings
/// shot with the plan for them, and where on the sensor the chart has been.
pub(super) struct ModelsContext<'a> {
    cx: ViewerContext<'a>,
    calibrated: Option<&'a Calibrated>,
    coverage: Option<&'a [SettingCoverage]>,
    sensor: (usize, usize),
}

impl<'a> ModelsContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            cx: f.cx,
            calibrated: f.data.calibrated.as_ref(),
            coverage: f.data.coverage.as_ref().map(|(_, maps)| maps.as_slice()),
            sensor: f.sensor,
        }
    }
}

fn family_color(name: &str) -> Color32 {
    if name == "global" {
        Color32::from_rgb(90, 170, 255)
    } else {
        Color32::from_rgb(240, 150, 60)
    }
}

/// Plots stop shrinking at this height; below it the view scrolls instead (the
/// shooting plan open on a small window).
const MIN_PLOT_H: f32 = 240.0;

pub(super) fn models_ui(m: &ModelsContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let view_h = ui.available_height();
    egui::ScrollArea::vertical()
        .auto_shrink([false, false])
        .show(ui, |ui| models_body_ui(m, out, ui, view_h));
}

/// The view's content; `view_h` is the height of the window's part it scrolls in, so
/// the plots fill what is left of it and keep [`MIN_PLOT_H`] when little is.
fn models_body_ui(m: &ModelsContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui, view_h: f32) {
    ui.heading("Models");
    profile_buttons_ui(m.cx.profile().is_some(), out, ui);
    advice_ui(m.calibrated, ui);
    egui::CollapsingHeader::new("Shooting plan")
        // A header of its own once a profile exists, so it folds then (the plots take
        // the view) even where it was open before calibration.
        .id_salt(("shooting plan", m.cx.profile().is_some()))
        .default_open(m.cx.profile().is_none())
        .show(ui, |ui| plan_ui(m, out, ui));
    profile_summary_ui(m.cx, ui);
    let Some(cv) = m.cx.cv().cloned() else {
        ui.label("Cross-validation curves over α and β (paper Fig. 5) and the error distributions (Fig. 6) appear after a calibration that selects α and β.");
        return;
    };
    ui.label(format!(
        "Cross-validation: {} shots in {} folds, whole shots held out. Errors are % of each parameter's 99 % range (C_xx {:.3} px, C_yy {:.3} px, C_or {:.3}).",
        cv.shots, cv.folds, cv.ranges.cxx, cv.ranges.cyy, cv.ranges.cor
    ));
    let families: Vec<(&str, &crate::crossval::Selection)> =
        [("global", cv.global.as_ref()), ("local", cv.local.as_ref())]
            .into_iter()
            .filter_map(|(n, s)| s.map(|s| (n, s)))
            .collect();
    chosen_models_ui(ui, &families);
    let avail = ui.available_size();
    let used = ui.cursor().top() - ui.max_rect().top();
    let size = PlotSize {
        width: (avail.x - 24.0) / 3.0,
        // Room below for the x axis's title and the scroll area's margin.
        height: (view_h - used - 44.0).max(MIN_PLOT_H),
        // Fixed bounds are kept in the plot's memory: a new report gets a new plot.
        report_id: std::sync::Arc::as_ptr(&cv) as usize,
    };
    ui.horizontal(|ui| {
        for (title, tip, by_alpha) in [
            ("CV error vs α (β = N − 1)", TIP_ALPHA, true),
            ("CV error vs β (chosen α)", TIP_BETA, false),
        ] {
            cv_order_plot_ui(out, ui, &families, (title, tip, by_alpha), size);
        }
        cv_cdf_plot_ui(out, ui, &families, size);
    });
}

/// Where the three plots go: their size, and the report they show (part of each plot's
/// id).
#[derive(Clone, Copy)]
struct PlotSize {
    width: f32,
    height: f32,
    report_id: usize,
}

/// Run calibration, load and save a profile.
fn profile_buttons_ui(has_profile: bool, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        if ui
            .button("Run calibration")
            .on_hover_text("Fit global and local models over every shot with kernels; cross-validation picks α and β unless the settings fix them (Ctrl+M)")
            .clicked()
        {
            out.push(Command::Stage(StageCommand::RunCalibrate));
        }
        if ui
            .button("Load profile…")
            .on_hover_text("Use a lens profile written earlier (lensblur calibrate or this studio)")
            .clicked()
        {
            out.push(Command::Dialog(DialogCommand::LoadProfileDialog));
        }
        if ui
            .add_enabled(has_profile, egui::Button::new("Save profile…"))
            .on_hover_text("Write the profile in use to a file of your choice")
            .clicked()
        {
            out.push(Command::Dialog(DialogCommand::SaveProfileDialog));
        }
    });
}

/// The profile in use: its file, model and orders, calibrated range; and its shape
/// model's cross-validation.
fn profile_summary_ui(cx: ViewerContext<'_>, ui: &mut egui::Ui) {
    if let Some((path, p)) = cx.profile() {
        let kind = format!("{:?}", p.preferred).to_lowercase();
        let orders = |k: crate::model::ModelKind, g: Option<(usize, usize)>| {
            g.map_or("—".to_owned(), |(a, b)| {
                format!("{} ({})", k.in_words(a, b), k.symbol(a, b))
            })
        };
        ui.horizontal_wrapped(|ui| {
            ui.strong(format!("Profile {}:", cx.shown_path(path)));
            ui.label(format!(
                "uses the {kind} model; global: {}; local: {}; calibrated {:.0}–{:.0} mm, f/{:.1}–f/{:.1}, sensor {} × {} px",
                orders(crate::model::ModelKind::Global, p.global.as_ref().map(|g| (g.alpha, g.beta))),
                orders(crate::model::ModelKind::Local, p.local.as_ref().map(|l| (l.alpha, l.beta))),
                p.norm.focal_range_mm[0],
                p.norm.focal_range_mm[1],
                p.norm.f_number_range[0],
                p.norm.f_number_range[1],
                p.norm.width,
                p.norm.height,
            ))
            .on_hover_text(format!("{TIP_ALPHA}\n{TIP_BETA}"));
        });
        shape_cv_ui(ui, p);
    } else {
        ui.label("No profile yet — press Calibrate once kernels are measured on the shots, or load a profile.");
    }
}

/// The chosen α and β of each family with their held-out errors.
fn chosen_models_ui(ui: &mut egui::Ui, families: &[(&str, &crate::crossval::Selection)]) {
    egui::Grid::new("cv-chosen")
        .striped(true)
        .spacing([18.0, 4.0])
        .show(ui, |ui| {
            ui.label("chosen");
            ui.label("α").on_hover_text(TIP_ALPHA);
            ui.label("β").on_hover_text(TIP_BETA);
            ui.label("terms");
            ui.label("mean error C_xx").on_hover_text(TIP_CXX);
            ui.label("C_yy").on_hover_text(TIP_CYY);
            ui.label("C_or").on_hover_text(TIP_COR);
            ui.label("95th percentile C_xx / C_yy / C_or");
            ui.end_row();
            for (name, sel) in families {
                ui.colored_label(family_color(name), *name);
                ui.monospace(sel.alpha.to_string());
                ui.monospace(sel.beta.to_string());
                ui.monospace(sel.chosen.terms.to_string());
                for v in sel.chosen.mean_error_pct {
                    ui.monospace(format!("{v:.2} %"));
                }
                ui.monospace(format!(
                    "{:.2} / {:.2} / {:.2} %",
                    sel.chosen.p95_error_pct[0],
                    sel.chosen.p95_error_pct[1],
                    sel.chosen.p95_error_pct[2]
                ));
                ui.end_row();
            }
        });
}

/// The cross-validation error over α (`by_alpha`) or β, one curve per family, the
/// chosen order marked.
fn cv_order_plot_ui(
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
    families: &[(&str, &crate::crossval::Selection)],
    (title, tip, by_alpha): (&str, &str, bool),
    size: PlotSize,
) {
    use egui_plot::{
        Corner, Legend, Line, LineStyle, MarkerShape, Plot, PlotPoints, Points, VLine,
    };
    let PlotSize {
        width: plot_w,
        height: plot_h,
        report_id,
    } = size;
    let integer_ticks = |mark: egui_plot::GridMark, _: &std::ops::RangeInclusive<f64>| {
        if (mark.value - mark.value.round()).abs() < 1e-9 {
            format!("{:.0}", mark.value)
        } else {
            String::new()
        }
    };
    let axis = crate::review::cv_curve_axis(families.iter().map(|(_, sel)| *sel), by_alpha);
    ui.vertical(|ui| {
        let title = if axis.points_above {
            format!("{title}; higher errors above the plot")
        } else {
            title.to_owned()
        };
        let id = if by_alpha {
            PlotId::CvAlpha
        } else {
            PlotId::CvBeta
        };
        super::plot_title_ui(out, ui, id, title, tip, plot_w);
        // Fixed bounds are kept in the plot's memory: a new report gets a new plot.
        let plot = Plot::new(format!("cv-{by_alpha}-{report_id}"))
            .width(plot_w)
            .height(plot_h)
            .custom_x_axes(vec![
                super::x_axis(if by_alpha {
                    "α (order in x, y)"
                } else {
                    "β (order in f, a)"
                })
                .formatter(integer_ticks),
            ])
            .custom_y_axes(vec![super::y_axis("mean error (% of range)")])
            .x_grid_spacer(egui_plot::uniform_grid_spacer(|_| [1.0, 5.0, 10.0]))
            .default_y_bounds(0.0, axis.top)
            .legend(Legend::default().position(Corner::RightTop))
            .allow_scroll(false);
        super::show_plot(ui, id, plot, |plot| {
            for (name, sel) in families {
                let color = family_color(name);
                let pts = crate::review::cv_curve(sel, by_alpha);
                plot.line(
                    Line::new(name.to_string(), PlotPoints::from(pts.clone()))
                        .color(color)
                        .width(1.5),
                );
                plot.points(
                    Points::new(name.to_string(), PlotPoints::from(pts))
                        .color(color)
                        .filled(true)
                        .radius(3.0),
                );
                // The chosen order: a dashed line; on the β curve (where the
                // chosen α, β lies) a diamond too. Unnamed: not in the legend.
                let chosen = if by_alpha { sel.alpha } else { sel.beta } as f64;
                plot.vline(
                    VLine::new("", chosen)
                        .color(color.gamma_multiply(0.6))
                        .style(LineStyle::dashed_loose()),
                );
                if !by_alpha {
                    plot.points(
                        Points::new("", PlotPoints::from(vec![[chosen, sel.chosen.mean_pct]]))
                            .shape(MarkerShape::Diamond)
                            .color(color)
                            .filled(false)
                            .radius(7.0),
                    );
                }
            }
        });
    });
}

/// The held-out error distributions of the chosen models (Fig. 6).
fn cv_cdf_plot_ui(
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
    families: &[(&str, &crate::crossval::Selection)],
    size: PlotSize,
) {
    use egui_plot::{Line, Plot, PlotPoints};
    let PlotSize {
        width: plot_w,
        height: plot_h,
        report_id,
    } = size;
    ui.vertical(|ui| {
        super::plot_title_ui(
            out,
            ui,
            PlotId::CvCdf,
            "Error CDF of the chosen models (Fig. 6)".to_owned(),
            "Fraction of held-out samples whose prediction error is below each value: solid C_xx, dashed C_yy, dotted C_or",
            plot_w,
        );
        cdf_legend_ui(ui, families, plot_w);
        let x_end = crate::review::cv_cdf_axis_end(families.iter().map(|(_, sel)| *sel));
        let plot = Plot::new(format!("cv-cdf-{report_id}"))
            .width(plot_w)
            .height(plot_h - CDF_LEGEND_H)
            .custom_x_axes(vec![super::x_axis("error (% of range)")])
            .custom_y_axes(vec![super::y_axis("held-out samples (%)")])
            .default_x_bounds(0.0, x_end)
            .default_y_bounds(0.0, 101.0)
            .allow_scroll(false);
        super::show_plot(ui, PlotId::CvCdf, plot, |plot| {
                for (name, sel) in families {
                    let color = family_color(name);
                    // The legend above the plot shows these same styles.
                    for ((param, pts), (_, style)) in
                        crate::review::cv_cdf_curves(sel).into_iter().zip(CDF_STYLES)
                    {
                        plot.line(
                            Line::new(format!("{name} {param}"), PlotPoints::from(pts))
                                .color(color)
                                .style(style)
                                .width(1.5),
                        );
                    }
                }
            });
    });
}

/// The line styles that tell the CDF's parameters apart, as the plot draws them.
const CDF_STYLES: [(&str, egui_plot::LineStyle); 3] = [
    ("C_xx", egui_plot::LineStyle::Solid),
    ("C_yy", egui_plot::LineStyle::Dashed { length: 5.0 }),
    ("C_or", egui_plot::LineStyle::Dotted { spacing: 5.0 }),
];

/// Height of the CDF's legend row, taken from its plot so the three plots end level.
const CDF_LEGEND_H: f32 = 22.0;

/// The CDF's legend above its plot: each family's colour, and a sample of each
/// parameter's line style (solid, dashed, dotted) so the curves read without colour.
fn cdf_legend_ui(ui: &mut egui::Ui, families: &[(&str, &crate::crossval::Selection)], width: f32) {
    ui.horizontal(|ui| {
        ui.set_max_width(width);
        ui.set_height(CDF_LEGEND_H - 4.0);
        // Tight, so that both families and the three styles fit a third of the window.
        ui.spacing_mut().item_spacing.x = 5.0;
        for (name, _) in families {
            ui.colored_label(family_color(name), *name);
        }
        ui.separator();
        let color = ui.visuals().text_color();
        for (param, style) in CDF_STYLES {
            let (r, _) = ui.allocate_exact_size(egui::Vec2::new(24.0, 12.0), egui::Sense::hover());
            let line = [r.left_center(), r.right_center()];
            let shapes = match style {
                egui_plot::LineStyle::Solid => {
                    vec![egui::Shape::line_segment(
                        line,
                        egui::Stroke::new(1.5, color),
                    )]
                }
                egui_plot::LineStyle::Dashed { length } => egui::Shape::dashed_line(
                    &line,
                    egui::Stroke::new(1.5, color),
                    length,
                    length * (std::f32::consts::GOLDEN_RATIO - 1.0),
                ),
                egui_plot::LineStyle::Dotted { spacing } => {
                    egui::Shape::dotted_line(&line, color, spacing, 1.5)
                }
            };
            ui.painter().extend(shapes);
            ui.label(param);
        }
    });
}

/// What the session's settings allow the model: warnings where it cannot be
/// determined, notes where it is limited, each saying what to shoot next.
pub(super) fn advice_ui(calibrated: Option<&Calibrated>, ui: &mut egui::Ui) {
    let Some(c) = calibrated else {
        return;
    };
    for a in &c.advice {
        match a.level {
            crate::review::AdviceLevel::Warning => {
                ui.colored_label(ui.visuals().warn_fg_color, format!("Warning: {}", a.text));
            }
            crate::review::AdviceLevel::Note => {
                ui.weak(format!("Note: {}", a.text));
            }
        }
    }
}

/// The kernel-shape cross-validation the profile holds: per aperture, how far the
/// predicted kernels miss the held-out measured ones with the Gaussians alone and with
/// the best shape model.
fn shape_cv_ui(ui: &mut egui::Ui, p: &crate::profile::Profile) {
    let Some(cv) = &p.shape_cv else {
        ui.label("Kernel shapes: no shape cross-validation in this profile (calibrated without measured kernels, or written before shape models); deblurring uses its Gaussians.");
        return;
    };
    let verdict = match (&cv.best_shape, cv.shape_chosen) {
        (Some(b), true) => format!(
            "the profile holds the shape model ({} component{}, α {}, β {}) and deblurs with it",
            b.components,
            if b.components == 1 { "" } else { "s" },
            b.alpha,
            b.beta
        ),
        _ => "cross-validation kept the Gaussians".to_owned(),
    };
    let around = match crate::model::ModelKind::parse_name(&cv.gaussian_model) {
        Some((k, a, b)) => format!("the {} ({})", k.in_words(a, b), k.symbol(a, b)),
        None => cv.gaussian_model.clone(),
    };
    ui.label(format!(
        "Kernel shapes: {} held-out kernels in {} folds, predicted around {around}; chosen by {}: {verdict}. Held-out error of predicted against measured kernels:",
        cv.kernels,
        cv.folds,
        cv.criterion.name()
    ))
    .on_hover_text(format!("{TIP_REL_L2}\n{TIP_RESTORATION}"));
    egui::Grid::new("shape-cv")
        .striped(true)
        .spacing([18.0, 2.0])
        .show(ui, |ui| {
            ui.label("aperture");
            ui.label("all");
            for a in &cv.per_aperture {
                ui.label(format!("f/{:.1}", a.f_number));
            }
            ui.end_row();
            // Both errors are fractions; shown in percent, as the Gaussian models' are.
            let row = |ui: &mut egui::Ui,
                       name: &str,
                       tip: &str,
                       all: f64,
                       per: &dyn Fn(&crate::crossval::ApertureError) -> f64| {
                ui.label(name).on_hover_text(tip);
                ui.monospace(format!("{:.1} %", 100.0 * all));
                for a in &cv.per_aperture {
                    ui.monospace(format!("{:.1} %", 100.0 * per(a)));
                }
                ui.end_row();
            };
            row(
                ui,
                "Gaussian, kernel error (relative L2)",
                TIP_REL_L2,
                cv.gaussian.mean_rel_l2,
                &|a| a.gaussian_mean_rel_l2,
            );
            if let Some(b) = &cv.best_shape {
                row(
                    ui,
                    "shapes, kernel error (relative L2)",
                    TIP_REL_L2,
                    b.mean_rel_l2,
                    &|a| a.shape_mean_rel_l2,
                );
            }
            let restoration = |v: Option<f64>| v.unwrap_or(f64::NAN);
            if let Some(g) = cv.gaussian.restoration_rms {
                row(
                    ui,
                    "Gaussian, error left in a deblurred photo",
                    TIP_RESTORATION,
                    g,
                    &|a| restoration(a.gaussian_restoration_rms),
                );
                if let Some(b) = &cv.best_shape {
                    row(
                        ui,
                        "shapes, error left in a deblurred photo",
                        TIP_RESTORATION,
                        restoration(b.restoration_rms),
                        &|a| restoration(a.shape_restoration_rms),
                    );
                }
            }
        });
}

/// The shooting plan: the lens's range (typed, or the session's), and every setting to
/// shoot as a checklist of the shots the session has and those still missing.
fn plan_ui(m: &ModelsContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let Some(c) = m.calibrated else {
        ui.label("Open a session to plan its shots.");
        return;
    };
    let mut r = c.plan_range;
    ui.horizontal_wrapped(|ui| {
        ui.label("The lens: focal length");
        let mut changed = false;
        for (v, tip) in r.focal_mm.iter_mut().zip(["The widest focal length (a prime: its focal length here and in the next box)", "The longest focal length"]) {
            changed |= ui
                .add(egui::DragValue::new(v).range(1.0..=2000.0).suffix(" mm").speed(1.0))
                .on_hover_text(tip)
                .changed();
        }
        ui.label("apertures f/");
        for (v, tip) in r.f_number.iter_mut().zip(["Wide open: the lens's largest aperture (smallest f-number)", "The smallest aperture you use (the plan stops at f/11: past it diffraction blurs every lens alike)"]) {
            changed |= ui
                .add(egui::DragValue::new(v).range(0.7..=64.0).speed(0.1).max_decimals(1))
                .on_hover_text(tip)
                .changed();
        }
        if changed {
            out.push(Command::View(ViewCommand::SetPlanRange(r)));
        }
    });
    let progress = crate::review::plan_progress(&c.plan);
    let off = match progress.off_plan {
        0 => String::new(),
        n => format!(" and {n} off it"),
    };
    ui.label(format!(
        "{} setting{} shot: {} of the plan's {}{off}; {} with the {} shots each recommended (on a tripod, RAW, base ISO, focused on the chart, the chart filling the frame or shot at several positions that together cover it):",
        progress.settings_shot,
        if progress.settings_shot == 1 { "" } else { "s" },
        progress.planned_shot,
        progress.planned,
        progress.complete,
        crate::review::SHOTS_PER_SETTING
    ))
    .on_hover_text("A setting counts once it has a shot; a second shot there lets cross-validation hold one out and still fit the setting. Settings off the plan's grid count too: the model is fitted to every shot.");
    let grid = crate::review::plan_grid(&c.plan);
    let (ok, missing) = (ui.visuals().text_color(), ui.visuals().warn_fg_color);
    egui::Grid::new("shooting plan grid")
        .striped(true)
        .show(ui, |ui| {
            ui.label("");
            for a in &grid.apertures {
                ui.strong(format!("f/{a:.1}"));
            }
            ui.end_row();
            for (f, row) in grid.focals.iter().zip(&grid.cells) {
                ui.strong(format!("{f:.0} mm"));
                for cell in row {
                    match cell {
                        Some(p) => {
                            let colour = if p.shot >= p.wanted { ok } else { missing };
                            let text = match p.shot {
                                0 => format!("0 of {}", p.wanted),
                                n => format!("{n} shot{}", if n == 1 { "" } else { "s" }),
                            };
                            let text = if p.on_plan {
                                text
                            } else {
                                format!("{text} (off plan)")
                            };
                            ui.colored_label(colour, text).on_hover_text(format!(
                                "{} of the {} shots recommended at {:.0} mm f/{:.1}{}",
                                p.shot,
                                p.wanted,
                                p.setting.focal_mm,
                                p.setting.f_number,
                                if p.on_plan {
                                    ""
                                } else {
                                    ", a setting off the plan's grid"
                                }
                            ));
                        }
                        None => {
                            ui.label("");
                        }
                    }
                }
                ui.end_row();
            }
        });
    super::coverage::coverage_ui(m.coverage, m.sensor, ui);
}

/// What relative L2 is, for a photographer.
const TIP_REL_L2: &str = "Kernel error (relative L2): how far the predicted kernel is from the one measured on a held-out shot, as the size of their difference over the size of the measured kernel (‖predicted − measured‖ / ‖measured‖). 0 % is a perfect prediction; 100 % an error as large as the kernel itself.";

/// What the restoration error is, for a photographer.
const TIP_RESTORATION: &str = "Error left in a deblurred photo: deblurring a held-out shot with the predicted kernel instead of the measured one leaves this RMS error, in percent of the photo's edge contrast (the RMS of its gradient). Lower is better; it is what the shape model is chosen by.";
