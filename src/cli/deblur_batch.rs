//! `lensblur deblur PHOTO|DIR... --out-dir OUTDIR [--profiles PROFILEDIR] [--format
//! tiff|png|dng] [--allow-extrapolation] [--jobs N]`: many photos, each with the
//! profile its EXIF matches (`lensblur::batch` holds the rule), written as
//! `<OUTDIR>/<stem>.<format>`. Skips are reported, not failures; the exit status is
//! non-zero only when a photo failed.

use super::common::progress_job;
use anyhow::{Context, Result, bail};
use lensblur::batch::{
    BatchOptions, Outcome, OutputFormat, ProfileLibrary, Skip, collect_photos, plan,
    run as run_batch,
};
use lensblur::deblur::output::{
    deblurred_note, output_supported, write_deblurred, write_like_original,
};
use lensblur::deblur::{DeblurOptions, KernelSource, Method, deblur_capture};
use lensblur::job::JobContext;
use lensblur::model::{KernelModel, LateralColour};
use lensblur::plane::Capture;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Default)]
pub struct BatchArgs {
    /// Batch: the folder the outputs go to, `<photo's stem>.<format>` each (made if
    /// missing). Photos whose output is already there and complete are skipped.
    #[arg(long)]
    pub out_dir: Option<PathBuf>,
    /// Batch: a folder of lens profiles (subfolders searched); each photo gets the one
    /// that matches its EXIF camera, lens and sensor size at its focal length and
    /// aperture. Default: the profile library the studio saves into,
    /// ~/lensblur/profiles unless another was chosen there (File ▸ Export ▸ Choose the
    /// profile library…).
    #[arg(
        long,
        requires = "out_dir",
        conflicts_with_all = ["out", "profile", "kernels", "focal", "aperture", "force"]
    )]
    pub profiles: Option<PathBuf>,
    /// Batch: the output format. auto: a RAW photo as DNG (its editor develops it as
    /// before), an RGB photo in its own format and colour (JPEG in, JPEG out, ICC and
    /// EXIF kept); tiff or png: 16-bit linear (camera RGB for a RAW photo); dng: RAW
    /// photos only, others skipped.
    #[arg(long, value_enum, default_value = "auto")]
    pub format: FormatArg,
    /// Batch: photos decoded, and photos written, at once while one deblurs on every
    /// core (default: one per four cores, as memory allows).
    #[arg(long)]
    pub jobs: Option<usize>,
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum FormatArg {
    #[default]
    Auto,
    Tiff,
    Png,
    Dng,
}

/// Deblurs one loaded photo with a chosen source and writes it: the single photo's
/// step ([`write_one`] is the writing half, which every photo of a batch goes through).
/// `described` names the kernels (a DNG's note of what was done says it). Returns the
/// preview written, if any.
///
/// # Errors
/// The deblurring failed, or the output cannot be written.
#[allow(clippy::too_many_arguments)]
pub fn deblur_one(
    photo: &Path,
    capture: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    out: &Path,
    described: &str,
    like_original: bool,
    job: &JobContext,
) -> Result<Option<PathBuf>> {
    let deblurred =
        deblur_capture(capture, source, opts, job).with_context(|| photo.display().to_string())?;
    write_one(
        photo,
        &deblurred,
        opts.method,
        out,
        described,
        like_original,
    )
}

/// Writes a deblurred photo: as its original is (`like_original`), or by `out`'s
/// extension with the original's file name in a DNG; a preview's warning printed.
/// Returns the preview written, if any.
///
/// # Errors
/// The output cannot be written.
pub fn write_one(
    photo: &Path,
    deblurred: &Capture,
    method: Method,
    out: &Path,
    described: &str,
    like_original: bool,
) -> Result<Option<PathBuf>> {
    let note = deblurred_note(method, described);
    let written = if like_original {
        write_like_original(out, photo, deblurred, &note)?
    } else {
        write_deblurred(out, Some(file_name(photo)), deblurred, &note)?
    };
    if let Some(w) = &written.warning {
        eprintln!("lensblur: warning: {}: {w}", photo.display());
    }
    Ok(written.preview)
}

