//! The command line (clap). Parameter flags are named as the core's parameter fields and carry
//! no defaults of their own: their help shows the core's `Default` values, and what is given is
//! overlaid on the defaults (and, for `predict`, on the model's) by the core's JSON overlay.

use std::fmt::Display;
use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};
use serde::Serialize;

use isa_core::{DetectParams, ForestParams, PredictParams};

pub const EXIT_CODES: &str = "\
Exit codes:
  0  success
  1  unexpected failure
  2  bad command line (unknown option, missing argument)
  3  a file is missing or cannot be read/written (the message names it)
  4  an input is invalid: corrupt or foreign model/training-set file, depth image that is not
     16-bit single-channel or does not fit its intrinsics, malformed camera JSON
  5  a parameter value is invalid (the message names the parameter)
  130  interrupted (SIGINT/Ctrl-C; shells report 128 + the signal): outputs are written
     atomically, so each is the old file or absent, never half-written
A closed standard output (`isa inspect m | head`) ends the command quietly with 0.";

/// A flag's number, refused (by clap, naming the flag, exit 2) unless finite: NaN and
/// infinities would pass through the JSON overlay as `null`.
fn finite<T: std::str::FromStr + Into<f64> + Copy>(s: &str) -> Result<T, String>
where
    T::Err: Display,
{
    let v: T = s.parse().map_err(|e: T::Err| e.to_string())?;
    if v.into().is_finite() {
        Ok(v)
    } else {
        Err("not a finite number".into())
    }
}

/// `text [default: value]`, the value taken from the core's defaults.
fn dflt(text: &str, value: impl Display) -> String {
    format!("{text} [default: {value}]")
}

/// `text [default: the model's, else value]` for inference parameters.
fn model_dflt(text: &str, value: impl Display) -> String {
    format!("{text} [default: the model's, else {value}]")
}

fn fp() -> ForestParams {
    ForestParams::default()
}

fn pp() -> PredictParams {
    PredictParams::default()
}

fn dp() -> DetectParams {
    DetectParams::default()
}

/// Category-level 6D object pose from depth images (Intrinsic Structure Adaptor, ISA).
///
/// A forest trained on depth images of one object category (`isa train`) votes for the 6D pose
/// (rotation R, translation t of the category's semantically selected centre, X_cam = R X_obj + t)
/// of unseen instances in whole depth images (`isa predict`). `isa inspect` shows what a model
/// file holds. `isa detect` runs several category models over a room frame: every object with
/// its category, 6D pose, size and a score comparable across categories.
#[derive(Parser)]
#[command(name = "isa", version = isa_core::VERSION, after_help = EXIT_CODES)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    Train(TrainArgs),
    Predict(PredictArgs),
    Detect(DetectArgs),
    Inspect(InspectArgs),
}

/// Train a forest from a training-set file (.isat, written by Python's
/// `isa._core.TrainSet.write`) and save it as a model file.
///
/// Training parameters: the defaults of isa_core::ForestParams, overridden by `--params` (a
/// JSON object with any subset of the fields), overridden by the flags below.
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
pub struct TrainArgs {
    /// Training-set file (.isat): depth crops, parts, offsets, rotations, optional link angles
    /// and node offsets, metadata (format: docs/CLI.md).
    pub trainset: PathBuf,
    /// Where to write the model file (written atomically).
    #[arg(short, long, value_name = "MODEL")]
    pub output: PathBuf,
    /// JSON file of forest parameters (any subset of the ForestParams fields).
    #[arg(long, value_name = "JSON")]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub flags: TrainFlags,
    #[command(flatten)]
    pub run: RunArgs,
}

