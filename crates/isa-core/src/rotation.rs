//! Rotations: unit quaternions `(w, x, y, z)` and row-major rotation matrices, on nalgebra's
//! [`UnitQuaternion`] and [`Rotation3`].
//!
//! Quaternions are sign-free (`q` and `-q` are the same rotation); outputs follow one sign
//! convention ([`canonical`]: `w >= 0`, then the first non-zero component positive).
//!
//! Two groups of helpers:
//! * inference and tests, in `f64` on nalgebra ([`quat_to_matrix`], [`matrix_to_quat`],
//!   [`quat_angle`]);
//! * training, in the exact arithmetic the model bytes were fixed with ([`unit_w_positive`],
//!   [`angle_sq_approx`], [`quat_to_6d`]): leaf votes and criterion targets depend on their last
//!   bits, so they keep their own (`f32`, or `f64` in a fixed order) formulas instead of
//!   nalgebra's equivalent ones (`tests/model_digest.rs` pins the bytes).

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion};

/// How far a quaternion's norm may be from 1 where a unit quaternion is required (training
/// rotations, a model's vote rotations): float32 data normalised in any precision is within
/// 1e-6; a norm off by more is a bug or a foreign value, not rounding.
pub const UNIT_NORM_TOLERANCE: f32 = 1e-3;

/// Whether `q` (4 finite-or-not values) is a unit quaternion within [`UNIT_NORM_TOLERANCE`]
/// (in `f64`, so huge components cannot overflow the check).
pub fn is_unit(q: &[f32]) -> bool {
    let n = q
        .iter()
        .map(|&v| f64::from(v) * f64::from(v))
        .sum::<f64>()
        .sqrt();
    (n - 1.0).abs() <= f64::from(UNIT_NORM_TOLERANCE)
}

/// `(w, x, y, z)` as nalgebra's (non-unit) quaternion.
#[inline]
fn quaternion(q: [f64; 4]) -> Quaternion<f64> {
    Quaternion::new(q[0], q[1], q[2], q[3])
}

/// The 4x4 homogeneous pose `[[R, t], [0, 0, 0, 1]]` (row-major): `X_cam = T [X_obj; 1]`.
pub fn pose_matrix(r: &[[f64; 3]; 3], t: &[f64; 3]) -> [[f64; 4]; 4] {
    let row = |i: usize| [r[i][0], r[i][1], r[i][2], t[i]];
    [row(0), row(1), row(2), [0.0, 0.0, 0.0, 1.0]]
}

/// Rotation matrix (row-major) of a quaternion `(w, x, y, z)`; normalises it first.
pub fn quat_to_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let r = UnitQuaternion::from_quaternion(quaternion(q)).to_rotation_matrix();
    let m = r.matrix();
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// Unit quaternion `(w, x, y, z)` of a rotation matrix (row-major), in the [`canonical`] sign
/// convention; robust (Shepperd's method, as nalgebra's `from_rotation_matrix`).
pub fn matrix_to_quat(m: [[f64; 3]; 3]) -> [f64; 4] {
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_fn(|i, j| m[i][j]));
    // Shepperd's quaternion has norm 1 only up to rounding: normalise it in (w, x, y, z) order.
    let q = UnitQuaternion::from_rotation_matrix(&r).into_inner();
    canonical(normalise([q.w, q.i, q.j, q.k]))
}

/// Geodesic angle (radians, in [0, π]) between the rotations of two quaternions (normalised
/// here), sign-free: `2 atan2(|im(a⁻¹ b)|, |re(a⁻¹ b)|)`, accurate also for tiny angles
/// (unlike `2 acos(|a·b|)`, which loses half the digits near 0).
pub fn quat_angle(a: [f64; 4], b: [f64; 4]) -> f64 {
    let a = UnitQuaternion::from_quaternion(quaternion(a));
    let b = UnitQuaternion::from_quaternion(quaternion(b));
    a.angle_to(&b)
}

/// `a · b` of two quaternions as 4-vectors (the kernels of mode finding use it directly).
#[inline(always)]
pub(crate) fn dot4(a: [f64; 4], b: [f64; 4]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

/// `q / |q|`.
#[inline]
pub(crate) fn normalise(q: [f64; 4]) -> [f64; 4] {
    let n = dot4(q, q).sqrt();
    [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
}

/// Sign convention of output quaternions: `w >= 0`, then the first non-zero component positive.
pub(crate) fn canonical(q: [f64; 4]) -> [f64; 4] {
    let first = q.iter().copied().find(|v| *v != 0.0).unwrap_or(1.0);
    if q[0] < 0.0 || (q[0] == 0.0 && first < 0.0) {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    }
}

// ---------------------------------------------------------------------------------------------
// Training arithmetic (bit-exact: the model bytes depend on it).

/// A quaternion (`f32`, first four values of `q`) normalised with `w >= 0`, as leaf votes
/// store rotations.
#[inline]
pub fn unit_w_positive(q: &[f32]) -> [f32; 4] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let s = if q[0] < 0.0 { -1.0 / n } else { 1.0 / n };
    [q[0] * s, q[1] * s, q[2] * s, q[3] * s]
}

/// `8 (1 − |q_a · q_b|)` of unit quaternions: the squared rotation angle to second order (exact
/// as the angle goes to 0, 8/π² ≈ 0.81 of it at 180°), without a transcendental function.
#[inline]
pub fn angle_sq_approx(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let dot = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3])
        .abs()
        .min(1.0);
    8.0 * (1.0 - dot)
}

