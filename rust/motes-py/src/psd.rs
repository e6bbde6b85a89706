//! Particle size distributions given as JSON specs (`motes_core::psd`).

use crate::convert::*;
use numpy::IntoPyArray;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

pub(crate) fn psd(spec: &str) -> PyResult<motes_core::Psd> {
    motes_core::Psd::from_json(spec).map_err(to_py)
}

/// Validate a PSD spec (JSON) and return it normalised (defaults filled in).
#[pyfunction]
pub(crate) fn psd_validate(spec: &str) -> PyResult<String> {
    Ok(psd(spec)?.to_json())
}

/// Evaluate "cdf", "pdf" (continuous part) or "quantile" of a PSD elementwise.
#[pyfunction]
pub(crate) fn psd_eval<'py>(
    py: Python<'py>,
    spec: &str,
    what: &str,
    x: F64In,
) -> PyResult<F64Out<'py>> {
    let d = psd(spec)?;
    let x = x.as_array().to_vec();
    let f: fn(&motes_core::Psd, f64) -> f64 = match what {
        "cdf" => |d, v| d.cdf(v),
        "pdf" => |d, v| d.pdf(v),
        "quantile" => |d, v| d.quantile(v),
        other => {
            return Err(PyValueError::new_err(format!(
                "invalid what = {other:?}: allowed values are \"cdf\", \"pdf\", \"quantile\""
            )))
        }
    };
    if what == "quantile" {
        if let Some(u) = x.iter().find(|u| !(0.0..=1.0).contains(*u)) {
            return Err(PyValueError::new_err(format!(
                "invalid u = {u}: must be in [0, 1]"
            )));
        }
    } else if let Some(r) = x.iter().find(|r| r.is_nan()) {
        return Err(PyValueError::new_err(format!(
            "invalid radius_um = {r}: must not be NaN"
        )));
    }
    let out: Vec<f64> = py.detach(|| x.iter().map(|&v| f(&d, v)).collect());
    Ok(out.into_pyarray(py))
}

/// `n` radii drawn from a PSD, reproducible from `seed`.
#[pyfunction]
pub(crate) fn psd_sample<'py>(
    py: Python<'py>,
    spec: &str,
    n: usize,
    seed: u64,
) -> PyResult<F64Out<'py>> {
    let d = psd(spec)?;
    Ok(py.detach(|| d.sample(n, seed)).into_pyarray(py))
}

/// Quadrature (nodes, weights) over a PSD with panels of at most `max_log_step` in ln r.
#[pyfunction]
pub(crate) fn psd_quadrature<'py>(
    py: Python<'py>,
    spec: &str,
    max_log_step: f64,
) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
    let d = psd(spec)?;
    motes_core::error::require(
        "max_log_step",
        max_log_step,
        max_log_step.is_finite() && max_log_step > 0.0,
        "finite and > 0",
    )
    .map_err(to_py)?;
    let (r, w) = py.detach(|| d.quadrature(max_log_step));
    Ok((r.into_pyarray(py), w.into_pyarray(py)))
}

/// Support (r_lo, r_hi) and atoms [(radius, probability)] of a PSD.
#[pyfunction]
pub(crate) fn psd_support(spec: &str) -> PyResult<((f64, f64), Vec<(f64, f64)>)> {
    let d = psd(spec)?;
    Ok((d.support(), d.atoms()))
}
