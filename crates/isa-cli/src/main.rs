//! `isa` command-line interface: train a category forest from a training-set file, predict 6D
//! poses in depth PNGs, inspect model files. See `isa --help` and `isa <command> --help`.

mod inputs;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{json, Value};

use isa_core::vote::{self, DepthImage, Hypothesis, Intrinsics, PredictParams};
use isa_core::{trainset_io, Forest, ForestParams, IsaError, Quality};

const EXIT_CODES: &str = "\
Exit codes:
  0  success
  1  unexpected failure
  2  bad command line (unknown option, missing argument)
  3  a file is missing or cannot be read/written (the message names it)
  4  an input is invalid: corrupt or foreign model/training-set file, depth image that is not
     16-bit single-channel or does not fit its intrinsics, malformed camera JSON
  5  a parameter value is invalid (the message names the parameter)";

/// Category-level 6D object pose from depth images (Intrinsic Structure Adaptor, ISA).
///
/// A forest trained on depth images of one object category (`isa train`) votes for the 6D pose
/// (rotation R, translation t of the category's semantically selected centre, X_cam = R X_obj + t)
/// of unseen instances in whole depth images (`isa predict`). `isa inspect` shows what a model
/// file holds.
#[derive(Parser)]
#[command(name = "isa", version = isa_core::VERSION, after_help = EXIT_CODES)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    Train(TrainArgs),
    Predict(PredictArgs),
    Inspect(InspectArgs),
}

/// Train a forest from a training-set file (.isat, written by Python's
/// `isa._core.write_trainset`) and save it as a model file.
///
/// Training parameters: the defaults of isa_core::ForestParams, overridden by `--params` (a
/// JSON object with any subset of the fields), overridden by the flags below.
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
struct TrainArgs {
    /// Training-set file (.isat): depth crops, parts, offsets, rotations, optional link angles
    /// and node offsets, metadata (format: docs/CLI.md).
    trainset: PathBuf,
    /// Where to write the model file (written atomically).
    #[arg(short, long, value_name = "MODEL")]
    output: PathBuf,
    /// JSON file of forest parameters (any subset of the ForestParams fields).
    #[arg(long, value_name = "JSON")]
    params: Option<PathBuf>,
    /// Number of trees [default: 10].
    #[arg(long)]
    n_trees: Option<usize>,
    /// Maximum tree depth, root = 0 [default: 20].
    #[arg(long)]
    max_depth: Option<usize>,
    /// Split criterion: Q1, Q1+Q2, Q1+Q3 or Q1+Q2+Q3 (paper Eq. 9-11) [default: Q1+Q2+Q3].
    /// Q2 needs link angles and Q3 node offsets in the training set.
    #[arg(long)]
    quality: Option<String>,
    /// Random feature candidates per node [default: 100].
    #[arg(long)]
    n_candidates: Option<usize>,
    /// Minimum parts in each child of a split [default: 5].
    #[arg(long)]
    min_samples_leaf: Option<usize>,
    /// Nodes with fewer parts become leaves [default: 20].
    #[arg(long)]
    min_samples_split: Option<usize>,
    /// Fraction of the parts each tree trains on, in (0, 1] [default: 1].
    #[arg(long)]
    bag_fraction: Option<f64>,
    /// Seed of every random choice (same seed + data = same model bytes) [default: 0].
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads [default: all cores]. Does not change the model.
    #[arg(long)]
    threads: Option<usize>,
    /// No progress display.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Format {
    /// One JSON document: per image, its hypotheses (R row-major, t in metres, quaternion w x y z,
    /// score, support), the intrinsics, the parameters and the time.
    Json,
    /// BOP challenge results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in mm,
    /// time in seconds), one row per hypothesis.
    Bop,
}

