//! Grains nobody can see (issue 10.3): size classes whose particles are many per query cylinder, each
//! with a tiny optical depth τ_i, sampled as a continuous medium instead of particle by particle.
//!
//! ## Why this is the same medium
//! A ray meets the particles of such a class as a staircase of many tiny jumps τ_i = −ln(1 − x_i);
//! averaged over rays, its transmittance over a length L is exp(−n L Σ π R_i² (1 − e^{−τ_i})) =
//! exp(−n C̄_t L) (`discrete.rs`: each disk removes exactly C_t,i from a beam). The field keeps Σ C_t,i
//! per cell — σ_t of the cell is the extinction of the particles whose centre lies in it divided by
//! the cell's volume — and samples free flights through it exactly (piecewise-constant σ_t along a
//! 3D-DDA: one exponential per cell crossed). What is lost is the fluctuation of the staircase around
//! its mean, relative size 1/√N for N particles per cylinder: the grain texture that no pixel
//! resolves when N is large. [`resolvable`] decides which classes keep it.
//!
//! The discrete classes and this field are two independent processes along the ray, so the first
//! interaction is the nearer of their two sampled distances (`discrete.rs` samples the field first
//! and walks the particles only up to its distance). An interaction in the field picks one particle of
//! its cell with probability ∝ w_i: the site's albedo and phase function are that particle's, so the
//! expected phase function is the cell's mixture weighted by extinction (Eq. 24's Q(θ) of the cell).
//!
//! ## A packet's flights together
//! Free flights without an optical depth are delta tracking against the field's majorant (Woodcock
//! tracking). Where one majorant serves the whole field and the CPU has AVX-512 (F, DQ, VL), a packet's
//! rays take their tentative collisions in lockstep, sixteen SIMD lanes at a time
//! ([`ContinuousField::sample_free_flights`]): each ray gets exactly the hit it would alone from the
//! same random bits (test `packet_free_flights_match_one_ray_at_a_time`). Their exponential's
//! logarithm is [`ln_unit`], which vectorises, where one ray at a time uses libm's single-precision
//! one (faster there): the two modes draw different exponentials of one distribution, so an image
//! differs by its noise between CPUs with and without AVX-512 (`MOTES_SIMD=avx2` gives the latter's).

use crate::render::footprint::{ClassMoments, SurfaceFootprint};
use crate::rng::stream_bits;
use crate::space::dda::{Bounds3, Dda, GridFrame};
use crate::space::grid::{bounding_box, size_class};
use crate::space::ray::RaySegment;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Default number of a class's particles a query cylinder must hold (over one mean free path, or
/// across the medium if that is shorter) for the class to be rendered as a continuous medium:
/// the lost grain texture, of relative size 1/√N, is then at most 1/√16 = 25 % per pixel, below the
/// Monte Carlo noise of a render at tens of spp (measured: `scripts/figures/continuous_switch.py`).
pub const DEFAULT_CONTINUOUS_COUNT: f64 = 16.0;

/// Particles per cell of the field. A cell spreads its particles' extinction over its whole cross
/// section, so a ray meets a cell's particles all together or not at all, and the cells' shot noise
/// (±1/√n each) lets light through: E[e^{−τ}] > e^{−E[τ]} (Jensen), whereas each grain's own disk
/// (−ln(1 − x), `discrete.rs`) keeps the grains' mean transmittance exact. Larger cells: less of that
/// bias, but less of the cloud's own density texture at the pixel scale. Measured on a 10 cm cloud of
/// 10^7 ice grains of 50 µm (transmittance of the field over that of the same grains walked one by one,
/// at optical depth 0.57 / 2.3 / 4.5): 8 per cell +0.66 / +2.6 / +5.8 %; 64: +0.09 / +0.52 / +1.7 %;
/// 256: about a fifth of that again, but the 4·10^6 × 20 µm row of `scripts/bench/bench_dense.py`
/// (default against exact) went from per-pixel RMS/noise 0.98 (64) to 1.93 (256; 8: 1.08).
const PARTICLES_PER_CELL: f64 = 64.0;

/// Cells per axis of a majorant block: [`ContinuousField::sample_free_flight`] walks blocks of this
/// many cells cubed, each with the largest σ_t of its cells, and looks up σ_t only at tentative
/// collisions (delta tracking) instead of crossing every cell (one exponential per cell). A block's
/// majorant is its largest cell's fluctuation: wider blocks mean fewer steps but more null collisions.
/// Measured side by side with cells of 8 particles (±35 %; 64 since issue 24.3, ±12 %)
/// (`scripts/bench/bench_dense.py --rows 1.6e6x80,4e6x20 --reps 3`, llvm_ad_rgb, default render,
/// seconds): cell by cell 1.10 / 0.67, blocks of 4 1.28 / 0.50, blocks of 2 1.08 / 0.54.
const MAJORANT_BLOCK: usize = 2;

/// Most cells along one axis (and in all) of the field.
const MAX_AXIS_CELLS: usize = 1 << 10;
const MAX_CELLS: f64 = 1.0e8;

/// For each particle (centre, inclusion radius R_i, extinction cross section w_i): is it
/// in a size class (the grid's factor-of-two classes of R) whose particles a query cylinder holds
/// fewer than `min_count` of, i.e. one that must stay discrete? The cylinder's length is the mean
/// chord of the particles' box (4V/S) or one mean free path 1/σ_t of the whole medium, whichever is
/// shorter (light seen by a pixel comes from about one mean free path deep): a class with n_c
/// particles of mean disk area A holds N_c = n_c A L / V of them. With it, the rule by which rays from
/// surfaces may see the continuous equivalent (`crate::render::footprint`), from the same classes.
pub fn resolvable(
    positions: &[[f64; 3]],
    reach: Column,
    weight: Column,
    min_count: f64,
) -> (Vec<bool>, Option<SurfaceFootprint>) {
    let n = positions.len();
    if n == 0 || !(min_count.is_finite()) {
        return (vec![true; n], None);
    }
    let (lo, hi) = bounding_box(positions);
    let e = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(1e-12 * (hi[a].abs() + lo[a].abs()).max(1e-300)));
    let volume = e[0] * e[1] * e[2];
    let chord = 4.0 * volume / (2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]));
    let sigma = (0..n).into_par_iter().map(weight).sum::<f64>() / volume;
    let length = if sigma > 0.0 {
        chord.min(1.0 / sigma)
    } else {
        chord
    };
    let reach_max = (0..n).into_par_iter().map(reach).reduce(|| 0.0, f64::max);
    // Per class: Σ1, Σ R, Σ R², Σ C (the mean disk area is π Σ R² / Σ1).
    let mut sums = [[0.0f64; 4]; crate::space::grid::SIZE_CLASSES];
    for i in 0..n {
        let r = reach(i);
        let s = &mut sums[size_class(reach_max, r)];
        s[0] += 1.0;
        s[1] += r;
        s[2] += r * r;
        s[3] += weight(i);
    }
    let keep: Vec<bool> = sums
        .iter()
        .map(|s| PI * s[2] * length / volume < min_count)
        .collect();
    let moments = sums
        .iter()
        .zip(&keep)
        .filter(|(_, &k)| k)
        .map(|(s, _)| ClassMoments::from_sums(*s, volume))
        .collect();
    let bounds = Bounds3 { lo, hi };
    let footprint = SurfaceFootprint::new(moments, bounds, length, min_count);
    let keep = (0..n)
        .into_par_iter()
        .map(|i| keep[size_class(reach_max, reach(i))])
        .collect();
    (keep, footprint)
}

