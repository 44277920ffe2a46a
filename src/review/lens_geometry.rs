//! What the Geometry view draws of a measured lens geometry: a regular grid pushed
//! through the distortion, red and blue against green as arrows, and the fall-off in
//! stops over the frame. Distortion and lateral colour are a few pixels on a frame of
//! thousands, so both are exaggerated by a round factor (1, 2 or 5 × 10ⁿ) the view
//! names.

use crate::correction::{FocalGeometry, LensCorrection, LensfunFrame, VignettingFit};

/// The lines of a regular grid over the frame, ideal and as the lens (exaggerated)
/// draws them, sensor px.
#[derive(Clone, Debug)]
pub struct WarpedGrid {
    pub ideal: Vec<Vec<[f32; 2]>>,
    pub warped: Vec<Vec<[f32; 2]>>,
    /// How much the displacement is exaggerated.
    pub factor: f64,
    /// The displacement at the frame corner, px (negative: inward, barrel).
    pub corner_px: f64,
}

/// Red and blue against green at a grid of points, sensor px (tips exaggerated).
#[derive(Clone, Debug)]
pub struct ColourArrows {
    /// Each point's green position and red and blue tips.
    pub arrows: Vec<[[f32; 2]; 3]>,
    pub factor: f64,
    pub red_corner_px: f64,
    pub blue_corner_px: f64,
}

/// The light lost over the frame at one aperture, stops, on a grid of cells.
#[derive(Clone, Debug)]
pub struct FalloffMap {
    /// Cells across and down.
    pub cells: [usize; 2],
    /// Row-major, one value per cell (its centre's).
    pub stops: Vec<f64>,
    /// The range a colour scale spans: 0 to the largest loss (at least 0.1 stops, and at
    /// least the fit's corner figure, so a map and its corner number agree).
    pub range: [f64; 2],
}

/// The largest of 1, 2, 5 × 10ⁿ at most `x` (at least 1).
#[must_use]
pub fn nice_factor(x: f64) -> f64 {
    if !(x.is_finite() && x > 1.0) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&v| v <= x)
        .unwrap_or(p)
}

/// Lines of a 12 × 8 grid over the frame through the distortion, the displacement
/// (beside the uniform scale the model's normalisation carries) exaggerated so the
/// corner moves by about 15 % of the frame's short side.
#[must_use]
pub fn warped_grid(c: &LensCorrection, focal: &FocalGeometry) -> WarpedGrid {
    let d = focal.distortion_fit(c.distortion_model);
    let frame = &c.frame;
    let (w, h) = ((c.width as f64 - 1.0), (c.height as f64 - 1.0));
    let centre = frame.centre();
    let g0 = d.model.eval(&d.coefficients, 0.0).0;
    let displacement = |u: [f64; 2]| {
        let p = d.distort(frame, u);
        [
            p[0] - (centre[0] + (u[0] - centre[0]) * g0),
            p[1] - (centre[1] + (u[1] - centre[1]) * g0),
        ]
    };
    let corner = displacement([0.0, 0.0]);
    let corner_len = corner[0].hypot(corner[1]);
    // Below a millionth of a pixel there is no distortion to show, only rounding,
    // which no factor should magnify.
    let factor = if corner_len < 1e-6 {
        1.0
    } else {
        nice_factor(0.15 * w.min(h) / corner_len)
    };
    let (nx, ny, samples) = (12, 8, 48);
    let mut ideal = Vec::new();
    let mut warped = Vec::new();
    let mut line = |pts: Vec<[f64; 2]>| {
        ideal.push(pts.iter().map(|p| [p[0] as f32, p[1] as f32]).collect());
        warped.push(
            pts.iter()
                .map(|&p| {
                    let dp = displacement(p);
                    [
                        (p[0] + factor * dp[0]) as f32,
                        (p[1] + factor * dp[1]) as f32,
                    ]
                })
                .collect(),
        );
    };
    for i in 0..=nx {
        let x = w * f64::from(i) / f64::from(nx);
        line(
            (0..=samples)
                .map(|k| [x, h * f64::from(k) / f64::from(samples)])
                .collect(),
        );
    }
    for j in 0..=ny {
        let y = h * f64::from(j) / f64::from(ny);
        line(
            (0..=samples)
                .map(|k| [w * f64::from(k) / f64::from(samples), y])
                .collect(),
        );
    }
    WarpedGrid {
        ideal,
        warped,
        factor,
        corner_px: d.corner_displacement_px,
    }
}

