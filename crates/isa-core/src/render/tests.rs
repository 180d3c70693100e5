//! The rasteriser against analytic truths: exact depth and pixel sets of a fronto-parallel
//! square, ray-plane depth of a tilted plane, fans that cover each pixel once, faces cut by the
//! near plane or behind the camera against ray-triangle intersection, the depth test, the far
//! plane, windings, threads, and the argument errors.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;

/// 512 px focal length at 2 m: an object-frame coordinate of k/256 m lands on pixel k + c,
/// exactly in f32 and f64, so edges through pixel centres are exact.
const EXACT: Intrinsics = Intrinsics {
    fx: 512.0,
    fy: 512.0,
    cx: 320.0,
    cy: 240.0,
};
const I3: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn camera(k: Intrinsics) -> RenderCamera {
    RenderCamera {
        k,
        width: 640,
        height: 480,
        znear: 0.05,
        zfar: 20.0,
    }
}

fn render(
    v: &[[f32; 3]],
    f: &[[u32; 3]],
    r: &[[f64; 3]; 3],
    t: [f64; 3],
    c: &RenderCamera,
) -> DepthFrame {
    let out = render_depth(v, f, r, &t, c).unwrap();
    assert_eq!(out.depth.len(), c.width * c.height);
    for (d, m) in out.depth.iter().zip(&out.mask) {
        assert_eq!(*m, *d > 0.0);
    }
    out
}

/// One triangle given in camera coordinates (identity pose).
fn render_triangle(tri: &[[f32; 3]], c: &RenderCamera) -> DepthFrame {
    render(tri, &[[0, 1, 2]], &I3, [0.0; 3], c)
}

/// A rectangle `[x0, x1] x [y0, y1]` in the object's z = 0 plane, two triangles.
fn rect(x0: f32, x1: f32, y0: f32, y1: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let v = vec![[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]];
    (v, vec![[0, 1, 2], [0, 2, 3]])
}

fn rot(ax: f64, ay: f64) -> [[f64; 3]; 3] {
    let (sa, ca) = ax.to_radians().sin_cos();
    let (sb, cb) = ay.to_radians().sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]];
    let ry = [[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]];
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| rx[i][k] * ry[k][j]).sum()))
}

