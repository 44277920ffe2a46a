//! Sub-pixel alignment of one square (the paper's §2.2.1): the sharp
//! chart rasterised exactly through H, blurred by a Gaussian whose variance is
//! estimated jointly (registering a sharp template to a blurred square is unbiased
//! only when the template carries the blur), given each plane's black/white levels, and
//! registered to the observed pixels by Gauss–Newton on an 8-parameter projective
//! warp composed on the left of H, coarse to fine. RAW captures are registered on the
//! CFA planes themselves, each plane's pixels at their own sensor positions.

use super::DetectParams;
use super::filter::gaussian_blur;
use crate::chart::{ChartSpec, rasterize};
use crate::geometry::Homography;
use crate::plane::{Capture, Channel};
use nalgebra::{DMatrix, DVector, Matrix3};

/// What the refinement of one square gives.
#[derive(Clone, Debug)]
pub struct Aligned {
    pub image_from_chart: Homography,
    pub residual_rms: f64,
    pub black_level: f64,
    pub white_level: f64,
    /// Mean estimated Gaussian σ of the square's blur beyond the pixel area, sensor px.
    pub sigma_px: f64,
    /// The same per colour channel (the mean over its planes).
    pub sigma_by_channel: Vec<(Channel, f64)>,
    /// Each colour channel's own `image_from_chart` (the joint one translated and scaled), for
    /// a capture of several channels: lateral colour images the channels at slightly
    /// different magnifications, up to about a pixel apart in the corners. Empty
    /// unless [`DetectParams::channel_shifts`] asks the kernels to use them as they
    /// are; otherwise detection fills it per shot from the channels' shift fields
    /// ([`super::lateral`]).
    pub channel_image_from_chart: Vec<(Channel, Homography)>,
    /// The same registration, always made for a capture of several channels: what the
    /// lens's lateral colour is measured from (`correction`), whether or not the
    /// kernels use it.
    pub channel_registration: Vec<(Channel, Homography)>,
    /// Each colour channel's fitted black and white levels (the mean over its planes,
    /// normalised units): the white level across the frame is what the lens's fall-off
    /// is measured from.
    pub levels_by_channel: Vec<(Channel, [f64; 2])>,
}

#[derive(Clone, Copy)]
struct Sample {
    x: i64,
    y: i64,
    plane: usize,
    value: f64,
}

/// Integer sensor rectangle `[x0, x1] × [y0, y1]`.
#[derive(Clone, Copy)]
struct Rect {
    x0: i64,
    y0: i64,
    x1: i64,
    y1: i64,
}

fn quad_rect(h: &Homography, quad: &[[f64; 2]; 4]) -> Rect {
    let pts: Vec<[f64; 2]> = quad.iter().map(|p| h.apply(*p)).collect();
    let fx = |f: fn(f64, f64) -> f64, k: usize, init: f64| pts.iter().map(|p| p[k]).fold(init, f);
    Rect {
        x0: fx(f64::min, 0, f64::INFINITY).floor() as i64,
        y0: fx(f64::min, 1, f64::INFINITY).floor() as i64,
        x1: fx(f64::max, 0, f64::NEG_INFINITY).ceil() as i64,
        y1: fx(f64::max, 1, f64::NEG_INFINITY).ceil() as i64,
    }
}

