//! Training-set shards (`isa_core::shards`): writing a folder's manifest, and
//! `isa._core.ShardTrainer`, which fits single trees of a forest from a shard folder (one task
//! per tree on a cluster; `Forest.assemble` puts them together).

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use isa_core::forest::{with_threads, Prepared};
use isa_core::model_io::encode_tree;
use isa_core::shards::{self, ShardSet};
use isa_core::{Forest, ForestParams, Valid};

use crate::errors::{param_err, to_py};
use crate::params::forest_params;

/// Writes ``dir/manifest.json`` for the shard files ``files`` (names inside ``dir``, in training
/// order), reading each to validate it; returns the manifest as JSON text. Atomic.
#[pyfunction]
pub fn write_shard_manifest(py: Python<'_>, dir: PathBuf, files: Vec<String>) -> PyResult<String> {
    let m = py
        .detach(|| shards::write_manifest(&dir, &files))
        .map_err(to_py)?;
    Ok(serde_json::to_string(&m).expect("a manifest serialises"))
}

/// A shard folder opened and prepared (targets built) for fitting single trees of the forest
/// of ``params`` (keyword arguments as ``Forest``'s).
#[pyclass(name = "ShardTrainer", module = "isa._core")]
pub struct PyShardTrainer {
    params: Valid<ForestParams>,
    set: ShardSet,
    prep: Prepared,
    n_threads: Option<usize>,
}

#[pymethods]
impl PyShardTrainer {
    #[new]
    #[pyo3(signature = (shards, *, n_threads=None, **params))]
    fn new(
        py: Python<'_>,
        shards: PathBuf,
        n_threads: Option<usize>,
        params: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        if n_threads == Some(0) {
            return Err(param_err(
                "n_threads must be at least 1 (or None for all cores)",
            ));
        }
        let params = forest_params(params)?;
        let (set, prep) = py
            .detach(|| {
                with_threads(n_threads, || -> isa_core::Result<_> {
                    let set = ShardSet::open(&shards)?;
                    let prep = Forest::prepare(&params, &set.inputs())?;
                    Ok((set, prep))
                })?
            })
            .map_err(to_py)?;
        Ok(PyShardTrainer {
            params,
            set,
            prep,
            n_threads,
        })
    }

    /// Tree ``t`` of the forest, as bytes for ``Forest.assemble`` (the GIL is released).
    fn fit_tree<'py>(&self, py: Python<'py>, t: usize) -> PyResult<Bound<'py, PyBytes>> {
        let bytes = py
            .detach(|| {
                with_threads(self.n_threads, || {
                    Forest::fit_tree(&self.params, &self.set.inputs(), &self.prep, t)
                        .map(|tree| encode_tree(&tree))
                })?
            })
            .map_err(to_py)?;
        Ok(PyBytes::new(py, &bytes))
    }

    /// Parts in the set.
    #[getter]
    fn n_parts(&self) -> usize {
        self.set.n_parts()
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SHARD_MANIFEST", shards::MANIFEST)?;
    m.add_function(wrap_pyfunction!(write_shard_manifest, m)?)?;
    m.add_class::<PyShardTrainer>()?;
    Ok(())
}
