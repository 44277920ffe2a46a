//! The kernel's least-squares problem over the observed pixel centres, applied
//! directly rather than by FFT.
//!
//! With the default weighting only real pixel centres are observed: one sub-sample in
//! s² (s² · 4 for a Bayer plane), so an FFT over the whole oversampled grid computes
//! mostly outputs nobody reads. Here each observation is the dot product of the kernel
//! with the K × K patch of the sharp raster under it, and the chart's structure does
//! most of the work:
//!
//! - a patch that is uniformly white or black sees only the kernel's sum and the
//!   offset, so all of those together are a few running sums (`FlatSums`);
//! - in a patch that holds an edge, most lines (rows, or columns) are still uniform: a
//!   uniform line of value v contributes v × that line's kernel sum, so a run of them
//!   costs one difference of prefix sums. Each patch is read along whichever axis
//!   leaves it fewer non-uniform lines (rows beside a near-horizontal edge, columns
//!   beside a near-vertical one): on chart squares about a fifth of the lines remain,
//!   and only those are dot products.
//!
//! The remaining line segments are grouped by their line index within the patch, so
//! blocks of them share each load of the kernel's line (forward product) or of the
//! accumulator line (adjoint), and the inner loops are plain SIMD dot products and
//! AXPYs over contiguous samples.
//!
//! Precision: everything is `f64`. The iteration count is the regulariser here, and
//! conjugate gradients on this ill-conditioned problem amplify an operator's rounding
//! once its directions lose orthogonality: with the products in `f32` (even with `f64`
//! accumulation across rows and blocks of observations) the estimated σ moved by 1–3 %.
//! The uniform-line sums are exact algebra, not an approximation: the operator equals
//! the FFT form to rounding (tested below).
//!
//! Unknowns, as for the FFT form: the K × K kernel (row-major), one offset and the
//! light's slope across the window (two more). The model at an observation whose patch
//! starts at raster sample (x₀, y₀) is y = Σ_{r,c} f(r, c) X(y₀ + r, x₀ + c) + c₀ +
//! shading with f(r, c) = k(K−1−r, K−1−c): a convolution read as a correlation with the
//! flipped kernel. The uniformly white observations differ only in their position, so
//! with the slope in use they are three rows of compressed normal equations rather
//! than one repeated row.

use super::solve::{LinearOperator, gradient_rows, gradient_rows_adjoint};
use segments::{LANES, SegmentSet, Segments, correlate_segments, predict_segments};

mod segments;

/// Observations whose kernel patch is uniformly black (0) or white (1): each group is
/// one repeated design row, (0, …, 0, 1) or (1, …, 1, 1), so it enters the least squares
/// as that row weighted by √n with its mean as the target. (The white group's rows are
/// [`WhiteRows`], which also carry the light's slope.)
#[derive(Clone, Copy, Debug, Default)]
struct FlatSums {
    /// Count and sum of the observed values, per group.
    n: [f64; 2],
    y: [f64; 2],
}

impl FlatSums {
    fn weight(&self, g: usize) -> f64 {
        self.n[g].sqrt()
    }

    fn target(&self, g: usize) -> f64 {
        if self.n[g] > 0.0 {
            self.y[g] / self.n[g].sqrt()
        } else {
            0.0
        }
    }
}

/// Which patches of a raster are uniform: counts of exactly-0 and exactly-1 samples in
/// every K × K window, from summed-area tables (exact integer arithmetic).
pub struct Uniformity {
    nx: usize,
    k: usize,
    zeros: Vec<u32>,
    ones: Vec<u32>,
}

impl Uniformity {
    /// Summed-area tables of `raster` (`nx × ny`).
    #[must_use]
    pub fn new(raster: &[f32], nx: usize, ny: usize, k: usize) -> Self {
        let w = nx + 1;
        let mut zeros = vec![0u32; w * (ny + 1)];
        let mut ones = vec![0u32; w * (ny + 1)];
        for y in 0..ny {
            let (mut rz, mut ro) = (0u32, 0u32);
            for x in 0..nx {
                let v = raster[y * nx + x];
                rz += u32::from(v == 0.0);
                ro += u32::from(v == 1.0);
                zeros[(y + 1) * w + x + 1] = zeros[y * w + x + 1] + rz;
                ones[(y + 1) * w + x + 1] = ones[y * w + x + 1] + ro;
            }
        }
        Self { nx, k, zeros, ones }
    }

