//! File dialogs, each on its own thread so the window never waits, and the questions
//! asked before doing something that loses work.

use super::session::{apply_settings, remove_shot};
use crate::app::{Command, Confirm, DeblurResult, PlotId, StudioApp};
use crate::app::{
    DeblurCommand, DialogCommand, GeometryCommand, PlotCommand, SessionCommand, StageCommand,
};
use std::path::PathBuf;

/// File dialogs (each on its own thread) and the questions asked before losing work.
pub(super) fn apply_dialog(app: &mut StudioApp, command: DialogCommand) {
    match command {
        DialogCommand::AddShotsDialog => spawn_dialog(app, || async {
            rfd::AsyncFileDialog::new()
                .set_title("Add calibration shots")
                .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                .pick_files()
                .await
                .map(|files| {
                    Command::Session(SessionCommand::AddShots(
                        files.iter().map(|f| f.path().to_path_buf()).collect(),
                    ))
                })
                .into_iter()
                .collect()
        }),
        DialogCommand::LoadChartDialog => spawn_dialog(app, || async {
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Load a chart spec")
                    .add_filter("chart spec", &["json"])
                    .pick_file()
                    .await,
                |p| Command::Session(SessionCommand::LoadChart(p)),
            )
        }),
        DialogCommand::OpenPhotoDialog => spawn_dialog(app, || async {
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Open a photo to deblur")
                    .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
                    .pick_file()
                    .await,
                |p| Command::Deblur(DeblurCommand::OpenPhoto(p)),
            )
        }),
        DialogCommand::ExportDeblurDialog(result) => export_deblur_dialog(app, result),
        DialogCommand::ExportPhotosDialog { dng } => export_photos_dialog(app, dng),
        DialogCommand::LoadProfileDialog => load_profile_dialog(app, false),
        DialogCommand::LoadCompareProfileDialog => load_profile_dialog(app, true),
        DialogCommand::SaveProfileDialog => save_profile_dialog(app),
        DialogCommand::SavePlotDialog { plot, png } => save_plot_dialog(app, plot, png),
        DialogCommand::SaveSharpnessDialog { png } => save_sharpness_dialog(app, png),
        DialogCommand::ExportLensfunDialog => export_lensfun_dialog(app),
        DialogCommand::OpenSessionDialog => spawn_dialog(app, || async {
            answer(
                rfd::AsyncFileDialog::new()
                    .set_title("Open or create a session folder")
                    .pick_folder()
                    .await,
                |p| Command::Session(SessionCommand::OpenSession(p)),
            )
        }),
        DialogCommand::ChooseProfileLibraryDialog => {
            let current = app.profile_library().to_path_buf();
            spawn_dialog(app, move || async move {
                answer(
                    rfd::AsyncFileDialog::new()
                        .set_title("Choose the profile library (where a batch finds its profiles)")
                        .set_directory(&current)
                        .pick_folder()
                        .await,
                    |p| Command::Stage(StageCommand::SetProfileLibrary(p)),
                )
            });
        }
        DialogCommand::AskConfirm(c) => app.window.confirm = Some(c),
        DialogCommand::ConfirmAnswer(yes) => match app.window.confirm.take() {
            Some(Confirm::RemoveShot(id)) if yes => remove_shot(app, id),
            Some(Confirm::ReplaceChart { chart, settings }) if yes => {
                apply_settings(app, chart, settings);
            }
            _ => {}
        },
    }
}

/// Where to write the open photo deblurred: a DNG for a RAW photo, TIFF or PNG.
fn export_deblur_dialog(app: &mut StudioApp, result: DeblurResult) {
    let Some(photo) = &app.views.deblur.photo else {
        app.error("open a photo first");
        return;
    };
    let stem = photo
        .path
        .file_stem()
        .map_or_else(|| "photo".into(), |s| s.to_string_lossy().into_owned());
    let which = match result {
        DeblurResult::Predicted => "predicted",
        DeblurResult::Measured => "measured",
    };
    // A RAW photo goes back to a RAW editor as a DNG; TIFF/PNG stay offered.
    let raw = photo.capture.raw.is_some();
    let mut dialog = rfd::AsyncFileDialog::new().set_title(if raw {
        "Export the deblurred photo (DNG for a RAW editor, or 16-bit linear)"
    } else {
        "Export the deblurred photo (16-bit linear)"
    });
    if raw {
        dialog = dialog.add_filter("DNG", &["dng"]);
    }
    dialog = dialog
        .add_filter("TIFF or PNG", &["tiff", "tif", "png"])
        .set_file_name(format!(
            "{stem}.deblurred-{which}.{}",
            if raw { "dng" } else { "tiff" }
        ));
    if let Some(dir) = photo.path.parent() {
        dialog = dialog.set_directory(dir);
    }
    spawn_dialog(app, move || async move {
        answer(dialog.save_file().await, |path| {
            Command::Deblur(DeblurCommand::ExportDeblur { path, result })
        })
    });
}

