//! Bulk optical properties of a polydisperse, possibly multi-species particle cloud (paper Sec. 4.2,
//! Eq. 16–17; mixtures of species as in Müller et al., Sec. 5).
//!
//! For number concentration `N0` (m⁻³) split between species `s` with number shares `c_s`, each with a
//! PSD `P_s` and a relative index `m_s`:
//! * `σ_x = N0 Σ_s c_s ∫ C_x(r; m_s) dP_s(r)` for x = t, a (Eq. 16), `σ_s = σ_t − σ_a`, in m⁻¹;
//! * the ensemble phase function (Eq. 17, second line): `f(θ) ∝ N0 Σ_s c_s ∫ (|S1|²+|S2|²)/(2k²) dP_s`,
//!   normalised on the internal angle grid so that ∫ f dΩ = 1 — no per-particle normalisation is needed;
//! * `g = ∫ f cos θ dΩ` on the same grid;
//! * with [`BulkOptions::mueller`], the ensemble's Mueller ratios F12/F11, F33/F11, F34/F11: each element
//!   (Bohren & Huffman §4.4) summed like the numerator of Eq. 17, then divided ([`SpectralBulk::mueller`]).
//!
//! The normalisation, g, the energy ratio and the forward-peak truncation always come from the internal
//! grid ([`default_angles`], refined when asked); a caller's own angles ([`PhaseAngles::At`]) only choose
//! where f is reported, by exact evaluation of the amplitudes there divided by the internal-grid total,
//! so f(θ) does not depend on which other angles are asked for.
//!
//! The integrals over r use `Psd::quadrature_resolving` (atoms exactly; Gauss–Legendre in ln r, and where
//! Mie is used for 2 < x ≤ [`MIE_RIPPLE_X_MAX`] a midpoint grid [`MIE_RIPPLE_DX`] apart in x (wider ∝ x
//! above 300) that averages Mie's ripple); those Mie nodes are summed in coefficient space ([`MieIntensitySums`]). The
//! angle grid is graded: θ = 0, then log-spaced from 0.01/α_max to 0.1 rad (the diffraction lobe of
//! the largest particle, width ~1/α, gets ~25 nodes across its core), then uniform to π.

use crate::cancel;
use crate::ensemble::psd::{Psd, RippleResolution};
use crate::error::{require, require_len, require_min_len, OpticsError};
use crate::optics::goa::GoaOptions;
use crate::optics::mie::{
    mueller_elements, series_length, CoefficientSums, MieCoefficients, MieIntensitySums,
    MieMuellerSums,
};
use crate::optics::{self, GoaCache, GoaRays, Method, Particle, Theory};
use num_complex::Complex64 as C64;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::{Arc, OnceLock};

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
#[derive(Clone, Debug)]
pub struct BulkOptions {
    pub method: Method,
    pub goa: GoaOptions,
    /// Largest quadrature panel in ln r (see `Psd::quadrature`).
    pub max_log_step: f64,
    /// Largest step in size parameter of the radius quadrature where Mie amplitudes are used, for
    /// 2 < x < [`MIE_RIPPLE_X_MAX`] ([`MIE_RIPPLE_DX`] by default; 0: panels in ln r only).
    pub mie_dx: f64,
    /// Relative accuracy the tabulated phase function must reach between its nodes (0: no refinement).
    pub refine_tol: f64,
    /// Cap on the number of angles after refinement.
    pub refine_max_nodes: usize,
    /// GOA ray geometry shared with the caller's other computations (None: this computation's own).
    pub goa_cache: Option<Arc<GoaCache>>,
    /// Also the ensemble's Mueller ratios F12/F11, F33/F11, F34/F11 ([`SpectralBulk::mueller`]).
    pub mueller: bool,
}

/// Default [`BulkOptions::mie_dx`]. Mie's ripple (resonances in x = k r far narrower than a panel of
/// `max_log_step` in ln r) dominates the ensemble's side- and back-scattering: 8-node Gauss–Legendre
/// panels alias it (3–10 % errors at 180° for log-normal water droplets of r_g 1–10 µm), a uniform grid
/// in x averages it. 0.02 keeps the tables within 1 % of a 20 000-radius reference at every angle
/// (`scripts/figures/ensemble_accuracy.py`, BENCHMARKS.md "Ensemble tables: default accuracy").
pub const MIE_RIPPLE_DX: f64 = 0.02;
/// Up to this size parameter the ripple is resolved and Mie nodes are summed in coefficient space
/// ([`MieIntensitySums`], O(N²) per node); beyond, the cost of a fine grid (∝ x³) outgrows its use.
pub const MIE_RIPPLE_X_MAX: f64 = 600.0;
/// Above this size parameter the ripple grid's spacing grows ∝ x (`dx · x / MIE_RIPPLE_X_GROW`).
const MIE_RIPPLE_X_GROW: f64 = 300.0;
/// Below this size parameter the integrand is smooth (no resonances): Gauss–Legendre panels stay.
const MIE_RIPPLE_X_MIN: f64 = 2.0;
/// Panels carrying less than this share of the PSD's r²-weighted mass keep Gauss–Legendre nodes.
const MIE_RIPPLE_MIN_SHARE: f64 = 1e-6;

