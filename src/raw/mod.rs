//! Loading shots and photos into linear channel planes (docs/formats.md, "Images and
//! RAW files lensblur reads").
//!
//! RAW files keep their CFA: each colour site becomes its own plane at half resolution
//! (black subtracted, divided by white − black), so blur is measured before any
//! demosaicing or colour matrixing. 16-bit and float PNG/TIFF are taken as linear;
//! 8-bit images are sRGB-decoded unless the caller says they are linear.

use crate::limits;
use crate::plane::{Capture, Channel, ChannelPlane, Plane, RawMeta, srgb_decode, srgb_encode};
use std::path::{Path, PathBuf};

mod damage;
mod decoders;
mod info;

pub use decoders::{DecodedMeta, Decoder};
pub use info::{FileInfo, FocusDistance, INFO_SCHEMA, inspect, inspect_bytes};

#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("{}: cannot read: {reason}", path.display())]
    Unreadable { path: PathBuf, reason: String },
    /// Not an image we read, or one malformed in a way [`LoadError::Damaged`] does not
    /// locate.
    #[error("{}: unreadable image: {reason}", path.display())]
    Corrupt { path: PathBuf, reason: String },
    /// The file ends before its own structure says it does, or a part of it points
    /// past its end: a cut-short copy, not a camera we do not know.
    #[error("{}: damaged file: {reason}", path.display())]
    Damaged { path: PathBuf, reason: String },
    /// A well-formed file of a camera or a layout no decoder reads; the reason says
    /// what to do.
    #[error("{}: {reason}", path.display())]
    Unsupported { path: PathBuf, reason: String },
    /// The file decodes, but to no picture: missing image data decoded as zeros, or
    /// every sample the same.
    #[error("{}: no image: {reason}", path.display())]
    NoImage { path: PathBuf, reason: String },
    #[error("{}: {reason}", path.display())]
    TooLarge { path: PathBuf, reason: String },
}

impl From<crate::io::ReadError> for LoadError {
    fn from(e: crate::io::ReadError) -> Self {
        match e {
            crate::io::ReadError::Io { path, source } => LoadError::Unreadable {
                path,
                reason: source.to_string(),
            },
            crate::io::ReadError::TooLarge { path, bytes, limit } => LoadError::TooLarge {
                path,
                reason: format!("{bytes} bytes, above the limit of {limit} bytes for an image"),
            },
        }
    }
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
///
/// # Errors
/// The file cannot be read, is larger than [`limits::MAX_IMAGE_FILE_BYTES`], declares
/// an image outside [`limits::check_image_size`], or is not an image we read.
pub fn load_capture(path: &Path, options: &LoadOptions) -> Result<Capture, LoadError> {
    let bytes = crate::io::read_limited(path, limits::MAX_IMAGE_FILE_BYTES)?;
    decode_capture(path, &bytes, options)
}

/// [`load_capture`] on a file's bytes; `path` only names the file in messages.
///
/// # Errors
/// As [`load_capture`].
pub fn decode_capture(
    path: &Path,
    bytes: &[u8],
    options: &LoadOptions,
) -> Result<Capture, LoadError> {
    decode_with_decoder(path, bytes, options).map(|(c, _, _)| c)
}

/// [`decode_capture`], and which decoder read the file, and what it and EXIF say.
fn decode_with_decoder(
    path: &Path,
    bytes: &[u8],
    options: &LoadOptions,
) -> Result<(Capture, Decoder, ExifInfo), LoadError> {
    if bytes.is_empty() {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: "the file is empty".into(),
        });
    }
    let is_png = bytes.starts_with(b"\x89PNG");
    let is_jpeg = bytes.starts_with(&[0xFF, 0xD8]);
    let image = |bytes| {
        load_image(path, bytes, options).map(|c| (c, Decoder::Image, DecodedMeta::default()))
    };
    let (mut capture, decoder, meta) = if is_png || is_jpeg {
        image(bytes)?
    } else if is_tiff(bytes) {
        let ifd = tiff_ifd0(bytes).map_err(|reason| damaged(path, bytes, reason))?;
        if is_raw_ifd(&ifd) {
            load_raw(path, bytes, Some(&ifd))?
        } else if decoders::camera_raw(bytes) {
            // A camera's TIFF-based RAW (CR2, NEF, ARW, PEF, ...): its first directory
            // is a preview, the CFA is further in. Where the RAW decoders refuse it and
            // that first directory is a full-size picture of its own (a TIFF an editor
            // exported, which keeps the camera's Make), it is read as the picture.
            match load_raw(path, bytes, None) {
                Ok(found) => found,
                Err(e) if image_in_ifd0(&ifd) => image(bytes).map_err(|_| e)?,
                Err(e) => return Err(e),
            }
        } else {
            image(bytes)?
        }
    } else {
        // Every other camera format goes to the RAW decoders, which name what they
        // cannot read.
        load_raw(path, bytes, None)?
    };
    let mut exif = read_exif(bytes);
    exif.take_decoded(&meta);
    exif.clone().fill(&mut capture);
    Ok((capture, decoder, exif))
}

