//! `lensblur lensfun`: the lens's distortion, lateral colour and fall-off from a
//! calibration session's chart shots, written as a lensfun database entry (one XML
//! file for `~/.local/share/lensfun/`) for darktable, RawTherapee and the other
//! editors that correct lenses through lensfun.

use super::calibrate::measure_project;
use super::common::{load_chart, write_atomic, write_json};
use anyhow::{Context, Result, bail};
use lensblur::correction::lensfun::{NameOverrides, checked_entry};
use lensblur::correction::{
    CorrectionError, CorrectionOptions, DistortionModel, LensCorrection, LensfunNames, TcaModel,
};
use lensblur::project::{MeasurePlan, Stages};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Session manifest (or a studio session folder or its session.json); shots are
    /// detected, or taken from the cache in results/ beside it.
    #[arg(long)]
    pub manifest: PathBuf,
    /// Chart spec, where another chart than the manifest's was printed.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Where to write the lensfun entry (XML).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write every fit (all models, residuals, standard errors) as JSON.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// The distortion model to write (default: the simplest that fits as well as the
    /// others).
    #[arg(long, value_enum)]
    pub distortion_model: Option<DistortionArg>,
    /// The lateral-colour model to write (default: linear unless poly3 fits better).
    #[arg(long, value_enum)]
    pub tca_model: Option<TcaArg>,
    /// Leave the fall-off out (light that was not even, or a fall-off measured elsewhere).
    #[arg(long)]
    pub no_vignetting: bool,
    /// Camera maker as lensfun and your editor name it (default: EXIF Make).
    #[arg(long)]
    pub camera_maker: Option<String>,
    /// Camera model (default: EXIF Model).
    #[arg(long)]
    pub camera_model: Option<String>,
    /// Lens maker (default: EXIF LensMake, else the camera's maker).
    #[arg(long)]
    pub lens_maker: Option<String>,
    /// Lens model (default: EXIF LensModel).
    #[arg(long)]
    pub lens_model: Option<String>,
    /// Mount as lensfun names it, e.g. "Canon EF", "Sony E", "Nikon F AF" (default: a
    /// mount named after the camera). Give it when lensfun already knows the camera.
    #[arg(long)]
    pub mount: Option<String>,
    /// The camera's crop factor (default: from EXIF's 35 mm focal length).
    #[arg(long)]
    pub crop_factor: Option<f64>,
    /// The lens's focal range in mm, "24-105", or one length for a prime (default:
    /// EXIF LensSpecification).
    #[arg(long, value_parser = parse_range)]
    pub focal_range: Option<[f64; 2]>,
    /// Measure every shot again, ignoring (and replacing) cached results.
    #[arg(long)]
    pub no_cache: bool,
    /// Stop when any shot fails, instead of listing the failed shots and going on
    /// with the others.
    #[arg(long)]
    pub strict: bool,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum DistortionArg {
    Poly3,
    Poly5,
    Ptlens,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum TcaArg {
    Linear,
    Poly3,
}

fn parse_range(s: &str) -> Result<[f64; 2], String> {
    let parse = |t: &str| {
        t.trim()
            .trim_end_matches("mm")
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| format!("'{s}' is not a focal range such as 24-105 or 50"))
    };
    match s.split_once('-') {
        Some((a, b)) => {
            let (a, b) = (parse(a)?, parse(b)?);
            if b < a {
                return Err(format!("'{s}': the range's ends are the wrong way round"));
            }
            Ok([a, b])
        }
        None => parse(s).map(|v| [v, v]),
    }
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_out_folder(&args.out)?;
    let chart = match &args.chart {
        Some(_) => Some(load_chart(args.chart.as_deref())?),
        None => None,
    };
    let plan = MeasurePlan {
        require_setting: true,
        ..MeasurePlan::missing(Stages::Detect)
    };
    let mut project = measure_project(
        &args.manifest,
        "lensblur lensfun",
        chart,
        args.no_cache,
        plan,
        args.strict,
        None,
    )?;
    let first_file = project
        .shots()
        .find(|s| s.shot.setting().is_some() && s.state.detection.is_some())
        .map(|s| project.folder().join(&s.shot.path));
    let options = CorrectionOptions {
        distortion_model: args.distortion_model.map(|m| match m {
            DistortionArg::Poly3 => DistortionModel::Poly3,
            DistortionArg::Poly5 => DistortionModel::Poly5,
            DistortionArg::Ptlens => DistortionModel::PtLens,
        }),
        tca_model: args.tca_model.map(|m| match m {
            TcaArg::Linear => TcaModel::Linear,
            TcaArg::Poly3 => TcaModel::Poly3,
        }),
    };
    let job = project
        .geometry_job()
        .ok_or(CorrectionError::NoShots)?
        .with_options(options);
    let correction = job.measure()?;
    print_summary(&correction);
    let Some(first_file) = first_file else {
        bail!("no shot has a detected chart");
    };
    let header = lensblur::raw::read_header(&first_file)?;
    let overrides = NameOverrides {
        camera_maker: args.camera_maker.clone(),
        camera_model: args.camera_model.clone(),
        lens_maker: args.lens_maker.clone(),
        lens_model: args.lens_model.clone(),
        mount: args.mount.clone(),
        crop_factor: args.crop_factor,
        focal_range_mm: args.focal_range,
    };
    let focals: Vec<f64> = correction.focal.iter().map(|f| f.focal_mm).collect();
    let lens_names = LensfunNames::resolve(&header.exif, &overrides, &focals)
        .with_context(|| format!("{}", first_file.display()))?;
    let provenance = format!(
        "written by lensblur {} from {} shots of {} ({} × {} px); distortion {}, lateral colour {}",
        env!("CARGO_PKG_VERSION"),
        job.shots(),
        args.manifest.display(),
        correction.width,
        correction.height,
        correction.distortion_model.name(),
        correction.tca_model.name()
    );
    let xml = checked_entry(&lens_names, &correction, args.no_vignetting, &provenance)?;
    if let Some(path) = &args.report {
        write_json(path, &Report::new(&lens_names, &correction))?;
    }
    write_atomic(&args.out, xml.as_bytes())?;
    if args.mount.is_none() {
        eprintln!(
            "note: mount '{}' (a mount of its own): if lensfun already knows this camera, pass --mount with the mount it lists for it",
            lens_names.mount
        );
    }
    eprintln!(
        "wrote {}: {} {} on {} {}; copy it to ~/.local/share/lensfun/ for darktable and RawTherapee",
        args.out.display(),
        lens_names.lens_maker,
        lens_names.lens_model,
        lens_names.camera_maker,
        lens_names.camera_model
    );
    Ok(())
}

