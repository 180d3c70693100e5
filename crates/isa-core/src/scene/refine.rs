//! Refinement (as `isa.detection.refine`): ICP of a shape onto the observed points around a
//! hypothesis, the object kept upright (yaw about gravity and a translation). Pairs go from the
//! observed points to the nearest visible shape sample (a hash grid of the trimming distance),
//! trimmed at a distance falling geometrically; each step is linearised point-to-plane least
//! squares (with normals) or the closed-form 2D Procrustes yaw and mean shift.

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

use super::verify::visible_points;
use super::{floor_i64, rot_z, yaw_of, Camera, Frame};
use crate::params::RefineParams;

/// The refined pose (object to camera), the RMS distance of the last pairs and their count, the
/// yaw change (radians) and shift (metres) against the start, and whether it converged.
// Plain fields (`duplicates` pairs them by shape with `DetectParams`'; nothing shared).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refinement {
    pub r: Matrix3<f64>,
    pub t: Vector3<f64>,
    pub rms: f64,
    pub pairs: usize,
    pub yaw_change: f64,
    pub shift: f64,
    pub converged: bool,
}

/// Upright-frame points of the valid pixels on a `stride` grid, leaving out those less than
/// `clearance` above `floor` (when given).
pub fn upright_points(
    frame: &Frame<'_>,
    r_gravity: &Matrix3<f64>,
    stride: usize,
    floor: Option<f64>,
    clearance: f64,
) -> Vec<Vector3<f64>> {
    let cam = &frame.camera;
    let mut out = Vec::new();
    for v in (0..cam.height).step_by(stride) {
        for u in (0..cam.width).step_by(stride) {
            let z = frame.depth[v * cam.width + u];
            if z > 0.0 {
                let p = cam.k.back_project(u as f64, v as f64, f64::from(z));
                let q = r_gravity * Vector3::new(p[0], p[1], p[2]);
                if floor.is_none_or(|f| q.z > f + clearance) {
                    out.push(q);
                }
            }
        }
    }
    out
}

/// Nearest-neighbour lookups within a fixed radius: the points bucketed in vertical columns
/// of a dense 2D grid (side `radius`) over their bounds, each column's points sorted by height,
/// so a query tests only the 3 x 3 columns around its own and, in each, only the points whose
/// height is within its best distance so far (scanned outward from its height). Finer columns
/// were slower: each column visited costs a bisection.
struct RadiusGrid {
    radius: f64,
    cell: f64,
    lo: [f64; 2],
    dims: [i64; 2],
    /// Start of each column in the sorted arrays (compressed rows).
    start: Vec<u32>,
    z: Vec<f64>,
    points: Vec<Vector3<f64>>,
    ids: Vec<u32>,
}

impl RadiusGrid {
    fn new(points: &[Vector3<f64>], radius: f64) -> Self {
        let cell = radius;
        let lo = points
            .iter()
            .fold([f64::INFINITY; 2], |m, p| [m[0].min(p.x), m[1].min(p.y)]);
        let hi = points.iter().fold([f64::NEG_INFINITY; 2], |m, p| {
            [m[0].max(p.x), m[1].max(p.y)]
        });
        let dims = [0, 1].map(|k| ((hi[k] - lo[k]) / cell).floor() as i64 + 1);
        let n_cols = if points.is_empty() {
            0
        } else {
            (dims[0] * dims[1]) as usize
        };
        let mut g = RadiusGrid {
            radius,
            cell,
            lo,
            dims,
            start: vec![0; n_cols + 1],
            z: Vec::with_capacity(points.len()),
            points: Vec::with_capacity(points.len()),
            ids: Vec::new(),
        };
        let keys: Vec<usize> = points
            .iter()
            .map(|p| {
                let k = g.key(p);
                (k[0] * g.dims[1] + k[1]) as usize
            })
            .collect();
        for &k in &keys {
            g.start[k + 1] += 1;
        }
        for c in 0..n_cols {
            g.start[c + 1] += g.start[c];
        }
        let mut fill = g.start.clone();
        let mut by_col = vec![(0.0f64, 0u32); points.len()];
        for (i, &k) in keys.iter().enumerate() {
            by_col[fill[k] as usize] = (points[i].z, i as u32);
            fill[k] += 1;
        }
        for c in 0..n_cols {
            let col = &mut by_col[g.start[c] as usize..g.start[c + 1] as usize];
            if col.len() > 1 {
                col.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            }
        }
        for &(z, i) in &by_col {
            g.z.push(z);
            g.points.push(points[i as usize]);
        }
        g.ids = by_col.into_iter().map(|(_, i)| i).collect();
        g
    }

