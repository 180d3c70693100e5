//! Inference parameters: mode finding ([`VoteParams`]) and whole-image prediction
//! ([`PredictParams`], which holds a `VoteParams`). A model file stores a `PredictParams` as its
//! inference defaults (see [`crate::model_io`]).
//!
//! Flat keys: Python keyword arguments and the legacy `predict_defaults` metadata name the vote
//! fields at the top level (`stride=2, position_bandwidth=0.1`); [`PredictParams::overlay`]
//! accepts those and the nested form (`{"stride": 2, "vote": {"position_bandwidth": 0.1}}`).

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::checks::{at_least_one, bad, named};
use super::overlay::{known_keys, overlay_json};
use super::Valid;
use crate::error::{IsaError, Result};

/// Parameters of [`find_modes`](crate::vote::find_modes). Defaults suit furniture-sized objects (0.5-2 m) at 1-5 m.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoteParams {
    /// Radius of the position kernel and side of the grid cells (metres). Default 0.08.
    pub position_bandwidth: f32,
    /// Geodesic radius of the rotation kernel (radians, in (0, π]). Default 0.5 (~29°).
    pub rotation_bandwidth: f32,
    /// How many hypotheses to return at most. Default 5.
    pub max_hypotheses: usize,
    /// Position modes closer than this (metres) to a stronger one are suppressed; at least
    /// `position_bandwidth / 4` is used. Default 0.25.
    pub nms_radius: f32,
    /// How many of the heaviest grid cells seed the position mean-shift. Default 64.
    pub max_seeds: usize,
    /// Iteration cap of each mean-shift loop. Default 50.
    pub max_iterations: usize,
    /// Rotation modes per position mode (more than 1 for symmetric objects). Default 1.
    pub rotations_per_position: usize,
    /// Candidate starts for the rotation mode (a strided subsample of the support). Default 64.
    pub rotation_candidates: usize,
    /// Votes the candidates' densities are evaluated on (strided subsample). Default 1024.
    pub rotation_eval_votes: usize,
    /// Hypotheses supported by fewer votes (in both kernels) are dropped. Default 3.
    pub min_support: usize,
    /// The coarse grid is built from at most this many votes (an even-stride subsample).
    /// Default 32768.
    pub coarse_votes: usize,
    /// How many of the densest distinct coarse modes are refined on the raw votes. Default 16.
    pub refine_modes: usize,
    /// Mean-shift iterations (position and rotation) run on at most this many of a mode's votes
    /// (an even-stride subsample); densities and supports always use all of them. Default 4096.
    pub refine_votes: usize,
}

impl Default for VoteParams {
    fn default() -> Self {
        Self {
            position_bandwidth: 0.08,
            rotation_bandwidth: 0.5,
            max_hypotheses: 5,
            nms_radius: 0.25,
            max_seeds: 64,
            max_iterations: 50,
            rotations_per_position: 1,
            rotation_candidates: 64,
            rotation_eval_votes: 1024,
            min_support: 3,
            coarse_votes: 32768,
            refine_modes: 16,
            refine_votes: 4096,
        }
    }
}

impl VoteParams {
    /// Checks every field; the error names the parameter at fault.
    pub fn validate(&self) -> Result<()> {
        let h = self.position_bandwidth;
        if !(h.is_finite() && h > 1e-4 && h < 1e3) {
            return bad(
                "position_bandwidth",
                format!("must be in (1e-4, 1e3) metres, got {h}"),
            );
        }
        let r = self.rotation_bandwidth;
        if !(r.is_finite() && r > 1e-4 && r <= std::f32::consts::PI) {
            return bad(
                "rotation_bandwidth",
                format!("must be in (1e-4, pi] radians, got {r}"),
            );
        }
        if !(self.nms_radius.is_finite() && self.nms_radius >= 0.0) {
            return bad(
                "nms_radius",
                format!("must be finite and >= 0, got {}", self.nms_radius),
            );
        }
        at_least_one(&named!(self, "";
            max_hypotheses, max_seeds, max_iterations,
            rotations_per_position, rotation_candidates, rotation_eval_votes,
            coarse_votes, refine_modes, refine_votes))
    }
}

