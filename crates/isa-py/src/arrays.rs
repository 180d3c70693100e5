//! Strict NumPy argument checks: dtype, number of dimensions, shape, C-contiguity, finiteness.
//! Messages name the argument, what was expected and what was given.

use numpy::prelude::*;
use numpy::{Element, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArray};
use pyo3::prelude::*;
use pyo3::types::PyList;

use isa_core::{DepthStore, Part};

use crate::errors::input_err;

/// "float64 array of shape (10, 3)" or the Python type name.
pub fn describe(obj: &Bound<'_, PyAny>) -> String {
    if let Ok(a) = obj.cast::<PyUntypedArray>() {
        let dt = a
            .dtype()
            .str()
            .map(|s| s.to_string())
            .unwrap_or_else(|_| "?".into());
        let contig = if a.is_c_contiguous() {
            ""
        } else {
            " (not C-contiguous)"
        };
        let dims: Vec<String> = a.shape().iter().map(|d| d.to_string()).collect();
        let tuple = if dims.len() == 1 {
            format!("({},)", dims[0])
        } else {
            format!("({})", dims.join(", "))
        };
        format!("{dt} array of shape {tuple}{contig}")
    } else {
        obj.get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_else(|_| "?".into())
    }
}

/// Borrows `obj` as a C-contiguous `dtype` array of `ndim` dimensions whose shape matches
/// `shape` (None = any size). `want` names the dtype for messages.
pub fn array<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    want: &str,
    shape: &[Option<usize>],
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    let expect = {
        let dims: Vec<String> = shape
            .iter()
            .map(|d| d.map_or("n".into(), |v| v.to_string()))
            .collect();
        format!("a C-contiguous {want} array of shape ({})", dims.join(", "))
    };
    let arr = obj
        .cast::<PyArrayDyn<T>>()
        .map_err(|_| input_err(format!("{name}: expected {expect}, got {} (convert with np.ascontiguousarray({name}, dtype=np.{want}))", describe(obj))))?;
    let sh = arr.shape();
    if sh.len() != shape.len()
        || sh
            .iter()
            .zip(shape)
            .any(|(s, w)| w.is_some_and(|w| w != *s))
    {
        return Err(input_err(format!(
            "{name}: expected {expect}, got {}",
            describe(obj)
        )));
    }
    if !arr.is_c_contiguous() {
        return Err(input_err(format!(
            "{name}: expected {expect}, got a non-contiguous array (use np.ascontiguousarray({name}))"
        )));
    }
    Ok(arr.readonly())
}

/// Checks a float array has no NaN or infinity.
pub fn check_finite(a: &[f32], name: &str, cols: usize) -> PyResult<()> {
    if let Some(k) = a.iter().position(|v| !v.is_finite()) {
        let cols = cols.max(1);
        return Err(input_err(format!(
            "{name}[{}, {}] is not finite ({})",
            k / cols,
            k % cols,
            a[k]
        )));
    }
    Ok(())
}

/// Copies a list of uint16 2D C-contiguous depth images (mm, 0 = missing) into a store.
pub fn depth_store(images: &Bound<'_, PyAny>) -> PyResult<DepthStore> {
    let list = images.cast::<PyList>().map_err(|_| {
        input_err(format!(
            "images: expected a list of uint16 2D arrays, got {}",
            describe(images)
        ))
    })?;
    let mut store = DepthStore::new();
    for (i, img) in list.iter().enumerate() {
        let a = array::<u16>(&img, &format!("images[{i}]"), "uint16", &[None, None])?;
        let sh = a.shape().to_vec();
        store
            .push(
                sh[1],
                sh[0],
                a.as_slice()
                    .map_err(|e| input_err(format!("images[{i}]: {e}")))?,
            )
            .map_err(crate::errors::to_py)?;
    }
    Ok(store)
}

/// Copies `(P, 3)` int32 parts.
pub fn parts(obj: &Bound<'_, PyAny>) -> PyResult<Vec<Part>> {
    let a = array::<i32>(obj, "parts", "int32", &[None, Some(3)])?;
    let s = a.as_slice().map_err(|e| input_err(format!("parts: {e}")))?;
    Ok(s.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}
