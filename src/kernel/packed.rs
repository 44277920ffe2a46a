//! The packed kernels file (`<name>.kernels.bin`, docs/formats.md): a cached kernels
//! file's content in binary, beside the JSON one it mirrors. The JSON file stays the
//! contract; this is how the result cache reads a shot's kernels quickly (a shot's
//! kernel arrays are tens of megabytes as JSON text, a fraction of that as bytes, and
//! read without parsing a number). It names the JSON file's length and modification
//! time when it was written: one that no longer matches is ignored, so a JSON file
//! rewritten by anything else is never shadowed.
//!
//! Layout, little-endian: the magic `LBKERNEL`, the version (u32), the JSON file's
//! length in bytes (u64) and modification time in nanoseconds since the Unix epoch
//! (u64), the length of the head (u64), the head: the kernels file as JSON with every
//! kernel's `data` empty (its `size` kept), then each kept kernel's size² values (f64)
//! in sample order. Floats are stored as they are, so a kernels file read back equals
//! the one written, bit for bit.

use super::file::{KernelData, KernelsFile};
use std::path::{Path, PathBuf};

/// What starts every packed kernels file.
pub const MAGIC: &[u8; 8] = b"LBKERNEL";
/// The version this build writes and reads.
pub const VERSION: u32 = 1;
/// Bytes before the head: magic, version, the JSON file's length and time, head length.
const PREFIX: usize = 8 + 4 + 8 + 8 + 8;

