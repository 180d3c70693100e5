//! One randomised tree: the builder (breadth-first, flat node array) and traversal.
//!
//! Stopping: a node becomes a leaf at `max_depth`, with fewer than `min_samples_split` parts,
//! when no candidate threshold leaves `min_samples_leaf` scored parts on each side, or when the
//! best total gain is not above `min_gain`.
//!
//! Node ids are assigned breadth-first (root 0, children of a split at `child` and `child + 1`,
//! in node-id order within a level), so a node's random stream `mix(seed, tree, node id)` does
//! not depend on scheduling.
//!
//! ## Leaf votes
//! A leaf keeps at most `leaf_modes` weighted [`Vote`]s summarising the SSC offsets `Δx` and
//! rotations `q` of the training parts that reached it: on at most `leaf_max_points` of them (an
//! even-stride subset), with the joint distance
//! `d² = |Δx_i − Δx_j|² / h_x² + angle(q_i, q_j)² / h_θ²` (the squared angle taken as
//! `8 (1 − |q_i·q_j|)`, its second-order form), each point gets the kernel density
//! `Σ_j exp(−d²/2)`; in decreasing density the densest unassigned point opens a mode that takes
//! every unassigned point within `d² ≤ 4`. A mode's vote is the mean offset of its members,
//! their sign-aligned normalised mean quaternion (w ≥ 0) and `weight = members / points`, so the
//! weights of a leaf sum to at most 1 (less when points were left out of every mode).

use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::criterion::{Criterion, Targets, MAX_TARGET_OFFSET};
use crate::depth::{DepthStore, Part};
use crate::features::{CandidateSoa, Feature, PartGeom, MAX_FEATURE_OFFSET};
use crate::params::ForestParams;
use crate::rng::mix;
use crate::rotation::{angle_sq_approx, unit_w_positive};
use crate::splitter::{bins_row, score_bins, BinMatrix, NodeData, Thresholds};

/// A node of the flat array. Split: `f < threshold` goes to `child`, otherwise `child + 1`.
/// Leaf: `child` is the leaf index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    pub feature: Feature,
    pub threshold: f32,
    pub child: u32,
    pub is_leaf: bool,
}

impl Node {
    /// A leaf (feature and threshold unused) whose votes are leaf `index`'s.
    pub const fn leaf(index: u32) -> Node {
        Node {
            feature: Feature {
                u: [0.0; 2],
                v: [0.0; 2],
            },
            threshold: 0.0,
            child: index,
            is_leaf: true,
        }
    }
}

/// One weighted vote mode of a leaf.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vote {
    /// Fraction of the leaf's (clustered) training parts supporting this mode, in (0, 1].
    pub weight: f32,
    /// SSC offset Δx (camera frame, metres): SSC = part's 3D point + offset.
    pub offset: [f32; 3],
    /// Object rotation in the camera frame, unit quaternion (w, x, y, z) with w ≥ 0.
    pub rotation: [f32; 4],
}

/// A trained tree.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Tree {
    pub nodes: Vec<Node>,
    /// Leaf `l` owns `votes[leaf_offsets[l]..leaf_offsets[l + 1]]`.
    pub leaf_offsets: Vec<u32>,
    pub votes: Vec<Vote>,
}

