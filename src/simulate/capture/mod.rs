//! The capture simulator: the chart under a camera pose, blurred by the lens's spatially
//! varying optical PSF, integrated over each pixel's area, mosaicked, made noisy and
//! quantised like a 14-bit RAW file — with the exact ground truth of every square.
//!
//! How the PSF varies: the sensor is covered by a grid of PSF centres `tile_px` apart.
//! The image blurred with the PSF of each centre is computed on that centre's
//! neighbourhood, and the results are blended with bilinear partition-of-unity
//! weights. The PSF applied at a pixel is therefore exactly the weighted mixture of
//! the (up to) four neighbouring centres' PSFs; the truth reports that mixture's second
//! moments (the blended covariance), not the lens field at the point.
//!
//! How a neighbourhood is rendered: the chart is rasterised exactly (area coverage) at
//! `oversample`× onto the neighbourhood plus a margin of the PSF radius, transformed by
//! FFT, multiplied by the PSF's transfer function (analytic for a Gaussian), multiplied
//! by the transfer function of the s × s sub-pixel average, and decimated by folding
//! the spectrum, so only a pixel-resolution inverse FFT is needed. The sub-cell box of
//! the exact rasteriser (variance 1/(12 s²)) and the s-point average (1/12 − 1/(12 s²))
//! together add exactly the pixel box's 1/12 px², so the second moments of the
//! pixel-level PSF are those of the optical PSF plus 1/12 px² per axis.
//!
//! Under a lens that bends the image (distortion, lateral colour), the chart is
//! rasterised in small blocks, each under the homography that follows the bent mapping
//! to [`BLOCK_MAPPING_TOLERANCE_PX`] over it, once for the whole frame per distinct
//! mapping (strip by strip), and each neighbourhood is cut from that raster.

use super::distortion::{LensGeometry, SensorMapping};
use super::lens::{PsfShape, VirtualLens};
use crate::chart::{ChartSpec, rasterize};
use crate::fft::{Fft2, good_size};
use crate::geometry::Homography;
use crate::job::{Cancelled, JobContext};
use crate::plane::{CameraIdentity, Capture, Channel, ChannelPlane, LensSetting, Plane};
use crate::psf::{Gaussian2, Kernel};
use nalgebra::Matrix3;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, Poisson};
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeSet, HashMap};

mod bent;
pub use bent::{BLOCK_MAPPING_TOLERANCE_PX, block_homography};
use bent::{BentStrips, block_px};

/// Where the chart sits in the frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// In-plane rotation, degrees (clockwise on screen, since y points down).
    pub rotation_deg: f64,
    /// Mild perspective: relative scale change from the frame centre to its right
    /// (tilt_x) or bottom (tilt_y) edge, e.g. 0.03.
    pub tilt_x: f64,
    pub tilt_y: f64,
    /// Fraction of the frame width the checkerboard (without margin) spans.
    pub fill: f64,
    /// Offset of the chart centre from the frame centre, pixels.
    pub shift_px: [f64; 2],
}

impl Default for Pose {
    fn default() -> Self {
        Self {
            rotation_deg: 0.0,
            tilt_x: 0.0,
            tilt_y: 0.0,
            fill: 0.9,
            shift_px: [0.0, 0.0],
        }
    }
}

impl Pose {
    /// The homography from chart units to sensor pixels for a `width × height` frame.
    #[must_use]
    pub fn image_from_chart(&self, spec: &ChartSpec, width: usize, height: usize) -> Homography {
        let px_per_square = self.fill * width as f64 / spec.cols as f64;
        let centre_from_chart = Homography::scaling(px_per_square, px_per_square).compose(
            &Homography::translation(-(spec.cols as f64) / 2.0, -(spec.rows as f64) / 2.0),
        );
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        let rotation = Homography(Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0));
        let half_w = (width as f64 / 2.0).max(1.0);
        // w = 1 + tilt at the right/bottom edge: points there shrink by 1/(1 + tilt).
        let perspective = Homography(Matrix3::new(
            1.0,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
            self.tilt_x / half_w,
            self.tilt_y / half_w,
            1.0,
        ));
        let frame_centre = Homography::translation(
            (width as f64 - 1.0) / 2.0 + self.shift_px[0],
            (height as f64 - 1.0) / 2.0 + self.shift_px[1],
        );
        frame_centre
            .compose(&perspective)
            .compose(&rotation)
            .compose(&centre_from_chart)
    }
}

/// Poisson–Gaussian sensor noise in electrons.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoiseModel {
    /// Electrons at the white level; 0 or non-finite turns shot noise off.
    pub full_well_e: f64,
    /// Standard deviation of the read noise in electrons.
    pub read_noise_e: f64,
}

impl NoiseModel {
    /// No noise (quantisation remains).
    #[must_use]
    pub fn none() -> Self {
        Self {
            full_well_e: 0.0,
            read_noise_e: 0.0,
        }
    }

    /// A typical full-frame sensor at base ISO.
    #[must_use]
    pub fn typical() -> Self {
        Self {
            full_well_e: 30000.0,
            read_noise_e: 3.0,
        }
    }
}

impl Default for NoiseModel {
    fn default() -> Self {
        Self::typical()
    }
}

