//! The checks that the parameter sets' `validate` share; each error names the parameter.

use crate::error::{IsaError, Result};

/// The error "`name` `why`".
pub(super) fn bad<T>(name: &str, why: String) -> Result<T> {
    Err(IsaError::InvalidParameter(format!("{name} {why}")))
}

pub(super) fn positive(name: &str, x: f64) -> Result<()> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        bad(name, format!("must be finite and > 0, got {x}"))
    }
}

pub(super) fn non_negative(name: &str, x: f64) -> Result<()> {
    if x.is_finite() && x >= 0.0 {
        Ok(())
    } else {
        bad(name, format!("must be finite and >= 0, got {x}"))
    }
}

/// `[(prefix + "field", self.field), ...]`: fields with the names their errors give, for
/// [`at_least_one`] and loops over one check.
macro_rules! named {
    ($s:expr, $prefix:literal; $($f:ident),+ $(,)?) => {
        [$((concat!($prefix, stringify!($f)), $s.$f)),+]
    };
}
pub(super) use named;

/// `check(prefix + "field", self.field)?` for each `check(field)`, in order: one check a field,
/// each error naming the field.
macro_rules! checked {
    ($s:expr, $prefix:literal; $($check:ident($f:ident)),+ $(,)?) => {
        $( $check(concat!($prefix, stringify!($f)), $s.$f)?; )+
    };
}
pub(super) use checked;

/// Each `(name, count)` is at least 1.
pub(super) fn at_least_one(counts: &[(&str, usize)]) -> Result<()> {
    match counts.iter().find(|(_, v)| *v == 0) {
        Some((name, _)) => bad(name, "must be >= 1, got 0".into()),
        None => Ok(()),
    }
}

/// `v` is in `lo..=hi`.
pub(super) fn in_range(name: &str, v: usize, lo: usize, hi: usize) -> Result<()> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        bad(name, format!("must be in {lo}..={hi}, got {v}"))
    }
}
