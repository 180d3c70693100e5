//! `isa predict`: depth PNGs (or BOP scene or split folders) and their intrinsics, the model's inference
//! defaults overlaid by `--params` and the flags (the core's overlay), ranked hypotheses out.

use std::path::PathBuf;
use std::time::Instant;

use serde_json::Value;

use isa_core::vote::{self, DepthImage, Intrinsics};
use isa_core::{DepthParams, PredictParams, Valid};

use super::{load_model, overlay_sources};
use crate::args::{CameraArgs, PredictArgs};
use crate::error::{CliError, CliResult};
use crate::inputs;
use crate::output::{self, ImageResult};
use crate::progress::{bar, spinner, with_threads};

/// One depth image to run, with its camera and depth parameters.
pub struct ImageJob {
    pub path: PathBuf,
    pub id: Option<u64>,
    /// BOP scene id (from `--scene-id`, else the scene folder's name).
    pub scene_id: Option<u64>,
    pub k: Intrinsics,
    pub expected: Option<(usize, usize)>,
    pub depth: Valid<DepthParams>,
    pub source: String,
    /// The obj_ids of the image's ground truth (a scene's `scene_gt.json`), if known.
    pub gt_obj_ids: Option<Vec<u64>>,
}

/// `base` overlaid with the parameter file and the flags, checked.
fn params_over(
    base: &Valid<PredictParams>,
    sources: &[(Value, String)],
) -> CliResult<Valid<PredictParams>> {
    let mut p = base.clone().into_inner();
    for (json, source) in sources {
        p.overlay(json, source)?;
    }
    // Name the flag in the message (fields and flags share names).
    p.check()
        .map_err(|e| CliError::param(format!("{e} (flag --{})", flag_of(&e.to_string()))))
}

fn flag_of(msg: &str) -> String {
    let field = msg
        .trim_start_matches("invalid parameter: ")
        .split_whitespace()
        .next()
        .unwrap_or("");
    field.replace('_', "-")
}

fn jobs(a: &PredictArgs) -> CliResult<Vec<ImageJob>> {
    if !a.scene.is_empty() {
        let mut out = Vec::new();
        for dir in inputs::scene_folders(&a.scene)? {
            let (files, cam_path) = inputs::scene_folder(&dir)?;
            let cam = inputs::CameraFile::read(&cam_path)?;
            let gt = inputs::scene_gt_obj_ids(&dir)?;
            let scene_id = a
                .scene_id
                .or_else(|| dir.file_name()?.to_str()?.parse().ok());
            let source = cam_path.display().to_string();
            for f in files {
                let id = inputs::id_from_stem(&f);
                let (k, expected, scale) = cam.for_image(id)?;
                out.push(ImageJob {
                    path: f,
                    id,
                    scene_id,
                    k,
                    expected,
                    depth: inputs::depth_params(
                        scale.map(|s| (s, source.as_str())),
                        a.camera.depth_scale,
                    )?,
                    source: source.clone(),
                    gt_obj_ids: gt.as_ref().and_then(|g| g.get(&id?).cloned()),
                });
            }
        }
        return Ok(out);
    }
    if a.depth.is_empty() {
        return Err(CliError::param(
            "give depth images (isa predict MODEL PNG...) or a BOP scene folder with --scene DIR"
                .into(),
        ));
    }
    let mut out = image_jobs(&a.depth, &a.camera)?;
    for j in &mut out {
        j.scene_id = a.scene_id;
    }
    Ok(out)
}

