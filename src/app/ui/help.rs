//! The Help menu's windows: how the studio works in five steps, the guide to
//! calibrating your own lens (`docs/guide.md`, compiled in), and About.

use super::super::{Command, Window};
use crate::app::WindowCommand;

/// The workflow in a few lines, for someone who has never calibrated a lens.
const HELP: &[(&str, &str)] = &[
    (
        "1. Shoot the chart",
        "Print a chart (assets/chart_a4.pdf, chart_a3.pdf or chart_a2.pdf, at 100 %), fix it flat, and photograph it filling the frame at the settings of the shooting plan (Models view), focused on the chart, on a tripod, at base ISO, in RAW. Help ▸ Calibrate your own lens has every step.",
    ),
    (
        "2. Make a session",
        "File ▸ Open session… on an empty folder, then Add shots… or drop the files on the window. Focal length and aperture come from EXIF; type them where missing.",
    ),
    (
        "3. Calibrate all",
        "Calibrate all (Ctrl+Enter) detects the chart's squares in every shot, measures the blur at each square and fits a model of it over the frame, focal length and aperture: the lens profile. Detect (Ctrl+D), Kernels (Ctrl+K) and Calibrate (Ctrl+M) run one stage each; right-click a shot to redo it.",
    ),
    (
        "4. Check",
        "The Shot and Kernel field views show what was found at every square; Sweeps and Models how well the model fits, and what to shoot next.",
    ),
    (
        "5. Deblur",
        "Open a photo (Ctrl+P) in the Deblur view, click where to look, compare, and export it (Ctrl+E): a RAW photo as a DNG for your RAW editor.",
    ),
];

pub(super) fn help_ui(window: &Window, out: &mut Vec<Command>, ctx: &egui::Context) {
    let mut open = window.show_help;
    egui::Window::new("How the studio works")
        .open(&mut open)
        .collapsible(false)
        .pivot(egui::Align2::CENTER_CENTER)
        .default_pos(ctx.content_rect().center())
        .default_width(460.0)
        .show(ctx, |ui| {
            for (step, what) in HELP {
                ui.strong(*step);
                ui.label(*what);
                ui.add_space(4.0);
            }
            ui.label(
                egui::RichText::new(
                    "The demo session is made from a virtual lens whose true blur is known: every view can compare what was measured with the truth.",
                )
                .weak(),
            );
        });
    if !open {
        out.push(Command::Window(WindowCommand::ShowHelp(false)));
    }
}

/// The crates the studio is built on, as the About window credits them.
const CRATES: &[&str] = &[
    "egui, eframe, egui_plot, wgpu (the window)",
    "rfd (file dialogs)",
    "rawloader, imagepipe, ljpeg, kamadak-exif (RAW files and EXIF)",
    "image, tiff, imageproc (images)",
    "nalgebra, levenberg-marquardt, rustfft, realfft, rayon (the numerics)",
    "serde, serde_json, clap, thiserror, anyhow (files, command line, errors)",
    "pdf-writer, svg, flate2 (the chart)",
];

pub(super) fn about_ui(window: &Window, out: &mut Vec<Command>, ctx: &egui::Context) {
    let mut open = window.show_about;
    egui::Window::new("About lensblur")
        .open(&mut open)
        .collapsible(false)
        .resizable(false)
        .anchor(egui::Align2::CENTER_CENTER, [0.0, 0.0])
        .show(ctx, |ui| {
            ui.heading(format!("lensblur {}", env!("CARGO_PKG_VERSION")));
            ui.label(env!("CARGO_PKG_DESCRIPTION"));
            ui.add_space(6.0);
            ui.label(format!(
                "Licence: {} (GNU General Public License, version 3 or later).",
                env!("CARGO_PKG_LICENSE")
            ));
            ui.label("The demo photo: NASA, public domain (assets/README.md).");
            ui.add_space(6.0);
            ui.strong("Built with");
            for c in CRATES {
                ui.label(format!("• {c}"));
            }
        });
    if !open {
        out.push(Command::Window(WindowCommand::ShowAbout(false)));
    }
}

/// The guide to calibrating your own lens, as the repository has it.
const GUIDE: &str = include_str!("../../../docs/guide.md");

/// The guide in a window: its Markdown drawn plainly (headings, lists, code blocks and
/// tables in monospace), so what the studio shows is the file the repository holds.
pub(super) fn guide_ui(window: &Window, out: &mut Vec<Command>, ctx: &egui::Context) {
    let mut open = window.show_guide;
    egui::Window::new("Calibrate your own lens")
        .open(&mut open)
        .pivot(egui::Align2::CENTER_CENTER)
        .default_pos(ctx.content_rect().center())
        .default_size([640.0, 560.0])
        .show(ctx, |ui| {
            egui::ScrollArea::vertical().show(ui, |ui| {
                let mut code = false;
                for line in GUIDE.lines() {
                    if line.starts_with("```") {
                        code = !code;
                        continue;
                    }
                    if code || line.starts_with('|') {
                        ui.monospace(line);
                    } else if let Some(h) = line.strip_prefix("# ") {
                        ui.heading(h);
                    } else if let Some(h) = line.strip_prefix("## ") {
                        ui.add_space(6.0);
                        ui.strong(h);
                    } else if line.trim().is_empty() {
                        ui.add_space(4.0);
                    } else {
                        ui.label(plain(line));
                    }
                }
            });
        });
    if !open {
        out.push(Command::Window(WindowCommand::ShowGuide(false)));
    }
}

/// A Markdown line without its emphasis marks.
fn plain(line: &str) -> String {
    line.replace(['*', '`'], "")
}
