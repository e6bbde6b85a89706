//! `motes._motes`: the compiled extension. Every function takes flat, equally long float64 arrays
//! (broadcasting happens in the Python layer), releases the GIL, and runs rayon inside. One module per
//! topic: [`optics`], [`psd`], [`ensemble`], [`grid`], [`inside`], [`medium`]; [`convert`] holds the boundary's
//! conversions and the error type, [`interrupt`] Ctrl-C, [`native`] the native render path's C ABI.

mod cloud;
mod convert;
mod ensemble;
mod grid;
mod inside;
mod interrupt;
mod medium;
mod native;
mod optics;
mod psd;

use pyo3::prelude::*;

/// FNV-1a 64 hash (hex) of the Rust sources this extension was built from (`build.rs`): it changes with
/// the physics, so caches of computed tables key on it.
#[pyfunction]
fn core_hash() -> &'static str {
    env!("MOTES_CORE_HASH")
}

/// The particle walk this CPU runs: "avx2" (AVX2 + FMA, eight spheres per pre-test) or "sse"
/// (baseline, also where `MOTES_SIMD=sse` asks for it); `motes_core::simd::wide_simd`.
#[pyfunction]
fn simd_walk() -> &'static str {
    if motes_core::simd::wide_simd() {
        "avx2"
    } else {
        "sse"
    }
}

/// The default wavelength sets (µm): (RGB, spectral), `motes_core::ensemble::wavelengths`.
#[pyfunction]
fn default_wavelengths() -> (Vec<f64>, Vec<f64>) {
    (
        motes_core::ensemble::wavelengths::RGB_WAVELENGTHS_UM.to_vec(),
        motes_core::ensemble::wavelengths::spectral_wavelengths_um().to_vec(),
    )
}

#[pymodule]
fn _motes(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(optics::mie_amplitudes, m)?)?;
    m.add_function(wrap_pyfunction!(optics::goa_amplitudes, m)?)?;
    m.add_function(wrap_pyfunction!(optics::clear_goa_cache, m)?)?;
    m.add_function(wrap_pyfunction!(optics::goa_cache_info, m)?)?;
    m.add_function(wrap_pyfunction!(optics::cross_sections, m)?)?;
    m.add_function(wrap_pyfunction!(optics::phase_function, m)?)?;
    m.add_function(wrap_pyfunction!(optics::mueller_matrix, m)?)?;
    m.add_function(wrap_pyfunction!(optics::goa_extinction_efficiency, m)?)?;
    m.add_function(wrap_pyfunction!(optics::policy_constants, m)?)?;
    m.add_function(wrap_pyfunction!(optics::resolve_method, m)?)?;
    m.add_function(wrap_pyfunction!(ensemble::bulk_properties, m)?)?;
    m.add_function(wrap_pyfunction!(ensemble::henyey_greenstein, m)?)?;
    m.add_function(wrap_pyfunction!(optics::material_index, m)?)?;
    m.add_function(wrap_pyfunction!(core_hash, m)?)?;
    m.add_function(wrap_pyfunction!(default_wavelengths, m)?)?;
    m.add_function(wrap_pyfunction!(simd_walk, m)?)?;
    m.add_function(wrap_pyfunction!(cloud::generate_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(cloud::density_at, m)?)?;
    m.add_function(wrap_pyfunction!(cloud::value_noise, m)?)?;
    m.add_function(wrap_pyfunction!(cloud::move_grains, m)?)?;
    m.add_function(wrap_pyfunction!(interrupt::exit_on_wakeup, m)?)?;
    m.add_function(wrap_pyfunction!(interrupt::set_exit_message, m)?)?;
    m.add_function(wrap_pyfunction!(medium::check_discrete_inputs, m)?)?;
    m.add_function(wrap_pyfunction!(medium::bounding_box, m)?)?;
    m.add_function(wrap_pyfunction!(medium::size_bins, m)?)?;
    m.add_function(wrap_pyfunction!(medium::native_owner, m)?)?;
    m.add_function(wrap_pyfunction!(medium::native_pending_handle, m)?)?;
    m.add_function(wrap_pyfunction!(inside::mesh_open_edges, m)?)?;
    m.add("MotesError", m.py().get_type::<convert::MotesError>())?;
    m.add_class::<psd::PyPsd>()?;
    m.add_class::<ensemble::PyPhaseTable>()?;
    m.add_class::<ensemble::PyGoaCache>()?;
    m.add_class::<grid::PyParticleGrid>()?;
    m.add_class::<medium::PyDiscreteMedium>()?;
    m.add_class::<inside::PyHolders>()?;
    m.add_class::<medium::settings::PyMediumSettings>()?;
    m.add_class::<medium::settings::PyBinTables>()?;
    m.add(
        "DEFAULT_TAU_MAX",
        motes_core::render::discrete::DEFAULT_TAU_MAX,
    )?;
    m.add(
        "DEFAULT_CELLS_PER_PARTICLE",
        motes_core::space::grid::DEFAULT_CELLS_PER_PARTICLE,
    )?;
    m.add(
        "DEFAULT_CONTINUOUS_COUNT",
        motes_core::render::continuous::DEFAULT_CONTINUOUS_COUNT,
    )?;
    m.add(
        "DEFAULT_CACHE_BYTES",
        motes_core::render::procedural::DEFAULT_CACHE_BYTES,
    )?;
    m.add(
        "DEFAULT_GRAIN_DEPTH",
        motes_core::render::discrete::DEFAULT_GRAIN_DEPTH,
    )?;
    // The native render path's C interface (rust/motes-py/src/native/mod.rs): its address and version.
    m.add(
        "NATIVE_API",
        &native::API as *const native::NativeApi as usize,
    )?;
    m.add("NATIVE_ABI", native::NATIVE_ABI)?;

    Ok(())
}
