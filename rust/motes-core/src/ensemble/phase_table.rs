//! Tabulated phase functions with consistent evaluation, pdf and inverse-CDF sampling.
//!
//! The table is piecewise linear in μ = cos θ between its nodes. With the graded angle grid of
//! [`crate::ensemble::graded_angles`] (log-spaced in θ through the diffraction lobe) the nodes crowd
//! where the phase function is narrow. Evaluation is linear interpolation (O(log n)); the CDF in μ is
//! piecewise quadratic and inverted in closed form (O(log n) per sample). `eval` is exactly the density
//! that `sample` draws from, so the two are consistent by construction; normalisation is exact for the
//! interpolant (∫ f dΩ = 1).
//!
//! Both searches start from a directory ([`Directory`]): the nodes' segment range per bucket of a
//! monotone key (for μ, sin(θ/2) on a log scale through the forward peak, then linear, then cos(θ/2)
//! linear towards the back: about one node per bucket on the graded grid, [`ANGLE_BUCKETS`]; for
//! sampling, the CDF itself), so that a lookup searches a few nodes of its bucket instead of the whole
//! table (the renderer evaluates a mixture's tables per channel and member at every bounce: the search
//! was half of the scalar Cornell box's phase-function time). Tables on the same nodes (a bin's at each
//! wavelength) share one location of μ ([`PhaseTable::locate`]).
//!
//! Paper: the tabulated ensemble phase function of Eq. 17 (and a particle's, Eq. 1) as a renderer
//! evaluates and importance-samples it (Sec. 5.5).

use crate::error::{require, OpticsError};
use std::f64::consts::{FRAC_1_SQRT_2, PI};

/// A [`PhaseTable`]'s sampling data by address ([`PhaseTable::sampling_view`]): its interleaved nodes
/// (P(μ' ≤ μ_i), μ_i, f_i), its sampling directory's [first, last] segment per CDF bucket
/// ([`CDF_BUCKETS`] of them, every one covered) and its node count (at least two).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SamplingView {
    pub nodes: *const [f64; 3],
    pub ranges: *const [u32; 2],
    pub n_nodes: usize,
}

#[derive(Clone, Debug)]
pub struct PhaseTable {
    /// Increasing μ nodes from −1 to 1.
    mu: Vec<f64>,
    /// f at the nodes, sr⁻¹, normalised.
    f: Vec<f64>,
    /// P(μ' ≤ μ_i).
    cdf: Vec<f64>,
    /// Segments by bucket of sin(θ/2) = sqrt((1 − μ) / 2) (evaluation).
    by_angle: Directory,
    /// Segments by bucket of the CDF (sampling).
    by_cdf: Directory,
    /// (P(μ' ≤ μ_i), μ_i, f_i) side by side: what a sample reads, from one or two cache lines
    /// instead of one per array (the three arrays of a bin's channels outgrow the L1 cache).
    nodes: Vec<[f64; 3]>,
}

/// Buckets of the sampling [`Directory`] (by CDF value).
pub(crate) const CDF_BUCKETS: usize = 512;

/// The evaluation directory's buckets, three runs of [`ANGLE_RUN`] each in order of increasing θ:
/// sin(θ/2) below [`LOG_SPLIT`] on a log scale (32 buckets per octave over 16 octaves, read off the
/// bits of an f32: no logarithm), sin(θ/2) linearly up to θ = π/2, then cos(θ/2) linearly down to
/// θ = π. Each bucket then spans about one node of the graded grid ([`crate::ensemble::graded_angles`]:
/// 2.3 % apart below 0.1 rad, 0.0022 rad above): 128 buckets linear in sin(θ/2) held 300 nodes in the
/// first (the diffraction lobe's) and 115 in the last, and their searches were 3 % of a dense Cornell
/// box's render (4 % faster with 1024 such buckets).
const ANGLE_RUN: usize = 512;
const ANGLE_BUCKETS: usize = 3 * ANGLE_RUN;
/// sin(θ/2) where the evaluation directory turns from log to linear (θ ≈ 0.125 rad).
const LOG_SPLIT: f64 = 1.0 / 16.0;

/// For each bucket of a key that never increases along the nodes' order of increasing μ … or never
/// decreases (`bucket` maps a value to its bucket, monotone either way), the first and last segment
/// any value of that bucket can lie in. Exact: a lookup finds the same segment as a search of the
/// whole table, because a monotone key puts every value of a segment in the buckets between those of
/// the segment's two ends.
#[derive(Clone, Debug)]
struct Directory {
    /// Per bucket its first and last segment, side by side (one cache line per lookup).
    range: Vec<[u32; 2]>,
}