/// The direction of pixel `(u, v)`'s centre ray, z = 1.
fn ray(k: &Intrinsics, u: usize, v: usize) -> [f64; 3] {
    [(u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Where the ray `s d` (s > 0) meets the plane of triangle `p`: `(z, smallest barycentric
/// coordinate)` (negative outside the triangle), or `None` when it runs parallel or away.
fn ray_triangle(d: [f64; 3], p: [[f64; 3]; 3]) -> Option<(f64, f64)> {
    let (e1, e2) = (sub(p[1], p[0]), sub(p[2], p[0]));
    let h = cross(d, e2);
    let det = dot(e1, h);
    if det.abs() < 1e-15 {
        return None;
    }
    let s = [-p[0][0], -p[0][1], -p[0][2]];
    let b1 = dot(s, h) / det;
    let q = cross(s, e1);
    let b2 = dot(d, q) / det;
    let dist = dot(e2, q) / det;
    (dist > 0.0).then_some((dist * d[2], b1.min(b2).min(1.0 - b1 - b2)))
}

#[test]
fn fronto_parallel_square_has_exact_depth_and_pixel_set() {
    let c = camera(EXACT);
    // On pixel centres: u 96 and 400, v 112 and 304; the top-left rule keeps the left and
    // top edges' pixels and drops the right and bottom ones.
    let (v, f) = rect(-224.0 / 256.0, 80.0 / 256.0, -128.0 / 256.0, 64.0 / 256.0);
    let out = render(&v, &f, &I3, [0.0, 0.0, 2.0], &c);
    for y in 0..480 {
        for x in 0..640 {
            let i = y * 640 + x;
            let inside = (96..400).contains(&x) && (112..304).contains(&y);
            assert_eq!(out.mask[i], inside, "pixel ({x}, {y})");
            if inside {
                assert_eq!(out.depth[i], 2.0);
            }
        }
    }
    // Off pixel centres, at another depth: the centres strictly inside.
    let (v, f) = rect(-0.61, 0.37, -0.29, 0.43);
    let out = render(&v, &f, &I3, [0.013, -0.021, 3.7], &c);
    let k = &EXACT;
    let span = |a: f32, b: f32, off: f64, f: f64, cc: f64| {
        let (lo, hi) = (
            f * (a as f64 + off) / 3.7 + cc,
            f * (b as f64 + off) / 3.7 + cc,
        );
        lo.ceil() as usize..=hi.floor() as usize
    };
    let (us, vs) = (
        span(-0.61, 0.37, 0.013, k.fx, k.cx),
        span(-0.29, 0.43, -0.021, k.fy, k.cy),
    );
    let mut n = 0;
    for y in 0..480 {
        for x in 0..640 {
            let i = y * 640 + x;
            assert_eq!(
                out.mask[i],
                us.contains(&x) && vs.contains(&y),
                "pixel ({x}, {y})"
            );
            if out.mask[i] {
                assert!((out.depth[i] as f64 - 3.7).abs() < 3e-7);
                n += 1;
            }
        }
    }
    assert!(n > 10_000);
}

#[test]
fn tilted_plane_depth_is_the_ray_plane_intersection() {
    let k = Intrinsics::KINECT_V1;
    let c = camera(k);
    let (hx, hy) = (0.6f32, 0.5f32);
    let (v, f) = rect(-hx, hx, -hy, hy);
    for (r, t) in [
        (rot(40.0, 25.0), [0.1, -0.05, 2.5]),
        (rot(-70.0, 10.0), [-0.2, 0.1, 1.9]),
        (rot(5.0, -80.0), [0.0, 0.0, 3.0]),
    ] {
        let out = render(&v, &f, &r, t, &c);
        let n = [r[0][2], r[1][2], r[2][2]];
        let (mut covered, mut max_err) = (0, 0.0f64);
        for y in 0..480 {
            for x in 0..640 {
                let d = ray(&k, x, y);
                let z = dot(n, t) / dot(n, d);
                // The hit in the object frame: R^T (z d - t).
                let p = sub([z * d[0], z * d[1], z * d[2]], t);
                let q = [0, 1].map(|j| (0..3).map(|i| r[i][j] * p[i]).sum::<f64>());
                let margin = (hx as f64 - q[0].abs()).min(hy as f64 - q[1].abs());
                let i = y * 640 + x;
                if margin.abs() > 1e-6 {
                    assert_eq!(
                        out.mask[i],
                        margin > 0.0,
                        "pixel ({x}, {y}) margin {margin}"
                    );
                }
                if out.mask[i] {
                    max_err = max_err.max((out.depth[i] as f64 - z).abs());
                    covered += 1;
                }
            }
        }
        assert!(covered > 5_000, "{covered}");
        assert!(max_err < 1e-6, "{max_err}");
    }
}

/// How many of the fan's triangles, each rendered alone, cover each pixel.
fn coverage_counts(v: &[[f32; 3]], f: &[[u32; 3]], c: &RenderCamera) -> Vec<u8> {
    let mut count = vec![0u8; c.width * c.height];
    for face in f {
        let out = render(v, std::slice::from_ref(face), &I3, [0.0, 0.0, 2.0], c);
        for (n, m) in count.iter_mut().zip(&out.mask) {
            *n += *m as u8;
        }
    }
    count
}

/// A fan around `centre` through `rim` (pixel coordinates, convex, in angular order), as
/// object points at z = 0 seen at 2 m through [`EXACT`].
fn fan(centre: [f64; 2], rim: &[[f64; 2]]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let obj = |p: [f64; 2]| {
        [
            ((p[0] - 320.0) / 256.0) as f32,
            ((p[1] - 240.0) / 256.0) as f32,
            0.0,
        ]
    };
    let mut v = vec![obj(centre)];
    v.extend(rim.iter().map(|&p| obj(p)));
    let n = rim.len() as u32;
    let f = (0..n).map(|i| [0, 1 + i, 1 + (i + 1) % n]).collect();
    (v, f)
}

/// Every pixel of a closed fan once: no double anywhere, none missing strictly inside its rim.
fn assert_covered_once(centre: [f64; 2], rim: &[[f64; 2]]) {
    let c = camera(EXACT);
    let (v, f) = fan(centre, rim);
    let count = coverage_counts(&v, &f, &c);
    let whole = render(&v, &f, &I3, [0.0, 0.0, 2.0], &c);
    // The rim as the rasteriser sees it (f32 vertices).
    let px: Vec<[f64; 2]> = v[1..]
        .iter()
        .map(|p| [256.0 * p[0] as f64 + 320.0, 256.0 * p[1] as f64 + 240.0])
        .collect();
    let mut inside_n = 0;
    for y in 0..480 {
        for x in 0..640 {
            let i = y * 640 + x;
            assert!(count[i] <= 1, "pixel ({x}, {y}) covered {} times", count[i]);
            assert_eq!(whole.mask[i], count[i] == 1);
            let (u, w) = (x as f64, y as f64);
            let margin = (0..px.len())
                .map(|j| {
                    let (a, b) = (px[j], px[(j + 1) % px.len()]);
                    let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
                    ((b[0] - a[0]) * (w - a[1]) - (b[1] - a[1]) * (u - a[0])) / len
                })
                .fold(f64::INFINITY, f64::min);
            if margin > 1e-9 {
                assert_eq!(
                    count[i], 1,
                    "pixel ({x}, {y}) inside the rim is not covered"
                );
                inside_n += 1;
            }
        }
    }
    assert!(inside_n > 500, "{inside_n}");
}

#[test]
fn triangles_sharing_edges_cover_each_pixel_once() {
    // Spokes along rows, columns and diagonals through pixel centres, the centre on one.
    let (cu, cv) = (320.0, 240.0);
    let s = 40.0;
    let square: Vec<[f64; 2]> = [
        (1, 0),
        (1, 1),
        (0, 1),
        (-1, 1),
        (-1, 0),
        (-1, -1),
        (0, -1),
        (1, -1),
    ]
    .iter()
    .map(|&(a, b)| [cu + s * a as f64, cv + s * b as f64])
    .collect();
    assert_covered_once([cu, cv], &square);
    // Irregular convex fans, vertices on integer pixels (many ties) and anywhere.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut fans = 0;
    for round in 0..8 {
        let n = rng.random_range(3..9);
        // Spread round the circle (jittered), so that every fan has an inside to check.
        let step = std::f64::consts::TAU / n as f64;
        let start = rng.random_range(0.0..step);
        let angles: Vec<f64> = (0..n)
            .map(|i| start + step * (i as f64 + rng.random_range(-0.3..0.3)))
            .collect();
        let (a, b) = (rng.random_range(30.0..120.0), rng.random_range(30.0..100.0));
        let snap = |x: f64| if round % 2 == 0 { x.round() } else { x };
        let rim: Vec<[f64; 2]> = angles
            .iter()
            .map(|t| [snap(cu + a * t.cos()), snap(cv + b * t.sin())])
            .collect();
        // A centre inside the rim (the mean of its vertices), snapped too.
        let m = rim
            .iter()
            .fold([0.0, 0.0], |s, p| [s[0] + p[0], s[1] + p[1]]);
        let centre = [snap(m[0] / n as f64), snap(m[1] / n as f64)];
        let inside = (0..rim.len()).all(|j| {
            let (p, q) = (rim[j], rim[(j + 1) % rim.len()]);
            (q[0] - p[0]) * (centre[1] - p[1]) - (q[1] - p[1]) * (centre[0] - p[0]) > 0.0
        });
        // A centre on the inner side of every rim edge: the fan's triangles tile the polygon.
        if inside {
            assert_covered_once(centre, &rim);
            fans += 1;
        }
    }
    assert!(fans >= 4, "{fans} fans");
}

/// A face in the camera frame (R = I, t = 0) against ray-triangle intersection, at pixels
/// clear of its edges and of the near and far planes; at least `min_clipped` pixels see it
/// nearer than znear.
fn assert_matches_ray_casting(tri: [[f64; 3]; 3], c: &RenderCamera, min_clipped: usize) {
    let v: Vec<[f32; 3]> = tri.iter().map(|p| p.map(|x| x as f32)).collect();
    let p = [0, 1, 2].map(|i| v[i].map(f64::from));
    let out = render_triangle(&v, c);
    let (mut clipped, mut drawn, mut max_err) = (0, 0, 0.0f64);
    let eps = 1e-9;
    for y in 0..c.height {
        for x in 0..c.width {
            let i = y * c.width + x;
            let Some((z, bary)) = ray_triangle(ray(&c.k, x, y), p) else {
                assert!(
                    !out.mask[i],
                    "pixel ({x}, {y}) drawn, its ray misses the plane"
                );
                continue;
            };
            if bary > eps {
                if z < c.znear - eps {
                    clipped += 1;
                }
                let seen = z > c.znear + eps && z < c.zfar - eps;
                if seen || z < c.znear - eps || z > c.zfar + eps {
                    assert_eq!(out.mask[i], seen, "pixel ({x}, {y}) at z {z}");
                }
            } else if bary < -eps {
                assert!(!out.mask[i], "pixel ({x}, {y}) outside the face is drawn");
            }
            if out.mask[i] {
                assert!(
                    z >= c.znear * (1.0 - 1e-9) && z <= c.zfar * (1.0 + 1e-9),
                    "pixel ({x}, {y}) at z {z}"
                );
                max_err = max_err.max((out.depth[i] as f64 - z).abs() / z);
                drawn += 1;
            }
        }
    }
    assert!(drawn > 1000, "{drawn}");
    assert!(
        clipped >= min_clipped,
        "{clipped} pixels see the face nearer than znear"
    );
    assert!(max_err < 3e-7, "relative depth error {max_err}");
}

#[test]
fn faces_crossing_the_near_plane_are_clipped() {
    let mut c = camera(Intrinsics::KINECT_V1);
    c.znear = 0.5;
    // One vertex nearer than znear, in front of the camera.
    assert_matches_ray_casting(
        [[-1.0, -0.5, 3.0], [1.0, -0.5, 3.0], [0.0, 0.3, 0.1]],
        &c,
        1000,
    );
    // Two vertices nearer than znear (a triangle is left, not a quadrilateral).
    assert_matches_ray_casting(
        [[-0.3, 0.2, 0.2], [0.3, 0.2, 0.2], [0.0, -0.6, 2.5]],
        &c,
        1000,
    );
    // A vertex behind the camera.
    assert_matches_ray_casting(
        [[-1.0, -0.4, 2.0], [1.2, -0.3, 2.2], [0.1, 0.5, -1.0]],
        &c,
        0,
    );
    // Straddling the far plane.
    c.zfar = 2.5;
    assert_matches_ray_casting(
        [[-1.0, -0.5, 1.5], [1.0, -0.5, 1.5], [0.0, 0.8, 4.0]],
        &c,
        0,
    );
    let out = render_triangle(&[[-1.0, -1.0, 3.0], [1.0, -1.0, 3.0], [0.0, 1.0, 3.0]], &c);
    assert!(out.mask.iter().all(|m| !m), "a face beyond zfar is drawn");
    // Wholly behind the near plane.
    c.zfar = 20.0;
    let out = render_triangle(&[[-1.0, -1.0, 0.3], [1.0, -1.0, 0.3], [0.0, 1.0, 0.2]], &c);
    assert!(
        out.mask.iter().all(|m| !m),
        "a face nearer than znear is drawn"
    );
}

#[test]
fn the_nearer_face_wins_in_either_order() {
    let c = camera(EXACT);
    // Two squares overlapping around the optical axis, at camera z 3 and 4 (object z 0 and 1).
    let (mut v, _) = rect(-0.5, 0.25, -0.5, 0.25);
    v.extend(
        rect(-0.25, 0.5, -0.25, 0.5)
            .0
            .iter()
            .map(|p| [p[0], p[1], 1.0]),
    );
    let near_first = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]];
    let far_first = [[4, 5, 6], [4, 6, 7], [0, 1, 2], [0, 2, 3]];
    let t = [0.0, 0.0, 3.0];
    let a = render(&v, &near_first, &I3, t, &c);
    assert_eq!(a, render(&v, &far_first, &I3, t, &c));
    let at = |u: usize, w: usize| a.depth[w * 640 + u];
    assert!((at(320, 240) - 3.0).abs() < 1e-6); // both: the nearer
    assert!((at(250, 170) - 3.0).abs() < 1e-6); // only the near one
    assert_eq!(at(371, 291), 4.0); // only the far one: x = 51 / 512 * 4 = 0.398 < 0.5, > 0.25 at z 3
}

#[test]
fn both_windings_and_any_thread_count_give_the_same_frame() {
    let c = camera(Intrinsics::KINECT_V1);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    // A random soup of small triangles around a point 2.5 m away.
    let v: Vec<[f32; 3]> = (0..600)
        .map(|_| {
            [
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.4..0.4),
                rng.random_range(-0.3..0.3),
            ]
        })
        .collect();
    let f: Vec<[u32; 3]> = (0..200).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
    let flipped: Vec<[u32; 3]> = f.iter().map(|t| [t[0], t[2], t[1]]).collect();
    let (r, t) = (rot(20.0, -35.0), [0.05, 0.0, 2.5]);
    let a = render(&v, &f, &r, t, &c);
    assert!(a.mask.iter().filter(|m| **m).count() > 10_000);
    assert_eq!(a, render(&v, &flipped, &r, t, &c));
    for n in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap();
        assert_eq!(a, pool.install(|| render(&v, &f, &r, t, &c)), "{n} threads");
    }
}

