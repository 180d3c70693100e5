//! Behaviour lock: a fixed-seed forest trained on the crate's synthetic chair (Q1, and Q1+Q2+Q3
//! with synthetic privileged targets) must serialise to the same bytes, and predict the same
//! hypotheses on one synthetic frame, as when the digests were recorded (before the core was
//! split by concept). Regenerate the constants only on purpose, and say why in the commit.
//!
//! Two digests per model: of the trees (nodes, thresholds, leaf votes, as `Debug` prints them:
//! every float in its shortest round-trip form), recorded before the core was split by concept
//! and unchanged since; and of the whole file, regenerated on purpose once, for model format 2
//! (typed inference defaults and metadata: the header and those fields moved, the trees not).
//!
//! To print the current values: `cargo test -p isa-core --test model_digest -- --nocapture`.

use isa_core::criterion::RawTargets;
use isa_core::vote::{self, synth, DepthImage, Hypothesis, Intrinsics, PredictParams};
use isa_core::{
    sample_parts, DepthStore, Forest, ForestParams, ModelMetadata, Quality, TrainingSet,
};

/// FNV-1a, 64 bits (written here so the test does not trust the crate's own hash).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

const K: Intrinsics = Intrinsics {
    fx: 200.0,
    fy: 200.0,
    cx: 79.5,
    cy: 59.5,
};
const W: usize = 160;
const H: usize = 120;

/// Object-frame points (metres) whose offsets stand in for skeleton node offsets.
const NODES: [[f64; 3]; 3] = [[0.2, 0.19, -0.45], [-0.2, -0.19, 0.45], [0.0, 0.0, 0.0]];

struct Data {
    store: DepthStore,
    parts: Vec<[i32; 3]>,
    offsets: Vec<f32>,
    rotations: Vec<f32>,
    links: Vec<f32>,
    nodes: Vec<f32>,
}

/// Ten views of the chair, 300 parts each; privileged targets derived from the exact pose.
fn data() -> Data {
    let (store, poses) = synth::chair_views(10, |i| 0.3 + 0.05 * (i % 3) as f64, 2.5, &K, W, H);
    let parts = sample_parts(&store, 2, Some(300), 3).unwrap();
    let (offsets, rotations) = synth::view_targets(&parts, &store, &poses, &K);
    let (mut links, mut nodes) = (Vec::new(), Vec::new());
    for (p, off) in parts.iter().zip(offsets.chunks(3)) {
        let r = poses[p[0] as usize].0;
        let (x, y, z) = (f64::from(off[0]), f64::from(off[1]), f64::from(off[2]));
        links.push(y.atan2(x) as f32);
        links.push(z.atan2(x.hypot(y)) as f32);
        for n in NODES {
            for a in 0..3 {
                let rn = r[a][0] * n[0] + r[a][1] * n[1] + r[a][2] * n[2];
                nodes.push((f64::from(off[a]) + rn) as f32);
            }
        }
    }
    Data {
        store,
        parts,
        offsets,
        rotations,
        links,
        nodes,
    }
}

fn train(d: &Data, quality: Quality) -> Forest {
    let params = ForestParams {
        n_trees: 3,
        max_depth: 12,
        n_candidates: 40,
        min_samples_split: 10,
        min_samples_leaf: 3,
        max_score_samples: 1500,
        bag_fraction: 0.8,
        quality,
        seed: 17,
        ..Default::default()
    };
    let privileged = quality != Quality::Q1;
    let targets = RawTargets {
        offsets: &d.offsets,
        rotations: &d.rotations,
        link_angles: privileged.then_some((&d.links[..], 2)),
        node_offsets: privileged.then_some((&d.nodes[..], 3 * NODES.len())),
    };
    let set = TrainingSet {
        store: &d.store,
        parts: &d.parts,
        targets,
    };
    Forest::fit(
        &params.check().unwrap(),
        &set,
        ModelMetadata::default(),
        Some(2),
    )
    .unwrap()
}

/// A view between training views, shifted sideways, in a frame twice the size.
fn hypotheses(f: &Forest) -> Vec<Hypothesis> {
    let k = Intrinsics {
        cx: 159.5,
        cy: 119.5,
        ..K
    };
    let (r, mut t) = synth::look_at(0.9, 0.33, 2.4);
    t[0] += 0.25;
    let depth = synth::render(&synth::chair(), r, t, &k, 2 * W, 2 * H);
    let img = DepthImage::new(&depth, 2 * W, 2 * H).unwrap();
    let p = PredictParams {
        stride: 2,
        ..Default::default()
    }
    .check()
    .unwrap();
    vote::predict(f, &img, &k, &p).unwrap()
}

/// (rotation row-major, translation, score) of the first hypotheses.
type Expected = ([f64; 9], [f64; 3], f64);

