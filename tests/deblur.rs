//! Deblurring against simulator ground truth: SSIM/PSNR against scikit-image, solver
//! oracles, seams, the spatially varying field, the Gaussian-approximation experiment.

use lensblur::deblur::fft::Fft2;
use lensblur::deblur::solve::{HqsParams, Method, WienerParams, deconvolve_block};
use lensblur::deblur::source::{KernelSample, KernelsFile, Prefer, ScatteredKernels};
use lensblur::deblur::{DeblurOptions, TileGrid, deblur_channel_plane, deblur_plane_invariant};
use lensblur::experiment::{ExperimentOptions, dead_leaves, gaussian_approx, measured_kernels};
use lensblur::job::JobContext;
use lensblur::metrics::{SsimParams, psnr, reference_pair, ssim, ssim_f64};
use lensblur::plane::{Channel, ChannelPlane, LensSetting, Plane};
use lensblur::psf::{Gaussian2, Kernel};
use lensblur::simulate::PsfShape;
use lensblur::simulate::lens::VirtualLens;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

#[test]
fn ssim_and_psnr_match_scikit_image() {
    // From scripts/ssim_reference.py (scikit-image 0.26.0).
    let reference = [
        (0, 64, 48, 0.872723044096, 17.203081036615),
        (1, 50, 37, 0.766278689900, 16.707434976635),
        (2, 33, 29, -0.652798575078, 4.871108476895),
    ];
    for (index, w, h, want_ssim, want_psnr) in reference {
        let (a, b) = reference_pair(index, w, h);
        let got = ssim_f64(&a, &b, w, h, &SsimParams::default());
        assert!(
            (got - want_ssim).abs() < 1e-9,
            "pair {index}: SSIM {got} vs {want_ssim}"
        );
        let pa = Plane {
            width: w,
            height: h,
            data: a.iter().map(|&v| v as f32).collect(),
        };
        let pb = Plane {
            width: w,
            height: h,
            data: b.iter().map(|&v| v as f32).collect(),
        };
        let got = psnr(&pa, &pb, 1.0);
        assert!(
            (got - want_psnr).abs() < 1e-4,
            "pair {index}: PSNR {got} vs {want_psnr}"
        );
    }
}

fn to_f64(p: &Plane) -> Vec<f64> {
    p.data.iter().map(|&v| f64::from(v)).collect()
}

#[test]
fn solvers_recover_a_noise_free_periodic_image() {
    let n = 96;
    let sharp = to_f64(&dead_leaves(n, n, 3));
    let k = Gaussian2 {
        sigma_x: 1.4,
        sigma_y: 1.0,
        rho: 0.3,
    }
    .kernel(1);
    let fft = Fft2::new(n, n);
    let blurry = fft.convolve(&sharp, &k);
    let p = SsimParams::default();
    let before = ssim_f64(&blurry, &sharp, n, n, &p);
    for (method, bar) in [
        // Noise-free and periodic: with (almost) no regularisation both must invert the
        // blur; what is left is the frequencies the Gaussian all but erases.
        (Method::Wiener(WienerParams { nsr: 1e-10 }), 0.99),
        (
            Method::Hqs(HqsParams {
                lambda: 1e12,
                beta_max: 16.0,
                ..HqsParams::default()
            }),
            0.99,
        ),
    ] {
        let x = deconvolve_block(&fft, &blurry, &k, &method);
        let s = ssim_f64(&x, &sharp, n, n, &p);
        let rms = (x
            .iter()
            .zip(&sharp)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / (n * n) as f64)
            .sqrt();
        eprintln!(
            "{}: SSIM {before:.4} -> {s:.4}, RMS {rms:.5}",
            method.name()
        );
        assert!(s > bar, "{}: SSIM {s}", method.name());
    }
}

