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

/// Each species' fraction of the particles from their `shares` (finite, >= 0, one > 0: checked by the
/// callers): the shares divided by the largest first, then by their sum. Shares are relative, so 1e308
/// and 1e308 are an even split, whose plain sum would overflow and give every species 0.
pub fn share_fractions(shares: &[f64]) -> Vec<f64> {
    let largest = shares.iter().copied().fold(0.0, f64::max);
    let scaled: Vec<f64> = shares.iter().map(|s| s / largest).collect();
    let total: f64 = scaled.iter().sum();
    scaled.iter().map(|s| s / total).collect()
}

#[cfg(test)]
mod tests {
    /// Shares are relative: any scale gives the same fractions, the largest ones without overflow.
    #[test]
    fn share_fractions_are_relative_and_never_overflow() {
        assert_eq!(super::share_fractions(&[1e308, 1e308]), vec![0.5, 0.5]);
        assert_eq!(super::share_fractions(&[3.0, 1.0]), vec![0.75, 0.25]);
        assert_eq!(super::share_fractions(&[0.0, 5e-324]), vec![0.0, 1.0]);
        let f = super::share_fractions(&[f64::MAX, 0.0, f64::MAX / 3.0]);
        assert!((f[0] - 0.75).abs() < 1e-15 && f[1] == 0.0 && (f[2] - 0.25).abs() < 1e-15);
    }
}
