//! Procedural clouds (issue 24.3): a generated cloud whose particles are never stored. Each tile of the
//! cloud's Poisson process (`crate::space::cloud`) is generated from (seed, tile) when a ray first
//! needs it, so memory depends on the region a render visits and on the density field, not on the
//! count: 10^12 grains over a valley cost what the bricks a camera sees cost.
//!
//! ## The process, split by what a pixel resolves
//! A cloud of expected count N over a box with relative density d(x) is a Poisson process of intensity
//! N d(x) / ∫d. Its particles are marked with a species (by share) and a radius (the species' PSD),
//! quantised as compact storage quantises them (`crate::render::storage`: a bin and one of
//! [`LEVELS_PER_BIN`] radius levels), so each particle *is* a class k of probability p_k (from the PSD's
//! CDF over the level). Marking a Poisson process splits it into independent Poisson processes, one per
//! class, of intensity N p_k d(x) / ∫d. So:
//! * the classes that stay discrete ([`crate::render::continuous::resolvable`]'s criterion, with the
//!   class's expected count in place of a count of stored particles) are one Poisson process of
//!   intensity N P_disc d(x) / ∫d whose particles pick their class from the discrete classes in
//!   proportion to p_k: the only particles ever generated;
//! * the continuous classes are their expected extinction, σ_t(x) = Σ_k N p_k C_k d(x) / ∫d, a field of
//!   the density's shape ([`ContinuousField::from_density`]), each bin's classes scattering as one
//!   class of that bin.
//!
//! Both are what a stored cloud of the same distribution is in expectation (a stored cloud has exactly
//! N particles, a procedural one a Poisson count of mean N; at any N worth generating procedurally
//! the difference, 1/√N, is nothing a render shows).
//!
//! ## Bricks
//! The discrete process is tiled (`CloudSpec::tiling`, about 64 candidates a tile) and the
//! tiles grouped into bricks of B³ tiles (about [`BRICK_PARTICLES`] particles, and at least twice as
//! wide as the halo: the tiles a ball reaches across), with a ring of bricks around the box for the
//! balls that reach out of it. A brick's grid holds its own tiles' particles and those of the halo
//! tiles whose balls reach into it (bounds per axis, widened by the float32 rounding of the grids'
//! centres), built on first use into an ordinary [`ParticleGrid`] and kept in a cache of bounded size
//! (least recently used bricks dropped; each of its 64 shards keeps at least its newest brick, and
//! render threads missing the same brick at once may each build it: the same particles). A ray walks the bricks it crosses in order (a 3D-DDA in the cloud's own
//! coordinates, where the bricks are boxes) and each brick's grid over the part of the ray inside
//! the brick: every particle projecting onto that part is in the brick's grid, so the walk visits
//! each particle once and in t order, and the free flight is exact for the particles as generated.
//! Each particle is known by (tile, index in tile), whichever brick found it: the key that keeps a
//! scattered ray from meeting its own particle again.

mod classes;
mod export;

use crate::error::{require, shown, OpticsError};
use crate::render::continuous::{ContinuousField, CLASS_FLAG};
use crate::space::cloud::{det3, invert_affine, CloudSpec, Density, Tiling};
use crate::space::dda::{Dda, GridFrame};
use crate::space::grid::{GridSettings, ParticleGrid, Site, CELLS_DRIVER};
use crate::space::motion::Motion;
use crate::space::ray::RaySegment;
pub(crate) use classes::{class_table, ClassEntry};
use classes::{discrete_classes, push_representatives, scene_box, BinWeights, BoxShape};
pub use export::{DensityTerms, NoiseTerms, ProceduralExport, TileGrains};
use rustc_hash::FxHashMap;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, RwLock};

/// Expected discrete particles per brick: a brick's grid costs a cache lookup and a walk set-up per
/// ray that crosses it, and a build (its tiles and their neighbours generated) per cache miss.
pub const BRICK_PARTICLES: f64 = 8192.0;
/// Default bytes of bricks kept (the cache drops the least recently used beyond this).
pub const DEFAULT_CACHE_BYTES: usize = 1 << 30;
/// Cache shards (independent locks for the render threads).
const SHARDS: usize = 64;
/// Largest number of particles one tile may hold (a tile's index in a particle key).
const TILE_INDEX_BITS: u32 = 24;
/// Most candidates one brick may generate (its tiles and their halo).
const MAX_BRICK_CANDIDATES: f64 = 1e7;
/// Most centres of discrete grains (at the density's peak) one inclusion ball may hold: 10^10 grains
/// of 80 µm in a 12 cm cube with r_c 0.2 mm hold 530 and render (bricks of ~10 MB); 10^12 hold 53 000.
const MAX_BALL_NEIGHBOURS: f64 = 2000.0;

/// Most cells of a brick's grid (2^22: 64 MB to build at most; a brick of 65536 grains at the default
/// resolution has 8192).
const MAX_BRICK_CELLS: f64 = 4_194_304.0;

/// A procedural cloud's distribution and the optics bins its radii fall in.
#[derive(Clone, Debug)]
pub struct ProceduralSpec {
    /// The box (the cloud's own coordinates), density, species (share, PSD in µm) and seed.
    pub cloud: CloudSpec,
    /// Expected number of particles in the box.
    pub count: f64,
    /// The cloud's coordinates to scene units (3×4, row-major: rotation/scale, then translation).
    pub transform: [[f64; 4]; 3],
    /// Scene units per micrometre (radii are not transformed: `scale_m`).
    pub scene_per_um: f64,
    /// Per species: the edges of its optics bins (µm, increasing, spanning the PSD's support).
    pub bin_edges_um: Vec<Vec<f64>>,
    /// Per species: the global optics bin of its first bin (its bins follow in order).
    pub first_bin: Vec<u32>,
    /// Grey extinction efficiency Q_ext of each global optics bin.
    pub q_ext: Vec<f64>,
    /// Grains moved by a turbulent drift to a time (seconds): `crate::space::motion` (a velocity is
    /// the caller's `transform`, so the drift is evaluated at the moved rest position x₀ + v t where a
    /// stored cloud evaluates it at x₀). The continuous classes keep the density field at rest (the
    /// drift keeps a uniform density uniform to O((A / L)²)).
    pub motion: Option<(Motion, f64)>,
}

