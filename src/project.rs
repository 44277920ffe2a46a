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
use std::sync::{Arc, mpsc};

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

/// A shot's work in a [`MeasureJob`].
struct ShotWork {
    id: ShotId,
    path: PathBuf,
    file: Option<ShotFile>,
    given: GivenSetting,
    detection: Option<Arc<Detection>>,
    capture: Option<Arc<Capture>>,
}

/// A measurement of some of a project's shots, detached from the project so it runs on
/// any thread; its events go back to the project through [`Project::record`].
pub struct MeasureJob {
    measurement: Measurement,
    cache: ResultCache,
    stages: Stages,
    redo: bool,
    require_setting: bool,
    work: Vec<ShotWork>,
}

impl MeasureJob {
    /// Keeps only the shots `keep` says (the studio leaves out shots it cannot show).
    #[must_use]
    pub fn retain(mut self, keep: impl Fn(ShotId) -> bool) -> Self {
        self.work.retain(|w| keep(w.id));
        self
    }

    /// The shots the job will work on, in order.
    #[must_use]
    pub fn shots(&self) -> Vec<ShotId> {
        self.work.iter().map(|w| w.id).collect()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.work.is_empty()
    }

    /// Hands the job captures already in memory (the studio's previews), so those
    /// shots are not decoded again.
    #[must_use]
    pub fn with_captures(mut self, capture: impl Fn(ShotId) -> Option<Arc<Capture>>) -> Self {
        for w in &mut self.work {
            w.capture = capture(w.id);
        }
        self
    }

    /// Runs the job, one shot after another (each shot's stages are themselves
    /// parallel). `part` gives each shot's own context (`None`: the shot was removed,
    /// skip it), so one shot can be cancelled alone; every step is handed to `emit`.
    ///
    /// # Errors
    /// The whole job was cancelled.
    pub fn run(
        self,
        ctx: &JobContext,
        part: &dyn Fn(ShotId) -> Option<JobContext>,
        emit: &mut dyn FnMut(ShotEvent),
    ) -> Result<(), Cancelled> {
        let total = self.work.len();
        for (index, w) in self.work.iter().enumerate() {
            ctx.check()?;
            let Some(shot_ctx) = part(w.id) else {
                continue;
            };
            let shot_ctx = shot_ctx.prefixed(&format!("shot {} of {total}: ", index + 1));
            emit(ShotEvent::Started {
                id: w.id,
                index,
                total,
            });
            if let Err((stage, e)) = self.measure(w, &shot_ctx, emit) {
                if e.is_cancelled() {
                    emit(ShotEvent::Cancelled { id: w.id });
                    ctx.check()?;
                } else {
                    emit(ShotEvent::Failed {
                        id: w.id,
                        stage,
                        reason: e.to_string(),
                    });
                }
            }
        }
        Ok(())
    }

    fn measure(
        &self,
        w: &ShotWork,
        ctx: &JobContext,
        emit: &mut dyn FnMut(ShotEvent),
    ) -> Result<(), (Stage, pipeline::PipelineError)> {
        let first = if self.stages.detects() {
            Stage::Detect
        } else {
            Stage::Kernels
        };
        let at = |stage: Stage| move |e: pipeline::PipelineError| (stage, e);
        let file = match &w.file {
            Some(f) => f.clone(),
            None => ShotFile::read(&w.path).map_err(|e| (first, e.into()))?,
        };
        if self.redo {
            // The results being replaced go first: a run cut short then measures
            // again rather than finding the old ones.
            if self.stages.detects() {
                let _ = std::fs::remove_file(self.cache.detect_path(&file, &self.measurement));
            }
            if self.stages.measures_kernels() {
                let kernels = self.cache.kernels_path(&file, &self.measurement);
                let _ = std::fs::remove_file(&kernels);
                let _ = std::fs::remove_file(crate::kernel::packed::path_beside(&kernels));
            }
        }
        let capture = match &w.capture {
            Some(c) => Arc::clone(c),
            None => Arc::new(pipeline::load(&file.path).map_err(at(first))?),
        };
        if self.require_setting {
            w.given
                .or_exif(&capture)
                .require(&file.path)
                .map_err(at(first))?;
        }
        ctx.check().map_err(|c| (first, c.into()))?;
        let detection = match (&w.detection, self.stages.detects()) {
            (Some(d), _) if !(self.redo && self.stages.detects()) => Arc::clone(d),
            (_, true) => {
                let d = Arc::new(
                    pipeline::detect_shot(&capture, &file, &self.measurement, &self.cache, ctx)
                        .map_err(at(Stage::Detect))?,
                );
                emit(ShotEvent::Detected {
                    id: w.id,
                    file: file.clone(),
                    detection: Arc::clone(&d),
                });
                d
            }
            (_, false) => {
                return Err((
                    Stage::Kernels,
                    pipeline::PipelineError::Stage {
                        path: file.path.clone(),
                        reason: "the chart is not detected in it yet".into(),
                    },
                ));
            }
        };
        if self.stages.measures_kernels() {
            let kernels = pipeline::kernels_of_shot(
                &capture,
                &detection,
                &file,
                w.given,
                &self.measurement,
                &self.cache,
                ctx,
            )
            .map_err(at(Stage::Kernels))?;
            emit(ShotEvent::Measured {
                id: w.id,
                file,
                kernels: Arc::new(kernels),
            });
        }
        Ok(())
    }
}