impl Directory {
    /// The directory of the segments between consecutive `nodes` under `bucket`.
    fn new(nodes: &[f64], buckets: usize, bucket: impl Fn(f64) -> usize) -> Self {
        let mut range = vec![[u32::MAX, 0u32]; buckets];
        for i in 0..nodes.len() - 1 {
            let (a, b) = (bucket(nodes[i]), bucket(nodes[i + 1]));
            for r in &mut range[a.min(b)..=a.max(b)] {
                *r = [r[0].min(i as u32), r[1].max(i as u32)];
            }
        }
        Directory { range }
    }

    /// The segment i with nodes[i] ≤ x < nodes[i + 1] (clamped to the table), x in bucket `k`.
    #[inline]
    fn segment(&self, nodes: &[f64], k: usize, x: f64) -> usize {
        self.segment_by(nodes, |m| *m, k, x)
    }

    /// [`Self::segment`] over nodes whose key `key` reads (a column of interleaved records).
    #[inline(always)]
    fn segment_by<T>(&self, nodes: &[T], key: impl Fn(&T) -> f64, k: usize, x: f64) -> usize {
        let [a, b] = self.range[k].map(|v| v as usize);
        let within = &nodes[a + 1..=b];
        // Most buckets hold a segment or three: counting the nodes at or below x has no branch to
        // mispredict, where a binary search has one per halving.
        let i = if within.len() <= 8 {
            within.iter().map(|m| (key(m) <= x) as usize).sum::<usize>()
        } else {
            within.partition_point(|m| key(m) <= x)
        };
        (a + i).min(nodes.len() - 2)
    }
}

/// Bucket of μ in the evaluation directory (see [`ANGLE_BUCKETS`]): non-decreasing in θ, so
/// non-increasing in μ.
#[inline]
fn angle_bucket(mu: f64) -> usize {
    let run = ANGLE_RUN as f64;
    if mu >= 0.0 {
        let s = ((1.0 - mu) * 0.5).max(0.0).sqrt();
        if s < LOG_SPLIT {
            // x in [0, 1): its f32 exponent and top five mantissa bits, from 2^-16 up (below: 0).
            let bits = ((s / LOG_SPLIT) as f32).to_bits() >> 18;
            (bits.saturating_sub((127 - 16) << 5) as usize).min(ANGLE_RUN - 1)
        } else {
            let x = (s - LOG_SPLIT) / (FRAC_1_SQRT_2 - LOG_SPLIT);
            ANGLE_RUN + ((x * run) as usize).min(ANGLE_RUN - 1)
        }
    } else {
        let c = ((1.0 + mu) * 0.5).max(0.0).sqrt();
        let x = ((FRAC_1_SQRT_2 - c) / FRAC_1_SQRT_2).max(0.0);
        2 * ANGLE_RUN + ((x * run) as usize).min(ANGLE_RUN - 1)
    }
}

/// x / width along a segment; 0 on a segment of no width (θ nodes below ~1.5e-8 rad round to μ = 1
/// together: 0 / 0 gave f(1) = NaN).
#[inline]
fn fraction(x: f64, width: f64) -> f64 {
    if width > 0.0 {
        x / width
    } else {
        0.0
    }
}

/// Bucket of a CDF value in the sampling directory.
#[inline]
fn cdf_bucket(u: f64) -> usize {
    ((u.max(0.0) * CDF_BUCKETS as f64) as usize).min(CDF_BUCKETS - 1)
}

impl PhaseTable {
    /// Heap bytes of the table (allocated: capacities).
    pub fn bytes(&self) -> usize {
        (self.mu.capacity() + self.f.capacity() + self.cdf.capacity()) * 8
            + self.nodes.capacity() * 24
            + (self.by_angle.range.capacity() + self.by_cdf.range.capacity()) * 8
    }

