//! Per-leaf vote weights: how likely a part that reaches a leaf lies on an object of the
//! category, learnt from parts on and off objects in rooms (background parts, as Hough forests
//! weight their leaves). A one-class forest has none: every vote counts fully. With them every
//! vote of leaf `l` of tree `t` is multiplied by `w[t][l]` when an image is voted on, so floor
//! and wall parts that reach object-like leaves count less. Stored in the model file (format
//! version 3, [`crate::model_io`]).

use crate::error::{IsaError, Result};
use crate::tree::Tree;

/// Weights in [0, 1], one per leaf of each tree (tree order), validated against the trees.
#[derive(Clone, Debug, PartialEq)]
pub struct LeafWeights(Vec<Vec<f32>>);

impl LeafWeights {
    /// Checks `per_tree` against `trees`: one weight per leaf, each finite and in [0, 1]; the
    /// error names the tree and leaf.
    pub fn new(per_tree: Vec<Vec<f32>>, trees: &[Tree]) -> Result<Self> {
        Self::checked(per_tree, trees).map_err(IsaError::InvalidInput)
    }

    /// [`LeafWeights::new`] with the reason as text (the model decoder words its own error).
    pub(crate) fn checked(
        per_tree: Vec<Vec<f32>>,
        trees: &[Tree],
    ) -> std::result::Result<Self, String> {
        if per_tree.len() != trees.len() {
            return Err(format!(
                "leaf weights: {} trees of weights for a forest of {} trees",
                per_tree.len(),
                trees.len()
            ));
        }
        for (t, (w, tree)) in per_tree.iter().zip(trees).enumerate() {
            if w.len() != tree.n_leaves() {
                return Err(format!(
                    "leaf weights: tree {t} has {} leaves, {} weights given",
                    tree.n_leaves(),
                    w.len()
                ));
            }
            if let Some((l, x)) = w
                .iter()
                .enumerate()
                .find(|(_, x)| !(0.0..=1.0).contains(*x))
            {
                return Err(format!(
                    "leaf weights: tree {t} leaf {l} is {x}, not in [0, 1]"
                ));
            }
        }
        Ok(LeafWeights(per_tree))
    }

    /// The weight of leaf `leaf` of tree `tree`.
    #[inline]
    pub fn get(&self, tree: usize, leaf: usize) -> f32 {
        self.0[tree][leaf]
    }

    /// Weights per tree, per leaf.
    pub fn per_tree(&self) -> &[Vec<f32>] {
        &self.0
    }
}
