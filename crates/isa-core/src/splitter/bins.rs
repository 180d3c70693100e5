//! Binning: a candidate's thresholds (feature values of random scored parts, sorted) cut its
//! feature axis into bins; bin indices are `u8`, part-major when the forest fills them (all
//! candidates of a part while its image patch is in cache, [`bins_row`]) or candidate-major for
//! precomputed feature columns ([`fill_bins_columns`]); [`BinMatrix`] carries either layout.
//! AVX2 paths (counting thresholds 8 values at a time; the vectorised feature + bin path) have
//! portable twins giving the same bins (tests compare them).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::features::{CandidateSoa, Feature, PartGeom};
use crate::rng::mix;

/// Thresholds drawn per candidate for a node scoring `n` parts.
pub fn thresholds_for(n: usize, k: usize) -> usize {
    k.min(n.div_ceil(8)).max(1)
}

/// Bin of feature value `f` for thresholds padded to 16 with +inf: `#{k : τ_k ≤ f}`.
#[inline(always)]
fn bin16(thr: &[f32; 16], f: f32) -> u8 {
    let mut b = 0u8;
    for t in thr {
        b += (*t <= f) as u8;
    }
    b
}

/// The thresholds of every candidate of a node (sorted, deduplicated), drawn as the feature
/// values of `min(K, ⌈n/8⌉)` random scored parts from the candidate's own random stream.
pub struct Thresholds {
    pub values: Vec<Vec<f32>>,
    padded: Vec<[f32; 16]>,
    /// `transposed[g * 16 + k][l]` = threshold `k` of candidate `8g + l` (+inf padding).
    transposed: Vec<[f32; 8]>,
    wide: bool,
}

impl Thresholds {
    /// `feature(c, j)`: candidate `c` on the node's `j`-th scored part (`j < n`).
    pub fn draw<F: Fn(usize, usize) -> f32>(
        n: usize,
        n_candidates: usize,
        n_thresholds: usize,
        feature: &F,
        node_seed: u64,
    ) -> Self {
        let kmax = thresholds_for(n, n_thresholds.min(255));
        let values: Vec<Vec<f32>> = (0..n_candidates)
            .map(|c| {
                let mut rng = ChaCha8Rng::seed_from_u64(mix(&[node_seed, c as u64, 0x7468_7265]));
                let mut thr: Vec<f32> = (0..kmax)
                    .map(|_| feature(c, rng.random_range(0..n)))
                    .collect();
                thr.sort_unstable_by(|a, b| a.total_cmp(b));
                thr.dedup();
                thr
            })
            .collect();
        let padded: Vec<[f32; 16]> = values
            .iter()
            .map(|t| {
                let mut p = [f32::INFINITY; 16];
                let k = t.len().min(16);
                p[..k].copy_from_slice(&t[..k]);
                p
            })
            .collect();
        let mut transposed = vec![[f32::INFINITY; 8]; n_candidates.div_ceil(8) * 16];
        for (c, p) in padded.iter().enumerate() {
            for k in 0..16 {
                transposed[(c / 8) * 16 + k][c % 8] = p[k];
            }
        }
        Thresholds {
            values,
            padded,
            transposed,
            wide: kmax > 16,
        }
    }

    pub fn n_candidates(&self) -> usize {
        self.values.len()
    }

    /// Bins of several feature values of candidate `c` (`out[i] = bin(c, fs[i])`).
    #[inline]
    pub fn bins_of(&self, c: usize, fs: &[f32], out: &mut [u8]) {
        let t = &self.values[c];
        if self.wide {
            for (o, &f) in out.iter_mut().zip(fs) {
                *o = t.partition_point(|&x| x <= f) as u8;
            }
            return;
        }
        // At most 16 thresholds: count them threshold by threshold over the values (the +inf
        // padding of `bin` never counts for a finite or NaN value, so it is skipped).
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: AVX2 is available; `t.len() <= 16` (not wide).
                unsafe { bins_of_avx2(t, fs, out) };
                return;
            }
        }
        for (o, &f) in out.iter_mut().zip(fs) {
            *o = t.iter().map(|&tk| (tk <= f) as u8).sum();
        }
    }

    /// Bin of feature value `f` of candidate `c`: the number of its thresholds `≤ f`.
    #[inline(always)]
    pub fn bin(&self, c: usize, f: f32) -> u8 {
        if self.wide {
            self.values[c].partition_point(|&t| t <= f) as u8
        } else {
            bin16(&self.padded[c], f)
        }
    }
}

