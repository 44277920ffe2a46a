//! The session manifest (docs/formats.md): the chart that was printed and the shots with
//! their settings. Scripts write it by hand, the simulator writes it for its shots, and
//! every command that works on a session reads it.

use crate::chart::ChartSpec;
use crate::plane::LensSetting;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The manifest's name inside a session folder.
pub const MANIFEST_FILE: &str = "manifest.json";

/// The chart of a manifest: the spec inline, or a path to a spec file relative to the
/// manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ChartRef {
    Spec(ChartSpec),
    Path(PathBuf),
}

/// One shot: its file (relative to the manifest) and, where EXIF lacks them, its
/// settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ManifestShot {
    pub path: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_number: Option<f64>,
}

impl ManifestShot {
    /// Both settings, when the manifest gives both.
    #[must_use]
    pub fn setting(&self) -> Option<LensSetting> {
        Some(LensSetting {
            focal_mm: self.focal_mm?,
            f_number: self.f_number?,
        })
    }
}

/// The manifest's version. Manifests written by hand or before the field existed have
/// no schema and are version 1.
pub const MANIFEST_SCHEMA: crate::format::Schema = crate::format::Schema {
    kind: "manifest",
    current: 1,
    unversioned: Some(1),
};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub schema: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chart: Option<ChartRef>,
    pub shots: Vec<ManifestShot>,
}

#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    #[error("{reason}")]
    Read { path: PathBuf, reason: String },
    #[error("{}: not a session manifest: {reason}", path.display())]
    Parse { path: PathBuf, reason: String },
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl Manifest {
    /// Reads a manifest; the chart reference is resolved by [`Manifest::chart_spec`].
    ///
    /// # Errors
    /// Unreadable file, malformed JSON, or no shots.
    pub fn load(path: &Path) -> Result<Self, ManifestError> {
        let text = crate::io::read_json_text(path).map_err(|e| ManifestError::Read {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        Self::from_json(path, &text)
    }

    /// A manifest of this version.
    #[must_use]
    pub fn new(chart: Option<ChartRef>, shots: Vec<ManifestShot>) -> Self {
        Self {
            schema: Some(MANIFEST_SCHEMA.tag()),
            chart,
            shots,
        }
    }

    /// Parses and checks a manifest's text; `path` names it in errors.
    ///
    /// # Errors
    /// Malformed JSON, a newer version, no shots or more than
    /// [`crate::limits::MAX_SESSION_SHOTS`].
    pub fn from_json(path: &Path, text: &str) -> Result<Self, ManifestError> {
        let parse = |reason: String| ManifestError::Parse {
            path: path.to_path_buf(),
            reason,
        };
        MANIFEST_SCHEMA
            .version_of_json(text)
            .map_err(|e| parse(e.to_string()))?;
        let m: Manifest = serde_json::from_str(text).map_err(|e| parse(e.to_string()))?;
        if m.shots.is_empty() {
            return Err(parse("it lists no shots".into()));
        }
        if m.shots.len() > crate::limits::MAX_SESSION_SHOTS {
            return Err(parse(format!(
                "{} shots, above the limit of {}",
                m.shots.len(),
                crate::limits::MAX_SESSION_SHOTS
            )));
        }
        Ok(m)
    }

    /// The chart: inline, from the referenced file (relative to `base`, the manifest's
    /// folder), or the default one.
    ///
    /// # Errors
    /// The referenced chart file cannot be read or is not a valid spec.
    pub fn chart_spec(&self, base: &Path) -> Result<ChartSpec, crate::chart::ChartError> {
        match &self.chart {
            None => Ok(ChartSpec::default()),
            Some(ChartRef::Spec(c)) => {
                c.validate()?;
                Ok(c.clone())
            }
            Some(ChartRef::Path(p)) => ChartSpec::load(&resolve(base, p)),
        }
    }

    /// Writes the manifest as pretty JSON, atomically.
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn save(&self, path: &Path) -> Result<(), ManifestError> {
        crate::io::write_json(path, self).map_err(|e| ManifestError::Write {
            path: e.path,
            source: e.source,
        })
    }
}

/// A path as the manifest means it: relative paths are relative to the manifest's
/// folder.
#[must_use]
pub fn resolve(base: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}
