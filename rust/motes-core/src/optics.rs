//! One particle as a renderer needs it — cross sections (Eq. 2–3, 12–13, 28–29), the normalised phase
//! function `f_p` (Eq. 1) and the asymmetry g — computed by Lorenz–Mie, GOA, or a hybrid of the two,
//! batched over many particles and angles (rayon inside; no Python here).

use crate::error::{require, OpticsError};
use crate::goa::{self, GoaGeometry, GoaOptions};
use crate::mie::MieCoefficients;
use crate::quadrature::gauss_legendre;
use num_complex::Complex64 as C64;
use rayon::prelude::*;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::Arc;

/// Size parameter above which `Method::Auto` uses GOA. Chosen from the measured GOA-vs-Mie error of
/// `scripts/hybrid_threshold.py` (BENCHMARKS.md, "auto policy"): above it the RelMSE of
/// (|S1|+|S2|)/2 stays below 1e-2 for every tested index, and Mie costs grow linearly with x.
pub const AUTO_SIZE_PARAMETER: f64 = 60.0;

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
    pub fn new(radius_um: f64, wavelength_um: f64, eta: C64, eta_medium: f64) -> Result<Self, OpticsError> {
        require("radius_um", radius_um, radius_um.is_finite() && radius_um > 0.0, "finite and > 0")?;
        require("wavelength_um", wavelength_um, wavelength_um.is_finite() && wavelength_um > 0.0, "finite and > 0")?;
        require("eta (real part)", eta.re, eta.re.is_finite() && eta.re > 0.0, "finite and > 0")?;
        require("eta (imaginary part)", eta.im, eta.im.is_finite() && eta.im >= 0.0, "finite and >= 0")?;
        require("eta_medium", eta_medium, eta_medium.is_finite() && eta_medium > 0.0, "finite and > 0")?;
        let p = Particle { radius_um, wavelength_um, eta, eta_medium };
        let x = p.size_parameter();
        require("radius_um / wavelength_um", x, x <= MAX_SIZE_PARAMETER, "a size parameter 2π η_m r/λ <= 1e5")?;
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

    fn key(&self) -> [u64; 5] {
        [
            self.radius_um.to_bits(),
            self.wavelength_um.to_bits(),
            self.eta.re.to_bits(),
            self.eta.im.to_bits(),
            self.eta_medium.to_bits(),
        ]
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
    /// Mie below the size parameter [`AUTO_SIZE_PARAMETER`], GOA above.
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
                require("hybrid_radius_um", hybrid_radius_um, hybrid_radius_um.is_finite() && hybrid_radius_um >= 0.0, "finite and >= 0")?;
                Ok(Method::Hybrid { radius_um: hybrid_radius_um })
            }
            other => Err(OpticsError::InvalidOption {
                argument: "method",
                value: other.to_string(),
                allowed: "\"auto\", \"mie\", \"goa\", \"hybrid\"",
            }),
        }
    }

    pub fn theory(&self, p: &Particle) -> Theory {
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
                if p.size_parameter() < AUTO_SIZE_PARAMETER {
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

/// GOA angular integrals `(∫ (|S1|²+|S2|²) dΩ, ∫ (|S1|²+|S2|²) cosθ dΩ)` by composite 8-point
/// Gauss–Legendre on panels of width ≤ π/(2α): every ray-interference fringe (period ≳ π/α) and the
/// diffraction lobe (first zero 3.83/α) get several nodes. A panel edge sits at π/2, where Eq. 11
/// switches diffraction off.
pub fn goa_angular_integrals(geo: &GoaGeometry, alpha: f64, opts: &GoaOptions) -> (f64, f64) {
    let (x, w) = gauss_legendre(8);
    let half_panels = ((alpha).ceil() as usize).max(64);
    let h = 0.5 * PI / half_panels as f64;
    let (norm, first) = (0..2 * half_panels)
        .into_par_iter()
        .fold(
            || (0.0, 0.0, Vec::new()),
            |(mut n, mut f, mut scratch), k| {
                let a = k as f64 * h;
                for (xi, wi) in x.iter().zip(&w) {
                    let t = a + 0.5 * h * (1.0 + xi);
                    let (s1, s2) = geo.amplitudes(alpha, t, opts, &mut scratch);
                    let v = (s1.norm_sqr() + s2.norm_sqr()) * t.sin() * 0.5 * h * wi * 2.0 * PI;
                    n += v;
                    f += v * t.cos();
                }
                (n, f, scratch)
            },
        )
        .map(|(n, f, _)| (n, f))
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    (norm, first)
}

/// Everything needed to evaluate one particle's phase function at many angles.
pub enum Evaluator {
    Mie { series: crate::mie::MieAngularSeries, norm: f64 },
    Goa { geo: Arc<GoaGeometry>, alpha: f64, opts: GoaOptions, norm: f64 },
}

impl Evaluator {
    /// f_p(θ) of Eq. 1, normalised so that ∫ f dΩ = 1 (sr⁻¹).
    pub fn phase(&self, theta: f64, scratch: &mut Vec<(goa::RayGeometry, i32, i64)>) -> f64 {
        let (s1, s2) = match self {
            Evaluator::Mie { series, .. } => series.amplitudes(theta.cos()),
            Evaluator::Goa { geo, alpha, opts, .. } => geo.amplitudes(*alpha, theta, opts, scratch),
        };
        let norm = match self {
            Evaluator::Mie { norm, .. } | Evaluator::Goa { norm, .. } => *norm,
        };
        if norm > 0.0 {
            (s1.norm_sqr() + s2.norm_sqr()) / norm
        } else {
            1.0 / (4.0 * PI)
        }
    }
}

/// Cross sections of one particle with the given theory. For GOA the geometry (size independent)
/// is passed in so that callers can share it across radii.
pub fn cross_sections_with(p: &Particle, theory: Theory, geo: Option<&GoaGeometry>, opts: &GoaOptions) -> CrossSections {
    let area = PI * p.radius_um * p.radius_um;
    let m = p.relative_index();
    let alpha = p.size_parameter();
    match theory {
        Theory::Mie => {
            let c = MieCoefficients::new(alpha, m);
            let (qe, qs) = (c.q_ext(), c.q_sca());
            CrossSections { ext: qe * area, sca: qs * area, abs: ((qe - qs).max(0.0)) * area, g: c.g() }
        }
        Theory::Goa => {
            let owned;
            let geo = match geo {
                Some(g) => g,
                None => {
                    owned = GoaGeometry::new(m, opts.p_max);
                    &owned
                }
            };
            let qa = goa::absorption_efficiency(alpha, m);
            // Outside GOA's validity (α ≲ 1) Eq. 12 can dip below the absorption: clamp so that
            // C_ext ≥ C_abs and C_sca ≥ 0 always hold.
            let qe = goa::extinction_efficiency(alpha, m, opts.p_max, opts.regularise, opts.edge_correction).max(qa);
            let (norm, first) = goa_angular_integrals(geo, alpha, opts);
            let g = if norm > 0.0 { (first / norm).clamp(-1.0, 1.0) } else { 0.0 };
            CrossSections { ext: qe * area, sca: (qe - qa) * area, abs: qa * area, g }
        }
    }
}

/// Build the phase-function evaluator of one particle.
pub fn evaluator(p: &Particle, theory: Theory, geo: Option<Arc<GoaGeometry>>, opts: &GoaOptions) -> Evaluator {
    let alpha = p.size_parameter();
    let m = p.relative_index();
    match theory {
        Theory::Mie => {
            let c = MieCoefficients::new(alpha, m);
            // ∫(|S1|²+|S2|²) dΩ = 2 k² C_sca = 2π x² Q_sca.
            let norm = 2.0 * PI * alpha * alpha * c.q_sca();
            Evaluator::Mie { series: c.weighted(), norm }
        }
        Theory::Goa => {
            let geo = geo.unwrap_or_else(|| Arc::new(GoaGeometry::new(m, opts.p_max)));
            let (norm, _) = goa_angular_integrals(&geo, alpha, opts);
            Evaluator::Goa { geo, alpha, opts: *opts, norm }
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
                return Err(OpticsError::InvalidArgument { argument: name, value: len as f64, requirement: "the same length as radius_um" });
            }
        }
        Ok(())
    }

    /// Validate every element and group equal particles: returns the unique particles and, for each,
    /// the indices of the elements that use it.
    pub fn group(&self) -> Result<Vec<(Particle, Vec<usize>)>, OpticsError> {
        let mut items: Vec<([u64; 5], usize, Particle)> = Vec::with_capacity(self.len());
        for i in 0..self.len() {
            let p = Particle::new(self.radius_um[i], self.wavelength_um[i], C64::new(self.eta_re[i], self.eta_im[i]), self.eta_medium[i])?;
            items.push((p.key(), i, p));
        }
        items.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut groups: Vec<(Particle, Vec<usize>)> = Vec::new();
        let mut last: Option<[u64; 5]> = None;
        for (key, i, p) in items {
            if last == Some(key) {
                groups.last_mut().unwrap().1.push(i);
            } else {
                groups.push((p, vec![i]));
                last = Some(key);
            }
        }
        Ok(groups)
    }
}

fn check_theta(theta: &[f64]) -> Result<(), OpticsError> {
    for &t in theta {
        require("theta", t, t.is_finite() && (0.0..=PI).contains(&t), "finite and in [0, π]")?;
    }
    Ok(())
}

fn check_options(opts: &GoaOptions) -> Result<(), OpticsError> {
    require("p_max", opts.p_max as f64, opts.p_max <= 1000, "<= 1000")
}

/// Shared GOA geometries for every distinct relative index of a batch.
fn geometries(groups: &[(Particle, Vec<usize>)], opts: &GoaOptions, needed: impl Fn(&Particle) -> bool) -> HashMap<[u64; 2], Arc<GoaGeometry>> {
    let mut ms: Vec<C64> = groups.iter().filter(|(p, _)| needed(p)).map(|(p, _)| p.relative_index()).collect();
    ms.sort_by(|a, b| (a.re, a.im).partial_cmp(&(b.re, b.im)).unwrap());
    ms.dedup();
    ms.par_iter()
        .map(|m| ([m.re.to_bits(), m.im.to_bits()], Arc::new(GoaGeometry::new(*m, opts.p_max))))
        .collect::<Vec<_>>()
        .into_iter()
        .collect()
}

fn geo_key(p: &Particle) -> [u64; 2] {
    let m = p.relative_index();
    [m.re.to_bits(), m.im.to_bits()]
}

/// Scattering amplitudes for every element `i` (particle i at angle theta[i]).
pub fn amplitudes_batch(cols: &ParticleColumns, theta: &[f64], theory: Theory, opts: &GoaOptions) -> Result<Vec<(C64, C64)>, OpticsError> {
    cols.check_lengths(Some(theta.len()))?;
    check_theta(theta)?;
    check_options(opts)?;
    let groups = cols.group()?;
    let geos = if theory == Theory::Goa { geometries(&groups, opts, |_| true) } else { HashMap::new() };
    let per_group: Vec<Vec<(usize, (C64, C64))>> = groups
        .par_iter()
        .map(|(p, idx)| {
            let alpha = p.size_parameter();
            match theory {
                Theory::Mie => {
                    let series = MieCoefficients::new(alpha, p.relative_index()).weighted();
                    let th: Vec<f64> = idx.iter().map(|&i| theta[i]).collect();
                    idx.iter().copied().zip(series.amplitudes_many(&th)).collect()
                }
                Theory::Goa => {
                    let geo = &geos[&geo_key(p)];
                    idx.par_iter()
                        .map_init(Vec::new, |scratch, &i| (i, geo.amplitudes(alpha, theta[i], opts, scratch)))
                        .collect()
                }
            }
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

/// Cross sections for every particle of the batch.
pub fn cross_sections_batch(cols: &ParticleColumns, method: Method, opts: &GoaOptions) -> Result<Vec<CrossSections>, OpticsError> {
    cols.check_lengths(None)?;
    check_options(opts)?;
    let groups = cols.group()?;
    let geos = geometries(&groups, opts, |p| method.theory(p) == Theory::Goa);
    let per_group: Vec<CrossSections> = groups
        .par_iter()
        .map(|(p, _)| {
            let theory = method.theory(p);
            let geo = if theory == Theory::Goa { Some(geos[&geo_key(p)].as_ref()) } else { None };
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
pub fn phase_function_batch(cols: &ParticleColumns, theta: &[f64], method: Method, opts: &GoaOptions) -> Result<Vec<f64>, OpticsError> {
    cols.check_lengths(Some(theta.len()))?;
    check_theta(theta)?;
    check_options(opts)?;
    let groups = cols.group()?;
    let geos = geometries(&groups, opts, |p| method.theory(p) == Theory::Goa);
    let per_group: Vec<Vec<(usize, f64)>> = groups
        .par_iter()
        .map(|(p, idx)| {
            let theory = method.theory(p);
            let geo = if theory == Theory::Goa { Some(geos[&geo_key(p)].clone()) } else { None };
            let ev = evaluator(p, theory, geo, opts);
            idx.par_iter().map_init(Vec::new, |scratch, &i| (i, ev.phase(theta[i], scratch))).collect()
        })
        .collect();
    let mut out = vec![0.0; theta.len()];
    for g in per_group {
        for (i, v) in g {
            out[i] = v;
        }
    }
    Ok(out)
}
