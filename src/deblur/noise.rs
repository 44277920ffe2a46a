//! How much of a photo is not the scene, measured on the photo itself, and how strongly
//! the deconvolution is held back for it.
//!
//! A deconvolver undoes the blur by amplifying the frequencies the blur weakened, and
//! everything else at those frequencies with them: sensor noise, the steps between an
//! 8-bit picture's levels, a JPEG's 8 × 8 blocks, a demosaicer's zipper. The data
//! weight λ the methods are tuned with is right for a clean linear photo; a MAP
//! estimate's data weight goes as 1/σ², so a photo whose error σ is above the tuned
//! level gets λ·(σ_ref/σ)² (Wiener's noise ratio the inverse), and a cleaner one keeps
//! the tuned λ (what lies below the tuned level is not trusted to be signal either).

use super::solve::Method;
use crate::plane::{Capture, PictureKind, Plane, srgb_decode, srgb_encode};

/// The error level the methods' default strengths are tuned for (linear units, white
/// 1): a clean linear photo's noise, as the simulator's test photos have (σ 0.003) with
/// room for an estimate's spread.
pub const TUNED_SIGMA: f64 = 0.005;

/// What a photo holds besides the scene, each part as a σ in linear units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct InputNoise {
    /// Random noise: the median absolute finest diagonal detail (Haar HH, which a blur
    /// leaves almost empty) over 0.6745, per plane, as the RMS of the planes.
    pub random: f64,
    /// An 8-bit picture's quantisation: the step between its levels in linear light
    /// (sRGB-decoded, so it grows with brightness) over √12, RMS over its samples; 0 for
    /// 16-bit pictures.
    pub quantisation: f64,
    /// Block artefacts of a compressed picture: how far differences across the borders
    /// of an 8-pixel grid exceed those inside it.
    pub blocks: f64,
    /// Measured on a RAW file's CFA planes: its data weight goes as σ_ref/σ (see
    /// [`InputNoise::data_weight`]).
    pub raw: bool,
}

impl InputNoise {
    /// The three together.
    #[must_use]
    pub fn sigma(&self) -> f64 {
        (self.random.powi(2) + self.quantisation.powi(2) + self.blocks.powi(2)).sqrt()
    }

    /// How much weaker the data term is than the tuned one, at most 1: (σ_ref/σ)² for
    /// a picture, σ_ref/σ for a RAW file. A RAW file's noise is white and its CFA
    /// planes carry the lens's whole blur, and there the square holds a noisy photo
    /// back too far: on a simulated RAW file with σ 0.032 (about ISO 6400), the
    /// deblurred planes' SSIM against the sharp scene peaks at a weight near 0.12
    /// (0.888, against 0.846 at the tuned strength), which σ_ref/σ = 0.16 is close to
    /// and the square, 0.024, far below (0.758, blurrier than the photo).
    #[must_use]
    pub fn data_weight(&self) -> f64 {
        let s = self.sigma();
        if !(s.is_finite() && s > TUNED_SIGMA) {
            return 1.0;
        }
        if self.raw {
            TUNED_SIGMA / s
        } else {
            (TUNED_SIGMA / s).powi(2)
        }
    }

    /// `method` with its regularisation raised for this noise (unchanged at or below
    /// the tuned level).
    #[must_use]
    pub fn regularised(&self, method: &Method) -> Method {
        let w = self.data_weight();
        match *method {
            Method::Hqs(mut p) => {
                p.lambda *= w;
                Method::Hqs(p)
            }
            Method::Irls(mut p) => {
                p.lambda *= w;
                Method::Irls(p)
            }
            Method::Wiener(mut p) => {
                p.nsr /= w;
                Method::Wiener(p)
            }
        }
    }
}

/// Samples of a plane looked at, at most: the estimates are medians and means, which
/// a few hundred thousand samples fix to well under a percent.
const MAX_SAMPLES: usize = 1 << 18;

/// Estimates a capture's noise from its pixels: for a RAW file, on each CFA plane with
/// a detail filter the scene's blur leaves empty even at every other pixel
/// ([`cfa_sigma`]); for any other picture, its finest Haar detail, its levels and its
/// blocks.
#[must_use]
pub fn estimate(cap: &Capture) -> InputNoise {
    let planes: Vec<&Plane> = cap
        .planes
        .iter()
        .map(|cp| &cp.plane)
        .filter(|p| p.width >= 16 && p.height >= 16)
        .collect();
    if planes.is_empty() {
        return InputNoise::default();
    }
    let rms = |f: &dyn Fn(&Plane) -> f64| {
        (planes.iter().map(|p| f(p).powi(2)).sum::<f64>() / planes.len() as f64).sqrt()
    };
    if cap.is_raw {
        // A RAW file's levels are a 12- or 14-bit sensor's and it was never cut into
        // blocks: its random noise is all it holds besides the scene.
        return InputNoise {
            random: rms(&cfa_sigma),
            raw: true,
            ..InputNoise::default()
        };
    }
    let developed = cap.picture_kind() == PictureKind::Developed;
    InputNoise {
        random: rms(&haar_mad_sigma),
        quantisation: if developed {
            rms(&srgb_quantisation_sigma)
        } else {
            0.0
        },
        blocks: rms(&block_sigma),
        raw: false,
    }
}

