//! Blur variation models (DESIGN.md §1.6): per channel, three polynomials predicting
//! C_xx, C_yy and C_or from sensor position (x, y), focal length f and aperture a.
//!
//! Global G_{α,β}: every monomial x^i y^j f^k a^l with i+j ≤ α, k+l ≤ β and
//! i+j+k+l ≤ max(α, β). Local L_{α,β}: the same form fitted around a grid of centres,
//! each to the samples within a radius, blended between neighbouring centres with C¹
//! weights that sum to one, so the predicted field has no seams.
//!
//! Coordinates are normalised before the basis is evaluated: x, y to [−1, 1] over the
//! sensor (around a centre, to [−1, 1] over the radius for a local fit), f to [−1, 1]
//! over the calibrated focal range and a to [−1, 1] over the calibrated range in stops
//! (log f-number). The basis is the Legendre product P_i(x) P_j(y) P_k(f) P_l(a), which
//! keeps order-8 fits well conditioned; final fits are solved by QR (SVD where the
//! design is rank deficient). No ridge term is used.

use crate::plane::{CameraIdentity, Channel, LensSetting};
use crate::psf::Gaussian2;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Errors of reading samples and fitting models.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: {reason}")]
    File { path: String, reason: String },
    #[error(
        "shot '{shot}' has no known focal length and aperture (give them in the manifest or with flags)"
    )]
    UnknownSetting { shot: String },
    #[error("no measured samples to fit")]
    Empty,
    #[error(
        "β = {beta} needs at least {need} distinct values of every varying setting, but this session has N_f = {n_f} focal lengths and N_a = {n_a} apertures (β < min(N_f, N_a))"
    )]
    BetaTooLarge {
        beta: usize,
        need: usize,
        n_f: usize,
        n_a: usize,
    },
    #[error(
        "β = {beta} has {terms} terms in focal length and aperture, but this session's {settings} distinct settings (f, a) do not determine them; calibrate at more settings or lower β"
    )]
    SettingsTooSparse {
        beta: usize,
        terms: usize,
        settings: usize,
    },
    #[error("α = {alpha}, β = {beta}: model orders above {MAX_ORDER} are not supported")]
    OrderTooHigh { alpha: usize, beta: usize },
    #[error("too few samples for {model}: {samples} samples for {terms} terms")]
    TooFewSamples {
        model: String,
        samples: usize,
        terms: usize,
    },
    #[error(
        "cross-validation needs at least 2 shots, this session has {shots}; give --alpha and --beta"
    )]
    TooFewShots { shots: usize },
    #[error(
        "test shot '{shot}' (f = {focal_mm} mm, f/{f_number}) lies outside the calibrated range"
    )]
    OutsideCalibratedRange {
        shot: String,
        focal_mm: f64,
        f_number: f64,
    },
    #[error(
        "the session mixes cameras or lenses: {field} is '{a}' in earlier shots but '{b}' in {shot}"
    )]
    MixedIdentity {
        field: &'static str,
        a: String,
        b: String,
        shot: String,
    },
    #[error("sensor sizes differ: {a} and {b}")]
    SensorMismatch { a: String, b: String },
    #[error("cancelled")]
    Cancelled,
}

impl From<crate::job::Cancelled> for ModelError {
    fn from(_: crate::job::Cancelled) -> Self {
        ModelError::Cancelled
    }
}

/// The highest polynomial order, in any coordinate, a model may have: the basis tables
/// are sized for it, and a profile asking for more is refused.
pub const MAX_ORDER: usize = 15;

/// Refuses orders the basis cannot evaluate.
///
/// # Errors
/// [`ModelError::OrderTooHigh`].
pub fn check_order(alpha: usize, beta: usize) -> Result<(), ModelError> {
    if alpha.max(beta) > MAX_ORDER {
        return Err(ModelError::OrderTooHigh { alpha, beta });
    }
    Ok(())
}

/// One measured Gaussian: a square of a shot, one channel.
#[derive(Clone, Debug, PartialEq)]
pub struct BlurSample {
    pub shot: usize,
    pub x: f64,
    pub y: f64,
    /// The chart square (row, column) it was measured on, where known: it gives the
    /// imaged square width even when only every other square was measured.
    pub square: Option<[usize; 2]>,
    pub focal_mm: f64,
    pub f_number: f64,
    pub channel: Channel,
    pub gaussian: Gaussian2,
}

impl BlurSample {
    /// C_xx, C_yy, C_or in that order.
    #[must_use]
    pub fn params(&self) -> [f64; 3] {
        [
            self.gaussian.sigma_x,
            self.gaussian.sigma_y,
            self.gaussian.rho,
        ]
    }
}

/// What is known of one shot of a calibration session.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShotInfo {
    pub name: String,
    pub focal_mm: f64,
    pub f_number: f64,
}

/// The measured Gaussians of a calibration session.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    pub width: usize,
    pub height: usize,
    pub identity: CameraIdentity,
    pub samples: Vec<BlurSample>,
    pub shots: Vec<ShotInfo>,
}

/// The names of the three modelled parameters, in the order of [`BlurSample::params`].
pub const PARAM_NAMES: [&str; 3] = ["cxx", "cyy", "cor"];

impl Dataset {
    /// An empty session on a `width × height` sensor.
    #[must_use]
    pub fn new(width: usize, height: usize, identity: CameraIdentity) -> Self {
        Self {
            width,
            height,
            identity,
            samples: Vec::new(),
            shots: Vec::new(),
        }
    }

    /// Adds one shot's samples (their `shot` field is overwritten) and returns its index.
    pub fn push_shot(
        &mut self,
        info: ShotInfo,
        samples: impl IntoIterator<Item = BlurSample>,
    ) -> usize {
        let shot = self.shots.len();
        for mut s in samples {
            s.shot = shot;
            s.focal_mm = info.focal_mm;
            s.f_number = info.f_number;
            self.samples.push(s);
        }
        self.shots.push(info);
        shot
    }

