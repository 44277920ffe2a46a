//! A calibration project: one session folder held for writing, with everything known
//! about each of its shots, measured and calibrated through one object that every
//! front end drives. `lensblur calibrate` (and `crossval`, `sweeps`), `lensblur kernels
//! --session` and the studio open a [`Project`], survey it once, run its measurement as
//! a job that reports per-shot [`ShotEvent`]s, record those events, and calibrate from
//! what it holds; the command line prints the events, the studio shows them.
//!
//! What a project holds per shot is the session's [`Shot`] (id, file, capture settings,
//! each stage's status or failure reason, saved in `session.json`) beside a [`ShotState`]
//! (the file's fingerprint as this run read it, and the detection and kernels found in
//! the result cache or measured). Each shot file is fingerprinted once per run: by the
//! survey, or by the first job that needs a shot added after it; the [`ShotFile`] is then
//! handed on, and the cache is never looked up again for what the survey found.
//!
//! Made of the shots: the measured Gaussians and the profile ([`Results`]), and the
//! lens's geometry, measured from the detections once per set of them (`geometry`).
//!
//! `session.json` is written off the caller's thread: [`Project::save`] hands a copy to
//! the project's writer thread, which writes the newest copy it has (atomically and
//! durably, see [`crate::io`]); [`Project::flush`] waits for it.
//!
//! This module is core: it never touches egui.

use crate::calibrate::CalibrateOptions;
use crate::crossval::CvReport;
use crate::detect::Detection;
use crate::job::{Cancelled, JobContext};
use crate::kernel::file::KernelsFile;
use crate::lock::{FolderLock, LockError};
use crate::model::Dataset;
use crate::pipeline::{self, GivenSetting, MeasuredShot, Measurement, ResultCache};
use crate::plane::Capture;
use crate::profile::Profile;
use crate::session::{Session, SessionError, Shot, ShotId, StageStatus};
use crate::shot_file::ShotFile;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod geometry;
mod jobs;
mod saver;

use geometry::GeometryStage;
pub use geometry::{GeometryJob, GeometryKey, GeometryStatus, MeasuredGeometry};
pub use jobs::{
    CalibrateAllJob, Calibration, CalibrationJob, DatasetJob, MeasureJob, Survey, SurveyJob,
};
use jobs::{Pending, ShotWork, is_kernels_file};
use saver::Saver;

/// The cross-validation report a project keeps beside its profile, so a reopened
/// session shows its curves without calibrating again.
pub const CV_FILE: &str = "crossval.json";
/// The profile a project calibrates into its own folder.
pub const PROFILE_FILE: &str = "profile.json";

#[derive(Debug, thiserror::Error)]
pub enum ProjectError {
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error(transparent)]
    Lock(#[from] LockError),
    #[error(transparent)]
    Pipeline(#[from] pipeline::PipelineError),
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    #[error("{}: the session lists no shots", .0.display())]
    NoShots(PathBuf),
    #[error(
        "calibration needs kernels on at least two shots ({0} have them): measure the shots first"
    )]
    TooFewShots(usize),
    #[error("calibration: {0}")]
    Calibrate(String),
    /// A background write of `session.json` failed: the reason names the file.
    #[error("{0}")]
    Save(String),
    #[error("{0}")]
    Cancelled(#[from] Cancelled),
}

/// What [`Project::take_in_folder`] found in a plain folder of shots.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TakenIn {
    /// Shots added to the session.
    pub added: usize,
    /// Files that are not shots, by name.
    pub skipped: Vec<String>,
    /// Shots added without a focal length or an aperture (neither given nor in
    /// their EXIF), by name.
    pub no_setting: Vec<String>,
}

/// One stage of a shot's measurement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Detect,
    Kernels,
}

impl Stage {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Stage::Detect => "detection",
            Stage::Kernels => "kernels",
        }
    }
}

/// What a project knows of one shot in this run, beside the session's [`Shot`].
#[derive(Clone, Debug, Default)]
pub struct ShotState {
    /// The shot file as fingerprinted in this run; `None` until the survey (or the first
    /// job on a shot added later) reads it.
    pub file: Option<ShotFile>,
    /// Why the file could not be read, where it could not.
    pub unreadable: Option<String>,
    pub detection: Option<Arc<Detection>>,
    /// The kernels (with their arrays) and their Gaussians, all channels.
    pub kernels: Option<Arc<KernelsFile>>,
}

