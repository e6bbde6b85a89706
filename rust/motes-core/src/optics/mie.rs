//! Lorenz–Mie theory for a homogeneous sphere (paper App. A, Eq. 26–30).
//!
//! Conventions: Bohren & Huffman (time factor `exp(-iωt)`), so an absorbing particle has a relative
//! index `m = n + iκ` with `κ ≥ 0`, and `C_ext = 4π/k² Re S(0)` (Eq. 3).
//!
//! Numerics (stable up to size parameters of a few 1e4 and |m x| ~ 1e5):
//! * the logarithmic derivative `D_n(mx) = ψ'_n(mx)/ψ_n(mx)` is obtained by *downward* recurrence
//!   ([`log_derivative_downward`]) from `n_start = max(N, |mx| + 8 |mx|^{1/3}) + 32` (Bohren & Huffman
//!   §4.8); the downward direction is stable for every complex argument, including strongly absorbing
//!   ones where upward recurrence overflows;
//! * the Riccati–Bessel functions of the real argument `x` go upward ([`riccati_bessel_upward`]); they
//!   are only needed for `n ≤ N ≈ x + 4.3 x^{1/3}`, where the upward recurrence of `ψ_n` has lost at
//!   most a few digits and `a_n, b_n` are already negligible (Wiscombe 1980);
//! * `a_n`, `b_n` combine the two (Eq. 27, Bohren & Huffman 4.88).
//! * the series length is the larger of the paper's `⌈x + 4.3 x^{1/3} + 1⌉` and Wiscombe's
//!   `x + 4.05 x^{1/3} + 2`.

use num_complex::Complex64 as C64;
use rayon::prelude::*;

/// Number of terms kept in the partial-wave series for size parameter `x`.
pub fn series_length(x: f64) -> usize {
    let cbrt = x.cbrt();
    let paper = (x + 4.3 * cbrt + 1.0).ceil();
    let wiscombe = (x + 4.05 * cbrt + 2.0).ceil();
    paper.max(wiscombe).max(2.0) as usize
}

/// Mie coefficients `a_n`, `b_n` (n = 1..=N) of one sphere, with the efficiencies they imply.
#[derive(Clone, Debug)]
pub struct MieCoefficients {
    /// Size parameter `x = k r` in the host medium.
    pub x: f64,
    /// Relative refractive index `m = η_particle / η_medium` (BH convention, Im ≥ 0).
    pub m: C64,
    /// `a[n-1] = a_n`.
    pub a: Vec<C64>,
    /// `b[n-1] = b_n`.
    pub b: Vec<C64>,
}

/// Where the downward recurrence of `D_n(mx)` starts for a series of `n_max` terms: well beyond
/// |mx|, because the error of the arbitrary start value D = 0 decays only once n exceeds |mx| by a margin
/// growing like |mx|^{1/3} (measured against mpmath at 1e-15).
fn log_derivative_start(n_max: usize, mx: C64) -> usize {
    let mxn = mx.norm();
    (n_max as f64).max(mxn + 8.0 * mxn.cbrt()).ceil() as usize + 32
}

/// The logarithmic derivative `D_n(z) = ψ'_n(z)/ψ_n(z)` for n = 0..=`n_start` by downward recurrence
/// `D_{n−1} = n/z − 1/(D_n + n/z)` from `D_{n_start} = 0` (Bohren & Huffman §4.8; stable for every
/// complex z, strongly absorbing ones included). Entries near `n_start` carry the start's error; use
/// those below `log_derivative_start`'s margin.
pub fn log_derivative_downward(z: C64, n_start: usize) -> Vec<C64> {
    let mut d = vec![C64::new(0.0, 0.0); n_start + 1];
    for n in (1..=n_start).rev() {
        let nz = n as f64 / z;
        d[n - 1] = nz - 1.0 / (d[n] + nz);
    }
    d
}

