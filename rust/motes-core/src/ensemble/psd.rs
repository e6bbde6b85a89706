//! Particle size distributions (paper Sec. 4.1, Eq. 15) — number densities of radius, truncated to a
//! support `[r_min, r_max]` (the paper caps r at 2000 µm).
//!
//! A PSD is a probability distribution of the radius of one particle: continuous parts with a density
//! (`pdf`) and atoms (monodisperse components, log-normals with σ_g = 1) with a mass. Everything that
//! integrates over a PSD — bulk coefficients (Eq. 16–17), means, sampling — goes through
//! [`Psd::quadrature`] or [`Psd::sample`], which treat both alike. Specs are JSON (serde), e.g.
//! `{"type": "lognormal", "median_um": 800, "sigma_g": 4, "r_max_um": 2000}`.

use crate::error::{require, require_len, require_min_len, OpticsError};
use crate::quadrature::gauss_legendre;
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, Normal};

/// Default truncation of log-normal tails: the paper's r_max and a floor far below any visible grain.
pub const DEFAULT_R_MIN_UM: f64 = 1e-3;
pub const DEFAULT_R_MAX_UM: f64 = 2000.0;
/// Log-normal tails beyond ±Z_CUT standard deviations carry < 1e-17 of the mass and are dropped.
const Z_CUT: f64 = 8.5;

fn default_r_min() -> f64 {
    DEFAULT_R_MIN_UM
}
fn default_r_max() -> f64 {
    DEFAULT_R_MAX_UM
}

/// A particle size distribution (radius in µm).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum Psd {
    /// Every particle has the same radius.
    Monodisperse { radius_um: f64 },
    /// Eq. 15: ln r ~ Normal(ln r̄_g, ln σ_g), truncated to [r_min, r_max]. σ_g = 1 is monodisperse.
    LogNormal {
        median_um: f64,
        sigma_g: f64,
        #[serde(default = "default_r_min")]
        r_min_um: f64,
        #[serde(default = "default_r_max")]
        r_max_um: f64,
    },
    /// Uniform in r on [r_min, r_max] (the paper's Fig. 8 sampling).
    Uniform { r_min_um: f64, r_max_um: f64 },
    /// Piecewise-constant number density: `counts[i]` particles between `edges_um[i]` and `edges_um[i+1]`.
    Histogram {
        edges_um: Vec<f64>,
        counts: Vec<f64>,
    },
    /// Number-weighted mixture (e.g. the bimodal snow of Fig. 19): `weights[i]` is the share of
    /// particles in `components[i]`.
    Mixture {
        weights: Vec<f64>,
        components: Vec<Psd>,
    },
    /// An explicit list of particle radii (e.g. from a simulation), each one particle (an atom of mass
    /// 1/n). At least two radii: one radius is `Monodisperse`.
    Radii { radii_um: Vec<f64> },
}

fn std_normal() -> Normal {
    Normal::new(0.0, 1.0).expect("standard normal")
}

/// Radii from uniform numbers, as [`Psd::draw`] gives them (see [`Psd::sampler`]).
pub(crate) enum RadiusSampler<'a> {
    LogNormal {
        median_um: f64,
        ln_sigma: f64,
        z: (f64, f64),
        cdf: (f64, f64),
        normal: Normal,
    },
    Any(&'a Psd),
}

impl RadiusSampler<'_> {
    pub(crate) fn draw(&self, u_pick: f64, u: f64) -> f64 {
        match self {
            RadiusSampler::LogNormal {
                median_um,
                ln_sigma,
                z,
                cdf,
                normal,
            } => {
                let p = (cdf.0 + u.clamp(0.0, 1.0) * (cdf.1 - cdf.0))
                    .clamp(f64::MIN_POSITIVE, 1.0 - f64::EPSILON);
                median_um * (normal.inverse_cdf(p).clamp(z.0, z.1) * ln_sigma).exp()
            }
            RadiusSampler::Any(psd) => psd.draw(u_pick, u),
        }
    }
}

impl Psd {
    /// Parse and validate a JSON spec.
    pub fn from_json(spec: &str) -> Result<Self, OpticsError> {
        let psd: Psd = serde_json::from_str(spec).map_err(|e| OpticsError::InvalidOption {
            argument: "psd",
            value: e.to_string(),
            allowed: "a PSD spec (see motes.psd)",
        })?;
        psd.validate()?;
        Ok(psd)
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("PSD serialises")
    }

