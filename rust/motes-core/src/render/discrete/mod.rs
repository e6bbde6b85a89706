//! The discrete medium as a renderer sees it: exact free flights to particle *sites*, the site's albedo and
//! its phase function (paper Sec. 5; issue 5). Free of Mitsuba: the Python plugin maps these batched
//! queries onto Mitsuba's medium and phase-function interfaces.
//!
//! ## Model
//! Along a ray the discrete optical depth is a staircase: particle i, passing within R_i of the ray with
//! its centre projecting at t_i, adds τ_i. A free flight is sampled exactly by walking the particles
//! in t order ([`ParticleGrid::sample_site`](crate::space::grid::ParticleGrid::sample_site)): no
//! majorant, no null collisions. The interaction happens at the site's t (the particle's projection
//! on the ray). The scattered path must not meet the particle that scattered it again (its internal
//! paths are already in its phase function), so each event that starts new rays is remembered by the
//! exact bits of its position and the particles of that event are skipped by rays starting there
//! (`EventMap`); the phase function finds the event's particles there too (or, failing that, from the
//! geometry along the incident ray).
//!
//! ## Per-particle optical depth (a documented deviation from Eq. 18)
//! The paper spreads C_t,i over the query disk, τ_i = C_t,i / (π R_i²) with R_i = r_c + r_i, so that
//! E\[τ\] = σ_t · length. That is right only while τ_i ≪ 1: a ray through the disk interacts with
//! probability 1 − e^{−τ_i}, so the disk removes π R_i² (1 − e^{−τ_i}) < C_t,i from a beam. With
//! r_c = 0 and Q_ext ≈ 2 (τ_i ≈ 2) that is 43 % of C_t,i: the medium lets 57 % of the extinction and
//! side scattering through (measured against explicit spheres, issue 9). Two changes make every
//! particle's expected extinction exact whatever r_c:
//! * τ_i = −ln(1 − x_i) with the fill x_i = C_t,i / (π R_i²): then π R_i² (1 − e^{−τ_i}) = C_t,i, so
//!   the mean transmittance of a random cloud is exactly Beer–Lambert exp(−σ_t L) and each particle
//!   scatters exactly C_s,i of a beam;
//! * a floor on the disk, R_i = max(r_c + r_i, √(C_t,i / (π x_max))) with x_max = 1 − e^{−τ_max}, so
//!   that x_i < 1 and τ_i ≤ τ_max ([`DEFAULT_TAU_MAX`]; τ_max = ∞ allows opaque disks of area C_t,i).
//!
//! The grid walks these τ_i and R_i; Eq. 24's local density keeps the true C_t,i / (4/3 π R_i³).
//!
//! ## Grains along a path (issue 25; Müller et al. 2016, Sec. 4.3 and 7.1)
//! A viewer sees a grain one by one only where a path meets it first: directly visible grains and their
//! glints. Once a path has scattered, the grains its later rays meet are seen only through the light
//! they pass on, and the continuous equivalent of the same cells (per-cell extinction Σ C_t,i / V and the
//! cell's phase mixture, `crate::render::continuous`) carries the same expected transport. So rays that
//! leave a path's `grain_depth`-th event or a later one (events remember their depth in the chain;
//! default [`DEFAULT_GRAIN_DEPTH`] = 1: every ray after the first scattering) sample that field instead
//! of walking grains, where their pixel footprint holds many grains (the rule of rays from surfaces,
//! `crate::render::footprint`): the field carries the grains' mean, not one cloud's arrangement of
//! them, and in a sparse cloud of large grains, each of whose shadows matters, a path's later rays
//! walk the grains too (a side-lit cloud of 300 glass grains: +5.6 % with the field, exact without;
//! `scripts/bench/bench_lod.py`). What changes where the field is seen is the grain texture of
//! multiply scattered light, which no pixel resolves (measured against the fully discrete render by
//! `scripts/bench/bench_dense.py`: image means within noise and per-pixel differences at noise
//! level). Rays that start at no event (a wall's shadow ray, a bounce off the floor, a camera ray,
//! also re-spawned at the medium's boundary) see the same field where the narrowest pixel footprint
//! they can carry holds many grains (`crate::render::footprint`). An infinite `continuous_count` keeps
//! the medium exact: no field is built and every ray walks the grains.
//!
//! ## Colour weights along a path (throughput-proportional channel choice)
//! The phase function is sampled from a mixture over channels, q(ω) = Σ_c π_c f_c(ω), and returns the
//! weights f_c / q. With π uniform (the channel mean) every bounce's weights average 1, but their
//! product over hundreds of bounces in a dense cloud is a multiplicative random walk: unbiased, yet so
//! heavy-tailed that a white furnace read 0.91–0.97 at practical sample counts (issue 9). Instead each
//! event carries the path's channel throughput t_c (normalised; the product of the albedos and the
//! phase weights since the path entered the chain of remembered events) and samples channel c with
//! π_c = (1 − ε) t_c + ε / C (ε = [`DEFENSIVE_MIX`]): then Σ_c t_c f_c / q stays ≈ 1, so per-channel
//! path weights stay bounded (hero-wavelength sampling, Wilkie et al. 2014, done incrementally). Any π
//! that depends only on the path's past keeps the estimator unbiased; `eval` uses the same π, so NEE's
//! MIS weights match. A path that leaves the chain (a surface, an evicted event) restarts uniform.
//!
//! ## Colour
//! The free flight uses one (grey) optical depth per particle: the mean of τ over the tabulated
//! wavelengths. Per wavelength the site has its own albedo a_c = C_s,c / C_t,c and phase function
//! f_c. Why grey: Mitsuba's medium interface applies per-channel weights at collisions but not to a
//! path that leaves the medium without one, so a channel-dependent free flight cannot be re-weighted
//! there (see `mitsuba_plugin/motes/plugins/discrete_medium.py`). A non-absorbing particle keeps
//! a_c = 1 in every channel, so energy is conserved exactly (white furnace); what is approximated is
//! the colour of the transmittance, by the spread of C_t over the channels (measured by
//! scripts/figures/grey_extinction.py, BENCHMARKS.md).
//!
//! ## Phase function of a site (Eq. 24)
//! With the site's particles j, scattering weights s_j,c = τ_j a_j,c, the phase function for
//! channel c is the mixture f_c(μ) = Σ_j s_j,c f_j,c(μ) / Σ_j s_j,c — σ_s f of the site is Q(θ) of
//! Eq. 24 for the particles it holds. Sampling picks a channel uniformly, a particle with probability
//! ∝ s_j,c, then its tabulated f (piecewise linear in μ, inverse-CDF sampling). The pdf returned is
//! the mean over channels of f_c (one-sample MIS over channels), so `sample` and `eval` agree
//! exactly and the weights f_c / pdf stay bounded.
//!
//! ## Where it lives
//! * `settings`: what a build takes besides the particles ([`MediumSettings`]) and its checks.
//! * `build`: the medium from stored particles or a procedural cloud: each particle's disk, the grid
//!   and the continuous fields.
//! * `flight`: free flights: the grains walked one by one, the continuous fields, the choice between
//!   them.
//! * `events`: the event memory (events by the bits of their position) and what a ray takes from the
//!   event it starts at.
//! * `channels`: per-channel values, wavelength brackets and the throughput-proportional channel
//!   choice.
//! * `phase`: a site's phase function (Eq. 24's mixture): evaluation and sampling.
//! * `local`: Eq. 24's local scattering at points.
//! * `batch`: the batch interface (Dr.Jit's evaluated mode).
//! * `packet` and `packet_state`: the packet interface of the native render path, one packet at a
//!   time, with its per-thread state.
//! * `counters`: statistics counters shared by render threads.