/// A per-particle value by original index: a slice's entry, or computed (a class table through each
/// particle's code, so that 10^8 particles need no column of their own).
pub type Column<'a> = &'a (dyn Fn(usize) -> f64 + Sync);

/// Where a free flight through the field interacts: its t and the cell it lies in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldHit {
    pub t: f64,
    pub cell: usize,
}

/// Marks a member of a field that is a class code (compact storage, `crate::render::storage`) and not
/// a particle's index: the optics of a continuous particle are those of its class, and no ray needs
/// to know which grain it was. Particle indices stay below 2^31.
pub const CLASS_FLAG: u32 = 1 << 31;

/// The particles of a field, in cell order.
enum Members {
    /// Original indices (full storage).
    Ids(Vec<u32>),
    /// Class codes of at most 16 bits (compact storage), each with its running share of the cell's
    /// extinction in the upper 16 bits (the field's `cdf` is empty): a pick reads one array, one
    /// cache miss instead of two (the misses were 85 % of a pick's time in a dense Cornell box).
    Classes(Vec<u32>),
    /// Class codes with [`CLASS_FLAG`] (compact storage of more than 65536 classes).
    WideClasses(Vec<u32>),
    /// One list of class codes (with [`CLASS_FLAG`]) that every cell holds in the same shares, its
    /// σ_t set by a density (a procedural cloud, `crate::render::procedural`): `start` is empty.
    Shared(Vec<u32>),
    /// As many particles, not kept: the field's pick table ([`ContinuousField::picks`]) answers
    /// every pick ([`ContinuousField::forget_members`]).
    Counted(usize),
}

impl Members {
    #[inline]
    fn get(&self, j: usize) -> u32 {
        match self {
            Members::Ids(v) => v[j],
            Members::Classes(v) => CLASS_FLAG | (v[j] & 0xFFFF),
            Members::WideClasses(v) | Members::Shared(v) => v[j],
            Members::Counted(_) => unreachable!("a field without its members picks by its table"),
        }
    }
    fn len(&self) -> usize {
        match self {
            Members::Ids(v)
            | Members::WideClasses(v)
            | Members::Shared(v)
            | Members::Classes(v) => v.len(),
            Members::Counted(n) => *n,
        }
    }
    fn bytes(&self) -> usize {
        match self {
            Members::Ids(v)
            | Members::WideClasses(v)
            | Members::Shared(v)
            | Members::Classes(v) => v.len() * 4,
            Members::Counted(_) => 0,
        }
    }
}

/// The continuous part of a discrete medium (module docs).
pub struct ContinuousField {
    /// The cells: the centres' box, cell edges and cells per axis.
    frame: GridFrame,
    /// 1 / the cell edges (a tentative collision's cell by multiplication: three divisions were a few
    /// percent of a dense cloud's field free flight).
    inv_cell: [f64; 3],
    /// σ_t of each cell (grey, per scene unit).
    sigma: Vec<f32>,
    /// Cell `c` holds members `start[c]..start[c + 1]`.
    start: Vec<u32>,
    /// Each particle, in cell order: its original index, or its class (compact storage).
    members: Members,
    /// Running share of the cell's extinction up to and including each particle (for picking one),
    /// in units of 1/65535 (the last of a cell is 65535); empty where `members` holds it
    /// ([`Members::Classes`]).
    cdf: Vec<u16>,
    /// Where [`Self::picking_by`] found few groups of classes per cell (classes that scatter alike:
    /// an optics bin's radius levels), one class of each group once with the running share of the cell's extinction (packed as in [`Members::Classes`])
    /// and each cell's first entry: what a pick reads instead of `members`, small enough to stay in
    /// cache (a pick's cache miss was 10 % of a dense Cornell box's render in llvm_ad_rgb, and of the
    /// staircase's). Picks each class (group) with the same probability as `members` does.
    picks: Option<(Vec<u32>, Vec<u32>)>,
    /// Blocks of [`MAJORANT_BLOCK`]³ cells (the last ones along an axis may reach past the field's
    /// box, where σ_t = 0) and the largest σ_t of each.
    block_frame: GridFrame,
    majorant: Vec<f32>,
    /// The largest σ_t of all cells, where it is close to the blocks' mean (a cloud of even density):
    /// free flights then use it everywhere instead of walking the blocks ([`UNIFORM_MAJORANT_RATIO`]).
    uniform_majorant: Option<f64>,
}

/// A field uses one majorant for all its cells (its largest σ_t) when that is at most this many times
/// the mean of the blocks' majorants (over all blocks, empty ones included: the rate of tentative
/// collisions a block walk would see over the field's box). A few more null collisions then cost less
/// than a block walk per free flight. Measured in llvm_ad_rgb, 96 px, 16 spp, seconds per render with
/// the blocks / with one majorant (ratio): Cornell box 0.83 / 0.785 (1.24), staircase 0.49 / 0.39
/// (1.51), lamp 0.098 / 0.086 (2.41), house 0.103 / 0.071 (2.95); a Cornell box whose grains crowd
/// a ball in its middle 0.64 / 0.64 (7.8) and 0.615 / 0.675 (16.2).
const UNIFORM_MAJORANT_RATIO: f64 = 4.0;

/// Lanes of the lockstep that met a tentative collision outside the cells before their end and went on
/// one ray at a time (the tests check that they are exercised).
#[cfg(test)]
static CONTINUED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Rays of one [`ContinuousField::sample_free_flights`] call stepped together.
pub const FLIGHT_LANES: usize = 16;

/// A lane of [`FlightLanes`]: still tracking, past its end, at its site, or at its first tentative
/// collision outside the field's box (its end then needs clipping to the box: the caller goes on).
/// (Past its end is 0, so that a default lane is unused.)
const LANE_NONE: u64 = 0;
const LANE_RUNNING: u64 = 1;
const LANE_REAL: u64 = 2;
const LANE_OUTSIDE: u64 = 3;

