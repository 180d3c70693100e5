//! Hyper-parameters of a forest, validated in one place and written into every model file.

use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;

use super::checks::in_range;
use super::overlay::overlay_json;
use super::Valid;
use crate::error::{IsaError, Result};

/// Which criterion terms of the paper (Eq. 9-11) the split quality sums.
///
/// Q1 (6D pose entropy) is always present; Q2 (link-angle entropy) needs `link_angles`, Q3
/// (node-offset entropy) needs `node_offsets`. These are the paper's four forests.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Quality {
    #[serde(rename = "Q1")]
    Q1,
    #[serde(rename = "Q1+Q2")]
    Q1Q2,
    #[serde(rename = "Q1+Q3")]
    Q1Q3,
    #[serde(rename = "Q1+Q2+Q3")]
    Q1Q2Q3,
}

/// Read with [`Quality::parse`], so "q1 + q2" is accepted wherever parameters are read.
impl<'de> Deserialize<'de> for Quality {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Quality::parse(&s).map_err(|e| serde::de::Error::custom(e.to_string()))
    }
}

impl Quality {
    /// Parses "Q1", "Q1+Q2", "Q1+Q3" or "Q1+Q2+Q3" (spaces and case ignored).
    pub fn parse(s: &str) -> Result<Self> {
        let t: String = s
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_uppercase();
        match t.as_str() {
            "Q1" => Ok(Quality::Q1),
            "Q1+Q2" => Ok(Quality::Q1Q2),
            "Q1+Q3" => Ok(Quality::Q1Q3),
            "Q1+Q2+Q3" => Ok(Quality::Q1Q2Q3),
            _ => Err(IsaError::InvalidParameter(format!(
                "quality must be one of \"Q1\", \"Q1+Q2\", \"Q1+Q3\", \"Q1+Q2+Q3\", got {s:?}"
            ))),
        }
    }
    pub fn as_str(&self) -> &'static str {
        match self {
            Quality::Q1 => "Q1",
            Quality::Q1Q2 => "Q1+Q2",
            Quality::Q1Q3 => "Q1+Q3",
            Quality::Q1Q2Q3 => "Q1+Q2+Q3",
        }
    }
    pub fn uses_q2(&self) -> bool {
        matches!(self, Quality::Q1Q2 | Quality::Q1Q2Q3)
    }
    pub fn uses_q3(&self) -> bool {
        matches!(self, Quality::Q1Q3 | Quality::Q1Q2Q3)
    }
}

/// Training configuration of a forest. Every field is stored in the model file.
///
/// Units: feature offsets in pixel·metres (divided by the depth in metres at the part centre),
/// vote bandwidths in metres and radians; `reg` in standardised target units (see
/// [`crate::criterion`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForestParams {
    /// Number of trees.
    pub n_trees: usize,
    /// Maximum depth (the root has depth 0).
    pub max_depth: usize,
    /// A node with fewer parts than this becomes a leaf.
    pub min_samples_split: usize,
    /// Each child of a split must receive at least this many parts (of the scored subset).
    pub min_samples_leaf: usize,
    /// A node whose best total gain is not above this becomes a leaf.
    pub min_gain: f64,
    /// Random feature candidates ψ = (u, v) per node.
    pub n_candidates: usize,
    /// Random thresholds τ per candidate (drawn from feature values of random parts of the node).
    pub n_thresholds: usize,
    /// Largest |u_i|, |v_i| of a feature offset, pixel·metres.
    pub max_offset: f32,
    /// Nodes with more parts score candidates on a random subsample of this many parts
    /// (the split is then applied to all of the node's parts).
    pub max_score_samples: usize,
    /// Criterion terms summed ("Q1", "Q1+Q2", "Q1+Q3", "Q1+Q2+Q3").
    pub quality: Quality,
    /// Ridge added to every standardised covariance before its log-determinant.
    pub reg: f64,
    /// Dimension the criterion keeps of the embedded link angles and of the node offsets
    /// (principal components over the training set); 0 keeps the full dimension.
    ///
    /// Default 4: on skeleton-structured synthetic targets (`benches/bench_train.py
    /// --reduction-effect`) k = 2-4 picked splits keeping 84-91% of the full-dimension
    /// Q1+Q2+Q3 gain and 87-100% of its Q1 gain, k = 8-12 only ~55%, at 1/25 of the cost of the
    /// full 36 + 33 dimensions (whose near-singular covariances make the full gain itself noisy).
    pub reduce_dims: usize,
    /// Fraction of the parts each tree trains on (drawn without replacement per tree).
    pub bag_fraction: f64,
    /// Maximum number of weighted vote modes stored per leaf.
    pub leaf_modes: usize,
    /// At most this many of a leaf's parts are clustered into modes (an even-stride subset).
    pub leaf_max_points: usize,
    /// Mode-clustering bandwidth of the SSC offset, metres.
    pub vote_bandwidth_offset: f32,
    /// Mode-clustering bandwidth of the rotation, radians.
    pub vote_bandwidth_rotation: f32,
    /// Seed of every random choice; with the same data it fixes the model bytes.
    pub seed: u64,
}

impl Default for ForestParams {
    fn default() -> Self {
        ForestParams {
            n_trees: 10,
            max_depth: 20,
            min_samples_split: 20,
            min_samples_leaf: 5,
            min_gain: 0.0,
            n_candidates: 100,
            n_thresholds: 16,
            max_offset: 150.0,
            max_score_samples: 16384,
            quality: Quality::Q1Q2Q3,
            reg: 1e-4,
            reduce_dims: 4,
            bag_fraction: 1.0,
            leaf_modes: 4,
            leaf_max_points: 64,
            vote_bandwidth_offset: 0.05,
            vote_bandwidth_rotation: 0.35,
            seed: 0,
        }
    }
}