/// Observed samples of every plane inside `rect`, after an extra Gaussian blur of
/// `extra_sigma_px` (sensor px) for the coarse levels, every `stride`-th plane pixel.
/// With `clip`, a clipped sample is left out: it bounds the edge from below and no
/// more. Only the fine level takes it: a coarse level's blur would mix each clipped
/// pixel into its neighbours (see [`align_square`]).
fn samples(
    capture: &Capture,
    rect: Rect,
    extra_sigma_px: f64,
    stride: usize,
    clip: Option<f64>,
) -> Vec<Sample> {
    debug_assert!(clip.is_none() || extra_sigma_px == 0.0);
    let mut out = Vec::new();
    for (k, cp) in capture.planes.iter().enumerate() {
        let step = cp.step as i64;
        let (ox, oy) = (cp.offset_x as i64, cp.offset_y as i64);
        let sigma_plane = extra_sigma_px / step as f64;
        let pad = if extra_sigma_px > 0.0 {
            (4.0 * sigma_plane).ceil() as i64 + 1
        } else {
            0
        };
        let i0 = ((rect.x0 - ox) as f64 / step as f64).ceil() as i64;
        let i1 = ((rect.x1 - ox) as f64 / step as f64).floor() as i64;
        let j0 = ((rect.y0 - oy) as f64 / step as f64).ceil() as i64;
        let j1 = ((rect.y1 - oy) as f64 / step as f64).floor() as i64;
        let (pw, ph) = (cp.plane.width as i64, cp.plane.height as i64);
        let ci0 = (i0 - pad).max(0);
        let ci1 = (i1 + pad).min(pw - 1);
        let cj0 = (j0 - pad).max(0);
        let cj1 = (j1 + pad).min(ph - 1);
        if ci1 < ci0 || cj1 < cj0 {
            continue;
        }
        let (cw, ch) = ((ci1 - ci0 + 1) as usize, (cj1 - cj0 + 1) as usize);
        let mut crop = Vec::with_capacity(cw * ch);
        for j in cj0..=cj1 {
            for i in ci0..=ci1 {
                crop.push(f64::from(cp.plane.get(i as usize, j as usize)));
            }
        }
        if extra_sigma_px > 0.0 {
            crop = gaussian_blur(&crop, cw, ch, sigma_plane);
        }
        let s = stride as i64;
        let mut j = j0.max(0);
        while j <= j1.min(ph - 1) {
            let mut i = i0.max(0);
            while i <= i1.min(pw - 1) {
                let v = crop[((j - cj0) as usize) * cw + (i - ci0) as usize];
                if clip.is_none_or(|level| v < level) {
                    out.push(Sample {
                        x: step * i + ox,
                        y: step * j + oy,
                        plane: k,
                        value: v,
                    });
                }
                i += s;
            }
            j += s;
        }
    }
    out
}

/// Half-width (px) of the band along a square's edges that [`align_square`] requires
/// mostly unclipped: the steepest part of a blurred edge, where its position and the
/// kernel's core show. Beyond it, on the black side, the edge's tails still measure the
/// kernel's; on the white side clipping takes only what the black sides of the other
/// edges also see.
const EDGE_BAND_PX: f64 = 1.5;

/// Distance, in chart squares, from a point of the unit square's frame (u, v) to the
/// nearest of the square's four edges, as segments.
fn edge_distance([u, v]: [f64; 2]) -> f64 {
    let along = |t: f64| (-t).max(t - 1.0).max(0.0);
    let to_line = |a: f64, b: f64| a.hypot(along(b));
    to_line(u.abs(), v)
        .min(to_line((u - 1.0).abs(), v))
        .min(to_line(v.abs(), u))
        .min(to_line((v - 1.0).abs(), u))
}

/// Black and white levels of a plane's square: the two histogram peaks.
fn histogram_peaks(values: &[f64]) -> Option<(f64, f64)> {
    if values.len() < 16 {
        return None;
    }
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if !(hi > lo) {
        return None;
    }
    const BINS: usize = 64;
    let mut hist = [0usize; BINS];
    for &v in values {
        let b = (((v - lo) / (hi - lo)) * BINS as f64).floor() as usize;
        hist[b.min(BINS - 1)] += 1;
    }
    // Split at the mean (the square is part black part white), take each side's mode.
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    let split = ((((mean - lo) / (hi - lo)) * BINS as f64) as usize).clamp(1, BINS - 1);
    let mode = |r: std::ops::Range<usize>| r.max_by_key(|&b| hist[b]).unwrap_or(0);
    let b_lo = mode(0..split);
    let b_hi = mode(split..BINS);
    let centre = |b: usize| lo + (b as f64 + 0.5) / BINS as f64 * (hi - lo);
    Some((centre(b_lo), centre(b_hi)))
}

#[derive(Clone)]
struct State {
    h: Homography,
    var: Vec<f64>,
    a: Vec<f64>,
    b: Vec<f64>,
}

struct Eval {
    cost: f64,
    jtj: DMatrix<f64>,
    jtr: DVector<f64>,
    /// Per plane, the normal equations of its own pixels over (8 warp parameters,
    /// variance, offset, gain): upper triangle of the `P × P` matrix, and the right side.
    per_plane: Vec<(Vec<f64>, [f64; P])>,
}

/// Parameters per plane in [`Eval::per_plane`].
const P: usize = 11;

