//! The session panel: the shots with their settings and stage results, the buttons that
//! run each stage, and the session's settings.

use super::super::{Command, SessionPanelState, ViewerContext};
use super::Frame;
use crate::app::jobs::JobKind;
use crate::app::{DialogCommand, SessionCommand, StageCommand, ViewCommand};
use crate::session::{Session, Shot, ShotId, StageStatus};
use egui::{Color32, Sense};

/// What the session panel draws from: the session, its shots' thumbnails and results,
/// the shot selected and the settings being edited.
pub(super) struct SessionPanelContext<'a> {
    cx: ViewerContext<'a>,
    state: &'a SessionPanelState,
    selected: Option<ShotId>,
    /// The demo session is still being made (its shots arrive one by one).
    making_demo: bool,
}

impl<'a> SessionPanelContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            cx: f.cx,
            state: &f.views.session,
            selected: f.views.shot.selected,
            making_demo: f.jobs.is_running(JobKind::DemoSession),
        }
    }
}

fn status_text(s: &StageStatus) -> String {
    match s {
        StageStatus::Pending => "—".into(),
        StageStatus::Done { summary } => summary.clone(),
        StageStatus::Failed { reason } => format!("failed: {reason}"),
    }
}

pub(super) fn session_panel_ui(
    p: &SessionPanelContext<'_>,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) {
    let Some(session) = p.cx.session() else {
        ui.heading("Session");
        if p.making_demo {
            ui.label("Making the demo session: simulated calibration shots of the virtual lens (first launch only; progress below)…");
        } else {
            ui.label("No session open. Open or create a session folder (Ctrl+O).");
        }
        return;
    };
    ui.heading(&session.name)
        .on_hover_text(format!("Session folder: {}", session.folder().display()));
    if session.is_demo {
        ui.label("Demo: shots simulated from the virtual lens, whose true blur is known.");
        if p.making_demo {
            ui.label(
                egui::RichText::new(
                    "More shots arrive as they are simulated (first launch only; progress below).",
                )
                .weak(),
            );
        }
    }
    stage_buttons_ui(out, ui);
    ui.separator();
    let n = session.shots.len();
    ui.label(if n == 1 {
        "1 shot".to_owned()
    } else {
        format!("{n} shots")
    });
    for shot in &session.shots {
        shot_entry_ui(p, session, shot, out, ui);
    }
    if n > 0 {
        ui.label(
            egui::RichText::new(
                "Right-click a shot to detect it or estimate its kernels again (only that shot), or to remove it.",
            )
            .small()
            .weak(),
        );
    }
    ui.separator();
    settings_ui(p, out, ui);
}

/// The buttons that run each stage over the session.
fn stage_buttons_ui(out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal_wrapped(|ui| {
        if ui
            .button(egui::RichText::new("Calibrate all").strong())
            .on_hover_text(
                "Detect, estimate kernels and calibrate whatever is missing, as one job; the profile is then in use (Ctrl+Enter)",
            )
            .clicked()
        {
            out.push(Command::Stage(StageCommand::CalibrateAll { then_deblur: false }));
        }
        if ui
            .button("Add shots…")
            .on_hover_text(
                "RAW, DNG, TIFF, PNG or JPEG; or drop files on the window (Ctrl+Shift+A)",
            )
            .clicked()
        {
            out.push(Command::Dialog(DialogCommand::AddShotsDialog));
        }
        if ui
            .button("Detect")
            .on_hover_text("Find and align the chart's squares in every shot (Ctrl+D)")
            .clicked()
        {
            out.push(Command::Stage(StageCommand::RunDetect(None)));
        }
        if ui
            .button("Kernels")
            .on_hover_text("Estimate the blur kernel at every square (Ctrl+K)")
            .clicked()
        {
            out.push(Command::Stage(StageCommand::RunKernels(None)));
        }
        if ui
            .button("Calibrate")
            .on_hover_text("Cross-validate and fit the blur model; write the profile (Ctrl+M)")
            .clicked()
        {
            out.push(Command::Stage(StageCommand::RunCalibrate));
        }
    });
}

