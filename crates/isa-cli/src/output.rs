//! What the commands print: predictions as one JSON document or a BOP results CSV, model
//! summaries as JSON or text; and writing it to a file or standard output.

use std::io::Write;
use std::path::Path;

use serde_json::{json, Value};

use isa_core::vote::Hypothesis;
use isa_core::{Forest, PredictParams};

use crate::commands::predict::ImageJob;
use crate::error::{CliError, CliResult};

/// The hypotheses of one image.
pub struct ImageResult {
    pub job: ImageJob,
    pub width: usize,
    pub height: usize,
    pub hyps: Vec<Hypothesis>,
    pub seconds: f64,
}

/// Writes `text` to `path` atomically (the old file or the new one, whole), or to standard
/// output; a closed standard output (the reader is gone, as `| head`) is not an error.
pub fn write(path: Option<&Path>, text: &str) -> CliResult<()> {
    match path {
        Some(path) => Ok(isa_core::atomic::write_bytes(path, text.as_bytes())?),
        None => {
            let mut out = std::io::stdout().lock();
            match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
                Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
                    Err(CliError::io(Path::new("<stdout>"), e))
                }
                _ => Ok(()),
            }
        }
    }
}

pub fn predict_json(model: &Path, params: &PredictParams, results: &[ImageResult]) -> String {
    let images: Vec<Value> = results
        .iter()
        .map(|r| {
            json!({
                "depth": r.job.path.display().to_string(),
                "image_id": r.job.id,
                "width": r.width,
                "height": r.height,
                "intrinsics": r.job.k,
                "seconds": r.seconds,
                "hypotheses": r.hyps.iter().map(|h| json!({
                    "R": h.rotation,
                    "t": h.translation,
                    "quaternion": h.quaternion,
                    "score": h.score,
                    "support": h.support,
                    "position_score": h.position_score,
                    "position_support": h.position_support,
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    let doc = json!({
        "isa_version": isa_core::VERSION,
        "model": model.display().to_string(),
        "units": {"t": "metres, camera frame (OpenCV), X_cam = R X_obj + t", "R": "row-major"},
        "params": params,
        "images": images,
    });
    serde_json::to_string_pretty(&doc).expect("serialise") + "\n"
}

/// BOP challenge results: `scene_id,im_id,obj_id,score,R,t,time`, t in millimetres.
pub fn bop_csv(results: &[ImageResult], scene_id: u64, obj_id: u64) -> CliResult<String> {
    let mut s = String::from("scene_id,im_id,obj_id,score,R,t,time\n");
    for r in results {
        let im_id = r.job.id.ok_or_else(|| {
            CliError::param(format!(
                "--format bop needs an image id: name {} by its id (000012.png) or pass --image-id",
                r.job.path.display()
            ))
        })?;
        for h in &r.hyps {
            let rr: Vec<String> = h
                .rotation
                .iter()
                .flatten()
                .map(|v| format!("{v:.8}"))
                .collect();
            let tt: Vec<String> = h
                .translation
                .iter()
                .map(|v| format!("{:.4}", v * 1000.0))
                .collect();
            s.push_str(&format!(
                "{scene_id},{im_id},{obj_id},{:.6},{},{},{:.6}\n",
                h.score,
                rr.join(" "),
                tt.join(" "),
                r.seconds
            ));
        }
    }
    Ok(s)
}

fn tree_rows(forest: &Forest) -> Vec<Value> {
    forest
        .trees
        .iter()
        .map(|t| json!({"nodes": t.nodes.len(), "leaves": t.n_leaves(), "depth": t.depth(), "votes": t.votes.len()}))
        .collect()
}

/// A model file as `isa inspect` describes it.
pub struct ModelFile<'a> {
    pub path: &'a Path,
    pub bytes: u64,
    /// The format version in its header.
    pub version: u32,
}

pub fn inspect_json(forest: &Forest, file: &ModelFile<'_>) -> String {
    let (nodes, leaves) = forest.size();
    let votes: usize = forest.trees.iter().map(|t| t.votes.len()).sum();
    let doc = json!({
        "path": file.path.display().to_string(),
        "file_bytes": file.bytes,
        "format_version": file.version,
        "leaf_weights": forest.leaf_weights.is_some(),
        "crate_version": forest.crate_version,
        "params": forest.params,
        "predict_defaults": forest.predict_defaults,
        "metadata": forest.metadata,
        "n_trees": forest.n_trees(),
        "n_nodes": nodes,
        "n_leaves": leaves,
        "n_votes": votes,
        "trees": tree_rows(forest),
    });
    serde_json::to_string_pretty(&doc).expect("serialise") + "\n"
}

/// `value` as indented JSON under a 14-column label.
fn block(label: &str, value: &impl serde::Serialize) -> String {
    format!(
        "{label:<14}{}\n",
        serde_json::to_string_pretty(value)
            .expect("serialise")
            .replace('\n', "\n              ")
    )
}

pub fn inspect_text(forest: &Forest, file: &ModelFile<'_>) -> String {
    let (nodes, leaves) = forest.size();
    let votes: usize = forest.trees.iter().map(|t| t.votes.len()).sum();
    let mut s = format!(
        "model file    {} ({} bytes, format version {})\n",
        file.path.display(),
        file.bytes,
        file.version
    );
    s += &format!("trained by    isa {}\n", forest.crate_version);
    s += &format!(
        "forest        {} trees, {nodes} nodes, {leaves} leaves, {votes} leaf votes{}\n",
        forest.n_trees(),
        if forest.leaf_weights.is_some() { ", leaf weights" } else { "" }
    );
    let depths: Vec<usize> = forest.trees.iter().map(|t| t.depth()).collect();
    if let (Some(lo), Some(hi)) = (depths.iter().min(), depths.iter().max()) {
        s += &format!("tree depth    min {lo} / max {hi}\n");
    }
    s += &block("parameters", &forest.params);
    s += &block("inference", &*forest.predict_defaults);
    s += &block("metadata", &forest.metadata);
    s += "per tree      nodes / leaves / depth / votes\n";
    for (i, t) in forest.trees.iter().enumerate() {
        s += &format!(
            "  {i:>4}        {} / {} / {} / {}\n",
            t.nodes.len(),
            t.n_leaves(),
            t.depth(),
            t.votes.len()
        );
    }
    s
}
