//! A beam's rays tested against one particle side by side (issue 25).
//!
//! A beam (`ParticleGrid::sample_sites_beam`: a pixel's camera rays) finds the particles near its
//! representative ray once; each of those then meets every ray of the beam. One ray at a time that
//! meant, per block of eight particles and per ray, the ray's own single-precision pre-test and then
//! the exact double-precision test of each particle passing it (its centre decoded again for every
//! ray): 7.5 % of a dense Cornell box's render. Here the exact test of one particle runs against
//! eight rays a vector (AVX-512), the particle decoded once. The pre-test is conservative (it passes
//! every ball the exact test passes), so leaving it out changes no hit.
//!
//! Each ray computes exactly what `ball_contribution` and `RaySegment::contains` compute for it, bit
//! for bit (the same operations in the same order; no fused multiply-add): a beam still finds each
//! ray's own sites, as one ray at a time does.

use super::ray::RaySegment;

/// Rays a beam holds at most (`super::grid::BEAM_RAYS`).
pub(crate) const RAYS: usize = 16;

/// A beam's rays, one array per coordinate (a vector load per eight rays).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub(crate) struct RayLanes {
    ox: [f64; RAYS],
    oy: [f64; RAYS],
    oz: [f64; RAYS],
    dx: [f64; RAYS],
    dy: [f64; RAYS],
    dz: [f64; RAYS],
    t0: [f64; RAYS],
    t1: [f64; RAYS],
    /// Whether [`Self::contributions`] runs side by side (the CPU has AVX-512 F, as the field's
    /// lockstep: asked once per beam, not per particle). Tests clear it for the scalar reference.
    pub(crate) simd: bool,
}

