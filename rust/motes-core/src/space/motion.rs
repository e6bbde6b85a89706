//! Moving generated grains (issue 27): a grain's position is a deterministic function of time, so that
//! every frame of an animation, on any machine, puts the same grain (same radius, same species) where
//! the motion says.
//!
//! x(t) = x₀ + v t + A (W(x₀, t) − W(x₀, 0)),   W(x, t) = ∇_q × Ψ(q + t ω),  q = x / L.
//!
//! * x₀ is the grain's rest position (scene units, after the cloud's transform) and v a uniform
//!   velocity (scene units per second).
//! * Ψ is a vector potential of three independent seeded value-noise fields
//!   ([`crate::space::cloud::ValueNoise`], C², two octaves); W, its curl in noise coordinates, is a
//!   divergence-free field (∇·∇×Ψ = 0): the displacement field d(x₀) = A (W(x₀, t) − W(x₀, 0)) is
//!   solenoidal at every t, so the map x₀ ↦ x₀ + d preserves volume to first order in |∇d| ~ A / L
//!   (its Jacobian is 1 + O(|∇d|²)): a uniform cloud stays uniform to O((A / L)²). Keep A well below
//!   L (the drift would fold space where |∇d| > 1). The curl is taken by central differences (step
//!   [`CURL_STEP`] noise cells), whose divergence is zero to O(h²).
//! * The pattern Ψ slides through itself along ω (unit speed: [`PATTERN_SPEED`] noise cells per second),
//!   so a grain's drift decorrelates over about a second: a gust, not a fixed offset. The drift starts
//!   at zero at t = 0 and stays bounded (|W| is O(1)): grains wander around their mean path x₀ + v t,
//!   by displacements of order A = `turbulence` scene units over spatial scale L = `turbulence_scale`.
//!
//! Not the paper's (which renders still clouds); Müller et al. 2016 animate grains from simulations.
//! A smooth seeded displacement is what a renderer can afford for 10⁸ grains per frame: one curl
//! evaluation per grain and frame, no time integration.

use crate::error::{require, shown, OpticsError};
use crate::rng::splitmix64;
use crate::space::cloud::{apply, det3, invert_affine, ValueNoise};
use rayon::prelude::*;

/// Step of the central differences of the curl, in noise cells.
pub const CURL_STEP: f64 = 1e-3;
/// Speed at which the noise pattern slides through itself, noise cells per second.
pub const PATTERN_SPEED: f64 = 1.0;
/// Direction of the slide (unit vector, irrational-looking so that no lattice axis is favoured).
const PATTERN_DIR: [f64; 3] = [0.381_966, 0.618_034, 0.688_191];
/// Largest noise coordinate |q| the drift takes: the curl's step ([`CURL_STEP`]) is still ~200 ulps
/// of it (beyond, the differences round to zero and the grains stop drifting).
pub const MAX_NOISE_COORDINATE: f64 = 1e12;
/// Stream tag of the potential's seeds.
const MOTION_STREAM: u64 = 0x6D6F_7469_6F6E;

/// A uniform velocity plus a turbulent drift whose displacement field is divergence-free (module docs).
#[derive(Clone, Debug)]
pub struct Motion {
    pub velocity: [f64; 3],
    pub turbulence: f64,
    pub scale: f64,
    potential: Option<[ValueNoise; 3]>,
    /// Periodic wrap into the cloud's box: (world → local 3×4, local → world 3×4) of the box
    /// [-1, 1]³ (a grain that leaves through one face comes back through the opposite one: a
    /// snowfall that never runs out).
    wrap: Option<([[f64; 4]; 3], [[f64; 4]; 3])>,
}

impl Motion {
    /// `velocity` in scene units per second; `turbulence` (scene units, ≥ 0) the drift's amplitude;
    /// `scale` (scene units, > 0) its spatial scale; `seed` fixes the drift's pattern.
    pub fn new(
        velocity: [f64; 3],
        turbulence: f64,
        scale: f64,
        seed: u64,
    ) -> Result<Self, OpticsError> {
        for v in velocity {
            require("velocity", v, v.is_finite(), "finite")?;
        }
        require(
            "turbulence",
            turbulence,
            turbulence.is_finite() && turbulence >= 0.0,
            "finite and >= 0",
        )?;
        require(
            "turbulence",
            turbulence,
            drift_of(turbulence).is_finite(),
            "small enough that the grains' drift (up to 17.5 x turbulence) stays finite",
        )?;
        require(
            "turbulence_scale",
            scale,
            scale.is_finite() && scale > 0.0,
            "finite and > 0",
        )?;
        let potential = if turbulence > 0.0 {
            let s = |a: u64| splitmix64(seed ^ splitmix64(MOTION_STREAM ^ a));
            Some([
                ValueNoise::new(1.0, 2, s(0), 0.0)?,
                ValueNoise::new(1.0, 2, s(1), 0.0)?,
                ValueNoise::new(1.0, 2, s(2), 0.0)?,
            ])
        } else {
            None
        };
        Ok(Motion {
            velocity,
            turbulence,
            scale,
            potential,
            wrap: None,
        })
    }