/// A built brick: the particles of its tiles and of the neighbouring tiles whose balls reach into it.
struct Brick {
    grid: Option<ParticleGrid>,
    /// Per particle of the grid (its original index): class code and key ((tile << 24 | index in
    /// tile) + 1; never 0).
    code: Vec<u32>,
    key: Vec<u64>,
    bytes: usize,
}

struct Shard {
    /// Each brick and when it was last used (the shard's clock).
    map: FxHashMap<u64, (Arc<Brick>, AtomicU64)>,
    bytes: usize,
}

/// Bricks by index, the least recently used dropped beyond a byte budget. A hit takes a shard's read
/// lock and stamps the brick with the shard's clock; a miss builds the brick outside any lock.
struct BrickCache {
    shards: Vec<(RwLock<Shard>, AtomicU64)>,
    budget: usize,
    built: AtomicU64,
}

impl BrickCache {
    fn new(budget: usize) -> Self {
        BrickCache {
            shards: (0..SHARDS)
                .map(|_| {
                    let shard = Shard {
                        map: FxHashMap::default(),
                        bytes: 0,
                    };
                    (RwLock::new(shard), AtomicU64::new(0))
                })
                .collect(),
            budget: (budget / SHARDS).max(1),
            built: AtomicU64::new(0),
        }
    }

    fn get(&self, index: u64, build: impl FnOnce() -> Brick) -> Arc<Brick> {
        // Neighbouring bricks in different shards (consecutive indices), so threads rarely share one.
        let (shard, clock) = &self.shards[(index % SHARDS as u64) as usize];
        let now = clock.fetch_add(1, Ordering::Relaxed);
        if let Some(e) = shard.read().unwrap().map.get(&index) {
            e.1.store(now, Ordering::Relaxed);
            return e.0.clone();
        }
        // Built outside the lock (two threads may build the same brick: the same particles).
        let brick = Arc::new(build());
        self.built.fetch_add(1, Ordering::Relaxed);
        let mut s = shard.write().unwrap();
        if let Some(e) = s.map.get(&index) {
            return e.0.clone();
        }
        s.bytes += brick.bytes;
        s.map.insert(index, (brick.clone(), AtomicU64::new(now)));
        while s.bytes > self.budget && s.map.len() > 1 {
            let oldest = s
                .map
                .iter()
                .filter(|(&k, _)| k != index)
                .min_by_key(|(_, v)| v.1.load(Ordering::Relaxed))
                .map(|(&k, _)| k);
            let Some(k) = oldest else { break };
            let (b, _) = s.map.remove(&k).expect("present");
            s.bytes -= b.bytes;
        }
        brick
    }

    fn bytes(&self) -> usize {
        self.shards.iter().map(|s| s.0.read().unwrap().bytes).sum()
    }
}

/// The discrete classes of a procedural cloud, generated brick by brick (module docs).
pub struct ProceduralGrains {
    /// The turbulent drift and time the grains are moved to (their tiles generate them at rest).
    motion: Option<(Motion, f64)>,
    cloud: CloudSpec,
    tiling: Tiling,
    /// Tiles per brick along each axis, and tiles a ball reaches across (at least 1).
    per_brick: [usize; 3],
    halo: [usize; 3],
    /// Bricks over the tiles and a ring of one tile around them (the cloud's coordinates).
    frame: GridFrame,
    /// Scene ← cloud (3×4) and cloud ← scene linear part (3×3) with its translation.
    to_scene: [[f64; 4]; 3],
    to_cloud: [[f64; 4]; 3],
    /// Discrete class codes and the running sum of their probabilities (normalised to 1).
    codes: Vec<u32>,
    cdf: Vec<f64>,
    /// Per class code: the grid's radius and cross section (the disk as the grid walks it).
    grid_radius: Vec<f64>,
    grid_c: Vec<f64>,
    /// How far the widest inclusion ball reaches along each axis of the cloud's coordinates.
    reach_cloud: [f64; 3],
    settings: GridSettings,
    cache: BrickCache,
    /// Expected number of discrete particles.
    expected: f64,
}

/// The state of an exact free flight to the next site over a sequence of walks (one per brick): the
/// same grouping as [`ParticleGrid::sample_site`], with particles known by key.
pub(crate) struct SiteWalk<'a> {
    target: f64,
    pub acc: f64,
    group: Site,
    group_keys: [u64; Site::CAPACITY],
    group_tau: f64,
    last_t: f64,
    exclude: &'a [u64],
    coincide: f64,
    pub found: Option<Site>,
}

impl<'a> SiteWalk<'a> {
    pub(crate) fn new(u: f64, exclude: &'a [u64], coincide: f64) -> Self {
        SiteWalk {
            target: -(1.0 - u).ln(),
            acc: 0.0,
            group: Site::default(),
            group_keys: [0; Site::CAPACITY],
            group_tau: 0.0,
            last_t: f64::NEG_INFINITY,
            exclude,
            coincide,
            found: None,
        }
    }

    /// A particle in t order; false once the site is found.
    fn offer(&mut self, t: f64, tau: f64, member: u32, key: u64) -> bool {
        if self.exclude.contains(&key) {
            return true;
        }
        if self.group.len > 0 && t > self.last_t + self.coincide && !self.close() {
            return false;
        }
        if self.group.len == 0 {
            self.group.t = t;
        }
        let k = self.group.len as usize;
        if k < Site::CAPACITY {
            self.group_keys[k] = key;
        }
        self.group.push(member);
        self.group_tau += tau;
        self.last_t = t;
        true
    }