/// Everything about one simulated exposure.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureParams {
    pub width: usize,
    pub height: usize,
    pub setting: LensSetting,
    pub pose: Pose,
    pub noise: NoiseModel,
    /// RGGB mosaic (true) or three full planes (false).
    pub bayer: bool,
    /// White paper level in the green channel, as a fraction of the range.
    pub exposure: f64,
    pub black_level: u16,
    /// 14-bit: 16383.
    pub white_level: u16,
    /// Value (white = 1) of the scene outside the paper.
    pub paper_background: f32,
    pub seed: u64,
    /// Sub-pixels per pixel side when rendering the chart.
    pub oversample: usize,
    /// Spacing of the PSF centres, pixels.
    pub tile_px: usize,
    /// Gains of R, G, B relative to `exposure` (a camera's white balance).
    pub channel_gains: [f64; 3],
    /// Light that is not even: the illumination falls by this many stops per half
    /// diagonal along x and along y (0, 0: even light, as a chart should be lit).
    pub light_gradient_stops: [f64; 2],
}

/// The crop factor of the simulated camera (an APS-C sensor, whatever its pixel
/// count): what its EXIF's 35 mm focal length says.
pub const SIM_CROP_FACTOR: f64 = 1.5;

impl CaptureParams {
    /// A noiseless-free default shot of the given size and setting.
    #[must_use]
    pub fn new(width: usize, height: usize, setting: LensSetting) -> Self {
        Self {
            width,
            height,
            setting,
            pose: Pose::default(),
            noise: NoiseModel::typical(),
            bayer: true,
            exposure: 0.7,
            black_level: 512,
            white_level: 16383,
            paper_background: 0.35,
            seed: 1,
            oversample: 4,
            tile_px: 32,
            channel_gains: [0.82, 1.0, 0.74],
            light_gradient_stops: [0.0, 0.0],
        }
    }
}

/// The truth of one chart square.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SquareTruth {
    pub row: usize,
    pub col: usize,
    /// Top-left, top-right, bottom-right, bottom-left, sensor pixels.
    pub corners: [[f64; 2]; 4],
    pub centre: [f64; 2],
    pub fully_visible: bool,
    /// Optical PSF (before pixel integration) applied at the centre: its second moments.
    pub optical: Vec<(Channel, Gaussian2)>,
    /// Pixel-level PSF (optical ∗ pixel box) at the centre: its second moments.
    pub pixel: Vec<(Channel, Gaussian2)>,
    /// For non-Gaussian shapes: the true pixel-level kernel at 3×.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pixel_kernels: Vec<(Channel, Kernel)>,
    /// Where the lens bends the image (distortion, lateral colour): each colour
    /// channel's own corners and centre; `corners` and `centre` are green's. Empty for
    /// an ideal lens, where every channel's are `corners` and `centre`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub channels: Vec<ChannelPosition>,
}

/// One colour channel's image of a square, sensor px.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelPosition {
    pub channel: Channel,
    /// Top-left, top-right, bottom-right, bottom-left.
    pub corners: [[f64; 2]; 4],
    pub centre: [f64; 2],
}

impl SquareTruth {
    #[must_use]
    pub fn pixel_of(&self, ch: Channel) -> Option<Gaussian2> {
        self.pixel.iter().find(|(c, _)| *c == ch).map(|(_, g)| *g)
    }

    /// The corners of `ch`'s image of the square (green's for Y, or for a lens that
    /// does not bend the image).
    #[must_use]
    pub fn corners_of(&self, ch: Channel) -> [[f64; 2]; 4] {
        self.position_of(ch).map_or(self.corners, |p| p.corners)
    }

    /// The centre of `ch`'s image of the square, as [`Self::corners_of`].
    #[must_use]
    pub fn centre_of(&self, ch: Channel) -> [f64; 2] {
        self.position_of(ch).map_or(self.centre, |p| p.centre)
    }

    fn position_of(&self, ch: Channel) -> Option<&ChannelPosition> {
        self.channels.iter().find(|p| p.channel == ch)
    }
}

/// The truth of a shot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShotTruth {
    pub width: usize,
    pub height: usize,
    pub setting: LensSetting,
    pub image_from_chart: Homography,
    pub squares: Vec<SquareTruth>,
    /// The optical PSF actually applied anywhere on the sensor.
    pub psf_field: PsfField,
    /// The lens's distortion, lateral colour and vignetting: `image_from_chart` is the
    /// ideal (pinhole) mapping this bends.
    #[serde(default, skip_serializing_if = "LensGeometry::is_none")]
    pub geometry: LensGeometry,
}

/// The PSF centres of a shot and their optical covariances: the PSF applied at a pixel
/// is the bilinear blend of its four neighbouring centres' PSFs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PsfField {
    pub tile_px: usize,
    /// Centre positions along x and y, pixels.
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// Per channel (R, G, B), per centre (row-major over ys × xs): optical
    /// (var_x, var_y, cov_xy) in px².
    pub cov: Vec<(Channel, Vec<[f64; 3]>)>,
}

impl PsfField {
    /// Second moments of the optical PSF applied at sensor (x, y) (blended covariance).
    #[must_use]
    pub fn optical_at(&self, ch: Channel, x: f64, y: f64) -> Option<Gaussian2> {
        let ch = if ch == Channel::Y { Channel::G } else { ch };
        let (_, covs) = self.cov.iter().find(|(c, _)| *c == ch)?;
        let tile = self.tile_px as f64;
        let mut acc = [0.0; 3];
        for (j, wy) in hat_weights(&self.ys, tile, y) {
            for (i, wx) in hat_weights(&self.xs, tile, x) {
                let c = covs.get(j * self.xs.len() + i)?;
                for k in 0..3 {
                    acc[k] += wx * wy * c[k];
                }
            }
        }
        Some(Gaussian2::from_covariance(acc[0], acc[1], acc[2]))
    }
}

