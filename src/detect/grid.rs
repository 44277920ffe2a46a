//! Finding the checkerboard: X-junction candidates from the Hessian of a smoothed grey
//! image, a ring test that keeps only true four-sector junctions, sub-pixel saddle
//! refinement, and growth of the junctions into a lattice indexed by chart corner.

use super::filter::gaussian_blur;
use crate::chart::ChartSpec;
use crate::geometry::Homography;
use crate::plane::Plane;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet, VecDeque};

/// A refined X-junction in sensor pixels.
#[derive(Clone, Copy, Debug)]
pub struct Junction {
    pub pos: [f64; 2],
    pub response: f64,
    /// How far out (px) its four sectors keep their colours ([`sector_reach`]).
    pub reach: f64,
}

/// Smoothed grey image with its size.
pub struct Smoothed {
    pub w: usize,
    pub h: usize,
    pub data: Vec<f64>,
}

impl Smoothed {
    #[must_use]
    pub fn new(grey: &Plane, sigma_px: f64) -> Self {
        let d: Vec<f64> = grey.data.iter().map(|&v| f64::from(v)).collect();
        Self {
            w: grey.width,
            h: grey.height,
            data: gaussian_blur(&d, grey.width, grey.height, sigma_px),
        }
    }

    #[inline]
    fn at(&self, x: usize, y: usize) -> f64 {
        self.data[y * self.w + x]
    }

    /// Bilinear sample; `None` outside.
    #[must_use]
    pub fn sample(&self, x: f64, y: f64) -> Option<f64> {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.w - 1) as f64 && y <= (self.h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let a = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let b = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        Some(a * (1.0 - fy) + b * fy)
    }
}

/// X-junction candidates: local maxima of −det(Hessian) that pass the ring test.
#[must_use]
pub fn find_junctions(s: &Smoothed, ring_radius_px: f64, min_rel_response: f64) -> Vec<Junction> {
    let (w, h) = (s.w, s.h);
    if w < 16 || h < 16 {
        return Vec::new();
    }
    let mut resp = vec![0.0f64; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let c = s.at(x, y);
            let ixx = s.at(x + 1, y) - 2.0 * c + s.at(x - 1, y);
            let iyy = s.at(x, y + 1) - 2.0 * c + s.at(x, y - 1);
            let ixy = 0.25
                * (s.at(x + 1, y + 1) - s.at(x - 1, y + 1) - s.at(x + 1, y - 1)
                    + s.at(x - 1, y - 1));
            resp[y * w + x] = ixy * ixy - ixx * iyy;
        }
    }
    let mut positive: Vec<f64> = resp.iter().copied().filter(|v| *v > 0.0).collect();
    if positive.is_empty() {
        return Vec::new();
    }
    // The junctions are a tiny fraction of the pixels: scale the threshold by a high
    // quantile so it adapts to contrast and blur.
    let at = ((positive.len() as f64 * 0.9995) as usize).min(positive.len() - 1);
    let q = *positive.select_nth_unstable_by(at, f64::total_cmp).1;
    let thr = min_rel_response * q;
    let nms = 3i64;
    let border = (ring_radius_px.ceil() as usize + 2).max(4);
    let mut out = Vec::new();
    for y in border..h.saturating_sub(border) {
        for x in border..w.saturating_sub(border) {
            let v = resp[y * w + x];
            if v <= thr {
                continue;
            }
            let mut is_max = true;
            'n: for dy in -nms..=nms {
                for dx in -nms..=nms {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let (xx, yy) = ((x as i64 + dx) as usize, (y as i64 + dy) as usize);
                    let u = resp[yy * w + xx];
                    if u > v || (u == v && (dy < 0 || (dy == 0 && dx < 0))) {
                        is_max = false;
                        break 'n;
                    }
                }
            }
            if !is_max {
                continue;
            }
            let Some(pos) = refine_saddle(s, [x as f64, y as f64]) else {
                continue;
            };
            if let Some(sectors) = ring_test(s, pos, ring_radius_px) {
                out.push(Junction {
                    pos,
                    response: v,
                    reach: sector_reach(s, pos, ring_radius_px, &sectors),
                });
            }
        }
    }
    out
}

/// The directions (radians) through the middles of a junction's four sectors, the
/// first and third lighter than the ring's mean, the second and fourth darker.
type Sectors = [f64; 4];

/// Four alternating sectors on a ring around `p`, each close to a quarter turn with
/// opposite sectors equal: the signature of two straight edges crossing (an
/// X-junction). Saddles between a circle and a square edge have unequal sectors.
fn ring_test(s: &Smoothed, p: [f64; 2], r: f64) -> Option<Sectors> {
    const N: usize = 48;
    let mut v = [0.0; N];
    for (k, vk) in v.iter_mut().enumerate() {
        let a = 2.0 * std::f64::consts::PI * k as f64 / N as f64;
        *vk = s.sample(p[0] + r * a.cos(), p[1] + r * a.sin())?;
    }
    let mean = v.iter().sum::<f64>() / N as f64;
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    if hi - lo < 0.05 {
        return None;
    }
    // Sign changes, located by linear interpolation, in units of the sample step.
    let mut bounds = Vec::with_capacity(4);
    for k in 0..N {
        let (a, b) = (v[k] - mean, v[(k + 1) % N] - mean);
        if (a > 0.0) != (b > 0.0) {
            bounds.push(k as f64 + a / (a - b));
        }
    }
    if bounds.len() != 4 {
        return None;
    }
    let deg = 360.0 / N as f64;
    let spans: Vec<f64> = (0..4)
        .map(|k| ((bounds[(k + 1) % 4] - bounds[k]).rem_euclid(N as f64)) * deg)
        .collect();
    let x_junction = spans.iter().all(|&s| (60.0..=120.0).contains(&s))
        && (spans[0] - spans[2]).abs() < 16.0
        && (spans[1] - spans[3]).abs() < 16.0;
    if !x_junction {
        return None;
    }
    // Sector k runs from bounds[k] to bounds[k + 1]; start from a light one.
    let middle = |k: usize| bounds[k] + 0.5 * spans[k] / deg;
    let first = usize::from(v[(middle(0).round() as usize) % N] < mean);
    Some(std::array::from_fn(|k| {
        middle((first + k) % 4) * deg.to_radians()
    }))
}