    fn window(table: &[u32], w: usize, x0: usize, y0: usize, k: usize) -> u32 {
        table[(y0 + k) * w + x0 + k] + table[y0 * w + x0]
            - table[y0 * w + x0 + k]
            - table[(y0 + k) * w + x0]
    }

    /// The uniform value of the patch whose top-left sample is (x0, y0), if it has one.
    #[must_use]
    pub fn value(&self, x0: usize, y0: usize) -> Option<f32> {
        let (w, k) = (self.nx + 1, self.k);
        let full = (k * k) as u32;
        if Self::window(&self.zeros, w, x0, y0, k) == full {
            Some(0.0)
        } else if Self::window(&self.ones, w, x0, y0, k) == full {
            Some(1.0)
        } else {
            None
        }
    }
}

/// The raster read along one axis: lines are its rows, or (transposed) its columns.
struct Lines {
    /// Samples, each line padded with zeros to `stride` so that a segment can be read
    /// `kp` wide.
    data: Vec<f64>,
    stride: usize,
    /// Samples per line before padding.
    len: usize,
    /// `changes[line · len + i]`: how many samples of the line in 1..=i differ from the
    /// one before, so a segment is uniform when the count does not change across it.
    changes: Vec<u32>,
}

impl Lines {
    fn new(raster: &[f32], nx: usize, ny: usize, transposed: bool, pad: usize) -> Self {
        let (len, count) = if transposed { (ny, nx) } else { (nx, ny) };
        let at = |line: usize, i: usize| {
            if transposed {
                raster[i * nx + line]
            } else {
                raster[line * nx + i]
            }
        };
        let stride = len + pad;
        let mut data = vec![0.0; stride * count];
        let mut changes = vec![0u32; len * count];
        for line in 0..count {
            let mut n = 0u32;
            for i in 0..len {
                let v = at(line, i);
                data[line * stride + i] = f64::from(v);
                if i > 0 && v != at(line, i - 1) {
                    n += 1;
                }
                changes[line * len + i] = n;
            }
        }
        Self {
            data,
            stride,
            len,
            changes,
        }
    }

    fn is_uniform(&self, line: usize, start: usize, k: usize) -> bool {
        let c = &self.changes[line * self.len..];
        c[start + k - 1] == c[start]
    }

    fn value(&self, line: usize, i: usize) -> f64 {
        self.data[line * self.stride + i]
    }
}

/// A run of uniform lines `l0..l1` of one observation's patch, all of `value` (≠ 0).
#[derive(Clone, Copy, Debug)]
struct Run {
    obs: u32,
    l0: u32,
    l1: u32,
    value: f64,
}

/// The edge patches read along one axis: their non-uniform line segments grouped by line
/// index within the patch, and their uniform lines as runs.
#[derive(Default)]
struct Work {
    /// Segments of line l: `starts[l]..starts[l + 1]` index `segments`.
    starts: Vec<usize>,
    segments: SegmentSet,
    runs: Vec<Run>,
}

impl Work {
    fn segments(&self, l: usize) -> Segments<'_> {
        self.segments.range(self.starts[l]..self.starts[l + 1])
    }
}

/// The problem of one square and channel at one kernel size.
pub struct EdgeProblem {
    k: usize,
    /// K rounded up to the SIMD width: kernel lines are stored `kp` wide, zero-padded,
    /// so the inner loops have no remainder.
    kp: usize,
    /// The raster as rows, then as columns.
    lines: [Lines; 2],
    /// Edge observations' patches along the axis chosen for each, once built.
    work: [Work; 2],
    /// Top-left raster sample of each edge observation's patch, and its value.
    patches: Vec<(usize, usize)>,
    values: Vec<f64>,
    built: bool,
    flat: FlatSums,
    /// Each edge observation's position across the window (−1 to 1 along x and y).
    position: Vec<[f64; 2]>,
    /// Each edge observation's shading regressors: its position times the reference
    /// blur of the chart there (zero until [`EdgeProblem::set_shading_reference`]).
    shade: Vec<[f64; 2]>,
    /// The uniformly white observations' normal equations in (kernel sum + offset,
    /// shading x, shading y), and those compressed to three rows once built.
    white: WhiteRows,
    /// Whether the shading unknowns are in use (a reference has been set).
    shading: bool,
    smoothness: f64,
    /// Rows of the gradient penalty √λ·D k in the observation vector (0 without one).
    smooth_rows: usize,
    /// Scratch per axis: the flipped kernel along that axis's lines (`kp` wide), prefix
    /// sums of its line sums, the accumulator and the uniform lines' difference array.
    g: [Vec<f64>; 2],
    prefix: [Vec<f64>; 2],
    acc: [Vec<f64>; 2],
    diff: [Vec<f64>; 2],
    predicted: Vec<f64>,
}

