//! The model decoder on arbitrary bytes, as a file (header checks) and as a payload behind a
//! valid header (the parser itself); whatever decodes is traversed and predicts without panic.
#![no_main]

use isa_core::model_io::{self, fnv1a64, MAGIC};
use isa_core::vote::{predict, DepthImage, Intrinsics};
use isa_core::PredictParams;
use libfuzzer_sys::fuzz_target;

fn sealed(version: u32, payload: &[u8]) -> Vec<u8> {
    let mut b = MAGIC.to_vec();
    b.extend_from_slice(&version.to_le_bytes());
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    b.extend_from_slice(&fnv1a64(payload).to_le_bytes());
    b.extend_from_slice(payload);
    b
}

fuzz_target!(|data: &[u8]| {
    let _ = model_io::decode(data, "fuzz");
    // A seed file's payload (after its 32-byte header) under a fixed-up checksum.
    let (version, payload) = match data.get(..32) {
        Some(h) if h.starts_with(MAGIC) => (u32::from_le_bytes(h[8..12].try_into().unwrap()).clamp(1, 2), &data[32..]),
        _ => (2, data),
    };
    if let Ok(f) = model_io::decode(&sealed(version, payload), "fuzz") {
        let depth: Vec<u16> = (0..24 * 16).map(|i| [0u16, 1, 800, 1500, 65535][i % 5]).collect();
        let img = DepthImage::new(&depth, 24, 16).unwrap();
        let k = Intrinsics { fx: 30.0, fy: 30.0, cx: 12.0, cy: 8.0 };
        let p = PredictParams { stride: 2, ..Default::default() }.check().unwrap();
        for h in predict(&f, &img, &k, &p).unwrap() {
            assert!(h.translation.iter().chain(&h.quaternion).all(|v| v.is_finite()));
        }
    }
});
