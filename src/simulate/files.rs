//! Writing simulated shots the way cameras and editors write them: Bayer shots as DNG
//! (see [`super::dng`]), RGB shots as 16-bit linear PNG or TIFF, each with its exact
//! ground truth beside it.

use super::capture::SimulatedShot;
use crate::dng::{DngInfo, DngLayout, write_dng};
use crate::plane::{Capture, Channel};
use std::path::Path;

/// How a shot is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShotFormat {
    /// RGGB mosaic in a DNG, 14-bit values with the black level, settings in EXIF.
    Dng,
    /// Linear 16-bit RGB PNG (black 0, white 65535).
    Png,
    /// Linear 16-bit RGB TIFF.
    Tiff,
}

impl ShotFormat {
    #[must_use]
    pub fn extension(self) -> &'static str {
        match self {
            Self::Dng => "dng",
            Self::Png => "png",
            Self::Tiff => "tif",
        }
    }

    /// Whether the shot must be simulated as a Bayer mosaic.
    #[must_use]
    pub fn is_raw(self) -> bool {
        self == Self::Dng
    }
}

#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error("{path}: {reason}")]
    Unsuitable { path: String, reason: String },
    #[error("{path}: cannot write: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
}

/// Writes `shot` to `path` in `format`, atomically; a DNG in uncompressed strips.
///
/// # Errors
/// The shot does not suit the format (an RGB shot as DNG or the reverse), or I/O.
pub fn write_shot(path: &Path, shot: &SimulatedShot, format: ShotFormat) -> Result<(), WriteError> {
    write_shot_as(path, shot, format, DngLayout::default())
}

/// [`write_shot`] with the DNG's layout (ignored for other formats).
///
/// # Errors
/// As [`write_shot`], and a layout the mosaic cannot take.
pub fn write_shot_as(
    path: &Path,
    shot: &SimulatedShot,
    format: ShotFormat,
    dng_layout: DngLayout,
) -> Result<(), WriteError> {
    let unsuitable = |reason: &str| WriteError::Unsuitable {
        path: path.display().to_string(),
        reason: reason.into(),
    };
    let io = |source: std::io::Error| WriteError::Io {
        path: path.display().to_string(),
        source,
    };
    match format {
        ShotFormat::Dng => {
            if !shot.capture.is_raw {
                return Err(unsuitable("a DNG needs a Bayer shot"));
            }
            let mut info = DngInfo::simulated(
                shot.capture.identity.make.as_deref().unwrap_or_default(),
                shot.capture.identity.model.as_deref().unwrap_or_default(),
                shot.black_level,
                shot.white_level,
                Some(shot.truth.setting),
                dng_layout,
            );
            // What a camera records of its lens: lensfun finds entries by these.
            info.identity = shot.capture.identity.clone();
            info.raw.focal_35mm =
                Some(shot.truth.setting.focal_mm * super::capture::SIM_CROP_FACTOR);
            info.raw.lens_specification = Some(shot.lens_specification);
            write_dng(
                path,
                &shot.cfa,
                shot.capture.width,
                shot.capture.height,
                &info,
            )
            .map_err(io)
        }
        ShotFormat::Png | ShotFormat::Tiff => {
            let bytes = rgb16_bytes(&shot.capture, format).map_err(|r| unsuitable(&r))?;
            write_atomic(path, &bytes).map_err(io)
        }
    }
}

/// A linear 16-bit RGB image of a capture's full R, G, B planes, encoded.
///
/// # Errors
/// The capture has no full R, G and B planes, or encoding failed.
pub fn rgb16_bytes(capture: &Capture, format: ShotFormat) -> Result<Vec<u8>, String> {
    let (w, h) = (capture.width, capture.height);
    let plane = |c: Channel| {
        capture
            .planes
            .iter()
            .find(|p| p.channel == c && p.step == 1)
    };
    let (Some(r), Some(g), Some(b)) = (plane(Channel::R), plane(Channel::G), plane(Channel::B))
    else {
        return Err("an RGB image needs full R, G and B planes".into());
    };
    let mut data = Vec::with_capacity(w * h * 3);
    for i in 0..w * h {
        for p in [r, g, b] {
            data.push((p.plane.data[i].clamp(0.0, 1.0) * 65535.0).round() as u16);
        }
    }
    let img = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_raw(w as u32, h as u32, data)
        .ok_or("image size does not match its data")?;
    let fmt = match format {
        ShotFormat::Tiff => image::ImageFormat::Tiff,
        _ => image::ImageFormat::Png,
    };
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), fmt)
        .map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// Atomic, durable write (see [`crate::io`]), as an `io::Error` naming the file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    crate::io::write_atomic(path, bytes).map_err(|e| std::io::Error::other(e.to_string()))
}