/// Sum of squared residuals and the Gauss–Newton normal equations at `st`.
fn evaluate(
    spec: &ChartSpec,
    st: &State,
    smp: &[Sample],
    rect: Rect,
    extra_var: f64,
    centre: [f64; 2],
    scale: f64,
) -> Eval {
    let np = st.var.len();
    let n = 8 + 3 * np;
    let max_sigma = st
        .var
        .iter()
        .fold(0.0f64, |m, &v| m.max((v + extra_var).sqrt()));
    let pad = (4.0 * max_sigma).ceil() as i64 + 3;
    let (rx0, ry0) = (rect.x0 - pad, rect.y0 - pad);
    let rw = (rect.x1 - rect.x0 + 1 + 2 * pad) as usize;
    let rh = (rect.y1 - rect.y0 + 1 + 2 * pad) as usize;
    let local = Homography::translation(-(rx0 as f64), -(ry0 as f64)).compose(&st.h);
    let sharp = rasterize(spec, &local, rw, rh, 1.0).data;
    let mut templ: Vec<Option<Vec<f32>>> = vec![None; np];
    for s in smp {
        if templ[s.plane].is_none() {
            let sigma = (st.var[s.plane] + extra_var).max(1e-4).sqrt();
            templ[s.plane] = Some(gaussian_blur(&sharp, rw, rh, sigma));
        }
    }
    // Per plane: the 11 × 11 normal equations of (8 warp parameters, variance, offset,
    // gain), upper triangle only, in fixed-size arrays; scattered once at the end.
    let mut acc_jtj = vec![[0.0f64; P * P]; np];
    let mut acc_jtr = vec![[0.0f64; P]; np];
    let mut cost = 0.0;
    let mut j = [0.0f64; P];
    for s in smp {
        let Some(t) = templ[s.plane].as_ref() else {
            continue;
        };
        let (xi, yi) = ((s.x - rx0) as usize, (s.y - ry0) as usize);
        let c = yi * rw + xi;
        let t0 = f64::from(t[c]);
        let (l, r_, u_, d_) = (
            f64::from(t[c - 1]),
            f64::from(t[c + 1]),
            f64::from(t[c - rw]),
            f64::from(t[c + rw]),
        );
        let tx = 0.5 * (r_ - l);
        let ty = 0.5 * (d_ - u_);
        let lap = r_ + l + d_ + u_ - 4.0 * t0;
        let k = s.plane;
        let (a, b) = (st.a[k], st.b[k]);
        let r = s.value - (a + b * t0);
        cost += r * r;
        let (u, v) = (
            (s.x as f64 - centre[0]) / scale,
            (s.y as f64 - centre[1]) / scale,
        );
        let k_jtr = &mut acc_jtr[k];
        if tx == 0.0 && ty == 0.0 && lap == 0.0 {
            // Beyond the blur's reach of every edge the template is exactly flat: only
            // the offset and gain see this pixel.
            let m = &mut acc_jtj[k];
            k_jtr[9] += r;
            k_jtr[10] += t0 * r;
            m[9 * P + 9] += 1.0;
            m[9 * P + 10] += t0;
            m[10 * P + 10] += t0 * t0;
            continue;
        }
        // Moving the template by d (image px) changes it by −∇T·d.
        let gx = -b * tx * scale;
        let gy = -b * ty * scale;
        j = [
            gx * u,
            gx * v,
            gx,
            gy * u,
            gy * v,
            gy,
            -(gx * u * u + gy * u * v),
            -(gx * u * v + gy * v * v),
            0.5 * b * lap,
            1.0,
            t0,
        ];
        let m = &mut acc_jtj[k];
        for p in 0..P {
            let jp = j[p];
            k_jtr[p] += jp * r;
            for q in p..P {
                m[p * P + q] += jp * j[q];
            }
        }
    }
    let _ = j;
    let mut jtj = DMatrix::<f64>::zeros(n, n);
    let mut jtr = DVector::<f64>::zeros(n);
    let slot = |k: usize, m: usize| if m < 8 { m } else { 8 + 3 * k + (m - 8) };
    for k in 0..np {
        for p in 0..P {
            jtr[slot(k, p)] += acc_jtr[k][p];
            for q in p..P {
                let v = acc_jtj[k][p * P + q];
                let (sp, sq) = (slot(k, p), slot(k, q));
                jtj[(sp, sq)] += v;
                if sp != sq {
                    jtj[(sq, sp)] += v;
                }
            }
        }
    }
    Eval {
        cost,
        jtj,
        jtr,
        per_plane: acc_jtj
            .into_iter()
            .map(|m| m.to_vec())
            .zip(acc_jtr)
            .collect(),
    }
}

/// Weight of a held corner (see [`held_corners`]) per px² of its distance from the
/// bootstrap, in units of the square's squared contrast: a unit-contrast edge a pixel
/// long informs its position some 0.3 px⁻² at σ = 1 px, so a held corner weighs as
/// much as some thirty pixels of edge and moves by hundredths of a pixel under
/// whatever pulls at it.
const HOLD_WEIGHT: f64 = 10.0;