/// The state of [`FLIGHT_LANES`] free flights, one array per quantity (SIMD lanes). Unused lanes are
/// past their end from the start.
#[derive(Default)]
struct FlightLanes {
    o: [[f64; FLIGHT_LANES]; 3],
    d: [[f64; FLIGHT_LANES]; 3],
    t: [f64; FLIGHT_LANES],
    t1: [f64; FLIGHT_LANES],
    key: [u64; FLIGHT_LANES],
    /// The index k of the lane's last tentative collision.
    k: [u64; FLIGHT_LANES],
    cell: [u64; FLIGHT_LANES],
    state: [u64; FLIGHT_LANES],
    /// 1 where the lane's end is not known to be the box's exit (its ray started inside the box).
    /// (All lane columns are 64-bit: the loop over them vectorises.)
    clip_on_exit: [u64; FLIGHT_LANES],
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

/// (The path `render::phase_lanes` names it by.)
pub(crate) use crate::simd::lockstep_simd;

/// What a tentative collision of delta tracking turns out to be.
enum Tentative {
    Real(FieldHit),
    Null,
    /// Outside the field's box (σ_t = 0 there: a null collision).
    Outside,
}

/// A unit exponential from the upper 32 of `bits`: −ln((k + 1/2) / 2^32) (cut off at 22.9 mean free
/// paths, probability 1.2e-10). One ray at a time (`WIDE` false) by libm's single-precision logarithm
/// (a distance 6e-8 off relatively; f64's libm logarithm was 4 % of a dense cloud's events,
/// `field_events` bench); a packet's rays in lockstep (`WIDE`) by [`ln_unit`], which vectorises, and
/// so do their flights' continuations one by one (the same hits either way, for a test to compare).
#[inline(always)]
fn exponential<const WIDE: bool>(bits: u64) -> f64 {
    let u = ((bits >> 32) as f64 + 0.5) * (1.0 / 4294967296.0);
    if WIDE {
        -ln_unit(u)
    } else {
        -(u as f32).ln() as f64
    }
}

/// ln x for a normal x in (0, 1], to about 1e-13 relative, without a call (libm's is not inlined, so it
/// keeps a loop from vectorising): x = 2^e m with m in [√½, √2), ln m = 2 atanh(s), s = (m − 1) / (m + 1),
/// |s| ≤ 0.172, by its series to s^15 (the next term is below 4e-14 of the sum).
#[inline(always)]
fn ln_unit(x: f64) -> f64 {
    let bits = x.to_bits();
    let m = f64::from_bits(bits & 0x000F_FFFF_FFFF_FFFF | 0x3FF0_0000_0000_0000);
    let e = ((bits >> 52) & 0x7FF) as i64 - 1023;
    let high = m > std::f64::consts::SQRT_2;
    let (m, e) = (if high { 0.5 * m } else { m }, if high { e + 1 } else { e });
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let (z, c) = (s * s, |k: f64| 1.0 / k);
    // Estrin's scheme: the terms in pairs (a shorter chain of dependent products than Horner's).
    let (z2, z4) = (z * z, z * z * (z * z));
    let series = (1.0 + z * c(3.0))
        + z2 * (c(5.0) + z * c(7.0))
        + z4 * ((c(9.0) + z * c(11.0)) + z2 * (c(13.0) + z * c(15.0)));
    e as f64 * std::f64::consts::LN_2 + 2.0 * s * series
}

/// [`ContinuousField::uniform_majorant`] of block majorants. `MOTES_UNIFORM_MAJORANT=0` at build keeps
/// the blocks (`scripts/bench/bench_quantise.py --switch MOTES_UNIFORM_MAJORANT`'s comparison).
fn uniform_majorant(majorant: &[f32]) -> Option<f64> {
    if !crate::render::env_flag("MOTES_UNIFORM_MAJORANT") {
        return None;
    }
    let max = majorant.iter().fold(0.0f64, |x, &m| x.max(m as f64));
    let mean = majorant.iter().map(|&m| m as f64).sum::<f64>() / majorant.len().max(1) as f64;
    (max > 0.0 && max <= UNIFORM_MAJORANT_RATIO * mean).then_some(max)
}

impl ContinuousField {
    /// The field of the particles `ids` (original indices; None: all), with centres `positions`,
    /// inclusion radii `reach` and extinction cross sections `weight` (scene units), all indexed by
    /// original index (a subset is selected, not copied: 10^8 particles). With `classes` (each
    /// particle's class code, by original index) the field keeps the classes instead of the indices
    /// (compact storage).
    pub fn build(
        positions: &[[f64; 3]],
        reach: Column,
        weight: Column,
        ids: Option<&[u32]>,
        classes: Option<&[u32]>,
    ) -> Self {
        let n = ids.map_or(positions.len(), <[u32]>::len);
        let id = |j: usize| ids.map_or(j, |v| v[j] as usize);
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let mut reach_max = 0.0f64;
        for j in 0..n {
            let (p, i) = (positions[id(j)], id(j));
            reach_max = reach_max.max(reach(i));
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        // The field fills the centres' box exactly, cells fitted to it per axis: a cell straddling the
        // box face would spread its particles' extinction over volume a bounded medium (a null-BSDF
        // cube around generated particles) never reaches, and darken the cloud's edges (measured:
        // 1.6-2.7 % less light in the dust room before). An axis the centres do not span gets the
        // thickness of a ball, 2 R_max.
        for a in 0..3 {
            let pad =
                (reach_max - 0.5 * (hi[a] - lo[a])).max(0.0) + 1e-9 * (hi[a] - lo[a]).max(1e-300);
            lo[a] -= pad;
            hi[a] += pad;
        }
        let ext = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(1e-12));
        let volume = ext[0] * ext[1] * ext[2];
        let cells = (n as f64 / PARTICLES_PER_CELL).clamp(1.0, MAX_CELLS);
        let edge = (volume / cells).cbrt();
        let dims = ext.map(|x| ((x / edge).round() as usize).clamp(1, MAX_AXIS_CELLS));
        let cell = [0, 1, 2].map(|a| ext[a] / dims[a] as f64);
        let n_cells = dims[0] * dims[1] * dims[2];
        let cell_of = |p: &[f64; 3]| {
            let idx =
                [0, 1, 2].map(|a| (((p[a] - lo[a]) / cell[a]).max(0.0) as usize).min(dims[a] - 1));
            (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0]
        };
        // Counting sort by cell, in u32 (the field takes at most 2^32 particles, as the grid does).
        let which: Vec<u32> = (0..n)
            .into_par_iter()
            .map(|j| cell_of(&positions[id(j)]) as u32)
            .collect();
        let mut start = vec![0u32; n_cells + 1];
        for &c in &which {
            start[c as usize + 1] += 1;
        }
        for c in 0..n_cells {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        // The original indices in cell order.
        let mut order = vec![0u32; n];
        for (j, &c) in which.iter().enumerate() {
            order[fill[c as usize] as usize] = id(j) as u32;
            fill[c as usize] += 1;
        }
        drop((which, fill));
        let cell_volume = cell[0] * cell[1] * cell[2];
        let mut sigma = vec![0f32; n_cells];
        let mut cdf = vec![0u16; n];
        for c in 0..n_cells {
            let (a, b) = (start[c] as usize, start[c + 1] as usize);
            let total: f64 = order[a..b].iter().map(|&i| weight(i as usize)).sum();
            sigma[c] = (total / cell_volume) as f32;
            let mut acc = 0.0;
            for j in a..b {
                acc += weight(order[j] as usize);
                let share = if total > 0.0 {
                    acc / total
                } else {
                    (j + 1 - a) as f64 / (b - a) as f64
                };
                cdf[j] = if j + 1 == b {
                    u16::MAX
                } else {
                    (share * u16::MAX as f64).round() as u16
                };
            }
        }
        let (members, cdf) = match classes {
            None => (Members::Ids(order), cdf),
            Some(c) if c.iter().all(|&k| k <= u16::MAX as u32) => {
                let packed = order
                    .iter()
                    .zip(&cdf)
                    .map(|(&i, &f)| (f as u32) << 16 | c[i as usize])
                    .collect();
                (Members::Classes(packed), Vec::new())
            }
            Some(c) => (
                Members::WideClasses(order.iter().map(|&i| CLASS_FLAG | c[i as usize]).collect()),
                cdf,
            ),
        };
        let (block_frame, majorant) = block_majorants(lo, cell, dims, &sigma);
        ContinuousField {
            frame: GridFrame::new(lo, cell, dims),
            inv_cell: cell.map(|c| 1.0 / c),
            sigma,
            start,
            members,
            cdf,
            picks: None, // `picking_by`
            uniform_majorant: uniform_majorant(&majorant),
            block_frame,
            majorant,
        }
    }

    /// A field over the box [lo, hi] cut into `dims` cells, whose cells all hold the classes
    /// `members` (codes with [`CLASS_FLAG`]) in proportion to `weight` (extinction per unit volume at
    /// unit density, scene units⁻¹), scaled by `density(cell_lo, cell_hi)`, the mean relative density
    /// over the cell: σ_t of a cell = density × Σ weight. A procedural cloud's grains nobody can see,
    /// as the expected extinction of its Poisson process (`crate::render::procedural`).
    pub fn from_density(
        lo: [f64; 3],
        hi: [f64; 3],
        dims: [usize; 3],
        density: impl Fn([f64; 3], [f64; 3]) -> f64 + Sync,
        members: Vec<u32>,
        weight: &[f64],
    ) -> Self {
        let cell = [0, 1, 2].map(|a| (hi[a] - lo[a]) / dims[a] as f64);
        let total: f64 = weight.iter().sum();
        let sigma: Vec<f32> = (0..dims[0] * dims[1] * dims[2])
            .into_par_iter()
            .map(|c| {
                let idx = [
                    c % dims[0],
                    (c / dims[0]) % dims[1],
                    c / (dims[0] * dims[1]),
                ];
                let a = [0, 1, 2].map(|k| lo[k] + cell[k] * idx[k] as f64);
                let b = [0, 1, 2].map(|k| a[k] + cell[k]);
                (density(a, b) * total) as f32
            })
            .collect();
        let mut acc = 0.0;
        let cdf = weight
            .iter()
            .enumerate()
            .map(|(j, w)| {
                acc += w;
                if j + 1 == weight.len() || total <= 0.0 {
                    u16::MAX
                } else {
                    ((acc / total) * u16::MAX as f64).round() as u16
                }
            })
            .collect();
        let (block_frame, majorant) = block_majorants(lo, cell, dims, &sigma);
        ContinuousField {
            frame: GridFrame::new(lo, cell, dims),
            inv_cell: cell.map(|c| 1.0 / c),
            sigma,
            start: Vec::new(),
            members: Members::Shared(members),
            cdf,
            picks: None,
            uniform_majorant: uniform_majorant(&majorant),
            block_frame,
            majorant,
        }
    }

    /// Picks by groups of classes (`group` of a class code; compact storage: its optics bin, which
    /// is all an interaction in the field reads of the particle: albedo and phase function): each
    /// cell's groups with their summed shares and one class of each stand in for its classes, so that
    /// a broad size distribution's picks also read a table that stays in cache. The group is picked with
    /// its exact probability; which of its classes stands for it is the first in the cell.
    pub fn picking_by(mut self, group: impl Fn(u32) -> u32) -> Self {
        if let Members::Classes(m) = &self.members {
            self.picks = distinct_classes(m, &self.start, &group);
        }
        self
    }

    /// The same field without its list of members where its pick table answers every pick (the
    /// grains' continuous equivalent, whose picks are all it is asked: 4 bytes per particle saved).
    /// Its cells' members are then their table's classes, one for each group.
    pub fn forget_members(mut self) -> Self {
        if let (Some(_), Members::Classes(m)) = (&self.picks, &self.members) {
            self.members = Members::Counted(m.len());
        }
        self
    }

    /// The members of cell `c`: `range.0..range.1` of the member list.
    #[inline]
    fn range(&self, c: usize) -> (usize, usize) {
        match self.members {
            Members::Shared(ref m) if self.sigma[c] > 0.0 => (0, m.len()),
            Members::Shared(_) => (0, 0),
            _ => (self.start[c] as usize, self.start[c + 1] as usize),
        }
    }

    /// σ_t of the cell holding `p` carried by the class `member` of a shared field (None elsewhere).
    pub fn shared_sigma(&self, p: [f64; 3], member: u32) -> Option<f64> {
        let Members::Shared(m) = &self.members else {
            return None;
        };
        let k = m.iter().position(|&x| x == member)?;
        let c = self.cell_at(p)?;
        let below = if k == 0 { 0.0 } else { self.cdf[k - 1] as f64 };
        Some(self.sigma[c] as f64 * (self.cdf[k] as f64 - below) / u16::MAX as f64)
    }

    /// Particles of the field (the member list's length for a shared field).
    pub fn len(&self) -> usize {
        self.members.len()
    }
    pub fn is_empty(&self) -> bool {
        self.members.len() == 0
    }
    pub fn dims(&self) -> [usize; 3] {
        self.frame.dims
    }
    pub fn cell_volume(&self) -> f64 {
        let cell = self.frame.cell;
        cell[0] * cell[1] * cell[2]
    }
    /// Heap bytes.
    pub fn bytes(&self) -> usize {
        (self.sigma.len() + self.start.len() + self.majorant.len()) * 4
            + self.members.bytes()
            + self.cdf.len() * 2
            + self
                .picks
                .as_ref()
                .map_or(0, |(a, b)| (a.len() + b.len()) * 4)
    }

    /// The same free flight as [`Self::free_flight`] in distribution, by delta tracking (Woodcock
    /// tracking; pbrt-v4's majorant grid): tentative collisions at the rate of each block's majorant
    /// (or of the whole field's, [`UNIFORM_MAJORANT_RATIO`]), accepted with probability σ_t / majorant.
    /// Costs one σ_t lookup per tentative collision instead of one exponential per cell crossed, but
    /// gives no optical depth. `next_bits` supplies 64 random bits per tentative collision: the upper 32
    /// draw its distance, the lower 32 its acceptance (one hash where two uniforms were 2 % of a dense
    /// render; the distance's exponential is then cut off at 22.9 mean free paths, probability 1.2e-10).
    pub fn sample_free_flight(
        &self,
        ray: &RaySegment,
        next_bits: impl FnMut() -> u64,
    ) -> Option<FieldHit> {
        self.free_flight_by::<false>(ray, next_bits)
    }

    /// [`Self::sample_free_flight`] with the exponentials of [`exponential`]`::<WIDE>`.
    fn free_flight_by<const WIDE: bool>(
        &self,
        ray: &RaySegment,
        mut next_bits: impl FnMut() -> u64,
    ) -> Option<FieldHit> {
        if let Some(m) = self.uniform_majorant {
            // One majorant for the whole field: no block walk at all. A ray that starts inside the
            // field's box needs no clip (three divisions) until a tentative collision falls outside
            // it (past its exit, as a convex box is left once, or at a face by rounding).
            let bounds = &self.frame.bounds;
            let start = [0, 1, 2].map(|a| ray.o[a] + ray.t0 * ray.d[a]);
            let inside = (0..3).all(|a| start[a] > bounds.lo[a] && start[a] < bounds.hi[a]);
            let (t, t1) = if inside {
                (ray.t0, ray.t1)
            } else {
                bounds.clip(ray)?
            };
            return self.uniform_flight_from::<WIDE>(ray, m, t, t1, !inside, next_bits);
        }
        for b in Dda::new(&self.block_frame, ray) {
            let m = self.majorant[b.index] as f64;
            if m <= 0.0 {
                continue;
            }
            let mut t = b.t_enter;
            loop {
                let bits = next_bits();
                t += exponential::<WIDE>(bits) / m;
                if t >= b.t_exit {
                    break;
                }
                if let Some(hit) = self.tentative(ray, t, m, bits) {
                    return Some(hit);
                }
            }
        }
        None
    }

    /// Delta tracking against the whole field's majorant `m` from `t` (up to `t1`; `exit_known`: `t1` is
    /// at most the field's exit, else it is clipped there once a tentative collision falls outside).
    fn uniform_flight_from<const WIDE: bool>(
        &self,
        ray: &RaySegment,
        m: f64,
        mut t: f64,
        mut t1: f64,
        mut exit_known: bool,
        mut next_bits: impl FnMut() -> u64,
    ) -> Option<FieldHit> {
        let inv_m = 1.0 / m;
        loop {
            let bits = next_bits();
            t += exponential::<WIDE>(bits) * inv_m;
            if t >= t1 {
                return None;
            }
            match self.tentative_in_box(ray, t, m, bits) {
                Tentative::Real(hit) => return Some(hit),
                // Outside the box, or at its face by rounding: now its exit is worth a clip.
                Tentative::Outside if !exit_known => {
                    exit_known = true;
                    t1 = self
                        .frame
                        .bounds
                        .clip(ray)
                        .map_or(t, |(_, exit)| exit.min(t1));
                    if t >= t1 {
                        return None;
                    }
                }
                _ => {}
            }
        }
    }

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
    fn sample_packet_flights_with(
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
        // the loop lane by lane, each ray stepping as long as the packet's slowest (`field_events`
        // bench: 0.72 us per event against 0.49 one ray at a time).
        let Some(m) = self.uniform_majorant.filter(|_| n > 1 && lockstep) else {
            (0..n).for_each(|i| out[i] = one_by_one(i));
            return;
        };
        let mut lanes = FlightLanes::default();
        let bounds = &self.frame.bounds;
        for (i, ray) in rays.iter().enumerate().take(n) {
            let start = [0, 1, 2].map(|a| ray.o[a] + ray.t0 * ray.d[a]);
            let inside = (0..3).all(|a| start[a] > bounds.lo[a] && start[a] < bounds.hi[a]);
            let span = if inside {
                Some((ray.t0, ray.t1))
            } else {
                bounds.clip(ray)
            };
            let Some((t, t1)) = span else { continue };
            lanes.set(i, ray, keys[i], t, t1, !inside);
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
                    CONTINUED.fetch_add((t < t1) as usize, std::sync::atomic::Ordering::Relaxed);
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
    fn step_lanes(&self, m: f64, lanes: &mut FlightLanes) {
        #[cfg(target_arch = "x86_64")]
        if lockstep_simd() {
            // SAFETY: the CPU has AVX-512 F, DQ and VL (`lockstep_simd`).
            return unsafe { self.step_lanes_avx512(m, lanes) };
        }
        self.step_lanes_with(m, lanes)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
    unsafe fn step_lanes_avx512(&self, m: f64, lanes: &mut FlightLanes) {
        self.step_lanes_with(m, lanes)
    }

    /// [`Self::step_lanes`] as straight-line code over the lanes (no call, no early exit per lane), which
    /// the compiler vectorises for the instruction set it is compiled for. Each lane does exactly what
    /// [`Self::uniform_flight_from`] does with the same draws.
    #[inline(always)]
    fn step_lanes_with(&self, m: f64, l: &mut FlightLanes) {
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

    /// [`Self::tentative`], telling a null collision inside the field's box from a point outside it.
    #[inline(always)]
    fn tentative_in_box(&self, ray: &RaySegment, t: f64, m: f64, bits: u64) -> Tentative {
        let p = [0, 1, 2].map(|a| ray.o[a] + t * ray.d[a]);
        let Some(cell) = self.cell_near(p) else {
            return Tentative::Outside;
        };
        let u = (bits as u32) as f64 * (1.0 / 4294967296.0);
        if u * m < self.sigma[cell] as f64 {
            Tentative::Real(FieldHit { t, cell })
        } else {
            Tentative::Null
        }
    }

    /// A tentative collision at `t` against majorant `m`: real with probability σ_t / m (by the lower
    /// 32 of `bits`). Outside the field's box (blocks reach past it; rounding at its faces) σ_t = 0: a
    /// null collision.
    #[inline(always)]
    fn tentative(&self, ray: &RaySegment, t: f64, m: f64, bits: u64) -> Option<FieldHit> {
        match self.tentative_in_box(ray, t, m, bits) {
            Tentative::Real(hit) => Some(hit),
            Tentative::Null | Tentative::Outside => None,
        }
    }

    /// Exact free flight over a ray segment (|d| = 1): the first t where the optical depth walked
    /// exceeds `target` (= −ln(1 − u)), and the optical depth walked up to it (or to t1).
    pub fn free_flight(&self, ray: &RaySegment, target: f64) -> (Option<FieldHit>, f64) {
        let mut acc = 0.0;
        for c in Dda::new(&self.frame, ray) {
            let idx = c.index;
            let s = self.sigma[idx] as f64;
            if s > 0.0 {
                let x = s * (c.t_exit - c.t_enter);
                if acc + x > target {
                    let t = (c.t_enter + (target - acc) / s).min(c.t_exit);
                    return (Some(FieldHit { t, cell: idx }), target);
                }
                acc += x;
            }
        }
        (None, acc)
    }

    /// Optical depth of a ray segment (|d| = 1).
    pub fn optical_depth(&self, ray: &RaySegment) -> f64 {
        Dda::new(&self.frame, ray)
            .map(|c| self.sigma[c.index] as f64 * (c.t_exit - c.t_enter))
            .sum()
    }

    /// The particle of cell `cell` that an interaction there scatters from: each with probability ∝
    /// its extinction, by `u` in [0, 1). None for an empty cell.
    pub fn pick(&self, cell: usize, u: f64) -> Option<u32> {
        let (a, b) = self.range(cell);
        if a == b {
            return None;
        }
        let target = u * u16::MAX as f64;
        if let Some((first, packed)) = &self.picks {
            let (a, b) = (first[cell] as usize, first[cell + 1] as usize);
            let k = packed[a..b].partition_point(|&x| ((x >> 16) as f64) <= target);
            return Some(CLASS_FLAG | (packed[a + k.min(b - a - 1)] & 0xFFFF));
        }
        let k = match &self.members {
            Members::Classes(v) => v[a..b].partition_point(|&x| ((x >> 16) as f64) <= target),
            _ => self.cdf[a..b].partition_point(|&x| (x as f64) <= target),
        };
        Some(self.members.get(a + k.min(b - a - 1)))
    }

    /// [`Self::cell_at`] by multiplying with the cells' reciprocal edges: the same cell but at points
    /// within an ulp of a cell face, which may go to the neighbour (a tentative collision there is
    /// as likely in either).
    #[inline]
    fn cell_near(&self, p: [f64; 3]) -> Option<usize> {
        let lo = &self.frame.bounds.lo;
        self.cell_of(|a| (p[a] - lo[a]) * self.inv_cell[a])
    }

    /// The cell holding point `p`, if inside the field.
    pub fn cell_at(&self, p: [f64; 3]) -> Option<usize> {
        let GridFrame { bounds, cell, .. } = &self.frame;
        self.cell_of(|a| (p[a] - bounds.lo[a]) / cell[a])
    }

    /// The cell at `x(axis)` cells from the field's low corner along each axis, if inside.
    #[inline(always)]
    fn cell_of(&self, x: impl Fn(usize) -> f64) -> Option<usize> {
        let dims = &self.frame.dims;
        let mut c = [0usize; 3];
        for a in 0..3 {
            let x = x(a);
            if !(x >= 0.0 && x < dims[a] as f64) {
                return None;
            }
            c[a] = x as usize;
        }
        Some((c[2] * dims[1] + c[1]) * dims[0] + c[0])
    }

    /// The particles of a cell (original indices, or class codes with [`CLASS_FLAG`]; a field that
    /// forgot its members: one class of each group in the cell).
    pub fn members(&self, cell: usize) -> impl Iterator<Item = u32> + '_ {
        let (table, (a, b)): (&[u32], _) = match (&self.members, &self.picks) {
            (Members::Counted(_), Some((first, packed))) => (
                &packed[first[cell] as usize..first[cell + 1] as usize],
                (0, 0),
            ),
            _ => (&[], self.range(cell)),
        };
        // A shared list's classes that carry none of the cell's extinction are not in it.
        let shared = matches!(self.members, Members::Shared(_));
        table.iter().map(|&x| CLASS_FLAG | (x & 0xFFFF)).chain(
            (a..b)
                .filter(move |&j| !shared || self.cdf[j] > if j == 0 { 0 } else { self.cdf[j - 1] })
                .map(|j| self.members.get(j)),
        )
    }
}

/// Each cell's distinct groups of classes (`group` of a class code) of a [`Members::Classes`] list
/// (cells `start`), with their summed shares of the cell's extinction and the first class of each,
/// packed as the list is: (first entry per cell, entries), or None where a cell holds more than
/// sixteen groups or the whole would not be at most a quarter of the list.
fn distinct_classes(
    members: &[u32],
    start: &[u32],
    group: &dyn Fn(u32) -> u32,
) -> Option<(Vec<u32>, Vec<u32>)> {
    const PICK_GROUPS: usize = 16;
    let cells = start.len() - 1;
    let (mut first, mut packed) = (Vec::with_capacity(start.len()), Vec::new());
    // (group, its first class, summed share)
    let mut shares: Vec<(u32, u32, u32)> = Vec::new();
    for c in 0..cells {
        first.push(packed.len() as u32);
        shares.clear();
        let mut below = 0u32;
        for &m in &members[start[c] as usize..start[c + 1] as usize] {
            let (cdf, class) = (m >> 16, m & 0xFFFF);
            let share = cdf - below.min(cdf);
            below = cdf;
            let g = group(class);
            if let Some(s) = shares.iter_mut().find(|s| s.0 == g) {
                s.2 += share;
            } else if shares.len() < PICK_GROUPS {
                shares.push((g, class, share));
            } else {
                return None;
            }
        }
        let mut acc = 0u32;
        for (j, &(_, class, share)) in shares.iter().enumerate() {
            acc += share;
            // The last entry ends at the cell's total, as the list's does.
            let cdf = if j + 1 == shares.len() { below } else { acc };
            packed.push(cdf << 16 | class);
        }
        if packed.len() > members.len() / 4 + cells {
            return None;
        }
    }
    first.push(packed.len() as u32);
    Some((first, packed))
}

/// The majorant blocks over cells `dims` of edge `cell` from `lo`: their frame and the largest σ_t of
/// each block's cells.
fn block_majorants(
    lo: [f64; 3],
    cell: [f64; 3],
    dims: [usize; 3],
    sigma: &[f32],
) -> (GridFrame, Vec<f32>) {
    let bd = dims.map(|n| n.div_ceil(MAJORANT_BLOCK));
    let mut majorant = vec![0f32; bd[0] * bd[1] * bd[2]];
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let s = sigma[(z * dims[1] + y) * dims[0] + x];
                let b = ((z / MAJORANT_BLOCK) * bd[1] + y / MAJORANT_BLOCK) * bd[0]
                    + x / MAJORANT_BLOCK;
                majorant[b] = majorant[b].max(s);
            }
        }
    }
    let frame = GridFrame::new(lo, cell.map(|c| c * MAJORANT_BLOCK as f64), bd);
    (frame, majorant)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::space::vec3;
    use crate::test_rng::{assert_escape_rate, lcg, random_points};
    use std::sync::atomic::Ordering;

    /// The field's optical depth along long rays through a uniform random cloud equals σ_t L (the
    /// particles' summed extinction over the volume), free flights escape with probability e^{−τ},
    /// and picks follow each cell's extinction shares.
    #[test]
    fn field_is_the_mean_of_the_particles() {
        let mut s = 5u64;
        let n = 200_000;
        let pos = random_points(&mut s, n);
        let reach = vec![0.01; n];
        let w: Vec<f64> = (0..n).map(|_| 1e-5 * (0.5 + lcg(&mut s))).collect();
        let ids: Vec<u32> = (0..n as u32).collect();
        let f = ContinuousField::build(&pos, &|i| reach[i], &|i| w[i], Some(&ids), None);
        let sigma = w.iter().sum::<f64>(); // volume 1
        let ray = RaySegment::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], 0.0, 3.0);
        let tau = f.optical_depth(&ray);
        assert!((tau / sigma - 1.0).abs() < 0.1, "{tau} vs {sigma}");
        let mut mean = 0.0;
        for _ in 0..200 {
            let o = [lcg(&mut s), lcg(&mut s), -1.0];
            mean += f.optical_depth(&RaySegment { o, ..ray }) / 200.0;
        }
        assert!((mean / sigma - 1.0).abs() < 0.02, "{mean} vs {sigma}");
        assert_escape_rate(&mut s, 20_000, (-tau).exp(), |u| {
            let (hit, walked) = f.free_flight(&ray, -(1.0 - u).ln());
            if let Some(h) = hit {
                assert!(h.t >= 0.95 && h.t <= 2.05, "{}", h.t); // the box, to a cell (~0.034)
                let before = f.optical_depth(&ray.between(0.0, h.t));
                assert!((before - walked).abs() < 1e-6 * tau.max(1.0));
            } else {
                assert!((walked - tau).abs() < 1e-9);
            }
            hit.is_none()
        });
        let c = f.cell_at([0.5, 0.5, 0.5]).unwrap();
        let m: Vec<u32> = f.members(c).collect();
        assert!(!m.is_empty());
        let total: f64 = m.iter().map(|&i| w[i as usize]).sum();
        let mut counts = vec![0usize; m.len()];
        let picks = 40_000;
        for _ in 0..picks {
            let i = f.pick(c, lcg(&mut s)).unwrap();
            counts[m.iter().position(|&x| x == i).unwrap()] += 1;
        }
        for (k, &i) in m.iter().enumerate() {
            let p = w[i as usize] / total;
            let sd = (p * (1.0 - p) / picks as f64).sqrt();
            assert!((counts[k] as f64 / picks as f64 - p).abs() < 5.0 * sd);
        }
    }

