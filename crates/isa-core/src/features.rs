//! The split function of the paper (Eq. 5): a two-pixel depth comparison with
//! depth-normalised offsets,
//!
//! `f(w) = D(w + u / D(w)) - D(w + v / D(w))`,
//!
//! with `u`, `v` in pixel·metres, `D(w)` the part centre's depth in **metres** for the
//! normalisation and the probed depths in **millimetres** for the value (so `f` is in mm).
//!
//! Rules (as Shotton et al.):
//! * a probe lands on the nearest pixel: `w + floor(u * (1000 / D_mm) + 0.5)` per axis, with the
//!   product evaluated in `f32`;
//! * a probe outside the image or on missing depth (0) reads [`BACKGROUND_MM`], a large
//!   constant background depth.

use serde::{Deserialize, Serialize};

use crate::depth::{DepthStore, ImageRef, Part};
use crate::probe::probe;

/// Largest feature offset component (pixel·metres): the bound of `ForestParams::max_offset`
/// and of every split feature a model file may hold. Probes at this offset land far outside
/// any image and stay exact in integer pixel arithmetic.
pub const MAX_FEATURE_OFFSET: f32 = 1e5;

/// Depth (mm) read by a probe outside the image or on a pixel with missing depth.
pub const BACKGROUND_MM: f32 = 10_000.0;

/// Feature parameters ψ = (u, v): two pixel·metre offsets `[du, dv]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Feature {
    pub u: [f32; 2],
    pub v: [f32; 2],
}

impl Feature {
    /// Evaluates the feature at pixel (x, y) of `img`, whose depth there is `d_mm` (> 0).
    #[inline(always)]
    pub fn eval_at(&self, img: &ImageRef<'_>, x: i32, y: i32, d_mm: u16) -> f32 {
        let inv = 1000.0f32 / d_mm as f32;
        probe(img, x, y, self.u, inv) - probe(img, x, y, self.v, inv)
    }

    /// Evaluates the feature on a validated part.
    #[inline(always)]
    pub fn eval(&self, store: &DepthStore, p: &Part) -> f32 {
        let img = store.image(p[0] as usize);
        let d = img.get(p[1], p[2]);
        if d == 0 {
            // Only reachable with unvalidated parts; both probes then behave like background.
            return 0.0;
        }
        self.eval_at(&img, p[1], p[2], d)
    }
}

/// A part with its image and centre-depth normalisation resolved once, for evaluating many
/// candidates on it.
#[derive(Clone, Copy, Debug)]
pub struct PartGeom<'a> {
    pub(crate) img: ImageRef<'a>,
    pub(crate) x: i32,
    pub(crate) y: i32,
    /// 1000 / D_mm(w), or 0 for a part without depth (then every feature is 0).
    pub(crate) inv: f32,
}

impl<'a> PartGeom<'a> {
    #[inline]
    pub fn new(store: &'a DepthStore, p: &Part) -> Self {
        let img = store.image(p[0] as usize);
        let d = img.get(p[1], p[2]);
        PartGeom {
            img,
            x: p[1],
            y: p[2],
            inv: if d == 0 { 0.0 } else { 1000.0f32 / d as f32 },
        }
    }

    /// Same value as [`Feature::eval`] on this part.
    #[inline(always)]
    pub fn eval(&self, f: &Feature) -> f32 {
        if self.inv == 0.0 {
            return 0.0;
        }
        probe(&self.img, self.x, self.y, f.u, self.inv)
            - probe(&self.img, self.x, self.y, f.v, self.inv)
    }
}

/// Candidates in structure-of-arrays form (`u_x, u_y, v_x, v_y`), zero-padded to a multiple
/// of 8, for the vectorised feature + binning path.
#[derive(Clone, Debug, Default)]
pub struct CandidateSoa {
    pub ux: Vec<f32>,
    pub uy: Vec<f32>,
    pub vx: Vec<f32>,
    pub vy: Vec<f32>,
    pub n: usize,
}

impl CandidateSoa {
    pub fn new(cands: &[Feature]) -> Self {
        let n8 = cands.len().div_ceil(8) * 8;
        let col = |f: &dyn Fn(&Feature) -> f32| {
            let mut v: Vec<f32> = cands.iter().map(f).collect();
            v.resize(n8, 0.0);
            v
        };
        CandidateSoa {
            ux: col(&|c| c.u[0]),
            uy: col(&|c| c.u[1]),
            vx: col(&|c| c.v[0]),
            vy: col(&|c| c.v[1]),
            n: cands.len(),
        }
    }
}

/// Features of every part for every candidate: `(parts.len(), feats.len())` row-major.
pub fn eval_matrix(store: &DepthStore, parts: &[Part], feats: &[Feature]) -> Vec<f32> {
    use rayon::prelude::*;
    let c = feats.len();
    let mut out = vec![0f32; parts.len() * c];
    if c == 0 {
        return out;
    }
    out.par_chunks_mut(c)
        .zip(parts.par_iter())
        .for_each(|(row, p)| {
            for (o, f) in row.iter_mut().zip(feats) {
                *o = f.eval(store, p);
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_pixel_test_with_background_rule() {
        let mut s = DepthStore::new();
        // 5x5, depth 2000 mm everywhere except a missing pixel at (4, 2).
        let mut px = vec![2000u16; 25];
        px[2 * 5 + 4] = 0;
        px[2 * 5 + 3] = 1500;
        s.push(5, 5, &px).unwrap();
        let p = [0, 2, 2];
        // u = 2 px·m at 2 m -> 1 px right: (3,2) = 1500; v = 0 -> centre 2000.
        let f = Feature {
            u: [2.0, 0.0],
            v: [0.0, 0.0],
        };
        assert_eq!(f.eval(&s, &p), -500.0);
        // 4 px·m -> 2 px right: missing -> background.
        let f = Feature {
            u: [4.0, 0.0],
            v: [0.0, 0.0],
        };
        assert_eq!(f.eval(&s, &p), BACKGROUND_MM - 2000.0);
        // Far outside on both probes -> 0.
        let f = Feature {
            u: [100.0, 0.0],
            v: [0.0, -100.0],
        };
        assert_eq!(f.eval(&s, &p), 0.0);
        // Rounding: 1.0 px·m at 2 m = 0.5 px rounds up to 1.
        let f = Feature {
            u: [1.0, 0.0],
            v: [-1.0, 0.0],
        };
        assert_eq!(f.eval(&s, &p), 1500.0 - 2000.0);
        assert_eq!(PartGeom::new(&s, &p).eval(&f), f.eval(&s, &p));
    }
}
