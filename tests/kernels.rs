//! Kernel and Gaussian estimates against exact ground truth.
//!
//! The scaffolding renders the chart exactly at high oversampling under a known
//! homography, convolves it with a known optical PSF, integrates over pixel areas
//! (averages s × s blocks), mosaics or not, adds Poisson–Gaussian noise and quantises;
//! the estimator gets the TRUE homography, which isolates the kernel stage. Truth is the
//! pixel-level PSF: optical ⊛ 1-px box.

use lensblur::chart::{self, ChartSpec};
use lensblur::fft::convolve_full;
use lensblur::geometry::Homography;
use lensblur::kernel::{KernelParams, SquareGeometry, estimate_square_geometry};
use lensblur::plane::{Capture, Channel, ChannelPlane, Plane};
use lensblur::psf::{Gaussian2, Kernel};
use nalgebra::Matrix3;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

/// Simulation oversampling: the optical PSF and the chart live on a 1/SIM_OS px grid.
const SIM_OS: usize = 5;

/// A chart pose: `square_px` pixels per square, a small rotation and perspective, the
/// chart's (0, 0) corner at `origin`.
fn pose(square_px: f64, angle_deg: f64, origin: [f64; 2]) -> Homography {
    let (s, c) = angle_deg.to_radians().sin_cos();
    let m = Matrix3::new(
        square_px * c,
        -square_px * s,
        origin[0],
        square_px * s,
        square_px * c,
        origin[1],
        0.004,
        -0.003,
        1.0,
    );
    Homography(m)
}

/// The chart blurred by `optical` (sampled at SIM_OS×) and integrated over pixels:
/// linear values, white 1, black 0.
fn render(
    spec: &ChartSpec,
    image_from_chart: &Homography,
    width: usize,
    height: usize,
    optical: &Kernel,
) -> Plane {
    assert_eq!(optical.oversample, SIM_OS);
    let r = optical.size / 2;
    let (sw, sh) = (width * SIM_OS + 2 * r, height * SIM_OS + 2 * r);
    // Sub-cell u of pixel i: u = SIM_OS·i + k, centre at sensor (u + ½)/SIM_OS − ½; the
    // raster is shifted by r so the valid convolution covers the frame exactly.
    let s = SIM_OS as f64;
    let sub_from_image =
        Homography::translation(0.5 * s - 0.5 + r as f64, 0.5 * s - 0.5 + r as f64)
            .compose(&Homography::scaling(s, s));
    let sharp = chart::rasterize(spec, &sub_from_image.compose(image_from_chart), sw, sh, 1.0);
    let sharp64: Vec<f64> = sharp.data.iter().map(|&v| f64::from(v)).collect();
    let full = convolve_full(&sharp64, sw, sh, &optical.data, optical.size, optical.size);
    let fw = sw + optical.size - 1;
    Plane::from_fn(width, height, |x, y| {
        let mut acc = 0.0;
        for j in 0..SIM_OS {
            for i in 0..SIM_OS {
                // Valid output index = raster index + 2r.
                acc += full[(y * SIM_OS + j + 2 * r) * fw + x * SIM_OS + i + 2 * r];
            }
        }
        (acc / (s * s)) as f32
    })
}

struct Levels {
    black: f32,
    white: f32,
}

fn noisy(v: f32, rng: &mut impl Rng, bits: u32) -> f32 {
    // Poisson–Gaussian: 20 000 e⁻ full well, read noise 0.15 % of white.
    let var = f64::from(v.max(0.0)) / 20_000.0 + 0.0015f64.powi(2);
    let n = Normal::new(0.0, var.sqrt())
        .map(|d| d.sample(rng))
        .unwrap_or(0.0);
    let q = f64::from((1u32 << bits) - 1);
    ((f64::from(v) + n).clamp(0.0, 1.0) * q).round() as f32 / q as f32
}

