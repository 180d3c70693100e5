//! Training-set files (`.isat`): everything [`Forest::fit`](crate::forest::Forest::fit) needs,
//! in one versioned, checksummed file that Python writes (`isa._core.TrainSet.write`) and the
//! `isa train` command reads.
//!
//! # Layout (format version 1, little-endian)
//! ```text
//! magic        8 bytes  b"ISATRAIN"
//! version      u32      FORMAT_VERSION (1)
//! n_entries    u32
//! n_entries times:
//!   name_len   u32, then the name (UTF-8, unique)
//!   kind       u8       0 = a NumPy .npy file (format 1.0-3.0), 1 = UTF-8 text
//!   length     u64, then that many bytes
//! checksum     u64      FNV-1a 64 of every byte before it
//! ```
//! Entries (DESIGN.md, "data handed to the Rust forest"):
//!
//! | name | kind | dtype, shape | meaning |
//! |---|---|---|---|
//! | `image_sizes` | npy | int32 `(n, 2)` | `[height, width]` of each depth crop |
//! | `depth` | npy | uint16 `(Σ h·w,)` | the crops, row-major, concatenated in order (mm, 0 = missing) |
//! | `parts` | npy | int32 `(P, 3)` | `[image index, u, v]`, depth > 0 there |
//! | `offsets` | npy | float32 `(P, 3)` | SSC − part's 3D point, camera frame, metres |
//! | `rotations` | npy | float32 `(P, 4)` | object rotation, unit quaternion `(w, x, y, z)` |
//! | `link_angles` | npy, optional | float32 `(P, L)` | skeleton link angles, radians (Q2) |
//! | `node_offsets` | npy, optional | float32 `(P, 3N)` | skeleton node offsets (du px, dv px, dz m) (Q3) |
//! | `metadata` | text, optional | JSON | opaque; copied into the model file (category, SSC, ...) |
//!
//! Other entry names are skipped unread by this version, whatever their kind or dtype (room for
//! additions). In Python without `isa._core`: `struct` for the framing and
//! `numpy.lib.format.read_array(io.BytesIO(b))` for each array. Reading checks the magic, the
//! version, the checksum, every length against the bytes left, that nothing follows the last
//! entry, dtypes, shapes, finiteness and values (`TrainSetData::validate`: rotations unit
//! within 1e-3, offsets within ±1e3 m, parts inside their image on depth > 0), so a bad file
//! gives an error naming the entry.
//!
//! Over 600 lines because its unit tests live beside the code they test (`mod tests` below).

use std::ops::Range;
use std::path::Path;

use crate::criterion::RawTargets;
use crate::depth::{DepthStore, Part};
use crate::error::{IsaError, Result};
use crate::forest::TrainingSet;
use crate::model_io::fnv1a64;

pub const MAGIC: &[u8; 8] = b"ISATRAIN";
pub const FORMAT_VERSION: u32 = 1;

/// The array entries this version reads (every other name is skipped, whatever its kind).
const ARRAY_ENTRIES: [&str; 7] = [
    "image_sizes",
    "depth",
    "parts",
    "offsets",
    "rotations",
    "link_angles",
    "node_offsets",
];

/// The contents of a training-set file, owned.
#[derive(Clone, Debug, Default)]
pub struct TrainSetData {
    pub store: DepthStore,
    pub parts: Vec<Part>,
    /// `(P, 3)` row-major.
    pub offsets: Vec<f32>,
    /// `(P, 4)` row-major.
    pub rotations: Vec<f32>,
    /// `(P, L)` row-major and `L`.
    pub link_angles: Option<(Vec<f32>, usize)>,
    /// `(P, 3N)` row-major and `3N`.
    pub node_offsets: Option<(Vec<f32>, usize)>,
    /// Opaque JSON (`"{}"` when absent).
    pub metadata: String,
}

impl TrainSetData {
    pub fn n_parts(&self) -> usize {
        self.parts.len()
    }

