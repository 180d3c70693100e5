//! Vote aggregation and mode finding: the last step of inference (paper Sec. 3.4, Eq. 12-13).
//!
//! Every part of a depth image, passed down every tree, ends in leaves that vote for the SSC
//! position (a 3D point in the camera frame, metres) and the object's rotation (a unit
//! quaternion `w, x, y, z`, sign-free: `q` and `-q` are the same rotation), each vote with a
//! weight (e.g. `1 / |F|` per tree, Eq. 13). This module is independent of how the votes are
//! produced: [`find_modes`] takes a flat slice of [`PoseVote`]s and returns ranked [`Hypothesis`]es.
//!
//! # Algorithm
//! Kernel density of the votes, a product of a biweight kernel in position (radius
//! [`VoteParams::position_bandwidth`] `h`) and a biweight kernel on SO(3) (geodesic radius
//! [`VoteParams::rotation_bandwidth`]), and its modes:
//! 1. **Coarse grid**: an even-stride subsample of at most [`VoteParams::coarse_votes`] votes is
//!    hashed into cubic cells of side `2h`, each keeping its weight and weighted centroid.
//! 2. **Position mean-shift**, coarse to fine: the [`VoteParams::max_seeds`] heaviest cells seed a
//!    mean-shift on cell centroids with a kernel of radius `2h` (27 neighbour cells cover it; the
//!    wider kernel has fewer spurious modes); seeds reaching the same coarse mode count once,
//!    and the [`VoteParams::refine_modes`] densest coarse modes are refined, densest first, on the
//!    raw votes within `3h` (one gathering pass over all votes; iterations on at most
//!    [`VoteParams::refine_votes`] of them) with the kernel of radius `h`, until the shift is
//!    below `0.01 h`; a coarse mode within `max(2h, NMS distance)` of a refined mode is not
//!    refined, and a refinement stops once it comes within the NMS distance of one.
//!    Densities and supports are computed over all votes. Seeds and rotations run in parallel.
//! 3. **Non-maximum suppression** on position, by position density, with radius
//!    `max(nms_radius, h / 4)`.
//! 4. **Rotation mode** among the votes within `h` of each position mode, each weighted by its
//!    position kernel: the densest of a strided subsample of candidate votes (a medoid-like start,
//!    robust to outliers; [`VoteParams::rotation_candidates`] candidates scored on
//!    [`VoteParams::rotation_eval_votes`] votes), then mean-shift on the sphere of quaternions with
//!    every vote's sign aligned to the current estimate (the weighted chordal mean; iterations on
//!    at most [`VoteParams::refine_votes`] votes, the score over all). Optional further rotation
//!    modes per position ([`VoteParams::rotations_per_position`]) for symmetric objects.
//! 5. **Ranking** by the joint density at the mode ([`Hypothesis::score`], the unnormalised
//!    `p(Δx, θ | I)` of Eq. 13), ties broken deterministically; the first
//!    [`VoteParams::max_hypotheses`] are returned.
//!
//! Everything is deterministic: float reductions run in a fixed order, parallel work is per
//! seed/mode/chunk and collected in order, so results do not depend on the number of threads.
//! (Permuting the input changes results only by summation order and by which votes the
//! even-stride subsamples pick: well under a millimetre and a tenth of a degree in the tests.)
//!
//! Cost: one validation pass and one gathering pass over all votes, a hash grid over at most
//! `coarse_votes` of them, and work per mode bounded by `refine_votes`; `benches/vote.rs`
//! measures it (about 4 ms of one core for 10^5 votes; 13 ms for the 414,530 votes of its room
//! frame). The gathering pass tests runs of consecutive votes only against the centres whose
//! ball meets the run's bounding box, with AVX2 when the CPU has it (same answer either way).

mod gather;
mod grid;
mod nms;
mod position_modes;
pub mod predict;
mod rotation_modes;
pub mod synth;
#[cfg(test)]
mod tests;

pub use crate::params::{PredictParams, VoteParams};
pub use predict::{
    depth_m_to_mm, image_votes, predict, predict_parts, DepthImage, ImageParts, ImageVotes,
    Intrinsics,
};

use crate::error::{IsaError, Result};
use crate::rotation::normalise as normalise4;
pub use crate::rotation::{matrix_to_quat, quat_angle, quat_to_matrix};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use nms::{by_rank, suppress};
use position_modes::position_modes;
use rotation_modes::rotation_modes;

/// One vote: where the SSC is (camera frame, metres), the object's rotation, and a weight.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[repr(C)]
pub struct PoseVote {
    /// SSC position `t` in the camera frame (metres): `X_cam = R X_obj + t`.
    pub position: [f32; 3],
    /// Rotation `R` as a quaternion `(w, x, y, z)`; need not be unit (normalised here), sign-free.
    pub rotation: [f32; 4],
    /// Non-negative weight; votes with weight 0 are ignored.
    pub weight: f32,
}

