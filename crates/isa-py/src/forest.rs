//! `isa._core.Forest`: fit / save / load / pickle / leaves and votes of parts.
//!
//! Threads: the object is immutable to pyo3 (`frozen`) and keeps its state behind a lock that
//! is held only to read or swap it, never while the core works. A call takes the current
//! trained forest (an `Arc`) and runs on it with the GIL released; `fit`, `__setstate__` and
//! the `n_threads` setter swap in new state that later calls see, while calls in progress
//! finish on what they took. So reads are concurrent and a change while in use neither fails
//! nor waits for them (pyo3's mutable borrow raised a generic `RuntimeError: Already
//! borrowed`).

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, RwLock};

use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};

use isa_core::metadata::split_metadata;
use isa_core::model_io::decode_tree;
use isa_core::shards::{Manifest, ShardSet};
use isa_core::vote as core_vote;
use isa_core::{DepthStore, Forest, ForestParams, ModelMetadata, Part, PredictParams, Valid};

use crate::arrays::{as_slice, depth_store, f32_array, matrix, parts as parts_arg, rows, vector};
use crate::errors::{input_err, to_py};
use crate::params::{forest_params, json_to_py, kwargs_json};
use crate::trainset::PyTrainSet;
use crate::{hypothesis, predict, scalars};

/// A forest of randomised trees voting for the SSC offset and rotation of depth-image parts
/// (the ISA forest, paper Section 3.3).
#[pyclass(name = "Forest", module = "isa._core", frozen)]
pub struct PyForest {
    state: RwLock<State>,
    /// 0 = None (all cores).
    n_threads: AtomicUsize,
}

#[derive(Clone)]
struct State {
    params: Valid<ForestParams>,
    forest: Option<Arc<Forest>>,
}

impl State {
    fn of(f: Forest) -> Self {
        State {
            params: f
                .params
                .clone()
                .check()
                .expect("a forest's parameters are valid"),
            forest: Some(Arc::new(f)),
        }
    }
}

impl PyForest {
    fn new_with(state: State, n_threads: Option<usize>) -> Self {
        PyForest {
            state: RwLock::new(state),
            n_threads: AtomicUsize::new(n_threads.unwrap_or(0)),
        }
    }
    fn state(&self) -> State {
        self.state.read().unwrap_or_else(|p| p.into_inner()).clone()
    }
    fn set_state(&self, s: State) {
        *self.state.write().unwrap_or_else(|p| p.into_inner()) = s;
    }
    fn fitted(&self) -> PyResult<Arc<Forest>> {
        self.state()
            .forest
            .ok_or_else(|| input_err("this Forest is not fitted: call fit() or Forest.load()"))
    }
    pub fn from_core(f: Forest) -> Self {
        PyForest::new_with(State::of(f), None)
    }
    /// The trained core forest (for other bindings, e.g. prediction).
    pub fn core(&self) -> PyResult<Arc<Forest>> {
        self.fitted()
    }
    /// The thread setting (None = all cores).
    pub fn threads(&self) -> Option<usize> {
        Some(self.n_threads.load(Ordering::Relaxed)).filter(|&n| n > 0)
    }
}

fn metadata_arg(o: &Bound<'_, PyAny>) -> PyResult<String> {
    scalars::text(o, "metadata")
}

fn optional_metadata_arg(o: &Bound<'_, PyAny>) -> PyResult<Option<String>> {
    if o.is_none() {
        Ok(None)
    } else {
        metadata_arg(o).map(Some)
    }
}

impl PyForest {
    /// Keeps a trained forest (with the parameters it was trained with and its inference
    /// defaults); the first error of the progress hook, if any, is raised now.
    fn finish(
        &self,
        params: Valid<ForestParams>,
        forest: isa_core::Result<Forest>,
        defaults: Valid<PredictParams>,
        hook_err: Mutex<Option<PyErr>>,
    ) -> PyResult<()> {
        let mut forest = forest.map_err(to_py)?;
        forest.predict_defaults = defaults;
        if let Some(e) = hook_err.into_inner().unwrap_or_else(|p| p.into_inner()) {
            return Err(e);
        }
        self.set_state(State {
            params,
            forest: Some(Arc::new(forest)),
        });
        Ok(())
    }

