//! Every category in one pass (as `isa.detection.multi.detect`): gravity, planes, each forest's
//! votes on the cleaned depth, hypotheses snapped upright and set on the floor, verification
//! against each category's shapes with a size fit, refinement of the best, the forest's score
//! as a small term, NMS across categories, ranking ([`super::ranking`]). Categories and
//! hypotheses run in parallel (rayon); results do not depend on the thread count. Footprint
//! proposals ([`super::proposals`]) join the forests' hypotheses before verification.
//!
//! (Over 600 lines: the steps here share the private hypothesis-in-flight `Cand` and the
//! frame's `Scene`; the geometry of each stage lives in its own module.)

use std::time::Instant;

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde_json::Value;

use super::gravity::{floor_up, level, rotation_from_up, votes_up, GravitySource};
use super::nms::{nms_across, nms_within, UprightBox};
use super::planes::{find_planes, Planes};
use super::profile::{profile, seen_points, STRIDE as PROFILE_STRIDE};
use super::proposals::{footprints, Footprint};
use super::ranking::{features, Ranker, Rivals, FEATURES};
use super::refine::{refine_pose, upright_points};
use super::shapes::{ShapeLibrary, SizeRange};
use super::verify::{verify_pose, Evidence, Verification};
use super::{rot_z, rows, yaw_of, Camera, Frame};
use crate::error::{IsaError, Result};
use crate::forest::Forest;
use crate::params::{DetectParams, NmsOrder, ProposalParams, Valid, VerifyParams};
use crate::vote::{depth_m_to_mm, predict_parts, DepthImage, Hypothesis, ImageParts};

/// Margin (a fraction) by which a fitted size may leave the category's real-world range.
const SIZE_MARGIN: f64 = 0.15;
/// Coordinate-search rounds of the size fit.
const SIZE_ROUNDS: usize = 2;

/// One category model: its forest, its box (full extents and the SSC's offset from the box
/// centre, object frame), its shape library (None: the forest's score and box are used), the
/// category's real-world sizes the size fit keeps to (None: any), and optionally hypotheses
/// voted elsewhere (e.g. with leaf weights) instead of the forest's own.
#[derive(Clone, Copy, Debug)]
pub struct SceneModel<'a> {
    pub category: &'a str,
    pub forest: &'a Forest,
    pub size: [f64; 3],
    pub ssc_offset: [f64; 3],
    pub shapes: Option<&'a ShapeLibrary>,
    pub size_range: Option<SizeRange>,
    pub hypotheses: Option<&'a [Hypothesis]>,
    pub ranker: Option<&'a Ranker>,
}

impl<'a> SceneModel<'a> {
    /// A model whose box comes from the forest's metadata and whose size range from its shape
    /// library; the error names `source`.
    pub fn from_forest(
        category: &'a str,
        forest: &'a Forest,
        shapes: Option<&'a ShapeLibrary>,
        source: &str,
    ) -> Result<Self> {
        let b = forest.metadata.category_box.as_ref().ok_or_else(|| {
            IsaError::InvalidInput(format!(
                "{source}: the model's metadata has no box (category size and SSC offset)"
            ))
        })?;
        Ok(SceneModel {
            category,
            forest,
            size: b.size,
            ssc_offset: b.ssc_offset,
            shapes,
            size_range: shapes.and_then(|l| l.size_range),
            hypotheses: None,
            ranker: None,
        })
    }
}

/// One detected object: pose `(r, t)` (object to camera, `t` the category's origin), `size`
/// along its own axes, `box_centre` (object frame), `score` (verified, or the forest's without
/// shapes), `support` (votes), and where it came from.
// Plain fields, some like a vote `Hypothesis`'s (pose, score, support); `duplicates` pairs the
// two by shape, and each holds what its own stage gives.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    pub category: String,
    pub r: [[f64; 3]; 3],
    pub t: [f64; 3],
    pub size: [f64; 3],
    pub box_centre: [f64; 3],
    pub score: f64,
    pub support: usize,
    pub forest_score: f64,
    pub rank: usize,
    pub tilt_deg: f64,
    pub shape: Option<usize>,
    pub refined: bool,
    pub turn: usize,
    /// What ranking reads ([`super::ranking::FEATURES`]), for the detections of verified
    /// models that ranking saw (those NMS keeps, or all with `rank_before_nms`).
    pub features: Option<[f64; FEATURES.len()]>,
}