    /// Complete the current group: does the path interact there? (false: it does; the site is found).
    fn close(&mut self) -> bool {
        if self.group.len == 0 {
            return true;
        }
        if self.acc + self.group_tau > self.target {
            let mut s = self.group;
            s.keys = self.group_keys;
            self.found = Some(s);
            return false;
        }
        self.acc += self.group_tau;
        self.group = Site::default();
        self.group_tau = 0.0;
        true
    }
}

fn apply(m: &[[f64; 4]; 3], p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
}

fn apply_linear(m: &[[f64; 4]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

/// Per axis of the cloud's coordinates, how far a scene displacement of length `reach` can move a point
/// along it: `reach` times the norm of that row of the inverse map (exact: the row's direction attains
/// it), widened by the float32 rounding of the grids' centres (~6e-8 of the largest scene coordinate
/// `extent`, four times over), so that no ball a ray can meet is left out of the brick its projection
/// falls in.
fn cloud_reach(to_cloud: &[[f64; 4]; 3], reach: f64, extent: f64) -> [f64; 3] {
    let slack = 4.0 * f32::EPSILON as f64 * extent;
    [0, 1, 2].map(|a| {
        let row = (0..3)
            .map(|c| to_cloud[a][c] * to_cloud[a][c])
            .sum::<f64>()
            .sqrt();
        (reach + slack) * row * (1.0 + 1e-9)
    })
}

/// What the medium needs from a procedural cloud: the class table (fine classes, then one
/// representative per bin), which classes stay discrete, their grains, and the fields.
pub(crate) struct ProceduralParts {
    pub classes: Vec<ClassEntry>,
    /// Per class code: kept discrete (the representatives are continuous).
    pub discrete: Vec<bool>,
    pub grains: Option<ProceduralGrains>,
    /// The continuous classes as a field (None when every class is discrete).
    pub field: Option<ContinuousField>,
    /// Every class as a field (the grains' equivalent for rays past the grain depth).
    pub all_field: ContinuousField,
    /// The box's corners in scene units.
    pub corners: Vec<[f64; 3]>,
    /// Expected particles in the field.
    pub field_count: f64,
}

/// The parts of a procedural cloud (module docs), its disks `disk(radius, c_ext)` → (R, τ).
pub(crate) fn build_parts(
    spec: &ProceduralSpec,
    disk: impl Fn(f64, f64) -> (f64, f64),
    query_radius: f64,
    cells_per_particle: f64,
    continuous_count: f64,
    cache_bytes: usize,
) -> Result<ProceduralParts, OpticsError> {
    let (to_cloud, mean) = checked_cloud(spec)?;
    let count = spec.count;
    let mut classes = class_table(spec)?;
    let fine = classes.len();
    let (volume, chord, extents) = scene_box(spec);
    let disks: Vec<(f64, f64)> = classes.iter().map(|c| disk(c.radius, c.c_ext)).collect();
    let shape = BoxShape {
        volume,
        chord,
        extents,
    };
    let mut discrete = discrete_classes(&classes, &disks, count, &shape, continuous_count);
    let weights = push_representatives(&mut classes, &mut discrete, count, volume, &spec.q_ext);
    let fields = procedural_fields(spec, &to_cloud, mean, fine, &weights);
    let split = ClassSplit {
        classes: &classes,
        disks: &disks,
        discrete: &discrete,
        fine,
    };
    let grains = procedural_grains(
        spec,
        to_cloud,
        &split,
        &fields.corners,
        GridSettings::new(query_radius, cells_per_particle),
        cache_bytes,
    )?;
    Ok(ProceduralParts {
        classes,
        discrete,
        grains,
        field: fields.field,
        all_field: fields.all_field,
        corners: fields.corners,
        field_count: fields.field_count,
    })
}

/// The checks of a procedural cloud's count, box, density and transform; the map from scene units to
/// the cloud's coordinates and the density's mean over the box.
fn checked_cloud(spec: &ProceduralSpec) -> Result<([[f64; 4]; 3], f64), OpticsError> {
    let count = spec.count;
    require(
        "count",
        count,
        (1.0..=1e15).contains(&count),
        "in [1, 1e15]",
    )?;
    spec.cloud.check()?;
    let (lo, hi) = (spec.cloud.lo, spec.cloud.hi);
    let density = &spec.cloud.density;
    let mean = density.mean(lo, hi);
    require(
        "density",
        mean,
        mean > 0.0 && density.bound() / mean <= 1e4,
        "a density whose mean over the box is > 0 and at least 1e-4 of its largest value",
    )?;
    require(
        "to_world",
        0.0,
        spec.transform.iter().flatten().all(|x| x.is_finite()),
        "a finite transform",
    )?;
    // The box's volume in the cloud's coordinates and in scene units (|det| times it) set the grains'
    // number density: a box or transform of 1e200 overflows them, one of 1e-200 underflows them.
    let box_volume: f64 = (0..3).map(|a| hi[a] - lo[a]).product();
    require(
        "box",
        box_volume,
        box_volume.is_finite() && box_volume > 0.0,
        "a box whose volume (the product of its sides) is finite and > 0",
    )?;
    let scene_volume = scene_box(spec).0;
    require(
        "to_world",
        det3(&spec.transform),
        scene_volume.is_finite() && scene_volume > 0.0,
        "a transform whose determinant keeps the box's volume in scene units finite and > 0",
    )?;
    let to_cloud = invert_affine(&spec.transform).ok_or(OpticsError::InvalidArgument {
        argument: "to_world",
        value: 0.0,
        requirement: "an invertible transform",
    })?;
    Ok((to_cloud, mean))
}

/// The fields of a procedural cloud and the box's corners in scene units ([`procedural_fields`]).
struct FieldParts {
    corners: Vec<[f64; 3]>,
    field: Option<ContinuousField>,
    all_field: ContinuousField,
    field_count: f64,
}

/// Cells of the continuous classes' field along the box's longest side.
const FIELD_CELLS: usize = 64;
/// Sub-samples per axis of the density in each field cell.
const FIELD_SAMPLES: usize = 2;

/// A density's cells in scene units: the bounding box of the cloud's box [`lo`, `hi`] through
/// `transform`, FIELD_CELLS along its longest side, and the mean density over a cell relative to the
/// box's mean `mean`: the density mapped back to the cloud's coordinates (`to_cloud`; zero outside the
/// box), averaged over FIELD_SAMPLES³ points per cell. What a procedural cloud's fields and a
/// generated cloud's grains' equivalent (`DiscreteMedium::see_density`) spread their extinction by.
pub(crate) struct DensityCells<'a> {
    pub corners: Vec<[f64; 3]>,
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    pub dims: [usize; 3],
    density: &'a Density,
    cloud: ([f64; 3], [f64; 3]),
    to_cloud: [[f64; 4]; 3],
    mean: f64,
}

impl<'a> DensityCells<'a> {
    pub fn new(
        density: &'a Density,
        cloud: ([f64; 3], [f64; 3]),
        transform: &[[f64; 4]; 3],
        to_cloud: [[f64; 4]; 3],
        mean: f64,
    ) -> Self {
        let (lo, hi) = cloud;
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|i| {
                let p = [0, 1, 2].map(|a| if i >> a & 1 == 1 { hi[a] } else { lo[a] });
                apply(transform, p)
            })
            .collect();
        let (mut flo, mut fhi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for c in &corners {
            for a in 0..3 {
                flo[a] = flo[a].min(c[a]);
                fhi[a] = fhi[a].max(c[a]);
            }
        }
        let fext = [0, 1, 2].map(|a| (fhi[a] - flo[a]).max(1e-12));
        let longest = fext.iter().fold(0.0f64, |a, &b| a.max(b));
        let dims = fext.map(|x| ((x / longest * FIELD_CELLS as f64).round() as usize).max(1));
        DensityCells {
            corners,
            lo: flo,
            hi: fhi,
            dims,
            density,
            cloud,
            to_cloud,
            mean,
        }
    }

    /// The mean density over the cell [a, b] relative to the box's mean.
    pub fn relative(&self, a: [f64; 3], b: [f64; 3]) -> f64 {
        let (lo, hi) = self.cloud;
        let m = FIELD_SAMPLES;
        let mut sum = 0.0;
        for k in 0..m * m * m {
            let idx = [k % m, (k / m) % m, k / (m * m)];
            let p = [0, 1, 2].map(|x| a[x] + (b[x] - a[x]) * (idx[x] as f64 + 0.5) / m as f64);
            let q = apply(&self.to_cloud, p);
            if (0..3).all(|x| q[x] >= lo[x] && q[x] <= hi[x]) {
                sum += self.density.at(q, lo, hi);
            }
        }
        sum / (m * m * m) as f64 / self.mean
    }

    /// The field whose cells hold `members` in proportion to `weight` (extinction per unit volume at
    /// the box's mean density), their σ_t following the density (`ContinuousField::from_density`).
    pub fn field(&self, members: Vec<u32>, weight: &[f64]) -> ContinuousField {
        let rel = |a, b| self.relative(a, b);
        ContinuousField::from_density(self.lo, self.hi, self.dims, rel, members, weight)
    }
}

/// The continuous classes' field and every class's ([`DensityCells`]). `fine`: the code of the first
/// bin's representative.
fn procedural_fields(
    spec: &ProceduralSpec,
    to_cloud: &[[f64; 4]; 3],
    mean: f64,
    fine: usize,
    weights: &BinWeights,
) -> FieldParts {
    let cloud = (spec.cloud.lo, spec.cloud.hi);
    let cells = DensityCells::new(&spec.cloud.density, cloud, &spec.transform, *to_cloud, mean);
    let bins = weights.cont.len();
    let reps: Vec<u32> = (0..bins).map(|b| CLASS_FLAG | (fine + b) as u32).collect();
    let field_count: f64 = spec.count * weights.p_cont.iter().sum::<f64>();
    let field = (field_count > 0.0).then(|| cells.field(reps.clone(), &weights.cont));
    let all_field = cells.field(reps, &weights.all);
    FieldParts {
        corners: cells.corners,
        field,
        all_field,
        field_count,
    }
}

/// A procedural cloud's classes (the `fine` ones, then the representatives), their disks and which
/// stay discrete.
struct ClassSplit<'a> {
    classes: &'a [ClassEntry],
    disks: &'a [(f64, f64)],
    discrete: &'a [bool],
    fine: usize,
}

