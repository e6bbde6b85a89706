//! Geometrical optics approximation (GOA) of scattering by a sphere (paper Sec. 3.1, App. B, C).
//!
//! The amplitude is Fraunhofer diffraction (Eq. 4) plus one term per geometric ray that leaves the
//! sphere in direction θ after `p` chords inside it (Eq. 7–11).
//!
//! ## Conventions
//! The paper's formulas are written in van de Hulst's convention (time factor `exp(+iωt)`). We return
//! amplitudes in the Bohren–Huffman convention (`exp(-iωt)`, absorbing index `m = n + iκ`), the same as
//! our Lorenz–Mie code, by conjugating every ray phase: `S_BH(m) = conj(S_vdH(conj m))`. Diffraction
//! is real and unchanged, and so is `Re S(0)`, hence every cross section.
//!
//! ## Absorbing particles (App. C, after Yang & Liou / Chýlek's ref. \[65\])
//! Inside the sphere the refracted wave is inhomogeneous. With `b = sqrt(m² − sin²θi)` (the normal
//! component of the internal wave vector, `Im b ≥ 0` so the wave decays inward):
//! * the effective real index of Eq. 32 is `η' = sqrt(sin²θi + (Re b)²)` and `cos θ't = Re b / η'`;
//! * the effective absorption index of Eq. 36 is `χ = Im b`;
//! * the amplitude attenuation of Eq. 35 is `ξ_p = exp(−2 p α χ cos²θ't)` (depth `2r cos²θ't` per chord
//!   measured along the entry normal);
//! * the Fresnel amplitude coefficients are evaluated with the complex `b`,
//!   `r⊥ = (cosθi − b)/(cosθi + b)`, `r∥ = (m² cosθi − b)/(m² cosθi + b)`, and the coefficient of an
//!   internal reflection is `−r`. The reflection and refraction *phase shifts* of Eq. 34,
//!   `φ_r,j = arg r_j` and `φ_t,j = arg[(1 − r_j²)(−r_j)^{p−1}]`, are then simply the arguments of the
//!   complex `ε_j` of Eq. 8; for a non-absorbing particle they are 0 or π (the sign of the real `ε_j`) and
//!   under total internal reflection `arg r_j` is the Goos–Hänchen-free TIR phase.
//!
//! ## Singular points and their regularisation (see BENCHMARKS.md for the measured effect)
//! 1. θ → 0 and θ → π (`sin θ → 0` in Eq. 7): rays are evaluated at θ clamped to `[δ, π−δ]`,
//!    `δ = 1e-9`, where the axial rays (θi → 0) have their finite limit `|S| = α|ε|/|dθ_p/dθi|`.
//! 2. Glories (a ray with θi ≠ 0 leaving exactly forward/backward): `sin θ` is replaced by
//!    `sqrt(sin²θ + (2 sinθi/α)²)`, which bounds the amplitude at `O(α^{3/2})` (the glory's scaling).
//! 3. Rainbow caustics (`dθ_p/dθi → 0`): `|dθ_p/dθi|` is replaced by `sqrt(D² + D_c²)` with
//!    `D_c = max(|D'|^{2/3} α^{−1/3}, 2/α)`: `|D'|^{2/3} α^{−1/3}` is the width (in D) of the Airy zone
//!    and `2/α` guarantees that no ray carries more forward amplitude than the shadow, `|S_p| ≤ α²|ε|/2`.
//! 2b. Pole symmetry: near θ = 0 and π a glory ring is unresolved; each non-axial ray is blended toward
//!    the axially symmetric combination (S1 = S2 forward, S1 = −S2 backward) with weight 1/(1+u²),
//!    u = α sinθi sinθ, so the exact symmetries of every sphere hold on the axis.
//! 4. η → 1 (`|η − 1|` in Eq. 12/14): the `p = 1` extinction term is replaced by the anomalous
//!    diffraction (van de Hulst) kernel scaled by the normal-incidence Fresnel factor, which equals the
//!    GOA term asymptotically (ρ = 2α|η−1| → ∞); the factor and the edge term fade with
//!    `ray_optics_weight(ρ) = ρ²/(ρ²+25)`, so the extinction tends to ADT's (→ 0) as η → 1.

use crate::quadrature::gauss_legendre;
use num_complex::Complex64 as C64;
use std::f64::consts::{FRAC_PI_2, PI};

/// Clamp of θ away from 0 and π when evaluating rays (regularisation 1).
pub const THETA_EPS: f64 = 1e-9;
/// Number of samples of θ_p(θi) used to locate extrema (rainbows) before refinement.
const GEOMETRY_SAMPLES: usize = 129;

/// Options of a GOA evaluation.
#[derive(Clone, Copy, Debug)]
pub struct GoaOptions {
    /// Highest ray order kept (p = 0 reflection, 1 transmission, 2 one internal reflection, ...).
    pub p_max: u32,
    /// Include Fraunhofer diffraction (Eq. 4) in the forward hemisphere.
    pub diffraction: bool,
    /// Apply the documented regularisations at caustics, glories and η → 1.
    pub regularise: bool,
    /// Add the edge (surface-wave) term of the extinction that ray optics misses (see `edge_term`).
    pub edge_correction: bool,
}

