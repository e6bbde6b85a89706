//! One class's traversal: a cursor's DDA steps in batches, each step's slots pre-tested a block at a
//! time and the passing ones tested exactly.

use super::rows::{Near, Segment, ROWS_PER_STEP};
use super::slots::{
    ball_contribution, block_pretest, prefetch, qblock_pretest, sphere_contribution, Block, QBlock,
    QSlots, RayFrame, Spheres, ALL_LANES, LANES, LATTICE_PER_CELL, PRETEST_SLACK,
};
use super::SubGrid;
use crate::space::dda::{Dda, DdaCell};
use crate::space::ray::RaySegment;

/// DDA steps a traversal batch covers before its loads (see `SubGrid::advance`): more steps keep more
/// cache misses in flight on dense clouds, fewer waste less on a free flight that stops early.
pub(super) const SEGMENTS_PER_BATCH: usize = 36;

/// DDA steps of a walk's first batch (`SubGrid::advance` and its cached variants): each batch after it
/// twice as many, up to [`SEGMENTS_PER_BATCH`] (and the rows a prefetched batch holds). A free flight
/// that stops after a few cells (in a dense cloud, most) then walks few past its site, while a long walk
/// still sorts its hits once per large batch. Two: a ray from a wall into a cloud whose cells hold
/// about a free path finds its site in the first step or two.
pub(super) const FIRST_CACHED_BATCH: usize = 2;

/// Cache lines of the next cell's slots the cached sparse walk prefetches (a cell's ~12 slots fill two
/// blocks of two lines at the default resolution).
pub(super) const PREFETCH_AHEAD_LINES: usize = 4;

/// A traversal of one [`SubGrid`] in progress: the DDA and what the pre-test needs.
pub(crate) struct Cursor {
    dda: Dda,
    /// The ray as the tests see it.
    probe: Probe,
    first: bool,
    /// The cached sparse walk's next step (and whether it is the last), taken from the DDA one step
    /// early so that its blocks are on their way while the current step is tested.
    ahead: Option<(DdaCell, bool)>,
    /// The previous step's cell (k = 1: a step tests only the slab of cells its move adds to the
    /// neighbourhood already tested; `SubGrid::step_rows`).
    prev: Option<[usize; 3]>,
    /// Which cells the ray comes near (k = 1).
    near: Near,
    /// DDA steps of the next cached batch ([`FIRST_CACHED_BATCH`], doubling).
    batch: usize,
}

/// A ray as a class's slot tests see it: the segment (|d| = 1, the exact test's double precision),
/// its pre-test frame and, for quantised slots, where their origins lie across it.
#[derive(Clone, Copy)]
pub(super) struct Probe {
    pub(super) ray: RaySegment,
    pub(super) frame: RayFrame,
    /// Quantised slots: where their origins lie across the ray (`RayFrame::corner_offsets`).
    pub(super) corners: [[f64; 4]; 2],
}

impl Probe {
    /// A quantised step's offsets: (corner − o)·e1 and (corner − o)·e2 of the slot origin of `cell`, in
    /// single precision (rounded once from double: within the pre-test's slack).
    #[inline(always)]
    pub(super) fn offsets(&self, cell: [usize; 3]) -> [f32; 2] {
        let [x, y, z] = cell.map(|c| c as f64);
        self.corners
            .map(|k| (k[3] + x * k[0] + y * k[1] + z * k[2]) as f32)
    }
}

impl SubGrid {
    /// The pre-test's slack for a ray from `o`: the single-precision rounding of coordinates of that
    /// magnitude, and of quantised slots' lattice offsets.
    pub(super) fn pretest_slack(&self, o: [f64; 3]) -> f64 {
        let b = &self.frame.bounds;
        let scale = (0..3)
            .map(|a| o[a].abs() + b.lo[a].abs().max(b.hi[a].abs()))
            .fold(0.0, f64::max);
        // Quantised slots add the rounding of their lattice offsets' single-precision sums
        // (up to 4 cells of 2^16 steps, ~1e-6 of a cell): covered ten times over.
        let step = self.quant.as_ref().map_or(0.0, |q| q.step);
        PRETEST_SLACK * scale + 1e-5 * step * LATTICE_PER_CELL as f64
    }

    /// A ray as the slot tests see it, its pre-test's slack grown by `widen`.
    pub(super) fn probe(&self, ray: &RaySegment, widen: f64) -> Probe {
        self.probe_with_slack(ray, (self.pretest_slack(ray.o) + widen) as f32)
    }

