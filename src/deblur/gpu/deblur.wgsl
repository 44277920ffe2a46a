// The tiled spatially varying deconvolution of `deblur::deblur_channel_plane`, on a
// batch of tiles at once: each tile's block read from the plane (reflected past its
// border) with its kernel wrapped around the block's origin, the edge taper toward the
// block blurred circularly, then half-quadratic splitting (or Wiener), then the blend
// of each tile's window into the output plane. The FFTs are `fft.wgsl`'s. Blocks are
// complex (real part used in space), tile t's block at t·bw·bh, row-major.

struct Params {
    bw: u32,
    bh: u32,
    tiles: u32,
    tile0: u32,
    count_x: u32,
    count_y: u32,
    plane_w: u32,
    plane_h: u32,
    step_x: u32,
    step_y: u32,
    ramp_x: u32,
    ramp_y: u32,
    margin_x: u32,
    margin_y: u32,
    win_x: u32,
    win_y: u32,
    taper: u32,
    row0: u32,
    rows: u32,
    // Where the y windows start in `aux` (the x windows start at `wins_x`).
    wins_y: u32,
    wins_x: u32,
    lambda: f32,
    alpha: f32,
    nsr: f32,
    // This plane's first pixel in `plane` and `out_plane` (a photo's planes share them),
    // and the batch's first tile in `kinfo`.
    plane0: u32,
    kinfo0: u32,
    pad0: u32,
    pad1: u32,
}