/// A simulated shot: the capture as the loader would return it, the raw values, and the
/// truth.
#[derive(Clone, Debug)]
pub struct SimulatedShot {
    pub capture: Capture,
    /// `width × height` CFA values for a Bayer shot; `width × height × 3` interleaved RGB
    /// otherwise. Black level included.
    pub cfa: Vec<u16>,
    pub truth: ShotTruth,
    /// The noiseless, unquantised blurred image per channel (R, G, B), white paper = 1.
    pub clean: Vec<(Channel, Plane)>,
    /// Raw value of zero light and of saturation, as in `cfa`.
    pub black_level: u16,
    pub white_level: u16,
    /// The lens's EXIF LensSpecification (focal range, widest aperture at each end).
    pub lens_specification: [f64; 4],
}

#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    #[error("invalid capture parameters: {0}")]
    Invalid(String),
    #[error("cancelled")]
    Cancelled(#[from] Cancelled),
}

const CHANNELS: [Channel; 3] = [Channel::R, Channel::G, Channel::B];

/// The PSF centre grid and each centre's PSFs.
struct PsfCentre {
    x: f64,
    /// Per channel: covariance (var_x, var_y, cov) of the optical PSF in px², and the
    /// transfer function source.
    psfs: [CentrePsf; 3],
}

struct CentrePsf {
    cov: [f64; 3],
    /// How far the PSF reaches, px: a non-Gaussian shape's kernel grid's half-width
    /// and one standard deviation more; 4σ for a Gaussian.
    radius_px: f64,
}

fn centre_grid(n_px: usize, tile_px: usize) -> Vec<f64> {
    let last = n_px.saturating_sub(1) as f64;
    let n = ((last / tile_px as f64).ceil() as usize).max(1);
    (0..=n).map(|i| (i * tile_px) as f64).collect()
}

/// Bilinear partition-of-unity weights of the grid nodes around `p`: (index, weight).
fn hat_weights(grid: &[f64], tile: f64, p: f64) -> [(usize, f64); 2] {
    let t = (p / tile).clamp(0.0, (grid.len() - 1) as f64);
    let i = (t.floor() as usize).min(grid.len().saturating_sub(2));
    let f = t - i as f64;
    if grid.len() == 1 {
        return [(0, 1.0), (0, 0.0)];
    }
    [(i, 1.0 - f), (i + 1, f)]
}

/// Frequency (cycles per sample) of DFT bin k of length n.
#[inline]
fn freq(k: usize, n: usize) -> f64 {
    if k <= n / 2 {
        k as f64 / n as f64
    } else {
        k as f64 / n as f64 - 1.0
    }
}

