//! A minimal valid DNG of a simulated Bayer shot: RGGB samples in strips or tiles,
//! uncompressed or lossless-JPEG compressed (the layouts real writers produce: cameras
//! write strips, Adobe's converter lossless-JPEG tiles), the levels, the colour tags a
//! DNG reader needs, and the lens setting as EXIF tags in IFD0 — what many real writers
//! do.

use crate::plane::LensSetting;
use std::path::Path;

/// What goes into the DNG besides the samples.
#[derive(Clone, Debug)]
pub struct DngInfo {
    pub make: String,
    pub model: String,
    pub black: u16,
    pub white: u16,
    pub setting: Option<LensSetting>,
    pub layout: DngLayout,
}

/// How the samples are laid out in the file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DngLayout {
    /// Tiles of this side instead of strips (a multiple of 16).
    pub tile: Option<usize>,
    pub compression: DngCompression,
}

/// How each strip or tile is stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DngCompression {
    /// 16-bit little-endian samples (TIFF compression 1).
    #[default]
    Uncompressed,
    /// Lossless JPEG (TIFF compression 7, ITU T.81 process 14, predictor 1), each tile
    /// (or the one strip) coded as two interleaved components of half its width, as the
    /// DNG specification and Adobe's converter store a CFA.
    LosslessJpeg,
}

/// The lossless-JPEG code of a `w × h` block of CFA samples (`w` even) with `bits` of
/// precision.
// The encoder refuses only a buffer shorter than its header's size, `h` rows of
// `w / 2` two-component samples; both sides are truncated to 16 bits, so that size is
// at most `w · h`, and every caller passes exactly `w · h` samples.
#[allow(clippy::expect_used)]
fn ljpeg_block(block: &[u16], w: usize, h: usize, bits: ljpeg::Bitdepth) -> Vec<u8> {
    let encoder = ljpeg::Encoder::new(
        (w / 2) as u16,
        h as u16,
        ljpeg::Components::C2,
        bits,
        ljpeg::Predictor::P1,
        0,
        0,
    );
    encoder
        .encode(block)
        .expect("the block holds w × h samples")
}

/// The least JPEG precision (12–16 bits, what DNG readers accept) that holds `max`.
fn ljpeg_bits(max: u16) -> ljpeg::Bitdepth {
    let needed = (16 - max.leading_zeros()).max(12);
    match needed {
        12 => ljpeg::Bitdepth::B12,
        13 => ljpeg::Bitdepth::B13,
        14 => ljpeg::Bitdepth::B14,
        15 => ljpeg::Bitdepth::B15,
        _ => ljpeg::Bitdepth::B16,
    }
}

enum Val {
    Byte(Vec<u8>),
    Ascii(String),
    Short(Vec<u16>),
    Long(Vec<u32>),
    Rational(Vec<(u32, u32)>),
    SRational(Vec<(i32, i32)>),
}

impl Val {
    fn type_count(&self) -> (u16, u32) {
        match self {
            Val::Byte(v) => (1, v.len() as u32),
            Val::Ascii(s) => (2, s.len() as u32 + 1),
            Val::Short(v) => (3, v.len() as u32),
            Val::Long(v) => (4, v.len() as u32),
            Val::Rational(v) => (5, v.len() as u32),
            Val::SRational(v) => (10, v.len() as u32),
        }
    }
    fn bytes(&self) -> Vec<u8> {
        let mut b = Vec::new();
        match self {
            Val::Byte(v) => b.extend_from_slice(v),
            Val::Ascii(s) => {
                b.extend_from_slice(s.as_bytes());
                b.push(0);
            }
            Val::Short(v) => v.iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes())),
            Val::Long(v) => v.iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes())),
            Val::Rational(v) => v.iter().for_each(|(n, d)| {
                b.extend_from_slice(&n.to_le_bytes());
                b.extend_from_slice(&d.to_le_bytes());
            }),
            Val::SRational(v) => v.iter().for_each(|(n, d)| {
                b.extend_from_slice(&n.to_le_bytes());
                b.extend_from_slice(&d.to_le_bytes());
            }),
        }
        b
    }
}