    /// The targets as the forest reads them.
    pub fn targets(&self) -> RawTargets<'_> {
        RawTargets {
            offsets: &self.offsets,
            rotations: &self.rotations,
            link_angles: self.link_angles.as_ref().map(|(a, w)| (a.as_slice(), *w)),
            node_offsets: self.node_offsets.as_ref().map(|(a, w)| (a.as_slice(), *w)),
        }
    }

    /// Borrowed view for [`Forest::fit`](crate::forest::Forest::fit).
    pub fn training_set(&self) -> TrainingSet<'_> {
        TrainingSet {
            store: &self.store,
            parts: &self.parts,
            targets: self.targets(),
        }
    }

    /// Shapes, finiteness and parts (inside their image, depth > 0); the error names the array.
    pub fn validate(&self) -> Result<()> {
        self.training_set().validate()?;
        check_metadata(&self.metadata)
    }
}

// ---------------------------------------------------------------------------------------------
// NPY (NumPy's own array file format), the subset used here: little-endian, C order.

/// Element types of the arrays in a training set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    U16,
    I32,
    F32,
}

impl Dtype {
    fn descr(self) -> &'static str {
        match self {
            Dtype::U16 => "<u2",
            Dtype::I32 => "<i4",
            Dtype::F32 => "<f4",
        }
    }
    fn size(self) -> usize {
        match self {
            Dtype::U16 => 2,
            Dtype::I32 | Dtype::F32 => 4,
        }
    }
    fn name(self) -> &'static str {
        match self {
            Dtype::U16 => "uint16",
            Dtype::I32 => "int32",
            Dtype::F32 => "float32",
        }
    }
}

/// A decoded array: shape and little-endian element bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

/// Elements that can go in and out of an NPY array.
pub trait NpyElement: Copy {
    const DTYPE: Dtype;
    fn to_le(self, out: &mut Vec<u8>);
    fn from_le(b: &[u8]) -> Self;
}

macro_rules! npy_element {
    ($t:ty, $d:expr) => {
        impl NpyElement for $t {
            const DTYPE: Dtype = $d;
            fn to_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn from_le(b: &[u8]) -> Self {
                <$t>::from_le_bytes(b.try_into().expect("element size"))
            }
        }
    };
}
npy_element!(u16, Dtype::U16);
npy_element!(i32, Dtype::I32);
npy_element!(f32, Dtype::F32);

/// Encodes `data` with `shape` as an NPY 1.0 file (header padded to 64 bytes, as NumPy does).
pub fn npy_encode<T: NpyElement>(data: &[T], shape: &[usize]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "npy_encode: shape does not match data"
    );
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_str = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}",
        T::DTYPE.descr(),
        shape_str
    )
    .into_bytes();
    let total = 10 + header.len() + 1;
    header.extend(std::iter::repeat_n(b' ', (64 - total % 64) % 64));
    header.push(b'\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * T::DTYPE.size());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(&header);
    for v in data {
        v.to_le(&mut out);
    }
    out
}

/// Decodes an NPY file (versions 1-3) of one of the [`Dtype`]s; errors say what is wrong.
pub fn npy_decode(bytes: &[u8]) -> std::result::Result<NpyArray, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a NumPy .npy array".into());
    }
    let (hlen, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
            12,
        ),
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let header = bytes
        .get(start..start + hlen)
        .ok_or("truncated .npy header")?;
    let header = std::str::from_utf8(header).map_err(|_| "non-UTF-8 .npy header")?;
    let field = |key: &str| -> std::result::Result<&str, String> {
        let at = header
            .find(&format!("'{key}'"))
            .ok_or(format!(".npy header lacks '{key}'"))?;
        let rest = &header[at + key.len() + 2..];
        let colon = rest
            .find(':')
            .ok_or(format!(".npy header: no value for '{key}'"))?;
        Ok(rest[colon + 1..].trim_start())
    };
    let descr = field("descr")?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|s| s.split('\'').next())
        .ok_or(".npy header: bad 'descr'")?;
    let dtype = match descr {
        "<u2" => Dtype::U16,
        "<i4" => Dtype::I32,
        "<f4" => Dtype::F32,
        other => {
            return Err(format!(
                "dtype {other:?} is not one of uint16, int32, float32 (little-endian)"
            ))
        }
    };
    if !field("fortran_order")?.starts_with("False") {
        return Err("Fortran-ordered arrays are not supported (write C order)".into());
    }
    let shape_s = field("shape")?;
    let shape_s = shape_s
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or(".npy header: bad 'shape'")?;
    let mut shape = Vec::new();
    for d in shape_s.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        shape.push(
            d.parse::<usize>()
                .map_err(|_| format!(".npy header: bad dimension {d:?}"))?,
        );
    }
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or(".npy shape overflows")?;
    let nbytes = count
        .checked_mul(dtype.size())
        .ok_or(".npy shape overflows")?;
    let data = &bytes[start + hlen..];
    if data.len() != nbytes {
        return Err(format!(
            "{} data bytes for shape {shape:?} of {} (expected {nbytes})",
            data.len(),
            dtype.name()
        ));
    }
    Ok(NpyArray {
        dtype,
        shape,
        data: data.to_vec(),
    })
}

