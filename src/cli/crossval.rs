//! `lensblur crossval`: cross-validate model complexity (α, β) over a session; the data
//! of the paper's Fig. 5 (curves) and Fig. 6 (error distributions).

use super::calibrate::{ModelArg, SessionArgs, load_session};
use super::common::{progress_job, write_atomic, write_json};
use anyhow::Result;
use lensblur::crossval::{CvOptions, CvReport, Selection, cross_validate};
use lensblur::model::LocalOptions;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Where to write the report (lensblur.crossval/1 JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write CSV tables beside it: <out>.curves.csv and <out>.cdf.csv.
    #[arg(long)]
    pub csv: bool,
    #[arg(long, value_enum, default_value = "both")]
    pub model: ModelArg,
    #[arg(long, default_value_t = 10)]
    pub folds: usize,
    /// Spatial orders α to try for the global model.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,5,6,7,8")]
    pub global_alphas: Vec<usize>,
    /// Spatial orders α to try for the local model.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub local_alphas: Vec<usize>,
    #[arg(long)]
    pub radius_px: Option<f64>,
}

pub fn run(args: Args) -> Result<()> {
    if let Some(a) = args
        .global_alphas
        .iter()
        .chain(&args.local_alphas)
        .find(|&&a| a == 0 || a > 15)
    {
        anyhow::bail!("α = {a} is outside 1–15");
    }
    let (ds, _) = load_session(&args.session)?;
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
        ..CvOptions::default()
    };
    let report = cross_validate(&ds, &opts, &progress_job())?;
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
                    "{kind},{stage},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
                    p.alpha,
                    p.beta,
                    p.terms,
                    p.mean_pct,
                    p.mean_error_pct[0],
                    p.mean_error_pct[1],
                    p.mean_error_pct[2],
                    p.p95_error_pct[0],
                    p.p95_error_pct[1],
                    p.p95_error_pct[2]
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
    write_atomic(&with_suffix(out, ".cdf.csv"), cdf.as_bytes())
}
