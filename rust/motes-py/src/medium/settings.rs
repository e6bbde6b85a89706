//! What a discrete medium's build takes besides its particles, as Python objects: its settings
//! (`MediumSettings`, keyword arguments with the core's defaults) and its bins' optics tables
//! (`BinTables`). Each is checked once, where it is made, so a bad value fails before any build.

use crate::convert::*;
use motes_core::render::discrete::{BinOptics, MediumSettings, MuellerRatios};
use motes_core::render::storage::Storage;
use numpy::PyReadonlyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// The settings of a discrete medium (`motes_core::render::discrete::MediumSettings`): keyword
/// arguments, each defaulting to the core's own default.
#[pyclass(name = "MediumSettings", module = "motes._motes", frozen)]
pub(crate) struct PyMediumSettings {
    pub(crate) inner: MediumSettings,
}

#[pymethods]
impl PyMediumSettings {
    /// query_radius r_c (scene units); tau_max caps each particle's optical depth by widening its disk
    /// (inf: no cap); cells_per_particle sets the grid's resolution; size classes with at least
    /// continuous_count particles per query cylinder are sampled as a continuous medium (inf: none);
    /// seed the free flights' random numbers; storage "compact" (per-class optics, quantised radii) or
    /// "full" (`motes_core::render::storage`); cache_bytes bounds a procedural cloud's bricks.
    #[new]
    #[pyo3(signature = (*, query_radius=None, tau_max=None, cells_per_particle=None, continuous_count=None, seed=None, storage=None, cache_bytes=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        query_radius: Option<f64>,
        tau_max: Option<f64>,
        cells_per_particle: Option<f64>,
        continuous_count: Option<f64>,
        seed: Option<u64>,
        storage: Option<&str>,
        cache_bytes: Option<usize>,
    ) -> PyResult<Self> {
        let d = MediumSettings::default();
        let storage = storage
            .map(Storage::parse)
            .transpose()
            .map_err(to_py)?
            .unwrap_or(d.storage);
        Ok(PyMediumSettings {
            inner: MediumSettings {
                query_radius: query_radius.unwrap_or(d.query_radius),
                tau_max: tau_max.unwrap_or(d.tau_max),
                cells_per_particle: cells_per_particle.unwrap_or(d.cells_per_particle),
                continuous_count: continuous_count.unwrap_or(d.continuous_count),
                seed: seed.unwrap_or(d.seed),
                storage,
                cache_bytes: cache_bytes.unwrap_or(d.cache_bytes),
            },
        })
    }

    #[getter]
    fn query_radius(&self) -> f64 {
        self.inner.query_radius
    }
    #[getter]
    fn tau_max(&self) -> f64 {
        self.inner.tau_max
    }
    #[getter]
    fn cells_per_particle(&self) -> f64 {
        self.inner.cells_per_particle
    }
    #[getter]
    fn continuous_count(&self) -> f64 {
        self.inner.continuous_count
    }
    #[getter]
    fn seed(&self) -> u64 {
        self.inner.seed
    }
    #[getter]
    fn storage(&self) -> &'static str {
        match self.inner.storage {
            Storage::Compact => "compact",
            Storage::Full => "full",
        }
    }
    #[getter]
    fn cache_bytes(&self) -> usize {
        self.inner.cache_bytes
    }
    fn __repr__(&self) -> String {
        format!("{:?}", self.inner)
    }
}

/// Each optics bin's albedo and phase function per tabulated wavelength, from flat arrays: albedo
/// (bins*K), phase tables as flat theta/f with offsets (bins*K + 1) ending at len(theta), lambda (K
/// wavelengths in nm, increasing); optionally `mueller`, the tables' polarisation (`add_mueller`).
#[pyclass(name = "BinTables", module = "motes._motes", frozen)]
pub(crate) struct PyBinTables {
    pub(crate) bins: Vec<BinOptics>,
    pub(crate) lambda: Vec<f64>,
}

#[pymethods]
impl PyBinTables {
    #[new]
    #[pyo3(signature = (albedo, theta, f, offsets, lambda, mueller=None))]
    fn new(
        albedo: F64In,
        theta: F64In,
        f: F64In,
        offsets: PyReadonlyArray1<'_, u64>,
        lambda: F64In,
        mueller: Option<F64In>,
    ) -> PyResult<Self> {
        let lambda = lambda.as_slice()?.to_vec();
        let mut bins = bin_optics(&albedo, &theta, &f, &offsets, lambda.len())?;
        if let Some(m) = mueller {
            add_mueller(&mut bins, m.as_slice()?, offsets.as_slice()?, lambda.len())?;
        }
        Ok(PyBinTables { bins, lambda })
    }

    /// The number of optics bins.
    fn __len__(&self) -> usize {
        self.bins.len()
    }
}

/// The Mueller ratios of every table (polarised variants): `m` holds, table after table (as `offsets`
/// cut `theta`), three rows F12/F11, F33/F11, F34/F11 of that table's length.
fn add_mueller(bins: &mut [BinOptics], m: &[f64], off: &[u64], k: usize) -> PyResult<()> {
    if m.len() != 3 * off.last().copied().unwrap_or(0) as usize {
        return Err(PyValueError::new_err(
            "mueller must hold three ratios per phase-table node (3 * len(theta))",
        ));
    }
    for (t, b) in (0..).step_by(k).zip(bins.iter_mut()) {
        b.mueller = (t..t + k)
            .map(|t| {
                let (a, e) = (3 * off[t] as usize, 3 * off[t + 1] as usize);
                let n = (e - a) / 3;
                let rows = &m[a..e];
                MuellerRatios::new(&rows[..n], &rows[n..2 * n], &rows[2 * n..]).map_err(to_py)
            })
            .collect::<PyResult<_>>()?;
    }
    Ok(())
}

/// The bins of flat arrays as `PyBinTables::new` takes them, `k` wavelengths each.
fn bin_optics(
    albedo: &F64In,
    theta: &F64In,
    f: &F64In,
    offsets: &PyReadonlyArray1<'_, u64>,
    k: usize,
) -> PyResult<Vec<BinOptics>> {
    let (al, th, fv, off) = (
        albedo.as_slice()?,
        theta.as_slice()?,
        f.as_slice()?,
        offsets.as_slice()?,
    );
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
    let table = |t: usize| {
        let (a, e) = (off[t] as usize, off[t + 1] as usize);
        if a > e || e > th.len() {
            return Err(PyValueError::new_err("offsets must be increasing"));
        }
        motes_core::ensemble::phase_table::PhaseTable::new(&th[a..e], &fv[a..e]).map_err(to_py)
    };
    (0..al.len() / k)
        .map(|bi| {
            Ok(BinOptics {
                albedo: al[bi * k..(bi + 1) * k].to_vec(),
                phase: (bi * k..(bi + 1) * k).map(table).collect::<PyResult<_>>()?,
                mueller: Vec::new(),
            })
        })
        .collect()
}