/// What a photo's header says, read without decoding its image: enough to decide what
/// to do with it (which profile, whether its output is already there) before paying
/// for the decode.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// The active area, as [`load_capture`] would load it.
    pub width: usize,
    pub height: usize,
    pub is_raw: bool,
    pub exif: ExifInfo,
}

/// Reads a photo's [`Header`]: the file's bytes, but only its headers parsed (the RAW
/// decoder's header-only pass, image-rs's dimensions), and its EXIF.
///
/// # Errors
/// As [`load_capture`], for what the headers show.
pub fn read_header(path: &Path) -> Result<Header, LoadError> {
    let bytes = crate::io::read_limited(path, limits::MAX_IMAGE_FILE_BYTES)?;
    decode_header(path, &bytes)
}

/// [`read_header`] on a file's bytes; `path` only names the file in messages.
///
/// # Errors
/// As [`read_header`].
pub fn decode_header(path: &Path, bytes: &[u8]) -> Result<Header, LoadError> {
    if bytes.is_empty() {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: "the file is empty".into(),
        });
    }
    let corrupt = |reason: String| LoadError::Corrupt {
        path: path.to_path_buf(),
        reason,
    };
    let mut exif = read_exif(bytes);
    let ((width, height), is_raw) =
        if bytes.starts_with(b"\x89PNG") || bytes.starts_with(&[0xFF, 0xD8]) {
            (image_dimensions(path, bytes)?, false)
        } else if is_tiff(bytes) {
            let ifd = tiff_ifd0(bytes).map_err(|reason| damaged(path, bytes, reason))?;
            if !is_raw_ifd(&ifd) && decoders::camera_raw(bytes) {
                match raw_dimensions(path, bytes, &mut exif) {
                    Ok(size) => (size, true),
                    Err(e) if image_in_ifd0(&ifd) => {
                        (image_dimensions(path, bytes).map_err(|_| e)?, false)
                    }
                    Err(e) => return Err(e),
                }
            } else if !is_raw_ifd(&ifd) {
                (image_dimensions(path, bytes)?, false)
            } else if needs_own_reader(&ifd) {
                let one = |tag: u16| {
                    ifd.get(&tag)
                        .and_then(|v| v.first().copied())
                        .ok_or_else(|| corrupt(format!("DNG without tag {tag}")))
                };
                ((one(256)? as usize, one(257)? as usize), true)
            } else {
                (raw_dimensions(path, bytes, &mut exif)?, true)
            }
        } else {
            (raw_dimensions(path, bytes, &mut exif)?, true)
        };
    check_size(path, width, height)?;
    Ok(Header {
        width,
        height,
        is_raw,
        exif,
    })
}

/// The active area the RAW decoders' header-only passes find (rawler's, else
/// rawloader's), and the camera's names where EXIF gave none (as [`load_capture`]
/// fills them).
fn raw_dimensions(
    path: &Path,
    bytes: &[u8],
    exif: &mut ExifInfo,
) -> Result<(usize, usize), LoadError> {
    let _quiet = QuietPanics::new();
    let (size, make, model) = match decoders::rawler_header(path, bytes)? {
        Some(found) => found,
        None => {
            let head = std::panic::catch_unwind(|| {
                rawloader::decode_dummy(&mut std::io::Cursor::new(bytes))
            })
            .map_err(|_| LoadError::Corrupt {
                path: path.to_path_buf(),
                reason: "the RAW decoder stopped on malformed data".into(),
            })?
            .map_err(|e| LoadError::Corrupt {
                path: path.to_path_buf(),
                reason: format!("RAW decoder: {}", one_line(&e.to_string())),
            })?;
            let [top, right, bottom, left] = head.crops;
            (
                (
                    head.width.saturating_sub(left + right),
                    head.height.saturating_sub(top + bottom),
                ),
                head.clean_make,
                head.clean_model,
            )
        }
    };
    let id = &mut exif.identity;
    id.make = id.make.take().or(Some(make).filter(|s| !s.is_empty()));
    id.model = id.model.take().or(Some(model).filter(|s| !s.is_empty()));
    Ok(size)
}

/// A RAW file's bytes (DNG or a camera's own format) into CFA planes, without EXIF:
/// the part of [`decode_capture`] that is ours and rawloader's.
///
/// # Errors
/// As [`load_capture`].
pub fn decode_raw(path: &Path, bytes: &[u8]) -> Result<Capture, LoadError> {
    let ifd = if is_tiff(bytes) {
        Some(tiff_ifd0(bytes).map_err(|reason| damaged(path, bytes, reason))?)
    } else {
        None
    };
    load_raw(path, bytes, ifd.as_ref().filter(|i| is_raw_ifd(i))).map(|(c, _, _)| c)
}

