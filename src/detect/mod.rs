//! Stage 3: find the chart's squares in a shot and align each to sub-pixel accuracy
//! (Kee et al. 2011, §2.2; ARCHITECTURE.md, `detect`).
//!
//! Detection runs on the full-resolution grey image: X-junctions of the checkerboard
//! (Hessian saddles that pass a four-sector ring test) are grown into a lattice whose
//! chart column/row follow from the board's visible edges and the square colours, at
//! any rotation in the shot (the spec describes the print: of the quarter turns the
//! spec and the colours allow, the one that turns the print least). A lattice grows
//! only through steps between two squares of one colour each, alternating as a
//! chessboard's, so it stops at the board's edge whatever texture lies beyond; lattices
//! larger than the chart (a second chessboard beside it) are set aside. Every square of
//! the chart is then predicted, bootstrapped from its four localised corners by a
//! normalised DLT, and refined by registering the exactly rasterised, Gaussian-blurred
//! chart to the observed pixels ([`align`]; the outer corner of a white corner square,
//! which no edge of the print places, is held where the lattice puts it). Squares that
//! cannot be used are reported as skipped with a reason, never dropped.

pub mod align;
pub mod filter;
pub mod grid;
pub mod inspect;
pub mod lateral;

use crate::chart::ChartSpec;
use crate::geometry::Homography;
use crate::job::{Cancelled, JobContext};
use crate::plane::Capture;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Thresholds and iteration limits of detection and alignment.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectParams {
    /// Gaussian σ (px) of the smoothing before the saddle detector.
    pub smoothing_sigma_px: f64,
    /// Radius (px) of the ring on which an X-junction must show four sectors.
    pub ring_radius_px: f64,
    /// Minimum saddle response relative to the strongest junctions.
    pub min_relative_response: f64,
    /// Pixels of context around each square in the registration, px.
    pub margin_px: f64,
    /// Starting guess of the blur σ beyond the pixel area, px.
    pub initial_sigma_px: f64,
    /// Coarse-to-fine levels (1 = fine only); level ℓ > 0 smooths both images by
    /// `coarse_sigma_px · 2^(ℓ−1)` and subsamples.
    pub levels: usize,
    pub coarse_sigma_px: f64,
    /// Gauss–Newton iterations per level.
    pub max_iterations: usize,
    /// Stop when no corner moves by more than this, px.
    pub tolerance_px: f64,
    /// Refinement that moves a corner further than this from its bootstrap is rejected, px.
    pub max_refine_shift_px: f64,
    /// Values at or above this (normalised units) count as clipped: they weigh
    /// nothing in the registration.
    pub saturation_level: f64,
    /// A square with more than this fraction of the pixels along its edges clipped is
    /// skipped (its blur is no longer measured there).
    pub max_clipped_edge_fraction: f64,
    /// Centre each colour channel's kernels on that square's own registration of the
    /// channel, however noisy. Off by default: on a lens without lateral colour one
    /// square's registration of a RAW shot's quarter-resolution red and blue planes
    /// costs the kernels' σ accuracy (p95 6.8 % against 6 % on the Bayer kernel bars).
    /// Without it, the kernels follow each channel's shift field over the shot where
    /// that is measured above its noise ([`lateral`]).
    pub channel_shifts: bool,
    /// A square whose white − black peak difference is below this is skipped.
    pub min_contrast: f64,
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            smoothing_sigma_px: 1.5,
            ring_radius_px: 4.0,
            min_relative_response: 0.05,
            margin_px: 6.0,
            initial_sigma_px: 1.0,
            levels: 2,
            coarse_sigma_px: 1.5,
            max_iterations: 30,
            tolerance_px: 1e-3,
            max_refine_shift_px: 3.0,
            saturation_level: crate::plane::CLIPPED_FROM,
            max_clipped_edge_fraction: 0.5,
            channel_shifts: false,
            min_contrast: 0.05,
        }
    }
}

/// Whether a square was aligned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SquareStatus {
    Ok,
    Skipped,
}

