//! Hypotheses from the frame's own geometry. Once the floor and walls are set aside, what stands
//! on the floor falls apart into footprints: connected cells of a grid over the floor that hold
//! points. Each footprint proposes, for every category, the category's box in the four yaws
//! along the footprint's minimum-area rectangle, placed to cover the seen part and to reach away
//! from the camera (the side it cannot see). The forests still weigh in: a proposal carries the
//! score of its category's best hypothesis over the footprint, and verification decides.
//!
//! Why: in a room the forests' modes often miss an object a few decimetres away, or not at
//! all (issue 17: half the chairs of the validation rooms had no hypothesis whose box met
//! theirs at IoU 0.25), while the object itself stands clear of the floor.

use std::collections::VecDeque;
use std::f64::consts::FRAC_PI_2;

use nalgebra::Vector3;

use super::shapes::SizeRange;
use crate::params::ProposalParams;

/// Yaw steps of the minimum-area rectangle search (over a quarter turn).
const RECT_STEPS: usize = 45;
/// Points the rectangle search looks at, at most.
const RECT_POINTS: usize = 4000;

/// One footprint: its minimum-area rectangle in the upright frame (centre, yaw of its first
/// axis, half extents), the points' highest height above the floor and their count.
#[derive(Clone, Debug, PartialEq)]
pub struct Footprint {
    pub centre: [f64; 2],
    pub yaw: f64,
    pub half: [f64; 2],
    pub top: f64,
    pub n_points: usize,
}

impl Footprint {
    /// `[lo, hi]` of the rectangle's projection on the horizontal unit direction `d`.
    fn span(&self, d: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.yaw.sin_cos();
        let (u, v) = ([c, s], [-s, c]);
        let mid = self.centre[0] * d[0] + self.centre[1] * d[1];
        let r = (d[0] * u[0] + d[1] * u[1]).abs() * self.half[0]
            + (d[0] * v[0] + d[1] * v[1]).abs() * self.half[1];
        [mid - r, mid + r]
    }

    /// True when the horizontal point `q` lies in the rectangle grown by `margin`.
    pub fn contains(&self, q: [f64; 2], margin: f64) -> bool {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (q[0] - self.centre[0], q[1] - self.centre[1]);
        (dx * c + dy * s).abs() <= self.half[0] + margin
            && (-dx * s + dy * c).abs() <= self.half[1] + margin
    }

    /// Whether the footprint could be an object of sizes `range` (widened by `margin`, a
    /// fraction, and then by `slack` metres): its longer side no longer than the longest and
    /// its top between the lowest and the highest.
    pub fn fits(&self, range: &SizeRange, margin: f64, slack: f64) -> bool {
        let long = 2.0 * self.half[0].max(self.half[1]);
        long <= (1.0 + margin) * range.length[1] + slack
            && self.top >= (1.0 - margin) * range.height[0] - slack
            && self.top <= (1.0 + margin) * range.height[1] + slack
    }

    /// A box of extents `size` (object x, y, z) standing on the floor at `floor`, in the four
    /// yaws along the rectangle: `(yaw, box centre)` in the upright frame (the camera at the
    /// origin). Along each horizontal axis a box longer than the footprint starts at the
    /// footprint's side nearer the camera and reaches away from it.
    pub fn boxes(&self, size: [f64; 3], floor: f64) -> [(f64, Vector3<f64>); 4] {
        std::array::from_fn(|k| {
            let yaw = self.yaw + k as f64 * FRAC_PI_2;
            let (s, c) = yaw.sin_cos();
            let mut centre = Vector3::new(0.0, 0.0, floor + size[2] / 2.0);
            for (d, len) in [([c, s], size[0]), ([-s, c], size[1])] {
                let [lo, hi] = self.span(d);
                let along = if hi - lo >= len {
                    (lo + hi) / 2.0
                } else if lo >= 0.0 {
                    lo + len / 2.0
                } else if hi <= 0.0 {
                    hi - len / 2.0
                } else {
                    (lo + hi) / 2.0
                };
                centre.x += along * d[0];
                centre.y += along * d[1];
            }
            (yaw, centre)
        })
    }
}