    /// A ray as the slot tests see it, its pre-test's slack `slack`.
    #[inline(always)]
    fn probe_with_slack(&self, ray: &RaySegment, slack: f32) -> Probe {
        let step = self.quant.as_ref().map_or(0.0, |q| q.step);
        let frame = RayFrame::new(ray, slack, step);
        Probe {
            ray: *ray,
            corners: if self.quant.is_some() {
                frame.corner_offsets(self.frame.bounds.lo, self.frame.cell, ray.o)
            } else {
                [[0.0; 4]; 2]
            },
            frame,
        }
    }

    /// The lanes of slot block `blk` that may contribute to a probe's ray (the pre-test alone).
    #[inline(always)]
    pub(super) fn pretest<const WIDE: bool>(
        &self,
        slots: &Spheres,
        blk: usize,
        sg: &Segment,
        probe: &Probe,
    ) -> u32 {
        match &self.quant {
            Some(q) => qblock_pretest::<WIDE>(
                &q.blocks[blk],
                q.block_reach[blk],
                &probe.frame,
                sg.off,
                sg.base,
            ),
            None => block_pretest::<WIDE>(&slots.0[blk], &probe.frame),
        }
    }

    /// Start a traversal of a ray segment, |d| = 1, `inv_d` the direction's reciprocals.
    pub(crate) fn cursor(&self, ray: &RaySegment, inv_d: [f64; 3]) -> Cursor {
        let dda = Dda::new_in(&self.frame, ray, inv_d);
        // A ray that misses the grid tests nothing: no frame for it (in a room with a cloud in it,
        // most shadow rays).
        let misses = dda.finished();
        let probe = if misses {
            Probe {
                ray: *ray,
                frame: RayFrame::UNUSED,
                corners: [[0.0; 4]; 2],
            }
        } else {
            self.probe_with_slack(ray, self.pretest_slack(ray.o) as f32)
        };
        Cursor {
            dda,
            probe,
            first: true,
            ahead: None,
            prev: None,
            batch: FIRST_CACHED_BATCH,
            near: if self.k == 1 && !misses {
                self.near(ray)
            } else {
                Near::default()
            },
        }
    }

    /// A segment's cells `c0..c1` as the slots they hold, `start[c0]..start[c1]`.
    #[inline(always)]
    pub(super) fn load_slot_range(&self, sg: &mut Segment) {
        (sg.c0, sg.c1) = (self.start[sg.c0] as usize, self.start[sg.c1] as usize);
    }

    /// Where a segment's quantised slots lie across the ray (`Segment::off`, `Segment::base`): once per
    /// segment, before its slots are tested (spheres need nothing).
    #[inline(always)]
    pub(super) fn locate(&self, sg: &mut Segment, probe: &Probe) {
        if self.quant.is_some() {
            sg.off = probe.offsets(sg.cell);
            sg.base = QSlots::origin_bits(sg.cell);
        }
    }