    /// Check every parameter, naming the bad one.
    pub fn validate(&self) -> Result<(), OpticsError> {
        match self {
            Psd::Monodisperse { radius_um } => positive("radius_um", *radius_um),
            Psd::LogNormal { .. } => self.validate_lognormal(),
            Psd::Uniform { r_min_um, r_max_um } => {
                positive("r_min_um", *r_min_um)?;
                positive("r_max_um", *r_max_um)?;
                require("r_max_um", *r_max_um, r_max_um > r_min_um, "> r_min_um")
            }
            Psd::Histogram { edges_um, counts } => validate_histogram(edges_um, counts),
            Psd::Radii { radii_um } => {
                require_min_len(
                    "radii_um (length)",
                    radii_um.len(),
                    2,
                    ">= 2 (an empty list has no particles; for one radius use Monodisperse)",
                )?;
                radii_um.iter().try_for_each(|&r| positive("radii_um", r))
            }
            Psd::Mixture {
                weights,
                components,
            } => validate_mixture(weights, components),
        }
    }

    fn validate_lognormal(&self) -> Result<(), OpticsError> {
        let Psd::LogNormal {
            median_um,
            sigma_g,
            r_min_um,
            r_max_um,
        } = self
        else {
            unreachable!("validate_lognormal of a log-normal only")
        };
        positive("median_um", *median_um)?;
        require(
            "sigma_g",
            *sigma_g,
            sigma_g.is_finite() && *sigma_g >= 1.0,
            "finite and >= 1",
        )?;
        positive("r_min_um", *r_min_um)?;
        positive("r_max_um", *r_max_um)?;
        require("r_max_um", *r_max_um, r_max_um > r_min_um, "> r_min_um")?;
        if *sigma_g == 1.0 {
            require(
                "median_um",
                *median_um,
                (*r_min_um..=*r_max_um).contains(median_um),
                "inside [r_min_um, r_max_um] when sigma_g = 1",
            )?;
        } else {
            require(
                "r_min_um / r_max_um",
                0.0,
                self.lognormal_mass() > 0.0,
                "an interval holding some of the log-normal's mass",
            )?;
        }
        Ok(())
    }

    /// Standardised truncation bounds of a log-normal: (z_lo, z_hi) clipped to ±Z_CUT.
    fn lognormal_z(&self) -> (f64, f64) {
        if let Psd::LogNormal {
            median_um,
            sigma_g,
            r_min_um,
            r_max_um,
        } = self
        {
            let s = sigma_g.ln();
            (
                ((r_min_um / median_um).ln() / s).max(-Z_CUT),
                ((r_max_um / median_um).ln() / s).min(Z_CUT),
            )
        } else {
            unreachable!()
        }
    }

    fn lognormal_mass(&self) -> f64 {
        let (lo, hi) = self.lognormal_z();
        if hi <= lo {
            return 0.0;
        }
        let n = std_normal();
        n.cdf(hi) - n.cdf(lo)
    }

    /// Smallest and largest radius with non-zero probability.
    pub fn support(&self) -> (f64, f64) {
        match self {
            Psd::Monodisperse { radius_um } => (*radius_um, *radius_um),
            Psd::LogNormal {
                median_um, sigma_g, ..
            } if *sigma_g == 1.0 => (*median_um, *median_um),
            Psd::LogNormal {
                median_um, sigma_g, ..
            } => {
                let (lo, hi) = self.lognormal_z();
                (
                    median_um * (lo * sigma_g.ln()).exp(),
                    median_um * (hi * sigma_g.ln()).exp(),
                )
            }
            Psd::Uniform { r_min_um, r_max_um } => (*r_min_um, *r_max_um),
            Psd::Histogram { edges_um, counts } => {
                let first = counts.iter().position(|&c| c > 0.0).unwrap_or(0);
                let last = counts
                    .iter()
                    .rposition(|&c| c > 0.0)
                    .unwrap_or(counts.len() - 1);
                (edges_um[first], edges_um[last + 1])
            }
            Psd::Radii { radii_um } => radii_um
                .iter()
                .fold((f64::INFINITY, 0.0), |a, &r| (a.0.min(r), a.1.max(r))),
            Psd::Mixture {
                weights,
                components,
            } => components
                .iter()
                .zip(weights)
                .filter(|(_, w)| **w > 0.0)
                .map(|(c, _)| c.support())
                .fold((f64::INFINITY, 0.0), |a, b| (a.0.min(b.0), a.1.max(b.1))),
        }
    }

