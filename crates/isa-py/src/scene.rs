//! Scene detection bindings (`isa_core::scene`): `detect` (every category model over one frame),
//! its stages for `isa.detection`'s modules (`find_planes`, `verify_pose`, `refine_pose`,
//! `nms_across`), the `ShapeLibrary` class and its `.isl` files, and `DETECT_DEFAULTS`.
//!
//! Parameters are dicts in the JSON form of `isa_core::DetectParams` (nested `planes`,
//! `verify`, `refine`; None switches `verify` / `refine` off), overlaid on the core's defaults.

use nalgebra::{Matrix3, Vector3};
use numpy::prelude::*;
use numpy::{PyArray1, PyArray3};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde_json::Value;

use isa_core::params::{overlay_json, DetectParams, PlaneParams, RefineParams, VerifyParams};
use isa_core::scene::{self, planes::Planes, Camera, Frame, ShapeLibrary, SizeRange};

use crate::arrays::{
    array, as_slice, describe, fixed_rows, given, mat3_rows, rows, set_fields, t_arg, vector,
};
use crate::errors::{input_err, to_py};
use crate::hypothesis::PyHypothesis;
use crate::params::json_to_py;
use crate::predict::{core_forest, intrinsics};
use isa_core::vote::Intrinsics;

/// A dict (or None) as JSON for the parameter overlay.
fn dict_json(d: Option<&Bound<'_, PyAny>>) -> PyResult<Value> {
    match given(d) {
        None => Ok(Value::Object(Default::default())),
        Some(d) => {
            let text: String = d
                .py()
                .import("json")?
                .call_method1("dumps", (d,))?
                .extract()?;
            serde_json::from_str(&text).map_err(|e| input_err(format!("params: {e}")))
        }
    }
}

/// A stage's parameters: the dict `d` overlaid on the core's defaults, then `validate`d.
fn stage_params<T: serde::Serialize + serde::de::DeserializeOwned + Default>(
    d: Option<&Bound<'_, PyAny>>,
    what: &str,
    validate: impl FnOnce(&T) -> isa_core::Result<()>,
) -> PyResult<T> {
    let p = overlay_json(&T::default(), &dict_json(d)?, what).map_err(to_py)?;
    validate(&p).map_err(to_py)?;
    Ok(p)
}

/// A finite 3x3 matrix argument.
fn mat3(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Matrix3<f64>> {
    let m = scene::mat(&mat3_rows(obj, name)?);
    if !m.iter().all(|x| x.is_finite()) {
        return Err(input_err(format!("{name}: not finite")));
    }
    Ok(m)
}

/// A pose's rotation argument `R` (`#[pyo3(from_py_with = r_arg)]`).
fn r_arg(obj: &Bound<'_, PyAny>) -> PyResult<Matrix3<f64>> {
    mat3(obj, "R")
}

/// The camera-to-upright rotation argument `R_gravity`.
fn r_gravity_arg(obj: &Bound<'_, PyAny>) -> PyResult<Matrix3<f64>> {
    mat3(obj, "R_gravity")
}

/// The (H, W) float32 metre depth and its camera.
fn depth_frame<'py>(
    depth: &Bound<'py, PyAny>,
    k: Intrinsics,
) -> PyResult<(numpy::PyReadonlyArrayDyn<'py, f32>, Camera)> {
    let a = array::<f32>(depth, "depth", "float32", &[None, None])?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    Ok((a, Camera::new(k, w, h).map_err(to_py)?))
}

