//! How stored depth values become distances ([`DepthParams`]): the one `depth_scale` that the
//! binding's `depth_scale=` keyword, the CLI's `--depth-scale` flag and a BOP camera file's
//! `depth_scale` set. The conversion and its checks are [`crate::depth_input`].

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::overlay::overlay_json;
use super::Valid;
use crate::error::{IsaError, Result};

/// What `depth_scale` means, for help texts and docstrings (the field's documentation).
pub const DEPTH_SCALE_HELP: &str = "Millimetres per unit of the stored depth values (BOP's \
depth_scale): 1 for uint16 millimetre PNGs (Kinect, NYU, BOP), 0.2 for TUM RGB-D (5000 per \
metre), 0.1 for 0.1-mm sensors, 1 for float millimetres, 1000 for float metres";

/// Depth input parameters.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthParams {
    /// [`DEPTH_SCALE_HELP`]. `None`: by the values' type, 1 for integers (millimetres), 1000
    /// for floats (metres).
    pub depth_scale: Option<f64>,
}

impl DepthParams {
    /// `depth_scale` finite and in `[1e-4, 1e4]` (0.1 µm to 10 m per unit).
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = self.depth_scale {
            if !(s.is_finite() && (1e-4..=1e4).contains(&s)) {
                return Err(IsaError::InvalidParameter(format!(
                    "depth_scale must be in [1e-4, 1e4] millimetres per unit, got {s}"
                )));
            }
        }
        Ok(())
    }

    pub fn check(self) -> Result<Valid<Self>> {
        self.validate()?;
        Ok(Valid(self))
    }

    /// Replaces the fields named in `json`; errors name the key and `source`.
    pub fn overlay(&mut self, json: &Value, source: &str) -> Result<()> {
        *self = overlay_json(self, json, source)?;
        Ok(())
    }

    /// Millimetres per unit for integer (`float == false`) or float values.
    pub fn mm_per_unit(&self, float: bool) -> f64 {
        self.depth_scale.unwrap_or(if float { 1000.0 } else { 1.0 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;
    use serde_json::json;

    #[test]
    fn defaults_follow_the_type_and_the_overlay_names_bad_keys() {
        let p = DepthParams::default();
        assert_eq!((p.mm_per_unit(false), p.mm_per_unit(true)), (1.0, 1000.0));
        let mut p = DepthParams::default();
        p.overlay(&json!({"depth_scale": 0.2}), "flags").unwrap();
        assert_eq!((p.mm_per_unit(false), p.mm_per_unit(true)), (0.2, 0.2));
        expect_err(
            p.overlay(&json!({"scale": 1}), "flags"),
            &["flags", "\"scale\""],
        );
        for bad in [0.0, -1.0, 1e9] {
            expect_err(
                DepthParams {
                    depth_scale: Some(bad),
                }
                .check(),
                &["depth_scale"],
            );
        }
    }
}
