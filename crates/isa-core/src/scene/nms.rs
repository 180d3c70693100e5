//! Gravity-aligned boxes in the upright frame and non-maximum suppression across categories
//! (as `isa.evaluation.boxes3d` and `isa.detection.multi.nms_across`).

/// A gravity-aligned oriented box: `centre` (upright frame), full extents `size` (along its yaw
/// direction, across it, height), `yaw` (radians), `score`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UprightBox {
    pub centre: [f64; 3],
    pub size: [f64; 3],
    pub yaw: f64,
    pub score: f64,
}

impl UprightBox {
    pub fn volume(&self) -> f64 {
        self.size[0] * self.size[1] * self.size[2]
    }

    /// The 4 floor-plan corners, counter-clockwise seen from above.
    pub fn footprint(&self) -> [[f64; 2]; 4] {
        let (hl, hw) = (self.size[0] / 2.0, self.size[1] / 2.0);
        let (s, c) = self.yaw.sin_cos();
        [[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]].map(|[x, y]| {
            [
                x * c - y * s + self.centre[0],
                x * s + y * c + self.centre[1],
            ]
        })
    }
}

/// Signed (shoelace) area, positive counter-clockwise.
fn polygon_area(p: &[[f64; 2]]) -> f64 {
    if p.len() < 3 {
        return 0.0;
    }
    let n = p.len();
    0.5 * (0..n)
        .map(|i| p[i][0] * p[(i + 1) % n][1] - p[i][1] * p[(i + 1) % n][0])
        .sum::<f64>()
}

/// Sutherland-Hodgman: the part of `subject` inside the convex counter-clockwise `clip`.
fn clip_convex(subject: &[[f64; 2]], clip: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut out = subject.to_vec();
    // Points this close to an edge count as on it (identical boxes keep their vertices).
    let scale = clip.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs()));
    let eps = 1e-12 * scale * scale;
    for i in 0..clip.len() {
        if out.is_empty() {
            break;
        }
        let [ax, ay] = clip[i];
        let [bx, by] = clip[(i + 1) % clip.len()];
        let (ex, ey) = (bx - ax, by - ay);
        let side = |p: &[f64; 2]| ex * (p[1] - ay) - ey * (p[0] - ax);
        let cross = |p: &[f64; 2], q: &[f64; 2], sp: f64, sq: f64| {
            let t = sp / (sp - sq);
            [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]
        };
        let inp = std::mem::take(&mut out);
        let mut prev = *inp.last().expect("non-empty");
        let mut s_prev = side(&prev);
        for cur in inp {
            let s_cur = side(&cur);
            if s_cur >= -eps {
                if s_prev < -eps {
                    out.push(cross(&prev, &cur, s_prev, s_cur));
                }
                out.push(cur);
            } else if s_prev >= -eps {
                out.push(cross(&prev, &cur, s_prev, s_cur));
            }
            prev = cur;
            s_prev = s_cur;
        }
    }
    out
}

/// The 3D intersection volume of two boxes.
pub fn intersection(a: &UprightBox, b: &UprightBox) -> f64 {
    let dz = (a.centre[2] + a.size[2] / 2.0).min(b.centre[2] + b.size[2] / 2.0)
        - (a.centre[2] - a.size[2] / 2.0).max(b.centre[2] - b.size[2] / 2.0);
    if dz <= 0.0 {
        return 0.0;
    }
    let ra = 0.5 * a.size[0].hypot(a.size[1]);
    let rb = 0.5 * b.size[0].hypot(b.size[1]);
    if (a.centre[0] - b.centre[0]).hypot(a.centre[1] - b.centre[1]) >= ra + rb {
        return 0.0;
    }
    polygon_area(&clip_convex(&a.footprint(), &b.footprint())).max(0.0) * dz
}

/// Exact 3D IoU of two boxes.
pub fn iou(a: &UprightBox, b: &UprightBox) -> f64 {
    let inter = intersection(a, b);
    if inter <= 0.0 {
        return 0.0;
    }
    (inter / (a.volume() + b.volume() - inter)).min(1.0)
}

/// Greedy NMS over boxes of any category, best score first (ties: the earlier box): a box goes
/// when its IoU with a kept one exceeds `max_iou`, or when it is no larger and more than
/// `max_overlap` of its volume lies inside a kept one. Returns the kept indices, best first.
pub fn nms_across(boxes: &[UprightBox], max_iou: f64, max_overlap: f64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&i, &j| boxes[j].score.total_cmp(&boxes[i].score));
    let mut kept: Vec<usize> = Vec::new();
    for i in order {
        let a = &boxes[i];
        let ok = kept.iter().all(|&k| {
            let b = &boxes[k];
            let inter = intersection(a, b);
            if inter <= 0.0 {
                return true;
            }
            let o_iou = (inter / (a.volume() + b.volume() - inter)).min(1.0);
            !(o_iou > max_iou || (a.volume() <= b.volume() && inter / a.volume() > max_overlap))
        });
        if ok {
            kept.push(i);
        }
    }
    kept
}

