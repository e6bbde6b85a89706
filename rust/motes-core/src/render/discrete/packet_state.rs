//! The packet interface's per-thread state (module docs of `packet`): each lane's pending site and
//! last event, the thread's events, the lanes' last phase samples and blocked flights; and how a
//! lane's pending site becomes its event.

use super::channels::{LastBrackets, PacketWaves, PerChannel};
use super::counters::next_count_shard;
use super::events::{event_after_into, key, same_key, Event, EventMap, LaneEvents, NO_EVENT};
use super::flight::{FieldLanes, GrainWalk};
use super::lane::PendingLane;
use super::phase::bin_albedo;
use super::{DiscreteMedium, MAX_CHANNELS, PACKET_LANES};
use crate::render::enclosure::Enclosure;
use crate::render::footprint::View;
use crate::render::phase_lanes::PhaseLanes;
use crate::space::grid::Site;
use rustc_hash::FxHashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// A lane's free flight that ended at a site: its origin, its direction and where the site lies.
type BlockedFlight = ([f32; 3], [f32; 3], [f32; 3]);

/// Events a thread keeps per packet-interface medium: a path's events never leave its thread there.
const PACKET_EVENT_CAPACITY: usize = 512;

/// Media whose per-thread state a thread keeps before it forgets all but the one in use.
const PACKET_MEDIA_KEPT: usize = 8;

/// A lane's last phase-function sample, kept for the evaluation that Mitsuba's phase function asks for
/// next at the same event and direction where the sample's weights do not travel back with it (the C++
/// plugin's spectral `sample` calls `eval_pdf`): the inputs as their bits, the values and pdf computed
/// with the sample.
#[derive(Clone, Copy, Default)]
pub(super) struct SampledLane {
    pub(super) inputs: [[u32; 3]; 3],
    pub(super) lambda: [u64; MAX_CHANNELS],
    pub(super) values: [f64; MAX_CHANNELS],
    pub(super) pdf: f64,
}

impl SampledLane {
    pub(super) fn inputs(p: [f32; 3], wi: [f32; 3], wo: [f32; 3]) -> [[u32; 3]; 3] {
        [p, wi, wo].map(|v| v.map(f32::to_bits))
    }
    pub(super) fn lambda(lam: &[f64]) -> [u64; MAX_CHANNELS] {
        let mut out = [u64::MAX; MAX_CHANNELS];
        out.iter_mut().zip(lam).for_each(|(o, l)| *o = l.to_bits());
        out
    }
}

/// A lane's last Mueller evaluation (`mueller.rs`, `packet_phase_mueller`): the inputs (as [`SampledLane`]
/// keys them) and what they gave, so that the calls reading its elements one at a time evaluate it once.
#[derive(Clone, Copy)]
pub(super) struct MuellerLane {
    pub(super) inputs: [[u32; 3]; 3],
    pub(super) lambda: [u64; MAX_CHANNELS],
    /// Per channel F11, F12, F33, F34 (`mueller::Elements`).
    pub(super) values: [[f64; 4]; MAX_CHANNELS],
    pub(super) pdf: f64,
}

/// One thread's state of the packet interface for one medium: the pending sites of its last packet of
/// free flights, its events, and its lanes' last phase-function samples.
pub(super) struct PacketState {
    pub(super) pending: [PendingLane; PACKET_LANES],
    pub(super) events: EventMap,
    /// Each lane's last committed event ([`LaneEvents`]).
    pub(super) recent: [Option<([u32; 3], Event)>; PACKET_LANES],
    pub(super) sampled: [Option<SampledLane>; PACKET_LANES],
    /// Each lane's last Mueller evaluation (`mueller.rs`: one evaluation, read one element per call).
    pub(super) mueller: [Option<MuellerLane>; PACKET_LANES],
    /// Each lane's last free flight (origin, direction, where its site lies) where it ended at a site
    /// (whether that blocks it for certain, [`DiscreteMedium::set_enclosure`], is asked only where an
    /// evaluation towards it follows).
    pub(super) blocked: [Option<BlockedFlight>; PACKET_LANES],
    /// The medium's `optics_epoch` when these events were made (older ones carry stale albedos).
    pub(super) epoch: u64,
    /// The medium's view as of its `view_epoch` (u64::MAX: not read yet).
    pub(super) view: Arc<View>,
    /// The medium's enclosure as of its `view_epoch`.
    pub(super) enclosure: Arc<Enclosure>,
    pub(super) view_epoch: u64,
    /// The current packet's lanes that fly through the continuous field together.
    pub(super) fields: FieldLanes,
    /// The current packet's walks through the grains, and the sites of those walked as a beam (the
    /// lanes that have them: bits in `packet_free_flights`; kept here, not made empty per packet).
    pub(super) walks: [Option<GrainWalk>; PACKET_LANES],
    pub(super) found: [(Option<Site>, f64); PACKET_LANES],
    /// The current packet's phase samples at one-particle events, taken side by side (made at the
    /// first such sample: it holds this medium's tables; too big to be made afresh per packet).
    pub(super) phase: Option<Box<PhaseLanes>>,
    /// The brackets of the last wavelengths shared by a packet's lanes.
    pub(super) brackets: LastBrackets,
    /// The thread's shard of the medium's statistics counters (`ShardedCounts`).
    pub(super) count_shard: usize,
}

