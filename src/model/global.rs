//! The global model G_{α,β}: one polynomial per channel and parameter over the whole
//! sensor and every calibrated setting.

use super::basis::{Basis, Normalisation, SpatialPoly, solve_lsq};
use super::{
    Dataset, FieldAtSetting, FittedModel, ModelError, ModelKind, design_system, find_channel,
    fit_samples, fit_setup, fitted_model_fields,
};
use crate::plane::{Channel, LensSetting};
use rayon::prelude::*;

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
        let (norm, basis) = fit_setup(ds, alpha, beta)?;
        // Channels in parallel; each is its own least-squares problem.
        let channels = ds
            .channels()
            .into_par_iter()
            .map(|ch| {
                let samples = fit_samples(ds, ModelKind::Global, (alpha, beta), ch, basis.len())?;
                let (a, y) = design_system(
                    &basis,
                    samples.iter().map(|s| {
                        (
                            global_coords(&norm, s.x, s.y, s.focal_mm, s.f_number),
                            s.params(),
                        )
                    }),
                );
                Ok(ChannelCoeffs {
                    channel: ch,
                    coeffs: super::split_coeffs(&solve_lsq(a, &y)),
                })
            })
            .collect::<Vec<Result<_, ModelError>>>()
            // The first channel's error in channel order, whichever thread met it first.
            .into_iter()
            .collect::<Result<Vec<_>, _>>()?;
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
    fitted_model_fields!(ModelKind::Global, |c| c.channel);

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
