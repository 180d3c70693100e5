//! Progress display on standard error (hidden with `--quiet`), and the thread pool.

use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

use crate::error::{CliError, CliResult};

pub fn spinner(quiet: bool, msg: String) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed_precise}]").expect("template"),
    );
    pb.set_message(msg);
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

pub fn bar(quiet: bool, n: u64, msg: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(n);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} [{elapsed_precise}, eta {eta}]")
            .expect("template")
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// Runs `f` on `threads` worker threads (`--threads`; None = all cores).
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> CliResult<T> {
    if threads == Some(0) {
        return Err(CliError::param("--threads must be at least 1".into()));
    }
    isa_core::forest::with_threads(threads, f).map_err(CliError::from)
}
