//! motes-core: the physics of discrete participating media, free of Python and Mitsuba.
//!
//! Grouped as the paper builds the system (Guo et al.):
//! * [`optics`]: single-particle optics — Lorenz–Mie (App. A), GOA (Sec. 3.1, App. B–C) and the hybrid.
//! * [`ensemble`]: polydisperse ensembles — size distributions (Sec. 4.1) and bulk coefficients and
//!   phase functions (Sec. 4.2, Eq. 16–17).
//! * [`space`]: particles in space — a uniform grid, query cylinders (Eq. 18) and spheres (Eq. 24).
//! * [`render`]: the discrete medium as a renderer queries it (Sec. 5), and size classes no pixel
//!   resolves as a continuous medium.
//! * [`error`] (one error type naming the bad argument), [`cancel`] (Ctrl-C for long table builds),
//!   [`rng`] (the SplitMix64 hash behind every random number the core draws), [`quadrature`]
//!   (Gauss–Legendre nodes for the optics' and the ensembles' integrals) and [`options`] (the
//!   environment switches for side-by-side comparisons).
//! * [`simd`]: which SIMD paths this CPU runs, decided once per process.

pub mod cancel;
pub mod ensemble;
pub mod error;
pub mod optics;
pub mod options;
pub mod quadrature;
pub mod render;
pub mod rng;
pub mod simd;
pub mod space;

#[cfg(test)]
pub(crate) mod test_rng {
    pub fn lcg(s: &mut u64) -> f64 {
        *s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*s >> 11) as f64) / (1u64 << 53) as f64
    }

    /// `n` points uniform in the unit cube, the coordinates of each drawn x, y, z in turn from `s`.
    pub fn random_points(s: &mut u64, n: usize) -> Vec<[f64; 3]> {
        (0..n).map(|_| [lcg(s), lcg(s), lcg(s)]).collect()
    }

    /// `n` particles: centres from [`random_points`], then radii uniform in [r_min, r_min + r_span),
    /// all drawn from `s`.
    pub fn random_particles(
        s: &mut u64,
        n: usize,
        r_min: f64,
        r_span: f64,
    ) -> (Vec<[f64; 3]>, Vec<f64>) {
        let centres = random_points(s, n);
        let radii = (0..n).map(|_| r_min + r_span * lcg(s)).collect();
        (centres, radii)
    }

    /// A unit direction: three uniform components in [−0.5, 0.5), drawn x, y, z in turn from `s`,
    /// normalised (not uniform on the sphere, which no test needs).
    pub fn random_direction(s: &mut u64) -> [f64; 3] {
        let d = [lcg(s) - 0.5, lcg(s) - 0.5, lcg(s) - 0.5];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|x| x / l)
    }

    /// Runs `trials` free flights, `escapes(u)` each with a fresh uniform `u` from `s` (checking
    /// what it likes, and returning whether the flight escaped), and checks the escapes with
    /// [`assert_escape_fraction`].
    pub fn assert_escape_rate(
        s: &mut u64,
        trials: usize,
        expected: f64,
        mut escapes: impl FnMut(f64) -> bool,
    ) {
        let escaped = (0..trials).filter(|_| escapes(lcg(s))).count();
        assert_escape_fraction(escaped, trials, expected);
    }

    /// Asserts that `escaped` escapes in `trials` free flights are within 5 binomial standard
    /// deviations of the escape probability `expected` (= e^{−τ}).
    pub fn assert_escape_fraction(escaped: usize, trials: usize, expected: f64) {
        let p = escaped as f64 / trials as f64;
        let sd = (expected * (1.0 - expected) / trials as f64).sqrt();
        assert!(
            (p - expected).abs() < 5.0 * sd,
            "escaped {p} vs e^-τ {expected}"
        );
    }
}

pub use ensemble::psd::Psd;
pub use error::OpticsError;
pub use optics::{Method, Particle};
