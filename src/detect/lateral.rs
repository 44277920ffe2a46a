//! Where each colour channel's kernels are centred: on the channel's own image of the
//! chart where the lens's lateral colour moves it measurably, on the joint one
//! elsewhere.
//!
//! Every square registers each channel on its own
//! ([`super::align::Aligned::channel_registration`]), but one square's registration of
//! a RAW shot's quarter-resolution red or blue plane is noisy: taken as it is, it cost
//! the kernels' σ accuracy on a lens without lateral colour (p95 6.8 % against 6 % on
//! the Bayer kernel bars). Lateral colour is smooth across the frame, so per shot and
//! channel the squares' shifts against the joint registration are fitted by one field,
//! a constant shift plus a radial magnification (linear and cubic in the radius) about
//! the frame's centre. Where that field stands above its own noise (a χ² test on its
//! terms), and one channel's field moves some square far enough to widen its kernels
//! (`MATERIAL_SHIFT_PX`), each square's registration for each channel with a measured
//! field is the joint one moved and scaled by the field there; elsewhere the kernels
//! keep the joint one. The field's noise is the squares' scatter about it divided among
//! all the squares, so what the kernels are moved by is far steadier than any one
//! square's registration.

use super::SquareAlignment;
use super::SquareStatus;
use crate::chart::ChartSpec;
use crate::geometry::Homography;
use crate::plane::Channel;
use nalgebra::{Matrix4, Vector4};

/// χ² of the field's four terms above which it counts as measured: the 0.1 % tail of
/// χ² with 4 degrees of freedom, so a lens without lateral colour moves one channel of
/// one shot in a thousand, and then by no more than its noise.
const CHI2_MEASURED: f64 = 18.47;

/// A field whose shift stays below this at every square leaves the kernels on the
/// joint registration. A kernel measured δ px off its channel's image has its fitted
/// σ² widened by about δ²/2 per axis: below 0.1 px that is under 1 % of σ for the
/// sharpest kernels measured (σ ≈ 0.7 px), half the σ bar's median, and the kernels'
/// own centroids scatter by 0.05–0.06 px even with each channel registered on its own.
/// Chart squares register so precisely (scatter about a field of 0.002–0.007 px) that a
/// blur whose centroid differs a little between channels, such as the comet lens's
/// coma tails, is a measured field of a few hundredths of a pixel; 0.05 px here made
/// the kernels follow that on some shots and not others.
const MATERIAL_SHIFT_PX: f64 = 0.1;

/// Squares a field needs: four terms from two equations a square, with room to judge
/// the scatter.
const MIN_SQUARES: usize = 8;

/// A square's residual beyond this many robust σ (and this many pixels) is an outlier
/// the field is refitted without.
const OUTLIER_SIGMAS: f64 = 5.0;
const OUTLIER_MIN_PX: f64 = 0.05;

/// One channel's shift field over a shot: d(p) = t + (a + b·r²)·(p − c), with c the
/// frame's centre and r = |p − c| over half the frame's diagonal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShiftField {
    /// [tx, ty, a, b].
    pub terms: [f64; 4],
    /// θᵀ(AᵀA)θ / s²: how far the terms stand above their noise.
    pub chi2: f64,
    /// The squares' scatter about the field, px (per coordinate).
    pub scatter_px: f64,
    pub squares: usize,
    centre: [f64; 2],
    half_diagonal: f64,
}

