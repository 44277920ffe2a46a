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
}

impl InputNoise {
    /// The three together.
    #[must_use]
    pub fn sigma(&self) -> f64 {
        (self.random.powi(2) + self.quantisation.powi(2) + self.blocks.powi(2)).sqrt()
    }

    /// How much weaker the data term is than the tuned one: (σ_ref/σ)², at most 1.
    #[must_use]
    pub fn data_weight(&self) -> f64 {
        let s = self.sigma();
        if s.is_finite() && s > TUNED_SIGMA {
            (TUNED_SIGMA / s).powi(2)
        } else {
            1.0
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

/// Estimates a capture's noise from its pixels. A RAW file's CFA planes are what the
/// methods are tuned on, and each samples the scene at every other pixel, so its finest
/// detail is the scene's as much as noise: a RAW capture keeps the tuned strength.
#[must_use]
pub fn estimate(cap: &Capture) -> InputNoise {
    if cap.is_raw {
        return InputNoise::default();
    }
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
    let developed = cap.picture_kind() == PictureKind::Developed;
    InputNoise {
        random: rms(&haar_mad_sigma),
        quantisation: if developed {
            rms(&srgb_quantisation_sigma)
        } else {
            0.0
        },
        blocks: rms(&block_sigma),
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