// One HQS step: its β and where its shrinkage table lies in `aux`.
struct Step {
    beta: f32,
    range: f32,
    inv_step: f32,
    last: f32,
    table: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> plane: array<f32>;
// The estimate read by `divergence` and `blend`, and the block written by most steps.
@group(0) @binding(2) var<storage, read_write> src: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> dst: array<vec2<f32>>;
// First the kernel, then its transform K, then λ·K̄·Y.
@group(0) @binding(4) var<storage, read_write> num: array<vec2<f32>>;
// λ·|K|²; before `prepare`, each Gaussian kernel's sum at its block's first element.
@group(0) @binding(5) var<storage, read_write> den: array<f32>;
// Per tile of the photo: (offset of its kernel in `aux`, kernel side), the side
// MADE_GAUSSIAN or MADE_SHAPE for a kernel given by its numbers (`made_tap`).
@group(0) @binding(6) var<storage, read> kinfo: array<vec2<u32>>;
// The shape models' components, the photo's kernels (taps, or a Gaussian's or a
// shape's numbers), then each plane's blend windows along x and along y, then the
// steps' shrinkage tables.
@group(0) @binding(7) var<storage, read> aux: array<f32>;
@group(0) @binding(8) var<storage, read_write> out_plane: array<f32>;
@group(1) @binding(0) var<uniform> S: Step;

const TAU: f32 = 6.283185307179586;
const HALF_PI: f32 = 1.5707963267948966;

fn reflect_index(i: i32, n: u32) -> u32 {
    let n2 = 2 * i32(n);
    let m = ((i % n2) + n2) % n2;
    if m >= i32(n) {
        return u32(n2 - 1 - m);
    }
    return u32(m);
}

// The kernel tap stored at block position x (0..n) for a kernel of side ks centred at
// c = ks / 2: tap i sits at (i − c) mod n. −1 when no tap lands there.
fn wrap_tap(x: u32, n: u32, ks: u32, c: u32) -> i32 {
    if x + c < ks {
        return i32(x + c);
    }
    if x + c >= n && x + c - n < ks {
        return i32(x + c - n);
    }
    return -1;
}

// Tap (dx, dy) from the centre of the Gaussian kernel whose numbers start at `aux[at]`:
// its exponent's coefficients a, b, c, its mean, its half side (kernels.rs's
// GaussianTaps). Unnormalised: `kernel_sum` sums them.
fn gaussian_tap(at: u32, dx: i32, dy: i32) -> f32 {
    let u = f32(dx) - aux[at + 3u];
    let v = f32(dy) - aux[at + 4u];
    return exp(-(aux[at] * u * u + aux[at + 1u] * u * v + aux[at + 2u] * v * v));
}

fn gaussian_half(at: u32) -> u32 {
    return u32(aux[at + 5u]);
}

// The shape's residual grid, Σ cᵢ · componentᵢ, at sample (i, j); 0 outside it.
fn shape_residual(at: u32, i: f32, j: f32) -> f32 {
    let side = u32(aux[at + 10u]);
    if i < 0.0 || j < 0.0 || i >= f32(side) || j >= f32(side) {
        return 0.0;
    }
    let e = u32(j) * side + u32(i);
    let components = u32(aux[at + 12u]);
    let n = u32(aux[at + 13u]);
    var acc = 0.0;
    for (var c = 0u; c < n; c++) {
        acc += aux[at + 14u + c] * aux[components + c * side * side + e];
    }
    return acc;
}

// Tap (dx, dy) from the centre of the kernel-shape model's kernel whose numbers start
// at `aux[at]` (kernels.rs's ShapeTaps): with p = d − offset, max(0, s · N(A⁻¹p) +
// R(G p)), R the residual grid read bilinearly. Unnormalised, as `gaussian_tap`.
fn shape_tap(at: u32, dx: i32, dy: i32) -> f32 {
    let p = vec2<f32>(f32(dx) - aux[at + 7u], f32(dy) - aux[at + 8u]);
    let w = vec2<f32>(aux[at] * p.x + aux[at + 1u] * p.y, aux[at + 1u] * p.x + aux[at + 2u] * p.y);
    let normal = aux[at + 3u] * exp(-0.5 * dot(w, w)) / TAU;
    let g = vec2<f32>(
        aux[at + 4u] * p.x + aux[at + 5u] * p.y,
        aux[at + 5u] * p.x + aux[at + 6u] * p.y,
    );
    let h = f32(u32(aux[at + 10u]) / 2u);
    let q = g * aux[at + 11u] + vec2<f32>(h, h);
    let q0 = floor(q);
    let f = q - q0;
    let r = (1.0 - f.x) * (1.0 - f.y) * shape_residual(at, q0.x, q0.y)
        + f.x * (1.0 - f.y) * shape_residual(at, q0.x + 1.0, q0.y)
        + (1.0 - f.x) * f.y * shape_residual(at, q0.x, q0.y + 1.0)
        + f.x * f.y * shape_residual(at, q0.x + 1.0, q0.y + 1.0);
    return max(normal + r, 0.0);
}

const MADE_GAUSSIAN: u32 = 0u;
const MADE_SHAPE: u32 = 0xffffffffu;

fn is_made(ki: vec2<u32>) -> bool {
    return ki.y == MADE_GAUSSIAN || ki.y == MADE_SHAPE;
}

// A made kernel's tap (dx, dy) from its centre, unnormalised.
fn made_tap(ki: vec2<u32>, dx: i32, dy: i32) -> f32 {
    if ki.y == MADE_SHAPE {
        return shape_tap(ki.x, dx, dy);
    }
    return gaussian_tap(ki.x, dx, dy);
}

fn made_half(ki: vec2<u32>) -> u32 {
    if ki.y == MADE_SHAPE {
        return u32(aux[ki.x + 9u]);
    }
    return gaussian_half(ki.x);
}

var<workgroup> partial: array<f32, 256>;

// One workgroup per tile: a made kernel's taps summed, into `den` at the tile's
// block's first element, so `load` makes them sum to 1 as the CPU's do.
@compute @workgroup_size(256, 1, 1)
fn kernel_sum(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let t = wid.x;
    let ki = kinfo[P.kinfo0 + t];
    var half = 0u;
    var n = 0u;
    if is_made(ki) {
        half = made_half(ki);
        n = (2u * half + 1u) * (2u * half + 1u);
    }
    let side = 2u * half + 1u;
    var acc = 0.0;
    for (var e = lid; e < n; e += 256u) {
        acc += made_tap(ki, i32(e % side) - i32(half), i32(e / side) - i32(half));
    }
    partial[lid] = acc;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s >>= 1u) {
        if lid < s {
            partial[lid] += partial[lid + s];
        }
        workgroupBarrier();
    }
    if lid == 0u && is_made(ki) {
        den[t * block_len()] = partial[0];
    }
}

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

fn conj(a: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x, -a.y);
}

// |D_x|² + |D_y|² of forward differences at frequency (u, v).
fn grad_energy(u: u32, v: u32) -> f32 {
    let gx = 2.0 - 2.0 * cos(TAU * f32(u) / f32(P.bw));
    let gy = 2.0 - 2.0 * cos(TAU * f32(v) / f32(P.bh));
    return gx + gy;
}

fn block_len() -> u32 {
    return P.bw * P.bh;
}

// Elementwise passes: x over a block's elements in 256s, y over the batch's tiles.
fn element(gid: vec3<u32>) -> i32 {
    if gid.x >= block_len() || gid.y >= P.tiles {
        return -1;
    }
    return i32(gid.y * block_len() + gid.x);
}

