//! Parameters of scene detection ([`crate::scene`]): plane finding ([`PlaneParams`]),
//! verification ([`VerifyParams`]), refinement ([`RefineParams`]) and the whole pipeline
//! ([`DetectParams`], which holds the other three). Python's `isa.detection` dataclasses take
//! their defaults from these (`isa._core.DETECT_DEFAULTS`).

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::checks::{at_least_one, bad, checked, named, non_negative, positive};
use super::overlay::overlay_json;
use super::Valid;
use crate::error::Result;

/// The Kinect depth tolerance `(base, k)`: `max(base, k z^2)` metres (as
/// `isa.render.noise.DEPTH_TOLERANCE`; k = 3 sigma of Khoshelham & Elberink's 1.5e-3 z^2).
pub const DEPTH_TOLERANCE: [f64; 2] = [0.03, 0.0045];

fn tolerance(name: &str, t: [f64; 2]) -> Result<()> {
    positive(&format!("{name}[0]"), t[0])?;
    non_negative(&format!("{name}[1]"), t[1])
}

/// Floor and wall finding (see `isa.detection.planes.PlaneParams`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlaneParams {
    /// A point is on a plane within `max(base, k depth^2)` metres.
    pub tolerance: [f64; 2],
    /// The floor holds at least this fraction of the sampled points. Default 0.03.
    pub min_floor_fraction: f64,
    /// The floor lies at least this far below the camera (metres). Default 0.3.
    pub min_floor_drop: f64,
    /// Heights searched above the lowest points (metres, 1 cm steps). Default 0.3.
    pub floor_search: f64,
    /// A wall holds at least this fraction of the points. Default 0.05.
    pub min_wall_fraction: f64,
    /// A wall's points span this height (metres). Default 1.0.
    pub min_wall_height: f64,
    /// A wall's points span this width along it (metres). Default 1.0.
    pub min_wall_width: f64,
    /// Walls found at most. Default 3.
    pub max_walls: usize,
    /// Distinct wall hypotheses checked in turn. Default 8.
    pub wall_candidates: usize,
    /// Wall hypotheses scored. Default 200.
    pub ransac_iterations: usize,
    /// Points the hypotheses are scored on. Default 5000.
    pub samples: usize,
    /// Points candidates are screened on before the test on every point. Default 40000.
    pub check_samples: usize,
    /// Random seed. Default 0.
    pub seed: u64,
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            tolerance: DEPTH_TOLERANCE,
            min_floor_fraction: 0.03,
            min_floor_drop: 0.3,
            floor_search: 0.3,
            min_wall_fraction: 0.05,
            min_wall_height: 1.0,
            min_wall_width: 1.0,
            max_walls: 3,
            wall_candidates: 8,
            ransac_iterations: 200,
            samples: 5000,
            check_samples: 40000,
            seed: 0,
        }
    }
}

impl PlaneParams {
    pub fn validate(&self) -> Result<()> {
        checked!(self, "planes."; tolerance(tolerance));
        let fractions_and_lengths = named!(self, "planes.";
            min_floor_fraction, min_floor_drop, floor_search,
            min_wall_fraction, min_wall_height, min_wall_width);
        for (n, x) in fractions_and_lengths {
            non_negative(n, x)?;
        }
        at_least_one(&named!(self, "planes."; ransac_iterations, samples, check_samples))
    }
}

/// Verification (see `isa.detection.verify.VerifyParams`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerifyParams {
    /// A cell agrees within `max(base, k z^2)` metres.
    pub tolerance: [f64; 2],
    /// What one seen-through cell costs against one agreeing. Default 1.
    pub violation_weight: f64,
    /// What one unexplained cell costs: observed surface inside the shape's box (shrunk by
    /// `lateral`) but in front of the shape's surface or where the shape has none (a bed's solid
    /// side under a table hypothesis' top). 0: not counted. Default 0.
    pub unexplained_weight: f64,
    /// Grid cell side in units of the shape's point spacing. Default 2.
    pub cell_spacing: f64,
    /// Smallest cell (pixels). Default 2.
    pub min_cell_px: usize,
    /// Visible cells below which a hypothesis scores 0. Default 20.
    pub min_cells: usize,
    /// How far sideways (metres) the observed surface may be and still agree. Default 0.03.
    pub lateral: f64,
    /// The detector widens `lateral` to this fraction of the shape's diagonal. Default 0.03.
    pub lateral_fraction: f64,
}