    /// Runs `fit(params, n_threads, on_tree hook)` without the GIL on this forest's parameters
    /// and keeps the result ([`PyForest::finish`]): `fit` and `fit_shards`.
    fn train(
        &self,
        py: Python<'_>,
        defaults: Valid<PredictParams>,
        on_tree: Option<Py<PyAny>>,
        fit: impl FnOnce(
                &Valid<ForestParams>,
                Option<usize>,
                &(dyn Fn(usize) + Sync),
            ) -> isa_core::Result<Forest>
            + Send,
    ) -> PyResult<()> {
        let params = self.state().params;
        let threads = self.threads();
        let hook_err: Mutex<Option<PyErr>> = Mutex::new(None);
        let forest = py.detach(|| fit(&params, threads, &tree_hook(&on_tree, &hook_err)));
        self.finish(params, forest, defaults, hook_err)
    }

    /// Runs `run(forest, images, parts)` without the GIL with this forest's thread setting:
    /// `apply` and `votes`.
    fn on_parts<T: Send>(
        &self,
        py: Python<'_>,
        images: &Bound<'_, PyAny>,
        parts: &Bound<'_, PyAny>,
        run: impl FnOnce(&Forest, &DepthStore, &[Part]) -> isa_core::Result<T> + Send,
    ) -> PyResult<T> {
        let f = self.fitted()?;
        let store = depth_store(images)?;
        let parts = parts_arg(parts)?;
        let threads = self.threads();
        py.detach(|| isa_core::forest::with_threads(threads, || run(&f, &store, &parts)))
            .map_err(to_py)?
            .map_err(to_py)
    }
}

/// A model's metadata and inference defaults from ``metadata`` JSON and ``predict_defaults``.
fn model_defaults(
    metadata: &str,
    predict_defaults: Option<&Bound<'_, PyDict>>,
) -> PyResult<(ModelMetadata, Valid<PredictParams>)> {
    let (meta, defaults) = split_metadata(metadata, "metadata", false).map_err(to_py)?;
    let defaults = defaults
        .with_overrides(&kwargs_json(predict_defaults)?, "predict_defaults")
        .map_err(to_py)?;
    Ok((meta, defaults))
}

/// The per-tree callback of ``on_tree``; its first exception is kept in `err`.
fn tree_hook<'a>(
    on_tree: &'a Option<Py<PyAny>>,
    err: &'a Mutex<Option<PyErr>>,
) -> impl Fn(usize) + Sync + 'a {
    move |done: usize| {
        if let Some(cb) = on_tree {
            Python::attach(|py| {
                if let Err(e) = cb.call1(py, (done,)) {
                    err.lock()
                        .unwrap_or_else(|p| p.into_inner())
                        .get_or_insert(e);
                }
            });
        }
    }
}

const STATE_UNFITTED: &[u8] = b"ISA-UNFITTED\0";

#[pymethods]
impl PyForest {
    #[new]
    #[pyo3(signature = (*, n_threads=None, **params))]
    fn new(
        n_threads: Option<&Bound<'_, PyAny>>,
        params: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let n_threads = scalars::n_threads(n_threads)?;
        let state = State {
            params: forest_params(params)?,
            forest: None,
        };
        Ok(PyForest::new_with(state, n_threads))
    }

