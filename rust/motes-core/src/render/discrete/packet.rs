//! One packet at a time: the native render path.
//!
//! Mitsuba's symbolic LLVM kernels call native code once per SIMD packet (up to [`PACKET_LANES`]
//! lanes; scalar variants once per ray). A packet runs its paths from start to end on one thread, lane
//! i being one path throughout. So the packet interface keeps its state per thread and medium, without
//! locks (`packet_state`): each lane's site of its last free flight waits in a slot, and becomes the
//! lane's event (`DiscreteMedium::settle`) when the lane's next call starts there (the path scattered
//! at it: its shadow ray, its phase function, its next free flight); a shadow ray's site is never
//! settled, the next free flight replaces it. Each lane's last event lives beside it (`LaneEvents`: a
//! path's events are looked up by its own next rays only); those whose rays walk the grains (skipping
//! the event's particles) are also kept in a per-thread `EventMap`, the record that does not depend on
//! lanes. The renderer needs no call to place an event: every site scatters (σ_s = σ_t there) and the
//! phase function's values and weights carry the site's albedo (`scattered` in
//! `DiscreteMedium::lane_phase_sample`), which Mitsuba's volumetric integrators multiply into the path
//! exactly as they would σ_s / σ_t. This contract does not hold in Dr.Jit's evaluated mode, where a
//! wavefront's kernels may run a lane on different threads: there the batch interface
//! ([`DiscreteMedium::sample_sites`] and the rest, `batch`) is the one to use. Inactive lanes are
//! `None`. The free flight's random number is a hash of the ray and the seed: a render is a function
//! of the scene, the sampler's seed and spp, whatever the thread schedule. A packet holds one pixel's
//! samples (Mitsuba orders a wavefront's lanes pixel by pixel): its rays that start at no event walk
//! the grains as one beam where they make one (`ParticleGrid::sample_sites_beam`; the same sites as
//! one by one).

use super::channels::{copy_channels, lane_wavelengths, PacketWaves};
use super::counters::SurfaceTally;
use super::events::{key, same_key, LaneEvents};
use super::flight::{ray_bits, GrainWalk, Grains, Plan};
use super::lane::{at_site, same_direction, site_position, PendingLane};
use super::packet_state::{PacketState, SampledLane};
use super::phase::{null_sample, Sample};
use super::{
    DiscreteMedium, PacketRay, PhaseEvalLane, PhaseSampleLane, MAX_CHANNELS, PACKET_LANES,
};
use crate::render::continuous::ContinuousField;
use crate::render::phase_lanes::PhaseLanes;
use crate::rng::uniform;
use crate::space::grid::{ParticleGrid, Site};
use crate::space::ray::RaySegment;
use crate::space::vec3::{deflect, normalise};
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// The lanes of a packet's free flights after their plans ([`DiscreteMedium::plan_lanes`]).
struct PlannedLanes<'m> {
    /// Bit i: lane i walks the grains, its walk in the state's `walks[i]` (not sixteen empty walks
    /// made per call).
    walking: u32,
    /// The lanes that walk stored grains from no event (`in_beam` of them): walked together where they
    /// make a beam (`ParticleGrid::sample_sites_beam`: a pixel's camera rays, their shadow rays).
    beam: [usize; PACKET_LANES],
    in_beam: usize,
    /// The field that the lanes whose flight is through one continuous field alone fly through
    /// together after.
    field: Option<&'m ContinuousField>,
}

