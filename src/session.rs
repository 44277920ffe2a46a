//! A calibration session as the studio keeps it: the shots, their lens settings, the
//! chart, the stage settings, and where each stage's results live.
//!
//! A session is a folder: `session.json` plus the stage results the pipeline caches
//! under `results/` (named by each shot's content, see [`crate::pipeline`]). The studio
//! rewrites `session.json` (atomically) every time the session changes, so quitting or a
//! crash loses nothing. A session exports its manifest (the format
//! [`crate::manifest`] owns), which is what `lensblur calibrate` reads; both find the
//! same cached results.
//!
//! Shots are identified by a [`ShotId`] that never changes and is never reused within a
//! session, not by their place in the list: work running on a shot reports by its id,
//! so removing another shot cannot make it land on the wrong one.
//!
//! This module is core: it never touches egui.

use crate::chart::ChartSpec;
use crate::manifest::{ChartRef, MANIFEST_FILE, Manifest, ManifestShot};
use crate::plane::LensSetting;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub const SESSION_FILE: &str = "session.json";
/// The session file's version. Version 1 had no shot ids.
pub const SESSION: crate::format::Schema = crate::format::Schema {
    kind: "session",
    current: 2,
    unversioned: None,
};

/// File types a shot may have (RAW formats rawloader reads, DNG, TIFF, PNG, JPEG).
pub const SHOT_EXTENSIONS: &[&str] = &[
    "dng", "tif", "tiff", "png", "jpg", "jpeg", "cr2", "cr3", "nef", "arw", "orf", "rw2", "pef",
    "raf", "srw", "mrw", "3fr", "erf", "kdc", "dcr", "mef", "nrw", "rwl", "iiq",
];

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a session or manifest: {reason}")]
    Parse { path: PathBuf, reason: String },
    #[error("{path}: cannot write: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: unsupported file type (expected RAW, DNG, TIFF, PNG or JPEG)")]
    Unsupported { path: PathBuf },
    #[error("{path}: already in the session")]
    Duplicate { path: PathBuf },
    #[error("{path}: no such file")]
    Missing { path: PathBuf },
}

/// What [`Session::survey`] found in a session folder.
#[derive(Clone, Debug, Default)]
pub struct Survey {
    pub detections: std::collections::BTreeMap<ShotId, crate::detect::Detection>,
    pub kernels: std::collections::BTreeMap<ShotId, crate::kernel::file::KernelsFile>,
    /// What was left out, one line each, naming the file and why.
    pub dropped: Vec<String>,
}

/// A detection's one-line status.
#[must_use]
pub fn detect_summary(d: &crate::detect::Detection) -> String {
    format!(
        "{} of {} squares aligned",
        d.ok_squares().count(),
        d.squares.len()
    )
}

/// A kernels file's one-line status.
#[must_use]
pub fn kernels_summary(file: &crate::kernel::file::KernelsFile) -> String {
    format!(
        "{} kernels, {} failed",
        file.samples.len(),
        file.failed.len()
    )
}

/// Parameters of the stages, as the user set them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageSettings {
    /// Kernel super-resolution factor (the paper uses 3).
    #[serde(default = "default_oversample")]
    pub oversample: usize,
    /// Weight every sub-pixel (W = I) instead of only the real pixel centres.
    #[serde(default)]
    pub weight_all_subpixels: bool,
    /// Fixed model complexity; `None` lets cross-validation choose.
    #[serde(default)]
    pub alpha: Option<usize>,
    #[serde(default)]
    pub beta: Option<usize>,
    /// Deconvolution method: "hqs", "irls" or "wiener".
    #[serde(default = "default_method")]
    pub deblur_method: String,
}

fn default_oversample() -> usize {
    3
}
fn default_method() -> String {
    "hqs".into()
}

impl StageSettings {
    /// The kernel stage's parameters these settings choose.
    #[must_use]
    pub fn kernel_params(&self) -> crate::kernel::KernelParams {
        crate::kernel::KernelParams {
            oversample: self.oversample,
            weighting: if self.weight_all_subpixels {
                crate::kernel::Weighting::Uniform
            } else {
                crate::kernel::Weighting::PixelCentres
            },
            ..Default::default()
        }
    }
}

impl Default for StageSettings {
    fn default() -> Self {
        Self {
            oversample: default_oversample(),
            weight_all_subpixels: false,
            alpha: None,
            beta: None,
            deblur_method: default_method(),
        }
    }
}

/// Where one stage stands for one shot.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum StageStatus {
    #[default]
    Pending,
    /// Finished; `summary` is a short line for the shot list ("352 squares").
    Done { summary: String },
    /// Failed with a one-line reason naming the file.
    Failed { reason: String },
}

impl StageStatus {
    #[must_use]
    pub fn is_done(&self) -> bool {
        matches!(self, StageStatus::Done { .. })
    }
}

/// A shot's identity within its session: stable while the session lives, never reused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(transparent)]
pub struct ShotId(pub u64);

impl std::fmt::Display for ShotId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "#{}", self.0)
    }
}

/// One calibration shot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Shot {
    /// Version 1 files have none; [`Session::open`] numbers them.
    #[serde(default = "unnumbered")]
    pub id: ShotId,
    /// Relative to the session folder when the file is inside it, absolute otherwise.
    pub path: PathBuf,
    /// Settings from EXIF or typed by the user; `None` where unknown.
    #[serde(default)]
    pub focal_mm: Option<f64>,
    #[serde(default)]
    pub f_number: Option<f64>,
    #[serde(default)]
    pub detect: StageStatus,
    #[serde(default)]
    pub kernels: StageStatus,
}

