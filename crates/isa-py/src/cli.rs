//! The `isa` command line inside the extension, for the Python package's console script
//! (`isa.cli:main`): the same program as the Rust binary (`isa_cli::run`).

use pyo3::prelude::*;

/// Runs `isa` with `argv` (program name first) without the GIL; returns the exit code.
#[pyfunction]
pub fn _cli_main(py: Python<'_>, argv: Vec<String>) -> u8 {
    py.detach(|| isa_cli::run(argv))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(_cli_main, m)?)
}