/// The photos to export, then the folder they go to.
fn export_photos_dialog(app: &mut StudioApp, dng: bool) {
    spawn_dialog(app, move || async move {
        let Some(photos) = rfd::AsyncFileDialog::new()
            .set_title(if dng {
                "RAW photos to deblur (written as DNGs)"
            } else {
                "Photos to deblur (written as 16-bit TIFFs)"
            })
            .add_filter("RAW, DNG, TIFF, PNG, JPEG", crate::session::SHOT_EXTENSIONS)
            .pick_files()
            .await
        else {
            return Vec::new();
        };
        let photos: Vec<PathBuf> = photos.iter().map(|f| f.path().to_path_buf()).collect();
        answer(
            rfd::AsyncFileDialog::new()
                .set_title("Folder for the deblurred photos")
                .pick_folder()
                .await,
            |out_dir| {
                Command::Deblur(DeblurCommand::ExportPhotos {
                    photos,
                    out_dir,
                    dng,
                })
            },
        )
    });
}

/// A profile to load, as the one in use or as a second one to compare.
fn load_profile_dialog(app: &mut StudioApp, compare: bool) {
    spawn_dialog(app, move || async move {
        answer(
            rfd::AsyncFileDialog::new()
                .set_title(if compare {
                    "Load a second lens profile to compare"
                } else {
                    "Load a lens profile"
                })
                .add_filter("lens profile", &["json"])
                .pick_file()
                .await,
            |path| Command::Stage(StageCommand::LoadProfile { path, compare }),
        )
    });
}

/// Where to save the profile in use.
fn save_profile_dialog(app: &mut StudioApp) {
    if app.profile().is_none() {
        app.error("no profile to save: calibrate first (Ctrl+M) or load one");
        return;
    }
    spawn_dialog(app, || async {
        answer(
            rfd::AsyncFileDialog::new()
                .set_title("Save the lens profile")
                .add_filter("lens profile", &["json"])
                .set_file_name("profile.json")
                .save_file()
                .await,
            |p| Command::Stage(StageCommand::SaveProfile(p)),
        )
    });
}

/// Where to save a plot, as a PNG of it on screen or as CSV of its data.
fn save_plot_dialog(app: &mut StudioApp, plot: PlotId, png: bool) {
    let (what, ext) = if png { ("PNG", "png") } else { ("CSV", "csv") };
    let name = format!("{}.{ext}", plot_file_stem(plot, app.views.sweeps.axis));
    spawn_dialog(app, move || async move {
        answer(
            rfd::AsyncFileDialog::new()
                .set_title(format!("Save the plot as {what}"))
                .add_filter(what, &[ext])
                .set_file_name(name)
                .save_file()
                .await,
            |path| {
                if png {
                    Command::Plot(PlotCommand::SavePlotPng { plot, path })
                } else {
                    Command::Plot(PlotCommand::SavePlotCsv { plot, path })
                }
            },
        )
    });
}

/// Where to save the sharpness map shown, as a PNG or as CSV.
fn save_sharpness_dialog(app: &mut StudioApp, png: bool) {
    let (what, ext) = if png { ("PNG", "png") } else { ("CSV", "csv") };
    let choice = app.views.sharpness;
    let name = format!(
        "sharpness-{}-{}.{ext}",
        match choice.source {
            crate::app::FieldSource::Measured => "measured",
            crate::app::FieldSource::Predicted => "predicted",
            crate::app::FieldSource::Truth => "truth",
        },
        choice.direction.label()
    );
    spawn_dialog(app, move || async move {
        answer(
            rfd::AsyncFileDialog::new()
                .set_title(format!("Save the sharpness map as {what}"))
                .add_filter(what, &[ext])
                .set_file_name(name)
                .save_file()
                .await,
            |path| Command::Plot(PlotCommand::SaveSharpness { path, png }),
        )
    });
}

