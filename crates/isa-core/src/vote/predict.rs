//! Whole-image inference (paper Sec. 3.4): parts on a stride over every valid pixel of a depth
//! image (no segmentation, no box proposals), each passed down every tree; every leaf vote
//! `(Δx, q, w)` of a part at pixel `(u, v)` with depth `z` becomes the pose vote
//! `(K⁻¹ [u, v, 1]ᵀ z + Δx, q, w / |F|)` (Eq. 13 averages over the trees), and
//! [`find_modes`](super::find_modes) turns the votes into ranked hypotheses.
//!
//! Traversal runs in parallel over fixed blocks of parts (trees outer, parts inner inside a block,
//! so a tree's top levels stay in cache; 16 parts walk a tree at once with AVX2 gathers when the
//! CPU has them, see `forest/flat.rs`, else the portable `leaves_batched`); a second pass writes
//! each chunk's votes into its place in the output, so the votes and the hypotheses do not
//! depend on the number of threads (nor on which traversal ran: both take the same decisions).
//!
//! (Over 600 lines: the second half is its tests, which train and traverse a small forest on
//! the synthetic chair.)

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{find_modes_valid, Hypothesis, PoseVote};
use crate::depth::{sample_parts, DepthStore, Part};
use crate::error::{IsaError, Result};
use crate::forest::flat::leaves_batched;
#[cfg(test)]
use crate::forest::flat::FlatTree;
use crate::forest::Forest;
use crate::params::{PredictParams, Valid};
use crate::tree::Tree;

/// Pinhole intrinsics (pixels), OpenCV convention: pixel centres at integer `(u, v)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    /// Kinect v1 as in `isa.camera.KINECT_V1` (640x480).
    pub const KINECT_V1: Intrinsics = Intrinsics {
        fx: 525.0,
        fy: 525.0,
        cx: 319.5,
        cy: 239.5,
    };

    /// From a row-major 3x3 camera matrix `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]` (skew must be 0).
    pub fn from_matrix(k: [[f64; 3]; 3]) -> Result<Intrinsics> {
        let ok = k[0][1].abs() < 1e-9 && k[1][0].abs() < 1e-9 && k[2] == [0.0, 0.0, 1.0];
        if !ok {
            return Err(IsaError::InvalidInput(format!(
                "K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {k:?}"
            )));
        }
        let i = Intrinsics {
            fx: k[0][0],
            fy: k[1][1],
            cx: k[0][2],
            cy: k[1][2],
        };
        i.validate()?;
        Ok(i)
    }

    /// Focal lengths finite and positive, principal point finite.
    pub fn validate(&self) -> Result<()> {
        if !(self.fx.is_finite() && self.fx > 0.0 && self.fy.is_finite() && self.fy > 0.0) {
            return Err(IsaError::InvalidInput(format!(
                "intrinsics: focal lengths must be finite and > 0, got fx={} fy={}",
                self.fx, self.fy
            )));
        }
        if !(self.cx.is_finite() && self.cy.is_finite()) {
            return Err(IsaError::InvalidInput(format!(
                "intrinsics: principal point must be finite, got cx={} cy={}",
                self.cx, self.cy
            )));
        }
        Ok(())
    }

    /// [`validate`](Self::validate), and the principal point inside a `width x height` image
    /// (pixel centres at integers, so within `[-0.5, size - 0.5]`): outside it, the image and
    /// the intrinsics do not belong together.
    pub fn validate_for(&self, width: usize, height: usize) -> Result<()> {
        self.validate()?;
        let (w, h) = (width as f64, height as f64);
        if !(self.cx >= -0.5 && self.cy >= -0.5 && self.cx <= w - 0.5 && self.cy <= h - 0.5) {
            return Err(IsaError::InvalidInput(format!(
                "intrinsics: principal point ({}, {}) lies outside the {width}x{height} (width x height) image: wrong intrinsics for this image",
                self.cx, self.cy
            )));
        }
        Ok(())
    }

    /// 3D point (camera frame, metres) of pixel `(u, v)` at depth `z` metres.
    #[inline]
    pub fn back_project(&self, u: f64, v: f64, z: f64) -> [f64; 3] {
        [(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z]
    }
}

/// A borrowed depth image: uint16 millimetres, row-major `height x width`, 0 = missing.
#[derive(Clone, Copy, Debug)]
pub struct DepthImage<'a> {
    pub data: &'a [u16],
    pub width: usize,
    pub height: usize,
}

