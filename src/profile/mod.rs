//! Lens profiles (docs/formats.md, "Lens profile"): the fitted models of one camera + lens unit in a
//! versioned JSON file, `lensblur.profile/4` (versions 1–3 read too).
//!
//! Coefficients are stored as base64 of little-endian `f32` (7 significant digits, far
//! below the measurement noise): a G_{8,3} profile of three channels is about 17 kB (the
//! paper: ≈ 12 kB), an L_{1,3} one 50–160 kB depending on the chart's scale (≈ 200 kB).
//! Loading validates the schema and every number before it sizes anything (sensor and
//! grid sizes with checked arithmetic, ranges, orders, term and coefficient counts), so
//! a damaged or hostile file is refused with one line naming it; predicting refuses
//! another camera's photos (unless forced), and settings outside the calibrated ranges
//! or outside the hull of the calibrated settings (unless extrapolation is explicitly
//! allowed) — never a silent extrapolation in f and a. Over the sensor, where the chart
//! did not reach, the models continue linearly from the border of the measured area
//! (`lensblur predict` says so). Fitting a profile is [`crate::calibrate`]'s.

use crate::chart::ChartSpec;
use crate::crossval::ShapeCvReport;
use crate::crossval::{CvPoint, CvReport, Ranges};
use crate::model::{
    CentreGrid, ChannelCoeffs, FieldAtSetting, FittedModel, GlobalModel, LocalModel, MAX_ORDER,
    ModelKind, Normalisation, model_basis, to_gaussian,
};
use crate::model::{KernelModel, LateralColour, PlacedShape, ShapeModel};
use crate::plane::{
    CameraIdentity, Channel, LensSetting, PictureKind, f_number_text, focal_text, short_number,
};
use crate::psf::{Gaussian2, Kernel};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub mod trust;
pub use trust::{
    FOCUS_AS_INFINITY_M, FOCUS_FACTOR, FocusRange, LARGE_ERROR_PCT, SettingTrust, TRUST_ZONES,
    Trust, TrustWarning, warning_line,
};

/// The profile's version.
/// Version 2 adds the kernel-shape model and its cross-validation; a version-1 file
/// reads as a profile without one (its kernels are its Gaussians). Version 3 adds
/// where the profile is trusted (held-out errors per setting and zone; a version-2
/// file has none recorded). Version 4 adds where each channel's kernels are centred
/// (where its centroid lies, lateral colour included); earlier files centre every kernel's
/// Gaussian on its pixel as they were read before.
pub const PROFILE: crate::format::Schema = crate::format::Schema {
    kind: "profile",
    current: 4,
    unversioned: None,
};

use crate::limits::{MAX_LOCAL_CENTRES, MAX_SENSOR_SIDE_PX};

/// The oversampling of the kernels a profile predicts for deblurring.
pub const KERNEL_OVERSAMPLE: usize = 3;

/// Errors of reading, writing and using a profile.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    #[error("{path}: {reason}")]
    File { path: String, reason: String },
    #[error("{path}: {reason}")]
    Schema { path: String, reason: String },
    #[error("{path}: invalid profile: {reason}")]
    Invalid { path: String, reason: String },
    #[error(
        "the profile is for another camera or lens: {field} is '{profile}' in the profile but '{photo}' in the photo"
    )]
    IdentityMismatch {
        field: String,
        profile: String,
        photo: String,
    },
    #[error(
        "{} is outside the calibrated range {}–{}, {}–{}: the models would extrapolate",
        LensSetting { focal_mm: *focal_mm, f_number: *f_number },
        short_number(*f0),
        focal_text(*f1),
        f_number_text(*a0),
        f_number_text(*a1)
    )]
    OutOfRange {
        focal_mm: f64,
        f_number: f64,
        f0: f64,
        f1: f64,
        a0: f64,
        a1: f64,
    },
    #[error(
        "{} is inside the calibrated ranges but not among the calibrated settings (outside their convex hull): the models would extrapolate",
        LensSetting { focal_mm: *focal_mm, f_number: *f_number }
    )]
    BetweenRanges { focal_mm: f64, f_number: f64 },
    #[error("the profile holds no {0:?} model")]
    NoModel(ModelKind),
    #[error(
        "the profile holds no kernel-shape model (cross-validation found the Gaussians predict its kernels as well, or it was calibrated without kernels): use the Gaussian kernel model"
    )]
    NoShapeModel,
    #[error("the profile has no model for channel {0}")]
    NoChannel(Channel),
}

/// Summary of the cross-validation the models were chosen by.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CvSummary {
    pub folds: usize,
    pub ranges: Ranges,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub global: Option<CvPoint>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local: Option<CvPoint>,
}

impl CvSummary {
    #[must_use]
    pub fn from_report(r: &CvReport) -> Self {
        Self {
            folds: r.folds,
            ranges: r.ranges,
            global: r.global.as_ref().map(|s| s.chosen.clone()),
            local: r.local.as_ref().map(|s| s.chosen.clone()),
        }
    }
}

#[derive(Serialize, Deserialize)]
struct StoredChannel {
    channel: Channel,
    /// base64 of little-endian f32, `[centre][term]` order for a local model.
    cxx: String,
    cyy: String,
    cor: String,
}

#[derive(Serialize, Deserialize)]
struct StoredGlobal {
    alpha: usize,
    beta: usize,
    terms: usize,
    channels: Vec<StoredChannel>,
}

