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
//! indices are candidate-major; the accumulation is tiled (blocks of parts × groups of
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
    /// `n × m` per-part statistics of the centred targets.
    pub z: Vec<f64>,
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
        let mut z = vec![0f64; n * m];
        let mut x = vec![0f64; d];
        let mut parent = vec![0f64; m];
        for (zr, &p) in z.chunks_exact_mut(m).zip(subset) {
            for ((o, &v), mu) in x.iter_mut().zip(targets.row(p as usize)).zip(&mean) {
                *o = v as f64 - mu;
            }
            lay.accumulate(zr, &x);
            for (a, b) in parent.iter_mut().zip(zr.iter()) {
                *a += b;
            }
        }
        let mut scratch = Vec::new();
        let h_parent = crit.entropies(&parent, n.max(1), &mut scratch);
        NodeData { z, parent, h_parent, n }
    }
}

/// Thresholds drawn per candidate for a node scoring `n` parts.
pub fn thresholds_for(n: usize, k: usize) -> usize {
    k.min(n.div_ceil(8)).max(1)
}

const CAND_GROUP: usize = 4;

/// Bin of feature value `f` for thresholds padded to 16 with +inf: `#{k : τ_k ≤ f}`.
#[inline(always)]
fn bin16(thr: &[f32; 16], f: f32) -> u8 {
    let mut b = 0u8;
    for t in thr {
        b += (*t <= f) as u8;
    }
    b
}

/// `acc[bin] += z_row` over a group of candidates, tiled by blocks of parts so a block of `z`
/// rows is reused from L1/L2 by every candidate of the group. Summation order per element is
/// the part order whatever the SIMD width, so results are bit-identical on every CPU path.
#[inline(always)]
fn accumulate_group_body(z: &[f64], m: usize, n: usize, bins: &[&[u8]], accs: &mut [Vec<f64>], cnts: &mut [Vec<u32>]) {
    // Keep a block of z rows around 16 KiB.
    let block = (2048 / m.max(1)).clamp(8, 256);
    let mut j0 = 0;
    while j0 < n {
        let j1 = (j0 + block).min(n);
        for ((b, acc), cnt) in bins.iter().zip(accs.iter_mut()).zip(cnts.iter_mut()) {
            for (j, &bin) in b[j0..j1].iter().enumerate() {
                let bin = bin as usize;
                cnt[bin] += 1;
                let zr = &z[(j0 + j) * m..(j0 + j + 1) * m];
                let ar = &mut acc[bin * m..(bin + 1) * m];
                for (a, v) in ar.iter_mut().zip(zr) {
                    *a += v;
                }
            }
        }
        j0 = j1;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn accumulate_group_avx2(z: &[f64], m: usize, n: usize, bins: &[&[u8]], accs: &mut [Vec<f64>], cnts: &mut [Vec<u32>]) {
    accumulate_group_body(z, m, n, bins, accs, cnts)
}

fn accumulate_group(z: &[f64], m: usize, n: usize, bins: &[&[u8]], accs: &mut [Vec<f64>], cnts: &mut [Vec<u32>]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { accumulate_group_avx2(z, m, n, bins, accs, cnts) };
            return;
        }
    }
    accumulate_group_body(z, m, n, bins, accs, cnts)
}