impl Tree {
    /// Checks what a loaded tree must satisfy for traversal and voting to be defined and finite
    /// (a model file's trees, see `model_io`): structure (children after their parent and in
    /// range, every leaf id used once and in range, vote ranges monotone and covering the
    /// votes), split features within ±[`MAX_FEATURE_OFFSET`] and finite thresholds, vote
    /// weights in [0, 1], offsets within ±[`MAX_TARGET_OFFSET`] and unit rotations (within
    /// [`UNIT_NORM_TOLERANCE`](crate::rotation::UNIT_NORM_TOLERANCE)). The error says what and
    /// where.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let (n_nodes, n_leaves) = (self.nodes.len(), self.n_leaves());
        if n_nodes == 0 {
            return Err("has no nodes".into());
        }
        if self.leaf_offsets.is_empty() {
            return Err("has no leaf vote ranges".into());
        }
        let mut leaf_seen = vec![false; n_leaves];
        for (i, n) in self.nodes.iter().enumerate() {
            let c = n.child as usize;
            if n.is_leaf {
                if c >= n_leaves || leaf_seen[c] {
                    return Err(format!(
                        "node {i} names leaf {c} (have {n_leaves}, or used twice)"
                    ));
                }
                leaf_seen[c] = true;
                continue;
            }
            if c <= i || c >= n_nodes - 1 {
                return Err(format!(
                    "node {i} has children {c}, {} out of order/range",
                    c as u64 + 1
                ));
            }
            let f = &n.feature;
            if !n.threshold.is_finite() {
                return Err(format!("node {i}: threshold {} is not finite", n.threshold));
            }
            if f.u
                .iter()
                .chain(&f.v)
                .any(|x| x.is_nan() || x.abs() > MAX_FEATURE_OFFSET)
            {
                return Err(format!(
                    "node {i}: feature offsets {:?}, {:?} beyond ±{MAX_FEATURE_OFFSET} pixel·metres",
                    f.u, f.v
                ));
            }
        }
        let lo = &self.leaf_offsets;
        if lo[0] != 0
            || lo.windows(2).any(|w| w[0] > w[1])
            || lo[n_leaves] as usize != self.votes.len()
        {
            return Err("leaf vote ranges are inconsistent".into());
        }
        for (k, v) in self.votes.iter().enumerate() {
            if !(0.0..=1.0).contains(&v.weight) {
                return Err(format!("vote {k}: weight {} is not in [0, 1]", v.weight));
            }
            if v.offset
                .iter()
                .any(|x| x.is_nan() || x.abs() > MAX_TARGET_OFFSET)
            {
                return Err(format!(
                    "vote {k}: offset {:?} beyond ±{MAX_TARGET_OFFSET} m",
                    v.offset
                ));
            }
            if !crate::rotation::is_unit(&v.rotation) {
                return Err(format!(
                    "vote {k}: rotation {:?} is not a unit quaternion",
                    v.rotation
                ));
            }
        }
        Ok(())
    }

    pub fn n_leaves(&self) -> usize {
        self.leaf_offsets.len().saturating_sub(1)
    }

    /// Votes of leaf `leaf` (empty if out of range).
    pub fn leaf_votes(&self, leaf: usize) -> &[Vote] {
        if leaf + 1 >= self.leaf_offsets.len() {
            return &[];
        }
        &self.votes[self.leaf_offsets[leaf] as usize..self.leaf_offsets[leaf + 1] as usize]
    }

    /// Leaf index reached by a part (the part must be valid for `store`).
    #[inline]
    pub fn leaf_of(&self, store: &DepthStore, p: &Part) -> u32 {
        self.leaf_of_geom(&PartGeom::new(store, p))
    }

    /// Leaf index reached by a part whose geometry is resolved (see [`PartGeom`]); evaluates
    /// exactly the features of [`Feature::eval`].
    #[inline]
    pub fn leaf_of_geom(&self, g: &PartGeom<'_>) -> u32 {
        let mut i = 0usize;
        loop {
            let nd = &self.nodes[i];
            if nd.is_leaf {
                return nd.child;
            }
            let f = g.eval(&nd.feature);
            i = nd.child as usize + (f >= nd.threshold) as usize;
        }
    }

    /// Depth of the deepest leaf.
    pub fn depth(&self) -> usize {
        let mut depth = vec![0usize; self.nodes.len()];
        let mut best = 0;
        for i in 0..self.nodes.len() {
            let nd = &self.nodes[i];
            best = best.max(depth[i]);
            if !nd.is_leaf {
                depth[nd.child as usize] = depth[i] + 1;
                depth[nd.child as usize + 1] = depth[i] + 1;
            }
        }
        best
    }
}

