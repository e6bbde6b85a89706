//! Conversions at the boundary: core errors to Python exceptions ([`MotesError`]), numpy array
//! types, and rays and 3-vectors read from flat arrays (each checked once, here).

use motes_core::OpticsError;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

pyo3::create_exception!(
    motes,
    MotesError,
    PyValueError,
    "An invalid argument of motes: a ValueError whose `argument` names the parameter and whose `value` \
     is what was given (a number, a string, or None where the check concerns a whole array)."
);

/// A [`MotesError`] with its `argument` and `value` attributes set.
pub(crate) fn invalid<V>(argument: &str, value: V, message: String) -> PyErr
where
    V: for<'py> IntoPyObject<'py>,
{
    Python::attach(|py| {
        let err = MotesError::new_err(message);
        let exc = err.value(py);
        let _ = exc.setattr("argument", argument);
        let _ = exc.setattr("value", value);
        err
    })
}

/// The core's errors, mapped once: each names its argument and value.
pub(crate) fn to_py(e: OpticsError) -> PyErr {
    let message = e.to_string();
    match e {
        OpticsError::InvalidArgument {
            argument, value, ..
        } => invalid(argument, value, message),
        OpticsError::InvalidOption {
            argument, value, ..
        } => invalid(argument, value, message),
    }
}

pub(crate) type F64In<'py> = PyReadonlyArray1<'py, f64>;
pub(crate) type F64Out<'py> = Bound<'py, PyArray1<f64>>;

pub(crate) fn rays<'a>(
    origins: &'a [f64],
    directions: &'a [f64],
    n: usize,
) -> PyResult<Vec<([f64; 3], [f64; 3])>> {
    if origins.len() != 3 * n || directions.len() != 3 * n {
        return Err(invalid(
            "origins, directions",
            None::<f64>,
            "origins and directions must have shape (n, 3) with n rays".into(),
        ));
    }
    (0..n)
        .map(|i| {
            let o = [origins[3 * i], origins[3 * i + 1], origins[3 * i + 2]];
            let d = [
                directions[3 * i],
                directions[3 * i + 1],
                directions[3 * i + 2],
            ];
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if !(o.iter().all(|x| x.is_finite()) && l.is_finite() && l > 0.0) {
                return Err(invalid(
                    "origins, directions",
                    i,
                    format!("invalid ray {i}: origins must be finite and directions finite and non-zero"),
                ));
            }
            Ok((o, d.map(|x| x / l)))
        })
        .collect()
}

pub(crate) type F32In<'py> = PyReadonlyArray1<'py, f32>;

pub(crate) fn vec3s(a: &F32In, what: &str) -> PyResult<Vec<[f32; 3]>> {
    let s = a.as_slice()?;
    if s.len() % 3 != 0 {
        return Err(invalid(
            what,
            None::<f64>,
            format!("{what} must have shape (n, 3)"),
        ));
    }
    Ok(s.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}