/// Why a packed kernels file was not used (its JSON file is read instead).
#[derive(Debug, thiserror::Error)]
pub enum PackedError {
    #[error(transparent)]
    Read(#[from] crate::io::ReadError),
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    #[error("{}: {reason}", path.display())]
    Invalid { path: PathBuf, reason: String },
    #[error("{}: written for another version of its JSON file", path.display())]
    Stale { path: PathBuf },
}

/// The packed file beside a kernels JSON file: `x.kernels.json` → `x.kernels.bin`.
#[must_use]
pub fn path_beside(json: &Path) -> PathBuf {
    json.with_extension("bin")
}

/// The JSON file's length and modification time (ns since the epoch), which a packed
/// file records so that it is only used with the JSON file it was made from.
fn stamp(json: &Path) -> std::io::Result<(u64, u64)> {
    let meta = std::fs::metadata(json)?;
    let modified = meta.modified()?;
    let ns = modified
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
    Ok((meta.len(), ns))
}

/// Writes the packed form of `file` beside `json`, the kernels file it was just written
/// to (atomically, as every file lensblur writes).
///
/// # Errors
/// The JSON file cannot be looked at, or the packed file cannot be written.
pub fn write_beside(json: &Path, file: &KernelsFile) -> Result<(), PackedError> {
    let (json_len, json_ns) = stamp(json).map_err(|e| PackedError::Invalid {
        path: json.to_path_buf(),
        reason: e.to_string(),
    })?;
    crate::io::write_atomic(&path_beside(json), &encode(file, json_len, json_ns))?;
    Ok(())
}

/// The kernels file packed beside `json`, where there is one made from `json` as it is
/// now.
///
/// # Errors
/// No packed file, one made from another version of `json`, or one that is not a
/// valid packed kernels file (each is read from `json` instead).
pub fn load_beside(json: &Path) -> Result<KernelsFile, PackedError> {
    let path = path_beside(json);
    let bytes = crate::io::read_limited(&path, crate::limits::MAX_JSON_BYTES)?;
    let stamp = stamp(json).map_err(|e| PackedError::Invalid {
        path: json.to_path_buf(),
        reason: e.to_string(),
    })?;
    decode(&bytes, Some(stamp)).map_err(|reason| match reason {
        DecodeError::Stale => PackedError::Stale { path: path.clone() },
        DecodeError::Invalid(reason) => PackedError::Invalid {
            path: path.clone(),
            reason,
        },
    })
}

/// The packed bytes of `file`, recording its JSON file's length and time.
#[must_use]
pub fn encode(file: &KernelsFile, json_len: u64, json_ns: u64) -> Vec<u8> {
    let mut head = file.clone();
    for s in &mut head.samples {
        if let Some(k) = &mut s.kernel {
            k.data = Vec::new();
        }
    }
    // A kernels file always serialises; an empty head would only be refused on reading.
    let head = serde_json::to_vec(&head).unwrap_or_default();
    let values: usize = file
        .samples
        .iter()
        .filter_map(|s| s.kernel.as_ref())
        .map(|k| k.data.len())
        .sum();
    let mut out = Vec::with_capacity(PREFIX + head.len() + 8 * values);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&json_len.to_le_bytes());
    out.extend_from_slice(&json_ns.to_le_bytes());
    out.extend_from_slice(&(head.len() as u64).to_le_bytes());
    out.extend_from_slice(&head);
    for k in file.samples.iter().filter_map(|s| s.kernel.as_ref()) {
        for v in &k.data {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Why bytes did not decode.
#[derive(Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Made from another version of its JSON file.
    Stale,
    Invalid(String),
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(b)
}

/// The kernels file in packed `bytes`, checked as a kernels file read from JSON is.
/// With `stamp`, the JSON file's length and time it must have been made from.
///
/// # Errors
/// Not a packed kernels file of this version, lengths that do not add up to the
/// bytes, a head that is not a valid kernels file, or another JSON file's stamp.
pub fn decode(bytes: &[u8], stamp: Option<(u64, u64)>) -> Result<KernelsFile, DecodeError> {
    let invalid = |reason: String| DecodeError::Invalid(reason);
    if bytes.len() < PREFIX || &bytes[..8] != MAGIC {
        return Err(invalid("not a packed kernels file".into()));
    }
    let mut v = [0u8; 4];
    v.copy_from_slice(&bytes[8..12]);
    let version = u32::from_le_bytes(v);
    if version != VERSION {
        return Err(invalid(format!(
            "packed kernels version {version}, this lensblur reads version {VERSION}"
        )));
    }
    if let Some((len, ns)) = stamp
        && (u64_at(bytes, 12), u64_at(bytes, 20)) != (len, ns)
    {
        return Err(DecodeError::Stale);
    }
    let head_len = u64_at(bytes, 28);
    let body = &bytes[PREFIX..];
    let head_len = usize::try_from(head_len)
        .ok()
        .filter(|&n| n <= body.len())
        .ok_or_else(|| invalid(format!("head of {head_len} bytes in a shorter file")))?;
    let text = std::str::from_utf8(&body[..head_len])
        .map_err(|e| invalid(format!("head is not text: {e}")))?;
    let mut file: KernelsFile =
        serde_json::from_str(text).map_err(|e| invalid(format!("head: {e}")))?;
    let mut values = &body[head_len..];
    for (i, s) in file.samples.iter_mut().enumerate() {
        let Some(KernelData { size, data }) = &mut s.kernel else {
            continue;
        };
        // Checked before anything is sized from it.
        if *size > crate::limits::MAX_KERNEL_SIDE || !data.is_empty() {
            return Err(invalid(format!("sample {i}: kernel of side {size}")));
        }
        let n = *size * *size;
        if values.len() < 8 * n {
            return Err(invalid(format!(
                "sample {i}: the file ends inside its kernel"
            )));
        }
        let (mine, rest) = values.split_at(8 * n);
        *data = mine
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect();
        values = rest;
    }
    if !values.is_empty() {
        return Err(invalid(format!(
            "{} bytes after the last kernel",
            values.len()
        )));
    }
    file.check().map_err(invalid)?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::file::{FailedSample, KERNELS, KernelSample};
    use crate::plane::{CameraIdentity, Channel};

    fn kernels_file() -> KernelsFile {
        let sample = |x: f64, kernel: Option<KernelData>| KernelSample {
            x,
            y: 20.5,
            channel: Channel::G,
            cxx: Some(1.0 / 3.0),
            cyy: Some(0.1 + 0.2),
            cor: Some(-0.25),
            row: Some(2),
            col: Some(3),
            ml: None,
            kernel,
        };
        let data: Vec<f64> = (0..25).map(|i| f64::from(i) / 300.0 + 1e-17).collect();
        KernelsFile {
            schema: KERNELS.tag(),
            width: 640,
            height: 480,
            focal_mm: Some(35.0),
            f_number: Some(5.6),
            focus_distance_m: None,
            oversample: 3,
            identity: Some(CameraIdentity {
                make: Some("Virtual".into()),
                ..CameraIdentity::default()
            }),
            source: None,
            picture: None,
            samples: vec![
                sample(10.25, Some(KernelData { size: 5, data })),
                sample(11.0, None),
                sample(
                    12.0,
                    Some(KernelData {
                        size: 1,
                        data: vec![1.0],
                    }),
                ),
            ],
            failed: vec![FailedSample {
                row: 0,
                col: 1,
                x: 3.0,
                y: 4.0,
                channel: Channel::R,
                reason: "no edge".into(),
            }],
        }
    }

    #[test]
    fn a_packed_kernels_file_reads_back_equal_to_the_one_written() {
        let file = kernels_file();
        let bytes = encode(&file, 1234, 5678);
        assert_eq!(decode(&bytes, Some((1234, 5678))), Ok(file.clone()));
        assert_eq!(decode(&bytes, None), Ok(file));
    }

    #[test]
    fn a_packed_file_made_from_another_json_file_is_not_used() {
        let bytes = encode(&kernels_file(), 1234, 5678);
        assert_eq!(decode(&bytes, Some((1234, 5679))), Err(DecodeError::Stale));
        assert_eq!(decode(&bytes, Some((1235, 5678))), Err(DecodeError::Stale));
    }

    #[test]
    fn damaged_or_foreign_packed_files_are_refused() {
        let bytes = encode(&kernels_file(), 1, 2);
        let refused = |b: &[u8]| matches!(decode(b, None), Err(DecodeError::Invalid(_)));
        assert!(refused(&bytes[..bytes.len() - 1]), "cut short");
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(refused(&longer), "trailing bytes");
        let mut newer = bytes.clone();
        newer[8..12].copy_from_slice(&(VERSION + 1).to_le_bytes());
        assert!(refused(&newer), "a newer version");
        let mut huge_head = bytes.clone();
        huge_head[28..36].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(refused(&huge_head), "a head longer than the file");
        assert!(refused(b"LBKERNEL"), "no header");
        assert!(refused(b"{\"schema\": \"lensblur.kernels/1\"}"), "JSON");
        for cut in [0, 7, PREFIX, PREFIX + 10] {
            assert!(refused(&bytes[..cut]), "cut at {cut}");
        }
    }

    #[test]
    fn the_packed_file_beside_a_json_file_follows_it() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let json = dir.path().join("shot-0123.kernels.json");
        let file = kernels_file();
        crate::io::write_json(&json, &file).expect("JSON written");
        assert!(load_beside(&json).is_err(), "nothing packed yet");
        write_beside(&json, &file).expect("packed");
        assert_eq!(path_beside(&json), dir.path().join("shot-0123.kernels.bin"));
        assert_eq!(load_beside(&json).expect("packed file used"), file);
        // The JSON file rewritten by anything else: the packed one no longer speaks for it.
        let mut other = file.clone();
        other.width = 800;
        std::thread::sleep(std::time::Duration::from_millis(20));
        crate::io::write_json(&json, &other).expect("rewritten");
        assert!(matches!(load_beside(&json), Err(PackedError::Stale { .. })));
    }
}
