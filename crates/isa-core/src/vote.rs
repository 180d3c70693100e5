//! Vote aggregation and mode finding: the last step of inference (paper Sec. 3.4, Eq. 12-13).
//!
//! Every part of a depth image, passed down every tree, ends in leaves that vote for the SSC
//! position (a 3D point in the camera frame, metres) and the object's rotation (a unit
//! quaternion `w, x, y, z`, sign-free: `q` and `-q` are the same rotation), each vote with a
//! weight (e.g. `1 / |F|` per tree, Eq. 13). This module is independent of how the votes are
//! produced: [`find_modes`] takes a flat slice of [`PoseVote`]s and returns ranked [`Hypothesis`]es.
//!
//! # Algorithm
//! Kernel density of the votes, a product of a biweight kernel in position (radius
//! [`VoteParams::position_bandwidth`] `h`) and a biweight kernel on SO(3) (geodesic radius
//! [`VoteParams::rotation_bandwidth`]), and its modes:
//! 1. **Coarse grid**: an even-stride subsample of at most [`VoteParams::coarse_votes`] votes is
//!    hashed into cubic cells of side `2h`, each keeping its weight and weighted centroid.
//! 2. **Position mean-shift**, coarse to fine: the [`VoteParams::max_seeds`] heaviest cells seed a
//!    mean-shift on cell centroids with a kernel of radius `2h` (27 neighbour cells cover it; the
//!    wider kernel has fewer spurious modes); seeds reaching the same coarse mode count once,
//!    and the [`VoteParams::refine_modes`] densest coarse modes are refined, densest first, on the
//!    raw votes within `3h` (one gathering pass over all votes; iterations on at most
//!    [`VoteParams::refine_votes`] of them) with the kernel of radius `h`, until the shift is
//!    below `0.01 h`; a coarse mode within `max(2h, NMS distance)` of a refined mode is not
//!    refined, and a refinement stops once it comes within the NMS distance of one.
//!    Densities and supports are computed over all votes. Seeds and rotations run in parallel.
//! 3. **Non-maximum suppression** on position, by position density, with radius
//!    `max(nms_radius, h / 4)`.
//! 4. **Rotation mode** among the votes within `h` of each position mode, each weighted by its
//!    position kernel: the densest of a strided subsample of candidate votes (a medoid-like start,
//!    robust to outliers; [`VoteParams::rotation_candidates`] candidates scored on
//!    [`VoteParams::rotation_eval_votes`] votes), then mean-shift on the sphere of quaternions with
//!    every vote's sign aligned to the current estimate (the weighted chordal mean; iterations on
//!    at most [`VoteParams::refine_votes`] votes, the score over all). Optional further rotation
//!    modes per position ([`VoteParams::rotations_per_position`]) for symmetric objects.
//! 5. **Ranking** by the joint density at the mode ([`Hypothesis::score`], the unnormalised
//!    `p(Δx, θ | I)` of Eq. 13), ties broken deterministically; the first
//!    [`VoteParams::max_hypotheses`] are returned.
//!
//! Everything is deterministic: float reductions run in a fixed order, parallel work is per
//! seed/mode/chunk and collected in order, so results do not depend on the number of threads.
//! (Permuting the input changes results only by summation order and by which votes the
//! even-stride subsamples pick: well under a millimetre and a tenth of a degree in the tests.)
//!
//! Cost: one validation pass and one gathering pass over all votes, a hash grid over at most
//! `coarse_votes` of them, and work per mode bounded by `refine_votes`; `benches/vote.rs`
//! measures it (about 4 ms of one core for 10^5 votes; 13 ms for the 414,530 votes of its room
//! frame). The gathering pass tests runs of consecutive votes only against the centres whose
//! ball meets the run's bounding box, with AVX2 when the CPU has it (same answer either way).

pub mod predict;
pub mod synth;
pub(crate) mod traverse;

pub use crate::params::{PredictParams, VoteParams};
pub use predict::{depth_m_to_mm, image_votes, predict, DepthImage, ImageVotes, Intrinsics};

use crate::error::{IsaError, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// One vote: where the SSC is (camera frame, metres), the object's rotation, and a weight.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[repr(C)]
pub struct PoseVote {
    /// SSC position `t` in the camera frame (metres): `X_cam = R X_obj + t`.
    pub position: [f32; 3],
    /// Rotation `R` as a quaternion `(w, x, y, z)`; need not be unit (normalised here), sign-free.
    pub rotation: [f32; 4],
    /// Non-negative weight; votes with weight 0 are ignored.
    pub weight: f32,
}

/// A pose hypothesis: `X_cam = R X_obj + t` with the SSC as object origin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hypothesis {
    /// Rotation matrix `R`, row-major.
    pub rotation: [[f64; 3]; 3],
    /// The same rotation as a unit quaternion `(w, x, y, z)` with `w >= 0`.
    pub quaternion: [f64; 4],
    /// Translation `t` = SSC position in the camera frame (metres).
    pub translation: [f64; 3],
    /// Joint kernel density at the mode: `Σ w · k_pos · k_rot` (votes' weights times biweight
    /// kernels, each 1 at the mode). Hypotheses are sorted by it, highest first.
    pub score: f64,
    /// Votes inside both kernels.
    pub support: usize,
    /// Position-only density `Σ w · k_pos`.
    pub position_score: f64,
    /// Votes inside the position kernel.
    pub position_support: usize,
}

// ---------------------------------------------------------------------------------------------
// Quaternion helpers (w, x, y, z).

/// Rotation matrix (row-major) of a quaternion `(w, x, y, z)`; normalises it first.
pub fn quat_to_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Unit quaternion `(w, x, y, z)`, `w >= 0`, of a rotation matrix (row-major); robust
/// (Shepperd's method).
pub fn matrix_to_quat(m: [[f64; 3]; 3]) -> [f64; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    canonical(normalise4(q))
}

/// Geodesic angle (radians, in [0, π]) between the rotations of two quaternions, sign-free.
pub fn quat_angle(a: [f64; 4], b: [f64; 4]) -> f64 {
    let na = dot4(a, a).sqrt();
    let nb = dot4(b, b).sqrt();
    let c = (dot4(a, b).abs() / (na * nb)).min(1.0);
    2.0 * c.acos()
}