/// An RGB (16-bit) or RGGB RAW (14-bit) capture from three linear channel images.
fn capture(images: &[(Channel, Plane, Levels)], raw: bool, seed: u64) -> Capture {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (w, h) = (images[0].1.width, images[0].1.height);
    let level =
        |img: &Plane, l: &Levels, x: usize, y: usize| l.black + (l.white - l.black) * img.get(x, y);
    let mut planes = Vec::new();
    if raw {
        for (ch, ox, oy) in [
            (Channel::R, 0, 0),
            (Channel::G, 1, 0),
            (Channel::G, 0, 1),
            (Channel::B, 1, 1),
        ] {
            let Some((_, img, l)) = images.iter().find(|(c, _, _)| *c == ch) else {
                continue;
            };
            let plane = Plane::from_fn(w / 2, h / 2, |i, j| {
                noisy(level(img, l, 2 * i + ox, 2 * j + oy), &mut rng, 14)
            });
            planes.push(ChannelPlane {
                channel: ch,
                plane,
                step: 2,
                offset_x: ox,
                offset_y: oy,
            });
        }
    } else {
        for (ch, img, l) in images {
            let plane = Plane::from_fn(w, h, |x, y| noisy(level(img, l, x, y), &mut rng, 16));
            planes.push(ChannelPlane {
                channel: *ch,
                plane,
                step: 1,
                offset_x: 0,
                offset_y: 0,
            });
        }
    }
    Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: None,
        setting_f_number: None,
        identity: Default::default(),
        is_raw: raw,
    }
}

/// Squares whose whole region (plus `margin_px`) lies in the frame.
fn squares_inside(
    spec: &ChartSpec,
    h: &Homography,
    width: usize,
    height: usize,
    margin_px: f64,
) -> Vec<SquareGeometry> {
    let mut out = Vec::new();
    for row in 0..spec.rows {
        for col in 0..spec.cols {
            let inside = spec.square_corners(col, row).iter().all(|c| {
                let p = h.apply(*c);
                p[0] >= margin_px
                    && p[1] >= margin_px
                    && p[0] <= width as f64 - 1.0 - margin_px
                    && p[1] <= height as f64 - 1.0 - margin_px
            });
            if inside {
                out.push(SquareGeometry {
                    row,
                    col,
                    image_from_chart: *h,
                });
            }
        }
    }
    out
}

fn percentile(values: &[f64], p: f64) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let idx = ((v.len() - 1) as f64 * p).round() as usize;
    v[idx]
}

#[derive(Default)]
struct Errors {
    sigma_rel: Vec<f64>,
    rho_abs: Vec<f64>,
    failures: Vec<String>,
}

impl Errors {
    fn add(&mut self, est: &Gaussian2, truth: &Gaussian2) {
        self.sigma_rel
            .push((est.sigma_x / truth.sigma_x - 1.0).abs());
        self.sigma_rel
            .push((est.sigma_y / truth.sigma_y - 1.0).abs());
        self.rho_abs.push((est.rho - truth.rho).abs());
    }

    fn summary(&self) -> (f64, f64, f64, f64) {
        (
            percentile(&self.sigma_rel, 0.5),
            percentile(&self.sigma_rel, 0.95),
            percentile(&self.rho_abs, 0.5),
            percentile(&self.rho_abs, 0.95),
        )
    }
}

/// One shot per PSF triple (R, G, B optical Gaussians); every inside square estimated
/// in every channel; errors of the robust fit against the pixel-level truth.
fn gaussian_errors(
    psfs: &[[Gaussian2; 3]],
    raw: bool,
    params: &KernelParams,
    square_px: f64,
) -> Errors {
    let spec = ChartSpec {
        cols: 4,
        rows: 3,
        ..ChartSpec::default()
    };
    let (w, h) = (256usize, 192usize);
    let results: Vec<Errors> = psfs
        .par_iter()
        .enumerate()
        .map(|(shot, triple)| {
            let hom = pose(
                square_px,
                2.0 + shot as f64,
                [14.0 + shot as f64 * 0.37, 10.0 + shot as f64 * 0.61],
            );
            let levels = [(0.06, 0.78), (0.05, 0.92), (0.07, 0.70)];
            let images: Vec<(Channel, Plane, Levels)> = [Channel::R, Channel::G, Channel::B]
                .iter()
                .zip(triple)
                .zip(levels)
                .map(|((ch, g), (b, wl))| {
                    (
                        *ch,
                        render(&spec, &hom, w, h, &g.kernel(SIM_OS)),
                        Levels {
                            black: b,
                            white: wl,
                        },
                    )
                })
                .collect();
            let cap = capture(&images, raw, 100 + shot as u64);
            let mut errs = Errors::default();
            for sq in squares_inside(&spec, &hom, w, h, 4.0)
                .into_iter()
                .step_by(2)
            {
                for (ch, g) in [Channel::R, Channel::G, Channel::B].iter().zip(triple) {
                    let truth = g.convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
                    match estimate_square_geometry(&cap, &sq, &spec, params, *ch) {
                        Ok(e) => errs.add(&e.fit.robust, &truth),
                        Err(f) => errs.failures.push(format!(
                            "shot {shot} square ({},{}) {ch}: {f}",
                            sq.row, sq.col
                        )),
                    }
                }
            }
            errs
        })
        .collect();
    let mut all = Errors::default();
    for e in results {
        all.sigma_rel.extend(e.sigma_rel);
        all.rho_abs.extend(e.rho_abs);
        all.failures.extend(e.failures);
    }
    all
}