    /// Reads `lensblur.kernels/1` files, one shot each. `settings[i]`, where given,
    /// overrides the file's own focal length and f-number (a manifest's values).
    /// Entries with `"status": "failed"` or without numbers are skipped.
    ///
    /// # Errors
    /// A file that cannot be read or parsed, a wrong schema, sensors of different sizes,
    /// or a shot whose setting is unknown (named in the error).
    pub fn from_kernels_files(
        paths: &[&Path],
        settings: &[Option<LensSetting>],
    ) -> Result<Self, ModelError> {
        let mut ds: Option<Dataset> = None;
        for (i, path) in paths.iter().enumerate() {
            let file_err = |reason: String| ModelError::File {
                path: path.display().to_string(),
                reason,
            };
            let kf =
                crate::kernel::file::KernelsFile::load(path).map_err(|e| file_err(e.reason))?;
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            let given = settings.get(i).copied().flatten();
            let focal_mm = given.map(|s| s.focal_mm).or(kf.focal_mm);
            let f_number = given.map(|s| s.f_number).or(kf.f_number);
            let (Some(focal_mm), Some(f_number)) = (focal_mm, f_number) else {
                return Err(ModelError::UnknownSetting {
                    shot: path.display().to_string(),
                });
            };
            if !(focal_mm.is_finite() && focal_mm > 0.0 && f_number.is_finite() && f_number > 0.0) {
                return Err(ModelError::UnknownSetting {
                    shot: path.display().to_string(),
                });
            }
            let d = ds.get_or_insert_with(|| {
                Dataset::new(kf.width, kf.height, kf.identity.clone().unwrap_or_default())
            });
            if let Some(id) = &kf.identity {
                merge_identity(&mut d.identity, id).map_err(|(field, a, b)| {
                    ModelError::MixedIdentity {
                        field,
                        a,
                        b,
                        shot: path.display().to_string(),
                    }
                })?;
            }
            if (d.width, d.height) != (kf.width, kf.height) {
                return Err(ModelError::SensorMismatch {
                    a: format!("{}×{}", d.width, d.height),
                    b: format!("{}×{} in {}", kf.width, kf.height, path.display()),
                });
            }
            let samples: Vec<BlurSample> = kf
                .samples
                .iter()
                .filter_map(|e| {
                    let (cxx, cyy, cor) = (e.cxx?, e.cyy?, e.cor?);
                    (cxx.is_finite() && cyy.is_finite() && cor.is_finite()).then_some(BlurSample {
                        shot: 0,
                        x: e.x,
                        y: e.y,
                        square: e.row.zip(e.col).map(|(r, c)| [r, c]),
                        focal_mm,
                        f_number,
                        channel: e.channel,
                        gaussian: Gaussian2 {
                            sigma_x: cxx,
                            sigma_y: cyy,
                            rho: cor,
                        },
                    })
                })
                .collect();
            d.push_shot(
                ShotInfo {
                    name,
                    focal_mm,
                    f_number,
                },
                samples,
            );
        }
        ds.ok_or(ModelError::Empty)
    }

    /// Checks every shot's setting is a real one.
    ///
    /// # Errors
    /// [`ModelError::UnknownSetting`] naming the first shot without one.
    pub fn validate(&self) -> Result<(), ModelError> {
        for s in &self.shots {
            if !(s.focal_mm.is_finite()
                && s.focal_mm > 0.0
                && s.f_number.is_finite()
                && s.f_number > 0.0)
            {
                return Err(ModelError::UnknownSetting {
                    shot: s.name.clone(),
                });
            }
        }
        if self.samples.is_empty() {
            return Err(ModelError::Empty);
        }
        Ok(())
    }

    /// The channels present, sorted.
    #[must_use]
    pub fn channels(&self) -> Vec<Channel> {
        let mut c: Vec<Channel> = self.samples.iter().map(|s| s.channel).collect();
        c.sort();
        c.dedup();
        c
    }

    /// Distinct focal lengths and f-numbers (sorted), merged by
    /// [`LensSetting::same_value`].
    #[must_use]
    pub fn distinct_settings(&self) -> (Vec<f64>, Vec<f64>) {
        (
            LensSetting::distinct_values(self.shots.iter().map(|s| s.focal_mm)),
            LensSetting::distinct_values(self.shots.iter().map(|s| s.f_number)),
        )
    }

    /// The normalisation of this session: the sensor and the calibrated ranges.
    #[must_use]
    pub fn normalisation(&self) -> Normalisation {
        let (f, a) = self.distinct_settings();
        Normalisation {
            width: self.width,
            height: self.height,
            focal_range_mm: [
                f.first().copied().unwrap_or(0.0),
                f.last().copied().unwrap_or(0.0),
            ],
            f_number_range: [
                a.first().copied().unwrap_or(1.0),
                a.last().copied().unwrap_or(1.0),
            ],
            sampled_extent_px: self.sampled_extent_px(),
        }
    }

    /// The bounding box `[x0, y0, x1, y1]` of the sample positions, pixels.
    #[must_use]
    pub fn sampled_extent_px(&self) -> Option<[f64; 4]> {
        let mut it = self.samples.iter();
        let first = it.next()?;
        let mut e = [first.x, first.y, first.x, first.y];
        for s in it {
            e = [e[0].min(s.x), e[1].min(s.y), e[2].max(s.x), e[3].max(s.y)];
        }
        Some(e)
    }

    /// N = min(N_f, N_a) over the settings that vary (1 for a single-setting session):
    /// β must stay below it.
    #[must_use]
    pub fn setting_resolution(&self) -> usize {
        let (f, a) = self.distinct_settings();
        match (f.len() > 1, a.len() > 1) {
            (true, true) => f.len().min(a.len()),
            (true, false) => f.len(),
            (false, true) => a.len(),
            (false, false) => 1,
        }
    }

