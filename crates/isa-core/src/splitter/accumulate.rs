//! Per-bin sums of a node's part statistics for every candidate: the split search's hot loop
//! (`n × C` part × candidate additions of an `m`-vector), with an AVX2 path and a portable twin
//! doing the same additions in the same order (bit-identical; a test compares them).
//!
//! Layout for speed:
//! * the node's `z` rows are computed once, in f32 (`z_stride(m)` floats: the statistics, a
//!   count column of 1.0, zero padding to a multiple of 8; rows 32-byte aligned);
//! * bin indices are `u8`, part-major when the forest fills them (all candidates of a part
//!   while its image patch is in cache, [`bins_row`]) or candidate-major for precomputed
//!   feature columns ([`fill_bins_columns`]); [`BinMatrix`] carries either layout;
//! * the accumulation runs over blocks of [`F32_BLOCK`] parts (each task reads `z` from memory
//!   once); within a block, groups of candidates whose f32 partial sums fit in L1 take turns;
//!   for each part, its `z` row is loaded once into registers (up to 80 floats, wider rows in
//!   chunks of 64) and added into the partial row of its bin for every candidate of the group
//!   (AVX2 when the CPU has it, detected at run time, else portable code; same additions in
//!   the same order, so both paths give bit-identical sums); after each block the touched
//!   partial rows are added into f64 totals. Counts ride along as the count column.

use rayon::prelude::*;

use super::BinMatrix;
use crate::criterion::{Criterion, Targets, TermValues};

/// Sufficient statistics of a node's scored parts.
pub struct NodeData {
    /// `n × z_stride(m)` per-part statistics of the centred targets in f32 (summed in f32
    /// within blocks of [`F32_BLOCK`] parts, then in f64), a count column of 1.0 at `m`, zero
    /// padding; rows 32-byte aligned.
    pub(super) z: AlignedF32,
    pub parent: Vec<f64>,
    pub h_parent: TermValues,
    pub n: usize,
}

/// Parts per chunk of [`NodeData::gather`] (chunks run in parallel; their sums are combined
/// in chunk order, so the result does not depend on the number of threads).
const GATHER_CHUNK: usize = 2048;

impl NodeData {
    pub fn gather(crit: &Criterion, targets: &Targets, subset: &[u32]) -> Self {
        let lay = &crit.layout;
        let (d, m, n) = (lay.dim, lay.m, subset.len());
        let mp = z_stride(m);
        let add_in_order = |parts: Vec<Vec<f64>>, len: usize| {
            let mut out = vec![0f64; len];
            for p in parts {
                for (o, v) in out.iter_mut().zip(p) {
                    *o += v;
                }
            }
            out
        };
        let sums: Vec<Vec<f64>> = subset
            .par_chunks(GATHER_CHUNK)
            .map(|ch| {
                let mut s = vec![0f64; d];
                for &p in ch {
                    for (mu, &v) in s.iter_mut().zip(targets.row(p as usize)) {
                        *mu += v as f64;
                    }
                }
                s
            })
            .collect();
        let mut mean = add_in_order(sums, d);
        for mu in &mut mean {
            *mu /= n.max(1) as f64;
        }
        let mut z = AlignedF32::zeros(n * mp);
        let parents: Vec<Vec<f64>> = z
            .as_mut_slice()
            .par_chunks_mut(GATHER_CHUNK * mp)
            .zip(subset.par_chunks(GATHER_CHUNK))
            .map(|(zc, ch)| {
                let mut x = vec![0f64; d];
                let mut zr64 = vec![0f64; m];
                let mut parent = vec![0f64; m];
                for (zr, &p) in zc.chunks_exact_mut(mp).zip(ch) {
                    for ((o, &v), mu) in x.iter_mut().zip(targets.row(p as usize)).zip(&mean) {
                        *o = v as f64 - mu;
                    }
                    lay.statistics_of(&mut zr64, &x);
                    for ((a, o), b) in parent.iter_mut().zip(zr.iter_mut()).zip(&zr64) {
                        *a += b;
                        *o = *b as f32;
                    }
                    zr[m] = 1.0;
                }
                parent
            })
            .collect();
        let parent = add_in_order(parents, m);
        let mut scratch = Vec::new();
        let h_parent = crit.entropies(&parent, n.max(1), &mut scratch);
        NodeData {
            z,
            parent,
            h_parent,
            n,
        }
    }
}

/// Parts per f32 partial sum: the split search adds part statistics in f32 within blocks of
/// this many parts and flushes the block sums into f64 (relative error ~1e-6 of a block sum,
/// far below the ridge; the f64 criterion hook is the reference).
pub const F32_BLOCK: usize = 128;