impl Default for GoaOptions {
    fn default() -> Self {
        GoaOptions {
            p_max: 3,
            diffraction: true,
            regularise: true,
            edge_correction: true,
        }
    }
}

/// Geometry of one ray of order `p` entering at incidence θi (independent of the particle size).
#[derive(Clone, Copy, Debug)]
pub struct RayGeometry {
    pub theta_i: f64,
    /// Deflection θ_p of Eq. 5 (radians, not reduced).
    pub deflection: f64,
    /// dθ_p/dθi.
    pub d_deflection: f64,
    /// Effective real index η' (Eq. 32, relative to the host).
    pub eta_eff: f64,
    /// cos θ't.
    pub cos_t: f64,
    /// Effective absorption index χ (Eq. 36).
    pub chi: f64,
    /// ε_1, ε_2 of Eq. 8 (complex for absorbing particles and under TIR).
    pub eps: [C64; 2],
}

/// Fresnel amplitude coefficients (⊥, ∥) at incidence θi for relative index `m`, with the complex
/// normal wave number `b = sqrt(m² − sin²θi)` (Eq. 7–8 with App. C).
#[inline]
pub fn fresnel(m: C64, cos_i: f64, b: C64) -> [C64; 2] {
    let m2 = m * m;
    [
        (cos_i - b) / (cos_i + b),
        (m2 * cos_i - b) / (m2 * cos_i + b),
    ]
}

/// `ε_j` of Eq. 8: `r` for p = 0, `(1 − r²)(−r)^{p−1}` otherwise.
///
/// For a complex `r` (absorbing particles, total internal reflection) the magnitude is taken from the
/// energy balance, `(1 − |r|²)|r|^{p−1}`, and only the phase from `(1 − r²)(−r)^{p−1}`: for a real `r`
/// this is Eq. 8 exactly, and beyond the critical angle of a bubble, where the transmitted wave is
/// evanescent and carries no energy, it vanishes — so an absorption of 1e-12 no longer turns evanescent
/// waves into refracted rays (the transmitted amplitude is continuous in κ at κ = 0).
#[inline]
fn epsilon(r: C64, p: u32) -> C64 {
    if p == 0 {
        return r;
    }
    let coherent = (1.0 - r * r) * (-r).powu(p - 1);
    let magnitude = (1.0 - r.norm_sqr()).max(0.0) * r.norm().powi(p as i32 - 1);
    if coherent.norm() > 0.0 {
        coherent * (magnitude / coherent.norm())
    } else {
        C64::new(0.0, 0.0)
    }
}

/// Ray geometry at incidence θi (Eq. 5 with App. C's effective angle).
pub fn ray_geometry(m: C64, p: u32, theta_i: f64) -> RayGeometry {
    let (s, c) = theta_i.sin_cos();
    let b = (m * m - s * s).sqrt();
    let br = b.re.max(0.0);
    let eta_eff = (s * s + br * br).sqrt();
    let theta_t = s.atan2(br);
    let cos_t = if eta_eff > 0.0 { br / eta_eff } else { 0.0 };
    // dθt/dθi = (Re b · cos θi − sin θi · d(Re b)/dθi)/η'² with d b/dθi = −sinθi cosθi / b.
    let inv_b = if b.norm_sqr() > 0.0 {
        1.0 / b
    } else {
        C64::new(f64::INFINITY, 0.0)
    };
    let dtheta_t = if eta_eff > 0.0 {
        (br * c + s * s * c * inv_b.re) / (eta_eff * eta_eff)
    } else {
        f64::INFINITY
    };
    let (deflection, d_deflection) = if p == 0 {
        (PI - 2.0 * theta_i, -2.0)
    } else {
        let pf = p as f64;
        (
            2.0 * pf * theta_t - 2.0 * theta_i - (pf - 1.0) * PI,
            2.0 * pf * dtheta_t - 2.0,
        )
    };
    let r = fresnel(m, c, b);
    RayGeometry {
        theta_i,
        deflection,
        d_deflection,
        eta_eff,
        cos_t,
        chi: b.im.max(0.0),
        eps: [epsilon(r[0], p), epsilon(r[1], p)],
    }
}

/// Deflection θ_p (Eq. 5) and dθ_p/dθi only — the cheap part used inside the root finder. Real indices
/// take a real-arithmetic path (Snell's law); complex ones go through `ray_geometry`.
#[inline]
fn deflection(m: C64, p: u32, theta_i: f64) -> (f64, f64) {
    if p == 0 {
        return (PI - 2.0 * theta_i, -2.0);
    }
    let pf = p as f64;
    if m.im == 0.0 {
        let (s, c) = theta_i.sin_cos();
        let st = (s / m.re).min(1.0);
        let ct = (1.0 - st * st).sqrt();
        let theta_t = st.asin();
        let dtheta_t = if ct > 0.0 {
            c / (m.re * ct)
        } else {
            f64::INFINITY
        };
        (
            2.0 * pf * theta_t - 2.0 * theta_i - (pf - 1.0) * PI,
            2.0 * pf * dtheta_t - 2.0,
        )
    } else {
        let g = ray_geometry(m, p, theta_i);
        (g.deflection, g.d_deflection)
    }
}

/// One sample of θ_p(θi) on a branch.
#[derive(Clone, Copy, Debug)]
struct Sample {
    theta_i: f64,
    deflection: f64,
    d: f64,
    /// d²θ_p/dθi² (for the caustic width of regularisation 3).
    d2: f64,
}