    /// The distinct settings (f, a) of the session, merged by [`LensSetting::same_as`]
    /// (the first shot of each stands for it), sorted.
    #[must_use]
    pub fn distinct_setting_pairs(&self) -> Vec<LensSetting> {
        let mut out: Vec<LensSetting> = Vec::new();
        for s in &self.shots {
            let s = LensSetting {
                focal_mm: s.focal_mm,
                f_number: s.f_number,
            };
            if !out.iter().any(|o| o.same_as(s)) {
                out.push(s);
            }
        }
        out.sort_by(|a, b| {
            a.focal_mm
                .total_cmp(&b.focal_mm)
                .then(a.f_number.total_cmp(&b.f_number))
        });
        out
    }

    /// Checks β against the sampling of the settings: β < N = min(N_f, N_a) (the
    /// paper's constraint), and the settings shot must determine every term in f and
    /// a of order ≤ β — a 3 × 3 grid does for β = 2, three settings on a diagonal do
    /// not, and a least-squares fit would then invent the missing terms silently.
    ///
    /// # Errors
    /// [`ModelError::BetaTooLarge`] with the counts, [`ModelError::SettingsTooSparse`],
    /// or [`ModelError::OrderTooHigh`].
    pub fn check_beta(&self, beta: usize) -> Result<(), ModelError> {
        check_order(0, beta)?;
        let n = self.setting_resolution();
        if beta >= n {
            let (f, a) = self.distinct_settings();
            return Err(ModelError::BetaTooLarge {
                beta,
                need: beta + 1,
                n_f: f.len(),
                n_a: a.len(),
            });
        }
        let norm = self.normalisation();
        let basis = Basis::new(terms(0, beta, norm.uses_focal(), norm.uses_aperture()));
        let settings = self.distinct_setting_pairs();
        let mut a = DMatrix::zeros(settings.len(), basis.len());
        let mut row = vec![0.0; basis.len()];
        for (r, s) in settings.iter().enumerate() {
            let (nf, na) = norm.fa(*s);
            basis.row([0.0, 0.0, nf, na], &mut row);
            for (c, v) in row.iter().enumerate() {
                a[(r, c)] = *v;
            }
        }
        let sv = a.singular_values();
        let largest = sv.max();
        let rank = sv.iter().filter(|&&v| v > 1e-9 * largest).count();
        if rank < basis.len() {
            return Err(ModelError::SettingsTooSparse {
                beta,
                terms: basis.len(),
                settings: settings.len(),
            });
        }
        Ok(())
    }

    /// The width in pixels of the largest imaged square: per shot the 90th percentile
    /// of the spacing of neighbouring squares (from their chart row and column where
    /// known, else from nearest-neighbour distances), the largest over the shots.
    #[must_use]
    pub fn largest_square_px(&self) -> f64 {
        let mut best: f64 = 0.0;
        for shot in 0..self.shots.len() {
            let mine: Vec<&BlurSample> = self.samples.iter().filter(|s| s.shot == shot).collect();
            let mut widths = square_widths_from_grid(&mine);
            if widths.is_empty() {
                widths = nearest_neighbour_distances(&mine);
            }
            if widths.is_empty() {
                continue;
            }
            widths.sort_by(f64::total_cmp);
            best = best.max(widths[(widths.len() - 1) * 9 / 10]);
        }
        if best > 0.0 {
            best
        } else {
            self.width.max(self.height) as f64 / 10.0
        }
    }
}

/// Spacing of chart squares from samples with known (row, column): the distance to
/// each nearby square (up to two rows or columns away) divided by their offset in
/// squares, one value per pair.
fn square_widths_from_grid(samples: &[&BlurSample]) -> Vec<f64> {
    let mut by_square: std::collections::BTreeMap<[usize; 2], [f64; 2]> =
        std::collections::BTreeMap::new();
    for s in samples {
        if let Some(sq) = s.square {
            by_square.entry(sq).or_insert([s.x, s.y]);
        }
    }
    let mut out = Vec::new();
    for (&[r, c], p) in &by_square {
        for (dr, dc) in [(0usize, 1usize), (0, 2), (1, 0), (2, 0), (1, 1)] {
            if let Some(q) = by_square.get(&[r + dr, c + dc]) {
                out.push((p[0] - q[0]).hypot(p[1] - q[1]) / (dr as f64).hypot(dc as f64));
            }
        }
        // The other diagonal, which alternate-square sampling leaves as the only link.
        if c >= 1
            && let Some(q) = by_square.get(&[r + 1, c - 1])
        {
            out.push((p[0] - q[0]).hypot(p[1] - q[1]) / std::f64::consts::SQRT_2);
        }
    }
    out
}

