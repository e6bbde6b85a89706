//! Particles in space: where the grains are and what a ray meets.
//!
//! * [`ray`]: the segment [t0, t1) of a ray that every query along a ray takes.
//! * [`cloud`]: generated particle clouds (a density, species, size distributions), tile by tile.
//! * [`dda`]: an axis-aligned box with one slab test and the 3D-DDA walk of a ray through a uniform
//!   grid (Amanatides & Woo).
//! * [`grid`]: a uniform grid over particle centres, one per size class; optical depth along a query
//!   cylinder (Eq. 18), the local density in a query sphere (Eq. 24), exact free flights (Sec. 5.2–5.3)
//!   and beams of rays that travel together.
//! * `ray_lanes` (crate-internal): a beam's rays tested against one particle side by side (AVX-512 where
//!   [`crate::simd`] allows).
//! * [`motion`]: moving generated grains: a uniform velocity plus a divergence-free turbulent drift.
//! * [`inside`]: the inside of the closed shapes that hold a medium (meshes by ray parity, analytic spheres
//!   and cylinders), its volume, and points spread uniformly over it.

pub mod cloud;
pub mod dda;
pub mod grid;
pub mod inside;
pub mod motion;
pub mod ray;
pub(crate) mod ray_lanes;
pub mod vec3;
