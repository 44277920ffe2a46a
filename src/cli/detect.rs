//! `lensblur detect SHOT --out detect.json [--chart chart.json]`: find the chart's
//! squares and align each to sub-pixel accuracy; `detect.json` is in docs/formats.md.

use super::common::{load_chart, progress_job, write_json};
use anyhow::{Context, Result};
use lensblur::detect::{DetectParams, SquareStatus, detect};
use lensblur::raw::{LoadOptions, load_capture};
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// The shot: a RAW file, or a PNG/TIFF/JPEG image.
    pub shot: PathBuf,
    /// Where to write detect.json.
    #[arg(long)]
    pub out: PathBuf,
    /// The chart spec printed, when not the default 24 × 16 chart.
    #[arg(long)]
    pub chart: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_out_folder(&args.out)?;
    let spec = load_chart(args.chart.as_deref())?;
    let capture = load_capture(&args.shot, &LoadOptions::default())?;
    let job = progress_job();
    let det = detect(&capture, &spec, &DetectParams::default(), &job)
        .with_context(|| args.shot.display().to_string())?;
    let ok = det
        .squares
        .iter()
        .filter(|s| s.status == SquareStatus::Ok)
        .count();
    eprintln!(
        "{}: {} of {} squares aligned",
        args.shot.display(),
        ok,
        det.squares.len()
    );
    write_json(&args.out, &det.to_file())
}
