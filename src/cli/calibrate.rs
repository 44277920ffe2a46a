//! `lensblur calibrate`: fit blur models over a calibration session and write a profile.
//!
//! The session is either a manifest of shots, each measured through the core pipeline
//! (load, detect, kernels; every stage's result cached in `results/` beside the
//! manifest, the same cache the studio keeps, so shots measured there or in an earlier
//! run are not measured again), or a list of kernels files measured earlier.

use super::common::{load_chart, progress_job, write_json};
use anyhow::Result;
use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::chart::ChartSpec;
use lensblur::crossval::{CvOptions, HoldOut, ShapeCvOptions};
use lensblur::job::JobContext;
use lensblur::kernel::file::KernelsFile;
use lensblur::model::{Dataset, LocalOptions};
use lensblur::pipeline::{self, MeasuredShot, Provenance, ShotFile};
use lensblur::session::{SESSION_FILE, Session};
use std::path::{Path, PathBuf};

/// Where a session's measurements come from (shared by calibrate, crossval, sweeps).
#[derive(clap::Args, Default, Clone)]
pub struct SessionArgs {
    /// Session manifest (or a studio session folder or its session.json); every shot
    /// is measured, or taken from the cache in results/ beside it.
    #[arg(long, conflicts_with = "kernels")]
    pub manifest: Option<PathBuf>,
    /// Kernels files (lensblur.kernels/1), one per shot, instead of a manifest.
    #[arg(long, num_args = 1.., required_unless_present = "manifest")]
    pub kernels: Vec<PathBuf>,
    /// Chart spec, where another chart than the manifest's (or the default 24×16) was
    /// printed.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Measure every shot again, ignoring (and replacing) cached results.
    #[arg(long)]
    pub no_cache: bool,
}

fn is_kernels_file(path: &Path) -> bool {
    path.to_string_lossy().ends_with(".kernels.json")
        || lensblur::io::read_json_text(path)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| {
                v.get("schema")
                    .and_then(|s| s.as_str())
                    .map(|s| s.starts_with("lensblur.kernels/"))
            })
            .unwrap_or(false)
}

/// Loads a session's measured Gaussians, measuring (or taking from the cache) every
/// shot of a manifest.
pub fn load_session(args: &SessionArgs) -> Result<(Dataset, Option<ChartSpec>)> {
    load_session_locked(args).map(|(ds, chart, _)| (ds, chart))
}

/// [`load_session`], returning the session folder's lock (held while shots are
/// measured into it) for a caller that goes on writing there.
pub fn load_session_locked(
    args: &SessionArgs,
) -> Result<(
    Dataset,
    Option<ChartSpec>,
    Option<lensblur::lock::FolderLock>,
)> {
    let Some(manifest_path) = &args.manifest else {
        let mut chart = None;
        if args.chart.is_some() {
            chart = Some(load_chart(args.chart.as_deref())?);
        }
        let paths: Vec<&Path> = args.kernels.iter().map(PathBuf::as_path).collect();
        return Ok((Dataset::from_kernels_files(&paths, &[])?, chart, None));
    };
    let mut session = Session::open(manifest_path)?;
    // A session (not a bare manifest) gets each shot's status saved as it is measured,
    // so the studio opens it with the work done.
    let is_session = session.folder().join(SESSION_FILE).is_file()
        && (manifest_path.is_dir() || manifest_path.file_name().is_some_and(|n| n == SESSION_FILE));
    let (lock, swept) = session.lock("lensblur calibrate")?;
    if swept > 0 {
        eprintln!(
            "{}: removed {swept} unfinished temporary files left by an interrupted write",
            session.folder().display()
        );
    }
    if args.chart.is_some() {
        session.chart = load_chart(args.chart.as_deref())?;
    }
    if session.shots.is_empty() {
        anyhow::bail!("{}: the manifest lists no shots", manifest_path.display());
    }
    let measurement = session.measurement();
    let cache = session.cache();
    let job = progress_job();
    let mut survey = session
        .survey(&JobContext::silent())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    for line in &survey.dropped {
        eprintln!("note: {line}");
    }
    let total = session.shots.len();
    let (mut measured, mut cached) = (0, 0);
    let mut shots = Vec::with_capacity(total);
    for i in 0..total {
        let shot = &session.shots[i];
        let id = shot.id;
        job.report("measuring", i, total);
        let path = session.path_of(shot);
        let kernels = if is_kernels_file(&path) {
            KernelsFile::load(&path)?
        } else if let Some(k) = survey.kernels.remove(&id).filter(|_| !args.no_cache) {
            cached += 1;
            k
        } else {
            let file = ShotFile::read(&path)?;
            if args.no_cache {
                for stale in [
                    cache.detect_path(&file, &measurement),
                    cache.kernels_path(&file, &measurement),
                ] {
                    let _ = std::fs::remove_file(stale);
                }
            }
            let (k, how) = pipeline::measure_shot(
                &file,
                shot.given_setting(),
                true,
                &measurement,
                &cache,
                &job.prefixed(&format!("shot {} of {total}: ", i + 1)),
            )?;
            match how {
                Provenance::Cached => cached += 1,
                Provenance::Measured => measured += 1,
            }
            k
        };
        let shot = &session.shots[i];
        shots.push(MeasuredShot {
            name: shot.name(),
            kernels,
            given: shot.given_setting(),
        });
        if is_session && let Some(shot) = session.shot_mut(id) {
            shot.kernels = lensblur::session::StageStatus::Done {
                summary: lensblur::session::kernels_summary(&shots[i].kernels),
            };
            session.save()?;
        }
    }
    job.report("measuring", total, total);
    eprintln!("{measured} shots measured, {cached} from the cache");
    let ds = pipeline::dataset(&shots)?;
    Ok((ds, Some(session.chart), Some(lock)))
}

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Where to write the profile (lensblur.profile/2).
    #[arg(long)]
    pub out: PathBuf,
    /// Which models to fit.
    #[arg(long, value_enum, default_value = "both")]
    pub model: ModelArg,
    /// Spatial order α (skips cross-validated selection).
    #[arg(long)]
    pub alpha: Option<usize>,
    /// Order β in focal length and aperture (must stay below min(N_f, N_a)).
    #[arg(long)]
    pub beta: Option<usize>,
    /// Cross-validation folds (10: hold out 10 % of the shots per fold).
    #[arg(long, default_value_t = 10)]
    pub folds: usize,
    /// Local model radius in pixels (default: 3× the largest imaged square).
    #[arg(long)]
    pub radius_px: Option<f64>,
    /// What a cross-validation fold holds out.
    #[arg(long, value_enum, default_value = "shot")]
    pub hold_out: HoldOutArg,
    /// Also write the cross-validation report here.
    #[arg(long)]
    pub cv_out: Option<PathBuf>,
    /// Fit no kernel-shape model (by default one is cross-validated from the measured
    /// kernels and kept where it predicts held-out kernels better than the Gaussians).
    #[arg(long)]
    pub no_shape_model: bool,
}