/// Where to write the lens's lensfun entry: a file for `~/.local/share/lensfun/`.
fn export_lensfun_dialog(app: &mut StudioApp) {
    if super::geometry::measured_geometry(app).is_none() {
        app.error(
            "nothing to export yet: the lens's geometry is measured from the chart detected in shots at known settings (Detect, Ctrl+D)",
        );
        return;
    }
    let name = app
        .session()
        .map_or_else(|| "lens".to_owned(), |s| s.name.replace(' ', "-"));
    spawn_dialog(app, move || async move {
        answer(
            rfd::AsyncFileDialog::new()
                .set_title("Export the lens's lensfun entry (for darktable, RawTherapee)")
                .add_filter("lensfun XML", &["xml"])
                .set_file_name(format!("{name}.lensfun.xml"))
                .save_file()
                .await,
            |p| Command::Geometry(GeometryCommand::ExportLensfun(p)),
        )
    });
}

/// Commands made by the answers of file dialogs that have closed.
pub(in crate::app) fn drain_dialogs(app: &mut StudioApp) {
    while let Ok(commands) = app.dialogs.rx.try_recv() {
        app.dialogs.open = false;
        app.commands.extend(commands);
    }
}

/// Runs a file dialog on its own thread: `dialog` makes the dialog's future there (a
/// portal dialog is a D-Bus conversation that would otherwise hold the window's
/// frames), and the commands its answer makes come back through the app's channel.
fn spawn_dialog<F>(app: &mut StudioApp, dialog: impl FnOnce() -> F + Send + 'static)
where
    F: std::future::Future<Output = Vec<Command>>,
{
    if app.dialogs.open {
        app.info("a file dialog is already open: answer it first");
        return;
    }
    let tx = app.dialogs.tx.clone();
    let ctx = app.ctx.clone();
    let started = std::thread::Builder::new()
        .name("file dialog".into())
        .spawn(move || {
            let commands = pollster::block_on(dialog());
            // The app may have closed meanwhile; then nobody needs the answer.
            let _ = tx.send(commands);
            ctx.request_repaint();
        });
    match started {
        Ok(_) => app.dialogs.open = true,
        Err(e) => app.error(format!("cannot open the file dialog: {e}")),
    }
}

/// The path a dialog answered, or no command when it was cancelled.
fn answer(
    handle: Option<rfd::FileHandle>,
    command: impl FnOnce(PathBuf) -> Command,
) -> Vec<Command> {
    handle
        .map(|h| command(h.path().to_path_buf()))
        .into_iter()
        .collect()
}

/// A file name stem the save dialog proposes for a plot.
fn plot_file_stem(plot: PlotId, axis: crate::app::SweepAxis) -> String {
    match plot {
        PlotId::Sweep { vs_aperture, param } => {
            let name = crate::app::view_data::sweep_params(axis)
                .get(param)
                .map_or("sweep", |p| p.name)
                .replace(' ', "-");
            let against = if vs_aperture { "aperture" } else { "focal" };
            format!("sweep-{name}-vs-{against}")
        }
        PlotId::CvAlpha => "cv-alpha".into(),
        PlotId::CvBeta => "cv-beta".into(),
        PlotId::CvCdf => "cv-error-cdf".into(),
    }
}

/// File dialogs run on their own threads (a portal dialog's future, blocked on there)
/// and send back the commands their answer makes; the window never waits.
pub(in crate::app) struct Dialogs {
    pub(in crate::app) tx: std::sync::mpsc::Sender<Vec<Command>>,
    pub(in crate::app) rx: std::sync::mpsc::Receiver<Vec<Command>>,
    /// One file dialog at a time: a second would stack on the first.
    pub(in crate::app) open: bool,
}

impl Dialogs {
    pub(in crate::app) fn new() -> Self {
        let (tx, rx) = std::sync::mpsc::channel();
        Self {
            tx,
            rx,
            open: false,
        }
    }
}