impl ForestParams {
    /// The validated parameters, the only form [`Forest::fit`](crate::Forest::fit) takes.
    pub fn check(self) -> Result<Valid<Self>> {
        self.validate()?;
        Ok(Valid(self))
    }

    /// Replaces the fields named in `json` (an object); errors name the key and `source`.
    pub fn overlay(&mut self, json: &Value, source: &str) -> Result<()> {
        *self = overlay_json(self, json, source)?;
        Ok(())
    }

    /// Checks every field; the error names the parameter at fault.
    pub fn validate(&self) -> Result<()> {
        fn bad(msg: String) -> Result<()> {
            Err(IsaError::InvalidParameter(msg))
        }
        in_range("n_trees", self.n_trees, 1, 10_000)?;
        if self.max_depth > 64 {
            return bad(format!(
                "max_depth must be at most 64, got {}",
                self.max_depth
            ));
        }
        if self.min_samples_leaf == 0 {
            return bad("min_samples_leaf must be at least 1".into());
        }
        if self.min_samples_split < 2 * self.min_samples_leaf {
            return bad(format!(
                "min_samples_split ({}) must be at least 2 * min_samples_leaf ({})",
                self.min_samples_split, self.min_samples_leaf
            ));
        }
        if !self.min_gain.is_finite() {
            return bad(format!("min_gain must be finite, got {}", self.min_gain));
        }
        in_range("n_candidates", self.n_candidates, 1, 100_000)?;
        in_range("n_thresholds", self.n_thresholds, 1, 255)?;
        if !(self.max_offset.is_finite()
            && self.max_offset > 0.0
            && self.max_offset <= crate::features::MAX_FEATURE_OFFSET)
        {
            return bad(format!(
                "max_offset must be in (0, {}] pixel·metres, got {}",
                crate::features::MAX_FEATURE_OFFSET,
                self.max_offset
            ));
        }
        if self.max_score_samples < 2 * self.min_samples_leaf {
            return bad(format!(
                "max_score_samples ({}) must be at least 2 * min_samples_leaf ({})",
                self.max_score_samples, self.min_samples_leaf
            ));
        }
        if !(self.reg.is_finite() && self.reg > 0.0) {
            return bad(format!("reg must be finite and > 0, got {}", self.reg));
        }
        if self.reduce_dims > 4096 {
            return bad(format!(
                "reduce_dims must be at most 4096 (0 = full), got {}",
                self.reduce_dims
            ));
        }
        if !(self.bag_fraction.is_finite() && self.bag_fraction > 0.0 && self.bag_fraction <= 1.0) {
            return bad(format!(
                "bag_fraction must be in (0, 1], got {}",
                self.bag_fraction
            ));
        }
        in_range("leaf_modes", self.leaf_modes, 1, 64)?;
        in_range("leaf_max_points", self.leaf_max_points, 1, 100_000)?;
        if !(self.vote_bandwidth_offset.is_finite() && self.vote_bandwidth_offset > 0.0) {
            return bad(format!(
                "vote_bandwidth_offset must be > 0 metres, got {}",
                self.vote_bandwidth_offset
            ));
        }
        if !(self.vote_bandwidth_rotation.is_finite() && self.vote_bandwidth_rotation > 0.0) {
            return bad(format!(
                "vote_bandwidth_rotation must be > 0 radians, got {}",
                self.vote_bandwidth_rotation
            ));
        }
        Ok(())
    }

    /// JSON form (the one stored in model files).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("ForestParams serialises")
    }

    /// Parses and validates the JSON form.
    pub fn from_json(s: &str) -> Result<Valid<Self>> {
        let p: ForestParams = serde_json::from_str(s)
            .map_err(|e| IsaError::InvalidParameter(format!("forest parameters JSON: {e}")))?;
        p.check()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;

    #[test]
    fn defaults_validate_and_roundtrip() {
        let p = ForestParams::default();
        p.validate().unwrap();
        assert_eq!(*ForestParams::from_json(&p.to_json()).unwrap(), p);
    }

    #[test]
    fn quality_parse() {
        assert_eq!(Quality::parse("q1 + q2").unwrap(), Quality::Q1Q2);
        assert!(Quality::parse("Q2").is_err());
        for q in [Quality::Q1, Quality::Q1Q2, Quality::Q1Q3, Quality::Q1Q2Q3] {
            assert_eq!(Quality::parse(q.as_str()).unwrap(), q);
        }
    }

    #[test]
    fn overlay_parses_quality_and_names_bad_keys() {
        let mut p = ForestParams::default();
        p.overlay(
            &serde_json::json!({"quality": "q1 + q3", "n_trees": 3}),
            "kw",
        )
        .unwrap();
        assert_eq!((p.quality, p.n_trees), (Quality::Q1Q3, 3));
        expect_err(
            p.overlay(&serde_json::json!({"quality": "Q2"}), "flags"),
            &["flags: quality:", "Q1+Q2+Q3"],
        );
        expect_err(
            p.overlay(&serde_json::json!({"n_tree": 3}), "kw"),
            &["\"n_tree\"", "\"n_trees\""],
        );
        assert!(p.check().is_ok());
    }

    #[test]
    fn bad_params_named() {
        let no_thresholds = ForestParams {
            n_thresholds: 0,
            ..Default::default()
        };
        assert!(no_thresholds.clone().check().is_err());
        expect_err(no_thresholds.validate(), &["n_thresholds"]);
    }
}
