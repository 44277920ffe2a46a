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

/// One measured Gaussian: a square of a shot, one channel.
#[derive(Clone, Debug, PartialEq)]
pub struct BlurSample {
    pub shot: usize,
    pub x: f64,
    pub y: f64,
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

    /// Distinct focal lengths and f-numbers (sorted), merged within 0.1 %.
    #[must_use]
    pub fn distinct_settings(&self) -> (Vec<f64>, Vec<f64>) {
        let dedup = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.dedup_by(|a, b| (*a - *b).abs() <= 1e-3 * b.abs());
            v
        };
        (
            dedup(self.shots.iter().map(|s| s.focal_mm).collect()),
            dedup(self.shots.iter().map(|s| s.f_number).collect()),
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
        }
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

    /// Checks β against the sampling of the settings.
    ///
    /// # Errors
    /// [`ModelError::BetaTooLarge`] with the counts.
    pub fn check_beta(&self, beta: usize) -> Result<(), ModelError> {
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
        Ok(())
    }

    /// The width of the largest imaged square, in pixels, estimated as the largest
    /// per-shot median distance between neighbouring sample positions.
    #[must_use]
    pub fn largest_square_px(&self) -> f64 {
        let mut best: f64 = 0.0;
        for shot in 0..self.shots.len() {
            let mut pts: Vec<[f64; 2]> = self
                .samples
                .iter()
                .filter(|s| s.shot == shot)
                .map(|s| [s.x, s.y])
                .collect();
            pts.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
            pts.dedup_by(|a, b| (a[0] - b[0]).abs() < 0.5 && (a[1] - b[1]).abs() < 0.5);
            if pts.len() < 2 {
                continue;
            }
            let mut nn: Vec<f64> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    pts.iter()
                        .enumerate()
                        .filter(|&(j, _)| j != i)
                        .map(|(_, q)| (p[0] - q[0]).hypot(p[1] - q[1]))
                        .fold(f64::INFINITY, f64::min)
                })
                .collect();
            nn.sort_by(f64::total_cmp);
            best = best.max(nn[nn.len() / 2]);
        }
        if best > 0.0 {
            best
        } else {
            self.width.max(self.height) as f64 / 10.0
        }
    }
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

    /// Whether a setting lies in the calibrated range (with a 0.1 % tolerance for
    /// rounded EXIF values).
    #[must_use]
    pub fn contains(&self, s: LensSetting) -> bool {
        let inside = |v: f64, r: [f64; 2]| v >= r[0] * (1.0 - 1e-3) && v <= r[1] * (1.0 + 1e-3);
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
        Some(self.basis.eval3(
            global_coords(&self.norm, x, y, s.focal_mm, s.f_number),
            &cc.coeffs,
        ))
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

/// Samples within a centre's radius, widening it (up to 2×) where they are too few for
/// the terms, so edge and corner centres stay well posed.
pub(crate) fn local_members(
    grid: &CentreGrid,
    idx: usize,
    pts: &[[f64; 2]],
    n_terms: usize,
) -> Vec<usize> {
    let mut scale = 1.0;
    loop {
        let m = grid.within(idx, pts, scale);
        if m.len() >= 3 * n_terms || scale >= 2.0 {
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
        ds.check_beta(beta)?;
        let norm = ds.normalisation();
        let basis = model_basis(&norm, alpha, beta);
        let grid = local_grid(ds, opts);
        let mut channels = Vec::new();
        for ch in ds.channels() {
            let samples = samples_of(ds, ch);
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
        let per_centre = self
            .channels
            .iter()
            .find(|c| c.0 == channel)
            .or_else(|| match channel {
                Channel::Y => self.channels.iter().find(|c| c.0 == Channel::G),
                Channel::G => self.channels.iter().find(|c| c.0 == Channel::Y),
                _ => None,
            })
            .map(|c| &c.1)?;
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
        Some(out)
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

/// Measurement noise of simulated samples: relative on σ, absolute on ρ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleNoise {
    pub sigma_rel: f64,
    pub rho_abs: f64,
    /// Per-shot chart pose jitter: translation (px) and rotation (rad).
    pub shift_px: f64,
    pub rotation_rad: f64,
}

impl Default for SampleNoise {
    /// Close to real kernel estimates: 2 % on σ, 0.02 on ρ, a hand-held chart.
    fn default() -> Self {
        Self {
            sigma_rel: 0.02,
            rho_abs: 0.02,
            shift_px: 25.0,
            rotation_rad: 0.01,
        }
    }
}

/// A session measured directly from a virtual lens's truth: at the centres of a
/// `cols × rows` chart filling a `width × height` sensor (posed with jitter per shot),
/// the pixel-level Gaussian (optical ∗ pixel box) plus measurement noise. Fast stand-in
/// for detection + kernel estimation, for tests and benchmarks.
#[must_use]
pub fn simulated_dataset(
    lens: &crate::simulate::lens::VirtualLens,
    width: usize,
    height: usize,
    (cols, rows): (usize, usize),
    settings: &[LensSetting],
    shots_per_setting: usize,
    noise: &SampleNoise,
    seed: u64,
) -> Dataset {
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let std_normal = Normal::new(0.0, 1.0).unwrap_or_else(|_| unreachable!());
    let identity = CameraIdentity {
        make: Some(lens.make.clone()),
        model: Some(lens.model.clone()),
        body_serial: None,
        lens_model: Some(lens.model.clone()),
        lens_serial: Some(lens.serial.clone()),
    };
    let mut ds = Dataset::new(width, height, identity);
    let (sq_x, sq_y) = (width as f64 / cols as f64, height as f64 / rows as f64);
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    for (si, &setting) in settings.iter().enumerate() {
        for rep in 0..shots_per_setting {
            let dx = rng.random_range(-1.0..1.0) * noise.shift_px;
            let dy = rng.random_range(-1.0..1.0) * noise.shift_px;
            let th = rng.random_range(-1.0..1.0) * noise.rotation_rad;
            let (s, c) = th.sin_cos();
            let mut samples = Vec::new();
            for r in 0..rows {
                for q in 0..cols {
                    let (px, py) = (
                        (q as f64 + 0.5) * sq_x - 0.5 - cx,
                        (r as f64 + 0.5) * sq_y - 0.5 - cy,
                    );
                    let x = cx + c * px - s * py + dx;
                    let y = cy + s * px + c * py + dy;
                    if x < 0.0 || y < 0.0 || x > width as f64 - 1.0 || y > height as f64 - 1.0 {
                        continue;
                    }
                    for ch in [Channel::R, Channel::G, Channel::B] {
                        let g = lens
                            .gaussian_at(ch, x, y, width, height, setting)
                            .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
                        let mut n = || std_normal.sample(&mut rng);
                        let gaussian = Gaussian2 {
                            sigma_x: g.sigma_x * (1.0 + noise.sigma_rel * n()),
                            sigma_y: g.sigma_y * (1.0 + noise.sigma_rel * n()),
                            rho: (g.rho + noise.rho_abs * n()).clamp(-0.99, 0.99),
                        };
                        samples.push(BlurSample {
                            shot: 0,
                            x,
                            y,
                            focal_mm: 0.0,
                            f_number: 0.0,
                            channel: ch,
                            gaussian,
                        });
                    }
                }
            }
            ds.push_shot(
                ShotInfo {
                    name: format!("sim-{si:02}-{rep}"),
                    focal_mm: setting.focal_mm,
                    f_number: setting.f_number,
                },
                samples,
            );
        }
    }
    ds
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