/// What [`detect`] found: detections best first, the gravity rotation used and its source, the
/// floor's height, the planes, and seconds per stage.
#[derive(Clone, Debug)]
pub struct DetectOutput {
    pub detections: Vec<Detection>,
    pub gravity: Matrix3<f64>,
    pub gravity_source: GravitySource,
    pub floor_height: Option<f64>,
    pub planes: Option<Planes>,
    pub seconds: Vec<(&'static str, f64)>,
}

/// A pose `(r, t)`.
type Pose = (Matrix3<f64>, Vector3<f64>);

/// A hypothesis on its way through the stages.
#[derive(Clone, Debug)]
struct Cand {
    r: Matrix3<f64>,
    t: Vector3<f64>,
    forest_score: f64,
    support: usize,
    rank: usize,
    tilt_deg: f64,
    score: f64,
    shape: Option<usize>,
    scale: [f64; 3],
    turn: usize,
    shape_order: Vec<usize>,
    refined: bool,
}

impl Cand {
    /// A hypothesis not verified yet at `(r, t)`, with the forest's score and support (its
    /// score until verified), its rank among the category's and its tilt.
    fn new(
        (r, t): Pose,
        (forest_score, support): (f64, usize),
        rank: usize,
        tilt_deg: f64,
    ) -> Self {
        Cand {
            r,
            t,
            forest_score,
            support,
            rank,
            tilt_deg,
            score: forest_score,
            shape: None,
            scale: [1.0; 3],
            turn: 0,
            shape_order: vec![],
            refined: false,
        }
    }
}

/// The geometry every hypothesis of a frame is checked against.
struct Scene<'a> {
    ev: Evidence<'a>,
    rg: Matrix3<f64>,
    rg_inv: Matrix3<f64>,
    floor: Option<f64>,
}

