//! The discrete medium from its particles: from stored particles ([`DiscreteMedium::build`]) or a
//! procedural cloud ([`DiscreteMedium::procedural`]). Each particle's disk (module docs of
//! `crate::render::discrete`, "Per-particle optical depth"), the grid of the grains walked one by one
//! and the continuous fields of the others and of all of them.

use super::counters::ShardedCounts;
use super::events::{EventMap, EVENTS_PER_GENERATION};
use super::flight::Grains;
use super::settings::{
    check_build_inputs, check_procedural_inputs, MediumSettings, ParticleInputs,
};
use super::{BinOptics, DiscreteMedium, DEFAULT_GRAIN_DEPTH};
use crate::error::OpticsError;
use crate::options::BuildSwitches;
use crate::render::continuous::{resolvable, Column, ContinuousField, CLASS_FLAG};
use crate::render::enclosure::Enclosure;
use crate::render::footprint::{ClassMoments, SurfaceFootprint, View};
use crate::render::procedural::{build_parts, ProceduralParts, ProceduralSpec};
use crate::render::storage::{classes, Classes, ParticleOptics, Storage};
use crate::space::dda::Bounds3;
use crate::space::grid::{
    bounding_box, size_class, GridSettings, ParticleGrid, Particles, SIZE_CLASSES,
};
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};

/// Optical depth of a disk whose fill reaches 1 (opaque; e^{−30} ≈ 1e-13).
pub(super) const TAU_OPAQUE: f64 = 30.0;

/// What a medium's free flights walk and look up, as its builds make it ([`DiscreteMedium`]'s fields).
struct Walkable {
    grid: Option<Grains>,
    expected: Option<(f64, f64)>,
    field: Option<ContinuousField>,
    grains_field: Option<ContinuousField>,
    footprint: Option<SurfaceFootprint>,
    optics: ParticleOptics,
    widened: usize,
    coincide: f64,
    event_box: Bounds3,
}

/// A stored medium's particles as the builders of its walk read them, by original index: the disk's
/// reach R, the radius and cross section the grid is handed for it, and C_t,i.
struct WalkColumns<'a> {
    reach: Column<'a>,
    grid_radius: Column<'a>,
    grid_c: Column<'a>,
    c_ext: Column<'a>,
}

/// The structures a free flight walks: the grid of the particles whose grains a pixel can resolve and
/// the continuous field of the others (`continuous_count`, crate::render::continuous), and which is which.
/// With `classes` (compact storage) the grid names its particles by position
/// ([`ParticleGrid::positional`]), and the last item is their original indices in that order.
/// `centre_cells`: the `MOTES_CENTRE_CELLS` switch ([`centre_cells_for`]).
#[allow(clippy::type_complexity)]
fn build_walk(
    positions: &[[f64; 3]],
    columns: &WalkColumns,
    settings: &GridSettings,
    continuous_count: f64,
    classes: Option<&[u32]>,
    centre_cells: Option<bool>,
) -> Result<
    (
        Option<ParticleGrid>,
        Option<ContinuousField>,
        Vec<bool>,
        Option<SurfaceFootprint>,
        Option<Vec<u32>>,
    ),
    OpticsError,
