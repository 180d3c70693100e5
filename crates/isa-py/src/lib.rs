//! PyO3 binding of `isa-core`, importable as `isa._core`. This layer only converts: NumPy
//! arrays in and out, core errors to their Python exception classes.

use pyo3::prelude::*;

pub mod arrays;
pub mod errors;
pub mod forest;
pub mod hooks;
pub mod vote;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", isa_core::VERSION)?;
    m.add("MODEL_FORMAT_VERSION", isa_core::model_io::FORMAT_VERSION)?;
    m.add("BACKGROUND_MM", isa_core::BACKGROUND_MM)?;
    errors::register(m)?;
    m.add_class::<forest::PyForest>()?;
    m.add_function(wrap_pyfunction!(hooks::sample_parts, m)?)?;
    m.add_function(wrap_pyfunction!(hooks::depth_features, m)?)?;
    m.add_function(wrap_pyfunction!(hooks::criterion_gains, m)?)?;
    m.add_function(wrap_pyfunction!(hooks::criterion_targets, m)?)?;
    m.add_function(wrap_pyfunction!(hooks::split_search, m)?)?;
    vote::register(m)?; // inference: predict, image_votes, find_modes, trainset files
    Ok(())
}
