//! The jobs a project hands out, detached from it so they run on any thread: a
//! measurement, the survey of the result cache, calibration (alone or after whatever
//! measurement is missing) and the gathering of the measured Gaussians.

use super::*;

/// A shot's work in a [`MeasureJob`].
pub(super) struct ShotWork {
    pub(super) id: ShotId,
    pub(super) path: PathBuf,
    pub(super) file: Option<ShotFile>,
    pub(super) given: GivenSetting,
    pub(super) detection: Option<Arc<Detection>>,
    pub(super) capture: Option<Arc<Capture>>,
}

/// A measurement of some of a project's shots, detached from the project so it runs on
/// any thread; its events go back to the project through [`Project::record`].
pub struct MeasureJob {
    pub(super) measurement: Measurement,
    pub(super) cache: ResultCache,
    pub(super) stages: Stages,
    pub(super) redo: bool,
    pub(super) require_setting: bool,
    pub(super) work: Vec<ShotWork>,
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
    pub(super) shots: BTreeMap<ShotId, ShotState>,
    /// The chart and stage settings the results were read for.
    pub(super) measurement: Option<Measurement>,
    /// What was left out, one line each, naming the file and why.
    pub dropped: Vec<String>,
}

/// The reading of a project's result cache, detached so it runs off the caller's
/// thread (every shot is fingerprinted, and kernels files run to megabytes).
pub struct SurveyJob {
    pub(super) shots: Vec<(ShotId, String, PathBuf, bool, bool)>,
    pub(super) measurement: Measurement,
    pub(super) cache: ResultCache,
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
pub(super) fn is_kernels_file(path: &Path) -> bool {
    path.to_string_lossy().ends_with(".kernels.json")
}

/// Calibration of a project's measured shots, detached so it runs on any thread.
pub struct CalibrationJob {
    pub(super) shots: Vec<MeasuredShot>,
    pub(super) chart: crate::chart::ChartSpec,
    pub(super) options: CalibrateOptions,
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
    pub(super) measure: MeasureJob,
    /// Every shot in session order, with its kernels or what this job needs to take
    /// them once measured.
    pub(super) order: Vec<(ShotId, Pending)>,
    pub(super) chart: crate::chart::ChartSpec,
    pub(super) options: CalibrateOptions,
}

/// A shot in a [`CalibrateAllJob`]: measured already, or its name and setting for
/// when the job has measured it.
pub(super) enum Pending {
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

/// The gathering of a project's measured Gaussians (see [`Project::dataset_job`]).
pub struct DatasetJob {
    pub(super) shots: Vec<MeasuredShot>,
}

impl DatasetJob {
    /// Gathers the shots' Gaussians into one dataset.
    ///
    /// # Errors
    /// Shots of different cameras or lenses.
    pub fn run(self) -> Result<Dataset, crate::model::ModelError> {
        pipeline::dataset(&self.shots)
    }
}
