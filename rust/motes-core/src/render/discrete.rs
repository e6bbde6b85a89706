//! The discrete medium as a renderer sees it: exact free flights to particle *sites*, the site's albedo and
//! its phase function (paper Sec. 5; issue 5). Free of Mitsuba: the Python plugin maps these batched
//! queries onto Mitsuba's medium and phase-function interfaces.
//!
//! ## Model
//! Along a ray the discrete optical depth is a staircase: particle i, passing within R_i of the ray with
//! its centre projecting at t_i, adds τ_i. A free flight is sampled exactly by walking the
//! particles in t order ([`ParticleGrid::sample_site`]): no majorant, no null collisions. The
//! interaction happens at the site's t (the particle's projection on the ray). The scattered path must
//! not meet the particle that scattered it again (its internal paths are already in its phase
//! function), so each event that starts new rays is remembered by the exact bits of its position and
//! the particles of that event are skipped by rays starting there (`EventMap`); the phase function
//! finds the event's particles there too (or, failing that, from the geometry along the incident ray).
//!
//! ## Per-particle optical depth (a documented deviation from Eq. 18)
//! The paper spreads C_t,i over the query disk, τ_i = C_t,i / (π R_i²) with R_i = r_c + r_i, so that
//! E\[τ\] = σ_t · length. That is right only while τ_i ≪ 1: a ray through the disk interacts with
//! probability 1 − e^{−τ_i}, so the disk removes π R_i² (1 − e^{−τ_i}) < C_t,i from a beam. With
//! r_c = 0 and Q_ext ≈ 2 (τ_i ≈ 2) that is 43 % of C_t,i: the medium lets 57 % of the extinction and
//! side scattering through (measured against explicit spheres, issue 9). Two changes make every
//! particle's expected extinction exact whatever r_c:
//! * τ_i = −ln(1 − x_i) with the fill x_i = C_t,i / (π R_i²): then π R_i² (1 − e^{−τ_i}) = C_t,i, so
//!   the mean transmittance of a random cloud is exactly Beer–Lambert exp(−σ_t L) and each particle
//!   scatters exactly C_s,i of a beam;
//! * a floor on the disk, R_i = max(r_c + r_i, √(C_t,i / (π x_max))) with x_max = 1 − e^{−τ_max}, so
//!   that x_i < 1 and τ_i ≤ τ_max ([`DEFAULT_TAU_MAX`]; τ_max = ∞ allows opaque disks of area C_t,i).
//!
//! The grid walks these τ_i and R_i; Eq. 24's local density keeps the true C_t,i / (4/3 π R_i³).
//!
//! ## Grains along a path (issue 25; Müller et al. 2016, Sec. 4.3 and 7.1)
//! A viewer sees a grain one by one only where a path meets it first: directly visible grains and their
//! glints. Once a path has scattered, the grains its later rays meet are seen only through the light
//! they pass on, and the continuous equivalent of the same cells (per-cell extinction Σ C_t,i / V and the
//! cell's phase mixture, `crate::render::continuous`) carries the same expected transport. So rays that
//! leave a path's `grain_depth`-th event or a later one (events remember their depth in the chain;
//! default [`DEFAULT_GRAIN_DEPTH`] = 1: every ray after the first scattering) sample that field instead
//! of walking grains; camera rays still walk them. What changes is the grain texture of multiply
//! scattered light, which no pixel resolves (measured against the fully discrete render by
//! `scripts/bench/bench_dense.py`: image means within noise and per-pixel differences at noise
//! level). Rays that start at no event (a wall's shadow ray, a bounce off the floor, a camera ray
//! re-spawned at the medium's boundary) see the same field where the narrowest pixel footprint they
//! can carry holds many grains (`crate::render::footprint`; camera rays never do). An infinite
//! `continuous_count` keeps the medium exact: no field is built and every ray walks the grains.
//!
//! ## Colour weights along a path (throughput-proportional channel choice)
//! The phase function is sampled from a mixture over channels, q(ω) = Σ_c π_c f_c(ω), and returns the
//! weights f_c / q. With π uniform (the channel mean) every bounce's weights average 1, but their
//! product over hundreds of bounces in a dense cloud is a multiplicative random walk: unbiased, yet so
//! heavy-tailed that a white furnace read 0.91–0.97 at practical sample counts (issue 9). Instead each
//! event carries the path's channel throughput t_c (normalised; the product of the albedos and the
//! phase weights since the path entered the chain of remembered events) and samples channel c with
//! π_c = (1 − ε) t_c + ε / C (ε = [`DEFENSIVE_MIX`]): then Σ_c t_c f_c / q stays ≈ 1, so per-channel
//! path weights stay bounded (hero-wavelength sampling, Wilkie et al. 2014, done incrementally). Any π
//! that depends only on the path's past keeps the estimator unbiased; `eval` uses the same π, so NEE's
//! MIS weights match. A path that leaves the chain (a surface, an evicted event) restarts uniform.
//!
//! ## Colour
//! The free flight uses one (grey) optical depth per particle: the mean of τ over the tabulated
//! wavelengths. Per wavelength the site has its own albedo a_c = C_s,c / C_t,c and phase function
//! f_c. Why grey: Mitsuba's medium interface applies per-channel weights at collisions but not to a
//! path that leaves the medium without one, so a channel-dependent free flight cannot be re-weighted
//! there (see `mitsuba_plugin/motes/plugins/discrete.py`). A non-absorbing particle keeps a_c = 1 in
//! every channel, so energy is conserved exactly (white furnace); what is approximated is the colour
//! of the transmittance, by the spread of C_t over the channels (measured by scripts/figures/grey_extinction.py, BENCHMARKS.md).
//!
//! ## Phase function of a site (Eq. 24)
//! With the site's particles j, scattering weights s_j,c = τ_j a_j,c, the phase function for
//! channel c is the mixture f_c(μ) = Σ_j s_j,c f_j,c(μ) / Σ_j s_j,c — σ_s f of the site is Q(θ) of
//! Eq. 24 for the particles it holds. Sampling picks a channel uniformly, a particle with probability
//! ∝ s_j,c, then its tabulated f (piecewise linear in μ, inverse-CDF sampling). The pdf returned is
//! the mean over channels of f_c (one-sample MIS over channels), so `sample` and `eval` agree
//! exactly and the weights f_c / pdf stay bounded.

use crate::ensemble::phase_table::PhaseTable;
use crate::error::{require, require_len, OpticsError};
use crate::render::continuous::{resolvable, Column, ContinuousField, FieldHit, CLASS_FLAG};
use crate::render::enclosure::Enclosure;
use crate::render::env_flag;
use crate::render::footprint::{ClassMoments, SurfaceFootprint, View};
use crate::render::phase_lanes::PhaseLanes;
use crate::render::procedural::{build_parts, ProceduralGrains, ProceduralSpec};
use crate::render::storage::{classes, ParticleOptics, Storage};
use crate::rng::{stream_bits, unit_f64, GOLDEN_GAMMA};
use crate::space::dda::Bounds3;
use crate::space::grid::{
    bounding_box, check_particles, GridSettings, ParticleGrid, Particles, Site,
};
use crate::space::ray::RaySegment;
use crate::space::vec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};

/// Optical data of one radius bin of one species at the tabulated wavelengths.
pub struct BinOptics {
    /// Single-scattering albedo C_s / C_t per tabulated wavelength.
    pub albedo: Vec<f64>,
    /// Phase function per tabulated wavelength.
    pub phase: Vec<PhaseTable>,
}

/// Default cap on a particle's optical depth τ_i (module docs): its disk is widened until
/// τ_i ≤ 1, i.e. a ray through it interacts with probability at most 1 − e^{−1} = 63 %.
pub const DEFAULT_TAU_MAX: f64 = 1.0;
/// Default grain depth (`DiscreteMedium::set_grain_depth`): rays leaving a path's first scattering
/// event or a later one see the grains' continuous equivalent.
pub const DEFAULT_GRAIN_DEPTH: u32 = 1;
/// Share of uniform channel choice mixed into the throughput-proportional one (module docs): bounds a
/// bounce's weights by C / ε even for a channel whose throughput has fallen to 0.
pub const DEFENSIVE_MIX: f64 = 0.1;
/// Optical depth of a disk whose fill reaches 1 (opaque; e^{−30} ≈ 1e-13).
const TAU_OPAQUE: f64 = 30.0;
/// Stream of [`uniform`] numbers, drawn from a free flight's own, that the continuous field uses (its
/// distance, then the particle picked), independent of the discrete walk's.
const FIELD_STREAM: u64 = 0xF1E1D;
/// Channels whose throughput an event can carry (RGB: 3, Mitsuba's spectral variants: 4).
pub const MAX_CHANNELS: usize = 4;

/// A remembered event: the site's particles and the path's channel throughput (module docs) before
/// (`t_in`, sampling at this event) and after (`t_out`, for the next event) this event's phase sample.
/// All-zero throughputs mean "unknown": uniform channel choice.
#[derive(Clone, Copy, Debug)]
struct Event {
    site: Site,
    t_in: [f32; MAX_CHANNELS],
    t_out: [f32; MAX_CHANNELS],
    /// Which event of its chain this is (1: the first since the path entered the medium; 0: no
    /// event). A ray leaving an event at or past the medium's grain depth sees the grains' continuous
    /// equivalent (module docs, "Grains along a path").
    depth: u32,
    /// The site's albedo per channel at the wavelengths whose first is `albedo_nm` (NaN: not known),
    /// computed when the event was remembered (the packet interface weighs its phase function by it).
    albedo: [f32; MAX_CHANNELS],
    albedo_nm: f32,
}

/// No event: what a ray that starts at none takes from it.
const NO_EVENT: Event = Event {
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

impl Default for Event {
    fn default() -> Self {
        NO_EVENT
    }
}

/// Channel choice probabilities π from a throughput (zeros: uniform), `channels` of them.
fn channel_probabilities(t: &[f32; MAX_CHANNELS], channels: usize) -> [f64; MAX_CHANNELS] {
    let mut pi = [0.0; MAX_CHANNELS];
    let c = channels.min(MAX_CHANNELS);
    let total: f64 = t[..c].iter().map(|&x| x as f64).sum();
    let uniform = 1.0 / c as f64;
    // One division, not one per channel (these were 4 % of a dense cloud's per-event work).
    let inv = if total > 0.0 && total.is_finite() {
        1.0 / total
    } else {
        0.0
    };
    for k in 0..c {
        let share = if inv > 0.0 {
            t[k] as f64 * inv
        } else {
            uniform
        };
        pi[k] = (1.0 - DEFENSIVE_MIX) * share + DEFENSIVE_MIX * uniform;
    }
    pi
}

/// A throughput normalised to sum 1 (zeros stay zeros).
fn normalised_throughput(t: impl Iterator<Item = f64>) -> [f32; MAX_CHANNELS] {
    let mut out = [0.0f64; MAX_CHANNELS];
    for (k, x) in t.take(MAX_CHANNELS).enumerate() {
        out[k] = if x.is_finite() && x > 0.0 { x } else { 0.0 };
    }
    let total: f64 = out.iter().sum();
    let inv = if total > 0.0 { 1.0 / total } else { 0.0 };
    out.map(|x| (x * inv) as f32)
}

/// The event remembered at a site: the path's channel throughput after the site's albedo `a` (module
/// docs), from the throughput `parent` of the event the ray started at (zeros: unknown).
fn event_after(site: Site, parent: &Parent, a: &[f64], lam: &[f64]) -> Event {
    let mut e = NO_EVENT;
    event_after_into(&mut e, &site, parent, a, lam);
    e
}

/// [`event_after`] written into `e` where it stays: an event built on the stack and moved there was
/// read back in wider words than it was written in (a store-forwarding stall per event).
#[inline(always)]
fn event_after_into(e: &mut Event, site: &Site, parent: &Parent, a: &[f64], lam: &[f64]) {
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

/// What a ray takes from the event it starts at for the event it may lead to: the path's throughput
/// and the event's depth in its chain (both zero for a ray that starts at no event).
#[derive(Clone, Copy, Debug, Default)]
struct Parent {
    t_out: [f32; MAX_CHANNELS],
    depth: u32,
}

/// Bits of a ray's origin and direction, mixed: the ray's share of its random numbers (the caller's
/// SplitMix64 finaliser spreads them). Three words multiplied side by side by odd constants and
/// rotated apart, not one FNV chain of six dependent multiplies (3 % of a dense cloud's events).
fn ray_bits(o: &[f32; 3], d: &[f32; 3]) -> u64 {
    let word = |a: f32, b: f32| a.to_bits() as u64 | (b.to_bits() as u64) << 32;
    let x = word(o[0], o[1]).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let y = word(o[2], d[0]).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    let z = word(d[1], d[2]).wrapping_mul(0x1656_67B1_9E37_79F9);
    x ^ y.rotate_left(21) ^ z.rotate_left(42)
}

/// Lane `i`'s wavelengths in `lambda`: all of it when its `channels` wavelengths are shared by
/// every lane, else the lane's own `channels` of them.
fn lane_wavelengths(lambda: &[f64], channels: usize, i: usize) -> &[f64] {
    if lambda.len() == channels {
        lambda
    } else {
        &lambda[i * channels..(i + 1) * channels]
    }
}

/// Per-channel values of one lane: up to [`MAX_CHANNELS`] inline, more on the heap, so that a lane's
/// phase-function work allocates nothing in the RGB and spectral variants (allocations were 4 % of a
/// dense render).
#[derive(Clone, Debug)]
enum PerChannel<T> {
    Inline([T; MAX_CHANNELS], usize),
    Heap(Vec<T>),
}

impl<T: Copy + Default> PerChannel<T> {
    fn from_fn(n: usize, mut f: impl FnMut(usize) -> T) -> Self {
        if n <= MAX_CHANNELS {
            let mut a = [T::default(); MAX_CHANNELS];
            a.iter_mut()
                .take(n)
                .enumerate()
                .for_each(|(c, x)| *x = f(c));
            PerChannel::Inline(a, n)
        } else {
            PerChannel::Heap((0..n).map(f).collect())
        }
    }
}

impl<T> std::ops::Deref for PerChannel<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match self {
            PerChannel::Inline(a, n) => &a[..*n],
            PerChannel::Heap(v) => v,
        }
    }
}

impl<T> std::ops::DerefMut for PerChannel<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match self {
            PerChannel::Inline(a, n) => &mut a[..*n],
            PerChannel::Heap(v) => v,
        }
    }
}

/// Uniform channel choice.
fn uniform_channels(channels: usize) -> PerChannel<f64> {
    PerChannel::from_fn(channels, |_| 1.0 / channels as f64)
}

/// The channel choice of an event for `channels` channels (uniform beyond [`MAX_CHANNELS`]).
fn event_channels(e: &Event, channels: usize) -> PerChannel<f64> {
    if channels > MAX_CHANNELS {
        return uniform_channels(channels);
    }
    let pi = channel_probabilities(&e.t_in, channels);
    PerChannel::from_fn(channels, |c| pi[c])
}

/// Events one generation of the [`EventMap`] holds before it becomes the previous one: far more than
/// the events of the paths in flight at once (a packet batch of a few thousand lanes), so an event is
/// still found by the rays that start at it, and small enough (a few MB) to stay bounded.
const EVENTS_PER_GENERATION: usize = 1 << 16;

/// Events by the exact bits of their position, in two generations: lookups see both, inserts go to
/// the current one, and the current one becomes the previous when it outgrows `capacity`. An event is
/// looked up by the rays that start at it (its shadow rays and the scattered ray) within a few batches,
/// long before two generations pass.
struct EventMap {
    current: FxHashMap<[u32; 3], Event>,
    previous: FxHashMap<[u32; 3], Event>,
    capacity: usize,
}

impl EventMap {
    /// An empty map whose generations hold `capacity` events each.
    fn new(capacity: usize) -> Self {
        EventMap {
            current: FxHashMap::default(),
            previous: FxHashMap::default(),
            capacity,
        }
    }
    fn get(&self, key: &[u32; 3]) -> Option<&Event> {
        self.current.get(key).or_else(|| self.previous.get(key))
    }
    fn get_mut(&mut self, key: &[u32; 3]) -> Option<&mut Event> {
        match self.current.get_mut(key) {
            Some(e) => Some(e),
            None => self.previous.get_mut(key),
        }
    }
    fn clear(&mut self) {
        self.current.clear();
        self.previous.clear();
    }
    fn insert(&mut self, key: [u32; 3], event: Event) {
        if self.current.len() >= self.capacity {
            // The old generation's table becomes the new current one, emptied but with its capacity:
            // a fresh map would rehash its way up again every generation (1 % of a scalar render).
            std::mem::swap(&mut self.previous, &mut self.current);
            self.current.clear();
        }
        self.current.insert(key, event);
    }
}

