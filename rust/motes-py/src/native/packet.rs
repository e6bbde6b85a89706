//! One packet of the native render path: the ray/hit record [`motes_packet`] reads and writes (module
//! docs of `crate::native`), its lanes, and the operations on them.

use super::*;

/// The record of one packet.
struct Record {
    args: *mut u8,
    width: usize,
}

impl Record {
    fn ptr(&self, f: Field, lane: usize) -> *mut u32 {
        // SAFETY (callers): the record holds 20 fields of `width` 4-byte lanes.
        unsafe { self.args.add((f as usize * self.width + lane) * 4) as *mut u32 }
    }
    fn f(&self, f: Field, lane: usize) -> f32 {
        f32::from_bits(self.u(f, lane))
    }
    fn u(&self, f: Field, lane: usize) -> u32 {
        unsafe { self.ptr(f, lane).read_unaligned() }
    }
    fn set_f(&self, f: Field, lane: usize, x: f64) {
        self.set_u(f, lane, (x as f32).to_bits());
    }
    fn set_u(&self, f: Field, lane: usize, x: u32) {
        unsafe { self.ptr(f, lane).write_unaligned(x) }
    }
    fn v3(&self, a: Field, lane: usize) -> [f32; 3] {
        let k = a as usize;
        let at = |i: usize| {
            f32::from_bits(unsafe {
                self.args
                    .add(((k + i) * self.width + lane) * 4)
                    .cast::<u32>()
                    .read_unaligned()
            })
        };
        [at(0), at(1), at(2)]
    }
    /// Marks the lane as returned (drjit-core reads geom_id != -1 as a hit).
    fn returned(&self, lane: usize) {
        self.set_u(Field::GeomId, lane, 0);
        self.set_u(Field::InstId, lane, u32::MAX);
    }
}

/// The packet's lanes as an array of `N` (inactive: None), without allocating. A loop over the
/// `width` lanes, not `array::from_fn`: that one was unrolled over all 16 lanes, building each in a
/// temporary and copying it. `N` is 1 for the scalar variants' one-ray calls, so that they neither
/// clear nor copy sixteen lanes' arrays (3 % of a scalar render in memset and memmove alone).
#[inline(always)]
fn lanes<T: Copy, const N: usize>(width: usize, f: impl Fn(usize) -> Option<T>) -> [Option<T>; N] {
    let mut out = [None; N];
    for (i, x) in out.iter_mut().enumerate().take(width) {
        *x = f(i);
    }
    out
}

/// Per-lane wavelengths from the packed `mask`/`id` fields.
fn lane_lambda(r: &Record, lane: usize, out: &mut [f64]) {
    let words = [r.u(Field::Mask, lane), r.u(Field::Id, lane)];
    for (c, x) in out.iter_mut().enumerate() {
        let w = words[c / 2] >> (16 * (c % 2)) & 0xFFFF;
        *x = w as f64 / LAMBDA_UNITS_PER_NM;
    }
}

/// Clear the upper halves of the vector registers (`vzeroupper`) on entry from Mitsuba's kernels.
///
/// Why: the symbolic LLVM kernels run AVX-512/AVX2 code and call the packet function with the upper
/// halves of the vector registers still in use; the core is built for baseline x86-64, whose SSE
/// instructions then each wait on (and merge into) the whole wide register. Clearing that state once
/// per packet made the sparse render 24 % faster (`scripts/bench/render_seconds.py sparse`, 0.305 ->
/// 0.233 s, BENCHMARKS 10.1); the traversal benchmark, which has no AVX code around it, never saw the
/// cost. Nothing is lost: a caller's vector registers are not preserved across a C call anyway.
#[inline(always)]
fn clear_upper_vector_state() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: AVX is present (checked); vzeroupper only clears call-clobbered register halves.
        unsafe { std::arch::x86_64::_mm256_zeroupper() };
    }
}

/// # Safety
/// `medium` comes from [`handle`] and is alive; `args` holds a record of `width` ≤ 16 lanes; `valid` is
/// null or holds `width` entries; `lambda` is null or holds `channels` ≤ 4 values.
pub unsafe extern "C" fn motes_packet(
    medium: *const c_void,
    op: u32,
    width: u32,
    valid: *const i32,
    args: *mut u8,
    lambda: *const f64,
    channels: u32,
) {
    clear_upper_vector_state();
    let Some(m) = core(medium) else {
        return; // a pending medium (no particles yet): no lane is written, every ray passes
    };
    let ch = (channels as usize).clamp(1, 4);
    // Scalar variants call with one lane: arrays of one, not of sixteen (see `lanes`).
    if width == 1 {
        run::<1>(m, op, 1, valid, args, lambda, ch);
    } else {
        run::<PACKET_LANES>(
            m,
            op,
            (width as usize).min(PACKET_LANES),
            valid,
            args,
            lambda,
            ch,
        );
    }
}