impl NpyArray {
    /// The elements, checking the dtype.
    pub fn to_vec<T: NpyElement>(&self) -> std::result::Result<Vec<T>, String> {
        if self.dtype != T::DTYPE {
            return Err(format!(
                "expected {}, got {}",
                T::DTYPE.name(),
                self.dtype.name()
            ));
        }
        Ok(self
            .data
            .chunks_exact(T::DTYPE.size())
            .map(T::from_le)
            .collect())
    }
}

// ---------------------------------------------------------------------------------------------
// The container.

enum Entry {
    Npy(Vec<u8>),
    Text(String),
}

/// Encodes a training set (not validated here: call [`TrainSetData::validate`] first).
pub fn encode(ts: &TrainSetData) -> Vec<u8> {
    encode_set(&ts.training_set(), &ts.metadata)
}

/// Encodes a borrowed training set and its metadata JSON (not validated here).
pub fn encode_set(set: &TrainingSet<'_>, metadata: &str) -> Vec<u8> {
    let n_img = set.store.len();
    let mut sizes = Vec::with_capacity(2 * n_img);
    let mut depth = Vec::with_capacity(set.store.n_pixels());
    for i in 0..n_img {
        let (w, h) = set.store.dims(i);
        sizes.extend([h as i32, w as i32]);
        depth.extend_from_slice(set.store.image(i).data);
    }
    let p = set.parts.len();
    let flat_parts: Vec<i32> = set.parts.iter().flatten().copied().collect();
    let mut entries: Vec<(&str, Entry)> = vec![
        ("image_sizes", Entry::Npy(npy_encode(&sizes, &[n_img, 2]))),
        ("depth", Entry::Npy(npy_encode(&depth, &[depth.len()]))),
        ("parts", Entry::Npy(npy_encode(&flat_parts, &[p, 3]))),
        (
            "offsets",
            Entry::Npy(npy_encode(set.targets.offsets, &[p, 3])),
        ),
        (
            "rotations",
            Entry::Npy(npy_encode(set.targets.rotations, &[p, 4])),
        ),
    ];
    if let Some((a, w)) = set.targets.link_angles {
        entries.push(("link_angles", Entry::Npy(npy_encode(a, &[p, w]))));
    }
    if let Some((a, w)) = set.targets.node_offsets {
        entries.push(("node_offsets", Entry::Npy(npy_encode(a, &[p, w]))));
    }
    entries.push(("metadata", Entry::Text(metadata.to_string())));
    let framed: Vec<(&str, u8, &[u8])> = entries
        .iter()
        .map(|(name, e)| match e {
            Entry::Npy(b) => (*name, 0, b.as_slice()),
            Entry::Text(s) => (*name, 1, s.as_bytes()),
        })
        .collect();
    container(&framed)
}

/// The file framing (magic, version, entries `(name, kind, bytes)`, checksum).
fn container(entries: &[(&str, u8, &[u8])]) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(entries.len() as u32).to_le_bytes());
    for (name, kind, bytes) in entries {
        out.extend_from_slice(&(name.len() as u32).to_le_bytes());
        out.extend_from_slice(name.as_bytes());
        out.push(*kind);
        out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
        out.extend_from_slice(bytes);
    }
    let sum = fnv1a64(&out);
    out.extend_from_slice(&sum.to_le_bytes());
    out
}

/// Decodes and validates a training set; `path` only labels errors.
pub fn decode(bytes: &[u8], path: &str) -> Result<TrainSetData> {
    decode_located(bytes, path).map(|(ts, _)| ts)
}