/// 32-byte aligned lane of 8 floats (rows of `z` and of the f32 partial sums start on one).
#[derive(Clone, Copy, Default)]
#[repr(C, align(32))]
struct Lane([f32; 8]);

/// A zero-initialised, 32-byte aligned `f32` buffer of `len` (a multiple of 8) values.
pub(super) struct AlignedF32(Vec<Lane>);

impl AlignedF32 {
    fn zeros(len: usize) -> Self {
        debug_assert!(len.is_multiple_of(8));
        AlignedF32(vec![Lane::default(); len / 8])
    }
    pub(super) fn as_slice(&self) -> &[f32] {
        // SAFETY: `Lane` is `repr(C)` around `[f32; 8]` with no padding (32 bytes).
        unsafe { std::slice::from_raw_parts(self.0.as_ptr() as *const f32, self.0.len() * 8) }
    }
    fn as_mut_slice(&mut self) -> &mut [f32] {
        // SAFETY: as above.
        unsafe { std::slice::from_raw_parts_mut(self.0.as_mut_ptr() as *mut f32, self.0.len() * 8) }
    }
}

/// Row stride of the per-part statistics in the split search: the `m` statistics, one count
/// column (1.0 per part, so bin counts are summed with the statistics), zero padding to 8.
#[inline]
pub fn z_stride(m: usize) -> usize {
    (m + 1).div_ceil(8) * 8
}

/// Widest column chunk (in lanes of 8) whose `z` values stay in registers while they are
/// added into every candidate's bin; wider rows are processed in chunks of 8 lanes.
const MAX_LANES: usize = 10;

/// Target size of a candidate group's f32 partial sums (kept in L1 while a block streams by).
const GROUP_BYTES: usize = 24 * 1024;

/// One block's inputs: `z` (rows of stride `mp`), the parts `js = (j0, j1)`, their `bins`, the
/// candidates `grp = (c0, g, nb)` (first, count, bins per candidate) and the column chunk's
/// first lane `k0`.
#[derive(Clone, Copy)]
struct Block<'a> {
    z: &'a [f32],
    mp: usize,
    js: (usize, usize),
    bins: BinMatrix<'a>,
    grp: (usize, usize, usize),
    k0: usize,
}

impl Block<'_> {
    /// The block's parts.
    #[inline(always)]
    fn parts(&self) -> std::ops::Range<usize> {
        self.js.0..self.js.1
    }
    /// Where part `j`'s column chunk starts in `z`.
    #[inline(always)]
    fn z_at(&self, j: usize) -> usize {
        j * self.mp + self.k0
    }
    /// Where the chunk of the partial row of bin `b` of the group's candidate `gi` starts.
    #[inline(always)]
    fn part_at(&self, gi: usize, b: usize) -> usize {
        (gi * self.grp.2 + b) * self.mp + self.k0
    }
}

/// Adds `z[j, k0..k0 + 8W]` of the parts `j0..j1` into `part[(gi, bin_gi(j)), k0..]` for the
/// `g` candidates `c0..c0 + g` (portable path; the loop nest keeps one row chunk in registers
/// while it is added into every candidate's bin).
#[inline(always)]
fn add_block_lanes<const W: usize>(blk: Block<'_>, part: &mut [f32]) {
    let (c0, g, _) = blk.grp;
    for j in blk.parts() {
        let zr = &blk.z[blk.z_at(j)..blk.z_at(j) + 8 * W];
        let mut v = [[0f32; 8]; W];
        for (w, lane) in v.iter_mut().enumerate() {
            lane.copy_from_slice(&zr[8 * w..8 * w + 8]);
        }
        for gi in 0..g {
            let o = blk.part_at(gi, blk.bins.at(j, c0 + gi) as usize);
            let p = &mut part[o..o + 8 * W];
            for (w, lane) in v.iter().enumerate() {
                for (a, x) in p[8 * w..8 * w + 8].iter_mut().zip(lane) {
                    *a += x;
                }
            }
        }
    }
}

