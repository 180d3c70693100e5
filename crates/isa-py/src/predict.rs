//! Inference bindings: the whole-image calls behind `Forest.predict` / `Forest.image_votes`,
//! and `find_modes` on raw votes.
//!
//! Keyword parameters of `predict` / `image_votes` are the fields of
//! `isa_core::PredictParams` with the vote keys flat (`stride`, `min_depth`, `max_depth`,
//! `min_leaf_weight`, `position_bandwidth`, `rotation_bandwidth`, `max_hypotheses`, ...; see
//! `isa._core.PREDICT_DEFAULTS`), overlaid on the model's inference defaults by the core;
//! unknown names raise `InvalidParameterError`. `depth_scale` (the core's `DepthParams`) says
//! how the depth's values map to millimetres (`depth_input`).

use numpy::prelude::*;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use isa_core::vote::{self as core_vote, DepthImage, Intrinsics, PoseVote};
use isa_core::{PredictParams, Valid, VoteParams};

use crate::arrays::{array, as_slice, check_finite, describe, given, rows, vector};
use crate::depth_input::{depth_mm, take_depth_params};
use crate::errors::{input_err, to_py};
use crate::forest::PyForest;
use crate::hypothesis;
use crate::params::{kwargs_json, KWARGS};
use crate::scalars;

/// Intrinsics from an object with `fx, fy, cx, cy` attributes (e.g. `isa.camera.Intrinsics`),
/// a 3x3 camera matrix, or a sequence `(fx, fy, cx, cy)`.
pub(crate) fn intrinsics(k: &Bound<'_, PyAny>) -> PyResult<Intrinsics> {
    let i = if k.hasattr("fx")? {
        let num = |a: &str| scalars::number(&k.getattr(a)?, &format!("K.{a}"));
        Intrinsics {
            fx: num("fx")?,
            fy: num("fy")?,
            cx: num("cx")?,
            cy: num("cy")?,
        }
    } else if let Ok(m) = k.extract::<[[f64; 3]; 3]>() {
        return Intrinsics::from_matrix(m).map_err(to_py);
    } else if let Ok(v) = k.extract::<[f64; 4]>() {
        Intrinsics {
            fx: v[0],
            fy: v[1],
            cx: v[2],
            cy: v[3],
        }
    } else {
        return Err(input_err(format!(
            "K: expected a 3x3 camera matrix, (fx, fy, cx, cy) or an isa.camera.Intrinsics, got {}",
            describe(k)
        )));
    };
    i.validate().map_err(to_py)?;
    Ok(i)
}

/// The `_core.Forest` behind `obj`: itself, or its `.core` (an `isa.forest.Forest`).
pub(crate) fn core_forest<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyForest>> {
    if let Ok(f) = obj.cast::<PyForest>() {
        return Ok(f.clone());
    }
    if let Ok(c) = obj.getattr("core") {
        if let Ok(f) = c.cast::<PyForest>() {
            return Ok(f.clone());
        }
    }
    Err(input_err(format!(
        "forest: expected an isa.forest.Forest or isa._core.Forest, got {}",
        describe(obj)
    )))
}

/// The call's `n_threads`, else the forest's setting.
fn threads_of(
    forest: &Bound<'_, PyForest>,
    n_threads: Option<&Bound<'_, PyAny>>,
) -> PyResult<Option<usize>> {
    Ok(scalars::n_threads(n_threads)?.or(forest.get().threads()))
}

/// Converts and checks one whole-image call (threads, the model's inference defaults overlaid by
/// the keyword arguments, `depth_scale` taken from them, intrinsics, depth in mm) and runs `run`
/// on it without the GIL, on the forest's current trees (another thread may refit it
/// meanwhile). `Forest.predict` and `Forest.image_votes` are this with `run` = the core's
/// `predict` / `image_votes`.
pub(crate) fn on_image<'py, T: Send>(
    forest: &Bound<'py, PyForest>,
    depth: &Bound<'py, PyAny>,
    k: &Bound<'py, PyAny>,
    n_threads: Option<&Bound<'py, PyAny>>,
    params: Option<&Bound<'py, PyDict>>,
    run: impl FnOnce(
            &isa_core::Forest,
            &DepthImage<'_>,
            &Intrinsics,
            &Valid<PredictParams>,
        ) -> isa_core::Result<T>
        + Send,
) -> PyResult<T> {
    let threads = threads_of(forest, n_threads)?;
    let f = forest.get().core()?;
    let mut kw = kwargs_json(params)?;
    let depth_params = take_depth_params(&mut kw)?;
    let params = f
        .predict_defaults
        .with_overrides(&kw, KWARGS)
        .map_err(to_py)?;
    let (px, width, height, k) = depth_mm(depth, k, &depth_params)?;
    forest
        .py()
        .detach(|| {
            let img = DepthImage::new(&px, width, height)?;
            isa_core::forest::with_threads(threads, || run(&f, &img, &k, &params))?
        })
        .map_err(to_py)
}

