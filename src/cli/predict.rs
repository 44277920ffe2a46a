//! `lensblur predict`: the Gaussian blur a profile predicts at given sensor points or
//! on a grid over the sensor, with its MTF50; JSON, and CSV with `--csv`.

use super::common::{write_atomic, write_json};
use anyhow::{Context, Result};
use lensblur::model::ModelKind;
use lensblur::plane::{Channel, LensSetting};
use lensblur::profile::Profile;
use lensblur::psf::Mtf50Record;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// The lens profile (lensblur.profile/4).
    #[arg(long)]
    pub profile: PathBuf,
    /// Focal length in mm.
    #[arg(long)]
    pub focal: f64,
    /// Aperture as an f-number.
    #[arg(long)]
    pub aperture: f64,
    /// A JSON file of sensor points, [[x, y], ...] in full-resolution pixels.
    #[arg(long, required_unless_present = "grid", conflicts_with = "grid")]
    pub points: Option<PathBuf>,
    /// Instead of --points, a grid of NX × NY points over the sensor, each at the
    /// centre of its cell (the studio's predicted field).
    #[arg(long, value_name = "NX,NY", value_parser = parse_grid)]
    pub grid: Option<(usize, usize)>,
    /// Where to write the predictions (JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write <out>.csv, one row per channel and point.
    #[arg(long)]
    pub csv: bool,
    /// Channels to predict, comma-separated: r, g, b or y (default: every channel of the
    /// profile).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub channels: Vec<super::sharpness::ChannelArg>,
    /// Use this model instead of the profile's preferred one.
    #[arg(long, value_enum)]
    pub model: Option<KindArg>,
    /// Predict outside the calibrated range of focal length and aperture.
    #[arg(long)]
    pub allow_extrapolation: bool,
}

/// Points a side of `--grid` may have: enough for a field every few pixels of a large
/// sensor, few enough that the output stays a file a spreadsheet opens.
const MAX_GRID_SIDE: usize = 1000;

fn parse_grid(s: &str) -> Result<(usize, usize), String> {
    let (nx, ny) = s
        .split_once(',')
        .ok_or_else(|| format!("'{s}': expected NX,NY (e.g. 12,8)"))?;
    let side = |v: &str| {
        v.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=MAX_GRID_SIDE).contains(n))
            .ok_or_else(|| format!("'{v}': each side must be a whole number 1–{MAX_GRID_SIDE}"))
    };
    Ok((side(nx)?, side(ny)?))
}

#[derive(clap::ValueEnum, Clone, Copy, Default)]
pub enum KindArg {
    #[default]
    Global,
    Local,
}

impl From<KindArg> for ModelKind {
    fn from(k: KindArg) -> Self {
        match k {
            KindArg::Global => ModelKind::Global,
            KindArg::Local => ModelKind::Local,
        }
    }
}

#[derive(Serialize)]
struct Pred {
    focal_mm: f64,
    f_number: f64,
    samples: Vec<PredSample>,
}