impl Default for VerifyParams {
    fn default() -> Self {
        Self {
            tolerance: DEPTH_TOLERANCE,
            violation_weight: 1.0,
            unexplained_weight: 0.0,
            cell_spacing: 2.0,
            min_cell_px: 2,
            min_cells: 20,
            lateral: 0.03,
            lateral_fraction: 0.03,
        }
    }
}

impl VerifyParams {
    pub fn validate(&self) -> Result<()> {
        checked!(self, "verify."; tolerance(tolerance), non_negative(violation_weight),
            non_negative(unexplained_weight), positive(cell_spacing), non_negative(lateral),
            non_negative(lateral_fraction));
        at_least_one(&named!(self, "verify."; min_cell_px))
    }
}

/// Refinement (see `isa.detection.refine.RefineParams`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineParams {
    /// ICP iterations. Default 5.
    pub iterations: usize,
    /// The trimming distance falls from this (metres)... Default 0.15.
    pub max_distance: f64,
    /// ... to this, geometrically. Default 0.03.
    pub min_distance: f64,
    /// Margin (metres) around the shape's box observed points are gathered from. Default 0.15.
    pub margin: f64,
    /// A larger total yaw change (degrees) keeps the start. Default 30.
    pub max_yaw_deg: f64,
    /// A larger total shift (metres) keeps the start. Default 0.3.
    pub max_shift: f64,
    /// Fewer pairs leave the pose as it is. Default 30.
    pub min_pairs: usize,
    /// Observed points used at most (evenly subsampled). Default 800.
    pub max_points: usize,
    /// Z-buffer cell (pixels) of the shape's visible surface. Default 2.
    pub cell_px: usize,
    /// Keep the height (the object stands on the found floor). Default false.
    pub fix_height: bool,
}

impl Default for RefineParams {
    fn default() -> Self {
        Self {
            iterations: 5,
            max_distance: 0.15,
            min_distance: 0.03,
            margin: 0.15,
            max_yaw_deg: 30.0,
            max_shift: 0.3,
            min_pairs: 30,
            max_points: 800,
            cell_px: 2,
            fix_height: false,
        }
    }
}

impl RefineParams {
    pub fn validate(&self) -> Result<()> {
        checked!(self, "refine."; positive(max_distance), positive(min_distance),
            non_negative(margin), non_negative(max_yaw_deg), non_negative(max_shift));
        if self.iterations == 0 || self.cell_px == 0 || self.max_points == 0 {
            return bad(
                "refine.iterations, cell_px and max_points",
                "must be >= 1".into(),
            );
        }
        Ok(())
    }
}

/// Hypotheses from footprints on the floor ([`crate::scene::proposals`]; see
/// `isa.detection.proposals.ProposalParams`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProposalParams {
    /// Pixel stride of the points binned. Default 2.
    pub stride: usize,
    /// Grid cell side over the floor (metres). Default 0.05.
    pub cell: f64,
    /// Points less high above the floor are left out (metres). Default 0.05.
    pub clearance: f64,
    /// ... and higher ones (metres). Default 2.0.
    pub max_height: f64,
    /// A cell with fewer points is empty. Default 2.
    pub min_cell_points: usize,
    /// A footprint with fewer points proposes nothing. Default 150.
    pub min_points: usize,
    /// Footprints used at most, largest first. Default 12.
    pub max_footprints: usize,
    /// A forest hypothesis this close to a footprint (metres) lends it its score. Default 0.2.
    pub vote_margin: f64,
    /// A footprint no hypothesis of the category lends a score to carries this fraction of the
    /// weakest hypothesis' score; 0: it proposes nothing for the category. Default 0.5.
    pub unvoted: f64,
    /// A footprint wider or higher (or lower) than the category's real-world sizes by more than
    /// this (metres, beyond the size fit's margin) proposes nothing for it; None: no check.
    /// Default 0.1.
    pub size_slack: Option<f64>,
}

impl Default for ProposalParams {
    fn default() -> Self {
        Self {
            stride: 2,
            cell: 0.05,
            clearance: 0.05,
            max_height: 2.0,
            min_cell_points: 2,
            min_points: 150,
            max_footprints: 12,
            vote_margin: 0.2,
            unvoted: 0.5,
            size_slack: Some(0.1),
        }
    }
}

impl ProposalParams {
    pub fn validate(&self) -> Result<()> {
        checked!(self, "proposals."; positive(cell), non_negative(clearance),
            positive(max_height), non_negative(vote_margin), non_negative(unvoted));
        if let Some(s) = self.size_slack {
            non_negative("proposals.size_slack", s)?;
        }
        at_least_one(&named!(self, "proposals."; stride, max_footprints))
    }
}