/// A pose hypothesis: `X_cam = R X_obj + t` with the SSC as object origin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hypothesis {
    /// Rotation matrix `R`, row-major.
    pub rotation: [[f64; 3]; 3],
    /// The same rotation as a unit quaternion `(w, x, y, z)` with `w >= 0`.
    pub quaternion: [f64; 4],
    /// Translation `t` = SSC position in the camera frame (metres).
    pub translation: [f64; 3],
    /// Joint kernel density at the mode: `Σ w · k_pos · k_rot` (votes' weights times biweight
    /// kernels, each 1 at the mode). Hypotheses are sorted by it, highest first.
    pub score: f64,
    /// Votes inside both kernels.
    pub support: usize,
    /// Position-only density `Σ w · k_pos`.
    pub position_score: f64,
    /// Votes inside the position kernel.
    pub position_support: usize,
}

// ---------------------------------------------------------------------------------------------
// Vote checks.

fn vote_problem(v: &PoseVote) -> Option<String> {
    if !v.position.iter().all(|x| x.is_finite()) {
        return Some(format!("position {:?} is not finite", v.position));
    }
    if !(v.weight.is_finite() && v.weight >= 0.0) {
        return Some(format!("weight {} must be finite and >= 0", v.weight));
    }
    let q = v.rotation;
    let n2 = q.iter().map(|x| f64::from(*x) * f64::from(*x)).sum::<f64>();
    if !(n2.is_finite() && n2 > 1e-12) {
        return Some(format!(
            "rotation {q:?} is not a finite non-zero quaternion"
        ));
    }
    None
}

/// Cheap test equivalent to `vote_problem(v).is_none()` (up to the zero-quaternion threshold).
#[inline]
fn vote_ok(v: &PoseVote) -> bool {
    let p = v.position;
    let q = v.rotation;
    let finite = p[0].is_finite() && p[1].is_finite() && p[2].is_finite() && v.weight.is_finite();
    let qmax = q[0].abs().max(q[1].abs()).max(q[2].abs()).max(q[3].abs());
    finite && v.weight >= 0.0 && qmax.is_finite() && qmax > 1e-6
}

/// The first bad vote, checked in parallel over fixed chunks (deterministic answer).
fn validate_votes(votes: &[PoseVote]) -> Result<()> {
    const CH: usize = 1 << 15;
    let bad = votes
        .par_chunks(CH)
        .enumerate()
        .filter_map(|(c, chunk)| chunk.iter().position(|v| !vote_ok(v)).map(|i| c * CH + i))
        .min();
    match bad {
        Some(i) => Err(IsaError::InvalidInput(format!(
            "votes[{i}]: {}",
            vote_problem(&votes[i])
                .unwrap_or_else(|| "rotation is not a finite non-zero quaternion".into())
        ))),
        None => Ok(()),
    }
}

/// Squared distance.
#[inline]
pub(super) fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// `n` indices `0 .. len` evenly strided (all of them when `len <= n`).
pub(super) fn strided(len: usize, n: usize) -> impl Iterator<Item = usize> {
    let m = n.min(len);
    (0..m).map(move |j| j * len / m)
}

/// Finds the modes of the votes' density and returns them as hypotheses, best first.
///
/// Errors name the first bad vote (non-finite position, negative weight, zero quaternion) or
/// the bad parameter. No votes (or all of weight 0) give no hypotheses.
pub fn find_modes(votes: &[PoseVote], params: &VoteParams) -> Result<Vec<Hypothesis>> {
    params.validate()?;
    validate_votes(votes)?;
    Ok(find_modes_valid(votes, params))
}

/// [`find_modes`] on votes known to be valid (finite, weight >= 0, non-zero quaternions) with
/// validated parameters: what `predict` calls, its votes being built from a validated forest.
pub(crate) fn find_modes_valid(votes: &[PoseVote], params: &VoteParams) -> Vec<Hypothesis> {
    let modes = position_modes(votes, params);

    // NMS on positions (also merges modes that converged to the same place).
    let kept = suppress(modes, params);

    // Rotation modes among each position mode's members, in parallel.
    let mut hyps: Vec<Hypothesis> = kept
        .par_iter()
        .flat_map_iter(|m| {
            let quats: Vec<[f64; 4]> = m
                .members
                .iter()
                .map(|&j| normalise4(votes[j as usize].rotation.map(f64::from)))
                .collect();
            rotation_modes(&quats, &m.member_weights, params)
                .into_iter()
                .map(move |rm| Hypothesis {
                    rotation: quat_to_matrix(rm.q),
                    quaternion: rm.q,
                    translation: m.position,
                    score: rm.score,
                    support: rm.support,
                    position_score: m.score,
                    position_support: m.support,
                })
        })
        .filter(|hy| hy.support >= params.min_support)
        .collect();
    hyps.sort_by(by_rank);
    hyps.truncate(params.max_hypotheses);
    hyps
}
