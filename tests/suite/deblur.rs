//! Deblurring against simulator ground truth: SSIM/PSNR against scikit-image, solver
//! oracles, seams, image borders, the spatially varying field with a fitted lens
//! profile, the Gaussian-approximation experiment, and the `deblur` command.

use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::deblur::solve::{
    Deconvolver, HqsParams, IrlsParams, Method, WienerParams, deconvolve_block,
};
use lensblur::deblur::source::{KernelData, KernelSample, KernelsFile};
use lensblur::deblur::{
    DeblurOptions, KernelSource, ProfileKernels, TileGrid, deblur_channel_plane,
    deblur_plane_invariant,
};
use lensblur::dng::{DngInfo, write_dng};
use lensblur::experiment::{
    ExperimentOptions, MAX_FAILED_SHOTS_IN_A_ROW, MeasureError, MeasureOptions, gaussian_approx,
    measured_kernels,
};
use lensblur::fft::{Fft2, convolve_direct_circular};
use lensblur::job::JobContext;
use lensblur::metrics::{SsimParams, psnr, reference_pair, ssim, ssim_f64};
use lensblur::model::spaced;
use lensblur::plane::{CameraIdentity, Channel, ChannelPlane, LensSetting, Plane, RawMeta};
use lensblur::profile::Profile;
use lensblur::psf::{Gaussian2, Kernel};
use lensblur::raw::{FocusDistance, LoadOptions, load_capture};
use lensblur::simulate::capture::rggb_channel;
use lensblur::simulate::dead_leaves;
use lensblur::simulate::lens::VirtualLens;
use lensblur::simulate::{PsfShape, SimulatedSession};
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use std::sync::OnceLock;

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

fn asymmetric_kernel() -> Kernel {
    Gaussian2 {
        sigma_x: 1.4,
        sigma_y: 1.0,
        rho: 0.3,
    }
    .kernel(1)
}

#[test]
fn solvers_recover_a_noise_free_periodic_image() {
    let n = 96;
    let sharp = to_f64(&dead_leaves(n, n, 3));
    let k = asymmetric_kernel();
    let blurry = Fft2::new(n, n).convolve(&sharp, &k);
    let p = SsimParams::default();
    let before = ssim_f64(&blurry, &sharp, n, n, &p);
    for method in [
        // Noise-free and periodic: with (almost) no regularisation both must invert the
        // blur; what is left is the frequencies the Gaussian all but erases.
        Method::Wiener(WienerParams { nsr: 1e-10 }),
        Method::Hqs(HqsParams {
            lambda: 1e12,
            beta_max: 16.0,
            ..HqsParams::default()
        }),
    ] {
        let x = deconvolve_block(&blurry, n, n, &k, &method);
        let s = ssim_f64(&x, &sharp, n, n, &p);
        eprintln!("{}: SSIM {before:.4} -> {s:.4}", method.name());
        assert!(s > 0.99, "{}: SSIM {s}", method.name());
    }
}

/// The circular-convolution matrix of `k` on a `w × h` block, column by column.
fn conv_matrix(k: &Kernel, w: usize, h: usize) -> DMatrix<f64> {
    let n = w * h;
    let mut m = DMatrix::zeros(n, n);
    for q in 0..n {
        let mut e = vec![0.0; n];
        e[q] = 1.0;
        for (p, v) in convolve_direct_circular(&e, w, h, k)
            .into_iter()
            .enumerate()
        {
            m[(p, q)] = v;
        }
    }
    m
}

/// Forward differences x(i+1) − x(i) along x and y, circular, as matrices.
fn gradient_matrices(w: usize, h: usize) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = w * h;
    let (mut dx, mut dy) = (DMatrix::zeros(n, n), DMatrix::zeros(n, n));
    for r in 0..h {
        for c in 0..w {
            let p = r * w + c;
            dx[(p, p)] -= 1.0;
            dx[(p, r * w + (c + 1) % w)] += 1.0;
            dy[(p, p)] -= 1.0;
            dy[(p, ((r + 1) % h) * w + c)] += 1.0;
        }
    }
    (dx, dy)
}

#[test]
fn wiener_matches_a_dense_solve() {
    // The oracle: (KᵀK + nsr·(DxᵀDx + DyᵀDy)) x = Kᵀy by a dense solve, which checks
    // the OTF's placement, the gradient spectrum and the filter together.
    let (w, h) = (16, 14);
    let mut k = Gaussian2 {
        sigma_x: 1.2,
        sigma_y: 0.8,
        rho: -0.4,
    }
    .kernel(1);
    // Off-centre mass: a kernel placed the wrong way round would not match.
    k.data[3] += 0.1;
    k.normalise();
    let y: Vec<f64> = (0..w * h).map(|i| ((i * 37 % 23) as f64) / 23.0).collect();
    let kk = conv_matrix(&k, w, h);
    let (dx, dy) = gradient_matrices(w, h);
    let nsr = 0.01;
    let a = kk.transpose() * &kk + (dx.transpose() * &dx + dy.transpose() * &dy) * nsr;
    let want = a
        .lu()
        .solve(&(kk.transpose() * DVector::from_vec(y.clone())))
        .expect("regularised system is invertible");
    let got = deconvolve_block(&y, w, h, &k, &Method::Wiener(WienerParams { nsr }));
    let err = got
        .iter()
        .zip(want.iter())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-10, "max error {err}");
}

#[test]
fn irls_with_a_quadratic_prior_is_wiener() {
    // With α = 2 every IRLS weight is 1, so its system is Wiener's with nsr = α / λ:
    // a check of the reweighted operator and of the conjugate gradients.
    let n = 48;
    let sharp = to_f64(&dead_leaves(n, n, 4));
    let k = asymmetric_kernel();
    let mut y = Fft2::new(n, n).convolve(&sharp, &k);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let noise = Normal::new(0.0, 0.01).expect("σ > 0");
    for v in &mut y {
        *v += noise.sample(&mut rng);
    }
    let lambda = 500.0;
    let irls = deconvolve_block(
        &y,
        n,
        n,
        &k,
        &Method::Irls(IrlsParams {
            lambda,
            alpha: 2.0,
            ..IrlsParams::default()
        }),
    );
    let wiener = deconvolve_block(
        &y,
        n,
        n,
        &k,
        &Method::Wiener(WienerParams { nsr: 2.0 / lambda }),
    );
    let err = irls
        .iter()
        .zip(&wiener)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-6, "max difference {err}");
}

/// λ/2 ‖k ∗ x − y‖² + Σ |∇x|^α on a periodic block.
fn sparse_objective(x: &[f64], y: &[f64], n: usize, k: &Kernel, lambda: f64, alpha: f64) -> f64 {
    let kx = Fft2::new(n, n).convolve(x, k);
    let data: f64 = kx.iter().zip(y).map(|(a, b)| (a - b).powi(2)).sum();
    let mut prior = 0.0;
    for r in 0..n {
        for c in 0..n {
            let v = x[r * n + c];
            prior += (x[r * n + (c + 1) % n] - v).abs().powf(alpha);
            prior += (x[((r + 1) % n) * n + c] - v).abs().powf(alpha);
        }
    }
    0.5 * lambda * data + prior
}

#[test]
fn hqs_and_irls_minimise_the_sparse_objective() {
    let n = 64;
    let sharp = to_f64(&dead_leaves(n, n, 8));
    let k = asymmetric_kernel();
    let mut y = Fft2::new(n, n).convolve(&sharp, &k);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
    let noise = Normal::new(0.0, 0.005).expect("σ > 0");
    for v in &mut y {
        *v += noise.sample(&mut rng);
    }
    let (lambda, alpha) = (3000.0, 0.8);
    let e = |x: &[f64]| sparse_objective(x, &y, n, &k, lambda, alpha);
    let hqs = deconvolve_block(
        &y,
        n,
        n,
        &k,
        &Method::Hqs(HqsParams {
            lambda,
            alpha,
            ..HqsParams::default()
        }),
    );
    let irls = deconvolve_block(
        &y,
        n,
        n,
        &k,
        &Method::Irls(IrlsParams {
            lambda,
            alpha,
            ..IrlsParams::default()
        }),
    );
    let wiener = deconvolve_block(&y, n, n, &k, &Method::Wiener(WienerParams::default()));
    let (eh, ei, ew, ey, es) = (e(&hqs), e(&irls), e(&wiener), e(&y), e(&sharp));
    eprintln!("objective: hqs {eh:.2} irls {ei:.2} wiener {ew:.2} blurry {ey:.2} sharp {es:.2}");
    assert!(eh < ew && eh < ey, "HQS does not lower the objective");
    assert!(ei < ew && ei < ey, "IRLS does not lower the objective");
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
                    assert!(c as usize <= pad, "kernel wider than the padding");
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
    let noise = Normal::new(0.0, sigma).expect("σ > 0");
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

/// The deblurs of one plane under a spatially varying blur: with its true per-tile
/// kernels, its predicted ones, Wiener with the true ones, and one invariant kernel.
struct VaryingDeblurs<'a> {
    channel: Channel,
    sharp: &'a Plane,
    blurry: &'a Plane,
    predicted: &'a Plane,
    invariant: &'a Plane,
    /// SSIM of the blurry plane, the true kernels', the predicted ones', Wiener's.
    ssim: [f64; 4],
}

