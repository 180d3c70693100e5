//! Verification: how well the observed depth agrees with a shape at a pose (as
//! `isa.detection.verify`, whose docstring gives the rules).
//!
//! The shape's samples are moved to the pose and z-buffered on image cells (the front-most
//! sample per cell); each visible cell is compared with the raw depth on a 5 x 5 grid of pixels
//! spanning `lateral` metres around it: **agree** (an object surface within tolerance),
//! **violate** (seen through, or a wall/floor in front), **occluded** (something not a plane in
//! front, or the shape lies on a plane), **missing** (no depth), **outside** (out of the image).
//! With `unexplained_weight` > 0, cells of observed surface inside the shape's box but in front
//! of its surface or where it has none are **unexplained** too. Score `(agree - w violate - u
//! unexplained) / (agree + violate + occluded + outside)`, 0 under `min_cells`.

use nalgebra::{Matrix3, Vector3};

use super::{floor_i64, Camera, Frame};
use crate::params::VerifyParams;

/// Side of the comparison grid around each cell's pixel.
const GRID: i64 = 5;
/// Observed points this close above a shape's bottom are the floor it stands on, not
/// unexplained surface (metres).
const FLOOR_CLEARANCE: f64 = 0.05;

/// A depth frame prepared for verification: the raw depth and, when known, which pixels are
/// floor or wall.
#[derive(Clone, Copy, Debug)]
pub struct Evidence<'a> {
    pub frame: Frame<'a>,
    pub planes: Option<&'a [bool]>,
}

/// Counts of visible shape cells per outcome and the score; `unexplained` observed cells
/// (counted only when `unexplained_weight` > 0, else 0).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Verification {
    pub score: f64,
    pub agree: usize,
    pub violate: usize,
    pub occluded: usize,
    pub missing: usize,
    pub outside: usize,
    pub unexplained: usize,
}