    /// A packet's free flights stepped together give each ray exactly the hit it gets alone (with the
    /// same exponentials), on every CPU (the lockstep forced, lane by lane without AVX-512) and as the
    /// CPU runs them: rays starting inside, outside and on the box, leaving it, ending inside it, along
    /// axes; one field majorant, blocks, and one majorant with cells 5 % too small for the box (tentative
    /// collisions then fall outside the cells before the box's exit, and those lanes go on one ray at a
    /// time, which rounding at a face causes only now and then); packets of 1 to 24 rays.
    #[test]
    fn packet_free_flights_match_one_ray_at_a_time() {
        let mut s = 23u64;
        let mut f = ContinuousField::build(
            &random_points(&mut s, 30_000),
            &|_| 0.02,
            &|_| 1e-4,
            None,
            None,
        );
        let largest = f.majorant.iter().fold(0.0f64, |x, &m| x.max(m as f64));
        let inv_cell = f.inv_cell;
        let continued_before = CONTINUED.load(Ordering::Relaxed);
        let mut hits = 0;
        for (uniform, shrink) in [(Some(largest), 1.0), (None, 1.0), (Some(largest), 1.05)] {
            f.uniform_majorant = uniform;
            f.inv_cell = inv_cell.map(|x| x * shrink);
            for trial in 0..400 {
                let n = 1 + trial % (FLIGHT_LANES + 8); // 17 to 24: two packets
                let rays: Vec<RaySegment> = (0..n)
                    .map(|k| {
                        let o = match k % 4 {
                            0 => [lcg(&mut s), lcg(&mut s), lcg(&mut s)],
                            1 => [3.0 * lcg(&mut s) - 1.0, 3.0 * lcg(&mut s) - 1.0, -1.0],
                            2 => [0.0, lcg(&mut s), lcg(&mut s)], // on a face
                            _ => [0.5, 0.5, 0.5],
                        };
                        let d = if k % 5 == 4 {
                            [0.0, 0.0, 1.0]
                        } else {
                            let v = [0; 3].map(|_| 2.0 * lcg(&mut s) - 1.0);
                            let l = vec3::dot(v, v).sqrt().max(1e-3);
                            v.map(|x| x / l)
                        };
                        RaySegment::new(o, d, 0.0, [0.3, 1.0, 10.0][k % 3])
                    })
                    .collect();
                let keys: Vec<u64> = (0..n)
                    .map(|_| (lcg(&mut s) * 2f64.powi(62)) as u64)
                    .collect();
                let mut forced = vec![None; n];
                for a in (0..n).step_by(FLIGHT_LANES) {
                    let b = (a + FLIGHT_LANES).min(n);
                    f.sample_packet_flights_with(&rays[a..b], &keys[a..b], &mut forced[a..b], true);
                }
                let mut as_run = vec![None; n];
                f.sample_free_flights(&rays, &keys, &mut as_run);
                for i in 0..n {
                    let mut k = 0u64;
                    let mut next = || {
                        k += 1;
                        stream_bits(keys[i], 1 + k)
                    };
                    // A packet of one ray (the last of 17) flies it alone, libm's way.
                    let packet = n - i / FLIGHT_LANES * FLIGHT_LANES;
                    let lockstep = packet > 1 && f.uniform_majorant.is_some();
                    let alone = if lockstep {
                        f.free_flight_by::<true>(&rays[i], &mut next)
                    } else {
                        f.sample_free_flight(&rays[i], &mut next)
                    };
                    assert_eq!(forced[i], alone, "ray {i} of {n}: {:?}", rays[i]);
                    if f.flies_in_lockstep() || !lockstep {
                        assert_eq!(as_run[i], alone, "ray {i} of {n}: {:?}", rays[i]);
                    }
                    hits += alone.is_some() as usize;
                }
            }
        }
        assert!(hits > 500, "{hits}"); // both outcomes exercised
        let continued = CONTINUED.load(Ordering::Relaxed) - continued_before;
        assert!(continued > 20, "{continued}"); // and the continuation one ray at a time
    }