/// Simulates one shot.
///
/// # Errors
/// Parameters out of range, or the job was cancelled.
pub fn simulate_shot(
    spec: &ChartSpec,
    lens: &VirtualLens,
    params: &CaptureParams,
    job: &JobContext,
) -> Result<SimulatedShot, SimulateError> {
    check_params(lens, params)?;
    let (w, h) = (params.width, params.height);
    let s = params.oversample;
    let tile = params.tile_px;
    let image_from_chart = params.pose.image_from_chart(spec, w, h);
    let maps = channel_mappings(lens, params);
    let xs = centre_grid(w, tile);
    let ys = centre_grid(h, tile);

    // The PSFs of every centre; a non-Gaussian lens's kernels are the costly part of a
    // shot, and independent. Only their moments and reach are kept here: every centre's
    // oversampled kernel held at once is gigabytes at 2400 × 1600 (about 3 GB for the
    // aberrated lens), so each is made again where its window is rendered.
    let grid: Vec<(f64, f64)> = ys
        .iter()
        .flat_map(|&cy| xs.iter().map(move |&cx| (cx, cy)))
        .collect();
    let centres = psf_centres(lens, params, &grid);
    let margin = window_margin(&centres);
    let m = good_size(2 * tile + 1 + 2 * margin);
    let n = m * s;
    let chart_from_ideal = match &maps {
        Some(_) => image_from_chart
            .inverse()
            .ok_or_else(|| SimulateError::Invalid("degenerate chart pose".into()))?,
        None => Homography::identity(),
    };
    let bent = maps
        .as_ref()
        .map(|maps| distinct_mappings(maps, (tile + margin) as f64 + 1.0, w, h, s));
    // The oversampled window's transform and the pixel-resolution inverse; each worker
    // clones its own (the plans are shared, the scratch is not).
    let window_fft = Fft2::<f32>::new(n, n);
    let pixel_fft = Fft2::<f32>::new(m, m);
    let sf = s as f64;

    let box_tf = box_transfer(n, s);

    let mut strips = bent.as_ref().map(|(distinct, _, block)| BentStrips {
        spec,
        chart_from_ideal: &chart_from_ideal,
        maps: distinct,
        block: *block,
        background: params.paper_background,
        s,
        origin: [-((tile + margin) as i64); 2],
        tile,
        width_sub: ((xs.len() - 1) * tile + m) * s,
        first: 0,
        held: std::collections::VecDeque::new(),
    });
    let mut out: Vec<Plane> = (0..3).map(|_| Plane::new(w, h)).collect();
    let total_rows = ys.len();
    for (jy, &cy) in ys.iter().enumerate() {
        job.check()?;
        job.report("simulate", jy, total_rows);
        let row_y0 = cy as i64 - tile as i64 - margin as i64;
        if let Some(strips) = strips.as_mut() {
            strips.reach_row(row_y0, n);
        }
        let strips = strips.as_ref();
        let row: Vec<(usize, [Vec<f32>; 3], i64, i64)> = (0..xs.len())
            .into_par_iter()
            .map_init(
                || (window_fft.clone(), pixel_fft.clone()),
                |(window_fft, pixel_fft), ix| {
                    let c = &centres[jy * xs.len() + ix];
                    let cx = c.x;
                    let x0 = cx as i64 - tile as i64 - margin as i64;
                    let y0 = cy as i64 - tile as i64 - margin as i64;
                    let sub_from_sensor = sub_from_sensor(x0, y0, s);
                    let sharps: Vec<Plane> = match strips {
                        None => vec![rasterize(
                            spec,
                            &sub_from_sensor.compose(&image_from_chart),
                            n,
                            n,
                            params.paper_background,
                        )],
                        Some(strips) => strips.window(x0, y0, n),
                    };
                    let spectra: Vec<Vec<Complex32>> = sharps
                        .iter()
                        .map(|sharp| {
                            let mut spectrum: Vec<Complex32> =
                                sharp.data.iter().map(|&v| Complex32::new(v, 0.0)).collect();
                            window_fft.forward_complex(&mut spectrum);
                            spectrum
                        })
                        .collect();
                    let mut results: [Vec<f32>; 3] = [Vec::new(), Vec::new(), Vec::new()];
                    let fold: Vec<usize> = (0..n).map(|k| k % m).collect();
                    let mut small = vec![Complex32::new(0.0, 0.0); m * m];
                    let (u, v) = VirtualLens::normalised(cx, cy, w, h);
                    for (ci, psf) in c.psfs.iter().enumerate() {
                        let spectrum = &spectra[bent.as_ref().map_or(0, |b| b.1[ci])];
                        let kernel = (lens.shape != PsfShape::Gaussian)
                            .then(|| lens.optical_kernel_uv(CHANNELS[ci], u, v, params.setting, s));
                        let kernel_tf = kernel.as_ref().map(|k| kernel_transfer(k, n, window_fft));
                        blur_window(
                            spectrum,
                            psf,
                            kernel_tf.as_deref(),
                            &box_tf,
                            &fold,
                            sf,
                            &mut small,
                        );
                        pixel_fft.inverse_complex(&mut small);
                        // 1/n² from the inverse DFT of size n, folded into m² bins: the
                        // decimated image is (1/(s² m²)) Σ, i.e. 1/n².
                        let norm = 1.0 / (n * n) as f32;
                        results[ci] = small.iter().map(|v| v.re * norm).collect();
                    }
                    (ix, results, x0, y0)
                },
            )
            .collect();
        for (ix, results, x0, y0) in row {
            add_window(&mut out, &results, (x0, y0), m, (&xs, ix), (&ys, jy), tile);
        }
    }
    job.report("simulate", total_rows, total_rows);
    apply_light(&mut out, lens, params);

    let (capture, cfa) = sensor_readout(&out, params, lens);
    let truth = shot_truth(spec, lens, params, &image_from_chart, &xs, &ys, &centres);
    let clean = CHANNELS.iter().copied().zip(out).collect();
    Ok(SimulatedShot {
        capture,
        cfa,
        truth,
        clean,
        black_level: params.black_level,
        white_level: params.white_level,
        lens_specification: [
            lens.focal_range_mm[0],
            lens.focal_range_mm[1],
            lens.f_number_range[0],
            lens.f_number_range[0],
        ],
    })
}

/// Refuses a capture the simulator cannot make.
fn check_params(lens: &VirtualLens, params: &CaptureParams) -> Result<(), SimulateError> {
    let (w, h) = (params.width, params.height);
    if !(16..=20000).contains(&w) || !(16..=20000).contains(&h) {
        return Err(SimulateError::Invalid(format!(
            "size {w} × {h} out of range"
        )));
    }
    if !(1..=16).contains(&params.oversample) || !(4..=512).contains(&params.tile_px) {
        return Err(SimulateError::Invalid(
            "oversample must be 1–16 and tile_px 4–512".into(),
        ));
    }
    if params.white_level <= params.black_level {
        return Err(SimulateError::Invalid(
            "white level must exceed the black level".into(),
        ));
    }
    lens.geometry.validate().map_err(SimulateError::Invalid)?;
    Ok(())
}

/// The PSF moments and reach at every centre of `grid` (sensor px).
fn psf_centres(lens: &VirtualLens, params: &CaptureParams, grid: &[(f64, f64)]) -> Vec<PsfCentre> {
    let (w, h, s) = (params.width, params.height, params.oversample);
    grid.par_iter()
        .map(|&(cx, cy)| {
            let (u, v) = VirtualLens::normalised(cx, cy, w, h);
            let psfs = CHANNELS.map(|ch| {
                if lens.shape == PsfShape::Gaussian {
                    let g = lens.gaussian_uv(ch, u, v, params.setting);
                    CentrePsf {
                        cov: [g.sigma_x.powi(2), g.sigma_y.powi(2), g.cov_xy()],
                        radius_px: g.radius_px(4.0),
                    }
                } else {
                    let k = lens.optical_kernel_uv(ch, u, v, params.setting, s);
                    let m = k.moments();
                    CentrePsf {
                        cov: [m.var_x, m.var_y, m.cov_xy],
                        radius_px: k.radius_px() + m.var_x.max(m.var_y).sqrt(),
                    }
                }
            });
            PsfCentre { x: cx, psfs }
        })
        .collect()
}

