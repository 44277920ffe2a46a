//! The RAW decoders behind [`super::load_capture`], in the order they are tried:
//! rawler (dnglab's library: the newest cameras, CR3, compressed RAF, lossy DNG), then
//! rawloader where rawler refuses a file (it knows a few older bodies rawler does not),
//! then our own reader for the uncompressed DNGs rawloader would misread. Each one's
//! answer becomes the same normalised CFA planes; and where every one refuses, the
//! refusal is explained in words a photographer can act on (see [`explain`]).

use super::cfa::{Decoded, DecoderColour, mosaic_capture};
use super::tiff::{Ifd, TAG_DNG_VERSION, TAG_PHOTOMETRIC, first_tag, site_black_levels};
use super::{LoadError, check_size};
use crate::plane::{Capture, Channel, ChannelPlane, Plane, RawMeta};
use std::path::Path;

/// Which decoder read a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Decoder {
    /// The `rawler` crate.
    Rawler,
    /// The `rawloader` crate.
    Rawloader,
    /// lensblur's own reader of uncompressed DNGs.
    Lensblur,
    /// The `image` crate (PNG, TIFF, JPEG).
    Image,
}

impl Decoder {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Decoder::Rawler => "rawler",
            Decoder::Rawloader => "rawloader",
            Decoder::Lensblur => "lensblur",
            Decoder::Image => "image",
        }
    }
}

/// What the camera's own metadata says beyond the planes, where the decoder reads it
/// (rawler reads CR3's EXIF, which lives in boxes a TIFF-only EXIF reader never sees,
/// and lens names from maker notes).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DecodedMeta {
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
    pub lens_model: Option<String>,
    /// EXIF SubjectDistance, metres (infinite where the file says infinity).
    pub subject_distance_m: Option<f64>,
}

/// Where a decoder stopped on a file it could not make sense of (it panicked). Only
/// said once the damage checks found nothing cut short: the file is whole, so the
/// values in it are what is wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Stopped {
    /// Reading its directories or records, before any image data.
    Header,
    /// Decoding its image data.
    Image,
}

impl Stopped {
    const HEADER: &str = "its headers hold values that contradict each other (the file is \
                          whole, but a directory or record in it is corrupt)";
    const IMAGE: &str = "its image data does not decode as its headers describe it (the \
                         file is whole, but the data is corrupt)";
    const CURE: &str = "copy it from the card again, or convert the original to DNG with \
                        Adobe DNG Converter or `dnglab convert` and open the DNG";

    /// What is wrong and what to do, in one line.
    pub(super) fn words(self) -> String {
        let what = match self {
            Stopped::Header => Self::HEADER,
            Stopped::Image => Self::IMAGE,
        };
        format!("{what}: {}", Self::CURE)
    }

    /// Whether a reason is one of these.
    fn said(reason: &str) -> bool {
        reason.starts_with(Self::HEADER) || reason.starts_with(Self::IMAGE)
    }
}

/// Why rawler did not give an image.
pub(super) enum RawlerRefusal {
    /// rawler's own error.
    Refused(rawler::RawlerError),
    /// rawler panicked on the file, there.
    Panicked(Stopped),
    /// The file declared an image outside our limits, or shorter than its samples.
    Ours(LoadError),
}