/// One monotonic branch of θ_p(θi), sampled for bracketing.
#[derive(Clone, Debug)]
struct Branch {
    /// Samples with θ_p monotonic along the vector.
    samples: Vec<Sample>,
    increasing: bool,
}

/// The branches of θ_p(θi) of one order `p` for one relative index.
#[derive(Clone, Debug)]
pub struct OrderGeometry {
    pub p: u32,
    branches: Vec<Branch>,
}

/// Largest incidence angle that produces a refracted ray: the critical angle for a non-absorbing
/// optically thinner particle (bubbles, η < 1), π/2 otherwise.
fn max_incidence(m: C64, p: u32) -> f64 {
    if p >= 1 && m.im == 0.0 && m.re < 1.0 {
        m.re.asin()
    } else {
        FRAC_PI_2
    }
}

/// d²θ_p/dθi² by central differences of the analytic first derivative.
fn d2_deflection(m: C64, p: u32, theta_i: f64, hi: f64) -> f64 {
    let h = 1e-6;
    let a = (theta_i - h).max(0.0);
    let b = (theta_i + h).min(hi);
    let (da, db) = (deflection(m, p, a).1, deflection(m, p, b).1);
    if da.is_finite() && db.is_finite() && b > a {
        (db - da) / (b - a)
    } else {
        0.0
    }
}

impl OrderGeometry {
    /// Sample θ_p(θi), find every extremum (rainbow angle) by bisection on dθ_p/dθi, and split the
    /// domain into monotonic branches: each scattering angle then has at most one root per branch and
    /// per (q, l) of Eq. 6, so *every* contributing incidence angle is found.
    pub fn new(m: C64, p: u32) -> Self {
        let hi = max_incidence(m, p);
        let n = GEOMETRY_SAMPLES;
        let ti: Vec<f64> = (0..n).map(|k| hi * k as f64 / (n - 1) as f64).collect();
        let dd: Vec<(f64, f64)> = ti.iter().map(|&t| deflection(m, p, t)).collect();
        let mut cuts = vec![0.0];
        for k in 0..n - 1 {
            let (d0, d1) = (dd[k].1, dd[k + 1].1);
            if d0.is_finite() && d1.is_finite() && d0 * d1 < 0.0 {
                let (mut a, mut b) = (ti[k], ti[k + 1]);
                for _ in 0..60 {
                    let mid = 0.5 * (a + b);
                    let dm = deflection(m, p, mid).1;
                    if (dm < 0.0) == (d0 < 0.0) {
                        a = mid;
                    } else {
                        b = mid;
                    }
                }
                cuts.push(0.5 * (a + b));
            }
        }
        cuts.push(hi);
        let sample = |t: f64| {
            let (th, d) = deflection(m, p, t);
            Sample {
                theta_i: t,
                deflection: th,
                d,
                d2: d2_deflection(m, p, t, hi),
            }
        };
        let mut branches = Vec::new();
        for w in cuts.windows(2) {
            let (a, b) = (w[0], w[1]);
            if b - a <= 0.0 {
                continue;
            }
            let mut samples = vec![sample(a)];
            samples.extend(ti.iter().filter(|t| **t > a && **t < b).map(|&t| sample(t)));
            samples.push(sample(b));
            let increasing = samples.last().unwrap().deflection > samples[0].deflection;
            branches.push(Branch {
                samples,
                increasing,
            });
        }
        OrderGeometry { p, branches }
    }

    /// Every ray of this order leaving at scattering angle θ: each root θi of
    /// `q(θ_p(θi) − 2πl) = θ` (Eq. 6), prepared for evaluation at any size.
    pub fn rays_at(&self, m: C64, theta: f64, out: &mut Vec<PreparedRay>) {
        for br in &self.branches {
            let first = br.samples[0].deflection;
            let last = br.samples.last().unwrap().deflection;
            let (lo, hi) = if first < last {
                (first, last)
            } else {
                (last, first)
            };
            for q in [1i32, -1] {
                let qt = q as f64 * theta;
                let l_lo = ((lo - qt) / (2.0 * PI)).ceil() as i64;
                let l_hi = ((hi - qt) / (2.0 * PI)).floor() as i64;
                for l in l_lo..=l_hi {
                    let target = qt + 2.0 * PI * l as f64;
                    if let Some((ti, d2)) = solve_branch(m, self.p, br, target) {
                        let g = ray_geometry(m, self.p, ti);
                        if let Some(r) = PreparedRay::new(&g, self.p, q, l, theta, d2) {
                            out.push(r);
                        }
                    }
                }
            }
        }
    }
}

