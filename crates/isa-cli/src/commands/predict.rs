//! `isa predict`: depth PNGs (or a BOP scene folder) and their intrinsics, the model's inference
//! defaults overlaid by `--params` and the flags (the core's overlay), ranked hypotheses out.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde_json::Value;

use isa_core::vote::{self, DepthImage, Intrinsics};
use isa_core::{PredictParams, Valid};

use super::{flags_json, load_model, params_file, FLAGS};
use crate::args::PredictArgs;
use crate::error::{CliError, CliResult};
use crate::inputs;
use crate::output::{self, ImageResult};
use crate::progress::{bar, spinner, with_threads};

/// One depth image to run, with its camera.
pub struct ImageJob {
    pub path: PathBuf,
    pub id: Option<u64>,
    pub k: Intrinsics,
    pub expected: Option<(usize, usize)>,
    pub scale: f64,
    pub source: String,
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
    Ok((
        image_jobs(&a.depth, a.camera.as_deref(), a.intrinsics.as_deref(), a.image_id)?,
        a.scene_id,
    ))
}

/// The jobs of depth PNGs with their intrinsics from `camera` (a BOP camera file) or
/// `intrinsics` (FX FY CX CY); `image_id` names a single image (else the file names do).
pub fn image_jobs(
    depth: &[PathBuf],
    camera: Option<&Path>,
    intrinsics: Option<&[f64]>,
    image_id: Option<u64>,
) -> CliResult<Vec<ImageJob>> {
    let cam = camera.map(inputs::CameraFile::read).transpose()?;
    let mut out = Vec::new();
    for f in depth {
        let id = image_id
            .filter(|_| depth.len() == 1)
            .or_else(|| inputs::id_from_stem(f));
        let (k, expected, scale, source) = match (&cam, intrinsics) {
            (Some(c), _) => {
                let (k, e, s) = c.for_image(id)?;
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
    Ok(out)
}

pub fn run(a: PredictArgs) -> CliResult<()> {
    let mut sources: Vec<(Value, String)> = params_file(a.params.as_deref())?.into_iter().collect();
    sources.push((flags_json(&a.flags), FLAGS.to_string()));
    params_over(&Valid::default(), &sources)?; // bad flags or parameter files fail before a model is read
    let (jobs, scene_id) = jobs(&a)?;
    let pb = spinner(a.quiet, format!("loading {}", a.model.display()));
    let forest = load_model(&a.model)?;
    pb.finish_and_clear();
    let params = params_over(&forest.predict_defaults, &sources)?;
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
        crate::args::Format::Json => output::predict_json(&a.model, &params, &results),
        crate::args::Format::Bop => output::bop_csv(&results, scene_id.unwrap_or(0), a.obj_id)?,
    };
    output::write(a.output.as_deref(), &text)
}