@compute @workgroup_size(16, 16, 1)
fn load(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let j = gid.y;
    let t = gid.z;
    if i >= P.bw || j >= P.bh || t >= P.tiles {
        return;
    }
    let g = P.tile0 + t;
    let tx = g % P.count_x;
    let ty = g / P.count_x;
    let bx = i32(tx * P.step_x) - i32(P.ramp_x / 2u) - i32(P.margin_x);
    let by = i32(ty * P.step_y) - i32(P.ramp_y / 2u) - i32(P.margin_y);
    let sx = reflect_index(bx + i32(i), P.plane_w);
    let sy = reflect_index(by + i32(j), P.plane_h);
    let v = vec2<f32>(plane[P.plane0 + sy * P.plane_w + sx], 0.0);
    let idx = t * block_len() + j * P.bw + i;
    src[idx] = v;
    dst[idx] = v;
    let ki = kinfo[P.kinfo0 + t];
    var k = 0.0;
    if is_made(ki) {
        let half = made_half(ki);
        let ii = wrap_tap(i, P.bw, 2u * half + 1u, half);
        let jj = wrap_tap(j, P.bh, 2u * half + 1u, half);
        let sum = den[t * block_len()];
        // A kernel with no positive tap stays all zero, as the CPU's normalisation
        // leaves it.
        if ii >= 0 && jj >= 0 && sum > 0.0 {
            k = made_tap(ki, ii - i32(half), jj - i32(half)) / sum;
        }
    } else {
        let c = ki.y / 2u;
        let ii = wrap_tap(i, P.bw, ki.y, c);
        let jj = wrap_tap(j, P.bh, ki.y, c);
        if ii >= 0 && jj >= 0 {
            k = aux[ki.x + u32(jj) * ki.y + u32(ii)];
        }
    }
    num[idx] = vec2<f32>(k, 0.0);
}

// The block blurred by its kernel, in frequency: dst ← dst · K.
@compute @workgroup_size(256, 1, 1)
fn blur(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = element(gid);
    if e < 0 {
        return;
    }
    dst[e] = cmul(dst[e], num[e]);
}

fn ramp(t: u32, n: u32) -> f32 {
    let d = min(t, n - 1u - t);
    let taper = min(P.taper, min(P.bw / 2u, P.bh / 2u));
    if d >= taper {
        return 1.0;
    }
    let s = sin(HALF_PI * (f32(d) + 0.5) / f32(taper));
    return s * s;
}

// The block's outer `taper` pixels blended toward the circularly blurred block (in dst,
// back in space): the block is then consistent with a periodic blur. Both buffers get
// the tapered block: src as the first estimate, dst to be transformed.
@compute @workgroup_size(16, 16, 1)
fn taper(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let j = gid.y;
    let t = gid.z;
    if i >= P.bw || j >= P.bh || t >= P.tiles {
        return;
    }
    let idx = t * block_len() + j * P.bw + i;
    let a = ramp(j, P.bh) * ramp(i, P.bw);
    let v = vec2<f32>(a * src[idx].x + (1.0 - a) * dst[idx].x, 0.0);
    src[idx] = v;
    dst[idx] = v;
}

// With K in num and Y in dst: den ← λ|K|², num ← λ·K̄·Y.
@compute @workgroup_size(256, 1, 1)
fn prepare(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = element(gid);
    if e < 0 {
        return;
    }
    let k = num[e];
    den[e] = P.lambda * dot(k, k);
    num[e] = P.lambda * cmul(conj(k), dst[e]);
}

// X = K̄Y / (|K|² + nsr·|D|²) in dst.
@compute @workgroup_size(256, 1, 1)
fn wiener(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = element(gid);
    if e < 0 {
        return;
    }
    let k = num[e];
    let p = gid.x;
    let g = grad_energy(p % P.bw, p / P.bw);
    dst[e] = cmul(conj(k), dst[e]) / (dot(k, k) + P.nsr * g);
}

// argmin_w β/2 (w − v)² + |w|^α for α ∈ (0, 1): Newton from w = |v| onto the larger
// stationary point, kept only when it beats w = 0 (solve::shrink_hyper_laplacian).
fn shrink(v: f32, beta: f32, alpha: f32) -> f32 {
    let a = abs(v);
    if a == 0.0 {
        return 0.0;
    }
    var w = a;
    for (var it = 0; it < 30; it++) {
        let f = beta * (w - a) + alpha * pow(w, alpha - 1.0);
        let df = beta + alpha * (alpha - 1.0) * pow(w, alpha - 2.0);
        if df <= 0.0 {
            return 0.0;
        }
        let next = w - f / df;
        if next <= 0.0 {
            return 0.0;
        }
        let done = abs(next - w) < 1e-6 * a;
        w = next;
        if done {
            break;
        }
    }
    let e_w = 0.5 * beta * (w - a) * (w - a) + pow(w, alpha);
    let e_0 = 0.5 * beta * a * a;
    if e_w < e_0 {
        return sign(v) * w;
    }
    return 0.0;
}