/// What a survey found for each shot, detached from the project (see
/// [`Project::survey_job`]).
#[derive(Clone, Debug, Default)]
pub struct Survey {
    shots: BTreeMap<ShotId, ShotState>,
    /// The chart and stage settings the results were read for.
    measurement: Option<Measurement>,
    /// What was left out, one line each, naming the file and why.
    pub dropped: Vec<String>,
}

/// The reading of a project's result cache, detached so it runs off the caller's
/// thread (every shot is fingerprinted, and kernels files run to megabytes).
pub struct SurveyJob {
    shots: Vec<(ShotId, String, PathBuf, bool, bool)>,
    measurement: Measurement,
    cache: ResultCache,
}

impl SurveyJob {
    /// Reads what the cache holds for each shot: see [`Project::survey`].
    ///
    /// # Errors
    /// Only cancellation: everything else is a dropped entry or an unreadable shot.
    pub fn run(self, job: &JobContext) -> Result<Survey, Cancelled> {
        use rayon::prelude::*;
        use std::sync::atomic::{AtomicUsize, Ordering};
        let (m, cache) = (&self.measurement, &self.cache);
        let total = self.shots.len();
        let done = AtomicUsize::new(0);
        job.report("reading results", 0, total);
        // Shots are read in parallel (fingerprinting a photo reads all of it, and a
        // kernels file decodes tens of thousands of kernels); the survey is put
        // together in the shots' order, so it and its messages do not depend on it.
        let read: Vec<ShotRead> = self
            .shots
            .into_par_iter()
            .map(|(id, name, path, detect_done, kernels_done)| {
                job.check()?;
                let what = if is_kernels_file(&path) {
                    // A manifest may list kernels measured earlier instead of photos.
                    Read::Listed(KernelsFile::load(&path).map_err(|e| e.to_string()))
                } else {
                    match ShotFile::read(&path) {
                        Ok(file) => Read::Shot {
                            detection: cache.detection(&file, m),
                            kernels: cache.kernels(&file, m),
                            file,
                        },
                        Err(e) => Read::Unreadable(if path.exists() {
                            e.to_string()
                        } else {
                            format!("{}: not found (renamed or removed?)", path.display())
                        }),
                    }
                };
                job.report(
                    "reading results",
                    done.fetch_add(1, Ordering::Relaxed) + 1,
                    total,
                );
                Ok(ShotRead {
                    id,
                    name,
                    detect_done,
                    kernels_done,
                    what,
                })
            })
            .collect::<Result<_, Cancelled>>()?;
        let mut survey = Survey {
            measurement: Some(self.measurement.clone()),
            ..Survey::default()
        };
        for r in read {
            let state = survey.shots.entry(r.id).or_default();
            match r.what {
                Read::Listed(Ok(k)) => state.kernels = Some(Arc::new(k)),
                Read::Listed(Err(e)) => state.unreadable = Some(e),
                Read::Unreadable(why) => {
                    survey
                        .dropped
                        .push(format!("{why}: its results are left out until it is back"));
                    state.unreadable = Some(why);
                }
                Read::Shot {
                    file,
                    detection,
                    kernels,
                } => {
                    let dropped = &mut survey.dropped;
                    let recorded = (r.name.as_str(), r.detect_done);
                    if let Some(d) =
                        from_cache(detection, recorded, "detection is", "detected", dropped)
                    {
                        state.detection = Some(d);
                    }
                    let recorded = (r.name.as_str(), r.kernels_done);
                    if let Some(k) =
                        from_cache(kernels, recorded, "kernels are", "measured", dropped)
                    {
                        state.kernels = Some(k);
                    }
                    state.file = Some(file);
                }
            }
        }
        job.report("reading results", total, total);
        Ok(survey)
    }
}

/// One shot as the survey read it, before it joins the survey.
struct ShotRead {
    id: ShotId,
    name: String,
    detect_done: bool,
    kernels_done: bool,
    what: Read,
}

