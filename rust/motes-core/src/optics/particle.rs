//! One particle as a renderer needs it — cross sections (Eq. 2–3, 12–13, 28–29), the normalised phase
//! function `f_p` (Eq. 1) and the asymmetry g — computed by Lorenz–Mie, GOA, or a hybrid of the two,
//! batched over many particles and angles (rayon inside; no Python here).

use crate::cancel;
use crate::error::{require, OpticsError};
use crate::optics::goa::{self, GoaGeometry, GoaOptions};
use crate::optics::mie::{mueller_elements, MieCoefficients};
use crate::quadrature::gauss_legendre;
use num_complex::Complex64 as C64;
use rayon::prelude::*;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex};

/// Size parameter above which `Method::Auto` uses GOA. Chosen from the measured GOA-vs-Mie error of
/// `scripts/figures/hybrid_threshold.py` (BENCHMARKS.md, "auto policy"): above it the RelMSE of
/// (|S1|+|S2|)/2 stays below 1e-2 for every tested index, and Mie costs grow linearly with x.
pub const AUTO_SIZE_PARAMETER: f64 = 60.0;

/// `Method::Auto` also uses Mie (at any size) when an axial ray is degenerate, `|2p/η_r − 2| <` this for
/// some order p: there dθ_p/dθi vanishes on the axis (η = 2 focuses light on the back of the sphere, a
/// retro-reflecting ball lens; η → 1 makes the p = 1 ray go straight through). GOA's caustic then grows
/// like α² where Mie's grows like α^{3/2}; the measured window (`scripts/figures/hybrid_threshold.py`) is
/// |4/η − 2| ≲ 0.005 at x = 400..6400.
pub const AXIAL_CAUSTIC_WINDOW: f64 = 0.01;

/// True when some order p ≤ max(p_max, 2) has a degenerate axial ray (see [`AXIAL_CAUSTIC_WINDOW`]).
pub fn has_axial_caustic(m: C64, p_max: u32) -> bool {
    (1..=p_max.max(2)).any(|p| (2.0 * p as f64 / m.re - 2.0).abs() < AXIAL_CAUSTIC_WINDOW)
}

/// Default radius threshold of `Method::Hybrid` (the paper's 2 µm, Sec. 3.3).
pub const HYBRID_RADIUS_UM: f64 = 2.0;

/// Largest size parameter accepted (r = 2000 µm at λ = 0.38 µm in water is x ≈ 4.4e4).
pub const MAX_SIZE_PARAMETER: f64 = 1.0e5;

/// A homogeneous sphere in a non-absorbing host.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Particle {
    /// Radius, µm.
    pub radius_um: f64,
    /// Vacuum wavelength, µm.
    pub wavelength_um: f64,
    /// Complex refractive index of the particle `η_r + i η_i` (η_i ≥ 0 absorbs).
    pub eta: C64,
    /// Real refractive index of the host medium.
    pub eta_medium: f64,
}

impl Particle {
    pub fn new(
        radius_um: f64,
        wavelength_um: f64,
        eta: C64,
        eta_medium: f64,
    ) -> Result<Self, OpticsError> {
        require(
            "radius_um",
            radius_um,
            radius_um.is_finite() && radius_um > 0.0,
            "finite and > 0",
        )?;
        require(
            "wavelength_um",
            wavelength_um,
            wavelength_um.is_finite() && wavelength_um > 0.0,
            "finite and > 0",
        )?;
        require(
            "eta (real part)",
            eta.re,
            eta.re.is_finite() && eta.re > 0.0,
            "finite and > 0",
        )?;
        require(
            "eta (imaginary part)",
            eta.im,
            eta.im.is_finite() && eta.im >= 0.0,
            "finite and >= 0",
        )?;
        require(
            "eta_medium",
            eta_medium,
            eta_medium.is_finite() && eta_medium > 0.0,
            "finite and > 0",
        )?;
        let p = Particle {
            radius_um,
            wavelength_um,
            eta,
            eta_medium,
        };
        let x = p.size_parameter();
        require(
            "radius_um / wavelength_um",
            x,
            x <= MAX_SIZE_PARAMETER,
            "a size parameter 2π η_m r/λ <= 1e5",
        )?;
        Ok(p)
    }

    /// Wave number in the host, µm⁻¹.
    pub fn k(&self) -> f64 {
        2.0 * PI * self.eta_medium / self.wavelength_um
    }

