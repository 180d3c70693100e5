//! Gathering: the indices of the votes within a radius of each of a few centres, in one pass
//! over all votes (runs of consecutive votes tested only against the centres whose ball meets
//! the run's bounding box), 8 centres per block, with AVX2 when the CPU has it and a portable
//! twin doing the same `f32` operations in the same order (a test compares them).

use rayon::prelude::*;

use super::PoseVote;

/// Centres per block of [`gather`]: `[x, y, z]` lanes.
pub(super) const GATHER_LANES: usize = 8;

/// Centres packed [`GATHER_LANES`] to a block: a block's `[x, y, z]` lane arrays and each
/// lane's centre index; the padding lanes of the last block lie far away (never hit).
#[derive(Default)]
pub(super) struct CentreBlocks {
    pub(super) coords: Vec<[[f32; GATHER_LANES]; 3]>,
    pub(super) ids: Vec<[u32; GATHER_LANES]>,
    n: usize,
}

impl CentreBlocks {
    pub(super) fn clear(&mut self) {
        self.coords.clear();
        self.ids.clear();
        self.n = 0;
    }

    /// Adds centre `id` at `p` in the next lane.
    pub(super) fn push(&mut self, id: u32, p: [f32; 3]) {
        let l = self.n % GATHER_LANES;
        self.n += 1;
        if l == 0 {
            self.coords.push([[1e18f32; GATHER_LANES]; 3]);
            self.ids.push([0; GATHER_LANES]);
        }
        let b = self.coords.last_mut().expect("a block");
        for a in 0..3 {
            b[a][l] = p[a];
        }
        self.ids.last_mut().expect("a block")[l] = id;
    }

    pub(super) fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }
}

/// Appends `index` to `out[id[l]]` for every lane `l` set in `mask` (both paths).
#[inline(always)]
fn push_hits(mut mask: u32, id: &[u32; GATHER_LANES], index: u32, out: &mut [Vec<u32>]) {
    while mask != 0 {
        let l = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        out[id[l] as usize].push(index);
    }
}

/// [`gather`] on one chunk of votes whose first index is `base`: `out[c]` gets the indices
/// within `sqrt(r2)` of centre `c` (same f32 operations on every path).
#[inline(always)]
pub(super) fn gather_chunk(
    chunk: &[PoseVote],
    base: usize,
    centres: &CentreBlocks,
    r2: f32,
    out: &mut [Vec<u32>],
) {
    const B: usize = GATHER_LANES;
    for (i, v) in chunk.iter().enumerate() {
        if v.weight <= 0.0 {
            continue;
        }
        let p = v.position;
        for (b, id) in centres.coords.iter().zip(&centres.ids) {
            let mut mask = 0u32;
            // One lane index across the block's three coordinate arrays: the shape that the
            // portable twin of the AVX2 path is compared with.
            #[allow(clippy::needless_range_loop)]
            for l in 0..B {
                let (dx, dy, dz) = (p[0] - b[0][l], p[1] - b[1][l], p[2] - b[2][l]);
                mask |= u32::from(dx * dx + dy * dy + dz * dz < r2) << l;
            }
            push_hits(mask, id, (base + i) as u32, out);
        }
    }
}

/// [`gather_chunk`] with AVX2 (the 8 lanes of a block in one register; the same IEEE
/// operations in the same order, so the same answer; `gather_paths_agree` compares the two).
///
/// # Safety
/// AVX2 must be available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn gather_chunk_avx2(
    chunk: &[PoseVote],
    base: usize,
    centres: &CentreBlocks,
    r2: f32,
    out: &mut [Vec<u32>],
) {
    use std::arch::x86_64::*;
    let r2v = _mm256_set1_ps(r2);
    let bv: Vec<[__m256; 3]> = centres
        .coords
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
        for (b, id) in bv.iter().zip(&centres.ids) {
            let (dx, dy, dz) = (
                _mm256_sub_ps(px, b[0]),
                _mm256_sub_ps(py, b[1]),
                _mm256_sub_ps(pz, b[2]),
            );
            let d2 = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                _mm256_mul_ps(dz, dz),
            );
            let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(d2, r2v)) as u32;
            push_hits(mask, id, (base + i) as u32, out);
        }
    }
}

/// Indices of the votes (weight > 0) within `radius` of each centre (tested in `f32`), in vote
/// order; one pass over the votes, in parallel over fixed chunks, 8 centres per SIMD-friendly
/// block.
pub(super) fn gather(votes: &[PoseVote], centres: &[[f64; 3]], radius: f64) -> Vec<Vec<u32>> {
    const CH: usize = 1 << 14;
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
            let mut blocks = CentreBlocks::default();
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
                    blocks.push(c as u32, *p);
                }
                if blocks.is_empty() {
                    continue;
                }
                let base = ci * CH + si * SUB;
                #[cfg(target_arch = "x86_64")]
                if avx2 {
                    // SAFETY: AVX2 is available.
                    unsafe { gather_chunk_avx2(sub, base, &blocks, r2, &mut out) };
                    continue;
                }
                let _ = avx2;
                gather_chunk(sub, base, &blocks, r2, &mut out);
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