/// The bars both spatially varying tests hold: in every `c`-pixel corner the predicted
/// kernels beat the invariant one; over the plane they beat the blurry photo and
/// Wiener, within 0.01 SSIM of the true kernels.
fn assert_predicted_kernels_hold(d: &VaryingDeblurs, c: usize) {
    let (ch, (w, h)) = (d.channel, (d.sharp.width, d.sharp.height));
    for (x0, y0) in [(0, 0), (w - c, 0), (0, h - c), (w - c, h - c)] {
        let (cp_, ci) = (
            crop_ssim(d.predicted, d.sharp, x0, y0, c),
            crop_ssim(d.invariant, d.sharp, x0, y0, c),
        );
        eprintln!(
            "  corner {c} px at ({x0},{y0}): blurry {:.4} predicted {cp_:.4} invariant {ci:.4}",
            crop_ssim(d.blurry, d.sharp, x0, y0, c),
        );
        assert!(
            cp_ > ci,
            "{ch}: corner ({x0},{y0}): predicted {cp_} vs invariant {ci}"
        );
    }
    let [sb, st, sp, sw] = d.ssim;
    assert!(sp > sb, "{ch}: predicted {sp} vs blurry {sb}");
    assert!(
        (st - sp).abs() <= 0.01,
        "{ch}: predicted {sp} vs true kernels {st}"
    );
    assert!(sp > sw, "{ch}: HQS predicted {sp} vs Wiener true {sw}");
}

/// Mean squared residual on the bands where neighbouring tiles meet (within half a
/// ramp of a shared border, along x or y) over that elsewhere, `skip` pixels from the
/// image border left out.
fn border_energy_ratio(out: &Plane, sharp: &Plane, grid: &TileGrid, skip: usize) -> f64 {
    let near = |v: usize, axis: &lensblur::deblur::TileAxis| -> bool {
        (1..axis.count).any(|t| {
            let b = (t * axis.step) as isize;
            (v as isize - b).abs() < (axis.ramp / 2).max(1) as isize
        })
    };
    let (mut e_b, mut n_b, mut e_o, mut n_o) = (0.0, 0usize, 0.0, 0usize);
    for y in skip..out.height - skip {
        for x in skip..out.width - skip {
            let r = f64::from(out.get(x, y) - sharp.get(x, y)).powi(2);
            if near(x, &grid.x) || near(y, &grid.y) {
                e_b += r;
                n_b += 1;
            } else {
                e_o += r;
                n_o += 1;
            }
        }
    }
    (e_b / n_b as f64) / (e_o / n_o as f64)
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
    let step = 48;
    let opts = DeblurOptions {
        method: Method::default(),
        tile_step_px: Some(step),
        ..DeblurOptions::default()
    };
    let out = deblur_plane_invariant(&blurry, &k, &opts, &JobContext::silent()).expect("deblur");
    let grid = TileGrid::for_plane(w, h, k.size / 2, Some(step));
    assert!(grid.x.count >= 5 && grid.y.count >= 4, "{grid:?}");
    let ratio = border_energy_ratio(&out, &sharp, &grid, 12);

    // The control: the same tiles deconvolved without margins or taper and butted
    // together show their seams, so the measure can see one.
    let mut seamed = Plane::new(w, h);
    let (sx, sy) = (grid.x.step, grid.y.step);
    let mut dec = Deconvolver::new(sx, sy);
    let mut x = vec![0.0; sx * sy];
    for y0 in (0..h).step_by(sy) {
        for x0 in (0..w).step_by(sx) {
            let block: Vec<f64> = (0..sx * sy)
                .map(|i| {
                    let (bx, by) = ((x0 + i % sx).min(w - 1), (y0 + i / sx).min(h - 1));
                    f64::from(blurry.get(bx, by))
                })
                .collect();
            dec.deconvolve(&block, &k, &Method::default(), &mut x);
            for j in 0..sy.min(h - y0) {
                for i in 0..sx.min(w - x0) {
                    seamed.set(x0 + i, y0 + j, x[j * sx + i] as f32);
                }
            }
        }
    }
    let control = border_energy_ratio(&seamed, &sharp, &grid, 12);

    let before = ssim(&blurry, &sharp, &SsimParams::default());
    let after = ssim(&out, &sharp, &SsimParams::default());
    eprintln!(
        "seams: border/other residual energy {ratio:.4} (butted tiles: {control:.3}); SSIM {before:.4} -> {after:.4}"
    );
    assert!(
        control > 1.5,
        "the measure misses butted tiles' seams: {control}"
    );
    assert!(
        ratio <= 1.0,
        "tile borders carry {ratio}× the residual energy"
    );
    assert!(after > before + 0.05);
}

/// Root-mean-square residual of `out` against `sharp` over pixels whose distance to the
/// nearest image border lies in `from..to`.
fn band_rms(out: &Plane, sharp: &Plane, from: usize, to: usize) -> f64 {
    let (w, h) = (out.width, out.height);
    let (mut e, mut n) = (0.0, 0usize);
    for y in 0..h {
        for x in 0..w {
            let d = x.min(y).min(w - 1 - x).min(h - 1 - y);
            if (from..to).contains(&d) {
                e += f64::from(out.get(x, y) - sharp.get(x, y)).powi(2);
                n += 1;
            }
        }
    }
    (e / n as f64).sqrt()
}

#[test]
fn no_ringing_at_image_borders() {
    // A scene that continues past the frame, blurred with what lies outside it. The
    // reference is the same frame cut from a deblurred larger one, which saw that
    // content: near the border the photo cannot know it, but must not ring.
    let (w, h, pad, extra) = (256, 192, 24, 32);
    let (lw, lh) = (w + 2 * extra, h + 2 * extra);
    let big = dead_leaves(lw + 2 * pad, lh + 2 * pad, 13);
    let sharp = big.crop(pad + extra, pad + extra, w, h);
    let k = asymmetric_kernel();
    let r = k.size / 2;
    let mut large = render_varying(&big, pad, lw, lh, &|_, _| k.clone());
    add_noise(&mut large, 0.003, 6);
    let blurry = large.crop(extra, extra, w, h);
    let job = JobContext::silent();
    let opts = DeblurOptions::default();
    let out = deblur_plane_invariant(&blurry, &k, &opts, &job).expect("deblur");
    let reference = deblur_plane_invariant(&large, &k, &opts, &job)
        .expect("deblur")
        .crop(extra, extra, w, h);
    // The control: the frame deconvolved as one periodic block, borders untreated.
    let periodic = Plane {
        width: w,
        height: h,
        data: deconvolve_block(&to_f64(&blurry), w, h, &k, &Method::default())
            .into_iter()
            .map(|v| v as f32)
            .collect(),
    };
    // Residual RMS over the reference's, in the outer band (within 2 kernel radii of
    // the border) and in the next (2 to 6 radii), where ringing would spread.
    let bands = |p: &Plane| {
        (
            band_rms(p, &sharp, 0, 2 * r) / band_rms(&reference, &sharp, 0, 2 * r),
            band_rms(p, &sharp, 2 * r, 6 * r) / band_rms(&reference, &sharp, 2 * r, 6 * r),
        )
    };
    let (outer, next) = bands(&out);
    let (c_outer, c_next) = bands(&periodic);
    let interior =
        band_rms(&out, &sharp, 6 * r, usize::MAX) / band_rms(&reference, &sharp, 6 * r, usize::MAX);
    eprintln!(
        "border residual / reference residual: outer band {outer:.3}, next band {next:.3}, interior {interior:.3} (periodic block: {c_outer:.3}, {c_next:.3})"
    );
    assert!(
        c_outer > 2.0,
        "the measure misses a periodic block's ringing: {c_outer}"
    );
    // Within two kernel radii the border pays for the content it cannot see; past them
    // nothing of the border may show.
    assert!(
        outer <= 1.25,
        "outer band {outer}× the reference's residual"
    );
    assert!(next <= 1.02, "next band {next}× the reference's residual");
}

/// The calibration set: the demo lens on a 4 × 4 grid of settings (24–105 mm, f/4–10),
/// one shot each, its Gaussians measured with the noise of real kernel estimates.
fn calibration_settings() -> Vec<LensSetting> {
    let mut out = Vec::new();
    for f in spaced(24.0, 105.0, 4, false) {
        for a in spaced(4.0, 10.0, 4, true) {
            out.push(LensSetting {
                focal_mm: f,
                f_number: a,
            });
        }
    }
    out
}

/// A lens profile fitted, model order chosen by cross-validation, on the calibration
/// set for a `w × h` sensor: what `lensblur calibrate` makes from measured kernels.
fn fitted_profile(w: usize, h: usize) -> Profile {
    let ds = SimulatedSession {
        seed: 17,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&VirtualLens::demo(), &calibration_settings());
    let opts = CalibrateOptions {
        families: Families::Global,
        ..CalibrateOptions::default()
    };
    calibrate(&ds, None, &opts, &JobContext::silent())
        .expect("calibrate")
        .0
}