/// A TIFF whose first directory does not parse: damaged, said where it can be.
fn damaged(path: &Path, bytes: &[u8], reason: String) -> LoadError {
    LoadError::Damaged {
        path: path.to_path_buf(),
        reason: damage::diagnose(bytes).unwrap_or(reason),
    }
}

/// Whether a TIFF's first directory is a full-size picture (not a camera's reduced
/// preview, NewSubfileType 1, nor a JPEG-coded preview).
fn image_in_ifd0(ifd: &Ifd) -> bool {
    first_tag(ifd, 254).is_none_or(|t| t as u32 & 1 == 0)
        && !matches!(first_tag(ifd, TAG_COMPRESSION), Some(6.0 | 7.0))
}

/// A RAW file's bytes through one decoder alone, without the others as fallbacks and
/// without EXIF: how the decoders are compared (which reads what, and how fast).
/// [`Decoder::Image`] is refused: it is not a RAW decoder.
///
/// # Errors
/// As [`load_capture`], from that decoder alone.
pub fn decode_raw_with(decoder: Decoder, path: &Path, bytes: &[u8]) -> Result<Capture, LoadError> {
    let ifd = is_tiff(bytes).then(|| tiff_ifd0(bytes).ok()).flatten();
    let refused = |reason: &str| LoadError::Unsupported {
        path: path.to_path_buf(),
        reason: reason.into(),
    };
    let capture = match decoder {
        Decoder::Rawler => decoders::rawler_capture(path, bytes, ifd.as_ref())
            .map(|(c, _)| c)
            .map_err(|refusal| decoders::explain(path, bytes, refusal, None))?,
        Decoder::Rawloader => rawloader_capture(path, bytes, ifd.as_ref())?,
        Decoder::Lensblur => match &ifd {
            Some(ifd) if is_raw_ifd(ifd) && first_tag(ifd, TAG_COMPRESSION) == Some(1.0) => {
                read_uncompressed_dng(path, bytes, ifd)?
            }
            _ => {
                return Err(refused(
                    "not an uncompressed DNG (all our own reader reads)",
                ));
            }
        },
        Decoder::Image => return Err(refused("not a RAW decoder")),
    };
    refuse_blank(path, &capture)?;
    Ok(capture)
}

fn first_tag(ifd: &Ifd, tag: u16) -> Option<f64> {
    ifd.get(&tag).and_then(|v| v.first().copied())
}

fn is_tiff(bytes: &[u8]) -> bool {
    bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*")
}

/// A DNG, or a TIFF holding a CFA image.
fn is_raw_ifd(ifd: &Ifd) -> bool {
    ifd.contains_key(&TAG_DNG_VERSION)
        || ifd
            .get(&TAG_PHOTOMETRIC)
            .is_some_and(|v| v.first() == Some(&32803.0))
}

const TAG_PHOTOMETRIC: u16 = 262;
const TAG_ORIENTATION: u16 = 274;
const TAG_DNG_VERSION: u16 = 50706;

/// A TIFF directory's tags as numbers (RATIONALs as quotients), with the byte order.
type Ifd = std::collections::HashMap<u16, Vec<f64>>;

