//! Blur variation models: per channel, three polynomials predicting
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
//!
//! The parts: `dataset` (the measured samples of a session and what its settings can
//! support), `basis` (normalisation, term lists, the Legendre basis and its solvers),
//! `global` (G_{α,β}) and `local` (L_{α,β}, its centres and their blending). Both
//! families answer through [`FittedModel`], the one interface that profiles,
//! cross-validation and the sweeps predict with; everything is re-exported here.

mod basis;
mod dataset;
mod global;
mod local;
mod place;
mod restoration;
mod shape;

pub use basis::{
    Basis, MAX_ORDER, Normalisation, SpatialPoly, check_order, model_basis, solve_lsq,
    solve_normal, terms,
};
pub(crate) use basis::{design_system, split_coeffs};
pub use dataset::{BlurSample, Dataset, PARAM_NAMES, ShotInfo};
pub use global::{ChannelCoeffs, GlobalModel, global_coords};
pub use local::{CentreGrid, LocalModel, LocalOptions, local_coords, local_grid, local_members};
pub use place::{
    ChannelPlace, LateralColour, MAX_PLACE_ALPHA, MAX_PLACE_BETA, PlaceCv, PlaceModel, centroid_px,
};
pub use restoration::{RestorationError, WIENER_NSR};
#[cfg(test)]
pub(crate) use shape::kernel_with_shape_at;
pub use shape::{
    KernelModel, MAX_COMPONENTS, PIXEL_SIDE, PlacedShape, ShapeFit, ShapeModel, ShapeSpace,
    WHITENED_LEN, WHITENED_PER_SIGMA, WHITENED_SIDE, kernel_with_residual, kernel_with_shape,
    psf_mass, relative_l2, session_residuals, shape_basis, shape_residual, whitened_residual,
};
pub(crate) use shape::{PreparedKernels, Whitening, deployed_kernel_side};

use crate::plane::{Channel, LensSetting};
use crate::psf::Gaussian2;
use serde::{Deserialize, Serialize};

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
        "cross-validation needs at least 2 shots, this session has {shots}: add shots, or choose the orders yourself (lensblur calibrate --alpha and --beta)"
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

/// Which model family.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    Global,
    Local,
}

impl ModelKind {
    /// The model's name as the paper writes it: `G_{α,β}` or `L_{α,β}`.
    #[must_use]
    pub fn model_name(self, alpha: usize, beta: usize) -> String {
        let letter = match self {
            Self::Global => 'G',
            Self::Local => 'L',
        };
        format!("{letter}_{{{alpha},{beta}}}")
    }

    /// The model's symbol as the studio prints it, with subscripts: `G₄,₂`.
    #[must_use]
    pub fn symbol(self, alpha: usize, beta: usize) -> String {
        let sub = |n: usize| -> String {
            n.to_string()
                .chars()
                .map(|c| char::from_u32(0x2080 + c.to_digit(10).unwrap_or(0)).unwrap_or(c))
                .collect()
        };
        let letter = match self {
            Self::Global => 'G',
            Self::Local => 'L',
        };
        format!("{letter}{},{}", sub(alpha), sub(beta))
    }

    /// The model in words: "polynomial, order 4 in position, 2 in focal length and
    /// aperture" (the local one: "local polynomials, …").
    #[must_use]
    pub fn in_words(self, alpha: usize, beta: usize) -> String {
        let what = match self {
            Self::Global => "polynomial",
            Self::Local => "local polynomials",
        };
        format!("{what}, order {alpha} in position, {beta} in focal length and aperture")
    }

    /// A name [`Self::model_name`] made (`G_{4,2}`), read back: the family, α and β.
    #[must_use]
    pub fn parse_name(name: &str) -> Option<(Self, usize, usize)> {
        let kind = match name.get(..3)? {
            "G_{" => Self::Global,
            "L_{" => Self::Local,
            _ => return None,
        };
        let (a, b) = name.get(3..)?.strip_suffix('}')?.split_once(',')?;
        Some((kind, a.trim().parse().ok()?, b.trim().parse().ok()?))
    }
}

/// A fitted model of either family. Profiles, cross-validation, test-set evaluation and
/// the sweeps all predict through this, so none of them needs to know which family it
/// holds.
pub trait FittedModel: Send + Sync {
    fn kind(&self) -> ModelKind;

    /// (α, β).
    fn orders(&self) -> (usize, usize);

    /// Basis terms per channel (per centre, for a local model).
    fn terms(&self) -> usize;

    fn normalisation(&self) -> &Normalisation;

    /// The channels the model holds, in the order they were fitted.
    fn channels(&self) -> Vec<Channel>;

    /// C_xx, C_yy, C_or at a sensor position and setting; `None` for a channel the
    /// model does not hold (Y and G stand in for each other).
    fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<[f64; 3]>;