/// The discrete process (module docs): the grains of the discrete classes, generated brick by brick
/// (None when no class is discrete).
fn procedural_grains(
    spec: &ProceduralSpec,
    to_cloud: [[f64; 4]; 3],
    split: &ClassSplit,
    corners: &[[f64; 3]],
    settings: GridSettings,
    cache_bytes: usize,
) -> Result<Option<ProceduralGrains>, OpticsError> {
    let (classes, disks) = (split.classes, split.disks);
    let codes: Vec<u32> = (0..split.fine)
        .filter(|&k| split.discrete[k])
        .map(|k| k as u32)
        .collect();
    let p_disc: f64 = codes.iter().map(|&k| classes[k as usize].p).sum();
    if codes.is_empty() || p_disc.is_nan() || p_disc <= 0.0 {
        return Ok(None);
    }
    let mut acc = 0.0;
    let cdf = codes
        .iter()
        .map(|&k| {
            acc += classes[k as usize].p / p_disc;
            acc
        })
        .collect();
    let reach_disc = codes
        .iter()
        .map(|&k| disks[k as usize].0)
        .fold(0.0, f64::max);
    let grid_radius = disks
        .iter()
        .zip(classes)
        .map(|(d, c)| (d.0 - settings.query_radius).max(c.radius))
        .collect();
    let grid_c = disks.iter().map(|d| d.1 * PI * d.0 * d.0).collect();
    Ok(Some(ProceduralGrains::new(
        spec,
        to_cloud,
        codes,
        cdf,
        grid_radius,
        grid_c,
        reach_disc,
        // The largest scene coordinate a grain's centre can have: the f32 rounding it carries.
        corners.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs())) + reach_disc,
        settings,
        spec.count * p_disc,
        cache_bytes,
    )?))
}

