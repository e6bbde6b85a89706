//! The discrete medium as the renderer queries it (`motes_core::render::discrete`): its builds and the
//! figures fixed there, the handle the native plugin uses ([`native`]), its settings and optics tables
//! ([`settings`]), the evaluated-mode batch calls ([`batch`]) and what it knows of its scene ([`view`]).

mod batch;
mod procedural;
pub(crate) mod settings;
mod view;

use crate::convert::*;
use crate::native;
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::prelude::*;
use settings::{PyBinTables, PyMediumSettings};
use std::sync::Arc;

/// The discrete medium as the renderer queries it (see `motes_core::render::discrete`).
#[pyclass(name = "DiscreteMedium", module = "motes._motes", frozen)]
pub(crate) struct PyDiscreteMedium {
    medium: Arc<motes_core::render::discrete::DiscreteMedium>,
    // The medium's figures fixed at its build, read by Python as attributes.
    /// Particles whose disk the tau_max floor widened beyond query_radius + radius.
    #[pyo3(get)]
    widened: usize,
    /// Largest optical depth of a particle's disk.
    #[pyo3(get)]
    tau_max: f64,
    /// Largest inclusion radius of a particle (scene units).
    #[pyo3(get)]
    reach_max: f64,
    /// Particles sampled as a continuous medium (size classes no pixel resolves).
    #[pyo3(get)]
    continuous_particles: usize,
}

impl PyDiscreteMedium {
    /// The Python object over a built medium, with its figures fixed at the build.
    fn wrap(medium: motes_core::render::discrete::DiscreteMedium) -> Self {
        PyDiscreteMedium {
            widened: medium.widened(),
            tau_max: medium.tau_max(),
            reach_max: medium.reach_max(),
            continuous_particles: medium.continuous_len(),
            medium: Arc::new(medium),
        }
    }
}

#[pymethods]
impl PyDiscreteMedium {
    /// positions (n*3), radius (n) in scene units once multiplied by `radius_scale`; bin (n) into the
    /// optics bins of `tables` and each bin's grey extinction efficiency `q_ext` (a particle's cross
    /// section is π r² q_ext of its bin: no column); `settings` as `MediumSettings`. `holders`
    /// (`Holders`): the shapes whose inside the particles fill, to which the continuous fields are
    /// confined (`motes_core::render::discrete::DiscreteMedium::confine`). `density` (kind, params,
    /// noise seed as `generate_cloud`, the cloud's box lo and hi, its transform 3×4): the density the
    /// particles were drawn from, which then spreads the grains' continuous equivalent
    /// (`DiscreteMedium::see_density`).
    #[new]
    #[pyo3(signature = (positions, radius, q_ext, bin, tables, settings, radius_scale=1.0, holders=None, density=None))]
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn new(
        py: Python<'_>,
        positions: F64In,
        radius: F64In,
        q_ext: F64In,
        bin: PyReadonlyArray1<'_, u32>,
        tables: &PyBinTables,
        settings: &PyMediumSettings,
        radius_scale: f64,
        holders: Option<PyRef<'_, crate::inside::PyHolders>>,
        density: Option<(String, Vec<f64>, u64, [f64; 3], [f64; 3], [[f64; 4]; 3])>,
    ) -> PyResult<Self> {
        // Borrowed, not copied (10^8 particles: 4 GB): the build holds the GIL instead of releasing it,
        // so no Python thread can change the arrays under it (its rayon workers need no GIL).
        let (pos, r, q, b) = (
            points_view(positions.as_slice()?)?,
            radius.as_slice()?,
            q_ext.as_slice()?,
            bin.as_slice()?,
        );
        if q.len() != tables.bins.len() {
            return Err(invalid(
                "q_ext",
                q.len(),
                format!("one per bin ({})", tables.bins.len()),
            ));
        }
        // The core checks the lengths and each bin index before it forms any cross section.
        let _ = py;
        // Radii in scene units are r × radius_scale (the core checks the scale).
        let c_ext = |i: usize| {
            let r = r[i] * radius_scale;
            std::f64::consts::PI * r * r * q[b[i] as usize]
        };
        let mut medium = motes_core::render::discrete::DiscreteMedium::build(
            pos,
            r,
            radius_scale,
            &c_ext,
            b,
            tables.bins.clone(),
            tables.lambda.clone(),
            &settings.inner,
        )
        .map_err(to_py)?;
        if let Some(h) = holders {
            let h = h.holders();
            medium.confine(&|p| h.contains(p));
        }
        if let Some((kind, params, noise_seed, lo, hi, transform)) = density {
            let d = crate::cloud::density(&kind, &params, noise_seed)?;
            medium
                .see_density(&d, (lo, hi), &transform)
                .map_err(to_py)?;
        }
        Ok(Self::wrap(medium))
    }

