//! Errors of the core. Each variant maps to its own Python exception class in `isa-py`.

use thiserror::Error;

/// Everything that can go wrong in the core. Messages name the argument or file at fault.
#[derive(Debug, Error)]
pub enum IsaError {
    /// An argument has the wrong shape, range or value (names the argument).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// Hyper-parameters failed validation (names the parameter).
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// A model file is truncated, corrupted, foreign or from a newer format version.
    #[error("invalid model file {path}: {reason}")]
    ModelFormat { path: String, reason: String },
    /// An operating-system I/O failure (names the file).
    #[error("I/O error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
}

pub type Result<T> = std::result::Result<T, IsaError>;