/// A shot of the project: the session's record and this run's state, by one id.
#[derive(Clone, Copy, Debug)]
pub struct ProjectShot<'a> {
    pub shot: &'a Shot,
    pub state: &'a ShotState,
}

/// What happened to one shot while a [`MeasureJob`] ran.
#[derive(Clone, Debug)]
pub enum ShotEvent {
    /// Work on the shot began: it is `index` (from 0) of `total` in this job.
    Started {
        id: ShotId,
        index: usize,
        total: usize,
    },
    Detected {
        id: ShotId,
        file: ShotFile,
        detection: Arc<Detection>,
    },
    Measured {
        id: ShotId,
        file: ShotFile,
        kernels: Arc<KernelsFile>,
    },
    /// A stage failed on the shot; `reason` names its file.
    Failed {
        id: ShotId,
        stage: Stage,
        reason: String,
    },
    /// The shot's work was cancelled (the shot removed, or the whole job cancelled).
    Cancelled { id: ShotId },
}

impl ShotEvent {
    #[must_use]
    pub fn shot(&self) -> ShotId {
        match self {
            ShotEvent::Started { id, .. }
            | ShotEvent::Detected { id, .. }
            | ShotEvent::Measured { id, .. }
            | ShotEvent::Failed { id, .. }
            | ShotEvent::Cancelled { id } => *id,
        }
    }
}

/// Which stages a measurement runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stages {
    /// Detection only.
    Detect,
    /// Kernels of shots already detected.
    Kernels,
    /// Whatever is missing: detection where there is none, then kernels.
    All,
}

impl Stages {
    fn detects(self) -> bool {
        matches!(self, Stages::Detect | Stages::All)
    }
    fn measures_kernels(self) -> bool {
        matches!(self, Stages::Kernels | Stages::All)
    }
}

/// Which shots a measurement takes, and how.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MeasurePlan {
    pub stages: Stages,
    /// `None`: every readable shot still missing a result of the stages; `Some`: these
    /// shots, measured again even where results exist (their cached results replaced).
    pub only: Option<Vec<ShotId>>,
    /// Refuse a shot whose focal length or f-number is neither recorded nor in its
    /// EXIF, right after loading it and before the minutes of measuring it.
    pub require_setting: bool,
}

impl MeasurePlan {
    /// Whatever is missing of `stages`, on every shot that needs it.
    #[must_use]
    pub fn missing(stages: Stages) -> Self {
        Self {
            stages,
            only: None,
            require_setting: false,
        }
    }

    /// `stages` again on the given shots.
    #[must_use]
    pub fn again(stages: Stages, ids: Vec<ShotId>) -> Self {
        Self {
            stages,
            only: Some(ids),
            require_setting: false,
        }
    }
}
/// What a project has made of its shots or been given beside them: the measured
/// Gaussians, the profile in use and a second one to compare it with (another unit of
/// the lens), and the cross-validation report of the profile's fit.
#[derive(Clone, Default)]
pub struct Results {
    /// The measured Gaussians of every shot with kernels and a known setting.
    pub dataset: Option<Arc<Dataset>>,
    /// The profile in use, calibrated here or loaded, and where it lies.
    pub profile: Option<(PathBuf, Arc<Profile>)>,
    pub compare_profile: Option<(PathBuf, Arc<Profile>)>,
    /// `None` where α and β were fixed, or the profile was loaded without one.
    pub cv: Option<Arc<CvReport>>,
}

/// A calibration project: see the module documentation.
pub struct Project {
    session: Session,
    states: BTreeMap<ShotId, ShotState>,
    /// Whether `session.json` is written: a bare manifest the command line reads is
    /// left as it is.
    persistent: bool,
    saver: Saver,
    results: Results,
    /// The lens's geometry, measured from the detections (`geometry`).
    geometry: GeometryStage,
    // Dropped last: the writer finishes before the folder is let go.
    lock: Option<FolderLock>,
}