    /// Trains the forest on a ``TrainSet`` (the GIL is released while training).
    /// ``metadata``: a JSON object (category, centre, box, extra keys; a ``predict_defaults``
    /// key in it is read as inference defaults), by default the set's own; ``predict_defaults``:
    /// inference defaults (flat keys), overlaid on those. ``on_tree(trees_done)``, if given, is
    /// called after each tree (for a progress bar); its first exception is raised once training
    /// ends.
    #[pyo3(signature = (trainset, metadata=None, on_tree=None, predict_defaults=None))]
    fn fit(
        &self,
        py: Python<'_>,
        trainset: PyRef<'_, PyTrainSet>,
        #[pyo3(from_py_with = optional_metadata_arg)] metadata: Option<String>,
        on_tree: Option<Py<PyAny>>,
        predict_defaults: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<()> {
        let metadata = metadata.unwrap_or_else(|| trainset.metadata().to_string());
        let (meta, defaults) = model_defaults(&metadata, predict_defaults)?;
        trainset.with_training_set(py, |data| {
            self.train(py, defaults, on_tree, |params, threads, hook| {
                Forest::fit_with_progress(params, data, meta, threads, hook)
            })
        })
    }

    /// Trains from a shard folder (``isa_core::shards``: ``manifest.json`` and its ``.isat``
    /// shards); the same model bytes as ``fit`` on the shards' arrays concatenated. Arguments
    /// as ``fit``'s.
    #[pyo3(signature = (shards, metadata=String::from("{}"), on_tree=None, predict_defaults=None))]
    fn fit_shards(
        &self,
        py: Python<'_>,
        shards: PathBuf,
        #[pyo3(from_py_with = metadata_arg)] metadata: String,
        on_tree: Option<Py<PyAny>>,
        predict_defaults: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<()> {
        let (meta, defaults) = model_defaults(&metadata, predict_defaults)?;
        self.train(py, defaults, on_tree, |params, threads, hook| {
            Forest::fit_with_progress(params, &ShardSet::open(&shards)?, meta, threads, hook)
        })
    }

    /// Assembles the forest from its trees' bytes (``ShardTrainer.fit_tree(t)`` for every tree
    /// ``t``, in order) and the shard folder they were fitted on (for its counts): the model
    /// ``fit_shards`` makes, to the byte. ``metadata`` and ``predict_defaults`` as in ``fit``.
    #[pyo3(signature = (trees, shards, metadata=String::from("{}"), predict_defaults=None))]
    fn assemble(
        &self,
        trees: Vec<Vec<u8>>,
        shards: PathBuf,
        #[pyo3(from_py_with = metadata_arg)] metadata: String,
        predict_defaults: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<()> {
        let (meta, defaults) = model_defaults(&metadata, predict_defaults)?;
        let params = self.state().params;
        let manifest = Manifest::read(&shards).map_err(to_py)?;
        let trees = trees
            .iter()
            .enumerate()
            .map(|(t, b)| decode_tree(b, &format!("trees[{t}]")))
            .collect::<isa_core::Result<Vec<_>>>()
            .map_err(to_py)?;
        let forest = Forest::assemble(&params, trees, meta, &ShardSet::counts(&manifest));
        self.finish(params, forest, defaults, Mutex::new(None))
    }

    /// Saves the model atomically (temporary file + rename).
    fn save(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = scalars::path(path, "path")?;
        let f = self.fitted()?;
        py.detach(|| f.save(&path)).map_err(to_py)
    }

    /// Loads a model file; raises ModelFormatError for a bad file, IsaIOError if unreadable.
    #[staticmethod]
    #[pyo3(signature = (path, *, n_threads=None))]
    fn load(
        py: Python<'_>,
        path: &Bound<'_, PyAny>,
        n_threads: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let path = scalars::path(path, "path")?;
        let n_threads = scalars::n_threads(n_threads)?;
        let f = py.detach(|| Forest::load(&path)).map_err(to_py)?;
        Ok(PyForest::new_with(State::of(f), n_threads))
    }

    /// The model-file bytes.
    fn to_bytes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        Ok(PyBytes::new(py, &self.fitted()?.to_bytes()))
    }

    #[staticmethod]
    fn from_bytes(data: &Bound<'_, PyAny>) -> PyResult<Self> {
        let data = scalars::bytes(data, "data")?;
        Ok(PyForest::from_core(
            Forest::from_bytes(&data).map_err(to_py)?,
        ))
    }

    fn __getstate__<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        let s = self.state();
        match &s.forest {
            Some(f) => PyBytes::new(py, &f.to_bytes()),
            None => {
                let mut b = STATE_UNFITTED.to_vec();
                b.extend_from_slice(s.params.to_json().as_bytes());
                PyBytes::new(py, &b)
            }
        }
    }

    fn __setstate__(&self, state: &Bound<'_, PyAny>) -> PyResult<()> {
        let state = scalars::bytes(state, "state")?;
        let new = if let Some(rest) = state.strip_prefix(STATE_UNFITTED) {
            let s = std::str::from_utf8(rest)
                .map_err(|_| input_err("pickled Forest state is not UTF-8"))?;
            State {
                params: ForestParams::from_json(s).map_err(to_py)?,
                forest: None,
            }
        } else {
            State::of(Forest::from_bytes(&state).map_err(to_py)?)
        };
        self.set_state(new);
        Ok(())
    }

    /// Leaf index of every part in every tree: (P, n_trees) int32.
    fn apply<'py>(
        &self,
        py: Python<'py>,
        images: &Bound<'py, PyAny>,
        parts: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<i32>>> {
        let (leaves, n_parts, n_trees) = self.on_parts(py, images, parts, |f, store, parts| {
            Ok((f.apply(store, parts)?, parts.len(), f.n_trees()))
        })?;
        let v: Vec<i32> = leaves.into_iter().map(|x| x as i32).collect();
        Ok(matrix(py, n_parts, n_trees, v))
    }

    /// Every vote of every part through every tree, as a dict of flat arrays (V = number of
    /// votes): part (V,) int32, tree (V,) int32, weight (V,) float32, offset (V, 3) float32,
    /// rotation (V, 4) float32 (w, x, y, z). Ordered by part, tree, decreasing weight.
    fn votes<'py>(
        &self,
        py: Python<'py>,
        images: &Bound<'py, PyAny>,
        parts: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let votes = self.on_parts(py, images, parts, |f, store, parts| {
            f.part_votes(store, parts)
        })?;
        let d = PyDict::new(py);
        d.set_item(
            "part",
            vector(py, votes.iter().map(|v| v.part as i32).collect()),
        )?;
        d.set_item(
            "tree",
            vector(py, votes.iter().map(|v| v.tree as i32).collect()),
        )?;
        d.set_item(
            "weight",
            vector(py, votes.iter().map(|v| v.vote.weight).collect()),
        )?;
        d.set_item("offset", rows(py, votes.iter().map(|v| v.vote.offset)))?;
        d.set_item("rotation", rows(py, votes.iter().map(|v| v.vote.rotation)))?;
        Ok(d)
    }