/// Where a lane's events are looked up by position: the medium's map (batch interface), or a packet
/// lane's last event before its thread's map ([`LaneEvents`]).
trait Events {
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
/// instead of hashing the position (looked up four times per event, 5–7 % of a dense render).
struct LaneEvents<'a> {
    recent: &'a Option<([u32; 3], Event)>,
    map: &'a EventMap,
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
fn same_key(a: &[u32; 3], b: &[u32; 3]) -> bool {
    (a[0] == b[0]) & (a[1] == b[1]) & (a[2] == b[2])
}

fn key(p: [f32; 3]) -> [u32; 3] {
    // −0 and +0 are one position (Mitsuba may hand either for the same point).
    p.map(|x| (x + 0.0).to_bits())
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
#[inline(always)] // its pair came back through memory with a store-forwarding stall (3 % of scalar_rgb)
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
fn field_key(u: f64) -> u64 {
    stream_key(u.to_bits(), FIELD_STREAM)
}

/// A uniform number in [0, 1) from (seed, call, lane): SplitMix64 finaliser over a mixed counter, so
/// renders are reproducible whatever the thread schedule.
fn uniform(seed: u64, call: u64, lane: u64) -> f64 {
    unit_f64(random_bits(seed, call, lane))
}

/// The 64 random bits behind [`uniform`].
fn random_bits(seed: u64, call: u64, lane: u64) -> u64 {
    stream_bits(stream_key(seed, call), lane)
}

/// The stream of call `call` under `seed` ([`random_bits`] by index).
fn stream_key(seed: u64, call: u64) -> u64 {
    seed ^ call.wrapping_mul(GOLDEN_GAMMA)
}

/// The direction at cos θ = `mu` from `w_in`, at azimuth 2π `u` around it.
#[inline(always)]
fn deflect(w_in: [f64; 3], mu: f64, u: f64) -> [f64; 3] {
    let phi = 2.0 * PI * u;
    let st = (1.0 - mu * mu).max(0.0).sqrt();
    let (e1, e2) = frame(w_in);
    // φ in single precision: the direction goes to the renderer as float32 anyway.
    let (sin_phi, cos_phi) = (phi as f32).sin_cos();
    let (sin_phi, cos_phi) = (sin_phi as f64, cos_phi as f64);
    [0, 1, 2].map(|a| mu * w_in[a] + st * (cos_phi * e1[a] + sin_phi * e2[a]))
}

/// Unit vector and two perpendicular ones (Duff et al. 2017 branchless frame).
fn frame(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let sign = if n[2] >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    (
        [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]],
        [b, sign + n[1] * n[1] * a, -n[1]],
    )
}

/// A bin's albedo at the wavelength bracket `l` (without the medium's albedo scale).
#[inline(always)]
fn bin_albedo(b: &BinOptics, l: (usize, usize, f64)) -> f64 {
    (1.0 - l.2) * b.albedo[l.0] + l.2 * b.albedo[l.1]
}

/// A bin's phase function at the wavelength bracket `l` and μ = cos θ.
#[inline(always)]
fn bin_phase(b: &BinOptics, l: (usize, usize, f64), mu: f64) -> f64 {
    let lo = b.phase[l.0].eval(mu);
    if l.2 == 0.0 {
        lo
    } else {
        (1.0 - l.2) * lo + l.2 * b.phase[l.1].eval(mu)
    }
}

/// [`bin_phase`] at a location of μ in the bin's tables, all on the same nodes ([`PhaseTable::locate`]).
#[inline(always)]
fn bin_phase_at(b: &BinOptics, l: (usize, usize, f64), at: (usize, f64)) -> f64 {
    let lo = b.phase[l.0].eval_at(at);
    if l.2 == 0.0 {
        lo
    } else {
        (1.0 - l.2) * lo + l.2 * b.phase[l.1].eval_at(at)
    }
}

/// A mixture of particles as a phase function sees it (module docs): particle j of `members` weighs
/// `scale(j)` × its albedo in each channel; `ls` are the channels' wavelength brackets (from
/// `DiscreteMedium::bracket`) and `pi` the probabilities of sampling each channel.
struct Mixture<'a, S> {
    members: &'a [u32],
    scale: S,
    ls: &'a [(usize, usize, f64)],
    pi: &'a [f64],
}

/// A sampled direction, its weights per channel (value / pdf) and pdf.
type Sample = ([f64; 3], PerChannel<f64>, f64);

fn null_sample(channels: usize) -> Sample {
    ([0.0, 0.0, 1.0], PerChannel::from_fn(channels, |_| 0.0), 0.0)
}

/// Per-lane samples as flat columns (directions, weights lane-major, pdfs).
fn unzip_samples(res: Vec<Sample>) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
    let wo = res.iter().map(|r| r.0).collect();
    let pdf = res.iter().map(|r| r.2).collect();
    (
        wo,
        res.iter().flat_map(|r| r.1.iter().copied()).collect(),
        pdf,
    )
}

fn normalise(v: [f64; 3]) -> Option<[f64; 3]> {
    let n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if (n2 - 1.0).abs() < 1e-6 {
        // A unit vector to float32 rounding (every direction Mitsuba hands over): one Newton step
        // of 1/√n² from 1 leaves |v| − 1 below 1e-12, without the square root and divisions (half a
        // dense render's per-ray set-up).
        let s = 1.5 - 0.5 * n2;
        return Some(v.map(|x| x * s));
    }
    let l = n2.sqrt();
    (l.is_finite() && l > 0.0).then(|| v.map(|x| x / l))
}

/// A ray's walk through the grains still to do (`DiscreteMedium::lane_plan`).
struct GrainWalk {
    /// The whole ray, [0, t_max].
    ray: RaySegment,
    /// The continuous field's interaction (the walk stops there) and the field's optical depth.
    hit: Option<FieldHit>,
    tau_field: f64,
    u: f64,
    /// The particles of the event the ray starts at (skipped).
    parent: Site,
    from: Parent,
}

impl GrainWalk {
    /// The segment whose grains the walk visits: up to the field's interaction.
    fn grains(&self) -> RaySegment {
        self.ray.between(0.0, self.hit.map_or(self.ray.t1, |h| h.t))
    }
}

/// A ray's free flight as far as `DiscreteMedium::lane_plan` takes it.
enum Plan<'a> {
    /// Its site, the optical depth before it, what it takes from its parent event.
    Done(Option<Site>, f64, Parent),
    Walk(GrainWalk),
    /// A free flight through a continuous field alone, queued in the caller's [`FieldLanes`] (a
    /// packet's field flights are flown together, [`ContinuousField::sample_free_flights`]).
    Deferred(&'a ContinuousField),
}

/// A packet's lanes whose free flights go through one continuous field alone ([`Plan::Deferred`]), flown
/// together by [`ContinuousField::sample_free_flights`]. Kept in the thread's [`PacketState`] (1.5 kB:
/// made afresh on the stack, or boxed, per packet it cost what it saved in scalar_rgb and llvm_ad_rgb).
struct FieldLanes {
    n: usize,
    /// The address of the field they fly through (0: none yet): a packet's lanes fly through one.
    field: usize,
    lane: [usize; PACKET_LANES],
    rays: [RaySegment; PACKET_LANES],
    keys: [u64; PACKET_LANES],
    u: [f64; PACKET_LANES],
    parent: [Parent; PACKET_LANES],
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
    /// store-forwarding stall per lane, 1 % of a dense render).
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
    fn fly(&self, f: &ContinuousField, pending: &mut [PendingLane]) {
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

/// A lane of the last `sample_sites` call awaiting `commit_events`: its site, whether to remember it,
/// and the channel throughput of the event its ray started at (zeros: none).
type Pending = (Option<Site>, bool, Parent);

/// What a medium's free flights walk and look up, as its builds make it ([`DiscreteMedium`]'s fields).
struct Walkable {
    grid: Option<Grains>,
    expected: Option<(f64, f64)>,
    field: Option<ContinuousField>,
    grains_field: Option<ContinuousField>,
    footprint: Option<SurfaceFootprint>,
    optics: ParticleOptics,
    widened: usize,
    coincide: f64,
    event_box: Bounds3,
}

/// The particles walked one by one: stored in a grid, or a procedural cloud's bricks generated on
/// demand (`crate::render::procedural`).
enum Grains {
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
    fn walk(&self, ray: &RaySegment, mut visit: impl FnMut(f64, u32, u64) -> bool) {
        match self {
            Grains::Stored(g) => g.walk(ray, |t, _, i| visit(t, i, 0)),
            Grains::Procedural(p) => p.walk(ray, |t, _, m, k| visit(t, m, k)),
        }
    }
    fn containing(&self, p: [f64; 3]) -> Vec<u32> {
        match self {
            Grains::Stored(g) => g.containing(p),
            Grains::Procedural(g) => g.containing(p),
        }
    }
    fn optical_depth(&self, ray: &RaySegment) -> f64 {
        match self {
            Grains::Stored(g) => {
                let mut v = [0.0];
                g.optical_depth(ray, &mut v);
                v[0]
            }
            Grains::Procedural(p) => p.optical_depth(ray),
        }
    }
    fn bytes(&self) -> usize {
        match self {
            Grains::Stored(g) => g.bytes(),
            Grains::Procedural(p) => p.bytes(),
        }
    }
}

/// The discrete medium: particles in a grid with grey optical depths, and per-bin optics.
pub struct DiscreteMedium {
    /// The particles sampled one by one (None when every class is continuous).
    grid: Option<Grains>,
    /// A procedural cloud's expected particles, all and in `field` (its counts are not stored).
    expected: Option<(f64, f64)>,
    /// The size classes no pixel resolves, sampled as a continuous medium (None when there are none).
    field: Option<ContinuousField>,
    /// Each particle's disk (R_i = max(r_c + r_i, floor), τ_i = −ln(1 − x_i); module docs), C_t,i,
    /// optics bin and whether it lives in `field`, by original index, per particle or per class
    /// (`crate::render::storage`).
    optics: ParticleOptics,
    /// Particles whose disk the τ_max floor widened beyond r_c + r_i.
    widened: usize,
    /// Do a packet's rays from no event walk the grains as beams where they make one
    /// (`ParticleGrid::sample_sites_beam`)? `MOTES_BEAM=0` at build: one by one (the same sites;
    /// `scripts/bench/bench_quantise.py --switch MOTES_BEAM`'s comparison).
    beams: bool,
    bins: Vec<BinOptics>,
    /// Per bin: are its phase tables all on the same nodes (one search serves every channel)?
    shared_nodes: Vec<bool>,
    /// Tabulated wavelengths, increasing (any unit; the caller's channel wavelengths use the same).
    lambda: Vec<f64>,
    /// Projections closer than this along a ray form one site (scene units).
    coincide: f64,
    events: RwLock<EventMap>,
    /// Sites sampled by each calling thread's last `sample_sites` call, per lane, until its
    /// `commit_events` (Mitsuba's scalar variants call from several render threads at once).
    pending: Mutex<FxHashMap<std::thread::ThreadId, Vec<Pending>>>,
    seed: u64,
    calls: AtomicU64,
    /// Identifies the medium's per-thread state in the packet interface.
    id: u64,
    /// Rays and interactions of the packet interface so far (statistics).
    packet_counts: ShardedCounts,
    /// Factor on every particle's albedo (f64 bits; 1 at build), editable between renders (a look
    /// control: `set_albedo_scale`). Albedos are clamped to 1 after it.
    albedo_scale: AtomicU64,
    /// Where the renderer can place events: the particles' box grown by the largest disk (a site lies
    /// within its particles' disks). A free flight from outside it (a camera, a wall) starts at no event
    /// and skips the event lookup.
    event_box: Bounds3,
    /// The continuous equivalent of every particle, discrete classes included (None when
    /// `continuous_count` is infinite: the medium is then exact, fully discrete).
    grains_field: Option<ContinuousField>,
    /// Rays leaving the `grain_depth`-th event of a path or a later one sample `grains_field` instead
    /// of walking grains (module docs, "Grains along a path"); `u32::MAX`: never.
    grain_depth: std::sync::atomic::AtomicU32,
    /// When a ray that starts at no event (a surface, a boundary) may see `grains_field`
    /// (`crate::render::footprint`; None when the medium is exact or has no discrete class).
    footprint: Option<SurfaceFootprint>,
    /// The scene's cameras and lights, as the renderer set them (`set_view`; no camera: rays from
    /// surfaces walk the grains).
    view: RwLock<Arc<View>>,
    /// Counts `set_view` calls: the packet path keeps each thread's own reference to the view and
    /// takes the lock only when this changed (a shared lock per packet made two threads fight over its
    /// cache line: 8 % of a scalar render, where a packet is one ray).
    view_epoch: AtomicU64,
    /// The convex shapes that hold the medium, where the renderer vouches that a site inside one blocks
    /// a shadow ray from inside it (`set_enclosure`, `crate::render::enclosure`; empty: unknown). Read
    /// by the packet path with the view (`view_epoch`).
    enclosure: RwLock<Arc<Enclosure>>,
    /// Whether the footprint rule applies (`set_surface_footprint`).
    surface_footprint: std::sync::atomic::AtomicBool,
    /// Rays checked against the rule, and those that saw the field (statistics).
    surface_counts: ShardedCounts,
    /// Set once `insert_event` placed an event anywhere: then every free flight looks events up.
    events_anywhere: std::sync::atomic::AtomicBool,
    /// Counts changes of the optics (`set_albedo_scale`): per-thread events of an older epoch are
    /// dropped before use.
    optics_epoch: AtomicU64,
}

/// The checks of a particle set and the medium's settings that need no optics: one home for these
/// rules, called by [`DiscreteMedium::build`] and, before it spends minutes on optics tables, by the
/// Python layer (so that a bad setting fails at once).
pub fn check_particles_and_settings(
    positions: &[[f64; 3]],
    radius: &[f64],
    query_radius: f64,
    tau_max: f64,
    cells_per_particle: f64,
    continuous_count: f64,
) -> Result<(), OpticsError> {
    check_particles(
        positions,
        radius,
        &GridSettings::new(query_radius, cells_per_particle),
    )?;
    require("tau_max", tau_max, tau_max > 0.0, "> 0 (inf: no cap)")?;
    require(
        "continuous_count",
        continuous_count,
        continuous_count > 0.0,
        "> 0 (inf: every class discrete)",
    )
}

/// The checks of [`DiscreteMedium::build`]'s inputs, each naming its argument.
#[allow(clippy::too_many_arguments)]
fn check_build_inputs(
    positions: &[[f64; 3]],
    radius: &[f64],
    radius_scale: f64,
    c_ext: Column,
    bin: &[u32],
    bins: &[BinOptics],
    lambda: &[f64],
    query_radius: f64,
    tau_max: f64,
    cells_per_particle: f64,
    continuous_count: f64,
) -> Result<(), OpticsError> {
    let n = positions.len();
    // Indices of particles stay below CLASS_FLAG (the continuous fields' class members use that bit).
    require(
        "positions (count)",
        n as f64,
        (n as u64) < CLASS_FLAG as u64,
        "< 2^31 particles",
    )?;
    require_len("bin (length)", bin.len(), n, "one per particle")?;
    require(
        "radius_scale",
        radius_scale,
        radius_scale.is_finite() && radius_scale > 0.0,
        "finite and > 0",
    )?;
    check_particles_and_settings(
        positions,
        radius,
        query_radius,
        tau_max,
        cells_per_particle,
        continuous_count,
    )?;
    if let Some(&b) = bin.iter().find(|&&b| b as usize >= bins.len()) {
        require("bin (index)", b as f64, false, "< number of bins")?;
    }
    for i in 0..n {
        let c = c_ext(i);
        require("c_ext", c, c.is_finite() && c >= 0.0, "finite and >= 0")?;
    }
    require(
        "lambda (length)",
        lambda.len() as f64,
        !lambda.is_empty(),
        ">= 1",
    )?;
    for w in lambda.windows(2) {
        require("lambda", w[1], w[1] > w[0], "strictly increasing")?;
    }
    for (b, o) in bins.iter().enumerate() {
        require(
            "bins (albedo per wavelength)",
            b as f64,
            o.albedo.len() == lambda.len() && o.phase.len() == lambda.len(),
            "one albedo and one phase table per wavelength",
        )?;
        for &a in &o.albedo {
            require(
                "albedo",
                a,
                a.is_finite() && (0.0..=1.0 + 1e-9).contains(&a),
                "in [0, 1]",
            )?;
        }
    }
    Ok(())
}

/// The structures a free flight walks: the grid of the particles whose grains a pixel can resolve and
/// the continuous field of the others (`continuous_count`, crate::render::continuous), and which is which.
/// With `classes` (compact storage) the grid names its particles by position
/// ([`ParticleGrid::positional`]), and the last item is their original indices in that order.
#[allow(clippy::type_complexity)]
fn build_walk(
    positions: &[[f64; 3]],
    reach: Column,
    grid_radius: Column,
    grid_c: Column,
    c_ext: Column,
    settings: &GridSettings,
    continuous_count: f64,
    classes: Option<&[u32]>,
) -> (
    Option<ParticleGrid>,
    Option<ContinuousField>,
    Vec<bool>,
    Option<SurfaceFootprint>,
    Option<Vec<u32>>,
) {
    let n = positions.len();
    let (keep, footprint) = resolvable(positions, reach, c_ext, continuous_count);
    let (discrete_ids, field_ids): (Vec<u32>, Vec<u32>) =
        (0..n as u32).partition(|&i| keep[i as usize]);
    // The grid reads its particles through the columns and reports their original indices (no
    // copies: a subset of 10^8 particles would be 40 bytes each).
    let settings = &settings.centred(settings.centre_cells && centre_cells_for(discrete_ids.len()));
    let grid = (!discrete_ids.is_empty()).then(|| {
        ParticleGrid::from_particles(
            &Particles {
                positions,
                ids: (!field_ids.is_empty()).then_some(&discrete_ids[..]),
                radius: grid_radius,
                c_ext: &|i, _| grid_c(i),
                channels: 1,
            },
            settings,
        )
    });
    // Compact storage: particles named by position (no index kept).
    let (grid, order) = match (grid, classes) {
        (Some(g), Some(_)) => {
            let (g, order) = g.positional();
            (Some(g), Some(order))
        }
        (g, Some(_)) => (g, Some(Vec::new())),
        (g, None) => (g, None),
    };
    // The medium keeps its grid for rendering: what the slots duplicate is dropped.
    let grid = grid.map(|mut g| {
        g.release_stored();
        g
    });
    // Weighted by C_t,i, the extinction each disk removes from a beam (π R² (1 − e^{−τ_i})), not by
    // τ_i π R²: the mean transmittance of the discrete rays is e^{−n C L} (module docs). The field
    // selects its particles from the full columns (every particle continuous: all of them).
    let field = (!field_ids.is_empty()).then(|| {
        let ids = (!discrete_ids.is_empty()).then_some(&field_ids[..]);
        ContinuousField::build(positions, reach, c_ext, ids, classes)
    });
    (grid, field, keep, footprint, order)
}

/// The surface-ray rule (`crate::render::footprint`) of a procedural cloud: its discrete classes'
/// expected counts over the box's bounding box, grouped into the size classes that chose them.
fn procedural_footprint(
    count: f64,
    parts: &crate::render::procedural::ProceduralParts,
    disks: &[(f64, f64)],
    min_count: f64,
) -> Option<SurfaceFootprint> {
    let (lo, hi) = bounding_box(&parts.corners);
    let volume: f64 = (0..3).map(|a| (hi[a] - lo[a]).max(0.0)).product();
    let reach_max = disks.iter().map(|d| d.0).fold(0.0, f64::max);
    let mut sums = [[0.0f64; 4]; crate::space::grid::SIZE_CLASSES];
    let mut sigma = 0.0;
    for ((c, d), &discrete) in parts.classes.iter().zip(disks).zip(&parts.discrete) {
        let w = count * c.p;
        sigma += w * c.c_ext;
        if discrete && w > 0.0 {
            let s = &mut sums[crate::space::grid::size_class(reach_max, d.0)];
            s[0] += w;
            s[1] += w * d.0;
            s[2] += w * d.0 * d.0;
            s[3] += w * c.c_ext;
        }
    }
    let classes = sums
        .iter()
        .map(|s| ClassMoments::from_sums(*s, volume))
        .collect();
    // resolvable's cylinder length: the box's mean chord 4V/S, or a mean free path if shorter.
    let e = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(0.0));
    let surface = 2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]);
    let chord = if surface > 0.0 {
        4.0 * volume / surface
    } else {
        0.0
    };
    let length = if sigma > 0.0 {
        chord.min(volume / sigma)
    } else {
        chord
    };
    SurfaceFootprint::new(classes, Bounds3 { lo, hi }, length, min_count)
}

