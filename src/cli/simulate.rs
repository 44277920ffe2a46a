//! `lensblur simulate --out DIR [--lens demo|LENS.json] [--width W --height H] [...]`:
//! calibration shots of a virtual lens over a grid of settings, each under its own
//! camera pose, with a manifest and the exact ground truth of every shot.

use super::common::{progress_job, write_json};
use anyhow::{Context, Result, bail};
use lensblur::chart::ChartSpec;
use lensblur::manifest::{ChartRef, Manifest, ManifestShot};
use lensblur::plane::LensSetting;
use lensblur::simulate::{
    CaptureParams, DngCompression, DngLayout, NoiseModel, Pose, PsfShape, ShotFormat, VirtualLens,
    simulate_shot, write_shot_as,
};
use rand::{Rng, SeedableRng};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, Default, clap::ValueEnum)]
pub enum FormatArg {
    /// RGGB Bayer RAW in a DNG (14-bit, settings in EXIF).
    #[default]
    Dng,
    /// Linear 16-bit RGB PNG.
    Png,
    /// Linear 16-bit RGB TIFF.
    Tiff,
}

#[derive(Clone, Copy, Debug, Default, clap::ValueEnum)]
pub enum DngCompressionArg {
    /// 16-bit samples as they are.
    #[default]
    None,
    /// Lossless JPEG, as Adobe's DNG converter writes.
    Ljpeg,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ShapeArg {
    /// The lens's Gaussian at each point.
    Gaussian,
    /// A defocus disc.
    Disc,
    /// A coma-like comet with a tail pointing away from the centre.
    Comet,
    /// Diffraction through a Seidel wavefront (the lens's aberration design).
    Aberrated,
}

#[derive(clap::Args)]
pub struct Args {
    /// Folder for the shots, manifest.json, lens.json and the *.truth.json files.
    #[arg(long)]
    pub out: PathBuf,
    /// The virtual lens: `demo` (a 24–105 mm f/4 zoom), `demo2` (a second copy of it,
    /// decentred differently), `aberrated` (the same ranges with physically based
    /// PSFs) or a lens description JSON file.
    #[arg(long, default_value = "demo")]
    pub lens: String,
    /// Sensor width in pixels.
    #[arg(long, default_value_t = 2400)]
    pub width: usize,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = 1600)]
    pub height: usize,
    /// Focal lengths in mm, comma-separated; default: `--grid` values over the lens's range.
    #[arg(long, value_delimiter = ',')]
    pub focal: Vec<f64>,
    /// f-numbers, comma-separated; default: `--grid` values over the lens's range (even
    /// in stops).
    #[arg(long, value_delimiter = ',')]
    pub aperture: Vec<f64>,
    /// Settings per axis when `--focal` or `--aperture` is not given.
    #[arg(long, default_value_t = 5)]
    pub grid: usize,
    /// Shots per setting, each under its own pose and noise.
    #[arg(long, default_value_t = 1)]
    pub shots_per_setting: usize,
    #[arg(long, value_enum, default_value_t = FormatArg::Dng)]
    pub format: FormatArg,
    /// DNG samples in square tiles of this side (a multiple of 16) instead of strips.
    #[arg(long)]
    pub dng_tile: Option<usize>,
    /// How DNG strips or tiles are stored.
    #[arg(long, value_enum, default_value_t = DngCompressionArg::None)]
    pub dng_compression: DngCompressionArg,
    /// PSF shape, overriding the lens's.
    #[arg(long, value_enum)]
    pub shape: Option<ShapeArg>,
    /// The chart spec to photograph (default: the 24 × 16 chart).
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Fraction of the frame width the checkerboard spans.
    #[arg(long, default_value_t = 0.9)]
    pub fill: f64,
    /// Largest in-plane rotation of the chart, degrees (each shot draws its own).
    #[arg(long, default_value_t = 2.0)]
    pub max_rotation_deg: f64,
    /// Largest perspective tilt (relative scale change from the centre to an edge).
    #[arg(long, default_value_t = 0.02)]
    pub max_tilt: f64,
    /// No photon or read noise (quantisation stays).
    #[arg(long)]
    pub noiseless: bool,
    /// Light the chart unevenly: the light falls by GX stops per half diagonal along x
    /// and GY along y ("0.3,0"), as a lamp to one side would.
    #[arg(long, value_parser = parse_gradient, allow_hyphen_values = true)]
    pub light_gradient: Option<[f64; 2]>,
    /// Also write a flat field per setting (`flat_<setting>.png`, linear 16-bit grey):
    /// an evenly lit white surface through the lens's fall-off, as a diffuser gives.
    #[arg(long)]
    pub flat_field: bool,
    /// Seed of the poses and the noise: the same seed makes the same shots.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            out: PathBuf::new(),
            lens: "demo".into(),
            width: 2400,
            height: 1600,
            focal: Vec::new(),
            aperture: Vec::new(),
            grid: 5,
            shots_per_setting: 1,
            format: FormatArg::Dng,
            dng_tile: None,
            dng_compression: DngCompressionArg::None,
            shape: None,
            chart: None,
            fill: 0.9,
            max_rotation_deg: 2.0,
            max_tilt: 0.02,
            noiseless: false,
            light_gradient: None,
            flat_field: false,
            seed: 1,
        }
    }
}