fn points_f64(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Vector3<f64>>> {
    let rows = fixed_rows::<f64, 3>(obj, name, "float64")?;
    Ok(rows.into_iter().map(Vector3::from).collect())
}

/// A category's shape library (see `isa_core::scene::shapes`): surface samples (S, N, 3) and
/// normals of its training shapes in the object frame, each shape's sample spacing (S,) and
/// bounds (S, 2, 3), names, and the category's real-world size range.
#[pyclass(name = "ShapeLibrary", module = "isa._core", frozen)]
pub struct PyShapeLibrary {
    pub lib: ShapeLibrary,
}

#[pymethods]
impl PyShapeLibrary {
    #[new]
    #[pyo3(signature = (category, points, normals, spacing, bounds, names=Vec::new(), size_range=None))]
    fn new(
        category: String,
        points: &Bound<'_, PyAny>,
        normals: &Bound<'_, PyAny>,
        spacing: &Bound<'_, PyAny>,
        bounds: &Bound<'_, PyAny>,
        names: Vec<String>,
        size_range: Option<([f64; 2], [f64; 2])>,
    ) -> PyResult<Self> {
        let p = array::<f32>(points, "points", "float32", &[None, None, Some(3)])?;
        let (s, n) = (p.shape()[0], p.shape()[1]);
        let nr = array::<f32>(normals, "normals", "float32", &[Some(s), Some(n), Some(3)])?;
        let sp = array::<f64>(spacing, "spacing", "float64", &[Some(s)])?;
        let b = array::<f64>(bounds, "bounds", "float64", &[Some(s), Some(2), Some(3)])?;
        let tri = |a: &[f32]| {
            a.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>()
        };
        let lib = ShapeLibrary::new(
            category,
            names,
            size_range.map(|(height, length)| SizeRange { height, length }),
            n,
            tri(as_slice(&p, "points")?),
            tri(as_slice(&nr, "normals")?),
            as_slice(&sp, "spacing")?.to_vec(),
            as_slice(&b, "bounds")?
                .chunks_exact(6)
                .map(|c| [[c[0], c[1], c[2]], [c[3], c[4], c[5]]])
                .collect(),
        )
        .map_err(to_py)?;
        Ok(PyShapeLibrary { lib })
    }

    /// Reads an `.isl` file.
    #[staticmethod]
    fn load(path: std::path::PathBuf) -> PyResult<Self> {
        Ok(PyShapeLibrary {
            lib: ShapeLibrary::load(&path).map_err(to_py)?,
        })
    }

    /// Writes an `.isl` file atomically.
    fn save(&self, path: std::path::PathBuf) -> PyResult<()> {
        self.lib.save(&path).map_err(to_py)
    }

    #[getter]
    fn category(&self) -> String {
        self.lib.category.clone()
    }
    #[getter]
    fn names(&self) -> Vec<String> {
        self.lib.names.clone()
    }
    /// `((height_min, height_max), (length_min, length_max))` metres, or None.
    #[getter]
    fn size_range(&self) -> Option<([f64; 2], [f64; 2])> {
        self.lib.size_range.map(|r| (r.height, r.length))
    }
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let flat: Vec<f32> = self.lib.points.iter().flatten().copied().collect();
        PyArray1::from_vec(py, flat).reshape([self.lib.len(), self.lib.n_points, 3])
    }
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let flat: Vec<f32> = self.lib.normals.iter().flatten().copied().collect();
        PyArray1::from_vec(py, flat).reshape([self.lib.len(), self.lib.n_points, 3])
    }
    #[getter]
    fn spacing<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vector(py, self.lib.spacing.clone())
    }
    #[getter]
    fn bounds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let flat: Vec<f64> = self
            .lib
            .bounds
            .iter()
            .flatten()
            .flatten()
            .copied()
            .collect();
        PyArray1::from_vec(py, flat).reshape([self.lib.len(), 2, 3])
    }
    fn __len__(&self) -> usize {
        self.lib.len()
    }
}

fn planes_dict<'py>(
    py: Python<'py>,
    pl: &Planes,
    h: usize,
    w: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let list = PyList::empty(py);
    for p in &pl.planes {
        let e = PyDict::new(py);
        e.set_item(
            "kind",
            match p.kind {
                scene::planes::PlaneKind::Floor => "floor",
                scene::planes::PlaneKind::Wall => "wall",
            },
        )?;
        e.set_item("normal", vector(py, p.normal.to_vec()))?;
        e.set_item("offset", p.offset)?;
        e.set_item("n_inliers", p.inliers)?;
        list.append(e)?;
    }
    d.set_item("planes", list)?;
    d.set_item(
        "removed",
        PyArray1::from_vec(py, pl.removed.clone()).reshape([h, w])?,
    )?;
    Ok(d)
}