fn rational(v: f64) -> (u32, u32) {
    (
        (v * 1000.0).round().clamp(0.0, u32::MAX as f64) as u32,
        1000,
    )
}

/// The DNG file's bytes for a `width × height` RGGB mosaic (row-major, black level
/// included).
///
/// # Panics
/// Never for sizes [`write_dng`] accepts: sizes past 4 GiB of samples would not fit a
/// TIFF, and lossless JPEG needs an even width (a CFA's) and a strip or tile of at most
/// 65535 rows and 2 × 65535 columns.
#[must_use]
pub fn dng_bytes(cfa: &[u16], width: usize, height: usize, info: &DngInfo) -> Vec<u8> {
    let (w, h) = (width as u32, height as u32);
    // Image data first (after the 8-byte header), then the directory and its values.
    let mut data: Vec<u8> = Vec::with_capacity(cfa.len() * 2);
    let mut offsets = Vec::new();
    let mut counts = Vec::new();
    let base = 8u32;
    let ljpeg = info.layout.compression == DngCompression::LosslessJpeg;
    let bits = ljpeg_bits(cfa.iter().copied().max().unwrap_or(0).max(info.white));
    let mut put = |block: &[u16], w: usize, h: usize| {
        offsets.push(base + data.len() as u32);
        let before = data.len();
        if ljpeg {
            data.extend_from_slice(&ljpeg_block(block, w, h, bits));
        } else {
            block
                .iter()
                .for_each(|v| data.extend_from_slice(&v.to_le_bytes()));
        }
        counts.push((data.len() - before) as u32);
        if data.len() % 2 == 1 {
            // Keep every strip and tile at an even offset, as TIFF readers expect.
            data.push(0);
        }
    };
    // Lossless JPEG strips: one for the whole image, the only form DNG readers share.
    let rows_per_strip = if ljpeg { height } else { 64 };
    match info.layout.tile {
        Some(t) => {
            let mut block = vec![0u16; t * t];
            for ty in 0..height.div_ceil(t) {
                for tx in 0..width.div_ceil(t) {
                    // Tiles past the image's edge are padded with its last row and column
                    // (readers discard the padding; repeats code cheaply).
                    for y in 0..t {
                        let sy = (ty * t + y).min(height - 1);
                        for x in 0..t {
                            let sx = (tx * t + x).min(width - 1);
                            block[y * t + x] = cfa[sy * width + sx];
                        }
                    }
                    put(&block, t, t);
                }
            }
        }
        None => {
            for y0 in (0..height).step_by(rows_per_strip) {
                let rows = rows_per_strip.min(height - y0);
                put(&cfa[y0 * width..(y0 + rows) * width], width, rows);
            }
        }
    }
    let mut tags: Vec<(u16, Val)> = vec![
        (254, Val::Long(vec![0])),
        (256, Val::Long(vec![w])),
        (257, Val::Long(vec![h])),
        (258, Val::Short(vec![if ljpeg { bits as u16 } else { 16 }])),
        (259, Val::Short(vec![if ljpeg { 7 } else { 1 }])),
        (262, Val::Short(vec![32803])),
        (271, Val::Ascii(info.make.clone())),
        (272, Val::Ascii(info.model.clone())),
        (274, Val::Short(vec![1])),
        (277, Val::Short(vec![1])),
        (284, Val::Short(vec![1])),
        (33421, Val::Short(vec![2, 2])),
        (33422, Val::Byte(vec![0, 1, 1, 2])),
        (50706, Val::Byte(vec![1, 4, 0, 0])),
        (50707, Val::Byte(vec![1, 1, 0, 0])),
        (50708, Val::Ascii(format!("{} {}", info.make, info.model))),
        (50710, Val::Byte(vec![0, 1, 2])),
        (50711, Val::Short(vec![1])),
        (50713, Val::Short(vec![1, 1])),
        (50714, Val::Long(vec![u32::from(info.black)])),
        (50717, Val::Long(vec![u32::from(info.white)])),
        // Camera RGB is taken as linear sRGB primaries: XYZ → sRGB, ×10000.
        (
            50721,
            Val::SRational(
                [32406, -15372, -4986, -9689, 18758, 415, 557, -2040, 10570]
                    .iter()
                    .map(|&v| (v, 10000))
                    .collect(),
            ),
        ),
        (
            50728,
            Val::Rational(vec![(820, 1000), (1000, 1000), (740, 1000)]),
        ),
        (50778, Val::Short(vec![21])),
    ];
    match info.layout.tile {
        Some(t) => {
            tags.push((322, Val::Long(vec![t as u32])));
            tags.push((323, Val::Long(vec![t as u32])));
            tags.push((324, Val::Long(offsets)));
            tags.push((325, Val::Long(counts)));
        }
        None => {
            tags.push((273, Val::Long(offsets)));
            tags.push((278, Val::Long(vec![rows_per_strip as u32])));
            tags.push((279, Val::Long(counts)));
        }
    }
    if let Some(s) = info.setting {
        tags.push((33437, Val::Rational(vec![rational(s.f_number)])));
        tags.push((37386, Val::Rational(vec![rational(s.focal_mm)])));
    }
    tags.sort_by_key(|(t, _)| *t);
    let ifd_off = base + data.len() as u32;
    let ifd_len = 2 + 12 * tags.len() as u32 + 4;
    let mut extra: Vec<u8> = Vec::new();
    let mut ifd: Vec<u8> = Vec::new();
    ifd.extend_from_slice(&(tags.len() as u16).to_le_bytes());
    for (tag, val) in &tags {
        let (typ, count) = val.type_count();
        let bytes = val.bytes();
        ifd.extend_from_slice(&tag.to_le_bytes());
        ifd.extend_from_slice(&typ.to_le_bytes());
        ifd.extend_from_slice(&count.to_le_bytes());
        if bytes.len() <= 4 {
            let mut v = bytes.clone();
            v.resize(4, 0);
            ifd.extend_from_slice(&v);
        } else {
            let off = ifd_off + ifd_len + extra.len() as u32;
            ifd.extend_from_slice(&off.to_le_bytes());
            extra.extend_from_slice(&bytes);
            if extra.len() % 2 == 1 {
                extra.push(0);
            }
        }
    }
    ifd.extend_from_slice(&0u32.to_le_bytes());
    let mut out = Vec::with_capacity(8 + data.len() + ifd.len() + extra.len());
    out.extend_from_slice(b"II*\0");
    out.extend_from_slice(&ifd_off.to_le_bytes());
    out.extend_from_slice(&data);
    out.extend_from_slice(&ifd);
    out.extend_from_slice(&extra);
    out
}