/// What reading one shot found.
enum Read {
    /// A kernels file the manifest lists instead of a photo.
    Listed(Result<KernelsFile, String>),
    /// A photo that could not be read (why, in words).
    Unreadable(String),
    /// A photo, fingerprinted, with what the cache holds for it.
    Shot {
        file: ShotFile,
        detection: Result<Option<Detection>, pipeline::PipelineError>,
        kernels: Result<Option<KernelsFile>, pipeline::PipelineError>,
    },
}

/// A shot's cached detection or kernels as the survey takes them: what the cache holds,
/// or a line in `dropped` saying why not where the project had recorded it
/// (`recorded`: the shot's name and whether it had) or the cache could not be read.
fn from_cache<T>(
    found: Result<Option<T>, pipeline::PipelineError>,
    (name, recorded): (&str, bool),
    what_is: &str,
    redone: &str,
    dropped: &mut Vec<String>,
) -> Option<Arc<T>> {
    match found {
        Ok(Some(v)) => return Some(Arc::new(v)),
        Ok(None) if recorded => dropped.push(format!(
            "{name}: its recorded {what_is} gone from the results: pending again"
        )),
        Ok(None) => {}
        Err(e) => dropped.push(format!("{e}: left out, {redone} again when needed")),
    }
    None
}

/// Whether a shot path is a kernels file measured earlier rather than a photo.
fn is_kernels_file(path: &Path) -> bool {
    path.to_string_lossy().ends_with(".kernels.json")
}

/// Calibration of a project's measured shots, detached so it runs on any thread.
pub struct CalibrationJob {
    shots: Vec<MeasuredShot>,
    chart: crate::chart::ChartSpec,
    options: CalibrateOptions,
}

/// What calibration made.
pub struct Calibration {
    pub dataset: Dataset,
    pub profile: Profile,
    /// The cross-validation report; `None` where α and β were fixed.
    pub cv: Option<CvReport>,
}

impl CalibrationJob {
    /// Fits the models (cross-validated unless the options fix the orders).
    ///
    /// # Errors
    /// A shot without its setting (named), shots of different cameras or lenses, a
    /// failed fit, or cancellation.
    pub fn run(self, ctx: &JobContext) -> Result<Calibration, ProjectError> {
        let dataset =
            pipeline::dataset(&self.shots).map_err(|e| ProjectError::Calibrate(e.to_string()))?;
        let (profile, cv) =
            crate::calibrate::calibrate(&dataset, Some(self.chart), &self.options, ctx).map_err(
                |e| match e {
                    crate::model::ModelError::Cancelled => ProjectError::Cancelled(Cancelled),
                    e => ProjectError::Calibrate(e.to_string()),
                },
            )?;
        Ok(Calibration {
            dataset,
            profile,
            cv,
        })
    }
}

/// Everything a project still lacks, as one job: the shots missing a result
/// measured (detection where there is none, then kernels), then calibration over every
/// shot with kernels — those measured before and those measured now, in session order.
/// The studio's *Calibrate all*.
pub struct CalibrateAllJob {
    measure: MeasureJob,
    /// Every shot in session order, with its kernels or what this job needs to take
    /// them once measured.
    order: Vec<(ShotId, Pending)>,
    chart: crate::chart::ChartSpec,
    options: CalibrateOptions,
}

/// A shot in a [`CalibrateAllJob`]: measured already, or its name and setting for
/// when the job has measured it.
enum Pending {
    Measured(Box<MeasuredShot>),
    ToMeasure { name: String, given: GivenSetting },
}

impl CalibrateAllJob {
    /// Keeps only the shots `keep` says among those to measure.
    #[must_use]
    pub fn retain(mut self, keep: impl Fn(ShotId) -> bool) -> Self {
        self.measure = self.measure.retain(keep);
        self
    }

    /// Captures already in memory, as [`MeasureJob::with_captures`].
    #[must_use]
    pub fn with_captures(mut self, capture: impl Fn(ShotId) -> Option<Arc<Capture>>) -> Self {
        self.measure = self.measure.with_captures(capture);
        self
    }

    /// The shots this job measures (those it calibrates from the cache come on top).
    #[must_use]
    pub fn shots(&self) -> Vec<ShotId> {
        self.measure.shots()
    }

