//! What the studio asks of a session's results, answered by the core so that the app
//! only shows: measured sweep points and the model and truth curves beside them (the
//! paper's Fig. 4), predicted and true Gaussian fields, the numbers behind one square,
//! the kernels a photo is deblurred with, and deblurred crops of a photo region side by
//! side (the paper's Fig. 7–8 comparison of predicted Gaussians and measured kernels).
//!
//! This module is core: it never touches egui.

use crate::deblur::source::{Prefer, ScatteredKernels};
use crate::deblur::{DeblurError, DeblurOptions, KernelSource, ProfileKernels, SourceError};
use crate::detect::SquareAlignment;
use crate::develop::{DevelopError, Developed, Orient, develop};
use crate::job::JobContext;
use crate::kernel::file::KernelsFile;
use crate::model::Dataset;
use crate::model::{KernelModel, relative_l2};
use crate::plane::{Capture, Channel, ChannelPlane, LensSetting, Plane};
use crate::profile::Profile;
use crate::psf::{Gaussian2, Kernel};
use std::path::Path;

/// The value of `values` nearest `wanted` (the calibrated setting a sweep holds fixed).
#[must_use]
pub fn nearest_value(values: &[f64], wanted: f64) -> Option<f64> {
    values
        .iter()
        .copied()
        .min_by(|a, b| (a - wanted).abs().total_cmp(&(b - wanted).abs()))
}

/// `nx` × `ny` points spread evenly over a `width` × `height` sensor (cell centres),
/// row-major: where the Kernel field view shows a predicted or true field.
#[must_use]
pub fn field_grid(width: usize, height: usize, nx: usize, ny: usize) -> Vec<[f64; 2]> {
    let (w, h) = (width.max(1) as f64 - 1.0, height.max(1) as f64 - 1.0);
    (0..ny)
        .flat_map(|j| {
            (0..nx).map(move |i| {
                [
                    (i as f64 + 0.5) / nx as f64 * w,
                    (j as f64 + 0.5) / ny as f64 * h,
                ]
            })
        })
        .collect()
}

/// The pixel-level Gaussian of a virtual lens at a sensor point: its optical blur plus
/// the 1-px box of the pixel's own integration (what kernels measure).
#[must_use]
pub fn truth_pixel_gaussian(
    lens: &crate::simulate::VirtualLens,
    channel: Channel,
    (x, y): (f64, f64),
    (width, height): (usize, usize),
    setting: LensSetting,
) -> Gaussian2 {
    lens.gaussian_at(channel, x, y, width, height, setting)
        .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
}

/// `n` + 1 settings along a sweep for drawing model curves: the f-number from
/// `range[0]` to `range[1]` evenly in stops at focal length `fixed` (`vs_aperture`), or
/// the focal length evenly in mm at f-number `fixed`.
#[must_use]
pub fn sweep_settings(
    range: [f64; 2],
    fixed: f64,
    vs_aperture: bool,
    n: usize,
) -> Vec<LensSetting> {
    let n = n.max(1);
    (0..=n)
        .map(|k| {
            let t = k as f64 / n as f64;
            if vs_aperture {
                LensSetting {
                    focal_mm: fixed,
                    f_number: range[0] * (range[1] / range[0]).powf(t),
                }
            } else {
                LensSetting {
                    focal_mm: range[0] + (range[1] - range[0]) * t,
                    f_number: fixed,
                }
            }
        })
        .collect()
}

/// A profile's predicted Gaussians on the `grid` (`nx`, `ny`) of a `width` × `height`
/// sensor at `setting`, each with its sensor position; or why the profile has none
/// there (the first failure, one line).
///
/// # Errors
/// The profile cannot predict at some grid point (channel or setting outside it).
pub fn predicted_field(
    profile: &Profile,
    channel: Channel,
    (width, height): (usize, usize),
    (nx, ny): (usize, usize),
    setting: LensSetting,
) -> Result<Vec<(f64, f64, Gaussian2)>, String> {
    field_grid(width, height, nx, ny)
        .into_iter()
        .map(|[x, y]| {
            profile
                .predict(channel, x, y, setting)
                .map(|g| (x, y, g))
                .map_err(|e| e.to_string())
        })
        .collect()
}

/// One kernel a profile predicts: its sensor position, the Gaussian it is built
/// around and the 3× kernel itself.
#[derive(Clone, Debug)]
pub struct PredictedKernel {
    pub x: f64,
    pub y: f64,
    pub gaussian: Gaussian2,
    pub kernel: Kernel,
}

/// A profile's predicted kernels in `model` at sensor `points` and `setting`, so the
/// studio can lay them beside the measured ones cell for cell.
///
/// # Errors
/// The profile cannot predict at some point (channel or setting outside it, or no
/// shape model for [`KernelModel::Shape`]): the first failure, one line.
pub fn predicted_kernels(
    profile: &Profile,
    model: KernelModel,
    channel: Channel,
    points: &[[f64; 2]],
    setting: LensSetting,
) -> Result<Vec<PredictedKernel>, String> {
    points
        .iter()
        .map(|&[x, y]| {
            let gaussian = profile
                .predict(channel, x, y, setting)
                .map_err(|e| e.to_string())?;
            let kernel = profile
                .predict_kernel(model, channel, x, y, setting)
                .map_err(|e| e.to_string())?;
            Ok(PredictedKernel {
                x,
                y,
                gaussian,
                kernel,
            })
        })
        .collect()
}

/// How far a profile's predictions miss one measured kernel: relative L2 of the
/// predicted kernel against the measured one, for the Gaussian alone and, where the
/// profile holds a shape model, for the Gaussian with its predicted shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelError {
    pub gaussian: f64,
    pub shape: Option<f64>,
}

/// Per sample of a shot's kernels file (in the file's order), the error of `profile`'s
/// predicted kernels against the measured kernel at the shot's setting; `None` where
/// the sample is of another channel, holds no kernel array, or the profile cannot
/// predict there (the file names no setting, or one outside the profile).
#[must_use]
pub fn kernel_errors(
    profile: &Profile,
    file: &KernelsFile,
    channel: Channel,
) -> Vec<Option<KernelError>> {
    let setting = match (file.focal_mm, file.f_number) {
        (Some(focal_mm), Some(f_number)) => Some(LensSetting { focal_mm, f_number }),
        _ => None,
    };
    file.samples
        .iter()
        .map(|s| {
            let setting = setting?;
            if s.channel != channel {
                return None;
            }
            let measured = s.kernel_at(file.oversample)?;
            let error = |model| {
                profile
                    .predict_kernel(model, channel, s.x, s.y, setting)
                    .ok()
                    .map(|k| relative_l2(&k, &measured))
            };
            Some(KernelError {
                gaussian: error(KernelModel::Gaussian)?,
                shape: profile
                    .shape
                    .is_some()
                    .then(|| error(KernelModel::Shape))
                    .flatten(),
            })
        })
        .collect()
}

/// Why a profile holds no kernel-shape model, in a few words; `None` where it holds
/// one.
#[must_use]
pub fn no_shape_reason(profile: &Profile) -> Option<String> {
    if profile.shape.is_some() {
        return None;
    }
    Some(match &profile.shape_cv {
        Some(cv) => match &cv.best_shape {
            Some(best) => format!(
                "cross-validation kept the Gaussians (held-out error: Gaussian {:.3}, best shapes {:.3})",
                cv.gaussian.mean_rel_l2, best.mean_rel_l2
            ),
            None => "cross-validation kept the Gaussians (no shape model could be fitted)".into(),
        },
        None => "the profile holds no shape cross-validation (calibrated without measured kernels, or written before shape models)".into(),
    })
}