/// One chart square in the shot.
#[derive(Clone, Debug)]
pub struct SquareAlignment {
    pub row: usize,
    pub col: usize,
    pub status: SquareStatus,
    pub reason: Option<String>,
    /// Refined corners, sensor px, chart order TL TR BR BL.
    pub corners: [[f64; 2]; 4],
    pub bootstrap_corners: [[f64; 2]; 4],
    /// Refined `image_from_chart`.
    pub image_from_chart: Homography,
    pub bootstrap: Homography,
    /// RMS of observed − synthetic over the square after alignment (normalised units).
    pub residual_rms: f64,
    /// Histogram peaks of the observed square, normalised units.
    pub black_level: f64,
    pub white_level: f64,
    /// Estimated Gaussian blur σ beyond the pixel area (mean over planes), px.
    pub sigma_px: f64,
    /// The same per colour channel; empty for a square that was not aligned.
    pub sigma_by_channel: Vec<(crate::plane::Channel, f64)>,
    /// Each colour channel's own refined `image_from_chart` (see
    /// [`align::Aligned::channel_image_from_chart`]); empty for one channel or a square
    /// that was not aligned, where every channel's is `image_from_chart`.
    pub channel_image_from_chart: Vec<(crate::plane::Channel, Homography)>,
    /// Every colour channel's own registration, whether or not the kernels use it
    /// ([`align::Aligned::channel_registration`]); empty for one channel.
    pub channel_registration: Vec<(crate::plane::Channel, Homography)>,
    /// Each colour channel's fitted [black, white] level, normalised units; empty for
    /// a square that was not aligned.
    pub levels_by_channel: Vec<(crate::plane::Channel, [f64; 2])>,
}

impl SquareAlignment {
    /// The refined `image_from_chart` of colour channel `ch`.
    #[must_use]
    pub fn image_from_chart_of(&self, ch: crate::plane::Channel) -> Homography {
        self.channel_image_from_chart
            .iter()
            .find(|(c, _)| *c == ch)
            .map_or(self.image_from_chart, |(_, h)| *h)
    }
}

/// Every square of the chart, found or skipped, and the global chart pose.
#[derive(Clone, Debug)]
pub struct Detection {
    pub width: usize,
    pub height: usize,
    pub squares: Vec<SquareAlignment>,
    pub global: Homography,
}

#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    #[error("no chart found")]
    NoChart,
    #[error(
        "the chart in the shot has more squares than the chart spec's {spec_cols} × {spec_rows}{}: the spec does not match the printed chart (give the spec of the chart that was printed)",
        found_squares(*cols, *rows, *spec_cols, *spec_rows)
    )]
    ChartTooLarge {
        cols: usize,
        rows: usize,
        spec_cols: usize,
        spec_rows: usize,
    },
    #[error("cancelled")]
    Cancelled(#[from] Cancelled),
}

/// The squares a lattice larger than the spec spans, where the count is one a chart
/// could have: within twice the spec each way. Past that the lattice ran over other
/// patterns in the scene (a 10 × 7 spec on a 24 × 16 chart spans "59 × 109"), and a
/// count would mislead.
fn found_squares(cols: usize, rows: usize, spec_cols: usize, spec_rows: usize) -> String {
    let (big, small) = (cols.max(rows), cols.min(rows));
    let (spec_big, spec_small) = (spec_cols.max(spec_rows), spec_cols.min(spec_rows));
    if big <= 2 * spec_big && small <= 2 * spec_small {
        format!(" (at least {cols} × {rows} found)")
    } else {
        String::new()
    }
}

/// Finds and aligns every square of `spec` in `capture`.
///
/// # Errors
/// [`DetectError::NoChart`] when no checkerboard is found; `Cancelled` when the job is.
pub fn detect(
    capture: &Capture,
    spec: &ChartSpec,
    params: &DetectParams,
    job: &JobContext,
) -> Result<Detection, DetectError> {
    job.check()?;
    let grey = capture.grey();
    let smoothed = grid::Smoothed::new(&grey, params.smoothing_sigma_px);
    let junctions = grid::find_junctions(
        &smoothed,
        params.ring_radius_px,
        params.min_relative_response,
    );
    job.check()?;
    let lattice = grid::build_lattice(&junctions, &smoothed, spec).map_err(|e| match e {
        grid::LatticeError::NotFound => DetectError::NoChart,
        grid::LatticeError::TooLarge { cols, rows } => DetectError::ChartTooLarge {
            cols,
            rows,
            spec_cols: spec.cols,
            spec_rows: spec.rows,
        },
    })?;
    let mut cells: Vec<(usize, usize)> = Vec::with_capacity(spec.rows * spec.cols);
    for row in 0..spec.rows {
        for col in 0..spec.cols {
            cells.push((row, col));
        }
    }
    let total = cells.len();
    let done = std::sync::atomic::AtomicUsize::new(0);
    job.report("detect", 0, total);
    let squares: Result<Vec<SquareAlignment>, Cancelled> = cells
        .par_iter()
        .map(|&(row, col)| {
            job.check()?;
            let sq = square(capture, spec, &lattice, row, col, params);
            let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            job.report("detect", d, total);
            Ok(sq)
        })
        .collect();
    let mut squares = squares?;
    if squares.iter().all(|s| s.status == SquareStatus::Skipped) && lattice.corners.len() < 4 {
        return Err(DetectError::NoChart);
    }
    if !params.channel_shifts {
        lateral::register_where_measured(&mut squares, spec, capture.width, capture.height);
    }
    Ok(Detection {
        width: capture.width,
        height: capture.height,
        squares,
        global: lattice.image_from_chart,
    })
}

