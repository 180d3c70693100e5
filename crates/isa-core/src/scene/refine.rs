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

/// Nearest-neighbour lookups within a fixed radius: the points bucketed on a dense grid of
/// cells of that side over their bounds (compressed rows: a start per cell into one index list).
struct RadiusGrid<'a> {
    points: &'a [Vector3<f64>],
    cell: f64,
    lo: Vector3<f64>,
    dims: [i64; 3],
    start: Vec<u32>,
    order: Vec<u32>,
}

impl<'a> RadiusGrid<'a> {
    fn new(points: &'a [Vector3<f64>], radius: f64) -> Self {
        let lo = points
            .iter()
            .fold(Vector3::repeat(f64::INFINITY), |m, p| m.inf(p));
        let hi = points
            .iter()
            .fold(Vector3::repeat(f64::NEG_INFINITY), |m, p| m.sup(p));
        let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / radius).floor() as i64 + 1);
        let n_cells = (dims[0] * dims[1] * dims[2]) as usize;
        let mut g = RadiusGrid {
            points,
            cell: radius,
            lo,
            dims,
            start: vec![0; n_cells + 1],
            order: vec![0; points.len()],
        };
        let keys: Vec<usize> = points
            .iter()
            .map(|p| g.flat(g.key(p)).expect("inside its own bounds"))
            .collect();
        for &k in &keys {
            g.start[k + 1] += 1;
        }
        for c in 0..n_cells {
            g.start[c + 1] += g.start[c];
        }
        let mut fill = g.start.clone();
        for (i, &k) in keys.iter().enumerate() {
            g.order[fill[k] as usize] = i as u32;
            fill[k] += 1;
        }
        g
    }

    fn key(&self, p: &Vector3<f64>) -> [i64; 3] {
        [0, 1, 2].map(|k| floor_i64((p[k] - self.lo[k]) / self.cell))
    }

    fn flat(&self, k: [i64; 3]) -> Option<usize> {
        let inside = (0..3).all(|a| k[a] >= 0 && k[a] < self.dims[a]);
        inside.then(|| ((k[0] * self.dims[1] + k[1]) * self.dims[2] + k[2]) as usize)
    }

    /// The nearest point strictly within the radius: `(index, distance)`; ties to the lower index.
    fn nearest(&self, q: &Vector3<f64>) -> Option<(usize, f64)> {
        if self.points.is_empty() {
            return None;
        }
        let k = self.key(q);
        let mut best: Option<(usize, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(c) = self.flat([k[0] + dx, k[1] + dy, k[2] + dz]) else {
                        continue;
                    };
                    for &i in &self.order[self.start[c] as usize..self.start[c + 1] as usize] {
                        let i = i as usize;
                        let d2 = (self.points[i] - q).norm_squared();
                        if best.is_none_or(|b| d2 < b.1 || (d2 == b.1 && i < b.0)) {
                            best = Some((i, d2));
                        }
                    }
                }
            }
        }
        best.filter(|b| b.1 < self.cell * self.cell)
            .map(|(i, d2)| (i, d2.sqrt()))
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
