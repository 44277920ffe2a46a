//! The edge operator's inner products over segments of kernel lines: `predict` (one dot
//! product per segment, added to its observation) and `correlate` (each segment scaled
//! by its observation's weight, added into the kernel line), in AVX2 and FMA where the
//! CPU has them and portable otherwise. Their bounds are checked once a call against
//! [`SegmentBounds`] found once a problem, so the SIMD loops run unchecked.

/// Segments of `len` samples each, where each starts in the data and the observation
/// each belongs to, with their bounds: the only way to [`Segments`] outside this module,
/// so the bounds the unchecked products trust are always the segments' own.
#[derive(Default)]
pub(super) struct SegmentSet {
    obs: Vec<u32>,
    offsets: Vec<usize>,
    len: usize,
    bounds: SegmentBounds,
}

impl SegmentSet {
    pub(super) fn new(obs: Vec<u32>, offsets: Vec<usize>, len: usize) -> Self {
        let bounds = SegmentBounds::of(&obs, &offsets, len);
        Self {
            obs,
            offsets,
            len,
            bounds,
        }
    }

    /// The segments `range`, with the bounds of the whole set (valid for any part).
    pub(super) fn range(&self, range: std::ops::Range<usize>) -> Segments<'_> {
        Segments {
            obs: &self.obs[range.clone()],
            offsets: &self.offsets[range],
            len: self.len,
            bounds: self.bounds,
        }
    }
}

/// One past the last sample any of a set of segments reads, and one past its largest
/// observation index: found once for a problem's segments, so that the products, run
/// thirty times over them, check two numbers rather than every segment.
#[derive(Clone, Copy, Debug, Default)]
struct SegmentBounds {
    end: usize,
    observations: usize,
}

impl SegmentBounds {
    fn of(obs: &[u32], offsets: &[usize], len: usize) -> Self {
        Self {
            end: offsets.iter().max().map_or(0, |&off| off + len),
            observations: obs.iter().max().map_or(0, |&o| o as usize + 1),
        }
    }
}

/// Some segments of a [`SegmentSet`].
#[derive(Clone, Copy)]
pub(super) struct Segments<'a> {
    obs: &'a [u32],
    offsets: &'a [usize],
    len: usize,
    bounds: SegmentBounds,
}

/// Samples per kernel line chunk: lines are padded to a multiple of this, two AVX
/// registers of four.
pub(super) const LANES: usize = 8;

/// Segments per register block of the AVX2 products.
const BLOCK: usize = 4;

/// Four doubles at any address, for the AVX2 products' loads and stores. Read and
/// written through this type they are one unaligned move each; `_mm256_loadu_pd` and
/// `_mm256_storeu_pd` copy through a temporary in memory, and where debug assertions
/// are on (every test build) the standard library checks each copy's operands for
/// overlap, which kept every register on the stack and cost half the tests' time.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
#[repr(C, packed)]
struct Unaligned(std::arch::x86_64::__m256d);

/// # Safety
/// Four doubles are readable from `p`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
unsafe fn load4(p: *const f64) -> std::arch::x86_64::__m256d {
    // SAFETY: the caller's contract; `Unaligned` has alignment 1.
    unsafe { p.cast::<Unaligned>().read() }.0
}

/// # Safety
/// Four doubles are writable at `p`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
unsafe fn store4(p: *mut f64, v: std::arch::x86_64::__m256d) {
    // SAFETY: the caller's contract; `Unaligned` has alignment 1.
    unsafe { p.cast::<Unaligned>().write(Unaligned(v)) }
}

/// The bounds the unchecked SIMD products rely on: `len` (a multiple of [`LANES`])
/// samples from every offset lie in the data, and every observation index is below
/// `observations`. In time independent of the number of segments: their bounds were
/// found when they were laid out.
fn check_segments(data_len: usize, segments: &Segments, len: usize, observations: usize) {
    assert!(
        segments.len == len
            && len.is_multiple_of(LANES)
            && segments.obs.len() == segments.offsets.len(),
        "segment layout"
    );
    assert!(
        segments.bounds.end <= data_len,
        "segment outside the raster"
    );
    assert!(
        segments.bounds.observations <= observations,
        "observation out of range"
    );
}

