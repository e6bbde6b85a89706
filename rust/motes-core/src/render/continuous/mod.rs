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
//! resolves when N is large. [`resolvable`] decides which classes keep it. The cells fill only the
//! particles' box, so each particle counts there with the share of its disk (radius R across a ray) that
//! lies inside the box, 1 − Σ_faces (1 − d / R)₊² / 2 over random directions (`build::inside_share`):
//! the rest of the disk falls on rays outside the box, which the grains never reach (issue 43).
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
//! logarithm is `ln_unit`, which vectorises, where one ray at a time uses libm's single-precision
//! one (faster there): the two modes draw different exponentials of one distribution, so an image
//! differs by its noise between CPUs with and without AVX-512 (`MOTES_SIMD=avx2` gives the latter's).
//!
//! ## Files
//! * `build`: a field's cells, σ_t per cell, pick tables and majorants, from particles or a density.
//! * `flight`: free flights one ray at a time, exact or by delta tracking.
//! * `lockstep`: a packet's free flights stepped together in SIMD lanes.
//! * `export`: the field as flat arrays for a walk outside the core (the Dr.Jit kernel).

mod build;
mod export;
mod flight;
mod lockstep;

pub use export::FlatField;
pub use lockstep::FLIGHT_LANES;

use crate::render::footprint::{ClassMoments, SurfaceFootprint};
use crate::space::dda::{Bounds3, GridFrame};
use crate::space::grid::{bounding_box, size_class};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Default number of a class's particles a query cylinder must hold (over one mean free path, or
/// across the medium if that is shorter) for the class to be rendered as a continuous medium:
/// the lost grain texture, of relative size 1/√N, is then at most 1/√16 = 25 % per pixel, below the
/// Monte Carlo noise of a render at tens of spp (measured: `scripts/figures/continuous_switch.py`).
pub const DEFAULT_CONTINUOUS_COUNT: f64 = 16.0;

/// The largest share of a class's extinction that its disks may lose over the particles' box
/// ([`edge_share`]) for the class to be continuous. Near a face, a grain's disk reaches past the
/// box, where rays outside the medium miss it; how much it loses depends on the ray's direction,
/// which a field of one σ_t per cell cannot carry. Large disks (a query radius that is a sizeable
/// part of the cloud) therefore stay discrete: 300 grains of 0.2–0.45 mm in a 20 mm cube with a
/// 3 mm query radius (edge share 14 %) rendered +9.8 % brighter continuous than discrete
/// (`scripts/bench/bench_lod.py --scenes sidelit3mm`).
pub const CONTINUOUS_MAX_EDGE_SHARE: f64 = 0.02;

/// The share of a class's extinction that rays outside the particles' box miss, averaged over
/// the three axis directions, for disks of radius `reach` in a box of extents `e`: along axis z,
/// the two faces normal to x remove ∫ over the half disk of its depth x dA = (2/3) R³ per unit
/// length of face each, out of π R² per grain, i.e. (4 / 3π) R / e_x; so (8 / 9π) R Σ_a 1/e_a.
pub fn edge_share(reach: f64, e: [f64; 3]) -> f64 {
    8.0 / (9.0 * PI) * reach * e.iter().map(|&x| 1.0 / x.max(1e-300)).sum::<f64>()
}

/// Is a class continuous: do rays cross at least `min_count` of its disks (`count_per_ray`), and
/// are its disks (root-mean-square radius `reach`) small enough against the box of extents `e`
/// that the field loses nothing at its faces ([`CONTINUOUS_MAX_EDGE_SHARE`])?
pub fn class_is_continuous(count_per_ray: f64, reach: f64, e: [f64; 3], min_count: f64) -> bool {
    min_count.is_finite()
        && count_per_ray >= min_count
        && edge_share(reach, e) <= CONTINUOUS_MAX_EDGE_SHARE
}

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
        .map(|s| {
            let rms_reach = (s[2] / s[0].max(1.0)).sqrt();
            !class_is_continuous(PI * s[2] * length / volume, rms_reach, e, min_count)
        })
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
    /// cache miss instead of two (the misses are most of a pick's time).
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
            | Members::Classes(v) => v.capacity() * 4,
            Members::Counted(_) => 0,
        }
    }
}

/// The continuous part of a discrete medium (module docs).
pub struct ContinuousField {
    /// The cells: the centres' box, cell edges and cells per axis.
    frame: GridFrame,
    /// 1 / the cell edges (a tentative collision's cell by multiplication: three divisions cost more).
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
    /// an optics bin's radius levels), one class of each group once with the running share of the
    /// cell's extinction (packed as in [`Members::Classes`]) and each cell's first entry: what a pick
    /// reads instead of `members`, small enough to stay in cache where `members` costs a cache miss
    /// per pick. Picks each class (group) with the same probability as `members` does.
    picks: Option<(Vec<u32>, Vec<u32>)>,
    /// Blocks of [`MAJORANT_BLOCK`](build::MAJORANT_BLOCK)³ cells (the last ones along an axis may reach past the field's
    /// box, where σ_t = 0) and the largest σ_t of each.
    block_frame: GridFrame,
    majorant: Vec<f32>,
    /// The largest σ_t of all cells, where it is close to the blocks' mean (a cloud of even density):
    /// free flights then use it everywhere instead of walking the blocks ([`UNIFORM_MAJORANT_RATIO`](build::UNIFORM_MAJORANT_RATIO)).
    uniform_majorant: Option<f64>,
}

impl ContinuousField {
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

    /// Each member's share of the field's extinction, σ_t × cell volume × its share of its cell, as a
    /// pick returns members (`f(member, extinction × volume)`, once per cell it is in).
    pub fn member_extinction(&self, mut f: impl FnMut(u32, f64)) {
        let volume = self.cell_volume();
        for c in 0..self.sigma.len() {
            let total = self.sigma[c] as f64 * volume;
            self.cell_shares(c, &mut |member, units| {
                f(member, total * units / u16::MAX as f64)
            });
        }
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
        (self.sigma.capacity() + self.start.capacity() + self.majorant.capacity()) * 4
            + self.members.bytes()
            + self.cdf.capacity() * 2
            + self
                .picks
                .as_ref()
                .map_or(0, |(a, b)| (a.capacity() + b.capacity()) * 4)
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

#[cfg(test)]
mod tests;
