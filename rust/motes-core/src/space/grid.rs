//! Particles in space: a uniform grid over particle centres, optical depth along query cylinders
//! (paper Eq. 18) and exact free-flight sampling (paper Sec. 5.2–5.3; issue 4).
//!
//! ## Normalisation (why E\[τ\] = σ_t · length exactly)
//! A particle i at centre c_i with geometric radius r_i contributes to a segment of a ray when the ray
//! passes within `R_i = r_c + r_i` of c_i (the paper's inclusion test, Sec. 5.3) and the projection
//! `t_i` of c_i on the ray lies inside the segment. Its contribution is `C_t,i / (π R_i²)` — normalised by
//! its own inclusion disk rather than by the cylinder's π r_c² as in Eq. 18. For particles at number
//! density n, the expected optical depth over a length L is then
//! `Σ_i n ∫_{disk R_i} C_t,i/(π R_i²) dA · L = n C̄_t L = σ_t L`, exactly, for any r_c and any sizes:
//! the discrete medium converges to the continuous one as particles get dense.
//!
//! The optical depth along a ray is a staircase (a jump of τ_i at each t_i), so a free flight can be
//! sampled exactly: walk the contributing particles in order of t_i and interact at particle i with
//! probability 1 − exp(−τ_i) — no majorant, no null collisions.
//!
//! ## Grid
//! Each particle's data is stored once, in the order of its centre's cell (counting sort, O(N)); each
//! cell keeps references to particles. Two layouts of a class of similar sizes:
//!
//! * **Overlap slots** (k = 0; sparse classes of full storage, and of compact storage below 2^16
//!   discrete grains, `DiscreteMedium`): where inclusion balls (radius R_i)
//!   are narrower than the cells, a cell references every particle whose ball overlaps it, and a
//!   traversal (3D-DDA, Amanatides & Woo) tests only the particles referenced by the cells the ray
//!   itself crosses: the projection p_i = o + t_i d of a contributing particle lies within R_i of its
//!   centre, hence in a cell that references it. A particle counts in the DDA step whose t-interval
//!   holds t_i. Costs (1 + 2R/L)³ references a particle, padded to blocks (~2.5–3).
//! * **Centre cells** (k = 1; every class of compact storage from 2^16 discrete grains, and classes
//!   whose balls are wider than the particle spacing): cells at least R_max wide hold the particles
//!   whose centres they contain,
//!   once each. A traversal tests, per DDA step, the cells of the 3×3×3 block around the ray's cell
//!   that no earlier step tested (the first step the whole block, each later one the 3×3 slab its move
//!   adds) and that the ray comes within R_max of (`SubGrid::step_rows`): every particle near the ray
//!   is tested exactly once, wherever its t_i lies, and once a step is done every t_i before its exit
//!   is known, so the walk reports in order (it holds later ones back).
//!
//! The grid box is the centres' bounding box grown by R_max.
//!
//! ## Quantised slots (compact storage, issue 24)
//! A sparse class's overlap slots copy each ball into every cell it overlaps (24 bytes a slot: the
//! sphere in f32, τ and the particle's index). With [`GridSettings::quantise`] a slot is 8 bytes: the
//! centre's lattice coordinates (2^14 steps per cell edge, 6·10⁻⁵ of a cell) modulo 2^16 and a u16
//! code into the class's table of (R, τ); read relative to a corner one cell below the slot's cell
//! (or row of cells), the wrapped difference is the exact offset (`LATTICE_PER_CELL`). The lattice
//! point *is* the particle: every slot of a particle decodes to the same double-precision centre, the
//! cells that reference it are chosen from that centre, and the exact test runs on it, so the free
//! flight stays exact for the particles as stored. The single-precision pre-test works in the
//! segment's cell frame (its origin's offset across the ray once per segment, then `h (q·e)` per
//! lane), which is more precise than the spheres' global one. Its radius is the block's largest (each
//! cell's slots sorted by radius): a per-lane gather of radii by code cost more than the few extra
//! exact tests on AMD's cores. Overlap slots add each slot's particle index (12 bytes a slot);
//! centre cells need none where the grid names particles by position ([`ParticleGrid::positional`]):
//! compact storage's 8 bytes a particle (`crate::render::storage`). Measured side by side
//! (`scripts/bench/bench_quantise.py`; `MOTES_QUANTISE=0` keeps spheres, `MOTES_CENTRE_CELLS=0`
//! overlap slots, for those comparisons): BENCHMARKS.md section 24.

use crate::error::{require, require_len, OpticsError};
use crate::simd::wide_simd;
use crate::space::dda::{inverse, Dda, DdaCell, GridFrame};
use crate::space::ray::RaySegment;
use crate::space::ray_lanes::RayLanes;
use rayon::prelude::*;

/// A per-particle value, by the caller's particle index: a column need not exist as an array (10^8
/// particles; `DiscreteMedium` derives its grid's radii and cross sections from class tables).
pub type Column<'a> = &'a (dyn Fn(usize) -> f64 + Sync);
/// A per-particle value per channel: (particle index, channel).
pub type ChannelColumn<'a> = &'a (dyn Fn(usize, usize) -> f64 + Sync);

/// The particles a grid is built over, read through the caller's columns (no copies): its particles
/// `ids` (None: all of `positions`), each reported by its index.
#[derive(Clone, Copy)]
pub struct Particles<'a> {
    pub positions: &'a [[f64; 3]],
    pub ids: Option<&'a [u32]>,
    /// Geometric radius (scene units).
    pub radius: Column<'a>,
    /// Extinction cross section per channel (scene units²).
    pub c_ext: ChannelColumn<'a>,
    pub channels: usize,
}

impl Particles<'_> {
    fn len(&self) -> usize {
        self.ids.map_or(self.positions.len(), <[u32]>::len)
    }
    /// The caller's index of the j-th particle.
    #[inline]
    fn id(&self, j: usize) -> usize {
        self.ids.map_or(j, |v| v[j] as usize)
    }
}

/// Axis-aligned bounding box of the centres (in parallel: 10^8 centres are 2.4 GB to read).
pub fn bounding_box(positions: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    bounding_box_by(positions.len(), |i| positions[i])
}

/// [`bounding_box`] of the `n` centres `at(0..n)`.
fn bounding_box_by(n: usize, at: impl Fn(usize) -> [f64; 3] + Sync) -> ([f64; 3], [f64; 3]) {
    let empty = || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    const CHUNK: usize = 1 << 16;
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (mut lo, mut hi) = empty();
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let p = at(i);
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
            (lo, hi)
        })
        .reduce(empty, |x, y| {
            (
                [0, 1, 2].map(|a| x.0[a].min(y.0[a])),
                [0, 1, 2].map(|a| x.1[a].max(y.1[a])),
            )
        })
}

/// DDA steps a traversal batch covers before its loads (see `SubGrid::advance`): more steps keep more
/// cache misses in flight on dense clouds, fewer waste less on a free flight that stops early.
const SEGMENTS_PER_BATCH: usize = 36;
/// DDA steps of a walk's first batch (`SubGrid::advance` and its cached variants): each batch after it
/// twice as many, up to [`SEGMENTS_PER_BATCH`] (and the rows a prefetched batch holds). A free flight that stops after a
/// few cells (in a dense cloud, most) then walks few past its site, while a long walk still sorts its
/// hits once per large batch. Two, not four: a ray from a wall into a cloud whose cells hold about
/// a free path finds its site in the first step or two (the dense Cornell box, 10^6 x 2 mm, 1.2 %
/// faster; the default box 1.4 %; the sparse dust box unchanged; one step was no faster than two).
const FIRST_CACHED_BATCH: usize = 2;
thread_local! {
    /// The buffer of `ParticleGrid::walk_lanes`'s pending hits between walks on this thread.
    static WALK_PENDING: std::cell::Cell<Vec<(f64, u32, u32)>> = const { std::cell::Cell::new(Vec::new()) };
}

thread_local! {
    /// The per-ray buffers of `ParticleGrid::sample_sites_beam`'s pending hits between beams.
    static BEAM_PENDING: std::cell::Cell<[Vec<(f64, u32)>; BEAM_RAYS]> =
        const { std::cell::Cell::new([const { Vec::new() }; BEAM_RAYS]) };
}

/// A walk's pending hits, given back to [`WALK_PENDING`] when the walk ends (however it returns).
struct PendingHits(Vec<(f64, u32, u32)>);

impl Drop for PendingHits {
    fn drop(&mut self) {
        let v = std::mem::take(&mut self.0);
        // Keep a modest buffer only: a walk past huge numbers of hits should not pin its memory.
        // (A walk during the thread's teardown just drops it.)
        if v.capacity() <= 1 << 16 {
            let _ = WALK_PENDING.try_with(|b| b.set(v));
        }
    }
}

/// Row segments one DDA step can add (the 3×3 rows of a k = 1 step).
const ROWS_PER_STEP: usize = 9;
/// Relative slack of the single-precision pre-test against the exact (f64) inclusion test, in units of
/// the coordinates' scale (|o| + the grid box's largest |coordinate|): f32 keeps ~6e-8 of that per
/// operation, and the distance across the ray is a few operations deep (~6e-7 of the scale with SSE's
/// separate roundings, less with FMA; a review's bound). 2e-6 covers it about three times over, so the
/// pre-test never rejects a sphere the exact test accepts; a wider slack only lets a few more spheres
/// through to the exact test.
const PRETEST_SLACK: f64 = 2e-6;
/// Margin by which the grid box and a particle's referencing range grow beyond R_max (relative, then
/// absolute): a ball touching a face must not round outside the box.
const BOX_MARGIN: (f64, f64) = (1.0001, 1e-9);
/// Slot data above which a traversal prefetches every block of a batch (below it the blocks stay
/// cached and the prefetches only cost: sparse dust 0.47 -> 0.55 us per ray; dense haze 4.3 -> 3.7, in
/// `benches/traverse.rs`).
const PREFETCH_SLOTS_ABOVE_BYTES: usize = 4 << 20;
/// Particles per occupied cell of the grid that measures the occupied volume (`occupied_volume`): a
/// uniform cloud leaves e^-16 of those cells empty by chance.
const OCCUPANCY_PARTICLES_PER_CELL: f64 = 16.0;
/// Cache lines of the next cell's slots the cached sparse walk prefetches (a cell's ~12 slots fill two
/// blocks of two lines at the default resolution).
const PREFETCH_AHEAD_LINES: usize = 4;
/// `slot_particle` of a padding slot (k = 0 cells are padded to whole blocks; see `build_class`).
const PADDING_SLOT: u32 = u32::MAX;
/// Cells per particle of centre-cell classes ([`GridSettings::centre_cells`]) relative to the
/// setting: a centre-cell step works out which cells of its slab the ray comes near before it tests
/// any, so fewer, larger cells pay (32 particles a cell at the default; llvm_ad_rgb, 96 px, 16 spp,
/// s per render at 1 / 0.5 / 0.25 / 0.125 of the setting: dust_box 0.139 / 0.129 / 0.129 / 0.128,
/// cornell 0.756 / 0.739 / 0.722 / 0.720; the overlap layout 0.110 and 0.703 beside them).
const CENTRE_CELLS_FACTOR: f64 = 0.25;
/// Most cells per axis (the counting sorts index cells with u32).
const MAX_CELLS_PER_AXIS: usize = 1 << 20;
/// Most cells in all (a sparse cloud of 2e8 particles at one cell each: 800 MB of cell starts).
const MAX_CELLS: f64 = 2.0e8;

/// Cells `c0..c1` (then, once loaded, slots `c0..c1`) one step of a traversal tests, with the step's
/// t range.
#[derive(Clone, Copy, Default)]
struct Segment {
    c0: usize,
    c1: usize,
    t_enter: f64,
    t_exit: f64,
    /// The cell of a k = 0 step, or the first cell of a k = 1 row (quantised slots are read relative
    /// to it).
    cell: [usize; 3],
    /// Quantised slots: the cell's slot origin across the ray (`Probe::offsets`), set when the
    /// step is tested.
    off: [f32; 2],
    /// Quantised slots: the slot origin's lattice coordinates modulo 2^16 (`QSlots::origin_bits`).
    base: [u16; 3],
}

