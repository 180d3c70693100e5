//! Split quality: the paper's criterion terms Q1, Q2, Q3 (Eq. 9-11) as separate, composable
//! information gains
//!
//! `Q = H(S) - Σ_{i∈{L,R}} |S_i|/|S| · H(S_i)`
//!
//! with the node "entropies"
//! * Q1: `H = log(|Σ_Δx| + |Σ_θ|)` (6D pose), evaluated as `logaddexp(logdet Σ_Δx, logdet Σ_θ)`;
//! * Q2: `H = logdet Σ_a` (skeletal link angles);
//! * Q3: `H = logdet Σ_s` (skeletal node offsets).
//!
//! ## Target representation (documented choices)
//! * `Δx`: the 3D offset to the SSC (metres).
//! * `θ`: the **6D rotation representation** (Zhou et al. 2019): the first two columns of the
//!   rotation matrix of the unit quaternion `(w, x, y, z)`, ordered `[R00 R10 R20 R01 R11 R21]`.
//!   It is continuous on SO(3) (Euler angles and quaternions are not: wrap-around, double cover).
//! * `a`: each link angle embedded as `(cos a_l, sin a_l)`, ordered `[cos a_0, sin a_0, cos a_1, ...]`
//!   (angles are circular).
//! * `s`: the node offsets as given (`du px, dv px, dz m` per node).
//! * **Standardisation**: each embedded dimension is centred and divided by its population
//!   standard deviation over all training parts (1 when that is below 1e-6), so terms mixing
//!   units (px with m) and the two determinants of Q1 are comparable.
//! * **Dimension reduction** (`reduce_dims = k > 0`): the standardised `a` and `s` blocks are
//!   each projected on their top-`k` principal components over the training set (computed once,
//!   at the root, with faer's self-adjoint eigendecomposition). Q2/Q3 then measure the
//!   entropy of the projection. This cuts the per-part sufficient statistics from ~1,300 to ~100
//!   numbers (Q1+Q2+Q3 with 18 links and 11 nodes).
//! * Covariances are the biased (1/n) sample covariances plus `reg · I` (ridge), so a node of
//!   one part, or of parts with identical targets, has the finite entropy `d · log(reg)`.
//!   Log-determinants come from a Cholesky factorisation (faer's `cholesky_in_place` above 8
//!   dimensions, an inline one for tiny blocks, the two checked against each other); a pivot
//!   that rounding pushes below `reg · 1e-3` is clamped there, so no gain is ever NaN or ±inf.
//!
//! (Over 600 lines: one concept, the three terms share the layout and the Cholesky kernels;
//! the last hundred lines are its tests.)

// `!(x > y)` is deliberate throughout: it is true for NaN too, which is clamped, never passed on.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Index loops mirror the matrix formulas (Cholesky, covariance blocks).
#![allow(clippy::needless_range_loop)]

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    cholesky_in_place, cholesky_in_place_scratch, LltRegularization,
};
use faer::{MatMut, Par};

use crate::error::{IsaError, Result};
use crate::params::Quality;

/// Which target a block of the target vector holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Term {
    Offset,
    Rotation,
    Links,
    Nodes,
}

/// A contiguous block of the target vector, with the offset of its upper-triangular
/// outer-product sums in a statistics vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Block {
    pub term: Term,
    pub start: usize,
    pub dim: usize,
    pub tri: usize,
}

/// Layout of target vectors and of sufficient-statistics vectors
/// `[Σx (dim) | per block Σ x_a x_b, a ≤ b (dim(dim+1)/2)]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    pub dim: usize,
    pub blocks: Vec<Block>,
    /// Length of a statistics vector.
    pub m: usize,
}

impl Layout {
    pub fn new(dims: &[(Term, usize)]) -> Self {
        let dim: usize = dims.iter().map(|d| d.1).sum();
        let mut blocks = Vec::new();
        let (mut start, mut tri) = (0, dim);
        for &(term, d) in dims {
            blocks.push(Block {
                term,
                start,
                dim: d,
                tri,
            });
            start += d;
            tri += d * (d + 1) / 2;
        }
        Layout {
            dim,
            blocks,
            m: tri,
        }
    }

