//! A procedural cloud's generator as numbers and the grains it generates for given tiles
//! (`motes_core::render::procedural::export`): what `motes.drjit_procedural` regenerates on the
//! device, and what its tests check it against.

use super::PyDiscreteMedium;
use crate::convert::to_py;
use motes_core::render::procedural::{DensityTerms, NoiseTerms};
use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn noise_dict<'py>(py: Python<'py>, n: &NoiseTerms) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("scale", n.scale)?;
    d.set_item("contrast", n.contrast)?;
    d.set_item("offsets", n.offsets.clone())?;
    d.set_item("bases", n.bases.clone())?;
    Ok(d)
}

#[pymethods]
impl PyDiscreteMedium {
    /// A procedural cloud's discrete process as numbers (`ProceduralGrains::export`): a dict, or None
    /// where there are no procedural grains (stored particles, or every class continuous).
    fn procedural_export<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(g) = self.medium.procedural_grains() else {
            return Ok(None);
        };
        let e = g.export();
        let d = PyDict::new(py);
        d.set_item("seed", e.seed)?;
        d.set_item("tile_stream", e.tile_stream)?;
        d.set_item("dims", e.dims.to_vec())?;
        d.set_item("lo", e.lo.to_vec())?;
        d.set_item("size", e.size.to_vec())?;
        d.set_item("halo", e.halo.to_vec())?;
        d.set_item("box_lo", e.box_lo.to_vec())?;
        d.set_item("box_hi", e.box_hi.to_vec())?;
        d.set_item("lambda", e.lambda)?;
        d.set_item("poisson", e.poisson.to_vec())?;
        d.set_item("bound", e.bound)?;
        let density = PyDict::new(py);
        match &e.density {
            DensityTerms::Uniform => density.set_item("kind", "uniform")?,
            DensityTerms::Gradient { axis, start, end } => {
                density.set_item("kind", "gradient")?;
                density.set_item("axis", *axis)?;
                density.set_item("start", *start)?;
                density.set_item("end", *end)?;
            }
            DensityTerms::Noise(n) => {
                density.set_item("kind", "noise")?;
                density.set_item("noise", noise_dict(py, n)?)?;
            }
            DensityTerms::Grid => density.set_item("kind", "grid")?,
        }
        d.set_item("density", density)?;
        let bins: Vec<u32> = (0..e.reach.len() as u32)
            .map(|k| self.medium.class_bin(k) as u32)
            .collect();
        d.set_item("codes", e.codes.into_pyarray(py))?;
        d.set_item("cdf", e.cdf.into_pyarray(py))?;
        d.set_item("reach", e.reach.into_pyarray(py))?;
        d.set_item("tau", e.tau.into_pyarray(py))?;
        d.set_item("bin", bins.into_pyarray(py))?;
        d.set_item("to_scene", e.to_scene.map(|r| r.to_vec()).to_vec())?;
        match &e.motion {
            Some((noises, turbulence, scale, time)) => {
                let m = PyDict::new(py);
                let list: Vec<Bound<'py, PyDict>> = noises
                    .iter()
                    .map(|n| noise_dict(py, n))
                    .collect::<PyResult<_>>()?;
                m.set_item("potential", list)?;
                m.set_item("turbulence", *turbulence)?;
                m.set_item("scale", *scale)?;
                m.set_item("time", *time)?;
                d.set_item("motion", m)?;
            }
            None => d.set_item("motion", py.None())?,
        }
        d.set_item("tile_index_bits", e.tile_index_bits)?;
        Ok(Some(d))
    }

    /// The grains of `tiles` (linear tile indices) as the core's bricks generate them
    /// (`ProceduralGrains::tile_grains`): a dict of "candidates" (per tile asked), and per grain
    /// "tile", "key", "code", "centre" (n*3, the cloud's coordinates) and "position" (n*3, scene).
    fn procedural_tile_grains<'py>(
        &self,
        py: Python<'py>,
        tiles: Vec<u64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let Some(g) = self.medium.procedural_grains() else {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "the medium has no procedural grains",
            ));
        };
        let out = py.detach(|| g.tile_grains(&tiles)).map_err(to_py)?;
        let d = PyDict::new(py);
        d.set_item("candidates", out.candidates.into_pyarray(py))?;
        d.set_item("tile", out.tile.into_pyarray(py))?;
        d.set_item("key", out.key.into_pyarray(py))?;
        d.set_item("code", out.code.into_pyarray(py))?;
        let flat = |v: Vec<[f64; 3]>| v.into_iter().flatten().collect::<Vec<f64>>();
        d.set_item("centre", flat(out.centre).into_pyarray(py))?;
        d.set_item("position", flat(out.position).into_pyarray(py))?;
        Ok(d)
    }
}