#[inline]
fn dot4(a: [f64; 4], b: [f64; 4]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

fn normalise4(q: [f64; 4]) -> [f64; 4] {
    let n = dot4(q, q).sqrt();
    [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
}

/// Sign convention of output quaternions: `w >= 0`, then the first non-zero component positive.
fn canonical(q: [f64; 4]) -> [f64; 4] {
    let first = q.iter().copied().find(|v| *v != 0.0).unwrap_or(1.0);
    if q[0] < 0.0 || (q[0] == 0.0 && first < 0.0) {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    }
}

// ---------------------------------------------------------------------------------------------
// The coarse grid.

/// Hasher for packed cell keys (fast, fixed, so iteration order is reproducible).
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(*b as u64);
        }
    }
    #[inline]
    fn write_u64(&mut self, x: u64) {
        // splitmix64 finaliser: every key bit reaches the low (bucket) and high (tag) bits.
        let mut z = self.0 ^ x;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        self.0 = z ^ (z >> 31);
    }
}

type CellMap = HashMap<u64, u32, BuildHasherDefault<CellHasher>>;

const KEY_BITS: u32 = 21;
const KEY_OFF: i64 = 1 << (KEY_BITS - 1);

#[inline(always)]
fn cell_index(p: [f64; 3], inv_cell: f64) -> [i64; 3] {
    [
        (p[0] * inv_cell).floor() as i64,
        (p[1] * inv_cell).floor() as i64,
        (p[2] * inv_cell).floor() as i64,
    ]
}

/// Packs a cell index into 63 bits; indices beyond ±2^20 cells are clamped (votes that far
/// never fall inside a kernel of a sane mode anyway, distances use raw positions).
#[inline(always)]
fn pack(c: [i64; 3]) -> u64 {
    let f = |v: i64| ((v.clamp(-KEY_OFF, KEY_OFF - 1) + KEY_OFF) as u64) & ((1 << KEY_BITS) - 1);
    (f(c[0]) << (2 * KEY_BITS)) | (f(c[1]) << KEY_BITS) | f(c[2])
}

struct Cell {
    weight: f64,
    centroid: [f64; 3],
}

/// Cubic cells of side `h` over a strided subsample of the votes: weight and weighted centroid.
struct Grid {
    cells: Vec<Cell>,
    map: CellMap,
    inv_cell: f64,
}

impl Grid {
    /// Cells of the votes `0, stride, 2 stride, ...` (weight > 0), in order of first appearance.
    fn build(votes: &[PoseVote], stride: usize, cell: f64) -> Grid {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: AVX2 (and so SSE4.1's exact `floor`) is available.
                return unsafe { Self::build_avx2(votes, stride, cell) };
            }
        }
        Self::build_portable(votes, stride, cell)
    }

    /// [`Grid::build`] compiled for AVX2 (`floor` inline instead of a libm call; same values).
    ///
    /// # Safety
    /// AVX2 must be available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn build_avx2(votes: &[PoseVote], stride: usize, cell: f64) -> Grid {
        Self::build_portable(votes, stride, cell)
    }

    #[inline(always)]
    fn build_portable(votes: &[PoseVote], stride: usize, cell: f64) -> Grid {
        let inv_cell = 1.0 / cell;
        let n = votes.len().div_ceil(stride.max(1));
        let mut map = CellMap::with_capacity_and_hasher(n.min(1 << 16), Default::default());
        let mut cells: Vec<Cell> = Vec::new();
        for v in votes.iter().step_by(stride.max(1)) {
            if v.weight <= 0.0 {
                continue;
            }
            let p = v.position.map(f64::from);
            let next = cells.len() as u32;
            let c = *map.entry(pack(cell_index(p, inv_cell))).or_insert(next);
            if c == next {
                cells.push(Cell {
                    weight: 0.0,
                    centroid: [0.0; 3],
                });
            }
            let cell = &mut cells[c as usize];
            let w = f64::from(v.weight);
            cell.weight += w;
            for k in 0..3 {
                cell.centroid[k] += w * p[k];
            }
        }
        for cell in &mut cells {
            for k in 0..3 {
                cell.centroid[k] /= cell.weight;
            }
        }
        Grid {
            cells,
            map,
            inv_cell,
        }
    }

    /// Calls `f` with every cell in the 3x3x3 block around `p`'s cell.
    #[inline]
    fn for_neighbour_cells(&self, p: [f64; 3], mut f: impl FnMut(&Cell)) {
        let c = cell_index(p, self.inv_cell);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(&i) = self.map.get(&pack([c[0] + dx, c[1] + dy, c[2] + dz])) {
                        f(&self.cells[i as usize]);
                    }
                }
            }
        }
    }
}

fn vote_problem(v: &PoseVote) -> Option<String> {
    if !v.position.iter().all(|x| x.is_finite()) {
        return Some(format!("position {:?} is not finite", v.position));
    }
    if !(v.weight.is_finite() && v.weight >= 0.0) {
        return Some(format!("weight {} must be finite and >= 0", v.weight));
    }
    let q = v.rotation;
    let n2 = q.iter().map(|x| f64::from(*x) * f64::from(*x)).sum::<f64>();
    if !(n2.is_finite() && n2 > 1e-12) {
        return Some(format!(
            "rotation {q:?} is not a finite non-zero quaternion"
        ));
    }
    None
}

/// Cheap test equivalent to `vote_problem(v).is_none()` (up to the zero-quaternion threshold).
#[inline]
fn vote_ok(v: &PoseVote) -> bool {
    let p = v.position;
    let q = v.rotation;
    let finite = p[0].is_finite() && p[1].is_finite() && p[2].is_finite() && v.weight.is_finite();
    let qmax = q[0].abs().max(q[1].abs()).max(q[2].abs()).max(q[3].abs());
    finite && v.weight >= 0.0 && qmax.is_finite() && qmax > 1e-6
}

/// The first bad vote, checked in parallel over fixed chunks (deterministic answer).
fn validate_votes(votes: &[PoseVote]) -> Result<()> {
    const CH: usize = 1 << 15;
    let bad = votes
        .par_chunks(CH)
        .enumerate()
        .filter_map(|(c, chunk)| chunk.iter().position(|v| !vote_ok(v)).map(|i| c * CH + i))
        .min();
    match bad {
        Some(i) => Err(IsaError::InvalidInput(format!(
            "votes[{i}]: {}",
            vote_problem(&votes[i])
                .unwrap_or_else(|| "rotation is not a finite non-zero quaternion".into())
        ))),
        None => Ok(()),
    }
}