/// How far from junction `p` (px, in doublings of the ring radius `r`) its sectors keep
/// the colours they have on the ring: the light pair lighter than the dark pair by half
/// their difference at least. A chessboard's corner keeps them to about its square's
/// size; a saddle in a texture (where a stripe's ridge crosses a fainter dip, or noise
/// meets an edge) loses them within a period of the texture. Seeding the lattice from
/// the junctions that reach furthest finds the chart among thousands of such saddles.
fn sector_reach(s: &Smoothed, p: [f64; 2], r: f64, sectors: &Sectors) -> f64 {
    let mut reach = r;
    let far = s.w.min(s.h) as f64 / 2.0;
    let mut rho = 2.0 * r;
    while rho <= far {
        let mut v = [0.0; 4];
        for (vk, a) in v.iter_mut().zip(sectors) {
            match s.sample(p[0] + rho * a.cos(), p[1] + rho * a.sin()) {
                Some(x) => *vk = x,
                None => return reach,
            }
        }
        let (light_lo, dark_hi) = (v[0].min(v[2]), v[1].max(v[3]));
        let gap = 0.5 * (v[0] + v[2] - v[1] - v[3]);
        if !(gap > 0.0 && light_lo - dark_hi > 0.5 * gap) {
            break;
        }
        reach = rho;
        rho *= 2.0;
    }
    reach
}

/// Sub-pixel saddle: the stationary point of a quadratic fitted to the smoothed image
/// around `p`, iterated while it moves. `None` when it runs away or is not a saddle.
#[must_use]
pub fn refine_saddle(s: &Smoothed, p: [f64; 2]) -> Option<[f64; 2]> {
    let r = 3i64;
    let mut c = p;
    for _ in 0..6 {
        let (cx, cy) = (c[0].round() as i64, c[1].round() as i64);
        if cx - r < 0 || cy - r < 0 || cx + r >= s.w as i64 || cy + r >= s.h as i64 {
            return None;
        }
        // Fit f = a + b x + c y + d x² + e xy + f y² by least squares.
        let mut ata = nalgebra::SMatrix::<f64, 6, 6>::zeros();
        let mut atb = nalgebra::SVector::<f64, 6>::zeros();
        for dy in -r..=r {
            for dx in -r..=r {
                let (x, y) = (dx as f64, dy as f64);
                let wgt = (-(x * x + y * y) / (2.0 * 2.0 * 2.0)).exp();
                let row = nalgebra::SVector::<f64, 6>::from([1.0, x, y, x * x, x * y, y * y]);
                let v = s.at((cx + dx) as usize, (cy + dy) as usize);
                ata += wgt * row * row.transpose();
                atb += wgt * v * row;
            }
        }
        let k = ata.lu().solve(&atb)?;
        let (b, cc, d, e, f) = (k[1], k[2], k[3], k[4], k[5]);
        let det = 4.0 * d * f - e * e;
        if det >= 0.0 {
            return None;
        }
        let x = (-2.0 * f * b + e * cc) / det;
        let y = (-2.0 * d * cc + e * b) / det;
        let next = [cx as f64 + x, cy as f64 + y];
        if (next[0] - p[0]).hypot(next[1] - p[1]) > 4.0 {
            return None;
        }
        let moved = (next[0] - c[0]).hypot(next[1] - c[1]);
        c = next;
        if moved < 0.01 || (x.abs() <= 0.5 && y.abs() <= 0.5) {
            return Some(c);
        }
    }
    Some(c)
}

/// Junctions assigned to inner chart corners: `corners[(c, r)]` is the junction at chart
/// point (c, r), 1 ≤ c < cols, 1 ≤ r < rows.
pub struct Lattice {
    pub corners: HashMap<(usize, usize), [f64; 2]>,
    pub image_from_chart: Homography,
}

/// Why the junctions could not be organised into the chart's lattice.
#[derive(Debug)]
pub enum LatticeError {
    NotFound,
    TooLarge { cols: usize, rows: usize },
}

struct Buckets {
    cell: f64,
    // Looked up nine times per step of every grid walk, with keys that are our own
    // bucket indices: std's DoS-resistant SipHash costs more than the lookup's work.
    map: rustc_hash::FxHashMap<(i64, i64), Vec<usize>>,
}

impl Buckets {
    fn new(pts: &[Junction], cell: f64) -> Self {
        let mut map = rustc_hash::FxHashMap::<(i64, i64), Vec<usize>>::default();
        for (i, j) in pts.iter().enumerate() {
            map.entry((
                (j.pos[0] / cell).floor() as i64,
                (j.pos[1] / cell).floor() as i64,
            ))
            .or_default()
            .push(i);
        }
        Self { cell, map }
    }

    /// The nearest point to `q` within `radius` (radius ≤ cell).
    fn nearest(&self, pts: &[Junction], q: [f64; 2], radius: f64) -> Option<usize> {
        let (bx, by) = (
            (q[0] / self.cell).floor() as i64,
            (q[1] / self.cell).floor() as i64,
        );
        let mut best: Option<(usize, f64)> = None;
        let reach = (radius / self.cell).ceil() as i64;
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                if let Some(v) = self.map.get(&(bx + dx, by + dy)) {
                    for &i in v {
                        let d = (pts[i].pos[0] - q[0]).hypot(pts[i].pos[1] - q[1]);
                        if d <= radius && best.is_none_or(|(_, bd)| d < bd) {
                            best = Some((i, d));
                        }
                    }
                }
            }
        }
        best.map(|(i, _)| i)
    }
}

