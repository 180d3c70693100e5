//! Inference bindings (owned by the inference work; registered by `vote::register` in lib.rs):
//! whole-image `predict` / `image_votes` on a `Forest`, `find_modes` on raw votes, and the
//! training-set file (`write_trainset` / `read_trainset`).
//!
//! Keyword parameters of `predict` / `image_votes` are the fields of
//! `isa_core::vote::PredictParams` (`stride`, `min_depth`, `max_depth`, `min_leaf_weight`) and of
//! `VoteParams` (`position_bandwidth`, `rotation_bandwidth`, `max_hypotheses`, `nms_radius`,
//! `max_seeds`, `max_iterations`, `rotations_per_position`, `rotation_candidates`,
//! `rotation_eval_votes`, `min_support`, `coarse_votes`, `refine_modes`, `refine_votes`); unknown
//! names raise `InvalidParameterError`.

use std::path::PathBuf;

use numpy::ndarray::{Array1, Array2};
use numpy::prelude::*;
use numpy::{PyArray1, PyUntypedArray};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use isa_core::trainset_io::{self, TrainSetData};
use isa_core::vote::{
    self as core_vote, DepthImage, Hypothesis, Intrinsics, PoseVote, PredictParams, VoteParams,
};

use crate::arrays::{array, check_finite, depth_store, describe, parts as parts_arg};
use crate::errors::{input_err, param_err, to_py};
use crate::forest::PyForest;

const IMAGE_KEYS: [&str; 4] = ["stride", "min_depth", "max_depth", "min_leaf_weight"];

fn json_value(key: &str, val: &Bound<'_, PyAny>) -> PyResult<serde_json::Value> {
    if val.is_none() {
        Ok(serde_json::Value::Null)
    } else if val.is_instance_of::<pyo3::types::PyBool>() {
        Err(param_err(format!("{key}: expected a number, got a bool")))
    } else if let Ok(i) = val.extract::<i64>() {
        Ok(serde_json::Value::from(i))
    } else if let Ok(f) = val.extract::<f64>() {
        serde_json::Number::from_f64(f)
            .map(serde_json::Value::Number)
            .ok_or_else(|| param_err(format!("{key} must be finite, got {f}")))
    } else {
        Err(param_err(format!(
            "{key}: expected a number, got {}",
            describe(val)
        )))
    }
}

/// Defaults overridden by keyword arguments; `image` says whether the image-level keys
/// (stride, depth limits) are allowed.
fn predict_params(kwargs: Option<&Bound<'_, PyDict>>, image: bool) -> PyResult<PredictParams> {
    let mut top = serde_json::Map::new();
    let mut vote = serde_json::Map::new();
    if let Some(kw) = kwargs {
        for (k, v) in kw.iter() {
            let key: String = k.extract()?;
            let j = json_value(&key, &v)?;
            if image && IMAGE_KEYS.contains(&key.as_str()) {
                top.insert(key, j);
            } else {
                vote.insert(key, j);
            }
        }
    }
    top.insert("vote".into(), serde_json::Value::Object(vote));
    let p: PredictParams = serde_json::from_value(serde_json::Value::Object(top))
        .map_err(|e| param_err(format!("predict parameters: {e}")))?;
    p.validate().map_err(to_py)?;
    Ok(p)
}

