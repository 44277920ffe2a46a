//! The demo session the studio makes on first launch: simulated calibration shots of
//! the virtual lens at a grid of settings, written as a session with its manifest and
//! exact ground truth, handed over shot by shot as each is on disk
//! ([`make_demo_streaming`]), and a natural photo (`assets/astronaut.png`, compiled in)
//! blurred through the virtual lens's true kernels at one of its settings. Its spec's
//! key is recorded, so a stale demo is made again.
//!
//! It sits above the session and the simulator (it writes a session of simulated
//! shots); nothing in the core below it depends on it.

use crate::chart::ChartSpec;
use crate::manifest::MANIFEST_FILE;
use crate::plane::LensSetting;
use crate::project::{CV_FILE, PROFILE_FILE};
use crate::session::{DemoPhoto, SESSION_FILE, Session, SessionError, Shot};
use crate::simulate::LensGeometry;
use std::path::{Path, PathBuf};

/// The size and settings of a demo session.
#[derive(Clone, Debug, PartialEq)]
pub struct DemoSpec {
    pub width: usize,
    pub height: usize,
    pub settings: Vec<LensSetting>,
    pub seed: u64,
    /// The chart printed in the demo's shots.
    pub chart: ChartSpec,
    /// The lens's distortion, lateral colour and fall-off in the calibration shots
    /// (the demo photo is blurred without them); none unless given
    /// ([`DemoSpec::with_geometry`]; the studio's demo has a typical zoom's).
    pub geometry: LensGeometry,
    /// Where the chart is put at each setting.
    pub placement: ChartPlacement,
}

/// Where a demo's chart lies in the frame at each setting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ChartPlacement {
    /// One shot per setting, the board spanning 86 % of the frame (of its height
    /// where the chart is taller than the frame's aspect).
    Filling,
    /// A chart too small to fill the frame, shot at `across × down` positions per
    /// setting: its board spans `fill` of the frame's width, and the positions tile
    /// the same 86 % of the frame a filling chart spans, overlapping where the chart
    /// is larger than a tile. How a wide lens is calibrated with a print that fits on
    /// a desk.
    Positions {
        across: usize,
        down: usize,
        fill: f64,
    },
}

/// The share of the frame's width (or height) a demo's board spans, or its
/// positions tile.
const FRAME_SPAN: f64 = 0.86;

impl ChartPlacement {
    /// The positions (column, row) shot at each setting, row-major; `None` for a
    /// filling chart's one shot.
    #[must_use]
    pub fn positions(self) -> Vec<Option<[usize; 2]>> {
        match self {
            ChartPlacement::Filling => vec![None],
            ChartPlacement::Positions { across, down, .. } => (0..down.max(1))
                .flat_map(|r| (0..across.max(1)).map(move |c| Some([c, r])))
                .collect(),
        }
    }

    /// The board's share of the frame width and its centre's offset from the frame's
    /// centre, px, at `position` of a `width × height` frame for a chart of
    /// `cols × rows` squares.
    fn pose_at(
        self,
        position: Option<[usize; 2]>,
        (width, height): (usize, usize),
        (cols, rows): (usize, usize),
    ) -> (f64, [f64; 2]) {
        let (w, h) = (width as f64, height as f64);
        let aspect = rows as f64 / cols.max(1) as f64;
        match (self, position) {
            (ChartPlacement::Positions { across, down, fill }, Some([c, r])) => {
                // Centres evenly spaced so the outermost chart edges meet the span's.
                let step = |n: usize, frame: f64, chart: f64| {
                    if n > 1 {
                        ((FRAME_SPAN * frame - chart) / (n - 1) as f64).max(0.0)
                    } else {
                        0.0
                    }
                };
                let (chart_w, chart_h) = (fill * w, fill * w * aspect);
                let off = |i: usize, n: usize, s: f64| (i as f64 - (n as f64 - 1.0) / 2.0) * s;
                (
                    fill,
                    [
                        off(c, across, step(across, w, chart_w)),
                        off(r, down, step(down, h, chart_h)),
                    ],
                )
            }
            _ => (
                FRAME_SPAN.min(FRAME_SPAN * (h / w) / aspect.max(f64::EPSILON)),
                [0.0, 0.0],
            ),
        }
    }
}

impl DemoSpec {
    /// What the studio makes on first launch: 720 × 480 shots of a 12 × 8 chart (squares
    /// of about 54 px, as many pixels as a kernel needs) at a 3 × 3 grid of settings
    /// (enough for a β = 2 model): small enough that the first launch makes, measures
    /// and calibrates it in about a minute on a 2-core laptop. Its lens has a typical
    /// zoom's geometry, so the Geometry view and the lensfun export show something.
    #[must_use]
    pub fn studio() -> Self {
        Self::grid(720, 480, &[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0])
            .with_chart(12, 8)
            .with_geometry(LensGeometry::typical_zoom())
    }

