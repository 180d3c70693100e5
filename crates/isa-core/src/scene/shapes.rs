//! A category's shape library: surface samples (with normals) of its training meshes in the
//! object frame, each shape's sample spacing and bounds, and the category's real-world size
//! range; and its file format (`.isl`).
//!
//! File (little-endian): magic `ISASHAPE`, format version u32, payload length u64, FNV-1a 64 of
//! the payload, then the payload: header JSON length u32 and text (`category`, `names`,
//! `size_range` or null, `n_shapes`, `n_points`), points f32 (S, N, 3), normals f32 (S, N, 3),
//! spacing f64 (S), bounds f64 (S, 2, 3). Written atomically; reading checks everything and
//! never panics.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{IsaError, Result};
use crate::model_io::fnv1a64;

const MAGIC: &[u8; 8] = b"ISASHAPE";
/// The format version this build writes (and the newest it reads).
pub const SHAPES_FORMAT_VERSION: u32 = 1;
const HEADER: usize = 8 + 4 + 8 + 8;

/// A category's real-world extents (metres): `height` the z extent, `length` the longer
/// horizontal side (as `isa.categories.SizeRange`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SizeRange {
    pub height: [f64; 2],
    pub length: [f64; 2],
}

impl SizeRange {
    /// Whether extents `(x, y, z)` fit, the range widened by `margin` (a fraction).
    pub fn admits(&self, size: [f64; 3], margin: f64) -> bool {
        let (h, l) = (size[2], size[0].max(size[1]));
        (1.0 - margin) * self.height[0] <= h
            && h <= (1.0 + margin) * self.height[1]
            && (1.0 - margin) * self.length[0] <= l
            && l <= (1.0 + margin) * self.length[1]
    }
}

/// Surface samples of a category's shapes (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeLibrary {
    pub category: String,
    pub names: Vec<String>,
    pub size_range: Option<SizeRange>,
    /// Samples per shape.
    pub n_points: usize,
    /// (S * N) points, shape after shape.
    pub points: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Mean spacing of each shape's samples (metres).
    pub spacing: Vec<f64>,
    /// Axis-aligned bounds `[min, max]` of each shape.
    pub bounds: Vec<[[f64; 3]; 2]>,
}

#[derive(Serialize, Deserialize)]
struct Header {
    category: String,
    names: Vec<String>,
    size_range: Option<SizeRange>,
    n_shapes: usize,
    n_points: usize,
}

