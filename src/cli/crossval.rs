//! `lensblur crossval`: cross-validate model complexity (α, β) over a session; the data
//! of the paper's Fig. 5 (curves) and Fig. 6 (error distributions).

use super::calibrate::{HoldOutArg, ModelArg, SessionArgs, load_session};
use super::common::{progress_job, write_atomic, write_json};
use anyhow::{Context, Result};
use lensblur::crossval::{
    CvOptions, CvReport, Selection, cross_validate, evaluate_test_set, paper_test_models,
};
use lensblur::model::{LocalOptions, ModelKind};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Where to write the report (lensblur.crossval/1 JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write CSV tables beside it: <out>.curves.csv (Fig. 5) and <out>.cdf.csv (the
    /// chosen models' cross-validation error distributions); with a test session,
    /// <out>.test.csv and <out>.test_cdf.csv (Fig. 6).
    #[arg(long)]
    pub csv: bool,
    /// Which models to cross-validate.
    #[arg(long, value_enum, default_value = "both")]
    pub model: ModelArg,
    /// Cross-validation folds (10: hold out 10 % of the shots per fold).
    #[arg(long, default_value_t = 10)]
    pub folds: usize,
    /// Spatial orders α to try for the global model.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,5,6,7,8")]
    pub global_alphas: Vec<usize>,
    /// Spatial orders α to try for the local model.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub local_alphas: Vec<usize>,
    /// Local model radius in pixels (default: 3× the largest imaged square).
    #[arg(long)]
    pub radius_px: Option<f64>,
    /// What a fold holds out: whole shots, or every shot of a setting together.
    #[arg(long, value_enum, default_value = "shot")]
    pub hold_out: HoldOutArg,
    /// A test session at other settings (a manifest): the models are fitted to the whole
    /// calibration session and their errors at the test shots reported (the paper's
    /// Fig. 6): the cross-validated choices and G_{8,3}, L_{1,3}, G_{8,1}, L_{1,1}.
    #[arg(long, conflicts_with = "test_kernels")]
    pub test_manifest: Option<PathBuf>,
    /// The test session as kernels files, one per shot, instead of a manifest.
    #[arg(long, num_args = 1..)]
    pub test_kernels: Vec<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_out_folder(&args.out)?;
    if let Some(a) = args
        .global_alphas
        .iter()
        .chain(&args.local_alphas)
        .find(|&&a| a == 0 || a > 15)
    {
        anyhow::bail!("α = {a} is outside 1–15");
    }
    let (ds, _) = load_session(&args.session, "lensblur crossval")?;
    let opts = CvOptions {
        folds: args.folds,
        global_alphas: args.global_alphas.clone(),
        local_alphas: args.local_alphas.clone(),
        local: LocalOptions {
            radius_px: args.radius_px,
            ..LocalOptions::default()
        },
        run_global: args.model != ModelArg::Local,
        run_local: args.model != ModelArg::Global,
        hold_out: args.hold_out.into(),
        ..CvOptions::default()
    };
    let mut report = cross_validate(&ds, &opts, &progress_job())?;
    if args.test_manifest.is_some() || !args.test_kernels.is_empty() {
        let test_args = SessionArgs {
            session: None,
            manifest: args.test_manifest.clone(),
            kernels: args.test_kernels.clone(),
            ..args.session.clone()
        };
        let (test, _) = load_session(&test_args, "lensblur crossval").context("test session")?;
        let models: Vec<_> = paper_test_models(Some(&report))
            .into_iter()
            .filter(|m| match m.kind {
                ModelKind::Global => opts.run_global,
                ModelKind::Local => opts.run_local,
            })
            .collect();
        let t = evaluate_test_set(&ds, &test, &models, &opts.local, &report.ranges)?;
        for m in &t.models {
            eprintln!(
                "test set: {} {}: mean error {:.2} % of range; p95 C_xx {:.2}, C_yy {:.2}, C_or {:.2}",
                m.label,
                m.kind.model_name(m.alpha, m.beta),
                m.mean_pct,
                m.p95_error_pct[0],
                m.p95_error_pct[1],
                m.p95_error_pct[2]
            );
        }
        for s in &t.skipped {
            eprintln!("test set: skipped {s}");
        }
        report.test = Some(t);
    }
    write_json(&args.out, &report)?;
    if args.csv {
        write_csv(&args.out, &report)?;
    }
    for s in [&report.global, &report.local].into_iter().flatten() {
        eprintln!(
            "{:?}: chosen α = {}, β = {}; CV error {:.2} % of range (C_xx {:.2}, C_yy {:.2}, C_or {:.2})",
            s.kind,
            s.alpha,
            s.beta,
            s.chosen.mean_pct,
            s.chosen.mean_error_pct[0],
            s.chosen.mean_error_pct[1],
            s.chosen.mean_error_pct[2]
        );
    }
    Ok(())
}

fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// Curves (model, stage, α, β, terms, errors) and error CDFs as CSV.
pub fn write_csv(out: &Path, report: &CvReport) -> Result<()> {
    let mut curves = String::from(
        "model,stage,alpha,beta,terms,mean_pct,cxx_mean_pct,cyy_mean_pct,cor_mean_pct,cxx_p95_pct,cyy_p95_pct,cor_p95_pct\n",
    );
    let mut cdf = String::from("model,percentile,cxx_pct,cyy_pct,cor_pct\n");
    let sels: Vec<&Selection> = [&report.global, &report.local]
        .into_iter()
        .flatten()
        .collect();
    for s in sels {
        let kind = format!("{:?}", s.kind).to_lowercase();
        for (stage, curve) in [("alpha", &s.alpha_curve), ("beta", &s.beta_curve)] {
            for p in curve {
                let _ = writeln!(
                    curves,
                    "{kind},{stage},{}",
                    error_columns(
                        (p.alpha, p.beta, p.terms),
                        p.mean_pct,
                        p.mean_error_pct,
                        p.p95_error_pct
                    )
                );
            }
        }
        let c = &s.error_cdf;
        for i in 0..c.percentiles.len() {
            let _ = writeln!(
                cdf,
                "{kind},{},{:.4},{:.4},{:.4}",
                c.percentiles[i], c.cxx[i], c.cyy[i], c.cor[i]
            );
        }
    }
    write_atomic(&with_suffix(out, ".curves.csv"), curves.as_bytes())?;
    write_atomic(&with_suffix(out, ".cdf.csv"), cdf.as_bytes())?;
    if let Some(t) = &report.test {
        let mut summary = String::from(
            "model,label,alpha,beta,terms,mean_pct,cxx_mean_pct,cyy_mean_pct,cor_mean_pct,cxx_p95_pct,cyy_p95_pct,cor_p95_pct\n",
        );
        let mut cdf = String::from("model,label,alpha,beta,percentile,cxx_pct,cyy_pct,cor_pct\n");
        for m in &t.models {
            let kind = format!("{:?}", m.kind).to_lowercase();
            let _ = writeln!(
                summary,
                "{kind},{},{}",
                m.label,
                error_columns(
                    (m.alpha, m.beta, m.terms),
                    m.mean_pct,
                    m.mean_error_pct,
                    m.p95_error_pct
                )
            );
            let c = &m.error_cdf;
            for i in 0..c.percentiles.len() {
                let _ = writeln!(
                    cdf,
                    "{kind},{},{},{},{},{:.4},{:.4},{:.4}",
                    m.label, m.alpha, m.beta, c.percentiles[i], c.cxx[i], c.cyy[i], c.cor[i]
                );
            }
        }
        write_atomic(&with_suffix(out, ".test.csv"), summary.as_bytes())?;
        write_atomic(&with_suffix(out, ".test_cdf.csv"), cdf.as_bytes())?;
    }
    Ok(())
}

/// A model's orders and its errors as CSV columns: α, β, terms, the mean, then the mean
/// and the 95th percentile of C_xx, C_yy, C_or (% of range).
fn error_columns(
    (alpha, beta, terms): (usize, usize, usize),
    mean_pct: f64,
    mean: [f64; 3],
    p95: [f64; 3],
) -> String {
    format!(
        "{alpha},{beta},{terms},{mean_pct:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
        mean[0], mean[1], mean[2], p95[0], p95[1], p95[2]
    )
}