/// AVX2 form of [`add_block_lanes`] (same additions in the same order: bit-identical).
/// `accumulation_paths_agree` compares the two paths.
///
/// # Safety
/// AVX2 must be available; `z` holds `j1 * mp` values, `bins` covers parts `..j1` and
/// candidates `..c0 + g`, every bin index is `< nb`, `part` holds `g * nb * mp` values,
/// `k0 + 8W <= mp`, and `z` and `part` are 32-byte aligned with `mp % 8 == 0`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn add_block_lanes_avx2<const W: usize>(blk: Block<'_>, part: &mut [f32]) {
    use std::arch::x86_64::*;
    let (c0, g, nb) = blk.grp;
    let mp = blk.mp;
    debug_assert!(blk.z.len() >= blk.js.1 * mp && part.len() >= g * nb * mp);
    let (sj, sc) = (blk.bins.part_stride, blk.bins.cand_stride);
    let (zp, pp) = (blk.z.as_ptr(), part.as_mut_ptr());
    let bp = blk.bins.data.as_ptr().add(c0 * sc);
    for j in blk.parts() {
        let zr = zp.add(blk.z_at(j));
        // Rows of `z` stream from memory on the first pass over a block: fetch 4 rows ahead
        // (a hint; never faults, also past the end).
        let ahead = zr.wrapping_add(4 * mp);
        for l in 0..W.div_ceil(2) {
            _mm_prefetch::<_MM_HINT_T0>(ahead.wrapping_add(16 * l) as *const i8);
        }
        let mut v = [_mm256_setzero_ps(); W];
        for (w, lane) in v.iter_mut().enumerate() {
            *lane = _mm256_load_ps(zr.add(8 * w));
        }
        let br = bp.add(j * sj);
        for gi in 0..g {
            let b = *br.add(gi * sc) as usize;
            debug_assert!(b < nb);
            let p = pp.add(blk.part_at(gi, b));
            for (w, lane) in v.iter().enumerate() {
                let q = p.add(8 * w);
                _mm256_store_ps(q, _mm256_add_ps(_mm256_load_ps(q), *lane));
            }
        }
    }
}

/// One block of parts, one column chunk of `lanes` lanes (dispatch on the width).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn add_block(
    avx2: bool,
    lanes: usize,
    z: &[f32],
    mp: usize,
    js: (usize, usize),
    bins: BinMatrix<'_>,
    grp: (usize, usize, usize),
    k0: usize,
    part: &mut [f32],
) {
    let blk = Block {
        z,
        mp,
        js,
        bins,
        grp,
        k0,
    };
    macro_rules! dispatch {
        ($($w:literal)*) => {
            match lanes {
                $($w => {
                    #[cfg(target_arch = "x86_64")]
                    if avx2 {
                        // SAFETY: AVX2 checked by the caller; sizes and bin range checked in
                        // `accumulate_group`; z and part are 32-byte aligned with mp % 8 == 0.
                        unsafe { add_block_lanes_avx2::<$w>(blk, part) };
                        return;
                    }
                    add_block_lanes::<$w>(blk, part)
                })*
                _ => unreachable!("column chunk of {lanes} lanes"),
            }
        };
    }
    let _ = avx2;
    dispatch!(1 2 3 4 5 6 7 8 9 10)
}

/// Per-bin sums of the candidates `c0..c0 + nct`: returns `nct * nb * mp` f64 values (row
/// `(c - c0, bin)` holds the statistics and, in column `m`, the count of the parts in that
/// bin).
///
/// Loop nest: blocks of [`F32_BLOCK`] parts (read from memory once, then from cache); per
/// block, groups of `g` candidates whose f32 partial sums stay in L1 (`g` from
/// [`GROUP_BYTES`]); per group and column chunk, each part's chunk of `z` is loaded once into
/// registers and added into the partial row of its bin for every candidate of the group; the
/// touched partial rows are then flushed into f64. Per element, parts are summed in order
/// within a block and blocks in order, whatever the grouping, SIMD path or thread count, so
/// results are bit-identical on every path.
pub(super) fn accumulate_group(
    z: &[f32],
    m: usize,
    n: usize,
    bins: BinMatrix<'_>,
    c0: usize,
    nct: usize,
    nb: usize,
) -> Vec<f64> {
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    let avx2 = false;
    accumulate_group_with(
        avx2,
        Group {
            z,
            m,
            n,
            bins,
            c0,
            nct,
            nb,
        },
    )
}

/// The arguments of [`accumulate_group`], passed on to its AVX2 and portable bodies.
#[derive(Clone, Copy)]
struct Group<'a> {
    z: &'a [f32],
    m: usize,
    n: usize,
    bins: BinMatrix<'a>,
    c0: usize,
    nct: usize,
    nb: usize,
}

/// Candidates per group: their f32 partial sums (one column chunk) fit in [`GROUP_BYTES`].
pub(super) fn group_size(mp: usize, nb: usize) -> usize {
    let width = if mp <= 8 * MAX_LANES { mp } else { 64 };
    (GROUP_BYTES / (nb * width * 4)).max(1)
}

/// [`accumulate_group`] on the AVX2 path (`avx2`, which must be available) or the portable one.
fn accumulate_group_with(avx2: bool, g: Group<'_>) -> Vec<f64> {
    assert!(g.z.len() >= g.n * z_stride(g.m) && g.nb <= 256);
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the caller checked AVX2; sizes checked above, bin range by `score_bins`.
        return unsafe { accumulate_avx2(g) };
    }
    accumulate_body(false, g)
}