/// The footprints of the upright-frame points `points` (floor and walls already left out)
/// standing on the floor at height `floor`: points between `clearance` and `max_height` above
/// it, binned in `cell`-metre cells; cells with `min_cell_points` points or more are occupied,
/// and 8-connected occupied cells form a footprint, kept when it holds `min_points` points.
/// Largest first.
pub fn footprints(points: &[Vector3<f64>], floor: f64, p: &ProposalParams) -> Vec<Footprint> {
    let kept: Vec<&Vector3<f64>> = points
        .iter()
        .filter(|q| q.z > floor + p.clearance && q.z < floor + p.max_height)
        .collect();
    if kept.is_empty() {
        return Vec::new();
    }
    let lo = [0, 1].map(|k| kept.iter().map(|q| q[k]).fold(f64::INFINITY, f64::min));
    let hi = [0, 1].map(|k| kept.iter().map(|q| q[k]).fold(f64::NEG_INFINITY, f64::max));
    let dims = [0, 1].map(|k| ((hi[k] - lo[k]) / p.cell) as usize + 1);
    let cell_of = |q: &Vector3<f64>| {
        let i = (((q.x - lo[0]) / p.cell) as usize).min(dims[0] - 1);
        let j = (((q.y - lo[1]) / p.cell) as usize).min(dims[1] - 1);
        j * dims[0] + i
    };
    let mut count = vec![0u32; dims[0] * dims[1]];
    for q in &kept {
        count[cell_of(q)] += 1;
    }
    let occupied = |c: usize| count[c] as usize >= p.min_cell_points.max(1);
    // Connected components of the occupied cells (breadth first), numbered in cell order.
    let mut label = vec![usize::MAX; count.len()];
    let mut sizes: Vec<usize> = Vec::new();
    let mut queue = VecDeque::new();
    for seed in 0..count.len() {
        if label[seed] != usize::MAX || !occupied(seed) {
            continue;
        }
        let id = sizes.len();
        sizes.push(0);
        label[seed] = id;
        queue.push_back(seed);
        while let Some(c) = queue.pop_front() {
            sizes[id] += count[c] as usize;
            let (i, j) = ((c % dims[0]) as i64, (c / dims[0]) as i64);
            for (di, dj) in [
                (-1, -1),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let (a, b) = (i + di, j + dj);
                if a < 0 || b < 0 || a >= dims[0] as i64 || b >= dims[1] as i64 {
                    continue;
                }
                let n = b as usize * dims[0] + a as usize;
                if label[n] == usize::MAX && occupied(n) {
                    label[n] = id;
                    queue.push_back(n);
                }
            }
        }
    }
    let mut members: Vec<Vec<[f64; 2]>> = vec![Vec::new(); sizes.len()];
    let mut tops = vec![f64::NEG_INFINITY; sizes.len()];
    for q in &kept {
        let l = label[cell_of(q)];
        if l != usize::MAX && sizes[l] >= p.min_points {
            members[l].push([q.x, q.y]);
            tops[l] = tops[l].max(q.z);
        }
    }
    let mut out: Vec<Footprint> = members
        .iter()
        .zip(&tops)
        .filter(|(m, _)| !m.is_empty())
        .map(|(m, &top)| min_area_rectangle(m, top - floor))
        .collect();
    out.sort_by_key(|f| std::cmp::Reverse(f.n_points));
    out
}