/// Intrinsics from an object with `fx, fy, cx, cy` attributes (e.g. `isa.camera.Intrinsics`),
/// a 3x3 camera matrix, or a sequence `(fx, fy, cx, cy)`.
fn intrinsics(k: &Bound<'_, PyAny>) -> PyResult<Intrinsics> {
    let i = if k.hasattr("fx")? {
        Intrinsics {
            fx: k.getattr("fx")?.extract()?,
            fy: k.getattr("fy")?.extract()?,
            cx: k.getattr("cx")?.extract()?,
            cy: k.getattr("cy")?.extract()?,
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

/// `(pixels in mm, width, height)` of a 2D depth array: uint16 millimetres, or float32/float64
/// metres (0, NaN, negative = missing).
fn depth_mm(depth: &Bound<'_, PyAny>) -> PyResult<(Vec<u16>, usize, usize)> {
    let arr = depth.cast::<PyUntypedArray>().map_err(|_| {
        input_err(format!(
            "depth: expected a 2D uint16 (mm) or float32 (metres) array, got {}",
            describe(depth)
        ))
    })?;
    if arr.ndim() != 2 {
        return Err(input_err(format!(
            "depth: expected a 2D array (height, width), got {}",
            describe(depth)
        )));
    }
    let (h, w) = (arr.shape()[0], arr.shape()[1]);
    let dt = arr.dtype();
    let py = depth.py();
    let px = if dt.is_equiv_to(&numpy::dtype::<u16>(py)) {
        array::<u16>(depth, "depth", "uint16", &[None, None])?
            .as_slice()
            .map_err(|e| input_err(e.to_string()))?
            .to_vec()
    } else if dt.is_equiv_to(&numpy::dtype::<f32>(py)) {
        let a = array::<f32>(depth, "depth", "float32", &[None, None])?;
        core_vote::depth_m_to_mm(a.as_slice().map_err(|e| input_err(e.to_string()))?)
    } else if dt.is_equiv_to(&numpy::dtype::<f64>(py)) {
        let a = array::<f64>(depth, "depth", "float64", &[None, None])?;
        let m: Vec<f32> = a
            .as_slice()
            .map_err(|e| input_err(e.to_string()))?
            .iter()
            .map(|v| *v as f32)
            .collect();
        core_vote::depth_m_to_mm(&m)
    } else {
        return Err(input_err(format!(
            "depth: expected uint16 (mm) or float32/float64 (metres), got {}",
            describe(depth)
        )));
    };
    Ok((px, w, h))
}

/// The `_core.Forest` behind `obj`: itself, or its `.core` (an `isa.forest.Forest`).
fn core_forest<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyForest>> {
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

fn threads_of(forest: &Bound<'_, PyForest>, n_threads: Option<usize>) -> PyResult<Option<usize>> {
    match n_threads {
        Some(0) => Err(param_err(
            "n_threads must be at least 1 (or None for the forest's setting)",
        )),
        Some(n) => Ok(Some(n)),
        None => forest.getattr("n_threads")?.extract(),
    }
}

fn hypotheses_to_py<'py>(py: Python<'py>, hyps: &[Hypothesis]) -> PyResult<Bound<'py, PyList>> {
    let out = PyList::empty(py);
    for h in hyps {
        let d = PyDict::new(py);
        let r: Vec<f64> = h.rotation.iter().flatten().copied().collect();
        d.set_item(
            "R",
            Array2::from_shape_vec((3, 3), r)
                .expect("3x3")
                .into_pyarray(py),
        )?;
        d.set_item(
            "t",
            Array1::from_vec(h.translation.to_vec()).into_pyarray(py),
        )?;
        d.set_item(
            "quaternion",
            Array1::from_vec(h.quaternion.to_vec()).into_pyarray(py),
        )?;
        d.set_item("score", h.score)?;
        d.set_item("support", h.support)?;
        d.set_item("position_score", h.position_score)?;
        d.set_item("position_support", h.position_support)?;
        out.append(d)?;
    }
    Ok(out)
}

/// Ranked 6D pose hypotheses of the objects in a whole depth image (paper Eq. 12-13).
///
/// `depth`: (H, W) uint16 mm or float32 metres; `K`: 3x3 matrix, (fx, fy, cx, cy) or
/// `isa.camera.Intrinsics`. Returns a list of dicts, best first: `R` (3, 3), `t` (3,) metres
/// (the SSC in the camera frame), `quaternion` (w, x, y, z), `score`, `support`,
/// `position_score`, `position_support`.
#[pyfunction]
#[pyo3(signature = (forest, depth, K, *, n_threads=None, **params))]
#[allow(non_snake_case)]
pub fn predict<'py>(
    py: Python<'py>,
    forest: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    K: &Bound<'py, PyAny>,
    n_threads: Option<usize>,
    params: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyList>> {
    let p = predict_params(params, true)?;
    let k = intrinsics(K)?;
    let (px, w, h) = depth_mm(depth)?;
    let forest = core_forest(forest)?;
    let threads = threads_of(&forest, n_threads)?;
    let fref = forest.borrow();
    let f = fref.core()?;
    let hyps = py
        .detach(|| {
            let img = DepthImage::new(&px, w, h)?;
            isa_core::forest::with_threads(threads, || core_vote::predict(f, &img, &k, &p))?
        })
        .map_err(to_py)?;
    hypotheses_to_py(py, &hyps)
}

/// Every vote of a whole depth image (for plots): dict of `position` (V, 3) float32 metres,
/// `rotation` (V, 4) float32 (w, x, y, z), `weight` (V,) float32 (leaf share / n_trees),
/// `pixel` (V, 2) int32 (u, v) of the casting part, `tree` (V,) int32, `n_parts` int.
#[pyfunction]
#[pyo3(signature = (forest, depth, K, *, n_threads=None, **params))]
#[allow(non_snake_case)]
pub fn image_votes<'py>(
    py: Python<'py>,
    forest: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    K: &Bound<'py, PyAny>,
    n_threads: Option<usize>,
    params: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let p = predict_params(params, true)?;
    let k = intrinsics(K)?;
    let (px, w, h) = depth_mm(depth)?;
    let forest = core_forest(forest)?;
    let threads = threads_of(&forest, n_threads)?;
    let fref = forest.borrow();
    let f = fref.core()?;
    let iv = py
        .detach(|| {
            let img = DepthImage::new(&px, w, h)?;
            isa_core::forest::with_threads(threads, || core_vote::image_votes(f, &img, &k, &p))?
        })
        .map_err(to_py)?;
    let n = iv.votes.len();
    let d = PyDict::new(py);
    let pos: Vec<f32> = iv.votes.iter().flat_map(|v| v.position).collect();
    let rot: Vec<f32> = iv.votes.iter().flat_map(|v| v.rotation).collect();
    let pix: Vec<i32> = iv
        .pixels
        .iter()
        .flat_map(|p| [p[0] as i32, p[1] as i32])
        .collect();
    d.set_item(
        "position",
        Array2::from_shape_vec((n, 3), pos)
            .expect("shape")
            .into_pyarray(py),
    )?;
    d.set_item(
        "rotation",
        Array2::from_shape_vec((n, 4), rot)
            .expect("shape")
            .into_pyarray(py),
    )?;
    d.set_item(
        "weight",
        PyArray1::from_vec(py, iv.votes.iter().map(|v| v.weight).collect()),
    )?;
    d.set_item(
        "pixel",
        Array2::from_shape_vec((n, 2), pix)
            .expect("shape")
            .into_pyarray(py),
    )?;
    d.set_item(
        "tree",
        PyArray1::from_vec(py, iv.trees.iter().map(|t| *t as i32).collect()),
    )?;
    d.set_item("n_parts", iv.n_parts)?;
    Ok(d)
}

/// Mode finding on given votes: `positions` (V, 3) float32 metres, `rotations` (V, 4) float32
/// (w, x, y, z, any sign), `weights` (V,) float32 or None (all 1). Keyword parameters: those of
/// `VoteParams`. Returns hypotheses as `predict` does.
#[pyfunction]
#[pyo3(signature = (positions, rotations, weights=None, *, n_threads=None, **params))]
pub fn find_modes<'py>(
    py: Python<'py>,
    positions: &Bound<'py, PyAny>,
    rotations: &Bound<'py, PyAny>,
    weights: Option<&Bound<'py, PyAny>>,
    n_threads: Option<usize>,
    params: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyList>> {
    let p: VoteParams = predict_params(params, false)?.vote;
    let pos = array::<f32>(positions, "positions", "float32", &[None, Some(3)])?;
    let n = pos.shape()[0];
    let rot = array::<f32>(rotations, "rotations", "float32", &[Some(n), Some(4)])?;
    let wts = weights
        .filter(|w| !w.is_none())
        .map(|w| array::<f32>(w, "weights", "float32", &[Some(n)]))
        .transpose()?;
    let ps = pos.as_slice().map_err(|e| input_err(e.to_string()))?;
    let rs = rot.as_slice().map_err(|e| input_err(e.to_string()))?;
    check_finite(ps, "positions", 3)?;
    check_finite(rs, "rotations", 4)?;
    let ws = match &wts {
        Some(w) => Some(w.as_slice().map_err(|e| input_err(e.to_string()))?),
        None => None,
    };
    let votes: Vec<PoseVote> = (0..n)
        .map(|i| PoseVote {
            position: [ps[3 * i], ps[3 * i + 1], ps[3 * i + 2]],
            rotation: [rs[4 * i], rs[4 * i + 1], rs[4 * i + 2], rs[4 * i + 3]],
            weight: ws.map_or(1.0, |w| w[i]),
        })
        .collect();
    if n_threads == Some(0) {
        return Err(param_err(
            "n_threads must be at least 1 (or None for all cores)",
        ));
    }
    let hyps = py
        .detach(|| isa_core::forest::with_threads(n_threads, || core_vote::find_modes(&votes, &p))?)
        .map_err(to_py)?;
    hypotheses_to_py(py, &hyps)
}

/// Default inference parameters as a dict (image-level keys plus the vote keys, flat).
#[pyfunction]
pub fn default_predict_params(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    let p = PredictParams::default();
    d.set_item("stride", p.stride)?;
    d.set_item("min_depth", p.min_depth)?;
    d.set_item("max_depth", p.max_depth)?;
    d.set_item("min_leaf_weight", p.min_leaf_weight)?;
    let v = serde_json::to_value(&p.vote).expect("serialise");
    for (k, val) in v.as_object().expect("object") {
        if let Some(i) = val.as_u64() {
            d.set_item(k, i)?;
        } else {
            d.set_item(k, val.as_f64())?;
        }
    }
    Ok(d)
}

/// Writes a training-set file (`.isat`, see `isa_core::trainset_io`) for `isa train`: the same
/// arguments as `Forest.fit` (images: list of (h, w) uint16 crops; parts (P, 3) int32; offsets
/// (P, 3), rotations (P, 4), link_angles (P, L), node_offsets (P, 3N) float32) plus metadata JSON.
#[pyfunction]
#[pyo3(signature = (path, images, parts, offsets, rotations, link_angles=None, node_offsets=None, metadata="{}"))]
#[allow(clippy::too_many_arguments)]
pub fn write_trainset(
    py: Python<'_>,
    path: PathBuf,
    images: &Bound<'_, PyAny>,
    parts: &Bound<'_, PyAny>,
    offsets: &Bound<'_, PyAny>,
    rotations: &Bound<'_, PyAny>,
    link_angles: Option<&Bound<'_, PyAny>>,
    node_offsets: Option<&Bound<'_, PyAny>>,
    metadata: &str,
) -> PyResult<()> {
    let store = depth_store(images)?;
    let parts = parts_arg(parts)?;
    let n = parts.len();
    let f32_vec =
        |obj: &Bound<'_, PyAny>, name: &str, cols: Option<usize>| -> PyResult<(Vec<f32>, usize)> {
            let a = array::<f32>(obj, name, "float32", &[Some(n), cols])?;
            let c = a.shape()[1];
            Ok((
                a.as_slice()
                    .map_err(|e| input_err(format!("{name}: {e}")))?
                    .to_vec(),
                c,
            ))
        };
    let opt = |o: Option<&Bound<'_, PyAny>>, name: &str| -> PyResult<Option<(Vec<f32>, usize)>> {
        o.filter(|o| !o.is_none())
            .map(|o| f32_vec(o, name, None))
            .transpose()
    };
    let ts = TrainSetData {
        store,
        parts,
        offsets: f32_vec(offsets, "offsets", Some(3))?.0,
        rotations: f32_vec(rotations, "rotations", Some(4))?.0,
        link_angles: opt(link_angles, "link_angles")?,
        node_offsets: opt(node_offsets, "node_offsets")?,
        metadata: metadata.to_string(),
    };
    py.detach(|| trainset_io::write(&ts, &path)).map_err(to_py)
}