/// Ask for the cache line holding `p` (a hint: no fault for any address).
#[inline(always)]
fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    unsafe {
        std::arch::x86_64::_mm_prefetch(p as *const i8, std::arch::x86_64::_MM_HINT_T0);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Does the sphere (centre, R) contribute to the ray (|d| = 1; the segment's t range aside), and where
/// (t of its projection)?
#[inline]
fn sphere_contribution(p: [f32; 4], ray: &RaySegment) -> Option<f64> {
    ball_contribution([p[0] as f64, p[1] as f64, p[2] as f64], p[3] as f64, ray)
}

/// [`sphere_contribution`] of the ball (centre `c`, radius `r`) in double precision.
#[inline]
pub(crate) fn ball_contribution(c: [f64; 3], r: f64, ray: &RaySegment) -> Option<f64> {
    let (o, d) = (ray.o, ray.d);
    let v = [c[0] - o[0], c[1] - o[1], c[2] - o[2]];
    let t = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
    let q = [v[0] - t * d[0], v[1] - t * d[1], v[2] - t * d[2]];
    (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] < r * r).then_some(t)
}

/// Spheres per block: one pre-test covers a block (two SSE operations or one AVX2 operation per step).
const LANES: usize = 8;
/// Cache lines per block.
const LINES_PER_BLOCK: usize = std::mem::size_of::<Block>() / 64;
/// Lane mask of a whole block.
const ALL_LANES: u32 = (1 << LANES) - 1;

/// [`LANES`] spheres (centre and inclusion radius) by component, so that one pre-test covers all of
/// them.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, Default)]
struct Block {
    x: [f32; LANES],
    y: [f32; LANES],
    z: [f32; LANES],
    r: [f32; LANES],
}

/// Spheres in blocks: sphere s is lane s % LANES of block s / LANES. The padding lanes have R = 0
/// (they contribute to no ray).
#[derive(Default)]
struct Spheres(Vec<Block>);

impl Spheres {
    fn from_iter(n: usize, sphere: impl Fn(usize) -> [f32; 4]) -> Self {
        let mut b = vec![Block::default(); n.div_ceil(LANES)];
        for s in 0..n {
            let [x, y, z, r] = sphere(s);
            let (blk, l) = (&mut b[s / LANES], s % LANES);
            (blk.x[l], blk.y[l], blk.z[l], blk.r[l]) = (x, y, z, r);
        }
        Spheres(b)
    }
    #[inline]
    fn get(&self, s: usize) -> [f32; 4] {
        let (b, l) = (&self.0[s / LANES], s % LANES);
        [b.x[l], b.y[l], b.z[l], b.r[l]]
    }
    fn bytes(&self) -> usize {
        self.0.len() * std::mem::size_of::<Block>()
    }
    /// Ask for every cache line of block `blk` (a hint: any index is safe).
    #[inline(always)]
    fn prefetch_block(&self, blk: usize) {
        let p = self.0.as_ptr().wrapping_add(blk) as *const u8;
        for l in 0..LINES_PER_BLOCK {
            prefetch(p.wrapping_add(64 * l));
        }
    }
}

/// Lattice steps per cell edge of quantised slots (2^14). A slot stores its centre's lattice
/// coordinates modulo 2^16 (the u16 wraps every four cells) and is read relative to a corner one cell
/// below the cell (or row of cells) that holds it: a ball referenced by a k = 0 cell overlaps it and is
/// at most half a cell wide, and a k = 1 row holds centres of at most three consecutive cells, so the
/// centre lies within [1, 4) cells of that corner, where `q − corner` modulo 2^16 is its exact offset.
const LATTICE_PER_CELL: i64 = 1 << 14;

/// [`LANES`] quantised slots (issue 24's compact storage): the centres in lattice steps from the
/// cell's slot origin ([`LATTICE_PER_CELL`]) and each slot's code into its class's (R, τ) table.
/// One cache line where a [`Block`] and its τ and index take three.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, Default)]
struct QBlock {
    x: [u16; LANES],
    y: [u16; LANES],
    z: [u16; LANES],
    code: [u16; LANES],
}

/// The slots of a class in compact storage (overlap slots or centre cells): centres on a lattice of
/// step `step` (the cell edge
/// / [`LATTICE_PER_CELL`], 6·10⁻⁵ of a cell), radii and optical depths by code. The lattice point is
/// the particle *as stored*: every slot of a particle decodes to the same double-precision centre, the
/// cells that reference it were chosen from that centre, and the free flight is exact for it. Code 0
/// is padding: R = NaN, which no test passes.
#[derive(Default)]
struct QSlots {
    blocks: Vec<QBlock>,
    /// The largest inclusion radius of each block (its pre-test's radius: a per-lane gather costs
    /// more than the few extra exact tests on AMD's cores; each cell's slots are sorted by radius, so
    /// its blocks' radii stay close).
    block_reach: Vec<f32>,
    /// Inclusion radius per code.
    reach: Vec<f32>,
    /// τ per code and channel.
    tau: Vec<f32>,
    step: f64,
}

impl QSlots {
    /// The lattice coordinates of slot `s` of cell `cell` (k = 1: of the row that starts at `cell`).
    #[inline(always)]
    fn lattice(&self, s: usize, cell: [usize; 3]) -> [i64; 3] {
        let (b, l) = (&self.blocks[s / LANES], s % LANES);
        let origin = |a: usize| (cell[a] as i64 - 1) * LATTICE_PER_CELL;
        let at = |a: usize, q: u16| origin(a) + q.wrapping_sub(origin(a) as u16) as i64;
        [at(0, b.x[l]), at(1, b.y[l]), at(2, b.z[l])]
    }
    /// The slot origin of `cell` in lattice coordinates modulo 2^16: what a pre-test subtracts from a
    /// slot's coordinates to get its offset from that origin.
    #[inline(always)]
    fn origin_bits(cell: [usize; 3]) -> [u16; 3] {
        cell.map(|c| ((c as i64 - 1) * LATTICE_PER_CELL) as u16)
    }
    /// Centre (scene units) and inclusion radius of slot `s` of cell `cell` in a grid from `lo`.
    #[inline(always)]
    fn ball(&self, lo: [f64; 3], s: usize, cell: [usize; 3]) -> ([f64; 3], f64) {
        let g = self.lattice(s, cell);
        (
            [0, 1, 2].map(|a| lo[a] + g[a] as f64 * self.step),
            self.reach[self.code(s)] as f64,
        )
    }
    #[inline(always)]
    fn code(&self, s: usize) -> usize {
        self.blocks[s / LANES].code[s % LANES] as usize
    }
    fn bytes(&self) -> usize {
        self.blocks.len() * std::mem::size_of::<QBlock>()
            + (self.block_reach.len() + self.reach.len() + self.tau.len()) * 4
    }
}

/// The lattice point (steps of `step` from `lo`) nearest `p`.
#[inline]
fn lattice_point(p: [f64; 3], lo: [f64; 3], step: f64) -> [i64; 3] {
    [0, 1, 2].map(|a| ((p[a] - lo[a]) / step).round() as i64)
}

/// The ray as the pre-test sees it: two unit vectors `e1`, `e2` perpendicular to its direction and the
/// origin's coordinates along them, in single precision. A centre c lies within R of the ray's line iff
/// (c·e1 − o·e1)² + (c·e2 − o·e2)² < R²: the distance across the ray without forming c − o or its
/// projection on d (16 SSE operations per four lanes instead of 22, 14 AVX2 + FMA operations per eight,
/// and a shorter dependency chain).
#[derive(Clone, Copy)]
#[repr(C, align(32))]
struct RayFrame {
    // Each coefficient broadcast to the lanes of a block once per ray: the pre-test loop calls
    // out (to `found`), which spills every vector register, and reloading a broadcast vector is one
    // memory operand where a scalar costs a load and a shuffle per block (measured in
    // `benches/traverse.rs` and the sparse render, BENCHMARKS 10.2).
    e1: [[f32; LANES]; 3],
    e2: [[f32; LANES]; 3],
    o1: [f32; LANES],
    o2: [f32; LANES],
    /// The pre-test's tolerance (see [`PRETEST_SLACK`]).
    slack: [f32; LANES],
    /// e1 and e2 times the lattice step of quantised slots (zero for spheres).
    he1: [[f32; LANES]; 3],
    he2: [[f32; LANES]; 3],
    /// e1 and e2 in double precision (a quantised step's offset).
    e: [[f64; 3]; 2],
}

impl RayFrame {
    /// The frame of a cursor that tests no sphere.
    const UNUSED: RayFrame = RayFrame {
        e1: [[0.0; LANES]; 3],
        e2: [[0.0; LANES]; 3],
        o1: [0.0; LANES],
        o2: [0.0; LANES],
        slack: [0.0; LANES],
        he1: [[0.0; LANES]; 3],
        he2: [[0.0; LANES]; 3],
        e: [[0.0; 3]; 2],
    };

    /// The frame of `ray` for spheres, and for quantised slots of lattice step `step` (0: none).
    fn new(ray: &RaySegment, slack: f32, step: f64) -> Self {
        let (o, d) = (ray.o, ray.d);
        // Any unit vector perpendicular to d, then d × e1 (Duff et al.'s branchless basis).
        let sign = 1f64.copysign(d[2]);
        let a = -1.0 / (sign + d[2]);
        let b = d[0] * d[1] * a;
        let e1 = [1.0 + sign * d[0] * d[0] * a, sign * b, -sign * d[0]];
        let e2 = [b, sign + d[1] * d[1] * a, -d[1]];
        let dot = |u: [f64; 3]| u[0] * o[0] + u[1] * o[1] + u[2] * o[2];
        let lanes = |x: f64| [x as f32; LANES];
        RayFrame {
            e1: e1.map(lanes),
            e2: e2.map(lanes),
            o1: lanes(dot(e1)),
            o2: lanes(dot(e2)),
            slack: [slack; LANES],
            he1: e1.map(|x| lanes(x * step)),
            he2: e2.map(|x| lanes(x * step)),
            e: [e1, e2],
        }
    }

    /// How quantised slot origins lie across the ray: (corner − o)·e_k of the slot origin of cell
    /// (i, j, l) (its corner one cell below, `lo + (cell − 1) L`) is `[k][3] + i [k][0] + j [k][1] +
    /// l [k][2]`, so that a step's offsets cost three multiply-adds each.
    fn corner_offsets(&self, lo: [f64; 3], edge: [f64; 3], o: [f64; 3]) -> [[f64; 4]; 2] {
        self.e.map(|e| {
            let v = [0, 1, 2].map(|a| lo[a] - edge[a] - o[a]);
            [
                edge[0] * e[0],
                edge[1] * e[1],
                edge[2] * e[2],
                v[0] * e[0] + v[1] * e[1] + v[2] * e[2],
            ]
        })
    }
}

/// The lanes of a block whose sphere may contribute to the ray (seen through its [`RayFrame`]), as
/// bits: a conservative single-precision version of [`sphere_contribution`]. `WIDE`: one AVX2
/// operation per step ([`wide_simd`] said the CPU has it); otherwise two SSE operations (x86-64) or a
/// loop.
#[inline(always)]
fn block_pretest<const WIDE: bool>(b: &Block, f: &RayFrame) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if WIDE {
        // SAFETY: WIDE walks run only where `wide_simd()` found AVX2 and FMA.
        return unsafe { block_pretest_avx2(b, f) };
    }
    block_pretest_narrow(b, f)
}

/// [`block_pretest`] in one AVX2 operation per step (FMA rounds once where SSE rounds twice: the
/// slack covers both).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn block_pretest_avx2(b: &Block, f: &RayFrame) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY (loads): `Block` is 64-byte aligned and `RayFrame` 32-byte aligned, with eight-lane
    // fields, so each load is 32-byte aligned.
    let ld = |p: &[f32; LANES]| _mm256_load_ps(p.as_ptr());
    let (x, y, z) = (ld(&b.x), ld(&b.y), ld(&b.z));
    let across = |e: &[[f32; LANES]; 3], oe: &[f32; LANES]| {
        let c = _mm256_fmadd_ps(
            z,
            ld(&e[2]),
            _mm256_fmadd_ps(y, ld(&e[1]), _mm256_mul_ps(x, ld(&e[0]))),
        );
        _mm256_sub_ps(c, ld(oe))
    };
    let (q1, q2) = (across(&f.e1, &f.o1), across(&f.e2, &f.o2));
    let qq = _mm256_fmadd_ps(q1, q1, _mm256_mul_ps(q2, q2));
    let rr = _mm256_add_ps(ld(&b.r), ld(&f.slack));
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(qq, _mm256_mul_ps(rr, rr))) as u32
}

/// [`block_pretest`] four lanes per SSE operation (x86-64 baseline) or lane by lane.
#[inline(always)]
fn block_pretest_narrow(b: &Block, f: &RayFrame) -> u32 {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of x86_64; `Block` is 64-byte aligned and `RayFrame` 32-byte aligned with
    // lane arrays of a multiple of four, so each four-lane load is 16-byte aligned.
    unsafe {
        use std::arch::x86_64::*;
        let mut m = 0u32;
        for h in (0..LANES).step_by(4) {
            let ld = |p: &[f32; LANES]| _mm_load_ps(p.as_ptr().add(h));
            let (x, y, z) = (ld(&b.x), ld(&b.y), ld(&b.z));
            let across = |e: &[[f32; LANES]; 3], oe: &[f32; LANES]| {
                let c = _mm_add_ps(
                    _mm_add_ps(_mm_mul_ps(x, ld(&e[0])), _mm_mul_ps(y, ld(&e[1]))),
                    _mm_mul_ps(z, ld(&e[2])),
                );
                _mm_sub_ps(c, ld(oe))
            };
            let (q1, q2) = (across(&f.e1, &f.o1), across(&f.e2, &f.o2));
            let qq = _mm_add_ps(_mm_mul_ps(q1, q1), _mm_mul_ps(q2, q2));
            let rr = _mm_add_ps(ld(&b.r), ld(&f.slack));
            m |= (_mm_movemask_ps(_mm_cmplt_ps(qq, _mm_mul_ps(rr, rr))) as u32) << h;
        }
        m
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let mut m = 0u32;
        for l in 0..LANES {
            let c = [b.x[l], b.y[l], b.z[l]];
            let q1 = c[0] * f.e1[0][0] + c[1] * f.e1[1][0] + c[2] * f.e1[2][0] - f.o1[0];
            let q2 = c[0] * f.e2[0][0] + c[1] * f.e2[1][0] + c[2] * f.e2[2][0] - f.o2[0];
            let rr = b.r[l] + f.slack[0];
            m |= ((q1 * q1 + q2 * q2 < rr * rr) as u32) << l;
        }
        m
    }
}

/// The lanes of a quantised block whose ball may contribute to the ray: [`block_pretest`] for
/// centres `off + h (q·e)` across the ray and the block's largest radius `reach` (padding lanes
/// may pass: their exact test fails on R = NaN).
#[inline(always)]
fn qblock_pretest<const WIDE: bool>(
    b: &QBlock,
    reach: f32,
    f: &RayFrame,
    off: [f32; 2],
    base: [u16; 3],
) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if WIDE {
        // SAFETY: WIDE walks run only where `wide_simd()` found AVX2 and FMA.
        return unsafe { qblock_pretest_avx2(b, reach, f, off, base) };
    }
    let rr = reach + f.slack[0];
    let mut m = 0u32;
    for l in 0..LANES {
        let q = [
            b.x[l].wrapping_sub(base[0]) as f32,
            b.y[l].wrapping_sub(base[1]) as f32,
            b.z[l].wrapping_sub(base[2]) as f32,
        ];
        let across =
            |e: &[[f32; LANES]; 3], o: f32| o + q[0] * e[0][0] + q[1] * e[1][0] + q[2] * e[2][0];
        let (q1, q2) = (across(&f.he1, off[0]), across(&f.he2, off[1]));
        m |= ((q1 * q1 + q2 * q2 < rr * rr) as u32) << l;
    }
    m
}

/// [`qblock_pretest`] in AVX2: the u16 lattice offsets (wrapping differences) widened to f32.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn qblock_pretest_avx2(
    b: &QBlock,
    reach: f32,
    f: &RayFrame,
    off: [f32; 2],
    base: [u16; 3],
) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY (loads): `QBlock` is 64-byte aligned with 16-byte lane arrays; `RayFrame` 32-byte aligned.
    let wide = |p: &[u16; LANES], base: u16| {
        let q = _mm_load_si128(p.as_ptr() as *const __m128i);
        _mm256_cvtepu16_epi32(_mm_sub_epi16(q, _mm_set1_epi16(base as i16)))
    };
    let ld = |p: &[f32; LANES]| _mm256_load_ps(p.as_ptr());
    let (x, y, z) = (
        _mm256_cvtepi32_ps(wide(&b.x, base[0])),
        _mm256_cvtepi32_ps(wide(&b.y, base[1])),
        _mm256_cvtepi32_ps(wide(&b.z, base[2])),
    );
    let across = |e: &[[f32; LANES]; 3], o: f32| {
        _mm256_fmadd_ps(
            z,
            ld(&e[2]),
            _mm256_fmadd_ps(
                y,
                ld(&e[1]),
                _mm256_fmadd_ps(x, ld(&e[0]), _mm256_set1_ps(o)),
            ),
        )
    };
    let (q1, q2) = (across(&f.he1, off[0]), across(&f.he2, off[1]));
    let qq = _mm256_fmadd_ps(q1, q1, _mm256_mul_ps(q2, q2));
    let rr = _mm256_add_ps(_mm256_set1_ps(reach), ld(&f.slack));
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(qq, _mm256_mul_ps(rr, rr))) as u32
}

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
struct Probe {
    ray: RaySegment,
    frame: RayFrame,
    /// Quantised slots: where their origins lie across the ray (`RayFrame::corner_offsets`).
    corners: [[f64; 4]; 2],
}

impl Probe {
    /// A quantised step's offsets: (corner − o)·e1 and (corner − o)·e2 of the slot origin of `cell`, in
    /// single precision (rounded once from double: within the pre-test's slack).
    #[inline(always)]
    fn offsets(&self, cell: [usize; 3]) -> [f32; 2] {
        let [x, y, z] = cell.map(|c| c as f64);
        self.corners
            .map(|k| (k[3] + x * k[0] + y * k[1] + z * k[2]) as f32)
    }
}

/// When a ray comes near a layer of cells (k = 1, `SubGrid::step_rows`): along axis a, its coordinate
/// lies within R_max of cell layer m for t in [enter[a] + m step[a], exit[a] + m step[a]] (enter ≤
/// exit; an axis the ray runs across at d = 0 gets a direction of 1e-200, whose huge but finite t
/// values put the whole line near a layer it lies in, and never near another, with no NaN).
#[derive(Clone, Copy, Default)]
struct Near {
    enter: [f64; 3],
    exit: [f64; 3],
    step: [f64; 3],
    /// R_max with the grid's margin, in cells per axis.
    cells: [f64; 3],
    /// The ray's coordinates in cells from the grid's corner: `at + t per_t`.
    at: [f64; 3],
    per_t: [f64; 3],
}