// The shrinkage as the CPU solver takes it: interpolated in its table (solve.rs's
// ShrinkLut, the same nodes), exact past the table's range. The table matters beyond
// speed: the exact shrinkage jumps at its threshold, the table ramps over one node, so
// interpolating the same table keeps the two paths apart only by rounding.
fn shrink_step(v: f32) -> f32 {
    let t = (v + S.range) * S.inv_step;
    if t >= 0.0 && t < S.last {
        let i = u32(t);
        let a = aux[S.table + i];
        let b = aux[S.table + i + 1u];
        return a + (b - a) * (t - f32(i));
    }
    return shrink(v, S.beta, P.alpha);
}

fn estimate(t: u32, i: u32, j: u32) -> f32 {
    return src[t * block_len() + j * P.bw + i].x;
}

// The w-step (shrunk forward differences, wrapped) and their divergence
// Σ Dᵀw = wx(i − 1) − wx(i) + wy(j − 1) − wy(j), into dst.
@compute @workgroup_size(16, 16, 1)
fn divergence(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let j = gid.y;
    let t = gid.z;
    if i >= P.bw || j >= P.bh || t >= P.tiles {
        return;
    }
    let ip = select(i - 1u, P.bw - 1u, i == 0u);
    let inx = select(i + 1u, 0u, i + 1u == P.bw);
    let jp = select(j - 1u, P.bh - 1u, j == 0u);
    let jn = select(j + 1u, 0u, j + 1u == P.bh);
    let x = estimate(t, i, j);
    let wx_prev = shrink_step(x - estimate(t, ip, j));
    let wx = shrink_step(estimate(t, inx, j) - x);
    let wy_prev = shrink_step(x - estimate(t, i, jp));
    let wy = shrink_step(estimate(t, i, jn) - x);
    dst[t * block_len() + j * P.bw + i] = vec2<f32>(wx_prev - wx + wy_prev - wy, 0.0);
}

// The x-step: X = (λK̄Y + β·Σ D̄W) / (λ|K|² + β·Σ|D|²), in dst.
@compute @workgroup_size(256, 1, 1)
fn update(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = element(gid);
    if e < 0 {
        return;
    }
    let p = gid.x;
    let g = grad_energy(p % P.bw, p / P.bw);
    dst[e] = (num[e] + S.beta * dst[e]) / (den[e] + S.beta * g);
}

// Adds each of the batch's tiles, weighted by its window, to the output rows
// row0..row0 + rows. One invocation per output pixel, so no two write one place.
@compute @workgroup_size(16, 16, 1)
fn blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = P.row0 + gid.y;
    if x >= P.plane_w || gid.y >= P.rows || y >= P.plane_h {
        return;
    }
    let hx = i32(P.ramp_x / 2u);
    let hy = i32(P.ramp_y / 2u);
    let cx = (i32(x) + hx) / i32(P.step_x);
    let cy = (i32(y) + hy) / i32(P.step_y);
    var acc = 0.0;
    for (var ty = cy - 1; ty <= cy + 1; ty++) {
        if ty < 0 || ty >= i32(P.count_y) {
            continue;
        }
        let wj = i32(y) - (ty * i32(P.step_y) - hy);
        if wj < 0 || wj >= i32(P.win_y) {
            continue;
        }
        for (var tx = cx - 1; tx <= cx + 1; tx++) {
            if tx < 0 || tx >= i32(P.count_x) {
                continue;
            }
            let g = u32(ty) * P.count_x + u32(tx);
            if g < P.tile0 || g >= P.tile0 + P.tiles {
                continue;
            }
            let wi = i32(x) - (tx * i32(P.step_x) - hx);
            if wi < 0 || wi >= i32(P.win_x) {
                continue;
            }
            let w = aux[P.wins_x + u32(tx) * P.win_x + u32(wi)]
                * aux[P.wins_y + u32(ty) * P.win_y + u32(wj)];
            let v = estimate(g - P.tile0, u32(wi) + P.margin_x, u32(wj) + P.margin_y);
            acc += v * w;
        }
    }
    out_plane[P.plane0 + y * P.plane_w + x] += acc;
}
