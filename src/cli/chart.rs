//! `lensblur chart --out chart.{svg,pdf,png} [--cols C --rows R --square-mm S | --paper
//! a4|a3|a2|letter|tabloid] [--dpi D] [--spec-out chart.json]`: the calibration chart
//! for printing, and its spec.

use super::common::write_atomic;
use anyhow::{Result, bail};
use lensblur::chart::export::{to_pdf, to_plane, to_svg};
use lensblur::chart::{ChartSpec, Paper};
use lensblur::plane::Channel;
use lensblur::raw::save_planes;
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// Output file; the format follows the extension: .svg, .pdf (both at the physical
    /// size) or .png (at --dpi).
    #[arg(long)]
    pub out: PathBuf,
    /// Squares across. The default 24 × 16 chart, shot to fill the frame, images its
    /// squares at about 4 % of the image width (the paper's 2–6 %).
    #[arg(long, default_value_t = 24)]
    pub cols: usize,
    /// Squares down.
    #[arg(long, default_value_t = 16)]
    pub rows: usize,
    /// Printed side of a square, millimetres.
    #[arg(long, default_value_t = 20.0, conflicts_with = "paper")]
    pub square_mm: f64,
    /// Size the squares to fill a sheet (landscape, inside a 10 mm printer margin),
    /// in whole half-millimetres: a4, a3, a2, letter or tabloid.
    #[arg(long, value_parser = |s: &str| s.parse::<Paper>())]
    pub paper: Option<Paper>,
    /// White border around the checkerboard, in squares.
    #[arg(long, default_value_t = 1.0)]
    pub margin: f64,
    /// Resolution of a PNG, dots per inch.
    #[arg(long, default_value_t = 300.0)]
    pub dpi: f64,
    /// Also write the chart spec (give it to the other commands with --chart when the
    /// chart is not the default).
    #[arg(long)]
    pub spec_out: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    let square_mm = match args.paper {
        Some(p) => ChartSpec {
            cols: args.cols,
            rows: args.rows,
            margin: args.margin,
            ..ChartSpec::default()
        }
        .square_to_fill(p),
        None => args.square_mm,
    };
    let spec = ChartSpec {
        cols: args.cols,
        rows: args.rows,
        square_mm,
        margin: args.margin,
        ..ChartSpec::default()
    };
    spec.validate()?;
    let ext = args
        .out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "svg" => write_atomic(&args.out, to_svg(&spec)?.as_bytes())?,
        "pdf" => write_atomic(&args.out, &to_pdf(&spec)?)?,
        "png" => {
            let plane = to_plane(&spec, args.dpi)?;
            save_planes(&args.out, &[(Channel::Y, plane)], true)?;
        }
        _ => bail!(
            "{}: the chart is written as .svg, .pdf or .png",
            args.out.display()
        ),
    }
    let (w, h) = spec.paper_mm();
    eprintln!(
        "{}: {} × {} squares of {} mm on {w:.0} × {h:.0} mm paper; print at 100 % scale",
        args.out.display(),
        spec.cols,
        spec.rows,
        spec.square_mm
    );
    if let Some(p) = &args.spec_out {
        spec.save(p)?;
    }
    Ok(())
}