/// Largest size parameter below which `method` uses Mie for a particle of relative index `m`.
fn mie_size_limit(method: Method, m: C64, k: f64, p_max: u32) -> f64 {
    match method {
        Method::Mie => f64::INFINITY,
        Method::Goa => 0.0,
        Method::Hybrid { radius_um } => k * radius_um,
        Method::Auto if optics::has_axial_caustic(m, p_max) => f64::INFINITY,
        Method::Auto => optics::AUTO_SIZE_PARAMETER,
    }
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

/// The default internal grid of a bulk computation: [`graded_angles`] (400 log-spaced, 1400 uniform) for
/// the size parameter of the largest particle `r_max_um` at the shortest wavelength `lam_min_um`.
pub fn default_angles(r_max_um: f64, lam_min_um: f64, eta_medium: f64) -> Vec<f64> {
    graded_angles(2.0 * PI * eta_medium * r_max_um / lam_min_um, 400, 1400)
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

/// Checks that `theta` is strictly increasing in [0, π].
fn check_angles(theta: &[f64]) -> Result<(), OpticsError> {
    for w in theta.windows(2) {
        require("theta", w[1], w[1] > w[0], "strictly increasing")?;
    }
    if let (Some(&a), Some(&b)) = (theta.first(), theta.last()) {
        require("theta", a, a >= 0.0, ">= 0")?;
        require("theta", b, b <= PI, "<= π")?;
    }
    Ok(())
}

/// The (species, radius) quadrature nodes of a cloud at one wavelength, with the sums of Eq. 16 and the
/// un-normalised ensemble intensity of Eq. 17 at any angles.
struct Ensemble<'a> {
    nodes: Vec<(Particle, f64)>,
    opts: &'a BulkOptions,
    /// Σ w C_ext and Σ w C_abs, µm² m⁻³.
    ext: f64,
    abs: f64,
    /// The Mie nodes up to [`MIE_RIPPLE_X_MAX`], summed in coefficient space on first use.
    mie: OnceLock<Option<MieIntensitySums>>,
    /// The GOA nodes' ray geometry per relative index, shared by their radii (the caller's cache, or
    /// this ensemble's own).
    goa: Arc<GoaCache>,
}

impl<'a> Ensemble<'a> {
    /// The nodes of the ensemble, without the sums of Eq. 16 (`ext` and `abs` 0 until
    /// [`Self::with_cross_sections`]).
    fn new(
        species: &[Species],
        number_density_m3: f64,
        wavelength_um: f64,
        eta_medium: f64,
        opts: &'a BulkOptions,
    ) -> Result<Self, OpticsError> {
        let fractions = check_ensemble(species, number_density_m3, opts)?;
        let nodes = radius_nodes(
            species,
            &fractions,
            number_density_m3,
            wavelength_um,
            eta_medium,
            opts,
        )?;
        Ok(Ensemble {
            nodes,
            opts,
            ext: 0.0,
            abs: 0.0,
            mie: OnceLock::new(),
            goa: opts.goa_cache.clone().unwrap_or_default(),
        })
    }

    /// With the sums of Eq. 16 over the nodes.
    fn with_cross_sections(mut self) -> Self {
        let opts = self.opts;
        // Per-node values are computed in parallel but summed in node order, so results are bitwise
        // reproducible whatever the thread scheduling.
        let per_node: Vec<(f64, f64)> = self
            .nodes
            .par_iter()
            .map(|(p, w)| {
                if cancel::requested() {
                    return (0.0, 0.0);
                }
                let (ce, ca) = optics::extinction_and_absorption(
                    p,
                    opts.method.theory(p, opts.goa.p_max),
                    &opts.goa,
                );
                (w * ce, w * ca)
            })
            .collect();
        (self.ext, self.abs) = per_node
            .iter()
            .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        self
    }

    /// Whether a node is summed in coefficient space (Mie, x ≤ [`MIE_RIPPLE_X_MAX`]).
    fn in_sums(&self, p: &Particle) -> bool {
        p.size_parameter() <= MIE_RIPPLE_X_MAX
            && self.opts.method.theory(p, self.opts.goa.p_max) == Theory::Mie
    }

    /// `Σ w (|S1|²+|S2|²)/(2k²)` over the nodes at each angle (Eq. 17 before normalisation).
    /// Deterministic: nodes are summed in fixed chunks, in order, then the chunk sums in order (bitwise
    /// reproducible); the value at an angle does not depend on the other angles.
    fn intensity(&self, theta: &[f64]) -> Vec<f64> {
        let add =
            |a: Vec<f64>, b: Vec<f64>| a.iter().zip(&b).map(|(x, y)| x + y).collect::<Vec<f64>>();
        let direct = self.sum_direct(
            theta.len(),
            0.0,
            |x, y| x + y,
            |node, rays| {
                node_values(node, theta, self.opts, rays, 0.0, |w, k2, s1, s2| {
                    w * (s1.norm_sqr() + s2.norm_sqr()) / (2.0 * k2)
                })
            },
        );
        match self
            .mie
            .get_or_init(|| self.mie_sums(|w, k| w / (2.0 * k * k)))
        {
            Some(sums) => {
                let mie: Vec<f64> = theta.par_iter().map(|t| sums.intensity(t.cos())).collect();
                add(direct, mie)
            }
            None => direct,
        }
    }

    /// The ensemble's Mueller ratios `[F12/F11, F33/F11, F34/F11]` at each angle: the four elements
    /// ([`mueller_elements`], Bohren & Huffman §4.4) summed over the nodes with Eq. 17's weights `w/k²`
    /// (direct nodes from their amplitudes, Mie nodes up to [`MIE_RIPPLE_X_MAX`] in coefficient space,
    /// [`MieMuellerSums`]), then divided ([`mueller_ratios`]). Deterministic like [`Self::intensity`].
    fn mueller(&self, theta: &[f64]) -> Vec<[f64; 3]> {
        let mut sums = self.sum_direct(theta.len(), [0.0; 4], add4, |node, rays| {
            node_values(node, theta, self.opts, rays, [0.0; 4], |w, k2, s1, s2| {
                mueller_elements(s1, s2).map(|f| w * f / k2)
            })
        });
        if let Some(mie) = self.mie_sums::<MieMuellerSums>(|w, k| w / (k * k)) {
            let vals: Vec<[f64; 4]> = theta.par_iter().map(|t| mie.elements(t.cos())).collect();
            for (s, v) in sums.iter_mut().zip(vals) {
                *s = add4(*s, v);
            }
        }
        sums.into_iter().map(mueller_ratios).collect()
    }

    /// Σ over the nodes not summed in coefficient space of `per_node`'s values at `n` angles: fixed
    /// chunks of 16 nodes summed in order, then the chunk sums in order (bitwise reproducible).
    fn sum_direct<T: Copy + Send + Sync>(
        &self,
        n: usize,
        zero: T,
        add: fn(T, T) -> T,
        per_node: impl Fn(&(Particle, f64), Option<&GoaRays>) -> Vec<T> + Sync,
    ) -> Vec<T> {
        let add_all = |a: Vec<T>, b: Vec<T>| {
            a.iter()
                .zip(&b)
                .map(|(x, y)| add(*x, *y))
                .collect::<Vec<T>>()
        };
        let direct: Vec<&(Particle, f64)> = self
            .nodes
            .iter()
            .filter(|(p, _)| !self.in_sums(p))
            .collect();
        let chunks: Vec<Vec<T>> = direct
            .par_chunks(16)
            .map(|chunk| {
                chunk
                    .iter()
                    .map(|node| per_node(node, self.goa_rays(&node.0).as_deref()))
                    .fold(vec![zero; n], add_all)
            })
            .collect();
        chunks.into_iter().fold(vec![zero; n], add_all)
    }

    /// The shared GOA rays of a node's relative index (None for a Mie node).
    fn goa_rays(&self, p: &Particle) -> Option<Arc<GoaRays>> {
        let p_max = self.opts.goa.p_max;
        (self.opts.method.theory(p, p_max) == Theory::Goa)
            .then(|| self.goa.rays(p.relative_index(), p_max))
    }

    /// The coefficient-space sums of the Mie nodes, node weights `weight(w, k)`; 16 fixed groups
    /// summed in order (made a few at a time, as many as threads, so that at most that many groups'
    /// sums are held at once; the result does not depend on how many).
    fn mie_sums<S: CoefficientSums + Send>(
        &self,
        weight: impl Fn(f64, f64) -> f64 + Sync,
    ) -> Option<S> {
        let mie: Vec<&(Particle, f64)> =
            self.nodes.iter().filter(|(p, _)| self.in_sums(p)).collect();
        if mie.is_empty() {
            return None;
        }
        let size = |nodes: &[&(Particle, f64)]| {
            nodes
                .iter()
                .map(|(p, _)| series_length(p.size_parameter()))
                .max()
                .unwrap_or(0)
        };
        let groups: Vec<&[&(Particle, f64)]> = mie.chunks(mie.len().div_ceil(16)).collect();
        let mut total = S::with_len(size(&mie));
        for batch in groups.chunks(rayon::current_num_threads().max(1)) {
            let sums: Vec<S> = batch
                .par_iter()
                .map(|group| {
                    let mut sums = S::with_len(size(group));
                    for (p, w) in group.iter() {
                        if cancel::requested() {
                            break;
                        }
                        sums.add_sphere(
                            &MieCoefficients::new(p.size_parameter(), p.relative_index()),
                            weight(*w, p.k()),
                        );
                    }
                    sums
                })
                .collect();
            for g in &sums {
                total.merge_from(g);
            }
        }
        Some(total)
    }
}

/// Element-wise sum of two Mueller element vectors.
fn add4(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]
}

