//! The CLI's camera-file reader (BOP `camera.json` / `scene_camera.json`; compiled in from
//! crates/isa-cli/src/inputs.rs) on arbitrary files; what reads gives valid intrinsics.
#![no_main]

mod cli_files;

// `inputs` names its errors `crate::error`.
use cli_files::{error, inputs};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = cli_files::temp_file("camera.json", data);
    if let Ok(cam) = inputs::CameraFile::read(&path) {
        for id in [None, Some(0), Some(1), Some(u64::MAX)] {
            if let Ok((k, _, scale)) = cam.for_image(id) {
                k.validate().unwrap();
                assert!(scale.is_finite());
            }
        }
    }
});