#[inline]
fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// `n` indices `0 .. len` evenly strided (all of them when `len <= n`).
fn strided(len: usize, n: usize) -> impl Iterator<Item = usize> {
    let m = n.min(len);
    (0..m).map(move |j| j * len / m)
}

// ---------------------------------------------------------------------------------------------
// Position modes.

struct PositionMode {
    position: [f64; 3],
    score: f64,
    support: usize,
    /// Indices (into the votes) inside the position kernel, and their weight times kernel.
    members: Vec<u32>,
    member_weights: Vec<f64>,
}

/// Coarse mean-shift from `start` on cell centroids weighted by cell weight (27 cells per
/// step); returns the mode and the coarse density there. `None` if no centroid is within `h`.
fn coarse_mean_shift(
    grid: &Grid,
    start: [f64; 3],
    h: f64,
    max_iter: usize,
) -> Option<([f64; 3], f64)> {
    let h2 = h * h;
    let mut m = start;
    let mut density = 0.0;
    for _ in 0..max_iter {
        let (mut acc, mut ws) = ([0.0f64; 3], 0.0f64);
        density = 0.0;
        grid.for_neighbour_cells(m, |c| {
            let d2 = dist2(c.centroid, m);
            if d2 < h2 {
                let u = 1.0 - d2 / h2;
                let g = c.weight * u;
                ws += g;
                density += g * u;
                for k in 0..3 {
                    acc[k] += g * c.centroid[k];
                }
            }
        });
        if ws <= 0.0 {
            return None;
        }
        let next = acc.map(|a| a / ws);
        let shift2 = dist2(next, m);
        m = next;
        if shift2 < 1e-4 * h2 {
            break;
        }
    }
    Some((m, density))
}

/// Centres per block of [`gather`]: `[x, y, z]` lanes.
const GATHER_LANES: usize = 8;

/// [`gather`] on one chunk of votes whose first index is `base`: `out[c]` gets the indices
/// within `sqrt(r2)` of centre `c` (same f32 operations on every path).
#[inline(always)]
fn gather_chunk(
    chunk: &[PoseVote],
    base: usize,
    blocks: &[[[f32; GATHER_LANES]; 3]],
    ids: &[[u32; GATHER_LANES]],
    r2: f32,
    out: &mut [Vec<u32>],
) {
    const B: usize = GATHER_LANES;
    for (i, v) in chunk.iter().enumerate() {
        if v.weight <= 0.0 {
            continue;
        }
        let p = v.position;
        for (b, id) in blocks.iter().zip(ids) {
            let mut mask = 0u32;
            for l in 0..B {
                let (dx, dy, dz) = (p[0] - b[0][l], p[1] - b[1][l], p[2] - b[2][l]);
                mask |= u32::from(dx * dx + dy * dy + dz * dz < r2) << l;
            }
            while mask != 0 {
                let l = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                out[id[l] as usize].push((base + i) as u32);
            }
        }
    }
}

/// [`gather_chunk`] with AVX2 (the 8 lanes of a block in one register; the same IEEE
/// operations in the same order, so the same answer).
///
/// # Safety
/// AVX2 must be available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gather_chunk_avx2(
    chunk: &[PoseVote],
    base: usize,
    blocks: &[[[f32; GATHER_LANES]; 3]],
    ids: &[[u32; GATHER_LANES]],
    r2: f32,
    out: &mut [Vec<u32>],
) {
    use std::arch::x86_64::*;
    let r2v = _mm256_set1_ps(r2);
    let bv: Vec<[__m256; 3]> = blocks
        .iter()
        .map(|b| {
            [
                _mm256_loadu_ps(b[0].as_ptr()),
                _mm256_loadu_ps(b[1].as_ptr()),
                _mm256_loadu_ps(b[2].as_ptr()),
            ]
        })
        .collect();
    for (i, v) in chunk.iter().enumerate() {
        if v.weight <= 0.0 {
            continue;
        }
        let (px, py, pz) = (
            _mm256_set1_ps(v.position[0]),
            _mm256_set1_ps(v.position[1]),
            _mm256_set1_ps(v.position[2]),
        );
        for (b, id) in bv.iter().zip(ids) {
            let (dx, dy, dz) = (
                _mm256_sub_ps(px, b[0]),
                _mm256_sub_ps(py, b[1]),
                _mm256_sub_ps(pz, b[2]),
            );
            let d2 = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                _mm256_mul_ps(dz, dz),
            );
            let mut mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(d2, r2v)) as u32;
            while mask != 0 {
                let l = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                out[id[l] as usize].push((base + i) as u32);
            }
        }
    }
}

