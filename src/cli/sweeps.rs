//! `lensblur sweeps`: C_xx, C_yy, C_or against aperture at a fixed focal length and
//! against focal length at a fixed aperture, one series per sensor location and
//! channel: measured points and model curves (the paper's Fig. 4).

use super::calibrate::{SessionArgs, load_session};
use super::common::{write_atomic, write_json};
use anyhow::{Context, Result, bail};
use lensblur::model::{Dataset, FittedModel, LocalOptions, ModelKind, ShotInfo, fit_model, spaced};
use lensblur::plane::{Channel, LensSetting};
use lensblur::profile::Profile;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
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
    /// Sensor locations [[x, y], ...]; default: the centre and four off-axis points.
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
    /// C_xx, C_yy, C_or at (channel, x, y, setting).
    fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<[f64; 3]> {
        match self {
            Self::Profile(p) => p
                .predict(channel, x, y, s)
                .ok()
                .map(|g| [g.sigma_x, g.sigma_y, g.rho]),
            Self::Fitted(m) => m.predict(channel, x, y, s),
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

fn middle(values: &[f64], log: bool) -> Option<f64> {
    let (lo, hi) = (*values.first()?, *values.last()?);
    let mid = if log {
        (lo * hi).sqrt()
    } else {
        0.5 * (lo + hi)
    };
    values
        .iter()
        .copied()
        .min_by(|a, b| (a - mid).abs().total_cmp(&(b - mid).abs()))
}

pub fn run(args: Args) -> Result<()> {
    super::common::check_out_folder(&args.out)?;
    let (ds, _) = load_session(&args.session)?;
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
    let locations: Vec<[f64; 2]> = match &args.points {
        Some(p) => {
            let t = std::fs::read_to_string(p)
                .with_context(|| format!("{}: cannot read", p.display()))?;
            serde_json::from_str(&t)
                .with_context(|| format!("{}: expected [[x, y], ...]", p.display()))?
        }
        None => {
            let (w, h) = ((ds.width - 1) as f64, (ds.height - 1) as f64);
            vec![
                [0.5 * w, 0.5 * h],
                [0.12 * w, 0.12 * h],
                [0.88 * w, 0.12 * h],
                [0.12 * w, 0.88 * h],
                [0.88 * w, 0.88 * h],
            ]
        }
    };
    let focal = match args.focal {
        Some(f) => f,
        None => middle(&fs, false).context("no focal lengths in the session")?,
    };
    let aperture = match args.aperture {
        Some(a) => a,
        None => middle(&as_, true).context("no apertures in the session")?,
    };
    let near_px = 0.75 * ds.largest_square_px();
    let steps = args.steps.max(2);
    let a_curve = spaced(as_[0], as_[as_.len() - 1], steps, true);
    let f_curve = spaced(fs[0], fs[fs.len() - 1], steps, false);
    let mut vs_a = Vec::new();
    let mut vs_f = Vec::new();
    for ch in ds.channels() {
        for (li, &[x, y]) in locations.iter().enumerate() {
            let series = |fixed_is_focal: bool| {
                let measured = measured_near(&ds, ch, x, y, near_px, |s| {
                    if fixed_is_focal {
                        LensSetting::same_value(s.focal_mm, focal)
                    } else {
                        LensSetting::same_value(s.f_number, aperture)
                    }
                });
                let model: Vec<Point> = if fixed_is_focal { &a_curve } else { &f_curve }
                    .iter()
                    .filter_map(|&v| {
                        let s = if fixed_is_focal {
                            LensSetting {
                                focal_mm: focal,
                                f_number: v,
                            }
                        } else {
                            LensSetting {
                                focal_mm: v,
                                f_number: aperture,
                            }
                        };
                        curves.predict(ch, x, y, s).map(|p| Point {
                            focal_mm: s.focal_mm,
                            f_number: s.f_number,
                            cxx: p[0],
                            cyy: p[1],
                            cor: p[2],
                            shot: None,
                        })
                    })
                    .collect();
                Series {
                    location: li,
                    x,
                    y,
                    channel: ch,
                    measured,
                    model,
                }
            };
            vs_a.push(series(true));
            vs_f.push(series(false));
        }
    }
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
        let mut csv =
            String::from("sweep,location,x,y,channel,kind,focal_mm,f_number,cxx,cyy,cor\n");
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
        let mut p = args.out.as_os_str().to_owned();
        p.push(".csv");
        write_atomic(&PathBuf::from(p), csv.as_bytes())?;
    }
    Ok(())
}

/// Per shot passing `keep`, the sample of `channel` nearest (x, y) within `near_px`.
fn measured_near(
    ds: &Dataset,
    channel: Channel,
    x: f64,
    y: f64,
    near_px: f64,
    keep: impl Fn(&ShotInfo) -> bool,
) -> Vec<Point> {
    let mut out = Vec::new();
    for (i, shot) in ds.shots.iter().enumerate() {
        if !keep(shot) {
            continue;
        }
        let best = ds
            .samples
            .iter()
            .filter(|s| s.shot == i && s.channel == channel)
            .map(|s| ((s.x - x).hypot(s.y - y), s))
            .filter(|(d, _)| *d <= near_px)
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((_, s)) = best {
            let p = s.params();
            out.push(Point {
                focal_mm: shot.focal_mm,
                f_number: shot.f_number,
                cxx: p[0],
                cyy: p[1],
                cor: p[2],
                shot: Some(shot.name.clone()),
            });
        }
    }
    out.sort_by(|a, b| {
        a.f_number
            .total_cmp(&b.f_number)
            .then(a.focal_mm.total_cmp(&b.focal_mm))
    });
    out
}