/// A virtual lens's pixel-level Gaussians on the same grid as [`predicted_field`].
#[must_use]
pub fn truth_field(
    lens: &crate::simulate::VirtualLens,
    channel: Channel,
    size: (usize, usize),
    (nx, ny): (usize, usize),
    setting: LensSetting,
) -> Vec<(f64, f64, Gaussian2)> {
    field_grid(size.0, size.1, nx, ny)
        .into_iter()
        .map(|[x, y]| {
            (
                x,
                y,
                truth_pixel_gaussian(lens, channel, (x, y), size, setting),
            )
        })
        .collect()
}

/// A profile's model curve at sensor point (x, y) over `settings` (from
/// [`sweep_settings`]); settings it cannot predict at are left out.
#[must_use]
pub fn model_curve(
    profile: &Profile,
    channel: Channel,
    (x, y): (f64, f64),
    settings: &[LensSetting],
) -> Vec<(LensSetting, Gaussian2)> {
    settings
        .iter()
        .filter_map(|&s| Some((s, profile.predict(channel, x, y, s).ok()?)))
        .collect()
}

/// A virtual lens's pixel-level truth at sensor point (x, y) over `settings`.
#[must_use]
pub fn truth_curve(
    lens: &crate::simulate::VirtualLens,
    channel: Channel,
    at: (f64, f64),
    size: (usize, usize),
    settings: &[LensSetting],
) -> Vec<(LensSetting, Gaussian2)> {
    settings
        .iter()
        .map(|&s| (s, truth_pixel_gaussian(lens, channel, at, size, s)))
        .collect()
}

/// One measured point of a sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepPoint {
    pub setting: LensSetting,
    /// Where the square it was measured on lies, sensor px.
    pub x: f64,
    pub y: f64,
    pub gaussian: Gaussian2,
}

/// Measured points of one sweep: for every shot on the sweep (its focal length equals
/// `fixed` when `vs_aperture`, its f-number otherwise), the `channel` sample nearest
/// sensor point (x, y). Sorted by the varying setting.
#[must_use]
pub fn sweep_points(
    ds: &Dataset,
    channel: Channel,
    (x, y): (f64, f64),
    vs_aperture: bool,
    fixed: f64,
) -> Vec<SweepPoint> {
    let mut out: Vec<SweepPoint> = ds
        .shots
        .iter()
        .enumerate()
        .filter(|(_, info)| {
            if vs_aperture {
                LensSetting::same_value(info.focal_mm, fixed)
            } else {
                LensSetting::same_value(info.f_number, fixed)
            }
        })
        .filter_map(|(k, info)| {
            let s = ds
                .samples
                .iter()
                .filter(|s| s.shot == k && s.channel == channel)
                .min_by(|a, b| {
                    let da = (a.x - x).powi(2) + (a.y - y).powi(2);
                    let db = (b.x - x).powi(2) + (b.y - y).powi(2);
                    da.total_cmp(&db)
                })?;
            Some(SweepPoint {
                setting: LensSetting {
                    focal_mm: info.focal_mm,
                    f_number: info.f_number,
                },
                x: s.x,
                y: s.y,
                gaussian: s.gaussian,
            })
        })
        .collect();
    let key = |p: &SweepPoint| {
        if vs_aperture {
            p.setting.f_number
        } else {
            p.setting.focal_mm
        }
    };
    out.sort_by(|a, b| key(a).total_cmp(&key(b)));
    out
}

/// The numbers the inspector shows for one aligned square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SquareFacts {
    /// The square's centre through its refined homography, sensor px.
    pub centre: [f64; 2],
    /// How far refinement moved the bootstrap corners (the largest of the four), px.
    pub corner_shift_px: f64,
    /// Side lengths of the refined square (mean of opposite sides), px.
    pub side_px: [f64; 2],
}

#[must_use]
pub fn square_facts(sq: &SquareAlignment) -> SquareFacts {
    let centre = crate::kernel::square_centre(&crate::kernel::SquareGeometry {
        row: sq.row,
        col: sq.col,
        image_from_chart: sq.image_from_chart,
    });
    let dist = |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    let corner_shift_px = sq
        .corners
        .iter()
        .zip(&sq.bootstrap_corners)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max);
    let c = &sq.corners;
    let side_px = [
        0.5 * (dist(c[0], c[1]) + dist(c[3], c[2])),
        0.5 * (dist(c[0], c[3]) + dist(c[1], c[2])),
    ];
    SquareFacts {
        centre,
        corner_shift_px,
        side_px,
    }
}

/// Why a detection skipped squares: each reason with how many squares it covers, most
/// frequent first.
#[must_use]
pub fn skip_reasons(det: &crate::detect::Detection) -> Vec<(String, usize)> {
    let mut counts: std::collections::BTreeMap<String, usize> = std::collections::BTreeMap::new();
    for sq in det
        .squares
        .iter()
        .filter(|s| s.status != crate::detect::SquareStatus::Ok)
    {
        let reason = sq
            .reason
            .clone()
            .unwrap_or_else(|| "no reason given".into());
        *counts.entry(reason).or_default() += 1;
    }
    let mut out: Vec<(String, usize)> = counts.into_iter().collect();
    out.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    out
}

/// A rectangle of sensor pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    pub x0: usize,
    pub y0: usize,
    pub width: usize,
    pub height: usize,
}

impl Region {
    /// A `size` × `size` region (at most the sensor) centred as near (cx, cy) as the
    /// sensor allows, its corner and size even so that a Bayer mosaic keeps its phase.
    #[must_use]
    pub fn around(cx: f64, cy: f64, size: usize, sensor_w: usize, sensor_h: usize) -> Self {
        Self::around_size(cx, cy, size, size, sensor_w, sensor_h)
    }

    /// [`Self::around`] for a `width` × `height` region.
    #[must_use]
    pub fn around_size(
        cx: f64,
        cy: f64,
        width: usize,
        height: usize,
        sensor_w: usize,
        sensor_h: usize,
    ) -> Self {
        let even = |v: usize| v & !1;
        let w = even(width.min(sensor_w)).max(2.min(sensor_w));
        let h = even(height.min(sensor_h)).max(2.min(sensor_h));
        let place = |c: f64, len: usize, full: usize| -> usize {
            let start = (c - len as f64 / 2.0).round().max(0.0) as usize;
            even(start.min(full.saturating_sub(len)))
        };
        Self {
            x0: place(cx, w, sensor_w),
            y0: place(cy, h, sensor_h),
            width: w,
            height: h,
        }
    }

    /// This region grown by `margin` px on every side, clipped to the sensor (kept even).
    #[must_use]
    pub fn grown(&self, margin: usize, sensor_w: usize, sensor_h: usize) -> Self {
        let m = margin & !1;
        let x0 = self.x0.saturating_sub(m) & !1;
        let y0 = self.y0.saturating_sub(m) & !1;
        let x1 = (self.x0 + self.width + m).min(sensor_w);
        let y1 = (self.y0 + self.height + m).min(sensor_h);
        Self {
            x0,
            y0,
            width: (x1 - x0) & !1,
            height: (y1 - y0) & !1,
        }
    }

    #[must_use]
    pub fn centre(&self) -> [f64; 2] {
        [
            self.x0 as f64 + (self.width as f64 - 1.0) / 2.0,
            self.y0 as f64 + (self.height as f64 - 1.0) / 2.0,
        ]
    }
}