/// A segment product's form: the data, the segment offsets, the observation indices,
/// the input and the output.
#[cfg(target_arch = "x86_64")]
type UncheckedProduct = unsafe fn(&[f64], &[usize], &[u32], &[f64], &mut [f64]);
/// See [`UncheckedProduct`].
type Product = fn(&[f64], &[usize], &[u32], &[f64], &mut [f64]);

/// One segment product in its two forms: with AVX2 and FMA (where the CPU has them),
/// and portable.
struct SegmentOp {
    #[cfg(target_arch = "x86_64")]
    avx2: UncheckedProduct,
    portable: Product,
}

/// Runs `op` once [`check_segments`] has checked the bounds both forms rely on (`len`
/// samples a segment, `observations` observations).
fn run_segments(
    op: &SegmentOp,
    (len, observations): (usize, usize),
    (data, segments): (&[f64], Segments),
    input: &[f64],
    output: &mut [f64],
) {
    check_segments(data.len(), &segments, len, observations);
    let Segments { offsets, obs, .. } = segments;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA (checked just above), and every segment and
        // observation index is in bounds (asserted above).
        unsafe { (op.avx2)(data, offsets, obs, input, output) };
        return;
    }
    (op.portable)(data, offsets, obs, input, output);
}

/// `out[obs[i]] += Σ_j data[offsets[i] + j] · g[j]` over the `g.len()` (a multiple of
/// [`LANES`]) samples of each segment.
pub(super) fn predict_segments(data: &[f64], segments: Segments, g: &[f64], out: &mut [f64]) {
    const PREDICT: SegmentOp = SegmentOp {
        #[cfg(target_arch = "x86_64")]
        avx2: predict_segments_avx2,
        portable: predict_segments_portable,
    };
    run_segments(&PREDICT, (g.len(), out.len()), (data, segments), g, out);
}

/// `acc[j] += Σ_i w[obs[i]] · data[offsets[i] + j]`.
pub(super) fn correlate_segments(data: &[f64], segments: Segments, w: &[f64], acc: &mut [f64]) {
    const CORRELATE: SegmentOp = SegmentOp {
        #[cfg(target_arch = "x86_64")]
        avx2: correlate_segments_avx2,
        portable: correlate_segments_portable,
    };
    run_segments(&CORRELATE, (acc.len(), w.len()), (data, segments), w, acc);
}

fn predict_segments_portable(
    data: &[f64],
    offsets: &[usize],
    obs: &[u32],
    g: &[f64],
    out: &mut [f64],
) {
    for (&off, &o) in offsets.iter().zip(obs) {
        let mut lanes = [0.0f64; LANES];
        for (x, y) in data[off..off + g.len()]
            .chunks_exact(LANES)
            .zip(g.chunks_exact(LANES))
        {
            for l in 0..LANES {
                lanes[l] += x[l] * y[l];
            }
        }
        out[o as usize] += lanes.iter().sum::<f64>();
    }
}

fn correlate_segments_portable(
    data: &[f64],
    offsets: &[usize],
    obs: &[u32],
    w: &[f64],
    acc: &mut [f64],
) {
    let n = acc.len();
    for (&off, &o) in offsets.iter().zip(obs) {
        let wo = w[o as usize];
        for (a, &x) in acc.iter_mut().zip(&data[off..off + n]) {
            *a += wo * x;
        }
    }
}

