//! Gravity for a frame that does not come with it (as `isa.detection.gravity`): the floor's
//! normal by RANSAC, else the hypotheses' mean up axis, else a level camera.

use nalgebra::{Matrix3, Vector3};
use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::Frame;
use crate::vote::Hypothesis;

/// Where a gravity rotation came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GravitySource {
    Given,
    Floor,
    Votes,
    Level,
}

impl GravitySource {
    pub fn name(&self) -> &'static str {
        match self {
            GravitySource::Given => "given",
            GravitySource::Floor => "floor",
            GravitySource::Votes => "votes",
            GravitySource::Level => "level",
        }
    }
}

/// The gravity rotation of a level camera (up is the camera's -y).
pub fn level() -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0)
}

/// The gravity rotation whose z axis is `up` (camera coordinates): y the viewing direction
/// levelled, x to its right.
pub fn rotation_from_up(up: &Vector3<f64>) -> Matrix3<f64> {
    let z = up.normalize();
    let fwd = Vector3::new(0.0, 0.0, 1.0);
    let mut y = fwd - fwd.dot(&z) * z;
    if y.norm() < 1e-6 {
        let alt = Vector3::new(0.0, -1.0, 0.0);
        y = alt - alt.dot(&z) * z;
    }
    let y = y.normalize();
    let x = y.cross(&z);
    Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()])
}

/// The floor's upward normal (camera coordinates) and its inlier count, by RANSAC over
/// `samples` points: the best-supported plane within 50 degrees of the camera's -y, at least
/// 0.4 m below the camera, holding 5% of the samples; least squares on its inliers.
pub fn floor_up(frame: &Frame<'_>, seed: u64) -> Option<(Vector3<f64>, usize)> {
    const MAX_ANGLE_DEG: f64 = 50.0;
    const MIN_DROP: f64 = 0.4;
    const MIN_FRACTION: f64 = 0.05;
    const ITERATIONS: usize = 300;
    const SAMPLES: usize = 4000;
    const TOLERANCE: f64 = 0.03;
    let (all, _) = frame.points();
    if all.len() < 50 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let p: Vec<Vector3<f64>> = sample(&mut rng, all.len(), SAMPLES.min(all.len()))
        .iter()
        .map(|i| all[i])
        .collect();
    let cos_max = MAX_ANGLE_DEG.to_radians().cos();
    let mut best: Option<(usize, Vector3<f64>, f64)> = None;
    for _ in 0..ITERATIONS {
        let (a, b, c) = (
            p[rng.random_range(0..p.len())],
            p[rng.random_range(0..p.len())],
            p[rng.random_range(0..p.len())],
        );
        let mut n = (b - a).cross(&(c - a));
        let norm = n.norm();
        if norm <= 1e-9 {
            continue;
        }
        n /= norm;
        if n.y > 0.0 {
            n = -n;
        }
        let off = -n.dot(&a);
        if -n.y < cos_max || off < MIN_DROP {
            continue;
        }
        let support = p
            .iter()
            .filter(|q| (n.dot(q) + off).abs() < TOLERANCE)
            .count();
        if best.is_none_or(|b| support > b.0) {
            best = Some((support, n, off));
        }
    }
    let (support, n, off) = best?;
    if (support as f64) < MIN_FRACTION * p.len() as f64 {
        return None;
    }
    let inl: Vec<&Vector3<f64>> = p
        .iter()
        .filter(|q| (n.dot(q) + off).abs() < TOLERANCE)
        .collect();
    let centre = inl.iter().fold(Vector3::zeros(), |s, q| s + *q) / inl.len() as f64;
    let mut cov = Matrix3::zeros();
    for q in &inl {
        let d = *q - centre;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let k = (0..3)
        .min_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]))
        .expect("3");
    let mut normal: Vector3<f64> = eig.eigenvectors.column(k).into();
    if normal.y > 0.0 {
        normal = -normal;
    }
    Some((normal, support))
}

/// Up (camera coordinates) as the score-weighted mean of the best 10 hypotheses' z axes.
pub fn votes_up(hyps: &[&Hypothesis]) -> Option<Vector3<f64>> {
    if hyps.is_empty() {
        return None;
    }
    let m = hyps.iter().take(10).fold(Vector3::zeros(), |s, h| {
        let r = h.rotation;
        s + h.score.max(1e-12) * Vector3::new(r[0][2], r[1][2], r[2][2])
    });
    (m.norm() > 1e-9).then(|| m.normalize())
}

#[cfg(test)]
mod tests {
    use super::super::Camera;
    use super::*;
    use crate::vote::Intrinsics;

    #[test]
    fn the_floor_of_a_tilted_camera_gives_its_up() {
        // A camera 1.3 m above a floor, pitched down by 20 degrees and rolled by 5: each pixel's
        // depth is where its ray meets the plane.
        let (pitch, roll) = (20f64.to_radians(), 5f64.to_radians());
        let up_level = Vector3::new(0.0, -1.0, 0.0);
        let rx = Matrix3::new(
            1.0,
            0.0,
            0.0,
            0.0,
            pitch.cos(),
            -pitch.sin(),
            0.0,
            pitch.sin(),
            pitch.cos(),
        );
        let rz = Matrix3::new(
            roll.cos(),
            -roll.sin(),
            0.0,
            roll.sin(),
            roll.cos(),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        let up = rz * rx * up_level;
        let cam = Camera::new(Intrinsics::KINECT_V1, 640, 480).unwrap();
        let mut depth = vec![0f32; 640 * 480];
        for v in 0..480 {
            for u in 0..640 {
                let d = Vector3::new((u as f64 - 319.5) / 525.0, (v as f64 - 239.5) / 525.0, 1.0);
                let s = -up.dot(&d); // the floor: up . x + 1.3 = 0
                if s > 1e-6 && 1.3 / s < 8.0 {
                    depth[v * 640 + u] = (1.3 / s) as f32;
                }
            }
        }
        let f = Frame::new(&depth, cam).unwrap();
        let (n, support) = floor_up(&f, 0).unwrap();
        assert!(n.angle(&up).to_degrees() < 0.1, "{n} vs {up}");
        assert!(support > 3000);
        let rg = rotation_from_up(&n);
        assert!((rg * up - Vector3::z()).norm() < 1e-2);
        assert!((rg * rg.transpose() - Matrix3::identity()).norm() < 1e-12);
        assert!(floor_up(&Frame::new(&vec![0f32; 640 * 480], cam).unwrap(), 0).is_none());
    }
}