/// The corners of square (col, row) that no edge in its window places: a corner of the
/// board's outline whose square is white. Both its edges run between the square's
/// white and the white margin, and the print shows nothing there; the registration
/// would move it freely with whatever the margin holds (the paper's shading, the
/// board's outline bent by the lens against the neighbours' short stubs of edge), and
/// on real photos it moved by more than the shift allowed. Such a corner is held where
/// the lattice puts it.
fn held_corners(spec: &ChartSpec, col: usize, row: usize) -> Vec<[f64; 2]> {
    if spec.is_black(col, row) {
        return Vec::new();
    }
    let (cols, rows) = (spec.cols as f64, spec.rows as f64);
    spec.square_corners(col, row)
        .into_iter()
        .filter(|c| (c[0] == 0.0 || c[0] == cols) && (c[1] == 0.0 || c[1] == rows))
        .collect()
}

/// Adds to `ev` the cost of the `held` chart corners' distance under `h` from their
/// bootstrap positions, weighted by `weight`, with its Gauss–Newton terms over the 8
/// warp parameters (the warp's own Jacobian at each corner, as in [`evaluate`]).
fn hold_corners(
    ev: &mut Eval,
    h: &Homography,
    bootstrap: &Homography,
    held: &[[f64; 2]],
    weight: f64,
    centre: [f64; 2],
    scale: f64,
) {
    for c in held {
        let (p, target) = (h.apply(*c), bootstrap.apply(*c));
        let (u, v) = ((p[0] - centre[0]) / scale, (p[1] - centre[1]) / scale);
        let jx = [u, v, 1.0, 0.0, 0.0, 0.0, -u * u, -u * v].map(|d| d * scale);
        let jy = [0.0, 0.0, 0.0, u, v, 1.0, -u * v, -v * v].map(|d| d * scale);
        let (rx, ry) = (target[0] - p[0], target[1] - p[1]);
        ev.cost += weight * (rx * rx + ry * ry);
        for a in 0..8 {
            ev.jtr[a] += weight * (jx[a] * rx + jy[a] * ry);
            for b in 0..8 {
                ev.jtj[(a, b)] += weight * (jx[a] * jx[b] + jy[a] * jy[b]);
            }
        }
    }
}

fn apply_step(st: &State, d: &DVector<f64>, centre: [f64; 2], scale: f64) -> State {
    let w = Matrix3::new(
        1.0 + d[0],
        d[1],
        d[2],
        d[3],
        1.0 + d[4],
        d[5],
        d[6],
        d[7],
        1.0,
    );
    let norm = Homography::scaling(1.0 / scale, 1.0 / scale)
        .compose(&Homography::translation(-centre[0], -centre[1]));
    let norm_inv =
        Homography::translation(centre[0], centre[1]).compose(&Homography::scaling(scale, scale));
    let h = norm_inv
        .compose(&Homography(w))
        .compose(&norm)
        .compose(&st.h);
    let np = st.var.len();
    State {
        h,
        var: (0..np)
            // The blur is the one strongly nonlinear parameter: a step may at most halve
            // or double it, or a first step from a poor guess overshoots to nothing.
            .map(|k| {
                (st.var[k] + d[8 + 3 * k])
                    .clamp(0.5 * st.var[k], 2.0 * st.var[k])
                    .clamp(0.01, 64.0)
            })
            .collect(),
        a: (0..np).map(|k| st.a[k] + d[9 + 3 * k]).collect(),
        b: (0..np).map(|k| st.b[k] + d[10 + 3 * k]).collect(),
    }
}

fn max_corner_shift(h1: &Homography, h2: &Homography, quad: &[[f64; 2]; 4]) -> f64 {
    quad.iter()
        .map(|p| {
            let (a, b) = (h1.apply(*p), h2.apply(*p));
            (a[0] - b[0]).hypot(a[1] - b[1])
        })
        .fold(0.0, f64::max)
}

