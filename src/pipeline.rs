//! The chain a shot goes through (load → detect → kernels) and calibration over a
//! session's shots, written once for every front end: `lensblur kernels`,
//! `lensblur calibrate` and the studio all call these functions.
//!
//! Each stage's result is cached in the session folder's `results/`, in a file whose
//! name is derived from everything that decides it: the shot file's content (not its
//! path or its place in a list), the chart, the stage's parameters and
//! [`MEASURE_VERSION`]. A cache written by the studio is therefore read by
//! `lensblur calibrate` on the same folder's manifest and the other way round, a shot
//! renamed or moved keeps its results, and a shot whose file changed is measured again.
//! Every result file records the shot it was measured on ([`ShotRecord`]).

use crate::chart::ChartSpec;
use crate::detect::{DetectFile, DetectParams, Detection};
use crate::job::JobContext;
use crate::kernel::KernelParams;
use crate::kernel::file::KernelsFile;
use crate::plane::{Capture, LensSetting};
use crate::shot_file::Fnv;
pub use crate::shot_file::{Fingerprint, ShotFile, ShotRecord};
use std::path::{Path, PathBuf};

/// The folder, inside a session folder, that holds every shot's stage results.
pub const RESULTS_DIR: &str = "results";

/// Part of every cache key: bumped when a stage changes what it writes, so results of
/// an older measurement are measured again instead of mixed with new ones.
pub const MEASURE_VERSION: u32 = 3;

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Read(#[from] crate::shot_file::ShotReadError),
    #[error(transparent)]
    Load(#[from] crate::raw::LoadError),
    /// A stage failed on a shot: the shot's file and the stage's reason.
    #[error("{}: {reason}", path.display())]
    Stage { path: PathBuf, reason: String },
    #[error(
        "{}: no {missing} in the manifest or the file's EXIF; give the shot's \"focal_mm\" and \"f_number\" (manifest), type them (studio) or pass --focal and --aperture (lensblur calibrate and kernels)",
        path.display()
    )]
    NoSetting {
        path: PathBuf,
        missing: &'static str,
    },
    /// A cached result that cannot be read back: the file and the reason.
    #[error("{}: unreadable cached result: {reason}", path.display())]
    Cache { path: PathBuf, reason: String },
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    #[error("cancelled")]
    Cancelled(#[from] crate::job::Cancelled),
}

impl PipelineError {
    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        matches!(self, PipelineError::Cancelled(_))
    }
}

/// What decides a shot's results besides the shot itself: the chart printed and each
/// stage's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    pub chart: ChartSpec,
    pub detect: DetectParams,
    pub kernels: KernelParams,
}

impl Measurement {
    #[must_use]
    pub fn new(chart: ChartSpec, kernels: KernelParams) -> Self {
        Self {
            chart,
            detect: DetectParams::default(),
            kernels,
        }
    }

    fn detect_key(&self, shot: &ShotFile) -> u64 {
        let mut h = Fnv::new();
        h.eat(format!("detect v{MEASURE_VERSION} {}", shot.fingerprint).as_bytes());
        h.eat(
            serde_json::to_string(&self.chart)
                .unwrap_or_default()
                .as_bytes(),
        );
        h.eat(format!("{:?}", self.detect).as_bytes());
        h.0
    }

    fn kernels_key(&self, shot: &ShotFile) -> u64 {
        let mut h = Fnv::new();
        h.eat(&self.detect_key(shot).to_le_bytes());
        h.eat(format!("kernels {:?}", self.kernels).as_bytes());
        h.0
    }
}

/// A session folder's cache of stage results (see the module documentation).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ResultCache {
    pub dir: PathBuf,
}

impl ResultCache {
    /// The cache of the session (or manifest) in `folder`.
    #[must_use]
    pub fn in_folder(folder: &Path) -> Self {
        Self {
            dir: folder.join(RESULTS_DIR),
        }
    }

    #[must_use]
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    #[must_use]
    pub fn detect_path(&self, shot: &ShotFile, m: &Measurement) -> PathBuf {
        self.dir.join(format!(
            "{}-{:016x}.detect.json",
            shot.stem(),
            m.detect_key(shot)
        ))
    }

    #[must_use]
    pub fn kernels_path(&self, shot: &ShotFile, m: &Measurement) -> PathBuf {
        self.dir.join(format!(
            "{}-{:016x}.kernels.json",
            shot.stem(),
            m.kernels_key(shot)
        ))
    }

    /// The shot's cached detection, if there is one.
    ///
    /// # Errors
    /// A cached file that exists but cannot be read or parsed.
    pub fn detection(
        &self,
        shot: &ShotFile,
        m: &Measurement,
    ) -> Result<Option<Detection>, PipelineError> {
        let path = self.detect_path(shot, m);
        let Some(text) = read_if_present(&path)? else {
            return Ok(None);
        };
        let file = DetectFile::from_json(&text).map_err(|reason| PipelineError::Cache {
            path: path.clone(),
            reason,
        })?;
        Ok(Some(Detection::from_file(&file)))
    }