impl RayLanes {
    /// The rays of `rays` (None: a ray the beam does not test; its slot gets an empty segment).
    pub(crate) fn new<'a>(rays: impl Iterator<Item = Option<&'a RaySegment>>) -> Self {
        let mut l = RayLanes {
            ox: [0.0; RAYS],
            oy: [0.0; RAYS],
            oz: [0.0; RAYS],
            dx: [0.0; RAYS],
            dy: [0.0; RAYS],
            dz: [0.0; RAYS],
            t0: [0.0; RAYS],
            t1: [0.0; RAYS],
            simd: crate::simd::lockstep_simd(),
        };
        for (i, r) in rays.take(RAYS).enumerate() {
            let Some(r) = r else { continue };
            (l.ox[i], l.oy[i], l.oz[i]) = (r.o[0], r.o[1], r.o[2]);
            (l.dx[i], l.dy[i], l.dz[i]) = (r.d[0], r.d[1], r.d[2]);
            (l.t0[i], l.t1[i]) = (r.t0, r.t1);
        }
        l
    }

    /// The rays among `alive` (bit i: ray i) that the ball (centre, radius) contributes to within
    /// their segments, as a bit mask, each such ray's t (its projection) in `t`: side by side where
    /// [`Self::simd`], else one ray at a time (the reference the tests hold the vectors to).
    #[inline(always)]
    pub(crate) fn contributions(
        &self,
        (c, r): ([f64; 3], f64),
        alive: u32,
        t: &mut [f64; RAYS],
    ) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is set only where the CPU has AVX-512 F (`lockstep_simd`).
            return unsafe { self.contributions_avx512(c, r, alive, t) };
        }
        let mut hits = 0;
        for i in (0..RAYS).filter(|&i| alive >> i & 1 != 0) {
            let v = [c[0] - self.ox[i], c[1] - self.oy[i], c[2] - self.oz[i]];
            let (d0, d1, d2) = (self.dx[i], self.dy[i], self.dz[i]);
            let ti = v[0] * d0 + v[1] * d1 + v[2] * d2;
            let q = [v[0] - ti * d0, v[1] - ti * d1, v[2] - ti * d2];
            let inside = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] < r * r;
            t[i] = ti;
            hits |= ((inside && ti >= self.t0[i] && ti < self.t1[i]) as u32) << i;
        }
        hits
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn contributions_avx512(
        &self,
        c: [f64; 3],
        r: f64,
        alive: u32,
        t: &mut [f64; RAYS],
    ) -> u32 {
        use std::arch::x86_64::*;
        let (cx, cy, cz) = (
            _mm512_set1_pd(c[0]),
            _mm512_set1_pd(c[1]),
            _mm512_set1_pd(c[2]),
        );
        let rr = _mm512_set1_pd(r * r);
        let mut hits = 0u32;
        for k in [0, 8] {
            if alive >> k & 0xff == 0 {
                continue;
            }
            let at = |a: &[f64; RAYS]| _mm512_load_pd(a.as_ptr().add(k));
            let (vx, vy, vz) = (
                _mm512_sub_pd(cx, at(&self.ox)),
                _mm512_sub_pd(cy, at(&self.oy)),
                _mm512_sub_pd(cz, at(&self.oz)),
            );
            let (dx, dy, dz) = (at(&self.dx), at(&self.dy), at(&self.dz));
            // t = v·d, left to right as the scalar sum.
            let tk = _mm512_add_pd(
                _mm512_add_pd(_mm512_mul_pd(vx, dx), _mm512_mul_pd(vy, dy)),
                _mm512_mul_pd(vz, dz),
            );
            let (qx, qy, qz) = (
                _mm512_sub_pd(vx, _mm512_mul_pd(tk, dx)),
                _mm512_sub_pd(vy, _mm512_mul_pd(tk, dy)),
                _mm512_sub_pd(vz, _mm512_mul_pd(tk, dz)),
            );
            let q2 = _mm512_add_pd(
                _mm512_add_pd(_mm512_mul_pd(qx, qx), _mm512_mul_pd(qy, qy)),
                _mm512_mul_pd(qz, qz),
            );
            let m = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(q2, rr)
                & _mm512_cmp_pd_mask::<_CMP_GE_OQ>(tk, at(&self.t0))
                & _mm512_cmp_pd_mask::<_CMP_LT_OQ>(tk, at(&self.t1));
            _mm512_storeu_pd(t.as_mut_ptr().add(k), tk);
            hits |= (m as u32) << k;
        }
        hits & alive
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::grid::ball_contribution;

    /// The vectors give every ray the same hit and the same t bits as one ray at a time and as the
    /// grid's one-ray test (`ball_contribution` within the segment), over balls near and far, rays in
    /// every direction, segment ends at the projections themselves, and rays left out of `alive`.
    #[test]
    fn side_by_side_equals_one_by_one() {
        if !crate::simd::lockstep_simd() {
            crate::simd::say_simd_half_not_run(
                "side_by_side_equals_one_by_one",
                "no AVX-512 here (CPU or MOTES_SIMD): the scalar loop was compared with itself",
            );
        }
        let mut s = 7u64;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let projection = |c: [f64; 3], ray: &RaySegment| {
            let v = [0, 1, 2].map(|k| c[k] - ray.o[k]);
            v[0] * ray.d[0] + v[1] * ray.d[1] + v[2] * ray.d[2]
        };
        for round in 0..2000 {
            let c = [0; 3].map(|_| 2.0 * next() - 1.0);
            let mut rays: Vec<RaySegment> = (0..RAYS)
                .map(|_| {
                    let d = [0; 3].map(|_| 2.0 * next() - 1.0);
                    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-9);
                    let o = [0; 3].map(|_| 3.0 * next() - 1.5);
                    RaySegment::new(o, d.map(|x| x / l), next() - 0.5, 4.0 * next())
                })
                .collect();
            // Segments that start or end exactly at the ball's projection.
            rays[0].t0 = projection(c, &rays[0]);
            rays[1].t1 = projection(c, &rays[1]);
            let lanes = RayLanes::new(rays.iter().map(Some));
            let r = if round % 7 == 0 { 0.0 } else { 1.5 * next() };
            let alive = (next() * 65536.0) as u32;
            let (mut ta, mut tb) = ([0.0; RAYS], [0.0; RAYS]);
            let a = lanes.contributions((c, r), alive, &mut ta);
            let scalar = RayLanes {
                simd: false,
                ..lanes
            };
            let b = scalar.contributions((c, r), alive, &mut tb);
            assert_eq!(a, b, "round {round}");
            assert_eq!(a & !alive, 0);
            for i in (0..RAYS).filter(|&i| alive >> i & 1 != 0) {
                // Hit or miss, as the grid's one-ray test says (on CPUs without AVX-512 the first
                // comparison is of the scalar loop with itself: this one still holds it).
                let want = ball_contribution(c, r, &rays[i]).filter(|&t| rays[i].contains(t));
                assert_eq!(a >> i & 1 != 0, want.is_some(), "round {round} ray {i}");
                if let Some(t) = want {
                    assert_eq!(ta[i].to_bits(), tb[i].to_bits(), "round {round} ray {i}");
                    assert_eq!(t.to_bits(), ta[i].to_bits());
                    assert_eq!(projection(c, &rays[i]).to_bits(), t.to_bits());
                }
            }
        }
    }
}