> {
    let WalkColumns {
        reach,
        grid_radius,
        grid_c,
        c_ext,
    } = *columns;
    let n = positions.len();
    let (keep, footprint) = resolvable(positions, reach, c_ext, continuous_count);
    let (discrete_ids, field_ids): (Vec<u32>, Vec<u32>) =
        (0..n as u32).partition(|&i| keep[i as usize]);
    // The grid reads its particles through the columns and reports their original indices (no
    // copies: a subset of 10^8 particles would be 40 bytes each).
    let centred = settings.centre_cells && centre_cells_for(discrete_ids.len(), centre_cells);
    let settings = &settings.centred(centred);
    let grid = (!discrete_ids.is_empty())
        .then(|| {
            ParticleGrid::from_particles(
                &Particles {
                    positions,
                    ids: (!field_ids.is_empty()).then_some(&discrete_ids[..]),
                    radius: grid_radius,
                    c_ext: &|i, _| grid_c(i),
                    channels: 1,
                },
                settings,
            )
        })
        .transpose()?;
    // Compact storage: particles named by position (no index kept).
    let (grid, order) = match (grid, classes) {
        (Some(g), Some(_)) => {
            let (g, order) = g.positional();
            (Some(g), Some(order))
        }
        (g, Some(_)) => (g, Some(Vec::new())),
        (g, None) => (g, None),
    };
    // The medium keeps its grid for rendering: what the slots duplicate is dropped.
    let grid = grid.map(|mut g| {
        g.release_stored();
        g
    });
    // Weighted by C_t,i, the extinction each disk removes from a beam (π R² (1 − e^{−τ_i})), not by
    // τ_i π R²: the mean transmittance of the discrete rays is e^{−n C L} (`discrete` docs). The field
    // selects its particles from the full columns (every particle continuous: all of them).
    let field = (!field_ids.is_empty())
        .then(|| {
            let ids = (!discrete_ids.is_empty()).then_some(&field_ids[..]);
            ContinuousField::build(positions, reach, c_ext, ids, classes)
        })
        .transpose()?;
    Ok((grid, field, keep, footprint, order))
}

/// The surface-ray rule (`crate::render::footprint`) of a procedural cloud: its discrete classes'
/// expected counts over the box's bounding box, grouped into the size classes that chose them.
fn procedural_footprint(
    count: f64,
    parts: &ProceduralParts,
    disks: &[(f64, f64)],
    min_count: f64,
) -> Option<SurfaceFootprint> {
    let (lo, hi) = bounding_box(&parts.corners);
    let volume: f64 = (0..3).map(|a| (hi[a] - lo[a]).max(0.0)).product();
    let reach_max = disks.iter().map(|d| d.0).fold(0.0, f64::max);
    let mut sums = [[0.0f64; 4]; SIZE_CLASSES];
    let mut sigma = 0.0;
    for ((c, d), &discrete) in parts.classes.iter().zip(disks).zip(&parts.discrete) {
        let w = count * c.p;
        sigma += w * c.c_ext;
        if discrete && w > 0.0 {
            let s = &mut sums[size_class(reach_max, d.0)];
            s[0] += w;
            s[1] += w * d.0;
            s[2] += w * d.0 * d.0;
            s[3] += w * c.c_ext;
        }
    }
    let classes = sums
        .iter()
        .map(|s| ClassMoments::from_sums(*s, volume))
        .collect();
    // resolvable's cylinder length: the box's mean chord 4V/S, or a mean free path if shorter.
    let e = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(0.0));
    let surface = 2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]);
    let chord = if surface > 0.0 {
        4.0 * volume / surface
    } else {
        0.0
    };
    let length = if sigma > 0.0 {
        chord.min(volume / sigma)
    } else {
        chord
    };
    SurfaceFootprint::new(classes, Bounds3 { lo, hi }, length, min_count)
}

/// Inclusion radius and optical depth of one particle's disk (`discrete` docs): the disk r_c + r is
/// widened until its fill x = C / (π R²) is at most 1 − e^{−τ_max}, and τ = −ln(1 − x).
pub fn particle_disk(radius: f64, c_ext: f64, query_radius: f64, tau_max: f64) -> (f64, f64) {
    let fill_max = -(-tau_max).exp_m1(); // 1 − e^{−τ_max}, 1 for τ_max = ∞
    let floor = (c_ext / (PI * fill_max)).sqrt();
    let reach = (query_radius + radius).max(floor);
    let fill = (c_ext / (PI * reach * reach)).min(1.0);
    let tau = if fill >= 1.0 {
        TAU_OPAQUE
    } else {
        (-(-fill).ln_1p()).min(TAU_OPAQUE)
    };
    (reach, tau)
}

/// Discrete grains from which compact storage keeps them by their centres' cells (8 bytes each,
/// `crate::space::grid`) rather than in overlap slots (~2.5 slots of 12 bytes, and a slower walk on
/// sparse grains). Below it the slots total at most ~2.5 MB and the medium's fixed costs (its class
/// table, up to 16 × 1024 classes of 17 bytes, and its cells) dominate its bytes per particle whatever
/// the layout; from it up, at most 16 bytes a grain. `MOTES_CENTRE_CELLS` forces one layout
/// (`crate::options`).
const CENTRE_CELLS_FROM: usize = 1 << 16;

