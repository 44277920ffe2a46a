//! `lensblur deblur PHOTO --out OUT.{tiff,png,dng} (--profile P.json | --kernels K.json)
//! [--focal F --aperture A] [--method hqs|irls|wiener]`: remove the lens blur with the
//! kernels a profile predicts at the photo's settings, or a kernels file's. A RAW photo
//! can be written back as a DNG (its CFA deblurred, its metadata kept) for a RAW editor.

use super::common::progress_job;
use anyhow::{Context, Result, bail};
use lensblur::deblur::output::write_deblurred;
use lensblur::deblur::source::{Prefer, ScatteredKernels, load_kernels};
use lensblur::deblur::{DeblurOptions, KernelSource, Method, ProfileKernels, deblur_capture};
use lensblur::plane::Capture;
use lensblur::plane::LensSetting;
use lensblur::profile::Profile;
use lensblur::raw::{LoadOptions, load_capture};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Default)]
pub struct Args {
    /// The photo: a RAW file, or a linear 16-bit PNG/TIFF (8-bit images are sRGB-decoded).
    pub photo: PathBuf,
    /// Where to write the result: .tiff/.tif or .png (16-bit linear RGB), or, for a RAW
    /// photo, .dng (the deblurred CFA with the original's metadata, for a RAW editor).
    /// A RAW photo also gets a developed 8-bit sRGB preview beside it
    /// (`<name>.preview.png`).
    #[arg(long)]
    pub out: PathBuf,
    /// A lens profile (lensblur calibrate): kernels predicted at the photo's settings.
    #[arg(long, conflicts_with = "kernels", required_unless_present = "kernels")]
    pub profile: Option<PathBuf>,
    /// A kernels file (lensblur kernels, or any lensblur.kernels/1 file).
    #[arg(long)]
    pub kernels: Option<PathBuf>,
    /// Focal length in mm, when EXIF lacks it or is wrong.
    #[arg(long)]
    pub focal: Option<f64>,
    /// Aperture as an f-number, when EXIF lacks it or is wrong.
    #[arg(long)]
    pub aperture: Option<f64>,
    /// hqs (fast, hyper-Laplacian prior), irls (Levin et al.), or wiener (preview).
    #[arg(long, default_value = "hqs")]
    pub method: String,
    /// From a kernels file holding both: use the non-parametric kernels or the Gaussians.
    #[arg(long, value_enum, default_value = "kernels")]
    pub prefer: PreferArg,
    /// Use a profile made for another camera or lens unit anyway.
    #[arg(long)]
    pub force: bool,
    /// Use a profile at a focal length or aperture outside its calibrated range.
    #[arg(long)]
    pub allow_extrapolation: bool,
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum PreferArg {
    #[default]
    Kernels,
    Gaussians,
}

pub fn run(args: Args) -> Result<()> {
    let Some(method) = Method::from_name(&args.method) else {
        bail!(
            "--method must be hqs, irls or wiener (got '{}')",
            args.method
        );
    };
    for (name, v) in [("--focal", args.focal), ("--aperture", args.aperture)] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0)
        {
            bail!("{name} must be a positive number (got {v})");
        }
    }
    // Refuse an output we cannot write before the work, not after it.
    let ext = args
        .out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if !matches!(ext.as_str(), "png" | "tif" | "tiff" | "dng") {
        bail!(
            "{}: the output must be .tiff, .tif or .png (16-bit linear), or .dng for a RAW photo",
            args.out.display()
        );
    }
    let out_dir = args
        .out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !out_dir.is_dir() {
        bail!(
            "{}: the folder {} does not exist",
            args.out.display(),
            out_dir.display()
        );
    }
    if same_file(&args.photo, &args.out) {
        bail!(
            "{}: the output would overwrite the photo",
            args.out.display()
        );
    }
    let capture = load_capture(&args.photo, &LoadOptions::default())?;
    if ext == "dng" && (!capture.is_raw || capture.raw.is_none()) {
        bail!(
            "{}: only a RAW photo can be written as a DNG (give .tiff or .png)",
            args.photo.display()
        );
    }
    let photo_setting = (
        args.focal.or(capture.setting_focal_mm),
        args.aperture.or(capture.setting_f_number),
    );
    let described: String;
    let source: Box<dyn KernelSource> = match (&args.profile, &args.kernels) {
        (Some(p), _) => {
            let mut profile = Profile::load(p)?;
            let (Some(focal_mm), Some(f_number)) = photo_setting else {
                bail!(
                    "{}: focal length or aperture unknown (not in EXIF): give --focal and --aperture",
                    args.photo.display()
                );
            };
            if (profile.norm.width, profile.norm.height) != (capture.width, capture.height) {
                bail!(
                    "{}: the photo is {} × {} but the profile {} is for a {} × {} sensor (another camera?)",
                    args.photo.display(),
                    capture.width,
                    capture.height,
                    p.display(),
                    profile.norm.width,
                    profile.norm.height
                );
            }
            // Every check before any warning: a refused photo gets its one-line reason
            // and nothing else.
            let identity_warnings = profile
                .check_identity(&capture.identity, args.force)
                .with_context(|| format!("{} and {}", args.photo.display(), p.display()))?;
            let setting = LensSetting { focal_mm, f_number };
            profile.allow_extrapolation = args.allow_extrapolation;
            profile
                .check_setting(setting)
                .with_context(|| format!("{}: {}", args.photo.display(), p.display()))?;
            if !identity_warnings.is_empty() {
                eprintln!("lensblur: warning: {}", identity_warnings.join("; "));
            }
            if !profile.norm.contains(setting) {
                eprintln!(
                    "lensblur: warning: f = {focal_mm} mm, f/{f_number} is outside the calibrated range; extrapolating"
                );
            }
            described = format!(
                "the profile {} at {focal_mm} mm, f/{f_number}",
                file_name(p)
            );
            Box::new(ProfileKernels { profile, setting })
        }
        (None, Some(k)) => {
            let file = load_kernels(k)?;
            if (file.width, file.height) != (capture.width, capture.height) {
                bail!(
                    "{}: the photo is {} × {} but {} was measured on {} × {}",
                    args.photo.display(),
                    capture.width,
                    capture.height,
                    k.display(),
                    file.width,
                    file.height
                );
            }
            if let ((Some(pf), Some(pa)), Some(kf), Some(ka)) =
                (photo_setting, file.focal_mm, file.f_number)
                && ((pf - kf).abs() > 1e-6 * kf.abs() || (pa - ka).abs() > 1e-6 * ka.abs())
            {
                eprintln!(
                    "lensblur: warning: {} was measured at f = {kf} mm, f/{ka} but the photo is at f = {pf} mm, f/{pa}",
                    k.display()
                );
            }
            let prefer = match args.prefer {
                PreferArg::Kernels => Prefer::default(),
                PreferArg::Gaussians => Prefer::Gaussian,
            };
            described = format!("the kernels {}", file_name(k));
            Box::new(ScatteredKernels::checked(
                file,
                prefer,
                &k.display().to_string(),
            )?)
        }
        (None, None) => bail!("give --profile or --kernels"),
    };
    let job = progress_job();
    let opts = DeblurOptions {
        method,
        ..DeblurOptions::default()
    };
    let out = deblur_capture(&capture, source.as_ref(), &opts, &job)
        .with_context(|| args.photo.display().to_string())?;
    let note = format!(
        "Deblurred by {} ({}) with {described}",
        lensblur::dng::SOFTWARE,
        method.name()
    );
    write_output(&args.out, &args.photo, &out, &note)?;
    eprintln!(
        "{}: deblurred ({}) to {}",
        args.photo.display(),
        method.name(),
        args.out.display()
    );
    Ok(())
}

/// Writes a deblurred capture where `out`'s extension says (a RAW photo's developed
/// preview beside it), and says so.
fn write_output(out: &Path, photo: &Path, deblurred: &Capture, note: &str) -> Result<()> {
    let written = write_deblurred(out, Some(file_name(photo)), deblurred, note)?;
    if let Some(w) = &written.warning {
        eprintln!("lensblur: warning: {}: {w}", photo.display());
    }
    if let Some(p) = &written.preview {
        eprintln!("{}: preview {}", out.display(), p.display());
    }
    Ok(())
}

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Whether two paths name one existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}
