//! Free flights of rays that travel together, walked as one beam.

use super::flight::Flight;
use super::rows::{Near, Segment, ROWS_PER_STEP};
use super::settings::BOX_MARGIN;
use super::slots::{Spheres, LANES};
use super::walk::Probe;
use super::{ParticleGrid, Site, SubGrid};
use crate::simd::wide_simd;
use crate::space::dda::{Dda, GridFrame};
use crate::space::ray::RaySegment;
use crate::space::ray_lanes::RayLanes;
use crate::space::vec3::dot;

/// Rays a beam walks together at most ([`ParticleGrid::sample_sites_beam`]: a packet's lanes).
pub const BEAM_RAYS: usize = 16;

const _: () = assert!(BEAM_RAYS == crate::space::ray_lanes::RAYS);

/// Rays make a beam while they stay within this many R_max of their representative ray (δ): wider,
/// the blocks within R_max + δ of it hold few particles near any one ray, and every ray pre-tests them
/// (a tighter bound gained nothing on dense clouds).
pub(super) const BEAM_SPREAD: f64 = 2.0;

/// Halvings of its rays' segments a beam may take to keep within [`BEAM_SPREAD`] (then it covers their
/// first 1/64 in the box, and each ray walks the rest alone where it finds no site there).
pub(super) const BEAM_CUTS: i32 = 6;

thread_local! {
    /// The per-ray buffers of `ParticleGrid::sample_sites_beam`'s pending hits between beams.
    static BEAM_PENDING: std::cell::Cell<[Vec<(f64, u32)>; BEAM_RAYS]> =
        const { std::cell::Cell::new([const { Vec::new() }; BEAM_RAYS]) };
}

/// Rays walked as one beam through a class with centre cells ([`ParticleGrid::sample_sites_beam`]).
pub(super) struct Beam {
    /// The representative ray (segment [s0, s1] covering every ray's projection), its pre-test
    /// slack grown by δ: the lanes it passes are those any ray's pre-test may pass.
    pub(super) rep: Probe,
    /// The class's cells grown by one layer (a ray's point near the box's face projects on the
    /// representative ray within δ of it, possibly outside).
    pub(super) cells: GridFrame,
    /// Where the representative ray comes within R_max + δ of the cell layers.
    pub(super) near: Near,
    /// Per ray: (o − o_rep)·d_rep and d·d_rep, its points' projections on the representative ray.
    pub(super) proj: [(f64, f64); BEAM_RAYS],
    /// Per ray: where the beam's part of its segment ends (infinity: at its end), the rest to walk on
    /// its own.
    pub(super) cut: [f64; BEAM_RAYS],
    /// δ: the farthest any ray's segment in the class's box gets from the representative ray (what the
    /// walk uses of it is in `rep` and `near`; kept for tests).
    #[allow(dead_code)]
    pub(super) delta: f64,
}

impl Beam {
    /// The t on ray `i` whose point projects at `s` on the representative ray.
    fn frontier(&self, i: usize, s: f64) -> f64 {
        (s - self.proj[i].0) / self.proj[i].1
    }
}

