//! Part sampling and the Eq. 5 depth features of parts, on NumPy images.

use numpy::prelude::*;
use numpy::PyArray2;
use pyo3::prelude::*;

use isa_core::Feature;

use crate::arrays::{depth_store, f32_array, matrix, parts as parts_arg};
use crate::errors::{param_err, to_py};
use crate::scalars;

fn stride_arg(o: &Bound<'_, PyAny>) -> PyResult<usize> {
    scalars::count(o, "stride", 1, param_err)
}

fn seed_arg(o: &Bound<'_, PyAny>) -> PyResult<u64> {
    scalars::seed(o, "seed")
}

/// Parts on a `stride` grid of every image: (P, 3) int32 `[image, u, v]` with depth > 0.
/// `max_per_image` (training) keeps at most that many per image, drawn from `seed`.
#[pyfunction]
#[pyo3(signature = (images, stride=4, max_per_image=None, seed=0))]
pub fn sample_parts<'py>(
    py: Python<'py>,
    images: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = stride_arg)] stride: usize,
    max_per_image: Option<&Bound<'py, PyAny>>,
    #[pyo3(from_py_with = seed_arg)] seed: u64,
) -> PyResult<Bound<'py, PyArray2<i32>>> {
    let max_per_image = scalars::opt_count(max_per_image, "max_per_image", 0, param_err)?;
    let store = depth_store(images)?;
    let parts = py
        .detach(|| isa_core::sample_parts(&store, stride, max_per_image, seed))
        .map_err(to_py)?;
    let n = parts.len();
    let flat: Vec<i32> = parts.into_iter().flatten().collect();
    Ok(matrix(py, n, 3, flat))
}

/// Eq. 5 features of every part for every candidate `(u[c], v[c])` (pixel·metres): (P, C) float32 mm.
#[pyfunction]
pub fn depth_features<'py>(
    py: Python<'py>,
    images: &Bound<'py, PyAny>,
    parts: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    v: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let store = depth_store(images)?;
    let parts = parts_arg(parts)?;
    store.validate_parts(&parts).map_err(to_py)?;
    let ua = f32_array(u, "u", &[None, Some(2)])?;
    let c = ua.shape()[0];
    let va = f32_array(v, "v", &[Some(c), Some(2)])?;
    let (us, vs) = (ua.as_slice()?, va.as_slice()?);
    let feats: Vec<Feature> = (0..c)
        .map(|k| Feature {
            u: [us[2 * k], us[2 * k + 1]],
            v: [vs[2 * k], vs[2 * k + 1]],
        })
        .collect();
    let out = py.detach(|| isa_core::features::eval_matrix(&store, &parts, &feats));
    Ok(matrix(py, parts.len(), c, out))
}