    /// Size parameter α = k r.
    pub fn size_parameter(&self) -> f64 {
        self.k() * self.radius_um
    }

    /// Relative index m = η / η_m.
    pub fn relative_index(&self) -> C64 {
        self.eta / self.eta_medium
    }
}

/// How single-particle optics are computed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// Lorenz–Mie theory (exact).
    Mie,
    /// Geometrical optics approximation.
    Goa,
    /// Mie below `radius_um`, GOA at and above (the paper's policy, 2 µm).
    Hybrid { radius_um: f64 },
    /// Mie below the size parameter [`AUTO_SIZE_PARAMETER`] or near a degenerate axial ray
    /// ([`has_axial_caustic`]), GOA otherwise.
    Auto,
}

/// The concrete theory used for one particle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Theory {
    Mie,
    Goa,
}

impl Method {
    pub fn parse(name: &str, hybrid_radius_um: f64) -> Result<Self, OpticsError> {
        match name {
            "mie" => Ok(Method::Mie),
            "goa" => Ok(Method::Goa),
            "auto" => Ok(Method::Auto),
            "hybrid" => {
                require(
                    "hybrid_radius_um",
                    hybrid_radius_um,
                    hybrid_radius_um.is_finite() && hybrid_radius_um >= 0.0,
                    "finite and >= 0",
                )?;
                Ok(Method::Hybrid {
                    radius_um: hybrid_radius_um,
                })
            }
            other => Err(OpticsError::InvalidOption {
                argument: "method",
                value: other.to_string(),
                allowed: "\"auto\", \"mie\", \"goa\", \"hybrid\"",
            }),
        }
    }

    pub fn theory(&self, p: &Particle, p_max: u32) -> Theory {
        match *self {
            Method::Mie => Theory::Mie,
            Method::Goa => Theory::Goa,
            Method::Hybrid { radius_um } => {
                if p.radius_um < radius_um {
                    Theory::Mie
                } else {
                    Theory::Goa
                }
            }
            Method::Auto => {
                if p.size_parameter() < AUTO_SIZE_PARAMETER
                    || has_axial_caustic(p.relative_index(), p_max)
                {
                    Theory::Mie
                } else {
                    Theory::Goa
                }
            }
        }
    }
}

/// Cross sections in µm² and the asymmetry parameter.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CrossSections {
    pub ext: f64,
    pub sca: f64,
    pub abs: f64,
    pub g: f64,
}

/// A GOA ray geometry (size independent: Eq. 4–10 depend on the relative index and the order only)
/// together with the rays it has prepared at the angle grids asked of it so far, so that every radius of
/// a batch or of an ensemble shares both. Owned by the computation that builds it (one batch call, one
/// [`crate::ensemble`] wavelength); nothing is kept process-wide. The memo is a small LRU bounded in
/// bytes.
pub struct GoaRays {
    pub geometry: GoaGeometry,
    prepared: Mutex<Vec<(PreparedKey, Arc<goa::PreparedAngles>)>>,
}

/// (p_max, hash of the angle array, its length): a hit is confirmed by comparing the arrays.
type PreparedKey = (u32, u64, usize);

impl GoaRays {
    /// Prepared angle grids kept.
    const PREPARED_ENTRIES: usize = 32;
    /// A prepared grid larger than this is not kept.
    const MAX_BYTES_PER_ENTRY: usize = 64 << 20;
    /// Bytes of prepared grids kept in all (the oldest go first).
    const MAX_BYTES: usize = 256 << 20;

    pub fn new(m: C64, p_max: u32) -> Self {
        GoaRays {
            geometry: GoaGeometry::new(m, p_max),
            prepared: Mutex::new(Vec::new()),
        }
    }

    fn key(p_max: u32, theta: &[f64]) -> PreparedKey {
        // A fast multiplicative hash (FxHash-style).
        let mut h: u64 = 0;
        for t in theta {
            h = (h.rotate_left(5) ^ t.to_bits()).wrapping_mul(0x517c_c1b7_2722_0a95);
        }
        (p_max, h, theta.len())
    }

    /// Approximate heap bytes of the prepared angle grids in the memo.
    pub fn prepared_bytes(&self) -> usize {
        let c = self.prepared.lock().unwrap_or_else(|e| e.into_inner());
        c.iter().map(|(_, p)| p.bytes()).sum()
    }