/// Parameters of [`predict`](crate::vote::predict) and [`image_votes`](crate::vote::image_votes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictParams {
    /// Parts on every `stride`-th pixel in u and v (with depth > 0). Default 4: about 19k parts
    /// on a fully valid 640x480 frame; use 2 for small objects.
    pub stride: usize,
    /// Pixels nearer than this (metres) are not parts. Default 0.
    pub min_depth: f32,
    /// Pixels farther than this (metres) are not parts; `None` = no limit. Default `None`.
    pub max_depth: Option<f32>,
    /// Leaf votes of smaller weight (the leaf's share, before dividing by the number of trees)
    /// are dropped. Default 0 (keep all).
    pub min_leaf_weight: f32,
    /// Mode finding.
    pub vote: VoteParams,
}

impl Default for PredictParams {
    fn default() -> Self {
        Self {
            stride: 4,
            min_depth: 0.0,
            max_depth: None,
            min_leaf_weight: 0.0,
            vote: VoteParams::default(),
        }
    }
}

impl PredictParams {
    /// Checks every field (and the vote parameters); the error names the parameter.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(IsaError::InvalidParameter(m));
        if self.stride == 0 || self.stride > 1024 {
            return bad(format!(
                "stride must be in 1..=1024 pixels, got {}",
                self.stride
            ));
        }
        if !(self.min_depth.is_finite() && self.min_depth >= 0.0) {
            return bad(format!(
                "min_depth must be finite and >= 0 metres, got {}",
                self.min_depth
            ));
        }
        if let Some(m) = self.max_depth {
            if !(m.is_finite() && m > self.min_depth) {
                return bad(format!(
                    "max_depth must be finite and > min_depth ({}), got {m}",
                    self.min_depth
                ));
            }
        }
        if !(self.min_leaf_weight.is_finite() && (0.0..=1.0).contains(&self.min_leaf_weight)) {
            return bad(format!(
                "min_leaf_weight must be in [0, 1], got {}",
                self.min_leaf_weight
            ));
        }
        self.vote.validate()
    }
}

impl VoteParams {
    /// The validated parameters (see [`VoteParams::validate`]).
    pub fn check(self) -> Result<Valid<Self>> {
        self.validate()?;
        Ok(Valid(self))
    }

    /// Replaces the fields named in `json` (an object); errors name the key and `source`.
    pub fn overlay(&mut self, json: &Value, source: &str) -> Result<()> {
        *self = overlay_json(self, json, source)?;
        Ok(())
    }
}

/// Fields of [`PredictParams`] outside `vote`.
const IMAGE_KEYS: [&str; 4] = ["stride", "min_depth", "max_depth", "min_leaf_weight"];

impl PredictParams {
    /// The validated parameters (see [`PredictParams::validate`]).
    pub fn check(self) -> Result<Valid<Self>> {
        self.validate()?;
        Ok(Valid(self))
    }

    /// Replaces the fields named in `json`: an object with flat keys (`stride`,
    /// `position_bandwidth`, ...) and/or the nested `vote` object. Errors name the key and
    /// `source`.
    pub fn overlay(&mut self, json: &Value, source: &str) -> Result<()> {
        let nested = nest(json, source, false)?.0;
        *self = overlay_json(self, &nested, source)?;
        Ok(())
    }

    /// [`PredictParams::overlay`] that skips keys this version does not know (for inference
    /// defaults written by another version of isa); returns the skipped keys.
    pub fn overlay_known(&mut self, json: &Value, source: &str) -> Result<Vec<String>> {
        let (nested, skipped) = nest(json, source, true)?;
        *self = overlay_json(self, &nested, source)?;
        Ok(skipped)
    }

    /// Flat JSON form: the image keys and the vote keys side by side (as Python's keyword
    /// arguments name them).
    pub fn to_flat_json(&self) -> Map<String, Value> {
        // Through text: f32 fields print as their shortest decimal (0.06, not 0.0599999986...).
        let v: Value = serde_json::from_str(&serde_json::to_string(self).expect("serialise"))
            .expect("parameters serialise to JSON");
        let mut out = Map::new();
        for (k, val) in v.as_object().expect("object") {
            match val {
                Value::Object(vote) if k == "vote" => out.extend(vote.clone()),
                _ => {
                    out.insert(k.clone(), val.clone());
                }
            }
        }
        out
    }
}