/// Each brick's grid: about `generated` particles at `cells_per_particle` cells each, bounded so that
/// building one on every thread at once takes a few MB (`build_brick`).
fn check_brick_cells(cells_per_particle: f64, generated: f64) -> Result<(), OpticsError> {
    let most = MAX_BRICK_CELLS / generated.max(1.0);
    if cells_per_particle > most {
        return Err(OpticsError::OutOfRange {
            argument: CELLS_DRIVER,
            value: cells_per_particle,
            requirement: format!(
                "in (0, {}] for this procedural cloud, whose bricks hold about \
                 {generated:.0} grains each (a brick's grid takes at most {MAX_BRICK_CELLS:e} cells)",
                shown(most)
            ),
        });
    }
    Ok(())
}

impl ProceduralGrains {
    #[allow(clippy::too_many_arguments)]
    fn new(
        spec: &ProceduralSpec,
        to_cloud: [[f64; 4]; 3],
        codes: Vec<u32>,
        cdf: Vec<f64>,
        grid_radius: Vec<f64>,
        grid_c: Vec<f64>,
        reach_scene: f64,
        extent: f64,
        settings: GridSettings,
        expected: f64,
        cache_bytes: usize,
    ) -> Result<Self, OpticsError> {
        if let Some((motion, time)) = &spec.motion {
            // Each grain moves when its brick is built, where no error can be returned: the motion's
            // terms checked here, for the farthest grain the box holds.
            motion.check_reach(extent, *time)?;
        }
        let reach_cloud = cloud_reach(&to_cloud, reach_scene, extent);
        // Tiles are generated as far out as a ball plus the drift can carry a grain into a brick.
        let drift = spec.motion.as_ref().map_or(0.0, |(m, _)| m.drift_bound());
        let gen_reach = cloud_reach(&to_cloud, reach_scene + drift, extent + drift);
        let density = &spec.cloud.density;
        let (lo, hi) = (spec.cloud.lo, spec.cloud.hi);
        let candidates = expected * density.bound() / density.mean(lo, hi);
        let tiling = spec.cloud.tiling(expected);
        let per_tile = candidates / tiling.len() as f64;
        // Tiles a ball reaches across (the halo), and bricks at least twice that wide so that a brick
        // generates at most (1 + 2 halo / brick)³ ≤ 8 times its own particles.
        let halo = [0, 1, 2].map(|a| ((gen_reach[a] / tiling.size[a]).ceil() as usize).max(1));
        let natural = ((BRICK_PARTICLES / per_tile.max(1e-9)).cbrt().round() as usize).clamp(1, 16);
        let per_brick = halo.map(|h| natural.max(2 * h));
        let generated: f64 = (0..3)
            .map(|a| (per_brick[a] + 2 * halo[a]).min(tiling.dims[a]) as f64)
            .product::<f64>()
            * per_tile;
        // Discrete grains whose inclusion balls each hold thousands of others (a powder, not a cloud)
        // would make every brick's grid reference each grain from thousands of cells.
        let volume_scene = (0..3).map(|a| hi[a] - lo[a]).product::<f64>() / det3(&to_cloud).abs();
        let neighbours = candidates / volume_scene * 4.0 / 3.0 * PI * reach_scene.powi(3);
        require(
            "count",
            spec.count,
            generated <= MAX_BRICK_CANDIDATES && neighbours <= MAX_BALL_NEIGHBOURS,
            "low enough that a discrete grain's inclusion ball (its radius in scene units, \
             radius_um x 1e-6 / scale_m, plus query_radius) holds at most 2000 others' centres \
             (and a brick generates at most 10^7 candidates): lower count or query_radius, raise \
             scale_m, or lower continuous_count so that such grains are continuous",
        )?;
        check_brick_cells(settings.cells_per_particle, generated)?;
        // Bricks over tile indices −halo .. dims + halo (a ring of tiles whose own particles are none).
        let dims = [0, 1, 2].map(|a| (tiling.dims[a] + 2 * halo[a]).div_ceil(per_brick[a]));
        let brick_edge = [0, 1, 2].map(|a| tiling.size[a] * per_brick[a] as f64);
        let frame_lo = [0, 1, 2].map(|a| tiling.lo[a] - tiling.size[a] * halo[a] as f64);
        Ok(ProceduralGrains {
            motion: spec.motion.clone(),
            cloud: spec.cloud.clone(),
            per_brick,
            halo,
            frame: GridFrame::new(frame_lo, brick_edge, dims),
            to_scene: spec.transform,
            to_cloud,
            codes,
            cdf,
            grid_radius,
            grid_c,
            reach_cloud,
            settings,
            cache: BrickCache::new(cache_bytes),
            expected,
            tiling,
        })
    }

    /// Expected number of particles (all generated on demand).
    pub fn expected(&self) -> f64 {
        self.expected
    }

    /// Bytes of the bricks cached now.
    pub fn bytes(&self) -> usize {
        self.cache.bytes()
    }

    /// Bricks built so far (cache misses).
    pub fn bricks_built(&self) -> u64 {
        self.cache.built.load(Ordering::Relaxed)
    }

