//! Ranking: a detection's score as the probability that it is a true object, from what the
//! earlier stages measured about it (the verification counts, the forest's word, the size fit,
//! the pose). A [`Ranker`] is a logistic model per category, fitted on validation rooms
//! (`isa.detection.ranking`) and stored as JSON beside the model (`<model>.ranker.json`): its
//! log-odds are linear in the standardised features, plus the sum of boosted regression trees
//! ([`RankTree`], format 2) where a ranker has them.
//!
//! Why: the verification score alone ranks a panel that agrees with any box face (a chair seen
//! from behind, a cabinet under a table hypothesis) above a half-hidden real object; the counts
//! it is made of, with the forest's score and the fitted size, tell them apart better. The
//! probability is also what makes scores of different categories and frames comparable.

use serde::{Deserialize, Serialize};

use super::nms::{intersection, UprightBox};
use super::profile::{Profile, LEVELS};
use super::verify::Verification;
use super::Detection;
use crate::error::{IsaError, Result};
use crate::params::NmsOrder;

/// The ranker file format this build writes. It reads format 1 too (linear only: no trees).
pub const RANKER_FORMAT: u32 = 2;

/// The features a ranker may use, in the order [`features`] returns them.
pub const FEATURES: [&str; 35] = [
    "verify_score",
    "agree",
    "violate",
    "occluded",
    "outside",
    "missing",
    "unexplained",
    "log_agree",
    "log_forest_score",
    "log_support",
    "rank",
    "tilt_deg",
    "refined",
    "depth",
    "scale_change",
    "height",
    "length",
    "rival_margin",
    "outer_rival_margin",
    "inner_rival_margin",
    "fill",
    "level_1",
    "level_2",
    "level_3",
    "level_4",
    "level_5",
    "back_1",
    "back_2",
    "back_3",
    "back_4",
    "back_5",
    "middle",
    "span_length",
    "span_width",
    "around",
];
// The names above spell out the profile's levels.
const _: () = assert!(LEVELS == 5);

/// [`features`]' `rival_margin` of a detection that no other category's box overlaps.
pub const NO_RIVAL: f64 = 1.0;
/// Box IoU (upright boxes) at which another category's detection is a rival: the evaluation's
/// match threshold, so a rival is a box that would take the same object.
pub const RIVAL_IOU: f64 = 0.25;
/// Share of the smaller box's volume inside the larger at which another category's larger box
/// is an outer rival of a detection (or its smaller box an inner one), whatever their IoU: a
/// table box on a bed's mattress, a bed box over a table and the floor round it.
pub const RIVAL_COVER: f64 = 0.5;

/// The best scores (before ranking) of another category's candidates whose boxes meet a
/// detection's: at IoU >= [`RIVAL_IOU`] (`overlap`); holding at least [`RIVAL_COVER`] of its box
/// (`outer`); at least [`RIVAL_COVER`] inside its box (`inner`). None where no candidate does.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rivals {
    pub overlap: Option<f64>,
    pub outer: Option<f64>,
    pub inner: Option<f64>,
}

impl Rivals {
    /// The rivals of `boxes[i]` among the `boxes` (scored before ranking) whose `other[j]` is
    /// true (another category's).
    pub fn of(i: usize, boxes: &[UprightBox], other: impl Fn(usize) -> bool) -> Self {
        let best = |a: Option<f64>, s: f64| Some(a.map_or(s, |a: f64| a.max(s)));
        let mut r = Self::default();
        let vi = boxes[i].volume();
        for j in (0..boxes.len()).filter(|&j| j != i && other(j)) {
            let inter = intersection(&boxes[i], &boxes[j]);
            if inter <= 0.0 {
                continue;
            }
            let vj = boxes[j].volume();
            if inter / (vi + vj - inter) >= RIVAL_IOU {
                r.overlap = best(r.overlap, boxes[j].score);
            }
            if vj >= vi && inter >= RIVAL_COVER * vi {
                r.outer = best(r.outer, boxes[j].score);
            }
            if vj <= vi && inter >= RIVAL_COVER * vj {
                r.inner = best(r.inner, boxes[j].score);
            }
        }
        r
    }
}

