//! Training sets on disk as shards: a folder of `.isat` files ([`crate::trainset_io`], one per
//! rendered instance, image indices local to the shard) and a manifest, `manifest.json`, that
//! lists them in training order with their size, checksum and counts.
//!
//! ```text
//! {"format": "isa-training-shards", "version": 1,
//!  "link_angles": L | null, "node_offsets": 3N | null,
//!  "shards": [{"file": "0001.isat", "bytes": 123456, "checksum": "89ab...", "parts": 1400,
//!              "images": 89, "pixels": 2100000}, ...]}
//! ```
//! [`ShardSet::open`] reads each shard memory-mapped (`memmap2`), checks it against the manifest
//! (size, checksum: a truncated or replaced shard is refused by name) and validates it as a
//! training set; it keeps only what every tree reads (depth crops, each trimmed to the box of
//! its nonzero pixels, parts with global image indices and moved with their crop, offsets,
//! rotations: about 40 bytes a part plus the crops) and unmaps the shard. The
//! wide targets (link angles, node offsets: 300 bytes a part for 18 links and 19 nodes) are
//! read back a block of rows at a time when the targets are built ([`WideTargets`]), through
//! positioned reads that leave nothing resident.
//!
//! The rows of the set are the shards' rows in manifest order, so a forest trained from shards
//! is the forest trained from the same arrays concatenated in memory, to the byte.
//!
//! Over 600 lines because its unit tests live beside the code they test (`mod tests` below,
//! shared with the forest's shards-vs-memory test).

use std::fs::File;
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::criterion::Term;
use crate::depth::{DepthStore, Part};
use crate::error::{IsaError, Result};
use crate::model_io::fnv1a64;
use crate::targets::WideTargets;
use crate::trainset_io::{self, Located, TrainSetData};

/// File name of the manifest inside a shard folder.
pub const MANIFEST: &str = "manifest.json";
pub const MANIFEST_FORMAT: &str = "isa-training-shards";
pub const MANIFEST_VERSION: u32 = 1;

/// One shard as the manifest describes it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardEntry {
    /// File name, relative to the folder.
    pub file: String,
    pub bytes: u64,
    /// The shard's own trailing FNV-1a 64 checksum, hex.
    pub checksum: String,
    pub parts: usize,
    pub images: usize,
    pub pixels: usize,
}

/// The manifest of a shard folder.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    pub link_angles: Option<usize>,
    pub node_offsets: Option<usize>,
    pub shards: Vec<ShardEntry>,
}

impl Manifest {
    pub fn n_parts(&self) -> usize {
        self.shards.iter().map(|s| s.parts).sum()
    }
    pub fn n_images(&self) -> usize {
        self.shards.iter().map(|s| s.images).sum()
    }
    pub fn n_pixels(&self) -> usize {
        self.shards.iter().map(|s| s.pixels).sum()
    }

    /// Reads and checks `dir/manifest.json` (format, version, at least one shard, file names
    /// inside the folder).
    pub fn read(dir: &Path) -> Result<Manifest> {
        let path = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&path).map_err(|source| IsaError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let bad =
            |m: String| IsaError::InvalidInput(format!("shard manifest {}: {m}", path.display()));
        let m: Manifest = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if m.format != MANIFEST_FORMAT {
            return Err(bad(format!(
                "format {:?}, expected {MANIFEST_FORMAT:?}",
                m.format
            )));
        }
        if m.version != MANIFEST_VERSION {
            return Err(bad(format!(
                "version {}, this isa reads version {MANIFEST_VERSION}",
                m.version
            )));
        }
        if m.shards.is_empty() {
            return Err(bad("lists no shard".into()));
        }
        for s in &m.shards {
            if s.file.is_empty() || s.file.contains('/') || s.file.starts_with('.') {
                return Err(bad(format!(
                    "shard file name {:?} is not a plain name in the folder",
                    s.file
                )));
            }
        }
        Ok(m)
    }
}

/// A shard's bytes, memory-mapped read-only.
fn map(path: &Path) -> Result<memmap2::Mmap> {
    let io = |source| IsaError::Io {
        path: path.display().to_string(),
        source,
    };
    let f = File::open(path).map_err(io)?;
    // SAFETY: the file is only read; a shard changed on disk while mapped is caught by the
    // checksum checked right after mapping (and by the manifest's checksum).
    unsafe { memmap2::Mmap::map(&f) }.map_err(io)
}

