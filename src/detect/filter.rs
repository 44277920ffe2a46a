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

/// A sample type the filters run on: `f64` for accuracy, `f32` where a filter runs in
/// an inner loop (the alignment's template) and twice the SIMD lanes pay.
pub trait Sample:
    Copy + Default + std::ops::Mul<Output = Self> + std::ops::AddAssign + 'static
{
    fn from_f64(v: f64) -> Self;
}

impl Sample for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
}

impl Sample for f32 {
    #[allow(clippy::cast_possible_truncation)]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
}

/// Convolves a `w × h` buffer with a symmetric kernel along x then y; samples beyond
/// the border repeat the edge value.
#[must_use]
pub fn separable<T: Sample>(data: &[T], w: usize, h: usize, taps: &[f64]) -> Vec<T> {
    if w == 0 || h == 0 {
        return data.to_vec();
    }
    let taps: Vec<T> = taps.iter().map(|&t| T::from_f64(t)).collect();
    let r = taps.len() / 2;
    let mut tmp = vec![T::default(); w * h];
    // Each row padded by edge repetition, so the inner loops run without bounds logic
    // and vectorise (taps outside, pixels inside).
    let mut padded = vec![T::default(); w + 2 * r];
    for y in 0..h {
        let row = &data[y * w..(y + 1) * w];
        padded[r..r + w].copy_from_slice(row);
        let (first, last) = (row[0], row[w - 1]);
        padded[..r].fill(first);
        padded[r + w..].fill(last);
        let dst = &mut tmp[y * w..(y + 1) * w];
        for (k, &t) in taps.iter().enumerate() {
            for (d, &s) in dst.iter_mut().zip(&padded[k..k + w]) {
                *d += t * s;
            }
        }
    }
    let mut out = vec![T::default(); w * h];
    for y in 0..h {
        let dst = &mut out[y * w..(y + 1) * w];
        for (k, &t) in taps.iter().enumerate() {
            let yy = (y + k).saturating_sub(r).min(h - 1);
            let src = &tmp[yy * w..(yy + 1) * w];
            for (d, &s) in dst.iter_mut().zip(src) {
                *d += t * s;
            }
        }
    }
    out
}

/// Gaussian blur of a buffer (see [`separable`]).
#[must_use]
pub fn gaussian_blur<T: Sample>(data: &[T], w: usize, h: usize, sigma_px: f64) -> Vec<T> {
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
