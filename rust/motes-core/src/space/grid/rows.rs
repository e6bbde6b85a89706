//! Which cells a traversal step tests: the step's own cell (overlap slots), or the rows of the 3×3×3
//! block around it that the ray comes near and no earlier step tested (centre cells).

use super::settings::BOX_MARGIN;
use super::slots::{ALL_LANES, LANES};
use super::SubGrid;
use crate::space::dda::GridFrame;
use crate::space::ray::RaySegment;

/// Row segments one DDA step can add (the 3×3 rows of a k = 1 step).
pub(super) const ROWS_PER_STEP: usize = 9;

/// Cells `c0..c1` (then, once loaded, slots `c0..c1`) one step of a traversal tests, with the step's
/// t range.
#[derive(Clone, Copy, Default)]
pub(super) struct Segment {
    pub(super) c0: usize,
    pub(super) c1: usize,
    pub(super) t_enter: f64,
    pub(super) t_exit: f64,
    /// The cell of a k = 0 step, or the first cell of a k = 1 row (quantised slots are read relative
    /// to it).
    pub(super) cell: [usize; 3],
    /// Quantised slots: the cell's slot origin across the ray (`Probe::offsets`), set when the
    /// step is tested.
    pub(super) off: [f32; 2],
    /// Quantised slots: the slot origin's lattice coordinates modulo 2^16 (`QSlots::origin_bits`).
    pub(super) base: [u16; 3],
}

impl Segment {
    /// The lanes of slot block `blk` inside the slots `c0..c1`, as bits.
    #[inline(always)]
    pub(super) fn block_lanes(&self, blk: usize) -> u32 {
        let base = LANES * blk;
        let first = (self.c0.max(base) - base) as u32;
        let end = (self.c1.min(base + LANES) - base) as u32;
        (ALL_LANES >> (LANES as u32 - end)) & (ALL_LANES << first)
    }
}

/// When a ray comes near a layer of cells (k = 1, `SubGrid::step_rows`): along axis a, its coordinate
/// lies within R_max of cell layer m for t in [enter[a] + m step[a], exit[a] + m step[a]] (enter ≤
/// exit; an axis the ray runs across at d = 0 gets a direction of 1e-200, whose huge but finite t
/// values put the whole line near a layer it lies in, and never near another, with no NaN).
#[derive(Clone, Copy, Default)]
pub(super) struct Near {
    pub(super) enter: [f64; 3],
    pub(super) exit: [f64; 3],
    pub(super) step: [f64; 3],
    /// R_max with the grid's margin, in cells per axis.
    pub(super) cells: [f64; 3],
    /// The ray's coordinates in cells from the grid's corner: `at + t per_t`.
    pub(super) at: [f64; 3],
    pub(super) per_t: [f64; 3],
}

impl Near {
    /// The cells [`SubGrid::near_rows`] tests for DDA cell `c` after `prev` (None: the first step) of
    /// a segment on [t0, t1], in a grid of `dims` cells: per axis, the range of cells (None: none).
    /// The candidates are the cells within one of `c` along each axis (clamped to the grid), or the
    /// slab's one coordinate. Where the segment comes within R_max of them: first a t interval (near
    /// the slab's layer, or near the block along every axis), then along each other axis the layers
    /// the ray's coordinate comes near over that interval (a cell whose grown box the ray crosses at t
    /// has t in the interval and its layers within R_max of the coordinates there: none is dropped).
    #[inline(always)]
    fn cells_near(
        &self,
        c: [i64; 3],
        prev: Option<[i64; 3]>,
        t0: f64,
        t1: f64,
        dims: [i64; 3],
    ) -> Option<[[i64; 2]; 3]> {
        let range = [0, 1, 2].map(|a| [(c[a] - 1).max(0), (c[a] + 1).min(dims[a] - 1)]);
        match prev {
            Some(p) => self.slab_near(c, p, t0, t1, dims, range),
            None => self.block_near(t0, t1, range),
        }
    }