impl Near {
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
fn fmax(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else {
        b
    }
}

/// The smaller of two numbers that are never NaN (see [`fmax`]).
#[inline(always)]
fn fmin(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

/// One size class of a [`ParticleGrid`]: particles of similar inclusion radius in a uniform grid whose cells are at least
/// as large as that radius (so a traversal scans only the 3×3×3 cells around each ray cell).
pub struct SubGrid {
    /// Centre (scene units) and inclusion radius R_i = r_c + r_i of each stored particle, stored in
    /// cell order.
    particles: Spheres,
    /// Optical depth contributed per particle, C_t / (π R_i²) in scene units⁰, [particle][channel].
    tau: Vec<f32>,
    /// Original index of each stored particle.
    index: Vec<u32>,
    channels: usize,
    /// Cell `c` holds slots `start[c]..start[c+1]`: k = 0, its own copies of the spheres of every
    /// particle whose ball overlaps it (`inline`, with `slot_tau`, `slot_index`), so a step reads one contiguous
    /// run; k = 1, the particles whose centre it holds (slot = stored particle).
    start: Vec<u32>,
    inline: Spheres,
    /// Per slot (k = 0): the particle's τ per channel and its original index, so that a hit reads
    /// them next to the slot instead of through the stored particle (two dependent cache misses per
    /// hit on clouds that overflow the cache). Empty for k = 1, whose slots are the stored particles.
    slot_tau: Vec<f32>,
    slot_index: Vec<u32>,
    /// The class's slots quantised (compact storage, [`GridSettings::quantise`]): in place of
    /// `inline` and `slot_tau` (k = 0), or of `particles` and `tau` (k = 1).
    quant: Option<QSlots>,
    /// The cells (cubes) as a DDA walks them.
    frame: GridFrame,
    /// Largest inclusion radius.
    reach_max: f64,
    /// Neighbourhood half-width in cells scanned per traversal step: 0 (sparse) or 1 (dense).
    k: i64,
    /// Are the slots too many to stay in cache (then a batch prefetches every block it will test)?
    prefetch_slots: bool,
    /// Particles of the class (`particles`, `tau` and `index` are emptied by `release_stored` where the
    /// slots hold copies of everything a walk reads).
    count: usize,
    /// Positional identities ([`ParticleGrid::positional`]): a k = 1 class with no `index` reports
    /// stored particle j as `first_id + j`.
    first_id: u32,
}

/// Rays a beam walks together at most ([`ParticleGrid::sample_sites_beam`]: a packet's lanes).
pub const BEAM_RAYS: usize = 16;
const _: () = assert!(BEAM_RAYS == crate::space::ray_lanes::RAYS);

/// Rays make a beam while they stay within this many R_max of their representative ray (δ): wider,
/// the blocks within R_max + δ of it hold few particles near any one ray, and every ray pre-tests them.
/// Measured (llvm_ad_rgb, seconds per render with beams / without, alternating): the dense haze of
/// `scripts/bench/render_seconds.py dense --res 256 --spp 64` 4.08–4.26 / 4.42–4.43 with any
/// spread, no gain below 1; the Cornell box with 10^5 grains of 2 mm at 96 px (δ up to several R_max)
/// 0.71 with 2, 0.73 without a bound, 0.71 without beams.
const BEAM_SPREAD: f64 = 2.0;
/// Halvings of its rays' segments a beam may take to keep within [`BEAM_SPREAD`] (then it covers their
/// first 1/64 in the box, and each ray walks the rest alone where it finds no site there).
const BEAM_CUTS: i32 = 6;

/// A free flight over its ray's contributions in t order ([`ParticleGrid::sample_site`]): contributions
/// closer than `coincide` along the ray form one site, and the flight interacts at the first site where
/// the optical depth walked passes −ln(1 − u).
struct Flight<'a> {
    exclude: &'a [u32],
    coincide: f64,
    target: f64,
    acc: f64,
    group: Site,
    group_tau: f64,
    last_t: f64,
    found: Option<Site>,
}

impl<'a> Flight<'a> {
    fn new(exclude: &'a [u32], u: f64, coincide: f64) -> Self {
        Flight {
            exclude,
            coincide,
            target: -(1.0 - u).ln(),
            acc: 0.0,
            group: Site::default(),
            group_tau: 0.0,
            last_t: f64::NEG_INFINITY,
            found: None,
        }
    }

    /// The next contribution (at t, optical depth `tau`, particle `i`); false once the site is found.
    #[inline(always)]
    fn visit(&mut self, t: f64, tau: f32, i: u32) -> bool {
        if self.exclude.contains(&i) {
            return true;
        }
        if self.group.len > 0 && t > self.last_t + self.coincide {
            // The group is complete: does the path interact there?
            if self.acc + self.group_tau > self.target {
                self.found = Some(self.group);
                return false;
            }
            self.acc += self.group_tau;
            self.group = Site::default();
            self.group_tau = 0.0;
        }
        if self.group.len == 0 {
            self.group.t = t;
        }
        self.group.push(i);
        self.group_tau += tau as f64;
        self.last_t = t;
        true
    }

    /// The site (None: the ray passed every contribution) and the optical depth walked before it.
    fn finish(mut self) -> (Option<Site>, f64) {
        if self.found.is_none() && self.group.len > 0 {
            if self.acc + self.group_tau > self.target {
                self.found = Some(self.group);
            } else {
                self.acc += self.group_tau;
            }
        }
        (self.found, self.acc)
    }
}

/// Rays walked as one beam through a class with centre cells ([`ParticleGrid::sample_sites_beam`]).
struct Beam {
    /// The representative ray (segment [s0, s1] covering every ray's projection), its pre-test
    /// slack grown by δ: the lanes it passes are those any ray's pre-test may pass.
    rep: Probe,
    /// The class's cells grown by one layer (a ray's point near the box's face projects on the
    /// representative ray within δ of it, possibly outside).
    cells: GridFrame,
    /// Where the representative ray comes within R_max + δ of the cell layers.
    near: Near,
    /// Per ray: (o − o_rep)·d_rep and d·d_rep, its points' projections on the representative ray.
    proj: [(f64, f64); BEAM_RAYS],
    /// Per ray: where the beam's part of its segment ends (infinity: at its end), the rest to walk on
    /// its own.
    cut: [f64; BEAM_RAYS],
    /// δ: the farthest any ray's segment in the class's box gets from the representative ray (what the
    /// walk uses of it is in `rep` and `near`; kept for tests).
    #[allow(dead_code)]
    delta: f64,
}

impl Beam {
    /// The t on ray `i` whose point projects at `s` on the representative ray.
    fn frontier(&self, i: usize, s: f64) -> f64 {
        (s - self.proj[i].0) / self.proj[i].1
    }
}

/// One contributing particle of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub particle: u32,
}

/// Where a sampled free flight interacts: the t of the first particle of the site and up to
/// [`Site::CAPACITY`] particles (coincident along the ray within the sampler's tolerance; further ones
/// still add their optical depth but not their phase function).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Site {
    pub t: f64,
    pub particles: [u32; Site::CAPACITY],
    pub len: u8,
    /// The particles' identities where members are classes (a procedural cloud's (tile, index) keys,
    /// `crate::render::procedural`); zero for stored particles, whose members are their indices.
    pub keys: [u64; Site::CAPACITY],
}

impl Site {
    pub const CAPACITY: usize = 4;
    /// Add a particle (beyond the capacity it is dropped: it still counted in the free flight).
    pub(crate) fn push(&mut self, i: u32) {
        if (self.len as usize) < Self::CAPACITY {
            self.particles[self.len as usize] = i;
            self.len += 1;
        }
    }
    pub fn members(&self) -> &[u32] {
        &self.particles[..self.len as usize]
    }
}

/// Counting sort of items by key (O(N)): the start of each key's run and the items in key order.
fn counting_sort(keys: &[u32], n_keys: usize) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; n_keys + 1];
    for &c in keys {
        start[c as usize + 1] += 1;
    }
    for c in 0..n_keys {
        start[c + 1] += start[c];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; keys.len()];
    for (i, &c) in keys.iter().enumerate() {
        order[fill[c as usize] as usize] = i as u32;
        fill[c as usize] += 1;
    }
    (start, order)
}

/// The slots of a k = 0 class: every cell references each stored particle whose inclusion ball
/// overlaps it, padded to whole blocks. Returns each cell's first slot (and the end) and the stored
/// particle of each slot (`PADDING_SLOT` for padding).
fn inline_slots(
    at: &(impl Fn(usize) -> [f64; 3] + Sync),
    reach: &impl Fn(usize) -> f64,
    order: &[u32],
    lo: [f64; 3],
    cell: f64,
    dims: [usize; 3],
) -> (Vec<u32>, Vec<u32>) {
    let n_cells = dims[0] * dims[1] * dims[2];
    let cell_index = |idx: [usize; 3]| (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
    // Cell ranges (per axis) overlapped by each stored particle's inclusion ball, then a second
    // counting sort of the (cell, particle) references.
    let axis_range = |x: f64, r: f64, a: usize| -> [usize; 2] {
        [x - r, x + r].map(|y| (((y - lo[a]) / cell).floor().max(0.0) as usize).min(dims[a] - 1))
    };
    let mut ref_cell = Vec::new();
    let mut ref_particle = Vec::new();
    for (j, &i) in order.iter().enumerate() {
        let (p, r) = (at(i as usize), reach(i as usize) * BOX_MARGIN.0);
        let rg = [0, 1, 2].map(|a| axis_range(p[a], r, a));
        for z in rg[2][0]..=rg[2][1] {
            for y in rg[1][0]..=rg[1][1] {
                for x in rg[0][0]..=rg[0][1] {
                    ref_cell.push(cell_index([x, y, z]) as u32);
                    ref_particle.push(j as u32);
                }
            }
        }
    }
    let (refs_start, slot_order) = counting_sort(&ref_cell, n_cells);
    // Each cell's run padded to whole blocks, so that a step tests whole blocks of its own
    // (no lane masks, and a cell of eight never straddles two blocks). Padding lanes have NaN
    // centres: every comparison with them is false, so they contribute to no ray.
    let mut start = vec![0u32; n_cells + 1];
    for c in 0..n_cells {
        let len = refs_start[c + 1] - refs_start[c];
        start[c + 1] = start[c] + len.div_ceil(LANES as u32) * LANES as u32;
    }
    let mut slot_particle = vec![PADDING_SLOT; start[n_cells] as usize];
    for c in 0..n_cells {
        let (from, to) = (refs_start[c] as usize, refs_start[c + 1] as usize);
        for (k, &r) in slot_order[from..to].iter().enumerate() {
            slot_particle[start[c] as usize + k] = ref_particle[r as usize];
        }
    }
    (start, slot_particle)
}

/// Each slot's copy of its particle's sphere (padding: NaN centres, which no test passes).
fn slot_spheres(slot_particle: &[u32], particles: &Spheres) -> Spheres {
    Spheres::from_iter(slot_particle.len(), |s| match slot_particle[s] {
        PADDING_SLOT => [f32::NAN, f32::NAN, f32::NAN, 0.0],
        j => particles.get(j as usize),
    })
}

/// The quantised slots ([`QSlots`]) of a class of particles at `positions` (storage order `order`) on
/// the lattice of `step` from `lo` (each at its nearest point), or None where they have more distinct
/// (R, τ) pairs than a u16 code holds (then the class keeps spheres). `slot_particle`: each slot's
/// stored particle (k = 0), or None where slot j is stored particle j (k = 1).
#[allow(clippy::too_many_arguments)]
fn build_qslots(
    position: impl Fn(usize) -> [f64; 3],
    reach: impl Fn(usize) -> f64,
    tau: impl Fn(usize, usize) -> f32,
    channels: usize,
    order: &[u32],
    start: &[u32],
    slot_particle: Option<&[u32]>,
    lo: [f64; 3],
    step: f64,
    dims: [usize; 3],
) -> Option<QSlots> {
    if channels > 3 {
        return None;
    }
    // Codes by (R, τ) of each stored particle j; code 0 is padding.
    let mut table: rustc_hash::FxHashMap<[u32; 4], u16> = Default::default();
    let mut q_reach = vec![f32::NAN];
    let mut q_tau = vec![0f32; channels];
    let mut code_of = Vec::with_capacity(order.len());
    for &i in order {
        let r = reach(i as usize) as f32;
        let mut t = [0f32; 3];
        for (ch, x) in t.iter_mut().enumerate().take(channels) {
            *x = tau(i as usize, ch);
        }
        let t = &t[..channels];
        let mut key = [r.to_bits(), 0, 0, 0];
        for (k, x) in t.iter().enumerate() {
            key[k + 1] = x.to_bits();
        }
        let code = match table.get(&key) {
            Some(&c) => c,
            None => {
                if q_reach.len() > u16::MAX as usize {
                    return None;
                }
                let c = q_reach.len() as u16;
                table.insert(key, c);
                q_reach.push(r);
                q_tau.extend_from_slice(t);
                c
            }
        };
        code_of.push(code);
    }
    let slots = slot_particle.map_or(order.len(), <[u32]>::len);
    let mut blocks = vec![QBlock::default(); slots.div_ceil(LANES)];
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let c = (z * dims[1] + y) * dims[0] + x;
                let origin = [x, y, z].map(|i| (i as i64 - 1) * LATTICE_PER_CELL);
                for s in start[c] as usize..start[c + 1] as usize {
                    let j = slot_particle.map_or(s as u32, |sp| sp[s]);
                    if j == PADDING_SLOT {
                        continue; // code 0, R = NaN
                    }
                    let g = lattice_point(position(order[j as usize] as usize), lo, step);
                    // The coordinates modulo 2^16 (`LATTICE_PER_CELL`), read relative to a corner
                    // within four cells below.
                    // From the slot's cell's corner: [L, 2L) for a centre cell (its own centre),
                    // [0, 2^16) for an overlap slot (a ball that reaches into the cell).
                    let q = [0, 1, 2].map(|a| {
                        let rel = g[a] - origin[a];
                        let own = LATTICE_PER_CELL..2 * LATTICE_PER_CELL;
                        debug_assert!(
                            if slot_particle.is_none() {
                                own.contains(&rel)
                            } else {
                                (0..=u16::MAX as i64).contains(&rel)
                            },
                            "lattice offset {rel}"
                        );
                        g[a] as u16
                    });
                    let (b, l) = (&mut blocks[s / LANES], s % LANES);
                    (b.x[l], b.y[l], b.z[l], b.code[l]) = (q[0], q[1], q[2], code_of[j as usize]);
                }
            }
        }
    }
    let block_reach = blocks
        .iter()
        .map(|b| {
            b.code
                .iter()
                .filter(|&&c| c != 0)
                .map(|&c| q_reach[c as usize])
                .fold(0.0f32, f32::max)
        })
        .collect();
    Some(QSlots {
        blocks,
        block_reach,
        reach: q_reach,
        tau: q_tau,
        step,
    })
}

/// The optical depth of a particle's disk in one channel: C_ext / (π R²), R its inclusion radius
/// (the caller has already capped it at tau_max by widening R).
#[inline]
fn disk_tau(c_ext: f64, reach: f64) -> f32 {
    (c_ext / (std::f64::consts::PI * reach * reach)) as f32
}

/// Each particle's [`disk_tau`] per channel, in storage order `order`.
fn disk_taus(order: &[u32], tau: impl Fn(usize, usize) -> f32, channels: usize) -> Vec<f32> {
    let mut out = vec![0f32; order.len() * channels];
    for (j, &i) in order.iter().enumerate() {
        for ch in 0..channels {
            out[j * channels + ch] = tau(i as usize, ch);
        }
    }
    out
}

/// What a hit reads, per slot of a k = 0 class: its particle's τ per channel and original index
/// (padding slots: τ = 0, index unused); no τ where `tau` is empty (quantised slots: τ by code).
fn slot_hits(
    slot_particle: &[u32],
    tau: &[f32],
    index: &[u32],
    channels: usize,
) -> (Vec<f32>, Vec<u32>) {
    let slot_of = |sp: &u32| (*sp != PADDING_SLOT).then_some(*sp as usize);
    if tau.is_empty() {
        let index = slot_particle
            .iter()
            .map(|sp| slot_of(sp).map_or(u32::MAX, |j| index[j]))
            .collect();
        return (Vec::new(), index);
    }
    let mut slot_tau = vec![0f32; slot_particle.len() * channels];
    for (s, sp) in slot_particle.iter().enumerate() {
        if let Some(j) = slot_of(sp) {
            slot_tau[s * channels..(s + 1) * channels]
                .copy_from_slice(&tau[j * channels..(j + 1) * channels]);
        }
    }
    let slot_index = slot_particle
        .iter()
        .map(|sp| slot_of(sp).map_or(u32::MAX, |j| index[j]))
        .collect();
    (slot_tau, slot_index)
}