/// The Riccati–Bessel functions `ψ_n(x)` and `χ_n(x)` (with `ξ_n = ψ_n − i χ_n`) for n = 0..=`n_max`
/// by upward recurrence `f_n = (2n − 1)/x f_{n−1} − f_{n−2}` from `ψ_0 = sin x`, `χ_0 = cos x`. Upward
/// `ψ_n` loses digits once n exceeds x; the series stops at n ≈ x + 4.3 x^{1/3}, where a few digits are
/// lost and the coefficients are negligible (Wiscombe 1980).
pub fn riccati_bessel_upward(x: f64, n_max: usize) -> Vec<(f64, f64)> {
    let (sx, cx) = x.sin_cos();
    let mut out = Vec::with_capacity(n_max + 1);
    out.push((sx, cx));
    if n_max >= 1 {
        out.push((sx / x - cx, cx / x + sx));
    }
    for n in 2..=n_max {
        let k = (2 * n - 1) as f64 / x;
        let (p1, c1) = out[n - 1];
        let (p2, c2) = out[n - 2];
        out.push((k * p1 - p2, k * c1 - c2));
    }
    out
}

/// The coefficients `a_n`, `b_n` (Eq. 27, Bohren & Huffman 4.88) from `D_n(mx)` and the Riccati–Bessel
/// functions of x at orders n and n − 1.
#[inline]
fn an_bn(n: usize, x: f64, m: C64, dn: C64, rb: (f64, f64), rb_prev: (f64, f64)) -> (C64, C64) {
    let nf = n as f64;
    let (psi, psi_prev) = (rb.0, rb_prev.0);
    let xi = C64::new(rb.0, -rb.1);
    let xi_prev = C64::new(rb_prev.0, -rb_prev.1);
    let ta = dn / m + nf / x;
    let tb = dn * m + nf / x;
    (
        (ta * psi - psi_prev) / (ta * xi - xi_prev),
        (tb * psi - psi_prev) / (tb * xi - xi_prev),
    )
}

impl MieCoefficients {
    pub fn new(x: f64, m: C64) -> Self {
        let nmax = series_length(x);
        if m == C64::new(1.0, 0.0) {
            // A sphere of its medium's index is no sphere: a_n = b_n = 0 exactly (the recurrences
            // would give rounding noise, Q_ext ~ 1e-25, and a phase function of it).
            let zero = vec![C64::new(0.0, 0.0); nmax];
            return MieCoefficients {
                x,
                m,
                a: zero.clone(),
                b: zero,
            };
        }
        let mx = m * x;
        let d = log_derivative_downward(mx, log_derivative_start(nmax, mx));
        let rb = riccati_bessel_upward(x, nmax);
        let (a, b) = (1..=nmax)
            .map(|n| an_bn(n, x, m, d[n], rb[n], rb[n - 1]))
            .unzip();
        MieCoefficients { x, m, a, b }
    }

    /// Extinction efficiency `Q_ext = 2/x² Σ (2n+1) Re(a_n + b_n)` (Eq. 28 divided by πr²).
    pub fn q_ext(&self) -> f64 {
        let s: f64 = (0..self.a.len())
            .map(|i| (2.0 * (i as f64 + 1.0) + 1.0) * (self.a[i] + self.b[i]).re)
            .sum();
        2.0 * s / (self.x * self.x)
    }

    /// Scattering efficiency `Q_sca = 2/x² Σ (2n+1)(|a_n|² + |b_n|²)` (Eq. 29 for a real host index).
    pub fn q_sca(&self) -> f64 {
        let s: f64 = (0..self.a.len())
            .map(|i| (2.0 * (i as f64 + 1.0) + 1.0) * (self.a[i].norm_sqr() + self.b[i].norm_sqr()))
            .sum();
        2.0 * s / (self.x * self.x)
    }

    /// Asymmetry parameter g = <cos θ> (Bohren & Huffman Eq. 4.62).
    pub fn g(&self) -> f64 {
        let n_terms = self.a.len();
        let mut s = 0.0;
        for i in 0..n_terms {
            let n = i as f64 + 1.0;
            if i + 1 < n_terms {
                s += n * (n + 2.0) / (n + 1.0)
                    * (self.a[i] * self.a[i + 1].conj() + self.b[i] * self.b[i + 1].conj()).re;
            }
            s += (2.0 * n + 1.0) / (n * (n + 1.0)) * (self.a[i] * self.b[i].conj()).re;
        }
        let qsca = self.q_sca();
        if qsca > 0.0 {
            4.0 * s / (self.x * self.x * qsca)
        } else {
            0.0
        }
    }