/// What a cross-validation fold holds out.
#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum HoldOutArg {
    /// Whole shots, each on its own (the paper's holdout).
    #[default]
    Shot,
    /// Every shot of a setting together: each fold predicts unseen settings.
    Setting,
}

impl From<HoldOutArg> for HoldOut {
    fn from(h: HoldOutArg) -> Self {
        match h {
            HoldOutArg::Shot => HoldOut::Shot,
            HoldOutArg::Setting => HoldOut::Setting,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum ModelArg {
    Global,
    Local,
    #[default]
    Both,
}

impl From<ModelArg> for Families {
    fn from(m: ModelArg) -> Self {
        match m {
            ModelArg::Global => Families::Global,
            ModelArg::Local => Families::Local,
            ModelArg::Both => Families::Both,
        }
    }
}

pub fn run(args: Args) -> Result<()> {
    let t0 = std::time::Instant::now();
    // The folder stays locked until the profile is written (it may be written there).
    let (ds, chart, _lock) = load_session_locked(&args.session)?;
    let opts = CalibrateOptions {
        families: args.model.into(),
        alpha: args.alpha,
        beta: args.beta,
        cv: CvOptions {
            folds: args.folds,
            hold_out: args.hold_out.into(),
            local: LocalOptions {
                radius_px: args.radius_px,
                ..LocalOptions::default()
            },
            ..CvOptions::default()
        },
        shape: (!args.no_shape_model).then(ShapeCvOptions::default),
    };
    let (profile, report) = calibrate(&ds, chart, &opts, &progress_job())?;
    profile.save(&args.out)?;
    if let (Some(p), Some(r)) = (&args.cv_out, &report) {
        write_json(p, r)?;
    }
    let describe = |k: &str, a: usize, b: usize, cv: Option<f64>| {
        let e = cv
            .map(|e| format!(", CV error {e:.2} % of range"))
            .unwrap_or_default();
        eprintln!("{k} model: α = {a}, β = {b}{e}");
    };
    if let Some(g) = &profile.global {
        describe(
            "global",
            g.alpha,
            g.beta,
            profile
                .cv
                .as_ref()
                .and_then(|c| c.global.as_ref())
                .map(|p| p.mean_pct),
        );
    }
    if let Some(l) = &profile.local {
        describe(
            "local",
            l.alpha,
            l.beta,
            profile
                .cv
                .as_ref()
                .and_then(|c| c.local.as_ref())
                .map(|p| p.mean_pct),
        );
    }
    if let Some(cv) = &profile.shape_cv {
        eprintln!("{}", shape_summary(cv));
    }
    eprintln!(
        "{} shots, {} samples; profile {} written in {:.1} s",
        ds.shots.len(),
        ds.samples.len(),
        args.out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// One line on the kernel-shape model's cross-validation: what was kept and why.
fn shape_summary(cv: &lensblur::crossval::ShapeCvReport) -> String {
    let gauss = cv.gaussian.mean_rel_l2;
    match (&cv.best_shape, cv.shape_chosen) {
        (Some(b), true) => format!(
            "kernel shapes: {} components, α = {}, β = {}: held-out kernel error {:.3} vs {:.3} for the Gaussians alone (relative L2, {} kernels)",
            b.components, b.alpha, b.beta, b.mean_rel_l2, gauss, cv.kernels
        ),
        (Some(b), false) => format!(
            "kernel shapes: not kept: the best ({} components) predicts held-out kernels no better than the Gaussians ({:.3} vs {:.3} relative L2)",
            b.components, b.mean_rel_l2, gauss
        ),
        (None, _) => format!(
            "kernel shapes: none fitted; the Gaussians' held-out kernel error is {gauss:.3} (relative L2)"
        ),
    }
}
