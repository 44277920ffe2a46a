//! The light across one square's observed window: a gain that varies linearly over it.
//!
//! The kernel's unknowns carry one gain and one offset per square and channel (see the
//! module above), which is right for a chart lit evenly and a lens without fall-off. A
//! real lens darkens towards the corners (a stop is common wide open), so light falls
//! by several per cent across a square near the corner, and across a large square of a
//! high-resolution shot by more. A constant gain cannot explain that slope; the least
//! squares then spend the kernel's outer ring on it, a kernel that is not wide reads as
//! clipped by its support, and it is solved again two or three times at a larger one.
//!
//! Fall-off and uneven light both multiply what the chart reflects, so one relative
//! gain g(x, y) = 1 + gₓ·(x − cₓ) + g_y·(y − c_y) scales the black and the white of the
//! print alike. It is fitted where the sharp chart is uniform for a few blur widths
//! around a pixel (its blurred value is then the level itself, whatever the kernel),
//! jointly with the two levels, and the observations are divided by it before the
//! kernel is solved. Slopes beyond what a lens or a lamp makes over one square (a
//! shadow's edge, a misread square) are not trusted, and the window is solved as it is.

use nalgebra::{Matrix4, Vector4};

/// The largest change of gain the fit may claim from the window's centre to its edge:
/// fall-off of a few stops across the frame gives a few per cent over one square.
const MAX_CHANGE_TO_EDGE: f64 = 0.3;

/// Gauss–Newton steps of the fit: each squares the error of a slope of a few per cent.
const GAUSS_NEWTON_STEPS: usize = 4;

/// Fewest uniform samples of a level for it to take part in the fit.
const MIN_SAMPLES: usize = 16;

/// A relative gain over one window, 1 at its centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Shading {
    centre: [f64; 2],
    /// Relative change of gain per pixel along x and y.
    slope: [f64; 2],
}

/// One observation where the sharp chart is uniform around the pixel: its position
/// (sensor px), whether the chart is white there, and the value observed.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FlatSample {
    pub x: f64,
    pub y: f64,
    pub white: bool,
    pub value: f64,
}

impl Shading {
    /// Fits the gain's slope over a window centred on `centre` whose farthest pixel is
    /// `half_extent_px` from it. `None` when the window holds too few uniform samples
    /// to tell a slope, when both levels are dark, or when the slope found is larger
    /// than shading makes.
    pub(crate) fn fit(
        samples: &[FlatSample],
        centre: [f64; 2],
        half_extent_px: f64,
    ) -> Option<Self> {
        let count = |white: bool| samples.iter().filter(|s| s.white == white).count();
        let (n_white, n_black) = (count(true), count(false));
        let mean = |white: bool, n: usize| {
            (n >= MIN_SAMPLES).then(|| {
                samples
                    .iter()
                    .filter(|s| s.white == white)
                    .map(|s| s.value)
                    .sum::<f64>()
                    / n as f64
            })
        };
        let (white, black) = (mean(true, n_white), mean(false, n_black));
        let top = white.unwrap_or(0.0).max(black.unwrap_or(0.0));
        if !(top > 0.0) {
            return None;
        }
        // v = L·(1 + gₓ·dx + g_y·dy), L the white or the black level: Gauss–Newton on
        // (ω, β, gₓ, g_y) from the means and no slope. The model is bilinear in the
        // levels and the slope, so a few steps reach its least-squares solution.
        let (mut levels, mut slope) = ([white.unwrap_or(0.0), black.unwrap_or(0.0)], [0.0; 2]);
        for _ in 0..GAUSS_NEWTON_STEPS {
            let mut jtj = Matrix4::<f64>::zeros();
            let mut jtr = Vector4::<f64>::zeros();
            for s in samples {
                let k = usize::from(!s.white);
                if (k == 0 && white.is_none()) || (k == 1 && black.is_none()) {
                    continue;
                }
                let (dx, dy) = (s.x - centre[0], s.y - centre[1]);
                let g = 1.0 + slope[0] * dx + slope[1] * dy;
                let level = levels[k];
                let mut row = Vector4::new(0.0, 0.0, level * dx, level * dy);
                row[k] = g;
                jtj += row * row.transpose();
                jtr += row * (s.value - level * g);
            }
            // A level without samples leaves its column empty: pin it so the rest solves.
            for (k, present) in [white.is_some(), black.is_some()].into_iter().enumerate() {
                if !present {
                    jtj[(k, k)] = 1.0;
                }
            }
            let step = jtj.cholesky()?.solve(&jtr);
            levels[0] += step[0];
            levels[1] += step[1];
            slope[0] += step[2];
            slope[1] += step[3];
        }
        let change = (slope[0].abs() + slope[1].abs()) * half_extent_px;
        (slope.iter().all(|s| s.is_finite()) && change <= MAX_CHANGE_TO_EDGE)
            .then_some(Self { centre, slope })
    }

