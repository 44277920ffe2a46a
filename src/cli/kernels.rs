//! `lensblur kernels SHOT --out kernels.json [--with-kernels] [--focal F --aperture A]`:
//! the 3× kernel and its Gaussian fits at every square and channel of a shot; and
//! `lensblur kernels --session DIR`: every shot of a session measured into its result
//! cache (what the studio's Kernels does), through the same project as `calibrate`.

use super::common::{load_chart, progress_job, write_json};
use anyhow::{Result, bail};
use lensblur::kernel::{KernelParams, Operator, Weighting};
use lensblur::pipeline::{self, GivenSetting, Measurement};
use lensblur::project::{MeasurePlan, Stages};
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// The shot: a RAW file, or a PNG/TIFF/JPEG image of the chart.
    #[arg(required_unless_present = "session", conflicts_with = "session")]
    pub shot: Option<PathBuf>,
    /// Where to write kernels.json.
    #[arg(long, required_unless_present = "session")]
    pub out: Option<PathBuf>,
    /// A session folder (or its session.json, or a manifest): detect and measure every
    /// shot that has no kernels yet, caching the results in its results/ folder and
    /// recording each shot's status, as the studio does.
    /// A plain folder of shots is a session: the settings from their EXIF (or
    /// --focal and --aperture, for all), the manifest inferred written there.
    #[arg(long, conflicts_with_all = ["oversample", "uniform_weights", "fft"])]
    pub session: Option<PathBuf>,
    /// With --session: measure every shot again, replacing its cached results.
    #[arg(long, requires = "session")]
    pub again: bool,
    /// With --session: stop when any shot fails, instead of listing the failed shots
    /// and measuring the others.
    #[arg(long, requires = "session")]
    pub strict: bool,
    /// Also write every kernel array (at the oversampling), not only its Gaussians.
    #[arg(long)]
    pub with_kernels: bool,
    /// Focal length in mm, when EXIF lacks it or is wrong.
    #[arg(long)]
    pub focal: Option<f64>,
    /// Aperture as an f-number, when EXIF lacks it or is wrong.
    #[arg(long)]
    pub aperture: Option<f64>,
    /// The chart spec printed, when not the default 24 × 16 chart.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Sub-samples per pixel of the kernels (odd).
    #[arg(long, default_value_t = 3)]
    pub oversample: usize,
    /// Weight every sub-sample (the paper's W = I) instead of only real pixel centres.
    #[arg(long)]
    pub uniform_weights: bool,
    /// Compute every product with the sharp chart by FFT over the whole oversampled
    /// raster (the same kernels, several times slower than the default operator).
    #[arg(long)]
    pub fft: bool,
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_setting_args(args.focal, args.aperture)?;
    if let Some(session) = &args.session {
        let chart = match &args.chart {
            Some(p) => Some(load_chart(Some(p))?),
            None => None,
        };
        let project = super::calibrate::measure_project(
            session,
            "lensblur kernels",
            chart,
            args.again,
            MeasurePlan::missing(Stages::All),
            args.strict,
            GivenSetting {
                focal_mm: args.focal,
                f_number: args.aperture,
            },
        )?;
        let with = project
            .shots()
            .filter(|s| s.state.kernels.is_some())
            .count();
        eprintln!(
            "{}: {with} of {} shots have kernels",
            project.folder().display(),
            project.session().shots.len()
        );
        return Ok(());
    }
    let (Some(shot), Some(out)) = (&args.shot, &args.out) else {
        bail!("give a shot and --out, or --session");
    };
    super::common::check_out_folder(out)?;
    let spec = load_chart(args.chart.as_deref())?;
    let capture = pipeline::load(shot)?;
    let m = Measurement::new(
        spec,
        KernelParams {
            oversample: args.oversample,
            weighting: if args.uniform_weights {
                Weighting::Uniform
            } else {
                Weighting::PixelCentres
            },
            operator: if args.fft {
                Operator::Fft
            } else {
                Operator::Auto
            },
            ..KernelParams::default()
        },
    );
    let job = progress_job();
    let det = pipeline::detect(&capture, shot, &m, &job)?;
    let given = GivenSetting {
        focal_mm: args.focal,
        f_number: args.aperture,
    };
    let file = pipeline::estimate(&capture, &det, shot, given, &m, args.with_kernels, &job)?;
    let clipping = lensblur::detect::clipping_advice(&det, &m.detect);
    if let Some(advice) = &clipping {
        eprintln!("{}: {advice}", shot.display());
    }
    if file.samples.is_empty() {
        let why = match (&clipping, file.failed.first()) {
            (Some(_), _) => "clipping left no square to measure".to_string(),
            (None, Some(f)) => format!("every square failed (the first: {})", f.reason),
            (None, None) => "no square of the chart could be aligned".to_string(),
        };
        // The failures are still worth keeping: each square's reason is in the file.
        write_json(out, &file)?;
        bail!("{}: no kernel measured: {why}", shot.display());
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let gaussians: Vec<_> = file.samples.iter().filter_map(|s| s.gaussian()).collect();
    let sigma = median(gaussians.iter().map(|g| g.sigma()).collect());
    let mtf50 = median(
        gaussians
            .iter()
            .filter_map(|g| Some(g.mtf50()?.worst))
            .collect(),
    );
    eprintln!(
        "{}: {} kernels over {} squares, {} failed; median σ {sigma:.3} px, median MTF50 {mtf50:.3} cycles/px ({:.0} lp/ph) in the worst direction",
        shot.display(),
        file.samples.len(),
        det.ok_squares().count(),
        file.failed.len(),
        lensblur::psf::Mtf50::lp_per_picture_height(mtf50, file.height)
    );
    if file.focal_mm.is_none() || file.f_number.is_none() {
        eprintln!(
            "{}: warning: focal length or aperture unknown (no EXIF); give --focal and --aperture for calibration",
            shot.display()
        );
    }
    write_json(out, &file)
}
