//! Generated particle clouds (`motes_core::space::cloud`) and the value noise behind `motes.Noise`.

use crate::convert::*;
use crate::psd::PyPsd;
use motes_core::space::cloud::{generate, CloudSpec, Density, DensityGrid, ValueNoise};
use motes_core::space::motion::Motion;
use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;
use std::sync::Arc;

/// The density named `kind` ("uniform", "gradient" with `params` = [axis, start, end], "noise" with
/// `params` = [scale, octaves, contrast] and `noise_seed`, "grid" with `params` = [nx, ny, nz, then
/// the nx·ny·nz values, x fastest]).
pub(crate) fn density(kind: &str, params: &[f64], noise_seed: u64) -> PyResult<Density> {
    let want = |n: usize| -> PyResult<()> {
        if params.len() == n {
            Ok(())
        } else {
            Err(invalid(
                "params",
                params.len(),
                format!(
                    "density {kind:?} takes {n} parameters, got {}",
                    params.len()
                ),
            ))
        }
    };
    match kind {
        "uniform" => want(0).map(|_| Density::Uniform),
        "gradient" => {
            want(3)?;
            Density::gradient(params[0] as usize, params[1], params[2]).map_err(to_py)
        }
        "noise" => {
            want(3)?;
            ValueNoise::new(params[0], params[1] as u32, noise_seed, params[2])
                .map(Density::Noise)
                .map_err(to_py)
        }
        "grid" if params.len() >= 3 => {
            let dims = [0, 1, 2].map(|a| params[a]);
            if !dims
                .iter()
                .all(|&d| d >= 1.0 && d.fract() == 0.0 && d < 1e9)
            {
                return Err(invalid(
                    "params",
                    format!("{dims:?}"),
                    "a grid density's first three parameters are its dimensions (integers >= 1)"
                        .to_string(),
                ));
            }
            let values = params[3..].iter().map(|&v| v as f32).collect();
            DensityGrid::new(dims.map(|d| d as usize), values)
                .map(|g| Density::Grid(Arc::new(g)))
                .map_err(to_py)
        }
        _ => Err(invalid(
            "density",
            kind,
            format!(
                "unknown density {kind:?}: uniform, gradient, noise or grid [nx, ny, nz, values]"
            ),
        )),
    }
}

/// A cloud's spec from the binding's arguments (as `generate_cloud` and the procedural medium take them):
/// one share per size distribution, the density by name.
#[allow(clippy::too_many_arguments)]
pub(crate) fn cloud_spec(
    lo: [f64; 3],
    hi: [f64; 3],
    kind: &str,
    params: &[f64],
    noise_seed: u64,
    psds: &[PyRef<'_, PyPsd>],
    shares: Vec<f64>,
    seed: u64,
) -> PyResult<CloudSpec> {
    if psds.len() != shares.len() {
        return Err(invalid(
            "shares",
            shares.len(),
            format!("one share per size distribution ({})", psds.len()),
        ));
    }
    Ok(CloudSpec {
        lo,
        hi,
        density: density(kind, params, noise_seed)?,
        species: shares
            .into_iter()
            .zip(psds.iter().map(|p| p.inner().clone()))
            .collect(),
        seed,
    })
}

/// Exactly `count` particles in the box [lo, hi] after a density, species by `shares` with radii from
/// `psds`, centres mapped by `transform` (3×4, row-major), reproducible from `seed` whatever the
/// number of threads: (centres (count*3), radii (um), species index).
#[pyfunction]
#[pyo3(signature = (count, lo, hi, kind, params, noise_seed, psds, shares, seed, transform))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub(crate) fn generate_cloud<'py>(
    py: Python<'py>,
    count: u64,
    lo: [f64; 3],
    hi: [f64; 3],
    kind: &str,
    params: Vec<f64>,
    noise_seed: u64,
    psds: Vec<PyRef<'py, PyPsd>>,
    shares: Vec<f64>,
    seed: u64,
    transform: [[f64; 4]; 3],
) -> PyResult<(F64Out<'py>, F64Out<'py>, Bound<'py, PyArray1<u32>>)> {
    let spec = cloud_spec(lo, hi, kind, &params, noise_seed, &psds, shares, seed)?;
    let cloud = py
        .detach(|| generate(&spec, count, &transform))
        .map_err(to_py)?;
    let centres: Vec<f64> = flatten(cloud.centres);
    Ok((
        centres.into_pyarray(py),
        cloud.radius_um.into_pyarray(py),
        cloud.species.into_pyarray(py),
    ))
}

