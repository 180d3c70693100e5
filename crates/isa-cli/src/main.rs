//! `isa` command-line interface: train a category forest from a training-set file, predict 6D
//! poses in depth PNGs, detect every object of several categories in room frames, inspect
//! model files. See `isa --help` and `isa <command> --help`.
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

use std::io::Write;
use std::process::ExitCode;

use clap::Parser;

use args::{Cli, Command};

fn main() -> ExitCode {
    let cli = Cli::parse();
    let res = match cli.command {
        Command::Train(a) => commands::train::run(a),
        Command::Predict(a) => commands::predict::run(a),
        Command::Detect(a) => commands::detect::run(a),
        Command::Inspect(a) => commands::inspect::run(a),
    };
    match res {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Not eprintln!: it panics when standard error is closed.
            let _ = writeln!(std::io::stderr(), "isa: error: {}", e.msg);
            ExitCode::from(e.code)
        }
    }
}