    /// The rays leaving at `theta` (orders ≤ `p_max`), from the memo or computed (and kept if small enough).
    pub fn prepared(&self, theta: &[f64], p_max: u32) -> Arc<goa::PreparedAngles> {
        let k = Self::key(p_max, theta);
        {
            let mut c = self.prepared.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(pos) = c.iter().position(|(kk, v)| *kk == k && v.theta == theta) {
                let entry = c.remove(pos);
                let v = entry.1.clone();
                c.push(entry);
                return v;
            }
        }
        let v = Arc::new(self.geometry.prepare(theta, p_max));
        if v.bytes() <= Self::MAX_BYTES_PER_ENTRY {
            let mut c = self.prepared.lock().unwrap_or_else(|e| e.into_inner());
            c.push((k, v.clone()));
            while c.len() > Self::PREPARED_ENTRIES
                || c.iter().map(|(_, p)| p.bytes()).sum::<usize>() > Self::MAX_BYTES
            {
                c.remove(0);
            }
        }
        v
    }
}

/// The [`GoaRays`] of each relative index, for a caller that runs several computations over the same
/// materials (a medium's optics: one bulk computation per size bin; the binding's free functions: one
/// call after another) and wants them to share the ray geometry and its prepared angle grids. Owned by
/// that caller and dropped with it. [`GoaCache::bounded`] keeps only the most recently used indices.
#[derive(Default)]
pub struct GoaCache {
    rays: Mutex<CacheEntries>,
    /// Most relative indices kept (least recently used dropped first); `None`: all.
    capacity: Option<usize>,
}

/// The cache's entries by (Re m, Im m, p_max), each with the tick of its last use.
type CacheEntries = HashMap<(u64, u64, u32), (Arc<GoaRays>, u64)>;

impl GoaCache {
    pub fn new() -> Self {
        Self::default()
    }

    /// A cache that keeps at most `capacity` (≥ 1) relative indices, dropping the least recently used.
    pub fn bounded(capacity: usize) -> Self {
        GoaCache {
            rays: Mutex::default(),
            capacity: Some(capacity.max(1)),
        }
    }

    /// The rays of relative index `m` up to order `p_max` (made on first use).
    pub fn rays(&self, m: C64, p_max: u32) -> Arc<GoaRays> {
        let key = (m.re.to_bits(), m.im.to_bits(), p_max);
        {
            let mut c = self.lock();
            let tick = Self::next_tick(&c);
            if let Some((r, used)) = c.get_mut(&key) {
                *used = tick;
                return r.clone();
            }
        }
        // Made outside the lock (it may take a while); a concurrent first use keeps the first one.
        let made = Arc::new(GoaRays::new(m, p_max));
        let mut c = self.lock();
        let tick = Self::next_tick(&c);
        let kept = c.entry(key).or_insert((made, tick)).0.clone();
        if let Some(cap) = self.capacity {
            while c.len() > cap {
                let oldest = *c.iter().min_by_key(|(_, (_, used))| *used).unwrap().0;
                c.remove(&oldest);
            }
        }
        kept
    }

    /// How many relative indices it holds.
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Drop every entry (the memory they hold is freed once no computation uses them).
    pub fn clear(&self) {
        self.lock().clear();
    }

    /// Approximate heap bytes of the prepared angle grids it holds.
    pub fn bytes(&self) -> usize {
        self.lock().values().map(|(r, _)| r.prepared_bytes()).sum()
    }