/// The floor and walls of a frame: `{"planes": [{"kind", "normal", "offset", "n_inliers"}],
/// "removed": (H, W) bool}` (floor first; removed: on a plane or under the floor).
#[pyfunction]
#[pyo3(signature = (depth, K, R_gravity, params=None, floor=true, walls=true))]
#[allow(non_snake_case)]
pub fn find_planes<'py>(
    depth: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = intrinsics)] K: Intrinsics,
    #[pyo3(from_py_with = r_gravity_arg)] R_gravity: Matrix3<f64>,
    params: Option<&Bound<'py, PyAny>>,
    floor: bool,
    walls: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let py = depth.py();
    let p = stage_params(params, "plane parameters", PlaneParams::validate)?;
    let (a, cam) = depth_frame(depth, K)?;
    let d = as_slice(&a, "depth")?;
    let out = py
        .detach(|| {
            Frame::new(d, cam).map(|f| scene::planes::find_planes(&f, &R_gravity, &p, floor, walls))
        })
        .map_err(to_py)?;
    planes_dict(py, &out, cam.height, cam.width)
}

/// Verification of shape `points` (N, 3) (mean `spacing`) at pose `(R, t)` against `depth`
/// ((H, W) float32 metres; `planes` (H, W) bool or None): `{"score", "agree", "violate",
/// "occluded", "missing", "outside", "unexplained"}` (unexplained counted only with a positive
/// `unexplained_weight`).
#[pyfunction]
#[pyo3(signature = (depth, K, R, t, points, spacing, planes=None, params=None, n_points=None))]
#[allow(non_snake_case, clippy::too_many_arguments)]
pub fn verify_pose<'py>(
    depth: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = intrinsics)] K: Intrinsics,
    #[pyo3(from_py_with = r_arg)] R: Matrix3<f64>,
    #[pyo3(from_py_with = t_arg)] t: [f64; 3],
    points: &Bound<'py, PyAny>,
    spacing: f64,
    planes: Option<&Bound<'py, PyAny>>,
    params: Option<&Bound<'py, PyAny>>,
    n_points: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let py = depth.py();
    let p = stage_params(params, "verification parameters", VerifyParams::validate)?;
    let (a, cam) = depth_frame(depth, K)?;
    let d = as_slice(&a, "depth")?;
    let mask = match given(planes) {
        Some(m) => Some(array::<bool>(
            m,
            "planes",
            "bool",
            &[Some(cam.height), Some(cam.width)],
        )?),
        None => None,
    };
    let mask_s = match &mask {
        Some(m) => Some(as_slice(m, "planes")?),
        None => None,
    };
    let pts: Vec<[f32; 3]> = points_f64(points, "points")?
        .iter()
        .map(|q| [q.x as f32, q.y as f32, q.z as f32])
        .collect();
    let ev = scene::verify::Evidence {
        frame: Frame::new(d, cam).map_err(to_py)?,
        planes: mask_s,
    };
    let v = scene::verify::verify_pose(
        &ev,
        &R,
        &Vector3::from(t),
        &pts,
        [1.0; 3],
        spacing,
        &p,
        n_points,
    );
    let out = PyDict::new(py);
    set_fields!(out, v; score, agree, violate, occluded, missing, outside, unexplained);
    Ok(out)
}