/// The first directory of a TIFF (where our DNGs and many others keep the raw image
/// and the EXIF settings). Bounds are checked: a truncated file is an error.
fn tiff_ifd0(b: &[u8]) -> Result<Ifd, String> {
    let le = match b.get(0..2) {
        Some(b"II") => true,
        Some(b"MM") => false,
        _ => return Err("not a TIFF".into()),
    };
    let u16_at = |o: usize| -> Result<u16, String> {
        let s = b.get(o..o + 2).ok_or("truncated TIFF")?;
        Ok(if le {
            u16::from_le_bytes([s[0], s[1]])
        } else {
            u16::from_be_bytes([s[0], s[1]])
        })
    };
    let u32_at = |o: usize| -> Result<u32, String> {
        let s = b.get(o..o + 4).ok_or("truncated TIFF")?;
        let a = [s[0], s[1], s[2], s[3]];
        Ok(if le {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        })
    };
    let ifd_off = u32_at(4)? as usize;
    let n = u16_at(ifd_off)? as usize;
    let mut out = Ifd::new();
    for e in 0..n {
        let at = ifd_off + 2 + 12 * e;
        let tag = u16_at(at)?;
        let typ = u16_at(at + 2)?;
        let count = u32_at(at + 4)? as usize;
        let size = match typ {
            1 | 2 | 6 | 7 => 1,
            3 | 8 => 2,
            4 | 9 | 11 => 4,
            5 | 10 | 12 => 8,
            _ => continue,
        };
        if count > 1 << 24 {
            return Err(format!("tag {tag}: absurd count {count}"));
        }
        let data = if size * count <= 4 {
            at + 8
        } else {
            u32_at(at + 8)? as usize
        };
        if b.len() < data + size * count {
            return Err(format!("truncated TIFF (tag {tag} points past the end)"));
        }
        let vals: Result<Vec<f64>, String> = (0..count)
            .map(|k| {
                let o = data + k * size;
                Ok(match typ {
                    1 | 2 | 7 => f64::from(b[o]),
                    6 => f64::from(b[o] as i8),
                    3 => f64::from(u16_at(o)?),
                    8 => f64::from(u16_at(o)? as i16),
                    4 => f64::from(u32_at(o)?),
                    9 => f64::from(u32_at(o)? as i32),
                    5 => f64::from(u32_at(o)?) / f64::from(u32_at(o + 4)?.max(1)),
                    10 => f64::from(u32_at(o)? as i32) / f64::from((u32_at(o + 4)? as i32).max(1)),
                    _ => f64::NAN,
                })
            })
            .collect();
        out.insert(tag, vals?);
    }
    Ok(out)
}

/// A RAW file through the first decoder that reads it (rawler, then our own reader
/// for the uncompressed DNGs rawloader would misread, then rawloader), each one's
/// declared size checked against our limits before it allocates the image; and an
/// image of one value throughout (image data missing, decoded as zeros) refused.
fn load_raw(
    path: &Path,
    bytes: &[u8],
    ifd: Option<&Ifd>,
) -> Result<(Capture, Decoder, DecodedMeta), LoadError> {
    let (capture, decoder, meta) = match decoders::rawler_capture(path, bytes, ifd) {
        Ok((c, meta)) => (c, Decoder::Rawler, meta),
        Err(refusal) => {
            if let decoders::RawlerRefusal::Ours(e) = refusal {
                return Err(e);
            }
            let fallback = if let Some(ifd) = ifd
                && needs_own_reader(ifd)
            {
                read_uncompressed_dng(path, bytes, ifd).map(|c| (c, Decoder::Lensblur))
            } else {
                rawloader_capture(path, bytes, ifd).map(|c| (c, Decoder::Rawloader))
            };
            match fallback {
                Ok((c, d)) => (c, d, DecodedMeta::default()),
                Err(LoadError::TooLarge { path, reason }) => {
                    return Err(LoadError::TooLarge { path, reason });
                }
                Err(e) => {
                    return Err(decoders::explain(path, bytes, refusal, Some(e)));
                }
            }
        }
    };
    refuse_blank(path, &capture)?;
    Ok((capture, decoder, meta))
}

/// The reason inside a fallback decoder's error, for the message that explains why
/// no decoder read a file.
fn fallback_words(e: &LoadError) -> String {
    match e {
        LoadError::Unreadable { reason, .. }
        | LoadError::Corrupt { reason, .. }
        | LoadError::Damaged { reason, .. }
        | LoadError::Unsupported { reason, .. }
        | LoadError::NoImage { reason, .. }
        | LoadError::TooLarge { reason, .. } => reason.clone(),
    }
}

/// A decoded image whose every sample is the same is no picture: a file whose image
/// data was stripped or never written decodes to zeros (or to its black level), and
/// measuring or deblurring it would report a perfectly sharp, perfectly black lens.
fn refuse_blank(path: &Path, capture: &Capture) -> Result<(), LoadError> {
    let mut samples = capture.planes.iter().flat_map(|p| p.plane.data.iter());
    let Some(&first) = samples.next() else {
        return Err(LoadError::NoImage {
            path: path.to_path_buf(),
            reason: "the file holds no pixels".into(),
        });
    };
    if samples.all(|&v| v == first) {
        return Err(LoadError::NoImage {
            path: path.to_path_buf(),
            reason: format!(
                "every one of its {} × {} pixels has the same value: its image data is \
                 missing (a file cut short, or one with only its metadata kept)",
                capture.width, capture.height
            ),
        });
    }
    Ok(())
}