    /// Grains wrap around the box [-1, 1]³ that `to_world` (3×4, invertible) maps into the scene.
    pub fn wrapped(mut self, to_world: [[f64; 4]; 3]) -> Result<Self, OpticsError> {
        let inverse = invert_affine(&to_world).ok_or(OpticsError::InvalidArgument {
            argument: "to_world",
            value: det3(&to_world),
            requirement: "invertible (a non-zero scale)",
        })?;
        self.wrap = Some((inverse, to_world));
        Ok(self)
    }

    /// The potential's three noises (None without turbulence) and whether grains wrap around a box:
    /// what a re-implementation of [`Self::position`] needs (`crate::render::procedural::export`).
    pub(crate) fn potential(&self) -> (Option<&[ValueNoise; 3]>, bool) {
        (self.potential.as_ref(), self.wrap.is_some())
    }

    /// A bound on how far the turbulent drift can move a grain from x₀ + v t (scene units): each
    /// octave o of a potential component changes by at most 15/8 · 2^o per noise cell along an axis
    /// (the quintic's steepest slope times the octave's frequency; lattice values in [0, 1]), so with
    /// the two octaves' weights |∂Ψ_i/∂q_j| ≤ 2.5, each curl component ≤ 5, |W| ≤ 5√3, and
    /// |W(t) − W(0)| ≤ 10√3; one per cent more covers the central differences.
    pub fn drift_bound(&self) -> f64 {
        if self.potential.is_some() {
            drift_of(self.turbulence)
        } else {
            0.0
        }
    }

    /// W(x, t): the curl of the potential at noise coordinates q = x / L + t ω (module docs).
    fn curl(&self, psi: &[ValueNoise; 3], x: [f64; 3], t: f64) -> [f64; 3] {
        let q = [0, 1, 2].map(|a| x[a] / self.scale + t * PATTERN_SPEED * PATTERN_DIR[a]);
        let h = CURL_STEP;
        // ∂Ψ_i/∂q_j by central differences.
        let d = |i: usize, j: usize| {
            let (mut lo, mut hi) = (q, q);
            lo[j] -= h;
            hi[j] += h;
            (psi[i].value(hi) - psi[i].value(lo)) / (2.0 * h)
        };
        [d(2, 1) - d(1, 2), d(0, 2) - d(2, 0), d(1, 0) - d(0, 1)]
    }

    /// Position at time `t` (seconds) of the grain at rest position `x0` (scene units).
    pub fn position(&self, x0: [f64; 3], t: f64) -> [f64; 3] {
        let mut x = [0, 1, 2].map(|a| x0[a] + self.velocity[a] * t);
        if let Some(psi) = &self.potential {
            if t != 0.0 {
                let (w1, w0) = (self.curl(psi, x0, t), self.curl(psi, x0, 0.0));
                for a in 0..3 {
                    x[a] += self.turbulence * (w1[a] - w0[a]);
                }
            }
        }
        if let Some((to_local, to_world)) = &self.wrap {
            let local = apply(to_local, x).map(|c| (c + 1.0).rem_euclid(2.0) - 1.0);
            x = apply(to_world, local);
        }
        x
    }

    /// Every grain of `centres` moved from its rest position to its position at time `t`, in parallel.
    /// Checked first ([`Self::check_reach`]): each term of x(t) (module docs) for the farthest grain, so
    /// that no grain ends up nowhere and the message names the input that would have sent it there.
    pub fn apply(&self, centres: &mut [[f64; 3]], t: f64) -> Result<(), OpticsError> {
        let farthest = centres
            .par_iter()
            .map(|c| c.iter().fold(0.0f64, |m, x| m.max(x.abs())))
            .reduce(|| 0.0, f64::max);
        self.check_reach(farthest, t)?;
        centres
            .par_iter_mut()
            .with_min_len(4096)
            .for_each(|c| *c = self.position(*c, t));
        Ok(())
    }