    /// Build from angles θ (strictly increasing, spanning [0, π]) and values f(θ) ≥ 0.
    pub fn new(theta: &[f64], f: &[f64]) -> Result<Self, OpticsError> {
        require(
            "theta (length)",
            theta.len() as f64,
            theta.len() >= 2 && theta.len() == f.len(),
            ">= 2 and equal to len(f)",
        )?;
        require("theta[0]", theta[0], theta[0] == 0.0, "0")?;
        require(
            "theta[-1]",
            theta[theta.len() - 1],
            (theta[theta.len() - 1] - PI).abs() < 1e-12,
            "π",
        )?;
        for w in theta.windows(2) {
            require("theta", w[1], w[1] > w[0], "strictly increasing")?;
        }
        for &v in f {
            require("f", v, v.is_finite() && v >= 0.0, "finite and >= 0")?;
        }
        let mut mu: Vec<f64> = theta.iter().rev().map(|t| t.cos()).collect();
        mu[0] = -1.0;
        *mu.last_mut().unwrap() = 1.0;
        let mut fv: Vec<f64> = f.iter().rev().copied().collect();
        let mut cdf = vec![0.0; mu.len()];
        for i in 0..mu.len() - 1 {
            cdf[i + 1] = cdf[i] + 2.0 * PI * 0.5 * (fv[i] + fv[i + 1]) * (mu[i + 1] - mu[i]);
        }
        let total = *cdf.last().unwrap();
        require("f (integral)", total, total > 0.0, "> 0")?;
        for v in fv.iter_mut() {
            *v /= total;
        }
        for v in cdf.iter_mut() {
            *v /= total;
        }
        let by_angle = Directory::new(&mu, ANGLE_BUCKETS, angle_bucket);
        let by_cdf = Directory::new(&cdf, CDF_BUCKETS, cdf_bucket);
        let nodes = (0..mu.len()).map(|i| [cdf[i], mu[i], fv[i]]).collect();
        Ok(PhaseTable {
            mu,
            f: fv,
            cdf,
            by_angle,
            by_cdf,
            nodes,
        })
    }

    /// The segment of μ ∈ [−1, 1]: mu[i] ≤ μ < mu[i + 1] (the last one for μ = 1).
    fn segment(&self, mu: f64) -> usize {
        self.by_angle.segment(&self.mu, angle_bucket(mu), mu)
    }

    /// f(μ) in sr⁻¹ (also the pdf of sampled directions per unit solid angle).
    pub fn eval(&self, mu: f64) -> f64 {
        self.eval_at(self.locate(mu))
    }

    /// Where μ lies among the nodes: its segment and the fraction along it. Tables on the same nodes
    /// ([`Self::same_nodes`]: a bin's tables at each wavelength) share it, so that a renderer evaluating
    /// every channel at one μ searches once.
    #[inline]
    pub fn locate(&self, mu: f64) -> (usize, f64) {
        let mu = mu.clamp(-1.0, 1.0);
        let i = self.segment(mu);
        (i, fraction(mu - self.mu[i], self.mu[i + 1] - self.mu[i]))
    }

    /// f at a location from [`Self::locate`] of this table or of one on the same nodes.
    #[inline]
    pub fn eval_at(&self, (i, t): (usize, f64)) -> f64 {
        self.f[i] + t * (self.f[i + 1] - self.f[i])
    }

    /// Whether `other` has exactly these nodes (then a [`Self::locate`] of either serves both).
    pub fn same_nodes(&self, other: &PhaseTable) -> bool {
        self.mu == other.mu
    }

    /// μ with P(μ' ≤ μ) = u: the segment by binary search on the CDF, then the quadratic CDF inverted.
    pub fn sample(&self, u: f64) -> f64 {
        self.sample_located(u).0
    }

    /// [`Self::sample`] and where the sampled μ lies among the nodes, as [`Self::locate`] gives it (the
    /// segment and the fraction along it), so that its values need no search.
    pub fn sample_located(&self, u: f64) -> (f64, (usize, f64)) {
        let u = u.clamp(0.0, 1.0);
        let i = self
            .by_cdf
            .segment_by(&self.nodes, |n| n[0], cdf_bucket(u), u);
        let ([c0, m0, f0], [_, m1, f1]) = (self.nodes[i], self.nodes[i + 1]);
        let dm = m1 - m0;
        // q (a t + b t²/2) = u − cdf[i] with q = 2π dm, scaled by q so that one division solves it.
        let q = 2.0 * PI * dm;
        let (a, b) = (q * f0, q * (f1 - f0));
        let target = u - c0;
        let t = if !(target > 0.0) {
            // At the segment's start (u on a node whose f is 0 gave 0 / 0 below).
            0.0
        } else if b.abs() < 1e-12 * a.abs().max(1e-300) {
            if a > 0.0 {
                target / a
            } else {
                0.5
            }
        } else {
            // Stable root of (b/2) t² + a t − target = 0 in [0, 1].
            let disc = (a * a + 2.0 * b * target).max(0.0);
            2.0 * target / (a + disc.sqrt())
        };
        let t = t.clamp(0.0, 1.0);
        (m0 + t * dm, (i, t))
    }