fn unnumbered() -> ShotId {
    ShotId(0)
}

impl Shot {
    #[must_use]
    pub fn setting(&self) -> Option<LensSetting> {
        Some(LensSetting {
            focal_mm: self.focal_mm?,
            f_number: self.f_number?,
        })
    }

    /// The setting as the pipeline takes it (either value may be missing; EXIF fills in).
    #[must_use]
    pub fn given_setting(&self) -> crate::pipeline::GivenSetting {
        crate::pipeline::GivenSetting {
            focal_mm: self.focal_mm,
            f_number: self.f_number,
        }
    }

    /// The file name without its extension.
    #[must_use]
    pub fn stem(&self) -> String {
        self.path
            .file_stem()
            .map_or_else(|| "shot".into(), |s| s.to_string_lossy().into_owned())
    }

    /// How reports and errors name the shot: its path as the session stores it.
    #[must_use]
    pub fn name(&self) -> String {
        self.path.display().to_string()
    }
}

/// A session: see the module documentation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Session {
    pub schema: String,
    /// Shown in the title bar.
    pub name: String,
    pub chart: ChartSpec,
    #[serde(default)]
    pub settings: StageSettings,
    #[serde(default)]
    pub shots: Vec<Shot>,
    /// The lens profile last calibrated or loaded, relative to the folder.
    #[serde(default)]
    pub profile: Option<PathBuf>,
    /// True for the built-in demo session, whose ground truth is known.
    #[serde(default)]
    pub is_demo: bool,
    /// For the demo: what made it ([`DemoSpec::key`]), so a cache made by another spec
    /// or another version of the simulator is made again rather than shown.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demo_key: Option<String>,
    /// The id the next added shot gets.
    #[serde(default)]
    pub next_shot_id: u64,
    /// For the demo: a natural photo blurred by the virtual lens, which the Deblur view
    /// opens, so a newcomer sees deblurring on a photo rather than on the chart.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demo_photo: Option<DemoPhoto>,
    #[serde(skip)]
    folder: PathBuf,
}

/// The demo's photo: its file (relative to the session folder) and the setting the
/// virtual lens blurred it at (a PNG carries no EXIF to say so).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DemoPhoto {
    pub path: PathBuf,
    pub focal_mm: f64,
    pub f_number: f64,
}

impl Session {
    /// An empty session that will be saved in `folder`.
    #[must_use]
    pub fn new(folder: &Path) -> Self {
        let name = folder
            .file_name()
            .map_or_else(|| "session".into(), |s| s.to_string_lossy().into_owned());
        Self {
            schema: SESSION.tag(),
            name,
            chart: ChartSpec::default(),
            settings: StageSettings::default(),
            shots: Vec::new(),
            profile: None,
            is_demo: false,
            demo_key: None,
            next_shot_id: 1,
            demo_photo: None,
            folder: folder.to_path_buf(),
        }
    }

    #[must_use]
    pub fn folder(&self) -> &Path {
        &self.folder
    }

    /// Opens a session folder, a `session.json`, or a manifest (DESIGN.md §3), which
    /// becomes a session in the manifest's folder. A folder without `session.json` is a
    /// new, empty session there.
    ///
    /// # Errors
    /// The file cannot be read or is neither a session nor a manifest.
    pub fn open(path: &Path) -> Result<Self, SessionError> {
        if path.is_dir() {
            let file = path.join(SESSION_FILE);
            if file.is_file() {
                return Self::open(&file);
            }
            let manifest = path.join(MANIFEST_FILE);
            if manifest.is_file() {
                return Self::open(&manifest);
            }
            return Ok(Self::new(path));
        }
        if !path.exists() {
            return Err(SessionError::Missing {
                path: path.to_path_buf(),
            });
        }
        let text = crate::io::read_json_text(path).map_err(|e| match e {
            crate::io::ReadError::Io { path, source } => SessionError::Read { path, source },
            too_large => SessionError::Parse {
                path: path.to_path_buf(),
                reason: too_large.to_string(),
            },
        })?;
        Self::from_json(path, &text)
    }