/// The AVX2 form of [`predict_segments_portable`], in explicit 256-bit registers (the
/// compiler does not vectorise the lane loop by itself). Four segments at a time share
/// each load of the kernel line: with one, every FMA needs two loads and the loads, not
/// the FMA units, set the pace. The four segments and their eight accumulators are
/// named one by one rather than held in arrays: below the release profile's
/// optimisation level (the tests' build) the arrays stayed in memory and every FMA went
/// through the stack.
///
/// # Safety
/// The CPU must have AVX2 and FMA; every segment must lie in `data` and every
/// observation index in `out` (the caller asserts both).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn predict_segments_avx2(
    data: &[f64],
    offsets: &[usize],
    obs: &[u32],
    g: &[f64],
    out: &mut [f64],
) {
    use std::arch::x86_64::{
        __m256d, _mm256_add_pd, _mm256_fmadd_pd, _mm256_setzero_pd, _mm256_storeu_pd,
    };
    let sum = |a: __m256d, b: __m256d| {
        let mut lanes = [0.0f64; 4];
        // SAFETY: `lanes` holds four doubles.
        unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), _mm256_add_pd(a, b)) };
        lanes.iter().sum::<f64>()
    };
    let (base, gp, n) = (data.as_ptr(), g.as_ptr(), g.len());
    let (offset_blocks, rest_offsets) = offsets.as_chunks::<BLOCK>();
    let (obs_blocks, rest_obs) = obs.as_chunks::<BLOCK>();
    for (&[f0, f1, f2, f3], &[o0, o1, o2, o3]) in offset_blocks.iter().zip(obs_blocks) {
        // SAFETY: each segment lies in `data` (caller's contract).
        let (r0, r1, r2, r3) = unsafe { (base.add(f0), base.add(f1), base.add(f2), base.add(f3)) };
        // Two accumulators per segment (even and odd groups of four samples): eight
        // independent FMA chains.
        let zero = _mm256_setzero_pd();
        let (mut a0, mut b0, mut a1, mut b1) = (zero, zero, zero, zero);
        let (mut a2, mut b2, mut a3, mut b3) = (zero, zero, zero, zero);
        let mut c = 0;
        while c < n {
            // SAFETY: c + 8 ≤ n, and the kernel line and every segment have n samples.
            unsafe {
                let k0 = load4(gp.add(c));
                let k1 = load4(gp.add(c + 4));
                a0 = _mm256_fmadd_pd(load4(r0.add(c)), k0, a0);
                b0 = _mm256_fmadd_pd(load4(r0.add(c + 4)), k1, b0);
                a1 = _mm256_fmadd_pd(load4(r1.add(c)), k0, a1);
                b1 = _mm256_fmadd_pd(load4(r1.add(c + 4)), k1, b1);
                a2 = _mm256_fmadd_pd(load4(r2.add(c)), k0, a2);
                b2 = _mm256_fmadd_pd(load4(r2.add(c + 4)), k1, b2);
                a3 = _mm256_fmadd_pd(load4(r3.add(c)), k0, a3);
                b3 = _mm256_fmadd_pd(load4(r3.add(c + 4)), k1, b3);
            }
            c += LANES;
        }
        // In segment order: two segments may feed one observation.
        out[o0 as usize] += sum(a0, b0);
        out[o1 as usize] += sum(a1, b1);
        out[o2 as usize] += sum(a2, b2);
        out[o3 as usize] += sum(a3, b3);
    }
    for (&off, &o) in rest_offsets.iter().zip(rest_obs) {
        // SAFETY: the segment lies in `data` (caller's contract).
        let row = unsafe { base.add(off) };
        let (mut a0, mut a1) = (_mm256_setzero_pd(), _mm256_setzero_pd());
        let mut c = 0;
        while c < n {
            // SAFETY: as above.
            unsafe {
                a0 = _mm256_fmadd_pd(load4(row.add(c)), load4(gp.add(c)), a0);
                a1 = _mm256_fmadd_pd(load4(row.add(c + 4)), load4(gp.add(c + 4)), a1);
            }
            c += LANES;
        }
        out[o as usize] += sum(a0, a1);
    }
}

