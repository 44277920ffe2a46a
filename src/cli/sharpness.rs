//! `lensblur sharpness`: the sharpness map, MTF50 over the whole frame, predicted by a
//! profile at a focal length and aperture (`--profile --focal --aperture`) or measured
//! on one shot (`--kernels`); written as a PNG with its colour bar and as CSV.

use super::common::{check_out_folder, write_atomic};
use anyhow::{Context, Result, bail};
use lensblur::kernel::file::KernelsFile;
use lensblur::plane::{Channel, LensSetting};
use lensblur::profile::Profile;
use lensblur::review::{Mtf50Direction, SharpnessMap, SharpnessUnit};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Map what this profile predicts (with --focal and --aperture).
    #[arg(long, conflicts_with = "kernels", required_unless_present = "kernels")]
    pub profile: Option<PathBuf>,
    /// Focal length in mm, for --profile.
    #[arg(long, requires = "profile")]
    pub focal: Option<f64>,
    /// Aperture as an f-number, for --profile.
    #[arg(long, requires = "profile")]
    pub aperture: Option<f64>,
    /// Map what one shot's kernels file measured instead.
    #[arg(long)]
    pub kernels: Option<PathBuf>,
    /// Predict with --profile at a setting outside the calibrated ones (the models
    /// extrapolate).
    #[arg(long, requires = "profile")]
    pub allow_extrapolation: bool,
    /// The colour channel (default: G where the kernels have it, else the one they
    /// have: Y for a greyscale chart).
    #[arg(long, value_enum)]
    pub channel: Option<ChannelArg>,
    /// Which MTF50: along the worst or best direction, or isotropic.
    #[arg(long, value_enum, default_value_t = DirectionArg::Worst)]
    pub direction: DirectionArg,
    /// The PNG's unit: line pairs per picture height or cycles per pixel (the CSV
    /// has both).
    #[arg(long, value_enum, default_value_t = UnitArg::LpPh)]
    pub unit: UnitArg,
    /// Write the map as a PNG with its colour bar.
    #[arg(long, required_unless_present = "csv")]
    pub png: Option<PathBuf>,
    /// The PNG's width in pixels.
    #[arg(long, default_value_t = 960, value_parser = clap::value_parser!(u32).range(64..=8000))]
    pub width: u32,
    /// Write the map as CSV, one row per cell.
    #[arg(long)]
    pub csv: Option<PathBuf>,
}

/// A colour channel, as the kernels name it.
#[derive(clap::ValueEnum, Clone, Copy)]
pub enum ChannelArg {
    R,
    G,
    B,
    /// Luminance: a greyscale chart's only channel.
    Y,
}

impl From<ChannelArg> for Channel {
    fn from(c: ChannelArg) -> Self {
        match c {
            ChannelArg::R => Channel::R,
            ChannelArg::G => Channel::G,
            ChannelArg::B => Channel::B,
            ChannelArg::Y => Channel::Y,
        }
    }
}

/// The channel asked for, or G where the kernels have it, else the first they have.
fn pick_channel(asked: Option<ChannelArg>, have: &[Channel]) -> Channel {
    match asked {
        Some(c) => c.into(),
        None if have.contains(&Channel::G) || have.is_empty() => Channel::G,
        None => have[0],
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Default)]
pub enum DirectionArg {
    #[default]
    Worst,
    Best,
    Isotropic,
}

#[derive(clap::ValueEnum, Clone, Copy, Default)]
pub enum UnitArg {
    #[default]
    LpPh,
    CyclesPx,
}

pub fn run(args: Args) -> Result<()> {
    let direction = match args.direction {
        DirectionArg::Worst => Mtf50Direction::Worst,
        DirectionArg::Best => Mtf50Direction::Best,
        DirectionArg::Isotropic => Mtf50Direction::Isotropic,
    };
    let unit = match args.unit {
        UnitArg::LpPh => SharpnessUnit::LpPerPictureHeight,
        UnitArg::CyclesPx => SharpnessUnit::CyclesPerPixel,
    };
    for out in [&args.png, &args.csv].into_iter().flatten() {
        check_out_folder(out)?;
    }
    let (map, channel) = match (&args.profile, &args.kernels) {
        (Some(path), _) => {
            let (Some(focal_mm), Some(f_number)) = (args.focal, args.aperture) else {
                bail!("--profile needs --focal and --aperture: the setting to map");
            };
            let mut profile = Profile::load(path)?;
            let setting = LensSetting { focal_mm, f_number };
            profile.allow_extrapolation = args.allow_extrapolation;
            profile.check_setting(setting).map_err(|e| {
                anyhow::anyhow!(
                    "{}: {e} (--allow-extrapolation to map it anyway)",
                    path.display()
                )
            })?;
            let channel = pick_channel(args.channel, &profile.channels());
            let map = SharpnessMap::predicted(&profile, channel, setting, direction)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            (map, channel)
        }
        (None, Some(path)) => {
            let file = KernelsFile::load(path)?;
            let name = path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            let mut have: Vec<Channel> = Vec::new();
            for s in &file.samples {
                if !have.contains(&s.channel) {
                    have.push(s.channel);
                }
            }
            let channel = pick_channel(args.channel, &have);
            let map =
                SharpnessMap::measured(&file, channel, direction, format!("measured on {name}"))
                    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            (map, channel)
        }
        (None, None) => bail!("give --profile (with --focal and --aperture) or --kernels"),
    };
    if let Some(png) = &args.png {
        map.write_png(png, unit, args.width)
            .map_err(|e| anyhow::anyhow!("{}: {e}", png.display()))?;
    }
    if let Some(csv) = &args.csv {
        write_atomic(csv, map.csv().as_bytes())
            .with_context(|| format!("{}: cannot write", csv.display()))?;
    }
    if let Some(s) = map.summary(unit) {
        let d = match unit {
            SharpnessUnit::LpPerPictureHeight => 1,
            SharpnessUnit::CyclesPerPixel => 4,
        };
        // A measured map may not reach the centre or the corners: said in words.
        let v = |x: f64, place: &str| {
            if x.is_finite() {
                format!("{place} {x:.d$}")
            } else {
                format!("{place} not covered")
            }
        };
        println!(
            "MTF50 {} ({}), {}: {}, {}, from {:.d$} to {:.d$}, median {:.d$} {}",
            direction.label(),
            channel.name(),
            map.title,
            v(s.centre, "centre"),
            v(s.corners, "corners"),
            s.min,
            s.max,
            s.median,
            unit.label()
        );
    }
    Ok(())
}
