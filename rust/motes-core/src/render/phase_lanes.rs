//! A packet's phase-function samples side by side (issue 25).
//!
//! Most events of a dense cloud are one particle (a field's site, a grain hit alone) whose tables at
//! the channels' wavelengths share their nodes, and an RGB render asks at exactly the tabulated
//! wavelengths. For those lanes the whole sample, from the channel choice through the table's inverse
//! CDF to the weights and the throughput after the bounce, is the same arithmetic on per-lane data:
//! here it runs eight lanes a vector in AVX-512 intrinsics, the tables read by gathers at each lane's
//! own addresses (the compiler did not vectorise the same loop written lane by lane, which stays as
//! the reference the tests hold the SIMD to). One lane at a time the sample is a chain of dependent
//! loads, a square root and four divisions per lane.
//!
//! Each lane computes exactly what `DiscreteMedium::mixture_sample` and the weights after it compute
//! for the same inputs, bit for bit (the same operations in the same order; no fused multiply-add).
//! A sample that falls in a directory bucket of more than [`SEARCH_SPAN`] nodes (the phase function's
//! flat back half) halves the bucket first, a gather per halving, where the one-lane path
//! binary-searches it: the same segment, the one the draw lies in. Only lanes whose draws are not
//! numbers ([`PhaseLanes::is_alone`]) are left to the caller. The direction itself (a sine and cosine
//! in single precision) stays with the caller.

use crate::ensemble::phase_table::{SamplingView, CDF_BUCKETS};
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;
use std::f64::consts::PI;

/// Lanes of one packet (`crate::render::discrete::PACKET_LANES`).
pub(crate) const LANES: usize = 16;
/// Channels a lane can carry (`crate::render::discrete::MAX_CHANNELS`).
pub(crate) const CHANNELS: usize = 4;
/// Nodes of a directory bucket the straight-line search counts (the scalar search counts up to eight
/// too, and binary-searches longer buckets; here they are halved down to this first).
const SEARCH_SPAN: usize = 8;

/// Eight lanes of a column from lane `$o` on, as f64.
#[cfg(target_arch = "x86_64")]
macro_rules! lanes_f {
    ($col:expr, $o:expr) => {
        _mm512_loadu_pd($col.as_ptr().add($o))
    };
}

/// Eight lanes of a column from lane `$o` on, as 64-bit words.
#[cfg(target_arch = "x86_64")]
macro_rules! lanes_u {
    ($col:expr, $o:expr) => {
        _mm512_loadu_si512($col.as_ptr().add($o).cast())
    };
}

/// The f64 gathered at each lane's address (bytes).
#[cfg(target_arch = "x86_64")]
macro_rules! gather_f {
    ($addr:expr) => {
        _mm512_i64gather_pd::<1>($addr, std::ptr::null::<u8>().cast())
    };
}

/// The lanes' inputs and results, one array per quantity (structure of arrays, every column 64-bit:
/// a vector load per column). Lanes `n..LANES` and channels
/// `channels..CHANNELS` must hold valid tables too (copies of a used one): the loop reads every
/// lane's tables.
#[derive(Clone, Copy)]
pub(crate) struct PhaseLanes {
    pub n: usize,
    pub channels: usize,
    /// The channel's random number and the one for μ.
    pub u1: [f64; LANES],
    pub u2: [f64; LANES],
    /// Channel probabilities π_c (0 beyond `channels`).
    pub pi: [[f64; LANES]; CHANNELS],
    /// Per channel (1 or 0): does the particle scatter (its weight times its albedo > 0, as the
    /// values see it), and may the sample pick it (the same product as the pick computes it).
    pub scatters: [[u64; LANES]; CHANNELS],
    pub pickable: [[u64; LANES]; CHANNELS],
    /// Per channel the particle's table at the channel's wavelength (all on the same nodes): the
    /// addresses of its nodes and of its sampling directory; per lane its last node's index.
    pub nodes: [[*const f64; LANES]; CHANNELS],
    pub ranges: [[*const u64; LANES]; CHANNELS],
    pub last: [u64; LANES],
    /// Per channel: the path's throughput into the event (1 where unknown) and the site's albedo.
    pub t_in: [[f64; LANES]; CHANNELS],
    pub albedo: [[f64; LANES]; CHANNELS],
    /// Results: μ, the weights (value / pdf times the albedo), the pdf, the throughput after the
    /// bounce; `ok` 0 for a null sample; `alone` 1 for a lane the caller samples on its own.
    pub mu: [f64; LANES],
    pub weight: [[f64; LANES]; CHANNELS],
    pub pdf: [f64; LANES],
    pub t_out: [[f64; LANES]; CHANNELS],
    pub ok: [u64; LANES],
    pub alone: [u64; LANES],
}