    pub fn block(&self, term: Term) -> Option<&Block> {
        self.blocks.iter().find(|b| b.term == term)
    }

    /// Adds the statistics of one (centred) target vector.
    #[inline(always)]
    pub fn accumulate(&self, stats: &mut [f64], x: &[f64]) {
        let stats = &mut stats[..self.m];
        let x = &x[..self.dim];
        for (s, v) in stats[..self.dim].iter_mut().zip(x) {
            *s += v;
        }
        for b in &self.blocks {
            let xb = &x[b.start..b.start + b.dim];
            let mut idx = b.tri;
            for i in 0..b.dim {
                let xi = xb[i];
                let row = &mut stats[idx..idx + b.dim - i];
                for (s, xj) in row.iter_mut().zip(&xb[i..]) {
                    *s += xi * xj;
                }
                idx += b.dim - i;
            }
        }
    }

    /// Writes the per-part statistics vector `z` of a target vector (`z.len() == m`).
    #[inline]
    pub fn statistics_of(&self, z: &mut [f64], x: &[f64]) {
        z.fill(0.0);
        self.accumulate(z, x);
    }
}

/// Embedded, standardised (and optionally reduced) targets of every training part.
#[derive(Clone, Debug)]
pub struct Targets {
    pub layout: Layout,
    /// `n × layout.dim`, row-major.
    pub data: Vec<f32>,
    pub n: usize,
}

impl Targets {
    #[inline(always)]
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.layout.dim..(i + 1) * self.layout.dim]
    }
}

/// Largest SSC offset component (metres) accepted in training targets and in a model's votes:
/// far beyond any object (offsets are within an object's extent), small enough that every
/// position computed from it stays finite and exact to well under a millimetre in `f32`.
pub const MAX_TARGET_OFFSET: f32 = 1e3;

