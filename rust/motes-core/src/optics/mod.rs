//! Single-particle optics: how one sphere scatters and absorbs light.
//!
//! * [`mie`]: Lorenz–Mie theory (paper App. A, Eq. 26–30), exact at every size.
//! * [`goa`]: the geometrical optics approximation (Sec. 3.1, App. B–C: Eq. 4–14, 31–37), diffraction
//!   plus reflection/refraction orders, absorbing particles, with documented regularisations of its
//!   singular points.
//! * [`particle`] (re-exported here): one particle as a renderer needs it — cross sections (Eq. 2–3,
//!   12–13, 28–29), the normalised phase function (Eq. 1) and the choice between Mie and GOA
//!   ([`Method`], the hybrid), batched over many particles and angles.
//! * [`materials`]: tabulated complex refractive indices (ice, water).

pub mod goa;
pub mod materials;
pub mod mie;
pub mod particle;

pub use particle::*;