impl PacketState {
    /// Lane `i`'s view of the events ([`LaneEvents`]).
    pub(super) fn lane(&self, i: usize) -> LaneEvents<'_> {
        LaneEvents {
            recent: &self.recent[i],
            map: &self.events,
        }
    }
}

impl Default for PacketState {
    fn default() -> Self {
        PacketState {
            pending: [PendingLane::default(); PACKET_LANES],
            events: EventMap::new(PACKET_EVENT_CAPACITY),
            recent: [None; PACKET_LANES],
            sampled: [None; PACKET_LANES],
            mueller: [None; PACKET_LANES],
            blocked: [None; PACKET_LANES],
            epoch: 0,
            view: Arc::new(View::default()),
            enclosure: Arc::new(Enclosure::default()),
            view_epoch: u64::MAX,
            fields: FieldLanes::default(),
            walks: [const { None }; PACKET_LANES],
            found: [(None, 0.0); PACKET_LANES],
            phase: None,
            brackets: None,
            count_shard: next_count_shard(),
        }
    }
}

thread_local! {
    /// The packet interface's per-thread state, by medium id (module docs of `packet`).
    static PACKET_STATE: std::cell::RefCell<FxHashMap<u64, PacketState>> = std::cell::RefCell::new(FxHashMap::default());
}

impl DiscreteMedium {
    /// This thread's packet state for this medium.
    pub(super) fn with_packet_state<R>(&self, f: impl FnOnce(&mut PacketState) -> R) -> R {
        PACKET_STATE.with(|cell| {
            let mut states = cell.borrow_mut();
            if !states.contains_key(&self.id) && states.len() >= PACKET_MEDIA_KEPT {
                states.clear(); // media come and go (tests, notebooks): forget the old ones
            }
            let st = states.entry(self.id).or_default();
            // Events remember the albedo they were committed with: forget them when it changed.
            let epoch = self.optics_epoch.load(Ordering::Relaxed);
            if st.epoch != epoch {
                st.events.clear();
                st.recent = [None; PACKET_LANES];
                st.sampled = [None; PACKET_LANES];
                st.epoch = epoch;
            }
            f(st)
        })
    }

    /// Lane `i`'s pending site becomes its event where a call finds the lane at it (`p`, the position
    /// as the renderer placed it; `waves` the call's wavelengths): the lane's path scattered there.
    pub(super) fn settle(&self, st: &mut PacketState, i: usize, p: [f32; 3], waves: &PacketWaves) {
        if !st.pending[i].settles_at(p) {
            return;
        }
        self.settle_in(
            &mut st.pending[i],
            &mut st.events,
            &mut st.recent[i],
            p,
            waves,
            i,
        );
    }

    /// [`Self::settle`] on the parts of a packet state it changes (lane `i`'s wavelengths read only
    /// where it settles: a spectral lane's brackets cost a search per channel), where the lane is at
    /// its pending site ([`PendingLane::settles_at`], asked by the caller first).
    #[inline(never)]
    pub(super) fn settle_in(
        &self,
        pending: &mut PendingLane,
        events: &mut EventMap,
        recent: &mut Option<([u32; 3], Event)>,
        p: [f32; 3],
        waves: &PacketWaves,
        i: usize,
    ) {
        // The site read where it lies, not copied out (it was read back in wider words than the
        // copy had written: a store-forwarding stall per call).
        let Some(site) = pending.site.as_ref() else {
            return;
        };
        let k = key(p);
        if recent.as_ref().is_some_and(|(at, _)| same_key(at, &k)) {
            // The lane's event is here already: the pending site (a shadow ray's, a few ulps from
            // it) is not where the path goes on.
            return;
        }
        let lane_waves = waves.lane(i);
        let w = lane_waves.get();
        let a = match site.members() {
            // One particle (most sites): its bin and the albedo scale read once for every channel.
            [j] => {
                let (b, scale) = (&self.bins[self.optics.bin(*j)], self.albedo_scale());
                PerChannel::from_fn(w.lam.len(), |c| bin_albedo(b, w.ls[c]) * scale)
            }
            _ => PerChannel::from_fn(w.lam.len(), |c| self.site_albedo(site, w.ls[c])),
        };
        // Made where it stays (a copy of the event through the stack was a store-forwarding stall),
        // over the lane's last event (which `event_after_into` overwrites field by field): a new
        // slot's blank event, built on the stack and copied, stalled the same way.
        let (k, e) = match recent {
            Some((at, e)) => {
                *at = k;
                (&*at, e)
            }
            None => {
                let (at, e) = recent.insert((k, NO_EVENT));
                (&*at, e)
            }
        };
        event_after_into(e, site, &pending.parent, &a, w.lam);
        pending.site = None;
        // The map is the record for rays that skip the event's particles (they walk the grains from
        // it); the path's own next calls find the event beside the lane. Rays from an event that see
        // the grains' continuous equivalent skip nothing: the lane's copy is all they need (no insert
        // per event). In a sparse cloud a ray from it may walk the grains (`event_field`: a footprint
        // that holds few of them).
        if self.grains_field_from(e).is_none() || self.event_rays_may_walk() {
            events.insert(*k, *e);
        }
    }
}