/// The jobs of depth PNGs with their camera: a BOP camera file or `--intrinsics FX FY CX CY`;
/// `--image-id` names a single image (else the file names do).
pub fn image_jobs(depth: &[PathBuf], c: &CameraArgs) -> CliResult<Vec<ImageJob>> {
    let camera = c.camera.as_deref();
    let cam = camera.map(inputs::CameraFile::read).transpose()?;
    let mut out = Vec::new();
    for f in depth {
        let id = c
            .image_id
            .filter(|_| depth.len() == 1)
            .or_else(|| inputs::id_from_stem(f));
        let (k, expected, scale, source) = match (&cam, c.intrinsics.as_deref()) {
            (Some(cf), _) => {
                let (k, e, s) = cf.for_image(id)?;
                (k, e, s, camera.unwrap().display().to_string())
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
                (k, None, None, "--intrinsics".to_string())
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
            scene_id: None,
            k,
            expected,
            depth: inputs::depth_params(scale.map(|s| (s, source.as_str())), c.depth_scale)?,
            source,
            gt_obj_ids: None,
        });
    }
    Ok(out)
}

/// The obj_id written for `job`'s rows: `--obj-id`, else the model's metadata `obj_id`, else
/// the single object of the image's ground truth.
fn obj_id(a: &PredictArgs, forest: &isa_core::Forest, job: &ImageJob) -> CliResult<u64> {
    if let Some(id) = a
        .obj_id
        .or_else(|| forest.metadata.extra.get("obj_id")?.as_u64())
    {
        return Ok(id);
    }
    match job.gt_obj_ids.as_deref() {
        Some([id]) => Ok(*id),
        Some(ids) if !ids.is_empty() && ids.iter().all(|i| i == &ids[0]) => Ok(ids[0]),
        _ => Err(CliError::param(format!(
            "--format bop: no obj_id for {}: the model's metadata has none and the scene's scene_gt.json does not name exactly one object for it; pass --obj-id",
            job.path.display()
        ))),
    }
}

/// `each(job, its depth image)` for every job in order, behind a progress bar saying `what`
/// (shown for two or more images unless `quiet`); the first error ends the run.
pub fn each_image<R>(
    jobs: Vec<ImageJob>,
    quiet: bool,
    what: &str,
    mut each: impl FnMut(ImageJob, inputs::Depth) -> CliResult<R>,
) -> CliResult<Vec<R>> {
    let pb = bar(quiet || jobs.len() < 2, jobs.len() as u64, what);
    let mut results = Vec::with_capacity(jobs.len());
    for job in jobs {
        let d = inputs::read_depth(&job)?;
        results.push(each(job, d)?);
        pb.inc(1);
    }
    pb.finish_and_clear();
    Ok(results)
}

pub fn run(a: PredictArgs) -> CliResult<()> {
    let sources = overlay_sources(&a.common)?;
    params_over(&Valid::default(), &sources)?; // bad flags or parameter files fail before a model is read
    let jobs = jobs(&a)?;
    let pb = spinner(a.common.run.quiet, format!("loading {}", a.model.display()));
    let forest = load_model(&a.model)?;
    pb.finish_and_clear();
    let params = params_over(&forest.predict_defaults, &sources)?;
    if forest.n_trees() == 0 {
        return Err(CliError::input(format!(
            "model file {}: the forest has no trees",
            a.model.display()
        )));
    }
    let results = each_image(jobs, a.common.run.quiet, "predicting", |job, d| {
        let obj_id = match a.format {
            crate::args::Format::Bop => Some(obj_id(&a, &forest, &job)?),
            crate::args::Format::Json => None,
        };
        let img = DepthImage::new(&d.mm, d.width, d.height)?;
        let t0 = Instant::now();
        let hyps = with_threads(a.common.run.threads, || {
            vote::predict(&forest, &img, &job.k, &params)
        })??;
        let seconds = t0.elapsed().as_secs_f64();
        Ok(ImageResult {
            width: d.width,
            height: d.height,
            warnings: d.warnings,
            obj_id,
            job,
            hyps,
            seconds,
        })
    })?;
    match a.format {
        crate::args::Format::Json => output::write(
            a.common.output.as_deref(),
            &output::predict_json(&a.model, &params, &results),
        ),
        crate::args::Format::Bop => {
            let text = output::bop_csv(&results)?;
            let path = a
                .common
                .output
                .as_deref()
                .map(|o| output::bop_results_path(o, &a.method, &a.scene))
                .transpose()?;
            output::write(path.as_deref(), &text)
        }
    }
}