/// [`Thresholds::bins_of`] for at most 16 thresholds, 8 values at a time (same comparisons:
/// bit-identical).
///
/// # Safety
/// AVX2 must be available and `t.len() <= 16`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bins_of_avx2(t: &[f32], fs: &[f32], out: &mut [u8]) {
    use std::arch::x86_64::*;
    debug_assert!(t.len() <= 16);
    let k = t.len();
    let mut tv = [_mm256_setzero_ps(); 16];
    for (v, &x) in tv.iter_mut().zip(t) {
        *v = _mm256_set1_ps(x);
    }
    let n = fs.len().min(out.len());
    let count = |f: __m256| {
        let mut cnt = _mm256_setzero_si256();
        for v in &tv[..k] {
            cnt = _mm256_sub_epi32(cnt, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(*v, f)));
        }
        cnt
    };
    // 32 values per step: four counts of 8, packed to bytes (counts <= 16 never saturate;
    // the packs interleave 128-bit lanes, the permutation restores the order).
    let order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let mut j = 0;
    while j + 32 <= n {
        let p = fs.as_ptr().add(j);
        // Features usually stream from memory: fetch 2 KiB ahead (a hint; never faults).
        _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(512) as *const i8);
        _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(528) as *const i8);
        let c0 = count(_mm256_loadu_ps(p));
        let c1 = count(_mm256_loadu_ps(p.add(8)));
        let c2 = count(_mm256_loadu_ps(p.add(16)));
        let c3 = count(_mm256_loadu_ps(p.add(24)));
        let b = _mm256_packus_epi16(_mm256_packs_epi32(c0, c1), _mm256_packs_epi32(c2, c3));
        let b = _mm256_permutevar8x32_epi32(b, order);
        _mm256_storeu_si256(out.as_mut_ptr().add(j) as *mut __m256i, b);
        j += 32;
    }
    for (o, &f) in out[j..n].iter_mut().zip(&fs[j..n]) {
        *o = t.iter().map(|&tk| (tk <= f) as u8).sum();
    }
}

/// Bins of every candidate of `soa` on one part: `out[c] = bin(c, f_c(part))` (AVX2 when
/// available; the result is bit-identical to the scalar path).
#[inline]
pub fn bins_row(
    thr: &Thresholds,
    soa: &CandidateSoa,
    cands: &[Feature],
    g: &PartGeom<'_>,
    out: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if !thr.wide && g.inv != 0.0 && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is available; the store keeps a padding pixel after the last image.
            unsafe { bins_row_avx2(thr, soa, g, out) };
            return;
        }
    }
    for (c, o) in out.iter_mut().enumerate() {
        *o = thr.bin(c, g.eval(&cands[c]));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bins_row_avx2(thr: &Thresholds, soa: &CandidateSoa, g: &PartGeom<'_>, out: &mut [u8]) {
    use std::arch::x86_64::*;
    let nc = out.len();
    let inv = _mm256_set1_ps(g.inv);
    let (x, y) = (_mm256_set1_epi32(g.x), _mm256_set1_epi32(g.y));
    let zero = _mm256_setzero_si256();
    // SAFETY (of every `depth` below): AVX2 is available; a DepthStore image.
    let p8 = crate::probe::Probe8::new(&g.img);
    let probe = |ox: __m256, oy: __m256| -> __m256 { p8.depth(x, y, inv, ox, oy) };
    let mut lanes = [0i32; 8];
    for gi in 0..nc.div_ceil(8) {
        let o = gi * 8;
        let f = _mm256_sub_ps(
            probe(
                _mm256_loadu_ps(soa.ux.as_ptr().add(o)),
                _mm256_loadu_ps(soa.uy.as_ptr().add(o)),
            ),
            probe(
                _mm256_loadu_ps(soa.vx.as_ptr().add(o)),
                _mm256_loadu_ps(soa.vy.as_ptr().add(o)),
            ),
        );
        let mut cnt = zero;
        for k in 0..16 {
            let t = _mm256_loadu_ps(thr.transposed[gi * 16 + k].as_ptr());
            cnt = _mm256_sub_epi32(cnt, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(t, f)));
        }
        _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, cnt);
        for (l, v) in lanes.iter().take((nc - o).min(8)).enumerate() {
            out[o + l] = *v as u8;
        }
    }
}

/// Bin indices of a node's scored parts for every candidate: bin of part `j` for candidate
/// `c` at `data[j * part_stride + c * cand_stride]`.
#[derive(Clone, Copy, Debug)]
pub struct BinMatrix<'a> {
    pub data: &'a [u8],
    pub part_stride: usize,
    pub cand_stride: usize,
}

impl<'a> BinMatrix<'a> {
    /// `data[j * nc + c]` (all candidates of a part together, as the forest fills them).
    pub fn part_major(data: &'a [u8], nc: usize) -> Self {
        BinMatrix {
            data,
            part_stride: nc,
            cand_stride: 1,
        }
    }

    /// `data[c * n + j]` (one candidate's parts together, as [`fill_bins`] fills them).
    pub fn candidate_major(data: &'a [u8], n: usize) -> Self {
        BinMatrix {
            data,
            part_stride: 1,
            cand_stride: n,
        }
    }

    #[inline(always)]
    pub(super) fn at(&self, j: usize, c: usize) -> u8 {
        self.data[j * self.part_stride + c * self.cand_stride]
    }
}

