//! Every parameter set of the core, in one place: training ([`ForestParams`]), mode finding
//! ([`VoteParams`]) and whole-image inference ([`PredictParams`]).
//!
//! Depth input ([`DepthParams`]: `depth_scale`) sits here too.
//!
//! Each is validated once: `check(self)` returns a [`Valid`] wrapper, which only this module can
//! build, and the functions that use the parameters ([`Forest::fit`](crate::Forest::fit),
//! [`predict`](crate::vote::predict)) take the wrapper, so they cannot receive unchecked values.
//! Every front end (the Python binding's keyword arguments, the CLI's flags and parameter files,
//! a model's stored inference defaults) builds them with one JSON overlay
//! ([`ForestParams::overlay`], [`PredictParams::overlay`], [`VoteParams::overlay`]) whose
//! messages name the key and where it came from.

mod checks;
mod depth;
mod detect;
mod forest;
mod overlay;
mod predict;

pub use depth::{DepthParams, DEPTH_SCALE_HELP};
pub use detect::{
    DetectParams, NmsOrder, PlaneParams, ProposalParams, RefineParams, VerifyParams,
    DEPTH_TOLERANCE,
};
pub use forest::{ForestParams, Quality};
pub use overlay::overlay_json;
pub use predict::{PredictParams, VoteParams};

use serde::{Serialize, Serializer};

/// Parameters that passed their type's `check()`. Read through `Deref`; built only by `check`
/// (and by the model reader, which checks what it reads).
#[derive(Clone, Debug, PartialEq)]
pub struct Valid<T>(T);

impl<T> Valid<T> {
    /// The checked parameters, to edit and check again.
    pub fn into_inner(self) -> T {
        self.0
    }
}

impl<T> std::ops::Deref for Valid<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<T: Serialize> Serialize for Valid<T> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        self.0.serialize(s)
    }
}
