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

/// A CFA mosaic as its decoder read it: the active area's samples and what makes them
/// lensblur's planes ([`MosaicLayout`]). Kept so until the planes are made: it is half
/// their size, which is what a worker process hands its parent (`wire`).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Mosaic {
    pub layout: MosaicLayout,
    pub values: Vec<u16>,
}

/// A mosaic's size and its 2 × 2 sites (in [`RawMeta::site`] order): each one's
/// channel, black level, and the white level they share.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct MosaicLayout {
    pub width: usize,
    pub height: usize,
    pub channels: [Channel; 4],
    pub black: [f32; 4],
    pub white: f32,
}

impl MosaicLayout {
    /// Normalised CFA planes of `values` (`width × height` samples, row by row): one per
    /// site, black subtracted, divided by white − black (the same arithmetic the
    /// simulator uses, so a round trip is exact).
    pub(super) fn planes(&self, values: &[u16]) -> Vec<ChannelPlane> {
        let (w, h) = (self.width, self.height);
        debug_assert!(values.len() >= w * h);
        [(0, 0), (1, 0), (0, 1), (1, 1)]
            .into_iter()
            .map(|(ox, oy)| {
                let site = RawMeta::site(ox, oy);
                let black = self.black[site];
                let range = (self.white - black).max(1.0);
                let plane = Plane::from_fn((w + 1 - ox) / 2, (h + 1 - oy) / 2, |i, j| {
                    (f32::from(values[(2 * j + oy) * w + 2 * i + ox]) - black) / range
                });
                ChannelPlane {
                    channel: self.channels[site],
                    plane,
                    step: 2,
                    offset_x: ox,
                    offset_y: oy,
                }
            })
            .collect()
    }
}

/// What a decoder gives: a capture, whose planes are still a [`Mosaic`] where it read
/// one (the capture's own planes are then empty).
#[derive(Debug)]
pub(super) struct Decoded {
    pub capture: Capture,
    pub mosaic: Option<Mosaic>,
}

impl Decoded {
    /// A capture whose planes are made already.
    pub(super) fn planes(capture: Capture) -> Self {
        Self {
            capture,
            mosaic: None,
        }
    }

    /// The capture with its planes.
    pub(super) fn into_capture(self) -> Capture {
        let mut capture = self.capture;
        if let Some(m) = self.mosaic {
            capture.planes = m.layout.planes(&m.values);
        }
        capture
    }
}

/// A mosaic of `values` and the capture it will be, planes to come; refused where it
/// is too large, short of samples, or not an RGB Bayer pattern.
fn cfa_mosaic(
    path: &Path,
    values: Vec<u16>,
    (w, h): (usize, usize),
    color_at: &dyn Fn(usize, usize) -> usize,
    black: &dyn Fn(usize, usize) -> f32,
    white: f32,
) -> Result<Decoded, LoadError> {
    check_size(path, w, h)?;
    if values.len() < w * h {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: format!("{} samples for a {w} × {h} sensor", values.len()),
        });
    }
    let sites = [(0, 0), (1, 0), (0, 1), (1, 1)];
    let mut channels = [Channel::G; 4];
    for (site, (x, y)) in channels.iter_mut().zip(sites) {
        *site = cfa_channel(color_at(x, y)).ok_or_else(|| LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: "unsupported CFA colour (only RGB Bayer patterns)".into(),
        })?;
    }
    let layout = MosaicLayout {
        width: w,
        height: h,
        channels,
        black: sites.map(|(x, y)| black(x, y)),
        white,
    };
    Ok(Decoded {
        capture: Capture::of_planes(w, h, Vec::new(), true),
        mosaic: Some(Mosaic { layout, values }),
    })
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

/// A mosaic ([`cfa_mosaic`]) and its [`RawMeta`]: the one place a decoder's
/// answer becomes the levels and colour a DNG is written back with. A DNG's own colour
/// tags (`ifd`: its first directory, where its raw image is) win over the decoder's,
/// which rounds them to f32 or reads none; an unknown orientation is 1 (as stored).
/// The EXIF facts come with `ExifInfo::fill`.
#[allow(clippy::too_many_arguments)]
pub(super) fn mosaic_capture(
    path: &Path,
    values: Vec<u16>,
    size: (usize, usize),
    color_at: &dyn Fn(usize, usize) -> usize,
    black: &dyn Fn(usize, usize) -> f32,
    white: f32,
    ifd: Option<&Ifd>,
    decoded: DecoderColour,
) -> Result<Decoded, LoadError> {
    let mut d = cfa_mosaic(path, values, size, color_at, black, white)?;
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
    d.capture.raw = Some(RawMeta {
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
    Ok(d)
}