mod batch;
mod build;
mod channels;
mod counters;
mod events;
mod flight;
mod lane;
mod local;
mod mueller;
mod packet;
mod packet_state;
mod phase;
mod settings;

pub use crate::space::vec3::octahedral;
pub use build::particle_disk;
pub use mueller::{Elements, MuellerRatios};
pub use settings::{check_particles_and_settings, MediumSettings};

use crate::ensemble::phase_table::PhaseTable;
use crate::error::{require, OpticsError};
use crate::render::continuous::{ContinuousField, FlatField};
use crate::render::enclosure::Enclosure;
use crate::render::footprint::{SurfaceFootprint, View};
use crate::render::procedural::DensityCells;
use crate::render::storage::ParticleOptics;
use crate::space::cloud::{det3, invert_affine, Density};
use crate::space::dda::Bounds3;
use crate::space::grid::FlatGrid;
use crate::space::ray::RaySegment;
use batch::Pending;
use counters::ShardedCounts;
use events::EventMap;
use flight::Grains;
use rustc_hash::FxHashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};

/// Optical data of one radius bin of one species at the tabulated wavelengths.
#[derive(Clone, Debug)]
pub struct BinOptics {
    /// Single-scattering albedo C_s / C_t per tabulated wavelength.
    pub albedo: Vec<f64>,
    /// Phase function per tabulated wavelength.
    pub phase: Vec<PhaseTable>,
    /// Polarisation: F12/F11, F33/F11, F34/F11 on the nodes of each of `phase`'s tables, or empty where
    /// the bin depolarises (`mueller.rs`).
    pub mueller: Vec<MuellerRatios>,
}

