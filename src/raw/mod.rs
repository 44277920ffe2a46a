//! Loading shots and photos into linear channel planes (docs/formats.md, "Images and
//! RAW files lensblur reads").
//!
//! RAW files keep their CFA: each colour site becomes its own plane at half resolution
//! (black subtracted, divided by white − black), so blur is measured before any
//! demosaicing or colour matrixing. 16-bit and float PNG/TIFF are taken as linear;
//! 8-bit images are sRGB-decoded unless the caller says they are linear.

//!
//! The parts: which reader a file goes to and the errors it meets (here); the RAW
//! decoders and the words for their refusals (`decoders`, `damage`); the worker process
//! they run in for the command line and the studio, and the bytes it answers in
//! (`worker`, `wire`); our own TIFF and
//! DNG reading (`tiff`, `dng_read`); the CFA planes every RAW decoder's answer becomes
//! (`cfa`); EXIF (`exif`); PNG/TIFF/JPEG (`picture`); writing planes out (`save`).

use crate::limits;
use crate::plane::Capture;
use std::path::{Path, PathBuf};

mod cfa;
mod damage;
mod decoders;
mod dng_read;
mod exif;
mod info;
mod picture;
mod save;
mod tiff;
mod wire;
mod worker;

use cfa::Decoded;
pub use decoders::{DecodedMeta, Decoder};
pub use exif::{ExifInfo, read_exif};
pub use info::{FileInfo, FocusDistance, INFO_SCHEMA, inspect, inspect_bytes};
use picture::{image_dimensions, load_image};
pub use save::{SaveError, full_planes, save_like_original, save_planes};
use tiff::{
    Ifd, TAG_COMPRESSION, first_tag, image_in_ifd0, is_raw_ifd, is_tiff, needs_own_reader,
    tiff_ifd0,
};
use wire::{Answer, Job};
pub use worker::{
    Decoding, WORKER_SUBCOMMAND, WorkerLimits, decoding, serve as serve_worker, set_decoding,
    with_decoding,
};

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
    #[error("{}: damaged file: {reason}; copy it again from the card or the camera", path.display())]
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
    /// The RAW decoder's process ran out of memory, out of time, or crashed on the
    /// file (see [`Decoding`]).
    #[error("{}: {reason}", path.display())]
    DecoderStopped { path: PathBuf, reason: String },
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
    decode_with_decoder(path, &bytes, OnDisk(true), options).map(|(c, _, _)| c)
}

/// Whether a file's bytes are the whole file at its path, as read just now: a RAW
/// decoding worker then reads the file itself rather than be sent them.
#[derive(Clone, Copy, Debug)]
struct OnDisk(bool);

/// [`load_capture`] on a file's bytes; `path` only names the file in messages.
///
/// # Errors
/// As [`load_capture`].
pub fn decode_capture(
    path: &Path,
    bytes: &[u8],
    options: &LoadOptions,
) -> Result<Capture, LoadError> {
    decode_with_decoder(path, bytes, OnDisk(false), options).map(|(c, _, _)| c)
}

