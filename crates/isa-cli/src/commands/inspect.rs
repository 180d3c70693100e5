//! `isa inspect`: what a model file holds, as text or JSON.

use super::load_model;
use crate::args::InspectArgs;
use crate::error::CliResult;
use crate::output;

pub fn run(a: InspectArgs) -> CliResult<()> {
    let forest = load_model(&a.model)?;
    let bytes = std::fs::metadata(&a.model).map(|m| m.len()).unwrap_or(0);
    // The header's version (the file loaded, so it has one).
    let mut head = [0u8; 12];
    let version = std::fs::File::open(&a.model)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .ok()
        .and_then(|_| isa_core::model_io::file_version(&head))
        .unwrap_or(isa_core::model_io::FORMAT_VERSION);
    let file = output::ModelFile {
        path: &a.model,
        bytes,
        version,
    };
    let text = if a.json {
        output::inspect_json(&forest, &file)
    } else {
        output::inspect_text(&forest, &file)
    };
    output::write(None, &text)
}
