//! Free flights (module docs of `crate::render::discrete`): the grains walked one by one in t order
//! (exact, no majorant), the continuous fields of the size classes no pixel resolves, and the choice
//! of what a ray sees: the grains, or their continuous equivalent past the grain depth and where a
//! surface ray's pixel footprint holds many grains.

use super::counters::SurfaceTally;
use super::events::{key, Event, Events, Parent, NO_EVENT};
use super::lane::PendingLane;
use super::{DiscreteMedium, EVENT_FIELD_MIN_GRAINS, PACKET_LANES};
use crate::render::continuous::{ContinuousField, FieldHit};
use crate::render::footprint::View;
use crate::render::procedural::ProceduralGrains;
use crate::rng::{stream_bits, stream_key, uniform};
use crate::space::grid::{ParticleGrid, Site};
use crate::space::ray::RaySegment;
use crate::space::vec3::normalise;
use std::sync::atomic::Ordering;

/// Stream of [`uniform`] numbers, drawn from a free flight's own, that the continuous field uses (its
/// distance, then the particle picked), independent of the discrete walk's.
const FIELD_STREAM: u64 = 0xF1E1D;

/// Bits of a ray's origin and direction, mixed: the ray's share of its random numbers (the caller's
/// SplitMix64 finaliser spreads them). Three words multiplied side by side by odd constants and
/// rotated apart, not one FNV chain of six dependent multiplies (a hash per free flight).
#[inline]
pub(super) fn ray_bits(o: &[f32; 3], d: &[f32; 3]) -> u64 {
    let word = |a: f32, b: f32| a.to_bits() as u64 | (b.to_bits() as u64) << 32;
    let x = word(o[0], o[1]).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let y = word(o[2], d[0]).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    let z = word(d[1], d[2]).wrapping_mul(0x1656_67B1_9E37_79F9);
    x ^ y.rotate_left(21) ^ z.rotate_left(42)
}

/// The site of an interaction in a continuous field: one particle of the hit cell, picked ∝ its
/// extinction by the free flight's own stream.
fn field_site(f: &ContinuousField, hit: FieldHit, u: f64) -> Option<Site> {
    let mut site = None;
    field_site_into(&mut site, f, hit, u);
    site
}

/// [`field_site`] written field by field into `slot` (a packet lane's: a site built on the stack and
/// moved there was read back in wider words than it was written in).
#[inline(always)]
fn field_site_into(slot: &mut Option<Site>, f: &ContinuousField, hit: FieldHit, u: f64) {
    *slot = None;
    if let Some(j) = f.pick(hit.cell, uniform(u.to_bits(), FIELD_STREAM, 1)) {
        let s = slot.insert(Site::default());
        s.t = hit.t;
        s.push(j);
    }
}

/// A free flight through a continuous field alone: the site and the optical depth walked before it
/// (0 unless `want_tau`).
#[inline(always)] // its pair came back through memory with a store-forwarding stall
fn field_free_flight(
    f: &ContinuousField,
    ray: &RaySegment,
    u: f64,
    want_tau: bool,
) -> (Option<Site>, f64) {
    let (hit, tau) = field_hit(f, ray, u, want_tau);
    (hit.and_then(|h| field_site(f, h, u)), tau)
}

/// Where a free flight through a field interacts, and the optical depth walked before it. Without
/// `want_tau` (the native path never asks) by delta tracking against the field's majorant blocks, which
/// gives no optical depth (0) but skips the cells crossed; with it, cell by cell. The two sample the
/// same distribution from different random numbers.
fn field_hit(
    f: &ContinuousField,
    ray: &RaySegment,
    u: f64,
    want_tau: bool,
) -> (Option<FieldHit>, f64) {
    if want_tau {
        return f.free_flight(ray, -(1.0 - uniform(u.to_bits(), FIELD_STREAM, 0)).ln());
    }
    let (key, mut k) = (field_key(u), 0u64);
    let hit = f.sample_free_flight(ray, || {
        k += 1;
        stream_bits(key, 1 + k)
    });
    (hit, 0.0)
}

/// The stream of a free flight's tentative collisions in a continuous field, from the flight's `u`: its
/// k-th (k = 1, 2, ...) draws `stream_bits(key, 1 + k)` ([`ContinuousField::sample_free_flights`]).
#[inline]
fn field_key(u: f64) -> u64 {
    stream_key(u.to_bits(), FIELD_STREAM)
}

/// A ray's walk through the grains still to do (`DiscreteMedium::lane_plan`).
pub(super) struct GrainWalk {
    /// The whole ray, [0, t_max].
    pub(super) ray: RaySegment,
    /// The continuous field's interaction (the walk stops there) and the field's optical depth.
    hit: Option<FieldHit>,
    tau_field: f64,
    pub(super) u: f64,
    /// The particles of the event the ray starts at (skipped).
    pub(super) parent: Site,
    pub(super) from: Parent,
}

