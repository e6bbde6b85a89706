//! A ray segment: the part [t0, t1) of the ray o + t d that a query walks (pbrt-v4's `Ray` with the
//! t range its integrators pass beside it). Every query along a ray takes one: the slab test and the
//! DDA ([`crate::space::dda`]), the particle grid's optical depths, walks and free flights
//! ([`crate::space::grid`]), and the continuous field's and the discrete medium's
//! ([`crate::render`]).
//!
//! Paper: the ray segments of the query cylinders (Eq. 18) and of the free flights (Sec. 5.2); no
//! equation of its own.

/// The segment [t0, t1) of the ray o + t d. The queries that measure distance along it (every one
/// but the slab test and the DDA) want |d| = 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RaySegment {
    pub o: [f64; 3],
    pub d: [f64; 3],
    pub t0: f64,
    pub t1: f64,
}

impl RaySegment {
    #[inline]
    pub fn new(o: [f64; 3], d: [f64; 3], t0: f64, t1: f64) -> Self {
        RaySegment { o, d, t0, t1 }
    }

    /// Does the segment hold no t (t1 ≤ t0, or either is NaN)?
    #[inline]
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // NaN bounds make an empty segment
    pub fn is_empty(&self) -> bool {
        !(self.t1 > self.t0)
    }

    /// Does the segment hold `t` (t0 ≤ t < t1)?
    #[inline]
    pub fn contains(&self, t: f64) -> bool {
        t >= self.t0 && t < self.t1
    }

    /// The same ray over [t0, t1).
    #[inline]
    pub fn between(&self, t0: f64, t1: f64) -> Self {
        RaySegment { t0, t1, ..*self }
    }
}