    /// One channel at one setting, for evaluating a whole field quickly: the values
    /// [`FittedModel::predict`] gives at that setting, at a fraction of the cost.
    fn at_setting(&self, channel: Channel, s: LensSetting) -> Option<FieldAtSetting>;

    /// `G_{α,β}` or `L_{α,β}`.
    fn name(&self) -> String {
        let (alpha, beta) = self.orders();
        self.kind().model_name(alpha, beta)
    }
}

/// Fits a model of `kind` to `ds` (`local` is used by the local family only).
///
/// # Errors
/// As [`GlobalModel::fit`] and [`LocalModel::fit`].
pub fn fit_model(
    ds: &Dataset,
    kind: ModelKind,
    alpha: usize,
    beta: usize,
    local: &LocalOptions,
) -> Result<Box<dyn FittedModel>, ModelError> {
    Ok(match kind {
        ModelKind::Global => Box::new(GlobalModel::fit(ds, alpha, beta)?),
        ModelKind::Local => Box::new(LocalModel::fit(ds, alpha, beta, local)?),
    })
}

/// What fitting either family starts with: `ds` checked for the orders, its
/// normalisation and the model's basis.
pub(crate) fn fit_setup(
    ds: &Dataset,
    alpha: usize,
    beta: usize,
) -> Result<(Normalisation, Basis), ModelError> {
    ds.validate()?;
    check_order(alpha, beta)?;
    ds.check_beta(beta)?;
    let norm = ds.normalisation();
    let basis = model_basis(&norm, alpha, beta);
    Ok((norm, basis))
}

/// The samples of channel `ch` a model of `kind` is fitted to, at least one per basis
/// term (`terms`).
pub(crate) fn fit_samples(
    ds: &Dataset,
    kind: ModelKind,
    (alpha, beta): (usize, usize),
    ch: Channel,
    terms: usize,
) -> Result<Vec<&BlurSample>, ModelError> {
    let samples = ds.samples_of(ch);
    if samples.len() < terms {
        return Err(ModelError::TooFewSamples {
            model: format!("{} ({ch})", kind.model_name(alpha, beta)),
            samples: samples.len(),
            terms,
        });
    }
    Ok(samples)
}

/// The [`FittedModel`] methods both families answer from the same fields (`norm`,
/// `alpha`, `beta`, `basis` and a list of channels).
macro_rules! fitted_model_fields {
    ($kind:expr, $channel_of:expr) => {
        fn kind(&self) -> ModelKind {
            $kind
        }

        fn orders(&self) -> (usize, usize) {
            (self.alpha, self.beta)
        }

        fn terms(&self) -> usize {
            self.basis.len()
        }

        fn normalisation(&self) -> &Normalisation {
            &self.norm
        }

        fn channels(&self) -> Vec<Channel> {
            self.channels.iter().map($channel_of).collect()
        }
    };
}
pub(crate) use fitted_model_fields;

/// The entry of `entries` for `channel`; a model fitted to monochrome (Y) samples
/// answers for G and one fitted to colour answers for Y, so a profile made from RAW
/// shots serves a monochrome photo and the other way round.
pub(crate) fn find_channel<T>(
    entries: &[T],
    channel: Channel,
    channel_of: impl Fn(&T) -> Channel,
) -> Option<&T> {
    let find = |c: Channel| entries.iter().find(|e| channel_of(e) == c);
    find(channel).or_else(|| match channel {
        Channel::Y => find(Channel::G),
        Channel::G => find(Channel::Y),
        _ => None,
    })
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
                grid.blended(x, y, |idx| {
                    let (u, v) = grid.local_uv(idx, x, y);
                    polys[idx].eval(u, v)
                })
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

pub use crate::plane::spaced;

#[cfg(test)]
mod tests {
    use super::ModelKind;

    #[test]
    fn a_model_name_reads_back_and_reads_in_words() {
        let name = ModelKind::Global.model_name(4, 2);
        assert_eq!(name, "G_{4,2}");
        assert_eq!(
            ModelKind::parse_name(&name),
            Some((ModelKind::Global, 4, 2))
        );
        assert_eq!(
            ModelKind::parse_name("L_{10,3}"),
            Some((ModelKind::Local, 10, 3))
        );
        assert_eq!(ModelKind::parse_name("G_{4}"), None);
        assert_eq!(ModelKind::parse_name("X_{4,2}"), None);
        assert_eq!(ModelKind::Global.symbol(4, 2), "G₄,₂");
        assert_eq!(ModelKind::Local.symbol(12, 0), "L₁₂,₀");
        assert_eq!(
            ModelKind::Global.in_words(4, 2),
            "polynomial, order 4 in position, 2 in focal length and aperture"
        );
    }
}
