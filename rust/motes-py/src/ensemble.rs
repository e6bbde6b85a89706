//! Polydisperse ensembles: bulk coefficients and phase-function tables (`motes_core::ensemble`,
//! `motes_core::ensemble::phase_table`).

use crate::convert::*;
use crate::interrupt::interruptible;
use crate::psd::psd;
use motes_core::optics::goa::GoaOptions;
use motes_core::optics::Method;
use num_complex::Complex64 as C64;
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;

pub(crate) type BulkOut<'py> = (
    F64Out<'py>,
    F64Out<'py>,
    F64Out<'py>,
    F64Out<'py>,
    Bound<'py, numpy::PyArray2<f64>>,
    F64Out<'py>,
    F64Out<'py>,
    F64Out<'py>,
    Option<Bound<'py, numpy::PyArray3<f64>>>,
);

/// Bulk properties (Eq. 16–17) per wavelength. `eta_re/eta_im` are (n_species × n_wavelengths), row-major.
/// `theta` empty: the phase function on the internal grid; otherwise at those angles (g and the
/// normalisation still from the internal grid, `motes_core::ensemble::bulk_spectral`). `mueller`: the
/// last element is the ensemble's Mueller ratios (n_wavelengths × 3 × n_theta: F12/F11, F33/F11,
/// F34/F11 at the angles of the phase function), else None.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
pub(crate) fn bulk_properties<'py>(
    py: Python<'py>,
    psd_specs: Vec<String>,
    shares: Vec<f64>,
    eta_re: F64In,
    eta_im: F64In,
    wavelength_um: F64In,
    number_density_m3: f64,
    eta_medium: f64,
    method: &str,
    hybrid_radius_um: f64,
    p_max: u32,
    max_log_step: f64,
    mie_dx: Option<f64>,
    theta: F64In,
    with_phase: bool,
    truncate_below_rad: f64,
    refine_tol: f64,
    refine_max_nodes: usize,
    goa_cache: Option<PyRef<'_, PyGoaCache>>,
    mueller: bool,
) -> PyResult<BulkOut<'py>> {
    use motes_core::ensemble::{self, BulkOptions, PhaseAngles};
    let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
    let lam = wavelength_um.as_array().to_vec();
    let (er, ei) = (eta_re.as_array().to_vec(), eta_im.as_array().to_vec());
    let (ns, nl) = (psd_specs.len(), lam.len());
    if shares.len() != ns || er.len() != ns * nl || ei.len() != ns * nl {
        return Err(invalid(
            "shares, eta_re, eta_im",
            None::<f64>,
            "species, shares and eta must describe the same species and wavelengths".into(),
        ));
    }
    motes_core::Psd::require_log_step(max_log_step).map_err(to_py)?;
    motes_core::error::require(
        "refine_tol",
        refine_tol,
        refine_tol.is_finite() && refine_tol >= 0.0,
        "finite and >= 0",
    )
    .map_err(to_py)?;
    let species = species_per_wavelength(&psd_specs, &shares, &er, &ei, nl)?;
    let theta = theta.as_array().to_vec();
    let angles = match (with_phase, theta.is_empty()) {
        (false, _) => PhaseAngles::None,
        (true, true) => PhaseAngles::Table,
        (true, false) => PhaseAngles::At(&theta),
    };
    let mie_dx = mie_dx.unwrap_or(ensemble::MIE_RIPPLE_DX);
    let opts = BulkOptions {
        method,
        goa: GoaOptions {
            p_max,
            ..GoaOptions::default()
        },
        max_log_step,
        mie_dx,
        refine_tol,
        refine_max_nodes,
        goa_cache: goa_cache.map(|c| c.cache.clone()),
        mueller,
    };
    let out = interruptible(py, || {
        ensemble::bulk_spectral(
            &species,
            number_density_m3,
            &lam,
            eta_medium,
            angles,
            truncate_below_rad,
            &opts,
        )
    })?
    .map_err(to_py)?;
    bulk_out(py, &out, nl)
}

/// The species at each wavelength (`eta` given per species and wavelength, row-major).
fn species_per_wavelength(
    psd_specs: &[String],
    shares: &[f64],
    er: &[f64],
    ei: &[f64],
    nl: usize,
) -> PyResult<Vec<Vec<motes_core::ensemble::Species>>> {
    let psds = psd_specs
        .iter()
        .map(|s| psd(s))
        .collect::<PyResult<Vec<_>>>()?;
    Ok((0..nl)
        .map(|j| {
            psds.iter()
                .enumerate()
                .map(|(i, p)| motes_core::ensemble::Species {
                    psd: p.clone(),
                    eta: C64::new(er[i * nl + j], ei[i * nl + j]),
                    share: shares[i],
                })
                .collect()
        })
        .collect())
}

/// The Python tuple of a spectral bulk result (see `BulkOut`).
fn bulk_out<'py>(
    py: Python<'py>,
    out: &motes_core::ensemble::SpectralBulk,
    nl: usize,
) -> PyResult<BulkOut<'py>> {
    let col = |f: fn(&motes_core::ensemble::Bulk) -> f64| {
        out.bulk
            .iter()
            .map(f)
            .collect::<Vec<f64>>()
            .into_pyarray(py)
    };
    let phase = if out.theta.is_empty() {
        numpy::PyArray2::zeros(py, [nl, 0], false)
    } else {
        numpy::PyArray2::from_vec2(py, &out.phase)?
    };
    // (wavelength, ratio, angle), C order.
    let mueller = if out.mueller.is_empty() {
        None
    } else {
        let nt = out.theta.len();
        let flat: Vec<f64> = out
            .mueller
            .iter()
            .flat_map(|m| (0..3).flat_map(move |k| m.iter().map(move |r| r[k])))
            .collect();
        Some(flat.into_pyarray(py).reshape([nl, 3, nt])?)
    };
    Ok((
        col(|b| b.sigma_t),
        col(|b| b.sigma_s),
        col(|b| b.sigma_a),
        col(|b| b.g),
        phase,
        col(|b| b.energy_ratio),
        out.theta.clone().into_pyarray(py),
        out.peak_fraction.clone().into_pyarray(py),
        mueller,
    ))
}