    /// A small demo for tests: 600 × 400 shots at a 2 × 2 grid of settings.
    #[must_use]
    pub fn small() -> Self {
        Self::grid(600, 400, &[24.0, 105.0], &[4.0, 10.0])
    }

    #[must_use]
    pub fn grid(width: usize, height: usize, focal_mm: &[f64], f_number: &[f64]) -> Self {
        let settings = focal_mm
            .iter()
            .flat_map(|&f| {
                f_number.iter().map(move |&a| LensSetting {
                    focal_mm: f,
                    f_number: a,
                })
            })
            .collect();
        // Fewer squares on small shots so each square still spans enough pixels to
        // measure a kernel.
        let mut chart = ChartSpec::default();
        if width < 1000 {
            chart.cols = 12;
            chart.rows = 8;
        }
        Self {
            width,
            height,
            settings,
            seed: 7,
            chart,
            geometry: LensGeometry::default(),
            placement: ChartPlacement::Filling,
        }
    }

    /// The same demo with the chart placed as `placement` says.
    #[must_use]
    pub fn with_placement(mut self, placement: ChartPlacement) -> Self {
        self.placement = placement;
        self
    }

    /// The same demo with a chart of `cols` × `rows` squares.
    #[must_use]
    pub fn with_chart(mut self, cols: usize, rows: usize) -> Self {
        self.chart.cols = cols;
        self.chart.rows = rows;
        self
    }

    /// The same demo with another lens geometry (`LensGeometry::default()`: none).
    #[must_use]
    pub fn with_geometry(mut self, geometry: LensGeometry) -> Self {
        self.geometry = geometry;
        self
    }

    /// The chart printed in the demo's shots.
    #[must_use]
    pub fn chart(&self) -> ChartSpec {
        self.chart.clone()
    }

    /// Everything that decides the demo's files, and the version of the code that
    /// simulates them: a cached demo with another key is stale.
    #[must_use]
    pub fn key(&self) -> String {
        let settings: Vec<String> = self
            .settings
            .iter()
            .map(|s| format!("{}@{}", s.focal_mm, s.f_number))
            .collect();
        let mut key = format!(
            "lensblur {} demo {}x{} chart {}x{} seed {} settings {}",
            env!("CARGO_PKG_VERSION"),
            self.width,
            self.height,
            self.chart.cols,
            self.chart.rows,
            self.seed,
            settings.join(",")
        );
        if !self.geometry.is_none() {
            let g = &self.geometry;
            key.push_str(&format!(
                " geometry {:?} {:?} {:?} {:?}",
                g.distortion_wide, g.distortion_long, g.lateral_colour, g.vignetting_stops
            ));
        }
        if let ChartPlacement::Positions { across, down, fill } = self.placement {
            key.push_str(&format!(" positions {across}x{down} fill {fill}"));
        }
        key
    }

    /// File name of the demo shot for a setting (with a filling chart).
    #[must_use]
    pub fn shot_name(s: LensSetting) -> String {
        Self::shot_name_at(s, None)
    }

    /// File name of the demo shot for a setting with the chart at `position` (column,
    /// row) of [`ChartPlacement::Positions`].
    #[must_use]
    pub fn shot_name_at(s: LensSetting, position: Option<[usize; 2]>) -> String {
        let at = position.map_or(String::new(), |[c, r]| format!("_p{}{}", r + 1, c + 1));
        format!("demo_f{:03.0}_a{:04.1}{at}.png", s.focal_mm, s.f_number)
    }
}

/// Makes (or remakes) the demo session in `dir`: simulated calibration shots of the
/// virtual lens at `spec`'s settings, their manifest and ground truth.
///
/// # Errors
/// The simulator failed, the folder cannot be written, or the job was cancelled.
pub fn make_demo(
    dir: &Path,
    spec: &DemoSpec,
    job: &crate::job::JobContext,
) -> Result<Session, SessionError> {
    make_demo_streaming(dir, spec, job, &mut |_| {})
}