/// [`DiscreteMedium::flat_tables`]: per table (bin-major, then tabulated wavelength) its nodes
/// `offset[i]..offset[i + 1]` of `mu`, `f`, `cdf` and `mueller`, and its albedo.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlatTables {
    pub mu: Vec<f64>,
    pub f: Vec<f64>,
    pub cdf: Vec<f64>,
    /// Per node: F12/F11, F33/F11, F34/F11 (0 where the bin depolarises).
    pub mueller: Vec<[f32; 3]>,
    pub offset: Vec<u32>,
    pub albedo: Vec<f64>,
}

impl BinOptics {
    /// Heap bytes of the bin's albedos and phase tables.
    pub fn bytes(&self) -> usize {
        self.albedo.capacity() * 8
            + self.phase.iter().map(PhaseTable::bytes).sum::<usize>()
            + self.mueller.iter().map(MuellerRatios::bytes).sum::<usize>()
    }
}

/// Default cap on a particle's optical depth τ_i (module docs): its disk is widened until
/// τ_i ≤ 1, i.e. a ray through it interacts with probability at most 1 − e^{−1} = 63 %.
pub const DEFAULT_TAU_MAX: f64 = 1.0;

/// Discrete grains (expected, in the footprint rule's classes) from which rays leaving a path's
/// `grain_depth`-th event see the grains' continuous equivalent whatever their footprint
/// (`flight.rs`, `event_field`).
pub const EVENT_FIELD_MIN_GRAINS: f64 = 1e5;

/// Default grain depth (`DiscreteMedium::set_grain_depth`): rays leaving a path's first scattering
/// event or a later one see the grains' continuous equivalent.
pub const DEFAULT_GRAIN_DEPTH: u32 = 1;

/// Share of uniform channel choice mixed into the throughput-proportional one (module docs): bounds a
/// bounce's weights by C / ε even for a channel whose throughput has fallen to 0.
pub const DEFENSIVE_MIX: f64 = 0.1;

/// Channels whose throughput an event can carry (RGB: 3, Mitsuba's spectral variants: 4).
pub const MAX_CHANNELS: usize = 4;