    /// A session (or a manifest, which becomes a session) from the text of the file at
    /// `path`, whose folder is the session's.
    ///
    /// # Errors
    /// The text is neither a session nor a manifest, a newer version, or lists more
    /// than [`crate::limits::MAX_SESSION_SHOTS`] shots.
    pub fn from_json(path: &Path, text: &str) -> Result<Self, SessionError> {
        let folder = crate::io::parent_dir(path).to_path_buf();
        let parse = |reason: String| SessionError::Parse {
            path: path.to_path_buf(),
            reason,
        };
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| parse(e.to_string()))?;
        let schema = value.get("schema").and_then(|s| s.as_str());
        let is_session = schema.is_some_and(|s| s.starts_with("lensblur.session/"));
        let count = value
            .get("shots")
            .and_then(|v| v.as_array())
            .map_or(0, Vec::len);
        if count > crate::limits::MAX_SESSION_SHOTS {
            return Err(parse(format!(
                "{count} shots, above the limit of {}",
                crate::limits::MAX_SESSION_SHOTS
            )));
        }
        if !is_session {
            let m = Manifest::from_json(path, text).map_err(|e| match e {
                crate::manifest::ManifestError::Parse { reason, .. } => parse(reason),
                other => parse(other.to_string()),
            })?;
            let mut s = Self::new(&folder);
            s.chart = m.chart_spec(&folder).map_err(|e| parse(e.to_string()))?;
            for ms in m.shots {
                let id = s.new_shot_id();
                s.shots.push(Shot {
                    id,
                    path: ms.path,
                    focal_mm: ms.focal_mm,
                    f_number: ms.f_number,
                    ..Shot::blank()
                });
            }
            return Ok(s);
        }
        let version = SESSION
            .version_of(schema)
            .map_err(|e| parse(e.to_string()))?;
        let mut s: Session = serde_json::from_value(value).map_err(|e| parse(e.to_string()))?;
        s.chart.validate().map_err(|e| parse(e.to_string()))?;
        // Ids count up from 1 by one per shot ever added; past 2⁴⁸ a file was edited
        // into nonsense, and counting on from it could overflow.
        const MAX_ID: u64 = 1 << 48;
        if s.next_shot_id > MAX_ID || s.shots.iter().any(|x| x.id.0 > MAX_ID) {
            return Err(parse(format!("shot ids above {MAX_ID}")));
        }
        if version == 1 {
            // Version 1 kept results by list position: the ids are new, and results are
            // found again by content in the cache.
            for shot in &mut s.shots {
                shot.id = ShotId(0);
                shot.detect = StageStatus::Pending;
                shot.kernels = StageStatus::Pending;
            }
        }
        s.schema = SESSION.tag();
        s.folder = folder;
        s.number_shots();
        Ok(s)
    }

    /// Writes `session.json` atomically (temporary file, then rename).
    ///
    /// # Errors
    /// The folder cannot be created or the file written.
    pub fn save(&self) -> Result<(), SessionError> {
        std::fs::create_dir_all(&self.folder).map_err(|source| SessionError::Write {
            path: self.folder.clone(),
            source,
        })?;
        let text = serde_json::to_vec_pretty(self).map_err(|e| SessionError::Write {
            path: self.folder.join(SESSION_FILE),
            source: std::io::Error::other(e),
        })?;
        write_atomic(&self.folder.join(SESSION_FILE), &text)
    }

    /// Adds a shot file (its settings unknown until read from EXIF or typed).
    ///
    /// # Errors
    /// The file is missing, of an unsupported type, or already in the session.
    pub fn add_shot(&mut self, path: &Path) -> Result<ShotId, SessionError> {
        if !path.is_file() {
            return Err(SessionError::Missing {
                path: path.to_path_buf(),
            });
        }
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if !SHOT_EXTENSIONS.contains(&ext.as_str()) {
            return Err(SessionError::Unsupported {
                path: path.to_path_buf(),
            });
        }
        let abs = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
        if (0..self.shots.len()).any(|i| {
            std::fs::canonicalize(self.shot_path(i)).ok().as_deref() == Some(abs.as_path())
        }) {
            return Err(SessionError::Duplicate {
                path: path.to_path_buf(),
            });
        }
        let folder = std::fs::canonicalize(&self.folder).unwrap_or_else(|_| self.folder.clone());
        let stored = abs
            .strip_prefix(&folder)
            .map_or_else(|_| abs.clone(), Path::to_path_buf);
        let id = self.new_shot_id();
        self.shots.push(Shot {
            id,
            path: stored,
            ..Shot::blank()
        });
        Ok(id)
    }

    /// Gives every shot without an id (version 1, or a hand-edited file) a fresh one,
    /// and makes sure later ids stay unused.
    fn number_shots(&mut self) {
        let top = self.shots.iter().map(|s| s.id.0).max().unwrap_or(0);
        self.next_shot_id = self.next_shot_id.max(top.saturating_add(1));
        let mut seen = std::collections::BTreeSet::new();
        for i in 0..self.shots.len() {
            let id = self.shots[i].id;
            if id.0 == 0 || !seen.insert(id) {
                self.shots[i].id = self.new_shot_id();
                seen.insert(self.shots[i].id);
            }
        }
    }

    fn new_shot_id(&mut self) -> ShotId {
        let id = ShotId(self.next_shot_id.max(1));
        self.next_shot_id = id.0.saturating_add(1);
        id
    }

    /// Where a shot is in the list now.
    #[must_use]
    pub fn index_of(&self, id: ShotId) -> Option<usize> {
        self.shots.iter().position(|s| s.id == id)
    }

    #[must_use]
    pub fn shot(&self, id: ShotId) -> Option<&Shot> {
        self.shots.iter().find(|s| s.id == id)
    }

    pub fn shot_mut(&mut self, id: ShotId) -> Option<&mut Shot> {
        self.shots.iter_mut().find(|s| s.id == id)
    }

    /// Removes a shot from the session (its file and cached results stay on disk).
    pub fn remove_shot(&mut self, id: ShotId) -> Option<Shot> {
        let i = self.index_of(id)?;
        Some(self.shots.remove(i))
    }

    /// The file of a shot: absolute, or relative to the working directory.
    #[must_use]
    pub fn path_of(&self, shot: &Shot) -> PathBuf {
        crate::manifest::resolve(&self.folder, &shot.path)
    }

    /// What decides the session's stage results: its chart and stage settings.
    #[must_use]
    pub fn measurement(&self) -> crate::pipeline::Measurement {
        crate::pipeline::Measurement::new(self.chart.clone(), self.settings.kernel_params())
    }

    /// The cache of stage results in the session folder.
    #[must_use]
    pub fn cache(&self) -> crate::pipeline::ResultCache {
        crate::pipeline::ResultCache::in_folder(&self.folder)
    }

    /// Takes the session folder's lock for `who` (see [`crate::lock`]) and, holding
    /// it, removes what writers killed mid-write left behind (temporary files, never a
    /// result). Returns the lock and how many such files went.
    ///
    /// # Errors
    /// Another studio or command holds the folder, or it cannot be locked.
    pub fn lock(
        &self,
        who: &str,
    ) -> Result<(crate::lock::FolderLock, usize), crate::lock::LockError> {
        let lock = crate::lock::FolderLock::acquire(&self.folder, who)?;
        let swept = crate::io::remove_stale_temporaries(&self.folder)
            + crate::io::remove_stale_temporaries(&self.cache().dir);
        Ok((lock, swept))
    }

    /// What the session folder holds for each shot, read from the result cache, and
    /// what had to be dropped on the way, each with its reason: a shot file that is
    /// gone or unreadable (renamed by hand?), a cached result that cannot be read (it is
    /// measured again), a result the session recorded that is no longer there.
    ///
    /// # Errors
    /// Only cancellation: everything else is a dropped entry.
    pub fn survey(&self, job: &crate::job::JobContext) -> Result<Survey, crate::job::Cancelled> {
        use crate::pipeline::ShotFile;
        let (m, cache) = (self.measurement(), self.cache());
        let mut survey = Survey::default();
        let total = self.shots.len();
        for (k, shot) in self.shots.iter().enumerate() {
            job.check()?;
            job.report("reading results", k, total);
            let path = self.path_of(shot);
            let name = shot.name();
            let file = match ShotFile::read(&path) {
                Ok(f) => f,
                Err(e) => {
                    let why = if path.exists() {
                        e.to_string()
                    } else {
                        format!("{}: not found (renamed or removed?)", path.display())
                    };
                    survey
                        .dropped
                        .push(format!("{why}: its results are left out until it is back"));
                    continue;
                }
            };
            match cache.detection(&file, &m) {
                Ok(Some(d)) => {
                    survey.detections.insert(shot.id, d);
                }
                Ok(None) if shot.detect.is_done() => survey.dropped.push(format!(
                    "{name}: its recorded detection is gone from the results: pending again"
                )),
                Ok(None) => {}
                Err(e) => survey
                    .dropped
                    .push(format!("{e}: left out, detected again when needed")),
            }
            match cache.kernels(&file, &m) {
                Ok(Some(k)) => {
                    survey.kernels.insert(shot.id, k);
                }
                Ok(None) if shot.kernels.is_done() => survey.dropped.push(format!(
                    "{name}: its recorded kernels are gone from the results: pending again"
                )),
                Ok(None) => {}
                Err(e) => survey
                    .dropped
                    .push(format!("{e}: left out, measured again when needed")),
            }
        }
        job.report("reading results", total, total);
        Ok(survey)
    }

    /// Each shot's stage status as a [`Survey`] found it: done where a result exists,
    /// pending where a recorded result has gone, a recorded failure kept.
    pub fn settle(&mut self, survey: &Survey) {
        fn settle(status: &StageStatus, found: Option<String>) -> StageStatus {
            match (found, status) {
                (Some(summary), _) => StageStatus::Done { summary },
                (None, StageStatus::Failed { reason }) => StageStatus::Failed {
                    reason: reason.clone(),
                },
                (None, _) => StageStatus::Pending,
            }
        }
        for shot in &mut self.shots {
            shot.detect = settle(
                &shot.detect,
                survey.detections.get(&shot.id).map(detect_summary),
            );
            shot.kernels = settle(
                &shot.kernels,
                survey.kernels.get(&shot.id).map(kernels_summary),
            );
        }
    }

    /// The absolute (or working-directory-relative) path of shot `index`.
    #[must_use]
    pub fn shot_path(&self, index: usize) -> PathBuf {
        self.path_of(&self.shots[index])
    }

    /// The session's manifest, written into the session folder: shot paths as the
    /// session keeps them (relative to the folder where they lie inside it), so the
    /// command line names each shot as the studio does.
    #[must_use]
    pub fn manifest(&self) -> Manifest {
        Manifest::new(
            Some(ChartRef::Spec(self.chart.clone())),
            self.shots
                .iter()
                .map(|s| ManifestShot {
                    path: s.path.clone(),
                    focal_mm: s.focal_mm,
                    f_number: s.f_number,
                })
                .collect(),
        )
    }

    /// Writes the manifest beside `session.json` and returns its path.
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn write_manifest(&self) -> Result<PathBuf, SessionError> {
        let path = self.folder.join(MANIFEST_FILE);
        crate::io::create_dir_all(&self.folder).map_err(write_err)?;
        crate::io::write_json(&path, &self.manifest()).map_err(write_err)?;
        Ok(path)
    }

    /// Distinct focal lengths and apertures of the shots with known settings, sorted.
    #[must_use]
    pub fn setting_grid(&self) -> (Vec<f64>, Vec<f64>) {
        let mut f: Vec<f64> = self.shots.iter().filter_map(|s| s.focal_mm).collect();
        let mut a: Vec<f64> = self.shots.iter().filter_map(|s| s.f_number).collect();
        for v in [&mut f, &mut a] {
            v.sort_by(f64::total_cmp);
            v.dedup_by(|x, y| LensSetting::same_value(*x, *y));
        }
        (f, a)
    }
}

