//! Split search: random candidates ψ = (u, v) with random thresholds τ, all thresholds of a
//! candidate scored in one pass over the node's parts.
//!
//! For one candidate the `K` thresholds (feature values of `K` parts drawn at random from the
//! node, sorted, deduplicated) cut the feature axis into `K + 1` bins. One pass over the parts
//! adds each part's sufficient statistics `z = [x | per block upper(x xᵀ)]` of its centred target
//! vector `x` into its bin; prefix sums over the bins then give the left child of every threshold
//! (`f < τ_k`), the right child is parent − left, and each threshold costs a few small Cholesky
//! factorisations. This is the binned form of "sort, then sweep with incremental sufficient
//! statistics" and costs O(n · m) per candidate instead of O(n log n + n · m).
//!
//! Layout for speed (this accumulation is the hot loop: `n × C` part × candidate additions of
//! an `m`-vector):
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
//!
//! Documented approximations:
//! * large nodes score on a random subsample of at most `max_score_samples` parts (drawn without
//!   replacement by the tree builder, kept in part order); the split is applied to all parts;
//! * a node scoring `n` parts draws `min(K, ⌈n / 8⌉)` thresholds per candidate (small nodes
//!   have few distinct useful cut points, and every threshold costs its Cholesky factorisations).
//!
//! Determinism: every candidate draws its thresholds from its own stream (node seed, candidate
//! index), candidates are scored independently with a fixed summation order, and the best is the
//! highest total gain with ties going to the lowest (candidate, threshold), so the result is the
//! same on any number of threads.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::criterion::{Criterion, Targets, TermValues};
use crate::features::{CandidateSoa, Feature, PartGeom};
use crate::rng::mix;

/// Knobs of one split search.
#[derive(Clone, Copy, Debug)]
pub struct SplitConfig {
    pub n_thresholds: usize,
    pub min_samples_leaf: usize,
    /// Score candidates on several threads (results do not depend on it).
    pub parallel: bool,
}

/// The best split found at a node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitResult {
    /// Index of the candidate in the node's candidate list.
    pub candidate: usize,
    /// Parts with `f < threshold` go left.
    pub threshold: f32,
    /// Total gain (sum of the terms in use).
    pub gain: f64,
    /// Gains of Q1, Q2, Q3 (0 for terms not in use).
    pub term_gains: TermValues,
    /// Left/right counts among the scored parts.
    pub n_left: usize,
    pub n_right: usize,
}

