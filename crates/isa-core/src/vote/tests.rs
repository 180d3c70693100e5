//! Tests of mode finding on synthetic vote clouds (clusters among outliers).

use super::gather::{gather, gather_chunk, GATHER_LANES};
#[cfg(target_arch = "x86_64")]
use super::gather::{gather_chunk_avx2, CentreBlocks};
use super::*;
use crate::error::expect_err;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    // Box-Muller.
    let u1: f64 = rng.random::<f64>().max(1e-12);
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

fn axis_angle(axis: [f64; 3], angle: f64) -> [f64; 4] {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let s = (angle / 2.0).sin() / n;
    [(angle / 2.0).cos(), axis[0] * s, axis[1] * s, axis[2] * s]
}

fn random_quat(rng: &mut ChaCha8Rng) -> [f64; 4] {
    normalise4([gauss(rng), gauss(rng), gauss(rng), gauss(rng)])
}

/// Votes around `t` (σ metres) with rotations around `q` (σ_rot radians per axis), random signs.
fn cluster(
    rng: &mut ChaCha8Rng,
    n: usize,
    t: [f64; 3],
    sigma: f64,
    q: [f64; 4],
    sigma_rot: f64,
    w: f32,
) -> Vec<PoseVote> {
    (0..n)
        .map(|_| {
            let p = [
                t[0] + sigma * gauss(rng),
                t[1] + sigma * gauss(rng),
                t[2] + sigma * gauss(rng),
            ];
            let axis = [gauss(rng), gauss(rng), gauss(rng)];
            let ang = sigma_rot * gauss(rng);
            let mut r = quat_mul(q, axis_angle(axis, ang));
            if rng.random::<bool>() {
                r = r.map(|v| -v);
            }
            PoseVote {
                position: p.map(|v| v as f32),
                rotation: r.map(|v| v as f32),
                weight: w,
            }
        })
        .collect()
}

fn outliers(rng: &mut ChaCha8Rng, n: usize) -> Vec<PoseVote> {
    (0..n)
        .map(|_| {
            let p = [
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(0.5..6.0),
            ];
            PoseVote {
                position: p,
                rotation: random_quat(rng).map(|v| v as f32),
                weight: 1.0,
            }
        })
        .collect()
}

fn scene(seed: u64) -> (Vec<PoseVote>, [[f64; 3]; 2], [[f64; 4]; 2]) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let t = [[0.3, -0.1, 2.5], [-0.9, 0.2, 3.4]];
    let q = [
        normalise4([0.9, 0.1, -0.3, 0.2]),
        normalise4([-0.2, 0.7, 0.5, -0.4]),
    ];
    let mut v = cluster(&mut rng, 6000, t[0], 0.03, q[0], 0.08, 1.0);
    v.extend(cluster(&mut rng, 3000, t[1], 0.03, q[1], 0.08, 1.0));
    v.extend(outliers(&mut rng, 8000));
    // Shuffle so clusters are interleaved.
    for i in (1..v.len()).rev() {
        let j = rng.random_range(0..=i);
        v.swap(i, j);
    }
    (v, t, q)
}

#[test]
fn gather_paths_agree() {
    let (mut votes, _, _) = scene(11);
    for (i, v) in votes.iter_mut().enumerate() {
        if i % 97 == 0 {
            v.weight = 0.0;
        }
    }
    let centres: Vec<[f64; 3]> = votes
        .iter()
        .step_by(1500)
        .take(13)
        .map(|v| v.position.map(f64::from))
        .collect();
    let radius = 0.24;
    let r2 = (radius * radius) as f32;
    // Shuffled votes (boxes of consecutive votes span everything), then votes sorted along
    // x (compact boxes: most are pruned), and centres on the ball's rim.
    let mut sorted = votes.clone();
    sorted.sort_by(|a, b| a.position[0].total_cmp(&b.position[0]));
    let mut rim = centres.clone();
    let p0 = sorted[4000].position.map(f64::from);
    rim.push([p0[0] + radius, p0[1], p0[2]]);
    rim.push([p0[0], p0[1] - radius * 0.999_999, p0[2]]);
    for (votes, centres) in [(&votes, &centres), (&sorted, &rim)] {
        let all = gather(votes, centres, radius);
        for (c, got) in centres.iter().zip(&all) {
            let want: Vec<u32> = (0..votes.len() as u32)
                .filter(|&i| {
                    let v = &votes[i as usize];
                    let p = v.position;
                    let d = [p[0] - c[0] as f32, p[1] - c[1] as f32, p[2] - c[2] as f32];
                    v.weight > 0.0 && d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < r2
                })
                .collect();
            assert!(!want.is_empty());
            assert_eq!(*got, want);
        }
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        let mut blocks = CentreBlocks::default();
        for (c, p) in centres.iter().enumerate() {
            blocks.push(c as u32, p.map(|x| x as f32));
        }
        let mut fast = vec![Vec::new(); blocks.coords.len() * GATHER_LANES];
        let mut portable = fast.clone();
        // SAFETY: AVX2 is available.
        unsafe { gather_chunk_avx2(&votes, 5, &blocks, r2, &mut fast) };
        gather_chunk(&votes, 5, &blocks, r2, &mut portable);
        assert_eq!(fast, portable);
    }
}