impl<'a> DepthImage<'a> {
    /// Checks the size; the error says what was expected.
    pub fn new(data: &'a [u16], width: usize, height: usize) -> Result<Self> {
        if width == 0 || height == 0 || data.len() != width * height {
            return Err(IsaError::InvalidInput(format!(
                "depth: {} pixels for a {height}x{width} image",
                data.len()
            )));
        }
        Ok(Self {
            data,
            width,
            height,
        })
    }
}

/// Metres (float) to millimetres (uint16): rounds; non-finite, `<= 0` or `>= 65.5355` m become 0
/// (missing), as in BOP PNGs.
pub fn depth_m_to_mm(depth_m: &[f32]) -> Vec<u16> {
    depth_m
        .iter()
        .map(|&d| {
            let mm = (f64::from(d) * 1000.0).round();
            if (1.0..=65535.0).contains(&mm) {
                mm as u16
            } else {
                0
            }
        })
        .collect()
}

/// The votes of one image, with where each came from (for plots and diagnostics).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageVotes {
    pub votes: Vec<PoseVote>,
    /// Pixel `(u, v)` of the part that cast each vote.
    pub pixels: Vec<[u32; 2]>,
    /// Tree index of each vote.
    pub trees: Vec<u32>,
    /// Number of parts passed down the forest.
    pub n_parts: usize,
}

const CHUNK: usize = 256;

/// The parts of one depth image on a stride, sampled once for every forest that votes on it
/// (scene detection runs each category's forest over the same parts).
pub struct ImageParts {
    store: DepthStore,
    parts: Vec<Part>,
    stride: usize,
}

impl ImageParts {
    /// Every valid pixel of `depth` on `stride`.
    pub fn new(depth: &DepthImage<'_>, stride: usize) -> Result<Self> {
        let mut store = DepthStore::new();
        store.push(depth.width, depth.height, depth.data)?;
        let parts = sample_parts(&store, stride, None, 0)?;
        Ok(ImageParts {
            store,
            parts,
            stride,
        })
    }

    /// The parts within `params`' depth limits (all of them without limits).
    fn within(&self, params: &PredictParams) -> Result<std::borrow::Cow<'_, [Part]>> {
        if params.stride != self.stride {
            return Err(IsaError::InvalidParameter(format!(
                "stride {} for parts sampled on stride {}",
                params.stride, self.stride
            )));
        }
        let lo = (params.min_depth * 1000.0).ceil().max(1.0) as u32;
        let hi = params
            .max_depth
            .map_or(u32::MAX, |m| (m * 1000.0).floor() as u32);
        if lo > 1 || hi < u16::MAX as u32 {
            let store = &self.store;
            Ok(self
                .parts
                .iter()
                .filter(|p| {
                    let d = u32::from(store.center_depth(p));
                    d >= lo && d <= hi
                })
                .copied()
                .collect::<Vec<_>>()
                .into())
        } else {
            Ok(self.parts[..].into())
        }
    }

    fn width(&self) -> usize {
        self.store.image(0).width as usize
    }

    fn height(&self) -> usize {
        self.store.image(0).height as usize
    }
}

/// Parts traversed together per tree (several vote chunks of [`CHUNK`] parts: a long run keeps
/// every traversal lane busy and a tree's upper nodes in cache).
const BLOCK: usize = 4 * CHUNK;