    /// [`Self::cells_near`] of the slab a step from `p` to `c` adds to the block already tested.
    #[inline(always)]
    fn slab_near(
        &self,
        c: [i64; 3],
        p: [i64; 3],
        t0: f64,
        t1: f64,
        dims: [i64; 3],
        mut range: [[i64; 2]; 3],
    ) -> Option<[[i64; 2]; 3]> {
        // The axis the step moved along (exactly one differs), without a branch per axis.
        let a = usize::from(p[1] != c[1]) + 2 * usize::from(p[2] != c[2]);
        let far = if c[a] > p[a] { c[a] + 1 } else { c[a] - 1 };
        if far < 0 || far >= dims[a] {
            return None; // the slab lies outside the grid
        }
        let t0 = fmax(t0, self.enter[a] + far as f64 * self.step[a]);
        let t1 = fmin(t1, self.exit[a] + far as f64 * self.step[a]);
        if t0 > t1 {
            return None;
        }
        range[a] = [far, far];
        for b in [(a + 1) % 3, (a + 2) % 3] {
            range[b] = self.layers(b, t0, t1, range[b])?;
        }
        Some(range)
    }

    /// [`Self::cells_near`] of a first step: the whole block of `range`.
    #[inline(always)]
    fn block_near(&self, t0: f64, t1: f64, mut range: [[i64; 2]; 3]) -> Option<[[i64; 2]; 3]> {
        if range.iter().any(|r| r[0] > r[1]) {
            return None; // the block lies outside the grid
        }
        let (mut t0, mut t1) = (t0, t1);
        for a in 0..3 {
            let [m0, m1] = range[a];
            let (first, last) = if self.step[a] > 0.0 {
                (m0, m1)
            } else {
                (m1, m0)
            };
            t0 = fmax(t0, self.enter[a] + first as f64 * self.step[a]);
            t1 = fmin(t1, self.exit[a] + last as f64 * self.step[a]);
        }
        if t0 > t1 {
            return None;
        }
        for a in 0..3 {
            range[a] = self.layers(a, t0, t1, range[a])?;
        }
        Some(range)
    }

    /// The layers along axis `a` within `r` that the segment comes near over [t0, t1] (None: none).
    /// A layer m is near where [m, m + 1) meets the coordinate's span grown by R_max (in cells).
    #[inline(always)]
    fn layers(&self, a: usize, t0: f64, t1: f64, r: [i64; 2]) -> Option<[i64; 2]> {
        let (p, q) = (
            self.at[a] + t0 * self.per_t[a],
            self.at[a] + t1 * self.per_t[a],
        );
        let from = (fmin(p, q) - self.cells[a]).floor() as i64;
        let to = (fmax(p, q) + self.cells[a]).floor() as i64;
        let (m0, m1) = (r[0].max(from), r[1].min(to));
        (m0 <= m1).then_some([m0, m1])
    }
}

/// The larger of two numbers that are never NaN (plain comparisons: `f64::max`'s NaN rule costs a
/// compare and a blend per call on the walk's hot path).
#[inline(always)]
pub(super) fn fmax(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else {
        b
    }
}