/// Trains the `quality` model on [`data`] and compares it with the recorded digests and
/// hypotheses.
fn check(quality: Quality, (trees, digest): (u64, u64), expected: &[Expected]) {
    let name = quality.as_str();
    let f = &train(&data(), quality);
    let bytes = f.to_bytes();
    let tree_digest = fnv1a(format!("{:?}", f.trees).as_bytes());
    println!("{name}: trees {tree_digest:#018x}");
    let hyps = hypotheses(f);
    println!(
        "{name}: digest {:#018x}, {} bytes",
        fnv1a(&bytes),
        bytes.len()
    );
    for h in hyps.iter().take(expected.len().max(3)) {
        let r: Vec<f64> = h.rotation.iter().flatten().copied().collect();
        println!("    ({r:?}, {:?}, {:?}),", h.translation, h.score);
    }
    assert_eq!(tree_digest, trees, "{name}: trees changed");
    assert_eq!(fnv1a(&bytes), digest, "{name}: model bytes changed");
    assert!(hyps.len() >= expected.len(), "{name}: {hyps:?}");
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0);
    for (i, (h, (r, t, s))) in hyps.iter().zip(expected).enumerate() {
        let got_r: Vec<f64> = h.rotation.iter().flatten().copied().collect();
        assert!(
            got_r.iter().zip(r).all(|(a, b)| close(*a, *b)),
            "{name}: hypothesis {i} rotation {got_r:?} != {r:?}"
        );
        assert!(
            h.translation.iter().zip(t).all(|(a, b)| close(*a, *b)),
            "{name}: hypothesis {i} translation {:?} != {t:?}",
            h.translation
        );
        assert!(
            close(h.score, *s),
            "{name}: hypothesis {i} score {} != {s}",
            h.score
        );
    }
}

#[test]
fn q1_model_bytes_and_hypotheses_are_unchanged() {
    check(
        Quality::Q1,
        (0x8830_afbb_bdb1_0a94, 0x785e_f8f5_95d2_5395),
        &[
            (
                [
                    -0.5976424614819378,
                    0.8017626794893626,
                    0.0003066135156181704,
                    0.2754613101002698,
                    0.2056909165634433,
                    -0.9390486214680972,
                    -0.7529572065341121,
                    -0.5611308694247074,
                    -0.34378422376109485,
                ],
                [
                    0.24397958758903107,
                    -0.007687197930759543,
                    2.4247254050841587,
                ],
                19.630581686100726,
            ),
            (
                [
                    0.6307879000919454,
                    -0.775954303471857,
                    0.0012425864554483357,
                    -0.23168098272024307,
                    -0.1898656801176044,
                    -0.9540833012684282,
                    0.7405609680123415,
                    0.6015363184687896,
                    -0.2995388292352743,
                ],
                [0.1428171459583789, 0.3882917530312795, 2.5103049166608975],
                2.4792028569162787,
            ),
            (
                [
                    0.5877852387218838,
                    0.8090170042345577,
                    1.2653416259222894e-8,
                    0.23908083940286345,
                    -0.1737023763881571,
                    -0.9553365044148214,
                    -0.7728834746396642,
                    0.5615326983323854,
                    -0.29552015723545955,
                ],
                [0.2243574231141355, 0.04813237129239195, 2.866387344226846],
                0.7383002496754729,
            ),
        ],
    );
}

#[test]
fn q1q2q3_model_bytes_and_hypotheses_are_unchanged() {
    check(
        Quality::Q1Q2Q3,
        (0x3944_46e2_0706_6699, 0xa39e_0fea_b101_68f1),
        &[
            (
                [
                    -0.59205713174264,
                    0.8058959634750503,
                    0.0002209237407844178,
                    0.27652579387708587,
                    0.20340909326483514,
                    -0.9392327858937981,
                    -0.7569688488130316,
                    -0.5560183781421242,
                    -0.34328082541102667,
                ],
                [
                    0.24757238885252886,
                    -0.008006909575406434,
                    2.444599787663954,
                ],
                21.71385788465156,
            ),
            (
                [
                    0.5877852387218838,
                    -0.8090170042345575,
                    -1.2653416314734045e-8,
                    -0.23908083940286334,
                    -0.17370237638815667,
                    -0.9553365044148212,
                    0.7728834746396642,
                    0.5615326983323852,
                    -0.2955201572354591,
                ],
                [
                    -0.026930289954918685,
                    -0.1883678515041544,
                    2.5720659181300585,
                ],
                3.4776254997234775,
            ),
            (
                [
                    -4.440892098500626e-16,
                    -1.0000000000000004,
                    0.0,
                    -0.3894182189746368,
                    -4.440892098500626e-16,
                    -0.9210610461476603,
                    0.9210610461476603,
                    0.0,
                    -0.38941821897463713,
                ],
                [0.16603316337715981, -0.422819327800798, 2.6466788719568677],
                0.7528390436444309,
            ),
        ],
    );
}