impl PhaseLanes {
    /// Lanes reading `table` everywhere until set.
    pub fn new(channels: usize, table: SamplingView) -> Self {
        PhaseLanes {
            n: 0,
            channels,
            u1: [0.0; LANES],
            u2: [0.0; LANES],
            pi: [[0.0; LANES]; CHANNELS],
            scatters: [[0; LANES]; CHANNELS],
            pickable: [[0; LANES]; CHANNELS],
            nodes: [[table.nodes.cast(); LANES]; CHANNELS],
            ranges: [[table.ranges.cast(); LANES]; CHANNELS],
            last: [table.n_nodes as u64 - 1; LANES],
            t_in: [[1.0; LANES]; CHANNELS],
            albedo: [[1.0; LANES]; CHANNELS],
            mu: [0.0; LANES],
            weight: [[0.0; LANES]; CHANNELS],
            pdf: [0.0; LANES],
            t_out: [[0.0; LANES]; CHANNELS],
            ok: [0; LANES],
            alone: [0; LANES],
        }
    }

    /// Channel `c` of lane `k` reads `table`.
    pub fn set_table(&mut self, c: usize, k: usize, table: SamplingView) {
        self.nodes[c][k] = table.nodes.cast();
        self.ranges[c][k] = table.ranges.cast();
        self.last[k] = table.n_nodes as u64 - 1;
    }

    /// Whether [`Self::sample`] runs in SIMD here (AVX-512 F/DQ/VL): elsewhere a packet's lanes are
    /// better sampled one by one (the lane loop in scalar code does every step for every channel).
    pub fn available() -> bool {
        crate::simd::lockstep_simd()
    }

    /// Sample lanes `0..n` (`force_scalar`: the lane loop in scalar code, for tests).
    ///
    /// # Safety
    /// Every lane's tables (all `LANES` lanes and `CHANNELS` channels, used or not) are alive: set by
    /// [`Self::new`] and [`Self::set_table`] from tables that outlive this call, each lane's channels
    /// on the same nodes (the one `last` per lane).
    pub unsafe fn sample(&mut self, force_scalar: bool) {
        #[cfg(target_arch = "x86_64")]
        if !force_scalar && Self::available() {
            // SAFETY: the CPU has AVX-512 F/DQ/VL (`lockstep_simd`); the tables: the caller's.
            return unsafe { self.sample_avx512() };
        }
        // SAFETY: the caller's.
        unsafe { self.sample_with() };
    }

    /// [`Self::sample_with`] in AVX-512, eight lanes a vector: the same operations in the same order
    /// (IEEE addition, multiplication, division and square root round alike in both), the tables
    /// read by gathers at each lane's own addresses.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
    unsafe fn sample_avx512(&mut self) {
        let n_ch = self.channels.clamp(1, CHANNELS) as u64;
        for h in 0..self.n.div_ceil(8) {
            let o = 8 * h;
            // SAFETY (all below): lanes o..o + 8 lie within LANES; the tables: the caller's.
            let (pickable, nodes, ranges) = unsafe { self.channel_tables(o, n_ch) };
            let last = unsafe { lanes_u!(self.last, o) };
            // The table's inverse CDF.
            let v = unsafe {
                _mm512_min_pd(
                    _mm512_max_pd(lanes_f!(self.u2, o), _mm512_setzero_pd()),
                    _mm512_set1_pd(1.0),
                )
            };
            let seg = unsafe { segment_avx512(nodes, ranges, last, v) };
            let alone = unsafe {
                _mm512_cmp_pd_mask::<_CMP_UNORD_Q>(lanes_f!(self.u1, o), lanes_f!(self.u1, o))
                    | _mm512_cmp_pd_mask::<_CMP_UNORD_Q>(lanes_f!(self.u2, o), lanes_f!(self.u2, o))
            };
            let (t, mu) = unsafe { solve_avx512(nodes, seg, v) };
            // Values, pdf, weights and the throughput after the bounce.
            let (values, pdf) = unsafe { self.values_avx512(o, seg, t, n_ch) };
            unsafe { self.store_avx512(o, (values, pdf), (pickable, mu, alone), n_ch) };
        }
    }