/// Writes the DNG atomically (temporary file, then rename).
///
/// # Errors
/// I/O failures, or a mosaic too large for a TIFF.
pub fn write_dng(
    path: &Path,
    cfa: &[u16],
    width: usize,
    height: usize,
    info: &DngInfo,
) -> std::io::Result<()> {
    if cfa.len() != width * height
        || cfa.is_empty()
        || cfa.len() > (u32::MAX as usize - 1_000_000) / 2
    {
        return Err(std::io::Error::other(format!(
            "{}: a {width} × {height} mosaic does not fit a DNG",
            path.display()
        )));
    }
    if let Some(t) = info.layout.tile
        && (t == 0 || !t.is_multiple_of(16) || t > 65_520)
    {
        return Err(std::io::Error::other(format!(
            "{}: tile side {t} is not a multiple of 16 up to 65520",
            path.display()
        )));
    }
    if info.layout.compression == DngCompression::LosslessJpeg
        && info.layout.tile.is_none()
        && (!width.is_multiple_of(2) || width > 2 * 65_535 || height > 65_535)
    {
        return Err(std::io::Error::other(format!(
            "{}: a {width} × {height} mosaic cannot be one lossless-JPEG strip (use tiles)",
            path.display()
        )));
    }
    let bytes = dng_bytes(cfa, width, height, info);
    crate::io::write_atomic(path, &bytes).map_err(|e| e.source)
}
