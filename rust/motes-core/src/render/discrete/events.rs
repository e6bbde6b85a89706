//! The event memory (module docs of `crate::render::discrete`): each event that starts new rays is
//! remembered by the exact bits of its position, with its site's particles (which the rays that start
//! there skip) and the path's channel throughput; and what a ray takes from the event it starts at.

use super::MAX_CHANNELS;
use crate::space::grid::Site;
use rustc_hash::FxHashMap;

/// A remembered event: the site's particles and the path's channel throughput (`discrete` docs) before
/// (`t_in`, sampling at this event) and after (`t_out`, for the next event) this event's phase sample.
/// All-zero throughputs mean "unknown": uniform channel choice.
#[derive(Clone, Copy, Debug)]
pub(super) struct Event {
    pub(super) site: Site,
    pub(super) t_in: [f32; MAX_CHANNELS],
    pub(super) t_out: [f32; MAX_CHANNELS],
    /// Which event of its chain this is (1: the first since the path entered the medium; 0: no
    /// event). A ray leaving an event at or past the medium's grain depth sees the grains' continuous
    /// equivalent (`discrete` docs, "Grains along a path").
    pub(super) depth: u32,
    /// The site's albedo per channel at the wavelengths whose first is `albedo_nm` (NaN: not known),
    /// computed when the event was remembered (the packet interface weighs its phase function by it).
    pub(super) albedo: [f32; MAX_CHANNELS],
    pub(super) albedo_nm: f32,
}

impl Default for Event {
    fn default() -> Self {
        NO_EVENT
    }
}

/// No event: what a ray that starts at none takes from it.
pub(super) const NO_EVENT: Event = Event {
    site: Site {
        t: 0.0,
        particles: [0; Site::CAPACITY],
        len: 0,
        keys: [0; Site::CAPACITY],
    },
    t_in: [0.0; MAX_CHANNELS],
    t_out: [0.0; MAX_CHANNELS],
    depth: 0,
    albedo: [0.0; MAX_CHANNELS],
    albedo_nm: f32::NAN,
};

/// What a ray takes from the event it starts at for the event it may lead to: the path's throughput
/// and the event's depth in its chain (both zero for a ray that starts at no event).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Parent {
    pub(super) t_out: [f32; MAX_CHANNELS],
    pub(super) depth: u32,
}

/// The event remembered at a site: the path's channel throughput after the site's albedo `a` (module
/// docs), from the throughput `parent` of the event the ray started at (zeros: unknown).
pub(super) fn event_after(site: Site, parent: &Parent, a: &[f64], lam: &[f64]) -> Event {
    let mut e = NO_EVENT;
    event_after_into(&mut e, &site, parent, a, lam);
    e
}

/// [`event_after`] written into `e` where it stays: an event built on the stack and moved there was
/// read back in wider words than it was written in (a store-forwarding stall per event).
#[inline(always)]
pub(super) fn event_after_into(
    e: &mut Event,
    site: &Site,
    parent: &Parent,
    a: &[f64],
    lam: &[f64],
) {
    let (depth, parent) = (parent.depth.saturating_add(1), &parent.t_out);
    let known = parent.iter().any(|&x| x > 0.0);
    let t_in = if a.len() <= MAX_CHANNELS {
        normalised_throughput(a.iter().enumerate().map(|(c, &x)| {
            if known {
                parent[c] as f64 * x
            } else {
                x
            }
        }))
    } else {
        [0.0; MAX_CHANNELS]
    };
    e.site = *site;
    (e.t_in, e.t_out, e.depth) = (t_in, t_in, depth);
    // Channel by channel where it stays (an array made on the stack was read back in one wide load
    // over its narrow stores: a store-forwarding stall per event).
    for c in 0..MAX_CHANNELS {
        e.albedo[c] = a.get(c).map_or(0.0, |&x| x as f32);
    }
    e.albedo_nm = if a.len() <= MAX_CHANNELS {
        lam.first().map_or(f32::NAN, |&l| l as f32)
    } else {
        f32::NAN
    };
}