    /// P(R ≤ r).
    pub fn cdf(&self, r: f64) -> f64 {
        match self {
            Psd::Monodisperse { radius_um } => (r >= *radius_um) as u8 as f64,
            Psd::LogNormal {
                median_um, sigma_g, ..
            } if *sigma_g == 1.0 => (r >= *median_um) as u8 as f64,
            Psd::LogNormal {
                median_um, sigma_g, ..
            } => {
                let (lo, hi) = self.lognormal_z();
                let n = std_normal();
                let z = ((r / median_um).ln() / sigma_g.ln()).clamp(lo, hi);
                ((n.cdf(z) - n.cdf(lo)) / (n.cdf(hi) - n.cdf(lo))).clamp(0.0, 1.0)
            }
            Psd::Uniform { r_min_um, r_max_um } => {
                ((r - r_min_um) / (r_max_um - r_min_um)).clamp(0.0, 1.0)
            }
            Psd::Histogram { edges_um, counts } => {
                let total: f64 = counts.iter().sum();
                let mut acc = 0.0;
                for (i, &c) in counts.iter().enumerate() {
                    let (a, b) = (edges_um[i], edges_um[i + 1]);
                    if r >= b {
                        acc += c;
                    } else {
                        if r > a {
                            acc += c * (r - a) / (b - a);
                        }
                        break;
                    }
                }
                acc / total
            }
            Psd::Radii { radii_um } => {
                radii_um.iter().filter(|&&x| x <= r).count() as f64 / radii_um.len() as f64
            }
            Psd::Mixture { .. } => self.mixture_mean(|c| c.cdf(r)),
        }
    }

    /// Density of the continuous part at r (µm⁻¹); atoms are not included (see [`Psd::atoms`]).
    pub fn pdf(&self, r: f64) -> f64 {
        let (lo, hi) = self.support();
        if !(r >= lo && r <= hi) {
            return 0.0;
        }
        match self {
            Psd::Monodisperse { .. } | Psd::Radii { .. } => 0.0,
            Psd::LogNormal { sigma_g, .. } if *sigma_g == 1.0 => 0.0,
            Psd::LogNormal {
                median_um, sigma_g, ..
            } => {
                // Eq. 15 divided by N0 and by the mass kept by the truncation.
                let s = sigma_g.ln();
                let z = (r / median_um).ln() / s;
                (-0.5 * z * z).exp()
                    / ((2.0 * std::f64::consts::PI).sqrt() * r * s)
                    / self.lognormal_mass()
            }
            Psd::Uniform { r_min_um, r_max_um } => 1.0 / (r_max_um - r_min_um),
            Psd::Histogram { edges_um, counts } => {
                let total: f64 = counts.iter().sum();
                let i = edges_um
                    .partition_point(|&e| e <= r)
                    .saturating_sub(1)
                    .min(counts.len() - 1);
                counts[i] / (total * (edges_um[i + 1] - edges_um[i]))
            }
            Psd::Mixture { .. } => self.mixture_mean(|c| c.pdf(r)),
        }
    }

    /// Σ w_i f(c_i) / Σ w_i over a mixture's components c_i and weights w_i: the mixture's value of
    /// a quantity linear in the distribution (its CDF, its density).
    fn mixture_mean(&self, f: impl Fn(&Psd) -> f64) -> f64 {
        let Psd::Mixture {
            weights,
            components,
        } = self
        else {
            unreachable!("mixture_mean of a mixture only")
        };
        let total: f64 = weights.iter().sum();
        components
            .iter()
            .zip(weights)
            .map(|(c, w)| w * f(c))
            .sum::<f64>()
            / total
    }

    /// Point masses (radius, probability): monodisperse components and σ_g = 1 log-normals.
    pub fn atoms(&self) -> Vec<(f64, f64)> {
        match self {
            Psd::Monodisperse { radius_um } => vec![(*radius_um, 1.0)],
            Psd::LogNormal {
                median_um, sigma_g, ..
            } if *sigma_g == 1.0 => vec![(*median_um, 1.0)],
            Psd::Radii { .. } => self.radii_atoms(),
            Psd::Mixture {
                weights,
                components,
            } => {
                let total: f64 = weights.iter().sum();
                components
                    .iter()
                    .zip(weights)
                    .flat_map(|(c, w)| c.atoms().into_iter().map(move |(r, m)| (r, m * w / total)))
                    .collect()
            }
            _ => Vec::new(),
        }
    }