fn parse_gradient(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not two numbers such as 0.3,0"))?;
    match v[..] {
        [gx, gy] if gx.abs() <= 4.0 && gy.abs() <= 4.0 => Ok([gx, gy]),
        [_, _] => Err(format!("'{s}': at most 4 stops per half diagonal")),
        _ => Err(format!("'{s}' is not two numbers such as 0.3,0")),
    }
}

fn lens(name: &str) -> Result<VirtualLens> {
    match name {
        "demo" => Ok(VirtualLens::demo()),
        "demo2" => Ok(VirtualLens::demo_second_unit()),
        "aberrated" => Ok(VirtualLens::aberrated()),
        path => VirtualLens::load(std::path::Path::new(path)).map_err(anyhow::Error::msg),
    }
}

fn settings(args: &Args, lens: &VirtualLens) -> Result<Vec<LensSetting>> {
    if !(1..=20).contains(&args.grid) {
        bail!("--grid must be 1–20 (got {})", args.grid);
    }
    let grid = lens.setting_grid(args.grid, args.grid);
    let mut fs = LensSetting::distinct_values(grid.iter().map(|s| s.focal_mm));
    let mut as_ = LensSetting::distinct_values(grid.iter().map(|s| s.f_number));
    if !args.focal.is_empty() {
        fs.clone_from(&args.focal);
    }
    if !args.aperture.is_empty() {
        as_.clone_from(&args.aperture);
    }
    for &f in &fs {
        if !(f.is_finite() && f > 0.0) {
            bail!("--focal: {f} is not a focal length in mm");
        }
    }
    for &a in &as_ {
        if !(a.is_finite() && a > 0.0) {
            bail!("--aperture: {a} is not an f-number");
        }
    }
    Ok(fs
        .iter()
        .flat_map(|&f| {
            as_.iter().map(move |&a| LensSetting {
                focal_mm: f,
                f_number: a,
            })
        })
        .collect())
}

