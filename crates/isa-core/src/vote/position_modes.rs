//! Position modes: mean-shift on the coarse grid's cell centroids (kernel radius `2h`), then
//! refinement on the raw votes near each coarse mode (kernel radius `h`).

use rayon::prelude::*;

use super::gather::gather;
use super::grid::Grid;
use super::nms::{by_score_then_position, nms_distance};
use super::{dist2, strided, PoseVote, VoteParams};

pub(super) struct PositionMode {
    pub(super) position: [f64; 3],
    pub(super) score: f64,
    pub(super) support: usize,
    /// Indices (into the votes) inside the position kernel, and their weight times kernel.
    pub(super) members: Vec<u32>,
    pub(super) member_weights: Vec<f64>,
}

/// Coarse mean-shift from `start` on cell centroids weighted by cell weight (27 cells per
/// step); returns the mode and the coarse density there. `None` if no centroid is within `h`.
pub(super) fn coarse_mean_shift(
    grid: &Grid,
    start: [f64; 3],
    h: f64,
    max_iter: usize,
) -> Option<([f64; 3], f64)> {
    let h2 = h * h;
    let mut m = start;
    let mut density = 0.0;
    for _ in 0..max_iter {
        let (mut acc, mut ws) = ([0.0f64; 3], 0.0f64);
        density = 0.0;
        grid.for_neighbour_cells(m, |c| {
            let d2 = dist2(c.centroid, m);
            if d2 < h2 {
                let u = 1.0 - d2 / h2;
                let g = c.weight * u;
                ws += g;
                density += g * u;
                for (a, ck) in acc.iter_mut().zip(c.centroid) {
                    *a += g * ck;
                }
            }
        });
        if ws <= 0.0 {
            return None;
        }
        let next = acc.map(|a| a / ws);
        let shift2 = dist2(next, m);
        m = next;
        if shift2 < 1e-4 * h2 {
            break;
        }
    }
    Some((m, density))
}

/// Fine mean-shift on raw votes from a coarse mode: iterations on a strided subsample of at
/// most `refine` of the gathered votes (shift below `0.01 h`), then the density, support and
/// members over all of them. The gathered ball (radius `3h`) is refreshed if the mode drifts
/// more than `2h` from its centre. `near`: the votes within `3h` of `start`. `None` also when
/// the shift comes within the NMS distance of a mode in `known` (it would be suppressed, or
/// converge there; this also ends slow creeps along ridges towards a known mode).
pub(super) fn fine_mean_shift(
    votes: &[PoseVote],
    start: [f64; 3],
    mut near: Vec<u32>,
    h: f64,
    params: &VoteParams,
    known: &[PositionMode],
) -> Option<PositionMode> {
    let h2 = h * h;
    let suppress = nms_distance(params);
    let mut centre = start;
    let mut m = start;
    for _round in 0..4 {
        let sub: Vec<u32> = strided(near.len(), params.refine_votes)
            .map(|j| near[j])
            .collect();
        for _ in 0..params.max_iterations {
            let (mut acc, mut ws) = ([0.0f64; 3], 0.0f64);
            for &j in &sub {
                let v = &votes[j as usize];
                let p = v.position.map(f64::from);
                let d2 = dist2(p, m);
                if d2 < h2 {
                    let g = f64::from(v.weight) * (1.0 - d2 / h2);
                    ws += g;
                    for k in 0..3 {
                        acc[k] += g * p[k];
                    }
                }
            }
            if ws <= 0.0 {
                return None;
            }
            let next = acc.map(|a| a / ws);
            let shift2 = dist2(next, m);
            m = next;
            if known
                .iter()
                .any(|k| dist2(k.position, m) < suppress * suppress)
            {
                return None; // NMS would suppress it (or it would converge to a known mode)
            }
            if shift2 < 1e-4 * h2 {
                break;
            }
        }
        if dist2(m, centre) <= 4.0 * h2 {
            break;
        }
        centre = m;
        near = gather(votes, &[centre], 3.0 * h).pop().unwrap_or_default();
    }
    let (mut score, mut members, mut member_weights) = (0.0f64, Vec::new(), Vec::new());
    for &j in &near {
        let v = &votes[j as usize];
        let d2 = dist2(v.position.map(f64::from), m);
        if d2 < h2 {
            let u = 1.0 - d2 / h2;
            let a = f64::from(v.weight) * u * u;
            score += a;
            members.push(j);
            member_weights.push(a);
        }
    }
    (!members.is_empty()).then_some(PositionMode {
        position: m,
        score,
        support: members.len(),
        members,
        member_weights,
    })
}

/// The position modes of the votes, densest first (before NMS): coarse mean-shift from the
/// heaviest grid cells, the densest distinct coarse modes refined on the raw votes.
pub(super) fn position_modes(votes: &[PoseVote], params: &VoteParams) -> Vec<PositionMode> {
    let h = f64::from(params.position_bandwidth);
    let stride = votes.len().div_ceil(params.coarse_votes).max(1);
    let grid = Grid::build(votes, stride, 2.0 * h);
    if grid.cells.is_empty() {
        return Vec::new();
    }

    // Seeds: the heaviest cells (ties by order of appearance -> deterministic).
    let mut order: Vec<u32> = (0..grid.cells.len() as u32).collect();
    let n_seeds = params.max_seeds.min(order.len());
    let heavier = |a: &u32, b: &u32| {
        grid.cells[*b as usize]
            .weight
            .total_cmp(&grid.cells[*a as usize].weight)
            .then(a.cmp(b))
    };
    if n_seeds < order.len() {
        order.select_nth_unstable_by(n_seeds - 1, heavier);
        order.truncate(n_seeds);
    }
    order.sort_by(heavier);

    let max_iter = params.max_iterations;
    let coarse: Vec<Option<([f64; 3], f64)>> = order
        .par_iter()
        .map(|&c| coarse_mean_shift(&grid, grid.cells[c as usize].centroid, 2.0 * h, max_iter))
        .collect();
    // Seeds that reached the same coarse mode (within h / 2) count once; the densest coarse
    // modes are refined on the raw votes.
    let mut distinct: Vec<([f64; 3], f64)> = Vec::new();
    for (m, dens) in coarse.into_iter().flatten() {
        if distinct.iter().all(|d| dist2(d.0, m) >= 0.25 * h * h) {
            distinct.push((m, dens));
        }
    }
    distinct.sort_by(|a, b| by_score_then_position((a.1, a.0), (b.1, b.0)));
    distinct.truncate(params.refine_modes);
    // Refined densest first; a coarse mode within 2h (or the NMS distance) of a refined one
    // would reach it again (or be suppressed).
    let centres: Vec<[f64; 3]> = distinct.iter().map(|d| d.0).collect();
    let near = gather(votes, &centres, 3.0 * h);
    let mut modes: Vec<PositionMode> = Vec::new();
    for (c, near) in centres.into_iter().zip(near) {
        let skip = (2.0 * h).max(nms_distance(params));
        if modes.iter().any(|m| dist2(m.position, c) < skip * skip) {
            continue;
        }
        if let Some(m) = fine_mean_shift(votes, c, near, h, params, &modes) {
            modes.push(m);
        }
    }
    modes.sort_by(|a, b| by_score_then_position((a.score, a.position), (b.score, b.position)));
    modes
}