/// Everything a tree builder reads.
pub struct TrainContext<'a> {
    pub params: &'a ForestParams,
    pub store: &'a DepthStore,
    pub parts: &'a [Part],
    /// Raw `(n, 3)` offsets and `(n, 4)` quaternions (for leaf votes).
    pub offsets: &'a [f32],
    pub rotations: &'a [f32],
    pub targets: &'a Targets,
    pub crit: &'a Criterion,
}

enum Outcome {
    Leaf(Vec<Vote>),
    Split {
        feature: Feature,
        threshold: f32,
        left: Vec<u32>,
        right: Vec<u32>,
    },
}

/// Random feature candidates of a node.
pub fn draw_candidates(rng: &mut ChaCha8Rng, n: usize, max_offset: f32) -> Vec<Feature> {
    (0..n)
        .map(|_| Feature {
            u: [
                rng.random_range(-max_offset..=max_offset),
                rng.random_range(-max_offset..=max_offset),
            ],
            v: [
                rng.random_range(-max_offset..=max_offset),
                rng.random_range(-max_offset..=max_offset),
            ],
        })
        .collect()
}

/// A node of the current level that will be scored.
struct Plan {
    id: usize,
    idx: Vec<u32>,
    /// Scored parts (all of `idx`, or a sorted random subsample), global indices.
    subset: Vec<u32>,
    cands: Vec<Feature>,
    soa: CandidateSoa,
    thr: Thresholds,
}

enum Stage {
    Done(usize, Outcome),
    Score(Plan),
}

fn plan_node(ctx: &TrainContext<'_>, tree: usize, id: usize, depth: usize, idx: Vec<u32>) -> Stage {
    let p = ctx.params;
    if depth >= p.max_depth || idx.len() < p.min_samples_split {
        return Stage::Done(
            id,
            Outcome::Leaf(leaf_modes(&idx, ctx.offsets, ctx.rotations, p)),
        );
    }
    let node_seed = mix(&[p.seed, tree as u64, id as u64]);
    let mut rng = ChaCha8Rng::seed_from_u64(node_seed);
    let cands = draw_candidates(&mut rng, p.n_candidates, p.max_offset);
    let subset: Vec<u32> = if idx.len() > p.max_score_samples {
        let mut pick = sample(&mut rng, idx.len(), p.max_score_samples).into_vec();
        pick.sort_unstable();
        pick.into_iter().map(|k| idx[k]).collect()
    } else {
        idx.clone()
    };
    let (store, parts) = (ctx.store, ctx.parts);
    let feat = |c: usize, j: usize| cands[c].eval(store, &parts[subset[j] as usize]);
    let thr = Thresholds::draw(subset.len(), cands.len(), p.n_thresholds, &feat, node_seed);
    let soa = CandidateSoa::new(&cands);
    Stage::Score(Plan {
        id,
        idx,
        subset,
        cands,
        soa,
        thr,
    })
}

fn finish_node(ctx: &TrainContext<'_>, plan: Plan, bins: &[u8]) -> (usize, Outcome) {
    let p = ctx.params;
    let node = NodeData::gather(ctx.crit, ctx.targets, &plan.subset);
    let bins = BinMatrix::part_major(bins, plan.cands.len());
    let best = score_bins(ctx.crit, &node, &plan.thr, bins, p.min_samples_leaf, true);
    drop(node);
    let Plan { id, idx, cands, .. } = plan;
    let (store, parts) = (ctx.store, ctx.parts);
    let leaf = |idx: &[u32]| Outcome::Leaf(leaf_modes(idx, ctx.offsets, ctx.rotations, p));
    match best {
        Some(b) if b.gain.is_finite() && b.gain > p.min_gain => {
            let f = cands[b.candidate];
            let (left, right): (Vec<u32>, Vec<u32>) = idx
                .iter()
                .partition(|&&i| f.eval(store, &parts[i as usize]) < b.threshold);
            if left.is_empty() || right.is_empty() {
                return (id, leaf(&idx));
            }
            (
                id,
                Outcome::Split {
                    feature: f,
                    threshold: b.threshold,
                    left,
                    right,
                },
            )
        }
        _ => (id, leaf(&idx)),
    }
}