/// Where each array's elements lie in a file's bytes: (entry name, byte range).
pub type Located = Vec<(String, Range<usize>)>;

/// [`decode`], also saying where each array's elements lie in `bytes` (name, byte range), so
/// a reader can come back for rows of one array later ([`crate::shards`]).
pub fn decode_located(bytes: &[u8], path: &str) -> Result<(TrainSetData, Located)> {
    let bad = |reason: String| IsaError::InvalidInput(format!("training set {path}: {reason}"));
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(bad(
            "not an isa training-set file (bad magic; write it with isa._core.TrainSet.write)"
                .into(),
        ));
    }
    if bytes.len() < 24 {
        return Err(bad(format!("truncated ({} bytes)", bytes.len())));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
    if version != FORMAT_VERSION {
        return Err(bad(format!(
            "format version {version}, this isa reads version {FORMAT_VERSION}"
        )));
    }
    let (body, tail) = bytes.split_at(bytes.len() - 8);
    if fnv1a64(body) != u64::from_le_bytes(tail.try_into().unwrap()) {
        return Err(bad(
            "checksum mismatch (the file is truncated or corrupted)".into(),
        ));
    }
    let n_entries = u32::from_le_bytes(body[12..16].try_into().unwrap()) as usize;
    let mut at = 16usize;
    let mut take = |n: usize, what: &str| -> Result<&[u8]> {
        let end = at
            .checked_add(n)
            .filter(|&e| e <= body.len())
            .ok_or_else(|| bad(format!("truncated in {what}")))?;
        let s = &body[at..end];
        at = end;
        Ok(s)
    };
    let mut arrays: Vec<(String, NpyArray)> = Vec::new();
    let mut located = Vec::new();
    let mut metadata = None;
    for k in 0..n_entries {
        let nl = u32::from_le_bytes(take(4, "an entry name")?.try_into().unwrap()) as usize;
        let name = std::str::from_utf8(take(nl, "an entry name")?)
            .map_err(|_| bad(format!("entry {k}: name is not UTF-8")))?
            .to_string();
        let kind = take(1, &name)?[0];
        let len = u64::from_le_bytes(take(8, &name)?.try_into().unwrap());
        let len = usize::try_from(len).map_err(|_| bad(format!("entry {name}: too long")))?;
        let data = take(len, &name)?;
        let known_array = ARRAY_ENTRIES.contains(&name.as_str());
        if (known_array && arrays.iter().any(|(n, _)| *n == name))
            || (name == "metadata" && metadata.is_some())
        {
            return Err(bad(format!("entry {name} appears twice")));
        }
        match (kind, name.as_str()) {
            (1, "metadata") => {
                metadata = Some(
                    String::from_utf8(data.to_vec())
                        .map_err(|_| bad("entry metadata: not UTF-8".into()))?,
                )
            }
            (0, _) if known_array => {
                let a = npy_decode(data).map_err(|e| bad(format!("entry {name}: {e}")))?;
                // The elements are the entry's last bytes.
                let end = data.as_ptr() as usize - bytes.as_ptr() as usize + data.len();
                located.push((name.clone(), end - a.data.len()..end));
                arrays.push((name.clone(), a));
            }
            (k, "metadata") => {
                return Err(bad(format!("entry metadata: kind {k}, expected 1 (text)")))
            }
            (k, _) if known_array => {
                return Err(bad(format!("entry {name}: kind {k}, expected 0 (.npy)")))
            }
            // Room for additions: an entry this version does not know is skipped unread.
            _ => {}
        }
    }
    if at != body.len() {
        return Err(bad(format!(
            "{} unexpected bytes after the last of {n_entries} entries",
            body.len() - at
        )));
    }
    let get = |name: &str| arrays.iter().find(|(n, _)| n == name).map(|(_, a)| a);
    let need = |name: &str| get(name).ok_or_else(|| bad(format!("missing entry {name}")));
    let vec_of = |name: &str, a: &NpyArray, cols: Option<usize>| -> Result<()> {
        let ok = match cols {
            Some(c) => a.shape.len() == 2 && a.shape[1] == c,
            None => a.shape.len() == 2,
        };
        if !ok {
            let want = cols.map_or("(n, k)".to_string(), |c| format!("(n, {c})"));
            return Err(bad(format!(
                "entry {name}: expected shape {want}, got {:?}",
                a.shape
            )));
        }
        Ok(())
    };

    let sizes_a = need("image_sizes")?;
    vec_of("image_sizes", sizes_a, Some(2))?;
    let sizes: Vec<i32> = sizes_a
        .to_vec()
        .map_err(|e| bad(format!("entry image_sizes: {e}")))?;
    let depth_a = need("depth")?;
    if depth_a.shape.len() != 1 {
        return Err(bad(format!(
            "entry depth: expected a flat array, got shape {:?}",
            depth_a.shape
        )));
    }
    let depth: Vec<u16> = depth_a
        .to_vec()
        .map_err(|e| bad(format!("entry depth: {e}")))?;
    let mut store = DepthStore::new();
    let mut off = 0usize;
    for (i, hw) in sizes.chunks_exact(2).enumerate() {
        let (h, w) = (hw[0], hw[1]);
        if h <= 0 || w <= 0 {
            return Err(bad(format!(
                "entry image_sizes: image {i} has size {h}x{w}"
            )));
        }
        let n = h as usize * w as usize;
        let px = depth.get(off..off + n).ok_or_else(|| {
            bad(format!(
                "entry depth: {} pixels, but image_sizes needs more (image {i} is {h}x{w})",
                depth.len()
            ))
        })?;
        store
            .push(w as usize, h as usize, px)
            .map_err(|e| bad(e.to_string()))?;
        off += n;
    }
    if off != depth.len() {
        return Err(bad(format!(
            "entry depth: {} pixels, image_sizes account for {off}",
            depth.len()
        )));
    }
    let parts_a = need("parts")?;
    vec_of("parts", parts_a, Some(3))?;
    let flat: Vec<i32> = parts_a
        .to_vec()
        .map_err(|e| bad(format!("entry parts: {e}")))?;
    let parts: Vec<Part> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let p = parts.len();
    let f32_entry = |name: &str, cols: Option<usize>| -> Result<Option<(Vec<f32>, usize)>> {
        let Some(a) = get(name) else { return Ok(None) };
        vec_of(name, a, cols)?;
        if a.shape[0] != p {
            return Err(bad(format!(
                "entry {name}: {} rows for {p} parts",
                a.shape[0]
            )));
        }
        Ok(Some((
            a.to_vec().map_err(|e| bad(format!("entry {name}: {e}")))?,
            a.shape[1],
        )))
    };
    let offsets = f32_entry("offsets", Some(3))?
        .ok_or_else(|| bad("missing entry offsets".into()))?
        .0;
    let rotations = f32_entry("rotations", Some(4))?
        .ok_or_else(|| bad("missing entry rotations".into()))?
        .0;
    let ts = TrainSetData {
        store,
        parts,
        offsets,
        rotations,
        link_angles: f32_entry("link_angles", None)?,
        node_offsets: f32_entry("node_offsets", None)?,
        metadata: metadata.unwrap_or_else(|| "{}".into()),
    };
    ts.validate().map_err(|e| bad(e.to_string()))?;
    Ok((ts, located))
}

