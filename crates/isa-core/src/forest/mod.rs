//! The forest: training (rayon across trees and inside trees, deterministic), traversal and
//! the per-part votes the voting stage aggregates (paper Eq. 12-13).
//!
//! ## Traversal API (for voting)
//! * [`Forest::apply`] — leaf index of every (part, tree), row-major `P × T`.
//! * [`Forest::leaf_votes`] — the weighted [`Vote`] modes of one leaf of one tree.
//! * [`Forest::part_votes`] — both combined: for every part, every tree's leaf votes, as a
//!   flat list of [`PartVote`] (part index, tree index, vote), ordered by part then tree.
//!
//! A vote's `offset` is the SSC offset Δx in the camera frame (metres): the SSC hypothesis of a
//! part is its back-projected 3D point plus `offset`; `rotation` is the object rotation (unit
//! quaternion w, x, y, z, w ≥ 0); `weight` is the mode's share of its leaf. Eq. 13 averages over
//! trees: divide accumulated weights by `n_trees()`.
//!
//! Over 600 lines because its unit tests live beside the code they test (`mod tests` below).

pub(crate) mod flat;
mod leaf_weights;

pub use leaf_weights::LeafWeights;

use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::criterion::{Criterion, RawTargets, Targets, Term};
use crate::depth::{DepthStore, Part};
use crate::error::{IsaError, Result};
use crate::metadata::{ModelMetadata, TrainingSummary};
use crate::params::{ForestParams, PredictParams, Valid};
use crate::rng::mix;
use crate::shards::ShardSet;
use crate::targets::{build_targets_from, WideTargets};
use crate::tree::{build_tree, TrainContext, Tree, Vote};

/// Training data: images, parts and their targets (see DESIGN.md, data contract).
#[derive(Clone, Copy, Debug)]
pub struct TrainingSet<'a> {
    pub store: &'a DepthStore,
    pub parts: &'a [Part],
    pub targets: RawTargets<'a>,
}

impl TrainingSet<'_> {
    /// One row of targets per part.
    fn check_counts(&self) -> Result<()> {
        let n = self.parts.len();
        if self.targets.n() != n || self.targets.offsets.len() != 3 * n {
            return Err(IsaError::InvalidInput(format!(
                "offsets: expected ({n}, 3) for {n} parts, got {} values",
                self.targets.offsets.len()
            )));
        }
        Ok(())
    }

    /// Shapes, finiteness, unit rotations and parts (inside their image, depth > 0): what
    /// fitting checks, without fitting; the error names the array.
    pub fn validate(&self) -> Result<()> {
        self.check_counts()?;
        self.targets.validate()?;
        self.store.validate_parts(self.parts)
    }
}

/// What the trees read: depth crops, parts, the compact targets, and where the wide targets
/// (link angles, node offsets; read only while [`Forest::prepare`] builds the criterion's
/// targets) come from.
#[derive(Clone, Copy)]
pub struct TrainInputs<'a> {
    pub store: &'a DepthStore,
    pub parts: &'a [Part],
    /// `(n, 3)` SSC offsets.
    pub offsets: &'a [f32],
    /// `(n, 4)` quaternions.
    pub rotations: &'a [f32],
    pub wide: &'a dyn WideTargets,
}

/// Where [`Forest::fit`] reads its data: an in-memory [`TrainingSet`] or a shard folder opened
/// with [`ShardSet::open`] (the same forest, to the byte, as from the shards' arrays
/// concatenated in memory). `&TrainingSet` and `&ShardSet` convert into it with `From`.
#[derive(Clone, Copy)]
pub enum TrainData<'a> {
    Memory(&'a TrainingSet<'a>),
    Shards(&'a ShardSet),
}

impl<'a, 'b: 'a> From<&'a TrainingSet<'b>> for TrainData<'a> {
    fn from(set: &'a TrainingSet<'b>) -> Self {
        TrainData::Memory(set)
    }
}

impl<'a> From<&'a ShardSet> for TrainData<'a> {
    fn from(set: &'a ShardSet) -> Self {
        TrainData::Shards(set)
    }
}