/// Inclusion radius and optical depth of one particle's disk (module docs): the disk r_c + r is
/// widened until its fill x = C / (π R²) is at most 1 − e^{−τ_max}, and τ = −ln(1 − x).
pub fn particle_disk(radius: f64, c_ext: f64, query_radius: f64, tau_max: f64) -> (f64, f64) {
    let fill_max = -(-tau_max).exp_m1(); // 1 − e^{−τ_max}, 1 for τ_max = ∞
    let floor = (c_ext / (PI * fill_max)).sqrt();
    let reach = (query_radius + radius).max(floor);
    let fill = (c_ext / (PI * reach * reach)).min(1.0);
    let tau = if fill >= 1.0 {
        TAU_OPAQUE
    } else {
        (-(-fill).ln_1p()).min(TAU_OPAQUE)
    };
    (reach, tau)
}

/// Discrete grains from which compact storage keeps them by their centres' cells (8 bytes each,
/// `crate::space::grid`) rather than in overlap slots (~2.5 slots of 12 bytes, a walk up to twice as
/// fast on sparse grains: BENCHMARKS.md section 24, "Centre cells"). Below it the slots total at most
/// ~2.5 MB and the medium's fixed costs (its class table, up to 16 × 1024 classes of 17 bytes, and its
/// cells) dominate its bytes per particle whatever the layout; from it up, at most 16 bytes a grain.
/// `MOTES_CENTRE_CELLS=1` or `=0` forces one layout (scripts/bench/bench_quantise.py's comparison).
const CENTRE_CELLS_FROM: usize = 1 << 16;

/// Whether compact storage keeps `discrete` grains by their centres' cells ([`CENTRE_CELLS_FROM`]).
fn centre_cells_for(discrete: usize) -> bool {
    match std::env::var("MOTES_CENTRE_CELLS").as_deref() {
        Ok("1") => true,
        Ok("0") => false,
        _ => discrete >= CENTRE_CELLS_FROM,
    }
}

/// The coincidence window (sites closer than this along a ray are one site) and the box outside
/// which no ray can start at an event, for particles at `positions` with disks up to `reach_max`.
fn event_geometry(positions: &[[f64; 3]], reach_max: f64) -> (f64, Bounds3) {
    let (lo, hi) = bounding_box(positions);
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max) + reach_max;
    // Float32 positions carry ~6e-8 relative error: projections closer than 1e-6 of the extent cannot
    // be ordered reliably, so they form one site.
    let coincide = 1e-6 * extent.max(1e-30);
    // Grown by the largest disk, a relative margin for f32 positions, and the coincidence window.
    let grow = reach_max * 1.001 + 1e-6 * extent + coincide;
    let event_box = Bounds3 {
        lo: lo.map(|x| x - grow),
        hi: hi.map(|x| x + grow),
    };
    (coincide, event_box)
}

/// Per-lane result of [`DiscreteMedium::sample_sites`].
#[derive(Clone, Copy, Debug)]
pub struct SiteSample {
    /// Distance to the site, or None when the ray leaves [0, t_max) without interacting.
    pub t: Option<f64>,
    /// Optical depth walked before the site (or to t_max).
    pub tau_before: f64,
}

/// A lane of a phase-function sample: the event's position `p`, the incident direction `wi`
/// (pointing back along the path, Mitsuba's convention), `u1` (picks channel, particle and table)
/// and `u2` (the direction), uniform in [0, 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseSampleLane {
    pub p: [f32; 3],
    pub wi: [f32; 3],
    pub u1: f64,
    pub u2: [f64; 2],
}

/// A lane of a phase-function evaluation: the event's position `p`, the incident direction `wi`
/// (pointing back along the path) and the outgoing direction `wo`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseEvalLane {
    pub p: [f32; 3],
    pub wi: [f32; 3],
    pub wo: [f32; 3],
}