/// [`nms_across`] within each group (`group[i]` of box `i`, e.g. its category) only, at most
/// `max_per_group` kept in each: the kept indices of every group, best score first.
pub fn nms_within(
    boxes: &[UprightBox],
    group: &[usize],
    max_iou: f64,
    max_overlap: f64,
    max_per_group: usize,
) -> Vec<usize> {
    let mut groups: Vec<usize> = group.to_vec();
    groups.sort_unstable();
    groups.dedup();
    let mut keep: Vec<usize> = Vec::new();
    for g in groups {
        let mine: Vec<usize> = (0..boxes.len()).filter(|&i| group[i] == g).collect();
        let b: Vec<UprightBox> = mine.iter().map(|&i| boxes[i]).collect();
        let mut k = nms_across(&b, max_iou, max_overlap);
        k.truncate(max_per_group);
        keep.extend(k.into_iter().map(|j| mine[j]));
    }
    // Stable: ties keep the group order.
    keep.sort_by(|&a, &b| boxes[b].score.total_cmp(&boxes[a].score));
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    fn b(x: f64, y: f64, size: [f64; 3], yaw: f64, score: f64) -> UprightBox {
        UprightBox {
            centre: [x, y, size[2] / 2.0],
            size,
            yaw,
            score,
        }
    }

    #[test]
    fn iou_of_analytic_cases() {
        let a = b(0.0, 0.0, [1.0, 1.0, 1.0], 0.0, 1.0);
        assert!((iou(&a, &a) - 1.0).abs() < 1e-12);
        // half-shifted along x: intersection 0.5, union 1.5
        assert!((iou(&a, &b(0.5, 0.0, [1.0, 1.0, 1.0], 0.0, 1.0)) - 1.0 / 3.0).abs() < 1e-12);
        // a unit square turned 45 degrees over itself: the octagon of area 2 (sqrt 2 - 1)
        let r = b(0.0, 0.0, [1.0, 1.0, 1.0], std::f64::consts::FRAC_PI_4, 1.0);
        let oct = 2.0 * (2f64.sqrt() - 1.0);
        assert!((intersection(&a, &r) - oct).abs() < 1e-12);
        assert_eq!(iou(&a, &b(3.0, 0.0, [1.0, 1.0, 1.0], 0.3, 1.0)), 0.0);
        // stacked, not overlapping in height
        let mut up = a;
        up.centre[2] += 1.0;
        assert_eq!(iou(&a, &up), 0.0);
    }

    #[test]
    fn nms_keeps_one_box_per_object_across_categories() {
        let chair = b(0.0, 0.0, [0.5, 0.5, 0.9], 0.1, 0.9);
        let toilet_in_chair = b(0.02, 0.0, [0.4, 0.4, 0.7], 0.0, 0.5); // smaller, inside: goes
        let chair_shifted = b(0.05, 0.03, [0.5, 0.5, 0.9], 0.2, 0.7); // IoU > 0.25: goes
        let bed = b(0.5, 0.0, [2.0, 1.5, 0.6], 0.0, 0.4); // larger, the chair inside it: stays
        let table = b(3.0, 0.0, [1.2, 0.8, 0.75], 0.0, 0.3); // elsewhere: stays
        let boxes = [toilet_in_chair, bed, chair, table, chair_shifted];
        assert_eq!(nms_across(&boxes, 0.25, 0.6), vec![2, 1, 3]);
    }

    /// Within groups, an overlapping box of another group stays (across groups it would go);
    /// duplicates within a group go, and each group keeps at most its share.
    #[test]
    fn nms_within_groups_leaves_other_groups_alone() {
        let chair = b(0.0, 0.0, [0.5, 0.5, 0.9], 0.0, 0.9);
        let chair_dup = b(0.05, 0.0, [0.5, 0.5, 0.9], 0.1, 0.8);
        let toilet = b(0.02, 0.0, [0.45, 0.6, 0.8], 0.0, 0.95);
        let far = b(3.0, 0.0, [0.5, 0.5, 0.9], 0.0, 0.5);
        let boxes = [chair, chair_dup, toilet, far];
        assert_eq!(nms_across(&boxes, 0.25, 0.6), vec![2, 3]);
        assert_eq!(
            nms_within(&boxes, &[0, 0, 1, 0], 0.25, 0.6, 10),
            vec![2, 0, 3]
        );
        assert_eq!(nms_within(&boxes, &[0, 0, 1, 0], 0.25, 0.6, 1), vec![2, 0]);
        assert_eq!(
            nms_within(&boxes, &[0, 1, 2, 3], 0.25, 0.6, 10),
            vec![2, 0, 1, 3]
        );
    }
}
