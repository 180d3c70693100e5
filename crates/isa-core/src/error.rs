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

/// Tests: the message of `r`'s error, asserted to hold every one of `needles`.
#[cfg(test)]
#[track_caller]
pub(crate) fn expect_err<T, E: std::fmt::Display>(
    r: std::result::Result<T, E>,
    needles: &[&str],
) -> String {
    let e = match r {
        Ok(_) => panic!("expected an error holding {needles:?}"),
        Err(e) => e.to_string(),
    };
    for n in needles {
        assert!(e.contains(n), "{n:?} not in: {e}");
    }
    e
}