/// One line per focal length and per aperture: what was fitted and how well.
fn print_summary(c: &LensCorrection) {
    for f in &c.focal {
        let d = f.distortion_fit(c.distortion_model);
        let terms: Vec<String> = d
            .model
            .terms()
            .iter()
            .zip(d.coefficients.iter().zip(&d.std_errors))
            .map(|(n, (v, e))| format!("{n} {v:.6} ± {e:.6}"))
            .collect();
        let mut line = format!(
            "{} ({} shots): {} {} — {:+.2} px at the corners, RMS {:.3} px over {} corners",
            lensblur::plane::focal_text(f.focal_mm),
            f.shots,
            d.model.name(),
            terms.join(", "),
            d.corner_displacement_px,
            d.rms_px,
            d.corners
        );
        if d.outliers > 0 {
            line.push_str(&format!(" ({} set aside)", d.outliers));
        }
        if let Some(t) = f.tca_fit(c.tca_model) {
            line.push_str(&format!(
                "; lateral colour red {:+.2} px, blue {:+.2} px at the corners",
                t.red.corner_shift_px, t.blue.corner_shift_px
            ));
        }
        println!("{line}");
    }
    for v in &c.vignetting {
        println!(
            "{}: fall-off {:.2} stops at the corners (chart reached r = {:.2}), residual {:.2} %, light gradient {:.2} stops{}",
            v.setting,
            v.corner_stops,
            v.max_radius,
            100.0 * v.rms_relative,
            v.gradient_stops,
            if v.light_even() { "" } else { " (uneven)" }
        );
    }
}

/// `--report`: the names written and every fit.
#[derive(serde::Serialize)]
struct Report<'a> {
    schema: &'static str,
    camera_maker: &'a str,
    camera_model: &'a str,
    lens_maker: &'a str,
    lens_model: &'a str,
    mount: &'a str,
    crop_factor: f64,
    #[serde(flatten)]
    correction: &'a LensCorrection,
}

impl<'a> Report<'a> {
    fn new(n: &'a LensfunNames, correction: &'a LensCorrection) -> Self {
        Self {
            schema: "lensblur.lensfun-report/1",
            camera_maker: &n.camera_maker,
            camera_model: &n.camera_model,
            lens_maker: &n.lens_maker,
            lens_model: &n.lens_model,
            mount: &n.mount,
            crop_factor: n.crop_factor,
            correction,
        }
    }
}
