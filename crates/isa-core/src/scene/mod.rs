//! Detection in a room: every category model over one depth frame, one ranked list of 6D poses
//! with sizes (the Rust side of `isa.detection.detect`, and `isa detect`).
//!
//! Stages, in data-flow order (each module holds one):
//! * [`gravity`]: the camera -> upright rotation, given or from the floor's normal (RANSAC);
//! * [`planes`]: floor and walls of the frame in the upright frame (gravity-constrained RANSAC),
//!   set to missing depth for the voting;
//! * votes: each category forest ([`crate::vote::predict`]) on the cleaned depth, hypotheses
//!   snapped upright and set on the floor ([`detect`]);
//! * [`proposals`]: hypotheses from footprints on the floor beside the forests' (optional);
//! * [`verify`]: z-buffered, point-sampled training shapes ([`shapes`]) against the raw depth;
//!   the best shape and a per-axis scale give the score and the size;
//! * [`refine`]: upright ICP (yaw and translation) of the best hypotheses;
//! * [`nms`]: one ranked list, boxes suppressed across categories;
//! * [`ranking`]: the kept detections scored by each category's ranker (optional), from the
//!   earlier stages' measures and the seen surface's [`profile`] in each box.
//!
//! Frames: `R_gravity` maps camera to upright coordinates (`X_up = R_gravity X_cam`, z up); a
//! pose `(R, t)` maps object to camera (`X_cam = R X_obj + t`). All geometry is `f64`.

pub mod detect;
pub mod gravity;
pub mod nms;
pub mod planes;
pub mod profile;
pub mod proposals;
pub mod ranking;
pub mod refine;
pub mod shapes;
pub mod verify;

pub use crate::params::{DetectParams, PlaneParams, ProposalParams, RefineParams, VerifyParams};
pub use detect::{detect, DetectOutput, Detection, SceneModel};
pub use ranking::Ranker;
pub use shapes::{ShapeLibrary, SizeRange};

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::error::{IsaError, Result};
use crate::vote::Intrinsics;

/// A pinhole camera with its image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub k: Intrinsics,
    pub width: usize,
    pub height: usize,
}

impl Camera {
    /// Checks the intrinsics and that the image is not empty.
    pub fn new(k: Intrinsics, width: usize, height: usize) -> Result<Camera> {
        k.validate()?;
        if width == 0 || height == 0 {
            return Err(IsaError::InvalidInput(format!(
                "camera: image size {width}x{height}"
            )));
        }
        Ok(Camera { k, width, height })
    }
}

/// A depth frame in metres (row-major, 0 = missing) and its camera.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    pub depth: &'a [f32],
    pub camera: Camera,
}

impl<'a> Frame<'a> {
    /// Checks the buffer size against the camera and that every value is finite.
    pub fn new(depth: &'a [f32], camera: Camera) -> Result<Frame<'a>> {
        if depth.len() != camera.width * camera.height {
            return Err(IsaError::InvalidInput(format!(
                "depth: {} pixels for a {}x{} camera",
                depth.len(),
                camera.width,
                camera.height
            )));
        }
        if let Some(i) = depth.iter().position(|d| !d.is_finite()) {
            return Err(IsaError::InvalidInput(format!(
                "depth: pixel {i} is not finite"
            )));
        }
        Ok(Frame { depth, camera })
    }

    /// Camera-frame points of the valid pixels with their pixel index.
    pub fn points(&self) -> (Vec<Vector3<f64>>, Vec<usize>) {
        let k = &self.camera.k;
        let w = self.camera.width;
        // Rows in parallel (a whole frame's pixels), in order.
        self.depth
            .par_chunks(w)
            .enumerate()
            .flat_map_iter(|(v, row)| {
                row.iter()
                    .enumerate()
                    .filter(|(_, &d)| d > 0.0)
                    .map(move |(u, &d)| {
                        let p = k.back_project(u as f64, v as f64, f64::from(d));
                        (Vector3::new(p[0], p[1], p[2]), v * w + u)
                    })
            })
            .unzip()
    }
}

/// The rotation by `yaw` (radians) about z.
pub fn rot_z(yaw: f64) -> Matrix3<f64> {
    let (s, c) = yaw.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// The yaw of the rotation about z closest (Frobenius) to `m`.
pub fn yaw_of(m: &Matrix3<f64>) -> f64 {
    (m[(1, 0)] - m[(0, 1)]).atan2(m[(0, 0)] + m[(1, 1)])
}

/// `np.percentile(values, q)` (linear interpolation), by selection (`values` is reordered).
pub(crate) fn percentile(values: &mut [f64], q: f64) -> f64 {
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    let pos = q / 100.0 * (n - 1) as f64;
    let lo = (pos.floor() as usize).min(n - 1);
    let (_, &mut a, right) = values.select_nth_unstable_by(lo, f64::total_cmp);
    let b = right.iter().copied().fold(f64::INFINITY, f64::min);
    if b.is_finite() {
        a + (b - a) * (pos - lo as f64)
    } else {
        a
    }
}

/// `np.median(values)`, by selection (`values` is reordered).
pub(crate) fn median(values: &mut [f64]) -> f64 {
    percentile(values, 50.0)
}

/// `x.floor() as i64` without a libm call (x86-64's baseline has no rounding instruction):
/// exact for |x| < 2^53; saturating beyond (as `as` casts are), never overflowing.
#[inline]
pub(crate) fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// A row-major 3x3 array as a matrix.
pub fn mat(a: &[[f64; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| a[i][j])
}

/// A matrix as a row-major 3x3 array.
pub fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_i64_is_the_floor() {
        for x in [
            -3.5,
            -3.0,
            -2.999,
            -0.5,
            -1e-12,
            -0.0,
            0.0,
            1e-12,
            0.5,
            2.0,
            2.999,
            1e15 + 0.5,
            -1e15 - 0.5,
        ] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
        let mut v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v, 50.0), 3.0);
        assert_eq!(percentile(&mut v, 12.5), 1.5); // numpy: linear between 1 and 2
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
    }
}
