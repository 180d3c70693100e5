//! PyO3 binding of `isa-core`, importable as `isa._core`. This layer only converts: NumPy
//! arrays in and out (`arrays`), keyword arguments to the core's parameter overlay (`params`),
//! core errors to their Python exception classes (`errors`), scalar arguments checked into
//! `isa` errors (`scalars`). One file per domain: the forest
//! (`forest`, with `predict` / `image_votes` methods), inference (`predict`, `hypothesis`),
//! depth input (`depth_input`: `depth_scale`, size checks, warnings, point clouds), depth rendering (`render`), features (`features`), scene detection (`scene`), training-set files (`trainset`), the `isa` command line (`cli`, for the console script), and test hooks in the private
//! submodule `isa._core._testing` (`testing`).

use pyo3::prelude::*;

pub mod arrays;
pub mod cli;
pub mod depth_input;
pub mod errors;
pub mod features;
pub mod forest;
pub mod hypothesis;
pub mod params;
pub mod predict;
pub mod render;
pub mod scalars;
pub mod scene;
pub mod shards;
pub mod testing;
pub mod trainset;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", isa_core::VERSION)?;
    m.add("MODEL_FORMAT_VERSION", isa_core::model_io::FORMAT_VERSION)?;
    m.add("BACKGROUND_MM", isa_core::BACKGROUND_MM)?;
    errors::register(m)?;
    params::register(m)?;
    m.add_class::<forest::PyForest>()?;
    hypothesis::register(m)?;
    m.add_function(wrap_pyfunction!(features::sample_parts, m)?)?;
    m.add_function(wrap_pyfunction!(features::depth_features, m)?)?;
    predict::register(m)?;
    depth_input::register(m)?;
    render::register(m)?;
    cli::register(m)?;
    scene::register(m)?;
    trainset::register(m)?;
    shards::register(m)?;
    m.add_submodule(&testing::submodule(m.py())?)?;
    Ok(())
}
