//! PNG, TIFF and JPEG pictures through image-rs, held to lensblur's limits.

use super::{Encoding, LoadError, LoadOptions, check_size};
use crate::limits;
use crate::plane::{Capture, Channel, ChannelPlane, Plane, srgb_decode};
use std::path::Path;

/// image-rs's reader of a PNG/TIFF/JPEG, held to our limits (its own default would
/// refuse a 100 MP 16-bit TIFF).
pub(super) fn image_reader<'a>(
    path: &Path,
    bytes: &'a [u8],
) -> Result<image::ImageReader<std::io::Cursor<&'a [u8]>>, LoadError> {
    let mut r = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| LoadError::Unreadable {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    let mut l = image::Limits::default();
    l.max_image_width = u32::try_from(limits::MAX_IMAGE_SIDE).ok();
    l.max_image_height = u32::try_from(limits::MAX_IMAGE_SIDE).ok();
    // RGBA at 16 bits is the widest buffer a photo decodes to.
    l.max_alloc = Some(limits::MAX_IMAGE_PIXELS as u64 * 8);
    r.limits(l);
    Ok(r)
}

/// A PNG/TIFF/JPEG's size from its header alone.
pub(super) fn image_dimensions(path: &Path, bytes: &[u8]) -> Result<(usize, usize), LoadError> {
    image_reader(path, bytes)?
        .into_dimensions()
        .map(|(w, h)| (w as usize, h as usize))
        .map_err(|e| LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: image_error_words(&e),
        })
}

/// A decoder's failure in words: image-rs's decoding errors print the decoder's
/// internal state (a PNG chunk's fields, as Rust debug output), which tells a
/// photographer nothing but that the file is damaged.
pub(super) fn image_error_words(e: &image::ImageError) -> String {
    match e {
        image::ImageError::Decoding(d) => match d.format_hint() {
            image::error::ImageFormatHint::Exact(f) => format!(
                "the {} data is damaged or truncated",
                f.extensions_str()
                    .first()
                    .copied()
                    .unwrap_or("image")
                    .to_uppercase()
            ),
            _ => "the image data is damaged or truncated".into(),
        },
        other => other.to_string(),
    }
}

/// PNG/TIFF/JPEG into linear planes: one `Y` plane for grey images, R, G, B otherwise.
/// The size is checked from the header before anything is decoded, and the decoder is
/// held to the same limits (image-rs's own default would refuse a 100 MP 16-bit TIFF).
pub(super) fn load_image(
    path: &Path,
    bytes: &[u8],
    options: &LoadOptions,
) -> Result<Capture, LoadError> {
    let corrupt = |e: image::ImageError| LoadError::Corrupt {
        path: path.to_path_buf(),
        reason: image_error_words(&e),
    };
    let (w, h) = image_dimensions(path, bytes)?;
    check_size(path, w, h)?;
    let img = image_reader(path, bytes)?.decode().map_err(corrupt)?;
    if (img.width() as usize, img.height() as usize) != (w, h) {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: "the decoded image differs in size from its header".into(),
        });
    }
    let color = img.color();
    let grey = !color.has_color();
    let decode_srgb =
        color.bytes_per_pixel() / color.channel_count() == 1 && options.encoding == Encoding::Auto;
    // Straight from the decoder's buffer, not through a converted copy: a 100 MP photo
    // would otherwise hold a third full-size image in memory while its planes are made.
    let (data, cc) = (img.as_bytes(), usize::from(color.channel_count()));
    let bytes_per_sample = usize::from(color.bytes_per_pixel()) / cc;
    let float = matches!(color, image::ColorType::Rgb32F | image::ColorType::Rgba32F);
    let sample = |k: usize| -> f32 {
        match bytes_per_sample {
            1 => f32::from(data[k]) / 255.0,
            2 => f32::from(u16::from_ne_bytes([data[2 * k], data[2 * k + 1]])) / 65535.0,
            4 if float => f32::from_ne_bytes([
                data[4 * k],
                data[4 * k + 1],
                data[4 * k + 2],
                data[4 * k + 3],
            ]),
            _ => 0.0,
        }
    };
    if !matches!(bytes_per_sample, 1 | 2) && !float {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: format!("unsupported sample format {color:?}"),
        });
    }
    let channels: &[(Channel, usize)] = if grey {
        &[(Channel::Y, 0)]
    } else {
        &[(Channel::R, 0), (Channel::G, 1), (Channel::B, 2)]
    };
    let planes = channels
        .iter()
        .map(|&(channel, c)| ChannelPlane {
            channel,
            plane: Plane::par_from_fn(w, h, |x, y| {
                let v = sample((y * w + x) * cc + c);
                if decode_srgb { srgb_decode(v) } else { v }
            }),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        })
        .collect();
    Ok(Capture::of_planes(w, h, planes, false))
}