    /// The exponential's logarithm against libm's over (0, 1], the ends included.
    #[test]
    fn ln_unit_matches_libm() {
        let mut s = 3u64;
        let mut xs: Vec<f64> = (0..100_000)
            .map(|_| lcg(&mut s))
            .filter(|&x| x > 0.0)
            .collect();
        xs.extend([
            1.0,
            0.5,
            std::f64::consts::FRAC_1_SQRT_2,
            1.0 - f64::EPSILON,
            1.16e-10,
            0.5 / 4294967296.0,
        ]);
        for x in xs {
            let (a, b) = (ln_unit(x), x.ln());
            assert!(
                (a - b).abs() <= 1e-13 * b.abs().max(1e-300) + 1e-300,
                "{x}: {a} vs {b}"
            );
        }
    }

    /// Delta tracking against the majorant blocks samples the same free-flight distribution as the
    /// cell-by-cell walk: P(t_hit < t) = 1 − exp(−τ(0, t)) on a cloud whose density rises steeply
    /// along the ray (z³: majorants far above most cells' σ_t), along and across the gradient, with
    /// rays starting inside and outside the box.
    #[test]
    fn delta_tracking_samples_the_exact_free_flight() {
        let mut s = 11u64;
        let n = 100_000;
        let pos: Vec<[f64; 3]> = random_points(&mut s, n)
            .into_iter()
            .map(|p| [p[0], p[1], p[2].cbrt()])
            .collect();
        let reach = vec![0.01; n];
        let w = vec![3e-5; n];
        let ids: Vec<u32> = (0..n as u32).collect();
        let mut f = ContinuousField::build(&pos, &|i| reach[i], &|i| w[i], Some(&ids), None);
        // Both ways: the blocks' majorants, and the whole field's (which this gradient's field would
        // not choose, but is as exact).
        let largest = f.majorant.iter().fold(0.0f64, |x, &m| x.max(m as f64));
        for uniform in [None, Some(largest)] {
            f.uniform_majorant = uniform;
            delta_tracking_matches_exact(&f, &mut s);
        }
        // A cloud of even density takes the whole field's majorant.
        let even = ContinuousField::build(
            &random_points(&mut s, 20_000),
            &|_| 0.01,
            &|_| 3e-5,
            None,
            None,
        );
        assert!(even.uniform_majorant.is_some());
        delta_tracking_matches_exact(&even, &mut s);
        // All particles in one corner block of a large box: blocks.
        let mut corner = random_points(&mut s, 20_000);
        corner.iter_mut().for_each(|p| *p = p.map(|x| 0.05 * x));
        corner.push([1.0; 3]);
        let crowded = ContinuousField::build(&corner, &|_| 0.01, &|_| 3e-5, None, None);
        assert!(crowded.uniform_majorant.is_none());
    }