/// The discrete medium: particles in a grid with grey optical depths, and per-bin optics.
pub struct DiscreteMedium {
    /// The particles sampled one by one (None when every class is continuous).
    grid: Option<Grains>,
    /// A procedural cloud's expected particles, all and in `field` (its counts are not stored).
    expected: Option<(f64, f64)>,
    /// The size classes no pixel resolves, sampled as a continuous medium (None when there are none).
    field: Option<ContinuousField>,
    /// Each particle's disk (R_i = max(r_c + r_i, floor), τ_i = −ln(1 − x_i); module docs), C_t,i,
    /// optics bin and whether it lives in `field`, by original index, per particle or per class
    /// (`crate::render::storage`).
    optics: ParticleOptics,
    /// Particles whose disk the τ_max floor widened beyond r_c + r_i.
    widened: usize,
    /// Do a packet's rays from no event walk the grains as beams where they make one
    /// (`ParticleGrid::sample_sites_beam`)? `MOTES_BEAM=0` at build: one by one, the same sites
    /// (`crate::options`).
    beams: bool,
    bins: Vec<BinOptics>,
    /// Per bin: are its phase tables all on the same nodes (one search serves every channel)?
    shared_nodes: Vec<bool>,
    /// Tabulated wavelengths, increasing (any unit; the caller's channel wavelengths use the same).
    lambda: Vec<f64>,
    /// Projections closer than this along a ray form one site (scene units).
    coincide: f64,
    events: RwLock<EventMap>,
    /// Sites sampled by each calling thread's last `sample_sites` call, per lane, until its
    /// `commit_events` (Mitsuba's scalar variants call from several render threads at once).
    pending: Mutex<FxHashMap<std::thread::ThreadId, Vec<Pending>>>,
    seed: u64,
    calls: AtomicU64,
    /// Identifies the medium's per-thread state in the packet interface.
    id: u64,
    /// Rays and interactions of the packet interface so far (statistics).
    packet_counts: ShardedCounts,
    /// Factor on every particle's albedo (f64 bits; 1 at build), editable between renders (a look
    /// control: `set_albedo_scale`). Albedos are clamped to 1 after it.
    albedo_scale: AtomicU64,
    /// Where the renderer can place events: the particles' box grown by the largest disk (a site lies
    /// within its particles' disks). A free flight from outside it (a camera, a wall) starts at no event
    /// and skips the event lookup.
    event_box: Bounds3,
    /// The continuous equivalent of every particle, discrete classes included (None when
    /// `continuous_count` is infinite: the medium is then exact, fully discrete).
    grains_field: Option<ContinuousField>,
    /// Rays leaving the `grain_depth`-th event of a path or a later one sample `grains_field` instead
    /// of walking grains (module docs, "Grains along a path"); `u32::MAX`: never.
    grain_depth: std::sync::atomic::AtomicU32,
    /// When a ray that starts at no event (a surface, a boundary) may see `grains_field`
    /// (`crate::render::footprint`; None when the medium is exact or has no discrete class).
    footprint: Option<SurfaceFootprint>,
    /// The scene's cameras and lights, as the renderer set them (`set_view`; no camera: rays from
    /// surfaces walk the grains).
    view: RwLock<Arc<View>>,
    /// Counts `set_view` calls: the packet path keeps each thread's own reference to the view and
    /// takes the lock only when this changed (a shared lock per packet makes the threads fight over its
    /// cache line, where a packet is one ray).
    view_epoch: AtomicU64,
    /// The convex shapes that hold the medium, where the renderer vouches that a site inside one blocks
    /// a shadow ray from inside it (`set_enclosure`, `crate::render::enclosure`; empty: unknown). Read
    /// by the packet path with the view (`view_epoch`).
    enclosure: RwLock<Arc<Enclosure>>,
    /// Whether the footprint rule applies (`set_surface_footprint`).
    surface_footprint: std::sync::atomic::AtomicBool,
    /// Rays checked against the rule, and those that saw the field (statistics).
    surface_counts: ShardedCounts,
    /// Set once `insert_event` placed an event anywhere: then every free flight looks events up.
    events_anywhere: std::sync::atomic::AtomicBool,
    /// Counts changes of the optics (`set_albedo_scale`): per-thread events of an older epoch are
    /// dropped before use.
    optics_epoch: AtomicU64,
}

/// Per-lane result of [`DiscreteMedium::sample_sites`].
#[derive(Clone, Copy, Debug)]
pub struct SiteSample {
    /// Distance to the site, or None when the ray leaves [0, t_max) without interacting.
    pub t: Option<f64>,
    /// Optical depth walked before the site (or to t_max).
    pub tau_before: f64,
}

/// A lane of a phase-function sample: the event's position `p`, the incident direction `wi`
/// (pointing back along the path, Mitsuba's convention), `u1` (picks channel, particle and table)
/// and `u2` (the direction), uniform in [0, 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseSampleLane {
    pub p: [f32; 3],
    pub wi: [f32; 3],
    pub u1: f64,
    pub u2: [f64; 2],
}

/// A lane of a phase-function evaluation: the event's position `p`, the incident direction `wi`
/// (pointing back along the path) and the outgoing direction `wo`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseEvalLane {
    pub p: [f32; 3],
    pub wi: [f32; 3],
    pub wo: [f32; 3],
}

/// Lanes of one SIMD packet at most (Dr.Jit's widest LLVM vector; scalar variants use one).
pub const PACKET_LANES: usize = 16;

/// A ray of the packet interface: origin, direction, t_max.
pub type PacketRay = ([f32; 3], [f32; 3], f32);

