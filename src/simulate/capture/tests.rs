//! The capture simulator against exact expectations.

use super::bent::rasterize_bent;
use super::*;
use crate::simulate::LensGeometry;

/// The largest distance (px) between a block's local homography and the exact bent
/// mapping, over a dense grid on every block of a window at the frame corner (where
/// the curvature is largest), for each channel.
fn worst_block_error(geometry: LensGeometry, w: usize, h: usize, tf: f64) -> (f64, usize) {
    let spec = ChartSpec::default();
    let image_from_chart = Pose::default().image_from_chart(&spec, w, h);
    let chart_from_ideal = image_from_chart.inverse().expect("pose");
    let image_from_ideal = image_from_chart;
    let s = 4usize;
    let sf = s as f64;
    let tile = 32usize;
    let margin = 12usize;
    let mut worst = 0.0f64;
    let mut block_side = 0;
    for ch in CHANNELS {
        let map = geometry.mapping(ch, tf, 0.0, w, h);
        let reach = (tile + margin) as f64 + 1.0;
        let block = block_px(&map, w as f64 + 2.0 * reach, h as f64 + 2.0 * reach) * s;
        block_side = block / s;
        // The window about the PSF centre at the frame's top-left corner, reaching
        // beyond the frame as the renderer's do.
        let (x0, y0) = (-((tile + margin) as f64), -((tile + margin) as f64));
        let off = (sf - 1.0) / (2.0 * sf);
        let sensor_from_sub = Homography::translation(x0 - off, y0 - off)
            .compose(&Homography::scaling(1.0 / sf, 1.0 / sf));
        let n = (2 * (tile + margin)) * s;
        for b0 in (0..n).step_by(block) {
            for a0 in (0..n).step_by(block) {
                let (bw, bh) = (block.min(n - a0), block.min(n - b0));
                let hb = block_homography(
                    &chart_from_ideal,
                    &map,
                    &sensor_from_sub,
                    [a0 as f64, b0 as f64],
                    [bw as f64, bh as f64],
                )
                .expect("fit");
                for j in 0..=8 {
                    for i in 0..=8 {
                        let local = [
                            -0.5 + bw as f64 * f64::from(i) / 8.0,
                            -0.5 + bh as f64 * f64::from(j) / 8.0,
                        ];
                        let sub = [a0 as f64 + local[0], b0 as f64 + local[1]];
                        let sensor = sensor_from_sub.apply(sub);
                        // Exact: sensor ← bent ← ideal ← chart point of this sensor point.
                        let chart = chart_from_ideal.apply(map.ideal_from_sensor(sensor));
                        let back = image_from_ideal.apply(chart);
                        let exact = map.sensor_from_ideal(back);
                        assert!((exact[0] - sensor[0]).hypot(exact[1] - sensor[1]) < 1e-9);
                        let fitted = hb.apply(chart);
                        let e = (fitted[0] - local[0]).hypot(fitted[1] - local[1]) / sf;
                        worst = worst.max(e);
                    }
                }
            }
        }
    }
    (worst, block_side)
}

#[test]
fn block_homographies_follow_the_bent_mapping_to_a_hundredth_of_a_pixel() {
    let strong_colour = LensGeometry {
        lateral_colour: [3e-3, -3e-3],
        ..LensGeometry::typical_zoom()
    };
    for (name, g, tf) in [
        ("barrel", LensGeometry::typical_zoom(), 0.0),
        ("pincushion", LensGeometry::typical_zoom(), 1.0),
        ("barrel + strong lateral colour", strong_colour, 0.0),
    ] {
        for (w, h) in [(320usize, 213usize), (640, 427)] {
            let (err, block) = worst_block_error(g.clone(), w, h, tf);
            eprintln!("{name} {w}x{h}: blocks of {block} px, worst mapping error {err:.5} px");
            assert!(err < 0.01, "{name} {w}x{h}: {err} px");
        }
    }
}

