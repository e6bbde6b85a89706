//! `motes._motes`: the compiled extension. Every function takes flat, equally long float64 arrays
//! (broadcasting happens in the Python layer), releases the GIL, and runs rayon inside.

mod interrupt;
mod native;

use interrupt::interruptible;

use motes_core::goa::GoaOptions;
use motes_core::optics::{self, Method, ParticleColumns, Theory};
use motes_core::OpticsError;
use num_complex::Complex64 as C64;
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use rayon::prelude::*;

fn to_py(e: OpticsError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

type F64In<'py> = PyReadonlyArray1<'py, f64>;

struct Columns {
    r: Vec<f64>,
    lam: Vec<f64>,
    er: Vec<f64>,
    ei: Vec<f64>,
    em: Vec<f64>,
}

impl Columns {
    fn new(r: F64In, lam: F64In, er: F64In, ei: F64In, em: F64In) -> PyResult<Self> {
        let v = |a: &F64In| -> PyResult<Vec<f64>> { Ok(a.as_array().to_vec()) };
        Ok(Columns {
            r: v(&r)?,
            lam: v(&lam)?,
            er: v(&er)?,
            ei: v(&ei)?,
            em: v(&em)?,
        })
    }
    fn view(&self) -> ParticleColumns<'_> {
        ParticleColumns {
            radius_um: &self.r,
            wavelength_um: &self.lam,
            eta_re: &self.er,
            eta_im: &self.ei,
            eta_medium: &self.em,
        }
    }
}

fn options(p_max: u32, diffraction: bool, regularise: bool, edge_correction: bool) -> GoaOptions {
    GoaOptions {
        p_max,
        diffraction,
        regularise,
        edge_correction,
    }
}

type Amps<'py> = (Bound<'py, PyArray1<C64>>, Bound<'py, PyArray1<C64>>);

fn amplitudes(
    py: Python<'_>,
    cols: Columns,
    theta: Vec<f64>,
    theory: Theory,
    opts: GoaOptions,
) -> PyResult<Amps<'_>> {
    let out = interruptible(py, || {
        optics::amplitudes_batch(&cols.view(), &theta, theory, &opts)
    })?
    .map_err(to_py)?;
    let (s1, s2): (Vec<C64>, Vec<C64>) = out.into_iter().unzip();
    Ok((s1.into_pyarray(py), s2.into_pyarray(py)))
}

/// Lorenz–Mie amplitudes (S1, S2), Bohren–Huffman convention.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn mie_amplitudes<'py>(
    py: Python<'py>,
    radius_um: F64In,
    wavelength_um: F64In,
    eta_re: F64In,
    eta_im: F64In,
    eta_medium: F64In,
    theta: F64In,
) -> PyResult<Amps<'py>> {
    let cols = Columns::new(radius_um, wavelength_um, eta_re, eta_im, eta_medium)?;
    amplitudes(
        py,
        cols,
        theta.as_array().to_vec(),
        Theory::Mie,
        GoaOptions::default(),
    )
}

/// GOA amplitudes (S1, S2), Bohren–Huffman convention.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn goa_amplitudes<'py>(
    py: Python<'py>,
    radius_um: F64In,
    wavelength_um: F64In,
    eta_re: F64In,
    eta_im: F64In,
    eta_medium: F64In,
    theta: F64In,
    p_max: u32,
    diffraction: bool,
    regularise: bool,
    edge_correction: bool,
) -> PyResult<Amps<'py>> {
    let cols = Columns::new(radius_um, wavelength_um, eta_re, eta_im, eta_medium)?;
    amplitudes(
        py,
        cols,
        theta.as_array().to_vec(),
        Theory::Goa,
        options(p_max, diffraction, regularise, edge_correction),
    )
}

type F64Out<'py> = Bound<'py, PyArray1<f64>>;

/// Cross sections (ext, sca, abs in µm²) and asymmetry g.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn cross_sections<'py>(
    py: Python<'py>,
    radius_um: F64In,
    wavelength_um: F64In,
    eta_re: F64In,
    eta_im: F64In,
    eta_medium: F64In,
    method: &str,
    hybrid_radius_um: f64,
    p_max: u32,
    regularise: bool,
    edge_correction: bool,
    with_g: bool,
) -> PyResult<(F64Out<'py>, F64Out<'py>, F64Out<'py>, F64Out<'py>)> {
    let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
    let cols = Columns::new(radius_um, wavelength_um, eta_re, eta_im, eta_medium)?;
    let opts = options(p_max, true, regularise, edge_correction);
    let cs = interruptible(py, || {
        optics::cross_sections_batch(&cols.view(), method, &opts, with_g)
    })?
    .map_err(to_py)?;
    let col = |f: fn(&optics::CrossSections) -> f64| {
        cs.iter().map(f).collect::<Vec<f64>>().into_pyarray(py)
    };
    Ok((col(|c| c.ext), col(|c| c.sca), col(|c| c.abs), col(|c| c.g)))
}