fn tdist(a: [f64; 3], b: [f64; 3]) -> f64 {
    dist2(a, b).sqrt()
}

#[test]
fn recovers_two_modes_among_outliers_in_order() {
    let (votes, t, q) = scene(1);
    let hyps = find_modes(&votes, &VoteParams::default()).unwrap();
    assert!(hyps.len() >= 2, "{hyps:?}");
    assert!(tdist(hyps[0].translation, t[0]) < 0.01, "{:?}", hyps[0]);
    assert!(
        quat_angle(hyps[0].quaternion, q[0]) < 2f64.to_radians(),
        "{:?}",
        hyps[0]
    );
    assert!(tdist(hyps[1].translation, t[1]) < 0.01, "{:?}", hyps[1]);
    assert!(
        quat_angle(hyps[1].quaternion, q[1]) < 2f64.to_radians(),
        "{:?}",
        hyps[1]
    );
    for w in hyps.windows(2) {
        assert!(w[0].score >= w[1].score);
    }
    // Outlier-only hypotheses score far below the real ones.
    for hy in &hyps[2..] {
        assert!(hy.score < 0.1 * hyps[1].score, "{hy:?}");
    }
    assert!(hyps[0].support > 1000 && hyps[0].position_support >= hyps[0].support);
}

#[test]
fn subsampled_coarse_grid_and_refinement_find_the_same_modes() {
    let (votes, t, q) = scene(11);
    let full = find_modes(&votes, &VoteParams::default()).unwrap();
    let p = VoteParams {
        coarse_votes: 900,
        refine_votes: 400,
        rotation_eval_votes: 200,
        ..Default::default()
    };
    let sub = find_modes(&votes, &p).unwrap();
    for k in 0..2 {
        assert!(tdist(sub[k].translation, t[k]) < 0.01, "{:?}", sub[k]);
        assert!(quat_angle(sub[k].quaternion, q[k]) < 2f64.to_radians());
        assert!(tdist(sub[k].translation, full[k].translation) < 0.005);
        // Densities and supports still count every vote.
        assert!(
            (sub[k].position_score - full[k].position_score).abs() < 0.02 * full[k].position_score
        );
    }
}

#[test]
fn rotation_matrix_is_proper_and_matches_quaternion() {
    let (votes, _, _) = scene(2);
    for hy in find_modes(&votes, &VoteParams::default()).unwrap() {
        let r = hy.rotation;
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| r[i][k] * r[j][k]).sum();
                assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9);
            }
        }
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        assert!((det - 1.0).abs() < 1e-9);
        assert!(hy.quaternion[0] >= 0.0);
        assert!(quat_angle(matrix_to_quat(r), hy.quaternion) < 1e-6);
    }
}

#[test]
fn quaternion_signs_do_not_matter() {
    let (votes, _, _) = scene(3);
    let flipped: Vec<PoseVote> = votes
        .iter()
        .enumerate()
        .map(|(i, v)| {
            if i % 3 == 0 {
                PoseVote {
                    rotation: v.rotation.map(|x| -x),
                    ..*v
                }
            } else {
                *v
            }
        })
        .collect();
    let a = find_modes(&votes, &VoteParams::default()).unwrap();
    let b = find_modes(&flipped, &VoteParams::default()).unwrap();
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert!(tdist(x.translation, y.translation) < 1e-12);
        assert!(quat_angle(x.quaternion, y.quaternion) < 1e-6);
        assert!((x.score - y.score).abs() < 1e-9 * x.score);
    }
}

