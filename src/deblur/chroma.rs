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
use rayon::prelude::*;

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
    let (g_in, g_out): (&Plane, &Plane) = (input[1], g_out);
    for (channel, plane_out) in [(input[0], r_out), (input[2], b_out)] {
        // Bands of whole rows in parallel, each with the few rows around it it reads:
        // the window's extremes are made and used while they are in cache.
        plane_out
            .data
            .par_chunks_mut(BAND_ROWS * w)
            .enumerate()
            .for_each(|(band, rows_out)| {
                let y0 = band * BAND_ROWS;
                let y1 = y0 + rows_out.len() / w;
                let a = y0.saturating_sub(radius);
                let b = (y1 + radius).min(h);
                // Along each row first: the extremes of the chroma over ±radius columns.
                let (mut row_lo, mut row_hi) =
                    (vec![0.0f32; (b - a) * w], vec![0.0f32; (b - a) * w]);
                let mut chroma = vec![0.0f32; w];
                for (i, y) in (a..b).enumerate() {
                    let row = y * w..(y + 1) * w;
                    for ((c, &v), &g) in chroma
                        .iter_mut()
                        .zip(&channel.data[row.clone()])
                        .zip(&g_in.data[row])
                    {
                        *c = v - g;
                    }
                    let (lo, hi) = (
                        &mut row_lo[i * w..(i + 1) * w],
                        &mut row_hi[i * w..(i + 1) * w],
                    );
                    for x in 0..w {
                        let span = &chroma[x.saturating_sub(radius)..=(x + radius).min(w - 1)];
                        lo[x] = span.iter().copied().fold(f32::INFINITY, f32::min);
                        hi[x] = span.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                    }
                }
                // Then across ±radius rows, and the clamp.
                let (mut lo, mut hi) = (vec![0.0f32; w], vec![0.0f32; w]);
                for (y, out_row) in (y0..y1).zip(rows_out.chunks_exact_mut(w)) {
                    lo.fill(f32::INFINITY);
                    hi.fill(f32::NEG_INFINITY);
                    for yy in y.saturating_sub(radius)..=(y + radius).min(h - 1) {
                        let line = (yy - a) * w..(yy - a + 1) * w;
                        for ((l, u), (&rl, &rh)) in lo
                            .iter_mut()
                            .zip(hi.iter_mut())
                            .zip(row_lo[line.clone()].iter().zip(&row_hi[line]))
                        {
                            *l = l.min(rl);
                            *u = u.max(rh);
                        }
                    }
                    let g_row = &g_out.data[y * w..(y + 1) * w];
                    for (((v, &g), &l), &u) in out_row.iter_mut().zip(g_row).zip(&lo).zip(&hi) {
                        *v = g + (*v - g).clamp(l, u);
                    }
                }
            });
    }
}

/// Rows per band of work: enough to share the rows a band reads around it, few enough
/// that a band's extremes stay in cache.
const BAND_ROWS: usize = 32;

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
    fn each_pixel_is_held_to_its_own_window_across_bands() {
        // Taller than a band, so windows straddle band borders, and cut at every edge.
        let (w, h, r) = (23, 2 * BAND_ROWS + 7, 3);
        let field = |seed: usize| {
            plane(w, h, move |x, y| {
                (((x + w * y) * 7919 + seed) % 101) as f32 / 100.0
            })
        };
        let (r_in, g_in, b_in) = (field(1), field(2), field(3));
        let (mut r_out, mut g_out, mut b_out) = (field(4), field(5), field(6));
        let (r_before, b_before) = (r_out.clone(), b_out.clone());
        clamp_chroma(
            [&r_in, &g_in, &b_in],
            [&mut r_out, &mut g_out, &mut b_out],
            r,
        );
        assert_eq!(g_out.data, field(5).data, "green is untouched");
        for (input, before, after) in [(&r_in, &r_before, &r_out), (&b_in, &b_before, &b_out)] {
            for y in 0..h {
                for x in 0..w {
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    for v in y.saturating_sub(r)..=(y + r).min(h - 1) {
                        for u in x.saturating_sub(r)..=(x + r).min(w - 1) {
                            let c = input.get(u, v) - g_in.get(u, v);
                            (lo, hi) = (lo.min(c), hi.max(c));
                        }
                    }
                    let g = g_out.get(x, y);
                    let want = g + (before.get(x, y) - g).clamp(lo, hi);
                    assert_eq!(after.get(x, y), want, "at ({x}, {y})");
                }
            }
        }
    }
}