    /// The shot's cached kernels, if there are some.
    ///
    /// # Errors
    /// A cached file that exists but cannot be read or is not a valid kernels file.
    pub fn kernels(
        &self,
        shot: &ShotFile,
        m: &Measurement,
    ) -> Result<Option<KernelsFile>, PipelineError> {
        let path = self.kernels_path(shot, m);
        if !path.is_file() {
            return Ok(None);
        }
        if let Ok(k) = crate::kernel::packed::load_beside(&path) {
            return Ok(Some(k));
        }
        let k = KernelsFile::load(&path).map_err(|e| PipelineError::Cache {
            path: path.clone(),
            reason: e.reason,
        })?;
        // A result cached before the packed form existed (or copied without its file
        // times) gets one now, so the next read is fast; failing to write it only
        // costs that speed, never the result.
        let _ = crate::kernel::packed::write_beside(&path, &k);
        Ok(Some(k))
    }
}

fn read_if_present(path: &Path) -> Result<Option<String>, PipelineError> {
    match crate::io::read_json_text(path) {
        Ok(t) => Ok(Some(t)),
        Err(crate::io::ReadError::Io { source, .. })
            if source.kind() == std::io::ErrorKind::NotFound =>
        {
            Ok(None)
        }
        Err(e) => Err(PipelineError::Cache {
            path: path.to_path_buf(),
            reason: e.to_string(),
        }),
    }
}

/// A shot's focal length and f-number as given by a manifest, the studio or flags;
/// either may be missing, and then the file's EXIF decides.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GivenSetting {
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
}

impl GivenSetting {
    /// What was given, completed from the capture's EXIF.
    #[must_use]
    pub fn or_exif(self, capture: &Capture) -> GivenSetting {
        GivenSetting {
            focal_mm: self.focal_mm.or(capture.setting_focal_mm),
            f_number: self.f_number.or(capture.setting_f_number),
        }
    }

    /// Both values, or the error naming the shot and what is missing: a shot is only
    /// measured for calibration once its setting is known.
    ///
    /// # Errors
    /// [`PipelineError::NoSetting`].
    pub fn require(self, path: &Path) -> Result<LensSetting, PipelineError> {
        match (self.focal_mm, self.f_number) {
            (Some(focal_mm), Some(f_number)) => Ok(LensSetting { focal_mm, f_number }),
            (f, _) => Err(PipelineError::NoSetting {
                path: path.to_path_buf(),
                missing: match (f, self.f_number) {
                    (None, None) => "focal length or f-number",
                    (None, Some(_)) => "focal length",
                    _ => "f-number",
                },
            }),
        }
    }
}

/// Loads a shot through the core's loader.
///
/// # Errors
/// The file cannot be read or decoded (the reason names the file).
pub fn load(path: &Path) -> Result<Capture, PipelineError> {
    Ok(crate::raw::load_capture(
        path,
        &crate::raw::LoadOptions::default(),
    )?)
}

/// Detects the chart in a loaded shot; errors name the shot's file.
///
/// # Errors
/// Detection failed, or the job was cancelled.
pub fn detect(
    capture: &Capture,
    path: &Path,
    m: &Measurement,
    job: &JobContext,
) -> Result<Detection, PipelineError> {
    crate::detect::detect(capture, &m.chart, &m.detect, job).map_err(|e| match e {
        crate::detect::DetectError::Cancelled(c) => PipelineError::Cancelled(c),
        e => PipelineError::Stage {
            path: path.to_path_buf(),
            reason: e.to_string(),
        },
    })
}

/// Estimates a detected shot's kernels and their Gaussians as a kernels file, which
/// records the setting as given or else read from EXIF, and where the file says the
/// lens was focused; `with_kernels` keeps the
/// kernel arrays, not only their fits.
///
/// # Errors
/// Estimation failed, or the job was cancelled.
pub fn estimate(
    capture: &Capture,
    detection: &Detection,
    path: &Path,
    setting: GivenSetting,
    m: &Measurement,
    with_kernels: bool,
    job: &JobContext,
) -> Result<KernelsFile, PipelineError> {
    let kernels = crate::kernel::estimate_shot(capture, detection, &m.chart, &m.kernels, job)
        .map_err(|e| match e {
            crate::kernel::KernelError::Cancelled(c) => PipelineError::Cancelled(c),
            e => PipelineError::Stage {
                path: path.to_path_buf(),
                reason: e.to_string(),
            },
        })?;
    let setting = setting.or_exif(capture);
    let mut file = KernelsFile::from_shot(
        &kernels,
        setting.focal_mm,
        setting.f_number,
        Some(capture.identity.clone()),
        with_kernels,
    );
    file.focus_distance_m = capture
        .setting_focus_m
        .and_then(crate::raw::FocusDistance::from_metres);
    file.picture = Some(capture.picture_kind());
    Ok(file)
}