#[test]
fn rotation_near_pi_mixed_signs() {
    // Rotation of ~180° about z: w ~ 0, so noise flips the sign of w; a naive average fails.
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let q = axis_angle([0.0, 0.0, 1.0], std::f64::consts::PI);
    let votes = cluster(&mut rng, 2000, [0.0, 0.0, 2.0], 0.02, q, 0.1, 1.0);
    let hyps = find_modes(&votes, &VoteParams::default()).unwrap();
    assert!(
        quat_angle(hyps[0].quaternion, q) < 2f64.to_radians(),
        "{:?}",
        hyps[0]
    );
}

#[test]
fn deterministic_across_runs_and_threads_stable_under_input_order() {
    let (votes, _, _) = scene(5);
    let p = VoteParams::default();
    let a = find_modes(&votes, &p).unwrap();
    let b = find_modes(&votes, &p).unwrap();
    assert_eq!(a, b);
    let on_threads = |n| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap();
        pool.install(|| find_modes(&votes, &p).unwrap())
    };
    assert_eq!(a, on_threads(1));
    assert_eq!(a, on_threads(3));
    // Reversed input: the same modes up to float summation order and which votes the
    // even-stride subsamples pick (well under a millimetre and a tenth of a degree).
    let rev: Vec<PoseVote> = votes.iter().rev().copied().collect();
    let e = find_modes(&rev, &p).unwrap();
    for (x, y) in a.iter().zip(&e).take(2) {
        assert!(tdist(x.translation, y.translation) < 1e-3, "{x:?} {y:?}");
        assert!(quat_angle(x.quaternion, y.quaternion) < 0.1f64.to_radians());
    }
}

/// The modes of `votes` with the default parameters changed by `set`.
fn modes_with(votes: &[PoseVote], set: impl FnOnce(&mut VoteParams)) -> Vec<Hypothesis> {
    let mut p = VoteParams::default();
    set(&mut p);
    find_modes(votes, &p).unwrap()
}

#[test]
fn weights_decide_the_ranking() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let q = [1.0, 0.0, 0.0, 0.0];
    let mut votes = cluster(&mut rng, 1000, [0.0, 0.0, 2.0], 0.02, q, 0.05, 1.0);
    votes.extend(cluster(&mut rng, 300, [1.0, 0.0, 2.0], 0.02, q, 0.05, 10.0));
    let hyps = find_modes(&votes, &VoteParams::default()).unwrap();
    assert!(tdist(hyps[0].translation, [1.0, 0.0, 2.0]) < 0.01);
    assert!(tdist(hyps[1].translation, [0.0, 0.0, 2.0]) < 0.01);
    assert!(hyps[0].score > hyps[1].score);
}

#[test]
fn nms_and_max_hypotheses() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let q = [1.0, 0.0, 0.0, 0.0];
    let mut votes = Vec::new();
    for i in 0..8 {
        votes.extend(cluster(
            &mut rng,
            500 + 50 * i,
            [0.5 * i as f64, 0.0, 3.0],
            0.01,
            q,
            0.05,
            1.0,
        ));
    }
    let hyps = modes_with(&votes, |p| p.max_hypotheses = 3);
    assert_eq!(hyps.len(), 3);
    // The three biggest clusters (i = 7, 6, 5), in that order.
    for (k, hy) in hyps.iter().enumerate() {
        assert!(
            tdist(hy.translation, [0.5 * (7 - k) as f64, 0.0, 3.0]) < 0.01,
            "{hy:?}"
        );
    }
    // With an NMS radius over 0.5 m neighbours suppress each other.
    let hyps = modes_with(&votes, |p| {
        p.max_hypotheses = 8;
        p.nms_radius = 0.6;
    });
    for (i, a) in hyps.iter().enumerate() {
        for b in &hyps[i + 1..] {
            assert!(tdist(a.translation, b.translation) >= 0.6);
        }
    }
    assert!(tdist(hyps[0].translation, [3.5, 0.0, 3.0]) < 0.01);
}