impl GrainWalk {
    /// The segment whose grains the walk visits: up to the field's interaction.
    pub(super) fn grains(&self) -> RaySegment {
        self.ray.between(0.0, self.hit.map_or(self.ray.t1, |h| h.t))
    }
}

/// A ray's free flight as far as `DiscreteMedium::lane_plan` takes it.
pub(super) enum Plan<'a> {
    /// Its site, the optical depth before it, what it takes from its parent event.
    Done(Option<Site>, f64, Parent),
    Walk(GrainWalk),
    /// A free flight through a continuous field alone, queued in the caller's [`FieldLanes`] (a
    /// packet's field flights are flown together, [`ContinuousField::sample_free_flights`]).
    Deferred(&'a ContinuousField),
}

/// A packet's lanes whose free flights go through one continuous field alone ([`Plan::Deferred`]), flown
/// together by [`ContinuousField::sample_free_flights`]. Kept in the thread's `PacketState`: too big
/// to be made afresh per packet.
pub(super) struct FieldLanes {
    pub(super) n: usize,
    /// The address of the field they fly through (0: none yet): a packet's lanes fly through one.
    pub(super) field: usize,
    pub(super) lane: [usize; PACKET_LANES],
    pub(super) rays: [RaySegment; PACKET_LANES],
    pub(super) keys: [u64; PACKET_LANES],
    pub(super) u: [f64; PACKET_LANES],
    pub(super) parent: [Parent; PACKET_LANES],
}

impl Default for FieldLanes {
    fn default() -> Self {
        FieldLanes {
            n: 0,
            field: 0,
            lane: [0; PACKET_LANES],
            rays: [RaySegment::new([0.0; 3], [0.0, 0.0, 1.0], 0.0, 0.0); PACKET_LANES],
            keys: [0; PACKET_LANES],
            u: [0.0; PACKET_LANES],
            parent: [Parent::default(); PACKET_LANES],
        }
    }
}

impl FieldLanes {
    /// Whether lanes through `f` can join (the packet's other field lanes fly through it too).
    fn accepts(&self, f: &ContinuousField) -> bool {
        self.field == 0 || self.field == f as *const ContinuousField as usize
    }

    /// Add lane `i`'s flight from `o` along the unit `d` up to `t_max` (the caller checks that the
    /// lanes accept its field). The ray is written field by field where it stays: built on the stack
    /// and copied here, it was read back in wider words than it had been written in (a
    /// store-forwarding stall per lane).
    #[inline(always)]
    fn push(&mut self, i: usize, o: [f32; 3], d: [f64; 3], t_max: f64, u: f64, parent: &Parent) {
        let k = self.n.min(PACKET_LANES - 1);
        let ray = &mut self.rays[k];
        for a in 0..3 {
            ray.o[a] = o[a] as f64;
            ray.d[a] = d[a];
        }
        (ray.t0, ray.t1) = (0.0, t_max);
        (self.lane[k], self.keys[k], self.u[k]) = (i, field_key(u), u);
        self.parent[k].t_out = parent.t_out;
        self.parent[k].depth = parent.depth;
        self.n = k + 1;
    }

    /// Fly them through `f`: each lane's pending site, picked as [`field_free_flight`] picks it.
    pub(super) fn fly(&self, f: &ContinuousField, pending: &mut [PendingLane]) {
        let mut hits = [None; PACKET_LANES];
        f.sample_free_flights(&self.rays[..self.n], &self.keys[..self.n], &mut hits);
        for (k, hit) in hits.iter().enumerate().take(self.n) {
            let lane = &mut pending[self.lane[k]];
            (lane.parent, lane.at, lane.site) = (self.parent[k], [0.0; 3], None);
            if let Some(h) = hit {
                field_site_into(&mut lane.site, f, *h, self.u[k]);
            }
        }
    }
}

/// The particles walked one by one: stored in a grid, or a procedural cloud's bricks generated on
/// demand (`crate::render::procedural`).
pub(super) enum Grains {
    Stored(ParticleGrid),
    Procedural(Box<ProceduralGrains>),
}