/// Refines `bootstrap` for square (col, row).
///
/// # Errors
/// A one-line reason when the square cannot be aligned: out of frame, saturated, too
/// dark, or the registration did not converge.
pub fn align_square(
    capture: &Capture,
    spec: &ChartSpec,
    col: usize,
    row: usize,
    bootstrap: &Homography,
    levels: usize,
    params: &DetectParams,
) -> Result<Aligned, String> {
    let quad = spec.square_corners(col, row);
    let img = quad.map(|p| bootstrap.apply(p));
    let side_px = ((img[0][0] - img[1][0]).hypot(img[0][1] - img[1][1])
        + (img[1][0] - img[2][0]).hypot(img[1][1] - img[2][1]))
        / 2.0;
    if !(side_px.is_finite() && side_px > 4.0) {
        return Err("degenerate square".into());
    }
    let m = (params.margin_px / side_px).min(0.4);
    let outer = [
        [quad[0][0] - m, quad[0][1] - m],
        [quad[1][0] + m, quad[1][1] - m],
        [quad[2][0] + m, quad[2][1] + m],
        [quad[3][0] - m, quad[3][1] + m],
    ];
    let rect = quad_rect(bootstrap, &outer);
    // The template needs room for its blur and the one-pixel stencils.
    if rect.x0 < 1
        || rect.y0 < 1
        || rect.x1 >= capture.width as i64 - 1
        || rect.y1 >= capture.height as i64 - 1
    {
        return Err("partly out of frame".into());
    }
    let Levels {
        a,
        b,
        black_sum,
        white_sum,
        window_clips,
    } = square_levels(capture, bootstrap, &quad, col, row, m, side_px, params)?;
    // A coarse level blurs the pixels before it samples them, which spreads each
    // clipped pixel over the blur's reach: leaving out every sample it touches leaves
    // none near the edges of a clipped white, keeping them biases the edges. A coarse
    // level with its edges masked away constrains nothing, and Gauss–Newton then walks
    // where rounding takes it: a square kept or lost by chance, differently in the same
    // photo turned. Where the window clips, the fine level alone registers the square,
    // every pixel the same whichever way the shot is turned.
    let levels = if window_clips { 1 } else { levels };
    let np = capture.planes.len();
    let centre = bootstrap.apply([col as f64 + 0.5, row as f64 + 0.5]);
    let scale = side_px / 2.0;
    let st = State {
        h: *bootstrap,
        var: vec![params.initial_sigma_px.powi(2); np],
        a,
        b,
    };
    let held = held_corners(spec, col, row);
    let contrast2 = st.b.iter().map(|b| b * b).sum::<f64>() / np as f64;
    let hold = |ev: &mut Eval, h: &Homography| {
        hold_corners(
            ev,
            h,
            bootstrap,
            &held,
            HOLD_WEIGHT * contrast2,
            centre,
            scale,
        );
    };
    let (st, cost, n, final_eval) = register(
        capture, spec, &quad, st, rect, levels, centre, scale, &hold, params,
    )?;
    // The fitted gain is free in sign: a square registered against a chart whose
    // colours are swapped there (the board assigned the wrong way round) fits as well
    // with white below black, and would be kept with corners from the wrong squares.
    if st.b.iter().any(|&g| !(g > 0.0)) {
        return Err("its colours are the opposite of the chart's there".into());
    }
    if max_corner_shift(&st.h, bootstrap, &quad) > params.max_refine_shift_px {
        return Err(format!(
            "alignment moved a corner by more than {} px from its bootstrap",
            params.max_refine_shift_px
        ));
    }
    let sigma_px = st.var.iter().map(|v| v.sqrt()).sum::<f64>() / np as f64;
    let ChannelResults {
        sigma: sigma_by_channel,
        levels: levels_by_channel,
        registration: channel_registration,
    } = per_channel(
        capture,
        spec,
        &st,
        &final_eval,
        rect,
        &quad,
        centre,
        scale,
        params,
    );
    Ok(Aligned {
        image_from_chart: st.h,
        residual_rms: (cost / n.max(1) as f64).sqrt(),
        black_level: black_sum / np as f64,
        white_level: white_sum / np as f64,
        sigma_px,
        sigma_by_channel,
        channel_image_from_chart: if params.channel_shifts {
            channel_registration.clone()
        } else {
            Vec::new()
        },
        channel_registration,
        levels_by_channel,
    })
}

/// A square's starting levels: per plane, black and the white − black gain, and their
/// sums over planes; and whether any pixel of its window clips.
struct Levels {
    a: Vec<f64>,
    b: Vec<f64>,
    black_sum: f64,
    white_sum: f64,
    window_clips: bool,
}