/// [`detect`], and the result cached.
///
/// # Errors
/// Detection failed, the cache cannot be written, or the job was cancelled.
pub fn detect_shot(
    capture: &Capture,
    shot: &ShotFile,
    m: &Measurement,
    cache: &ResultCache,
    job: &JobContext,
) -> Result<Detection, PipelineError> {
    let det = detect(capture, &shot.path, m, job)?;
    let mut file = det.to_file();
    file.source = Some(shot.record());
    crate::io::create_dir_all(cache.dir())?;
    crate::io::write_json(&cache.detect_path(shot, m), &file)?;
    Ok(det)
}

/// [`estimate`] with the kernel arrays (the studio shows them, and deblurring with
/// measured kernels needs them), and the kernels file cached.
///
/// # Errors
/// Estimation failed, the cache cannot be written, or the job was cancelled.
pub fn kernels_of_shot(
    capture: &Capture,
    detection: &Detection,
    shot: &ShotFile,
    setting: GivenSetting,
    m: &Measurement,
    cache: &ResultCache,
    job: &JobContext,
) -> Result<KernelsFile, PipelineError> {
    let mut file = estimate(capture, detection, &shot.path, setting, m, true, job)?;
    file.source = Some(shot.record());
    crate::io::create_dir_all(cache.dir())?;
    let path = cache.kernels_path(shot, m);
    crate::io::write_json(&path, &file)?;
    // The packed form, which the cache reads instead of the JSON file's text; without
    // it (a failed write) the JSON file is read, so the result stands either way.
    let _ = crate::kernel::packed::write_beside(&path, &file);
    Ok(file)
}

/// How [`measure_shot`] came by a shot's kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Provenance {
    Cached,
    Measured,
}

/// A shot's kernels from the cache, or by the whole chain (load → detect, itself from
/// the cache where it can be → kernels), caching what it computes. With
/// `require_setting`, a shot whose focal length or f-number is neither given nor in
/// its EXIF is refused right after loading, before the minutes of measuring.
///
/// # Errors
/// Any stage's failure naming the shot, a missing setting, or cancellation.
pub fn measure_shot(
    shot: &ShotFile,
    given: GivenSetting,
    require_setting: bool,
    m: &Measurement,
    cache: &ResultCache,
    job: &JobContext,
) -> Result<(KernelsFile, Provenance), PipelineError> {
    // A cached result that cannot be read (edited or damaged by hand: our own writes
    // are atomic) is measured again and overwritten; a survey names it to the user.
    if let Some(k) = usable(cache.kernels(shot, m))? {
        if require_setting {
            GivenSetting {
                focal_mm: given.focal_mm.or(k.focal_mm),
                f_number: given.f_number.or(k.f_number),
            }
            .require(&shot.path)?;
        }
        return Ok((k, Provenance::Cached));
    }
    let capture = load(&shot.path)?;
    if require_setting {
        given.or_exif(&capture).require(&shot.path)?;
    }
    job.check()?;
    let det = match usable(cache.detection(shot, m))? {
        Some(d) => d,
        None => detect_shot(&capture, shot, m, cache, job)?,
    };
    let k = kernels_of_shot(&capture, &det, shot, given, m, cache, job)?;
    Ok((k, Provenance::Measured))
}

/// A cache lookup with an unreadable entry taken as absent.
fn usable<T>(found: Result<Option<T>, PipelineError>) -> Result<Option<T>, PipelineError> {
    match found {
        Err(PipelineError::Cache { .. }) => Ok(None),
        other => other,
    }
}

/// One measured shot as calibration takes it.
#[derive(Clone, Debug)]
pub struct MeasuredShot {
    /// How errors and reports name the shot (its photo, never its cache file).
    pub name: String,
    pub kernels: KernelsFile,
    /// The session's record of its setting; the kernels file's own where absent.
    pub given: GivenSetting,
}

/// The measured Gaussians of a session's shots, each at its setting.
///
/// # Errors
/// A shot without a setting, or shots of different cameras or lenses (each names the
/// photo).
pub fn dataset(shots: &[MeasuredShot]) -> Result<crate::model::Dataset, crate::model::ModelError> {
    let named: Vec<(&str, &KernelsFile, Option<LensSetting>)> = shots
        .iter()
        .map(|s| {
            let setting = GivenSetting {
                focal_mm: s.given.focal_mm.or(s.kernels.focal_mm),
                f_number: s.given.f_number.or(s.kernels.f_number),
            };
            (
                s.name.as_str(),
                &s.kernels,
                setting
                    .focal_mm
                    .zip(setting.f_number)
                    .map(|(f, a)| LensSetting {
                        focal_mm: f,
                        f_number: a,
                    }),
            )
        })
        .collect();
    crate::model::Dataset::from_kernels(&named)
}