#[derive(Serialize)]
struct PredSample {
    x: f64,
    y: f64,
    channel: Channel,
    cxx: f64,
    cyy: f64,
    cor: f64,
    /// Absent where the prediction is degenerate (never for a valid profile: its σs
    /// are at least 0.05 px and |ρ| at most 0.99).
    #[serde(skip_serializing_if = "Option::is_none")]
    mtf50: Option<Mtf50Record>,
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_out_folder(&args.out)?;
    let mut profile = Profile::load(&args.profile)?;
    profile.allow_extrapolation = args.allow_extrapolation;
    let setting = LensSetting {
        focal_mm: args.focal,
        f_number: args.aperture,
    };
    // Outside the shots' range (only reached with --allow-extrapolation), far from
    // any shot, or where the profile recorded a large held-out error: one line.
    if (args.allow_extrapolation || profile.covers(setting))
        && let Some(line) = profile.trust_line(setting, None, None)
    {
        eprintln!("lensblur: {line}");
    }
    let (points, origin) = match (&args.points, args.grid) {
        (Some(path), _) => {
            let text = lensblur::io::read_json_text(path)
                .with_context(|| format!("{}: cannot read", path.display()))?;
            let points: Vec<[f64; 2]> = serde_json::from_str(&text)
                .with_context(|| format!("{}: expected [[x, y], ...]", path.display()))?;
            (points, path.display().to_string())
        }
        (None, Some((nx, ny))) => (
            lensblur::review::field_grid(profile.norm.width, profile.norm.height, nx, ny),
            format!("--grid {nx},{ny}"),
        ),
        (None, None) => anyhow::bail!("give --points or --grid"),
    };
    let kind = args.model.map_or(profile.preferred, ModelKind::from);
    let channels = if args.channels.is_empty() {
        profile.model(kind)?.channels()
    } else {
        args.channels.iter().map(|&c| Channel::from(c)).collect()
    };
    let (w, h) = (profile.norm.width as f64, profile.norm.height as f64);
    if let Some(p) = points.iter().find(|p| {
        !(p[0].is_finite()
            && p[1].is_finite()
            && (0.0..=w - 1.0).contains(&p[0])
            && (0.0..=h - 1.0).contains(&p[1]))
    }) {
        anyhow::bail!(
            "{origin}: point [{}, {}] lies outside the profile's {}×{} sensor",
            p[0],
            p[1],
            profile.norm.width,
            profile.norm.height
        );
    }
    let outside = points
        .iter()
        .filter(|p| !profile.norm.in_sampled_extent(p[0], p[1]))
        .count();
    if outside > 0 {
        eprintln!(
            "lensblur: warning: {outside} of {} points lie outside the area the chart covered in calibration; their blur is extrapolated linearly from its border",
            points.len()
        );
    }
    let mut samples = Vec::with_capacity(points.len() * channels.len());
    for &ch in &channels {
        for &[x, y] in &points {
            let g = profile.predict_with(kind, ch, x, y, setting)?;
            samples.push(PredSample {
                x,
                y,
                channel: ch,
                cxx: g.sigma_x,
                cyy: g.sigma_y,
                cor: g.rho,
                mtf50: g.mtf50().map(|m| m.record(profile.norm.height)),
            });
        }
    }
    let pred = Pred {
        focal_mm: args.focal,
        f_number: args.aperture,
        samples,
    };
    write_json(
        &args.out,
        &lensblur::format::Versioned::new(&lensblur::format::PREDICTION, &pred),
    )?;
    if args.csv {
        let mut p = args.out.as_os_str().to_owned();
        p.push(".csv");
        write_atomic(&PathBuf::from(p), csv(&pred).as_bytes())?;
    }
    Ok(())
}

/// The predictions as CSV (docs/formats.md, "Points and predictions"): `sigma` is
/// √(C_xx·C_yy); `mtf50` the worst direction's, in cycles/px and line pairs per
/// picture height; empty cells where a prediction has no MTF50.
fn csv(pred: &Pred) -> String {
    let mut out = String::from(
        "x,y,channel,cxx,cyy,cor,sigma,mtf50,mtf50_best,mtf50_isotropic,mtf50_lp_ph\n",
    );
    for s in &pred.samples {
        let sigma = lensblur::psf::Gaussian2 {
            sigma_x: s.cxx,
            sigma_y: s.cyy,
            rho: s.cor,
        }
        .sigma();
        let mtf = s.mtf50.map_or_else(
            || ",,,".to_owned(),
            |m| {
                format!(
                    "{:.5},{:.5},{:.5},{:.1}",
                    m.worst, m.best, m.isotropic, m.worst_lp_ph
                )
            },
        );
        let _ = writeln!(
            out,
            "{:.2},{:.2},{},{:.5},{:.5},{:.5},{sigma:.5},{mtf}",
            s.x, s.y, s.channel, s.cxx, s.cyy, s.cor
        );
    }
    out
}
