//! motes-core: the physics of discrete participating media, free of Python and Mitsuba.
//!
//! * [`mie`]: Lorenz–Mie theory (paper App. A).
//! * [`goa`]: the geometrical optics approximation (Sec. 3.1, App. B–C) with documented
//!   regularisations of its singular points.
//! * [`optics`]: one particle as the renderer sees it — cross sections, normalised phase function,
//!   and the choice between Mie and GOA (`Method`), batched over many particles and angles.
//! * [`grid`]: particles in space, optical depth along query cylinders and exact free flights.
//! * [`dda`]: boxes and the 3D-DDA walk of a ray through a uniform grid.
//! * [`continuous`]: size classes no pixel resolves, sampled as a continuous medium (issue 10.3).
//! * [`discrete`]: the discrete medium as a renderer queries it (sites, albedo, phase function).
//! * [`wavelengths`]: the default RGB and spectral wavelength sets.
//! * [`cancel`]: cooperative cancellation of long table builds (Ctrl-C from the binding).

pub mod cancel;
pub mod continuous;
pub mod dda;
pub mod discrete;
pub mod ensemble;
pub mod error;
pub mod goa;
pub mod grid;
pub mod materials;
pub mod mie;
pub mod optics;
pub mod phase_table;
pub mod psd;
pub mod quadrature;
pub mod wavelengths;

/// The tests' random numbers: one 64-bit LCG (Knuth's MMIX constants), uniform in [0, 1) from its top
/// 53 bits, so that every test's particles and rays are reproducible and share one generator.
#[cfg(test)]
pub(crate) mod test_rng {
    pub fn lcg(s: &mut u64) -> f64 {
        *s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*s >> 11) as f64) / (1u64 << 53) as f64
    }
}

pub use error::OpticsError;
pub use optics::{Method, Particle};
pub use psd::Psd;
