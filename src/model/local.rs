//! The local model L_{α,β}: the form of G_{α,β} fitted around each centre of a grid to
//! the samples within a radius, and blended between the four centres around a point
//! with C¹ weights that sum to one ([`CentreGrid::blended`], the one place the blend is
//! computed), so the field has no seams.

use super::basis::{Basis, Normalisation, SpatialPoly, solve_lsq};
use super::{
    Dataset, FieldAtSetting, FittedModel, ModelError, ModelKind, design_system, find_channel,
    fit_samples, fit_setup, fitted_model_fields,
};
use crate::plane::{Channel, LensSetting};
use serde::{Deserialize, Serialize};

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

    /// The blend at (x, y) of what `at_centre` gives for each of the (up to) four
    /// centres there: Σ wᵢ · at_centre(i) over [`CentreGrid::blend`]. Centres of zero
    /// weight are not evaluated (their fits may lie far outside their radius).
    pub fn blended(
        &self,
        x: f64,
        y: f64,
        mut at_centre: impl FnMut(usize) -> [f64; 3],
    ) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (idx, w) in self.blend(x, y) {
            if w == 0.0 {
                continue;
            }
            let p = at_centre(idx);
            for k in 0..3 {
                out[k] += w * p[k];
            }
        }
        out
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
        // Squared distances: hypot's care with overflow cost about 0.3 s of a 50-shot
        // calibration here, and no sensor is large enough to need it.
        let r2 = r * r;
        pts.iter()
            .enumerate()
            .filter(|(_, p)| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) <= r2)
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
        let (norm, basis) = fit_setup(ds, alpha, beta)?;
        let grid = local_grid(ds, opts);
        let mut channels = Vec::new();
        for ch in ds.channels() {
            let samples = fit_samples(ds, ModelKind::Local, (alpha, beta), ch, basis.len())?;
            let pts: Vec<[f64; 2]> = samples.iter().map(|s| [s.x, s.y]).collect();
            let fitted: Vec<[Vec<f64>; 3]> = {
                use rayon::prelude::*;
                (0..grid.len())
                    .into_par_iter()
                    .map(|idx| {
                        let members = local_members(&grid, idx, &pts, basis.len());
                        let (a, y) = design_system(
                            &basis,
                            members.iter().map(|&m| {
                                let s = samples[m];
                                (
                                    local_coords(
                                        &grid, &norm, idx, s.x, s.y, s.focal_mm, s.f_number,
                                    ),
                                    s.params(),
                                )
                            }),
                        );
                        super::split_coeffs(&solve_lsq(a, &y))
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

    fn centres_of(&self, channel: Channel) -> Option<&Vec<[Vec<f64>; 3]>> {
        find_channel(&self.channels, channel, |c| c.0).map(|c| &c.1)
    }
}

impl FittedModel for LocalModel {
    fitted_model_fields!(ModelKind::Local, |c| c.0);

    /// Blended over the four neighbouring centres.
    fn predict(&self, channel: Channel, x: f64, y: f64, s: LensSetting) -> Option<[f64; 3]> {
        let centres = self.centres_of(channel)?;
        Some(self.norm.extrapolate(x, y, |x, y| {
            self.grid.blended(x, y, |idx| {
                self.basis.eval3(
                    local_coords(&self.grid, &self.norm, idx, x, y, s.focal_mm, s.f_number),
                    &centres[idx],
                )
            })
        }))
    }

    fn at_setting(&self, channel: Channel, s: LensSetting) -> Option<FieldAtSetting> {
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