/// Scored parts of a level planned and binned at once (the bins cost `n_candidates` bytes a
/// scored part, the plans a few kilobytes a node); a larger level goes in chunks of whole nodes.
/// 2^19 rows: 52 MB of bins at 100 candidates (2^20 held 105 MB).
const LEVEL_BIN_ROWS: usize = 1 << 19;
/// Nodes planned at once (each plan holds its candidates and thresholds: about 25 KB a node at
/// 100 candidates and 16 thresholds, so 1024 nodes hold about 25 MB; 8192 held about 200 MB).
const LEVEL_NODES: usize = 1024;

/// The level's nodes in consecutive chunks of at most `level_rows` parts to score and
/// [`LEVEL_NODES`] nodes (a node scores at most `max_score_samples`; one with more than
/// `level_rows` is a chunk of its own).
fn level_chunks(
    frontier: Vec<(usize, Vec<u32>)>,
    level_rows: usize,
    max_score_samples: usize,
) -> Vec<Vec<(usize, Vec<u32>)>> {
    let mut chunks: Vec<Vec<(usize, Vec<u32>)>> = Vec::new();
    let mut rows = 0;
    for node in frontier {
        let scored = node.1.len().min(max_score_samples);
        let full = chunks
            .last()
            .is_none_or(|c| c.len() >= LEVEL_NODES || rows + scored > level_rows);
        if full {
            chunks.push(Vec::new());
            rows = 0;
        }
        rows += scored;
        chunks.last_mut().expect("a chunk was pushed").push(node);
    }
    chunks
}

/// Grows tree number `tree` on the parts `bag` (global indices, ascending).
///
/// Level by level: (1) every node of the level draws its candidates, scored subset and
/// thresholds; (2) one pass over the level's scored parts **in part (= image) order** evaluates
/// each part's node candidates into bin indices, so each depth crop is brought into cache once
/// per level instead of once per node (a level of over [`LEVEL_BIN_ROWS`] scored parts: steps
/// 1-3 per chunk of its nodes, once per chunk); (3) every node accumulates its statistics and picks its
/// split; (4) children get breadth-first ids. Phases 1-3 run in parallel. With the environment
/// variable `ISA_TRACE` set, the wall time of each phase is printed to stderr per tree.
pub fn build_tree(ctx: &TrainContext<'_>, tree: usize, bag: Vec<u32>) -> Tree {
    grow_tree(ctx, tree, bag, LEVEL_BIN_ROWS)
}

