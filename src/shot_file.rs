//! What identifies a shot file: its content's fingerprint, and the record of it that
//! every result measured on the shot carries. Below every stage (detection and kernels
//! files record their shot), so any stage can name its source.

use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};

/// A shot file that could not be read to fingerprint it.
#[derive(Debug, thiserror::Error)]
#[error("{}: cannot read: {source}", path.display())]
pub struct ShotReadError {
    pub path: PathBuf,
    pub source: std::io::Error,
}

/// How many times this process has fingerprinted each file: reading a shot costs a pass
/// over its bytes, and a project reads each shot once per run. Kept per path (not one
/// global count) so that concurrent runs on other files never disturb what a caller
/// counts for its own.
static READS: std::sync::Mutex<Option<std::collections::BTreeMap<PathBuf, usize>>> =
    std::sync::Mutex::new(None);

fn count_read(path: &Path) {
    if let Ok(mut reads) = READS.lock() {
        *reads
            .get_or_insert_with(Default::default)
            .entry(path.to_path_buf())
            .or_insert(0) += 1;
    }
}

/// How many times this process has fingerprinted the file at `path`.
#[must_use]
pub fn times_read(path: &Path) -> usize {
    READS
        .lock()
        .ok()
        .and_then(|r| r.as_ref().and_then(|m| m.get(path).copied()))
        .unwrap_or(0)
}

/// A 64-bit FNV-1a hash of a shot file's bytes: what identifies a shot's content.
/// FNV is stable across runs, platforms and versions (std's hasher is seeded per
/// process), and reading the file costs far less than any stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Fingerprint(#[serde(with = "hex_u64")] pub u64);

impl Fingerprint {
    /// Hashes a file's content.
    ///
    /// # Errors
    /// The file cannot be read.
    pub fn of_file(path: &Path) -> Result<Self, ShotReadError> {
        count_read(path);
        let err = |source| ShotReadError {
            path: path.to_path_buf(),
            source,
        };
        let mut f = std::fs::File::open(path).map_err(err)?;
        let mut h = Fnv::new();
        let mut buf = vec![0u8; 1 << 20];
        loop {
            let n = f.read(&mut buf).map_err(err)?;
            if n == 0 {
                break;
            }
            h.eat(&buf[..n]);
        }
        Ok(Fingerprint(h.0))
    }
}

impl std::fmt::Display for Fingerprint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:016x}", self.0)
    }
}

mod hex_u64 {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &u64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&format!("{v:016x}"))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        let text = String::deserialize(d)?;
        u64::from_str_radix(&text, 16).map_err(serde::de::Error::custom)
    }
}

pub(crate) struct Fnv(pub(crate) u64);

impl Fnv {
    pub(crate) fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }

    pub(crate) fn eat(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
}

/// Which shot a result was measured on: written into every result file, so a result
/// can always be traced to (and checked against) its photo.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShotRecord {
    /// The shot's file name (no folder: the session may move).
    pub file: String,
    pub fingerprint: Fingerprint,
}

/// A shot file as the pipeline knows it: where it is and what it holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShotFile {
    pub path: PathBuf,
    pub fingerprint: Fingerprint,
}

impl ShotFile {
    /// Reads the file once to fingerprint it.
    ///
    /// # Errors
    /// The file cannot be read.
    pub fn read(path: &Path) -> Result<Self, ShotReadError> {
        Ok(Self {
            path: path.to_path_buf(),
            fingerprint: Fingerprint::of_file(path)?,
        })
    }

    #[must_use]
    pub fn record(&self) -> ShotRecord {
        ShotRecord {
            file: self
                .path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            fingerprint: self.fingerprint,
        }
    }

    pub(crate) fn stem(&self) -> String {
        self.path
            .file_stem()
            .map_or_else(|| "shot".into(), |s| s.to_string_lossy().into_owned())
    }
}