    /// The table as [`Self::sample_located`] reads it, for samplers that read many tables side by side
    /// through their addresses (`crate::render::phase_lanes`). Valid while the table lives.
    pub(crate) fn sampling_view(&self) -> SamplingView {
        SamplingView {
            nodes: self.nodes.as_ptr(),
            ranges: self.by_cdf.range.as_ptr(),
            n_nodes: self.nodes.len(),
        }
    }

    /// The nodes as evaluation and sampling use them: increasing μ from −1 to 1, f normalised (sr⁻¹)
    /// and P(μ' ≤ μ_i), for a walk written outside the core (`DiscreteMedium::flat_tables`).
    pub fn nodes(&self) -> (&[f64], &[f64], &[f64]) {
        (&self.mu, &self.f, &self.cdf)
    }

    /// P(μ' ≤ μ) of the piecewise-linear table (exact, closed form).
    pub fn cdf_at(&self, mu: f64) -> f64 {
        let mu = mu.clamp(-1.0, 1.0);
        let i = self.segment(mu);
        let dm = self.mu[i + 1] - self.mu[i];
        let t = fraction(mu - self.mu[i], dm);
        let (a, b) = (self.f[i], self.f[i + 1] - self.f[i]);
        (self.cdf[i] + 2.0 * PI * dm * (a * t + 0.5 * b * t * t)).clamp(0.0, 1.0)
    }

    /// Average of f over μ ∈ [lo, hi] (exact integral of the interpolant), for resampling onto other
    /// grids (e.g. Mitsuba's `tabphase`, regular in μ) without losing or gaining energy.
    pub fn average(&self, lo: f64, hi: f64) -> f64 {
        let (lo, hi) = (lo.clamp(-1.0, 1.0), hi.clamp(-1.0, 1.0));
        if hi <= lo {
            return self.eval(lo);
        }
        (self.cdf_at(hi) - self.cdf_at(lo)) / (2.0 * PI * (hi - lo))
    }

    /// Asymmetry parameter g = ∫ f μ dΩ of the interpolant (exact: f is linear in μ on each segment).
    pub fn mean_cosine(&self) -> f64 {
        let mut g = 0.0;
        for i in 0..self.mu.len() - 1 {
            let (m0, m1, f0, f1) = (self.mu[i], self.mu[i + 1], self.f[i], self.f[i + 1]);
            // ∫ (f0 + (f1 - f0) t) μ dμ over the segment, μ = m0 + t (m1 - m0).
            let dm = m1 - m0;
            g += dm * (f0 * (m0 / 3.0 + m1 / 6.0) + f1 * (m0 / 6.0 + m1 / 3.0));
        }
        (2.0 * PI * g).clamp(-1.0, 1.0)
    }

    pub fn len(&self) -> usize {
        self.mu.len()
    }
    pub fn is_empty(&self) -> bool {
        self.mu.is_empty()
    }
}

