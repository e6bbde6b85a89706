//! Conversions at the boundary: core errors to Python exceptions ([`MotesError`]), numpy array
//! types, and rays and 3-vectors read from flat arrays (each checked once, here).
//!
//! ## Borrow or copy
//! A numpy array is borrowed (`as_slice`, `as_array`) where Rust reads it with the GIL held, and
//! copied (`to_vec`) where Rust reads it after releasing the GIL (`py.detach`, for rayon): a
//! `PyReadonlyArray` stops other Rust code from writing the array, not another Python thread, which
//! may run as soon as the GIL is released. The copies are O(n) next to work that is O(n) or more
//! (a grid build, a batch of free flights), and they are the price of running that work on every core
//! while Python threads go on.

use motes_core::space::ray::RaySegment;
use motes_core::OpticsError;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::{PyMemoryError, PyValueError};
use pyo3::prelude::*;
use rayon::prelude::*;

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
        OpticsError::OutOfRange {
            argument, value, ..
        } => invalid(argument, value, message),
        // A MemoryError (the Python layer's own estimates raise it too), naming what drives the size.
        OpticsError::OutOfMemory { argument, .. } => Python::attach(|py| {
            let err = PyMemoryError::new_err(message);
            let _ = err.value(py).setattr("argument", argument);
            err
        }),
    }
}

pub(crate) type F64In<'py> = PyReadonlyArray1<'py, f64>;
pub(crate) type F64Out<'py> = Bound<'py, PyArray1<f64>>;

/// Points from a flat (n*3) array, unchecked: a trailing partial point is dropped.
pub(crate) fn triples(flat: &[f64]) -> Vec<[f64; 3]> {
    flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// Particle positions from a flat (n*3) array.
pub(crate) fn points(flat: &F64In) -> PyResult<Vec<[f64; 3]>> {
    let p = flat.as_slice()?;
    if p.len() % 3 != 0 {
        return Err(PyValueError::new_err("positions must have shape (n, 3)"));
    }
    Ok(triples(p))
}

/// Particle positions from a flat (n*3) array, borrowed (for work done with the GIL held: a build that
/// must not copy 10^8 positions).
pub(crate) fn points_view(flat: &[f64]) -> PyResult<&[[f64; 3]]> {
    if flat.len() % 3 != 0 {
        return Err(PyValueError::new_err("positions must have shape (n, 3)"));
    }
    // SAFETY: [f64; 3] is three f64 without padding and with f64's alignment, so n*3 contiguous f64
    // are n contiguous [f64; 3]; the borrow keeps `flat`'s lifetime.
    Ok(unsafe { std::slice::from_raw_parts(flat.as_ptr() as *const [f64; 3], flat.len() / 3) })
}

/// Positions, radii and extinction cross sections of a particle set.
pub(crate) type ParticleColumns = (Vec<[f64; 3]>, Vec<f64>, Vec<f64>);

/// A particle set's columns — positions (flat n*3), radii (n) and extinction cross sections — copied:
/// the builds read them with the GIL released (module docs).
pub(crate) fn particle_columns(
    positions: &F64In,
    radius: &F64In,
    c_ext: &F64In,
) -> PyResult<ParticleColumns> {
    Ok((
        points(positions)?,
        radius.as_slice()?.to_vec(),
        c_ext.as_slice()?.to_vec(),
    ))
}

/// Per-ray arrays (t0, t1, u, …), copied; they must be equally long ("t0, t1 and u must have one
/// value per ray", from their names).
pub(crate) fn per_ray<const N: usize>(arrays: [(&str, &F64In); N]) -> PyResult<[Vec<f64>; N]> {
    let mut out = Vec::with_capacity(N);
    for (_, a) in arrays {
        out.push(a.as_slice()?.to_vec());
    }
    if out.iter().any(|v| v.len() != out[0].len()) {
        let names: Vec<&str> = arrays.iter().map(|(name, _)| *name).collect();
        let (last, rest) = names.split_last().expect("two or more arrays");
        return Err(PyValueError::new_err(format!(
            "{} and {last} must have one value per ray",
            rest.join(", ")
        )));
    }
    Ok(out.try_into().expect("N arrays"))
}

/// The ray segments [t0, t1) that the grid and medium queries take, from flat (n*3) origins and
/// directions (the directions normalised) and the per-ray `t0` and `t1` (from [`per_ray`]).
pub(crate) fn segments(
    origins: &F64In,
    directions: &F64In,
    t0: &[f64],
    t1: &[f64],
) -> PyResult<Vec<RaySegment>> {
    let n = t0.len();
    let (origins, directions) = (origins.as_slice()?, directions.as_slice()?);
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
            Ok(RaySegment::new(o, d.map(|x| x / l), t0[i], t1[i]))
        })
        .collect()
}

/// Ray segments as Python passes them to a query: one tuple `(origins, directions, t0, t1)` of flat
/// (n*3) origins and directions and per-ray `t0` and `t1` (the Python layer broadcasts them).
#[derive(FromPyObject)]
pub(crate) struct SegmentsIn<'py>(F64In<'py>, F64In<'py>, F64In<'py>, F64In<'py>);

impl SegmentsIn<'_> {
    /// The checked [`segments`].
    pub(crate) fn get(&self) -> PyResult<Vec<RaySegment>> {
        let [t0, t1] = per_ray([("t0", &self.2), ("t1", &self.3)])?;
        segments(&self.0, &self.1, &t0, &t1)
    }
}

/// `f(i, segment)` of each ray segment, in parallel and without the GIL.
pub(crate) fn per_segment<T, F>(py: Python<'_>, segments: &[RaySegment], f: F) -> Vec<T>
where
    T: Send,
    F: Fn(usize, &RaySegment) -> T + Sync + Send,
{
    py.detach(|| {
        segments
            .par_iter()
            .enumerate()
            .map(|(i, s)| f(i, s))
            .collect()
    })
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
