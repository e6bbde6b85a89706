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
//! The build runs on every core (issue 43): the counting sorts count per thread and scatter side by
//! side, each cell's sort by radius, the class codes and the slot blocks go chunk by chunk. It makes
//! the same grid, bit for bit, on any number of threads (`tests::parallel_builds_equal_one_thread`,
//! and `build::tests` against the one-thread loops it replaced).
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
//!
//! ## Files
//! * `settings`: the grid's settings, the cells' size, the size classes and the checks of its inputs.
//! * `slots`: what a cell's slots hold (spheres, quantised slots) and their single-precision pre-test.
//! * `subgrid`: one size class's grid ([`SubGrid`]) and its build.
//! * `rows`: which cells a traversal step tests.
//! * `walk`: one class's traversal, a batch of DDA steps at a time.
//! * `flight`: the walk over every class in t order, and free flights along it.
//! * `beam`: rays that travel together, walked as one beam.
//! * `flat`: the grains as flat arrays in the centre-cell layout, for a walk written outside the core
//!   (issue 46's Dr.Jit kernels).

mod beam;
mod build;
mod flat;
mod flight;
mod rows;
mod settings;
mod slots;
mod subgrid;
mod walk;

pub use beam::BEAM_RAYS;
pub(crate) use build::counting_sort_by;
pub use flat::{FlatClass, FlatGrid};
pub use settings::{
    bounding_box, check_cells_per_particle, check_cross_sections, check_particles, GridSettings,
    DEFAULT_CELLS_PER_PARTICLE, FREE_PATHS_PER_CELL, MAX_CELLS,
};
pub(crate) use settings::{first_where, size_class, CELLS_DRIVER, SIZE_CLASSES};
pub use subgrid::SubGrid;
// The crate's paths for these (outside this folder only tests name them today).
#[allow(unused_imports)]
pub(crate) use {slots::ball_contribution, walk::Cursor};

use crate::error::OpticsError;
#[cfg(any(test, feature = "oracles"))]
use crate::space::ray::RaySegment;
use rayon::prelude::*;
use settings::{mean_free_path, merge_sparse_classes, occupied_volume_by};

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
        Self::from_checked(positions, radius, c_ext, channels, settings)
    }

    /// [`ParticleGrid::build`] from inputs that passed [`check_particles`] (or are derived from such
    /// inputs, finite and positive by construction). Fails only where the memory of its cells is not
    /// there ([`OpticsError::OutOfMemory`]).
    pub(crate) fn from_checked(
        positions: &[[f64; 3]],
        radius: &[f64],
        c_ext: &[f64],
        channels: usize,
        settings: &GridSettings,
    ) -> Result<Self, OpticsError> {
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
    /// lists aside: four bytes a particle). Its cells' arrays are allocated fallibly
    /// ([`OpticsError::OutOfMemory`] naming `cells_per_particle`).
    pub(crate) fn from_particles(
        p: &Particles,
        settings: &GridSettings,
    ) -> Result<Self, OpticsError> {
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
        let members = build::buckets(
            n,
            SIZE_CLASSES,
            |j| size_class(reach_max, reach_of(&(p.id(j) as u32))),
            |j| p.id(j) as u32,
        );
        // Volume the centres occupy, shared by the classes as the density reference.
        let volume = occupied_volume_by(n, |j| p.positions[p.id(j)])?;
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
            )?);
        }
        Ok(ParticleGrid {
            classes,
            channels: p.channels,
            n,
        })
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
    pub(super) fn batched(mut self) -> Self {
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
mod tests;