/// Indices of the votes (weight > 0) within `radius` of each centre (tested in `f32`), in vote
/// order; one pass over the votes, in parallel over fixed chunks, 8 centres per SIMD-friendly
/// block.
fn gather(votes: &[PoseVote], centres: &[[f64; 3]], radius: f64) -> Vec<Vec<u32>> {
    const CH: usize = 1 << 14;
    const B: usize = GATHER_LANES;
    /// Votes per bounding box (consecutive votes come from neighbouring parts, so they are
    /// close in space and most boxes are far from most centres).
    const SUB: usize = 64;
    let r2 = (radius * radius) as f32;
    // A box farther than this from a centre holds no vote within `radius` of it: the margin
    // covers the rounding of the f32 distance test (relative error ~1e-7).
    let prune2 = (radius * radius) * (1.0 + 1e-4) + 1e-12;
    let cf: Vec<[f32; 3]> = centres.iter().map(|c| c.map(|x| x as f32)).collect();
    let avx2 = {
        #[cfg(target_arch = "x86_64")]
        {
            std::arch::is_x86_feature_detected!("avx2")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    };
    let parts: Vec<Vec<Vec<u32>>> = votes
        .par_chunks(CH)
        .enumerate()
        .map(|(ci, chunk)| {
            let mut out = vec![Vec::new(); centres.len()];
            let mut blocks: Vec<[[f32; B]; 3]> = Vec::new();
            let mut ids: Vec<[u32; B]> = Vec::new();
            for (si, sub) in chunk.chunks(SUB).enumerate() {
                // Bounding box of the sub-block's votes (weight > 0).
                let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
                for v in sub.iter().filter(|v| v.weight > 0.0) {
                    for a in 0..3 {
                        lo[a] = lo[a].min(v.position[a]);
                        hi[a] = hi[a].max(v.position[a]);
                    }
                }
                if lo[0] > hi[0] {
                    continue;
                }
                // The centres whose ball meets the box, packed 8 to a block (padding lanes far
                // away: never hit).
                blocks.clear();
                ids.clear();
                let mut n_sel = 0usize;
                for (c, p) in cf.iter().enumerate() {
                    let d2: f64 = (0..3)
                        .map(|a| {
                            let d = (f64::from(lo[a]) - f64::from(p[a]))
                                .max(f64::from(p[a]) - f64::from(hi[a]))
                                .max(0.0);
                            d * d
                        })
                        .sum();
                    if d2 > prune2 {
                        continue;
                    }
                    let l = n_sel % B;
                    n_sel += 1;
                    if l == 0 {
                        blocks.push([[1e18f32; B]; 3]);
                        ids.push([0; B]);
                    }
                    let b = blocks.last_mut().unwrap();
                    for a in 0..3 {
                        b[a][l] = p[a];
                    }
                    ids.last_mut().unwrap()[l] = c as u32;
                }
                if blocks.is_empty() {
                    continue;
                }
                let base = ci * CH + si * SUB;
                #[cfg(target_arch = "x86_64")]
                if avx2 {
                    // SAFETY: AVX2 is available.
                    unsafe { gather_chunk_avx2(sub, base, &blocks, &ids, r2, &mut out) };
                    continue;
                }
                let _ = avx2;
                gather_chunk(sub, base, &blocks, &ids, r2, &mut out);
            }
            out
        })
        .collect();
    let mut all = vec![Vec::new(); centres.len()];
    for p in parts {
        for (a, b) in all.iter_mut().zip(p) {
            a.extend_from_slice(&b);
        }
    }
    all
}

/// Fine mean-shift on raw votes from a coarse mode: iterations on a strided subsample of at
/// most `refine` of the gathered votes (shift below `0.01 h`), then the density, support and
/// members over all of them. The gathered ball (radius `3h`) is refreshed if the mode drifts
/// more than `2h` from its centre. `near`: the votes within `3h` of `start`. `None` also when
/// the shift comes within the NMS distance of a mode in `known` (it would be suppressed, or
/// converge there; this also ends slow creeps along ridges towards a known mode).
fn fine_mean_shift(
    votes: &[PoseVote],
    start: [f64; 3],
    mut near: Vec<u32>,
    h: f64,
    params: &VoteParams,
    known: &[PositionMode],
) -> Option<PositionMode> {
    let h2 = h * h;
    let suppress = nms_distance(params);
    let mut centre = start;
    let mut m = start;
    for _round in 0..4 {
        let sub: Vec<u32> = strided(near.len(), params.refine_votes)
            .map(|j| near[j])
            .collect();
        for _ in 0..params.max_iterations {
            let (mut acc, mut ws) = ([0.0f64; 3], 0.0f64);
            for &j in &sub {
                let v = &votes[j as usize];
                let p = v.position.map(f64::from);
                let d2 = dist2(p, m);
                if d2 < h2 {
                    let g = f64::from(v.weight) * (1.0 - d2 / h2);
                    ws += g;
                    for k in 0..3 {
                        acc[k] += g * p[k];
                    }
                }
            }
            if ws <= 0.0 {
                return None;
            }
            let next = acc.map(|a| a / ws);
            let shift2 = dist2(next, m);
            m = next;
            if known
                .iter()
                .any(|k| dist2(k.position, m) < suppress * suppress)
            {
                return None; // NMS would suppress it (or it would converge to a known mode)
            }
            if shift2 < 1e-4 * h2 {
                break;
            }
        }
        if dist2(m, centre) <= 4.0 * h2 {
            break;
        }
        centre = m;
        near = gather(votes, &[centre], 3.0 * h).pop().unwrap_or_default();
    }
    let (mut score, mut members, mut member_weights) = (0.0f64, Vec::new(), Vec::new());
    for &j in &near {
        let v = &votes[j as usize];
        let d2 = dist2(v.position.map(f64::from), m);
        if d2 < h2 {
            let u = 1.0 - d2 / h2;
            let a = f64::from(v.weight) * u * u;
            score += a;
            members.push(j);
            member_weights.push(a);
        }
    }
    (!members.is_empty()).then_some(PositionMode {
        position: m,
        score,
        support: members.len(),
        members,
        member_weights,
    })
}

/// Position modes closer than this to a stronger one are suppressed: `max(nms_radius, h / 4)`.
fn nms_distance(params: &VoteParams) -> f64 {
    f64::from(params.nms_radius).max(0.25 * f64::from(params.position_bandwidth))
}

/// Orders by score, highest first; ties by position (total order on floats), so sorting is
/// deterministic whatever the input order.
fn by_score_then_position(a: (f64, [f64; 3]), b: (f64, [f64; 3])) -> std::cmp::Ordering {
    b.0.total_cmp(&a.0)
        .then_with(|| a.1[0].total_cmp(&b.1[0]))
        .then_with(|| a.1[1].total_cmp(&b.1[1]))
        .then_with(|| a.1[2].total_cmp(&b.1[2]))
}

// ---------------------------------------------------------------------------------------------
// Rotation modes.

/// Biweight kernel on SO(3) expressed through `c = |q·p|` (cos of half the angle), so no `acos`:
/// `u = (1 - c²) / (1 - cos²(θ_h / 2))` = `sin²(θ/2) / sin²(θ_h/2)`, inside the kernel iff `u < 1`.
struct RotKernel {
    inv_denom: f64,
}

impl RotKernel {
    fn new(bandwidth: f64) -> Self {
        let ch = (bandwidth / 2.0).cos();
        Self {
            inv_denom: 1.0 / (1.0 - ch * ch).max(1e-300),
        }
    }
    /// `1 - u` (the mean-shift weight profile, <= 0 outside the kernel) and `q·p`.
    #[inline]
    fn g(&self, q: [f64; 4], p: [f64; 4]) -> (f64, f64) {
        let d = dot4(q, p);
        let c = d.abs().min(1.0);
        (1.0 - (1.0 - c * c) * self.inv_denom, d)
    }
}

struct RotationMode {
    q: [f64; 4],
    score: f64,
    support: usize,
}

/// Rotation modes among the unit quaternions `quats` with weights `a`.
fn rotation_modes(quats: &[[f64; 4]], a: &[f64], params: &VoteParams) -> Vec<RotationMode> {
    let n = quats.len();
    if n == 0 {
        return Vec::new();
    }
    let kern = RotKernel::new(f64::from(params.rotation_bandwidth));
    let eval: Vec<usize> = strided(n, params.rotation_eval_votes).collect();
    let refine: Vec<usize> = strided(n, params.refine_votes).collect();
    let mut cands: Vec<(f64, usize)> = strided(n, params.rotation_candidates)
        .map(|ci| {
            let c = quats[ci];
            let dens: f64 = eval
                .iter()
                .map(|&e| {
                    let (g, _) = kern.g(c, quats[e]);
                    if g > 0.0 {
                        a[e] * g * g
                    } else {
                        0.0
                    }
                })
                .sum();
            (dens, ci)
        })
        .collect();
    cands.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));

    // Mean-shift over the members `set` until the rotation stops moving.
    let shift = |start: [f64; 4], set: &[usize]| -> [f64; 4] {
        let mut q = start;
        for _ in 0..params.max_iterations {
            let mut acc = [0.0f64; 4];
            let mut ws = 0.0;
            for &i in set {
                let p = quats[i];
                let (g, d) = kern.g(q, p);
                if g > 0.0 {
                    let w = a[i] * g * d.signum();
                    ws += a[i] * g;
                    for k in 0..4 {
                        acc[k] += w * p[k];
                    }
                }
            }
            let norm = dot4(acc, acc).sqrt();
            if ws <= 0.0 || norm <= 1e-300 {
                break;
            }
            let next = acc.map(|v| v / norm);
            let moved = 1.0 - dot4(next, q).abs();
            q = next;
            if moved < 1e-12 {
                break;
            }
        }
        q
    };

    let mut modes: Vec<RotationMode> = Vec::new();
    let min_sep = f64::from(params.rotation_bandwidth);
    for &(_, ci) in &cands {
        if modes.len() >= params.rotations_per_position {
            break;
        }
        let start = quats[ci];
        if modes.iter().any(|m| quat_angle(m.q, start) < min_sep) {
            continue;
        }
        // Converge on the evaluation subsample first (cheap), then on the refinement subsample.
        let q = shift(shift(start, &eval), &refine);
        if modes.iter().any(|m| quat_angle(m.q, q) < 0.5 * min_sep) {
            continue;
        }
        let (mut score, mut support) = (0.0f64, 0usize);
        for i in 0..n {
            let (g, _) = kern.g(q, quats[i]);
            if g > 0.0 {
                score += a[i] * g * g;
                support += 1;
            }
        }
        modes.push(RotationMode {
            q: canonical(q),
            score,
            support,
        });
    }
    modes
}