/// A path's file name (the whole path where it has none).
pub fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Runs a batch: `photos` (files and folders) with the profiles `b` names.
pub fn run(
    photos: &[PathBuf],
    b: &BatchArgs,
    allow_extrapolation: bool,
    kernel_model: Option<KernelModel>,
    lateral_colour: LateralColour,
    deblur: &DeblurOptions,
) -> Result<()> {
    let Some(out_dir) = &b.out_dir else {
        bail!("a batch needs --out-dir");
    };
    let profiles = b.profiles.clone().unwrap_or_else(|| {
        lensblur::recent::profile_library(&lensblur::recent::default_settings_file())
    });
    let format = match b.format {
        FormatArg::Auto => OutputFormat::Auto,
        FormatArg::Tiff => OutputFormat::Tiff,
        FormatArg::Png => OutputFormat::Png,
        FormatArg::Dng => OutputFormat::Dng,
    };
    debug_assert!(format == OutputFormat::Auto || output_supported(format.extension()));
    if b.jobs == Some(0) {
        bail!("--jobs must be at least 1");
    }
    lensblur::io::create_dir_all(out_dir)?;
    let library = ProfileLibrary::load(&profiles).map_err(|e| match &b.profiles {
        Some(_) => anyhow::Error::from(e),
        // The default library: say what it is and how to fill it or pass another.
        None => anyhow::anyhow!(
            "{e} (the profile library: save a profile into it from the studio, Export ▸ Lens profile to the library, or give --profiles FOLDER)"
        ),
    })?;
    for w in &library.warnings {
        eprintln!("lensblur: warning: {w}");
    }
    let photos = collect_photos(photos, out_dir)?;
    if photos.is_empty() {
        bail!("no photos among the paths given");
    }
    let opts = BatchOptions {
        out_dir: out_dir.clone(),
        format,
        allow_extrapolation,
        deblur: *deblur,
        memory_budget: None,
        max_parallel: b.jobs,
        kernel_model,
        lateral_colour,
    };
    let planned = plan(&photos, &library, &opts);
    let job = progress_job();
    let report = run_batch(
        &planned,
        &library,
        &opts,
        &job,
        &|photo, deblurred, out, described| {
            let like = format == OutputFormat::Auto;
            write_one(photo, deblurred, deblur.method, out, described, like)
                .map(|_| ())
                .map_err(|e| format!("{e:#}"))
        },
    );
    for o in &report.outcomes {
        let photo = o.photo.display();
        match &o.outcome {
            Outcome::Done {
                profile,
                setting,
                focus_m,
                extrapolated,
                picture,
            } => {
                eprintln!(
                    "{photo}: deblurred with {} at {setting}{} to {}",
                    profile.display(),
                    if *extrapolated { " (extrapolated)" } else { "" },
                    o.output.display()
                );
                // As for one photo: outside the shots' range, far from any shot, where
                // the profile recorded a large held-out error, or focused far from
                // where the shots were.
                let entry = library.profiles.iter().find(|p| &p.path == profile);
                let trust = entry.and_then(|p| p.profile.trust_line(*setting, *focus_m, None));
                if let Some(line) = trust {
                    eprintln!("{photo}: {line}");
                }
                let kind = entry.and_then(|p| {
                    let name = profile.display().to_string();
                    p.profile
                        .picture_warning(*picture, &photo.to_string(), &name)
                });
                if let Some(w) = kind {
                    eprintln!("lensblur: warning: {w}");
                }
            }
            Outcome::Skipped(s @ Skip::OutOfRange { .. }) => {
                eprintln!("{photo}: skipped: {s} (--allow-extrapolation to deblur it anyway)");
            }
            Outcome::Skipped(s) => eprintln!("{photo}: skipped: {s}"),
            Outcome::Failed(e) => {
                // Errors from reading the photo name it already.
                let e = e.strip_prefix(&format!("{photo}: ")).unwrap_or(e.as_str());
                eprintln!("{photo}: failed: {e}");
            }
            Outcome::Cancelled => eprintln!("{photo}: cancelled"),
        }
    }
    for line in report.summary() {
        eprintln!("{line}");
    }
    let failed = report.failed();
    if failed > 0 {
        bail!("{failed} of {} photos failed", report.outcomes.len());
    }
    Ok(())
}
