//! Particles in space: a grid built once and queried in batches (`motes_core::space::grid`).

use crate::convert::*;
use motes_core::space::grid::{FlatGrid, GridSettings, ParticleGrid};
use numpy::{IntoPyArray, PyArray1, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A [`FlatGrid`] as a dict of numpy arrays (`_motes.pyi`, `ParticleGrid.flat_arrays`).
pub(crate) fn flat_dict<'py>(py: Python<'py>, f: FlatGrid) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let (n, c) = (f.spheres.len(), f.classes.len());
    let spheres: Vec<f32> = f.spheres.iter().flatten().copied().collect();
    d.set_item("spheres", spheres.into_pyarray(py).reshape([n, 4])?)?;
    d.set_item("tau", f.tau.into_pyarray(py))?;
    d.set_item("index", f.index.into_pyarray(py))?;
    d.set_item("start", f.start.into_pyarray(py))?;
    let k = &f.classes;
    let lo: Vec<f64> = k.iter().flat_map(|k| k.lo).collect();
    let dims: Vec<i64> = k.iter().flat_map(|k| k.dims.map(|x| x as i64)).collect();
    let cell: Vec<f64> = k.iter().map(|k| k.cell).collect();
    let reach: Vec<f64> = k.iter().map(|k| k.reach).collect();
    let start: Vec<i64> = k.iter().map(|k| k.start_offset as i64).collect();
    let grains: Vec<i64> = k
        .iter()
        .map(|k| k.first_grain as i64)
        .chain([n as i64])
        .collect();
    d.set_item("class_lo", lo.into_pyarray(py).reshape([c, 3])?)?;
    d.set_item("class_dims", dims.into_pyarray(py).reshape([c, 3])?)?;
    d.set_item("class_cell", cell.into_pyarray(py))?;
    d.set_item("class_reach", reach.into_pyarray(py))?;
    d.set_item("class_start", start.into_pyarray(py))?;
    d.set_item("class_grains", grains.into_pyarray(py))?;
    Ok(d)
}

/// A particle grid (scene units): build once, query in batches.
#[pyclass(name = "ParticleGrid", module = "motes._motes", frozen)]
pub(crate) struct PyParticleGrid {
    grid: ParticleGrid,
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
        let (pos, r, c) = particle_columns(&positions, &radius, &c_ext)?;
        let settings = GridSettings::new(query_radius, cells_per_particle);
        let grid = py
            .detach(|| ParticleGrid::build(&pos, &r, &c, channels, &settings))
            .map_err(to_py)?;
        Ok(PyParticleGrid { grid })
    }

    /// Optical depth per ray and channel over [t0, t1); `brute` loops over every particle instead.
    fn optical_depth<'py>(
        &self,
        py: Python<'py>,
        segments: SegmentsIn,
        brute: bool,
    ) -> PyResult<F64Out<'py>> {
        let segs = segments.get()?;
        let ch = self.grid.channels();
        let out = per_segment(py, &segs, |_, ray| {
            let mut v = vec![0.0; ch];
            if brute {
                self.grid.optical_depth_brute(ray, &mut v);
            } else {
                self.grid.optical_depth(ray, &mut v);
            }
            v
        });
        Ok(out.concat().into_pyarray(py))
    }

    /// Exact free flights on [t0, t1): (t or NaN, particle index or -1, transmittance to there).
    fn free_flight<'py>(
        &self,
        py: Python<'py>,
        segments: SegmentsIn,
        u: F64In,
        channel: usize,
    ) -> PyResult<(F64Out<'py>, Bound<'py, PyArray1<i64>>, F64Out<'py>)> {
        let segs = segments.get()?;
        // Copied: read with the GIL released (see `convert`'s module docs).
        let u = u.as_slice()?.to_vec();
        if u.len() != segs.len() {
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
        let res = per_segment(py, &segs, |i, ray| {
            let (hit, tr) = self.grid.free_flight(ray, channel, u[i]);
            match hit {
                Some(h) => (h.t, h.particle as i64, tr),
                None => (f64::NAN, -1, tr),
            }
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
        segments: SegmentsIn,
        brute: bool,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let segs = segments.get()?;
        let res = per_segment(py, &segs, |_, ray| {
            let r = if brute {
                self.grid.occupied_interval_brute(ray)
            } else {
                self.grid.occupied_interval(ray)
            };
            r.unwrap_or((f64::NAN, f64::NAN))
        });
        let (lo, hi): (Vec<f64>, Vec<f64>) = res.into_iter().unzip();
        Ok((lo.into_pyarray(py), hi.into_pyarray(py)))
    }

    /// The grains as flat arrays in the centre-cell layout, τ of `channel`
    /// (`motes_core::space::grid::FlatGrid`).
    fn flat_arrays<'py>(&self, py: Python<'py>, channel: usize) -> PyResult<Bound<'py, PyDict>> {
        let f = py.detach(|| self.grid.flat(channel)).map_err(to_py)?;
        flat_dict(py, f)
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
