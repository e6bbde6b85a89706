//! The C ABI of the native render path: the C++ Mitsuba plugins (`mitsuba_plugin/motes/native/`) call
//! [`motes_packet`] once per SIMD packet from inside Mitsuba's symbolic LLVM kernels (through
//! `jit_llvm_ray_trace`, the hook Mitsuba's own CPU ray tracers use), and once per ray in the scalar
//! variants. They find it through [`NativeApi`], whose address Python hands them with a medium handle
//! (a [`NativeMedium`]: an `Arc` of the core medium and the Python object that owns it, which
//! [`NativeApi::release`] drops).
//!
//! A packet is Embree's ray/hit record in structure-of-arrays layout, `width` lanes per field, in the
//! field order of [`Field`]. What each operation reads and writes (lanes the renderer marks inactive in
//! `valid` are skipped; a lane counts as returned where `geom_id` is written):
//!
//! | op              | reads                                          | writes                                   |
//! |-----------------|------------------------------------------------|------------------------------------------|
//! | `FREE_FLIGHT`   | o, d, tfar = t_max; wavelengths (see below)    | tfar = t of the site (hit lanes only)    |
//! | `PHASE_SAMPLE`  | o = p, d = wi, tnear = u1, time, tfar = u2     | up to 3 channels: tfar, u = wo (octahedral), v, prim_id, geom_id = weights, inst_id = pdf; 4: tfar, u, v = wo, prim_id = pdf |
//! | `PHASE_EVAL`    | o = p, d = wi, tnear, time, tfar = wo          | values in tfar, u, v, prim_id; inst_id = pdf |
//! | `PHASE_MUELLER` | as `PHASE_EVAL`; flags = element e (0–3)       | one channel: F11, F12, F33, F34 in tfar, u, v, prim_id; more: element e of each channel there; inst_id = pdf |
//! | `PHASE_SAMPLE_DIRECTION` | as `PHASE_SAMPLE`                     | tfar, u, v = wo, prim_id = pdf (whatever the channels) |
//!
//! `PHASE_MUELLER` (polarised variants) evaluates a lane afresh for e = 0 and reads the same evaluation
//! again for e = 1–3 with the same inputs (`DiscreteMedium::packet_phase_mueller`); the elements are
//! those of Bohren & Huffman in the scattering plane's Stokes frames, which the C++ plugin rotates into
//! Mitsuba's. `PHASE_SAMPLE_DIRECTION` leaves the weights to an evaluation that follows (polarised
//! variants, whose weights are matrices).
//!
//! No operation places an event: a lane's site becomes its event where the lane's next call starts at
//! it, and the phase function's values and weights carry the site's albedo (`DiscreteMedium`'s
//! "One packet at a time"). Floats travel in u32 fields as their bits (a weight in geom_id is never
//! the miss marker 0xFFFFFFFF, a NaN). Wavelengths: `lambda` (`channels` values shared by all
//! lanes, RGB variants) or, when it is null, per lane in `mask` and `id` as two u16 each in units of
//! 1/50 nm (spectral variants: 4 channels; the quantisation, 0.01 nm, is far below the tables'
//! wavelength spacing).
//!
//! A sampled direction with up to three channels travels in two floats, the octahedral map of the unit
//! sphere (`motes_core::render::discrete::octahedral`, Cigolle et al. 2014): x, y of w / |w|_1, the
//! lower hemisphere folded over the diagonals; the C++ plugin unfolds and normalises it (float32 error
//! about 1e-7 rad).

use motes_core::render::discrete::{
    octahedral, DiscreteMedium, PacketRay, PhaseEvalLane, PhaseSampleLane, PACKET_LANES,
};
use pyo3::prelude::*;
use std::collections::BTreeSet;
use std::ffi::{c_char, c_void};
use std::sync::{Arc, Mutex, OnceLock};

mod packet;
pub use packet::motes_packet;

/// Version of this interface; the C++ plugin refuses another (2: `set_albedo_scale`; 3: no commit,
/// phase samples with their weights; 4: polarisation, `PHASE_MUELLER` and `PHASE_SAMPLE_DIRECTION`).
pub const NATIVE_ABI: u32 = 4;

pub const FREE_FLIGHT: u32 = 0;
// 1 was the commit of ABI 2.
pub const PHASE_SAMPLE: u32 = 2;
pub const PHASE_EVAL: u32 = 3;
pub const PHASE_MUELLER: u32 = 4;
pub const PHASE_SAMPLE_DIRECTION: u32 = 5;

/// Wavelength units per nm in the packed per-lane wavelengths.
const LAMBDA_UNITS_PER_NM: f64 = 50.0;

/// Fields of the ray/hit record (Embree's RTCRayHitN order, as drjit-core lays it out).
#[allow(dead_code)]
#[derive(Clone, Copy)]
enum Field {
    Ox,
    Oy,
    Oz,
    Tnear,
    Dx,
    Dy,
    Dz,
    Time,
    Tfar,
    Mask,
    Id,
    Flags,
    NgX,
    NgY,
    NgZ,
    U,
    V,
    PrimId,
    GeomId,
    InstId,
}

/// The packet entry point, [`motes_packet`]: (medium, op, width, valid, args, lambda, channels).
pub type PacketFn =
    unsafe extern "C" fn(*const c_void, u32, u32, *const i32, *mut u8, *const f64, u32);

/// What C++ receives: the interface version and three functions.
#[repr(C)]
pub struct NativeApi {
    pub abi: u32,
    pub packet: PacketFn,
    pub release: unsafe extern "C" fn(medium: *const c_void),
    /// The medium's `albedo_scale` (a scene parameter the C++ medium's `traverse` lists): 0 when set,
    /// else 1 with the reason, NUL-terminated and cut to `capacity` bytes, in `message`.
    pub set_albedo_scale: unsafe extern "C" fn(
        medium: *const c_void,
        scale: f64,
        message: *mut c_char,
        capacity: usize,
    ) -> i32,
}

