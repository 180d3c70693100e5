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
//! The pieces (as scikit-learn's splitter / partitioner split): `bins` turns feature values
//! into bin indices (thresholds, the vectorised feature + bin path), `accumulate` sums the
//! parts' statistics per bin (the hot loop, AVX2 and portable), and this module's search loop
//! scores every threshold of every candidate from those sums.
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

mod accumulate;
mod bins;

use rayon::prelude::*;

use crate::criterion::{Criterion, Targets, TermValues};

use accumulate::{accumulate_group, group_size};
pub use accumulate::{z_stride, NodeData, F32_BLOCK};
pub use bins::{bins_row, fill_bins, fill_bins_columns, thresholds_for, BinMatrix, Thresholds};

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
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The gain the search reports for its best split equals the reference gain of that split.
    #[test]
    fn reported_gain_matches_term_gains() {
        let n = 400;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let off: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let rot: Vec<f32> = (0..n)
            .flat_map(|i| crate::rotation::unit_w_positive(&[1.0, 0.0, 0.0, (i % 7) as f32 * 0.1]))
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

    /// The column entry point gives the closure's result, on one thread and on several.
    #[test]
    fn best_split_columns_matches_best_split() {
        let n = 3000;
        let nc = 9;
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let off: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let rot: Vec<f32> = (0..n)
            .flat_map(|i| {
                crate::rotation::unit_w_positive(&[
                    1.0,
                    0.1 * (i % 3) as f32,
                    0.0,
                    (i % 7) as f32 * 0.1,
                ])
            })
            .collect();
        let cols: Vec<f32> = (0..n * nc)
            .map(|i| {
                (off[3 * (i % n)] * 50.0 * (i / n) as f32 + rng.random_range(-9.0..9.0)).round()
            })
            .collect();
        let raw = RawTargets::pose(&off, &rot);
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
}
