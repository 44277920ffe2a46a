//! The lens's geometry (distortion, lateral colour, fall-off: [`crate::correction`]) as
//! a stage of the project, measured from the shots' detections: what it depends on
//! ([`GeometryKey`]), the measurement detached to run on any thread ([`GeometryJob`]),
//! and the rule that keeps one result per set of inputs, measured again only when they
//! change.
//!
//! A project is one session, so the key needs no session of its own: a result carries
//! the detections it was measured from, which no other project's shots hold.

use super::{Project, ShotId};
use crate::chart::ChartSpec;
use crate::correction::{CorrectionError, CorrectionOptions, GeometryShot, LensCorrection};
use crate::detect::Detection;
use crate::plane::LensSetting;
use std::sync::Arc;

/// What the lens's geometry is measured from: the chart, and every shot with a detection
/// and a known setting. A detection counts by identity: a shot detected again is a new
/// input, even where its squares came out the same.
#[derive(Clone, Debug)]
pub struct GeometryKey {
    chart: ChartSpec,
    shots: Vec<(ShotId, Arc<Detection>, LensSetting)>,
}

impl PartialEq for GeometryKey {
    fn eq(&self, other: &Self) -> bool {
        self.chart == other.chart
            && self.shots.len() == other.shots.len()
            && self
                .shots
                .iter()
                .zip(&other.shots)
                .all(|(a, b)| a.0 == b.0 && Arc::ptr_eq(&a.1, &b.1) && a.2 == b.2)
    }
}

/// The measured geometry, or why it could not be measured, with what it was measured
/// from.
#[derive(Clone, Debug)]
pub struct MeasuredGeometry {
    key: GeometryKey,
    pub result: Result<Arc<LensCorrection>, String>,
}

/// Where a project's geometry stands.
#[derive(Clone, Copy, Debug)]
pub enum GeometryStatus<'a> {
    /// No shot has both a detection and a known setting.
    NoShots,
    /// Not measured from the present inputs yet (being measured, or to be).
    Waiting,
    /// Measured from the present inputs, or why it could not be.
    Measured(&'a Result<Arc<LensCorrection>, String>),
}

/// The project's geometry stage: the last result, and the inputs being measured now.
#[derive(Clone, Debug, Default)]
pub(super) struct GeometryStage {
    measured: Option<MeasuredGeometry>,
    measuring: Option<GeometryKey>,
}

/// The measurement of the lens's geometry, detached from the project so it runs on any
/// thread; its result goes back through [`Project::record_geometry`].
pub struct GeometryJob {
    key: GeometryKey,
    names: Vec<String>,
    options: CorrectionOptions,
}

impl GeometryJob {
    /// The models to fit, where they are chosen rather than picked by the fit.
    #[must_use]
    pub fn with_options(mut self, options: CorrectionOptions) -> Self {
        self.options = options;
        self
    }

    /// How many shots it is measured from.
    #[must_use]
    pub fn shots(&self) -> usize {
        self.key.shots.len()
    }

    /// Fits the geometry to every shot's corners and white squares.
    ///
    /// # Errors
    /// See [`crate::correction::measure`].
    pub fn measure(&self) -> Result<LensCorrection, CorrectionError> {
        let shots: Vec<GeometryShot<'_>> = self
            .key
            .shots
            .iter()
            .zip(&self.names)
            .map(|((_, detection, setting), name)| GeometryShot {
                name,
                setting: *setting,
                detection,
            })
            .collect();
        crate::correction::measure(&shots, &self.key.chart, self.options)
    }

    /// [`Self::measure`], as the project records it.
    #[must_use]
    pub fn run(self) -> MeasuredGeometry {
        let result = self.measure().map(Arc::new).map_err(|e| e.to_string());
        MeasuredGeometry {
            key: self.key,
            result,
        }
    }
}

impl Project {
    /// The shots the geometry is measured from, in session order, with their names.
    fn geometry_inputs(&self) -> impl Iterator<Item = (ShotId, &Arc<Detection>, LensSetting)> {
        self.shots()
            .filter_map(|s| Some((s.shot.id, s.state.detection.as_ref()?, s.shot.setting()?)))
    }

    /// Whether `key` is what the geometry would be measured from now.
    fn is_current(&self, key: &GeometryKey) -> bool {
        let mut inputs = self.geometry_inputs();
        key.chart == self.session.chart
            && key.shots.iter().all(|(id, d, s)| {
                inputs
                    .next()
                    .is_some_and(|(i, e, t)| i == *id && Arc::ptr_eq(d, e) && t == *s)
            })
            && inputs.next().is_none()
    }