/// Upright ICP of a shape (`shape_points` (N, 3), `bounds` (2, 3), `normals` (N, 3) or None)
/// from `(R, t)` on upright-frame points `points_up` (M, 3) of a `width` x `height` camera:
/// `{"R", "t", "rms", "pairs", "yaw_change", "shift", "converged"}`.
#[pyfunction]
#[pyo3(signature = (points_up, K, width, height, R, t, shape_points, bounds, R_gravity, params=None, normals=None))]
#[allow(non_snake_case, clippy::too_many_arguments)]
pub fn refine_pose<'py>(
    points_up: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = intrinsics)] K: Intrinsics,
    width: usize,
    height: usize,
    #[pyo3(from_py_with = r_arg)] R: Matrix3<f64>,
    #[pyo3(from_py_with = t_arg)] t: [f64; 3],
    shape_points: &Bound<'py, PyAny>,
    bounds: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = r_gravity_arg)] R_gravity: Matrix3<f64>,
    params: Option<&Bound<'py, PyAny>>,
    normals: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let py = points_up.py();
    let p = stage_params(params, "refinement parameters", RefineParams::validate)?;
    let cam = Camera::new(K, width, height).map_err(to_py)?;
    let obs = points_f64(points_up, "points_up")?;
    let pts = points_f64(shape_points, "shape_points")?;
    let nrm = match given(normals) {
        Some(n) => Some(points_f64(n, "normals")?),
        None => None,
    };
    if nrm.as_ref().is_some_and(|n| n.len() != pts.len()) {
        return Err(input_err("normals: one per shape point"));
    }
    let b: [[f64; 3]; 2] = bounds
        .extract()
        .map_err(|_| input_err(format!("bounds: expected (2, 3), got {}", describe(bounds))))?;
    let t = Vector3::from(t);
    let out = py.detach(|| {
        scene::refine::refine_pose(&obs, &cam, &R, &t, &pts, nrm.as_deref(), b, &R_gravity, &p)
    });
    let d = PyDict::new(py);
    d.set_item("R", rows(py, scene::rows(&out.r).into_iter()))?;
    d.set_item("t", vector(py, vec![out.t.x, out.t.y, out.t.z]))?;
    set_fields!(d, out; rms, pairs, yaw_change, shift, converged);
    Ok(d)
}

/// Greedy NMS across categories over boxes (n, 8) float64 rows `[cx, cy, cz, sx, sy, sz, yaw,
/// score]` (upright frame): the kept indices, best first.
#[pyfunction]
#[pyo3(signature = (boxes, iou=0.25, overlap=0.6))]
pub fn nms_across(boxes: &Bound<'_, PyAny>, iou: f64, overlap: f64) -> PyResult<Vec<usize>> {
    let b: Vec<scene::nms::UprightBox> = fixed_rows::<f64, 8>(boxes, "boxes", "float64")?
        .into_iter()
        .map(|c| scene::nms::UprightBox {
            centre: [c[0], c[1], c[2]],
            size: [c[3], c[4], c[5]],
            yaw: c[6],
            score: c[7],
        })
        .collect();
    Ok(scene::nms::nms_across(&b, iou, overlap))
}