/// Reads, validates and describes shard `file` of `dir`, with where its wide arrays lie.
fn load_shard(dir: &Path, file: &str) -> Result<(ShardEntry, TrainSetData, Located)> {
    let path = dir.join(file);
    let bytes = map(&path)?;
    let label = format!("shard {}", path.display());
    let (ts, located) = trainset_io::decode_located(&bytes, &label)?;
    let sum = u64::from_le_bytes(bytes[bytes.len() - 8..].try_into().expect("8 bytes"));
    debug_assert_eq!(sum, fnv1a64(&bytes[..bytes.len() - 8]));
    let entry = ShardEntry {
        file: file.to_string(),
        bytes: bytes.len() as u64,
        checksum: format!("{sum:016x}"),
        parts: ts.parts.len(),
        images: ts.store.len(),
        pixels: ts.store.n_pixels(),
    };
    Ok((entry, ts, located))
}

/// Writes `dir/manifest.json` for the shards `files` (in training order), reading each to
/// validate it and record its counts; atomic (temporary file + rename).
pub fn write_manifest(dir: &Path, files: &[String]) -> Result<Manifest> {
    let mut m = Manifest {
        format: MANIFEST_FORMAT.into(),
        version: MANIFEST_VERSION,
        link_angles: None,
        node_offsets: None,
        shards: Vec::new(),
    };
    if files.is_empty() {
        return Err(IsaError::InvalidInput(format!(
            "shards in {}: no shard files given",
            dir.display()
        )));
    }
    for (k, file) in files.iter().enumerate() {
        let (entry, ts, _) = load_shard(dir, file)?;
        let widths = (
            ts.link_angles.as_ref().map(|a| a.1),
            ts.node_offsets.as_ref().map(|a| a.1),
        );
        if k == 0 {
            (m.link_angles, m.node_offsets) = widths;
        } else if widths != (m.link_angles, m.node_offsets) {
            return Err(IsaError::InvalidInput(format!(
                "shard {}: link_angles / node_offsets columns {widths:?} differ from the first shard's {:?}",
                dir.join(file).display(),
                (m.link_angles, m.node_offsets)
            )));
        }
        m.shards.push(entry);
    }
    let text = serde_json::to_string_pretty(&m).expect("a manifest serialises");
    crate::atomic::write_bytes(&dir.join(MANIFEST), text.as_bytes())?;
    Ok(m)
}

/// Where one shard's rows of a wide array lie.
#[derive(Debug)]
struct Piece {
    /// First global row.
    row: usize,
    rows: usize,
    file: usize,
    /// Byte offset of the shard's first row in its file.
    at: u64,
}

/// A wide target array spread over the shards.
#[derive(Debug, Default)]
struct WideColumn {
    width: usize,
    pieces: Vec<Piece>,
}

/// A shard folder opened for training (see the module doc).
#[derive(Debug)]
pub struct ShardSet {
    pub dir: PathBuf,
    pub manifest: Manifest,
    pub store: DepthStore,
    pub parts: Vec<Part>,
    /// `(P, 3)` row-major.
    pub offsets: Vec<f32>,
    /// `(P, 4)` row-major.
    pub rotations: Vec<f32>,
    files: Vec<(PathBuf, File)>,
    links: Option<WideColumn>,
    nodes: Option<WideColumn>,
}

