//! Writing DNGs: the one owner of the format on the way out. A Bayer mosaic in strips
//! or tiles, uncompressed or lossless-JPEG compressed (the layouts real writers
//! produce: cameras write strips, Adobe's converter lossless-JPEG tiles), with the
//! levels, CFA, colour matrix, white balance, orientation and EXIF a RAW editor needs.
//! The simulator writes its shots with it, and `deblur` writes a deblurred RAW photo
//! back as a DNG with its original's metadata ([`capture_dng`]).

use crate::plane::{CameraIdentity, Capture, LensSetting, RawMeta};
use rayon::prelude::*;
use std::path::Path;

/// What goes into the DNG besides the samples.
#[derive(Clone, Debug, PartialEq)]
pub struct DngInfo {
    /// Make, model, serial numbers and lens (Make, Model and EXIF tags).
    pub identity: CameraIdentity,
    /// Focal length and f-number (EXIF FocalLength, FNumber).
    pub setting: Option<LensSetting>,
    /// Where the lens was focused, metres, infinite for infinity (EXIF SubjectDistance).
    pub focus_m: Option<f64>,
    /// Levels, CFA, colour, orientation and the rest of the shot's EXIF.
    pub raw: RawMeta,
    /// Where the EXIF tags go: their own directory (what Adobe's converter writes) or
    /// IFD0 (what some camera writers do, and what readers must accept too).
    pub exif_in_ifd0: bool,
    /// The file the samples came from (DNG OriginalRawFileName).
    pub original_file_name: Option<String>,
    pub layout: DngLayout,
}

impl DngInfo {
    /// A simulated RGGB shot: camera and levels, the lens setting in IFD0.
    #[must_use]
    pub fn simulated(
        make: &str,
        model: &str,
        black: u16,
        white: u16,
        setting: Option<LensSetting>,
        layout: DngLayout,
    ) -> Self {
        Self {
            identity: CameraIdentity {
                make: Some(make.to_string()),
                model: Some(model.to_string()),
                ..CameraIdentity::default()
            },
            setting,
            focus_m: None,
            raw: RawMeta::rggb(black, white),
            exif_in_ifd0: true,
            original_file_name: None,
            layout,
        }
    }
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
    Undefined(Vec<u8>),
    Rational(Vec<(u32, u32)>),
    SRational(Vec<(i32, i32)>),
}

