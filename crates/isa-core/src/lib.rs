//! Intrinsic Structure Adaptor (ISA): a part-based one-class random forest that votes for the
//! category-level 6D pose of objects in a depth image (Sahin & Kim, "Category-level 6D Object
//! Pose Recovery in Depth Images").
//!
//! The crate is pure Rust; `isa-py` binds it to Python and `isa-cli` wraps it as a binary.

pub mod error;
/// Vote aggregation, mode finding and whole-image prediction (inference helper's module).
pub mod vote;

pub use error::{IsaError, Result};

/// Version of this crate, written into every model file.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