fn profile_384x256() -> &'static Profile {
    static PROFILE: OnceLock<Profile> = OnceLock::new();
    PROFILE.get_or_init(|| fitted_profile(384, 256))
}

#[test]
fn spatially_varying_field_beats_blurry_and_invariant() {
    let lens = VirtualLens::demo();
    let (w, h, pad) = (384, 256, 24);
    let t0 = std::time::Instant::now();
    let profile = profile_384x256();
    eprintln!("profile fitted in {:.1} s", t0.elapsed().as_secs_f64());
    let calibrated = calibration_settings();
    // Settings between the calibrated ones, each image on another channel.
    let cases = [
        (21, Channel::G, 31.0, 4.5),
        (22, Channel::R, 62.0, 7.1),
        (23, Channel::B, 88.0, 5.0),
    ];
    let job = JobContext::silent();
    let hqs = DeblurOptions::default();
    let wiener = DeblurOptions {
        method: Method::Wiener(WienerParams::default()),
        tile_step_px: None,
        ..DeblurOptions::default()
    };
    let p = SsimParams::default();
    for (seed, ch, focal_mm, f_number) in cases {
        let setting = LensSetting { focal_mm, f_number };
        assert!(
            calibrated.iter().all(|c| (c.focal_mm - focal_mm).abs() > 1.0
                && (c.f_number - f_number).abs() > 0.1),
            "{setting:?} is a calibration setting"
        );
        let truth = |x: f64, y: f64| {
            lens.gaussian_at(ch, x, y, w, h, setting)
                .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
        };
        let big = dead_leaves(w + 2 * pad, h + 2 * pad, seed);
        let sharp = big.crop(pad, pad, w, h);
        let mut blurry =
            render_varying(&big, pad, w, h, &|x, y| truth(x as f64, y as f64).kernel(1));
        add_noise(&mut blurry, 0.005, seed);
        let cp = ChannelPlane {
            channel: ch,
            plane: blurry.clone(),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        };
        let true_source = |_c: Channel, x: f64, y: f64| truth(x, y).kernel(1);
        let predicted = ProfileKernels::new(profile.clone(), setting);
        let x_true = deblur_channel_plane(&cp, w, h, &true_source, &hqs, &job).expect("deblur");
        let x_pred = deblur_channel_plane(&cp, w, h, &predicted, &hqs, &job).expect("deblur");
        let x_wiener =
            deblur_channel_plane(&cp, w, h, &true_source, &wiener, &job).expect("deblur");
        let centre = truth((w - 1) as f64 / 2.0, (h - 1) as f64 / 2.0).kernel(1);
        let x_inv = deblur_plane_invariant(&blurry, &centre, &hqs, &job).expect("deblur");
        let s = |x: &Plane| ssim(x, &sharp, &p);
        let (sb, st, sp, sw, si) = (s(&blurry), s(&x_true), s(&x_pred), s(&x_wiener), s(&x_inv));
        eprintln!(
            "{ch} at {focal_mm} mm f/{f_number}: SSIM blurry {sb:.4} | HQS true {st:.4} predicted {sp:.4} | Wiener true {sw:.4} | invariant {si:.4}"
        );
        let deblurs = VaryingDeblurs {
            channel: ch,
            sharp: &sharp,
            blurry: &blurry,
            predicted: &x_pred,
            invariant: &x_inv,
            ssim: [sb, st, sp, sw],
        };
        assert_predicted_kernels_hold(&deblurs, 96);
    }
}

#[test]
fn gaussian_approximation_experiment() {
    // Kernels measured on simulated chart shots of the (Gaussian-blurring) virtual lens,
    // estimated with W = I as the paper's (the command's default; 300 kernels there).
    let t0 = std::time::Instant::now();
    let kernels = measured_kernels(
        &MeasureOptions::new(30, PsfShape::Gaussian, 5),
        &JobContext::silent(),
    )
    .unwrap_or_else(|e| panic!("measuring kernels on simulated shots: {e}"))
    .kernels;
    eprintln!(
        "{} kernels measured in {:.1} s",
        kernels.len(),
        t0.elapsed().as_secs_f64()
    );
    let opts = ExperimentOptions {
        image_px: 128,
        ..ExperimentOptions::default()
    };
    let report = gaussian_approx(&kernels, &opts, &JobContext::silent()).expect("experiment");
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
    // "ML fits are worse": on the natural image, yes, in the tail (p99 1.014 against
    // 1.008) and kernel by kernel (17 of 30). On the synthetic image with this
    // Gaussian-blurring lens the two fits are equally good (p99 1.00132 ML against
    // 1.00137 robust; ML better on 22 of 30 kernels), so that half of the paper's
    // claim is not reproduced here and is not asserted; with comet-shaped kernels ML
    // is clearly worse on both images but the robust p99 on the natural one is 1.011.
    let rows: Vec<_> = report
        .rows
        .iter()
        .filter(|r| r.image == "natural")
        .collect();
    let ml_worse = rows.iter().filter(|r| r.ratio_ml > r.ratio_robust).count();
    eprintln!(
        "natural: ML worse than robust on {ml_worse} of {}",
        rows.len()
    );
    assert!(
        2 * ml_worse > rows.len(),
        "natural: ML worse on only {ml_worse} of {}",
        rows.len()
    );
    assert!(nat.ml_p99 > nat.robust_p99, "natural: ML p99 not worse");
}

#[test]
fn measuring_kernels_stops_fast_when_no_shot_yields_any() {
    // A chart of 2-pixel squares: no shot can yield a kernel. The run must give up
    // after a few shots with the reason, not shoot on.
    let opts = MeasureOptions {
        width: 96,
        height: 64,
        cols: 40,
        rows: 27,
        ..MeasureOptions::new(10, PsfShape::Gaussian, 1)
    };
    match measured_kernels(&opts, &JobContext::silent()) {
        Err(MeasureError::NoKernels { failed, last }) => {
            eprintln!("{failed} failed shots; the last: {last}");
            assert_eq!(failed, MAX_FAILED_SHOTS_IN_A_ROW);
            assert!(last.contains("shot 3"), "{last}");
        }
        Err(e) => panic!("expected NoKernels, got {e}"),
        Ok(m) => panic!(
            "expected NoKernels, got {} kernels ({} shots skipped)",
            m.kernels.len(),
            m.skipped_shots.len()
        ),
    }
}

// ---------------------------------------------------------------------------------
// The `deblur` command.

fn lensblur(args: &[&std::ffi::OsStr]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
        .args(args)
        .output()
        .expect("run lensblur")
}

/// A sharp RGB scene (a dead-leaves plane per channel) and its blur by the demo lens
/// at `setting`, `w × h`, with noise.
fn blurred_rgb(w: usize, h: usize, setting: LensSetting, seed: u64) -> (Vec<Plane>, Vec<Plane>) {
    let lens = VirtualLens::demo();
    let pad = 24;
    let mut sharp = Vec::new();
    let mut blurry = Vec::new();
    for (i, ch) in [Channel::R, Channel::G, Channel::B].into_iter().enumerate() {
        let big = dead_leaves(w + 2 * pad, h + 2 * pad, seed + i as u64);
        let mut b = render_varying(&big, pad, w, h, &|x, y| {
            lens.gaussian_at(ch, x as f64, y as f64, w, h, setting)
                .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
                .kernel(1)
        });
        add_noise(&mut b, 0.003, seed + 10 + i as u64);
        sharp.push(big.crop(pad, pad, w, h));
        blurry.push(b);
    }
    (sharp, blurry)
}

fn write_rgb16(path: &std::path::Path, planes: &[Plane]) {
    let (w, h) = (planes[0].width, planes[0].height);
    let data: Vec<u16> = (0..w * h)
        .flat_map(|i| {
            planes
                .iter()
                .map(move |p| (p.data[i].clamp(0.0, 1.0) * 65535.0).round() as u16)
        })
        .collect();
    image::ImageBuffer::<image::Rgb<u16>, _>::from_raw(w as u32, h as u32, data)
        .expect("buffer")
        .save(path)
        .expect("write png");
}

/// The R, G, B planes of a 16-bit output, checked to be 16-bit.
fn read_rgb16(path: &std::path::Path) -> Vec<Plane> {
    let img = image::open(path).expect("read output");
    assert!(
        matches!(img, image::DynamicImage::ImageRgb16(_)),
        "{}: not 16-bit RGB: {:?}",
        path.display(),
        img.color()
    );
    let rgb = img.to_rgb16();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    (0..3)
        .map(|c| {
            Plane::from_fn(w, h, |x, y| {
                f32::from(rgb.get_pixel(x as u32, y as u32)[c]) / 65535.0
            })
        })
        .collect()
}

fn os(s: &str) -> &std::ffi::OsStr {
    std::ffi::OsStr::new(s)
}