/// Renders `sharp` (larger than the output by `pad` on every side) through a per-pixel
/// kernel: the output pixel (x, y) is Σ k_{x,y}(q) sharp((x, y) − q).
fn render_varying(
    sharp: &Plane,
    pad: usize,
    w: usize,
    h: usize,
    kernel_at: &(dyn Fn(usize, usize) -> Kernel + Sync),
) -> Plane {
    let rows: Vec<Vec<f32>> = (0..h)
        .into_par_iter()
        .map(|y| {
            (0..w)
                .map(|x| {
                    let k = kernel_at(x, y);
                    let c = (k.size / 2) as isize;
                    let mut acc = 0.0;
                    for j in 0..k.size {
                        for i in 0..k.size {
                            let sx = (x + pad) as isize - (i as isize - c);
                            let sy = (y + pad) as isize - (j as isize - c);
                            acc += k.at(i, j) * f64::from(sharp.get(sx as usize, sy as usize));
                        }
                    }
                    acc as f32
                })
                .collect()
        })
        .collect();
    Plane {
        width: w,
        height: h,
        data: rows.concat(),
    }
}

fn add_noise(p: &mut Plane, sigma: f64, seed: u64) {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma).unwrap();
    for v in &mut p.data {
        *v += noise.sample(&mut rng) as f32;
    }
}

fn crop_ssim(a: &Plane, b: &Plane, x0: usize, y0: usize, s: usize) -> f64 {
    ssim(
        &a.crop(x0, y0, s, s),
        &b.crop(x0, y0, s, s),
        &SsimParams::default(),
    )
}

#[test]
fn no_seams_with_a_constant_kernel() {
    let (w, h, pad) = (320, 256, 24);
    let big = dead_leaves(w + 2 * pad, h + 2 * pad, 11);
    let sharp = big.crop(pad, pad, w, h);
    let k = Gaussian2 {
        sigma_x: 1.6,
        sigma_y: 1.3,
        rho: 0.2,
    }
    .kernel(1);
    let mut blurry = render_varying(&big, pad, w, h, &|_, _| k.clone());
    add_noise(&mut blurry, 0.003, 5);
    let opts = DeblurOptions {
        method: Method::default(),
        tile_core: Some(64),
    };
    let out = deblur_plane_invariant(&blurry, &k, &opts, &JobContext::silent()).unwrap();
    let grid = TileGrid::for_radius(k.size / 2, Some(64));
    // Tile borders: where a window is zero (a core's first column) — every step pixels.
    let step = grid.step() as isize;
    let on_border = |v: usize| -> bool {
        let r = (v as isize + step).rem_euclid(step);
        r == 0 || r == 1 || r == step - 1
    };
    let (mut e_b, mut n_b, mut e_o, mut n_o) = (0.0, 0usize, 0.0, 0usize);
    let m = 12;
    for y in m..h - m {
        for x in m..w - m {
            let r = f64::from(out.get(x, y) - sharp.get(x, y)).powi(2);
            if on_border(x) || on_border(y) {
                e_b += r;
                n_b += 1;
            } else {
                e_o += r;
                n_o += 1;
            }
        }
    }
    let ratio = (e_b / n_b as f64) / (e_o / n_o as f64);
    let before = ssim(&blurry, &sharp, &SsimParams::default());
    let after = ssim(&out, &sharp, &SsimParams::default());
    eprintln!("seams: border/other residual energy {ratio:.4}; SSIM {before:.4} -> {after:.4}");
    assert!(
        ratio < 1.1,
        "tile borders carry {ratio}× the residual energy"
    );
    assert!(after > before + 0.05);
}