/// Traverses every tree for every part; `meta` also records pixels and trees.
///
/// Two passes, in parallel over blocks of parts: (1) the leaf of every (tree, part) and the
/// number of votes of every chunk of [`CHUNK`] parts; (2) every chunk writes its votes straight
/// into its slice of the output (chunk, then tree, then part, then leaf vote), so votes are
/// neither reallocated nor concatenated, and their order does not depend on the thread count.
fn collect_votes(
    forest: &Forest,
    store: &DepthStore,
    parts: &[Part],
    k: &Intrinsics,
    params: &PredictParams,
    meta: bool,
) -> ImageVotes {
    let n_trees = forest.n_trees();
    let mut all = ImageVotes {
        n_parts: parts.len(),
        ..Default::default()
    };
    if n_trees == 0 || parts.is_empty() {
        return all;
    }
    let inv_trees = 1.0 / n_trees as f32;
    let min_w = params.min_leaf_weight;
    let img = store.image(0);
    // The AVX2 traversal, when the CPU has it and every tree is well formed.
    let flat = forest.flat.get(&forest.trees);
    let kept = |tree: &Tree, leaf: u32| -> usize {
        tree.leaf_votes(leaf as usize)
            .iter()
            .filter(|v| v.weight >= min_w)
            .count()
    };
    // Pass 1: leaves[block][tree * block_len + part], votes per chunk.
    let blocks: Vec<(Vec<u32>, Vec<usize>)> = parts
        .par_chunks(BLOCK)
        .map(|block| {
            let pix: Vec<(i32, i32, u16)> = block
                .iter()
                .map(|p| (p[1], p[2], img.get(p[1], p[2])))
                .collect();
            let nb = block.len();
            let mut leaves = vec![0u32; nb * n_trees];
            // Trees in parallel too: an object-only frame is a single block. Each tree writes
            // its own row, so the result does not depend on scheduling.
            leaves
                .par_chunks_mut(nb)
                .enumerate()
                .for_each(|(t, row)| match &flat {
                    // SAFETY: AVX2 checked by `FlatTree::available`; `img` is an image of a
                    // DepthStore (padding pixel after it).
                    Some(f) => unsafe { f[t].leaves(&img, &pix, row) },
                    None => leaves_batched(&forest.trees[t], &img, &pix, row),
                });
            let mut counts = vec![0usize; nb.div_ceil(CHUNK)];
            for (t, tree) in forest.trees.iter().enumerate() {
                let row = &leaves[t * nb..(t + 1) * nb];
                for (c, ls) in counts.iter_mut().zip(row.chunks(CHUNK)) {
                    *c += ls.iter().map(|&l| kept(tree, l)).sum::<usize>();
                }
            }
            (leaves, counts)
        })
        .collect();
    // Pass 2: each chunk fills its own slice of the outputs.
    let counts: Vec<usize> = blocks.iter().flat_map(|b| b.1.iter().copied()).collect();
    let total: usize = counts.iter().sum();
    all.votes.reserve_exact(total);
    if meta {
        all.pixels.reserve_exact(total);
        all.trees.reserve_exact(total);
    }
    {
        let mut votes_rest = &mut all.votes.spare_capacity_mut()[..total];
        let (mut pix_rest, mut tree_rest) = if meta {
            (
                &mut all.pixels.spare_capacity_mut()[..total],
                &mut all.trees.spare_capacity_mut()[..total],
            )
        } else {
            (&mut [][..], &mut [][..])
        };
        let mut jobs = Vec::with_capacity(counts.len());
        let mut ci = 0;
        for (b, (leaves, bcounts)) in blocks.iter().enumerate() {
            let block = &parts[b * BLOCK..(b * BLOCK + BLOCK).min(parts.len())];
            for (c, &n) in bcounts.iter().enumerate() {
                let (v, vr) = std::mem::take(&mut votes_rest).split_at_mut(n);
                votes_rest = vr;
                let m = if meta { n } else { 0 };
                let (px, pr) = std::mem::take(&mut pix_rest).split_at_mut(m);
                pix_rest = pr;
                let (tr, trr) = std::mem::take(&mut tree_rest).split_at_mut(m);
                tree_rest = trr;
                let lo = c * CHUNK;
                let hi = (lo + CHUNK).min(block.len());
                jobs.push((leaves, block.len(), lo, &block[lo..hi], v, px, tr));
                ci += 1;
            }
        }
        debug_assert_eq!(ci, counts.len());
        jobs.into_par_iter()
            .for_each(|(leaves, nb, lo, chunk, v_out, px_out, tr_out)| {
                let mut j = 0usize;
                let centres: Vec<[f32; 3]> = chunk
                    .iter()
                    .map(|p| {
                        let z = f64::from(store.center_depth(p)) * 1e-3;
                        k.back_project(f64::from(p[1]), f64::from(p[2]), z)
                            .map(|c| c as f32)
                    })
                    .collect();
                for (t, tree) in forest.trees.iter().enumerate() {
                    let row = &leaves[t * nb + lo..t * nb + lo + chunk.len()];
                    for ((p, c), &leaf) in chunk.iter().zip(&centres).zip(row) {
                        // Background-trained forests weight each leaf's votes (exactly 1 otherwise).
                        let lw = forest
                            .leaf_weights
                            .as_ref()
                            .map_or(1.0, |w| w.get(t, leaf as usize));
                        for v in tree.leaf_votes(leaf as usize) {
                            if v.weight < min_w {
                                continue;
                            }
                            v_out[j].write(PoseVote {
                                position: [
                                    c[0] + v.offset[0],
                                    c[1] + v.offset[1],
                                    c[2] + v.offset[2],
                                ],
                                rotation: v.rotation,
                                weight: v.weight * inv_trees * lw,
                            });
                            if meta {
                                px_out[j].write([p[1] as u32, p[2] as u32]);
                                tr_out[j].write(t as u32);
                            }
                            j += 1;
                        }
                    }
                }
                // Pass 1 counted exactly these votes: every slot is written.
                assert_eq!(j, v_out.len());
            });
    }
    // SAFETY: the slices covering the first `total` slots were all written (asserted above;
    // a failed assertion panics before this point).
    unsafe {
        all.votes.set_len(total);
        if meta {
            all.pixels.set_len(total);
            all.trees.set_len(total);
        }
    }
    all
}

