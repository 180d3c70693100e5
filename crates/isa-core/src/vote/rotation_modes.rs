//! Rotation modes among the votes of one position mode: a biweight kernel on SO(3), a
//! medoid-like start among strided candidates, then mean-shift on the sphere of quaternions
//! with every vote's sign aligned to the current estimate.

use super::{strided, VoteParams};
use crate::rotation::{canonical, dot4, quat_angle};

/// Biweight kernel on SO(3) expressed through `c = |q·p|` (cos of half the angle), so no `acos`:
/// `u = (1 - c²) / (1 - cos²(θ_h / 2))` = `sin²(θ/2) / sin²(θ_h/2)`, inside the kernel iff `u < 1`.
pub(super) struct RotKernel {
    inv_denom: f64,
}

impl RotKernel {
    fn new(bandwidth: f64) -> Self {
        let ch = (bandwidth / 2.0).cos();
        Self {
            inv_denom: 1.0 / (1.0 - ch * ch).max(1e-300),
        }
    }
    /// `1 - u` (the mean-shift weight profile, <= 0 outside the kernel) and `q·p`.
    #[inline]
    fn g(&self, q: [f64; 4], p: [f64; 4]) -> (f64, f64) {
        let d = dot4(q, p);
        let c = d.abs().min(1.0);
        (1.0 - (1.0 - c * c) * self.inv_denom, d)
    }
}

pub(super) struct RotationMode {
    pub(super) q: [f64; 4],
    pub(super) score: f64,
    pub(super) support: usize,
}

/// Rotation modes among the unit quaternions `quats` with weights `a`.
pub(super) fn rotation_modes(
    quats: &[[f64; 4]],
    a: &[f64],
    params: &VoteParams,
) -> Vec<RotationMode> {
    let n = quats.len();
    if n == 0 {
        return Vec::new();
    }
    let kern = RotKernel::new(f64::from(params.rotation_bandwidth));
    let eval: Vec<usize> = strided(n, params.rotation_eval_votes).collect();
    let refine: Vec<usize> = strided(n, params.refine_votes).collect();
    let mut cands: Vec<(f64, usize)> = strided(n, params.rotation_candidates)
        .map(|ci| {
            let c = quats[ci];
            let dens: f64 = eval
                .iter()
                .map(|&e| {
                    let (g, _) = kern.g(c, quats[e]);
                    if g > 0.0 {
                        a[e] * g * g
                    } else {
                        0.0
                    }
                })
                .sum();
            (dens, ci)
        })
        .collect();
    cands.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));

    // Mean-shift over the members `set` until the rotation stops moving.
    let shift = |start: [f64; 4], set: &[usize]| -> [f64; 4] {
        let mut q = start;
        for _ in 0..params.max_iterations {
            let mut acc = [0.0f64; 4];
            let mut ws = 0.0;
            for &i in set {
                let p = quats[i];
                let (g, d) = kern.g(q, p);
                if g > 0.0 {
                    let w = a[i] * g * d.signum();
                    ws += a[i] * g;
                    for k in 0..4 {
                        acc[k] += w * p[k];
                    }
                }
            }
            let norm = dot4(acc, acc).sqrt();
            if ws <= 0.0 || norm <= 1e-300 {
                break;
            }
            let next = acc.map(|v| v / norm);
            let moved = 1.0 - dot4(next, q).abs();
            q = next;
            if moved < 1e-12 {
                break;
            }
        }
        q
    };

    let mut modes: Vec<RotationMode> = Vec::new();
    let min_sep = f64::from(params.rotation_bandwidth);
    for &(_, ci) in &cands {
        if modes.len() >= params.rotations_per_position {
            break;
        }
        let start = quats[ci];
        if modes.iter().any(|m| quat_angle(m.q, start) < min_sep) {
            continue;
        }
        // Converge on the evaluation subsample first (cheap), then on the refinement subsample.
        let q = shift(shift(start, &eval), &refine);
        if modes.iter().any(|m| quat_angle(m.q, q) < 0.5 * min_sep) {
            continue;
        }
        let (mut score, mut support) = (0.0f64, 0usize);
        for i in 0..n {
            let (g, _) = kern.g(q, quats[i]);
            if g > 0.0 {
                score += a[i] * g * g;
                support += 1;
            }
        }
        modes.push(RotationMode {
            q: canonical(q),
            score,
            support,
        });
    }
    modes
}
