//! `lensblur sweeps`: C_xx, C_yy, C_or against aperture at a fixed focal length and
//! against focal length at a fixed aperture, one series per sensor location and
//! channel: measured points and model curves (the paper's Fig. 4).

use super::calibrate::{SessionArgs, load_session};
use super::common::{write_atomic, write_json};
use anyhow::{Context, Result, bail};
use lensblur::model::{Dataset, FittedModel, LocalOptions, ModelKind, fit_model};
use lensblur::plane::{Channel, LensSetting};
use lensblur::profile::Profile;
use lensblur::psf::Gaussian2;
use lensblur::review;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Where to write the sweeps (lensblur.sweeps/1 JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write <out>.csv (one row per point).
    #[arg(long)]
    pub csv: bool,
    /// Model curves from this profile (otherwise a model is fitted to the session).
    #[arg(long)]
    pub profile: Option<PathBuf>,
    /// Model fitted when no profile is given.
    #[arg(long, value_enum, default_value = "global")]
    pub model: super::predict::KindArg,
    /// Spatial order α of the model fitted when no profile is given.
    #[arg(long, default_value_t = 6)]
    pub alpha: usize,
    /// Default N − 1.
    #[arg(long)]
    pub beta: Option<usize>,
    /// Focal length (mm) of the aperture sweep; default: the calibrated one nearest the middle.
    #[arg(long)]
    pub focal: Option<f64>,
    /// f-number of the focal-length sweep; default: the calibrated one nearest the middle (in stops).
    #[arg(long)]
    pub aperture: Option<f64>,
    /// A JSON file of sensor locations, [[x, y], ...] in full-resolution pixels;
    /// default: the centre and four off-axis points.
    #[arg(long)]
    pub points: Option<PathBuf>,
    /// Points on each model curve.
    #[arg(long, default_value_t = 25)]
    pub steps: usize,
}

/// Where the model curves come from.
enum Curves {
    /// A profile's preferred model, as `lensblur predict` uses it: settings it would
    /// refuse are left off the curve and predictions are kept physical.
    Profile(Box<Profile>),
    /// A model fitted to the session, as it is.
    Fitted(Box<dyn FittedModel>),
}

impl Curves {
    /// The Gaussian at (channel, x, y, setting), if the curve reaches it.
    fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<Gaussian2> {
        match self {
            Self::Profile(p) => p.predict(channel, x, y, s).ok(),
            Self::Fitted(m) => m
                .predict(channel, x, y, s)
                .map(|[cxx, cyy, cor]| Gaussian2::new(cxx, cyy, cor)),
        }
    }
}

#[derive(Serialize)]
struct Point {
    focal_mm: f64,
    f_number: f64,
    cxx: f64,
    cyy: f64,
    cor: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    shot: Option<String>,
}

impl Point {
    fn new(s: LensSetting, g: &Gaussian2, shot: Option<String>) -> Self {
        Self {
            focal_mm: s.focal_mm,
            f_number: s.f_number,
            cxx: g.sigma_x,
            cyy: g.sigma_y,
            cor: g.rho,
            shot,
        }
    }
}

#[derive(Serialize)]
struct Series {
    location: usize,
    x: f64,
    y: f64,
    channel: Channel,
    measured: Vec<Point>,
    model: Vec<Point>,
}

#[derive(Serialize)]
struct Sweep {
    /// "f_number" or "focal_mm": what varies along the series.
    varies: &'static str,
    fixed_focal_mm: Option<f64>,
    fixed_f_number: Option<f64>,
    series: Vec<Series>,
}

#[derive(Serialize)]
struct Sweeps {
    schema: &'static str,
    model: String,
    locations: Vec<[f64; 2]>,
    vs_aperture: Sweep,
    vs_focal: Sweep,
}

/// The calibrated value nearest the middle of `values`' range (in stops when `log`).
fn middle(values: &[f64], log: bool) -> Option<f64> {
    let (lo, hi) = (*values.first()?, *values.last()?);
    let mid = if log {
        (lo * hi).sqrt()
    } else {
        0.5 * (lo + hi)
    };
    review::nearest_value(values, mid)
}

/// The sensor locations asked for, or the centre and four off-axis points.
fn locations(args: &Args, ds: &Dataset) -> Result<Vec<[f64; 2]>> {
    if let Some(p) = &args.points {
        let t =
            std::fs::read_to_string(p).with_context(|| format!("{}: cannot read", p.display()))?;
        return serde_json::from_str(&t)
            .with_context(|| format!("{}: expected [[x, y], ...]", p.display()));
    }
    let (w, h) = ((ds.width - 1) as f64, (ds.height - 1) as f64);
    Ok(vec![
        [0.5 * w, 0.5 * h],
        [0.12 * w, 0.12 * h],
        [0.88 * w, 0.12 * h],
        [0.12 * w, 0.88 * h],
        [0.88 * w, 0.88 * h],
    ])
}

