//! The inside of the shapes that hold a medium (`motes_core::space::inside`): inside tests, volume and
//! uniform points over closed meshes and Mitsuba's analytic spheres and cylinders, for a `discrete`
//! medium that fills its holders.

use crate::convert::*;
use motes_core::space::inside::{open_edges, Holders, Mesh, Solid};
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::prelude::*;
use rayon::prelude::*;

/// A mesh's faces (m*3 vertex indices) as triangles.
fn faces_of(faces: &PyReadonlyArray1<'_, u32>) -> PyResult<Vec<[u32; 3]>> {
    let f = faces.as_slice()?;
    if f.len() % 3 != 0 {
        return Err(invalid(
            "faces",
            f.len(),
            "three vertex indices per triangle".into(),
        ));
    }
    Ok(f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Edges of a mesh (vertices n*3, world space; faces m*3) shared by an odd number of its faces, after
/// welding vertices at the same position: 0 for a closed mesh.
#[pyfunction]
pub(crate) fn mesh_open_edges(
    py: Python<'_>,
    vertices: F64In,
    faces: PyReadonlyArray1<'_, u32>,
) -> PyResult<usize> {
    let v = points(&vertices)?;
    let f = faces_of(&faces)?;
    Ok(py.detach(|| open_edges(&v, &f)))
}

/// The closed shapes that hold a medium, in world space: `meshes` as (vertices n*3, faces m*3) pairs,
/// `ellipsoids` and `cylinders` as the 3×4 `to_world` of Mitsuba's unit sphere and unit cylinder
/// (taken solid). The inside is their union.
#[pyclass(name = "Holders", module = "motes._motes", frozen)]
pub(crate) struct PyHolders {
    inner: Holders,
}

impl PyHolders {
    pub(crate) fn holders(&self) -> &Holders {
        &self.inner
    }
}

#[pymethods]
impl PyHolders {
    #[new]
    #[pyo3(signature = (meshes=Vec::new(), ellipsoids=Vec::new(), cylinders=Vec::new()))]
    fn new(
        py: Python<'_>,
        meshes: Vec<(F64In, PyReadonlyArray1<'_, u32>)>,
        ellipsoids: Vec<[[f64; 4]; 3]>,
        cylinders: Vec<[[f64; 4]; 3]>,
    ) -> PyResult<Self> {
        let mut solids = Vec::new();
        for (v, f) in &meshes {
            let (v, f) = (points(v)?, faces_of(f)?);
            solids.push(Solid::Mesh(py.detach(|| Mesh::new(&v, &f)).map_err(to_py)?));
        }
        for m in ellipsoids {
            solids.push(Solid::ellipsoid(m).map_err(to_py)?);
        }
        for m in cylinders {
            solids.push(Solid::cylinder(m).map_err(to_py)?);
        }
        Ok(PyHolders {
            inner: Holders::new(solids).map_err(to_py)?,
        })
    }

    /// Whether each point (n*3) lies inside any of the shapes.
    fn contains<'py>(
        &self,
        py: Python<'py>,
        points_in: F64In,
    ) -> PyResult<Bound<'py, numpy::PyArray1<bool>>> {
        let p = points_view(points_in.as_slice()?)?;
        let out: Vec<bool> = py.detach(|| p.par_iter().map(|&q| self.inner.contains(q)).collect());
        Ok(out.into_pyarray(py))
    }

    /// `contains` testing every triangle of every mesh (the O(N·T) oracle of the grid).
    fn contains_brute<'py>(
        &self,
        py: Python<'py>,
        points_in: F64In,
    ) -> PyResult<Bound<'py, numpy::PyArray1<bool>>> {
        let p = points_view(points_in.as_slice()?)?;
        let out: Vec<bool> = py.detach(|| {
            p.par_iter()
                .map(|&q| {
                    self.inner.solids().iter().any(|s| match s {
                        Solid::Mesh(m) => m.contains_brute(q),
                        other => other.contains(q),
                    })
                })
                .collect()
        });
        Ok(out.into_pyarray(py))
    }

    /// (volume of the union, whether it is exact) (`motes_core::space::inside::Holders::volume`).
    #[pyo3(signature = (seed=0))]
    fn volume(&self, py: Python<'_>, seed: u64) -> (f64, bool) {
        py.detach(|| self.inner.volume(seed))
    }

    /// Exactly `count` points (count*3) uniform over the union, reproducible from `seed`.
    fn fill<'py>(&self, py: Python<'py>, count: u64, seed: u64) -> PyResult<F64Out<'py>> {
        let pts = py.detach(|| self.inner.fill(count, seed)).map_err(to_py)?;
        let flat: Vec<f64> = pts.into_iter().flatten().collect();
        Ok(flat.into_pyarray(py))
    }

    /// The box of all the shapes: ((lo x, y, z), (hi x, y, z)).
    #[getter]
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        self.inner.bounds()
    }

    fn __len__(&self) -> usize {
        self.inner.solids().len()
    }
}
