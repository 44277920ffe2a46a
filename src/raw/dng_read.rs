//! lensblur's own reader of the uncompressed 16-bit DNGs rawloader misreads: tiled
//! ones, and strips that do not follow one another in the file.

use super::cfa::{Decoded, DecoderColour, mosaic_capture};
use super::tiff::{
    Ifd, TAG_ORIENTATION, TAG_ROWS_PER_STRIP, TAG_STRIP_OFFSETS, TAG_TILE_OFFSETS, first_tag,
};
use super::{LoadError, check_size};
use crate::limits;
use std::path::Path;

/// An uncompressed 16-bit CFA DNG whose raw image is in the first directory, in tiles
/// or strips (a strip is a tile as wide as the image).
pub(super) fn read_uncompressed_dng(
    path: &Path,
    b: &[u8],
    ifd: &Ifd,
) -> Result<Decoded, LoadError> {
    let err = |reason: String| LoadError::Corrupt {
        path: path.to_path_buf(),
        reason,
    };
    let one = |tag: u16| -> Result<f64, LoadError> {
        ifd.get(&tag)
            .and_then(|v| v.first().copied())
            .ok_or_else(|| err(format!("DNG without tag {tag}")))
    };
    if one(258)? != 16.0 {
        return Err(err("only 16-bit uncompressed DNGs are read".into()));
    }
    let (w, h) = (one(256)? as usize, one(257)? as usize);
    check_size(path, w, h)?;
    // Uncompressed, every sample is in the file: a file shorter than its samples is
    // truncated, and is refused before the image is allocated.
    let needed = 2 * w * h;
    if b.len() < needed {
        return Err(err(format!(
            "truncated: a {w} × {h} 16-bit image needs {needed} bytes, the file has {}",
            b.len()
        )));
    }
    let tiled = ifd.contains_key(&TAG_TILE_OFFSETS);
    let (tw, th, offsets_tag) = if tiled {
        (one(322)? as usize, one(323)? as usize, TAG_TILE_OFFSETS)
    } else {
        let rows = ifd
            .get(&TAG_ROWS_PER_STRIP)
            .and_then(|v| v.first().copied())
            .map_or(h, |r| (r as usize).min(h));
        (w, rows, TAG_STRIP_OFFSETS)
    };
    if tw == 0 || th == 0 || tw > limits::MAX_IMAGE_SIDE || th > limits::MAX_IMAGE_SIDE {
        return Err(err(format!("absurd tile or strip size {tw} × {th}")));
    }
    let offsets = ifd.get(&offsets_tag).cloned().unwrap_or_default();
    let (across, down) = (w.div_ceil(tw), h.div_ceil(th));
    if offsets.len() < across * down {
        return Err(err(format!(
            "{} {} for a {across} × {down} grid",
            offsets.len(),
            if tiled { "tiles" } else { "strips" }
        )));
    }
    let le = b.starts_with(b"II");
    let mut values = vec![0u16; w * h];
    for ty in 0..down {
        for tx in 0..across {
            let base = offsets[ty * across + tx] as usize;
            // A strip holds only the rows it has; a tile is always whole.
            let rows = if tiled { th } else { th.min(h - ty * th) };
            if base
                .checked_add(2 * tw * rows)
                .is_none_or(|end| b.len() < end)
            {
                return Err(err(format!(
                    "truncated: a {} lies past the end of the file",
                    if tiled { "tile" } else { "strip" }
                )));
            }
            for y in 0..th.min(h - ty * th) {
                for x in 0..tw.min(w - tx * tw) {
                    let o = base + 2 * (y * tw + x);
                    let v = if le {
                        u16::from_le_bytes([b[o], b[o + 1]])
                    } else {
                        u16::from_be_bytes([b[o], b[o + 1]])
                    };
                    values[(ty * th + y) * w + tx * tw + x] = v;
                }
            }
        }
    }
    let pattern = ifd
        .get(&33422)
        .cloned()
        .unwrap_or_else(|| vec![0.0, 1.0, 1.0, 2.0]);
    if pattern.len() != 4 {
        return Err(err("only 2 × 2 CFA patterns are read".into()));
    }
    let color_at = |x: usize, y: usize| pattern[(y % 2) * 2 + x % 2] as usize;
    let blacks = ifd.get(&50714).cloned().unwrap_or_else(|| vec![0.0]);
    let black = |x: usize, y: usize| {
        let k = (y % 2) * 2 + x % 2;
        blacks.get(k).or(blacks.first()).copied().unwrap_or(0.0) as f32
    };
    let white = ifd
        .get(&50717)
        .and_then(|v| v.first().copied())
        .unwrap_or(65535.0) as f32;
    // Its colour is the DNG's own tags alone: no decoder read it.
    let colour = DecoderColour {
        orientation: first_tag(ifd, TAG_ORIENTATION).map_or(0, |v| v as u16),
        ..DecoderColour::default()
    };
    mosaic_capture(
        path,
        values,
        (w, h),
        &color_at,
        &black,
        white,
        Some(ifd),
        colour,
    )
}