/// Transfer function of the s-point sub-pixel average that makes pixel j of the
/// window from sub-pixels s·j … s·j+s−1 (a forward-looking average), length `n`.
fn box_transfer(n: usize, s: usize) -> Vec<Complex32> {
    (0..n)
        .map(|k| {
            let mut acc = Complex32::new(0.0, 0.0);
            for u in 0..s {
                let ph = 2.0 * std::f64::consts::PI * (k * u) as f64 / n as f64;
                acc += Complex32::new(ph.cos() as f32, ph.sin() as f32);
            }
            acc / s as f32
        })
        .collect()
}

/// One channel's blurred window folded to pixel resolution, before the inverse
/// transform: the `n × n` window `spectrum` times the PSF's transfer function (the
/// kernel's, else the Gaussian of `psf`'s covariance) and the sub-pixel box, summed
/// into the `m × m` bins of `small` (`fold[k]` = k mod m).
fn blur_window(
    spectrum: &[Complex32],
    psf: &CentrePsf,
    kernel_tf: Option<&[Complex32]>,
    box_tf: &[Complex32],
    fold: &[usize],
    sf: f64,
    small: &mut [Complex32],
) {
    let n = box_tf.len();
    let m = (small.len() as f64).sqrt().round() as usize;
    debug_assert_eq!(m * m, small.len(), "the folded window is square");
    // σ in sub-pixels for the analytic Gaussian transfer function.
    let [vx, vy, cxy] = psf.cov;
    let (vx, vy, cxy) = (vx * sf * sf, vy * sf * sf, cxy * sf * sf);
    small.iter_mut().for_each(|v| *v = Complex32::new(0.0, 0.0));
    let two_pi2 = 2.0 * std::f64::consts::PI.powi(2);
    // Beyond these frequencies the Gaussian's transfer is below e^−18
    // (the quadratic form is at least the conditional variance × f²).
    const CUTOFF: f64 = 18.0;
    let cond_x = (vx - cxy * cxy / vy.max(1e-12)).max(1e-12);
    let cond_y = (vy - cxy * cxy / vx.max(1e-12)).max(1e-12);
    let (fx_max, fy_max) = match kernel_tf {
        Some(_) => (1.0, 1.0),
        None => (
            (CUTOFF / (two_pi2 * cond_x)).sqrt(),
            (CUTOFF / (two_pi2 * cond_y)).sqrt(),
        ),
    };
    let ex: Vec<f64> = (0..n)
        .map(|k| (-two_pi2 * vx * freq(k, n).powi(2)).exp())
        .collect();
    for kb in 0..n {
        let fy = freq(kb, n);
        if fy.abs() > fy_max {
            continue;
        }
        let ey = (-two_pi2 * vy * fy * fy).exp();
        let row_tf = box_tf[kb];
        let dst_row = fold[kb] * m;
        let cross = -2.0 * two_pi2 * cxy * fy;
        for ka in 0..n {
            let fx = freq(ka, n);
            if fx.abs() > fx_max {
                continue;
            }
            let t = match kernel_tf {
                Some(tf) => tf[kb * n + ka],
                None => {
                    let e = ex[ka] * ey * (cross * fx).exp();
                    Complex32::new(e as f32, 0.0)
                }
            };
            let v = spectrum[kb * n + ka] * t * box_tf[ka] * row_tf;
            small[dst_row + fold[ka]] += v;
        }
    }
}

/// The lens's fall-off and the light's gradient over the rendered planes.
fn apply_light(out: &mut [Plane], lens: &VirtualLens, params: &CaptureParams) {
    let (w, h) = (params.width, params.height);
    if lens.geometry.vignetting_stops != [0.0; 2] || params.light_gradient_stops != [0.0; 2] {
        let map = lens.sensor_mapping(Channel::G, params.setting, w, h);
        let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let half_diagonal = cx.hypot(cy).max(1.0);
        let [gx, gy] = params.light_gradient_stops;
        for y in 0..h {
            for x in 0..w {
                let light = ((gx * (x as f64 - cx) + gy * (y as f64 - cy)) / half_diagonal).exp2();
                let gain = (map.illumination([x as f64, y as f64]) * light) as f32;
                for plane in out.iter_mut() {
                    plane.data[y * w + x] *= gain;
                }
            }
        }
    }
}

/// The transfer function of an oversampled kernel centred on an `n × n` window.
fn kernel_transfer(k: &crate::psf::Kernel, n: usize, window_fft: &mut Fft2<f32>) -> Vec<Complex32> {
    let mut buf = vec![Complex32::new(0.0, 0.0); n * n];
    let half = k.size / 2;
    for j in 0..k.size {
        for i in 0..k.size {
            let a = (i + n - half % n) % n;
            let b = (j + n - half % n) % n;
            buf[b * n + a] += Complex32::new(k.at(i, j) as f32, 0.0);
        }
    }
    window_fft.forward_complex(&mut buf);
    buf
}

/// Adds the window rendered around centre (`xs[ix]`, `ys[jy]`), whose pixel (0, 0) is
/// sensor (x0, y0) and which is `m` pixels wide, to `out` under the centre's hat weights.
fn add_window(
    out: &mut [Plane],
    results: &[Vec<f32>; 3],
    (x0, y0): (i64, i64),
    m: usize,
    (xs, ix): (&[f64], usize),
    (ys, jy): (&[f64], usize),
    tile: usize,
) {
    let (w, h) = (out[0].width, out[0].height);
    let (cx, cy) = (xs[ix], ys[jy]);
    let lo_x = (cx as i64 - tile as i64 + 1).max(0);
    let hi_x = (cx as i64 + tile as i64 - 1).min(w as i64 - 1);
    let lo_y = (cy as i64 - tile as i64 + 1).max(0);
    let hi_y = (cy as i64 + tile as i64 - 1).min(h as i64 - 1);
    for y in lo_y..=hi_y {
        let wy = hat_weight_of(ys, tile as f64, y as f64, jy);
        if wy == 0.0 {
            continue;
        }
        for x in lo_x..=hi_x {
            let wx = hat_weight_of(xs, tile as f64, x as f64, ix);
            if wx == 0.0 {
                continue;
            }
            let idx = ((y - y0) as usize) * m + (x - x0) as usize;
            for ci in 0..3 {
                out[ci].data[y as usize * w + x as usize] += (wx * wy) as f32 * results[ci][idx];
            }
        }
    }
}