    /// The weights `c_n a_n`, `c_n b_n` with `c_n = (2n+1)/(n(n+1))` of Eq. 26–27.
    pub fn weighted(&self) -> MieAngularSeries {
        let (wa, wb) = self
            .a
            .iter()
            .zip(&self.b)
            .enumerate()
            .map(|(i, (a, b))| {
                let n = i as f64 + 1.0;
                let c = (2.0 * n + 1.0) / (n * (n + 1.0));
                (a * c, b * c)
            })
            .unzip();
        MieAngularSeries { wa, wb }
    }
}

/// Pre-weighted coefficients for fast evaluation of S1, S2 at many angles.
pub struct MieAngularSeries {
    wa: Vec<C64>,
    wb: Vec<C64>,
}

impl MieAngularSeries {
    /// `(S1, S2)` at `μ = cos θ` by Eq. 26–27, with the angular functions by upward recurrence
    /// `π_n = ((2n-1) μ π_{n-1} - n π_{n-2})/(n-1)`, `τ_n = n μ π_n - (n+1) π_{n-1}`
    /// (stable: |π_n| ≤ n(n+1)/2).
    #[inline]
    pub fn amplitudes(&self, mu: f64) -> (C64, C64) {
        let mut pi_prev = 0.0f64; // π_0
        let mut pi = 1.0f64; // π_1
        let (mut s1r, mut s1i, mut s2r, mut s2i) = (0.0, 0.0, 0.0, 0.0);
        for i in 0..self.wa.len() {
            let n = i as f64 + 1.0;
            if i > 0 {
                let p = ((2.0 * n - 1.0) * mu * pi - n * pi_prev) / (n - 1.0);
                pi_prev = pi;
                pi = p;
            }
            let tau = n * mu * pi - (n + 1.0) * pi_prev;
            let (a, b) = (self.wa[i], self.wb[i]);
            s1r += a.re * pi + b.re * tau;
            s1i += a.im * pi + b.im * tau;
            s2r += b.re * pi + a.re * tau;
            s2i += b.im * pi + a.im * tau;
        }
        (C64::new(s1r, s1i), C64::new(s2r, s2i))
    }

    /// Amplitudes at many angles (radians), in parallel.
    pub fn amplitudes_many(&self, theta: &[f64]) -> Vec<(C64, C64)> {
        if theta.len() * self.wa.len() < 20_000 {
            theta.iter().map(|t| self.amplitudes(t.cos())).collect()
        } else {
            theta.par_iter().map(|t| self.amplitudes(t.cos())).collect()
        }
    }
}

/// Weighted sums over spheres of products of their Mie coefficients ([`MieIntensitySums`],
/// [`MieMuellerSums`]): made for a largest series length, added to sphere by sphere, merged.
pub trait CoefficientSums: Sized {
    /// Empty sums for spheres of series length up to `n_max` ([`series_length`]).
    fn with_len(n_max: usize) -> Self;
    /// Adds one sphere with weight `w`.
    fn add_sphere(&mut self, c: &MieCoefficients, w: f64);
    /// Adds the sums of `other` (of any size up to this one's).
    fn merge_from(&mut self, other: &Self);
}

macro_rules! coefficient_sums {
    ($t:ty) => {
        impl CoefficientSums for $t {
            fn with_len(n_max: usize) -> Self {
                Self::new(n_max)
            }
            fn add_sphere(&mut self, c: &MieCoefficients, w: f64) {
                self.add(c, w)
            }
            fn merge_from(&mut self, other: &Self) {
                self.merge(other)
            }
        }
    };
}
coefficient_sums!(MieIntensitySums);
coefficient_sums!(MieMuellerSums);