impl DiscreteMedium {
    /// The grains' continuous equivalent (what rays past the grain depth and rays the footprint rules
    /// let through see) spread by the density the grains were drawn from, `density` over the cloud's
    /// box `cloud` mapped by `transform`, instead of by their counts in cells: each bin keeps the
    /// extinction the counts gave it. Cells of 64 grains flatten a concentrated density, and rays
    /// leaving an event in a density's tail met the extinction of its denser part: a gridvolume puff
    /// of 2.7·10⁴ grains rendered 1.8 % darker than every grain walked (z −3.5); a procedural cloud's
    /// fields, built this way, rendered it as exact (`scripts/bench/bench_dropin.py --heterogeneous`).
    /// Only for grains that still follow the density (not moved since).
    pub fn see_density(
        &mut self,
        density: &Density,
        cloud: ([f64; 3], [f64; 3]),
        transform: &[[f64; 4]; 3],
    ) -> Result<(), OpticsError> {
        let Some(counted) = &self.grains_field else {
            return Ok(());
        };
        let to_cloud = invert_affine(transform).ok_or(OpticsError::InvalidArgument {
            argument: "to_world",
            value: 0.0,
            requirement: "an invertible transform",
        })?;
        let (lo, hi) = cloud;
        let mean = density.mean(lo, hi);
        let volume = det3(transform).abs() * (0..3).map(|a| hi[a] - lo[a]).product::<f64>();
        require(
            "density",
            mean,
            mean > 0.0 && volume > 0.0 && volume.is_finite(),
            "a density whose mean over a box of finite, positive volume is > 0",
        )?;
        // Per bin: its first member (what a pick returns) and its extinction × volume.
        let mut by_bin: Vec<Option<(u32, f64)>> = Vec::new();
        counted.member_extinction(|member, ext| {
            let bin = self.optics.bin[self.optics.code(member)] as usize;
            if by_bin.len() <= bin {
                by_bin.resize(bin + 1, None);
            }
            by_bin[bin].get_or_insert((member, 0.0)).1 += ext;
        });
        let (members, weight): (Vec<u32>, Vec<f64>) = by_bin
            .into_iter()
            .flatten()
            .map(|(member, ext)| (member, ext / volume))
            .unzip();
        let cells = DensityCells::new(density, cloud, transform, to_cloud, mean);
        self.grains_field = Some(cells.field(members, &weight));
        Ok(())
    }

    /// Confine the continuous fields to the inside of the shapes that hold the medium (`inside(p)`;
    /// `ContinuousField::confined`): a medium whose grains fill those shapes. The grains themselves are
    /// unchanged.
    pub fn confine(&mut self, inside: &(dyn Fn([f64; 3]) -> bool + Sync)) {
        self.field = self.field.take().map(|f| f.confined(inside));
        self.grains_field = self.grains_field.take().map(|f| f.confined(inside));
    }

    /// Particles whose disk the τ_max floor widened beyond r_c + r_i.
    pub fn widened(&self) -> usize {
        self.widened
    }

    /// Largest optical depth of a particle's disk.
    pub fn tau_max(&self) -> f64 {
        self.optics.tau.iter().fold(0.0f32, |a, &b| a.max(b)) as f64
    }

    /// Largest inclusion radius of a particle (scene units).
    pub fn reach_max(&self) -> f64 {
        self.optics.reach.iter().fold(0.0f32, |a, &b| a.max(b)) as f64
    }

    /// Particles sampled as a continuous medium ([`crate::render::continuous`]).
    pub fn continuous_len(&self) -> usize {
        match self.expected {
            Some((_, c)) => c.round() as usize,
            None => self.field.as_ref().map_or(0, ContinuousField::len),
        }
    }

    /// Grey optical depth along a ray segment (|d| = 1) as the free flights see it: the discrete
    /// particles' staircase plus the continuous field's mean.
    pub fn optical_depth(&self, ray: &RaySegment) -> f64 {
        self.grid.as_ref().map_or(0.0, |g| g.optical_depth(ray))
            + self.field.as_ref().map_or(0.0, |f| f.optical_depth(ray))
    }