/// The distinct mappings to render, which one each channel sees (one render for all
/// three when no channel is magnified against another), and the sub-pixel block the
/// mappings are interpolated over. `reach`: the farthest any window reaches beyond the
/// frame, px, which bounds the curvature.
fn distinct_mappings(
    maps: &[SensorMapping; 3],
    reach: f64,
    w: usize,
    h: usize,
    s: usize,
) -> (Vec<SensorMapping>, [usize; 3], usize) {
    let mut distinct: Vec<SensorMapping> = Vec::new();
    let which = std::array::from_fn(|ci| {
        distinct
            .iter()
            .position(|d| *d == maps[ci])
            .unwrap_or_else(|| {
                distinct.push(maps[ci]);
                distinct.len() - 1
            })
    });
    let block = distinct
        .iter()
        .map(|d| block_px(d, w as f64 + 2.0 * reach, h as f64 + 2.0 * reach))
        .min()
        .unwrap_or(1);
    (distinct, which, block * s)
}

/// How far past its tile a window reaches, px: the widest PSF's reach and two more.
fn window_margin(centres: &[PsfCentre]) -> usize {
    let mut radius_px: f64 = 1.0;
    for p in centres.iter().flat_map(|c| &c.psfs) {
        radius_px = radius_px.max(p.radius_px);
    }
    radius_px.ceil() as usize + 2
}

/// From sensor px to the sub-pixels of a window whose pixel (0, 0) is sensor (x0, y0),
/// `s` sub-pixels a side: sub-pixel (a, b) has its centre at sensor
/// (x0 + (a − (s−1)/2)/s, …).
fn sub_from_sensor(x0: i64, y0: i64, s: usize) -> Homography {
    let sf = s as f64;
    let off = (sf - 1.0) / (2.0 * sf);
    Homography::translation(x0 as f64 - off, y0 as f64 - off)
        .compose(&Homography::scaling(1.0 / sf, 1.0 / sf))
        .inverse()
        .unwrap_or_else(Homography::identity)
}

/// Per chart row, the (channel, column, row) of the centres whose fine kernels its
/// squares blend. Neighbouring squares share centres, so each fine kernel is made once,
/// when the first row that needs it comes, and dropped after the last: at 12× they are
/// megabytes each, and all of a 2400 × 1600 shot's at once were gigabytes.
fn fine_kernels_needed(
    spec: &ChartSpec,
    lens: &VirtualLens,
    image_from_chart: &Homography,
    maps: Option<&[SensorMapping; 3]>,
    xs: &[f64],
    ys: &[f64],
    tile: f64,
) -> Vec<BTreeSet<(usize, usize, usize)>> {
    (0..spec.rows)
        .map(|row| {
            let mut need = BTreeSet::new();
            if lens.shape == PsfShape::Gaussian {
                return need;
            }
            for col in 0..spec.cols {
                let ideal = image_from_chart.apply([col as f64 + 0.5, row as f64 + 0.5]);
                for ci in 0..CHANNELS.len() {
                    // Each channel's square sits where its own mapping puts it.
                    let centre = maps
                        .and_then(|m| m.get(ci))
                        .map_or(ideal, |m| m.sensor_from_ideal(ideal));
                    for &(j, wyj) in &hat_weights(ys, tile, centre[1]) {
                        for &(i, wxi) in &hat_weights(xs, tile, centre[0]) {
                            if wxi * wyj > 0.0 {
                                need.insert((ci, i, j));
                            }
                        }
                    }
                }
            }
            need
        })
        .collect()
}

fn hat_weight_of(grid: &[f64], tile: f64, p: f64, node: usize) -> f64 {
    hat_weights(grid, tile, p)
        .iter()
        .filter(|(i, _)| *i == node)
        .map(|(_, w)| *w)
        .sum()
}

/// Each channel's ideal-to-sensor mapping, when the lens bends the image at all.
fn channel_mappings(lens: &VirtualLens, params: &CaptureParams) -> Option<[SensorMapping; 3]> {
    lens.geometry.bends().then(|| {
        CHANNELS.map(|ch| lens.sensor_mapping(ch, params.setting, params.width, params.height))
    })
}

/// CFA colour of sensor pixel (x, y) for RGGB: 0 = R, 1 = G, 2 = B.
#[inline]
#[must_use]
pub fn rggb_channel(x: usize, y: usize) -> usize {
    match (x % 2, y % 2) {
        (0, 0) => 0,
        (1, 1) => 2,
        _ => 1,
    }
}

