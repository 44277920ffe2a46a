//! Colour kept where the photo had it: each deblurred pixel's chroma (R − G, B − G) is
//! held inside the range the blurry photo's chroma spans around it.
//!
//! Deconvolving R, G and B each with its own kernel rings a little differently in each
//! channel, and at a strong neutral edge those differences are colour the scene never
//! had: a fringe. Blur only averages, so the sharp scene's chroma near a pixel lies
//! within the extremes the blurry photo's chroma takes over a window as wide as the
//! blur; a true colour edge keeps its colours, a fringe the deconvolution invents is cut
//! back to what the photo showed. Luminance (G) is untouched, so the sharpening stays.

use crate::plane::Plane;

/// Half-width of the window, px: the blurs lensblur removes reach a few pixels, and a
/// window wider than the blur only loosens the bound.
pub const CHROMA_WINDOW_RADIUS: usize = 3;

/// Clamps `out`'s chroma, pixel by pixel, to the range `input`'s chroma takes within
/// `radius` px: R' = G' + clamp(R' − G', min(R − G), max(R − G)), and B' alike. Planes
/// of other sizes are left as they are.
pub fn clamp_chroma(input: [&Plane; 3], out: [&mut Plane; 3], radius: usize) {
    let (w, h) = (input[1].width, input[1].height);
    let same = |p: &Plane| p.width == w && p.height == h;
    if !(input.iter().all(|p| same(p)) && out.iter().all(|p| same(p))) {
        return;
    }
    let [r_out, g_out, b_out] = out;
    for (channel, plane_out) in [(input[0], r_out), (input[2], b_out)] {
        let chroma: Vec<f32> = channel
            .data
            .iter()
            .zip(&input[1].data)
            .map(|(c, g)| c - g)
            .collect();
        let (lo, hi) = window_extremes(&chroma, w, h, radius);
        for (i, v) in plane_out.data.iter_mut().enumerate() {
            let g = g_out.data[i];
            *v = g + (*v - g).clamp(lo[i], hi[i]);
        }
    }
}

/// The minimum and maximum of `data` (w × h) over a (2r + 1)² window at each pixel,
/// the window cut at the borders: separable, a row pass then a column pass.
fn window_extremes(data: &[f32], w: usize, h: usize, r: usize) -> (Vec<f32>, Vec<f32>) {
    let pass = |src: &[f32], along_rows: bool, pick: fn(f32, f32) -> f32| {
        let mut dst = vec![0.0f32; src.len()];
        let (n, lines) = if along_rows { (w, h) } else { (h, w) };
        let at = |line: usize, k: usize| {
            if along_rows {
                line * w + k
            } else {
                k * w + line
            }
        };
        for line in 0..lines {
            for k in 0..n {
                let (a, b) = (k.saturating_sub(r), (k + r).min(n - 1));
                dst[at(line, k)] = (a..=b)
                    .map(|j| src[at(line, j)])
                    .fold(src[at(line, k)], pick);
            }
        }
        dst
    };
    let lo = pass(&pass(data, true, f32::min), false, f32::min);
    let hi = pass(&pass(data, true, f32::max), false, f32::max);
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Plane {
        Plane {
            width: w,
            height: h,
            data: (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .collect(),
        }
    }

    #[test]
    fn a_fringe_on_a_neutral_edge_goes_and_a_colour_edge_stays() {
        let (w, h) = (24, 4);
        // Neutral blurry edge in; out, the same edge sharpened with a red overshoot.
        let grey = plane(w, h, |x, _| if x < 12 { 0.2 } else { 0.8 });
        let mut r = plane(w, h, |x, _| {
            if x == 12 {
                1.0
            } else if x < 12 {
                0.2
            } else {
                0.8
            }
        });
        let mut g = grey.clone();
        let mut b = grey.clone();
        clamp_chroma([&grey, &grey, &grey], [&mut r, &mut g, &mut b], 3);
        assert!(
            r.data
                .iter()
                .zip(&g.data)
                .all(|(r, g)| (r - g).abs() < 1e-6),
            "the fringe is gone"
        );

        // A red-to-blue edge keeps its colours, also where the output is sharper.
        let r_in = plane(w, h, |x, _| if x < 12 { 0.9 } else { 0.1 });
        let b_in = plane(w, h, |x, _| if x < 12 { 0.1 } else { 0.9 });
        let g_in = plane(w, h, |_, _| 0.3);
        let mut r2 = r_in.clone();
        let mut g2 = g_in.clone();
        let mut b2 = b_in.clone();
        clamp_chroma([&r_in, &g_in, &b_in], [&mut r2, &mut g2, &mut b2], 3);
        let same = |a: &Plane, b: &Plane| {
            a.data
                .iter()
                .zip(&b.data)
                .all(|(x, y)| (x - y).abs() < 1e-6)
        };
        assert!(
            same(&r2, &r_in) && same(&b2, &b_in),
            "a colour edge keeps its colours"
        );
    }

    #[test]
    fn extremes_cover_the_window_and_stop_at_the_borders() {
        let data: Vec<f32> = (0..20).map(|i| i as f32).collect();
        let (lo, hi) = window_extremes(&data, 5, 4, 1);
        // Pixel (2, 1) = 7 sees rows 0–2, columns 1–3: 1..=13.
        assert_eq!((lo[7], hi[7]), (1.0, 13.0));
        // The corner sees only its 2 × 2.
        assert_eq!((lo[0], hi[0]), (0.0, 6.0));
    }
}