/// Henyey–Greenstein phase function with asymmetry `g` at μ = cos θ, sr⁻¹: the one-parameter model
/// graphics uses in place of a tabulated phase function (the paper's Fig. 13 compares the two at equal g).
pub fn henyey_greenstein(g: f64, mu: f64) -> f64 {
    let g = g.clamp(-0.999_999, 0.999_999);
    let denom = 1.0 + g * g - 2.0 * g * mu.clamp(-1.0, 1.0);
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_cosine_of_tabulated_henyey_greenstein() {
        // A fine table of HG(g) has mean cosine g; isotropic has 0.
        for &g in &[-0.5, 0.0, 0.3, 0.85] {
            let theta: Vec<f64> = (0..=4000).map(|i| PI * i as f64 / 4000.0).collect();
            let f: Vec<f64> = theta
                .iter()
                .map(|t| henyey_greenstein(g, t.cos()))
                .collect();
            let t = PhaseTable::new(&theta, &f).unwrap();
            assert!(
                (t.mean_cosine() - g).abs() < 2e-4,
                "g = {g}: {}",
                t.mean_cosine()
            );
        }
    }

    /// Bin averages on a regular μ grid conserve the integral exactly.
    #[test]
    fn averages_conserve_energy() {
        let theta: Vec<f64> = (0..=400).map(|i| PI * (i as f64 / 400.0).powi(3)).collect();
        let f: Vec<f64> = theta
            .iter()
            .map(|th| (-50.0 * th).exp() * 1e3 + 0.05)
            .collect();
        let t = PhaseTable::new(&theta, &f).unwrap();
        let n = 37;
        let total: f64 = (0..n)
            .map(|i| {
                let (lo, hi) = (
                    -1.0 + 2.0 * i as f64 / n as f64,
                    -1.0 + 2.0 * (i + 1) as f64 / n as f64,
                );
                2.0 * PI * t.average(lo, hi) * (hi - lo)
            })
            .sum();
        assert!((total - 1.0).abs() < 1e-12, "{total}");
        assert!((t.cdf_at(1.0) - 1.0).abs() < 1e-12 && t.cdf_at(-1.0) == 0.0);
    }

    /// An isotropic table samples μ uniformly and evaluates 1/4π; sample inverts the CDF for a peaked one.
    #[test]
    fn isotropic_and_inverse() {
        let theta: Vec<f64> = (0..=100).map(|i| PI * i as f64 / 100.0).collect();
        let t = PhaseTable::new(&theta, &vec![1.0; 101]).unwrap();
        assert!((t.eval(0.3) - 1.0 / (4.0 * PI)).abs() < 1e-12);
        assert!((t.sample(0.25) + 0.5).abs() < 1e-12);
        let f: Vec<f64> = theta.iter().map(|th| (-20.0 * th).exp() + 0.01).collect();
        let t = PhaseTable::new(&theta, &f).unwrap();
        for k in 1..50 {
            let u = k as f64 / 50.0;
            let mu = t.sample(u);
            // CDF at mu by integrating the interpolant numerically.
            let n = 200_000;
            let cdf: f64 = (0..n)
                .map(|j| {
                    let m = -1.0 + (mu + 1.0) * (j as f64 + 0.5) / n as f64;
                    2.0 * PI * t.eval(m) * (mu + 1.0) / n as f64
                })
                .sum();
            assert!((cdf - u).abs() < 1e-6, "u={u}: {cdf}");
        }
    }

    /// The evaluation directory's bucket never increases with μ (the directory is exact only then):
    /// a sweep of μ and the adjacent floats around the runs' joints (μ = ±0, sin(θ/2) = 1/16), the
    /// log run's bottom and μ → 1.
    #[test]
    fn angle_buckets_never_increase_with_mu() {
        let mut probes: Vec<f64> = (0..=200_000)
            .map(|i| 1.0 - 2.0 * i as f64 / 200_000.0)
            .collect();
        let split = 1.0 - 2.0 * LOG_SPLIT * LOG_SPLIT; // sin(θ/2) = 1/16
        for centre in [
            0.0f64,
            split,
            1.0 - 2.0 * (LOG_SPLIT * 2f64.powi(-16)).powi(2),
            1.0,
        ] {
            let mut x = centre;
            for _ in 0..2000 {
                probes.push(x);
                x = x.next_down();
            }
            let mut x = centre;
            for _ in 0..2000 {
                probes.push(x);
                x = x.next_up();
            }
        }
        probes.extend([-0.0, 1e-300, -1e-300, f64::MIN_POSITIVE, 1.0 - f64::EPSILON]);
        probes.retain(|m| (-1.0..=1.0).contains(m));
        probes.sort_by(f64::total_cmp);
        for w in probes.windows(2) {
            assert!(
                angle_bucket(w[0]) >= angle_bucket(w[1]),
                "{} {}",
                w[0],
                w[1]
            );
        }
        assert_eq!(angle_bucket(1.0), 0);
        assert_eq!(angle_bucket(-1.0), ANGLE_BUCKETS - 1);
    }

    /// Tables on the same nodes share a location: `eval_at` of one `locate` equals each table's own
    /// `eval`, bit for bit; other nodes are told apart.
    #[test]
    fn tables_on_the_same_nodes_share_a_location() {
        let theta: Vec<f64> = (0..=300).map(|i| PI * (i as f64 / 300.0).powi(3)).collect();
        let a = PhaseTable::new(
            &theta,
            &theta.iter().map(|t| (-4.0 * t).exp()).collect::<Vec<_>>(),
        )
        .unwrap();
        let b = PhaseTable::new(
            &theta,
            &theta.iter().map(|t| 1.0 + t.cos()).collect::<Vec<_>>(),
        )
        .unwrap();
        let other: Vec<f64> = (0..=300).map(|i| PI * (i as f64 / 300.0).powi(2)).collect();
        let c = PhaseTable::new(&other, &vec![1.0; other.len()]).unwrap();
        assert!(a.same_nodes(&b) && !a.same_nodes(&c));
        for k in 0..=10_000 {
            let mu = -1.0 + 2.0 * k as f64 / 10_000.0;
            let at = a.locate(mu);
            assert_eq!(a.eval_at(at).to_bits(), a.eval(mu).to_bits());
            assert_eq!(b.eval_at(at).to_bits(), b.eval(mu).to_bits());
        }
    }

    /// Nodes whose μ round together (θ below ~1.5e-8 rad: a graded grid at α above ~7e5, or a caller's
    /// table) evaluate, integrate and sample to finite values.
    #[test]
    fn nodes_that_round_together_give_finite_values() {
        // 1e-9 rad: cos rounds to 1, the first two μ nodes coincide.
        let t = PhaseTable::new(&[0.0, 1e-9, 0.5, PI], &[10.0, 9.0, 1.0, 0.5]).unwrap();
        for mu in [1.0, 1.0 - 1e-17, 0.99, 0.0, -1.0] {
            assert!(t.eval(mu).is_finite() && t.eval(mu) >= 0.0, "{mu}");
            assert!(t.cdf_at(mu).is_finite(), "{mu}");
        }
        for u in [0.0, 0.5, 1.0 - 1e-16, 1.0] {
            let (mu, (_, f)) = t.sample_located(u);
            assert!(mu.is_finite() && f.is_finite(), "{u}");
        }
    }

    /// The directories find the segment a search of the whole table finds, for every μ and u: on
    /// graded grids crowded at the forward peak, with zero runs (flat CDF), at nodes and at the ends.
    #[test]
    fn directory_lookups_equal_full_search() {
        let full = |nodes: &[f64], x: f64| {
            nodes.partition_point(|&m| m <= x).clamp(1, nodes.len() - 1) - 1
        };
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in [2usize, 3, 17, 400, 5000] {
            // Log-spaced from 1e-7 rad (then π), with a band of zeros in the middle.
            let mut theta: Vec<f64> = (0..n - 1)
                .map(|i| 1e-7 * (PI / 1e-7).powf(i as f64 / (n - 1) as f64))
                .collect();
            theta.insert(0, 0.0);
            *theta.last_mut().unwrap() = PI;
            let f: Vec<f64> = theta
                .iter()
                .map(|&t| {
                    if (1.0..2.0).contains(&t) {
                        0.0
                    } else {
                        (-3.0 * t).exp() * 1e4 + 0.1
                    }
                })
                .collect();
            let t = PhaseTable::new(&theta, &f).unwrap();
            let mut probes: Vec<f64> = (0..20_000).map(|_| 2.0 * next() - 1.0).collect();
            probes.extend(t.mu.iter().copied());
            probes.extend([
                -1.0,
                1.0,
                1.0 - 1e-15,
                1.0 - 1e-12,
                -1.0 + 1e-15,
                0.0,
                -0.0,
                1e-17,
                -1e-17,
            ]);
            // Angles on a log scale from 1e-9 rad (the log run of the directory and below it), and
            // near the runs' joints: θ = 2 asin(1/16) and π/2.
            probes.extend((0..20_000).map(|_| (1e-9 * (PI / 1e-9).powf(next())).cos()));
            for joint in [2.0 * (1.0f64 / 16.0).asin(), PI / 2.0] {
                probes.extend((0..2000).map(|_| (joint + 1e-6 * (2.0 * next() - 1.0)).cos()));
            }
            for &mu in &probes {
                assert_eq!(t.segment(mu), full(&t.mu, mu), "n = {n}, mu = {mu}");
            }
            let mut us: Vec<f64> = (0..20_000).map(|_| next()).collect();
            us.extend(t.cdf.iter().copied());
            us.extend([0.0, 1.0]);
            for &u in &us {
                let i = t.by_cdf.segment(&t.cdf, cdf_bucket(u), u);
                assert_eq!(i, full(&t.cdf, u), "n = {n}, u = {u}");
                // The interleaved records a sample reads: the same segment and the same μ.
                let j = t.by_cdf.segment_by(&t.nodes, |x| x[0], cdf_bucket(u), u);
                assert_eq!(j, i, "n = {n}, u = {u}");
                let (mu, (k, _)) = t.sample_located(u);
                assert_eq!(k, i);
                assert!(mu >= t.mu[i] && mu <= t.mu[i + 1], "n = {n}, u = {u}: {mu}");
            }
        }
    }
}