impl ShardSet {
    /// Opens every shard of `dir`'s manifest; the error names the shard (or manifest) at fault.
    pub fn open(dir: &Path) -> Result<ShardSet> {
        let manifest = Manifest::read(dir)?;
        let (p, n_img, px) = (manifest.n_parts(), manifest.n_images(), manifest.n_pixels());
        if p > u32::MAX as usize / 2 || n_img > i32::MAX as usize {
            return Err(IsaError::InvalidInput(format!(
                "shards in {}: {p} parts is too many",
                dir.display()
            )));
        }
        let mut set = ShardSet {
            dir: dir.to_path_buf(),
            store: DepthStore::with_capacity(n_img, px),
            parts: Vec::with_capacity(p),
            offsets: Vec::with_capacity(3 * p),
            rotations: Vec::with_capacity(4 * p),
            files: Vec::new(),
            links: manifest.link_angles.map(|width| WideColumn {
                width,
                pieces: Vec::new(),
            }),
            nodes: manifest.node_offsets.map(|width| WideColumn {
                width,
                pieces: Vec::new(),
            }),
            manifest,
        };
        for want in set.manifest.shards.clone() {
            let path = dir.join(&want.file);
            let label = path.display().to_string();
            let size = std::fs::metadata(&path)
                .map_err(|source| IsaError::Io {
                    path: label.clone(),
                    source,
                })?
                .len();
            if size != want.bytes {
                return Err(IsaError::InvalidInput(format!(
                    "shard {label}: {size} bytes, the manifest says {} (truncated or replaced)",
                    want.bytes
                )));
            }
            let (got, ts, located) = load_shard(dir, &want.file)?;
            if got != want {
                return Err(IsaError::InvalidInput(format!(
                    "shard {label}: checksum or counts differ from the manifest (replaced since it was written)"
                )));
            }
            let widths = (
                ts.link_angles.as_ref().map(|a| a.1),
                ts.node_offsets.as_ref().map(|a| a.1),
            );
            if widths != (set.manifest.link_angles, set.manifest.node_offsets) {
                return Err(IsaError::InvalidInput(format!(
                    "shard {label}: link_angles / node_offsets columns {widths:?}, the manifest says {:?}",
                    (set.manifest.link_angles, set.manifest.node_offsets)
                )));
            }
            let first_image = set.store.len() as i32;
            // Each crop trimmed to the box of its nonzero pixels, its parts moved with it.
            let mut shift = Vec::with_capacity(ts.store.len());
            let mut buf = Vec::new();
            for i in 0..ts.store.len() {
                let (w, h) = ts.store.dims(i);
                let data = ts.store.image(i).data;
                let (c0, r0, tw, th) = nonzero_box(data, w, h);
                if (tw, th) == (w, h) {
                    set.store.push(w, h, data)?;
                } else {
                    buf.clear();
                    for r in r0..r0 + th {
                        buf.extend_from_slice(&data[r * w + c0..r * w + c0 + tw]);
                    }
                    set.store.push(tw, th, &buf)?;
                }
                shift.push([c0 as i32, r0 as i32]);
            }
            set.parts.extend(ts.parts.iter().map(|q| {
                let [du, dv] = shift[q[0] as usize];
                [q[0] + first_image, q[1] - du, q[2] - dv]
            }));
            set.offsets.extend_from_slice(&ts.offsets);
            set.rotations.extend_from_slice(&ts.rotations);
            let row = set.parts.len() - ts.parts.len();
            let file = set.files.len();
            for (name, col) in [
                ("link_angles", &mut set.links),
                ("node_offsets", &mut set.nodes),
            ] {
                if let Some(col) = col {
                    let at = located
                        .iter()
                        .find(|(n, _)| n == name)
                        .expect("validated above")
                        .1
                        .start;
                    col.pieces.push(Piece {
                        row,
                        rows: ts.parts.len(),
                        file,
                        at: at as u64,
                    });
                }
            }
            let f = File::open(&path).map_err(|source| IsaError::Io {
                path: label.clone(),
                source,
            })?;
            set.files.push((path, f));
        }
        Ok(set)
    }

    pub fn n_parts(&self) -> usize {
        self.parts.len()
    }
}

/// The smallest box holding every nonzero pixel of a `w` x `h` row-major crop, as
/// `(first column, first row, width, height)`; the whole crop if it has none.
///
/// A probe reads the same [`BACKGROUND_MM`](crate::features::BACKGROUND_MM) outside an image
/// as on a zero pixel, and moves a whole number of pixels from its part, so a crop trimmed to
/// this box, with its parts moved by the box's corner, gives every feature the same value: the
/// same trees. Crops are cut around the object mask with a margin of zeros (8 pixels in
/// `isa.privileged.annotate`), which this drops (7.5% of the bed beyond set's pixels).
fn nonzero_box(data: &[u16], w: usize, h: usize) -> (usize, usize, usize, usize) {
    let (mut r0, mut r1, mut c0, mut c1) = (h, 0, w, 0);
    for (r, row) in data.chunks_exact(w).enumerate() {
        if let Some(a) = row.iter().position(|&d| d != 0) {
            let b = row.iter().rposition(|&d| d != 0).expect("a nonzero pixel");
            (r0, r1) = (r0.min(r), r + 1);
            (c0, c1) = (c0.min(a), c1.max(b + 1));
        }
    }
    if r0 >= r1 {
        return (0, 0, w, h);
    }
    (c0, r0, c1 - c0, r1 - r0)
}

impl WideTargets for ShardSet {
    fn width(&self, term: Term) -> Option<usize> {
        self.column(term).map(|c| c.width)
    }