impl std::fmt::Debug for Project {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Project")
            .field("folder", &self.session.folder())
            .field("shots", &self.session.shots.len())
            .finish_non_exhaustive()
    }
}

/// How a project was opened.
#[derive(Debug, Default)]
pub struct Opened {
    /// Temporary files of an interrupted write that opening removed.
    pub swept: usize,
    /// Why the folder is not locked, where it could not be (read-only, say): it is
    /// shown, and saving it will say why not.
    pub unlocked: Option<String>,
}

impl Project {
    /// Opens a session folder, its `session.json`, or a manifest for `who` (a few
    /// words naming the program, shown to whoever finds the folder locked), taking
    /// the folder's lock. A bare manifest file is read, never rewritten.
    ///
    /// # Errors
    /// The session cannot be read, or the folder is locked or cannot be locked.
    pub fn open(path: &Path, who: &str) -> Result<(Self, Opened), ProjectError> {
        let session = Session::open(path)?;
        // A session file, named or in the folder given, is kept up to date; a manifest
        // (or a folder holding only one) is read, never turned into a session.
        let persistent = session
            .folder()
            .join(crate::session::SESSION_FILE)
            .is_file()
            && (path.is_dir()
                || path
                    .file_name()
                    .is_some_and(|n| n == crate::session::SESSION_FILE));
        let (lock, swept) = session.lock(who)?;
        let mut p = Self::with_lock(session, Some(lock));
        p.persistent = persistent;
        Ok((
            p,
            Opened {
                swept,
                unlocked: None,
            },
        ))
    }

    /// A project of `session`, which the caller has read or made, holding its
    /// folder's lock where it can be taken. `lock` is one the caller already holds
    /// for the same folder (reopening the folder open now); with `None` it is taken.
    ///
    /// # Errors
    /// Another program holds the folder.
    pub fn with_session(
        session: Session,
        lock: Option<FolderLock>,
        who: &str,
    ) -> Result<(Self, Opened), ProjectError> {
        let mut opened = Opened::default();
        let lock = match lock.filter(|l| l.dir() == session.folder()) {
            Some(l) => Some(l),
            None => match session.lock(who) {
                Ok((l, swept)) => {
                    opened.swept = swept;
                    Some(l)
                }
                Err(e @ LockError::Held { .. }) => return Err(e.into()),
                Err(e) => {
                    opened.unlocked = Some(e.to_string());
                    None
                }
            },
        };
        Ok((Self::with_lock(session, lock), opened))
    }

    fn with_lock(session: Session, lock: Option<FolderLock>) -> Self {
        let states = session
            .shots
            .iter()
            .map(|s| (s.id, ShotState::default()))
            .collect();
        Self {
            session,
            states,
            persistent: true,
            saver: Saver::start(),
            results: Results::default(),
            geometry: GeometryStage::default(),
            lock,
        }
    }

    /// Gives the folder's lock up, for a project of the same folder to take over.
    #[must_use]
    pub fn into_lock(mut self) -> Option<FolderLock> {
        self.saver.flush();
        self.lock.take()
    }

    #[must_use]
    pub fn session(&self) -> &Session {
        &self.session
    }

    #[must_use]
    pub fn folder(&self) -> &Path {
        self.session.folder()
    }

    /// The session, to change what the user changes (settings, names); call
    /// [`Project::save`] after. Shots are added and removed through the project.
    pub fn session_mut(&mut self) -> &mut Session {
        &mut self.session
    }