/// How a command runs (shared by every command that computes).
#[derive(Args)]
pub struct RunArgs {
    /// Worker threads [default: all cores]. Does not change the output.
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress display.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Forest-parameter flags: serialised, the given ones form the "flags" overlay.
#[derive(Args, Serialize)]
pub struct TrainFlags {
    #[arg(long, help = dflt("Number of trees", fp().n_trees))]
    pub n_trees: Option<usize>,
    #[arg(long, help = dflt("Maximum tree depth, root = 0", fp().max_depth))]
    pub max_depth: Option<usize>,
    #[arg(long, help = dflt(
        "Split criterion: Q1, Q1+Q2, Q1+Q3 or Q1+Q2+Q3 (paper Eq. 9-11); Q2 needs link angles and \
         Q3 node offsets in the training set",
        fp().quality.as_str()
    ))]
    pub quality: Option<String>,
    #[arg(long, help = dflt("Random feature candidates per node", fp().n_candidates))]
    pub n_candidates: Option<usize>,
    #[arg(long, help = dflt("Minimum parts in each child of a split", fp().min_samples_leaf))]
    pub min_samples_leaf: Option<usize>,
    #[arg(long, help = dflt("Nodes with fewer parts become leaves", fp().min_samples_split))]
    pub min_samples_split: Option<usize>,
    #[arg(long, value_parser = finite::<f64>, help = dflt("Fraction of the parts each tree trains on, in (0, 1]", fp().bag_fraction))]
    pub bag_fraction: Option<f64>,
    #[arg(long, help = dflt(
        "Seed of every random choice (same seed + data = same model bytes)",
        fp().seed
    ))]
    pub seed: Option<u64>,
}

/// How depth images meet their camera: intrinsics from flags or a camera file, the image id,
/// the depth unit (shared by `isa predict` and `isa detect`).
#[derive(Args)]
pub struct CameraArgs {
    /// Pinhole intrinsics in pixels: FX FY CX CY.
    #[arg(short = 'k', long, num_args = 4, value_names = ["FX", "FY", "CX", "CY"], conflicts_with = "camera",
          allow_negative_numbers = true, value_parser = finite::<f64>)]
    pub intrinsics: Option<Vec<f64>>,
    /// Camera file: a BOP scene_camera.json (per image id: cam_K, depth_scale; the id is the
    /// PNG's file name, e.g. 000012.png, or --image-id) or a BOP camera.json (fx, fy, cx, cy,
    /// width, height, depth_scale; the image size is then checked).
    #[arg(short, long, value_name = "JSON")]
    pub camera: Option<PathBuf>,
    /// Image id for --camera scene_camera.json when the file name is not one [default: from the
    /// file name].
    #[arg(long)]
    pub image_id: Option<u64>,
    #[arg(long, value_parser = finite::<f64>, help = dflt(
        isa_core::params::DEPTH_SCALE_HELP,
        "the camera file's depth_scale, else 1"
    ))]
    pub depth_scale: Option<f64>,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
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
/// a BOP scene folder with `--scene`. Inference parameters: the model's defaults, overridden by
/// `--params`, overridden by the flags. Examples:
///
///   isa predict chair.isaf depth.png -k 525 525 319.5 239.5
///
///   isa predict chair.isaf scene/depth/000012.png --camera scene/scene_camera.json
///
///   isa predict chair.isaf --scene bop/test/000001 --format bop -o results.csv
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
pub struct PredictArgs {
    /// Model file written by `isa train` or Python's `Forest.save`.
    #[arg(value_name = "MODEL")]
    pub model: PathBuf,
    /// Depth images: 16-bit single-channel PNGs in millimetres (times --depth-scale or the
    /// camera's depth_scale), 0 = missing.
    #[arg(value_name = "PNG", conflicts_with = "scene")]
    pub depth: Vec<PathBuf>,
    #[command(flatten)]
    pub camera: CameraArgs,
    /// BOP scene folders (every depth/*.png with its scene_camera.json), or a split folder
    /// holding them (every scene): one results file with one header. Repeatable.
    #[arg(long, value_name = "DIR", num_args = 1..)]
    pub scene: Vec<PathBuf>,
    /// BOP scene id for --format bop [default: the --scene folder's name if a number, else 0].
    #[arg(long)]
    pub scene_id: Option<u64>,
    /// BOP object id for --format bop [default: the model's metadata "obj_id", else the one
    /// object of the image's category in the scene's scene_gt.json].
    #[arg(long)]
    pub obj_id: Option<u64>,
    /// Method name in the BOP results file name, `METHOD_DATASET-SPLIT.csv`, written when -o is
    /// a folder (DATASET and SPLIT from the --scene path, `.../DATASET/SPLIT/SCENE`).
    #[arg(long, default_value = "isa")]
    pub method: String,
    /// Output format.
    #[arg(short, long, value_enum, default_value_t = Format::Json)]
    pub format: Format,
    #[command(flatten)]
    pub common: InferenceArgs<PredictFlags>,
}