/// A RAW file through rawler: the declared size first, checked against
/// [`crate::limits`] before the image is allocated, then the one decode. The size is
/// rawler's header-only pass's, or where a DNG's first directory is its raw image, that
/// directory's: rawler (0.8) decodes a DNG's whole image even in its header-only pass,
/// which doubled the time of a 24 MP lossless-JPEG DNG (docs/figures.md, "Decoding a
/// RAW file") and checked nothing before that decode.
pub(super) fn rawler_capture(
    path: &Path,
    bytes: &[u8],
    ifd: Option<&Ifd>,
) -> Result<(Decoded, DecodedMeta), RawlerRefusal> {
    let _quiet = QuietPanics::new();
    let source = rawler::rawsource::RawSource::new_from_slice(bytes);
    let params = rawler::decoders::RawDecodeParams::default();
    let stage = std::cell::Cell::new(Stopped::Header);
    let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let decoder = rawler::get_decoder(&source).map_err(RawlerRefusal::Refused)?;
        let (width, height, cpp) = match ifd.and_then(dng_raw_size) {
            Some(size) => size,
            None => {
                let head = decoder
                    .raw_image(&source, &params, true)
                    .map_err(RawlerRefusal::Refused)?;
                (head.width, head.height, head.cpp)
            }
        };
        check_size(path, width, height).map_err(RawlerRefusal::Ours)?;
        let samples = width.saturating_mul(height).saturating_mul(cpp.max(1));
        // No lossless coding spends less than a bit on a sample (and a lossy one not
        // less than a tenth of one): a file that claims far more samples than it has
        // bits is truncated, and is refused before the decoder allocates its image.
        if bytes.len().saturating_mul(80) < samples {
            return Err(RawlerRefusal::Ours(LoadError::Damaged {
                path: path.to_path_buf(),
                reason: format!(
                    "truncated at byte {}: a {width} × {height} image cannot be coded in so few \
                     bytes",
                    bytes.len(),
                ),
            }));
        }
        stage.set(Stopped::Image);
        let image = decoder
            .raw_image(&source, &params, false)
            .map_err(RawlerRefusal::Refused)?;
        stage.set(Stopped::Header);
        let meta = decoder.raw_metadata(&source, &params).ok();
        Ok((image, meta))
    }))
    .map_err(|_| RawlerRefusal::Panicked(stage.get()))??;
    let (image, meta) = decoded;
    let capture = from_rawler(path, &image, ifd).map_err(RawlerRefusal::Ours)?;
    Ok((capture, decoded_meta(meta.as_ref())))
}

/// A DNG's raw image size (width, height, samples per pixel) where its first directory
/// holds it (not a preview: NewSubfileType 0; a CFA or linear raw image), as the DNG's
/// writer declared it.
fn dng_raw_size(ifd: &Ifd) -> Option<(usize, usize, usize)> {
    let main = first_tag(ifd, 254).is_none_or(|t| t as u32 & 1 == 0);
    let raw = matches!(first_tag(ifd, TAG_PHOTOMETRIC), Some(32803.0 | 34892.0));
    if !(ifd.contains_key(&TAG_DNG_VERSION) && main && raw) {
        return None;
    }
    let count = |tag: u16| {
        first_tag(ifd, tag)
            .filter(|v| v.is_finite() && *v >= 0.0)
            .map(|v| v as usize)
    };
    Some((count(256)?, count(257)?, count(277).unwrap_or(1)))
}

fn rational(r: Option<&rawler::formats::tiff::Rational>) -> Option<f64> {
    r.filter(|r| r.d != 0)
        .map(|r| f64::from(r.n) / f64::from(r.d))
        .filter(|v| v.is_finite() && *v > 0.0)
}

fn decoded_meta(meta: Option<&rawler::decoders::RawMetadata>) -> DecodedMeta {
    let Some(meta) = meta else {
        return DecodedMeta::default();
    };
    let exif = &meta.exif;
    let lens_model = meta
        .lens
        .as_ref()
        .map(|l| {
            format!("{} {}", l.lens_make, l.lens_model)
                .trim()
                .to_string()
        })
        .or_else(|| exif.lens_model.clone())
        .map(|s| s.trim().chars().take(256).collect::<String>())
        .filter(|s| !s.is_empty());
    DecodedMeta {
        focal_mm: rational(exif.focal_length.as_ref()),
        f_number: rational(exif.fnumber.as_ref()),
        lens_model,
        subject_distance_m: exif.subject_distance.as_ref().and_then(|r| {
            // EXIF writes infinity as 0xFFFFFFFF/1 and "unknown" as 0.
            if r.n == u32::MAX {
                Some(f64::INFINITY)
            } else {
                rational(Some(r))
            }
        }),
    }
}