/// Red and blue against green at a 9 × 6 grid of points, exaggerated so the longest
/// arrow spans about two thirds of the grid's step.
#[must_use]
pub fn colour_arrows(c: &LensCorrection, focal: &FocalGeometry) -> Option<ColourArrows> {
    let t = focal.tca_fit(c.tca_model)?;
    let frame = &c.frame;
    let (w, h) = (c.width as f64, c.height as f64);
    let (nx, ny) = (9, 6);
    let points: Vec<[f64; 2]> = (0..ny)
        .flat_map(|j| {
            (0..nx).map(move |i| {
                [
                    w * (f64::from(i) + 0.5) / f64::from(nx),
                    h * (f64::from(j) + 0.5) / f64::from(ny),
                ]
            })
        })
        .collect();
    let shift = |p: [f64; 2], blue: bool| {
        let q = t.channel_at(frame, p, blue);
        [q[0] - p[0], q[1] - p[1]]
    };
    let longest = points
        .iter()
        .flat_map(|&p| [shift(p, false), shift(p, true)])
        .map(|v| v[0].hypot(v[1]))
        .fold(0.0, f64::max);
    let factor = if longest < 1e-6 {
        1.0
    } else {
        nice_factor(0.65 * (w / f64::from(nx)) / longest)
    };
    let tip = |p: [f64; 2], blue: bool| {
        let s = shift(p, blue);
        [(p[0] + factor * s[0]) as f32, (p[1] + factor * s[1]) as f32]
    };
    Some(ColourArrows {
        arrows: points
            .iter()
            .map(|&p| [[p[0] as f32, p[1] as f32], tip(p, false), tip(p, true)])
            .collect(),
        factor,
        red_corner_px: t.red.corner_shift_px,
        blue_corner_px: t.blue.corner_shift_px,
    })
}

/// Light lost (stops) at sensor point `p`.
#[must_use]
pub fn stops_at(frame: &LensfunFrame, v: &VignettingFit, p: [f64; 2]) -> f64 {
    let q = frame.to_vignetting(p);
    -v.illumination(q[0].hypot(q[1])).max(1e-6).log2()
}