impl DiscreteMedium {
    /// `positions` in scene units, `radius` in scene units once multiplied by `radius_scale` (a caller
    /// with radii in µm passes them with the scale instead of a scaled copy: 800 MB at 10^8 particles),
    /// `c_ext` the grey extinction cross section per particle
    /// (scene units²), `bin` each particle's index into `bins`, `lambda` the tabulated wavelengths
    /// (increasing), `query_radius` r_c (scene units), `tau_max` the cap on each disk's optical depth
    /// (module docs; [`DEFAULT_TAU_MAX`], `f64::INFINITY` for none).
    /// `continuous_count`: size classes holding at least this many particles per query cylinder are
    /// sampled as a continuous medium ([`crate::render::continuous`]; `f64::INFINITY`: none).
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        positions: &[[f64; 3]],
        radius: &[f64],
        radius_scale: f64,
        c_ext: Column,
        bin: &[u32],
        bins: Vec<BinOptics>,
        lambda: Vec<f64>,
        query_radius: f64,
        tau_max: f64,
        cells_per_particle: f64,
        continuous_count: f64,
        seed: u64,
        storage: Storage,
    ) -> Result<Self, OpticsError> {
        check_build_inputs(
            positions,
            radius,
            radius_scale,
            c_ext,
            bin,
            &bins,
            &lambda,
            query_radius,
            tau_max,
            cells_per_particle,
            continuous_count,
        )?;
        let n = positions.len();
        // Compact storage: each particle becomes its class (a bin and a radius level), and everything
        // below sees the class's radius and cross section (crate::render::storage).
        // Full storage keeps every particle's cross section: its table is per particle.
        let radius_at = |i: usize| radius[i] * radius_scale;
        let (c_full, r_full): (Vec<f64>, Vec<f64>) = match storage {
            Storage::Full => (
                (0..n).into_par_iter().map(c_ext).collect(),
                (0..n).into_par_iter().map(radius_at).collect(),
            ),
            Storage::Compact => (Vec::new(), Vec::new()),
        };
        let classes = match storage {
            Storage::Compact => Some(classes(&radius_at, c_ext, bin, bins.len())?),
            Storage::Full => None,
        };
        let (t_radius, t_c): (&[f64], &[f64]) = match &classes {
            Some(c) => (&c.radius, &c.c_ext),
            None => (&r_full, &c_full[..]),
        };
        let table_disks: Vec<(f64, f64)> = t_radius
            .par_iter()
            .zip(t_c)
            .map(|(&r, &c)| {
                if r > 0.0 {
                    particle_disk(r, c, query_radius, tau_max)
                } else {
                    (0.0, 0.0)
                }
            })
            .collect();
        let code_of = |i: usize| classes.as_ref().map_or(i, |c| c.codes[i] as usize);
        // Per-particle values as functions of the particle through the table, not columns (at 10^8
        // particles every f64 column is 800 MB): the grid takes columns of its discrete particles only.
        let reach = |i: usize| table_disks[code_of(i)].0;
        let p_c = |i: usize| t_c[code_of(i)];
        let widened = (0..n)
            .into_par_iter()
            .filter(|&i| {
                let k = code_of(i);
                table_disks[k].0 > query_radius + t_radius[k]
            })
            .count();
        // The grid reaches r_c + radius and spreads c / (π reach²): the widened disks (R, τ) are handed
        // to it as radii R − r_c (at least r) and cross sections τ π R², so that it walks exactly them.
        let grid_radius = |i: usize| {
            let k = code_of(i);
            (table_disks[k].0 - query_radius).max(t_radius[k])
        };
        let grid_c = |i: usize| {
            let (r, tau) = table_disks[code_of(i)];
            tau * PI * r * r
        };
        let (grid, field, keep, footprint, order) = build_walk(
            positions,
            &reach,
            &grid_radius,
            &grid_c,
            &p_c,
            // MOTES_QUANTISE=0 keeps spheres (scripts/bench/bench_quantise.py's comparison); centre
            // cells from CENTRE_CELLS_FROM discrete grains (`build_walk`).
            &GridSettings::new(query_radius, cells_per_particle)
                .quantised(storage == Storage::Compact && env_flag("MOTES_QUANTISE"))
                .centred(storage == Storage::Compact)
                .by_free_path(true),
            continuous_count,
            classes.as_ref().map(|c| &c.codes[..]),
        );
        let reach_max = (0..n).into_par_iter().map(reach).reduce(|| 0.0, f64::max);
        // Every particle's continuous equivalent, for rays past the grain depth (weighted by C_t,i as
        // the continuous classes are); none when the medium must stay exact. When every particle is
        // already in the continuous field, the field is that equivalent (built once: see
        // `grains_field_from`).
        let all_continuous = grid.is_none();
        let grains_field = (continuous_count.is_finite() && !all_continuous).then(|| {
            ContinuousField::build(
                positions,
                &reach,
                &p_c,
                None,
                classes.as_ref().map(|c| &c.codes[..]),
            )
        });
        // An interaction in a field reads only its particle's optics bin: picks by bin (compact storage).
        let (field, grains_field) = match &classes {
            Some(c) => {
                let by_bin =
                    |f: ContinuousField| f.picking_by(|k| c.bin[(k & !CLASS_FLAG) as usize]);
                // The grains' equivalent is only ever picked from: its table is enough.
                let forget = |f: ContinuousField| by_bin(f).forget_members();
                (field.map(by_bin), grains_field.map(forget))
            }
            None => (field, grains_field),
        };
        let (table_c, table_bin, in_field) = match classes {
            Some(c) => {
                let mut in_field = vec![false; c.radius.len()];
                for (i, &k) in c.codes.iter().enumerate() {
                    in_field[k as usize] = !keep[i];
                }
                // The grid's particles by position (`build_walk`): the continuous ones are named by
                // class in their field, so only the grid's keep a code.
                let codes = match order {
                    Some(order) => order.par_iter().map(|&i| c.codes[i as usize]).collect(),
                    None => c.codes,
                };
                (c.c_ext, c.bin, Some((in_field, codes)))
            }
            None => (c_full, bin.to_vec(), None),
        };
        let optics = match in_field {
            Some((in_field, codes)) => {
                ParticleOptics::new(&table_disks, &table_c, table_bin, in_field, Some(codes), n)
            }
            None => ParticleOptics::new(
                &table_disks,
                &table_c,
                table_bin,
                keep.iter().map(|k| !k).collect(),
                None,
                n,
            ),
        };
        let (coincide, event_box) = event_geometry(positions, reach_max);
        Ok(Self::assemble(
            Walkable {
                grid: grid.map(Grains::Stored),
                expected: None,
                field,
                // The surface rule chooses between the grains and their equivalent: both must exist.
                footprint: footprint.filter(|_| grains_field.is_some()),
                grains_field,
                optics,
                widened,
                coincide,
                event_box,
            },
            bins,
            lambda,
            seed,
        ))
    }

    /// The medium over what its free flights walk, with fresh per-render state.
    fn assemble(w: Walkable, bins: Vec<BinOptics>, lambda: Vec<f64>, seed: u64) -> Self {
        DiscreteMedium {
            grid: w.grid,
            expected: w.expected,
            field: w.field,
            grains_field: w.grains_field,
            footprint: w.footprint,
            view: RwLock::new(Arc::new(View::default())),
            view_epoch: AtomicU64::new(0),
            enclosure: RwLock::new(Arc::new(Enclosure::default())),
            surface_footprint: std::sync::atomic::AtomicBool::new(true),
            surface_counts: ShardedCounts::default(),
            optics: w.optics,
            widened: w.widened,
            coincide: w.coincide,
            event_box: w.event_box,
            beams: env_flag("MOTES_BEAM"),
            shared_nodes: bins
                .iter()
                .map(|b| b.phase.iter().all(|t| t.same_nodes(&b.phase[0])))
                .collect(),
            bins,
            lambda,
            events: RwLock::new(EventMap::new(EVENTS_PER_GENERATION)),
            pending: Mutex::new(FxHashMap::default()),
            seed,
            calls: AtomicU64::new(0),
            id: MEDIUM_IDS.fetch_add(1, Ordering::Relaxed),
            packet_counts: ShardedCounts::default(),
            albedo_scale: AtomicU64::new(1f64.to_bits()),
            events_anywhere: std::sync::atomic::AtomicBool::new(false),
            optics_epoch: AtomicU64::new(0),
            grain_depth: std::sync::atomic::AtomicU32::new(DEFAULT_GRAIN_DEPTH),
        }
    }

    /// A procedural cloud (`crate::render::procedural`): nothing stored but the class table, the
    /// continuous classes' field and the bricks a render visits (at most `cache_bytes` of them kept).
    /// `spec.q_ext` per bin of `bins`; the other settings as [`Self::build`]'s.
    #[allow(clippy::too_many_arguments)]
    pub fn procedural(
        spec: &ProceduralSpec,
        bins: Vec<BinOptics>,
        lambda: Vec<f64>,
        query_radius: f64,
        tau_max: f64,
        cells_per_particle: f64,
        continuous_count: f64,
        seed: u64,
        cache_bytes: usize,
    ) -> Result<Self, OpticsError> {
        // The settings and optics checked as for stored particles (one stand-in particle).
        check_build_inputs(
            &[[0.0; 3]],
            &[1.0],
            1.0,
            &|_| 1.0,
            &[0],
            &bins,
            &lambda,
            query_radius,
            tau_max,
            cells_per_particle,
            continuous_count,
        )?;
        require_len("q_ext", spec.q_ext.len(), bins.len(), "one per bin")?;
        for &q in &spec.q_ext {
            require("q_ext", q, q.is_finite() && q >= 0.0, "finite and >= 0")?;
        }
        let disk = |r: f64, c: f64| {
            if r > 0.0 {
                particle_disk(r, c, query_radius, tau_max)
            } else {
                (0.0, 0.0)
            }
        };
        let parts = build_parts(
            spec,
            disk,
            query_radius,
            cells_per_particle,
            continuous_count,
            cache_bytes,
        )?;
        let disks: Vec<(f64, f64)> = parts
            .classes
            .iter()
            .map(|c| disk(c.radius, c.c_ext))
            .collect();
        let c_ext: Vec<f64> = parts.classes.iter().map(|c| c.c_ext).collect();
        let bin = parts.classes.iter().map(|c| c.bin).collect();
        let in_field = parts.discrete.iter().map(|d| !d).collect();
        let optics = ParticleOptics::new(&disks, &c_ext, bin, in_field, None, 0);
        let reach_max = parts
            .discrete
            .iter()
            .zip(&disks)
            .filter(|(d, _)| **d)
            .map(|(_, k)| k.0)
            .fold(0.0, f64::max);
        let widened = 0;
        // Grains drifted by turbulence may sit outside the box at rest by up to the drift's bound.
        let drift = spec.motion.as_ref().map_or(0.0, |(m, _)| m.drift_bound());
        let (coincide, event_box) = event_geometry(&parts.corners, reach_max + drift);
        let footprint = (continuous_count.is_finite() && parts.grains.is_some())
            .then(|| procedural_footprint(spec.count, &parts, &disks, continuous_count))
            .flatten();
        let grid = parts.grains.map(|g| Grains::Procedural(Box::new(g)));
        let exact = !continuous_count.is_finite();
        let all_continuous = grid.is_none();
        Ok(Self::assemble(
            Walkable {
                expected: Some((spec.count, parts.field_count)),
                field: parts.field,
                footprint,
                // Every class continuous: the field is the grains' equivalent (as `build` does).
                grains_field: (!exact && !all_continuous).then_some(parts.all_field),
                grid,
                optics,
                widened,
                coincide,
                event_box,
            },
            bins,
            lambda,
            seed,
        ))
    }

    /// Particles whose disk the τ_max floor widened beyond r_c + r_i.
    pub fn widened(&self) -> usize {
        self.widened
    }
    /// Largest optical depth of a particle's disk.
    pub fn tau_max(&self) -> f64 {
        self.optics.tau.iter().fold(0.0f32, |a, &b| a.max(b)) as f64
    }

    /// Largest inclusion radius of a particle (scene units).
    pub fn reach_max(&self) -> f64 {
        self.optics.reach.iter().fold(0.0f32, |a, &b| a.max(b)) as f64
    }
    /// Particles sampled as a continuous medium ([`crate::render::continuous`]).
    pub fn continuous_len(&self) -> usize {
        match self.expected {
            Some((_, c)) => c.round() as usize,
            None => self.field.as_ref().map_or(0, ContinuousField::len),
        }
    }
    /// Grey optical depth along a ray segment (|d| = 1) as the free flights see it: the discrete
    /// particles' staircase plus the continuous field's mean.
    pub fn optical_depth(&self, ray: &RaySegment) -> f64 {
        self.grid.as_ref().map_or(0.0, |g| g.optical_depth(ray))
            + self.field.as_ref().map_or(0.0, |f| f.optical_depth(ray))
    }
    /// Particles (a procedural cloud's expected count).
    pub fn len(&self) -> usize {
        match self.expected {
            Some((n, _)) => n.round() as usize,
            None => self.optics.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Is this a procedural cloud (`crate::render::procedural`)?
    pub fn is_procedural(&self) -> bool {
        matches!(self.grid, Some(Grains::Procedural(_))) || self.expected.is_some()
    }
    /// A procedural cloud's bricks built so far (0 for stored particles).
    pub fn bricks_built(&self) -> u64 {
        match &self.grid {
            Some(Grains::Procedural(p)) => p.bricks_built(),
            _ => 0,
        }
    }
    pub fn bytes(&self) -> usize {
        self.grid.as_ref().map_or(0, Grains::bytes)
            + self.field.as_ref().map_or(0, ContinuousField::bytes)
            + self.grains_field.as_ref().map_or(0, ContinuousField::bytes)
            + self.optics.bytes()
    }
    pub fn lambda(&self) -> &[f64] {
        &self.lambda
    }

    /// The [`Self::bracket`] of each wavelength of `lam`.
    fn brackets(&self, lam: &[f64]) -> PerChannel<(usize, usize, f64)> {
        PerChannel::from_fn(lam.len(), |c| self.bracket(lam[c]))
    }

    /// [`Self::brackets`] of the wavelengths a packet's lanes share, kept in the thread's packet state
    /// for the last wavelengths asked (an RGB render asks for the same three in every call: their
    /// searches were 1.5 % of a dense render; a thread-local of its own cost a TLS lookup per call, 5 %
    /// of a scalar_rgb render's samples in `PacketWaves::new`).
    fn brackets_cached(
        &self,
        lam: &[f64],
        last: &mut LastBrackets,
    ) -> PerChannel<(usize, usize, f64)> {
        if lam.len() > MAX_CHANNELS {
            return self.brackets(lam);
        }
        let mut bits = [0u64; MAX_CHANNELS];
        bits.iter_mut().zip(lam).for_each(|(b, l)| *b = l.to_bits());
        if let Some((k, n, ls)) = last {
            if *k == bits && *n == lam.len() {
                return PerChannel::Inline(*ls, lam.len());
            }
        }
        let ls = self.brackets(lam);
        let mut flat = [(0, 0, 0.0); MAX_CHANNELS];
        flat.iter_mut().zip(ls.iter()).for_each(|(f, l)| *f = *l);
        *last = Some((bits, lam.len(), flat));
        ls
    }

    /// Interpolation of the tables at wavelength `l`: (lower index, upper index, weight of the upper);
    /// clamped to the tabulated range.
    fn bracket(&self, l: f64) -> (usize, usize, f64) {
        let k = self.lambda.partition_point(|&x| x <= l);
        if k == 0 {
            (0, 0, 0.0)
        } else if k >= self.lambda.len() {
            let m = self.lambda.len() - 1;
            (m, m, 0.0)
        } else {
            let (a, b) = (self.lambda[k - 1], self.lambda[k]);
            (k - 1, k, (l - a) / (b - a))
        }
    }

    fn albedo_at(&self, particle: u32, l: (usize, usize, f64)) -> f64 {
        bin_albedo(&self.bins[self.optics.bin(particle)], l) * self.albedo_scale()
    }

    /// The factor on every particle's albedo (1 unless set).
    pub fn albedo_scale(&self) -> f64 {
        f64::from_bits(self.albedo_scale.load(Ordering::Relaxed))
    }

    /// Scale every particle's albedo by `scale` from the next query on (between renders; a render in
    /// flight may see either value). `scale` × the largest albedo must stay within [0, 1]. Events
    /// remembered so far (they carry the old albedo in their throughputs) are forgotten.
    pub fn set_albedo_scale(&self, scale: f64) -> Result<(), OpticsError> {
        let a_max = self
            .bins
            .iter()
            .flat_map(|b| b.albedo.iter().copied())
            .fold(0.0, f64::max);
        require(
            "albedo_scale",
            scale,
            scale.is_finite() && scale >= 0.0 && scale * a_max <= 1.0 + 1e-12,
            "finite, >= 0 and at most 1 / (the largest particle albedo)",
        )?;
        if scale != self.albedo_scale() {
            self.albedo_scale.store(scale.to_bits(), Ordering::Relaxed);
            // Remembered events carry throughputs of the old albedo.
            self.optics_epoch.fetch_add(1, Ordering::Relaxed);
            self.events.write().unwrap().clear();
        }
        Ok(())
    }

    fn phase_at(&self, particle: u32, l: (usize, usize, f64), mu: f64) -> f64 {
        bin_phase(&self.bins[self.optics.bin(particle)], l, mu)
    }

    /// Sample the next site along each ray (origin `o`, direction `d`, on (0, t_max)), skipping the
    /// particles of the event the ray starts at. The sites are kept for [`Self::commit_events`], which
    /// remembers the events of the lanes marked in `remember` (those whose events start new rays; an
    /// event ends a shadow ray, so shadow rays need not be remembered).
    pub fn sample_sites(
        &self,
        o: &[[f32; 3]],
        d: &[[f32; 3]],
        t_max: &[f64],
        remember: &[bool],
    ) -> Vec<SiteSample> {
        let call = self.calls.fetch_add(1, Ordering::Relaxed);
        let events = self.events.read().unwrap();
        let view = Arc::clone(&self.view.read().unwrap());
        let res: Vec<(Option<Site>, f64, Parent)> = o
            .par_iter()
            .zip(d.par_iter().zip(t_max.par_iter()))
            .enumerate()
            .map(|(lane, (oo, (dd, &tm)))| {
                // Counter and ray bits: distinct for every lane and call (and for concurrent callers).
                let u = uniform(self.seed ^ ray_bits(oo, dd), call, lane as u64);
                let mut surface = SurfaceTally::default();
                let plan =
                    self.lane_plan(&*events, &view, &mut surface, *oo, *dd, tm, u, true, None);
                let r = self.fly(plan, true);
                if surface.checked > 0 {
                    self.surface_counts.add(surface.checked, surface.saw_field);
                }
                r
            })
            .collect();
        drop(events);
        let out = res
            .iter()
            .map(|(s, tau, _)| SiteSample {
                t: s.map(|s| s.t),
                tau_before: *tau,
            })
            .collect();
        let pending = res
            .into_iter()
            .zip(remember)
            .map(|(r, &keep)| (r.0, keep, r.2))
            .collect();
        self.pending
            .lock()
            .unwrap()
            .insert(std::thread::current().id(), pending);
        out
    }

    /// A ray's free flight from its plan (`Self::lane_plan`), its walk through the grains (if any)
    /// alone: its site, the optical depth walked before it and what it takes from its parent event.
    fn fly(&self, plan: Plan, want_tau: bool) -> (Option<Site>, f64, Parent) {
        match plan {
            Plan::Done(site, tau, from) => (site, tau, from),
            Plan::Walk(w) => self.finish_walk(&w, self.walk_alone(&w), want_tau),
            Plan::Deferred(_) => unreachable!("a plan is deferred only into a caller's FieldLanes"),
        }
    }

    /// One ray's walk through the grains (skipping the particles of the event it starts at).
    fn walk_alone(&self, w: &GrainWalk) -> (Option<Site>, f64) {
        match &self.grid {
            Some(g) => g.sample_site(&w.grains(), &w.parent, w.u, self.coincide),
            None => (None, 0.0),
        }
    }

    /// What a ray's free flight (to its next site, skipping the particles of the event it starts at;
    /// `u` uniform in [0, 1)) takes: the answer where no grain needs walking (no ray, the grains'
    /// continuous equivalent), or else the walk through the grains still to do (module docs).
    /// `defer`: a flight through the continuous equivalent alone is queued as lane `i` of the caller's
    /// field lanes where the field steps a packet's flights together ([`Plan::Deferred`]; never with
    /// `want_tau`). Queued in place: through the returned plan the ray was copied twice.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn lane_plan(
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
            .grains_field_from(parent)
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
    fn finish_walk(
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
    /// the grains: `parent` is the `grain_depth`-th event of its path or a later one (module docs).
    fn grains_field_from(&self, parent: &Event) -> Option<&ContinuousField> {
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

    /// The continuous equivalent of all particles when a ray that starts at no event (a surface, a
    /// boundary, a camera) carries a pixel footprint that holds many grains (an effective count over the
    /// discrete classes, `crate::render::footprint`; the ray from `o` along the unit `d` on
    /// [0, `t_max`)): None for camera rays, without cameras, or with the rule off.
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

    /// Rays that started at no event and were checked against the surface-ray rule, and those of them
    /// that saw the grains' continuous equivalent (statistics; `crate::render::footprint`).
    pub fn surface_counts(&self) -> (u64, u64) {
        self.surface_counts.totals()
    }

    /// The cameras whose pixel footprints rays from surfaces carry, and the lights their shadow rays
    /// converge to (`crate::render::footprint`); no camera makes every ray from a surface walk the
    /// grains. Set by the renderer from its scene.
    pub fn set_view(&self, view: View) {
        *self.view.write().unwrap() = Arc::new(view);
        self.view_epoch.fetch_add(1, Ordering::Release);
    }

    /// The convex regions that hold the medium and inside which no surface lets a shadow ray through
    /// (`crate::render::enclosure`): the packet path then answers a phase evaluation towards the
    /// direction of the lane's last free flight, from its origin, with zero where that flight ended at a
    /// site inside the region that holds its origin (the ray is blocked, and Mitsuba's `volpath` and
    /// `volpathmis` multiply that evaluation by the light they then do not see). Set by the renderer
    /// only for those integrators; empty (the default): every evaluation is computed.
    pub fn set_enclosure(&self, enclosure: Enclosure) {
        *self.enclosure.write().unwrap() = Arc::new(enclosure);
        self.view_epoch.fetch_add(1, Ordering::Release);
    }

    /// What [`Self::set_enclosure`] set.
    pub fn enclosure(&self) -> Enclosure {
        Enclosure::clone(&self.enclosure.read().unwrap())
    }

    /// What [`Self::set_view`] set.
    pub fn view(&self) -> View {
        View::clone(&self.view.read().unwrap())
    }

    /// Whether rays from surfaces may see the grains' continuous equivalent where their pixel footprint
    /// holds many grains (`crate::render::footprint`; on by default, and moot when the medium is
    /// exact: infinite `continuous_count`).
    pub fn set_surface_footprint(&self, on: bool) {
        self.surface_footprint.store(on, Ordering::Relaxed);
    }

    /// See [`Self::set_surface_footprint`].
    pub fn surface_footprint(&self) -> bool {
        self.surface_footprint.load(Ordering::Relaxed)
    }

    /// Rays leaving the `depth`-th scattering event of a path or a later one see the continuous
    /// equivalent of the grains (the same mean extinction and local phase mixture per cell) instead of
    /// walking them one by one: 1 sees grains only until a path first scatters (Müller et al. 2016),
    /// `u32::MAX` always (exact). Ignored when every class is kept discrete (`continuous_count`
    /// infinite): then the medium is exact whatever this says.
    pub fn set_grain_depth(&self, depth: u32) -> Result<(), OpticsError> {
        require("grain_depth", depth as f64, depth >= 1, ">= 1")?;
        self.grain_depth.store(depth, Ordering::Relaxed);
        Ok(())
    }

    /// See [`Self::set_grain_depth`].
    pub fn grain_depth(&self) -> u32 {
        self.grain_depth.load(Ordering::Relaxed)
    }

    /// Record the events of this thread's last [`Self::sample_sites`] call at the positions the renderer placed
    /// them (`p`, one per lane of that call; `active` false for lanes without an event) and return each
    /// lane's albedo at its channel wavelengths (`lambda`: `channels` per lane, or `channels` shared).
    pub fn commit_events(
        &self,
        p: &[[f32; 3]],
        active: &[bool],
        lambda: &[f64],
        channels: usize,
    ) -> Result<Vec<f64>, OpticsError> {
        let pending = self
            .pending
            .lock()
            .unwrap()
            .remove(&std::thread::current().id())
            .unwrap_or_default();
        let n = p.len();
        require(
            "lanes (must equal the last sample_sites call)",
            n as f64,
            pending.len() == n && active.len() == n,
            "the same lane count",
        )?;
        require(
            "lambda (length)",
            lambda.len() as f64,
            lambda.len() == channels || lambda.len() == n * channels,
            "channels or lanes × channels",
        )?;
        let albedo: Vec<f64> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let site = if active[i] { pending[i].0 } else { None };
                let lam = lane_wavelengths(lambda, channels, i);
                (0..channels)
                    .map(move |c| site.map_or(0.0, |s| self.site_albedo(&s, self.bracket(lam[c]))))
            })
            .collect();
        let mut events = self.events.write().unwrap();
        events.capacity = events.capacity.max(4 * n);
        for i in 0..n {
            if let (true, (Some(site), true, parent)) = (active[i], pending[i]) {
                events.insert(
                    key(p[i]),
                    event_after(
                        site,
                        &parent,
                        &albedo[i * channels..(i + 1) * channels],
                        lane_wavelengths(lambda, channels, i),
                    ),
                );
            }
        }
        Ok(albedo)
    }

    /// `v` (one value per channel of `lam`, brackets `ls`) times the event's albedo: the one remembered
    /// with it where it was remembered at these wavelengths, else the site's.
    fn times_albedo(&self, e: &Event, lam: &[f64], ls: &[(usize, usize, f64)], v: &mut [f64]) {
        let known =
            lam.len() <= MAX_CHANNELS && lam.first().map(|&l| l as f32) == Some(e.albedo_nm);
        for (c, x) in v.iter_mut().enumerate() {
            *x *= if known {
                e.albedo[c] as f64
            } else {
                self.site_albedo(&e.site, ls[c])
            };
        }
    }

    /// τ-weighted albedo of a site at one wavelength.
    fn site_albedo(&self, s: &Site, l: (usize, usize, f64)) -> f64 {
        if let [j] = s.members() {
            // One particle (most sites): its own albedo, no weights to divide out.
            return self.albedo_at(*j, l);
        }
        let (mut num, mut den) = (0.0, 0.0);
        for &j in s.members() {
            let t = self.optics.tau(j);
            num += t * self.albedo_at(j, l);
            den += t;
        }
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    }

    /// The site at `p` found from the geometry when the event is not remembered: the particles whose
    /// projection on the ray through `p` along `w_in` lies within a few float32 ulps of `p`.
    fn site_near(&self, p: [f32; 3], w_in: [f64; 3]) -> Option<Site> {
        let o = p.map(|x| x as f64);
        let tol = 4.0 * self.coincide + 1e-6 * o.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        let mut site = Site::default();
        if let Some(g) = &self.grid {
            g.walk(&RaySegment::new(o, w_in, -tol, tol), |t, i, key| {
                if site.len == 0 {
                    site.t = t;
                }
                if (site.len as usize) < Site::CAPACITY {
                    site.keys[site.len as usize] = key;
                }
                site.push(i);
                true
            });
        }
        // An interaction in the continuous field is at no particle's projection: its cell's particles
        // (up to the site's capacity) stand in for the one picked there.
        if let (0, Some(f)) = (site.len, &self.field) {
            if let Some(c) = f.cell_at(o) {
                f.members(c).for_each(|i| site.push(i));
            }
        }
        (site.len > 0).then_some(site)
    }

    /// The site of an event position, if it is remembered.
    pub fn event_at(&self, p: [f32; 3]) -> Option<Site> {
        self.events.read().unwrap().get(&key(p)).map(|e| e.site)
    }

    /// Phase function of a mixture of particles per channel at μ = cos θ, and the pdf Σ_c π_c f_c of
    /// sampling it (module docs; see [`Mixture`]).
    fn mixture_phase(&self, m: &Mixture<impl Fn(u32) -> f64>, mu: f64, values: &mut [f64]) -> f64 {
        self.mixture_phase_at(m, mu, None, values)
    }

    /// [`Self::mixture_phase`] with μ's location in the tables of the one particle's bin where the
    /// caller knows it (`at`: a sample from one of them, [`PhaseTable::sample_located`]).
    fn mixture_phase_at(
        &self,
        m: &Mixture<impl Fn(u32) -> f64>,
        mu: f64,
        at: Option<(usize, f64)>,
        values: &mut [f64],
    ) -> f64 {
        let mut pdf = 0.0;
        if let [j] = m.members {
            // One particle (most events): its own phase function in every channel where it scatters,
            // its bin looked up once (the weights below cancel: 5 % of a dense render), μ located
            // once for all its tables where they share their nodes (or not at all where a sample from
            // them told where it lies).
            let bin = self.optics.bin(*j);
            let (b, w) = (&self.bins[bin], (m.scale)(*j) * self.albedo_scale());
            let at = self.shared_nodes[bin].then(|| at.unwrap_or_else(|| b.phase[0].locate(mu)));
            for (c, &l) in m.ls.iter().enumerate() {
                values[c] = match (w * bin_albedo(b, l) > 0.0, at) {
                    (false, _) => 0.0,
                    (true, Some(at)) => bin_phase_at(b, l, at),
                    (true, None) => bin_phase(b, l, mu),
                };
                pdf += m.pi[c] * values[c];
            }
            return pdf;
        }
        for (c, &l) in m.ls.iter().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for &j in m.members {
                let w = (m.scale)(j) * self.albedo_at(j, l);
                num += w * self.phase_at(j, l, mu);
                den += w;
            }
            values[c] = if den > 0.0 { num / den } else { 0.0 };
            pdf += m.pi[c] * values[c];
        }
        pdf
    }

    /// Sample a mixture (see [`Self::mixture_phase`]) around the propagation direction `w_in`: a channel
    /// with probability π_c, then a particle by its weight in that channel, then its table (lower/upper
    /// wavelength), each by rescaling `u1`; `u2` draws the direction. Returns (wo, weight per
    /// channel = value / pdf, pdf), or the null sample.
    fn mixture_sample(
        &self,
        m: &Mixture<impl Fn(u32) -> f64>,
        w_in: [f64; 3],
        u1: f64,
        u2: [f64; 2],
    ) -> Sample {
        let Mixture {
            members,
            scale,
            ls,
            pi,
        } = m;
        let mut u = u1.clamp(0.0, 1.0 - f64::EPSILON);
        let mut c = ls.len() - 1;
        let mut acc = 0.0;
        for (k, &p) in pi.iter().enumerate().take(ls.len()) {
            if u < acc + p && p > 0.0 {
                c = k;
                u = ((u - acc) / p).clamp(0.0, 1.0 - f64::EPSILON);
                break;
            }
            acc += p;
        }
        let l = ls[c];
        // Weights computed twice (the total, then the pick) rather than stored: no allocation per sample.
        let weight = |j: u32| scale(j) * self.albedo_at(j, l);
        let j = if let [j] = members {
            // One particle: no pick (u is left as it is).
            if !(weight(*j) > 0.0) {
                return null_sample(ls.len());
            }
            *j
        } else {
            let total: f64 = members.iter().map(|&j| weight(j)).sum();
            if !(total > 0.0) {
                return null_sample(ls.len());
            }
            let mut pick = members.len() - 1;
            let mut acc = 0.0;
            for (k, w) in members.iter().map(|&j| weight(j)).enumerate() {
                if u * total < acc + w {
                    pick = k;
                    u = ((u * total - acc) / w).clamp(0.0, 1.0 - f64::EPSILON);
                    break;
                }
                acc += w;
            }
            members[pick]
        };
        let table = if u < 1.0 - l.2 { l.0 } else { l.1 };
        let (mu, at) = self.bins[self.optics.bin(j)].phase[table].sample_located(u2[0]);
        let wo = deflect(w_in, mu, u2[1]);
        let mut v = PerChannel::from_fn(ls.len(), |_| 0.0);
        let pdf = self.mixture_phase_at(m, mu, Some(at), &mut v);
        if pdf > 0.0 {
            let inv = 1.0 / pdf;
            v.iter_mut().for_each(|x| *x *= inv);
            (wo, v, pdf)
        } else {
            null_sample(ls.len())
        }
    }

    /// Local scattering at points (paper Eq. 24 with the per-particle normalisation of the grid): the
    /// particles whose inclusion ball (R_i = r_c + r_i) contains p each add C_s,i / V_i with
    /// V_i = 4/3 π R_i³, so that E[σ_s(p)] is the bulk σ_s. Returns σ_s per channel and
    /// Q_c(μ) = σ_s,c f_c(μ) (1/sr per unit length) at the given μ = cos θ, each `n × channels`.
    pub fn local_scattering(
        &self,
        p: &[[f64; 3]],
        mu: &[f64],
        lambda: &[f64],
        channels: usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let res: Vec<(Vec<f64>, Vec<f64>)> = (0..p.len())
            .into_par_iter()
            .map(|i| {
                let members = self.local_members(p[i]);
                let lam = lane_wavelengths(lambda, channels, i);
                let ls: Vec<_> = lam.iter().map(|&l| self.bracket(l)).collect();
                let scale = |j: u32| self.local_weight(j, p[i]);
                let sigma: Vec<f64> = ls
                    .iter()
                    .map(|&l| {
                        members
                            .iter()
                            .map(|&j| scale(j) * self.albedo_at(j, l))
                            .sum()
                    })
                    .collect();
                let mut f = vec![0.0; channels];
                let mixture = Mixture {
                    members: &members,
                    scale,
                    ls: &ls,
                    pi: &uniform_channels(channels),
                };
                self.mixture_phase(&mixture, mu[i].clamp(-1.0, 1.0), &mut f);
                let q = f.iter().zip(&sigma).map(|(a, b)| a * b).collect();
                (sigma, q)
            })
            .collect();
        let sigma = res.iter().flat_map(|r| r.0.iter().copied()).collect();
        (sigma, res.into_iter().flat_map(|r| r.1).collect())
    }

    /// C_t,i / V_i of particle i (grey), the weight of a particle in the query sphere of Eq. 24 (a
    /// particle of the continuous field is spread over its cell: V_i is the cell's volume).
    fn local_weight(&self, j: u32, p: [f64; 3]) -> f64 {
        // A procedural cloud's field: the σ_t its class carries at p.
        if let (Some(f), true) = (&self.field, self.optics.in_field(j)) {
            if let Some(s) = f.shared_sigma(p, j) {
                return s;
            }
        }
        let r = self.optics.reach(j);
        let volume = match (&self.field, self.optics.in_field(j)) {
            (Some(f), true) => f.cell_volume(),
            _ => 4.0 / 3.0 * PI * r * r * r,
        };
        self.optics.c_ext(j) / volume
    }

    /// The particles local to `p` (Eq. 24's query sphere): those whose ball contains it, and the
    /// continuous field's particles of its cell.
    fn local_members(&self, p: [f64; 3]) -> Vec<u32> {
        let mut m = self
            .grid
            .as_ref()
            .map_or_else(Vec::new, |g| g.containing(p));
        if let Some(f) = &self.field {
            if let Some(c) = f.cell_at(p) {
                m.extend(f.members(c));
            }
        }
        m
    }

    /// Sample scattered directions from the local mixture at points (see [`Self::local_scattering`]):
    /// a particle with probability ∝ its local scattering weight, then its tabulated phase function.
    /// `w_in` is the propagation direction. Returns (wo, weight per channel = f_c / pdf, pdf); pdf 0
    /// where no particle is local.
    pub fn sample_local(
        &self,
        p: &[[f64; 3]],
        w_in: &[[f64; 3]],
        lambda: &[f64],
        channels: usize,
        u1: &[f64],
        u2: &[[f64; 2]],
    ) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
        let res: Vec<Sample> = (0..p.len())
            .into_par_iter()
            .map(|i| {
                let members = self.local_members(p[i]);
                let Some(dir) = normalise(w_in[i]) else {
                    return null_sample(channels);
                };
                let lam = lane_wavelengths(lambda, channels, i);
                let ls: Vec<_> = lam.iter().map(|&l| self.bracket(l)).collect();
                let mixture = Mixture {
                    members: &members,
                    scale: |j| self.local_weight(j, p[i]),
                    ls: &ls,
                    pi: &uniform_channels(channels),
                };
                self.mixture_sample(&mixture, dir, u1[i], u2[i])
            })
            .collect();
        unzip_samples(res)
    }

    /// Evaluate the phase function of the event at each lane's `p` for its incident and outgoing
    /// directions: per-channel values (1/sr) and the pdf. Positions without a remembered event give 0
    /// and 0.
    pub fn phase_eval(
        &self,
        lanes: &[PhaseEvalLane],
        lambda: &[f64],
        channels: usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let events = self.events.read().unwrap();
        let res: Vec<(Vec<f64>, f64)> = (0..lanes.len())
            .into_par_iter()
            .map(|i| {
                let lam = lane_wavelengths(lambda, channels, i);
                let mut v = vec![0.0; channels];
                let pdf = self.lane_phase_eval(
                    &*events,
                    &lanes[i],
                    lam,
                    &self.brackets(lam),
                    &mut v,
                    false,
                );
                (v, pdf)
            })
            .collect();
        let pdf = res.iter().map(|r| r.1).collect();
        (res.into_iter().flat_map(|r| r.0).collect(), pdf)
    }

    /// One lane of [`Self::phase_eval`]: the values into `v` (one per wavelength of `lam`; times the
    /// event's albedo with `scattered`), the pdf returned.
    #[allow(clippy::too_many_arguments)]
    fn lane_phase_eval(
        &self,
        events: &impl Events,
        lane: &PhaseEvalLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        v: &mut [f64],
        scattered: bool,
    ) -> f64 {
        v.iter_mut().for_each(|x| *x = 0.0);
        let dirs =
            normalise(lane.wi.map(|x| -(x as f64))).zip(normalise(lane.wo.map(|x| x as f64)));
        let Some((w_in, w_out)) = dirs else {
            return 0.0;
        };
        let Some(e) = self.event_or_geometry(events, lane.p, w_in) else {
            return 0.0;
        };
        let mu = (w_in[0] * w_out[0] + w_in[1] * w_out[1] + w_in[2] * w_out[2]).clamp(-1.0, 1.0);
        let pi = event_channels(&e, lam.len());
        let mixture = self.event_mixture(&e, ls, &pi);
        let pdf = self.mixture_phase(&mixture, mu, v);
        if scattered {
            self.times_albedo(&e, lam, ls, v);
        }
        pdf
    }

    /// Sample the phase function of the event at each lane's `p` (module docs): outgoing directions,
    /// weights (value / pdf per channel) and pdfs.
    pub fn phase_sample(
        &self,
        lanes: &[PhaseSampleLane],
        lambda: &[f64],
        channels: usize,
    ) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
        let events = self.events.read().unwrap();
        let res: Vec<(Sample, Option<[f32; MAX_CHANNELS]>)> = (0..lanes.len())
            .into_par_iter()
            .map(|i| {
                let lam = lane_wavelengths(lambda, channels, i);
                self.lane_phase_sample(&*events, &lanes[i], lam, &self.brackets(lam), false)
            })
            .collect();
        drop(events);
        let mut events = self.events.write().unwrap();
        for (lane, (_, t_out)) in lanes.iter().zip(&res) {
            if let (Some(t), Some(e)) = (t_out, events.get_mut(&key(lane.p))) {
                e.t_out = *t;
            }
        }
        drop(events);
        unzip_samples(res.into_iter().map(|r| r.0).collect())
    }

    /// One lane of [`Self::phase_sample`]: the sample (its weights times the event's albedo with
    /// `scattered`) and the path's throughput after it (to store as the event's `t_out`; the albedo is
    /// in its `t_in` already).
    fn lane_phase_sample(
        &self,
        events: &impl Events,
        lane: &PhaseSampleLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        scattered: bool,
    ) -> (Sample, Option<[f32; MAX_CHANNELS]>) {
        match self.sample_event(events, lane) {
            Some((w_in, e)) => self.event_phase_sample(&e, w_in, lane, lam, ls, scattered),
            None => (null_sample(lam.len()), None),
        }
    }

    /// A phase sample's incident direction (the path's, reversed back) and its event (None: no
    /// direction, or no event there).
    fn sample_event<'e>(
        &self,
        events: &'e impl Events,
        lane: &PhaseSampleLane,
    ) -> Option<([f64; 3], std::borrow::Cow<'e, Event>)> {
        let w_in = normalise(lane.wi.map(|x| -(x as f64)))?;
        Some((w_in, self.event_or_geometry(events, lane.p, w_in)?))
    }

    /// [`Self::lane_phase_sample`] at the lane's event `e`, the path arriving along `w_in`.
    fn event_phase_sample(
        &self,
        e: &Event,
        w_in: [f64; 3],
        lane: &PhaseSampleLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        scattered: bool,
    ) -> (Sample, Option<[f32; MAX_CHANNELS]>) {
        let channels = lam.len();
        let pi = event_channels(e, channels);
        let mixture = self.event_mixture(e, ls, &pi);
        let mut sample = self.mixture_sample(&mixture, w_in, lane.u1, lane.u2);
        // The path's throughput after this bounce, t_c f_c / q ∝ t_c × weight_c (module docs).
        let known = e.t_in.iter().any(|&x| x > 0.0);
        let t_out = (channels <= MAX_CHANNELS && sample.2 > 0.0).then(|| {
            normalised_throughput(
                (0..channels).map(|c| if known { e.t_in[c] as f64 } else { 1.0 } * sample.1[c]),
            )
        });
        if scattered {
            self.times_albedo(e, lam, ls, &mut sample.1);
        }
        (sample, t_out)
    }

    /// Slot `k` of `lanes` ([`PhaseLanes`]) for lane `lane`'s sample at its event `e`, where the event
    /// is one particle whose tables share their nodes and the wavelengths `ls` are tabulated ones
    /// (checked by the caller); false where it is not one particle with shared nodes.
    fn fill_phase_lane(
        &self,
        e: &Event,
        lane: &PhaseSampleLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        lanes: &mut PhaseLanes,
        k: usize,
    ) -> bool {
        let [j] = e.site.members() else {
            return false;
        };
        let bin = self.optics.bin(*j);
        if !self.shared_nodes[bin] {
            return false;
        }
        let channels = lam.len();
        let (b, tau, scale) = (&self.bins[bin], self.optics.tau(*j), self.albedo_scale());
        let pi = channel_probabilities(&e.t_in, channels);
        let known = e.t_in.iter().any(|&x| x > 0.0);
        let mut albedo = [1.0; MAX_CHANNELS];
        self.times_albedo(e, lam, ls, &mut albedo[..channels]);
        for c in 0..MAX_CHANNELS {
            let l = ls[c.min(channels - 1)];
            lanes.set_table(c, k, b.phase[l.0].sampling_view());
            if c < channels {
                // As `mixture_sample` (the pick) and `mixture_phase_at` (the values) weigh them.
                let a = bin_albedo(b, l);
                lanes.pi[c][k] = pi[c];
                lanes.pickable[c][k] = (tau * (a * scale) > 0.0) as u64;
                lanes.scatters[c][k] = (tau * scale * a > 0.0) as u64;
                lanes.t_in[c][k] = if known { e.t_in[c] as f64 } else { 1.0 };
                lanes.albedo[c][k] = albedo[c];
            } else {
                lanes.pi[c][k] = 0.0;
                lanes.pickable[c][k] = 0;
                lanes.scatters[c][k] = 0;
            }
        }
        (lanes.u1[k], lanes.u2[k]) = (lane.u1, lane.u2[0]);
        true
    }

    /// The mixture of an event's particles, each weighing its τ (module docs), at the channels'
    /// wavelength brackets `ls`, sampled with channel probabilities `pi`.
    fn event_mixture<'a>(
        &'a self,
        e: &'a Event,
        ls: &'a [(usize, usize, f64)],
        pi: &'a [f64],
    ) -> Mixture<'a, impl Fn(u32) -> f64 + 'a> {
        Mixture {
            members: e.site.members(),
            scale: |j| self.optics.tau(j),
            ls,
            pi,
        }
    }

    /// The remembered event at `p`, or else the site found from the geometry (uniform channels).
    fn event_or_geometry<'e>(
        &self,
        events: &'e impl Events,
        p: [f32; 3],
        w_in: [f64; 3],
    ) -> Option<std::borrow::Cow<'e, Event>> {
        match events.event(&key(p)) {
            Some(e) => Some(std::borrow::Cow::Borrowed(e)),
            None => self.site_near(p, w_in).map(|site| {
                std::borrow::Cow::Owned(Event {
                    site,
                    ..Event::default()
                })
            }),
        }
    }

    /// Remember an event directly (tests and tools: e.g. a chi-square test of a chosen mixture).
    pub fn insert_event(&self, p: [f32; 3], particles: &[u32]) -> Result<(), OpticsError> {
        let mut s = Site::default();
        for &i in particles {
            require(
                "particle",
                i as f64,
                (i as usize) < self.optics.ids(),
                "< number of particles walked one by one (compact storage: by position)",
            )?;
            s.push(i);
        }
        require(
            "particles (count)",
            particles.len() as f64,
            !particles.is_empty(),
            ">= 1",
        )?;
        self.events_anywhere.store(true, Ordering::Relaxed);
        self.events.write().unwrap().insert(
            key(p),
            Event {
                site: s,
                ..Event::default()
            },
        );
        Ok(())
    }
}

