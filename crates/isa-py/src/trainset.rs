//! Training-set files (`.isat`, see `isa_core::trainset_io`) from and to NumPy: what
//! `isa train` reads.

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use isa_core::trainset_io::{self, TrainSetData};

use crate::arrays::{matrix, rows, TrainParts};
use crate::errors::to_py;

/// Writes a training-set file (`.isat`, see `isa_core::trainset_io`) for `isa train`: the same
/// arguments as `Forest.fit` (images: list of (h, w) uint16 crops; parts (P, 3) int32; offsets
/// (P, 3), rotations (P, 4), link_angles (P, L), node_offsets (P, 3N) float32) plus metadata JSON.
// Its array arguments are `Forest.fit`'s on purpose (the public API; converted by the same
// `arrays::TrainParts`).
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
    let train = TrainParts::new(images, parts)?;
    let targets = train.targets(offsets, rotations, link_angles, node_offsets)?;
    let raw = targets.raw();
    let owned = |a: Option<(&[f32], usize)>| a.map(|(v, c)| (v.to_vec(), c));
    let ts = TrainSetData {
        store: train.store,
        parts: train.parts,
        offsets: raw.offsets.to_vec(),
        rotations: raw.rotations.to_vec(),
        link_angles: owned(raw.link_angles),
        node_offsets: owned(raw.node_offsets),
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
    m.add_function(wrap_pyfunction!(write_trainset, m)?)?;
    m.add_function(wrap_pyfunction!(read_trainset, m)?)?;
    Ok(())
}