/// Every category model over one frame (see `isa_core::scene::detect`). `depth` (H, W) float32
/// metres; `models` a list of dicts `{"category", "forest", "size", "ssc_offset", "shapes"
/// (ShapeLibrary or None), "hypotheses" (list of Hypothesis voted elsewhere, or None)}`;
/// `gravity` (3, 3) camera -> upright or None; `removed` (H, W) bool planes found beforehand
/// (with `planes`, their list) or None; `params` a DetectParams dict. Returns `{"detections":
/// [dict], "gravity", "gravity_source", "floor_height", "planes", "removed", "seconds"}`.
#[pyfunction]
#[pyo3(signature = (depth, K, models, gravity=None, planes=None, params=None))]
#[allow(non_snake_case)]
pub fn detect<'py>(
    depth: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = intrinsics)] K: Intrinsics,
    models: &Bound<'py, PyList>,
    gravity: Option<&Bound<'py, PyAny>>,
    planes: Option<&Bound<'py, PyAny>>,
    params: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let py = depth.py();
    let mut p = DetectParams::default();
    p.overlay(&dict_json(params)?, "detect parameters")
        .map_err(to_py)?;
    let p = p.check().map_err(to_py)?;
    let (a, cam) = depth_frame(depth, K)?;
    let d = as_slice(&a, "depth")?;
    let g = given(gravity).map(|g| mat3(g, "gravity")).transpose()?;
    // Models: borrow the forests and libraries for the call.
    let mut forests = Vec::new();
    let mut libs = Vec::new();
    let mut meta = Vec::new();
    for (i, m) in models.iter().enumerate() {
        let m = m
            .cast::<PyDict>()
            .map_err(|_| {
                input_err(format!(
                    "models[{i}]: expected a dict, got {}",
                    describe(&m)
                ))
            })?
            .clone();
        let get = |k: &str| -> PyResult<Bound<'py, PyAny>> {
            m.get_item(k)?
                .ok_or_else(|| input_err(format!("models[{i}]: no {k:?}")))
        };
        let category: String = get("category")?.extract()?;
        forests.push(core_forest(&get("forest")?)?);
        let size: [f64; 3] = get("size")?.extract()?;
        let ssc: [f64; 3] = get("ssc_offset")?.extract()?;
        let shapes = m.get_item("shapes")?.filter(|s| !s.is_none());
        libs.push(match shapes {
            Some(s) => Some(
                s.cast::<PyShapeLibrary>()
                    .map_err(|_| {
                        input_err(format!(
                            "models[{i}].shapes: expected an isa._core.ShapeLibrary, got {}",
                            describe(&s)
                        ))
                    })?
                    .clone(),
            ),
            None => None,
        });
        let range = match m.get_item("size_range")?.filter(|r| !r.is_none()) {
            Some(r) => {
                let (height, length): ([f64; 2], [f64; 2]) = r.extract().map_err(|_| {
                    input_err(format!(
                        "models[{i}].size_range: expected ((h0, h1), (l0, l1)), got {}",
                        describe(&r)
                    ))
                })?;
                Some(SizeRange { height, length })
            }
            None => None,
        };
        let hyps = match m.get_item("hypotheses")?.filter(|h| !h.is_none()) {
            Some(h) => {
                let mut v = Vec::new();
                for x in h.try_iter()? {
                    let x = x?;
                    let hh = x.cast::<PyHypothesis>().map_err(|_| {
                        input_err(format!(
                            "models[{i}].hypotheses: expected isa._core.Hypothesis items, got {}",
                            describe(&x)
                        ))
                    })?;
                    v.push(hh.get().inner().clone());
                }
                Some(v)
            }
            None => None,
        };
        let ranker = match m.get_item("ranker")?.filter(|r| !r.is_none()) {
            Some(r) => {
                let text: String = r.extract().map_err(|_| {
                    input_err(format!(
                        "models[{i}].ranker: expected the ranker's JSON text, got {}",
                        describe(&r)
                    ))
                })?;
                Some(
                    scene::Ranker::from_json(&text, &format!("models[{i}].ranker"))
                        .map_err(to_py)?,
                )
            }
            None => None,
        };
        meta.push((category, size, ssc, range, hyps, ranker));
    }
    // Each forest's trees, held for the call (a concurrent fit replaces them, never these).
    let cores = forests
        .iter()
        .map(|f| f.get().core())
        .collect::<PyResult<Vec<_>>>()?;
    let mut core_models = Vec::new();
    for (i, (category, size, ssc, range, hyps, ranker)) in meta.iter().enumerate() {
        core_models.push(scene::SceneModel {
            category,
            forest: &cores[i],
            size: *size,
            ssc_offset: *ssc,
            shapes: libs[i].as_ref().map(|l| &l.get().lib),
            size_range: *range,
            hypotheses: hyps.as_deref(),
            ranker: ranker.as_ref(),
        });
    }
    let given_planes = match given(planes) {
        Some(pl) => {
            let pd = pl
                .cast::<PyDict>()
                .map_err(|_| input_err("planes: expected find_planes' dict"))?;
            let removed = pd
                .get_item("removed")?
                .ok_or_else(|| input_err("planes: no \"removed\""))?;
            let m = array::<bool>(
                &removed,
                "planes[\"removed\"]",
                "bool",
                &[Some(cam.height), Some(cam.width)],
            )?;
            let mut list = Vec::new();
            if let Some(ps) = pd.get_item("planes")? {
                for e in ps.try_iter()? {
                    let e = e?;
                    let kind: String = e.get_item("kind")?.extract()?;
                    list.push(scene::planes::Plane {
                        kind: if kind == "floor" {
                            scene::planes::PlaneKind::Floor
                        } else {
                            scene::planes::PlaneKind::Wall
                        },
                        normal: e.get_item("normal")?.extract()?,
                        offset: e.get_item("offset")?.extract()?,
                        inliers: e.get_item("n_inliers")?.extract()?,
                    });
                }
            }
            Some(Planes {
                planes: list,
                removed: as_slice(&m, "planes")?.to_vec(),
            })
        }
        None => None,
    };
    let out = py
        .detach(|| scene::detect(d, cam, &core_models, g, given_planes, &p))
        .map_err(to_py)?;
    let res = PyDict::new(py);
    let dets = PyList::empty(py);
    for x in &out.detections {
        let e = PyDict::new(py);
        e.set_item("category", &x.category)?;
        e.set_item("R", rows(py, x.r.iter().copied()))?;
        e.set_item("t", vector(py, x.t.to_vec()))?;
        e.set_item("size", vector(py, x.size.to_vec()))?;
        e.set_item("box_centre", vector(py, x.box_centre.to_vec()))?;
        set_fields!(e, x; score, support, forest_score, rank, tilt_deg, shape, refined, turn);
        match &x.features {
            Some(f) => {
                let fd = PyDict::new(py);
                for (name, v) in scene::ranking::FEATURES.iter().zip(f) {
                    fd.set_item(name, v)?;
                }
                e.set_item("features", fd)?;
            }
            None => e.set_item("features", py.None())?,
        }
        dets.append(e)?;
    }
    res.set_item("detections", dets)?;
    res.set_item("gravity", rows(py, scene::rows(&out.gravity).into_iter()))?;
    res.set_item("gravity_source", out.gravity_source.name())?;
    res.set_item("floor_height", out.floor_height)?;
    match &out.planes {
        Some(pl) => res.set_item("planes", planes_dict(py, pl, cam.height, cam.width)?)?,
        None => res.set_item("planes", py.None())?,
    }
    let secs = PyDict::new(py);
    for (k, v) in &out.seconds {
        secs.set_item(k, v)?;
    }
    res.set_item("seconds", secs)?;
    Ok(res)
}

