//! One Python exception class per `IsaError` variant, all subclassing `isa._core.IsaError`.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

use isa_core::IsaError as CoreError;

create_exception!(
    _core,
    IsaError,
    PyException,
    "Base class of every error raised by isa."
);
create_exception!(
    _core,
    InvalidInputError,
    IsaError,
    "An argument has the wrong dtype, shape, layout or value (the message names it)."
);
create_exception!(
    _core,
    InvalidParameterError,
    IsaError,
    "A hyper-parameter failed validation (the message names it)."
);
create_exception!(
    _core,
    ModelFormatError,
    IsaError,
    "A model file is truncated, corrupted, foreign or from a newer format version."
);
create_exception!(
    _core,
    IsaIOError,
    IsaError,
    "An operating-system I/O failure on a named file."
);

/// Converts a core error to its Python exception.
pub fn to_py(e: CoreError) -> PyErr {
    let msg = e.to_string();
    match e {
        CoreError::InvalidInput(_) => InvalidInputError::new_err(msg),
        CoreError::InvalidParameter(_) => InvalidParameterError::new_err(msg),
        CoreError::ModelFormat { .. } => ModelFormatError::new_err(msg),
        CoreError::Io { .. } => IsaIOError::new_err(msg),
    }
}

pub fn input_err(msg: impl Into<String>) -> PyErr {
    InvalidInputError::new_err(msg.into())
}

pub fn param_err(msg: impl Into<String>) -> PyErr {
    InvalidParameterError::new_err(msg.into())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("IsaError", py.get_type::<IsaError>())?;
    m.add("InvalidInputError", py.get_type::<InvalidInputError>())?;
    m.add(
        "InvalidParameterError",
        py.get_type::<InvalidParameterError>(),
    )?;
    m.add("ModelFormatError", py.get_type::<ModelFormatError>())?;
    m.add("IsaIOError", py.get_type::<IsaIOError>())?;
    Ok(())
}
