//! Bulk optical properties of a polydisperse, possibly multi-species particle cloud (paper Sec. 4.2,
//! Eq. 16–17; mixtures of species as in Müller et al., Sec. 5).
//!
//! For number concentration `N0` (m⁻³) split between species `s` with number shares `c_s`, each with a
//! PSD `P_s` and a relative index `m_s`:
//! * `σ_x = N0 Σ_s c_s ∫ C_x(r; m_s) dP_s(r)` for x = t, a (Eq. 16), `σ_s = σ_t − σ_a`, in m⁻¹;
//! * the ensemble phase function (Eq. 17, second line): `f(θ) ∝ N0 Σ_s c_s ∫ (|S1|²+|S2|²)/(2k²) dP_s`,
//!   normalised on the angle grid so that ∫ f dΩ = 1 — no per-particle normalisation is needed;
//! * `g = ∫ f cos θ dΩ` on the same grid.
//!
//! The integrals over r use `Psd::quadrature` (atoms exactly; Gauss–Legendre in ln r otherwise). The
//! angle grid is graded: θ = 0, then log-spaced from 0.01/α_max to 0.1 rad (the diffraction lobe of
//! the largest particle, width ~1/α, gets ~25 nodes across its core), then uniform to π.

use crate::error::{require, OpticsError};
use crate::goa::GoaOptions;
use crate::optics::{self, Method, Particle, Theory};
use crate::psd::Psd;
use num_complex::Complex64 as C64;
use rayon::prelude::*;
use std::f64::consts::PI;

/// One particle species of a medium.
#[derive(Clone, Debug)]
pub struct Species {
    pub psd: Psd,
    /// Refractive index of the particle material at the wavelength considered.
    pub eta: C64,
    /// Number share (need not be normalised).
    pub share: f64,
}

/// Options of a bulk computation.
#[derive(Clone, Copy, Debug)]
pub struct BulkOptions {
    pub method: Method,
    pub goa: GoaOptions,
    /// Largest quadrature panel in ln r (see `Psd::quadrature`).
    pub max_log_step: f64,
    /// Relative accuracy the tabulated phase function must reach between its nodes (0: no refinement).
    pub refine_tol: f64,
    /// Cap on the number of angles after refinement.
    pub refine_max_nodes: usize,
}

/// Bulk properties at one wavelength.
#[derive(Clone, Debug)]
pub struct Bulk {
    /// Extinction, scattering and absorption coefficients, m⁻¹.
    pub sigma_t: f64,
    pub sigma_s: f64,
    pub sigma_a: f64,
    /// Asymmetry parameter of the ensemble phase function.
    pub g: f64,
    /// Ensemble phase function on the angle grid, sr⁻¹ (∫ f dΩ = 1 by trapezoid on the grid).
    pub phase: Vec<f64>,
    /// ∫ (|S1|²+|S2|²)/(2k²) dΩ over the ensemble divided by its C_sca (1 for exact Mie up to the grid's
    /// quadrature error; GOA amplitudes carry slightly less energy than Eq. 12's C_sca, p > p_max).
    pub energy_ratio: f64,
    /// The angle grid of `phase` (the input grid, refined where needed).
    pub theta: Vec<f64>,
}

/// The graded angle grid: 0, `n_forward` log-spaced angles from `0.01/alpha_max` to 0.1 rad, then
/// `n_rest` uniform ones up to π.
pub fn graded_angles(alpha_max: f64, n_forward: usize, n_rest: usize) -> Vec<f64> {
    let lo = (0.01 / alpha_max.max(1.0)).min(1e-3);
    let split: f64 = 0.1;
    let mut t = vec![0.0];
    let (a, b) = (lo.ln(), split.ln());
    for i in 0..n_forward {
        t.push((a + (b - a) * i as f64 / n_forward as f64).exp());
    }
    for i in 0..=n_rest {
        t.push(split + (PI - split) * i as f64 / n_rest as f64);
    }
    t
}

