//! The coarse grid of mode finding: cubic cells over a strided subsample of the votes, keyed
//! by packed cell index in a hash map with a fixed hasher (reproducible iteration order), each
//! keeping its weight and weighted centroid.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use super::PoseVote;

/// Hasher for packed cell keys (fast, fixed, so iteration order is reproducible).
#[derive(Default)]
pub(super) struct CellHasher(u64);

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

pub(super) type CellMap = HashMap<u64, u32, BuildHasherDefault<CellHasher>>;

pub(super) const KEY_BITS: u32 = 21;
pub(super) const KEY_OFF: i64 = 1 << (KEY_BITS - 1);

/// Cell indices are clamped to ±2^40 (far beyond what [`pack`] keeps), so neighbours `c ± 1`
/// never overflow, whatever the position.
const INDEX_LIMIT: f64 = (1u64 << 40) as f64;

#[inline(always)]
pub(super) fn cell_index(p: [f64; 3], inv_cell: f64) -> [i64; 3] {
    p.map(|x| (x * inv_cell).floor().clamp(-INDEX_LIMIT, INDEX_LIMIT) as i64)
}

/// Packs a cell index into 63 bits; indices beyond ±2^20 cells are clamped (votes that far
/// never fall inside a kernel of a sane mode anyway, distances use raw positions).
#[inline(always)]
pub(super) fn pack(c: [i64; 3]) -> u64 {
    let f = |v: i64| ((v.clamp(-KEY_OFF, KEY_OFF - 1) + KEY_OFF) as u64) & ((1 << KEY_BITS) - 1);
    (f(c[0]) << (2 * KEY_BITS)) | (f(c[1]) << KEY_BITS) | f(c[2])
}

pub(super) struct Cell {
    pub(super) weight: f64,
    pub(super) centroid: [f64; 3],
}

/// Cubic cells of side `h` over a strided subsample of the votes: weight and weighted centroid.
pub(super) struct Grid {
    pub(super) cells: Vec<Cell>,
    map: CellMap,
    inv_cell: f64,
}

impl Grid {
    /// Cells of the votes `0, stride, 2 stride, ...` (weight > 0), in order of first appearance.
    pub(super) fn build(votes: &[PoseVote], stride: usize, cell: f64) -> Grid {
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
            for (c, pk) in cell.centroid.iter_mut().zip(p) {
                *c += w * pk;
            }
        }
        for cell in &mut cells {
            let w = cell.weight;
            for c in &mut cell.centroid {
                *c /= w;
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
    pub(super) fn for_neighbour_cells(&self, p: [f64; 3], mut f: impl FnMut(&Cell)) {
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