    /// Measures, handing every step to `emit` as [`MeasureJob::run`] does, then
    /// calibrates.
    ///
    /// # Errors
    /// Cancellation, fewer than two shots with kernels once measuring ended, or what
    /// [`CalibrationJob::run`] refuses.
    pub fn run(
        self,
        ctx: &JobContext,
        part: &dyn Fn(ShotId) -> Option<JobContext>,
        emit: &mut dyn FnMut(ShotEvent),
    ) -> Result<Calibration, ProjectError> {
        let mut measured = BTreeMap::new();
        self.measure.run(ctx, part, &mut |e| {
            if let ShotEvent::Measured { id, kernels, .. } = &e {
                measured.insert(*id, Arc::clone(kernels));
            }
            emit(e);
        })?;
        let shots: Vec<MeasuredShot> = self
            .order
            .into_iter()
            .filter_map(|(id, shot)| match shot {
                Pending::Measured(shot) => Some(*shot),
                Pending::ToMeasure { name, given } => Some(MeasuredShot {
                    name,
                    kernels: KernelsFile::clone(measured.get(&id)?),
                    given,
                }),
            })
            .collect();
        if shots.len() < 2 {
            return Err(ProjectError::TooFewShots(shots.len()));
        }
        CalibrationJob {
            shots,
            chart: self.chart,
            options: self.options,
        }
        .run(ctx)
    }
}

impl Calibration {
    /// Writes the profile to `profile_path` and, with `cv_path`, the cross-validation
    /// report there (or removes an old one, which would describe another fit).
    ///
    /// # Errors
    /// A file cannot be written.
    pub fn write(&self, profile_path: &Path, cv_path: Option<&Path>) -> Result<(), ProjectError> {
        self.profile
            .save(profile_path)
            .map_err(|e| ProjectError::Calibrate(e.to_string()))?;
        if let Some(cv_path) = cv_path {
            match &self.cv {
                Some(report) => crate::io::write_json(cv_path, report)?,
                None => {
                    let _ = std::fs::remove_file(cv_path);
                }
            }
        }
        Ok(())
    }
}

/// Writes `session.json` on a thread of its own, the newest copy first.
struct Saver {
    tx: Option<mpsc::Sender<SaveRequest>>,
    thread: Option<std::thread::JoinHandle<()>>,
    failed: Arc<std::sync::Mutex<Option<String>>>,
}

enum SaveRequest {
    Save(Box<Session>),
    Flush(mpsc::Sender<()>),
}

impl Saver {
    fn start() -> Self {
        let (tx, rx) = mpsc::channel::<SaveRequest>();
        let failed = Arc::new(std::sync::Mutex::new(None));
        let failures = Arc::clone(&failed);
        let thread = std::thread::Builder::new()
            .name("lensblur session writer".into())
            .spawn(move || {
                let mut pending: Option<Box<Session>> = None;
                while let Ok(first) = rx.recv() {
                    // Only the newest copy matters: take everything waiting first.
                    let mut requests = vec![first];
                    requests.extend(rx.try_iter());
                    let mut acks = Vec::new();
                    for r in requests {
                        match r {
                            SaveRequest::Save(s) => pending = Some(s),
                            SaveRequest::Flush(ack) => acks.push(ack),
                        }
                    }
                    if let Some(s) = pending.take()
                        && let Err(e) = s.save()
                        && let Ok(mut f) = failures.lock()
                    {
                        *f = Some(e.to_string());
                    }
                    for ack in acks {
                        let _ = ack.send(());
                    }
                }
            })
            .ok();
        Self {
            tx: thread.as_ref().map(|_| tx),
            thread,
            failed,
        }
    }

    fn save(&self, session: &Session) -> Result<(), SessionError> {
        match &self.tx {
            Some(tx)
                if tx
                    .send(SaveRequest::Save(Box::new(session.clone())))
                    .is_ok() =>
            {
                Ok(())
            }
            // No writer thread could be started: write here.
            _ => session.save(),
        }
    }

    fn flush(&self) {
        if let Some(tx) = &self.tx {
            let (ack, done) = mpsc::channel();
            if tx.send(SaveRequest::Flush(ack)).is_ok() {
                let _ = done.recv();
            }
        }
    }

    fn take_failure(&self) -> Option<String> {
        self.failed.lock().ok().and_then(|mut f| f.take())
    }
}

impl Drop for Saver {
    fn drop(&mut self) {
        // Closing the channel ends the thread once it has written what it was given.
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A calibration project: see the module documentation.
pub struct Project {
    session: Session,
    states: BTreeMap<ShotId, ShotState>,
    /// Whether `session.json` is written: a bare manifest the command line reads is
    /// left as it is.
    persistent: bool,
    saver: Saver,
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

    /// The measured Gaussians of every shot with kernels and a known setting (the
    /// sweeps show them before any calibration); `None` where there are none.
    ///
    /// # Errors
    /// Shots of different cameras or lenses.
    pub fn dataset(&self) -> Result<Option<Dataset>, crate::model::ModelError> {
        let shots = self.shots_with_settings();
        if shots.is_empty() {
            return Ok(None);
        }
        pipeline::dataset(&shots).map(Some)
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