/// One shot: its thumbnail, name, settings and stage results; a click selects it, a
/// right-click offers its stages again and its removal.
fn shot_entry_ui(
    p: &SessionPanelContext<'_>,
    session: &Session,
    shot: &Shot,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) {
    let id = shot.id;
    let selected = p.selected == Some(id);
    let frame = egui::Frame::group(ui.style()).fill(if selected {
        ui.visuals().selection.bg_fill.gamma_multiply(0.35)
    } else {
        Color32::TRANSPARENT
    });
    let r = frame.show(ui, |ui| {
        ui.horizontal(|ui| {
            match (
                p.cx.preview(id).and_then(|v| v.thumbnail.as_ref()),
                p.cx.unreadable(id),
            ) {
                (Some(t), _) => {
                    let size = t.size_vec2() * (72.0 / t.size_vec2().x.max(1.0));
                    ui.image((t.id(), size));
                }
                (None, Some(reason)) => {
                    ui.add_sized(
                        [72.0, 48.0],
                        egui::Label::new(
                            egui::RichText::new("unreadable").color(ui.visuals().error_fg_color),
                        ),
                    )
                    .on_hover_text(reason);
                }
                (None, None) => {
                    ui.add_sized([72.0, 48.0], egui::Spinner::new());
                }
            }
            ui.vertical(|ui| {
                let name = shot.path.file_name().map_or_else(
                    || shot.path.display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                );
                if ui
                    .selectable_label(selected, name)
                    .on_hover_text(p.cx.shown_path(&session.path_of(shot)))
                    .clicked()
                {
                    out.push(Command::View(ViewCommand::SelectShot(id)));
                }
                ui.horizontal(|ui| {
                    // Unknown settings show as "?" (0 internally) until the user drags.
                    let mut f = shot.focal_mm.unwrap_or(0.0);
                    let mut a = shot.f_number.unwrap_or(0.0);
                    let (rf, ra) = super::setting_drag_values(
                        ui,
                        (&mut f, &mut a),
                        [
                            "focal length, mm (from EXIF; drag or type)",
                            "aperture, f-number (from EXIF; drag or type)",
                        ],
                    );
                    if rf.changed() || ra.changed() {
                        out.push(Command::Session(SessionCommand::SetShotSetting {
                            shot: id,
                            focal_mm: (f > 0.0).then_some(f),
                            f_number: (a > 0.0).then_some(a),
                        }));
                    }
                });
                let failed = matches!(shot.detect, StageStatus::Failed { .. })
                    || matches!(shot.kernels, StageStatus::Failed { .. });
                let text = egui::RichText::new(format!(
                    "detect: {}\nkernels: {}",
                    status_text(&shot.detect),
                    status_text(&shot.kernels)
                ))
                .small();
                let text = if failed {
                    text.color(ui.visuals().error_fg_color)
                } else {
                    text
                };
                ui.add(egui::Label::new(text).wrap());
            });
        });
    });
    let response = r.response.interact(Sense::click());
    if response.clicked() {
        out.push(Command::View(ViewCommand::SelectShot(id)));
    }
    // Each entry says what it will do for this shot: run a stage for the first
    // time or again, or why it cannot yet.
    let detected = p.cx.detection(id).is_some();
    let measured = p.cx.kernels(id).is_some();
    response.context_menu(|ui| {
        let detect = if detected {
            "Detect this shot again"
        } else {
            "Detect this shot"
        };
        if ui.button(detect).clicked() {
            out.push(Command::Stage(StageCommand::RunDetect(Some(id))));
            ui.close();
        }
        let kernels = if measured {
            "Estimate its kernels again"
        } else {
            "Estimate its kernels"
        };
        if ui
            .add_enabled(detected, egui::Button::new(kernels))
            .on_disabled_hover_text("Detect the chart in this shot first")
            .clicked()
        {
            out.push(Command::Stage(StageCommand::RunKernels(Some(id))));
            ui.close();
        }
        if ui.button("Remove from the session…").clicked() {
            out.push(Command::Dialog(DialogCommand::AskConfirm(
                super::super::Confirm::RemoveShot(id),
            )));
            ui.close();
        }
    });
}

