//! Single-particle optics (Mie, GOA, the `auto` policy and materials): batches over flat arrays of
//! particles and angles (`motes_core::optics`, `motes_core::optics::mie`, `motes_core::optics::goa`).

use crate::convert::*;
use crate::interrupt::interruptible;
use motes_core::optics::goa::GoaOptions;
use motes_core::optics::{self, GoaCache, Method, ParticleColumns, Theory};
use num_complex::Complex64 as C64;
use numpy::{IntoPyArray, PyArray1, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// The five particle columns every batch function below takes first, copied once.
pub(crate) struct Columns {
    r: Vec<f64>,
    lam: Vec<f64>,
    er: Vec<f64>,
    ei: Vec<f64>,
    em: Vec<f64>,
}

impl Columns {
    fn new(r: F64In, lam: F64In, er: F64In, ei: F64In, em: F64In) -> Self {
        let v = |a: &F64In| a.as_array().to_vec();
        Columns {
            r: v(&r),
            lam: v(&lam),
            er: v(&er),
            ei: v(&ei),
            em: v(&em),
        }
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

/// A `#[pyfunction]` over a batch of particles: its Python signature starts with the columns
/// `radius_um, wavelength_um, eta_re, eta_im, eta_medium`, which reach the body as the [`Columns`]
/// named after `py`; the other arguments follow as written.
macro_rules! particle_pyfunction {
    (
        $(#[$attr:meta])*
        fn $name:ident<$lt:lifetime>($py:ident, $cols:ident $(, $arg:ident: $ty:ty)* $(,)?)
            -> $ret:ty $body:block
    ) => {
        $(#[$attr])*
        #[pyfunction]
        #[allow(clippy::too_many_arguments)]
        pub(crate) fn $name<$lt>(
            $py: Python<$lt>,
            radius_um: F64In,
            wavelength_um: F64In,
            eta_re: F64In,
            eta_im: F64In,
            eta_medium: F64In,
            $($arg: $ty,)*
        ) -> PyResult<$ret> {
            let $cols = Columns::new(radius_um, wavelength_um, eta_re, eta_im, eta_medium);
            $body
        }
    };
}

pub(crate) fn options(
    p_max: u32,
    diffraction: bool,
    regularise: bool,
    edge_correction: bool,
) -> GoaOptions {
    GoaOptions {
        p_max,
        diffraction,
        regularise,
        edge_correction,
    }
}

/// Relative indices whose GOA ray geometry (with its prepared angle grids) the free functions keep.
const FREE_FUNCTION_INDICES: usize = 8;

/// The GOA ray geometry the binding's free functions (`goa_amplitudes`, `cross_sections`,
/// `phase_function`) share from one call to the next: owned by the binding, not by the core, bounded
/// (the [`FREE_FUNCTION_INDICES`] most recently used relative indices, each memo bounded in bytes) and
/// emptied by `clear_goa_cache` (issue 23: without it every call rebuilt the geometry, ~1 ms).
static FREE_FUNCTION_GOA: std::sync::LazyLock<GoaCache> =
    std::sync::LazyLock::new(|| GoaCache::bounded(FREE_FUNCTION_INDICES));

/// Empty the free functions' GOA cache.
#[pyfunction]
pub(crate) fn clear_goa_cache() {
    FREE_FUNCTION_GOA.clear();
}

/// (relative indices held, approximate bytes) of the free functions' GOA cache.
#[pyfunction]
pub(crate) fn goa_cache_info() -> (usize, usize) {
    (FREE_FUNCTION_GOA.len(), FREE_FUNCTION_GOA.bytes())
}

pub(crate) type Amps<'py> = (Bound<'py, PyArray1<C64>>, Bound<'py, PyArray1<C64>>);

pub(crate) fn amplitudes<'py>(
    py: Python<'py>,
    cols: Columns,
    theta: &F64In,
    theory: Theory,
    opts: GoaOptions,
) -> PyResult<Amps<'py>> {
    let theta = theta.as_array().to_vec();
    let out = interruptible(py, || {
        optics::amplitudes_batch(
            &cols.view(),
            &theta,
            theory,
            &opts,
            Some(&FREE_FUNCTION_GOA),
        )
    })?
    .map_err(to_py)?;
    let (s1, s2): (Vec<C64>, Vec<C64>) = out.into_iter().unzip();
    Ok((s1.into_pyarray(py), s2.into_pyarray(py)))
}

particle_pyfunction! {
    /// Lorenz–Mie amplitudes (S1, S2), Bohren–Huffman convention.
    fn mie_amplitudes<'py>(py, cols, theta: F64In) -> Amps<'py> {
        amplitudes(py, cols, &theta, Theory::Mie, GoaOptions::default())
    }
}

particle_pyfunction! {
    /// GOA amplitudes (S1, S2), Bohren–Huffman convention.
    fn goa_amplitudes<'py>(
        py,
        cols,
        theta: F64In,
        p_max: u32,
        diffraction: bool,
        regularise: bool,
        edge_correction: bool,
    ) -> Amps<'py> {
        let opts = options(p_max, diffraction, regularise, edge_correction);
        amplitudes(py, cols, &theta, Theory::Goa, opts)
    }
}

particle_pyfunction! {
    /// Cross sections (ext, sca, abs in µm²) and asymmetry g.
    fn cross_sections<'py>(
        py,
        cols,
        method: &str,
        hybrid_radius_um: f64,
        p_max: u32,
        regularise: bool,
        edge_correction: bool,
        with_g: bool,
    ) -> (F64Out<'py>, F64Out<'py>, F64Out<'py>, F64Out<'py>) {
        let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
        let opts = options(p_max, true, regularise, edge_correction);
        let cs = interruptible(py, || {
            optics::cross_sections_batch(
                &cols.view(),
                method,
                &opts,
                with_g,
                Some(&FREE_FUNCTION_GOA),
            )
        })?
        .map_err(to_py)?;
        let col = |f: fn(&optics::CrossSections) -> f64| {
            cs.iter().map(f).collect::<Vec<f64>>().into_pyarray(py)
        };
        Ok((col(|c| c.ext), col(|c| c.sca), col(|c| c.abs), col(|c| c.g)))
    }
}