/// rawler's image as our planes: a 2 × 2 CFA mosaic as [`mosaic_capture`] keeps it (the
/// active area, black per CFA site, white), linear (demosaiced) RGB data as three
/// full-resolution linear planes.
fn from_rawler(
    path: &Path,
    img: &rawler::RawImage,
    ifd: Option<&Ifd>,
) -> Result<Decoded, LoadError> {
    let corrupt = |reason: String| LoadError::Corrupt {
        path: path.to_path_buf(),
        reason,
    };
    let rawler::RawImageData::Integer(data) = &img.data else {
        return Err(corrupt(
            "floating-point RAW data (an HDR merge) is not read".into(),
        ));
    };
    let cpp = img.cpp.max(1);
    if data.len() < img.width * img.height * cpp {
        return Err(LoadError::Damaged {
            path: path.to_path_buf(),
            reason: "the decoder found fewer samples than the sensor has pixels".into(),
        });
    }
    let (left, top, w, h) = match &img.active_area {
        Some(r) if r.p.x + r.d.w <= img.width && r.p.y + r.d.h <= img.height => {
            (r.p.x, r.p.y, r.d.w, r.d.h)
        }
        _ => (0, 0, img.width, img.height),
    };
    check_size(path, w, h)?;
    let bl = &img.blacklevel;
    let black_at = |x: usize, y: usize, c: usize| -> f32 {
        let (bw, bh) = (bl.width.max(1), bl.height.max(1));
        let k =
            (((y + top) % bh) * bw + (x + left) % bw) * bl.cpp.max(1) + c.min(bl.cpp.max(1) - 1);
        bl.levels.get(k).or(bl.levels.first()).map_or(0.0, |r| {
            if r.d == 0 {
                0.0
            } else {
                r.n as f32 / r.d as f32
            }
        })
    };
    let white_of = |c: usize| -> f32 {
        img.whitelevel
            .0
            .get(c)
            .or(img.whitelevel.0.first())
            .map_or(65535.0, |&v| v.min(65535) as f32)
    };
    let mut decoded = match (&img.photometric, cpp) {
        (rawler::rawimage::RawPhotometricInterpretation::Cfa(config), 1) => {
            let cfa = &config.cfa;
            if (cfa.width, cfa.height) != (2, 2) {
                return Err(LoadError::Unsupported {
                    path: path.to_path_buf(),
                    reason: format!(
                        "its {} × {} colour filter (not a 2 × 2 Bayer pattern) is not measured",
                        cfa.width, cfa.height
                    ),
                });
            }
            let mut values = Vec::with_capacity(w * h);
            for y in 0..h {
                let row = (y + top) * img.width + left;
                values.extend_from_slice(&data[row..row + w]);
            }
            let color_at = |x: usize, y: usize| cfa.color_at(y + top, x + left);
            let black = |x: usize, y: usize| black_at(x, y, 0);
            let colour = DecoderColour {
                matrix: rawler_matrix(img),
                wb: Some(img.wb_coeffs),
                orientation: img.orientation.to_u16(),
            };
            let (white, size) = (white_of(0), (w, h));
            mosaic_capture(path, values, size, &color_at, &black, white, ifd, colour)?
        }
        (_, 3) => {
            // Linear (already demosaiced) camera RGB, as phones and Adobe's converter's
            // lossy DNGs write: each channel a full-resolution linear plane, black
            // subtracted and scaled by its own white.
            let planes = [Channel::R, Channel::G, Channel::B]
                .into_iter()
                .enumerate()
                .map(|(c, channel)| {
                    let range_black = black_at(0, 0, c);
                    let range = (white_of(c) - range_black).max(1.0);
                    ChannelPlane {
                        channel,
                        plane: Plane::from_fn(w, h, |x, y| {
                            (f32::from(data[((y + top) * img.width + x + left) * 3 + c])
                                - black_at(x, y, c))
                                / range
                        }),
                        step: 1,
                        offset_x: 0,
                        offset_y: 0,
                    }
                })
                .collect();
            Decoded::planes(Capture::of_planes(w, h, planes, false))
        }
        (_, 1) => {
            let black = black_at(0, 0, 0);
            let range = (white_of(0) - black).max(1.0);
            let plane = Plane::from_fn(w, h, |x, y| {
                (f32::from(data[(y + top) * img.width + x + left]) - black_at(x, y, 0)) / range
            });
            Decoded::planes(Capture::of_planes(
                w,
                h,
                vec![ChannelPlane {
                    channel: Channel::Y,
                    plane,
                    step: 1,
                    offset_x: 0,
                    offset_y: 0,
                }],
                false,
            ))
        }
        (_, n) => {
            return Err(LoadError::Unsupported {
                path: path.to_path_buf(),
                reason: format!("{n} samples per pixel: neither a CFA mosaic nor RGB"),
            });
        }
    };
    decoded.capture.identity.make = named(&img.clean_make);
    decoded.capture.identity.model = named(&img.clean_model);
    Ok(decoded)
}