    fn key(&self, p: &Vector3<f64>) -> [i64; 2] {
        [0, 1].map(|k| floor_i64((p[k] - self.lo[k]) / self.cell))
    }

    /// The nearest point strictly within the radius: `(index, distance)`; ties to the lower
    /// index. The query's own column first; a column or height range farther than the best
    /// distance so far (or the radius) is skipped, with a margin for rounding, so the answer is
    /// that of testing every point.
    fn nearest(&self, q: &Vector3<f64>) -> Option<(usize, f64)> {
        if self.points.is_empty() {
            return None;
        }
        let r2 = self.radius * self.radius;
        let k = self.key(q);
        // The query's distance to the columns one step left / on / right of its own, per axis.
        let gaps = |a: usize| {
            [-1, 0, 1].map(|d| {
                let base = self.lo[a] + (k[a] + d) as f64 * self.cell;
                (base - q[a]).max(q[a] - (base + self.cell)).max(0.0)
            })
        };
        let (gx, gy) = (gaps(0), gaps(1));
        // (index, squared distance); no index yet: usize::MAX, infinitely far.
        let mut best = (usize::MAX, f64::INFINITY);
        // The own column first, then the sides, then the corners: the best distance shrinks
        // early and prunes the rest.
        const ORDER: [(i64, i64); 9] = [
            (0, 0),
            (-1, 0),
            (1, 0),
            (0, -1),
            (0, 1),
            (-1, -1),
            (-1, 1),
            (1, -1),
            (1, 1),
        ];
        for (dx, dy) in ORDER {
            let (cx, cy) = (k[0] + dx, k[1] + dy);
            if cx < 0 || cy < 0 || cx >= self.dims[0] || cy >= self.dims[1] {
                continue;
            }
            let c = (cx * self.dims[1] + cy) as usize;
            let (s, e) = (self.start[c] as usize, self.start[c + 1] as usize);
            if s == e {
                continue;
            }
            let (ax, ay) = (gx[(dx + 1) as usize], gy[(dy + 1) as usize]);
            let box2 = ax * ax + ay * ay;
            if box2 - best.1.min(r2) > 1e-9 * box2 + 1e-12 {
                continue;
            }
            // Outward from the query's height, up then down, until the height difference alone
            // exceeds the best distance so far (which only shrinks): every point left out is
            // farther than one already seen.
            let within = |dz: f64, best: f64| {
                let bound = best.min(r2) - box2;
                dz * dz - bound <= 1e-9 * bound.abs() + 1e-12
            };
            let visit = |j: usize, best: &mut (usize, f64)| {
                let d2 = (self.points[j] - q).norm_squared();
                let i = self.ids[j] as usize;
                if d2 < best.1 || (d2 == best.1 && i < best.0) {
                    *best = (i, d2);
                }
            };
            let mid = s + self.z[s..e].partition_point(|&z| z < q.z);
            for j in mid..e {
                if !within(self.z[j] - q.z, best.1) {
                    break;
                }
                visit(j, &mut best);
            }
            for j in (s..mid).rev() {
                if !within(q.z - self.z[j], best.1) {
                    break;
                }
                visit(j, &mut best);
            }
        }
        (best.1 < r2).then(|| (best.0, best.1.sqrt()))
    }
}