#[test]
fn errors_name_the_argument() {
    let c = camera(Intrinsics::KINECT_V1);
    let (v, f) = rect(-0.1, 0.1, -0.1, 0.1);
    let t = [0.0, 0.0, 2.0];
    let msg = |v: &[[f32; 3]], f: &[[u32; 3]], r: &[[f64; 3]; 3], t: [f64; 3], c: &RenderCamera| {
        match render_depth(v, f, r, &t, c) {
            Err(IsaError::InvalidInput(m)) => m,
            other => panic!("expected InvalidInput, got {other:?}"),
        }
    };
    assert!(msg(&v, &[[0, 1, 4]], &I3, t, &c).contains("faces[0, 2] = 4"));
    let mut bad = v.clone();
    bad[2][1] = f32::NAN;
    assert!(msg(&bad, &f, &I3, t, &c).contains("vertices[2, 1]"));
    let mut r = I3;
    r[1][2] = f64::INFINITY;
    assert!(msg(&v, &f, &r, t, &c).contains("R[1, 2]"));
    assert!(msg(&v, &f, &I3, [0.0, f64::NAN, 2.0], &c).contains("t[1]"));
    let big = [[1e300, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(msg(&[[1e30, 0.0, 0.0]], &[], &big, t, &c).contains("vertices[0]"));
    for (w, h) in [(0, 480), (640, 0), (1 << 15, 1 << 14)] {
        let cc = RenderCamera {
            width: w,
            height: h,
            ..c
        };
        assert!(msg(&v, &f, &I3, t, &cc).contains("width, height"));
    }
    for (n, fz) in [(0.0, 10.0), (2.0, 1.0), (0.1, f64::INFINITY), (-1.0, 5.0)] {
        let cc = RenderCamera {
            znear: n,
            zfar: fz,
            ..c
        };
        assert!(msg(&v, &f, &I3, t, &cc).contains("znear, zfar"));
    }
    let cc = RenderCamera {
        k: Intrinsics { fx: 0.0, ..c.k },
        ..c
    };
    assert!(msg(&v, &f, &I3, t, &cc).contains("focal"));
    // No faces, or no vertices and no faces: an empty frame, not an error.
    assert!(render(&[], &[], &I3, t, &c).mask.iter().all(|m| !m));
}