    /// The checks of [`Self::apply`] for grains whose farthest rest coordinate is `farthest` (scene
    /// units) at time `t`: |x(t)| <= |x0| + |v t| + the drift's bound stays finite (velocity x time
    /// overflows at 1e300 m/s for 1e10 s), and where there is turbulence its noise coordinates
    /// q = x / L + t w stay below [`MAX_NOISE_COORDINATE`], where the curl's central differences
    /// still resolve (beyond it the grains would silently stop drifting). Each names its input.
    pub fn check_reach(&self, farthest: f64, t: f64) -> Result<(), OpticsError> {
        require("time", t, t.is_finite(), "finite (seconds)")?;
        require(
            "positions",
            farthest,
            farthest.is_finite(),
            "finite coordinates",
        )?;
        let (v, shift) = self
            .velocity
            .iter()
            .map(|v| (*v, (v * t).abs()))
            .fold((0.0, 0.0), |a, b| if b.1 >= a.1 { b } else { a });
        let moved = farthest + shift;
        if !moved.is_finite() {
            return Err(OpticsError::OutOfRange {
                argument: "velocity",
                value: v,
                requirement: format!(
                    "small enough that the grains' positions plus velocity x time (time = {} s) \
                     stay finite",
                    shown(t)
                ),
            });
        }
        if self.potential.is_some() {
            require(
                "turbulence",
                self.turbulence,
                (moved + self.drift_bound()).is_finite(),
                "small enough that the grains' positions plus their drift (up to 17.5 x turbulence) \
                 stay finite",
            )?;
            require(
                "time",
                t,
                t.abs() * PATTERN_SPEED <= MAX_NOISE_COORDINATE,
                "at most 1e12 s where turbulence moves the grains (its pattern, sliding at one noise \
                 cell per second, is resolved to 1e-3 of a cell)",
            )?;
            let q = (moved + self.drift_bound()) / self.scale;
            require(
                "turbulence_scale",
                self.scale,
                q <= MAX_NOISE_COORDINATE,
                "at least 1e-12 of the grains' largest coordinate (the drift is resolved to 1e-3 of \
                 turbulence_scale, which a coordinate of more than 1e12 of it rounds away)",
            )?;
        }
        Ok(())
    }
}