    /// A procedural cloud (`motes_core::render::procedural`): `count` expected particles in `box_`
    /// (lo, hi) after `density` (kind, params, noise seed, as `generate_cloud`), `species` (psds,
    /// shares), `cloud_seed`, mapped by `transform` (3×4); radii in scene units are µm ×
    /// `scene_per_um`; `bins` per species its optics bins' edges (µm) and first global bin, and `q_ext`
    /// per global bin, whose tables are `tables`; `settings` as `MediumSettings` (its `cache_bytes`
    /// bounds the bricks kept). Grains drift by `turbulence` (scale `turbulence_scale`, both scene
    /// units) to `time` seconds (`motes_core::space::motion`; a velocity is in `transform`).
    #[staticmethod]
    #[pyo3(signature = (count, box_, density, species, cloud_seed, transform, scene_per_um, bins, tables, settings, *, turbulence=0.0, turbulence_scale=1.0, time=0.0))]
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn procedural(
        py: Python<'_>,
        count: f64,
        box_: ([f64; 3], [f64; 3]),
        density: (String, Vec<f64>, u64),
        species: (Vec<PyRef<'_, crate::psd::PyPsd>>, Vec<f64>),
        cloud_seed: u64,
        transform: [[f64; 4]; 3],
        scene_per_um: f64,
        bins: (Vec<Vec<f64>>, Vec<u32>, Vec<f64>),
        tables: &PyBinTables,
        settings: &PyMediumSettings,
        turbulence: f64,
        turbulence_scale: f64,
        time: f64,
    ) -> PyResult<Self> {
        if !time.is_finite() {
            return Err(invalid(
                "time",
                time,
                format!("invalid time = {time}: must be finite (seconds)"),
            ));
        }
        // Checked whether or not it moves anything now (a NaN turbulence is an error at time 0 too).
        let m = motes_core::space::motion::Motion::new(
            [0.0; 3],
            turbulence,
            turbulence_scale,
            cloud_seed,
        )
        .map_err(to_py)?;
        let motion = (turbulence > 0.0 && time != 0.0).then_some((m, time));
        let ((lo, hi), (kind, params, noise_seed), (psds, shares)) = (box_, density, species);
        let (bin_edges_um, first_bin, q_ext) = bins;
        let spec = motes_core::render::procedural::ProceduralSpec {
            cloud: crate::cloud::cloud_spec(
                lo, hi, &kind, &params, noise_seed, &psds, shares, cloud_seed,
            )?,
            count,
            transform,
            scene_per_um,
            bin_edges_um,
            first_bin,
            q_ext,
            motion,
        };
        let (bins, lam) = (tables.bins.clone(), tables.lambda.clone());
        let medium = py
            .detach(|| {
                motes_core::render::discrete::DiscreteMedium::procedural(
                    &spec,
                    bins,
                    lam,
                    &settings.inner,
                )
            })
            .map_err(to_py)?;
        Ok(Self::wrap(medium))
    }

    /// A procedural cloud's bricks built so far (0 for stored particles).
    #[getter]
    fn bricks_built(&self) -> u64 {
        self.medium.bricks_built()
    }

    /// Whether the particles are procedural (generated on demand, none stored).
    #[getter]
    fn procedural_cloud(&self) -> bool {
        self.medium.is_procedural()
    }

    /// A new handle on the core medium for a native plugin (an address; it releases it through the
    /// native API's `release`), which keeps `owner` alive until then (`native_owner`).
    #[pyo3(signature = (owner=None))]
    fn native_handle(&self, owner: Option<Py<PyAny>>) -> usize {
        native::handle(&self.medium, owner)
    }

    /// Set this medium as the core of the pending native handle `handle` (`native_pending_handle`),
    /// once, with `owner` as its new owner.
    #[pyo3(signature = (handle, owner=None))]
    fn native_fill(&self, handle: usize, owner: Option<Py<PyAny>>) -> PyResult<()> {
        native::fill(handle, &self.medium, owner)
            .map_err(|e| invalid("handle", handle, e.to_string()))
    }

    /// How many references to the core medium live outside this object (native plugins not yet
    /// destroyed, and calls in flight): 0 once every native plugin made over it is gone.
    #[getter]
    fn native_references(&self) -> usize {
        Arc::strong_count(&self.medium) - 1
    }

    /// (rays, events) that went through the native render path so far.
    #[getter]
    fn native_counts(&self) -> (u64, u64) {
        self.medium.packet_counts()
    }

    /// The factor on every particle's albedo (1 unless set; see `set_albedo_scale`).
    #[getter]
    fn albedo_scale(&self) -> f64 {
        self.medium.albedo_scale()
    }

    /// Scale every particle's albedo from the next query on (between renders).
    fn set_albedo_scale(&self, scale: f64) -> PyResult<()> {
        self.medium.set_albedo_scale(scale).map_err(to_py)
    }

    /// Scattering events of a path from which its rays see the grains' continuous equivalent (1 as
    /// built; see `set_grain_depth`).
    #[getter]
    fn grain_depth(&self) -> u32 {
        self.medium.grain_depth()
    }

    /// Rays leaving a path's `depth`-th scattering event or a later one see the grains' continuous
    /// equivalent instead of walking them (ignored when `continuous_count` is infinite: exact).
    fn set_grain_depth(&self, depth: u32) -> PyResult<()> {
        self.medium.set_grain_depth(depth).map_err(to_py)
    }

    /// Remember an event of the given particles at `p` (tests and tools). Particles are named as the
    /// medium names them: by index (full storage) or by position in its grid (compact storage).
    fn insert_event(&self, p: (f32, f32, f32), particles: Vec<u32>) -> PyResult<()> {
        self.medium
            .insert_event([p.0, p.1, p.2], &particles)
            .map_err(to_py)
    }

    /// The bins' optics tables as flat arrays (`DiscreteMedium::flat_tables`): "mu", "f", "cdf" (the
    /// nodes of table i at `offset[i]..offset[i + 1]`), "mueller" (3 ratios a node, F12/F11, F33/F11,
    /// F34/F11; 0 where a bin depolarises), "offset" and "albedo" per table, table
    /// `bin * n_lambda + k` at tabulated wavelength k.
    fn flat_tables<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let t = self.medium.flat_tables();
        let d = pyo3::types::PyDict::new(py);
        d.set_item("mu", t.mu.into_pyarray(py))?;
        d.set_item("f", t.f.into_pyarray(py))?;
        d.set_item("cdf", t.cdf.into_pyarray(py))?;
        let mueller: Vec<f32> = t.mueller.iter().flatten().copied().collect();
        d.set_item("mueller", mueller.into_pyarray(py))?;
        d.set_item("offset", t.offset.into_pyarray(py))?;
        d.set_item("albedo", t.albedo.into_pyarray(py))?;
        Ok(d)
    }

