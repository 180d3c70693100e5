//! Reading the CLI's inputs: depth PNGs, intrinsics (flags, BOP `scene_camera.json` or BOP
//! `camera.json`), BOP scene and split folders and their `scene_gt.json`. Depth units, the size
//! check and the warnings are the core's (`isa_core::depth_input`). Every error names the file
//! and what was wrong.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::json;

use isa_core::depth_input::{self, DepthValues};
use isa_core::vote::Intrinsics;
use isa_core::{DepthParams, Valid};

use crate::commands::predict::ImageJob;
use crate::error::{CliError, CliResult};

/// A depth image in millimetres, and what looked wrong about it.
pub struct Depth {
    pub width: usize,
    pub height: usize,
    pub mm: Vec<u16>,
    pub warnings: Vec<String>,
}

/// The stored values of a 16-bit single-channel PNG, and its width and height.
fn read_png16(path: &Path) -> CliResult<(Vec<u16>, usize, usize)> {
    if !path.exists() {
        return Err(CliError::missing(path, "depth image"));
    }
    let img = image::ImageReader::open(path)
        .map_err(|e| CliError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| CliError::io(path, e))?
        .decode()
        .map_err(|e| {
            CliError::input(format!(
                "depth image {}: cannot decode: {e}",
                path.display()
            ))
        })?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    match img {
        image::DynamicImage::ImageLuma16(buf) => Ok((buf.into_raw(), width, height)),
        other => Err(CliError::input(format!(
            "depth image {}: expected a 16-bit single-channel PNG (uint16 millimetres, or units of --depth-scale), got {:?}",
            path.display(),
            other.color()
        ))),
    }
}

/// Reads the depth PNG of `job` in millimetres (by its depth parameters), checked against its
/// intrinsics and stated size; the core's warnings (implausible range, looks transposed) are
/// kept and printed to standard error.
pub fn read_depth(job: &ImageJob) -> CliResult<Depth> {
    let (raw, width, height) = read_png16(&job.path)?;
    let at = |m: String| format!("depth image {}: {m}", job.path.display());
    let mut warnings = Vec::new();
    let size = depth_input::check_image_size(&job.k, width, height, job.expected, &job.source)
        .map_err(|e| CliError::input(at(e.to_string())))?;
    warnings.extend(size);
    let (mm, summary) = depth_input::to_mm(DepthValues::U16(&raw), &job.depth);
    warnings.extend(summary.warning());
    for w in &warnings {
        crate::error::warn(&at(w.clone()));
    }
    Ok(Depth {
        width,
        height,
        mm,
        warnings,
    })
}

/// The depth parameters of an image: the core's defaults, overlaid with the camera file's
/// `depth_scale` (if it has one, with its name), overlaid with `--depth-scale`.
pub fn depth_params(
    camera: Option<(f64, &str)>,
    flag: Option<f64>,
) -> CliResult<Valid<DepthParams>> {
    let mut p = DepthParams::default();
    if let Some((s, source)) = camera {
        p.overlay(&json!({ "depth_scale": s }), source)?;
    }
    if let Some(s) = flag {
        p.overlay(&json!({ "depth_scale": s }), crate::commands::FLAGS)?;
    }
    p.check().map_err(|e| {
        CliError::param(format!(
            "{e} (--depth-scale, or the camera file's depth_scale)"
        ))
    })
}

/// A JSON file; `what` names it in messages, `invalid` makes the error for bad JSON (an input
/// or a parameter error, by what the file is).
pub fn read_json(
    path: &Path,
    what: &str,
    invalid: fn(String) -> CliError,
) -> CliResult<serde_json::Value> {
    if !path.exists() {
        return Err(CliError::missing(path, what));
    }
    let text = std::fs::read_to_string(path).map_err(|e| CliError::io(path, e))?;
    serde_json::from_str(&text)
        .map_err(|e| invalid(format!("{what} {}: not valid JSON: {e}", path.display())))
}

/// A camera file: BOP `scene_camera.json` (per image id: `cam_K`, `depth_scale`) or BOP
/// `camera.json` (one camera: `fx, fy, cx, cy, width, height, depth_scale`).
pub enum CameraFile {
    /// Per image id: intrinsics and depth scale (if the file gives one).
    Scene(PathBuf, BTreeMap<u64, (Intrinsics, Option<f64>)>),
    /// One camera for every image: intrinsics, image size, depth scale (if given).
    Single(Intrinsics, Option<(usize, usize)>, Option<f64>),
}