    /// [`ContinuousField::sample_free_flight`]'s distribution against the exact optical depth along
    /// four rays.
    fn delta_tracking_matches_exact(f: &ContinuousField, s: &mut u64) {
        let rays = [
            RaySegment::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], 0.0, 3.0),
            RaySegment::new([0.3, 0.7, 0.2], [0.0, 0.0, 1.0], 0.0, 3.0),
            RaySegment::new([-0.5, 0.4, 0.9], [0.8, 0.0, -0.6], 0.0, 4.0),
            RaySegment::new([0.5, 0.5, 2.0], [0.0, 0.6, -0.8], 0.0, 5.0),
        ];
        for ray in rays {
            let trials = 40_000;
            let mut times = Vec::with_capacity(trials);
            for _ in 0..trials {
                let mut seed = (lcg(s) * 2f64.powi(52)) as u64;
                let hit = f.sample_free_flight(&ray, || {
                    seed = seed.wrapping_add(crate::rng::GOLDEN_GAMMA);
                    crate::rng::splitmix64_finalise(seed)
                });
                if let Some(h) = hit {
                    assert!(f.sigma[h.cell] > 0.0 && h.t >= ray.t0 && h.t <= ray.t1);
                    times.push(h.t);
                }
            }
            for q in [0.2, 0.4, 0.6, 0.8, 1.0] {
                let t = ray.t0 + q * (ray.t1 - ray.t0);
                let expect = 1.0 - (-f.optical_depth(&ray.between(ray.t0, t))).exp();
                let got = times.iter().filter(|&&x| x < t).count() as f64 / trials as f64;
                let se = (expect * (1.0 - expect) / trials as f64).sqrt().max(1e-4);
                assert!(
                    (got - expect).abs() < 5.0 * se,
                    "t = {t}: {got} vs {expect}"
                );
            }
        }
    }

    /// The cells' shot noise lets little light through: over rays through a uniform random cloud
    /// (optical depth ~3 across), the mean transmittance is e^{−mean τ} within 1 % (cells of eight
    /// particles, before issue 24.3: 2 % more here, Jensen's inequality; 5.8 % in a 10 cm cloud of 10^7
    /// grains at τ 4.5, BENCHMARKS.md).
    #[test]
    fn cells_add_no_transmittance() {
        let mut s = 21u64;
        let n = 200_000;
        let pos = random_points(&mut s, n);
        let w = vec![3.0 / n as f64; n]; // σ_t = 3 per unit length in the unit cube
        let f = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, None);
        let (mut tau, mut tr) = (0.0, 0.0);
        let rays = 4000;
        for _ in 0..rays {
            let o = [0.02 + 0.96 * lcg(&mut s), 0.02 + 0.96 * lcg(&mut s), -1.0];
            let t = f.optical_depth(&RaySegment::new(o, [0.0, 0.0, 1.0], 0.0, 3.0));
            tau += t / rays as f64;
            tr += (-t).exp() / rays as f64;
        }
        assert!((tau - 3.0).abs() < 0.1, "{tau}");
        assert!(
            (tr / (-tau).exp() - 1.0).abs() < 0.01,
            "{tr} vs {}",
            (-tau).exp()
        );
    }

    /// Sparse grains stay discrete, dense small-τ ones become continuous; an infinite threshold keeps all.
    #[test]
    fn resolvable_classes() {
        let n = 20_000;
        let pos = random_points(&mut 9, n);
        // Half the particles with R = 0.05 (many per cylinder: 1e4 π 0.05² ≈ 79), half with R = 0.002 (0.13).
        let reach: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 0.05 } else { 0.002 })
            .collect();
        let w: Vec<f64> = reach.iter().map(|r| PI * r * r * 1e-3).collect();
        let (keep, footprint) = resolvable(&pos, &|i| reach[i], &|i| w[i], 16.0);
        assert!((0..n).all(|i| keep[i] == (i % 2 == 1)));
        assert!(footprint.is_some());
        assert!(resolvable(&pos, &|i| reach[i], &|i| w[i], f64::INFINITY)
            .0
            .iter()
            .all(|&k| k));
        // Optically thick: the mean free path limits the cylinder (σ_t = 1e4·π·0.05²·0.5 ≈ 39 per unit).
        let w_thick: Vec<f64> = reach.iter().map(|r| PI * r * r * 0.5).collect();
        let keep = resolvable(&pos, &|i| reach[i], &|i| w_thick[i], 16.0).0;
        assert!(keep.iter().all(|&k| k));
    }
    /// A field of few classes picks from its table of each cell's distinct classes (`picking_by` each
    /// class alone) with the same probabilities as from the list of its particles; one of many classes
    /// keeps the list alone, unless they fall in few groups.
    #[test]
    fn picks_of_distinct_classes_match_the_list() {
        let mut s = 17u64;
        let n = 20_000;
        let pos = random_points(&mut s, n);
        let w: Vec<f64> = (0..n).map(|_| 1e-5 * (0.2 + lcg(&mut s))).collect();
        for classes_count in [1u32, 3, 5000] {
            let classes: Vec<u32> = (0..n)
                .map(|_| (lcg(&mut s) * classes_count as f64) as u32)
                .collect();
            let mut f = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, Some(&classes))
                .picking_by(|k| k);
            assert_eq!(f.picks.is_some(), classes_count <= 16, "{classes_count}");
            let Some(table) = f.picks.take() else {
                continue;
            };
            let cells = f.start.len() - 1;
            for cell in (0..cells).step_by(7) {
                let (mut by_list, mut by_table) = (vec![0u32; 0], vec![0u32; 0]);
                let steps = 65_535 * 2;
                f.picks = None;
                for j in 0..steps {
                    by_list.extend(f.pick(cell, (j as f64 + 0.5) / steps as f64));
                }
                f.picks = Some(table.clone());
                for j in 0..steps {
                    by_table.extend(f.pick(cell, (j as f64 + 0.5) / steps as f64));
                }
                by_list.sort_unstable();
                by_table.sort_unstable();
                assert_eq!(by_list, by_table, "cell {cell}");
                f.picks = None;
            }
        }
        // Many classes in four groups: the groups are picked as the list picks them, each by a class
        // of its own.
        let classes: Vec<u32> = (0..n).map(|_| (lcg(&mut s) * 5000.0) as u32).collect();
        let group = |k: u32| (k & 0xFFFF) % 4;
        let f = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, Some(&classes));
        let f = f.picking_by(|k| k);
        assert!(f.picks.is_none());
        let mut f = f.picking_by(group);
        let table = f.picks.take().expect("four groups");
        for cell in (0..f.start.len() - 1).step_by(7) {
            let steps = 65_535 * 2;
            let mut by_list: Vec<u32> = (0..steps)
                .filter_map(|j| f.pick(cell, (j as f64 + 0.5) / steps as f64))
                .map(group)
                .collect();
            f.picks = Some(table.clone());
            let mut by_table: Vec<u32> = (0..steps)
                .filter_map(|j| f.pick(cell, (j as f64 + 0.5) / steps as f64))
                .map(group)
                .collect();
            f.picks = None;
            by_list.sort_unstable();
            by_table.sort_unstable();
            assert_eq!(by_list, by_table, "cell {cell}");
        }
        // Without its list (the grains' equivalent): the same picks, the table's classes as each
        // cell's members, four bytes fewer per particle; a field without a table keeps its list.
        f.picks = Some(table);
        let picks = |f: &ContinuousField| -> Vec<Option<u32>> {
            (0..f.start.len() - 1)
                .flat_map(|c| (0..100).map(move |j| (c, (j as f64 + 0.5) / 100.0)))
                .map(|(c, u)| f.pick(c, u))
                .collect()
        };
        let (before, bytes) = (picks(&f), f.bytes());
        let members: Vec<Vec<u32>> = (0..f.start.len() - 1)
            .map(|c| f.members(c).collect())
            .collect();
        let f = f.forget_members();
        assert_eq!(picks(&f), before);
        assert_eq!(f.bytes() + 4 * n, bytes);
        assert_eq!(f.len(), n);
        for (c, m) in members.iter().enumerate() {
            let kept: Vec<u32> = f.members(c).collect();
            assert!(!kept.is_empty() || m.is_empty());
            assert!(kept.iter().all(|k| m.contains(k)), "cell {c}");
        }
        let untabled = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, Some(&classes));
        let bytes = untabled.bytes();
        assert_eq!(untabled.forget_members().bytes(), bytes);
    }
}
