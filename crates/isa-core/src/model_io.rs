//! Versioned binary model files.
//!
//! Layout (little-endian):
//! ```text
//! header (32 bytes)
//!   magic            8 bytes  b"ISAFRST\0"
//!   format version   u32      FORMAT_VERSION
//!   reserved         u32      0
//!   payload length   u64
//!   checksum         u64      FNV-1a 64 of the payload
//! payload
//!   crate version    str      (u32 length + UTF-8)
//!   params           str      ForestParams as JSON (the training configuration)
//!   metadata         str      ModelMetadata as JSON (category, origin, box, training summary,
//!                             extra keys)
//!   predict defaults str      PredictParams as JSON (the inference defaults; version >= 2)
//!   n_trees          u32
//!   per tree
//!     n_nodes u32, then per node: is_leaf u8, child u32, threshold f32, u f32×2, v f32×2
//!     n_leaves u32, then leaf_offsets u32×(n_leaves+1)
//!     n_votes u32, then per vote: weight f32, offset f32×3, rotation f32×4
//!   leaf weights     (version 3 only) per tree: n_leaves u32, then weight f32×n_leaves
//! ```
//! Decoding checks the magic (foreign file), the version (newer file), the length (truncated),
//! the checksum (corrupted), then every count against the bytes left before allocating and the
//! tree structure and values ([`Tree::validate`]: children after their parent and in range,
//! leaf ids in range, vote ranges monotone; finite thresholds, feature offsets within
//! ±[`MAX_FEATURE_OFFSET`](crate::features::MAX_FEATURE_OFFSET) pixel·metres, vote weights in
//! [0, 1], vote offsets within ±[`MAX_TARGET_OFFSET`](crate::criterion::MAX_TARGET_OFFSET) m,
//! unit vote rotations within
//! [`UNIT_NORM_TOLERANCE`](crate::rotation::UNIT_NORM_TOLERANCE)), so any byte string gives a
//! forest that predicts finite poses or [`IsaError::ModelFormat`], never a panic. Saving is atomic ([`crate::atomic`]).
//!
//! Versions: 1 had no inference-defaults field and free-form metadata JSON, in which Python's
//! pipeline kept them as `predict_defaults` (flat keys); such files still load, their
//! `predict_defaults` read into the typed field ([`split_metadata`], unknown keys skipped) and
//! metadata that is not a JSON object kept as the string `extra["legacy_metadata"]`. Version 2
//! added the field; the trees and votes are encoded as in version 1. Version 3 adds the per-leaf
//! vote weights ([`LeafWeights`]) after the trees; a forest without them is written as version 2,
//! so one-class models keep their bytes and older readers keep reading them.
//!
//! Over 600 lines because its unit tests live beside the code they test (`mod tests` below).

use std::fs;
use std::path::Path;

use crate::error::{IsaError, Result};
use crate::features::Feature;
use crate::forest::{Forest, LeafWeights};
use crate::metadata::{split_metadata, ModelMetadata};
use crate::params::{ForestParams, PredictParams};
use crate::tree::{Node, Tree, Vote};

pub const MAGIC: &[u8; 8] = b"ISAFRST\0";
pub const FORMAT_VERSION: u32 = 3;
/// The version a forest without leaf weights is written in.
const ONE_CLASS_VERSION: u32 = 2;
const HEADER: usize = 32;
const NODE_BYTES: usize = 1 + 4 + 4 + 16;
const VOTE_BYTES: usize = 32;

/// FNV-1a 64-bit hash.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

fn put_f32s(out: &mut Vec<u8>, v: &[f32]) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// Serialises a forest to bytes (header + payload).
pub fn encode(forest: &Forest) -> Vec<u8> {
    let mut p = Vec::new();
    put_str(&mut p, crate::VERSION);
    put_str(&mut p, &forest.params.to_json());
    put_str(&mut p, &forest.metadata.to_json());
    put_str(
        &mut p,
        &serde_json::to_string(&*forest.predict_defaults).expect("parameters serialise"),
    );
    encode_trees(&mut p, forest);
    match &forest.leaf_weights {
        None => seal(ONE_CLASS_VERSION, &p),
        Some(w) => {
            for tw in w.per_tree() {
                p.extend_from_slice(&(tw.len() as u32).to_le_bytes());
                put_f32s(&mut p, tw);
            }
            seal(FORMAT_VERSION, &p)
        }
    }
}