/// The levels of square (`col`, `row`) from its histogram's peaks over a window wider
/// than the square; an error naming why the square is set aside when its edges clip or
/// it has too little contrast. `m` is the registration's margin in chart units.
#[allow(clippy::too_many_arguments)]
fn square_levels(
    capture: &Capture,
    bootstrap: &Homography,
    quad: &[[f64; 2]; 4],
    col: usize,
    row: usize,
    m: f64,
    side_px: f64,
    params: &DetectParams,
) -> Result<Levels, String> {
    let chart_from_image = bootstrap.inverse().ok_or("degenerate homography")?;
    // Levels come from a wider window than the square alone: a blurred square's
    // circles never reach the full level of the opposite colour, the neighbours do.
    let wide_m = 0.35f64.max(m);
    let wide = [
        [quad[0][0] - wide_m, quad[0][1] - wide_m],
        [quad[1][0] + wide_m, quad[1][1] - wide_m],
        [quad[2][0] + wide_m, quad[2][1] + wide_m],
        [quad[3][0] - wide_m, quad[3][1] + wide_m],
    ];
    let mut wide_rect = quad_rect(bootstrap, &wide);
    wide_rect.x0 = wide_rect.x0.max(0);
    wide_rect.y0 = wide_rect.y0.max(0);
    wide_rect.x1 = wide_rect.x1.min(capture.width as i64 - 1);
    wide_rect.y1 = wide_rect.y1.min(capture.height as i64 - 1);
    let fine = samples(capture, wide_rect, 0.0, 1, None);
    let np = capture.planes.len();
    let mut a = vec![0.0; np];
    let mut b = vec![1.0; np];
    let (mut black_sum, mut white_sum) = (0.0, 0.0);
    let mut per_plane: Vec<Vec<f64>> = vec![Vec::new(); np];
    // Per plane, the pixels along the square's edges and how many of them are clipped.
    let mut edge_clipped = vec![[0usize; 2]; np];
    for s in &fine {
        let c = chart_from_image.apply([s.x as f64, s.y as f64]);
        if c[0] >= col as f64 - wide_m
            && c[0] <= col as f64 + 1.0 + wide_m
            && c[1] >= row as f64 - wide_m
            && c[1] <= row as f64 + 1.0 + wide_m
        {
            per_plane[s.plane].push(s.value);
        }
        if edge_distance([c[0] - col as f64, c[1] - row as f64]) * side_px <= EDGE_BAND_PX {
            edge_clipped[s.plane][0] += 1;
            edge_clipped[s.plane][1] += usize::from(s.value >= params.saturation_level);
        }
    }
    for (k, inside) in per_plane.iter().enumerate() {
        // Clipped pixels weigh nothing in the registration and are censored in the
        // kernels; a square goes only when its edges themselves are lost.
        let [along, clipped] = edge_clipped[k];
        if clipped as f64 > params.max_clipped_edge_fraction * along as f64 {
            return Err(format!(
                "saturated ({clipped} of the {along} pixels along its edges at or above {})",
                params.saturation_level
            ));
        }
        let (lo, hi) = histogram_peaks(inside).ok_or("too few pixels")?;
        if hi - lo < params.min_contrast {
            return Err(format!(
                "too dark (contrast {:.3} below {})",
                hi - lo,
                params.min_contrast
            ));
        }
        a[k] = lo;
        b[k] = hi - lo;
        black_sum += lo;
        white_sum += hi;
    }
    Ok(Levels {
        a,
        b,
        black_sum,
        white_sum,
        window_clips: fine.iter().any(|s| s.value >= params.saturation_level),
    })
}

