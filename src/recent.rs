//! The list of recently opened sessions (the studio's File ▸ Recent sessions), and
//! where the studio keeps its own files.

use crate::session::SessionError;
use std::path::{Path, PathBuf};

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

/// The profile library the studio saves into and the batch reads (`lensblur deblur
/// PHOTOS --out-dir OUT --profiles ~/lensblur/profiles`): a folder of the user's own,
/// beside the session folders the guide suggests (`~/lensblur/<lens>`); under the
/// temporary directory where there is no home.
#[must_use]
pub fn default_profile_library() -> PathBuf {
    std::env::var_os("HOME")
        .filter(|v| !v.is_empty())
        .map_or_else(std::env::temp_dir, PathBuf::from)
        .join("lensblur")
        .join("profiles")
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
    crate::io::write_atomic(file, &text).map_err(SessionError::from)?;
    Ok(list)
}