/// Whether a square was set aside because its edges are clipped.
#[must_use]
pub fn is_clipped(square: &SquareAlignment) -> bool {
    square
        .reason
        .as_deref()
        .is_some_and(|r| r.starts_with("saturated"))
}

/// When clipping cost a shot most of its squares in frame, what to do about it, in
/// words: how many were lost and how much darker to expose. A square goes when more
/// than half the pixels along its edges are clipped, that is when the middle of its
/// edges, halfway from black (b) to white (w), is at or above the top of the range (c):
/// then w ≥ 2c − b, and only an exposure (2c − b)/c times lower brings it below c.
#[must_use]
pub fn clipping_advice(det: &Detection, params: &DetectParams) -> Option<String> {
    let in_frame = det
        .squares
        .iter()
        .filter(|s| s.reason.as_deref() != Some("partly out of frame"))
        .count();
    let clipped = det.squares.iter().filter(|s| is_clipped(s)).count();
    if clipped == 0 || 2 * clipped <= in_frame {
        return None;
    }
    let mut blacks: Vec<f64> = det
        .ok_squares()
        .map(|s| s.black_level)
        .filter(|b| b.is_finite())
        .collect();
    blacks.sort_by(f64::total_cmp);
    let black = blacks
        .get(blacks.len() / 2)
        .copied()
        .unwrap_or(0.0)
        .max(0.0);
    let c = params.saturation_level;
    let stops = ((2.0 * c - black) / c).log2();
    // In thirds of a stop, as cameras step their exposure, rounded up.
    let thirds = (stops * 3.0 - 1e-9).ceil().max(1.0);
    let darker = if thirds % 3.0 == 0.0 {
        format!("{}", thirds / 3.0)
    } else {
        format!("{:.1}", thirds / 3.0)
    };
    Some(format!(
        "{clipped} of the {in_frame} squares in frame are set aside because their whites are clipped: expose at least {darker} stop{} darker",
        if thirds > 3.0 { "s" } else { "" }
    ))
}

/// Bootstrap position of chart corner (c, r): its junction when found (then `true`),
/// else a local homography over nearby junctions, else the global one. The board's
/// own outer corners have only a 2 × 2 block of junctions within two steps, so the
/// neighbourhood widens to three: under lens distortion the global homography is off
/// by a good fraction of a square there, exactly where the blur is worst, and the local
/// one, extrapolated a step, still misses the bend by most of a pixel, so a quadratic
/// through its residuals adds it (the outer corner of a white corner square is held
/// at this estimate).
fn corner_estimate(lattice: &grid::Lattice, c: usize, r: usize) -> ([f64; 2], bool) {
    if let Some(p) = lattice.corners.get(&(c, r)) {
        return (*p, true);
    }
    let (ci, ri) = (c as i64, r as i64);
    for reach in [2i64, 3] {
        let mut from = Vec::new();
        let mut to = Vec::new();
        for dr in -reach..=reach {
            for dc in -reach..=reach {
                let (cc, rr) = (ci + dc, ri + dr);
                if cc < 0 || rr < 0 {
                    continue;
                }
                if let Some(p) = lattice.corners.get(&(cc as usize, rr as usize)) {
                    from.push([cc as f64, rr as f64]);
                    to.push(*p);
                }
            }
        }
        if from.len() >= 6
            && let Some(h) = Homography::from_correspondences(&from, &to)
        {
            let p = h.apply([c as f64, r as f64]);
            // A board corner lies a step outside its block of junctions: a homography
            // has no curvature, and the lens's bends it by most of a pixel there.
            if reach == 3
                && let Some(d) = quadratic_residual_at(&h, &from, &to, [c as f64, r as f64])
            {
                return ([p[0] + d[0], p[1] + d[1]], false);
            }
            return (p, false);
        }
    }
    (lattice.image_from_chart.apply([c as f64, r as f64]), false)
}

