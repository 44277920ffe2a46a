//! `lensblur predict`: the Gaussian blur a profile predicts at given sensor points.

use super::common::write_json;
use anyhow::{Context, Result};
use lensblur::model::ModelKind;
use lensblur::plane::{Channel, LensSetting};
use lensblur::profile::Profile;
use serde::Serialize;
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// The lens profile (lensblur.profile/1).
    #[arg(long)]
    pub profile: PathBuf,
    /// Focal length in mm.
    #[arg(long)]
    pub focal: f64,
    /// Aperture as an f-number.
    #[arg(long)]
    pub aperture: f64,
    /// Sensor points: [[x, y], ...] in full-resolution pixels.
    #[arg(long)]
    pub points: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Channels to predict (default: every channel of the profile).
    #[arg(long, value_delimiter = ',')]
    pub channels: Vec<Channel>,
    /// Use this model instead of the profile's preferred one.
    #[arg(long, value_enum)]
    pub model: Option<KindArg>,
    /// Predict outside the calibrated range of focal length and aperture.
    #[arg(long)]
    pub allow_extrapolation: bool,
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
}

pub fn run(args: Args) -> Result<()> {
    let mut profile = Profile::load(&args.profile)?;
    profile.allow_extrapolation = args.allow_extrapolation;
    let setting = LensSetting {
        focal_mm: args.focal,
        f_number: args.aperture,
    };
    if !profile.norm.contains(setting) && args.allow_extrapolation {
        eprintln!(
            "lensblur: warning: f = {} mm, f/{} is outside the calibrated range; extrapolating",
            args.focal, args.aperture
        );
    }
    let text = std::fs::read_to_string(&args.points)
        .with_context(|| format!("{}: cannot read", args.points.display()))?;
    let points: Vec<[f64; 2]> = serde_json::from_str(&text)
        .with_context(|| format!("{}: expected [[x, y], ...]", args.points.display()))?;
    let kind = args.model.map_or(profile.preferred, ModelKind::from);
    let channels = if args.channels.is_empty() {
        profile.model(kind)?.channels()
    } else {
        args.channels.clone()
    };
    let (w, h) = (profile.norm.width as f64, profile.norm.height as f64);
    if let Some(p) = points.iter().find(|p| {
        !(p[0].is_finite()
            && p[1].is_finite()
            && (0.0..=w - 1.0).contains(&p[0])
            && (0.0..=h - 1.0).contains(&p[1]))
    }) {
        anyhow::bail!(
            "{}: point [{}, {}] lies outside the profile's {}×{} sensor",
            args.points.display(),
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
            });
        }
    }
    write_json(
        &args.out,
        &lensblur::format::Versioned::new(
            &lensblur::format::PREDICTION,
            &Pred {
                focal_mm: args.focal,
                f_number: args.aperture,
                samples,
            },
        ),
    )
}