pub fn run(args: Args) -> Result<()> {
    let mut lens = lens(&args.lens)?;
    if let Some(shape) = args.shape {
        lens.shape = match shape {
            ShapeArg::Gaussian => PsfShape::Gaussian,
            ShapeArg::Disc => PsfShape::Disc,
            ShapeArg::Comet => PsfShape::Comet,
            ShapeArg::Aberrated => PsfShape::Aberrated,
        };
    }
    let chart = match &args.chart {
        Some(p) => ChartSpec::load(p)?,
        None => ChartSpec::default(),
    };
    if !(0.1..=1.5).contains(&args.fill) {
        bail!("--fill must be 0.1–1.5 (got {})", args.fill);
    }
    if !(0.0..=45.0).contains(&args.max_rotation_deg) || !(0.0..=0.3).contains(&args.max_tilt) {
        bail!("--max-rotation-deg must be 0–45 and --max-tilt 0–0.3");
    }
    if !(1..=20).contains(&args.shots_per_setting) {
        bail!("--shots-per-setting must be 1–20");
    }
    let format = match args.format {
        FormatArg::Dng => ShotFormat::Dng,
        FormatArg::Png => ShotFormat::Png,
        FormatArg::Tiff => ShotFormat::Tiff,
    };
    let dng_layout = DngLayout {
        tile: args.dng_tile,
        compression: match args.dng_compression {
            DngCompressionArg::None => DngCompression::Uncompressed,
            DngCompressionArg::Ljpeg => DngCompression::LosslessJpeg,
        },
    };
    if let Some(t) = args.dng_tile
        && (t == 0 || !t.is_multiple_of(16) || t > 65_520)
    {
        bail!("--dng-tile must be a multiple of 16 up to 65520 (got {t})");
    }
    let settings = settings(&args, &lens)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    write_json(
        &args.out.join("lens.json"),
        &lensblur::format::Versioned::new(&lensblur::format::LENS, &lens),
    )?;
    let job = progress_job();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(args.seed);
    let mut shots = Vec::new();
    let total = settings.len() * args.shots_per_setting;
    for (k, setting) in settings
        .iter()
        .flat_map(|s| std::iter::repeat_n(*s, args.shots_per_setting))
        .enumerate()
    {
        let mut params = CaptureParams::new(args.width, args.height, setting);
        params.bayer = format.is_raw();
        params.seed = args.seed.wrapping_mul(1_000_003).wrapping_add(k as u64);
        if args.noiseless {
            params.noise = NoiseModel::none();
        }
        if let Some(g) = args.light_gradient {
            params.light_gradient_stops = g;
        }
        let jitter = |rng: &mut rand_pcg::Pcg64, m: f64| {
            if m > 0.0 {
                rng.random_range(-m..=m)
            } else {
                0.0
            }
        };
        params.pose = Pose {
            rotation_deg: jitter(&mut rng, args.max_rotation_deg),
            tilt_x: jitter(&mut rng, args.max_tilt),
            tilt_y: jitter(&mut rng, args.max_tilt),
            fill: args.fill,
            shift_px: [
                jitter(&mut rng, 0.01 * args.width as f64),
                jitter(&mut rng, 0.01 * args.height as f64),
            ],
        };
        let name = format!(
            "f{:05.1}_a{:04.1}_{}",
            setting.focal_mm,
            setting.f_number,
            k % args.shots_per_setting + 1
        );
        let file = format!("{name}.{}", format.extension());
        eprintln!(
            "simulating {file} ({} of {total}): {} × {} at {setting}",
            k + 1,
            args.width,
            args.height,
        );
        let shot = simulate_shot(&chart, &lens, &params, &job)
            .with_context(|| format!("{}: simulating", args.out.join(&file).display()))?;
        write_shot_as(&args.out.join(&file), &shot, format, dng_layout)?;
        write_json(
            &args.out.join(format!("{name}.truth.json")),
            &lensblur::format::Versioned::new(&lensblur::format::TRUTH, &shot.truth),
        )?;
        shots.push(ManifestShot {
            path: PathBuf::from(file),
            focal_mm: Some(setting.focal_mm),
            f_number: Some(setting.f_number),
        });
    }
    if args.flat_field {
        for setting in &settings {
            let name = format!(
                "flat_f{:05.1}_a{:04.1}.png",
                setting.focal_mm, setting.f_number
            );
            let plane = lensblur::simulate::flat_field(&lens, *setting, args.width, args.height);
            lensblur::raw::save_planes(
                &args.out.join(&name),
                &[(lensblur::plane::Channel::Y, plane)],
                false,
            )
            .with_context(|| format!("{}: writing", args.out.join(&name).display()))?;
        }
    }
    let manifest = Manifest::new(Some(ChartRef::Spec(chart)), shots);
    manifest.save(&args.out.join("manifest.json"))?;
    eprintln!(
        "{}: {total} shots, manifest.json, lens.json and ground truth written",
        args.out.display()
    );
    Ok(())
}