/// A ranker's JSON text checked (`isa_core::scene::ranking::Ranker`; errors name `source`),
/// returned in the core's own layout.
#[pyfunction]
pub fn check_ranker(text: &str, source: &str) -> PyResult<String> {
    Ok(scene::Ranker::from_json(text, source)
        .map_err(to_py)?
        .to_json())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<PyShapeLibrary>()?;
    m.add("RANK_FEATURES", scene::ranking::FEATURES.to_vec())?;
    m.add("RANKER_FORMAT", scene::ranking::RANKER_FORMAT)?;
    m.add_function(wrap_pyfunction!(check_ranker, m)?)?;
    m.add(
        "SHAPES_FORMAT_VERSION",
        scene::shapes::SHAPES_FORMAT_VERSION,
    )?;
    let d = serde_json::to_value(DetectParams::default()).expect("parameters serialise");
    m.add("DETECT_DEFAULTS", json_to_py(py, &d)?)?;
    m.add_function(wrap_pyfunction!(detect, m)?)?;
    m.add_function(wrap_pyfunction!(find_planes, m)?)?;
    m.add_function(wrap_pyfunction!(verify_pose, m)?)?;
    m.add_function(wrap_pyfunction!(refine_pose, m)?)?;
    m.add_function(wrap_pyfunction!(nms_across, m)?)?;
    Ok(())
}
