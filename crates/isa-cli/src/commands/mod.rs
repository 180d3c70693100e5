//! One module per subcommand, and what they share: reading JSON and model files, the
//! parameter overlay sources.

pub mod detect;
pub mod inspect;
pub mod predict;
pub mod train;

use std::path::Path;

use serde::Serialize;
use serde_json::Value;

use isa_core::Forest;

use crate::args::{InferenceArgs, ParamFlags};
use crate::error::{CliError, CliResult};
use crate::inputs::read_json;

/// Where flag values come from, in the core's overlay messages.
pub const FLAGS: &str = "flags";

/// The `--params` file (if given) as an overlay source: its JSON and its name.
pub fn params_file(path: Option<&Path>) -> CliResult<Option<(Value, String)>> {
    path.map(|p| {
        Ok((
            read_json(p, "parameter file", CliError::param)?,
            format!("parameter file {}", p.display()),
        ))
    })
    .transpose()
}

/// The given flags (a struct of `Option`s; `None`, a flag not given, dropped) as a JSON object.
pub fn flags_json(flags: &impl Serialize) -> Value {
    let mut v = serde_json::to_value(flags).expect("flags serialise");
    if let Some(o) = v.as_object_mut() {
        o.retain(|_, x| !x.is_null());
    }
    v
}

/// The overlay sources of `predict` and `detect`, in order: the `--params` file (if given),
/// then the flags.
pub fn overlay_sources<F: ParamFlags>(a: &InferenceArgs<F>) -> CliResult<Vec<(Value, String)>> {
    let mut sources: Vec<(Value, String)> = params_file(a.params.as_deref())?.into_iter().collect();
    sources.push((flags_json(&a.flags), FLAGS.to_string()));
    Ok(sources)
}

pub fn load_model(path: &Path) -> CliResult<Forest> {
    if !path.exists() {
        return Err(CliError::missing(path, "model file"));
    }
    Ok(Forest::load(path)?)
}
