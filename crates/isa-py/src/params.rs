//! Keyword arguments to JSON and JSON to Python: the core's parameter overlay
//! (`isa_core::params`) does the rest (unknown keys, types, ranges), so keyword arguments,
//! CLI flags and a model's stored defaults meet the same rules and messages.

use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict};
use serde_json::{Map, Value};

use isa_core::{ForestParams, PredictParams, Valid};

use crate::arrays::describe;
use crate::errors::{param_err, to_py};

/// Where keyword arguments come from, in error messages.
pub const KWARGS: &str = "keyword arguments";

/// One Python value as JSON: None, bool, int, float (finite), str.
fn to_json(key: &str, val: &Bound<'_, PyAny>) -> PyResult<Value> {
    if val.is_none() {
        Ok(Value::Null)
    } else if val.is_instance_of::<PyBool>() {
        Ok(Value::Bool(val.extract()?))
    } else if let Ok(i) = val.extract::<i64>() {
        Ok(Value::from(i))
    } else if let Ok(i) = val.extract::<u64>() {
        Ok(Value::from(i))
    } else if let Ok(f) = val.extract::<f64>() {
        serde_json::Number::from_f64(f)
            .map(Value::Number)
            .ok_or_else(|| param_err(format!("{key} must be finite, got {f}")))
    } else if let Ok(s) = val.extract::<String>() {
        Ok(Value::String(s))
    } else {
        Err(param_err(format!(
            "{key}: expected a number or a string, got {}",
            describe(val)
        )))
    }
}

/// Keyword arguments (or any str-keyed dict of plain values) as a JSON object.
pub fn kwargs_json(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Value> {
    let mut o = Map::new();
    if let Some(kw) = kwargs {
        for (k, v) in kw.iter() {
            let key: String = k.extract()?;
            let j = to_json(&key, &v)?;
            o.insert(key, j);
        }
    }
    Ok(Value::Object(o))
}

/// JSON to Python objects (dicts, lists, numbers, strings) through the `json` module.
pub fn json_to_py<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (v.to_string(),))
}

/// Forest parameters: the defaults overlaid with `kwargs`, checked.
pub fn forest_params(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Valid<ForestParams>> {
    let mut p = ForestParams::default();
    p.overlay(&kwargs_json(kwargs)?, KWARGS).map_err(to_py)?;
    p.check().map_err(to_py)
}

/// `FOREST_DEFAULTS` and `PREDICT_DEFAULTS` (flat keys): the core's defaults, for Python's
/// `ForestParams` and documentation.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    // Through text: f32 fields as their shortest decimal (0.05, not 0.0500000007...).
    let forest: Value = serde_json::from_str(&ForestParams::default().to_json()).expect("JSON");
    m.add("FOREST_DEFAULTS", json_to_py(py, &forest)?)?;
    let predict = Value::Object(PredictParams::default().to_flat_json());
    m.add("PREDICT_DEFAULTS", json_to_py(py, &predict)?)?;
    Ok(())
}