/// The fall-off over the frame, `across` cells along its width and as many down as keep
/// the cells square (at least 2).
#[must_use]
pub fn falloff_map(frame: &LensfunFrame, v: &VignettingFit, across: usize) -> FalloffMap {
    let (w, h) = (frame.width as f64, frame.height as f64);
    let gx = across.max(1);
    let gy = ((gx as f64 * h / w).round() as usize).max(2);
    let stops: Vec<f64> = (0..gy)
        .flat_map(|j| {
            (0..gx).map(move |i| {
                let p = [
                    w * (i as f64 + 0.5) / gx as f64,
                    h * (j as f64 + 0.5) / gy as f64,
                ];
                stops_at(frame, v, p)
            })
        })
        .collect();
    let hi = stops
        .iter()
        .copied()
        .fold(v.corner_stops.max(0.1), f64::max);
    FalloffMap {
        cells: [gx, gy],
        stops,
        range: [0.0, hi],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correction::tca::ChannelTca;
    use crate::correction::{DistortionFit, DistortionModel, TcaFit, TcaModel};
    use crate::plane::LensSetting;

    /// A 600 × 400 frame whose lens has Hugin's poly3 distortion `k1` and lateral colour
    /// as linear scales of red and blue.
    fn lens(k1: f64, red: f64, blue: f64) -> (LensCorrection, FocalGeometry) {
        let frame = LensfunFrame::of_image(600, 400);
        let channel = |k: f64| ChannelTca {
            terms: vec![k],
            std_errors: vec![0.0],
            rms_px: 0.0,
            corner_shift_px: 0.0,
        };
        let focal = FocalGeometry {
            focal_mm: 50.0,
            shots: 1,
            distortion: vec![DistortionFit {
                model: DistortionModel::Poly3,
                coefficients: vec![k1],
                std_errors: vec![0.0],
                rms_px: 0.0,
                max_px: 0.0,
                corners: 0,
                outliers: 0,
                corner_displacement_px: 0.0,
                poses: Vec::new(),
            }],
            tca: vec![TcaFit {
                model: TcaModel::Linear,
                red: channel(red),
                blue: channel(blue),
                corners: 0,
            }],
        };
        let c = LensCorrection {
            frame,
            width: 600,
            height: 400,
            focal: vec![focal.clone()],
            vignetting: Vec::new(),
            distortion_model: DistortionModel::Poly3,
            tca_model: TcaModel::Linear,
        };
        (c, focal)
    }

    #[test]
    fn nice_factors_are_one_two_or_five_times_a_power_of_ten_at_most_x() {
        let cases = [
            (0.3, 1.0),
            (1.0, 1.0),
            (1.9, 1.0),
            (2.0, 2.0),
            (4.99, 2.0),
            (5.0, 5.0),
            (37.0, 20.0),
            (999.0, 500.0),
            (f64::NAN, 1.0),
            (f64::INFINITY, 1.0),
        ];
        for (x, want) in cases {
            let got = nice_factor(x);
            assert!((got - want).abs() < 1e-9 * want, "nice_factor({x}) = {got}");
        }
    }

    #[test]
    fn a_lens_without_distortion_draws_the_grid_straight() {
        let (c, focal) = lens(0.0, 1.0, 1.0);
        let g = warped_grid(&c, &focal);
        assert_eq!(
            g.ideal.len(),
            13 + 9,
            "12 × 8 cells: 13 columns and 9 rows of lines"
        );
        for (a, b) in g.ideal.iter().flatten().zip(g.warped.iter().flatten()) {
            assert!((a[0] - b[0]).abs() < 1e-3 && (a[1] - b[1]).abs() < 1e-3);
        }
    }

    #[test]
    fn barrel_distortion_pulls_the_corner_in_by_about_15_percent_of_the_short_side() {
        let (c, focal) = lens(-0.01, 1.0, 1.0);
        let g = warped_grid(&c, &focal);
        // The first column's first point is the top-left corner: barrel pulls it
        // towards the centre, down and to the right.
        let (ideal, warped) = (g.ideal[0][0], g.warped[0][0]);
        let moved = [
            f64::from(warped[0] - ideal[0]),
            f64::from(warped[1] - ideal[1]),
        ];
        assert!(
            moved[0] > 0.0 && moved[1] > 0.0,
            "corner moved by {moved:?}"
        );
        // The exaggeration is the largest round factor keeping the move within 15 %
        // of the short side (399 px), so the move is between 6 % and 15 %.
        let len = moved[0].hypot(moved[1]);
        assert!(
            (0.06 * 399.0 - 1e-3..=0.15 * 399.0 + 1e-3).contains(&len),
            "{len} px at factor {}",
            g.factor
        );
        assert!(g.factor > 1.0 && nice_factor(g.factor) == g.factor);
    }

    #[test]
    fn colour_arrows_point_out_for_a_magnified_channel_and_in_for_a_shrunk_one() {
        let (c, focal) = lens(0.0, 1.0005, 0.9995);
        let a = colour_arrows(&c, &focal).expect("lateral colour is measured");
        assert_eq!(a.arrows.len(), 9 * 6);
        let step = 600.0 / 9.0;
        let centre = c.frame.centre();
        for [green, red, blue] in &a.arrows {
            let out = |tip: &[f32; 2]| {
                let r = [
                    f64::from(green[0]) - centre[0],
                    f64::from(green[1]) - centre[1],
                ];
                let d = [f64::from(tip[0] - green[0]), f64::from(tip[1] - green[1])];
                assert!(
                    d[0].hypot(d[1]) <= 0.65 * step + 1e-3,
                    "arrow within its cell"
                );
                r[0] * d[0] + r[1] * d[1]
            };
            assert!(out(red) >= 0.0, "red points outward");
            assert!(out(blue) <= 0.0, "blue points inward");
        }
    }

    #[test]
    fn the_falloff_map_grows_towards_the_corners_and_its_range_holds_it() {
        let frame = LensfunFrame::of_image(600, 400);
        let v = VignettingFit {
            setting: LensSetting {
                focal_mm: 50.0,
                f_number: 4.0,
            },
            k: [-0.3, 0.0, 0.0],
            std_errors: [0.0; 3],
            corner_stops: 0.0,
            rms_relative: 0.0,
            max_radius: 1.0,
            gradient_stops: 0.0,
            samples: 0,
        };
        let m = falloff_map(&frame, &v, 60);
        assert_eq!(m.cells, [60, 40], "square cells on a 3:2 frame");
        assert_eq!(m.stops.len(), 60 * 40);
        let at = |i: usize, j: usize| m.stops[j * 60 + i];
        assert!(at(0, 0) > at(15, 10) && at(15, 10) > at(30, 20));
        assert!(
            at(30, 20) >= 0.0 && at(30, 20) < 0.01,
            "almost no loss at the centre"
        );
        let max = m.stops.iter().copied().fold(0.0, f64::max);
        assert_eq!(m.range, [0.0, max]);
        // c(r) = 1 − 0.3 r² at the corner cell's radius, in stops.
        let q = frame.to_vignetting([5.0, 5.0]);
        let want = -(1.0 - 0.3 * (q[0] * q[0] + q[1] * q[1])).log2();
        assert!((at(0, 0) - want).abs() < 1e-9);
    }
}