/// [`decode_capture`], and which decoder read the file, and what it and EXIF say.
fn decode_with_decoder(
    path: &Path,
    bytes: &[u8],
    on_disk: OnDisk,
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
            load_raw(path, bytes, on_disk)?
        } else if decoders::camera_raw(bytes) {
            // A camera's TIFF-based RAW (CR2, NEF, ARW, PEF, ...): its first directory
            // is a preview, the CFA is further in. Where the RAW decoders refuse it and
            // that first directory is a full-size picture of its own (a TIFF an editor
            // exported, which keeps the camera's Make), it is read as the picture.
            match load_raw(path, bytes, on_disk) {
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
        load_raw(path, bytes, on_disk)?
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
    header_of(path, &bytes, OnDisk(true))
}

/// [`read_header`] on a file's bytes; `path` only names the file in messages.
///
/// # Errors
/// As [`read_header`].
pub fn decode_header(path: &Path, bytes: &[u8]) -> Result<Header, LoadError> {
    header_of(path, bytes, OnDisk(false))
}

fn header_of(path: &Path, bytes: &[u8], on_disk: OnDisk) -> Result<Header, LoadError> {
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
                match raw_dimensions(path, bytes, on_disk, &mut exif) {
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
                (raw_dimensions(path, bytes, on_disk, &mut exif)?, true)
            }
        } else {
            (raw_dimensions(path, bytes, on_disk, &mut exif)?, true)
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
    on_disk: OnDisk,
    exif: &mut ExifInfo,
) -> Result<(usize, usize), LoadError> {
    let Answer::Header((size, make, model)) = worker::run(Job::Header, path, bytes, on_disk)?
    else {
        return Err(worker_mixup(path));
    };
    let id = &mut exif.identity;
    id.make = id.make.take().or(make);
    id.model = id.model.take().or(model);
    Ok(size)
}

/// A RAW file's bytes (DNG or a camera's own format) into CFA planes, without EXIF:
/// the part of [`decode_capture`] that is ours and rawloader's.
///
/// # Errors
/// As [`load_capture`].
pub fn decode_raw(path: &Path, bytes: &[u8]) -> Result<Capture, LoadError> {
    if is_tiff(bytes) {
        tiff_ifd0(bytes).map_err(|reason| damaged(path, bytes, reason))?;
    }
    load_raw(path, bytes, OnDisk(false)).map(|(c, _, _)| c)
}

/// A TIFF whose first directory does not parse: damaged, said where it can be.
fn damaged(path: &Path, bytes: &[u8], reason: String) -> LoadError {
    LoadError::Damaged {
        path: path.to_path_buf(),
        reason: damage::diagnose(bytes).unwrap_or(reason),
    }
}

/// A RAW file's bytes through one decoder alone, without the others as fallbacks and
/// without EXIF: how the decoders are compared (which reads what, and how fast).
/// [`Decoder::Image`] is refused: it is not a RAW decoder.
///
/// # Errors
/// As [`load_capture`], from that decoder alone.
pub fn decode_raw_with(decoder: Decoder, path: &Path, bytes: &[u8]) -> Result<Capture, LoadError> {
    if decoder == Decoder::Image {
        return Err(LoadError::Unsupported {
            path: path.to_path_buf(),
            reason: "not a RAW decoder".into(),
        });
    }
    match worker::run(Job::With(decoder), path, bytes, OnDisk(false))? {
        Answer::With(decoded) => {
            let capture = decoded.into_capture();
            refuse_blank(path, &capture)?;
            Ok(capture)
        }
        _ => Err(worker_mixup(path)),
    }
}

/// A RAW job in this process: what [`worker::run`] does here, or has a worker do.
fn run_in_process(job: Job, path: &Path, bytes: &[u8]) -> Result<Answer, LoadError> {
    Ok(match job {
        Job::Load => {
            let ifd = raw_ifd(bytes);
            let (capture, decoder, meta) = load_raw_here(path, bytes, ifd.as_ref())?;
            Answer::Load(capture, decoder, meta)
        }
        Job::Header => Answer::Header(match decoders::rawler_header(bytes) {
            Some(found) => found,
            None => decoders::rawloader_header(path, bytes)?,
        }),
        Job::With(decoder) => Answer::With(decode_with_here(decoder, path, bytes)?),
    })
}

/// A TIFF's first directory, where it holds the raw image (a DNG's, or a CFA TIFF's).
fn raw_ifd(bytes: &[u8]) -> Option<Ifd> {
    is_tiff(bytes)
        .then(|| tiff_ifd0(bytes).ok())
        .flatten()
        .filter(is_raw_ifd)
}

/// A worker's answer to another question than the one asked: a bug of ours, said as
/// one line all the same.
fn worker_mixup(path: &Path) -> LoadError {
    LoadError::DecoderStopped {
        path: path.to_path_buf(),
        reason: "the RAW decoder answered another request than this file's".into(),
    }
}

/// [`decode_raw_with`] in this process.
fn decode_with_here(decoder: Decoder, path: &Path, bytes: &[u8]) -> Result<Decoded, LoadError> {
    let ifd = is_tiff(bytes).then(|| tiff_ifd0(bytes).ok()).flatten();
    let refused = |reason: &str| LoadError::Unsupported {
        path: path.to_path_buf(),
        reason: reason.into(),
    };
    Ok(match decoder {
        Decoder::Rawler => decoders::rawler_capture(path, bytes, ifd.as_ref())
            .map(|(c, _)| c)
            .map_err(|refusal| decoders::explain(path, bytes, refusal, None))?,
        Decoder::Rawloader => decoders::rawloader_capture(path, bytes, ifd.as_ref())?,
        Decoder::Lensblur => match &ifd {
            Some(ifd) if is_raw_ifd(ifd) && first_tag(ifd, TAG_COMPRESSION) == Some(1.0) => {
                dng_read::read_uncompressed_dng(path, bytes, ifd)?
            }
            _ => {
                return Err(refused(
                    "not an uncompressed DNG (all our own reader reads)",
                ));
            }
        },
        Decoder::Image => return Err(refused("not a RAW decoder")),
    })
}

/// A RAW file through the decoders, where [`decoding`] says (see [`load_raw_here`]);
/// an image of one value throughout (image data missing, decoded as zeros) refused.
fn load_raw(
    path: &Path,
    bytes: &[u8],
    on_disk: OnDisk,
) -> Result<(Capture, Decoder, DecodedMeta), LoadError> {
    match worker::run(Job::Load, path, bytes, on_disk)? {
        Answer::Load(decoded, decoder, meta) => {
            let capture = decoded.into_capture();
            refuse_blank(path, &capture)?;
            Ok((capture, decoder, meta))
        }
        _ => Err(worker_mixup(path)),
    }
}

/// A RAW file through the first decoder that reads it (rawler, then our own reader
/// for the uncompressed DNGs rawloader would misread, then rawloader), each one's
/// declared size checked against our limits before it allocates the image.
fn load_raw_here(
    path: &Path,
    bytes: &[u8],
    ifd: Option<&Ifd>,
) -> Result<(Decoded, Decoder, DecodedMeta), LoadError> {
    Ok(match decoders::rawler_capture(path, bytes, ifd) {
        Ok((c, meta)) => (c, Decoder::Rawler, meta),
        Err(refusal) => {
            if let decoders::RawlerRefusal::Ours(e) = refusal {
                return Err(e);
            }
            let fallback = if let Some(ifd) = ifd
                && needs_own_reader(ifd)
            {
                dng_read::read_uncompressed_dng(path, bytes, ifd).map(|c| (c, Decoder::Lensblur))
            } else {
                decoders::rawloader_capture(path, bytes, ifd).map(|c| (c, Decoder::Rawloader))
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
    })
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
        | LoadError::TooLarge { reason, .. }
        | LoadError::DecoderStopped { reason, .. } => reason.clone(),
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

fn check_size(path: &Path, width: usize, height: usize) -> Result<(), LoadError> {
    limits::check_image_size(width, height).map_err(|reason| LoadError::TooLarge {
        path: path.to_path_buf(),
        reason,
    })
}
