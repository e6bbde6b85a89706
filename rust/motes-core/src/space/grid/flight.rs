//! The walk over every class in t order, and free flights along it.

use super::walk::Cursor;
use super::{Hit, ParticleGrid, Site};
use crate::simd::wide_simd;
use crate::space::dda::inverse;
use crate::space::ray::RaySegment;

thread_local! {
    /// The buffer of `ParticleGrid::walk_lanes`'s pending hits between walks on this thread.
    static WALK_PENDING: std::cell::Cell<Vec<(f64, u32, u32)>> = const { std::cell::Cell::new(Vec::new()) };
}

/// A walk's pending hits, given back to [`WALK_PENDING`] when the walk ends (however it returns).
struct PendingHits(Vec<(f64, u32, u32)>);

impl Drop for PendingHits {
    fn drop(&mut self) {
        let v = std::mem::take(&mut self.0);
        // Keep a modest buffer only: a walk past huge numbers of hits should not pin its memory.
        // (A walk during the thread's teardown just drops it.)
        if v.capacity() <= 1 << 16 {
            let _ = WALK_PENDING.try_with(|b| b.set(v));
        }
    }
}

/// A free flight over its ray's contributions in t order ([`ParticleGrid::sample_site`]): contributions
/// closer than `coincide` along the ray form one site, and the flight interacts at the first site where
/// the optical depth walked passes −ln(1 − u).
pub(super) struct Flight<'a> {
    pub(super) exclude: &'a [u32],
    pub(super) coincide: f64,
    pub(super) target: f64,
    pub(super) acc: f64,
    pub(super) group: Site,
    pub(super) group_tau: f64,
    pub(super) last_t: f64,
    pub(super) found: Option<Site>,
}

impl<'a> Flight<'a> {
    pub(super) fn new(exclude: &'a [u32], u: f64, coincide: f64) -> Self {
        Flight {
            exclude,
            coincide,
            target: -(1.0 - u).ln(),
            acc: 0.0,
            group: Site::default(),
            group_tau: 0.0,
            last_t: f64::NEG_INFINITY,
            found: None,
        }
    }

    /// The next contribution (at t, optical depth `tau`, particle `i`); false once the site is found.
    #[inline(always)]
    pub(super) fn visit(&mut self, t: f64, tau: f32, i: u32) -> bool {
        if self.exclude.contains(&i) {
            return true;
        }
        if self.group.len > 0 && t > self.last_t + self.coincide {
            // The group is complete: does the path interact there?
            if self.acc + self.group_tau > self.target {
                self.found = Some(self.group);
                return false;
            }
            self.acc += self.group_tau;
            self.group = Site::default();
            self.group_tau = 0.0;
        }
        if self.group.len == 0 {
            self.group.t = t;
        }
        self.group.push(i);
        self.group_tau += tau as f64;
        self.last_t = t;
        true
    }

    /// The site (None: the ray passed every contribution) and the optical depth walked before it.
    pub(super) fn finish(mut self) -> (Option<Site>, f64) {
        if self.found.is_none() && self.group.len > 0 {
            if self.acc + self.group_tau > self.target {
                self.found = Some(self.group);
            } else {
                self.acc += self.group_tau;
            }
        }
        (self.found, self.acc)
    }
}

impl ParticleGrid {
    /// Optical depth of a ray segment, per channel (Eq. 18, normalised as in the module docs).
    pub fn optical_depth(&self, ray: &RaySegment, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        self.walk(ray, |_, tau, _| {
            out.iter_mut().zip(tau).for_each(|(v, &x)| *v += x as f64);
            true
        });
    }

    /// Visit every contributing particle with t in the segment, over all classes, in increasing t, as
    /// `visit(t, τ per channel, original index)` (a positional grid's: the position,
    /// [`Self::positional`]); `visit` returns false to stop. Each class advances
    /// its own traversal a batch at a time (the class furthest behind first); a hit is passed on once
    /// every class has reported everything before it, so a walk that stops early costs only the
    /// batches it reached, and no traversal restarts.
    pub fn walk(&self, ray: &RaySegment, visit: impl FnMut(f64, &[f32], u32) -> bool) {
        #[cfg(target_arch = "x86_64")]
        if wide_simd() {
            // SAFETY: the CPU has AVX2 and FMA (`wide_simd`).
            return unsafe { self.walk_avx2(ray, visit) };
        }
        self.walk_lanes::<false>(ray, visit)
    }