/// Distance from each distinct sample position to its nearest neighbour.
fn nearest_neighbour_distances(samples: &[&BlurSample]) -> Vec<f64> {
    let mut pts: Vec<[f64; 2]> = samples.iter().map(|s| [s.x, s.y]).collect();
    pts.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup_by(|a, b| (a[0] - b[0]).abs() < 0.5 && (a[1] - b[1]).abs() < 0.5);
    if pts.len() < 2 {
        return Vec::new();
    }
    pts.iter()
        .enumerate()
        .map(|(i, p)| {
            pts.iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| (p[0] - q[0]).hypot(p[1] - q[1]))
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// Adds what `more` knows to `into`; a field both know differently is returned as
/// (name, known, other): a session's shots must come from one camera and lens unit.
fn merge_identity(
    into: &mut CameraIdentity,
    more: &CameraIdentity,
) -> Result<(), (&'static str, String, String)> {
    for (name, mine, theirs) in [
        ("make", &mut into.make, &more.make),
        ("model", &mut into.model, &more.model),
        ("body serial", &mut into.body_serial, &more.body_serial),
        ("lens", &mut into.lens_model, &more.lens_model),
        ("lens serial", &mut into.lens_serial, &more.lens_serial),
    ] {
        match (mine.as_ref(), theirs) {
            (Some(a), Some(b)) if a.trim() != b.trim() => {
                return Err((name, a.clone(), b.clone()));
            }
            (None, Some(b)) => *mine = Some(b.clone()),
            _ => {}
        }
    }
    Ok(())
}

/// How raw coordinates map to the [−1, 1] ranges the basis is evaluated on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    pub width: usize,
    pub height: usize,
    /// Calibrated focal range; f maps linearly to [−1, 1] over it.
    pub focal_range_mm: [f64; 2],
    /// Calibrated f-number range; a maps to [−1, 1] linearly in stops (log a).
    pub f_number_range: [f64; 2],
    /// Bounding box `[x0, y0, x1, y1]` (pixels) of the measured squares' centres. The
    /// chart rarely covers the whole sensor, and a polynomial evaluated beyond its data
    /// grows without bound (an order-8 one by tens of % of range at the corners, a
    /// local quadratic by far more), so outside this box the models extrapolate
    /// linearly from its border instead; see [`Normalisation::extrapolate`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampled_extent_px: Option<[f64; 4]>,
}

impl Normalisation {
    #[must_use]
    pub fn uses_focal(&self) -> bool {
        self.focal_range_mm[1] > self.focal_range_mm[0] * (1.0 + 1e-6)
    }

    #[must_use]
    pub fn uses_aperture(&self) -> bool {
        self.f_number_range[1] > self.f_number_range[0] * (1.0 + 1e-6)
    }

    /// Sensor position to [−1, 1]².
    #[must_use]
    pub fn uv(&self, x: f64, y: f64) -> (f64, f64) {
        (
            2.0 * x / (self.width.max(2) as f64 - 1.0) - 1.0,
            2.0 * y / (self.height.max(2) as f64 - 1.0) - 1.0,
        )
    }

    /// Setting to [−1, 1]² (0 along a setting that does not vary).
    #[must_use]
    pub fn fa(&self, s: LensSetting) -> (f64, f64) {
        let [f0, f1] = self.focal_range_mm;
        let [a0, a1] = self.f_number_range;
        let nf = if self.uses_focal() {
            2.0 * (s.focal_mm - f0) / (f1 - f0) - 1.0
        } else {
            0.0
        };
        let na = if self.uses_aperture() {
            2.0 * (s.f_number.ln() - a0.ln()) / (a1.ln() - a0.ln()) - 1.0
        } else {
            0.0
        };
        (nf, na)
    }

    /// Whether a sensor point lies inside the area the calibration measured.
    #[must_use]
    pub fn in_sampled_extent(&self, x: f64, y: f64) -> bool {
        self.sampled_extent_px
            .is_none_or(|e| x >= e[0] && x <= e[2] && y >= e[1] && y <= e[3])
    }

    /// `eval` at (x, y) inside the sampled extent; outside it, the value at the nearest
    /// point of the extent's box plus the slope there (a one-sided difference over 2 %
    /// of the sensor, taken inwards) times the distance. Continuous across the border,
    /// and growing at most linearly where nothing was measured.
    pub fn extrapolate(&self, x: f64, y: f64, eval: impl Fn(f64, f64) -> [f64; 3]) -> [f64; 3] {
        let Some(e) = self.sampled_extent_px else {
            return eval(x, y);
        };
        let (cx, cy) = (x.clamp(e[0], e[2]), y.clamp(e[1], e[3]));
        if cx == x && cy == y {
            return eval(x, y);
        }
        let base = eval(cx, cy);
        let mut out = base;
        let step = 0.02 * self.width.max(self.height) as f64;
        let mut add_slope = |d: f64, lo: f64, hi: f64, at: &dyn Fn(f64) -> [f64; 3]| {
            let h = step.min(hi - lo);
            if d == 0.0 || h <= 0.0 {
                return;
            }
            // Inwards from the border the point was clamped to.
            let inner = at(if d < 0.0 { h } else { -h });
            for k in 0..3 {
                out[k] += (base[k] - inner[k]) / h * d.abs();
            }
        };
        add_slope(x - cx, e[0], e[2], &|dx| eval(cx + dx, cy));
        add_slope(y - cy, e[1], e[3], &|dy| eval(cx, cy + dy));
        out
    }

    /// Whether a setting lies in the calibrated range, widened by the tolerance under
    /// which two values are the same setting ([`LensSetting::RELATIVE_TOLERANCE`]).
    #[must_use]
    pub fn contains(&self, s: LensSetting) -> bool {
        let tol = LensSetting::RELATIVE_TOLERANCE;
        let inside = |v: f64, r: [f64; 2]| v >= r[0] * (1.0 - tol) && v <= r[1] * (1.0 + tol);
        inside(s.focal_mm, self.focal_range_mm) && inside(s.f_number, self.f_number_range)
    }
}

/// The monomials x^i y^j f^k a^l of G_{α,β} (or L_{α,β}) as exponent quadruples, in a
/// fixed order. Terms in a setting that does not vary (`use_f`/`use_a` false) are left
/// out, which makes a single-focal session a model over a only, and a single-setting
/// session spatial only.
#[must_use]
pub fn terms(alpha: usize, beta: usize, use_f: bool, use_a: bool) -> Vec<[u8; 4]> {
    let total = alpha.max(beta);
    let mut out = Vec::new();
    for s in 0..=alpha {
        for t in 0..=beta {
            if s + t > total {
                continue;
            }
            for i in 0..=s {
                let j = s - i;
                for k in 0..=t {
                    let l = t - k;
                    if (k > 0 && !use_f) || (l > 0 && !use_a) {
                        continue;
                    }
                    out.push([i as u8, j as u8, k as u8, l as u8]);
                }
            }
        }
    }
    out
}

/// P_0(t) … P_n(t) by the three-term recurrence.
fn legendre(n: usize, t: f64, out: &mut [f64]) {
    out[0] = 1.0;
    if n >= 1 {
        out[1] = t;
    }
    for m in 1..n {
        let mf = m as f64;
        out[m + 1] = ((2.0 * mf + 1.0) * t * out[m] - mf * out[m - 1]) / (mf + 1.0);
    }
}

/// A Legendre product basis over a term list.
#[derive(Clone, Debug)]
pub struct Basis {
    terms: Vec<[u8; 4]>,
    max_deg: usize,
}

impl Basis {
    #[must_use]
    pub fn new(terms: Vec<[u8; 4]>) -> Self {
        let max_deg = terms
            .iter()
            .flat_map(|t| t.iter().copied())
            .max()
            .unwrap_or(0) as usize;
        Self { terms, max_deg }
    }

    #[must_use]
    pub fn len(&self) -> usize {
        self.terms.len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    #[must_use]
    pub fn terms(&self) -> &[[u8; 4]] {
        &self.terms
    }

    /// The per-coordinate Legendre values at normalised (u, v, f, a).
    fn tables(&self, c: [f64; 4]) -> [[f64; 16]; 4] {
        let mut tab = [[0.0; 16]; 4];
        for (d, &cv) in c.iter().enumerate() {
            legendre(self.max_deg, cv, &mut tab[d]);
        }
        tab
    }

    /// Writes the basis row at normalised coordinates into `out`.
    pub fn row(&self, c: [f64; 4], out: &mut [f64]) {
        let tab = self.tables(c);
        for (o, t) in out.iter_mut().zip(&self.terms) {
            *o = tab[0][t[0] as usize]
                * tab[1][t[1] as usize]
                * tab[2][t[2] as usize]
                * tab[3][t[3] as usize];
        }
    }

    /// Σ coeffs[p][n] · basis_n for each of the three parameters.
    #[must_use]
    pub fn eval3(&self, c: [f64; 4], coeffs: &[Vec<f64>; 3]) -> [f64; 3] {
        let tab = self.tables(c);
        let mut out = [0.0; 3];
        for (n, t) in self.terms.iter().enumerate() {
            let b = tab[0][t[0] as usize]
                * tab[1][t[1] as usize]
                * tab[2][t[2] as usize]
                * tab[3][t[3] as usize];
            for p in 0..3 {
                out[p] += coeffs[p][n] * b;
            }
        }
        out
    }
}

/// Least squares for three right-hand sides: QR, or SVD where R is (near) singular.
/// Returns `n × 3`.
#[must_use]
pub fn solve_lsq(a: DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let (m, n) = a.shape();
    if m >= n && n > 0 {
        let qr = a.clone().qr();
        let r = qr.r();
        let diag_max = (0..n).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
        let well_posed = (0..n).all(|i| r[(i, i)].abs() > 1e-10 * diag_max.max(1e-300));
        if well_posed {
            let mut qty = y.clone();
            qr.q_tr_mul(&mut qty);
            let top = qty.rows(0, n).into_owned();
            if let Some(x) = r.solve_upper_triangular(&top) {
                return x;
            }
        }
    }
    let svd = a.svd(true, true);
    svd.solve(y, 1e-10 * svd.singular_values.max().max(1e-300))
        .unwrap_or_else(|_| DMatrix::zeros(n, y.ncols()))
}

/// Solves the normal equations `gram · x = rhs` (Cholesky; SVD pseudo-inverse where the
/// Gram matrix is singular). Used by cross-validation, whose folds reuse per-shot Gram
/// sums; in the orthogonal basis these agree with [`solve_lsq`] to rounding.
#[must_use]
pub fn solve_normal(gram: DMatrix<f64>, rhs: &DMatrix<f64>) -> DMatrix<f64> {
    let n = gram.nrows();
    if let Some(ch) = gram.clone().cholesky() {
        let x = ch.solve(rhs);
        if x.iter().all(|v| v.is_finite()) {
            return x;
        }
    }
    let svd = gram.svd(true, true);
    svd.solve(rhs, 1e-12 * svd.singular_values.max().max(1e-300))
        .unwrap_or_else(|_| DMatrix::zeros(n, rhs.ncols()))
}

/// Three polynomials in (u, v) only: a model's terms at one fixed setting, with the
/// factors P_k(f) P_l(a) folded into the spatial coefficients. A whole field at one
/// setting then costs one small spatial polynomial per point instead of the full
/// four-dimensional basis.
#[derive(Clone, Debug)]
pub struct SpatialPoly {
    terms: Vec<[u8; 2]>,
    max_deg: usize,
    coeffs: [Vec<f64>; 3],
}

impl SpatialPoly {
    fn fold(basis: &Basis, coeffs: &[Vec<f64>; 3], nf: f64, na: f64) -> Self {
        let mut pf = [0.0; MAX_ORDER + 1];
        let mut pa = [0.0; MAX_ORDER + 1];
        legendre(basis.max_deg, nf, &mut pf);
        legendre(basis.max_deg, na, &mut pa);
        let mut index = [[usize::MAX; MAX_ORDER + 1]; MAX_ORDER + 1];
        let mut terms: Vec<[u8; 2]> = Vec::new();
        let mut out: [Vec<f64>; 3] = Default::default();
        for (n, t) in basis.terms.iter().enumerate() {
            let (i, j) = (t[0] as usize, t[1] as usize);
            if index[i][j] == usize::MAX {
                index[i][j] = terms.len();
                terms.push([t[0], t[1]]);
                for o in &mut out {
                    o.push(0.0);
                }
            }
            let w = pf[t[2] as usize] * pa[t[3] as usize];
            for p in 0..3 {
                out[p][index[i][j]] += coeffs[p][n] * w;
            }
        }
        let max_deg = terms
            .iter()
            .flat_map(|t| t.iter().copied())
            .max()
            .unwrap_or(0) as usize;
        Self {
            terms,
            max_deg,
            coeffs: out,
        }
    }

    #[must_use]
    pub fn eval(&self, u: f64, v: f64) -> [f64; 3] {
        let mut pu = [0.0; MAX_ORDER + 1];
        let mut pv = [0.0; MAX_ORDER + 1];
        legendre(self.max_deg, u, &mut pu);
        legendre(self.max_deg, v, &mut pv);
        let mut out = [0.0; 3];
        for (n, t) in self.terms.iter().enumerate() {
            let b = pu[t[0] as usize] * pv[t[1] as usize];
            for (o, c) in out.iter_mut().zip(&self.coeffs) {
                *o += c[n] * b;
            }
        }
        out
    }
}

/// One channel of a model at one fixed setting (see [`SpatialPoly`]): predicts exactly
/// what the model's `predict` does at that setting, faster.
#[derive(Clone, Debug)]
pub enum FieldAtSetting {
    Global {
        norm: Normalisation,
        poly: SpatialPoly,
    },
    Local {
        norm: Normalisation,
        grid: CentreGrid,
        polys: Vec<SpatialPoly>,
    },
}

impl FieldAtSetting {
    /// C_xx, C_yy, C_or at sensor (x, y).
    #[must_use]
    pub fn predict(&self, x: f64, y: f64) -> [f64; 3] {
        match self {
            Self::Global { norm, poly } => norm.extrapolate(x, y, |x, y| {
                let (u, v) = norm.uv(x, y);
                poly.eval(u, v)
            }),
            Self::Local { norm, grid, polys } => norm.extrapolate(x, y, |x, y| {
                let mut out = [0.0; 3];
                for (idx, w) in grid.blend(x, y) {
                    if w == 0.0 {
                        continue;
                    }
                    let (u, v) = grid.local_uv(idx, x, y);
                    let p = polys[idx].eval(u, v);
                    for k in 0..3 {
                        out[k] += w * p[k];
                    }
                }
                out
            }),
        }
    }
}

/// Predicted C_xx, C_yy, C_or as a Gaussian, kept physical: σ at least 0.05 px,
/// |ρ| below 0.99.
#[must_use]
pub fn to_gaussian(p: [f64; 3]) -> Gaussian2 {
    Gaussian2 {
        sigma_x: p[0].max(0.05),
        sigma_y: p[1].max(0.05),
        rho: p[2].clamp(-0.99, 0.99),
    }
}

/// Which model family.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    Global,
    Local,
}

/// One channel's coefficients: `coeffs[p][n]` for parameter p (C_xx, C_yy, C_or) and
/// basis term n.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelCoeffs {
    pub channel: Channel,
    pub coeffs: [Vec<f64>; 3],
}

