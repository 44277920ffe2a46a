//! Plots saved as CSV of their data or as PNG cut out of a screenshot.

use crate::app::PlotCommand;
use crate::app::view_data;
use crate::app::{PendingPlotPng, PlotId, StudioApp};
use crate::review::PlotTable;
use std::path::PathBuf;

/// Saving a plot, as CSV of its data or as a PNG of it on screen.
pub(super) fn apply_plot(app: &mut StudioApp, command: PlotCommand) {
    match command {
        PlotCommand::SavePlotCsv { plot, path } => {
            let written = plot_table(app, plot).and_then(|t| {
                crate::io::write_atomic(&path, crate::review::plot_csv(&t).as_bytes())
                    .map_err(|e| e.to_string())
            });
            match written {
                Ok(()) => app.info(format!("plot data saved to {}", app.shown_path(&path))),
                Err(e) => app.error(format!("cannot save the plot's data: {e}")),
            }
        }
        PlotCommand::SavePlotPng { plot, path } => request_plot_png(app, plot, path),
        PlotCommand::SaveSharpness { path, png } => {
            let written = match app.data.sharpness.as_ref().map(|d| &d.map) {
                Some(Ok(map)) if png => {
                    map.write_png(&path, app.views.sharpness.unit, SHARPNESS_PNG_WIDTH)
                }
                Some(Ok(map)) => {
                    crate::io::write_atomic(&path, map.csv().as_bytes()).map_err(|e| e.to_string())
                }
                Some(Err(why)) => Err(why.clone()),
                None => Err("the map is not made yet: open the Sharpness view".to_owned()),
            };
            match written {
                Ok(()) => app.info(format!("sharpness map saved to {}", app.shown_path(&path))),
                Err(e) => app.error(format!("cannot save the sharpness map: {e}")),
            }
        }
    }
}

/// How wide a saved sharpness map is, px: sharp on a screen, small enough to mail.
const SHARPNESS_PNG_WIDTH: u32 = 1200;

/// The data a plot draws, from the same view data and report its draw code reads.
fn plot_table(app: &StudioApp, plot: PlotId) -> Result<PlotTable, String> {
    match plot {
        PlotId::Sweep { vs_aperture, param } => {
            let data = app
                .data
                .sweeps
                .as_ref()
                .ok_or("the sweeps are not prepared yet: open the Sweeps view")?;
            view_data::sweep_table(data, app.views.sweeps.axis, vs_aperture, param)
                .ok_or_else(|| format!("the sweeps have no plot {param}"))
        }
        PlotId::CvAlpha | PlotId::CvBeta | PlotId::CvCdf => {
            let cv = app
                .cv()
                .ok_or("no cross-validation yet: calibrate first (Ctrl+M)")?;
            let families = [("global", cv.global.as_ref()), ("local", cv.local.as_ref())]
                .into_iter()
                .filter_map(|(n, s)| s.map(|s| (n, s)));
            let (x_label, series) = match plot {
                PlotId::CvCdf => (
                    "error (% of range)",
                    families
                        .flat_map(|(n, s)| {
                            crate::review::cv_cdf_curves(s)
                                .map(|(param, pts)| (format!("{n} {param}"), pts))
                        })
                        .collect(),
                ),
                _ => {
                    let by_alpha = plot == PlotId::CvAlpha;
                    (
                        if by_alpha {
                            "α (order in x, y)"
                        } else {
                            "β (order in f, a)"
                        },
                        families
                            .map(|(n, s)| (n.to_owned(), crate::review::cv_curve(s, by_alpha)))
                            .collect(),
                    )
                }
            };
            let y_label = if plot == PlotId::CvCdf {
                "held-out samples (%)"
            } else {
                "mean error (% of range)"
            };
            Ok(PlotTable {
                x_label: x_label.to_owned(),
                y_label: y_label.to_owned(),
                series,
            })
        }
    }
}

/// Asks for a screenshot of the next frame; the plot is cut out of it when it arrives
/// ([`finish_plot_png`]), so the PNG is the plot exactly as drawn.
fn request_plot_png(app: &mut StudioApp, plot: PlotId, path: PathBuf) {
    let rect = app
        .ctx
        .data(|d| d.get_temp::<egui::Rect>(plot.rect_id()))
        .filter(|_| app.view == plot.view());
    let Some(rect) = rect else {
        app.error("cannot save the plot: it is not on screen; open its view first");
        return;
    };
    if app.window.plot_png.is_some() {
        app.error("cannot save the plot: another plot is being saved");
        return;
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let wake = app.ctx.clone();
    app.ctx.request_screenshot(move |image| {
        // The app may have closed meanwhile; then nobody waits for the image.
        let _ = tx.send(image);
        wake.request_repaint();
    });
    app.window.plot_png = Some(PendingPlotPng {
        path,
        rect,
        image: rx,
    });
}

/// Writes the pending plot PNG once its screenshot has arrived.
pub(in crate::app) fn finish_plot_png(app: &mut StudioApp) {
    let Some(pending) = &app.window.plot_png else {
        return;
    };
    let image = match pending.image.try_recv() {
        Ok(image) => Ok(image),
        Err(std::sync::mpsc::TryRecvError::Empty) => return,
        Err(std::sync::mpsc::TryRecvError::Disconnected) => {
            Err("the window gave no screenshot".to_owned())
        }
    };
    let Some(pending) = app.window.plot_png.take() else {
        return;
    };
    let ppp = app.ctx.pixels_per_point();
    let r = pending.rect;
    let px = |v: f32| (v * ppp).round().max(0.0) as usize;
    let written = image.and_then(|image| {
        let [w, h] = image.size;
        let rgba: Vec<u8> = image
            .pixels
            .iter()
            .flat_map(|c| c.to_srgba_unmultiplied())
            .collect();
        crate::review::write_png_crop(
            &pending.path,
            rgba,
            w,
            h,
            [px(r.min.x), px(r.min.y), px(r.max.x), px(r.max.y)],
        )
    });
    match written {
        Ok(()) => app.info(format!("plot saved to {}", app.shown_path(&pending.path))),
        Err(e) => app.error(format!("cannot save the plot: {e}")),
    }
}