/// The front-most point per `cell_px` image cell of camera-frame points: `(index, u, v,
/// inside the image)`. Points nearer than 5 cm are dropped, and so are those beyond `margin`
/// times the image size outside it.
pub fn visible_points(
    points: &[Vector3<f64>],
    cam: &Camera,
    cell_px: i64,
    margin: f64,
) -> Vec<(usize, i64, i64, bool)> {
    let (w, h) = (cam.width as i64, cam.height as i64);
    let mu = (margin * w as f64) as i64;
    let mv = (margin * h as f64) as i64;
    // Each point's pixel (u: i32::MIN when dropped), kept small: this runs for every shape
    // sample of every hypothesis.
    const DROPPED: i32 = i32::MIN;
    let mut uv: Vec<(i32, i32)> = Vec::with_capacity(points.len());
    let (mut u0, mut u1, mut v0, mut v1) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
    for p in points {
        let z = p.z;
        if z <= 0.05 {
            uv.push((DROPPED, 0));
            continue;
        }
        let u = floor_i64(cam.k.fx * p.x / z + cam.k.cx + 0.5);
        let v = floor_i64(cam.k.fy * p.y / z + cam.k.cy + 0.5);
        if u < -mu || u >= w + mu || v < -mv || v >= h + mv {
            uv.push((DROPPED, 0));
            continue;
        }
        (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        uv.push((u as i32, v as i32));
    }
    if u0 > u1 {
        return vec![];
    }
    // The front-most point per cell on a dense grid over the cells the points reach (an object
    // covers few), ties to the earlier point. Cells count from `margin` outside the image, so
    // the shifted pixels are non-negative (and the cell of the least pixel is the least cell).
    let cell = cell_px as u32;
    let cell_of = |u: i64, m: i64| (u + m) as u32 / cell;
    let (c0, r0) = (cell_of(u0, mu), cell_of(v0, mv));
    let cols = (cell_of(u1, mu) - c0 + 1) as usize;
    let rows = (cell_of(v1, mv) - r0 + 1) as usize;
    // Each reached pixel column's and row's cell, looked up: a division per point is what
    // this loop would otherwise spend most of its time on.
    let col_of: Vec<u32> = (u0..=u1).map(|u| cell_of(u, mu) - c0).collect();
    let row_of: Vec<usize> = (v0..=v1)
        .map(|v| (cell_of(v, mv) - r0) as usize * cols)
        .collect();
    // Per cell the front-most point and its depth, kept beside it (no lookup of the point).
    let mut best = vec![(u32::MAX, f64::INFINITY); cols * rows];
    for (k, &(u, v)) in uv.iter().enumerate() {
        if u == DROPPED {
            continue;
        }
        let slot = &mut best
            [row_of[(i64::from(v) - v0) as usize] + col_of[(i64::from(u) - u0) as usize] as usize];
        let z = points[k].z;
        if slot.0 == u32::MAX || z < slot.1 {
            *slot = (k as u32, z);
        }
    }
    best.iter()
        .filter(|b| b.0 != u32::MAX)
        .map(|&(k, _)| {
            let (u, v) = (i64::from(uv[k as usize].0), i64::from(uv[k as usize].1));
            (k as usize, u, v, u >= 0 && u < w && v >= 0 && v < h)
        })
        .collect()
}

/// The cell side in pixels for samples of `spacing` at depth `z`.
pub(crate) fn cell_px(spacing: f64, z: f64, cam: &Camera, params: &VerifyParams) -> i64 {
    (params.min_cell_px as i64)
        .max((params.cell_spacing * spacing * cam.k.fx / z.max(1e-3)).round_ties_even() as i64)
}

/// Verifies a shape (object-frame `points`, scaled per axis by `scale`, mean `spacing`) at pose
/// `(r, t)`. `n_points`: only the first that many samples (an even subsample: the samples are
/// random), the cells grown to match.
#[allow(clippy::too_many_arguments)]
pub fn verify_pose(
    ev: &Evidence<'_>,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    points: &[[f32; 3]],
    scale: [f64; 3],
    spacing: f64,
    params: &VerifyParams,
    n_points: Option<usize>,
) -> Verification {
    let cam = &ev.frame.camera;
    let (mut pts, mut spacing) = (points, spacing);
    if let Some(n) = n_points.filter(|n| *n < points.len()) {
        spacing *= (points.len() as f64 / n as f64).sqrt();
        pts = &points[..n];
    }
    let pc: Vec<Vector3<f64>> = pts
        .iter()
        .map(|p| {
            r * Vector3::new(
                f64::from(p[0]) * scale[0],
                f64::from(p[1]) * scale[1],
                f64::from(p[2]) * scale[2],
            ) + t
        })
        .collect();
    let cell = cell_px(spacing, t.z, cam, params);
    let vis = visible_points(&pc, cam, cell, 1.0);
    let outside = vis.iter().filter(|v| !v.3).count();
    let (w, h) = (cam.width as i64, cam.height as i64);
    let half = params.lateral * cam.k.fx / t.z.max(1e-3);
    let step = half / (GRID / 2) as f64;
    let offs: Vec<i64> = (-(GRID / 2)..=GRID / 2)
        .map(|g| (g as f64 * step).round_ties_even() as i64)
        .collect();
    let [base, k] = params.tolerance;
    let depth = ev.frame.depth;
    let (mut agree, mut violate, mut missing, mut n_in) = (0usize, 0usize, 0usize, 0usize);
    for &(i, u0, v0, inside) in &vis {
        if !inside {
            continue;
        }
        n_in += 1;
        let zm = pc[i].z;
        let tol = base.max(k * zm * zm);
        let (mut ag, mut any_valid, mut hidden) = (false, false, false);
        // One agreeing pixel decides the cell: the rest of its grid is not looked at.
        'grid: for &dv in &offs {
            let v = v0 + dv;
            for &du in &offs {
                let u = u0 + du;
                let pix = (v.clamp(0, h - 1) * w + u.clamp(0, w - 1)) as usize;
                let zo = if u >= 0 && u < w && v >= 0 && v < h {
                    f64::from(depth[pix])
                } else {
                    0.0
                };
                if zo <= 0.0 {
                    continue;
                }
                any_valid = true;
                let d = zo - zm;
                let near = d.abs() < tol;
                let plane = ev.planes.is_some_and(|p| p[pix]);
                if plane {
                    hidden |= near;
                } else if near {
                    ag = true;
                    break 'grid;
                } else {
                    hidden |= d <= -tol;
                }
            }
        }
        if ag {
            agree += 1;
        } else if !any_valid {
            missing += 1;
        } else if !hidden {
            violate += 1;
        }
    }
    let occluded = n_in - agree - violate - missing;
    let n = agree + violate + occluded + outside;
    let unexplained = if params.unexplained_weight > 0.0 {
        unexplained_cells(ev, r, t, &pc, &vis, cell, base, k, params.lateral)
    } else {
        0
    };
    let score = if n - outside < params.min_cells {
        0.0
    } else {
        (agree as f64
            - params.violation_weight * violate as f64
            - params.unexplained_weight * unexplained as f64)
            / n as f64
    };
    Verification {
        score,
        agree,
        violate,
        occluded,
        missing,
        outside,
        unexplained,
    }
}