/// Solve θ_p(θi) = target on a monotonic branch: bracket by binary search over the samples, start from
/// cubic Hermite interpolation of the inverse, then safeguarded Newton (typically 1–3 steps).
/// Returns the root and the interpolated d²θ_p/dθi² there.
fn solve_branch(m: C64, p: u32, br: &Branch, target: f64) -> Option<(f64, f64)> {
    let s = &br.samples;
    let key = |v: f64| if br.increasing { v } else { -v };
    let t = key(target);
    if t < key(s[0].deflection) || t > key(s[s.len() - 1].deflection) {
        return None;
    }
    let (mut i0, mut i1) = (0usize, s.len() - 1);
    while i1 - i0 > 1 {
        let mid = (i0 + i1) / 2;
        if key(s[mid].deflection) <= t {
            i0 = mid;
        } else {
            i1 = mid;
        }
    }
    let (sa, sb) = (s[i0], s[i1]);
    let (mut a, mut b) = (sa.theta_i, sb.theta_i);
    let span = sb.deflection - sa.deflection;
    // Hermite interpolation of θi(θ_p) with slopes 1/D (when finite), else linear.
    let mut x = if span != 0.0 {
        let u = (target - sa.deflection) / span;
        let (ia, ib) = (1.0 / sa.d, 1.0 / sb.d);
        if ia.is_finite() && ib.is_finite() && sa.d * sb.d > 0.0 {
            let (h00, h10, h01, h11) = (
                (1.0 + 2.0 * u) * (1.0 - u) * (1.0 - u),
                u * (1.0 - u) * (1.0 - u),
                u * u * (3.0 - 2.0 * u),
                u * u * (u - 1.0),
            );
            h00 * a + h10 * span * ia + h01 * b + h11 * span * ib
        } else {
            a + u * (b - a)
        }
    } else {
        0.5 * (a + b)
    };
    if !(x >= a && x <= b) {
        x = 0.5 * (a + b);
    }
    for _ in 0..60 {
        let (th, d) = deflection(m, p, x);
        let f = th - target;
        if f == 0.0 {
            break;
        }
        if (f > 0.0) == br.increasing {
            b = x;
        } else {
            a = x;
        }
        let newton = x - f / d;
        let next = if newton.is_finite() && newton > a && newton < b {
            newton
        } else {
            0.5 * (a + b)
        };
        let step = (next - x).abs();
        x = next;
        if step <= 2.0 * f64::EPSILON * x.abs().max(1e-300) || b - a <= 2.0 * f64::EPSILON * b.abs()
        {
            break;
        }
    }
    let w = if sb.theta_i > sa.theta_i {
        (x - sa.theta_i) / (sb.theta_i - sa.theta_i)
    } else {
        0.0
    };
    Some((x, sa.d2 + w.clamp(0.0, 1.0) * (sb.d2 - sa.d2)))
}

/// A ray found for one scattering angle, with everything that does not depend on the particle size
/// (Eq. 7–10 and 35 factored as `α ε √(ratio(α)) ξ(α) exp(−i(α·path + φ_f))`).
#[derive(Clone, Copy, Debug)]
pub struct PreparedRay {
    /// ε_1, ε_2 of Eq. 8.
    eps: [C64; 2],
    /// sin 2θi.
    sin2i: f64,
    /// sin θi (glory regularisation).
    sin_i: f64,
    /// sin θ at the (clamped) scattering angle.
    sin_th: f64,
    /// cos θ (which pole is near).
    cos_th: f64,
    /// dθ_p/dθi.
    d: f64,
    /// |d²θ_p/dθi²|^{2/3} (caustic width coefficient).
    caustic: f64,
    /// Eq. 9 divided by α: 2(cos θi − p η' cos θ't).
    path: f64,
    /// Eq. 35 exponent divided by α: 2 p χ cos²θ't.
    attenuation: f64,
    /// Eq. 10.
    phi_f: f64,
}

impl PreparedRay {
    fn new(g: &RayGeometry, p: u32, q: i32, l: i64, theta: f64, d2: f64) -> Option<Self> {
        let d = g.d_deflection;
        if !d.is_finite() {
            return None;
        }
        let (sin_i, cos_i) = g.theta_i.sin_cos();
        let pf = p as f64;
        let sgn = sign(d);
        Some(PreparedRay {
            eps: g.eps,
            sin2i: 2.0 * sin_i * cos_i,
            sin_i,
            sin_th: theta.sin(),
            cos_th: theta.cos(),
            d,
            caustic: d2.abs().powf(2.0 / 3.0),
            path: 2.0 * (cos_i - pf * g.eta_eff * g.cos_t),
            attenuation: 2.0 * pf * g.chi * g.cos_t * g.cos_t,
            phi_f: FRAC_PI_2 * (1.0 + pf - 2.0 * l as f64 - 0.5 * sgn - 0.5 * q as f64),
        })
    }

