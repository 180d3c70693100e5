//! Depth as users have it, converted and checked by the core (`isa_core::depth_input`): a 2D
//! depth array (uint16 units or float) or an organised point cloud (H, W, 3), with
//! `depth_scale` (the core's `DepthParams`, taken from the keyword arguments), the image size
//! checked against intrinsics that carry one (`width`, `height`), and the core's warnings
//! (implausible depth range, an image that looks transposed) raised as `isa.InputWarning`.

use numpy::prelude::*;
use numpy::{PyArray2, PyUntypedArray};
use pyo3::prelude::*;
use serde_json::Value;

use isa_core::depth_input::{self as di, DepthValues};
use isa_core::vote::Intrinsics;
use isa_core::{DepthParams, Valid};

use crate::arrays::{array, as_slice, describe, given};
use crate::errors::{input_err, to_py};
use crate::params::KWARGS;
use crate::predict::intrinsics;

pyo3::create_exception!(
    _core,
    InputWarning,
    pyo3::exceptions::PyUserWarning,
    "An input that is accepted but probably wrong: a depth range implausible for a depth sensor \
     (a wrong depth_scale), an image that looks transposed against its intrinsics."
);

/// Removes the `DepthParams` keys (`depth_scale`) from a JSON object of keyword arguments and
/// returns them overlaid on the defaults, checked.
pub(crate) fn take_depth_params(kw: &mut Value) -> PyResult<Valid<DepthParams>> {
    let known = serde_json::to_value(DepthParams::default()).expect("JSON");
    let mut own = serde_json::Map::new();
    if let (Some(o), Some(k)) = (kw.as_object_mut(), known.as_object()) {
        for key in k.keys() {
            if let Some(v) = o.remove(key) {
                own.insert(key.clone(), v);
            }
        }
    }
    let mut p = DepthParams::default();
    p.overlay(&Value::Object(own), KWARGS).map_err(to_py)?;
    p.check().map_err(to_py)
}

/// `depth_scale` given as a plain optional number (None = by type).
fn depth_params(
    py: Python<'_>,
    depth_scale: Option<&Bound<'_, PyAny>>,
) -> PyResult<Valid<DepthParams>> {
    let kw = pyo3::types::PyDict::new(py);
    if let Some(s) = given(depth_scale) {
        kw.set_item("depth_scale", s)?;
    }
    take_depth_params(&mut crate::params::kwargs_json(Some(&kw))?)
}

fn warn(py: Python<'_>, msg: &str) -> PyResult<()> {
    let cls = py.get_type::<InputWarning>();
    let text = std::ffi::CString::new(msg).unwrap_or_default();
    PyErr::warn(py, &cls, &text, 2)
}

/// The image size `(width, height)` that intrinsics carry (`isa.camera.Intrinsics` does).
fn stated_size(k: &Bound<'_, PyAny>) -> Option<(usize, usize)> {
    let get = |a: &str| k.getattr(a).ok()?.extract::<usize>().ok();
    Some((get("width")?, get("height")?))
}

/// A depth array or organised cloud read as stored values, with its size.
enum Stored {
    U16(Vec<u16>),
    F32(Vec<f32>),
    F64(Vec<f64>),
}

impl Stored {
    fn view(&self) -> DepthValues<'_> {
        match self {
            Stored::U16(v) => DepthValues::U16(v),
            Stored::F32(v) => DepthValues::F32(v),
            Stored::F64(v) => DepthValues::F64(v),
        }
    }
}

/// The pixels of a 2D depth array of dtype `T` (named `dtype` in errors).
fn pixels<T: numpy::Element + Copy>(depth: &Bound<'_, PyAny>, dtype: &str) -> PyResult<Vec<T>> {
    Ok(as_slice(&array::<T>(depth, "depth", dtype, &[None, None])?, "depth")?.to_vec())
}