    /// The channel that lanes `o..o + 8` sample (those whose interval of π ends at or below u1), and
    /// its `pickable` flag, table nodes and sampling directory per lane.
    ///
    /// # Safety
    /// As [`Self::sample`]; `o + 8 <= LANES`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
    #[inline]
    unsafe fn channel_tables(&self, o: usize, n_ch: u64) -> (__m512i, __m512i, __m512i) {
        let zero = _mm512_setzero_pd();
        let (izero, ione) = (_mm512_setzero_si512(), _mm512_set1_epi64(1));
        let u = _mm512_min_pd(
            _mm512_max_pd(lanes_f!(self.u1, o), zero),
            _mm512_set1_pd(1.0 - f64::EPSILON),
        );
        let mut acc = zero;
        let mut below = izero;
        for c in 0..CHANNELS {
            acc = _mm512_add_pd(acc, lanes_f!(self.pi[c], o));
            if (c as u64) < n_ch {
                let m = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(acc, u);
                below = _mm512_mask_add_epi64(below, m, below, ione);
            }
        }
        let c = _mm512_min_epu64(below, _mm512_set1_epi64(n_ch as i64 - 1));
        let is = |k: i64| _mm512_cmpeq_epi64_mask(c, _mm512_set1_epi64(k));
        let (m0, m1, m2) = (is(0), is(1), is(2));
        let pick = |x: [__m512i; CHANNELS]| {
            let r = _mm512_mask_blend_epi64(m2, x[3], x[2]);
            let r = _mm512_mask_blend_epi64(m1, r, x[1]);
            _mm512_mask_blend_epi64(m0, r, x[0])
        };
        let pickable = pick([0, 1, 2, 3].map(|k| lanes_u!(self.pickable[k], o)));
        let nodes = pick([0, 1, 2, 3].map(|k| lanes_u!(self.nodes[k], o)));
        let ranges = pick([0, 1, 2, 3].map(|k| lanes_u!(self.ranges[k], o)));
        (pickable, nodes, ranges)
    }

    /// Each channel's phase function at the lanes' μ (`t` of the way through segment `seg`; 0 where
    /// the particle does not scatter in that channel), and the pdf Σ π_c f_c.
    ///
    /// # Safety
    /// As [`Self::sample`]; `o + 8 <= LANES`; `seg` within every lane's tables.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
    #[inline]
    #[allow(clippy::needless_range_loop)] // channel by channel, as the lane loop
    unsafe fn values_avx512(
        &self,
        o: usize,
        seg: __m512i,
        t: __m512d,
        n_ch: u64,
    ) -> ([__m512d; CHANNELS], __m512d) {
        let (zero, izero) = (_mm512_setzero_pd(), _mm512_setzero_si512());
        let mut values = [zero; CHANNELS];
        let mut pdf = zero;
        let seg24 = times24(seg);
        for k in 0..CHANNELS {
            let bk = _mm512_add_epi64(lanes_u!(self.nodes[k], o), seg24);
            let fa = gather_f!(_mm512_add_epi64(bk, _mm512_set1_epi64(16)));
            let fb = gather_f!(_mm512_add_epi64(bk, _mm512_set1_epi64(40)));
            let fv = _mm512_add_pd(fa, _mm512_mul_pd(t, _mm512_sub_pd(fb, fa)));
            let scatters = _mm512_cmpneq_epi64_mask(lanes_u!(self.scatters[k], o), izero);
            let used = if (k as u64) < n_ch { scatters } else { 0 };
            values[k] = _mm512_maskz_mov_pd(used, fv);
            pdf = _mm512_add_pd(pdf, _mm512_mul_pd(lanes_f!(self.pi[k], o), values[k]));
        }
        (values, pdf)
    }