/// rawler's XYZ → camera matrix for D65 (else the first it has), 3 × 3.
fn rawler_matrix(img: &rawler::RawImage) -> Option<[[f64; 3]; 3]> {
    use rawler::imgop::xyz::Illuminant;
    let m = img
        .color_matrix
        .get(&Illuminant::D65)
        .or_else(|| img.color_matrix.values().next())?;
    (m.len() >= 9 && m.iter().take(9).all(|v| v.is_finite()) && m.iter().any(|v| *v != 0.0))
        .then(|| std::array::from_fn(|r| std::array::from_fn(|k| f64::from(m[3 * r + k]))))
}

/// A decoder refused a whole file in words of its own internals: what that means, and
/// what to do.
const UNREADABLE: &str = "the RAW decoder could not make sense of it (a directory, a \
     record or the image data in it is corrupt, or written in a form the decoder does not \
     know): copy it from the card again, or convert the original to DNG with Adobe DNG \
     Converter or `dnglab convert` and open the DNG";

/// Why a DNG of lossy-JPEG mosaic tiles is refused, and what to do.
pub(super) const LOSSY_MOSAIC: &str = "its raw image is stored in lossy-compressed \
     (DCT JPEG) tiles, as Blackmagic cameras record CinemaDNG at 3:1 and above, and no \
     decoder here reads those; lossy compression also alters the fine detail blur is \
     measured from: record the calibration shots as uncompressed or lossless CinemaDNG";

/// Every decoder refused the file: why, in words that say what to do. A camera the
/// decoders do not know is named (convert it to DNG); a file that ends before its own
/// directories or image data say it does is damaged, and where it was cut is said.
pub(super) fn explain(
    path: &Path,
    bytes: &[u8],
    rawler: RawlerRefusal,
    fallback: Option<LoadError>,
) -> LoadError {
    let refusal = match rawler {
        RawlerRefusal::Ours(e) => return e,
        RawlerRefusal::Refused(e) => Ok(e),
        RawlerRefusal::Panicked(stage) => Err(stage),
    };
    // A camera no decoder knows is named first: the decoders stopped before its image
    // data, so the cure is a converter that knows it, whatever else is wrong.
    if let Ok(rawler::RawlerError::Unsupported { make, model, .. }) = &refusal
        && !(make.trim().is_empty() && model.trim().is_empty())
    {
        return LoadError::Unsupported {
            path: path.to_path_buf(),
            reason: format!(
                "unsupported camera {} {}: no decoder here knows it; convert the file to DNG \
                 with Adobe DNG Converter or `dnglab convert` and open the DNG",
                make.trim(),
                model.trim(),
            ),
        };
    }
    // A DNG whose mosaic is lossy JPEG: well formed, but no decoder here reads it.
    if super::raw_ifd(bytes).is_some_and(|ifd| super::tiff::lossy_jpeg_mosaic(bytes, &ifd)) {
        return LoadError::Unsupported {
            path: path.to_path_buf(),
            reason: LOSSY_MOSAIC.into(),
        };
    }
    // The fallback decoder's own finding, where it located the damage or the missing
    // picture (rawler may have stopped on the file before its checks).
    let fallback = match fallback {
        Some(e @ (LoadError::Damaged { .. } | LoadError::NoImage { .. })) => return e,
        other => other,
    };
    if let Some(reason) = super::damage::diagnose(bytes) {
        let path = path.to_path_buf();
        return if reason.starts_with(super::damage::MISSING) {
            LoadError::NoImage { path, reason }
        } else {
            LoadError::Damaged { path, reason }
        };
    }
    let rawler_words = match &refusal {
        Ok(rawler::RawlerError::Unsupported { .. }) => {
            "not a RAW format lensblur knows".to_string()
        }
        Ok(rawler::RawlerError::DecoderFailed(m)) => {
            let m = one_line(m);
            // rawler's I/O failures are reads past the end of what it was given.
            if m.contains("I/O") || m.contains("fill whole buffer") || m.contains("EOF") {
                return LoadError::Damaged {
                    path: path.to_path_buf(),
                    reason: format!(
                        "truncated at byte {}: the decoder needed data past the end",
                        bytes.len()
                    ),
                };
            }
            // The decoder's own words name its internals, not what to do.
            UNREADABLE.to_string()
        }
        Err(stage) => stage.words(),
    };
    LoadError::Corrupt {
        path: path.to_path_buf(),
        reason: match fallback {
            // What the photographer can do about a file no decoder recognises: it may
            // be a camera's RAW that only a converter knows, or no photo at all.
            // Where rawler does not know the format but rawloader does and stops in
            // it, the file is one of rawloader's, corrupt: its words say so.
            Some(e)
                if rawler_words.starts_with("not a RAW")
                    && Stopped::said(&super::fallback_words(&e)) =>
            {
                super::fallback_words(&e)
            }
            Some(_) if rawler_words.starts_with("not a RAW") => format!(
                "{rawler_words}; if it is a camera's RAW file, convert it to DNG with \
                 Adobe DNG Converter or `dnglab convert` and open the DNG (PNG, TIFF and \
                 JPEG are read as they are)"
            ),
            _ => rawler_words,
        },
    }
}

