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
/// How the native plugin's phase samples send a direction in two floats (`rust/motes-py/src/native.rs`;
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