/// Gaussians, 3× kernels or both of the demo lens at `setting`, for every channel at
/// scattered (jittered-grid) sensor points, as a kernels file.
fn lens_kernels_file(w: usize, h: usize, setting: LensSetting, with: &str) -> KernelsFile {
    let lens = VirtualLens::demo();
    let oversample = if with == "gaussians" { 1 } else { 3 };
    let mut samples = Vec::new();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(4);
    for j in 0..5 {
        for i in 0..7 {
            use rand::Rng;
            let x = (i as f64 + rng.random_range(0.2..0.8)) * w as f64 / 7.0;
            let y = (j as f64 + rng.random_range(0.2..0.8)) * h as f64 / 5.0;
            for ch in [Channel::R, Channel::G, Channel::B] {
                let g = lens
                    .gaussian_at(ch, x, y, w, h, setting)
                    .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0);
                let kernel = (with != "gaussians").then(|| {
                    let k = g.kernel(3);
                    KernelData {
                        size: k.size,
                        data: k.data,
                    }
                });
                let gauss = with != "kernels";
                samples.push(KernelSample {
                    x,
                    y,
                    channel: ch,
                    cxx: gauss.then_some(g.sigma_x),
                    cyy: gauss.then_some(g.sigma_y),
                    cor: gauss.then_some(g.rho),
                    row: None,
                    col: None,
                    ml: None,
                    kernel,
                });
            }
        }
    }
    KernelsFile {
        schema: "lensblur.kernels/1".into(),
        width: w,
        height: h,
        focal_mm: Some(setting.focal_mm),
        f_number: Some(setting.f_number),
        focus_distance_m: None,
        oversample,
        identity: None,
        source: None,
        picture: None,
        samples,
        failed: Vec::new(),
    }
}

fn mean_ssim(a: &[Plane], b: &[Plane]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ssim(x, y, &SsimParams::default()))
        .sum::<f64>()
        / a.len() as f64
}

#[test]
fn deblur_command_on_linear_png_with_kernels_files_and_a_profile() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (w, h) = (192, 128);
    let setting = LensSetting {
        focal_mm: 40.0,
        f_number: 5.0,
    };
    let (sharp, blurry) = blurred_rgb(w, h, setting, 31);
    let photo = dir.path().join("photo.png");
    write_rgb16(&photo, &blurry);
    // What the 16-bit round trip leaves of the blurry photo.
    let before = mean_ssim(&read_rgb16(&photo), &sharp);
    let mut results = Vec::new();
    for with in ["gaussians", "kernels", "both"] {
        let kf = dir.path().join(format!("{with}.json"));
        std::fs::write(
            &kf,
            serde_json::to_vec(&lens_kernels_file(w, h, setting, with)).expect("json"),
        )
        .expect("write kernels");
        for ext in ["png", "tiff"] {
            let out = dir.path().join(format!("out-{with}.{ext}"));
            let o = lensblur(&[
                os("deblur"),
                photo.as_os_str(),
                os("--out"),
                out.as_os_str(),
                os("--kernels"),
                kf.as_os_str(),
            ]);
            assert!(
                o.status.success(),
                "{with} → {ext}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            let after = mean_ssim(&read_rgb16(&out), &sharp);
            results.push(format!("{with}/{ext} {after:.4}"));
            assert!(
                after > before + 0.05,
                "{with} → {ext}: SSIM {before} → {after}"
            );
        }
    }
    // A profile fitted on a simulated calibration set of this sensor size; the PNG has
    // no EXIF, so the settings come from the flags.
    let profile = dir.path().join("profile.json");
    fitted_profile(w, h).save(&profile).expect("save profile");
    let out = dir.path().join("out-profile.png");
    let o = lensblur(&[
        os("deblur"),
        photo.as_os_str(),
        os("--out"),
        out.as_os_str(),
        os("--profile"),
        profile.as_os_str(),
        os("--focal"),
        os("40"),
        os("--aperture"),
        os("5"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let after = mean_ssim(&read_rgb16(&out), &sharp);
    eprintln!(
        "SSIM blurry {before:.4}; {}; profile {after:.4}",
        results.join(", ")
    );
    assert!(after > before + 0.05, "profile: SSIM {before} → {after}");
}

#[test]
fn deblur_command_on_a_raw_photo_with_settings_from_exif() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (w, h) = (192, 128);
    let setting = LensSetting {
        focal_mm: 45.0,
        f_number: 6.3,
    };
    let (sharp, blurry) = blurred_rgb(w, h, setting, 41);
    let (black, white) = (512u16, 16383u16);
    let cfa: Vec<u16> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let v = blurry[rggb_channel(x, y)].get(x, y).clamp(0.0, 1.0);
            (f64::from(black) + f64::from(v) * f64::from(white - black)).round() as u16
        })
        .collect();
    let lens = VirtualLens::demo();
    let photo = dir.path().join("photo.dng");
    let info = DngInfo::simulated(
        &lens.make,
        &lens.model,
        black,
        white,
        Some(setting),
        lensblur::dng::DngLayout::default(),
    );
    write_dng(&photo, &cfa, w, h, &info).expect("write dng");
    let profile = dir.path().join("profile.json");
    fitted_profile(w, h).save(&profile).expect("save profile");
    let out = dir.path().join("out.tiff");
    // No --focal or --aperture: the DNG's EXIF says them.
    let o = lensblur(&[
        os("deblur"),
        photo.as_os_str(),
        os("--out"),
        out.as_os_str(),
        os("--profile"),
        profile.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let result = read_rgb16(&out);
    let preview = image::open(dir.path().join("out.preview.png")).expect("preview");
    assert_eq!(preview.color(), image::ColorType::Rgb8);
    assert_eq!((preview.width(), preview.height()), (w as u32, h as u32));
    // Deblurred on the CFA planes: each site of a colour against the sharp scene there.
    let sites = |p: &Plane, c: usize| {
        let (ox, oy) = [(0, 0), (1, 0), (1, 1)][c];
        Plane::from_fn(w / 2, h / 2, |i, j| p.get(2 * i + ox, 2 * j + oy))
    };
    for c in 0..3 {
        let truth = sites(&sharp[c], c);
        let before = ssim(&sites(&blurry[c], c), &truth, &SsimParams::default());
        let after = ssim(&sites(&result[c], c), &truth, &SsimParams::default());
        eprintln!("RAW channel {c}: SSIM at its CFA sites {before:.4} -> {after:.4}");
        assert!(after > before + 0.03, "channel {c}: {before} → {after}");
    }
}

/// Issue 36: a photo focused far from where the calibration shots were focused is
/// warned about in one line, the profile's focus range kept from its shots; one
/// focused among them is not.
#[test]
fn deblur_command_warns_when_the_photo_was_focused_far_from_the_shots() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (w, h) = (192, 128);
    let lens = VirtualLens::demo();
    // The shots at 1.5 and 3 m, as a chart on a wall is shot.
    let mut ds = SimulatedSession {
        seed: 17,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&lens, &calibration_settings());
    for (i, shot) in ds.shots.iter_mut().enumerate() {
        shot.focus_distance_m = FocusDistance::from_metres([1.5, 3.0][i % 2]);
    }
    let profile = crate::global_profile(&ds, 3, 2);
    let range = profile.focus_range.expect("a focus range");
    assert_eq!(
        (range.nearest_m.metres(), range.farthest_m.metres()),
        (1.5, 3.0)
    );
    let profile_path = dir.path().join("profile.json");
    profile.save(&profile_path).expect("save profile");
    let setting = LensSetting {
        focal_mm: 45.0,
        f_number: 6.3,
    };
    let (_, blurry) = blurred_rgb(w, h, setting, 43);
    let stderr_for = |name: &str, focus_m: f64| {
        let mut info = DngInfo::simulated(
            &lens.make,
            &lens.model,
            512,
            16383,
            Some(setting),
            lensblur::dng::DngLayout::default(),
        );
        info.focus_m = Some(focus_m);
        let photo = dir.path().join(format!("{name}.dng"));
        write_dng(&photo, &mosaic_of(&blurry, &info), w, h, &info).expect("write dng");
        let read = lensblur::raw::inspect(&photo).expect("inspect");
        assert_eq!(read.focus_distance_m, FocusDistance::from_metres(focus_m));
        let out = dir.path().join(format!("{name}.tiff"));
        let o = lensblur(&[
            os("deblur"),
            photo.as_os_str(),
            os("--out"),
            out.as_os_str(),
            os("--profile"),
            profile_path.as_os_str(),
        ]);
        let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{stderr}");
        stderr
    };
    let far = stderr_for("far", f64::INFINITY);
    let warned: Vec<&str> = far.lines().filter(|l| l.contains("focused at")).collect();
    assert_eq!(warned.len(), 1, "{far}");
    assert!(
        warned[0].starts_with("lensblur: warning: ")
            && warned[0].contains("focused at infinity")
            && warned[0].contains("(1.5 m–3 m)"),
        "{far}"
    );
    let among = stderr_for("among", 2.0);
    assert!(!among.contains("focused at"), "{among}");
}

/// A RAW photo as a camera writes it: a Bayer mosaic with per-site black levels, a
/// camera colour matrix, an as-shot white balance, a rotated orientation and the EXIF a
/// RAW editor reads.
fn camera_dng_info(setting: LensSetting) -> DngInfo {
    let lens = VirtualLens::demo();
    DngInfo {
        identity: CameraIdentity {
            make: Some(lens.make.clone()),
            model: Some(lens.model.clone()),
            body_serial: Some("0412345".into()),
            lens_model: Some(lens.model.clone()),
            lens_serial: Some("VZ-0001".into()),
        },
        setting: Some(setting),
        focus_m: None,
        raw: RawMeta {
            cfa: [0, 1, 1, 2],
            black: [512, 510, 511, 514],
            white: 16383,
            color_matrix: Some([
                [0.6847, -0.0614, -0.1014],
                [-0.4669, 1.2737, 0.2139],
                [-0.1197, 0.2488, 0.6846],
            ]),
            calibration_illuminant: 21,
            as_shot_neutral: Some([0.4713, 1.0, 0.6329]),
            orientation: 6,
            exposure_s: Some(1.0 / 250.0),
            iso: Some(400),
            date_time_original: Some("2026:11:25 10:30:00".into()),
            lens_make: Some("Virtual Optics".into()),
            description: None,
            focal_35mm: Some(75.0),
            lens_specification: Some([24.0, 105.0, 4.0, 4.0]),
        },
        exif_in_ifd0: false,
        original_file_name: None,
        layout: lensblur::dng::DngLayout::default(),
    }
}

/// The Bayer mosaic of a blurred RGB scene under `info`'s levels.
fn mosaic_of(planes: &[Plane], info: &DngInfo) -> Vec<u16> {
    let (w, h) = (planes[0].width, planes[0].height);
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let site = RawMeta::site(x, y);
            let black = f64::from(info.raw.black[site]);
            let v = planes[usize::from(info.raw.cfa[site])]
                .get(x, y)
                .clamp(0.0, 1.0);
            (black + f64::from(v) * (f64::from(info.raw.white) - black)).round() as u16
        })
        .collect()
}