/// Every vote of every part of `depth` through every tree of `forest` (for plots): parts on
/// `params.stride`, votes ordered by chunk of 256 parts, then tree, then part.
pub fn image_votes(
    forest: &Forest,
    depth: &DepthImage<'_>,
    k: &Intrinsics,
    params: &Valid<PredictParams>,
) -> Result<ImageVotes> {
    k.validate_for(depth.width, depth.height)?;
    let ip = ImageParts::new(depth, params.stride)?;
    let parts = ip.within(params)?;
    Ok(collect_votes(forest, &ip.store, &parts, k, params, true))
}

/// The 6D pose hypotheses of the objects in `depth`, best first (see the module docs).
///
/// Errors: bad parameters or intrinsics, a depth buffer whose length is not `width * height`.
/// An image without valid pixels, or a forest without trees, gives no hypotheses.
pub fn predict(
    forest: &Forest,
    depth: &DepthImage<'_>,
    k: &Intrinsics,
    params: &Valid<PredictParams>,
) -> Result<Vec<Hypothesis>> {
    k.validate_for(depth.width, depth.height)?;
    predict_parts(forest, &ImageParts::new(depth, params.stride)?, k, params)
}

/// [`predict`] on parts sampled beforehand (the same hypotheses); `params.stride` must be
/// the parts' stride.
pub fn predict_parts(
    forest: &Forest,
    parts: &ImageParts,
    k: &Intrinsics,
    params: &Valid<PredictParams>,
) -> Result<Vec<Hypothesis>> {
    k.validate_for(parts.width(), parts.height())?;
    let within = parts.within(params)?;
    let votes = collect_votes(forest, &parts.store, &within, k, params, false);
    // Leaf votes are finite (model files are validated) and so are back-projected pixels.
    Ok(find_modes_valid(&votes.votes, &params.vote))
}

#[cfg(test)]
mod tests {
    use super::super::{quat_angle, synth};
    use super::*;
    use crate::criterion::RawTargets;
    use crate::error::expect_err;
    use crate::forest::TrainingSet;
    use crate::params::{ForestParams, Quality};
    use crate::tree::{Node, Tree, Vote};

    /// A forest of `n` one-leaf trees, each leaf voting `votes`.
    fn constant_forest(n: usize, votes: &[Vote]) -> Forest {
        let tree = Tree {
            nodes: vec![Node::leaf(0)],
            leaf_offsets: vec![0, votes.len() as u32],
            votes: votes.to_vec(),
        };
        Forest {
            params: ForestParams::default(),
            trees: vec![tree; n],
            metadata: Default::default(),
            predict_defaults: Default::default(),
            crate_version: crate::VERSION.into(),
            leaf_weights: None,
            flat: Default::default(),
        }
    }

