//! What lensblur reads from a shot or photo (`lensblur info`, docs/formats.md "info"):
//! the image it measures, its CFA and levels, the camera and lens, the settings and
//! where it was focused, and which decoder read it. The pixels are decoded, so a file
//! whose image is missing is refused here as everywhere else, not reported as fine.

use super::{Decoder, LoadError, LoadOptions, OnDisk, decode_with_decoder, refuse_blank};
use crate::limits;
use std::path::Path;

/// The `info` JSON's schema.
pub const INFO_SCHEMA: crate::format::Schema = crate::format::Schema {
    kind: "info",
    current: 1,
    unversioned: None,
};

/// Where the camera focused.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum FocusDistance {
    /// Metres.
    Metres(f64),
    /// The file says infinity (written as the string "infinity").
    Infinity(InfinityWord),
}

/// The word `"infinity"`, the one value a JSON number cannot be.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InfinityWord {
    Infinity,
}

impl FocusDistance {
    #[must_use]
    pub fn from_metres(m: f64) -> Option<Self> {
        if m == f64::INFINITY {
            Some(FocusDistance::Infinity(InfinityWord::Infinity))
        } else {
            (m.is_finite() && m > 0.0).then_some(FocusDistance::Metres(m))
        }
    }

    /// Metres, infinite for infinity.
    #[must_use]
    pub fn metres(self) -> f64 {
        match self {
            FocusDistance::Metres(m) => m,
            FocusDistance::Infinity(_) => f64::INFINITY,
        }
    }
}

/// A file as lensblur reads it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FileInfo {
    /// `lensblur.info/1`.
    pub schema: String,
    pub file: String,
    /// Which decoder read it: `rawler`, `rawloader`, `lensblur` (our DNG reader) or
    /// `image` (PNG, TIFF, JPEG).
    pub decoder: Decoder,
    /// The image measured: a RAW file's active area, in sensor pixels.
    pub width: usize,
    pub height: usize,
    /// The 2 × 2 CFA pattern from the top-left pixel, row by row ("RGGB"); `None` for
    /// linear RGB or grey data.
    pub cfa: Option<String>,
    /// Black level of each CFA site, in the order of `cfa`; `None` without a CFA.
    pub black: Option<[u16; 4]>,
    /// The white (saturation) level; `None` without a CFA.
    pub white: Option<u16>,
    pub make: Option<String>,
    pub model: Option<String>,
    pub lens: Option<String>,
    pub focal_length_mm: Option<f64>,
    pub f_number: Option<f64>,
    pub focus_distance_m: Option<FocusDistance>,
}

/// Reads and decodes a file and says what it holds.
///
/// # Errors
/// As [`super::load_capture`]; and a file whose pixels are all one value (its image
/// data missing) is refused.
pub fn inspect(path: &Path) -> Result<FileInfo, LoadError> {
    let bytes = crate::io::read_limited(path, limits::MAX_IMAGE_FILE_BYTES)?;
    inspect_of(path, &bytes, OnDisk(true))
}

/// [`inspect`] on a file's bytes; `path` names the file.
///
/// # Errors
/// As [`inspect`].
pub fn inspect_bytes(path: &Path, bytes: &[u8]) -> Result<FileInfo, LoadError> {
    inspect_of(path, bytes, OnDisk(false))
}

fn inspect_of(path: &Path, bytes: &[u8], on_disk: OnDisk) -> Result<FileInfo, LoadError> {
    let (capture, decoder, exif) =
        decode_with_decoder(path, bytes, on_disk, &LoadOptions::default())?;
    // RAW files are refused blank as they load; a PNG, TIFF or JPEG of one value is a
    // picture of nothing all the same.
    refuse_blank(path, &capture)?;
    let raw = capture.raw.as_ref();
    let letters = ['R', 'G', 'B', 'E'];
    Ok(FileInfo {
        schema: INFO_SCHEMA.tag(),
        file: path.display().to_string(),
        decoder,
        width: capture.width,
        height: capture.height,
        cfa: raw.map(|r| {
            r.cfa
                .iter()
                .map(|&c| letters.get(usize::from(c)).copied().unwrap_or('?'))
                .collect()
        }),
        black: raw.map(|r| r.black),
        white: raw.map(|r| r.white),
        make: capture.identity.make.clone(),
        model: capture.identity.model.clone(),
        lens: capture.identity.lens_model.clone(),
        focal_length_mm: capture.setting_focal_mm,
        f_number: capture.setting_f_number,
        focus_distance_m: exif.subject_distance_m.and_then(FocusDistance::from_metres),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn focus_at_infinity_is_the_word() {
        let inf = FocusDistance::from_metres(f64::INFINITY).unwrap();
        assert_eq!(serde_json::to_string(&inf).unwrap(), "\"infinity\"");
        let near: FocusDistance = serde_json::from_str("1.5").unwrap();
        assert_eq!(near.metres(), 1.5);
        let back: FocusDistance = serde_json::from_str("\"infinity\"").unwrap();
        assert_eq!(back.metres(), f64::INFINITY);
        assert_eq!(FocusDistance::from_metres(0.0), None);
    }
}