/// [`make_demo`], handing the session to `on_shot` each time a shot is on disk, so a
/// window can show the first shot within seconds rather than after the whole demo.
/// The session passed is not saved yet; the one returned is, with the demo's photo.
///
/// # Errors
/// As [`make_demo`].
pub fn make_demo_streaming(
    dir: &Path,
    spec: &DemoSpec,
    job: &crate::job::JobContext,
    on_shot: &mut dyn FnMut(&Session),
) -> Result<Session, SessionError> {
    use crate::simulate::{CaptureParams, Pose, VirtualLens, simulate_shot};
    let chart = spec.chart();
    let lens = VirtualLens::demo();
    // The shots carry the spec's geometry; the photo is blurred by the plain lens.
    let shot_lens = VirtualLens {
        geometry: spec.geometry.clone(),
        ..VirtualLens::demo()
    };
    std::fs::create_dir_all(dir).map_err(|source| SessionError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    // Shots left by an interrupted first launch are reused (see below), but only when
    // they were made for this very spec by this version.
    let key = spec.key();
    let key_path = dir.join(DEMO_KEY_FILE);
    if std::fs::read_to_string(&key_path).ok().as_deref() != Some(key.as_str()) {
        clear_demo_files(dir)?;
        write_atomic(&key_path, key.as_bytes())?;
    }
    let mut session = Session::new(dir);
    session.name = "demo".into();
    session.chart = chart.clone();
    session.is_demo = true;
    session.demo_key = Some(key);
    let shots: Vec<(LensSetting, Option<[usize; 2]>)> = spec
        .settings
        .iter()
        .flat_map(|&s| spec.placement.positions().into_iter().map(move |p| (s, p)))
        .collect();
    let total = shots.len();
    job.report("simulating demo shots", 0, total);
    for (k, &(setting, position)) in shots.iter().enumerate() {
        let name = DemoSpec::shot_name_at(setting, position);
        let path = dir.join(&name);
        let truth_path = dir.join(format!("{name}.truth.json"));
        // A session folder that already holds a shot is reused: only missing shots
        // are simulated, so an interrupted first launch resumes where it stopped.
        if !(path.is_file() && truth_path.is_file()) {
            let mut params = CaptureParams::new(spec.width, spec.height, setting);
            let (fill, [sx, sy]) = spec.placement.pose_at(
                position,
                (spec.width, spec.height),
                (chart.cols, chart.rows),
            );
            // Each shot a slightly different pose, as a hand-held series would be.
            let t = k as f64;
            params.pose = Pose {
                rotation_deg: 1.5 * (0.9 * t + 0.3).sin(),
                tilt_x: 0.02 * (1.3 * t).cos(),
                tilt_y: 0.015 * (0.7 * t + 1.0).sin(),
                fill,
                shift_px: [sx + 4.0 * (t * 0.5).sin(), sy + 3.0 * (t * 0.8).cos()],
            };
            params.bayer = false;
            params.seed = spec.seed.wrapping_add(k as u64);
            let shot = simulate_shot(
                &chart,
                &shot_lens,
                &params,
                &job.prefixed(&format!("shot {} of {total}: ", k + 1)),
            )
            .map_err(|e| SessionError::Parse {
                path: path.clone(),
                reason: e.to_string(),
            })?;
            write_rgb16_png(&path, &shot.capture)?;
            let truth = serde_json::to_vec(&crate::format::Versioned::new(
                &crate::format::TRUTH,
                &shot.truth,
            ))
            .map_err(|e| SessionError::Write {
                path: truth_path.clone(),
                source: std::io::Error::other(e),
            })?;
            write_atomic(&truth_path, &truth)?;
        }
        let id = session.new_shot_id();
        session.shots.push(Shot {
            id,
            path: PathBuf::from(&name),
            focal_mm: Some(setting.focal_mm),
            f_number: Some(setting.f_number),
            ..Shot::blank()
        });
        job.report("simulating demo shots", k + 1, total);
        on_shot(&session);
    }
    session.demo_photo = Some(make_demo_photo(dir, spec, &lens, job)?);
    session.write_manifest()?;
    session.save()?;
    Ok(session)
}

/// The demo photo's file name.
pub const DEMO_PHOTO_FILE: &str = "demo_photo.png";

/// The public-domain photo the demo blurs (assets/README.md says where it comes from).
const DEMO_PHOTO_SOURCE: &[u8] = include_bytes!("../../assets/astronaut.png");

/// The demo's photo: a natural image seen through the virtual lens at the demo's middle
/// setting (one it measures, so both the profile's and the measured kernels apply),
/// on the shots' sensor, with the lens's true, spatially varying kernels. Kept when it
/// is already there (the folder's key says it was made by this spec).
fn make_demo_photo(
    dir: &Path,
    spec: &DemoSpec,
    lens: &crate::simulate::VirtualLens,
    job: &crate::job::JobContext,
) -> Result<DemoPhoto, SessionError> {
    use crate::plane::{Capture, Channel, ChannelPlane};
    let path = dir.join(DEMO_PHOTO_FILE);
    let setting = demo_photo_setting(spec);
    let photo = DemoPhoto {
        path: PathBuf::from(DEMO_PHOTO_FILE),
        focal_mm: setting.focal_mm,
        f_number: setting.f_number,
    };
    if path.is_file() {
        return Ok(photo);
    }
    job.report("blurring the demo photo", 0, 1);
    let (w, h) = (spec.width, spec.height);
    let parse = |reason: String| SessionError::Parse {
        path: path.clone(),
        reason,
    };
    let pad = photo_pad(spec, lens, setting);
    let sharp = sharp_photo(w + 2 * pad, h + 2 * pad).map_err(parse)?;
    let mut planes = Vec::with_capacity(3);
    for (sharp, channel) in sharp.iter().zip([Channel::R, Channel::G, Channel::B]) {
        job.check().map_err(|e| parse(e.to_string()))?;
        let blurred = crate::simulate::blur_varying(sharp, pad, w, h, 16, &|x, y| {
            true_photo_kernel(lens, spec, setting, channel, x, y)
        });
        planes.push(ChannelPlane {
            channel,
            plane: blurred,
            step: 1,
            offset_x: 0,
            offset_y: 0,
        });
    }
    let capture = Capture::of_planes(w, h, planes, false);
    write_rgb16_png(&path, &capture)?;
    job.report("blurring the demo photo", 1, 1);
    Ok(photo)
}

/// The demo photo's setting: the middle one of the spec's, which the demo measures.
fn demo_photo_setting(spec: &DemoSpec) -> LensSetting {
    spec.settings
        .get(spec.settings.len() / 2)
        .copied()
        .unwrap_or(LensSetting {
            focal_mm: 50.0,
            f_number: 5.6,
        })
}

/// The lens's true pixel-level kernel of `channel` at sensor point (x, y).
fn true_photo_kernel(
    lens: &crate::simulate::VirtualLens,
    spec: &DemoSpec,
    setting: LensSetting,
    channel: crate::plane::Channel,
    x: f64,
    y: f64,
) -> crate::psf::Kernel {
    let (u, v) = crate::simulate::VirtualLens::normalised(x, y, spec.width, spec.height);
    crate::deblur::plane_kernel(
        &lens
            .optical_kernel_uv(channel, u, v, setting, 3)
            .pixel_integrated(),
        1,
    )
}

/// How far the sharp frame extends past the photo: the widest kernel is in a corner,
/// and the frame's edges are blurred from real content, not from a border.
fn photo_pad(spec: &DemoSpec, lens: &crate::simulate::VirtualLens, setting: LensSetting) -> usize {
    use crate::plane::Channel;
    let (w, h) = (spec.width as f64, spec.height as f64);
    let corners = [
        (0.0, 0.0),
        (w - 1.0, 0.0),
        (0.0, h - 1.0),
        (w - 1.0, h - 1.0),
    ];
    [Channel::R, Channel::G, Channel::B]
        .iter()
        .flat_map(|&c| {
            corners.map(|(x, y)| true_photo_kernel(lens, spec, setting, c, x, y).size / 2)
        })
        .max()
        .unwrap_or(0)
        + 2
}

/// The built-in photo covering a `pw × ph` frame (scaled to fill it, centred), as
/// linear R, G and B planes: what the demo's photo is before the lens blurs it.
pub fn sharp_photo(pw: usize, ph: usize) -> Result<[crate::plane::Plane; 3], String> {
    let source = image::load_from_memory(DEMO_PHOTO_SOURCE)
        .map_err(|e| format!("the built-in photo: {e}"))?
        .into_rgb8();
    // Cover the frame (scale to fill, centre crop), as a print fills a frame.
    let scale = (pw as f64 / f64::from(source.width())).max(ph as f64 / f64::from(source.height()));
    let (sw, sh) = (
        ((f64::from(source.width()) * scale).ceil() as u32).max(pw as u32),
        ((f64::from(source.height()) * scale).ceil() as u32).max(ph as u32),
    );
    let scaled = image::imageops::resize(&source, sw, sh, image::imageops::FilterType::Lanczos3);
    let (x0, y0) = ((sw as usize - pw) / 2, (sh as usize - ph) / 2);
    // The shots are linear; the photo is sRGB-encoded: blur what the sensor sees.
    let linear = |v: u8| crate::plane::srgb_decode(f32::from(v) / 255.0);
    Ok(std::array::from_fn(|i| {
        let mut plane = crate::plane::Plane::new(pw, ph);
        for y in 0..ph {
            for x in 0..pw {
                plane.data[y * pw + x] =
                    linear(scaled.get_pixel((x0 + x) as u32, (y0 + y) as u32)[i]);
            }
        }
        plane
    }))
}

/// The demo photo as it was before the lens blurred it (linear R, G, B planes of the
/// shots' size): the truth a deblurred demo photo is measured against. It is the centre
/// of the sharp frame the blur was made from, which extends past the photo by `pad`
/// pixels a side; `pad` is found as the blurred photo was made.
///
/// # Errors
/// The built-in photo cannot be decoded.
pub fn sharp_demo_photo(spec: &DemoSpec) -> Result<[crate::plane::Plane; 3], String> {
    let (w, h) = (spec.width, spec.height);
    // The sharp frame is scaled to cover the padded frame, so its centre crop depends
    // on the pad: the same pad as the blurred photo's.
    let pad = photo_pad(
        spec,
        &crate::simulate::VirtualLens::demo(),
        demo_photo_setting(spec),
    );
    let padded = sharp_photo(w + 2 * pad, h + 2 * pad)?;
    Ok(padded.map(|p| {
        let mut out = crate::plane::Plane::new(w, h);
        for y in 0..h {
            let row = (y + pad) * p.width + pad;
            out.data[y * w..(y + 1) * w].copy_from_slice(&p.data[row..row + w]);
        }
        out
    }))
}

/// Which spec the demo files in a folder were made for.
const DEMO_KEY_FILE: &str = "demo.key";

/// Removes what a demo folder holds (and only that): its shots and their truth, the
/// session, manifest, profile, cross-validation and results.
fn clear_demo_files(dir: &Path) -> Result<(), SessionError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(source) => {
            return Err(SessionError::Read {
                path: dir.to_path_buf(),
                source,
            });
        }
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let ours = (name.starts_with("demo_")
            && (name.ends_with(".png") || name.ends_with(".truth.json")))
            || [
                SESSION_FILE,
                MANIFEST_FILE,
                PROFILE_FILE,
                CV_FILE,
                DEMO_KEY_FILE,
            ]
            .contains(&name.as_str());
        let path = entry.path();
        let removed = if ours {
            std::fs::remove_file(&path)
        } else if name == "results" && path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            Ok(())
        };
        removed.map_err(|source| SessionError::Write {
            path: path.clone(),
            source,
        })?;
    }
    Ok(())
}

