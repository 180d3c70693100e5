//! The CLI's depth PNG reader (crates/isa-cli/src/inputs.rs, compiled in) on arbitrary files.
#![no_main]

#[allow(dead_code)]
#[path = "../../crates/isa-cli/src/error.rs"]
mod error;
#[allow(dead_code)]
#[path = "../../crates/isa-cli/src/inputs.rs"]
mod inputs;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::env::temp_dir().join(format!("isa-fuzz-depth-{}.png", std::process::id()));
    std::fs::write(&path, data).unwrap();
    let scale = if data.first().is_some_and(|b| b & 1 == 1) { 0.1 } else { 1.0 };
    if let Ok(d) = inputs::read_depth_png(&path, scale) {
        assert_eq!(d.mm.len(), d.width * d.height);
    }
});