/// [`motes_packet`] for packets of at most `N` lanes.
///
/// # Safety
/// As for [`motes_packet`], with `width` ≤ `N`.
#[inline(always)]
unsafe fn run<const N: usize>(
    m: &DiscreteMedium,
    op: u32,
    width: usize,
    valid: *const i32,
    args: *mut u8,
    lambda: *const f64,
    ch: usize,
) {
    let r = Record { args, width };
    // The active lanes as bits (one test per lane, not a call through a closure per use).
    let active = (0..width).fold(0u32, |m, i| {
        m | ((valid.is_null() || *valid.add(i) != 0) as u32) << i
    });
    let is_active = |i: usize| active >> i & 1 != 0;
    // (Made only where the lanes carry their own: zeroed for every call it was a memset per packet.)
    let mut own: [[f64; 4]; N];
    let lam: &[f64] = if lambda.is_null() {
        own = [[0.0f64; 4]; N];
        let flat = own.as_flattened_mut();
        for i in (0..width).filter(|&i| is_active(i)) {
            lane_lambda(&r, i, &mut flat[i * ch..(i + 1) * ch]);
        }
        &flat[..width * ch]
    } else {
        std::slice::from_raw_parts(lambda, ch)
    };
    let packet = Packet::<N> {
        m,
        r: &r,
        width,
        active,
        lam,
        ch,
    };
    match op {
        FREE_FLIGHT => packet.free_flights(),
        PHASE_SAMPLE => packet.phase_sample(false),
        PHASE_SAMPLE_DIRECTION => packet.phase_sample(true),
        PHASE_EVAL => packet.phase_eval(),
        PHASE_MUELLER => packet.phase_mueller(),
        _ => {}
    }
}

/// One call's packet: the medium, the ray/hit record of `width` lanes, which lanes are active, and the
/// wavelengths (`ch` per lane, or `ch` shared).
#[derive(Clone, Copy)]
struct Packet<'a, const N: usize> {
    m: &'a DiscreteMedium,
    r: &'a Record,
    width: usize,
    /// Bit i: lane i is active.
    active: u32,
    lam: &'a [f64],
    ch: usize,
}