/// Refines `(r, t)` of a shape (object-frame `points`, `normals` or none, `bounds`) on the
/// observed upright points `obs_up` ([`upright_points`], the floor left out).
#[allow(clippy::too_many_arguments)]
pub fn refine_pose(
    obs_up: &[Vector3<f64>],
    cam: &Camera,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    points: &[Vector3<f64>],
    normals: Option<&[Vector3<f64>]>,
    bounds: [[f64; 3]; 2],
    rg: &Matrix3<f64>,
    p: &RefineParams,
) -> Refinement {
    let mut a = rg * r;
    let mut b = rg * t;
    let lo = Vector3::from(bounds[0]);
    let hi = Vector3::from(bounds[1]);
    let centre_obj = (lo + hi) / 2.0;
    let half = (hi - lo) / 2.0 + Vector3::repeat(p.margin);
    let yaw0 = yaw_of(&a);
    let c_up = a * centre_obj + b;
    let (s, c) = yaw0.sin_cos();
    let near: Vec<Vector3<f64>> = obs_up
        .iter()
        .filter(|q| {
            let d = *q - c_up;
            (d.x * c + d.y * s).abs() <= half.x
                && (d.y * c - d.x * s).abs() <= half.y
                && d.z.abs() <= half.z
        })
        .copied()
        .collect();
    let obs: Vec<Vector3<f64>> = if near.len() > p.max_points {
        let m = p.max_points;
        (0..m)
            .map(|j| {
                near[if m == 1 {
                    0
                } else {
                    (j as f64 * (near.len() - 1) as f64 / (m - 1) as f64) as usize
                }]
            })
            .collect()
    } else {
        near
    };
    let unchanged = |rms: f64, pairs: usize, yaw: f64, shift: f64| Refinement {
        r: *r,
        t: *t,
        rms,
        pairs,
        yaw_change: yaw,
        shift,
        converged: false,
    };
    if obs.len() < p.min_pairs {
        return unchanged(f64::INFINITY, obs.len(), 0.0, 0.0);
    }
    let (mut rms, mut n_pairs, mut converged) = (f64::INFINITY, 0usize, false);
    let n_it = p.iterations;
    let ratio = p.min_distance / p.max_distance;
    for it in 0..n_it {
        let dmax = if n_it == 1 {
            p.max_distance
        } else {
            p.max_distance * ratio.powf(it as f64 / (n_it - 1) as f64)
        };
        let model_up_all: Vec<Vector3<f64>> = points.iter().map(|q| a * q + b).collect();
        let model_cam: Vec<Vector3<f64>> =
            model_up_all.iter().map(|q| rg.transpose() * q).collect();
        let idx: Vec<usize> = visible_points(&model_cam, cam, p.cell_px as i64, 0.0)
            .into_iter()
            .map(|v| v.0)
            .collect();
        if idx.len() < p.min_pairs {
            break;
        }
        let model_up: Vec<Vector3<f64>> = idx.iter().map(|&i| model_up_all[i]).collect();
        let grid = RadiusGrid::new(&model_up, dmax);
        let pairs: Vec<(usize, usize, f64)> = obs
            .iter()
            .enumerate()
            .filter_map(|(o, q)| grid.nearest(q).map(|(j, d)| (o, j, d)))
            .collect();
        n_pairs = pairs.len();
        if n_pairs < p.min_pairs {
            break;
        }
        rms = (pairs.iter().map(|x| x.2 * x.2).sum::<f64>() / n_pairs as f64).sqrt();
        let cq = pairs
            .iter()
            .fold(Vector3::zeros(), |s, x| s + model_up[x.1])
            / n_pairs as f64;
        let (dyaw, mut shift) = match normals {
            Some(nrm) => {
                let mut jtj = Matrix4::zeros();
                let mut jtr = Vector4::zeros();
                for &(o, j, _) in &pairs {
                    let q = model_up[j] - cq;
                    let pp = obs[o] - cq;
                    let n = a * nrm[idx[j]];
                    let row = Vector4::new(n.x * -q.y + n.y * q.x, n.x, n.y, n.z);
                    jtj += row * row.transpose();
                    jtr += row * n.dot(&(pp - q));
                }
                jtj += Matrix4::identity() * (1e-6 * n_pairs as f64);
                let x = jtj.lu().solve(&jtr).unwrap_or_else(Vector4::zeros);
                (x[0], Vector3::new(x[1], x[2], x[3]))
            }
            None => {
                let pc = pairs.iter().fold(Vector3::zeros(), |s, x| s + obs[x.0]) / n_pairs as f64;
                let (mut cross, mut dot) = (0.0, 0.0);
                for &(o, j, _) in &pairs {
                    let dp = obs[o] - pc;
                    let dq = model_up[j] - cq;
                    cross += dq.x * dp.y - dq.y * dp.x;
                    dot += dq.x * dp.x + dq.y * dp.y;
                }
                (cross.atan2(dot), pc - cq)
            }
        };
        let rz = rot_z(dyaw);
        shift += cq - rz * cq;
        if p.fix_height {
            shift.z = 0.0;
        }
        a = rz * a;
        b = rz * b + shift;
        if dyaw.abs() < 1e-4 && shift.norm() < 1e-4 && it >= n_it / 2 {
            converged = true;
            break;
        }
    }
    let dy = yaw_of(&a) - yaw0;
    let yaw_change = dy.sin().atan2(dy.cos());
    let shift_total = ((a * centre_obj + b) - rg * (r * centre_obj + t)).norm();
    if yaw_change.to_degrees().abs() > p.max_yaw_deg || shift_total > p.max_shift {
        return unchanged(rms, n_pairs, yaw_change, shift_total);
    }
    let rg_inv = rg.try_inverse().unwrap_or_else(|| rg.transpose());
    Refinement {
        r: rg_inv * a,
        t: rg_inv * b,
        rms,
        pairs: n_pairs,
        yaw_change,
        shift: shift_total,
        converged,
    }
}

