//! The list of recently opened sessions (the studio's File ▸ Recent sessions), where
//! the studio keeps its own files, and the profile library it and the batch share.

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

/// Where the studio remembers its settings (the profile library chosen): beside the
/// demo. The command line's batch reads the same file, so both name one library.
#[must_use]
pub fn default_settings_file() -> PathBuf {
    let demo = default_demo_dir();
    crate::io::parent_dir(&demo).join("settings.json")
}

/// What the studio remembers between launches.
#[derive(serde::Serialize, serde::Deserialize, Default)]
struct Settings {
    /// The profile library chosen in the studio; `None`: [`default_profile_library`].
    #[serde(default)]
    profile_library: Option<PathBuf>,
}

/// The profile library: the folder chosen in the studio (remembered in `settings`),
/// else [`default_profile_library`]. A missing or unreadable settings file is the
/// default: forgetting the choice costs the user one click.
#[must_use]
pub fn profile_library(settings: &Path) -> PathBuf {
    std::fs::read_to_string(settings)
        .ok()
        .and_then(|t| serde_json::from_str::<Settings>(&t).ok())
        .and_then(|s| s.profile_library)
        .unwrap_or_else(default_profile_library)
}

/// Remembers `folder` as the profile library in `settings`, for the studio's next
/// launch and the command line's batch.
///
/// # Errors
/// The settings file cannot be written.
pub fn choose_profile_library(settings: &Path, folder: &Path) -> Result<(), SessionError> {
    let chosen = Settings {
        profile_library: Some(folder.to_path_buf()),
    };
    write_json(settings, &chosen)
}

/// Writes `value` as JSON to `file`, its folder made first.
fn write_json(file: &Path, value: &impl serde::Serialize) -> Result<(), SessionError> {
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir).map_err(|source| SessionError::Write {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    let text = serde_json::to_vec_pretty(value).map_err(|e| SessionError::Write {
        path: file.to_path_buf(),
        source: std::io::Error::other(e),
    })?;
    crate::io::write_atomic(file, &text).map_err(SessionError::from)
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
    write_json(file, &list)?;
    Ok(list)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The library chosen in the studio is the one read back (by the studio's next
    /// launch and the batch); no choice, or an unreadable file, is the default.
    #[test]
    fn the_chosen_profile_library_is_remembered() {
        let dir = tempfile::tempdir().expect("temp dir");
        let settings = dir.path().join("lensblur").join("settings.json");
        assert_eq!(profile_library(&settings), default_profile_library());
        let chosen = dir.path().join("my lenses");
        choose_profile_library(&settings, &chosen).expect("remembered");
        assert_eq!(profile_library(&settings), chosen);
        std::fs::write(&settings, b"{not json").expect("write");
        assert_eq!(profile_library(&settings), default_profile_library());
    }
}
