//! Rendering: the discrete medium as a renderer queries it (paper Sec. 5).
//!
//! * [`discrete`]: exact free flights to particle sites, the site's albedo and phase function, the
//!   per-particle optical depth (a documented deviation from Eq. 18) and the event memory that keeps a
//!   scattered ray from meeting its own particle again.
//! * [`storage`]: what each particle carries (disk, cross section, bin), per particle or per class.
//! * [`continuous`]: size classes whose grains no pixel resolves, sampled as a continuous medium and
//!   combined exactly with the discrete classes.
//! * [`footprint`]: when a ray from a surface may see the grains' continuous equivalent (its pixel
//!   footprint holds many grains; camera rays never do).
//! * [`procedural`]: clouds whose grains are never stored, generated brick by brick from a seed when a
//!   ray first reaches a brick.
//! * [`enclosure`]: the convex shapes that hold a medium, inside which next-event estimation towards a
//!   light blocked by a site needs no phase evaluation.
//! * `phase_lanes`: a packet's phase samples side by side (AVX-512), bit for bit the one-lane result.

pub mod continuous;
pub mod discrete;
pub mod enclosure;
pub mod footprint;
mod phase_lanes;
pub mod procedural;
pub mod storage;
