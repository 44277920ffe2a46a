//! Image quality against a reference: SSIM (Wang, Bovik, Sheikh, Simoncelli 2004) and
//! PSNR.
//!
//! SSIM follows the common reference implementation exactly, so numbers compare with
//! published ones: a Gaussian window of σ = 1.5 truncated at 3.5σ (11 × 11), K1 = 0.01,
//! K2 = 0.03, population (not sample) covariances, reflected borders for the local
//! statistics, and the mean taken over the image less a 5-pixel border.

use crate::plane::{Plane, reflect};

/// SSIM parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimParams {
    pub sigma: f64,
    pub truncate: f64,
    pub k1: f64,
    pub k2: f64,
    /// Range of the pixel values (1 for images in [0, 1]).
    pub data_range: f64,
}

impl Default for SsimParams {
    fn default() -> Self {
        Self {
            sigma: 1.5,
            truncate: 3.5,
            k1: 0.01,
            k2: 0.03,
            data_range: 1.0,
        }
    }
}

fn gaussian_taps(sigma: f64, truncate: f64) -> Vec<f64> {
    let r = (truncate * sigma + 0.5) as isize;
    let mut t: Vec<f64> = (-r..=r)
        .map(|x| (-0.5 * (x * x) as f64 / (sigma * sigma)).exp())
        .collect();
    let s: f64 = t.iter().sum();
    for v in &mut t {
        *v /= s;
    }
    t
}

/// Separable filtering with reflected borders. Each output is Σ_k taps[k]·v_k summed in
/// tap order from zero; the borders are reflected once a row (horizontal pass) and the
/// rows of a tap added whole (vertical pass), so the inner loops run over contiguous
/// memory without an index computed per tap.
fn filter(data: &[f64], w: usize, h: usize, taps: &[f64]) -> Vec<f64> {
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let r = (taps.len() / 2) as isize;
    let mut tmp = vec![0.0; w * h];
    let mut padded = vec![0.0; w + taps.len() - 1];
    for (row, out) in data.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        for (i, p) in padded.iter_mut().enumerate() {
            *p = row[reflect(i as isize - r, w)];
        }
        for (x, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0;
            for (&t, &v) in taps.iter().zip(&padded[x..]) {
                acc += t * v;
            }
            *o = acc;
        }
    }
    let mut out = vec![0.0; w * h];
    for (y, out_row) in out.chunks_exact_mut(w).enumerate() {
        for (k, &t) in taps.iter().enumerate() {
            let src = reflect(y as isize + k as isize - r, h) * w;
            for (o, &v) in out_row.iter_mut().zip(&tmp[src..src + w]) {
                *o += t * v;
            }
        }
    }
    out
}