    fn next_tick(c: &CacheEntries) -> u64 {
        c.values().map(|(_, used)| *used).max().unwrap_or(0) + 1
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, CacheEntries> {
        self.rays.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl std::fmt::Debug for GoaCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GoaCache({} indices)", self.len())
    }
}

/// Quadrature nodes and weights (in θ, including 2π sin θ) for the GOA angular integrals: composite
/// 8-point Gauss–Legendre on `2·half_panels` equal panels over [0, π], so that a panel edge sits at π/2
/// where Eq. 11 switches diffraction off. `half_panels` is a power of two ≥ α, so every ray-interference
/// fringe (period ≳ π/α) and the diffraction lobe (first zero 3.83/α) get several nodes, and radii of
/// similar size share a node set (and the prepared rays of their [`GoaRays`]).
fn goa_quadrature(alpha: f64) -> (Vec<f64>, Vec<f64>) {
    let (x, w) = gauss_legendre(8);
    let half_panels = (alpha.ceil() as usize).max(64).next_power_of_two();
    let h = 0.5 * PI / half_panels as f64;
    let mut nodes = Vec::with_capacity(16 * half_panels);
    let mut weights = Vec::with_capacity(16 * half_panels);
    for k in 0..2 * half_panels {
        let a = k as f64 * h;
        for (xi, wi) in x.iter().zip(&w) {
            let t = a + 0.5 * h * (1.0 + xi);
            nodes.push(t);
            weights.push(0.5 * h * wi * 2.0 * PI * t.sin());
        }
    }
    (nodes, weights)
}

/// GOA angular integrals `(∫ (|S1|²+|S2|²) dΩ, ∫ (|S1|²+|S2|²) cosθ dΩ)`.
/// Small grids go through the prepared rays of `rays` (shared by radii of similar size); large ones
/// (α ≳ 4000, up to ~5e5 nodes) are streamed node by node so that memory stays bounded.
pub fn goa_angular_integrals(rays: &GoaRays, alpha: f64, opts: &GoaOptions) -> (f64, f64) {
    const CACHED_NODES: usize = 1 << 16;
    let (nodes, weights) = goa_quadrature(alpha);
    let moments = |(s1, s2): (C64, C64), t: f64, w: f64| {
        let v = (s1.norm_sqr() + s2.norm_sqr()) * w;
        (v, v * t.cos())
    };
    let add = |a: (f64, f64), b: (f64, f64)| (a.0 + b.0, a.1 + b.1);
    if nodes.len() <= CACHED_NODES {
        let prepared = rays.prepared(&nodes, opts.p_max);
        let amps = goa::evaluate_prepared(rays.geometry.m, &prepared, alpha, opts);
        amps.iter()
            .zip(nodes.iter().zip(&weights))
            .map(|(a, (t, w))| moments(*a, *t, *w))
            .fold((0.0, 0.0), add)
    } else {
        // Fixed chunks summed in order: bitwise reproducible whatever the thread scheduling.
        let idx: Vec<usize> = (0..nodes.len()).collect();
        idx.par_chunks(1024)
            .map(|chunk| {
                if cancel::requested() {
                    return (0.0, 0.0);
                }
                let mut scratch = Vec::new();
                chunk
                    .iter()
                    .map(|&i| {
                        moments(
                            rays.geometry
                                .amplitudes(alpha, nodes[i], opts, &mut scratch),
                            nodes[i],
                            weights[i],
                        )
                    })
                    .fold((0.0, 0.0), add)
            })
            .collect::<Vec<_>>()
            .into_iter()
            .fold((0.0, 0.0), add)
    }
}

/// (S1, S2) of one particle at the angles `theta` with the given theory.
pub fn particle_amplitudes(
    p: &Particle,
    theory: Theory,
    rays: Option<&GoaRays>,
    theta: &[f64],
    opts: &GoaOptions,
) -> Vec<(C64, C64)> {
    let alpha = p.size_parameter();
    match (theory, rays) {
        (Theory::Goa, Some(rays)) => goa::evaluate_prepared(
            rays.geometry.m,
            &rays.prepared(theta, opts.p_max),
            alpha,
            opts,
        ),
        (Theory::Goa, None) => {
            let geo = GoaGeometry::new(p.relative_index(), opts.p_max);
            goa::evaluate_prepared(geo.m, &geo.prepare(theta, opts.p_max), alpha, opts)
        }
        (Theory::Mie, _) => MieCoefficients::new(alpha, p.relative_index())
            .weighted()
            .amplitudes_many(theta),
    }
}

/// `∫ (|S1|²+|S2|²) dΩ`, the normaliser of f_p (Eq. 1): `2π x² Q_sca` for Mie (exact), the
/// quadrature of `goa_angular_integrals` for GOA (so that ∫ f dΩ = 1 whatever p_max keeps).
fn phase_normaliser(
    p: &Particle,
    theory: Theory,
    rays: Option<&GoaRays>,
    opts: &GoaOptions,
) -> f64 {
    let alpha = p.size_parameter();
    match (theory, rays) {
        (Theory::Mie, _) => {
            2.0 * PI * alpha * alpha * MieCoefficients::new(alpha, p.relative_index()).q_sca()
        }
        (Theory::Goa, Some(rays)) => goa_angular_integrals(rays, alpha, opts).0,
        (Theory::Goa, None) => {
            goa_angular_integrals(&GoaRays::new(p.relative_index(), opts.p_max), alpha, opts).0
        }
    }
}

/// `(C_ext, C_abs)` in µm² without the asymmetry parameter — cheap for GOA (Eq. 12 and the
/// geometric absorption integral, no angular quadrature).
pub fn extinction_and_absorption(p: &Particle, theory: Theory, opts: &GoaOptions) -> (f64, f64) {
    match theory {
        Theory::Mie => {
            let (_, [ext, _, abs]) = mie_cross_sections(p);
            (ext, abs)
        }
        Theory::Goa => {
            let area = PI * p.radius_um * p.radius_um;
            let (m, alpha) = (p.relative_index(), p.size_parameter());
            let qa = goa::absorption_efficiency(alpha, m);
            // Outside GOA's validity (α ≲ 1) Eq. 12 can dip below the absorption: clamp so that
            // C_ext ≥ C_abs and C_sca ≥ 0 always hold.
            let qe = goa::extinction_efficiency(
                alpha,
                m,
                opts.p_max,
                opts.regularise,
                opts.edge_correction,
            )
            .max(qa);
            (qe * area, qa * area)
        }
    }
}

/// Mie's series of one particle (App. A) and its `[C_ext, C_sca, C_abs]` in µm², with
/// C_abs = C_ext − C_sca clamped at 0 against rounding.
fn mie_cross_sections(p: &Particle) -> (MieCoefficients, [f64; 3]) {
    let area = PI * p.radius_um * p.radius_um;
    let c = MieCoefficients::new(p.size_parameter(), p.relative_index());
    let (qe, qs) = (c.q_ext(), c.q_sca());
    (c, [qe * area, qs * area, (qe - qs).max(0.0) * area])
}

/// Cross sections of one particle with the given theory. For GOA the geometry (size independent)
/// is passed in so that callers can share it across radii.
pub fn cross_sections_with(
    p: &Particle,
    theory: Theory,
    rays: Option<&GoaRays>,
    opts: &GoaOptions,
) -> CrossSections {
    match theory {
        Theory::Mie => {
            let (c, [ext, sca, abs]) = mie_cross_sections(p);
            CrossSections {
                ext,
                sca,
                abs,
                g: c.g(),
            }
        }
        Theory::Goa => {
            let owned;
            let rays = match rays {
                Some(r) => r,
                None => {
                    owned = GoaRays::new(p.relative_index(), opts.p_max);
                    &owned
                }
            };
            let (ext, abs) = extinction_and_absorption(p, theory, opts);
            let (norm, first) = goa_angular_integrals(rays, p.size_parameter(), opts);
            let g = if norm > 0.0 {
                (first / norm).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            CrossSections {
                ext,
                sca: ext - abs,
                abs,
                g,
            }
        }
    }
}

/// Columns of a batch of particles (all the same length; already broadcast by the caller).
pub struct ParticleColumns<'a> {
    pub radius_um: &'a [f64],
    pub wavelength_um: &'a [f64],
    pub eta_re: &'a [f64],
    pub eta_im: &'a [f64],
    pub eta_medium: &'a [f64],
}

impl ParticleColumns<'_> {
    pub fn len(&self) -> usize {
        self.radius_um.len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn check_lengths(&self, extra: Option<usize>) -> Result<(), OpticsError> {
        let n = self.len();
        for (name, len) in [
            ("wavelength_um", self.wavelength_um.len()),
            ("eta (real part)", self.eta_re.len()),
            ("eta (imaginary part)", self.eta_im.len()),
            ("eta_medium", self.eta_medium.len()),
            ("theta", extra.unwrap_or(n)),
        ] {
            if len != n {
                return Err(OpticsError::InvalidArgument {
                    argument: name,
                    value: len as f64,
                    requirement: "the same length as radius_um",
                });
            }
        }
        Ok(())
    }

    /// Validate every element and group equal particles: returns the unique particles (in order of
    /// first appearance) and, for each, the indices of the elements that use it. Linear time: runs of
    /// equal particles (the usual broadcast layout) skip the hash map.
    pub fn group(&self) -> Result<Vec<(Particle, Vec<usize>)>, OpticsError> {
        let mut groups: Vec<(Particle, Vec<usize>)> = Vec::new();
        let mut index: HashMap<[u64; 5], usize> = HashMap::new();
        let mut last: Option<([u64; 5], usize)> = None;
        for i in 0..self.len() {
            let key = [
                self.radius_um[i].to_bits(),
                self.wavelength_um[i].to_bits(),
                self.eta_re[i].to_bits(),
                self.eta_im[i].to_bits(),
                self.eta_medium[i].to_bits(),
            ];
            if let Some((k, g)) = last {
                if k == key {
                    groups[g].1.push(i);
                    continue;
                }
            }
            let g = match index.get(&key) {
                Some(&g) => g,
                None => {
                    let p = Particle::new(
                        self.radius_um[i],
                        self.wavelength_um[i],
                        C64::new(self.eta_re[i], self.eta_im[i]),
                        self.eta_medium[i],
                    )?;
                    groups.push((p, Vec::new()));
                    index.insert(key, groups.len() - 1);
                    groups.len() - 1
                }
            };
            groups[g].1.push(i);
            last = Some((key, g));
        }
        Ok(groups)
    }
}

fn check_theta(theta: &[f64]) -> Result<(), OpticsError> {
    for &t in theta {
        require(
            "theta",
            t,
            t.is_finite() && (0.0..=PI).contains(&t),
            "finite and in [0, π]",
        )?;
    }
    Ok(())
}

fn check_options(opts: &GoaOptions) -> Result<(), OpticsError> {
    require("p_max", opts.p_max as f64, opts.p_max <= 1000, "<= 1000")
}

/// One [`GoaRays`] per distinct relative index of a batch, shared by its radii: from the caller's
/// `cache` when given (so that repeated calls reuse the ray geometry and its prepared angle grids),
/// else made for this call and dropped with it.
fn geometries(
    groups: &[(Particle, Vec<usize>)],
    opts: &GoaOptions,
    cache: Option<&GoaCache>,
    needed: impl Fn(&Particle) -> bool,
) -> HashMap<[u64; 2], Arc<GoaRays>> {
    let mut ms: Vec<C64> = groups
        .iter()
        .filter(|(p, _)| needed(p))
        .map(|(p, _)| p.relative_index())
        .collect();
    ms.sort_by(|a, b| (a.re, a.im).partial_cmp(&(b.re, b.im)).unwrap());
    ms.dedup();
    ms.par_iter()
        .map(|m| {
            let rays = match cache {
                Some(c) => c.rays(*m, opts.p_max),
                None => Arc::new(GoaRays::new(*m, opts.p_max)),
            };
            ([m.re.to_bits(), m.im.to_bits()], rays)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .collect()
}

fn geo_key(p: &Particle) -> [u64; 2] {
    let m = p.relative_index();
    [m.re.to_bits(), m.im.to_bits()]
}

/// Scattering amplitudes for every element `i` (particle i at angle theta\[i\]).
pub fn amplitudes_batch(
    cols: &ParticleColumns,
    theta: &[f64],
    theory: Theory,
    opts: &GoaOptions,
    cache: Option<&GoaCache>,
) -> Result<Vec<(C64, C64)>, OpticsError> {
    cols.check_lengths(Some(theta.len()))?;
    check_theta(theta)?;
    check_options(opts)?;
    let groups = cols.group()?;
    let geos = if theory == Theory::Goa {
        geometries(&groups, opts, cache, |_| true)
    } else {
        HashMap::new()
    };
    let per_group: Vec<Vec<(usize, (C64, C64))>> = groups
        .par_iter()
        .map(|(p, idx)| {
            if cancel::requested() {
                return Vec::new();
            }
            let th: Vec<f64> = idx.iter().map(|&i| theta[i]).collect();
            let geo = geos.get(&geo_key(p)).map(|r| &**r);
            idx.iter()
                .copied()
                .zip(particle_amplitudes(p, theory, geo, &th, opts))
                .collect()
        })
        .collect();
    let mut out = vec![(C64::new(0.0, 0.0), C64::new(0.0, 0.0)); theta.len()];
    for g in per_group {
        for (i, v) in g {
            out[i] = v;
        }
    }
    Ok(out)
}

/// Cross sections for every particle of the batch (`with_g = false` skips GOA's angular integral and
/// returns g = NaN).
pub fn cross_sections_batch(
    cols: &ParticleColumns,
    method: Method,
    opts: &GoaOptions,
    with_g: bool,
    cache: Option<&GoaCache>,
) -> Result<Vec<CrossSections>, OpticsError> {
    cols.check_lengths(None)?;
    check_options(opts)?;
    let groups = cols.group()?;
    let geos = geometries(&groups, opts, cache, |p| {
        with_g && method.theory(p, opts.p_max) == Theory::Goa
    });
    let per_group: Vec<CrossSections> = groups
        .par_iter()
        .map(|(p, _)| {
            if cancel::requested() {
                return CrossSections::default();
            }
            let theory = method.theory(p, opts.p_max);
            if !with_g {
                let (ext, abs) = extinction_and_absorption(p, theory, opts);
                return CrossSections {
                    ext,
                    sca: ext - abs,
                    abs,
                    g: f64::NAN,
                };
            }
            let geo = if theory == Theory::Goa {
                Some(&*geos[&geo_key(p)])
            } else {
                None
            };
            cross_sections_with(p, theory, geo, opts)
        })
        .collect();
    let mut out = vec![CrossSections::default(); cols.len()];
    for ((_, idx), cs) in groups.iter().zip(per_group) {
        for &i in idx {
            out[i] = cs;
        }
    }
    Ok(out)
}

/// Normalised phase function f_p(θ) (sr⁻¹) for every element.
pub fn phase_function_batch(
    cols: &ParticleColumns,
    theta: &[f64],
    method: Method,
    opts: &GoaOptions,
    cache: Option<&GoaCache>,
) -> Result<Vec<f64>, OpticsError> {
    per_element_batch(cols, theta, method, opts, cache, true, |norm, s1, s2| {
        if norm > 0.0 {
            (s1.norm_sqr() + s2.norm_sqr()) / norm
        } else {
            1.0 / (4.0 * PI)
        }
    })
}

/// The Mueller elements `[F11, F12, F33, F34]` of every element in Bohren & Huffman's convention
/// ([`mueller_elements`], BH 1983 §4.4). `normalize`: all four divided by the normaliser of
/// [`phase_function_batch`] over 2, so that F11 is f_p exactly (sr⁻¹); a particle that scatters nothing
/// gets `[1/4π, 0, 1/4π, 0]` (f_p's isotropic fallback, ratios 0, 1, 0). Otherwise the raw values of the
/// amplitudes (dimensionless).
pub fn mueller_batch(
    cols: &ParticleColumns,
    theta: &[f64],
    method: Method,
    opts: &GoaOptions,
    cache: Option<&GoaCache>,
    normalize: bool,
) -> Result<Vec<[f64; 4]>, OpticsError> {
    per_element_batch(
        cols,
        theta,
        method,
        opts,
        cache,
        normalize,
        |norm, s1, s2| {
            if !normalize {
                return mueller_elements(s1, s2);
            }
            if norm > 0.0 {
                // F11 by the very expression of f_p (bitwise equal); the others scaled alike (2/norm).
                let c = s2 * s1.conj();
                [
                    (s1.norm_sqr() + s2.norm_sqr()) / norm,
                    (s2.norm_sqr() - s1.norm_sqr()) / norm,
                    2.0 * c.re / norm,
                    2.0 * c.im / norm,
                ]
            } else {
                let iso = 1.0 / (4.0 * PI);
                [iso, 0.0, iso, 0.0]
            }
        },
    )
}

/// A value per element from the particle's amplitudes there and (with `with_norm`) its phase
/// normaliser `∫ (|S1|²+|S2|²) dΩ` (0 when not asked for); particles grouped, groups in parallel.
fn per_element_batch<T: Copy + Default + Send>(
    cols: &ParticleColumns,
    theta: &[f64],
    method: Method,
    opts: &GoaOptions,
    cache: Option<&GoaCache>,
    with_norm: bool,
    value: impl Fn(f64, C64, C64) -> T + Sync,
) -> Result<Vec<T>, OpticsError> {
    cols.check_lengths(Some(theta.len()))?;
    check_theta(theta)?;
    check_options(opts)?;
    let groups = cols.group()?;
    let geos = geometries(&groups, opts, cache, |p| {
        method.theory(p, opts.p_max) == Theory::Goa
    });
    let per_group: Vec<Vec<(usize, T)>> = groups
        .par_iter()
        .map(|(p, idx)| {
            if cancel::requested() {
                return Vec::new();
            }
            let theory = method.theory(p, opts.p_max);
            let geo = if theory == Theory::Goa {
                Some(&*geos[&geo_key(p)])
            } else {
                None
            };
            let norm = if with_norm {
                phase_normaliser(p, theory, geo, opts)
            } else {
                0.0
            };
            let th: Vec<f64> = idx.iter().map(|&i| theta[i]).collect();
            let amps = particle_amplitudes(p, theory, geo, &th, opts);
            idx.iter()
                .zip(amps)
                .map(|(&i, (s1, s2))| (i, value(norm, s1, s2)))
                .collect()
        })
        .collect();
    let mut out = vec![T::default(); theta.len()];
    for g in per_group {
        for (i, v) in g {
            out[i] = v;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `GoaRays` prepares each angle grid once (the second request returns the same rays) and gives
    /// exactly what its geometry prepares directly; another grid is prepared anew.
    #[test]
    fn goa_rays_memoise_prepared_angles() {
        let rays = GoaRays::new(C64::new(1.33, 1e-4), 4);
        let a: Vec<f64> = (0..50).map(|i| i as f64 * PI / 49.0).collect();
        let b: Vec<f64> = a.iter().map(|t| 0.5 * t).collect();
        let first = rays.prepared(&a, 4);
        assert!(Arc::ptr_eq(&first, &rays.prepared(&a, 4)));
        assert!(!Arc::ptr_eq(&first, &rays.prepared(&b, 4)));
        let opts = GoaOptions::default();
        let direct = rays.geometry.prepare(&a, 4);
        let (x, y) = (
            goa::evaluate_prepared(rays.geometry.m, &first, 300.0, &opts),
            goa::evaluate_prepared(rays.geometry.m, &direct, 300.0, &opts),
        );
        assert_eq!(x, y);
    }

    /// A bounded `GoaCache` keeps the most recently used indices only: a reused index survives, the
    /// least recently used one is dropped, and `clear` empties it.
    #[test]
    fn bounded_goa_cache_drops_least_recently_used() {
        let cache = GoaCache::bounded(2);
        let m = |re: f64| C64::new(re, 0.0);
        let a = cache.rays(m(1.31), 3);
        cache.rays(m(1.5), 3);
        assert!(Arc::ptr_eq(&a, &cache.rays(m(1.31), 3))); // 1.31 now the most recent
        cache.rays(m(1.7), 3); // drops 1.5
        assert_eq!(cache.len(), 2);
        assert!(Arc::ptr_eq(&a, &cache.rays(m(1.31), 3)));
        let before = cache.rays(m(1.5), 3); // made again; drops 1.7
        assert_eq!(cache.len(), 2);
        assert!(Arc::ptr_eq(&before, &cache.rays(m(1.5), 3)));
        cache.clear();
        assert!(cache.is_empty());
    }

    /// The batch functions give the same numbers with a caller's cache (cold and warm) as without one.
    #[test]
    fn batch_results_do_not_depend_on_the_cache() {
        let theta: Vec<f64> = (0..64).map(|i| i as f64 * PI / 63.0).collect();
        let n = theta.len();
        let (r, lam, er, ei, em) = (
            vec![250.0; n],
            vec![0.6; n],
            vec![1.33; n],
            vec![1e-4; n],
            vec![1.0; n],
        );
        let cols = ParticleColumns {
            radius_um: &r,
            wavelength_um: &lam,
            eta_re: &er,
            eta_im: &ei,
            eta_medium: &em,
        };
        let opts = GoaOptions::default();
        let cache = GoaCache::bounded(1);
        let none = amplitudes_batch(&cols, &theta, Theory::Goa, &opts, None).unwrap();
        for _ in 0..2 {
            let with = amplitudes_batch(&cols, &theta, Theory::Goa, &opts, Some(&cache)).unwrap();
            assert_eq!(none, with);
        }
        assert_eq!(cache.len(), 1);
        let f0 = phase_function_batch(&cols, &theta, Method::Goa, &opts, None).unwrap();
        let f1 = phase_function_batch(&cols, &theta, Method::Goa, &opts, Some(&cache)).unwrap();
        assert_eq!(f0, f1);
        let c0 = cross_sections_batch(&cols, Method::Goa, &opts, true, None).unwrap();
        let c1 = cross_sections_batch(&cols, Method::Goa, &opts, true, Some(&cache)).unwrap();
        assert_eq!(c0, c1);
    }
}
