//! What a cell's slots hold and the single-precision pre-test of a block of them: spheres
//! ([`Block`]), quantised slots ([`QBlock`]) and the ray as the pre-test sees it ([`RayFrame`]).

use crate::space::ray::RaySegment;
use rayon::prelude::*;

/// Relative slack of the single-precision pre-test against the exact (f64) inclusion test, in units of
/// the coordinates' scale (|o| + the grid box's largest |coordinate|): f32 keeps ~6e-8 of that per
/// operation, and the distance across the ray is a few operations deep (~6e-7 of the scale with SSE's
/// separate roundings, less with FMA; a review's bound). 2e-6 covers it about three times over, so the
/// pre-test never rejects a sphere the exact test accepts; a wider slack only lets a few more spheres
/// through to the exact test.
pub(super) const PRETEST_SLACK: f64 = 2e-6;

/// `slot_particle` of a padding slot (k = 0 cells are padded to whole blocks; see `build_class`).
pub(super) const PADDING_SLOT: u32 = u32::MAX;

/// Ask for the cache line holding `p` (a hint: no fault for any address).
#[inline(always)]
pub(super) fn prefetch<T>(p: *const T) {
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
pub(super) fn sphere_contribution(p: [f32; 4], ray: &RaySegment) -> Option<f64> {
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
pub(super) const LANES: usize = 8;

/// Cache lines per block.
pub(super) const LINES_PER_BLOCK: usize = std::mem::size_of::<Block>() / 64;

/// Lane mask of a whole block.
pub(super) const ALL_LANES: u32 = (1 << LANES) - 1;

/// [`LANES`] spheres (centre and inclusion radius) by component, so that one pre-test covers all of
/// them.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Block {
    pub(super) x: [f32; LANES],
    pub(super) y: [f32; LANES],
    pub(super) z: [f32; LANES],
    pub(super) r: [f32; LANES],
}

/// Spheres in blocks: sphere s is lane s % LANES of block s / LANES. The padding lanes have R = 0
/// (they contribute to no ray).
#[derive(Default)]
pub(super) struct Spheres(pub(super) Vec<Block>);

impl Spheres {
    /// The spheres `sphere(0..n)`, blocks filled in parallel.
    pub(super) fn from_iter(n: usize, sphere: impl Fn(usize) -> [f32; 4] + Sync) -> Self {
        let mut b = vec![Block::default(); n.div_ceil(LANES)];
        b.par_iter_mut().enumerate().for_each(|(k, blk)| {
            for l in 0..LANES.min(n - k * LANES) {
                let [x, y, z, r] = sphere(k * LANES + l);
                (blk.x[l], blk.y[l], blk.z[l], blk.r[l]) = (x, y, z, r);
            }
        });
        Spheres(b)
    }
    #[inline]
    pub(super) fn get(&self, s: usize) -> [f32; 4] {
        let (b, l) = (&self.0[s / LANES], s % LANES);
        [b.x[l], b.y[l], b.z[l], b.r[l]]
    }
    pub(super) fn bytes(&self) -> usize {
        self.0.capacity() * std::mem::size_of::<Block>()
    }
    /// Ask for every cache line of block `blk` (a hint: any index is safe).
    #[inline(always)]
    pub(super) fn prefetch_block(&self, blk: usize) {
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
pub(super) const LATTICE_PER_CELL: i64 = 1 << 14;

/// [`LANES`] quantised slots (issue 24's compact storage): the centres in lattice steps from the
/// cell's slot origin ([`LATTICE_PER_CELL`]) and each slot's code into its class's (R, τ) table.
/// One cache line where a [`Block`] and its τ and index take three.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct QBlock {
    pub(super) x: [u16; LANES],
    pub(super) y: [u16; LANES],
    pub(super) z: [u16; LANES],
    pub(super) code: [u16; LANES],
}

/// The slots of a class in compact storage (overlap slots or centre cells): centres on a lattice of
/// step `step` (the cell edge
/// / [`LATTICE_PER_CELL`], 6·10⁻⁵ of a cell), radii and optical depths by code. The lattice point is
/// the particle *as stored*: every slot of a particle decodes to the same double-precision centre, the
/// cells that reference it were chosen from that centre, and the free flight is exact for it. Code 0
/// is padding: R = NaN, which no test passes.
#[derive(Default)]
pub(super) struct QSlots {
    pub(super) blocks: Vec<QBlock>,
    /// The largest inclusion radius of each block (its pre-test's radius: a per-lane gather costs
    /// more than the few extra exact tests on AMD's cores; each cell's slots are sorted by radius, so
    /// its blocks' radii stay close).
    pub(super) block_reach: Vec<f32>,
    /// Inclusion radius per code.
    pub(super) reach: Vec<f32>,
    /// τ per code and channel.
    pub(super) tau: Vec<f32>,
    pub(super) step: f64,
}

impl QSlots {
    /// The lattice coordinates of slot `s` of cell `cell` (k = 1: of the row that starts at `cell`).
    #[inline(always)]
    pub(super) fn lattice(&self, s: usize, cell: [usize; 3]) -> [i64; 3] {
        let (b, l) = (&self.blocks[s / LANES], s % LANES);
        let origin = |a: usize| (cell[a] as i64 - 1) * LATTICE_PER_CELL;
        let at = |a: usize, q: u16| origin(a) + q.wrapping_sub(origin(a) as u16) as i64;
        [at(0, b.x[l]), at(1, b.y[l]), at(2, b.z[l])]
    }
    /// The slot origin of `cell` in lattice coordinates modulo 2^16: what a pre-test subtracts from a
    /// slot's coordinates to get its offset from that origin.
    #[inline(always)]
    pub(super) fn origin_bits(cell: [usize; 3]) -> [u16; 3] {
        cell.map(|c| ((c as i64 - 1) * LATTICE_PER_CELL) as u16)
    }
    /// Centre (scene units) and inclusion radius of slot `s` of cell `cell` in a grid from `lo`.
    #[inline(always)]
    pub(super) fn ball(&self, lo: [f64; 3], s: usize, cell: [usize; 3]) -> ([f64; 3], f64) {
        let g = self.lattice(s, cell);
        (
            [0, 1, 2].map(|a| lo[a] + g[a] as f64 * self.step),
            self.reach[self.code(s)] as f64,
        )
    }
    #[inline(always)]
    pub(super) fn code(&self, s: usize) -> usize {
        self.blocks[s / LANES].code[s % LANES] as usize
    }
    pub(super) fn bytes(&self) -> usize {
        self.blocks.capacity() * std::mem::size_of::<QBlock>()
            + (self.block_reach.capacity() + self.reach.capacity() + self.tau.capacity()) * 4
    }
}

/// The lattice point (steps of `step` from `lo`) nearest `p`.
#[inline]
pub(super) fn lattice_point(p: [f64; 3], lo: [f64; 3], step: f64) -> [i64; 3] {
    [0, 1, 2].map(|a| ((p[a] - lo[a]) / step).round() as i64)
}

/// The ray as the pre-test sees it: two unit vectors `e1`, `e2` perpendicular to its direction and the
/// origin's coordinates along them, in single precision. A centre c lies within R of the ray's line iff
/// (c·e1 − o·e1)² + (c·e2 − o·e2)² < R²: the distance across the ray without forming c − o or its
/// projection on d (16 SSE operations per four lanes instead of 22, 14 AVX2 + FMA operations per eight,
/// and a shorter dependency chain).
#[derive(Clone, Copy)]
#[repr(C, align(32))]
pub(super) struct RayFrame {
    // Each coefficient broadcast to the lanes of a block once per ray: the pre-test loop calls
    // out (to `found`), which spills every vector register, and reloading a broadcast vector is one
    // memory operand where a scalar costs a load and a shuffle per block.
    pub(super) e1: [[f32; LANES]; 3],
    pub(super) e2: [[f32; LANES]; 3],
    pub(super) o1: [f32; LANES],
    pub(super) o2: [f32; LANES],
    /// The pre-test's tolerance (see [`PRETEST_SLACK`]).
    pub(super) slack: [f32; LANES],
    /// e1 and e2 times the lattice step of quantised slots (zero for spheres).
    pub(super) he1: [[f32; LANES]; 3],
    pub(super) he2: [[f32; LANES]; 3],
    /// e1 and e2 in double precision (a quantised step's offset).
    pub(super) e: [[f64; 3]; 2],
}

impl RayFrame {
    /// The frame of a cursor that tests no sphere.
    pub(super) const UNUSED: RayFrame = RayFrame {
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
    pub(super) fn new(ray: &RaySegment, slack: f32, step: f64) -> Self {
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
    pub(super) fn corner_offsets(
        &self,
        lo: [f64; 3],
        edge: [f64; 3],
        o: [f64; 3],
    ) -> [[f64; 4]; 2] {
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
/// operation per step ([`crate::simd::wide_simd`] said the CPU has it); otherwise two SSE operations
/// (x86-64) or a loop.
#[inline(always)]
pub(super) fn block_pretest<const WIDE: bool>(b: &Block, f: &RayFrame) -> u32 {
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
pub(super) unsafe fn block_pretest_avx2(b: &Block, f: &RayFrame) -> u32 {
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
pub(super) fn block_pretest_narrow(b: &Block, f: &RayFrame) -> u32 {
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
pub(super) fn qblock_pretest<const WIDE: bool>(
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
pub(super) unsafe fn qblock_pretest_avx2(
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
