//! What a discrete medium knows of its scene (`motes_core::render::footprint`, `::enclosure`): the
//! cameras and lights whose footprints rays from surfaces carry, and the convex shapes that hold it.

use super::PyDiscreteMedium;
use crate::convert::*;
use motes_core::render::enclosure::{Enclosure, Region};
use motes_core::render::footprint::{Camera, Light, View};
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;

/// A camera as Python passes it: (position, pixel angle in radians, aperture radius, orthographic
/// axis or zero, orthographic pixel width or 0).
type CameraTuple = ((f64, f64, f64), f64, f64, (f64, f64, f64), f64);
/// A light as Python passes it: (centre, radius, radius of a disc on it, the disc's normal or zero,
/// a spot's axis or zero, the cosine of its cutoff angle or -1).
type LightTuple = (
    (f64, f64, f64),
    f64,
    f64,
    (f64, f64, f64),
    (f64, f64, f64),
    f64,
);

#[pymethods]
impl PyDiscreteMedium {
    /// The cameras whose pixel footprints rays from surfaces and camera rays carry, as (position,
    /// pixel angle in radians, aperture radius, orthographic axis, orthographic pixel width) tuples
    /// (`rust/motes-core/src/render/footprint.rs`).
    #[getter]
    fn cameras(&self) -> Vec<CameraTuple> {
        let t = |p: [f64; 3]| (p[0], p[1], p[2]);
        let view = self.medium.view();
        view.cameras
            .iter()
            .map(|c| {
                let axis = t(c.axis);
                (
                    t(c.position),
                    c.pixel_angle,
                    c.aperture,
                    axis,
                    c.pixel_width,
                )
            })
            .collect()
    }

    /// The lights that shadow rays converge to, as (centre, radius, disc radius, disc normal, spot
    /// axis, spot cos_cutoff) tuples (None: unknown).
    #[getter]
    fn lights(&self) -> Option<Vec<LightTuple>> {
        let t = |p: [f64; 3]| (p[0], p[1], p[2]);
        let view = self.medium.view();
        view.lights.map(|ls| {
            ls.iter()
                .map(|l| {
                    (
                        t(l.centre),
                        l.radius,
                        l.disc,
                        t(l.normal),
                        t(l.axis),
                        l.cos_cutoff,
                    )
                })
                .collect()
        })
    }

    /// Set the cameras (a list of (position, pixel angle, aperture, orthographic axis, orthographic
    /// pixel width) tuples, axis zero for a perspective camera; empty: rays from surfaces walk the
    /// grains) and the lights at finite distance (a list of (centre, radius, disc radius,
    /// disc normal, spot axis, spot cos_cutoff) tuples: a sphere that shadow rays aim into, a disc on
    /// the light (radius 0 where none is known) and a spot's cone (axis 0 and -1 for none); None:
    /// unknown, every ray's end taken for a light), and whether every surface of
    /// the scene reflects and transmits only diffusely (rays bounced off them are blurred by the
    /// lobe), and the render's samples per pixel (0: unknown, camera rays walk the grains). The
    /// renderer calls it with its scene's sensors, emitters and shapes.
    #[pyo3(signature = (cameras, lights = None, diffuse_surfaces = false, samples_per_pixel = 0.0))]
    fn set_cameras(
        &self,
        cameras: Vec<CameraTuple>,
        lights: Option<Vec<LightTuple>>,
        diffuse_surfaces: bool,
        samples_per_pixel: f64,
    ) -> PyResult<()> {
        let cameras = cameras
            .into_iter()
            .map(|(p, angle, aperture, axis, width)| {
                let p = [p.0, p.1, p.2];
                if axis == (0.0, 0.0, 0.0) {
                    Camera::new(p, angle, aperture)
                } else {
                    Camera::orthographic(p, [axis.0, axis.1, axis.2], width)
                }
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(to_py)?;
        let lights = lights
            .map(|ls| {
                ls.into_iter()
                    .map(|(c, r, disc, n, axis, cos_cutoff)| {
                        Light::new([c.0, c.1, c.2], r)?
                            .with_disc(disc, [n.0, n.1, n.2])?
                            .with_spot([axis.0, axis.1, axis.2], cos_cutoff)
                    })
                    .collect::<Result<Vec<_>, _>>()
            })
            .transpose()
            .map_err(to_py)?;
        self.medium.set_view(View {
            cameras,
            lights,
            diffuse_surfaces,
            samples_per_pixel: if samples_per_pixel.is_finite() && samples_per_pixel > 0.0 {
                samples_per_pixel
            } else {
                0.0
            },
        });
        Ok(())
    }

    /// Set the convex shapes that hold the medium, inside which no surface lets a shadow ray through:
    /// `meshes` as (vertices (flat n*3 float64), faces (flat m*3 uint32)) pairs, `balls` as (centre,
    /// radius) pairs. A phase evaluation towards the direction of a lane's last free flight, from its
    /// origin, is then zero where that flight ended at a site inside the region holding its origin
    /// (next-event estimation multiplies it by the light it does not see; only for integrators that do
    /// so: the renderer decides). Meshes that are open or not convex hold nothing. Returns the number
    /// of regions set; no arguments: none (every evaluation computed).
    #[pyo3(signature = (meshes = Vec::new(), balls = Vec::new()))]
    fn set_enclosure(
        &self,
        meshes: Vec<(F64In<'_>, PyReadonlyArray1<'_, u32>)>,
        balls: Vec<((f64, f64, f64), f64)>,
    ) -> PyResult<usize> {
        let mut regions = Vec::new();
        for (vertices, faces) in &meshes {
            let faces = faces.as_slice()?;
            if faces.len() % 3 != 0 {
                return Err(invalid(
                    "faces",
                    faces.len(),
                    "faces must have shape (m, 3)".into(),
                ));
            }
            let faces: Vec<[u32; 3]> = faces.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            if let Some(r) = Region::convex_mesh(&points(vertices)?, &faces).map_err(to_py)? {
                regions.push(r);
            }
        }
        for (c, r) in balls {
            regions.push(Region::ball([c.0, c.1, c.2], r).map_err(to_py)?);
        }
        let n = regions.len();
        self.medium.set_enclosure(Enclosure { regions });
        Ok(n)
    }

    /// The number of convex regions set by `set_enclosure`.
    #[getter]
    fn enclosure_regions(&self) -> usize {
        self.medium.enclosure().regions.len()
    }

    /// Whether the scene's surfaces were set as diffuse only (`set_cameras`).
    #[getter]
    fn diffuse_surfaces(&self) -> bool {
        self.medium.view().diffuse_surfaces
    }

    /// The render's samples per pixel as set by `set_cameras` (0: unknown).
    #[getter]
    fn samples_per_pixel(&self) -> f64 {
        self.medium.view().samples_per_pixel
    }

    /// Whether rays from surfaces may see the grains' continuous equivalent where their pixel
    /// footprint holds many grains (an effective count over the discrete classes; on as built).
    #[getter]
    fn surface_footprint(&self) -> bool {
        self.medium.surface_footprint()
    }

    /// Rays that started at no event and were checked against the surface-ray rule, and those of them
    /// that saw the grains' continuous equivalent (statistics).
    #[getter]
    fn surface_counts(&self) -> (u64, u64) {
        self.medium.surface_counts()
    }

    /// See the `surface_footprint` property.
    fn set_surface_footprint(&self, on: bool) {
        self.medium.set_surface_footprint(on)
    }
}