impl ShiftField {
    /// No shift anywhere on a `width × height` frame.
    fn zero(width: usize, height: usize) -> Self {
        Self {
            terms: [0.0; 4],
            chi2: 0.0,
            scatter_px: 0.0,
            squares: 0,
            centre: [(width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0],
            half_diagonal: 0.5 * (width as f64).hypot(height as f64),
        }
    }

    /// Whether the field is measured above its noise.
    #[must_use]
    pub fn measured(&self) -> bool {
        self.chi2 > CHI2_MEASURED
    }

    /// The largest shift at `points`, px.
    #[must_use]
    pub fn largest_shift(&self, points: &[[f64; 2]]) -> f64 {
        points
            .iter()
            .map(|&p| {
                let d = self.at(p);
                d[0].hypot(d[1])
            })
            .fold(0.0, f64::max)
    }

    /// The shift at sensor point `p`, px.
    #[must_use]
    pub fn at(&self, p: [f64; 2]) -> [f64; 2] {
        let [tx, ty, a, b] = self.terms;
        let m = a + b * self.radius2(p);
        let (dx, dy) = (p[0] - self.centre[0], p[1] - self.centre[1]);
        [tx + m * dx, ty + m * dy]
    }

    /// The field's magnification at `p` (a + b·r²): how much larger the channel's
    /// image of a square there is.
    fn magnification(&self, p: [f64; 2]) -> f64 {
        self.terms[2] + self.terms[3] * self.radius2(p)
    }

    fn radius2(&self, p: [f64; 2]) -> f64 {
        let (dx, dy) = (p[0] - self.centre[0], p[1] - self.centre[1]);
        (dx * dx + dy * dy) / (self.half_diagonal * self.half_diagonal)
    }

    /// Fits the field to `shifts` ((sensor point, shift) pairs) on a `width × height`
    /// frame, with one round of outlier rejection. `None` with too few squares or a
    /// singular system.
    #[must_use]
    pub fn fit(shifts: &[([f64; 2], [f64; 2])], width: usize, height: usize) -> Option<Self> {
        let shell = Self::zero(width, height);
        let first = shell.solve(shifts.iter())?;
        let residual = |(p, d): &&([f64; 2], [f64; 2])| {
            let f = first.at(*p);
            (d[0] - f[0]).abs().max((d[1] - f[1]).abs())
        };
        let mut abs: Vec<f64> = shifts.iter().map(|s| residual(&s)).collect();
        abs.sort_by(f64::total_cmp);
        let robust_sigma = 1.4826 * abs[abs.len() / 2];
        let limit = (OUTLIER_SIGMAS * robust_sigma).max(OUTLIER_MIN_PX);
        shell.solve(shifts.iter().filter(|s| residual(s) <= limit))
    }

    fn solve<'a>(
        &self,
        shifts: impl Iterator<Item = &'a ([f64; 2], [f64; 2])> + Clone,
    ) -> Option<Self> {
        let mut ata = Matrix4::<f64>::zeros();
        let mut atb = Vector4::<f64>::zeros();
        let mut n = 0;
        let rows = |p: [f64; 2]| {
            let (dx, dy) = (p[0] - self.centre[0], p[1] - self.centre[1]);
            let r2 = self.radius2(p);
            [
                Vector4::new(1.0, 0.0, dx, dx * r2),
                Vector4::new(0.0, 1.0, dy, dy * r2),
            ]
        };
        for (p, d) in shifts.clone() {
            for (row, v) in rows(*p).iter().zip(d) {
                ata += row * row.transpose();
                atb += row * *v;
            }
            n += 1;
        }
        if n < MIN_SQUARES {
            return None;
        }
        let theta = ata.cholesky()?.solve(&atb);
        let mut rss = 0.0;
        for (p, d) in shifts {
            for (row, v) in rows(*p).iter().zip(d) {
                rss += (v - row.dot(&theta)).powi(2);
            }
        }
        let s2 = rss / (2 * n - 4) as f64;
        let chi2 = if s2 > 0.0 {
            theta.dot(&(ata * theta)) / s2
        } else {
            f64::INFINITY
        };
        Some(Self {
            terms: [theta[0], theta[1], theta[2], theta[3]],
            chi2,
            scatter_px: s2.sqrt(),
            squares: n,
            ..*self
        })
    }
}

/// Each channel's shift field over a shot's aligned squares (its registration against
/// the joint one at each square's centre), per channel the squares register.
#[must_use]
pub fn shift_fields(
    squares: &[SquareAlignment],
    spec: &ChartSpec,
    width: usize,
    height: usize,
) -> Vec<(Channel, ShiftField)> {
    let channels: Vec<Channel> = {
        let mut c: Vec<Channel> = squares
            .iter()
            .flat_map(|s| s.channel_registration.iter().map(|(ch, _)| *ch))
            .collect();
        c.sort();
        c.dedup();
        c
    };
    channels
        .into_iter()
        .filter_map(|ch| {
            let shifts: Vec<([f64; 2], [f64; 2])> = squares
                .iter()
                .filter(|s| s.status == SquareStatus::Ok)
                .filter_map(|s| {
                    let (_, own) = s.channel_registration.iter().find(|(c, _)| *c == ch)?;
                    let q = square_centre(spec, s);
                    let (p, o) = (s.image_from_chart.apply(q), own.apply(q));
                    Some((p, [o[0] - p[0], o[1] - p[1]]))
                })
                .collect();
            Some((ch, ShiftField::fit(&shifts, width, height)?))
        })
        .collect()
}