/// A RAW file through rawloader, whose header-only pass gives the declared size to
/// check against our limits before the real decode allocates the image.
fn rawloader_capture(path: &Path, bytes: &[u8], ifd: Option<&Ifd>) -> Result<Capture, LoadError> {
    let panicked = || LoadError::Corrupt {
        path: path.to_path_buf(),
        reason: "the RAW decoder stopped on malformed data".into(),
    };
    // rawloader reports its decoders' panics as errors: a panic is never the message.
    let decoder_error = |e: rawloader::RawLoaderError| {
        let m = one_line(&e.to_string());
        if m.contains("panic") {
            panicked()
        } else {
            LoadError::Corrupt {
                path: path.to_path_buf(),
                reason: format!("RAW decoder: {m}"),
            }
        }
    };
    let _quiet = QuietPanics::new();
    let head =
        std::panic::catch_unwind(|| rawloader::decode_dummy(&mut std::io::Cursor::new(bytes)))
            .map_err(|_| panicked())?
            .map_err(decoder_error)?;
    check_size(path, head.width, head.height)?;
    // No lossless coding spends less than a bit on a sample: a file that claims more
    // samples than it has bits is truncated, and is refused before the decoder
    // allocates its image (a few kB claiming 300 MP would otherwise take 600 MB).
    let samples = head
        .width
        .saturating_mul(head.height)
        .saturating_mul(head.cpp.max(1));
    if bytes.len().saturating_mul(8) < samples {
        return Err(LoadError::Damaged {
            path: path.to_path_buf(),
            reason: format!(
                "truncated at byte {}: a {} × {} image cannot be coded in so few bytes",
                bytes.len(),
                head.width,
                head.height,
            ),
        });
    }
    let decoded = std::panic::catch_unwind(|| rawloader::decode(&mut std::io::Cursor::new(bytes)))
        .map_err(|_| panicked())?
        .map_err(decoder_error)?;
    from_rawloader(path, &decoded, ifd)
}

const TAG_COMPRESSION: u16 = 259;
const TAG_STRIP_OFFSETS: u16 = 273;
const TAG_ROWS_PER_STRIP: u16 = 278;
const TAG_STRIP_BYTE_COUNTS: u16 = 279;
const TAG_TILE_OFFSETS: u16 = 324;

/// Whether the first directory holds an uncompressed CFA image that rawloader reads
/// wrongly or not at all: tiles (it refuses them: "Couldn't find tag StripOffsets"), or
/// strips that do not follow one another in the file (it reads every sample on from the
/// first strip, so a gap or a reordering would be read as image).
fn needs_own_reader(ifd: &Ifd) -> bool {
    let first = |tag: u16| ifd.get(&tag).and_then(|v| v.first().copied());
    if first(TAG_PHOTOMETRIC) != Some(32803.0) || first(TAG_COMPRESSION) != Some(1.0) {
        return false;
    }
    if ifd.contains_key(&TAG_TILE_OFFSETS) {
        return true;
    }
    match (ifd.get(&TAG_STRIP_OFFSETS), ifd.get(&TAG_STRIP_BYTE_COUNTS)) {
        (Some(offsets), Some(counts)) => offsets
            .windows(2)
            .zip(counts)
            .any(|(o, c)| o[1] != o[0] + c),
        _ => false,
    }
}

type PanicHook = Box<dyn Fn(&std::panic::PanicHookInfo<'_>) + Sync + Send + 'static>;

/// The panic hook saved while any decode runs, and how many decodes run.
static QUIET: std::sync::Mutex<(usize, Option<PanicHook>)> = std::sync::Mutex::new((0, None));

/// While alive, panics print nothing. rawloader turns its decoders' panics into errors
/// but prints each one on the way; a malformed file must cost the user one line, not
/// hundreds. Counted, so decodes on several threads restore the original hook only when
/// the last one ends (a plain take/set pair per call would leave the silent hook in
/// place when two overlap).
struct QuietPanics;

impl QuietPanics {
    fn new() -> Self {
        let mut q = QUIET
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if q.0 == 0 {
            q.1 = Some(std::panic::take_hook());
            std::panic::set_hook(Box::new(|_| {}));
        }
        q.0 += 1;
        Self
    }
}

impl Drop for QuietPanics {
    fn drop(&mut self) {
        let mut q = QUIET
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        q.0 -= 1;
        if q.0 == 0
            && let Some(hook) = q.1.take()
        {
            std::panic::set_hook(hook);
        }
    }
}

/// The decoder's message as one line: its first line, without the error type's wrapper
/// (it appends an address to report samples to on a second line).
fn one_line(message: &str) -> String {
    let first = message.lines().next().unwrap_or_default();
    let bare = first.strip_prefix("RawLoaderError: ").unwrap_or(first);
    bare.trim_matches('"').trim().to_string()
}

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
    Ok(decoded_capture(w, h, planes, true))
}

