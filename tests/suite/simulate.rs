//! The capture simulator against its own ground truth.

use lensblur::chart::ChartSpec;
use lensblur::job::JobContext;
use lensblur::plane::{Channel, LensSetting};
use lensblur::simulate::{
    CaptureParams, NoiseModel, Pose, SimulatedShot, VirtualLens, simulate_shot,
};

fn big_square_chart() -> ChartSpec {
    ChartSpec {
        cols: 8,
        rows: 6,
        ..ChartSpec::default()
    }
}

fn shot(spec: &ChartSpec, noise: NoiseModel, bayer: bool) -> SimulatedShot {
    shot_with(spec, noise, bayer, 0.0)
}

fn shot_with(spec: &ChartSpec, noise: NoiseModel, bayer: bool, rotation_deg: f64) -> SimulatedShot {
    let mut p = CaptureParams::new(
        480,
        320,
        LensSetting {
            focal_mm: 24.0,
            f_number: 4.0,
        },
    );
    p.noise = noise;
    p.bayer = bayer;
    p.pose = Pose {
        fill: 0.85,
        rotation_deg,
        ..Pose::default()
    };
    let t = std::time::Instant::now();
    let s = simulate_shot(spec, &VirtualLens::demo(), &p, &JobContext::silent()).expect("simulate");
    eprintln!("480×320 shot in {:.2} s", t.elapsed().as_secs_f64());
    s
}

/// Φ((x − e)/σ) integrated over the unit pixel box, numerically.
fn box_erf(x: f64, edge: f64, sigma: f64) -> f64 {
    let n = 64;
    (0..n)
        .map(|k| {
            let t = x - 0.5 + (k as f64 + 0.5) / n as f64;
            0.5 * (1.0 + erf((t - edge) / (sigma * std::f64::consts::SQRT_2)))
        })
        .sum::<f64>()
        / n as f64
}

fn erf(x: f64) -> f64 {
    // Abramowitz–Stegun 7.1.26 is too coarse for a 1 % σ test; integrate the series.
    let t = x.abs();
    let mut sum = 0.0;
    let mut term = t;
    let mut k = 0.0;
    while k < 200.0 {
        let add = term / (2.0 * k + 1.0);
        sum += add;
        if add.abs() < 1e-17 {
            break;
        }
        k += 1.0;
        term *= -t * t / k;
        if t > 6.0 {
            return x.signum();
        }
    }
    x.signum() * (2.0 / std::f64::consts::PI.sqrt() * sum).clamp(-1.0, 1.0)
}

/// The σ of an erf profile fitted to pixels `xs` of row `y` around an edge at `edge`.
fn fit_edge_sigma(plane: &lensblur::plane::Plane, y: usize, edge: f64, rising: bool) -> f64 {
    let xs: Vec<usize> = ((edge - 4.5).ceil() as usize..=(edge + 4.5).floor() as usize).collect();
    let observed: Vec<f64> = xs.iter().map(|&x| f64::from(plane.get(x, y))).collect();
    let cost = |sigma: f64| -> f64 {
        xs.iter()
            .zip(&observed)
            .map(|(&x, &o)| {
                let f = box_erf(x as f64, edge, sigma);
                let m = if rising { f } else { 1.0 - f };
                (m - o).powi(2)
            })
            .sum()
    };
    // Golden-section search.
    let (mut a, mut b) = (0.2f64, 5.0f64);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        let c = b - g * (b - a);
        let d = a + g * (b - a);
        if cost(c) < cost(d) { b = d } else { a = c }
    }
    0.5 * (a + b)
}

/// A near-vertical edge (the chart turned 0.6°, so its rows sample every sub-pixel phase
/// of the edge) has the erf profile of the truth σ along x.
#[test]
fn vertical_edge_profile_has_the_truth_sigma() {
    let spec = big_square_chart();
    let s = shot_with(&spec, NoiseModel::none(), false, 0.6);
    let hfc = s.truth.image_from_chart;
    let theta = 0.6f64.to_radians();
    // The edge between squares (3, 2) and (4, 2), near the frame centre.
    let (col, row) = (4usize, 2usize);
    let rising = spec.is_black(col - 1, row);
    let top = hfc.apply([col as f64, row as f64 + 0.1]);
    let bottom = hfc.apply([col as f64, row as f64 + 0.9]);
    for (ci, ch) in [Channel::R, Channel::G, Channel::B].into_iter().enumerate() {
        let plane = &s.clean[ci].1;
        let (mut sum_rel, mut worst_row, mut n) = (0.0, 0.0f64, 0);
        for y in top[1].ceil() as usize..=bottom[1].floor() as usize {
            let t = (y as f64 - top[1]) / (bottom[1] - top[1]);
            let edge = top[0] + t * (bottom[0] - top[0]);
            let g = s
                .truth
                .psf_field
                .optical_at(ch, edge, y as f64)
                .expect("truth");
            // Along x, a step with normal (cos θ, −sin θ) has σ_n / cos θ.
            let var_n = g.sigma_x.powi(2) * theta.cos().powi(2)
                - 2.0 * g.cov_xy() * theta.sin() * theta.cos()
                + g.sigma_y.powi(2) * theta.sin().powi(2);
            let truth = var_n.sqrt() / theta.cos();
            let rel = fit_edge_sigma(plane, y, edge, rising) / truth - 1.0;
            sum_rel += rel;
            worst_row = worst_row.max(rel.abs());
            n += 1;
        }
        let mean_rel = sum_rel / f64::from(n);
        eprintln!(
            "{ch}: {n} rows, mean σ error {:+.3} %, worst single row {:.3} %",
            100.0 * mean_rel,
            100.0 * worst_row
        );
        assert!(
            mean_rel.abs() < 0.01,
            "{ch}: edge σ off by {:.2} %",
            100.0 * mean_rel
        );
    }
}