impl SubGrid {
    /// The beam of `rays` through this class ([`ParticleGrid::sample_sites_beam`]), if they make one:
    /// directions within ~25° of their mean, and the farthest any ray's segment in the class's box
    /// gets from the representative ray (their mean direction through their mean entry point), δ,
    /// small enough that R_max + δ stays within a cell.
    /// Each ray as the tests see it goes to `probes` (None: it misses the class's box).
    pub(super) fn beam(
        &self,
        rays: &[RaySegment],
        probes: &mut [Option<Probe>; BEAM_RAYS],
    ) -> Option<Beam> {
        let (clip, sum, live) = self.beam_clips(rays)?;
        let (o, d, proj) = beam_axis(rays, &clip, sum, live)?;
        let cell = self.frame.cell;
        let reach_with = |delta: f64| self.reach_max * BOX_MARGIN.0 + BOX_MARGIN.1 + delta;
        let fits = |&(_, (delta, s0, s1)): &(i32, (f64, f64, f64))| {
            s0.is_finite()
                && s1.is_finite()
                && reach_with(delta) <= cell[0].min(cell[1]).min(cell[2])
                && delta <= BEAM_SPREAD * self.reach_max
        };
        // Rays that spread too far over the whole box (a pixel's camera rays through a deep cloud)
        // make a beam over their first part: most of them find their site there in a dense cloud,
        // the others go on one by one from where it ends (`ParticleGrid::beam_lanes`).
        let (k, (delta, s0, s1)) = (0..=BEAM_CUTS)
            .map(|k| (k, beam_spread(rays, &clip, o, d, k)))
            .find(fits)?;
        let reach = reach_with(delta);
        let rep = RaySegment::new(o, d, s0, s1);
        let mut cut = [f64::INFINITY; BEAM_RAYS];
        for (i, r) in rays.iter().enumerate() {
            let Some((t0, t1)) = clip[i] else { continue };
            if k > 0 {
                cut[i] = (t0 + (t1 - t0) * 0.5f64.powi(k)).min(r.t1);
            }
            probes[i] = Some(self.probe(&r.between(r.t0, cut[i].min(r.t1)), 0.0));
        }
        let lo = self.frame.bounds.lo;
        Some(Beam {
            cut,
            rep: self.probe(&rep, delta),
            cells: GridFrame::new(
                [0, 1, 2].map(|a| lo[a] - cell[a]),
                cell,
                self.frame.dims.map(|n| n + 2),
            ),
            near: self.near_reach(&rep, reach),
            proj,
            delta,
        })
    }

    /// Each ray's segment in the class's box (None: an empty segment, NaN ends included, or one that
    /// misses the box), the sum of those rays' directions and their count; None where a ray has a
    /// NaN or infinite origin or direction (it clips to a NaN-free range and would poison the mean).
    #[allow(clippy::type_complexity)]
    fn beam_clips(
        &self,
        rays: &[RaySegment],
    ) -> Option<([Option<(f64, f64)>; BEAM_RAYS], [f64; 3], usize)> {
        let mut clip = [None; BEAM_RAYS];
        let (mut sum, mut live) = ([0.0; 3], 0);
        for (i, r) in rays.iter().enumerate() {
            if !r.o.iter().chain(&r.d).all(|x| x.is_finite()) {
                return None;
            }
            // (The box's clip drops a NaN end: an empty segment gets no probe.)
            clip[i] = if r.is_empty() {
                None
            } else {
                self.frame.bounds.clip(r)
            };
            if clip[i].is_some() {
                (0..3).for_each(|a| sum[a] += r.d[a]);
                live += 1;
            }
        }
        Some((clip, sum, live))
    }
}

/// The point at `t` on ray `r`.
#[inline]
fn point_at(r: &RaySegment, t: f64) -> [f64; 3] {
    [0, 1, 2].map(|a| r.o[a] + t * r.d[a])
}

/// The representative ray of the `live` rays with segments `clip` in the box, whose directions sum to
/// `sum`: its origin (their mean entry point) and direction (their mean), and each ray's projections
/// on it ([`Beam::proj`]); None where the mean is no direction or a ray's is more than ~25° from it.
#[allow(clippy::type_complexity)]
fn beam_axis(
    rays: &[RaySegment],
    clip: &[Option<(f64, f64)>; BEAM_RAYS],
    sum: [f64; 3],
    live: usize,
) -> Option<([f64; 3], [f64; 3], [(f64, f64); BEAM_RAYS])> {
    let norm = dot(sum, sum).sqrt();
    let d = (live > 0 && norm > 0.0).then(|| sum.map(|x| x / norm))?;
    let mut o = [0.0; 3];
    for (r, c) in rays.iter().zip(clip) {
        if let Some((t0, _)) = c {
            let p = point_at(r, *t0);
            (0..3).for_each(|a| o[a] += p[a] / live as f64);
        }
    }
    let mut proj = [(0.0, 1.0); BEAM_RAYS];
    for (i, (r, c)) in rays.iter().zip(clip).enumerate() {
        if c.is_none() {
            continue;
        }
        let cos = dot(r.d, d);
        if cos.is_nan() || cos < 0.9 {
            return None;
        }
        let rel = [0, 1, 2].map(|a| r.o[a] - o[a]);
        proj[i] = (dot(rel, d), cos);
    }
    Some((o, d, proj))
}

