//! Depth rendering (`isa_core::render`): a mesh's vertices and faces, a pose and a camera in,
//! the (H, W) float32 depth and bool mask out; `isa.render.renderer.DepthRenderer`'s "core"
//! backend calls it.

use numpy::prelude::*;
use numpy::{Element, PyArray2, PyUntypedArray};
use pyo3::prelude::*;

use isa_core::render::{render_depth as core_render, RenderCamera};
use isa_core::vote::Intrinsics;

use crate::arrays::{describe, fixed_rows, mat3_rows, matrix, t_arg};
use crate::errors::{input_err, to_py};
use crate::predict::intrinsics;
use crate::scalars::{count, number};

/// `faces` of any common integer dtype, each index checked into `u32` (range against the
/// vertices: the core).
fn faces(obj: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    fn rows<T: Element + Copy + TryInto<u32>>(
        obj: &Bound<'_, PyAny>,
        want: &str,
    ) -> PyResult<Vec<[u32; 3]>> {
        let rows = fixed_rows::<T, 3>(obj, "faces", want)?;
        let mut out = Vec::with_capacity(rows.len());
        for (k, c) in rows.iter().enumerate() {
            let mut f = [0u32; 3];
            for (j, (dst, &src)) in f.iter_mut().zip(c).enumerate() {
                *dst = src.try_into().map_err(|_| {
                    input_err(format!(
                        "faces[{k}, {j}] is not a vertex index (negative or 2**32 or more)"
                    ))
                })?;
            }
            out.push(f);
        }
        Ok(out)
    }
    let wrong = || {
        input_err(format!(
            "faces: expected an integer array (uint32, int32, int64 or uint64) of shape (n, 3), got {}",
            describe(obj)
        ))
    };
    let dt = obj.cast::<PyUntypedArray>().map_err(|_| wrong())?.dtype();
    let py = obj.py();
    if dt.is_equiv_to(&numpy::dtype::<u32>(py)) {
        rows::<u32>(obj, "uint32")
    } else if dt.is_equiv_to(&numpy::dtype::<i64>(py)) {
        rows::<i64>(obj, "int64")
    } else if dt.is_equiv_to(&numpy::dtype::<i32>(py)) {
        rows::<i32>(obj, "int32")
    } else if dt.is_equiv_to(&numpy::dtype::<u64>(py)) {
        rows::<u64>(obj, "uint64")
    } else {
        Err(wrong())
    }
}

/// The pose's rotation `R` as given (finiteness: the core, which names the vertex it spoils).
fn r_arg(obj: &Bound<'_, PyAny>) -> PyResult<[[f64; 3]; 3]> {
    mat3_rows(obj, "R")
}

/// Depth (H, W) float32 metres (0 = background) and mask (H, W) bool of the mesh
/// (`vertices` (N, 3) float32 in the object frame, `faces` (M, 3) integer) at pose
/// `X_cam = R @ X_obj + t`, through `K` (OpenCV, pixel centres at integers) in a
/// `width` x `height` image between `znear` and `zfar` metres. Both windings of every face are
/// drawn; the nearest face wins.
#[pyfunction]
#[pyo3(signature = (vertices, faces, R, t, K, width, height, znear, zfar))]
#[allow(non_snake_case, clippy::too_many_arguments, clippy::type_complexity)]
pub fn render_depth<'py>(
    vertices: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = r_arg)] R: [[f64; 3]; 3],
    #[pyo3(from_py_with = t_arg)] t: [f64; 3],
    #[pyo3(from_py_with = intrinsics)] K: Intrinsics,
    width: &Bound<'py, PyAny>,
    height: &Bound<'py, PyAny>,
    znear: &Bound<'py, PyAny>,
    zfar: &Bound<'py, PyAny>,
) -> PyResult<(Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<bool>>)> {
    let py = vertices.py();
    let v = fixed_rows::<f32, 3>(vertices, "vertices", "float32")?;
    let f = self::faces(faces)?;
    let camera = RenderCamera {
        k: K,
        width: count(width, "width", 0, input_err)?,
        height: count(height, "height", 0, input_err)?,
        znear: number(znear, "znear")?,
        zfar: number(zfar, "zfar")?,
    };
    let out = py
        .detach(|| core_render(&v, &f, &R, &t, &camera))
        .map_err(to_py)?;
    Ok((
        matrix(py, out.height, out.width, out.depth),
        matrix(py, out.height, out.width, out.mask),
    ))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(render_depth, m)?)?;
    Ok(())
}