/// Predict 6D poses in depth images: every part of the whole image votes (no segmentation, no
/// boxes); modes of the votes become ranked hypotheses.
///
/// Inputs: depth PNGs (16-bit, millimetres, 0 = missing) with `--intrinsics` or `--camera`, or
/// a BOP scene folder with `--scene`. Examples:
///
///   isa predict chair.isaf depth.png -k 525 525 319.5 239.5
///
///   isa predict chair.isaf scene/depth/000012.png --camera scene/scene_camera.json
///
///   isa predict chair.isaf --scene bop/test/000001 --format bop -o results.csv
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
struct PredictArgs {
    /// Model file written by `isa train` or Python's `Forest.save`.
    #[arg(value_name = "MODEL")]
    model: PathBuf,
    /// Depth images: 16-bit single-channel PNGs in millimetres (times the camera's depth_scale
    /// with --camera), 0 = missing.
    #[arg(value_name = "PNG", conflicts_with = "scene")]
    depth: Vec<PathBuf>,
    /// Pinhole intrinsics in pixels: FX FY CX CY.
    #[arg(short = 'k', long, num_args = 4, value_names = ["FX", "FY", "CX", "CY"], conflicts_with = "camera")]
    intrinsics: Option<Vec<f64>>,
    /// Camera file: a BOP scene_camera.json (per image id: cam_K, depth_scale; the id is the
    /// PNG's file name, e.g. 000012.png, or --image-id) or a BOP camera.json (fx, fy, cx, cy,
    /// width, height, depth_scale; the image size is then checked).
    #[arg(short, long, value_name = "JSON")]
    camera: Option<PathBuf>,
    /// A BOP scene folder: every depth/*.png with its scene_camera.json.
    #[arg(long, value_name = "DIR")]
    scene: Option<PathBuf>,
    /// Image id for --camera scene_camera.json when the file name is not one [default: from the
    /// file name].
    #[arg(long)]
    image_id: Option<u64>,
    /// BOP scene id for --format bop [default: the --scene folder's name if a number, else 0].
    #[arg(long)]
    scene_id: Option<u64>,
    /// BOP object id of the category for --format bop.
    #[arg(long, default_value_t = 1)]
    obj_id: u64,
    /// Output format.
    #[arg(short, long, value_enum, default_value_t = Format::Json)]
    format: Format,
    /// Output file [default: standard output].
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Parts on every STRIDE-th pixel in u and v [default: 4].
    #[arg(long)]
    stride: Option<usize>,
    /// Ignore pixels nearer than this, metres [default: 0].
    #[arg(long)]
    min_depth: Option<f32>,
    /// Ignore pixels farther than this, metres [default: no limit].
    #[arg(long)]
    max_depth: Option<f32>,
    /// Radius of the position kernel and grid cell, metres [default: 0.08].
    #[arg(long)]
    position_bandwidth: Option<f32>,
    /// Geodesic radius of the rotation kernel, radians [default: 0.5].
    #[arg(long)]
    rotation_bandwidth: Option<f32>,
    /// Hypotheses per image at most [default: 5].
    #[arg(long)]
    max_hypotheses: Option<usize>,
    /// Positions closer than this to a better hypothesis are suppressed, metres [default: 0.25].
    #[arg(long)]
    nms_radius: Option<f32>,
    /// Rotation modes per position (for symmetric objects) [default: 1].
    #[arg(long)]
    rotations_per_position: Option<usize>,
    /// Drop hypotheses supported by fewer votes [default: 3].
    #[arg(long)]
    min_support: Option<usize>,
    /// JSON file of inference parameters (fields of PredictParams, with mode finding under
    /// "vote"); flags override it.
    #[arg(long, value_name = "JSON")]
    params: Option<PathBuf>,
    /// Worker threads [default: all cores]. Does not change the result.
    #[arg(long)]
    threads: Option<usize>,
    /// No progress display.
    #[arg(short, long)]
    quiet: bool,
}

