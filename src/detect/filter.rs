//! Small separable filters on row-major `f64` buffers, shared by corner finding and
//! alignment.

/// A sampled Gaussian of standard deviation `sigma_px`, normalised to sum 1, radius
/// ⌈4σ⌉ (at least 1).
#[must_use]
pub fn gaussian_taps(sigma_px: f64) -> Vec<f64> {
    let sigma = sigma_px.max(1e-3);
    let r = (4.0 * sigma).ceil().max(1.0) as i64;
    let mut taps: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = taps.iter().sum();
    for t in &mut taps {
        *t /= s;
    }
    taps
}

/// Convolves a `w × h` buffer with a symmetric kernel along x then y; samples beyond
/// the border repeat the edge value.
#[must_use]
pub fn separable(data: &[f64], w: usize, h: usize, taps: &[f64]) -> Vec<f64> {
    let r = (taps.len() / 2) as i64;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        let row = &data[y * w..(y + 1) * w];
        for x in 0..w {
            let mut s = 0.0;
            for (k, t) in taps.iter().enumerate() {
                let xx = (x as i64 + k as i64 - r).clamp(0, w as i64 - 1) as usize;
                s += t * row[xx];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for (k, t) in taps.iter().enumerate() {
            let yy = (y as i64 + k as i64 - r).clamp(0, h as i64 - 1) as usize;
            let src = &tmp[yy * w..(yy + 1) * w];
            let dst = &mut out[y * w..(y + 1) * w];
            for (d, s) in dst.iter_mut().zip(src) {
                *d += t * s;
            }
        }
    }
    out
}

/// Gaussian blur of a buffer (see [`separable`]).
#[must_use]
pub fn gaussian_blur(data: &[f64], w: usize, h: usize, sigma_px: f64) -> Vec<f64> {
    separable(data, w, h, &gaussian_taps(sigma_px))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_mass_and_spreads_variance() {
        let (w, h) = (41, 41);
        let mut d = vec![0.0; w * h];
        d[20 * w + 20] = 1.0;
        let b = gaussian_blur(&d, w, h, 2.0);
        let s: f64 = b.iter().sum();
        assert!((s - 1.0).abs() < 1e-9);
        let var_x: f64 = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| b[y * w + x] * (x as f64 - 20.0).powi(2))
            .sum();
        assert!((var_x - 4.0).abs() < 0.01, "{var_x}");
    }
}
