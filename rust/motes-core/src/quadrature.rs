//! Gauss–Legendre nodes and weights on [-1, 1] (Newton on the Legendre recurrence; exact to
//! machine precision for the orders used here).
//!
//! Paper: the numerical integration behind Eq. 16–17 (over radius) and GOA's incidence integrals
//! (App. B); no equation of its own.

use std::sync::OnceLock;

fn compute(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 1 { z } else { p1 };
            let pn1 = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (z * pn - pn1) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-16 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

/// Cached nodes and weights of the n-point rule (n = 8, 16, 32 are cached; others computed).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    static CACHE: OnceLock<Vec<(Vec<f64>, Vec<f64>)>> = OnceLock::new();
    let cache = CACHE.get_or_init(|| [8, 16, 32].iter().map(|&k| compute(k)).collect());
    match n {
        8 => cache[0].clone(),
        16 => cache[1].clone(),
        32 => cache[2].clone(),
        _ => compute(n),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn integrates_polynomials_exactly() {
        for n in [1usize, 2, 5, 8, 16, 32] {
            let (x, w) = gauss_legendre(n);
            for deg in 0..(2 * n) {
                let exact = if deg % 2 == 1 {
                    0.0
                } else {
                    2.0 / (deg as f64 + 1.0)
                };
                let got: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(deg as i32)).sum();
                assert!((got - exact).abs() < 1e-13, "n={n} deg={deg} got={got}");
            }
        }
    }
}