    /// The ray's (S1, S2) for size parameter α (BH convention: conjugated phase, module docs).
    #[inline]
    fn amplitude(&self, alpha: f64, alpha_m13: f64, regularise: bool) -> [C64; 2] {
        let (sin_eff2, d_eff2) = if regularise {
            // Regularisations 2 (glory) and 3 (caustic), module docs.
            let glory = 2.0 * self.sin_i / alpha;
            let dc = (self.caustic * alpha_m13).max(2.0 / alpha);
            (
                self.sin_th * self.sin_th + glory * glory,
                self.d * self.d + dc * dc,
            )
        } else {
            (self.sin_th * self.sin_th, self.d * self.d)
        };
        let denom = 2.0 * (sin_eff2 * d_eff2).sqrt();
        let ratio = if self.sin2i == 0.0 {
            0.0
        } else {
            self.sin2i / denom
        };
        if !(ratio > 0.0) || !ratio.is_finite() {
            return [C64::new(0.0, 0.0); 2];
        }
        let xi = if self.attenuation > 0.0 {
            (-alpha * self.attenuation).exp()
        } else {
            1.0
        };
        let phase = C64::from_polar(alpha * xi * ratio.sqrt(), -(alpha * self.path + self.phi_f));
        let (a1, a2) = (self.eps[0] * phase, self.eps[1] * phase);
        if !regularise {
            return [a1, a2];
        }
        // Regularisation 2b (pole symmetry): a ray with θi ≠ 0 that reaches θ ≈ 0 or π belongs to a
        // glory ring of angular radius ~1/(α sinθi) that the ray picture cannot resolve. On the axis
        // only the axially symmetric part survives (S1 = S2 forward, S1 = −S2 backward); the rest
        // grows back like the ring's J2 term, ∝ u² with u = α sinθi sinθ. Axial rays (θi → 0, u → 0)
        // already have ε2 = ±ε1 and are unchanged.
        let u = alpha * self.sin_i * self.sin_th;
        let w = u * u / (1.0 + u * u);
        let sigma = if self.cos_th >= 0.0 { 1.0 } else { -1.0 };
        let (sym, anti) = (0.5 * (a1 + sigma * a2), 0.5 * (a1 - sigma * a2));
        [sym + w * anti, sigma * (sym - w * anti)]
    }
}

/// The rays of every order at a list of angles (size independent; reusable across radii).
#[derive(Clone, Debug, Default)]
pub struct PreparedAngles {
    /// Scattering angles (unclamped, for diffraction).
    pub theta: Vec<f64>,
    /// `rays[offsets[i]..offsets[i+1]]` belong to `theta[i]`.
    offsets: Vec<usize>,
    rays: Vec<PreparedRay>,
}

impl PreparedAngles {
    pub fn len(&self) -> usize {
        self.theta.len()
    }
    pub fn is_empty(&self) -> bool {
        self.theta.is_empty()
    }
    /// Approximate heap size in bytes.
    pub fn bytes(&self) -> usize {
        self.theta.len() * 16 + self.rays.len() * std::mem::size_of::<PreparedRay>()
    }
}

/// All orders 0..=p_max of one relative index: the size-independent part of a GOA evaluation.
#[derive(Clone, Debug)]
pub struct GoaGeometry {
    pub m: C64,
    pub p_max: u32,
    pub orders: Vec<OrderGeometry>,
}

impl GoaGeometry {
    pub fn new(m: C64, p_max: u32) -> Self {
        GoaGeometry {
            m,
            p_max,
            orders: (0..=p_max).map(|p| OrderGeometry::new(m, p)).collect(),
        }
    }

    /// Append the rays (orders ≤ p_max) leaving at θ ∈ [0, π].
    pub fn rays_at(&self, theta: f64, p_max: u32, out: &mut Vec<PreparedRay>) {
        // Regularisation 1: rays at θ clamped away from 0 and π (their axial limits are finite).
        let th = theta.clamp(THETA_EPS, PI - THETA_EPS);
        for order in self.orders.iter().take(p_max as usize + 1) {
            order.rays_at(self.m, th, out);
        }
    }

    /// Prepare many angles at once (parallel).
    pub fn prepare(&self, theta: &[f64], p_max: u32) -> PreparedAngles {
        use rayon::prelude::*;
        let per: Vec<Vec<PreparedRay>> = theta
            .par_iter()
            .with_min_len(64)
            .map(|&t| {
                let mut v = Vec::with_capacity(8);
                self.rays_at(t, p_max, &mut v);
                v
            })
            .collect();
        let mut offsets = Vec::with_capacity(theta.len() + 1);
        offsets.push(0);
        let mut rays = Vec::with_capacity(per.iter().map(Vec::len).sum());
        for v in per {
            rays.extend(v);
            offsets.push(rays.len());
        }
        PreparedAngles {
            theta: theta.to_vec(),
            offsets,
            rays,
        }
    }

    /// Amplitudes (S1, S2) in the BH convention at one scattering angle θ ∈ [0, π] for size parameter α.
    pub fn amplitudes(
        &self,
        alpha: f64,
        theta: f64,
        opts: &GoaOptions,
        scratch: &mut Vec<PreparedRay>,
    ) -> (C64, C64) {
        scratch.clear();
        self.rays_at(theta, opts.p_max, scratch);
        SizeTerms::new(self.m, alpha, opts).sum(theta, scratch, opts)
    }
}

/// The size-dependent constants of one evaluation, computed once per particle.
struct SizeTerms {
    alpha: f64,
    /// α^{-1/3} (caustic width).
    alpha_m13: f64,
    /// Diffraction amplitude factor: `sqrt(1 + edge_term)` or 1.
    diffraction_scale: f64,
}

impl SizeTerms {
    fn new(m: C64, alpha: f64, opts: &GoaOptions) -> Self {
        let diffraction_scale = if opts.edge_correction {
            (1.0 + edge_term(alpha, m)).sqrt()
        } else {
            1.0
        };
        SizeTerms {
            alpha,
            alpha_m13: alpha.powf(-1.0 / 3.0),
            diffraction_scale,
        }
    }