/// Whether compact storage keeps `discrete` grains by their centres' cells: as `switch`
/// (`MOTES_CENTRE_CELLS`) says, or else from [`CENTRE_CELLS_FROM`] on.
fn centre_cells_for(discrete: usize, switch: Option<bool>) -> bool {
    switch.unwrap_or(discrete >= CENTRE_CELLS_FROM)
}

/// The coincidence window (sites closer than this along a ray are one site) and the box outside
/// which no ray can start at an event, for particles at `positions` with disks up to `reach_max`.
fn event_geometry(positions: &[[f64; 3]], reach_max: f64) -> (f64, Bounds3) {
    let (lo, hi) = bounding_box(positions);
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max) + reach_max;
    // Float32 positions carry ~6e-8 relative error: projections closer than 1e-6 of the extent cannot
    // be ordered reliably, so they form one site.
    let coincide = 1e-6 * extent.max(1e-30);
    // Grown by the largest disk, a relative margin for f32 positions, and the coincidence window.
    let grow = reach_max * 1.001 + 1e-6 * extent + coincide;
    let event_box = Bounds3 {
        lo: lo.map(|x| x - grow),
        hi: hi.map(|x| x + grow),
    };
    (coincide, event_box)
}

/// Ids of media (never reused, unlike addresses).
static MEDIUM_IDS: AtomicU64 = AtomicU64::new(1);

/// A stored medium's table by code (its particle's index, or compact storage's class: `Self::code`):
/// the radius, cross section and disk (R, τ) that everything the build makes sees.
struct DiskTable {
    /// Compact storage's classes (None: full storage, a table per particle).
    classes: Option<Classes>,
    /// Full storage's cross sections and radii per particle (empty for compact storage).
    c_full: Vec<f64>,
    r_full: Vec<f64>,
    /// The disk (R, τ) per code.
    disks: Vec<(f64, f64)>,
}

/// What [`DiskTable::walk`] builds: the grid and the fields, which particles the grid walks
/// (`keep`, by original index) and in which order (`order`, compact storage), and the figures the
/// medium reports.
struct StoredWalk {
    grid: Option<ParticleGrid>,
    field: Option<ContinuousField>,
    grains_field: Option<ContinuousField>,
    footprint: Option<SurfaceFootprint>,
    keep: Vec<bool>,
    order: Option<Vec<u32>>,
    widened: usize,
    reach_max: f64,
}

impl DiskTable {
    /// The table of the particles `p` as `settings.storage` keeps them, with their disks.
    fn new(
        p: &ParticleInputs,
        bins: usize,
        settings: &MediumSettings,
    ) -> Result<Self, OpticsError> {
        let (n, storage) = (p.positions.len(), settings.storage);
        // Compact storage: each particle becomes its class (a bin and a radius level), and everything
        // below sees the class's radius and cross section (crate::render::storage).
        // Full storage keeps every particle's cross section: its table is per particle.
        let radius_at = |i: usize| p.radius[i] * p.radius_scale;
        let (c_full, r_full): (Vec<f64>, Vec<f64>) = match storage {
            Storage::Full => (
                (0..n).into_par_iter().map(p.c_ext).collect(),
                (0..n).into_par_iter().map(radius_at).collect(),
            ),
            Storage::Compact => (Vec::new(), Vec::new()),
        };
        let classes = match storage {
            Storage::Compact => Some(classes(&radius_at, p.c_ext, p.bin, bins)?),
            Storage::Full => None,
        };
        let (t_radius, t_c): (&[f64], &[f64]) = match &classes {
            Some(c) => (&c.radius, &c.c_ext),
            None => (&r_full, &c_full[..]),
        };
        let (query_radius, tau_max) = (settings.query_radius, settings.tau_max);
        let disks: Vec<(f64, f64)> = t_radius
            .par_iter()
            .zip(t_c)
            .map(|(&r, &c)| {
                if r > 0.0 {
                    particle_disk(r, c, query_radius, tau_max)
                } else {
                    (0.0, 0.0)
                }
            })
            .collect();
        Ok(DiskTable {
            classes,
            c_full,
            r_full,
            disks,
        })
    }

