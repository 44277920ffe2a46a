//! `lensblur detect SHOT --out detect.json [--chart chart.json]`: find the chart's
//! squares and align each to sub-pixel accuracy (DESIGN.md §3).

use super::common::{load_chart, progress_job, write_json};
use anyhow::{Context, Result, bail};
use lensblur::detect::{DetectParams, SquareStatus, detect};
use lensblur::plane::{Capture, Channel, ChannelPlane, Plane};
use std::path::{Path, PathBuf};

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
    let spec = load_chart(args.chart.as_deref())?;
    let capture = load_shot(&args.shot)?;
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

/// Loads a PNG/TIFF/JPEG shot into linear planes: 16-bit and float images are linear,
/// 8-bit ones are sRGB-decoded.
fn load_shot(path: &Path) -> Result<Capture> {
    let img = image::ImageReader::open(path)
        .with_context(|| format!("{}: cannot open", path.display()))?
        .with_guessed_format()
        .with_context(|| format!("{}: cannot read", path.display()))?
        .decode()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 16 || h < 16 || w > 100_000 || h > 100_000 {
        bail!("{}: absurd image size {w} × {h}", path.display());
    }
    let eight_bit = matches!(
        img.color(),
        image::ColorType::L8
            | image::ColorType::La8
            | image::ColorType::Rgb8
            | image::ColorType::Rgba8
    );
    let grey = matches!(
        img.color(),
        image::ColorType::L8
            | image::ColorType::La8
            | image::ColorType::L16
            | image::ColorType::La16
    );
    let rgb = img.into_rgb32f();
    let decode = |v: f32| -> f32 {
        if eight_bit {
            if v <= 0.04045 {
                v / 12.92
            } else {
                ((v + 0.055) / 1.055).powf(2.4)
            }
        } else {
            v
        }
    };
    let channels: &[(Channel, usize)] = if grey {
        &[(Channel::Y, 0)]
    } else {
        &[(Channel::R, 0), (Channel::G, 1), (Channel::B, 2)]
    };
    let planes = channels
        .iter()
        .map(|&(channel, c)| ChannelPlane {
            channel,
            plane: Plane::from_fn(w, h, |x, y| decode(rgb.get_pixel(x as u32, y as u32)[c])),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        })
        .collect();
    Ok(Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: None,
        setting_f_number: None,
        identity: Default::default(),
        is_raw: false,
    })
}