/// Mean SSIM of `a` against `b` (f64 slices of `w × h`).
///
/// # Panics
/// If the slices do not hold `w × h` values.
#[must_use]
pub fn ssim_f64(a: &[f64], b: &[f64], w: usize, h: usize, p: &SsimParams) -> f64 {
    assert!(a.len() == w * h && b.len() == w * h, "image sizes differ");
    let taps = gaussian_taps(p.sigma, p.truncate);
    let pad = taps.len() / 2;
    let prod = |f: &dyn Fn(usize) -> f64| -> Vec<f64> { (0..w * h).map(f).collect() };
    let ux = filter(a, w, h, &taps);
    let uy = filter(b, w, h, &taps);
    let uxx = filter(&prod(&|i| a[i] * a[i]), w, h, &taps);
    let uyy = filter(&prod(&|i| b[i] * b[i]), w, h, &taps);
    let uxy = filter(&prod(&|i| a[i] * b[i]), w, h, &taps);
    let c1 = (p.k1 * p.data_range).powi(2);
    let c2 = (p.k2 * p.data_range).powi(2);
    let (mut sum, mut n) = (0.0, 0usize);
    for y in pad..h.saturating_sub(pad) {
        for x in pad..w.saturating_sub(pad) {
            let i = y * w + x;
            let vx = uxx[i] - ux[i] * ux[i];
            let vy = uyy[i] - uy[i] * uy[i];
            let vxy = uxy[i] - ux[i] * uy[i];
            let s = ((2.0 * ux[i] * uy[i] + c1) * (2.0 * vxy + c2))
                / ((ux[i] * ux[i] + uy[i] * uy[i] + c1) * (vx + vy + c2));
            sum += s;
            n += 1;
        }
    }
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

/// Mean SSIM of two planes of equal size.
///
/// # Panics
/// If the sizes differ.
#[must_use]
pub fn ssim(a: &Plane, b: &Plane, p: &SsimParams) -> f64 {
    assert!(
        a.width == b.width && a.height == b.height,
        "image sizes differ"
    );
    let fa: Vec<f64> = a.data.iter().map(|&v| f64::from(v)).collect();
    let fb: Vec<f64> = b.data.iter().map(|&v| f64::from(v)).collect();
    ssim_f64(&fa, &fb, a.width, a.height, p)
}

/// Peak signal-to-noise ratio in dB for values of range `data_range`.
///
/// # Panics
/// If the sizes differ.
#[must_use]
pub fn psnr(a: &Plane, b: &Plane, data_range: f64) -> f64 {
    assert!(
        a.width == b.width && a.height == b.height,
        "image sizes differ"
    );
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
        .sum::<f64>()
        / a.data.len().max(1) as f64;
    10.0 * (data_range * data_range / mse).log10()
}

/// The deterministic test images shared with `scripts/ssim_reference.py`: integer
/// formulas both sides evaluate identically, scaled to [0, 1].
#[must_use]
pub fn reference_pair(index: usize, w: usize, h: usize) -> (Vec<f64>, Vec<f64>) {
    let a: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            ((x * 7 + y * 13 + (x * y) % 17) % 256) as f64 / 255.0
        })
        .collect();
    let b: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let base = (x * 7 + y * 13 + (x * y) % 17) % 256;
            let v = match index {
                0 => (base + (x * 3 + y * 5) % 11) % 256,
                1 => (base / 2 + 60 + (x ^ y) % 23) % 256,
                _ => (255 - base + (x * y) % 7) % 256,
            };
            v as f64 / 255.0
        })
        .collect();
    (a, b)
}

/// Colour error at edges: the RMS, over the strongest `fraction` of the truth's edges
/// (by the gradient of its green plane), of how far an RGB image's colour differences
/// (R − G, B − G) are from the truth's. A deblurred image that shifts or sharpens its
/// channels differently shows fringes there before anywhere else; on a neutral target
/// (the chart) the truth's differences are zero and this is the fringes themselves.
///
/// # Panics
/// If the planes' sizes differ.
#[must_use]
pub fn edge_colour_error(image: [&Plane; 3], truth: [&Plane; 3], fraction: f64) -> f64 {
    let g = truth[1];
    let (w, h) = (g.width, g.height);
    for p in image.iter().chain(truth.iter()) {
        assert!(p.width == w && p.height == h, "image sizes differ");
    }
    if w < 3 || h < 3 {
        return f64::NAN;
    }
    let mut grad: Vec<(f32, usize)> = Vec::with_capacity((w - 2) * (h - 2));
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let i = y * w + x;
            let gx = g.data[i + 1] - g.data[i - 1];
            let gy = g.data[i + w] - g.data[i - w];
            grad.push((gx * gx + gy * gy, i));
        }
    }
    let keep = ((grad.len() as f64 * fraction.clamp(0.0, 1.0)).round() as usize).max(1);
    grad.select_nth_unstable_by(keep - 1, |a, b| b.0.total_cmp(&a.0));
    let mut sum = 0.0;
    for &(_, i) in &grad[..keep] {
        let diff = |c: usize| {
            f64::from(image[c].data[i] - image[1].data[i])
                - f64::from(truth[c].data[i] - truth[1].data[i])
        };
        sum += diff(0).powi(2) + diff(2).powi(2);
    }
    (sum / (2 * keep) as f64).sqrt()
}