/// Lanes of one SIMD packet at most (Dr.Jit's widest LLVM vector; scalar variants use one).
pub const PACKET_LANES: usize = 16;

/// A lane's site of its last free flight in the packet interface, until a call finds the lane there
/// ([`DiscreteMedium::settle`]) or its next free flight replaces it.
#[derive(Clone, Copy, Default)]
struct PendingLane {
    site: Option<Site>,
    parent: Parent,
    /// Where the renderer puts the site ([`site_position`]).
    at: [f32; 3],
}

impl PendingLane {
    /// Whether a call at `p` finds the lane at its pending site (then `DiscreteMedium::settle_in`).
    /// Three calls of four do not (no pending site, or one elsewhere: a shadow ray's): told in the
    /// caller, not in a call (one call for all, with its big frame, was 5 % of a dense render).
    #[inline(always)]
    fn settles_at(&self, p: [f32; 3]) -> bool {
        self.site.is_some() && at_site(p, self.at)
    }

    fn new(site: Option<Site>, parent: Parent) -> Self {
        PendingLane {
            site,
            parent,
            at: [0.0; 3],
        }
    }
}

/// `dst.copy_from_slice(src)` for a lane's channels, a few moves where there are at most
/// [`MAX_CHANNELS`] (`copy_from_slice` of a length known only at run time is a call to `memcpy`, per
/// lane per call).
#[inline(always)]
fn copy_channels(dst: &mut [f64], src: &[f64]) {
    debug_assert_eq!(dst.len(), src.len());
    match dst.len() {
        1 => dst[..1].copy_from_slice(&src[..1]),
        2 => dst[..2].copy_from_slice(&src[..2]),
        3 => dst[..3].copy_from_slice(&src[..3]),
        4 => dst[..4].copy_from_slice(&src[..4]),
        _ => dst.copy_from_slice(src),
    }
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

/// Where the renderer puts a site at distance `t` along a ray: Mitsuba's `Ray3f` evaluates o + t d as
/// a float32 fma of the float32 t it received. Here in f64 (the product is exact, the sum rounds twice:
/// at most an ulp off, which [`at_site`] allows), since f32::mul_add is a libm call in this build.
fn site_position(o: [f32; 3], d: [f32; 3], t: f64) -> [f32; 3] {
    let t = t as f32 as f64;
    [0, 1, 2].map(|a| (d[a] as f64 * t + o[a] as f64) as f32)
}

/// The octahedral map of a unit vector (Cigolle et al. 2014, "A survey of efficient representations
/// for independent unit vectors"): x, y of w / |w|_1, the lower hemisphere folded over the diagonals.
/// How the native plugin's phase samples send a direction in two floats (`rust/motes-py/src/native.rs`;
/// the C++ plugin unfolds it: test `octahedral_directions_survive_float32`).
pub fn octahedral(w: [f64; 3]) -> [f64; 2] {
    let n = w[0].abs() + w[1].abs() + w[2].abs();
    let (x, y) = (w[0] / n, w[1] / n);
    if w[2] >= 0.0 {
        [x, y]
    } else {
        [(1.0 - y.abs()).copysign(x), (1.0 - x.abs()).copysign(y)]
    }
}

/// A lane's wavelengths and their tables' brackets ([`DiscreteMedium::bracket`]).
#[derive(Clone, Copy)]
struct Waves<'a> {
    lam: &'a [f64],
    ls: &'a [(usize, usize, f64)],
}

/// A packet call's wavelengths: `channels` shared by every lane (their brackets found once per call:
/// RGB variants) or `channels` per lane.
struct PacketWaves<'a> {
    m: &'a DiscreteMedium,
    lambda: &'a [f64],
    channels: usize,
    shared: Option<PerChannel<(usize, usize, f64)>>,
}

/// The last shared wavelengths' bits and count, and their brackets ([`DiscreteMedium::brackets_cached`]).
type LastBrackets = Option<(
    [u64; MAX_CHANNELS],
    usize,
    [(usize, usize, f64); MAX_CHANNELS],
)>;

impl<'a> PacketWaves<'a> {
    fn new(
        m: &'a DiscreteMedium,
        lambda: &'a [f64],
        channels: usize,
        last: &mut LastBrackets,
    ) -> Self {
        let shared = (lambda.len() == channels).then(|| m.brackets_cached(lambda, last));
        PacketWaves {
            m,
            lambda,
            channels,
            shared,
        }
    }

    /// Lane `i`'s wavelengths (`.get()` borrows them as [`Waves`]).
    fn lane(&self, i: usize) -> LaneWaves<'_> {
        let lam = lane_wavelengths(self.lambda, self.channels, i);
        LaneWaves {
            lam,
            own: self.shared.is_none().then(|| self.m.brackets(lam)),
            shared: &self.shared,
        }
    }
}

/// One lane's wavelengths from [`PacketWaves::lane`].
struct LaneWaves<'a> {
    lam: &'a [f64],
    own: Option<PerChannel<(usize, usize, f64)>>,
    shared: &'a Option<PerChannel<(usize, usize, f64)>>,
}

impl LaneWaves<'_> {
    fn get(&self) -> Waves<'_> {
        Waves {
            lam: self.lam,
            ls: self
                .own
                .as_deref()
                .or(self.shared.as_deref())
                .expect("brackets, shared or the lane's own"),
        }
    }
}

/// Float32 ulps by which a call's position may differ from a lane's predicted site ([`at_site`]).
const SITE_ULPS: f32 = 4.0;

