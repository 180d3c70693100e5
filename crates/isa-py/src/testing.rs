//! `isa._core._testing`: the criterion and split-search hooks that the NumPy reference tests
//! and the benchmarks call (not part of the public API).

use numpy::prelude::*;
use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use isa_core::criterion::{build_targets, term_gains, Criterion};
use isa_core::splitter::{best_split_columns, SplitConfig};
use isa_core::Quality;

use crate::arrays::{array, describe, f32_array, matrix, Targets};
use crate::errors::{input_err, param_err, to_py};

/// The hooks' `targets`: the tuple `(offsets, rotations, link_angles, node_offsets)` of the
/// arrays `Forest.fit` takes (the last two None when absent).
fn targets_arg<'py>(targets: &Bound<'py, PyAny>) -> PyResult<Targets<'py>> {
    type Four<'py> = (
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
    );
    let (off, rot, la, no): Four<'py> = targets.extract().map_err(|_| {
        input_err(format!(
            "targets: expected (offsets, rotations, link_angles, node_offsets), got {}",
            describe(targets)
        ))
    })?;
    Targets::new(None, &off, &rot, Some(&la), Some(&no))
}

/// Test hook: gains of the criterion terms for splitting these parts by `left_mask`, computed
/// by the forest's own code (embedding, standardisation over these parts, optional reduction,
/// ridge `reg`). Returns {"Q1": g1} plus "Q2" / "Q3" when link angles / node offsets are given.
#[pyfunction]
#[pyo3(signature = (targets, left_mask, reg=1e-4, reduce_dims=0))]
pub fn criterion_gains<'py>(
    py: Python<'py>,
    targets: &Bound<'py, PyAny>,
    left_mask: &Bound<'py, PyAny>,
    reg: f64,
    reduce_dims: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let r = targets_arg(targets)?;
    let n = r.n_parts();
    let mask = array::<bool>(left_mask, "left_mask", "bool_", &[Some(n)])?;
    let g = term_gains(&r.raw(), mask.as_slice()?, reg, reduce_dims).map_err(to_py)?;
    let d = PyDict::new(py);
    d.set_item("Q1", g[0])?;
    if r.link_angles.is_some() {
        d.set_item("Q2", g[1])?;
    }
    if r.node_offsets.is_some() {
        d.set_item("Q3", g[2])?;
    }
    Ok(d)
}

/// The criterion's target vectors (embedded, standardised, optionally reduced): (P, D) float32
/// and the block sizes [offset 3, rotation 6, links, nodes].
#[pyfunction]
#[pyo3(signature = (targets, reduce_dims=0))]
pub fn criterion_targets<'py>(
    py: Python<'py>,
    targets: &Bound<'py, PyAny>,
    reduce_dims: usize,
) -> PyResult<(Bound<'py, PyArray2<f32>>, Vec<usize>)> {
    let r = targets_arg(targets)?;
    let q = match (r.link_angles.is_some(), r.node_offsets.is_some()) {
        (false, false) => Quality::Q1,
        (true, false) => Quality::Q1Q2,
        (false, true) => Quality::Q1Q3,
        (true, true) => Quality::Q1Q2Q3,
    };
    let t = build_targets(&r.raw(), q, reduce_dims).map_err(to_py)?;
    let dims = t.layout.blocks.iter().map(|b| b.dim).collect();
    Ok((matrix(py, t.n, t.layout.dim, t.data), dims))
}

/// Benchmark hook: the forest's split search on precomputed features (P, C) float32 (candidate
/// c = column c) and the given targets, scoring all P parts. Returns a dict with the best
/// candidate, threshold, total gain, term gains and the search time in seconds (excluding the
/// target preprocessing).
#[pyfunction]
#[pyo3(signature = (features, targets, *, quality="Q1+Q2+Q3", n_thresholds=16, min_samples_leaf=1, reg=1e-4, reduce_dims=4, seed=0, n_threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn split_search<'py>(
    py: Python<'py>,
    features: &Bound<'py, PyAny>,
    targets: &Bound<'py, PyAny>,
    quality: &str,
    n_thresholds: usize,
    min_samples_leaf: usize,
    reg: f64,
    reduce_dims: usize,
    seed: u64,
    n_threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let q = Quality::parse(quality).map_err(to_py)?;
    let r = targets_arg(targets)?;
    let n = r.n_parts();
    let fa = f32_array(features, "features", &[Some(n), None])?;
    let c = fa.shape()[1];
    if n_thresholds == 0 || reg.is_nan() || reg <= 0.0 {
        return Err(param_err("n_thresholds must be >= 1 and reg > 0"));
    }
    let fs = fa.as_slice()?;
    let raw = r.raw();
    let res = py.detach(|| {
        isa_core::forest::with_threads(n_threads, || -> isa_core::Result<_> {
            let t = build_targets(&raw, q, reduce_dims)?;
            let crit = Criterion::new(t.layout.clone(), reg);
            let subset: Vec<u32> = (0..n as u32).collect();
            let cfg = SplitConfig {
                n_thresholds,
                min_samples_leaf,
                parallel: true,
            };
            // Candidate-major copy so each candidate's column is contiguous (as the forest's
            // on-the-fly features are); not timed.
            let mut cm = vec![0f32; n * c];
            for p in 0..n {
                for k in 0..c {
                    cm[k * n + p] = fs[p * c + k];
                }
            }
            let t0 = std::time::Instant::now();
            let b = best_split_columns(&crit, &t, &subset, c, &cm, &cfg, seed);
            Ok((b, t0.elapsed().as_secs_f64()))
        })
    });
    let (best, secs) = res.map_err(to_py)?.map_err(to_py)?;
    let d = PyDict::new(py);
    d.set_item("seconds", secs)?;
    if let Some(b) = best {
        d.set_item("candidate", b.candidate)?;
        d.set_item("threshold", b.threshold)?;
        d.set_item("gain", b.gain)?;
        d.set_item("gains", b.term_gains.to_vec())?;
        d.set_item("n_left", b.n_left)?;
    }
    Ok(d)
}

/// The `_testing` submodule (also importable as `isa._core._testing`).
pub fn submodule<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyModule>> {
    let m = PyModule::new(py, "_testing")?;
    m.add_function(wrap_pyfunction!(criterion_gains, &m)?)?;
    m.add_function(wrap_pyfunction!(criterion_targets, &m)?)?;
    m.add_function(wrap_pyfunction!(split_search, &m)?)?;
    py.import("sys")?
        .getattr("modules")?
        .set_item("isa._core._testing", &m)?;
    Ok(m)
}
