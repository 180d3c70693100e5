//! The rasteriser behind [`render_depth`](super::render_depth): clipping at the near plane,
//! triangle set-up (edge functions in a canonical order, the tie rule), and the z-buffer,
//! filled a band of rows at a time.

use rayon::prelude::*;

use super::RenderCamera;
use crate::vote::Intrinsics;

/// Rows per band of the z-buffer (one parallel task): small enough to balance two to a few
/// dozen threads on a 480-row frame, large enough that a triangle is rarely in many bands.
const BAND_ROWS: usize = 8;

/// A projected vertex: pixel coordinates and the inverse of its depth.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Vert {
    u: f64,
    v: f64,
    iz: f64,
}

/// The camera point `p` (`p[2] > 0`) in pixels. A vertex is projected by the same operations
/// wherever it appears, so the triangles that share it see the same bits.
fn project(p: [f64; 3], k: &Intrinsics) -> Vert {
    Vert {
        u: k.fx * p[0] / p[2] + k.cx,
        v: k.fy * p[1] / p[2] + k.cy,
        iz: 1.0 / p[2],
    }
}

/// The edge function of the directed edge `a -> b`, `e(p) = (b - a) x (p - a)`, computed from
/// the endpoints in one canonical order (lexicographic on `(u, v)`) and negated when `a -> b`
/// runs against it: the triangle on the other side of a shared edge evaluates exactly `-e(p)`,
/// so a pixel centre is never inside both nor, with [`Edge::tie`], outside both.
#[derive(Clone, Copy, Debug)]
struct Edge {
    lo_u: f64,
    lo_v: f64,
    du: f64,
    dv: f64,
    sign: f64,
    /// Whether a centre exactly on the edge is covered: top and left edges (the Direct3D
    /// rule; in image coordinates, v down, of a triangle whose inside has `e > 0`, a left edge
    /// runs upwards and a top edge runs rightwards). Of the two directions of an edge exactly
    /// one qualifies, so a shared edge's pixels go to exactly one of its triangles.
    tie: bool,
}

impl Edge {
    fn new(a: Vert, b: Vert) -> Edge {
        let forward = (a.u, a.v) < (b.u, b.v);
        let (lo, hi, sign) = if forward { (a, b, 1.0) } else { (b, a, -1.0) };
        let (du, dv) = (hi.u - lo.u, hi.v - lo.v);
        let (dx, dy) = (sign * du, sign * dv); // a -> b
        Edge {
            lo_u: lo.u,
            lo_v: lo.v,
            du,
            dv,
            sign,
            tie: dy < 0.0 || (dy == 0.0 && dx > 0.0),
        }
    }

    #[inline]
    fn eval(&self, u: f64, v: f64) -> f64 {
        self.sign * (self.du * (v - self.lo_v) - self.dv * (u - self.lo_u))
    }

    #[inline]
    fn covers(&self, e: f64) -> bool {
        e > 0.0 || (e == 0.0 && self.tie)
    }
}

/// A triangle ready to draw: its edges (inside where all are positive), the inverse depth of
/// the vertex opposite each edge (the edge's value is that vertex's barycentric weight, up to
/// the common factor), and its pixel bounding box, inclusive.
#[derive(Clone, Copy, Debug)]
struct Tri {
    edges: [Edge; 3],
    iz_opposite: [f64; 3],
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

impl Tri {
    /// `None` for a triangle with no area or no pixel centre in its box.
    fn new(a: Vert, mut b: Vert, mut c: Vert, width: usize, height: usize) -> Option<Tri> {
        let edges = |a, b, c| [Edge::new(a, b), Edge::new(b, c), Edge::new(c, a)];
        let area = |e: &[Edge; 3], a: Vert, b: Vert, c: Vert| {
            e[0].eval(c.u, c.v) + e[1].eval(a.u, a.v) + e[2].eval(b.u, b.v)
        };
        let mut e = edges(a, b, c);
        let s = area(&e, a, b, c);
        if !(s.is_finite() && s != 0.0) {
            return None;
        }
        if s < 0.0 {
            // The other winding: the same edges reversed, whose values are exactly negated.
            std::mem::swap(&mut b, &mut c);
            e = edges(a, b, c);
        }
        let (umin, umax) = (a.u.min(b.u).min(c.u), a.u.max(b.u).max(c.u));
        let (vmin, vmax) = (a.v.min(b.v).min(c.v), a.v.max(b.v).max(c.v));
        let (x0, x1) = pixel_span(umin, umax, width)?;
        let (y0, y1) = pixel_span(vmin, vmax, height)?;
        Some(Tri {
            edges: e,
            iz_opposite: [c.iz, a.iz, b.iz],
            x0,
            x1,
            y0,
            y1,
        })
    }

