//! A mosaic as lensblur measures it: one normalised plane per site of the 2 × 2 CFA,
//! and the levels and colour that go with it. Every RAW decoder's answer ends here, so
//! the rules for what a file says (whose matrix, whose white balance) are kept once.

use super::tiff::{Ifd, dng_matrix, dng_neutral, matrix_illuminant};
use super::{LoadError, check_size};
use crate::plane::{Capture, Channel, ChannelPlane, Plane, RawMeta};
use std::path::Path;

fn cfa_channel(c: usize) -> Option<Channel> {
    match c {
        0 => Some(Channel::R),
        1 => Some(Channel::G),
        2 => Some(Channel::B),
        _ => None,
    }
}

/// Normalised CFA planes: one per position of the 2 × 2 pattern, black subtracted,
/// divided by white − black (the same arithmetic the simulator uses, so a round trip is
/// exact).
fn cfa_capture(
    path: &Path,
    values: &[u16],
    (w, h): (usize, usize),
    color_at: &dyn Fn(usize, usize) -> usize,
    black: &dyn Fn(usize, usize) -> f32,
    white: f32,
) -> Result<Capture, LoadError> {
    check_size(path, w, h)?;
    if values.len() < w * h {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: format!("{} samples for a {w} × {h} sensor", values.len()),
        });
    }
    let mut planes = Vec::with_capacity(4);
    for (ox, oy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        let Some(channel) = cfa_channel(color_at(ox, oy)) else {
            return Err(LoadError::Corrupt {
                path: path.to_path_buf(),
                reason: "unsupported CFA colour (only RGB Bayer patterns)".into(),
            });
        };
        let black_f = black(ox, oy);
        let range = (white - black_f).max(1.0);
        let pw = (w + 1 - ox) / 2;
        let ph = (h + 1 - oy) / 2;
        let plane = Plane::from_fn(pw, ph, |i, j| {
            (f32::from(values[(2 * j + oy) * w + 2 * i + ox]) - black_f) / range
        });
        planes.push(ChannelPlane {
            channel,
            plane,
            step: 2,
            offset_x: ox,
            offset_y: oy,
        });
    }
    Ok(Capture::of_planes(w, h, planes, true))
}

/// What a decoder read of a mosaic's colour beyond its samples.
#[derive(Default)]
pub(super) struct DecoderColour {
    /// XYZ → camera RGB, from the decoder's camera table (D65).
    pub matrix: Option<[[f64; 3]; 3]>,
    /// White-balance multipliers as shot: R, G, B (and a fourth the decoders keep).
    pub wb: Option<[f32; 4]>,
    /// EXIF orientation code as read; anything outside 1–8 is unknown.
    pub orientation: u16,
}

/// A mosaic's planes ([`cfa_capture`]) and its [`RawMeta`]: the one place a decoder's
/// answer becomes the levels and colour a DNG is written back with. A DNG's own colour
/// tags (`ifd`: its first directory, where its raw image is) win over the decoder's,
/// which rounds them to f32 or reads none; an unknown orientation is 1 (as stored).
/// The EXIF facts come with `ExifInfo::fill`.
#[allow(clippy::too_many_arguments)]
pub(super) fn mosaic_capture(
    path: &Path,
    values: &[u16],
    size: (usize, usize),
    color_at: &dyn Fn(usize, usize) -> usize,
    black: &dyn Fn(usize, usize) -> f32,
    white: f32,
    ifd: Option<&Ifd>,
    decoded: DecoderColour,
) -> Result<Capture, LoadError> {
    let mut c = cfa_capture(path, values, size, color_at, black, white)?;
    let sites = [(0, 0), (1, 0), (0, 1), (1, 1)];
    let usable = |m: &[[f64; 3]; 3]| {
        m.iter().flatten().all(|v| v.is_finite()) && m.iter().flatten().any(|v| *v != 0.0)
    };
    // Green 1: the multipliers' reciprocals, as DNG's AsShotNeutral has them.
    let neutral = |wb: [f32; 4]| {
        wb[..3].iter().all(|v| v.is_normal() && *v > 0.0).then(|| {
            let g = f64::from(wb[1]);
            [g / f64::from(wb[0]), 1.0, g / f64::from(wb[2])]
        })
    };
    c.raw = Some(RawMeta {
        cfa: sites.map(|(x, y)| color_at(x, y).min(3) as u8),
        black: sites.map(|(x, y)| black(x, y).clamp(0.0, 65535.0) as u16),
        white: white.clamp(0.0, 65535.0) as u16,
        color_matrix: ifd.and_then(dng_matrix).or(decoded.matrix.filter(usable)),
        calibration_illuminant: ifd.map_or(21, matrix_illuminant),
        as_shot_neutral: ifd
            .and_then(dng_neutral)
            .or_else(|| decoded.wb.and_then(neutral)),
        orientation: if (1..=8).contains(&decoded.orientation) {
            decoded.orientation
        } else {
            1
        },
        ..RawMeta::default()
    });
    Ok(c)
}
