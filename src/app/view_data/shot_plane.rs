//! The shot viewer's plane: which plane of the selected shot maps onto the sensor.

use super::Same;
use crate::app::StudioApp;
use crate::plane::{Capture, Channel};
use crate::session::ShotId;

/// Which plane of the selected shot the viewer maps onto the sensor (its step and
/// offset) and reads hovered values from: the channel's first plane (G1 for a Bayer
/// G), else the capture's first.
pub struct ShotPlane {
    key: (ShotId, Channel, Same<Capture>),
    /// Index into the capture's planes.
    pub index: Option<usize>,
}

impl ShotPlane {
    #[must_use]
    pub fn shot(&self) -> ShotId {
        self.key.0
    }
}

pub(super) fn refresh_shot_plane(app: &mut StudioApp) {
    let Some((shot, preview)) = app
        .views
        .shot
        .selected
        .and_then(|id| Some((id, app.preview(id)?)))
    else {
        app.data.shot_plane = None;
        return;
    };
    let key = (
        shot,
        app.views.shot.channel,
        Same::of(Some(&preview.capture)),
    );
    if app.data.shot_plane.as_ref().is_some_and(|p| p.key == key) {
        return;
    }
    let planes = &preview.capture.planes;
    let index = planes
        .iter()
        .position(|p| p.channel == app.views.shot.channel)
        .or_else(|| (!planes.is_empty()).then_some(0));
    app.data.shot_plane = Some(ShotPlane { key, index });
}