impl Val {
    fn type_count(&self) -> (u16, u32) {
        match self {
            Val::Byte(v) => (1, v.len() as u32),
            Val::Ascii(s) => (2, s.len() as u32 + 1),
            Val::Short(v) => (3, v.len() as u32),
            Val::Undefined(v) => (7, v.len() as u32),
            Val::Long(v) => (4, v.len() as u32),
            Val::Rational(v) => (5, v.len() as u32),
            Val::SRational(v) => (10, v.len() as u32),
        }
    }
    fn bytes(&self) -> Vec<u8> {
        let mut b = Vec::new();
        match self {
            Val::Byte(v) | Val::Undefined(v) => b.extend_from_slice(v),
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

/// The nearest fraction to `v` with a denominator of at most 10⁶ (continued
/// fractions): exact for the fractions cameras write (1/250 s, 5.6, 0.4711), so a
/// value read from a RAW file is written back as it was.
fn best_fraction(v: f64) -> (i64, i64) {
    const MAX_DEN: i64 = 1_000_000;
    if !v.is_finite() {
        return (0, 1);
    }
    let sign = if v < 0.0 { -1 } else { 1 };
    let x = v.abs();
    let (mut h0, mut h1, mut k0, mut k1) = (0i64, 1i64, 1i64, 0i64);
    let mut r = x;
    for _ in 0..40 {
        let a = r.floor();
        if a > 4.0e9 {
            break;
        }
        let a = a as i64;
        let (h2, k2) = (a * h1 + h0, a * k1 + k0);
        if k2 > MAX_DEN {
            break;
        }
        (h0, h1, k0, k1) = (h1, h2, k1, k2);
        let frac = r - a as f64;
        if frac < 1e-12 || (h1 as f64 / k1 as f64 - x).abs() <= 1e-12 * x.max(1.0) {
            break;
        }
        r = 1.0 / frac;
    }
    if k1 == 0 {
        (sign * h0, 1)
    } else {
        (sign * h1, k1)
    }
}

fn rational(v: f64) -> (u32, u32) {
    let (n, d) = best_fraction(v.max(0.0));
    (
        u32::try_from(n).unwrap_or(u32::MAX),
        u32::try_from(d).unwrap_or(1),
    )
}

fn srational(v: f64) -> (i32, i32) {
    let (n, d) = best_fraction(v);
    (
        i32::try_from(n).unwrap_or(if n < 0 { i32::MIN } else { i32::MAX }),
        i32::try_from(d).unwrap_or(1),
    )
}

/// An XMP packet saying what lensblur did (dc:description, read by Lightroom,
/// darktable and digiKam as the caption) and with which tool (xmp:CreatorTool).
fn xmp_packet(description: &str) -> Vec<u8> {
    let escaped = description
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;");
    format!(
        "<?xpacket begin=\"\u{feff}\" id=\"W5M0MpCehiHzreSzNTczkc9d\"?>\n\
         <x:xmpmeta xmlns:x=\"adobe:ns:meta/\">\n \
         <rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n  \
         <rdf:Description rdf:about=\"\" xmlns:xmp=\"http://ns.adobe.com/xap/1.0/\" \
         xmlns:dc=\"http://purl.org/dc/elements/1.1/\" xmp:CreatorTool=\"{SOFTWARE}\">\n   \
         <dc:description><rdf:Alt><rdf:li xml:lang=\"x-default\">{escaped}</rdf:li></rdf:Alt></dc:description>\n  \
         </rdf:Description>\n </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end=\"w\"?>"
    )
    .into_bytes()
}

/// What the Software tag and the XMP packet name.
pub const SOFTWARE: &str = concat!("lensblur ", env!("CARGO_PKG_VERSION"));

/// Tag 34665: where IFD0 points to the EXIF directory.
const TAG_EXIF_IFD: u16 = 34665;

/// One TIFF directory and the values that do not fit its entries, laid out to start
/// at byte `at` of the file.
fn ifd_bytes(tags: &[(u16, Val)], at: u32) -> Vec<u8> {
    let ifd_len = 2 + 12 * tags.len() as u32 + 4;
    let mut extra: Vec<u8> = Vec::new();
    let mut ifd: Vec<u8> = Vec::new();
    ifd.extend_from_slice(&(tags.len() as u16).to_le_bytes());
    for (tag, val) in tags {
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
            let off = at + ifd_len + extra.len() as u32;
            ifd.extend_from_slice(&off.to_le_bytes());
            extra.extend_from_slice(&bytes);
            if extra.len() % 2 == 1 {
                extra.push(0);
            }
        }
    }
    ifd.extend_from_slice(&0u32.to_le_bytes());
    ifd.extend_from_slice(&extra);
    ifd
}

/// The EXIF tags of a shot: settings, exposure, date, lens and serials.
fn exif_tags(info: &DngInfo) -> Vec<(u16, Val)> {
    let id = &info.identity;
    let raw = &info.raw;
    let mut tags = Vec::new();
    if let Some(t) = raw.exposure_s {
        tags.push((33434, Val::Rational(vec![rational(t)])));
    }
    if let Some(s) = info.setting {
        tags.push((33437, Val::Rational(vec![rational(s.f_number)])));
        tags.push((37386, Val::Rational(vec![rational(s.focal_mm)])));
    }
    // EXIF writes infinity as 0xFFFFFFFF/1.
    match info.focus_m {
        Some(m) if m.is_infinite() => tags.push((37382, Val::Rational(vec![(u32::MAX, 1)]))),
        Some(m) if m.is_finite() && m > 0.0 => {
            tags.push((37382, Val::Rational(vec![rational(m)])));
        }
        _ => {}
    }
    if let Some(iso) = raw.iso {
        tags.push((
            34855,
            Val::Short(vec![u16::try_from(iso).unwrap_or(u16::MAX)]),
        ));
    }
    if let Some(d) = &raw.date_time_original {
        tags.push((36867, Val::Ascii(d.clone())));
    }
    let text = |tag: u16, v: &Option<String>, tags: &mut Vec<(u16, Val)>| {
        if let Some(v) = v {
            tags.push((tag, Val::Ascii(v.clone())));
        }
    };
    text(42033, &id.body_serial, &mut tags);
    text(42035, &raw.lens_make, &mut tags);
    if let Some(f) = raw.focal_35mm {
        tags.push((
            41989,
            Val::Short(vec![f.round().clamp(0.0, 65535.0) as u16]),
        ));
    }
    if let Some(spec) = raw.lens_specification {
        tags.push((
            42034,
            Val::Rational(spec.iter().map(|&v| rational(v)).collect()),
        ));
    }
    text(42036, &id.lens_model, &mut tags);
    text(42037, &id.lens_serial, &mut tags);
    tags
}

/// The mosaic's strips or tiles as the file holds them, from byte `base` on.
struct ImageData {
    data: Vec<u8>,
    offsets: Vec<u32>,
    counts: Vec<u32>,
    rows_per_strip: usize,
}

/// The mosaic cut into `info`'s strips or tiles, each uncompressed or lossless JPEG of
/// `bits` bits, at even offsets from `base`.
fn image_data(
    cfa: &[u16],
    width: usize,
    height: usize,
    info: &DngInfo,
    base: u32,
    bits: ljpeg::Bitdepth,
) -> ImageData {
    let mut data: Vec<u8> = Vec::with_capacity(cfa.len() * 2);
    let mut offsets = Vec::new();
    let mut counts = Vec::new();
    let ljpeg = info.layout.compression == DngCompression::LosslessJpeg;
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
    ImageData {
        data,
        offsets,
        counts,
        rows_per_strip,
    }
}

/// IFD0's tags that describe the mosaic and the camera (not where its data lies).
fn mosaic_tags(info: &DngInfo, w: u32, h: u32, bits: ljpeg::Bitdepth) -> Vec<(u16, Val)> {
    let raw = &info.raw;
    let ljpeg = info.layout.compression == DngCompression::LosslessJpeg;
    let make = info.identity.make.clone().unwrap_or_default();
    let model = info.identity.model.clone().unwrap_or_default();
    let unique = format!("{make} {model}").trim().to_string();
    let one_black = raw.black.iter().all(|&b| b == raw.black[0]);
    let mut tags: Vec<(u16, Val)> = vec![
        (254, Val::Long(vec![0])),
        (256, Val::Long(vec![w])),
        (257, Val::Long(vec![h])),
        (258, Val::Short(vec![if ljpeg { bits as u16 } else { 16 }])),
        (259, Val::Short(vec![if ljpeg { 7 } else { 1 }])),
        (262, Val::Short(vec![32803])),
        (271, Val::Ascii(make)),
        (272, Val::Ascii(model)),
        (274, Val::Short(vec![raw.orientation.clamp(1, 8)])),
        (277, Val::Short(vec![1])),
        (284, Val::Short(vec![1])),
        (33421, Val::Short(vec![2, 2])),
        (33422, Val::Byte(raw.cfa.to_vec())),
        (50706, Val::Byte(vec![1, 4, 0, 0])),
        (50707, Val::Byte(vec![1, 1, 0, 0])),
        (
            50708,
            Val::Ascii(if unique.is_empty() {
                "unknown camera".into()
            } else {
                unique
            }),
        ),
        (50710, Val::Byte(vec![0, 1, 2])),
        (50711, Val::Short(vec![1])),
        (
            50713,
            Val::Short(if one_black { vec![1, 1] } else { vec![2, 2] }),
        ),
        (
            50714,
            Val::Long(if one_black {
                vec![u32::from(raw.black[0])]
            } else {
                raw.black.iter().map(|&b| u32::from(b)).collect()
            }),
        ),
        (50717, Val::Long(vec![u32::from(raw.white)])),
    ];
    if let Some(m) = raw.color_matrix {
        tags.push((
            50721,
            Val::SRational(m.iter().flatten().map(|&v| srational(v)).collect()),
        ));
        tags.push((50778, Val::Short(vec![raw.calibration_illuminant])));
    }
    if let Some(n) = raw.as_shot_neutral {
        tags.push((
            50728,
            Val::Rational(n.iter().map(|&v| rational(v)).collect()),
        ));
    }
    if let Some(d) = &raw.description {
        tags.push((270, Val::Ascii(d.clone())));
        tags.push((305, Val::Ascii(SOFTWARE.into())));
        tags.push((700, Val::Byte(xmp_packet(d))));
    }
    if let Some(name) = &info.original_file_name {
        tags.push((50827, Val::Ascii(name.clone())));
    }
    tags
}

/// The DNG file's bytes for a `width × height` Bayer mosaic (row-major, black level
/// included) with `info`'s metadata.
///
/// # Panics
/// Never for sizes [`write_dng`] accepts: sizes past 4 GiB of samples would not fit a
/// TIFF, and lossless JPEG needs an even width (a CFA's) and a strip or tile of at most
/// 65535 rows and 2 × 65535 columns.
#[must_use]
pub fn dng_bytes(cfa: &[u16], width: usize, height: usize, info: &DngInfo) -> Vec<u8> {
    let base = 8u32;
    let bits = ljpeg_bits(cfa.iter().copied().max().unwrap_or(0).max(info.raw.white));
    // Image data first (after the 8-byte header), then the directories and their values.
    let ImageData {
        data,
        offsets,
        counts,
        rows_per_strip,
    } = image_data(cfa, width, height, info, base, bits);
    let mut tags = mosaic_tags(info, width as u32, height as u32, bits);
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
    let exif = exif_tags(info);
    let ifd0_off = base + data.len() as u32;
    let mut exif_block = Vec::new();
    if info.exif_in_ifd0 {
        tags.extend(exif);
    } else if !exif.is_empty() {
        let mut exif = exif;
        exif.push((36864, Val::Undefined(b"0231".to_vec())));
        exif.sort_by_key(|(t, _)| *t);
        // The pointer's value is inline, so IFD0's length does not depend on it.
        tags.push((TAG_EXIF_IFD, Val::Long(vec![0])));
        tags.sort_by_key(|(t, _)| *t);
        let exif_off = ifd0_off + ifd_bytes(&tags, ifd0_off).len() as u32;
        for (t, v) in &mut tags {
            if *t == TAG_EXIF_IFD {
                *v = Val::Long(vec![exif_off]);
            }
        }
        exif_block = ifd_bytes(&exif, exif_off);
    }
    tags.sort_by_key(|(t, _)| *t);
    let ifd0 = ifd_bytes(&tags, ifd0_off);
    let mut out = Vec::with_capacity(8 + data.len() + ifd0.len() + exif_block.len());
    out.extend_from_slice(b"II*\0");
    out.extend_from_slice(&ifd0_off.to_le_bytes());
    out.extend_from_slice(&data);
    out.extend_from_slice(&ifd0);
    out.extend_from_slice(&exif_block);
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

#[derive(Debug, thiserror::Error)]
pub enum DngError {
    #[error("{}: a DNG needs a RAW photo (this is {kind})", path.display())]
    NotRaw {
        path: std::path::PathBuf,
        kind: &'static str,
    },
    #[error("{}: cannot write: {reason}", path.display())]
    Write {
        path: std::path::PathBuf,
        reason: String,
    },
}

/// A RAW capture's CFA planes as the mosaic they came from: each site's value times
/// its white − black, plus its black (the inverse of the loader's normalisation, in
/// the same f32 arithmetic, so a capture loaded from a DNG gives back its samples
/// exactly). Values past the sensor's range (a deblurred highlight's overshoot, the
/// ringing below black) are clipped to 0 and the white level, as a sensor would.
///
/// `None` unless the capture is a Bayer mosaic with its RAW metadata.
#[must_use]
pub fn mosaic(capture: &Capture) -> Option<Vec<u16>> {
    let raw = capture.raw.as_ref()?;
    let (w, h) = (capture.width, capture.height);
    if !capture.is_raw || capture.planes.len() != 4 {
        return None;
    }
    // Each of the four sites' plane, its black and its range; a site no plane covers,
    // or a plane too small for the sensor, leaves the mosaic incomplete.
    let mut sites: [Option<(&crate::plane::Plane, f32, f32)>; 4] = [None; 4];
    for cp in &capture.planes {
        if cp.step != 2 || cp.offset_x > 1 || cp.offset_y > 1 {
            return None;
        }
        let site = RawMeta::site(cp.offset_x, cp.offset_y);
        let black = f32::from(raw.black[site]);
        let range = (f32::from(raw.white) - black).max(1.0);
        sites[site] = Some((&cp.plane, black, range));
    }
    for (s, site) in sites.iter().enumerate() {
        // The samples of site s along each side: x = 2i + s % 2 < w, y = 2j + s / 2 < h.
        let (nx, ny) = ((w + 1 - s % 2) / 2, (h + 1 - s / 2) / 2);
        let holds = site.is_some_and(|(p, ..)| p.width >= nx && p.height >= ny);
        if nx > 0 && ny > 0 && !holds {
            return None;
        }
    }
    if w == 0 {
        return Some(Vec::new());
    }
    let white = f32::from(raw.white);
    let mut out = vec![0u16; w * h];
    // Row-parallel: a writer's serial pass over 24 M samples otherwise.
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            if let Some((plane, black, range)) = sites[RawMeta::site(x, y)] {
                let v = (plane.get(x / 2, y / 2) * range + black).round();
                *o = v.clamp(0.0, white) as u16;
            }
        }
    });
    Some(out)
}