#[test]
fn deblur_command_writes_a_raw_photo_back_as_a_dng_with_its_metadata() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (w, h) = (192, 128);
    let setting = LensSetting {
        focal_mm: 45.0,
        f_number: 6.3,
    };
    let (sharp, blurry) = blurred_rgb(w, h, setting, 43);
    let info = camera_dng_info(setting);
    let photo = dir.path().join("IMG_0001.dng");
    write_dng(&photo, &mosaic_of(&blurry, &info), w, h, &info).expect("write dng");
    let profile_path = dir.path().join("lens.profile.json");
    let profile = fitted_profile(w, h);
    profile.save(&profile_path).expect("save profile");
    let out = dir.path().join("IMG_0001.deblurred.dng");
    let o = lensblur(&[
        os("deblur"),
        photo.as_os_str(),
        os("--out"),
        out.as_os_str(),
        os("--profile"),
        profile_path.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let original = load_capture(&photo, &LoadOptions::default()).expect("original");
    let result = load_capture(&out, &LoadOptions::default()).expect("the written DNG");
    // Every field a RAW editor needs, as the original has it.
    assert_eq!((result.width, result.height), (w, h));
    assert!(result.is_raw);
    assert_eq!(result.identity, original.identity);
    assert_eq!(result.identity.lens_model, info.identity.lens_model);
    assert_eq!(result.setting_focal_mm, Some(45.0));
    assert_eq!(result.setting_f_number, Some(6.3));
    let (a, b) = (
        original.raw.clone().expect("original metadata"),
        result.raw.clone().expect("written metadata"),
    );
    assert_eq!(a.cfa, info.raw.cfa);
    assert_eq!(a.black, info.raw.black);
    for (got, want) in [(&b, &a), (&a, &info.raw)] {
        assert_eq!(got.cfa, want.cfa);
        assert_eq!(got.black, want.black);
        assert_eq!(got.white, want.white);
        assert_eq!(got.orientation, want.orientation);
        assert_eq!(got.calibration_illuminant, want.calibration_illuminant);
        assert_eq!(got.iso, want.iso);
        assert_eq!(got.date_time_original, want.date_time_original);
        assert_eq!(got.lens_make, want.lens_make);
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * y.abs().max(1.0);
        assert!(close(
            got.exposure_s.expect("exposure"),
            want.exposure_s.expect("exposure")
        ));
        // Matrix and neutral pass through the decoder's f32: equal to 10⁻⁶.
        let (gm, wm) = (
            got.color_matrix.expect("matrix"),
            want.color_matrix.expect("matrix"),
        );
        assert!(
            gm.iter()
                .flatten()
                .zip(wm.iter().flatten())
                .all(|(x, y)| close(*x, *y)),
            "{gm:?} vs {wm:?}"
        );
        let (gn, wn) = (
            got.as_shot_neutral.expect("neutral"),
            want.as_shot_neutral.expect("neutral"),
        );
        assert!(
            gn.iter().zip(&wn).all(|(x, y)| close(*x, *y)),
            "{gn:?} vs {wn:?}"
        );
    }
    let note = b.description.expect("a note of what was done");
    assert!(
        note.starts_with("Deblurred by lensblur") && note.contains("lens.profile.json"),
        "{note}"
    );

    // The planes read back are the ones written: the same deblurring in this process,
    // quantised as the writer does.
    // The profile as the command read it back from its file, and the setting as it
    // read it from the photo's EXIF: the same inputs, so the same pixels to the bit.
    let profile = Profile::load(&profile_path).expect("the profile file");
    let read = LensSetting {
        focal_mm: original.setting_focal_mm.expect("focal length in EXIF"),
        f_number: original.setting_f_number.expect("f-number in EXIF"),
    };
    let source = ProfileKernels::new(profile, read);
    let deblurred = lensblur::deblur::deblur_capture(
        &original,
        &source,
        &DeblurOptions::default(),
        &JobContext::silent(),
    )
    .expect("deblur");
    let written = lensblur::dng::mosaic(&deblurred).expect("mosaic");
    assert_eq!(lensblur::dng::mosaic(&result).expect("mosaic"), written);
    for (p, q) in result.planes.iter().zip(&original.planes) {
        assert_eq!(
            (p.channel, p.offset_x, p.offset_y),
            (q.channel, q.offset_x, q.offset_y)
        );
    }

    // Sharper against the simulator's truth at every colour's CFA sites.
    for (c, (ox, oy)) in [(0, (0, 0)), (1, (1, 0)), (2, (1, 1))] {
        let sites = |p: &Plane| Plane::from_fn(w / 2, h / 2, |i, j| p.get(2 * i + ox, 2 * j + oy));
        let plane = |cap: &lensblur::plane::Capture| {
            cap.planes
                .iter()
                .find(|p| (p.offset_x, p.offset_y) == (ox, oy))
                .expect("site plane")
                .plane
                .clone()
        };
        let truth = sites(&sharp[c]);
        let before = ssim(&plane(&original), &truth, &SsimParams::default());
        let after = ssim(&plane(&result), &truth, &SsimParams::default());
        eprintln!("DNG channel {c}: SSIM {before:.4} -> {after:.4}");
        assert!(after > before + 0.03, "channel {c}: {before} → {after}");
    }

    // The developed preview beside it, turned as the camera was held (orientation 6).
    let preview = image::open(dir.path().join("IMG_0001.deblurred.preview.png")).expect("preview");
    assert_eq!((preview.width(), preview.height()), (h as u32, w as u32));

    independent_readers_agree(&out, &written, w, h);
}

/// exiftool (Perl, its own TIFF parser) and dcraw (the reader LibRaw grew from) read
/// the DNG we wrote: its size, CFA, levels, colour tags and EXIF, and dcraw the very
/// samples. CI installs both; a machine without them fails here, not silently.
fn independent_readers_agree(dng: &std::path::Path, samples: &[u16], w: usize, h: usize) {
    let run = |cmd: &str, args: &[&str]| -> std::process::Output {
        std::process::Command::new(cmd)
            .args(args)
            .arg(dng)
            .output()
            .unwrap_or_else(|e| panic!("{cmd}: {e} (install exiftool and dcraw; .ci/run does)"))
    };
    let o = run("exiftool", &["-j", "-n", "-a", "-G1"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).expect("exiftool json");
    let tags = &json[0];
    let find = |name: &str| -> serde_json::Value {
        tags.as_object()
            .and_then(|m| m.iter().find(|(k, _)| k.ends_with(&format!(":{name}"))))
            .map(|(_, v)| v.clone())
            .unwrap_or(serde_json::Value::Null)
    };
    assert_eq!(find("ImageWidth"), serde_json::json!(w));
    assert_eq!(find("ImageHeight"), serde_json::json!(h));
    assert_eq!(find("CFAPattern2"), serde_json::json!("0 1 1 2"));
    assert_eq!(find("Make"), serde_json::json!(VirtualLens::demo().make));
    assert_eq!(
        find("LensModel"),
        serde_json::json!(VirtualLens::demo().model)
    );
    assert_eq!(find("FocalLength"), serde_json::json!(45));
    assert_eq!(find("FNumber"), serde_json::json!(6.3));
    assert_eq!(find("ExposureTime"), serde_json::json!(0.004));
    assert_eq!(find("ISO"), serde_json::json!(400));
    assert_eq!(
        find("DateTimeOriginal"),
        serde_json::json!("2026:11:25 10:30:00")
    );
    assert_eq!(find("Orientation"), serde_json::json!(6));
    assert_eq!(find("WhiteLevel"), serde_json::json!(16383));
    assert_eq!(find("BlackLevel"), serde_json::json!("512 510 511 514"));
    assert_eq!(find("AsShotNeutral"), serde_json::json!("0.4713 1 0.6329"));
    assert_eq!(find("DNGVersion"), serde_json::json!("1 4 0 0"));
    assert!(
        find("Description")
            .as_str()
            .is_some_and(|d| d.starts_with("Deblurred by lensblur")),
        "XMP dc:description: {:?}",
        find("Description")
    );
    // dcraw: identification, then the raw samples as a 16-bit PGM (document mode: no
    // scaling, no demosaicing, not turned).
    let o = run("dcraw", &["-i", "-v"]);
    let info = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "dcraw -i: {info}");
    let line = |key: &str| {
        info.lines()
            .find_map(|l| l.strip_prefix(key))
            .map(str::trim)
            .unwrap_or_default()
    };
    assert_eq!(line("Image size:"), format!("{w} x {h}"), "{info}");
    // Turned as the camera was held: orientation 6 swaps the output's sides.
    assert_eq!(line("Output size:"), format!("{h} x {w}"), "{info}");
    assert!(info.contains("Filter pattern: RG/GB"), "{info}");
    let o = run("dcraw", &["-D", "-4", "-t", "0", "-c"]);
    assert!(
        o.status.success(),
        "dcraw -D: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let pgm = o.stdout;
    let header = format!("P5\n{w} {h}\n65535\n");
    assert!(
        pgm.starts_with(header.as_bytes()),
        "dcraw's header: {:?}",
        &pgm[..20.min(pgm.len())]
    );
    let body = &pgm[header.len()..];
    let read: Vec<u16> = body
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    assert_eq!(read.len(), samples.len());
    let differ = read.iter().zip(samples).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "dcraw reads {differ} samples differently");
}

#[test]
fn deblur_command_refuses_bad_input_with_one_line_naming_the_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = |name: &str| dir.path().join(name);
    let (w, h) = (64, 48);
    let setting = LensSetting {
        focal_mm: 40.0,
        f_number: 5.0,
    };
    let (_, blurry) = blurred_rgb(w, h, setting, 51);
    write_rgb16(&d("photo.png"), &blurry);
    let photo_bytes = std::fs::read(d("photo.png")).expect("photo");
    std::fs::write(
        d("kernels.json"),
        serde_json::to_vec(&lens_kernels_file(w, h, setting, "gaussians")).expect("json"),
    )
    .expect("write");
    std::fs::write(
        d("other-size.json"),
        serde_json::to_vec(&lens_kernels_file(100, 100, setting, "gaussians")).expect("json"),
    )
    .expect("write");
    let mut bad_sample = lens_kernels_file(w, h, setting, "gaussians");
    bad_sample.samples[5].cxx = Some(-1.0);
    std::fs::write(
        d("bad-sample.json"),
        serde_json::to_vec(&bad_sample).expect("json"),
    )
    .expect("write");
    std::fs::write(d("bad-kernels.json"), b"{ not json").expect("write");
    std::fs::write(d("bad-profile.json"), b"{\"schema\": 3}").expect("write");
    std::fs::write(d("garbage.png"), b"\x89PNG\r\n\x1a\nnot really").expect("write");
    fitted_profile(w, h)
        .save(&d("profile.json"))
        .expect("save profile");

    let s = |p: &std::path::Path| p.to_str().expect("utf-8").to_owned();
    let (photo, out) = (s(&d("photo.png")), s(&d("out.png")));
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![s(&d("nope.png")), "--kernels".into(), s(&d("kernels.json"))],
            "nope.png",
        ),
        (
            vec![
                s(&d("garbage.png")),
                "--kernels".into(),
                s(&d("kernels.json")),
            ],
            "garbage.png",
        ),
        (
            vec![photo.clone(), "--kernels".into(), s(&d("bad-kernels.json"))],
            "bad-kernels.json",
        ),
        (
            vec![photo.clone(), "--kernels".into(), s(&d("missing.json"))],
            "missing.json",
        ),
        (
            vec![photo.clone(), "--kernels".into(), s(&d("other-size.json"))],
            "other-size.json",
        ),
        (
            vec![photo.clone(), "--kernels".into(), s(&d("bad-sample.json"))],
            "bad-sample.json",
        ),
        (
            vec![photo.clone(), "--profile".into(), s(&d("profile.json"))],
            "photo.png",
        ),
        (
            vec![photo.clone(), "--profile".into(), s(&d("bad-profile.json"))],
            "bad-profile.json",
        ),
        (
            vec![
                photo.clone(),
                "--profile".into(),
                s(&d("profile.json")),
                "--focal".into(),
                "300".into(),
                "--aperture".into(),
                "5".into(),
            ],
            "outside the calibrated range",
        ),
        (
            vec![
                photo.clone(),
                "--kernels".into(),
                s(&d("kernels.json")),
                "--method".into(),
                "fast".into(),
            ],
            "'--method <METHOD>' [possible values: hqs, irls, wiener]",
        ),
        (
            vec![
                photo.clone(),
                "--kernels".into(),
                s(&d("kernels.json")),
                "--focal=-3".into(),
            ],
            "--focal",
        ),
    ];
    let run = |args: &[String], out: &str| {
        let mut all: Vec<&std::ffi::OsStr> = vec![os("deblur"), os("--out"), os(out)];
        all.extend(args.iter().map(|a| os(a)));
        lensblur(&all)
    };
    let check = |o: &std::process::Output, needle: &str, out: &std::path::Path| {
        let err = String::from_utf8_lossy(&o.stderr);
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        eprintln!("{}", lines.join(" / "));
        assert!(!o.status.success(), "{needle}: exit 0");
        assert_eq!(lines.len(), 1, "{needle}: not one line: {err}");
        assert!(lines[0].contains(needle), "{needle}: {}", lines[0]);
        assert!(!out.exists(), "{needle}: {} written", out.display());
    };
    for (args, needle) in &cases {
        check(&run(args, &out), needle, &d("out.png"));
    }
    // Outputs that cannot be written are refused before the work.
    let kernels = vec![photo.clone(), "--kernels".into(), s(&d("kernels.json"))];
    for (target, needle) in [
        (d("out.jpg"), "out.jpg"),
        (d("no-such-folder").join("out.png"), "no-such-folder"),
    ] {
        check(&run(&kernels, &s(&target)), needle, &target);
    }
    let o = run(&kernels, &photo);
    assert!(!o.status.success(), "overwrote the photo");
    assert!(String::from_utf8_lossy(&o.stderr).contains("overwrite"));
    assert_eq!(std::fs::read(d("photo.png")).expect("photo"), photo_bytes);
    // Nothing else appeared beside the inputs (no temporary files left behind).
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("dir")
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "bad-kernels.json",
            "bad-profile.json",
            "bad-sample.json",
            "garbage.png",
            "kernels.json",
            "other-size.json",
            "photo.png",
            "profile.json"
        ]
    );
}