/// Random asymmetric optical Gaussians, σ in [lo, hi] px, |ρ| ≤ 0.5.
fn random_psfs(n: usize, lo: f64, hi: f64, seed: u64) -> Vec<[Gaussian2; 3]> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            std::array::from_fn(|_| Gaussian2 {
                sigma_x: rng.random_range(lo..hi),
                sigma_y: rng.random_range(lo..hi),
                rho: rng.random_range(-0.5..0.5),
            })
        })
        .collect()
}

fn assert_bars(name: &str, errs: &Errors) {
    let (med, p95, rho_med, rho_p95) = errs.summary();
    eprintln!(
        "{name}: {} σ values, |σ/σ_true − 1| median {:.2} % p95 {:.2} %; |ρ err| median {:.4} p95 {:.4}; {} failures",
        errs.sigma_rel.len(),
        100.0 * med,
        100.0 * p95,
        rho_med,
        rho_p95,
        errs.failures.len()
    );
    assert!(
        errs.failures.is_empty(),
        "{name}: failures {:?}",
        errs.failures
    );
    assert!(med <= 0.02, "{name}: median σ error {:.2} %", 100.0 * med);
    assert!(p95 <= 0.06, "{name}: p95 σ error {:.2} %", 100.0 * p95);
    assert!(rho_med <= 0.02, "{name}: median ρ error {rho_med:.4}");
    assert!(rho_p95 <= 0.06, "{name}: p95 ρ error {rho_p95:.4}");
}

#[test]
fn gaussian_psfs_rgb16_meet_the_bars() {
    let errs = gaussian_errors(
        &random_psfs(3, 0.7, 3.0, 1),
        false,
        &KernelParams::default(),
        52.0,
    );
    assert_bars("RGB 16-bit", &errs);
}

#[test]
fn gaussian_psfs_raw_bayer_meet_the_bars() {
    let errs = gaussian_errors(
        &random_psfs(3, 0.7, 3.0, 2),
        true,
        &KernelParams::default(),
        52.0,
    );
    assert_bars("RAW Bayer", &errs);
}

#[test]
fn debug_one() {
    let spec = ChartSpec {
        cols: 4,
        rows: 3,
        ..ChartSpec::default()
    };
    let (w, h) = (256usize, 192usize);
    let hom = pose(52.0, 2.0, [14.0, 10.0]);
    let g = Gaussian2 {
        sigma_x: 1.5,
        sigma_y: 1.0,
        rho: 0.3,
    };
    let t = std::time::Instant::now();
    let img = render(&spec, &hom, w, h, &g.kernel(SIM_OS));
    eprintln!("render {:?}", t.elapsed());
    let cap = capture(
        &[(
            Channel::G,
            img,
            Levels {
                black: 0.05,
                white: 0.9,
            },
        )],
        false,
        1,
    );
    let sq = squares_inside(&spec, &hom, w, h, 4.0);
    eprintln!("{} squares inside", sq.len());
    let truth = g.convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
    for it in [10, 20, 40, 80] {
        let params = KernelParams {
            cg_iterations: it,
            clipped_fraction: 1.0,
            ..KernelParams::default()
        };
        let t = std::time::Instant::now();
        let r = estimate_square_geometry(&cap, &sq[5], &spec, &params, Channel::G);
        match r {
            Ok(e) => {
                let c = lensblur::gaussian::central_region(&e.kernel, 0.02);
                let ck = Kernel {
                    size: e.kernel.size,
                    oversample: 3,
                    data: c,
                };
                eprintln!(
                    "it {it} {:?} border {:.3} central border {:.3} res {:.2e} robust {:?} ml {:?} truth {:?}",
                    t.elapsed(),
                    lensblur::kernel::border_fraction(&e.kernel),
                    lensblur::kernel::border_fraction(&ck),
                    e.cg_residual,
                    e.fit.robust,
                    e.fit.ml,
                    truth
                )
            }
            Err(f) => eprintln!("{:?} fail {f}", t.elapsed()),
        }
    }
}
