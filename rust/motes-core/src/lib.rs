//! motes-core: the physics of discrete participating media, free of Python and Mitsuba.
//!
//! Grouped as the paper builds the system (Guo et al.):
//! * [`optics`]: single-particle optics — Lorenz–Mie (App. A), GOA (Sec. 3.1, App. B–C) and the hybrid.
//! * [`ensemble`]: polydisperse ensembles — size distributions (Sec. 4.1) and bulk coefficients and
//!   phase functions (Sec. 4.2, Eq. 16–17).
//! * [`space`]: particles in space — a uniform grid, query cylinders (Eq. 18) and spheres (Eq. 24).
//! * [`render`]: the discrete medium as a renderer queries it (Sec. 5), and size classes no pixel
//!   resolves as a continuous medium.
//! * [`error`] (one error type naming the bad argument) and [`cancel`] (Ctrl-C for long table builds).

pub mod cancel;
pub mod ensemble;
pub mod error;
pub mod optics;
pub mod render;
pub mod space;

#[cfg(test)]
pub(crate) mod test_rng {
    pub fn lcg(s: &mut u64) -> f64 {
        *s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*s >> 11) as f64) / (1u64 << 53) as f64
    }
}

pub use ensemble::psd::Psd;
pub use error::OpticsError;
pub use optics::{Method, Particle};