/// The bound on the drift of a turbulence of amplitude `turbulence` ([`Motion::drift_bound`]).
fn drift_of(turbulence: f64) -> f64 {
    turbulence * 10.0 * 3f64.sqrt() * 1.01
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn velocity_moves_by_v_dt_and_time_zero_is_rest() {
        let m = Motion::new([1.0, -2.0, 0.5], 0.0, 1.0, 7).unwrap();
        assert_eq!(m.position([0.1, 0.2, 0.3], 0.0), [0.1, 0.2, 0.3]);
        let p = m.position([0.1, 0.2, 0.3], 2.0);
        for (a, e) in p.iter().zip([2.1, -3.8, 1.3]) {
            assert!((a - e).abs() < 1e-12);
        }
        let t = Motion::new([0.0; 3], 0.3, 0.5, 7).unwrap();
        assert_eq!(t.position([0.1, 0.2, 0.3], 0.0), [0.1, 0.2, 0.3]);
    }

    /// An overflow names the input that causes it (issue 44: turbulence's was blamed on velocity).
    #[test]
    fn overflows_name_their_input() {
        let arg = |r: Result<(), OpticsError>| match r.unwrap_err() {
            OpticsError::InvalidArgument { argument, .. }
            | OpticsError::OutOfRange { argument, .. } => argument,
            e => panic!("{e}"),
        };
        let e = Motion::new([0.0; 3], 1e308, 1.0, 1)
            .map(|_| ())
            .unwrap_err();
        assert!(matches!(
            e,
            OpticsError::InvalidArgument {
                argument: "turbulence",
                ..
            }
        ));
        let mut c = vec![[0.5, 0.0, 0.0]; 3];
        let v = Motion::new([1e300, 0.0, 0.0], 0.0, 1.0, 1).unwrap();
        assert_eq!(arg(v.apply(&mut c, 1e10)), "velocity");
        let s = Motion::new([0.0; 3], 1.0, 1e-300, 1).unwrap();
        assert_eq!(arg(s.apply(&mut c, 1.0)), "turbulence_scale");
        let slow = Motion::new([0.0; 3], 1.0, 1.0, 1).unwrap();
        assert_eq!(arg(slow.apply(&mut c, 1e300)), "time");
        assert_eq!(c, vec![[0.5, 0.0, 0.0]; 3]); // nothing moved
        let ok = Motion::new([1.0, 0.0, 0.0], 1e200, 1e200, 1).unwrap();
        ok.apply(&mut c, 2.0).unwrap();
        assert!(c.iter().flatten().all(|x| x.is_finite()));
    }

    /// The drift's displacement field is divergence-free (finite differences over x0), smooth in
    /// time, bounded, and reproducible from the seed.
    #[test]
    fn drift_is_solenoidal_bounded_and_seeded() {
        let (a, l) = (0.2, 0.7);
        let m = Motion::new([0.0; 3], a, l, 11).unwrap();
        let t = 1.3;
        let disp = |x: [f64; 3]| {
            let p = m.position(x, t);
            [p[0] - x[0], p[1] - x[1], p[2] - x[2]]
        };
        let h = 1e-3 * l;
        let (mut max_div, mut max_grad, mut max_disp) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..200 {
            let x = [
                0.37 * i as f64 % 3.0,
                0.73 * i as f64 % 2.0,
                0.11 * i as f64 % 5.0,
            ];
            let mut div = 0.0;
            for j in 0..3 {
                let (mut lo, mut hi) = (x, x);
                lo[j] -= h;
                hi[j] += h;
                let g = (disp(hi)[j] - disp(lo)[j]) / (2.0 * h);
                div += g;
                max_grad = max_grad.max(g.abs());
            }
            max_div = max_div.max(div.abs());
            let d = disp(x);
            max_disp = max_disp.max((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt());
        }
        assert!(max_grad > 1e-2, "a drift that moves nothing: {max_grad}");
        assert!(
            max_div < 1e-3 * max_grad,
            "divergence {max_div} against gradients {max_grad}"
        );
        assert!(
            max_disp > 0.05 * a && max_disp < 10.0 * a,
            "displacement {max_disp} for amplitude {a}"
        );
        // Continuity in time and reproducibility.
        let x = [0.3, 0.4, 0.5];
        let (p1, p2) = (m.position(x, t), m.position(x, t + 1e-4));
        assert!((0..3).all(|k| (p1[k] - p2[k]).abs() < 1e-2 * a));
        let again = Motion::new([0.0; 3], a, l, 11).unwrap();
        assert_eq!(again.position(x, t), p1);
        let other = Motion::new([0.0; 3], a, l, 12).unwrap();
        assert_ne!(other.position(x, t), p1);
    }

    #[test]
    fn wrapped_grains_stay_in_the_box() {
        let to_world = [
            [2.0, 0.5, 0.0, 1.0],
            [0.0, 1.0, 0.0, -3.0],
            [0.0, 0.3, 4.0, 0.5],
        ];
        let m = Motion::new([5.0, 0.0, 1.0], 0.0, 1.0, 0)
            .unwrap()
            .wrapped(to_world)
            .unwrap();
        let inv = invert_affine(&to_world).unwrap();
        for i in 0..50 {
            let x0 = apply(&to_world, [0.9 - 0.03 * i as f64, 0.2, -0.4]);
            let local = apply(&inv, m.position(x0, 0.37 * i as f64));
            assert!(
                local.iter().all(|c| (-1.0 - 1e-9..1.0 + 1e-9).contains(c)),
                "{local:?}"
            );
        }
        // A grain that has not left the box is where the velocity puts it.
        let x0 = apply(&to_world, [0.0, 0.0, 0.0]);
        let p = m.position(x0, 0.01);
        assert!((p[0] - x0[0] - 0.05).abs() < 1e-12 && (p[2] - x0[2] - 0.01).abs() < 1e-12);
    }

    #[test]
    fn bad_inputs_name_themselves() {
        let e = Motion::new([f64::NAN, 0.0, 0.0], 0.0, 1.0, 0).unwrap_err();
        assert!(e.to_string().contains("velocity"));
        assert!(Motion::new([0.0; 3], -1.0, 1.0, 0)
            .unwrap_err()
            .to_string()
            .contains("turbulence"));
        assert!(Motion::new([0.0; 3], 1.0, 0.0, 0)
            .unwrap_err()
            .to_string()
            .contains("turbulence_scale"));
        let m = Motion::new([0.0; 3], 0.0, 1.0, 0).unwrap();
        assert!(m
            .apply(&mut [[0.0; 3]], f64::INFINITY)
            .unwrap_err()
            .to_string()
            .contains("time"));
    }
}