    /// The grains walked one by one (stored, not a procedural cloud's) as flat arrays
    /// ([`FlatGrid`], their grey τ_i and disks R_i as the free flights walk them; the index a grain
    /// carries is what the phase functions name it by) and each grain's optics bin: None where no
    /// grain is stored to be walked (a procedural cloud, or every class continuous). The size classes
    /// sampled as a continuous medium are not in it.
    pub fn flat_grains(&self) -> Option<Result<(FlatGrid, Vec<u32>), OpticsError>> {
        let Some(Grains::Stored(g)) = &self.grid else {
            return None;
        };
        Some(g.flat(0).map(|f| {
            let bins = f.index.iter().map(|&i| self.optics.bin(i) as u32).collect();
            (f, bins)
        }))
    }

    /// The continuous field of the size classes no pixel resolves (not the grains' equivalent that
    /// `grain_depth` and the footprint rule switch to) as flat arrays ([`FlatField`]: cells, σ_t, and per
    /// cell its optics bins, as [`Self::flat_tables`] numbers them, with their shares of the cell's
    /// extinction), for a walk written outside the core (issue 46's Dr.Jit kernel); None where there is
    /// no such field (`continuous_count` infinite, or every class discrete).
    pub fn flat_field(&self) -> Option<FlatField> {
        let f = self.field.as_ref()?;
        Some(f.flat(|member| self.optics.bin(member) as u32))
    }

    /// A procedural cloud's discrete grains (None: stored particles, or every class continuous).
    pub fn procedural_grains(&self) -> Option<&crate::render::procedural::ProceduralGrains> {
        match &self.grid {
            Some(Grains::Procedural(p)) => Some(p),
            _ => None,
        }
    }

    /// The optics bin of a procedural cloud's class `code`.
    pub fn class_bin(&self, code: u32) -> usize {
        self.optics
            .bin(crate::render::continuous::CLASS_FLAG | code)
    }

