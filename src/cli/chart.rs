//! `lensblur chart --out chart.{svg,pdf,png} [--cols C --rows R --square-mm S | --paper
//! a4|a3|a2|letter|tabloid] [--dpi D] [--spec-out chart.json]`: the calibration chart
//! for printing, and its spec.

use super::common::write_atomic;
use anyhow::{Result, bail};
use lensblur::chart::export::{to_pdf, to_plane, to_svg};
use lensblur::chart::{ChartSpec, NOTES_MM, PRINTER_MARGIN_MM, Paper};
use lensblur::plane::Channel;
use lensblur::plane::millimetres;
use lensblur::raw::save_planes;
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// Output file; the format follows the extension: .svg (the chart at its physical
    /// size), .pdf (a page the size of the sheet, the chart centred on it at its
    /// physical size, with a 100 mm scale bar and how to print it) or .png (at --dpi).
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
    /// Size the squares to fill a sheet (landscape, inside a 10 mm printer margin and
    /// above the PDF's notes), in whole half-millimetres; the PDF's page is that sheet.
    /// Without it, the PDF's page is the first of these the chart fits on.
    #[arg(long, value_enum)]
    pub paper: Option<PaperArg>,
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

/// The sheets a chart can be sized to, as `--paper` takes them.
#[derive(clap::ValueEnum, Clone, Copy)]
pub enum PaperArg {
    A4,
    A3,
    A2,
    Letter,
    Tabloid,
}

impl From<PaperArg> for Paper {
    fn from(p: PaperArg) -> Self {
        match p {
            PaperArg::A4 => Paper::A4,
            PaperArg::A3 => Paper::A3,
            PaperArg::A2 => Paper::A2,
            PaperArg::Letter => Paper::Letter,
            PaperArg::Tabloid => Paper::Tabloid,
        }
    }
}

pub fn run(args: Args) -> Result<()> {
    let paper = args.paper.map(Paper::from);
    super::common::check_out_folder(&args.out)?;
    let square_mm = match paper {
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
        "pdf" => write_atomic(&args.out, &to_pdf(&spec, paper)?)?,
        "png" => {
            let plane = to_plane(&spec, args.dpi)?;
            save_planes(&args.out, &[(Channel::Y, plane)], true)?;
        }
        _ => bail!(
            "{}: the chart is written as .svg, .pdf or .png",
            args.out.display()
        ),
    }
    eprintln!("{}: {}", args.out.display(), printed(&spec, paper));
    if let Some(p) = &args.spec_out {
        spec.save(p)?;
    }
    Ok(())
}

/// What was written and how to print it, in the numbers the guide gives: the squares,
/// the chart's printed size, and the sheet it is centred on or fits (or that it fits
/// none).
fn printed(spec: &ChartSpec, paper: Option<Paper>) -> String {
    let (w, h) = spec.paper_mm();
    let chart = format!(
        "{} × {} squares of {} mm, chart {} × {} mm",
        spec.cols,
        spec.rows,
        millimetres(spec.square_mm),
        millimetres(w),
        millimetres(h)
    );
    let print = "print at 100 % / actual size, never \"fit to page\"";
    match paper.or_else(|| spec.sheet()) {
        Some(p) => format!("{chart}, centred on {p} landscape; {print}"),
        None => format!(
            "{chart}: fits none of {} inside a {} mm printer margin; {print}, on a sheet of at least {} × {} mm, or size it to a sheet with --paper",
            Paper::ALL.map(Paper::name).join(", "),
            millimetres(PRINTER_MARGIN_MM),
            millimetres(w + 2.0 * PRINTER_MARGIN_MM),
            millimetres(h + NOTES_MM + 2.0 * PRINTER_MARGIN_MM)
        ),
    }
}