    /// [`Self::walk`] compiled for AVX2 + FMA (the whole walk, so that its pre-tests inline).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn walk_avx2(
        &self,
        ray: &RaySegment,
        visit: impl FnMut(f64, &[f32], u32) -> bool,
    ) {
        self.walk_lanes::<true>(ray, visit)
    }

    #[inline(always)]
    pub(super) fn walk_lanes<const WIDE: bool>(
        &self,
        ray: &RaySegment,
        mut visit: impl FnMut(f64, &[f32], u32) -> bool,
    ) {
        if ray.is_empty() {
            return;
        }
        let mut emit = |&(t, ci, j): &(f64, u32, u32)| {
            let c = &self.classes[ci as usize];
            let j = j as usize;
            visit(t, c.hit_tau(j), c.hit_index(j))
        };
        // Hits waiting for their batch's frontier, in a buffer kept per thread (no allocation per
        // walk); a nested walk takes a fresh one.
        let mut buffer = PendingHits(WALK_PENDING.with(|b| b.take()));
        buffer.0.clear();
        let pending = &mut buffer.0;
        if let [c] = &self.classes[..] {
            // One class: each batch is complete up to its frontier, in t order once sorted (a k = 1
            // batch may also find contributions past its frontier: they wait for the next).
            let mut cur = c.cursor(ray, inverse(ray.d));
            loop {
                let frontier = c
                    .advance::<WIDE>(&mut cur, &mut |t, j| {
                        pending.push((t, 0, j as u32));
                        true
                    })
                    .unwrap_or(f64::INFINITY);
                pending.sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
                let n = pending.partition_point(|h| h.0 < frontier);
                for h in &pending[..n] {
                    if !emit(h) {
                        return;
                    }
                }
                if frontier == f64::INFINITY {
                    return;
                }
                pending.drain(..n);
            }
        }
        let inv_d = inverse(ray.d);
        let mut cursors: Vec<(Cursor, f64)> = self
            .classes
            .iter()
            .map(|c| (c.cursor(ray, inv_d), ray.t0))
            .collect();
        // Advance the class furthest behind.
        while let Some(ci) = (0..cursors.len())
            .filter(|&i| cursors[i].1 < f64::INFINITY)
            .min_by(|&a, &b| cursors[a].1.total_cmp(&cursors[b].1))
        {
            let (cur, frontier) = &mut cursors[ci];
            *frontier = self.classes[ci]
                .advance::<WIDE>(cur, &mut |t, j| {
                    pending.push((t, ci as u32, j as u32));
                    true
                })
                .unwrap_or(f64::INFINITY);
            // Everything before the smallest frontier is final.
            let ready = cursors.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
            pending.sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
            let n = pending.partition_point(|h| h.0 < ready);
            for h in &pending[..n] {
                if !emit(h) {
                    return;
                }
            }
            pending.drain(..n);
        }
        for h in pending.iter() {
            if !emit(h) {
                return;
            }
        }
    }

    /// Exact free flight over a ray segment in `channel`: each particle interacts with probability
    /// 1 − exp(−τ_i); equivalently, particles are walked in t order and the path interacts where the accumulated optical depth first exceeds −ln(1 − u).
    /// Returns the hit (or None) and the transmittance up to it (or to t1).
    pub fn free_flight(&self, ray: &RaySegment, channel: usize, u: f64) -> (Option<Hit>, f64) {
        let target = -(1.0 - u).ln();
        let mut acc = 0.0;
        let mut found = None;
        self.walk(ray, |t, tau, i| {
            let x = tau[channel] as f64;
            if acc + x > target {
                found = Some(Hit { t, particle: i });
                return false;
            }
            acc += x;
            true
        });
        (found, (-acc).exp())
    }

    /// Exact free flight to the next *site* (channel 0), for the renderer: particles whose projections lie
    /// within `coincide` of each other along the ray form one site (their optical depths add and the site
    /// scatters as their mixture), and the particles in `exclude` (the one that scattered the path at
    /// its origin) are skipped. Returns the site and the optical depth walked before it.
    pub fn sample_site(
        &self,
        ray: &RaySegment,
        exclude: &[u32],
        u: f64,
        coincide: f64,
    ) -> (Option<Site>, f64) {
        let mut flight = Flight::new(exclude, u, coincide);
        self.walk(ray, |t, tau, i| flight.visit(t, tau[0], i));
        flight.finish()
    }

    /// First and last t in the segment where any particle contributes (for empty-space skipping), or
    /// None.
    pub fn occupied_interval(&self, ray: &RaySegment) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        self.walk(ray, |t, _, _| {
            lo = lo.min(t);
            hi = hi.max(t);
            true
        });
        (lo <= hi).then_some((lo, hi))
    }
}
