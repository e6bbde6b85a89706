//! Polydisperse ensembles: many particles of many sizes and species seen as one bulk medium.
//!
//! * [`psd`]: particle size distributions (Sec. 4.1, Eq. 15) and their quadratures.
//! * [`properties`] (re-exported here): bulk σ_t, σ_s, σ_a and the ensemble phase function (Sec. 4.2,
//!   Eq. 16–17), spectral and RGB, with forward-peak truncation.
//! * [`phase_table`]: a tabulated phase function with consistent evaluation, pdf and sampling.
//! * [`wavelengths`]: the default RGB and spectral wavelength sets.
//!
//! The Gauss–Legendre nodes of the integrals over radius are [`crate::quadrature`]'s (shared with the
//! single-particle optics, which come before ensembles).

pub mod phase_table;
pub mod properties;
pub mod psd;
pub mod wavelengths;

pub use properties::*;