/// The options `predict` and `detect` both end with: --output, the command's parameter flags
/// `F`, --params and the run options. The help of --output and --params is the command's own
/// ([`ParamFlags`]): what each writes and what its parameter file holds differ. Clap drops the
/// final period of a one-paragraph doc comment, so those constants end without one.
#[derive(Args)]
pub struct InferenceArgs<F: ParamFlags> {
    #[arg(short, long, value_name = "FILE", help = F::OUTPUT_HELP)]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub flags: F,
    #[arg(long, value_name = "JSON", help = F::PARAMS_HELP)]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// A command's parameter flags (serialised, the given ones form the "flags" overlay), with the
/// help of its --output and --params.
pub trait ParamFlags: Args + Serialize {
    const OUTPUT_HELP: &'static str;
    const PARAMS_HELP: &'static str;
}

impl ParamFlags for PredictFlags {
    const OUTPUT_HELP: &'static str = "Output file [default: standard output]; with --format bop \
        a folder gets the file bop_toolkit expects, METHOD_DATASET-SPLIT.csv";
    const PARAMS_HELP: &'static str = "JSON file of inference parameters (fields of \
        PredictParams, with mode finding under \"vote\" or flat); flags override it";
}

impl ParamFlags for DetectFlags {
    const OUTPUT_HELP: &'static str = "Output file [default: standard output]";
    const PARAMS_HELP: &'static str = "JSON file of detection parameters (fields of \
        DetectParams: nested planes, verify, refine, proposals; null switches verify, refine or \
        proposals off); flags override it";
}

/// Inference-parameter flags (flat keys of PredictParams): the given ones form the "flags"
/// overlay.
#[derive(Args, Serialize)]
pub struct PredictFlags {
    #[arg(long, help = model_dflt("Parts on every STRIDE-th pixel in u and v", pp().stride))]
    pub stride: Option<usize>,
    // allow_hyphen_values: a value such as -inf reaches the finite check (and its message)
    // instead of reading as short flags.
    #[arg(long, allow_hyphen_values = true, value_parser = finite::<f32>,
          help = model_dflt("Ignore pixels nearer than this, metres", pp().min_depth))]
    pub min_depth: Option<f32>,
    #[arg(long, value_parser = finite::<f32>, help = model_dflt(
        "Ignore pixels farther than this, metres",
        pp().max_depth.map_or("no limit".to_string(), |m| m.to_string())
    ))]
    pub max_depth: Option<f32>,
    #[arg(long, value_parser = finite::<f32>, help = model_dflt(
        "Radius of the position kernel and grid cell, metres",
        pp().vote.position_bandwidth
    ))]
    pub position_bandwidth: Option<f32>,
    #[arg(long, value_parser = finite::<f32>, help = model_dflt(
        "Geodesic radius of the rotation kernel, radians",
        pp().vote.rotation_bandwidth
    ))]
    pub rotation_bandwidth: Option<f32>,
    #[arg(long, help = model_dflt("Hypotheses per image at most", pp().vote.max_hypotheses))]
    pub max_hypotheses: Option<usize>,
    #[arg(long, value_parser = finite::<f32>, help = model_dflt(
        "Positions closer than this to a better hypothesis are suppressed, metres",
        pp().vote.nms_radius
    ))]
    pub nms_radius: Option<f32>,
    #[arg(long, help = model_dflt(
        "Rotation modes per position (for symmetric objects)",
        pp().vote.rotations_per_position
    ))]
    pub rotations_per_position: Option<usize>,
    #[arg(long, help = model_dflt(
        "Drop hypotheses supported by fewer votes",
        pp().vote.min_support
    ))]
    pub min_support: Option<usize>,
}

