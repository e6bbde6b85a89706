//! Free flights through the field one ray at a time: exact (one exponential per cell crossed) or by
//! delta tracking against the majorants.

use super::{ContinuousField, FieldHit};
use crate::space::dda::Dda;
use crate::space::ray::RaySegment;

/// What a tentative collision of delta tracking turns out to be.
pub(super) enum Tentative {
    Real(FieldHit),
    Null,
    /// Outside the field's box (σ_t = 0 there: a null collision).
    Outside,
}

/// A unit exponential from the upper 32 of `bits`: −ln((k + 1/2) / 2^32) (cut off at 22.9 mean free
/// paths, probability 1.2e-10). One ray at a time (`WIDE` false) by libm's single-precision logarithm
/// (a distance 6e-8 off relatively, and cheaper than f64's); a packet's rays in lockstep (`WIDE`) by
/// [`ln_unit`], which vectorises, and so do their flights' continuations one by one (the same hits
/// either way, for a test to compare).
#[inline(always)]
pub(super) fn exponential<const WIDE: bool>(bits: u64) -> f64 {
    let u = ((bits >> 32) as f64 + 0.5) * (1.0 / 4294967296.0);
    if WIDE {
        -ln_unit(u)
    } else {
        -(u as f32).ln() as f64
    }
}

/// ln x for a normal x in (0, 1], to about 1e-13 relative, without a call (libm's is not inlined, so it
/// keeps a loop from vectorising): x = 2^e m with m in [√½, √2), ln m = 2 atanh(s), s = (m − 1) / (m + 1),
/// |s| ≤ 0.172, by its series to s^15 (the next term is below 4e-14 of the sum).
#[inline(always)]
pub(super) fn ln_unit(x: f64) -> f64 {
    let bits = x.to_bits();
    let m = f64::from_bits(bits & 0x000F_FFFF_FFFF_FFFF | 0x3FF0_0000_0000_0000);
    let e = ((bits >> 52) & 0x7FF) as i64 - 1023;
    let high = m > std::f64::consts::SQRT_2;
    let (m, e) = (if high { 0.5 * m } else { m }, if high { e + 1 } else { e });
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let (z, c) = (s * s, |k: f64| 1.0 / k);
    // Estrin's scheme: the terms in pairs (a shorter chain of dependent products than Horner's).
    let (z2, z4) = (z * z, z * z * (z * z));
    let series = (1.0 + z * c(3.0))
        + z2 * (c(5.0) + z * c(7.0))
        + z4 * ((c(9.0) + z * c(11.0)) + z2 * (c(13.0) + z * c(15.0)));
    e as f64 * std::f64::consts::LN_2 + 2.0 * s * series
}

impl ContinuousField {
    /// The same free flight as [`Self::free_flight`] in distribution, by delta tracking (Woodcock
    /// tracking; pbrt-v4's majorant grid): tentative collisions at the rate of each block's majorant
    /// (or of the whole field's, [`UNIFORM_MAJORANT_RATIO`](super::build::UNIFORM_MAJORANT_RATIO)), accepted with probability σ_t / majorant.
    /// Costs one σ_t lookup per tentative collision instead of one exponential per cell crossed, but
    /// gives no optical depth. `next_bits` supplies 64 random bits per tentative collision: the upper 32
    /// draw its distance, the lower 32 its acceptance (one hash instead of two uniforms; the distance's
    /// exponential is then cut off at 22.9 mean free paths, probability 1.2e-10).
    pub fn sample_free_flight(
        &self,
        ray: &RaySegment,
        next_bits: impl FnMut() -> u64,
    ) -> Option<FieldHit> {
        self.free_flight_by::<false>(ray, next_bits)
    }

    /// [`Self::sample_free_flight`] with the exponentials of [`exponential`]`::<WIDE>`.
    pub(super) fn free_flight_by<const WIDE: bool>(
        &self,
        ray: &RaySegment,
        mut next_bits: impl FnMut() -> u64,
    ) -> Option<FieldHit> {
        if let Some(m) = self.uniform_majorant {
            // One majorant for the whole field: no block walk at all.
            let (t, t1, exit_known) = self.uniform_span(ray)?;
            return self.uniform_flight_from::<WIDE>(ray, m, t, t1, exit_known, next_bits);
        }
        for b in Dda::new(&self.block_frame, ray) {
            let m = self.majorant[b.index] as f64;
            if m <= 0.0 {
                continue;
            }
            let mut t = b.t_enter;
            loop {
                let bits = next_bits();
                t += exponential::<WIDE>(bits) / m;
                if t >= b.t_exit {
                    break;
                }
                if let Some(hit) = self.tentative(ray, t, m, bits) {
                    return Some(hit);
                }
            }
        }
        None
    }