/// The raw per-part targets handed over by Python (see DESIGN.md, data contract).
#[derive(Clone, Copy, Debug)]
pub struct RawTargets<'a> {
    /// `(n, 3)` SSC offsets, metres.
    pub offsets: &'a [f32],
    /// `(n, 4)` unit quaternions `(w, x, y, z)`.
    pub rotations: &'a [f32],
    /// `(n, L)` link angles, radians, and `L`.
    pub link_angles: Option<(&'a [f32], usize)>,
    /// `(n, 3N)` node offsets and `3N`.
    pub node_offsets: Option<(&'a [f32], usize)>,
}

impl<'a> RawTargets<'a> {
    /// The pose targets alone (a Q1 training set: no privileged data).
    pub fn pose(offsets: &'a [f32], rotations: &'a [f32]) -> Self {
        RawTargets {
            offsets,
            rotations,
            link_angles: None,
            node_offsets: None,
        }
    }

    pub fn n(&self) -> usize {
        self.offsets.len() / 3
    }

    /// Checks shapes, finiteness, offsets within [`MAX_TARGET_OFFSET`] and unit rotations
    /// (within [`UNIT_NORM_TOLERANCE`](crate::rotation::UNIT_NORM_TOLERANCE)); the error names
    /// the array and row at fault.
    pub fn validate(&self) -> Result<()> {
        let n = self.n();
        let bad = |m: String| Err(IsaError::InvalidInput(m));
        if self.offsets.len() != 3 * n {
            return bad(format!(
                "offsets: length {} is not a multiple of 3",
                self.offsets.len()
            ));
        }
        if self.rotations.len() != 4 * n {
            return bad(format!(
                "rotations: expected ({n}, 4), got {} values",
                self.rotations.len()
            ));
        }
        check_finite("offsets", self.offsets, 3)?;
        check_finite("rotations", self.rotations, 4)?;
        if let Some(k) = self
            .offsets
            .iter()
            .position(|v| v.abs() > MAX_TARGET_OFFSET)
        {
            return bad(format!(
                "offsets[{}, {}] = {} is beyond ±{MAX_TARGET_OFFSET} m",
                k / 3,
                k % 3,
                self.offsets[k]
            ));
        }
        for (i, q) in self.rotations.chunks_exact(4).enumerate() {
            if !crate::rotation::is_unit(q) {
                let norm = q.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
                return bad(format!(
                    "rotations[{i}] has norm {norm:.6}: expected a unit quaternion (w, x, y, z) within {}",
                    crate::rotation::UNIT_NORM_TOLERANCE
                ));
            }
        }
        for (name, arr) in [
            ("link_angles", self.link_angles),
            ("node_offsets", self.node_offsets),
        ] {
            if let Some((a, w)) = arr {
                if w == 0 {
                    return bad(format!("{name}: has zero columns"));
                }
                if a.len() != n * w {
                    return bad(format!(
                        "{name}: expected ({n}, {w}), got {} values",
                        a.len()
                    ));
                }
                check_finite(name, a, w)?;
            }
        }
        if let Some((_, w)) = self.node_offsets {
            if w % 3 != 0 {
                return bad(format!("node_offsets: {w} columns is not 3 per node"));
            }
        }
        Ok(())
    }
}

fn check_finite(name: &str, a: &[f32], w: usize) -> Result<()> {
    if let Some(k) = a.iter().position(|v| !v.is_finite()) {
        return Err(IsaError::InvalidInput(format!(
            "{name}[{}, {}] is not finite ({})",
            k / w,
            k % w,
            a[k]
        )));
    }
    Ok(())
}

pub use crate::targets::build_targets;

/// Dimension up to which the inline Cholesky is used instead of faer.
const SMALL_DIM: usize = 8;

/// `log det(A)` of a symmetric positive-definite `d × d` matrix (column-major, overwritten).
/// Pivots below `floor` are clamped to it.
pub fn logdet_spd(a: &mut [f64], d: usize, floor: f64) -> f64 {
    if d == 0 {
        return 0.0;
    }
    if d <= SMALL_DIM {
        return logdet_inline(a, d, floor);
    }
    let reg = LltRegularization {
        dynamic_regularization_delta: floor,
        dynamic_regularization_epsilon: floor,
    };
    let backup = a[..d * d].to_vec();
    let req = cholesky_in_place_scratch::<f64>(d, Par::Seq, Default::default());
    let mut buf = MemBuffer::new(req);
    let ok = {
        let m = MatMut::from_column_major_slice_mut(&mut a[..d * d], d, d);
        cholesky_in_place(
            m,
            reg,
            Par::Seq,
            MemStack::new(&mut buf),
            Default::default(),
        )
        .is_ok()
    };
    if ok {
        let mut s = 0.0;
        for i in 0..d {
            s += a[i * d + i].max(floor.sqrt()).ln();
        }
        2.0 * s
    } else {
        // Unreachable with dynamic regularisation; the clamped inline factorisation is the
        // fallback so that no input can give NaN.
        a[..d * d].copy_from_slice(&backup);
        logdet_inline(a, d, floor)
    }
}

/// Inline Cholesky (lower, column-major) log-determinant with pivot clamping.
#[inline]
pub fn logdet_inline(a: &mut [f64], d: usize, floor: f64) -> f64 {
    let mut logdet = 0.0;
    for j in 0..d {
        let mut p = a[j * d + j];
        for k in 0..j {
            p -= a[k * d + j] * a[k * d + j];
        }
        if !(p > floor) {
            p = floor;
        }
        logdet += p.ln();
        let l = p.sqrt();
        a[j * d + j] = l;
        let inv = 1.0 / l;
        for i in j + 1..d {
            let mut v = a[j * d + i];
            for k in 0..j {
                v -= a[k * d + i] * a[k * d + j];
            }
            a[j * d + i] = v * inv;
        }
    }
    logdet
}

/// Regularised log-determinant of a `D ≤ 8` block from statistics (fully unrolled Cholesky;
/// pivots clamped at `floor`; one logarithm of the pivot product).
#[inline(always)]
fn ld_fixed<const D: usize>(stats: &[f64], b: &Block, inv_n: f64, reg: f64, floor: f64) -> f64 {
    let mut m = [0f64; D];
    let st = &stats[b.start..b.start + D];
    for i in 0..D {
        m[i] = st[i] * inv_n;
    }
    let tri = &stats[b.tri..b.tri + D * (D + 1) / 2];
    let mut a = [[0f64; D]; D];
    let mut idx = 0;
    for i in 0..D {
        for j in i..D {
            a[j][i] = tri[idx] * inv_n - m[i] * m[j];
            idx += 1;
        }
        a[i][i] += reg;
    }
    let mut prod = 1.0f64;
    for j in 0..D {
        let mut p = a[j][j];
        for k in 0..j {
            p -= a[j][k] * a[j][k];
        }
        if !(p > floor) {
            p = floor;
        }
        prod *= p;
        let inv = 1.0 / p.sqrt();
        for i in j + 1..D {
            let mut v = a[i][j];
            for k in 0..j {
                v -= a[i][k] * a[j][k];
            }
            a[i][j] = v * inv;
        }
    }
    if prod > 0.0 && prod.is_finite() {
        prod.ln()
    } else {
        // Product out of range (extreme reg or data): redo with a sum of logarithms.
        let mut c = [0f64; 64];
        let mut idx = 0;
        for i in 0..D {
            for j in i..D {
                let v = tri[idx] * inv_n - m[i] * m[j];
                c[i * D + j] = v;
                c[j * D + i] = v;
                idx += 1;
            }
            c[i * D + i] += reg;
        }
        logdet_inline(&mut c[..D * D], D, floor)
    }
}

/// The criterion of a forest: layout, ridge and which terms count.
#[derive(Clone, Debug)]
pub struct Criterion {
    pub layout: Layout,
    pub reg: f64,
}

/// Gains (or node entropies) of the three terms; absent terms are 0.
pub type TermValues = [f64; 3];

impl Criterion {
    pub fn new(layout: Layout, reg: f64) -> Self {
        Criterion { layout, reg }
    }

    /// Regularised log-determinant of one block's covariance from statistics of `n` parts.
    #[inline]
    pub fn block_logdet(&self, b: &Block, stats: &[f64], n: f64, scratch: &mut Vec<f64>) -> f64 {
        let inv_n = 1.0 / n;
        let (r, f) = (self.reg, self.reg * 1e-3);
        match b.dim {
            0 => 0.0,
            1 => ld_fixed::<1>(stats, b, inv_n, r, f),
            2 => ld_fixed::<2>(stats, b, inv_n, r, f),
            3 => ld_fixed::<3>(stats, b, inv_n, r, f),
            4 => ld_fixed::<4>(stats, b, inv_n, r, f),
            5 => ld_fixed::<5>(stats, b, inv_n, r, f),
            6 => ld_fixed::<6>(stats, b, inv_n, r, f),
            7 => ld_fixed::<7>(stats, b, inv_n, r, f),
            8 => ld_fixed::<8>(stats, b, inv_n, r, f),
            d => {
                scratch.clear();
                scratch.resize(d * d, 0.0);
                let mut idx = b.tri;
                for i in 0..d {
                    let mi = stats[b.start + i] * inv_n;
                    for j in i..d {
                        let c = stats[idx] * inv_n - mi * stats[b.start + j] * inv_n;
                        idx += 1;
                        scratch[i * d + j] = c;
                        scratch[j * d + i] = c;
                    }
                    scratch[i * d + i] += self.reg;
                }
                logdet_spd(scratch, d, f)
            }
        }
    }

    /// Node entropies `[H1, H2, H3]` from statistics of `n ≥ 1` parts.
    pub fn entropies(&self, stats: &[f64], n: usize, scratch: &mut Vec<f64>) -> TermValues {
        let n = n as f64;
        let mut ld_off = None;
        let mut ld_rot = None;
        let mut h = [0.0; 3];
        for b in &self.layout.blocks {
            let ld = self.block_logdet(b, stats, n, scratch);
            match b.term {
                Term::Offset => ld_off = Some(ld),
                Term::Rotation => ld_rot = Some(ld),
                Term::Links => h[1] = ld,
                Term::Nodes => h[2] = ld,
            }
        }
        h[0] = match (ld_off, ld_rot) {
            (Some(a), Some(b)) => logaddexp(a, b),
            (Some(a), None) | (None, Some(a)) => a,
            (None, None) => 0.0,
        };
        h
    }

    /// Gains of a split from the parent's entropies and both children's statistics.
    pub fn gains(
        &self,
        parent: &TermValues,
        left: (&[f64], usize),
        right: (&[f64], usize),
        scratch: &mut Vec<f64>,
    ) -> TermValues {
        let n = (left.1 + right.1) as f64;
        let hl = self.entropies(left.0, left.1, scratch);
        let hr = self.entropies(right.0, right.1, scratch);
        let (wl, wr) = (left.1 as f64 / n, right.1 as f64 / n);
        [
            parent[0] - wl * hl[0] - wr * hr[0],
            parent[1] - wl * hl[1] - wr * hr[1],
            parent[2] - wl * hl[2] - wr * hr[2],
        ]
    }
}

#[inline]
pub fn logaddexp(a: f64, b: f64) -> f64 {
    let m = a.max(b);
    m + ((a - m).exp() + (b - m).exp()).ln()
}

/// Gains `[Q1, Q2, Q3]` of splitting the given parts by `left_mask` (test/reference hook).
///
/// Runs exactly the forest's pipeline: embedding, standardisation over these parts, optional
/// reduction, statistics centred at these parts' mean, ridge `reg`. Q2/Q3 are 0 when the
/// corresponding array is absent.
pub fn term_gains(
    raw: &RawTargets<'_>,
    left_mask: &[bool],
    reg: f64,
    reduce_dims: usize,
) -> Result<TermValues> {
    let quality = match (raw.link_angles.is_some(), raw.node_offsets.is_some()) {
        (false, false) => Quality::Q1,
        (true, false) => Quality::Q1Q2,
        (false, true) => Quality::Q1Q3,
        (true, true) => Quality::Q1Q2Q3,
    };
    if !(reg.is_finite() && reg > 0.0) {
        return Err(IsaError::InvalidParameter(format!(
            "reg must be finite and > 0, got {reg}"
        )));
    }
    let t = build_targets(raw, quality, reduce_dims)?;
    if left_mask.len() != t.n {
        return Err(IsaError::InvalidInput(format!(
            "left_mask: {} values for {} parts",
            left_mask.len(),
            t.n
        )));
    }
    let nl = left_mask.iter().filter(|&&b| b).count();
    if nl == 0 || nl == t.n {
        return Err(IsaError::InvalidInput(
            "left_mask: both sides of the split need at least one part".into(),
        ));
    }
    let crit = Criterion::new(t.layout.clone(), reg);
    let lay = &crit.layout;
    let mut sp = vec![0.0; lay.m];
    let mut sl = vec![0.0; lay.m];
    let mut x = vec![0.0; lay.dim];
    for i in 0..t.n {
        for (o, &v) in x.iter_mut().zip(t.row(i)) {
            *o = v as f64;
        }
        lay.accumulate(&mut sp, &x);
        if left_mask[i] {
            lay.accumulate(&mut sl, &x);
        }
    }
    let sr: Vec<f64> = sp.iter().zip(&sl).map(|(a, b)| a - b).collect();
    let mut scratch = Vec::new();
    let hp = crit.entropies(&sp, t.n, &mut scratch);
    Ok(crit.gains(&hp, (&sl, nl), (&sr, t.n - nl), &mut scratch))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotation::quat_to_6d;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn spd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let g: Vec<f64> = (0..d * d).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut a = vec![0.0; d * d];
        for i in 0..d {
            for j in 0..d {
                a[i * d + j] = (0..d).map(|k| g[i * d + k] * g[j * d + k]).sum::<f64>()
                    + if i == j { 0.1 } else { 0.0 };
            }
        }
        a
    }

    #[test]
    fn inline_and_faer_logdet_agree() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for d in [1, 2, 3, 6, 8, 9, 12, 36] {
            let a = spd(d, &mut rng);
            let x = logdet_inline(&mut a.clone(), d, 1e-12);
            let reg = LltRegularization {
                dynamic_regularization_delta: 0.0,
                dynamic_regularization_epsilon: 0.0,
            };
            let req = cholesky_in_place_scratch::<f64>(d, Par::Seq, Default::default());
            let mut buf = MemBuffer::new(req);
            let mut b = a.clone();
            let m = MatMut::from_column_major_slice_mut(&mut b, d, d);
            cholesky_in_place(
                m,
                reg,
                Par::Seq,
                MemStack::new(&mut buf),
                Default::default(),
            )
            .unwrap();
            let y: f64 = 2.0 * (0..d).map(|i| b[i * d + i].ln()).sum::<f64>();
            assert!((x - y).abs() < 1e-9 * (1.0 + y.abs()), "d={d}: {x} vs {y}");
            let z = logdet_spd(&mut a.clone(), d, 1e-12);
            assert!((z - y).abs() < 1e-9 * (1.0 + y.abs()));
        }
    }

    #[test]
    fn degenerate_nodes_are_finite() {
        let lay = Layout::new(&[(Term::Offset, 3), (Term::Rotation, 6), (Term::Links, 10)]);
        let crit = Criterion::new(lay.clone(), 1e-4);
        let mut st = vec![0.0; lay.m];
        let x = vec![0.5; lay.dim];
        for _ in 0..7 {
            lay.accumulate(&mut st, &x);
        }
        let mut sc = Vec::new();
        let h = crit.entropies(&st, 7, &mut sc);
        assert!(h.iter().all(|v| v.is_finite()), "{h:?}");
        // All-identical targets: entropy is d log(reg) per block.
        assert!((h[1] - 10.0 * 1e-4f64.ln()).abs() < 1e-6);
        let h1 = crit.entropies(&st, 1, &mut sc); // inconsistent stats (variance < 0) stay finite
        assert!(h1.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn quat_6d_identity_and_rotation() {
        assert_eq!(
            quat_to_6d(&[1.0, 0.0, 0.0, 0.0]),
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        );
        // 90° about z: x -> y, y -> -x.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let r = quat_to_6d(&[h, 0.0, 0.0, h]);
        let e = [0.0, 1.0, 0.0, -1.0, 0.0, 0.0];
        for k in 0..6 {
            assert!((r[k] - e[k]).abs() < 1e-6);
        }
    }

    #[test]
    fn gain_of_a_perfect_split_is_positive() {
        let n = 200;
        let mut off = Vec::new();
        let mut rot = Vec::new();
        let mut mask = Vec::new();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for i in 0..n {
            let left = i % 2 == 0;
            let c = if left { -1.0 } else { 1.0 };
            for _ in 0..3 {
                off.push(c + rng.random_range(-0.05f32..0.05));
            }
            rot.extend_from_slice(&[1.0, 0.0, 0.0, 0.0]);
            mask.push(left);
        }
        let raw = RawTargets::pose(&off, &rot);
        let g = term_gains(&raw, &mask, 1e-4, 0).unwrap();
        assert!(g[0] > 1.0, "{g:?}");
        let rnd: Vec<bool> = (0..n).map(|i| (i / 2) % 2 == 0).collect();
        let g2 = term_gains(&raw, &rnd, 1e-4, 0).unwrap();
        assert!(g2[0].abs() < 0.2, "{g2:?}");
    }
}