/// The dict of `Forest.image_votes`.
pub(crate) fn votes_dict(py: Python<'_>, iv: core_vote::ImageVotes) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("position", rows(py, iv.votes.iter().map(|v| v.position)))?;
    d.set_item("rotation", rows(py, iv.votes.iter().map(|v| v.rotation)))?;
    d.set_item(
        "weight",
        vector(py, iv.votes.iter().map(|v| v.weight).collect()),
    )?;
    d.set_item(
        "pixel",
        rows(py, iv.pixels.iter().map(|p| [p[0] as i32, p[1] as i32])),
    )?;
    d.set_item(
        "tree",
        vector(py, iv.trees.iter().map(|t| *t as i32).collect()),
    )?;
    d.set_item("n_parts", iv.n_parts)?;
    Ok(d)
}

/// Mode finding on given votes: `positions` (V, 3) float32 metres, `rotations` (V, 4) float32
/// (w, x, y, z, any sign), `weights` (V,) float32 or None (all 1). Keyword parameters: those of
/// `VoteParams`. Returns hypotheses as `Forest.predict` does.
#[pyfunction]
#[pyo3(signature = (positions, rotations, weights=None, *, n_threads=None, **params))]
pub fn find_modes<'py>(
    py: Python<'py>,
    positions: &Bound<'py, PyAny>,
    rotations: &Bound<'py, PyAny>,
    weights: Option<&Bound<'py, PyAny>>,
    n_threads: Option<&Bound<'py, PyAny>>,
    params: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyList>> {
    let mut p = VoteParams::default();
    p.overlay(&kwargs_json(params)?, KWARGS).map_err(to_py)?;
    let pos = array::<f32>(positions, "positions", "float32", &[None, Some(3)])?;
    let n = pos.shape()[0];
    let rot = array::<f32>(rotations, "rotations", "float32", &[Some(n), Some(4)])?;
    let wts = given(weights)
        .map(|w| array::<f32>(w, "weights", "float32", &[Some(n)]))
        .transpose()?;
    let ps = as_slice(&pos, "positions")?;
    let rs = as_slice(&rot, "rotations")?;
    check_finite(ps, "positions", 3)?;
    check_finite(rs, "rotations", 4)?;
    let ws = wts.as_ref().map(|w| as_slice(w, "weights")).transpose()?;
    let votes: Vec<PoseVote> = (0..n)
        .map(|i| PoseVote {
            position: [ps[3 * i], ps[3 * i + 1], ps[3 * i + 2]],
            rotation: [rs[4 * i], rs[4 * i + 1], rs[4 * i + 2], rs[4 * i + 3]],
            weight: ws.map_or(1.0, |w| w[i]),
        })
        .collect();
    let n_threads = scalars::n_threads(n_threads)?;
    let hyps = py
        .detach(|| isa_core::forest::with_threads(n_threads, || core_vote::find_modes(&votes, &p))?)
        .map_err(to_py)?;
    hypothesis::to_list(py, hyps)
}

/// Default inference parameters as a dict (image-level keys plus the vote keys, flat): the
/// same as `PREDICT_DEFAULTS`.
#[pyfunction]
pub fn default_predict_params(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    crate::params::json_to_py(
        py,
        &serde_json::Value::Object(PredictParams::default().to_flat_json()),
    )
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(find_modes, m)?)?;
    m.add_function(wrap_pyfunction!(default_predict_params, m)?)?;
    Ok(())
}