#[derive(Serialize, Deserialize)]
struct StoredLocal {
    alpha: usize,
    beta: usize,
    terms: usize,
    radius_px: f64,
    centres_x: usize,
    centres_y: usize,
    channels: Vec<StoredChannel>,
}

/// The kernel-shape model as stored: its components on the whitened grid (component
/// after component, row-major) and per channel each component's coefficients over the
/// G_{α,β} basis (component after component).
#[derive(Serialize, Deserialize)]
struct StoredShape {
    /// Where the shape is described (files without it: whitened).
    #[serde(default)]
    space: crate::model::ShapeSpace,
    alpha: usize,
    beta: usize,
    terms: usize,
    components: usize,
    /// Samples per side of the whitened grid, and per σ: a grid this build does not use
    /// is refused rather than misread.
    grid_side: usize,
    grid_per_sigma: usize,
    basis: String,
    channels: Vec<StoredShapeChannel>,
}

#[derive(Serialize, Deserialize)]
struct StoredShapeChannel {
    channel: Channel,
    coefficients: String,
}

#[derive(Serialize, Deserialize)]
struct ProfileFile {
    schema: String,
    #[serde(default)]
    identity: CameraIdentity,
    #[serde(default)]
    chart: Option<ChartSpec>,
    width: usize,
    height: usize,
    focal_range_mm: [f64; 2],
    f_number_range: [f64; 2],
    /// Bounding box [x0, y0, x1, y1] of the measured squares; outside it predictions
    /// extrapolate linearly from its border.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sampled_extent_px: Option<[f64; 4]>,
    /// How f and a are normalised, for readers of the file.
    #[serde(default)]
    normalisation: String,
    #[serde(default)]
    calibrated_settings: Vec<LensSetting>,
    preferred: ModelKind,
    #[serde(default)]
    global: Option<StoredGlobal>,
    #[serde(default)]
    local: Option<StoredLocal>,
    #[serde(default)]
    cv: Option<CvSummary>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shape: Option<StoredShape>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shape_cv: Option<ShapeCvReport>,
    /// Version 3: where the profile is trusted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    trust: Option<Trust>,
    /// Version 4: where each channel's kernels are centred.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    place: Option<StoredPlace>,
    /// The focus distances of the shots, where they record one (optional in any version).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    focus_range_m: Option<FocusRange>,
    /// What the shots were: RAW files, linear or developed pictures (optional in any
    /// version: a file without it was made before it was recorded, from RAW files).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    measured_on: Option<PictureKind>,
}

/// Where the kernels sit, as stored: per channel, each part's x and y offsets (px) as
/// coefficients over the G_{α,β} basis.
#[derive(Serialize, Deserialize)]
struct StoredPlace {
    alpha: usize,
    beta: usize,
    terms: usize,
    channels: Vec<crate::model::ChannelPlace>,
    /// Held-out RMS of the centroids' offsets per order tried, px.
    #[serde(default)]
    cv: Vec<crate::model::PlaceCv>,
    /// RMS of the measured centroids about the pixel, px.
    #[serde(default)]
    centred_rms_px: f64,
}

/// A loaded (or freshly fitted) lens profile.
#[derive(Clone, Debug)]
pub struct Profile {
    pub identity: CameraIdentity,
    pub chart: Option<ChartSpec>,
    pub norm: Normalisation,
    pub calibrated_settings: Vec<LensSetting>,
    /// The model [`Profile::predict`] uses.
    pub preferred: ModelKind,
    pub global: Option<GlobalModel>,
    pub local: Option<LocalModel>,
    pub cv: Option<CvSummary>,
    /// The kernel-shape model, where cross-validation found it predicts held-out kernels
    /// better than the Gaussians alone.
    pub shape: Option<ShapeModel>,
    /// That cross-validation, whichever way it went.
    pub shape_cv: Option<ShapeCvReport>,
    /// Where each channel's kernels are centred, lateral colour included (version 4;
    /// `None` in earlier files and for sessions that kept no kernels: every kernel
    /// centred on its pixel).
    pub place: Option<crate::model::PlaceModel>,
    /// Where the profile is trusted: its preferred model's held-out error by setting
    /// and zone (version 3; `None` in earlier files and without cross-validation).
    pub trust: Option<Trust>,
    /// The focus distances the shots were taken at; `None` where none recorded one
    /// (and in profiles made before it was kept).
    pub focus_range: Option<FocusRange>,
    /// What the shots were, where recorded ([`Profile::measured_on`] says what a
    /// profile without it is taken for).
    pub measured_on: Option<PictureKind>,
    /// Predict outside the calibrated range instead of failing. Off by default.
    pub allow_extrapolation: bool,
}

/// One predicted Gaussian of a field.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldSample {
    pub x: f64,
    pub y: f64,
    pub channel: Channel,
    pub gaussian: Gaussian2,
}

fn encode_f32(values: &[f64]) -> String {
    let mut bytes = Vec::with_capacity(values.len() * 4);
    for &v in values {
        bytes.extend_from_slice(&(v as f32).to_le_bytes());
    }
    base64_encode(&bytes)
}

fn decode_f32(text: &str) -> Option<Vec<f64>> {
    let bytes = base64_decode(text)?;
    if bytes.len() % 4 != 0 {
        return None;
    }
    Some(
        bytes
            .chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect(),
    )
}

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