    /// Issue 20: huge feature offsets panicked with integer overflow where overflow checks are
    /// on (this test profile). The largest values a model file may hold, and ±3e38 in a forest
    /// built in memory (a file refuses them), on the nearest depth (1 mm: the largest pixel
    /// steps) and the farthest, predict finite poses without a panic.
    #[test]
    fn extreme_models_predict_without_overflow() {
        use crate::criterion::MAX_TARGET_OFFSET;
        use crate::features::{Feature, MAX_FEATURE_OFFSET};
        let make = |m: f32, o: f32| {
            let vote = |s: f32| Vote {
                weight: 1.0,
                offset: [s * o, -s * o, o],
                rotation: [0.0, 0.0, 0.6, 0.8],
            };
            let split = Node {
                feature: Feature {
                    u: [m, -m],
                    v: [-m, m],
                },
                threshold: -f32::MAX,
                child: 1,
                is_leaf: false,
            };
            let mut forest = constant_forest(2, &[vote(1.0)]);
            forest.params.n_trees = 2;
            forest.trees[0] = Tree {
                nodes: vec![split, Node::leaf(0), Node::leaf(1)],
                leaf_offsets: vec![0, 1, 2],
                votes: vec![vote(1.0), vote(-1.0)],
            };
            forest
        };
        let at_bounds =
            Forest::from_bytes(&make(MAX_FEATURE_OFFSET, MAX_TARGET_OFFSET).to_bytes()).unwrap();
        let huge = make(3e38, 3e38);
        assert!(Forest::from_bytes(&huge.to_bytes()).is_err());
        let (w, h) = (40usize, 30usize);
        let depth: Vec<u16> = (0..w * h).map(|i| [1u16, 65535, 0, 7][i % 4]).collect();
        let img = DepthImage::new(&depth, w, h).unwrap();
        let k = Intrinsics {
            fx: 1e-3,
            fy: 1e6,
            cx: -0.5,
            cy: 29.5,
        };
        let p = PredictParams {
            stride: 1,
            ..Default::default()
        }
        .check()
        .unwrap();
        for forest in [at_bounds, huge] {
            let hyps = predict(&forest, &img, &k, &p).unwrap();
            assert!(!hyps.is_empty());
            for hy in &hyps {
                assert!(
                    hy.translation
                        .iter()
                        .chain(&hy.quaternion)
                        .all(|v| v.is_finite()),
                    "{hy:?}"
                );
            }
        }
    }

    const K: Intrinsics = Intrinsics {
        fx: 100.0,
        fy: 110.0,
        cx: 15.5,
        cy: 11.5,
    };

    /// The toy forest trained with `seed` (one thread).
    fn toy_forest(seed: u64) -> Forest {
        use crate::forest::tests::{q1_set, toy, toy_params};
        let (store, parts, off, rot) = toy(2);
        let params = ForestParams {
            seed,
            ..toy_params()
        };
        Forest::fit(
            &params.check().unwrap(),
            &q1_set(&store, &parts, &off, &rot),
            Default::default(),
            Some(1),
        )
        .unwrap()
    }

    /// A 64 x 48 depth ramp every pixel of which is valid, and stride-2 parameters.
    fn ramp() -> (Vec<u16>, usize, usize, Valid<PredictParams>) {
        let (w, h) = (64usize, 48usize);
        let depth: Vec<u16> = (0..w * h).map(|i| 1000 + ((i * 37) % 900) as u16).collect();
        let p = PredictParams {
            stride: 2,
            ..Default::default()
        };
        (depth, w, h, p.check().unwrap())
    }

    #[test]
    fn prepared_trees_follow_replaced_trees() {
        let mut a = toy_forest(crate::forest::tests::toy_params().seed);
        let b = toy_forest(7);
        let (depth, w, h, p) = ramp();
        let img = DepthImage::new(&depth, w, h).unwrap();
        let votes = |f: &Forest| image_votes(f, &img, &K, &p).unwrap().votes;
        let va = votes(&a);
        assert_eq!(votes(&a), va); // from the cache
        let vb = votes(&b.clone()); // a clone prepares its own trees
        assert_ne!(va, vb);
        a.trees = b.trees.clone();
        assert_eq!(votes(&a), vb);
    }