impl CameraFile {
    pub fn read(path: &Path) -> CliResult<CameraFile> {
        let v = read_json(path, "camera file", CliError::input)?;
        let bad = |m: String| CliError::input(format!("camera file {}: {m}", path.display()));
        let obj = v
            .as_object()
            .ok_or_else(|| bad("expected a JSON object".into()))?;
        let num = |o: &serde_json::Map<String, serde_json::Value>, k: &str| -> CliResult<f64> {
            o.get(k)
                .and_then(|x| x.as_f64())
                .ok_or_else(|| bad(format!("missing number {k:?}")))
        };
        if obj.contains_key("fx") {
            let k = Intrinsics {
                fx: num(obj, "fx")?,
                fy: num(obj, "fy")?,
                cx: num(obj, "cx")?,
                cy: num(obj, "cy")?,
            };
            k.validate().map_err(|e| bad(e.to_string()))?;
            let size = match (
                obj.get("width").and_then(|x| x.as_u64()),
                obj.get("height").and_then(|x| x.as_u64()),
            ) {
                (Some(w), Some(h)) => Some((w as usize, h as usize)),
                _ => None,
            };
            let scale = obj.get("depth_scale").and_then(|x| x.as_f64());
            return Ok(CameraFile::Single(k, size, scale));
        }
        let mut map = BTreeMap::new();
        for (key, entry) in obj {
            let id: u64 = key
                .parse()
                .map_err(|_| bad(format!("key {key:?} is not an image id")))?;
            let e = entry
                .as_object()
                .ok_or_else(|| bad(format!("entry {key}: expected an object")))?;
            let km: Vec<f64> = e
                .get("cam_K")
                .and_then(|x| x.as_array())
                .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
                .unwrap_or_default();
            if km.len() != 9 {
                return Err(bad(format!("entry {key}: cam_K must be 9 numbers")));
            }
            let k = Intrinsics::from_matrix([
                [km[0], km[1], km[2]],
                [km[3], km[4], km[5]],
                [km[6], km[7], km[8]],
            ])
            .map_err(|e| bad(format!("entry {key}: {e}")))?;
            let scale = e.get("depth_scale").and_then(|x| x.as_f64());
            map.insert(id, (k, scale));
        }
        if map.is_empty() {
            return Err(bad("no cameras in the file".into()));
        }
        Ok(CameraFile::Scene(path.to_path_buf(), map))
    }

    /// Intrinsics, expected size and depth scale of image `id`.
    // A plain tuple: its two callers destructure it at once.
    #[allow(clippy::type_complexity)]
    pub fn for_image(
        &self,
        id: Option<u64>,
    ) -> CliResult<(Intrinsics, Option<(usize, usize)>, Option<f64>)> {
        match self {
            CameraFile::Single(k, size, scale) => Ok((*k, *size, *scale)),
            CameraFile::Scene(path, map) => {
                let id = id.ok_or_else(|| {
                    CliError::input(format!(
                        "camera file {}: holds one camera per image id; name the image by id (depth/000012.png) or pass --image-id",
                        path.display()
                    ))
                })?;
                map.get(&id).map(|(k, s)| (*k, None, *s)).ok_or_else(|| {
                    CliError::input(format!(
                        "camera file {}: no camera for image id {id}",
                        path.display()
                    ))
                })
            }
        }
    }
}

/// Image id from a BOP file name (`000012.png` -> 12).
pub fn id_from_stem(path: &Path) -> Option<u64> {
    path.file_stem()?.to_str()?.parse().ok()
}

/// The depth PNGs of a BOP scene folder (`DIR/depth/*.png`), sorted, and its camera file.
pub fn scene_folder(dir: &Path) -> CliResult<(Vec<PathBuf>, PathBuf)> {
    if !dir.is_dir() {
        return Err(CliError::missing(dir, "BOP scene folder"));
    }
    let cam = dir.join("scene_camera.json");
    if !cam.exists() {
        return Err(CliError::missing(&cam, "scene camera file"));
    }
    let depth_dir = dir.join("depth");
    let rd = std::fs::read_dir(&depth_dir).map_err(|e| CliError::io(&depth_dir, e))?;
    let mut files: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(CliError::input(format!(
            "BOP scene folder {}: no PNG in depth/",
            dir.display()
        )));
    }
    Ok((files, cam))
}

/// Scene folders of `dirs`: each a BOP scene folder (it has `scene_camera.json`) or a split
/// folder whose subfolders are (all of them, sorted).
pub fn scene_folders(dirs: &[PathBuf]) -> CliResult<Vec<PathBuf>> {
    let mut out = Vec::new();
    for dir in dirs {
        if !dir.is_dir() {
            return Err(CliError::missing(dir, "BOP scene folder"));
        }
        if dir.join("scene_camera.json").exists() {
            out.push(dir.clone());
            continue;
        }
        let rd = std::fs::read_dir(dir).map_err(|e| CliError::io(dir, e))?;
        let mut scenes: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("scene_camera.json").exists())
            .collect();
        if scenes.is_empty() {
            return Err(CliError::input(format!(
                "{}: neither a BOP scene folder (no scene_camera.json) nor a split folder of them",
                dir.display()
            )));
        }
        scenes.sort();
        out.extend(scenes);
    }
    Ok(out)
}

/// Per image id, the obj_ids of a scene's `scene_gt.json` (None when it has none).
pub fn scene_gt_obj_ids(dir: &Path) -> CliResult<Option<BTreeMap<u64, Vec<u64>>>> {
    let path = dir.join("scene_gt.json");
    if !path.exists() {
        return Ok(None);
    }
    let v = read_json(&path, "scene ground-truth file", CliError::input)?;
    let bad = || {
        CliError::input(format!(
            "scene ground-truth file {}: expected {{image id: [{{\"obj_id\": ...}}, ...]}}",
            path.display()
        ))
    };
    let mut out = BTreeMap::new();
    for (key, objs) in v.as_object().ok_or_else(bad)? {
        let id: u64 = key.parse().map_err(|_| bad())?;
        let ids = objs
            .as_array()
            .ok_or_else(bad)?
            .iter()
            .map(|o| o.get("obj_id").and_then(|x| x.as_u64()).ok_or_else(bad))
            .collect::<CliResult<Vec<u64>>>()?;
        out.insert(id, ids);
    }
    Ok(Some(out))
}