fn from_rawloader(
    path: &Path,
    img: &rawloader::RawImage,
    ifd: Option<&Ifd>,
) -> Result<Capture, LoadError> {
    if img.cpp != 1 {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: format!("{} samples per pixel: not a CFA RAW", img.cpp),
        });
    }
    let rawloader::RawImageData::Integer(data) = &img.data else {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: "floating-point RAW data is not supported".into(),
        });
    };
    if data.len() < img.width * img.height {
        return Err(LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: "fewer samples than the sensor has pixels (truncated?)".into(),
        });
    }
    // The active area: crops are [top, right, bottom, left].
    let [top, right, bottom, left] = img.crops;
    let (w, h) = (
        img.width.saturating_sub(left + right),
        img.height.saturating_sub(top + bottom),
    );
    check_size(path, w, h)?;
    let mut values = Vec::with_capacity(w * h);
    for y in 0..h {
        let row = (y + top) * img.width + left;
        values.extend_from_slice(&data[row..row + w]);
    }
    let color_at = |x: usize, y: usize| img.cfa.color_at(y + top, x + left);
    // rawloader keeps one black level per colour, reading a DNG's per-site levels (a
    // 2 × 2 BlackLevelRepeatDim, what Adobe's converter writes) as if they were per
    // colour; where the raw image is in IFD0 we take them per site ourselves.
    let site_blacks = ifd.and_then(site_black_levels);
    let black = |x: usize, y: usize| match site_blacks {
        Some(b) => b[RawMeta::site(x + left, y + top)],
        None => f32::from(img.blacklevels[color_at(x, y).min(3)]),
    };
    let white = f32::from(img.whitelevels[0]);
    let mut c = cfa_capture(path, &values, (w, h), &color_at, &black, white)?;
    let sites = [(0, 0), (1, 0), (0, 1), (1, 1)];
    let matrix: [[f64; 3]; 3] =
        std::array::from_fn(|r| std::array::from_fn(|k| f64::from(img.xyz_to_cam[r][k])));
    let wb = img.wb_coeffs;
    c.raw = Some(RawMeta {
        cfa: sites.map(|(x, y)| color_at(x, y).min(3) as u8),
        black: sites.map(|(x, y)| black(x, y) as u16),
        white: img.whitelevels[0],
        // A DNG's own values where it has them (rawloader rounds them to f32).
        color_matrix: ifd
            .and_then(dng_matrix)
            .or_else(|| matrix.iter().flatten().any(|v| *v != 0.0).then_some(matrix)),
        calibration_illuminant: ifd.map_or(21, matrix_illuminant),
        as_shot_neutral: ifd.and_then(dng_neutral).or_else(|| {
            (wb[..3].iter().all(|v| v.is_normal() && *v > 0.0)).then(|| {
                let g = f64::from(wb[1]);
                [g / f64::from(wb[0]), 1.0, g / f64::from(wb[2])]
            })
        }),
        orientation: match img.orientation.to_u16() {
            0 => 1,
            o => o,
        },
        // The EXIF facts come with `ExifInfo::fill`.
        ..RawMeta::default()
    });
    c.identity.make = Some(img.clean_make.clone()).filter(|s| !s.is_empty());
    c.identity.model = Some(img.clean_model.clone()).filter(|s| !s.is_empty());
    Ok(c)
}

/// Per-site black levels of a CFA image in this directory with a 2 × 2 black pattern,
/// in [`RawMeta::site`] order.
fn site_black_levels(ifd: &Ifd) -> Option<[f32; 4]> {
    let first = |tag: u16| ifd.get(&tag).and_then(|v| v.first().copied());
    if first(TAG_PHOTOMETRIC) != Some(32803.0) || ifd.get(&50713)? != &vec![2.0, 2.0] {
        return None;
    }
    let b = ifd.get(&50714).filter(|b| b.len() == 4)?;
    b.iter()
        .all(|v| v.is_finite() && (0.0..=65535.0).contains(v))
        .then(|| [b[0] as f32, b[1] as f32, b[2] as f32, b[3] as f32])
}

/// A DNG's XYZ → camera matrix: ColorMatrix2 where there are two (as rawloader picks),
/// else ColorMatrix1; 3 × 3 (a 3-colour sensor's).
fn dng_matrix(ifd: &Ifd) -> Option<[[f64; 3]; 3]> {
    ifd.get(&50722)
        .or_else(|| ifd.get(&50721))
        .filter(|m| m.len() == 9 && m.iter().all(|v| v.is_finite()))
        .map(|m| std::array::from_fn(|r| std::array::from_fn(|k| m[3 * r + k])))
}

/// A DNG's AsShotNeutral.
fn dng_neutral(ifd: &Ifd) -> Option<[f64; 3]> {
    ifd.get(&50728)
        .filter(|n| n.len() == 3 && n.iter().all(|v| v.is_finite() && *v > 0.0))
        .map(|n| [n[0], n[1], n[2]])
}

