//! The criterion's targets (embedded, standardised, reduced; see [`crate::criterion`]) built a
//! block of [`STAT_CHUNK`] rows at a time, so the raw per-part arrays need never be in memory
//! at once: the wide ones (link angles, node offsets) are read through [`WideTargets`], from
//! slices ([`RawTargets`]) or from training-set shards on disk ([`crate::shards`]).
//!
//! Every statistic is a sum over fixed chunks of rows combined in chunk order, and every
//! embedded value is recomputed from its raw value by the same expression in each pass, so the
//! targets (and the forest) are the same bits whatever the source and the thread count.

use std::ops::Range;

use faer::{Mat, Side};
use rayon::prelude::*;

use crate::criterion::{Layout, RawTargets, Targets, Term};
use crate::error::{IsaError, Result};
use crate::params::Quality;
use crate::rotation::quat_to_6d;

/// Rows per parallel chunk of the column statistics (fixed, so sums do not depend on threads).
pub const STAT_CHUNK: usize = 8192;

/// The wide raw targets, read a range of rows at a time.
pub trait WideTargets: Sync {
    /// Columns of `Term::Links` (link angles) or `Term::Nodes` (node offsets); None if absent.
    fn width(&self, term: Term) -> Option<usize>;
    /// Rows `rows` of that array, row-major, into `out` (`rows.len() * width` values).
    fn read(&self, term: Term, rows: Range<usize>, out: &mut [f32]) -> Result<()>;
}

impl WideTargets for RawTargets<'_> {
    fn width(&self, term: Term) -> Option<usize> {
        self.wide(term).map(|a| a.1)
    }
    fn read(&self, term: Term, rows: Range<usize>, out: &mut [f32]) -> Result<()> {
        let (a, w) = self.wide(term).expect("width() said the array is there");
        out.copy_from_slice(&a[rows.start * w..rows.end * w]);
        Ok(())
    }
}

impl<'a> RawTargets<'a> {
    fn wide(&self, term: Term) -> Option<(&'a [f32], usize)> {
        match term {
            Term::Links => self.link_angles,
            Term::Nodes => self.node_offsets,
            Term::Offset | Term::Rotation => None,
        }
    }
}

/// Builds the criterion's targets for `quality` from raw arrays in memory (validated here).
pub fn build_targets(
    raw: &RawTargets<'_>,
    quality: Quality,
    reduce_dims: usize,
) -> Result<Targets> {
    raw.validate()?;
    build_targets_from(raw.offsets, raw.rotations, raw, quality, reduce_dims)
}