impl SubGrid {
    /// Build one class from already validated inputs (see [`ParticleGrid::build`]): the particles
    /// `ids` of `p` (the caller's indices, which the class reports).
    fn build_class(
        p: &Particles,
        ids: &[u32],
        settings: &GridSettings,
        volume_hint: Option<f64>,
        free_path_cell: Option<f64>,
    ) -> Self {
        let (n, channels) = (ids.len(), p.channels);
        // The class's particle j: the caller's ids[j], read where needed (no copies of the columns).
        let position = |j: usize| p.positions[ids[j] as usize];
        let reach = |j: usize| settings.query_radius + (p.radius)(ids[j] as usize);
        let tau = |j: usize, ch: usize| disk_tau((p.c_ext)(ids[j] as usize, ch), reach(j));
        let reach_max = (0..n).into_par_iter().map(reach).reduce(|| 0.0, f64::max);
        let (mut lo, mut hi) = bounding_box_by(n, position);
        for a in 0..3 {
            lo[a] -= reach_max * BOX_MARGIN.0 + BOX_MARGIN.1;
            hi[a] += reach_max * BOX_MARGIN.0 + BOX_MARGIN.1;
        }
        let mut ext: Vec<f64> = (0..3).map(|a| hi[a] - lo[a]).collect();
        let volume = volume_hint
            .unwrap_or(ext[0] * ext[1] * ext[2])
            .max(ext[0] * ext[1] * ext[2] * 1e-9);

        // About `cells_per_particle` cells per particle. Sparse classes (inclusion diameter below the
        // cell) reference each particle from every cell its ball overlaps (k = 0: a traversal tests only
        // the ray's own cells). Dense classes (balls wider than the spacing) would need many references
        // per particle; there cells are at least R_max wide, each particle is referenced by its centre's
        // cell only, and a traversal scans the 3×3×3 cells around the ray's cell (k = 1).
        // With `centre_cells` every class is stored by its centres' cells (k = 1; issue 24's compact
        // storage: each particle once, in eight bytes).
        let factor = if settings.centre_cells {
            CENTRE_CELLS_FACTOR
        } else {
            1.0
        };
        let mut spacing = cell_spacing(volume, n, settings.cells_per_particle * factor);
        if let Some(l) = free_path_cell {
            // An optically thick cloud: cells about its free flights' length (FREE_PATHS_PER_CELL).
            let finest = cell_spacing(volume, n, FREE_PATH_CELLS_PER_PARTICLE_MAX);
            spacing = spacing.min(l.max(finest));
        }
        let k: i64 = if !settings.centre_cells && is_sparse(reach_max, spacing) {
            0
        } else {
            1
        };
        let cell = spacing.max(reach_max).max(1e-12);
        // Compact storage quantises a class's centres to a lattice of its cells (`QSlots`): from here
        // on the particles are those lattice points, the box grown by two steps to hold them.
        let quantise = settings.quantise;
        let step = cell / LATTICE_PER_CELL as f64;
        if quantise {
            for a in 0..3 {
                lo[a] -= 2.0 * step;
                hi[a] += 2.0 * step;
                ext[a] = hi[a] - lo[a];
            }
        }
        // Each particle's centre as stored (computed where needed: no copy of the positions).
        let at = |i: usize| -> [f64; 3] {
            if quantise {
                let g = lattice_point(position(i), lo, step);
                [0, 1, 2].map(|a| lo[a] + g[a] as f64 * step)
            } else {
                position(i)
            }
        };
        let dims =
            [0, 1, 2].map(|a| ((ext[a] / cell).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS));
        let n_cells = dims[0] * dims[1] * dims[2];
        let cell_index = |idx: [usize; 3]| (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
        let cell_of = |p: &[f64; 3]| {
            cell_index([0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1)))
        };
        // The storage order: particles sorted by the cell of their centre. A quantised centre's cell
        // comes from its lattice coordinates, in integers: a lattice point on a cell face must be in
        // the cell whose corner its slots are read from (in floating point (lo + g h − lo) / L can
        // round below the face, and the wrapped offset from a row's corner 3 cells down would read
        // 2^16 as 0: the centre 4 cells away).
        let cells: Vec<u32> = (0..n)
            .into_par_iter()
            .map(|i| {
                if quantise {
                    let g = lattice_point(position(i), lo, step);
                    cell_index([0, 1, 2].map(|a| {
                        (g[a].div_euclid(LATTICE_PER_CELL).max(0) as usize).min(dims[a] - 1)
                    })) as u32
                } else {
                    cell_of(&at(i)) as u32
                }
            })
            .collect();
        let (centre_start, mut order) = counting_sort(&cells, n_cells);
        drop(cells);
        if quantise && k == 1 {
            // Largest balls first in each cell: a block's pre-test radius is its largest.
            for c in 0..n_cells {
                order[centre_start[c] as usize..centre_start[c + 1] as usize]
                    .sort_unstable_by(|a, b| reach(*b as usize).total_cmp(&reach(*a as usize)));
            }
        }
        let sphere_of = |i: usize| {
            let p = at(i);
            [p[0] as f32, p[1] as f32, p[2] as f32, reach(i) as f32]
        };
        // Quantised k = 1 slots are the stored particles: no spheres besides them.
        let particles = if quantise && k == 1 {
            Spheres::default()
        } else {
            Spheres::from_iter(n, |j| sphere_of(order[j] as usize))
        };
        let (start, mut slot_particle) = if k == 1 {
            // Each cell's slots are its own particles, already in cell order.
            (centre_start, Vec::new())
        } else {
            inline_slots(&at, &reach, &order, lo, cell, dims)
        };
        if quantise && k == 0 {
            // Largest balls first in each cell, padding last: a block's pre-test radius is its
            // largest, so blocks of like radii test tightly.
            let key = |j: &u32| match *j {
                PADDING_SLOT => -1.0,
                j => reach(order[j as usize] as usize),
            };
            for c in 0..n_cells {
                slot_particle[start[c] as usize..start[c + 1] as usize]
                    .sort_unstable_by(|a, b| key(b).total_cmp(&key(a)));
            }
        }
        let quant = quantise
            .then(|| {
                build_qslots(
                    position,
                    reach,
                    tau,
                    channels,
                    &order,
                    &start,
                    (k == 0).then_some(&slot_particle[..]),
                    lo,
                    step,
                    dims,
                )
            })
            .flatten();
        let particles = match (&quant, k) {
            // Too many codes: spheres after all.
            (None, 1) if particles.0.is_empty() && n > 0 => {
                Spheres::from_iter(n, |j| sphere_of(order[j] as usize))
            }
            _ => particles,
        };
        // τ per stored particle where no code holds it.
        let tau = if quant.is_some() {
            Vec::new()
        } else {
            disk_taus(&order, tau, channels)
        };
        let inline = if k == 0 && quant.is_none() {
            slot_spheres(&slot_particle, &particles)
        } else {
            Spheres::default()
        };
        let index: Vec<u32> = order.iter().map(|&i| ids[i as usize]).collect();
        let slot_bytes = quant.as_ref().map_or(inline.bytes(), QSlots::bytes);
        let prefetch_slots = slot_bytes.max(particles.bytes()) > PREFETCH_SLOTS_ABOVE_BYTES;
        // Quantised slots read τ by code.
        let slot_tau_of: &[f32] = if quant.is_some() { &[] } else { &tau };
        let (slot_tau, slot_index) = slot_hits(&slot_particle, slot_tau_of, &index, channels);
        SubGrid {
            particles,
            tau,
            index,
            channels,
            start,
            inline,
            slot_tau,
            slot_index,
            quant,
            frame: GridFrame::new(lo, [cell; 3], dims),
            reach_max,
            k,
            prefetch_slots,
            count: n,
            first_id: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.count
    }
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Drop the stored particles of a class whose cells hold their own copies (k = 0): a walk, a
    /// point query and a hit read only the slots. The oracles then read the slots too.
    fn release_stored(&mut self) {
        if self.k == 0 {
            self.particles = Spheres::default();
            self.tau = Vec::new();
            self.index = Vec::new();
        }
    }

    /// Each particle once with its sphere, τ per channel and original index: the stored particles,
    /// or (released) the first slot of each (the oracles' view).
    #[cfg(any(test, feature = "oracles"))]
    fn each_particle(&self, mut visit: impl FnMut(([f64; 3], f64), &[f32], u32)) {
        let ball = |p: [f32; 4]| ([p[0] as f64, p[1] as f64, p[2] as f64], p[3] as f64);
        if self.index.len() == self.count && self.quant.is_none() {
            for j in 0..self.count {
                visit(
                    ball(self.particles.get(j)),
                    &self.tau[j * self.channels..(j + 1) * self.channels],
                    self.index[j],
                );
            }
            return;
        }
        // The slots (quantised: decoded in their cells), each particle at its first.
        let mut seen = std::collections::HashSet::new();
        let dims = self.frame.dims;
        for c in 0..dims[0] * dims[1] * dims[2] {
            let cell = [c % dims[0], c / dims[0] % dims[1], c / (dims[0] * dims[1])];
            for s in self.start[c] as usize..self.start[c + 1] as usize {
                let i = self.hit_index(s);
                if i != u32::MAX && seen.insert(i) {
                    visit(self.slot_ball(s, cell), self.hit_tau(s), i);
                }
            }
        }
    }
    pub fn channels(&self) -> usize {
        self.channels
    }
    pub fn dims(&self) -> [usize; 3] {
        self.frame.dims
    }

    /// Heap bytes of the grid and the particles it stores.
    pub fn bytes(&self) -> usize {
        self.particles.bytes()
            + self.inline.bytes()
            + self.quant.as_ref().map_or(0, QSlots::bytes)
            + self.slot_tau.len() * 4
            + self.slot_index.len() * 4
            + self.tau.len() * 4
            + self.index.len() * 4
            + self.start.len() * 4
    }

    /// The slots' spheres.
    #[inline(always)]
    fn slots(&self) -> &Spheres {
        if self.k == 0 {
            &self.inline
        } else {
            &self.particles
        }
    }
    /// Centre and inclusion radius of slot `s` of cell `cell` (double precision).
    #[inline(always)]
    fn slot_ball(&self, s: usize, cell: [usize; 3]) -> ([f64; 3], f64) {
        match &self.quant {
            Some(q) => q.ball(self.frame.bounds.lo, s, cell),
            None => {
                let p = self.slots().get(s);
                ([p[0] as f64, p[1] as f64, p[2] as f64], p[3] as f64)
            }
        }
    }
    /// τ per channel of the particle in slot `s` (what `walk` reports).
    #[inline(always)]
    fn hit_tau(&self, s: usize) -> &[f32] {
        if let Some(q) = &self.quant {
            let c = q.code(s);
            return &q.tau[c * self.channels..(c + 1) * self.channels];
        }
        let tau = if self.k == 0 {
            &self.slot_tau
        } else {
            &self.tau
        };
        &tau[s * self.channels..(s + 1) * self.channels]
    }
    /// Original index of the particle in slot `s` (positional grids: its position).
    #[inline(always)]
    fn hit_index(&self, s: usize) -> u32 {
        if self.k == 0 {
            self.slot_index[s]
        } else if self.index.is_empty() {
            self.first_id + s as u32
        } else {
            self.index[s]
        }
    }

    /// When `ray` comes near each layer of cells ([`Near`]).
    fn near(&self, ray: &RaySegment) -> Near {
        self.near_reach(ray, self.reach_max * BOX_MARGIN.0 + BOX_MARGIN.1)
    }

    /// [`Near`] of a ray for balls of radius `reach`.
    fn near_reach(&self, ray: &RaySegment, reach: f64) -> Near {
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

    /// The pre-test's slack for a ray from `o`: the single-precision rounding of coordinates of that
    /// magnitude, and of quantised slots' lattice offsets.
    fn pretest_slack(&self, o: [f64; 3]) -> f64 {
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
    fn probe(&self, ray: &RaySegment, widen: f64) -> Probe {
        let step = self.quant.as_ref().map_or(0.0, |q| q.step);
        let frame = RayFrame::new(ray, (self.pretest_slack(ray.o) + widen) as f32, step);
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
    fn pretest<const WIDE: bool>(
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

    /// The beam of `rays` through this class ([`ParticleGrid::sample_sites_beam`]), if they make one:
    /// directions within ~25° of their mean, and the farthest any ray's segment in the class's box
    /// gets from the representative ray (their mean direction through their mean entry point), δ,
    /// small enough that R_max + δ stays within a cell.
    /// Each ray as the tests see it goes to `probes` (None: it misses the class's box).
    fn beam(&self, rays: &[RaySegment], probes: &mut [Option<Probe>; BEAM_RAYS]) -> Option<Beam> {
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let mut clip = [None; BEAM_RAYS];
        let (mut sum, mut live) = ([0.0; 3], 0);
        for (i, r) in rays.iter().enumerate() {
            // (A NaN origin or direction clips to a NaN-free range and would poison the mean.)
            if !r.o.iter().chain(&r.d).all(|x| x.is_finite()) {
                return None;
            }
            // (An empty segment, NaN ends included, has no contribution: no probe. The box's clip
            // drops a NaN end.)
            clip[i] = if r.is_empty() {
                None
            } else {
                self.frame.bounds.clip(r)
            };
            if clip[i].is_some() {
                (0..3).for_each(|a| sum[a] += r.d[a]);
                live += 1;
            }
        }
        let norm = dot(sum, sum).sqrt();
        let d = (live > 0 && norm > 0.0).then(|| sum.map(|x| x / norm))?;
        let at = |r: &RaySegment, t: f64| [0, 1, 2].map(|a| r.o[a] + t * r.d[a]);
        let mut o = [0.0; 3];
        for (r, c) in rays.iter().zip(&clip) {
            if let Some((t0, _)) = c {
                let p = at(r, *t0);
                (0..3).for_each(|a| o[a] += p[a] / live as f64);
            }
        }
        let mut proj = [(0.0, 1.0); BEAM_RAYS];
        for (i, (r, c)) in rays.iter().zip(&clip).enumerate() {
            if c.is_none() {
                continue;
            }
            let cos = dot(r.d, d);
            if cos.is_nan() || cos < 0.9 {
                return None;
            }
            let rel = [0, 1, 2].map(|a| r.o[a] - o[a]);
            proj[i] = (dot(rel, d), cos);
        }
        // δ and the representative's range [s0, s1] over the rays' segments in the box, each cut to
        // its first 1 / 2^k (δ is largest at a segment's ends: a ray's distance from another line
        // is convex along it).
        let spread = |k: i32| {
            let (mut delta, mut s0, mut s1) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY);
            for (r, c) in rays.iter().zip(&clip) {
                let Some((t0, t1)) = *c else { continue };
                for t in [t0, t0 + (t1 - t0) * 0.5f64.powi(k)] {
                    let p = at(r, t);
                    let v = [0, 1, 2].map(|a| p[a] - o[a]);
                    let s = dot(v, d);
                    let across = [0, 1, 2].map(|a| v[a] - s * d[a]);
                    delta = delta.max(dot(across, across).sqrt());
                    s0 = s0.min(s);
                    s1 = s1.max(s);
                }
            }
            (delta, s0, s1)
        };
        let cell = self.frame.cell;
        let reach_with = |delta: f64| self.reach_max * BOX_MARGIN.0 + BOX_MARGIN.1 + delta;
        let fits = |&(_, (delta, s0, s1)): &(i32, (f64, f64, f64))| {
            s0.is_finite()
                && s1.is_finite()
                && reach_with(delta) <= cell[0].min(cell[1]).min(cell[2])
                && delta <= BEAM_SPREAD * self.reach_max
        };
        // Rays that spread too far over the whole box (a pixel's camera rays through a deep cloud)
        // make a beam over their first part: most of them find their site there in a dense cloud,
        // the others go on one by one from where it ends (`ParticleGrid::beam_lanes`).
        let (k, (delta, s0, s1)) = (0..=BEAM_CUTS).map(|k| (k, spread(k))).find(fits)?;
        let reach = reach_with(delta);
        let rep = RaySegment::new(o, d, s0, s1);
        let mut cut = [f64::INFINITY; BEAM_RAYS];
        for (i, r) in rays.iter().enumerate() {
            let Some((t0, t1)) = clip[i] else { continue };
            if k > 0 {
                cut[i] = (t0 + (t1 - t0) * 0.5f64.powi(k)).min(r.t1);
            }
            probes[i] = Some(self.probe(&r.between(r.t0, cut[i].min(r.t1)), 0.0));
        }
        let lo = self.frame.bounds.lo;
        Some(Beam {
            cut,
            rep: self.probe(&rep, delta),
            cells: GridFrame::new(
                [0, 1, 2].map(|a| lo[a] - cell[a]),
                cell,
                self.frame.dims.map(|n| n + 2),
            ),
            near: self.near_reach(&rep, reach),
            proj,
            delta,
        })
    }

    /// Start a traversal of a ray segment, |d| = 1, `inv_d` the direction's reciprocals.
    pub(crate) fn cursor(&self, ray: &RaySegment, inv_d: [f64; 3]) -> Cursor {
        let b = &self.frame.bounds;
        let dda = Dda::new_in(&self.frame, ray, inv_d);
        // A ray that misses the grid tests nothing: no frame for it (in a room with a cloud in it,
        // most shadow rays).
        let misses = dda.finished();
        let frame = if misses {
            RayFrame::UNUSED
        } else {
            let step = self.quant.as_ref().map_or(0.0, |q| q.step);
            RayFrame::new(ray, self.pretest_slack(ray.o) as f32, step)
        };
        Cursor {
            dda,
            probe: Probe {
                ray: *ray,
                corners: if self.quant.is_some() && !misses {
                    frame.corner_offsets(b.lo, self.frame.cell, ray.o)
                } else {
                    [[0.0; 4]; 2]
                },
                frame,
            },
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

    /// Where a segment's quantised slots lie across the ray (`Segment::off`, `Segment::base`): once per
    /// segment, before its slots are tested (spheres need nothing).
    #[inline(always)]
    fn locate(&self, sg: &mut Segment, probe: &Probe) {
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
    fn advance<const WIDE: bool>(
        &self,
        cur: &mut Cursor,
        found: &mut impl FnMut(f64, usize) -> bool,
    ) -> Option<f64> {
        // The walk is memory-latency bound on dense clouds: a cell's start offset, then its slots are
        // dependent cache misses. So the DDA runs ahead over a batch of steps, gathering the row
        // segments to test, and each level of loads of the whole batch is prefetched before the next
        // is read (many misses in flight instead of one after the other: 14.1 -> 4.8 us per dense ray
        // in `benches/traverse.rs`).
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
            (sg.c0, sg.c1) = (self.start[sg.c0] as usize, self.start[sg.c1] as usize);
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
    fn test_slots<const WIDE: bool>(
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
            // Lanes of this block inside the segment's slot range.
            let base = LANES * blk;
            let first = (sg.c0.max(base) - base) as u32;
            let end = (sg.c1.min(base + LANES) - base) as u32;
            let lanes = (ALL_LANES >> (LANES as u32 - end)) & (ALL_LANES << first);
            if !self.test_block::<WIDE>(slots, blk, lanes, sg, probe, found) {
                return false;
            }
        }
        true
    }

    /// Test the `lanes` of slot block `blk` against the ray (pre-test, then the exact test) and report
    /// each contribution in the step's t range as `found(t, slot)`; false when `found` stops.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn test_block<const WIDE: bool>(
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
    fn test_qblock(
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
    /// whole blocks), no batch of segments to gather and prefetch. The same contract as `advance`
    /// (measured in `benches/traverse.rs`: sparse free flight 0.49 -> 0.39 us per ray without the
    /// batch; cells padded to whole blocks then make larger cells pay, see DEFAULT_CELLS_PER_PARTICLE).
    #[inline(always)]
    fn advance_cached_sparse<const WIDE: bool>(
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
    fn advance_cached_near<const WIDE: bool>(
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
                (sg.c0, sg.c1) = (self.start[sg.c0] as usize, self.start[sg.c1] as usize);
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
    fn next_rows(&self, cur: &mut Cursor, out: &mut [Segment]) -> Option<(usize, f64, bool)> {
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
    fn step_rows(
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
    fn near_rows(
        &self,
        c: [i64; 3],
        prev: Option<[i64; 3]>,
        t0: f64,
        t1: f64,
        near: &Near,
        out: &mut [Segment],
    ) -> usize {
        let dims = self.frame.dims.map(|d| d as i64);
        // Cells within one of `c` along axis a (clamped to the grid), or the slab's one coordinate.
        let mut range = [0, 1, 2].map(|a| [(c[a] - 1).max(0), (c[a] + 1).min(dims[a] - 1)]);
        // Where the segment comes within R_max of the candidate cells: first a t interval (near the
        // slab's layer, or near the block along every axis), then along each other axis the layers
        // the ray's coordinate comes near over that interval (a cell whose grown box the ray crosses
        // at t has t in the interval and its layers within R_max of the coordinates there: none is
        // dropped).
        let (mut t0, mut t1) = (t0, t1);
        // The layers near the segment along `a` over [t0, t1], within `range[a]` (None: none). A
        // layer m is near where [m, m + 1) meets the coordinate's span grown by R_max (in cells).
        if let Some(p) = prev {
            // The axis the step moved along (exactly one differs), without a branch per axis.
            let a = usize::from(p[1] != c[1]) + 2 * usize::from(p[2] != c[2]);
            let far = if c[a] > p[a] { c[a] + 1 } else { c[a] - 1 };
            if far < 0 || far >= dims[a] {
                return 0; // the slab lies outside the grid
            }
            t0 = fmax(t0, near.enter[a] + far as f64 * near.step[a]);
            t1 = fmin(t1, near.exit[a] + far as f64 * near.step[a]);
            if t0 > t1 {
                return 0;
            }
            range[a] = [far, far];
            for b in [(a + 1) % 3, (a + 2) % 3] {
                match near.layers(b, t0, t1, range[b]) {
                    Some(r) => range[b] = r,
                    None => return 0,
                }
            }
        } else {
            if range.iter().any(|r| r[0] > r[1]) {
                return 0; // the block lies outside the grid
            }
            for a in 0..3 {
                let [m0, m1] = range[a];
                let (first, last) = if near.step[a] > 0.0 {
                    (m0, m1)
                } else {
                    (m1, m0)
                };
                t0 = fmax(t0, near.enter[a] + first as f64 * near.step[a]);
                t1 = fmin(t1, near.exit[a] + last as f64 * near.step[a]);
            }
            if t0 > t1 {
                return 0;
            }
            for a in 0..3 {
                match near.layers(a, t0, t1, range[a]) {
                    Some(r) => range[a] = r,
                    None => return 0,
                }
            }
        }
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

    /// Optical depth of a ray segment, per channel, by a loop over every particle (the O(N) oracle of
    /// the tests).
    #[cfg(any(test, feature = "oracles"))]
    pub fn optical_depth_brute(&self, ray: &RaySegment, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        if ray.is_empty() {
            return;
        }
        self.each_particle(|(c, r), tau, _| {
            if let Some(t) = ball_contribution(c, r, ray) {
                if ray.contains(t) {
                    out.iter_mut().zip(tau).for_each(|(v, &x)| *v += x as f64);
                }
            }
        });
    }

    /// Per-stored-particle optical depth (channel), for tests.
    #[cfg(any(test, feature = "oracles"))]
    pub fn tau_of(&self, original: u32, channel: usize) -> f64 {
        let mut out = None;
        self.each_particle(|_, tau, i| {
            if i == original {
                out = Some(tau[channel] as f64);
            }
        });
        out.expect("a particle of this class")
    }

    pub fn reach_max(&self) -> f64 {
        self.reach_max
    }
}

/// Default grid resolution, in cells per particle: about eight particles per cell. A step tests its
/// cell's spheres eight per pre-test in whole blocks, so larger cells than the paper's one particle
/// per voxel (Sec. 6.5) pay: fewer DDA steps for a few more (cheap) sphere tests (measured in
/// `cargo bench -p motes-core --bench traverse` over 1, 0.5, 0.25, 0.125, 0.0625, AVX2 walk: free
/// flights 0.60, 0.35, 0.30, 0.27, 0.27 us per sparse ray; 2.20, 2.01, 1.98, 2.00, 2.22 us per dense
/// one; memory falls with the cell count).
pub const DEFAULT_CELLS_PER_PARTICLE: f64 = 0.125;

/// How a [`ParticleGrid`] is laid over its particles: the query radius r_c (scene units; a particle
/// contributes to the rays passing within r_c + r_i of its centre, Sec. 5.3) and the resolution in
/// cells per particle (paper Sec. 6.5: about one particle per voxel; see
/// [`DEFAULT_CELLS_PER_PARTICLE`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridSettings {
    pub query_radius: f64,
    pub cells_per_particle: f64,
    /// Quantise every class's slots ([`QSlots`]: centres on a lattice of 2^14 steps per cell, radii
    /// and τ by code): 8 bytes a slot (12 with an overlap slot's index) instead of 24.
    pub quantise: bool,
    /// Store every class by its centres' cells (k = 1: each particle once, the walk scanning the
    /// cells around the ray) instead of referencing sparse classes' balls from every cell they
    /// overlap: with `quantise`, eight bytes per particle instead of ~2.5 slots of twelve.
    pub centre_cells: bool,
    /// Free flights stop at their first interaction: where the cloud's mean free path is shorter
    /// than a cell, size the cells by it ([`FREE_PATHS_PER_CELL`]) instead of by the particle count
    /// (a renderer's grid; the queries along whole segments, Eq. 18, keep the count's cells).
    pub free_path_cells: bool,
}

impl GridSettings {
    pub fn new(query_radius: f64, cells_per_particle: f64) -> Self {
        GridSettings {
            query_radius,
            cells_per_particle,
            quantise: false,
            centre_cells: false,
            free_path_cells: false,
        }
    }
    /// The same settings, cells sized by the mean free path where it is the shorter or not.
    pub fn by_free_path(self, free_path_cells: bool) -> Self {
        GridSettings {
            free_path_cells,
            ..self
        }
    }
    /// The same settings, quantising the slots or not.
    pub fn quantised(self, quantise: bool) -> Self {
        GridSettings { quantise, ..self }
    }
    /// The same settings, every class stored by its centres' cells or not.
    pub fn centred(self, centre_cells: bool) -> Self {
        GridSettings {
            centre_cells,
            ..self
        }
    }
}

/// Cell edge in mean free paths where [`GridSettings::free_path_cells`] sizes the cells by it. A free
/// flight ends about one mean free path into the cloud; a centre-cell walk scans the cells around
/// the ray's, so cells much wider than that path test grains far beyond the interaction, and much
/// narrower ones cost DDA steps. Chosen by sweeps of 0.75–3 on dense Cornell boxes with a temporary
/// switch (a few per cent on grains of 4 mm, noise on 2 mm; BENCHMARKS 25, session 12).
pub const FREE_PATHS_PER_CELL: f64 = 1.5;
/// The finest cells [`GridSettings::free_path_cells`] makes, in cells per particle (four particles a
/// cell: the cell index then costs a byte per particle).
const FREE_PATH_CELLS_PER_PARTICLE_MAX: f64 = 0.25;

/// The mean free path 1 / σ_t of a grid's particles spread over `volume`: σ_t = Σ C_t,i / V (the mean
/// over channels), the walk's own extinction (each disk removes exactly C_t,i from a beam,
/// `render::discrete`).
fn mean_free_path(p: &Particles, volume: f64) -> f64 {
    let channels = p.channels.max(1);
    let c_mean =
        |j: usize| (0..channels).map(|ch| (p.c_ext)(p.id(j), ch)).sum::<f64>() / channels as f64;
    // Summed in fixed chunks, in order: the same cells whatever the thread count.
    let chunk = 1 << 16;
    let parts: Vec<f64> = (0..p.len().div_ceil(chunk))
        .into_par_iter()
        .map(|k| {
            (k * chunk..((k + 1) * chunk).min(p.len()))
                .map(c_mean)
                .sum()
        })
        .collect();
    volume / parts.iter().sum::<f64>()
}

/// Size classes of a [`ParticleGrid`]: factors of two in inclusion radius, the last one open below.
pub(crate) const SIZE_CLASSES: usize = 13;

/// The size class of an inclusion radius `reach` among radii up to `reach_max`: class c holds reach in
/// (R_max 2^-(c+1), R_max 2^-c]; everything below 2^-12 R_max shares the last.
pub(crate) fn size_class(reach_max: f64, reach: f64) -> usize {
    let x = reach_max / reach;
    if x.is_finite() && x > 1.0 {
        (x.log2().floor() as usize).min(SIZE_CLASSES - 1)
    } else {
        0
    }
}

/// The cell edge of `n` particles in `volume` at about `cells_per_particle` cells each.
fn cell_spacing(volume: f64, n: usize, cells_per_particle: f64) -> f64 {
    (volume / (n as f64 * cells_per_particle).clamp(1.0, MAX_CELLS)).cbrt()
}

/// Can a class with inclusion radii up to `reach_max` reference each ball from every cell it overlaps
/// (k = 0, balls narrower than the cells), at cell edge `spacing`?
fn is_sparse(reach_max: f64, spacing: f64) -> bool {
    2.0 * reach_max <= spacing
}

/// Size classes merged, largest first, while the merged set is still sparse (its largest inclusion
/// diameter at most its cell spacing, `SubGrid::build_class`'s k = 0 rule). A sparse grid references
/// each ball from every cell it overlaps, so it needs no split by size; each class a ray walks costs a
/// DDA set-up and a merge of its hits in t, several percent of a sparse render per extra class.
/// The set of particles a ray meets is the same either way.
fn merge_sparse_classes(
    members: Vec<Vec<u32>>,
    reach_of: impl Fn(&u32) -> f64,
    volume: f64,
    cells_per_particle: f64,
) -> Vec<Vec<u32>> {
    let sparse = |n: usize, reach_max: f64| {
        is_sparse(reach_max, cell_spacing(volume, n, cells_per_particle))
    };
    let mut out: Vec<(Vec<u32>, f64)> = Vec::new();
    for ids in members.into_iter().filter(|m| !m.is_empty()) {
        let reach_max = ids.iter().map(&reach_of).fold(0.0, f64::max);
        match out.last_mut() {
            // Classes come largest first: the group keeps its first class's largest reach.
            // (sparse for more particles implies sparse for fewer: a dense group stays apart)
            Some((group, r)) if sparse(group.len() + ids.len(), *r) => group.extend(ids),
            _ => out.push((ids, reach_max)),
        }
    }
    out.into_iter().map(|(ids, _)| ids).collect()
}

/// The volume the centres occupy, to size the cells by: their bounding box, less the cells that hold no
/// centre, measured at [`OCCUPANCY_PARTICLES_PER_CELL`] per occupied cell (so few cells of a uniform
/// cloud are empty by chance) and refined twice. A cloud that fills a
/// slanted column, a noise density or a Houdini sim covers a fraction of its bounding box; sized by the
/// box, its occupied cells would hold several times the intended particles each (a column around the
/// default scene's beam: ~40 instead of ~8 per cell, 1.1 us per ray instead of 0.4 in the render).
fn occupied_volume_by(n: usize, at: impl Fn(usize) -> [f64; 3] + Sync) -> f64 {
    let (lo, hi) = bounding_box_by(n, &at);
    let ext = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(1e-12));
    let mut volume = ext[0] * ext[1] * ext[2];
    let target = (n as f64 / OCCUPANCY_PARTICLES_PER_CELL).clamp(1.0, MAX_CELLS);
    for _ in 0..2 {
        let cell = (volume / target).cbrt();
        let dims = ext.map(|e| ((e / cell).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS));
        let n_cells = dims[0] * dims[1] * dims[2];
        if n_cells as f64 > 8.0 * MAX_CELLS {
            break;
        }
        let mut occupied = vec![0u64; n_cells.div_ceil(64)];
        for p in (0..n).map(&at) {
            let c = [0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1));
            let i = (c[2] * dims[1] + c[1]) * dims[0] + c[0];
            occupied[i / 64] |= 1 << (i % 64);
        }
        let count: u64 = occupied.iter().map(|w| w.count_ones() as u64).sum();
        let v = (count as f64 * cell.powi(3)).min(volume);
        // Mostly occupied (a box-shaped cloud): the box it is.
        if v >= 0.9 * volume {
            break;
        }
        volume = v;
    }
    volume
}

/// The checks of a particle set and its grid settings, each naming its argument: done once, where the
/// particles enter the core ([`ParticleGrid::build`], `DiscreteMedium::build`); what is derived from
/// checked inputs is built without checking again (`ParticleGrid::from_checked`).
pub fn check_particles(
    positions: &[[f64; 3]],
    radius: &[f64],
    settings: &GridSettings,
) -> Result<(), OpticsError> {
    let GridSettings {
        query_radius,
        cells_per_particle,
        ..
    } = *settings;
    let n = positions.len();
    require("positions (count)", n as f64, n >= 1, ">= 1")?;
    require_len("radius (length)", radius.len(), n, "one per particle")?;
    require(
        "query_radius",
        query_radius,
        query_radius.is_finite() && query_radius >= 0.0,
        "finite and >= 0",
    )?;
    require(
        "cells_per_particle",
        cells_per_particle,
        cells_per_particle.is_finite() && cells_per_particle > 0.0,
        "finite and > 0",
    )?;
    for (i, p) in positions.iter().enumerate() {
        require(
            "positions (index of the first non-finite particle)",
            i as f64,
            p.iter().all(|x| x.is_finite()),
            "finite coordinates",
        )?;
        require(
            "radius",
            radius[i],
            radius[i].is_finite() && radius[i] > 0.0,
            "finite and > 0",
        )?;
    }
    Ok(())
}

/// The checks of extinction cross sections, `[particle][channel]` row-major, of `n` particles.
pub fn check_cross_sections(c_ext: &[f64], n: usize, channels: usize) -> Result<(), OpticsError> {
    require("channels", channels as f64, channels >= 1, ">= 1")?;
    require(
        "c_ext (length)",
        c_ext.len() as f64,
        c_ext.len() == n * channels,
        "particles × channels",
    )?;
    for &c in c_ext {
        require("c_ext", c, c.is_finite() && c >= 0.0, "finite and >= 0")?;
    }
    Ok(())
}

/// Particles of every size: one [`SubGrid`] per factor-of-two class of inclusion radius, so that a
/// few large grains (a log-normal tail reaching 2 mm) do not force every traversal to scan wide
/// neighbourhoods. Queries sum over the classes; free flights merge their contributions in t.
pub struct ParticleGrid {
    classes: Vec<SubGrid>,
    channels: usize,
    n: usize,
}

impl ParticleGrid {
    /// Build from centres (scene units), geometric radii (scene units) and extinction cross sections
    /// (scene units², `[particle][channel]` row-major), with the query radius and resolution of
    /// `settings`.
    pub fn build(
        positions: &[[f64; 3]],
        radius: &[f64],
        c_ext: &[f64],
        channels: usize,
        settings: &GridSettings,
    ) -> Result<Self, OpticsError> {
        check_particles(positions, radius, settings)?;
        check_cross_sections(c_ext, positions.len(), channels)?;
        Ok(Self::from_checked(
            positions, radius, c_ext, channels, settings,
        ))
    }

    /// [`ParticleGrid::build`] from inputs that passed [`check_particles`] (or are derived from such
    /// inputs, finite and positive by construction).
    pub(crate) fn from_checked(
        positions: &[[f64; 3]],
        radius: &[f64],
        c_ext: &[f64],
        channels: usize,
        settings: &GridSettings,
    ) -> Self {
        Self::from_particles(
            &Particles {
                positions,
                ids: None,
                radius: &|i| radius[i],
                c_ext: &|i, ch| c_ext[i * channels + ch],
                channels,
            },
            settings,
        )
    }

    /// [`Self::from_checked`] over the particles `p` (checked inputs), read through its columns: a
    /// grid of a subset of a medium's particles, reporting their indices, with no copies (the class
    /// lists aside: four bytes a particle).
    pub(crate) fn from_particles(p: &Particles, settings: &GridSettings) -> Self {
        let GridSettings {
            query_radius,
            cells_per_particle,
            ..
        } = *settings;
        let n = p.len();
        let reach_of = |i: &u32| query_radius + (p.radius)(*i as usize);
        let reach_max = (0..n)
            .into_par_iter()
            .map(|j| query_radius + (p.radius)(p.id(j)))
            .reduce(|| 0.0, f64::max);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); SIZE_CLASSES];
        for j in 0..n {
            let i = p.id(j) as u32;
            members[size_class(reach_max, reach_of(&i))].push(i);
        }
        // Volume the centres occupy, shared by the classes as the density reference.
        let volume = occupied_volume_by(n, |j| p.positions[p.id(j)]);
        let members = merge_sparse_classes(members, reach_of, volume, cells_per_particle);
        let free_path_cell = settings
            .free_path_cells
            .then(|| FREE_PATHS_PER_CELL * mean_free_path(p, volume))
            .filter(|l| l.is_finite() && *l > 0.0);
        let mut classes = Vec::new();
        for ids in members {
            classes.push(SubGrid::build_class(
                p,
                &ids,
                settings,
                Some(volume),
                free_path_cell,
            ));
        }
        ParticleGrid {
            classes,
            channels: p.channels,
            n,
        }
    }

    pub fn len(&self) -> usize {
        self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    pub fn channels(&self) -> usize {
        self.channels
    }
    /// Cells of the finest class (the one holding the most particles).
    pub fn dims(&self) -> [usize; 3] {
        self.classes
            .iter()
            .max_by_key(|c| c.len())
            .map(|c| c.frame.dims)
            .unwrap_or([0; 3])
    }
    pub fn class_count(&self) -> usize {
        self.classes.len()
    }
    pub fn bytes(&self) -> usize {
        self.classes.iter().map(SubGrid::bytes).sum()
    }

    /// Optical depth of a ray segment, per channel (Eq. 18, normalised as in the module docs).
    pub fn optical_depth(&self, ray: &RaySegment, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        self.walk(ray, |_, tau, _| {
            out.iter_mut().zip(tau).for_each(|(v, &x)| *v += x as f64);
            true
        });
    }

    /// The same by a loop over every particle of every class (test oracle).
    #[cfg(any(test, feature = "oracles"))]
    pub fn optical_depth_brute(&self, ray: &RaySegment, out: &mut [f64]) {
        let mut part = vec![0.0; self.channels];
        out.iter_mut().for_each(|v| *v = 0.0);
        for c in &self.classes {
            c.optical_depth_brute(ray, &mut part);
            out.iter_mut().zip(&part).for_each(|(a, b)| *a += b);
        }
    }

    /// Visit every contributing particle with t in the segment, over all classes, in increasing t, as
    /// `visit(t, τ per channel, original index)` (a positional grid's: the position,
    /// [`Self::positional`]); `visit` returns false to stop. Each class advances
    /// its own traversal a batch at a time (the class furthest behind first); a hit is passed on once
    /// every class has reported everything before it, so a walk that stops early costs only the
    /// batches it reached, and no traversal restarts.
    pub fn walk(&self, ray: &RaySegment, visit: impl FnMut(f64, &[f32], u32) -> bool) {
        #[cfg(target_arch = "x86_64")]
        if wide_simd() {
            // SAFETY: the CPU has AVX2 and FMA (`wide_simd`).
            return unsafe { self.walk_avx2(ray, visit) };
        }
        self.walk_lanes::<false>(ray, visit)
    }

    /// [`Self::walk`] compiled for AVX2 + FMA (the whole walk, so that its pre-tests inline).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn walk_avx2(&self, ray: &RaySegment, visit: impl FnMut(f64, &[f32], u32) -> bool) {
        self.walk_lanes::<true>(ray, visit)
    }

    #[inline(always)]
    fn walk_lanes<const WIDE: bool>(
        &self,
        ray: &RaySegment,
        mut visit: impl FnMut(f64, &[f32], u32) -> bool,
    ) {
        if ray.is_empty() {
            return;
        }
        let mut emit = |&(t, ci, j): &(f64, u32, u32)| {
            let c = &self.classes[ci as usize];
            let j = j as usize;
            visit(t, c.hit_tau(j), c.hit_index(j))
        };
        // Hits waiting for their batch's frontier, in a buffer kept per thread (an allocation and its
        // growth per walk were 1 % of a dense render); a nested walk takes a fresh one.
        let mut buffer = PendingHits(WALK_PENDING.with(|b| b.take()));
        buffer.0.clear();
        let pending = &mut buffer.0;
        if let [c] = &self.classes[..] {
            // One class: each batch is complete up to its frontier, in t order once sorted (a k = 1
            // batch may also find contributions past its frontier: they wait for the next).
            let mut cur = c.cursor(ray, inverse(ray.d));
            loop {
                let frontier = c
                    .advance::<WIDE>(&mut cur, &mut |t, j| {
                        pending.push((t, 0, j as u32));
                        true
                    })
                    .unwrap_or(f64::INFINITY);
                pending.sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
                let n = pending.partition_point(|h| h.0 < frontier);
                for h in &pending[..n] {
                    if !emit(h) {
                        return;
                    }
                }
                if frontier == f64::INFINITY {
                    return;
                }
                pending.drain(..n);
            }
        }
        let inv_d = inverse(ray.d);
        let mut cursors: Vec<(Cursor, f64)> = self
            .classes
            .iter()
            .map(|c| (c.cursor(ray, inv_d), ray.t0))
            .collect();
        // Advance the class furthest behind.
        while let Some(ci) = (0..cursors.len())
            .filter(|&i| cursors[i].1 < f64::INFINITY)
            .min_by(|&a, &b| cursors[a].1.total_cmp(&cursors[b].1))
        {
            let (cur, frontier) = &mut cursors[ci];
            *frontier = self.classes[ci]
                .advance::<WIDE>(cur, &mut |t, j| {
                    pending.push((t, ci as u32, j as u32));
                    true
                })
                .unwrap_or(f64::INFINITY);
            // Everything before the smallest frontier is final.
            let ready = cursors.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
            pending.sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
            let n = pending.partition_point(|h| h.0 < ready);
            for h in &pending[..n] {
                if !emit(h) {
                    return;
                }
            }
            pending.drain(..n);
        }
        for h in pending.iter() {
            if !emit(h) {
                return;
            }
        }
    }

    /// Exact free flight over a ray segment in `channel`: each particle interacts with probability
    /// 1 − exp(−τ_i); equivalently, particles are walked in t order and the path interacts where the accumulated optical depth first exceeds −ln(1 − u).
    /// Returns the hit (or None) and the transmittance up to it (or to t1).
    pub fn free_flight(&self, ray: &RaySegment, channel: usize, u: f64) -> (Option<Hit>, f64) {
        let target = -(1.0 - u).ln();
        let mut acc = 0.0;
        let mut found = None;
        self.walk(ray, |t, tau, i| {
            let x = tau[channel] as f64;
            if acc + x > target {
                found = Some(Hit { t, particle: i });
                return false;
            }
            acc += x;
            true
        });
        (found, (-acc).exp())
    }

    /// Exact free flight to the next *site* (channel 0), for the renderer: particles whose projections lie
    /// within `coincide` of each other along the ray form one site (their optical depths add and the site
    /// scatters as their mixture), and the particles in `exclude` (the one that scattered the path at
    /// its origin) are skipped. Returns the site and the optical depth walked before it.
    pub fn sample_site(
        &self,
        ray: &RaySegment,
        exclude: &[u32],
        u: f64,
        coincide: f64,
    ) -> (Option<Site>, f64) {
        let mut flight = Flight::new(exclude, u, coincide);
        self.walk(ray, |t, tau, i| flight.visit(t, tau[0], i));
        flight.finish()
    }

    /// Free flights ([`Self::sample_site`], nothing excluded) of up to [`BEAM_RAYS`] rays walked as one
    /// beam: the cells around a representative ray (their mean), within R_max + δ of it, δ the
    /// farthest any ray's segment in the grid gets from it, each cell once; each ray tests those cells'
    /// particles that come within R + δ of the representative ray (one pre-test for all) with its own
    /// exact test (all rays at once where the CPU has AVX-512: `RayLanes`; else its own pre-test
    /// first), so that every ray gets exactly its own contributions, in t order (a
    /// contribution at t lies within R_max + δ of the representative ray's point nearest the ray's
    /// point at t, whose block the walk has tested once it is past that point). A pixel's camera rays
    /// (a packet of Mitsuba's symbolic kernels holds one pixel's samples) and their shadow rays towards a
    /// point light share their steps and their loads. Rays that spread too far over their whole
    /// segments make a beam over the first 1/2^k of them in the grid (k ≤ [`BEAM_CUTS`]), and a ray that
    /// finds no site there walks the rest alone, its flight going on. Writes `out` and returns true, or
    /// returns false (nothing written) where the rays are no such beam: one size class with centre
    /// cells, δ + R_max within a cell and δ within [`BEAM_SPREAD`] R_max (over the cut segments),
    /// directions within ~25° of their mean.
    pub fn sample_sites_beam(
        &self,
        rays: &[RaySegment],
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        if wide_simd() {
            // SAFETY: the CPU has AVX2 and FMA (`wide_simd`).
            return unsafe { self.beam_avx2(rays, us, coincide, out) };
        }
        self.beam_lanes::<false>(rays, us, coincide, out)
    }

    /// [`Self::sample_sites_beam`] compiled for AVX2 + FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn beam_avx2(
        &self,
        rays: &[RaySegment],
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> bool {
        self.beam_lanes::<true>(rays, us, coincide, out)
    }

    #[inline(always)]
    fn beam_lanes<const WIDE: bool>(
        &self,
        rays: &[RaySegment],
        us: &[f64],
        coincide: f64,
        out: &mut [(Option<Site>, f64)],
    ) -> bool {
        let [c] = &self.classes[..] else {
            return false;
        };
        let n = rays.len();
        if c.k != 1 || !(2..=BEAM_RAYS).contains(&n) || us.len() != n || out.len() < n {
            return false;
        }
        let mut probes = [None; BEAM_RAYS];
        let Some(beam) = c.beam(rays, &mut probes) else {
            return false;
        };
        let mut flights: [Option<Flight>; BEAM_RAYS] = [const { None }; BEAM_RAYS];
        for i in 0..n {
            out[i] = (None, 0.0);
            flights[i] = probes[i].map(|_| Flight::new(&[], us[i], coincide));
        }
        // Each ray's hits waiting for its frontier, in buffers kept per thread (a beam per packet).
        let mut pending = BEAM_PENDING.take();
        pending.iter_mut().for_each(Vec::clear);
        // Ray i's hits before `upto`, in t order, into its flight; false once it found its site.
        let emit = |upto: f64, pending: &mut Vec<(f64, u32)>, flight: &mut Flight| -> bool {
            // The hits before the frontier to the front, then only those sorted: the ones held back
            // were sorted again at every step (the sorts were 2 % of a dense box's render).
            let mut k = 0;
            for j in 0..pending.len() {
                if pending[j].0 < upto {
                    pending.swap(k, j);
                    k += 1;
                }
            }
            pending[..k].sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
            for &(t, s) in &pending[..k] {
                if !flight.visit(t, c.hit_tau(s as usize)[0], c.hit_index(s as usize)) {
                    return false;
                }
            }
            pending.drain(..k);
            true
        };
        let slots = c.slots();
        // Each candidate particle against every ray at once where the CPU can (`RayLanes`), else
        // each ray's own pre-test and exact test, block by block.
        let lanes_of_rays = RayLanes::new(probes.iter().map(|p| p.as_ref().map(|p| &p.ray)));
        let side_by_side = WIDE && lanes_of_rays.simd;
        // (A ray has a flight exactly where it has a probe.)
        let mut alive = (0..n).fold(0u32, |m, i| m | (flights[i].is_some() as u32) << i);
        let mut ts = [0.0; BEAM_RAYS];
        let mut rows = [Segment::default(); ROWS_PER_STEP];
        let mut dda = Dda::new(&beam.cells, &beam.rep.ray);
        let mut prev: Option<[i64; 3]> = None;
        let mut flying = flights.iter().filter(|f| f.is_some()).count();
        while flying > 0 {
            let Some(step) = dda.next() else { break };
            let last = dda.finished();
            // The grown grid's cell, in the class's cell coordinates (−1 and dims: outside).
            let cell = step.cell.map(|x| x as i64 - 1);
            let rep = &beam.rep;
            let m = c.near_rows(
                cell,
                prev.replace(cell),
                rep.ray.t0,
                rep.ray.t1,
                &beam.near,
                &mut rows,
            );
            for sg in rows[..m].iter_mut() {
                (sg.c0, sg.c1) = (c.start[sg.c0] as usize, c.start[sg.c1] as usize);
                if sg.c0 == sg.c1 {
                    continue;
                }
                c.locate(sg, rep);
                // Where each ray's pre-test reads the row's slots from (its lattice offsets; the
                // rest of the segment is the row's).
                let mut offs = [[0.0f32; 2]; BEAM_RAYS];
                if c.quant.is_some() && !side_by_side {
                    for i in 0..n {
                        if let (Some(probe), Some(_)) = (&probes[i], &flights[i]) {
                            offs[i] = probe.offsets(sg.cell);
                        }
                    }
                }
                for blk in sg.c0 / LANES..=(sg.c1 - 1) / LANES {
                    let base = LANES * blk;
                    let first = (sg.c0.max(base) - base) as u32;
                    let end = (sg.c1.min(base + LANES) - base) as u32;
                    let lanes = (ALL_LANES >> (LANES as u32 - end)) & (ALL_LANES << first);
                    // The lanes the representative ray's pre-test passes (within R + δ of it): one
                    // pre-test for all rays, most blocks of a dense cloud none.
                    let candidates = lanes & c.pretest::<WIDE>(slots, blk, sg, rep);
                    if candidates == 0 {
                        continue;
                    }
                    if side_by_side {
                        // (A row's contributions count anywhere on a ray's segment: `near_rows`.)
                        debug_assert!(sg.t_enter == f64::NEG_INFINITY && sg.t_exit == f64::INFINITY);
                        let mut m = candidates;
                        while m != 0 {
                            let s = base + m.trailing_zeros() as usize;
                            m &= m - 1;
                            let ball = c.slot_ball(s, sg.cell);
                            let mut hit = lanes_of_rays.contributions(ball, alive, &mut ts);
                            while hit != 0 {
                                let i = hit.trailing_zeros() as usize;
                                hit &= hit - 1;
                                pending[i].push((ts[i], s as u32));
                            }
                        }
                        continue;
                    }
                    for i in 0..n {
                        let (Some(probe), Some(_)) = (&probes[i], &flights[i]) else {
                            continue;
                        };
                        let own = Segment {
                            off: offs[i],
                            ..*sg
                        };
                        let list = &mut pending[i];
                        c.test_block::<WIDE>(slots, blk, candidates, &own, probe, &mut |t, s| {
                            list.push((t, s as u32));
                            true
                        });
                    }
                }
            }
            // Each ray's contributions are known where its points project before this step's exit.
            for i in 0..n {
                let Some(f) = &mut flights[i] else { continue };
                let upto = if last {
                    f64::INFINITY
                } else {
                    beam.frontier(i, step.t_exit)
                };
                if !emit(upto, &mut pending[i], f) {
                    out[i] = flights[i].take().map_or((None, 0.0), Flight::finish);
                    alive &= !(1 << i);
                    flying -= 1;
                }
            }
            if last {
                break;
            }
        }
        for i in 0..n {
            if let Some(mut f) = flights[i].take() {
                let mut going = emit(f64::INFINITY, &mut pending[i], &mut f);
                let r = &rays[i];
                if going && beam.cut[i] < r.t1 {
                    // Past the beam's cut, the ray's own walk (the same flight going on).
                    self.walk(&r.between(beam.cut[i], r.t1), |t, tau, j| {
                        going = f.visit(t, tau[0], j);
                        going
                    });
                }
                out[i] = f.finish();
            }
        }
        BEAM_PENDING.set(pending);
        true
    }

    /// Original indices (a positional grid's: positions) of the particles whose inclusion ball
    /// (radius R_i = r_c + r_i) contains `p`:
    /// the query sphere of Eq. 24 (a particle is in the sphere of radius r_c around `p` when it overlaps it).
    pub fn containing(&self, p: [f64; 3]) -> Vec<u32> {
        let mut out = Vec::new();
        for c in &self.classes {
            c.containing(p, |s| out.push(c.hit_index(s)));
        }
        out
    }

    /// The same grid walking every class in prefetched batches (`SubGrid::advance`), the path of
    /// classes whose slots outgrow the cache, for tests of that path on small grids.
    #[cfg(test)]
    fn batched(mut self) -> Self {
        self.classes
            .iter_mut()
            .for_each(|c| c.prefetch_slots = true);
        self
    }

    /// The same by a loop over every particle (test oracle).
    #[cfg(any(test, feature = "oracles"))]
    pub fn containing_brute(&self, p: [f64; 3]) -> Vec<u32> {
        let mut out = Vec::new();
        for c in &self.classes {
            c.each_particle(|(q, r), _, i| {
                let dd = (0..3).map(|a| (q[a] - p[a]).powi(2)).sum::<f64>();
                if dd < r * r {
                    out.push(i);
                }
            });
        }
        out
    }

    /// First and last t in the segment where any particle contributes (for empty-space skipping), or
    /// None.
    pub fn occupied_interval(&self, ray: &RaySegment) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        self.walk(ray, |t, _, _| {
            lo = lo.min(t);
            hi = hi.max(t);
            true
        });
        (lo <= hi).then_some((lo, hi))
    }

    /// The same by a loop over every particle (test oracle).
    #[cfg(any(test, feature = "oracles"))]
    pub fn occupied_interval_brute(&self, ray: &RaySegment) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        if !ray.is_empty() {
            for c in &self.classes {
                c.each_particle(|(c, r), _, _| {
                    if let Some(t) = ball_contribution(c, r, ray) {
                        if ray.contains(t) {
                            lo = lo.min(t);
                            hi = hi.max(t);
                        }
                    }
                });
            }
        }
        (lo <= hi).then_some((lo, hi))
    }

    #[cfg(any(test, feature = "oracles"))]
    pub fn tau_of(&self, original: u32, channel: usize) -> f64 {
        let mut out = f64::NAN;
        for c in &self.classes {
            c.each_particle(|_, tau, i| {
                if i == original {
                    out = tau[channel] as f64;
                }
            });
        }
        out
    }

    /// The same grid reporting each particle by its position in the grid's storage (classes in turn,
    /// each in its storage order) instead of its original index, and that order: the original index
    /// of the particle at each position. Centre-cell classes then keep no index at all (four bytes a
    /// particle: compact storage's identities, `crate::render::storage`); a medium looks up what it
    /// keeps per particle by position. Call before [`Self::release_stored`].
    pub fn positional(mut self) -> (Self, Vec<u32>) {
        let mut order = Vec::with_capacity(self.n);
        for c in &mut self.classes {
            assert_eq!(
                c.index.len(),
                c.count,
                "positional() before release_stored()"
            );
            c.first_id = order.len() as u32;
            if c.k == 0 {
                // Overlap slots name their particle per slot: renamed through a map of the class.
                let at: rustc_hash::FxHashMap<u32, u32> = c
                    .index
                    .iter()
                    .enumerate()
                    .map(|(j, &i)| (i, c.first_id + j as u32))
                    .collect();
                c.slot_index
                    .iter_mut()
                    .filter(|i| **i != u32::MAX)
                    .for_each(|i| *i = at[i]);
                order.extend_from_slice(&c.index);
                c.index = (c.first_id..c.first_id + c.count as u32).collect();
            } else {
                order.append(&mut c.index);
                c.index = Vec::new();
            }
        }
        (self, order)
    }

    /// Drop the stored copies of particles that the slots of their cells duplicate (classes whose
    /// cells reference every overlapping ball, k = 0): walks and point queries read only the slots,
    /// and the oracles read them too. Saves the sphere, τ and index of each such particle (24 bytes at
    /// one channel). For a medium that keeps its grid for rendering.
    pub fn release_stored(&mut self) {
        self.classes.iter_mut().for_each(SubGrid::release_stored);
    }

    pub fn reach_max(&self) -> f64 {
        self.classes.iter().map(|c| c.reach_max).fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_rng::{
        assert_escape_rate, lcg, random_direction, random_particles, random_points,
    };
    use std::f64::consts::PI;

    /// Free flights interact at a particle with exactly the probability the transmittance implies:
    /// P(no interaction on [t0, t1)) = exp(−τ) (binomial 5σ bound), and the interaction point has an
    /// accumulated optical depth straddling −ln(1 − u).
    #[test]
    fn free_flight_matches_transmittance() {
        let mut s = 11u64;
        let (pos, rad) = random_particles(&mut s, 2000, 0.005, 0.01);
        let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r * 15.0).collect();
        let g = ParticleGrid::build(&pos, &rad, &cext, 1, &GridSettings::new(0.03, 1.0)).unwrap();
        assert!(g.class_count() >= 1);
        let ray = RaySegment::new([0.5, 0.5, -0.5], [0.0, 0.6, 0.8], 0.0, 3.0);
        let mut tau = [0.0];
        g.optical_depth(&ray, &mut tau);
        let expected = (-tau[0]).exp();
        assert!(tau[0] > 0.3 && tau[0] < 3.0, "{}", tau[0]);
        assert_escape_rate(&mut s, 20000, expected, |u| {
            let (hit, tr) = g.free_flight(&ray, 0, u);
            match hit {
                None => {
                    assert!((tr - expected).abs() < 1e-12);
                    true
                }
                Some(h) => {
                    // accumulated depth before the hit ≤ target < accumulated + τ_hit
                    let before = -tr.ln();
                    let target = -(1.0 - u).ln();
                    assert!(
                        before <= target + 1e-9 && target < before + g.tau_of(h.particle, 0) + 1e-9
                    );
                    false
                }
            }
        });
    }

    /// The segments `grid_equals_brute_force` queries: random ones (whole and in part), rays along
    /// each axis from outside, rays on a cell face of the grid (`lo0 + 3 cell` in x) starting inside,
    /// a zero-length segment and a ray missing the grid.
    fn test_rays(s: &mut u64, lo0: f64, cell: f64) -> Vec<RaySegment> {
        let mut rays = Vec::new();
        for _ in 0..300 {
            let o = [lcg(s) * 3.0 - 1.0, lcg(s) * 3.0 - 1.0, lcg(s) * 3.0 - 1.0];
            let ray = RaySegment::new(o, random_direction(s), 0.0, 4.0);
            rays.push(ray);
            rays.push(ray.between(lcg(s), lcg(s) + 1.0));
        }
        for a in 0..3 {
            for sign in [1.0, -1.0] {
                let mut d = [0.0; 3];
                d[a] = sign;
                let mut o = [0.5, 0.5, 0.5];
                o[a] -= sign * 2.0;
                rays.push(RaySegment::new(o, d, 0.0, 5.0));
                // on a cell face of the grid and starting inside
                let mut o2 = [lo0 + 3.0 * cell, 0.37, 0.61];
                o2[a] = 0.5;
                rays.push(RaySegment::new(o2, d, 0.0, 3.0));
            }
        }
        let x = [1.0, 0.0, 0.0];
        rays.push(RaySegment::new([0.5, 0.5, 0.5], x, 0.3, 0.3)); // zero length
        rays.push(RaySegment::new([5.0, 5.0, 5.0], x, 0.0, 10.0)); // misses
        rays
    }

    /// The walk, the optical depth and the occupied interval of `ray` equal the O(N) loops: the walk
    /// merges the classes' traversals, every contributing particle once, in t order.
    fn assert_queries_match_brute(g: &ParticleGrid, ray: &RaySegment, rc: f64) {
        assert_eq!(g.occupied_interval(ray), g.occupied_interval_brute(ray));
        let mut walked = Vec::new();
        g.walk(ray, |t, _, i| {
            walked.push((t, i));
            true
        });
        assert!(
            walked.windows(2).all(|w| w[0].0 <= w[1].0),
            "walk out of order"
        );
        let mut expect = Vec::new();
        for c in &g.classes {
            c.each_particle(
                |(centre, r), _, i| match ball_contribution(centre, r, ray) {
                    Some(t) if ray.contains(t) => expect.push(i),
                    _ => {}
                },
            );
        }
        let mut got: Vec<u32> = walked.iter().map(|w| w.1).collect();
        got.sort();
        expect.sort();
        let RaySegment { o, d, t0, t1 } = *ray;
        assert_eq!(got, expect, "walk rc={rc} o={o:?} d={d:?}");
        let (mut a, mut b) = (vec![0.0; 2], vec![0.0; 2]);
        g.optical_depth(ray, &mut a);
        g.optical_depth_brute(ray, &mut b);
        for ch in 0..2 {
            assert!(
                (a[ch] - b[ch]).abs() <= 1e-9 * b[ch].abs().max(1e-300),
                "rc={rc} o={o:?} d={d:?} [{t0},{t1}) grid {} brute {}",
                a[ch],
                b[ch]
            );
        }
    }

    /// 3000 random particles with two channels of cross sections (the brute-force tests' set).
    fn two_channel_particles(s: &mut u64) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
        let (pos, rad) = random_particles(s, 3000, 0.001, 0.02);
        let cext = rad
            .iter()
            .flat_map(|r| [2.0 * PI * r * r, 3.0 * r * r])
            .collect();
        (pos, rad, cext)
    }

    /// Every contribution a walk reports along `ray`: (t, τ per channel, `name` of the particle).
    fn walk_hits(
        g: &ParticleGrid,
        ray: &RaySegment,
        name: impl Fn(u32) -> u32,
    ) -> Vec<(f64, Vec<f32>, u32)> {
        let mut h = Vec::new();
        g.walk(ray, |t, tau, i| {
            h.push((t, tau.to_vec(), name(i)));
            true
        });
        h
    }

    /// Grids of particles (`pos`, `rad`, `cext` of two channels) in the layouts (query radius, cells
    /// per particle, quantised, centre cells) `layouts`.
    fn grids_of<'a>(
        pos: &'a [[f64; 3]],
        rad: &'a [f64],
        cext: &'a [f64],
        layouts: &'a [(f64, f64, bool, bool)],
    ) -> impl Iterator<Item = ((f64, f64, bool, bool), ParticleGrid)> + 'a {
        layouts.iter().map(move |&(rc, cpp, quantise, centred)| {
            let settings = GridSettings::new(rc, cpp)
                .quantised(quantise)
                .centred(centred);
            let g = ParticleGrid::build(pos, rad, cext, 2, &settings).unwrap();
            ((rc, cpp, quantise, centred), g)
        })
    }

    /// A grid whose sparse classes released their stored copies (what a medium keeps) answers every
    /// query as before, its oracles read the slots, and it keeps fewer bytes.
    #[test]
    fn released_grid_answers_the_same() {
        let mut s = 5u64;
        let (pos, rad, cext) = two_channel_particles(&mut s);
        let layouts = [
            (0.01, 1.0, false, false),
            (0.0, 20.0, false, false),
            (0.01, 1.0, true, false),
            (0.0, 20.0, true, false),
            (0.01, 1.0, true, true),
        ];
        let released = grids_of(&pos, &rad, &cext, &layouts).map(|(_, mut r)| {
            r.release_stored();
            r
        });
        for (((.., centred), g), r) in grids_of(&pos, &rad, &cext, &layouts).zip(released) {
            // Centred classes store each particle once: nothing to release.
            assert!(r.bytes() < g.bytes() || centred && r.bytes() == g.bytes());
            assert_eq!(r.len(), g.len());
            let frame = &g.classes[0].frame;
            for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
                assert_eq!(walk_hits(&g, ray, |i| i), walk_hits(&r, ray, |i| i));
                let (mut x, mut y) = (vec![0.0; 2], vec![0.0; 2]);
                g.optical_depth_brute(ray, &mut x);
                r.optical_depth_brute(ray, &mut y);
                assert!((0..2).all(|ch| (x[ch] - y[ch]).abs() <= 1e-12 * x[ch].abs().max(1e-300)));
                assert_eq!(
                    g.occupied_interval_brute(ray),
                    r.occupied_interval_brute(ray)
                );
            }
            for _ in 0..100 {
                let p = [lcg(&mut s), lcg(&mut s), lcg(&mut s)];
                let (mut a, mut b) = (g.containing_brute(p), r.containing_brute(p));
                a.sort();
                b.sort();
                assert_eq!(a, b);
                assert_eq!(g.containing(p), r.containing(p));
            }
            for i in [0u32, 17, 2999] {
                assert_eq!(g.tau_of(i, 1), r.tau_of(i, 1));
            }
        }
    }

    /// Centre-cell classes walked in prefetched batches (the path of clouds whose slots outgrow the
    /// cache) report what the O(N) loop finds, as the cached walk does.
    #[test]
    fn batched_centre_cell_walks_equal_brute_force() {
        let mut s = 19u64;
        let (pos, rad, cext) = two_channel_particles(&mut s);
        let layouts = [
            (0.01, 1.0, true, true),
            (0.2, 5.0, true, true),
            (0.0, 20.0, false, true),
        ];
        for ((rc, ..), g) in grids_of(&pos, &rad, &cext, &layouts) {
            let g = g.batched();
            let frame = &g.classes[0].frame;
            for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
                assert_queries_match_brute(&g, ray, rc);
            }
        }
    }

    /// A beam's free flights equal each ray's own ([`ParticleGrid::sample_site`]): the same sites and
    /// optical depths, for a pixel's camera rays from outside the grid, shadow rays from nearby
    /// points converging on a light, rays from inside the grid and rays that miss it, with flights
    /// that stop at once and flights that pass every particle; in centre cells quantised or not, with
    /// AVX2 and without; beams over the whole segments and beams cut short (their rays walking on
    /// alone past the cut). Rays that diverge from the start are no beam.
    #[test]
    fn beams_sample_each_rays_own_free_flight() {
        let mut s = 29u64;
        let n = 20_000;
        let pos = random_points(&mut s, n);
        // One size class (radii within a factor of two).
        let rad: Vec<f64> = (0..n).map(|_| 0.004 + 0.003 * lcg(&mut s)).collect();
        let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
        let (mut beams, mut rays_checked, mut wide, mut cut, mut odd_beams) = (0, 0, 0, 0, 0);
        for (quantise, simd) in [(true, true), (false, true), (true, false)] {
            let settings = GridSettings::new(0.01, 0.25)
                .quantised(quantise)
                .centred(true);
            let g = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
            assert_eq!(g.class_count(), 1);
            let norm = |v: [f64; 3]| {
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v.map(|x| x / l)
            };
            for b in 0..120 {
                let k = 2 + (lcg(&mut s) * 15.0) as usize;
                // Spreads from far below the balls' reach to beyond a cell.
                let spread = 0.002 * 30f64.powf(lcg(&mut s));
                let target = [0, 1, 2].map(|_| 1.2 * lcg(&mut s) - 0.1);
                let rays: Vec<RaySegment> = match b % 3 {
                    // A pixel's camera rays: one eye, directions a few mrad apart (or, from an eye
                    // at the box, ten times as many: they spread across the box, and make a beam
                    // over its first part only).
                    0 => {
                        let (z, wider) = if b % 2 == 0 { (-3.0, 1.0) } else { (-0.05, 4.0) };
                        let eye = [0.5 + 0.3 * lcg(&mut s), 0.4, z];
                        (0..k)
                            .map(|_| {
                                let aim =
                                    target.map(|x| x + wider * spread * (lcg(&mut s) - 0.5));
                                let d = norm([0, 1, 2].map(|a| aim[a] - eye[a]));
                                RaySegment::new(eye, d, 0.0, 10.0)
                            })
                            .collect()
                    }
                    // Shadow rays from points of a small spot towards a light far away.
                    1 => {
                        let light = [3.0, 4.0, 2.0];
                        (0..k)
                            .map(|_| {
                                let o = target.map(|x| x + spread * (lcg(&mut s) - 0.5));
                                let d = [0, 1, 2].map(|a| light[a] - o[a]);
                                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                                RaySegment::new(o, d.map(|x| x / l), 0.0, l)
                            })
                            .collect()
                    }
                    // Axis-aligned rays starting part-way along (t0 > 0).
                    2 if b % 2 == 0 => {
                        let o = [target[0], target[1], -1.0];
                        (0..k)
                            .map(|_| {
                                let o = [o[0] + spread * (lcg(&mut s) - 0.5), o[1], o[2]];
                                RaySegment::new(o, [0.0, 0.0, 1.0], 0.5 + 0.5 * lcg(&mut s), 3.0)
                            })
                            .collect()
                    }
                    // Rays leaving the grid's neighbourhood, some missing it.
                    _ => {
                        let o = [0.5, 0.5, 0.5].map(|x: f64| x + 0.9 * (lcg(&mut s) - 0.5));
                        let d0 = norm([lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, lcg(&mut s) - 0.5]);
                        (0..k)
                            .map(|i| {
                                let d = norm(d0.map(|x| x + 0.002 * (lcg(&mut s) - 0.5)));
                                let o = o.map(|x| x + spread * (lcg(&mut s) - 0.5));
                                let o = if i % 5 == 4 { o.map(|x| x + 3.0) } else { o };
                                RaySegment::new(o, d, 0.0, 2.0)
                            })
                            .collect()
                    }
                };
                let us: Vec<f64> = (0..k)
                    .map(|i| match i % 4 {
                        0 => 0.999_999,
                        1 => 1e-9,
                        _ => lcg(&mut s),
                    })
                    .collect();
                let mut out = vec![(None, -1.0); k];
                let ran = if simd {
                    g.sample_sites_beam(&rays, &us, 1e-6, &mut out)
                } else {
                    g.beam_lanes::<false>(&rays, &us, 1e-6, &mut out)
                };
                if !ran {
                    continue;
                }
                beams += 1;
                let beam = g.classes[0].beam(&rays, &mut [None; BEAM_RAYS]).unwrap();
                wide += (beam.delta > 0.5 * g.classes[0].reach_max) as usize;
                cut += beam.cut.iter().any(|c| c.is_finite()) as usize;
                for i in 0..k {
                    let (site, tau) = g.sample_site(&rays[i], &[], us[i], 1e-6);
                    assert_eq!(out[i].0, site, "beam {b}, ray {i}");
                    assert_eq!(out[i].1, tau, "beam {b}, ray {i}");
                    rays_checked += 1;
                }
            }
            // Rays in all directions are no beam.
            let spread: Vec<RaySegment> = (0..8)
                .map(|i| {
                    let a = i as f64;
                    RaySegment::new([0.5; 3], norm([a.cos(), a.sin(), 0.3]), 0.0, 2.0)
                })
                .collect();
            let mut out = vec![(None, 0.0); 8];
            assert!(!g.sample_sites_beam(&spread, &[0.5; 8], 1e-6, &mut out));
            // Nor rays one of which has a NaN origin.
            let d = norm([0.1, 0.2, 1.0]);
            let nan = [
                RaySegment::new([0.4, 0.3, -1.0], d, 0.0, 3.0),
                RaySegment::new([f64::NAN, 0.3, -1.0], d, 0.0, 3.0),
            ];
            assert!(!g.sample_sites_beam(&nan, &[0.5; 2], 1e-6, &mut out));
            // Rays with a NaN end or an empty segment among others: nothing for them, the others
            // their own sites (the box's clip drops a NaN end: such a ray must not walk).
            let odd = [
                RaySegment::new([0.4, 0.3, -1.0], d, 0.0, 3.0),
                RaySegment::new([0.4, 0.3, -1.0], d, 0.0, f64::NAN),
                RaySegment::new([0.4, 0.3, -1.0], d, f64::NAN, 3.0),
                RaySegment::new([0.4, 0.3, -1.0], d, 2.0, 1.0),
                RaySegment::new([0.41, 0.3, -1.0], d, 0.0, 3.0),
            ];
            let us = [0.999_999, 0.5, 0.5, 0.5, 0.3];
            let mut out = vec![(None, -1.0); odd.len()];
            if g.sample_sites_beam(&odd, &us, 1e-6, &mut out) {
                for i in 0..odd.len() {
                    assert_eq!(out[i], g.sample_site(&odd[i], &[], us[i], 1e-6), "ray {i}");
                }
                odd_beams += 1;
            }
        }
        assert!(odd_beams > 0);
        assert!(
            beams > 200 && wide > 60 && cut > 30,
            "{beams} beams, {wide} wider than half the reach, {cut} cut short"
        );
        assert!(rays_checked > 1500);
    }

    /// Quantised centres on cell faces: each is stored in the cell its lattice coordinates give, so
    /// its slots read the same centre from the corners of every row that holds its cell (the first,
    /// second or third cell of a row), and the walk finds what the O(N) loop finds. (Cells chosen in
    /// floating point put ~8 % of such centres one cell low, read 4 cells away from a row's corner.)
    #[test]
    fn centres_on_cell_faces_stay_in_their_cells() {
        let mut s = 23u64;
        let settings = GridSettings::new(0.01, 1.0).quantised(true).centred(true);
        let mut checked = 0;
        // Clouds of their own (each face rounds its own way), every particle but the box's extremes
        // moved onto the nearest face of the grid's cells along x, then y (the box, hence the grid,
        // stays the same).
        for axis in [0, 1, 0, 1, 0, 1] {
            let (mut pos, rad, cext) = two_channel_particles(&mut s);
            let g = ParticleGrid::build(&pos, &rad, &cext, 2, &settings).unwrap();
            let frame = g.classes[0].frame;
            let (lo, hi) = bounding_box(&pos);
            for p in pos.iter_mut() {
                if (0..3).all(|a| p[a] > lo[a] && p[a] < hi[a]) {
                    let k = ((p[axis] - frame.bounds.lo[axis]) / frame.cell[axis]).round();
                    p[axis] =
                        (frame.bounds.lo[axis] + k * frame.cell[axis]).clamp(lo[axis], hi[axis]);
                }
            }
            let g = ParticleGrid::build(&pos, &rad, &cext, 2, &settings).unwrap();
            assert_eq!(g.classes.len(), 1);
            let c = &g.classes[0];
            assert_eq!(
                (c.frame.bounds.lo, c.frame.cell),
                (frame.bounds.lo, frame.cell)
            );
            let q = c.quant.as_ref().expect("quantised");
            let dims = c.frame.dims;
            for z in 0..dims[2] {
                for y in 0..dims[1] {
                    for x in 0..dims[0] {
                        let i = (z * dims[1] + y) * dims[0] + x;
                        for sl in c.start[i] as usize..c.start[i + 1] as usize {
                            let own = q.lattice(sl, [x, y, z]);
                            for first in x.saturating_sub(2)..=x {
                                assert_eq!(q.lattice(sl, [first, y, z]), own, "cell {x} {y} {z}");
                            }
                            checked += 1;
                        }
                    }
                }
            }
            let batched = ParticleGrid::build(&pos, &rad, &cext, 2, &settings)
                .unwrap()
                .batched();
            for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
                assert_queries_match_brute(&g, ray, 0.01);
                assert_queries_match_brute(&batched, ray, 0.01);
            }
        }
        assert_eq!(checked, 6 * 3000);
    }