/// `spatially_varying_field_beats_blurry_and_invariant` at 10 MP (3872 × 2592), its bars
/// the same: the predicted field beats the blurry photo, Wiener with the true kernels
/// and, in every corner, the centre's kernel; it comes within 0.01 SSIM of the true
/// kernels.
#[test]
#[ignore = "10 MP figures, minutes: cargo test --test suite full_size_spatially_varying_figures -- --ignored --nocapture"]
fn full_size_spatially_varying_figures() {
    let lens = VirtualLens::demo();
    let (w, h, pad) = (3872, 2592, 32);
    let profile = fitted_profile(w, h);
    let job = JobContext::silent();
    let p = SsimParams::default();
    let cases = [
        (21, Channel::G, 31.0, 4.5),
        (22, Channel::R, 62.0, 7.1),
        (23, Channel::B, 88.0, 5.0),
    ];
    for (seed, ch, focal_mm, f_number) in cases {
        let setting = LensSetting { focal_mm, f_number };
        let truth = |x: f64, y: f64| {
            lens.gaussian_at(ch, x, y, w, h, setting)
                .convolved_variance(1.0 / 12.0, 1.0 / 12.0, 0.0)
        };
        let big = dead_leaves(w + 2 * pad, h + 2 * pad, seed);
        let sharp = big.crop(pad, pad, w, h);
        let mut blurry =
            lensblur::simulate::blur_varying(&big, pad, w, h, 8, &|x, y| truth(x, y).kernel(1));
        drop(big);
        add_noise(&mut blurry, 0.005, seed);
        let cp = ChannelPlane {
            channel: ch,
            plane: blurry.clone(),
            step: 1,
            offset_x: 0,
            offset_y: 0,
        };
        let true_source = |_c: Channel, x: f64, y: f64| truth(x, y).kernel(1);
        let predicted = ProfileKernels::new(profile.clone(), setting);
        let hqs = DeblurOptions::default();
        let wiener = DeblurOptions {
            method: Method::Wiener(WienerParams::default()),
            tile_step_px: None,
            ..DeblurOptions::default()
        };
        let t = std::time::Instant::now();
        let x_pred = deblur_channel_plane(&cp, w, h, &predicted, &hqs, &job).expect("deblur");
        let t_pred = t.elapsed().as_secs_f64();
        let x_true = deblur_channel_plane(&cp, w, h, &true_source, &hqs, &job).expect("deblur");
        let x_wiener =
            deblur_channel_plane(&cp, w, h, &true_source, &wiener, &job).expect("deblur");
        let centre = truth((w - 1) as f64 / 2.0, (h - 1) as f64 / 2.0).kernel(1);
        let x_inv = deblur_plane_invariant(&blurry, &centre, &hqs, &job).expect("deblur");
        let s = |x: &Plane| ssim(x, &sharp, &p);
        let (sb, st, sp, sw, si) = (s(&blurry), s(&x_true), s(&x_pred), s(&x_wiener), s(&x_inv));
        eprintln!(
            "{w} × {h} {ch} at {focal_mm} mm f/{f_number}: SSIM blurry {sb:.4} | HQS true {st:.4} predicted {sp:.4} ({t_pred:.1} s) | Wiener true {sw:.4} | invariant {si:.4}"
        );
        let deblurs = VaryingDeblurs {
            channel: ch,
            sharp: &sharp,
            blurry: &blurry,
            predicted: &x_pred,
            invariant: &x_inv,
            ssim: [sb, st, sp, sw],
        };
        assert_predicted_kernels_hold(&deblurs, 512);
    }
}