impl EdgeProblem {
    /// A problem for a `k × k` kernel over `raster` (`nx` samples per row), with no
    /// observations yet.
    #[must_use]
    pub fn new(raster: &[f32], nx: usize, k: usize) -> Self {
        let kp = k.div_ceil(LANES) * LANES;
        let ny = raster.len() / nx.max(1);
        let lines = [
            Lines::new(raster, nx, ny, false, kp - k),
            Lines::new(raster, nx, ny, true, kp - k),
        ];
        Self {
            k,
            kp,
            lines,
            work: [Work::default(), Work::default()],
            patches: Vec::new(),
            values: Vec::new(),
            built: false,
            flat: FlatSums::default(),
            position: Vec::new(),
            shade: Vec::new(),
            white: WhiteRows::default(),
            shading: false,
            smoothness: 0.0,
            smooth_rows: 0,
            g: [vec![0.0; kp * k], vec![0.0; kp * k]],
            prefix: [vec![0.0; k + 1], vec![0.0; k + 1]],
            acc: [vec![0.0; kp * k], vec![0.0; kp * k]],
            diff: [vec![0.0; k + 1], vec![0.0; k + 1]],
            predicted: Vec::new(),
        }
    }

    /// Adds an observation whose patch starts at raster sample (x0, y0); `uniform` is
    /// the patch's value when it is uniform (see [`Uniformity`]).
    ///
    /// # Panics
    /// If the patch leaves the raster.
    pub fn observe(&mut self, x0: usize, y0: usize, value: f64, uniform: Option<f32>) {
        assert!(
            x0 + self.k <= self.lines[0].len && y0 + self.k <= self.lines[1].len,
            "patch outside the raster"
        );
        let (dx, dy) = (
            across(x0, self.k, self.lines[0].len),
            across(y0, self.k, self.lines[1].len),
        );
        match uniform {
            Some(v) => {
                let g = usize::from(v > 0.5);
                self.flat.n[g] += 1.0;
                self.flat.y[g] += value;
                if g == 1 {
                    self.white.add([1.0, dx, dy], value);
                }
            }
            None => {
                self.patches.push((x0, y0));
                self.values.push(value);
                self.position.push([dx, dy]);
                self.shade.push([0.0, 0.0]);
                self.built = false;
            }
        }
    }

    /// Number of observations (edge and flat).
    #[must_use]
    pub fn observations(&self) -> usize {
        self.patches.len() + (self.flat.n[0] + self.flat.n[1]) as usize
    }

    /// Adds λ·‖∇k‖² with λ = `relative` × the typical diagonal of AᵀA.
    pub fn set_smoothness(&mut self, relative: f64) {
        if !(relative > 0.0) {
            self.smoothness = 0.0;
            self.smooth_rows = 0;
            return;
        }
        let k = self.k;
        let rows = &self.lines[0];
        let diag: f64 = self
            .patches
            .iter()
            .map(|&(x0, y0)| {
                (0..k)
                    .map(|r| {
                        let at = (y0 + r) * rows.stride + x0;
                        rows.data[at..at + k].iter().map(|&v| v * v).sum::<f64>()
                    })
                    .sum::<f64>()
            })
            .sum::<f64>()
            + self.flat.n[1] * (k * k) as f64;
        self.smoothness = relative * diag / (k * k) as f64;
        self.smooth_rows = 2 * k * (k - 1);
    }

