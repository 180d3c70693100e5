//! Synthetic depth images of objects made of boxes, with exact poses and per-part targets.
//!
//! A tiny analytic ray caster for tests, benchmarks and the CLI's round-trip checks: no meshes,
//! no GPU, bit-for-bit reproducible. Frames follow `docs/DESIGN.md`: object frame metres, z up,
//! origin = the SSC; camera OpenCV; `X_cam = R X_obj + t`; depth uint16 mm, 0 = missing.

use super::predict::Intrinsics;
use super::{matrix_to_quat, quat_to_matrix};
use crate::DepthStore;

/// An axis-aligned box in the object frame: centre and half extents (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxPart {
    pub centre: [f64; 3],
    pub half: [f64; 3],
}

/// A chair-like object (0.45 m seat at 0.45 m, a back on the -y side, four legs), origin at the
/// seat centre; asymmetric, so its rotation is well defined.
pub fn chair() -> Vec<BoxPart> {
    let mut b = vec![
        BoxPart {
            centre: [0.0, 0.0, 0.0],
            half: [0.23, 0.22, 0.03],
        }, // seat
        BoxPart {
            centre: [0.0, -0.20, 0.25],
            half: [0.23, 0.025, 0.22],
        }, // back
    ];
    for (x, y) in [(-0.2, -0.19), (0.2, -0.19), (-0.2, 0.19), (0.2, 0.19)] {
        b.push(BoxPart {
            centre: [x, y, -0.24],
            half: [0.025, 0.025, 0.21],
        });
    }
    b
}

/// The pose `(R row-major, t)` of a camera at distance `distance` from the object origin,
/// azimuth `azimuth` (about the object's z axis, from +x) and elevation `elevation` (radians),
/// looking at the origin with the object's z axis pointing up in the image.
pub fn look_at(azimuth: f64, elevation: f64, distance: f64) -> ([[f64; 3]; 3], [f64; 3]) {
    let c = [
        distance * elevation.cos() * azimuth.cos(),
        distance * elevation.cos() * azimuth.sin(),
        distance * elevation.sin(),
    ];
    let f = [-c[0] / distance, -c[1] / distance, -c[2] / distance];
    let up = [0.0, 0.0, 1.0];
    let r = normalise(cross(f, up));
    let d = cross(f, r);
    let rot = [r, d, f];
    let t = [-dot(rot[0], c), -dot(rot[1], c), -dot(rot[2], c)];
    (rot, t)
}

