//! The global model G_{α,β}: one polynomial per channel and parameter over the whole
//! sensor and every calibrated setting.

use super::basis::{Basis, Normalisation, SpatialPoly, check_order, model_basis, solve_lsq};
use super::{Dataset, FieldAtSetting, FittedModel, ModelError, ModelKind, find_channel};
use crate::plane::{Channel, LensSetting};
use nalgebra::DMatrix;

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
            let samples = ds.samples_of(ch);
            if samples.len() < basis.len() {
                return Err(ModelError::TooFewSamples {
                    model: format!("{} ({ch})", ModelKind::Global.model_name(alpha, beta)),
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
                coeffs: super::split_coeffs(&x),
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

    fn coeffs_of(&self, channel: Channel) -> Option<&ChannelCoeffs> {
        find_channel(&self.channels, channel, |c| c.channel)
    }
}

impl FittedModel for GlobalModel {
    fn kind(&self) -> ModelKind {
        ModelKind::Global
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
        self.channels.iter().map(|c| c.channel).collect()
    }

    fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<[f64; 3]> {
        let cc = self.coeffs_of(channel)?;
        Some(self.norm.extrapolate(x, y, |x, y| {
            self.basis.eval3(
                global_coords(&self.norm, x, y, s.focal_mm, s.f_number),
                &cc.coeffs,
            )
        }))
    }

    fn at_setting(&self, channel: Channel, s: LensSetting) -> Option<FieldAtSetting> {
        let cc = self.coeffs_of(channel)?;
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