    /// Sets the shading regressors from `kernel` (`K × K`, a guess at the blur): at an
    /// edge observation the light's slope scales the blurred chart, so the regressor is
    /// the position times the chart blurred by the guess. The guess only has to be
    /// close: the error is the slope times the guess's error, second order.
    pub fn set_shading_reference(&mut self, kernel: &[f64]) {
        let mut x = kernel.to_vec();
        x.extend([0.0; 3]);
        self.shade.iter_mut().for_each(|s| *s = [0.0, 0.0]);
        let mut out = vec![0.0; self.rows()];
        self.forward(&x, &mut out);
        for ((s, p), v) in self.shade.iter_mut().zip(&self.position).zip(&out) {
            *s = [p[0] * v, p[1] * v];
        }
        // On white the guess's blur is the chart itself: the regressor is the position.
        self.shading = true;
        self.white.compress(true);
    }

    /// Whether the uniformly white observations show the light sloping across the
    /// window (fall-off, an uneven light) beyond their noise: only then are the shading
    /// unknowns worth their cost in conditioning.
    #[must_use]
    pub fn light_slopes(&self) -> bool {
        self.white.slope_is_significant()
    }

    /// Splits every edge patch into its uniform runs and non-uniform segments along the
    /// axis that leaves fewer segments, grouped by line index.
    fn build(&mut self) {
        if self.built {
            return;
        }
        self.white.compress(self.shading);
        let k = self.k;
        // (line index in the patch, observation, offset) per axis, then grouped by line.
        let mut items: [Vec<(u32, u32, usize)>; 2] = [Vec::new(), Vec::new()];
        let mut runs: [Vec<Run>; 2] = [Vec::new(), Vec::new()];
        for (o, &(x0, y0)) in self.patches.iter().enumerate() {
            let along = [(y0, x0), (x0, y0)];
            let segments = |axis: usize| {
                let (first, start) = along[axis];
                (0..k)
                    .filter(|&l| !self.lines[axis].is_uniform(first + l, start, k))
                    .count()
            };
            let axis = usize::from(segments(1) < segments(0));
            let (first, start) = along[axis];
            let lines = &self.lines[axis];
            for l in 0..k {
                let line = first + l;
                if lines.is_uniform(line, start, k) {
                    let value = lines.value(line, start);
                    if value == 0.0 {
                        continue;
                    }
                    match runs[axis].last_mut() {
                        Some(run)
                            if run.obs == o as u32 && run.l1 == l as u32 && run.value == value =>
                        {
                            run.l1 += 1;
                        }
                        _ => runs[axis].push(Run {
                            obs: o as u32,
                            l0: l as u32,
                            l1: l as u32 + 1,
                            value,
                        }),
                    }
                } else {
                    items[axis].push((l as u32, o as u32, line * lines.stride + start));
                }
            }
        }
        for (axis, (mut items, runs)) in items.into_iter().zip(runs).enumerate() {
            // Stable, so within a line the segments stay in raster order.
            items.sort_by_key(|&(l, _, _)| l);
            let mut starts = vec![0usize; k + 1];
            for &(l, _, _) in &items {
                starts[l as usize + 1] += 1;
            }
            for l in 0..k {
                starts[l + 1] += starts[l];
            }
            self.work[axis] = Work {
                starts,
                segments: SegmentSet::new(
                    items.iter().map(|&(_, o, _)| o).collect(),
                    items.iter().map(|&(_, _, off)| off).collect(),
                    self.kp,
                ),
                runs,
            };
        }
        self.built = true;
    }

    /// `predicted[o]` = the kernel part of the model at every edge observation, for the
    /// flipped kernel already laid out in `self.g`.
    fn predict_edges(&mut self) {
        let k = self.k;
        self.predicted.clear();
        self.predicted.resize(self.patches.len(), 0.0);
        for axis in 0..2 {
            let (g, prefix) = (&mut self.g[axis], &mut self.prefix[axis]);
            prefix[0] = 0.0;
            for l in 0..k {
                prefix[l + 1] = prefix[l] + g[l * self.kp..(l + 1) * self.kp].iter().sum::<f64>();
            }
            let (work, data) = (&self.work[axis], &self.lines[axis].data);
            for l in 0..k {
                predict_segments(
                    data,
                    work.segments(l),
                    &g[l * self.kp..(l + 1) * self.kp],
                    &mut self.predicted,
                );
            }
            for run in &work.runs {
                self.predicted[run.obs as usize] +=
                    run.value * (prefix[run.l1 as usize] - prefix[run.l0 as usize]);
            }
        }
    }