    /// The discrete class of a candidate from its mark number.
    fn class_of(&self, u: f64) -> u32 {
        let k = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.codes.len() - 1);
        self.codes[k]
    }

    /// The particles of tile `t` (linear index, inside the tiling): (cloud-coordinate centre, code, key).
    pub(crate) fn tile_particles(&self, t: usize, mut emit: impl FnMut([f64; 3], u32, u64)) {
        let mut i = 0u64;
        self.cloud.visit_candidates(&self.tiling, t, |centre, u| {
            // Plus one: key 0 is no particle (a site of the continuous field has keys 0).
            let key = (((t as u64) << TILE_INDEX_BITS) | i.min((1 << TILE_INDEX_BITS) - 1)) + 1;
            i += 1;
            emit(centre, self.class_of(u[4]), key);
        });
    }

    fn build_brick(&self, b: [usize; 3]) -> Brick {
        let (pb, h) = (
            self.per_brick.map(|x| x as i64),
            self.halo.map(|x| x as i64),
        );
        let dims = self.tiling.dims.map(|n| n as i64);
        // Tile index range of the brick (shifted by the ring), and its box in cloud coordinates.
        let t0 = [0, 1, 2].map(|a| b[a] as i64 * pb[a] - h[a]);
        let blo = [0, 1, 2].map(|a| self.frame.bounds.lo[a] + self.frame.cell[a] * b[a] as f64);
        let bhi = [0, 1, 2].map(|a| blo[a] + self.frame.cell[a]);
        let m = self.reach_cloud;
        let range = |a: usize| (t0[a] - h[a]).max(0)..(t0[a] + pb[a] + h[a]).min(dims[a]);
        let (mut pos, mut code, mut key) = (Vec::new(), Vec::new(), Vec::new());
        for z in range(2) {
            for y in range(1) {
                for x in range(0) {
                    let t = ((z * dims[1] + y) * dims[0] + x) as usize;
                    self.tile_particles(t, |c, k, id| {
                        let (c, p) = match &self.motion {
                            Some((mo, time)) => {
                                let p = mo.position(apply(&self.to_scene, c), *time);
                                (apply(&self.to_cloud, p), p)
                            }
                            None => (c, apply(&self.to_scene, c)),
                        };
                        if (0..3).all(|a| c[a] >= blo[a] - m[a] && c[a] <= bhi[a] + m[a]) {
                            pos.push(p);
                            code.push(k);
                            key.push(id);
                        }
                    });
                }
            }
        }
        if pos.is_empty() {
            return Brick {
                grid: None,
                code,
                key,
                bytes: 64,
            };
        }
        let radius: Vec<f64> = code.iter().map(|&k| self.grid_radius[k as usize]).collect();
        let c_ext: Vec<f64> = code.iter().map(|&k| self.grid_c[k as usize]).collect();
        // A brick's particles are bounded (`MAX_BRICK_CANDIDATES`) and so are its cells
        // (`MAX_BRICK_CELLS`, checked at load): its grid's memory is a few MB, which a render
        // cannot do without (there is no error path out of a free flight).
        let mut grid = ParticleGrid::from_checked(&pos, &radius, &c_ext, 1, &self.settings)
            .expect("a brick's grid of bounded cells");
        grid.release_stored();
        let bytes = grid.bytes() + code.len() * 12 + 64;
        Brick {
            grid: Some(grid),
            code,
            key,
            bytes,
        }
    }

    fn brick(&self, cell: [usize; 3], index: usize) -> Arc<Brick> {
        self.cache.get(index as u64, || self.build_brick(cell))
    }

    /// The ray in cloud coordinates (the same t: the direction is mapped, not normalised).
    fn cloud_ray(&self, ray: &RaySegment) -> RaySegment {
        RaySegment::new(
            apply(&self.to_cloud, ray.o),
            apply_linear(&self.to_cloud, ray.d),
            ray.t0,
            ray.t1,
        )
    }

    /// Each brick the ray crosses, in order, with the part of the ray inside it; `visit` returns false
    /// to stop.
    fn bricks_along(&self, ray: &RaySegment, mut visit: impl FnMut(&Brick, RaySegment) -> bool) {
        if ray.is_empty() {
            return;
        }
        for c in Dda::new(&self.frame, &self.cloud_ray(ray)) {
            let brick = self.brick(c.cell, c.index);
            if brick.grid.is_some() && !visit(&brick, ray.between(c.t_enter, c.t_exit)) {
                return;
            }
        }
    }

    /// Exact free flight to the next site (as [`ParticleGrid::sample_site`]), skipping the particles
    /// whose keys are in `exclude`. Members are class codes with [`CLASS_FLAG`], keys in `Site::keys`.
    pub fn sample_site(
        &self,
        ray: &RaySegment,
        exclude: &[u64],
        u: f64,
        coincide: f64,
    ) -> (Option<Site>, f64) {
        let mut w = SiteWalk::new(u, exclude, coincide);
        self.bricks_along(ray, |b, seg| {
            let g = b.grid.as_ref().expect("non-empty brick");
            g.walk(&seg, |t, tau, i| {
                w.offer(
                    t,
                    tau[0] as f64,
                    CLASS_FLAG | b.code[i as usize],
                    b.key[i as usize],
                )
            });
            // A group still open at the brick's end may continue in the next brick (particles within
            // `coincide` of each other across a brick face are one site, as in one grid).
            w.found.is_none()
        });
        if w.found.is_none() {
            w.close();
        }
        (w.found, w.acc)
    }

    /// Grey optical depth of a segment.
    pub fn optical_depth(&self, ray: &RaySegment) -> f64 {
        let mut total = 0.0;
        self.bricks_along(ray, |b, seg| {
            let mut v = [0.0];
            b.grid
                .as_ref()
                .expect("non-empty brick")
                .optical_depth(&seg, &mut v);
            total += v[0];
            true
        });
        total
    }

    /// Every contributing particle with t in the segment, in t order: `visit(t, τ, member, key)`.
    pub fn walk(&self, ray: &RaySegment, mut visit: impl FnMut(f64, f64, u32, u64) -> bool) {
        let mut go = true;
        self.bricks_along(ray, |b, seg| {
            b.grid
                .as_ref()
                .expect("non-empty brick")
                .walk(&seg, |t, tau, i| {
                    go = visit(
                        t,
                        tau[0] as f64,
                        CLASS_FLAG | b.code[i as usize],
                        b.key[i as usize],
                    );
                    go
                });
            go
        });
    }

    /// Members (class codes with [`CLASS_FLAG`]) of the particles whose inclusion ball holds `p`.
    pub fn containing(&self, p: [f64; 3]) -> Vec<u32> {
        let q = apply(&self.to_cloud, p);
        let GridFrame { bounds, cell, dims } = &self.frame;
        let mut c = [0usize; 3];
        for a in 0..3 {
            let x = (q[a] - bounds.lo[a]) / cell[a];
            if !(x >= 0.0 && x < dims[a] as f64) {
                return Vec::new();
            }
            c[a] = x as usize;
        }
        let index = (c[2] * dims[1] + c[1]) * dims[0] + c[0];
        let b = self.brick(c, index);
        b.grid.as_ref().map_or_else(Vec::new, |g| {
            g.containing(p)
                .into_iter()
                .map(|i| CLASS_FLAG | b.code[i as usize])
                .collect()
        })
    }

    /// Tiles of the discrete process.
    pub fn tiles(&self) -> usize {
        self.tiling.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ensemble::psd::Psd;
    use crate::render::discrete::particle_disk;
    use crate::space::cloud::Density;
    use crate::test_rng::lcg;

    /// A cloud of `count` grains (log-normal, median `median_um`) over [0, 1]³ mapped by a rotation
    /// about z, a scale of 2 and a shift; one species, four bins.
    fn spec(count: f64, median_um: f64, density: Density) -> ProceduralSpec {
        let psd = Psd::LogNormal {
            median_um,
            sigma_g: 1.5,
            r_min_um: median_um / 8.0,
            r_max_um: median_um * 8.0,
        };
        let (lo, hi) = psd.support();
        let edges = (0..=4)
            .map(|i| lo * (hi / lo).powf(i as f64 / 4.0))
            .collect();
        let (c, s) = (0.6f64, 0.8f64);
        ProceduralSpec {
            cloud: CloudSpec {
                lo: [0.0; 3],
                hi: [1.0; 3],
                density,
                species: vec![(1.0, psd)],
                seed: 7,
            },
            count,
            transform: [
                [2.0 * c, -2.0 * s, 0.0, 0.3],
                [2.0 * s, 2.0 * c, 0.0, -0.1],
                [0.0, 0.0, 2.0, 0.5],
            ],
            scene_per_um: 1e-6,
            bin_edges_um: vec![edges],
            first_bin: vec![0],
            q_ext: vec![2.0; 4],
            motion: None,
        }
    }

    fn parts(spec: &ProceduralSpec, qr: f64, cc: f64, cache: usize) -> ProceduralParts {
        build_parts(
            spec,
            |r, c| particle_disk(r, c, qr, 1.0),
            qr,
            0.125,
            cc,
            cache,
        )
        .unwrap()
    }

    /// Random rays through the cloud's scene box (unit directions).
    fn rays(s: &mut u64, n: usize) -> Vec<RaySegment> {
        (0..n)
            .map(|_| {
                let o = [lcg(s) * 3.0 - 1.5, lcg(s) * 3.0 - 0.5, -1.0];
                let d = [lcg(s) - 0.5, lcg(s) - 0.5, 1.0];
                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                RaySegment::new(o, d.map(|x| x / l), lcg(s) * 0.5, 4.0 + lcg(s))
            })
            .collect()
    }

    /// The brick walk visits exactly the particles a loop over every tile finds on the ray (once each,
    /// in t order, with their disks' τ), whatever the cache keeps: a budget of one brick gives the
    /// same walk.
    #[test]
    fn bricks_walk_every_particle_once_in_order() {
        // Balls narrower than a tile (halo 1), and balls wider than a tile (halo 2).
        // The third: a sheared, non-uniformly scaled box (per-axis reach in the cloud's coordinates).
        // The fourth: grains moved by a turbulent drift (wider halos; the brute force moves them too).
        for (count, qr, halo, shear, drift) in [
            (3000.0, 0.01, 1, false, 0.0),
            (30_000.0, 0.3, 2, false, 0.0),
            (3000.0, 0.01, 1, true, 0.0),
            (3000.0, 0.01, 0, false, 0.02),
        ] {
            let mut sp = spec(count, 20_000.0, Density::Uniform);
            if drift > 0.0 {
                sp.motion = Some((Motion::new([0.0; 3], drift, 0.5, 9).unwrap(), 1.7));
            }
            if shear {
                sp.transform = [
                    [3.0, 0.8, 0.0, 0.1],
                    [0.0, 0.7, 0.4, 0.0],
                    [0.2, 0.0, 1.5, 0.3],
                ];
            }
            for cache in [DEFAULT_CACHE_BYTES, 1] {
                let p = parts(&sp, qr, f64::INFINITY, cache);
                let g = p.grains.as_ref().unwrap();
                assert!(g.per_brick.iter().all(|&b| b >= 2) && g.tiles() > 1);
                if !shear && drift == 0.0 {
                    assert_eq!(*g.halo.iter().max().unwrap(), halo);
                }
                let mut all = Vec::new();
                for t in 0..g.tiles() {
                    g.tile_particles(t, |c, k, key| {
                        let p = apply(&g.to_scene, c);
                        let p = sp
                            .motion
                            .as_ref()
                            .map_or(p, |(m, time)| m.position(p, *time));
                        all.push((p, k, key))
                    });
                }
                assert!((all.len() as f64 - count).abs() < 5.0 * count.sqrt());
                assert!(all.iter().all(|p| p.2 > 0), "key 0 is no particle");
                let mut s = 3u64;
                for ray in rays(&mut s, 60) {
                    let mut want: Vec<(f64, u64)> = all
                        .iter()
                        .filter_map(|&(c, k, key)| {
                            let v = [0, 1, 2].map(|a| c[a] - ray.o[a]);
                            let t = v[0] * ray.d[0] + v[1] * ray.d[1] + v[2] * ray.d[2];
                            let dd = v.iter().map(|x| x * x).sum::<f64>() - t * t;
                            let r = g.grid_radius[k as usize] + qr;
                            (dd < r * r && ray.contains(t)).then_some((t, key))
                        })
                        .collect();
                    want.sort_by(|a, b| a.0.total_cmp(&b.0));
                    let mut got = Vec::new();
                    g.walk(&ray, |t, tau, _, key| {
                        assert!(tau > 0.0);
                        got.push((t, key));
                        true
                    });
                    assert_eq!(got.len(), want.len());
                    for (a, b) in got.iter().zip(&want) {
                        assert_eq!(a.1, b.1);
                        assert!((a.0 - b.0).abs() < 1e-5);
                    }
                }
            }
        }
    }

    /// The same cloud built twice gives the same particles on every ray (nothing depends on the
    /// order bricks are built in), and a site found excludes by key.
    #[test]
    fn reproducible_and_sites_exclude_their_particles() {
        let sp = spec(3000.0, 20_000.0, Density::Uniform);
        let a = parts(&sp, 0.01, f64::INFINITY, DEFAULT_CACHE_BYTES);
        let b = parts(&sp, 0.01, f64::INFINITY, 1);
        let (ga, gb) = (a.grains.unwrap(), b.grains.unwrap());
        let mut s = 5u64;
        let rs = rays(&mut s, 40);
        for ray in rs.iter().rev() {
            assert_eq!(ga.optical_depth(ray), gb.optical_depth(ray));
        }
        for ray in &rs {
            let u = lcg(&mut s);
            let (site, acc) = ga.sample_site(ray, &[], u, 1e-9);
            assert_eq!((site, acc), gb.sample_site(ray, &[], u, 1e-9));
            if let Some(site) = site {
                let keys = &site.keys[..site.len as usize];
                let (next, _) = ga.sample_site(ray, keys, u, 1e-9);
                if let Some(n) = next {
                    assert!(n.keys[..n.len as usize].iter().all(|k| !keys.contains(k)));
                    assert!(n.t >= site.t);
                }
            }
        }
    }

    /// Over random rays the mean transmittance is Beer–Lambert with the distribution's σ_t (each disk
    /// removes C_t: the procedural process has the right density of the right classes), for a
    /// uniform and a gradient density; the continuous classes' field carries the same σ_t.
    #[test]
    fn mean_transmittance_is_beer_lambert() {
        for density in [Density::Uniform, Density::gradient(2, 0.0, 2.0).unwrap()] {
            let sp = spec(20_000.0, 10_000.0, density.clone());
            let p = parts(&sp, 0.005, f64::INFINITY, DEFAULT_CACHE_BYTES);
            let g = p.grains.as_ref().unwrap();
            let volume = 8.0;
            let n_c: f64 = p
                .classes
                .iter()
                .map(|c| sp.count * c.p * c.c_ext)
                .sum::<f64>()
                / volume;
            // Rays along z through the box at random (x, y): length 2 in scene units; the gradient's
            // density is 2 z over the box's height, mean 1, so the same σ_t on average along z.
            let mut s = 17u64;
            let trials = 4000;
            let mut sum = 0.0;
            let mut sq = 0.0;
            for _ in 0..trials {
                let q = [0.05 + 0.9 * lcg(&mut s), 0.05 + 0.9 * lcg(&mut s), -0.5];
                let o = apply(&sp.transform, q);
                let ray = RaySegment::new(o, [0.0, 0.0, 1.0], 0.0, 3.0);
                let tr = (-g.optical_depth(&ray)).exp();
                sum += tr;
                sq += tr * tr;
            }
            let mean = sum / trials as f64;
            let se = ((sq / trials as f64 - mean * mean) / trials as f64).sqrt();
            let want = (-n_c * 2.0).exp();
            assert!((mean - want).abs() < 4.0 * se, "{mean} vs {want} (se {se})");
            // The all-classes field: σ_t L along the same rays.
            let ray = RaySegment::new(
                apply(&sp.transform, [0.5, 0.5, -0.5]),
                [0.0, 0.0, 1.0],
                0.0,
                3.0,
            );
            let tau = p.all_field.optical_depth(&ray);
            assert!(
                (tau / (n_c * 2.0) - 1.0).abs() < 0.02,
                "{tau} vs {}",
                n_c * 2.0
            );
        }
    }

    /// A dense cloud of small grains is all continuous; with an infinite threshold all discrete; the
    /// class probabilities sum to 1.
    #[test]
    fn continuous_split_and_class_table() {
        let sp = spec(1e9, 5.0, Density::Uniform);
        let p = parts(&sp, 0.001, 16.0, DEFAULT_CACHE_BYTES);
        assert!(p.grains.is_none() && p.field.is_some());
        assert!((p.field_count / 1e9 - 1.0).abs() < 1e-9);
        let total: f64 = p.classes.iter().map(|c| c.p).sum();
        assert!((total - 1.0).abs() < 1e-9, "{total}");
        let sp = spec(2000.0, 5.0, Density::Uniform);
        let p = parts(&sp, 0.001, f64::INFINITY, DEFAULT_CACHE_BYTES);
        assert!(p.grains.is_some() && p.field.is_none());
        let refused = |sp: &ProceduralSpec| {
            build_parts(
                sp,
                |r, c| particle_disk(r, c, 0.0, 1.0),
                0.0,
                0.125,
                16.0,
                1,
            )
            .err()
            .unwrap()
            .to_string()
        };
        let mut flat = spec(10.0, 5.0, Density::Uniform);
        flat.cloud.hi[1] = flat.cloud.lo[1];
        assert!(refused(&flat).contains("hi"));
        let mut bad = spec(10.0, 5.0, Density::Uniform);
        bad.count = 0.0;
        assert!(refused(&bad).contains("count"));
    }
}