/// Show what a model file holds: format and crate versions, training parameters, inference
/// defaults, metadata (category, SSC, ...), and the size of every tree.
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
pub struct InspectArgs {
    /// Model file.
    pub model: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Output format of `isa detect`.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DetectFormat {
    /// One JSON document: per image, its detections (category, R row-major, t in metres, size
    /// along the object's axes, box centre in the object frame, score, support), the gravity
    /// used, the floor's height, the parameters and the time per stage.
    Json,
    /// BOP challenge results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in mm),
    /// one row per detection, obj_id by category (--obj-id).
    Bop,
}

/// Detect every object of several categories in room depth images: one ranked list of 6D poses
/// with sizes (a 9D pose) and scores comparable across categories and frames.
///
/// Per frame: gravity (--gravity, else the floor's normal, else the votes), floor and walls
/// found and removed for the voting, each category forest votes, hypotheses are snapped upright,
/// set on the floor, verified against the category's training shapes (`<model>.shapes.isl`
/// beside the model, or in --shapes DIR as `<category>.shapes.isl`; without one the forest's
/// score and box are used), sized, refined by ICP, suppressed across categories, and scored by
/// each category's ranker when it has one (`<model>.ranker.json`, or in --rankers DIR as
/// `<category>.ranker.json`; fitted by `python -m isa.detection.ranking`). Parameters:
/// the core's DetectParams, overridden by `--params`, overridden by the flags. Example:
///
///   isa detect --model chair.isa --model table.isa depth.png --camera camera.json --gravity 0,1,0
#[derive(Args)]
#[command(after_help = EXIT_CODES)]
pub struct DetectArgs {
    /// Category model: PATH or CATEGORY=PATH (default category: the model's metadata). Repeat
    /// for every category.
    #[arg(
        short,
        long = "model",
        value_name = "[CATEGORY=]MODEL",
        required = true
    )]
    pub models: Vec<String>,
    /// Depth images: 16-bit single-channel PNGs in millimetres (times --depth-scale or the
    /// camera's depth_scale), 0 = missing.
    #[arg(value_name = "PNG", required = true)]
    pub depth: Vec<PathBuf>,
    #[command(flatten)]
    pub camera: CameraArgs,
    /// Gravity in camera coordinates (OpenCV: x right, y down, z forward), any length, e.g.
    /// 0,1,0 for a level camera [default: the floor's normal, else the votes' up axis].
    #[arg(
        long,
        value_name = "GX,GY,GZ",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub gravity: Option<Vec<f64>>,
    /// Folder of shape libraries `<category>.shapes.isl` [default: `<model>.shapes.isl` beside
    /// each model].
    #[arg(long, value_name = "DIR")]
    pub shapes: Option<PathBuf>,
    /// Folder of rankers `<category>.ranker.json` [default: `<model>.ranker.json` beside each
    /// model, when it exists].
    #[arg(long, value_name = "DIR")]
    pub rankers: Option<PathBuf>,
    /// BOP scene id for --format bop.
    #[arg(long, default_value_t = 0)]
    pub scene_id: u64,
    /// BOP object id of a category for --format bop, CATEGORY=ID, repeatable [default: the
    /// models' order, from 1].
    #[arg(long, value_name = "CATEGORY=ID")]
    pub obj_id: Vec<String>,
    /// Output format.
    #[arg(short, long, value_enum, default_value_t = DetectFormat::Json)]
    pub format: DetectFormat,
    #[command(flatten)]
    pub common: InferenceArgs<DetectFlags>,
}

/// Detection-parameter flags (fields of DetectParams): the given ones form the "flags" overlay.
#[derive(Args, Serialize)]
pub struct DetectFlags {
    #[arg(long, help = dflt("Parts on every STRIDE-th pixel of each forest's voting", dp().stride))]
    pub stride: Option<usize>,
    #[arg(long, help = dflt("Hypotheses per category forest", dp().max_hypotheses))]
    pub max_hypotheses: Option<usize>,
    #[arg(long, help = dflt("Detections per image at most", dp().max_detections))]
    pub max_detections: Option<usize>,
    #[arg(long, help = dflt("Hypotheses refined per category", dp().refine_top))]
    pub refine_top: Option<usize>,
    #[arg(long, help = dflt("Cross-category NMS: IoU above which a box goes", dp().nms_iou))]
    pub nms_iou: Option<f64>,
    #[arg(
        long,
        help = "Drop detections whose verified score (before ranking) is below this [default: none]"
    )]
    pub min_score: Option<f64>,
}
