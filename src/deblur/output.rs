//! Writing a deblurred photo: the one place that picks the file format from the output
//! name, the writers of a deblurred photo (by its name, [`write_deblurred`], or as its
//! original is, [`write_like_original`]) and the "deblur, then write" step
//! ([`deblur_and_write`]), for the command line (one photo or a batch), the core's batch
//! and the studio's export.

use super::{DeblurError, DeblurOptions, KernelSource, Method};
use crate::develop::{Orient, develop, save_png};
use crate::job::JobContext;
use crate::plane::Capture;
use std::path::{Path, PathBuf};

/// What was written besides the result.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Written {
    /// A RAW photo's 8-bit preview beside the result (`<stem>.preview.png`).
    pub preview: Option<PathBuf>,
    /// Why the preview shows the linear planes rather than the developed RAW.
    pub warning: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error(transparent)]
    Dng(#[from] crate::dng::DngError),
    #[error(transparent)]
    Save(#[from] crate::raw::SaveError),
}

/// Why [`deblur_and_write`] failed: the deblurring (or its cancellation) of the photo
/// that was to be written to `path`, or the writing (whose error names its file).
#[derive(Debug, thiserror::Error)]
pub enum DeblurWriteError {
    #[error("{}: {source}", path.display())]
    Deblur { path: PathBuf, source: DeblurError },
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// Deblurs a capture with `source` and writes the result as [`write_deblurred`] does
/// (`note` in a DNG says what was done; [`deblurred_note`] is the usual one).
///
/// # Errors
/// The deblurring failed or was cancelled, or the output cannot be written.
pub fn deblur_and_write(
    capture: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    out: &Path,
    original_file_name: Option<String>,
    note: &str,
    job: &JobContext,
) -> Result<Written, DeblurWriteError> {
    let deblurred = super::deblur_capture(capture, source, opts, job).map_err(|source| {
        DeblurWriteError::Deblur {
            path: out.to_path_buf(),
            source,
        }
    })?;
    Ok(write_deblurred(out, original_file_name, &deblurred, note)?)
}

/// Writes a deblurred capture as its original photo is: a RAW photo as
/// [`write_deblurred`] does by `out`'s extension (a DNG, for the RAW editor), an RGB
/// photo in its original's format, bit depth, encoding, ICC profile and EXIF
/// ([`crate::raw::save_like_original`]): a JPEG in, a JPEG out that a viewer shows as
/// it showed the original.
///
/// # Errors
/// The original cannot be read again, or the output cannot be written.
pub fn write_like_original(
    out: &Path,
    original: &Path,
    deblurred: &Capture,
    note: &str,
) -> Result<Written, OutputError> {
    if deblurred.is_raw {
        let name = original
            .file_name()
            .map(|n| n.to_string_lossy().into_owned());
        return write_deblurred(out, name, deblurred, note);
    }
    if is_dng(out) {
        return Err(OutputError::Save(crate::raw::SaveError {
            path: out.to_path_buf(),
            reason: "a linear (demosaiced) RAW photo is not written back as a DNG: \
                     ask for --format tiff"
                .into(),
        }));
    }
    let bytes =
        crate::io::read_limited(original, crate::limits::MAX_IMAGE_FILE_BYTES).map_err(|e| {
            OutputError::Save(crate::raw::SaveError {
                path: out.to_path_buf(),
                reason: format!("reading the original again: {e}"),
            })
        })?;
    crate::raw::save_like_original(out, &crate::raw::full_planes(deblurred), &bytes)?;
    Ok(Written::default())
}

/// A deblurred photo's note of what was done: the software, the method and what it was
/// deblurred with (`described`, e.g. [`profile_described`]).
#[must_use]
pub fn deblurred_note(method: Method, described: &str) -> String {
    format!(
        "Deblurred by {} ({}) with {described}",
        crate::dng::SOFTWARE,
        method.name()
    )
}

/// Whether [`write_deblurred`] writes a file of this extension (lower case).
#[must_use]
pub fn output_supported(ext: &str) -> bool {
    matches!(ext, "png" | "tif" | "tiff" | "dng")
}

/// Whether `out` names a JPEG, which is only written as its original photo was
/// ([`write_like_original`]): 8-bit sRGB has no linear form.
#[must_use]
pub fn is_jpeg(out: &Path) -> bool {
    out.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("jpg") || e.eq_ignore_ascii_case("jpeg"))
}

/// Whether `out` names a DNG.
#[must_use]
pub fn is_dng(out: &Path) -> bool {
    out.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("dng"))
}

/// Writes a deblurred capture as `out`'s extension says: a DNG (the CFA with the
/// original's metadata and `note` saying what was done; RAW photos only) or 16-bit
/// linear TIFF/PNG. A RAW photo also gets its developed preview beside it, or the
/// linear planes' where it cannot be developed (said in [`Written::warning`]).
///
/// # Errors
/// The output cannot be written, or a DNG was asked for an RGB photo.
pub fn write_deblurred(
    out: &Path,
    original_file_name: Option<String>,
    deblurred: &Capture,
    note: &str,
) -> Result<Written, OutputError> {
    // The preview first: an output that exists implies its preview does, so a batch
    // that finds the output complete may skip the photo.
    let mut written = Written::default();
    if deblurred.is_raw {
        let preview = preview_path(out);
        match develop(deblurred, None, Orient::AsShot) {
            Ok(image) => save_png(&preview, &image)?,
            Err(e) => {
                written.warning = Some(format!("{e}; the preview shows the linear planes"));
                crate::raw::save_planes(&preview, &crate::raw::full_planes(deblurred), true)?;
            }
        }
        written.preview = Some(preview);
    }
    if is_dng(out) {
        crate::dng::write_capture_dng(out, deblurred, note, original_file_name)?;
    } else {
        crate::raw::save_planes(out, &crate::raw::full_planes(deblurred), false)?;
    }
    Ok(written)
}

/// `<stem>.preview.png` beside `out`.
#[must_use]
pub fn preview_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or_else(|| "out".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}.preview.png"))
}

/// How a deblurred photo's note names what it was deblurred with: "the profile NAME at
/// F mm, f/A", and "with its kernel shapes" when the shape model was used.
#[must_use]
pub fn profile_described(
    profile: &Path,
    setting: crate::plane::LensSetting,
    model: crate::model::KernelModel,
    lateral: Option<crate::model::LateralColour>,
) -> String {
    let name = profile.file_name().map_or_else(
        || profile.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let shapes = match model {
        crate::model::KernelModel::Shape => " with its kernel shapes",
        crate::model::KernelModel::Gaussian => "",
    };
    let lateral = match lateral {
        Some(crate::model::LateralColour::Correct) => ", lateral colour corrected",
        Some(crate::model::LateralColour::Keep) => ", lateral colour kept for lensfun",
        None => "",
    };
    format!("the profile {name} at {setting}{shapes}{lateral}")
}