/// The bent renderer with an identity mapping is the exact renderer: the blocks
/// tile the window without seams or offsets.
#[test]
fn blocks_tile_the_window_exactly() {
    let spec = ChartSpec::default();
    let image_from_chart = Pose::default().image_from_chart(&spec, 200, 150);
    let chart_from_ideal = image_from_chart.inverse().expect("pose");
    let identity = LensGeometry::default().mapping(Channel::G, 0.0, 0.0, 200, 150);
    let sensor_from_sub = Homography::translation(37.0 - 0.375, 21.0 - 0.375)
        .compose(&Homography::scaling(0.25, 0.25));
    let n = 96;
    let exact = rasterize(
        &spec,
        &sensor_from_sub
            .inverse()
            .expect("inverse")
            .compose(&image_from_chart),
        n,
        n,
        0.35,
    );
    let bent = rasterize_bent(
        &spec,
        &chart_from_ideal,
        &identity,
        &sensor_from_sub,
        (n, n),
        20,
        0.35,
    );
    let worst = exact
        .data
        .iter()
        .zip(&bent.data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "worst difference {worst}");
}

/// Windows cut from the frame's strips are the windows rendered on their own: with an
/// identity mapping, exactly the exact renderer's, at every row and column of the grid
/// (strips dropped and rendered as the rows move down included).
#[test]
fn windows_cut_from_the_strips_are_the_exact_windows() {
    let spec = ChartSpec::default();
    let (w, h) = (200usize, 150usize);
    let image_from_chart = Pose::default().image_from_chart(&spec, w, h);
    let chart_from_ideal = image_from_chart.inverse().expect("pose");
    let identity = [LensGeometry::default().mapping(Channel::G, 0.0, 0.0, w, h)];
    let (s, tile, margin) = (4usize, 16usize, 5usize);
    let m = good_size(2 * tile + 1 + 2 * margin);
    let n = m * s;
    let (xs, ys) = (centre_grid(w, tile), centre_grid(h, tile));
    let mut strips = BentStrips {
        spec: &spec,
        chart_from_ideal: &chart_from_ideal,
        maps: &identity,
        block: 28,
        background: 0.35,
        s,
        origin: [-((tile + margin) as i64); 2],
        tile,
        width_sub: ((xs.len() - 1) * tile + m) * s,
        first: 0,
        held: std::collections::VecDeque::new(),
    };
    let sf = s as f64;
    let off = (sf - 1.0) / (2.0 * sf);
    let mut worst = 0.0f32;
    for &cy in &ys {
        let y0 = cy as i64 - (tile + margin) as i64;
        strips.reach_row(y0, n);
        assert!(strips.held.len() <= n.div_ceil(tile * s) + 1);
        for &cx in xs.iter().step_by(3) {
            let x0 = cx as i64 - (tile + margin) as i64;
            let cut = strips.window(x0, y0, n);
            let sub_from_sensor = Homography::translation(x0 as f64 - off, y0 as f64 - off)
                .compose(&Homography::scaling(1.0 / sf, 1.0 / sf))
                .inverse()
                .expect("inverse");
            let exact = rasterize(
                &spec,
                &sub_from_sensor.compose(&image_from_chart),
                n,
                n,
                0.35,
            );
            for (a, b) in exact.data.iter().zip(&cut[0].data) {
                worst = worst.max((a - b).abs());
            }
        }
    }
    assert!(worst < 1e-4, "worst difference {worst}");
}

/// An ideal lens takes the exact path: no per-channel truth, nothing new in the
/// truth file.
#[test]
fn an_ideal_lens_adds_nothing_to_the_truth() {
    let spec = ChartSpec {
        cols: 4,
        rows: 3,
        ..ChartSpec::default()
    };
    let setting = LensSetting {
        focal_mm: 35.0,
        f_number: 5.6,
    };
    let mut cp = CaptureParams::new(96, 64, setting);
    cp.noise = NoiseModel::none();
    let job = JobContext::silent();
    let shot = simulate_shot(&spec, &VirtualLens::demo(), &cp, &job).expect("simulate");
    assert!(shot.truth.squares.iter().all(|s| s.channels.is_empty()));
    let json = serde_json::to_string(&shot.truth).expect("json");
    assert!(!json.contains("geometry") && !json.contains("\"channels\""));
    let sq = &shot.truth.squares[5];
    assert_eq!(sq.corners_of(Channel::R), sq.corners);
}