/// Gain, noise and quantisation; returns the normalised capture and the raw values.
fn sensor_readout(
    clean: &[Plane],
    params: &CaptureParams,
    lens: &VirtualLens,
) -> (Capture, Vec<u16>) {
    let (w, h) = (params.width, params.height);
    let black = f64::from(params.black_level);
    let range = f64::from(params.white_level) - black;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(params.seed);
    let shot_noise = params.noise.full_well_e.is_finite() && params.noise.full_well_e > 0.0;
    let full_well = if shot_noise {
        params.noise.full_well_e
    } else {
        1.0
    };
    let read = Normal::new(0.0, params.noise.read_noise_e.max(0.0)).ok();
    let mut quantise = |signal: f64| -> u16 {
        let signal = signal.max(0.0);
        let mut e = signal * full_well;
        if shot_noise {
            e = if e > 1e-9 {
                Poisson::new(e).map(|p| p.sample(&mut rng)).unwrap_or(e)
            } else {
                0.0
            };
        }
        if let Some(n) = &read
            && params.noise.read_noise_e > 0.0
        {
            e += n.sample(&mut rng);
        }
        let dn = black + e / full_well * range;
        dn.round().clamp(0.0, f64::from(params.white_level)) as u16
    };
    let gain = |ci: usize| params.exposure * params.channel_gains[ci];
    let mut cfa;
    if params.bayer {
        cfa = vec![0u16; w * h];
        for y in 0..h {
            for x in 0..w {
                let ci = rggb_channel(x, y);
                cfa[y * w + x] = quantise(f64::from(clean[ci].get(x, y)) * gain(ci));
            }
        }
    } else {
        cfa = vec![0u16; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                for ci in 0..3 {
                    cfa[(y * w + x) * 3 + ci] = quantise(f64::from(clean[ci].get(x, y)) * gain(ci));
                }
            }
        }
    }
    let capture = capture_from_raw(
        &cfa,
        w,
        h,
        params.bayer,
        params.black_level,
        params.white_level,
    );
    let mut capture = capture;
    capture.setting_focal_mm = Some(params.setting.focal_mm);
    capture.setting_f_number = Some(params.setting.f_number);
    capture.identity = CameraIdentity {
        make: Some("Virtual".into()),
        model: Some("Sim 14".into()),
        body_serial: Some("SIM-0001".into()),
        lens_model: Some(lens.model.clone()),
        lens_serial: Some(lens.serial.clone()),
    };
    (capture, cfa)
}

/// The normalised capture of raw values: RGGB planes (step 2) or three full planes.
#[must_use]
pub fn capture_from_raw(
    values: &[u16],
    w: usize,
    h: usize,
    bayer: bool,
    black: u16,
    white: u16,
) -> Capture {
    let black_f = f32::from(black);
    let range = (f32::from(white) - black_f).max(1.0);
    let norm = |v: u16| (f32::from(v) - black_f) / range;
    let planes = if bayer {
        [
            (Channel::R, 0, 0),
            (Channel::G, 1, 0),
            (Channel::G, 0, 1),
            (Channel::B, 1, 1),
        ]
        .iter()
        .map(|&(channel, ox, oy)| {
            let pw = (w + 1 - ox) / 2;
            let ph = (h + 1 - oy) / 2;
            let plane = Plane::from_fn(pw, ph, |i, j| norm(values[(2 * j + oy) * w + 2 * i + ox]));
            ChannelPlane {
                channel,
                plane,
                step: 2,
                offset_x: ox,
                offset_y: oy,
            }
        })
        .collect()
    } else {
        CHANNELS
            .iter()
            .enumerate()
            .map(|(ci, &channel)| ChannelPlane {
                channel,
                plane: Plane::from_fn(w, h, |x, y| norm(values[(y * w + x) * 3 + ci])),
                step: 1,
                offset_x: 0,
                offset_y: 0,
            })
            .collect()
    };
    Capture::of_planes(w, h, planes, bayer)
}