    /// Grey optical depth of segments [t0, t1) (f64 rays), as used by the free flights.
    fn optical_depth<'py>(&self, py: Python<'py>, segments: SegmentsIn) -> PyResult<F64Out<'py>> {
        let segs = segments.get()?;
        let out = per_segment(py, &segs, |_, ray| self.medium.optical_depth(ray));
        Ok(out.into_pyarray(py))
    }

    /// The grains walked one by one as flat arrays (`ParticleGrid.flat_arrays`, grey τ) with each
    /// grain's optics bin ("bin"); None where no grain is stored (procedural, all continuous).
    fn flat_arrays<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, pyo3::types::PyDict>>> {
        let Some(out) = py.detach(|| self.medium.flat_grains()) else {
            return Ok(None);
        };
        let (flat, bins) = out.map_err(to_py)?;
        let d = crate::grid::flat_dict(py, flat)?;
        d.set_item("bin", bins.into_pyarray(py))?;
        Ok(Some(d))
    }

    /// The continuous field of the size classes no pixel resolves (`DiscreteMedium::flat_field`) as
    /// numpy arrays: "lo", "cell" (3 each, f64), "dims" (3, u32), "sigma" (per cell, f32, per scene unit,
    /// x fastest), "start" (cells + 1, u32) and per entry "bin" (u32, as `flat_tables`) and "share"
    /// (f32, of its cell's extinction); None without such a field.
    fn flat_field<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, pyo3::types::PyDict>>> {
        let Some(f) = py.detach(|| self.medium.flat_field()) else {
            return Ok(None);
        };
        let d = pyo3::types::PyDict::new(py);
        d.set_item("lo", f.lo.to_vec().into_pyarray(py))?;
        d.set_item("cell", f.cell.to_vec().into_pyarray(py))?;
        d.set_item("dims", f.dims.to_vec().into_pyarray(py))?;
        d.set_item("sigma", f.sigma.into_pyarray(py))?;
        d.set_item("start", f.start.into_pyarray(py))?;
        d.set_item("bin", f.bin.into_pyarray(py))?;
        d.set_item("share", f.share.into_pyarray(py))?;
        Ok(Some(d))
    }

    /// Heap bytes the medium holds (its particles, grid, fields and optics tables).
    #[getter]
    fn bytes(&self) -> usize {
        self.medium.bytes()
    }

    /// Of `bytes`, the optics bins' tables: a fixed cost whatever the number of particles.
    #[getter]
    fn table_bytes(&self) -> usize {
        self.medium.table_bytes()
    }
    fn __len__(&self) -> usize {
        self.medium.len()
    }
}