    /// Draws the triangle's pixels in rows `band_y0..` of `band` (whole rows of `width`),
    /// keeping the nearer depth (the earlier triangle on an exact tie).
    fn draw(&self, band: &mut [f64], band_y0: usize, width: usize, zfar: f64) {
        let band_y1 = band_y0 + band.len() / width - 1;
        let [e0, e1, e2] = &self.edges;
        let [iz0, iz1, iz2] = self.iz_opposite;
        for y in self.y0.max(band_y0)..=self.y1.min(band_y1) {
            let v = y as f64;
            let row = &mut band[(y - band_y0) * width..][..width];
            for (z_old, x) in row[self.x0..=self.x1].iter_mut().zip(self.x0..) {
                let u = x as f64;
                let w0 = e0.eval(u, v);
                if !e0.covers(w0) {
                    continue;
                }
                let w1 = e1.eval(u, v);
                if !e1.covers(w1) {
                    continue;
                }
                let w2 = e2.eval(u, v);
                if !e2.covers(w2) {
                    continue;
                }
                // 1/z is affine in the image: its barycentric mean is the plane's exact 1/z.
                let z = (w0 + w1 + w2) / (w0 * iz0 + w1 * iz1 + w2 * iz2);
                if z <= zfar && z < *z_old {
                    *z_old = z;
                }
            }
        }
    }
}

/// The integer pixel centres in `[lo, hi]` clamped to `0..size`, or `None` if there are none.
fn pixel_span(lo: f64, hi: f64, size: usize) -> Option<(usize, usize)> {
    let last = (size - 1) as f64;
    let (lo, hi) = (lo.ceil().max(0.0), hi.floor().min(last));
    (lo <= hi).then_some((lo as usize, hi as usize))
}

/// The triangles of one face in camera coordinates: none (behind the near plane or without
/// area), one, or two (a face cut by the near plane is a quadrilateral, drawn as a fan).
fn face_triangles(p: [[f64; 3]; 3], camera: &RenderCamera) -> impl Iterator<Item = Tri> {
    let (k, zn) = (&camera.k, camera.znear);
    let inside = |q: &[f64; 3]| q[2] >= zn;
    let mut poly = [Vert {
        u: 0.0,
        v: 0.0,
        iz: 0.0,
    }; 4];
    let mut n = 0;
    for i in 0..3 {
        let (a, b) = (p[i], p[(i + 1) % 3]);
        if inside(&a) {
            poly[n] = project(a, k);
            n += 1;
        }
        if inside(&a) != inside(&b) {
            // From the inside end whichever way the face runs, so that the faces sharing this
            // edge compute the same point.
            let (i_, o_) = if inside(&a) { (a, b) } else { (b, a) };
            let s = (zn - i_[2]) / (o_[2] - i_[2]);
            let q = [i_[0] + s * (o_[0] - i_[0]), i_[1] + s * (o_[1] - i_[1]), zn];
            poly[n] = project(q, k);
            n += 1;
        }
    }
    let (w, h) = (camera.width, camera.height);
    let first = (n >= 3).then(|| Tri::new(poly[0], poly[1], poly[2], w, h));
    let second = (n == 4).then(|| Tri::new(poly[0], poly[2], poly[3], w, h));
    first.flatten().into_iter().chain(second.flatten())
}

/// The z-buffer (row-major, metres, `+inf` where nothing is) of the faces of `cam_points`
/// (finite camera coordinates; indices checked by the caller).
pub(super) fn rasterise(
    cam_points: &[[f64; 3]],
    faces: &[[u32; 3]],
    camera: &RenderCamera,
) -> Vec<f64> {
    let (w, h) = (camera.width, camera.height);
    let tris: Vec<Tri> = faces
        .par_iter()
        .flat_map_iter(|f| face_triangles(f.map(|i| cam_points[i as usize]), camera))
        .collect();
    // Each band's triangles in face order: the order ties are broken in, for any thread count.
    let n_bands = h.div_ceil(BAND_ROWS);
    let mut bands: Vec<Vec<usize>> = vec![Vec::new(); n_bands];
    for (i, t) in tris.iter().enumerate() {
        for band in &mut bands[t.y0 / BAND_ROWS..=t.y1 / BAND_ROWS] {
            band.push(i);
        }
    }
    let mut z = vec![f64::INFINITY; w * h];
    z.par_chunks_mut(w * BAND_ROWS)
        .zip(bands.par_iter())
        .enumerate()
        .for_each(|(b, (rows, list))| {
            for &i in list {
                tris[i].draw(rows, b * BAND_ROWS, w, camera.zfar);
            }
        });
    z
}
