//! Writing planes back out: a capture's full-resolution planes, 16-bit or preview
//! PNG/TIFF, and a deblurred photo in its original's format.

use crate::plane::{Capture, Channel, ChannelPlane, Plane, srgb_encode};
use std::path::{Path, PathBuf};

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
        if let [only] = planes[..]
            && (only.step, only.offset_x, only.offset_y) == (1, 0, 0)
            && (only.plane.width, only.plane.height) == (w, h)
        {
            // Already whole: nothing to fill in.
            out.push((ch, only.plane.clone()));
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
    let (w, h, rgb) = rgb_or_grey(planes).map_err(|r| err(r.into()))?;
    let encode = |v: f32| -> f32 {
        let v = v.clamp(0.0, 1.0);
        if srgb { srgb_encode(v) } else { v }
    };
    let (w32, h32) = (
        u32::try_from(w).map_err(|_| err("too wide".into()))?,
        u32::try_from(h).map_err(|_| err("too tall".into()))?,
    );
    let img: image::DynamicImage = if srgb {
        let data: Vec<u8> = interleave(&rgb, |v| (encode(v) * 255.0).round() as u8);
        if rgb.len() == 3 {
            image::RgbImage::from_raw(w32, h32, data).map(image::DynamicImage::ImageRgb8)
        } else {
            image::GrayImage::from_raw(w32, h32, data).map(image::DynamicImage::ImageLuma8)
        }
        .ok_or_else(|| err("image buffer size".into()))?
    } else {
        let data: Vec<u16> = interleave(&rgb, |v| (encode(v) * 65535.0).round() as u16);
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
    crate::io::write_atomic(path, &bytes).map_err(|e| err(e.source.to_string()))
}

/// The planes to write, all of one size: R, G, B where there are all three, else the
/// first (a grey image).
/// The planes' samples interleaved pixel by pixel (R, G, B or one Y), each through
/// `sample`; rows in parallel, a whole photo's worth of rounding being no work for one
/// core while the others wait.
fn interleave<T: Copy + Default + Send>(
    planes: &[&Plane],
    sample: impl Fn(f32) -> T + Sync,
) -> Vec<T> {
    use rayon::prelude::*;
    let Some(first) = planes.first() else {
        return Vec::new();
    };
    let (w, c) = (first.width, planes.len());
    let mut out = vec![T::default(); first.data.len() * c];
    if w > 0 {
        out.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
            for (x, px) in row.chunks_exact_mut(c).enumerate() {
                for (o, p) in px.iter_mut().zip(planes) {
                    *o = sample(p.data[y * w + x]);
                }
            }
        });
    }
    out
}

fn rgb_or_grey(planes: &[(Channel, Plane)]) -> Result<(usize, usize, Vec<&Plane>), &'static str> {
    let Some((_, first)) = planes.first() else {
        return Err("no image planes");
    };
    let (w, h) = (first.width, first.height);
    if planes.iter().any(|(_, p)| p.width != w || p.height != h) {
        return Err("planes differ in size");
    }
    let get = |c: Channel| planes.iter().find(|(ch, _)| *ch == c).map(|(_, p)| p);
    let rgb: Vec<&Plane> = match (get(Channel::R), get(Channel::G), get(Channel::B)) {
        (Some(r), Some(g), Some(b)) => vec![r, g, b],
        _ => vec![first],
    };
    Ok((w, h, rgb))
}

/// Writes linear planes (black 0, white 1) as the photo they came from was written: its
/// format (PNG, TIFF or JPEG), its bit depth and its encoding as [`load_capture`] read
/// them (8-bit sRGB-encoded, 16-bit linear), its ICC profile and (JPEG, PNG) its EXIF.
/// So a deblurred photo opens in a viewer looking as its original does.
///
/// # Errors
/// The original is not a PNG, TIFF or JPEG we read, the planes are malformed, or an
/// I/O failure.
pub fn save_like_original(
    path: &Path,
    planes: &[(Channel, Plane)],
    original: &[u8],
) -> Result<(), SaveError> {
    use image::ImageEncoder;
    let err = |reason: String| SaveError {
        path: path.to_path_buf(),
        reason,
    };
    let reader = image::ImageReader::new(std::io::Cursor::new(original))
        .with_guessed_format()
        .map_err(|e| err(e.to_string()))?;
    let format = reader
        .format()
        .filter(|f| {
            matches!(
                f,
                image::ImageFormat::Png | image::ImageFormat::Jpeg | image::ImageFormat::Tiff
            )
        })
        .ok_or_else(|| err("the original is not a PNG, TIFF or JPEG".into()))?;
    let mut decoder = reader.into_decoder().map_err(|e| err(e.to_string()))?;
    let icc = image::ImageDecoder::icc_profile(&mut decoder)
        .ok()
        .flatten();
    let exif = image::ImageDecoder::exif_metadata(&mut decoder)
        .ok()
        .flatten();
    let color = image::ImageDecoder::color_type(&decoder);
    let eight_bit = color.bytes_per_pixel() / color.channel_count() == 1;
    let (w, h, rgb) = rgb_or_grey(planes).map_err(|r| err(r.into()))?;
    let layout = if rgb.len() == 3 {
        image::ExtendedColorType::from(if eight_bit {
            image::ColorType::Rgb8
        } else {
            image::ColorType::Rgb16
        })
    } else {
        image::ExtendedColorType::from(if eight_bit {
            image::ColorType::L8
        } else {
            image::ColorType::L16
        })
    };
    // JPEG has no 16-bit form: it is always 8-bit sRGB.
    let eight_bit = eight_bit || format == image::ImageFormat::Jpeg;
    let layout = if format == image::ImageFormat::Jpeg {
        image::ExtendedColorType::from(if rgb.len() == 3 {
            image::ColorType::Rgb8
        } else {
            image::ColorType::L8
        })
    } else {
        layout
    };
    let data: Vec<u8> = if eight_bit {
        interleave(&rgb, |v| {
            (srgb_encode(v.clamp(0.0, 1.0)) * 255.0).round() as u8
        })
    } else {
        interleave(&rgb, |v| {
            ((v.clamp(0.0, 1.0) * 65535.0).round() as u16).to_ne_bytes()
        })
        .into_flattened()
    };
    let (w32, h32) = (
        u32::try_from(w).map_err(|_| err("too wide".into()))?,
        u32::try_from(h).map_err(|_| err("too tall".into()))?,
    );
    let mut bytes = Vec::new();
    let sink = std::io::Cursor::new(&mut bytes);
    let result = match format {
        image::ImageFormat::Jpeg => {
            let mut e = image::codecs::jpeg::JpegEncoder::new_with_quality(sink, 95);
            if let Some(icc) = icc {
                let _ = e.set_icc_profile(icc);
            }
            if let Some(exif) = exif {
                let _ = e.set_exif_metadata(exif);
            }
            e.write_image(&data, w32, h32, layout)
        }
        image::ImageFormat::Png => {
            let mut e = image::codecs::png::PngEncoder::new(sink);
            if let Some(icc) = icc {
                let _ = e.set_icc_profile(icc);
            }
            if let Some(exif) = exif {
                let _ = e.set_exif_metadata(exif);
            }
            e.write_image(&data, w32, h32, layout)
        }
        _ => {
            let mut e = image::codecs::tiff::TiffEncoder::new(sink);
            if let Some(icc) = icc {
                let _ = e.set_icc_profile(icc);
            }
            e.write_image(&data, w32, h32, layout)
        }
    };
    result.map_err(|e| err(e.to_string()))?;
    crate::io::write_atomic(path, &bytes).map_err(|e| err(e.source.to_string()))
}