/// `[F12/F11, F33/F11, F34/F11]` of summed elements `[F11, F12, F33, F34]`, each clamped to [−1, 1]
/// (it holds for every sphere, hence for their sums, up to rounding); `[0, 1, 0]` (no polarisation
/// change) where F11 is not > 0 — no scattering at all — so never NaN.
pub fn mueller_ratios(f: [f64; 4]) -> [f64; 3] {
    if f[0] > 0.0 && f[0].is_finite() {
        [f[1], f[2], f[3]].map(|v| (v / f[0]).clamp(-1.0, 1.0))
    } else {
        [0.0, 1.0, 0.0]
    }
}

/// σ_t, σ_s, σ_a (m⁻¹) from the sums of Eq. 16.
fn coefficients(ens: &Ensemble) -> (f64, f64, f64) {
    // µm² × m⁻³ → m⁻¹.
    let (sigma_t, sigma_a) = (ens.ext * 1e-12, ens.abs * 1e-12);
    (sigma_t, (sigma_t - sigma_a).max(0.0), sigma_a)
}

/// The tabulated bulk properties on the internal grid `theta` (refined when asked), and the
/// normaliser `∫ Σ w |S|²/(2k²) dΩ` of Eq. 17 on that grid.
fn tabulate(ens: &Ensemble, theta: &[f64]) -> (Bulk, f64) {
    let (sigma_t, sigma_s, sigma_a) = coefficients(ens);
    if theta.is_empty() {
        return (
            Bulk {
                sigma_t,
                sigma_s,
                sigma_a,
                g: 0.0,
                phase: Vec::new(),
                energy_ratio: 0.0,
                theta: Vec::new(),
            },
            0.0,
        );
    }
    let base = ens.intensity(theta);
    let (theta, intensity) = refine(ens, theta.to_vec(), base);
    let wts = solid_angle_weights(&theta);
    let total: f64 = intensity.iter().zip(&wts).map(|(i, w)| i * w).sum();
    let (phase, g) = if total > 0.0 {
        let phase: Vec<f64> = intensity.iter().map(|i| i / total).collect();
        let g = phase
            .iter()
            .zip(&wts)
            .zip(&theta)
            .map(|((f, w), t)| f * w * t.cos())
            .sum();
        (phase, g)
    } else {
        (vec![1.0 / (4.0 * PI); theta.len()], 0.0)
    };
    let energy_ratio = if sigma_s > 0.0 {
        total * 1e-12 / sigma_s
    } else {
        0.0
    };
    (
        Bulk {
            sigma_t,
            sigma_s,
            sigma_a,
            g,
            phase,
            energy_ratio,
            theta,
        },
        total,
    )
}