/// Normalised phase function f_p(θ) (sr⁻¹), ∫ f dΩ = 1.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn phase_function<'py>(
    py: Python<'py>,
    radius_um: F64In,
    wavelength_um: F64In,
    eta_re: F64In,
    eta_im: F64In,
    eta_medium: F64In,
    theta: F64In,
    method: &str,
    hybrid_radius_um: f64,
    p_max: u32,
    regularise: bool,
    edge_correction: bool,
) -> PyResult<F64Out<'py>> {
    let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
    let cols = Columns::new(radius_um, wavelength_um, eta_re, eta_im, eta_medium)?;
    let theta = theta.as_array().to_vec();
    let opts = options(p_max, true, regularise, edge_correction);
    let f = interruptible(py, || {
        optics::phase_function_batch(&cols.view(), &theta, method, &opts)
    })?
    .map_err(to_py)?;
    Ok(f.into_pyarray(py))
}

/// GOA extinction efficiency by Eq. 12 (per element), for studies of p and the regularisation.
#[pyfunction]
fn goa_extinction_efficiency<'py>(
    py: Python<'py>,
    alpha: F64In,
    eta_re: F64In,
    eta_im: F64In,
    p_max: u32,
    regularise: bool,
    edge_correction: bool,
) -> PyResult<F64Out<'py>> {
    let (a, er, ei) = (
        alpha.as_array().to_vec(),
        eta_re.as_array().to_vec(),
        eta_im.as_array().to_vec(),
    );
    if a.len() != er.len() || a.len() != ei.len() {
        return Err(PyValueError::new_err(
            "alpha, eta_re and eta_im must have the same length",
        ));
    }
    for ((a, r), im) in a.iter().zip(&er).zip(&ei) {
        motes_core::error::require("alpha", *a, a.is_finite() && *a > 0.0, "finite and > 0")
            .map_err(to_py)?;
        motes_core::error::require(
            "eta (real part)",
            *r,
            r.is_finite() && *r > 0.0,
            "finite and > 0",
        )
        .map_err(to_py)?;
        motes_core::error::require(
            "eta (imaginary part)",
            *im,
            im.is_finite() && *im >= 0.0,
            "finite and >= 0",
        )
        .map_err(to_py)?;
    }
    let out: Vec<f64> = py.detach(|| {
        a.iter()
            .zip(&er)
            .zip(&ei)
            .map(|((a, r), i)| {
                motes_core::goa::extinction_efficiency(
                    *a,
                    C64::new(*r, *i),
                    p_max,
                    regularise,
                    edge_correction,
                )
            })
            .collect()
    });
    Ok(out.into_pyarray(py))
}

/// Constants of the method policy: (AUTO_SIZE_PARAMETER, HYBRID_RADIUS_UM, AXIAL_CAUSTIC_WINDOW).
#[pyfunction]
fn policy_constants() -> (f64, f64, f64) {
    (
        optics::AUTO_SIZE_PARAMETER,
        optics::HYBRID_RADIUS_UM,
        optics::AXIAL_CAUSTIC_WINDOW,
    )
}

/// The theory ("mie" or "goa") that `method` picks for each particle.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn resolve_method(
    radius_um: F64In,
    wavelength_um: F64In,
    eta_re: F64In,
    eta_im: F64In,
    eta_medium: F64In,
    method: &str,
    hybrid_radius_um: f64,
    p_max: u32,
) -> PyResult<Vec<&'static str>> {
    let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
    let cols = Columns::new(radius_um, wavelength_um, eta_re, eta_im, eta_medium)?;
    let groups = cols.view().group().map_err(to_py)?;
    let mut out = vec![""; cols.r.len()];
    for (p, idx) in groups {
        let name = match method.theory(&p, p_max) {
            Theory::Mie => "mie",
            Theory::Goa => "goa",
        };
        for i in idx {
            out[i] = name;
        }
    }
    Ok(out)
}

fn psd(spec: &str) -> PyResult<motes_core::Psd> {
    motes_core::Psd::from_json(spec).map_err(to_py)
}

/// Validate a PSD spec (JSON) and return it normalised (defaults filled in).
#[pyfunction]
fn psd_validate(spec: &str) -> PyResult<String> {
    Ok(psd(spec)?.to_json())
}

/// Evaluate "cdf", "pdf" (continuous part) or "quantile" of a PSD elementwise.
#[pyfunction]
fn psd_eval<'py>(py: Python<'py>, spec: &str, what: &str, x: F64In) -> PyResult<F64Out<'py>> {
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
fn psd_sample<'py>(py: Python<'py>, spec: &str, n: usize, seed: u64) -> PyResult<F64Out<'py>> {
    let d = psd(spec)?;
    Ok(py.detach(|| d.sample(n, seed)).into_pyarray(py))
}