    /// Where the geometry of the detections and settings held now stands.
    #[must_use]
    pub fn geometry_status(&self) -> GeometryStatus<'_> {
        match &self.geometry.measured {
            Some(m) if self.is_current(&m.key) => GeometryStatus::Measured(&m.result),
            _ if self.geometry_inputs().next().is_none() => GeometryStatus::NoShots,
            _ => GeometryStatus::Waiting,
        }
    }

    /// The geometry measured from the detections and settings held now: `None` until
    /// it is (or where no shot has both).
    #[must_use]
    pub fn geometry(&self) -> Option<&Result<Arc<LensCorrection>, String>> {
        match self.geometry_status() {
            GeometryStatus::Measured(r) => Some(r),
            GeometryStatus::NoShots | GeometryStatus::Waiting => None,
        }
    }

    /// Whether a measurement of the present inputs has been handed out and not yet
    /// recorded.
    #[must_use]
    pub fn geometry_measuring(&self) -> bool {
        self.geometry
            .measuring
            .as_ref()
            .is_some_and(|k| self.is_current(k))
    }

    /// The measurement of the present inputs where neither a result nor a measurement
    /// handed out already answers them; `None` too where no shot has both a detection
    /// and a setting. From here until it is recorded the inputs count as being measured.
    pub fn geometry_job(&mut self) -> Option<GeometryJob> {
        if self.geometry().is_some() || self.geometry_measuring() {
            return None;
        }
        let (shots, names): (Vec<_>, Vec<_>) = self
            .geometry_inputs()
            .map(|(id, d, s)| {
                let name = self.session.shot(id).map(crate::session::Shot::name);
                ((id, Arc::clone(d), s), name.unwrap_or_default())
            })
            .unzip();
        if shots.is_empty() {
            return None;
        }
        let key = GeometryKey {
            chart: self.session.chart.clone(),
            shots,
        };
        self.geometry.measuring = Some(key.clone());
        Some(GeometryJob {
            key,
            names,
            options: CorrectionOptions::default(),
        })
    }

    /// Takes a finished measurement; returns whether it was kept (it answers the inputs
    /// held now: a late one, for detections since replaced, is dropped).
    pub fn record_geometry(&mut self, measured: MeasuredGeometry) -> bool {
        if self.geometry.measuring.as_ref() == Some(&measured.key) {
            self.geometry.measuring = None;
        }
        if !self.is_current(&measured.key) {
            return false;
        }
        self.geometry.measured = Some(measured);
        true
    }

    /// A measurement handed out ended without a result (it failed or was cancelled):
    /// `reason` stands as its result, so it is not handed out again until the inputs
    /// change.
    pub fn geometry_abandoned(&mut self, reason: String) {
        if let Some(key) = self.geometry.measuring.take() {
            self.record_geometry(MeasuredGeometry {
                key,
                result: Err(reason),
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::project::ShotEvent;
    use crate::session::Session;
    use crate::shot_file::{Fingerprint, ShotFile};

    fn detected(p: &mut Project, id: ShotId) -> Arc<Detection> {
        let detection = Arc::new(Detection {
            width: 64,
            height: 48,
            squares: Vec::new(),
            global: crate::geometry::Homography::identity(),
        });
        let path = p.session().path_of(p.session().shot(id).expect("shot"));
        assert!(p.record(&ShotEvent::Detected {
            id,
            file: ShotFile {
                path,
                fingerprint: Fingerprint(id.0),
            },
            detection: Arc::clone(&detection),
        }));
        detection
    }

    fn measured(p: &mut Project) -> bool {
        let job = p.geometry_job().expect("a measurement to run");
        p.record_geometry(job.run())
    }

    /// The geometry is measured once per set of inputs: again when a detection, a
    /// setting or the chart changes, or a shot comes or goes; not when nothing does,
    /// nor while a measurement is out; and a late result for old inputs is dropped.
    #[test]
    fn the_geometry_is_measured_again_exactly_when_its_inputs_change() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut session = Session::new(dir.path());
        let ids: Vec<ShotId> = ["a.png", "b.png", "c.png"]
            .iter()
            .map(|n| {
                let path = dir.path().join(n);
                std::fs::write(&path, n.as_bytes()).expect("write");
                session.add_shot(&path).expect("add")
            })
            .collect();
        for shot in &mut session.shots {
            shot.focal_mm = Some(35.0);
            shot.f_number = Some(4.0);
        }
        let (mut p, _) = Project::with_session(session, None, "test").expect("project");
        assert!(p.geometry_job().is_none(), "nothing detected");
        assert!(matches!(p.geometry_status(), GeometryStatus::NoShots));

        detected(&mut p, ids[0]);
        detected(&mut p, ids[1]);
        let job = p.geometry_job().expect("detections to measure");
        assert!(p.geometry_measuring());
        assert!(p.geometry_job().is_none(), "already being measured");
        assert!(matches!(p.geometry_status(), GeometryStatus::Waiting));
        assert!(p.record_geometry(job.run()));
        assert!(!p.geometry_measuring());
        // The fake detections hold no squares: the core says why, and that is the result.
        assert!(p.geometry().is_some_and(Result::is_err));
        assert!(p.geometry_job().is_none(), "nothing changed");

        // A shot without a setting is not an input.
        p.session_mut().shots[2].f_number = None;
        detected(&mut p, ids[2]);
        assert!(p.geometry().is_some() && p.geometry_job().is_none());

        // A detection made again, even alike, while a measurement is out: that one's
        // result comes late and is dropped.
        p.session_mut().shots[0].focal_mm = Some(50.0);
        assert!(p.geometry().is_none(), "measured at another setting");
        let late = p.geometry_job().expect("a setting changed");
        detected(&mut p, ids[1]);
        assert!(!p.geometry_measuring(), "what is out answers older inputs");
        let job = p.geometry_job().expect("a detection made again");
        assert!(!p.record_geometry(late.run()), "a late result is dropped");
        assert!(p.geometry_measuring());
        assert!(p.record_geometry(job.run()));
        assert!(p.geometry_job().is_none());

        // The chart, a shot removed.
        p.session_mut().chart.rows += 1;
        assert!(p.geometry().is_none());
        assert!(measured(&mut p));
        p.remove_shot(ids[0]);
        assert!(p.geometry().is_none());
        assert!(measured(&mut p));
        assert!(p.geometry_job().is_none());

        // A measurement that ended without a result is not handed out again.
        detected(&mut p, ids[1]);
        assert!(p.geometry_job().is_some());
        p.geometry_abandoned("cancelled".into());
        assert_eq!(
            p.geometry().cloned().map(|r| r.err()),
            Some(Some("cancelled".into()))
        );
        assert!(p.geometry_job().is_none());
    }
}