impl Scene<'_> {
    fn up(&self) -> Vector3<f64> {
        self.rg.row(2).transpose()
    }

    /// Shape `s` scaled by `scale` at `(r, t)`, set on the floor when there is one.
    #[allow(clippy::too_many_arguments)]
    fn verify_scaled(
        &self,
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
        lib: &ShapeLibrary,
        s: usize,
        scale: [f64; 3],
        p: &VerifyParams,
        n_points: Option<usize>,
    ) -> (Verification, Vector3<f64>) {
        let mut t = *t;
        if let Some(f) = self.floor {
            let up = self.up();
            t -= (up.dot(&t) + lib.bounds[s][0][2] * scale[2] - f) * up;
        }
        let size = lib.size(s);
        let diag = (0..3)
            .map(|i| (size[i] * scale[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let p = VerifyParams {
            lateral: p.lateral.max(p.lateral_fraction * diag),
            ..p.clone()
        };
        (
            verify_pose(
                &self.ev,
                r,
                &t,
                lib.points_of(s),
                scale,
                lib.spacing[s],
                &p,
                n_points,
            ),
            t,
        )
    }

    /// The pose turned by `angle` about the vertical through the object-frame point `c`.
    fn turned(
        &self,
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
        angle: f64,
        c: &Vector3<f64>,
    ) -> (Matrix3<f64>, Vector3<f64>) {
        let rz = self.rg.transpose() * rot_z(angle) * self.rg;
        let centre = r * c + t;
        let r2 = rz * r;
        (r2, centre - r2 * c)
    }
}

fn candidates(
    model: &SceneModel<'_>,
    hyps: &[Hypothesis],
    sc: &Scene<'_>,
    p: &DetectParams,
) -> Vec<Cand> {
    let up = sc.up();
    let mut out = Vec::new();
    for (rank, h) in hyps.iter().enumerate() {
        let m = sc.rg * super::mat(&h.rotation);
        let tilt = (m[(2, 2)] / m.column(2).norm().max(1e-12))
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        if p.max_tilt_deg.is_some_and(|x| tilt > x) {
            continue;
        }
        let r_up = sc.rg_inv * rot_z(yaw_of(&m));
        let mut t = Vector3::from(h.translation);
        if let Some(f) = sc.floor {
            let gap = up.dot(&t) - model.ssc_offset[2] - model.size[2] / 2.0 - f;
            if p.floor_gap.is_some_and(|g| gap.abs() > g) {
                continue;
            }
            t -= gap * up;
        }
        out.push(Cand::new((r_up, t), (h.score, h.support), rank, tilt));
    }
    out
}

/// The model's box on every footprint in its four yaws (standing on the floor at `floor`). Each
/// carries the score and support of the model's best hypothesis over the footprint (grown by
/// `vote_margin`), else `unvoted` times the weakest hypothesis' score (0: none proposed): the
/// forest's word on the category.
fn proposed(
    model: &SceneModel<'_>,
    hyps: &[Hypothesis],
    fps: &[Footprint],
    floor: f64,
    sc: &Scene<'_>,
    pp: &ProposalParams,
) -> Vec<Cand> {
    let weakest = hyps.iter().map(|h| h.score).fold(f64::INFINITY, f64::min);
    let fallback = if weakest.is_finite() {
        weakest * pp.unvoted
    } else {
        1e-6 * pp.unvoted
    };
    let mut out = Vec::new();
    for fp in fps {
        let over = hyps
            .iter()
            .filter(|h| {
                let q = sc.rg * Vector3::from(h.translation);
                fp.contains([q.x, q.y], pp.vote_margin)
            })
            .max_by(|a, b| a.score.total_cmp(&b.score));
        if over.is_none() && pp.unvoted == 0.0 {
            continue;
        }
        if let (Some(r), Some(slack)) = (&model.size_range, pp.size_slack) {
            if !fp.fits(r, SIZE_MARGIN, slack) {
                continue;
            }
        }
        let forest = over.map_or((fallback, 0), |h| (h.score, h.support));
        for (yaw, centre) in fp.boxes(model.size, floor) {
            let r_up = rot_z(yaw);
            let origin = centre + r_up * Vector3::from(model.ssc_offset);
            let rank = hyps.len() + out.len();
            let pose = (sc.rg_inv * r_up, sc.rg_inv * origin);
            out.push(Cand::new(pose, forest, rank, 0.0));
        }
    }
    out
}

/// Every shape at its training size, at the candidate's pose and its turns; the best wins.
fn score_shapes(
    c: &mut Cand,
    lib: &ShapeLibrary,
    sc: &Scene<'_>,
    vp: &VerifyParams,
    p: &DetectParams,
) {
    let mut best: Option<(f64, usize, Pose, usize)> = None;
    let mut per_shape = vec![f64::NEG_INFINITY; lib.len()];
    for (s, shape_best) in per_shape.iter_mut().enumerate() {
        for k in 0..p.turns {
            let (r, t) = if k == 0 {
                (c.r, c.t)
            } else {
                let angle = 2.0 * std::f64::consts::PI * k as f64 / p.turns as f64;
                sc.turned(&c.r, &c.t, angle, &Vector3::from(lib.centre(s)))
            };
            let (v, t) = sc.verify_scaled(&r, &t, lib, s, [1.0; 3], vp, p.quick_points);
            *shape_best = shape_best.max(v.score);
            if best.as_ref().is_none_or(|b| v.score > b.0) {
                best = Some((v.score, s, (r, t), k));
            }
        }
    }
    let (score, s, (r, t), k) = best.expect("a library has shapes");
    let mut order: Vec<usize> = (0..lib.len()).collect();
    order.sort_by(|&a, &b| per_shape[b].total_cmp(&per_shape[a]));
    *c = Cand {
        score,
        shape: Some(s),
        r,
        t,
        turn: k,
        scale: [1.0; 3],
        shape_order: order,
        ..c.clone()
    };
}

/// The object's size: a coordinate search over per-axis scale factors of the candidate's best
/// shapes, within the category's real-world range; the final score from every sample.
fn fit_size(
    c: &mut Cand,
    lib: &ShapeLibrary,
    range: Option<SizeRange>,
    sc: &Scene<'_>,
    vp: &VerifyParams,
    p: &DetectParams,
) {
    let mut best: Option<(f64, usize, [f64; 3])> = None;
    for &s in c.shape_order.iter().take(p.size_shapes) {
        let (v, _) = sc.verify_scaled(&c.r, &c.t, lib, s, [1.0; 3], vp, p.quick_points);
        let mut cur = (v.score, [1.0; 3]);
        // Scales already scored: a later round retries those whose start has not moved since.
        let mut scored: Vec<([f64; 3], f64)> = Vec::new();
        for _ in 0..SIZE_ROUNDS {
            for axis in 0..3 {
                for &f in &p.size_steps {
                    let mut trial = cur.1;
                    trial[axis] *= f;
                    let size = lib.size(s);
                    let scaled = [size[0] * trial[0], size[1] * trial[1], size[2] * trial[2]];
                    if range.is_some_and(|r| !r.admits(scaled, SIZE_MARGIN)) {
                        continue;
                    }
                    let score = match scored.iter().find(|x| x.0 == trial) {
                        Some(x) => x.1,
                        None => {
                            let (v, _) =
                                sc.verify_scaled(&c.r, &c.t, lib, s, trial, vp, p.quick_points);
                            scored.push((trial, v.score));
                            v.score
                        }
                    };
                    if score > cur.0 {
                        cur = (score, trial);
                    }
                }
            }
        }
        if best.is_none_or(|b| cur.0 > b.0) {
            best = Some((cur.0, s, cur.1));
        }
    }
    let Some((_, s, scale)) = best else { return };
    let (v, t) = sc.verify_scaled(&c.r, &c.t, lib, s, scale, vp, None);
    c.score = v.score;
    c.shape = Some(s);
    c.scale = scale;
    c.t = t;
}

/// Indices of the best `n` candidates by score (ties: the earlier).
fn top(cands: &[Cand], n: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..cands.len()).collect();
    order.sort_by(|&a, &b| cands[b].score.total_cmp(&cands[a].score));
    order.truncate(n);
    order
}

fn v3(p: &[f32; 3], s: [f64; 3]) -> Vector3<f64> {
    Vector3::new(
        f64::from(p[0]) * s[0],
        f64::from(p[1]) * s[1],
        f64::from(p[2]) * s[2],
    )
}

/// The whole pipeline on one frame (see the module docs). `depth` metres, row-major, 0 =
/// missing; `gravity` the camera -> upright rotation when known; `planes` found beforehand
/// (e.g. to vote elsewhere on the cleaned depth) or None to find them here.
pub fn detect(
    depth: &[f32],
    camera: Camera,
    models: &[SceneModel<'_>],
    gravity: Option<Matrix3<f64>>,
    planes: Option<Planes>,
    params: &Valid<DetectParams>,
) -> Result<DetectOutput> {
    let p: &DetectParams = params;
    let frame = Frame::new(depth, camera)?;
    if let Some(g) = &gravity {
        if !g.iter().all(|x| x.is_finite()) || g.determinant().abs() < 1e-6 {
            return Err(IsaError::InvalidInput(format!(
                "gravity: not a rotation: {g:?}"
            )));
        }
    }
    let predict_over = {
        let mut o = p.predict.clone();
        o.insert("stride".into(), Value::from(p.stride));
        o.insert("max_hypotheses".into(), Value::from(p.max_hypotheses));
        Value::Object(o)
    };
    let vote_params = models
        .iter()
        .map(|m| {
            m.forest
                .predict_defaults
                .with_overrides(&predict_over, "detect: predict")
        })
        .collect::<Result<Vec<_>>>()?;
    let mut secs = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &'static str, secs: &mut Vec<(&'static str, f64)>| {
        secs.push((name, clock.elapsed().as_secs_f64()));
        clock = Instant::now();
    };
    let (mut rg, mut source) = match gravity {
        Some(g) => (g, GravitySource::Given),
        None => match floor_up(&frame, 0) {
            Some((up, _)) => (rotation_from_up(&up), GravitySource::Floor),
            None => (level(), GravitySource::Level),
        },
    };
    lap("gravity", &mut secs);
    let planes = match planes {
        Some(pl) => {
            if pl.removed.len() != depth.len() {
                return Err(IsaError::InvalidInput(format!(
                    "planes: {} pixels for a {}-pixel frame",
                    pl.removed.len(),
                    depth.len()
                )));
            }
            Some(pl)
        }
        None if p.remove_planes => Some(find_planes(&frame, &rg, &p.planes, true, true)),
        None => None,
    };
    let floor = planes.as_ref().and_then(|pl| pl.floor_height());
    lap("planes", &mut secs);
    let clean = planes
        .as_ref()
        .map_or_else(|| depth.to_vec(), |pl| pl.clean(depth));
    let clean_mm = depth_m_to_mm(&clean);
    let img = DepthImage::new(&clean_mm, camera.width, camera.height)?;
    // One part sampling for every forest (each keeps its own depth limits).
    let parts = ImageParts::new(&img, p.stride)?;
    let per_model: Vec<Vec<Hypothesis>> = models
        .par_iter()
        .zip(&vote_params)
        .map(|(m, vp)| match m.hypotheses {
            Some(h) => Ok(h.to_vec()),
            None => predict_parts(m.forest, &parts, &camera.k, vp),
        })
        .collect::<Result<_>>()?;
    lap("votes", &mut secs);
    if source == GravitySource::Level {
        let all: Vec<&Hypothesis> = per_model.iter().flatten().collect();
        if let Some(up) = votes_up(&all) {
            rg = rotation_from_up(&up);
            source = GravitySource::Votes;
        }
    }
    let rg_inv = rg.try_inverse().unwrap_or_else(|| rg.transpose());
    let sc = Scene {
        ev: Evidence {
            frame,
            planes: planes.as_ref().map(|pl| &pl.removed[..]),
        },
        rg,
        rg_inv,
        floor,
    };
    // Proposals only where verification can judge them: they carry no evidence of their own.
    let verified = |m: &SceneModel<'_>| m.shapes.is_some() && p.verify.is_some();
    let fps = match (&p.proposals, floor, &planes) {
        (Some(pp), Some(f), Some(_)) if models.iter().any(verified) => {
            let pts = upright_points(&Frame::new(&clean, camera)?, &rg, pp.stride, Some(f), 0.0);
            let mut fps = footprints(&pts, f, pp);
            fps.truncate(pp.max_footprints);
            fps
        }
        _ => Vec::new(),
    };
    lap("proposals", &mut secs);
    let obs_up = p
        .refine
        .as_ref()
        .map(|_| upright_points(&frame, &rg, 2, floor, 0.02));
    // Verification and size per category (candidates in parallel), then refinement.
    let mut per_cat: Vec<Vec<Cand>> = models
        .par_iter()
        .zip(&per_model)
        .map(|(m, hyps)| {
            let mut cands = candidates(m, hyps, &sc, p);
            if let (Some(pp), Some(f), true) = (&p.proposals, floor, verified(m)) {
                cands.extend(proposed(m, hyps, &fps, f, &sc, pp));
            }
            if let (Some(lib), Some(vp)) = (m.shapes, &p.verify) {
                cands
                    .par_iter_mut()
                    .for_each(|c| score_shapes(c, lib, &sc, vp, p));
                if p.size_top > 0 {
                    let chosen = top(&cands, p.size_top);
                    let fitted: Vec<(usize, Cand)> = chosen
                        .par_iter()
                        .map(|&i| {
                            let mut c = cands[i].clone();
                            fit_size(&mut c, lib, m.size_range, &sc, vp, p);
                            (i, c)
                        })
                        .collect();
                    for (i, c) in fitted {
                        cands[i] = c;
                    }
                }
            }
            cands
        })
        .collect();
    lap("verify", &mut secs);
    if let (Some(rp), Some(vp), Some(obs)) = (&p.refine, &p.verify, &obs_up) {
        let rp = crate::params::RefineParams {
            fix_height: rp.fix_height || floor.is_some(),
            ..rp.clone()
        };
        per_cat.par_iter_mut().zip(models).for_each(|(cands, m)| {
            let Some(lib) = m.shapes else { return };
            let chosen = top(cands, p.refine_top);
            let refined: Vec<(usize, Option<(Pose, f64)>)> = chosen
                .par_iter()
                .map(|&i| {
                    let c = &cands[i];
                    let s = c.shape.expect("verified candidates have a shape");
                    let sc_ = c.scale;
                    let pts: Vec<Vector3<f64>> =
                        lib.points_of(s).iter().map(|q| v3(q, sc_)).collect();
                    let nrm: Vec<Vector3<f64>> = lib
                        .normals_of(s)
                        .iter()
                        .map(|q| {
                            let n = v3(q, [1.0 / sc_[0], 1.0 / sc_[1], 1.0 / sc_[2]]);
                            n / n.norm().max(1e-300)
                        })
                        .collect();
                    let b = lib.bounds[s];
                    let bounds = [
                        [0, 1, 2].map(|k| b[0][k] * sc_[k]),
                        [0, 1, 2].map(|k| b[1][k] * sc_[k]),
                    ];
                    let r =
                        refine_pose(obs, &camera, &c.r, &c.t, &pts, Some(&nrm), bounds, &rg, &rp);
                    let (v, t) = sc.verify_scaled(&r.r, &r.t, lib, s, sc_, vp, None);
                    (i, (v.score >= c.score).then_some(((r.r, t), v.score)))
                })
                .collect();
            for (i, r) in refined {
                if let Some(((r, t), score)) = r {
                    let c = &mut cands[i];
                    c.r = r;
                    c.t = t;
                    c.score = score;
                    c.refined = true;
                }
            }
        });
    }
    lap("refine", &mut secs);
    let mut dets = Vec::new();
    // Each detection's fitted scale and model.
    let mut owner: Vec<([f64; 3], usize)> = Vec::new();
    for (mi, (m, cands)) in models.iter().zip(per_cat).enumerate() {
        let verified = m.shapes.is_some() && p.verify.is_some();
        for mut c in cands {
            if verified && p.forest_weight != 0.0 {
                c.score += p.forest_weight * c.forest_score.max(1e-6).ln();
            }
            if p.min_score.is_some_and(|s| c.score < s) {
                continue;
            }
            let (size, centre) = match (c.shape, m.shapes) {
                (Some(s), Some(lib)) => {
                    let (z, ce) = (lib.size(s), lib.centre(s));
                    (
                        [0, 1, 2].map(|k| z[k] * c.scale[k]),
                        [0, 1, 2].map(|k| ce[k] * c.scale[k]),
                    )
                }
                _ => (m.size, m.ssc_offset.map(|x| -x)),
            };
            dets.push(Detection {
                category: m.category.to_string(),
                r: rows(&c.r),
                t: [c.t.x, c.t.y, c.t.z],
                size,
                box_centre: centre,
                score: c.score,
                support: c.support,
                forest_score: c.forest_score,
                rank: c.rank,
                tilt_deg: c.tilt_deg,
                shape: c.shape,
                refined: c.refined,
                turn: c.turn,
                features: None,
            });
            owner.push((c.scale, mi));
        }
    }
    let nms_at = |dets: &[Detection], iou: f64, overlap: f64| {
        let boxes: Vec<UprightBox> = dets.iter().map(|d| upright_box(d, &rg)).collect();
        let mut keep = nms_across(&boxes, iou, overlap);
        keep.truncate(p.max_detections);
        keep
    };
    let nms = |dets: &[Detection]| nms_at(dets, p.nms_iou, p.nms_overlap);
    let detections = match &p.verify {
        Some(vp) if p.rank_before_nms => {
            let all: Vec<usize> = (0..dets.len()).collect();
            let ranked = rank(&dets, &owner, &all, models, &sc, vp);
            lap("rank", &mut secs);
            let keep = nms(&ranked);
            lap("nms", &mut secs);
            keep.into_iter().map(|i| ranked[i].clone()).collect()
        }
        Some(vp) if p.nms_order == NmsOrder::Joint => {
            let keep = nms(&dets);
            lap("nms", &mut secs);
            let ranked = rank(&dets, &owner, &keep, models, &sc, vp);
            lap("rank", &mut secs);
            ranked
        }
        Some(vp) => {
            // Within each category first (its best `max_detections`).
            let boxes: Vec<UprightBox> = dets.iter().map(|d| upright_box(d, &rg)).collect();
            let model: Vec<usize> = owner.iter().map(|o| o.1).collect();
            let keep = nms_within(&boxes, &model, p.nms_iou, p.nms_overlap, p.max_detections);
            lap("nms", &mut secs);
            let ranked = rank(&dets, &owner, &keep, models, &sc, vp);
            lap("rank", &mut secs);
            if p.nms_order == NmsOrder::Ranked {
                let keep = nms_at(&ranked, p.cross_iou, p.cross_overlap);
                lap("nms_across", &mut secs);
                keep.into_iter().map(|i| ranked[i].clone()).collect()
            } else {
                ranked
            }
        }
        None => {
            let keep = nms(&dets);
            lap("nms", &mut secs);
            keep.into_iter().map(|i| dets[i].clone()).collect()
        }
    };
    Ok(DetectOutput {
        detections,
        gravity: rg,
        gravity_source: source,
        floor_height: floor,
        planes,
        seconds: secs,
    })
}

/// The detections `keep` (best first) with their features, those of models with a ranker
/// scored by it and all sorted again (stable: ties keep the NMS order). The features come from
/// one full verification at the final pose that also counts the unexplained cells.
fn rank(
    dets: &[Detection],
    owner: &[([f64; 3], usize)],
    keep: &[usize],
    models: &[SceneModel<'_>],
    sc: &Scene<'_>,
    vp: &VerifyParams,
) -> Vec<Detection> {
    // The smallest positive weight counts the cells and leaves the score as it is (a count
    // times 2e-308 vanishes beside the other terms).
    let counting = VerifyParams {
        unexplained_weight: vp.unexplained_weight.max(f64::MIN_POSITIVE),
        ..vp.clone()
    };
    let boxes: Vec<UprightBox> = dets.iter().map(|d| upright_box(d, &sc.rg)).collect();
    let seen = seen_points(&sc.ev.frame, &sc.rg, sc.ev.planes, sc.floor, PROFILE_STRIDE);
    let mut out: Vec<Detection> = keep
        .par_iter()
        .map(|&i| {
            let mut d = dets[i].clone();
            let (scale, mi) = owner[i];
            let m = &models[mi];
            if let (Some(lib), Some(s)) = (m.shapes, d.shape) {
                let r = super::mat(&d.r);
                let t = Vector3::from(d.t);
                let (v, _) = sc.verify_scaled(&r, &t, lib, s, scale, &counting, None);
                // Every candidate of the other categories counts, suppressed or not.
                let rivals = Rivals::of(i, &boxes, |j| owner[j].1 != mi);
                let f = features(&d, &v, scale, &rivals, &profile(&seen, &boxes[i]));
                if let Some(rk) = m.ranker {
                    d.score = rk.probability(&f);
                }
                d.features = Some(f);
            }
            d
        })
        .collect();
    out.sort_by(|a, b| b.score.total_cmp(&a.score));
    out
}

/// A detection's gravity-aligned box in the upright frame.
pub fn upright_box(d: &Detection, rg: &Matrix3<f64>) -> UprightBox {
    let r = super::mat(&d.r);
    let c = rg * (r * Vector3::from(d.box_centre) + Vector3::from(d.t));
    UprightBox {
        centre: [c.x, c.y, c.z],
        size: d.size,
        yaw: yaw_of(&(rg * r)),
        score: d.score,
    }
}