/// GOA ray geometry that several `bulk_properties` calls share (a medium's size bins): build one, pass
/// it to each call, drop it when done.
#[pyclass(name = "GoaCache", module = "motes._motes", frozen)]
pub(crate) struct PyGoaCache {
    cache: std::sync::Arc<motes_core::optics::GoaCache>,
}

#[pymethods]
impl PyGoaCache {
    #[new]
    fn new() -> Self {
        PyGoaCache {
            cache: Default::default(),
        }
    }

    /// Relative indices held.
    fn __len__(&self) -> usize {
        self.cache.len()
    }
}

/// A tabulated phase function (nodes `theta` from 0 to π, values `f`), validated and prepared for
/// sampling once (`motes_core::ensemble::phase_table::PhaseTable`); every query reuses it.
#[pyclass(name = "PhaseTable", module = "motes._motes", frozen)]
pub(crate) struct PyPhaseTable {
    table: motes_core::ensemble::phase_table::PhaseTable,
    theta: Vec<f64>,
    f: Vec<f64>,
}

#[pymethods]
impl PyPhaseTable {
    #[new]
    fn new(theta: F64In, f: F64In) -> PyResult<Self> {
        let (theta, f) = (theta.as_slice()?.to_vec(), f.as_slice()?.to_vec());
        let table =
            motes_core::ensemble::phase_table::PhaseTable::new(&theta, &f).map_err(to_py)?;
        Ok(PyPhaseTable { table, theta, f })
    }

    /// Asymmetry parameter g = ∫ f cos θ dΩ of the table.
    fn mean_cosine(&self) -> f64 {
        self.table.mean_cosine()
    }

    /// f (1/sr) at angles `query` (radians).
    fn eval<'py>(&self, py: Python<'py>, query: F64In) -> PyResult<F64Out<'py>> {
        let q = query.as_slice()?;
        check_angles(q)?;
        let t = &self.table;
        let out: Vec<f64> = py.detach(|| q.iter().map(|th| t.eval(th.cos())).collect());
        Ok(out.into_pyarray(py))
    }

    /// Scattering angles (radians), one per uniform number `u` in [0, 1].
    fn sample<'py>(&self, py: Python<'py>, u: F64In) -> PyResult<F64Out<'py>> {
        let u = u.as_slice()?;
        if let Some(&v) = u.iter().find(|v| !(0.0..=1.0).contains(*v)) {
            return Err(invalid(
                "u",
                v,
                format!("invalid u = {v}: must be in [0, 1]"),
            ));
        }
        let t = &self.table;
        let out: Vec<f64> = py.detach(|| {
            u.iter()
                .map(|&x| t.sample(x).clamp(-1.0, 1.0).acos())
                .collect()
        });
        Ok(out.into_pyarray(py))
    }

    /// Averages over `n` equal bins of μ = cos θ from −1 to 1, as values at `n` evenly spaced nodes
    /// from μ = −1 (backward) to μ = 1 (forward) — Mitsuba `tabphase` order.
    fn regular_mu<'py>(&self, py: Python<'py>, n: usize) -> PyResult<F64Out<'py>> {
        if n < 2 {
            return Err(invalid("n", n, format!("invalid n = {n}: must be >= 2")));
        }
        // Node i sits at μ_i = −1 + 2i/(n−1); it takes the average over its Voronoi cell in μ.
        let h = 2.0 / (n - 1) as f64;
        let out: Vec<f64> = (0..n)
            .map(|i| {
                let mu = -1.0 + h * i as f64;
                self.table.average(mu - 0.5 * h, mu + 0.5 * h)
            })
            .collect();
        Ok(out.into_pyarray(py))
    }

    /// Pickled as its nodes and values.
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
        py: Python<'py>,
    ) -> (Bound<'py, pyo3::types::PyType>, (F64Out<'py>, F64Out<'py>)) {
        let me = slf.get();
        (
            slf.get_type(),
            (
                me.theta.clone().into_pyarray(py),
                me.f.clone().into_pyarray(py),
            ),
        )
    }
}

/// Henyey–Greenstein phase function (1/sr) with asymmetry `g` in (−1, 1) at angles `theta` (radians).
#[pyfunction]
pub(crate) fn henyey_greenstein<'py>(
    py: Python<'py>,
    g: f64,
    theta: F64In,
) -> PyResult<F64Out<'py>> {
    if !(g.is_finite() && g > -1.0 && g < 1.0) {
        return Err(invalid(
            "g",
            g,
            format!("invalid g = {g}: must be in (-1, 1)"),
        ));
    }
    let q = theta.as_slice()?;
    check_angles(q)?;
    let out: Vec<f64> = q
        .iter()
        .map(|t| motes_core::ensemble::phase_table::henyey_greenstein(g, t.cos()))
        .collect();
    Ok(out.into_pyarray(py))
}

/// Scattering angles must be finite and in [0, π] (the error names `theta` and the first bad value).
fn check_angles(q: &[f64]) -> PyResult<()> {
    match q
        .iter()
        .find(|v| !(v.is_finite() && (0.0..=std::f64::consts::PI).contains(*v)))
    {
        Some(&v) => Err(invalid(
            "theta",
            v,
            format!("invalid theta = {v}: must be finite and in [0, π]"),
        )),
        None => Ok(()),
    }
}
