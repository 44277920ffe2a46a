//! The menu bar and the keyboard shortcuts: what a photographer looks for first.

use super::super::{Command, DeblurResult, View, Window};
use super::Frame;
use crate::app::{DialogCommand, SessionCommand, StageCommand, ViewCommand, WindowCommand};
use crate::plane::Channel;
use crate::session::{Session, ShotId};
use egui::{Key, KeyboardShortcut, Modifiers};
use std::path::Path;

/// What the menus and the shortcuts read: which view and panels are shown, whether a
/// photo and a profile are there to export, the session's shots to step through.
pub(super) struct MenuContext<'a> {
    view: View,
    window: &'a Window,
    session_panel_open: bool,
    has_photo: bool,
    has_profile: bool,
    profile_library: &'a Path,
    session: Option<&'a Session>,
    selected: Option<ShotId>,
}

impl<'a> MenuContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            view: f.view,
            window: f.window,
            session_panel_open: f.views.session.open,
            has_photo: f.views.deblur.photo.is_some(),
            has_profile: f.cx.profile().is_some(),
            profile_library: f.profile_library,
            session: f.cx.session(),
            selected: f.views.shot.selected,
        }
    }
}

/// Every keyboard shortcut, as the Shortcuts menu lists it.
const SHORTCUTS: &[(&str, &str)] = &[
    ("Ctrl+O", "open or create a session folder"),
    ("Ctrl+Shift+A", "add shots"),
    ("Ctrl+D", "detect the chart in every shot"),
    ("Ctrl+K", "estimate kernels on every detected shot"),
    ("Ctrl+M", "calibrate: cross-validate and fit the models"),
    (
        "Ctrl+Enter",
        "calibrate all: detect, kernels and calibrate whatever is missing",
    ),
    ("Ctrl+P", "open a photo to deblur"),
    (
        "Ctrl+E",
        "export the photo deblurred with the predicted Gaussians",
    ),
    (
        "Alt+1 … Alt+7",
        "Shot, Kernel field, Sharpness, Sweeps, Models, Deblur, Geometry",
    ),
    ("Page Up / Page Down", "previous / next shot"),
    ("Alt+R, Alt+G, Alt+B", "red, green, blue channel"),
    ("Ctrl+T", "light or dark theme"),
    ("Ctrl+L", "show or hide the log"),
    ("Ctrl+B", "show or fold the session panel"),
    ("Ctrl+Q", "quit"),
    ("Esc", "cancel every running job"),
];