/// The AVX2 form of [`correlate_segments_portable`]. Four segments at a time share each
/// load and store of the accumulator, which otherwise cost a store per FMA; named one by
/// one, as in [`predict_segments_avx2`].
///
/// # Safety
/// As [`predict_segments_avx2`], with every observation index in `w`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn correlate_segments_avx2(
    data: &[f64],
    offsets: &[usize],
    obs: &[u32],
    w: &[f64],
    acc: &mut [f64],
) {
    use std::arch::x86_64::{_mm256_fmadd_pd, _mm256_set1_pd};
    let (base, n) = (data.as_ptr(), acc.len());
    let dst = acc.as_mut_ptr();
    let (offset_blocks, rest_offsets) = offsets.as_chunks::<BLOCK>();
    let (obs_blocks, rest_obs) = obs.as_chunks::<BLOCK>();
    for (&[f0, f1, f2, f3], &[o0, o1, o2, o3]) in offset_blocks.iter().zip(obs_blocks) {
        // SAFETY: each segment lies in `data` (caller's contract).
        let (r0, r1, r2, r3) = unsafe { (base.add(f0), base.add(f1), base.add(f2), base.add(f3)) };
        let (w0, w1) = (
            _mm256_set1_pd(w[o0 as usize]),
            _mm256_set1_pd(w[o1 as usize]),
        );
        let (w2, w3) = (
            _mm256_set1_pd(w[o2 as usize]),
            _mm256_set1_pd(w[o3 as usize]),
        );
        let mut c = 0;
        while c < n {
            // SAFETY: c + 4 ≤ n; the segments and the accumulator have n samples.
            unsafe {
                let mut v = load4(dst.add(c));
                v = _mm256_fmadd_pd(load4(r0.add(c)), w0, v);
                v = _mm256_fmadd_pd(load4(r1.add(c)), w1, v);
                v = _mm256_fmadd_pd(load4(r2.add(c)), w2, v);
                v = _mm256_fmadd_pd(load4(r3.add(c)), w3, v);
                store4(dst.add(c), v);
            }
            c += 4;
        }
    }
    for (&off, &o) in rest_offsets.iter().zip(rest_obs) {
        // SAFETY: the segment lies in `data` (caller's contract).
        let row = unsafe { base.add(off) };
        let wv = _mm256_set1_pd(w[o as usize]);
        let mut c = 0;
        while c < n {
            // SAFETY: as above.
            unsafe {
                let v = _mm256_fmadd_pd(load4(row.add(c)), wv, load4(dst.add(c)));
                store4(dst.add(c), v);
            }
            c += 4;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The SIMD products (blocks of segments plus a remainder) against the portable ones.
    #[test]
    fn simd_products_match_the_portable_ones() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        for (len, n, obs_count) in [(64usize, 4 * 23 + 3, 40usize), (24, 4 * 9, 36), (8, 2, 3)] {
            let data: Vec<f64> = (0..4000).map(|_| rng.random::<f64>()).collect();
            let offsets: Vec<usize> = (0..n)
                .map(|_| rng.random_range(0..=data.len() - len))
                .collect();
            // Distinct observations within a call, as for one line of the patches.
            let obs: Vec<u32> = (0..n).map(|i| (i % obs_count) as u32).collect();
            let obs = &obs[..n.min(obs_count)];
            let offsets = &offsets[..obs.len()];
            let g: Vec<f64> = (0..len).map(|_| rng.random::<f64>() - 0.5).collect();
            let w: Vec<f64> = (0..obs_count).map(|_| rng.random::<f64>() - 0.5).collect();
            let agree = |what: &str, fast: &[f64], slow: &[f64]| {
                for (a, b) in fast.iter().zip(slow) {
                    assert!(
                        (a - b).abs() <= 1e-12 * (1.0 + b.abs()),
                        "{what} {a} vs {b}"
                    );
                }
            };
            let set = SegmentSet::new(obs.to_vec(), offsets.to_vec(), len);
            let all = set.range(0..obs.len());
            let (mut fast, mut slow) = (vec![0.5; obs_count], vec![0.5; obs_count]);
            predict_segments(&data, all, &g, &mut fast);
            predict_segments_portable(&data, offsets, obs, &g, &mut slow);
            agree("predict", &fast, &slow);
            let (mut fast, mut slow) = (vec![0.25; len], vec![0.25; len]);
            correlate_segments(&data, all, &w, &mut fast);
            correlate_segments_portable(&data, offsets, obs, &w, &mut slow);
            agree("correlate", &fast, &slow);
        }
    }

    /// The bounds found when the segments were laid out guard the unchecked products.
    #[test]
    #[should_panic(expected = "segment outside the raster")]
    fn a_segment_past_the_data_is_refused() {
        let data = vec![1.0; 40];
        let (obs, offsets) = ([0u32, 1], [0usize, 33]);
        let mut out = vec![0.0; 2];
        predict_segments(
            &data,
            SegmentSet::new(obs.to_vec(), offsets.to_vec(), 8).range(0..2),
            &[0.5; 8],
            &mut out,
        );
    }

    #[test]
    #[should_panic(expected = "observation out of range")]
    fn an_observation_past_the_output_is_refused() {
        let data = vec![1.0; 40];
        let (obs, offsets) = ([0u32, 2], [0usize, 32]);
        let mut acc = vec![0.0; 8];
        correlate_segments(
            &data,
            SegmentSet::new(obs.to_vec(), offsets.to_vec(), 8).range(0..2),
            &[0.5; 2],
            &mut acc,
        );
    }
}
