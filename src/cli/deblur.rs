//! `lensblur deblur PHOTO --out OUT.{tiff,png,dng} (--profile P.json | --kernels K.json)
//! [--focal F --aperture A] [--method hqs|irls|wiener] [--device auto|gpu|cpu]`: remove the lens blur with the
//! kernels a profile predicts at the photo's settings, or a kernels file's. A RAW photo
//! can be written back as a DNG (its CFA deblurred, its metadata kept) for a RAW editor.
//! With `--out-dir` (and the profile library, or `--profiles`), many photos at once
//! (`deblur_batch`).

use super::common::progress_job;
use super::deblur_batch::{deblur_one, file_name};
use anyhow::{Context, Result, bail};
use lensblur::deblur::output::{is_jpeg, output_supported, profile_described};
use lensblur::deblur::source::{Prefer, ScatteredKernels, load_kernels};
use lensblur::deblur::{Amount, DeblurOptions, Device, KernelSource, Method, ProfileKernels};
use lensblur::model::{KernelModel, LateralColour};
use lensblur::plane::LensSetting;
use lensblur::profile::Profile;
use lensblur::raw::{LoadOptions, load_capture};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Default)]
pub struct Args {
    /// The photo: a RAW file, a linear 16-bit PNG/TIFF, or an 8-bit JPEG/PNG/TIFF
    /// (sRGB-decoded; deblurred as far as its noise and compression allow, best with a
    /// profile calibrated from the same kind of pictures). With --out-dir: photos and
    /// folders of photos.
    #[arg(required = true, num_args = 1..)]
    pub photos: Vec<PathBuf>,
    /// Where to write the result: .tiff/.tif or .png (16-bit linear RGB), or, for a RAW
    /// photo, .dng (the deblurred CFA with the original's metadata, for a RAW editor).
    /// A RAW photo also gets a developed 8-bit sRGB preview beside it
    /// (`<name>.preview.png`).
    #[arg(long, required_unless_present = "out_dir")]
    pub out: Option<PathBuf>,
    /// A lens profile (lensblur calibrate): kernels predicted at the photo's settings.
    #[arg(
        long,
        conflicts_with = "kernels",
        required_unless_present_any = ["kernels", "profiles", "out_dir"]
    )]
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
    /// The deconvolution: hqs (fast, hyper-Laplacian prior), irls (Levin et al.), or
    /// wiener (preview).
    #[arg(long, value_enum, default_value = "hqs")]
    pub method: MethodArg,
    /// Where to deblur: cpu (the reference), auto (a hardware GPU that can run the
    /// shaders when there is one, else the CPU), or gpu (any adapter, a software one
    /// included; an error without one). HQS and Wiener run on the GPU; IRLS on the CPU
    /// only.
    #[arg(long, value_enum, default_value = "cpu")]
    pub device: DeviceArg,
    /// How strongly to deblur, in percent of the method's result: 0 leaves the photo as
    /// it is, 100 is the method at its tuned strength, up to 200 carries it further.
    #[arg(long, default_value_t = 100.0)]
    pub amount: f64,
    /// Keep the colour the deconvolution adds at strong edges instead of holding each
    /// pixel's colour inside the photo's own around it (RGB photos; RAW ones always
    /// keep it).
    #[arg(long)]
    pub keep_fringes: bool,
    /// From a kernels file holding both: use the non-parametric kernels or the Gaussians.
    #[arg(long, value_enum, default_value = "kernels")]
    pub prefer: PreferArg,
    /// With a profile: deblur with its Gaussians, or with its predicted kernel shapes
    /// (default: the shapes where the profile holds a kernel-shape model, which
    /// calibration keeps only where it predicts held-out kernels better).
    #[arg(long, value_enum)]
    pub kernel_model: Option<KernelModelArg>,
    /// With a profile that knows where each channel's kernels sit: move red and blue
    /// back onto green as the blur is removed (correct), or leave the lens's lateral
    /// colour in the photo for lensfun's correction to remove afterwards (keep; doing
    /// both would move the channels twice).
    #[arg(long, value_enum, default_value = "correct")]
    pub lateral_colour: LateralColourArg,
    /// Use a profile made for another camera or lens unit anyway.
    #[arg(long)]
    pub force: bool,
    /// Use a profile at a focal length or aperture outside its calibrated range.
    #[arg(long)]
    pub allow_extrapolation: bool,
    /// Say where the deblur's time went, stage by stage (one photo).
    #[arg(long)]
    pub timings: bool,
    #[command(flatten)]
    pub batch: super::deblur_batch::BatchArgs,
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum MethodArg {
    /// Half-quadratic splitting with a hyper-Laplacian prior (fast).
    #[default]
    Hqs,
    /// Iteratively reweighted least squares (Levin et al.).
    Irls,
    /// Wiener deconvolution (a preview).
    Wiener,
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Self {
        match m {
            MethodArg::Hqs => Method::Hqs(lensblur::deblur::HqsParams::default()),
            MethodArg::Irls => Method::Irls(lensblur::deblur::IrlsParams::default()),
            MethodArg::Wiener => Method::Wiener(lensblur::deblur::WienerParams::default()),
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum DeviceArg {
    /// A hardware GPU that can run the shaders when there is one, else the CPU.
    Auto,
    /// Any adapter, a software one included.
    Gpu,
    /// The reference.
    #[default]
    Cpu,
}

impl From<DeviceArg> for Device {
    fn from(d: DeviceArg) -> Self {
        match d {
            DeviceArg::Auto => Device::Auto,
            DeviceArg::Gpu => Device::Gpu,
            DeviceArg::Cpu => Device::Cpu,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub enum KernelModelArg {
    Gaussian,
    Shape,
}

impl From<KernelModelArg> for KernelModel {
    fn from(m: KernelModelArg) -> Self {
        match m {
            KernelModelArg::Gaussian => KernelModel::Gaussian,
            KernelModelArg::Shape => KernelModel::Shape,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum LateralColourArg {
    #[default]
    Correct,
    Keep,
}

impl From<LateralColourArg> for LateralColour {
    fn from(m: LateralColourArg) -> Self {
        match m {
            LateralColourArg::Correct => LateralColour::Correct,
            LateralColourArg::Keep => LateralColour::Keep,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum PreferArg {
    #[default]
    Kernels,
    Gaussians,
}

pub fn run(args: Args) -> Result<()> {
    let opts = deblur_options(&args)?;
    let (method, device) = (opts.method, opts.device);
    if args.batch.out_dir.is_some() {
        return super::deblur_batch::run(
            &args.photos,
            &args.batch,
            args.allow_extrapolation,
            args.kernel_model.map(Into::into),
            args.lateral_colour.into(),
            &opts,
        );
    }
    let (Some(out), [photo]) = (&args.out, args.photos.as_slice()) else {
        bail!("one photo and --out, or photos and folders with --out-dir");
    };
    for (name, v) in [("--focal", args.focal), ("--aperture", args.aperture)] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0)
        {
            bail!("{name} must be a positive number (got {v})");
        }
    }
    let ext = check_output(photo, out)?;
    let capture = load_capture(photo, &LoadOptions::default())?;
    if ext == "dng" && (!capture.is_raw || capture.raw.is_none()) {
        bail!(
            "{}: only a RAW photo can be written as a DNG (give .tiff or .png)",
            photo.display()
        );
    }
    let photo_setting = (
        args.focal.or(capture.setting_focal_mm),
        args.aperture.or(capture.setting_f_number),
    );
    let (source, described) = match (&args.profile, &args.kernels) {
        (Some(p), _) => profile_source(&args, p, photo, &capture, photo_setting)?,
        (None, Some(k)) => kernels_source(&args, k, photo, &capture, photo_setting)?,
        (None, None) => bail!("give --profile or --kernels"),
    };
    // Said once, when the inputs are known good and the work starts (an adapter is
    // only looked for then): where it runs and, when not where asked, why.
    if device != Device::Cpu {
        let on = lensblur::deblur::gpu::describe(device, &method);
        eprintln!("lensblur: deblurring on the {on}");
    }
    let timings = std::sync::Arc::new(lensblur::timings::Timings::new());
    let job = if args.timings {
        progress_job().with_timings(std::sync::Arc::clone(&timings))
    } else {
        progress_job()
    };
    if let Some(preview) = deblur_one(
        photo,
        &capture,
        source.as_ref(),
        &opts,
        out,
        &described,
        // A JPEG is only ever written as its original is (8-bit sRGB, its ICC and EXIF).
        is_jpeg(out),
        &job,
    )? {
        eprintln!("{}: preview {}", out.display(), preview.display());
    }
    eprintln!(
        "{}: deblurred ({}) to {}",
        photo.display(),
        method.name(),
        out.display()
    );
    if args.timings {
        eprintln!("{}", timings.table());
    }
    Ok(())
}

/// The deblur's method, device, amount and fringes from the flags.
fn deblur_options(args: &Args) -> Result<DeblurOptions> {
    let (method, device) = (Method::from(args.method), Device::from(args.device));
    if !(0.0..=Amount::MAX_PERCENT).contains(&args.amount) {
        bail!(
            "--amount is a percentage from 0 to {} (got {})",
            Amount::MAX_PERCENT,
            args.amount
        );
    }
    Ok(DeblurOptions {
        method,
        device,
        amount: Amount::percent(args.amount),
        fringes: if args.keep_fringes {
            lensblur::deblur::Fringes::Keep
        } else {
            lensblur::deblur::Fringes::Suppress
        },
        ..DeblurOptions::default()
    })
}

/// Refuses an output that cannot be written before the work, not after it; returns
/// its extension, lower-case.
fn check_output(photo: &Path, out: &Path) -> Result<String> {
    let ext = out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    // A JPEG is written only as its original JPEG was: 8-bit sRGB, its ICC and EXIF.
    let photo_is_jpeg = {
        use std::io::Read;
        let mut magic = [0u8; 2];
        std::fs::File::open(photo)
            .and_then(|mut f| f.read_exact(&mut magic))
            .is_ok()
            && magic == [0xFF, 0xD8]
    };
    if is_jpeg(out) && !photo_is_jpeg {
        bail!(
            "{}: a .jpg output is for a JPEG photo; write .tiff, .png or (RAW) .dng",
            out.display()
        );
    }
    if !output_supported(&ext) && !is_jpeg(out) {
        bail!(
            "{}: the output must be .tiff, .tif or .png (16-bit linear), .dng for a RAW photo, \
             or .jpg for a JPEG photo",
            out.display()
        );
    }
    super::common::check_out_folder(out)?;
    if same_file(photo, out) {
        bail!("{}: the output would overwrite the photo", out.display());
    }
    Ok(ext)
}

/// The kernels a profile predicts at the photo's setting, once the photo passed its
/// checks (sensor size, identity, range), and what they are called.
fn profile_source(
    args: &Args,
    p: &Path,
    photo: &Path,
    capture: &lensblur::plane::Capture,
    photo_setting: (Option<f64>, Option<f64>),
) -> Result<(Box<dyn KernelSource>, String)> {
    let mut profile = Profile::load(p)?;
    let (Some(focal_mm), Some(f_number)) = photo_setting else {
        bail!(
            "{}: focal length or aperture unknown (not in EXIF): give --focal and --aperture",
            photo.display()
        );
    };
    if (profile.norm.width, profile.norm.height) != (capture.width, capture.height) {
        bail!(
            "{}: the photo is {} × {} but the profile {} is for a {} × {} sensor (another camera?)",
            photo.display(),
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
        .map_err(|e| {
            anyhow::anyhow!(
                "{} and {}: {e} (--force to use it anyway)",
                photo.display(),
                p.display()
            )
        })?;
    let setting = LensSetting { focal_mm, f_number };
    profile.allow_extrapolation = args.allow_extrapolation;
    profile.check_setting(setting).map_err(|e| {
        anyhow::anyhow!(
            "{}: {}: {e} (--allow-extrapolation to deblur anyway)",
            photo.display(),
            p.display()
        )
    })?;
    if !identity_warnings.is_empty() {
        eprintln!("lensblur: warning: {}", identity_warnings.join("; "));
    }
    // A JPEG deblurred with a RAW profile (or the other way round): said once.
    let names = (photo.display().to_string(), p.display().to_string());
    if let Some(w) = profile.picture_warning(capture.picture_kind(), &names.0, &names.1) {
        eprintln!("lensblur: warning: {w}");
    }
    // Outside the shots' range (only reached with --allow-extrapolation), far
    // from any shot, where the profile recorded a large held-out error, or
    // focused far from where the shots were.
    if let Some(line) = profile.trust_line(setting, capture.setting_focus_m, None) {
        eprintln!("lensblur: {line}");
    }
    let model = args
        .kernel_model
        .map_or_else(|| profile.kernel_model(), Into::into);
    let source = ProfileKernels::with_model(profile, setting, model)
        .with_context(|| p.display().to_string())?
        .with_lateral(args.lateral_colour.into());
    let described = profile_described(p, setting, model, source.lateral_colour());
    Ok((Box::new(source), described))
}

/// A kernels file's kernels, once it matches the photo's sensor, and what they are
/// called.
fn kernels_source(
    args: &Args,
    k: &Path,
    photo: &Path,
    capture: &lensblur::plane::Capture,
    photo_setting: (Option<f64>, Option<f64>),
) -> Result<(Box<dyn KernelSource>, String)> {
    let file = load_kernels(k)?;
    if (file.width, file.height) != (capture.width, capture.height) {
        bail!(
            "{}: the photo is {} × {} but {} was measured on {} × {}",
            photo.display(),
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
        let at = |focal_mm, f_number| LensSetting { focal_mm, f_number };
        eprintln!(
            "lensblur: warning: {} was measured at {} but the photo is at {}",
            k.display(),
            at(kf, ka),
            at(pf, pa)
        );
    }
    let prefer = match args.prefer {
        PreferArg::Kernels => Prefer::default(),
        PreferArg::Gaussians => Prefer::Gaussian,
    };
    let described = format!("the kernels {}", file_name(k));
    let source = ScatteredKernels::checked(file, prefer, &k.display().to_string())?;
    Ok((Box::new(source), described))
}

/// Whether two paths name one existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}