impl Shot {
    fn blank() -> Self {
        Shot {
            id: ShotId(0),
            path: PathBuf::new(),
            focal_mm: None,
            f_number: None,
            detect: StageStatus::Pending,
            kernels: StageStatus::Pending,
        }
    }
}

/// Where the demo session is cached: `$XDG_DATA_HOME/lensblur/demo`, else
/// `~/.local/share/lensblur/demo`, else a folder under the temporary directory.
#[must_use]
pub fn default_demo_dir() -> PathBuf {
    let base = std::env::var_os("XDG_DATA_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local").join("share")))
        .unwrap_or_else(std::env::temp_dir);
    base.join("lensblur").join("demo")
}

/// Where the studio keeps its list of recently opened sessions: beside the demo.
#[must_use]
pub fn default_recent_file() -> PathBuf {
    let demo = default_demo_dir();
    crate::io::parent_dir(&demo).join("recent.json")
}

/// How many recent sessions are remembered.
pub const RECENT_MAX: usize = 10;

/// The recently opened session folders listed in `file`, most recent first, those no
/// longer there dropped. A missing or unreadable list is an empty one: forgetting it
/// costs the user nothing but a menu entry.
#[must_use]
pub fn read_recent(file: &Path) -> Vec<PathBuf> {
    let Ok(text) = std::fs::read_to_string(file) else {
        return Vec::new();
    };
    let list: Vec<PathBuf> = serde_json::from_str(&text).unwrap_or_default();
    list.into_iter()
        .filter(|p| p.exists())
        .take(RECENT_MAX)
        .collect()
}