/// A linear 16-bit RGB PNG of a capture's R, G, B planes (black 0, white 65535), as the
/// simulator writes its PNG shots.
fn write_rgb16_png(path: &Path, capture: &crate::plane::Capture) -> Result<(), SessionError> {
    let bytes = crate::simulate::files::rgb16_bytes(capture, crate::simulate::ShotFormat::Png)
        .map_err(|reason| SessionError::Parse {
            path: path.to_path_buf(),
            reason,
        })?;
    write_atomic(path, &bytes)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SessionError> {
    crate::io::write_atomic(path, bytes).map_err(SessionError::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stale_demo_is_made_again() {
        let dir = tempfile::tempdir().unwrap();
        let job = crate::job::JobContext::silent();
        let spec = DemoSpec::grid(160, 112, &[24.0], &[4.0]).with_chart(4, 3);
        let s = make_demo(dir.path(), &spec, &job).unwrap();
        assert_eq!(s.demo_key.as_deref(), Some(spec.key().as_str()));
        let shot = s.shot_path(0);
        let made = std::fs::metadata(&shot).unwrap().modified().unwrap();
        // Same spec: the shot is reused.
        make_demo(dir.path(), &spec, &job).unwrap();
        assert_eq!(std::fs::metadata(&shot).unwrap().modified().unwrap(), made);
        // Another spec (same file names): everything is made again, and a file that
        // is not the demo's stays.
        std::fs::write(dir.path().join("mine.txt"), b"keep").unwrap();
        std::fs::create_dir_all(dir.path().join("results")).unwrap();
        let other = DemoSpec::grid(200, 140, &[24.0], &[4.0]).with_chart(4, 3);
        let s2 = make_demo(dir.path(), &other, &job).unwrap();
        let cap = crate::raw::load_capture(&s2.shot_path(0), &Default::default()).unwrap();
        assert_eq!((cap.width, cap.height), (200, 140));
        assert!(!dir.path().join("results").exists());
        assert!(dir.path().join("mine.txt").is_file());
        let reopened = Session::open(dir.path()).unwrap();
        assert_eq!(reopened.demo_key.as_deref(), Some(other.key().as_str()));
    }
}