/// Trapezoid weights for ∫ g(θ) 2π sin θ dθ on an increasing grid.
pub fn solid_angle_weights(theta: &[f64]) -> Vec<f64> {
    let n = theta.len();
    let mut w = vec![0.0; n];
    for i in 0..n.saturating_sub(1) {
        let h = theta[i + 1] - theta[i];
        w[i] += 0.5 * h * 2.0 * PI * theta[i].sin();
        w[i + 1] += 0.5 * h * 2.0 * PI * theta[i + 1].sin();
    }
    w
}

/// Bulk properties of `species` at one wavelength; `theta` must be increasing in [0, π] (use
/// [`graded_angles`]); an empty `theta` skips the phase function and g.
pub fn bulk(species: &[Species], number_density_m3: f64, wavelength_um: f64, eta_medium: f64, theta: &[f64], opts: &BulkOptions) -> Result<Bulk, OpticsError> {
    require("number_density_m3", number_density_m3, number_density_m3.is_finite() && number_density_m3 >= 0.0, "finite and >= 0")?;
    require("species (count)", species.len() as f64, !species.is_empty(), ">= 1")?;
    let total_share: f64 = species.iter().map(|s| s.share).sum();
    for s in species {
        require("share", s.share, s.share.is_finite() && s.share >= 0.0, "finite and >= 0")?;
        s.psd.validate()?;
    }
    require("share (sum)", total_share, total_share > 0.0, "> 0")?;
    for w in theta.windows(2) {
        require("theta", w[1], w[1] > w[0], "strictly increasing")?;
    }
    if let (Some(&a), Some(&b)) = (theta.first(), theta.last()) {
        require("theta", a, a >= 0.0, ">= 0")?;
        require("theta", b, b <= PI, "<= π")?;
    }
    // Every (species, radius node) with its number weight per m³.
    let mut nodes: Vec<(Particle, f64)> = Vec::new();
    for s in species {
        let (r, w) = s.psd.quadrature(opts.max_log_step);
        for (ri, wi) in r.into_iter().zip(w) {
            if wi > 0.0 {
                nodes.push((Particle::new(ri, wavelength_um, s.eta, eta_medium)?, number_density_m3 * s.share / total_share * wi));
            }
        }
    }
    // Per-node values are computed in parallel but summed in node order, so results are bitwise
    // reproducible whatever the thread scheduling.
    let per_node: Vec<(f64, f64)> = nodes
        .par_iter()
        .map(|(p, w)| {
            let (ce, ca) = optics::extinction_and_absorption(p, opts.method.theory(p, opts.goa.p_max), &opts.goa);
            (w * ce, w * ca)
        })
        .collect();
    let (ext, abs) = per_node.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let (theta, intensity) = if theta.is_empty() {
        (Vec::new(), Vec::new())
    } else {
        let base = intensity_at(&nodes, theta, opts);
        refine(&nodes, theta.to_vec(), base, opts)
    };
    let n_theta = theta.len();
    // µm² × m⁻³ → m⁻¹.
    let (sigma_t, sigma_a) = (ext * 1e-12, abs * 1e-12);
    let sigma_s = (sigma_t - sigma_a).max(0.0);
    let (mut phase, mut g, mut energy_ratio) = (Vec::new(), 0.0, 0.0);
    if n_theta > 0 {
        let wts = solid_angle_weights(&theta);
        let total: f64 = intensity.iter().zip(&wts).map(|(i, w)| i * w).sum();
        if total > 0.0 {
            phase = intensity.iter().map(|i| i / total).collect();
            g = phase.iter().zip(&wts).zip(&theta).map(|((f, w), t)| f * w * t.cos()).sum();
        } else {
            phase = vec![1.0 / (4.0 * PI); n_theta];
        }
        energy_ratio = if sigma_s > 0.0 { total * 1e-12 / sigma_s } else { 0.0 };
    }
    Ok(Bulk { sigma_t, sigma_s, sigma_a, g, phase, energy_ratio, theta })
}