impl Grains {
    /// Exact free flight to the next site, skipping the particles of `parent` (by index for stored
    /// particles, by key for procedural ones).
    fn sample_site(
        &self,
        ray: &RaySegment,
        parent: &Site,
        u: f64,
        coincide: f64,
    ) -> (Option<Site>, f64) {
        match self {
            Grains::Stored(g) => g.sample_site(ray, parent.members(), u, coincide),
            Grains::Procedural(p) => {
                p.sample_site(ray, &parent.keys[..parent.len as usize], u, coincide)
            }
        }
    }
    /// Every contributing particle in t order as `visit(t, member, key)`.
    pub(super) fn walk(&self, ray: &RaySegment, mut visit: impl FnMut(f64, u32, u64) -> bool) {
        match self {
            Grains::Stored(g) => g.walk(ray, |t, _, i| visit(t, i, 0)),
            Grains::Procedural(p) => p.walk(ray, |t, _, m, k| visit(t, m, k)),
        }
    }
    /// The particles whose balls contain `p`.
    pub(super) fn containing(&self, p: [f64; 3]) -> Vec<u32> {
        match self {
            Grains::Stored(g) => g.containing(p),
            Grains::Procedural(g) => g.containing(p),
        }
    }
    /// The grey optical depth along `ray`.
    pub(super) fn optical_depth(&self, ray: &RaySegment) -> f64 {
        match self {
            Grains::Stored(g) => {
                let mut v = [0.0];
                g.optical_depth(ray, &mut v);
                v[0]
            }
            Grains::Procedural(p) => p.optical_depth(ray),
        }
    }
    pub(super) fn bytes(&self) -> usize {
        match self {
            Grains::Stored(g) => g.bytes(),
            Grains::Procedural(p) => p.bytes(),
        }
    }
}

impl DiscreteMedium {
    /// A ray's free flight from its plan (`Self::lane_plan`), its walk through the grains (if any)
    /// alone: its site, the optical depth walked before it and what it takes from its parent event.
    pub(super) fn fly(&self, plan: Plan, want_tau: bool) -> (Option<Site>, f64, Parent) {
        match plan {
            Plan::Done(site, tau, from) => (site, tau, from),
            Plan::Walk(w) => self.finish_walk(&w, self.walk_alone(&w), want_tau),
            Plan::Deferred(_) => unreachable!("a plan is deferred only into a caller's FieldLanes"),
        }
    }

    /// One ray's walk through the grains (skipping the particles of the event it starts at).
    pub(super) fn walk_alone(&self, w: &GrainWalk) -> (Option<Site>, f64) {
        match &self.grid {
            Some(g) => g.sample_site(&w.grains(), &w.parent, w.u, self.coincide),
            None => (None, 0.0),
        }
    }