/// The part of a capture inside `region`, as a capture of its own whose pixel (0, 0) is
/// sensor pixel (x0, y0). The region's corner must be even (see [`Region::around`]) so
/// every plane keeps its mosaic offset.
#[must_use]
pub fn crop_capture(cap: &Capture, region: Region) -> Capture {
    let planes = cap
        .planes
        .iter()
        .map(|cp| {
            let s = cp.step.max(1);
            let i0 = region.x0 / s;
            let j0 = region.y0 / s;
            let w = (region.width / s).min(cp.plane.width.saturating_sub(i0));
            let h = (region.height / s).min(cp.plane.height.saturating_sub(j0));
            ChannelPlane {
                channel: cp.channel,
                plane: cp.plane.crop(i0, j0, w, h),
                step: cp.step,
                offset_x: cp.offset_x,
                offset_y: cp.offset_y,
            }
        })
        .collect();
    Capture {
        width: region.width,
        height: region.height,
        planes,
        setting_focal_mm: cap.setting_focal_mm,
        setting_f_number: cap.setting_f_number,
        identity: cap.identity.clone(),
        is_raw: cap.is_raw,
        raw: cap.raw.clone(),
    }
}

/// A kernel source asked in a crop's coordinates, answering from the full sensor's.
struct Shifted<'a> {
    inner: &'a dyn KernelSource,
    dx: f64,
    dy: f64,
}

impl KernelSource for Shifted<'_> {
    fn kernel_at(&self, channel: Channel, x: f64, y: f64) -> Result<Kernel, SourceError> {
        self.inner.kernel_at(channel, x + self.dx, y + self.dy)
    }
}