/// Whether a call's position `p` is a lane's site predicted at `at`: the same bits, or within
/// [`SITE_ULPS`] × |x| ε per axis (4–8 float32 ulps) (Mitsuba's tentative distance is the site's t plus E / majorant,
/// below an ulp unless t is tiny; the prediction may be an ulp off).
fn at_site(p: [f32; 3], at: [f32; 3]) -> bool {
    p == at
        || (0..3).all(|a| {
            let ulp = p[a].abs().max(at[a].abs()) * f32::EPSILON;
            (p[a] - at[a]).abs() <= SITE_ULPS * ulp.max(f32::MIN_POSITIVE)
        })
}

/// Are two directions the same up to single-precision rounding (|a| = |b| = 1 within it)? The
/// shadow ray's direction and the light's direction that Mitsuba evaluates the phase function at are
/// the same difference of positions, normalised alike.
fn same_direction(a: [f32; 3], b: [f32; 3]) -> bool {
    let (a, b) = (a.map(|x| x as f64), b.map(|x| x as f64));
    let c = vec3::cross(a, b);
    // Within 1e-6 rad: single precision rounds a unit vector's direction by ~1e-7.
    vec3::dot(a, b) > 0.0 && vec3::dot(c, c) <= 1e-12 * vec3::dot(a, a) * vec3::dot(b, b)
}

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
struct SampledLane {
    inputs: [[u32; 3]; 3],
    lambda: [u64; MAX_CHANNELS],
    values: [f64; MAX_CHANNELS],
    pdf: f64,
}

impl SampledLane {
    fn inputs(p: [f32; 3], wi: [f32; 3], wo: [f32; 3]) -> [[u32; 3]; 3] {
        [p, wi, wo].map(|v| v.map(f32::to_bits))
    }
    fn lambda(lam: &[f64]) -> [u64; MAX_CHANNELS] {
        let mut out = [u64::MAX; MAX_CHANNELS];
        out.iter_mut().zip(lam).for_each(|(o, l)| *o = l.to_bits());
        out
    }
}

/// One thread's state of the packet interface for one medium: the pending sites of its last packet of
/// free flights, its events, and its lanes' last phase-function samples.
struct PacketState {
    pending: [PendingLane; PACKET_LANES],
    events: EventMap,
    /// Each lane's last committed event ([`LaneEvents`]).
    recent: [Option<([u32; 3], Event)>; PACKET_LANES],
    sampled: [Option<SampledLane>; PACKET_LANES],
    /// Each lane's last free flight (origin, direction, where its site lies) where it ended at a site
    /// (whether that blocks it for certain, [`DiscreteMedium::set_enclosure`], is asked only where an
    /// evaluation towards it follows).
    blocked: [Option<BlockedFlight>; PACKET_LANES],
    /// The medium's `optics_epoch` when these events were made (older ones carry stale albedos).
    epoch: u64,
    /// The medium's view as of its `view_epoch` (u64::MAX: not read yet).
    view: Arc<View>,
    /// The medium's enclosure as of its `view_epoch`.
    enclosure: Arc<Enclosure>,
    view_epoch: u64,
    /// The current packet's lanes that fly through the continuous field together.
    fields: FieldLanes,
    /// The current packet's walks through the grains, and the sites of those walked as a beam (the
    /// lanes that have them: bits in `packet_free_flights`; kept here, not made empty per packet).
    walks: [Option<GrainWalk>; PACKET_LANES],
    found: [(Option<Site>, f64); PACKET_LANES],
    /// The current packet's phase samples at one-particle events, taken side by side (made at the
    /// first such sample: it holds this medium's tables; 4.5 kB, not made afresh per packet).
    phase: Option<Box<PhaseLanes>>,
    /// The brackets of the last wavelengths shared by a packet's lanes.
    brackets: LastBrackets,
    /// The thread's shard of the medium's statistics counters ([`ShardedCounts`]).
    count_shard: usize,
}

impl PacketState {
    /// Lane `i`'s view of the events ([`LaneEvents`]).
    fn lane(&self, i: usize) -> LaneEvents<'_> {
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
    /// The packet interface's per-thread state, by medium id (see "One packet at a time").
    static PACKET_STATE: std::cell::RefCell<FxHashMap<u64, PacketState>> = std::cell::RefCell::new(FxHashMap::default());
}

/// Counter shards: more than the render threads of most machines (threads beyond share shards, still
/// exactly).
const COUNT_SHARDS: usize = 16;

/// One shard of [`ShardedCounts`], alone on its cache lines.
#[derive(Default)]
#[repr(align(128))]
struct CountShard([AtomicU64; 2]);

/// Two statistics counters (rays, interactions) that render threads add to without sharing a cache
/// line. With one shared atomic per counter, `perf` put 3.5 % of the sparse render's samples on its
/// locked adds (the line moving between the cores once per packet); sharded, the render is 0–4 %
/// faster in alternating runs (`scripts/bench/render_seconds.py sparse`), within this machine's noise.
#[derive(Default)]
struct ShardedCounts([CountShard; COUNT_SHARDS]);

thread_local! {
    /// This thread's shard of every [`ShardedCounts`].
    static COUNT_SHARD: usize = next_count_shard();
}
static NEXT_COUNT_SHARD: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// A shard for a new thread (or its packet state).
fn next_count_shard() -> usize {
    NEXT_COUNT_SHARD.fetch_add(1, Ordering::Relaxed) % COUNT_SHARDS
}

impl ShardedCounts {
    fn add(&self, a: u64, b: u64) {
        self.add_to(COUNT_SHARD.with(|s| *s), a, b)
    }
    /// [`Self::add`] to shard `shard` (a packet state's own: no thread-local lookup per packet).
    fn add_to(&self, shard: usize, a: u64, b: u64) {
        let shard = &self.0[shard % COUNT_SHARDS].0;
        shard[0].fetch_add(a, Ordering::Relaxed);
        shard[1].fetch_add(b, Ordering::Relaxed);
    }
    fn totals(&self) -> (u64, u64) {
        let sum = |k: usize| self.0.iter().map(|s| s.0[k].load(Ordering::Relaxed)).sum();
        (sum(0), sum(1))
    }
}

/// Rays checked against the surface-ray rule and those that saw the field, counted per call or packet
/// and added to the medium's [`ShardedCounts`] once.
#[derive(Default)]
struct SurfaceTally {
    checked: u64,
    saw_field: u64,
}

/// Ids of media (never reused, unlike addresses).
static MEDIUM_IDS: AtomicU64 = AtomicU64::new(1);

/// A ray of the packet interface: origin, direction, t_max.
pub type PacketRay = ([f32; 3], [f32; 3], f32);

/// # One packet at a time (the native render path)
/// Mitsuba's symbolic LLVM kernels call native code once per SIMD packet (up to [`PACKET_LANES`] lanes;
/// scalar variants once per ray). A packet runs its paths from start to end on one thread, lane i
/// being one path throughout. So the packet interface keeps its state per thread and medium, without
/// locks: each lane's site of its last free flight waits in a slot, and becomes the lane's event
/// ([`Self::settle`]) when the lane's next call starts there (the path scattered at it: its shadow
/// ray, its phase function, its next free flight); a shadow ray's site is never settled, the next free
/// flight replaces it. Each lane's last event lives beside it ([`LaneEvents`]: a path's events are
/// looked up by its own next rays only); those whose rays walk the grains (skipping the event's
/// particles) are also kept in a per-thread `EventMap`, the record that does not depend on lanes. The renderer needs no
/// call to place an event: every site scatters (σ_s = σ_t there) and the phase function's values and
/// weights carry the site's albedo (`scattered` in [`Self::lane_phase_sample`]), which Mitsuba's
/// volumetric integrators multiply into the path exactly as they would σ_s / σ_t. This contract does not hold in Dr.Jit's evaluated
/// mode, where a wavefront's kernels may run a lane on different threads: there the batch interface
/// ([`Self::sample_sites`] and the rest) is the one to use. Inactive lanes are `None`. The free
/// flight's random number is a hash of the ray and the seed: a render is a function of the scene, the
/// sampler's seed and spp, whatever the thread schedule. A packet holds one pixel's samples (Mitsuba
/// orders a wavefront's lanes pixel by pixel): its rays that start at no event walk the grains as one
/// beam where they make one (`ParticleGrid::sample_sites_beam`; the same sites as one by one).
impl DiscreteMedium {
    /// Rays and interactions (sites found: scattering events and blocked shadow rays) of the packet
    /// interface so far.
    pub fn packet_counts(&self) -> (u64, u64) {
        self.packet_counts.totals()
    }