pub static API: NativeApi = NativeApi {
    abi: NATIVE_ABI,
    packet: motes_packet,
    release: motes_release,
    set_albedo_scale: motes_set_albedo_scale,
};

/// What a handle points at: a strong reference to the core medium, and one to the Python object that
/// owns it (`motes.DiscreteMedium`), so that a scene whose medium is the native plugin itself (scalar
/// variants) can still report its data for as long as the plugin lives ([`owner`]). A pending handle
/// ([`pending_handle`]: a medium that fills the shapes holding it, known only once its scene has loaded)
/// has no core until [`fill`] sets it, once; until then every ray passes it (no site) and its owner is
/// the Python object that will fill it.
pub struct NativeMedium {
    core: OnceLock<Arc<DiscreteMedium>>,
    owner: Mutex<Option<Py<PyAny>>>,
}

/// Handles not yet released: [`owner`] dereferences only these (its argument comes from Python).
static LIVE: Mutex<BTreeSet<usize>> = Mutex::new(BTreeSet::new());

fn live() -> std::sync::MutexGuard<'static, BTreeSet<usize>> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// A new handle on `medium` for C++ (dropped by [`NativeApi::release`]).
pub fn handle(medium: &Arc<DiscreteMedium>, owner: Option<Py<PyAny>>) -> usize {
    let core = OnceLock::new();
    let _ = core.set(Arc::clone(medium));
    new_handle(core, owner)
}

/// A new handle without a core medium yet (see [`NativeMedium`]; [`fill`] sets it).
pub fn pending_handle(owner: Option<Py<PyAny>>) -> usize {
    new_handle(OnceLock::new(), owner)
}

fn new_handle(core: OnceLock<Arc<DiscreteMedium>>, owner: Option<Py<PyAny>>) -> usize {
    let h = Box::into_raw(Box::new(NativeMedium {
        core,
        owner: Mutex::new(owner),
    })) as usize;
    live().insert(h);
    h
}

/// Set the core medium of the pending handle `h` (once) and its new owner. Errors: an unknown or
/// released handle, or one that has its core already.
pub fn fill(
    h: usize,
    medium: &Arc<DiscreteMedium>,
    owner: Option<Py<PyAny>>,
) -> Result<(), &'static str> {
    let set = live();
    if !set.contains(&h) {
        return Err("not a live native medium handle");
    }
    // SAFETY: `h` is live (released handles leave the set before they are freed, under this lock).
    let m = unsafe { &*(h as *const NativeMedium) };
    m.core
        .set(Arc::clone(medium))
        .map_err(|_| "the native medium has its particles already")?;
    let old = std::mem::replace(
        &mut *m.owner.lock().unwrap_or_else(|e| e.into_inner()),
        owner,
    );
    drop(set);
    drop(old);
    Ok(())
}

/// The owner given to the live handle `h` (None for an unknown or released handle).
pub fn owner(py: Python<'_>, h: usize) -> Option<Py<PyAny>> {
    let set = live();
    if !set.contains(&h) {
        return None;
    }
    // SAFETY: `h` is live (released handles leave the set before they are freed, under this lock).
    let m = unsafe { &*(h as *const NativeMedium) };
    let owner = m.owner.lock().unwrap_or_else(|e| e.into_inner());
    owner.as_ref().map(|o| o.clone_ref(py))
}

/// The core medium behind a handle (None while it is pending).
///
/// # Safety
/// `medium` comes from [`handle`] or [`pending_handle`] and is alive.
unsafe fn core<'a>(medium: *const c_void) -> Option<&'a DiscreteMedium> {
    (*(medium as *const NativeMedium)).core.get().map(|a| &**a)
}

extern "C" {
    /// CPython's "does this thread hold the GIL" (in every CPython this module loads into, though not
    /// in the limited API that pyo3's abi3 bindings declare).
    fn PyGILState_Check() -> std::ffi::c_int;
}

/// # Safety
/// `medium` comes from [`handle`] and is released once.
pub unsafe extern "C" fn motes_release(medium: *const c_void) {
    if !medium.is_null() {
        live().remove(&(medium as usize));
        let m = Box::from_raw(medium as *mut NativeMedium);
        // The owner (the Python data, large) goes now where this thread holds the GIL (a scene
        // destroyed from Python, under nanobind's GIL, which pyo3 does not count as its own); elsewhere
        // pyo3 queues the decref for the next time it holds the GIL.
        if pyo3::ffi::Py_IsInitialized() != 0 && PyGILState_Check() == 1 {
            Python::attach(|_| drop(m));
        } else {
            drop(m);
        }
    }
}

/// # Safety
/// `medium` comes from [`handle`] and is alive; `message` holds `capacity` bytes (or is null).
pub unsafe extern "C" fn motes_set_albedo_scale(
    medium: *const c_void,
    scale: f64,
    message: *mut c_char,
    capacity: usize,
) -> i32 {
    let result = match core(medium) {
        Some(m) => m.set_albedo_scale(scale).map_err(|e| e.to_string()),
        None => Err("its particles are not made yet (they fill the shapes that hold it once its scene loads)".into()),
    };
    match result {
        Ok(()) => 0,
        Err(text) => {
            if !message.is_null() && capacity > 0 {
                let mut n = text.len().min(capacity - 1);
                while !text.is_char_boundary(n) {
                    n -= 1;
                }
                std::ptr::copy_nonoverlapping(text.as_ptr(), message.cast::<u8>(), n);
                *message.add(n) = 0;
            }
            1
        }
    }
}