/// A fitted global model G_{α,β}.
#[derive(Clone, Debug)]
pub struct GlobalModel {
    pub norm: Normalisation,
    pub alpha: usize,
    pub beta: usize,
    pub basis: Basis,
    pub channels: Vec<ChannelCoeffs>,
}

/// The basis of G_{α,β} (or L_{α,β}) under a normalisation.
#[must_use]
pub fn model_basis(norm: &Normalisation, alpha: usize, beta: usize) -> Basis {
    Basis::new(terms(alpha, beta, norm.uses_focal(), norm.uses_aperture()))
}

fn samples_of(ds: &Dataset, channel: Channel) -> Vec<&BlurSample> {
    ds.samples.iter().filter(|s| s.channel == channel).collect()
}

impl GlobalModel {
    /// Fits G_{α,β} per channel over all of `ds`.
    ///
    /// # Errors
    /// Unknown settings, β too large for the session, or fewer samples than terms.
    pub fn fit(ds: &Dataset, alpha: usize, beta: usize) -> Result<Self, ModelError> {
        ds.validate()?;
        check_order(alpha, beta)?;
        ds.check_beta(beta)?;
        let norm = ds.normalisation();
        let basis = model_basis(&norm, alpha, beta);
        let mut channels = Vec::new();
        for ch in ds.channels() {
            let samples = samples_of(ds, ch);
            if samples.len() < basis.len() {
                return Err(ModelError::TooFewSamples {
                    model: format!("G_{{{alpha},{beta}}} ({ch})"),
                    samples: samples.len(),
                    terms: basis.len(),
                });
            }
            let mut a = DMatrix::zeros(samples.len(), basis.len());
            let mut y = DMatrix::zeros(samples.len(), 3);
            let mut row = vec![0.0; basis.len()];
            for (r, s) in samples.iter().enumerate() {
                basis.row(
                    global_coords(&norm, s.x, s.y, s.focal_mm, s.f_number),
                    &mut row,
                );
                for (c, v) in row.iter().enumerate() {
                    a[(r, c)] = *v;
                }
                for (p, v) in s.params().iter().enumerate() {
                    y[(r, p)] = *v;
                }
            }
            let x = solve_lsq(a, &y);
            channels.push(ChannelCoeffs {
                channel: ch,
                coeffs: split_coeffs(&x),
            });
        }
        Ok(Self {
            norm,
            alpha,
            beta,
            basis,
            channels,
        })
    }