    /// This thread's packet state for this medium.
    fn with_packet_state<R>(&self, f: impl FnOnce(&mut PacketState) -> R) -> R {
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
    fn settle(&self, st: &mut PacketState, i: usize, p: [f32; 3], waves: &PacketWaves) {
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
    fn settle_in(
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
        // the grains' continuous equivalent skip nothing: the lane's copy is all they need (the insert
        // was 2 % of a dense render).
        if self.grains_field_from(e).is_none() {
            events.insert(*k, *e);
        }
    }

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
            let view = &*st.view;
            // Lanes that walk stored grains from no event: walked together where they make a beam
            // (`ParticleGrid::sample_sites_beam`: a pixel's camera rays, their shadow rays).
            // (Bit i: lane i walks, its walk in the state's `walks[i]`: sixteen empty walks made per
            // call were 3 kB copied from a constant, 0.7 % of a dense render.)
            let mut walking = 0u32;
            let mut beam = [0usize; PACKET_LANES];
            let mut in_beam = 0;
            // Lanes whose flight is through one continuous field alone: flown together after.
            let mut field: Option<&ContinuousField> = None;
            (st.fields.n, st.fields.field) = (0, 0);
            for (i, ray) in rays.iter().enumerate().take(PACKET_LANES) {
                t[i] = None;
                // A lane inactive in this call keeps its site: the lane's path has not moved on.
                let Some((o, d, t_max)) = *ray else { continue };
                let (pending, recent) = (&mut st.pending[i], &mut st.recent[i]);
                if pending.settles_at(o) {
                    self.settle_in(pending, &mut st.events, recent, o, &waves, i);
                }
                // (Every plan below sets the lane's pending site: deferred ones when they fly.)
                let u = uniform(self.seed ^ ray_bits(&o, &d), t_max.to_bits() as u64, 0);
                let events = LaneEvents {
                    recent: &st.recent[i],
                    map: &st.events,
                };
                // A packet of one ray (scalar variants) flies it here: nothing to step together.
                let defer = (n_rays > 1).then_some((&mut st.fields, i));
                match self.lane_plan(
                    &events,
                    view,
                    &mut surface,
                    o,
                    d,
                    t_max as f64,
                    u,
                    false,
                    defer,
                ) {
                    Plan::Done(site, _, parent) => st.pending[i] = PendingLane::new(site, parent),
                    Plan::Walk(w) => {
                        if w.parent.len == 0 && matches!(self.grid, Some(Grains::Stored(_))) {
                            beam[in_beam] = i;
                            in_beam += 1;
                        }
                        st.walks[i] = Some(w);
                        walking |= 1 << i;
                    }
                    // (A lane through another field than the packet's others' flew on its own.)
                    Plan::Deferred(f) => field = Some(f),
                }
            }
            if let Some(f) = field {
                st.fields.fly(f, &mut st.pending);
            }
            // (Bit i: lane i's walk is in the state's `found[i]`.)
            let mut found = 0u32;
            if let (Some(Grains::Stored(g)), 2.., true) = (&self.grid, in_beam, self.beams) {
                found = self.beam_walks(g, &st.walks, &beam[..in_beam], &mut st.found);
            }
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
            (sites, st.count_shard)
        });
        let (sites, shard) = sites;
        self.packet_counts.add_to(shard, n_rays, sites);
        if surface.checked > 0 {
            self.surface_counts
                .add_to(shard, surface.checked, surface.saw_field);
        }
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
    fn packet_settle(&self, p: &[Option<[f32; 3]>], lambda: &[f64], channels: usize) {
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
    /// value / pdf times the site's albedo, module docs "One packet at a time") and `pdf` (0 where
    /// there is no event); the events' throughputs are updated as [`Self::phase_sample`] does (in the
    /// lane's own copy where the event is its last, else in the map). `evaluated_next`: the caller
    /// evaluates each sampled direction next (the C++ plugin's spectral variants, whose record has no
    /// room for four weights), which the sample's own values then answer ([`SampledLane`]).
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
            // (Packets of one lane, the scalar variants', sample it alone: 5 % faster there.)
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
                let lane_waves = waves.lane(i);
                let wv = lane_waves.get();
                self.settle(st, i, lane.p, &waves);
                // A blocked shadow ray answers one evaluation, the light's (not a sample's: spectral
                // variants evaluate the sampled direction in a second call).
                st.blocked[i] = None;
                let out = (
                    &mut wo[i],
                    &mut weight[i * channels..(i + 1) * channels],
                    &mut pdf[i],
                );
                let events = LaneEvents {
                    recent: &st.recent[i],
                    map: &st.events,
                };
                let Some((w_in, e)) = self.sample_event(&events, lane) else {
                    let null = (null_sample(wv.lam.len()), None);
                    commit_lane(st, i, lane, wv.lam, null, evaluated_next, out);
                    continue;
                };
                if side_by_side {
                    let first = || {
                        let view = self.bins[0].phase[wv.ls[0].0].sampling_view();
                        Box::new(PhaseLanes::new(channels, view))
                    };
                    let side = st.phase.get_or_insert_with(first);
                    // (A sample whose draws are not numbers is taken here, with the event at hand.)
                    if self.fill_phase_lane(&e, lane, wv.lam, wv.ls, side, m) && !side.is_alone(m) {
                        (slot_lane[m], w_ins[i]) = (i, w_in);
                        m += 1;
                        continue;
                    }
                }
                let one = self.event_phase_sample(&e, w_in, lane, wv.lam, wv.ls, true);
                commit_lane(st, i, lane, wv.lam, one, evaluated_next, out);
            }
            if m > 0 {
                // Out of the state while its lanes are committed to it (given back below).
                let mut side = st.phase.take().expect("filled above");
                (side.n, side.channels) = (m, channels);
                // SAFETY: the lanes' tables are this medium's, which live as long as it does (its
                // packet state is its own: `with_packet_state`).
                unsafe { side.sample(false) };
                for (k, &i) in slot_lane.iter().enumerate().take(m) {
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
        })
    }

    /// Evaluate the phase functions of a packet's events: lanes → `values` (`channels` per lane, times
    /// the site's albedo: module docs "One packet at a time") and `pdf`. `lambda`: `channels`
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A packet's phase samples side by side (`crate::render::phase_lanes`), in AVX-512 where the CPU
    /// has it and in the scalar lane loop everywhere, give every lane exactly what one lane at a time
    /// gives (`event_phase_sample`): direction, weights, pdf and the throughput after the bounce, bit
    /// for bit. Packets of 1 to 16 lanes, one to three channels, known and unknown throughputs, draws
    /// at the ends of [0, 1), samples in long directory buckets (halved before they are searched) and
    /// in short ones, events with and without their own albedo, slots left over from
    /// the previous packet, and an albedo scaled to 0 (every sample null).
    #[test]
    fn phase_lanes_match_one_lane_at_a_time() {
        let mut s = 11u64;
        let mut r = || crate::test_rng::lcg(&mut s);
        let (mut long, mut short, mut alone) = (0, 0, 0);
        // The albedo scaled to 0 (every sample null), and one bin black at 500 nm (that channel neither
        // picked nor valued there).
        let media = [(medium(400), 1.0), (medium(400), 0.0)];
        let black = (medium_with_albedo(400, f64::INFINITY, [0.0, 0.7]), 1.0);
        for (m, scale) in media.iter().chain([&black]) {
            m.set_albedo_scale(*scale).unwrap();
            for lam in [vec![500.0, 600.0], vec![600.0, 500.0, 500.0], vec![500.0]] {
                let ls = m.brackets(&lam);
                let first = m.bins[0].phase[ls[0].0].sampling_view();
                let mut side = PhaseLanes::new(lam.len(), first);
                for round in 0..60 {
                    let n = 1 + round % PACKET_LANES;
                    let mut lanes = Vec::new();
                    for k in 0..n {
                        let mut site = Site::default();
                        site.push((r() * 400.0) as u32 % 400);
                        let t_in = if r() < 0.3 {
                            [0.0; MAX_CHANNELS]
                        } else {
                            normalised_throughput((0..lam.len()).map(|_| r()))
                        };
                        let mut e = Event {
                            site,
                            t_in,
                            t_out: t_in,
                            depth: 1,
                            ..NO_EVENT
                        };
                        if k % 3 == 1 {
                            // The event's own albedo (remembered at these wavelengths).
                            e.albedo = [0.9, 0.7, 0.5, 0.3];
                            e.albedo_nm = lam[0] as f32;
                        }
                        let w_in = normalise([r() - 0.5, r() - 0.5, r() - 0.5]).unwrap();
                        let edge = |x: f64| match k % 5 {
                            0 => 0.0,
                            1 => 1.0 - f64::EPSILON,
                            _ => x,
                        };
                        // Now and then a draw that is not a number: left to the caller.
                        let nan = (round + k) % 13 == 12;
                        let lane = PhaseSampleLane {
                            p: [0.0; 3],
                            wi: [0.0; 3],
                            u1: if nan && k % 2 == 0 { f64::NAN } else { edge(r()) },
                            u2: [if nan && k % 2 == 1 { f64::NAN } else { edge(r()) }, r()],
                        };
                        assert!(m.fill_phase_lane(&e, &lane, &lam, &ls, &mut side, k));
                        lanes.push((e, w_in, lane));
                    }
                    (side.n, side.channels) = (n, lam.len());
                    for force_scalar in [true, false] {
                        let mut got = side;
                        // SAFETY: the tables are `m`'s, alive throughout.
                        unsafe { got.sample(force_scalar) };
                        for (k, (e, w_in, lane)) in lanes.iter().enumerate() {
                            let (want, t_want) =
                                m.event_phase_sample(e, *w_in, lane, &lam, &ls, true);
                            let nan = lane.u1.is_nan() || lane.u2[0].is_nan();
                            assert_eq!(got.alone[k] != 0, nan, "lane {k}: left alone iff NaN");
                            assert_eq!(side.is_alone(k), nan, "lane {k}");
                            if nan {
                                alone += 1;
                                continue;
                            }
                            // SAFETY: as above.
                            if unsafe { side.in_long_bucket(k) } {
                                long += 1;
                            } else {
                                short += 1;
                            }
                            if got.ok[k] == 0 {
                                assert!(!(want.2 > 0.0), "{lam:?} lane {k}: null, want {want:?}");
                                continue;
                            }
                            let at = format!("{lam:?} lane {k} of {n}, scalar {force_scalar}");
                            let bits = |v: [f64; 3]| v.map(f64::to_bits);
                            assert_eq!(got.pdf[k].to_bits(), want.2.to_bits(), "{at}");
                            let dir = deflect(*w_in, got.mu[k], lane.u2[1]);
                            assert_eq!(bits(dir), bits(want.0), "{at}");
                            for c in 0..lam.len() {
                                let w = (got.weight[c][k].to_bits(), want.1[c].to_bits());
                                assert_eq!(w.0, w.1, "{at}: channel {c}");
                                let t = (got.t_out[c][k] as f32).to_bits();
                                assert_eq!(t, t_want.unwrap()[c].to_bits(), "{at}");
                            }
                        }
                    }
                }
            }
        }
        assert!(
            long > 100 && short > 1000 && alone > 20,
            "long {long}, short {short}, alone {alone}"
        );
    }

    /// Each disk removes exactly C from a beam: π R² (1 − e^{−τ}) = C, whatever r_c (issue 9.0), and
    /// τ ≤ τ_max; with r_c = 0 and Q = 2 the paper's τ = C / (π R²) would be 2 (43 % of C removed).
    #[test]
    fn disks_remove_their_cross_section() {
        for &(r, q, rc, tmax) in &[
            (1.0, 2.0, 0.0, DEFAULT_TAU_MAX),
            (1.0, 2.0, 0.0, f64::INFINITY),
            (1.0, 1.0, 0.0, f64::INFINITY),
            (1.0, 2.0, 10.0, 0.1),
            (0.5, 2.2, 0.1, 0.05),
        ] {
            let c = q * PI * r * r;
            let (reach, tau) = particle_disk(r, c, rc, tmax);
            assert!(reach >= rc + r);
            assert!(tau <= tmax.min(TAU_OPAQUE) + 1e-12, "{tau}");
            let removed = PI * reach * reach * (1.0 - (-tau).exp());
            assert!(
                (removed / c - 1.0).abs() < 1e-9,
                "{r} {q} {rc} {tmax}: {removed} vs {c}"
            );
        }
    }

    /// The channel throughput carried by events: sampling channel c ∝ t_c keeps Σ_c t_c f_c / q at 1
    /// for a non-absorbing medium, so per-channel path weights stay bounded over many bounces.
    #[test]
    fn channel_weights_stay_bounded_along_a_chain() {
        let m = medium(4000);
        let mut o = [0.5f32, 0.5, -0.2];
        let mut d = [0.0f32, 0.0, 1.0];
        let mut throughput = [1.0f64; 2];
        let mut k = 0u64;
        let mut bounces = 0;
        for _ in 0..20000 {
            let r = m.sample_sites(&[o], &[d], &[f64::INFINITY], &[true]);
            let Some(t) = r[0].t else {
                o = [0.5, 0.5, -0.2];
                d = [0.0, 0.0, 1.0];
                continue;
            };
            let p = [0, 1, 2].map(|a| o[a] + t as f32 * d[a]);
            let a = m.commit_events(&[p], &[true], &[500.0, 600.0], 2).unwrap();
            k += 1;
            let u = |s: u64| uniform(11, k, s);
            let lane = PhaseSampleLane {
                p,
                wi: d.map(|x| -x),
                u1: u(0),
                u2: [u(1), u(2)],
            };
            let (wo, w, pdf) = m.phase_sample(&[lane], &[500.0, 600.0], 2);
            if pdf[0] <= 0.0 {
                continue;
            }
            for c in 0..2 {
                throughput[c] *= a[c] * w[c];
            }
            // Σ_c t_c is what the throughput-proportional choice preserves (up to albedo and ε).
            assert!(
                throughput.iter().all(|x| x.is_finite() && *x < 50.0),
                "{throughput:?}"
            );
            o = p;
            d = wo[0].map(|x| x as f32);
            bounces += 1;
        }
        assert!(bounces > 1000);
    }

    fn table(g: f64) -> PhaseTable {
        // Henyey–Greenstein on a fine grid.
        let theta: Vec<f64> = (0..2001).map(|i| PI * i as f64 / 2000.0).collect();
        let f: Vec<f64> = theta
            .iter()
            .map(|t| (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * t.cos()).powf(1.5)))
            .collect();
        PhaseTable::new(&theta, &f).unwrap()
    }

    fn medium(n: usize) -> DiscreteMedium {
        medium_with(n, f64::INFINITY)
    }

    /// The test medium with a `continuous_count` (1: its one size class, 1.7 particles per cylinder,
    /// is continuous).
    fn medium_with(n: usize, continuous_count: f64) -> DiscreteMedium {
        medium_with_albedo(n, continuous_count, [0.5, 0.7])
    }

    /// [`medium_with`], its second bin's albedo at 500 and 600 nm given.
    fn medium_with_albedo(n: usize, continuous_count: f64, albedo: [f64; 2]) -> DiscreteMedium {
        let mut s = 3u64;
        let mut r = || crate::test_rng::lcg(&mut s);
        let pos: Vec<[f64; 3]> = (0..n).map(|_| [r(), r(), r()]).collect();
        let rad: Vec<f64> = (0..n).map(|_| 0.002 + 0.004 * r()).collect();
        let c: Vec<f64> = rad.iter().map(|x| 2.0 * PI * x * x).collect();
        let bins = vec![
            BinOptics {
                albedo: vec![1.0, 0.9],
                phase: vec![table(0.3), table(0.5)],
            },
            BinOptics {
                albedo: albedo.to_vec(),
                phase: vec![table(-0.2), table(0.8)],
            },
        ];
        let bin: Vec<u32> = (0..n).map(|i| (i % 2) as u32).collect();
        DiscreteMedium::build(
            &pos,
            &rad,
            1.0,
            &|i| c[i],
            &bin,
            bins,
            vec![500.0, 600.0],
            0.01,
            DEFAULT_TAU_MAX,
            1.0,
            continuous_count,
            7,
            Storage::Full,
        )
        .unwrap()
    }

    /// Runs `check(medium, continuous_count)` on the test medium of 4000 particles kept discrete
    /// (an infinite `continuous_count`) and as a continuous field (1).
    fn discrete_and_continuous(check: impl Fn(&DiscreteMedium, f64)) {
        for continuous_count in [f64::INFINITY, 1.0] {
            check(&medium_with(4000, continuous_count), continuous_count);
        }
    }

    /// Sites are sampled with the exact escape probability exp(−τ) (binomial 5σ bound), and the
    /// walked optical depth before a site never exceeds the segment's; the same with the particles
    /// as a continuous field.
    #[test]
    fn site_escape_probability() {
        discrete_and_continuous(|m, continuous_count| {
            assert_eq!(m.continuous_len() > 0, continuous_count.is_finite());
            let lanes = 40000;
            let o = vec![[0.5f32, 0.5, -0.2]; lanes];
            let d = vec![[0.0f32, 0.0, 1.0]; lanes];
            let tm = vec![1.4; lanes];
            let ray = RaySegment::new([0.5, 0.5, -0.2], [0.0, 0.0, 1.0], 0.0, 1.4);
            let tau = [m.optical_depth(&ray)];
            let res = m.sample_sites(&o, &d, &tm, &vec![true; lanes]);
            let escaped = res.iter().filter(|r| r.t.is_none()).count();
            assert!(tau[0] > 0.2, "{}", tau[0]);
            crate::test_rng::assert_escape_fraction(escaped, lanes, (-tau[0]).exp());
            for r in &res {
                assert!(r.tau_before <= tau[0] + 1e-6);
            }
        });
    }

    /// Eq. 24 at points: the mean of σ_s(p) over random interior points is the bulk Σ C_s / V (6σ),
    /// and sampling the local mixture returns the pdf that evaluation gives (mean of Q_c / σ_s,c).
    #[test]
    fn local_scattering_is_unbiased_and_consistent() {
        discrete_and_continuous(|m, continuous_count| {
            let mut s = 99u64;
            let mut r = || crate::test_rng::lcg(&mut s);
            // Discrete: interior points, away from the faces of the particles' unit box (balls
            // stick out). Continuous: the whole box, because a sub-box's mean differs from the
            // box's by the cells' own fluctuation (~8 particles per cell: 35 % per cell, ~2 % over
            // a sub-box).
            let (a, w) = if continuous_count.is_finite() {
                (0.0, 1.0)
            } else {
                (0.1, 0.8)
            };
            let pts: Vec<[f64; 3]> = (0..40000)
                .map(|_| [a + w * r(), a + w * r(), a + w * r()])
                .collect();
            let mu = vec![0.3; pts.len()];
            let (sigma, q) = m.local_scattering(&pts, &mu, &[500.0], 1);
            let mean = sigma.iter().sum::<f64>() / sigma.len() as f64;
            let var =
                sigma.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (sigma.len() - 1) as f64;
            // bulk: Σ_i C_t,i a_i / V over the unit box (albedo 1.0 / 0.5 by bin at 500 nm)
            let bulk: f64 = (0..m.len())
                .map(|i| m.optics.c_ext(i as u32) * m.bins[m.optics.bin(i as u32)].albedo[0])
                .sum::<f64>();
            let se = (var / sigma.len() as f64).sqrt();
            assert!(
                (mean - bulk).abs() < 6.0 * se,
                "mean σ_s {mean} vs bulk {bulk} (se {se})"
            );
            assert!(q
                .iter()
                .zip(&sigma)
                .all(|(a, b)| *a >= 0.0 && (*b > 0.0 || *a == 0.0)));
            let n = 2000;
            let w_in = vec![[0.0, 0.0, 1.0]; n];
            let u1: Vec<f64> = (0..n).map(|_| r()).collect();
            let u2: Vec<[f64; 2]> = (0..n).map(|_| [r(), r()]).collect();
            let (wo, w, pdf) = m.sample_local(&pts[..n], &w_in, &[500.0, 600.0], 2, &u1, &u2);
            for i in 0..n {
                if pdf[i] == 0.0 {
                    continue;
                }
                let (sg, qq) = m.local_scattering(&pts[i..i + 1], &[wo[i][2]], &[500.0, 600.0], 2);
                let expect = (qq[0] / sg[0] + qq[1] / sg[1]) / 2.0;
                assert!(
                    (pdf[i] - expect).abs() < 1e-9 * expect.max(1.0),
                    "{} {}",
                    pdf[i],
                    expect
                );
                assert!((w[2 * i] * pdf[i] - qq[0] / sg[0]).abs() < 1e-9 * expect.max(1.0));
            }
        });
    }

    /// A ray leaving an event at or past the grain depth sees the grains' continuous equivalent: it
    /// escapes with probability exp(−τ of that field) and interacts anywhere along the ray, not only at
    /// grains; below the grain depth, or with an infinite `continuous_count`, it walks the grains.
    #[test]
    fn rays_past_the_grain_depth_see_the_continuous_equivalent() {
        for continuous_count in [1e12, f64::INFINITY] {
            let m = medium_with(4000, continuous_count);
            assert_eq!(m.continuous_len(), 0); // every class discrete either way
            let (o, d) = ([[0.5f32, 0.5, -0.2]], [[0.0f32, 0.0, 1.0]]);
            let t = (0..200)
                .find_map(|_| m.sample_sites(&o, &d, &[f64::INFINITY], &[true])[0].t)
                .expect("an event");
            let p = [0.5f32, 0.5, (-0.2 + t) as f32];
            m.commit_events(&[p], &[true], &[500.0, 600.0], 2).unwrap();
            let lanes = 20000;
            let sites_from_event = |depth: u32| {
                m.set_grain_depth(depth).unwrap();
                let r = m.sample_sites(
                    &vec![p; lanes],
                    &vec![d[0]; lanes],
                    &vec![1.0; lanes],
                    &vec![false; lanes],
                );
                r.iter().map(|x| x.t).collect::<Vec<_>>()
            };
            let distinct = |ts: &[Option<f64>]| {
                let mut v: Vec<u64> = ts.iter().flatten().map(|t| t.to_bits()).collect();
                v.sort_unstable();
                v.dedup();
                v.len()
            };
            let walked = sites_from_event(2);
            assert!(distinct(&walked) < 100, "{}", distinct(&walked)); // grains only
            let seen = sites_from_event(1);
            match &m.grains_field {
                Some(f) => {
                    assert!(distinct(&seen) > 1000, "{}", distinct(&seen));
                    let ray = RaySegment::new(p.map(|x| x as f64), [0.0, 0.0, 1.0], 0.0, 1.0);
                    let escaped = seen.iter().filter(|t| t.is_none()).count();
                    let tau = f.optical_depth(&ray);
                    assert!(tau > 0.1, "{tau}");
                    crate::test_rng::assert_escape_fraction(escaped, lanes, (-tau).exp());
                }
                None => assert!(distinct(&seen) < 100, "{}", distinct(&seen)), // exact: no field at all
            }
        }
    }

    /// A ray along +z through the test medium whose free flight (lane 1 of a packet) meets a site in
    /// the cube's lower half (rays from it cross much of the cube): the first of a row of origins
    /// (which one depends on the free flights' random numbers).
    fn ray_with_site(m: &DiscreteMedium, lambda: &[f64]) -> ([f32; 3], [f32; 3]) {
        let d = [0.0f32, 0.0, 1.0];
        (0..400)
            .map(|k| [0.3 + 0.001 * k as f32, 0.5, -0.2])
            .find(|&o| {
                let mut t = [None; 2];
                m.packet_free_flights(&[None, Some((o, d, 10.0))], lambda, 2, &mut t);
                t[1].is_some_and(|t| t < 0.7)
            })
            .map(|o| (o, d))
            .expect("a ray that meets a site")
    }

    /// A packet phase sample with lane 1 active (two channels): directions, weights and pdfs, every
    /// output first NaN so that each must be written.
    fn sample_lane_1(
        m: &DiscreteMedium,
        lane: PhaseSampleLane,
        lambda: &[f64],
        evaluated_next: bool,
    ) -> ([[f64; 3]; 2], [f64; 4], [f64; 2]) {
        let (mut wo, mut w, mut pdf) = ([[f64::NAN; 3]; 2], [f64::NAN; 4], [f64::NAN; 2]);
        m.packet_phase_sample(
            &[None, Some(lane)],
            lambda,
            2,
            &mut wo,
            &mut w,
            &mut pdf,
            evaluated_next,
        );
        (wo, w, pdf)
    }

    /// Lane 1's pending site after a free flight along +z ([`ray_with_site`]): the ray's direction and
    /// where the renderer puts the site.
    fn pending_site(m: &DiscreteMedium, lambda: &[f64]) -> ([f32; 3], [f32; 3]) {
        let (o, d) = ray_with_site(m, lambda);
        let mut t = [None; 2];
        m.packet_free_flights(&[None, Some((o, d, 10.0))], lambda, 2, &mut t);
        (d, site_position(o, d, t[1].expect("a site")))
    }

    /// A packet lane's site becomes its event where the lane's next call starts at it (the position as
    /// the renderer computes it, o + t d in float32): the map holds it, the lane's own copy carries the
    /// phase sample's throughput, and its phase function's values and weights carry the site's
    /// albedo. A site no call starts at (a shadow ray's) is never remembered.
    #[test]
    fn a_lanes_site_is_settled_where_its_path_goes_on() {
        let m = medium(4000);
        let lambda = [500.0, 600.0];
        let (o, d) = ray_with_site(&m, &lambda);
        for _ in 0..3 {
            let mut t = [None; 2];
            m.packet_free_flights(&[None, Some((o, d, 10.0))], &lambda, 2, &mut t);
            let t = t[1].expect("a site") as f32;
            let p = [0, 1, 2].map(|a| d[a].mul_add(t, o[a]));
            let lane = PhaseSampleLane {
                p,
                wi: d,
                u1: 0.3,
                u2: [0.2, 0.7],
            };
            let (wo, w, pdf) = sample_lane_1(&m, lane, &lambda, false);
            assert!(pdf[1] > 0.0);
            let event = m.with_packet_state(|st| {
                let (at, e) = st.recent[1].expect("lane 1's event");
                assert_eq!(at, key(p));
                let mapped = st.events.get(&at).expect("in the map");
                assert_eq!(e.t_in, mapped.t_in);
                assert!(e.t_out.iter().any(|&x| x > 0.0));
                assert_eq!(st.lane(1).event(&at).map(|e| e.t_out), Some(e.t_out));
                assert!(st.recent[0].is_none());
                e
            });
            // The weights are the plain sample's times the albedo.
            let mut map = EventMap::new(4);
            map.insert(key(p), event);
            let ls = m.brackets(&lambda);
            let ((wo_plain, w_plain, pdf_plain), _) =
                m.lane_phase_sample(&map, &lane, &lambda, &ls, false);
            assert_eq!(wo[1], wo_plain);
            assert!((pdf[1] / pdf_plain - 1.0).abs() < 1e-12);
            let albedo = [0, 1].map(|c| m.site_albedo(&event.site, m.bracket(lambda[c])));
            // Every particle of the test medium has an albedo below 1 in some channel.
            assert!(albedo.iter().any(|&a| a < 1.0), "{albedo:?}");
            for c in 0..2 {
                let a = albedo[c];
                assert!(a > 0.0 && a <= 1.0, "{a}");
                assert!(
                    (w[2 + c] / (w_plain[c] * a) - 1.0).abs() < 1e-6,
                    "{w:?} {w_plain:?} {a}"
                );
            }
            // A shadow ray from the event (the first of some directions that meets a grain): its site
            // is left pending, then replaced.
            let q = (0..200)
                .find_map(|k| {
                    let a = 0.1 * k as f32;
                    let ds = [a.sin() * 0.6, a.cos() * 0.6, 0.8];
                    let mut s = [None; 2];
                    m.packet_free_flights(&[None, Some((p, ds, 10.0))], &lambda, 2, &mut s);
                    let ts = s[1]? as f32;
                    Some([0, 1, 2].map(|a| ds[a].mul_add(ts, p[a])))
                })
                .unwrap_or_else(|| panic!("a shadow ray that meets a grain from {p:?} (o {o:?})"));
            m.with_packet_state(|st| assert!(st.pending[1].site.is_some()));
            let mut s = [None; 2];
            m.packet_free_flights(&[None, Some((o, d, 10.0))], &lambda, 2, &mut s);
            m.with_packet_state(|st| {
                assert!(st.events.get(&key(q)).is_none());
                assert_eq!(st.recent[1].map(|r| r.0), Some(key(p)));
            });
        }
    }

    /// Positions a few ulps from a lane's site are its site; others are not.
    #[test]
    fn sites_are_found_within_a_few_ulps() {
        let at = [0.25f32, -3.0, 1e-9];
        assert!(at_site(at, at));
        let up = |x: f32, n: i32| f32::from_bits((x.to_bits() as i32 + n) as u32);
        assert!(at_site([up(0.25, 4), up(-3.0, -4), up(1e-9, 3)], at));
        assert!(!at_site([up(0.25, 9), -3.0, 1e-9], at)); // |x| ε is one to two ulps
        assert!(!at_site([0.25, up(-3.0, 9), 1e-9], at));
        assert!(!at_site([0.2501, -3.0, 1e-9], at));
        assert!(!at_site([0.25, -3.0, 2e-9], at));
        assert!(!at_site([f32::NAN, -3.0, 1e-9], at));
        // −0 and +0: one position, one key.
        assert!(at_site([0.0, -3.0, 1e-9], [-0.0, -3.0, 1e-9]));
        assert_eq!(key([-0.0, 1.0, 2.0]), key([0.0, 1.0, 2.0]));
    }

    /// Octahedral directions (how the native plugin's phase samples travel) unfolded as the C++ plugin
    /// does, in float32, come back within float32 precision: axes, signed zeros, the equator, the
    /// poles and random directions.
    #[test]
    fn octahedral_directions_survive_float32() {
        // motes_native.cpp's `octahedral`, in float32.
        let decode = |x: f32, y: f32| {
            let z = 1.0 - x.abs() - y.abs();
            let (ux, uy) = if z < 0.0 {
                ((1.0 - y.abs()).copysign(x), (1.0 - x.abs()).copysign(y))
            } else {
                (x, y)
            };
            let n = (ux * ux + uy * uy + z * z).sqrt();
            [ux / n, uy / n, z / n].map(|c| c as f64)
        };
        let mut s = 17u64;
        let mut r = || crate::test_rng::lcg(&mut s);
        let mut dirs: Vec<[f64; 3]> = vec![
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [-0.0, -0.0, -1.0],
            [0.6, -0.8, 0.0],
            [0.6, -0.8, -0.0],
            [1e-9, 0.0, -1.0],
        ];
        for _ in 0..20000 {
            let z: f64 = 2.0 * r() - 1.0;
            let phi = 2.0 * PI * r();
            let st = (1.0 - z * z).sqrt();
            dirs.push([st * phi.cos(), st * phi.sin(), z]);
        }
        for w in dirs {
            let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            let w = w.map(|c| c / l);
            let [x, y] = octahedral(w);
            let v = decode(x as f32, y as f32);
            let err =
                ((v[0] - w[0]).powi(2) + (v[1] - w[1]).powi(2) + (v[2] - w[2]).powi(2)).sqrt();
            assert!(err < 1e-6, "{w:?} -> {v:?}: {err}");
        }
    }

    /// A lane inactive in a packet's free flights keeps the site of its own last one: its path has
    /// not moved on, and its phase function finds the event there.
    #[test]
    fn inactive_lanes_keep_their_site() {
        let m = medium(4000);
        let lambda = [500.0, 600.0];
        let (o, d) = ray_with_site(&m, &lambda);
        let mut t = [None; 2];
        m.packet_free_flights(&[None, Some((o, d, 10.0))], &lambda, 2, &mut t);
        let p = site_position(o, d, t[1].expect("a site"));
        // Another lane's free flight (lane 1 inactive), as a shadow ray of lane 0's path.
        let mut t0 = [None; 2];
        m.packet_free_flights(
            &[Some((o, [0.0, 1.0, 0.0], 10.0)), None],
            &lambda,
            2,
            &mut t0,
        );
        assert_eq!(t0[1], None);
        let lane = PhaseEvalLane {
            p,
            wi: d.map(|x| -x),
            wo: [0.0, 0.6, 0.8],
        };
        let (mut v, mut pdf) = ([0.0; 4], [0.0; 2]);
        m.packet_phase_eval(&[None, Some(lane)], &lambda, 2, &mut v, &mut pdf);
        assert!(pdf[1] > 0.0);
        m.with_packet_state(|st| assert_eq!(st.recent[1].map(|r| r.0), Some(key(p))));
    }

    /// A phase evaluation from a lane's last free-flight origin towards its direction, where that flight
    /// ended at a site inside the medium's enclosure, is zero (next-event estimation multiplies it by
    /// the light the blocked shadow ray does not see), once; any other is computed: no enclosure, an
    /// enclosure that does not hold the site, another direction, a second evaluation.
    #[test]
    fn an_evaluation_behind_a_blocked_shadow_ray_is_zero_inside_the_enclosure() {
        use crate::render::enclosure::{Enclosure, Region};
        let m = medium(4000);
        let lambda = [500.0, 600.0];
        let (d, p) = pending_site(&m, &lambda);
        // A shadow ray from the event that meets a site (the first of some directions; its flight
        // settles the event). The same ray always meets the same site (its numbers come from the ray).
        let flight = |m: &DiscreteMedium, ds: [f32; 3]| {
            let mut s = [None; 2];
            m.packet_free_flights(&[None, Some((p, ds, 10.0))], &lambda, 2, &mut s);
            s[1]
        };
        let ds = (0..200)
            .map(|k| {
                let a = 0.1 * k as f32;
                [a.sin() * 0.6, a.cos() * 0.6, 0.8]
            })
            .find(|&ds| flight(&m, ds).is_some_and(|t| t > 1e-3))
            .expect("a shadow ray that meets a grain");
        let eval = |m: &DiscreteMedium, wo: [f32; 3]| {
            let lane = PhaseEvalLane {
                p,
                wi: d.map(|x| -x),
                wo,
            };
            let (mut v, mut pdf) = ([0.0; 4], [0.0; 2]);
            m.packet_phase_eval(&[None, Some(lane)], &lambda, 2, &mut v, &mut pdf);
            (v[2] + v[3], pdf[1])
        };
        let computed = eval(&m, ds);
        assert!(computed.0 > 0.0 && computed.1 > 0.0, "{computed:?}");
        m.set_enclosure(Enclosure {
            regions: vec![Region::ball([0.5; 3], 10.0).unwrap()],
        });
        flight(&m, ds);
        assert_eq!(eval(&m, ds), (0.0, 0.0));
        assert_eq!(eval(&m, ds), computed, "one evaluation per blocked flight");
        flight(&m, ds);
        let other = [ds[0], ds[1] + 2e-3, ds[2]];
        assert!(eval(&m, other).0 > 0.0, "another direction");
        // A region that holds the event but not the site.
        m.set_enclosure(Enclosure {
            regions: vec![Region::ball(p.map(|x| x as f64), 5e-4).unwrap()],
        });
        flight(&m, ds);
        assert_eq!(eval(&m, ds), computed);
        m.set_enclosure(Enclosure::default());
        flight(&m, ds);
        assert_eq!(eval(&m, ds), computed);
    }

    /// A site that scatters nothing (every albedo scaled to 0) gives a phase sample of zero weight and
    /// pdf 1, not pdf 0: the integrator ends the path there (with pdf 0 it would leave the path on the
    /// ray Mitsuba cut at the site).
    #[test]
    fn black_grains_end_the_path_with_a_zero_weight() {
        let m = medium(4000);
        let lambda = [500.0, 600.0];
        m.set_albedo_scale(0.0).unwrap();
        let (d, p) = pending_site(&m, &lambda);
        let lane = PhaseSampleLane {
            p,
            wi: d,
            u1: 0.3,
            u2: [0.2, 0.7],
        };
        let (wo, w, pdf) = sample_lane_1(&m, lane, &lambda, true);
        assert_eq!(pdf[1], 1.0);
        assert_eq!(&w[2..], &[0.0, 0.0]);
        let n: f64 = wo[1].iter().map(|x| x * x).sum();
        assert!((n - 1.0).abs() < 1e-12, "{:?}", wo[1]);
        // The spectral variants' second call, at the sampled direction, agrees.
        let e = PhaseEvalLane {
            p,
            wi: d,
            wo: wo[1].map(|x| x as f32),
        };
        let (mut v, mut pe) = ([1.0; 4], [0.0; 2]);
        m.packet_phase_eval(&[None, Some(e)], &lambda, 2, &mut v, &mut pe);
        assert_eq!((&v[2..], pe[1]), (&[0.0, 0.0][..], 1.0));
    }

    /// Events whose rays see the grains' continuous equivalent live beside their lane only (they
    /// skip no particles: the map is the record of those that do), and the lane's next free flight
    /// from one sees the field; a pending site a few ulps from the lane's event (a shadow ray's) does
    /// not replace it.
    #[test]
    fn field_events_live_beside_their_lane() {
        let m = medium_with(20000, 1.0);
        assert!(m
            .grains_field_from(&Event {
                depth: 1,
                ..NO_EVENT
            })
            .is_some());
        let (o, d) = ([0.5f32, 0.5, -0.2], [0.0f32, 0.0, 1.0]);
        let lambda = [500.0, 600.0];
        let mut t = [None; 1];
        m.packet_free_flights(&[Some((o, d, 10.0))], &lambda, 2, &mut t);
        let p = site_position(o, d, t[0].expect("a site"));
        let next = |m: &DiscreteMedium| {
            let mut t = [None; 1];
            m.packet_free_flights(&[Some((p, [0.6, 0.0, 0.8], 10.0))], &lambda, 2, &mut t);
            t[0]
        };
        next(&m);
        m.with_packet_state(|st| {
            let (k, e) = st.recent[0].expect("the lane's event");
            assert_eq!(k, key(p));
            assert_eq!(e.depth, 1);
            assert!(st.events.get(&k).is_none(), "not in the map");
            // A pending site an ulp from the event.
            let near = [p[0], p[1], f32::from_bits(p[2].to_bits() + 1)];
            st.pending[0] = PendingLane {
                site: Some(Site::default()),
                parent: Parent::default(),
                at: near,
            };
        });
        let lane = PhaseEvalLane {
            p,
            wi: d.map(|x| -x),
            wo: [0.0, 0.6, 0.8],
        };
        let (mut v, mut pdf) = ([0.0; 2], [0.0; 1]);
        m.packet_phase_eval(&[Some(lane)], &lambda, 2, &mut v, &mut pdf);
        assert!(pdf[0] > 0.0);
        m.with_packet_state(|st| {
            let (k, e) = st.recent[0].expect("the lane's event");
            assert_eq!((k, e.depth), (key(p), 1));
            assert!(st.pending[0].site.is_some(), "left pending");
        });
    }

    /// One particle's mixture (the fast path: its bin's tables, located once) gives what the general
    /// mixture of the same particle twice gives, in every channel.
    #[test]
    fn one_particle_mixtures_equal_the_general_mixture() {
        let m = medium(4000);
        let ls: Vec<_> = [480.0, 550.0, 600.0, 700.0].map(|l| m.bracket(l)).to_vec();
        let pi = [0.1, 0.2, 0.3, 0.4];
        for j in [0u32, 1, 17, 3999] {
            for k in 0..=200 {
                let mu = -1.0 + 2.0 * k as f64 / 200.0;
                let (mut one, mut two) = ([0.0; 4], [0.0; 4]);
                let (single, double) = ([j], [j, j]);
                let mix = |members| Mixture {
                    members,
                    scale: |j| m.optics.tau(j),
                    ls: &ls,
                    pi: &pi,
                };
                let p1 = m.mixture_phase(&mix(&single), mu, &mut one);
                let p2 = m.mixture_phase(&mix(&double), mu, &mut two);
                assert!((p1 - p2).abs() <= 1e-12 * p2, "{p1} vs {p2}");
                for c in 0..4 {
                    assert!(
                        (one[c] - two[c]).abs() <= 1e-12 * two[c],
                        "{one:?} vs {two:?}"
                    );
                }
            }
        }
    }

    /// A packet's rays that start at no event and walk the grains together as a beam (a pixel's camera
    /// rays in compact storage's centre cells) find the sites each finds alone, also beside lanes that
    /// start at an event and inactive lanes.
    #[test]
    fn packets_walked_as_beams_find_each_rays_own_site() {
        let mut s = 41u64;
        let mut r = || crate::test_rng::lcg(&mut s);
        let n = 70_000; // compact storage's centre cells (from 2^16 discrete grains)
        let pos: Vec<[f64; 3]> = (0..n).map(|_| [r(), r(), r()]).collect();
        let rad: Vec<f64> = (0..n).map(|_| 0.002 + 0.0015 * r()).collect();
        let c: Vec<f64> = rad.iter().map(|x| 2.0 * PI * x * x).collect();
        let bins = vec![BinOptics {
            albedo: vec![0.9, 0.8],
            phase: vec![table(0.3), table(0.5)],
        }];
        let m = DiscreteMedium::build(
            &pos,
            &rad,
            1.0,
            &|i| c[i],
            &vec![0; n],
            bins,
            vec![500.0, 600.0],
            0.004,
            DEFAULT_TAU_MAX,
            1.0,
            f64::INFINITY,
            7,
            Storage::Compact,
        )
        .unwrap();
        let Some(Grains::Stored(g)) = &m.grid else {
            panic!("stored grains")
        };
        // An event of this thread's packets for one lane to start at (it skips its particles: no beam
        // for it).
        let (o, d) = ([0.5f32, 0.5, -0.2], [0.0f32, 0.0, 1.0]);
        let mut first = [None];
        m.packet_free_flights(&[Some((o, d, 10.0))], &[500.0, 600.0], 2, &mut first);
        let event = [0.5f32, 0.5, -0.2 + first[0].expect("a site") as f32];
        m.packet_settle(&[Some(event)], &[500.0, 600.0], 2);
        assert!(m.with_packet_state(|st| st.events.get(&key(event)).is_some()));
        let (mut beams, mut sites) = (0, 0);
        for k in 0..60 {
            let eye = [0.2 + 0.6 * r(), 0.2 + 0.6 * r(), -2.0];
            let aim = [0.2 + 0.6 * r(), 0.2 + 0.6 * r(), 0.5];
            let rays: Vec<Option<PacketRay>> = (0..PACKET_LANES)
                .map(|i| {
                    if i == 3 && k % 2 == 0 {
                        return None;
                    }
                    if i == 5 && k % 3 == 0 {
                        return Some((event, [0.1, 0.0, 0.995], 5.0));
                    }
                    let a = aim.map(|x| x + 0.003 * (r() - 0.5));
                    let d = [0, 1, 2].map(|j| a[j] - eye[j]);
                    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    Some((eye.map(|x| x as f32), d.map(|x| (x / l) as f32), 10.0f32))
                })
                .collect();
            let mut together = [None; PACKET_LANES];
            m.packet_free_flights(&rays, &[500.0, 600.0], 2, &mut together);
            for (i, ray) in rays.iter().enumerate() {
                let mut alone = [None];
                m.packet_free_flights(&[*ray], &[500.0, 600.0], 2, &mut alone);
                assert_eq!(together[i], alone[0], "packet {k}, lane {i}");
                sites += alone[0].is_some() as usize;
            }
            let segs: Vec<RaySegment> = rays
                .iter()
                .flatten()
                .filter(|r| r.0 != event)
                .map(|&(o, d, t)| {
                    RaySegment::new(o.map(|x| x as f64), d.map(|x| x as f64), 0.0, t as f64)
                })
                .collect();
            let mut out = vec![(None, 0.0); segs.len()];
            beams +=
                g.sample_sites_beam(&segs, &vec![0.5; segs.len()], m.coincide, &mut out) as usize;
        }
        assert!(beams > 50 && sites > 300, "{beams} beams, {sites} sites");
    }

    /// After an event is committed, a ray starting at its position skips the event's particles; the
    /// phase function of the event samples what it evaluates (pdf = mean of channel values).
    #[test]
    fn events_exclude_and_phase_is_consistent() {
        let m = medium(4000);
        let o = [[0.5f32, 0.5, -0.2]];
        let d = [[0.0f32, 0.0, 1.0]];
        let mut site = None;
        for _ in 0..100 {
            let r = m.sample_sites(&o, &d, &[f64::INFINITY], &[true]);
            if let Some(t) = r[0].t {
                site = Some(t);
                break;
            }
        }
        let t = site.expect("an event");
        let p = [0.5f32, 0.5, (-0.2 + t) as f32];
        let alb = m.commit_events(&[p], &[true], &[500.0, 600.0], 2).unwrap();
        assert!(alb.iter().all(|a| (0.0..=1.0).contains(a)));
        let s = m.event_at(p).unwrap();
        assert!(s.len >= 1);
        // without the map entry the phase function finds the site from the geometry
        assert_eq!(
            m.site_near(p, [0.0, 0.0, 1.0])
                .map(|x| x.members().to_vec()),
            Some(s.members().to_vec())
        );
        // an event of a lane not marked `remember` (a shadow ray) is not remembered
        let mut shadow_hit = None;
        for _ in 0..200 {
            if let Some(t) = m.sample_sites(
                &[[0.5f32, 0.5, -0.2]],
                &[[0.0f32, 0.0, 1.0]],
                &[1.0],
                &[false],
            )[0]
            .t
            {
                shadow_hit = Some(t);
                break;
            }
        }
        let q = [0.5f32, 0.5, (-0.2 + shadow_hit.unwrap()) as f32];
        if q != p {
            m.commit_events(&[q], &[true], &[500.0, 600.0], 2).unwrap();
            assert!(m.event_at(q).is_none());
        }
        let wi = [0.0, 0.0, -1.0];
        let lanes: Vec<PhaseSampleLane> = (0..64)
            .map(|i| PhaseSampleLane {
                p,
                wi,
                u1: i as f64 / 64.0,
                u2: [((i * 37) % 64) as f64 / 64.0, ((i * 11) % 64) as f64 / 64.0],
            })
            .collect();
        let (wo, w, pdf) = m.phase_sample(&lanes, &[500.0, 600.0], 2);
        let lanes: Vec<PhaseEvalLane> = wo
            .iter()
            .map(|v| PhaseEvalLane {
                p,
                wi,
                wo: v.map(|x| x as f32),
            })
            .collect();
        let (vals, pdf2) = m.phase_eval(&lanes, &[500.0, 600.0], 2);
        for i in 0..64 {
            assert!(pdf[i] > 0.0);
            assert!(
                (pdf[i] - pdf2[i]).abs() < 1e-3 * pdf[i],
                "{} {}",
                pdf[i],
                pdf2[i]
            );
            assert!((w[2 * i] * pdf[i] - vals[2 * i]).abs() < 1e-3 * vals[2 * i].max(1e-9));
            // the pdf is a mixture of the channel values (throughput-proportional weights, module docs)
            let (lo, hi) = (
                vals[2 * i].min(vals[2 * i + 1]),
                vals[2 * i].max(vals[2 * i + 1]),
            );
            assert!(pdf2[i] >= lo * (1.0 - 1e-12) && pdf2[i] <= hi * (1.0 + 1e-12));
        }
    }
}