/// Full-resolution planes of `region` of a capture deblurred with `source` (asked at
/// full-sensor positions). A margin around the region is deconvolved with it and cut
/// away afterwards, so the crop's own borders do not ring into the result.
///
/// # Errors
/// The source has no kernel, or the job was cancelled.
pub fn deblur_region(
    cap: &Capture,
    region: Region,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Vec<(Channel, Plane)>, DeblurError> {
    deblur_region_capture(cap, region, source, opts, job)
        .map(|(out, outer)| inner_planes(&out, region, outer))
}

/// [`deblur_region`]'s result before it is cut to the region: the deblurred capture of
/// the grown region, and that region.
fn deblur_region_capture(
    cap: &Capture,
    region: Region,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<(Capture, Region), DeblurError> {
    let outer = region.grown(48, cap.width, cap.height);
    let crop = crop_capture(cap, outer);
    let shifted = Shifted {
        inner: source,
        dx: outer.x0 as f64,
        dy: outer.y0 as f64,
    };
    let out = crate::deblur::deblur_capture(&crop, &shifted, opts, job)?;
    Ok((out, outer))
}

/// `region` of a RAW capture of the grown region `outer`, developed (imagepipe): what
/// a photographer compares. Developed with its margin, so demosaicing has neighbours
/// at the region's edges, then cut.
fn developed_region(
    cap: &Capture,
    region: Region,
    outer: Region,
) -> Result<Developed, DevelopError> {
    let full = develop(cap, None, Orient::Sensor)?;
    let (dx, dy) = (region.x0 - outer.x0, region.y0 - outer.y0);
    let w = region.width.min(full.width.saturating_sub(dx));
    let h = region.height.min(full.height.saturating_sub(dy));
    let mut rgb = Vec::with_capacity(w * h * 3);
    for y in dy..dy + h {
        let row = (y * full.width + dx) * 3;
        rgb.extend_from_slice(&full.rgb[row..row + w * 3]);
    }
    Ok(Developed {
        width: w,
        height: h,
        rgb,
    })
}

fn inner_planes(cap: &Capture, region: Region, outer: Region) -> Vec<(Channel, Plane)> {
    let (dx, dy) = (region.x0 - outer.x0, region.y0 - outer.y0);
    crate::raw::full_planes(cap)
        .into_iter()
        .map(|(c, p)| {
            let w = region.width.min(p.width.saturating_sub(dx));
            let h = region.height.min(p.height.saturating_sub(dy));
            (c, p.crop(dx, dy, w, h))
        })
        .collect()
}

/// The linear value each plane shows as white on screen: its 99.5th percentile (at
/// least a small positive floor), so a few specular pixels do not darken the picture
/// and the paper of a chart, whatever the camera's channel gains, shows neutral.
#[must_use]
pub fn display_whites(planes: &[(Channel, Plane)]) -> Vec<(Channel, f32)> {
    planes
        .iter()
        .map(|(c, p)| {
            let mut v: Vec<f32> = p.data.iter().copied().filter(|v| v.is_finite()).collect();
            if v.is_empty() {
                return (*c, 1.0);
            }
            let k = ((v.len() - 1) as f64 * 0.995).round() as usize;
            let (_, white, _) = v.select_nth_unstable_by(k, f32::total_cmp);
            (*c, white.max(1e-3))
        })
        .collect()
}

/// The planes of `region` as they are (the "original" of a comparison).
#[must_use]
pub fn region_planes(cap: &Capture, region: Region) -> Vec<(Channel, Plane)> {
    let outer = region.grown(2, cap.width, cap.height);
    inner_planes(&crop_capture(cap, outer), region, outer)
}

/// A photo region and its deblurred versions: with the Gaussians the profile predicts
/// and with the kernels measured on a chart shot at the same setting. Each result is
/// absent with the reason when its kernels are not available.
#[derive(Clone, Debug)]
pub struct DeblurComparison {
    pub region: Region,
    pub original: Vec<(Channel, Plane)>,
    pub predicted: Result<Vec<(Channel, Plane)>, String>,
    pub measured: Result<Vec<(Channel, Plane)>, String>,
    /// For a RAW photo, the original, predicted and measured crops developed as a RAW
    /// editor shows them (each absent where its planes are); `Err` says why the photo
    /// could not be developed. `None` for an RGB photo.
    pub developed: Option<Result<[Option<Developed>; 3], String>>,
}

/// Deblurs `region` with both sources (each may be absent, with its reason).
///
/// # Errors
/// Only on cancellation; a source that fails leaves its reason in the comparison.
pub fn compare_deblur(
    cap: &Capture,
    region: Region,
    predicted: Result<&dyn KernelSource, String>,
    measured: Result<&dyn KernelSource, String>,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<DeblurComparison, crate::job::Cancelled> {
    let predicted = deblur_or_reason(cap, region, predicted, opts, &job.prefixed("predicted: "))?;
    let measured = deblur_or_reason(cap, region, measured, opts, &job.prefixed("measured: "))?;
    let outer = region.grown(48, cap.width, cap.height);
    let developed = cap.is_raw.then(|| {
        let original = developed_region(&crop_capture(cap, outer), region, outer)
            .map_err(|e| e.to_string())?;
        let result = |r: &Result<(Capture, Region), String>| {
            r.as_ref()
                .ok()
                .and_then(|(c, o)| developed_region(c, region, *o).ok())
        };
        Ok([Some(original), result(&predicted), result(&measured)])
    });
    let planes = |r: Result<(Capture, Region), String>| r.map(|(c, o)| inner_planes(&c, region, o));
    Ok(DeblurComparison {
        region,
        original: region_planes(cap, region),
        predicted: planes(predicted),
        measured: planes(measured),
        developed,
    })
}

/// One result of a comparison: the planes, or why there are none; `Err` only when
/// cancelled.
fn deblur_or_reason(
    cap: &Capture,
    region: Region,
    source: Result<&dyn KernelSource, String>,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Result<(Capture, Region), String>, crate::job::Cancelled> {
    let source = match source {
        Ok(s) => s,
        Err(reason) => return Ok(Err(reason)),
    };
    match deblur_region_capture(cap, region, source, opts, job) {
        Ok(p) => Ok(Ok(p)),
        Err(DeblurError::Cancelled(c)) => Err(c),
        Err(e) => Ok(Err(e.to_string())),
    }
}

/// The kernels a profile predicts for a photo at `setting`, or why there are none: the
/// setting is unknown or outside the calibrated range, or the photo comes from another
/// sensor size.
///
/// # Errors
/// The one-line reason.
pub fn profile_source(
    profile: &Profile,
    cap: &Capture,
    setting: Option<LensSetting>,
) -> Result<ProfileKernels, String> {
    let Some(setting) = setting else {
        return Err("focal length and aperture unknown: type them above".into());
    };
    if (profile.norm.width, profile.norm.height) != (cap.width, cap.height) {
        return Err(format!(
            "the photo is {} × {} but the profile is for a {} × {} sensor",
            cap.width, cap.height, profile.norm.width, profile.norm.height
        ));
    }
    profile.check_setting(setting).map_err(|e| e.to_string())?;
    Ok(ProfileKernels::new(profile.clone(), setting))
}

/// Whether kernels measured on a shot at `shot_setting` serve a photo at `setting` on a
/// sensor of the photo's size: what a photo at that setting is deblurred with
/// "measured kernels".
#[must_use]
pub fn measured_at(
    shot_setting: Option<LensSetting>,
    file: &KernelsFile,
    width: usize,
    height: usize,
    setting: LensSetting,
) -> bool {
    shot_setting.is_some_and(|s| s.same_as(setting)) && (file.width, file.height) == (width, height)
}

/// The measured non-parametric kernels of a kernels file as a deblurring source.
///
/// # Errors
/// The file holds no sample.
pub fn measured_source(file: &KernelsFile) -> Result<ScatteredKernels, String> {
    if file.samples.is_empty() {
        return Err(match &file.source {
            Some(s) => format!("{}: no measured kernel", s.file),
            None => "no measured kernel".into(),
        });
    }
    Ok(ScatteredKernels::new(file.clone(), Prefer::Kernel))
}

/// Deblurs a whole capture and writes it as `out` says: 16-bit linear PNG or TIFF (full
/// resolution, RAW mosaics interpolated), or DNG for a RAW photo
/// ([`crate::deblur::output::deblur_and_write`]).
///
/// # Errors
/// The source failed, the file cannot be written, or the job was cancelled.
pub fn export_deblurred(
    cap: &Capture,
    source: &dyn KernelSource,
    opts: &DeblurOptions,
    out: &Path,
    original_file_name: Option<String>,
    note: &str,
    job: &JobContext,
) -> Result<crate::deblur::output::Written, String> {
    use crate::deblur::output::{DeblurWriteError, deblur_and_write};
    deblur_and_write(cap, source, opts, out, original_file_name, note, job).map_err(|e| match e {
        DeblurWriteError::Deblur(e) => format!("{}: {e}", out.display()),
        DeblurWriteError::Output(e) => e.to_string(),
    })
}

/// A plot's data as the studio draws it, for saving beside its picture: the axes'
/// titles and every named series of (x, y) points.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotTable {
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<(String, Vec<[f64; 2]>)>,
}

/// A CSV field, quoted when it holds a comma, a quote or a line break (axis titles
/// such as "σ, px" do).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// The table as CSV: a header `series,<x axis>,<y axis>`, then one row per point.
/// Points with a non-finite coordinate are not drawn, so they are left out here too.
#[must_use]
pub fn plot_csv(table: &PlotTable) -> String {
    let mut out = format!(
        "series,{},{}\n",
        csv_field(&table.x_label),
        csv_field(&table.y_label)
    );
    for (name, points) in &table.series {
        let name = csv_field(name);
        for [x, y] in points
            .iter()
            .filter(|p| p[0].is_finite() && p[1].is_finite())
        {
            out.push_str(&format!("{name},{x},{y}\n"));
        }
    }
    out
}

/// A cross-validation curve's points: mean error against α, or against β.
#[must_use]
pub fn cv_curve(sel: &crate::crossval::Selection, by_alpha: bool) -> Vec<[f64; 2]> {
    let curve = if by_alpha {
        &sel.alpha_curve
    } else {
        &sel.beta_curve
    };
    curve
        .iter()
        .map(|p| [if by_alpha { p.alpha } else { p.beta } as f64, p.mean_pct])
        .collect()
}

/// The error CDF's curves of one chosen model, one per parameter: (error, percentile).
#[must_use]
pub fn cv_cdf_curves(sel: &crate::crossval::Selection) -> [(&'static str, Vec<[f64; 2]>); 3] {
    let cdf = &sel.error_cdf;
    let curve = |q: &[f64]| -> Vec<[f64; 2]> {
        q.iter()
            .zip(&cdf.percentiles)
            .map(|(&e, &p)| [e, p])
            .collect()
    };
    [
        ("C_xx", curve(&cdf.cxx)),
        ("C_yy", curve(&cdf.cyy)),
        ("C_or", curve(&cdf.cor)),
    ]
}

/// Writes a rectangle `[x0, y0, x1, y1]` (pixels, clamped to the image) of an RGBA
/// image `width` × `height` as a PNG, atomically: a plot cut out of a window's
/// screenshot.
pub fn write_png_crop(
    path: &Path,
    rgba: Vec<u8>,
    width: usize,
    height: usize,
    rect: [usize; 4],
) -> Result<(), String> {
    let to_u32 =
        |v: usize| u32::try_from(v).map_err(|_| format!("an image {v} px wide is too large"));
    let img = image::RgbaImage::from_raw(to_u32(width)?, to_u32(height)?, rgba)
        .ok_or_else(|| format!("the screenshot's pixels do not fill {width} × {height}"))?;
    let (x0, y0) = (rect[0].min(width), rect[1].min(height));
    let (x1, y1) = (rect[2].clamp(x0, width), rect[3].clamp(y0, height));
    if x1 == x0 || y1 == y0 {
        return Err("the plot is not on screen".into());
    }
    let crop = image::imageops::crop_imm(
        &img,
        to_u32(x0)?,
        to_u32(y0)?,
        to_u32(x1 - x0)?,
        to_u32(y1 - y0)?,
    )
    .to_image();
    let mut bytes = Vec::new();
    crop.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| format!("cannot encode the PNG: {e}"))?;
    crate::io::write_atomic(path, &bytes).map_err(|e| e.to_string())
}

/// Largest rise of a measured kernel's tails (a fraction of its weight) before the
/// studio marks the kernel as a noisy estimate.
///
/// Criterion ([`kernel_tails`]): seen at the sensor's resolution (the kernel averaged
/// over a 1-px box), walk outwards from the kernel's core (the centroid of its samples
/// at or above half the peak) along rays, and add up every rise — how much each sample
/// outside the 3σ ellipse of the kernel's robust Gaussian fit exceeds the sample one px
/// nearer the core — as a fraction of the kernel's weight Σ|k|. A lens's blur falls
/// off away from its core: a Gaussian, a defocus disc, a comet's tail and a diffraction
/// halo all do, however much weight they carry out there (the aberrated lens keeps up to
/// 30 % of its weight outside 3σ). Stripes and speckle rise and fall, and every rise
/// counts.
///
/// Why 0.06, on the simulator (`clean_simulated_kernels_pass_and_striped_tails_are_flagged`:
/// 16 true kernels per shape over the field and the settings' corners, on a measured
/// kernel's support, cleaned as the measurement cleans them):
/// - every shape's true kernels rise by 0.0000, and by at most 0.0030 with the
///   simulator's measured-kernel noise (1 % of the peak per sample);
/// - the measured chain itself (simulated 1200 × 800 shots of the 24 × 16 chart at
///   24 mm and 105 mm, f/4; detected and measured, 2 × 1152 kernels) leaves speckle in
///   the tails: median 0.024, 95th percentile 0.043 and 0.038, largest 0.0625 and
///   0.0775; 3 of the 2304 lie above 0.06;
/// - the true Gaussian kernels with stripes of 10 % of the peak, 2 px apart, beyond
///   2σ rise by 0.062 to 0.18 (5 % stripes: 0.044 to 0.19).
///
/// So a flag means the estimate is worse than the measurement's own speckle on a clean
/// shot, as badly as visibly striped tails.
pub const NOISY_TAIL_FRACTION: f64 = 0.06;

/// What the noisy-kernel criterion measures of one kernel (see
/// [`NOISY_TAIL_FRACTION`]): fractions of its absolute weight Σ|k|.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelTails {
    /// Outside the 3σ ellipse of the fit.
    pub outside: f64,
    /// How much the kernel rises outside that ellipse, walking outwards from its core:
    /// Σ max(0, k(p) − k(p′)) over the samples p outside, with p′ one sample nearer the
    /// core along the ray through p. A lens's blur falls off away from its core (a
    /// halo, a comet's tail, a disc's edge all do); stripes and speckle rise and fall.
    pub rising: f64,
}

/// The kernel averaged over a 1-px box (`oversample` samples a side, rounded up to odd),
/// zero outside.
fn box_1px(kernel: &Kernel) -> Vec<f64> {
    let n = kernel.size;
    let r = (kernel.oversample / 2) as isize;
    let pass = |src: &[f64], along_x: bool| -> Vec<f64> {
        let mut out = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let mut acc = 0.0;
                for d in -r..=r {
                    let (ii, jj) = if along_x {
                        (i as isize + d, j as isize)
                    } else {
                        (i as isize, j as isize + d)
                    };
                    if ii >= 0 && jj >= 0 && (ii as usize) < n && (jj as usize) < n {
                        acc += src[jj as usize * n + ii as usize];
                    }
                }
                out[j * n + i] = acc / (2 * r + 1) as f64;
            }
        }
        out
    };
    pass(&pass(&kernel.data, true), false)
}