    /// C_xx, C_yy, C_or at a sensor position and setting; `None` for a channel the
    /// model does not hold (Y falls back to G).
    #[must_use]
    pub fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<[f64; 3]> {
        let cc = find_channel(&self.channels, channel)?;
        Some(self.norm.extrapolate(x, y, |x, y| {
            self.basis.eval3(
                global_coords(&self.norm, x, y, s.focal_mm, s.f_number),
                &cc.coeffs,
            )
        }))
    }
}

impl GlobalModel {
    /// One channel at one setting, for evaluating a whole field quickly.
    #[must_use]
    pub fn at_setting(&self, channel: Channel, s: LensSetting) -> Option<FieldAtSetting> {
        let cc = find_channel(&self.channels, channel)?;
        let (nf, na) = self.norm.fa(s);
        Some(FieldAtSetting::Global {
            norm: self.norm.clone(),
            poly: SpatialPoly::fold(&self.basis, &cc.coeffs, nf, na),
        })
    }
}

/// Normalised (u, v, f, a) of a sample for the global model.
#[must_use]
pub fn global_coords(
    norm: &Normalisation,
    x: f64,
    y: f64,
    focal_mm: f64,
    f_number: f64,
) -> [f64; 4] {
    let (u, v) = norm.uv(x, y);
    let (nf, na) = norm.fa(LensSetting { focal_mm, f_number });
    [u, v, nf, na]
}