    fn read(&self, term: Term, rows: Range<usize>, out: &mut [f32]) -> Result<()> {
        let col = self.column(term).expect("width() said the array is there");
        let w = col.width;
        let first = col.pieces.partition_point(|p| p.row + p.rows <= rows.start);
        let mut buf = Vec::new();
        for p in &col.pieces[first..] {
            if p.row >= rows.end {
                break;
            }
            let (a, b) = (rows.start.max(p.row), rows.end.min(p.row + p.rows));
            buf.resize((b - a) * w * 4, 0u8);
            let (path, f) = &self.files[p.file];
            f.read_exact_at(&mut buf, p.at + ((a - p.row) * w * 4) as u64)
                .map_err(|source| IsaError::Io {
                    path: path.display().to_string(),
                    source,
                })?;
            let dst = &mut out[(a - rows.start) * w..(b - rows.start) * w];
            for (d, c) in dst.iter_mut().zip(buf.chunks_exact(4)) {
                *d = f32::from_le_bytes(c.try_into().expect("4 bytes"));
            }
        }
        Ok(())
    }
}

impl ShardSet {
    fn column(&self, term: Term) -> Option<&WideColumn> {
        match term {
            Term::Links => self.links.as_ref(),
            Term::Nodes => self.nodes.as_ref(),
            Term::Offset | Term::Rotation => None,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::error::expect_err;

    /// Writes `sets` as shards `0.isat`, `1.isat`, ... of a fresh folder with its manifest.
    pub(crate) fn write_shards(name: &str, sets: &[TrainSetData]) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("isa-shards-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let files: Vec<String> = (0..sets.len()).map(|k| format!("{k}.isat")).collect();
        for (ts, f) in sets.iter().zip(&files) {
            trainset_io::write(ts, &dir.join(f)).unwrap();
        }
        write_manifest(&dir, &files).unwrap();
        dir
    }

    /// Splits a training set into shards of whole images (`cuts`: first image of each shard after the first).
    pub(crate) fn split(ts: &TrainSetData, cuts: &[usize]) -> Vec<TrainSetData> {
        let mut bounds = vec![0];
        bounds.extend_from_slice(cuts);
        bounds.push(ts.store.len());
        bounds
            .windows(2)
            .map(|b| {
                let mut s = TrainSetData {
                    metadata: "{}".into(),
                    ..Default::default()
                };
                for i in b[0]..b[1] {
                    let (w, h) = ts.store.dims(i);
                    s.store.push(w, h, ts.store.image(i).data).unwrap();
                }
                let rows: Vec<usize> = (0..ts.parts.len())
                    .filter(|&k| (b[0]..b[1]).contains(&(ts.parts[k][0] as usize)))
                    .collect();
                s.parts = rows
                    .iter()
                    .map(|&k| {
                        let q = ts.parts[k];
                        [q[0] - b[0] as i32, q[1], q[2]]
                    })
                    .collect();
                let take = |a: &[f32], w: usize| -> Vec<f32> {
                    rows.iter()
                        .flat_map(|&k| a[k * w..(k + 1) * w].to_vec())
                        .collect()
                };
                s.offsets = take(&ts.offsets, 3);
                s.rotations = take(&ts.rotations, 4);
                s.link_angles = ts.link_angles.as_ref().map(|(a, w)| (take(a, *w), *w));
                s.node_offsets = ts.node_offsets.as_ref().map(|(a, w)| (take(a, *w), *w));
                s
            })
            .collect()
    }

    fn sample() -> TrainSetData {
        let mut store = DepthStore::new();
        store.push(3, 2, &[0, 1000, 1001, 1002, 0, 1003]).unwrap();
        store.push(2, 2, &[2000, 2001, 0, 2002]).unwrap();
        store.push(1, 1, &[1500]).unwrap();
        TrainSetData {
            store,
            parts: vec![[0, 1, 0], [0, 2, 1], [1, 0, 0], [1, 1, 1], [2, 0, 0]],
            offsets: (0..15).map(|k| k as f32 * 0.1).collect(),
            // Unit quaternions (w, x, y, z) that differ by part.
            rotations: (0..5)
                .flat_map(|k| {
                    let (w, x, z) = (1.0f32, k as f32, 0.5f32);
                    let n = (w * w + x * x + z * z).sqrt();
                    [w / n, x / n, 0.0, z / n]
                })
                .collect(),
            link_angles: Some(((0..10).map(|k| k as f32 * 0.3).collect(), 2)),
            node_offsets: Some(((0..15).map(|k| k as f32 - 7.0).collect(), 3)),
            metadata: "{}".into(),
        }
    }

    #[test]
    fn shards_read_back_as_the_whole_set() {
        let ts = sample();
        let dir = write_shards("round", &split(&ts, &[1, 2]));
        let set = ShardSet::open(&dir).unwrap();
        assert_eq!(set.parts, ts.parts);
        assert_eq!(set.offsets, ts.offsets);
        assert_eq!(set.rotations, ts.rotations);
        for i in 0..ts.store.len() {
            assert_eq!(set.store.image(i).data, ts.store.image(i).data);
        }
        // Row ranges across shard boundaries read the same values as the whole arrays.
        for (term, (a, w)) in [
            (Term::Links, ts.link_angles.clone().unwrap()),
            (Term::Nodes, ts.node_offsets.clone().unwrap()),
        ] {
            assert_eq!(set.width(term), Some(w));
            for r in [0..5, 1..4, 2..3, 3..5] {
                let mut out = vec![0f32; r.len() * w];
                set.read(term, r.clone(), &mut out).unwrap();
                assert_eq!(out, a[r.start * w..r.end * w], "{term:?} {r:?}");
            }
        }
        assert_eq!(set.manifest.n_parts(), 5);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn crops_are_trimmed_to_their_nonzero_pixels_with_the_same_features() {
        use crate::features::{eval_matrix, Feature};
        use crate::tree::draw_candidates;
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // Crops of an object in a margin of zeros (as annotation cuts them), with holes, one
        // touching the crop's edge, and an empty view (a 1x1 zero crop).
        let mut ts = TrainSetData {
            metadata: "{}".into(),
            ..Default::default()
        };
        for (w, h, c0, r0, ow, oh) in [
            (30, 20, 8, 5, 12, 9),
            (25, 25, 0, 8, 10, 17),
            (1, 1, 0, 0, 0, 0),
            (40, 12, 8, 3, 24, 9),
        ] {
            let mut px = vec![0u16; w * h];
            for r in r0..r0 + oh {
                for c in c0..c0 + ow {
                    if rng.random_range(0..5) > 0 {
                        px[r * w + c] = rng.random_range(800..3000);
                    }
                }
            }
            // The object's box reaches its corners, so it is the nonzero box.
            if ow > 0 {
                for (r, c) in [(r0, c0), (r0 + oh - 1, c0 + ow - 1)] {
                    px[r * w + c] = 1500;
                }
            }
            let i = ts.store.len() as i32;
            for (k, d) in px.iter().enumerate() {
                if *d > 0 && k % 3 == 0 {
                    ts.parts.push([i, (k % w) as i32, (k / w) as i32]);
                }
            }
            ts.store.push(w, h, &px).unwrap();
        }
        let n = ts.parts.len();
        ts.offsets = vec![0.1; 3 * n];
        ts.rotations = [1.0, 0.0, 0.0, 0.0].repeat(n);
        let dir = write_shards("trim", &split(&ts, &[2]));
        let set = ShardSet::open(&dir).unwrap();
        let dims: Vec<(usize, usize)> = (0..set.store.len()).map(|i| set.store.dims(i)).collect();
        assert_eq!(dims, [(12, 9), (10, 17), (1, 1), (24, 9)]);
        assert_eq!(set.parts.len(), n);
        for (a, b) in ts.parts.iter().zip(&set.parts) {
            assert_eq!(ts.store.center_depth(a), set.store.center_depth(b));
        }
        // Probes from 0 to far beyond the crops: the same value on every part.
        let mut feats: Vec<Feature> = Vec::new();
        for reach in [3.0, 20.0, 80.0] {
            feats.extend(draw_candidates(&mut rng, 40, reach * 1.5));
        }
        assert_eq!(
            eval_matrix(&set.store, &set.parts, &feats),
            eval_matrix(&ts.store, &ts.parts, &feats)
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn truncated_foreign_or_replaced_shards_are_refused_by_name() {
        let ts = sample();
        let parts = split(&ts, &[2]);
        let dir = write_shards("bad", &parts);
        let shard = dir.join("1.isat");
        let good = std::fs::read(&shard).unwrap();
        let cases: [(Vec<u8>, &str); 3] = [
            (good[..good.len() - 10].to_vec(), "truncated"),
            (
                {
                    let mut b = good.clone();
                    b[..8].copy_from_slice(b"NOTISATX");
                    b
                },
                "not an isa training-set file",
            ),
            (
                {
                    let mut b = good.clone();
                    b[good.len() - 20] ^= 1;
                    b
                },
                "checksum",
            ),
        ];
        for (bytes, expect) in cases {
            std::fs::write(&shard, &bytes).unwrap();
            expect_err(ShardSet::open(&dir), &["1.isat", expect]);
        }
        // A valid shard that is not the one the manifest lists.
        trainset_io::write(&parts[0], &shard).unwrap();
        expect_err(ShardSet::open(&dir), &["1.isat"]);
        std::fs::remove_file(&shard).unwrap();
        expect_err(ShardSet::open(&dir), &["1.isat"]);
        std::fs::write(dir.join(MANIFEST), "{\"format\": \"other\"}").unwrap();
        expect_err(ShardSet::open(&dir), &[MANIFEST]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