/// The menus: what a photographer looks for first (open, recent, export, quit), the
/// views and panels, and help.
pub(super) fn menu_bar_ui(m: &MenuContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    egui::MenuBar::new().ui(ui, |ui| {
        ui.menu_button("File", |ui| {
            if ui
                .add(egui::Button::new("Open session…").shortcut_text("Ctrl+O"))
                .on_hover_text("Open or create a session folder")
                .clicked()
            {
                out.push(Command::Dialog(DialogCommand::OpenSessionDialog));
            }
            ui.add_enabled_ui(!m.window.recent.is_empty(), |ui| {
                ui.menu_button("Recent sessions", |ui| {
                    for path in &m.window.recent {
                        let name = path.file_name().map_or_else(
                            || path.display().to_string(),
                            |n| n.to_string_lossy().into_owned(),
                        );
                        if ui
                            .button(name)
                            .on_hover_text(path.display().to_string())
                            .clicked()
                        {
                            out.push(Command::Session(SessionCommand::OpenSession(path.clone())));
                        }
                    }
                });
            })
            .response
            .on_disabled_hover_text("Sessions you open are listed here");
            if ui
                .add(egui::Button::new("Add shots…").shortcut_text("Ctrl+Shift+A"))
                .clicked()
            {
                out.push(Command::Dialog(DialogCommand::AddShotsDialog));
            }
            ui.separator();
            if ui
                .add(egui::Button::new("Open photo…").shortcut_text("Ctrl+P"))
                .on_hover_text("Open a photo to deblur in the Deblur view")
                .clicked()
            {
                out.push(Command::View(ViewCommand::SelectView(View::Deblur)));
                out.push(Command::Dialog(DialogCommand::OpenPhotoDialog));
            }
            ui.menu_button("Export", |ui| export_menu_ui(m, out, ui));
            if ui.button("Load lens profile…").clicked() {
                out.push(Command::Dialog(DialogCommand::LoadProfileDialog));
            }
            ui.separator();
            if ui
                .add(egui::Button::new("Quit").shortcut_text("Ctrl+Q"))
                .clicked()
            {
                out.push(Command::Window(WindowCommand::Quit));
            }
        });
        ui.menu_button("View", |ui| {
            for (k, v) in View::ALL.into_iter().enumerate() {
                if ui
                    .add(
                        egui::Button::selectable(m.view == v, v.label())
                            .shortcut_text(format!("Alt+{}", k + 1)),
                    )
                    .clicked()
                {
                    out.push(Command::View(ViewCommand::SelectView(v)));
                }
            }
            ui.separator();
            if ui
                .add(
                    egui::Button::selectable(m.session_panel_open, "Session panel")
                        .shortcut_text("Ctrl+B"),
                )
                .on_hover_text(
                    "The shots and their stages on the left; folded, the view has the whole width",
                )
                .clicked()
            {
                out.push(Command::Window(WindowCommand::SetSessionPanel(
                    !m.session_panel_open,
                )));
            }
            if ui
                .add(egui::Button::selectable(m.window.log_open, "Log").shortcut_text("Ctrl+L"))
                .on_hover_text("Every message of this run, with its time")
                .clicked()
            {
                out.push(Command::Window(WindowCommand::SetLogOpen(
                    !m.window.log_open,
                )));
            }
            ui.separator();
            for (dark, label) in [(true, "Dark theme"), (false, "Light theme")] {
                if ui
                    .add(
                        egui::Button::selectable(m.window.dark == dark, label)
                            .shortcut_text("Ctrl+T"),
                    )
                    .clicked()
                {
                    out.push(Command::Window(WindowCommand::SetDark(dark)));
                }
            }
        });
        ui.menu_button("Help", |ui| {
            if ui.button("How it works…").clicked() {
                out.push(Command::Window(WindowCommand::ShowHelp(true)));
            }
            if ui.button("Calibrate your own lens (guide)…").clicked() {
                out.push(Command::Window(WindowCommand::ShowGuide(true)));
            }
            ui.menu_button("Shortcuts", |ui| {
                egui::Grid::new("shortcuts").striped(true).show(ui, |ui| {
                    for (keys, what) in SHORTCUTS {
                        ui.monospace(*keys);
                        ui.label(*what);
                        ui.end_row();
                    }
                });
            });
            if ui.button("About lensblur…").clicked() {
                out.push(Command::Window(WindowCommand::ShowAbout(true)));
            }
        });
    });
}

/// File ▸ Export: a photo deblurred, a set of photos, the lens profile (to a file, or
/// into the library a batch reads).
fn export_menu_ui(m: &MenuContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let photo = m.has_photo;
    if ui
        .add_enabled(
            photo,
            egui::Button::new("Photo deblurred (predicted)…").shortcut_text("Ctrl+E"),
        )
        .on_disabled_hover_text("Open a photo first (Ctrl+P)")
        .clicked()
    {
        out.push(Command::Dialog(DialogCommand::ExportDeblurDialog(
            DeblurResult::Predicted,
        )));
    }
    if ui
        .add_enabled(
            photo,
            egui::Button::new("Photo deblurred (measured kernels)…"),
        )
        .on_disabled_hover_text("Open a photo first (Ctrl+P)")
        .clicked()
    {
        out.push(Command::Dialog(DialogCommand::ExportDeblurDialog(
            DeblurResult::Measured,
        )));
    }
    let profile = m.has_profile;
    if ui
        .add_enabled(profile, egui::Button::new("Photos as TIFF…"))
        .on_disabled_hover_text("Calibrate (Ctrl+M) or load a profile first")
        .clicked()
    {
        out.push(Command::Dialog(DialogCommand::ExportPhotosDialog {
            dng: false,
        }));
    }
    if ui
        .add_enabled(profile, egui::Button::new("RAW photos as DNG…"))
        .on_disabled_hover_text("Calibrate (Ctrl+M) or load a profile first")
        .clicked()
    {
        out.push(Command::Dialog(DialogCommand::ExportPhotosDialog {
            dng: true,
        }));
    }
    if ui
        .add_enabled(profile, egui::Button::new("Lens profile…"))
        .on_disabled_hover_text("Calibrate (Ctrl+M) or load a profile first")
        .clicked()
    {
        out.push(Command::Dialog(DialogCommand::SaveProfileDialog));
    }
    if ui
        .add_enabled(profile, egui::Button::new("Lens profile to the library"))
        .on_hover_text(format!(
            "Into {}, where a batch finds it: lensblur deblur PHOTOS --out-dir OUT --profiles {0}",
            m.profile_library.display()
        ))
        .on_disabled_hover_text("Calibrate (Ctrl+M) or load a profile first")
        .clicked()
    {
        out.push(Command::Stage(StageCommand::SaveProfileToLibrary));
    }
    if ui
        .button("Choose the profile library…")
        .on_hover_text(format!(
            "The folder profiles are saved into and a batch reads: now {}",
            m.profile_library.display()
        ))
        .clicked()
    {
        out.push(Command::Dialog(DialogCommand::ChooseProfileLibraryDialog));
    }
}