/// Weighted sums over many spheres (one wavelength) of the products of their Mie coefficients, from which
/// `Σ_i w_i (|S1|² + |S2|²)` follows at any angle — the numerator of the ensemble phase function
/// (paper Eq. 17) — at O(N²) per sphere and per angle instead of O(N) per sphere *and* angle.
///
/// With `A_n = c_n a_n`, `B_n = c_n b_n` (Eq. 26–27): `|S1|² + |S2|² = Σ_nm U_nm (π_n π_m + τ_n τ_m)
/// + V_nm (π_n τ_m + τ_n π_m)`, `U_nm = Re(A_n A_m* + B_n B_m*)`, `V_nm = Re(A_n B_m* + B_n A_m*)`, both
/// symmetric: the sums keep the upper triangles of `Σ w U` and `Σ w V`.
#[derive(Clone, Debug)]
pub struct MieIntensitySums {
    n: usize,
    u: Vec<f64>,
    v: Vec<f64>,
}

impl MieIntensitySums {
    /// Empty sums for spheres of series length up to `n_max` ([`series_length`]).
    pub fn new(n_max: usize) -> Self {
        MieIntensitySums {
            n: n_max,
            u: vec![0.0; n_max * n_max],
            v: vec![0.0; n_max * n_max],
        }
    }

    /// Adds one sphere with weight `w`.
    pub fn add(&mut self, c: &MieCoefficients, w: f64) {
        let k = c.a.len();
        assert!(k <= self.n, "series length {k} beyond the sums' {}", self.n);
        let s = c.weighted();
        let (ar, ai): (Vec<f64>, Vec<f64>) = s.wa.iter().map(|z| (z.re, z.im)).unzip();
        let (br, bi): (Vec<f64>, Vec<f64>) = s.wb.iter().map(|z| (z.re, z.im)).unzip();
        for i in 0..k {
            let (wr, wi, vr, vi) = (w * ar[i], w * ai[i], w * br[i], w * bi[i]);
            let row = i * self.n;
            let (u, v) = (&mut self.u[row + i..row + k], &mut self.v[row + i..row + k]);
            for (j, (u, v)) in (i..k).zip(u.iter_mut().zip(v.iter_mut())) {
                *u += wr * ar[j] + wi * ai[j] + vr * br[j] + vi * bi[j];
                *v += wr * br[j] + wi * bi[j] + vr * ar[j] + vi * ai[j];
            }
        }
    }

    /// Adds the sums of `other` (of any size up to this one's).
    pub fn merge(&mut self, other: &MieIntensitySums) {
        assert!(other.n <= self.n);
        for i in 0..other.n {
            let (a, b) = (i * self.n, i * other.n);
            for j in i..other.n {
                self.u[a + j] += other.u[b + j];
                self.v[a + j] += other.v[b + j];
            }
        }
    }

    /// `Σ w (|S1|² + |S2|²)` at `μ = cos θ`.
    pub fn intensity(&self, mu: f64) -> f64 {
        let n = self.n;
        let (pi, tau) = angular_functions(n, mu);
        let mut total = 0.0;
        for i in 0..n {
            let (a, b) = (pi[i], tau[i]);
            let row = i * n;
            let (u, v) = (&self.u[row + i..row + n], &self.v[row + i..row + n]);
            // Off-diagonal pairs count twice, the diagonal once.
            let mut acc = 0.5 * (u[0] * (a * a + b * b) + v[0] * 2.0 * a * b);
            for ((u, v), (pj, tj)) in u[1..]
                .iter()
                .zip(&v[1..])
                .zip(pi[i + 1..].iter().zip(&tau[i + 1..]))
            {
                acc += u * (a * pj + b * tj) + v * (a * tj + b * pj);
            }
            total += 2.0 * acc;
        }
        // A sum of squares, evaluated as a quadratic form in the coefficients: where the intensity is
        // tiny against the terms (deep minima, index-matched spheres) it rounds to a few 1e-16 of them,
        // of either sign. Clamped here, at its source, so that a phase table never holds a negative.
        total.max(0.0)
    }
}

/// The angular functions `π_n`, `τ_n` (n = 1..=`n`) at `μ = cos θ` by the upward recurrence of
/// [`MieAngularSeries::amplitudes`].
fn angular_functions(n: usize, mu: f64) -> (Vec<f64>, Vec<f64>) {
    let (mut pi, mut tau) = (vec![0.0; n], vec![0.0; n]);
    let (mut pi_prev, mut p) = (0.0f64, 1.0f64);
    for i in 0..n {
        let nf = i as f64 + 1.0;
        if i > 0 {
            let next = ((2.0 * nf - 1.0) * mu * p - nf * pi_prev) / (nf - 1.0);
            pi_prev = p;
            p = next;
        }
        pi[i] = p;
        tau[i] = nf * mu * p - (nf + 1.0) * pi_prev;
    }
    (pi, tau)
}