/// Bulk properties of `species` at one wavelength, tabulated on the internal grid `theta` (strictly
/// increasing in [0, π]: use [`default_angles`]), refined when `opts.refine_tol > 0`; an empty `theta`
/// skips the phase function and g.
pub fn bulk(
    species: &[Species],
    number_density_m3: f64,
    wavelength_um: f64,
    eta_medium: f64,
    theta: &[f64],
    opts: &BulkOptions,
) -> Result<Bulk, OpticsError> {
    check_angles(theta)?;
    let ens = Ensemble::new(species, number_density_m3, wavelength_um, eta_medium, opts)?
        .with_cross_sections();
    Ok(tabulate(&ens, theta).0)
}

/// Bulk properties at one wavelength with everything that depends on the angular integral — the
/// normalisation of Eq. 17, g, the energy ratio and the forward-peak truncation at `truncate_below_rad`
/// (0: none) — measured on the internal grid `grid` (refined when asked), and the phase function
/// reported on the grid or, with `query`, at those angles by exact evaluation of the amplitudes divided
/// by the internal-grid total (truncated the same way: clipped at f(θ_c) inside the cone, divided by the
/// kept fraction). Returns the properties and the truncated fraction F.
#[allow(clippy::too_many_arguments)]
pub fn bulk_at(
    species: &[Species],
    number_density_m3: f64,
    wavelength_um: f64,
    eta_medium: f64,
    grid: &[f64],
    query: Option<&[f64]>,
    truncate_below_rad: f64,
    opts: &BulkOptions,
) -> Result<(Bulk, f64), OpticsError> {
    check_angles(grid)?;
    if let Some(q) = query {
        check_angles(q)?;
    }
    let ens = Ensemble::new(species, number_density_m3, wavelength_um, eta_medium, opts)?
        .with_cross_sections();
    let (b, total) = tabulate(&ens, grid);
    let (b, cut) = if truncate_below_rad > 0.0 && !b.theta.is_empty() {
        let cut = Truncation::measure(&b, &b.theta, truncate_below_rad)?;
        (cut.apply_to(&b, &b.theta), Some(cut))
    } else {
        (b, None)
    };
    let fraction = cut.map_or(0.0, |c| c.fraction);
    let Some(q) = query.filter(|_| !b.theta.is_empty()) else {
        return Ok((b, fraction));
    };
    let phase: Vec<f64> = if total > 0.0 {
        ens.intensity(q)
            .iter()
            .zip(q)
            .map(|(i, &t)| cut.map_or(i / total, |c| c.apply(t, i / total)))
            .collect()
    } else {
        vec![1.0 / (4.0 * PI); q.len()]
    };
    Ok((
        Bulk {
            phase,
            theta: q.to_vec(),
            ..b
        },
        fraction,
    ))
}

