//! Split search: random candidates ψ = (u, v) with random thresholds τ, all thresholds of a
//! candidate scored in one pass over the node's parts.
//!
//! For one candidate the `K` thresholds (feature values of `K` parts drawn at random from the
//! node, sorted, deduplicated) cut the feature axis into `K + 1` bins. One pass over the parts
//! adds each part's sufficient statistics (count, Σx, per-block Σxxᵀ of its centred target
//! vector) into its bin; prefix sums over the bins then give the left child of every threshold
//! (`f < τ_k`), the right child is parent − left, and each threshold costs a few small
//! Cholesky factorisations. This is the binned form of "sort, then sweep with incremental
//! sufficient statistics" and costs O(n · m) per candidate instead of O(n log n + n · m).
//!
//! Large nodes score on a random subsample of at most `max_score_samples` parts (drawn
//! without replacement, kept in part order); the chosen split is then applied to all parts.
//!
//! Determinism: every candidate draws its thresholds from its own stream (node seed, candidate
//! index), candidates are scored independently, and the best is the highest total gain with ties
//! going to the lowest (candidate, threshold) index, so the result is the same on any number of
//! threads.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::criterion::{Criterion, TermValues, Targets};
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

/// The centred target rows of a node's scored parts and their parent statistics.
pub struct NodeData {
    /// `n × dim` centred targets.
    pub rows: Vec<f64>,
    pub parent: Vec<f64>,
    pub h_parent: TermValues,
    pub n: usize,
}

impl NodeData {
    pub fn gather(crit: &Criterion, targets: &Targets, subset: &[u32]) -> Self {
        let lay = &crit.layout;
        let d = lay.dim;
        let n = subset.len();
        let mut mean = vec![0f64; d];
        for &p in subset {
            for (m, &v) in mean.iter_mut().zip(targets.row(p as usize)) {
                *m += v as f64;
            }
        }
        for m in &mut mean {
            *m /= n.max(1) as f64;
        }
        let mut rows = vec![0f64; n * d];
        for (r, &p) in rows.chunks_exact_mut(d.max(1)).zip(subset) {
            for ((o, &v), m) in r.iter_mut().zip(targets.row(p as usize)).zip(&mean) {
                *o = v as f64 - m;
            }
        }
        let mut parent = vec![0f64; lay.m];
        for r in rows.chunks_exact(d.max(1)) {
            lay.accumulate(&mut parent, r);
        }
        let mut scratch = Vec::new();
        let h_parent = crit.entropies(&parent, n.max(1), &mut scratch);
        NodeData { rows, parent, h_parent, n }
    }
}

/// Finds the best split of a node.
///
/// `subset` are the global part indices scored; `feature(c, p)` evaluates candidate `c` on
/// global part `p`. Returns `None` if no threshold leaves `min_samples_leaf` parts on each side.
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
    F: Fn(usize, u32) -> f32 + Sync,
{
    if subset.len() < 2 * cfg.min_samples_leaf.max(1) {
        return None;
    }
    let node = NodeData::gather(crit, targets, subset);
    let eval = |c: usize| score_candidate(crit, &node, subset, c, feature, cfg, node_seed);
    let results: Vec<Option<SplitResult>> = if cfg.parallel && subset.len() * n_candidates >= 20_000 {
        (0..n_candidates).into_par_iter().map(eval).collect()
    } else {
        (0..n_candidates).map(eval).collect()
    };
    let mut best: Option<SplitResult> = None;
    for r in results.into_iter().flatten() {
        if best.is_none_or(|b| r.gain > b.gain) {
            best = Some(r);
        }
    }
    best
}

/// Scores every threshold of candidate `c`; returns its best.
pub fn score_candidate<F>(
    crit: &Criterion,
    node: &NodeData,
    subset: &[u32],
    c: usize,
    feature: &F,
    cfg: &SplitConfig,
    node_seed: u64,
) -> Option<SplitResult>
where
    F: Fn(usize, u32) -> f32 + Sync,
{
    let lay = &crit.layout;
    let (m, d, n) = (lay.m, lay.dim, node.n);
    let mut rng = ChaCha8Rng::seed_from_u64(mix(&[node_seed, c as u64, 0x7468_7265]));
    let mut thr: Vec<f32> = (0..cfg.n_thresholds.max(1))
        .map(|_| feature(c, subset[rng.random_range(0..n)]))
        .collect();
    thr.sort_unstable_by(|a, b| a.total_cmp(b));
    thr.dedup();
    let k = thr.len();
    let mut acc = vec![0f64; (k + 1) * m];
    let mut cnt = vec![0usize; k + 1];
    for (j, &p) in subset.iter().enumerate() {
        let f = feature(c, p);
        let b = thr.partition_point(|&t| t <= f);
        cnt[b] += 1;
        lay.accumulate(&mut acc[b * m..(b + 1) * m], &node.rows[j * d..(j + 1) * d]);
    }
    // Left of τ_k = bins 0..=k.
    let mut left = vec![0f64; m];
    let mut right = vec![0f64; m];
    let mut nl = 0usize;
    let mut scratch = Vec::new();
    let mut best: Option<SplitResult> = None;
    for t in 0..k {
        nl += cnt[t];
        for (l, a) in left.iter_mut().zip(&acc[t * m..(t + 1) * m]) {
            *l += a;
        }
        let nr = n - nl;
        if nl < cfg.min_samples_leaf.max(1) || nr < cfg.min_samples_leaf.max(1) {
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