    /// Radius with P(R ≤ r) = u, u ∈ [0, 1] (inverse CDF; bisection in ln r for mixtures).
    pub fn quantile(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        match self {
            Psd::Monodisperse { radius_um } => *radius_um,
            Psd::LogNormal {
                median_um, sigma_g, ..
            } if *sigma_g == 1.0 => *median_um,
            Psd::LogNormal {
                median_um, sigma_g, ..
            } => {
                let (lo, hi) = self.lognormal_z();
                let n = std_normal();
                let (clo, chi) = (n.cdf(lo), n.cdf(hi));
                let z = n
                    .inverse_cdf(
                        (clo + u * (chi - clo)).clamp(f64::MIN_POSITIVE, 1.0 - f64::EPSILON),
                    )
                    .clamp(lo, hi);
                median_um * (z * sigma_g.ln()).exp()
            }
            Psd::Uniform { r_min_um, r_max_um } => r_min_um + u * (r_max_um - r_min_um),
            Psd::Histogram { edges_um, counts } => {
                let total: f64 = counts.iter().sum();
                let target = u * total;
                let mut acc = 0.0;
                for (i, &c) in counts.iter().enumerate() {
                    if c > 0.0 && acc + c >= target {
                        return edges_um[i] + (target - acc) / c * (edges_um[i + 1] - edges_um[i]);
                    }
                    acc += c;
                }
                self.support().1
            }
            Psd::Radii { radii_um } => {
                let mut r = radii_um.clone();
                r.sort_by(f64::total_cmp);
                let k = ((u * r.len() as f64).ceil() as usize).clamp(1, r.len());
                r[k - 1]
            }
            Psd::Mixture { .. } => {
                let (mut a, mut b) = self.support();
                for _ in 0..200 {
                    let mid = (a * b).sqrt();
                    if self.cdf(mid) < u {
                        a = mid;
                    } else {
                        b = mid;
                    }
                    if b / a - 1.0 < 1e-14 {
                        break;
                    }
                }
                b
            }
        }
    }