/// δ and the representative ray's (origin `o`, direction `d`) range [s0, s1] over the rays' segments
/// in the box, each cut to its first 1 / 2^k (δ is largest at a segment's ends: a ray's distance
/// from another line is convex along it).
fn beam_spread(
    rays: &[RaySegment],
    clip: &[Option<(f64, f64)>; BEAM_RAYS],
    o: [f64; 3],
    d: [f64; 3],
    k: i32,
) -> (f64, f64, f64) {
    let (mut delta, mut s0, mut s1) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for (r, c) in rays.iter().zip(clip) {
        let Some((t0, t1)) = *c else { continue };
        for t in [t0, t0 + (t1 - t0) * 0.5f64.powi(k)] {
            let p = point_at(r, t);
            let v = [0, 1, 2].map(|a| p[a] - o[a]);
            let s = dot(v, d);
            let across = [0, 1, 2].map(|a| v[a] - s * d[a]);
            delta = delta.max(dot(across, across).sqrt());
            s0 = s0.min(s);
            s1 = s1.max(s);
        }
    }
    (delta, s0, s1)
}

/// A beam's walk in progress: its class, and per ray its probe, its flight (None: not flying, or
/// done) and its hits waiting for their frontier.
struct BeamWalk<'a> {
    c: &'a SubGrid,
    slots: &'a Spheres,
    n: usize,
    probes: [Option<Probe>; BEAM_RAYS],
    flights: [Option<Flight<'static>>; BEAM_RAYS],
    /// Buffers kept per thread between beams ([`BEAM_PENDING`]: a beam per packet).
    pending: [Vec<(f64, u32)>; BEAM_RAYS],
    /// Each candidate particle against every ray at once where the CPU can (`RayLanes`), else each
    /// ray's own pre-test and exact test, block by block.
    lanes_of_rays: RayLanes,
    side_by_side: bool,
    /// The rays still flying, as bits.
    alive: u32,
    ts: [f64; BEAM_RAYS],
}