/// The checks of a particle set (positions n*3 and radii in scene units) and the medium's settings
/// that need no optics tables (`motes_core::render::discrete::check_particles_and_settings`): the
/// Python layer calls this before it builds the tables, so a bad value fails at once, with the core's
/// own rule and message.
#[pyfunction]
pub(crate) fn check_discrete_inputs(
    positions: F64In,
    radius: F64In,
    settings: &PyMediumSettings,
) -> PyResult<()> {
    motes_core::render::discrete::check_particles_and_settings(
        points_view(positions.as_slice()?)?,
        radius.as_slice()?,
        &settings.inner,
    )
    .map_err(to_py)
}

/// The box of points (n*3): ((lo x, y, z), (hi x, y, z)); numpy's `min(axis=0)` over an (n, 3) array
/// reads it strided, ~0.25 s per call at 10^7 points.
#[pyfunction]
pub(crate) fn bounding_box(py: Python<'_>, points: F64In) -> PyResult<([f64; 3], [f64; 3])> {
    let p = points_view(points.as_slice()?)?;
    Ok(py.detach(|| motes_core::space::grid::bounding_box(p)))
}

/// Each radius's optics bin among the increasing bin `edges` (numpy's
/// `searchsorted(edges, radius, side="right") - 1`, clipped to the bins), as `lookup[bin]` where
/// given; in parallel (`motes_core::render::storage::size_bins`).
#[pyfunction]
#[pyo3(signature = (radius, edges, lookup=None))]
pub(crate) fn size_bins<'py>(
    py: Python<'py>,
    radius: F64In,
    edges: F64In,
    lookup: Option<PyReadonlyArray1<'_, u32>>,
) -> PyResult<Bound<'py, numpy::PyArray1<u32>>> {
    let (r, e) = (radius.as_slice()?, edges.as_slice()?);
    let bins = e.len().saturating_sub(1).max(1);
    let lookup = match &lookup {
        Some(l) => {
            let l = l.as_slice()?;
            if l.len() < bins {
                return Err(invalid("lookup", l.len(), format!("one per bin ({bins})")));
            }
            Some(l)
        }
        None => None,
    };
    if e.is_empty() {
        return Err(invalid("edges", 0, "at least one edge".to_string()));
    }
    // Borrowed arrays, the GIL held (as `DiscreteMedium.__new__`): its rayon workers need none.
    Ok(motes_core::render::storage::size_bins(r, e, lookup).into_pyarray(py))
}

/// The owner given with a native handle that is still held by a native plugin, or None (an unknown or
/// released handle: nothing is dereferenced then).
#[pyfunction]
pub fn native_owner(py: Python<'_>, handle: usize) -> Option<Py<PyAny>> {
    native::owner(py, handle)
}

/// A new native handle without a core medium yet (a medium that fills the shapes holding it): the
/// native plugins made over it let every ray pass until `DiscreteMedium.native_fill` sets its core.
/// `owner` is what `native_owner` answers until then.
#[pyfunction]
#[pyo3(signature = (owner=None))]
pub fn native_pending_handle(owner: Option<Py<PyAny>>) -> usize {
    native::pending_handle(owner)
}