/// # Safety
/// AVX2 must be available; see [`accumulate_body`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn accumulate_avx2(g: Group<'_>) -> Vec<f64> {
    accumulate_body(true, g)
}

#[inline(always)]
fn accumulate_body(avx2: bool, g: Group<'_>) -> Vec<f64> {
    let Group {
        z,
        m,
        n,
        bins,
        c0,
        nct,
        nb,
    } = g;
    let mp = z_stride(m);
    let g = group_size(mp, nb).min(nct.max(1));
    let mut part = AlignedF32::zeros(g * nb * mp);
    let part = part.as_mut_slice();
    let mut acc = vec![0f64; nct * nb * mp];
    let chunks: Vec<(usize, usize)> = if mp <= 8 * MAX_LANES {
        vec![(0, mp / 8)]
    } else {
        (0..mp)
            .step_by(64)
            .map(|k0| (k0, (mp - k0).min(64) / 8))
            .collect()
    };
    let mut j0 = 0;
    while j0 < n {
        let j1 = (j0 + F32_BLOCK).min(n);
        let mut ca = 0;
        while ca < nct {
            let gg = g.min(nct - ca);
            for &(k0, lanes) in &chunks {
                add_block(
                    avx2,
                    lanes,
                    z,
                    mp,
                    (j0, j1),
                    bins,
                    (c0 + ca, gg, nb),
                    k0,
                    part,
                );
            }
            // Flush the partial rows touched by this block (count column > 0) into f64.
            let rows = gg * nb * mp;
            let acc_g = &mut acc[ca * nb * mp..ca * nb * mp + rows];
            for (pr, ar) in part[..rows]
                .chunks_exact_mut(mp)
                .zip(acc_g.chunks_exact_mut(mp))
            {
                if pr[m] != 0.0 {
                    for (a, v) in ar.iter_mut().zip(pr.iter_mut()) {
                        *a += *v as f64;
                        *v = 0.0;
                    }
                }
            }
            ca += gg;
        }
        j0 = j1;
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The accumulation gives bit-identical per-bin sums on the AVX2 and portable paths, for
    /// part-major and candidate-major bins, narrow and wide (column-chunked) rows, and any
    /// grouping of the candidates; counts land in column `m`.
    #[test]
    fn accumulation_paths_agree() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for (m, n, nc, nb) in [
            (36usize, 300usize, 7usize, 17usize),
            (64, 257, 5, 9),
            (130, 200, 3, 17),
            (7, 129, 4, 256),
        ] {
            let mp = z_stride(m);
            let mut z = AlignedF32::zeros(n * mp);
            for r in z.as_mut_slice().chunks_exact_mut(mp) {
                for v in &mut r[..m] {
                    *v = rng.random_range(-2.0..2.0);
                }
                r[m] = 1.0;
            }
            let pm: Vec<u8> = (0..n * nc).map(|_| rng.random_range(0..nb) as u8).collect();
            let mut cm = vec![0u8; n * nc];
            for j in 0..n {
                for c in 0..nc {
                    cm[c * n + j] = pm[j * nc + c];
                }
            }
            let z = z.as_slice();
            let group = |bins, c0, nct| Group {
                z,
                m,
                n,
                bins,
                c0,
                nct,
                nb,
            };
            let reference =
                accumulate_group_with(false, group(BinMatrix::part_major(&pm, nc), 0, nc));
            // Plain f64 sums of the f32 block sums, the documented order.
            for c in 0..nc {
                for b in 0..nb {
                    let cnt = (0..n).filter(|&j| pm[j * nc + c] as usize == b).count();
                    assert_eq!(reference[(c * nb + b) * mp + m], cnt as f64);
                }
            }
            let avx2 = cfg!(target_arch = "x86_64") && {
                #[cfg(target_arch = "x86_64")]
                {
                    std::arch::is_x86_feature_detected!("avx2")
                }
                #[cfg(not(target_arch = "x86_64"))]
                {
                    false
                }
            };
            for path in [false, avx2] {
                for bins in [
                    BinMatrix::part_major(&pm, nc),
                    BinMatrix::candidate_major(&cm, n),
                ] {
                    let all = accumulate_group_with(path, group(bins, 0, nc));
                    assert!(all
                        .iter()
                        .zip(&reference)
                        .all(|(a, b)| a.to_bits() == b.to_bits()));
                    for c0 in 0..nc {
                        let one = accumulate_group_with(path, group(bins, c0, 1));
                        let r = &reference[c0 * nb * mp..(c0 + 1) * nb * mp];
                        assert!(one.iter().zip(r).all(|(a, b)| a.to_bits() == b.to_bits()));
                    }
                }
            }
        }
    }
}
