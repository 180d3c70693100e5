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
//! Layout for speed: the node's `z` rows are computed once (`n × m` f64); features and bin
//! indices are part-major (all candidates of a part while its image patch is in cache); the accumulation is tiled (blocks of parts × groups of
//! candidates) so a block of `z` rows is reused from cache by every candidate of a group.
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
    /// `n × m` per-part statistics of the centred targets (f32: summed in f32 within blocks
    /// of [`F32_BLOCK`] parts, then in f64).
    pub z: Vec<f32>,
    pub parent: Vec<f64>,
    pub h_parent: TermValues,
    pub n: usize,
}

impl NodeData {
    pub fn gather(crit: &Criterion, targets: &Targets, subset: &[u32]) -> Self {
        let lay = &crit.layout;
        let (d, m, n) = (lay.dim, lay.m, subset.len());
        let mut mean = vec![0f64; d];
        for &p in subset {
            for (mu, &v) in mean.iter_mut().zip(targets.row(p as usize)) {
                *mu += v as f64;
            }
        }
        for mu in &mut mean {
            *mu /= n.max(1) as f64;
        }
        let mut z = vec![0f32; n * m];
        let mut x = vec![0f64; d];
        let mut zr64 = vec![0f64; m];
        let mut parent = vec![0f64; m];
        for (zr, &p) in z.chunks_exact_mut(m).zip(subset) {
            for ((o, &v), mu) in x.iter_mut().zip(targets.row(p as usize)).zip(&mean) {
                *o = v as f64 - mu;
            }
            lay.statistics_of(&mut zr64, &x);
            for ((a, o), b) in parent.iter_mut().zip(zr.iter_mut()).zip(&zr64) {
                *a += b;
                *o = *b as f32;
            }
        }
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

const CAND_GROUP: usize = 2;

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

/// `acc[bin] += z_row` over the candidates `c0..c0 + accs.len()`, tiled by blocks of parts so
/// a block of `z` rows is reused from cache by every candidate of the group (`bins` is
/// part-major with `nc` candidates per part). Summation order per element is fixed (parts in
/// order within a block, blocks in order) whatever the SIMD width or thread count, so results
/// are bit-identical on every CPU path.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn accumulate_group_body(
    z: &[f32],
    m: usize,
    n: usize,
    bins: &[u8],
    nc: usize,
    c0: usize,
    accs: &mut [Vec<f64>],
    cnts: &mut [Vec<u32>],
) {
    let nb = accs.iter().map(|a| a.len() / m.max(1)).max().unwrap_or(0);
    let mut part = vec![0f32; nb * m];
    let mut touched = vec![false; nb];
    let mut j0 = 0;
    while j0 < n {
        let j1 = (j0 + F32_BLOCK).min(n);
        for (gi, (acc, cnt)) in accs.iter_mut().zip(cnts.iter_mut()).enumerate() {
            let c = c0 + gi;
            let nbc = acc.len() / m.max(1);
            for j in j0..j1 {
                let bin = bins[j * nc + c] as usize;
                cnt[bin] += 1;
                touched[bin] = true;
                let zr = &z[j * m..(j + 1) * m];
                let pr = &mut part[bin * m..(bin + 1) * m];
                for (a, v) in pr.iter_mut().zip(zr) {
                    *a += v;
                }
            }
            for b in 0..nbc {
                if touched[b] {
                    touched[b] = false;
                    let pr = &mut part[b * m..(b + 1) * m];
                    for (a, v) in acc[b * m..(b + 1) * m].iter_mut().zip(pr.iter_mut()) {
                        *a += *v as f64;
                        *v = 0.0;
                    }
                }
            }
        }
        j0 = j1;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn accumulate_group_avx2(
    z: &[f32],
    m: usize,
    n: usize,
    bins: &[u8],
    nc: usize,
    c0: usize,
    accs: &mut [Vec<f64>],
    cnts: &mut [Vec<u32>],
) {
    accumulate_group_body(z, m, n, bins, nc, c0, accs, cnts)
}

#[allow(clippy::too_many_arguments)]
fn accumulate_group(
    z: &[f32],
    m: usize,
    n: usize,
    bins: &[u8],
    nc: usize,
    c0: usize,
    accs: &mut [Vec<f64>],
    cnts: &mut [Vec<u32>],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { accumulate_group_avx2(z, m, n, bins, nc, c0, accs, cnts) };
            return;
        }
    }
    accumulate_group_body(z, m, n, bins, nc, c0, accs, cnts)
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

/// Part-major bin indices `bins[j * C + c]` of `n` parts (all candidates of a part are
/// evaluated together, while its image neighbourhood is in cache).
pub fn fill_bins<F>(thr: &Thresholds, n: usize, feature: &F, parallel: bool) -> Vec<u8>
where
    F: Fn(usize, usize) -> f32 + Sync,
{
    let nc = thr.n_candidates();
    let fill = |j0: usize, chunk: &mut [u8]| {
        for (jj, row) in chunk.chunks_exact_mut(nc).enumerate() {
            for (c, out) in row.iter_mut().enumerate() {
                *out = thr.bin(c, feature(c, j0 + jj));
            }
        }
    };
    let mut bins = vec![0u8; n * nc];
    if nc == 0 {
        return bins;
    }
    if parallel && n * nc >= 8192 {
        const ROWS: usize = 256;
        bins.par_chunks_mut(ROWS * nc)
            .enumerate()
            .for_each(|(k, ch)| fill(k * ROWS, ch));
    } else {
        fill(0, &mut bins);
    }
    bins
}

/// Best split of a node from its statistics, thresholds and part-major bins.
pub fn score_bins(
    crit: &Criterion,
    node: &NodeData,
    thr: &Thresholds,
    bins: &[u8],
    min_samples_leaf: usize,
    parallel: bool,
) -> Option<SplitResult> {
    let (m, n, nc) = (crit.layout.m, node.n, thr.n_candidates());
    let min_leaf = min_samples_leaf.max(1);
    if n < 2 * min_leaf || nc == 0 {
        return None;
    }
    // Accumulate + score, by groups of candidates sharing each block of z rows.
    let score_group = |g: usize| -> Vec<Option<SplitResult>> {
        let c0 = g * CAND_GROUP;
        let c1 = (c0 + CAND_GROUP).min(nc);
        let mut accs: Vec<Vec<f64>> = (c0..c1)
            .map(|c| vec![0f64; (thr.values[c].len() + 1) * m])
            .collect();
        let mut cnts: Vec<Vec<u32>> = (c0..c1)
            .map(|c| vec![0u32; thr.values[c].len() + 1])
            .collect();
        accumulate_group(&node.z, m, n, bins, nc, c0, &mut accs, &mut cnts);
        (c0..c1)
            .enumerate()
            .map(|(gi, c)| {
                score_thresholds(
                    crit,
                    node,
                    c,
                    &thr.values[c],
                    &accs[gi],
                    &cnts[gi],
                    min_leaf,
                )
            })
            .collect()
    };
    let n_groups = nc.div_ceil(CAND_GROUP);
    let results: Vec<Option<SplitResult>> = if parallel && n * nc >= 8192 {
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
    score_bins(crit, &node, &thr, &bins, cfg.min_samples_leaf, cfg.parallel)
}

/// Scores every threshold of one candidate from its per-bin statistics.
fn score_thresholds(
    crit: &Criterion,
    node: &NodeData,
    c: usize,
    thr: &[f32],
    acc: &[f64],
    cnt: &[u32],
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
        nl += cnt[t] as usize;
        for (l, a) in left.iter_mut().zip(&acc[t * m..(t + 1) * m]) {
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