    /// The radius and the cross section per code.
    fn radius_and_c_ext(&self) -> (&[f64], &[f64]) {
        match &self.classes {
            Some(c) => (&c.radius, &c.c_ext),
            None => (&self.r_full, &self.c_full[..]),
        }
    }

    /// Compact storage's class of each particle (None: full storage).
    fn codes(&self) -> Option<&[u32]> {
        self.classes.as_ref().map(|c| &c.codes[..])
    }

    /// The grid and the fields of the particles at `positions` (`discrete` docs).
    fn walk(
        &self,
        positions: &[[f64; 3]],
        settings: &MediumSettings,
        switches: &BuildSwitches,
    ) -> Result<StoredWalk, OpticsError> {
        let (n, query_radius) = (positions.len(), settings.query_radius);
        let ((t_radius, t_c), table_disks) = (self.radius_and_c_ext(), &self.disks);
        let code_of = |i: usize| self.classes.as_ref().map_or(i, |c| c.codes[i] as usize);
        // Per-particle values as functions of the particle through the table, not columns (at 10^8
        // particles every f64 column is 800 MB): the grid takes columns of its discrete particles only.
        let reach = |i: usize| table_disks[code_of(i)].0;
        let p_c = |i: usize| t_c[code_of(i)];
        let widened = (0..n)
            .into_par_iter()
            .filter(|&i| {
                let k = code_of(i);
                table_disks[k].0 > query_radius + t_radius[k]
            })
            .count();
        // The grid reaches r_c + radius and spreads c / (π reach²): the widened disks (R, τ) are handed
        // to it as radii R − r_c (at least r) and cross sections τ π R², so that it walks exactly them.
        let grid_radius = |i: usize| {
            let k = code_of(i);
            (table_disks[k].0 - query_radius).max(t_radius[k])
        };
        let grid_c = |i: usize| {
            let (r, tau) = table_disks[code_of(i)];
            tau * PI * r * r
        };
        let compact = settings.storage == Storage::Compact;
        let columns = WalkColumns {
            reach: &reach,
            grid_radius: &grid_radius,
            grid_c: &grid_c,
            c_ext: &p_c,
        };
        let (grid, field, keep, footprint, order) = build_walk(
            positions,
            &columns,
            // MOTES_QUANTISE=0 keeps spheres (`crate::options`); centre cells from
            // CENTRE_CELLS_FROM discrete grains (`build_walk`).
            &settings
                .grid()
                .quantised(compact && switches.quantise)
                .centred(compact)
                .by_free_path(true),
            settings.continuous_count,
            self.codes(),
            switches.centre_cells,
        )?;
        let reach_max = (0..n).into_par_iter().map(reach).reduce(|| 0.0, f64::max);
        // Every particle's continuous equivalent, for rays past the grain depth (weighted by C_t,i as
        // the continuous classes are); none when the medium must stay exact. When every particle is
        // already in the continuous field, the field is that equivalent (built once: see
        // `grains_field_from`).
        let all_continuous = grid.is_none();
        let grains_field = (settings.continuous_count.is_finite() && !all_continuous)
            .then(|| ContinuousField::build(positions, &reach, &p_c, None, self.codes()))
            .transpose()?;
        let (field, grains_field) = self.picking_by_bin(field, grains_field);
        Ok(StoredWalk {
            grid,
            field,
            grains_field,
            footprint,
            keep,
            order,
            widened,
            reach_max,
        })
    }

    /// The fields as compact storage picks from them: an interaction in a field reads only its
    /// particle's optics bin, so they pick by bin.
    fn picking_by_bin(
        &self,
        field: Option<ContinuousField>,
        grains_field: Option<ContinuousField>,
    ) -> (Option<ContinuousField>, Option<ContinuousField>) {
        match &self.classes {
            Some(c) => {
                let by_bin =
                    |f: ContinuousField| f.picking_by(|k| c.bin[(k & !CLASS_FLAG) as usize]);
                // The grains' equivalent is only ever picked from: its table is enough.
                let forget = |f: ContinuousField| by_bin(f).forget_members();
                (field.map(by_bin), grains_field.map(forget))
            }
            None => (field, grains_field),
        }
    }