/// Quadrature (nodes, weights) over a PSD with panels of at most `max_log_step` in ln r.
#[pyfunction]
fn psd_quadrature<'py>(
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
fn psd_support(spec: &str) -> PyResult<((f64, f64), Vec<(f64, f64)>)> {
    let d = psd(spec)?;
    Ok((d.support(), d.atoms()))
}

type BulkOut<'py> = (
    F64Out<'py>,
    F64Out<'py>,
    F64Out<'py>,
    F64Out<'py>,
    Bound<'py, numpy::PyArray2<f64>>,
    F64Out<'py>,
    F64Out<'py>,
    F64Out<'py>,
);

/// Bulk properties (Eq. 16–17) per wavelength. `eta_re/eta_im` are (n_species × n_wavelengths), row-major.
/// `theta` empty: the phase function on the internal grid; otherwise at those angles (g and the
/// normalisation still from the internal grid, `motes_core::ensemble::bulk_spectral`).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn bulk_properties<'py>(
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
) -> PyResult<BulkOut<'py>> {
    use motes_core::ensemble::{self, BulkOptions, PhaseAngles, Species};
    let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
    let lam = wavelength_um.as_array().to_vec();
    let (er, ei) = (eta_re.as_array().to_vec(), eta_im.as_array().to_vec());
    let (ns, nl) = (psd_specs.len(), lam.len());
    if shares.len() != ns || er.len() != ns * nl || ei.len() != ns * nl {
        return Err(PyValueError::new_err(
            "species, shares and eta must describe the same species and wavelengths",
        ));
    }
    motes_core::error::require(
        "max_log_step",
        max_log_step,
        max_log_step.is_finite() && max_log_step > 0.0,
        "finite and > 0",
    )
    .map_err(to_py)?;
    motes_core::error::require(
        "refine_tol",
        refine_tol,
        refine_tol.is_finite() && refine_tol >= 0.0,
        "finite and >= 0",
    )
    .map_err(to_py)?;
    let psds = psd_specs
        .iter()
        .map(|s| psd(s))
        .collect::<PyResult<Vec<_>>>()?;
    let species: Vec<Vec<Species>> = (0..nl)
        .map(|j| {
            psds.iter()
                .enumerate()
                .map(|(i, p)| Species {
                    psd: p.clone(),
                    eta: C64::new(er[i * nl + j], ei[i * nl + j]),
                    share: shares[i],
                })
                .collect()
        })
        .collect();
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
    let col = |f: fn(&ensemble::Bulk) -> f64| {
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
    Ok((
        col(|b| b.sigma_t),
        col(|b| b.sigma_s),
        col(|b| b.sigma_a),
        col(|b| b.g),
        phase,
        col(|b| b.energy_ratio),
        out.theta.clone().into_pyarray(py),
        out.peak_fraction.clone().into_pyarray(py),
    ))
}

fn phase_table(theta: F64In, f: F64In) -> PyResult<motes_core::phase_table::PhaseTable> {
    motes_core::phase_table::PhaseTable::new(theta.as_slice()?, f.as_slice()?).map_err(to_py)
}

/// Evaluate a tabulated phase function (nodes `theta`, values `f`) at angles `query` (radians).
#[pyfunction]
fn phase_table_eval<'py>(
    py: Python<'py>,
    theta: F64In,
    f: F64In,
    query: F64In,
) -> PyResult<F64Out<'py>> {
    let t = phase_table(theta, f)?;
    let q = query.as_array().to_vec();
    if let Some(v) = q
        .iter()
        .find(|v| !(v.is_finite() && (0.0..=std::f64::consts::PI).contains(*v)))
    {
        return Err(PyValueError::new_err(format!(
            "invalid theta = {v}: must be finite and in [0, π]"
        )));
    }
    let out: Vec<f64> = py.detach(|| q.iter().map(|th| t.eval(th.cos())).collect());
    Ok(out.into_pyarray(py))
}

/// Sample scattering angles (radians) from a tabulated phase function, one per uniform number `u`.
#[pyfunction]
fn phase_table_sample<'py>(
    py: Python<'py>,
    theta: F64In,
    f: F64In,
    u: F64In,
) -> PyResult<F64Out<'py>> {
    let t = phase_table(theta, f)?;
    let u = u.as_array().to_vec();
    if let Some(v) = u.iter().find(|v| !(0.0..=1.0).contains(*v)) {
        return Err(PyValueError::new_err(format!(
            "invalid u = {v}: must be in [0, 1]"
        )));
    }
    let out: Vec<f64> = py.detach(|| {
        u.iter()
            .map(|&x| t.sample(x).clamp(-1.0, 1.0).acos())
            .collect()
    });
    Ok(out.into_pyarray(py))
}

