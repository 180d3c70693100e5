//! What a model file says about its forest besides the trees and the parameters: one typed
//! record ([`ModelMetadata`]) that every trainer writes (Python's `Forest.fit`, the pipeline,
//! `isa train`): the category, the object-frame origin, the category box, a training summary
//! (filled by [`Forest::fit`](crate::Forest::fit)), and free-form extra JSON (the SSC, the
//! skeleton template, versions, ...).
//!
//! Trainers hand metadata over as JSON; the inference defaults they used to put inside it as
//! `predict_defaults` (flat keys) are split off by [`split_metadata`] into the model's typed
//! inference defaults.

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::error::{IsaError, Result};
use crate::params::{PredictParams, Valid};

/// The metadata of a model. JSON keys: `category`, `centre`, `box`, `training`, then the extra
/// keys side by side (so older readers of the JSON see the keys they wrote).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModelMetadata {
    /// Object category ("chair", ...).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub category: Option<String>,
    /// The object frame's origin: "ssc", "com" or "box" (Python's `isa.ssc.CENTRES`).
    #[serde(default, rename = "centre", skip_serializing_if = "Option::is_none")]
    pub origin: Option<String>,
    /// The category's upright box, for detection in scenes.
    #[serde(default, rename = "box", skip_serializing_if = "Option::is_none")]
    pub category_box: Option<CategoryBox>,
    /// What the forest was trained on (written by training).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<TrainingSummary>,
    /// Everything else, free-form.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// A category's gravity-aligned box: median size of its training instances (metres, x y z in
/// the object frame) and the origin minus the box centre.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CategoryBox {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub category: Option<String>,
    pub size: [f64; 3],
    pub ssc_offset: [f64; 3],
    #[serde(default)]
    pub n_instances: u64,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// What a forest was trained on: the data's counts (filled by
/// [`Forest::fit`](crate::Forest::fit)) beside the trainer's own description (instances, views,
/// stride, seed, ...: free-form keys, kept as written).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainingSummary {
    #[serde(default)]
    pub n_parts: usize,
    #[serde(default)]
    pub n_images: usize,
    /// Columns of the link angles (0 without Q2 data).
    #[serde(default)]
    pub link_angle_dims: usize,
    /// Columns of the node offsets (0 without Q3 data).
    #[serde(default)]
    pub node_offset_dims: usize,
    /// The trainer's description.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Key of the legacy inference defaults inside metadata JSON.
pub const PREDICT_DEFAULTS_KEY: &str = "predict_defaults";

impl ModelMetadata {
    /// Parses metadata JSON (an object; "" = empty); `source` names it in errors.
    pub fn from_json(json: &str, source: &str) -> Result<Self> {
        Self::from_value(parse_object(json, source)?, source)
    }

    fn from_value(v: Map<String, Value>, source: &str) -> Result<Self> {
        serde_json::from_value(Value::Object(v))
            .map_err(|e| IsaError::InvalidParameter(format!("{source}: {e}")))
    }

    /// The JSON form (one object).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("metadata serialises")
    }
}

fn parse_object(json: &str, source: &str) -> Result<Map<String, Value>> {
    if json.trim().is_empty() {
        return Ok(Map::new());
    }
    match serde_json::from_str::<Value>(json) {
        Ok(Value::Object(o)) => Ok(o),
        Ok(other) => Err(IsaError::InvalidParameter(format!(
            "{source}: expected a JSON object, got {other}"
        ))),
        Err(e) => Err(IsaError::InvalidParameter(format!(
            "{source}: not valid JSON: {e}"
        ))),
    }
}

/// Metadata JSON as trainers hand it over, split into the typed record and the inference
/// defaults (`predict_defaults` inside it overlaid on [`PredictParams::default`]). With
/// `skip_unknown`, inference keys this version does not know are skipped (files written by
/// another version); otherwise they are errors.
pub fn split_metadata(
    json: &str,
    source: &str,
    skip_unknown: bool,
) -> Result<(ModelMetadata, Valid<PredictParams>)> {
    let mut o = parse_object(json, source)?;
    let mut defaults = PredictParams::default();
    if let Some(d) = o.remove(PREDICT_DEFAULTS_KEY) {
        let src = format!("{source}: {PREDICT_DEFAULTS_KEY}");
        if skip_unknown {
            defaults.overlay_known(&d, &src)?;
        } else {
            defaults.overlay(&d, &src)?;
        }
    }
    let defaults = defaults.check().map_err(|e| {
        IsaError::InvalidParameter(format!("{source}: {PREDICT_DEFAULTS_KEY}: {e}"))
    })?;
    Ok((ModelMetadata::from_value(o, source)?, defaults))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;
    use serde_json::json;

    #[test]
    fn typed_fields_and_extra_roundtrip() {
        let src = json!({"category": "chair", "centre": "ssc", "ssc": {"x": 1.5},
                         "box": {"category": "chair", "size": [0.5, 0.6, 0.9], "ssc_offset": [0.0, 0.1, -0.2],
                                 "n_instances": 28}, "isa_version": "0.1.0"});
        let m = ModelMetadata::from_json(&src.to_string(), "t").unwrap();
        assert_eq!(m.category.as_deref(), Some("chair"));
        assert_eq!(m.origin.as_deref(), Some("ssc"));
        let b = m.category_box.as_ref().unwrap();
        assert_eq!((b.size, b.n_instances), ([0.5, 0.6, 0.9], 28));
        assert_eq!(m.extra["ssc"], json!({"x": 1.5}));
        let back: Value = serde_json::from_str(&m.to_json()).unwrap();
        assert_eq!(back, src);
        assert_eq!(
            ModelMetadata::from_json("", "t").unwrap(),
            ModelMetadata::default()
        );
    }

    #[test]
    fn predict_defaults_split_off() {
        let (m, d) = split_metadata(
            r#"{"category": "bed", "predict_defaults": {"stride": 3, "position_bandwidth": 0.2}}"#,
            "metadata",
            false,
        )
        .unwrap();
        assert_eq!(m.category.as_deref(), Some("bed"));
        assert!(!m.extra.contains_key(PREDICT_DEFAULTS_KEY));
        assert_eq!((d.stride, d.vote.position_bandwidth), (3, 0.2));
        expect_err(
            split_metadata(r#"{"predict_defaults": {"strde": 3}}"#, "metadata", false),
            &["metadata: predict_defaults", "\"strde\""],
        );
        let (_, d) = split_metadata(
            r#"{"predict_defaults": {"strde": 3, "stride": 2}}"#,
            "m",
            true,
        )
        .unwrap();
        assert_eq!(d.stride, 2);
        expect_err(
            split_metadata(r#"{"predict_defaults": {"stride": 0}}"#, "m", true),
            &["predict_defaults", "stride"],
        );
        expect_err(
            split_metadata(r#"{"category": 3}"#, "metadata", false),
            &["metadata", "invalid type"],
        );
        assert!(split_metadata("[1]", "metadata", false).is_err());
    }
}
