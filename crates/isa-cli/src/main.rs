//! The `isa` binary: the command line of the `isa_cli` library ([`isa_cli::run`]).

use std::process::ExitCode;

fn main() -> ExitCode {
    ExitCode::from(isa_cli::run(std::env::args_os()))
}