/// Averages of a tabulated phase function over `n` equal bins of μ = cos θ from −1 to 1, as values at
/// `n` evenly spaced nodes from μ = −1 (backward) to μ = 1 (forward) — Mitsuba `tabphase` order.
#[pyfunction]
fn phase_table_regular_mu<'py>(
    py: Python<'py>,
    theta: F64In,
    f: F64In,
    n: usize,
) -> PyResult<F64Out<'py>> {
    let t = phase_table(theta, f)?;
    if n < 2 {
        return Err(PyValueError::new_err(format!(
            "invalid n = {n}: must be >= 2"
        )));
    }
    // Node i sits at μ_i = −1 + 2i/(n−1); it takes the average over its Voronoi cell in μ.
    let h = 2.0 / (n - 1) as f64;
    let out: Vec<f64> = (0..n)
        .map(|i| {
            let mu = -1.0 + h * i as f64;
            t.average(mu - 0.5 * h, mu + 0.5 * h)
        })
        .collect();
    Ok(out.into_pyarray(py))
}

/// Complex refractive index of a tabulated material ("ice", "water") at wavelengths (µm).
#[pyfunction]
fn material_index<'py>(
    py: Python<'py>,
    name: &str,
    wavelength_um: F64In,
) -> PyResult<Bound<'py, PyArray1<C64>>> {
    let m = motes_core::materials::Material::parse(name).map_err(to_py)?;
    let out = wavelength_um
        .as_array()
        .iter()
        .map(|&l| m.index(l))
        .collect::<Result<Vec<_>, _>>()
        .map_err(to_py)?;
    Ok(out.into_pyarray(py))
}

/// A particle grid (scene units): build once, query in batches.
#[pyclass(name = "ParticleGrid", module = "motes._motes", frozen)]
struct PyParticleGrid {
    grid: motes_core::grid::ParticleGrid,
}

fn rays<'a>(
    origins: &'a [f64],
    directions: &'a [f64],
    n: usize,
) -> PyResult<Vec<([f64; 3], [f64; 3])>> {
    if origins.len() != 3 * n || directions.len() != 3 * n {
        return Err(PyValueError::new_err(
            "origins and directions must have shape (n, 3) with n rays",
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
                return Err(PyValueError::new_err(format!(
                    "invalid ray {i}: origins must be finite and directions finite and non-zero"
                )));
            }
            Ok((o, d.map(|x| x / l)))
        })
        .collect()
}

#[pymethods]
impl PyParticleGrid {
    /// positions (n*3, scene units), radius (n, scene units), c_ext (n*channels, scene units²).
    #[new]
    fn new(
        py: Python<'_>,
        positions: F64In,
        radius: F64In,
        c_ext: F64In,
        channels: usize,
        query_radius: f64,
        cells_per_particle: f64,
    ) -> PyResult<Self> {
        let p = positions.as_slice()?;
        if p.len() % 3 != 0 {
            return Err(PyValueError::new_err("positions must have shape (n, 3)"));
        }
        let pos: Vec<[f64; 3]> = p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let (r, c) = (radius.as_slice()?.to_vec(), c_ext.as_slice()?.to_vec());
        let grid = py
            .detach(|| {
                motes_core::grid::ParticleGrid::build(
                    &pos,
                    &r,
                    &c,
                    channels,
                    query_radius,
                    cells_per_particle,
                )
            })
            .map_err(to_py)?;
        Ok(PyParticleGrid { grid })
    }

