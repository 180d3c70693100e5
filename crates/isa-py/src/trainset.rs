//! Training-set files (`.isat`, see `isa_core::trainset_io`) from and to NumPy: what
//! `isa train` reads.

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use isa_core::trainset_io;

use isa_core::TrainingSet;

use crate::arrays::{given, matrix, rows, TrainParts};
use crate::errors::to_py;

/// A training set as `Forest.fit` takes it and `isa train` reads it from a `.isat` file:
/// images (list of (h, w) uint16 crops), parts (P, 3) int32, offsets (P, 3), rotations (P, 4),
/// link_angles (P, L) and node_offsets (P, 3N) float32 or None, and metadata JSON. Checked
/// when made; the crops and parts are copied, the per-part targets referenced (converted and
/// checked again where used), so fitting holds no second copy of them.
#[pyclass(name = "TrainSet", module = "isa._core", frozen)]
pub struct PyTrainSet {
    parts: TrainParts,
    offsets: Py<PyAny>,
    rotations: Py<PyAny>,
    link_angles: Option<Py<PyAny>>,
    node_offsets: Option<Py<PyAny>>,
    metadata: String,
}

impl PyTrainSet {
    /// The checked targets, borrowed for the span of `run` on the core's training set.
    pub fn with_training_set<R>(
        &self,
        py: Python<'_>,
        run: impl FnOnce(&TrainingSet<'_>) -> PyResult<R>,
    ) -> PyResult<R> {
        let bind = |o: &Option<Py<PyAny>>| o.as_ref().map(|o| o.bind(py).clone());
        let (la, no) = (bind(&self.link_angles), bind(&self.node_offsets));
        let targets = self.parts.targets(
            self.offsets.bind(py),
            self.rotations.bind(py),
            la.as_ref(),
            no.as_ref(),
        )?;
        run(&self.parts.training_set(&targets))
    }

    /// The metadata JSON it was made with.
    pub fn metadata(&self) -> &str {
        &self.metadata
    }
}

#[pymethods]
impl PyTrainSet {
    #[new]
    #[pyo3(signature = (images, parts, offsets, rotations, link_angles=None, node_offsets=None, metadata="{}"))]
    fn new(
        images: &Bound<'_, PyAny>,
        parts: &Bound<'_, PyAny>,
        offsets: &Bound<'_, PyAny>,
        rotations: &Bound<'_, PyAny>,
        link_angles: Option<&Bound<'_, PyAny>>,
        node_offsets: Option<&Bound<'_, PyAny>>,
        metadata: &str,
    ) -> PyResult<Self> {
        let train = TrainParts::new(images, parts)?;
        // Checked now, so a bad array is named where the set is made.
        let targets = train.targets(offsets, rotations, link_angles, node_offsets)?;
        train.training_set(&targets).validate().map_err(to_py)?;
        let own = |o: Option<&Bound<'_, PyAny>>| given(o).map(|o| o.clone().unbind());
        Ok(PyTrainSet {
            parts: train,
            offsets: offsets.clone().unbind(),
            rotations: rotations.clone().unbind(),
            link_angles: own(link_angles),
            node_offsets: own(node_offsets),
            metadata: metadata.to_string(),
        })
    }

    /// The number of parts.
    fn __len__(&self) -> usize {
        self.parts.parts.len()
    }

    /// The number of depth crops.
    #[getter]
    fn n_images(&self) -> usize {
        self.parts.store.len()
    }

    /// Writes the set as a training-set file (`.isat`, see `isa_core::trainset_io` and
    /// docs/CLI.md: versioned, checksummed NPY arrays) for `isa train`. Atomic (temporary
    /// file + rename).
    fn write(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.with_training_set(py, |set| {
            py.detach(|| trainset_io::write_set(set, &self.metadata, &path))
                .map_err(to_py)
        })
    }
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
        imgs.append(matrix(py, h, w, ts.store.image(i).data.to_vec()))?;
    }
    let p = ts.parts.len();
    d.set_item("images", imgs)?;
    d.set_item("parts", rows(py, ts.parts.iter().copied()))?;
    d.set_item("offsets", matrix(py, p, 3, ts.offsets))?;
    d.set_item("rotations", matrix(py, p, 4, ts.rotations))?;
    for (name, arr) in [
        ("link_angles", ts.link_angles),
        ("node_offsets", ts.node_offsets),
    ] {
        match arr {
            Some((a, c)) => d.set_item(name, matrix(py, p, c, a))?,
            None => d.set_item(name, py.None())?,
        }
    }
    d.set_item("metadata", ts.metadata)?;
    Ok(d)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TRAINSET_FORMAT_VERSION", trainset_io::FORMAT_VERSION)?;
    m.add_class::<PyTrainSet>()?;
    m.add_function(wrap_pyfunction!(read_trainset, m)?)?;
    Ok(())
}