/// The least-squares quadratic in chart (c, r) through the junctions' residuals from
/// `h`, evaluated at `at`: the lens's bend that a homography over the block leaves out.
/// None when the block cannot fix the six terms.
fn quadratic_residual_at(
    h: &Homography,
    from: &[[f64; 2]],
    to: &[[f64; 2]],
    at: [f64; 2],
) -> Option<[f64; 2]> {
    if from.len() < 9 {
        return None;
    }
    let terms = |q: [f64; 2]| {
        let (u, v) = (q[0] - at[0], q[1] - at[1]);
        [1.0, u, v, u * u, u * v, v * v]
    };
    let mut ata = nalgebra::Matrix6::<f64>::zeros();
    let mut atb = nalgebra::Matrix6x2::<f64>::zeros();
    for (f, t) in from.iter().zip(to) {
        let p = h.apply(*f);
        let row = nalgebra::Vector6::from(terms(*f));
        ata += row * row.transpose();
        atb.column_mut(0).axpy(t[0] - p[0], &row, 1.0);
        atb.column_mut(1).axpy(t[1] - p[1], &row, 1.0);
    }
    let x = ata.cholesky()?.solve(&atb);
    // With the terms centred on `at`, the constant is the value there.
    Some([x[(0, 0)], x[(0, 1)]])
}

fn square(
    capture: &Capture,
    spec: &ChartSpec,
    lattice: &grid::Lattice,
    row: usize,
    col: usize,
    params: &DetectParams,
) -> SquareAlignment {
    let chart = spec.square_corners(col, row);
    let estimates = [
        corner_estimate(lattice, col, row),
        corner_estimate(lattice, col + 1, row),
        corner_estimate(lattice, col + 1, row + 1),
        corner_estimate(lattice, col, row + 1),
    ];
    let boot: [[f64; 2]; 4] = estimates.map(|e| e.0);
    // Corners localised at their junctions are within a few hundredths of a pixel: the
    // fine level starts inside its basin, and a coarse level (whose extra blur biases
    // the blur estimate it hands on) only costs time. Predicted corners need it.
    let levels = if estimates.iter().all(|e| e.1) {
        1
    } else {
        params.levels
    };
    let bootstrap =
        Homography::from_correspondences(&chart, &boot).unwrap_or(lattice.image_from_chart);
    let skipped = SquareAlignment {
        row,
        col,
        status: SquareStatus::Skipped,
        reason: None,
        corners: boot,
        bootstrap_corners: boot,
        image_from_chart: bootstrap,
        bootstrap,
        residual_rms: f64::NAN,
        black_level: f64::NAN,
        white_level: f64::NAN,
        sigma_px: f64::NAN,
        sigma_by_channel: Vec::new(),
        channel_image_from_chart: Vec::new(),
        channel_registration: Vec::new(),
        levels_by_channel: Vec::new(),
    };
    match align::align_square(capture, spec, col, row, &bootstrap, levels, params) {
        Ok(a) => SquareAlignment {
            status: SquareStatus::Ok,
            corners: chart.map(|p| a.image_from_chart.apply(p)),
            image_from_chart: a.image_from_chart,
            residual_rms: a.residual_rms,
            black_level: a.black_level,
            white_level: a.white_level,
            sigma_px: a.sigma_px,
            sigma_by_channel: a.sigma_by_channel,
            channel_image_from_chart: a.channel_image_from_chart,
            channel_registration: a.channel_registration,
            levels_by_channel: a.levels_by_channel,
            ..skipped
        },
        Err(reason) => SquareAlignment {
            reason: Some(reason),
            ..skipped
        },
    }
}

/// `detect.json` (its format is in docs/formats.md).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DetectFile {
    pub schema: String,
    pub width: usize,
    pub height: usize,
    /// The shot it was detected on, where the pipeline wrote it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<crate::shot_file::ShotRecord>,
    pub squares: Vec<SquareRecord>,
}