/// [`build_tree`] planning and binning at most `level_rows` scored parts at once (the tree is
/// the same for any value; tests use small ones).
pub(crate) fn grow_tree(
    ctx: &TrainContext<'_>,
    tree: usize,
    bag: Vec<u32>,
    level_rows: usize,
) -> Tree {
    let placeholder = Node::leaf(0);
    let mut t = Tree {
        nodes: vec![placeholder],
        leaf_offsets: vec![0],
        votes: Vec::new(),
    };
    let nc = ctx.params.n_candidates;
    let mut frontier: Vec<(usize, Vec<u32>)> = vec![(0, bag)];
    let mut depth = 0;
    let trace = std::env::var_os("ISA_TRACE").is_some();
    let mut tt = [0f64; 5];
    while !frontier.is_empty() {
        let mut outcomes: Vec<(usize, Outcome)> = Vec::new();
        // (1)-(3) in chunks of whole nodes of at most `level_rows` scored parts: the plans and
        // the bin matrix are a level's largest working memory, and a node's plan, bins and
        // split do not depend on the chunk it falls in.
        for chunk in level_chunks(frontier, level_rows, ctx.params.max_score_samples) {
            let c0 = std::time::Instant::now();
            let stages: Vec<Stage> = chunk
                .into_par_iter()
                .map(|(id, idx)| plan_node(ctx, tree, id, depth, idx))
                .collect();
            let mut plans: Vec<Plan> = Vec::new();
            for st in stages {
                match st {
                    Stage::Done(id, o) => outcomes.push((id, o)),
                    Stage::Score(p) => plans.push(p),
                }
            }
            let c1 = std::time::Instant::now();
            tt[0] += (c1 - c0).as_secs_f64();
            if plans.is_empty() {
                continue;
            }
            // (2) the chunk's scored parts in part order, each with its plan's slot, and their
            // bins (row `r` of the bins is part `scan[r].0`). Nodes' subsets are disjoint, so
            // sorting their union gives each part once; no per-part array of the whole set.
            let mut scan: Vec<(u32, u32)> =
                Vec::with_capacity(plans.iter().map(|pl| pl.subset.len()).sum());
            for (s, pl) in plans.iter().enumerate() {
                scan.extend(pl.subset.iter().map(|&p| (p, s as u32)));
            }
            scan.par_sort_unstable();
            let c2 = std::time::Instant::now();
            let mut bins = vec![0u8; scan.len() * nc];
            {
                let (store, parts, plans) = (ctx.store, ctx.parts, &plans);
                const ROWS: usize = 512;
                bins.par_chunks_mut(ROWS * nc)
                    .zip(scan.par_chunks(ROWS))
                    .for_each(|(out, ps)| {
                        for (row, &(p, slot)) in out.chunks_exact_mut(nc).zip(ps) {
                            let pl = &plans[slot as usize];
                            let g = PartGeom::new(store, &parts[p as usize]);
                            bins_row(&pl.thr, &pl.soa, &pl.cands, &g, row);
                        }
                    });
            }
            let c3 = std::time::Instant::now();
            // (3) score every node on its rows (found by binary search in `scan`: the node's
            // subset is ascending, so each search starts at the previous row).
            let (bins, scan) = (&bins, &scan);
            let scored: Vec<(usize, Outcome)> = plans
                .into_par_iter()
                .map(|pl| {
                    let mut local = vec![0u8; pl.subset.len() * nc];
                    let mut r = 0;
                    for (dst, &p) in local.chunks_exact_mut(nc).zip(&pl.subset) {
                        r += scan[r..].partition_point(|&(q, _)| q < p);
                        debug_assert_eq!(scan[r].0, p);
                        dst.copy_from_slice(&bins[r * nc..(r + 1) * nc]);
                    }
                    finish_node(ctx, pl, &local)
                })
                .collect();
            outcomes.extend(scored);
            let c4 = std::time::Instant::now();
            tt[1] += (c2 - c1).as_secs_f64();
            tt[2] += (c3 - c2).as_secs_f64();
            tt[3] += (c4 - c3).as_secs_f64();
        }
        let t4 = std::time::Instant::now();
        outcomes.sort_by_key(|o| o.0);
        // (4) assemble in node-id order (breadth-first ids).
        let mut next = Vec::new();
        for (id, out) in outcomes {
            match out {
                Outcome::Leaf(votes) => {
                    let leaf = t.n_leaves() as u32;
                    t.votes.extend_from_slice(&votes);
                    t.leaf_offsets.push(t.votes.len() as u32);
                    t.nodes[id] = Node {
                        child: leaf,
                        ..placeholder
                    };
                }
                Outcome::Split {
                    feature,
                    threshold,
                    left,
                    right,
                } => {
                    let child = t.nodes.len();
                    t.nodes.push(placeholder);
                    t.nodes.push(placeholder);
                    t.nodes[id] = Node {
                        feature,
                        threshold,
                        child: child as u32,
                        is_leaf: false,
                    };
                    next.push((child, left));
                    next.push((child + 1, right));
                }
            }
        }
        frontier = next;
        let t5 = std::time::Instant::now();
        tt[4] += (t5 - t4).as_secs_f64();
        depth += 1;
    }
    if trace {
        eprintln!(
            "tree {tree}: plan {:.2} scan {:.2} bins {:.2} score {:.2} assemble {:.2}",
            tt[0], tt[1], tt[2], tt[3], tt[4]
        );
    }
    t
}