    /// One batch of a traversal: the rows of cells of the next DDA steps (up to
    /// [`SEGMENTS_PER_BATCH`]), each level of loads prefetched for the whole batch before it is read,
    /// then every contributing particle of those steps reported as `found(t, slot)` (unsorted
    /// within the batch). Returns the t before which this class has reported every contribution —
    /// infinity once the ray has left the grid — or None when `found` asked to stop.
    #[inline(always)]
    pub(super) fn advance<const WIDE: bool>(
        &self,
        cur: &mut Cursor,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> Option<f64> {
        // The walk is memory-latency bound on dense clouds: a cell's start offset, then its slots are
        // dependent cache misses. So the DDA runs ahead over a batch of steps, gathering the row
        // segments to test, and each level of loads of the whole batch is prefetched before the next
        // is read (many misses in flight instead of one after the other).
        if self.k == 0 && !self.prefetch_slots {
            return self.advance_cached_sparse::<WIDE>(cur, found);
        }
        if self.k == 1 && !self.prefetch_slots {
            return self.advance_cached_near::<WIDE>(cur, found);
        }
        let mut segs = [Segment::default(); SEGMENTS_PER_BATCH];
        let mut n = 0;
        // Infinity unless the batch fills up before the ray leaves the grid.
        let mut frontier = f64::INFINITY;
        // A step adds one row (k = 0) or up to nine (k = 1).
        let rows_per_step = if self.k == 0 { 1 } else { ROWS_PER_STEP };
        // At most `cur.batch` steps (doubling from batch to batch, as in the cached walks).
        let steps = cur.batch;
        cur.batch = (2 * steps).min(SEGMENTS_PER_BATCH);
        let mut taken = 0;
        while n + rows_per_step <= SEGMENTS_PER_BATCH && taken < steps {
            taken += 1;
            let Some((rows, t_exit, last)) = self.next_rows(cur, &mut segs[n..]) else {
                break;
            };
            n += rows;
            if last {
                frontier = f64::INFINITY;
                break;
            }
            frontier = t_exit;
        }
        let batch = &mut segs[..n];
        for sg in batch.iter() {
            prefetch(self.start.as_ptr().wrapping_add(sg.c0));
            prefetch(self.start.as_ptr().wrapping_add(sg.c1));
        }
        let slots = self.slots();
        for sg in batch.iter_mut() {
            self.load_slot_range(sg);
            self.locate(sg, &cur.probe);
            if self.prefetch_slots {
                for blk in sg.c0 / LANES..sg.c1.div_ceil(LANES) {
                    match &self.quant {
                        Some(q) => prefetch(q.blocks.as_ptr().wrapping_add(blk)),
                        None => slots.prefetch_block(blk),
                    }
                }
            }
        }
        for sg in batch.iter() {
            if !self.test_slots::<WIDE>(slots, sg, &cur.probe, found) {
                return None;
            }
        }
        Some(frontier)
    }

    /// Test the slots `sg.c0..sg.c1` (a step's spheres) against the ray and report each contribution
    /// whose t lies in the step's range as `found(t, slot)`; false when `found` asked to stop.
    #[inline(always)]
    pub(super) fn test_slots<const WIDE: bool>(
        &self,
        slots: &Spheres,
        sg: &Segment,
        probe: &Probe,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> bool {
        if sg.c0 == sg.c1 {
            return true;
        }
        for blk in sg.c0 / LANES..=(sg.c1 - 1) / LANES {
            if !self.test_block::<WIDE>(slots, blk, sg.block_lanes(blk), sg, probe, found) {
                return false;
            }
        }
        true
    }

    /// Test the `lanes` of slot block `blk` against the ray (pre-test, then the exact test) and report
    /// each contribution in the step's t range as `found(t, slot)`; false when `found` stops.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn test_block<const WIDE: bool>(
        &self,
        slots: &Spheres,
        blk: usize,
        lanes: u32,
        sg: &Segment,
        probe: &Probe,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> bool {
        let mut m = lanes & self.pretest::<WIDE>(slots, blk, sg, probe);
        if let Some(q) = &self.quant {
            return self.test_qblock(q, blk, m, sg, probe, found);
        }
        while m != 0 {
            let s = LANES * blk + m.trailing_zeros() as usize;
            m &= m - 1;
            if let Some(t) = sphere_contribution(slots.get(s), &probe.ray) {
                let in_step = t >= sg.t_enter && t < sg.t_exit && probe.ray.contains(t);
                if in_step && self.k == 0 {
                    // A hit's τ and index are read when the batch's hits are merged in t order:
                    // start fetching them now.
                    prefetch(self.slot_tau.as_ptr().wrapping_add(s * self.channels));
                    prefetch(self.slot_index.as_ptr().wrapping_add(s));
                }
                if in_step && !found(t, s) {
                    return false;
                }
            }
        }
        true
    }

    /// [`Self::test_block`] for quantised slots, whose lanes `passed` the pre-test (in the step's cell
    /// frame): the exact test on the decoded (double-precision) lattice centre.
    #[inline(always)]
    pub(super) fn test_qblock(
        &self,
        q: &QSlots,
        blk: usize,
        passed: u32,
        sg: &Segment,
        probe: &Probe,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> bool {
        let lo = self.frame.bounds.lo;
        let mut m = passed;
        while m != 0 {
            let s = LANES * blk + m.trailing_zeros() as usize;
            m &= m - 1;
            let (c, r) = q.ball(lo, s, sg.cell);
            if let Some(t) = ball_contribution(c, r, &probe.ray) {
                let in_step = t >= sg.t_enter && t < sg.t_exit && probe.ray.contains(t);
                if in_step {
                    let index = if self.k == 0 {
                        &self.slot_index
                    } else {
                        &self.index
                    };
                    if !index.is_empty() {
                        prefetch(index.as_ptr().wrapping_add(s));
                    }
                    if !found(t, s) {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// [`Self::advance`] for a class that references its particles from every cell their balls
    /// overlap (k = 0) with slots that stay cached: one pass per step (DDA, the cell's slot range, its
    /// whole blocks), no batch of segments to gather and prefetch: cheaper where nothing waits on
    /// memory. The same contract as `advance`.
    #[inline(always)]
    pub(super) fn advance_cached_sparse<const WIDE: bool>(
        &self,
        cur: &mut Cursor,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> Option<f64> {
        let slots = &self.inline;
        let take = |cur: &mut Cursor| cur.dda.next().map(|st| (st, cur.dda.finished()));
        let mut frontier = cur.probe.ray.t0;
        let mut this = match cur.ahead.take() {
            Some(a) => Some(a),
            None => take(cur),
        };
        let steps = cur.batch;
        cur.batch = (2 * steps).min(SEGMENTS_PER_BATCH);
        for _ in 0..steps {
            let Some((step, last)) = this else {
                return Some(f64::INFINITY);
            };
            // The next step's blocks are fetched while this one is tested (the slots overflow L2 in a
            // render, where Mitsuba's own data shares the cache).
            let next = if last { None } else { take(cur) };
            if let Some((st, _)) = &next {
                let (base, block) = match &self.quant {
                    Some(q) => (
                        q.blocks.as_ptr() as *const u8,
                        std::mem::size_of::<QBlock>(),
                    ),
                    None => (slots.0.as_ptr() as *const u8, std::mem::size_of::<Block>()),
                };
                let b = base.wrapping_add(self.start[st.index] as usize / LANES * block);
                for k in 0..PREFETCH_AHEAD_LINES {
                    prefetch(b.wrapping_add(64 * k));
                }
            }
            let c = step.index;
            let mut sg = Segment {
                c0: self.start[c] as usize,
                c1: self.start[c + 1] as usize,
                t_enter: if cur.first {
                    cur.probe.ray.t0
                } else {
                    step.t_enter
                },
                t_exit: if last { cur.probe.ray.t1 } else { step.t_exit },
                cell: step.cell,
                ..Segment::default()
            };
            self.locate(&mut sg, &cur.probe);
            cur.first = false;
            // Whole blocks (padded cells): every lane is tested.
            for blk in sg.c0 / LANES..sg.c1 / LANES {
                if !self.test_block::<WIDE>(slots, blk, ALL_LANES, &sg, &cur.probe, found) {
                    return None;
                }
            }
            if last {
                return Some(f64::INFINITY);
            }
            frontier = sg.t_exit;
            this = next;
        }
        // The batch is full: everything before the last step's exit is reported; the step taken
        // ahead starts the next batch.
        cur.ahead = this;
        Some(frontier)
    }

    /// [`Self::advance`] for a k = 1 class whose slots stay cached: one pass per step (the few rows
    /// near the ray it adds, `step_rows`), no batch to gather and prefetch.
    /// The same contract as `advance`.
    #[inline(always)]
    pub(super) fn advance_cached_near<const WIDE: bool>(
        &self,
        cur: &mut Cursor,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> Option<f64> {
        let slots = self.slots();
        let mut rows = [Segment::default(); ROWS_PER_STEP];
        let mut frontier = cur.probe.ray.t0;
        let steps = cur.batch;
        cur.batch = (2 * steps).min(SEGMENTS_PER_BATCH);
        for _ in 0..steps {
            let Some((n, t_exit, last)) = self.next_rows(cur, &mut rows) else {
                return Some(f64::INFINITY);
            };
            for sg in rows[..n].iter_mut() {
                self.load_slot_range(sg);
                if sg.c0 == sg.c1 {
                    continue;
                }
                self.locate(sg, &cur.probe);
                if !self.test_slots::<WIDE>(slots, sg, &cur.probe, found) {
                    return None;
                }
            }
            if last {
                return Some(f64::INFINITY);
            }
            frontier = t_exit;
        }
        Some(frontier)
    }

    /// The cursor's next DDA step: the rows it scans into `out` (`Self::step_rows`), its exit and
    /// whether it is the last (None: the walk is over). The first step starts at t0 (particles before
    /// the box entry are too far from the ray to count), the last ends at t1.
    #[inline(always)]
    pub(super) fn next_rows(
        &self,
        cur: &mut Cursor,
        out: &mut [Segment],
    ) -> Option<(usize, f64, bool)> {
        let step = cur.dda.next()?;
        let last = cur.dda.finished();
        let ray = &cur.probe.ray;
        let t_enter = if cur.first { ray.t0 } else { step.t_enter };
        let t_exit = if last { ray.t1 } else { step.t_exit };
        cur.first = false;
        let prev = cur.prev.replace(step.cell);
        let n = self.step_rows(
            step.cell, step.index, prev, ray, &cur.near, t_enter, t_exit, out,
        );
        Some((n, t_exit, last))
    }
}