/// One square in `detect.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SquareRecord {
    pub row: usize,
    pub col: usize,
    pub status: SquareStatus,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    pub corners: [[f64; 2]; 4],
    pub bootstrap_corners: [[f64; 2]; 4],
    /// `image_from_chart`, 9 numbers row-major.
    pub homography: Homography,
    /// `null` for a skipped square.
    pub residual_rms: Option<f64>,
    /// Each colour channel's own `image_from_chart` where detection refined them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub channel_homographies: Vec<(crate::plane::Channel, Homography)>,
    /// Each colour channel's own registration, made whether or not the kernels use it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub channel_registration: Vec<(crate::plane::Channel, Homography)>,
    /// Each colour channel's fitted [black, white] level.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub levels: Vec<(crate::plane::Channel, [f64; 2])>,
}

/// The detection file's version.
pub const DETECT: crate::format::Schema = crate::format::Schema {
    kind: "detect",
    current: 1,
    unversioned: None,
};

impl DetectFile {
    /// Parses and checks a detection file's text.
    ///
    /// # Errors
    /// The reason it is not a usable detection file.
    pub fn from_json(text: &str) -> Result<Self, String> {
        DETECT.version_of_json(text).map_err(|e| e.to_string())?;
        let f: DetectFile =
            serde_json::from_str(text).map_err(|e| format!("not a detection file: {e}"))?;
        crate::limits::check_image_size(f.width, f.height)?;
        let corners_finite = f.squares.iter().all(|q| {
            q.corners
                .iter()
                .chain(&q.bootstrap_corners)
                .flatten()
                .all(|v| v.is_finite())
        });
        if !corners_finite {
            return Err("a square's corners are not finite numbers".into());
        }
        Ok(f)
    }
}

/// The mean over channels of level `which` (0 black, 1 white); NaN for none.
fn mean_level(levels: &[(crate::plane::Channel, [f64; 2])], which: usize) -> f64 {
    if levels.is_empty() {
        return f64::NAN;
    }
    levels.iter().map(|(_, l)| l[which]).sum::<f64>() / levels.len() as f64
}

impl Detection {
    /// The file form.
    #[must_use]
    pub fn to_file(&self) -> DetectFile {
        DetectFile {
            schema: DETECT.tag(),
            width: self.width,
            height: self.height,
            source: None,
            squares: self
                .squares
                .iter()
                .map(|s| SquareRecord {
                    row: s.row,
                    col: s.col,
                    status: s.status,
                    reason: s.reason.clone(),
                    corners: s.corners,
                    bootstrap_corners: s.bootstrap_corners,
                    homography: s.image_from_chart,
                    residual_rms: s.residual_rms.is_finite().then_some(s.residual_rms),
                    channel_homographies: s.channel_image_from_chart.clone(),
                    channel_registration: s.channel_registration.clone(),
                    levels: s.levels_by_channel.clone(),
                })
                .collect(),
        }
    }

    /// Back from the file form (what the studio reads when it reopens a session). The
    /// blur estimate is not in the file and comes back as NaN; so do the mean levels
    /// of a file without per-channel levels.
    #[must_use]
    pub fn from_file(file: &DetectFile) -> Self {
        let squares: Vec<SquareAlignment> = file
            .squares
            .iter()
            .map(|r| SquareAlignment {
                row: r.row,
                col: r.col,
                status: r.status,
                reason: r.reason.clone(),
                corners: r.corners,
                bootstrap_corners: r.bootstrap_corners,
                image_from_chart: r.homography,
                bootstrap: r.homography,
                residual_rms: r.residual_rms.unwrap_or(f64::NAN),
                black_level: mean_level(&r.levels, 0),
                white_level: mean_level(&r.levels, 1),
                sigma_px: f64::NAN,
                sigma_by_channel: Vec::new(),
                channel_image_from_chart: r.channel_homographies.clone(),
                channel_registration: r.channel_registration.clone(),
                levels_by_channel: r.levels.clone(),
            })
            .collect();
        let global = squares
            .iter()
            .find(|s| s.status == SquareStatus::Ok)
            .map_or(Homography::identity(), |s| s.image_from_chart);
        Self {
            width: file.width,
            height: file.height,
            squares,
            global,
        }
    }

    /// Squares that were aligned.
    pub fn ok_squares(&self) -> impl Iterator<Item = &SquareAlignment> {
        self.squares.iter().filter(|s| s.status == SquareStatus::Ok)
    }
}