/// Writes a RAW capture (a deblurred photo) as an uncompressed DNG with its original's
/// metadata, plus `description` saying how it was made (ImageDescription, and XMP's
/// dc:description for editors that show a caption).
///
/// # Errors
/// The capture is not a Bayer RAW with its metadata, or the file cannot be written.
pub fn write_capture_dng(
    path: &Path,
    capture: &Capture,
    description: &str,
    original_file_name: Option<String>,
) -> Result<(), DngError> {
    let Some(raw) = capture.raw.clone().filter(|_| capture.is_raw) else {
        return Err(DngError::NotRaw {
            path: path.to_path_buf(),
            kind: if capture.is_raw {
                "a RAW without its metadata"
            } else {
                "an RGB image"
            },
        });
    };
    let Some(cfa) = mosaic(capture) else {
        return Err(DngError::NotRaw {
            path: path.to_path_buf(),
            kind: "not a 2 × 2 Bayer mosaic",
        });
    };
    let setting = match (capture.setting_focal_mm, capture.setting_f_number) {
        (Some(focal_mm), Some(f_number)) => Some(LensSetting { focal_mm, f_number }),
        _ => None,
    };
    let info = DngInfo {
        identity: capture.identity.clone(),
        setting,
        focus_m: capture.setting_focus_m,
        raw: RawMeta {
            description: Some(description.to_string()),
            ..raw
        },
        exif_in_ifd0: false,
        original_file_name,
        layout: DngLayout::default(),
    };
    write_dng(path, &cfa, capture.width, capture.height, &info).map_err(|e| DngError::Write {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A DNG's capture gives back its mosaic sample for sample, at even and odd sides
    /// (where the sites' planes differ in size); with a site's plane missing or too
    /// small for the sensor, there is no mosaic.
    #[test]
    fn a_captures_mosaic_is_the_one_it_was_loaded_from() {
        let dir = tempfile::tempdir().expect("temp dir");
        for (w, h) in [(64, 48), (37, 23), (17, 16)] {
            let cfa: Vec<u16> = (0..w * h)
                .map(|k| (600 + (k * 7919) % 15000) as u16)
                .collect();
            let info = DngInfo::simulated("Virtual", "Sim", 512, 16383, None, DngLayout::default());
            let path = dir.path().join(format!("m{w}x{h}.dng"));
            write_dng(&path, &cfa, w, h, &info).expect("write");
            let cap = crate::raw::load_capture(&path, &Default::default()).expect("load");
            assert_eq!(mosaic(&cap).as_deref(), Some(&cfa[..]), "{w} × {h}");
            let mut short = cap.clone();
            let p = &mut short.planes[3].plane;
            p.width -= 1;
            p.data.truncate(p.width * p.height);
            assert_eq!(mosaic(&short), None, "{w} × {h}, a plane too narrow");
            let mut doubled = cap.clone();
            doubled.planes[3] = doubled.planes[0].clone();
            assert_eq!(mosaic(&doubled), None, "{w} × {h}, a site twice");
        }
    }

    #[test]
    fn fractions_written_are_the_ones_read() {
        for (v, n, d) in [
            (0.004, 1, 250),
            (5.6, 28, 5),
            (1.0 / 3.0, 1, 3),
            (-0.4986, -2493, 5000),
            (0.0, 0, 1),
            (35.0, 35, 1),
        ] {
            assert_eq!(best_fraction(v), (n, d), "{v}");
        }
        // No exact fraction: the nearest within a denominator of 10⁶.
        let (n, d) = best_fraction(std::f64::consts::PI);
        assert!(d <= 1_000_000 && (n as f64 / d as f64 - std::f64::consts::PI).abs() < 1e-11);
    }
}