/// The EXIF light source of the colour matrix a DNG reader uses: rawloader (and we)
/// take ColorMatrix2 where there are two (usually D65), ColorMatrix1 otherwise; D65
/// where the file does not say (a camera RAW, whose matrix is rawloader's D65 one).
fn matrix_illuminant(ifd: &Ifd) -> u16 {
    let tag = if ifd.contains_key(&50722) {
        50779
    } else {
        50778
    };
    ifd.get(&tag)
        .and_then(|v| v.first().copied())
        .filter(|v| (1.0..=255.0).contains(v))
        .map_or(21, |v| v as u16)
}

/// An uncompressed 16-bit CFA DNG whose raw image is in the first directory, in tiles
/// or strips (a strip is a tile as wide as the image).
fn read_uncompressed_dng(path: &Path, b: &[u8], ifd: &Ifd) -> Result<Capture, LoadError> {
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
    let mut c = cfa_capture(path, &values, (w, h), &color_at, &black, white)?;
    let sites = [(0, 0), (1, 0), (0, 1), (1, 1)];
    c.raw = Some(RawMeta {
        cfa: sites.map(|(x, y)| color_at(x, y).min(3) as u8),
        black: sites.map(|(x, y)| black(x, y).clamp(0.0, 65535.0) as u16),
        white: white.clamp(0.0, 65535.0) as u16,
        color_matrix: dng_matrix(ifd),
        calibration_illuminant: matrix_illuminant(ifd),
        as_shot_neutral: dng_neutral(ifd),
        orientation: ifd
            .get(&TAG_ORIENTATION)
            .and_then(|v| v.first().copied())
            .filter(|v| (1.0..=8.0).contains(v))
            .map_or(1, |v| v as u16),
        // The EXIF facts come with `ExifInfo::fill`.
        ..RawMeta::default()
    });
    Ok(c)
}

/// What lensblur takes from a file's EXIF.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExifInfo {
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
    pub identity: crate::plane::CameraIdentity,
    pub exposure_s: Option<f64>,
    pub iso: Option<u32>,
    pub date_time_original: Option<String>,
    pub lens_make: Option<String>,
    pub description: Option<String>,
    /// FocalLengthIn35mmFilm, mm.
    pub focal_35mm: Option<f64>,
    /// LensSpecification: shortest and longest focal length, widest aperture at each.
    pub lens_specification: Option<[f64; 4]>,
    /// SubjectDistance, metres: where the camera focused (infinite where it says
    /// infinity). Blur depends on it; a profile knows the range it was measured at.
    pub subject_distance_m: Option<f64>,
}

impl ExifInfo {
    /// Takes what the RAW decoder read where EXIF (as we parse it) has nothing: CR3
    /// keeps its EXIF where a TIFF reader does not look, and lens names come from
    /// maker notes.
    fn take_decoded(&mut self, meta: &DecodedMeta) {
        self.focal_mm = self.focal_mm.or(meta.focal_mm);
        self.f_number = self.f_number.or(meta.f_number);
        self.subject_distance_m = self.subject_distance_m.or(meta.subject_distance_m);
        let lens = &mut self.identity.lens_model;
        *lens = lens.take().or_else(|| meta.lens_model.clone());
    }

    /// Fills what the capture does not already have (settings) or has less exactly
    /// (EXIF's make and model win over the RAW decoder's cleaned names).
    fn fill(self, capture: &mut Capture) {
        capture.setting_focal_mm = capture.setting_focal_mm.or(self.focal_mm);
        capture.setting_f_number = capture.setting_f_number.or(self.f_number);
        let id = &mut capture.identity;
        id.make = self.identity.make.or(id.make.take());
        id.model = self.identity.model.or(id.model.take());
        id.body_serial = self.identity.body_serial.or(id.body_serial.take());
        id.lens_model = self.identity.lens_model.or(id.lens_model.take());
        id.lens_serial = self.identity.lens_serial.or(id.lens_serial.take());
        if let Some(raw) = &mut capture.raw {
            raw.exposure_s = self.exposure_s;
            raw.iso = self.iso;
            raw.date_time_original = self.date_time_original;
            raw.lens_make = self.lens_make;
            raw.focal_35mm = self.focal_35mm;
            raw.lens_specification = self.lens_specification;
            raw.description = self.description;
        }
    }
}