/// A detection's features (named by [`FEATURES`]): the verification's score and its counts as
/// fractions of the visible shape cells, `ln(1 + agree)`, the forest's log score and support,
/// the hypothesis' rank and tilt, whether refinement moved it, its depth (camera z, metres),
/// the size fit's largest `|ln scale|` (`scale`: the fitted size over the shape's own), and its
/// height and horizontal length (metres), and `rival_margin`: how far its score (before ranking)
/// is above the best of another category's detections whose box overlaps it (`rivals.overlap`;
/// None: none overlaps, the margin is [`NO_RIVAL`]), and the same margins over the best larger
/// box that holds it (`outer_rival_margin`) and the best smaller box inside it
/// (`inner_rival_margin`). The other features see one category's shapes alone; the margins say
/// whether another category explains the same surface better (a chair and a toilet box on one
/// object, a table box on a bed). Then the seen surface's [`Profile`] in the box: `fill`,
/// `level_1` to `level_5` (bottom first), `back_1` to `back_5`, `middle`, `span_length`,
/// `span_width` and `around`.
pub fn features(
    d: &Detection,
    v: &Verification,
    scale: [f64; 3],
    rivals: &Rivals,
    seen: &Profile,
) -> [f64; FEATURES.len()] {
    let n = (v.agree + v.violate + v.occluded + v.outside).max(1) as f64;
    let frac = |k: usize| k as f64 / n;
    [
        v.score,
        frac(v.agree),
        frac(v.violate),
        frac(v.occluded),
        frac(v.outside),
        frac(v.missing),
        frac(v.unexplained),
        (1.0 + v.agree as f64).ln(),
        d.forest_score.max(1e-6).ln(),
        (1.0 + d.support as f64).ln(),
        d.rank as f64,
        d.tilt_deg,
        f64::from(u8::from(d.refined)),
        d.t[2],
        scale.iter().map(|s| s.ln().abs()).fold(0.0, f64::max),
        d.size[2],
        d.size[0].max(d.size[1]),
        rivals.overlap.map_or(NO_RIVAL, |r| d.score - r),
        rivals.outer.map_or(NO_RIVAL, |r| d.score - r),
        rivals.inner.map_or(NO_RIVAL, |r| d.score - r),
        seen.fill,
        seen.levels[0],
        seen.levels[1],
        seen.levels[2],
        seen.levels[3],
        seen.levels[4],
        seen.back[0],
        seen.back[1],
        seen.back[2],
        seen.back[3],
        seen.back[4],
        seen.middle,
        seen.span[0],
        seen.span[1],
        seen.around,
    ]
}

/// One regression tree of a boosted ranker, as flat node arrays (scikit-learn's `tree_` layout).
/// Node `i` is a leaf when `feature[i] < 0` and then adds `value[i]` to the log-odds; otherwise
/// a detection goes to `left[i]` when its feature number `feature[i]` (an index into the
/// ranker's `features`), rounded to `f32` as scikit-learn compares it, is `<= threshold[i]`,
/// else to `right[i]`. Children stand after their parent, so every walk ends.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RankTree {
    pub feature: Vec<i32>,
    pub threshold: Vec<f64>,
    pub left: Vec<u32>,
    pub right: Vec<u32>,
    pub value: Vec<f64>,
}

impl RankTree {
    fn check(&self, n_features: usize) -> std::result::Result<(), String> {
        let n = self.feature.len();
        if n == 0
            || [
                self.threshold.len(),
                self.left.len(),
                self.right.len(),
                self.value.len(),
            ]
            .iter()
            .any(|&k| k != n)
        {
            return Err(format!("{n} nodes but arrays of other lengths (or none)"));
        }
        for i in 0..n {
            if self.feature[i] < 0 {
                if !self.value[i].is_finite() {
                    return Err(format!("leaf {i}: value not finite"));
                }
                continue;
            }
            let (l, r) = (self.left[i] as usize, self.right[i] as usize);
            if self.feature[i] as usize >= n_features
                || !self.threshold[i].is_finite()
                || l <= i
                || r <= i
                || l >= n
                || r >= n
            {
                return Err(format!(
                    "node {i}: feature {} of {n_features}, threshold {}, children {l} and {r} of {n} \
                     (children must stand after their parent)",
                    self.feature[i], self.threshold[i]
                ));
            }
        }
        Ok(())
    }

    /// The leaf value reached by features `x` (in the ranker's `features` order).
    fn eval(&self, x: &[f64]) -> f64 {
        let mut i = 0;
        while self.feature[i] >= 0 {
            let v = f64::from(x[self.feature[i] as usize] as f32);
            i = if v <= self.threshold[i] {
                self.left[i]
            } else {
                self.right[i]
            } as usize;
        }
        self.value[i]
    }
}