impl<'a> TrainData<'a> {
    /// The data as trees read it; an in-memory set's targets are checked first (their counts
    /// against the parts', then their values).
    pub fn inputs(self) -> Result<TrainInputs<'a>> {
        let data = match self {
            TrainData::Shards(shards) => return Ok(shards.inputs()),
            TrainData::Memory(data) => data,
        };
        data.check_counts()?;
        if !data.parts.is_empty() {
            data.targets.validate()?;
        }
        Ok(TrainInputs {
            store: data.store,
            parts: data.parts,
            offsets: data.targets.offsets,
            rotations: data.targets.rotations,
            wide: &data.targets,
        })
    }
}

/// What [`Forest::prepare`] builds once per training set.
pub struct Prepared {
    targets: Targets,
    crit: Criterion,
    /// The data's counts for the model's training summary.
    pub counts: TrainingSummary,
}

impl ShardSet {
    /// The set as trees read it.
    pub fn inputs(&self) -> TrainInputs<'_> {
        TrainInputs {
            store: &self.store,
            parts: &self.parts,
            offsets: &self.offsets,
            rotations: &self.rotations,
            wide: self,
        }
    }

    /// The data counts of a shard folder's manifest (as [`Prepared::counts`] would say).
    pub fn counts(manifest: &crate::shards::Manifest) -> TrainingSummary {
        TrainingSummary {
            n_parts: manifest.n_parts(),
            n_images: manifest.n_images(),
            link_angle_dims: manifest.link_angles.unwrap_or(0),
            node_offset_dims: manifest.node_offsets.unwrap_or(0),
            ..Default::default()
        }
    }
}

/// One vote of one part through one tree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartVote {
    pub part: u32,
    pub tree: u32,
    pub vote: Vote,
}

/// A trained forest, its metadata and its inference defaults.
// Plain fields (`duplicates` pairs them by shape with `DetectParams`'; nothing shared).
#[derive(Clone, Debug, PartialEq)]
pub struct Forest {
    pub params: ForestParams,
    pub trees: Vec<Tree>,
    /// Category, origin, box, training summary, extra JSON (stored in the model file).
    pub metadata: ModelMetadata,
    /// Inference parameters `predict` starts from (stored in the model file); callers overlay
    /// their own on top (`PredictParams::overlay`).
    pub predict_defaults: Valid<PredictParams>,
    /// Version of the crate that trained (or wrote) this forest.
    pub crate_version: String,
    /// Per-leaf vote weights from background parts (`None`: one-class, every vote counts
    /// fully); set with [`Forest::with_leaf_weights`].
    pub leaf_weights: Option<LeafWeights>,
    /// The trees prepared for fast inference (built on the first prediction).
    pub(crate) flat: flat::FlatCache,
}

/// Runs `f` on a pool of `n_threads` threads, or on rayon's global pool when `None`.
pub fn with_threads<T: Send>(n_threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    match n_threads {
        None => Ok(f()),
        Some(0) => Err(IsaError::InvalidParameter(
            "n_threads must be at least 1".into(),
        )),
        Some(k) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(k)
                .build()
                .map_err(|e| {
                    IsaError::InvalidParameter(format!("n_threads: cannot start {k} threads: {e}"))
                })?;
            Ok(pool.install(f))
        }
    }
}