impl<'a> BeamWalk<'a> {
    /// The walk of the `n` rays with `probes` through class `c` (`us` and `coincide` as
    /// [`ParticleGrid::sample_sites_beam`]'s), each ray's result in `out` cleared.
    #[inline(always)]
    fn new<const WIDE: bool>(
        c: &'a SubGrid,
        probes: [Option<Probe>; BEAM_RAYS],
        n: usize,
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> Self {
        let mut flights: [Option<Flight>; BEAM_RAYS] = [const { None }; BEAM_RAYS];
        for i in 0..n {
            out[i] = (None, 0.0);
            flights[i] = probes[i].map(|_| Flight::new(&[], us[i], coincide));
        }
        let mut pending = BEAM_PENDING.take();
        pending.iter_mut().for_each(Vec::clear);
        let lanes_of_rays = RayLanes::new(probes.iter().map(|p| p.as_ref().map(|p| &p.ray)));
        // (A ray has a flight exactly where it has a probe.)
        let alive = (0..n).fold(0u32, |m, i| m | (flights[i].is_some() as u32) << i);
        BeamWalk {
            c,
            slots: c.slots(),
            n,
            probes,
            flights,
            pending,
            side_by_side: WIDE && lanes_of_rays.simd,
            lanes_of_rays,
            alive,
            ts: [0.0; BEAM_RAYS],
        }
    }

    /// The beam's DDA steps through the cells around its representative ray, each step's rows tested
    /// and each ray's hits before the step's exit passed to its flight, until no ray flies (a ray that
    /// found its site writes it to `out`).
    // (Ray i's entries of the walk's arrays are indexed together.)
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn walk<const WIDE: bool>(&mut self, beam: &Beam, out: &mut [(Option<Site>, f64)]) {
        let mut rows = [Segment::default(); ROWS_PER_STEP];
        let mut dda = Dda::new(&beam.cells, &beam.rep.ray);
        let mut prev: Option<[i64; 3]> = None;
        let mut flying = self.flights.iter().filter(|f| f.is_some()).count();
        while flying > 0 {
            let Some(step) = dda.next() else { break };
            let last = dda.finished();
            // The grown grid's cell, in the class's cell coordinates (−1 and dims: outside).
            let cell = step.cell.map(|x| x as i64 - 1);
            let rep = &beam.rep;
            let (t0, t1) = (rep.ray.t0, rep.ray.t1);
            let m = self
                .c
                .near_rows(cell, prev.replace(cell), t0, t1, &beam.near, &mut rows);
            for sg in rows[..m].iter_mut() {
                self.test_row::<WIDE>(sg, rep);
            }
            // Each ray's contributions are known where its points project before this step's exit.
            for i in 0..self.n {
                let Some(f) = &mut self.flights[i] else {
                    continue;
                };
                let upto = if last {
                    f64::INFINITY
                } else {
                    beam.frontier(i, step.t_exit)
                };
                if !self.c.visit_before(upto, &mut self.pending[i], f) {
                    out[i] = self.flights[i].take().map_or((None, 0.0), Flight::finish);
                    self.alive &= !(1 << i);
                    flying -= 1;
                }
            }
            if last {
                break;
            }
        }
    }

    /// Test the slots of row `sg` (cells, until loaded here) against the beam's flying rays: the
    /// representative ray's pre-test for all of them, then each ray's exact test.
    // (Ray i's entries of the walk's arrays are indexed together.)
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn test_row<const WIDE: bool>(&mut self, sg: &mut Segment, rep: &Probe) {
        let c = self.c;
        c.load_slot_range(sg);
        if sg.c0 == sg.c1 {
            return;
        }
        c.locate(sg, rep);
        // Where each ray's pre-test reads the row's slots from (its lattice offsets; the rest of the
        // segment is the row's).
        let mut offs = [[0.0f32; 2]; BEAM_RAYS];
        if c.quant.is_some() && !self.side_by_side {
            for i in 0..self.n {
                if let (Some(probe), Some(_)) = (&self.probes[i], &self.flights[i]) {
                    offs[i] = probe.offsets(sg.cell);
                }
            }
        }
        for blk in sg.c0 / LANES..=(sg.c1 - 1) / LANES {
            // The lanes the representative ray's pre-test passes (within R + δ of it): one pre-test
            // for all rays, most blocks of a dense cloud none.
            let candidates = sg.block_lanes(blk) & c.pretest::<WIDE>(self.slots, blk, sg, rep);
            if candidates == 0 {
                continue;
            }
            if self.side_by_side {
                // (A row's contributions count anywhere on a ray's segment: `near_rows`.)
                debug_assert!(sg.t_enter == f64::NEG_INFINITY && sg.t_exit == f64::INFINITY);
                self.block_side_by_side(blk, candidates, sg);
                continue;
            }
            for i in 0..self.n {
                let (Some(probe), Some(_)) = (&self.probes[i], &self.flights[i]) else {
                    continue;
                };
                let own = Segment {
                    off: offs[i],
                    ..*sg
                };
                let list = &mut self.pending[i];
                c.test_block::<WIDE>(self.slots, blk, candidates, &own, probe, &mut |t, s| {
                    list.push((t, s as u32));
                    true
                });
            }
        }
    }

    /// The `candidates` of block `blk` of row `sg` against every flying ray at once (`RayLanes`).
    #[inline(always)]
    fn block_side_by_side(&mut self, blk: usize, candidates: u32, sg: &Segment) {
        let mut m = candidates;
        while m != 0 {
            let s = LANES * blk + m.trailing_zeros() as usize;
            m &= m - 1;
            let ball = self.c.slot_ball(s, sg.cell);
            let mut hit = self
                .lanes_of_rays
                .contributions(ball, self.alive, &mut self.ts);
            while hit != 0 {
                let i = hit.trailing_zeros() as usize;
                hit &= hit - 1;
                self.pending[i].push((self.ts[i], s as u32));
            }
        }
    }
}

impl SubGrid {
    /// Ray `pending`'s hits (t, slot) before `upto`, in t order, into its flight, and out of the
    /// list; false once the flight found its site.
    #[inline(always)]
    fn visit_before(&self, upto: f64, pending: &mut Vec<(f64, u32)>, flight: &mut Flight) -> bool {
        // The hits before the frontier to the front, then only those sorted: the ones held back are
        // not sorted again at every step.
        let mut k = 0;
        for j in 0..pending.len() {
            if pending[j].0 < upto {
                pending.swap(k, j);
                k += 1;
            }
        }
        pending[..k].sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
        for &(t, s) in &pending[..k] {
            if !flight.visit(t, self.hit_tau(s as usize)[0], self.hit_index(s as usize)) {
                return false;
            }
        }
        pending.drain(..k);
        true
    }
}

impl ParticleGrid {
    /// Free flights ([`Self::sample_site`], nothing excluded) of up to [`BEAM_RAYS`] rays walked as one
    /// beam: the cells around a representative ray (their mean), within R_max + δ of it, δ the
    /// farthest any ray's segment in the grid gets from it, each cell once; each ray tests those cells'
    /// particles that come within R + δ of the representative ray (one pre-test for all) with its own
    /// exact test (all rays at once where the CPU has AVX-512: `RayLanes`; else its own pre-test
    /// first), so that every ray gets exactly its own contributions, in t order (a
    /// contribution at t lies within R_max + δ of the representative ray's point nearest the ray's
    /// point at t, whose block the walk has tested once it is past that point). A pixel's camera rays
    /// (a packet of Mitsuba's symbolic kernels holds one pixel's samples) and their shadow rays towards a
    /// point light share their steps and their loads. Rays that spread too far over their whole
    /// segments make a beam over the first 1/2^k of them in the grid (k ≤ [`BEAM_CUTS`]), and a ray that
    /// finds no site there walks the rest alone, its flight going on. Writes `out` and returns true, or
    /// returns false (nothing written) where the rays are no such beam: one size class with centre
    /// cells, δ + R_max within a cell and δ within [`BEAM_SPREAD`] R_max (over the cut segments),
    /// directions within ~25° of their mean.
    pub fn sample_sites_beam(
        &self,
        rays: &[RaySegment],
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        if wide_simd() {
            // SAFETY: the CPU has AVX2 and FMA (`wide_simd`).
            return unsafe { self.beam_avx2(rays, us, coincide, out) };
        }
        self.beam_lanes::<false>(rays, us, coincide, out)
    }