/// When non-maximum suppression runs against ranking.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NmsOrder {
    /// One NMS over every category's boxes on their verified scores, then the kept ones ranked.
    Joint,
    /// NMS within each category on the verified scores, those ranked, then NMS across
    /// categories on the ranked scores: a ranker's probability decides between categories.
    Ranked,
    /// NMS within each category, then ranking; no NMS across categories (what the rankers
    /// of `ranked` are fitted on).
    PerCategory,
}

impl NmsOrder {
    pub fn name(&self) -> &'static str {
        match self {
            NmsOrder::Joint => "joint",
            NmsOrder::Ranked => "ranked",
            NmsOrder::PerCategory => "per_category",
        }
    }
}

/// The whole detection pipeline (see `isa.detection.multi.DetectParams`).
// A flat list of typed fields (its JSON form, which the CLI and Python overlay, is this list);
// `duplicates` pairs runs of it with itself and with other structs by shape alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectParams {
    /// Part stride of each forest's voting. Default 4.
    pub stride: usize,
    /// Hypotheses per forest. Default 20.
    pub max_hypotheses: usize,
    /// Hypotheses tilted further from up (degrees) are rejected; None: none. Default 30.
    pub max_tilt_deg: Option<f64>,
    /// Floor and walls set to missing for the voting. Default true.
    pub remove_planes: bool,
    /// Hypotheses whose bottom is further (metres) from the floor are rejected. Default 0.3.
    pub floor_gap: Option<f64>,
    /// Plane finding.
    pub planes: PlaneParams,
    /// Verification; None: the forests' scores and boxes are used.
    pub verify: Option<VerifyParams>,
    /// Refinement; None: off.
    pub refine: Option<RefineParams>,
    /// Hypotheses from footprints on the floor beside the forests' (needs a floor); None: off.
    pub proposals: Option<ProposalParams>,
    /// Hypotheses refined per category. Default 5.
    pub refine_top: usize,
    /// > 1: each hypothesis also verified turned by multiples of 360 / turns degrees. Default 1.
    pub turns: usize,
    /// Hypotheses per category whose size is fitted. Default 8.
    pub size_top: usize,
    /// Best shapes tried in the size fit. Default 3.
    pub size_shapes: usize,
    /// Scale factors tried per axis. Default [0.85, 1.15].
    pub size_steps: Vec<f64>,
    /// Shapes screened and sized on their first that many samples; None: all. Default 1000.
    pub quick_points: Option<usize>,
    /// Weight of log(forest score) added to a verified score. Default 0.05.
    pub forest_weight: f64,
    /// NMS (across categories, or within each with `nms_order` other than joint): IoU above
    /// which a box goes. Default 0.25.
    pub nms_iou: f64,
    /// ... or the share of a smaller box inside a better one. Default 0.6.
    pub nms_overlap: f64,
    /// Detections per frame at most. Default 20.
    pub max_detections: usize,
    /// Every candidate ranked (features and, with a ranker, its probability) before NMS, so
    /// that the probability decides overlaps; else only the detections NMS keeps. Default
    /// false.
    pub rank_before_nms: bool,
    /// When NMS runs against ranking (without `rank_before_nms`, which needs joint; without
    /// verification there is no ranking and the NMS is joint). Default ranked: with rankers it
    /// wins on validation rooms (`docs/experiments.md`, "Rivals"); without, joint is a little
    /// better.
    pub nms_order: NmsOrder,
    /// `ranked`'s NMS across categories: IoU above which a box goes (a chair tucked under a
    /// table overlaps it by about 0.25). Default 0.5.
    pub cross_iou: f64,
    /// ... or the share of a smaller box inside a likelier one; 1: never. Default 1.
    pub cross_overlap: f64,
    /// Detections whose verified score (before ranking) is weaker are dropped; None: none.
    /// Default None.
    pub min_score: Option<f64>,
    /// Further inference parameters for every forest's voting (flat keys, as `predict`'s).
    pub predict: serde_json::Map<String, Value>,
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            stride: 4,
            max_hypotheses: 20,
            max_tilt_deg: Some(30.0),
            remove_planes: true,
            floor_gap: Some(0.3),
            planes: PlaneParams::default(),
            verify: Some(VerifyParams::default()),
            refine: Some(RefineParams::default()),
            proposals: Some(ProposalParams::default()),
            refine_top: 5,
            turns: 1,
            size_top: 8,
            size_shapes: 3,
            size_steps: vec![0.85, 1.15],
            quick_points: Some(1000),
            forest_weight: 0.05,
            nms_iou: 0.25,
            nms_overlap: 0.6,
            max_detections: 20,
            rank_before_nms: false,
            nms_order: NmsOrder::Ranked,
            cross_iou: 0.5,
            cross_overlap: 1.0,
            min_score: None,
            predict: Default::default(),
        }
    }
}

