//! Scalar arguments (counts, indices, thread numbers, seeds, numbers, byte strings, paths)
//! taken as Python objects and checked here, so that a negative, huge or wrongly typed value
//! raises an `isa` error naming the argument: pyo3's own conversions raise a bare
//! `OverflowError` (`n_threads=-1`, `2**70`) or `TypeError` (`fx="a"`, `from_bytes("abc")`).
//! Range errors are the caller's kind (`param_err` for parameters, `input_err` for indices);
//! type errors are `InvalidTypeError` (also `TypeError`).

use std::path::PathBuf;

use pyo3::exceptions::PyOverflowError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyBytes, PyString};

use crate::arrays::describe;
use crate::errors::type_err;

/// A whole number `>= min` (`usize`); `range` makes the error for a value out of range.
pub fn count(
    obj: &Bound<'_, PyAny>,
    name: &str,
    min: usize,
    range: fn(String) -> PyErr,
) -> PyResult<usize> {
    let out_of_range = || {
        range(format!(
            "{name} must be an integer >= {min}, got {}",
            obj.repr().map_or("?".into(), |r| r.to_string())
        ))
    };
    if obj.is_instance_of::<PyBool>() {
        return Err(type_err(format!("{name}: expected an integer, got bool")));
    }
    match obj.extract::<i64>() {
        Ok(v) if v >= 0 && v as u64 >= min as u64 => usize::try_from(v).map_err(|_| out_of_range()),
        Ok(_) => Err(out_of_range()),
        Err(e) if e.is_instance_of::<PyOverflowError>(obj.py()) => Err(out_of_range()),
        Err(_) => Err(type_err(format!(
            "{name}: expected an integer, got {}",
            describe(obj)
        ))),
    }
}

/// [`count`] of an optional argument (absent or `None` gives `None`).
pub fn opt_count(
    obj: Option<&Bound<'_, PyAny>>,
    name: &str,
    min: usize,
    range: fn(String) -> PyErr,
) -> PyResult<Option<usize>> {
    crate::arrays::given(obj)
        .map(|o| count(o, name, min, range))
        .transpose()
}

/// `n_threads`: None (all cores) or at least 1.
pub fn n_threads(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<usize>> {
    opt_count(obj, "n_threads", 1, crate::errors::param_err)
}

/// A seed: a whole number in `[0, 2^64)`.
pub fn seed(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<u64> {
    if obj.is_instance_of::<PyBool>() {
        return Err(type_err(format!("{name}: expected an integer, got bool")));
    }
    obj.extract::<u64>().map_err(|e| {
        if e.is_instance_of::<PyOverflowError>(obj.py()) {
            crate::errors::param_err(format!(
                "{name} must be an integer in [0, 2**64), got {}",
                obj.repr().map_or("?".into(), |r| r.to_string())
            ))
        } else {
            type_err(format!(
                "{name}: expected an integer, got {}",
                describe(obj)
            ))
        }
    })
}

/// `obj` as a `T`, or "`name`: expected `what`, got ..." as an `InvalidTypeError`.
fn typed<'py, T: FromPyObjectOwned<'py>>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    what: &str,
) -> PyResult<T> {
    obj.extract::<T>()
        .map_err(|_| type_err(format!("{name}: expected {what}, got {}", describe(obj))))
}

/// A real number (int or float, NumPy scalars included).
pub fn number(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f64> {
    typed(obj, name, "a number")
}

/// The bytes of a `bytes`, `bytearray`, `memoryview` or other buffer of bytes.
pub fn bytes(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<u8>> {
    if let Ok(b) = obj.cast::<PyBytes>() {
        return Ok(b.as_bytes().to_vec());
    }
    if !obj.is_instance_of::<PyString>() {
        // Through memoryview rather than the buffer API, which the stable ABI (abi3) lacks
        // before Python 3.11: byte buffers only, as PyBuffer::<u8> accepted.
        if let Ok(mv) = obj
            .py()
            .import("builtins")?
            .getattr("memoryview")?
            .call1((obj,))
        {
            if mv.getattr("format")?.extract::<String>()? == "B" {
                let b = mv.call_method0("tobytes")?;
                return Ok(b.cast::<PyBytes>()?.as_bytes().to_vec());
            }
        }
    }
    Err(type_err(format!(
        "{name}: expected bytes (or a bytearray / memoryview of bytes), got {}",
        describe(obj)
    )))
}

/// A file-system path (`str` or `os.PathLike`).
pub fn path(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<PathBuf> {
    typed(obj, name, "a path (str or os.PathLike)")
}

/// A `str`.
pub fn text(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<String> {
    typed(obj, name, "a str")
}