/// The density named `kind` (`params`, `noise_seed` as `generate_cloud`) at `points` (n*3, in the
/// cloud's coordinates), over the box [lo, hi]: relative values, as the generator draws by them (a
/// grid's trilinear interpolation between cell centres, clamped at the faces, as Mitsuba's
/// `gridvolume`).
#[pyfunction]
#[pyo3(signature = (kind, params, noise_seed, points, lo, hi))]
pub(crate) fn density_at<'py>(
    py: Python<'py>,
    kind: &str,
    params: Vec<f64>,
    noise_seed: u64,
    points: F64In<'py>,
    lo: [f64; 3],
    hi: [f64; 3],
) -> PyResult<F64Out<'py>> {
    let d = density(kind, &params, noise_seed)?;
    let pts = points_view(points.as_slice()?)?;
    let out: Vec<f64> = pts.iter().map(|&q| d.at(q, lo, hi)).collect();
    Ok(out.into_pyarray(py))
}

/// A `Vec<[f64; 3]>` as the flat `Vec<f64>` of its coordinates, without a copy.
fn flatten(v: Vec<[f64; 3]>) -> Vec<f64> {
    let mut v = std::mem::ManuallyDrop::new(v);
    let (ptr, len, cap) = (v.as_mut_ptr(), v.len(), v.capacity());
    // SAFETY: [f64; 3] is three f64 with f64's alignment and no padding; the allocation is handed
    // over whole (its capacity in f64), so it is freed with the layout it was allocated with.
    unsafe { Vec::from_raw_parts(ptr as *mut f64, len * 3, cap * 3) }
}

/// The value noise v(x) ∈ [0, 1] of `motes.Noise` at points (n*3).
#[pyfunction]
pub(crate) fn value_noise<'py>(
    py: Python<'py>,
    points: F64In<'py>,
    scale: f64,
    octaves: u32,
    seed: u64,
    contrast: f64,
) -> PyResult<F64Out<'py>> {
    let noise = ValueNoise::new(scale, octaves, seed, contrast).map_err(to_py)?;
    let p = triples(points.as_slice()?);
    let out: Vec<f64> = py.detach(|| {
        use rayon::prelude::*;
        p.par_iter().map(|&x| noise.value(x)).collect()
    });
    Ok(out.into_pyarray(py))
}

/// Rest positions (n*3, scene units) moved to time `time` (seconds) by a uniform `velocity` plus a
/// divergence-free turbulent drift of amplitude `turbulence` and scale `turbulence_scale` seeded by
/// `seed` (`motes_core::space::motion`), wrapped around the box [-1, 1]³ that `wrap_to_world` (3×4)
/// maps into the scene when given; a new array.
#[pyfunction]
#[pyo3(signature = (centres, velocity, turbulence, turbulence_scale, seed, time, wrap_to_world=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn move_grains<'py>(
    py: Python<'py>,
    centres: F64In<'py>,
    velocity: [f64; 3],
    turbulence: f64,
    turbulence_scale: f64,
    seed: u64,
    time: f64,
    wrap_to_world: Option<[[f64; 4]; 3]>,
) -> PyResult<F64Out<'py>> {
    let mut motion = Motion::new(velocity, turbulence, turbulence_scale, seed).map_err(to_py)?;
    if let Some(m) = wrap_to_world {
        motion = motion.wrapped(m).map_err(to_py)?;
    }
    let mut p = triples(centres.as_slice()?);
    py.detach(|| motion.apply(&mut p, time)).map_err(to_py)?;
    Ok(flatten(p).into_pyarray(py))
}