/// The Mueller elements `[F11, F12, F33, F34]` of amplitudes `(S1, S2)` in Bohren & Huffman's convention
/// (BH 1983 §4.4, Eq. 3.16 for a sphere): `F11 = (|S2|² + |S1|²)/2`, `F12 = (|S2|² − |S1|²)/2`,
/// `F33 = Re(S2 S1*)`, `F34 = Im(S2 S1*)`. With BH's `m = n + iκ` (this crate's), a code using
/// `m = n − iκ` has conjugate amplitudes and the opposite F34.
#[inline]
pub fn mueller_elements(s1: C64, s2: C64) -> [f64; 4] {
    let (i1, i2) = (s1.norm_sqr(), s2.norm_sqr());
    let c = s2 * s1.conj();
    [0.5 * (i2 + i1), 0.5 * (i2 - i1), c.re, c.im]
}

/// Weighted sums over many spheres (one wavelength) of the products of their Mie coefficients, from which
/// the four Mueller elements `Σ_i w_i [F11, F12, F33, F34]` ([`mueller_elements`]) follow at any angle:
/// the polarised counterpart of [`MieIntensitySums`], O(N²) per sphere and per angle.
///
/// With `A_n = c_n a_n`, `B_n = c_n b_n` (Eq. 26–27: `S1 = Σ A_n π_n + B_n τ_n`, `S2 = Σ B_n π_n + A_n τ_n`)
/// and the sums `P_nm = Σ w A_n A_m*`, `Q_nm = Σ w B_n B_m*` (Hermitian), `R_nm = Σ w A_n B_m*`:
/// * `2 F11 = Σ Re(P+Q)_nm (π_n π_m + τ_n τ_m) + 2 Re R_nm (π_n τ_m + τ_n π_m)`,
/// * `2 F12 = Σ Re(Q−P)_nm (π_n π_m − τ_n τ_m) + 2 Re R_nm (τ_n π_m − π_n τ_m)`,
/// * `F33 = Σ Re R_nm (π_n π_m + τ_n τ_m) + Re(P+Q)_nm π_n τ_m`,
/// * `F34 = Σ Im R_nm (τ_n τ_m − π_n π_m) + Im(Q−P)_nm π_n τ_m`.
///
/// `Re(P+Q)`, `Re(Q−P)` are symmetric (upper triangles kept), `Im(Q−P)` antisymmetric (strict upper
/// triangle kept), `R` has no symmetry (kept whole).
#[derive(Clone, Debug)]
pub struct MieMuellerSums {
    n: usize,
    /// Σ w Re(P + Q), upper triangle.
    u: Vec<f64>,
    /// Σ w Re(Q − P), upper triangle.
    d: Vec<f64>,
    /// Σ w Im(Q − P), strict upper triangle.
    e: Vec<f64>,
    /// Σ w Re R and Σ w Im R, whole.
    r_re: Vec<f64>,
    r_im: Vec<f64>,
}

impl MieMuellerSums {
    /// Empty sums for spheres of series length up to `n_max` ([`series_length`]).
    pub fn new(n_max: usize) -> Self {
        let z = vec![0.0; n_max * n_max];
        MieMuellerSums {
            n: n_max,
            u: z.clone(),
            d: z.clone(),
            e: z.clone(),
            r_re: z.clone(),
            r_im: z,
        }
    }

    /// Adds one sphere with weight `w`.
    pub fn add(&mut self, c: &MieCoefficients, w: f64) {
        let k = c.a.len();
        assert!(k <= self.n, "series length {k} beyond the sums' {}", self.n);
        let s = c.weighted();
        let (a, b) = (&s.wa, &s.wb);
        for i in 0..k {
            let (wa, wb) = (a[i] * w, b[i] * w);
            let row = i * self.n;
            for j in 0..k {
                let r = wa * b[j].conj();
                self.r_re[row + j] += r.re;
                self.r_im[row + j] += r.im;
                if j >= i {
                    let (p, q) = (wa * a[j].conj(), wb * b[j].conj());
                    self.u[row + j] += p.re + q.re;
                    self.d[row + j] += q.re - p.re;
                    self.e[row + j] += q.im - p.im;
                }
            }
        }
    }