    /// Lanes `o..o + 8`'s results from their values and pdf: the weights (times the albedo), the
    /// throughput after the bounce, μ, the pdf, whether each is a sample (`pickable`, pdf > 0) and
    /// whether it is left alone.
    ///
    /// # Safety
    /// `o + 8 <= LANES`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
    #[inline]
    #[allow(clippy::needless_range_loop)] // channel by channel, as the lane loop
    unsafe fn store_avx512(
        &mut self,
        o: usize,
        (values, pdf): ([__m512d; CHANNELS], __m512d),
        (pickable, mu, alone): (__m512i, __m512d, __mmask8),
        n_ch: u64,
    ) {
        let (zero, one) = (_mm512_setzero_pd(), _mm512_set1_pd(1.0));
        let (izero, ione) = (_mm512_setzero_si512(), _mm512_set1_epi64(1));
        let ok =
            _mm512_cmpneq_epi64_mask(pickable, izero) & _mm512_cmp_pd_mask::<_CMP_GT_OQ>(pdf, zero);
        let inv = _mm512_div_pd(one, pdf);
        let mut out = [zero; CHANNELS];
        let mut total = zero;
        for k in 0..CHANNELS {
            let w = _mm512_mul_pd(values[k], inv);
            let x = _mm512_mul_pd(lanes_f!(self.t_in[k], o), w);
            let finite =
                _mm512_cmp_pd_mask::<_CMP_LT_OQ>(_mm512_abs_pd(x), _mm512_set1_pd(f64::INFINITY));
            let keep = finite & _mm512_cmp_pd_mask::<_CMP_GT_OQ>(x, zero);
            out[k] = _mm512_maskz_mov_pd(if (k as u64) < n_ch { keep } else { 0 }, x);
            total = _mm512_add_pd(total, out[k]);
            _mm512_storeu_pd(
                self.weight[k].as_mut_ptr().add(o),
                _mm512_mul_pd(w, lanes_f!(self.albedo[k], o)),
            );
        }
        let inv_total = _mm512_maskz_mov_pd(
            _mm512_cmp_pd_mask::<_CMP_GT_OQ>(total, zero),
            _mm512_div_pd(one, total),
        );
        for k in 0..CHANNELS {
            _mm512_storeu_pd(
                self.t_out[k].as_mut_ptr().add(o),
                _mm512_mul_pd(out[k], inv_total),
            );
        }
        _mm512_storeu_pd(self.mu.as_mut_ptr().add(o), mu);
        _mm512_storeu_pd(self.pdf.as_mut_ptr().add(o), pdf);
        _mm512_storeu_si512(
            self.ok.as_mut_ptr().add(o).cast(),
            _mm512_maskz_mov_epi64(ok, ione),
        );
        _mm512_storeu_si512(
            self.alone.as_mut_ptr().add(o).cast(),
            _mm512_maskz_mov_epi64(alone, ione),
        );
    }

    /// Whether slot `k`'s draws are not numbers, so that the caller samples it on its own at once
    /// (the one-lane path decides what they give).
    pub fn is_alone(&self, k: usize) -> bool {
        self.u1[k].is_nan() || self.u2[k].is_nan()
    }

    /// Whether slot `k`'s draw for μ falls in a directory bucket of more than [`SEARCH_SPAN`] nodes
    /// (tests: that both kinds are sampled).
    ///
    /// # Safety
    /// As [`Self::sample`], for slot `k`.
    #[cfg(test)]
    pub unsafe fn in_long_bucket(&self, k: usize) -> bool {
        // SAFETY: the caller's.
        let (a, b) = unsafe { self.bucket_range(self.channel(k), k) };
        b < a || b - a > SEARCH_SPAN as u64
    }

    /// Slot `k`'s channel (as `DiscreteMedium::mixture_sample` picks it): those whose interval of π
    /// ends at or below u.
    fn channel(&self, k: usize) -> usize {
        let n_ch = self.channels.clamp(1, CHANNELS);
        let u = self.u1[k].clamp(0.0, 1.0 - f64::EPSILON);
        let (mut acc, mut below) = (0.0, 0usize);
        for c in 0..CHANNELS {
            acc += self.pi[c][k];
            below += ((acc <= u) & (c < n_ch)) as usize;
        }
        below.min(n_ch - 1)
    }

    /// The first and last segment of the directory bucket of slot `k`'s draw for μ in channel `c`'s
    /// table (`PhaseTable::sample_located`).
    ///
    /// # Safety
    /// As [`Self::sample`], for slot `k`.
    unsafe fn bucket_range(&self, c: usize, k: usize) -> (u64, u64) {
        let v = self.u2[k].clamp(0.0, 1.0);
        let bucket = ((v * CDF_BUCKETS as f64) as usize).min(CDF_BUCKETS - 1);
        // SAFETY: the caller's; the directory has CDF_BUCKETS entries of two u32 (4-byte aligned).
        let ab = unsafe { self.ranges[c][k].add(bucket).read_unaligned() };
        (ab & 0xFFFF_FFFF, ab >> 32)
    }