/// Rotation matrix columns 0 and 1 of a quaternion `(w, x, y, z)` (normalised here): the
/// continuous 6D rotation representation the criterion's Q1 term uses.
#[inline]
pub fn quat_to_6d(q: &[f32]) -> [f64; 6] {
    let (w, x, y, z) = (q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64);
    let n = (w * w + x * x + y * y + z * z).sqrt();
    let (w, x, y, z) = (w / n, x / n, y / n, z / n);
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y + w * z),
        2.0 * (x * z - w * y),
        2.0 * (x * y - w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z + w * x),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_quat(rng: &mut ChaCha8Rng) -> [f64; 4] {
        loop {
            let q: [f64; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let n2 = dot4(q, q);
            if n2 > 1e-3 && n2 <= 1.0 {
                return normalise(q);
            }
        }
    }

    /// `q` composed with a rotation of `angle` about `axis`, as `(w, x, y, z)`.
    fn turn(q: [f64; 4], axis: [f64; 3], angle: f64) -> [f64; 4] {
        let ax = nalgebra::Unit::new_normalize(Vector3::from(axis));
        let p = UnitQuaternion::from_quaternion(quaternion(q))
            * UnitQuaternion::from_axis_angle(&ax, angle);
        [p.w, p.i, p.j, p.k]
    }

    /// Rodrigues' formula, independent of any quaternion code.
    fn axis_angle_matrix(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
        let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        let [x, y, z] = axis.map(|v| v / n);
        let (s, c) = angle.sin_cos();
        let t = 1.0 - c;
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ]
    }

    #[test]
    fn matrix_of_a_quaternion_is_rodrigues() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let axis: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let angle = rng.random_range(0.0..std::f64::consts::PI);
            let n = (axis.iter().map(|v| v * v).sum::<f64>()).sqrt();
            let s = (angle / 2.0).sin() / n;
            let q = [(angle / 2.0).cos(), axis[0] * s, axis[1] * s, axis[2] * s];
            let want = axis_angle_matrix(axis, angle);
            // Not unit, and of either sign: the same matrix.
            for q in [q, q.map(|v| -2.5 * v)] {
                let got = quat_to_matrix(q);
                for i in 0..3 {
                    for j in 0..3 {
                        assert!((got[i][j] - want[i][j]).abs() < 1e-12, "{got:?} {want:?}");
                    }
                }
            }
            let back = matrix_to_quat(want);
            assert!(back[0] >= 0.0 && (dot4(back, back) - 1.0).abs() < 1e-12);
            assert!((dot4(back, normalise(q)).abs() - 1.0).abs() < 1e-12);
        }
        // Near 180°, every Shepperd branch.
        for axis in [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, -1.0, 0.2],
        ] {
            let m = axis_angle_matrix(axis, std::f64::consts::PI - 1e-9);
            assert!(
                quat_angle(
                    matrix_to_quat(m),
                    matrix_to_quat(quat_to_matrix(matrix_to_quat(m)))
                ) < 1e-8
            );
        }
    }

    #[test]
    fn angle_is_geodesic_sign_free_and_accurate_when_tiny() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200 {
            let q = random_quat(&mut rng);
            assert!(quat_angle(q, matrix_to_quat(quat_to_matrix(q))) < 1e-7);
            for angle in [0.7, 3.0, 1e-7] {
                let p = turn(q, [1.0, 2.0, 3.0], angle);
                let tol = 1e-9 * angle.max(1e-3);
                assert!((quat_angle(q, p) - angle).abs() < tol, "{angle}");
                assert!((quat_angle(q, p.map(|v| -3.0 * v)) - angle).abs() < tol);
            }
        }
    }

    #[test]
    fn canonical_sign() {
        assert_eq!(canonical([-0.5, 0.5, -0.5, 0.5]), [0.5, -0.5, 0.5, -0.5]);
        assert_eq!(canonical([0.0, -1.0, 0.0, 0.0]), [0.0, 1.0, 0.0, 0.0]);
        assert_eq!(canonical([0.0, 0.0, 1.0, 0.0]), [0.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn training_helpers_agree_with_nalgebra() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for _ in 0..100 {
            let q = random_quat(&mut rng).map(|v| (3.0 * v) as f32);
            let u = unit_w_positive(&q);
            let qd = q.map(f64::from);
            assert!(u[0] >= 0.0);
            assert!(quat_angle(u.map(f64::from), qd) < 1e-3);
            let m = quat_to_matrix(qd);
            let six = quat_to_6d(&q);
            for i in 0..3 {
                assert!((six[i] - m[i][0]).abs() < 1e-12 && (six[3 + i] - m[i][1]).abs() < 1e-12);
            }
            let p =
                unit_w_positive(&turn(u.map(f64::from), [0.3, -1.0, 0.5], 0.2).map(|v| v as f32));
            let approx = angle_sq_approx(&u, &p);
            assert!((approx - 0.04).abs() < 1e-3, "{approx}");
        }
    }
}
