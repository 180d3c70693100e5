//! `isa inspect`: what a model file holds, as text or JSON.

use super::load_model;
use crate::args::InspectArgs;
use crate::error::CliResult;
use crate::output;

pub fn run(a: InspectArgs) -> CliResult<()> {
    let forest = load_model(&a.model)?;
    let bytes = std::fs::metadata(&a.model).map(|m| m.len()).unwrap_or(0);
    let text = if a.json {
        output::inspect_json(&forest, &a.model, bytes)
    } else {
        output::inspect_text(&forest, &a.model, bytes)
    };
    output::write(None, &text)
}