/// The chart and the stage settings, edited on a copy and applied by one button (a
/// change of chart or kernel settings makes earlier results stale).
fn settings_ui(p: &SessionPanelContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let Some(session) = p.cx.session() else {
        return;
    };
    let current = (session.chart.clone(), session.settings.clone());
    egui::CollapsingHeader::new("Settings")
        .default_open(false)
        .show(ui, |ui| {
            // The draft is edited here and handed back as a command; the app keeps it.
            let before = p.state.settings_edit.clone().unwrap_or_else(|| current.clone());
            let mut draft = before.clone();
            let (chart, s) = (&mut draft.0, &mut draft.1);
            ui.strong("Chart");
            egui::Grid::new("chart-settings").num_columns(2).show(ui, |ui| {
                ui.label("squares across");
                ui.add(egui::DragValue::new(&mut chart.cols).range(2..=200));
                ui.end_row();
                ui.label("squares down");
                ui.add(egui::DragValue::new(&mut chart.rows).range(2..=200));
                ui.end_row();
                ui.label("square side");
                ui.add(
                    egui::DragValue::new(&mut chart.square_mm)
                        .range(1.0..=500.0)
                        .speed(0.1)
                        .suffix(" mm"),
                );
                ui.end_row();
            });
            let mut load_chart = false;
            ui.horizontal(|ui| {
                load_chart = ui
                    .button("Load chart spec…")
                    .on_hover_text("A chart.json written by `lensblur chart --spec-out`")
                    .clicked();
                if ui.button("Default chart").clicked() {
                    *chart = crate::chart::ChartSpec::default();
                }
            });
            ui.strong("Kernels");
            ui.horizontal(|ui| {
                ui.label("oversampling")
                    .on_hover_text("Kernel super-resolution factor (odd; the paper uses 3)");
                for k in [1usize, 3, 5] {
                    ui.selectable_value(&mut s.oversample, k, format!("{k}×"));
                }
            });
            ui.checkbox(&mut s.weight_all_subpixels, "weight every sub-pixel (W = I)")
                .on_hover_text("Off: only the sub-pixels at real pixel centres carry data (the default).");
            ui.strong("Model");
            let mut auto = s.alpha.is_none();
            ui.checkbox(&mut auto, "α and β chosen by cross-validation")
                .on_hover_text(format!("{}\n{}", super::TIP_ALPHA, super::TIP_BETA));
            if auto {
                s.alpha = None;
                s.beta = None;
            } else {
                let mut a = s.alpha.unwrap_or(6);
                let mut b = s.beta.unwrap_or(1);
                ui.horizontal(|ui| {
                    ui.label("α").on_hover_text(super::TIP_ALPHA);
                    ui.add(egui::DragValue::new(&mut a).range(0..=15));
                    ui.label("β").on_hover_text(super::TIP_BETA);
                    ui.add(egui::DragValue::new(&mut b).range(0..=15));
                });
                s.alpha = Some(a);
                s.beta = Some(b);
            }
            ui.strong("Deblur");
            ui.horizontal(|ui| {
                ui.label("method");
                for (m, tip) in [
                    ("hqs", "half-quadratic splitting with a hyper-Laplacian prior (fast)"),
                    ("irls", "iteratively reweighted least squares (Levin et al., slower)"),
                    ("wiener", "Wiener filter (instant, rings more)"),
                ] {
                    ui.selectable_value(&mut s.deblur_method, m.to_owned(), m)
                        .on_hover_text(tip);
                }
            });
            let changed = (chart.clone(), s.clone()) != current;
            let (chart, s) = (chart.clone(), s.clone());
            ui.horizontal(|ui| {
                if ui
                    .add_enabled(changed, egui::Button::new("Apply"))
                    .on_hover_text(
                        "A new chart resets detection and kernels; new kernel settings reset kernels",
                    )
                    .clicked()
                {
                    out.push(Command::Session(SessionCommand::ApplySettings {
                        chart,
                        settings: s,
                    }));
                }
                if ui.add_enabled(changed, egui::Button::new("Revert")).clicked() {
                    out.push(Command::Session(SessionCommand::EditSettings(None)));
                }
            });
            if draft != before {
                out.push(Command::Session(SessionCommand::EditSettings(Some(draft))));
            }
            if load_chart {
                out.push(Command::Dialog(DialogCommand::LoadChartDialog));
            }
        });
}