/// Cells of observed surface the shape does not explain: a pixel per shape cell (the cells'
/// own grid, over the shape's image footprint) whose observed point lies inside the shape's
/// box grown by `margin`, off the planes, and in front of the shape's front surface there
/// (beyond the depth tolerance) or where the shape shows no surface. Seen-through cells are
/// the violations; these are the other direction: something solid where the shape is empty.
#[allow(clippy::too_many_arguments)]
fn unexplained_cells(
    ev: &Evidence<'_>,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    pc: &[Vector3<f64>],
    vis: &[(usize, i64, i64, bool)],
    cell: i64,
    base: f64,
    k: f64,
    margin: f64,
) -> usize {
    let cam = &ev.frame.camera;
    let (w, h) = (cam.width as i64, cam.height as i64);
    // The shape's front depth per cell, on visible_points' grid (cells counted from one image
    // size left of and above the image).
    let key = |u: i64, v: i64| ((u + w) / cell, (v + h) / cell);
    let cells: Vec<((i64, i64), f64)> = vis
        .iter()
        .filter(|v| v.3)
        .map(|&(i, u, v, _)| (key(u, v), pc[i].z))
        .collect();
    let Some(c0) = cells.iter().map(|c| c.0 .0).min() else {
        return 0;
    };
    let c1 = cells.iter().map(|c| c.0 .0).max().expect("non-empty");
    let r0 = cells.iter().map(|c| c.0 .1).min().expect("non-empty");
    let r1 = cells.iter().map(|c| c.0 .1).max().expect("non-empty");
    let cols = (c1 - c0 + 1) as usize;
    let rows = (r1 - r0 + 1) as usize;
    let mut front = vec![f64::INFINITY; cols * rows];
    for &((c, rr), z) in &cells {
        let slot = &mut front[(rr - r0) as usize * cols + (c - c0) as usize];
        *slot = slot.min(z);
    }
    // The shape's box in its own (scaled, z-up) frame, grown by the margin (an observed face on
    // the box is the object's own, and poses are a few centimetres off) but raised above the
    // floor it stands on.
    let rt = r.transpose();
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in pc {
        let q = rt * (p - t);
        lo = lo.inf(&q);
        hi = hi.sup(&q);
    }
    lo -= Vector3::new(margin, margin, -margin.max(FLOOR_CLEARANCE));
    hi.add_scalar_mut(margin);
    let mut count = 0;
    for row in 0..rows as i64 {
        for col in 0..cols as i64 {
            // The cell's centre pixel.
            let u = (c0 + col) * cell - w + cell / 2;
            let v = (r0 + row) * cell - h + cell / 2;
            if u < 0 || u >= w || v < 0 || v >= h {
                continue;
            }
            let pix = (v * w + u) as usize;
            let zo = f64::from(ev.frame.depth[pix]);
            if zo <= 0.0 || ev.planes.is_some_and(|p| p[pix]) {
                continue;
            }
            let x = Vector3::new(
                (u as f64 - cam.k.cx) * zo / cam.k.fx,
                (v as f64 - cam.k.cy) * zo / cam.k.fy,
                zo,
            );
            let q = rt * (x - t);
            if (0..3).any(|a| q[a] <= lo[a] || q[a] >= hi[a]) {
                continue;
            }
            let zf = front[row as usize * cols + col as usize];
            if !zf.is_finite() || zo < zf - base.max(k * zf * zf) {
                count += 1;
            }
        }
    }
    count
}