impl ShapeLibrary {
    /// Checks the array sizes, finiteness and bounds.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        category: String,
        names: Vec<String>,
        size_range: Option<SizeRange>,
        n_points: usize,
        points: Vec<[f32; 3]>,
        normals: Vec<[f32; 3]>,
        spacing: Vec<f64>,
        bounds: Vec<[[f64; 3]; 2]>,
    ) -> Result<ShapeLibrary> {
        let bad = |m: String| {
            Err(IsaError::InvalidInput(format!(
                "shape library {category:?}: {m}"
            )))
        };
        let s = spacing.len();
        if s == 0 || n_points == 0 {
            return bad(format!("{s} shapes of {n_points} points"));
        }
        if points.len() != s * n_points || normals.len() != s * n_points || bounds.len() != s {
            return bad(format!(
                "{} points, {} normals, {} bounds for {s} shapes of {n_points} points",
                points.len(),
                normals.len(),
                bounds.len()
            ));
        }
        if !names.is_empty() && names.len() != s {
            return bad(format!("{} names for {s} shapes", names.len()));
        }
        let finite = points
            .iter()
            .chain(&normals)
            .all(|p| p.iter().all(|x| x.is_finite()))
            && spacing.iter().all(|x| x.is_finite() && *x > 0.0)
            && bounds.iter().all(|b| {
                (0..3).all(|i| b[0][i].is_finite() && b[1][i].is_finite() && b[0][i] <= b[1][i])
            });
        if !finite {
            return bad("non-finite values, a spacing <= 0 or bounds with min > max".into());
        }
        Ok(ShapeLibrary {
            category,
            names,
            size_range,
            n_points,
            points,
            normals,
            spacing,
            bounds,
        })
    }

    pub fn len(&self) -> usize {
        self.spacing.len()
    }

    pub fn is_empty(&self) -> bool {
        self.spacing.is_empty()
    }

    /// Shape `s`'s samples.
    pub fn points_of(&self, s: usize) -> &[[f32; 3]] {
        &self.points[s * self.n_points..(s + 1) * self.n_points]
    }

    /// Shape `s`'s normals.
    pub fn normals_of(&self, s: usize) -> &[[f32; 3]] {
        &self.normals[s * self.n_points..(s + 1) * self.n_points]
    }

    /// Shape `s`'s full extents.
    pub fn size(&self, s: usize) -> [f64; 3] {
        let b = &self.bounds[s];
        [0, 1, 2].map(|i| b[1][i] - b[0][i])
    }

    /// Shape `s`'s box centre (object frame).
    pub fn centre(&self, s: usize) -> [f64; 3] {
        let b = &self.bounds[s];
        [0, 1, 2].map(|i| 0.5 * (b[0][i] + b[1][i]))
    }

    /// The file's bytes (see the module docs).
    pub fn encode(&self) -> Vec<u8> {
        let header = serde_json::to_string(&Header {
            category: self.category.clone(),
            names: self.names.clone(),
            size_range: self.size_range,
            n_shapes: self.len(),
            n_points: self.n_points,
        })
        .expect("header serialises");
        let mut p = Vec::with_capacity(header.len() + 4 + self.points.len() * 24 + self.len() * 56);
        p.extend((header.len() as u32).to_le_bytes());
        p.extend(header.as_bytes());
        for v in self.points.iter().chain(&self.normals) {
            for x in v {
                p.extend(x.to_le_bytes());
            }
        }
        p.extend(self.spacing.iter().flat_map(|x| x.to_le_bytes()));
        for b in &self.bounds {
            p.extend(b.iter().flatten().flat_map(|x| x.to_le_bytes()));
        }
        let mut out = Vec::with_capacity(HEADER + p.len());
        out.extend(MAGIC);
        out.extend(SHAPES_FORMAT_VERSION.to_le_bytes());
        out.extend((p.len() as u64).to_le_bytes());
        out.extend(fnv1a64(&p).to_le_bytes());
        out.extend(p);
        out
    }

    /// A library from a file's bytes; the error names `source`.
    pub fn decode(bytes: &[u8], source: &str) -> Result<ShapeLibrary> {
        let err = |m: String| IsaError::ModelFormat {
            path: source.to_string(),
            reason: m,
        };
        if bytes.len() < HEADER || &bytes[..8] != MAGIC {
            return Err(err("not a shape library (no ISASHAPE header)".into()));
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
        if version == 0 || version > SHAPES_FORMAT_VERSION {
            return Err(err(format!(
                "format version {version}; this build reads 1..={SHAPES_FORMAT_VERSION}"
            )));
        }
        let len = u64::from_le_bytes(bytes[12..20].try_into().unwrap());
        if len != (bytes.len() - HEADER) as u64 {
            return Err(err(format!(
                "truncated: {len} payload bytes announced, {} present",
                bytes.len() - HEADER
            )));
        }
        let p = &bytes[HEADER..];
        if fnv1a64(p) != u64::from_le_bytes(bytes[20..28].try_into().unwrap()) {
            return Err(err("corrupted: checksum mismatch".into()));
        }
        let mut pos = 0usize;
        let mut take = |n: usize| -> Result<&[u8]> {
            let end = pos
                .checked_add(n)
                .filter(|e| *e <= p.len())
                .ok_or_else(|| err("payload too short".into()))?;
            let s = &p[pos..end];
            pos = end;
            Ok(s)
        };
        let hlen = u32::from_le_bytes(take(4)?.try_into().unwrap()) as usize;
        let h: Header =
            serde_json::from_slice(take(hlen)?).map_err(|e| err(format!("header: {e}")))?;
        let n = h
            .n_shapes
            .checked_mul(h.n_points)
            .filter(|n| n.checked_mul(24).is_some_and(|b| b <= p.len()))
            .ok_or_else(|| {
                err(format!(
                    "{} shapes of {} points do not fit the file",
                    h.n_shapes, h.n_points
                ))
            })?;
        let f32s = |b: &[u8]| -> Vec<[f32; 3]> {
            b.chunks_exact(12)
                .map(|c| {
                    [0, 1, 2].map(|i| f32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap()))
                })
                .collect()
        };
        let points = f32s(take(n * 12)?);
        let normals = f32s(take(n * 12)?);
        let spacing = take(h.n_shapes * 8)?
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let bounds = take(h.n_shapes * 48)?
            .chunks_exact(48)
            .map(|c| {
                let x = |i: usize| f64::from_le_bytes(c[8 * i..8 * i + 8].try_into().unwrap());
                [[x(0), x(1), x(2)], [x(3), x(4), x(5)]]
            })
            .collect();
        if pos != p.len() {
            return Err(err(format!("{} bytes after the bounds", p.len() - pos)));
        }
        ShapeLibrary::new(
            h.category,
            h.names,
            h.size_range,
            h.n_points,
            points,
            normals,
            spacing,
            bounds,
        )
        .map_err(|e| err(e.to_string()))
    }

    /// Writes the library atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::atomic::write_bytes(path, &self.encode())
    }

    /// Reads a library file.
    pub fn load(path: &Path) -> Result<ShapeLibrary> {
        let bytes = std::fs::read(path).map_err(|e| IsaError::Io {
            path: path.display().to_string(),
            source: e,
        })?;
        ShapeLibrary::decode(&bytes, &path.display().to_string())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::error::expect_err;

    /// The surface of an axis-aligned box `size` standing on z = 0 (centre over the origin),
    /// `n` samples per face side.
    pub(crate) fn box_library(size: [f64; 3], n: usize) -> ShapeLibrary {
        let mut pts = Vec::new();
        let mut nrm = Vec::new();
        let h = [size[0] / 2.0, size[1] / 2.0, size[2] / 2.0];
        for axis in 0..3 {
            for sign in [-1.0f64, 1.0] {
                let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                for i in 0..n {
                    for j in 0..n {
                        let mut p = [0.0; 3];
                        p[axis] = sign * h[axis];
                        p[a] = -h[a] + size[a] * (i as f64 + 0.5) / n as f64;
                        p[b] = -h[b] + size[b] * (j as f64 + 0.5) / n as f64;
                        p[2] += h[2];
                        let mut q = [0.0f32; 3];
                        q[axis] = sign as f32;
                        pts.push(p.map(|x| x as f32));
                        nrm.push(q);
                    }
                }
            }
        }
        let area = 2.0 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2]);
        let npts = pts.len();
        ShapeLibrary::new(
            "box".into(),
            vec![],
            None,
            npts,
            pts,
            nrm,
            vec![(area / npts as f64).sqrt()],
            vec![[[-h[0], -h[1], 0.0], [h[0], h[1], size[2]]]],
        )
        .unwrap()
    }

    #[test]
    fn roundtrip_and_every_damage_is_an_error() {
        let mut lib = box_library([0.5, 0.4, 0.8], 4);
        lib.size_range = Some(SizeRange {
            height: [0.7, 1.1],
            length: [0.4, 0.8],
        });
        let bytes = lib.encode();
        assert_eq!(ShapeLibrary::decode(&bytes, "t").unwrap(), lib);
        for cut in [0, 7, HEADER, bytes.len() / 2, bytes.len() - 1] {
            assert!(ShapeLibrary::decode(&bytes[..cut], "t").is_err(), "{cut}");
        }
        let mut bad = bytes.clone();
        bad[HEADER + 40] ^= 1;
        expect_err(ShapeLibrary::decode(&bad, "t"), &["checksum"]);
        let mut newer = bytes.clone();
        newer[8] = 9;
        expect_err(ShapeLibrary::decode(&newer, "t"), &["version 9"]);
        let dir = std::env::temp_dir().join(format!("isa-shapes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("box.shapes.isl");
        lib.save(&path).unwrap();
        assert_eq!(ShapeLibrary::load(&path).unwrap(), lib);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn size_range_admits_within_the_margin() {
        let r = SizeRange {
            height: [0.75, 1.1],
            length: [0.42, 0.75],
        };
        assert!(r.admits([0.5, 0.6, 0.9], 0.0));
        assert!(!r.admits([0.5, 0.6, 1.3], 0.15));
        assert!(r.admits([0.5, 0.6, 1.25], 0.15));
        assert!(!r.admits([0.3, 0.3, 0.9], 0.15));
    }
}
