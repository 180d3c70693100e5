//! One JSON overlay for every parameter set: keys of a JSON object replace the same keys of the
//! parameters' JSON form (nested objects key by key). Unknown keys and values of the wrong type
//! are errors that name the key and the source ("flags", "parameter file x.json", "keyword
//! arguments", ...).

use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Value};

use crate::error::{IsaError, Result};

fn bad(msg: String) -> IsaError {
    IsaError::InvalidParameter(msg)
}

/// The keys of a JSON object, sorted, for "known: [...]" messages.
pub(crate) fn known_keys(v: &Value) -> Vec<String> {
    let mut k: Vec<String> = v
        .as_object()
        .map(|o| o.keys().cloned().collect())
        .unwrap_or_default();
    k.sort();
    k
}

/// `base` with the keys of `over` (a JSON object) replacing its own; `source` names where `over`
/// came from in errors. Does not validate ranges: call `check()` on the result.
pub fn overlay_json<T: Serialize + DeserializeOwned>(
    base: &T,
    over: &Value,
    source: &str,
) -> Result<T> {
    let over = over.as_object().ok_or_else(|| {
        bad(format!(
            "{source}: expected a JSON object of parameters, got {over}"
        ))
    })?;
    let start = serde_json::to_value(base).expect("parameters serialise to JSON");
    let mut v = start.clone();
    merge(&mut v, over, source, "")?;
    serde_json::from_value::<T>(v).map_err(|e| {
        // Name the culprit: the first key that fails on its own.
        let mut leaves = Vec::new();
        flatten(over, "", &mut leaves);
        for (path, val) in &leaves {
            let mut one = start.clone();
            set(&mut one, path, val.clone());
            if let Err(e1) = serde_json::from_value::<T>(one) {
                return bad(format!("{source}: {path}: {e1}"));
            }
        }
        bad(format!("{source}: {e}"))
    })
}

fn merge(base: &mut Value, over: &Map<String, Value>, source: &str, prefix: &str) -> Result<()> {
    let known = known_keys(base);
    let b = base.as_object_mut().expect("parameters are a JSON object");
    for (k, v) in over {
        match b.get_mut(k) {
            None => {
                return Err(bad(format!(
                    "{source}: unknown parameter \"{prefix}{k}\"; known: {known:?}"
                )))
            }
            // null switches an optional parameter set off (a non-optional one fails to parse).
            Some(slot) if slot.is_object() && !v.is_null() => {
                let o = v.as_object().ok_or_else(|| {
                    bad(format!(
                        "{source}: {prefix}{k}: expected a JSON object, got {v}"
                    ))
                })?;
                merge(slot, o, source, &format!("{prefix}{k}."))?;
            }
            Some(slot) => *slot = v.clone(),
        }
    }
    Ok(())
}

fn flatten(o: &Map<String, Value>, prefix: &str, out: &mut Vec<(String, Value)>) {
    for (k, v) in o {
        match v {
            Value::Object(inner) => flatten(inner, &format!("{prefix}{k}."), out),
            _ => out.push((format!("{prefix}{k}"), v.clone())),
        }
    }
}

fn set(v: &mut Value, path: &str, val: Value) {
    let mut cur = v;
    let parts: Vec<&str> = path.split('.').collect();
    for p in &parts[..parts.len() - 1] {
        cur = cur.get_mut(*p).expect("merged path exists");
    }
    cur[parts[parts.len() - 1]] = val;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;
    use serde::Deserialize;
    use serde_json::json;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Inner {
        b: f32,
    }
    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Outer {
        a: usize,
        o: Option<f32>,
        inner: Inner,
    }
    const BASE: Outer = Outer {
        a: 1,
        o: None,
        inner: Inner { b: 0.5 },
    };

    #[test]
    fn keys_replace_nested_key_by_key() {
        let got = overlay_json(&BASE, &json!({"o": 2.0, "inner": {"b": 3}}), "t").unwrap();
        assert_eq!(
            got,
            Outer {
                a: 1,
                o: Some(2.0),
                inner: Inner { b: 3.0 }
            }
        );
        assert_eq!(overlay_json(&BASE, &json!({}), "t").unwrap(), BASE);
    }

    #[test]
    fn errors_name_the_key_and_the_source() {
        expect_err(
            overlay_json(&BASE, &json!({"zz": 1}), "flags"),
            &["flags", "\"zz\"", "\"inner\""],
        );
        expect_err(
            overlay_json(&BASE, &json!({"inner": {"c": 1}}), "file x"),
            &["file x", "\"inner.c\""],
        );
        expect_err(
            overlay_json(&BASE, &json!({"o": 1.0, "a": -2}), "kw"),
            &["kw: a:", "-2"],
        );
        expect_err(
            overlay_json(&BASE, &json!({"inner": 3}), "kw"),
            &["kw: inner: expected a JSON object"],
        );
        expect_err(
            overlay_json(&BASE, &json!([1]), "kw"),
            &["kw: expected a JSON object"],
        );
    }
}