/// Builds the criterion's targets from the compact `offsets` `(n, 3)` and `rotations` `(n, 4)`
/// and the wide arrays of `wide` (validated by the caller).
pub fn build_targets_from(
    offsets: &[f32],
    rotations: &[f32],
    wide: &dyn WideTargets,
    quality: Quality,
    reduce_dims: usize,
) -> Result<Targets> {
    let n = offsets.len() / 3;
    if n == 0 {
        return Err(IsaError::InvalidInput("no parts".into()));
    }
    let need = |term: Term, name: &str| -> Result<usize> {
        wide.width(term).ok_or_else(|| {
            IsaError::InvalidInput(format!("quality {} needs {name}", quality.as_str()))
        })
    };
    let mut blocks = vec![
        Source {
            term: Term::Offset,
            raw_width: 3,
            dim: 3,
        },
        Source {
            term: Term::Rotation,
            raw_width: 4,
            dim: 6,
        },
    ];
    if quality.uses_q2() {
        let l = need(Term::Links, "link_angles")?;
        blocks.push(Source {
            term: Term::Links,
            raw_width: l,
            dim: 2 * l,
        });
    }
    if quality.uses_q3() {
        let w = need(Term::Nodes, "node_offsets")?;
        blocks.push(Source {
            term: Term::Nodes,
            raw_width: w,
            dim: w,
        });
    }
    let rows = Rows {
        n,
        offsets,
        rotations,
        wide,
    };
    // Standardise, then reduce a and s; each block is written straight into its columns.
    let mut plans = Vec::new();
    for src in blocks {
        let (mean, scale) = rows.standardisation(&src)?;
        let reduce = matches!(src.term, Term::Links | Term::Nodes)
            && reduce_dims > 0
            && reduce_dims < src.dim;
        let basis = if reduce {
            Some(rows.principal_basis(&src, &mean, &scale, reduce_dims)?)
        } else {
            None
        };
        let dim = if reduce { reduce_dims } else { src.dim };
        plans.push((src, mean, scale, basis, dim));
    }
    let layout = Layout::new(&plans.iter().map(|p| (p.0.term, p.4)).collect::<Vec<_>>());
    let mut out = vec![0f32; n * layout.dim];
    out.par_chunks_mut(STAT_CHUNK * layout.dim)
        .enumerate()
        .try_for_each(|(c, o)| -> Result<()> {
            let range = rows.chunk(c);
            let mut e = Vec::new();
            for ((src, mean, scale, basis, dim), b) in plans.iter().zip(&layout.blocks) {
                rows.standardised(src, range.clone(), mean, scale, &mut e)?;
                let mut put =
                    |i: usize, j: usize, v: f64| o[i * layout.dim + b.start + j] = v as f32;
                match basis {
                    Some(basis) => {
                        for (i, r) in e.chunks_exact(src.dim).enumerate() {
                            for j in 0..*dim {
                                let bj = &basis[j * src.dim..(j + 1) * src.dim];
                                put(i, j, r.iter().zip(bj).map(|(x, y)| x * y).sum());
                            }
                        }
                    }
                    None => {
                        for (i, r) in e.chunks_exact(src.dim).enumerate() {
                            for (j, &v) in r.iter().enumerate() {
                                put(i, j, v);
                            }
                        }
                    }
                }
            }
            Ok(())
        })?;
    Ok(Targets {
        layout,
        data: out,
        n,
    })
}

/// One block of the target vector and the raw array it embeds.
struct Source {
    term: Term,
    raw_width: usize,
    /// Embedded dimension.
    dim: usize,
}

struct Rows<'a> {
    n: usize,
    offsets: &'a [f32],
    rotations: &'a [f32],
    wide: &'a dyn WideTargets,
}