fn shot_truth(
    spec: &ChartSpec,
    lens: &VirtualLens,
    params: &CaptureParams,
    image_from_chart: &Homography,
    xs: &[f64],
    ys: &[f64],
    centres: &[PsfCentre],
) -> ShotTruth {
    let (w, h) = (params.width, params.height);
    let tile = params.tile_px as f64;
    let maps = channel_mappings(lens, params);
    let inside = |p: [f64; 2]| {
        p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (w - 1) as f64 && p[1] <= (h - 1) as f64
    };
    let psf_field = PsfField {
        tile_px: params.tile_px,
        xs: xs.to_vec(),
        ys: ys.to_vec(),
        cov: CHANNELS
            .iter()
            .enumerate()
            .map(|(ci, &ch)| (ch, centres.iter().map(|c| c.psfs[ci].cov).collect()))
            .collect(),
    };
    let row_needs = fine_kernels_needed(spec, lens, image_from_chart, maps.as_ref(), xs, ys, tile);
    let mut last_row: HashMap<(usize, usize, usize), usize> = HashMap::new();
    for (row, need) in row_needs.iter().enumerate() {
        for &key in need {
            last_row.insert(key, row);
        }
    }
    let mut fine: HashMap<(usize, usize, usize), Kernel> = HashMap::new();
    let mut squares = Vec::with_capacity(spec.rows * spec.cols);
    for (row, need) in row_needs.iter().enumerate() {
        let missing: Vec<(usize, usize, usize)> = need
            .iter()
            .copied()
            .filter(|key| !fine.contains_key(key))
            .collect();
        let made: Vec<((usize, usize, usize), Kernel)> = missing
            .into_par_iter()
            .map(|(ci, i, j)| {
                let (u, v) = VirtualLens::normalised(xs[i], ys[j], w, h);
                let k = lens.optical_kernel_uv(CHANNELS[ci], u, v, params.setting, FINE);
                ((ci, i, j), k)
            })
            .collect();
        fine.extend(made);
        for col in 0..spec.cols {
            let ideal_corners = spec
                .square_corners(col, row)
                .map(|p| image_from_chart.apply(p));
            let ideal_centre = image_from_chart.apply([col as f64 + 0.5, row as f64 + 0.5]);
            let positions: Vec<ChannelPosition> = maps.as_ref().map_or_else(Vec::new, |maps| {
                CHANNELS
                    .iter()
                    .zip(maps)
                    .map(|(&channel, map)| ChannelPosition {
                        channel,
                        corners: ideal_corners.map(|p| map.sensor_from_ideal(p)),
                        centre: map.sensor_from_ideal(ideal_centre),
                    })
                    .collect()
            });
            let green = positions.iter().find(|p| p.channel == Channel::G);
            let corners = green.map_or(ideal_corners, |p| p.corners);
            let centre = green.map_or(ideal_centre, |p| p.centre);
            let fully_visible = corners.iter().all(|&p| inside(p))
                && positions
                    .iter()
                    .all(|p| p.corners.iter().all(|&q| inside(q)));
            let mut optical = Vec::with_capacity(3);
            let mut pixel = Vec::with_capacity(3);
            let mut pixel_kernels = Vec::new();
            for (ci, &ch) in CHANNELS.iter().enumerate() {
                let centre = positions
                    .iter()
                    .find(|p| p.channel == ch)
                    .map_or(centre, |p| p.centre);
                let wx = hat_weights(xs, tile, centre[0]);
                let wy = hat_weights(ys, tile, centre[1]);
                let g = psf_field
                    .optical_at(ch, centre[0], centre[1])
                    .unwrap_or(Gaussian2::isotropic(0.0));
                optical.push((ch, g));
                pixel.push((ch, g.convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)));
                if lens.shape != PsfShape::Gaussian {
                    let mut blend = Vec::with_capacity(4);
                    for &(j, wyj) in &wy {
                        for &(i, wxi) in &wx {
                            if wxi * wyj > 0.0
                                && let Some(k) = fine.get(&(ci, i, j))
                            {
                                blend.push((wxi * wyj, k));
                            }
                        }
                    }
                    pixel_kernels.push((ch, blended_pixel_kernel(&blend)));
                }
            }
            squares.push(SquareTruth {
                row,
                col,
                corners,
                centre,
                fully_visible,
                optical,
                pixel,
                pixel_kernels,
                channels: positions,
            });
        }
        fine.retain(|key, _| last_row.get(key).is_some_and(|&last| last > row));
    }
    ShotTruth {
        width: w,
        height: h,
        setting: params.setting,
        image_from_chart: *image_from_chart,
        squares,
        psf_field,
        geometry: lens.geometry.clone(),
    }
}

/// Samples per pixel of the optical kernels the truth's pixel-level kernels integrate.
const FINE: usize = 12;

/// The pixel-level kernel at 3× of a blend of centre PSFs: each optical PSF sampled
/// finely ([`FINE`]×) and integrated over the unit pixel box around every 3× offset.
fn blended_pixel_kernel(fine: &[(f64, &Kernel)]) -> Kernel {
    const OUT: usize = 3;
    let radius = fine.iter().map(|(_, k)| k.radius_px()).fold(0.0, f64::max) + 0.5;
    let half = (radius * OUT as f64).ceil() as usize;
    let size = 2 * half + 1;
    let mut data = vec![0.0; size * size];
    for &(wgt, k) in fine {
        let c = (k.size / 2) as i64;
        // Fine sample (i, j) at offset ((i − c)/12, …) falls in the box of 3× offset d
        // when |offset − d| ≤ ½ on both axes; boundary samples count half. The box is
        // separable: integrate along x, then along y.
        let cells: Vec<Vec<(usize, f64)>> = (0..k.size)
            .map(|i| {
                let mut v = Vec::with_capacity(5);
                box_cells_1d((i as i64 - c) as f64 / FINE as f64, half, |a, f| {
                    v.push((a, f));
                });
                v
            })
            .collect();
        let mut rows = vec![0.0; k.size * size];
        for (row, src) in rows.chunks_exact_mut(size).zip(k.data.chunks_exact(k.size)) {
            for (&val, cell) in src.iter().zip(&cells) {
                if val == 0.0 {
                    continue;
                }
                for &(a, f) in cell {
                    row[a] += val * f;
                }
            }
        }
        for j in 0..k.size {
            let row = &rows[j * size..(j + 1) * size];
            for &(b, f) in &cells[j] {
                let dst = &mut data[b * size..(b + 1) * size];
                for (d, &r) in dst.iter_mut().zip(row) {
                    *d += wgt * f * r;
                }
            }
        }
    }
    let mut kern = Kernel {
        size,
        oversample: OUT,
        data,
    };
    kern.normalise();
    kern
}

/// The 3× cells (index, weight) whose unit box covers fine offset `o` on one axis.
fn box_cells_1d(o: f64, half: usize, mut add: impl FnMut(usize, f64)) {
    let os = OUT_F;
    let lo = ((o - 0.5) * os - 1e-9).ceil() as i64;
    let hi = ((o + 0.5) * os + 1e-9).floor() as i64;
    for d in lo..=hi {
        let a = d + half as i64;
        if a < 0 || a > 2 * half as i64 {
            continue;
        }
        let dist = (o - d as f64 / os).abs();
        add(
            a as usize,
            if (dist - 0.5).abs() < 1e-9 { 0.5 } else { 1.0 },
        );
    }
}

const OUT_F: f64 = 3.0;

#[cfg(test)]
mod tests;
