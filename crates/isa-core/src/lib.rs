//! Intrinsic Structure Adaptor (ISA): a part-based one-class random forest that votes for the
//! category-level 6D pose of objects in a depth image (Sahin & Kim, "Category-level 6D Object
//! Pose Recovery in Depth Images").
//!
//! The crate is pure Rust; `isa-py` binds it to Python and `isa-cli` wraps it as a binary.
//!
//! Module map, in data-flow order:
//! * training data: [`depth`] (image store, part sampling), [`trainset_io`] (training-set files);
//! * the split function: [`features`] (Eq. 5) and its depth probe (`probe`: scalar and AVX2);
//! * training: [`criterion`] (Q1/Q2/Q3, Eq. 9-11), [`splitter`] (split search: binning,
//!   accumulation, the search loop), [`tree`] (builder, leaf votes), [`forest`] (training, the
//!   traversal API, and `forest::flat`: the fast inference traversal kept with the forest);
//! * depth input: [`depth_input`] (stored values to millimetres or metres by `depth_scale`, the
//!   checks of scale and image size, point clouds to depth images);
//! * inference: [`vote`] (whole-image voting in `vote::predict`, then mode finding: grid,
//!   gather, position modes, NMS, rotation modes);
//! * rendering: [`render`] (depth frames of triangle meshes: the z-buffer rasteriser that
//!   renders training and test views without OpenGL);
//! * scenes: [`scene`] (every category model over one room frame: gravity, planes, votes,
//!   verification against shape libraries, size, ICP refinement, NMS across categories);
//! * shared: [`rotation`] (quaternions and matrices on nalgebra), [`rng`] (seeding),
//!   [`params`] (every parameter set, validated once, one JSON overlay), [`metadata`] (what a
//!   model says about itself), [`model_io`] (model files), [`atomic`] (whole-or-nothing file writes), [`error`].
//!
//! Dependencies run one way: `vote` uses `forest`, `forest` never uses `vote`.

pub mod atomic;
pub mod criterion;
pub mod depth;
pub mod depth_input;
pub mod error;
pub mod features;
pub mod forest;
pub mod metadata;
pub mod model_io;
pub mod params;
pub(crate) mod probe;
pub mod render;
pub mod rng;
pub mod rotation;
pub mod scene;
pub mod shards;
pub mod splitter;
pub mod targets;
pub mod trainset_io;
pub mod tree;
pub mod vote;

pub use depth::{sample_parts, DepthStore, Part};
pub use error::{IsaError, Result};
pub use features::{Feature, BACKGROUND_MM};
pub use forest::{Forest, PartVote, TrainData, TrainingSet};
pub use metadata::ModelMetadata;
pub use params::{
    DepthParams, DetectParams, ForestParams, PredictParams, Quality, Valid, VoteParams,
};
pub use tree::{Tree, Vote};

/// Version of this crate, written into every model file.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
