//! A detection as the Shot view draws it over the shot: the chart's grid through the
//! global homography, a square's circles through its own homography, and the square a
//! point falls in. Everything in sensor pixels; the view only maps it to the screen.

use crate::chart::ChartSpec;
use crate::detect::Detection;
use crate::geometry::Homography;

/// The chart's grid through the detection's global homography: a segment per column
/// edge, then one per row edge, in sensor px.
#[must_use]
pub fn chart_grid(det: &Detection, chart: &ChartSpec) -> Vec<[[f64; 2]; 2]> {
    let h = &det.global;
    let (cols, rows) = (chart.cols as f64, chart.rows as f64);
    let verticals = (0..=chart.cols).map(|c| [h.apply([c as f64, 0.0]), h.apply([c as f64, rows])]);
    let horizontals =
        (0..=chart.rows).map(|r| [h.apply([0.0, r as f64]), h.apply([cols, r as f64])]);
    verticals.chain(horizontals).collect()
}

/// The chart's circles in the square at (`row`, `col`) through that square's own
/// homography (`image_from_chart`), each a closed polyline of `points` vertices in
/// sensor px: a misaligned square shows its circles off the imaged ones.
#[must_use]
pub fn square_circles(
    image_from_chart: &Homography,
    (row, col): (usize, usize),
    chart: &ChartSpec,
    points: usize,
) -> Vec<Vec<[f64; 2]>> {
    chart
        .circle_centres
        .iter()
        .map(|c| {
            (0..points)
                .map(|k| {
                    let t = std::f64::consts::TAU * k as f64 / points as f64;
                    image_from_chart.apply([
                        col as f64 + c[0] + chart.circle_radius * t.cos(),
                        row as f64 + c[1] + chart.circle_radius * t.sin(),
                    ])
                })
                .collect()
        })
        .collect()
}

/// Whether `p` lies in the convex quadrilateral `q` (either winding; on an edge counts).
#[must_use]
pub fn point_in_quad(p: [f64; 2], q: &[[f64; 2]; 4]) -> bool {
    let mut sign = 0.0;
    for k in 0..4 {
        let a = q[k];
        let b = q[(k + 1) % 4];
        let cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        if cross != 0.0 {
            if sign != 0.0 && cross.signum() != sign {
                return false;
            }
            sign = cross.signum();
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_is_in_a_quad_of_either_winding_and_out_of_it_beside() {
        let square = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]];
        let mut reversed = square;
        reversed.reverse();
        // A diamond: inside its bounding box is not enough.
        let diamond = [[1.0, 0.0], [2.0, 1.0], [1.0, 2.0], [0.0, 1.0]];
        for q in [square, reversed] {
            assert!(point_in_quad([1.0, 1.0], &q));
            assert!(point_in_quad([2.0, 1.0], &q), "on an edge");
            assert!(!point_in_quad([2.5, 1.0], &q));
            assert!(!point_in_quad([1.0, -0.1], &q));
        }
        assert!(point_in_quad([1.0, 1.0], &diamond));
        assert!(!point_in_quad([0.2, 0.2], &diamond));
        assert!(!point_in_quad([1.9, 1.9], &diamond));
    }

    #[test]
    fn the_grid_has_an_edge_per_column_and_row_through_the_global_homography() {
        let chart = ChartSpec::default();
        let det = Detection {
            width: 100,
            height: 80,
            squares: Vec::new(),
            global: Homography::translation(10.0, 5.0),
        };
        let grid = chart_grid(&det, &chart);
        assert_eq!(grid.len(), chart.cols + 1 + chart.rows + 1);
        assert_eq!(grid[0], [[10.0, 5.0], [10.0, 5.0 + chart.rows as f64]]);
        let last = grid[grid.len() - 1];
        assert_eq!(last[1], [10.0 + chart.cols as f64, 5.0 + chart.rows as f64]);
    }

    #[test]
    fn a_squares_circles_lie_at_the_charts_radius_through_its_homography() {
        let chart = ChartSpec::default();
        assert!(!chart.circle_centres.is_empty());
        let scale = 20.0;
        let h = Homography::scaling(scale, scale);
        let circles = square_circles(&h, (2, 3), &chart, 24);
        assert_eq!(circles.len(), chart.circle_centres.len());
        for (ring, c) in circles.iter().zip(&chart.circle_centres) {
            assert_eq!(ring.len(), 24);
            let centre = [(3.0 + c[0]) * scale, (2.0 + c[1]) * scale];
            for p in ring {
                let r = (p[0] - centre[0]).hypot(p[1] - centre[1]);
                assert!((r - chart.circle_radius * scale).abs() < 1e-9, "{r}");
            }
        }
    }
}