/// Events one generation of the [`EventMap`] holds before it becomes the previous one: far more than
/// the events of the paths in flight at once (a packet batch of a few thousand lanes), so an event is
/// still found by the rays that start at it, and small enough (a few MB) to stay bounded.
pub(super) const EVENTS_PER_GENERATION: usize = 1 << 16;

/// Events by the exact bits of their position, in two generations: lookups see both, inserts go to
/// the current one, and the current one becomes the previous when it outgrows `capacity`. An event is
/// looked up by the rays that start at it (its shadow rays and the scattered ray) within a few batches,
/// long before two generations pass.
pub(super) struct EventMap {
    pub(super) current: FxHashMap<[u32; 3], Event>,
    pub(super) previous: FxHashMap<[u32; 3], Event>,
    pub(super) capacity: usize,
}

impl EventMap {
    /// An empty map whose generations hold `capacity` events each.
    pub(super) fn new(capacity: usize) -> Self {
        EventMap {
            current: FxHashMap::default(),
            previous: FxHashMap::default(),
            capacity,
        }
    }
    #[inline]
    pub(super) fn get(&self, key: &[u32; 3]) -> Option<&Event> {
        self.current.get(key).or_else(|| self.previous.get(key))
    }
    #[inline]
    pub(super) fn get_mut(&mut self, key: &[u32; 3]) -> Option<&mut Event> {
        match self.current.get_mut(key) {
            Some(e) => Some(e),
            None => self.previous.get_mut(key),
        }
    }
    pub(super) fn clear(&mut self) {
        self.current.clear();
        self.previous.clear();
    }
    pub(super) fn insert(&mut self, key: [u32; 3], event: Event) {
        if self.current.len() >= self.capacity {
            // The old generation's table becomes the new current one, emptied but with its capacity:
            // a fresh map would rehash its way up again every generation.
            std::mem::swap(&mut self.previous, &mut self.current);
            self.current.clear();
        }
        self.current.insert(key, event);
    }
}

/// Where a lane's events are looked up by position: the medium's map (batch interface), or a packet
/// lane's last event before its thread's map ([`LaneEvents`]).
pub(super) trait Events {
    fn event(&self, k: &[u32; 3]) -> Option<&Event>;
}

impl Events for EventMap {
    fn event(&self, k: &[u32; 3]) -> Option<&Event> {
        self.get(k)
    }
}

/// A packet lane's events: the last one its path settled, then its thread's map. A packet runs its
/// paths from start to end, so lane i is one path throughout, and a path's rays start at its last event
/// (its shadow rays, the phase function's sample and evaluation, its next free flight): one comparison
/// instead of hashing the position (looked up four times per event).
pub(super) struct LaneEvents<'a> {
    pub(super) recent: &'a Option<([u32; 3], Event)>,
    pub(super) map: &'a EventMap,
}

impl Events for LaneEvents<'_> {
    fn event(&self, k: &[u32; 3]) -> Option<&Event> {
        match self.recent {
            Some((at, e)) if same_key(at, k) => Some(e),
            _ => self.map.get(k),
        }
    }
}

/// `a == b`, word by word: the key just built from a position's three floats is compared where it
/// lies, not reloaded as wider words (a store-forwarding stall in every free flight's set-up).
#[inline(always)]
pub(super) fn same_key(a: &[u32; 3], b: &[u32; 3]) -> bool {
    (a[0] == b[0]) & (a[1] == b[1]) & (a[2] == b[2])
}

/// The key of an event at `p`: the bits of its position, −0 and +0 one position (Mitsuba may hand
/// either for the same point).
#[inline]
pub(super) fn key(p: [f32; 3]) -> [u32; 3] {
    p.map(|x| (x + 0.0).to_bits())
}

/// A throughput normalised to sum 1 (zeros stay zeros).
#[inline]
pub(super) fn normalised_throughput(t: impl Iterator<Item = f64>) -> [f32; MAX_CHANNELS] {
    let mut out = [0.0f64; MAX_CHANNELS];
    for (k, x) in t.take(MAX_CHANNELS).enumerate() {
        out[k] = if x.is_finite() && x > 0.0 { x } else { 0.0 };
    }
    let total: f64 = out.iter().sum();
    let inv = if total > 0.0 { 1.0 / total } else { 0.0 };
    out.map(|x| (x * inv) as f32)
}