impl Forest {
    /// Trains a forest on an in-memory [`TrainingSet`] or a [`ShardSet`] (see [`TrainData`]).
    /// The model (and its file bytes) depends only on `params` (incl. the seed) and the data,
    /// not on `n_threads`.
    pub fn fit<'a>(
        params: &Valid<ForestParams>,
        data: impl Into<TrainData<'a>>,
        metadata: ModelMetadata,
        n_threads: Option<usize>,
    ) -> Result<Forest> {
        Self::fit_with_progress(params, data, metadata, n_threads, &|_| {})
    }

    /// [`Forest::fit`], calling `on_tree(trees_done)` after each tree (trees are built one after
    /// the other), e.g. to drive a progress bar. `metadata.training` is set to the data's counts;
    /// the inference defaults are [`PredictParams::default`] (set `predict_defaults` after).
    pub fn fit_with_progress<'a>(
        params: &Valid<ForestParams>,
        data: impl Into<TrainData<'a>>,
        metadata: ModelMetadata,
        n_threads: Option<usize>,
        on_tree: &(dyn Fn(usize) + Sync),
    ) -> Result<Forest> {
        let data = data.into().inputs()?;
        with_threads(n_threads, || -> Result<Forest> {
            let prep = Self::prepare(params, &data)?;
            // Trees one after the other, each using every thread (level-wise, see `tree`): the
            // working memory is that of one tree.
            let trees = (0..params.n_trees)
                .map(|t| {
                    let tree = Self::fit_tree(params, &data, &prep, t)?;
                    on_tree(t + 1);
                    Ok(tree)
                })
                .collect::<Result<Vec<Tree>>>()?;
            Self::assemble(params, trees, metadata, &prep.counts)
        })?
    }

    /// Checks the data and builds what every tree reads (the criterion's targets); done once
    /// per training set, then [`Forest::fit_tree`] for each tree, on any machine.
    pub fn prepare(params: &Valid<ForestParams>, data: &TrainInputs<'_>) -> Result<Prepared> {
        let params: &ForestParams = params;
        let n = data.parts.len();
        if n == 0 {
            return Err(IsaError::InvalidInput("parts: no training parts".into()));
        }
        if data.offsets.len() != 3 * n || data.rotations.len() != 4 * n {
            return Err(IsaError::InvalidInput(format!(
                "offsets / rotations: expected ({n}, 3) / ({n}, 4) for {n} parts, got {} / {} values",
                data.offsets.len(),
                data.rotations.len()
            )));
        }
        if n > u32::MAX as usize / 2 {
            return Err(IsaError::InvalidInput(format!(
                "parts: {n} parts is too many"
            )));
        }
        data.store.validate_parts(data.parts)?;
        let targets = build_targets_from(
            data.offsets,
            data.rotations,
            data.wide,
            params.quality,
            params.reduce_dims,
        )?;
        let crit = Criterion::new(targets.layout.clone(), params.reg);
        Ok(Prepared {
            targets,
            crit,
            counts: TrainingSummary {
                n_parts: n,
                n_images: data.store.len(),
                link_angle_dims: data.wide.width(Term::Links).unwrap_or(0),
                node_offset_dims: data.wide.width(Term::Nodes).unwrap_or(0),
                ..Default::default()
            },
        })
    }

    /// Tree `t` of the forest (its bag and node seeds derive from `params.seed` and `t` alone,
    /// so trees fitted apart assemble into the forest [`Forest::fit`] makes).
    pub fn fit_tree(
        params: &Valid<ForestParams>,
        data: &TrainInputs<'_>,
        prep: &Prepared,
        t: usize,
    ) -> Result<Tree> {
        let params: &ForestParams = params;
        if t >= params.n_trees {
            return Err(IsaError::InvalidInput(format!(
                "tree: index {t} out of range (the forest has {} trees)",
                params.n_trees
            )));
        }
        if prep.targets.n != data.parts.len() {
            return Err(IsaError::InvalidInput(format!(
                "tree: prepared for {} parts, given {}",
                prep.targets.n,
                data.parts.len()
            )));
        }
        let n = data.parts.len();
        let ctx = TrainContext {
            params,
            store: data.store,
            parts: data.parts,
            offsets: data.offsets,
            rotations: data.rotations,
            targets: &prep.targets,
            crit: &prep.crit,
        };
        let n_bag = ((n as f64 * params.bag_fraction).round() as usize).clamp(1, n);
        let bag: Vec<u32> = if n_bag == n {
            (0..n as u32).collect()
        } else {
            let mut rng = ChaCha8Rng::seed_from_u64(mix(&[params.seed, t as u64, 0xba66]));
            let mut v: Vec<u32> = sample(&mut rng, n, n_bag)
                .into_iter()
                .map(|i| i as u32)
                .collect();
            v.sort_unstable();
            v
        };
        Ok(build_tree(&ctx, t, bag))
    }

    /// The forest of `trees` (tree `t` at index `t`, from [`Forest::fit_tree`]) with the data's
    /// `counts` (from [`Prepared::counts`], or [`ShardSet`]'s manifest) joining whatever
    /// `metadata.training` says.
    pub fn assemble(
        params: &Valid<ForestParams>,
        trees: Vec<Tree>,
        mut metadata: ModelMetadata,
        counts: &TrainingSummary,
    ) -> Result<Forest> {
        if trees.len() != params.n_trees {
            return Err(IsaError::InvalidInput(format!(
                "trees: {} given, the parameters say {}",
                trees.len(),
                params.n_trees
            )));
        }
        // The counts join whatever the trainer said about its data.
        let extra = metadata
            .training
            .take()
            .map(|t| t.extra)
            .unwrap_or_default();
        metadata.training = Some(TrainingSummary {
            extra,
            ..counts.clone()
        });
        Ok(Forest {
            params: (**params).clone(),
            trees,
            metadata,
            predict_defaults: Valid::default(),
            crate_version: crate::VERSION.to_string(),
            leaf_weights: None,
            flat: Default::default(),
        })
    }

    /// This forest with per-leaf vote weights (one per leaf of each tree, in [0, 1]; see
    /// [`LeafWeights`]), or without any (`None`).
    pub fn with_leaf_weights(mut self, per_tree: Option<Vec<Vec<f32>>>) -> Result<Forest> {
        self.leaf_weights = per_tree
            .map(|w| LeafWeights::new(w, &self.trees))
            .transpose()?;
        Ok(self)
    }

    pub fn n_trees(&self) -> usize {
        self.trees.len()
    }

    /// Leaf index of every (part, tree): `out[p * n_trees + t]`. Parts are validated.
    pub fn apply(&self, store: &DepthStore, parts: &[Part]) -> Result<Vec<u32>> {
        store.validate_parts(parts)?;
        let t = self.trees.len();
        let mut out = vec![0u32; parts.len() * t];
        if t == 0 {
            return Ok(out);
        }
        // Blocks of parts, tree by tree inside a block: a tree's upper nodes stay in cache.
        const BLOCK: usize = 256;
        out.par_chunks_mut(BLOCK * t)
            .zip(parts.par_chunks(BLOCK))
            .for_each(|(rows, ps)| {
                let geoms: Vec<crate::features::PartGeom<'_>> = ps
                    .iter()
                    .map(|p| crate::features::PartGeom::new(store, p))
                    .collect();
                for (ti, tree) in self.trees.iter().enumerate() {
                    for (k, g) in geoms.iter().enumerate() {
                        rows[k * t + ti] = tree.leaf_of_geom(g);
                    }
                }
            });
        Ok(out)
    }

    /// The vote modes of leaf `leaf` of tree `tree` (empty if either is out of range).
    pub fn leaf_votes(&self, tree: usize, leaf: usize) -> &[Vote] {
        self.trees.get(tree).map_or(&[], |t| t.leaf_votes(leaf))
    }

    /// Every vote of every part through every tree, ordered by part, then tree, then weight.
    pub fn part_votes(&self, store: &DepthStore, parts: &[Part]) -> Result<Vec<PartVote>> {
        let leaves = self.apply(store, parts)?;
        let t = self.trees.len();
        let mut out = Vec::new();
        for (p, row) in leaves.chunks(t.max(1)).enumerate() {
            for (ti, &l) in row.iter().enumerate() {
                for v in self.leaf_votes(ti, l as usize) {
                    out.push(PartVote {
                        part: p as u32,
                        tree: ti as u32,
                        vote: *v,
                    });
                }
            }
        }
        Ok(out)
    }

    /// Total nodes and leaves over all trees.
    pub fn size(&self) -> (usize, usize) {
        (
            self.trees.iter().map(|t| t.nodes.len()).sum(),
            self.trees.iter().map(|t| t.n_leaves()).sum(),
        )
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::error::expect_err;

    /// Toy problem: 20x20 planes at 1 m; a part's SSC offset is the vector to the image centre
    /// (1 cm per pixel). Features reach the image border (background), so the answer is learnable.
    pub(crate) fn toy(n_images: usize) -> (DepthStore, Vec<Part>, Vec<f32>, Vec<f32>) {
        let mut store = DepthStore::new();
        let (w, h) = (20usize, 20usize);
        let mut parts = Vec::new();
        let mut off = Vec::new();
        let mut rot = Vec::new();
        for i in 0..n_images {
            store.push(w, h, &vec![1000u16; w * h]).unwrap();
            for v in 0..h as i32 {
                for u in 0..w as i32 {
                    parts.push([i as i32, u, v]);
                    off.extend_from_slice(&[(9.5 - u as f32) * 0.01, (9.5 - v as f32) * 0.01, 0.0]);
                    let a = if u < 10 { 0.0f32 } else { 0.5 };
                    rot.extend_from_slice(&[(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()]);
                }
            }
        }
        (store, parts, off, rot)
    }

    pub(crate) fn toy_params() -> ForestParams {
        ForestParams {
            n_trees: 3,
            max_depth: 12,
            min_samples_split: 4,
            min_samples_leaf: 2,
            n_candidates: 40,
            max_offset: 25.0,
            quality: crate::params::Quality::Q1,
            vote_bandwidth_offset: 0.02,
            ..Default::default()
        }
    }

    /// [`toy_params`] with bagging and sampled split scores (the paths a tree's RNG drives).
    pub(crate) fn sampled_params() -> ForestParams {
        ForestParams {
            max_score_samples: 300,
            bag_fraction: 0.7,
            ..toy_params()
        }
    }

    /// A Q1 training set (no privileged data) over the toy arrays.
    pub(crate) fn q1_set<'a>(
        store: &'a DepthStore,
        parts: &'a [Part],
        off: &'a [f32],
        rot: &'a [f32],
    ) -> TrainingSet<'a> {
        TrainingSet {
            store,
            parts,
            targets: RawTargets::pose(off, rot),
        }
    }

    #[test]
    fn toy_problem_is_recovered() {
        let (store, parts, off, rot) = toy(2);
        let data = q1_set(&store, &parts, &off, &rot);
        let f = Forest::fit(
            &toy_params().check().unwrap(),
            &data,
            Default::default(),
            None,
        )
        .unwrap();
        let leaves = f.apply(&store, &parts).unwrap();
        let mut good = 0;
        for (p, row) in leaves.chunks(f.n_trees()).enumerate() {
            let v = f.leaf_votes(0, row[0] as usize)[0];
            let e = ((v.offset[0] - off[3 * p]).powi(2) + (v.offset[1] - off[3 * p + 1]).powi(2))
                .sqrt();
            let a = crate::rotation::quat_angle(
                v.rotation.map(f64::from),
                std::array::from_fn(|k| f64::from(rot[4 * p + k])),
            );
            if e < 0.03 && a < 0.1 {
                good += 1;
            }
        }
        assert!(
            good as f64 > 0.9 * parts.len() as f64,
            "{good} of {}",
            parts.len()
        );
        let votes = f.part_votes(&store, &parts[..5]).unwrap();
        assert!(votes
            .iter()
            .all(|v| v.vote.weight > 0.0 && v.vote.weight <= 1.0));
    }

    #[test]
    fn scoring_a_level_in_chunks_of_nodes_changes_no_tree() {
        let (store, parts, off, rot) = toy(3);
        let set = q1_set(&store, &parts, &off, &rot);
        let p = sampled_params().check().unwrap();
        let inputs = TrainInputs {
            store: &store,
            parts: &parts,
            offsets: &off,
            rotations: &rot,
            wide: &set.targets,
        };
        let prep = Forest::prepare(&p, &inputs).unwrap();
        let ctx = TrainContext {
            params: &p,
            store: &store,
            parts: &parts,
            offsets: &off,
            rotations: &rot,
            targets: &prep.targets,
            crit: &prep.crit,
        };
        let bag: Vec<u32> = (0..parts.len() as u32).step_by(2).collect();
        let whole = build_tree(&ctx, 1, bag.clone());
        assert!(
            whole.nodes.len() > 20,
            "a tree of {} nodes",
            whole.nodes.len()
        );
        // 1 row: every node a chunk of its own; 700: several nodes a chunk.
        for rows in [1, 700] {
            assert_eq!(
                crate::tree::grow_tree(&ctx, 1, bag.clone(), rows),
                whole,
                "{rows} rows"
            );
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let (store, parts, off, rot) = toy(2);
        let data = q1_set(&store, &parts, &off, &rot);
        let p = sampled_params();
        // The model file of `p` fitted on `threads` threads.
        let bytes = |p: &ForestParams, threads: usize| {
            Forest::fit(
                &p.clone().check().unwrap(),
                &data,
                Default::default(),
                Some(threads),
            )
            .unwrap()
            .to_bytes()
        };
        let a = bytes(&p, 1);
        assert_eq!(a, bytes(&p, 2));
        assert_ne!(a, bytes(&ForestParams { seed: 1, ..p }, 2));
    }

    #[test]
    fn progress_reports_each_tree_in_order_and_changes_nothing() {
        let (store, parts, off, rot) = toy(2);
        let data = q1_set(&store, &parts, &off, &rot);
        let p = ForestParams {
            n_trees: 3,
            ..toy_params()
        };
        let seen = std::sync::Mutex::new(Vec::new());
        let with = Forest::fit_with_progress(
            &p.clone().check().unwrap(),
            &data,
            Default::default(),
            Some(2),
            &|k| seen.lock().unwrap().push(k),
        )
        .unwrap();
        assert_eq!(*seen.lock().unwrap(), vec![1, 2, 3]);
        let without = Forest::fit(
            &p.clone().check().unwrap(),
            &data,
            Default::default(),
            Some(2),
        )
        .unwrap();
        assert_eq!(with.to_bytes(), without.to_bytes());
    }

    /// The toy set as a `.isat` training set with (synthetic) privileged targets.
    fn toy_trainset(n_images: usize) -> crate::trainset_io::TrainSetData {
        let (store, parts, offsets, rotations) = toy(n_images);
        let p = parts.len();
        let la: Vec<f32> = (0..2 * p)
            .map(|k| ((k * 7919) % 628) as f32 * 0.01 - std::f32::consts::PI)
            .collect();
        let no: Vec<f32> = (0..6 * p)
            .map(|k| offsets[(k / 6) * 3 + k % 3] * 100.0 + (k % 6) as f32)
            .collect();
        crate::trainset_io::TrainSetData {
            store,
            parts,
            offsets,
            rotations,
            link_angles: Some((la, 2)),
            node_offsets: Some((no, 6)),
            metadata: "{}".into(),
        }
    }

    #[test]
    fn trees_fitted_apart_and_shards_give_the_same_bytes() {
        let ts = toy_trainset(3);
        let p = ForestParams {
            quality: crate::params::Quality::Q1Q2Q3,
            reduce_dims: 2,
            bag_fraction: 0.8,
            max_score_samples: 300,
            ..toy_params()
        }
        .check()
        .unwrap();
        let whole = Forest::fit(&p, &ts.training_set(), Default::default(), Some(2))
            .unwrap()
            .to_bytes();
        // Shards of 1 and 2 images, opened from disk.
        let dir =
            crate::shards::tests::write_shards("fit", &crate::shards::tests::split(&ts, &[1]));
        let set = ShardSet::open(&dir).unwrap();
        let sharded =
            Forest::fit_with_progress(&p, &set, Default::default(), Some(1), &|_| {}).unwrap();
        assert_eq!(sharded.to_bytes(), whole);
        // Trees one at a time, in reverse order, through their bytes, then assembled.
        let prep = Forest::prepare(&p, &set.inputs()).unwrap();
        let mut trees: Vec<Tree> = (0..p.n_trees)
            .rev()
            .map(|t| {
                let b = crate::model_io::encode_tree(
                    &Forest::fit_tree(&p, &set.inputs(), &prep, t).unwrap(),
                );
                crate::model_io::decode_tree(&b, "tree").unwrap()
            })
            .collect();
        trees.reverse();
        let counts = ShardSet::counts(&set.manifest);
        assert_eq!(counts, prep.counts);
        assert_eq!(
            Forest::assemble(&p, trees, Default::default(), &counts)
                .unwrap()
                .to_bytes(),
            whole
        );
        assert!(Forest::fit_tree(&p, &set.inputs(), &prep, p.n_trees).is_err());
        let b = crate::model_io::encode_tree(&sharded.trees[0]);
        expect_err(
            crate::model_io::decode_tree(&b[..b.len() - 1], "tree 0"),
            &["tree 0"],
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (store, parts, off, rot) = toy(1);
        let raw = RawTargets::pose(&off, &rot);
        let mut bad_parts = parts.clone();
        bad_parts[3] = [5, 0, 0];
        let data = TrainingSet {
            store: &store,
            parts: &bad_parts,
            targets: raw,
        };
        assert!(matches!(
            Forest::fit(
                &toy_params().check().unwrap(),
                &data,
                Default::default(),
                None
            ),
            Err(IsaError::InvalidInput(_))
        ));
        let data = TrainingSet {
            store: &store,
            parts: &parts,
            targets: raw,
        };
        let p = ForestParams {
            quality: crate::params::Quality::Q1Q2,
            ..toy_params()
        };
        expect_err(
            Forest::fit(&p.clone().check().unwrap(), &data, Default::default(), None),
            &["link_angles"],
        );
        let mut nan = off.clone();
        nan[7] = f32::NAN;
        let data = TrainingSet {
            store: &store,
            parts: &parts,
            targets: RawTargets {
                offsets: &nan,
                ..raw
            },
        };
        expect_err(
            Forest::fit(
                &toy_params().check().unwrap(),
                &data,
                Default::default(),
                None,
            ),
            &["offsets[2, 1]"],
        );
    }
}