/// What a decoder's header-only pass finds: the active area's size, the camera's make
/// and model.
pub(super) type RawHeader = ((usize, usize), Option<String>, Option<String>);

/// rawler's header-only pass: the active area's size and the camera's names, or `None`
/// where rawler does not read the file (or stops on it).
pub(super) fn rawler_header(bytes: &[u8]) -> Option<RawHeader> {
    let _quiet = QuietPanics::new();
    let source = rawler::rawsource::RawSource::new_from_slice(bytes);
    let params = rawler::decoders::RawDecodeParams::default();
    let head = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        rawler::get_decoder(&source)?.raw_image(&source, &params, true)
    }));
    let Ok(Ok(head)) = head else {
        return None;
    };
    let size = match &head.active_area {
        Some(r) if r.p.x + r.d.w <= head.width && r.p.y + r.d.h <= head.height => (r.d.w, r.d.h),
        _ => (head.width, head.height),
    };
    Some((size, named(&head.clean_make), named(&head.clean_model)))
}

/// rawloader's header-only pass: the active area's size and the camera's names.
///
/// # Errors
/// rawloader does not read the file.
pub(super) fn rawloader_header(path: &Path, bytes: &[u8]) -> Result<RawHeader, LoadError> {
    let head = rawloader_head(path, bytes)?;
    let [top, right, bottom, left] = head.crops;
    let size = (
        head.width.saturating_sub(left + right),
        head.height.saturating_sub(top + bottom),
    );
    Ok((size, named(&head.clean_make), named(&head.clean_model)))
}