    /// Leaf weights scale each vote by its (tree, leaf)'s weight, the leaf found by the
    /// separate `Forest::apply` traversal; weights of 1 change no bit; the weighted model's
    /// hypotheses keep only the votes the weights keep.
    #[test]
    fn leaf_weights_scale_the_votes_of_their_leaves() {
        let plain = toy_forest(crate::forest::tests::toy_params().seed);
        let (depth, w, h, p) = ramp();
        let img = DepthImage::new(&depth, w, h).unwrap();
        // Weight of leaf l of tree t: a value in [0, 1] that differs between leaves and trees.
        let lw = |t: usize, l: usize| ((t * 7 + l * 3) % 5) as f32 / 4.0;
        let per_tree = |f: &dyn Fn(usize, usize) -> f32| -> Vec<Vec<f32>> {
            plain
                .trees
                .iter()
                .enumerate()
                .map(|(t, tr)| (0..tr.n_leaves()).map(|l| f(t, l)).collect())
                .collect()
        };
        let ones = plain
            .clone()
            .with_leaf_weights(Some(per_tree(&|_, _| 1.0)))
            .unwrap();
        let weighted = plain
            .clone()
            .with_leaf_weights(Some(per_tree(&lw)))
            .unwrap();
        let base = image_votes(&plain, &img, &K, &p).unwrap();
        assert_eq!(image_votes(&ones, &img, &K, &p).unwrap().votes, base.votes);
        let got = image_votes(&weighted, &img, &K, &p).unwrap();
        assert_eq!(got.votes.len(), base.votes.len());
        // The leaf of each vote's part, by the other traversal.
        let ip = ImageParts::new(&img, p.stride).unwrap();
        let (ds, dparts) = (&ip.store, ip.within(&p).unwrap());
        let leaves = plain.apply(ds, &dparts).unwrap();
        let index: std::collections::HashMap<(u32, u32), usize> = dparts
            .iter()
            .enumerate()
            .map(|(i, q)| ((q[1] as u32, q[2] as u32), i))
            .collect();
        let n_t = plain.n_trees();
        let mut zeroed = 0;
        for ((g, b), (px, t)) in got
            .votes
            .iter()
            .zip(&base.votes)
            .zip(got.pixels.iter().zip(&got.trees))
        {
            let i = index[&(px[0], px[1])];
            let leaf = leaves[i * n_t + *t as usize] as usize;
            assert_eq!(g.weight, b.weight * lw(*t as usize, leaf));
            assert_eq!((g.position, g.rotation), (b.position, b.rotation));
            zeroed += usize::from(g.weight == 0.0);
        }
        assert!(
            zeroed > 0 && zeroed < got.votes.len(),
            "the weights must keep some votes and drop others"
        );
        // Bad weights are refused by name.
        expect_err(
            plain.clone().with_leaf_weights(Some(per_tree(&|_, _| 1.5))),
            &["tree 0 leaf 0", "1.5"],
        );
        expect_err(
            plain.clone().with_leaf_weights(Some(vec![vec![1.0]])),
            &["trees of weights"],
        );
    }

    #[test]
    fn votes_are_back_projected_part_centres_plus_offsets() {
        let (w, h) = (32usize, 24usize);
        let depth: Vec<u16> = (0..w * h)
            .map(|i| {
                if i % 7 == 0 {
                    0
                } else {
                    1500 + (i % 13) as u16 * 100
                }
            })
            .collect();
        let leaf_votes = [
            Vote {
                weight: 0.75,
                offset: [0.1, -0.2, 0.3],
                rotation: [1.0, 0.0, 0.0, 0.0],
            },
            Vote {
                weight: 0.25,
                offset: [0.0; 3],
                rotation: [0.0, 1.0, 0.0, 0.0],
            },
        ];
        let forest = constant_forest(4, &leaf_votes);
        let params = PredictParams {
            stride: 3,
            ..Default::default()
        };
        let img = DepthImage::new(&depth, w, h).unwrap();
        let iv = image_votes(&forest, &img, &K, &params.clone().check().unwrap()).unwrap();
        let expected_parts: Vec<(usize, usize)> = (0..h)
            .step_by(3)
            .flat_map(|v| (0..w).step_by(3).map(move |u| (u, v)))
            .filter(|&(u, v)| depth[v * w + u] > 0)
            .collect();
        assert_eq!(iv.n_parts, expected_parts.len());
        assert_eq!(iv.votes.len(), expected_parts.len() * 4 * 2);
        assert_eq!(iv.pixels.len(), iv.votes.len());
        assert_eq!(iv.trees.len(), iv.votes.len());
        for ((vote, px), tree) in iv.votes.iter().zip(&iv.pixels).zip(&iv.trees) {
            let (u, v) = (px[0] as usize, px[1] as usize);
            assert!(u % 3 == 0 && v % 3 == 0 && *tree < 4);
            let z = f64::from(depth[v * w + u]) / 1000.0;
            let x = K.back_project(u as f64, v as f64, z);
            let lv = if vote.rotation[0] == 1.0 {
                leaf_votes[0]
            } else {
                leaf_votes[1]
            };
            for ((p, xa), o) in vote.position.iter().zip(x).zip(lv.offset) {
                assert!((f64::from(*p) - (xa + f64::from(o))).abs() < 1e-5);
            }
            assert_eq!(vote.weight, lv.weight / 4.0);
        }
        // Depth limits and leaf-weight filter.
        let p2 = PredictParams {
            stride: 3,
            min_depth: 1.8,
            max_depth: Some(2.2),
            min_leaf_weight: 0.5,
            ..Default::default()
        };
        let iv2 = image_votes(&forest, &img, &K, &p2.clone().check().unwrap()).unwrap();
        assert!(iv2.n_parts > 0 && iv2.n_parts < iv.n_parts);
        assert_eq!(iv2.votes.len(), iv2.n_parts * 4);
        for px in &iv2.pixels {
            let d = depth[px[1] as usize * w + px[0] as usize];
            assert!((1800..=2200).contains(&d));
        }
    }