    /// Vote modes of one leaf: (weights (k,), offsets (k, 3), rotations (k, 4)).
    #[allow(clippy::type_complexity)]
    fn leaf_votes<'py>(
        &self,
        py: Python<'py>,
        tree: &Bound<'py, PyAny>,
        leaf: &Bound<'py, PyAny>,
    ) -> PyResult<(
        Bound<'py, PyArray1<f32>>,
        Bound<'py, PyArray2<f32>>,
        Bound<'py, PyArray2<f32>>,
    )> {
        let tree = scalars::count(tree, "tree", 0, input_err)?;
        let leaf = scalars::count(leaf, "leaf", 0, input_err)?;
        let f = self.fitted()?;
        if tree >= f.n_trees() || leaf >= f.trees[tree].n_leaves() {
            return Err(input_err(format!("no leaf {leaf} in tree {tree}")));
        }
        let v = f.leaf_votes(tree, leaf);
        Ok((
            vector(py, v.iter().map(|x| x.weight).collect()),
            rows(py, v.iter().map(|x| x.offset)),
            rows(py, v.iter().map(|x| x.rotation)),
        ))
    }

    /// This forest with per-leaf vote weights (one float32 array of `n_leaves[t]` weights in
    /// [0, 1] per tree `t`), or without any (`None`): a new Forest, this one unchanged. Every
    /// vote of leaf `l` of tree `t` then counts `weights[t][l]` times its weight in `predict`.
    fn with_leaf_weights(&self, weights: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let f = self.fitted()?;
        let per_tree = match weights {
            None => None,
            Some(w) => Some(
                w.try_iter()
                    .map_err(|_| input_err("weights: a sequence of float32 arrays, one per tree"))?
                    .enumerate()
                    .map(|(t, a)| {
                        let name = format!("weights[{t}]");
                        Ok(as_slice(&f32_array(&a?, &name, &[None])?, &name)?.to_vec())
                    })
                    .collect::<PyResult<Vec<Vec<f32>>>>()?,
            ),
        };
        let forest = (*f).clone().with_leaf_weights(per_tree).map_err(to_py)?;
        Ok(PyForest::new_with(State::of(forest), self.threads()))
    }
    /// The per-leaf vote weights (one float32 array per tree), or None (one-class).
    #[getter]
    fn leaf_weights<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<Vec<Bound<'py, PyArray1<f32>>>>> {
        Ok(self
            .fitted()?
            .leaf_weights
            .as_ref()
            .map(|w| w.per_tree().iter().map(|t| vector(py, t.clone())).collect()))
    }

    /// Training configuration as JSON.
    #[getter]
    fn params_json(&self) -> String {
        self.state().params.to_json()
    }
    /// Metadata as a JSON object (category, centre, box, training summary, extra keys).
    #[getter]
    fn metadata(&self) -> PyResult<String> {
        Ok(self.fitted()?.metadata.to_json())
    }
    /// The inference defaults stored in the model (flat keys), which `predict` starts from.
    #[getter]
    fn predict_defaults<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let flat = self.fitted()?.predict_defaults.to_flat_json();
        json_to_py(py, &serde_json::Value::Object(flat))
    }

    /// Ranked 6D pose hypotheses of the objects in a whole depth image (paper Eq. 12-13).
    ///
    /// `depth`: (H, W) uint16 mm or float32/float64 metres; `K`: 3x3 matrix, (fx, fy, cx, cy)
    /// or `isa.camera.Intrinsics`. Keyword parameters (flat keys of `PREDICT_DEFAULTS`) overlay
    /// the model's `predict_defaults`. Returns `Hypothesis` objects, best first.
    #[pyo3(signature = (depth, K, *, n_threads=None, **params))]
    #[allow(non_snake_case)]
    fn predict<'py>(
        slf: &Bound<'py, Self>,
        depth: &Bound<'py, PyAny>,
        K: &Bound<'py, PyAny>,
        n_threads: Option<&Bound<'py, PyAny>>,
        params: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Bound<'py, PyList>> {
        let hyps = predict::on_image(slf, depth, K, n_threads, params, core_vote::predict)?;
        hypothesis::to_list(slf.py(), hyps)
    }

    // The arguments of `predict` (the public API); both are `predict::on_image`.
    /// Every vote of a whole depth image (for plots): dict of `position` (V, 3) float32 metres,
    /// `rotation` (V, 4) float32 (w, x, y, z), `weight` (V,) float32 (leaf share / n_trees),
    /// `pixel` (V, 2) int32 (u, v) of the casting part, `tree` (V,) int32, `n_parts` int.
    #[pyo3(signature = (depth, K, *, n_threads=None, **params))]
    #[allow(non_snake_case)]
    fn image_votes<'py>(
        slf: &Bound<'py, Self>,
        depth: &Bound<'py, PyAny>,
        K: &Bound<'py, PyAny>,
        n_threads: Option<&Bound<'py, PyAny>>,
        params: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let votes = predict::on_image(slf, depth, K, n_threads, params, core_vote::image_votes)?;
        predict::votes_dict(slf.py(), votes)
    }
    #[getter]
    fn is_fitted(&self) -> bool {
        self.state().forest.is_some()
    }
    #[getter]
    fn n_trees(&self) -> usize {
        let s = self.state();
        s.forest.as_ref().map_or(s.params.n_trees, |f| f.n_trees())
    }
    #[getter]
    fn n_threads(&self) -> Option<usize> {
        self.threads()
    }
    #[setter]
    fn set_n_threads(&self, n: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let n = scalars::n_threads(n)?;
        self.n_threads.store(n.unwrap_or(0), Ordering::Relaxed);
        Ok(())
    }
    /// Version of isa that trained the model.
    #[getter]
    fn crate_version(&self) -> PyResult<String> {
        Ok(self.fitted()?.crate_version.clone())
    }
    /// Number of nodes of each tree.
    #[getter]
    fn n_nodes(&self) -> PyResult<Vec<usize>> {
        Ok(self.fitted()?.trees.iter().map(|t| t.nodes.len()).collect())
    }
    /// Number of leaves of each tree.
    #[getter]
    fn n_leaves(&self) -> PyResult<Vec<usize>> {
        Ok(self.fitted()?.trees.iter().map(|t| t.n_leaves()).collect())
    }
    /// Depth of each tree.
    #[getter]
    fn depths(&self) -> PyResult<Vec<usize>> {
        Ok(self.fitted()?.trees.iter().map(|t| t.depth()).collect())
    }

    fn __repr__(&self) -> String {
        let s = self.state();
        match &s.forest {
            Some(f) => {
                let (n, l) = f.size();
                format!(
                    "Forest(n_trees={}, quality={:?}, nodes={n}, leaves={l})",
                    f.n_trees(),
                    f.params.quality.as_str()
                )
            }
            None => format!(
                "Forest(unfitted, n_trees={}, quality={:?})",
                s.params.n_trees,
                s.params.quality.as_str()
            ),
        }
    }
}