    /// Where delta tracking against the whole field's majorant runs along `ray`: (t, t1, whether t1 is
    /// at most the field's exit), None where the ray misses the field's box. A ray that starts inside
    /// the box needs no clip (three divisions) until a tentative collision falls outside it (past its
    /// exit, as a convex box is left once, or at a face by rounding).
    #[inline(always)]
    pub(super) fn uniform_span(&self, ray: &RaySegment) -> Option<(f64, f64, bool)> {
        let bounds = &self.frame.bounds;
        let start = [0, 1, 2].map(|a| ray.o[a] + ray.t0 * ray.d[a]);
        let inside = (0..3).all(|a| start[a] > bounds.lo[a] && start[a] < bounds.hi[a]);
        let (t, t1) = if inside {
            (ray.t0, ray.t1)
        } else {
            bounds.clip(ray)?
        };
        Some((t, t1, !inside))
    }

    /// Delta tracking against the whole field's majorant `m` from `t` (up to `t1`; `exit_known`: `t1` is
    /// at most the field's exit, else it is clipped there once a tentative collision falls outside).
    pub(super) fn uniform_flight_from<const WIDE: bool>(
        &self,
        ray: &RaySegment,
        m: f64,
        mut t: f64,
        mut t1: f64,
        mut exit_known: bool,
        mut next_bits: impl FnMut() -> u64,
    ) -> Option<FieldHit> {
        let inv_m = 1.0 / m;
        loop {
            let bits = next_bits();
            t += exponential::<WIDE>(bits) * inv_m;
            if t >= t1 {
                return None;
            }
            match self.tentative_in_box(ray, t, m, bits) {
                Tentative::Real(hit) => return Some(hit),
                // Outside the box, or at its face by rounding: now its exit is worth a clip.
                Tentative::Outside if !exit_known => {
                    exit_known = true;
                    t1 = self
                        .frame
                        .bounds
                        .clip(ray)
                        .map_or(t, |(_, exit)| exit.min(t1));
                    if t >= t1 {
                        return None;
                    }
                }
                _ => {}
            }
        }
    }

    /// [`Self::tentative`], telling a null collision inside the field's box from a point outside it.
    #[inline(always)]
    pub(super) fn tentative_in_box(
        &self,
        ray: &RaySegment,
        t: f64,
        m: f64,
        bits: u64,
    ) -> Tentative {
        let p = [0, 1, 2].map(|a| ray.o[a] + t * ray.d[a]);
        let Some(cell) = self.cell_near(p) else {
            return Tentative::Outside;
        };
        let u = (bits as u32) as f64 * (1.0 / 4294967296.0);
        if u * m < self.sigma[cell] as f64 {
            Tentative::Real(FieldHit { t, cell })
        } else {
            Tentative::Null
        }
    }

    /// A tentative collision at `t` against majorant `m`: real with probability σ_t / m (by the lower
    /// 32 of `bits`). Outside the field's box (blocks reach past it; rounding at its faces) σ_t = 0: a
    /// null collision.
    #[inline(always)]
    pub(super) fn tentative(
        &self,
        ray: &RaySegment,
        t: f64,
        m: f64,
        bits: u64,
    ) -> Option<FieldHit> {
        match self.tentative_in_box(ray, t, m, bits) {
            Tentative::Real(hit) => Some(hit),
            Tentative::Null | Tentative::Outside => None,
        }
    }

    /// Exact free flight over a ray segment (|d| = 1): the first t where the optical depth walked
    /// exceeds `target` (= −ln(1 − u)), and the optical depth walked up to it (or to t1).
    pub fn free_flight(&self, ray: &RaySegment, target: f64) -> (Option<FieldHit>, f64) {
        let mut acc = 0.0;
        for c in Dda::new(&self.frame, ray) {
            let idx = c.index;
            let s = self.sigma[idx] as f64;
            if s > 0.0 {
                let x = s * (c.t_exit - c.t_enter);
                if acc + x > target {
                    let t = (c.t_enter + (target - acc) / s).min(c.t_exit);
                    return (Some(FieldHit { t, cell: idx }), target);
                }
                acc += x;
            }
        }
        (None, acc)
    }

    /// Optical depth of a ray segment (|d| = 1).
    pub fn optical_depth(&self, ray: &RaySegment) -> f64 {
        Dda::new(&self.frame, ray)
            .map(|c| self.sigma[c.index] as f64 * (c.t_exit - c.t_enter))
            .sum()
    }
}