impl Valid<PredictParams> {
    /// These parameters with the keys of `json` overlaid ([`PredictParams::overlay`]), checked:
    /// how a model's inference defaults meet a caller's settings.
    pub fn with_overrides(&self, json: &Value, source: &str) -> Result<Valid<PredictParams>> {
        let mut p = self.0.clone();
        p.overlay(json, source)?;
        p.check()
    }
}

impl Default for Valid<PredictParams> {
    fn default() -> Self {
        PredictParams::default()
            .check()
            .expect("default inference parameters are valid")
    }
}

/// Flat or nested keys to the nested form of [`PredictParams`]; unknown keys are errors (or
/// skipped and listed, with `skip_unknown`).
fn nest(json: &Value, source: &str, skip_unknown: bool) -> Result<(Value, Vec<String>)> {
    let o = json.as_object().ok_or_else(|| {
        IsaError::InvalidParameter(format!(
            "{source}: expected a JSON object of parameters, got {json}"
        ))
    })?;
    let vote_keys = known_keys(&serde_json::to_value(VoteParams::default()).expect("serialise"));
    let (mut top, mut vote, mut skipped) = (Map::new(), Map::new(), Vec::new());
    for (k, v) in o {
        if k == "vote" {
            match v.as_object() {
                Some(inner) => vote.extend(inner.clone()),
                // Not an object: left for the overlay to report.
                None => {
                    top.insert(k.clone(), v.clone());
                }
            }
        } else if IMAGE_KEYS.contains(&k.as_str()) {
            top.insert(k.clone(), v.clone());
        } else if vote_keys.contains(k) {
            vote.insert(k.clone(), v.clone());
        } else if skip_unknown {
            skipped.push(k.clone());
        } else {
            let mut known: Vec<String> = IMAGE_KEYS.iter().map(|s| s.to_string()).collect();
            known.extend(vote_keys.iter().cloned());
            known.sort();
            return Err(IsaError::InvalidParameter(format!(
                "{source}: unknown parameter \"{k}\"; known: {known:?}"
            )));
        }
    }
    if skip_unknown {
        let before = vote.len();
        vote.retain(|k, _| vote_keys.contains(k));
        if vote.len() != before {
            skipped.push("vote.<unknown>".into());
        }
    }
    top.entry("vote").or_insert(Value::Object(vote));
    Ok((Value::Object(top), skipped))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;
    use serde_json::json;

    #[test]
    fn flat_and_nested_keys_overlay_alike() {
        let mut a = PredictParams::default();
        a.overlay(&json!({"stride": 2, "position_bandwidth": 0.1}), "kw")
            .unwrap();
        let mut b = PredictParams::default();
        b.overlay(
            &json!({"stride": 2, "vote": {"position_bandwidth": 0.1}}),
            "file",
        )
        .unwrap();
        assert_eq!(a, b);
        assert_eq!((a.stride, a.vote.position_bandwidth), (2, 0.1));
        assert_eq!(a.vote.max_hypotheses, VoteParams::default().max_hypotheses);
        let flat = a.to_flat_json();
        let mut c = PredictParams::default();
        c.overlay(&Value::Object(flat), "flat").unwrap();
        assert_eq!(c, a);
    }

    #[test]
    fn unknown_keys_are_named_or_skipped() {
        let mut p = PredictParams::default();
        expect_err(
            p.overlay(&json!({"strid": 2}), "flags"),
            &["flags", "\"strid\"", "\"stride\""],
        );
        let skipped = p
            .overlay_known(&json!({"stride": 3, "from_the_future": 1}), "model")
            .unwrap();
        assert_eq!(skipped, vec!["from_the_future".to_string()]);
        assert_eq!(p.stride, 3);
        expect_err(
            p.overlay(&json!({"max_hypotheses": 1.5}), "kw"),
            &["kw: vote.max_hypotheses:"],
        );
    }

    #[test]
    fn check_names_the_parameter() {
        let p = PredictParams {
            stride: 0,
            ..Default::default()
        };
        expect_err(p.check(), &["stride"]);
        let v = VoteParams {
            rotation_bandwidth: 4.0,
            ..Default::default()
        };
        expect_err(v.check(), &["rotation_bandwidth"]);
    }
}
