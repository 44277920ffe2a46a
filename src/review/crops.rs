//! Crops: a photo region as it is and deblurred with a profile's predicted kernels and
//! with kernels measured on a chart (the paper's Fig. 7–8 comparison), and the kernel
//! sources each is deblurred with.

use crate::deblur::source::{Prefer, ScatteredKernels};
use crate::deblur::{DeblurError, DeblurOptions, KernelSource, ProfileKernels, SourceError};
use crate::develop::{DevelopError, Developed, Orient, develop};
use crate::job::JobContext;
use crate::kernel::file::KernelsFile;
use crate::plane::{Capture, Channel, ChannelPlane, LensSetting, Plane};
use crate::profile::Profile;
use crate::psf::Kernel;

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
        setting_focus_m: cap.setting_focus_m,
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

    fn placed_gaussian(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
    ) -> Result<Option<crate::deblur::PlacedGaussian>, SourceError> {
        self.inner
            .placed_gaussian(channel, x + self.dx, y + self.dy)
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