    /// The loop over the lanes, one at a time: what [`Self::sample_avx512`] does eight lanes a vector
    /// (the reference the tests hold it to; no caller samples this way). Every read is in bounds for
    /// every lane: the bucket is clamped to the directory, the counted nodes to the last node, the
    /// segment to the last but one. A lane whose draws are not numbers is `alone` (the one-lane path
    /// decides what they give).
    ///
    /// # Safety
    /// As [`Self::sample`].
    unsafe fn sample_with(&mut self) {
        let n_ch = self.channels.clamp(1, CHANNELS) as u64;
        for i in 0..LANES {
            // SAFETY: the caller's.
            unsafe { self.sample_lane(i, n_ch) };
        }
    }

    /// Lane `i` of [`Self::sample_with`].
    ///
    /// # Safety
    /// As [`Self::sample`], for lane `i`.
    #[inline]
    unsafe fn sample_lane(&mut self, i: usize, n_ch: u64) {
        let c = self.channel(i);
        let (pickable, nodes, last) = (self.pickable[c][i], self.nodes[c][i], self.last[i]);
        let v = self.u2[i].clamp(0.0, 1.0);
        // SAFETY (reads): the caller's; nodes up to `last`.
        let seg = unsafe { self.segment(c, i, v) };
        let alone = self.u1[i].is_nan() | self.u2[i].is_nan();
        let (t, mu) = unsafe { solve(nodes, last, seg, v) };
        // Values in every channel at that μ (the tables share their nodes), the pdf Σ π_c f_c.
        let (values, pdf) = unsafe { self.values(i, seg, t, n_ch) };
        let ok = (pickable != 0) & (pdf > 0.0);
        let inv = 1.0 / pdf;
        // The throughput after the bounce (as `DiscreteMedium::event_phase_sample` computes it), then
        // the albedo.
        let mut out = [0.0; CHANNELS];
        let mut total = 0.0;
        for k in 0..CHANNELS {
            let w = values[k] * inv;
            let x = self.t_in[k][i] * w;
            out[k] = if ((k as u64) < n_ch) & x.is_finite() & (x > 0.0) {
                x
            } else {
                0.0
            };
            total += out[k];
            self.weight[k][i] = w * self.albedo[k][i];
        }
        let inv_total = if total > 0.0 { 1.0 / total } else { 0.0 };
        for k in 0..CHANNELS {
            self.t_out[k][i] = out[k] * inv_total;
        }
        self.mu[i] = mu;
        self.pdf[i] = pdf;
        self.ok[i] = ok as u64;
        self.alone[i] = alone as u64;
    }

    /// The segment of lane `i`'s table in channel `c` that its draw `v` for μ falls in: the
    /// directory's bucket of v, a long bucket halved first (as the vectors do), the nodes left counted.
    ///
    /// # Safety
    /// As [`Self::sample`], for lane `i`.
    #[inline]
    unsafe fn segment(&self, c: usize, i: usize, v: f64) -> u64 {
        let (nodes, last) = (self.nodes[c][i], self.last[i]);
        // SAFETY: the caller's.
        let (a, b) = unsafe { self.bucket_range(c, i) };
        // The bucket's nodes a + 1 ..= b.
        let (mut lo, mut len) = (a + 1, if b >= a { b - a } else { 0 });
        while len > SEARCH_SPAN as u64 {
            let (half, mid) = (len / 2, lo + len / 2);
            if unsafe { node(nodes, last, mid, 0) } <= v {
                (lo, len) = (mid + 1, len - half - 1);
            } else {
                len = half;
            }
        }
        let mut count = lo - (a + 1);
        for j in 0..SEARCH_SPAN as u64 {
            count += ((j < len) & (unsafe { node(nodes, last, lo + j, 0) } <= v)) as u64;
        }
        (a.min(last) + count).min(last - 1)
    }

