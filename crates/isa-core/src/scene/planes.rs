//! The floor and walls of a frame in its upright frame (as `isa.detection.planes`): the floor
//! one height searched along gravity, walls by gravity-constrained RANSAC (vertical planes
//! through two sampled points), refined by least squares, accepted when their largest connected
//! patch spans a wall's height and width. Seeded; the samples differ from numpy's.

use nalgebra::{Matrix2, Vector2, Vector3};
use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{median, percentile, Frame};
use crate::params::PlaneParams;

/// Kind of a plane.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlaneKind {
    Floor,
    Wall,
}

/// A plane `normal . x + offset = 0` of the upright frame; `inliers` its pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    pub kind: PlaneKind,
    pub normal: [f64; 3],
    pub offset: f64,
    pub inliers: usize,
}

/// What plane removal found: the planes (floor first) and the pixels on them (or under the
/// floor), to be set to missing for the voting.
#[derive(Clone, Debug, PartialEq)]
pub struct Planes {
    pub planes: Vec<Plane>,
    pub removed: Vec<bool>,
}

impl Planes {
    /// The floor's height in the upright frame, when one was found.
    pub fn floor_height(&self) -> Option<f64> {
        self.planes
            .iter()
            .find(|p| p.kind == PlaneKind::Floor)
            .map(|p| -p.offset)
    }

    /// `depth` with the removed pixels set to 0.
    pub fn clean(&self, depth: &[f32]) -> Vec<f32> {
        depth
            .iter()
            .zip(&self.removed)
            .map(|(&d, &r)| if r { 0.0 } else { d })
            .collect()
    }
}

fn subsample(rng: &mut ChaCha8Rng, n: usize, k: usize) -> Vec<usize> {
    if n > k {
        sample(rng, n, k).into_vec()
    } else {
        (0..n).collect()
    }
}

fn find_floor(z: &[f64], tol: &[f64], p: &PlaneParams, rng: &mut ChaCha8Rng) -> Option<f64> {
    if z.is_empty() {
        return None;
    }
    let idx = subsample(rng, z.len(), p.samples);
    let zs_orig: Vec<f64> = idx.iter().map(|&i| z[i]).collect();
    let ts: Vec<f64> = idx.iter().map(|&i| tol[i]).collect();
    let lo = percentile(&mut zs_orig.clone(), 0.5);
    let n_h = ((p.floor_search + 0.05) / 0.01).ceil() as usize;
    let mut best: Option<(usize, f64)> = None;
    for j in 0..n_h {
        let h = lo - 0.05 + 0.01 * j as f64;
        if h > -p.min_floor_drop || h >= lo + p.floor_search {
            continue;
        }
        let s = zs_orig
            .iter()
            .zip(&ts)
            .filter(|(z, t)| (*z - h).abs() < **t)
            .count();
        if best.is_none_or(|b| s > b.0) {
            best = Some((s, h));
        }
    }
    let (s, h) = best?;
    if (s as f64) < p.min_floor_fraction * zs_orig.len() as f64 {
        return None;
    }
    let mut on: Vec<f64> = z
        .iter()
        .zip(tol)
        .filter(|(z, t)| (*z - h).abs() < **t)
        .map(|(z, _)| *z)
        .collect();
    Some(median(&mut on))
}

/// Whether points on a vertical plane with this normal span a wall's height and width.
fn wall_extent(pts: &[Vector3<f64>], n: Vector2<f64>, p: &PlaneParams) -> bool {
    if pts.len() < 3 {
        return false;
    }
    let mut z: Vec<f64> = pts.iter().map(|q| q.z).collect();
    let mut along: Vec<f64> = pts.iter().map(|q| q.x * -n.y + q.y * n.x).collect();
    let zr = percentile(&mut z, 98.0) - percentile(&mut z, 2.0);
    let ar = percentile(&mut along, 98.0) - percentile(&mut along, 2.0);
    zr >= p.min_wall_height && ar >= p.min_wall_width
}