    /// Every shot in session order with its state.
    pub fn shots(&self) -> impl Iterator<Item = ProjectShot<'_>> {
        static NONE: std::sync::OnceLock<ShotState> = std::sync::OnceLock::new();
        let none = NONE.get_or_init(ShotState::default);
        self.session.shots.iter().map(move |shot| ProjectShot {
            shot,
            state: self.states.get(&shot.id).unwrap_or(none),
        })
    }

    #[must_use]
    pub fn state(&self, id: ShotId) -> Option<&ShotState> {
        self.states.get(&id)
    }

    #[must_use]
    pub fn detection(&self, id: ShotId) -> Option<&Arc<Detection>> {
        self.states.get(&id)?.detection.as_ref()
    }

    #[must_use]
    pub fn kernels(&self, id: ShotId) -> Option<&Arc<KernelsFile>> {
        self.states.get(&id)?.kernels.as_ref()
    }

    /// Adds a shot file.
    ///
    /// # Errors
    /// See [`Session::add_shot`].
    pub fn add_shot(&mut self, path: &Path) -> Result<ShotId, ProjectError> {
        let id = self.session.add_shot(path)?;
        self.states.insert(id, ShotState::default());
        Ok(id)
    }

    /// Takes in a plain folder of shots as the session: every shot file lying in the
    /// session's folder (not in its subfolders), in name order, each with the setting
    /// `given` where given, else the one its EXIF records. Files that are not shots
    /// are skipped and named; lensblur's own files (JSON) and hidden ones are passed
    /// over in silence. A shot already in the session is not added twice.
    ///
    /// # Errors
    /// The folder cannot be listed.
    pub fn take_in_folder(&mut self, given: GivenSetting) -> Result<TakenIn, ProjectError> {
        let folder = self.session.folder().to_path_buf();
        let listing = std::fs::read_dir(&folder).map_err(|source| SessionError::Read {
            path: folder.clone(),
            source,
        })?;
        let mut files: Vec<PathBuf> = listing
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.is_file())
            .collect();
        files.sort();
        let mut taken = TakenIn::default();
        for path in files {
            let name = path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            let ext = path
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default();
            if name.starts_with('.') || ext == "json" {
                continue;
            }
            if !crate::session::SHOT_EXTENSIONS.contains(&ext.as_str()) {
                taken.skipped.push(name);
                continue;
            }
            let Ok(id) = self.add_shot(&path) else {
                continue;
            };
            // A file whose headers cannot be read is still a shot: measuring it says
            // why it fails, with the others.
            let exif = crate::raw::read_header(&path).ok().map(|h| h.exif);
            let setting = GivenSetting {
                focal_mm: given
                    .focal_mm
                    .or_else(|| exif.as_ref().and_then(|e| e.focal_mm)),
                f_number: given
                    .f_number
                    .or_else(|| exif.as_ref().and_then(|e| e.f_number)),
            };
            if let Some(shot) = self.session.shot_mut(id) {
                shot.focal_mm = setting.focal_mm;
                shot.f_number = setting.f_number;
            }
            if setting.focal_mm.is_none() || setting.f_number.is_none() {
                taken.no_setting.push(name);
            }
            taken.added += 1;
        }
        Ok(taken)
    }

    /// Adds shots made elsewhere under ids the session has not given yet (the demo,
    /// made on another thread shot by shot); a shot removed meanwhile stays removed.
    pub fn adopt_shots(&mut self, made: &Session) {
        let known = self.session.next_shot_id;
        for shot in made.shots.iter().filter(|s| s.id.0 >= known) {
            self.states.insert(shot.id, ShotState::default());
            self.session.shots.push(shot.clone());
        }
        self.session.next_shot_id = self.session.next_shot_id.max(made.next_shot_id);
    }

    /// Removes a shot (its file and cached results stay on disk).
    pub fn remove_shot(&mut self, id: ShotId) -> Option<Shot> {
        self.states.remove(&id);
        self.session.remove_shot(id)
    }

    /// Forgets the detections and/or kernels of this run (the chart or the stage
    /// settings changed, so what was measured no longer applies): those stages are
    /// pending again on every shot. Their files stay until the stage runs again.
    pub fn forget_results(&mut self, detections: bool, kernels: bool) {
        for state in self.states.values_mut() {
            if detections {
                state.detection = None;
            }
            if kernels {
                state.kernels = None;
            }
        }
        if kernels {
            self.results.dataset = None;
        }
        for shot in &mut self.session.shots {
            if detections {
                shot.detect = StageStatus::Pending;
            }
            if kernels {
                shot.kernels = StageStatus::Pending;
            }
        }
    }

    /// The reading of the result cache, to run off the caller's thread; its result
    /// goes back through [`Project::apply_survey`].
    #[must_use]
    pub fn survey_job(&self) -> SurveyJob {
        SurveyJob {
            shots: self
                .session
                .shots
                .iter()
                .map(|s| {
                    (
                        s.id,
                        s.name(),
                        self.session.path_of(s),
                        s.detect.is_done(),
                        s.kernels.is_done(),
                    )
                })
                .collect(),
            measurement: self.session.measurement(),
            cache: self.session.cache(),
        }
    }

    /// Takes what a survey found: each shot's file, detection and kernels, and each
    /// stage's status settled (done where a result exists, pending where a recorded
    /// one has gone, a recorded failure kept). Returns what had to be left out.
    ///
    /// The survey runs off the caller's thread, so a job may record results while it
    /// reads: what the project recorded is newer than what the survey read and is
    /// kept, and results read for a chart or stage settings changed since are not
    /// taken (kernels files a manifest lists do not depend on them).
    pub fn apply_survey(&mut self, survey: Survey) -> Vec<String> {
        fn settle(status: &StageStatus, found: Option<String>) -> StageStatus {
            match (found, status) {
                (Some(summary), _) => StageStatus::Done { summary },
                (None, StageStatus::Failed { reason }) => StageStatus::Failed {
                    reason: reason.clone(),
                },
                (None, _) => StageStatus::Pending,
            }
        }
        let current = survey
            .measurement
            .is_none_or(|m| m == self.session.measurement());
        for (id, found) in survey.shots {
            let Some(shot) = self.session.shot_mut(id) else {
                continue;
            };
            let listed = is_kernels_file(&shot.path);
            let state = self.states.entry(id).or_default();
            // A job that read the shot knows its file better than the survey did.
            if state.file.is_none() {
                state.file = found.file;
                state.unreadable = found.unreadable;
            }
            if current {
                state.detection = state.detection.take().or(found.detection);
            }
            if current || listed {
                state.kernels = state.kernels.take().or(found.kernels);
            }
            shot.detect = settle(&shot.detect, state.detection.as_deref().map(detect_summary));
            shot.kernels = settle(&shot.kernels, state.kernels.as_deref().map(kernels_summary));
        }
        survey.dropped
    }

    /// [`Project::survey_job`] run here and applied.
    ///
    /// # Errors
    /// Cancellation.
    pub fn survey(&mut self, job: &JobContext) -> Result<Vec<String>, Cancelled> {
        let survey = self.survey_job().run(job)?;
        Ok(self.apply_survey(survey))
    }

    /// Runs the measurement `plan` asks for on the calling thread, recording each
    /// shot's result as it comes: for scripts and tests, which have no job thread to
    /// hand the job to and nothing to show meanwhile.
    ///
    /// # Errors
    /// `ctx` was cancelled; what was measured before is recorded.
    pub fn measure_now(&mut self, plan: &MeasurePlan, ctx: &JobContext) -> Result<(), Cancelled> {
        let job = self.measure_job(plan);
        job.run(ctx, &|_| Some(ctx.clone()), &mut |event| {
            self.record(&event);
        })
    }

    /// The measurement `plan` asks for, detached to run on any thread. Shots that
    /// cannot be read, and shots that are kernels files, are left out of a run over
    /// what is missing.
    #[must_use]
    pub fn measure_job(&self, plan: &MeasurePlan) -> MeasureJob {
        let wanted = |s: &ProjectShot| -> bool {
            let st = s.state;
            if is_kernels_file(&s.shot.path) {
                return false;
            }
            if let Some(only) = &plan.only {
                return only.contains(&s.shot.id);
            }
            if st.unreadable.is_some() {
                return false;
            }
            match plan.stages {
                Stages::Detect => st.detection.is_none(),
                Stages::Kernels => st.kernels.is_none() && st.detection.is_some(),
                Stages::All => st.kernels.is_none(),
            }
        };
        let work = self
            .shots()
            .filter(|s| wanted(s))
            .map(|s| ShotWork {
                id: s.shot.id,
                path: self.session.path_of(s.shot),
                file: s.state.file.clone(),
                given: s.shot.given_setting(),
                detection: s.state.detection.clone(),
                capture: None,
            })
            .collect();
        MeasureJob {
            measurement: self.session.measurement(),
            cache: self.session.cache(),
            stages: plan.stages,
            redo: plan.only.is_some(),
            require_setting: plan.require_setting,
            work,
        }
    }

    /// Takes one event of a measurement: the shot's result and status. Returns whether
    /// the shot is still in the project (a removed shot's late events are dropped).
    pub fn record(&mut self, event: &ShotEvent) -> bool {
        let id = event.shot();
        let (Some(state), Some(shot)) = (self.states.get_mut(&id), self.session.shot_mut(id))
        else {
            return false;
        };
        match event {
            ShotEvent::Started { .. } | ShotEvent::Cancelled { .. } => {}
            ShotEvent::Detected {
                file, detection, ..
            } => {
                shot.detect = StageStatus::Done {
                    summary: detect_summary(detection),
                };
                state.file = Some(file.clone());
                state.unreadable = None;
                state.detection = Some(Arc::clone(detection));
            }
            ShotEvent::Measured { file, kernels, .. } => {
                shot.kernels = StageStatus::Done {
                    summary: kernels_summary(kernels),
                };
                state.file = Some(file.clone());
                state.unreadable = None;
                state.kernels = Some(Arc::clone(kernels));
            }
            ShotEvent::Failed { stage, reason, .. } => {
                let failed = StageStatus::Failed {
                    reason: reason.clone(),
                };
                match stage {
                    Stage::Detect => shot.detect = failed,
                    Stage::Kernels => shot.kernels = failed,
                }
            }
        }
        true
    }

    /// The shots with measured kernels, in session order, as calibration takes them.
    #[must_use]
    pub fn measured_shots(&self) -> Vec<MeasuredShot> {
        self.shots()
            .filter_map(|s| {
                Some(MeasuredShot {
                    name: s.shot.name(),
                    kernels: KernelsFile::clone(s.state.kernels.as_ref()?),
                    given: s.shot.given_setting(),
                })
            })
            .collect()
    }

    /// The gathering of the measured Gaussians of every shot with kernels and a known
    /// setting (the sweeps show them before any calibration), detached to run on any
    /// thread; `None` where there are none (the project's dataset is then cleared).
    pub fn dataset_job(&mut self) -> Option<DatasetJob> {
        let shots = self.shots_with_settings();
        if shots.is_empty() {
            self.results.dataset = None;
            return None;
        }
        Some(DatasetJob { shots })
    }

    /// The measured shots whose setting is known (recorded, or in the kernels file).
    #[must_use]
    pub fn shots_with_settings(&self) -> Vec<MeasuredShot> {
        self.measured_shots()
            .into_iter()
            .filter(|s| {
                s.given.focal_mm.or(s.kernels.focal_mm).is_some()
                    && s.given.f_number.or(s.kernels.f_number).is_some()
            })
            .collect()
    }

    /// Calibration of every shot with kernels, detached to run on any thread.
    ///
    /// # Errors
    /// Fewer than two shots have kernels.
    pub fn calibration_job(
        &self,
        options: CalibrateOptions,
    ) -> Result<CalibrationJob, ProjectError> {
        let shots = self.measured_shots();
        if shots.len() < 2 {
            return Err(ProjectError::TooFewShots(shots.len()));
        }
        Ok(CalibrationJob {
            shots,
            chart: self.session.chart.clone(),
            options,
        })
    }

    /// Whatever is missing, measured, then calibration over every measured shot, as
    /// one job (see [`CalibrateAllJob`]).
    #[must_use]
    pub fn calibrate_all_job(&self, options: CalibrateOptions) -> CalibrateAllJob {
        let order = self
            .shots()
            .filter(|s| s.state.kernels.is_some() || !is_kernels_file(&s.shot.path))
            .map(|s| {
                let shot = match &s.state.kernels {
                    Some(k) => Pending::Measured(Box::new(MeasuredShot {
                        name: s.shot.name(),
                        kernels: KernelsFile::clone(k),
                        given: s.shot.given_setting(),
                    })),
                    None => Pending::ToMeasure {
                        name: s.shot.name(),
                        given: s.shot.given_setting(),
                    },
                };
                (s.shot.id, shot)
            })
            .collect();
        CalibrateAllJob {
            measure: self.measure_job(&MeasurePlan::missing(Stages::All)),
            order,
            chart: self.session.chart.clone(),
            options,
        }
    }

    /// Records the profile the session now uses (relative to its folder where it lies
    /// inside it).
    pub fn set_profile(&mut self, path: &Path) {
        let stored = path
            .strip_prefix(self.session.folder())
            .map_or_else(|_| path.to_path_buf(), Path::to_path_buf);
        self.session.profile = Some(stored);
    }

    /// What the project has calibrated or been given.
    #[must_use]
    pub fn results(&self) -> &Results {
        &self.results
    }

    /// The measured Gaussians, once gathered or calibrated on.
    #[must_use]
    pub fn dataset(&self) -> Option<&Arc<Dataset>> {
        self.results.dataset.as_ref()
    }

    /// The profile in use and where it lies.
    #[must_use]
    pub fn profile(&self) -> Option<&(PathBuf, Arc<Profile>)> {
        self.results.profile.as_ref()
    }

    /// The profile shown beside the one in use.
    #[must_use]
    pub fn compare_profile(&self) -> Option<&(PathBuf, Arc<Profile>)> {
        self.results.compare_profile.as_ref()
    }

    /// The cross-validation report of the profile's fit.
    #[must_use]
    pub fn cv(&self) -> Option<&Arc<CvReport>> {
        self.results.cv.as_ref()
    }

    /// The measured Gaussians a [`DatasetJob`] gathered (`None`: it failed).
    pub fn set_dataset(&mut self, dataset: Option<Arc<Dataset>>) {
        self.results.dataset = dataset;
    }

    /// What calibration made, in use from now on: the profile (recorded in the
    /// session, see [`Self::set_profile`]), the measurements it was fitted to and its
    /// cross-validation report.
    pub fn use_calibration(
        &mut self,
        path: PathBuf,
        dataset: Arc<Dataset>,
        profile: Arc<Profile>,
        cv: Option<Arc<CvReport>>,
    ) {
        self.set_profile(&path);
        self.results.dataset = Some(dataset);
        self.results.profile = Some((path, profile));
        self.results.cv = cv;
    }

    /// A profile loaded from a file: the one in use, or (with `compare`) the one
    /// shown beside it.
    pub fn use_profile(&mut self, path: PathBuf, profile: Arc<Profile>, compare: bool) {
        let slot = if compare {
            &mut self.results.compare_profile
        } else {
            &mut self.results.profile
        };
        *slot = Some((path, profile));
    }

    /// The cross-validation report read back with the session's results, unless a
    /// calibration of this run has made one already.
    pub fn read_cv(&mut self, cv: Option<Arc<CvReport>>) {
        if self.results.cv.is_none() {
            self.results.cv = cv;
        }
    }

    /// Hands `session.json` to the writer thread (a no-op for a bare manifest).
    ///
    /// # Errors
    /// An earlier background write failed (the reason names the file); this one is
    /// handed on all the same.
    pub fn save(&self) -> Result<(), ProjectError> {
        let earlier = self.saver.take_failure();
        if self.persistent {
            self.saver.save(&self.session)?;
        }
        earlier.map_or(Ok(()), |reason| Err(ProjectError::Save(reason)))
    }

    /// Waits until every save handed on so far is on disk.
    ///
    /// # Errors
    /// A background write failed.
    pub fn flush(&self) -> Result<(), ProjectError> {
        self.saver.flush();
        self.saver
            .take_failure()
            .map_or(Ok(()), |reason| Err(ProjectError::Save(reason)))
    }
}

/// A detection's one-line status.
#[must_use]
pub fn detect_summary(d: &Detection) -> String {
    format!(
        "{} of {} squares aligned",
        d.ok_squares().count(),
        d.squares.len()
    )
}

/// A kernels file's one-line status.
#[must_use]
pub fn kernels_summary(file: &KernelsFile) -> String {
    format!(
        "{} kernels, {} failed",
        file.samples.len(),
        file.failed.len()
    )
}