    /// Optical depth per ray and channel over [t0, t1); `brute` loops over every particle instead.
    fn optical_depth<'py>(
        &self,
        py: Python<'py>,
        origins: F64In,
        directions: F64In,
        t0: F64In,
        t1: F64In,
        brute: bool,
    ) -> PyResult<F64Out<'py>> {
        let (t0, t1) = (t0.as_slice()?.to_vec(), t1.as_slice()?.to_vec());
        let n = t0.len();
        if t1.len() != n {
            return Err(PyValueError::new_err(
                "t0 and t1 must have one value per ray",
            ));
        }
        let rs = rays(origins.as_slice()?, directions.as_slice()?, n)?;
        let ch = self.grid.channels();
        let out: Vec<f64> = py.detach(|| {
            rs.par_iter()
                .zip(t0.par_iter().zip(t1.par_iter()))
                .flat_map_iter(|((o, d), (a, b))| {
                    let mut v = vec![0.0; ch];
                    if brute {
                        self.grid.optical_depth_brute(*o, *d, *a, *b, &mut v);
                    } else {
                        self.grid.optical_depth(*o, *d, *a, *b, &mut v);
                    }
                    v
                })
                .collect()
        });
        Ok(out.into_pyarray(py))
    }

    /// Exact free flights on [t0, t1): (t or NaN, particle index or -1, transmittance to there).
    fn free_flight<'py>(
        &self,
        py: Python<'py>,
        origins: F64In,
        directions: F64In,
        t0: F64In,
        t1: F64In,
        u: F64In,
        channel: usize,
    ) -> PyResult<(F64Out<'py>, Bound<'py, PyArray1<i64>>, F64Out<'py>)> {
        let (t0, t1, u) = (
            t0.as_slice()?.to_vec(),
            t1.as_slice()?.to_vec(),
            u.as_slice()?.to_vec(),
        );
        let n = t0.len();
        if t1.len() != n || u.len() != n {
            return Err(PyValueError::new_err(
                "t0, t1 and u must have one value per ray",
            ));
        }
        if channel >= self.grid.channels() {
            return Err(PyValueError::new_err(format!(
                "invalid channel = {channel}: the grid has {} channels",
                self.grid.channels()
            )));
        }
        if let Some(v) = u.iter().find(|v| !(0.0..1.0).contains(*v)) {
            return Err(PyValueError::new_err(format!(
                "invalid u = {v}: must be in [0, 1)"
            )));
        }
        let rs = rays(origins.as_slice()?, directions.as_slice()?, n)?;
        let res: Vec<(f64, i64, f64)> = py.detach(|| {
            rs.par_iter()
                .zip(t0.par_iter().zip(t1.par_iter().zip(u.par_iter())))
                .map(|((o, d), (a, (b, uu)))| {
                    let (hit, tr) = self.grid.free_flight(*o, *d, *a, *b, channel, *uu);
                    match hit {
                        Some(h) => (h.t, h.particle as i64, tr),
                        None => (f64::NAN, -1, tr),
                    }
                })
                .collect()
        });
        let t: Vec<f64> = res.iter().map(|r| r.0).collect();
        let i: Vec<i64> = res.iter().map(|r| r.1).collect();
        let tr: Vec<f64> = res.iter().map(|r| r.2).collect();
        Ok((t.into_pyarray(py), i.into_pyarray(py), tr.into_pyarray(py)))
    }

    /// First and last t of contributing particles on [t0, t1) per ray (NaN, NaN where none).
    fn occupied_interval<'py>(
        &self,
        py: Python<'py>,
        origins: F64In,
        directions: F64In,
        t0: F64In,
        t1: F64In,
        brute: bool,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let (t0, t1) = (t0.as_slice()?.to_vec(), t1.as_slice()?.to_vec());
        let n = t0.len();
        if t1.len() != n {
            return Err(PyValueError::new_err(
                "t0 and t1 must have one value per ray",
            ));
        }
        let rs = rays(origins.as_slice()?, directions.as_slice()?, n)?;
        let res: Vec<(f64, f64)> = py.detach(|| {
            rs.par_iter()
                .zip(t0.par_iter().zip(t1.par_iter()))
                .map(|((o, d), (a, b))| {
                    let r = if brute {
                        self.grid.occupied_interval_brute(*o, *d, *a, *b)
                    } else {
                        self.grid.occupied_interval(*o, *d, *a, *b)
                    };
                    r.unwrap_or((f64::NAN, f64::NAN))
                })
                .collect()
        });
        let (lo, hi): (Vec<f64>, Vec<f64>) = res.into_iter().unzip();
        Ok((lo.into_pyarray(py), hi.into_pyarray(py)))
    }

    #[getter]
    fn bytes(&self) -> usize {
        self.grid.bytes()
    }
    #[getter]
    fn dims(&self) -> (usize, usize, usize) {
        let d = self.grid.dims();
        (d[0], d[1], d[2])
    }
    #[getter]
    fn channels(&self) -> usize {
        self.grid.channels()
    }
    fn __len__(&self) -> usize {
        self.grid.len()
    }
}

type F32In<'py> = PyReadonlyArray1<'py, f32>;