/// Of the points `along`/`z` (the inliers, in the plane's own coordinates), those in the largest
/// connected patch of a `cell` grid (cells with `min_points`, closed once with a cross, joined
/// 8-connected, weighed by their points).
fn largest_patch(along: &[f64], z: &[f64], cell: f64, min_points: usize) -> Vec<bool> {
    if along.is_empty() {
        return vec![];
    }
    let amin = along.iter().copied().fold(f64::INFINITY, f64::min);
    let zmin = z.iter().copied().fold(f64::INFINITY, f64::min);
    let a: Vec<usize> = along
        .iter()
        .map(|x| ((x - amin) / cell) as usize) // >= 0: truncation is the floor
        .collect();
    let b: Vec<usize> = z.iter().map(|x| ((x - zmin) / cell) as usize).collect();
    let (na, nb) = (a.iter().max().unwrap() + 1, b.iter().max().unwrap() + 1);
    let mut counts = vec![0usize; na * nb];
    for (i, j) in a.iter().zip(&b) {
        counts[i * nb + j] += 1;
    }
    let occ: Vec<bool> = counts.iter().map(|&c| c >= min_points).collect();
    let cross = |g: &[bool], i: usize, j: usize, outside: bool, any: bool| -> bool {
        let at = |di: isize, dj: isize| {
            let (ii, jj) = (i as isize + di, j as isize + dj);
            if ii < 0 || jj < 0 || ii >= na as isize || jj >= nb as isize {
                outside
            } else {
                g[ii as usize * nb + jj as usize]
            }
        };
        let n = [at(0, 0), at(-1, 0), at(1, 0), at(0, -1), at(0, 1)];
        if any {
            n.iter().any(|x| *x)
        } else {
            n.iter().all(|x| *x)
        }
    };
    // scipy's binary_closing: dilation (outside = 0), then erosion (outside = 0), or'ed with
    // the cells themselves.
    let dil: Vec<bool> = (0..na * nb)
        .map(|c| cross(&occ, c / nb, c % nb, false, true))
        .collect();
    let closed: Vec<bool> = (0..na * nb)
        .map(|c| cross(&dil, c / nb, c % nb, false, false) || occ[c])
        .collect();
    // 8-connected labels in raster order.
    let mut label = vec![0usize; na * nb];
    let mut weights: Vec<usize> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..na * nb {
        if !closed[start] || label[start] != 0 {
            continue;
        }
        weights.push(0);
        let l = weights.len();
        label[start] = l;
        stack.push(start);
        while let Some(c) = stack.pop() {
            weights[l - 1] += counts[c];
            let (i, j) = ((c / nb) as isize, (c % nb) as isize);
            for di in -1..=1 {
                for dj in -1..=1 {
                    let (ii, jj) = (i + di, j + dj);
                    if ii < 0 || jj < 0 || ii >= na as isize || jj >= nb as isize {
                        continue;
                    }
                    let n = ii as usize * nb + jj as usize;
                    if closed[n] && label[n] == 0 {
                        label[n] = l;
                        stack.push(n);
                    }
                }
            }
        }
    }
    if weights.is_empty() {
        return vec![false; along.len()];
    }
    let best = 1 + (0..weights.len()).fold(0, |m, k| if weights[k] > weights[m] { k } else { m });
    a.iter()
        .zip(&b)
        .map(|(i, j)| label[i * nb + j] == best)
        .collect()
}

/// Refines a vertical plane on the samples and accepts it if it is a wall (first on the check
/// subset, then on every point): `(normal, offset, inlier mask over pts)`.
#[allow(clippy::too_many_arguments)]
fn check_wall(
    pts: &[Vector3<f64>],
    tol: &[f64],
    ps: &[Vector3<f64>],
    ts: &[f64],
    check: &[usize],
    mut n: Vector2<f64>,
    mut off: f64,
    p: &PlaneParams,
    n_total: usize,
) -> Option<(Vector2<f64>, f64, Vec<bool>)> {
    let dist = |q: &Vector3<f64>, n: &Vector2<f64>, off: f64| (q.x * n.x + q.y * n.y + off).abs();
    let mut on_s: Vec<Vector3<f64>> = Vec::new();
    for _ in 0..2 {
        on_s = ps
            .iter()
            .zip(ts)
            .filter(|(q, t)| dist(q, &n, off) < **t)
            .map(|(q, _)| *q)
            .collect();
        if on_s.len() < 3 {
            return None;
        }
        let c = on_s.iter().fold(Vector2::zeros(), |s, q| s + q.xy()) / on_s.len() as f64;
        let mut cov = Matrix2::zeros();
        for q in &on_s {
            let d = q.xy() - c;
            cov += d * d.transpose();
        }
        let e = cov.symmetric_eigen();
        let k = if e.eigenvalues[0] <= e.eigenvalues[1] {
            0
        } else {
            1
        };
        n = e.eigenvectors.column(k).into();
        off = -c.dot(&n);
    }
    if !wall_extent(&on_s, n, p) {
        return None;
    }
    let full: Vec<usize> = (0..pts.len()).collect();
    let mut result = None;
    for (sel, min_points) in [(check, 1usize), (&full[..], 3usize)] {
        let on_idx: Vec<usize> = sel
            .par_iter()
            .copied()
            .filter(|&i| dist(&pts[i], &n, off) < tol[i])
            .collect();
        let along: Vec<f64> = on_idx
            .iter()
            .map(|&i| pts[i].x * -n.y + pts[i].y * n.x)
            .collect();
        let z: Vec<f64> = on_idx.iter().map(|&i| pts[i].z).collect();
        let keep = largest_patch(&along, &z, 0.1, min_points);
        let kept: Vec<usize> = on_idx
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(i, _)| *i)
            .collect();
        let kp: Vec<Vector3<f64>> = kept.iter().map(|&i| pts[i]).collect();
        if (kept.len() as f64)
            < p.min_wall_fraction * n_total as f64 * sel.len() as f64 / pts.len() as f64
            || !wall_extent(&kp, n, p)
        {
            return None;
        }
        let mut mask = vec![false; pts.len()];
        for i in kept {
            mask[i] = true;
        }
        result = Some(mask);
    }
    result.map(|m| (n, off, m))
}

