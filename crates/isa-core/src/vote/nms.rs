//! Non-maximum suppression of position modes, and the deterministic ranking order.

use super::position_modes::PositionMode;
use super::{dist2, Hypothesis, VoteParams};

/// Position modes closer than this to a stronger one are suppressed: `max(nms_radius, h / 4)`.
pub(super) fn nms_distance(params: &VoteParams) -> f64 {
    f64::from(params.nms_radius).max(0.25 * f64::from(params.position_bandwidth))
}

/// Orders by score, highest first; ties by position (total order on floats), so sorting is
/// deterministic whatever the input order.
pub(super) fn by_score_then_position(a: (f64, [f64; 3]), b: (f64, [f64; 3])) -> std::cmp::Ordering {
    b.0.total_cmp(&a.0)
        .then_with(|| a.1[0].total_cmp(&b.1[0]))
        .then_with(|| a.1[1].total_cmp(&b.1[1]))
        .then_with(|| a.1[2].total_cmp(&b.1[2]))
}

/// The position modes (sorted best first) that no stronger kept mode is within
/// [`nms_distance`] of, at most `2 max_hypotheses` (and `max_hypotheses + 2`) of them: a position
/// may still lose all its rotation modes to `min_support`.
pub(super) fn suppress(modes: Vec<PositionMode>, params: &VoteParams) -> Vec<PositionMode> {
    let r = nms_distance(params);
    let keep_positions = params
        .max_hypotheses
        .saturating_mul(2)
        .max(params.max_hypotheses + 2);
    let mut kept: Vec<PositionMode> = Vec::new();
    for m in modes {
        if kept.len() >= keep_positions {
            break;
        }
        if kept.iter().all(|k| dist2(k.position, m.position) >= r * r) {
            kept.push(m);
        }
    }
    kept
}

/// Ranking of hypotheses: by score, then position, then quaternion (a total order).
pub(super) fn by_rank(a: &Hypothesis, b: &Hypothesis) -> std::cmp::Ordering {
    by_score_then_position((a.score, a.translation), (b.score, b.translation)).then_with(|| {
        a.quaternion
            .iter()
            .zip(&b.quaternion)
            .fold(std::cmp::Ordering::Equal, |o, (x, y)| {
                o.then(x.total_cmp(y))
            })
    })
}