/// The trees and their votes (the same bytes in every format version).
pub(crate) fn encode_trees(p: &mut Vec<u8>, forest: &Forest) {
    p.extend_from_slice(&(forest.trees.len() as u32).to_le_bytes());
    for t in &forest.trees {
        put_tree(p, t);
    }
}

fn put_tree(p: &mut Vec<u8>, t: &Tree) {
    p.extend_from_slice(&(t.nodes.len() as u32).to_le_bytes());
    for n in &t.nodes {
        p.push(n.is_leaf as u8);
        p.extend_from_slice(&n.child.to_le_bytes());
        put_f32s(
            p,
            &[
                n.threshold,
                n.feature.u[0],
                n.feature.u[1],
                n.feature.v[0],
                n.feature.v[1],
            ],
        );
    }
    p.extend_from_slice(&(t.n_leaves() as u32).to_le_bytes());
    for o in &t.leaf_offsets {
        p.extend_from_slice(&o.to_le_bytes());
    }
    p.extend_from_slice(&(t.votes.len() as u32).to_le_bytes());
    for v in &t.votes {
        put_f32s(p, &[v.weight]);
        put_f32s(p, &v.offset);
        put_f32s(p, &v.rotation);
    }
}

/// Header (magic, `version`, length, checksum) + payload.
pub(crate) fn seal(version: u32, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&version.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a64(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

type R<T> = std::result::Result<T, String>;

impl<'a> Reader<'a> {
    fn left(&self) -> usize {
        self.b.len() - self.pos
    }
    fn take(&mut self, n: usize) -> R<&'a [u8]> {
        if n > self.left() {
            return Err(format!(
                "truncated: needs {n} more bytes at offset {}, {} left",
                self.pos,
                self.left()
            ));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u8(&mut self) -> R<u8> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> R<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn f32(&mut self) -> R<f32> {
        let v = f32::from_le_bytes(self.take(4)?.try_into().unwrap());
        if !v.is_finite() {
            return Err(format!("non-finite number at offset {}", self.pos - 4));
        }
        Ok(v)
    }
    fn str(&mut self, what: &str) -> R<String> {
        let n = self.u32()? as usize;
        let s = self.take(n).map_err(|e| format!("{what}: {e}"))?;
        String::from_utf8(s.to_vec()).map_err(|_| format!("{what} is not UTF-8"))
    }
    /// Reads a count of items of `size` bytes each, checking they fit in what is left.
    fn count(&mut self, size: usize, what: &str) -> R<usize> {
        let n = self.u32()? as usize;
        if n.saturating_mul(size) > self.left() {
            return Err(format!(
                "truncated: {n} {what} do not fit in the {} bytes left",
                self.left()
            ));
        }
        Ok(n)
    }
}

/// Metadata and inference defaults of a version-1 file (free-form metadata JSON).
fn legacy_metadata(raw: String) -> R<(ModelMetadata, crate::params::Valid<PredictParams>)> {
    // Python's json module wrote NaN and infinities as bare tokens, which JSON has not: null.
    match split_metadata(&python_floats_to_null(&raw), "metadata", true) {
        Ok(v) => Ok(v),
        // Bad inference defaults are an error; metadata that is not an object is kept as text.
        Err(e)
            if e.to_string()
                .contains(crate::metadata::PREDICT_DEFAULTS_KEY) =>
        {
            Err(e.to_string())
        }
        Err(_) => {
            let mut m = ModelMetadata::default();
            m.extra.insert("legacy_metadata".into(), raw.into());
            Ok((m, Default::default()))
        }
    }
}

/// One tree (after the trees count), checked for structure; `ti` names it in errors.
fn read_tree(r: &mut Reader<'_>, ti: usize) -> R<Tree> {
    let n_nodes = r.count(NODE_BYTES, "nodes")?;
    if n_nodes == 0 {
        return Err(format!("tree {ti} has no nodes"));
    }
    let mut nodes = Vec::with_capacity(n_nodes);
    for _ in 0..n_nodes {
        let is_leaf = match r.u8()? {
            0 => false,
            1 => true,
            x => return Err(format!("tree {ti}: bad node kind {x}")),
        };
        let child = r.u32()?;
        let threshold = r.f32()?;
        let u = [r.f32()?, r.f32()?];
        let v = [r.f32()?, r.f32()?];
        nodes.push(Node {
            feature: Feature { u, v },
            threshold,
            child,
            is_leaf,
        });
    }
    let n_leaves = r.count(4, "leaves")?;
    let mut leaf_offsets = Vec::with_capacity(n_leaves + 1);
    for _ in 0..=n_leaves {
        leaf_offsets.push(r.u32()?);
    }
    let n_votes = r.count(VOTE_BYTES, "votes")?;
    let mut votes = Vec::with_capacity(n_votes);
    for _ in 0..n_votes {
        let weight = r.f32()?;
        let offset = [r.f32()?, r.f32()?, r.f32()?];
        let rotation = [r.f32()?, r.f32()?, r.f32()?, r.f32()?];
        votes.push(Vote {
            weight,
            offset,
            rotation,
        });
    }
    let tree = Tree {
        nodes,
        leaf_offsets,
        votes,
    };
    // Structure and values, so that what loads predicts finite poses.
    tree.validate().map_err(|e| format!("tree {ti}: {e}"))?;
    Ok(tree)
}

/// Magic of a lone tree's bytes ([`encode_tree`]).
const TREE_MAGIC: &[u8; 8] = b"ISATREE1";

/// One tree's bytes (the model file's tree encoding, magic and checksum): how a tree fitted
/// on another machine ([`Forest::fit_tree`](crate::Forest::fit_tree)) travels to the assembly.
pub fn encode_tree(tree: &Tree) -> Vec<u8> {
    let mut p = TREE_MAGIC.to_vec();
    put_tree(&mut p, tree);
    let sum = fnv1a64(&p);
    p.extend_from_slice(&sum.to_le_bytes());
    p
}

/// Decodes [`encode_tree`]'s bytes; `what` names them in errors.
pub fn decode_tree(bytes: &[u8], what: &str) -> Result<Tree> {
    let err = |reason: String| IsaError::InvalidInput(format!("{what}: {reason}"));
    if bytes.len() < 16 || &bytes[..8] != TREE_MAGIC {
        return Err(err(
            "not an isa tree (wrong magic bytes or truncated)".into()
        ));
    }
    let (body, tail) = bytes.split_at(bytes.len() - 8);
    if fnv1a64(body) != u64::from_le_bytes(tail.try_into().expect("8 bytes")) {
        return Err(err("checksum mismatch (truncated or corrupted)".into()));
    }
    let mut r = Reader {
        b: &body[8..],
        pos: 0,
    };
    let tree = read_tree(&mut r, 0).map_err(err)?;
    if r.left() != 0 {
        return Err(err(format!("{} unexpected bytes after the tree", r.left())));
    }
    Ok(tree)
}

/// `NaN`, `Infinity` and `-Infinity` outside JSON strings replaced by `null`.
fn python_floats_to_null(raw: &str) -> String {
    let mut out = String::with_capacity(raw.len());
    let (mut in_str, mut escaped) = (false, false);
    let mut rest = raw;
    while let Some(c) = rest.chars().next() {
        if in_str {
            in_str = escaped || c != '"';
            escaped = !escaped && c == '\\';
        } else if c == '"' {
            in_str = true;
        } else if let Some(tok) = ["-Infinity", "Infinity", "NaN"]
            .iter()
            .find(|t| rest.starts_with(**t))
        {
            out.push_str("null");
            rest = &rest[tok.len()..];
            continue;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

/// Parses a payload of format `version` (after header checks). Exposed for fuzzing.
pub fn decode_payload(payload: &[u8], version: u32) -> R<Forest> {
    let mut r = Reader { b: payload, pos: 0 };
    let crate_version = r.str("crate version")?;
    let params_json = r.str("parameters")?;
    let params = ForestParams::from_json(&params_json)
        .map_err(|e| format!("training configuration: {e}"))?
        .into_inner();
    let meta_json = r.str("metadata")?;
    let (metadata, predict_defaults) = if version < 2 {
        legacy_metadata(meta_json)?
    } else {
        let m = ModelMetadata::from_json(&meta_json, "metadata").map_err(|e| e.to_string())?;
        let d = r.str("inference defaults")?;
        let d: PredictParams =
            serde_json::from_str(&d).map_err(|e| format!("inference defaults: {e}"))?;
        let d = d.check().map_err(|e| format!("inference defaults: {e}"))?;
        (m, d)
    };
    let n_trees = r.count(12, "trees")?;
    let mut trees = Vec::with_capacity(n_trees);
    for ti in 0..n_trees {
        trees.push(read_tree(&mut r, ti)?);
    }
    let leaf_weights = if version >= 3 {
        let mut per_tree = Vec::with_capacity(n_trees);
        for ti in 0..n_trees {
            let what = |e: String| format!("leaf weights of tree {ti}: {e}");
            let n = r.count(4, "weights").map_err(what)?;
            per_tree.push(
                (0..n)
                    .map(|_| r.f32())
                    .collect::<R<Vec<f32>>>()
                    .map_err(what)?,
            );
        }
        Some(LeafWeights::checked(per_tree, &trees)?)
    } else {
        None
    };
    if r.left() != 0 {
        return Err(format!("{} unexpected bytes after the last tree", r.left()));
    }
    if trees.len() != params.n_trees {
        return Err(format!(
            "{} trees but the configuration says {}",
            trees.len(),
            params.n_trees
        ));
    }
    Ok(Forest {
        params,
        trees,
        metadata,
        predict_defaults,
        crate_version,
        leaf_weights,
        flat: Default::default(),
    })
}

/// Parses a whole file's bytes; `path` only names the file in errors.
pub fn decode(bytes: &[u8], path: &str) -> Result<Forest> {
    let err = |reason: String| IsaError::ModelFormat {
        path: path.to_string(),
        reason,
    };
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        if bytes.len() < 8 && MAGIC.starts_with(bytes) {
            return Err(err(format!(
                "truncated: {} bytes, not even a header",
                bytes.len()
            )));
        }
        return Err(err("not an isa forest model (wrong magic bytes)".into()));
    }
    if bytes.len() < HEADER {
        return Err(err(format!(
            "truncated: {} bytes, the header needs {HEADER}",
            bytes.len()
        )));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
    if version > FORMAT_VERSION {
        return Err(err(format!(
            "written in model format version {version} by a newer isa; this isa {} reads up to version {FORMAT_VERSION}",
            crate::VERSION
        )));
    }
    if version == 0 {
        return Err(err("corrupted: format version 0".into()));
    }
    let len = u64::from_le_bytes(bytes[16..24].try_into().unwrap());
    let have = (bytes.len() - HEADER) as u64;
    if len > have {
        return Err(err(format!(
            "truncated: payload of {len} bytes, only {have} present"
        )));
    }
    if len < have {
        return Err(err(format!(
            "corrupted: {} trailing bytes after the payload",
            have - len
        )));
    }
    let sum = u64::from_le_bytes(bytes[24..32].try_into().unwrap());
    let payload = &bytes[HEADER..];
    if fnv1a64(payload) != sum {
        return Err(err("corrupted: checksum mismatch".into()));
    }
    decode_payload(payload, version).map_err(|r| err(format!("corrupted: {r}")))
}

/// The format version of a model file's bytes (its header), if they start like one.
pub fn file_version(bytes: &[u8]) -> Option<u32> {
    (bytes.len() >= 12 && &bytes[..8] == MAGIC)
        .then(|| u32::from_le_bytes(bytes[8..12].try_into().unwrap()))
}

/// Writes a forest atomically ([`crate::atomic`]).
pub fn save(forest: &Forest, path: &Path) -> Result<()> {
    crate::atomic::write_bytes(path, &encode(forest))
}

/// Reads a forest file.
pub fn load(path: &Path) -> Result<Forest> {
    crate::atomic::clean_stale(path);
    let bytes = fs::read(path).map_err(|e| IsaError::Io {
        path: path.display().to_string(),
        source: e,
    })?;
    decode(&bytes, &path.display().to_string())
}

impl Forest {
    /// Model-file bytes of this forest.
    pub fn to_bytes(&self) -> Vec<u8> {
        encode(self)
    }
    /// Parses model-file bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Forest> {
        decode(bytes, "<bytes>")
    }
    /// Saves atomically.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        save(self, path.as_ref())
    }
    /// Loads a model file.
    pub fn load(path: impl AsRef<Path>) -> Result<Forest> {
        load(path.as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::criterion::RawTargets;
    use crate::error::expect_err;
    use crate::forest::tests::{toy, toy_params};
    use crate::forest::TrainingSet;
    use proptest::prelude::*;

    /// A version-1 file of `f`'s trees with metadata JSON `raw` (version 1 had no typed defaults).
    fn version_1_file(f: &Forest, raw: &str) -> Vec<u8> {
        let mut p = Vec::new();
        put_str(&mut p, "0.0.1");
        put_str(&mut p, &f.params.to_json());
        put_str(&mut p, raw);
        encode_trees(&mut p, f);
        seal(1, &p)
    }

    fn small_forest() -> Forest {
        let (store, parts, off, rot) = toy(1);
        let data = TrainingSet {
            store: &store,
            parts: &parts,
            targets: RawTargets::pose(&off, &rot),
        };
        let p = ForestParams {
            n_trees: 2,
            max_depth: 3,
            n_candidates: 5,
            ..toy_params()
        };
        let meta = ModelMetadata {
            category: Some("toy".into()),
            ..Default::default()
        };
        Forest::fit(&p.check().unwrap(), &data, meta, None).unwrap()
    }

    /// [`small_forest`] with leaf weights that differ between leaves (format version 3).
    fn weighted_forest() -> Forest {
        let f = small_forest();
        let w = f
            .trees
            .iter()
            .map(|t| (0..t.n_leaves()).map(|l| (l % 4) as f32 / 3.0).collect())
            .collect();
        f.with_leaf_weights(Some(w)).unwrap()
    }

    #[test]
    fn leaf_weights_roundtrip_in_version_3_and_one_class_forests_stay_version_2() {
        let plain = small_forest();
        let f = weighted_forest();
        let (bp, bw) = (encode(&plain), encode(&f));
        assert_eq!(u32::from_le_bytes(bp[8..12].try_into().unwrap()), 2);
        assert_eq!(u32::from_le_bytes(bw[8..12].try_into().unwrap()), 3);
        // Version 3 is version 2's payload followed by the weights.
        assert!(bw[HEADER..].starts_with(&bp[HEADER..]));
        let g = decode(&bw, "w.isa").unwrap();
        assert_eq!(g, f);
        assert_eq!(
            g.leaf_weights.unwrap().per_tree(),
            f.leaf_weights.as_ref().unwrap().per_tree()
        );
        assert_eq!(decode(&bp, "p.isa").unwrap().leaf_weights, None);
        // A version-3 header on a payload without weights, and weights out of range or for the
        // wrong number of leaves, are refused by name.
        expect_err(
            decode(&seal(3, &bp[HEADER..]), "cut.isa"),
            &["cut.isa", "leaf weights of tree 0"],
        );
        let mut payload = bw[HEADER..].to_vec();
        let k = payload.len() - 4;
        payload[k..].copy_from_slice(&1.5f32.to_le_bytes());
        expect_err(
            decode(&seal(3, &payload), "big.isa"),
            &["big.isa", "not in [0, 1]"],
        );
        payload[k..].copy_from_slice(&f32::NAN.to_le_bytes());
        expect_err(decode(&seal(3, &payload), "nan.isa"), &["non-finite"]);
        let n0 = f.trees[0].n_leaves();
        let mut short = bp[HEADER..].to_vec();
        for t in &f.trees {
            short.extend_from_slice(&((t.n_leaves() - 1) as u32).to_le_bytes());
            short.extend(std::iter::repeat_n(0u8, 4 * (t.n_leaves() - 1)));
        }
        expect_err(
            decode(&seal(3, &short), "few.isa"),
            &[&format!("tree 0 has {n0} leaves")],
        );
    }

    fn is_format_err(r: Result<Forest>) -> bool {
        matches!(r, Err(IsaError::ModelFormat { .. }))
    }

    #[test]
    fn roundtrip_and_atomic_save() {
        let f = small_forest();
        let b = encode(&f);
        assert_eq!(decode(&b, "x").unwrap(), f);
        let dir = std::env::temp_dir().join(format!("isa-io-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.isa");
        f.save(&path).unwrap();
        assert_eq!(Forest::load(&path).unwrap(), f);
        assert_eq!(
            fs::read_dir(&dir).unwrap().count(),
            1,
            "no temporary file left"
        );
        assert!(matches!(
            Forest::load(dir.join("missing.isa")),
            Err(IsaError::Io { .. })
        ));
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn every_truncation_and_bad_header_is_an_error() {
        let b = encode(&small_forest());
        for n in 0..b.len() {
            assert!(is_format_err(decode(&b[..n], "t")), "prefix {n}");
        }
        let mut foreign = b.clone();
        foreign[0] = b'P';
        expect_err(decode(&foreign, "f"), &["magic"]);
        let mut newer = b.clone();
        newer[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
        expect_err(decode(&newer, "n"), &["newer"]);
        let mut flipped = b.clone();
        let k = flipped.len() - 3;
        flipped[k] ^= 0x40;
        expect_err(decode(&flipped, "c"), &["checksum"]);
    }

    fn reseal(payload: &[u8]) -> Vec<u8> {
        seal(FORMAT_VERSION, payload)
    }

    /// A file written by the code before format version 2 (`tests/data/make_model_v1.py`).
    const V1: &[u8] = include_bytes!("../../../tests/data/model_v1.isa");

    #[test]
    fn version_1_files_load_with_their_inference_defaults() {
        assert_eq!(u32::from_le_bytes(V1[8..12].try_into().unwrap()), 1);
        let f = decode(V1, "v1").unwrap();
        assert_eq!(f.metadata.category.as_deref(), Some("plate"));
        assert_eq!(f.metadata.extra["ssc"], serde_json::json!([0.0, 0.0, 0.0]));
        assert!(!f.metadata.extra.contains_key("predict_defaults"));
        let d = &f.predict_defaults;
        assert_eq!(
            (d.stride, d.vote.position_bandwidth, d.vote.max_hypotheses),
            (3, 0.06, 2)
        );
        assert_eq!(
            d.vote.min_support,
            PredictParams::default().vote.min_support
        );
        // Format 2 moves the header and the fields before the trees only: the trees' bytes are
        // the old file's, and a rewritten file reads back the same forest.
        let mut trees = Vec::new();
        encode_trees(&mut trees, &f);
        assert!(V1.ends_with(&trees));
        let v2 = encode(&f);
        assert_eq!(
            u32::from_le_bytes(v2[8..12].try_into().unwrap()),
            ONE_CLASS_VERSION
        );
        assert!(v2.ends_with(&trees));
        assert_eq!(decode(&v2, "v2").unwrap(), f);
    }

    #[test]
    fn version_1_metadata_with_python_nan_keeps_its_fields() {
        // Python's json.dumps wrote NaN bare (the protocol models' SSC statistics); the box and
        // category must still be read, the NaN read as null, a "NaN" inside a string kept.
        let f = small_forest();
        let raw = r#"{"category": "bed", "box": {"category": "bed", "size": [1.0, 2.0, 0.5], "ssc_offset": [0.0, 0.1, -0.2], "n_instances": 2}, "ssc": {"d": [0.2, NaN, -Infinity, Infinity], "note": "NaN \" Infinity"}}"#;
        let g = decode(&version_1_file(&f, raw), "old").unwrap();
        assert!(g.metadata.extra.get("legacy_metadata").is_none());
        assert_eq!(g.metadata.category.as_deref(), Some("bed"));
        assert_eq!(
            g.metadata.category_box.as_ref().unwrap().size,
            [1.0, 2.0, 0.5]
        );
        let ssc = &g.metadata.extra["ssc"];
        assert_eq!(ssc["d"], serde_json::json!([0.2, null, null, null]));
        assert_eq!(ssc["note"], "NaN \" Infinity");
    }

    #[test]
    fn version_1_metadata_that_is_not_an_object_is_kept_as_text() {
        let f = small_forest();
        for (raw, kept) in [("not json", true), ("[1, 2]", true), ("", false)] {
            let g = decode(&version_1_file(&f, raw), "old").unwrap();
            assert_eq!(g.trees, f.trees);
            assert_eq!(
                g.metadata.extra.get("legacy_metadata").is_some(),
                kept,
                "{raw}"
            );
        }
        // Bad inference defaults in an old file are a format error naming them.
        expect_err(
            decode(
                &version_1_file(&f, r#"{"predict_defaults": {"stride": 0}}"#),
                "old",
            ),
            &["predict_defaults", "stride"],
        );
    }

    #[test]
    fn inference_defaults_and_metadata_roundtrip() {
        let mut f = small_forest();
        let mut d = PredictParams::default();
        d.overlay(&serde_json::json!({"stride": 2, "nms_radius": 0.5}), "t")
            .unwrap();
        f.predict_defaults = d.check().unwrap();
        f.metadata.origin = Some("com".into());
        let g = decode(&encode(&f), "x").unwrap();
        assert_eq!(g.predict_defaults, f.predict_defaults);
        assert_eq!(g.metadata, f.metadata);
        assert_eq!(
            g.metadata.training.unwrap().n_parts,
            f.metadata.training.unwrap().n_parts
        );
    }

    /// Issue 20: a zero vote quaternion (valid checksum) loaded and predicted NaN rotations;
    /// negative weights and huge offsets loaded too.
    #[test]
    fn semantically_bad_values_are_refused_on_load() {
        let f = small_forest();
        let split = f.trees[0].nodes.iter().position(|n| !n.is_leaf).unwrap();
        type Edit = fn(&mut Tree, usize);
        let cases: [(Edit, &str); 8] = [
            (|t, _| t.votes[0].rotation = [0.0; 4], "rotation"),
            (
                |t, _| t.votes[0].rotation = [5.0, 0.0, 0.0, 0.0],
                "rotation",
            ),
            (
                |t, _| t.votes[0].rotation = [1e30, 0.0, 0.0, 0.0],
                "rotation",
            ),
            (|t, _| t.votes[0].weight = -0.25, "weight"),
            (|t, _| t.votes[0].weight = 2.0, "weight"),
            (|t, _| t.votes[0].offset[1] = 3e38, "offset"),
            (|t, s| t.nodes[s].feature.u[0] = 3e38, "feature offsets"),
            (|t, s| t.nodes[s].feature.v[1] = -1.5e5, "feature offsets"),
        ];
        for (edit, what) in cases {
            let mut g = f.clone();
            edit(&mut g.trees[0], split);
            expect_err(decode(&encode(&g), "bad.isa"), &["bad.isa", "tree 0", what]);
        }
        // At the bounds: accepted.
        let mut g = f.clone();
        g.trees[0].nodes[split].feature.u = [
            crate::features::MAX_FEATURE_OFFSET,
            -crate::features::MAX_FEATURE_OFFSET,
        ];
        g.trees[0].votes[0].offset = [crate::criterion::MAX_TARGET_OFFSET; 3];
        g.trees[0].votes[0].weight = 0.0;
        g.trees[0].votes[0].rotation = [0.0, 0.0, 0.0, 1.0005];
        assert_eq!(decode(&encode(&g), "edge").unwrap(), g);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = decode(&bytes, "fuzz");
            let _ = decode(&reseal(&bytes), "fuzz");
        }

        /// Mutations of a valid payload with a fixed-up checksum exercise the parser itself;
        /// whatever decodes must traverse without panicking.
        #[test]
        fn mutated_payloads_never_panic(muts in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
                                        cut in any::<prop::sample::Index>()) {
            let good = encode(&weighted_forest());
            let mut payload = good[HEADER..].to_vec();
            for (i, v) in muts {
                let k = i.index(payload.len());
                payload[k] = v;
            }
            let keep = payload.len() - cut.index(payload.len() / 4 + 1);
            payload.truncate(keep);
            if let Ok(f) = decode(&reseal(&payload), "fuzz") {
                let (store, parts, _, _) = toy(1);
                let _ = f.apply(&store, &parts[..20]);
            }
        }
    }
}
