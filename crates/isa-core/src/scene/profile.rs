//! What the observed surface inside a detection's box looks like, whatever the category's shapes
//! say: how much of the box the seen surface fills, how it rises through the box's height and
//! at what height it leans to the box's back, how much of it is over the box's middle and how
//! far it spans the box, and how much surface crowds round the box. Ranking reads
//! these ([`super::ranking::FEATURES`]).
//!
//! Why: verification compares a hypothesis with one category's shapes, and a toilet box on a
//! cabinet or a chair box on a toilet agrees with their faces well enough; most false detections
//! on validation rooms are boxes on other objects or on clutter. The profile of what is seen
//! there is the same whichever category asks, so a ranker learns each category's from rooms (a
//! table's surface at the top, a toilet's high at the back) and tells a part of a larger thing
//! (surface carrying on past the box) from an object.

use nalgebra::{Matrix3, Vector3};

use super::nms::UprightBox;
use super::Frame;

/// Horizontal slices of a box's height in [`Profile::levels`], bottom first.
pub const LEVELS: usize = 5;
/// How far (metres) past the box's sides and top [`Profile::around`] looks.
pub const SHELL: f64 = 0.15;
/// Pixel step of the points a profile is made of (every 4th pixel: about 19,000 of a VGA frame,
/// a fraction of a millisecond per box).
pub const STRIDE: usize = 4;
/// Height (metres) above the floor below which a point is floor, not object.
const FLOOR_CLEARANCE: f64 = 0.02;
/// Seen area (m^2) added to a box's own in [`Profile::around`], so an empty box does not divide by 0.
const MIN_AREA: f64 = 0.01;

/// One observed point in the upright frame and the surface area (m^2) its pixel step covers
/// there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeenPoint {
    pub p: Vector3<f64>,
    pub area: f64,
}

/// The frame's points every `stride` pixels, in the upright frame (`r_gravity`), without those
/// `removed` (the planes' pixels, when given) and those on or under the `floor`.
pub fn seen_points(
    frame: &Frame<'_>,
    r_gravity: &Matrix3<f64>,
    removed: Option<&[bool]>,
    floor: Option<f64>,
    stride: usize,
) -> Vec<SeenPoint> {
    let cam = &frame.camera;
    let s = stride as f64;
    let mut out = Vec::new();
    for v in (0..cam.height).step_by(stride) {
        for u in (0..cam.width).step_by(stride) {
            let i = v * cam.width + u;
            let z = frame.depth[i];
            if z <= 0.0 || removed.is_some_and(|r| r[i]) {
                continue;
            }
            let z = f64::from(z);
            let p = r_gravity * Vector3::from(cam.k.back_project(u as f64, v as f64, z));
            if floor.is_none_or(|f| p.z > f + FLOOR_CLEARANCE) {
                let area = (s * z / cam.k.fx) * (s * z / cam.k.fy);
                out.push(SeenPoint { p, area });
            }
        }
    }
    out
}

/// A box's profile (see the module docs), every share a fraction of the seen area inside it
/// (all 0 when none is seen).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Profile {
    /// Seen area inside the box over its largest vertical face (length or width, times height).
    pub fill: f64,
    /// Share of the seen area in each fifth of the box's height, bottom first.
    pub levels: [f64; LEVELS],
    /// Share of the seen area in each fifth that lies in the box's back half (its object frame's
    /// +y; the front is -y): a chair's back or a toilet's tank, high at the back.
    pub back: [f64; LEVELS],
    /// Share of the seen area over the box's middle (the central half of its length and width).
    pub middle: f64,
    /// How far the seen surface spans the box: its extent along the box's length and width over
    /// the box's.
    pub span: [f64; 2],
    /// Seen area within [`SHELL`] of the box's sides and top, outside it, over the area inside.
    pub around: f64,
}

