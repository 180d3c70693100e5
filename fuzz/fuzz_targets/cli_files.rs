//! The CLI's file readers (crates/isa-cli/src/inputs.rs and the errors it returns, compiled in)
//! for the targets that fuzz them, and the file those targets write their input to.

#[allow(dead_code)]
#[path = "../../crates/isa-cli/src/error.rs"]
pub mod error;
#[allow(dead_code)]
#[path = "../../crates/isa-cli/src/inputs.rs"]
pub mod inputs;

/// Writes `data` to this process's temporary file `isa-fuzz-{name}` and returns its path.
pub fn temp_file(name: &str, data: &[u8]) -> std::path::PathBuf {
    let path = std::env::temp_dir().join(format!("isa-fuzz-{}-{name}", std::process::id()));
    std::fs::write(&path, data).unwrap();
    path
}