impl Rows<'_> {
    fn n_chunks(&self) -> usize {
        self.n.div_ceil(STAT_CHUNK)
    }

    fn chunk(&self, c: usize) -> Range<usize> {
        c * STAT_CHUNK..((c + 1) * STAT_CHUNK).min(self.n)
    }

    /// The embedded rows `rows` of `src` into `out` (`rows.len() * src.dim` values).
    fn embed(&self, src: &Source, rows: Range<usize>, out: &mut Vec<f64>) -> Result<()> {
        out.clear();
        match src.term {
            Term::Offset => out.extend(
                self.offsets[3 * rows.start..3 * rows.end]
                    .iter()
                    .map(|&v| v as f64),
            ),
            Term::Rotation => {
                for q in self.rotations[4 * rows.start..4 * rows.end].chunks_exact(4) {
                    out.extend_from_slice(&quat_to_6d(q));
                }
            }
            term => {
                let mut raw = vec![0f32; rows.len() * src.raw_width];
                self.wide.read(term, rows, &mut raw)?;
                if term == Term::Links {
                    for &v in &raw {
                        let v = v as f64;
                        out.push(v.cos());
                        out.push(v.sin());
                    }
                } else {
                    out.extend(raw.iter().map(|&v| v as f64));
                }
            }
        }
        Ok(())
    }

    /// Per-column sums of `f(row)` over the embedded rows, chunks combined in order.
    fn column_sums(
        &self,
        src: &Source,
        width: usize,
        f: impl Fn(&[f64], &mut [f64]) + Sync,
    ) -> Result<Vec<f64>> {
        let parts: Vec<Vec<f64>> = (0..self.n_chunks())
            .into_par_iter()
            .map(|c| {
                let mut e = Vec::new();
                self.embed(src, self.chunk(c), &mut e)?;
                let mut acc = vec![0f64; width];
                for r in e.chunks_exact(src.dim) {
                    f(r, &mut acc);
                }
                Ok(acc)
            })
            .collect::<Result<_>>()?;
        let mut out = vec![0f64; width];
        for p in parts {
            for (o, v) in out.iter_mut().zip(p) {
                *o += v;
            }
        }
        Ok(out)
    }

    /// Column means and inverse population standard deviations (1 when the std is below 1e-6).
    fn standardisation(&self, src: &Source) -> Result<(Vec<f64>, Vec<f64>)> {
        let n = self.n as f64;
        let mean: Vec<f64> = self
            .column_sums(src, src.dim, |r, acc| {
                for (a, v) in acc.iter_mut().zip(r) {
                    *a += v;
                }
            })?
            .into_iter()
            .map(|s| s / n)
            .collect();
        let var = self.column_sums(src, src.dim, |r, acc| {
            for ((a, v), m) in acc.iter_mut().zip(r).zip(&mean) {
                *a += (v - m) * (v - m);
            }
        })?;
        let scale = var
            .iter()
            .map(|v| {
                let sd = (v / n).sqrt();
                if sd < 1e-6 {
                    1.0
                } else {
                    1.0 / sd
                }
            })
            .collect();
        Ok((mean, scale))
    }

    /// The standardised embedded rows `rows` of `src` into `out`.
    fn standardised(
        &self,
        src: &Source,
        rows: Range<usize>,
        mean: &[f64],
        scale: &[f64],
        out: &mut Vec<f64>,
    ) -> Result<()> {
        self.embed(src, rows, out)?;
        for r in out.chunks_exact_mut(src.dim) {
            for ((v, m), s) in r.iter_mut().zip(mean).zip(scale) {
                *v = (*v - m) * s;
            }
        }
        Ok(())
    }

    /// The top-`k` principal directions of the standardised block (faer's self-adjoint
    /// eigendecomposition), largest first, each `src.dim` long.
    fn principal_basis(
        &self,
        src: &Source,
        mean: &[f64],
        scale: &[f64],
        k: usize,
    ) -> Result<Vec<f64>> {
        let d = src.dim;
        // Upper-triangular second moments, parallel chunks combined in order.
        let tri: Vec<Vec<f64>> = (0..self.n_chunks())
            .into_par_iter()
            .map(|c| {
                let mut e = Vec::new();
                self.standardised(src, self.chunk(c), mean, scale, &mut e)?;
                let mut acc = vec![0f64; d * d];
                for r in e.chunks_exact(d) {
                    for a in 0..d {
                        let ra = r[a];
                        let row = &mut acc[a * d..(a + 1) * d];
                        for b in a..d {
                            row[b] += ra * r[b];
                        }
                    }
                }
                Ok(acc)
            })
            .collect::<Result<_>>()?;
        let mut cov = Mat::<f64>::zeros(d, d);
        for t in &tri {
            for a in 0..d {
                for b in a..d {
                    cov[(a, b)] += t[a * d + b];
                }
            }
        }
        for a in 0..d {
            for b in a..d {
                let v = cov[(a, b)] / self.n as f64;
                cov[(a, b)] = v;
                cov[(b, a)] = v;
            }
        }
        let evd = cov.self_adjoint_eigen(Side::Lower).map_err(|e| {
            IsaError::InvalidInput(format!("principal components of the targets failed: {e:?}"))
        })?;
        let u = evd.U();
        // Eigenvalues are nondecreasing: keep the last k columns, largest first.
        Ok((0..k)
            .flat_map(|c| (0..d).map(move |a| (a, d - 1 - c)))
            .map(|(a, col)| u[(a, col)])
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The dense reference: every block embedded whole in memory, standardised, projected.
    fn dense(raw: &RawTargets<'_>, quality: Quality, k: usize) -> Vec<f32> {
        let n = raw.n();
        let mut blocks: Vec<(bool, usize, Vec<f64>)> = vec![
            (false, 3, raw.offsets.iter().map(|&v| v as f64).collect()),
            (
                false,
                6,
                raw.rotations.chunks_exact(4).flat_map(quat_to_6d).collect(),
            ),
        ];
        if quality.uses_q2() {
            let (a, l) = raw.link_angles.unwrap();
            blocks.push((
                true,
                2 * l,
                a.iter()
                    .flat_map(|&v| [(v as f64).cos(), (v as f64).sin()])
                    .collect(),
            ));
        }
        if quality.uses_q3() {
            let (s, w) = raw.node_offsets.unwrap();
            blocks.push((true, w, s.iter().map(|&v| v as f64).collect()));
        }
        let mut cols: Vec<(usize, Vec<f64>)> = Vec::new();
        for (wide, d, mut x) in blocks {
            for j in 0..d {
                let m = (0..n).map(|i| x[i * d + j]).sum::<f64>() / n as f64;
                let sd =
                    ((0..n).map(|i| (x[i * d + j] - m).powi(2)).sum::<f64>() / n as f64).sqrt();
                let s = if sd < 1e-6 { 1.0 } else { 1.0 / sd };
                for i in 0..n {
                    x[i * d + j] = (x[i * d + j] - m) * s;
                }
            }
            if wide && k > 0 && k < d {
                let cov = Mat::<f64>::from_fn(d, d, |a, b| {
                    (0..n).map(|i| x[i * d + a] * x[i * d + b]).sum::<f64>() / n as f64
                });
                let evd = cov.self_adjoint_eigen(Side::Lower).unwrap();
                let u = evd.U();
                let y = (0..n)
                    .flat_map(|i| {
                        let x = &x;
                        (0..k).map(move |c| (0..d).map(|a| x[i * d + a] * u[(a, d - 1 - c)]).sum())
                    })
                    .collect();
                cols.push((k, y));
            } else {
                cols.push((d, x));
            }
        }
        (0..n)
            .flat_map(|i| {
                cols.iter()
                    .flat_map(move |(d, x)| x[i * d..(i + 1) * d].iter().map(|&v| v as f32))
            })
            .collect()
    }

    #[test]
    fn chunked_targets_match_the_dense_reference_and_any_thread_count() {
        // More rows than two chunks, so chunk boundaries and their in-order combination matter.
        let n = 2 * STAT_CHUNK + 123;
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut g = |lo: f32, hi: f32, k: usize| -> Vec<f32> {
            (0..k).map(|_| rng.random_range(lo..hi)).collect()
        };
        let (off, rot, z, e) = (
            g(-1.0, 1.0, 3 * n),
            g(-1.0, 1.0, 4 * n),
            g(-1.0, 1.0, 2 * n),
            g(-0.01, 0.01, 11 * n),
        );
        // Unit quaternions, as every training set's rotations must be.
        let rot: Vec<f32> = rot
            .chunks_exact(4)
            .flat_map(|q| {
                let norm = q.iter().map(|x| x * x).sum::<f32>().sqrt();
                q.iter().map(move |x| x / norm).collect::<Vec<_>>()
            })
            .collect();
        // Wide targets driven by two factors of distinct strength, so the top two principal
        // directions are well separated (PCA is then unique up to sign).
        let la: Vec<f32> = (0..5 * n)
            .map(|k| (k % 5 + 1) as f32 * (0.3 * z[2 * (k / 5)] + 0.1 * z[2 * (k / 5) + 1]) + e[k])
            .collect();
        let no: Vec<f32> = (0..6 * n)
            .map(|k| {
                20.0 * z[2 * (k / 6)] - (k % 6) as f32 * 4.0 * z[2 * (k / 6) + 1] + e[5 * n + k]
            })
            .collect();
        let raw = RawTargets {
            offsets: &off,
            rotations: &rot,
            link_angles: Some((&la, 5)),
            node_offsets: Some((&no, 6)),
        };
        for (q, k) in [(Quality::Q1, 0), (Quality::Q1Q2Q3, 0), (Quality::Q1Q2Q3, 2)] {
            let t = build_targets(&raw, q, k).unwrap();
            let want = dense(&raw, q, k);
            assert_eq!(t.data.len(), want.len());
            // The reference sums in another order: equal to float rounding; PCA columns up to sign.
            for (i, (a, b)) in t.data.iter().zip(&want).enumerate() {
                assert!(
                    (a.abs() - b.abs()).abs() < 1e-3,
                    "{q:?} k={k} value {i}: {a} vs {b}"
                );
            }
            let one = crate::forest::with_threads(Some(1), || build_targets(&raw, q, k).unwrap())
                .unwrap();
            assert_eq!(one.data, t.data, "{q:?}: thread count changed the targets");
        }
    }
}