/// The arguments of a per-element batch with a method (`phase_function_batch`, `mueller_batch`): the
/// particles, the angles, the method parsed and the GOA options.
pub(crate) struct MethodArgs {
    cols: Columns,
    theta: Vec<f64>,
    method: Method,
    opts: GoaOptions,
}

impl MethodArgs {
    /// Runs `batch` on them with the GIL released, on the free functions' GOA cache.
    fn run<T: Send>(
        &self,
        py: Python<'_>,
        batch: impl Fn(
                &ParticleColumns,
                &[f64],
                Method,
                &GoaOptions,
                Option<&GoaCache>,
            ) -> Result<Vec<T>, motes_core::OpticsError>
            + Send
            + Sync,
    ) -> PyResult<Vec<T>> {
        interruptible(py, || {
            batch(
                &self.cols.view(),
                &self.theta,
                self.method,
                &self.opts,
                Some(&FREE_FUNCTION_GOA),
            )
        })?
        .map_err(to_py)
    }
}

/// A [`particle_pyfunction!`] of particles at angles with a method: its Python arguments go on with
/// `theta, method, hybrid_radius_um, p_max, regularise, edge_correction`, which reach the body as the
/// [`MethodArgs`] named second; the other arguments follow as written.
macro_rules! method_pyfunction {
    (
        $(#[$attr:meta])*
        fn $name:ident<$lt:lifetime>($py:ident, $args:ident $(, $arg:ident: $ty:ty)* $(,)?)
            -> $ret:ty $body:block
    ) => {
        particle_pyfunction! {
            $(#[$attr])*
            fn $name<$lt>(
                $py,
                cols,
                theta: F64In,
                method: &str,
                hybrid_radius_um: f64,
                p_max: u32,
                regularise: bool,
                edge_correction: bool
                $(, $arg: $ty)*
            ) -> $ret {
                let $args = MethodArgs {
                    cols,
                    theta: theta.as_array().to_vec(),
                    method: Method::parse(method, hybrid_radius_um).map_err(to_py)?,
                    opts: options(p_max, true, regularise, edge_correction),
                };
                $body
            }
        }
    };
}

method_pyfunction! {
    /// Normalised phase function f_p(θ) (sr⁻¹), ∫ f dΩ = 1.
    fn phase_function<'py>(py, args) -> F64Out<'py> {
        Ok(args.run(py, optics::phase_function_batch)?.into_pyarray(py))
    }
}

method_pyfunction! {
    /// Mueller elements (n, 4): F11, F12, F33, F34 in Bohren & Huffman's convention, normalised so that
    /// F11 = f_p (`normalize`) or raw (`optics::mueller_batch`).
    fn mueller_matrix<'py>(py, args, normalize: bool) -> Bound<'py, numpy::PyArray2<f64>> {
        let m = args.run(py, |c, t, m, o, g| optics::mueller_batch(c, t, m, o, g, normalize))?;
        let n = m.len();
        let flat: Vec<f64> = m.into_iter().flatten().collect();
        flat.into_pyarray(py).reshape([n, 4])
    }
}

/// GOA extinction efficiency by Eq. 12 (per element), for studies of p and the regularisation.
#[pyfunction]
pub(crate) fn goa_extinction_efficiency<'py>(
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
                motes_core::optics::goa::extinction_efficiency(
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
pub(crate) fn policy_constants() -> (f64, f64, f64) {
    (
        optics::AUTO_SIZE_PARAMETER,
        optics::HYBRID_RADIUS_UM,
        optics::AXIAL_CAUSTIC_WINDOW,
    )
}

particle_pyfunction! {
    /// The theory ("mie" or "goa") that `method` picks for each particle.
    fn resolve_method<'py>(
        _py,
        cols,
        method: &str,
        hybrid_radius_um: f64,
        p_max: u32,
    ) -> Vec<&'static str> {
        let method = Method::parse(method, hybrid_radius_um).map_err(to_py)?;
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
}

/// Complex refractive index of a tabulated material ("ice", "water") at wavelengths (µm).
#[pyfunction]
pub(crate) fn material_index<'py>(
    py: Python<'py>,
    name: &str,
    wavelength_um: F64In,
) -> PyResult<Bound<'py, PyArray1<C64>>> {
    let m = motes_core::optics::materials::Material::parse(name).map_err(to_py)?;
    let out = wavelength_um
        .as_array()
        .iter()
        .map(|&l| m.index(l))
        .collect::<Result<Vec<_>, _>>()
        .map_err(to_py)?;
    Ok(out.into_pyarray(py))
}