/// One sweep at every location and channel: the measured points (the studio's rule,
/// `review::sweep_points`) and the model curve over `settings`.
fn sweep(
    ds: &Dataset,
    curves: &Curves,
    locations: &[[f64; 2]],
    vs_aperture: bool,
    fixed: f64,
    settings: &[LensSetting],
) -> Vec<Series> {
    let mut out = Vec::new();
    for ch in ds.channels() {
        for (location, &[x, y]) in locations.iter().enumerate() {
            let measured = review::sweep_points(ds, ch, (x, y), vs_aperture, fixed)
                .into_iter()
                .map(|p| {
                    let shot = ds.shots.get(p.shot).map(|s| s.name.clone());
                    Point::new(p.setting, &p.gaussian, shot)
                })
                .collect();
            let model = settings
                .iter()
                .filter_map(|&s| Some(Point::new(s, &curves.predict(ch, x, y, s)?, None)))
                .collect();
            out.push(Series {
                location,
                x,
                y,
                channel: ch,
                measured,
                model,
            });
        }
    }
    out
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_out_folder(&args.out)?;
    let (ds, _) = load_session(&args.session, "lensblur sweeps")?;
    ds.validate()?;
    let (fs, as_) = ds.distinct_settings();
    let (curves, name) = if let Some(p) = &args.profile {
        let profile = Profile::load(p)?;
        let name = format!("{:?} model of {}", profile.preferred, p.display()).to_lowercase();
        (Curves::Profile(Box::new(profile)), name)
    } else {
        let beta = args.beta.unwrap_or(ds.setting_resolution() - 1);
        let kind = ModelKind::from(args.model);
        let m = fit_model(&ds, kind, args.alpha, beta, &LocalOptions::default())?;
        let name = m.name();
        (Curves::Fitted(m), name)
    };
    let locations = locations(&args, &ds)?;
    let focal = match args.focal {
        Some(f) => f,
        None => middle(&fs, false).context("no focal lengths in the session")?,
    };
    let aperture = match args.aperture {
        Some(a) => a,
        None => middle(&as_, true).context("no apertures in the session")?,
    };
    let steps = args.steps.max(2) - 1;
    let a_curve = review::sweep_settings([as_[0], as_[as_.len() - 1]], focal, true, steps);
    let f_curve = review::sweep_settings([fs[0], fs[fs.len() - 1]], aperture, false, steps);
    let vs_a = sweep(&ds, &curves, &locations, true, focal, &a_curve);
    let vs_f = sweep(&ds, &curves, &locations, false, aperture, &f_curve);
    if vs_a.iter().all(|s| s.measured.is_empty()) && vs_f.iter().all(|s| s.measured.is_empty()) {
        bail!(
            "no measured samples near the requested locations at {} or {}",
            lensblur::plane::focal_text(focal),
            lensblur::plane::f_number_text(aperture)
        );
    }
    let out = Sweeps {
        schema: "lensblur.sweeps/1",
        model: name,
        locations,
        vs_aperture: Sweep {
            varies: "f_number",
            fixed_focal_mm: Some(focal),
            fixed_f_number: None,
            series: vs_a,
        },
        vs_focal: Sweep {
            varies: "focal_mm",
            fixed_focal_mm: None,
            fixed_f_number: Some(aperture),
            series: vs_f,
        },
    };
    write_json(&args.out, &out)?;
    if args.csv {
        let mut p = args.out.as_os_str().to_owned();
        p.push(".csv");
        write_atomic(&PathBuf::from(p), csv(&out).as_bytes())?;
    }
    Ok(())
}

/// The sweeps as CSV, one row per point.
fn csv(out: &Sweeps) -> String {
    let mut csv = String::from("sweep,location,x,y,channel,kind,focal_mm,f_number,cxx,cyy,cor\n");
    for (sweep, sw) in [
        ("vs_aperture", &out.vs_aperture),
        ("vs_focal", &out.vs_focal),
    ] {
        for s in &sw.series {
            for (kind, pts) in [("measured", &s.measured), ("model", &s.model)] {
                for p in pts {
                    let _ = writeln!(
                        csv,
                        "{sweep},{},{:.1},{:.1},{},{kind},{},{},{:.5},{:.5},{:.5}",
                        s.location,
                        s.x,
                        s.y,
                        s.channel,
                        p.focal_mm,
                        p.f_number,
                        p.cxx,
                        p.cyy,
                        p.cor
                    );
                }
            }
        }
    }
    csv
}