    /// What a ray's free flight (to its next site, skipping the particles of the event it starts at;
    /// `u` uniform in [0, 1)) takes: the answer where no grain needs walking (no ray, the grains'
    /// continuous equivalent), or else the walk through the grains still to do (`discrete` docs).
    /// `defer`: a flight through the continuous equivalent alone is queued as lane `i` of the caller's
    /// field lanes where the field steps a packet's flights together ([`Plan::Deferred`]; never with
    /// `want_tau`). Queued in place: through the returned plan the ray was copied twice.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn lane_plan(
        &self,
        events: &impl Events,
        view: &View,
        surface: &mut SurfaceTally,
        o: [f32; 3],
        d: [f32; 3],
        t_max: f64,
        u: f64,
        want_tau: bool,
        defer: Option<(&mut FieldLanes, usize)>,
    ) -> Plan<'_> {
        let (Some(dir), true) = (
            normalise(d.map(|x| x as f64)),
            o.iter().all(|x| x.is_finite()),
        ) else {
            return Plan::Done(None, 0.0, Parent::default());
        };
        let may_be_event = self.events_anywhere.load(Ordering::Relaxed)
            || (0..3).all(|a| {
                (o[a] as f64) >= self.event_box.lo[a] && (o[a] as f64) <= self.event_box.hi[a]
            });
        let parent = if may_be_event {
            events.event(&key(o)).unwrap_or(&NO_EVENT)
        } else {
            &NO_EVENT
        };
        let from = Parent {
            t_out: parent.t_out,
            depth: parent.depth,
        };
        // (The segment is made only where the ray is not queued: `FieldLanes::push` writes it.)
        let o64 = o.map(|x| x as f64);
        let all = self
            .event_field(parent, o64, dir, t_max, view)
            .or_else(|| self.surface_field(parent, o64, dir, t_max, view, surface));
        if let Some(all) = all {
            if let Some((lanes, i)) =
                defer.filter(|(l, _)| all.flies_in_lockstep() && l.accepts(all))
            {
                // Delta tracking, which the caller does for its lanes together.
                lanes.field = all as *const ContinuousField as usize;
                lanes.push(i, o, dir, t_max, u, &from);
                return Plan::Deferred(all);
            }
            let ray = RaySegment::new(o64, dir, 0.0, t_max);
            let (site, tau) = field_free_flight(all, &ray, u, want_tau);
            return Plan::Done(site, tau, from);
        }
        let ray = RaySegment::new(o64, dir, 0.0, t_max);
        // The continuous field first, then the particles up to its distance: the nearer of two
        // independent processes' interactions (crate::render::continuous).
        let (hit, tau_field) = match &self.field {
            Some(f) => field_hit(f, &ray, u, want_tau),
            None => (None, 0.0),
        };
        Plan::Walk(GrainWalk {
            ray,
            hit,
            tau_field,
            u,
            parent: parent.site,
            from,
        })
    }

    /// A ray's free flight from its walk through the grains (`found`: the site and optical depth
    /// walked to it up to the continuous field's interaction).
    pub(super) fn finish_walk(
        &self,
        w: &GrainWalk,
        (site, tau): (Option<Site>, f64),
        want_tau: bool,
    ) -> (Option<Site>, f64, Parent) {
        let site = site.or_else(|| field_site(self.field.as_ref()?, w.hit?, w.u));
        // Before a discrete site nearer than the field's interaction, the field's depth counts only up to
        // the site: walked again when a caller asks for it (the packet interface does not).
        let tau_field = match (&self.field, site) {
            (Some(f), Some(s)) if want_tau && w.hit.is_none_or(|h| s.t < h.t) => {
                f.optical_depth(&w.ray.between(0.0, s.t))
            }
            _ => w.tau_field,
        };
        (site, tau + tau_field, w.from)
    }

    /// The continuous equivalent of all particles when a ray leaving `parent` is to see it rather than
    /// the grains: `parent` is the `grain_depth`-th event of its path or a later one (`discrete` docs).
    pub(super) fn grains_field_from(&self, parent: &Event) -> Option<&ContinuousField> {
        let depth = self.grain_depth.load(Ordering::Relaxed);
        if !(parent.depth > 0 && parent.depth >= depth) {
            return None;
        }
        // Every particle continuous: the field is their equivalent (an exact medium has none).
        self.grains_field.as_ref().or(if self.grid.is_none() {
            self.field.as_ref()
        } else {
            None
        })
    }

    /// The continuous equivalent of all particles when a ray leaving the event `parent` (the
    /// `grain_depth`-th of its path or a later one: [`Self::grains_field_from`]) is to see it: where no
    /// grains are walked, or where its pixel footprint holds many of them, as for a ray from a surface
    /// (`crate::render::footprint`). The field carries the grains' mean, not this cloud's arrangement of
    /// them: a sparse cloud of large grains, each of whose shadows matters, differs from its mean by
    /// several per cent (a side-lit cloud of 300 glass grains of 0.2–0.45 mm: +5.6 %, and ±2.6 % from
    /// cloud to cloud; `scripts/bench/bench_lod.py`), so there the path's later rays walk the grains too.
    /// Without cameras (the footprint unknown) they walk them. A cloud of at least
    /// [`EVENT_FIELD_MIN_GRAINS`] discrete grains sees the field from its events whatever the
    /// footprint: one arrangement of that many grains differs from their mean by ~1/√N in the image's
    /// mean (0.3 %), and walking them from every event costs ~3× (the dense Cornell box of 10⁶ grains
    /// of 2 mm at 96 px: 5.5 s against 1.7 s a render, where `bench_dense.py` measured the field's
    /// image at noise level); a sparse cloud's walk is cheap.
    fn event_field(
        &self,
        parent: &Event,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        view: &View,
    ) -> Option<&ContinuousField> {
        let all = self.grains_field_from(parent)?;
        if !self.event_rays_may_walk() {
            return Some(all); // nothing to walk, or too many grains for one arrangement to show
        }
        let rule = self.footprint.as_ref()?;
        rule.sees_field(view, o, d, t_max).then_some(all)
    }

    /// May a ray from an event past the grain depth walk the grains ([`Self::event_field`])? Only
    /// where grains are stored or generated and fewer than [`EVENT_FIELD_MIN_GRAINS`] are discrete.
    pub(super) fn event_rays_may_walk(&self) -> bool {
        self.grid.is_some()
            && self
                .footprint
                .as_ref()
                .is_none_or(|r| r.discrete_count() < EVENT_FIELD_MIN_GRAINS)
    }

    /// The continuous equivalent of all particles when a ray that starts at no event (a surface, a
    /// boundary, a camera) carries a pixel footprint that holds many grains (an effective count over the
    /// discrete classes, `crate::render::footprint`; the ray from `o` along the unit `d` on
    /// [0, `t_max`)): None without cameras, or with the rule off.
    fn surface_field(
        &self,
        parent: &Event,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        view: &View,
        tally: &mut SurfaceTally,
    ) -> Option<&ContinuousField> {
        if parent.depth != 0 || !self.surface_footprint.load(Ordering::Relaxed) {
            return None;
        }
        let (rule, all) = (self.footprint.as_ref()?, self.grains_field.as_ref()?);
        let sees = rule.sees_field(view, o, d, t_max);
        tally.checked += 1;
        tally.saw_field += sees as u64;
        sees.then_some(all)
    }
}