fn vec3s(a: &F32In, what: &str) -> PyResult<Vec<[f32; 3]>> {
    let s = a.as_slice()?;
    if s.len() % 3 != 0 {
        return Err(PyValueError::new_err(format!(
            "{what} must have shape (n, 3)"
        )));
    }
    Ok(s.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// The discrete medium as the renderer queries it (see `motes_core::discrete`).
#[pyclass(name = "DiscreteMedium", module = "motes._motes", frozen)]
struct PyDiscreteMedium {
    medium: std::sync::Arc<motes_core::discrete::DiscreteMedium>,
}

#[pymethods]
impl PyDiscreteMedium {
    /// positions (n*3), radius (n), c_ext (n, grey) in scene units; bin (n) into the bins; albedo
    /// (bins*K); phase tables as flat theta/f with offsets (bins*K + 1); lambda (K, increasing);
    /// tau_max caps each particle's optical depth by widening its disk (inf: no cap); size classes with
    /// at least continuous_count particles per query cylinder are sampled as a continuous medium.
    #[new]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        positions: F64In,
        radius: F64In,
        c_ext: F64In,
        bin: PyReadonlyArray1<'_, u32>,
        albedo: F64In,
        theta: F64In,
        f: F64In,
        offsets: PyReadonlyArray1<'_, u64>,
        lambda: F64In,
        query_radius: f64,
        tau_max: f64,
        cells_per_particle: f64,
        continuous_count: f64,
        seed: u64,
    ) -> PyResult<Self> {
        let p = positions.as_slice()?;
        if p.len() % 3 != 0 {
            return Err(PyValueError::new_err("positions must have shape (n, 3)"));
        }
        let pos: Vec<[f64; 3]> = p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let (r, c, b) = (
            radius.as_slice()?.to_vec(),
            c_ext.as_slice()?.to_vec(),
            bin.as_slice()?.to_vec(),
        );
        let (al, th, fv, off, lam) = (
            albedo.as_slice()?,
            theta.as_slice()?,
            f.as_slice()?,
            offsets.as_slice()?,
            lambda.as_slice()?.to_vec(),
        );
        let k = lam.len();
        if k == 0
            || al.len() % k != 0
            || off.len() != al.len() + 1
            || th.len() != fv.len()
            || off.last().copied() != Some(th.len() as u64)
        {
            return Err(PyValueError::new_err(
                "albedo must have bins*K entries and offsets bins*K + 1, ending at len(theta)",
            ));
        }
        let mut bins = Vec::new();
        for bi in 0..al.len() / k {
            let mut phase = Vec::new();
            for kk in 0..k {
                let t = bi * k + kk;
                let (a, e) = (off[t] as usize, off[t + 1] as usize);
                if a > e || e > th.len() {
                    return Err(PyValueError::new_err("offsets must be increasing"));
                }
                phase.push(
                    motes_core::phase_table::PhaseTable::new(&th[a..e], &fv[a..e])
                        .map_err(to_py)?,
                );
            }
            bins.push(motes_core::discrete::BinOptics {
                albedo: al[bi * k..(bi + 1) * k].to_vec(),
                phase,
            });
        }
        let medium = py
            .detach(|| {
                motes_core::discrete::DiscreteMedium::build(
                    &pos,
                    &r,
                    &c,
                    b,
                    bins,
                    lam,
                    query_radius,
                    tau_max,
                    cells_per_particle,
                    continuous_count,
                    seed,
                )
            })
            .map_err(to_py)?;
        Ok(PyDiscreteMedium {
            medium: std::sync::Arc::new(medium),
        })
    }

    /// A new strong reference to the core medium for the native plugins (an address; they release it
    /// through the native API's `release`).
    fn native_handle(&self) -> usize {
        native::handle(&self.medium)
    }

    /// (rays, events) that went through the native render path so far.
    #[getter]
    fn native_counts(&self) -> (u64, u64) {
        self.medium.packet_counts()
    }

    /// Next site per ray on (0, t_max): (t or NaN, optical depth walked before it); the events of
    /// lanes marked in `remember` are remembered at commit.
    fn sample_sites<'py>(
        &self,
        py: Python<'py>,
        origins: F32In,
        directions: F32In,
        t_max: F64In,
        remember: PyReadonlyArray1<'_, bool>,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let (o, d, tm, keep) = (
            vec3s(&origins, "origins")?,
            vec3s(&directions, "directions")?,
            t_max.as_slice()?.to_vec(),
            remember.as_slice()?.to_vec(),
        );
        if d.len() != o.len() || tm.len() != o.len() || keep.len() != o.len() {
            return Err(PyValueError::new_err(
                "origins, directions, t_max and remember must describe the same rays",
            ));
        }
        let res = py.detach(|| self.medium.sample_sites(&o, &d, &tm, &keep));
        let t: Vec<f64> = res.iter().map(|r| r.t.unwrap_or(f64::NAN)).collect();
        let tau: Vec<f64> = res.iter().map(|r| r.tau_before).collect();
        Ok((t.into_pyarray(py), tau.into_pyarray(py)))
    }

    /// Remember the last call's events at the positions `p` (where `active`), return albedo (n*channels).
    fn commit_events<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        active: PyReadonlyArray1<'_, bool>,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<F64Out<'py>> {
        let (pp, act, lam) = (
            vec3s(&p, "p")?,
            active.as_slice()?.to_vec(),
            lambda.as_slice()?.to_vec(),
        );
        let out = py
            .detach(|| self.medium.commit_events(&pp, &act, &lam, channels))
            .map_err(to_py)?;
        Ok(out.into_pyarray(py))
    }

    /// Phase function of the events at `p`: (values n*channels, pdf n).
    fn phase_eval<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        wi: F32In,
        wo: F32In,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let (pp, a, b, lam) = (
            vec3s(&p, "p")?,
            vec3s(&wi, "wi")?,
            vec3s(&wo, "wo")?,
            lambda.as_slice()?.to_vec(),
        );
        if a.len() != pp.len()
            || b.len() != pp.len()
            || (lam.len() != channels && lam.len() != channels * pp.len())
        {
            return Err(PyValueError::new_err(
                "p, wi, wo and lambda must describe the same lanes",
            ));
        }
        let (v, pdf) = py.detach(|| self.medium.phase_eval(&pp, &a, &b, &lam, channels));
        Ok((v.into_pyarray(py), pdf.into_pyarray(py)))
    }

    /// Sample the phase function of the events at `p`: (wo n*3, weight n*channels, pdf n).
    #[allow(clippy::too_many_arguments)]
    fn phase_sample<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        wi: F32In,
        lambda: F64In,
        channels: usize,
        u1: F64In,
        u2: F64In,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>, F64Out<'py>)> {
        let (pp, a, lam, s1, s2) = (
            vec3s(&p, "p")?,
            vec3s(&wi, "wi")?,
            lambda.as_slice()?.to_vec(),
            u1.as_slice()?.to_vec(),
            u2.as_slice()?,
        );
        if a.len() != pp.len()
            || s1.len() != pp.len()
            || s2.len() != 2 * pp.len()
            || (lam.len() != channels && lam.len() != channels * pp.len())
        {
            return Err(PyValueError::new_err(
                "p, wi, u1, u2 and lambda must describe the same lanes",
            ));
        }
        let s2: Vec<[f64; 2]> = s2.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let (wo, w, pdf) =
            py.detach(|| self.medium.phase_sample(&pp, &a, &lam, channels, &s1, &s2));
        let wo: Vec<f64> = wo.into_iter().flatten().collect();
        Ok((
            wo.into_pyarray(py),
            w.into_pyarray(py),
            pdf.into_pyarray(py),
        ))
    }

    /// Eq. 24 at points (f64 n*3): (sigma_s n*channels, Q = sigma_s f at cos θ = `mu`, n*channels).
    fn local_scattering<'py>(
        &self,
        py: Python<'py>,
        points: F64In,
        mu: F64In,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let pts: Vec<[f64; 3]> = points
            .as_slice()?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let (mu, lam) = (mu.as_slice()?.to_vec(), lambda.as_slice()?.to_vec());
        if mu.len() != pts.len()
            || points.len()? != 3 * pts.len()
            || channels == 0
            || (lam.len() != channels && lam.len() != channels * pts.len())
        {
            return Err(PyValueError::new_err("points (n, 3), mu (n) and lambda (channels or n*channels) must describe the same points"));
        }
        let (sg, q) = py.detach(|| self.medium.local_scattering(&pts, &mu, &lam, channels));
        Ok((sg.into_pyarray(py), q.into_pyarray(py)))
    }

    /// Sample the local mixture at points: (wo n*3, weight n*channels, pdf n); `w_in` = propagation direction.
    #[allow(clippy::too_many_arguments)]
    fn sample_local<'py>(
        &self,
        py: Python<'py>,
        points: F64In,
        w_in: F64In,
        lambda: F64In,
        channels: usize,
        u1: F64In,
        u2: F64In,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>, F64Out<'py>)> {
        let pts: Vec<[f64; 3]> = points
            .as_slice()?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let dirs: Vec<[f64; 3]> = w_in
            .as_slice()?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let (lam, s1, s2) = (
            lambda.as_slice()?.to_vec(),
            u1.as_slice()?.to_vec(),
            u2.as_slice()?,
        );
        let n = pts.len();
        if dirs.len() != n
            || s1.len() != n
            || s2.len() != 2 * n
            || channels == 0
            || (lam.len() != channels && lam.len() != channels * n)
        {
            return Err(PyValueError::new_err(
                "points, w_in, u1, u2 and lambda must describe the same points",
            ));
        }
        let s2: Vec<[f64; 2]> = s2.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let (wo, w, pdf) = py.detach(|| {
            self.medium
                .sample_local(&pts, &dirs, &lam, channels, &s1, &s2)
        });
        let wo: Vec<f64> = wo.into_iter().flatten().collect();
        Ok((
            wo.into_pyarray(py),
            w.into_pyarray(py),
            pdf.into_pyarray(py),
        ))
    }

    /// Particles whose disk the tau_max floor widened beyond query_radius + radius.
    #[getter]
    fn widened(&self) -> usize {
        self.medium.widened()
    }

    /// Largest optical depth of a particle's disk.
    #[getter]
    fn tau_max(&self) -> f64 {
        self.medium.tau_max()
    }

    /// Largest inclusion radius of a particle (scene units).
    #[getter]
    fn reach_max(&self) -> f64 {
        self.medium.reach_max()
    }

    /// Particles sampled as a continuous medium (size classes no pixel resolves).
    #[getter]
    fn continuous_particles(&self) -> usize {
        self.medium.continuous_len()
    }

    /// Remember an event of the given particles at `p` (tests and tools).
    fn insert_event(&self, p: (f32, f32, f32), particles: Vec<u32>) -> PyResult<()> {
        self.medium
            .insert_event([p.0, p.1, p.2], &particles)
            .map_err(to_py)
    }

    /// Grey optical depth of segments [t0, t1) (f64 rays), as used by the free flights.
    fn optical_depth<'py>(
        &self,
        py: Python<'py>,
        origins: F64In,
        directions: F64In,
        t0: F64In,
        t1: F64In,
    ) -> PyResult<F64Out<'py>> {
        let (t0, t1) = (t0.as_slice()?.to_vec(), t1.as_slice()?.to_vec());
        let rs = rays(origins.as_slice()?, directions.as_slice()?, t0.len())?;
        if t1.len() != t0.len() {
            return Err(PyValueError::new_err(
                "t0 and t1 must have one value per ray",
            ));
        }
        let m = &self.medium;
        let out: Vec<f64> = py.detach(|| {
            rs.par_iter()
                .zip(t0.par_iter().zip(t1.par_iter()))
                .map(|((o, d), (a, b))| m.optical_depth(*o, *d, *a, *b))
                .collect()
        });
        Ok(out.into_pyarray(py))
    }

    #[getter]
    fn bytes(&self) -> usize {
        self.medium.bytes()
    }
    fn __len__(&self) -> usize {
        self.medium.len()
    }
}