    /// `self.acc`/`self.diff` = the adjoint's sums for weights `w` on the edge
    /// observations.
    fn correlate(&mut self, weights: &[f64]) {
        let kp = self.kp;
        for axis in 0..2 {
            let (acc, diff) = (&mut self.acc[axis], &mut self.diff[axis]);
            acc.iter_mut().for_each(|v| *v = 0.0);
            diff.iter_mut().for_each(|v| *v = 0.0);
            let (work, data) = (&self.work[axis], &self.lines[axis].data);
            for l in 0..self.k {
                correlate_segments(
                    data,
                    work.segments(l),
                    weights,
                    &mut acc[l * kp..(l + 1) * kp],
                );
            }
            for run in &work.runs {
                let wv = weights[run.obs as usize] * run.value;
                diff[run.l0 as usize] += wv;
                diff[run.l1 as usize] -= wv;
            }
        }
    }
}

impl LinearOperator for EdgeProblem {
    fn dim(&self) -> usize {
        self.k * self.k + 3
    }

    fn rows(&self) -> usize {
        self.patches.len() + 4 + self.smooth_rows
    }

    /// Edge observations, the black row, the three white rows, then the penalty rows.
    fn forward(&mut self, x: &[f64], out: &mut [f64]) {
        self.build();
        let (k, kp) = (self.k, self.kp);
        let n = k * k;
        let (kernel, rest) = x.split_at(n);
        let (c, shade) = (rest[0], [rest[1], rest[2]]);
        // f(r, c) = k(K−1−r, K−1−c), along rows (g[0]) and along columns (g[1]).
        for r in 0..k {
            for col in 0..k {
                let f = kernel[(k - 1 - r) * k + (k - 1 - col)];
                self.g[0][r * kp + col] = f;
                self.g[1][col * kp + r] = f;
            }
        }
        self.predict_edges();
        let e = self.patches.len();
        for ((o, p), u) in out[..e].iter_mut().zip(&self.predicted).zip(&self.shade) {
            *o = p + c + shade[0] * u[0] + shade[1] * u[1];
        }
        let sum_k: f64 = kernel.iter().sum();
        out[e] = self.flat.weight(0) * c;
        let z = [sum_k + c, shade[0], shade[1]];
        out[e + 1..e + 4].copy_from_slice(&self.white.forward(z));
        if self.smooth_rows > 0 {
            gradient_rows(kernel, k, self.smoothness.sqrt(), &mut out[e + 4..]);
        }
    }

    fn adjoint(&mut self, r: &[f64], out: &mut [f64]) {
        self.build();
        let (k, kp) = (self.k, self.kp);
        let n = k * k;
        let e = self.patches.len();
        self.correlate(&r[..e]);
        let w0 = self.flat.weight(0) * r[e];
        let dz = self.white.adjoint([r[e + 1], r[e + 2], r[e + 3]]);
        // Uniform lines add their weight to every entry of their line: running sums of
        // the difference arrays.
        let mut line_add = [vec![0.0; k], vec![0.0; k]];
        for (add, diff) in line_add.iter_mut().zip(&self.diff) {
            let mut s = 0.0;
            for l in 0..k {
                s += diff[l];
                add[l] = s;
            }
        }
        for row in 0..k {
            for col in 0..k {
                out[(k - 1 - row) * k + (k - 1 - col)] = self.acc[0][row * kp + col]
                    + self.acc[1][col * kp + row]
                    + line_add[0][row]
                    + line_add[1][col]
                    + dz[0];
            }
        }
        out[n] = r[..e].iter().sum::<f64>() + w0 + dz[0];
        let (mut sx, mut sy) = (0.0, 0.0);
        for (ri, u) in r[..e].iter().zip(&self.shade) {
            sx += ri * u[0];
            sy += ri * u[1];
        }
        out[n + 1] = sx + dz[1];
        out[n + 2] = sy + dz[2];
        if self.smooth_rows > 0 {
            gradient_rows_adjoint(&r[e + 4..], k, self.smoothness.sqrt(), &mut out[..n]);
        }
    }

    fn target(&self) -> Vec<f64> {
        let mut b = self.values.clone();
        b.push(self.flat.target(0));
        // CGLS asks for the target before any product has built the problem.
        let mut white = self.white.clone();
        white.compress(self.shading);
        b.extend(white.target());
        b.resize(self.rows(), 0.0);
        b
    }
}