    /// Particles (a procedural cloud's expected count).
    pub fn len(&self) -> usize {
        match self.expected {
            Some((n, _)) => n.round() as usize,
            None => self.optics.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Is this a procedural cloud (`crate::render::procedural`)?
    pub fn is_procedural(&self) -> bool {
        matches!(self.grid, Some(Grains::Procedural(_))) || self.expected.is_some()
    }

    /// A procedural cloud's bricks built so far (0 for stored particles).
    pub fn bricks_built(&self) -> u64 {
        match &self.grid {
            Some(Grains::Procedural(p)) => p.bricks_built(),
            _ => 0,
        }
    }

    pub fn bytes(&self) -> usize {
        self.grid.as_ref().map_or(0, Grains::bytes)
            + self.field.as_ref().map_or(0, ContinuousField::bytes)
            + self.grains_field.as_ref().map_or(0, ContinuousField::bytes)
            + self.optics.bytes()
            + self.table_bytes()
    }

    /// Heap bytes of the optics bins' tables (albedos and phase functions): fixed whatever the count.
    pub fn table_bytes(&self) -> usize {
        self.bins.iter().map(BinOptics::bytes).sum()
    }

    /// The bins' optics as flat arrays for a walk written outside the core (issue 46's Dr.Jit kernel):
    /// per bin and tabulated wavelength (table `b · λ count + k`), its albedo and its phase table's nodes
    /// as evaluation and sampling read them ([`crate::ensemble::phase_table::PhaseTable::nodes`]).
    pub fn flat_tables(&self) -> FlatTables {
        let mut t = FlatTables {
            offset: vec![0],
            ..FlatTables::default()
        };
        for b in &self.bins {
            for (k, (table, &albedo)) in b.phase.iter().zip(&b.albedo).enumerate() {
                let (mu, f, cdf) = table.nodes();
                t.mu.extend_from_slice(mu);
                t.f.extend_from_slice(f);
                t.cdf.extend_from_slice(cdf);
                // A bin without ratios depolarises: its ratios are 0 (`mueller.rs`).
                match b.mueller.get(k).filter(|r| r.len() == mu.len()) {
                    Some(r) => t.mueller.extend_from_slice(r.nodes()),
                    None => t.mueller.extend(std::iter::repeat_n([0.0f32; 3], mu.len())),
                }
                t.offset.push(t.mu.len() as u32);
                t.albedo.push(albedo);
            }
        }
        t
    }

    pub fn lambda(&self) -> &[f64] {
        &self.lambda
    }

    /// The factor on every particle's albedo (1 unless set).
    pub fn albedo_scale(&self) -> f64 {
        f64::from_bits(self.albedo_scale.load(Ordering::Relaxed))
    }

    /// Scale every particle's albedo by `scale` from the next query on (between renders; a render in
    /// flight may see either value). `scale` × the largest albedo must stay within [0, 1]. Events
    /// remembered so far (they carry the old albedo in their throughputs) are forgotten.
    pub fn set_albedo_scale(&self, scale: f64) -> Result<(), OpticsError> {
        let a_max = self
            .bins
            .iter()
            .flat_map(|b| b.albedo.iter().copied())
            .fold(0.0, f64::max);
        require(
            "albedo_scale",
            scale,
            scale.is_finite() && scale >= 0.0 && scale * a_max <= 1.0 + 1e-12,
            "finite, >= 0 and at most 1 / (the largest particle albedo)",
        )?;
        if scale != self.albedo_scale() {
            self.albedo_scale.store(scale.to_bits(), Ordering::Relaxed);
            // Remembered events carry throughputs of the old albedo.
            self.optics_epoch.fetch_add(1, Ordering::Relaxed);
            self.events.write().unwrap().clear();
        }
        Ok(())
    }

    /// Rays that started at no event and were checked against the surface-ray rule, and those of them
    /// that saw the grains' continuous equivalent (statistics; `crate::render::footprint`).
    pub fn surface_counts(&self) -> (u64, u64) {
        self.surface_counts.totals()
    }

    /// The cameras whose pixel footprints rays from surfaces carry, and the lights their shadow rays
    /// converge to (`crate::render::footprint`); no camera makes every ray from a surface walk the
    /// grains. Set by the renderer from its scene.
    pub fn set_view(&self, view: View) {
        *self.view.write().unwrap() = Arc::new(view);
        self.view_epoch.fetch_add(1, Ordering::Release);
    }

    /// The convex regions that hold the medium and inside which no surface lets a shadow ray through
    /// (`crate::render::enclosure`): the packet path then answers a phase evaluation towards the
    /// direction of the lane's last free flight, from its origin, with zero where that flight ended at a
    /// site inside the region that holds its origin (the ray is blocked, and Mitsuba's `volpath` and
    /// `volpathmis` multiply that evaluation by the light they then do not see). Set by the renderer
    /// only for those integrators; empty (the default): every evaluation is computed.
    pub fn set_enclosure(&self, enclosure: Enclosure) {
        *self.enclosure.write().unwrap() = Arc::new(enclosure);
        self.view_epoch.fetch_add(1, Ordering::Release);
    }

    /// What [`Self::set_enclosure`] set.
    pub fn enclosure(&self) -> Enclosure {
        Enclosure::clone(&self.enclosure.read().unwrap())
    }

    /// What [`Self::set_view`] set.
    pub fn view(&self) -> View {
        View::clone(&self.view.read().unwrap())
    }

    /// Whether rays from surfaces may see the grains' continuous equivalent where their pixel footprint
    /// holds many grains (`crate::render::footprint`; on by default, and moot when the medium is
    /// exact: infinite `continuous_count`).
    pub fn set_surface_footprint(&self, on: bool) {
        self.surface_footprint.store(on, Ordering::Relaxed);
    }

    /// See [`Self::set_surface_footprint`].
    pub fn surface_footprint(&self) -> bool {
        self.surface_footprint.load(Ordering::Relaxed)
    }

    /// Rays leaving the `depth`-th scattering event of a path or a later one see the continuous
    /// equivalent of the grains (the same mean extinction and local phase mixture per cell) instead of
    /// walking them one by one: 1 sees grains only until a path first scatters (Müller et al. 2016),
    /// `u32::MAX` always (exact). Ignored when every class is kept discrete (`continuous_count`
    /// infinite): then the medium is exact whatever this says.
    pub fn set_grain_depth(&self, depth: u32) -> Result<(), OpticsError> {
        require("grain_depth", depth as f64, depth >= 1, ">= 1")?;
        self.grain_depth.store(depth, Ordering::Relaxed);
        Ok(())
    }

    /// See [`Self::set_grain_depth`].
    pub fn grain_depth(&self) -> u32 {
        self.grain_depth.load(Ordering::Relaxed)
    }

    /// Rays and interactions (sites found: scattering events and blocked shadow rays) of the packet
    /// interface so far.
    pub fn packet_counts(&self) -> (u64, u64) {
        self.packet_counts.totals()
    }
}

#[cfg(test)]
mod tests;