    /// [`Self::sample_sites_beam`] compiled for AVX2 + FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn beam_avx2(
        &self,
        rays: &[RaySegment],
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> bool {
        self.beam_lanes::<true>(rays, us, coincide, out)
    }

    #[inline(always)]
    pub(super) fn beam_lanes<const WIDE: bool>(
        &self,
        rays: &[RaySegment],
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> bool {
        let [c] = &self.classes[..] else {
            return false;
        };
        let n = rays.len();
        if c.k != 1 || !(2..=BEAM_RAYS).contains(&n) || us.len() != n || out.len() < n {
            return false;
        }
        let mut probes = [None; BEAM_RAYS];
        let Some(beam) = c.beam(rays, &mut probes) else {
            return false;
        };
        let mut walk = BeamWalk::new::<WIDE>(c, probes, n, us, coincide, out);
        walk.walk::<WIDE>(&beam, out);
        // The rays still flying past the beam's end: their last hits, then past its cut their own
        // walks (the same flights going on).
        for i in 0..n {
            if let Some(mut f) = walk.flights[i].take() {
                let mut going = c.visit_before(f64::INFINITY, &mut walk.pending[i], &mut f);
                let r = &rays[i];
                if going && beam.cut[i] < r.t1 {
                    self.walk(&r.between(beam.cut[i], r.t1), |t, tau, j| {
                        going = f.visit(t, tau[0], j);
                        going
                    });
                }
                out[i] = f.finish();
            }
        }
        BEAM_PENDING.set(walk.pending);
        true
    }
}
