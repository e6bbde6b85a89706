//! The few 3-vector operations the core writes out on `[f64; 3]` (its positions and directions are plain
//! arrays throughout, as the grid, the rays and the Python boundary hold them): arithmetic, and the
//! directions a phase function's sample turns into (a frame around a direction, a deflection from it,
//! the octahedral map that sends one in two floats).
//!
//! Infrastructure: implements no equation of the paper.

use std::f64::consts::PI;

#[inline(always)]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `v` scaled to unit length, or None for a zero, infinite or NaN `v`.
#[inline]
pub fn normalise(v: [f64; 3]) -> Option<[f64; 3]> {
    let n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if (n2 - 1.0).abs() < 1e-6 {
        // A unit vector to float32 rounding (every direction Mitsuba hands over): one Newton step
        // of 1/√n² from 1 leaves |v| − 1 below 1e-12, without the square root and divisions.
        let s = 1.5 - 0.5 * n2;
        return Some(v.map(|x| x * s));
    }
    let l = n2.sqrt();
    (l.is_finite() && l > 0.0).then(|| v.map(|x| x / l))
}

/// Two unit vectors perpendicular to the unit `n` and to each other (Duff et al. 2017, branchless).
#[inline]
pub fn frame(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let sign = if n[2] >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    (
        [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]],
        [b, sign + n[1] * n[1] * a, -n[1]],
    )
}

/// The direction at cos θ = `mu` from the unit `w_in`, at azimuth 2π `u` around it.
#[inline(always)]
pub fn deflect(w_in: [f64; 3], mu: f64, u: f64) -> [f64; 3] {
    let phi = 2.0 * PI * u;
    let st = (1.0 - mu * mu).max(0.0).sqrt();
    let (e1, e2) = frame(w_in);
    // φ in single precision: the direction goes to the renderer as float32 anyway.
    let (sin_phi, cos_phi) = (phi as f32).sin_cos();
    let (sin_phi, cos_phi) = (sin_phi as f64, cos_phi as f64);
    [0, 1, 2].map(|a| mu * w_in[a] + st * (cos_phi * e1[a] + sin_phi * e2[a]))
}

/// The octahedral map of a unit vector (Cigolle et al. 2014, "A survey of efficient representations
/// for independent unit vectors"): x, y of w / |w|_1, the lower hemisphere folded over the diagonals.
/// How the native plugin's phase samples send a direction in two floats (`rust/motes-py/src/native/mod.rs`;
/// the C++ plugin unfolds it: test `octahedral_directions_survive_float32`).
pub fn octahedral(w: [f64; 3]) -> [f64; 2] {
    let n = w[0].abs() + w[1].abs() + w[2].abs();
    let (x, y) = (w[0] / n, w[1] / n);
    if w[2] >= 0.0 {
        [x, y]
    } else {
        [(1.0 - y.abs()).copysign(x), (1.0 - x.abs()).copysign(y)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Octahedral directions (how the native plugin's phase samples travel) unfolded as the C++ plugin
    /// does, in float32, come back within float32 precision: axes, signed zeros, the equator, the
    /// poles and random directions.
    #[test]
    fn octahedral_directions_survive_float32() {
        // motes_native.cpp's `octahedral`, in float32.
        let decode = |x: f32, y: f32| {
            let z = 1.0 - x.abs() - y.abs();
            let (ux, uy) = if z < 0.0 {
                ((1.0 - y.abs()).copysign(x), (1.0 - x.abs()).copysign(y))
            } else {
                (x, y)
            };
            let n = (ux * ux + uy * uy + z * z).sqrt();
            [ux / n, uy / n, z / n].map(|c| c as f64)
        };
        let mut s = 17u64;
        let mut r = || crate::test_rng::lcg(&mut s);
        let mut dirs: Vec<[f64; 3]> = vec![
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [-0.0, -0.0, -1.0],
            [0.6, -0.8, 0.0],
            [0.6, -0.8, -0.0],
            [1e-9, 0.0, -1.0],
        ];
        for _ in 0..20000 {
            let z: f64 = 2.0 * r() - 1.0;
            let phi = 2.0 * PI * r();
            let st = (1.0 - z * z).sqrt();
            dirs.push([st * phi.cos(), st * phi.sin(), z]);
        }
        for w in dirs {
            let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            let w = w.map(|c| c / l);
            let [x, y] = octahedral(w);
            let v = decode(x as f32, y as f32);
            let err =
                ((v[0] - w[0]).powi(2) + (v[1] - w[1]).powi(2) + (v[2] - w[2]).powi(2)).sqrt();
            assert!(err < 1e-6, "{w:?} -> {v:?}: {err}");
        }
    }
}