/// Sufficient statistics of a node's scored parts.
pub struct NodeData {
    /// `n × z_stride(m)` per-part statistics of the centred targets in f32 (summed in f32
    /// within blocks of [`F32_BLOCK`] parts, then in f64), a count column of 1.0 at `m`, zero
    /// padding; rows 32-byte aligned.
    z: AlignedF32,
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

/// Thresholds drawn per candidate for a node scoring `n` parts.
pub fn thresholds_for(n: usize, k: usize) -> usize {
    k.min(n.div_ceil(8)).max(1)
}

/// Bin of feature value `f` for thresholds padded to 16 with +inf: `#{k : τ_k ≤ f}`.
#[inline(always)]
fn bin16(thr: &[f32; 16], f: f32) -> u8 {
    let mut b = 0u8;
    for t in thr {
        b += (*t <= f) as u8;
    }
    b
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
struct AlignedF32(Vec<Lane>);

impl AlignedF32 {
    fn zeros(len: usize) -> Self {
        debug_assert!(len % 8 == 0);
        AlignedF32(vec![Lane::default(); len / 8])
    }
    fn as_slice(&self) -> &[f32] {
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

/// Adds `z[j, k0..k0 + 8W]` of the parts `j0..j1` into `part[(gi, bin_gi(j)), k0..]` for the
/// `g` candidates `c0..c0 + g` (portable path; the loop nest keeps one row chunk in registers
/// while it is added into every candidate's bin).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn add_block_lanes<const W: usize>(
    z: &[f32],
    mp: usize,
    (j0, j1): (usize, usize),
    bins: BinMatrix<'_>,
    (c0, g, nb): (usize, usize, usize),
    k0: usize,
    part: &mut [f32],
) {
    for j in j0..j1 {
        let zr = &z[j * mp + k0..j * mp + k0 + 8 * W];
        let mut v = [[0f32; 8]; W];
        for (w, lane) in v.iter_mut().enumerate() {
            lane.copy_from_slice(&zr[8 * w..8 * w + 8]);
        }
        for gi in 0..g {
            let b = bins.at(j, c0 + gi);
            let o = (gi * nb + b as usize) * mp + k0;
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
///
/// # Safety
/// AVX2 must be available; `z` holds `j1 * mp` values, `bins` covers parts `..j1` and
/// candidates `..c0 + g`, every bin index is `< nb`, `part` holds `g * nb * mp` values,
/// `k0 + 8W <= mp`, and `z` and `part` are 32-byte aligned with `mp % 8 == 0`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn add_block_lanes_avx2<const W: usize>(
    z: &[f32],
    mp: usize,
    (j0, j1): (usize, usize),
    bins: BinMatrix<'_>,
    (c0, g, nb): (usize, usize, usize),
    k0: usize,
    part: &mut [f32],
) {
    use std::arch::x86_64::*;
    debug_assert!(z.len() >= j1 * mp && part.len() >= g * nb * mp);
    let (sj, sc) = (bins.part_stride, bins.cand_stride);
    let (zp, pp) = (z.as_ptr(), part.as_mut_ptr());
    let bp = bins.data.as_ptr().add(c0 * sc);
    for j in j0..j1 {
        let zr = zp.add(j * mp + k0);
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
            let p = pp.add((gi * nb + b) * mp + k0);
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
    macro_rules! dispatch {
        ($($w:literal)*) => {
            match lanes {
                $($w => {
                    #[cfg(target_arch = "x86_64")]
                    if avx2 {
                        // SAFETY: AVX2 checked by the caller; sizes and bin range checked in
                        // `accumulate_group`; z and part are 32-byte aligned with mp % 8 == 0.
                        unsafe { add_block_lanes_avx2::<$w>(z, mp, js, bins, grp, k0, part) };
                        return;
                    }
                    add_block_lanes::<$w>(z, mp, js, bins, grp, k0, part)
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
fn accumulate_group(
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
    accumulate_group_with(avx2, z, m, n, bins, c0, nct, nb)
}

/// Candidates per group: their f32 partial sums (one column chunk) fit in [`GROUP_BYTES`].
fn group_size(mp: usize, nb: usize) -> usize {
    let width = if mp <= 8 * MAX_LANES { mp } else { 64 };
    (GROUP_BYTES / (nb * width * 4)).max(1)
}

/// [`accumulate_group`] on the AVX2 path (`avx2`, which must be available) or the portable one.
#[allow(clippy::too_many_arguments)]
fn accumulate_group_with(
    avx2: bool,
    z: &[f32],
    m: usize,
    n: usize,
    bins: BinMatrix<'_>,
    c0: usize,
    nct: usize,
    nb: usize,
) -> Vec<f64> {
    let mp = z_stride(m);
    assert!(z.len() >= n * mp && nb <= 256);
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the caller checked AVX2; sizes checked above, bin range by `score_bins`.
        return unsafe { accumulate_avx2(z, m, n, bins, c0, nct, nb) };
    }
    accumulate_body(false, z, m, n, bins, c0, nct, nb)
}

/// # Safety
/// AVX2 must be available; see [`accumulate_body`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn accumulate_avx2(
    z: &[f32],
    m: usize,
    n: usize,
    bins: BinMatrix<'_>,
    c0: usize,
    nct: usize,
    nb: usize,
) -> Vec<f64> {
    accumulate_body(true, z, m, n, bins, c0, nct, nb)
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn accumulate_body(
    avx2: bool,
    z: &[f32],
    m: usize,
    n: usize,
    bins: BinMatrix<'_>,
    c0: usize,
    nct: usize,
    nb: usize,
) -> Vec<f64> {
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

/// The thresholds of every candidate of a node (sorted, deduplicated), drawn as the feature
/// values of `min(K, ⌈n/8⌉)` random scored parts from the candidate's own random stream.
pub struct Thresholds {
    pub values: Vec<Vec<f32>>,
    padded: Vec<[f32; 16]>,
    /// `transposed[g * 16 + k][l]` = threshold `k` of candidate `8g + l` (+inf padding).
    transposed: Vec<[f32; 8]>,
    wide: bool,
}

impl Thresholds {
    /// `feature(c, j)`: candidate `c` on the node's `j`-th scored part (`j < n`).
    pub fn draw<F: Fn(usize, usize) -> f32>(
        n: usize,
        n_candidates: usize,
        n_thresholds: usize,
        feature: &F,
        node_seed: u64,
    ) -> Self {
        let kmax = thresholds_for(n, n_thresholds.min(255));
        let values: Vec<Vec<f32>> = (0..n_candidates)
            .map(|c| {
                let mut rng = ChaCha8Rng::seed_from_u64(mix(&[node_seed, c as u64, 0x7468_7265]));
                let mut thr: Vec<f32> = (0..kmax)
                    .map(|_| feature(c, rng.random_range(0..n)))
                    .collect();
                thr.sort_unstable_by(|a, b| a.total_cmp(b));
                thr.dedup();
                thr
            })
            .collect();
        let padded: Vec<[f32; 16]> = values
            .iter()
            .map(|t| {
                let mut p = [f32::INFINITY; 16];
                let k = t.len().min(16);
                p[..k].copy_from_slice(&t[..k]);
                p
            })
            .collect();
        let mut transposed = vec![[f32::INFINITY; 8]; n_candidates.div_ceil(8) * 16];
        for (c, p) in padded.iter().enumerate() {
            for k in 0..16 {
                transposed[(c / 8) * 16 + k][c % 8] = p[k];
            }
        }
        Thresholds {
            values,
            padded,
            transposed,
            wide: kmax > 16,
        }
    }

    pub fn n_candidates(&self) -> usize {
        self.values.len()
    }

    /// Bins of several feature values of candidate `c` (`out[i] = bin(c, fs[i])`).
    #[inline]
    pub fn bins_of(&self, c: usize, fs: &[f32], out: &mut [u8]) {
        let t = &self.values[c];
        if self.wide {
            for (o, &f) in out.iter_mut().zip(fs) {
                *o = t.partition_point(|&x| x <= f) as u8;
            }
            return;
        }
        // At most 16 thresholds: count them threshold by threshold over the values (the +inf
        // padding of `bin` never counts for a finite or NaN value, so it is skipped).
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: AVX2 is available; `t.len() <= 16` (not wide).
                unsafe { bins_of_avx2(t, fs, out) };
                return;
            }
        }
        for (o, &f) in out.iter_mut().zip(fs) {
            *o = t.iter().map(|&tk| (tk <= f) as u8).sum();
        }
    }

    /// Bin of feature value `f` of candidate `c`: the number of its thresholds `≤ f`.
    #[inline(always)]
    pub fn bin(&self, c: usize, f: f32) -> u8 {
        if self.wide {
            self.values[c].partition_point(|&t| t <= f) as u8
        } else {
            bin16(&self.padded[c], f)
        }
    }
}

/// [`Thresholds::bins_of`] for at most 16 thresholds, 8 values at a time (same comparisons:
/// bit-identical).
///
/// # Safety
/// AVX2 must be available and `t.len() <= 16`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bins_of_avx2(t: &[f32], fs: &[f32], out: &mut [u8]) {
    use std::arch::x86_64::*;
    debug_assert!(t.len() <= 16);
    let k = t.len();
    let mut tv = [_mm256_setzero_ps(); 16];
    for (v, &x) in tv.iter_mut().zip(t) {
        *v = _mm256_set1_ps(x);
    }
    let n = fs.len().min(out.len());
    let count = |f: __m256| {
        let mut cnt = _mm256_setzero_si256();
        for v in &tv[..k] {
            cnt = _mm256_sub_epi32(cnt, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(*v, f)));
        }
        cnt
    };
    // 32 values per step: four counts of 8, packed to bytes (counts <= 16 never saturate;
    // the packs interleave 128-bit lanes, the permutation restores the order).
    let order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let mut j = 0;
    while j + 32 <= n {
        let p = fs.as_ptr().add(j);
        // Features usually stream from memory: fetch 2 KiB ahead (a hint; never faults).
        _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(512) as *const i8);
        _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(528) as *const i8);
        let c0 = count(_mm256_loadu_ps(p));
        let c1 = count(_mm256_loadu_ps(p.add(8)));
        let c2 = count(_mm256_loadu_ps(p.add(16)));
        let c3 = count(_mm256_loadu_ps(p.add(24)));
        let b = _mm256_packus_epi16(_mm256_packs_epi32(c0, c1), _mm256_packs_epi32(c2, c3));
        let b = _mm256_permutevar8x32_epi32(b, order);
        _mm256_storeu_si256(out.as_mut_ptr().add(j) as *mut __m256i, b);
        j += 32;
    }
    for (o, &f) in out[j..n].iter_mut().zip(&fs[j..n]) {
        *o = t.iter().map(|&tk| (tk <= f) as u8).sum();
    }
}

/// Bins of every candidate of `soa` on one part: `out[c] = bin(c, f_c(part))` (AVX2 when
/// available; the result is bit-identical to the scalar path).
#[inline]
pub fn bins_row(
    thr: &Thresholds,
    soa: &CandidateSoa,
    cands: &[Feature],
    g: &PartGeom<'_>,
    out: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if !thr.wide && g.inv != 0.0 && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is available; the store keeps a padding pixel after the last image.
            unsafe { bins_row_avx2(thr, soa, g, out) };
            return;
        }
    }
    for (c, o) in out.iter_mut().enumerate() {
        *o = thr.bin(c, g.eval(&cands[c]));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bins_row_avx2(thr: &Thresholds, soa: &CandidateSoa, g: &PartGeom<'_>, out: &mut [u8]) {
    use std::arch::x86_64::*;
    let nc = out.len();
    let inv = _mm256_set1_ps(g.inv);
    let half = _mm256_set1_ps(0.5);
    let (x, y) = (_mm256_set1_epi32(g.x), _mm256_set1_epi32(g.y));
    let (w, h) = (
        _mm256_set1_epi32(g.img.width),
        _mm256_set1_epi32(g.img.height),
    );
    let minus1 = _mm256_set1_epi32(-1);
    let zero = _mm256_setzero_si256();
    let lo16 = _mm256_set1_epi32(0xFFFF);
    let bg = _mm256_set1_ps(crate::features::BACKGROUND_MM);
    let base = g.img.data.as_ptr() as *const i32;
    let probe = |ox: __m256, oy: __m256| -> __m256 {
        let px = _mm256_add_epi32(
            x,
            _mm256_cvttps_epi32(_mm256_floor_ps(_mm256_add_ps(_mm256_mul_ps(ox, inv), half))),
        );
        let py = _mm256_add_epi32(
            y,
            _mm256_cvttps_epi32(_mm256_floor_ps(_mm256_add_ps(_mm256_mul_ps(oy, inv), half))),
        );
        let inside = _mm256_and_si256(
            _mm256_and_si256(_mm256_cmpgt_epi32(w, px), _mm256_cmpgt_epi32(px, minus1)),
            _mm256_and_si256(_mm256_cmpgt_epi32(h, py), _mm256_cmpgt_epi32(py, minus1)),
        );
        let idx = _mm256_and_si256(_mm256_add_epi32(_mm256_mullo_epi32(py, w), px), inside);
        // 32-bit gathers at byte offset 2 * idx: the low half is the pixel.
        let raw = _mm256_mask_i32gather_epi32::<2>(zero, base, idx, inside);
        let d = _mm256_and_si256(raw, lo16);
        let missing = _mm256_castsi256_ps(_mm256_cmpeq_epi32(d, zero));
        _mm256_blendv_ps(_mm256_cvtepi32_ps(d), bg, missing)
    };
    let mut lanes = [0i32; 8];
    for gi in 0..nc.div_ceil(8) {
        let o = gi * 8;
        let f = _mm256_sub_ps(
            probe(
                _mm256_loadu_ps(soa.ux.as_ptr().add(o)),
                _mm256_loadu_ps(soa.uy.as_ptr().add(o)),
            ),
            probe(
                _mm256_loadu_ps(soa.vx.as_ptr().add(o)),
                _mm256_loadu_ps(soa.vy.as_ptr().add(o)),
            ),
        );
        let mut cnt = zero;
        for k in 0..16 {
            let t = _mm256_loadu_ps(thr.transposed[gi * 16 + k].as_ptr());
            cnt = _mm256_sub_epi32(cnt, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(t, f)));
        }
        _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, cnt);
        for (l, v) in lanes.iter().take((nc - o).min(8)).enumerate() {
            out[o + l] = *v as u8;
        }
    }
}

/// Bin indices of a node's scored parts for every candidate: bin of part `j` for candidate
/// `c` at `data[j * part_stride + c * cand_stride]`.
#[derive(Clone, Copy, Debug)]
pub struct BinMatrix<'a> {
    pub data: &'a [u8],
    pub part_stride: usize,
    pub cand_stride: usize,
}

impl<'a> BinMatrix<'a> {
    /// `data[j * nc + c]` (all candidates of a part together, as the forest fills them).
    pub fn part_major(data: &'a [u8], nc: usize) -> Self {
        BinMatrix {
            data,
            part_stride: nc,
            cand_stride: 1,
        }
    }

    /// `data[c * n + j]` (one candidate's parts together, as [`fill_bins`] fills them).
    pub fn candidate_major(data: &'a [u8], n: usize) -> Self {
        BinMatrix {
            data,
            part_stride: 1,
            cand_stride: n,
        }
    }

    #[inline(always)]
    fn at(&self, j: usize, c: usize) -> u8 {
        self.data[j * self.part_stride + c * self.cand_stride]
    }
}

/// Candidate-major bin indices `bins[c * n + j]` of `n` parts (use with
/// [`BinMatrix::candidate_major`]): one candidate's features are read for a run of parts and
/// binned together (contiguous reads when the features are stored candidate-major).
pub fn fill_bins<F>(thr: &Thresholds, n: usize, feature: &F, parallel: bool) -> Vec<u8>
where
    F: Fn(usize, usize) -> f32 + Sync,
{
    let nc = thr.n_candidates();
    const TILE: usize = 1024;
    let fill = |c: usize, col: &mut [u8]| {
        let mut fbuf = [0f32; TILE];
        for (t, out) in col.chunks_mut(TILE).enumerate() {
            let fs = &mut fbuf[..out.len()];
            for (jj, f) in fs.iter_mut().enumerate() {
                *f = feature(c, t * TILE + jj);
            }
            thr.bins_of(c, fs, out);
        }
    };
    let mut bins = vec![0u8; n * nc];
    if n == 0 || nc == 0 {
        return bins;
    }
    if parallel && n * nc >= 8192 {
        bins.par_chunks_mut(n)
            .enumerate()
            .for_each(|(c, col)| fill(c, col));
    } else {
        for (c, col) in bins.chunks_mut(n).enumerate() {
            fill(c, col);
        }
    }
    bins
}

/// [`fill_bins`] for features stored candidate-major: `columns[c * n + j]` is candidate `c`
/// on the node's `j`-th scored part (each column is binned in place, no copies).
pub fn fill_bins_columns(thr: &Thresholds, n: usize, columns: &[f32], parallel: bool) -> Vec<u8> {
    let nc = thr.n_candidates();
    assert!(
        columns.len() >= n * nc,
        "columns: {} values for {n} x {nc}",
        columns.len()
    );
    let mut bins = vec![0u8; n * nc];
    if n == 0 || nc == 0 {
        return bins;
    }
    let fill = |c: usize, col: &mut [u8]| thr.bins_of(c, &columns[c * n..(c + 1) * n], col);
    if parallel && n * nc >= 8192 {
        bins.par_chunks_mut(n)
            .enumerate()
            .for_each(|(c, col)| fill(c, col));
    } else {
        for (c, col) in bins.chunks_mut(n).enumerate() {
            fill(c, col);
        }
    }
    bins
}

/// Best split of a node from its statistics, thresholds and bins.
pub fn score_bins(
    crit: &Criterion,
    node: &NodeData,
    thr: &Thresholds,
    bins: BinMatrix<'_>,
    min_samples_leaf: usize,
    parallel: bool,
) -> Option<SplitResult> {
    let (m, n, nc) = (crit.layout.m, node.n, thr.n_candidates());
    let min_leaf = min_samples_leaf.max(1);
    if n < 2 * min_leaf || nc == 0 {
        return None;
    }
    // Bins per candidate (uniform); every bin index must be below it (checked once here, so
    // the accumulation can index without checks).
    let nb = thr.values.iter().map(|t| t.len() + 1).max().unwrap_or(1);
    let last = (n - 1) * bins.part_stride + (nc - 1) * bins.cand_stride;
    assert!(
        bins.data.len() > last,
        "bins: {} values for {n} x {nc}",
        bins.data.len()
    );
    assert!(
        (bins.data.iter().copied().max().unwrap_or(0) as usize) < nb,
        "bin index out of range"
    );
    let mp = z_stride(m);
    // Tasks of candidates (each streams the node's `z` once, in blocks): one per group of
    // `group_size` when sequential; with several threads, two per thread (rounded to whole
    // groups where possible). The partition does not change any result.
    let par = parallel && n * nc >= 8192;
    let mut n_groups = nc.div_ceil(group_size(mp, nb));
    if par {
        n_groups = n_groups.min(2 * rayon::current_num_threads().max(1));
    } else {
        n_groups = 1;
    }
    let score_group = |gi: usize| -> Vec<Option<SplitResult>> {
        let (c0, c1) = (gi * nc / n_groups, (gi + 1) * nc / n_groups);
        let acc = accumulate_group(node.z.as_slice(), m, n, bins, c0, c1 - c0, nb);
        (c0..c1)
            .zip(acc.chunks_exact(nb * mp))
            .map(|(c, a)| score_thresholds(crit, node, c, &thr.values[c], a, mp, min_leaf))
            .collect()
    };
    let results: Vec<Option<SplitResult>> = if par {
        (0..n_groups)
            .into_par_iter()
            .flat_map_iter(score_group)
            .collect()
    } else {
        (0..n_groups).flat_map(score_group).collect()
    };
    let mut best: Option<SplitResult> = None;
    for r in results.into_iter().flatten() {
        if best.is_none_or(|b| r.gain > b.gain) {
            best = Some(r);
        }
    }
    best
}

/// Finds the best split of a node (thresholds, bins, statistics and scoring in one call).
///
/// `subset` are the global target rows of the node's scored parts; `feature(c, j)` evaluates
/// candidate `c` on the `j`-th of them. Returns `None` if no threshold leaves
/// `min_samples_leaf` parts on each side.
pub fn best_split<F>(
    crit: &Criterion,
    targets: &Targets,
    subset: &[u32],
    n_candidates: usize,
    feature: &F,
    cfg: &SplitConfig,
    node_seed: u64,
) -> Option<SplitResult>
where
    F: Fn(usize, usize) -> f32 + Sync,
{
    let n = subset.len();
    if n < 2 * cfg.min_samples_leaf.max(1) || n_candidates == 0 {
        return None;
    }
    let thr = Thresholds::draw(n, n_candidates, cfg.n_thresholds, feature, node_seed);
    let bins = fill_bins(&thr, n, feature, cfg.parallel);
    let node = NodeData::gather(crit, targets, subset);
    let bins = BinMatrix::candidate_major(&bins, n);
    score_bins(crit, &node, &thr, bins, cfg.min_samples_leaf, cfg.parallel)
}

/// [`best_split`] on precomputed features stored candidate-major: `columns[c * n + j]` is
/// candidate `c` on the `j`-th scored part, `n = subset.len()` (same result as `best_split`
/// with `feature(c, j) = columns[c * n + j]`).
pub fn best_split_columns(
    crit: &Criterion,
    targets: &Targets,
    subset: &[u32],
    n_candidates: usize,
    columns: &[f32],
    cfg: &SplitConfig,
    node_seed: u64,
) -> Option<SplitResult> {
    let n = subset.len();
    assert!(
        columns.len() >= n * n_candidates,
        "columns: {} values for {n} x {n_candidates}",
        columns.len()
    );
    if n < 2 * cfg.min_samples_leaf.max(1) || n_candidates == 0 {
        return None;
    }
    let feature = |c: usize, j: usize| columns[c * n + j];
    let thr = Thresholds::draw(n, n_candidates, cfg.n_thresholds, &feature, node_seed);
    let bins = fill_bins_columns(&thr, n, columns, cfg.parallel);
    let node = NodeData::gather(crit, targets, subset);
    let bins = BinMatrix::candidate_major(&bins, n);
    score_bins(crit, &node, &thr, bins, cfg.min_samples_leaf, cfg.parallel)
}

/// Scores every threshold of one candidate from its per-bin sums (`acc` rows of stride `mp`:
/// statistics, then the bin's count in column `m`).
fn score_thresholds(
    crit: &Criterion,
    node: &NodeData,
    c: usize,
    thr: &[f32],
    acc: &[f64],
    mp: usize,
    min_leaf: usize,
) -> Option<SplitResult> {
    let m = crit.layout.m;
    let n = node.n;
    let mut left = vec![0f64; m];
    let mut right = vec![0f64; m];
    let mut nl = 0usize;
    let mut scratch = Vec::new();
    let mut best: Option<SplitResult> = None;
    for t in 0..thr.len() {
        let row = &acc[t * mp..t * mp + m + 1];
        nl += row[m] as usize;
        for (l, a) in left.iter_mut().zip(&row[..m]) {
            *l += a;
        }
        let nr = n - nl;
        if nl < min_leaf || nr < min_leaf {
            continue;
        }
        for ((r, p), l) in right.iter_mut().zip(&node.parent).zip(&left) {
            *r = p - l;
        }
        let g = crit.gains(&node.h_parent, (&left, nl), (&right, nr), &mut scratch);
        let total = g[0] + g[1] + g[2];
        if !total.is_finite() {
            continue;
        }
        if best.is_none_or(|b| total > b.gain) {
            best = Some(SplitResult {
                candidate: c,
                threshold: thr[t],
                gain: total,
                term_gains: g,
                n_left: nl,
                n_right: nr,
            });
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::criterion::{build_targets, term_gains, RawTargets};
    use crate::params::Quality;

    /// The gain the search reports for its best split equals the reference gain of that split.
    #[test]
    fn reported_gain_matches_term_gains() {
        let n = 400;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let off: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let rot: Vec<f32> = (0..n)
            .flat_map(|i| [1.0, 0.0, 0.0, (i % 7) as f32 * 0.1])
            .collect();
        let la: Vec<f32> = (0..2 * n).map(|_| rng.random_range(-3.0..3.0)).collect();
        let feats: Vec<f32> = (0..n * 5)
            .map(|i| off[3 * (i / 5)] * (i % 5) as f32 + rng.random_range(-0.1..0.1))
            .collect();
        let raw = RawTargets {
            offsets: &off,
            rotations: &rot,
            link_angles: Some((&la, 2)),
            node_offsets: None,
        };
        let t = build_targets(&raw, Quality::Q1Q2, 0).unwrap();
        let crit = Criterion::new(t.layout.clone(), 1e-4);
        let subset: Vec<u32> = (0..n as u32).collect();
        let f = |c: usize, j: usize| feats[j * 5 + c];
        for parallel in [false, true] {
            let cfg = SplitConfig {
                n_thresholds: 16,
                min_samples_leaf: 3,
                parallel,
            };
            let b = best_split(&crit, &t, &subset, 5, &f, &cfg, 9).unwrap();
            let mask: Vec<bool> = (0..n)
                .map(|p| feats[p * 5 + b.candidate] < b.threshold)
                .collect();
            let g = term_gains(&raw, &mask, 1e-4, 0).unwrap();
            assert!(
                (g[0] + g[1] - b.gain).abs() < 1e-4 * b.gain.abs().max(1.0),
                "{g:?} vs {b:?}"
            );
            assert_eq!(mask.iter().filter(|&&x| x).count(), b.n_left);
            assert!(b.candidate != 0, "candidate 0 carries no information");
        }
    }

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
            let reference =
                accumulate_group_with(false, z, m, n, BinMatrix::part_major(&pm, nc), 0, nc, nb);
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
                    let all = accumulate_group_with(path, z, m, n, bins, 0, nc, nb);
                    assert!(all
                        .iter()
                        .zip(&reference)
                        .all(|(a, b)| a.to_bits() == b.to_bits()));
                    for c0 in 0..nc {
                        let one = accumulate_group_with(path, z, m, n, bins, c0, 1, nb);
                        let r = &reference[c0 * nb * mp..(c0 + 1) * nb * mp];
                        assert!(one.iter().zip(r).all(|(a, b)| a.to_bits() == b.to_bits()));
                    }
                }
            }
        }
    }

    /// The column entry point gives the closure's result, on one thread and on several.
    #[test]
    fn best_split_columns_matches_best_split() {
        let n = 3000;
        let nc = 9;
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let off: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let rot: Vec<f32> = (0..n)
            .flat_map(|i| [1.0, 0.1 * (i % 3) as f32, 0.0, (i % 7) as f32 * 0.1])
            .collect();
        let cols: Vec<f32> = (0..n * nc)
            .map(|i| {
                (off[3 * (i % n)] * 50.0 * (i / n) as f32 + rng.random_range(-9.0..9.0)).round()
            })
            .collect();
        let raw = RawTargets {
            offsets: &off,
            rotations: &rot,
            link_angles: None,
            node_offsets: None,
        };
        let t = build_targets(&raw, Quality::Q1, 0).unwrap();
        let crit = Criterion::new(t.layout.clone(), 1e-4);
        let subset: Vec<u32> = (0..n as u32).collect();
        let f = |c: usize, j: usize| cols[c * n + j];
        let mut results = Vec::new();
        for parallel in [false, true] {
            let cfg = SplitConfig {
                n_thresholds: 16,
                min_samples_leaf: 5,
                parallel,
            };
            results.push(best_split(&crit, &t, &subset, nc, &f, &cfg, 4));
            results.push(best_split_columns(&crit, &t, &subset, nc, &cols, &cfg, 4));
        }
        assert!(results[0].is_some());
        assert!(results.iter().all(|r| *r == results[0]), "{results:?}");
    }

    /// Binning many values at once equals binning them one by one (features are finite; NaN
    /// is in no bin above 0 either way).
    #[test]
    fn bins_of_matches_bin() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for k in [1usize, 5, 16, 40] {
            let vals: Vec<f32> = (0..1000)
                .map(|_| rng.random_range(-50.0..50.0f32).round())
                .collect();
            let f = |_c: usize, j: usize| vals[j];
            let thr = Thresholds::draw(vals.len(), 1, k, &f, k as u64);
            let mut probe = vals.clone();
            probe.extend([f32::NEG_INFINITY, f32::NAN, 10000.0, -10000.0]);
            let mut out = vec![0u8; probe.len()];
            thr.bins_of(0, &probe, &mut out);
            let mut out2 = vec![0u8; probe.len() - 3];
            thr.bins_of(0, &probe[3..], &mut out2);
            assert_eq!(out[3..], out2[..]);
            for (o, &v) in out.iter().zip(&probe) {
                assert_eq!(*o, thr.bin(0, v), "value {v}");
            }
        }
    }