    /// Lane `i`'s phase function in every channel at t of the way through segment `seg` (0 where
    /// the particle does not scatter in that channel), and the pdf Σ π_c f_c.
    ///
    /// # Safety
    /// As [`Self::sample`], for lane `i`; `seg` below its last node.
    #[inline]
    #[allow(clippy::needless_range_loop)] // channel by channel: the SIMD layout
    unsafe fn values(&self, i: usize, seg: u64, t: f64, n_ch: u64) -> ([f64; CHANNELS], f64) {
        let last = self.last[i];
        let mut values = [0.0; CHANNELS];
        let mut pdf = 0.0;
        for k in 0..CHANNELS {
            let at = self.nodes[k][i];
            let (fa, fb) = unsafe { (node(at, last, seg, 2), node(at, last, seg + 1, 2)) };
            let f = fa + t * (fb - fa);
            values[k] = if (self.scatters[k][i] != 0) & ((k as u64) < n_ch) {
                f
            } else {
                0.0
            };
            pdf += self.pi[k][i] * values[k];
        }
        (values, pdf)
    }
}

/// 24 x: the byte offset of node x (three f64 a node).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
#[inline]
fn times24(x: __m512i) -> __m512i {
    _mm512_add_epi64(_mm512_slli_epi64::<4>(x), _mm512_slli_epi64::<3>(x))
}

/// The segment of each lane's table (`nodes`, sampling directory `ranges`, last node `last`) that
/// its draw `v` for μ falls in: the directory's bucket of v, a long bucket halved down to
/// [`SEARCH_SPAN`] nodes (the nodes before `lo` at or below v, those from lo + len on above it), the
/// nodes left counted.
///
/// # Safety
/// As [`PhaseLanes::sample`], for every lane.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
#[inline]
unsafe fn segment_avx512(nodes: __m512i, ranges: __m512i, last: __m512i, v: __m512d) -> __m512i {
    let ione = _mm512_set1_epi64(1);
    let bucket = _mm512_min_epu64(
        _mm512_cvttpd_epu64(_mm512_mul_pd(v, _mm512_set1_pd(CDF_BUCKETS as f64))),
        _mm512_set1_epi64(CDF_BUCKETS as i64 - 1),
    );
    let ab = _mm512_i64gather_epi64::<1>(
        _mm512_add_epi64(ranges, _mm512_slli_epi64::<3>(bucket)),
        std::ptr::null::<u8>().cast(),
    );
    let a = _mm512_and_si512(ab, _mm512_set1_epi64(0xFFFF_FFFF));
    let b = _mm512_srli_epi64::<32>(ab);
    let cdf_at =
        |k: __m512i| gather_f!(_mm512_add_epi64(nodes, times24(_mm512_min_epu64(k, last))));
    // The bucket's nodes a + 1 ..= b.
    let mut lo = _mm512_add_epi64(a, ione);
    let mut len = _mm512_maskz_sub_epi64(_mm512_cmpge_epu64_mask(b, a), b, a);
    let span = _mm512_set1_epi64(SEARCH_SPAN as i64);
    loop {
        let long = _mm512_cmpgt_epu64_mask(len, span);
        if long == 0 {
            break;
        }
        let half = _mm512_srli_epi64::<1>(len);
        let mid = _mm512_add_epi64(lo, half);
        let le = long & _mm512_cmp_pd_mask::<_CMP_LE_OQ>(cdf_at(mid), v);
        lo = _mm512_mask_add_epi64(lo, le, mid, ione);
        len = _mm512_mask_sub_epi64(len, le, len, _mm512_add_epi64(half, ione));
        len = _mm512_mask_mov_epi64(len, long & !le, half);
    }
    let mut count = _mm512_sub_epi64(lo, _mm512_add_epi64(a, ione));
    for j in 0..SEARCH_SPAN as i64 {
        let valid = _mm512_cmpgt_epu64_mask(len, _mm512_set1_epi64(j));
        if valid == 0 {
            break; // (no lane's bucket holds another node: most buckets hold one to three)
        }
        let k = _mm512_add_epi64(lo, _mm512_set1_epi64(j));
        let le = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(cdf_at(k), v);
        count = _mm512_mask_add_epi64(count, valid & le, count, ione);
    }
    _mm512_min_epu64(
        _mm512_add_epi64(_mm512_min_epu64(a, last), count),
        _mm512_sub_epi64(last, ione),
    )
}