    /// Adds the sums of `other` (of any size up to this one's).
    pub fn merge(&mut self, other: &MieMuellerSums) {
        assert!(other.n <= self.n);
        for i in 0..other.n {
            let (a, b) = (i * self.n, i * other.n);
            for j in 0..other.n {
                self.r_re[a + j] += other.r_re[b + j];
                self.r_im[a + j] += other.r_im[b + j];
                if j >= i {
                    self.u[a + j] += other.u[b + j];
                    self.d[a + j] += other.d[b + j];
                    self.e[a + j] += other.e[b + j];
                }
            }
        }
    }

    /// `Σ w [F11, F12, F33, F34]` at `μ = cos θ` (F11 clamped at 0 against rounding, as
    /// [`MieIntensitySums::intensity`]).
    pub fn elements(&self, mu: f64) -> [f64; 4] {
        let n = self.n;
        let (pi, tau) = angular_functions(n, mu);
        let (mut t11, mut t12, mut f33, mut f34) = (0.0, 0.0, 0.0, 0.0);
        for i in 0..n {
            let (pi_i, tau_i) = (pi[i], tau[i]);
            let row = i * n;
            // R over the whole row.
            for j in 0..n {
                let (pp, tt) = (pi_i * pi[j], tau_i * tau[j]);
                let (pt, tp) = (pi_i * tau[j], tau_i * pi[j]);
                let (rr, ri) = (self.r_re[row + j], self.r_im[row + j]);
                t11 += 2.0 * rr * (pt + tp);
                t12 += 2.0 * rr * (tp - pt);
                f33 += rr * (pp + tt);
                f34 += ri * (tt - pp);
            }
            // The symmetric parts: the diagonal once, off-diagonal pairs (i, j) and (j, i) together.
            let (u, d) = (self.u[row + i], self.d[row + i]);
            t11 += u * (pi_i * pi_i + tau_i * tau_i);
            t12 += d * (pi_i * pi_i - tau_i * tau_i);
            f33 += u * pi_i * tau_i;
            for j in i + 1..n {
                let (pp, tt) = (pi_i * pi[j], tau_i * tau[j]);
                let (pt, tp) = (pi_i * tau[j], tau_i * pi[j]);
                let (u, d, e) = (self.u[row + j], self.d[row + j], self.e[row + j]);
                t11 += 2.0 * u * (pp + tt);
                t12 += 2.0 * d * (pp - tt);
                f33 += u * (pt + tp);
                // Antisymmetric: Im(Q−P)_ij π_i τ_j + Im(Q−P)_ji π_j τ_i = e_ij (π_i τ_j − τ_i π_j).
                f34 += e * (pt - tp);
            }
        }
        [(0.5 * t11).max(0.0), 0.5 * t12, f33, f34]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// D_n from the downward recurrence equals ψ'_n/ψ_n = ψ_{n−1}/ψ_n − n/z from closed forms of ψ_0,
    /// ψ_1, ψ_2 at complex arguments (absorbing included), well below the start of the recurrence.
    #[test]
    fn log_derivative_matches_closed_forms() {
        for z in [
            C64::new(0.7, 0.0),
            C64::new(3.2, 0.4),
            C64::new(12.0, 2.5),
            C64::new(0.4, 0.05),
        ] {
            let psi0 = z.sin();
            let psi1 = z.sin() / z - z.cos();
            let psi2 = (3.0 / (z * z) - 1.0) * z.sin() - 3.0 * z.cos() / z;
            let d = log_derivative_downward(z, log_derivative_start(4, z));
            let d1 = psi0 / psi1 - 1.0 / z;
            let d2 = psi1 / psi2 - 2.0 / z;
            assert!(
                (d[1] - d1).norm() < 1e-12 * d1.norm().max(1.0),
                "{z}: {} vs {d1}",
                d[1]
            );
            assert!(
                (d[2] - d2).norm() < 1e-12 * d2.norm().max(1.0),
                "{z}: {} vs {d2}",
                d[2]
            );
        }
    }

    /// ψ_n, χ_n from the upward recurrence: the closed forms at n = 2 and the Wronskian
    /// ψ_n χ_{n−1} − ψ_{n−1} χ_n = −1 up to the series length.
    #[test]
    fn riccati_bessel_closed_forms_and_wronskian() {
        for x in [0.3, 2.0, 17.5, 250.0] {
            let n_max = series_length(x);
            let rb = riccati_bessel_upward(x, n_max);
            let (s, c) = x.sin_cos();
            let psi2 = (3.0 / (x * x) - 1.0) * s - 3.0 * c / x;
            let chi2 = (3.0 / (x * x) - 1.0) * c + 3.0 * s / x;
            assert!((rb[2].0 - psi2).abs() < 1e-12 * psi2.abs().max(1.0));
            assert!((rb[2].1 - chi2).abs() < 1e-12 * chi2.abs().max(1.0));
            for n in 1..=n_max {
                let w = rb[n].0 * rb[n - 1].1 - rb[n - 1].0 * rb[n].1;
                assert!((w + 1.0).abs() < 1e-9, "x {x} n {n}: {w}");
            }
        }
    }

    /// m = 1 (the sphere is the host): no scattering, every a_n and b_n is 0.
    #[test]
    fn coefficients_vanish_for_an_index_match() {
        for x in [0.5, 8.0, 120.0] {
            let c = MieCoefficients::new(x, C64::new(1.0, 0.0));
            assert!(c.a.iter().chain(&c.b).all(|v| v.norm() < 1e-12), "x {x}");
        }
    }

    /// Rayleigh limit: Q_sca = 8/3 x⁴ |(m²−1)/(m²+2)|² and Q_abs = 4x Im((m²−1)/(m²+2)) for x → 0.
    #[test]
    fn rayleigh_limit() {
        let m = C64::new(1.5, 0.1);
        let x = 1e-3;
        let c = MieCoefficients::new(x, m);
        let pol = (m * m - 1.0) / (m * m + 2.0);
        let qsca = 8.0 / 3.0 * x.powi(4) * pol.norm_sqr();
        let qabs = 4.0 * x * pol.im;
        assert!(
            (c.q_sca() / qsca - 1.0).abs() < 1e-4,
            "{} vs {}",
            c.q_sca(),
            qsca
        );
        assert!(((c.q_ext() - c.q_sca()) / qabs - 1.0).abs() < 1e-4);
    }

    /// Spheres (x, m, weight) of the sums tests: clear, weakly and strongly absorbing, a bubble.
    const SPHERES: [(f64, C64, f64); 5] = [
        (3.7, C64::new(1.33, 0.0), 0.3),
        (41.2, C64::new(1.31, 1e-4), 1.7),
        (0.4, C64::new(2.0, 0.5), 5.0),
        (17.0, C64::new(0.75, 0.0), 0.9),
        (9.3, C64::new(1.5, 0.2), 2.2),
    ];

    /// The sums of `spheres` (x, m, weight): the first added to sums of its own size, merged into sums
    /// of the largest size, the others added there.
    fn summed<S: CoefficientSums>(spheres: &[(f64, C64, f64)]) -> S {
        let n_max = spheres.iter().map(|s| series_length(s.0)).max().unwrap();
        let mut sums = S::with_len(n_max);
        let (x, m, w) = spheres[0];
        let mut part = S::with_len(series_length(x));
        part.add_sphere(&MieCoefficients::new(x, m), w);
        sums.merge_from(&part);
        for &(x, m, w) in &spheres[1..] {
            sums.add_sphere(&MieCoefficients::new(x, m), w);
        }
        sums
    }

    /// The coefficient-product sums give the same summed intensity as the amplitudes, at every angle.
    #[test]
    fn intensity_sums_match_amplitudes() {
        let spheres = SPHERES;
        let sums: MieIntensitySums = summed(&spheres);
        for theta in [0.0, 0.01, 0.7, 1.5707963, 2.9, 3.1, std::f64::consts::PI] {
            let direct: f64 = spheres
                .iter()
                .map(|&(x, m, w)| {
                    let (s1, s2) = MieCoefficients::new(x, m)
                        .weighted()
                        .amplitudes(f64::cos(theta));
                    w * (s1.norm_sqr() + s2.norm_sqr())
                })
                .sum();
            let got = sums.intensity(f64::cos(theta));
            assert!(
                (got / direct - 1.0).abs() < 1e-11,
                "theta {theta}: {got} vs {direct}"
            );
        }
    }

    /// The coefficient-space Mueller sums give the weighted sums of the four elements of the amplitudes
    /// (`mueller_elements` of S1, S2 from Eq. 26–27) at every angle, absorbing spheres and a bubble
    /// included, merged sums too; errors relative to F11 (F12, F33, F34 cross zero).
    #[test]
    fn mueller_sums_match_amplitude_products() {
        let spheres = SPHERES;
        let sums: MieMuellerSums = summed(&spheres);
        let mut saw_f34 = false;
        for theta in [
            0.0,
            0.01,
            0.7,
            1.5707963,
            2.2,
            2.9,
            3.1,
            std::f64::consts::PI,
        ] {
            let mu = f64::cos(theta);
            let mut direct = [0.0; 4];
            for &(x, m, w) in &spheres {
                let (s1, s2) = MieCoefficients::new(x, m).weighted().amplitudes(mu);
                for (d, v) in direct.iter_mut().zip(mueller_elements(s1, s2)) {
                    *d += w * v;
                }
            }
            let got = sums.elements(mu);
            for k in 0..4 {
                assert!(
                    (got[k] - direct[k]).abs() < 1e-11 * direct[0],
                    "theta {theta} element {k}: {got:?} vs {direct:?}"
                );
            }
            saw_f34 |= direct[3].abs() > 1e-3 * direct[0];
        }
        assert!(saw_f34, "the test must exercise a non-zero F34");
    }

    /// A sphere of its medium's index has no coefficients (Q = 0 exactly, not rounding noise), and the
    /// intensity sums never go negative, there or near it (issue 44: a phase table of −4e-17).
    #[test]
    fn index_matched_sphere_scatters_nothing_and_sums_stay_non_negative() {
        let c = MieCoefficients::new(300.0, C64::new(1.0, 0.0));
        assert_eq!((c.q_ext(), c.q_sca()), (0.0, 0.0));
        for m in [
            C64::new(1.0, 0.0),
            C64::new(1.0 + 1e-9, 0.0),
            C64::new(1.0001, 0.0),
        ] {
            let mut sums = MieIntensitySums::new(series_length(300.0));
            for x in [250.0, 270.0, 300.0] {
                sums.add(&MieCoefficients::new(x, m), 1.0);
            }
            for k in 0..=2000 {
                let mu = (std::f64::consts::PI * k as f64 / 2000.0).cos();
                assert!(sums.intensity(mu) >= 0.0, "{m} at mu {mu}");
            }
        }
    }

    /// Optical theorem in BH convention: Q_ext = 4/x² Re S(0), and S1(0) = S2(0), S2(π) = −S1(π).
    #[test]
    fn forward_and_backward_symmetry() {
        for (x, m) in [
            (5.0, C64::new(1.33, 0.0)),
            (300.0, C64::new(1.5, 0.01)),
            (50.0, C64::new(0.75, 0.0)),
        ] {
            let c = MieCoefficients::new(x, m);
            let s = c.weighted();
            let (s1, s2) = s.amplitudes(1.0);
            assert!((s1 - s2).norm() < 1e-9 * s1.norm());
            assert!((4.0 / (x * x) * s1.re / c.q_ext() - 1.0).abs() < 1e-9);
            let (b1, b2) = s.amplitudes(-1.0);
            assert!((b1 + b2).norm() < 1e-9 * b1.norm().max(1e-300));
        }
    }

    /// Large non-absorbing spheres: Q_ext → 2 (extinction paradox) and Q_sca = Q_ext.
    #[test]
    fn extinction_paradox() {
        let c = MieCoefficients::new(20000.0, C64::new(1.33, 0.0));
        assert!((c.q_ext() - 2.0).abs() < 0.01);
        assert!((c.q_sca() / c.q_ext() - 1.0).abs() < 1e-9);
    }
}
