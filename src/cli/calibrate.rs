//! `lensblur calibrate`: fit blur models over a calibration session and write a profile.
//!
//! The session is either a manifest of shots (the whole chain runs per shot: load,
//! detect, kernels; each shot's kernels are cached in `lensblur-cache/` beside the
//! manifest, keyed by the file's hash and setting, so re-runs are quick) or a list of
//! kernels files.

use super::common::{load_chart, progress_job, write_json};
use anyhow::{Context, Result, bail};
use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::chart::ChartSpec;
use lensblur::crossval::{CvOptions, HoldOut};
use lensblur::detect::{DetectParams, detect};
use lensblur::kernel::file::KernelsFile;
use lensblur::kernel::{KernelParams, estimate_shot};
use lensblur::model::{Dataset, LocalOptions, ModelError};
use lensblur::plane::LensSetting;
use lensblur::raw::{LoadOptions, load_capture};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Where a session's measurements come from (shared by calibrate, crossval, sweeps).
#[derive(clap::Args, Default, Clone)]
pub struct SessionArgs {
    /// Session manifest (DESIGN §3); every shot is measured (cached in lensblur-cache/).
    #[arg(long, conflicts_with = "kernels")]
    pub manifest: Option<PathBuf>,
    /// Kernels files (lensblur.kernels/1), one per shot, instead of a manifest.
    #[arg(long, num_args = 1.., required_unless_present = "manifest")]
    pub kernels: Vec<PathBuf>,
    /// Chart spec, where another chart than the default 24×16 was printed.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Re-measure every shot, ignoring the cache.
    #[arg(long)]
    pub no_cache: bool,
}

#[derive(Deserialize)]
struct Manifest {
    #[serde(default)]
    chart: Option<serde_json::Value>,
    shots: Vec<ManifestShot>,
}

#[derive(Deserialize)]
struct ManifestShot {
    path: PathBuf,
    #[serde(default)]
    focal_mm: Option<f64>,
    #[serde(default)]
    f_number: Option<f64>,
}

fn is_kernels_file(path: &Path) -> bool {
    path.to_string_lossy().ends_with(".kernels.json")
        || std::fs::read_to_string(path)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| {
                v.get("schema")
                    .and_then(|s| s.as_str())
                    .map(|s| s == "lensblur.kernels/1")
            })
            .unwrap_or(false)
}

