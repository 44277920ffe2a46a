//! Test scenes for the simulator, the experiments and the benchmarks: a dead-leaves
//! image with natural-image statistics, a hard-edge synthetic one, an image seen
//! through a spatially varying PSF, and a camera-like raw mosaic.

use crate::plane::Plane;
use crate::psf::Kernel;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;

/// A `width × height` raw mosaic (row-major, 14-bit range above a black level of 512)
/// with a smooth scene and noise-like detail, so that lossless JPEG codes it at a
/// camera's rate rather than a flat field's: what the RAW decoding benchmarks decode.
#[must_use]
pub fn camera_like_mosaic(width: usize, height: usize) -> Vec<u16> {
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    (0..width * height)
        .map(|k| {
            // xorshift64: the detail only has to be incompressible, not random.
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let (x, y) = ((k % width) as f64, (k / width) as f64);
            let scene = 0.5 + 0.4 * (x / 700.0).sin() * (y / 500.0).cos();
            (512.0 + scene * 12000.0) as u16 + (state % 64) as u16
        })
        .collect()
}

/// A dead-leaves image: opaque discs of uniform random grey, radii drawn from a power
/// law p(r) ∝ r⁻³ (scale invariant, like natural images), 2 × 2 supersampled.
#[must_use]
pub fn dead_leaves(width: usize, height: usize, seed: u64) -> Plane {
    let mut rng = Pcg64::seed_from_u64(seed);
    let (r_min, r_max) = (1.0f64, width.max(height) as f64 / 4.0);
    let ss = 2usize;
    let (sw, sh) = (width * ss, height * ss);
    let mut fine = vec![f32::NAN; sw * sh];
    let mut unfilled = sw * sh;
    // Leaves fall front to back: a later leaf only shows where no earlier one lies.
    for _ in 0..200_000 {
        if unfilled == 0 {
            break;
        }
        let u: f64 = rng.random();
        // Inverse CDF of p(r) ∝ r⁻³ on [r_min, r_max].
        let inv = 1.0 / (r_min * r_min) - u * (1.0 / (r_min * r_min) - 1.0 / (r_max * r_max));
        let r = inv.powf(-0.5) * ss as f64;
        let cx = rng.random_range(-r..sw as f64 + r);
        let cy = rng.random_range(-r..sh as f64 + r);
        let grey: f32 = rng.random_range(0.05..0.95);
        let x0 = (cx - r).floor().max(0.0) as usize;
        let x1 = ((cx + r).ceil().max(0.0) as usize).min(sw);
        let y0 = (cy - r).floor().max(0.0) as usize;
        let y1 = ((cy + r).ceil().max(0.0) as usize).min(sh);
        for y in y0..y1 {
            for x in x0..x1 {
                let i = y * sw + x;
                if fine[i].is_nan()
                    && (x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2) <= r * r
                {
                    fine[i] = grey;
                    unfilled -= 1;
                }
            }
        }
    }
    downsample(&fine, width, height, ss, 0.5)
}

fn downsample(fine: &[f32], width: usize, height: usize, ss: usize, fill: f32) -> Plane {
    let sw = width * ss;
    Plane::from_fn(width, height, |x, y| {
        let mut acc = 0.0;
        for b in 0..ss {
            for a in 0..ss {
                let v = fine[(y * ss + b) * sw + x * ss + a];
                acc += if v.is_nan() { fill } else { v };
            }
        }
        acc / (ss * ss) as f32
    })
}

/// A synthetic hard-edge image: rotated rectangles and discs of flat grey on a flat
/// background, edges at every orientation, 4 × 4 supersampled.
#[must_use]
pub fn hard_edges(width: usize, height: usize, seed: u64) -> Plane {
    let mut rng = Pcg64::seed_from_u64(seed);
    let ss = 4usize;
    let (sw, sh) = (width * ss, height * ss);
    let mut fine = vec![0.3f32; sw * sh];
    let n = 6 + width * height / 2000;
    for s in 0..n {
        let grey: f32 = rng.random_range(0.05..0.95);
        let cx = rng.random_range(0.0..sw as f64);
        let cy = rng.random_range(0.0..sh as f64);
        let a = rng.random_range(4.0..width.min(height) as f64 / 4.0) * ss as f64;
        let b = rng.random_range(4.0..width.min(height) as f64 / 4.0) * ss as f64;
        let th: f64 = rng.random_range(0.0..std::f64::consts::PI);
        let (c, sn) = (th.cos(), th.sin());
        let disc = s % 3 == 2;
        for y in 0..sh {
            for x in 0..sw {
                let (dx, dy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                let inside = if disc {
                    dx * dx + dy * dy <= a * a / 4.0
                } else {
                    let (u, v) = (c * dx + sn * dy, -sn * dx + c * dy);
                    u.abs() <= a / 2.0 && v.abs() <= b / 2.0
                };
                if inside {
                    fine[y * sw + x] = grey;
                }
            }
        }
    }
    downsample(&fine, width, height, ss, 0.3)
}

/// A `w × h` image seen through a spatially varying PSF: output pixel (x, y) is
/// Σ k(q) · sharp((x, y) + pad − q), with `sharp` larger than the output by `pad` on
/// every side and the (1×, plane-resolution) kernel taken once per `block` × `block`
/// block, at its centre — a lens field varies far more slowly than that.
///
/// # Panics
/// If a kernel is wider than `pad` allows.
#[must_use]
pub fn blur_varying(
    sharp: &Plane,
    pad: usize,
    w: usize,
    h: usize,
    block: usize,
    kernel_at: &(dyn Fn(f64, f64) -> Kernel + Sync),
) -> Plane {
    let b = block.max(1);
    let bands: Vec<Vec<f32>> = (0..h.div_ceil(b))
        .into_par_iter()
        .map(|by| {
            let rows = b.min(h - by * b);
            let mut band = vec![0.0f32; rows * w];
            for bx in 0..w.div_ceil(b) {
                let cols = b.min(w - bx * b);
                let k = kernel_at(
                    (bx * b) as f64 + (cols as f64 - 1.0) / 2.0,
                    (by * b) as f64 + (rows as f64 - 1.0) / 2.0,
                );
                let c = k.size / 2;
                assert!(c <= pad, "kernel wider than the padding");
                for r in 0..rows {
                    for q in 0..cols {
                        let (x, y) = (bx * b + q, by * b + r);
                        let mut acc = 0.0;
                        for j in 0..k.size {
                            let row = &sharp.data[(y + pad + c - j) * sharp.width..];
                            for i in 0..k.size {
                                acc += k.at(i, j) * f64::from(row[x + pad + c - i]);
                            }
                        }
                        band[r * w + x] = acc as f32;
                    }
                }
            }
            band
        })
        .collect();
    Plane {
        width: w,
        height: h,
        data: bands.concat(),
    }
}