#[test]
fn black_squares_read_the_black_level_and_paper_the_exposure() {
    let spec = big_square_chart();
    let s = shot(&spec, NoiseModel::typical(), true);
    let w = s.truth.width;
    let hfc = s.truth.image_from_chart;
    let mut black_means = Vec::new();
    for sq in s
        .truth
        .squares
        .iter()
        .filter(|q| q.fully_visible && spec.is_black(q.col, q.row))
    {
        // A patch between the circles: around (0.5, 0.1) of the square.
        let p = hfc.apply([sq.col as f64 + 0.5, sq.row as f64 + 0.12]);
        let (mut sum, mut n) = (0.0, 0);
        for y in (p[1] as usize - 1)..=(p[1] as usize + 1) {
            for x in (p[0] as usize - 6)..=(p[0] as usize + 6) {
                sum += f64::from(s.cfa[y * w + x]);
                n += 1;
            }
        }
        black_means.push(sum / f64::from(n));
    }
    let mean = black_means.iter().sum::<f64>() / black_means.len() as f64;
    // Read noise 3 e⁻ of 30000 e⁻ over 15871 DN is 1.6 DN; the mean of 39 px × N squares.
    eprintln!(
        "black squares mean {mean:.3} DN (black level 512), {} squares",
        black_means.len()
    );
    assert!((mean - 512.0).abs() < 0.5, "black level {mean}");
    let g = s
        .capture
        .planes
        .iter()
        .find(|p| p.channel == lensblur::plane::Channel::G)
        .expect("G plane");
    assert_eq!(g.step, 2);
}

#[test]
fn truth_corners_follow_the_pose() {
    let spec = ChartSpec::default();
    let mut p = CaptureParams::new(
        480,
        320,
        LensSetting {
            focal_mm: 50.0,
            f_number: 5.6,
        },
    );
    p.pose = Pose {
        rotation_deg: 1.5,
        tilt_x: 0.03,
        tilt_y: -0.02,
        fill: 0.9,
        shift_px: [3.0, -2.0],
    };
    let h = p.pose.image_from_chart(&spec, 480, 320);
    let c = h.apply([12.0, 8.0]);
    assert!(
        (c[0] - 242.5).abs() < 1e-9 && (c[1] - 157.5).abs() < 1e-9,
        "{c:?}"
    );
    let tl = h.apply([0.0, 0.0]);
    let tr = h.apply([24.0, 0.0]);
    let width = ((tr[0] - tl[0]).powi(2) + (tr[1] - tl[1]).powi(2)).sqrt();
    assert!(
        (width / (0.9 * 480.0) - 1.0).abs() < 0.05,
        "checkerboard width {width}"
    );
}

#[test]
fn aberrated_shot_simulates_with_its_true_kernels() {
    let spec = big_square_chart();
    let mut p = CaptureParams::new(
        320,
        214,
        LensSetting {
            // Mid-range: the wide-open corners' 24 px kernels would make this slow.
            focal_mm: 70.0,
            f_number: 5.6,
        },
    );
    p.noise = NoiseModel::none();
    p.bayer = false;
    let lens = VirtualLens::aberrated();
    let s = simulate_shot(&spec, &lens, &p, &JobContext::silent()).expect("simulate");
    assert_eq!(s.truth.squares.len(), spec.rows * spec.cols);
    for sq in &s.truth.squares {
        assert_eq!(sq.pixel_kernels.len(), 3, "square {} {}", sq.row, sq.col);
        for (ch, k) in &sq.pixel_kernels {
            assert_eq!(k.oversample, 3);
            let sum: f64 = k.data.iter().sum();
            assert!((sum - 1.0).abs() < 1e-9, "{ch:?} kernel sums to {sum}");
            // The truth's moments and its kernel describe the same PSF: the kernel's
            // variance is the pixel-level one (optical plus the pixel box).
            let m = k.moments();
            let g = sq.pixel_of(*ch).expect("pixel truth");
            let rel = m.var_x / g.sigma_x.powi(2);
            assert!((0.85..1.15).contains(&rel), "{ch:?} var ratio {rel}");
        }
    }
    for (_, plane) in &s.clean {
        assert!(plane.data.iter().all(|v| v.is_finite()));
    }
}
