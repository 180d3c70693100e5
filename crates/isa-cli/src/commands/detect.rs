//! `isa detect`: several category models (with their shape libraries) over depth PNGs, one
//! ranked list of detections per image (the core's `scene::detect`), as JSON or BOP CSV.

use std::path::PathBuf;

use serde_json::{json, Value};

use isa_core::rotation::pose_matrix;
use isa_core::scene::gravity::rotation_from_up;
use isa_core::scene::{self, Camera, DetectOutput, Ranker, SceneModel, ShapeLibrary};
use isa_core::{DetectParams, Forest, Valid};

use super::predict::{each_image, image_jobs, ImageJob};
use super::{load_model, overlay_sources};
use crate::args::{DetectArgs, DetectFormat};
use crate::error::{CliError, CliResult};
use crate::output;
use crate::progress::{spinner, with_threads};

/// One `--model` with what it needs.
struct Model {
    category: String,
    path: PathBuf,
    forest: Forest,
    shapes: Option<(ShapeLibrary, PathBuf)>,
    ranker: Option<(Ranker, PathBuf)>,
}

/// One image's detections, with its job, the core's warnings about it and its time.
struct FrameResult {
    job: ImageJob,
    warnings: Vec<String>,
    cam: Camera,
    out: DetectOutput,
    secs: f64,
}

fn params(sources: &[(Value, String)]) -> CliResult<Valid<DetectParams>> {
    let mut p = DetectParams::default();
    for (json, source) in sources {
        p.overlay(json, source)?;
    }
    Ok(p.check()?)
}

fn load_models(a: &DetectArgs) -> CliResult<Vec<Model>> {
    let mut out: Vec<Model> = Vec::new();
    for spec in &a.models {
        let (cat, path) = match spec.split_once('=') {
            Some((c, p)) if !c.is_empty() => (Some(c.to_string()), PathBuf::from(p)),
            _ => (None, PathBuf::from(spec)),
        };
        let forest = load_model(&path)?;
        let category = cat
            .or_else(|| forest.metadata.category.clone())
            .ok_or_else(|| {
                CliError::param(format!(
                    "--model {spec}: the model names no category; give CATEGORY={}",
                    path.display()
                ))
            })?;
        if out.iter().any(|m| m.category == category) {
            return Err(CliError::param(format!(
                "--model {spec}: category {category} given twice"
            )));
        }
        let shapes_path = match &a.shapes {
            Some(dir) => dir.join(format!("{category}.shapes.isl")),
            None => path.with_extension("shapes.isl"),
        };
        let shapes = if shapes_path.exists() {
            Some((ShapeLibrary::load(&shapes_path)?, shapes_path))
        } else if a.shapes.is_some() {
            return Err(CliError::missing(&shapes_path, "shape library"));
        } else {
            None
        };
        let ranker_path = match &a.rankers {
            Some(dir) => dir.join(format!("{category}.ranker.json")),
            None => path.with_extension("ranker.json"),
        };
        let ranker = if ranker_path.exists() {
            let text =
                std::fs::read_to_string(&ranker_path).map_err(|e| CliError::io(&ranker_path, e))?;
            let r = Ranker::from_json(&text, &ranker_path.display().to_string())?;
            Some((r, ranker_path))
        } else if a.rankers.is_some() {
            return Err(CliError::missing(&ranker_path, "ranker"));
        } else {
            None
        };
        out.push(Model {
            category,
            path,
            forest,
            shapes,
            ranker,
        });
    }
    Ok(out)
}

fn gravity(a: &DetectArgs) -> CliResult<Option<nalgebra::Matrix3<f64>>> {
    let Some(g) = &a.gravity else { return Ok(None) };
    let &[x, y, z] = g.as_slice() else {
        return Err(CliError::param(format!(
            "--gravity: expected GX,GY,GZ (3 numbers), got {g:?}"
        )));
    };
    let v = nalgebra::Vector3::new(x, y, z);
    if !(v.iter().all(|x| x.is_finite()) && v.norm() > 1e-9) {
        return Err(CliError::param(format!(
            "--gravity: expected a non-zero vector, got {g:?}"
        )));
    }
    Ok(Some(rotation_from_up(&-v)))
}

fn obj_ids(a: &DetectArgs, models: &[Model]) -> CliResult<Vec<u64>> {
    let mut ids: Vec<u64> = (1..=models.len() as u64).collect();
    for spec in &a.obj_id {
        let bad = || CliError::param(format!("--obj-id {spec}: expected CATEGORY=ID"));
        let (c, id) = spec.split_once('=').ok_or_else(bad)?;
        let id: u64 = id.parse().map_err(|_| bad())?;
        let k = models
            .iter()
            .position(|m| m.category == c)
            .ok_or_else(|| CliError::param(format!("--obj-id {spec}: no model of category {c}")))?;
        ids[k] = id;
    }
    Ok(ids)
}