/// Median distance from a junction to its nearest neighbour (over at most 400 of them).
fn nearest_spacing(pts: &[Junction]) -> f64 {
    let stride = (pts.len() / 400).max(1);
    let mut d: Vec<f64> = pts
        .iter()
        .step_by(stride)
        .map(|p| {
            pts.iter()
                .map(|q| norm(sub(q.pos, p.pos)))
                .filter(|&d| d > 1e-9)
                .fold(f64::INFINITY, f64::min)
        })
        .filter(|d| d.is_finite())
        .collect();
    if d.is_empty() {
        return 8.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, f64::total_cmp).1
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}
fn add(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] + b[0], a[1] + b[1]]
}
fn norm(a: [f64; 2]) -> f64 {
    a[0].hypot(a[1])
}

/// [`lattice_score`] with each edge's contrast measured once: candidate lattices from
/// one seed share most of their edges.
fn memo_score<'a>(
    contrasts: &'a mut HashMap<(usize, usize), Option<f64>>,
    smoothed: &'a Smoothed,
    pts: &'a [Junction],
) -> impl FnMut(&HashMap<(i64, i64), usize>) -> f64 + 'a {
    move |g| {
        lattice_score(g, |k, q| {
            *contrasts
                .entry((k, q))
                .or_insert_with(|| edge_contrast(smoothed, pts[k].pos, pts[q].pos))
        })
    }
}

/// The best lattice grown from one seed, and the largest one refused as larger than
/// the chart (nodes, columns, rows).
#[derive(Default)]
struct SeedLattice {
    best: HashMap<(i64, i64), usize>,
    score: f64,
    too_large: (usize, usize, usize),
    /// The junctions of every lattice grown from this seed that is larger than the
    /// chart: a periodic texture beside the chart, not the chart.
    too_large_nodes: Vec<usize>,
}

/// Where a lattice step is checked against the image: the smoothed grey image, and the
/// points of a lattice cell where a chessboard square shows its own colour.
struct Cells<'a> {
    smoothed: &'a Smoothed,
    /// (u, v) in a unit cell, along its two lattice axes: a grid over its middle, clear
    /// of its edges' blur and of the spec's circles whichever way round the print lies.
    probes: Vec<[f64; 2]>,
}

impl<'a> Cells<'a> {
    fn new(smoothed: &'a Smoothed, spec: &ChartSpec) -> Self {
        let clear = spec.circle_radius + 0.08;
        let images = |c: &[f64; 2]| {
            let [x, y] = *c;
            [
                [x, y],
                [1.0 - x, y],
                [x, 1.0 - y],
                [1.0 - x, 1.0 - y],
                [y, x],
                [1.0 - y, x],
                [y, 1.0 - x],
                [1.0 - y, 1.0 - x],
            ]
        };
        let mut probes = Vec::new();
        for v in [0.3, 0.5, 0.7] {
            for u in [0.3, 0.5, 0.7] {
                let off_circles = spec
                    .circle_centres
                    .iter()
                    .flat_map(images)
                    .all(|c| (c[0] - u).hypot(c[1] - v) > clear);
                if off_circles {
                    probes.push([u, v]);
                }
            }
        }
        Self { smoothed, probes }
    }