/// Compresses the votes of the parts `idx` into at most `leaf_modes` weighted modes.
pub fn leaf_modes(idx: &[u32], offsets: &[f32], rotations: &[f32], p: &ForestParams) -> Vec<Vote> {
    if idx.is_empty() {
        return Vec::new();
    }
    let n = idx.len().min(p.leaf_max_points);
    let pts: Vec<usize> = (0..n).map(|i| idx[i * idx.len() / n] as usize).collect();
    let off: Vec<[f32; 3]> = pts
        .iter()
        .map(|&k| [offsets[3 * k], offsets[3 * k + 1], offsets[3 * k + 2]])
        .collect();
    let q: Vec<[f32; 4]> = pts
        .iter()
        .map(|&k| unit_w_positive(&rotations[4 * k..4 * k + 4]))
        .collect();
    let (ihx2, iht2) = (
        1.0 / (p.vote_bandwidth_offset * p.vote_bandwidth_offset),
        1.0 / (p.vote_bandwidth_rotation * p.vote_bandwidth_rotation),
    );
    let mut d2 = vec![0f32; n * n];
    for i in 0..n {
        for j in i + 1..n {
            let dx = (off[i][0] - off[j][0]).powi(2)
                + (off[i][1] - off[j][1]).powi(2)
                + (off[i][2] - off[j][2]).powi(2);
            let v = dx * ihx2 + angle_sq_approx(&q[i], &q[j]) * iht2;
            d2[i * n + j] = v;
            d2[j * n + i] = v;
        }
    }
    let dens: Vec<f32> = (0..n)
        .map(|i| {
            d2[i * n..(i + 1) * n]
                .iter()
                .map(|&v| (-0.5 * v).exp())
                .sum()
        })
        .collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| dens[b].total_cmp(&dens[a]).then(a.cmp(&b)));
    let mut assigned = vec![false; n];
    let mut votes = Vec::new();
    for &c in &order {
        if votes.len() >= p.leaf_modes {
            break;
        }
        if assigned[c] {
            continue;
        }
        let mut cnt = 0usize;
        let mut so = [0f64; 3];
        let mut sq = [0f64; 4];
        for j in 0..n {
            if !assigned[j] && (j == c || d2[c * n + j] <= 4.0) {
                assigned[j] = true;
                cnt += 1;
                for k in 0..3 {
                    so[k] += off[j][k] as f64;
                }
                let sgn = if q[j].iter().zip(&q[c]).map(|(a, b)| a * b).sum::<f32>() < 0.0 {
                    -1.0
                } else {
                    1.0
                };
                for k in 0..4 {
                    sq[k] += sgn * q[j][k] as f64;
                }
            }
        }
        let qn = (sq.iter().map(|v| v * v).sum::<f64>()).sqrt();
        let rq = if qn > 1e-12 {
            [sq[0] / qn, sq[1] / qn, sq[2] / qn, sq[3] / qn]
        } else {
            [1.0, 0.0, 0.0, 0.0]
        };
        let rq = unit_w_positive(&[rq[0] as f32, rq[1] as f32, rq[2] as f32, rq[3] as f32]);
        votes.push(Vote {
            weight: cnt as f32 / n as f32,
            offset: [
                (so[0] / cnt as f64) as f32,
                (so[1] / cnt as f64) as f32,
                (so[2] / cnt as f64) as f32,
            ],
            rotation: rq,
        });
    }
    votes.sort_by(|a, b| b.weight.total_cmp(&a.weight));
    votes
}