/// Whether a TIFF is a camera's own RAW (not a DNG): a CR2, or a TIFF whose first
/// directory names one of the makers whose TIFF-based RAWs rawler reads by their
/// Make (a NEF's first directory is a thumbnail, a CR2's a JPEG preview).
pub(super) fn camera_raw(bytes: &[u8]) -> bool {
    const MAKERS: &[&str] = &[
        "Canon",
        "PENTAX",
        "PENTAX Corporation",
        "RICOH IMAGING COMPANY, LTD.",
        "Phase One",
        "Phase One A/S",
        "Leaf",
        "Hasselblad",
        "SONY",
        "Mamiya-OP Co.,Ltd.",
        "OLYMPUS IMAGING CORP.",
        "OLYMPUS CORPORATION",
        "OLYMPUS OPTICAL CO.,LTD",
        "OM Digital Solutions",
        "SAMSUNG",
        "SEIKO EPSON CORP.",
        "EASTMAN KODAK COMPANY",
        "Eastman Kodak Company",
        "KODAK",
        "Kodak",
        "Panasonic",
        "LEICA",
        "LEICA CAMERA AG",
        "NIKON",
        "Nikon",
        "NIKON CORPORATION",
    ];
    if bytes.get(8..10) == Some(b"CR") {
        return true;
    }
    let Ok(ifd) = super::tiff_ifd0(bytes) else {
        return false;
    };
    ifd.get(&271).is_some_and(|v| {
        let make: String = v
            .iter()
            .take_while(|&&c| c != 0.0)
            .map(|&c| char::from(c as u8))
            .collect();
        MAKERS.contains(&make.trim_end())
    })
}

/// A RAW file through rawloader, whose header-only pass gives the declared size to
/// check against our limits before the real decode allocates the image.
pub(super) fn rawloader_capture(
    path: &Path,
    bytes: &[u8],
    ifd: Option<&Ifd>,
) -> Result<Decoded, LoadError> {
    let head = rawloader_head(path, bytes)?;
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
    let _quiet = QuietPanics::new();
    let decoded = std::panic::catch_unwind(|| rawloader::decode(&mut std::io::Cursor::new(bytes)))
        .map_err(|_| stopped(path, Stopped::Image))?
        .map_err(|e| rawloader_error(path, &e, Stopped::Image))?;
    from_rawloader(path, &decoded, ifd)
}

/// rawloader's header-only pass (its image left empty).
fn rawloader_head(path: &Path, bytes: &[u8]) -> Result<rawloader::RawImage, LoadError> {
    let _quiet = QuietPanics::new();
    std::panic::catch_unwind(|| rawloader::decode_dummy(&mut std::io::Cursor::new(bytes)))
        .map_err(|_| stopped(path, Stopped::Header))?
        .map_err(|e| rawloader_error(path, &e, Stopped::Header))
}

/// A decoder panicked on the file, there.
fn stopped(path: &Path, stage: Stopped) -> LoadError {
    LoadError::Corrupt {
        path: path.to_path_buf(),
        reason: stage.words(),
    }
}

/// rawloader's refusal as one line. It reports its decoders' panics (in `stage`) as
/// errors: a panic is never the message.
fn rawloader_error(path: &Path, e: &rawloader::RawLoaderError, stage: Stopped) -> LoadError {
    let m = one_line(&e.to_string());
    if m.contains("panic") {
        stopped(path, stage)
    } else {
        LoadError::Corrupt {
            path: path.to_path_buf(),
            reason: UNREADABLE.into(),
        }
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
pub(super) struct QuietPanics;

impl QuietPanics {
    pub(super) fn new() -> Self {
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
pub(super) fn one_line(message: &str) -> String {
    let first = message.lines().next().unwrap_or_default();
    let bare = first.strip_prefix("RawLoaderError: ").unwrap_or(first);
    bare.trim_matches('"').trim().to_string()
}

/// rawloader's image as our planes: the active area of its CFA mosaic.
fn from_rawloader(
    path: &Path,
    img: &rawloader::RawImage,
    ifd: Option<&Ifd>,
) -> Result<Decoded, LoadError> {
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
    let colour = DecoderColour {
        matrix: Some(std::array::from_fn(|r| {
            std::array::from_fn(|k| f64::from(img.xyz_to_cam[r][k]))
        })),
        wb: Some(img.wb_coeffs),
        orientation: img.orientation.to_u16(),
    };
    let white = f32::from(img.whitelevels[0]);
    let mut d = mosaic_capture(path, values, (w, h), &color_at, &black, white, ifd, colour)?;
    d.capture.identity.make = named(&img.clean_make);
    d.capture.identity.model = named(&img.clean_model);
    Ok(d)
}

/// A decoder's cleaned-up camera name, `None` where it has none.
fn named(name: &str) -> Option<String> {
    Some(name.to_string()).filter(|s| !s.is_empty())
}