/// The profile of the seen `points` in box `b`.
pub fn profile(points: &[SeenPoint], b: &UprightBox) -> Profile {
    let half = [b.size[0] / 2.0, b.size[1] / 2.0];
    let bottom = b.centre[2] - b.size[2] / 2.0;
    let top = bottom + b.size[2];
    let (s, c) = b.yaw.sin_cos();
    let reach = (half[0] + SHELL).hypot(half[1] + SHELL);
    let (mut inside, mut shell, mut middle) = (0.0, 0.0, 0.0);
    let (mut levels, mut back) = ([0.0; LEVELS], [0.0; LEVELS]);
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in points {
        let (dx, dy) = (q.p.x - b.centre[0], q.p.y - b.centre[1]);
        // A quick reject before the rotation: most of a frame is far from any one box.
        if dx.abs() > reach || dy.abs() > reach || q.p.z < bottom || q.p.z > top + SHELL {
            continue;
        }
        let (x, y) = (dx * c + dy * s, -dx * s + dy * c);
        if x.abs() <= half[0] && y.abs() <= half[1] && q.p.z <= top {
            inside += q.area;
            let k = ((((q.p.z - bottom) / b.size[2]) * LEVELS as f64) as usize).min(LEVELS - 1);
            levels[k] += q.area;
            if y > 0.0 {
                back[k] += q.area;
            }
            if x.abs() <= half[0] / 2.0 && y.abs() <= half[1] / 2.0 {
                middle += q.area;
            }
            for (a, v) in [x, y].into_iter().enumerate() {
                lo[a] = lo[a].min(v);
                hi[a] = hi[a].max(v);
            }
        } else if x.abs() <= half[0] + SHELL && y.abs() <= half[1] + SHELL {
            shell += q.area;
        }
    }
    let share = |a: f64| if inside > 0.0 { a / inside } else { 0.0 };
    let span = |a: usize| {
        if inside > 0.0 {
            (hi[a] - lo[a]) / b.size[a]
        } else {
            0.0
        }
    };
    Profile {
        fill: inside / (b.size[0].max(b.size[1]) * b.size[2]).max(1e-12),
        levels: levels.map(share),
        back: back.map(share),
        middle: share(middle),
        span: [span(0), span(1)],
        around: shell / (inside + MIN_AREA),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn boxed(yaw: f64) -> UprightBox {
        // 1 m long (x), 0.5 m wide, 1 m high, standing on z = 0 at (2, 0).
        UprightBox {
            centre: [2.0, 0.0, 0.5],
            size: [1.0, 0.5, 1.0],
            yaw,
            score: 0.0,
        }
    }

    fn pt(x: f64, y: f64, z: f64, area: f64) -> SeenPoint {
        SeenPoint {
            p: Vector3::new(x, y, z),
            area,
        }
    }

    #[test]
    fn shares_are_of_the_area_inside_by_height_and_side() {
        let b = boxed(0.0);
        let pts = [
            pt(2.0, -0.1, 0.05, 0.1), // bottom fifth, front
            pt(2.3, 0.2, 0.95, 0.3),  // top fifth, back
            pt(1.8, 0.1, 0.5, 0.1),   // middle fifth, back
            pt(2.0, 0.3, 0.5, 0.2),   // 5 cm past the side: shell
            pt(2.0, 0.0, 1.1, 0.05),  // 10 cm over the top: shell
            pt(2.0, 0.0, 1.3, 9.0),   // beyond the shell
            pt(4.0, 0.0, 0.5, 9.0),   // far away
        ];
        let p = profile(&pts, &b);
        let inside = 0.5;
        assert!((p.fill - inside / 1.0).abs() < 1e-12);
        let want = [0.1 / inside, 0.0, 0.1 / inside, 0.0, 0.3 / inside];
        for (a, w) in p.levels.iter().zip(want) {
            assert!((a - w).abs() < 1e-12, "{:?}", p.levels);
        }
        let back = [0.0, 0.0, 0.1 / inside, 0.0, 0.3 / inside];
        for (a, w) in p.back.iter().zip(back) {
            assert!((a - w).abs() < 1e-12, "{:?}", p.back);
        }
        // Only (2.0, -0.1) and (1.8, 0.1) lie over the middle (|x| <= 0.25, |y| <= 0.125).
        assert!((p.middle - 0.2 / inside).abs() < 1e-12);
        // Seen from x = 1.8 to 2.3 of a 1 m length, y = -0.1 to 0.2 of a 0.5 m width.
        assert!((p.span[0] - 0.5).abs() < 1e-12 && (p.span[1] - 0.6).abs() < 1e-12);
        assert!((p.around - 0.25 / (inside + MIN_AREA)).abs() < 1e-12);
    }

    #[test]
    fn a_turned_box_turns_its_back() {
        // Yaw 90 degrees: the box's +y (its back) is the upright frame's -x.
        let b = boxed(std::f64::consts::FRAC_PI_2);
        let p = profile(&[pt(1.9, 0.0, 0.5, 1.0)], &b);
        assert!((p.back[2] - 1.0).abs() < 1e-12 && p.around == 0.0);
        let p = profile(&[pt(2.1, 0.0, 0.5, 1.0)], &b);
        assert_eq!(p.back, [0.0; LEVELS]);
        // The box is 0.5 m across x now: 0.3 m off its centre along x is in the shell.
        let p = profile(&[pt(2.3, 0.0, 0.5, 1.0)], &b);
        assert_eq!(p.fill, 0.0);
        assert!((p.around - 1.0 / MIN_AREA).abs() < 1e-9);
        assert_eq!(p.levels, [0.0; LEVELS]);
        assert_eq!((p.middle, p.span), (0.0, [0.0; 2]));
    }

    #[test]
    fn seen_points_cover_the_pixel_area_and_skip_floor_and_planes() {
        use super::super::Camera;
        use crate::vote::Intrinsics;
        let k = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 4.0,
            cy: 4.0,
        };
        let cam = Camera::new(k, 8, 8).unwrap();
        let depth = vec![2.0f32; 64];
        let frame = Frame::new(&depth, cam).unwrap();
        let mut removed = vec![false; 64];
        removed[0] = true;
        // Upright frame = camera frame: the optical axis is "up", so every point is at height 2.
        let rg = Matrix3::identity();
        let pts = seen_points(&frame, &rg, Some(&removed), None, 2);
        assert_eq!(pts.len(), 15);
        assert!(pts
            .iter()
            .all(|q| (q.area - (2.0 * 2.0 / 100.0f64).powi(2)).abs() < 1e-15));
        // Every point is at z = 2 here: a floor at 1.99 leaves them (1 cm is under the clearance).
        assert!(seen_points(&frame, &rg, None, Some(1.99), 2).is_empty());
        assert_eq!(seen_points(&frame, &rg, None, Some(1.9), 2).len(), 16);
    }
}