pub(crate) fn split_coeffs(x: &DMatrix<f64>) -> [Vec<f64>; 3] {
    [
        x.column(0).iter().copied().collect(),
        x.column(1).iter().copied().collect(),
        x.column(2).iter().copied().collect(),
    ]
}

pub(crate) fn find_channel(chs: &[ChannelCoeffs], channel: Channel) -> Option<&ChannelCoeffs> {
    chs.iter()
        .find(|c| c.channel == channel)
        .or_else(|| match channel {
            Channel::Y => chs.iter().find(|c| c.channel == Channel::G),
            Channel::G => chs.iter().find(|c| c.channel == Channel::Y),
            _ => None,
        })
}

/// Options of the local model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalOptions {
    /// Fit radius in pixels; default 3× the largest imaged square.
    pub radius_px: Option<f64>,
    /// Centre spacing as a fraction of the radius. At 1/√2 every point of a grid cell
    /// lies within the radius of all four centres that blend there.
    pub spacing_of_radius: f64,
}

impl Default for LocalOptions {
    fn default() -> Self {
        Self {
            radius_px: None,
            spacing_of_radius: std::f64::consts::FRAC_1_SQRT_2,
        }
    }
}

/// The grid of local-model centres over the sensor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CentreGrid {
    pub nx: usize,
    pub ny: usize,
    pub radius_px: f64,
    pub width: usize,
    pub height: usize,
}

impl CentreGrid {
    #[must_use]
    pub fn new(width: usize, height: usize, radius_px: f64, spacing_of_radius: f64) -> Self {
        let spacing = (radius_px * spacing_of_radius).max(1.0);
        let n = |len: usize| (((len.max(2) - 1) as f64 / spacing).ceil() as usize + 1).max(2);
        Self {
            nx: n(width),
            ny: n(height),
            radius_px,
            width,
            height,
        }
    }

    #[must_use]
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn step(&self) -> (f64, f64) {
        (
            (self.width.max(2) - 1) as f64 / (self.nx - 1) as f64,
            (self.height.max(2) - 1) as f64 / (self.ny - 1) as f64,
        )
    }

    /// Sensor position of centre `idx` (row-major).
    #[must_use]
    pub fn centre(&self, idx: usize) -> [f64; 2] {
        let (sx, sy) = self.step();
        [(idx % self.nx) as f64 * sx, (idx / self.nx) as f64 * sy]
    }

    /// The (up to) four centres that blend at (x, y) with their weights, which sum to
    /// one and vary C¹-smoothly (smoothstep of the cell coordinate).
    #[must_use]
    pub fn blend(&self, x: f64, y: f64) -> [(usize, f64); 4] {
        let (sx, sy) = self.step();
        let cell = |p: f64, step: f64, n: usize| {
            let t = (p / step).clamp(0.0, (n - 1) as f64);
            let i = (t.floor() as usize).min(n - 2);
            let f = t - i as f64;
            (i, f * f * (3.0 - 2.0 * f))
        };
        let (i, wx) = cell(x, sx, self.nx);
        let (j, wy) = cell(y, sy, self.ny);
        let id = |i: usize, j: usize| j * self.nx + i;
        [
            (id(i, j), (1.0 - wx) * (1.0 - wy)),
            (id(i + 1, j), wx * (1.0 - wy)),
            (id(i, j + 1), (1.0 - wx) * wy),
            (id(i + 1, j + 1), wx * wy),
        ]
    }

    /// Normalised local (u, v) of a point around centre `idx`.
    #[must_use]
    pub fn local_uv(&self, idx: usize, x: f64, y: f64) -> (f64, f64) {
        let c = self.centre(idx);
        ((x - c[0]) / self.radius_px, (y - c[1]) / self.radius_px)
    }

    /// Indices (into `pts`) of the points within `radius_px · scale` of centre `idx`.
    #[must_use]
    pub fn within(&self, idx: usize, pts: &[[f64; 2]], scale: f64) -> Vec<usize> {
        let c = self.centre(idx);
        let r = self.radius_px * scale;
        pts.iter()
            .enumerate()
            .filter(|(_, p)| (p[0] - c[0]).hypot(p[1] - c[1]) <= r)
            .map(|(i, _)| i)
            .collect()
    }
}

/// A fitted local model L_{α,β}.
#[derive(Clone, Debug)]
pub struct LocalModel {
    pub norm: Normalisation,
    pub alpha: usize,
    pub beta: usize,
    pub grid: CentreGrid,
    pub basis: Basis,
    /// Per channel, per centre coefficients.
    pub channels: Vec<(Channel, Vec<[Vec<f64>; 3]>)>,
}

/// The radius (pixels) and grid of a local model for a session.
#[must_use]
pub fn local_grid(ds: &Dataset, opts: &LocalOptions) -> CentreGrid {
    let radius = opts
        .radius_px
        .unwrap_or_else(|| 3.0 * ds.largest_square_px());
    CentreGrid::new(ds.width, ds.height, radius, opts.spacing_of_radius)
}

/// Samples within a centre's radius, widening it (in steps of 1.25×) until they number
/// at least three per term, so edge and corner centres, and sparse sessions, stay well
/// posed; a centre whose widened circle covers the whole sensor takes what there is.
#[must_use]
pub fn local_members(
    grid: &CentreGrid,
    idx: usize,
    pts: &[[f64; 2]],
    n_terms: usize,
) -> Vec<usize> {
    let diagonal = (grid.width as f64).hypot(grid.height as f64);
    let mut scale = 1.0;
    loop {
        let m = grid.within(idx, pts, scale);
        if m.len() >= 3 * n_terms || grid.radius_px * scale >= diagonal {
            return m;
        }
        scale *= 1.25;
    }
}