/// The smaller of two numbers that are never NaN (see [`fmax`]).
#[inline(always)]
pub(super) fn fmin(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

impl SubGrid {
    /// When `ray` comes near each layer of cells ([`Near`]).
    pub(super) fn near(&self, ray: &RaySegment) -> Near {
        self.near_reach(ray, self.reach_max * BOX_MARGIN.0 + BOX_MARGIN.1)
    }

    /// [`Near`] of a ray for balls of radius `reach`.
    pub(super) fn near_reach(&self, ray: &RaySegment, reach: f64) -> Near {
        let (lo, edge) = (self.frame.bounds.lo, self.frame.cell);
        let mut near = Near::default();
        for a in 0..3 {
            near.cells[a] = reach / edge[a];
            near.at[a] = (ray.o[a] - lo[a]) / edge[a];
            near.per_t[a] = ray.d[a] / edge[a];
            // (Also below 1e-200: a subnormal d would make the step infinite, and 0 × ∞ NaN.)
            let d = if ray.d[a].abs() < 1e-200 {
                1e-200f64.copysign(ray.d[a])
            } else {
                ray.d[a]
            };
            let inv = 1.0 / d;
            let (x0, x1) = (lo[a] - reach - ray.o[a], lo[a] + edge[a] + reach - ray.o[a]);
            let (t0, t1) = (x0 * inv, x1 * inv);
            (near.enter[a], near.exit[a]) = if inv > 0.0 { (t0, t1) } else { (t1, t0) };
            near.step[a] = edge[a] * inv;
        }
        near
    }

    /// The rows of cells one DDA step at cell `c` (linear `index`) scans, as segments [first cell,
    /// last cell + 1) of `start`; returns how many.
    ///
    /// * k = 0: the cell itself, contributions counted in the step's t range.
    /// * k = 1: the cells around `c` that no earlier step tested and that a ball can reach the ray
    ///   from. The 3×3×3 block around `c` holds every centre whose ball reaches the ray inside `c`
    ///   (R ≤ one cell); consecutive blocks overlap in all but the 3×3 slab the step's move adds on
    ///   the far side (a DDA step moves along one axis), so a step tests only that slab (the first
    ///   step, `prev` None, the whole block), and of it only the rows the segment comes within R_max
    ///   of (per axis, over the t interval where it is near the slab: one or two rows of a slab for
    ///   balls much narrower than a cell). Every particle near the ray is then tested exactly once,
    ///   and its contribution counts wherever it lies on the segment (the segments' t range is
    ///   unbounded). In order: a particle contributing at t lies within R of the ray's point at t,
    ///   whose cell the DDA visits at t, so it is tested by then; once a step is done every
    ///   contribution before its exit is known (the walk holds later ones back:
    ///   `ParticleGrid::walk_lanes`).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn step_rows(
        &self,
        c: [usize; 3],
        index: usize,
        prev: Option<[usize; 3]>,
        ray: &RaySegment,
        near: &Near,
        t_enter: f64,
        t_exit: f64,
        out: &mut [Segment],
    ) -> usize {
        if self.k == 0 {
            out[0] = Segment {
                c0: index,
                c1: index + 1,
                t_enter,
                t_exit,
                cell: c,
                ..Segment::default()
            };
            return 1;
        }
        self.near_rows(
            c.map(|x| x as i64),
            prev.map(|p| p.map(|x| x as i64)),
            ray.t0,
            ray.t1,
            near,
            out,
        )
    }

    /// The k = 1 rows of [`Self::step_rows`] for DDA cell `c` after cell `prev`, in signed cell
    /// coordinates (a beam's walk steps through the cells one layer outside the grid too:
    /// `ParticleGrid::sample_sites_beam`), for a segment on [t0, t1] whose nearness `near` gives.
    #[inline(always)]
    pub(super) fn near_rows(
        &self,
        c: [i64; 3],
        prev: Option<[i64; 3]>,
        t0: f64,
        t1: f64,
        near: &Near,
        out: &mut [Segment],
    ) -> usize {
        let Some(range) = near.cells_near(c, prev, t0, t1, self.frame.dims.map(|d| d as i64))
        else {
            return 0;
        };
        let mut n = 0;
        let (first, last) = (range[0][0] as usize, range[0][1] as usize);
        let dims = self.frame.dims;
        for z in range[2][0] as usize..=range[2][1] as usize {
            for y in range[1][0] as usize..=range[1][1] as usize {
                let row = (z * dims[1] + y) * dims[0];
                out[n] = Segment {
                    c0: row + first,
                    c1: row + last + 1,
                    t_enter: f64::NEG_INFINITY,
                    t_exit: f64::INFINITY,
                    // The row's first cell: quantised slots decode relative to it.
                    cell: [first, y, z],
                    ..Segment::default()
                };
                n += 1;
            }
        }
        n
    }

    /// Every particle whose inclusion ball (radius R_i) contains the point `p`, as `visit(slot)` (see
    /// `hit_index`).
    pub fn containing(&self, p: [f64; 3], mut visit: impl FnMut(usize)) {
        let GridFrame { bounds, cell, dims } = &self.frame;
        let mut c = [0usize; 3];
        for a in 0..3 {
            let x = ((p[a] - bounds.lo[a]) / cell[a]).floor();
            if !(x >= 0.0 && x < dims[a] as f64) {
                return; // outside the grid box: no ball reaches there
            }
            c[a] = x as usize;
        }
        let mut rows = [Segment::default(); ROWS_PER_STEP];
        let index = (c[2] * dims[1] + c[1]) * dims[0] + c[0];
        // The point as a ray of no length: only the cells within R_max of it.
        let at_p = RaySegment::new(p, [1.0, 0.0, 0.0], 0.0, 0.0);
        let near = self.near(&at_p);
        let n = self.step_rows(c, index, None, &at_p, &near, 0.0, 0.0, &mut rows);
        for sg in &rows[..n] {
            for s in self.start[sg.c0] as usize..self.start[sg.c1] as usize {
                let (q, r) = self.slot_ball(s, sg.cell);
                let dd = (0..3).map(|a| (q[a] - p[a]).powi(2)).sum::<f64>();
                if dd < r * r {
                    visit(s);
                }
            }
        }
    }
}