fn detection_json(d: &scene::Detection) -> Value {
    json!({
        "category": d.category, "R": d.r, "t": d.t, "pose": pose_matrix(&d.r, &d.t), "size": d.size, "box_centre": d.box_centre,
        "score": d.score, "support": d.support, "forest_score": d.forest_score, "shape": d.shape,
        "refined": d.refined,
    })
}

fn to_json(models: &[Model], params: &DetectParams, results: &[FrameResult]) -> String {
    let images: Vec<Value> = results
        .iter()
        .map(|FrameResult { job, warnings, cam, out, secs }| {
            json!({
                "depth": job.path.display().to_string(),
                "image_id": job.id,
                "width": cam.width,
                "height": cam.height,
                "intrinsics": job.k,
                "gravity": scene::rows(&out.gravity),
                "gravity_source": out.gravity_source.name(),
                "floor_height": out.floor_height,
                "seconds": secs,
                "warnings": warnings,
                "stages": out.seconds.iter().map(|(k, v)| (k.to_string(), json!(v))).collect::<serde_json::Map<_, _>>(),
                "detections": out.detections.iter().map(detection_json).collect::<Vec<_>>(),
            })
        })
        .collect();
    let doc = json!({
        "isa_version": isa_core::VERSION,
        "models": models.iter().map(|m| json!({
            "category": m.category, "model": m.path.display().to_string(),
            "shapes": m.shapes.as_ref().map(|s| s.1.display().to_string()),
            "ranker": m.ranker.as_ref().map(|r| r.1.display().to_string()),
        })).collect::<Vec<_>>(),
        "units": units(),
        "params": params,
        "images": images,
    });
    serde_json::to_string_pretty(&doc).expect("serialise") + "\n"
}

fn units() -> Value {
    let mut u = output::UNITS.clone();
    u["size"] = json!("metres, along the object's x, y, z");
    u["gravity"] = json!("camera -> upright (z up)");
    u
}

fn to_bop(
    models: &[Model],
    ids: &[u64],
    scene_id: u64,
    results: &[FrameResult],
) -> CliResult<String> {
    let mut s = String::from(output::BOP_HEADER);
    for FrameResult { job, out, secs, .. } in results {
        let im_id = output::bop_image_id(job)?;
        for d in &out.detections {
            let k = models
                .iter()
                .position(|m| m.category == d.category)
                .expect("a model's category");
            s += &output::bop_row([scene_id, im_id, ids[k]], d.score, &d.r, &d.t, *secs);
        }
    }
    Ok(s)
}

pub fn run(a: DetectArgs) -> CliResult<()> {
    let sources = overlay_sources(&a.common)?;
    let params = params(&sources)?; // bad flags or parameter files fail before a model is read
    let g = gravity(&a)?;
    let jobs = image_jobs(&a.depth, &a.camera)?;
    let pb = spinner(
        a.common.run.quiet,
        format!("loading {} models", a.models.len()),
    );
    let models = load_models(&a)?;
    pb.finish_and_clear();
    let ids = obj_ids(&a, &models)?;
    let scene_models = models
        .iter()
        .map(|m| {
            SceneModel::from_forest(
                &m.category,
                &m.forest,
                m.shapes.as_ref().map(|s| &s.0),
                &m.path.display().to_string(),
            )
            .map(|sm| SceneModel {
                ranker: m.ranker.as_ref().map(|r| &r.0),
                ..sm
            })
            .map_err(|e| CliError::input(e.to_string()))
        })
        .collect::<CliResult<Vec<_>>>()?;
    let results = each_image(jobs, a.common.run.quiet, "detecting", |job, d| {
        let metres: Vec<f32> = d.mm.iter().map(|&v| f32::from(v) / 1000.0).collect();
        let cam = Camera::new(job.k, d.width, d.height)?;
        let t0 = std::time::Instant::now();
        let out = with_threads(a.common.run.threads, || {
            scene::detect(&metres, cam, &scene_models, g, None, &params)
        })??;
        let secs = t0.elapsed().as_secs_f64();
        Ok(FrameResult {
            job,
            warnings: d.warnings,
            cam,
            out,
            secs,
        })
    })?;
    let text = match a.format {
        DetectFormat::Json => to_json(&models, &params, &results),
        DetectFormat::Bop => to_bop(&models, &ids, a.scene_id, &results)?,
    };
    output::write(a.common.output.as_deref(), &text)
}
