//! Reading and writing files: every file lensblur writes goes through here, so that
//! nothing is ever half-written, and every file it reads whole is read through a size
//! limit, so that nothing is read past what [`crate::limits`] allows.
//!
//! A write goes to a temporary file beside the target, is flushed to the disk
//! (`fsync`), renamed over the target, and then the folder itself is flushed, so that
//! after a crash or power loss a reader finds either the old file or the new one,
//! never a torn one, and never a rename that the disk has not recorded.

use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A file that could not be written, naming it.
#[derive(Debug, thiserror::Error)]
#[error("{}: cannot write: {source}", path.display())]
pub struct WriteError {
    pub path: PathBuf,
    pub source: std::io::Error,
}

/// A file that could not be read, naming it.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: {bytes} bytes, above the limit of {limit} bytes for this kind of file", path.display())]
    TooLarge {
        path: PathBuf,
        bytes: u64,
        limit: u64,
    },
}

/// Reads a whole file of at most `limit` bytes. The length is checked before anything
/// is allocated, and the read stops past the limit should the file grow meanwhile.
///
/// # Errors
/// The file cannot be opened or read, or is longer than `limit`.
pub fn read_limited(path: &Path, limit: u64) -> Result<Vec<u8>, ReadError> {
    use std::io::Read;
    let io = |source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let too_large = |bytes| ReadError::TooLarge {
        path: path.to_path_buf(),
        bytes,
        limit,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len > limit {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(limit + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Reads a whole UTF-8 text file of at most `limit` bytes (see [`read_limited`]).
///
/// # Errors
/// As [`read_limited`], or the file is not UTF-8.
pub fn read_text_limited(path: &Path, limit: u64) -> Result<String, ReadError> {
    let bytes = read_limited(path, limit)?;
    String::from_utf8(bytes).map_err(|e| ReadError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e.utf8_error()),
    })
}

/// Reads a JSON file lensblur wrote or a person wrote for it, within
/// [`crate::limits::MAX_JSON_BYTES`].
///
/// # Errors
/// As [`read_text_limited`].
pub fn read_json_text(path: &Path) -> Result<String, ReadError> {
    read_text_limited(path, crate::limits::MAX_JSON_BYTES)
}

/// Whether a file name is one of [`write_atomic`]'s temporary files: what a writer
/// killed before its rename leaves behind. Never a result; whoever holds the folder's
/// lock may delete it.
#[must_use]
pub fn is_temporary(name: &str) -> bool {
    name.starts_with('.')
        && name.rsplit_once(".tmp").is_some_and(|(_, tail)| {
            tail.split_once('-').is_some_and(|(pid, n)| {
                !pid.is_empty()
                    && pid.bytes().all(|b| b.is_ascii_digit())
                    && !n.is_empty()
                    && n.bytes().all(|b| b.is_ascii_digit())
            })
        })
}

/// Removes the temporary files of writers that died in `dir` (see [`is_temporary`]);
/// only whoever holds the folder's lock may call this, or a live writer's file would go.
/// Returns how many were removed.
pub fn remove_stale_temporaries(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .flatten()
        .filter(|e| is_temporary(&e.file_name().to_string_lossy()))
        .filter(|e| std::fs::remove_file(e.path()).is_ok())
        .count()
}

/// Distinguishes temporary files of concurrent writers in one process (two job
/// threads may save the same session at once).
static NEXT_TMP: AtomicU64 = AtomicU64::new(0);

/// The folder a path's relative components start from (`.` for a bare file name).
#[must_use]
pub fn parent_dir(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Writes `bytes` to `path` atomically and durably (see the module documentation).
/// The parent folder must exist.
///
/// # Errors
/// The temporary file cannot be created, written or flushed, or the rename fails; the
/// target is then untouched and the temporary file removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let err = |source| WriteError {
        path: path.to_path_buf(),
        source,
    };
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(
        ".{name}.tmp{}-{}",
        std::process::id(),
        NEXT_TMP.fetch_add(1, Ordering::Relaxed)
    ));
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(err(e));
    }
    sync_dir(dir).map_err(err)
}

/// Writes `value` as pretty JSON with [`write_atomic`].
///
/// # Errors
/// As [`write_atomic`]; a value that cannot be serialised is reported the same way.
pub fn write_json<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<(), WriteError> {
    let bytes = serde_json::to_vec_pretty(value).map_err(|e| WriteError {
        path: path.to_path_buf(),
        source: std::io::Error::other(e),
    })?;
    write_atomic(path, &bytes)
}

/// Creates a folder and its parents.
///
/// # Errors
/// The folder cannot be created.
pub fn create_dir_all(dir: &Path) -> Result<(), WriteError> {
    std::fs::create_dir_all(dir).map_err(|source| WriteError {
        path: dir.to_path_buf(),
        source,
    })
}

/// Records a rename in the folder on disk. Where a platform cannot open a folder as a
/// file (Windows), the rename is as durable as that platform makes it.
fn sync_dir(dir: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::fs::File::open(dir)?.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_whole_and_leaves_no_temporary_files() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.json");
        write_json(&p, &vec![1, 2, 3]).unwrap();
        write_atomic(&p, b"[4]").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"[4]");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.json")]);
    }

    #[test]
    fn a_failed_write_names_the_file_and_keeps_the_old_one() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("missing-folder").join("a.json");
        let e = write_atomic(&p, b"x").unwrap_err().to_string();
        assert!(e.contains("a.json") && e.contains("cannot write"), "{e}");
    }

    #[test]
    fn reads_refuse_past_the_limit_with_the_numbers() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("big.json");
        std::fs::write(&p, vec![b' '; 100]).unwrap();
        assert_eq!(read_limited(&p, 100).unwrap().len(), 100);
        let e = read_limited(&p, 99).unwrap_err().to_string();
        assert!(
            e.contains("big.json") && e.contains("100") && e.contains("99"),
            "{e}"
        );
        std::fs::write(&p, [0xff, 0xfe]).unwrap();
        assert!(read_text_limited(&p, 10).is_err());
    }

    #[test]
    fn temporary_names_are_recognised_and_swept() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("session.json");
        write_atomic(&p, b"{}").unwrap();
        let stale = dir.path().join(".session.json.tmp4242-7");
        std::fs::write(&stale, b"{\"half").unwrap();
        assert!(is_temporary(".session.json.tmp4242-7"));
        assert!(!is_temporary("session.json"));
        assert!(!is_temporary(".session.json.tmp-"));
        assert!(!is_temporary(".hidden.tmpx-1"));
        assert_eq!(remove_stale_temporaries(dir.path()), 1);
        assert!(!stale.exists() && p.exists());
    }
}