/// The smallest-area rectangle (yaw steps of 2 degrees) around the horizontal points `pts` (at
/// most `RECT_POINTS` of them, evenly subsampled, are used).
fn min_area_rectangle(pts: &[[f64; 2]], top: f64) -> Footprint {
    let step = pts.len().div_ceil(RECT_POINTS).max(1);
    let mut best: Option<(f64, Footprint)> = None;
    for k in 0..RECT_STEPS {
        let yaw = k as f64 * FRAC_PI_2 / RECT_STEPS as f64;
        let (s, c) = yaw.sin_cos();
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for q in pts.iter().step_by(step) {
            let a = [q[0] * c + q[1] * s, -q[0] * s + q[1] * c];
            for i in 0..2 {
                lo[i] = lo[i].min(a[i]);
                hi[i] = hi[i].max(a[i]);
            }
        }
        let half = [0, 1].map(|i| (hi[i] - lo[i]) / 2.0);
        let area = half[0] * half[1];
        if best.as_ref().is_none_or(|b| area < b.0) {
            let (m0, m1) = ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0);
            let fp = Footprint {
                centre: [m0 * c - m1 * s, m0 * s + m1 * c],
                yaw,
                half,
                top,
                n_points: pts.len(),
            };
            best = Some((area, fp));
        }
    }
    best.expect("at least one yaw step").1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::rot_z;

    /// Points filling the rectangle `centre`, `half`, turned by `yaw`, up to `height`, 1 cm apart.
    fn block(centre: [f64; 2], half: [f64; 2], yaw: f64, height: f64) -> Vec<Vector3<f64>> {
        let r = rot_z(yaw);
        let mut out = Vec::new();
        let n = [0, 1].map(|k| (2.0 * half[k] / 0.01) as i64);
        for i in 0..=n[0] {
            for j in 0..=n[1] {
                for h in [0.2, height] {
                    let q = Vector3::new(-half[0] + i as f64 * 0.01, -half[1] + j as f64 * 0.01, h);
                    out.push(r * q + Vector3::new(centre[0], centre[1], 0.0));
                }
            }
        }
        out
    }

    #[test]
    fn two_blocks_are_two_turned_rectangles() {
        // A 1.0 x 0.4 m block turned 30 degrees and a 0.5 x 0.5 m one 1 m away, on the floor
        // at z = 0; a point under the floor's clearance and one on the ceiling are left out.
        let mut pts = block([2.0, 0.5], [0.5, 0.2], 30f64.to_radians(), 0.7);
        pts.extend(block([0.5, 2.0], [0.25, 0.25], 0.0, 0.45));
        pts.push(Vector3::new(-1.0, -1.0, 0.01));
        pts.push(Vector3::new(-1.0, -1.0, 2.5));
        let fps = footprints(&pts, 0.0, &ProposalParams::default());
        assert_eq!(fps.len(), 2, "{fps:?}");
        let a = &fps[0];
        assert!(
            (a.centre[0] - 2.0).abs() < 0.04 && (a.centre[1] - 0.5).abs() < 0.04,
            "{a:?}"
        );
        // The long axis along 30 degrees (the search covers a quarter turn).
        assert!((a.yaw.to_degrees() - 30.0).abs() < 3.0, "{a:?}");
        assert!(
            (a.half[0] - 0.5).abs() < 0.05 && (a.half[1] - 0.2).abs() < 0.05,
            "{a:?}"
        );
        assert!((a.top - 0.7).abs() < 1e-9);
        let b = &fps[1];
        assert!(
            (b.centre[0] - 0.5).abs() < 0.04 && (b.centre[1] - 2.0).abs() < 0.04,
            "{b:?}"
        );
        assert!(a.contains([2.3, 0.6], 0.0) && !a.contains([0.5, 2.0], 0.1));
        // The 1 m long, 0.7 m high block could be a table but not a chair.
        let table = SizeRange {
            height: [0.38, 0.8],
            length: [0.45, 2.2],
        };
        let chair = SizeRange {
            height: [0.75, 1.1],
            length: [0.42, 0.75],
        };
        assert!(a.fits(&table, 0.15, 0.1) && !a.fits(&chair, 0.15, 0.1));
        // 0.5 m wide but 0.45 m high: lower than 0.85 x 0.75 - 0.1 m, within 0.2 m of it.
        assert!(!b.fits(&chair, 0.15, 0.1) && b.fits(&chair, 0.15, 0.2));
    }

    #[test]
    fn a_longer_box_reaches_away_from_the_camera() {
        // The seen front 0.3 m of an object 1 m deep, 2 m in front of the camera along y.
        let fp = Footprint {
            centre: [0.0, 2.15],
            yaw: 0.0,
            half: [0.4, 0.15],
            top: 0.5,
            n_points: 100,
        };
        let boxes = fp.boxes([0.8, 1.0, 0.5], -1.0);
        let (yaw, c) = boxes[0];
        assert_eq!(yaw, 0.0);
        // Along x the footprint is as wide as the box: centred; along y it starts at 2.0.
        assert!(
            (c.x - 0.0).abs() < 1e-12 && (c.y - 2.5).abs() < 1e-12,
            "{c}"
        );
        assert!((c.z - (-0.75)).abs() < 1e-12);
        // A quarter turn: the box's 0.8 m x runs along world y.
        let (_, c1) = boxes[1];
        assert!((c1.y - 2.4).abs() < 1e-12 && c1.x.abs() < 1e-12, "{c1}");
        // Behind the camera the box reaches the other way.
        let back = Footprint {
            centre: [0.0, -2.15],
            ..fp
        };
        assert!((back.boxes([0.8, 1.0, 0.5], 0.0)[0].1.y + 2.5).abs() < 1e-12);
    }
}