/// Candidate-major bin indices `bins[c * n + j]` of `n` parts (use with
/// [`BinMatrix::candidate_major`]): one candidate's features are read for a run of parts and
/// binned together (contiguous reads when the features are stored candidate-major).
pub fn fill_bins<F>(thr: &Thresholds, n: usize, feature: &F, parallel: bool) -> Vec<u8>
where
    F: Fn(usize, usize) -> f32 + Sync,
{
    let nc = thr.n_candidates();
    const TILE: usize = 1024;
    let fill = |c: usize, col: &mut [u8]| {
        let mut fbuf = [0f32; TILE];
        for (t, out) in col.chunks_mut(TILE).enumerate() {
            let fs = &mut fbuf[..out.len()];
            for (jj, f) in fs.iter_mut().enumerate() {
                *f = feature(c, t * TILE + jj);
            }
            thr.bins_of(c, fs, out);
        }
    };
    candidate_major_bins(n, nc, parallel, fill)
}

/// [`fill_bins`] for features stored candidate-major: `columns[c * n + j]` is candidate `c`
/// on the node's `j`-th scored part (each column is binned in place, no copies).
pub fn fill_bins_columns(thr: &Thresholds, n: usize, columns: &[f32], parallel: bool) -> Vec<u8> {
    let nc = thr.n_candidates();
    assert!(
        columns.len() >= n * nc,
        "columns: {} values for {n} x {nc}",
        columns.len()
    );
    let fill = |c: usize, col: &mut [u8]| thr.bins_of(c, &columns[c * n..(c + 1) * n], col);
    candidate_major_bins(n, nc, parallel, fill)
}

/// `n * nc` candidate-major bins, column `c` filled by `fill(c, column)` (columns in parallel
/// when asked and worth it; each column is independent, so the result is the same).
fn candidate_major_bins(
    n: usize,
    nc: usize,
    parallel: bool,
    fill: impl Fn(usize, &mut [u8]) + Sync,
) -> Vec<u8> {
    let mut bins = vec![0u8; n * nc];
    if n == 0 || nc == 0 {
        return bins;
    }
    if parallel && n * nc >= 8192 {
        bins.par_chunks_mut(n)
            .enumerate()
            .for_each(|(c, col)| fill(c, col));
    } else {
        for (c, col) in bins.chunks_mut(n).enumerate() {
            fill(c, col);
        }
    }
    bins
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Binning many values at once equals binning them one by one (features are finite; NaN
    /// is in no bin above 0 either way).
    #[test]
    fn bins_of_matches_bin() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for k in [1usize, 5, 16, 40] {
            let vals: Vec<f32> = (0..1000)
                .map(|_| rng.random_range(-50.0..50.0f32).round())
                .collect();
            let f = |_c: usize, j: usize| vals[j];
            let thr = Thresholds::draw(vals.len(), 1, k, &f, k as u64);
            let mut probe = vals.clone();
            probe.extend([f32::NEG_INFINITY, f32::NAN, 10000.0, -10000.0]);
            let mut out = vec![0u8; probe.len()];
            thr.bins_of(0, &probe, &mut out);
            let mut out2 = vec![0u8; probe.len() - 3];
            thr.bins_of(0, &probe[3..], &mut out2);
            assert_eq!(out[3..], out2[..]);
            for (o, &v) in out.iter().zip(&probe) {
                assert_eq!(*o, thr.bin(0, v), "value {v}");
            }
        }
    }

    /// The vectorised feature + bin path equals the scalar one, including probes outside the
    /// image, on missing depth and on the last pixel of the store.
    #[test]
    fn bins_row_matches_scalar() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut store = crate::depth::DepthStore::new();
        for (w, h) in [(13usize, 9usize), (31, 17)] {
            let px: Vec<u16> = (0..w * h)
                .map(|_| {
                    if rng.random_range(0.0..1.0) < 0.2 {
                        0
                    } else {
                        rng.random_range(300..5000)
                    }
                })
                .collect();
            store.push(w, h, &px).unwrap();
        }
        let cands = crate::tree::draw_candidates(&mut rng, 21, 40.0);
        let soa = CandidateSoa::new(&cands);
        for img in 0..2 {
            let (w, h) = store.dims(img);
            for v in 0..h as i32 {
                for u in 0..w as i32 {
                    let p = [img as i32, u, v];
                    if store.center_depth(&p) == 0 {
                        continue;
                    }
                    let g = PartGeom::new(&store, &p);
                    let feat = |c: usize, _j: usize| g.eval(&cands[c]);
                    let thr = Thresholds::draw(30, cands.len(), 16, &feat, (u * 7 + v) as u64);
                    let mut a = vec![0u8; cands.len()];
                    bins_row(&thr, &soa, &cands, &g, &mut a);
                    let b: Vec<u8> = (0..cands.len())
                        .map(|c| thr.bin(c, g.eval(&cands[c])))
                        .collect();
                    assert_eq!(a, b, "part {p:?}");
                }
            }
        }
    }
}