pub(super) fn shortcuts(m: &MenuContext<'_>, out: &mut Vec<Command>, ctx: &egui::Context) {
    let cmd = |k| KeyboardShortcut::new(Modifiers::COMMAND, k);
    let alt = |k| KeyboardShortcut::new(Modifiers::ALT, k);
    let n_shots = m.session.map_or(0, |s| s.shots.len());
    ctx.input_mut(|i| {
        if i.consume_shortcut(&cmd(Key::O)) {
            out.push(Command::Dialog(DialogCommand::OpenSessionDialog));
        }
        if i.consume_shortcut(&KeyboardShortcut::new(
            Modifiers::COMMAND | Modifiers::SHIFT,
            Key::A,
        )) {
            out.push(Command::Dialog(DialogCommand::AddShotsDialog));
        }
        if i.consume_shortcut(&cmd(Key::D)) {
            out.push(Command::Stage(StageCommand::RunDetect(None)));
        }
        if i.consume_shortcut(&cmd(Key::K)) {
            out.push(Command::Stage(StageCommand::RunKernels(None)));
        }
        if i.consume_shortcut(&cmd(Key::M)) {
            out.push(Command::Stage(StageCommand::RunCalibrate));
        }
        if i.consume_shortcut(&cmd(Key::Enter)) {
            out.push(Command::Stage(StageCommand::CalibrateAll {
                then_deblur: false,
            }));
        }
        if i.consume_shortcut(&cmd(Key::P)) {
            out.push(Command::View(ViewCommand::SelectView(View::Deblur)));
            out.push(Command::Dialog(DialogCommand::OpenPhotoDialog));
        }
        if i.consume_shortcut(&cmd(Key::E)) {
            out.push(Command::Dialog(DialogCommand::ExportDeblurDialog(
                DeblurResult::Predicted,
            )));
        }
        if i.consume_shortcut(&cmd(Key::T)) {
            out.push(Command::Window(WindowCommand::SetDark(!m.window.dark)));
        }
        if i.consume_shortcut(&cmd(Key::L)) {
            out.push(Command::Window(WindowCommand::SetLogOpen(
                !m.window.log_open,
            )));
        }
        if i.consume_shortcut(&cmd(Key::B)) {
            out.push(Command::Window(WindowCommand::SetSessionPanel(
                !m.session_panel_open,
            )));
        }
        if i.consume_shortcut(&cmd(Key::Q)) {
            out.push(Command::Window(WindowCommand::Quit));
        }
        if i.consume_key(Modifiers::NONE, Key::Escape) {
            out.push(Command::Window(WindowCommand::CancelAll));
        }
        for (k, v) in [
            Key::Num1,
            Key::Num2,
            Key::Num3,
            Key::Num4,
            Key::Num5,
            Key::Num6,
            Key::Num7,
        ]
        .into_iter()
        .zip(View::ALL)
        {
            if i.consume_shortcut(&alt(k)) {
                out.push(Command::View(ViewCommand::SelectView(v)));
            }
        }
        for (k, c) in [
            (Key::R, Channel::R),
            (Key::G, Channel::G),
            (Key::B, Channel::B),
        ] {
            if i.consume_shortcut(&alt(k)) {
                out.push(Command::View(ViewCommand::SelectChannel(c)));
            }
        }
        if let Some(s) = m.session.filter(|_| n_shots > 0) {
            let current = m.selected.and_then(|id| s.index_of(id)).unwrap_or(0);
            let at = |i: usize| s.shots[i.min(n_shots - 1)].id;
            if i.consume_key(Modifiers::NONE, Key::PageDown) {
                out.push(Command::View(ViewCommand::SelectShot(at(current + 1))));
            }
            if i.consume_key(Modifiers::NONE, Key::PageUp) {
                out.push(Command::View(ViewCommand::SelectShot(at(
                    current.saturating_sub(1)
                ))));
            }
        }
    });
}