#[test]
fn spatially_varying_field_beats_blurry_and_invariant() {
    let lens = VirtualLens::demo();
    // Not a calibration setting: between the usual sweep points.
    let setting = LensSetting {
        focal_mm: 31.0,
        f_number: 4.5,
    };
    let (w, h, pad) = (384, 256, 24);
    let ch = Channel::G;
    let truth = |x: f64, y: f64| {
        lens.gaussian_at(ch, x, y, w, h, setting)
            .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
    };
    let big = dead_leaves(w + 2 * pad, h + 2 * pad, 21);
    let sharp = big.crop(pad, pad, w, h);
    let mut blurry = render_varying(&big, pad, w, h, &|x, y| truth(x as f64, y as f64).kernel(1));
    add_noise(&mut blurry, 0.005, 9);
    let cp = ChannelPlane {
        channel: ch,
        plane: blurry.clone(),
        step: 1,
        offset_x: 0,
        offset_y: 0,
    };
    let job = JobContext::silent();
    let hqs = DeblurOptions::default();
    let true_source = |_c: Channel, x: f64, y: f64| truth(x, y).kernel(1);
    // "Predicted": Gaussians known only on a sparse 6 × 4 grid, interpolated.
    let mut samples = Vec::new();
    for j in 0..4 {
        for i in 0..6 {
            let (x, y) = (
                i as f64 * (w - 1) as f64 / 5.0,
                j as f64 * (h - 1) as f64 / 3.0,
            );
            let g = truth(x, y);
            samples.push(KernelSample {
                x,
                y,
                channel: ch,
                cxx: Some(g.sigma_x),
                cyy: Some(g.sigma_y),
                cor: Some(g.rho),
                row: None,
                col: None,
                ml: None,
                kernel: None,
            });
        }
    }
    let file = KernelsFile {
        schema: "lensblur.kernels/1".into(),
        width: w,
        height: h,
        focal_mm: Some(31.0),
        f_number: Some(4.5),
        oversample: 1,
        identity: None,
        samples,
        failed: Vec::new(),
    };
    let predicted = ScatteredKernels::new(file, Prefer::Gaussian);
    let x_true = deblur_channel_plane(&cp, w, h, &true_source, &hqs, &job).unwrap();
    let x_pred = deblur_channel_plane(&cp, w, h, &predicted, &hqs, &job).unwrap();
    let wiener = DeblurOptions {
        method: Method::Wiener(WienerParams::default()),
        tile_core: None,
    };
    let x_wiener = deblur_channel_plane(&cp, w, h, &true_source, &wiener, &job).unwrap();
    let centre = truth((w - 1) as f64 / 2.0, (h - 1) as f64 / 2.0).kernel(1);
    let x_inv = deblur_plane_invariant(&blurry, &centre, &hqs, &job).unwrap();
    let p = SsimParams::default();
    let s = |x: &Plane| ssim(x, &sharp, &p);
    let (sb, st, sp, sw, si) = (s(&blurry), s(&x_true), s(&x_pred), s(&x_wiener), s(&x_inv));
    eprintln!(
        "SSIM blurry {sb:.4} true {st:.4} predicted {sp:.4} wiener-true {sw:.4} invariant {si:.4}"
    );
    let c = 96;
    let corners = [(0, 0), (w - c, 0), (0, h - c), (w - c, h - c)];
    for (x0, y0) in corners {
        let (cp_, ci) = (
            crop_ssim(&x_pred, &sharp, x0, y0, c),
            crop_ssim(&x_inv, &sharp, x0, y0, c),
        );
        eprintln!("corner ({x0},{y0}): predicted {cp_:.4} invariant {ci:.4}");
        assert!(
            cp_ > ci,
            "corner ({x0},{y0}): predicted {cp_} vs invariant {ci}"
        );
    }
    assert!(sp > sb + 0.05, "predicted {sp} vs blurry {sb}");
    assert!((st - sp).abs() < 0.01, "predicted {sp} vs true {st}");
    assert!(sp > sw, "HQS predicted {sp} vs Wiener true {sw}");
}

#[test]
fn gaussian_approximation_experiment() {
    // Kernels measured on simulated chart shots of the (Gaussian-blurring) virtual lens.
    let kernels = measured_kernels(30, PsfShape::Gaussian, 5, &JobContext::silent())
        .expect("kernels measured on simulated shots");
    let opts = ExperimentOptions {
        image_px: 96,
        ..ExperimentOptions::default()
    };
    let report = gaussian_approx(&kernels, &opts, &JobContext::silent()).unwrap();
    for s in &report.summary {
        eprintln!("{s:?}");
    }

    let nat = &report.summary[0];
    let syn = &report.summary[1];
    assert!(
        nat.robust_p99 <= 1.01,
        "natural robust p99 {}",
        nat.robust_p99
    );
    assert!(
        syn.robust_p99 <= 1.02,
        "synthetic robust p99 {}",
        syn.robust_p99
    );
    assert!(
        nat.ml_p99 > nat.robust_p99 && syn.ml_p99 > syn.robust_p99,
        "ML not worse"
    );
}
