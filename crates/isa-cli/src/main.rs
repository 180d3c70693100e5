//! `isa` command-line interface.
use clap::Parser;

/// Category-level 6D object pose from depth images (Intrinsic Structure Adaptor).
#[derive(Parser)]
#[command(name = "isa", version = isa_core::VERSION)]
struct Cli {}

fn main() {
    let _cli = Cli::parse();
}