/// `Σ w (|S1|²+|S2|²)/(2k²)` over the (species, radius) nodes at each angle. Deterministic: nodes are
/// summed in fixed chunks of 16, in order, then the chunk sums in order (bitwise reproducible).
fn intensity_at(nodes: &[(Particle, f64)], theta: &[f64], opts: &BulkOptions) -> Vec<f64> {
    let n = theta.len();
    let add = |a: Vec<f64>, b: Vec<f64>| a.iter().zip(&b).map(|(x, y)| x + y).collect::<Vec<f64>>();
    let chunks: Vec<Vec<f64>> = nodes
        .par_chunks(16)
        .map(|chunk| chunk.iter().map(|node| node_intensity(node, theta, opts)).fold(vec![0.0; n], add))
        .collect();
    chunks.into_iter().fold(vec![0.0; n], add)
}

/// One node's weighted intensity `w (|S1|²+|S2|²)/(2k²)` at every angle.
fn node_intensity((p, w): &(Particle, f64), theta: &[f64], opts: &BulkOptions) -> Vec<f64> {
    let theory = opts.method.theory(p, opts.goa.p_max);
    let geo = (theory == Theory::Goa).then(|| optics::cached_geometry(p.relative_index(), opts.goa.p_max));
    let k2 = p.k() * p.k();
    optics::particle_amplitudes(p, theory, geo.as_deref(), theta, &opts.goa)
        .into_iter()
        .map(|(s1, s2)| w * (s1.norm_sqr() + s2.norm_sqr()) / (2.0 * k2))
        .collect()
}

/// Adaptive refinement of the angle grid (when `opts.refine_tol > 0`): the table is piecewise linear in
/// μ = cos θ, so at the μ-midpoint of an interval it predicts the mean of the two ends. Every interval's
/// midpoint is evaluated and inserted where the table would be off by more
/// than `refine_tol` (relative) and f > 1e-6 max, or where the misprediction moves more than 1e-5 of the
/// total probability. Repeats on the new intervals, up to `refine_max_nodes`.
/// The result stays a piecewise-linear table, so sampling remains exactly consistent with evaluation.
fn refine(nodes: &[(Particle, f64)], mut theta: Vec<f64>, mut inten: Vec<f64>, opts: &BulkOptions) -> (Vec<f64>, Vec<f64>) {
    if opts.refine_tol <= 0.0 {
        return (theta, inten);
    }
    let fmax = inten.iter().cloned().fold(0.0, f64::max);
    let floor = 1e-6 * fmax;
    let mu = |t: f64| t.cos();
    // Second criterion: an interval whose misprediction moves more than MASS_TOL of the total
    // probability is refined too, wherever f is (keeps the normalisation right when fine fringes
    // below the 1e-6 floor carry much of the energy, e.g. a single millimetre grain).
    const MASS_TOL: f64 = 1e-5;
    let total: f64 = inten.iter().zip(solid_angle_weights(&theta)).map(|(f, w)| f * w).sum();
    let mass_floor = MASS_TOL * total;
    // First pass: every interval is a candidate (a feature may lie entirely between two nodes, where
    // no curvature test on the nodes can see it); later passes only the halves of refined intervals.
    let mut candidates: Vec<usize> = (0..theta.len() - 1).collect();
    for _pass in 0..40 {
        if candidates.is_empty() || theta.len() >= opts.refine_max_nodes {
            break;
        }
        candidates.truncate(opts.refine_max_nodes - theta.len());
        let mids: Vec<f64> = candidates.iter().map(|&i| ((mu(theta[i]) + mu(theta[i + 1])) * 0.5).clamp(-1.0, 1.0).acos()).collect();
        let vals = intensity_at(nodes, &mids, opts);
        // Insert where the linear table is off; the new intervals on both sides become candidates.
        let mut inserts: Vec<(usize, f64, f64)> = Vec::new();
        for ((&i, &t), &v) in candidates.iter().zip(&mids).zip(&vals) {
            let predicted = 0.5 * (inten[i] + inten[i + 1]);
            let relative = v.max(predicted) > floor && (predicted - v).abs() > opts.refine_tol * v.max(floor);
            let mass = (predicted - v).abs() * 2.0 * PI * (mu(theta[i]) - mu(theta[i + 1])).abs() > mass_floor;
            if (relative || mass) && t > theta[i] && t < theta[i + 1] {
                inserts.push((i, t, v));
            }
        }
        if inserts.is_empty() {
            break;
        }
        let mut new_theta = Vec::with_capacity(theta.len() + inserts.len());
        let mut new_inten = Vec::with_capacity(theta.len() + inserts.len());
        let mut next = Vec::with_capacity(2 * inserts.len());
        let mut k = 0;
        for i in 0..theta.len() {
            new_theta.push(theta[i]);
            new_inten.push(inten[i]);
            if k < inserts.len() && inserts[k].0 == i {
                let j = new_theta.len() - 1;
                new_theta.push(inserts[k].1);
                new_inten.push(inserts[k].2);
                next.push(j);
                next.push(j + 1);
                k += 1;
            }
        }
        theta = new_theta;
        inten = new_inten;
        candidates = next;
    }
    (theta, inten)
}