/// FNV-1a over the file's bytes and the setting: the cache key of a shot's kernels.
fn cache_key(
    path: &Path,
    (focal_mm, f_number): (Option<f64>, Option<f64>),
    chart: &ChartSpec,
) -> Result<String> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |b: &[u8]| {
        for &x in b {
            h ^= u64::from(x);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(&bytes);
    for (tag, v) in [(b'f', focal_mm), (b'a', f_number)] {
        if let Some(v) = v {
            eat(&[tag]);
            eat(&v.to_le_bytes());
        }
    }
    eat(serde_json::to_string(chart).unwrap_or_default().as_bytes());
    Ok(format!("{h:016x}"))
}

/// Loads a session's measured Gaussians, measuring (or taking from the cache) every
/// shot of a manifest.
pub fn load_session(args: &SessionArgs) -> Result<(Dataset, Option<ChartSpec>)> {
    let Some(manifest_path) = &args.manifest else {
        let mut chart = None;
        if args.chart.is_some() {
            chart = Some(load_chart(args.chart.as_deref())?);
        }
        let paths: Vec<&Path> = args.kernels.iter().map(PathBuf::as_path).collect();
        return Ok((Dataset::from_kernels_files(&paths, &[])?, chart));
    };
    let text = std::fs::read_to_string(manifest_path)
        .with_context(|| format!("{}: cannot read", manifest_path.display()))?;
    let manifest: Manifest = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a session manifest", manifest_path.display()))?;
    let base = manifest_path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let chart = match (&args.chart, &manifest.chart) {
        (Some(p), _) => load_chart(Some(p))?,
        (None, Some(serde_json::Value::String(p))) => load_chart(Some(&base.join(p)))?,
        (None, Some(v)) => serde_json::from_value(v.clone())
            .with_context(|| format!("{}: the chart spec is malformed", manifest_path.display()))?,
        (None, None) => ChartSpec::default(),
    };
    if manifest.shots.is_empty() {
        bail!("{}: the manifest lists no shots", manifest_path.display());
    }
    let cache_dir = base.join("lensblur-cache");
    let job = progress_job();
    let mut kernel_paths = Vec::new();
    let mut settings = Vec::new();
    for (i, shot) in manifest.shots.iter().enumerate() {
        job.report("measuring", i, manifest.shots.len());
        let path = base.join(&shot.path);
        let setting = match (shot.focal_mm, shot.f_number) {
            (Some(f), Some(a)) => Some(LensSetting {
                focal_mm: f,
                f_number: a,
            }),
            _ => None,
        };
        if is_kernels_file(&path) {
            kernel_paths.push(path);
        } else {
            let key = cache_key(&path, (shot.focal_mm, shot.f_number), &chart)?;
            let cached = cache_dir.join(format!("{key}.kernels.json"));
            if args.no_cache || !cached.exists() {
                std::fs::create_dir_all(&cache_dir)
                    .with_context(|| format!("{}: cannot create", cache_dir.display()))?;
                let kernels = measure_shot(&path, (shot.focal_mm, shot.f_number), &chart, &job)?;
                write_json(&cached, &kernels)?;
            }
            kernel_paths.push(cached);
        }
        settings.push(setting);
    }
    job.report("measuring", manifest.shots.len(), manifest.shots.len());
    let paths: Vec<&Path> = kernel_paths.iter().map(PathBuf::as_path).collect();
    // Errors name the photo, not its cached kernels.
    let photo_of = |shot: &str| {
        kernel_paths
            .iter()
            .position(|k| k.display().to_string() == shot)
            .map_or_else(
                || shot.to_string(),
                |i| base.join(&manifest.shots[i].path).display().to_string(),
            )
    };
    let mut ds = Dataset::from_kernels_files(&paths, &settings).map_err(|e| match e {
        ModelError::UnknownSetting { shot } => ModelError::UnknownSetting {
            shot: photo_of(&shot),
        },
        ModelError::MixedIdentity { field, a, b, shot } => ModelError::MixedIdentity {
            field,
            a,
            b,
            shot: photo_of(&shot),
        },
        e => e,
    })?;
    // Name shots by their photo, not the cache file.
    for (info, shot) in ds.shots.iter_mut().zip(&manifest.shots) {
        info.name = shot.path.display().to_string();
    }
    Ok((ds, Some(chart)))
}

/// Runs load → detect → kernels on one shot and returns its kernels document. The
/// manifest's focal length and f-number (either may be absent) take precedence over the
/// file's EXIF; a shot with neither is refused before the minutes of measuring.
fn measure_shot(
    path: &Path,
    (focal_mm, f_number): (Option<f64>, Option<f64>),
    chart: &ChartSpec,
    job: &lensblur::job::JobContext,
) -> Result<KernelsFile> {
    let capture = load_capture(path, &LoadOptions::default())?;
    let focal_mm = focal_mm.or(capture.setting_focal_mm);
    let f_number = f_number.or(capture.setting_f_number);
    if focal_mm.is_none() || f_number.is_none() {
        bail!(
            "{}: no {} in the manifest or the file's EXIF; add \"focal_mm\" and \"f_number\" to its manifest entry",
            path.display(),
            match (focal_mm, f_number) {
                (None, None) => "focal length or f-number",
                (None, Some(_)) => "focal length",
                _ => "f-number",
            }
        );
    }
    let det = detect(&capture, chart, &DetectParams::default(), job)
        .with_context(|| path.display().to_string())?;
    let shot = estimate_shot(&capture, &det, chart, &KernelParams::default(), job)
        .with_context(|| path.display().to_string())?;
    Ok(KernelsFile::from_shot(
        &shot,
        focal_mm,
        f_number,
        Some(capture.identity.clone()),
        false,
    ))
}

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Where to write the profile (lensblur.profile/1).
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
    let (ds, chart) = load_session(&args.session)?;
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
    eprintln!(
        "{} shots, {} samples; profile {} written in {:.1} s",
        ds.shots.len(),
        ds.samples.len(),
        args.out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