/// Finds the best split of a node.
///
/// `n` parts are scored, `z`-statistics gathered from `targets` rows `subset[j]`;
/// `feature(c, j)` evaluates candidate `c` on the node's `j`-th scored part. Returns `None` if
/// no threshold leaves `min_samples_leaf` parts on each side.
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
    let min_leaf = cfg.min_samples_leaf.max(1);
    if n < 2 * min_leaf || n_candidates == 0 {
        return None;
    }
    let par = cfg.parallel && n * n_candidates >= 8192;
    let node = NodeData::gather(crit, targets, subset);
    let m = crit.layout.m;
    let kmax = thresholds_for(n, cfg.n_thresholds.min(255));

    // Thresholds and bin indices per candidate (features evaluated once, candidate-major).
    let prep = |c: usize| -> (Vec<f32>, Vec<u8>) {
        let mut rng = ChaCha8Rng::seed_from_u64(mix(&[node_seed, c as u64, 0x7468_7265]));
        let mut thr: Vec<f32> = (0..kmax).map(|_| feature(c, rng.random_range(0..n))).collect();
        thr.sort_unstable_by(|a, b| a.total_cmp(b));
        thr.dedup();
        let bins: Vec<u8> = if thr.len() <= 16 {
            let mut t16 = [f32::INFINITY; 16];
            t16[..thr.len()].copy_from_slice(&thr);
            (0..n).map(|j| bin16(&t16, feature(c, j))).collect()
        } else {
            (0..n).map(|j| { let f = feature(c, j); thr.partition_point(|&t| t <= f) as u8 }).collect()
        };
        (thr, bins)
    };
    let prepared: Vec<(Vec<f32>, Vec<u8>)> = if par {
        (0..n_candidates).into_par_iter().with_min_len(2).map(prep).collect()
    } else {
        (0..n_candidates).map(prep).collect()
    };

    // Accumulate + score, by groups of candidates sharing each block of z rows.
    let score_group = |g: usize| -> Vec<Option<SplitResult>> {
        let c0 = g * CAND_GROUP;
        let c1 = (c0 + CAND_GROUP).min(n_candidates);
        let mut accs: Vec<Vec<f64>> = (c0..c1).map(|c| vec![0f64; (prepared[c].0.len() + 1) * m]).collect();
        let mut cnts: Vec<Vec<u32>> = (c0..c1).map(|c| vec![0u32; prepared[c].0.len() + 1]).collect();
        let bins: Vec<&[u8]> = (c0..c1).map(|c| prepared[c].1.as_slice()).collect();
        accumulate_group(&node.z, m, n, &bins, &mut accs, &mut cnts);
        (c0..c1)
            .enumerate()
            .map(|(gi, c)| score_thresholds(crit, &node, c, &prepared[c].0, &accs[gi], &cnts[gi], min_leaf))
            .collect()
    };
    let n_groups = n_candidates.div_ceil(CAND_GROUP);
    let results: Vec<Option<SplitResult>> = if par {
        (0..n_groups).into_par_iter().flat_map_iter(score_group).collect()
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
            best = Some(SplitResult { candidate: c, threshold: thr[t], gain: total, term_gains: g, n_left: nl, n_right: nr });
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
        let rot: Vec<f32> = (0..n).flat_map(|i| [1.0, 0.0, 0.0, (i % 7) as f32 * 0.1]).collect();
        let la: Vec<f32> = (0..2 * n).map(|_| rng.random_range(-3.0..3.0)).collect();
        let feats: Vec<f32> = (0..n * 5).map(|i| off[3 * (i / 5)] * (i % 5) as f32 + rng.random_range(-0.1..0.1)).collect();
        let raw = RawTargets { offsets: &off, rotations: &rot, link_angles: Some((&la, 2)), node_offsets: None };
        let t = build_targets(&raw, Quality::Q1Q2, 0).unwrap();
        let crit = Criterion::new(t.layout.clone(), 1e-4);
        let subset: Vec<u32> = (0..n as u32).collect();
        let f = |c: usize, j: usize| feats[j * 5 + c];
        for parallel in [false, true] {
            let cfg = SplitConfig { n_thresholds: 16, min_samples_leaf: 3, parallel };
            let b = best_split(&crit, &t, &subset, 5, &f, &cfg, 9).unwrap();
            let mask: Vec<bool> = (0..n).map(|p| feats[p * 5 + b.candidate] < b.threshold).collect();
            let g = term_gains(&raw, &mask, 1e-4, 0).unwrap();
            assert!((g[0] + g[1] - b.gain).abs() < 1e-6 * b.gain.abs().max(1.0), "{g:?} vs {b:?}");
            assert_eq!(mask.iter().filter(|&&x| x).count(), b.n_left);
            assert!(b.candidate != 0, "candidate 0 carries no information");
        }
    }
}