    /// The optics the medium keeps of `n` particles in bins `bin`, `keep` those the grid walks and
    /// `order` their order in it ([`StoredWalk`]).
    fn optics(
        self,
        bin: &[u32],
        keep: &[bool],
        order: Option<Vec<u32>>,
        n: usize,
    ) -> ParticleOptics {
        let DiskTable {
            classes,
            c_full,
            disks: table_disks,
            ..
        } = self;
        let (table_c, table_bin, in_field) = match classes {
            Some(c) => {
                let mut in_field = vec![false; c.radius.len()];
                for (i, &k) in c.codes.iter().enumerate() {
                    in_field[k as usize] = !keep[i];
                }
                // The grid's particles by position (`build_walk`): the continuous ones are named by
                // class in their field, so only the grid's keep a code.
                let codes = match order {
                    Some(order) => order.par_iter().map(|&i| c.codes[i as usize]).collect(),
                    None => c.codes,
                };
                (c.c_ext, c.bin, Some((in_field, codes)))
            }
            None => (c_full, bin.to_vec(), None),
        };
        match in_field {
            Some((in_field, codes)) => {
                ParticleOptics::new(&table_disks, &table_c, table_bin, in_field, Some(codes), n)
            }
            None => ParticleOptics::new(
                &table_disks,
                &table_c,
                table_bin,
                keep.iter().map(|k| !k).collect(),
                None,
                n,
            ),
        }
    }
}

/// A procedural cloud's optics table: its classes' disks `disks`, cross sections and bins, and
/// which are continuous.
fn procedural_optics(parts: &ProceduralParts, disks: &[(f64, f64)]) -> ParticleOptics {
    let c_ext: Vec<f64> = parts.classes.iter().map(|c| c.c_ext).collect();
    let bin = parts.classes.iter().map(|c| c.bin).collect();
    let in_field = parts.discrete.iter().map(|d| !d).collect();
    ParticleOptics::new(disks, &c_ext, bin, in_field, None, 0)
}