/// The aberrated lens calibrated on a 300 × 200 session of 8 × 6 boards at 3 × 3
/// settings, its kernels kept: a profile whose cross-validation chose a kernel-shape
/// model.
fn aberrated_profile_300x200() -> &'static Profile {
    static PROFILE: OnceLock<Profile> = OnceLock::new();
    PROFILE.get_or_init(|| {
        let lens = VirtualLens::aberrated();
        let ds = SimulatedSession {
            cols: 8,
            rows: 6,
            kernel_noise: Some(0.01),
            seed: 9,
            ..SimulatedSession::new(300, 200)
        }
        .dataset(&lens, &lens.setting_grid(3, 3));
        crate::global_profile(&ds, 4, 2)
    })
}

/// The aberrated lens (coma, astigmatism, spherical aberration through an imperfect
/// pupil) calibrated on a small session that kept its kernels: wide open, between the
/// calibrated settings, its predicted kernel shapes deblur better than its predicted
/// Gaussians, over the frame and in its corners. (Stopped down, where its PSFs are
/// close to Gaussian, the two are equal to about 1e-4 SSIM either way; that and how
/// close the shapes come to the true kernels are figures in the README:
/// `examples/kernel_shapes.rs`.)
#[test]
fn predicted_kernel_shapes_deblur_an_aberrated_lens_better_than_its_gaussians() {
    let lens = VirtualLens::aberrated();
    let (w, h) = (300, 200);
    let profile = aberrated_profile_300x200();
    assert!(
        profile.shape.is_some(),
        "cross-validation kept the Gaussians"
    );
    let job = JobContext::silent();
    let at = |focal_mm: f64, f_number: f64, ch: Channel, seed: u64| {
        lensblur::experiment::compare_kernel_models(
            profile,
            &lens,
            ch,
            LensSetting { focal_mm, f_number },
            (w, h),
            seed,
            0.005,
            &job,
        )
        .expect("deblurs")
    };
    let open = at(40.0, 4.5, Channel::G, 61);
    eprintln!("wide open {open:?}");
    assert!(open.shape > open.gaussian, "wide open: {open:?}");
    assert!(
        open.corners_shape > open.corners_gaussian,
        "wide-open corners: {open:?}"
    );
}

/// A lens with lateral colour (red magnified by 3e-3 against green, blue shrunk by as
/// much: about 0.6 px at this frame's corners), calibrated on a small session that kept
/// its kernels, deblurring a neutral scene between the calibrated settings, where every
/// colour at an edge is a fringe. Item by item against the sharp scene (the RMS of
/// R − G, B − G over the strongest 10 % of edges of each of five crops): wherever the
/// true kernels do not raise the colour error over the blurry photo's, the profile's
/// kernels do not either. Without the profile's place model (every kernel centred on
/// its pixel, as before it) the same deblur raises it, so the comparison can fail. The
/// same holds with the default fringe hold.
#[test]
fn deblurring_adds_no_colour_the_lens_did_not_make() {
    let mut lens = VirtualLens::demo();
    lens.geometry.lateral_colour = [6e-3, -6e-3];
    let (w, h) = (300, 200);
    let ds = SimulatedSession {
        cols: 8,
        rows: 6,
        kernel_noise: Some(0.01),
        seed: 11,
        ..SimulatedSession::new(w, h)
    }
    .dataset(&lens, &lens.setting_grid(3, 2));
    let opts = CalibrateOptions {
        families: Families::Global,
        alpha: Some(3),
        beta: Some(1),
        shape: None,
        ..CalibrateOptions::default()
    };
    let (profile, _) = calibrate(&ds, None, &opts, &JobContext::silent()).expect("calibrate");
    assert!(profile.place.is_some(), "the session kept its kernels");
    let pad = 24;
    let leaves = dead_leaves(w + 2 * pad, h + 2 * pad, 5);
    let neutral = [leaves.clone(), leaves.clone(), leaves];
    let setting = LensSetting {
        focal_mm: 45.0,
        f_number: 6.3,
    };
    let colour = |p: &Profile| {
        lensblur::experiment::compare_colour(
            p,
            &lens,
            setting,
            &neutral,
            pad,
            (w, h),
            3,
            0.002,
            &JobContext::silent(),
        )
        .expect("deblurs")
    };
    let show = |label: &str, c: &lensblur::experiment::CropColour| {
        let (a, h) = (c.alone.colour, c.held.colour);
        eprintln!(
            "{:<13} {label}: blurry {:.4} true {:.4} profile {:.4}; held: true {:.4} profile {:.4}",
            c.name, a[0], a[1], a[2], h[1], h[2]
        );
    };
    let crops = colour(&profile);
    for c in &crops {
        show("colour", c);
        // The deconvolution alone, and as a user gets it (the default fringe hold).
        for (what, v) in [("alone", c.alone.colour), ("held", c.held.colour)] {
            if v[1] <= v[0] {
                assert!(v[2] <= v[0], "{} {what}: {v:?}", c.name);
            }
        }
    }
    let centred = Profile {
        place: None,
        ..profile.clone()
    };
    let centred = colour(&centred);
    centred.iter().for_each(|c| show("centred", c));
    let raised = |score: fn(&lensblur::experiment::CropColour) -> [f64; 4]| {
        centred.iter().filter(|c| score(c)[2] > score(c)[0]).count()
    };
    assert!(
        raised(|c| c.alone.colour) > 0,
        "centred kernels raised no crop's colour error"
    );
    assert!(
        raised(|c| c.held.colour) > 0,
        "held, centred kernels raised no crop's colour error"
    );
}

/// A 3-colour capture of dead leaves blurred by a field of Gaussians that widen and
/// turn toward the corners, with the field as its kernel source.
fn gpu_test_photo(w: usize, h: usize) -> (lensblur::plane::Capture, impl KernelSource) {
    use lensblur::simulate::blur_varying;
    let field = move |x: f64, y: f64| {
        let (u, v) = (x / w as f64 - 0.5, y / h as f64 - 0.5);
        let r2 = u * u + v * v;
        Gaussian2 {
            sigma_x: 0.9 + 2.0 * r2 + 0.3 * u.abs(),
            sigma_y: 0.8 + 1.5 * r2,
            rho: 0.6 * u * v,
        }
        .kernel(1)
    };
    let pad = 16;
    let planes = [Channel::R, Channel::G, Channel::B]
        .into_iter()
        .enumerate()
        .map(|(i, channel)| {
            let sharp = dead_leaves(w + 2 * pad, h + 2 * pad, 40 + i as u64);
            let mut plane = blur_varying(&sharp, pad, w, h, 8, &field);
            add_noise(&mut plane, 0.002, 7 + i as u64);
            ChannelPlane {
                channel,
                plane,
                step: 1,
                offset_x: 0,
                offset_y: 0,
            }
        })
        .collect();
    let cap = lensblur::plane::Capture {
        width: w,
        height: h,
        planes,
        setting_focal_mm: None,
        setting_f_number: None,
        setting_focus_m: None,
        identity: CameraIdentity::default(),
        is_raw: false,
        raw: None,
    };
    (cap, move |_c: Channel, x: f64, y: f64| field(x, y))
}