#[test]
fn several_rotations_per_position() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let q1 = axis_angle([0.0, 0.0, 1.0], 0.3);
    let q2 = axis_angle([0.0, 0.0, 1.0], 0.3 + std::f64::consts::PI);
    let mut votes = cluster(&mut rng, 1500, [0.0, 0.0, 2.0], 0.02, q1, 0.05, 1.0);
    votes.extend(cluster(
        &mut rng,
        1000,
        [0.0, 0.0, 2.0],
        0.02,
        q2,
        0.05,
        1.0,
    ));
    let hyps = modes_with(&votes, |p| p.rotations_per_position = 2);
    assert!(quat_angle(hyps[0].quaternion, q1) < 2f64.to_radians());
    assert!(quat_angle(hyps[1].quaternion, q2) < 2f64.to_radians());
    assert_eq!(hyps[0].translation, hyps[1].translation);
    let one = find_modes(&votes, &VoteParams::default()).unwrap();
    assert_eq!(one.len(), 1);
}

#[test]
fn empty_zero_weight_and_min_support() {
    assert!(find_modes(&[], &VoteParams::default()).unwrap().is_empty());
    let v = PoseVote {
        position: [0.0, 0.0, 1.0],
        rotation: [1.0, 0.0, 0.0, 0.0],
        weight: 0.0,
    };
    assert!(find_modes(&[v; 10], &VoteParams::default())
        .unwrap()
        .is_empty());
    let v1 = PoseVote { weight: 1.0, ..v };
    assert!(find_modes(&[v1; 2], &VoteParams::default())
        .unwrap()
        .is_empty());
    let hyps = find_modes(&[v1; 3], &VoteParams::default()).unwrap();
    assert_eq!(hyps.len(), 1);
    assert_eq!(hyps[0].support, 3);
    assert!((hyps[0].score - 3.0).abs() < 1e-9);
    assert!(tdist(hyps[0].translation, [0.0, 0.0, 1.0]) < 1e-6);
    // Non-unit quaternions are normalised.
    let v2 = PoseVote {
        rotation: [0.0, 0.0, 0.0, -3.0],
        weight: 1.0,
        ..v
    };
    let hyps = find_modes(&[v2; 5], &VoteParams::default()).unwrap();
    assert!((hyps[0].quaternion[3] - 1.0).abs() < 1e-9);
}

#[test]
fn errors_name_the_vote_or_parameter() {
    let good = PoseVote {
        position: [0.0, 0.0, 1.0],
        rotation: [1.0, 0.0, 0.0, 0.0],
        weight: 1.0,
    };
    let mut votes = vec![good; 5];
    votes[3].position[1] = f32::NAN;
    expect_err(
        find_modes(&votes, &VoteParams::default()),
        &["votes[3]", "position"],
    );
    votes[3] = PoseVote {
        weight: -1.0,
        ..good
    };
    votes[4] = PoseVote {
        rotation: [0.0; 4],
        ..good
    };
    expect_err(
        find_modes(&votes, &VoteParams::default()),
        &["votes[3]", "weight"],
    );
    // Each parameter set out of range in turn.
    type Setter = fn(&mut VoteParams);
    let spoil: [(&str, Setter); 5] = [
        ("position_bandwidth", |p| p.position_bandwidth = 0.0),
        ("rotation_bandwidth", |p| p.rotation_bandwidth = 4.0),
        ("nms_radius", |p| p.nms_radius = f32::NAN),
        ("max_hypotheses", |p| p.max_hypotheses = 0),
        ("max_seeds", |p| p.max_seeds = 0),
    ];
    for (name, set) in spoil {
        let mut p = VoteParams::default();
        set(&mut p);
        let e = find_modes(&[good], &p).unwrap_err();
        assert!(matches!(e, IsaError::InvalidParameter(_)));
        assert!(e.to_string().contains(name), "{e}");
    }
}

#[test]
fn params_serde_defaults_and_unknown_fields() {
    let p: VoteParams = serde_json::from_str(r#"{"max_hypotheses": 2}"#).unwrap();
    assert_eq!(
        p,
        VoteParams {
            max_hypotheses: 2,
            ..Default::default()
        }
    );
    assert!(serde_json::from_str::<VoteParams>(r#"{"bandwidth": 2}"#).is_err());
}