impl DiscreteMedium {
    /// `positions` in scene units, `radius` in scene units once multiplied by `radius_scale` (a caller
    /// with radii in µm passes them with the scale instead of a scaled copy: 800 MB at 10^8 particles),
    /// `c_ext` the grey extinction cross section per particle (scene units²), `bin` each particle's
    /// index into `bins`, `lambda` the tabulated wavelengths (increasing), and the medium's
    /// [`MediumSettings`] (its query radius r_c, the cap τ_max on each disk's optical depth, the
    /// `continuous_count` from which size classes are sampled as a continuous medium, the seed and
    /// the storage).
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        positions: &[[f64; 3]],
        radius: &[f64],
        radius_scale: f64,
        c_ext: Column,
        bin: &[u32],
        bins: Vec<BinOptics>,
        lambda: Vec<f64>,
        settings: &MediumSettings,
    ) -> Result<Self, OpticsError> {
        let p = ParticleInputs {
            positions,
            radius,
            radius_scale,
            c_ext,
            bin,
        };
        check_build_inputs(&p, &bins, &lambda, settings)?;
        let switches = BuildSwitches::from_env();
        let table = DiskTable::new(&p, bins.len(), settings)?;
        let w = table.walk(positions, settings, &switches)?;
        let optics = table.optics(bin, &w.keep, w.order, positions.len());
        let (coincide, event_box) = event_geometry(positions, w.reach_max);
        let walkable = Walkable {
            grid: w.grid.map(Grains::Stored),
            expected: None,
            field: w.field,
            // The surface rule chooses between the grains and their equivalent: both must exist.
            footprint: w.footprint.filter(|_| w.grains_field.is_some()),
            grains_field: w.grains_field,
            optics,
            widened: w.widened,
            coincide,
            event_box,
        };
        Ok(walkable.into_medium(bins, lambda, settings.seed, &switches))
    }

    /// A procedural cloud (`crate::render::procedural`): nothing stored but the class table, the
    /// continuous classes' field and the bricks a render visits (at most `settings.cache_bytes` of
    /// them kept). `spec.q_ext` per bin of `bins`; the other settings as [`Self::build`]'s.
    pub fn procedural(
        spec: &ProceduralSpec,
        bins: Vec<BinOptics>,
        lambda: Vec<f64>,
        settings: &MediumSettings,
    ) -> Result<Self, OpticsError> {
        check_procedural_inputs(spec, &bins, &lambda, settings)?;
        let switches = BuildSwitches::from_env();
        let (query_radius, tau_max) = (settings.query_radius, settings.tau_max);
        let continuous_count = settings.continuous_count;
        let disk = |r: f64, c: f64| {
            if r > 0.0 {
                particle_disk(r, c, query_radius, tau_max)
            } else {
                (0.0, 0.0)
            }
        };
        let parts = build_parts(
            spec,
            disk,
            query_radius,
            settings.cells_per_particle,
            continuous_count,
            settings.cache_bytes,
        )?;
        let disks: Vec<(f64, f64)> = parts
            .classes
            .iter()
            .map(|c| disk(c.radius, c.c_ext))
            .collect();
        let optics = procedural_optics(&parts, &disks);
        let reach_max = parts
            .discrete
            .iter()
            .zip(&disks)
            .filter(|(d, _)| **d)
            .map(|(_, k)| k.0)
            .fold(0.0, f64::max);
        let widened = 0;
        // Grains drifted by turbulence may sit outside the box at rest by up to the drift's bound.
        let drift = spec.motion.as_ref().map_or(0.0, |(m, _)| m.drift_bound());
        let (coincide, event_box) = event_geometry(&parts.corners, reach_max + drift);
        let footprint = (continuous_count.is_finite() && parts.grains.is_some())
            .then(|| procedural_footprint(spec.count, &parts, &disks, continuous_count))
            .flatten();
        let grid = parts.grains.map(|g| Grains::Procedural(Box::new(g)));
        let exact = !continuous_count.is_finite();
        let all_continuous = grid.is_none();
        let walkable = Walkable {
            expected: Some((spec.count, parts.field_count)),
            field: parts.field,
            footprint,
            // Every class continuous: the field is the grains' equivalent (as `build` does).
            grains_field: (!exact && !all_continuous).then_some(parts.all_field),
            grid,
            optics,
            widened,
            coincide,
            event_box,
        };
        Ok(walkable.into_medium(bins, lambda, settings.seed, &switches))
    }
}

impl Walkable {
    /// The medium over what its free flights walk, with fresh per-render state.
    fn into_medium(
        self,
        bins: Vec<BinOptics>,
        lambda: Vec<f64>,
        seed: u64,
        switches: &BuildSwitches,
    ) -> DiscreteMedium {
        DiscreteMedium {
            grid: self.grid,
            expected: self.expected,
            field: self.field,
            grains_field: self.grains_field,
            footprint: self.footprint,
            view: RwLock::new(Arc::new(View::default())),
            view_epoch: AtomicU64::new(0),
            enclosure: RwLock::new(Arc::new(Enclosure::default())),
            surface_footprint: AtomicBool::new(true),
            surface_counts: ShardedCounts::default(),
            optics: self.optics,
            widened: self.widened,
            coincide: self.coincide,
            event_box: self.event_box,
            beams: switches.beams,
            shared_nodes: bins
                .iter()
                .map(|b| b.phase.iter().all(|t| t.same_nodes(&b.phase[0])))
                .collect(),
            bins,
            lambda,
            events: RwLock::new(EventMap::new(EVENTS_PER_GENERATION)),
            pending: Mutex::new(FxHashMap::default()),
            seed,
            calls: AtomicU64::new(0),
            id: MEDIUM_IDS.fetch_add(1, Ordering::Relaxed),
            packet_counts: ShardedCounts::default(),
            albedo_scale: AtomicU64::new(1f64.to_bits()),
            events_anywhere: AtomicBool::new(false),
            optics_epoch: AtomicU64::new(0),
            grain_depth: AtomicU32::new(DEFAULT_GRAIN_DEPTH),
        }
    }
}