    /// The least, mean and greatest of the image at the probes of the cell at `p`
    /// spanned by `a` and `b`; `None` when fewer than half of them lie in the frame.
    fn levels(&self, p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> Option<[f64; 3]> {
        let (mut lo, mut sum, mut hi, mut n) = (f64::INFINITY, 0.0, f64::NEG_INFINITY, 0);
        for [u, v] in &self.probes {
            let q = [p[0] + u * a[0] + v * b[0], p[1] + u * a[1] + v * b[1]];
            if let Some(x) = self.smoothed.sample(q[0], q[1]) {
                lo = lo.min(x);
                hi = hi.max(x);
                sum += x;
                n += 1;
            }
        }
        (n > 0 && 2 * n >= self.probes.len()).then(|| [lo, sum / n as f64, hi])
    }

    /// Whether the lattice step from `p` by `step` runs between two squares of a
    /// chessboard: the cells on its two sides (towards `side`, and away from it) each of
    /// one colour, the one `plus_dark` says darker than the other by `min_contrast` at
    /// least. A cell beyond the frame is not held against the step, but the other must
    /// be of one colour. A lattice grown only through such steps stops at the board's
    /// edge: stripes, tiles or a grille beside the print are not a chessboard's squares
    /// at the chart's step, however many saddles they hold.
    fn between_squares(
        &self,
        p: [f64; 2],
        step: [f64; 2],
        side: [f64; 2],
        plus_dark: bool,
        min_contrast: f64,
    ) -> bool {
        if self.probes.is_empty() {
            return true;
        }
        let plus = self.levels(p, step, side);
        let minus = self.levels(p, step, [-side[0], -side[1]]);
        match (plus, minus) {
            (Some(a), Some(b)) => {
                let (dark, light) = if plus_dark { (a, b) } else { (b, a) };
                let contrast = light[1] - dark[1];
                contrast >= min_contrast
                    && light[2] - light[0] <= 0.5 * contrast
                    && dark[2] - dark[0] <= 0.5 * contrast
            }
            (Some(c), None) | (None, Some(c)) => c[2] - c[0] <= 0.5 * min_contrast,
            (None, None) => false,
        }
    }
}

/// Grows a lattice from `seed` with starting axes `ex`, `ey`: every node predicts its
/// four neighbours from its own local axes, so mild perspective and rotation are
/// followed smoothly. Each step must run between two squares of the seed's chessboard
/// ([`Cells::between_squares`], the squares' colours alternating from the seed's and
/// their contrast at least a third of the seed's), so the lattice does not run on
/// into a periodic texture beside the print.
fn grow(
    pts: &[Junction],
    buckets: &Buckets,
    cells: &Cells<'_>,
    seed: usize,
    ex: [f64; 2],
    ey: [f64; 2],
    excluded: &HashSet<usize>,
) -> HashMap<(i64, i64), usize> {
    let mut grid: HashMap<(i64, i64), usize> = HashMap::new();
    let mut taken: HashMap<usize, (i64, i64)> = HashMap::new();
    grid.insert((0, 0), seed);
    taken.insert(seed, (0, 0));
    let p0 = pts[seed].pos;
    // Whether the cells (i, j) with i + j even are the dark ones, and how much darker.
    let (even_dark, min_contrast) = if cells.probes.is_empty() {
        (false, 0.0)
    } else {
        let (Some(a), Some(b)) = (
            cells.levels(p0, ex, ey),
            cells.levels(p0, ex, [-ey[0], -ey[1]]),
        ) else {
            return grid;
        };
        let even_dark = a[1] < b[1];
        let contrast = (a[1] - b[1]).abs();
        if contrast < 0.05 || !cells.between_squares(p0, ex, ey, even_dark, 0.05) {
            return grid;
        }
        (even_dark, contrast / 3.0)
    };
    let mut queue = VecDeque::from([((0i64, 0i64), ex, ey)]);
    while let Some(((i, j), ex, ey)) = queue.pop_front() {
        let p = pts[grid[&(i, j)]].pos;
        for (di, dj, step) in [
            (1, 0, ex),
            (-1, 0, [-ex[0], -ex[1]]),
            (0, 1, ey),
            (0, -1, [-ey[0], -ey[1]]),
        ] {
            let key = (i + di, j + dj);
            if grid.contains_key(&key) {
                continue;
            }
            let radius = 0.3 * norm(step);
            let Some(k) = buckets.nearest(pts, add(p, step), radius) else {
                continue;
            };
            if taken.contains_key(&k) || excluded.contains(&k) {
                continue;
            }
            let found = sub(pts[k].pos, p);
            // The cell on the `side` of the step, (i, j) for a step to (i + 1, j).
            let (side, cell) = if di != 0 {
                (ey, (i + di.min(0), j))
            } else {
                (ex, (i, j + dj.min(0)))
            };
            let plus_dark = ((cell.0 + cell.1).rem_euclid(2) == 0) == even_dark;
            if !cells.between_squares(p, found, side, plus_dark, min_contrast) {
                continue;
            }
            let (nx, ny) = match (di, dj) {
                (1, 0) => (found, ey),
                (-1, 0) => ([-found[0], -found[1]], ey),
                (0, 1) => (ex, found),
                _ => (ex, [-found[0], -found[1]]),
            };
            grid.insert(key, k);
            taken.insert(k, key);
            queue.push_back((key, nx, ny));
        }
    }
    grid
}

/// Lattices grown from the strongest of `order`'s junctions and others spread over it,
/// one [`SeedLattice`] per seed.
fn grow_from_seeds(
    pts: &[Junction],
    order: &[usize],
    buckets: &Buckets,
    cells: &Cells<'_>,
    spec: &ChartSpec,
    excluded: &HashSet<usize>,
) -> Vec<SeedLattice> {
    let smoothed = cells.smoothed;
    let (inner_c, inner_r) = (spec.cols - 1, spec.rows - 1);
    let n_seeds = 24usize;
    let stride = (order.len() / n_seeds).max(1);
    // The strongest saddles are mostly true corners; the rest spread over the list in
    // case a strong false lattice (circles against square edges) dominates the top.
    let mut seeds: Vec<usize> = order.iter().take(n_seeds / 2).copied().collect();
    for &k in order.iter().step_by(stride).take(n_seeds) {
        if seeds.len() < n_seeds + n_seeds / 2 && !seeds.contains(&k) {
            seeds.push(k);
        }
    }
    // And those whose sectors reach furthest: where a texture's saddles outnumber the
    // chart's corners a hundred to one, neither the strongest nor a spread of the list
    // need hold one of the chart's.
    if !cells.probes.is_empty() {
        let mut by_reach = order.to_vec();
        by_reach.sort_by(|&a, &b| pts[b].reach.total_cmp(&pts[a].reach));
        for &k in by_reach.iter().take(n_seeds) {
            if seeds.len() < 2 * n_seeds && !seeds.contains(&k) {
                seeds.push(k);
            }
        }
    }
    let max_step = (smoothed.w.min(smoothed.h) as f64) / 3.0;
    // Seeds are independent: grown in parallel, then judged in seed order as a serial
    // search would (the first of equal scores wins).
    seeds
        .par_iter()
        .map_init(HashMap::new, |contrasts, &seed| {
            let mut score = memo_score(contrasts, smoothed, pts);
            let mut out = SeedLattice::default();
            let p0 = pts[seed].pos;
            let cone = |target: f64| -> Vec<[f64; 2]> {
                let mut v: Vec<(f64, [f64; 2])> = pts
                    .iter()
                    .map(|q| sub(q.pos, p0))
                    .filter(|d| {
                        let n = norm(*d);
                        if !(6.0..=max_step).contains(&n) {
                            return false;
                        }
                        let mut diff = (d[1].atan2(d[0]) - target).abs();
                        if diff > std::f64::consts::PI {
                            diff = 2.0 * std::f64::consts::PI - diff;
                        }
                        diff < std::f64::consts::FRAC_PI_4
                    })
                    .map(|d| (norm(d), d))
                    .collect();
                v.sort_by(|a, b| a.0.total_cmp(&b.0));
                // The adjacent corner is among the nearest few in each direction
                // (others there are saddles between circles, or corners further along).
                v.into_iter().take(8).map(|x| x.1).collect()
            };
            for ex in cone(0.0) {
                for ey in cone(std::f64::consts::FRAC_PI_2) {
                    let ratio = norm(ex) / norm(ey);
                    if !(0.6..=1.6).contains(&ratio) {
                        continue;
                    }
                    let mut g = grow(pts, buckets, cells, seed, ex, ey, excluded);
                    let (imin, imax, jmin, jmax) = extent(&g);
                    let (lim_i, lim_j) = lattice_limits(
                        (imax - imin + 1) as usize,
                        (jmax - jmin + 1) as usize,
                        inner_c,
                        inner_r,
                    );
                    trim_border(&mut g, lim_i, lim_j, |g, axis, lo, hi| {
                        worse_line(g, axis, lo, hi, &mut score)
                    });
                    if g.len() < 9 {
                        continue;
                    }
                    // Finer lattices of saddles between circles span more nodes than
                    // the chart has corners.
                    let (imin, imax, jmin, jmax) = extent(&g);
                    let (ni, nj) = ((imax - imin + 1) as usize, (jmax - jmin + 1) as usize);
                    if !fits(ni, nj, inner_c, inner_r) {
                        if g.len() > out.too_large.0 {
                            out.too_large = (g.len(), ni + 1, nj + 1);
                        }
                        out.too_large_nodes.extend(g.values().copied());
                        continue;
                    }
                    let s = score(&g);
                    if s > out.score {
                        out.score = s;
                        out.best = g;
                    }
                }
            }
            out
        })
        .collect()
}

/// Organises junctions into the chart's lattice of inner corners, fixing the chart
/// column/row of each from the visible board edges and the square colours.
///
/// # Errors
/// [`LatticeError`] when no lattice of at least 3 × 3 junctions is found, or it is
/// larger than the chart.
pub fn build_lattice(
    pts: &[Junction],
    smoothed: &Smoothed,
    spec: &ChartSpec,
) -> Result<Lattice, LatticeError> {
    if pts.len() < 9 {
        return Err(LatticeError::NotFound);
    }

    // Bucket cells of about the search radius, so a neighbour query looks at a few
    // cells whatever the square size: the median distance to the nearest junction
    // estimates the corner spacing.
    let buckets = Buckets::new(pts, (0.3 * nearest_spacing(pts)).max(4.0));
    let cells = Cells::new(smoothed, spec);
    let (best, excluded) = search_lattices(pts, &buckets, &cells, spec)?;
    let (best, h) = settle(pts, &buckets, smoothed, spec, best, &excluded)?;
    let (inner_c, inner_r) = (spec.cols - 1, spec.rows - 1);
    let (imin, imax, jmin, jmax) = extent(&best);
    let (ni, nj) = ((imax - imin + 1) as usize, (jmax - jmin + 1) as usize);
    if ni < 3 || nj < 3 || best.len() * 2 < ni * nj {
        return Err(LatticeError::NotFound);
    }
    if !fits(ni, nj, inner_c, inner_r) {
        return Err(LatticeError::TooLarge {
            cols: ni + 1,
            rows: nj + 1,
        });
    }
    let even_black = even_cells_black(&best, pts, &h, smoothed);
    let (w, hgt) = (smoothed.w as f64, smoothed.h as f64);
    let inside = |p: [f64; 2]| p[0] > 2.0 && p[1] > 2.0 && p[0] < w - 3.0 && p[1] < hgt - 3.0;
    // The spec describes the print, not the shot: the board may show at any rotation.
    // Each quarter turn of the lattice onto the chart's axes (never a mirror image) is
    // tried; the board's visible edges fix the offsets, the square colours rule out
    // the turns that put black where the print has white, and of the turns left (a
    // board as symmetric as its squares' colours allow, or seen in part) the one that
    // turns the print least in the shot is taken.
    let mut chosen: Option<(f64, usize, i64, i64)> = None;
    for quarter in 0..4usize {
        let turned: Vec<(i64, i64)> = best.keys().map(|&k| turn(quarter, k)).collect();
        let amin = turned.iter().map(|k| k.0).min().unwrap_or(0);
        let amax = turned.iter().map(|k| k.0).max().unwrap_or(0);
        let bmin = turned.iter().map(|k| k.1).min().unwrap_or(0);
        let bmax = turned.iter().map(|k| k.1).max().unwrap_or(0);
        if (amax - amin + 1) as usize > inner_c || (bmax - bmin + 1) as usize > inner_r {
            continue;
        }
        // Chart axes (a, b) back to the lattice's, then to the image.
        let image_at = |a: i64, b: i64| -> [f64; 2] {
            let (i, j) = turn((4 - quarter) % 4, (a, b));
            h.apply([i as f64, j as f64])
        };
        // A side of the board is visible when the lattice line beyond the last found
        // one still falls inside the frame (there is no junction there: it is the
        // board's edge).
        let line_inside = |line: &dyn Fn(i64) -> [f64; 2], lo: i64, hi: i64| -> bool {
            let n_in = (lo..=hi).filter(|&t| inside(line(t))).count();
            n_in * 2 > (hi - lo + 1) as usize
        };
        let ocs = allowed_offsets(
            amin,
            amax,
            spec.cols as i64,
            line_inside(&|b| image_at(amin - 1, b), bmin, bmax),
            line_inside(&|b| image_at(amax + 1, b), bmin, bmax),
        );
        let ors = allowed_offsets(
            bmin,
            bmax,
            spec.rows as i64,
            line_inside(&|a| image_at(a, bmin - 1), amin, amax),
            line_inside(&|a| image_at(a, bmax + 1), amin, amax),
        );
        // Lattice cell (i, j) lands on chart square (c, r) with c + r ≡ i + j + quarter
        // + oc + or (mod 2) (an odd turn moves the cell's corner by one along one axis);
        // square (c, r) is black ⇔ (c + r even) == black_top_left.
        let offset_parity = (quarter as i64 + i64::from(even_black != spec.black_top_left)) % 2;
        // Among the offsets the edges allow, those matching the colours, nearest the
        // middle of the allowed range.
        let (mc, mr) = (ocs[ocs.len() / 2] as f64, ors[ors.len() / 2] as f64);
        let mut pick: Option<(i64, i64, f64)> = None;
        for &oc in &ocs {
            for &or in &ors {
                if (oc + or).rem_euclid(2) != offset_parity {
                    continue;
                }
                let d = (oc as f64 - mc).abs() + (or as f64 - mr).abs();
                if pick.is_none_or(|(_, _, bd)| d < bd) {
                    pick = Some((oc, or, d));
                }
            }
        }
        let Some((oc, or, _)) = pick else { continue };
        let (am, bm) = ((amin + amax) / 2, (bmin + bmax) / 2);
        let (p, q) = (image_at(am, bm), image_at(am + 1, bm));
        let turn_in_shot = (q[1] - p[1]).atan2(q[0] - p[0]).abs();
        if chosen.is_none_or(|(t, ..)| turn_in_shot < t - 1e-9) {
            chosen = Some((turn_in_shot, quarter, oc, or));
        }
    }
    let Some((_, quarter, oc, or)) = chosen else {
        return Err(LatticeError::NotFound);
    };
    let mut corners = HashMap::new();
    for (&key, &k) in &best {
        let (a, b) = turn(quarter, key);
        let (c, r) = (a + oc, b + or);
        if c >= 1 && r >= 1 && c < spec.cols as i64 && r < spec.rows as i64 {
            corners.insert((c as usize, r as usize), pts[k].pos);
        }
    }
    let mut keys: Vec<&(usize, usize)> = corners.keys().collect();
    keys.sort();
    let from: Vec<[f64; 2]> = keys.iter().map(|k| [k.0 as f64, k.1 as f64]).collect();
    let to: Vec<[f64; 2]> = keys.iter().map(|k| corners[k]).collect();
    let image_from_chart =
        Homography::from_correspondences(&from, &to).ok_or(LatticeError::NotFound)?;
    Ok(Lattice {
        corners,
        image_from_chart,
    })
}

/// Which colour each lattice cell is (cell (i, j) spans nodes (i, j) to
/// (i + 1, j + 1)): a vote over nodes of whether the cells with i + j even are black.
fn even_cells_black(
    best: &HashMap<(i64, i64), usize>,
    pts: &[Junction],
    h: &Homography,
    smoothed: &Smoothed,
) -> bool {
    let mut even_black_votes = [0usize; 2];
    for (&(i, j), &k) in best {
        let p = pts[k].pos;
        let e_x = sub(h.apply([i as f64 + 1.0, j as f64]), p);
        let e_y = sub(h.apply([i as f64, j as f64 + 1.0]), p);
        let below = add(
            p,
            [0.5 * e_x[0] + 0.15 * e_y[0], 0.5 * e_x[1] + 0.15 * e_y[1]],
        );
        let above = add(
            p,
            [0.5 * e_x[0] - 0.15 * e_y[0], 0.5 * e_x[1] - 0.15 * e_y[1]],
        );
        if let (Some(b), Some(a)) = (
            smoothed.sample(below[0], below[1]),
            smoothed.sample(above[0], above[1]),
        ) {
            // `below` lies in cell (i, j).
            let cell_black = b < a;
            let ij_even = (i + j).rem_euclid(2) == 0;
            even_black_votes[usize::from(cell_black == ij_even)] += 1;
        }
    }
    even_black_votes[1] > even_black_votes[0]
}

/// A lattice's nodes: lattice index (i, j) to junction.
type Nodes = HashMap<(i64, i64), usize>;

/// The best lattice grown from seeds over the junctions, and the junctions set aside
/// as part of lattices larger than the chart.
///
/// Saddles also form between the circles and the square edges, in lattices of their
/// own; lattices are grown from several seeds and axis hypotheses and the one whose
/// edges separate dark from light squares in the checkerboard's alternation is kept.
fn search_lattices(
    pts: &[Junction],
    buckets: &Buckets,
    cells: &Cells<'_>,
    spec: &ChartSpec,
) -> Result<(Nodes, HashSet<usize>), LatticeError> {
    let mut order: Vec<usize> = (0..pts.len()).collect();
    order.sort_by(|&a, &b| pts[b].response.total_cmp(&pts[a].response));
    // A chessboard beside the chart (a second board, two-colour tiles) can fill the
    // seeds with junctions whose lattice is larger than the chart; lattices stop at a
    // chessboard's edge, so such a lattice is not the chart whatever its score: its
    // junctions are set aside and the search seeded again from the rest, so the
    // printed grid's size decides.
    let mut excluded: HashSet<usize> = HashSet::new();
    let mut best: HashMap<(i64, i64), usize> = HashMap::new();
    let mut best_score = 0.0;
    let mut too_large = (0usize, 0usize, 0usize);
    for _round in 0..4 {
        let order: Vec<usize> = order
            .iter()
            .copied()
            .filter(|k| !excluded.contains(k))
            .collect();
        let per_seed = grow_from_seeds(pts, &order, buckets, cells, spec, &excluded);
        let mut newly_excluded = Vec::new();
        for r in per_seed {
            if r.too_large.0 > too_large.0 {
                too_large = r.too_large;
            }
            newly_excluded.extend(r.too_large_nodes);
            if r.score > best_score {
                best_score = r.score;
                best = r.best;
            }
        }
        let before = excluded.len();
        excluded.extend(newly_excluded);
        if best.len() >= 9 || excluded.len() == before {
            break;
        }
    }
    if best.len() < 9 {
        if too_large.0 >= 9 && too_large.0 > 2 * best.len() {
            return Err(LatticeError::TooLarge {
                cols: too_large.1,
                rows: too_large.2,
            });
        }
        return Err(LatticeError::NotFound);
    }
    Ok((best, excluded))
}

/// The search's lattice settled against its own fit: nodes their neighbours disown
/// dropped, holes filled, outer lines beyond the chart trimmed; with its homography.
fn settle(
    pts: &[Junction],
    buckets: &Buckets,
    smoothed: &Smoothed,
    spec: &ChartSpec,
    mut best: Nodes,
    excluded: &HashSet<usize>,
) -> Result<(Nodes, Homography), LatticeError> {
    let (inner_c, inner_r) = (spec.cols - 1, spec.rows - 1);
    let mut contrasts = HashMap::new();
    let mut score = memo_score(&mut contrasts, smoothed, pts);
    let mut steps: Vec<f64> = best
        .iter()
        .filter_map(|(&(i, j), &k)| {
            best.get(&(i + 1, j))
                .map(|&q| norm(sub(pts[q].pos, pts[k].pos)))
        })
        .collect();
    if steps.is_empty() {
        return Err(LatticeError::NotFound);
    }
    steps.sort_by(f64::total_cmp);
    let spacing = steps[steps.len() / 2];
    let fit = |g: &HashMap<(i64, i64), usize>| fit_lattice(g, pts);
    let Some(mut h) = fit(&best) else {
        return Err(LatticeError::NotFound);
    };
    // Drop nodes the global fit disowns, then fill holes from its predictions. Along
    // an axis that spans fewer lines than the chart has, look one line beyond each
    // end too; where that overshoots (a line of saddles just outside the board lines
    // up with the lattice), the outer line whose removal leaves the better
    // checkerboard goes.
    for _ in 0..2 {
        // Each node is judged by its neighbours, not by the global fit: lens distortion
        // bends the lattice by a good fraction of a square toward the frame corners,
        // where one homography for the whole board disowns true corners.
        let disowned: Vec<(i64, i64)> = best
            .iter()
            .filter(|&(&k, &i)| {
                let predicted = local_prediction(&best, pts, k)
                    .unwrap_or_else(|| h.apply([k.0 as f64, k.1 as f64]));
                norm(sub(predicted, pts[i].pos)) >= 0.2 * spacing
            })
            .map(|(&k, _)| k)
            .collect();
        for k in disowned {
            best.remove(&k);
        }
        let (imin, imax, jmin, jmax) = extent(&best);
        let (ni, nj) = ((imax - imin + 1) as usize, (jmax - jmin + 1) as usize);
        let (lim_i, lim_j) = lattice_limits(ni, nj, inner_c, inner_r);
        let grow_i = i64::from(ni < lim_i);
        let grow_j = i64::from(nj < lim_j);
        let mut taken: HashSet<usize> = best.values().copied().collect();
        taken.extend(excluded);
        for j in jmin - grow_j..=jmax + grow_j {
            for i in imin - grow_i..=imax + grow_i {
                if best.contains_key(&(i, j)) {
                    continue;
                }
                let q = local_prediction(&best, pts, (i, j))
                    .unwrap_or_else(|| h.apply([i as f64, j as f64]));
                if let Some(k) = buckets.nearest(pts, q, 0.2 * spacing)
                    && !taken.contains(&k)
                {
                    best.insert((i, j), k);
                    taken.insert(k);
                }
            }
        }
        trim_border(&mut best, lim_i, lim_j, |g, axis, lo, hi| {
            worse_line(g, axis, lo, hi, &mut score)
        });
        match fit(&best) {
            Some(nh) => h = nh,
            None => return Err(LatticeError::NotFound),
        }
    }
    Ok((best, h))
}

/// The homography from lattice indices to the nodes' junctions.
fn fit_lattice(g: &HashMap<(i64, i64), usize>, pts: &[Junction]) -> Option<Homography> {
    let mut keys: Vec<&(i64, i64)> = g.keys().collect();
    keys.sort();
    let from: Vec<[f64; 2]> = keys.iter().map(|k| [k.0 as f64, k.1 as f64]).collect();
    let to: Vec<[f64; 2]> = keys.iter().map(|k| pts[g[k]].pos).collect();
    Homography::from_correspondences(&from, &to)
}

/// Lattice node (i, j) turned by `quarter` quarter turns (a rotation, never a mirror).
fn turn(quarter: usize, (i, j): (i64, i64)) -> (i64, i64) {
    match quarter % 4 {
        0 => (i, j),
        1 => (-j, i),
        2 => (-i, -j),
        _ => (j, -i),
    }
}

/// Whether a lattice of `ni` × `nj` nodes fits inside the chart's `inner_c` × `inner_r`
/// inner corners either way round.
fn fits(ni: usize, nj: usize, inner_c: usize, inner_r: usize) -> bool {
    (ni <= inner_c && nj <= inner_r) || (ni <= inner_r && nj <= inner_c)
}

/// How many lines the lattice may span along its i and j axes: the chart's inner
/// corners the way round the lattice fits, else with its longer side along the
/// chart's longer side.
fn lattice_limits(ni: usize, nj: usize, inner_c: usize, inner_r: usize) -> (usize, usize) {
    if ni <= inner_c && nj <= inner_r {
        (inner_c, inner_r)
    } else if ni <= inner_r && nj <= inner_c {
        (inner_r, inner_c)
    } else if (ni >= nj) == (inner_c >= inner_r) {
        (inner_c, inner_r)
    } else {
        (inner_r, inner_c)
    }
}

/// Offsets o that put lattice lines lo..=hi on chart lines 1..n_chart − 1: the one a
/// visible board edge fixes, else every one that fits.
fn allowed_offsets(lo: i64, hi: i64, n_chart: i64, lo_edge: bool, hi_edge: bool) -> Vec<i64> {
    let (omin, omax) = (1 - lo, n_chart - 1 - hi);
    if lo_edge {
        vec![omin]
    } else if hi_edge {
        vec![omax]
    } else {
        (omin..=omax).collect()
    }
}

/// Where lattice node `key` should lie, from a homography fitted to the other nodes
/// within two lattice steps (three where fewer than six are found that close): local
/// enough that lens distortion across it is a small fraction of a pixel.
fn local_prediction(
    g: &HashMap<(i64, i64), usize>,
    pts: &[Junction],
    key: (i64, i64),
) -> Option<[f64; 2]> {
    for reach in [2i64, 3] {
        let mut from = Vec::new();
        let mut to = Vec::new();
        for dj in -reach..=reach {
            for di in -reach..=reach {
                if di == 0 && dj == 0 {
                    continue;
                }
                if let Some(&k) = g.get(&(key.0 + di, key.1 + dj)) {
                    from.push([(key.0 + di) as f64, (key.1 + dj) as f64]);
                    to.push(pts[k].pos);
                }
            }
        }
        if from.len() >= 6 {
            return Homography::from_correspondences(&from, &to)
                .map(|h| h.apply([key.0 as f64, key.1 as f64]));
        }
    }
    None
}

/// Drops up to two outermost lines of nodes on each axis while the lattice spans more
/// corners than the chart has inside it. Junctions just outside the board (where the
/// outer squares' circles meet their edges, or the board's own outer corners in some
/// framings) can line up with the lattice one step beyond the last inner corner;
/// `pick(g, axis, lo, hi)` says which of the two outer lines (index along `axis`) goes.
fn trim_border(
    g: &mut HashMap<(i64, i64), usize>,
    max_i: usize,
    max_j: usize,
    mut pick: impl FnMut(&HashMap<(i64, i64), usize>, usize, i64, i64) -> i64,
) {
    for axis in 0..2 {
        for _ in 0..2 {
            if g.is_empty() {
                return;
            }
            let (imin, imax, jmin, jmax) = extent(g);
            let (lo, hi, limit) = if axis == 0 {
                (imin, imax, max_i)
            } else {
                (jmin, jmax, max_j)
            };
            if ((hi - lo + 1) as usize) <= limit {
                break;
            }
            let drop = pick(g, axis, lo, hi);
            g.retain(|&(i, j), _| (if axis == 0 { i } else { j }) != drop);
        }
    }
}

/// Of the outer lines `lo` and `hi` along `axis`, the one whose removal leaves the
/// better checkerboard by `score`. A line of saddles along the board's outer edge can
/// be as full as a true line and respond as strongly (the true corners nearest the
/// frame are the blurriest), but half of its edges run between a white square and the
/// white margin and have no contrast.
fn worse_line(
    g: &HashMap<(i64, i64), usize>,
    axis: usize,
    lo: i64,
    hi: i64,
    score: &mut impl FnMut(&HashMap<(i64, i64), usize>) -> f64,
) -> i64 {
    let mut without = |v: i64| {
        let mut rest = g.clone();
        rest.retain(|&(i, j), _| (if axis == 0 { i } else { j }) != v);
        score(&rest)
    };
    if without(lo) >= without(hi) { lo } else { hi }
}

fn extent(g: &HashMap<(i64, i64), usize>) -> (i64, i64, i64, i64) {
    let imin = g.keys().map(|k| k.0).min().unwrap_or(0);
    let imax = g.keys().map(|k| k.0).max().unwrap_or(0);
    let jmin = g.keys().map(|k| k.1).min().unwrap_or(0);
    let jmax = g.keys().map(|k| k.1).max().unwrap_or(0);
    (imin, imax, jmin, jmax)
}

/// How many of a lattice's edges are edges of the checkerboard, less those that are not.
///
/// An edge between two neighbouring square corners is a straight boundary with dark on
/// one side and light on the other all along it, and its sign alternates with the
/// checkerboard's parity. Lattices that skip corners (twice or three times the square)
/// run across squares of both colours, so the contrast flips along their edges;
/// lattices of saddles between circles and square edges, or diagonal ones, have edges
/// with no consistent contrast. Counting (rather than weighting by length) keeps every
/// super-lattice below the true one.
///
/// `contrast(k, q)` is [`edge_contrast`] from junction k to junction q.
fn lattice_score(
    g: &HashMap<(i64, i64), usize>,
    mut contrast: impl FnMut(usize, usize) -> Option<f64>,
) -> f64 {
    let mut signed = [0usize; 2];
    let mut bad = 0usize;
    for (&(i, j), &k) in g {
        let parity = (i + j).rem_euclid(2) == 0;
        for key in [(i + 1, j), (i, j + 1)] {
            let Some(&q) = g.get(&key) else { continue };
            match contrast(k, q) {
                // Square (i, j) lies on the +y side of the edge to (i+1, j) and on the −x
                // side of the edge to (i, j+1) (as seen along the edge): flip one so both
                // edge kinds report the colour of square (i, j).
                Some(c) => {
                    let positive = (c > 0.0) == (key.0 == i + 1);
                    signed[usize::from(positive == parity)] += 1;
                }
                None => bad += 1,
            }
        }
    }
    let good = signed[0].max(signed[1]);
    good as f64 - (signed[0].min(signed[1]) + bad) as f64
}

/// The contrast across the segment p → q (image on its left minus its right, as seen
/// walking from p to q in image coordinates with y down), when it is the same sign and
/// of similar size all along the segment; `None` otherwise.
fn edge_contrast(s: &Smoothed, p: [f64; 2], q: [f64; 2]) -> Option<f64> {
    let d = sub(q, p);
    let len = norm(d);
    if len < 4.0 {
        return None;
    }
    // Close enough to the edge to stay clear of the circles (which start 0.15 of a
    // square inside), far enough to see past the blur.
    let off = (0.08 * len).max(1.5);
    let n = [-d[1] / len * off, d[0] / len * off];
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for t in [0.2, 0.35, 0.5, 0.65, 0.8] {
        let m = add(p, [t * d[0], t * d[1]]);
        let c = s.sample(m[0] - n[0], m[1] - n[1])? - s.sample(m[0] + n[0], m[1] + n[1])?;
        lo = lo.min(c);
        hi = hi.max(c);
    }
    let (weak, strong) = if hi <= 0.0 {
        (-hi, -lo)
    } else if lo >= 0.0 {
        (lo, hi)
    } else {
        return None;
    };
    (strong > 1e-3 && weak > 0.35 * strong).then_some(if hi <= 0.0 { lo } else { hi })
}
