//! Particle size distributions given as JSON specs (`motes_core::ensemble::psd`).

use crate::convert::*;
use numpy::IntoPyArray;
use pyo3::prelude::*;

pub(crate) fn psd(spec: &str) -> PyResult<motes_core::Psd> {
    motes_core::Psd::from_json(spec).map_err(to_py)
}

/// A particle size distribution, parsed and validated once from its JSON spec; every query reuses it.
#[pyclass(name = "Psd", module = "motes._motes", frozen)]
pub(crate) struct PyPsd {
    psd: motes_core::Psd,
}

impl PyPsd {
    /// The core distribution.
    pub(crate) fn inner(&self) -> &motes_core::Psd {
        &self.psd
    }
}

#[pymethods]
impl PyPsd {
    #[new]
    fn new(spec: &str) -> PyResult<Self> {
        Ok(PyPsd { psd: psd(spec)? })
    }

    /// The spec, normalised (defaults filled in), as JSON.
    fn spec(&self) -> String {
        self.psd.to_json()
    }

    /// Evaluate "cdf", "pdf" (continuous part) or "quantile" elementwise.
    fn eval<'py>(&self, py: Python<'py>, what: &str, x: F64In) -> PyResult<F64Out<'py>> {
        let x = x.as_slice()?;
        let f: fn(&motes_core::Psd, f64) -> f64 = match what {
            "cdf" => |d, v| d.cdf(v),
            "pdf" => |d, v| d.pdf(v),
            "quantile" => |d, v| d.quantile(v),
            other => {
                return Err(invalid(
                    "what",
                    other,
                    format!(
                    "invalid what = {other:?}: allowed values are \"cdf\", \"pdf\", \"quantile\""
                ),
                ))
            }
        };
        if what == "quantile" {
            if let Some(&u) = x.iter().find(|u| !(0.0..=1.0).contains(*u)) {
                return Err(invalid(
                    "u",
                    u,
                    format!("invalid u = {u}: must be in [0, 1]"),
                ));
            }
        } else if let Some(&r) = x.iter().find(|r| r.is_nan()) {
            return Err(invalid(
                "radius_um",
                r,
                format!("invalid radius_um = {r}: must not be NaN"),
            ));
        }
        let d = &self.psd;
        let out: Vec<f64> = py.detach(|| x.iter().map(|&v| f(d, v)).collect());
        Ok(out.into_pyarray(py))
    }

    /// `n` radii, reproducible from `seed`.
    fn sample<'py>(&self, py: Python<'py>, n: usize, seed: u64) -> F64Out<'py> {
        let d = &self.psd;
        py.detach(|| d.sample(n, seed)).into_pyarray(py)
    }

    /// Quadrature (nodes, weights) with panels of at most `max_log_step` in ln r.
    fn quadrature<'py>(
        &self,
        py: Python<'py>,
        max_log_step: f64,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        motes_core::Psd::require_log_step(max_log_step).map_err(to_py)?;
        let d = &self.psd;
        let (r, w) = py.detach(|| d.quadrature(max_log_step));
        Ok((r.into_pyarray(py), w.into_pyarray(py)))
    }

    /// Support (r_lo, r_hi) and atoms [(radius, probability)].
    fn support(&self) -> ((f64, f64), Vec<(f64, f64)>) {
        (self.psd.support(), self.psd.atoms())
    }

    /// Pickled as its spec.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> (Bound<'py, pyo3::types::PyType>, (String,)) {
        (slf.get_type(), (slf.get().psd.to_json(),))
    }
}
