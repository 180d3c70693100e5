//! One Python exception class per `IsaError` variant, each also the matching builtin, all
//! subclasses of `isa._core.IsaError`:
//!
//! | core variant | Python class | also |
//! |---|---|---|
//! | `InvalidInput` | `InvalidInputError` | `ValueError` |
//! | (argument of the wrong type, binding side) | `InvalidTypeError` (an `InvalidInputError`) | `TypeError` |
//! | `InvalidParameter` | `InvalidParameterError` | `ValueError` |
//! | `ModelFormat` | `ModelFormatError` | `ValueError` |
//! | `Io` | `IsaIOError` | `OSError`; by error kind `IsaFileNotFoundError` (`FileNotFoundError`), `IsaPermissionError` (`PermissionError`), `IsaIsADirectoryError` (`IsADirectoryError`), with `errno` and `filename` set |
//!
//! The classes have two bases, which `create_exception!` cannot express, so they are defined
//! in Python, from the table below, when the module loads.

use std::ffi::CString;

use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

use isa_core::IsaError as CoreError;

/// Name, bases and docstring of each class, in the order of [`Kind`] (a base before its
/// subclasses); [`source`] turns them into the Python that defines them.
const CLASSES: [(&str, &str, &str); 9] = [
    (
        "IsaError",
        "Exception",
        "Base class of every error raised by isa.",
    ),
    (
        "InvalidInputError",
        "IsaError, ValueError",
        "An argument has the wrong dtype, shape, layout or value (the message names it).",
    ),
    (
        "InvalidTypeError",
        "InvalidInputError, TypeError",
        "An argument has the wrong type (the message names it).",
    ),
    (
        "InvalidParameterError",
        "IsaError, ValueError",
        "A hyper-parameter failed validation (the message names it).",
    ),
    (
        "ModelFormatError",
        "IsaError, ValueError",
        "A model file is truncated, corrupted, foreign or from a newer format version.",
    ),
    (
        "IsaIOError",
        "IsaError, OSError",
        "An operating-system I/O failure on a named file (``filename``, ``errno`` set).",
    ),
    (
        "IsaFileNotFoundError",
        "IsaIOError, FileNotFoundError",
        "A file that isa needs does not exist.",
    ),
    (
        "IsaPermissionError",
        "IsaIOError, PermissionError",
        "A file cannot be read or written for lack of permission.",
    ),
    (
        "IsaIsADirectoryError",
        "IsaIOError, IsADirectoryError",
        "A path names a directory where isa needs a file.",
    ),
];

/// The Python source of the classes.
fn source() -> CString {
    let text: String = CLASSES
        .iter()
        .map(|(name, bases, doc)| {
            format!(
                "class {name}({bases}):\n    \"\"\"{doc}\"\"\"\n    __module__ = \"isa._core\"\n\n"
            )
        })
        .collect();
    CString::new(text).expect("no NUL in the class table")
}

#[derive(Clone, Copy)]
enum Kind {
    Input = 1,
    Type = 2,
    Parameter = 3,
    Format = 4,
    Io = 5,
    NotFound = 6,
    Permission = 7,
    IsDirectory = 8,
}

static TYPES: PyOnceLock<Vec<Py<PyType>>> = PyOnceLock::new();

fn types(py: Python<'_>) -> &Vec<Py<PyType>> {
    TYPES
        .get_or_try_init(py, || -> PyResult<Vec<Py<PyType>>> {
            let m =
                PyModule::from_code(py, &source(), c"isa/_core/errors.py", c"isa._core._errors")?;
            CLASSES
                .iter()
                .map(|(n, _, _)| Ok(m.getattr(*n)?.cast_into::<PyType>()?.unbind()))
                .collect()
        })
        .expect("the exception classes are valid Python")
}

fn new_err(kind: Kind, msg: String) -> PyErr {
    Python::attach(|py| PyErr::from_type(types(py)[kind as usize].bind(py).clone(), msg))
}

/// Converts a core error to its Python exception.
pub fn to_py(e: CoreError) -> PyErr {
    let msg = e.to_string();
    match e {
        CoreError::InvalidInput(_) => new_err(Kind::Input, msg),
        CoreError::InvalidParameter(_) => new_err(Kind::Parameter, msg),
        CoreError::ModelFormat { .. } => new_err(Kind::Format, msg),
        CoreError::Io { path, source } => {
            let kind = match source.kind() {
                std::io::ErrorKind::NotFound => Kind::NotFound,
                std::io::ErrorKind::PermissionDenied => Kind::Permission,
                std::io::ErrorKind::IsADirectory => Kind::IsDirectory,
                _ => Kind::Io,
            };
            Python::attach(|py| {
                let ty = types(py)[kind as usize].bind(py).clone();
                match source.raw_os_error() {
                    // OSError(errno, strerror, filename): str() is "[Errno 2] ...: 'path'".
                    Some(errno) => {
                        let text = source.to_string();
                        let strerror = text
                            .strip_suffix(&format!(" (os error {errno})"))
                            .unwrap_or(&text)
                            .to_string();
                        PyErr::from_type(ty, (errno, strerror, path))
                    }
                    None => PyErr::from_type(ty, (msg,)),
                }
            })
        }
    }
}

pub fn input_err(msg: impl Into<String>) -> PyErr {
    new_err(Kind::Input, msg.into())
}

pub fn type_err(msg: impl Into<String>) -> PyErr {
    new_err(Kind::Type, msg.into())
}

pub fn param_err(msg: impl Into<String>) -> PyErr {
    new_err(Kind::Parameter, msg.into())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    for ((name, _, _), ty) in CLASSES.iter().zip(types(py)) {
        m.add(*name, ty.bind(py))?;
    }
    Ok(())
}