fn base64_encode(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(B64[((n >> (18 - 6 * i)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn base64_decode(text: &str) -> Option<Vec<u8>> {
    let t = text.trim().trim_end_matches('=');
    let mut out = Vec::with_capacity(t.len() * 3 / 4);
    let mut acc = 0u32;
    let mut bits = 0;
    let mut value_of = [u8::MAX; 256];
    for (i, &b) in B64.iter().enumerate() {
        value_of[b as usize] = i as u8;
    }
    for c in t.bytes() {
        let v = value_of[c as usize];
        if v == u8::MAX {
            return None;
        }
        let v = u32::from(v);
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

fn store_channel(channel: Channel, coeffs: [&[f64]; 3]) -> StoredChannel {
    StoredChannel {
        channel,
        cxx: encode_f32(coeffs[0]),
        cyy: encode_f32(coeffs[1]),
        cor: encode_f32(coeffs[2]),
    }
}

fn load_channel(
    sc: &StoredChannel,
    expected: usize,
    invalid: &dyn Fn(String) -> ProfileError,
) -> Result<[Vec<f64>; 3], ProfileError> {
    let mut out: [Vec<f64>; 3] = Default::default();
    for (k, text) in [&sc.cxx, &sc.cyy, &sc.cor].into_iter().enumerate() {
        let v = decode_f32(text).ok_or_else(|| {
            invalid(format!(
                "channel {}: coefficients are not base64 f32",
                sc.channel
            ))
        })?;
        if v.len() != expected {
            return Err(invalid(format!(
                "channel {}: {} coefficients, expected {expected}",
                sc.channel,
                v.len()
            )));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(invalid(format!(
                "channel {}: non-finite coefficient",
                sc.channel
            )));
        }
        out[k] = v;
    }
    Ok(out)
}

/// The file's sensor, ranges, sampled extent, settings and chart, each what it says.
fn check_file(
    file: &ProfileFile,
    invalid: &dyn Fn(String) -> ProfileError,
) -> Result<(), ProfileError> {
    let sides = 2..=MAX_SENSOR_SIDE_PX;
    if !(sides.contains(&file.width) && sides.contains(&file.height)) {
        return Err(invalid(format!(
            "sensor {}×{} px (each side must be 2–{MAX_SENSOR_SIDE_PX})",
            file.width, file.height
        )));
    }
    let ok_range = |r: [f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] > 0.0 && r[1] >= r[0];
    if !ok_range(file.focal_range_mm) || !ok_range(file.f_number_range) {
        return Err(invalid(
            "calibrated ranges are not positive intervals".into(),
        ));
    }
    if let Some(e) = file.sampled_extent_px
        && !(e.iter().all(|v| v.is_finite()) && e[0] <= e[2] && e[1] <= e[3])
    {
        return Err(invalid("sampled extent is not a box".into()));
    }
    let real = |v: f64| v.is_finite() && v > 0.0;
    if let Some(s) = file
        .calibrated_settings
        .iter()
        .find(|s| !(real(s.focal_mm) && real(s.f_number)))
    {
        return Err(invalid(format!(
            "calibrated setting f = {} mm, f/{} is not a lens setting",
            s.focal_mm, s.f_number
        )));
    }
    if let Some(chart) = &file.chart {
        chart.validate().map_err(|e| invalid(e.to_string()))?;
    }
    Ok(())
}

/// A model's basis from its name, orders α, β and stored term count, refused where the
/// orders are too high or the count is not the basis's (made once in `from_json`).
type CheckedBasis<'a> =
    dyn Fn(String, usize, usize, usize) -> Result<crate::model::Basis, ProfileError> + 'a;

/// A stored local model, checked against the sensor (`norm`) before any of it is
/// believed: orders, radius, a centre grid that fits the sensor, coefficient counts.
fn load_local(
    l: &StoredLocal,
    norm: &Normalisation,
    invalid: &dyn Fn(String) -> ProfileError,
    checked_basis: &CheckedBasis<'_>,
) -> Result<LocalModel, ProfileError> {
    let name = format!(
        "local model {}",
        ModelKind::Local.model_name(l.alpha, l.beta)
    );
    let basis = checked_basis(name, l.alpha, l.beta, l.terms)?;
    if !(l.radius_px.is_finite() && l.radius_px >= 1.0) {
        return Err(invalid(format!(
            "local model radius {} px is not a radius of at least 1 px",
            l.radius_px
        )));
    }
    // A fit places at most one centre per pixel along each side.
    let centres = l
        .centres_x
        .checked_mul(l.centres_y)
        .filter(|&n| n <= MAX_LOCAL_CENTRES);
    let per_side = |n: usize, side: usize| (2..=side).contains(&n);
    let (Some(n_centres), true, true) = (
        centres,
        per_side(l.centres_x, norm.width),
        per_side(l.centres_y, norm.height),
    ) else {
        return Err(invalid(format!(
            "local model grid of {} × {} centres does not fit a {}×{} sensor (at least 2 per side, at most one per pixel and {MAX_LOCAL_CENTRES} in all)",
            l.centres_x, l.centres_y, norm.width, norm.height
        )));
    };
    let n = basis.len();
    let expected = n
        .checked_mul(n_centres)
        .ok_or_else(|| invalid(format!("local model: {n_centres} centres of {n} terms")))?;
    check_distinct_channels(l.channels.iter().map(|c| c.channel), invalid)?;
    let grid = CentreGrid {
        nx: l.centres_x,
        ny: l.centres_y,
        radius_px: l.radius_px,
        width: norm.width,
        height: norm.height,
    };
    let mut channels = Vec::new();
    for sc in &l.channels {
        let flat = load_channel(sc, expected, invalid)?;
        let centres = (0..n_centres)
            .map(|c| {
                [
                    flat[0][c * n..(c + 1) * n].to_vec(),
                    flat[1][c * n..(c + 1) * n].to_vec(),
                    flat[2][c * n..(c + 1) * n].to_vec(),
                ]
            })
            .collect();
        channels.push((sc.channel, centres));
    }
    Ok(LocalModel {
        norm: norm.clone(),
        alpha: l.alpha,
        beta: l.beta,
        grid,
        basis,
        channels,
    })
}

/// Reads and checks a stored kernel-shape model against the profile's sensor and ranges.
fn load_shape(
    sh: &StoredShape,
    norm: &Normalisation,
    invalid: &dyn Fn(String) -> ProfileError,
    checked_basis: &CheckedBasis<'_>,
) -> Result<ShapeModel, ProfileError> {
    let (side, per_unit) = (sh.space.side(), sh.space.per_unit());
    if sh.grid_side != side || sh.grid_per_sigma != per_unit {
        return Err(invalid(format!(
            "kernel-shape model in the {} space on a {} × {} grid at {} per unit; this lensblur uses {side} × {side} at {per_unit}",
            sh.space.name(),
            sh.grid_side,
            sh.grid_side,
            sh.grid_per_sigma,
        )));
    }
    if sh.components > crate::model::MAX_COMPONENTS {
        return Err(invalid(format!(
            "kernel-shape model of {} components (at most {})",
            sh.components,
            crate::model::MAX_COMPONENTS
        )));
    }
    let basis = checked_basis(
        format!("kernel-shape model of order {}, {}", sh.alpha, sh.beta),
        sh.alpha,
        sh.beta,
        sh.terms,
    )?;
    let values = |text: &str, expected: usize, what: &str| -> Result<Vec<f64>, ProfileError> {
        let v = decode_f32(text)
            .ok_or_else(|| invalid(format!("kernel-shape {what} are not base64 f32")))?;
        if v.len() != expected {
            return Err(invalid(format!(
                "kernel-shape {what}: {} values, expected {expected}",
                v.len()
            )));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(invalid(format!("kernel-shape {what}: non-finite value")));
        }
        Ok(v)
    };
    let k = sh.components;
    let len = sh.space.values();
    let flat = values(&sh.basis, k * len, "components")?;
    let components: Vec<Vec<f64>> = flat.chunks_exact(len).map(<[f64]>::to_vec).collect();
    let mut channels: Vec<(Channel, Vec<Vec<f64>>)> = Vec::new();
    for c in &sh.channels {
        if channels.iter().any(|(ch, _)| *ch == c.channel) {
            return Err(invalid(format!(
                "kernel-shape channel {} is stored twice",
                c.channel
            )));
        }
        let flat = values(&c.coefficients, k * basis.len(), "coefficients")?;
        let per: Vec<Vec<f64>> = if basis.is_empty() {
            vec![Vec::new(); k]
        } else {
            flat.chunks_exact(basis.len())
                .map(<[f64]>::to_vec)
                .collect()
        };
        channels.push((c.channel, per));
    }
    if channels.is_empty() {
        return Err(invalid("kernel-shape model without channels".into()));
    }
    Ok(ShapeModel {
        space: sh.space,
        norm: norm.clone(),
        alpha: sh.alpha,
        beta: sh.beta,
        basis,
        components,
        channels,
    })
}

/// Refuses a model that stores a channel twice (which of the two would it predict?).
fn check_distinct_channels(
    channels: impl Iterator<Item = Channel>,
    invalid: &dyn Fn(String) -> ProfileError,
) -> Result<(), ProfileError> {
    let mut seen = Vec::new();
    for c in channels {
        if seen.contains(&c) {
            return Err(invalid(format!("channel {c} is stored twice")));
        }
        seen.push(c);
    }
    Ok(())
}

/// Whether `q` lies in the convex hull of `pts` (2-D), within `tol`. Handles hulls
/// that are a point or a segment (a session at one setting, or at one focal length).
fn point_in_hull(pts: &[[f64; 2]], q: [f64; 2], tol: f64) -> bool {
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let dist_to_segment = |a: [f64; 2], b: [f64; 2]| {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len2 = dx * dx + dy * dy;
        let t = if len2 > 0.0 {
            (((q[0] - a[0]) * dx + (q[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (q[0] - a[0] - t * dx).hypot(q[1] - a[1] - t * dy)
    };
    let mut p: Vec<[f64; 2]> = pts.to_vec();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup_by(|a, b| (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12);
    if p.is_empty() {
        return false;
    }
    // Andrew's monotone chain, counter-clockwise, collinear points dropped.
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &pt in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], pt) <= 1e-12
            {
                hull.pop();
            }
            hull.push(pt);
        }
        hull.pop();
    }
    match hull.len() {
        0 => dist_to_segment(p[0], p[0]) <= tol,
        1 | 2 => dist_to_segment(hull[0], *hull.last().unwrap_or(&hull[0])) <= tol,
        n => (0..n).all(|i| {
            let (a, b) = (hull[i], hull[(i + 1) % n]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            cross(a, b, q) >= -tol * len
        }),
    }
}

impl Profile {
    /// A profile from fitted models. `preferred` falls back to whichever model exists.
    #[must_use]
    pub fn new(
        identity: CameraIdentity,
        chart: Option<ChartSpec>,
        calibrated_settings: Vec<LensSetting>,
        global: Option<GlobalModel>,
        local: Option<LocalModel>,
        cv: Option<CvSummary>,
        preferred: ModelKind,
    ) -> Option<Self> {
        let norm = global
            .as_ref()
            .map(|g| g.norm.clone())
            .or_else(|| local.as_ref().map(|l| l.norm.clone()))?;
        let preferred = match (preferred, global.is_some(), local.is_some()) {
            (ModelKind::Global, false, _) => ModelKind::Local,
            (ModelKind::Local, _, false) => ModelKind::Global,
            (p, _, _) => p,
        };
        Some(Self {
            identity,
            chart,
            norm,
            calibrated_settings,
            preferred,
            global,
            local,
            cv,
            shape: None,
            shape_cv: None,
            place: None,
            trust: None,
            focus_range: None,
            measured_on: None,
            allow_extrapolation: false,
        })
    }

    fn to_file(&self) -> ProfileFile {
        ProfileFile {
            schema: PROFILE.tag(),
            identity: self.identity.clone(),
            chart: self.chart.clone(),
            width: self.norm.width,
            height: self.norm.height,
            focal_range_mm: self.norm.focal_range_mm,
            f_number_range: self.norm.f_number_range,
            sampled_extent_px: self.norm.sampled_extent_px,
            normalisation: "Legendre product basis; x, y: 2x/(W-1)-1, 2y/(H-1)-1 (local: (x-cx)/radius); f linear over focal_range_mm; a linear in ln(f-number) over f_number_range; a setting that does not vary has no terms; outside sampled_extent_px, linear extrapolation from its border".into(),
            calibrated_settings: self.calibrated_settings.clone(),
            preferred: self.preferred,
            global: self.global.as_ref().map(|g| StoredGlobal {
                alpha: g.alpha,
                beta: g.beta,
                terms: g.basis.len(),
                channels: g
                    .channels
                    .iter()
                    .map(|c| store_channel(c.channel, [&c.coeffs[0], &c.coeffs[1], &c.coeffs[2]]))
                    .collect(),
            }),
            local: self.local.as_ref().map(|l| StoredLocal {
                alpha: l.alpha,
                beta: l.beta,
                terms: l.basis.len(),
                radius_px: l.grid.radius_px,
                centres_x: l.grid.nx,
                centres_y: l.grid.ny,
                channels: l
                    .channels
                    .iter()
                    .map(|(ch, centres)| {
                        let flat = |p: usize| centres.iter().flat_map(|c| c[p].iter().copied()).collect::<Vec<f64>>();
                        store_channel(*ch, [&flat(0), &flat(1), &flat(2)])
                    })
                    .collect(),
            }),
            cv: self.cv.clone(),
            shape: self.shape.as_ref().map(|m| StoredShape {
                space: m.space,
                alpha: m.alpha,
                beta: m.beta,
                terms: m.basis.len(),
                components: m.components.len(),
                grid_side: m.space.side(),
                grid_per_sigma: m.space.per_unit(),
                basis: encode_f32(&m.components.concat()),
                channels: m
                    .channels
                    .iter()
                    .map(|(ch, c)| StoredShapeChannel {
                        channel: *ch,
                        coefficients: encode_f32(&c.concat()),
                    })
                    .collect(),
            }),
            shape_cv: self.shape_cv.clone(),
            trust: self.trust.clone(),
            place: self.place.as_ref().map(|c| StoredPlace {
                alpha: c.alpha,
                beta: c.beta,
                terms: c.channels.first().map_or(0, |ch| ch.kernel[0].len()),
                channels: c.channels.clone(),
                cv: c.cv.clone(),
                centred_rms_px: c.centred_rms_px,
            }),
            focus_range_m: self.focus_range,
            measured_on: self.measured_on,
        }
    }

    /// The profile as JSON bytes.
    ///
    /// # Errors
    /// Serialisation failure (not expected).
    pub fn to_json(&self) -> Result<Vec<u8>, ProfileError> {
        serde_json::to_vec_pretty(&self.to_file()).map_err(|e| ProfileError::File {
            path: "profile".into(),
            reason: e.to_string(),
        })
    }

    /// Writes the profile atomically: a temporary file beside `path`, then a rename.
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn save(&self, path: &Path) -> Result<(), ProfileError> {
        let bytes = self.to_json()?;
        let err = |e: std::io::Error| ProfileError::File {
            path: path.display().to_string(),
            reason: e.to_string(),
        };
        crate::io::write_atomic(path, &bytes).map_err(|e| err(e.source))
    }

    /// Reads and validates a profile.
    ///
    /// # Errors
    /// Unreadable file, not JSON, a wrong schema or version, or inconsistent models.
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        let p = path.display().to_string();
        let text = crate::io::read_json_text(path).map_err(|e| ProfileError::File {
            path: p.clone(),
            reason: match e {
                crate::io::ReadError::Io { source, .. } => source.to_string(),
                too_large => too_large.to_string(),
            },
        })?;
        Self::from_json(&text, &p)
    }

    /// Parses and validates profile JSON; `origin` names it in errors.
    ///
    /// # Errors
    /// As [`Profile::load`].
    pub fn from_json(text: &str, origin: &str) -> Result<Self, ProfileError> {
        // The schema first, so another version is named as such rather than reported
        // as whichever field it lacks.
        serde_json::from_str::<serde::de::IgnoredAny>(text).map_err(|e| ProfileError::File {
            path: origin.into(),
            reason: format!("not JSON: {e}"),
        })?;
        PROFILE
            .version_of_json(text)
            .map_err(|e| ProfileError::Schema {
                path: origin.into(),
                reason: e.to_string(),
            })?;
        let file: ProfileFile = serde_json::from_str(text).map_err(|e| ProfileError::Invalid {
            path: origin.into(),
            reason: e.to_string(),
        })?;
        let invalid = |reason: String| ProfileError::Invalid {
            path: origin.into(),
            reason,
        };
        check_file(&file, &invalid)?;
        let norm = Normalisation {
            width: file.width,
            height: file.height,
            focal_range_mm: file.focal_range_mm,
            f_number_range: file.f_number_range,
            sampled_extent_px: file.sampled_extent_px,
        };
        // Orders first: the basis of an order beyond MAX_ORDER is not even enumerated.
        let checked_basis = |name: String, alpha: usize, beta: usize, terms: usize| {
            if alpha.max(beta) > MAX_ORDER {
                return Err(invalid(format!(
                    "{name}: model order α = {alpha}, β = {beta} above {MAX_ORDER}"
                )));
            }
            let basis = model_basis(&norm, alpha, beta);
            if basis.len() != terms {
                return Err(invalid(format!(
                    "{name} has {} terms, file says {terms}",
                    basis.len()
                )));
            }
            Ok(basis)
        };
        let global = match &file.global {
            None => None,
            Some(g) => {
                let name = format!(
                    "global model {}",
                    ModelKind::Global.model_name(g.alpha, g.beta)
                );
                let basis = checked_basis(name, g.alpha, g.beta, g.terms)?;
                check_distinct_channels(g.channels.iter().map(|c| c.channel), &invalid)?;
                let mut channels = Vec::new();
                for sc in &g.channels {
                    channels.push(ChannelCoeffs {
                        channel: sc.channel,
                        coeffs: load_channel(sc, basis.len(), &invalid)?,
                    });
                }
                Some(GlobalModel {
                    norm: norm.clone(),
                    alpha: g.alpha,
                    beta: g.beta,
                    basis,
                    channels,
                })
            }
        };
        let local = match &file.local {
            None => None,
            Some(l) => Some(load_local(l, &norm, &invalid, &checked_basis)?),
        };
        if global.is_none() && local.is_none() {
            return Err(invalid("holds neither a global nor a local model".into()));
        }
        if let Some(t) = &file.trust {
            t.validate().map_err(&invalid)?;
        }
        let trust = file.trust.clone();
        if let Some(r) = &file.focus_range_m {
            r.validate().map_err(&invalid)?;
        }
        let shape = match &file.shape {
            None => None,
            Some(sh) => Some(load_shape(sh, &norm, &invalid, &checked_basis)?),
        };
        let place = match file.place {
            None => None,
            Some(c) => {
                check_distinct_channels(c.channels.iter().map(|ch| ch.channel), &invalid)?;
                let model = crate::model::PlaceModel::from_parts(
                    norm.clone(),
                    (c.alpha, c.beta),
                    c.channels,
                    c.cv,
                    c.centred_rms_px,
                )
                .map_err(&invalid)?;
                if model
                    .channels
                    .iter()
                    .any(|ch| ch.kernel[0].len() != c.terms)
                {
                    return Err(invalid(format!(
                        "kernel place model of orders {}, {} says {} terms",
                        c.alpha, c.beta, c.terms
                    )));
                }
                Some(model)
            }
        };
        let preferred = match (file.preferred, global.is_some(), local.is_some()) {
            (ModelKind::Global, false, _) | (ModelKind::Local, _, false) => {
                return Err(invalid(format!(
                    "preferred model {:?} is missing",
                    file.preferred
                )));
            }
            (p, _, _) => p,
        };
        Ok(Self {
            identity: file.identity,
            chart: file.chart,
            norm,
            calibrated_settings: file.calibrated_settings,
            preferred,
            global,
            local,
            cv: file.cv,
            shape,
            shape_cv: file.shape_cv,
            place,
            trust,
            focus_range: file.focus_range_m,
            measured_on: file.measured_on,
            allow_extrapolation: false,
        })
    }

    /// What the profile's shots were. A profile that does not record it was made before
    /// lensblur recorded it, when calibration sessions were RAW files: it is taken for a
    /// RAW profile.
    #[must_use]
    pub fn measured_on(&self) -> PictureKind {
        self.measured_on.unwrap_or(PictureKind::Raw)
    }

    /// The one warning for a photo of another kind than the profile's shots (a
    /// developed JPEG deblurred with a RAW profile, or the other way round), naming
    /// the mismatch and what to do; `None` when they match. `photo` and `profile` are
    /// the files' names as the user gave them.
    #[must_use]
    pub fn picture_warning(&self, kind: PictureKind, photo: &str, profile: &str) -> Option<String> {
        let ours = self.measured_on();
        if ours.matches(kind) {
            return None;
        }
        let assumed = if self.measured_on.is_none() {
            " (it records nothing, so it is taken for a RAW profile)"
        } else {
            ""
        };
        let remedy = if kind == PictureKind::Developed {
            "the camera's demosaicing, sharpening and tone curve changed the blur, so the \
             profile's kernels are not this picture's and it is deblurred only as far as its \
             noise and compression allow; to deblur this camera's JPEGs, calibrate from its \
             JPEGs of the chart (or deblur the RAW file)"
        } else {
            "a developed picture's blur is the camera's processing as much as the lens's; to \
             deblur RAW files, calibrate from RAW files of the chart"
        };
        Some(format!(
            "{photo} is {} but {profile} was measured on {}{assumed}: {remedy}",
            kind.one(),
            ours.describe()
        ))
    }

    /// Refuses a photo from another camera or lens unit: any identity field present on
    /// both sides must agree. Returns warnings for fields the photo lacks. With `force`,
    /// mismatches become warnings too.
    ///
    /// # Errors
    /// [`ProfileError::IdentityMismatch`] naming the first differing field.
    pub fn check_identity(
        &self,
        photo: &CameraIdentity,
        force: bool,
    ) -> Result<Vec<String>, ProfileError> {
        let fields = self.identity.fields().into_iter().zip(photo.fields());
        let mut warnings = Vec::new();
        for ((name, mine), (_, theirs)) in fields {
            match (mine, theirs) {
                (Some(a), Some(b)) if !CameraIdentity::same_value(a, b) => {
                    let e = ProfileError::IdentityMismatch {
                        field: name.into(),
                        profile: a.to_owned(),
                        photo: b.to_owned(),
                    };
                    if force {
                        warnings.push(e.to_string());
                    } else {
                        return Err(e);
                    }
                }
                (Some(a), None) => warnings.push(format!(
                    "the photo does not record its {name}; the profile is for '{a}'"
                )),
                _ => {}
            }
        }
        Ok(warnings)
    }

    /// Checks a setting against the calibrated range.
    ///
    /// # Errors
    /// [`ProfileError::OutOfRange`] unless extrapolation is allowed.
    pub fn check_setting(&self, s: LensSetting) -> Result<(), ProfileError> {
        if self.allow_extrapolation || self.covers(s) {
            return Ok(());
        }
        if !self.norm.contains(s) {
            return Err(ProfileError::OutOfRange {
                focal_mm: s.focal_mm,
                f_number: s.f_number,
                f0: self.norm.focal_range_mm[0],
                f1: self.norm.focal_range_mm[1],
                a0: self.norm.f_number_range[0],
                a1: self.norm.f_number_range[1],
            });
        }
        if !self.in_calibrated_hull(s) {
            return Err(ProfileError::BetweenRanges {
                focal_mm: s.focal_mm,
                f_number: s.f_number,
            });
        }
        Ok(())
    }

    /// Whether the profile was calibrated for a setting: inside the ranges and among
    /// the calibrated settings ([`Profile::in_calibrated_hull`]), whatever
    /// `allow_extrapolation` says.
    #[must_use]
    pub fn covers(&self, s: LensSetting) -> bool {
        self.norm.contains(s) && self.in_calibrated_hull(s)
    }

    /// Whether a setting lies among the calibrated ones: inside their convex hull in
    /// the normalised (f, a) plane. The ranges alone are not enough: a zoom whose
    /// widest aperture shrinks with focal length, calibrated at f/4 at 24 mm and f/5.6
    /// at 105 mm, has both f/4 and 105 mm in range but was never measured at 105 mm f/4.
    #[must_use]
    pub fn in_calibrated_hull(&self, s: LensSetting) -> bool {
        if self.calibrated_settings.is_empty() {
            return true;
        }
        let pts: Vec<[f64; 2]> = self
            .calibrated_settings
            .iter()
            .map(|c| {
                let (f, a) = self.norm.fa(*c);
                [f, a]
            })
            .collect();
        let (f, a) = self.norm.fa(s);
        // About the 0.1 % the ranges allow for rounded EXIF values.
        point_in_hull(&pts, [f, a], 2e-3)
    }

    /// The pixel-level Gaussian at sensor (x, y) for a setting, from the preferred model.
    ///
    /// # Errors
    /// A setting outside the calibrated range, or a channel the profile lacks.
    pub fn predict(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
    ) -> Result<Gaussian2, ProfileError> {
        self.predict_with(self.preferred, channel, x, y, setting)
    }

    /// As [`Profile::predict`] with a chosen model family.
    ///
    /// # Errors
    /// As [`Profile::predict`], and a missing family.
    pub fn predict_with(
        &self,
        kind: ModelKind,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
    ) -> Result<Gaussian2, ProfileError> {
        self.check_setting(setting)?;
        self.model(kind)?
            .predict(channel, x, y, setting)
            .map(to_gaussian)
            .ok_or(ProfileError::NoChannel(channel))
    }

    /// The Gaussian kernel model's prediction at sensor (x, y): the Gaussian and its
    /// mean (px), where the place model puts the channel's kernels. The kernel
    /// [`Self::predict_kernel`] renders of it is `g.kernel_at(KERNEL_OVERSAMPLE, mean)`;
    /// a GPU makes the same from these few numbers.
    ///
    /// # Errors
    /// As [`Profile::predict`].
    pub fn placed_gaussian(
        &self,
        lateral: LateralColour,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
    ) -> Result<(Gaussian2, [f64; 2]), ProfileError> {
        let g = self.predict(channel, x, y, setting)?;
        let c = self
            .place
            .as_ref()
            .and_then(|p| p.centroid(channel, x, y, setting, lateral));
        Ok((g, c.unwrap_or([0.0, 0.0])))
    }

    /// The kernel the profile predicts for deblurring at sensor (x, y) for a setting,
    /// at 3×: the preferred model's Gaussian, with the shape model's predicted shape
    /// when `model` asks for it, placed where the profile's place model puts the channel's
    /// kernels (`lateral` says whether that includes the lens's lateral colour).
    ///
    /// # Errors
    /// As [`Profile::predict`]; [`ProfileError::NoShapeModel`] when the shape is asked
    /// of a profile without one.
    pub fn predict_kernel(
        &self,
        model: KernelModel,
        lateral: LateralColour,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
    ) -> Result<Kernel, ProfileError> {
        match model {
            // A Gaussian is centred: all of its place comes from the place model.
            KernelModel::Gaussian => {
                let (g, mean) = self.placed_gaussian(lateral, channel, x, y, setting)?;
                Ok(g.kernel_at(KERNEL_OVERSAMPLE, mean))
            }
            KernelModel::Shape => {
                let (shape, placed) = self.placed_shape(lateral, channel, x, y, setting)?;
                shape
                    .kernel_of(&placed, KERNEL_OVERSAMPLE)
                    .ok_or(ProfileError::NoChannel(channel))
            }
        }
    }

    /// The shape model's prediction at sensor (x, y), as its parts: the model and the
    /// placed shape whose kernel [`Self::predict_kernel`] renders
    /// (`shape.kernel_of(&placed, KERNEL_OVERSAMPLE)`); a GPU makes the same from them.
    ///
    /// # Errors
    /// As [`Profile::predict`]; [`ProfileError::NoShapeModel`] for a profile without
    /// one, [`ProfileError::NoChannel`] for a channel it does not hold.
    pub fn placed_shape(
        &self,
        lateral: LateralColour,
        channel: Channel,
        x: f64,
        y: f64,
        setting: LensSetting,
    ) -> Result<(&ShapeModel, PlacedShape), ProfileError> {
        let shape = self.shape.as_ref().ok_or(ProfileError::NoShapeModel)?;
        let g = self.predict(channel, x, y, setting)?;
        // A shape keeps the place it learnt from the kernels (moving it to their
        // centroid would move its core by whatever its tail gets wrong, and the core
        // is what deconvolution aligns the channels by); it moves only by what the
        // kernels did not carry, their channel's registration against green's.
        let offset = match lateral {
            LateralColour::Correct => self
                .place
                .as_ref()
                .and_then(|c| c.registration(channel, x, y, setting))
                .unwrap_or([0.0, 0.0]),
            LateralColour::Keep => [0.0, 0.0],
        };
        let placed = shape
            .placed(channel, [x, y], setting, &g, offset)
            .ok_or(ProfileError::NoChannel(channel))?;
        Ok((shape, placed))
    }

    /// The kernel model the profile recommends: its shape model where it holds one.
    #[must_use]
    pub fn kernel_model(&self) -> KernelModel {
        if self.shape.is_some() {
            KernelModel::Shape
        } else {
            KernelModel::Gaussian
        }
    }

    /// The fitted model of a family.
    ///
    /// # Errors
    /// [`ProfileError::NoModel`] when the profile holds none of that family.
    pub fn model(&self, kind: ModelKind) -> Result<&dyn FittedModel, ProfileError> {
        let model: Option<&dyn FittedModel> = match kind {
            ModelKind::Global => self.global.as_ref().map(|g| g as &dyn FittedModel),
            ModelKind::Local => self.local.as_ref().map(|l| l as &dyn FittedModel),
        };
        model.ok_or(ProfileError::NoModel(kind))
    }

    /// The channels the preferred model holds.
    #[must_use]
    pub fn channels(&self) -> Vec<Channel> {
        self.model(self.preferred)
            .map(|m| m.channels())
            .unwrap_or_default()
    }

    /// The predicted field every `step_px` pixels (from pixel 0, plus the last row and
    /// column), every channel, row-major per channel.
    ///
    /// # Errors
    /// As [`Profile::predict`].
    pub fn predict_field(
        &self,
        setting: LensSetting,
        step_px: usize,
    ) -> Result<Vec<FieldSample>, ProfileError> {
        self.check_setting(setting)?;
        let step = step_px.max(1);
        let axis = |len: usize| {
            let mut v: Vec<f64> = (0..len).step_by(step).map(|i| i as f64).collect();
            if !(len - 1).is_multiple_of(step) {
                v.push((len - 1) as f64);
            }
            v
        };
        let xs = axis(self.norm.width);
        let ys = axis(self.norm.height);
        let mut out = Vec::with_capacity(xs.len() * ys.len() * 3);
        for ch in self.channels() {
            let field = self.field_at_setting(self.preferred, ch, setting)?;
            for &y in &ys {
                for &x in &xs {
                    out.push(FieldSample {
                        x,
                        y,
                        channel: ch,
                        gaussian: to_gaussian(field.predict(x, y)),
                    });
                }
            }
        }
        Ok(out)
    }

    /// One channel of a model family at one setting, for predicting many points at it
    /// (the same values as [`Profile::predict_with`], a fraction of the cost).
    ///
    /// # Errors
    /// As [`Profile::predict_with`].
    pub fn field_at_setting(
        &self,
        kind: ModelKind,
        channel: Channel,
        setting: LensSetting,
    ) -> Result<FieldAtSetting, ProfileError> {
        self.check_setting(setting)?;
        self.model(kind)?
            .at_setting(channel, setting)
            .ok_or(ProfileError::NoChannel(channel))
    }

    /// The family a profile prefers: the one that cross-validates better at its orders
    /// (`cv`, the global model only when its error is strictly lower); without both
    /// errors, the local model where there is one (`has_local`; the smaller error in the
    /// paper's tests).
    #[must_use]
    pub fn preferred_family(cv: Option<&CvSummary>, has_local: bool) -> ModelKind {
        match cv.map(|c| (&c.global, &c.local)) {
            Some((Some(g), Some(l))) if g.mean_pct < l.mean_pct => ModelKind::Global,
            _ if has_local => ModelKind::Local,
            _ => ModelKind::Global,
        }
    }
}

#[cfg(test)]
mod tests;