/// The GPU path against the CPU path on the same photo and kernels, on whatever adapter
/// wgpu finds (CI: the software Vulkan). Both run the same tiles, kernels, taper and
/// steps and interpolate the same shrinkage table; the GPU in single precision, the
/// CPU in double. What is left is rounding, amplified where the solver sharpens
/// (measured on llvmpipe: max 5.5e-4, median 1.2e-7 of a [0, 1] image). Held, per
/// plane: SSIM between the two ≥ 0.9999; max |difference| below half an 8-bit level
/// (1/510), so an 8-bit rendering of the two differs by at most one level; median
/// ≤ 1e-5, so the agreement is everywhere, not on average. Four sources: kernels handed
/// over as taps (a field of kernels); Gaussians placed off centre, as lateral colour
/// places a channel's, and a profile's Gaussians, both of which the device makes from
/// six numbers a tile; and a profile's kernel-shape model, which the device makes from
/// its components and each tile's Gaussian and coefficients.
#[test]
fn gpu_deblur_matches_the_cpu_path() {
    use lensblur::deblur::gpu;
    use lensblur::model::KernelModel;
    let g = gpu::shared().expect("a GPU adapter (CI installs the software Vulkan)");
    eprintln!("adapter: {}", g.adapter());
    let (cap, source) = gpu_test_photo(200, 140);
    let taps = gpu_matches_cpu(&cap, &source, "kernel taps");
    let placed = gpu_matches_cpu(
        &cap,
        &PlacedField { w: 200.0, h: 140.0 },
        "placed Gaussians",
    );
    let (cap, _) = gpu_test_photo(384, 256);
    let setting = LensSetting {
        focal_mm: 31.0,
        f_number: 4.5,
    };
    let profile = profile_384x256().clone();
    let gaussians = ProfileKernels::with_model(profile, setting, KernelModel::Gaussian)
        .expect("the Gaussian model");
    let made = gpu_matches_cpu(&cap, &gaussians, "profile Gaussians");
    // What went up of the kernels: six numbers and the tile's entry (8 bytes) a tile,
    // where taps take their side² numbers.
    assert_eq!(made.1, 32 * made.2, "{made:?}");
    assert_eq!(placed.1, 32 * placed.2, "{placed:?}");
    assert!(taps.1 > 32 * taps.2, "{taps:?}");
    // A kernel-shape model's kernels, also made on the device: its components once, then
    // a tile's entry, fourteen numbers and its coefficients.
    let (cap, _) = gpu_test_photo(300, 200);
    let profile = aberrated_profile_300x200();
    let model = profile.shape.as_ref().expect("a kernel-shape model");
    let (k, values) = (model.len() as u64, model.space.values() as u64);
    eprintln!("shape model: {k} components, {} space", model.space.name());
    let shapes = ProfileKernels::with_model(
        profile.clone(),
        LensSetting {
            focal_mm: 40.0,
            f_number: 4.5,
        },
        KernelModel::Shape,
    )
    .expect("the shape model");
    let shaped = gpu_matches_cpu(&cap, &shapes, "profile shapes");
    assert_eq!(
        shaped.1,
        4 * k * values + (8 + 4 * (14 + k)) * shaped.2,
        "{shaped:?}"
    );
}

/// Gaussians that widen and turn toward the corners, red's and blue's moved outward
/// and inward (lateral colour), said as placed Gaussians.
struct PlacedField {
    w: f64,
    h: f64,
}

impl PlacedField {
    fn at(&self, channel: Channel, x: f64, y: f64) -> lensblur::deblur::PlacedGaussian {
        let (u, v) = (x / self.w - 0.5, y / self.h - 0.5);
        let r2 = u * u + v * v;
        let shift = match channel {
            Channel::R => 1.2,
            Channel::B => -1.2,
            _ => 0.0,
        };
        lensblur::deblur::PlacedGaussian {
            gaussian: Gaussian2 {
                sigma_x: 0.9 + 2.0 * r2,
                sigma_y: 0.8 + 1.5 * r2,
                rho: 0.6 * u * v,
            },
            mean: [shift * u, shift * v],
            oversample: 3,
        }
    }
}

impl KernelSource for PlacedField {
    fn kernel_at(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
    ) -> Result<Kernel, lensblur::deblur::SourceError> {
        let g = self.at(channel, x, y);
        Ok(g.gaussian.kernel_at(g.oversample, g.mean))
    }

    fn placed_gaussian(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
    ) -> Result<Option<lensblur::deblur::PlacedGaussian>, lensblur::deblur::SourceError> {
        Ok(Some(self.at(channel, x, y)))
    }
}

/// Deblurs `cap` on the CPU and on the GPU with HQS and Wiener, holds the two to the
/// bounds above, and returns the GPU's HQS upload: (all bytes, the kernels', tiles).
fn gpu_matches_cpu(
    cap: &lensblur::plane::Capture,
    source: &dyn KernelSource,
    what: &str,
) -> (u64, u64, u64) {
    use lensblur::deblur::{Device, deblur_capture};
    use lensblur::timings::Timings;
    let job = JobContext::silent();
    let mut upload = (0, 0, 0);
    for method in [Method::default(), Method::Wiener(WienerParams::default())] {
        let on = |device| DeblurOptions {
            method,
            device,
            ..DeblurOptions::default()
        };
        let cpu = deblur_capture(cap, source, &on(Device::Cpu), &job).expect("cpu");
        let timings = std::sync::Arc::new(Timings::new());
        let counted = job.with_timings(std::sync::Arc::clone(&timings));
        let gpu_out = deblur_capture(cap, source, &on(Device::Gpu), &counted).expect("gpu");
        if upload.2 == 0 {
            let (all, kernels) = timings.uploaded();
            upload = (all, kernels, timings.tiles());
            eprintln!(
                "{what}: uploaded {all} bytes, kernels {kernels}, {} tiles",
                upload.2
            );
        }
        for (a, b) in cpu.planes.iter().zip(&gpu_out.planes) {
            let s = ssim(&a.plane, &b.plane, &SsimParams::default());
            let mut diffs: Vec<f64> = a
                .plane
                .data
                .iter()
                .zip(&b.plane.data)
                .map(|(x, y)| f64::from((x - y).abs()))
                .collect();
            diffs.sort_by(f64::total_cmp);
            let max = diffs[diffs.len() - 1];
            let median = diffs[diffs.len() / 2];
            let name = method.name();
            eprintln!(
                "{what}, {name} {:?}: SSIM {s:.6}, max |diff| {max:.5}, median {median:.2e}",
                a.channel
            );
            assert!(s >= 0.9999, "{what}, {name}: SSIM {s}");
            assert!(max <= 1.0 / 510.0, "{what}, {name}: max difference {max}");
            assert!(median <= 1e-5, "{what}, {name}: median difference {median}");
        }
    }
    upload
}

/// Auto takes a hardware adapter only and otherwise is the CPU path, bit for bit; the
/// GPU asked for a method it lacks is an error in words, and Auto then uses the CPU.
#[test]
fn gpu_fallback_is_the_cpu_path() {
    use lensblur::deblur::{Device, deblur_capture, gpu};
    let (cap, source) = gpu_test_photo(160, 120);
    let job = JobContext::silent();
    let on = |method, device| DeblurOptions {
        method,
        device,
        ..DeblurOptions::default()
    };
    let cpu =
        deblur_capture(&cap, &source, &on(Method::default(), Device::Cpu), &job).expect("cpu");
    let hardware = gpu::shared().is_ok_and(|g| !g.adapter().software);
    if !hardware {
        let auto = deblur_capture(&cap, &source, &on(Method::default(), Device::Auto), &job)
            .expect("auto");
        assert!(
            cpu.planes
                .iter()
                .zip(&auto.planes)
                .all(|(a, b)| a.plane.data == b.plane.data),
            "auto without a hardware adapter must be the CPU path"
        );
        let said = gpu::describe(Device::Auto, &Method::default());
        assert!(said.starts_with("CPU ("), "{said}");
    }
    let irls = Method::Irls(IrlsParams {
        outer: 1,
        cg_iterations: 3,
        ..IrlsParams::default()
    });
    let err =
        deblur_capture(&cap, &source, &on(irls, Device::Gpu), &job).expect_err("IRLS on the GPU");
    assert_eq!(
        err.to_string(),
        "the GPU path has no IRLS: it runs on the CPU"
    );
    let auto = deblur_capture(&cap, &source, &on(irls, Device::Auto), &job).expect("auto");
    let cpu_irls = deblur_capture(&cap, &source, &on(irls, Device::Cpu), &job).expect("cpu");
    assert!(
        cpu_irls
            .planes
            .iter()
            .zip(&auto.planes)
            .all(|(a, b)| a.plane.data == b.plane.data)
    );
}

/// Every enumerated option's help lists the values it takes, as clap's possible
/// values (`-h` in one bracket, `--help` one per line with what each does), so a wrong
/// one is refused naming them, on one line.
#[test]
fn help_lists_every_enumerated_options_values() {
    for (command, values) in [
        ("deblur", "[possible values: hqs, irls, wiener]"),
        ("deblur", "[possible values: auto, gpu, cpu]"),
        ("deblur", "[possible values: auto, tiff, png, dng]"),
        ("predict", "[possible values: r, g, b, y]"),
        ("sharpness", "[possible values: r, g, b, y]"),
        ("chart", "[possible values:"),
        ("calibrate", "[possible values:"),
    ] {
        let o = lensblur(&[os(command), os("-h")]);
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{command} -h");
        assert!(help.contains(values), "{command} -h lacks {values}: {help}");
    }
    let o = lensblur(&[
        os("deblur"),
        os("p.dng"),
        os("--out"),
        os("o.tiff"),
        os("--device"),
        os("tpu"),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("'tpu'") && err.contains("auto, gpu, cpu"),
        "{err}"
    );
}