fn find_wall(
    pts: &[Vector3<f64>],
    tol: &[f64],
    p: &PlaneParams,
    rng: &mut ChaCha8Rng,
    n_total: usize,
) -> Option<(Vector2<f64>, f64, Vec<bool>)> {
    let n = pts.len();
    if n < 3 {
        return None;
    }
    let idx = subsample(rng, n, p.samples);
    let ps: Vec<Vector3<f64>> = idx.iter().map(|&i| pts[i]).collect();
    let ts: Vec<f64> = idx.iter().map(|&i| tol[i]).collect();
    // The pairs drawn first (the generator's sequence), then scored in parallel.
    let pairs: Vec<(usize, usize)> = (0..p.ransac_iterations)
        .map(|_| (rng.random_range(0..ps.len()), rng.random_range(0..ps.len())))
        .collect();
    let hyps: Vec<(usize, Vector2<f64>, f64)> = pairs
        .par_iter()
        .filter_map(|&(i, j)| {
            let d = ps[j].xy() - ps[i].xy();
            let len = d.norm();
            if len <= 0.2 {
                return None; // two close points fix a direction badly
            }
            let nrm = Vector2::new(-d.y, d.x) / len;
            let off = -nrm.dot(&ps[i].xy());
            let score = ps
                .iter()
                .zip(&ts)
                .filter(|(q, t)| (q.x * nrm.x + q.y * nrm.y + off).abs() < **t)
                .count();
            Some((score, nrm, off))
        })
        .collect();
    let mut check = subsample(rng, n, p.check_samples);
    check.sort_unstable();
    let mut order: Vec<usize> = (0..hyps.len()).collect();
    order.sort_by(|&a, &b| hyps[b].0.cmp(&hyps[a].0));
    let mut tried: Vec<(Vector2<f64>, f64)> = Vec::new();
    let min_score = p.min_wall_fraction * ps.len() as f64 * n_total as f64 / n as f64;
    for k in order {
        let (score, nrm, off) = hyps[k];
        if tried.len() >= p.wall_candidates || (score as f64) < min_score {
            break;
        }
        if tried.iter().any(|(nn, oo)| {
            nrm.dot(nn).abs() > 0.995 && (off - oo * nrm.dot(nn).signum()).abs() < 0.15
        }) {
            continue;
        }
        tried.push((nrm, off));
        if let Some(w) = check_wall(pts, tol, &ps, &ts, &check, nrm, off, p, n_total) {
            return Some(w);
        }
    }
    None
}