    #[test]
    fn bad_inputs_are_named() {
        let forest = constant_forest(1, &[]);
        let depth = vec![1000u16; 20];
        expect_err(DepthImage::new(&depth, 5, 5), &["depth", "5x5"]);
        let img = DepthImage::new(&depth, 5, 4).unwrap();
        let bad_k = Intrinsics { fx: 0.0, ..K };
        expect_err(
            predict(&forest, &img, &bad_k, &Valid::default()),
            &["focal"],
        );
        let p = PredictParams {
            stride: 0,
            ..Default::default()
        };
        expect_err(p.check(), &["stride"]);
        let p = PredictParams {
            max_depth: Some(0.0),
            ..Default::default()
        };
        expect_err(p.check(), &["max_depth"]);
        // A principal point outside the image: the intrinsics are not this image's.
        expect_err(
            predict(&forest, &img, &K, &Valid::default()),
            &["principal point"],
        );
        // No trees, or no valid pixels: no hypotheses.
        let k = Intrinsics {
            cx: 2.0,
            cy: 1.5,
            ..K
        };
        assert!(predict(&forest, &img, &k, &Valid::default())
            .unwrap()
            .is_empty());
        assert!(
            Intrinsics::from_matrix([[1.0, 0.0, 2.0], [0.0, 1.0, 2.0], [0.0, 0.0, 2.0]]).is_err()
        );
        assert_eq!(
            Intrinsics::from_matrix([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
                .unwrap(),
            Intrinsics::KINECT_V1
        );
    }

    #[test]
    fn metres_to_millimetres() {
        assert_eq!(
            depth_m_to_mm(&[0.0, -1.0, f32::NAN, 1.2344, 65.535, 70.0, 0.0004]),
            vec![0, 0, 0, 1234, 65535, 0, 0]
        );
    }

    /// Trains a small forest on views of the synthetic chair; returns it with the intrinsics.
    #[allow(clippy::type_complexity)] // a test fixture: forest, camera and the (R, t) of its views
    pub(crate) fn chair_forest() -> (Forest, Intrinsics, Vec<([[f64; 3]; 3], [f64; 3])>) {
        let k = Intrinsics {
            fx: 200.0,
            fy: 200.0,
            cx: 79.5,
            cy: 59.5,
        };
        let (w, h) = (160usize, 120usize);
        let (store, poses) = synth::chair_views(12, |_| 0.35, 2.5, &k, w, h);
        let parts = sample_parts(&store, 2, Some(400), 7).unwrap();
        let (offsets, rotations) = synth::view_targets(&parts, &store, &poses, &k);
        let params = ForestParams {
            n_trees: 4,
            max_depth: 14,
            n_candidates: 60,
            quality: Quality::Q1,
            min_samples_split: 10,
            min_samples_leaf: 3,
            ..Default::default()
        };
        let targets = RawTargets::pose(&offsets, &rotations);
        let data = TrainingSet {
            store: &store,
            parts: &parts,
            targets,
        };
        (
            Forest::fit(
                &params.clone().check().unwrap(),
                &data,
                Default::default(),
                None,
            )
            .unwrap(),
            k,
            poses,
        )
    }

    #[test]
    fn recovers_the_pose_of_a_training_view_in_a_larger_frame() {
        let (forest, k, poses) = chair_forest();
        // The batched traversal takes the same decisions as Tree::leaf_of.
        {
            let (r, t) = poses[3];
            let depth = synth::render(&synth::chair(), r, t, &k, 160, 120);
            let mut store = DepthStore::new();
            store.push(160, 120, &depth).unwrap();
            let parts = sample_parts(&store, 1, None, 0).unwrap();
            let img = store.image(0);
            let pix: Vec<(i32, i32, u16)> = parts
                .iter()
                .map(|p| (p[1], p[2], img.get(p[1], p[2])))
                .collect();
            for tree in &forest.trees {
                let mut leaves = vec![0u32; parts.len()];
                leaves_batched(tree, &img, &pix, &mut leaves);
                let want: Vec<u32> = parts.iter().map(|p| tree.leaf_of(&store, p)).collect();
                assert_eq!(leaves, want);
            }
        }
        // So does the AVX2 traversal, on every pixel (missing depth included) of a noisy frame
        // with holes, probes running off every border.
        {
            let (r, t) = poses[7];
            let mut depth = synth::render(&synth::chair(), r, t, &k, 160, 120);
            let mut state = 12345u32;
            for d in depth.iter_mut() {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                match state >> 28 {
                    0 => *d = 0,
                    1 => *d = 400 + (state >> 8 & 0x1fff) as u16,
                    2 if *d == 0 => *d = 2000 + (state >> 12 & 0x3ff) as u16,
                    _ => {}
                }
            }
            let mut store = DepthStore::new();
            store.push(160, 120, &depth).unwrap();
            let img = store.image(0);
            let mut pix = Vec::new();
            let mut parts = Vec::new();
            for v in 0..120 {
                for u in 0..160 {
                    pix.push((u, v, img.get(u, v)));
                    parts.push([0, u, v]);
                }
            }
            if FlatTree::available() {
                for tree in &forest.trees {
                    let flat = FlatTree::new(tree).unwrap();
                    let mut fast = vec![0u32; pix.len()];
                    // SAFETY: AVX2 available; a DepthStore image.
                    unsafe { flat.leaves(&img, &pix, &mut fast) };
                    let mut portable = vec![0u32; pix.len()];
                    leaves_batched(tree, &img, &pix, &mut portable);
                    assert_eq!(fast, portable);
                    let want: Vec<u32> = parts.iter().map(|p| tree.leaf_of(&store, p)).collect();
                    assert_eq!(fast, want);
                    // Fewer parts than lanes, and none.
                    unsafe { flat.leaves(&img, &pix[..5], &mut fast[..5]) };
                    assert_eq!(fast[..5], want[..5]);
                    unsafe { flat.leaves(&img, &[], &mut []) };
                }
            } else {
                eprintln!("(no AVX2 here: only the portable traversal is tested)");
            }
        }
        // The same camera, a 320x240 frame: principal point moved, so the chair sits off-centre.
        let kk = Intrinsics {
            cx: 159.5,
            cy: 119.5,
            ..k
        };
        let params = PredictParams {
            stride: 2,
            ..Default::default()
        };
        for &i in &[0usize, 5] {
            let (r, mut t) = poses[i];
            t[0] += 0.3; // shift sideways too
            let depth = synth::render(&synth::chair(), r, t, &kk, 320, 240);
            let img = DepthImage::new(&depth, 320, 240).unwrap();
            let hyps = predict(&forest, &img, &kk, &params.clone().check().unwrap()).unwrap();
            assert!(!hyps.is_empty());
            let best = &hyps[0];
            let err_t = (0..3)
                .map(|a| (best.translation[a] - t[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            let err_r = quat_angle(best.quaternion, super::super::matrix_to_quat(r)).to_degrees();
            assert!(
                err_t < 0.03,
                "view {i}: translation error {err_t} m, {best:?}"
            );
            assert!(err_r < 5.0, "view {i}: rotation error {err_r} deg");
            for w in hyps.windows(2) {
                assert!(w[0].score >= w[1].score);
            }
            // Deterministic, whatever the thread count.
            let one = crate::forest::with_threads(Some(1), || {
                predict(&forest, &img, &kk, &params.clone().check().unwrap()).unwrap()
            })
            .unwrap();
            assert_eq!(one, hyps);
        }
    }
}
