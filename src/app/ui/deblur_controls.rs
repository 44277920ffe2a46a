//! The Deblur view's controls: zoom, region, amount, and under *Advanced* the method,
//! its strength and the device.

use super::super::{Command, DeblurState, DeblurZoom, PreviewScope};
use crate::app::DeblurCommand;
use crate::deblur::{Device, HqsParams, IrlsParams, Method, WienerParams};

/// Zoom, region size and the amount, with the method, its strength and the device
/// under *Advanced*: each change deblurs the region again (a newer preview replaces one
/// still running), so dragging a control updates the region live.
///
/// `method` is the view's (its own, else the session's); `has_place` whether the profile
/// records where each channel's kernels sit (lateral colour can then be corrected).
pub(super) fn controls_ui(
    state: &DeblurState,
    (method, has_place): (Method, bool),
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) {
    ui.horizontal_wrapped(|ui| {
        ui.label("zoom");
        for z in DeblurZoom::ALL {
            if ui
                .selectable_label(state.zoom == z, z.label())
                .on_hover_text("Fit: the region scaled into the panes; 100–400 %: one photo pixel on 1, 2 or 4 screen pixels, the region as large as the panes (drag a pane to pan; all panes move together)")
                .clicked()
            {
                out.push(Command::Deblur(DeblurCommand::SetDeblurZoom(z)));
            }
        }
        if state.zoom == DeblurZoom::Fit {
            let mut side = state.crop_px as f64;
            let r = ui
                .add(
                    egui::Slider::new(&mut side, 64.0..=1024.0)
                        .logarithmic(true)
                        .suffix(" px")
                        .text("region"),
                )
                .on_hover_text("Side of the compared region, photo pixels");
            if r.drag_stopped() || (r.changed() && !r.dragged()) {
                out.push(Command::Deblur(DeblurCommand::SetDeblurCrop(side.round() as usize)));
            }
        }
        ui.separator();
        let mut amount = state.amount.as_percent();
        let r = ui
            .add(
                egui::Slider::new(&mut amount, 0.0..=crate::deblur::Amount::MAX_PERCENT)
                    .step_by(5.0)
                    .suffix(" %")
                    .text("amount"),
            )
            .on_hover_text("How strongly to deblur: 0 % is the photo as it is, 100 % the method at its tuned strength, more carries it further (and sharpens noise)");
        if r.changed() {
            out.push(Command::Deblur(DeblurCommand::SetDeblurAmount(amount)));
        }
    });
    egui::CollapsingHeader::new("Advanced: method and device")
        .id_salt("deblur advanced")
        .show(ui, |ui| advanced_ui(state, (method, has_place), out, ui));
    // Always one line, so the panes below keep their size when the note arrives.
    let note = state.device_note.as_ref().map_or_else(
        || " ".to_owned(),
        |n| format!("The preview runs on the {n}."),
    );
    ui.label(egui::RichText::new(note).weak());
    // What it deblurs, and why not the whole photo: also one line, always.
    let scope = match &state.scope {
        None | Some(PreviewScope::Trial) => " ".to_owned(),
        Some(PreviewScope::Whole { ms }) => {
            format!("At Fit it deblurs the whole photo as the controls move ({ms:.0} ms).")
        }
        Some(PreviewScope::Crops(why)) => why.clone(),
    };
    ui.label(egui::RichText::new(scope).weak());
}

