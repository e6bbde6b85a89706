//! A packet's free flights stepped together (module docs, "A packet's flights together").

use super::flight::exponential;
use super::{ContinuousField, FieldHit};
use crate::rng::stream_bits;
use crate::simd::lockstep_simd;
use crate::space::ray::RaySegment;

/// Rays of one [`ContinuousField::sample_free_flights`] call stepped together.
pub const FLIGHT_LANES: usize = 16;

/// A lane of [`FlightLanes`]: still tracking, past its end, at its site, or at its first tentative
/// collision outside the field's box (its end then needs clipping to the box: the caller goes on).
/// (Past its end is 0, so that a default lane is unused.)
pub(super) const LANE_NONE: u64 = 0;

pub(super) const LANE_RUNNING: u64 = 1;

pub(super) const LANE_REAL: u64 = 2;

pub(super) const LANE_OUTSIDE: u64 = 3;

/// The state of [`FLIGHT_LANES`] free flights, one array per quantity (SIMD lanes). Unused lanes are
/// past their end from the start.
#[derive(Default)]
pub(super) struct FlightLanes {
    pub(super) o: [[f64; FLIGHT_LANES]; 3],
    pub(super) d: [[f64; FLIGHT_LANES]; 3],
    pub(super) t: [f64; FLIGHT_LANES],
    pub(super) t1: [f64; FLIGHT_LANES],
    pub(super) key: [u64; FLIGHT_LANES],
    /// The index k of the lane's last tentative collision.
    pub(super) k: [u64; FLIGHT_LANES],
    pub(super) cell: [u64; FLIGHT_LANES],
    pub(super) state: [u64; FLIGHT_LANES],
    /// 1 where the lane's end is not known to be the box's exit (its ray started inside the box).
    /// (All lane columns are 64-bit: the loop over them vectorises.)
    pub(super) clip_on_exit: [u64; FLIGHT_LANES],
}

impl FlightLanes {
    /// Lane `i` tracks `ray` from `t` to `t1` with stream `key` (`exit_known`: `t1` is at most the
    /// field's exit).
    fn set(&mut self, i: usize, ray: &RaySegment, key: u64, t: f64, t1: f64, exit_known: bool) {
        for a in 0..3 {
            (self.o[a][i], self.d[a][i]) = (ray.o[a], ray.d[a]);
        }
        (self.t[i], self.t1[i], self.key[i]) = (t, t1, key);
        self.state[i] = LANE_RUNNING;
        self.clip_on_exit[i] = !exit_known as u64;
    }
}

impl ContinuousField {
    /// [`Self::sample_free_flight`] of each ray of `rays` (in packets of [`FLIGHT_LANES`]; `rays`, `keys`
    /// and `out` as long as the shortest of them), ray i
    /// drawing its k-th tentative collision (k = 1, 2, ...) from `stream_bits(keys[i], 1 + k)`: the
    /// same hits as one ray at a time, into `out`. Where the field has one majorant (a cloud of even
    /// density) the rays step together, one tentative collision each per step, in SIMD lanes: a dense
    /// cloud's paths make most of their events in the field, two free flights each (the scattered
    /// ray and its shadow ray), and a packet's rays all fly at once.
    pub fn sample_free_flights(
        &self,
        rays: &[RaySegment],
        keys: &[u64],
        out: &mut [Option<FieldHit>],
    ) {
        let n = rays.len().min(keys.len()).min(out.len());
        for a in (0..n).step_by(FLIGHT_LANES) {
            let b = (a + FLIGHT_LANES).min(n);
            let lockstep = self.flies_in_lockstep();
            self.sample_packet_flights_with(&rays[a..b], &keys[a..b], &mut out[a..b], lockstep);
        }
    }

    /// [`Self::sample_free_flights`] of at most [`FLIGHT_LANES`] rays, in lockstep where `lockstep` (and
    /// the field has one majorant) whatever the CPU (the tests run it without AVX-512 too, lane by lane).
    pub(super) fn sample_packet_flights_with(
        &self,
        rays: &[RaySegment],
        keys: &[u64],
        out: &mut [Option<FieldHit>],
        lockstep: bool,
    ) {
        let n = rays.len().min(FLIGHT_LANES);
        let one_by_one = |i: usize| {
            let mut k = 0u64;
            self.sample_free_flight(&rays[i], || {
                k += 1;
                stream_bits(keys[i], 1 + k)
            })
        };
        // In lockstep only where 64-bit lanes multiply and convert natively (AVX-512 DQ): AVX2 runs
        // the loop lane by lane, each ray stepping as long as the packet's slowest: slower than one
        // ray at a time.
        let Some(m) = self.uniform_majorant.filter(|_| n > 1 && lockstep) else {
            (0..n).for_each(|i| out[i] = one_by_one(i));
            return;
        };
        let mut lanes = FlightLanes::default();
        let bounds = &self.frame.bounds;
        for (i, ray) in rays.iter().enumerate().take(n) {
            let Some((t, t1, exit_known)) = self.uniform_span(ray) else {
                continue;
            };
            lanes.set(i, ray, keys[i], t, t1, exit_known);
        }
        self.step_lanes(m, &mut lanes);
        for (i, ray) in rays.iter().enumerate().take(n) {
            out[i] = match lanes.state[i] {
                LANE_REAL => Some(FieldHit {
                    t: lanes.t[i],
                    cell: lanes.cell[i] as usize,
                }),
                LANE_OUTSIDE => {
                    // Its first tentative collision outside the box: the rest as one ray does it.
                    let t = lanes.t[i];
                    let t1 = bounds
                        .clip(ray)
                        .map_or(t, |(_, exit)| exit.min(lanes.t1[i]));
                    let mut k = lanes.k[i];
                    #[cfg(test)]
                    super::tests::CONTINUED
                        .fetch_add((t < t1) as usize, std::sync::atomic::Ordering::Relaxed);
                    (t < t1)
                        .then(|| {
                            self.uniform_flight_from::<true>(ray, m, t, t1, true, || {
                                k += 1;
                                stream_bits(keys[i], 1 + k)
                            })
                        })
                        .flatten()
                }
                _ => None,
            };
        }
    }

