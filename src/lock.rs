//! One writer per session folder (docs/formats.md, "Locking").
//!
//! Whoever writes into a session folder (a studio with the session open, `lensblur
//! calibrate` on it) holds an exclusive operating-system lock on `.lensblur.lock` in
//! it for as long as it works there. A second writer is refused at once with who holds
//! it, never queued and never interleaved. The lock is the kernel's (`flock` on Unix,
//! `LockFileEx` on Windows): it goes with its process, so a crashed or killed holder
//! never leaves the folder locked, and the file's contents (who holds it) are only a
//! note for the message.

use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

/// The lock file's name inside a session folder.
pub const LOCK_FILE: &str = ".lensblur.lock";

/// Why a folder could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error("{}: in use by {holder}; close it there first", dir.display())]
    Held { dir: PathBuf, holder: String },
    #[error("{}: cannot lock the session folder: {source}", dir.display())]
    Io {
        dir: PathBuf,
        source: std::io::Error,
    },
}

/// An exclusive lock on a session folder, released when dropped.
#[derive(Debug)]
pub struct FolderLock {
    dir: PathBuf,
    // Held open: closing the file releases the lock.
    _file: std::fs::File,
}

impl FolderLock {
    /// Takes the folder's lock for `who` (a few words: "lensblur calibrate", "the
    /// studio"), or says who has it.
    ///
    /// # Errors
    /// Another process (or another open session in this one) holds it, or the lock
    /// file cannot be opened.
    pub fn acquire(dir: &Path, who: &str) -> Result<Self, LockError> {
        let io = |source| LockError::Io {
            dir: dir.to_path_buf(),
            source,
        };
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(dir.join(LOCK_FILE))
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut note = String::new();
                let _ = file.read_to_string(&mut note);
                let holder = note.trim();
                return Err(LockError::Held {
                    dir: dir.to_path_buf(),
                    holder: if holder.is_empty() {
                        "another lensblur".into()
                    } else {
                        holder.chars().take(200).collect()
                    },
                });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io(e)),
        }
        // The note is best effort: the lock itself is what excludes.
        let note = format!("{who} (process {})", std::process::id());
        let _ = file
            .set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(note.as_bytes()))
            .and_then(|()| file.flush());
        Ok(Self {
            dir: dir.to_path_buf(),
            _file: file,
        })
    }

    /// The folder this lock holds.
    #[must_use]
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_writer_is_refused_with_who_holds_it_until_the_first_lets_go() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::acquire(dir.path(), "the studio").unwrap();
        let e = FolderLock::acquire(dir.path(), "lensblur calibrate")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("in use by the studio (process")
                && e.contains(&dir.path().display().to_string()),
            "{e}"
        );
        drop(first);
        let again = FolderLock::acquire(dir.path(), "lensblur calibrate").unwrap();
        assert_eq!(again.dir(), dir.path());
    }
}
