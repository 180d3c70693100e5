//! `isa` command-line interface: train a category forest from a training-set file, predict 6D
//! poses in depth PNGs, detect every object of several categories in room frames, inspect
//! model files. See `isa --help` and `isa <command> --help`.
//!
//! [`run`] is the whole program: the `isa` binary (`main.rs`) and the Python package's `isa`
//! console script (`isa.cli`, through the binding's `_cli_main`) both call it.
//!
//! Files: `args` (the command line), `commands/` (one per subcommand), `inputs` (depth PNGs,
//! camera files, BOP folders), `output` (JSON, BOP CSV, text), `error` (exit codes),
//! `progress` (bars, threads).

mod args;
mod commands;
mod error;
mod inputs;
mod output;
mod progress;

use std::ffi::OsString;
use std::io::Write;

use clap::Parser;

use args::{Cli, Command};

/// Runs the command line `argv` (program name first) and returns its exit code (see
/// `isa --help`): usage errors and `--help` / `--version` print as clap prints them.
pub fn run<I, T>(argv: I) -> u8
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(argv) {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return u8::try_from(e.exit_code()).unwrap_or(2);
        }
    };
    let res = match cli.command {
        Command::Train(a) => commands::train::run(a),
        Command::Predict(a) => commands::predict::run(a),
        Command::Detect(a) => commands::detect::run(a),
        Command::Inspect(a) => commands::inspect::run(a),
    };
    match res {
        Ok(()) => 0,
        Err(e) => {
            // Not eprintln!: it panics when standard error is closed.
            let _ = writeln!(std::io::stderr(), "isa: error: {}", e.msg);
            e.code
        }
    }
}