/// Reads a training-set file back: dict with `images` (list of uint16 arrays), `parts`,
/// `offsets`, `rotations`, `link_angles` / `node_offsets` (or None) and `metadata` (str).
#[pyfunction]
pub fn read_trainset(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let ts = py.detach(|| trainset_io::read(&path)).map_err(to_py)?;
    let d = PyDict::new(py);
    let imgs = PyList::empty(py);
    for i in 0..ts.store.len() {
        let (w, h) = ts.store.dims(i);
        imgs.append(
            Array2::from_shape_vec((h, w), ts.store.image(i).data.to_vec())
                .expect("shape")
                .into_pyarray(py),
        )?;
    }
    let p = ts.parts.len();
    d.set_item("images", imgs)?;
    let flat: Vec<i32> = ts.parts.iter().flatten().copied().collect();
    d.set_item(
        "parts",
        Array2::from_shape_vec((p, 3), flat)
            .expect("shape")
            .into_pyarray(py),
    )?;
    d.set_item(
        "offsets",
        Array2::from_shape_vec((p, 3), ts.offsets)
            .expect("shape")
            .into_pyarray(py),
    )?;
    d.set_item(
        "rotations",
        Array2::from_shape_vec((p, 4), ts.rotations)
            .expect("shape")
            .into_pyarray(py),
    )?;
    for (name, arr) in [
        ("link_angles", ts.link_angles),
        ("node_offsets", ts.node_offsets),
    ] {
        match arr {
            Some((a, c)) => d.set_item(
                name,
                Array2::from_shape_vec((p, c), a)
                    .expect("shape")
                    .into_pyarray(py),
            )?,
            None => d.set_item(name, py.None())?,
        }
    }
    d.set_item("metadata", ts.metadata)?;
    Ok(d)
}

/// Registers this file's functions (one line in lib.rs: `vote::register(m)?;`).
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TRAINSET_FORMAT_VERSION", trainset_io::FORMAT_VERSION)?;
    m.add_function(wrap_pyfunction!(predict, m)?)?;
    m.add_function(wrap_pyfunction!(image_votes, m)?)?;
    m.add_function(wrap_pyfunction!(find_modes, m)?)?;
    m.add_function(wrap_pyfunction!(default_predict_params, m)?)?;
    m.add_function(wrap_pyfunction!(write_trainset, m)?)?;
    m.add_function(wrap_pyfunction!(read_trainset, m)?)?;
    Ok(())
}
