//! Tabulated complex refractive indices of particle materials over the visible (0.35–0.85 µm).
//!
//! * Water ice at −7 °C: S. G. Warren and R. E. Brandt, "Optical constants of ice from the ultraviolet
//!   to the microwave: A revised compilation", J. Geophys. Res. 113, D14220 (2008),
//!   doi:10.1029/2007JD009744.
//! * Liquid water at 25 °C: G. M. Hale and M. R. Querry, "Optical constants of water in the 200-nm to
//!   200-µm wavelength region", Appl. Opt. 12, 555–563 (1973), doi:10.1364/AO.12.000555.
//!
//! Values as distributed (public domain, CC0) by the refractiveindex.info database
//! (`database/data-nk/main/H2O/Warren-2008.yml`, `Hale.yml`). Between samples `n` is interpolated
//! linearly and `κ` log-linearly in λ (κ spans orders of magnitude).
//!
//! Paper: the relative index m = n + iκ that Eq. 26–30 (Mie) and Eq. 7–14 (GOA) take as input.

use crate::error::{require, OpticsError};
use num_complex::Complex64 as C64;

/// (λ µm, n, κ) — Warren & Brandt (2008), ice at −7 °C.
const ICE_WARREN_BRANDT_2008: &[(f64, f64, f64)] = &[
    (0.350, 1.3249, 2.0e-11),
    (0.390, 1.3203, 2.0e-11),
    (0.400, 1.3194, 2.365e-11),
    (0.410, 1.3185, 2.669e-11),
    (0.420, 1.3177, 3.135e-11),
    (0.430, 1.3170, 4.140e-11),
    (0.440, 1.3163, 6.268e-11),
    (0.450, 1.3157, 9.239e-11),
    (0.460, 1.3151, 1.325e-10),
    (0.470, 1.3145, 1.956e-10),
    (0.480, 1.3140, 2.861e-10),
    (0.490, 1.3135, 4.172e-10),
    (0.500, 1.3130, 5.889e-10),
    (0.510, 1.3126, 8.036e-10),
    (0.520, 1.3121, 1.076e-9),
    (0.530, 1.3117, 1.409e-9),
    (0.540, 1.3114, 1.813e-9),
    (0.550, 1.3110, 2.289e-9),
    (0.560, 1.3106, 2.839e-9),
    (0.570, 1.3103, 3.461e-9),
    (0.580, 1.3100, 4.159e-9),
    (0.590, 1.3097, 4.930e-9),
    (0.600, 1.3094, 5.730e-9),
    (0.610, 1.3091, 6.890e-9),
    (0.620, 1.3088, 8.580e-9),
    (0.630, 1.3085, 1.040e-8),
    (0.640, 1.3083, 1.220e-8),
    (0.650, 1.3080, 1.430e-8),
    (0.660, 1.3078, 1.660e-8),
    (0.670, 1.3076, 1.890e-8),
    (0.680, 1.3073, 2.090e-8),
    (0.690, 1.3071, 2.400e-8),
    (0.700, 1.3069, 2.900e-8),
    (0.710, 1.3067, 3.440e-8),
    (0.720, 1.3065, 4.030e-8),
    (0.730, 1.3062, 4.300e-8),
    (0.740, 1.3060, 4.920e-8),
    (0.750, 1.3059, 5.870e-8),
    (0.760, 1.3057, 7.080e-8),
    (0.770, 1.3055, 8.580e-8),
    (0.780, 1.3053, 1.020e-7),
    (0.790, 1.3051, 1.180e-7),
    (0.800, 1.3049, 1.340e-7),
    (0.810, 1.3047, 1.400e-7),
    (0.820, 1.3046, 1.430e-7),
    (0.830, 1.3044, 1.450e-7),
    (0.840, 1.3042, 1.510e-7),
    (0.850, 1.3040, 1.830e-7),
];

/// (λ µm, n, κ) — Hale & Querry (1973), liquid water at 25 °C.
const WATER_HALE_QUERRY_1973: &[(f64, f64, f64)] = &[
    (0.350, 1.343, 6.50e-9),
    (0.375, 1.341, 3.50e-9),
    (0.400, 1.339, 1.86e-9),
    (0.425, 1.338, 1.30e-9),
    (0.450, 1.337, 1.02e-9),
    (0.475, 1.336, 9.35e-10),
    (0.500, 1.335, 1.00e-9),
    (0.525, 1.334, 1.32e-9),
    (0.550, 1.333, 1.96e-9),
    (0.575, 1.333, 3.60e-9),
    (0.600, 1.332, 1.09e-8),
    (0.625, 1.332, 1.39e-8),
    (0.650, 1.331, 1.64e-8),
    (0.675, 1.331, 2.23e-8),
    (0.700, 1.331, 3.35e-8),
    (0.725, 1.330, 9.15e-8),
    (0.750, 1.330, 1.56e-7),
    (0.775, 1.330, 1.48e-7),
    (0.800, 1.329, 1.25e-7),
    (0.825, 1.329, 1.82e-7),
    (0.850, 1.329, 2.93e-7),
];

/// A tabulated material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Material {
    Ice,
    Water,
}

impl Material {
    pub fn parse(name: &str) -> Result<Self, OpticsError> {
        match name {
            "ice" => Ok(Material::Ice),
            "water" => Ok(Material::Water),
            other => Err(OpticsError::InvalidOption {
                argument: "material",
                value: other.to_string(),
                allowed: "\"ice\", \"water\"",
            }),
        }
    }

    fn table(self) -> &'static [(f64, f64, f64)] {
        match self {
            Material::Ice => ICE_WARREN_BRANDT_2008,
            Material::Water => WATER_HALE_QUERRY_1973,
        }
    }

    /// Wavelength range covered, µm.
    pub fn range(self) -> (f64, f64) {
        let t = self.table();
        (t[0].0, t[t.len() - 1].0)
    }

    /// Complex index n + iκ at λ (µm), inside the tabulated range.
    pub fn index(self, wavelength_um: f64) -> Result<C64, OpticsError> {
        let t = self.table();
        let (lo, hi) = self.range();
        require(
            "wavelength_um",
            wavelength_um,
            wavelength_um.is_finite() && (lo..=hi).contains(&wavelength_um),
            "inside the tabulated range 0.35–0.85 µm",
        )?;
        let i = t
            .partition_point(|r| r.0 <= wavelength_um)
            .clamp(1, t.len() - 1);
        let (a, b) = (t[i - 1], t[i]);
        let w = (wavelength_um - a.0) / (b.0 - a.0);
        let n = a.1 + w * (b.1 - a.1);
        let k = (a.2.ln() + w * (b.2.ln() - a.2.ln())).exp();
        Ok(C64::new(n, k))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tabulated samples are reproduced exactly; interpolation stays between neighbours.
    #[test]
    fn samples_and_interpolation() {
        let ice = Material::Ice.index(0.55).unwrap();
        assert_eq!(ice.re, 1.3110);
        assert!((ice.im / 2.289e-9 - 1.0).abs() < 1e-12);
        let w = Material::Water.index(0.5125).unwrap();
        assert!(w.re < 1.335 && w.re > 1.334 && w.im > 1.0e-9 && w.im < 1.32e-9);
        assert!(Material::Ice.index(0.30).is_err() && Material::parse("glass").is_err());
    }
}