// ---------------------------------------------------------------------------------------------

/// Finds the modes of the votes' density and returns them as hypotheses, best first.
///
/// Errors name the first bad vote (non-finite position, negative weight, zero quaternion) or
/// the bad parameter. No votes (or all of weight 0) give no hypotheses.
pub fn find_modes(votes: &[PoseVote], params: &VoteParams) -> Result<Vec<Hypothesis>> {
    params.validate()?;
    validate_votes(votes)?;
    Ok(find_modes_valid(votes, params))
}

/// [`find_modes`] on votes known to be valid (finite, weight >= 0, non-zero quaternions) with
/// validated parameters: what `predict` calls, its votes being built from a validated forest.
pub(crate) fn find_modes_valid(votes: &[PoseVote], params: &VoteParams) -> Vec<Hypothesis> {
    let h = f64::from(params.position_bandwidth);
    let stride = votes.len().div_ceil(params.coarse_votes).max(1);
    let grid = Grid::build(votes, stride, 2.0 * h);
    if grid.cells.is_empty() {
        return Vec::new();
    }

    // Seeds: the heaviest cells (ties by order of appearance -> deterministic).
    let mut order: Vec<u32> = (0..grid.cells.len() as u32).collect();
    let n_seeds = params.max_seeds.min(order.len());
    let heavier = |a: &u32, b: &u32| {
        grid.cells[*b as usize]
            .weight
            .total_cmp(&grid.cells[*a as usize].weight)
            .then(a.cmp(b))
    };
    if n_seeds < order.len() {
        order.select_nth_unstable_by(n_seeds - 1, heavier);
        order.truncate(n_seeds);
    }
    order.sort_by(heavier);

    let max_iter = params.max_iterations;
    let coarse: Vec<Option<([f64; 3], f64)>> = order
        .par_iter()
        .map(|&c| coarse_mean_shift(&grid, grid.cells[c as usize].centroid, 2.0 * h, max_iter))
        .collect();
    // Seeds that reached the same coarse mode (within h / 2) count once; the densest coarse
    // modes are refined on the raw votes.
    let mut distinct: Vec<([f64; 3], f64)> = Vec::new();
    for (m, dens) in coarse.into_iter().flatten() {
        if distinct.iter().all(|d| dist2(d.0, m) >= 0.25 * h * h) {
            distinct.push((m, dens));
        }
    }
    distinct.sort_by(|a, b| by_score_then_position((a.1, a.0), (b.1, b.0)));
    distinct.truncate(params.refine_modes);
    // Refined densest first; a coarse mode within 2h (or the NMS distance) of a refined one
    // would reach it again (or be suppressed).
    let centres: Vec<[f64; 3]> = distinct.iter().map(|d| d.0).collect();
    let near = gather(votes, &centres, 3.0 * h);
    let mut modes: Vec<PositionMode> = Vec::new();
    for (c, near) in centres.into_iter().zip(near) {
        let skip = (2.0 * h).max(nms_distance(params));
        if modes.iter().any(|m| dist2(m.position, c) < skip * skip) {
            continue;
        }
        if let Some(m) = fine_mean_shift(votes, c, near, h, params, &modes) {
            modes.push(m);
        }
    }
    modes.sort_by(|a, b| by_score_then_position((a.score, a.position), (b.score, b.position)));

    // NMS on positions (also merges modes that converged to the same place).
    let r = nms_distance(params);
    let keep_positions = params
        .max_hypotheses
        .saturating_mul(2)
        .max(params.max_hypotheses + 2);
    let mut kept: Vec<PositionMode> = Vec::new();
    for m in modes {
        if kept.len() >= keep_positions {
            break;
        }
        if kept.iter().all(|k| dist2(k.position, m.position) >= r * r) {
            kept.push(m);
        }
    }

    // Rotation modes among each position mode's members, in parallel.
    let mut hyps: Vec<Hypothesis> = kept
        .par_iter()
        .flat_map_iter(|m| {
            let quats: Vec<[f64; 4]> = m
                .members
                .iter()
                .map(|&j| normalise4(votes[j as usize].rotation.map(f64::from)))
                .collect();
            rotation_modes(&quats, &m.member_weights, params)
                .into_iter()
                .map(move |rm| Hypothesis {
                    rotation: quat_to_matrix(rm.q),
                    quaternion: rm.q,
                    translation: m.position,
                    score: rm.score,
                    support: rm.support,
                    position_score: m.score,
                    position_support: m.support,
                })
        })
        .filter(|hy| hy.support >= params.min_support)
        .collect();
    hyps.sort_by(|a, b| {
        by_score_then_position((a.score, a.translation), (b.score, b.translation)).then_with(|| {
            a.quaternion
                .iter()
                .zip(&b.quaternion)
                .fold(std::cmp::Ordering::Equal, |o, (x, y)| {
                    o.then(x.total_cmp(y))
                })
        })
    });
    hyps.truncate(params.max_hypotheses);
    hyps
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        // Box-Muller.
        let u1: f64 = rng.random::<f64>().max(1e-12);
        let u2: f64 = rng.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
        [
            a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
        ]
    }

    fn axis_angle(axis: [f64; 3], angle: f64) -> [f64; 4] {
        let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        let s = (angle / 2.0).sin() / n;
        [(angle / 2.0).cos(), axis[0] * s, axis[1] * s, axis[2] * s]
    }

    fn random_quat(rng: &mut ChaCha8Rng) -> [f64; 4] {
        normalise4([gauss(rng), gauss(rng), gauss(rng), gauss(rng)])
    }

    /// Votes around `t` (σ metres) with rotations around `q` (σ_rot radians per axis), random signs.
    fn cluster(
        rng: &mut ChaCha8Rng,
        n: usize,
        t: [f64; 3],
        sigma: f64,
        q: [f64; 4],
        sigma_rot: f64,
        w: f32,
    ) -> Vec<PoseVote> {
        (0..n)
            .map(|_| {
                let p = [
                    t[0] + sigma * gauss(rng),
                    t[1] + sigma * gauss(rng),
                    t[2] + sigma * gauss(rng),
                ];
                let axis = [gauss(rng), gauss(rng), gauss(rng)];
                let ang = sigma_rot * gauss(rng);
                let mut r = quat_mul(q, axis_angle(axis, ang));
                if rng.random::<bool>() {
                    r = r.map(|v| -v);
                }
                PoseVote {
                    position: p.map(|v| v as f32),
                    rotation: r.map(|v| v as f32),
                    weight: w,
                }
            })
            .collect()
    }

    fn outliers(rng: &mut ChaCha8Rng, n: usize) -> Vec<PoseVote> {
        (0..n)
            .map(|_| {
                let p = [
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-1.5..1.5),
                    rng.random_range(0.5..6.0),
                ];
                PoseVote {
                    position: p,
                    rotation: random_quat(rng).map(|v| v as f32),
                    weight: 1.0,
                }
            })
            .collect()
    }

    fn scene(seed: u64) -> (Vec<PoseVote>, [[f64; 3]; 2], [[f64; 4]; 2]) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let t = [[0.3, -0.1, 2.5], [-0.9, 0.2, 3.4]];
        let q = [
            normalise4([0.9, 0.1, -0.3, 0.2]),
            normalise4([-0.2, 0.7, 0.5, -0.4]),
        ];
        let mut v = cluster(&mut rng, 6000, t[0], 0.03, q[0], 0.08, 1.0);
        v.extend(cluster(&mut rng, 3000, t[1], 0.03, q[1], 0.08, 1.0));
        v.extend(outliers(&mut rng, 8000));
        // Shuffle so clusters are interleaved.
        for i in (1..v.len()).rev() {
            let j = rng.random_range(0..=i);
            v.swap(i, j);
        }
        (v, t, q)
    }

    #[test]
    fn gather_paths_agree() {
        let (mut votes, _, _) = scene(11);
        for (i, v) in votes.iter_mut().enumerate() {
            if i % 97 == 0 {
                v.weight = 0.0;
            }
        }
        let centres: Vec<[f64; 3]> = votes
            .iter()
            .step_by(1500)
            .take(13)
            .map(|v| v.position.map(f64::from))
            .collect();
        let radius = 0.24;
        let r2 = (radius * radius) as f32;
        // Shuffled votes (boxes of consecutive votes span everything), then votes sorted along
        // x (compact boxes: most are pruned), and centres on the ball's rim.
        let mut sorted = votes.clone();
        sorted.sort_by(|a, b| a.position[0].total_cmp(&b.position[0]));
        let mut rim = centres.clone();
        let p0 = sorted[4000].position.map(f64::from);
        rim.push([p0[0] + radius, p0[1], p0[2]]);
        rim.push([p0[0], p0[1] - radius * 0.999_999, p0[2]]);
        for (votes, centres) in [(&votes, &centres), (&sorted, &rim)] {
            let all = gather(votes, centres, radius);
            for (c, got) in centres.iter().zip(&all) {
                let want: Vec<u32> = (0..votes.len() as u32)
                    .filter(|&i| {
                        let v = &votes[i as usize];
                        let p = v.position;
                        let d = [p[0] - c[0] as f32, p[1] - c[1] as f32, p[2] - c[2] as f32];
                        v.weight > 0.0 && d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < r2
                    })
                    .collect();
                assert!(!want.is_empty());
                assert_eq!(*got, want);
            }
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut b = [[1e18f32; GATHER_LANES]; 3];
            let blocks: Vec<[[f32; GATHER_LANES]; 3]> = centres
                .chunks(GATHER_LANES)
                .map(|blk| {
                    for (l, c) in blk.iter().enumerate() {
                        for a in 0..3 {
                            b[a][l] = c[a] as f32;
                        }
                    }
                    b
                })
                .collect();
            let ids: Vec<[u32; GATHER_LANES]> = (0..blocks.len())
                .map(|bi| std::array::from_fn(|l| (bi * GATHER_LANES + l) as u32))
                .collect();
            let mut fast = vec![Vec::new(); blocks.len() * GATHER_LANES];
            let mut portable = fast.clone();
            // SAFETY: AVX2 is available.
            unsafe { gather_chunk_avx2(&votes, 5, &blocks, &ids, r2, &mut fast) };
            gather_chunk(&votes, 5, &blocks, &ids, r2, &mut portable);
            assert_eq!(fast, portable);
        }
    }

    fn tdist(a: [f64; 3], b: [f64; 3]) -> f64 {
        dist2(a, b).sqrt()
    }

    #[test]
    fn recovers_two_modes_among_outliers_in_order() {
        let (votes, t, q) = scene(1);
        let hyps = find_modes(&votes, &VoteParams::default()).unwrap();
        assert!(hyps.len() >= 2, "{hyps:?}");
        assert!(tdist(hyps[0].translation, t[0]) < 0.01, "{:?}", hyps[0]);
        assert!(
            quat_angle(hyps[0].quaternion, q[0]) < 2f64.to_radians(),
            "{:?}",
            hyps[0]
        );
        assert!(tdist(hyps[1].translation, t[1]) < 0.01, "{:?}", hyps[1]);
        assert!(
            quat_angle(hyps[1].quaternion, q[1]) < 2f64.to_radians(),
            "{:?}",
            hyps[1]
        );
        for w in hyps.windows(2) {
            assert!(w[0].score >= w[1].score);
        }
        // Outlier-only hypotheses score far below the real ones.
        for hy in &hyps[2..] {
            assert!(hy.score < 0.1 * hyps[1].score, "{hy:?}");
        }
        assert!(hyps[0].support > 1000 && hyps[0].position_support >= hyps[0].support);
    }

    #[test]
    fn subsampled_coarse_grid_and_refinement_find_the_same_modes() {
        let (votes, t, q) = scene(11);
        let full = find_modes(&votes, &VoteParams::default()).unwrap();
        let p = VoteParams {
            coarse_votes: 900,
            refine_votes: 400,
            rotation_eval_votes: 200,
            ..Default::default()
        };
        let sub = find_modes(&votes, &p).unwrap();
        for k in 0..2 {
            assert!(tdist(sub[k].translation, t[k]) < 0.01, "{:?}", sub[k]);
            assert!(quat_angle(sub[k].quaternion, q[k]) < 2f64.to_radians());
            assert!(tdist(sub[k].translation, full[k].translation) < 0.005);
            // Densities and supports still count every vote.
            assert!(
                (sub[k].position_score - full[k].position_score).abs()
                    < 0.02 * full[k].position_score
            );
        }
    }

    #[test]
    fn rotation_matrix_is_proper_and_matches_quaternion() {
        let (votes, _, _) = scene(2);
        for hy in find_modes(&votes, &VoteParams::default()).unwrap() {
            let r = hy.rotation;
            for i in 0..3 {
                for j in 0..3 {
                    let d: f64 = (0..3).map(|k| r[i][k] * r[j][k]).sum();
                    assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9);
                }
            }
            let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
                - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
                + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
            assert!((det - 1.0).abs() < 1e-9);
            assert!(hy.quaternion[0] >= 0.0);
            assert!(quat_angle(matrix_to_quat(r), hy.quaternion) < 1e-6);
        }
    }

    #[test]
    fn quaternion_signs_do_not_matter() {
        let (votes, _, _) = scene(3);
        let flipped: Vec<PoseVote> = votes
            .iter()
            .enumerate()
            .map(|(i, v)| {
                if i % 3 == 0 {
                    PoseVote {
                        rotation: v.rotation.map(|x| -x),
                        ..*v
                    }
                } else {
                    *v
                }
            })
            .collect();
        let a = find_modes(&votes, &VoteParams::default()).unwrap();
        let b = find_modes(&flipped, &VoteParams::default()).unwrap();
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(&b) {
            assert!(tdist(x.translation, y.translation) < 1e-12);
            assert!(quat_angle(x.quaternion, y.quaternion) < 1e-6);
            assert!((x.score - y.score).abs() < 1e-9 * x.score);
        }
    }

    #[test]
    fn rotation_near_pi_mixed_signs() {
        // Rotation of ~180° about z: w ~ 0, so noise flips the sign of w; a naive average fails.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let q = axis_angle([0.0, 0.0, 1.0], std::f64::consts::PI);
        let votes = cluster(&mut rng, 2000, [0.0, 0.0, 2.0], 0.02, q, 0.1, 1.0);
        let hyps = find_modes(&votes, &VoteParams::default()).unwrap();
        assert!(
            quat_angle(hyps[0].quaternion, q) < 2f64.to_radians(),
            "{:?}",
            hyps[0]
        );
    }

    #[test]
    fn deterministic_across_runs_and_threads_stable_under_input_order() {
        let (votes, _, _) = scene(5);
        let p = VoteParams::default();
        let a = find_modes(&votes, &p).unwrap();
        let b = find_modes(&votes, &p).unwrap();
        assert_eq!(a, b);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let c = one.install(|| find_modes(&votes, &p).unwrap());
        assert_eq!(a, c);
        let three = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let d = three.install(|| find_modes(&votes, &p).unwrap());
        assert_eq!(a, d);
        // Reversed input: the same modes up to float summation order and which votes the
        // even-stride subsamples pick (well under a millimetre and a tenth of a degree).
        let rev: Vec<PoseVote> = votes.iter().rev().copied().collect();
        let e = find_modes(&rev, &p).unwrap();
        for (x, y) in a.iter().zip(&e).take(2) {
            assert!(tdist(x.translation, y.translation) < 1e-3, "{x:?} {y:?}");
            assert!(quat_angle(x.quaternion, y.quaternion) < 0.1f64.to_radians());
        }
    }

    #[test]
    fn weights_decide_the_ranking() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let q = [1.0, 0.0, 0.0, 0.0];
        let mut votes = cluster(&mut rng, 1000, [0.0, 0.0, 2.0], 0.02, q, 0.05, 1.0);
        votes.extend(cluster(&mut rng, 300, [1.0, 0.0, 2.0], 0.02, q, 0.05, 10.0));
        let hyps = find_modes(&votes, &VoteParams::default()).unwrap();
        assert!(tdist(hyps[0].translation, [1.0, 0.0, 2.0]) < 0.01);
        assert!(tdist(hyps[1].translation, [0.0, 0.0, 2.0]) < 0.01);
        assert!(hyps[0].score > hyps[1].score);
    }

    #[test]
    fn nms_and_max_hypotheses() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let q = [1.0, 0.0, 0.0, 0.0];
        let mut votes = Vec::new();
        for i in 0..8 {
            votes.extend(cluster(
                &mut rng,
                500 + 50 * i,
                [0.5 * i as f64, 0.0, 3.0],
                0.01,
                q,
                0.05,
                1.0,
            ));
        }
        let p = VoteParams {
            max_hypotheses: 3,
            ..Default::default()
        };
        let hyps = find_modes(&votes, &p).unwrap();
        assert_eq!(hyps.len(), 3);
        // The three biggest clusters (i = 7, 6, 5), in that order.
        for (k, hy) in hyps.iter().enumerate() {
            assert!(
                tdist(hy.translation, [0.5 * (7 - k) as f64, 0.0, 3.0]) < 0.01,
                "{hy:?}"
            );
        }
        // With an NMS radius over 0.5 m neighbours suppress each other.
        let p = VoteParams {
            max_hypotheses: 8,
            nms_radius: 0.6,
            ..Default::default()
        };
        let hyps = find_modes(&votes, &p).unwrap();
        for (i, a) in hyps.iter().enumerate() {
            for b in &hyps[i + 1..] {
                assert!(tdist(a.translation, b.translation) >= 0.6);
            }
        }
        assert!(tdist(hyps[0].translation, [3.5, 0.0, 3.0]) < 0.01);
    }

    #[test]
    fn several_rotations_per_position() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let q1 = axis_angle([0.0, 0.0, 1.0], 0.3);
        let q2 = axis_angle([0.0, 0.0, 1.0], 0.3 + std::f64::consts::PI);
        let mut votes = cluster(&mut rng, 1500, [0.0, 0.0, 2.0], 0.02, q1, 0.05, 1.0);
        votes.extend(cluster(
            &mut rng,
            1000,
            [0.0, 0.0, 2.0],
            0.02,
            q2,
            0.05,
            1.0,
        ));
        let p = VoteParams {
            rotations_per_position: 2,
            ..Default::default()
        };
        let hyps = find_modes(&votes, &p).unwrap();
        assert!(quat_angle(hyps[0].quaternion, q1) < 2f64.to_radians());
        assert!(quat_angle(hyps[1].quaternion, q2) < 2f64.to_radians());
        assert_eq!(hyps[0].translation, hyps[1].translation);
        let one = find_modes(&votes, &VoteParams::default()).unwrap();
        assert_eq!(one.len(), 1);
    }

    #[test]
    fn empty_zero_weight_and_min_support() {
        assert!(find_modes(&[], &VoteParams::default()).unwrap().is_empty());
        let v = PoseVote {
            position: [0.0, 0.0, 1.0],
            rotation: [1.0, 0.0, 0.0, 0.0],
            weight: 0.0,
        };
        assert!(find_modes(&[v; 10], &VoteParams::default())
            .unwrap()
            .is_empty());
        let v1 = PoseVote { weight: 1.0, ..v };
        assert!(find_modes(&[v1; 2], &VoteParams::default())
            .unwrap()
            .is_empty());
        let hyps = find_modes(&[v1; 3], &VoteParams::default()).unwrap();
        assert_eq!(hyps.len(), 1);
        assert_eq!(hyps[0].support, 3);
        assert!((hyps[0].score - 3.0).abs() < 1e-9);
        assert!(tdist(hyps[0].translation, [0.0, 0.0, 1.0]) < 1e-6);
        // Non-unit quaternions are normalised.
        let v2 = PoseVote {
            rotation: [0.0, 0.0, 0.0, -3.0],
            weight: 1.0,
            ..v
        };
        let hyps = find_modes(&[v2; 5], &VoteParams::default()).unwrap();
        assert!((hyps[0].quaternion[3] - 1.0).abs() < 1e-9);
    }

    #[test]
    fn errors_name_the_vote_or_parameter() {
        let good = PoseVote {
            position: [0.0, 0.0, 1.0],
            rotation: [1.0, 0.0, 0.0, 0.0],
            weight: 1.0,
        };
        let mut votes = vec![good; 5];
        votes[3].position[1] = f32::NAN;
        let e = find_modes(&votes, &VoteParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("votes[3]") && e.contains("position"), "{e}");
        votes[3] = PoseVote {
            weight: -1.0,
            ..good
        };
        votes[4] = PoseVote {
            rotation: [0.0; 4],
            ..good
        };
        let e = find_modes(&votes, &VoteParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("votes[3]") && e.contains("weight"), "{e}");
        for (p, name) in [
            (
                VoteParams {
                    position_bandwidth: 0.0,
                    ..Default::default()
                },
                "position_bandwidth",
            ),
            (
                VoteParams {
                    rotation_bandwidth: 4.0,
                    ..Default::default()
                },
                "rotation_bandwidth",
            ),
            (
                VoteParams {
                    nms_radius: f32::NAN,
                    ..Default::default()
                },
                "nms_radius",
            ),
            (
                VoteParams {
                    max_hypotheses: 0,
                    ..Default::default()
                },
                "max_hypotheses",
            ),
            (
                VoteParams {
                    max_seeds: 0,
                    ..Default::default()
                },
                "max_seeds",
            ),
        ] {
            let e = find_modes(&[good], &p).unwrap_err();
            assert!(matches!(e, IsaError::InvalidParameter(_)));
            assert!(e.to_string().contains(name), "{e}");
        }
    }

    #[test]
    fn params_serde_defaults_and_unknown_fields() {
        let p: VoteParams = serde_json::from_str(r#"{"max_hypotheses": 2}"#).unwrap();
        assert_eq!(
            p,
            VoteParams {
                max_hypotheses: 2,
                ..Default::default()
            }
        );
        assert!(serde_json::from_str::<VoteParams>(r#"{"bandwidth": 2}"#).is_err());
    }

    #[test]
    fn quaternion_helpers_agree() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200 {
            let q = random_quat(&mut rng);
            let back = matrix_to_quat(quat_to_matrix(q));
            assert!(quat_angle(q, back) < 1e-6);
            let p = quat_mul(q, axis_angle([1.0, 2.0, 3.0], 0.7));
            assert!((quat_angle(q, p) - 0.7).abs() < 1e-9);
            assert!((quat_angle(q, p.map(|v| -v)) - 0.7).abs() < 1e-9);
        }
    }
}