/// Levenberg–Marquardt over the square's warp, blur and levels from `st`, coarse to
/// fine over `levels`; `hold` adds the held corners' terms. The fitted state, the fine
/// level's cost, its sample count and its normal equations; an error when the fine
/// level does not converge.
#[allow(clippy::too_many_arguments)]
fn register(
    capture: &Capture,
    spec: &ChartSpec,
    quad: &[[f64; 2]; 4],
    mut st: State,
    rect: Rect,
    levels: usize,
    centre: [f64; 2],
    scale: f64,
    hold: &dyn Fn(&mut Eval, &Homography),
    params: &DetectParams,
) -> Result<(State, f64, usize, Eval), String> {
    let mut last_eval: Option<(f64, usize, Eval)> = None;
    for level in (0..levels.max(1)).rev() {
        let extra_sigma = if level == 0 {
            0.0
        } else {
            params.coarse_sigma_px * f64::from(1u32 << (level - 1))
        };
        let stride = 1usize << level.min(2);
        let smp = if level == 0 {
            samples(capture, rect, 0.0, 1, Some(params.saturation_level))
        } else {
            samples(capture, rect, extra_sigma, stride, None)
        };
        let extra_var = extra_sigma * extra_sigma;
        let tol = if level == 0 {
            params.tolerance_px
        } else {
            params.tolerance_px * 10.0
        };
        let mut ev = evaluate(spec, &st, &smp, rect, extra_var, centre, scale);
        hold(&mut ev, &st.h);
        let mut lambda = 1e-4;
        let mut converged = false;
        for _ in 0..params.max_iterations {
            let mut damped = ev.jtj.clone();
            for d in 0..damped.nrows() {
                damped[(d, d)] += lambda * ev.jtj[(d, d)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&ev.jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let next = apply_step(&st, &step, centre, scale);
            let shift = max_corner_shift(&st.h, &next.h, quad);
            let mut nev = evaluate(spec, &next, &smp, rect, extra_var, centre, scale);
            hold(&mut nev, &next.h);
            if nev.cost <= ev.cost {
                st = next;
                ev = nev;
                lambda = (lambda * 0.3).max(1e-7);
                if shift < tol {
                    converged = true;
                    break;
                }
            } else {
                lambda *= 10.0;
                // A step too small to matter that does not lower the cost: the cost is
                // at its minimum to within the noise of its evaluation.
                if shift < tol || lambda > 1e6 {
                    // No descent left: at the minimum to within numerical noise.
                    converged = true;
                    break;
                }
            }
        }
        if level == 0 {
            if !converged {
                return Err(format!(
                    "alignment did not converge in {} iterations",
                    params.max_iterations
                ));
            }
            last_eval = Some((ev.cost, smp.len(), ev));
        }
    }
    let (cost, n, final_eval) = last_eval.ok_or("no alignment level ran")?;
    Ok((st, cost, n, final_eval))
}

/// A square's results per colour channel.
struct ChannelResults {
    /// Each channel's blur σ, px.
    sigma: Vec<(Channel, f64)>,
    /// Each channel's [black, white] levels.
    levels: Vec<(Channel, [f64; 2])>,
    /// Each channel's own registration; none for one channel.
    registration: Vec<(Channel, Homography)>,
}

/// A square's [`ChannelResults`] after the joint registration `st`.
#[allow(clippy::too_many_arguments)]
fn per_channel(
    capture: &Capture,
    spec: &ChartSpec,
    st: &State,
    final_eval: &Eval,
    rect: Rect,
    quad: &[[f64; 2]; 4],
    centre: [f64; 2],
    scale: f64,
    params: &DetectParams,
) -> ChannelResults {
    let np = capture.planes.len();
    let channels = capture.channels();
    // Measured on every capture of several channels (lateral colour is measured from
    // it); the kernels take it only where `channel_shifts` asks.
    let per_channel: Vec<(Channel, State)> = if channels.len() > 1 {
        let fine = samples(capture, rect, 0.0, 1, Some(params.saturation_level));
        channels
            .iter()
            .map(|&ch| {
                let planes: Vec<usize> = (0..np)
                    .filter(|&k| capture.planes[k].channel == ch)
                    .collect();
                let own = channel_state(
                    spec, st, final_eval, &fine, &planes, rect, quad, centre, scale, params,
                );
                (ch, own)
            })
            .collect()
    } else {
        Vec::new()
    };
    let mut sigma_by_channel: Vec<(Channel, f64)> = Vec::new();
    for &ch in &channels {
        // A channel's blur is best measured where that channel's image lies.
        let var = per_channel
            .iter()
            .find(|(c, _)| *c == ch && params.channel_shifts)
            .map_or(&st.var, |(_, s)| &s.var);
        let sigmas: Vec<f64> = capture
            .planes
            .iter()
            .zip(var)
            .filter(|(p, _)| p.channel == ch)
            .map(|(_, v)| v.sqrt())
            .collect();
        if !sigmas.is_empty() {
            sigma_by_channel.push((ch, sigmas.iter().sum::<f64>() / sigmas.len() as f64));
        }
    }
    let levels_by_channel = channels
        .iter()
        .filter_map(|&ch| {
            let planes: Vec<usize> = (0..np)
                .filter(|&k| capture.planes[k].channel == ch)
                .collect();
            let n = planes.len() as f64;
            let black = planes.iter().map(|&k| st.a[k]).sum::<f64>() / n;
            let white = planes.iter().map(|&k| st.a[k] + st.b[k]).sum::<f64>() / n;
            (!planes.is_empty()).then_some((ch, [black, white]))
        })
        .collect();
    let channel_registration: Vec<(Channel, Homography)> =
        per_channel.into_iter().map(|(c, s)| (c, s.h)).collect();
    ChannelResults {
        sigma: sigma_by_channel,
        levels: levels_by_channel,
        registration: channel_registration,
    }
}

/// A translation step smaller than this (px) from the joint solution is taken as one
/// Gauss–Newton step without re-evaluating: the residual is then linear in it to well
/// within the alignment's own noise.
const SMALL_CHANNEL_SHIFT_PX: f64 = 0.05;

/// One channel's registration: the joint solution moved by a translation and scaled
/// (with the channel's planes' blur, offset and gain) fitted to that channel's pixels alone. The
/// first step comes from the joint solution's own normal equations, split by plane;
/// only a channel that moves further is iterated on its own pixels.
#[allow(clippy::too_many_arguments)]
fn channel_state(
    spec: &ChartSpec,
    joint: &State,
    joint_eval: &Eval,
    fine: &[Sample],
    planes: &[usize],
    rect: Rect,
    quad: &[[f64; 2]; 4],
    centre: [f64; 2],
    scale: f64,
    params: &DetectParams,
) -> State {
    let step = |ev: &Eval, lambda: f64| -> Option<DVector<f64>> {
        channel_step(ev, planes, joint.var.len(), lambda)
    };
    let Some(first) = step(joint_eval, 1e-4) else {
        return joint.clone();
    };
    let first_px = corner_move_px(&first, scale);
    if !(first_px <= params.max_refine_shift_px) {
        return joint.clone();
    }
    let mut st = apply_step(joint, &first, centre, scale);
    if first_px < SMALL_CHANNEL_SHIFT_PX {
        return st;
    }
    let own: Vec<Sample> = fine
        .iter()
        .filter(|s| planes.contains(&s.plane))
        .copied()
        .collect();
    let mut ev = evaluate(spec, &st, &own, rect, 0.0, centre, scale);
    let mut lambda = 1e-4;
    for _ in 0..params.max_iterations {
        let Some(d) = step(&ev, lambda) else {
            lambda *= 10.0;
            continue;
        };
        let next = apply_step(&st, &d, centre, scale);
        let moved = corner_move_px(&d, scale);
        let nev = evaluate(spec, &next, &own, rect, 0.0, centre, scale);
        if nev.cost <= ev.cost {
            st = next;
            ev = nev;
            lambda = (lambda * 0.3).max(1e-7);
            if moved < params.tolerance_px {
                break;
            }
        } else {
            lambda *= 10.0;
            if moved < params.tolerance_px || lambda > 1e6 {
                break;
            }
        }
    }
    if max_corner_shift(&st.h, &joint.h, quad) > params.max_refine_shift_px {
        return joint.clone();
    }
    st
}

/// How far a channel step moves the square's corners at most, px.
fn corner_move_px(d: &DVector<f64>, scale: f64) -> f64 {
    (d[2].hypot(d[5]) + d[0].abs() * std::f64::consts::SQRT_2) * scale
}

/// The damped Gauss–Newton step of a translation (warp parameters 2 and 5), an
/// isotropic scale about the square's centre (lateral colour is a magnification about
/// the optical centre: locally both) and the blur, offset and gain of `planes`, from those planes' normal equations; as a full
/// step vector (zero elsewhere) for [`apply_step`].
fn channel_step(ev: &Eval, planes: &[usize], np: usize, lambda: f64) -> Option<DVector<f64>> {
    // Local unknown u ↦ the (plane, parameter) columns it sums; the translation and the
    // isotropic scale (warp parameters 0 and 4 together) are shared by the planes.
    let params_of = |u: usize| -> Vec<(usize, usize)> {
        match u {
            0 => planes.iter().map(|&k| (k, 2)).collect(),
            1 => planes.iter().map(|&k| (k, 5)).collect(),
            2 => planes.iter().flat_map(|&k| [(k, 0), (k, 4)]).collect(),
            _ => vec![(planes[(u - 3) / 3], 8 + (u - 3) % 3)],
        }
    };
    let dim = 3 + 3 * planes.len();
    let get = |m: &[f64], p: usize, q: usize| if p <= q { m[p * P + q] } else { m[q * P + p] };
    let mut a = DMatrix::<f64>::zeros(dim, dim);
    let mut b = DVector::<f64>::zeros(dim);
    for u in 0..dim {
        for (k, p) in params_of(u) {
            let (m, r) = ev.per_plane.get(k)?;
            b[u] += r[p];
            for v in 0..dim {
                for (k2, q) in params_of(v) {
                    if k2 == k {
                        a[(u, v)] += get(m, p, q);
                    }
                }
            }
        }
    }
    for d in 0..dim {
        a[(d, d)] += lambda * a[(d, d)].max(1e-12);
    }
    let x = a.cholesky()?.solve(&b);
    let mut full = DVector::<f64>::zeros(8 + 3 * np);
    full[2] = x[0];
    full[5] = x[1];
    full[0] = x[2];
    full[4] = x[2];
    for (i, &k) in planes.iter().enumerate() {
        for j in 0..3 {
            full[8 + 3 * k + j] = x[3 + 3 * i + j];
        }
    }
    Some(full)
}