/// `data` (`n` × `n`, row-major) between samples at (u, w), zero outside.
fn bilinear(data: &[f64], n: usize, u: f64, w: f64) -> f64 {
    let (u0, w0) = (u.floor(), w.floor());
    let (fu, fw) = (u - u0, w - w0);
    let get = |i: f64, j: f64| -> f64 {
        if i < 0.0 || j < 0.0 || i >= n as f64 || j >= n as f64 {
            0.0
        } else {
            data[j as usize * n + i as usize]
        }
    };
    (get(u0, w0) * (1.0 - fu) + get(u0 + 1.0, w0) * fu) * (1.0 - fw)
        + (get(u0, w0 + 1.0) * (1.0 - fu) + get(u0 + 1.0, w0 + 1.0) * fu) * fw
}

/// The tails of `kernel` against the 3σ ellipse of `fit` (see [`NOISY_TAIL_FRACTION`]);
/// `None` for an empty kernel or a degenerate fit.
#[must_use]
pub fn kernel_tails(kernel: &Kernel, fit: &Gaussian2) -> Option<KernelTails> {
    let (vx, vy, cxy) = (
        fit.sigma_x * fit.sigma_x,
        fit.sigma_y * fit.sigma_y,
        fit.cov_xy(),
    );
    let det = vx * vy - cxy * cxy;
    let n = kernel.size;
    if !(det.is_finite() && det > 0.0)
        || n == 0
        || kernel.oversample == 0
        || kernel.data.len() != n * n
    {
        return None;
    }
    let c = (n / 2) as f64;
    let os = kernel.oversample as f64;
    let peak = kernel.data.iter().copied().fold(0.0, f64::max);
    if peak <= 0.0 {
        return None;
    }
    // The core's centroid: the tails themselves must not move the ellipse they are
    // measured against.
    let (mut w0, mut mx, mut my) = (0.0, 0.0, 0.0);
    for j in 0..n {
        for i in 0..n {
            let v = kernel.at(i, j);
            if v >= 0.5 * peak {
                w0 += v;
                mx += v * (i as f64 - c) / os;
                my += v * (j as f64 - c) / os;
            }
        }
    }
    let (mx, my) = (mx / w0, my / w0);
    // Seen at the sensor's resolution (a 1-px box): sample noise averages down, while
    // stripes the sensor resolves (2 px apart or more) stay.
    let smooth = box_1px(kernel);
    let (mut total, mut outside, mut rising) = (0.0, 0.0, 0.0);
    for j in 0..n {
        for i in 0..n {
            let v = kernel.at(i, j);
            let (dx, dy) = ((i as f64 - c) / os - mx, (j as f64 - c) / os - my);
            let d2 = (vy * dx * dx - 2.0 * cxy * dx * dy + vx * dy * dy) / det;
            total += v.abs();
            if d2 > 9.0 {
                outside += v.abs();
                // One px nearer the core along the ray (bilinear between samples).
                let r = dx.hypot(dy);
                let (u, w) = (i as f64 - dx / r * os, j as f64 - dy / r * os);
                let inward = bilinear(&smooth, n, u, w);
                rising += (smooth[j * n + i] - inward).max(0.0);
            }
        }
    }
    (total > 0.0).then(|| KernelTails {
        outside: outside / total,
        rising: rising / total,
    })
}

/// The fraction the criterion compares with [`NOISY_TAIL_FRACTION`].
#[must_use]
pub fn kernel_tail_fraction(kernel: &Kernel, fit: &Gaussian2) -> Option<f64> {
    kernel_tails(kernel, fit).map(|t| t.rising)
}

/// Why a measured kernel is not to be trusted, in one line, or `None` where it passes
/// (see [`NOISY_TAIL_FRACTION`]).
#[must_use]
pub fn noisy_kernel_reason(kernel: &Kernel, fit: &Gaussian2) -> Option<String> {
    let t = kernel_tail_fraction(kernel, fit)?;
    (t > NOISY_TAIL_FRACTION).then(|| {
        format!(
            "noisy estimate: its tails beyond 3σ rise again by {:.1} % of its weight (a lens's blur only falls off there; flagged above {:.1} %): stripes or speckle, not the lens",
            100.0 * t,
            100.0 * NOISY_TAIL_FRACTION
        )
    })
}

/// One point of a difference map: the Gaussians of field A and field B at (about) the
/// same sensor position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldDifference {
    pub x: f64,
    pub y: f64,
    pub a: Gaussian2,
    pub b: Gaussian2,
}

impl FieldDifference {
    /// σ(A) − σ(B), px: what the difference map colours.
    #[must_use]
    pub fn delta_sigma(&self) -> f64 {
        self.a.sigma() - self.b.sigma()
    }
}

/// Pairs each point of field `a` with the nearest point of field `b` within
/// `max_distance` px (points of `a` with none are left out): the difference map of A
/// − B, at A's positions.
#[must_use]
pub fn field_difference(
    a: &[(f64, f64, Gaussian2)],
    b: &[(f64, f64, Gaussian2)],
    max_distance: f64,
) -> Vec<FieldDifference> {
    a.iter()
        .filter_map(|&(x, y, ga)| {
            let d2 = |p: &(f64, f64, Gaussian2)| (p.0 - x).powi(2) + (p.1 - y).powi(2);
            let nearest = b.iter().min_by(|p, q| d2(p).total_cmp(&d2(q)))?;
            (d2(nearest) <= max_distance * max_distance).then_some(FieldDifference {
                x,
                y,
                a: ga,
                b: nearest.2,
            })
        })
        .collect()
}

/// A profile's predicted Gaussians at sensor `points` and `setting`.
///
/// # Errors
/// The profile cannot predict at some point: the first failure, one line.
pub fn predicted_at(
    profile: &Profile,
    channel: Channel,
    points: &[[f64; 2]],
    setting: LensSetting,
) -> Result<Vec<(f64, f64, Gaussian2)>, String> {
    points
        .iter()
        .map(|&[x, y]| {
            profile
                .predict(channel, x, y, setting)
                .map(|g| (x, y, g))
                .map_err(|e| e.to_string())
        })
        .collect()
}

