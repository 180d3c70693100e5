//! Depth rendering of triangle meshes without OpenGL: what `isa.render.DepthRenderer` draws its
//! training and test frames with (its default backend), so that rendering needs no GL library.
//!
//! [`render_depth`] is a z-buffer rasteriser with the project's camera conventions: the OpenCV
//! pinhole camera of [`Intrinsics`] (x right, y down, z forward, pixel centres at integer
//! `(u, v)`), the pose `X_cam = R X_obj + t`, depth in metres along the optical axis (0 =
//! background), every triangle drawn with both windings (ModelNet's windings are inconsistent,
//! so nothing is culled).
//!
//! How it decides, so that its frames are exact rather than close (`raster.rs` does the work):
//! * **coverage**: a pixel is covered when its centre is inside the projected triangle; a centre
//!   exactly on an edge goes to the triangle whose edge is a top or left edge (the Direct3D
//!   tie rule), and edge functions are evaluated with the edge's endpoints in one canonical
//!   order, so the two triangles sharing an edge get exactly opposite values: every pixel of a
//!   closed fan is covered once, with no gap and no double;
//! * **depth**: `1/z` interpolated in screen space (exact for a plane: perspective-correct), in
//!   `f64`; the nearest triangle wins, the first in face order on an exact tie;
//! * **near and far**: triangles are clipped against `z = znear` (a polygon of up to four
//!   vertices, drawn as a fan); pixels farther than `zfar` are dropped, as clipping at the far
//!   plane would;
//! * **threads**: bands of rows in parallel, each band drawing its triangles in face order, so
//!   the frame is the same bytes for any number of threads.

mod raster;
#[cfg(test)]
mod tests;

use rayon::prelude::*;

use crate::error::{IsaError, Result};
use crate::vote::Intrinsics;

/// Most pixels a frame may have (a guard against a mistyped size allocating gigabytes).
pub const MAX_PIXELS: usize = 1 << 28;

/// A camera for rendering: intrinsics, image size (pixels) and depth range (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderCamera {
    pub k: Intrinsics,
    pub width: usize,
    pub height: usize,
    /// Nearest rendered depth: geometry closer than this is clipped away.
    pub znear: f64,
    /// Farthest rendered depth: pixels beyond it stay background.
    pub zfar: f64,
}

impl RenderCamera {
    /// Focal lengths finite and positive, a non-empty image of at most [`MAX_PIXELS`] pixels,
    /// `0 < znear < zfar`, both finite.
    pub fn validate(&self) -> Result<()> {
        self.k.validate()?;
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Err(IsaError::InvalidInput(format!(
                "width, height: the image must have at least one pixel, got {w}x{h}"
            )));
        }
        if w.checked_mul(h).is_none_or(|n| n > MAX_PIXELS) {
            return Err(IsaError::InvalidInput(format!(
                "width, height: {w}x{h} is more than {MAX_PIXELS} pixels"
            )));
        }
        let (n, f) = (self.znear, self.zfar);
        if !(n.is_finite() && f.is_finite() && n > 0.0 && f > n) {
            return Err(IsaError::InvalidInput(format!(
                "znear, zfar: expected finite 0 < znear < zfar, got znear={n} zfar={f}"
            )));
        }
        Ok(())
    }
}

/// A rendered frame, row-major `height x width`.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthFrame {
    pub width: usize,
    pub height: usize,
    /// Depth along the optical axis, metres; 0 where no triangle is.
    pub depth: Vec<f32>,
    /// Pixels some triangle covers (`depth > 0`).
    pub mask: Vec<bool>,
}

/// Renders the mesh (`vertices` in the object frame, metres; `faces` indexing them) at pose
/// `X_cam = r X_obj + t` through `camera`. Errors name the argument at fault: a face index out
/// of range, a non-finite vertex or pose, an empty image, a bad depth range.
pub fn render_depth(
    vertices: &[[f32; 3]],
    faces: &[[u32; 3]],
    r: &[[f64; 3]; 3],
    t: &[f64; 3],
    camera: &RenderCamera,
) -> Result<DepthFrame> {
    camera.validate()?;
    check_pose(r, t)?;
    check_mesh(vertices, faces)?;
    let cam_points: Vec<[f64; 3]> = vertices
        .par_iter()
        .map(|p| {
            let p = p.map(f64::from);
            std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + t[i])
        })
        .collect();
    if let Some(k) = cam_points
        .iter()
        .position(|p| !p.iter().all(|x| x.is_finite()))
    {
        return Err(IsaError::InvalidInput(format!(
            "R, t: vertices[{k}] = {:?} lands at a non-finite camera point",
            vertices[k]
        )));
    }
    let z = raster::rasterise(&cam_points, faces, camera);
    let depth: Vec<f32> = z
        .par_iter()
        .map(|&z| if z.is_finite() { z as f32 } else { 0.0 })
        .collect();
    let mask = depth.par_iter().map(|&d| d > 0.0).collect();
    Ok(DepthFrame {
        width: camera.width,
        height: camera.height,
        depth,
        mask,
    })
}

fn check_pose(r: &[[f64; 3]; 3], t: &[f64; 3]) -> Result<()> {
    for (i, row) in r.iter().enumerate() {
        if let Some(j) = row.iter().position(|x| !x.is_finite()) {
            return Err(IsaError::InvalidInput(format!(
                "R[{i}, {j}] is not finite ({})",
                row[j]
            )));
        }
    }
    if let Some(i) = t.iter().position(|x| !x.is_finite()) {
        return Err(IsaError::InvalidInput(format!(
            "t[{i}] is not finite ({})",
            t[i]
        )));
    }
    Ok(())
}

fn check_mesh(vertices: &[[f32; 3]], faces: &[[u32; 3]]) -> Result<()> {
    for (k, p) in vertices.iter().enumerate() {
        if let Some(j) = p.iter().position(|x| !x.is_finite()) {
            return Err(IsaError::InvalidInput(format!(
                "vertices[{k}, {j}] is not finite ({})",
                p[j]
            )));
        }
    }
    let n = vertices.len();
    for (k, f) in faces.iter().enumerate() {
        if let Some(j) = f.iter().position(|&i| i as usize >= n) {
            return Err(IsaError::InvalidInput(format!(
                "faces[{k}, {j}] = {} is out of range: there are {n} vertices",
                f[j]
            )));
        }
    }
    Ok(())
}