/// Show what a model file holds: format and crate versions, training parameters, metadata
/// (category, SSC, ...), and the size of every tree.
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
struct InspectArgs {
    /// Model file.
    model: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

// ---------------------------------------------------------------------------------------------
// Errors and exit codes.

/// An error with its exit code; the message names the file or parameter at fault.
#[derive(Debug)]
pub struct CliError {
    pub code: u8,
    pub msg: String,
}

pub type CliResult<T> = Result<T, CliError>;

impl CliError {
    pub fn missing(path: &Path, what: &str) -> Self {
        CliError {
            code: 3,
            msg: format!("{what} {} does not exist", path.display()),
        }
    }
    pub fn io(path: &Path, e: std::io::Error) -> Self {
        CliError {
            code: 3,
            msg: format!("cannot read or write {}: {e}", path.display()),
        }
    }
    pub fn input(msg: String) -> Self {
        CliError { code: 4, msg }
    }
    pub fn param(msg: String) -> Self {
        CliError { code: 5, msg }
    }
}

impl From<IsaError> for CliError {
    fn from(e: IsaError) -> Self {
        let code = match &e {
            IsaError::Io { .. } => 3,
            IsaError::ModelFormat { .. } | IsaError::InvalidInput(_) => 4,
            IsaError::InvalidParameter(_) => 5,
        };
        CliError {
            code,
            msg: e.to_string(),
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let res = match cli.command {
        Command::Train(a) => train(a),
        Command::Predict(a) => predict(a),
        Command::Inspect(a) => inspect(a),
    };
    match res {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("isa: error: {}", e.msg);
            ExitCode::from(e.code)
        }
    }
}

fn spinner(quiet: bool, msg: String) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed_precise}]").expect("template"),
    );
    pb.set_message(msg);
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

fn bar(quiet: bool, n: u64, msg: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(n);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} [{elapsed_precise}, eta {eta}]")
            .expect("template")
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> CliResult<T> {
    if threads == Some(0) {
        return Err(CliError::param("--threads must be at least 1".into()));
    }
    isa_core::forest::with_threads(threads, f).map_err(CliError::from)
}

fn read_json_file(path: &Path, what: &str) -> CliResult<Value> {
    if !path.exists() {
        return Err(CliError::missing(path, what));
    }
    let text = std::fs::read_to_string(path).map_err(|e| CliError::io(path, e))?;
    serde_json::from_str(&text)
        .map_err(|e| CliError::param(format!("{what} {}: not valid JSON: {e}", path.display())))
}

/// Overlays the `--params` JSON file (if given) on `base`.
fn overlay_params_file(base: &mut Value, path: Option<&Path>) -> CliResult<()> {
    match path {
        Some(path) => overlay(
            base,
            &read_json_file(path, "parameter file")?,
            &format!("parameter file {}", path.display()),
        ),
        None => Ok(()),
    }
}