/// Where a bulk computation reports the phase function.
#[derive(Clone, Copy, Debug)]
pub enum PhaseAngles<'a> {
    /// No phase function (and no g).
    None,
    /// On the internal grid ([`default_angles`], refined when asked).
    Table,
    /// At these angles (strictly increasing in [0, π]).
    At(&'a [f64]),
}

/// Bulk properties at several wavelengths, the phase functions on one common angle grid.
#[derive(Clone, Debug)]
pub struct SpectralBulk {
    /// One per wavelength (each with its own internal `theta` and `phase` when refined, or the query).
    pub bulk: Vec<Bulk>,
    /// The truncated fraction F per wavelength (0 without truncation).
    pub peak_fraction: Vec<f64>,
    /// The common angle grid: the query, the internal grid, or the union of the refined grids.
    pub theta: Vec<f64>,
    /// f(θ) per wavelength on `theta`, sr⁻¹.
    pub phase: Vec<Vec<f64>>,
    /// With [`BulkOptions::mueller`]: per wavelength, at each angle of `theta`, the ensemble's Mueller
    /// ratios `[F12/F11, F33/F11, F34/F11]` (Bohren & Huffman §4.4; Eq. 17's weighted sums over the radius
    /// nodes, divided; [`mueller_ratios`]), evaluated exactly at those angles. They are those of the
    /// untruncated ensemble: forward-peak truncation clips F11 only. Empty otherwise.
    pub mueller: Vec<Vec<[f64; 3]>>,
}

