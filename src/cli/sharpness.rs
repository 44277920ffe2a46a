//! `lensblur sharpness`: the sharpness map, MTF50 over the whole frame, predicted by a
//! profile at a focal length and aperture (`--profile --focal --aperture`) or measured
//! on one shot (`--kernels`); written as a PNG with its colour bar and as CSV.

use super::common::write_atomic;
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
    /// The colour channel.
    #[arg(long, default_value = "g")]
    pub channel: Channel,
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
    let map = match (&args.profile, &args.kernels) {
        (Some(path), _) => {
            let (Some(focal_mm), Some(f_number)) = (args.focal, args.aperture) else {
                bail!("--profile needs --focal and --aperture: the setting to map");
            };
            let profile = Profile::load(path)?;
            SharpnessMap::predicted(
                &profile,
                args.channel,
                LensSetting { focal_mm, f_number },
                direction,
            )
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
        }
        (None, Some(path)) => {
            let file = KernelsFile::load(path)?;
            let name = path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            SharpnessMap::measured(
                &file,
                args.channel,
                direction,
                format!("measured on {name}"),
            )
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
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
        println!(
            "MTF50 {} ({}), {}: centre {:.d$}, corners {:.d$}, from {:.d$} to {:.d$}, median {:.d$} {}",
            direction.label(),
            args.channel.name(),
            map.title,
            s.centre,
            s.corners,
            s.min,
            s.max,
            s.median,
            unit.label()
        );
    }
    Ok(())
}