/// The median of `v` (reordered), 0 for none.
fn median(v: &mut [f32]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m)
}

/// Donoho's estimate: the finest diagonal Haar detail of iid noise σ has σ itself, and
/// its median absolute value is 0.6745 σ; edges, few and blurred, barely move a median.
fn haar_mad_sigma(p: &Plane) -> f64 {
    let (bw, bh) = (p.width / 2, p.height / 2);
    let stride = (bw * bh / MAX_SAMPLES).max(1);
    let mut hh: Vec<f32> = (0..bw * bh)
        .step_by(stride)
        .map(|b| {
            let (x, y) = (2 * (b % bw), 2 * (b / bw));
            let d = p.get(x, y) - p.get(x + 1, y) - p.get(x, y + 1) + p.get(x + 1, y + 1);
            (0.5 * d).abs()
        })
        .collect();
    median(&mut hh) / 0.6745
}

/// A CFA plane samples the scene at every other pixel, so its finest Haar detail is
/// the scene's as much as noise. The second difference across and along ([1 −2 1] ⊗
/// [1 −2 1], Immerkær's mask) cancels whatever is linear in x or in y and holds iid
/// noise σ at 6σ; it is read only where the plane is flattest (its Sobel gradient
/// among the lowest [`CFA_FLAT_SHARE`]), away from the edges a blurred scene still
/// has at this scale. The gradient's mask is odd and the detail's even, so on noise
/// alone the two are uncorrelated and choosing by one leaves the other's spread as it
/// was: the median absolute detail there over 0.6745 · 6 is σ.
fn cfa_sigma(p: &Plane) -> f64 {
    if p.width < 3 || p.height < 3 {
        return 0.0;
    }
    let (w, h) = (p.width - 2, p.height - 2);
    let stride = (w * h / MAX_SAMPLES).max(1);
    let mut pairs: Vec<(f32, f32)> = (0..w * h)
        .step_by(stride)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let v = |dx: usize, dy: usize| p.get(x + dx, y + dy);
            let across = |dy| v(0, dy) - 2.0 * v(1, dy) + v(2, dy);
            let detail = (across(0) - 2.0 * across(1) + across(2)).abs();
            let gx = v(2, 0) + 2.0 * v(2, 1) + v(2, 2) - v(0, 0) - 2.0 * v(0, 1) - v(0, 2);
            let gy = v(0, 2) + 2.0 * v(1, 2) + v(2, 2) - v(0, 0) - 2.0 * v(1, 0) - v(2, 0);
            (gx.abs() + gy.abs(), detail)
        })
        .collect();
    let keep = ((pairs.len() as f64 * CFA_FLAT_SHARE).ceil() as usize).clamp(1, pairs.len());
    pairs.select_nth_unstable_by(keep - 1, |a, b| a.0.total_cmp(&b.0));
    let mut detail: Vec<f32> = pairs[..keep].iter().map(|&(_, d)| d).collect();
    median(&mut detail) / (0.6745 * 6.0)
}

/// The share of a CFA plane's pixels, the flattest, whose detail [`cfa_sigma`] reads:
/// on a simulated clean RAW file of a dead-leaves scene (edges everywhere, each
/// channel its own) the estimate reads 0.0047 at 5 %, 0.0074 at 10 % and 0.025 over
/// every pixel for a true σ of 0.003; on a noisy one (σ 0.032) 0.031 at 5 %.
const CFA_FLAT_SHARE: f64 = 0.05;

/// The RMS over the plane's samples of the sRGB-decoded step at each one's level, over
/// √12 (a uniform rounding error's σ).
fn srgb_quantisation_sigma(p: &Plane) -> f64 {
    let stride = (p.data.len() / MAX_SAMPLES).max(1);
    let (mut sum, mut n) = (0.0f64, 0usize);
    for &v in p.data.iter().step_by(stride) {
        let code = (srgb_encode(v.clamp(0.0, 1.0)) * 255.0).round();
        let up = srgb_decode(((code + 1.0) / 255.0).min(1.0));
        let down = srgb_decode(((code - 1.0) / 255.0).max(0.0));
        let step = f64::from(up - down) / 2.0;
        sum += step * step;
        n += 1;
    }
    (sum / n.max(1) as f64 / 12.0).sqrt()
}