fn stored(depth: &Bound<'_, PyAny>, k: &Intrinsics) -> PyResult<(Stored, usize, usize)> {
    let arr = depth.cast::<PyUntypedArray>().map_err(|_| {
        input_err(format!(
            "depth: expected a 2D uint16 or float array (H, W), or an organised point cloud (H, W, 3), got {}",
            describe(depth)
        ))
    })?;
    let sh = arr.shape().to_vec();
    let py = depth.py();
    let dt = arr.dtype();
    if sh.len() == 3 && sh[2] == 3 {
        if sh[0] == 0 || sh[1] == 0 {
            return Err(input_err(format!(
                "depth: an organised point cloud needs at least one row and column, got {}",
                describe(depth)
            )));
        }
        // An organised cloud: its points projected (each lands on its own pixel when the
        // intrinsics are the cloud's), in the cloud's unit.
        let a = array::<f64>(
            &depth.call_method1("astype", ("float64",))?,
            "depth",
            "float64",
            &[None, None, Some(3)],
        )?;
        let pts: Vec<[f64; 3]> = as_slice(&a, "depth")?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let (z, _) = di::depth_from_points(&pts, k, sh[1], sh[0]).map_err(to_py)?;
        return Ok((Stored::F32(z), sh[1], sh[0]));
    }
    if sh.len() != 2 {
        return Err(input_err(format!(
            "depth: expected a 2D array (height, width) or an organised point cloud (H, W, 3), got {}",
            describe(depth)
        )));
    }
    let (h, w) = (sh[0], sh[1]);
    let s = if dt.is_equiv_to(&numpy::dtype::<u16>(py)) {
        Stored::U16(pixels::<u16>(depth, "uint16")?)
    } else if dt.is_equiv_to(&numpy::dtype::<f32>(py)) {
        Stored::F32(pixels::<f32>(depth, "float32")?)
    } else if dt.is_equiv_to(&numpy::dtype::<f64>(py)) {
        Stored::F64(pixels::<f64>(depth, "float64")?)
    } else {
        return Err(input_err(format!(
            "depth: expected uint16 (millimetres, or units of depth_scale) or float32/float64 (metres, or units of depth_scale), got {}",
            describe(depth)
        )));
    };
    Ok((s, w, h))
}

/// Reads `depth` against `k_obj`: the stored values, the size checked, warnings raised.
fn read<'py>(
    depth: &Bound<'py, PyAny>,
    k_obj: &Bound<'py, PyAny>,
) -> PyResult<(Stored, usize, usize, Intrinsics)> {
    let k = intrinsics(k_obj)?;
    let (s, w, h) = stored(depth, &k)?;
    let size_warning =
        di::check_image_size(&k, w, h, stated_size(k_obj), "the intrinsics").map_err(to_py)?;
    if let Some(m) = size_warning {
        warn(depth.py(), &m)?;
    }
    Ok((s, w, h, k))
}

/// `(millimetres, width, height, intrinsics)` of a depth input (for `predict`).
pub(crate) fn depth_mm<'py>(
    depth: &Bound<'py, PyAny>,
    k_obj: &Bound<'py, PyAny>,
    p: &Valid<DepthParams>,
) -> PyResult<(Vec<u16>, usize, usize, Intrinsics)> {
    let (s, w, h, k) = read(depth, k_obj)?;
    let (mm, summary) = di::to_mm(s.view(), p);
    if let Some(m) = summary.warning() {
        warn(depth.py(), &m)?;
    }
    Ok((mm, w, h, k))
}

/// A depth image (H, W) or organised point cloud (H, W, 3) as float32 metres (0 = missing),
/// checked as `Forest.predict` checks it: `depth_scale` millimetres per stored unit (default:
/// 1 for integers, 1000 for floats), the size against intrinsics that carry one (an error when
/// it differs; `InputWarning` when the image looks transposed), `InputWarning` when the median
/// depth is implausible for a depth sensor.
#[pyfunction]
#[pyo3(signature = (depth, K, depth_scale=None))]
#[allow(non_snake_case)]
pub fn depth_to_metres<'py>(
    depth: &Bound<'py, PyAny>,
    K: &Bound<'py, PyAny>,
    depth_scale: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let py = depth.py();
    let p = depth_params(py, depth_scale)?;
    let (s, w, h, _) = read(depth, K)?;
    let (m, summary) = di::to_metres(s.view(), &p);
    if let Some(msg) = summary.warning() {
        warn(py, &msg)?;
    }
    Ok(crate::arrays::matrix(py, h, w, m))
}

/// Camera-frame points (N, 3) projected through `K` to a (height, width) float32 depth image
/// in the points' unit (0 = missing; the nearest point per pixel; points behind the camera or
/// outside the image skipped).
#[pyfunction]
#[pyo3(signature = (points, K, width, height))]
#[allow(non_snake_case)]
pub fn depth_from_points<'py>(
    points: &Bound<'py, PyAny>,
    K: &Bound<'py, PyAny>,
    width: usize,
    height: usize,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let k = intrinsics(K)?;
    let a = array::<f64>(points, "points", "float64", &[None, Some(3)])?;
    let pts: Vec<[f64; 3]> = as_slice(&a, "points")?
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let (d, _) = di::depth_from_points(&pts, &k, width, height).map_err(to_py)?;
    Ok(crate::arrays::matrix(points.py(), height, width, d))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let ty = m.py().get_type::<InputWarning>();
    ty.setattr("__module__", "isa._core")?; // the macro names the bare "_core"
    m.add("InputWarning", ty)?;
    m.add_function(wrap_pyfunction!(depth_to_metres, m)?)?;
    m.add_function(wrap_pyfunction!(depth_from_points, m)?)?;
    Ok(())
}