/// Puts `folder` first in the recent list in `file` and writes it; returns the list.
///
/// # Errors
/// The list cannot be written.
pub fn remember_recent(file: &Path, folder: &Path) -> Result<Vec<PathBuf>, SessionError> {
    let folder = std::fs::canonicalize(folder).unwrap_or_else(|_| folder.to_path_buf());
    let mut list = read_recent(file);
    list.retain(|p| p != &folder);
    list.insert(0, folder);
    list.truncate(RECENT_MAX);
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir).map_err(|source| SessionError::Write {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    let text = serde_json::to_vec_pretty(&list).map_err(|e| SessionError::Write {
        path: file.to_path_buf(),
        source: std::io::Error::other(e),
    })?;
    write_atomic(file, &text)?;
    Ok(list)
}

/// The size and settings of a demo session.
#[derive(Clone, Debug, PartialEq)]
pub struct DemoSpec {
    pub width: usize,
    pub height: usize,
    pub settings: Vec<LensSetting>,
    pub seed: u64,
    /// The chart printed in the demo's shots.
    pub chart: ChartSpec,
}

impl DemoSpec {
    /// What the studio makes on first launch: modest shots of a 16 × 10 chart at a
    /// 3 × 3 grid of settings (enough for a β = 2 model), small enough that every stage
    /// runs in minutes on a laptop.
    #[must_use]
    pub fn studio() -> Self {
        Self::grid(960, 640, &[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0]).with_chart(16, 10)
    }

    /// A small demo for tests: 600 × 400 shots at a 2 × 2 grid of settings.
    #[must_use]
    pub fn small() -> Self {
        Self::grid(600, 400, &[24.0, 105.0], &[4.0, 10.0])
    }

    #[must_use]
    pub fn grid(width: usize, height: usize, focal_mm: &[f64], f_number: &[f64]) -> Self {
        let settings = focal_mm
            .iter()
            .flat_map(|&f| {
                f_number.iter().map(move |&a| LensSetting {
                    focal_mm: f,
                    f_number: a,
                })
            })
            .collect();
        // Fewer squares on small shots so each square still spans enough pixels to
        // measure a kernel.
        let mut chart = ChartSpec::default();
        if width < 1000 {
            chart.cols = 12;
            chart.rows = 8;
        }
        Self {
            width,
            height,
            settings,
            seed: 7,
            chart,
        }
    }

    /// The same demo with a chart of `cols` × `rows` squares.
    #[must_use]
    pub fn with_chart(mut self, cols: usize, rows: usize) -> Self {
        self.chart.cols = cols;
        self.chart.rows = rows;
        self
    }

    /// The chart printed in the demo's shots.
    #[must_use]
    pub fn chart(&self) -> ChartSpec {
        self.chart.clone()
    }

    /// Everything that decides the demo's files, and the version of the code that
    /// simulates them: a cached demo with another key is stale.
    #[must_use]
    pub fn key(&self) -> String {
        let settings: Vec<String> = self
            .settings
            .iter()
            .map(|s| format!("{}@{}", s.focal_mm, s.f_number))
            .collect();
        format!(
            "lensblur {} demo {}x{} chart {}x{} seed {} settings {}",
            env!("CARGO_PKG_VERSION"),
            self.width,
            self.height,
            self.chart.cols,
            self.chart.rows,
            self.seed,
            settings.join(",")
        )
    }

    /// File name of the demo shot for a setting.
    #[must_use]
    pub fn shot_name(s: LensSetting) -> String {
        format!("demo_f{:03.0}_a{:04.1}.png", s.focal_mm, s.f_number)
    }
}

/// Makes (or remakes) the demo session in `dir`: simulated calibration shots of the
/// virtual lens at `spec`'s settings, their manifest and ground truth.
///
/// # Errors
/// The simulator failed, the folder cannot be written, or the job was cancelled.
pub fn make_demo(
    dir: &Path,
    spec: &DemoSpec,
    job: &crate::job::JobContext,
) -> Result<Session, SessionError> {
    make_demo_streaming(dir, spec, job, &mut |_| {})
}

/// [`make_demo`], handing the session to `on_shot` each time a shot is on disk, so a
/// window can show the first shot within seconds rather than after the whole demo.
/// The session passed is not saved yet; the one returned is, with the demo's photo.
///
/// # Errors
/// As [`make_demo`].
pub fn make_demo_streaming(
    dir: &Path,
    spec: &DemoSpec,
    job: &crate::job::JobContext,
    on_shot: &mut dyn FnMut(&Session),
) -> Result<Session, SessionError> {
    use crate::simulate::{CaptureParams, Pose, VirtualLens, simulate_shot};
    let chart = spec.chart();
    let lens = VirtualLens::demo();
    std::fs::create_dir_all(dir).map_err(|source| SessionError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    // Shots left by an interrupted first launch are reused (see below), but only when
    // they were made for this very spec by this version.
    let key = spec.key();
    let key_path = dir.join(DEMO_KEY_FILE);
    if std::fs::read_to_string(&key_path).ok().as_deref() != Some(key.as_str()) {
        clear_demo_files(dir)?;
        write_atomic(&key_path, key.as_bytes())?;
    }
    let mut session = Session::new(dir);
    session.name = "demo".into();
    session.chart = chart.clone();
    session.is_demo = true;
    session.demo_key = Some(key);
    let total = spec.settings.len();
    job.report("simulating demo shots", 0, total);
    for (k, &setting) in spec.settings.iter().enumerate() {
        let name = DemoSpec::shot_name(setting);
        let path = dir.join(&name);
        let truth_path = dir.join(format!("{name}.truth.json"));
        // A session folder that already holds a shot is reused: only missing shots
        // are simulated, so an interrupted first launch resumes where it stopped.
        if !(path.is_file() && truth_path.is_file()) {
            let mut params = CaptureParams::new(spec.width, spec.height, setting);
            // Each shot a slightly different pose, as a hand-held series would be.
            let t = k as f64;
            params.pose = Pose {
                rotation_deg: 1.5 * (0.9 * t + 0.3).sin(),
                tilt_x: 0.02 * (1.3 * t).cos(),
                tilt_y: 0.015 * (0.7 * t + 1.0).sin(),
                // The board spans 86 % of the frame's width, or of its height when
                // the chart is taller than the frame's aspect.
                fill: 0.86_f64.min(
                    0.86 * (spec.height as f64 / spec.width as f64)
                        * (chart.cols as f64 / chart.rows as f64),
                ),
                shift_px: [4.0 * (t * 0.5).sin(), 3.0 * (t * 0.8).cos()],
            };
            params.bayer = false;
            params.seed = spec.seed.wrapping_add(k as u64);
            let shot = simulate_shot(
                &chart,
                &lens,
                &params,
                &job.prefixed(&format!("shot {} of {total}: ", k + 1)),
            )
            .map_err(|e| SessionError::Parse {
                path: path.clone(),
                reason: e.to_string(),
            })?;
            write_rgb16_png(&path, &shot.capture)?;
            let truth = serde_json::to_vec(&crate::format::Versioned::new(
                &crate::format::TRUTH,
                &shot.truth,
            ))
            .map_err(|e| SessionError::Write {
                path: truth_path.clone(),
                source: std::io::Error::other(e),
            })?;
            write_atomic(&truth_path, &truth)?;
        }
        let id = session.new_shot_id();
        session.shots.push(Shot {
            id,
            path: PathBuf::from(&name),
            focal_mm: Some(setting.focal_mm),
            f_number: Some(setting.f_number),
            ..Shot::blank()
        });
        job.report("simulating demo shots", k + 1, total);
        on_shot(&session);
    }
    session.demo_photo = Some(make_demo_photo(dir, spec, &lens, job)?);
    session.write_manifest()?;
    session.save()?;
    Ok(session)
}

/// The demo photo's file name.
pub const DEMO_PHOTO_FILE: &str = "demo_photo.png";

/// The public-domain photo the demo blurs (assets/README.md says where it comes from).
const DEMO_PHOTO_SOURCE: &[u8] = include_bytes!("../assets/astronaut.png");

/// The demo's photo: a natural image seen through the virtual lens at the demo's middle
/// setting (one it measures, so both the profile's and the measured kernels apply),
/// on the shots' sensor, with the lens's true, spatially varying kernels. Kept when it
/// is already there (the folder's key says it was made by this spec).
fn make_demo_photo(
    dir: &Path,
    spec: &DemoSpec,
    lens: &crate::simulate::VirtualLens,
    job: &crate::job::JobContext,
) -> Result<DemoPhoto, SessionError> {
    use crate::plane::{Capture, Channel, ChannelPlane, Plane};
    let path = dir.join(DEMO_PHOTO_FILE);
    let setting = spec
        .settings
        .get(spec.settings.len() / 2)
        .copied()
        .unwrap_or(LensSetting {
            focal_mm: 50.0,
            f_number: 5.6,
        });
    let photo = DemoPhoto {
        path: PathBuf::from(DEMO_PHOTO_FILE),
        focal_mm: setting.focal_mm,
        f_number: setting.f_number,
    };
    if path.is_file() {
        return Ok(photo);
    }
    job.report("blurring the demo photo", 0, 1);
    let (w, h) = (spec.width, spec.height);
    let parse = |reason: String| SessionError::Parse {
        path: path.clone(),
        reason,
    };
    let true_kernel = |channel: Channel, x: f64, y: f64| {
        let (u, v) = crate::simulate::VirtualLens::normalised(x, y, w, h);
        crate::deblur::plane_kernel(
            &lens
                .optical_kernel_uv(channel, u, v, setting, 3)
                .pixel_integrated(),
            1,
        )
    };
    // The widest kernel is in a corner; the sharp image extends past the frame by that
    // much so the frame's edges are blurred from real content, not from a border.
    let pad = [Channel::R, Channel::G, Channel::B]
        .iter()
        .flat_map(|&c| {
            [
                (0.0, 0.0),
                ((w - 1) as f64, 0.0),
                (0.0, (h - 1) as f64),
                ((w - 1) as f64, (h - 1) as f64),
            ]
            .map(|(x, y)| true_kernel(c, x, y).size / 2)
        })
        .max()
        .unwrap_or(0)
        + 2;
    let (pw, ph) = (w + 2 * pad, h + 2 * pad);
    let source = image::load_from_memory(DEMO_PHOTO_SOURCE)
        .map_err(|e| parse(format!("the built-in photo: {e}")))?
        .into_rgb8();
    // Cover the padded frame (scale to fill, centre crop), as a print fills a frame.
    let scale = (pw as f64 / f64::from(source.width())).max(ph as f64 / f64::from(source.height()));
    let (sw, sh) = (
        ((f64::from(source.width()) * scale).ceil() as u32).max(pw as u32),
        ((f64::from(source.height()) * scale).ceil() as u32).max(ph as u32),
    );
    let scaled = image::imageops::resize(&source, sw, sh, image::imageops::FilterType::Lanczos3);
    let (x0, y0) = ((sw as usize - pw) / 2, (sh as usize - ph) / 2);
    // The shots are linear; the photo is sRGB-encoded: blur what the sensor sees.
    let linear = |v: u8| {
        let c = f32::from(v) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let mut planes = Vec::with_capacity(3);
    for (i, channel) in [Channel::R, Channel::G, Channel::B].into_iter().enumerate() {
        job.check().map_err(|e| parse(e.to_string()))?;
        let mut sharp = Plane::new(pw, ph);
        for y in 0..ph {
            for x in 0..pw {
                sharp.data[y * pw + x] =
                    linear(scaled.get_pixel((x0 + x) as u32, (y0 + y) as u32)[i]);
            }
        }
        let blurred = crate::experiment::blur_varying(&sharp, pad, w, h, 16, &|x, y| {
            true_kernel(channel, x, y)
        });
        planes.push(ChannelPlane {
            channel,
            plane: blurred,
            step: 1,
            offset_x: 0,
            offset_y: 0,
        });
    }
    let capture = Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: None,
        setting_f_number: None,
        identity: crate::plane::CameraIdentity::default(),
        is_raw: false,
        raw: None,
    };
    write_rgb16_png(&path, &capture)?;
    job.report("blurring the demo photo", 1, 1);
    Ok(photo)
}

/// Which spec the demo files in a folder were made for.
const DEMO_KEY_FILE: &str = "demo.key";

/// Removes what a demo folder holds (and only that): its shots and their truth, the
/// session, manifest, profile, cross-validation and results.
fn clear_demo_files(dir: &Path) -> Result<(), SessionError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(source) => {
            return Err(SessionError::Read {
                path: dir.to_path_buf(),
                source,
            });
        }
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let ours = (name.starts_with("demo_")
            && (name.ends_with(".png") || name.ends_with(".truth.json")))
            || [
                SESSION_FILE,
                MANIFEST_FILE,
                "profile.json",
                "crossval.json",
                DEMO_KEY_FILE,
            ]
            .contains(&name.as_str());
        let path = entry.path();
        let removed = if ours {
            std::fs::remove_file(&path)
        } else if name == "results" && path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            Ok(())
        };
        removed.map_err(|source| SessionError::Write {
            path: path.clone(),
            source,
        })?;
    }
    Ok(())
}

