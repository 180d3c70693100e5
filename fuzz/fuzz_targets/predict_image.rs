//! `predict` on arbitrary depth images, intrinsics and parameters, with a forest trained once
//! on a synthetic set: the first bytes choose the size, camera and stride, the rest are pixels.
#![no_main]

use std::sync::OnceLock;

use isa_core::criterion::RawTargets;
use isa_core::vote::{predict, DepthImage, Intrinsics};
use isa_core::{sample_parts, DepthStore, Forest, ForestParams, PredictParams, TrainingSet};
use libfuzzer_sys::fuzz_target;

fn forest() -> &'static Forest {
    static F: OnceLock<Forest> = OnceLock::new();
    F.get_or_init(|| {
        let mut store = DepthStore::new();
        for i in 0..2u16 {
            let px: Vec<u16> = (0..32 * 24).map(|j| 900 + ((j as u16 * 7 + i * 13) % 400)).collect();
            store.push(32, 24, &px).unwrap();
        }
        let parts = sample_parts(&store, 2, None, 0).unwrap();
        let n = parts.len();
        let offsets: Vec<f32> = (0..3 * n).map(|i| ((i % 17) as f32 - 8.0) * 0.01).collect();
        let rotations: Vec<f32> = (0..n).flat_map(|i| if i % 2 == 0 { [1.0, 0.0, 0.0, 0.0] } else { [0.0, 0.0, 0.6, 0.8] }).collect();
        let data = TrainingSet {
            store: &store,
            parts: &parts,
            targets: RawTargets { offsets: &offsets, rotations: &rotations, link_angles: None, node_offsets: None },
        };
        let p = ForestParams { n_trees: 2, max_depth: 6, n_candidates: 20, quality: isa_core::Quality::Q1, ..Default::default() };
        Forest::fit(&p.check().unwrap(), &data, Default::default(), Some(1)).unwrap()
    })
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 8 {
        return;
    }
    let (w, h) = (1 + data[0] as usize % 48, 1 + data[1] as usize % 48);
    let f = |b: u8| (b as f64 - 128.0) * 4.0;
    let k = Intrinsics { fx: 1.0 + data[2] as f64 * 3.0, fy: 1.0 + data[3] as f64 * 3.0, cx: f(data[4]), cy: f(data[5]) };
    let stride = 1 + data[6] as usize % 4;
    let px: Vec<u16> = data[8..].chunks(2).map(|c| u16::from_le_bytes([c[0], *c.get(1).unwrap_or(&0)])).cycle().take(w * h).collect();
    let px = if px.len() == w * h { px } else { vec![0; w * h] };
    let img = DepthImage::new(&px, w, h).unwrap();
    let mut p = PredictParams { stride, ..Default::default() };
    p.vote.position_bandwidth = 0.005 + data[7] as f32 * 0.002;
    let Ok(p) = p.check() else { return };
    // An error (e.g. intrinsics that do not fit the image) is an answer; only a panic or a
    // non-finite pose is a bug.
    let Ok(hyps) = predict(forest(), &img, &k, &p) else { return };
    for hy in hyps {
        assert!(hy.translation.iter().chain(&hy.quaternion).all(|v| v.is_finite()));
    }
});