    /// Whether [`Self::sample_free_flights`] steps its rays together (else it flies them one by one,
    /// as a caller can as well).
    pub fn flies_in_lockstep(&self) -> bool {
        self.uniform_majorant.is_some() && lockstep_simd()
    }

    /// The lanes' delta tracking against the majorant `m`, every running lane one tentative collision
    /// per step, until none runs (a lane stops at its site, past its end, or at its first tentative
    /// collision outside the box when its end is not the box's exit: [`FlightLanes`]).
    pub(super) fn step_lanes(&self, m: f64, lanes: &mut FlightLanes) {
        #[cfg(target_arch = "x86_64")]
        if lockstep_simd() {
            // SAFETY: the CPU has AVX-512 F, DQ and VL (`lockstep_simd`).
            return unsafe { self.step_lanes_avx512(m, lanes) };
        }
        self.step_lanes_with(m, lanes)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
    pub(super) unsafe fn step_lanes_avx512(&self, m: f64, lanes: &mut FlightLanes) {
        self.step_lanes_with(m, lanes)
    }

    /// [`Self::step_lanes`] as straight-line code over the lanes (no call, no early exit per lane), which
    /// the compiler vectorises for the instruction set it is compiled for. Each lane does exactly what
    /// [`Self::uniform_flight_from`] does with the same draws.
    #[inline(always)]
    pub(super) fn step_lanes_with(&self, m: f64, l: &mut FlightLanes) {
        let inv_m = 1.0 / m;
        let lo = self.frame.bounds.lo;
        let ic = self.inv_cell;
        let dims = self.frame.dims.map(|d| d as u64);
        let df = dims.map(|d| d as f64);
        let last = self.sigma.len().saturating_sub(1) as u64;
        if self.sigma.is_empty() {
            return;
        }
        let mut k = 1u64;
        loop {
            let mut running = 0u64;
            for i in 0..FLIGHT_LANES {
                let bits = stream_bits(l.key[i], 1 + k);
                let t = l.t[i] + exponential::<true>(bits) * inv_m;
                let gx = (l.o[0][i] + t * l.d[0][i] - lo[0]) * ic[0];
                let gy = (l.o[1][i] + t * l.d[1][i] - lo[1]) * ic[1];
                let gz = (l.o[2][i] + t * l.d[2][i] - lo[2]) * ic[2];
                let inside = (gx >= 0.0)
                    & (gx < df[0])
                    & (gy >= 0.0)
                    & (gy < df[1])
                    & (gz >= 0.0)
                    & (gz < df[2]);
                // Converted only inside, where 0 <= g < dims (a saturating cast is not vectorised).
                let index =
                    |g: f64| unsafe { (if inside { g } else { 0.0 }).to_int_unchecked::<i64>() }
                        as u64;
                let cell = (index(gz) * dims[1] + index(gy)) * dims[0] + index(gx);
                let cell = if inside { cell.min(last) } else { 0 };
                // SAFETY: `cell` <= last < sigma.len() (not empty, checked above).
                let sigma = unsafe { *self.sigma.get_unchecked(cell as usize) } as f64;
                let u = (bits as u32) as f64 * (1.0 / 4294967296.0);
                let real = inside & (u * m < sigma);
                let next = if t >= l.t1[i] {
                    LANE_NONE
                } else if real {
                    LANE_REAL
                } else if !inside & (l.clip_on_exit[i] != 0) {
                    LANE_OUTSIDE
                } else {
                    LANE_RUNNING
                };
                let live = l.state[i] == LANE_RUNNING;
                l.t[i] = if live { t } else { l.t[i] };
                l.cell[i] = if live { cell } else { l.cell[i] };
                l.k[i] = if live { k } else { l.k[i] };
                l.state[i] = if live { next } else { l.state[i] };
                running |= (live & (next == LANE_RUNNING)) as u64;
            }
            if running == 0 {
                return;
            }
            k += 1;
        }
    }
}