/// The method, its regularisation and where it runs: for those who know them.
fn advanced_ui(
    state: &DeblurState,
    (method, has_place): (Method, bool),
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
) {
    ui.horizontal_wrapped(|ui| {
        ui.label("method");
        let choices = [
            ("HQS", matches!(method, Method::Hqs(_)), Method::Hqs(HqsParams::default())),
            ("Wiener", matches!(method, Method::Wiener(_)), Method::Wiener(WienerParams::default())),
            ("IRLS", matches!(method, Method::Irls(_)), Method::Irls(IrlsParams::default())),
        ];
        for (label, on, m) in choices {
            if ui
                .selectable_label(on, label)
                .on_hover_text("HQS: hyper-Laplacian prior, fast (the default); Wiener: quadratic prior, fastest, rings more; IRLS: the paper's solver, slow, CPU only")
                .clicked()
                && !on
            {
                out.push(Command::Deblur(DeblurCommand::SetDeblurMethod(m)));
            }
        }
        strength_ui(out, ui, method);
        ui.separator();
        let mut suppress = state.fringes == crate::deblur::Fringes::Suppress;
        if ui
            .checkbox(&mut suppress, "no colour fringes")
            .on_hover_text("Hold each deblurred pixel's colour inside the colours the photo has around it: the channels' deconvolutions ring a little differently, and at strong neutral edges that shows as fringes the scene never had (RGB photos; a RAW photo's Bayer planes are left as they are)")
            .changed()
        {
            out.push(Command::Deblur(DeblurCommand::SetDeblurFringes(if suppress {
                crate::deblur::Fringes::Suppress
            } else {
                crate::deblur::Fringes::Keep
            })));
        }
        let mut correct = state.lateral == crate::model::LateralColour::Correct;
        if ui
            .add_enabled(has_place, egui::Checkbox::new(&mut correct, "correct lateral colour"))
            .on_hover_text("Move red and blue back onto green as the blur is removed, where the profile measured how far the lens moves them. Leave it off when darktable or RawTherapee corrects lateral colour with the lens's lensfun entry, or the channels move twice")
            .on_disabled_hover_text("This profile does not record where each channel's kernels sit (it was calibrated before profile version 4, or from shots whose kernels were not kept): calibrate again to correct lateral colour")
            .changed()
        {
            out.push(Command::Deblur(DeblurCommand::SetDeblurLateral(if correct {
                crate::model::LateralColour::Correct
            } else {
                crate::model::LateralColour::Keep
            })));
        }
        ui.separator();
        ui.label("device");
        for (device, label, tip) in [
            (Device::Auto, "Auto", "The GPU the window draws with when it is a hardware one, else the CPU"),
            (Device::Gpu, "GPU", "The window's GPU whatever it is (a software rasteriser is slow)"),
            (Device::Cpu, "CPU", "The reference path"),
        ] {
            if ui
                .selectable_label(state.device == device, label)
                .on_hover_text(tip)
                .clicked()
            {
                out.push(Command::Deblur(DeblurCommand::SetDeblurDevice(device)));
            }
        }
    });
}

/// The regularisation strength of the method: the data weight λ of HQS and IRLS (more:
/// sharper and noisier), the noise-to-signal ratio of Wiener (more: smoother).
fn strength_ui(out: &mut Vec<Command>, ui: &mut egui::Ui, method: Method) {
    let (mut v, range, text, tip) = match method {
        Method::Hqs(p) => (
            p.lambda,
            100.0..=100_000.0,
            "λ",
            "Data weight: higher sharpens more and keeps more noise",
        ),
        Method::Irls(p) => (
            p.lambda,
            100.0..=100_000.0,
            "λ",
            "Data weight: higher sharpens more and keeps more noise",
        ),
        Method::Wiener(p) => (p.nsr, 1e-5..=0.1, "noise/signal", "Higher smooths more"),
    };
    let r = ui
        .add(
            egui::Slider::new(&mut v, range)
                .logarithmic(true)
                .text(text),
        )
        .on_hover_text(tip);
    if r.changed() {
        let m = match method {
            Method::Hqs(p) => Method::Hqs(HqsParams { lambda: v, ..p }),
            Method::Irls(p) => Method::Irls(IrlsParams { lambda: v, ..p }),
            Method::Wiener(_) => Method::Wiener(WienerParams { nsr: v }),
        };
        out.push(Command::Deblur(DeblurCommand::SetDeblurMethod(m)));
    }
}