    /// A sampler of this distribution's radii that draws exactly what [`Self::draw`] draws, with the
    /// truncated log-normal's bound CDFs computed once instead of per radius (two of its three normal
    /// CDF evaluations: ~3x faster on generated clouds).
    pub(crate) fn sampler(&self) -> RadiusSampler<'_> {
        match self {
            Psd::LogNormal {
                median_um, sigma_g, ..
            } if *sigma_g != 1.0 => {
                let (lo, hi) = self.lognormal_z();
                let n = std_normal();
                RadiusSampler::LogNormal {
                    median_um: *median_um,
                    ln_sigma: sigma_g.ln(),
                    z: (lo, hi),
                    cdf: (n.cdf(lo), n.cdf(hi)),
                    normal: n,
                }
            }
            _ => RadiusSampler::Any(self),
        }
    }

    /// One radius from uniform numbers: a mixture first picks its component by weight (`u_pick`),
    /// then the component inverts its CDF at `u`.
    pub(crate) fn draw(&self, u_pick: f64, u: f64) -> f64 {
        match self {
            Psd::Mixture {
                weights,
                components,
            } => {
                let total: f64 = weights.iter().sum();
                let mut acc = 0.0;
                for (c, w) in components.iter().zip(weights) {
                    acc += w / total;
                    if u_pick < acc {
                        let local = (u_pick - (acc - w / total)) / (w / total);
                        return c.draw(local.clamp(0.0, 1.0), u);
                    }
                }
                let last = components
                    .iter()
                    .zip(weights)
                    .rfind(|(_, w)| **w > 0.0)
                    .map(|(c, _)| c)
                    .unwrap();
                last.draw(0.5, u)
            }
            Psd::Radii { radii_um } => {
                radii_um[((u * radii_um.len() as f64) as usize).min(radii_um.len() - 1)]
            }
            _ => self.quantile(u),
        }
    }

    /// Equal-mass atoms of an explicit radius list, equal radii merged.
    fn radii_atoms(&self) -> Vec<(f64, f64)> {
        let Psd::Radii { radii_um } = self else {
            return Vec::new();
        };
        let mut r = radii_um.clone();
        r.sort_by(f64::total_cmp);
        let m = 1.0 / r.len() as f64;
        let mut out: Vec<(f64, f64)> = Vec::new();
        for x in r {
            match out.last_mut() {
                Some(last) if last.0 == x => last.1 += m,
                _ => out.push((x, m)),
            }
        }
        out
    }

    /// `n` radii, reproducible from `seed` whatever the number of threads: chunk k of 65536 radii uses
    /// its own xoshiro256++ stream seeded from (seed, k).
    pub fn sample(&self, n: usize, seed: u64) -> Vec<f64> {
        use rayon::prelude::*;
        const CHUNK: usize = 1 << 16;
        let to_unit = |x: u64| ((x >> 11) as f64 + 0.5) * (1.0 / (1u64 << 53) as f64);
        (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .flat_map_iter(|k| {
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(
                    seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                let len = CHUNK.min(n - k * CHUNK);
                (0..len)
                    .map(move |_| {
                        let a = to_unit(rng.next_u64());
                        let b = to_unit(rng.next_u64());
                        self.draw(a, b)
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// The check of a quadrature's panel width, shared by every caller that takes one from a user.
    pub fn require_log_step(max_log_step: f64) -> Result<(), crate::OpticsError> {
        crate::error::require(
            "max_log_step",
            max_log_step,
            max_log_step.is_finite() && max_log_step > 0.0,
            "finite and > 0",
        )
    }

    /// Nodes and weights with `Σ w g(r) ≈ E[g(R)]` for smooth g: atoms as nodes of their mass, continuous
    /// parts by Gauss–Legendre in ln r on panels no wider than `max_log_step` (in ln r), so that
    /// structure of g on that scale (e.g. the extinction ripple) is resolved where it matters.
    pub fn quadrature(&self, max_log_step: f64) -> (Vec<f64>, Vec<f64>) {
        self.quadrature_resolving(max_log_step, None)
    }

    /// [`Psd::quadrature`], and with `ripple` the panels in its size-parameter range that carry
    /// scattering (see [`RippleResolution`]) integrated by the midpoint rule on a grid uniform in
    /// x = k r, at most `ripple.dx` apart: Mie's resonances in x are far narrower than any panel in ln r,
    /// and equal weights on a fine uniform grid average them where Gauss–Legendre nodes alias them.
    pub fn quadrature_resolving(
        &self,
        max_log_step: f64,
        ripple: Option<&RippleResolution>,
    ) -> (Vec<f64>, Vec<f64>) {
        let step = max_log_step.clamp(1e-6, 1.0);
        let mut nodes = Vec::new();
        let mut weights = Vec::new();
        // The r²-weighted mass (∝ scattering) of the whole PSD, to skip panels that carry too little.
        let ripple = ripple.filter(|q| q.dx > 0.0 && q.x_max > q.x_min).map(|q| {
            self.push_quadrature(1.0, step, None, &mut nodes, &mut weights);
            let m2: f64 = nodes.iter().zip(&weights).map(|(r, w)| w * r * r).sum();
            nodes.clear();
            weights.clear();
            (q, q.min_share * m2)
        });
        self.push_quadrature(1.0, step, ripple, &mut nodes, &mut weights);
        (nodes, weights)
    }

    fn push_quadrature(
        &self,
        scale: f64,
        step: f64,
        ripple: Option<(&RippleResolution, f64)>,
        nodes: &mut Vec<f64>,
        weights: &mut Vec<f64>,
    ) {
        let rule = gauss_legendre(8);
        let mut out = QuadratureOut {
            ripple,
            nodes,
            weights,
        };
        match self {
            Psd::Monodisperse { radius_um } => out.atom(*radius_um, scale),
            Psd::LogNormal {
                sigma_g, median_um, ..
            } if *sigma_g == 1.0 => out.atom(*median_um, scale),
            Psd::LogNormal { .. } => self.push_lognormal(scale, step, &rule, &mut out),
            Psd::Uniform { .. } => {
                let (a, b) = self.support();
                out.panels(a, b, &|r| self.pdf(r), scale, step, &rule);
            }
            Psd::Histogram { edges_um, counts } => {
                let total: f64 = counts.iter().sum();
                for (i, &c) in counts.iter().enumerate() {
                    if c > 0.0 {
                        let (a, b) = (edges_um[i], edges_um[i + 1]);
                        let d = c / (total * (b - a));
                        out.panels(a, b, &|_| d, scale, step, &rule);
                    }
                }
            }
            Psd::Radii { .. } => {
                for (r, m) in self.radii_atoms() {
                    out.atom(r, scale * m);
                }
            }
            Psd::Mixture {
                weights: ws,
                components,
            } => {
                let total: f64 = ws.iter().sum();
                for (c, w) in components.iter().zip(ws) {
                    if *w > 0.0 {
                        c.push_quadrature(scale * w / total, step, ripple, out.nodes, out.weights);
                    }
                }
            }
        }
    }

    /// The log-normal's panels: in the standard variable z (r = r_g e^{z ln σ_g}) the weights
    /// φ(z)/mass are exact for any width, down to σ_g = 1 + 1e-15; panels ≤ 0.5 in z and ≤ `step` in
    /// ln r.
    fn push_lognormal(
        &self,
        scale: f64,
        step: f64,
        (x, w): &(Vec<f64>, Vec<f64>),
        out: &mut QuadratureOut,
    ) {
        let Psd::LogNormal {
            median_um, sigma_g, ..
        } = self
        else {
            unreachable!("push_lognormal of a log-normal only")
        };
        let s_ln = sigma_g.ln();
        let (zlo, zhi) = self.lognormal_z();
        let mass = self.lognormal_mass();
        let norm = scale / (2.0 * std::f64::consts::PI).sqrt() / mass;
        let panels = (((zhi - zlo) * s_ln / step).ceil() as usize)
            .max((2.0 * (zhi - zlo)).ceil() as usize)
            .max(1);
        let h = (zhi - zlo) / panels as f64;
        let ln_med = median_um.ln();
        // Density per unit ln r: φ(z) / (ln σ_g · mass).
        let per_t = |t: f64| {
            let z = (t - ln_med) / s_ln;
            norm * (-0.5 * z * z).exp() / s_ln
        };
        for k in 0..panels {
            let z0 = zlo + k as f64 * h;
            let gl: Vec<(f64, f64)> = x
                .iter()
                .zip(w)
                .map(|(xi, wi)| {
                    let z = z0 + 0.5 * h * (1.0 + xi);
                    (
                        median_um * (z * s_ln).exp(),
                        scale * 0.5 * h * wi * (-0.5 * z * z).exp()
                            / (2.0 * std::f64::consts::PI).sqrt()
                            / mass,
                    )
                })
                .collect();
            out.emit(ln_med + z0 * s_ln, ln_med + (z0 + h) * s_ln, &gl, &per_t);
        }
    }
}

/// Where a quadrature's nodes and weights go, with the ripple resolution its panels honour.
struct QuadratureOut<'a> {
    ripple: Option<(&'a RippleResolution, f64)>,
    nodes: &'a mut Vec<f64>,
    weights: &'a mut Vec<f64>,
}

impl QuadratureOut<'_> {
    /// A point mass.
    fn atom(&mut self, r: f64, weight: f64) {
        self.nodes.push(r);
        self.weights.push(weight);
    }

    /// One panel [ta, tb] in t = ln r with `density(t)` per unit t (scale included): midpoints uniform in
    /// x where the ripple resolution asks for them, else the Gauss–Legendre nodes `gl`.
    fn emit(&mut self, ta: f64, tb: f64, gl: &[(f64, f64)], density: &dyn Fn(f64) -> f64) {
        if let Some((q, min_mass)) = self.ripple {
            let (xa, xb) = (
                q.wavenumber_per_um * ta.exp(),
                q.wavenumber_per_um * tb.exp(),
            );
            let m2: f64 = gl.iter().map(|(r, w)| w * r * r).sum();
            if xb <= q.x_max && xb > q.x_min && m2 >= min_mass {
                let dx = q.dx * (xb / q.x_grow).max(1.0);
                let n = ((xb - xa) / dx).ceil().max(1.0) as usize;
                let h = (xb - xa) / n as f64;
                for i in 0..n {
                    let xi = xa + (i as f64 + 0.5) * h;
                    // ∫ g p dr = ∫ g density(t) dx / x.
                    self.nodes.push(xi / q.wavenumber_per_um);
                    self.weights
                        .push(h * density((xi / q.wavenumber_per_um).ln()) / xi);
                }
                return;
            }
        }
        for &(r, wt) in gl {
            self.atom(r, wt);
        }
    }

    /// ∫_a^b g(r) p(r) dr with r = e^t: panels of at most `step` in t, `density(r)` per unit r.
    fn panels(
        &mut self,
        a: f64,
        b: f64,
        density: &dyn Fn(f64) -> f64,
        scale: f64,
        step: f64,
        (x, w): &(Vec<f64>, Vec<f64>),
    ) {
        let (ta, tb) = (a.ln(), b.ln());
        let panels = (((tb - ta) / step).ceil() as usize).max(1);
        let h = (tb - ta) / panels as f64;
        for k in 0..panels {
            let t0 = ta + k as f64 * h;
            let per_t = |t: f64| scale * density(t.exp()) * t.exp();
            let gl: Vec<(f64, f64)> = x
                .iter()
                .zip(w)
                .map(|(xi, wi)| {
                    let t = t0 + 0.5 * h * (1.0 + xi);
                    let r = t.exp();
                    (r, scale * 0.5 * h * wi * density(r) * r)
                })
                .collect();
            self.emit(t0, t0 + h, &gl, &per_t);
        }
    }
}

/// `v` finite and > 0, else an error naming `name`.
fn positive(name: &'static str, v: f64) -> Result<(), OpticsError> {
    require(name, v, v.is_finite() && v > 0.0, "finite and > 0")
}

fn validate_histogram(edges_um: &[f64], counts: &[f64]) -> Result<(), OpticsError> {
    require_min_len("edges_um (length)", edges_um.len(), 2, ">= 2")?;
    require_len(
        "counts (length)",
        counts.len(),
        edges_um.len() - 1,
        "len(edges_um) - 1",
    )?;
    for &e in edges_um {
        positive("edges_um", e)?;
    }
    for w in edges_um.windows(2) {
        require("edges_um", w[1], w[1] > w[0], "strictly increasing")?;
    }
    require_shares("counts", "counts (sum)", counts)
}

fn validate_mixture(weights: &[f64], components: &[Psd]) -> Result<(), OpticsError> {
    require_min_len("components (length)", components.len(), 1, ">= 1")?;
    require_len(
        "weights (length)",
        weights.len(),
        components.len(),
        "len(components)",
    )?;
    require_shares("weights", "weights (sum)", weights)?;
    components.iter().try_for_each(Psd::validate)
}

/// Relative amounts (histogram counts, mixture weights): each finite and >= 0, else an error naming
/// `each`, and some > 0 (a sum > 0), else one naming `sum`.
fn require_shares(
    each: &'static str,
    sum: &'static str,
    values: &[f64],
) -> Result<(), OpticsError> {
    for &v in values {
        require(each, v, v.is_finite() && v >= 0.0, "finite and >= 0")?;
    }
    require(
        sum,
        values.iter().sum(),
        values.iter().sum::<f64>() > 0.0,
        "> 0",
    )
}

/// Where a radius quadrature must resolve Mie's ripple in the size parameter x = k r: panels that end in
/// `x_min < x ≤ x_max` and carry at least `min_share` of the PSD's r²-weighted mass (∝ its
/// scattering) are integrated on a grid uniform in x, `dx` apart (more above `x_grow`) (see [`Psd::quadrature_resolving`]).
#[derive(Clone, Copy, Debug)]
pub struct RippleResolution {
    /// k = 2π η_medium / λ, µm⁻¹.
    pub wavenumber_per_um: f64,
    pub dx: f64,
    /// Above this size parameter the spacing grows in proportion to x (`dx · x / x_grow`): the
    /// resonances get denser and narrower, and a constant relative step samples them evenly.
    pub x_grow: f64,
    pub x_min: f64,
    pub x_max: f64,
    pub min_share: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lognormal(median: f64, sigma: f64) -> Psd {
        Psd::LogNormal {
            median_um: median,
            sigma_g: sigma,
            r_min_um: DEFAULT_R_MIN_UM,
            r_max_um: DEFAULT_R_MAX_UM,
        }
    }

    /// Quadrature weights sum to 1 and reproduce the log-normal moments E[r^k] = r_g^k exp(k² ln²σ_g / 2)
    /// (untruncated case: bounds far in the tails).
    #[test]
    fn lognormal_moments() {
        let psd = Psd::LogNormal {
            median_um: 10.0,
            sigma_g: 2.0,
            r_min_um: 1e-6,
            r_max_um: 1e8,
        };
        let (r, w) = psd.quadrature(0.05);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        for k in 1..=3 {
            let exact = 10f64.powi(k) * (0.5 * (k * k) as f64 * 2f64.ln().powi(2)).exp();
            let got: f64 = r.iter().zip(&w).map(|(r, w)| w * r.powi(k)).sum();
            assert!((got / exact - 1.0).abs() < 1e-10, "k={k}: {got} vs {exact}");
        }
    }

    /// With ripple resolution the quadrature keeps the moments (midpoint rule, step ≤ dx in x) and puts
    /// nodes at most dx/k apart across the resolved range (where the scattering is); beyond x_max the nodes are unchanged.
    #[test]
    fn ripple_resolution_keeps_moments() {
        for psd in [
            lognormal(3.0, 1.5),
            Psd::Uniform {
                r_min_um: 0.5,
                r_max_um: 40.0,
            },
        ] {
            let k = 2.0 * std::f64::consts::PI / 0.55;
            let q = RippleResolution {
                wavenumber_per_um: k,
                dx: 0.02,
                x_grow: 1e9,
                x_min: 2.0,
                x_max: 300.0,
                min_share: 1e-6,
            };
            let (r0, w0) = psd.quadrature(0.05);
            let (r, w) = psd.quadrature_resolving(0.05, Some(&q));
            assert!(r.len() > 10 * r0.len());
            for p in 0..=4 {
                let m =
                    |r: &[f64], w: &[f64]| r.iter().zip(w).map(|(r, w)| w * r.powi(p)).sum::<f64>();
                assert!((m(&r, &w) / m(&r0, &w0) - 1.0).abs() < 1e-5, "moment {p}");
            }
            let inside: Vec<f64> = r
                .iter()
                .map(|r| k * r)
                .filter(|&x| x > 20.0 && x < 150.0)
                .collect();
            assert!(inside
                .windows(2)
                .all(|x| x[1] > x[0] && x[1] - x[0] <= 0.02 * (1.0 + 1e-9)));
            assert_eq!(
                r.iter().filter(|&&r| k * r > 320.0).count(),
                r0.iter().filter(|&&r| k * r > 320.0).count()
            );
        }
    }

    /// A log-normal narrower than one quadrature panel in ln r still integrates to 1 with the right mean.
    #[test]
    fn narrow_lognormal_quadrature() {
        for sigma in [1.0 + 1e-12, 1.0 + 1e-9, 1.0 + 1e-6, 1.01] {
            let (r, w) = lognormal(800.0, sigma).quadrature(0.05);
            let mean: f64 = r.iter().zip(&w).map(|(r, w)| r * w).sum();
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12, "σ_g = {sigma}");
            assert!(
                (mean / (800.0 * (0.5 * sigma.ln().powi(2)).exp()) - 1.0).abs() < 1e-12,
                "σ_g = {sigma}: {mean}"
            );
        }
    }

    /// σ_g = 1 is monodisperse: no division by ln 1 anywhere.
    #[test]
    fn sigma_one_is_monodisperse() {
        let psd = lognormal(800.0, 1.0);
        assert_eq!(psd.quadrature(0.1), (vec![800.0], vec![1.0]));
        assert_eq!(psd.sample(10, 1), vec![800.0; 10]);
        assert_eq!(psd.cdf(799.0), 0.0);
        assert_eq!(psd.cdf(800.0), 1.0);
        assert_eq!(psd.pdf(800.0), 0.0);
    }

    /// quantile inverts cdf, for every kind, including the mixture's bisection.
    #[test]
    fn quantile_inverts_cdf() {
        let mix = Psd::Mixture {
            weights: vec![0.7, 0.3],
            components: vec![lognormal(100.0, 1.5), lognormal(800.0, 2.0)],
        };
        let hist = Psd::Histogram {
            edges_um: vec![1.0, 2.0, 5.0, 10.0],
            counts: vec![1.0, 0.0, 3.0],
        };
        for psd in [
            lognormal(800.0, 4.0),
            Psd::Uniform {
                r_min_um: 1.0,
                r_max_um: 3.0,
            },
            hist,
            mix,
        ] {
            for k in 1..20 {
                let u = k as f64 / 20.0;
                let r = psd.quantile(u);
                assert!(
                    (psd.cdf(r) - u).abs() < 1e-9,
                    "{psd:?} u={u} r={r} cdf={}",
                    psd.cdf(r)
                );
            }
        }
    }

    /// Sampling is reproducible, thread-count independent, and follows the CDF (KS distance).
    #[test]
    fn sampling_follows_cdf() {
        let psd = Psd::Mixture {
            weights: vec![0.9, 0.1],
            components: vec![lognormal(100.0, 1.0), lognormal(800.0, 4.0)],
        };
        let a = psd.sample(200_000, 7);
        assert_eq!(a, psd.sample(200_000, 7));
        assert_ne!(a, psd.sample(200_000, 8));
        let mut s = a.clone();
        s.sort_by(f64::total_cmp);
        let n = s.len() as f64;
        let ks = s.iter().enumerate().map(|(i, &r)| {
            // Atoms make the CDF jump: compare against both sides of the step.
            let below = psd.cdf(r * (1.0 - 1e-12));
            let at = psd.cdf(r);
            let e = (i + 1) as f64 / n;
            if e < below {
                below - e
            } else if e > at {
                e - at
            } else {
                0.0
            }
        });
        let d = ks.fold(0.0, f64::max);
        assert!(
            d < 1.63 / n.sqrt() + 1e-9,
            "KS distance {d} (1% critical value {})",
            1.63 / n.sqrt()
        );
    }

    /// JSON specs round-trip; unknown fields and bad values are rejected with the parameter's name.
    #[test]
    fn json_specs() {
        let p = Psd::from_json(r#"{"type": "lognormal", "median_um": 800, "sigma_g": 4}"#).unwrap();
        assert_eq!(Psd::from_json(&p.to_json()).unwrap(), p);
        let e = Psd::from_json(r#"{"type": "lognormal", "median_um": 800, "sigma_g": 0.5}"#)
            .unwrap_err();
        assert!(e.to_string().contains("sigma_g"), "{e}");
        let e =
            Psd::from_json(r#"{"type": "lognormal", "median_um": 800, "sigmag": 2}"#).unwrap_err();
        assert!(e.to_string().contains("sigmag"), "{e}");
        let e = Psd::from_json(r#"{"type": "histogram", "edges_um": [1, 2], "counts": [0]}"#)
            .unwrap_err();
        assert!(e.to_string().contains("counts"), "{e}");
    }
}
