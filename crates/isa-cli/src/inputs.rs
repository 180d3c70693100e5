//! Reading the CLI's inputs: depth PNGs, intrinsics (flags, BOP `scene_camera.json` or BOP
//! `camera.json`), BOP scene folders. Every error names the file and what was wrong.

use std::path::{Path, PathBuf};

use isa_core::vote::Intrinsics;

use crate::error::{CliError, CliResult};

/// A depth image in millimetres plus where it came from.
pub struct Depth {
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    pub mm: Vec<u16>,
}

/// Reads a 16-bit single-channel PNG; `scale` converts its values to millimetres (BOP's
/// `depth_scale`; 1 for plain uint16 mm).
pub fn read_depth_png(path: &Path, scale: f64) -> CliResult<Depth> {
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
    let mm: Vec<u16> = match img {
        image::DynamicImage::ImageLuma16(buf) => buf.into_raw(),
        other => {
            return Err(CliError::input(format!(
            "depth image {}: expected a 16-bit single-channel PNG (uint16 millimetres), got {:?}",
            path.display(),
            other.color()
        )))
        }
    };
    let mm = if (scale - 1.0).abs() < 1e-12 {
        mm
    } else {
        mm.into_iter()
            .map(|v| (f64::from(v) * scale).round().min(65535.0) as u16)
            .collect()
    };
    Ok(Depth {
        path: path.to_path_buf(),
        width,
        height,
        mm,
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
    /// Per image id: intrinsics and depth scale.
    Scene(PathBuf, std::collections::BTreeMap<u64, (Intrinsics, f64)>),
    /// One camera for every image: intrinsics, image size, depth scale.
    Single(Intrinsics, Option<(usize, usize)>, f64),
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
            let scale = obj
                .get("depth_scale")
                .and_then(|x| x.as_f64())
                .unwrap_or(1.0);
            return Ok(CameraFile::Single(k, size, scale));
        }
        let mut map = std::collections::BTreeMap::new();
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
            let scale = e.get("depth_scale").and_then(|x| x.as_f64()).unwrap_or(1.0);
            if !(scale.is_finite() && scale > 0.0) {
                return Err(bad(format!(
                    "entry {key}: depth_scale must be > 0, got {scale}"
                )));
            }
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
    ) -> CliResult<(Intrinsics, Option<(usize, usize)>, f64)> {
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

/// Checks an image against its intrinsics (and an expected size): a principal point outside the
/// image means the image and the intrinsics do not belong together.
pub fn check_size(
    d: &Depth,
    k: &Intrinsics,
    expected: Option<(usize, usize)>,
    source: &str,
) -> CliResult<()> {
    if let Some((w, h)) = expected {
        if (w, h) != (d.width, d.height) {
            return Err(CliError::input(format!(
                "depth image {} is {}x{} (width x height), but {source} says {w}x{h}: wrong-size image",
                d.path.display(),
                d.width,
                d.height
            )));
        }
    }
    if k.validate_for(d.width, d.height).is_err() {
        return Err(CliError::input(format!(
            "depth image {} is {}x{} (width x height), but the principal point ({}, {}) of {source} lies outside it: wrong-size image for these intrinsics",
            d.path.display(),
            d.width,
            d.height,
            k.cx,
            k.cy
        )));
    }
    Ok(())
}