/// FNV-1a 64 hash (hex) of the Rust sources this extension was built from (`build.rs`): it changes with
/// the physics, so caches of computed tables key on it.
#[pyfunction]
fn core_hash() -> &'static str {
    env!("MOTES_CORE_HASH")
}

/// The default wavelength sets (µm): (RGB, spectral), `motes_core::wavelengths`.
#[pyfunction]
fn default_wavelengths() -> (Vec<f64>, Vec<f64>) {
    (
        motes_core::wavelengths::RGB_WAVELENGTHS_UM.to_vec(),
        motes_core::wavelengths::spectral_wavelengths_um().to_vec(),
    )
}

#[pymodule]
fn _motes(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(mie_amplitudes, m)?)?;
    m.add_function(wrap_pyfunction!(goa_amplitudes, m)?)?;
    m.add_function(wrap_pyfunction!(cross_sections, m)?)?;
    m.add_function(wrap_pyfunction!(phase_function, m)?)?;
    m.add_function(wrap_pyfunction!(goa_extinction_efficiency, m)?)?;
    m.add_function(wrap_pyfunction!(policy_constants, m)?)?;
    m.add_function(wrap_pyfunction!(resolve_method, m)?)?;
    m.add_function(wrap_pyfunction!(psd_validate, m)?)?;
    m.add_function(wrap_pyfunction!(psd_eval, m)?)?;
    m.add_function(wrap_pyfunction!(psd_sample, m)?)?;
    m.add_function(wrap_pyfunction!(psd_quadrature, m)?)?;
    m.add_function(wrap_pyfunction!(psd_support, m)?)?;
    m.add_function(wrap_pyfunction!(bulk_properties, m)?)?;
    m.add_function(wrap_pyfunction!(phase_table_eval, m)?)?;
    m.add_function(wrap_pyfunction!(phase_table_sample, m)?)?;
    m.add_function(wrap_pyfunction!(phase_table_regular_mu, m)?)?;
    m.add_function(wrap_pyfunction!(material_index, m)?)?;
    m.add_function(wrap_pyfunction!(core_hash, m)?)?;
    m.add_function(wrap_pyfunction!(default_wavelengths, m)?)?;
    m.add_function(wrap_pyfunction!(interrupt::exit_on_wakeup, m)?)?;
    m.add_function(wrap_pyfunction!(interrupt::set_exit_message, m)?)?;
    m.add_class::<PyParticleGrid>()?;
    m.add_class::<PyDiscreteMedium>()?;
    m.add("DEFAULT_TAU_MAX", motes_core::discrete::DEFAULT_TAU_MAX)?;
    m.add(
        "DEFAULT_CELLS_PER_PARTICLE",
        motes_core::grid::DEFAULT_CELLS_PER_PARTICLE,
    )?;
    m.add(
        "DEFAULT_CONTINUOUS_COUNT",
        motes_core::continuous::DEFAULT_CONTINUOUS_COUNT,
    )?;
    // The native render path's C interface (rust/motes-py/src/native.rs): its address and version.
    m.add(
        "NATIVE_API",
        &native::API as *const native::NativeApi as usize,
    )?;
    m.add("NATIVE_ABI", native::NATIVE_ABI)?;

    Ok(())
}
