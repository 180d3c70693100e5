//! What the commands print: predictions as one JSON document or a BOP results CSV, model
//! summaries as JSON or text; and writing it to a file or standard output.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use isa_core::rotation::pose_matrix;
use isa_core::vote::Hypothesis;
use isa_core::{Forest, PredictParams};

use crate::commands::predict::ImageJob;
use crate::error::{CliError, CliResult};

/// The hypotheses of one image.
// Plain fields (`duplicates` pairs them by shape with the core's `ShardSet`; nothing shared).
pub struct ImageResult {
    pub job: ImageJob,
    pub width: usize,
    pub height: usize,
    /// The core's warnings about the image (depth range, size).
    pub warnings: Vec<String>,
    /// The obj_id of its BOP rows (for --format bop).
    pub obj_id: Option<u64>,
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
                "warnings": r.warnings,
                "hypotheses": r.hyps.iter().map(|h| json!({
                    "R": h.rotation,
                    "t": h.translation,
                    "pose": pose_matrix(&h.rotation, &h.translation),
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
        "units": UNITS.clone(),
        "params": params,
        "images": images,
    });
    serde_json::to_string_pretty(&doc).expect("serialise") + "\n"
}

/// What the JSON outputs' numbers mean (predict's and detect's).
pub static UNITS: std::sync::LazyLock<Value> = std::sync::LazyLock::new(|| {
    json!({"t": "metres, camera frame (OpenCV), X_cam = R X_obj + t", "R": "row-major",
           "pose": "4x4 row-major [[R, t], [0, 0, 0, 1]], X_cam = pose [X_obj; 1]"})
});

/// The header of a BOP results file (bop_toolkit's `inout.load_bop_results` skips it on the
/// first line only, so a file has it once).
pub const BOP_HEADER: &str = "scene_id,im_id,obj_id,score,R,t,time\n";

/// One BOP results row: R row-major, t in millimetres, the image's time in seconds.
pub fn bop_row(ids: [u64; 3], score: f64, r: &[[f64; 3]; 3], t: &[f64; 3], seconds: f64) -> String {
    let rr: Vec<String> = r.iter().flatten().map(|v| format!("{v:.8}")).collect();
    let tt: Vec<String> = t.iter().map(|v| format!("{:.4}", v * 1000.0)).collect();
    format!(
        "{},{},{},{score:.6},{},{},{seconds:.6}\n",
        ids[0],
        ids[1],
        ids[2],
        rr.join(" "),
        tt.join(" ")
    )
}

/// The image id of a BOP row, or the error saying how to give one.
pub fn bop_image_id(job: &ImageJob) -> CliResult<u64> {
    job.id.ok_or_else(|| {
        CliError::param(format!(
            "--format bop needs an image id: name {} by its id (000012.png) or pass --image-id",
            job.path.display()
        ))
    })
}

/// BOP challenge results of every image, one header.
pub fn bop_csv(results: &[ImageResult]) -> CliResult<String> {
    let mut s = String::from(BOP_HEADER);
    for r in results {
        let im_id = bop_image_id(&r.job)?;
        let obj_id = r.obj_id.expect("obj_id resolved for --format bop");
        for h in &r.hyps {
            s += &bop_row(
                [r.job.scene_id.unwrap_or(0), im_id, obj_id],
                h.score,
                &h.rotation,
                &h.translation,
                r.seconds,
            );
        }
    }
    Ok(s)
}

/// Where a BOP results file goes for `-o out`: `out` itself when it is not a folder (with a
/// warning when its name is not bop_toolkit's `METHOD_DATASET-SPLIT.csv`), else
/// `out/METHOD_DATASET-SPLIT.csv` with DATASET and SPLIT from the scene folders' path
/// (`.../DATASET/SPLIT/SCENE`, or a split folder `.../DATASET/SPLIT`).
pub fn bop_results_path(out: &Path, method: &str, scenes: &[PathBuf]) -> CliResult<PathBuf> {
    if method.is_empty() || method.contains(['_', '-', '.', '/']) {
        return Err(CliError::param(format!(
            "--method {method:?}: bop_toolkit reads the method up to the first '_': give a name without '_', '-', '.' or '/'"
        )));
    }
    if !out.is_dir() {
        let name = out.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if !is_bop_results_name(name) {
            crate::error::warn(&format!(
                "{}: bop_toolkit's evaluation expects a results file named METHOD_DATASET-SPLIT.csv (e.g. isa_lm-test.csv); give -o a folder to get that name",
                out.display()
            ));
        }
        return Ok(out.to_path_buf());
    }
    let mut names = std::collections::BTreeSet::new();
    for dir in crate::inputs::scene_folders(scenes)? {
        let dir = std::fs::canonicalize(&dir).map_err(|e| CliError::io(&dir, e))?;
        let part = |p: Option<&Path>| p.and_then(|p| p.file_name()?.to_str().map(String::from));
        let split = part(dir.parent());
        let dataset = part(dir.parent().and_then(Path::parent));
        names.insert((dataset, split));
    }
    match names.into_iter().collect::<Vec<_>>().as_slice() {
        [(Some(d), Some(sp))] if !d.contains(['_', '-']) && !sp.contains('_') => {
            Ok(out.join(format!("{method}_{d}-{sp}.csv")))
        }
        [(d, sp)] => Err(CliError::param(format!(
            "-o {}: a folder, but the scene folders' dataset {d:?} and split {sp:?} (from .../DATASET/SPLIT/SCENE) do not make a BOP results name (no '_' in either, no '-' in the dataset); give -o a file",
            out.display()
        ))),
        _ => Err(CliError::param(format!(
            "-o {}: a folder, but the scenes come from several (or no) DATASET/SPLIT folders; give -o a file",
            out.display()
        ))),
    }
}

/// `METHOD_DATASET-SPLIT[-TYPE][_ID].csv` as bop_toolkit's `parse_result_filename` splits it.
fn is_bop_results_name(name: &str) -> bool {
    let Some(stem) = name.strip_suffix(".csv") else {
        return false;
    };
    let parts: Vec<&str> = stem.split('_').collect();
    parts.len() >= 2
        && !parts[0].is_empty()
        && parts[1].split('-').count() >= 2
        && parts[1].split('-').all(|p| !p.is_empty())
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
        if forest.leaf_weights.is_some() {
            ", leaf weights"
        } else {
            ""
        }
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