/// [`commit_sample`] of a sample from one lane at a time (`mixture_sample`'s, or a null one). A null
/// sample (the site scatters nothing: black grains, an albedo scaled to 0) becomes a direction with zero
/// weight and pdf 1, so that the integrator ends the path here. A pdf of 0 would leave the path on its
/// old ray, which Mitsuba has cut at this site where the medium lets it (`set_clips_rays`): it would
/// escape. Only here: in `phase_sample` (the evaluated-mode path) the albedo rides on σ_s, so such a
/// path's throughput is zero already and volpath ends it anyway.
#[inline(always)]
fn commit_lane(
    st: &mut PacketState,
    i: usize,
    lane: &PhaseSampleLane,
    lam: &[f64],
    (sample, t_out): (Sample, Option<[f32; MAX_CHANNELS]>),
    evaluated_next: bool,
    out: (&mut [f64; 3], &mut [f64], &mut f64),
) {
    if sample.2 > 0.0 {
        commit_sample(
            st,
            i,
            lane,
            lam,
            (sample.0, &sample.1, sample.2, t_out),
            evaluated_next,
            out,
        );
    } else {
        let back = normalise(lane.wi.map(|x| -(x as f64))).unwrap_or([0.0, 0.0, 1.0]);
        let zeros = [0.0; MAX_CHANNELS];
        let w: &[f64] = if lam.len() <= MAX_CHANNELS {
            &zeros[..lam.len()]
        } else {
            &vec![0.0; lam.len()]
        };
        commit_sample(st, i, lane, lam, (back, w, 1.0, t_out), evaluated_next, out);
    }
}

/// Lane `i`'s phase sample (direction, weights, pdf, the path's throughput after it) into the packet's
/// outputs and into its event (the throughput; with `evaluated_next` the values that the evaluation of
/// the same direction will ask for: [`SampledLane`]).
#[inline(always)]
fn commit_sample(
    st: &mut PacketState,
    i: usize,
    lane: &PhaseSampleLane,
    lam: &[f64],
    (dir, w, p, t_out): ([f64; 3], &[f64], f64, Option<[f32; MAX_CHANNELS]>),
    evaluated_next: bool,
    (wo, weight, pdf): (&mut [f64; 3], &mut [f64], &mut f64),
) {
    (*wo, *pdf) = (dir, p);
    copy_channels(weight, w);
    if let Some(t) = t_out {
        let k = key(lane.p);
        match &mut st.recent[i] {
            Some((at, e)) if same_key(at, &k) => e.t_out = t,
            _ => {
                if let Some(e) = st.events.get_mut(&k) {
                    e.t_out = t;
                }
            }
        }
    }
    if evaluated_next && p > 0.0 && lam.len() <= MAX_CHANNELS {
        // What the evaluation at the direction as it travels back (f32) would give.
        let mut values = [0.0; MAX_CHANNELS];
        values.iter_mut().zip(w).for_each(|(v, w)| *v = w * p);
        st.sampled[i] = Some(SampledLane {
            inputs: SampledLane::inputs(lane.p, lane.wi, dir.map(|x| x as f32)),
            lambda: SampledLane::lambda(lam),
            values,
            pdf: p,
        });
    }
}

impl DiscreteMedium {
    /// Free flights of a packet: the distance to each lane's next site (None: the ray leaves [0, t_max)).
    /// `lambda` holds the lanes' wavelengths as for [`Self::packet_phase_eval`] (a ray leaving its
    /// lane's last site settles it there).
    pub fn packet_free_flights(
        &self,
        rays: &[Option<PacketRay>],
        lambda: &[f64],
        channels: usize,
        t: &mut [Option<f64>],
    ) {
        let n_rays = rays.iter().filter(|r| r.is_some()).count() as u64;
        let mut surface = SurfaceTally::default();
        let sites = self.with_packet_state(|st| {
            let waves = PacketWaves::new(self, lambda, channels, &mut st.brackets);
            let epoch = self.view_epoch.load(Ordering::Acquire);
            if st.view_epoch != epoch {
                st.view = Arc::clone(&self.view.read().unwrap());
                st.enclosure = Arc::clone(&self.enclosure.read().unwrap());
                st.view_epoch = epoch;
            }
            let planned = self.plan_lanes(st, rays, &waves, n_rays, &mut surface, t);
            if let Some(f) = planned.field {
                st.fields.fly(f, &mut st.pending);
            }
            // (Bit i: lane i's walk is in the state's `found[i]`.)
            let mut found = 0u32;
            let (beam, in_beam) = (&planned.beam, planned.in_beam);
            if let (Some(Grains::Stored(g)), 2.., true) = (&self.grid, in_beam, self.beams) {
                found = self.beam_walks(g, &st.walks, &beam[..in_beam], &mut st.found);
            }
            let sites = self.finish_lanes(st, rays, planned.walking, found, t);
            (sites, st.count_shard)
        });
        let (sites, shard) = sites;
        self.packet_counts.add_to(shard, n_rays, sites);
        if surface.checked > 0 {
            self.surface_counts
                .add_to(shard, surface.checked, surface.saw_field);
        }
    }