    /// Diffraction plus the given rays (Eq. 11).
    #[inline]
    fn sum(&self, theta: f64, rays: &[PreparedRay], opts: &GoaOptions) -> (C64, C64) {
        let mut s = [C64::new(0.0, 0.0); 2];
        if opts.diffraction {
            let d = diffraction(self.alpha, theta) * self.diffraction_scale;
            s[0].re += d;
            s[1].re += d;
        }
        for r in rays {
            let a = r.amplitude(self.alpha, self.alpha_m13, opts.regularise);
            s[0] += a[0];
            s[1] += a[1];
        }
        (s[0], s[1])
    }
}

/// Evaluate prepared angles at size parameter α: element i is (S1, S2) at `prepared.theta[i]`.
pub fn evaluate_prepared(
    m: C64,
    prepared: &PreparedAngles,
    alpha: f64,
    opts: &GoaOptions,
) -> Vec<(C64, C64)> {
    use rayon::prelude::*;
    let size = SizeTerms::new(m, alpha, opts);
    (0..prepared.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let rays = &prepared.rays[prepared.offsets[i]..prepared.offsets[i + 1]];
            size.sum(prepared.theta[i], rays, opts)
        })
        .collect()
}

/// Fraunhofer diffraction, Eq. 4: `S_D = α² J1(α sinθ)/(α sinθ)` for θ < π/2 (Eq. 11), else 0.
#[inline]
pub fn diffraction(alpha: f64, theta: f64) -> f64 {
    if theta >= FRAC_PI_2 {
        return 0.0;
    }
    let x = alpha * theta.sin();
    let j1_over_x = if x < 1e-4 {
        0.5 - x * x / 16.0
    } else {
        libm::j1(x) / x
    };
    alpha * alpha * j1_over_x
}

/// Edge term of the extinction efficiency (Nussenzveig & Wiscombe 1980, Phys. Rev. Lett. 45, 1490):
/// `Q_ext ≈ 2 + 1.9923861 α^{-2/3} − 0.7153537 α^{-4/3}` on average over the ripple. Ray optics (Eq. 12)
/// contains only the `2`; grazing rays that creep around the edge add the rest — 4.5 % of C_ext at
/// α = 100. The extra extinction is scattered into the diffraction lobe, so when enabled the
/// diffraction amplitude is scaled by `sqrt(1 + edge_term)` and energy stays balanced. α is clamped to
/// ≥ 3, below which the asymptotic series is meaningless (and GOA with it).
///
/// The coefficients are derived for η > 1; for bubbles (η < 1) the measured ripple-averaged
/// coefficient is different (1.29 instead of 1.99 at η = 0.75, `scripts/figures/edge_term.py`), so the term is
/// left out for η_r < 1.
pub fn edge_term(alpha: f64, m: C64) -> f64 {
    if m.re < 1.0 {
        return 0.0;
    }
    let a = alpha.max(3.0);
    // A sphere with η → 1 has no edge: taper with the phase shift ρ (regularisation 4).
    ray_optics_weight(alpha, m) * (1.9923861 * a.powf(-2.0 / 3.0) - 0.7153537 * a.powf(-4.0 / 3.0))
}

/// Weight of ray-optics (as opposed to anomalous-diffraction) behaviour: `t = ρ²/(ρ² + ρ0²)` with
/// `ρ = 2α|m − 1|` the central phase shift and ρ0 = 5. t → 0 as η → 1 at fixed α (ADT regime, where
/// the edge term and the Fresnel focusing factor of the p = 1 ray both disappear) and t → 1 in the
/// GOA regime. ρ0 from the η → 1 table of `scripts/figures/singularities.py` (part b).
pub fn ray_optics_weight(alpha: f64, m: C64) -> f64 {
    let rho = 2.0 * alpha * (m - 1.0).norm();
    rho * rho / (rho * rho + 25.0)
}