/// How far through its segment `seg` (of the tables at `nodes`) each lane's draw `v` lies, t in
/// [0, 1] (the inverse of the segment's CDF, quadratic in t), and the μ there.
///
/// # Safety
/// As [`PhaseLanes::sample`], for every lane; `seg` below each lane's last node.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
#[inline]
unsafe fn solve_avx512(nodes: __m512i, seg: __m512i, v: __m512d) -> (__m512d, __m512d) {
    let (zero, one) = (_mm512_setzero_pd(), _mm512_set1_pd(1.0));
    let base = _mm512_add_epi64(nodes, times24(seg));
    let off = |bytes: i64| _mm512_add_epi64(base, _mm512_set1_epi64(bytes));
    let (c0, m0v, f0) = (gather_f!(base), gather_f!(off(8)), gather_f!(off(16)));
    let (m1v, f1) = (gather_f!(off(32)), gather_f!(off(40)));
    let dm = _mm512_sub_pd(m1v, m0v);
    let q = _mm512_mul_pd(_mm512_set1_pd(2.0 * PI), dm);
    let qa = _mm512_mul_pd(q, f0);
    let qb = _mm512_mul_pd(q, _mm512_sub_pd(f1, f0));
    let target = _mm512_sub_pd(v, c0);
    let linear = _mm512_mask_blend_pd(
        _mm512_cmp_pd_mask::<_CMP_GT_OQ>(qa, zero),
        _mm512_set1_pd(0.5),
        _mm512_div_pd(target, qa),
    );
    let disc = _mm512_max_pd(
        _mm512_add_pd(
            _mm512_mul_pd(qa, qa),
            _mm512_mul_pd(_mm512_mul_pd(_mm512_set1_pd(2.0), qb), target),
        ),
        zero,
    );
    let quadratic = _mm512_div_pd(
        _mm512_mul_pd(_mm512_set1_pd(2.0), target),
        _mm512_add_pd(qa, _mm512_sqrt_pd(disc)),
    );
    let small = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(
        _mm512_abs_pd(qb),
        _mm512_mul_pd(
            _mm512_set1_pd(1e-12),
            _mm512_max_pd(_mm512_abs_pd(qa), _mm512_set1_pd(1e-300)),
        ),
    );
    let t = _mm512_mask_blend_pd(small, quadratic, linear);
    let t = _mm512_mask_blend_pd(_mm512_cmp_pd_mask::<_CMP_GT_OQ>(target, zero), zero, t);
    let t = _mm512_min_pd(_mm512_max_pd(t, zero), one);
    let mu = _mm512_add_pd(m0v, _mm512_mul_pd(t, dm));
    (t, mu)
}

/// Field `field` (0: P(μ' ≤ μ), 1: μ, 2: f) of node `k` (at most `last`) of the table at `at`.
///
/// # Safety
/// `at` holds nodes up to `last`.
#[inline(always)]
unsafe fn node(at: *const f64, last: u64, k: u64, field: u64) -> f64 {
    unsafe { *at.add((3 * k.min(last) + field) as usize) }
}

/// How far through segment `seg` (of the table at `nodes`, last node `last`) a draw `v` lies, t in
/// [0, 1] (the inverse of the segment's CDF, quadratic in t), and the μ there.
///
/// # Safety
/// `nodes` holds nodes up to `last`.
#[inline]
unsafe fn solve(nodes: *const f64, last: u64, seg: u64, v: f64) -> (f64, f64) {
    let node = |k: u64, field: u64| unsafe { node(nodes, last, k, field) };
    let (c0, m0, f0) = (node(seg, 0), node(seg, 1), node(seg, 2));
    let (m1, f1) = (node(seg + 1, 1), node(seg + 1, 2));
    let dm = m1 - m0;
    let q = 2.0 * PI * dm;
    let (qa, qb) = (q * f0, q * (f1 - f0));
    let target = v - c0;
    let linear = if qa > 0.0 { target / qa } else { 0.5 };
    let disc = (qa * qa + 2.0 * qb * target).max(0.0);
    let quadratic = 2.0 * target / (qa + disc.sqrt());
    let t = if !(target > 0.0) {
        0.0
    } else if qb.abs() < 1e-12 * qa.abs().max(1e-300) {
        linear
    } else {
        quadratic
    };
    let t = t.clamp(0.0, 1.0);
    (t, m0 + t * dm)
}
