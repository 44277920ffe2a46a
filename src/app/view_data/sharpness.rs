//! The Sharpness view's map: MTF50 over the frame (`crate::review::SharpnessMap`)
//! measured on the selected shot, predicted by the profile at the sliders' setting, or
//! the demo lens's truth; its colour scale and its texture.

use super::{ColourScale, Same, StudioApp, is_demo, sensor_size};
use crate::app::{FieldSource, SharpnessChoice};
use crate::kernel::file::KernelsFile;
use crate::plane::{Channel, LensSetting};
use crate::profile::Profile;
use crate::review::{MapSummary, SharpnessMap};
use crate::session::ShotId;

/// What the map depends on.
#[derive(Clone, Debug, PartialEq)]
struct SharpnessKey {
    choice: SharpnessChoice,
    channel: Channel,
    shot: Option<ShotId>,
    file: Same<KernelsFile>,
    profile: Same<Profile>,
    setting: [f64; 2],
    is_demo: bool,
    size: (usize, usize),
}

/// The Sharpness view's map, or why there is none.
pub struct SharpnessData {
    key: SharpnessKey,
    pub map: Result<SharpnessMap, String>,
    /// Its colours, in the chosen unit.
    pub scale: Option<ColourScale>,
    pub summary: Option<MapSummary>,
    /// One texel per cell, drawn smoothed over the frame.
    pub texture: Option<egui::TextureHandle>,
}

fn key(app: &StudioApp) -> SharpnessKey {
    let choice = app.views.sharpness;
    let measured = choice.source == FieldSource::Measured;
    let at_setting = choice.source != FieldSource::Measured;
    SharpnessKey {
        choice,
        channel: app.views.shot.channel,
        shot: app.views.shot.selected.filter(|_| measured),
        file: Same::of(
            app.views
                .shot
                .selected
                .and_then(|i| app.kernels(i))
                .filter(|_| measured),
        ),
        profile: Same::of(
            app.profile()
                .as_ref()
                .map(|p| &p.1)
                .filter(|_| choice.source == FieldSource::Predicted),
        ),
        setting: if at_setting {
            [app.views.field.focal_mm, app.views.field.f_number]
        } else {
            [0.0; 2]
        },
        is_demo: is_demo(app),
        size: sensor_size(app),
    }
}

pub(super) fn refresh_sharpness(app: &mut StudioApp) {
    let key = key(app);
    if app.data.sharpness.as_ref().is_some_and(|d| d.key == key) {
        return;
    }
    let choice = key.choice;
    let setting = LensSetting {
        focal_mm: key.setting[0],
        f_number: key.setting[1],
    };
    let map = match choice.source {
        FieldSource::Measured => match (&key.file.0, key.shot) {
            (Some(file), Some(shot)) => {
                let name = app
                    .session()
                    .and_then(|s| s.shot(shot))
                    .and_then(|s| s.path.file_name())
                    .map_or_else(
                        || "the shot".to_owned(),
                        |n| n.to_string_lossy().into_owned(),
                    );
                SharpnessMap::measured(
                    file,
                    key.channel,
                    choice.direction,
                    format!("measured on {name}"),
                )
            }
            _ => Err(
                "no kernels on the selected shot: measure it (Kernels), or choose Predicted"
                    .to_owned(),
            ),
        },
        FieldSource::Predicted => match &key.profile.0 {
            Some(profile) => {
                SharpnessMap::predicted(profile, key.channel, setting, choice.direction)
            }
            None => Err("no profile yet: Calibrate all (Ctrl+Enter), or load one".to_owned()),
        },
        FieldSource::Truth if key.is_demo => Ok(SharpnessMap::truth(
            &crate::simulate::VirtualLens::demo(),
            key.channel,
            key.size,
            setting,
            choice.direction,
        )),
        FieldSource::Truth => Err("the ground truth is known for the demo session only".to_owned()),
    };
    let range = map.as_ref().ok().and_then(|m| m.range(choice.unit));
    let scale = range.map(|range| ColourScale {
        range,
        diverging: false,
        title: format!(
            "MTF50 {}, {}",
            choice.direction.label(),
            choice.unit.label()
        ),
        ticks: crate::review::nice_ticks(range, 6),
    });
    let summary = map.as_ref().ok().and_then(|m| m.summary(choice.unit));
    let texture = match (&map, range) {
        (Ok(m), Some(range)) => {
            let pixels: Vec<egui::Color32> = m
                .rgba_cells(choice.unit, range)
                .into_iter()
                .map(|[r, g, b, a]| egui::Color32::from_rgba_unmultiplied(r, g, b, a))
                .collect();
            let image = egui::ColorImage::new([m.grid.0, m.grid.1], pixels);
            Some(
                app.ctx
                    .load_texture("sharpness map", image, egui::TextureOptions::LINEAR),
            )
        }
        _ => None,
    };
    app.data.sharpness = Some(SharpnessData {
        key,
        map,
        scale,
        summary,
        texture,
    });
}