#[cfg(test)]
mod tests {
    use super::super::shapes::tests::box_library;
    use super::super::verify::tests::box_scene;
    use super::*;

    /// The column grid answers as testing every point: nearest within the radius, ties to the
    /// lower index (duplicated points), queries inside, on and outside the points' bounds.
    #[test]
    fn nearest_is_the_brute_force_answer() {
        let mut state = 7u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        // A surface-like cloud (a box's faces, coarse coordinates so distances tie) and copies.
        let mut pts: Vec<Vector3<f64>> = (0..1500)
            .map(|_| {
                let mut p = Vector3::new(rnd() * 2.0, rnd() * 0.8, rnd());
                p[(rnd() * 3.0) as usize] = if rnd() < 0.5 { 0.0 } else { 1.0 };
                p.map(|x| (x * 64.0).round() / 64.0)
            })
            .collect();
        pts.extend(pts[..200].to_vec());
        for radius in [0.15, 0.07, 0.03, 1.0 / 64.0] {
            let grid = RadiusGrid::new(&pts, radius);
            for _ in 0..2000 {
                let q = Vector3::new(rnd() * 2.6 - 0.3, rnd() * 1.4 - 0.3, rnd() * 1.6 - 0.3).map(
                    |x| {
                        if rnd() < 0.3 {
                            (x * 64.0).round() / 64.0
                        } else {
                            x
                        }
                    },
                );
                let mut want: Option<(usize, f64)> = None;
                for (i, p) in pts.iter().enumerate() {
                    let d2 = (p - q).norm_squared();
                    if d2 < radius * radius && want.is_none_or(|b| d2 < b.1) {
                        want = Some((i, d2));
                    }
                }
                assert_eq!(
                    grid.nearest(&q),
                    want.map(|(i, d2)| (i, d2.sqrt())),
                    "{q:?} {radius}"
                );
            }
        }
        assert_eq!(RadiusGrid::new(&[], 0.1).nearest(&Vector3::zeros()), None);
    }

    #[test]
    fn a_known_small_offset_is_recovered() {
        let size = [0.5, 1.0, 1.5];
        let lib = box_library(size, 24);
        let (depth, cam, r, t, rg) = box_scene(size, 0.4);
        let frame = Frame::new(&depth, cam).unwrap();
        let obs = upright_points(&frame, &rg, 2, Some(-1.2), 0.02);
        let pts: Vec<Vector3<f64>> = lib
            .points_of(0)
            .iter()
            .map(|q| Vector3::new(q[0].into(), q[1].into(), q[2].into()))
            .collect();
        let nrm: Vec<Vector3<f64>> = lib
            .normals_of(0)
            .iter()
            .map(|q| Vector3::new(q[0].into(), q[1].into(), q[2].into()))
            .collect();
        for (dyaw, dx, dy) in [(8f64, 0.05, -0.04), (-12.0, -0.08, 0.03)] {
            let r0 = rg.transpose() * rot_z(dyaw.to_radians()) * rg * r;
            let t0 = t + rg.transpose() * Vector3::new(dx, dy, 0.0);
            for normals in [Some(&nrm[..]), None] {
                let p = RefineParams {
                    fix_height: true,
                    iterations: 15,
                    ..Default::default()
                };
                let out = refine_pose(&obs, &cam, &r0, &t0, &pts, normals, lib.bounds[0], &rg, &p);
                let err = ((out.r.transpose() * r).trace() - 1.0).clamp(-2.0, 2.0) / 2.0;
                // point-to-point is biased by the samples' grid; point-to-plane is not
                let (dt, da) = if normals.is_some() {
                    (0.01, 1.0)
                } else {
                    (0.02, 3.0)
                };
                assert!(
                    (out.t - t).norm() < dt,
                    "{dyaw} {normals:?} {out:?}",
                    normals = normals.is_some()
                );
                assert!(
                    err.acos().to_degrees() < da,
                    "{dyaw} {}: {}",
                    normals.is_some(),
                    err.acos().to_degrees()
                );
            }
        }
        // a move over the limit keeps the start
        let t0 = t + rg.transpose() * Vector3::new(0.25, 0.0, 0.0);
        let p = RefineParams {
            max_shift: 0.05,
            ..Default::default()
        };
        let out = refine_pose(
            &obs,
            &cam,
            &r,
            &t0,
            &pts,
            Some(&nrm),
            lib.bounds[0],
            &rg,
            &p,
        );
        assert_eq!((out.t, out.converged), (t0, false));
    }
}