impl DetectParams {
    /// Checks every field and the nested parameter sets; the error names the parameter.
    pub fn validate(&self) -> Result<()> {
        if self.stride == 0
            || self.max_hypotheses == 0
            || self.turns == 0
            || self.max_detections == 0
        {
            return bad(
                "stride, max_hypotheses, turns and max_detections",
                "must be >= 1".into(),
            );
        }
        if let Some(t) = self.max_tilt_deg {
            non_negative("max_tilt_deg", t)?;
        }
        if let Some(g) = self.floor_gap {
            non_negative("floor_gap", g)?;
        }
        if self.quick_points == Some(0) {
            return bad("quick_points", "must be >= 1 or None, got 0".into());
        }
        if let Some(s) = self
            .size_steps
            .iter()
            .find(|s| !(s.is_finite() && **s > 0.0))
        {
            return bad("size_steps", format!("must be finite and > 0, got {s}"));
        }
        non_negative("forest_weight", self.forest_weight)?;
        for (n, x) in [
            ("nms_iou", self.nms_iou),
            ("nms_overlap", self.nms_overlap),
            ("cross_iou", self.cross_iou),
            ("cross_overlap", self.cross_overlap),
        ] {
            if !(0.0..=1.0).contains(&x) {
                return bad(n, format!("must be in [0, 1], got {x}"));
            }
        }
        if self.rank_before_nms && self.nms_order != NmsOrder::Joint {
            return bad(
                "nms_order",
                format!(
                    "must be \"joint\" with rank_before_nms, got {:?}",
                    self.nms_order.name()
                ),
            );
        }
        if let Some(m) = self.min_score {
            if m.is_nan() {
                return bad("min_score", "must not be NaN".into());
            }
        }
        self.planes.validate()?;
        if let Some(v) = &self.verify {
            v.validate()?;
        }
        if let Some(r) = &self.refine {
            r.validate()?;
        }
        if let Some(r) = &self.proposals {
            r.validate()?;
        }
        Ok(())
    }

    /// The validated parameters.
    pub fn check(self) -> Result<Valid<Self>> {
        self.validate()?;
        Ok(Valid(self))
    }

    /// Replaces the fields named in `json` (nested objects key by key); errors name the key
    /// and `source`.
    /// `predict` is merged key by key as given (checked against the forests' inference
    /// parameters when they vote).
    pub fn overlay(&mut self, json: &Value, source: &str) -> Result<()> {
        let mut json = json.clone();
        let predict = json.as_object_mut().and_then(|o| o.remove("predict"));
        *self = overlay_json(self, &json, source)?;
        match predict {
            None | Some(Value::Null) => {}
            Some(Value::Object(o)) => self.predict.extend(o),
            Some(other) => {
                return bad(
                    &format!("{source}: predict"),
                    format!("must be an object, got {other}"),
                )
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;
    use serde_json::json;

    #[test]
    fn overlay_nested_and_check_names_the_parameter() {
        let mut p = DetectParams::default();
        p.overlay(&json!({"stride": 8, "verify": {"lateral": 0.05}, "refine": null, "predict": {"min_support": 2}}), "kw")
            .unwrap();
        assert_eq!(p.predict["min_support"], 2);
        assert_eq!(p.stride, 8);
        assert_eq!(p.verify.as_ref().unwrap().lateral, 0.05);
        assert_eq!(
            p.verify.as_ref().unwrap().min_cells,
            VerifyParams::default().min_cells
        );
        assert!(p.refine.is_none());
        expect_err(p.clone().overlay(&json!({"verfy": {}}), "kw"), &["verfy"]);
        p.nms_iou = 1.5;
        expect_err(p.check(), &["nms_iou"]);
        let mut q = DetectParams::default();
        q.overlay(&json!({"planes": {"tolerance": [0.0, 1.0]}}), "kw")
            .unwrap();
        expect_err(q.check(), &["planes.tolerance[0]"]);
    }
}