/// The sign s of dθ/dθi in Eq. 10: 1, −1, or 0 where it vanishes (or is NaN), unlike `f64::signum`.
fn sign(d: f64) -> f64 {
    if d > 0.0 {
        1.0
    } else if d < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Normal-incidence amplitude of order p (θi → 0), the axial limit used by Eq. 12.
fn axial_term(m: C64, p: u32, alpha: f64, regularise: bool) -> C64 {
    let g = ray_geometry(m, p, 0.0);
    let d = g.d_deflection;
    let d_eff = if regularise {
        (d * d + 4.0 / (alpha * alpha)).sqrt()
    } else {
        d.abs()
    };
    if d_eff == 0.0 {
        return C64::new(0.0, 0.0);
    }
    let pf = p as f64;
    let sgn = sign(d);
    // θ_p(0) = −(p−1)π = 2πl with q = s: φ_f = π/2 (2p − s) (Eq. 10).
    let phi_f = FRAC_PI_2 * (2.0 * pf - sgn);
    let phi_p = 2.0 * alpha * (1.0 - pf * g.eta_eff * g.cos_t);
    let xi = (-2.0 * pf * alpha * g.chi).exp();
    g.eps[0] * C64::from_polar(alpha * xi / d_eff, -(phi_p + phi_f))
}

/// Extinction efficiency of anomalous diffraction minus its large-size limit 2:
/// `Q_ADT − 2 = 4 Re[−e^a/a + (e^a − 1)/a²]`, `a = 2iα(m − 1)` (van de Hulst §11.22).
fn adt_excess(alpha: f64, m: C64) -> f64 {
    let a = C64::new(0.0, 2.0 * alpha) * (m - 1.0);
    let v = if a.norm() < 1e-3 {
        -0.5 - a / 3.0 - a * a / 8.0
    } else {
        -a.exp() / a + (a.exp() - 1.0) / (a * a)
    };
    4.0 * v.re
}

/// GOA extinction efficiency `Q_t = C_t / πr²`, Eq. 12 (App. B) summed over odd p ≤ p_max.
/// With `regularise`, the p = 1 term is the Fresnel-weighted ADT kernel (regularisation 4) and the
/// higher terms use the bounded `D_eff`.
pub fn extinction_efficiency(
    alpha: f64,
    m: C64,
    p_max: u32,
    regularise: bool,
    edge_correction: bool,
) -> f64 {
    let mut q = if edge_correction {
        2.0 + edge_term(alpha, m)
    } else {
        2.0
    };
    let mut p = 1;
    while p <= p_max {
        if p == 1 && regularise {
            let r0 = (1.0 - m) / (1.0 + m);
            // GOA's axial p = 1 amplitude is the ADT one times |m(1 − r0²)| = 4η²/(1+η)² (focusing and
            // Fresnel transmission); that factor fades to 1 in the ADT regime, so that Q → Q_ADT ≥ 0.
            let fresnel_factor =
                1.0 + ((m * (1.0 - r0 * r0)).norm() - 1.0) * ray_optics_weight(alpha, m);
            q += fresnel_factor * adt_excess(alpha, m);
        } else {
            q += 4.0 / (alpha * alpha) * axial_term(m, p, alpha, regularise).re;
        }
        p += 2;
    }
    q
}

/// Eq. 14: the closed form of Eq. 12 with p = 1 for a real η (as printed, valid for η > 1; for η < 1 the
/// focal phase of Eq. 10 flips the sign of the sine, which Eq. 12 and `extinction_efficiency` handle).
pub fn extinction_eq14(r_um: f64, wavelength_um: f64, eta: f64) -> f64 {
    let pi = PI;
    2.0 * pi * r_um * r_um
        + 4.0 * r_um * wavelength_um * eta * eta / ((eta + 1.0).powi(2) * (eta - 1.0).abs())
            * (4.0 * pi * r_um / wavelength_um * (1.0 - eta)).sin()
}

/// Eq. 13: absorption efficiency for weak absorption, `C_a/πr²`, with `(η_r²−1)^{3/2}` taken as 0 for
/// η_r < 1 (every refracted ray then stays inside the critical cone).
pub fn absorption_eq13(alpha: f64, m: C64) -> f64 {
    let (n, k) = (m.re, m.im);
    let c = (n * n - 1.0).max(0.0).powf(1.5);
    // 16π² r³ η_i [...]/(3 λ η_r) / (π r²) = (8/3) α η_i [...]/η_r
    8.0 / 3.0 * alpha * k * (n.powi(3) - c) / n
}

/// Geometric-optics absorption efficiency without the weak-absorption limit: every ray entering at θi
/// is absorbed with probability `(1 − R)(1 − T)/(1 − R T)` (the geometric series over internal
/// reflections), `T = ξ_1² = exp(−4αχ cos²θ't)`, averaged over polarisations and integrated over the
/// projected area. Reduces to Eq. 13 when `α κ → 0` (checked in tests) and never exceeds 1.
pub fn absorption_efficiency(alpha: f64, m: C64) -> f64 {
    if m.im <= 0.0 {
        return 0.0;
    }
    let hi = max_incidence(m, 1);
    let (x, w) = gauss_legendre(32);
    let panels = 8;
    let mut sum = 0.0;
    for k in 0..panels {
        let a = hi * k as f64 / panels as f64;
        let b = hi * (k + 1) as f64 / panels as f64;
        for (xi, wi) in x.iter().zip(&w) {
            let t = 0.5 * (a + b) + 0.5 * (b - a) * xi;
            let (s, c) = t.sin_cos();
            let bb = (m * m - s * s).sqrt();
            let br = bb.re.max(0.0);
            let eta_eff = (s * s + br * br).sqrt();
            let cos_t = br / eta_eff;
            // 1 − T per chord, without cancellation for thin absorption.
            let absorbed = -(-4.0 * alpha * bb.im * cos_t * cos_t).exp_m1();
            let r = fresnel(m, c, bb);
            let mut f = 0.0;
            for rj in r {
                // (1−R)(1−T)/(1−RT) written as ab/(a + b − ab) with a = 1−R, b = 1−T: no 0/0 when
                // both R and T round to 1 (grazing rays of weakly absorbing bubbles).
                let a = (1.0 - rj.norm_sqr()).max(0.0);
                let den = a + absorbed - a * absorbed;
                if den > 0.0 {
                    f += 0.5 * a * absorbed / den;
                }
            }
            // d(sin²θi) = sin 2θi dθi
            sum += 0.5 * (b - a) * wi * f * 2.0 * s * c;
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    fn real(n: f64) -> C64 {
        C64::new(n, 0.0)
    }

    /// Descartes' primary rainbow (p = 2) for water: minimum deviation at cos²θi = (m²−1)/3, found as
    /// the split point of the p = 2 branches, and both rays on the bright side are found.
    #[test]
    fn rainbow_branches() {
        let m = 1.333;
        let g = OrderGeometry::new(real(m), 2);
        assert_eq!(g.branches.len(), 2, "p = 2 must split at the rainbow");
        let ti_r = ((m * m - 1.0) / 3.0).sqrt().acos();
        let split = g.branches[0].samples.last().unwrap().theta_i;
        assert!((split - ti_r).abs() < 1e-9, "{split} vs {ti_r}");
        let theta_r = PI + g.branches[0].samples.last().unwrap().deflection; // θ = −θ_2 with l = 0
        let theta_rainbow = PI - theta_r; // scattering angle of the rainbow (~137.9°)
        assert!(
            (theta_rainbow.to_degrees() - 137.5).abs() < 1.0,
            "{}",
            theta_rainbow.to_degrees()
        );
        let mut rays = Vec::new();
        g.rays_at(real(m), theta_rainbow + 0.05, &mut rays);
        assert_eq!(rays.len(), 2, "bright side: two rays");
        rays.clear();
        g.rays_at(real(m), theta_rainbow - 0.05, &mut rays);
        assert_eq!(
            rays.len(),
            0,
            "dark side (Alexander's band side for p = 2): no ray"
        );
    }

    /// Every ray found satisfies Eq. 6 to rounding, for real, complex and bubble indices.
    #[test]
    fn roots_satisfy_eq6() {
        for m in [
            real(1.33),
            real(1.56),
            real(0.75),
            C64::new(1.5, 0.05),
            real(2.5),
        ] {
            let geo = GoaGeometry::new(m, 5);
            for k in 0..=90 {
                let theta = PI * k as f64 / 90.0;
                for order in &geo.orders {
                    let th = theta.clamp(THETA_EPS, PI - THETA_EPS);
                    for br in &order.branches {
                        for q in [1i32, -1] {
                            let (lo, hi) = (
                                br.samples[0].deflection,
                                br.samples.last().unwrap().deflection,
                            );
                            let (lo, hi) = (lo.min(hi), lo.max(hi));
                            let qt = q as f64 * th;
                            for l in ((lo - qt) / (2.0 * PI)).ceil() as i64
                                ..=((hi - qt) / (2.0 * PI)).floor() as i64
                            {
                                let target = qt + 2.0 * PI * l as f64;
                                let (ti, _) =
                                    solve_branch(m, order.p, br, target).expect("root in range");
                                let (dev, _) = deflection(m, order.p, ti);
                                assert!(
                                    (dev - target).abs() < 1e-9,
                                    "m={m} p={} θ={theta} dev={dev} target={target}",
                                    order.p
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    /// The exact geometric absorption reduces to Eq. 13 for weak absorption and never exceeds 1.
    #[test]
    fn absorption_limits() {
        for n in [1.1, 1.33, 1.5, 2.0, 0.8] {
            let m = C64::new(n, 1e-7);
            let (a, b) = (absorption_efficiency(100.0, m), absorption_eq13(100.0, m));
            assert!((a / b - 1.0).abs() < 0.02, "n={n}: {a} vs Eq.13 {b}");
        }
        let strong = absorption_efficiency(1e4, C64::new(1.5, 0.5));
        assert!(strong > 0.8 && strong <= 1.0, "{strong}");
    }

    /// Eq. 12 with p = 1 (paper verbatim) equals the closed form Eq. 14 for η > 1.
    #[test]
    fn eq12_matches_eq14() {
        let (lam, eta) = (0.6, 1.33);
        for r in [1.0, 7.3, 50.0, 400.0] {
            let alpha = 2.0 * PI * r / lam;
            let q12 = extinction_efficiency(alpha, real(eta), 1, false, false);
            let q14 = extinction_eq14(r, lam, eta) / (PI * r * r);
            assert!(
                (q12 - q14).abs() < 1e-9 * q14.abs(),
                "r={r}: {q12} vs {q14}"
            );
        }
    }

    /// η → 1: the regularised extinction tends to 0 (the particle disappears); the paper's diverges.
    #[test]
    fn eta_to_one() {
        let alpha = 1000.0;
        let q = extinction_efficiency(alpha, real(1.0 + 1e-9), 3, true, false);
        assert!(q.abs() < 1e-3, "{q}");
        let paper = extinction_efficiency(alpha, real(1.0 + 1e-9), 3, false, false);
        assert!(paper.abs() > 1.0, "{paper}");
    }

    /// Amplitudes are finite everywhere with regularisation, including θ = 0, π and the caustics.
    #[test]
    fn finite_everywhere() {
        let opts = GoaOptions::default();
        for m in [
            real(1.0),
            real(1.33),
            real(0.75),
            C64::new(2.5, 0.5),
            real(1.414),
        ] {
            let geo = GoaGeometry::new(m, 3);
            let mut scratch = Vec::new();
            for alpha in [0.1, 10.0, 3e4] {
                for k in 0..=2000 {
                    let theta = PI * k as f64 / 2000.0;
                    let (s1, s2) = geo.amplitudes(alpha, theta, &opts, &mut scratch);
                    assert!(
                        s1.norm().is_finite() && s2.norm().is_finite(),
                        "m={m} α={alpha} θ={theta}"
                    );
                }
            }
        }
    }
}