/// The colour range of a map from its finite `values`: [min, max], or for a difference
/// map (`symmetric`) [−m, m] with m the largest magnitude, so that white is exactly 0.
/// Never empty: a constant field gets a small span around its value.
#[must_use]
pub fn colour_range(values: impl IntoIterator<Item = f64>, symmetric: bool) -> Option<[f64; 2]> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.into_iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return None;
    }
    if symmetric {
        let m = lo.abs().max(hi.abs()).max(1e-3);
        return Some([-m, m]);
    }
    if hi - lo < 1e-3 {
        return Some([lo - 0.05, hi + 0.05]);
    }
    Some([lo, hi])
}

/// Round tick values (1, 2 or 5 × 10ⁿ apart) inside `range`, about `n` of them: a
/// colour bar's labels.
#[must_use]
pub fn nice_ticks(range: [f64; 2], n: usize) -> Vec<f64> {
    let [lo, hi] = range;
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Vec::new();
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last)
        // Ticks at multiples of the step, so 0 is exact on a symmetric bar.
        .map(|k| k as f64 * step)
        .collect()
}

/// How serious a piece of shooting advice is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdviceLevel {
    /// The session cannot determine the model asked for (or any that follows a
    /// setting).
    Warning,
    /// The model is determined but limited by the settings shot.
    Note,
}

/// What the session's settings allow the model, and what to shoot next.
#[derive(Clone, Debug, PartialEq)]
pub struct ShootingAdvice {
    pub level: AdviceLevel,
    pub text: String,
}

/// Where one more value of a setting tells the model most: the middle of the widest gap
/// between the values shot (in stops for apertures, as the slider moves).
fn widest_gap(values: &[f64], aperture: bool) -> Option<(f64, f64)> {
    values.windows(2).map(|w| (w[0], w[1])).max_by(|a, b| {
        let span = |(lo, hi): (f64, f64)| if aperture { (hi / lo).ln() } else { hi - lo };
        span(*a).total_cmp(&span(*b))
    })
}