/// A linear 16-bit RGB PNG of a capture's R, G, B planes (black 0, white 65535), as the
/// simulator writes its PNG shots.
fn write_rgb16_png(path: &Path, capture: &crate::plane::Capture) -> Result<(), SessionError> {
    let bytes = crate::simulate::files::rgb16_bytes(capture, crate::simulate::ShotFormat::Png)
        .map_err(|reason| SessionError::Parse {
            path: path.to_path_buf(),
            reason,
        })?;
    write_atomic(path, &bytes)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SessionError> {
    crate::io::write_atomic(path, bytes).map_err(write_err)
}

fn write_err(e: crate::io::WriteError) -> SessionError {
    SessionError::Write {
        path: e.path,
        source: e.source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn save_open_round_trip_and_manifest() {
        let dir = tempfile::tempdir().unwrap();
        let shot = dir.path().join("a.png");
        std::fs::write(&shot, b"x").unwrap();
        let mut s = Session::new(dir.path());
        assert_eq!(s.add_shot(&shot).unwrap(), ShotId(1));
        assert!(matches!(
            s.add_shot(&shot),
            Err(SessionError::Duplicate { .. })
        ));
        let txt = dir.path().join("notes.txt");
        std::fs::write(&txt, b"x").unwrap();
        assert!(matches!(
            s.add_shot(&txt),
            Err(SessionError::Unsupported { .. })
        ));
        assert_eq!(s.shots[0].path, PathBuf::from("a.png"));
        s.shots[0].focal_mm = Some(35.0);
        s.shots[0].detect = StageStatus::Done {
            summary: "96 squares".into(),
        };
        s.save().unwrap();
        let back = Session::open(dir.path()).unwrap();
        assert_eq!(back, s);
        let m = s.write_manifest().unwrap();
        std::fs::remove_file(dir.path().join(SESSION_FILE)).unwrap();
        let from_manifest = Session::open(&m).unwrap();
        assert_eq!(from_manifest.shots.len(), 1);
        assert_eq!(from_manifest.shots[0].focal_mm, Some(35.0));
        assert_eq!(from_manifest.shots[0].f_number, None);
    }

    #[test]
    fn a_stale_demo_is_made_again() {
        let dir = tempfile::tempdir().unwrap();
        let job = crate::job::JobContext::silent();
        let spec = DemoSpec::grid(160, 112, &[24.0], &[4.0]).with_chart(4, 3);
        let s = make_demo(dir.path(), &spec, &job).unwrap();
        assert_eq!(s.demo_key.as_deref(), Some(spec.key().as_str()));
        let shot = s.shot_path(0);
        let made = std::fs::metadata(&shot).unwrap().modified().unwrap();
        // Same spec: the shot is reused.
        make_demo(dir.path(), &spec, &job).unwrap();
        assert_eq!(std::fs::metadata(&shot).unwrap().modified().unwrap(), made);
        // Another spec (same file names): everything is made again, and a file that
        // is not the demo's stays.
        std::fs::write(dir.path().join("mine.txt"), b"keep").unwrap();
        std::fs::create_dir_all(dir.path().join("results")).unwrap();
        let other = DemoSpec::grid(200, 140, &[24.0], &[4.0]).with_chart(4, 3);
        let s2 = make_demo(dir.path(), &other, &job).unwrap();
        let cap = crate::raw::load_capture(&s2.shot_path(0), &Default::default()).unwrap();
        assert_eq!((cap.width, cap.height), (200, 140));
        assert!(!dir.path().join("results").exists());
        assert!(dir.path().join("mine.txt").is_file());
        let reopened = Session::open(dir.path()).unwrap();
        assert_eq!(reopened.demo_key.as_deref(), Some(other.key().as_str()));
    }

    #[test]
    fn bad_files_are_one_line_errors() {
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("session.json");
        std::fs::write(&bad, b"{ not json").unwrap();
        let e = Session::open(&bad).unwrap_err().to_string();
        assert!(e.contains("session.json") && !e.contains('\n'), "{e}");
        let e = Session::open(&dir.path().join("nope.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("no such file"), "{e}");
    }

    #[test]
    fn shot_ids_stay_with_their_shots_and_are_never_reused() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Session::new(dir.path());
        let ids: Vec<ShotId> = ["a.png", "b.png", "c.png"]
            .iter()
            .map(|n| {
                let p = dir.path().join(n);
                std::fs::write(&p, n.as_bytes()).unwrap();
                s.add_shot(&p).unwrap()
            })
            .collect();
        s.remove_shot(ids[1]).unwrap();
        assert_eq!(s.index_of(ids[2]), Some(1));
        let p = dir.path().join("d.png");
        std::fs::write(&p, b"d").unwrap();
        let d = s.add_shot(&p).unwrap();
        assert!(!ids.contains(&d), "a removed shot's id is not given again");
        s.save().unwrap();
        let back = Session::open(dir.path()).unwrap();
        assert_eq!(back.shot(ids[2]).map(|x| x.stem()), Some("c".into()));
        assert_eq!(back.shot(d).map(|x| x.stem()), Some("d".into()));
    }

    #[test]
    fn a_version_1_session_is_numbered_and_a_newer_one_refused() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join(SESSION_FILE);
        let v1 = serde_json::json!({
            "schema": "lensblur.session/1",
            "name": "old",
            "chart": ChartSpec::default(),
            "shots": [
                {"path": "a.png", "focal_mm": 24.0, "detect": {"state": "done", "summary": "x"}},
                {"path": "b.png"}
            ]
        });
        std::fs::write(&file, serde_json::to_vec(&v1).unwrap()).unwrap();
        let s = Session::open(dir.path()).unwrap();
        assert_eq!(s.schema, SESSION.tag());
        let ids: Vec<ShotId> = s.shots.iter().map(|x| x.id).collect();
        assert_eq!(ids, vec![ShotId(1), ShotId(2)]);
        assert_eq!(s.shots[0].focal_mm, Some(24.0));
        // Version 1 results were kept by position: they are found again by content.
        assert_eq!(s.shots[0].detect, StageStatus::Pending);
        let mut newer = v1;
        newer["schema"] = "lensblur.session/9".into();
        std::fs::write(&file, serde_json::to_vec(&newer).unwrap()).unwrap();
        let e = Session::open(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("version 9") && e.contains("up to version 2"),
            "{e}"
        );
    }
}
