// Batched complex FFT of lines (rows or columns of tiles' blocks), one line per
// workgroup, in workgroup memory: a Stockham autosort over radices 2, 3 and 5, the
// lengths the CPU tiler picks (`fft::good_size`), so blocks are the CPU path's blocks.
//
// Stage with span `ns` (the product of the radices done so far) and radix r: butterfly
// j (of n / r) reads x[j + q·n/r], twiddles by e^{±2πi·(j mod ns)·q / (ns·r)}, takes
// the r-point DFT, and writes to ((j / ns)·ns·r + j mod ns) + q·ns.

struct FftParams {
    n: u32,
    // Distance between a line's consecutive elements, between consecutive lines of one
    // tile, and between tiles (in elements).
    elem_stride: u32,
    line_stride: u32,
    tile_stride: u32,
    // −1 forward, +1 inverse.
    sign: f32,
    // Applied on the way out: 1 / (width · height) on the inverse's last pass.
    scale: f32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<storage, read_write> data: array<vec2<f32>>;
@group(0) @binding(1) var<uniform> F: FftParams;
// e^{−2πi·k/n} for k in 0..n, made in double precision on the host: every twiddle of
// every stage is one of them (conjugated for the inverse). A table, not sin/cos per
// butterfly: a software rasteriser spends microseconds on each transcendental.
@group(0) @binding(2) var<storage, read> roots: array<vec2<f32>>;

// Invocations per workgroup: 256 for long lines, 64 for lines of up to 512 points
// (fewer idle invocations waiting at each stage's barriers).
override WG: u32 = 256u;
// 16 KiB of workgroup memory, the default limit every adapter offers: lines of up to
// 2048 points.
const MAX_N: u32 = 2048u;
// Values one invocation holds between a stage's read and its write: at most
// ceil((n / r) / WG) butterflies of r values, ≤ 10 for n ≤ 2048 with 256 invocations
// and for n ≤ 512 with 64.
const HELD: u32 = 16u;

var<workgroup> row_buf: array<vec2<f32>, MAX_N>;

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

// e^{sign·2πi·num/den} for den dividing n.
fn expi(num: u32, den: u32, sign: f32) -> vec2<f32> {
    let w = roots[(num % den) * (F.n / den)];
    return vec2<f32>(w.x, -sign * w.y);
}

@compute @workgroup_size(WG)
fn fft(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let n = F.n;
    let base = wid.y * F.tile_stride + wid.x * F.line_stride;
    for (var i = lid; i < n; i += WG) {
        row_buf[i] = data[base + i * F.elem_stride];
    }
    workgroupBarrier();
    var held: array<vec2<f32>, HELD>;
    var ns = 1u;
    var rem = n;
    loop {
        if rem <= 1u {
            break;
        }
        var r = 5u;
        if rem % 2u == 0u {
            r = 2u;
        } else if rem % 3u == 0u {
            r = 3u;
        }
        let m = n / r;
        var b = 0u;
        for (var j = lid; j < m; j += WG) {
            let k = j % ns;
            var v: array<vec2<f32>, 5>;
            for (var q = 0u; q < r; q++) {
                v[q] = cmul(row_buf[j + q * m], expi(k * q, ns * r, F.sign));
            }
            for (var q = 0u; q < r; q++) {
                var acc = v[0];
                for (var q2 = 1u; q2 < r; q2++) {
                    acc += cmul(v[q2], expi(q * q2, r, F.sign));
                }
                held[b * r + q] = acc;
            }
            b++;
        }
        workgroupBarrier();
        b = 0u;
        for (var j = lid; j < m; j += WG) {
            let k = j % ns;
            let to = (j / ns) * ns * r + k;
            for (var q = 0u; q < r; q++) {
                row_buf[to + q * ns] = held[b * r + q];
            }
            b++;
        }
        workgroupBarrier();
        ns *= r;
        rem /= r;
    }
    for (var i = lid; i < n; i += WG) {
        data[base + i * F.elem_stride] = row_buf[i] * F.scale;
    }
}