/// [`bulk_at`] at each wavelength `wavelength_um[j]` with the species `species[j]` (the same PSDs and
/// shares, the indices at that wavelength). The internal grid is [`default_angles`] for the largest
/// particle at the shortest wavelength. Without a query, refined grids that differ between wavelengths
/// are merged and every phase function is resampled (linear in μ) onto the union.
pub fn bulk_spectral(
    species: &[Vec<Species>],
    number_density_m3: f64,
    wavelength_um: &[f64],
    eta_medium: f64,
    angles: PhaseAngles,
    truncate_below_rad: f64,
    opts: &BulkOptions,
) -> Result<SpectralBulk, OpticsError> {
    require_len(
        "species (wavelengths)",
        species.len(),
        wavelength_um.len(),
        "one list per wavelength",
    )?;
    for &l in wavelength_um {
        require(
            "wavelength_um",
            l,
            l.is_finite() && l > 0.0,
            "finite and > 0",
        )?;
    }
    require(
        "truncate_below_rad",
        truncate_below_rad,
        truncate_below_rad.is_finite() && (0.0..PI).contains(&truncate_below_rad),
        "finite and in [0, π)",
    )?;
    let grid = match angles {
        PhaseAngles::None => Vec::new(),
        _ => {
            let r_max = species
                .iter()
                .flatten()
                .map(|s| s.psd.support().1)
                .fold(0.0, f64::max);
            let lam_min = wavelength_um.iter().cloned().fold(f64::INFINITY, f64::min);
            default_angles(r_max, lam_min, eta_medium)
        }
    };
    let query = match angles {
        PhaseAngles::At(q) => Some(q),
        _ => None,
    };
    let results = wavelength_um
        .iter()
        .zip(species)
        .map(|(&l, s)| {
            bulk_at(
                s,
                number_density_m3,
                l,
                eta_medium,
                &grid,
                query,
                truncate_below_rad,
                opts,
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let (bulk, peak_fraction): (Vec<Bulk>, Vec<f64>) = results.into_iter().unzip();
    let (theta, phase) = on_union_grid(&bulk);
    // The Mueller ratios once the common grid is known, exactly at its angles; each wavelength's nodes
    // again (without their cross sections), one wavelength at a time.
    let mueller = if opts.mueller {
        wavelength_um
            .iter()
            .zip(species)
            .map(|(&l, s)| {
                let ens = Ensemble::new(s, number_density_m3, l, eta_medium, opts)?;
                Ok(ens.mueller(&theta))
            })
            .collect::<Result<Vec<_>, OpticsError>>()?
    } else {
        Vec::new()
    };
    Ok(SpectralBulk {
        bulk,
        peak_fraction,
        theta,
        phase,
        mueller,
    })
}

/// The wavelengths' phase tables on one angle grid: their common grid, or else the union of their
/// grids with each table resampled linearly in μ (exact at its own nodes).
fn on_union_grid(bulk: &[Bulk]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let theta: Vec<f64> = if bulk.iter().all(|b| b.theta == bulk[0].theta) {
        bulk.first().map(|b| b.theta.clone()).unwrap_or_default()
    } else {
        let mut u: Vec<f64> = bulk.iter().flat_map(|b| b.theta.iter().copied()).collect();
        u.sort_by(f64::total_cmp);
        u.dedup();
        u
    };
    let phase = bulk
        .iter()
        .map(|b| {
            if b.theta == theta {
                b.phase.clone()
            } else {
                resample_linear_mu(&b.theta, &b.phase, &theta)
            }
        })
        .collect();
    (theta, phase)
}

/// Linear-in-μ interpolation of (theta, f) onto `target` (both increasing in θ).
fn resample_linear_mu(theta: &[f64], f: &[f64], target: &[f64]) -> Vec<f64> {
    target
        .iter()
        .map(|&t| {
            let i = theta.partition_point(|&x| x <= t).clamp(1, theta.len() - 1);
            let (m0, m1, m) = (theta[i - 1].cos(), theta[i].cos(), t.cos());
            let w = if m1 != m0 {
                ((m - m0) / (m1 - m0)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            f[i - 1] + w * (f[i] - f[i - 1])
        })
        .collect()
}

/// `value(w, k², S1, S2)` of one node `(p, w)` at every angle (`zero` everywhere once cancelled).
fn node_values<T: Clone>(
    (p, w): &(Particle, f64),
    theta: &[f64],
    opts: &BulkOptions,
    rays: Option<&GoaRays>,
    zero: T,
    value: impl Fn(f64, f64, C64, C64) -> T,
) -> Vec<T> {
    if cancel::requested() {
        return vec![zero; theta.len()];
    }
    let theory = opts.method.theory(p, opts.goa.p_max);
    let k2 = p.k() * p.k();
    optics::particle_amplitudes(p, theory, rays, theta, &opts.goa)
        .into_iter()
        .map(|(s1, s2)| value(*w, k2, s1, s2))
        .collect()
}

/// The checks of an ensemble's inputs; returns each species' fraction of the particles.
fn check_ensemble(
    species: &[Species],
    number_density_m3: f64,
    opts: &BulkOptions,
) -> Result<Vec<f64>, OpticsError> {
    require(
        "number_density_m3",
        number_density_m3,
        number_density_m3.is_finite() && number_density_m3 >= 0.0,
        "finite and >= 0",
    )?;
    require_min_len("species (count)", species.len(), 1, ">= 1")?;
    require(
        "mie_dx",
        opts.mie_dx,
        opts.mie_dx.is_finite() && opts.mie_dx >= 0.0,
        "finite and >= 0",
    )?;
    for s in species {
        require(
            "share",
            s.share,
            s.share.is_finite() && s.share >= 0.0,
            "finite and >= 0",
        )?;
        s.psd.validate()?;
    }
    let largest = species.iter().map(|s| s.share).fold(0.0, f64::max);
    require(
        "share",
        largest,
        largest > 0.0,
        "> 0 for at least one species",
    )?;
    Ok(super::share_fractions(
        &species.iter().map(|s| s.share).collect::<Vec<_>>(),
    ))
}

/// Every (species, radius node) with its number weight per m³ (Eq. 16–17's radius integral), the
/// ripple in x resolved where the species is computed by Mie.
fn radius_nodes(
    species: &[Species],
    fractions: &[f64],
    number_density_m3: f64,
    wavelength_um: f64,
    eta_medium: f64,
    opts: &BulkOptions,
) -> Result<Vec<(Particle, f64)>, OpticsError> {
    let k = 2.0 * PI * eta_medium / wavelength_um;
    let mut nodes: Vec<(Particle, f64)> = Vec::new();
    for (s, fraction) in species.iter().zip(fractions) {
        let ripple = RippleResolution {
            wavenumber_per_um: k,
            dx: opts.mie_dx,
            x_grow: MIE_RIPPLE_X_GROW,
            x_min: MIE_RIPPLE_X_MIN,
            x_max: mie_size_limit(opts.method, s.eta / eta_medium, k, opts.goa.p_max)
                .min(MIE_RIPPLE_X_MAX),
            min_share: MIE_RIPPLE_MIN_SHARE,
        };
        let (r, w) = s.psd.quadrature_resolving(opts.max_log_step, Some(&ripple));
        for (ri, wi) in r.into_iter().zip(w) {
            if wi > 0.0 {
                nodes.push((
                    Particle::new(ri, wavelength_um, s.eta, eta_medium)?,
                    number_density_m3 * fraction * wi,
                ));
            }
        }
    }
    Ok(nodes)
}

/// Adaptive refinement of the angle grid (when `opts.refine_tol > 0`): the table is piecewise linear in
/// μ = cos θ, so at the μ-midpoint of an interval it predicts the mean of the two ends. Every interval's
/// midpoint is evaluated and inserted where the table would be off by more
/// than `refine_tol` (relative) and f > 1e-6 max, or where the misprediction moves more than 1e-5 of the
/// total probability. Repeats on the new intervals, up to `refine_max_nodes`.
/// The result stays a piecewise-linear table, so sampling remains exactly consistent with evaluation.
fn refine(ens: &Ensemble, mut theta: Vec<f64>, mut inten: Vec<f64>) -> (Vec<f64>, Vec<f64>) {
    let opts = ens.opts;
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
    let total: f64 = inten
        .iter()
        .zip(solid_angle_weights(&theta))
        .map(|(f, w)| f * w)
        .sum();
    let mass_floor = MASS_TOL * total;
    // First pass: every interval is a candidate (a feature may lie entirely between two nodes, where
    // no curvature test on the nodes can see it); later passes only the halves of refined intervals.
    let mut candidates: Vec<usize> = (0..theta.len() - 1).collect();
    for _pass in 0..40 {
        if candidates.is_empty() || theta.len() >= opts.refine_max_nodes || cancel::requested() {
            break;
        }
        candidates.truncate(opts.refine_max_nodes - theta.len());
        let mids: Vec<f64> = candidates
            .iter()
            .map(|&i| {
                ((mu(theta[i]) + mu(theta[i + 1])) * 0.5)
                    .clamp(-1.0, 1.0)
                    .acos()
            })
            .collect();
        let vals = ens.intensity(&mids);
        // Insert where the linear table is off; the new intervals on both sides become candidates.
        let mut inserts: Vec<(usize, f64, f64)> = Vec::new();
        for ((&i, &t), &v) in candidates.iter().zip(&mids).zip(&vals) {
            let predicted = 0.5 * (inten[i] + inten[i + 1]);
            let relative =
                v.max(predicted) > floor && (predicted - v).abs() > opts.refine_tol * v.max(floor);
            let mass = (predicted - v).abs() * 2.0 * PI * (mu(theta[i]) - mu(theta[i + 1])).abs()
                > mass_floor;
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
/// Measured once on a table ([`Truncation::measure`]), it applies at any angle ([`Truncation::apply`]).
#[derive(Clone, Copy, Debug)]
pub struct Truncation {
    pub theta_c: f64,
    /// f(θ_c) of the table (linear interpolation between its nodes), the clipping level.
    pub f_c: f64,
    /// ∫ min(f, f_c) dΩ on the table: what f' is divided by (1 − F for a normalised table).
    pub kept: f64,
    /// The truncated fraction F.
    pub fraction: f64,
}

impl Truncation {
    /// Measures the truncation at `theta_c` on the table `b.phase` at the nodes `theta`.
    pub fn measure(b: &Bulk, theta: &[f64], theta_c: f64) -> Result<Self, OpticsError> {
        require(
            "theta_c",
            theta_c,
            (0.0..PI).contains(&theta_c),
            "finite and in [0, π)",
        )?;
        require(
            "phase (length)",
            b.phase.len() as f64,
            b.phase.len() == theta.len() && theta.len() >= 2,
            "len(theta) >= 2",
        )?;
        // f at θc by linear interpolation on the grid.
        let i = theta
            .partition_point(|&t| t <= theta_c)
            .clamp(1, theta.len() - 1);
        let (t0, t1) = (theta[i - 1], theta[i]);
        let w = ((theta_c - t0) / (t1 - t0)).clamp(0.0, 1.0);
        let f_c = (b.phase[i - 1] + w * (b.phase[i] - b.phase[i - 1])).max(0.0);
        let wts = solid_angle_weights(theta);
        let clip = |f: f64, t: f64| if t < theta_c { f.min(f_c) } else { f };
        let kept: f64 = b
            .phase
            .iter()
            .zip(theta)
            .zip(&wts)
            .map(|((&f, &t), w)| clip(f, t) * w)
            .sum();
        let total: f64 = b.phase.iter().zip(&wts).map(|(f, w)| f * w).sum();
        let fraction = ((total - kept) / total).clamp(0.0, 1.0);
        Ok(Truncation {
            theta_c,
            f_c,
            kept,
            fraction,
        })
    }

    /// The truncated phase function f' at angle `theta` from the untruncated value `f` there.
    pub fn apply(&self, theta: f64, f: f64) -> f64 {
        (if theta < self.theta_c {
            f.min(self.f_c)
        } else {
            f
        }) / self.kept
    }

    /// The truncated properties of the table `b` at the nodes `theta`: f' there, g of f', and σ_s, σ_t
    /// without the fraction F (σ_a unchanged).
    pub fn apply_to(&self, b: &Bulk, theta: &[f64]) -> Bulk {
        let phase: Vec<f64> = b
            .phase
            .iter()
            .zip(theta)
            .map(|(&f, &t)| self.apply(t, f))
            .collect();
        let wts = solid_angle_weights(theta);
        let g = phase
            .iter()
            .zip(&wts)
            .zip(theta)
            .map(|((f, w), t)| f * w * t.cos())
            .sum();
        let removed = b.sigma_s * self.fraction;
        Bulk {
            sigma_t: b.sigma_t - removed,
            sigma_s: b.sigma_s - removed,
            sigma_a: b.sigma_a,
            g,
            phase,
            energy_ratio: b.energy_ratio,
            theta: theta.to_vec(),
        }
    }
}

/// [`Truncation`] at `theta_c` of the table `b` on the nodes `theta`: the truncated properties and F.
pub fn truncate_forward_peak(
    b: &Bulk,
    theta: &[f64],
    theta_c: f64,
) -> Result<(Bulk, f64), OpticsError> {
    let cut = Truncation::measure(b, theta, theta_c)?;
    Ok((cut.apply_to(b, theta), cut.fraction))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(method: Method) -> BulkOptions {
        BulkOptions {
            method,
            goa: GoaOptions::default(),
            max_log_step: 0.05,
            mie_dx: MIE_RIPPLE_DX,
            refine_tol: 0.0,
            refine_max_nodes: 0,
            goa_cache: None,
            mueller: false,
        }
    }

    /// A species of one radius `radius_um` with index `eta`, in the given share.
    fn monodisperse(radius_um: f64, eta: C64, share: f64) -> Species {
        Species {
            psd: Psd::Monodisperse { radius_um },
            eta,
            share,
        }
    }

    /// The monodisperse limit equals the single-particle values exactly: σ_t = N0 C_t.
    #[test]
    fn monodisperse_limit() {
        let s = monodisperse(10.0, C64::new(1.33, 1e-3), 1.0);
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
        let s = monodisperse(100.0, C64::new(1.31, 1e-6), 1.0);
        let theta = graded_angles(1100.0, 400, 1400);
        let b = bulk(&[s], 1e4, 0.55, 1.0, &theta, &opts(Method::Auto)).unwrap();
        let (same, f0) = truncate_forward_peak(&b, &theta, 0.0).unwrap();
        assert_eq!(f0, 0.0);
        assert!((same.sigma_t - b.sigma_t).abs() < 1e-15 * b.sigma_t);
        let (t, f) = truncate_forward_peak(&b, &theta, 0.01).unwrap();
        assert!(
            f > 0.3 && f < 0.7,
            "diffraction lobe of a 100 µm grain inside 10 mrad: {f}"
        );
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
        let s = [Species {
            psd: Psd::LogNormal {
                median_um: 800.0,
                sigma_g: 4.0,
                r_min_um: 1e-3,
                r_max_um: 2000.0,
            },
            eta: C64::new(1.31, 1e-8),
            share: 1.0,
        }];
        let theta = graded_angles(2e4, 100, 300);
        let run = || bulk(&s, 1e4, 0.55, 1.0, &theta, &opts(Method::Auto)).unwrap();
        let first = run();
        for _ in 0..5 {
            let again = run();
            assert_eq!(
                (again.sigma_t, again.sigma_a, again.g),
                (first.sigma_t, first.sigma_a, first.g)
            );
            assert_eq!(again.phase, first.phase);
        }
    }

    /// Species shares mix linearly: two species at shares c and 1 − c give the share-weighted σ's.
    #[test]
    fn species_mix_linearly() {
        let a = monodisperse(5.0, C64::new(1.33, 0.0), 3.0);
        let b = monodisperse(50.0, C64::new(1.5, 0.01), 1.0);
        let o = opts(Method::Auto);
        let both = bulk(&[a.clone(), b.clone()], 4e6, 0.55, 1.0, &[], &o).unwrap();
        let only_a = bulk(&[a], 3e6, 0.55, 1.0, &[], &o).unwrap();
        let only_b = bulk(&[b], 1e6, 0.55, 1.0, &[], &o).unwrap();
        assert!((both.sigma_t / (only_a.sigma_t + only_b.sigma_t) - 1.0).abs() < 1e-12);
        assert!((both.sigma_a / (only_a.sigma_a + only_b.sigma_a) - 1.0).abs() < 1e-12);
    }
}