/// Focal length, f-number and identity from a file's EXIF, by tag number: DNGs often
/// keep these in IFD0, where they are not the EXIF-context tags a lookup by name
/// expects. A file without EXIF, or with EXIF we cannot parse, has none.
#[must_use]
pub fn read_exif(bytes: &[u8]) -> ExifInfo {
    let mut info = ExifInfo::default();
    let Ok(exif) = exif::Reader::new().read_from_container(&mut std::io::Cursor::new(bytes)) else {
        return info;
    };
    for f in exif.fields() {
        let number = f.tag.number();
        let rational = match &f.value {
            exif::Value::Rational(v) => v
                .first()
                .map(|r| f64::from(r.num) / f64::from(r.denom.max(1))),
            exif::Value::Short(v) => v.first().map(|&x| f64::from(x)),
            exif::Value::Long(v) => v.first().map(|&x| f64::from(x)),
            _ => None,
        }
        .filter(|v| v.is_finite() && *v > 0.0);
        let text = match &f.value {
            exif::Value::Ascii(v) => v
                .first()
                .map(|s| {
                    String::from_utf8_lossy(s)
                        .trim_end_matches('\0')
                        .trim()
                        .chars()
                        .take(256)
                        .collect::<String>()
                })
                .filter(|s| !s.is_empty()),
            _ => None,
        };
        let id = &mut info.identity;
        match number {
            37386 => info.focal_mm = info.focal_mm.or(rational),
            37382 => {
                // SubjectDistance: 0xFFFFFFFF is infinity, 0 unknown.
                if let exif::Value::Rational(v) = &f.value
                    && let Some(r) = v.first()
                {
                    info.subject_distance_m = info.subject_distance_m.or(if r.num == u32::MAX {
                        Some(f64::INFINITY)
                    } else {
                        rational
                    });
                }
            }
            33434 => info.exposure_s = info.exposure_s.or(rational),
            // ISOSpeedRatings; PhotographicSensitivity in EXIF 2.3.
            34855 => info.iso = info.iso.or(rational.map(|v| v.round() as u32)),
            36867 => info.date_time_original = info.date_time_original.take().or(text),
            42035 => info.lens_make = info.lens_make.take().or(text),
            41989 => info.focal_35mm = info.focal_35mm.or(rational),
            42034 => {
                if let exif::Value::Rational(v) = &f.value
                    && v.len() == 4
                {
                    let spec: Vec<f64> = v
                        .iter()
                        .map(|r| f64::from(r.num) / f64::from(r.denom.max(1)))
                        .collect();
                    // Unknown values are written as 0/0: keep the focal range anyway.
                    if spec[0].is_finite() && spec[1].is_finite() && spec[0] > 0.0 {
                        info.lens_specification = Some([spec[0], spec[1], spec[2], spec[3]]);
                    }
                }
            }
            270 => info.description = info.description.take().or(text),
            33437 => info.f_number = info.f_number.or(rational),
            271 => id.make = id.make.take().or(text),
            272 => id.model = id.model.take().or(text),
            42033 => id.body_serial = id.body_serial.take().or(text),
            42036 => id.lens_model = id.lens_model.take().or(text),
            42037 => id.lens_serial = id.lens_serial.take().or(text),
            _ => {}
        }
    }
    info
}

fn check_size(path: &Path, width: usize, height: usize) -> Result<(), LoadError> {
    limits::check_image_size(width, height).map_err(|reason| LoadError::TooLarge {
        path: path.to_path_buf(),
        reason,
    })
}

/// A capture as decoding leaves it: its planes, and nothing yet of its settings, its
/// camera or (for a RAW file) its metadata, which the loader fills in from the file.
fn decoded_capture(
    width: usize,
    height: usize,
    planes: Vec<ChannelPlane>,
    is_raw: bool,
) -> Capture {
    Capture {
        width,
        height,
        planes,
        setting_focal_mm: None,
        setting_f_number: None,
        identity: Default::default(),
        is_raw,
        raw: None,
    }
}

/// image-rs's reader of a PNG/TIFF/JPEG, held to our limits (its own default would
/// refuse a 100 MP 16-bit TIFF).
fn image_reader<'a>(
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
fn image_dimensions(path: &Path, bytes: &[u8]) -> Result<(usize, usize), LoadError> {
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
fn image_error_words(e: &image::ImageError) -> String {
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
fn load_image(path: &Path, bytes: &[u8], options: &LoadOptions) -> Result<Capture, LoadError> {
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
            plane: Plane::from_fn(w, h, |x, y| {
                let v = sample((y * w + x) * cc + c);
                if decode_srgb { srgb_decode(v) } else { v }
            }),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        })
        .collect();
    Ok(decoded_capture(w, h, planes, false))
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
    crate::io::write_atomic(path, &bytes).map_err(|e| err(e.source.to_string()))
}

/// The planes to write, all of one size: R, G, B where there are all three, else the
/// first (a grey image).
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
        (0..w * h)
            .flat_map(|i| {
                rgb.iter()
                    .map(move |p| (srgb_encode(p.data[i].clamp(0.0, 1.0)) * 255.0).round() as u8)
            })
            .collect()
    } else {
        (0..w * h)
            .flat_map(|i| {
                rgb.iter().flat_map(move |p| {
                    ((p.data[i].clamp(0.0, 1.0) * 65535.0).round() as u16).to_ne_bytes()
                })
            })
            .collect()
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