impl<const N: usize> Packet<'_, N> {
    #[inline(always)]
    fn is_active(&self, i: usize) -> bool {
        self.active >> i & 1 != 0
    }

    /// `f(lane)` of each active lane (inactive: None).
    fn gather<T: Copy>(&self, f: impl Fn(usize) -> T) -> [Option<T>; N] {
        lanes(self.width, |i| self.is_active(i).then(|| f(i)))
    }

    /// Marks each active lane as returned, then `write`s its results.
    fn answer(&self, write: impl Fn(usize)) {
        for i in (0..self.width).filter(|&i| self.is_active(i)) {
            self.r.returned(i);
            write(i);
        }
    }

    /// The packet's free flights: each hit lane's tfar becomes its site's distance.
    fn free_flights(&self) {
        let rays: [Option<PacketRay>; N] = self.gather(|i| {
            (
                self.r.v3(Field::Ox, i),
                self.r.v3(Field::Dx, i),
                self.r.f(Field::Tfar, i),
            )
        });
        let mut t = [None; N];
        self.m
            .packet_free_flights(&rays[..self.width], self.lam, self.ch, &mut t);
        for (i, t) in t.iter().enumerate().take(self.width) {
            if let Some(t) = t {
                self.r.set_f(Field::Tfar, i, *t);
                self.r.returned(i);
            }
        }
    }

    /// Sample the phase functions of the packet's events (layout in the module docs); `direction_only`:
    /// the direction and pdf, whatever the channels (`PHASE_SAMPLE_DIRECTION`).
    fn phase_sample(&self, direction_only: bool) {
        let l = self.gather(|i| PhaseSampleLane {
            p: self.r.v3(Field::Ox, i),
            wi: self.r.v3(Field::Dx, i),
            u1: self.r.f(Field::Tnear, i) as f64,
            u2: [
                self.r.f(Field::Time, i) as f64,
                self.r.f(Field::Tfar, i) as f64,
            ],
        });
        let (mut wo, mut weight, mut pdf) = ([[0.0; 3]; N], [[0.0; 4]; N], [0.0; N]);
        let weight = weight.as_flattened_mut();
        self.m.packet_phase_sample(
            &l[..self.width],
            self.lam,
            self.ch,
            &mut wo,
            &mut weight[..self.width * self.ch],
            &mut pdf,
            // Four weights do not fit the record, nor do matrices: C++ evaluates the direction next.
            direction_only || self.ch > 3,
        );
        let ch = self.ch;
        self.answer(|i| {
            if ch <= 3 && !direction_only {
                let [x, y] = octahedral(wo[i]);
                self.r.set_f(Field::Tfar, i, x);
                self.r.set_f(Field::U, i, y);
                for (c, f) in [Field::V, Field::PrimId, Field::GeomId]
                    .into_iter()
                    .enumerate()
                {
                    let w = if c < ch { weight[i * ch + c] } else { 0.0 };
                    // Finite and not negative: never the miss marker in geom_id.
                    self.r
                        .set_f(f, i, if w.is_finite() { w.max(0.0) } else { 0.0 });
                }
                self.r.set_f(Field::InstId, i, pdf[i]);
            } else {
                self.r.set_f(Field::Tfar, i, wo[i][0]);
                self.r.set_f(Field::U, i, wo[i][1]);
                self.r.set_f(Field::V, i, wo[i][2]);
                self.r.set_f(Field::PrimId, i, pdf[i]);
            }
        });
    }

    /// Lane `i` of an evaluation (`PHASE_EVAL`, `PHASE_MUELLER`: module docs).
    fn eval_lane(&self, i: usize) -> PhaseEvalLane {
        PhaseEvalLane {
            p: self.r.v3(Field::Ox, i),
            wi: self.r.v3(Field::Dx, i),
            wo: [
                self.r.f(Field::Tnear, i),
                self.r.f(Field::Time, i),
                self.r.f(Field::Tfar, i),
            ],
        }
    }

    /// Evaluate the phase functions of the packet's events: values per channel, pdf in inst_id.
    fn phase_eval(&self) {
        let l = self.gather(|i| self.eval_lane(i));
        let (mut v, mut pdf) = ([[0.0; 4]; N], [0.0; N]);
        let v = v.as_flattened_mut();
        self.m
            .packet_phase_eval(&l[..self.width], self.lam, self.ch, v, &mut pdf);
        self.answer(|i| {
            write_channels(self.r, i, &v[i * self.ch..(i + 1) * self.ch]);
            self.r.set_f(Field::InstId, i, pdf[i]);
        });
    }
}

impl<const N: usize> Packet<'_, N> {
    /// The Mueller elements of the packet's events (layout in the module docs): element `flags` of each
    /// channel, or all four of the only channel.
    fn phase_mueller(&self) {
        let l = self.gather(|i| self.eval_lane(i));
        let first = (0..self.width).find(|&i| self.is_active(i));
        let element = first
            .map_or(0, |i| self.r.u(Field::Flags, i) as usize)
            .min(3);
        let (mut v, mut pdf) = ([[[0.0; 4]; 4]; N], [0.0; N]);
        let v = v.as_flattened_mut();
        self.m.packet_phase_mueller(
            &l[..self.width],
            self.lam,
            self.ch,
            element > 0,
            &mut v[..self.width * self.ch],
            &mut pdf,
        );
        let ch = self.ch;
        self.answer(|i| {
            let rows = &v[i * ch..(i + 1) * ch];
            if ch == 1 {
                write_channels(self.r, i, &rows[0]);
            } else {
                let e: [f64; 4] = std::array::from_fn(|c| rows.get(c).map_or(0.0, |r| r[element]));
                write_channels(self.r, i, &e[..ch]);
            }
            self.r.set_f(Field::InstId, i, pdf[i]);
        });
    }
}

/// Up to four channel values into tfar, u, v, prim_id.
fn write_channels(r: &Record, lane: usize, v: &[f64]) {
    for (x, f) in v
        .iter()
        .zip([Field::Tfar, Field::U, Field::V, Field::PrimId])
    {
        r.set_f(f, lane, *x);
    }
}
