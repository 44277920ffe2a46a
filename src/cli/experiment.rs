//! `lensblur experiment gaussian-approx --out DIR`: the paper's Figure 2 experiment —
//! how much deblurring loses when a measured kernel is replaced by its Gaussian fit.

use super::common::{progress_job, write_atomic, write_json};
use anyhow::{Context, Result, bail};
use lensblur::experiment::{
    ExperimentOptions, MeasureOptions, cdf_csv, gaussian_approx, measured_kernels,
    simulated_kernels,
};
use lensblur::kernel::Weighting;
use lensblur::simulate::PsfShape;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub which: Which,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            which: Which::GaussianApprox(GaussianApproxArgs::default()),
        }
    }
}

#[derive(clap::Subcommand)]
pub enum Which {
    /// SSIM error ratio (paper Eq. 1) of deblurring with the robust and the ML Gaussian
    /// instead of the non-parametric kernel, on a dead-leaves and a hard-edge image.
    GaussianApprox(GaussianApproxArgs),
}

#[derive(clap::Args)]
pub struct GaussianApproxArgs {
    /// Folder for report.json (every row and the summary) and cdf.csv (Fig. 2 curves).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of kernels.
    #[arg(long, default_value_t = 300)]
    pub kernels: usize,
    /// Side of the two test images, pixels.
    #[arg(long, default_value_t = 160)]
    pub size: usize,
    /// measured: kernels estimated on simulated calibration shots (the paper's setup);
    /// analytic: the virtual lens's exact kernels, its three shapes mixed.
    #[arg(long, value_enum, default_value = "measured")]
    pub source: SourceArg,
    /// PSF shape of the virtual lens (measured source).
    #[arg(long, value_enum, default_value = "gaussian")]
    pub shape: ShapeArg,
    /// Kernel estimate weighting (measured source): uniform is the paper's W = I, which
    /// it uses for the kernels it deblurs with; pixel-centres is calibration's default.
    #[arg(long, value_enum, default_value = "uniform")]
    pub weighting: WeightingArg,
    /// Shoot only at f-numbers LO,HI within the lens's range (measured source), e.g.
    /// to compare wide open with stopped down.
    #[arg(long, value_delimiter = ',')]
    pub f_numbers: Option<Vec<f64>>,
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
}

#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub enum WeightingArg {
    Uniform,
    PixelCentres,
}

impl Default for GaussianApproxArgs {
    fn default() -> Self {
        Self {
            out: PathBuf::from("."),
            kernels: 300,
            size: 160,
            source: SourceArg::Measured,
            shape: ShapeArg::Gaussian,
            weighting: WeightingArg::Uniform,
            f_numbers: None,
            seed: 7,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub enum SourceArg {
    Measured,
    Analytic,
}

#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub enum ShapeArg {
    Gaussian,
    Disc,
    Comet,
    /// Diffraction through a Seidel wavefront: the aberrated lens.
    Aberrated,
}

pub fn run(args: Args) -> Result<()> {
    match args.which {
        Which::GaussianApprox(a) => gaussian_approx_cmd(a),
    }
}

fn gaussian_approx_cmd(a: GaussianApproxArgs) -> Result<()> {
    if !(1..=5000).contains(&a.kernels) {
        bail!("--kernels must be 1–5000 (got {})", a.kernels);
    }
    if !(32..=2048).contains(&a.size) {
        bail!("--size must be 32–2048 pixels (got {})", a.size);
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("{}: cannot create", a.out.display()))?;
    let f_numbers = match a.f_numbers.as_deref() {
        None => None,
        Some(&[lo, hi]) if lo.is_finite() && hi.is_finite() && 0.0 < lo && lo < hi => {
            Some([lo, hi])
        }
        Some(v) => bail!("--f-numbers must be two increasing positive f-numbers (got {v:?})"),
    };
    let job = progress_job();
    let shape = match a.shape {
        ShapeArg::Gaussian => PsfShape::Gaussian,
        ShapeArg::Disc => PsfShape::Disc,
        ShapeArg::Comet => PsfShape::Comet,
        ShapeArg::Aberrated => PsfShape::Aberrated,
    };
    let kernels = match a.source {
        SourceArg::Measured => {
            let opts = MeasureOptions {
                weighting: match a.weighting {
                    WeightingArg::Uniform => Weighting::Uniform,
                    WeightingArg::PixelCentres => Weighting::PixelCentres,
                },
                f_numbers,
                ..MeasureOptions::new(a.kernels, shape, a.seed)
            };
            let m = measured_kernels(&opts, &job)
                .context("measuring kernels on simulated calibration shots")?;
            for s in &m.skipped_shots {
                eprintln!("lensblur: warning: skipped {s}");
            }
            m.kernels
        }
        SourceArg::Analytic => simulated_kernels(a.kernels, 3),
    };
    let opts = ExperimentOptions {
        image_px: a.size,
        seed: a.seed,
        ..ExperimentOptions::default()
    };
    let report = gaussian_approx(&kernels, &opts, &job)?;
    write_json(
        &a.out.join("report.json"),
        &lensblur::format::Versioned::new(&lensblur::format::EXPERIMENT, &report),
    )?;
    write_atomic(&a.out.join("cdf.csv"), cdf_csv(&report).as_bytes())?;
    for s in &report.summary {
        println!(
            "{:>9}: {} kernels; error ratio robust p50 {:.4} p99 {:.4}; ML p50 {:.4} p99 {:.4}",
            s.image, s.count, s.robust_p50, s.robust_p99, s.ml_p50, s.ml_p99
        );
    }
    eprintln!("wrote {}/report.json and cdf.csv", a.out.display());
    Ok(())
}