#[cfg(test)]
pub(crate) mod tests {
    use super::super::rot_z;
    use super::super::shapes::tests::box_library;
    use super::*;
    use crate::vote::Intrinsics;

    /// A level camera at height 1.2 m looking along +y (upright) at a box standing on the floor
    /// 3.2 m ahead; the depth rendered analytically by ray casting the box and the floor.
    pub(crate) fn box_scene(
        size: [f64; 3],
        yaw: f64,
    ) -> (Vec<f32>, Camera, Matrix3<f64>, Vector3<f64>, Matrix3<f64>) {
        let cam = Camera::new(Intrinsics::KINECT_V1, 640, 480).unwrap();
        // camera -> upright: x right, y forward (camera z), z up (camera -y); camera at (0, 0, 1.2).
        let rg = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
        let eye = Vector3::new(0.0, 0.0, 1.2);
        let centre = Vector3::new(0.1, 3.2, 0.0);
        let ry = rot_z(yaw);
        let mut depth = vec![0f32; 640 * 480];
        for v in 0..480 {
            for u in 0..640 {
                let dc = Vector3::new((u as f64 - 319.5) / 525.0, (v as f64 - 239.5) / 525.0, 1.0);
                let d = rg * dc; // upright ray direction for unit camera depth
                let mut best = f64::INFINITY;
                if d.z < -1e-9 {
                    best = best.min(-eye.z / d.z);
                }
                // slab test in the box frame
                let o = ry.transpose() * (eye - centre);
                let dd = ry.transpose() * d;
                let lo = [-size[0] / 2.0, -size[1] / 2.0, 0.0];
                let hi = [size[0] / 2.0, size[1] / 2.0, size[2]];
                let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
                for a in 0..3 {
                    if dd[a].abs() < 1e-12 {
                        if o[a] < lo[a] || o[a] > hi[a] {
                            t1 = -1.0;
                        }
                    } else {
                        let (x, y) = ((lo[a] - o[a]) / dd[a], (hi[a] - o[a]) / dd[a]);
                        t0 = t0.max(x.min(y));
                        t1 = t1.min(x.max(y));
                    }
                }
                if t0 <= t1 && t0 > 0.0 {
                    best = best.min(t0);
                }
                if best.is_finite() && best < 30.0 {
                    depth[v * 640 + u] = best as f32; // camera depth = ray parameter (dc.z = 1)
                }
            }
        }
        let r = rg.transpose() * ry;
        let t = rg.transpose() * (centre - eye);
        (depth, cam, r, t, rg)
    }

