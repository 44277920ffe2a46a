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

/// Full-resolution linear R, G, B (or one Y) planes of a capture: a CFA capture is
/// demosaiced bilinearly (each missing sample the mean of its channel's nearest
/// neighbours), so a deblurred RAW is written as linear camera RGB.
#[must_use]
pub fn full_planes(capture: &Capture) -> Vec<(Channel, Plane)> {
    let (w, h) = (capture.width, capture.height);
    let mut out = Vec::new();
    for ch in [Channel::R, Channel::G, Channel::B, Channel::Y] {
        let planes: Vec<&ChannelPlane> =
            capture.planes.iter().filter(|p| p.channel == ch).collect();
        if planes.is_empty() {
            continue;
        }
        let mut sum = vec![0.0f32; w * h];
        let mut known = vec![false; w * h];
        for cp in &planes {
            for j in 0..cp.plane.height {
                for i in 0..cp.plane.width {
                    let (x, y) = (cp.step * i + cp.offset_x, cp.step * j + cp.offset_y);
                    if x < w && y < h {
                        sum[y * w + x] = cp.plane.get(i, j);
                        known[y * w + x] = true;
                    }
                }
            }
        }
        let mut plane = Plane::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let k = y * w + x;
                plane.data[k] = if known[k] {
                    sum[k]
                } else {
                    let (mut s, mut n) = (0.0f32, 0u32);
                    for (dx, dy) in [
                        (-1, 0),
                        (1, 0),
                        (0, -1),
                        (0, 1),
                        (-1, -1),
                        (1, -1),
                        (-1, 1),
                        (1, 1),
                    ] {
                        let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                        if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < h {
                            let q = yy as usize * w + xx as usize;
                            if known[q] {
                                s += sum[q];
                                n += 1;
                            }
                        }
                    }
                    if n > 0 { s / n as f32 } else { 0.0 }
                };
            }
        }
        out.push((ch, plane));
    }
    out
}

#[derive(Debug, thiserror::Error)]
#[error("{}: cannot write: {reason}", path.display())]
pub struct SaveError {
    pub path: PathBuf,
    pub reason: String,
}

/// Writes linear planes (R, G, B or Y; black 0, white 1) as a 16-bit PNG or TIFF, the
/// format chosen by the extension; with `srgb`, as an 8-bit sRGB-encoded preview.
///
/// # Errors
/// An unknown extension, planes of the wrong size, or an I/O failure.
pub fn save_planes(path: &Path, planes: &[(Channel, Plane)], srgb: bool) -> Result<(), SaveError> {
    let err = |reason: String| SaveError {
        path: path.to_path_buf(),
        reason,
    };
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let format = match ext.as_str() {
        "png" => image::ImageFormat::Png,
        "tif" | "tiff" => image::ImageFormat::Tiff,
        other => {
            return Err(err(format!(
                "unknown image extension '{other}' (png, tif, tiff)"
            )));
        }
    };
    let Some((_, first)) = planes.first() else {
        return Err(err("no image planes".into()));
    };
    let (w, h) = (first.width, first.height);
    if planes.iter().any(|(_, p)| p.width != w || p.height != h) {
        return Err(err("planes differ in size".into()));
    }
    let get = |c: Channel| planes.iter().find(|(ch, _)| *ch == c).map(|(_, p)| p);
    let rgb: Vec<&Plane> = match (get(Channel::R), get(Channel::G), get(Channel::B)) {
        (Some(r), Some(g), Some(b)) => vec![r, g, b],
        _ => vec![first],
    };
    let encode = |v: f32| -> f32 {
        let v = v.clamp(0.0, 1.0);
        if !srgb {
            v
        } else if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    };
    let (w32, h32) = (
        u32::try_from(w).map_err(|_| err("too wide".into()))?,
        u32::try_from(h).map_err(|_| err("too tall".into()))?,
    );
    let img: image::DynamicImage = if srgb {
        let data: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                rgb.iter()
                    .map(move |p| (encode(p.data[i]) * 255.0).round() as u8)
            })
            .collect();
        if rgb.len() == 3 {
            image::RgbImage::from_raw(w32, h32, data).map(image::DynamicImage::ImageRgb8)
        } else {
            image::GrayImage::from_raw(w32, h32, data).map(image::DynamicImage::ImageLuma8)
        }
        .ok_or_else(|| err("image buffer size".into()))?
    } else {
        let data: Vec<u16> = (0..w * h)
            .flat_map(|i| {
                rgb.iter()
                    .map(move |p| (encode(p.data[i]) * 65535.0).round() as u16)
            })
            .collect();
        if rgb.len() == 3 {
            image::ImageBuffer::<image::Rgb<u16>, _>::from_raw(w32, h32, data)
                .map(image::DynamicImage::ImageRgb16)
        } else {
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w32, h32, data)
                .map(image::DynamicImage::ImageLuma16)
        }
        .ok_or_else(|| err("image buffer size".into()))?
    };
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), format)
        .map_err(|e| err(e.to_string()))?;
    // Atomic: a temporary file beside the target, then rename.
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    std::fs::write(&tmp, &bytes).map_err(|e| err(e.to_string()))?;
    std::fs::rename(&tmp, path).map_err(|e| err(e.to_string()))
}