impl LocalModel {
    /// Fits L_{α,β} per channel and centre.
    ///
    /// # Errors
    /// Unknown settings or β too large for the session.
    pub fn fit(
        ds: &Dataset,
        alpha: usize,
        beta: usize,
        opts: &LocalOptions,
    ) -> Result<Self, ModelError> {
        ds.validate()?;
        check_order(alpha, beta)?;
        ds.check_beta(beta)?;
        let norm = ds.normalisation();
        let basis = model_basis(&norm, alpha, beta);
        let grid = local_grid(ds, opts);
        let mut channels = Vec::new();
        for ch in ds.channels() {
            let samples = samples_of(ds, ch);
            if samples.len() < basis.len() {
                return Err(ModelError::TooFewSamples {
                    model: format!("L_{{{alpha},{beta}}} ({ch})"),
                    samples: samples.len(),
                    terms: basis.len(),
                });
            }
            let pts: Vec<[f64; 2]> = samples.iter().map(|s| [s.x, s.y]).collect();
            let fitted: Vec<[Vec<f64>; 3]> = {
                use rayon::prelude::*;
                (0..grid.len())
                    .into_par_iter()
                    .map(|idx| {
                        let members = local_members(&grid, idx, &pts, basis.len());
                        let mut a = DMatrix::zeros(members.len(), basis.len());
                        let mut y = DMatrix::zeros(members.len(), 3);
                        let mut row = vec![0.0; basis.len()];
                        for (r, &m) in members.iter().enumerate() {
                            let s = samples[m];
                            basis.row(
                                local_coords(&grid, &norm, idx, s.x, s.y, s.focal_mm, s.f_number),
                                &mut row,
                            );
                            for (c, v) in row.iter().enumerate() {
                                a[(r, c)] = *v;
                            }
                            for (p, v) in s.params().iter().enumerate() {
                                y[(r, p)] = *v;
                            }
                        }
                        split_coeffs(&solve_lsq(a, &y))
                    })
                    .collect()
            };
            channels.push((ch, fitted));
        }
        Ok(Self {
            norm,
            alpha,
            beta,
            grid,
            basis,
            channels,
        })
    }

    /// C_xx, C_yy, C_or at a sensor position and setting, blended over the four
    /// neighbouring centres.
    #[must_use]
    pub fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<[f64; 3]> {
        let per_centre = self.centres_of(channel)?;
        Some(self.norm.extrapolate(x, y, |x, y| {
            let mut out = [0.0; 3];
            for (idx, w) in self.grid.blend(x, y) {
                if w == 0.0 {
                    continue;
                }
                let p = self.basis.eval3(
                    local_coords(&self.grid, &self.norm, idx, x, y, s.focal_mm, s.f_number),
                    &per_centre[idx],
                );
                for k in 0..3 {
                    out[k] += w * p[k];
                }
            }
            out
        }))
    }
}

impl LocalModel {
    fn centres_of(&self, channel: Channel) -> Option<&Vec<[Vec<f64>; 3]>> {
        self.channels
            .iter()
            .find(|c| c.0 == channel)
            .or_else(|| match channel {
                Channel::Y => self.channels.iter().find(|c| c.0 == Channel::G),
                Channel::G => self.channels.iter().find(|c| c.0 == Channel::Y),
                _ => None,
            })
            .map(|c| &c.1)
    }

    /// One channel at one setting, for evaluating a whole field quickly.
    #[must_use]
    pub fn at_setting(&self, channel: Channel, s: LensSetting) -> Option<FieldAtSetting> {
        let centres = self.centres_of(channel)?;
        let (nf, na) = self.norm.fa(s);
        Some(FieldAtSetting::Local {
            norm: self.norm.clone(),
            grid: self.grid.clone(),
            polys: centres
                .iter()
                .map(|c| SpatialPoly::fold(&self.basis, c, nf, na))
                .collect(),
        })
    }
}

/// Normalised (u, v, f, a) of a point for the local fit around centre `idx`.
#[must_use]
pub fn local_coords(
    grid: &CentreGrid,
    norm: &Normalisation,
    idx: usize,
    x: f64,
    y: f64,
    focal_mm: f64,
    f_number: f64,
) -> [f64; 4] {
    let (u, v) = grid.local_uv(idx, x, y);
    let (nf, na) = norm.fa(LensSetting { focal_mm, f_number });
    [u, v, nf, na]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn legendre_matches_closed_forms() {
        let mut p = [0.0; 5];
        legendre(4, 0.3, &mut p);
        assert!((p[2] - 0.5 * (3.0 * 0.09 - 1.0)).abs() < 1e-12);
        assert!((p[3] - 0.5 * (5.0 * 0.027 - 3.0 * 0.3)).abs() < 1e-12);
        assert!((p[4] - (35.0 * 0.0081 - 30.0 * 0.09 + 3.0) / 8.0).abs() < 1e-12);
    }

    #[test]
    fn qr_and_normal_equations_agree() {
        let basis = Basis::new(terms(3, 2, true, true));
        let n = basis.len();
        let m = 400;
        let mut a = DMatrix::zeros(m, n);
        let mut y = DMatrix::zeros(m, 3);
        let mut row = vec![0.0; n];
        for r in 0..m {
            let t = r as f64;
            let c = [
                (t * 0.37).sin(),
                (t * 0.71).cos(),
                ((t * 0.13).sin()),
                (t * 0.29).cos(),
            ];
            basis.row(c, &mut row);
            for k in 0..n {
                a[(r, k)] = row[k];
            }
            for p in 0..3 {
                y[(r, p)] = c[0] * c[1] + (p as f64) * c[2] * c[3] * c[3] + 0.01 * (t * 1.7).sin();
            }
        }
        let x1 = solve_lsq(a.clone(), &y);
        let x2 = solve_normal(a.tr_mul(&a), &a.tr_mul(&y));
        assert!((x1 - x2).abs().max() < 1e-8);
    }
}

/// `n` values from `lo` to `hi`, evenly spaced (geometrically when `log`).
#[must_use]
pub fn spaced(lo: f64, hi: f64, n: usize, log: bool) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let t = if n > 1 {
                i as f64 / (n - 1) as f64
            } else {
                0.5
            };
            if log {
                (lo.ln() + t * (hi.ln() - lo.ln())).exp()
            } else {
                lo + t * (hi - lo)
            }
        })
        .collect()
}