/// A logistic model of one category: `P(true) = 1 / (1 + exp(-(bias + sum_i w_i (f_i - mean_i)
/// / scale_i + sum_t tree_t(f))))` over the named features; `fitted_on` says on what (free text);
/// `nms_order` the NMS order the detections it was fitted on came from (None: not recorded, as
/// in files from before it was): under another order it sees other detections.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ranker {
    pub format: u32,
    pub category: String,
    pub features: Vec<String>,
    pub mean: Vec<f64>,
    pub scale: Vec<f64>,
    pub weights: Vec<f64>,
    pub bias: f64,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trees: Vec<RankTree>,
    #[serde(default)]
    pub fitted_on: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nms_order: Option<NmsOrder>,
}

impl Ranker {
    /// A ranker from its JSON text, checked; errors name `source`.
    pub fn from_json(text: &str, source: &str) -> Result<Self> {
        let r: Ranker = serde_json::from_str(text)
            .map_err(|e| IsaError::InvalidInput(format!("{source}: not a ranker ({e})")))?;
        r.validate().map_err(|e| match e {
            IsaError::InvalidInput(m) => IsaError::InvalidInput(format!("{source}: {m}")),
            other => other,
        })?;
        Ok(r)
    }

    /// The ranker as JSON (what [`Ranker::from_json`] reads).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a ranker serialises")
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(IsaError::InvalidInput(m));
        if self.format == 0 || self.format > RANKER_FORMAT {
            return bad(format!(
                "ranker format {} (this build reads 1 to {RANKER_FORMAT})",
                self.format
            ));
        }
        if self.format < 2 && !self.trees.is_empty() {
            return bad(format!(
                "ranker format {} has no trees (format 2 has)",
                self.format
            ));
        }
        let n = self.features.len();
        if n == 0 || self.mean.len() != n || self.scale.len() != n || self.weights.len() != n {
            return bad(format!(
                "ranker: {n} features, {} means, {} scales and {} weights (must be equal and >= 1)",
                self.mean.len(),
                self.scale.len(),
                self.weights.len()
            ));
        }
        if let Some(f) = self
            .features
            .iter()
            .find(|f| !FEATURES.contains(&f.as_str()))
        {
            return bad(format!(
                "ranker: unknown feature {f:?}; known: {}",
                FEATURES.join(", ")
            ));
        }
        let finite = self
            .mean
            .iter()
            .chain(&self.weights)
            .chain(std::iter::once(&self.bias))
            .all(|x| x.is_finite());
        if !finite || !self.scale.iter().all(|s| s.is_finite() && *s > 0.0) {
            return bad("ranker: means, weights and bias must be finite, scales positive".into());
        }
        for (t, tree) in self.trees.iter().enumerate() {
            tree.check(n)
                .or_else(|m| bad(format!("ranker: tree {t}: {m}")))?;
        }
        Ok(())
    }

    /// The probability that a detection with features `f` (all of [`FEATURES`], in order) is
    /// a true object.
    pub fn probability(&self, f: &[f64; FEATURES.len()]) -> f64 {
        let x: Vec<f64> = self
            .features
            .iter()
            .map(|name| {
                let k = FEATURES
                    .iter()
                    .position(|x| x == name)
                    .expect("validated names");
                f[k]
            })
            .collect();
        let linear: f64 = x
            .iter()
            .zip(&self.mean)
            .zip(&self.scale)
            .zip(&self.weights)
            .map(|(((v, m), s), w)| w * (v - m) / s)
            .sum();
        let z = self.bias + linear + self.trees.iter().map(|t| t.eval(&x)).sum::<f64>();
        1.0 / (1.0 + (-z).exp())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ranker(features: &[&str], weights: &[f64], bias: f64) -> Ranker {
        Ranker {
            format: RANKER_FORMAT,
            category: "chair".into(),
            features: features.iter().map(|s| s.to_string()).collect(),
            mean: vec![0.5; features.len()],
            scale: vec![2.0; features.len()],
            weights: weights.to_vec(),
            bias,
            trees: Vec::new(),
            fitted_on: String::new(),
            nms_order: None,
        }
    }

    #[test]
    fn probability_is_the_logistic_of_the_standardised_features() {
        let r = ranker(&["agree", "depth"], &[3.0, -1.0], 0.25);
        let mut f = [0.0; FEATURES.len()];
        f[1] = 0.9; // agree
        f[13] = 2.5; // depth
        let z: f64 = 0.25 + 3.0 * (0.9 - 0.5) / 2.0 - (2.5 - 0.5) / 2.0;
        assert!((r.probability(&f) - 1.0 / (1.0 + (-z).exp())).abs() < 1e-15);
        // More agreement, surer; the unused features change nothing.
        let mut g = f;
        g[1] = 1.0;
        g[0] = 123.0;
        assert!(r.probability(&g) > r.probability(&f));
    }

    /// A stump on `depth` (the ranker's feature 1): left (<= 2.5 m) adds -1, right +2.
    fn stump() -> RankTree {
        RankTree {
            feature: vec![1, -1, -1],
            threshold: vec![2.5, 0.0, 0.0],
            left: vec![1, 0, 0],
            right: vec![2, 0, 0],
            value: vec![0.0, -1.0, 2.0],
        }
    }

    #[test]
    fn trees_add_their_leaf_to_the_log_odds() {
        let mut r = ranker(&["agree", "depth"], &[0.0, 0.0], 0.5);
        r.format = RANKER_FORMAT;
        r.trees = vec![stump(), stump()];
        let logistic = |z: f64| 1.0 / (1.0 + (-z).exp());
        let mut f = [0.0; FEATURES.len()];
        for (depth, leaf) in [(1.0, -1.0), (2.5, -1.0), (2.6, 2.0), (9.0, 2.0)] {
            f[13] = depth;
            assert!((r.probability(&f) - logistic(0.5 + 2.0 * leaf)).abs() < 1e-15);
        }
        // Compared in f32, as scikit-learn's trees compare: 2.5 + 1e-12 is 2.5.
        f[13] = 2.5 + 1e-12;
        assert!((r.probability(&f) - logistic(0.5 - 2.0)).abs() < 1e-15);
        assert_eq!(Ranker::from_json(&r.to_json(), "x").unwrap(), r);
    }

    #[test]
    fn bad_trees_and_old_formats_with_trees_are_refused() {
        let mut ok = ranker(&["agree", "depth"], &[0.0, 0.0], 0.0);
        ok.trees = vec![stump()];
        let cycle = RankTree {
            left: vec![0, 0, 0],
            ..stump()
        };
        let far = RankTree {
            feature: vec![2, -1, -1],
            ..stump()
        };
        let short = RankTree {
            value: vec![0.0],
            ..stump()
        };
        for (tree, needle) in [
            (cycle, "tree 0: node 0"),
            (far, "feature 2 of 2"),
            (short, "arrays of other lengths"),
        ] {
            let r = Ranker {
                trees: vec![tree],
                ..ok.clone()
            };
            let e = Ranker::from_json(&r.to_json(), "m.ranker.json")
                .unwrap_err()
                .to_string();
            assert!(e.contains("m.ranker.json") && e.contains(needle), "{e}");
        }
        let old = Ranker {
            format: 1,
            ..ok.clone()
        };
        let e = Ranker::from_json(&old.to_json(), "m")
            .unwrap_err()
            .to_string();
        assert!(e.contains("format 1 has no trees"), "{e}");
        // A format-1 file (no trees) still reads.
        let linear = Ranker {
            format: 1,
            trees: Vec::new(),
            ..ok
        };
        assert_eq!(Ranker::from_json(&linear.to_json(), "m").unwrap(), linear);
    }

    #[test]
    fn the_nms_order_round_trips_and_an_unknown_one_names_the_file() {
        let r = Ranker {
            nms_order: Some(NmsOrder::Ranked),
            ..ranker(&["agree"], &[1.0], 0.0)
        };
        let text = r.to_json();
        assert!(text.contains("\"nms_order\": \"ranked\""), "{text}");
        assert_eq!(Ranker::from_json(&text, "x").unwrap(), r);
        let e = Ranker::from_json(&text.replace("\"ranked\"", "\"sideways\""), "m.ranker.json")
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.ranker.json") && e.contains("sideways"), "{e}");
        // Files from before the field: not recorded, and not written when not recorded.
        let old = ranker(&["agree"], &[1.0], 0.0);
        assert!(!old.to_json().contains("nms_order"));
        assert_eq!(
            Ranker::from_json(&old.to_json(), "x").unwrap().nms_order,
            None
        );
    }

    #[test]
    fn rivals_are_the_best_other_category_boxes_by_iou_and_by_cover() {
        let b = |x: f64, size: [f64; 3], score: f64| UprightBox {
            centre: [x, 0.0, size[2] / 2.0],
            size,
            yaw: 0.0,
            score,
        };
        let boxes = [
            b(0.0, [1.0, 1.0, 1.0], 0.5), // the detection
            b(0.1, [1.0, 1.0, 1.0], 0.3), // IoU 0.9/1.1: an overlap rival, and it holds 0.9
            b(0.0, [3.0, 3.0, 1.0], 0.7), // holds it all; IoU 1/9: outer only
            b(0.2, [0.4, 0.4, 0.4], 0.9), // wholly inside it; IoU 0.064: inner only
            b(0.0, [0.4, 0.4, 0.4], 2.0), // inside it too, but its own category
            b(5.0, [1.0, 1.0, 1.0], 3.0), // far away
        ];
        let r = Rivals::of(0, &boxes, |j| j != 4);
        assert_eq!(r.overlap, Some(0.3));
        assert_eq!(r.outer, Some(0.7));
        assert_eq!(r.inner, Some(0.9));
        // Half of a box's volume inside the other is enough; less is not.
        let half = [b(0.0, [1.0, 1.0, 1.0], 0.5), b(0.5, [1.0, 1.0, 1.0], 0.1)];
        // (Equal boxes: each holds the other.) IoU 1/3 makes it an overlap rival as well.
        let all = Rivals {
            overlap: Some(0.1),
            outer: Some(0.1),
            inner: Some(0.1),
        };
        assert_eq!(Rivals::of(0, &half, |_| true), all);
        let less = [b(0.0, [1.0, 1.0, 1.0], 0.5), b(0.51, [1.0, 1.0, 1.0], 0.1)];
        let overlap_only = Rivals {
            overlap: Some(0.1),
            ..Rivals::default()
        };
        assert_eq!(Rivals::of(0, &less, |_| true), overlap_only);
    }

    #[test]
    fn features_are_fractions_of_the_visible_cells() {
        let d = Detection {
            category: "chair".into(),
            r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            t: [0.0, 0.0, 3.0],
            size: [0.5, 0.6, 0.9],
            box_centre: [0.0; 3],
            score: 0.0,
            support: 9,
            forest_score: 0.5,
            rank: 2,
            tilt_deg: 4.0,
            shape: Some(0),
            refined: true,
            turn: 0,
            features: None,
        };
        let v = Verification {
            score: 0.4,
            agree: 60,
            violate: 10,
            occluded: 20,
            missing: 7,
            outside: 10,
            unexplained: 5,
        };
        let seen = Profile {
            fill: 0.3,
            levels: [0.1, 0.2, 0.3, 0.4, 0.0],
            back: [0.0, 0.1, 0.2, 0.3, 0.0],
            middle: 0.25,
            span: [0.8, 0.9],
            around: 2.5,
        };
        let rivals = Rivals {
            overlap: Some(0.5),
            outer: None,
            inner: Some(-0.25),
        };
        let f = features(&d, &v, [1.0, 0.5, 2.0], &rivals, &seen);
        let expect = [
            0.4,
            0.6,
            0.1,
            0.2,
            0.1,
            0.07,
            0.05,
            61f64.ln(),
            0.5f64.ln(),
            10f64.ln(),
            2.0,
            4.0,
            1.0,
            3.0,
            2f64.ln(),
            0.9,
            0.6,
            -0.5,
            1.0,
            0.25,
            0.3,
            0.1,
            0.2,
            0.3,
            0.4,
            0.0,
            0.0,
            0.1,
            0.2,
            0.3,
            0.0,
            0.25,
            0.8,
            0.9,
            2.5,
        ];
        assert_eq!(expect.len(), FEATURES.len());
        for (k, (a, b)) in f.iter().zip(expect).enumerate() {
            assert!((a - b).abs() < 1e-12, "{}: {a} vs {b}", FEATURES[k]);
        }
    }

    #[test]
    fn bad_rankers_are_refused_naming_the_source() {
        let ok = ranker(&["agree"], &[1.0], 0.0);
        assert_eq!(Ranker::from_json(&ok.to_json(), "x").unwrap(), ok);
        for (r, needle) in [
            (ranker(&["agree"], &[1.0, 2.0], 0.0), "2 weights"),
            (ranker(&["agreement"], &[1.0], 0.0), "unknown feature"),
            (ranker(&["agree"], &[1.0], 0.0), "scales positive"),
            (
                Ranker {
                    format: 9,
                    ..ok.clone()
                },
                "format 9",
            ),
        ] {
            let mut r = r;
            if needle == "scales positive" {
                r.scale = vec![0.0];
            }
            let text = serde_json::to_string(&r).unwrap();
            let e = Ranker::from_json(&text, "m.ranker.json")
                .unwrap_err()
                .to_string();
            assert!(e.contains("m.ranker.json") && e.contains(needle), "{e}");
        }
        let e = Ranker::from_json("{}", "m.ranker.json")
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.ranker.json: not a ranker"), "{e}");
    }
}
