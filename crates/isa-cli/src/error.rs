//! Errors with their exit codes (see `args::EXIT_CODES`); the message names the file or
//! parameter at fault.

use std::path::Path;

use isa_core::IsaError;

#[derive(Debug)]
pub struct CliError {
    pub code: u8,
    pub msg: String,
}

pub type CliResult<T> = Result<T, CliError>;

impl CliError {
    pub fn missing(path: &Path, what: &str) -> Self {
        CliError {
            code: 3,
            msg: format!("{what} {} does not exist", path.display()),
        }
    }
    pub fn io(path: &Path, e: std::io::Error) -> Self {
        CliError {
            code: 3,
            msg: format!("cannot read or write {}: {e}", path.display()),
        }
    }
    pub fn input(msg: String) -> Self {
        CliError { code: 4, msg }
    }
    pub fn param(msg: String) -> Self {
        CliError { code: 5, msg }
    }
}

impl From<IsaError> for CliError {
    fn from(e: IsaError) -> Self {
        let code = match &e {
            IsaError::Io { .. } => 3,
            IsaError::ModelFormat { .. } | IsaError::InvalidInput(_) => 4,
            IsaError::InvalidParameter(_) => 5,
        };
        CliError {
            code,
            msg: e.to_string(),
        }
    }
}

/// Prints `isa: warning: msg` to standard error (not eprintln!, which panics when it is closed).
pub fn warn(msg: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "isa: warning: {msg}");
}
