//! PyO3 binding of `isa-core`, importable as `isa._core`. This layer only converts: NumPy
//! arrays in and out, core errors to their Python exception classes.

use pyo3::prelude::*;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", isa_core::VERSION)?;
    Ok(())
}