/// A JPEG's 8 × 8 blocks show as steps on the grid's borders: the median absolute
/// difference across them, less the median inside the blocks, as a σ (0 where the
/// borders are no different, as in any picture never cut into blocks).
fn block_sigma(p: &Plane) -> f64 {
    let (mut border, mut inside) = (Vec::new(), Vec::new());
    let rows = (p.height / 8).max(1);
    let row_stride = (p.width * p.height / MAX_SAMPLES).max(1);
    for y in (0..p.height).step_by(row_stride.min(rows)) {
        for x in 0..p.width - 1 {
            let d = (p.get(x + 1, y) - p.get(x, y)).abs();
            if x % 8 == 7 { &mut border } else { &mut inside }.push(d);
        }
    }
    for x in (0..p.width).step_by(row_stride.min((p.width / 8).max(1))) {
        for y in 0..p.height - 1 {
            let d = (p.get(x, y + 1) - p.get(x, y)).abs();
            if y % 8 == 7 { &mut border } else { &mut inside }.push(d);
        }
    }
    ((median(&mut border) - median(&mut inside)).max(0.0)) / 0.6745
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plane::{Channel, ChannelPlane};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn capture(planes: Vec<Plane>) -> Capture {
        let (w, h) = (planes[0].width, planes[0].height);
        let planes = planes
            .into_iter()
            .zip([Channel::R, Channel::G, Channel::B])
            .map(|(plane, channel)| ChannelPlane {
                plane,
                channel,
                step: 1,
                offset_x: 0,
                offset_y: 0,
            })
            .collect();
        Capture::of_planes(w, h, planes, false)
    }

    /// A smooth ramp (what a blurred photo mostly is) with Gaussian noise σ.
    fn noisy(w: usize, h: usize, sigma: f64, seed: u64) -> Plane {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let n = Normal::new(0.0, sigma).expect("σ ≥ 0");
        Plane::from_fn(w, h, |x, y| {
            0.2 + 0.5 * (x + y) as f32 / (w + h) as f32 + n.sample(&mut rng) as f32
        })
    }

    #[test]
    fn the_noise_of_a_linear_photo_is_found_and_left_at_the_tuned_strength() {
        for sigma in [0.002, 0.01, 0.03] {
            let cap = capture((0..3).map(|c| noisy(256, 192, sigma, c)).collect());
            let n = estimate(&cap);
            assert!(
                (n.random / sigma - 1.0).abs() < 0.05,
                "σ {sigma}: estimated {n:?}"
            );
            assert_eq!(n.quantisation, 0.0);
            assert!(n.blocks < 0.2 * sigma, "σ {sigma}: {n:?}");
        }
        let clean = estimate(&capture(
            (0..3).map(|c| noisy(256, 192, 0.003, c)).collect(),
        ));
        assert_eq!(clean.data_weight(), 1.0);
        let grainy = estimate(&capture((0..3).map(|c| noisy(256, 192, 0.02, c)).collect()));
        let w = grainy.data_weight();
        assert!((w - (TUNED_SIGMA / 0.02).powi(2)).abs() < 0.01, "{w}");
        let Method::Hqs(p) = grainy.regularised(&Method::default()) else {
            unreachable!()
        };
        assert!((p.lambda - 3000.0 * w).abs() < 1e-9);
    }

    /// A RAW capture's four CFA planes, each a smooth ramp with noise σ: the estimate
    /// finds σ, the levels and blocks of a picture it has none of left at 0.
    #[test]
    fn the_noise_of_a_raw_photo_is_found_on_its_cfa_planes() {
        for sigma in [0.002, 0.01, 0.03] {
            let planes = (0..4)
                .map(|c| ChannelPlane {
                    plane: noisy(256, 192, sigma, 10 + c),
                    channel: [Channel::R, Channel::G, Channel::G, Channel::B][c as usize],
                    step: 2,
                    offset_x: (c % 2) as usize,
                    offset_y: (c / 2) as usize,
                })
                .collect();
            let n = estimate(&Capture::of_planes(512, 384, planes, true));
            assert!(
                (n.random / sigma - 1.0).abs() < 0.08,
                "σ {sigma}: estimated {n:?}"
            );
            assert_eq!((n.quantisation, n.blocks), (0.0, 0.0));
            let expected = (TUNED_SIGMA / n.random).min(1.0);
            assert!((n.data_weight() - expected).abs() < 1e-12, "{n:?}");
        }
    }

    #[test]
    fn an_8_bit_picture_counts_its_levels_and_its_blocks() {
        // The same ramp as an 8-bit sRGB picture decodes, with steps on an 8-pixel grid.
        let eight_bit =
            |v: f32| srgb_decode((srgb_encode(v.clamp(0.0, 1.0)) * 255.0).round() / 255.0);
        let planes: Vec<Plane> = (0..3)
            .map(|c| {
                let p = noisy(256, 192, 0.0005, c);
                Plane::from_fn(256, 192, |x, y| {
                    let block = ((x / 8 * 7 + y / 8 * 13) % 5) as f32 * 0.01;
                    eight_bit(p.get(x, y) + block)
                })
            })
            .collect();
        let cap = capture(planes);
        assert_eq!(cap.picture_kind(), PictureKind::Developed);
        let n = estimate(&cap);
        // Levels 1/255 apart in sRGB are 0.002–0.009 apart in linear light here.
        assert!((0.0005..0.003).contains(&n.quantisation), "{n:?}");
        assert!(n.blocks > 0.003, "{n:?}");
        assert!(n.data_weight() < 1.0, "{n:?}");
    }
}
