//! Criterion microbenchmarks of the forest core.
//!
//! * `split_search/{Q1,Q1+Q2+Q3}/{10k,100k}`: one node's split search over all its parts with
//!   100 candidates x 16 thresholds on precomputed (candidate-major) features; the reported
//!   throughput "elements" are part x candidate evaluations. Q2/Q3 use 18 links and 11 nodes,
//!   reduced to 4 principal components each (`reduce_dims = 4`, the default); `full` variants
//!   keep all 36 + 33 dimensions.
//! * `traversal/10_trees`: parts per second through a 10-tree forest (depth 20 max) trained on
//!   synthetic depth images.
//!
//! Run: `cargo bench -p isa-core --bench forest` (set `RAYON_NUM_THREADS` to pin threads).
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use isa_core::criterion::{build_targets, Criterion as Crit, RawTargets};
use isa_core::splitter::{best_split_columns, SplitConfig};
use isa_core::{DepthStore, Forest, ForestParams, Quality, TrainingSet};

struct Data {
    off: Vec<f32>,
    rot: Vec<f32>,
    la: Vec<f32>,
    no: Vec<f32>,
}

fn data(n: usize, rng: &mut ChaCha8Rng) -> Data {
    let off = (0..3 * n).map(|_| rng.random_range(-0.5..0.5)).collect();
    let rot = (0..n)
        .flat_map(|_| {
            let q: [f32; 4] = [
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ];
            q
        })
        .collect();
    let la = (0..18 * n).map(|_| rng.random_range(-3.1..3.1)).collect();
    let no = (0..33 * n)
        .map(|_| rng.random_range(-100.0..100.0))
        .collect();
    Data { off, rot, la, no }
}

fn split_search(c: &mut Criterion) {
    let mut group = c.benchmark_group("split_search");
    group.sample_size(10);
    let n_cand = 100;
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    for &n in &[10_000usize, 100_000] {
        let d = data(n, &mut rng);
        let feats: Vec<f32> = (0..n * n_cand)
            .map(|_| rng.random_range(-500.0..500.0f32).round())
            .collect();
        for (name, q, reduce) in [
            ("Q1", Quality::Q1, 4),
            ("Q1+Q2+Q3", Quality::Q1Q2Q3, 4),
            ("Q1+Q2+Q3_full", Quality::Q1Q2Q3, 0),
        ] {
            if reduce == 0 && n > 10_000 {
                continue;
            }
            let raw = RawTargets {
                offsets: &d.off,
                rotations: &d.rot,
                link_angles: Some((&d.la, 18)),
                node_offsets: Some((&d.no, 33)),
            };
            let t = build_targets(&raw, q, reduce).unwrap();
            let crit = Crit::new(t.layout.clone(), 1e-4);
            let subset: Vec<u32> = (0..n as u32).collect();
            let cfg = SplitConfig {
                n_thresholds: 16,
                min_samples_leaf: 5,
                parallel: true,
            };
            group.throughput(Throughput::Elements((n * n_cand) as u64));
            group.bench_with_input(
                BenchmarkId::new(name, format!("{}k", n / 1000)),
                &n,
                |b, _| b.iter(|| best_split_columns(&crit, &t, &subset, n_cand, &feats, &cfg, 1)),
            );
        }
    }
    group.finish();
}

/// Synthetic scene-like images: a tilted plane with a box on it, depths 1-3 m, 10% holes.
pub fn synthetic_images(n_images: usize, w: usize, h: usize, rng: &mut ChaCha8Rng) -> DepthStore {
    let mut s = DepthStore::new();
    for _ in 0..n_images {
        let base = rng.random_range(1000.0..3000.0f32);
        let (bx, by) = (rng.random_range(0..w / 2), rng.random_range(0..h / 2));
        let px: Vec<u16> = (0..w * h)
            .map(|i| {
                let (u, v) = (i % w, i / w);
                if rng.random_range(0.0..1.0f32) < 0.1 {
                    return 0;
                }
                let mut d = base + 2.0 * v as f32;
                if (bx..bx + w / 3).contains(&u) && (by..by + h / 3).contains(&v) {
                    d -= 300.0;
                }
                d as u16
            })
            .collect();
        s.push(w, h, &px).unwrap();
    }
    s
}

fn traversal(c: &mut Criterion) {
    let mut group = c.benchmark_group("traversal");
    group.sample_size(10);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let store = synthetic_images(40, 120, 100, &mut rng);
    let parts = isa_core::sample_parts(&store, 2, None, 0).unwrap();
    let n = parts.len();
    // Train the forest only when this benchmark is selected.
    let mut forest: Option<Forest> = None;
    let mut make = || {
        let off: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-0.5..0.5)).collect();
        let rot: Vec<f32> = (0..n)
            .flat_map(|i| [1.0, 0.0, 0.0, (i % 13) as f32 * 0.05])
            .collect();
        let params = ForestParams {
            n_trees: 10,
            max_depth: 20,
            n_candidates: 20,
            quality: Quality::Q1,
            ..Default::default()
        };
        let data = TrainingSet {
            store: &store,
            parts: &parts,
            targets: RawTargets::pose(&off, &rot),
        };
        Forest::fit(
            &params.clone().check().unwrap(),
            &data,
            Default::default(),
            None,
        )
        .unwrap()
    };
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function("10_trees", |b| {
        let f = forest.get_or_insert_with(&mut make);
        b.iter(|| f.apply(&store, &parts).unwrap())
    });
    group.finish();
}

criterion_group!(benches, split_search, traversal);
criterion_main!(benches);