/// Where the centre of a patch starting at raster sample `start` lies across a raster
/// `len` samples long, from −1 to 1: the shading unknowns' coordinate.
fn across(start: usize, k: usize, len: usize) -> f64 {
    let half = (len as f64 - 1.0) / 2.0;
    (start as f64 + (k / 2) as f64 - half) / half.max(1.0)
}

/// [`EdgeProblem::light_slopes`] for observations (patch start x, y and value) given to
/// another form of the problem, over a raster `nx × ny`.
pub fn light_slopes(
    uniform: &Uniformity,
    (nx, ny): (usize, usize),
    observations: impl Iterator<Item = (usize, usize, f64)>,
) -> bool {
    let k = uniform.k;
    let mut white = WhiteRows::default();
    for (x0, y0, v) in observations {
        if uniform.value(x0, y0).is_some_and(|u| u > 0.5) {
            white.add([1.0, across(x0, k, nx), across(y0, k, ny)], v);
        }
    }
    white.slope_is_significant()
}

/// The uniformly white observations as least squares in z = (kernel sum + offset,
/// shading x, shading y): each is the row φ = (1, x, y) with its value as target. All of
/// them together equal three rows, Lᵀ z against L⁻¹ Σ φ y, with L Lᵀ = Σ φ φᵀ (Cholesky),
/// up to a constant.
#[derive(Clone, Debug, Default)]
struct WhiteRows {
    gram: [[f64; 3]; 3],
    sum: [f64; 3],
    /// Σ y², for the slope's significance.
    sum_sq: f64,
    /// Lower-triangular L (zero rows and columns where the positions do not span).
    l: [[f64; 3]; 3],
    t: [f64; 3],
}

impl WhiteRows {
    fn add(&mut self, phi: [f64; 3], value: f64) {
        for i in 0..3 {
            for j in 0..3 {
                self.gram[i][j] += phi[i] * phi[j];
            }
            self.sum[i] += phi[i] * value;
        }
        self.sum_sq += value * value;
    }

    /// Whether a slope across the window explains the white observations better than
    /// a constant, beyond what their noise would by chance: the F statistic of the two
    /// slope terms against a false-alarm rate of 1 in 1000 (for two numerator degrees
    /// of freedom and many observations, P(F > f) = e^(−f)).
    fn slope_is_significant(&self) -> bool {
        let mut full = self.clone();
        full.compress(true);
        let n = self.gram[0][0];
        if !(n > 10.0) || (1..3).any(|i| !(full.l[i][i] > 0.0)) {
            return false;
        }
        let explained = full.t[1] * full.t[1] + full.t[2] * full.t[2];
        let rss = self.sum_sq - full.t.iter().map(|t| t * t).sum::<f64>();
        let f = (explained / 2.0) / (rss.max(0.0) / (n - 3.0));
        f > -(1e-3f64).ln()
    }

    /// Without `shading`, only the first unknown: the shading directions left out.
    fn compress(&mut self, shading: bool) {
        let g = &self.gram;
        let mut l = [[0.0; 3]; 3];
        let used = if shading { 3 } else { 1 };
        let scale = g[0][0].max(g[1][1]).max(g[2][2]);
        for j in 0..used {
            let d = g[j][j] - (0..j).map(|p| l[j][p] * l[j][p]).sum::<f64>();
            // Positions that do not span a direction leave it out (a pivot of zero).
            if !(d > 1e-12 * scale) {
                continue;
            }
            l[j][j] = d.sqrt();
            for i in j + 1..used {
                l[i][j] = (g[i][j] - (0..j).map(|p| l[i][p] * l[j][p]).sum::<f64>()) / l[j][j];
            }
        }
        let mut t = [0.0; 3];
        for i in 0..3 {
            if l[i][i] > 0.0 {
                t[i] = (self.sum[i] - (0..i).map(|p| l[i][p] * t[p]).sum::<f64>()) / l[i][i];
            }
        }
        self.l = l;
        self.t = t;
    }