/// Depth (uint16 mm, row-major `height x width`) of `boxes` at pose `(r, t)`; 0 where no box.
pub fn render(
    boxes: &[BoxPart],
    r: [[f64; 3]; 3],
    t: [f64; 3],
    k: &Intrinsics,
    width: usize,
    height: usize,
) -> Vec<u16> {
    // Ray x = s * d_cam (s = depth since d_cam.z = 1); in the object frame o + s * d_obj.
    let rt = |v: [f64; 3]| {
        [
            r[0][0] * v[0] + r[1][0] * v[1] + r[2][0] * v[2],
            r[0][1] * v[0] + r[1][1] * v[1] + r[2][1] * v[2],
            r[0][2] * v[0] + r[1][2] * v[1] + r[2][2] * v[2],
        ]
    };
    let o = rt([-t[0], -t[1], -t[2]]);
    let mut out = vec![0u16; width * height];
    for v in 0..height {
        for u in 0..width {
            let dcam = [(u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0];
            let d = rt(dcam);
            let mut best = f64::INFINITY;
            for b in boxes {
                let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
                let mut hit = true;
                for a in 0..3 {
                    let (bmin, bmax) = (b.centre[a] - b.half[a], b.centre[a] + b.half[a]);
                    if d[a].abs() < 1e-15 {
                        if o[a] < bmin || o[a] > bmax {
                            hit = false;
                            break;
                        }
                    } else {
                        let (s1, s2) = ((bmin - o[a]) / d[a], (bmax - o[a]) / d[a]);
                        lo = lo.max(s1.min(s2));
                        hi = hi.min(s1.max(s2));
                    }
                }
                if hit && lo <= hi && lo > 0.0 && lo < best {
                    best = lo;
                }
            }
            if best.is_finite() {
                let mm = (best * 1000.0).round();
                if (1.0..=65535.0).contains(&mm) {
                    out[v * width + u] = mm as u16;
                }
            }
        }
    }
    out
}

/// Training targets of parts of one rendered view (DESIGN.md data contract): for each part
/// `[image, u, v]`, the offset `t - X(u, v)` (SSC minus the part's back-projected point, from its
/// millimetre depth) and the quaternion of `r`.
pub fn targets(
    parts: &[[i32; 3]],
    depth: &[u16],
    width: usize,
    r: [[f64; 3]; 3],
    t: [f64; 3],
    k: &Intrinsics,
) -> (Vec<f32>, Vec<f32>) {
    let q = matrix_to_quat(r);
    let mut offsets = Vec::with_capacity(parts.len() * 3);
    let mut rotations = Vec::with_capacity(parts.len() * 4);
    for p in parts {
        let z = f64::from(depth[p[2] as usize * width + p[1] as usize]) * 1e-3;
        let x = k.back_project(f64::from(p[1]), f64::from(p[2]), z);
        offsets.extend((0..3).map(|a| (t[a] - x[a]) as f32));
        rotations.extend(q.iter().map(|v| *v as f32));
    }
    (offsets, rotations)
}

/// A view's pose `(R row-major, t)`, as [`look_at`] gives it.
pub type Pose = ([[f64; 3]; 3], [f64; 3]);

/// `n` views of the [`chair`] around it (azimuth `i * 2π / n`, elevation `elevation(i)` radians,
/// at `distance` metres), rendered at `width x height` through `k`: the images and their poses
/// (the training fixture of the tests and benchmarks).
pub fn chair_views(
    n: usize,
    elevation: impl Fn(usize) -> f64,
    distance: f64,
    k: &Intrinsics,
    width: usize,
    height: usize,
) -> (DepthStore, Vec<Pose>) {
    let chair = chair();
    let mut store = DepthStore::new();
    let mut poses = Vec::new();
    for i in 0..n {
        let az = i as f64 * std::f64::consts::TAU / n as f64;
        let pose = look_at(az, elevation(i), distance);
        store
            .push(
                width,
                height,
                &render(&chair, pose.0, pose.1, k, width, height),
            )
            .expect("a rendered view is a valid image");
        poses.push(pose);
    }
    (store, poses)
}

/// [`targets`] of `parts` (grouped by image in order, as [`crate::sample_parts`] gives them)
/// over the views of `store` at `poses`: offsets (P, 3) and rotations (P, 4), flat.
pub fn view_targets(
    parts: &[[i32; 3]],
    store: &DepthStore,
    poses: &[Pose],
    k: &Intrinsics,
) -> (Vec<f32>, Vec<f32>) {
    let (mut offsets, mut rotations) = (Vec::new(), Vec::new());
    for (i, (r, t)) in poses.iter().enumerate() {
        let mine: Vec<[i32; 3]> = parts.iter().filter(|p| p[0] == i as i32).copied().collect();
        let (o, q) = targets(&mine, store.image(i).data, store.dims(i).0, *r, *t, k);
        offsets.extend(o);
        rotations.extend(q);
    }
    (offsets, rotations)
}

/// Rotation matrix of a quaternion (re-exported for callers of this module).
pub fn rotation_of(q: [f64; 4]) -> [[f64; 3]; 3] {
    quat_to_matrix(q)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalise(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_is_a_rotation_and_puts_origin_ahead() {
        let (r, t) = look_at(0.7, 0.3, 2.5);
        assert!((t[0]).abs() < 1e-12 && (t[1]).abs() < 1e-12 && (t[2] - 2.5).abs() < 1e-12);
        for i in 0..3 {
            for j in 0..3 {
                let d = dot(r[i], r[j]);
                assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        // Object z (up) points up in the image: its camera y component is negative.
        assert!(r[1][2] < 0.0);
    }

    #[test]
    fn render_matches_a_plane() {
        // A wide flat box facing the camera at 2 m: depth = 2 m - half thickness everywhere.
        let k = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 31.5,
            cy: 23.5,
        };
        let b = [BoxPart {
            centre: [0.0, 0.0, 0.0],
            half: [5.0, 5.0, 0.1],
        }];
        let r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let d = render(&b, r, [0.0, 0.0, 2.0], &k, 64, 48);
        assert!(d.iter().all(|&v| v == 1900));
        let (off, rot) = targets(&[[0, 31, 23]], &d, 64, r, [0.0, 0.0, 2.0], &k);
        assert!((off[2] - 0.1).abs() < 1e-6 && (off[0] - 0.0095).abs() < 1e-6);
        assert_eq!(rot, vec![1.0, 0.0, 0.0, 0.0]);
    }
}
