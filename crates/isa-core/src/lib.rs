//! Intrinsic Structure Adaptor (ISA): a part-based one-class random forest that votes for the
//! category-level 6D pose of objects in a depth image (Sahin & Kim, "Category-level 6D Object
//! Pose Recovery in Depth Images").
//!
//! The crate is pure Rust; `isa-py` binds it to Python and `isa-cli` wraps it as a binary.
//!
//! Module map: [`depth`] (image store, part sampling), [`features`] (Eq. 5),
//! [`criterion`] (Q1/Q2/Q3, Eq. 9-11), [`splitter`] (split search), [`tree`] (builder, leaf
//! votes), [`forest`] (training, traversal API for voting), [`params`] (every parameter set, validated
//! once, one JSON overlay), [`metadata`] (what a model says about itself), [`model_io`] (model
//! files).

pub mod criterion;
pub mod depth;
pub mod error;
pub mod features;
pub mod forest;
pub mod metadata;
pub mod model_io;
pub mod params;
pub mod rng;
pub mod splitter;
pub mod trainset_io;
pub mod tree;
pub mod vote;

pub use depth::{sample_parts, DepthStore, Part};
pub use error::{IsaError, Result};
pub use features::{Feature, BACKGROUND_MM};
pub use forest::{Forest, PartVote, TrainingSet};
pub use metadata::ModelMetadata;
pub use params::{ForestParams, PredictParams, Quality, Valid, VoteParams};
pub use tree::{Tree, Vote};

/// Version of this crate, written into every model file.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
