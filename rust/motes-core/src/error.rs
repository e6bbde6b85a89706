//! Errors of the core: each names the offending argument so the Python layer can raise a precise
//! `ValueError`.
//!
//! Infrastructure: implements no equation of the paper.

use std::fmt;

#[derive(Clone, Debug, PartialEq)]
pub enum OpticsError {
    /// `argument` had `value`, which violates `requirement`.
    InvalidArgument {
        argument: &'static str,
        value: f64,
        requirement: &'static str,
    },
    /// An option outside its allowed set.
    InvalidOption {
        argument: &'static str,
        value: String,
        allowed: &'static str,
    },
}

impl fmt::Display for OpticsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OpticsError::InvalidArgument {
                argument,
                value,
                requirement,
            } => {
                write!(f, "invalid {argument} = {value}: must be {requirement}")
            }
            OpticsError::InvalidOption {
                argument,
                value,
                allowed,
            } => {
                write!(
                    f,
                    "invalid {argument} = {value:?}: allowed values are {allowed}"
                )
            }
        }
    }
}

impl std::error::Error for OpticsError {}

/// Check `pred(value)`, else an `InvalidArgument` error.
pub fn require(
    argument: &'static str,
    value: f64,
    ok: bool,
    requirement: &'static str,
) -> Result<(), OpticsError> {
    if ok {
        Ok(())
    } else {
        Err(OpticsError::InvalidArgument {
            argument,
            value,
            requirement,
        })
    }
}

/// An array argument whose length must equal `expected` (e.g. one entry per particle).
pub fn require_len(
    argument: &'static str,
    len: usize,
    expected: usize,
    requirement: &'static str,
) -> Result<(), OpticsError> {
    require(argument, len as f64, len == expected, requirement)
}

/// An array argument that needs at least `min` entries (e.g. a non-empty list).
pub fn require_min_len(
    argument: &'static str,
    len: usize,
    min: usize,
    requirement: &'static str,
) -> Result<(), OpticsError> {
    require(argument, len as f64, len >= min, requirement)
}