    /// The vectorised feature + bin path equals the scalar one, including probes outside the
    /// image, on missing depth and on the last pixel of the store.
    #[test]
    fn bins_row_matches_scalar() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut store = crate::depth::DepthStore::new();
        for (w, h) in [(13usize, 9usize), (31, 17)] {
            let px: Vec<u16> = (0..w * h)
                .map(|_| {
                    if rng.random_range(0.0..1.0) < 0.2 {
                        0
                    } else {
                        rng.random_range(300..5000)
                    }
                })
                .collect();
            store.push(w, h, &px).unwrap();
        }
        let cands = crate::tree::draw_candidates(&mut rng, 21, 40.0);
        let soa = CandidateSoa::new(&cands);
        for img in 0..2 {
            let (w, h) = store.dims(img);
            for v in 0..h as i32 {
                for u in 0..w as i32 {
                    let p = [img as i32, u, v];
                    if store.center_depth(&p) == 0 {
                        continue;
                    }
                    let g = PartGeom::new(&store, &p);
                    let feat = |c: usize, _j: usize| g.eval(&cands[c]);
                    let thr = Thresholds::draw(30, cands.len(), 16, &feat, (u * 7 + v) as u64);
                    let mut a = vec![0u8; cands.len()];
                    bins_row(&thr, &soa, &cands, &g, &mut a);
                    let b: Vec<u8> = (0..cands.len())
                        .map(|c| thr.bin(c, g.eval(&cands[c])))
                        .collect();
                    assert_eq!(a, b, "part {p:?}");
                }
            }
        }
    }
}
