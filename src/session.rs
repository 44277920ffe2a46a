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

    /// Opens a session folder, a `session.json`, or a manifest (docs/formats.md), which
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

    pub(crate) fn new_shot_id(&mut self) -> ShotId {
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
        crate::io::create_dir_all(&self.folder).map_err(SessionError::from)?;
        crate::io::write_json(&path, &self.manifest()).map_err(SessionError::from)?;
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
    pub(crate) fn blank() -> Self {
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

impl From<crate::io::WriteError> for SessionError {
    fn from(e: crate::io::WriteError) -> Self {
        SessionError::Write {
            path: e.path,
            source: e.source,
        }
    }
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SessionError> {
    crate::io::write_atomic(path, bytes).map_err(SessionError::from)
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