/// SSIM of a crop of a restored image after the sub-pixel translation that best
/// aligns it with the reference, and that translation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Registered {
    pub ssim: f64,
    /// The restored image is read at reference position + `shift_px`.
    pub shift_px: [f64; 2],
    /// The SSIM of the crop as it is, unmoved.
    pub unmoved: f64,
}

/// Mean SSIM of the channels of `image` against those of `reference` (planes of one
/// size) over the crop at `origin` of `size`, with every channel of `image` first moved
/// by the one translation within ±`max_shift_px` that scores best: a grid of 0.25 px,
/// then 0.05 px around its best. One move for all channels, so what moves the channels
/// against each other (a fringe) still counts.
///
/// A kernel measured from a chart is known only relative to where the chart's blurred
/// edges appear, so where a lens's PSF is lopsided (coma, flare), a deblur with measured
/// kernels leaves the image where the blurred photo shows it, a fraction of a pixel from
/// where one with the lens's exact kernels puts it. Deblurring benchmarks score after
/// this alignment for the same reason (Levin et al. 2009); both figures are reported.
///
/// # Panics
/// If the planes differ in size or number, there are none, or the crop does not lie
/// inside them.
#[must_use]
pub fn registered_ssim(
    image: &[&Plane],
    reference: &[&Plane],
    origin: (usize, usize),
    size: (usize, usize),
    max_shift_px: f64,
    p: &SsimParams,
) -> Registered {
    assert!(
        !image.is_empty()
            && image.len() == reference.len()
            && image
                .iter()
                .zip(reference)
                .all(|(a, b)| { a.width == b.width && a.height == b.height }),
        "image sizes differ"
    );
    let targets: Vec<Plane> = reference
        .iter()
        .map(|r| r.crop(origin.0, origin.1, size.0, size.1))
        .collect();
    let mean = |crop: &dyn Fn(&Plane) -> Plane| {
        image
            .iter()
            .zip(&targets)
            .map(|(a, t)| ssim(&crop(a), t, p))
            .sum::<f64>()
            / image.len() as f64
    };
    let score = |shift: [f64; 2]| mean(&|a: &Plane| a.shifted_crop(origin, size, shift));
    let search = |mut best: Registered, centre: [f64; 2], step: f64, reach: f64| {
        let n = (reach / step).round() as i32;
        for j in -n..=n {
            for i in -n..=n {
                let shift = [
                    centre[0] + f64::from(i) * step,
                    centre[1] + f64::from(j) * step,
                ];
                if shift[0].abs() > max_shift_px || shift[1].abs() > max_shift_px {
                    continue;
                }
                let v = score(shift);
                if v > best.ssim {
                    best = Registered {
                        ssim: v,
                        shift_px: shift,
                        ..best
                    };
                }
            }
        }
        best
    };
    let ssim_unmoved = mean(&|a: &Plane| a.crop(origin.0, origin.1, size.0, size.1));
    let unmoved = Registered {
        ssim: ssim_unmoved,
        shift_px: [0.0, 0.0],
        unmoved: ssim_unmoved,
    };
    let coarse = search(unmoved, [0.0, 0.0], 0.25, max_shift_px);
    search(coarse, coarse.shift_px, 0.05, 0.2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The filter against its definition, term by term: the same sums in the same
    /// order, so the same bits, on images narrower and shorter than the window too.
    #[test]
    fn filtering_is_its_definition() {
        let taps = gaussian_taps(1.5, 3.5);
        let r = (taps.len() / 2) as isize;
        for (w, h) in [(23usize, 17usize), (3, 2), (1, 12), (12, 1)] {
            let data: Vec<f64> = (0..w * h)
                .map(|i| ((i * 7919) % 101) as f64 / 100.0)
                .collect();
            let direct = |x: usize, y: usize| {
                let mut acc = 0.0;
                for (j, &tj) in taps.iter().enumerate() {
                    let yy = reflect(y as isize + j as isize - r, h);
                    let mut row = 0.0;
                    for (i, &ti) in taps.iter().enumerate() {
                        row += ti * data[yy * w + reflect(x as isize + i as isize - r, w)];
                    }
                    acc += tj * row;
                }
                acc
            };
            let fast = filter(&data, w, h, &taps);
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(
                        fast[y * w + x].to_bits(),
                        direct(x, y).to_bits(),
                        "{w}×{h} at ({x}, {y})"
                    );
                }
            }
        }
    }

    /// A band-limited pattern moved by a known sub-pixel amount is found where it was
    /// moved to, and scores as the unmoved pattern does once aligned.
    #[test]
    fn registration_finds_a_sub_pixel_move() {
        let pattern = |dx: f64, dy: f64| {
            Plane::from_fn(96, 80, |x, y| {
                let (x, y) = (x as f64 - dx, y as f64 - dy);
                let waves = [
                    (0.11, 0.03, 0.4),
                    (-0.05, 0.17, 1.3),
                    (0.23, 0.19, 2.2),
                    (0.07, -0.21, 0.7),
                ];
                let v: f64 = waves
                    .iter()
                    .map(|&(u, v, phase)| (std::f64::consts::TAU * (u * x + v * y) + phase).cos())
                    .sum();
                (0.5 + 0.1 * v) as f32
            })
        };
        let reference = pattern(0.0, 0.0);
        let moved = pattern(0.3, -0.45);
        let p = SsimParams::default();
        let (origin, size) = ((20, 16), (48, 40));
        let same = registered_ssim(&[&reference], &[&reference], origin, size, 1.0, &p);
        assert_eq!(same.shift_px, [0.0, 0.0]);
        assert!((same.ssim - 1.0).abs() < 1e-12, "{same:?}");
        let unaligned = ssim(
            &moved.crop(origin.0, origin.1, size.0, size.1),
            &reference.crop(origin.0, origin.1, size.0, size.1),
            &p,
        );
        let found = registered_ssim(&[&moved], &[&reference], origin, size, 1.0, &p);
        assert!((found.shift_px[0] - 0.3).abs() < 1e-9, "{found:?}");
        assert!((found.shift_px[1] + 0.45).abs() < 1e-9, "{found:?}");
        assert!(found.ssim > 0.9995, "{found:?}");
        assert!(unaligned < 0.99, "{unaligned}");
    }

    #[test]
    fn identical_images_have_ssim_one() {
        let (a, _) = reference_pair(0, 40, 30);
        assert!((ssim_f64(&a, &a, 40, 30, &SsimParams::default()) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn colour_error_at_edges_sees_a_shifted_channel_and_nothing_else() {
        let (w, h) = (40, 30);
        // A neutral step edge and a gentle ramp.
        let grey = |x: usize, y: usize| if x < 20 { 0.2 } else { 0.8 } + 0.001 * y as f32;
        let plane = |shift: usize| {
            let mut p = Plane::new(w, h);
            for y in 0..h {
                for x in 0..w {
                    p.data[y * w + x] = grey(x.saturating_sub(shift), y);
                }
            }
            p
        };
        let truth = [plane(0), plane(0), plane(0)];
        let t = [&truth[0], &truth[1], &truth[2]];
        assert_eq!(edge_colour_error(t, t, 0.1), 0.0);
        // The same colour change everywhere is not a fringe.
        let mut tinted = truth.clone();
        tinted[0].data.iter_mut().for_each(|v| *v += 0.05);
        let tinted_err = edge_colour_error([&tinted[0], &tinted[1], &tinted[2]], t, 0.1);
        assert!(
            (tinted_err - 0.05 / 2f64.sqrt()).abs() < 1e-6,
            "{tinted_err}"
        );
        // Red one pixel right of green and blue: a fringe along the edge.
        let fringed = [plane(1), plane(0), plane(0)];
        // (5 %: the edge's two columns, not the ramp.)
        let e = edge_colour_error([&fringed[0], &fringed[1], &fringed[2]], t, 0.05);
        assert!(e > 0.25, "{e}");
    }
}