/// Sets each square's per-channel `image_from_chart` from the channels' shift fields
/// where they are measured (and leaves the joint one, no entry, where not).
pub fn register_where_measured(
    squares: &mut [SquareAlignment],
    spec: &ChartSpec,
    width: usize,
    height: usize,
) {
    let centres: Vec<[f64; 2]> = squares
        .iter()
        .filter(|s| s.status == SquareStatus::Ok)
        .map(|s| s.image_from_chart.apply(square_centre(spec, s)))
        .collect();
    let fields: Vec<(Channel, ShiftField)> = shift_fields(squares, spec, width, height)
        .into_iter()
        .filter(|(_, f)| f.measured())
        .collect();
    // Once one channel moves enough to matter, every channel follows its own measured
    // field: the joint registration is then a compromise between the channels.
    if !fields
        .iter()
        .any(|(_, f)| f.largest_shift(&centres) > MATERIAL_SHIFT_PX)
    {
        return;
    }
    for (s, &p) in squares
        .iter_mut()
        .filter(|s| s.status == SquareStatus::Ok)
        .zip(&centres)
    {
        s.channel_image_from_chart = fields
            .iter()
            .map(|(ch, f)| {
                // Moved by the field at the square's centre and scaled about it by the
                // field's magnification there.
                let d = f.at(p);
                let m = 1.0 + f.magnification(p);
                let moved = Homography::translation(p[0] + d[0], p[1] + d[1])
                    .compose(&Homography::scaling(m, m))
                    .compose(&Homography::translation(-p[0], -p[1]))
                    .compose(&s.image_from_chart);
                (*ch, moved)
            })
            .collect();
    }
}

fn square_centre(spec: &ChartSpec, s: &SquareAlignment) -> [f64; 2] {
    let q = spec.square_corners(s.col, s.row);
    [
        q.iter().map(|c| c[0]).sum::<f64>() / 4.0,
        q.iter().map(|c| c[1]).sum::<f64>() / 4.0,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Shifts at a 12 × 8 grid of points over a 2400 × 1600 frame: `field`'s plus
    /// Gaussian noise of `noise_px`.
    fn grid_shifts(terms: [f64; 4], noise_px: f64, seed: u64) -> Vec<([f64; 2], [f64; 2])> {
        let truth = ShiftField {
            terms,
            ..ShiftField::zero(2400, 1600)
        };
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let noise = Normal::new(0.0, noise_px).expect("normal");
        (0..8)
            .flat_map(|j| {
                (0..12).map(move |i| [100.0 + 200.0 * i as f64, 100.0 + 200.0 * j as f64])
            })
            .map(|p| {
                let d = truth.at(p);
                (
                    p,
                    [d[0] + noise.sample(&mut rng), d[1] + noise.sample(&mut rng)],
                )
            })
            .collect()
    }

    #[test]
    fn lateral_colour_is_measured_and_recovered() {
        // Red magnified by 3e-4 (0.43 px at the corners), squares registered to 0.05 px.
        let terms = [0.0, 0.0, 3e-4, 0.0];
        let f = ShiftField::fit(&grid_shifts(terms, 0.05, 1), 2400, 1600).expect("fits");
        assert!(f.measured(), "χ² {}", f.chi2);
        let corner = f.at([0.0, 0.0]);
        let want = [-3e-4 * 1199.5, -3e-4 * 799.5];
        for k in 0..2 {
            assert!((corner[k] - want[k]).abs() < 0.03, "{corner:?} vs {want:?}");
        }
        assert!(
            (f.scatter_px - 0.05).abs() < 0.01,
            "scatter {}",
            f.scatter_px
        );
    }

    #[test]
    fn noise_alone_is_not_measured() {
        // No lateral colour: the field stays below its noise in all but about one shot
        // in a thousand (none of these fifty).
        for seed in 0..50 {
            let f = ShiftField::fit(&grid_shifts([0.0; 4], 0.05, seed), 2400, 1600).expect("fits");
            assert!(!f.measured(), "seed {seed}: χ² {}", f.chi2);
        }
    }

    #[test]
    fn an_outlier_square_does_not_move_the_field() {
        let mut shifts = grid_shifts([0.0; 4], 0.02, 3);
        shifts[5].1 = [2.0, -1.5];
        let f = ShiftField::fit(&shifts, 2400, 1600).expect("fits");
        assert!(!f.measured(), "χ² {}", f.chi2);
        assert_eq!(f.squares, shifts.len() - 1);
    }
}