/// Overlays the keys of `over` on `base` (both objects); unknown keys are errors naming them.
fn overlay(base: &mut Value, over: &Value, what: &str) -> CliResult<()> {
    let o = over
        .as_object()
        .ok_or_else(|| CliError::param(format!("{what}: expected a JSON object")))?;
    let b = base.as_object_mut().expect("object");
    for (k, v) in o {
        match b.get_mut(k) {
            None => {
                let mut known: Vec<&String> = b.keys().collect();
                known.sort();
                return Err(CliError::param(format!(
                    "{what}: unknown parameter {k:?}; known: {known:?}"
                )));
            }
            Some(slot) if slot.is_object() && v.is_object() => {
                overlay(slot, v, &format!("{what}.{k}"))?
            }
            Some(slot) => *slot = v.clone(),
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// train

fn train(a: TrainArgs) -> CliResult<()> {
    let mut p = serde_json::to_value(ForestParams::default()).expect("serialise");
    overlay_params_file(&mut p, a.params.as_deref())?;
    let mut flags = serde_json::Map::new();
    let mut set = |k: &str, v: Option<Value>| {
        if let Some(v) = v {
            flags.insert(k.to_string(), v);
        }
    };
    set("n_trees", a.n_trees.map(Value::from));
    set("max_depth", a.max_depth.map(Value::from));
    set("n_candidates", a.n_candidates.map(Value::from));
    set("min_samples_leaf", a.min_samples_leaf.map(Value::from));
    set("min_samples_split", a.min_samples_split.map(Value::from));
    set("bag_fraction", a.bag_fraction.map(Value::from));
    set("seed", a.seed.map(Value::from));
    if let Some(q) = &a.quality {
        flags.insert("quality".into(), Value::from(Quality::parse(q)?.as_str()));
    }
    overlay(&mut p, &Value::Object(flags), "flags")?;
    let params: ForestParams = serde_json::from_value(p)
        .map_err(|e| CliError::param(format!("forest parameters: {e}")))?;
    params.validate()?;

    if !a.trainset.exists() {
        return Err(CliError::missing(&a.trainset, "training-set file"));
    }
    let pb = spinner(a.quiet, format!("reading {}", a.trainset.display()));
    let ts = trainset_io::read(&a.trainset)?;
    pb.finish_and_clear();
    if params.quality.uses_q2() && ts.link_angles.is_none() {
        return Err(CliError::param(format!(
            "quality {} needs link angles (Q2), but {} has none: use --quality Q1 or Q1+Q3, or write link_angles",
            params.quality.as_str(),
            a.trainset.display()
        )));
    }
    if params.quality.uses_q3() && ts.node_offsets.is_none() {
        return Err(CliError::param(format!(
            "quality {} needs node offsets (Q3), but {} has none: use --quality Q1 or Q1+Q2, or write node_offsets",
            params.quality.as_str(),
            a.trainset.display()
        )));
    }
    let msg = format!(
        "training {} trees (depth <= {}, {}) on {} parts of {} images",
        params.n_trees,
        params.max_depth,
        params.quality.as_str(),
        ts.n_parts(),
        ts.store.len()
    );
    if a.threads == Some(0) {
        return Err(CliError::param("--threads must be at least 1".into()));
    }
    let pb = bar(
        a.quiet,
        params.n_trees as u64,
        &format!("training {} trees", params.n_trees),
    );
    let t0 = Instant::now();
    let forest = Forest::fit_with_progress(
        &params,
        &ts.training_set(),
        &ts.metadata,
        a.threads,
        &|done| pb.set_position(done as u64),
    )?;
    let secs = t0.elapsed().as_secs_f64();
    pb.finish_and_clear();
    forest.save(&a.output)?;
    let (nodes, leaves) = forest.size();
    if !a.quiet {
        eprintln!(
            "{msg}: done in {secs:.1} s; {nodes} nodes, {leaves} leaves; wrote {}",
            a.output.display()
        );
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// predict

fn load_model(path: &Path) -> CliResult<Forest> {
    if !path.exists() {
        return Err(CliError::missing(path, "model file"));
    }
    Ok(Forest::load(path)?)
}

/// The inference defaults a model carries in its metadata (`predict_defaults`, flat keys as in
/// Python's `Forest.predict`, e.g. the size-aware `position_bandwidth`), nested as
/// [`PredictParams`]; keys this version does not know are ignored (the metadata is opaque).
fn model_predict_defaults(forest: &Forest) -> Option<Value> {
    let meta: Value = serde_json::from_str(&forest.metadata).ok()?;
    let flat = meta.get("predict_defaults")?.as_object()?;
    let base = serde_json::to_value(PredictParams::default()).expect("serialise");
    let (top_keys, vote_keys) = (base.as_object()?, base.get("vote")?.as_object()?);
    let (mut top, mut vote) = (serde_json::Map::new(), serde_json::Map::new());
    for (k, v) in flat {
        if k != "vote" && top_keys.contains_key(k) {
            top.insert(k.clone(), v.clone());
        } else if vote_keys.contains_key(k) {
            vote.insert(k.clone(), v.clone());
        }
    }
    top.insert("vote".into(), Value::Object(vote));
    Some(Value::Object(top))
}

/// Inference parameters: defaults, then the model's `predict_defaults` (if given), then the
/// parameter file, then the flags.
fn predict_params(a: &PredictArgs, model_defaults: Option<&Value>) -> CliResult<PredictParams> {
    let mut p = serde_json::to_value(PredictParams::default()).expect("serialise");
    if let Some(d) = model_defaults {
        overlay(&mut p, d, "model predict_defaults")?;
    }
    overlay_params_file(&mut p, a.params.as_deref())?;
    let mut top = serde_json::Map::new();
    let mut v = serde_json::Map::new();
    let put = |m: &mut serde_json::Map<String, Value>, k: &str, x: Option<Value>| {
        if let Some(x) = x {
            m.insert(k.into(), x);
        }
    };
    put(&mut top, "stride", a.stride.map(Value::from));
    put(&mut top, "min_depth", a.min_depth.map(Value::from));
    put(&mut top, "max_depth", a.max_depth.map(Value::from));
    put(
        &mut v,
        "position_bandwidth",
        a.position_bandwidth.map(Value::from),
    );
    put(
        &mut v,
        "rotation_bandwidth",
        a.rotation_bandwidth.map(Value::from),
    );
    put(&mut v, "max_hypotheses", a.max_hypotheses.map(Value::from));
    put(&mut v, "nms_radius", a.nms_radius.map(Value::from));
    put(
        &mut v,
        "rotations_per_position",
        a.rotations_per_position.map(Value::from),
    );
    put(&mut v, "min_support", a.min_support.map(Value::from));
    top.insert("vote".into(), Value::Object(v));
    overlay(&mut p, &Value::Object(top), "flags")?;
    let params: PredictParams = serde_json::from_value(p)
        .map_err(|e| CliError::param(format!("inference parameters: {e}")))?;
    // Name the flag in the message (fields and flags share names).
    params
        .validate()
        .map_err(|e| CliError::param(format!("{e} (flag --{})", flag_of(&e.to_string()))))?;
    Ok(params)
}

fn flag_of(msg: &str) -> String {
    let field = msg
        .trim_start_matches("invalid parameter: ")
        .split_whitespace()
        .next()
        .unwrap_or("");
    field.replace('_', "-")
}

struct ImageJob {
    path: PathBuf,
    id: Option<u64>,
    k: Intrinsics,
    expected: Option<(usize, usize)>,
    scale: f64,
    source: String,
}

struct ImageResult {
    job: ImageJob,
    width: usize,
    height: usize,
    hyps: Vec<Hypothesis>,
    seconds: f64,
}

fn jobs(a: &PredictArgs) -> CliResult<(Vec<ImageJob>, Option<u64>)> {
    if let Some(dir) = &a.scene {
        let (files, cam_path) = inputs::scene_folder(dir)?;
        let cam = inputs::CameraFile::read(&cam_path)?;
        let scene_id = a
            .scene_id
            .or_else(|| dir.file_name()?.to_str()?.parse().ok());
        let mut out = Vec::new();
        for f in files {
            let id = inputs::id_from_stem(&f);
            let (k, expected, scale) = cam.for_image(id)?;
            out.push(ImageJob {
                path: f,
                id,
                k,
                expected,
                scale,
                source: cam_path.display().to_string(),
            });
        }
        return Ok((out, scene_id));
    }
    if a.depth.is_empty() {
        return Err(CliError::param(
            "give depth images (isa predict MODEL PNG...) or a BOP scene folder with --scene DIR"
                .into(),
        ));
    }
    let cam = a
        .camera
        .as_ref()
        .map(|c| inputs::CameraFile::read(c))
        .transpose()?;
    let mut out = Vec::new();
    for f in &a.depth {
        let id = a
            .image_id
            .filter(|_| a.depth.len() == 1)
            .or_else(|| inputs::id_from_stem(f));
        let (k, expected, scale, source) = match (&cam, &a.intrinsics) {
            (Some(c), _) => {
                let (k, e, s) = c.for_image(id)?;
                (k, e, s, a.camera.as_ref().unwrap().display().to_string())
            }
            (None, Some(v)) => {
                let k = Intrinsics {
                    fx: v[0],
                    fy: v[1],
                    cx: v[2],
                    cy: v[3],
                };
                k.validate()
                    .map_err(|e| CliError::param(format!("--intrinsics: {e}")))?;
                (k, None, 1.0, "--intrinsics".to_string())
            }
            (None, None) => {
                return Err(CliError::param(
                    "give the intrinsics with --intrinsics FX FY CX CY or --camera JSON".into(),
                ))
            }
        };
        out.push(ImageJob {
            path: f.clone(),
            id,
            k,
            expected,
            scale,
            source,
        });
    }
    Ok((out, a.scene_id))
}

fn predict(a: PredictArgs) -> CliResult<()> {
    predict_params(&a, None)?; // bad flags or parameter files fail before a model is read
    let (jobs, scene_id) = jobs(&a)?;
    let pb = spinner(a.quiet, format!("loading {}", a.model.display()));
    let forest = load_model(&a.model)?;
    pb.finish_and_clear();
    let params = predict_params(&a, model_predict_defaults(&forest).as_ref())?;
    if forest.n_trees() == 0 {
        return Err(CliError::input(format!(
            "model file {}: the forest has no trees",
            a.model.display()
        )));
    }
    let pb = bar(a.quiet || jobs.len() < 2, jobs.len() as u64, "predicting");
    let mut results = Vec::with_capacity(jobs.len());
    for job in jobs {
        let d = inputs::read_depth_png(&job.path, job.scale)?;
        inputs::check_size(&d, &job.k, job.expected, &job.source)?;
        let img = DepthImage::new(&d.mm, d.width, d.height)?;
        let t0 = Instant::now();
        let hyps = with_threads(a.threads, || vote::predict(&forest, &img, &job.k, &params))??;
        let seconds = t0.elapsed().as_secs_f64();
        results.push(ImageResult {
            width: d.width,
            height: d.height,
            job,
            hyps,
            seconds,
        });
        pb.inc(1);
    }
    pb.finish_and_clear();

    let text = match a.format {
        Format::Json => {
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
                "model": a.model.display().to_string(),
                "units": {"t": "metres, camera frame (OpenCV), X_cam = R X_obj + t", "R": "row-major"},
                "params": params,
                "images": images,
            });
            serde_json::to_string_pretty(&doc).expect("serialise") + "\n"
        }
        Format::Bop => {
            let mut s = String::from("scene_id,im_id,obj_id,score,R,t,time\n");
            for r in &results {
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
                        "{},{},{},{:.6},{},{},{:.6}\n",
                        scene_id.unwrap_or(0),
                        im_id,
                        a.obj_id,
                        h.score,
                        rr.join(" "),
                        tt.join(" "),
                        r.seconds
                    ));
                }
            }
            s
        }
    };
    match &a.output {
        Some(path) => std::fs::write(path, text).map_err(|e| CliError::io(path, e))?,
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())
                .map_err(|e| CliError::io(Path::new("<stdout>"), e))?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// inspect

fn inspect(a: InspectArgs) -> CliResult<()> {
    let forest = load_model(&a.model)?;
    let bytes = std::fs::metadata(&a.model).map(|m| m.len()).unwrap_or(0);
    let trees: Vec<Value> = forest
        .trees
        .iter()
        .map(|t| json!({"nodes": t.nodes.len(), "leaves": t.n_leaves(), "depth": t.depth(), "votes": t.votes.len()}))
        .collect();
    let (nodes, leaves) = forest.size();
    let votes: usize = forest.trees.iter().map(|t| t.votes.len()).sum();
    let metadata: Value =
        serde_json::from_str(&forest.metadata).unwrap_or(Value::String(forest.metadata.clone()));
    if a.json {
        let doc = json!({
            "path": a.model.display().to_string(),
            "file_bytes": bytes,
            "format_version": isa_core::model_io::FORMAT_VERSION,
            "crate_version": forest.crate_version,
            "params": forest.params,
            "metadata": metadata,
            "n_trees": forest.n_trees(),
            "n_nodes": nodes,
            "n_leaves": leaves,
            "n_votes": votes,
            "trees": trees,
        });
        println!("{}", serde_json::to_string_pretty(&doc).expect("serialise"));
        return Ok(());
    }
    println!(
        "model file    {} ({bytes} bytes, format version {})",
        a.model.display(),
        isa_core::model_io::FORMAT_VERSION
    );
    println!("trained by    isa {}", forest.crate_version);
    println!(
        "forest        {} trees, {nodes} nodes, {leaves} leaves, {votes} leaf votes",
        forest.n_trees()
    );
    let depths: Vec<usize> = forest.trees.iter().map(|t| t.depth()).collect();
    if !depths.is_empty() {
        println!(
            "tree depth    min {} / max {}",
            depths.iter().min().unwrap(),
            depths.iter().max().unwrap()
        );
    }
    println!(
        "parameters    {}",
        serde_json::to_string_pretty(&forest.params)
            .expect("serialise")
            .replace('\n', "\n              ")
    );
    println!(
        "metadata      {}",
        serde_json::to_string_pretty(&metadata)
            .expect("serialise")
            .replace('\n', "\n              ")
    );
    println!("per tree      nodes / leaves / depth / votes");
    for (i, t) in forest.trees.iter().enumerate() {
        println!(
            "  {i:>4}        {} / {} / {} / {}",
            t.nodes.len(),
            t.n_leaves(),
            t.depth(),
            t.votes.len()
        );
    }
    Ok(())
}
