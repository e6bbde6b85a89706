//! The discrete medium as the renderer queries it (`motes_core::render::discrete`): the evaluated-mode batch
//! interface and the handle the native plugin uses.

use crate::convert::*;
use crate::native;
use motes_core::render::discrete::{MediumSettings, PhaseEvalLane, PhaseSampleLane};
use motes_core::render::enclosure::{Enclosure, Region};
use motes_core::render::footprint::{Camera, Light, View};
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::sync::Arc;

/// A camera as Python passes it: (position, pixel angle in radians, aperture radius).
type CameraTuple = ((f64, f64, f64), f64, f64);
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
    /// positions (n*3), radius (n) in scene units; bin (n) into the bins and each bin's grey extinction
    /// efficiency `q_ext` (a particle's cross section is π r² q_ext of its bin: no column); albedo
    /// (bins*K); phase tables as flat theta/f with offsets (bins*K + 1); lambda (K, increasing);
    /// tau_max caps each particle's optical depth by widening its disk (inf: no cap); size classes with
    /// at least continuous_count particles per query cylinder are sampled as a continuous medium;
    /// storage "compact" (per-class optics, quantised radii) or "full" (`motes_core::render::storage`).
    #[new]
    #[pyo3(signature = (positions, radius, q_ext, bin, albedo, theta, f, offsets, lambda, query_radius, tau_max, cells_per_particle, continuous_count, seed, storage="full", radius_scale=1.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        positions: F64In,
        radius: F64In,
        q_ext: F64In,
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
        storage: &str,
        radius_scale: f64,
    ) -> PyResult<Self> {
        let storage = motes_core::render::storage::Storage::parse(storage).map_err(to_py)?;
        let lam = lambda.as_slice()?.to_vec();
        let bins = bin_optics(&albedo, &theta, &f, &offsets, lam.len())?;
        // Borrowed, not copied (10^8 particles: 4 GB): the build holds the GIL instead of releasing it,
        // so no Python thread can change the arrays under it (its rayon workers need no GIL).
        let (pos, r, q, b) = (
            points_view(positions.as_slice()?)?,
            radius.as_slice()?,
            q_ext.as_slice()?,
            bin.as_slice()?,
        );
        if q.len() != bins.len() {
            return Err(invalid(
                "q_ext",
                q.len(),
                format!("one per bin ({})", bins.len()),
            ));
        }
        // The core checks the lengths and each bin index before it forms any cross section.
        let _ = py;
        // Radii in scene units are r × radius_scale (the core checks the scale).
        let c_ext = |i: usize| {
            let r = r[i] * radius_scale;
            std::f64::consts::PI * r * r * q[b[i] as usize]
        };
        let settings = MediumSettings {
            query_radius,
            tau_max,
            cells_per_particle,
            continuous_count,
            seed,
            storage,
            ..MediumSettings::default()
        };
        let medium = motes_core::render::discrete::DiscreteMedium::build(
            pos,
            r,
            radius_scale,
            &c_ext,
            b,
            bins,
            lam,
            &settings,
        )
        .map_err(to_py)?;
        Ok(Self::wrap(medium))
    }

    /// A procedural cloud (`motes_core::render::procedural`): `count` expected particles in the box
    /// [lo, hi] after the density `kind`/`params` (as `generate_cloud`), species `psds` by `shares`,
    /// mapped by `transform` (3×4); radii in scene units are µm × `scene_per_um`; per species its optics
    /// bins' edges (µm) and first global bin; `q_ext` per global bin and the bins' tables as for `new`;
    /// `cache_bytes` bounds the bricks kept; grains drift by `turbulence` (scale `turbulence_scale`, both
    /// scene units) to `time` seconds (`motes_core::space::motion`; a velocity is in `transform`).
    #[staticmethod]
    #[pyo3(signature = (count, lo, hi, kind, params, noise_seed, psds, shares, cloud_seed, transform, scene_per_um, bin_edges_um, first_bin, q_ext, albedo, theta, f, offsets, lambda, query_radius, tau_max, cells_per_particle, continuous_count, seed, cache_bytes, turbulence=0.0, turbulence_scale=1.0, time=0.0))]
    #[allow(clippy::too_many_arguments)]
    fn procedural(
        py: Python<'_>,
        count: f64,
        lo: [f64; 3],
        hi: [f64; 3],
        kind: &str,
        params: Vec<f64>,
        noise_seed: u64,
        psds: Vec<PyRef<'_, crate::psd::PyPsd>>,
        shares: Vec<f64>,
        cloud_seed: u64,
        transform: [[f64; 4]; 3],
        scene_per_um: f64,
        bin_edges_um: Vec<Vec<f64>>,
        first_bin: Vec<u32>,
        q_ext: Vec<f64>,
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
        cache_bytes: usize,
        turbulence: f64,
        turbulence_scale: f64,
        time: f64,
    ) -> PyResult<Self> {
        let lam = lambda.as_slice()?.to_vec();
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
        let bins = bin_optics(&albedo, &theta, &f, &offsets, lam.len())?;
        let spec = motes_core::render::procedural::ProceduralSpec {
            cloud: crate::cloud::cloud_spec(
                lo, hi, kind, &params, noise_seed, &psds, shares, cloud_seed,
            )?,
            count,
            transform,
            scene_per_um,
            bin_edges_um,
            first_bin,
            q_ext,
            motion,
        };
        let settings = MediumSettings {
            query_radius,
            tau_max,
            cells_per_particle,
            continuous_count,
            seed,
            cache_bytes,
            ..MediumSettings::default()
        };
        let medium = py
            .detach(|| {
                motes_core::render::discrete::DiscreteMedium::procedural(
                    &spec, bins, lam, &settings,
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
            u1.as_slice()?,
            u2.as_slice()?,
        );
        if a.len() != pp.len()
            || s1.len() != pp.len()
            || s2.len() != 2 * pp.len()
            || !per_lane(&lam, channels, pp.len())
        {
            return Err(PyValueError::new_err(
                "p, wi, u1, u2 and lambda must describe the same lanes",
            ));
        }
        let lanes: Vec<PhaseSampleLane> = pp
            .into_iter()
            .zip(a.into_iter().zip(s1.iter().copied().zip(pairs(s2))))
            .map(|(p, (wi, (u1, u2)))| PhaseSampleLane { p, wi, u1, u2 })
            .collect();
        let out = py.detach(|| self.medium.phase_sample(&lanes, &lam, channels));
        Ok(sampled(py, out))
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
        if a.len() != pp.len() || b.len() != pp.len() || !per_lane(&lam, channels, pp.len()) {
            return Err(PyValueError::new_err(
                "p, wi, wo and lambda must describe the same lanes",
            ));
        }
        let lanes: Vec<PhaseEvalLane> = pp
            .into_iter()
            .zip(a.into_iter().zip(b))
            .map(|(p, (wi, wo))| PhaseEvalLane { p, wi, wo })
            .collect();
        let (v, pdf) = py.detach(|| self.medium.phase_eval(&lanes, &lam, channels));
        Ok((v.into_pyarray(py), pdf.into_pyarray(py)))
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
        let pts = triples(points.as_slice()?);
        let (mu, lam) = (mu.as_slice()?.to_vec(), lambda.as_slice()?.to_vec());
        if mu.len() != pts.len()
            || points.len()? != 3 * pts.len()
            || channels == 0
            || !per_lane(&lam, channels, pts.len())
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
        let (pts, dirs) = (triples(points.as_slice()?), triples(w_in.as_slice()?));
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
            || !per_lane(&lam, channels, n)
        {
            return Err(PyValueError::new_err(
                "points, w_in, u1, u2 and lambda must describe the same points",
            ));
        }
        let s2 = pairs(s2);
        let out = py.detach(|| {
            self.medium
                .sample_local(&pts, &dirs, &lam, channels, &s1, &s2)
        });
        Ok(sampled(py, out))
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

    /// The cameras whose pixel footprints rays from surfaces carry, as (position, pixel angle in
    /// radians, aperture radius) tuples (`rust/motes-core/src/render/footprint.rs`).
    #[getter]
    fn cameras(&self) -> Vec<CameraTuple> {
        let t = |p: [f64; 3]| (p[0], p[1], p[2]);
        let view = self.medium.view();
        view.cameras
            .iter()
            .map(|c| (t(c.position), c.pixel_angle, c.aperture))
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

    /// Set the cameras (a list of (position, pixel angle, aperture) tuples; empty: rays from surfaces
    /// walk the grains) and the lights at finite distance (a list of (centre, radius, disc radius,
    /// disc normal, spot axis, spot cos_cutoff) tuples: a sphere that shadow rays aim into, a disc on
    /// the light (radius 0 where none is known) and a spot's cone (axis 0 and -1 for none); None:
    /// unknown, every ray's end taken for a light), and whether every surface of
    /// the scene reflects and transmits only diffusely (rays bounced off them are blurred by the
    /// lobe). The renderer calls it with its scene's sensors, emitters and shapes.
    #[pyo3(signature = (cameras, lights = None, diffuse_surfaces = false))]
    fn set_cameras(
        &self,
        cameras: Vec<CameraTuple>,
        lights: Option<Vec<LightTuple>>,
        diffuse_surfaces: bool,
    ) -> PyResult<()> {
        let cameras = cameras
            .into_iter()
            .map(|(p, angle, aperture)| Camera::new([p.0, p.1, p.2], angle, aperture))
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

    /// Remember an event of the given particles at `p` (tests and tools). Particles are named as the
    /// medium names them: by index (full storage) or by position in its grid (compact storage).
    fn insert_event(&self, p: (f32, f32, f32), particles: Vec<u32>) -> PyResult<()> {
        self.medium
            .insert_event([p.0, p.1, p.2], &particles)
            .map_err(to_py)
    }

    /// Grey optical depth of segments [t0, t1) (f64 rays), as used by the free flights.
    fn optical_depth<'py>(&self, py: Python<'py>, segments: SegmentsIn) -> PyResult<F64Out<'py>> {
        let segs = segments.get()?;
        let out = per_segment(py, &segs, |_, ray| self.medium.optical_depth(ray));
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

/// Whether wavelengths `lam` are `channels` values shared by all `n` lanes or `channels` per lane.
fn per_lane(lam: &[f64], channels: usize, n: usize) -> bool {
    lam.len() == channels || lam.len() == channels * n
}

/// The second sample dimension (flat n*2) as pairs.
fn pairs(flat: &[f64]) -> Vec<[f64; 2]> {
    flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect()
}

/// Sampled directions as numpy arrays: (wo n*3, weight n*channels, pdf n).
fn sampled(
    py: Python<'_>,
    (wo, w, pdf): (Vec<[f64; 3]>, Vec<f64>, Vec<f64>),
) -> (F64Out<'_>, F64Out<'_>, F64Out<'_>) {
    let wo: Vec<f64> = wo.into_iter().flatten().collect();
    (
        wo.into_pyarray(py),
        w.into_pyarray(py),
        pdf.into_pyarray(py),
    )
}

/// Each bin's albedo and phase table per wavelength, from flat arrays: albedo (bins*K), phase tables
/// as theta/f with offsets (bins*K + 1) ending at len(theta).
fn bin_optics(
    albedo: &F64In,
    theta: &F64In,
    f: &F64In,
    offsets: &PyReadonlyArray1<'_, u64>,
    k: usize,
) -> PyResult<Vec<motes_core::render::discrete::BinOptics>> {
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
            Ok(motes_core::render::discrete::BinOptics {
                albedo: al[bi * k..(bi + 1) * k].to_vec(),
                phase: (bi * k..(bi + 1) * k).map(table).collect::<PyResult<_>>()?,
            })
        })
        .collect()
}

/// The checks of a particle set (positions n*3 and radii in scene units) and the medium's settings
/// that need no optics tables (`motes_core::render::discrete::check_particles_and_settings`): the
/// Python layer calls this before it builds the tables, so a bad value fails at once, with the core's
/// own rule and message.
#[pyfunction]
pub(crate) fn check_discrete_inputs(
    positions: F64In,
    radius: F64In,
    query_radius: f64,
    tau_max: f64,
    cells_per_particle: f64,
    continuous_count: f64,
) -> PyResult<()> {
    let settings = MediumSettings {
        query_radius,
        tau_max,
        cells_per_particle,
        continuous_count,
        ..MediumSettings::default()
    };
    motes_core::render::discrete::check_particles_and_settings(
        points_view(positions.as_slice()?)?,
        radius.as_slice()?,
        &settings,
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

/// The owner given with a native handle that is still held by a native plugin, or None (an unknown or
/// released handle: nothing is dereferenced then).
#[pyfunction]
pub fn native_owner(py: Python<'_>, handle: usize) -> Option<Py<PyAny>> {
    native::owner(py, handle)
}