    /// The relative gain at sensor position (x, y).
    pub(crate) fn gain(&self, x: f64, y: f64) -> f64 {
        1.0 + self.slope[0] * (x - self.centre[0]) + self.slope[1] * (y - self.centre[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(slope: [f64; 2], white: f64, black: f64) -> Vec<FlatSample> {
        let centre = [50.0, 40.0];
        let mut out = Vec::new();
        for y in 10..70 {
            for x in 20..80 {
                // A square of white in a frame of black, as a window shows a white square.
                let is_white = (30..70).contains(&x) && (20..60).contains(&y);
                let (xf, yf) = (f64::from(x), f64::from(y));
                let g = 1.0 + slope[0] * (xf - centre[0]) + slope[1] * (yf - centre[1]);
                let level = if is_white { white } else { black };
                out.push(FlatSample {
                    x: xf,
                    y: yf,
                    white: is_white,
                    value: g * level,
                });
            }
        }
        out
    }

    #[test]
    fn recovers_a_fall_off_across_the_window() {
        let slope = [-1.5e-3, 8e-4];
        let s = Shading::fit(&samples(slope, 0.8, 0.06), [50.0, 40.0], 40.0).expect("fit");
        assert!((s.slope[0] - slope[0]).abs() < 1e-9, "{:?}", s.slope);
        assert!((s.slope[1] - slope[1]).abs() < 1e-9, "{:?}", s.slope);
        assert!((s.gain(50.0, 40.0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn one_level_alone_gives_the_slope() {
        let slope = [2e-3, -1e-3];
        let only_white: Vec<FlatSample> = samples(slope, 0.7, 0.05)
            .into_iter()
            .filter(|s| s.white)
            .collect();
        let s = Shading::fit(&only_white, [50.0, 40.0], 40.0).expect("fit");
        assert!((s.slope[0] - slope[0]).abs() < 1e-9 && (s.slope[1] - slope[1]).abs() < 1e-9);
    }

    #[test]
    fn even_light_gives_no_slope() {
        let s = Shading::fit(&samples([0.0, 0.0], 0.8, 0.06), [50.0, 40.0], 40.0).expect("fit");
        assert!(s.slope.iter().all(|g| g.abs() < 1e-12), "{:?}", s.slope);
    }

    #[test]
    fn a_slope_no_lens_makes_is_not_trusted() {
        // 60 % from centre to edge: a shadow across the square, not fall-off.
        assert!(Shading::fit(&samples([1.5e-2, 0.0], 0.8, 0.06), [50.0, 40.0], 40.0).is_none());
    }

    #[test]
    fn too_few_samples_fit_nothing() {
        let few: Vec<FlatSample> = samples([1e-3, 0.0], 0.8, 0.06)
            .into_iter()
            .take(10)
            .collect();
        assert!(Shading::fit(&few, [50.0, 40.0], 40.0).is_none());
    }
}