    /// The first half of [`Self::packet_free_flights`]: each active lane's pending site settled where
    /// its ray starts at it, and its flight planned (`Self::lane_plan`): done (its pending site set),
    /// a walk through the grains (kept in the state), or queued in the state's field lanes.
    #[inline(always)]
    fn plan_lanes<'m>(
        &'m self,
        st: &mut PacketState,
        rays: &[Option<PacketRay>],
        waves: &PacketWaves,
        n_rays: u64,
        surface: &mut SurfaceTally,
        t: &mut [Option<f64>],
    ) -> PlannedLanes<'m> {
        let view = &*st.view;
        let mut planned = PlannedLanes {
            walking: 0,
            beam: [0usize; PACKET_LANES],
            in_beam: 0,
            field: None,
        };
        (st.fields.n, st.fields.field) = (0, 0);
        for (i, ray) in rays.iter().enumerate().take(PACKET_LANES) {
            t[i] = None;
            // A lane inactive in this call keeps its site: the lane's path has not moved on.
            let Some((o, d, t_max)) = *ray else { continue };
            let (pending, recent) = (&mut st.pending[i], &mut st.recent[i]);
            if pending.settles_at(o) {
                self.settle_in(pending, &mut st.events, recent, o, waves, i);
            }
            // (Every plan below sets the lane's pending site: deferred ones when they fly.)
            let u = uniform(self.seed ^ ray_bits(&o, &d), t_max.to_bits() as u64, 0);
            let events = LaneEvents {
                recent: &st.recent[i],
                map: &st.events,
            };
            // A packet of one ray (scalar variants) flies it here: nothing to step together.
            let defer = (n_rays > 1).then_some((&mut st.fields, i));
            match self.lane_plan(&events, view, surface, o, d, t_max as f64, u, false, defer) {
                Plan::Done(site, _, parent) => st.pending[i] = PendingLane::new(site, parent),
                Plan::Walk(w) => {
                    if w.parent.len == 0 && matches!(self.grid, Some(Grains::Stored(_))) {
                        planned.beam[planned.in_beam] = i;
                        planned.in_beam += 1;
                    }
                    st.walks[i] = Some(w);
                    planned.walking |= 1 << i;
                }
                // (A lane through another field than the packet's others' flew on its own.)
                Plan::Deferred(f) => planned.field = Some(f),
            }
        }
        planned
    }

    /// The second half of [`Self::packet_free_flights`]: the walking lanes' sites (walked as a beam:
    /// bit i of `found`, or alone), then every active lane's distance to its pending site into `t`
    /// and where its flight ended; the number of sites returned.
    #[inline(always)]
    fn finish_lanes(
        &self,
        st: &mut PacketState,
        rays: &[Option<PacketRay>],
        walking: u32,
        found: u32,
        t: &mut [Option<f64>],
    ) -> u64 {
        let mut sites = 0;
        for i in 0..rays.len().min(PACKET_LANES) {
            let Some((o, d, _)) = rays[i] else { continue };
            if let Some(w) = st.walks[i].as_ref().filter(|_| walking >> i & 1 != 0) {
                let walked = if found >> i & 1 != 0 {
                    st.found[i]
                } else {
                    self.walk_alone(w)
                };
                let (site, _, parent) = self.finish_walk(w, walked, false);
                st.pending[i] = PendingLane::new(site, parent);
            }
            let pending = &mut st.pending[i];
            // The site's distance read where it lies (not the whole site copied out for it).
            let at = pending.site.as_ref().map(|s| s.t);
            t[i] = at;
            // (The position kept in a local: read back from the lane, it stalled on its store.)
            st.blocked[i] = at.map(|t| {
                let p = site_position(o, d, t);
                pending.at = p;
                (o, d, p)
            });
            sites += at.is_some() as u64;
        }
        sites
    }

    /// The walks of a packet's `lanes` (at least two, none starting at an event) as one beam where they
    /// make one (`ParticleGrid::sample_sites_beam`): each lane's site and optical depth into `found`,
    /// the lanes found returned as bits (none where they make no beam).
    fn beam_walks(
        &self,
        g: &ParticleGrid,
        walks: &[Option<GrainWalk>],
        lanes: &[usize],
        found: &mut [(Option<Site>, f64)],
    ) -> u32 {
        let mut segs = [RaySegment::new([0.0; 3], [0.0, 0.0, 1.0], 0.0, 0.0); PACKET_LANES];
        let mut us = [0.0; PACKET_LANES];
        for (k, &i) in lanes.iter().enumerate() {
            let w = walks[i].as_ref().expect("a walking lane");
            (segs[k], us[k]) = (w.grains(), w.u);
        }
        let n = lanes.len();
        let mut out = [(None, 0.0); PACKET_LANES];
        if !g.sample_sites_beam(&segs[..n], &us[..n], self.coincide, &mut out) {
            return 0;
        }
        let mut bits = 0;
        for (k, &i) in lanes.iter().enumerate() {
            found[i] = out[k];
            bits |= 1 << i;
        }
        bits
    }

    /// Settle the sites of this thread's last packet of free flights at the positions the renderer
    /// placed them (`p`, None for lanes without an event; `lambda` as for [`Self::packet_phase_eval`]),
    /// as the lanes' next calls there do ([`Self::settle`]): for tests that look the events up from
    /// other lanes.
    #[cfg(test)]
    pub(super) fn packet_settle(&self, p: &[Option<[f32; 3]>], lambda: &[f64], channels: usize) {
        self.with_packet_state(|st| {
            let waves = PacketWaves::new(self, lambda, channels, &mut st.brackets);
            for (i, pos) in p.iter().enumerate().take(PACKET_LANES) {
                if let Some(pos) = *pos {
                    self.settle(st, i, pos, &waves);
                }
            }
        })
    }

    /// Sample the phase functions of a packet's events: lanes → `wo`, `weight` (`channels` per lane:
    /// value / pdf times the site's albedo, module docs) and `pdf` (0 where there is no event); the
    /// events' throughputs are updated as [`Self::phase_sample`] does (in the lane's own copy where
    /// the event is its last, else in the map). `evaluated_next`: the caller evaluates each sampled
    /// direction next (the C++ plugin's spectral variants, whose record has no room for four weights),
    /// which the sample's own values then answer (`SampledLane`).
    #[allow(clippy::too_many_arguments)]
    pub fn packet_phase_sample(
        &self,
        lanes: &[Option<PhaseSampleLane>],
        lambda: &[f64],
        channels: usize,
        wo: &mut [[f64; 3]],
        weight: &mut [f64],
        pdf: &mut [f64],
        evaluated_next: bool,
    ) {
        self.with_packet_state(|st| {
            let waves = PacketWaves::new(self, lambda, channels, &mut st.brackets);
            // Lanes at one-particle events with tabulated wavelengths (RGB) are sampled side by side
            // (`crate::render::phase_lanes`), the others here one by one, with the same results.
            // (Packets of one lane, the scalar variants', sample it alone: faster there.)
            let side_by_side = PhaseLanes::available()
                && lanes.iter().filter(|l| l.is_some()).count() > 1
                && channels <= MAX_CHANNELS
                && waves
                    .shared
                    .as_ref()
                    .is_some_and(|ls| ls.iter().all(|l| l.2 == 0.0));
            let (mut slot_lane, mut w_ins, mut m) =
                ([0usize; PACKET_LANES], [[0.0; 3]; PACKET_LANES], 0);
            for (i, lane) in lanes.iter().enumerate().take(PACKET_LANES) {
                (wo[i], pdf[i]) = ([0.0, 0.0, 1.0], 0.0);
                weight[i * channels..(i + 1) * channels]
                    .iter_mut()
                    .for_each(|x| *x = 0.0);
                st.sampled[i] = None;
                let Some(lane) = lane else {
                    continue;
                };
                let out = (
                    &mut wo[i],
                    &mut weight[i * channels..(i + 1) * channels],
                    &mut pdf[i],
                );
                let slot = side_by_side.then_some(m);
                if let Some(w_in) = self.sample_lane(st, i, lane, &waves, slot, evaluated_next, out)
                {
                    (slot_lane[m], w_ins[i]) = (i, w_in);
                    m += 1;
                }
            }
            if m > 0 {
                let out = (wo, weight, pdf);
                self.commit_side_by_side(
                    st,
                    lanes,
                    &waves,
                    &slot_lane[..m],
                    &w_ins,
                    out,
                    evaluated_next,
                );
            }
        })
    }

    /// Lane `i`'s phase sample in [`Self::packet_phase_sample`] (its outputs `out` zeroed by the
    /// caller): committed here, or, where `slot` is given and the lane's event is one the side-by-side
    /// sampler takes, filled into that slot of the state's [`PhaseLanes`] and the path's incident
    /// direction returned.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn sample_lane(
        &self,
        st: &mut PacketState,
        i: usize,
        lane: &PhaseSampleLane,
        waves: &PacketWaves,
        slot: Option<usize>,
        evaluated_next: bool,
        out: (&mut [f64; 3], &mut [f64], &mut f64),
    ) -> Option<[f64; 3]> {
        let lane_waves = waves.lane(i);
        let wv = lane_waves.get();
        self.settle(st, i, lane.p, waves);
        // A blocked shadow ray answers one evaluation, the light's (not a sample's: spectral
        // variants evaluate the sampled direction in a second call).
        st.blocked[i] = None;
        let events = LaneEvents {
            recent: &st.recent[i],
            map: &st.events,
        };
        let Some((w_in, e)) = self.sample_event(&events, lane) else {
            let null = (null_sample(wv.lam.len()), None);
            commit_lane(st, i, lane, wv.lam, null, evaluated_next, out);
            return None;
        };
        if let Some(m) = slot {
            let first = || {
                let view = self.bins[0].phase[wv.ls[0].0].sampling_view();
                Box::new(PhaseLanes::new(waves.channels, view))
            };
            let side = st.phase.get_or_insert_with(first);
            // (A sample whose draws are not numbers is taken here, with the event at hand.)
            if self.fill_phase_lane(&e, lane, wv.lam, wv.ls, side, m) && !side.is_alone(m) {
                return Some(w_in);
            }
        }
        let one = self.event_phase_sample(&e, w_in, lane, wv.lam, wv.ls, true);
        commit_lane(st, i, lane, wv.lam, one, evaluated_next, out);
        None
    }

    /// The lanes `slot_lane` (lane by slot) of [`Self::packet_phase_sample`] that wait in the state's
    /// [`PhaseLanes`], sampled side by side and committed (their paths' incident directions in
    /// `w_ins`, by lane).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn commit_side_by_side(
        &self,
        st: &mut PacketState,
        lanes: &[Option<PhaseSampleLane>],
        waves: &PacketWaves,
        slot_lane: &[usize],
        w_ins: &[[f64; 3]; PACKET_LANES],
        (wo, weight, pdf): (&mut [[f64; 3]], &mut [f64], &mut [f64]),
        evaluated_next: bool,
    ) {
        let (lambda, channels) = (waves.lambda, waves.channels);
        // Out of the state while its lanes are committed to it (given back below).
        let mut side = st.phase.take().expect("filled above");
        (side.n, side.channels) = (slot_lane.len(), channels);
        // SAFETY: the lanes' tables are this medium's, which live as long as it does (its
        // packet state is its own: `with_packet_state`).
        unsafe { side.sample(false) };
        for (k, &i) in slot_lane.iter().enumerate() {
            let lane = lanes[i].as_ref().expect("an active lane");
            let lam = lane_wavelengths(lambda, channels, i);
            let out = (
                &mut wo[i],
                &mut weight[i * channels..(i + 1) * channels],
                &mut pdf[i],
            );
            if side.ok[k] != 0 && side.alone[k] == 0 {
                let mut w = [0.0; MAX_CHANNELS];
                let mut t = [0.0f32; MAX_CHANNELS];
                for c in 0..MAX_CHANNELS {
                    (w[c], t[c]) = (side.weight[c][k], side.t_out[c][k] as f32);
                }
                let dir = deflect(w_ins[i], side.mu[k], lane.u2[1]);
                let sample = (dir, &w[..channels], side.pdf[k], Some(t));
                commit_sample(st, i, lane, lam, sample, evaluated_next, out);
                continue;
            }
            let one = if side.alone[k] != 0 {
                // (Not reached: `is_alone` kept such lanes back. Kept as the safe answer.)
                let wv = waves.lane(i);
                let wv = wv.get();
                let events = LaneEvents {
                    recent: &st.recent[i],
                    map: &st.events,
                };
                self.lane_phase_sample(&events, lane, wv.lam, wv.ls, true)
            } else {
                (null_sample(channels), None)
            };
            commit_lane(st, i, lane, lam, one, evaluated_next, out);
        }
        st.phase = Some(side);
    }

    /// Evaluate the phase functions of a packet's events: lanes → `values` (`channels` per lane, times
    /// the site's albedo: module docs) and `pdf`. `lambda`: `channels`
    /// wavelengths shared by all lanes, or `channels` per lane.
    pub fn packet_phase_eval(
        &self,
        lanes: &[Option<PhaseEvalLane>],
        lambda: &[f64],
        channels: usize,
        values: &mut [f64],
        pdf: &mut [f64],
    ) {
        self.with_packet_state(|st| {
            let waves = PacketWaves::new(self, lambda, channels, &mut st.brackets);
            for (i, lane) in lanes.iter().enumerate().take(PACKET_LANES) {
                let v = &mut values[i * channels..(i + 1) * channels];
                pdf[i] = 0.0;
                let Some(lane) = lane else {
                    v.iter_mut().for_each(|x| *x = 0.0);
                    continue;
                };
                let lane_waves = waves.lane(i);
                let wv = lane_waves.get();
                let lam = wv.lam;
                self.settle(st, i, lane.p, &waves);
                // The direction this lane's last sample returned, at the same event: its values.
                let same = |c: &SampledLane| {
                    c.inputs == SampledLane::inputs(lane.p, lane.wi, lane.wo)
                        && c.lambda == SampledLane::lambda(lam)
                };
                if let Some(c) = st.sampled[i].as_ref().filter(|c| same(c)) {
                    copy_channels(v, &c.values[..lam.len()]);
                    pdf[i] = c.pdf;
                    continue;
                }
                // Towards a light whose shadow ray the lane's last free flight found blocked inside
                // the medium's enclosure: the light's zero multiplies this (`Self::set_enclosure`).
                // One evaluation per blocked flight.
                let widen = |p: [f32; 3]| p.map(|x| x as f64);
                if st.blocked[i].take().is_some_and(|(o, d, at)| {
                    at_site(lane.p, o)
                        && same_direction(d, lane.wo)
                        && st.enclosure.holds_segment(widen(o), widen(at))
                }) {
                    v.iter_mut().for_each(|x| *x = 0.0);
                    continue;
                }
                pdf[i] = self.lane_phase_eval(&st.lane(i), lane, lam, wv.ls, v, true);
            }
        })
    }
}