/// Validates and writes a training set atomically ([`crate::atomic`]).
pub fn write(ts: &TrainSetData, path: &Path) -> Result<()> {
    write_set(&ts.training_set(), &ts.metadata, path)
}

/// [`write`] from borrowed arrays (what the Python binding holds), without copying them.
pub fn write_set(set: &TrainingSet<'_>, metadata: &str, path: &Path) -> Result<()> {
    set.validate()?;
    check_metadata(metadata)?;
    crate::atomic::write_bytes(path, &encode_set(set, metadata))
}

fn check_metadata(metadata: &str) -> Result<()> {
    match serde_json::from_str::<serde_json::Value>(metadata) {
        Ok(_) => Ok(()),
        Err(_) => Err(IsaError::InvalidInput("metadata: not valid JSON".into())),
    }
}

/// Reads and validates a training set.
pub fn read(path: &Path) -> Result<TrainSetData> {
    crate::atomic::clean_stale(path);
    let bytes = std::fs::read(path).map_err(|source| IsaError::Io {
        path: path.display().to_string(),
        source,
    })?;
    decode(&bytes, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;

    fn sample() -> TrainSetData {
        let mut store = DepthStore::new();
        store.push(3, 2, &[0, 1000, 1001, 1002, 0, 1003]).unwrap();
        store.push(2, 2, &[2000, 2001, 0, 2002]).unwrap();
        TrainSetData {
            store,
            parts: vec![[0, 1, 0], [0, 2, 1], [1, 0, 0]],
            offsets: vec![0.1, 0.2, 0.3, -0.1, 0.0, 0.5, 1.0, 2.0, 3.0],
            rotations: vec![1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.5],
            link_angles: Some((vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 2)),
            node_offsets: None,
            metadata: r#"{"category": "chair"}"#.into(),
        }
    }

    fn same(a: &TrainSetData, b: &TrainSetData) {
        assert_eq!(a.store.len(), b.store.len());
        for i in 0..a.store.len() {
            assert_eq!(a.store.dims(i), b.store.dims(i));
            assert_eq!(a.store.image(i).data, b.store.image(i).data);
        }
        assert_eq!(a.parts, b.parts);
        assert_eq!(a.offsets, b.offsets);
        assert_eq!(a.rotations, b.rotations);
        assert_eq!(a.link_angles, b.link_angles);
        assert_eq!(a.node_offsets, b.node_offsets);
        assert_eq!(a.metadata, b.metadata);
    }

    #[test]
    fn round_trip_bytes_and_file() {
        let ts = sample();
        same(&decode(&encode(&ts), "x").unwrap(), &ts);
        let dir = std::env::temp_dir().join(format!("isa-trainset-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.isat");
        write(&ts, &path).unwrap();
        same(&read(&path).unwrap(), &ts);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn npy_matches_numpy_layout() {
        let b = npy_encode(&[1.5f32, -2.0, 3.0, 4.0, 5.0, 6.0], &[2, 3]);
        assert_eq!(&b[..8], b"\x93NUMPY\x01\x00");
        assert_eq!((b.len() - 6 * 4) % 64, 0);
        let hdr = std::str::from_utf8(&b[10..b.len() - 24]).unwrap();
        assert_eq!(
            hdr.trim_end(),
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"
        );
        let a = npy_decode(&b).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(
            a.to_vec::<f32>().unwrap(),
            vec![1.5, -2.0, 3.0, 4.0, 5.0, 6.0]
        );
        assert!(a.to_vec::<i32>().is_err());
        let one = npy_decode(&npy_encode(&[7u16], &[1])).unwrap();
        assert_eq!(one.shape, vec![1]);
        // A header as NumPy 2 writes it (shape of a 1-D array, version 1.0).
        let mut h = b"{'descr': '<i4', 'fortran_order': False, 'shape': (2,), }".to_vec();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(b' ');
        }
        h.push(b'\n');
        let mut f = b"\x93NUMPY\x01\x00".to_vec();
        f.extend_from_slice(&(h.len() as u16).to_le_bytes());
        f.extend_from_slice(&h);
        f.extend_from_slice(&[1, 0, 0, 0, 2, 0, 0, 0]);
        assert_eq!(npy_decode(&f).unwrap().to_vec::<i32>().unwrap(), vec![1, 2]);
        assert!(npy_decode(&f[..f.len() - 1])
            .unwrap_err()
            .contains("data bytes"));
        let fortran = String::from_utf8_lossy(&f).replace("False", "True ");
        assert!(npy_decode(fortran.as_bytes()).is_err());
    }

    /// The entries of `encode(ts)` with `extra` appended, re-framed (valid checksum).
    fn with_entries(ts: &TrainSetData, extra: &[(&str, u8, &[u8])]) -> Vec<u8> {
        let b = encode(ts);
        let n = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
        let mut at = 16;
        let mut entries: Vec<(String, u8, Vec<u8>)> = Vec::new();
        for _ in 0..n {
            let nl = u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
            let name = String::from_utf8(b[at + 4..at + 4 + nl].to_vec()).unwrap();
            let kind = b[at + 4 + nl];
            let len = u64::from_le_bytes(b[at + 5 + nl..at + 13 + nl].try_into().unwrap()) as usize;
            entries.push((name, kind, b[at + 13 + nl..at + 13 + nl + len].to_vec()));
            at += 13 + nl + len;
        }
        let mut all: Vec<(&str, u8, &[u8])> = entries
            .iter()
            .map(|(n, k, d)| (n.as_str(), *k, d.as_slice()))
            .collect();
        all.extend_from_slice(extra);
        container(&all)
    }

    /// Issue 20: an unknown entry of another dtype was refused although the docs say unknown
    /// entries are ignored; bytes after the last entry were accepted.
    #[test]
    fn unknown_entries_are_skipped_trailing_bytes_refused() {
        let ts = sample();
        let f64_npy = {
            let mut b = npy_encode(&[1.0f32, 2.0], &[2]);
            let h = String::from_utf8_lossy(&b).replace("<f4", "<f8");
            b = h.into_bytes();
            b.extend_from_slice(&[0; 8]);
            b
        };
        let odd = with_entries(
            &ts,
            &[
                ("future_f64", 0, &f64_npy),
                ("future_kind", 7, b"??"),
                ("notes", 1, b"hi"),
            ],
        );
        same(&decode(&odd, "x").unwrap(), &ts);
        // A known name of the wrong kind is still an error naming it.
        expect_err(
            decode(&with_entries(&ts, &[("metadata", 0, b"x")]), "x"),
            &["metadata"],
        );
        // Bytes after the last entry (checksum fixed up): refused.
        let mut b = encode(&ts);
        b.truncate(b.len() - 8);
        b.extend_from_slice(b"trailing");
        let sum = fnv1a64(&b);
        b.extend_from_slice(&sum.to_le_bytes());
        expect_err(decode(&b, "t.isat"), &["t.isat", "8 unexpected bytes"]);
    }

    /// Issue 20: rotations of norm 5 or 1e30 were accepted (the docs say unit quaternions).
    #[test]
    fn rotations_must_be_unit_and_offsets_bounded() {
        for (q, ok) in [
            ([5.0, 0.0, 0.0, 0.0], false),
            ([1e30, 0.0, 0.0, 0.0], false),
            ([0.0; 4], false),
            ([0.0, 0.9995, 0.0, 0.0], true),
            ([0.5, 0.5, 0.5, -0.5], true),
        ] {
            let mut ts = sample();
            ts.rotations[4..8].copy_from_slice(&q);
            let r = decode(&encode(&ts), "r.isat");
            assert_eq!(r.is_ok(), ok, "{q:?}: {r:?}");
            if let Err(e) = r {
                assert!(e.to_string().contains("rotations[1]"), "{e}");
            }
        }
        let mut ts = sample();
        ts.offsets[4] = 2e3;
        expect_err(decode(&encode(&ts), "o.isat"), &["offsets[1, 1]"]);
    }

    #[test]
    fn corrupt_files_are_named_errors_never_panics() {
        let bytes = encode(&sample());
        for (b, expect) in [
            (b"hello world, not a trainset".to_vec(), "bad magic"),
            (bytes[..bytes.len() - 3].to_vec(), "checksum"),
            (
                {
                    let mut b = bytes.clone();
                    b[40] ^= 0xff;
                    b
                },
                "checksum",
            ),
            (
                {
                    let mut b = bytes.clone();
                    b[8] = 9;
                    b
                },
                "version 9",
            ),
        ] {
            expect_err(decode(&b, "f.isat"), &["f.isat", expect]);
        }
        // Every truncation and single-byte change with a re-computed checksum: error or ok, no panic.
        for cut in (0..bytes.len()).step_by(7) {
            let _ = decode(&bytes[..cut], "f");
            let mut b = bytes.clone();
            b[cut] = b[cut].wrapping_add(1);
            let n = b.len() - 8;
            let sum = fnv1a64(&b[..n]);
            b[n..].copy_from_slice(&sum.to_le_bytes());
            let _ = decode(&b, "f");
        }
        // Parts on missing depth are caught by validation, with the array named.
        let mut ts = sample();
        ts.parts[0] = [0, 0, 0];
        expect_err(write(&ts, Path::new("/nonexistent/x.isat")), &["parts[0]"]);
        expect_err(decode(&encode(&ts), "f"), &["parts[0]"]);
    }
}