    /// A positional grid (`ParticleGrid::positional`) reports the same particles in the same order,
    /// named by their positions, which its order maps back to the original indices; centre-cell
    /// classes then keep no index.
    #[test]
    fn positional_ids_name_the_same_particles() {
        let mut s = 13u64;
        let (pos, rad, cext) = two_channel_particles(&mut s);
        let layouts = [
            (0.01, 1.0, true, false),
            (0.0, 20.0, false, false),
            (0.01, 1.0, true, true),
            (0.2, 5.0, true, true),
            (0.01, 1.0, false, true),
        ];
        let positional = grids_of(&pos, &rad, &cext, &layouts).map(|(_, g)| {
            let (mut p, order) = g.positional();
            p.release_stored();
            (p, order)
        });
        for (((.., centred), g), (p, order)) in
            grids_of(&pos, &rad, &cext, &layouts).zip(positional)
        {
            let mut sorted = order.clone();
            sorted.sort_unstable();
            assert!(sorted.iter().enumerate().all(|(j, &i)| j as u32 == i));
            if centred {
                assert!(
                    p.bytes() + 4 * pos.len() <= g.bytes(),
                    "{} {}",
                    p.bytes(),
                    g.bytes()
                );
            }
            let frame = &g.classes[0].frame;
            for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
                assert_eq!(
                    walk_hits(&g, ray, |i| i),
                    walk_hits(&p, ray, |j| order[j as usize])
                );
            }
            for _ in 0..100 {
                let q = [lcg(&mut s), lcg(&mut s), lcg(&mut s)];
                let mut a = g.containing(q);
                let mut b: Vec<u32> = p.containing(q).iter().map(|&j| order[j as usize]).collect();
                a.sort();
                b.sort();
                assert_eq!(a, b);
            }
        }
    }

    /// The AVX2 walk (where the CPU has it, whatever `MOTES_SIMD` says) and the SSE/scalar one report
    /// the same hits, in the same order, on sparse and dense classes and on rays along the axes.
    #[test]
    fn wide_and_narrow_walks_agree() {
        #[cfg(target_arch = "x86_64")]
        let cpu_has_wide = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
        #[cfg(not(target_arch = "x86_64"))]
        let cpu_has_wide = false;
        if !cpu_has_wide {
            eprintln!(
                "wide_and_narrow_walks_agree: no AVX2 + FMA here, only the narrow walk is run"
            );
        }
        let mut s = 11u64;
        let (pos, rad) = random_particles(&mut s, 3000, 0.001, 0.02);
        let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
        for (rc, cpp, quantise, centred) in [
            (0.01, 1.0, false, false),
            (0.0, 0.125, false, false),
            (0.2, 5.0, false, false),
            (0.0, 20.0, false, false),
            (0.01, 1.0, true, false),
            (0.0, 0.125, true, false),
            (0.0, 20.0, true, false),
            (0.01, 1.0, true, true),
            (0.0, 0.125, true, true),
            (0.2, 5.0, true, true),
        ] {
            let settings = GridSettings::new(rc, cpp)
                .quantised(quantise)
                .centred(centred);
            let g = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
            let frame = &g.classes[0].frame;
            let rays = test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]);
            let hits = |wide: bool, ray: &RaySegment| {
                let _ = wide; // read only on x86_64
                let mut h = Vec::new();
                let record = |t: f64, tau: &[f32], i: u32| {
                    h.push((t, tau[0], i));
                    true
                };
                #[cfg(target_arch = "x86_64")]
                if wide {
                    // SAFETY: only where the CPU has AVX2 and FMA.
                    unsafe { g.walk_avx2(ray, record) };
                    return h;
                }
                g.walk_lanes::<false>(ray, record);
                h
            };
            let mut total = 0;
            for ray in &rays {
                let narrow = hits(false, ray);
                total += narrow.len();
                if cpu_has_wide {
                    assert_eq!(hits(true, ray), narrow, "rc={rc} cpp={cpp} ray={ray:?}");
                }
            }
            assert!(total > 0, "the rays must hit something");
        }
    }

    /// Grid traversal equals the O(N) loop for random rays, axis-aligned rays, rays starting inside,
    /// rays on cell faces, zero-length segments and rays missing the grid.
    #[test]
    fn grid_equals_brute_force() {
        let mut s = 7u64;
        let (pos, rad, cext) = two_channel_particles(&mut s);
        for ((rc, cpp), quantise, centred) in [
            (0.0, 1.0),
            (0.01, 1.0),
            (0.05, 0.2),
            (0.2, 5.0),
            (0.0, 0.25),
            (0.0, 20.0),
        ]
        .into_iter()
        .flat_map(|x| {
            [
                (x, false, false),
                (x, true, false),
                (x, true, true),
                (x, false, true),
            ]
        }) {
            let settings = GridSettings::new(rc, cpp)
                .quantised(quantise)
                .centred(centred);
            let g = ParticleGrid::build(&pos, &rad, &cext, 2, &settings).unwrap();
            assert!(
                g.classes.iter().all(|c| c.quant.is_some() == quantise),
                "classes are quantised exactly when asked"
            );
            assert!(!centred || g.classes.iter().all(|c| c.k == 1));
            if rc == 0.0 && cpp == 1.0 {
                // Every class is sparse at this resolution: one grid (merge_sparse_classes).
                assert_eq!(g.class_count(), 1);
            }
            if cpp == 20.0 {
                // Fine cells make the largest grains a dense class apart from the sparse rest.
                assert!(g.class_count() > 1, "the test needs several size classes");
            }
            let frame = &g.classes[0].frame;
            let rays = test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]);
            for _ in 0..200 {
                let p = [
                    lcg(&mut s) * 1.4 - 0.2,
                    lcg(&mut s) * 1.4 - 0.2,
                    lcg(&mut s) * 1.4 - 0.2,
                ];
                let (mut a, mut b) = (g.containing(p), g.containing_brute(p));
                a.sort();
                b.sort();
                assert_eq!(a, b, "containing({p:?}) rc={rc}");
            }
            for ray in &rays {
                assert_queries_match_brute(&g, ray, rc);
            }
        }
    }

    /// Quantised slots (compact storage) move each centre by at most half a lattice step (6·10⁻⁵ of a
    /// cell), keep every particle, and take fewer bytes than spheres; a class with more distinct
    /// (R, τ) than a u16 code holds keeps spheres.
    #[test]
    fn quantised_slots_stay_on_their_particles() {
        let mut s = 3u64;
        let (pos, rad) = random_particles(&mut s, 3000, 0.001, 0.02);
        let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
        let settings = GridSettings::new(0.01, 1.0);
        let full = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
        let q = ParticleGrid::build(&pos, &rad, &cext, 1, &settings.quantised(true)).unwrap();
        let c = &q.classes[0];
        let step = c.quant.as_ref().expect("a sparse class, quantised").step;
        assert!(step < 1e-4 * c.frame.cell[0]);
        let mut seen = 0;
        c.each_particle(|(centre, r), _, i| {
            seen += 1;
            for a in 0..3 {
                let d = (centre[a] - pos[i as usize][a]).abs();
                assert!(
                    d <= 0.5 * step * (1.0 + 1e-6),
                    "particle {i} moved {d} (step {step})"
                );
            }
            assert!((r - (0.01 + rad[i as usize])).abs() < 1e-6 * r);
        });
        assert_eq!(seen, pos.len());
        let (mut qr, mut fr) = (q, full);
        qr.release_stored();
        fr.release_stored();
        assert!(
            (qr.bytes() as f64) < 0.6 * fr.bytes() as f64,
            "{} vs {}",
            qr.bytes(),
            fr.bytes()
        );
        // More distinct (R, τ) than codes: spheres, still answering as the oracle does.
        let n = 70_000;
        let (pos, _) = random_particles(&mut s, n, 0.001, 0.002);
        let rad: Vec<f64> = (0..n).map(|i| 1e-4 * (1.0 + i as f64 / n as f64)).collect();
        let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
        let exact_radii = GridSettings::new(0.0, 1.0).quantised(true);
        let g = ParticleGrid::build(&pos, &rad, &cext, 1, &exact_radii).unwrap();
        assert!(g.classes.iter().all(|c| c.k == 0 && c.quant.is_none()));
        let frame = &g.classes[0].frame;
        for ray in test_rays(&mut s, frame.bounds.lo[0], frame.cell[0])
            .iter()
            .take(50)
        {
            assert_queries_match_brute(&g, ray, 0.0);
        }
    }
}
