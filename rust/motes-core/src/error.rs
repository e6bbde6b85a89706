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
    /// `argument` had `value`, outside a range that depends on the other inputs (e.g. the cells per
    /// particle a grid of n particles takes), stated in `requirement`.
    OutOfRange {
        argument: &'static str,
        value: f64,
        requirement: String,
    },
    /// An allocation of `bytes` for `what` failed: the memory that `argument` (the input that drives
    /// its size) asks for is not there. The Python layer raises a `MemoryError`.
    OutOfMemory {
        argument: &'static str,
        what: &'static str,
        bytes: f64,
    },
}

impl fmt::Display for OpticsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let invalid =
            |f: &mut fmt::Formatter<'_>, argument: &str, value: f64, requirement: &str| {
                write!(
                    f,
                    "invalid {argument} = {}: must be {requirement}",
                    shown(value)
                )
            };
        match self {
            OpticsError::InvalidArgument {
                argument,
                value,
                requirement,
            } => invalid(f, argument, *value, requirement),
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
            OpticsError::OutOfRange {
                argument,
                value,
                requirement,
            } => invalid(f, argument, *value, requirement),
            OpticsError::OutOfMemory {
                argument,
                what,
                bytes,
            } => {
                write!(
                    f,
                    "out of memory: {what} needs {:.2} GiB more, which the system refused (lower {argument})",
                    bytes / (1u64 << 30) as f64
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

/// `x` as a message shows it: its shortest decimal form where that is short (20000, 0.0125), else in
/// scientific notation (1e15, 1e308), with four significant digits where it has more (6.6667e7).
pub fn shown(x: f64) -> String {
    let (plain, short) = (format!("{x}"), format!("{x:e}"));
    if plain.len() <= 10 {
        plain
    } else if short.len() <= 10 {
        short
    } else {
        format!("{x:.4e}")
    }
}

/// `len` copies of `value` in a vector whose allocation may fail: an [`OpticsError::OutOfMemory`]
/// naming `what` and the input that drives its size (`argument`), instead of the process aborting in
/// the allocator. For the large arrays of a build (a grid's cells, its references).
pub fn try_filled<T: Clone>(
    len: usize,
    value: T,
    argument: &'static str,
    what: &'static str,
) -> Result<Vec<T>, OpticsError> {
    let mut v = Vec::new();
    v.try_reserve_exact(len)
        .map_err(|_| OpticsError::OutOfMemory {
            argument,
            what,
            bytes: len as f64 * std::mem::size_of::<T>() as f64,
        })?;
    v.resize(len, value);
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An allocation no machine can make is an error naming its driver, not an abort.
    #[test]
    fn failed_allocation_is_an_error() {
        let e = try_filled(
            usize::MAX / 8,
            0u64,
            "cells_per_particle",
            "the grid's cells",
        )
        .unwrap_err();
        assert!(matches!(
            e,
            OpticsError::OutOfMemory {
                argument: "cells_per_particle",
                ..
            }
        ));
        assert!(e.to_string().contains("the grid's cells") && e.to_string().contains("GiB"));
        assert_eq!(try_filled(3, 7u32, "n", "x").unwrap(), vec![7, 7, 7]);
    }
}