/// The floor (and everything under it) and walls of `frame` seen through `r_gravity`; `floor`
/// / `walls` false skip that kind.
pub fn find_planes(
    frame: &Frame<'_>,
    r_gravity: &nalgebra::Matrix3<f64>,
    p: &PlaneParams,
    floor: bool,
    walls: bool,
) -> Planes {
    let (cam, pix) = frame.points();
    let up: Vec<Vector3<f64>> = cam.par_iter().map(|q| r_gravity * q).collect();
    let [base, k] = p.tolerance;
    let tol: Vec<f64> = cam.par_iter().map(|q| base.max(k * q.z * q.z)).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    // -1 none, -2 under the floor, else the plane's index
    let mut labels = vec![-1i64; up.len()];
    let mut planes = Vec::new();
    let z: Vec<f64> = up.par_iter().map(|q| q.z).collect();
    if let Some(h) = find_floor(&z, &tol, p, &mut rng).filter(|_| floor) {
        labels
            .par_iter_mut()
            .zip(&z)
            .zip(&tol)
            .for_each(|((l, &zi), &ti)| {
                let dz = zi - h;
                if dz.abs() < ti {
                    *l = 0;
                } else if dz <= -ti {
                    *l = -2;
                }
            });
        let n_on = labels.par_iter().filter(|&&l| l == 0).count();
        planes.push(Plane {
            kind: PlaneKind::Floor,
            normal: [0.0, 0.0, 1.0],
            offset: -h,
            inliers: n_on,
        });
    }
    for _ in 0..if walls { p.max_walls } else { 0 } {
        let free: Vec<usize> = (0..up.len())
            .into_par_iter()
            .filter(|&i| labels[i] == -1)
            .collect();
        let fp: Vec<Vector3<f64>> = free.par_iter().map(|&i| up[i]).collect();
        let ft: Vec<f64> = free.par_iter().map(|&i| tol[i]).collect();
        let Some((n, off, mask)) = find_wall(&fp, &ft, p, &mut rng, up.len()) else {
            break;
        };
        let mut count = 0;
        for (j, &m) in mask.iter().enumerate() {
            if m {
                labels[free[j]] = planes.len() as i64;
                count += 1;
            }
        }
        planes.push(Plane {
            kind: PlaneKind::Wall,
            normal: [n.x, n.y, 0.0],
            offset: off,
            inliers: count,
        });
    }
    let mut removed = vec![false; frame.depth.len()];
    for (i, &l) in labels.iter().enumerate() {
        removed[pix[i]] = l != -1;
    }
    Planes { planes, removed }
}

#[cfg(test)]
mod tests {
    use super::super::{Camera, Frame};
    use super::*;
    use crate::vote::Intrinsics;
    use nalgebra::Matrix3;

    #[test]
    fn a_floor_and_a_wall_are_found_and_a_box_is_kept() {
        // Camera 1.4 m up, level, looking along +y at a wall 5 m ahead (y = 5) over a floor
        // (z = 0), a 0.6 m box on the floor 3.2 m ahead.
        let cam = Camera::new(Intrinsics::KINECT_V1, 640, 480).unwrap();
        let rg = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
        let eye = Vector3::new(0.0, 0.0, 1.4);
        let mut depth = vec![0f32; 640 * 480];
        let mut truth = vec![0u8; 640 * 480]; // 1 floor, 2 wall, 3 box
        for v in 0..480 {
            for u in 0..640 {
                let d =
                    rg * Vector3::new((u as f64 - 319.5) / 525.0, (v as f64 - 239.5) / 525.0, 1.0);
                let mut hit = (f64::INFINITY, 0u8);
                if d.z < 0.0 {
                    hit = (-eye.z / d.z, 1);
                }
                let s = (5.0 - eye.y) / d.y;
                if s < hit.0 {
                    hit = (s, 2);
                }
                let s = (3.2 - eye.y) / d.y; // the box's front face, x in [-0.3, 0.3], z in [0, 0.6]
                let q = eye + s * d;
                if q.x.abs() <= 0.3 && q.z <= 0.6 && q.z >= 0.0 && s < hit.0 {
                    // its bottom 5 cm lie within the floor's tolerance: no truth asked there
                    hit = (s, if q.z > 0.05 { 3 } else { 4 });
                }
                if hit.0.is_finite() {
                    depth[v * 640 + u] = hit.0 as f32;
                    truth[v * 640 + u] = hit.1;
                }
            }
        }
        let f = Frame::new(&depth, cam).unwrap();
        let out = find_planes(&f, &rg, &PlaneParams::default(), true, true);
        assert_eq!(out.planes.len(), 2, "{:?}", out.planes);
        assert!(
            (out.floor_height().unwrap() + 1.4).abs() < 1e-3,
            "{:?}",
            out.planes
        );
        let w = out.planes[1];
        assert_eq!(w.kind, PlaneKind::Wall);
        assert!(
            (w.normal[1].abs() - 1.0).abs() < 1e-6 && (w.offset.abs() - 5.0).abs() < 1e-3,
            "{w:?}"
        );
        let count = |t: u8, removed: bool| {
            (0..depth.len())
                .filter(|&i| truth[i] == t && out.removed[i] == removed)
                .count()
        };
        assert_eq!(
            count(1, false) + count(2, false),
            0,
            "every floor and wall pixel removed"
        );
        assert_eq!(count(3, true), 0, "the box is kept");
    }
}