    #[test]
    fn the_true_pose_beats_a_turned_and_a_shifted_one() {
        let size = [0.5, 1.0, 1.5]; // taller than the camera's 1.2 m: no grazing top face
        let lib = box_library(size, 24);
        let (depth, cam, r, t, rg) = box_scene(size, 0.4);
        let ev = Evidence {
            frame: Frame::new(&depth, cam).unwrap(),
            planes: None,
        };
        let p = VerifyParams::default();
        let score = |r: &Matrix3<f64>, t: &Vector3<f64>| {
            verify_pose(
                &ev,
                r,
                t,
                lib.points_of(0),
                [1.0; 3],
                lib.spacing[0],
                &p,
                None,
            )
        };
        let truth = score(&r, &t);
        assert!(truth.score > 0.95, "{truth:?}");
        // turned by 90 degrees about the vertical through its centre: the long side across
        let turned = rg.transpose() * rot_z(0.4 + std::f64::consts::FRAC_PI_2);
        assert!(truth.score - score(&turned, &t).score > 0.2);
        let right = rg.transpose() * Vector3::new(0.3, 0.0, 0.0);
        assert!(truth.score - score(&r, &(t + right)).score > 0.5);
        // 0.3 m nearer the camera: the observed surface is behind it, seen through
        let v = score(&r, &(t * (1.0 - 0.3 / t.norm())));
        assert!(v.violate > v.agree, "{v:?}");
        // nothing observed: all missing, score 0; behind the camera: no cells
        let empty = vec![0f32; 640 * 480];
        let ev0 = Evidence {
            frame: Frame::new(&empty, cam).unwrap(),
            planes: None,
        };
        let v0 = verify_pose(
            &ev0,
            &r,
            &t,
            lib.points_of(0),
            [1.0; 3],
            lib.spacing[0],
            &p,
            None,
        );
        assert_eq!((v0.score, v0.agree), (0.0, 0));
        assert!(v0.missing > 0);
        let vb = verify_pose(
            &ev0,
            &r,
            &-t,
            lib.points_of(0),
            [1.0; 3],
            lib.spacing[0],
            &p,
            None,
        );
        assert_eq!(vb, Verification::default());
    }

    /// A table-like shape (a top on four legs) hypothesised on a solid box of the same size:
    /// the box's front face fills the table's empty space under its top, so the unexplained
    /// cells mark it down; the box's own shape explains every observed cell and keeps its score.
    #[test]
    fn observed_surface_where_the_shape_is_empty_is_unexplained() {
        let size = [1.0, 1.6, 0.6];
        let (depth, cam, r, t, _) = box_scene(size, 0.3);
        let ev = Evidence {
            frame: Frame::new(&depth, cam).unwrap(),
            planes: None,
        };
        let solid = box_library(size, 24);
        let mut table: Vec<[f32; 3]> = box_library([1.0, 1.6, 0.05], 24)
            .points_of(0)
            .iter()
            .map(|p| [p[0], p[1], p[2] + 0.55])
            .collect();
        let leg = box_library([0.05, 0.05, 0.55], 8);
        for (x, y) in [
            (-0.475, -0.775),
            (0.475, -0.775),
            (-0.475, 0.775),
            (0.475, 0.775),
        ] {
            table.extend(leg.points_of(0).iter().map(|p| [p[0] + x, p[1] + y, p[2]]));
        }
        let score = |points: &[[f32; 3]], spacing: f64, w: f64| {
            let p = VerifyParams {
                unexplained_weight: w,
                ..VerifyParams::default()
            };
            verify_pose(&ev, &r, &t, points, [1.0; 3], spacing, &p, None).score
        };
        // The table's samples are about as dense as the box's (the same grid on its top).
        let spacing = solid.spacing[0];
        let box0 = score(solid.points_of(0), spacing, 0.0);
        let box1 = score(solid.points_of(0), spacing, 1.0);
        let table0 = score(&table, spacing, 0.0);
        let table1 = score(&table, spacing, 1.0);
        assert!(box0 > 0.75 && (box0 - box1).abs() < 0.02, "{box0} {box1}");
        assert!(table1 < table0 - 0.2, "{table0} -> {table1}");
        assert!(box1 > table1 + 0.3, "{box1} vs {table1}");
    }
}
