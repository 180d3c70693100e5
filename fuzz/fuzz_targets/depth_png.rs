//! The CLI's depth PNG reader (crates/isa-cli/src/inputs.rs, compiled in) on arbitrary files.
#![no_main]

mod cli_files;

// `inputs` names its errors `crate::error`.
use cli_files::{error, inputs};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = cli_files::temp_file("depth.png", data);
    let scale = if data.first().is_some_and(|b| b & 1 == 1) { 0.1 } else { 1.0 };
    if let Ok(d) = inputs::read_depth_png(&path, scale) {
        assert_eq!(d.mm.len(), d.width * d.height);
    }
});
