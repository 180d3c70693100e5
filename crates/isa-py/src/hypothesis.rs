//! `isa._core.Hypothesis`: one ranked 6D pose. Its fields are attributes (`h.R`, `h.t`, ...) and
//! also items under the same names (`h["R"]`, `h.get("score")`, `dict(h)`), as when hypotheses
//! were dicts; `isa/__init__` registers the class as a `collections.abc.Mapping`.

use numpy::{PyArray1, PyArray2};
use pyo3::exceptions::PyKeyError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use isa_core::vote::Hypothesis as CoreHypothesis;

use crate::arrays::{rows, vector};

const KEYS: [&str; 8] = [
    "R",
    "t",
    "pose",
    "quaternion",
    "score",
    "support",
    "position_score",
    "position_support",
];

/// A pose hypothesis `X_cam = R @ X_obj + t`: `R` (3, 3), `t` (3,) metres (the object-frame
/// origin in the camera frame), `pose` (4, 4) the same as one matrix, `quaternion` (w, x, y, z), `score` (joint vote density, the
/// ranking key), `support` (votes in both kernels), `position_score`, `position_support`.
#[pyclass(name = "Hypothesis", module = "isa._core", frozen)]
pub struct PyHypothesis {
    h: CoreHypothesis,
    // The scalar fields, copied from `h` so that pyo3 makes their getters.
    #[pyo3(get)]
    score: f64,
    #[pyo3(get)]
    support: usize,
    #[pyo3(get)]
    position_score: f64,
    #[pyo3(get)]
    position_support: usize,
}

impl From<CoreHypothesis> for PyHypothesis {
    fn from(h: CoreHypothesis) -> Self {
        PyHypothesis {
            score: h.score,
            support: h.support,
            position_score: h.position_score,
            position_support: h.position_support,
            h,
        }
    }
}

impl PyHypothesis {
    /// The core hypothesis.
    pub fn inner(&self) -> &CoreHypothesis {
        &self.h
    }

    fn item<'py>(&self, py: Python<'py>, key: &str) -> Option<Bound<'py, PyAny>> {
        let h = &self.h;
        Some(match key {
            "R" => rows(py, h.rotation.iter().copied()).into_any(),
            "t" => vector(py, h.translation.to_vec()).into_any(),
            "pose" => self.pose(py).into_any(),
            "quaternion" => vector(py, h.quaternion.to_vec()).into_any(),
            "score" => h.score.into_pyobject(py).ok()?.into_any(),
            "support" => h.support.into_pyobject(py).ok()?.into_any(),
            "position_score" => h.position_score.into_pyobject(py).ok()?.into_any(),
            "position_support" => h.position_support.into_pyobject(py).ok()?.into_any(),
            _ => return None,
        })
    }
}

#[pymethods]
impl PyHypothesis {
    /// Rotation matrix (3, 3).
    #[getter(R)]
    fn rotation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        rows(py, self.h.rotation.iter().copied())
    }
    /// Translation (3,), metres.
    #[getter]
    fn t<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vector(py, self.h.translation.to_vec())
    }
    /// The 4x4 pose `[[R, t], [0, 0, 0, 1]]`: `X_cam = pose @ [X_obj, 1]`.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let m = isa_core::rotation::pose_matrix(&self.h.rotation, &self.h.translation);
        rows(py, m.iter().copied())
    }
    /// The rotation as a unit quaternion (w, x, y, z), w >= 0.
    #[getter]
    fn quaternion<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vector(py, self.h.quaternion.to_vec())
    }
    fn __getitem__<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        self.item(py, key)
            .ok_or_else(|| PyKeyError::new_err(key.to_string()))
    }
    #[pyo3(signature = (key, default=None))]
    fn get<'py>(
        &self,
        py: Python<'py>,
        key: &str,
        default: Option<Bound<'py, PyAny>>,
    ) -> Option<Bound<'py, PyAny>> {
        self.item(py, key).or(default)
    }
    fn __contains__(&self, key: &str) -> bool {
        KEYS.contains(&key)
    }
    fn __len__(&self) -> usize {
        KEYS.len()
    }
    fn __iter__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        PyList::new(py, KEYS)?
            .into_any()
            .try_iter()
            .map(|i| i.into_any())
    }
    fn keys(&self) -> Vec<&'static str> {
        KEYS.to_vec()
    }
    fn values<'py>(&self, py: Python<'py>) -> Vec<Option<Bound<'py, PyAny>>> {
        KEYS.iter().map(|k| self.item(py, k)).collect()
    }
    #[allow(clippy::type_complexity)]
    fn items<'py>(&self, py: Python<'py>) -> Vec<(&'static str, Option<Bound<'py, PyAny>>)> {
        KEYS.iter().map(|k| (*k, self.item(py, k))).collect()
    }
    /// The fields as a plain dict.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for k in KEYS {
            d.set_item(k, self.item(py, k))?;
        }
        Ok(d)
    }
    fn __repr__(&self) -> String {
        let t = self.h.translation;
        format!(
            "Hypothesis(t=[{:.4}, {:.4}, {:.4}], score={:.4}, support={})",
            t[0], t[1], t[2], self.h.score, self.h.support
        )
    }
}

/// Python list of hypotheses, best first.
pub fn to_list<'py>(py: Python<'py>, hyps: Vec<CoreHypothesis>) -> PyResult<Bound<'py, PyList>> {
    PyList::new(py, hyps.into_iter().map(PyHypothesis::from))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyHypothesis>()?;
    // Hypotheses were dicts: code that checks for a Mapping keeps working.
    let ty = m.py().get_type::<PyHypothesis>();
    m.py()
        .import("collections.abc")?
        .getattr("Mapping")?
        .call_method1("register", (ty,))?;
    Ok(())
}