/// What the settings shot (the distinct focal lengths and f-numbers, sorted) allow the
/// model in focal length and aperture, for a β fixed by the session's settings or
/// chosen by cross-validation (`None`): the model's β-order polynomial in f and a needs
/// β + 1 distinct values of each setting that varies (β < N = min(N_f, N_a)), and a
/// setting shot at one value only cannot be followed at all. Each problem comes with
/// what to shoot next.
#[must_use]
pub fn shooting_advice(
    focals: &[f64],
    f_numbers: &[f64],
    beta: Option<usize>,
) -> Vec<ShootingAdvice> {
    let mut out = Vec::new();
    if focals.is_empty() || f_numbers.is_empty() {
        return out;
    }
    let fmt_f = |v: f64| format!("{v:.0} mm");
    let fmt_a = |v: f64| format!("f/{v:.1}");
    // Name, values shot, whether in stops (apertures), how a value reads.
    type Dim<'a> = (&'a str, &'a [f64], bool, &'a dyn Fn(f64) -> String);
    let dims: [Dim; 2] = [
        ("focal length", focals, false, &fmt_f),
        ("aperture", f_numbers, true, &fmt_a),
    ];
    for (name, values, _, fmt) in dims {
        if values.len() == 1 {
            out.push(ShootingAdvice {
                level: AdviceLevel::Warning,
                text: format!(
                    "Every shot is at {}: the model cannot follow the {name}, and the profile predicts nowhere else. Shoot at least one more {name} (the range's other end first).",
                    fmt(values[0])
                ),
            });
        }
    }
    let varying: Vec<_> = dims.iter().filter(|d| d.1.len() > 1).collect();
    let n = varying.iter().map(|d| d.1.len()).min().unwrap_or(1);
    let need = beta.map_or(2, |b| b + 1);
    for (name, values, aperture, fmt) in &varying {
        if values.len() >= need.max(3) {
            continue;
        }
        let Some((lo, hi)) = widest_gap(values, *aperture) else {
            continue;
        };
        let more = need.max(3) - values.len();
        let shoot = format!(
            "shoot at least {more} more {name}{} between {} and {}",
            if more == 1 { "" } else { "s" },
            fmt(lo),
            fmt(hi)
        );
        match beta {
            Some(b) if values.len() <= b => out.push(ShootingAdvice {
                level: AdviceLevel::Warning,
                text: format!(
                    "β = {b} (the session's setting) needs {} distinct {name}s, the session has {}: the model is not determined; {shoot}, or lower β.",
                    b + 1,
                    values.len()
                ),
            }),
            _ if values.len() == 2 && n == 2 => out.push(ShootingAdvice {
                level: AdviceLevel::Note,
                text: format!(
                    "With 2 {name}s the model is at most linear in {name} (β ≤ 1); to let it curve, {shoot}."
                ),
            }),
            _ => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{BlurSample, ShotInfo};
    use crate::plane::CameraIdentity;

    /// A comet lens's session with measured kernels, calibrated with and without shape
    /// models, and one shot's samples as a kernels file.
    fn comet_profiles() -> (Profile, Profile, KernelsFile) {
        use crate::calibrate::{CalibrateOptions, Families, calibrate};
        use crate::kernel::file::{KERNELS, KernelData, KernelSample};
        use crate::simulate::{PsfShape, SimulatedSession, VirtualLens};
        let lens = VirtualLens {
            shape: PsfShape::Comet,
            ..VirtualLens::demo()
        };
        let mut settings = Vec::new();
        for focal_mm in [24.0, 60.0, 105.0] {
            for f_number in [4.0, 10.0] {
                settings.push(LensSetting { focal_mm, f_number });
            }
        }
        let ds = SimulatedSession {
            cols: 6,
            rows: 4,
            kernel_noise: Some(0.01),
            seed: 3,
            ..SimulatedSession::new(240, 160)
        }
        .dataset(&lens, &settings);
        let opts = CalibrateOptions {
            families: crate::calibrate::Families::Global,
            alpha: Some(2),
            beta: Some(1),
            ..CalibrateOptions::default()
        };
        let job = JobContext::silent();
        let (with_shape, _) = calibrate(&ds, None, &opts, &job).expect("calibrate");
        let (without, _) = calibrate(
            &ds,
            None,
            &CalibrateOptions {
                shape: None,
                families: Families::Global,
                ..opts
            },
            &job,
        )
        .expect("calibrate");
        let shot = &ds.shots[0];
        let samples = ds
            .samples
            .iter()
            .filter(|s| s.shot == 0)
            .map(|s| KernelSample {
                x: s.x,
                y: s.y,
                channel: s.channel,
                cxx: Some(s.gaussian.sigma_x),
                cyy: Some(s.gaussian.sigma_y),
                cor: Some(s.gaussian.rho),
                row: None,
                col: None,
                ml: None,
                kernel: s.kernel.as_ref().map(|k| KernelData {
                    size: k.size,
                    data: k.data.clone(),
                }),
            })
            .collect();
        let file = KernelsFile {
            schema: KERNELS.tag(),
            width: ds.width,
            height: ds.height,
            focal_mm: Some(shot.focal_mm),
            f_number: Some(shot.f_number),
            oversample: 3,
            identity: None,
            source: None,
            samples,
            failed: Vec::new(),
        };
        (with_shape, without, file)
    }

    #[test]
    fn predicted_kernel_errors_favour_shapes_on_a_comet_lens() {
        let (with_shape, without, file) = comet_profiles();
        assert!(with_shape.shape.is_some(), "the comet's shapes were kept");
        assert_eq!(no_shape_reason(&with_shape), None);
        let reason = no_shape_reason(&without).expect("no shape model");
        assert!(reason.contains("no shape cross-validation"), "{reason}");

        let errors = kernel_errors(&with_shape, &file, Channel::G);
        assert_eq!(errors.len(), file.samples.len());
        let judged: Vec<KernelError> = errors.iter().flatten().copied().collect();
        let greens = file
            .samples
            .iter()
            .filter(|s| s.channel == Channel::G)
            .count();
        assert_eq!(judged.len(), greens, "every green sample judged");
        let mean = |f: &dyn Fn(&KernelError) -> f64| {
            judged.iter().map(f).sum::<f64>() / judged.len() as f64
        };
        let gaussian = mean(&|e| e.gaussian);
        let shape = mean(&|e| e.shape.unwrap_or(f64::NAN));
        assert!(shape < gaussian, "shapes {shape} vs Gaussian {gaussian}");
        // Without a shape model only the Gaussian is judged, and identically.
        let plain = kernel_errors(&without, &file, Channel::G);
        assert!(plain.iter().flatten().all(|e| e.shape.is_none()));

        let points = [[40.0, 30.0], [120.0, 80.0]];
        let s = LensSetting {
            focal_mm: file.focal_mm.unwrap_or(24.0),
            f_number: file.f_number.unwrap_or(4.0),
        };
        let shapes = predicted_kernels(&with_shape, KernelModel::Shape, Channel::G, &points, s)
            .expect("shape kernels");
        let gaussians =
            predicted_kernels(&with_shape, KernelModel::Gaussian, Channel::G, &points, s)
                .expect("Gaussian kernels");
        assert_eq!(shapes.len(), 2);
        assert_eq!((shapes[1].x, shapes[1].y), (120.0, 80.0));
        assert!(relative_l2(&shapes[0].kernel, &gaussians[0].kernel) > 1e-3);
        assert!(
            predicted_kernels(&without, KernelModel::Shape, Channel::G, &points, s).is_err(),
            "no shape model, no shape kernels"
        );
    }

    #[test]
    fn regions_stay_inside_and_even() {
        let r = Region::around(5.0, 3.0, 64, 100, 80);
        assert_eq!((r.x0, r.y0, r.width, r.height), (0, 0, 64, 64));
        let r = Region::around(99.0, 79.0, 64, 101, 80);
        assert_eq!((r.x0 + r.width <= 101, r.y0 + r.height <= 80), (true, true));
        assert_eq!((r.x0 % 2, r.y0 % 2), (0, 0));
        let r = Region::around(50.0, 40.0, 500, 100, 80);
        assert_eq!((r.width, r.height), (100, 80));
        let g = Region::around(50.0, 40.0, 20, 100, 80).grown(13, 100, 80);
        assert_eq!((g.x0 % 2, g.y0 % 2, g.width % 2), (0, 0, 0));
        assert!(g.x0 + g.width <= 100 && g.y0 + g.height <= 80);
    }

    #[test]
    fn crops_keep_sensor_positions() {
        // A Bayer-like capture: an R plane at even sites, values = sensor x + 1000 y.
        let (w, h) = (40, 30);
        let plane = Plane::from_fn(w / 2, h / 2, |i, j| (2 * i + 1000 * 2 * j) as f32);
        let cap = Capture {
            width: w,
            height: h,
            planes: vec![ChannelPlane {
                channel: Channel::R,
                plane,
                step: 2,
                offset_x: 0,
                offset_y: 0,
            }],
            setting_focal_mm: None,
            setting_f_number: None,
            identity: CameraIdentity::default(),
            is_raw: true,
            raw: None,
        };
        let r = Region::around(20.0, 15.0, 10, w, h);
        let c = crop_capture(&cap, r);
        let cp = &c.planes[0];
        let [x, y] = cp.sensor_from_plane(1.0, 2.0);
        let v = cp.plane.get(1, 2);
        assert_eq!(v, (x as usize + r.x0 + 1000 * (y as usize + r.y0)) as f32);
    }

    #[test]
    fn truth_field_and_curve_are_the_pixel_truth_at_their_points() {
        let lens = crate::simulate::VirtualLens::demo();
        let size = (120, 80);
        let s = LensSetting {
            focal_mm: lens.focal_range_mm[0],
            f_number: lens.f_number_range[0],
        };
        let field = truth_field(&lens, Channel::G, size, (3, 2), s);
        let grid = field_grid(size.0, size.1, 3, 2);
        assert_eq!(field.len(), grid.len());
        for ((x, y, g), [gx, gy]) in field.iter().zip(&grid) {
            assert_eq!((*x, *y), (*gx, *gy));
            assert_eq!(
                *g,
                truth_pixel_gaussian(&lens, Channel::G, (*x, *y), size, s)
            );
        }
        let settings = sweep_settings(lens.f_number_range, s.focal_mm, true, 4);
        let curve = truth_curve(&lens, Channel::R, (10.0, 20.0), size, &settings);
        assert_eq!(curve.len(), settings.len());
        assert!(curve.iter().zip(&settings).all(|((a, _), b)| a == b));
    }

    #[test]
    fn sweep_points_follow_the_fixed_setting() {
        let mut ds = Dataset::new(100, 100, CameraIdentity::default());
        let g = |s: f64| Gaussian2::isotropic(s);
        for (f, a) in [(24.0, 4.0), (24.0, 8.0), (50.0, 4.0)] {
            let samples = [(10.0, 10.0, 1.0), (90.0, 90.0, 2.0)].map(|(x, y, s)| BlurSample {
                shot: 0,
                x,
                y,
                focal_mm: 0.0,
                f_number: 0.0,
                channel: Channel::G,
                gaussian: g(s * a / 4.0),
                square: None,
                kernel: None,
            });
            ds.push_shot(
                ShotInfo {
                    name: format!("{f}-{a}"),
                    focal_mm: f,
                    f_number: a,
                },
                samples,
            );
        }
        let p = sweep_points(&ds, Channel::G, (80.0, 85.0), true, 24.0);
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].setting.f_number, 4.0);
        assert_eq!((p[1].x, p[1].gaussian.sigma_x), (90.0, 4.0));
        let q = sweep_points(&ds, Channel::G, (0.0, 0.0), false, 4.0);
        assert_eq!(
            q.iter().map(|p| p.setting.focal_mm).collect::<Vec<_>>(),
            [24.0, 50.0]
        );
        assert!(sweep_points(&ds, Channel::R, (0.0, 0.0), false, 4.0).is_empty());
        assert_eq!(nearest_value(&[4.0, 5.6, 10.0], 6.0), Some(5.6));
    }

    /// The tail fraction of the simulator's true kernels (each shape, over the field and
    /// the settings, clean and with the simulated measurement noise) and of the same
    /// clean kernels with striped tails added: the numbers behind
    /// [`NOISY_TAIL_FRACTION`] (shown with --nocapture).
    fn truth_tail_fractions(
        shape: crate::simulate::PsfShape,
        noise: f64,
        stripes: f64,
    ) -> (f64, f64) {
        use crate::simulate::VirtualLens;
        let lens = VirtualLens {
            shape,
            ..VirtualLens::demo()
        };
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        let mut seed = 7u64;
        for (u, v) in [(0.0, 0.0), (0.9, 0.0), (-0.9, 0.6), (0.7, -0.7)] {
            for focal_mm in [24.0, 105.0] {
                for f_number in [4.0, 10.0] {
                    let s = LensSetting { focal_mm, f_number };
                    let mut k = padded(
                        &lens
                            .optical_kernel_uv(Channel::G, u, v, s, 3)
                            .pixel_integrated(),
                        MEASURED_SIZE,
                    );
                    let peak = k.data.iter().copied().fold(0.0, f64::max);
                    let fit = crate::gaussian::fit_gaussians(&k).0;
                    let c = (k.size / 2) as f64;
                    for j in 0..k.size {
                        for i in 0..k.size {
                            let (dx, dy) = ((i as f64 - c) / 3.0, (j as f64 - c) / 3.0);
                            // A fixed pseudo-random draw per sample (uniform, the
                            // simulator's 1 % of the peak as its standard deviation).
                            seed = seed
                                .wrapping_mul(6_364_136_223_846_793_005)
                                .wrapping_add(1_442_695_040_888_963_407);
                            let r =
                                ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 12f64.sqrt();
                            let d = (dx / fit.sigma_x).hypot(dy / fit.sigma_y);
                            // Stripes across x, 2 px apart (the sensor's Nyquist),
                            // beyond 2σ: the ringing of a poorly constrained solve.
                            let stripe = if d > 2.0 {
                                stripes * peak * 0.5 * (1.0 + (std::f64::consts::PI * dx).cos())
                            } else {
                                0.0
                            };
                            let v = &mut k.data[j * k.size + i];
                            *v += noise * peak * r + stripe;
                            // As the measurement cleans a kernel: negatives and samples
                            // under 2 % of the peak are zeroed.
                            if *v < 0.02 * peak {
                                *v = 0.0;
                            }
                        }
                    }
                    k.normalise();
                    let tails = kernel_tails(&k, &crate::gaussian::fit_gaussians(&k).0)
                        .expect("a fraction");
                    let t = tails.rising;
                    lo = lo.min(t);
                    hi = hi.max(t);
                }
            }
        }
        eprintln!("{shape:?} noise {noise} stripes {stripes}: tail fraction {lo:.4}–{hi:.4}");
        (lo, hi)
    }

    /// The side the measured chain gives kernels of the demo's σ (±6 px at 3×): the
    /// support a measured kernel's stripes and speckle can spread over.
    const MEASURED_SIZE: usize = 37;

    /// `k` centred in an `n` × `n` array (or as it is, if larger).
    fn padded(k: &Kernel, n: usize) -> Kernel {
        if k.size >= n {
            return k.clone();
        }
        let off = (n - k.size) / 2;
        let mut data = vec![0.0; n * n];
        for j in 0..k.size {
            for i in 0..k.size {
                data[(j + off) * n + i + off] = k.at(i, j);
            }
        }
        Kernel {
            size: n,
            oversample: k.oversample,
            data,
        }
    }

    #[test]
    fn clean_simulated_kernels_pass_and_striped_tails_are_flagged() {
        use crate::simulate::PsfShape;
        for shape in [
            PsfShape::Gaussian,
            PsfShape::Disc,
            PsfShape::Comet,
            PsfShape::Aberrated,
        ] {
            let (_, clean) = truth_tail_fractions(shape, 0.0, 0.0);
            assert!(clean < NOISY_TAIL_FRACTION / 2.0, "{shape:?}: {clean}");
            let (_, noisy) = truth_tail_fractions(shape, 0.01, 0.0);
            assert!(noisy < NOISY_TAIL_FRACTION, "{shape:?} with noise: {noisy}");
        }
        let (striped, _) = truth_tail_fractions(PsfShape::Gaussian, 0.0, 0.1);
        assert!(striped > NOISY_TAIL_FRACTION, "striped: {striped}");
        // One kernel, both ways, through the reason the studio shows.
        let g = Gaussian2 {
            sigma_x: 1.2,
            sigma_y: 0.9,
            rho: 0.2,
        };
        let clean = padded(&g.kernel(3), MEASURED_SIZE);
        assert_eq!(noisy_kernel_reason(&clean, &g), None);
        let mut striped = clean.clone();
        let peak = striped.data.iter().copied().fold(0.0, f64::max);
        let c = (striped.size / 2) as f64;
        for j in 0..striped.size {
            for i in 0..striped.size {
                let dx = (i as f64 - c) / 3.0;
                let dy = (j as f64 - c) / 3.0;
                if (dx / 1.2).hypot(dy / 0.9) > 2.0 {
                    striped.data[j * striped.size + i] +=
                        0.1 * peak * 0.5 * (1.0 + (std::f64::consts::PI * dx).cos());
                }
            }
        }
        striped.normalise();
        let reason = noisy_kernel_reason(&striped, &g).expect("flagged");
        assert!(reason.contains("rise again"), "{reason}");
    }

    #[test]
    fn difference_maps_pair_points_and_ranges_are_symmetric() {
        let g = |s: f64| Gaussian2::isotropic(s);
        let a = [
            (0.0, 0.0, g(2.0)),
            (100.0, 0.0, g(1.0)),
            (500.0, 0.0, g(1.0)),
        ];
        let b = [(1.0, 1.0, g(1.5)), (100.0, 2.0, g(1.25))];
        let d = field_difference(&a, &b, 10.0);
        assert_eq!(d.len(), 2, "the far point has no partner");
        assert!((d[0].delta_sigma() - 0.5).abs() < 1e-12);
        assert!((d[1].delta_sigma() + 0.25).abs() < 1e-12);
        assert_eq!(
            colour_range(d.iter().map(FieldDifference::delta_sigma), true),
            Some([-0.5, 0.5])
        );
        assert_eq!(colour_range([1.0, 3.0, f64::NAN], false), Some([1.0, 3.0]));
        assert_eq!(colour_range([], false), None);
        assert_eq!(nice_ticks([-0.5, 0.5], 4), vec![-0.5, 0.0, 0.5]);
        assert_eq!(nice_ticks([0.93, 3.1], 5), vec![1.0, 1.5, 2.0, 2.5, 3.0]);
    }

    #[test]
    fn shooting_advice_says_what_to_shoot_next() {
        // One focal length: the model cannot follow it.
        let a = shooting_advice(&[50.0], &[4.0, 8.0, 16.0], None);
        assert!(
            a.iter()
                .any(|x| x.level == AdviceLevel::Warning
                    && x.text.contains("Every shot is at 50 mm"))
        );
        // β fixed at 2 with two focal lengths: a third between them.
        let b = shooting_advice(&[24.0, 105.0], &[4.0, 5.6, 10.0], Some(2));
        let w = b
            .iter()
            .find(|x| x.level == AdviceLevel::Warning)
            .expect("warning");
        assert!(
            w.text
                .contains("shoot at least 1 more focal length between 24 mm and 105 mm"),
            "{}",
            w.text
        );
        // The demo's 2 × 2 grid: determined for β ≤ 1, with a note for a curve.
        let c = shooting_advice(&[24.0, 105.0], &[4.0, 10.0], None);
        assert!(c.iter().all(|x| x.level == AdviceLevel::Note), "{c:?}");
        assert!(
            c.iter()
                .any(|x| x.text.contains("between f/4.0 and f/10.0"))
        );
        // Enough of both.
        assert!(shooting_advice(&[24.0, 50.0, 105.0], &[4.0, 5.6, 10.0], None).is_empty());
    }

    #[test]
    fn plot_csv_quotes_axis_titles_and_leaves_out_undrawn_points() {
        let t = PlotTable {
            x_label: "aperture (f-number)".into(),
            y_label: "C_xx (σ, px)".into(),
            series: vec![(
                "model centre".into(),
                vec![[4.0, 1.5], [5.6, f64::NAN], [8.0, 2.0]],
            )],
        };
        assert_eq!(
            plot_csv(&t),
            "series,aperture (f-number),\"C_xx (σ, px)\"\nmodel centre,4,1.5\nmodel centre,8,2\n"
        );
    }
}