/// Forward-peak truncation (the delta-M idea of atmospheric radiative transfer): scattering by less than
/// `theta_c` — typically narrower than a pixel — is indistinguishable from no scattering, so it is folded
/// into unscattered transmission. The phase function is clipped at its value at θ_c inside the cone,
/// the clipped fraction F = ∫_{θ<θc} (f − f(θc)) dΩ is removed, and
/// `σ_s' = σ_s (1 − F)`, `σ_t' = σ_t − σ_s F`, `f' = min(f, f(θc)) / (1 − F)`; σ_a is unchanged.
/// Returns the truncated properties and F.
pub fn truncate_forward_peak(b: &Bulk, theta: &[f64], theta_c: f64) -> Result<(Bulk, f64), OpticsError> {
    require("theta_c", theta_c, theta_c.is_finite() && theta_c >= 0.0 && theta_c < PI, "finite and in [0, π)")?;
    require("phase (length)", b.phase.len() as f64, b.phase.len() == theta.len() && theta.len() >= 2, "len(theta) >= 2")?;
    // f at θc by linear interpolation on the grid.
    let i = theta.partition_point(|&t| t <= theta_c).clamp(1, theta.len() - 1);
    let (t0, t1) = (theta[i - 1], theta[i]);
    let w = ((theta_c - t0) / (t1 - t0)).clamp(0.0, 1.0);
    let f_c = b.phase[i - 1] + w * (b.phase[i] - b.phase[i - 1]);
    let clipped: Vec<f64> = b.phase.iter().zip(theta).map(|(&f, &t)| if t < theta_c { f.min(f_c.max(0.0)) } else { f }).collect();
    let wts = solid_angle_weights(theta);
    let kept: f64 = clipped.iter().zip(&wts).map(|(f, w)| f * w).sum();
    let total: f64 = b.phase.iter().zip(&wts).map(|(f, w)| f * w).sum();
    let fraction = ((total - kept) / total).clamp(0.0, 1.0);
    let phase: Vec<f64> = clipped.iter().map(|f| f / kept).collect();
    let g = phase.iter().zip(&wts).zip(theta).map(|((f, w), t)| f * w * t.cos()).sum();
    let removed = b.sigma_s * fraction;
    Ok((
        Bulk { sigma_t: b.sigma_t - removed, sigma_s: b.sigma_s - removed, sigma_a: b.sigma_a, g, phase, energy_ratio: b.energy_ratio, theta: theta.to_vec() },
        fraction,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(method: Method) -> BulkOptions {
        BulkOptions { method, goa: GoaOptions::default(), max_log_step: 0.05, refine_tol: 0.0, refine_max_nodes: 0 }
    }

    /// The monodisperse limit equals the single-particle values exactly: σ_t = N0 C_t.
    #[test]
    fn monodisperse_limit() {
        let s = Species { psd: Psd::Monodisperse { radius_um: 10.0 }, eta: C64::new(1.33, 1e-3), share: 1.0 };
        let theta = graded_angles(105.0, 200, 600);
        let b = bulk(&[s], 1e6, 0.6, 1.0, &theta, &opts(Method::Mie)).unwrap();
        let p = Particle::new(10.0, 0.6, C64::new(1.33, 1e-3), 1.0).unwrap();
        let cs = optics::cross_sections_with(&p, Theory::Mie, None, &GoaOptions::default());
        assert_eq!(b.sigma_t, 1e6 * cs.ext * 1e-12);
        assert!((b.sigma_s / (1e6 * cs.sca * 1e-12) - 1.0).abs() < 1e-12);
        // The grid integrates Mie's |S|² to its exact C_sca, and g to Mie's g.
        assert!((b.energy_ratio - 1.0).abs() < 2e-3, "{}", b.energy_ratio);
        assert!((b.g - cs.g).abs() < 2e-3, "{} vs {}", b.g, cs.g);
    }

    /// Truncation keeps σ_a, removes exactly the clipped peak from σ_s and σ_t, leaves a normalised
    /// phase function, and is the identity at θc = 0.
    #[test]
    fn truncation_conserves() {
        let s = Species { psd: Psd::Monodisperse { radius_um: 100.0 }, eta: C64::new(1.31, 1e-6), share: 1.0 };
        let theta = graded_angles(1100.0, 400, 1400);
        let b = bulk(&[s], 1e4, 0.55, 1.0, &theta, &opts(Method::Auto)).unwrap();
        let (same, f0) = truncate_forward_peak(&b, &theta, 0.0).unwrap();
        assert_eq!(f0, 0.0);
        assert!((same.sigma_t - b.sigma_t).abs() < 1e-15 * b.sigma_t);
        let (t, f) = truncate_forward_peak(&b, &theta, 0.01).unwrap();
        assert!(f > 0.3 && f < 0.7, "diffraction lobe of a 100 µm grain inside 10 mrad: {f}");
        assert_eq!(t.sigma_a, b.sigma_a);
        assert!((t.sigma_s - b.sigma_s * (1.0 - f)).abs() < 1e-12 * b.sigma_s);
        let w = solid_angle_weights(&theta);
        let norm: f64 = t.phase.iter().zip(&w).map(|(f, w)| f * w).sum();
        assert!((norm - 1.0).abs() < 1e-12);
        assert!(t.g < b.g);
    }

    /// Bulk properties are bitwise reproducible run to run (no scheduling-dependent reductions).
    #[test]
    fn bitwise_reproducible() {
        let s = Species { psd: Psd::LogNormal { median_um: 800.0, sigma_g: 4.0, r_min_um: 1e-3, r_max_um: 2000.0 }, eta: C64::new(1.31, 1e-8), share: 1.0 };
        let theta = graded_angles(2e4, 100, 300);
        let first = bulk(std::slice::from_ref(&s), 1e4, 0.55, 1.0, &theta, &opts(Method::Auto)).unwrap();
        for _ in 0..5 {
            let again = bulk(std::slice::from_ref(&s), 1e4, 0.55, 1.0, &theta, &opts(Method::Auto)).unwrap();
            assert_eq!((again.sigma_t, again.sigma_a, again.g), (first.sigma_t, first.sigma_a, first.g));
            assert_eq!(again.phase, first.phase);
        }
    }

    /// Species shares mix linearly: two species at shares c and 1 − c give the share-weighted σ's.
    #[test]
    fn species_mix_linearly() {
        let a = Species { psd: Psd::Monodisperse { radius_um: 5.0 }, eta: C64::new(1.33, 0.0), share: 3.0 };
        let b = Species { psd: Psd::Monodisperse { radius_um: 50.0 }, eta: C64::new(1.5, 0.01), share: 1.0 };
        let o = opts(Method::Auto);
        let both = bulk(&[a.clone(), b.clone()], 4e6, 0.55, 1.0, &[], &o).unwrap();
        let only_a = bulk(&[a], 3e6, 0.55, 1.0, &[], &o).unwrap();
        let only_b = bulk(&[b], 1e6, 0.55, 1.0, &[], &o).unwrap();
        assert!((both.sigma_t / (only_a.sigma_t + only_b.sigma_t) - 1.0).abs() < 1e-12);
        assert!((both.sigma_a / (only_a.sigma_a + only_b.sigma_a) - 1.0).abs() < 1e-12);
    }
}