    /// Lᵀ z.
    fn forward(&self, z: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|j| (0..3).map(|i| self.l[i][j] * z[i]).sum())
    }

    /// L r.
    fn adjoint(&self, r: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| self.l[i][j] * r[j]).sum())
    }

    fn target(&self) -> [f64; 3] {
        self.t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::solve::{LeastSquares, NormalEquations, cg_solve, cgls_solve};
    use rand::{Rng, SeedableRng};

    /// One side of the normal equations by the FFT form, then by the edge form.
    type NormalPair = (Vec<f64>, Vec<f64>);

    /// AᵀA p for a random probe p and the right-hand sides Aᵀb, each by the FFT form
    /// then by the edge form (there AᵀA p is adjoint(forward(p))).
    fn normal_equations_both_ways(
        fft: &mut LeastSquares,
        edges: &mut EdgeProblem,
        rng: &mut impl Rng,
    ) -> (NormalPair, NormalPair) {
        let n = edges.dim();
        let probe: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        fft.apply(&probe, &mut a);
        let mut y = vec![0.0; edges.rows()];
        edges.forward(&probe, &mut y);
        edges.adjoint(&y, &mut b);
        let mut rb = vec![0.0; n];
        edges.adjoint(&edges.target(), &mut rb);
        ((a, b), (fft.rhs(), rb))
    }

    /// AᵀA p by the edge form against the FFT form, and the right-hand sides.
    fn assert_same_normal_equations(fft: &mut LeastSquares, edges: &mut EdgeProblem, seed: u64) {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let ((a, b), (ra, rb)) = normal_equations_both_ways(fft, edges, &mut rng);
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-9 * scale, "{x} vs {y}");
        }
        let scale = ra.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (x, y) in ra.iter().zip(&rb) {
            assert!((x - y).abs() < 1e-9 * scale, "{x} vs {y}");
        }
    }

    /// A chart-like raster: a square rotated a little, dark discs in it, exact 0 and 1
    /// away from the edges and coverage fractions on them; observations on a lattice of
    /// step 6 as for a Bayer plane at 3×. Patches beside near-vertical edges are read as
    /// columns, beside near-horizontal ones as rows, and the operator still equals the
    /// FFT form.
    #[test]
    fn chart_patches_read_along_either_axis_equal_the_fft_operator() {
        let (n, k) = (150usize, 19usize);
        let (c, s) = (0.03f64.cos(), 0.03f64.sin());
        let white = |x: f64, y: f64| {
            let (u, v) = (
                c * (x - 75.0) + s * (y - 75.0),
                -s * (x - 75.0) + c * (y - 75.0),
            );
            let inside = u.abs() < 50.0 && v.abs() < 50.0;
            let disc = [(0.0, 0.0), (-25.0, -25.0), (25.0, 25.0)]
                .iter()
                .any(|&(cx, cy)| (u - cx).powi(2) + (v - cy).powi(2) < 100.0);
            inside && !disc
        };
        let raster: Vec<f32> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64, (i / n) as f64);
                let mut cover = 0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        cover += usize::from(white(
                            x + (sx as f64 + 0.5) / 4.0,
                            y + (sy as f64 + 0.5) / 4.0,
                        ));
                    }
                }
                cover as f32 / 16.0
            })
            .collect();
        let uniform = Uniformity::new(&raster, n, n, k);
        let mut fft = LeastSquares::new(&raster, n, n, k);
        let mut edges = EdgeProblem::new(&raster, n, k);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for y0 in (1..=n - k).step_by(6) {
            for x0 in (2..=n - k).step_by(6) {
                let v = rng.random::<f64>();
                fft.observe(x0 + k - 1, y0 + k - 1, v);
                edges.observe(x0, y0, v, uniform.value(x0, y0));
            }
        }
        edges.build();
        let segments = |axis: usize| edges.work[axis].starts.last().copied().unwrap_or(0);
        let runs = |axis: usize| edges.work[axis].runs.len();
        assert!(
            segments(0) > 0 && segments(1) > 0 && runs(0) > 0 && runs(1) > 0,
            "both axes in use: segments {} / {}, runs {} / {}",
            segments(0),
            segments(1),
            runs(0),
            runs(1)
        );
        // The point of it: far fewer lines than patches × K are dot products.
        let all_lines = edges.patches.len() * k;
        assert!(
            segments(0) + segments(1) < all_lines / 3,
            "{} of {all_lines} lines are dot products",
            segments(0) + segments(1)
        );
        assert_same_normal_equations(&mut fft, &mut edges, 11);
        // With the shading unknowns in use, from a Gaussian guess at the blur.
        let guess = super::super::gaussian_guess(k, 3, 1.0);
        fft.set_shading_reference(&guess);
        edges.set_shading_reference(&guess);
        assert_same_normal_equations(&mut fft, &mut edges, 12);
    }

    /// A raster with uniform regions and edges, and observations on a lattice of step 3:
    /// the edge form must equal the FFT form (which is tested against a dense solve).
    #[test]
    fn edge_operator_equals_the_fft_operator() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let (nx, ny, k) = (40, 34, 5);
        let raster = flat_and_random(&mut rng, (nx, ny), 28);
        let uniform = Uniformity::new(&raster, nx, ny, k);
        let mut fft = LeastSquares::new(&raster, nx, ny, k);
        let mut edges = EdgeProblem::new(&raster, nx, k);
        let mut flat = 0;
        for y0 in (0..=ny - k).step_by(3) {
            for x0 in (0..=nx - k).step_by(3) {
                let v = rng.random::<f64>();
                // Output index of the patch starting at (x0, y0) is (x0, y0) + K − 1.
                fft.observe(x0 + k - 1, y0 + k - 1, v);
                let u = uniform.value(x0, y0);
                flat += usize::from(u.is_some());
                edges.observe(x0, y0, v, u);
            }
        }
        assert!(flat > 5, "the test needs flat patches ({flat})");
        let guess = super::super::gaussian_guess(k, 1, 0.8);
        fft.set_shading_reference(&guess);
        edges.set_shading_reference(&guess);
        let ((a, b), (ra, rb)) = normal_equations_both_ways(&mut fft, &mut edges, &mut rng);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-4 * (1.0 + x.abs()), "{x} vs {y}");
        }
        for (x, y) in ra.iter().zip(&rb) {
            assert!((x - y).abs() < 1e-4 * (1.0 + x.abs()), "{x} vs {y}");
        }
        let (sa, sb) = (
            cg_solve(&mut fft, 100, 1e-10),
            cgls_solve(&mut edges, 100, 1e-10),
        );
        for (x, y) in sa.x.iter().zip(&sb.x) {
            assert!((x - y).abs() < 1e-3 * (1.0 + x.abs()), "{x} vs {y}");
        }
    }

    /// A raster black in its top-left corner, white right of column `white_after`, random
    /// elsewhere: uniform patches of both kinds beside non-uniform ones.
    fn flat_and_random(
        rng: &mut rand_pcg::Pcg64,
        (nx, ny): (usize, usize),
        white_after: usize,
    ) -> Vec<f32> {
        (0..nx * ny)
            .map(|i| {
                let (x, y) = (i % nx, i / nx);
                if x < 15 && y < 20 {
                    0.0
                } else if x > white_after {
                    1.0
                } else {
                    rng.random::<f32>()
                }
            })
            .collect()
    }

    /// With the shading unknowns (edge regressors and the white rows' compression), the
    /// forward and adjoint products are each other's transpose.
    #[test]
    fn forward_and_adjoint_are_transposes() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let (nx, ny, k) = (40, 34, 5);
        let raster = flat_and_random(&mut rng, (nx, ny), 22);
        let uniform = Uniformity::new(&raster, nx, ny, k);
        let mut edges = EdgeProblem::new(&raster, nx, k);
        for y0 in (0..=ny - k).step_by(3) {
            for x0 in (0..=nx - k).step_by(3) {
                edges.observe(x0, y0, rng.random::<f64>(), uniform.value(x0, y0));
            }
        }
        edges.set_shading_reference(&super::super::gaussian_guess(k, 1, 0.7));
        let x: Vec<f64> = (0..edges.dim())
            .map(|_| rng.random::<f64>() - 0.5)
            .collect();
        let y: Vec<f64> = (0..edges.rows())
            .map(|_| rng.random::<f64>() - 0.5)
            .collect();
        let mut ax = vec![0.0; edges.rows()];
        edges.forward(&x, &mut ax);
        let mut aty = vec![0.0; edges.dim()];
        edges.adjoint(&y, &mut aty);
        let l: f64 = ax.iter().zip(&y).map(|(a, b)| a * b).sum();
        let r: f64 = x.iter().zip(&aty).map(|(a, b)| a * b).sum();
        assert!((l - r).abs() < 1e-9 * l.abs().max(1.0), "{l} vs {r}");
        // All three white rows carry weight: the shading directions are in use.
        assert!(
            (0..3).all(|i| edges.white.l[i][i] > 0.0),
            "{:?}",
            edges.white.l
        );
    }
}
