//! Generated particle clouds (issue 24): centres in a box after a relative density (uniform, a linear
//! gradient, fBm value noise), each particle's species by its share and its radius from the species'
//! size distribution — reproducible from a seed whatever the thread count, and generated **tile by
//! tile**, so that any tile can be generated alone, the same every time (what a procedural cloud that
//! stores no particles needs, and what a distributed render needs: the same grains on every machine).
//!
//! ## The process
//! The box is cut into tiles of about [`CANDIDATES_PER_TILE`] candidates. Tile t draws its candidate
//! count K_t ~ Poisson(Λ |t| · bound) from its own stream (xoshiro256++ seeded from (seed, t)),
//! places each candidate uniformly in the tile and keeps it with probability d(x) / bound (thinning):
//! the kept centres are a Poisson process of intensity Λ d(x), exactly, with no integral of d per tile.
//! Each candidate consumes the same seven numbers of its tile's stream whether it is kept or not, so a
//! tile's particles depend on nothing but (seed, tile).
//!
//! A stored cloud of exactly N particles: a process of mean N' slightly above N (6 σ), then M − N of
//! its M particles dropped uniformly at random (Floyd's sampling of their indices). Given M, a Poisson
//! process's points are independent draws from d / ∫d, and a uniformly random subset of independent
//! draws is again independent draws: the N particles are N independent draws from the density, exactly
//! what a rejection sampler gives, but built in two parallel passes over the tiles (count, then write)
//! straight into the output arrays, in tile order (spatially coherent, which the grid build likes).
//!
//! Infrastructure for paper Sec. 5 (particle sets "generated or loaded"); no equation of its own.

use crate::ensemble::psd::{Psd, RadiusSampler};
use crate::error::{require, OpticsError};
use crate::rng::{splitmix64, unit_f64};
use rand_distr::{Distribution, Poisson};
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::sync::Arc;

/// Expected candidates per tile: enough that a tile's fixed cost (a stream, a Poisson draw) is small
/// against its particles, few enough that a procedural cloud generates little it does not need.
pub const CANDIDATES_PER_TILE: f64 = 64.0;
/// Numbers of a tile's stream each candidate consumes: 3 position, 1 thinning, 1 species, 2 radius.
pub(crate) const DRAWS_PER_CANDIDATE: usize = 7;
/// Stream tags, so that the tiles', the drops' and the noise's numbers never coincide.
pub(crate) const TILE_STREAM: u64 = 0x7469_6C65;
const DROP_STREAM: u64 = 0x6472_6F70;
const NOISE_STREAM: u64 = 0x006E_6F69_7365;
/// Standard deviations of the oversampled process's count kept above N.
const MARGIN_SIGMAS: f64 = 6.0;
/// Midpoints per axis of the mean-density estimate of a noise density.
const MEAN_POINTS_PER_AXIS: usize = 32;
/// Largest ratio of a density's largest value to its mean over the box (candidates per particle).
const MAX_CONCENTRATION: f64 = 1.0e4;
/// Most tiles of a stored cloud (a u32 count each).
const MAX_TILES: f64 = 4.0e9;

/// Smooth procedural fBm value noise, v(x) ∈ [0, 1]: the weight-normalised sum of `octaves` octaves of
/// value noise (lattice values hashed from the integer cell and the seed, quintic smoothstep between
/// them, so C²), octave o with lattice spacing `scale` / 2^o and weight 2^−o, each octave's lattice
/// shifted by its own random offset. As a density: max(0, 1 + contrast (2v − 1)).
#[derive(Clone, Debug)]
pub struct ValueNoise {
    scale: f64,
    contrast: f64,
    offsets: Vec<[f64; 3]>,
    /// Each octave's lattice hash seed (computed once, not per evaluation).
    bases: Vec<u64>,
}

impl ValueNoise {
    pub fn new(scale: f64, octaves: u32, seed: u64, contrast: f64) -> Result<Self, OpticsError> {
        require(
            "scale",
            scale,
            scale.is_finite() && scale > 0.0,
            "finite and > 0",
        )?;
        require(
            "octaves",
            octaves as f64,
            (1..=16).contains(&octaves),
            "in [1, 16]",
        )?;
        require(
            "contrast",
            contrast,
            contrast.is_finite() && contrast >= 0.0,
            "finite and >= 0",
        )?;
        let offsets = (0..octaves as u64)
            .map(|o| {
                [0u64, 1, 2]
                    .map(|a| unit_f64(splitmix64(seed ^ splitmix64(NOISE_STREAM ^ (3 * o + a)))))
            })
            .collect();
        let bases = (0..octaves as u64)
            .map(|o| splitmix64(seed ^ (o + 1)))
            .collect();
        Ok(ValueNoise {
            scale,
            contrast,
            offsets,
            bases,
        })
    }

    /// (scale, contrast, each octave's lattice offset and hash seed): what a re-implementation of
    /// [`Self::value`] needs (`crate::render::procedural::export`).
    pub(crate) fn terms(&self) -> (f64, f64, &[[f64; 3]], &[u64]) {
        (self.scale, self.contrast, &self.offsets, &self.bases)
    }

    /// v(x) ∈ [0, 1].
    pub fn value(&self, p: [f64; 3]) -> f64 {
        let (mut total, mut weights) = (0.0, 0.0);
        for (o, (off, &base)) in self.offsets.iter().zip(&self.bases).enumerate() {
            let f = (1u64 << o) as f64 / self.scale;
            let q = [0, 1, 2].map(|a| p[a] * f + off[a]);
            let i = q.map(f64::floor);
            let w = [0, 1, 2].map(|a| quintic(q[a] - i[a]));
            let cell = i.map(|x| x as i64 as u64);
            let mut acc = 0.0;
            for corner in 0..8u64 {
                let c = [0, 1, 2].map(|a| (corner >> a) & 1);
                let h = splitmix64(
                    splitmix64(
                        splitmix64(base ^ cell[0].wrapping_add(c[0])) ^ cell[1].wrapping_add(c[1]),
                    ) ^ cell[2].wrapping_add(c[2]),
                );
                let wt: f64 = (0..3)
                    .map(|a| if c[a] == 1 { w[a] } else { 1.0 - w[a] })
                    .product();
                acc += wt * unit_f64(h);
            }
            let weight = 0.5f64.powi(o as i32);
            total += weight * acc;
            weights += weight;
        }
        (total / weights).clamp(0.0, 1.0)
    }

    /// The relative density 1 + contrast (2v − 1), clipped to [0, 1 + contrast].
    pub fn density(&self, p: [f64; 3]) -> f64 {
        (1.0 + self.contrast * (2.0 * self.value(p) - 1.0)).clamp(0.0, 1.0 + self.contrast)
    }
}

/// 6t⁵ − 15t⁴ + 10t³: zero first and second derivatives at 0 and 1.
fn quintic(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// A relative number density over the cloud's box (any positive scale).
#[derive(Clone, Debug)]
pub enum Density {
    Uniform,
    /// `start` on the box's low face along `axis`, linearly to `end` on its high face.
    Gradient {
        axis: usize,
        start: f64,
        end: f64,
    },
    Noise(ValueNoise),
    /// Values on a grid over the box, interpolated trilinearly between cell centres and clamped at the
    /// faces (Mitsuba's `gridvolume`: a `heterogeneous` medium's density, issue 43).
    Grid(Arc<DensityGrid>),
}

/// A density sampled on a grid of `dims` cells over the box, x fastest (Mitsuba's volume layout).
#[derive(Clone, Debug, PartialEq)]
pub struct DensityGrid {
    dims: [usize; 3],
    values: Vec<f32>,
    max: f64,
    mean: f64,
}

impl DensityGrid {
    pub fn new(dims: [usize; 3], values: Vec<f32>) -> Result<Self, OpticsError> {
        let cells = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
        require(
            "density grid cells",
            values.len() as f64,
            dims.iter().all(|&d| d >= 1) && cells == Some(values.len()),
            "nx * ny * nz values, each dimension >= 1",
        )?;
        let (mut max, mut sum) = (0.0f64, 0.0f64);
        for &v in &values {
            require(
                "density grid value",
                v as f64,
                v.is_finite() && v >= 0.0,
                "finite and >= 0",
            )?;
            max = max.max(v as f64);
            sum += v as f64;
        }
        // The trilinear interpolant of cell-centred values clamped at the faces integrates to the
        // values' mean: along each axis every value's hat covers one cell (the end cells' halves
        // beyond their centres are flat).
        let mean = sum / values.len() as f64;
        Ok(DensityGrid {
            dims,
            values,
            max,
            mean,
        })
    }

    fn value(&self, i: [usize; 3]) -> f64 {
        self.values[i[0] + self.dims[0] * (i[1] + self.dims[1] * i[2])] as f64
    }

    /// The interpolated density at `p` in the box [lo, hi].
    fn at(&self, p: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut f = [0.0f64; 3];
        for a in 0..3 {
            let n = self.dims[a];
            let u = ((p[a] - lo[a]) / (hi[a] - lo[a]) * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
            let k = (u.floor() as usize).min(n - 1);
            i0[a] = k;
            i1[a] = (k + 1).min(n - 1);
            f[a] = u - k as f64;
        }
        let mut acc = 0.0;
        for corner in 0..8 {
            let b = [0, 1, 2].map(|a| corner >> a & 1 == 1);
            let idx = [0, 1, 2].map(|a| if b[a] { i1[a] } else { i0[a] });
            let w: f64 = (0..3)
                .map(|a| if b[a] { f[a] } else { 1.0 - f[a] })
                .product();
            if w > 0.0 {
                acc += w * self.value(idx);
            }
        }
        acc
    }
}

impl Density {
    pub fn gradient(axis: usize, start: f64, end: f64) -> Result<Self, OpticsError> {
        require("axis", axis as f64, axis < 3, "0, 1 or 2")?;
        for (name, v) in [("start", start), ("end", end)] {
            require(name, v, v.is_finite() && v >= 0.0, "finite and >= 0")?;
        }
        require(
            "end",
            end,
            start + end > 0.0,
            "> 0 where start is 0 (a zero density)",
        )?;
        // A relative density: scaled to a largest value of 1, so that its mean over the box
        // ((start + end) / 2) cannot overflow (start = end = 1e308).
        let largest = start.max(end);
        Ok(Density::Gradient {
            axis,
            start: start / largest,
            end: end / largest,
        })
    }

    /// The (relative) density at `p` in the cloud's box [lo, hi], as the generator draws by it.
    pub fn at(&self, p: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
        match self {
            Density::Uniform => 1.0,
            Density::Gradient { axis, start, end } => {
                let t = ((p[*axis] - lo[*axis]) / (hi[*axis] - lo[*axis])).clamp(0.0, 1.0);
                start + (end - start) * t
            }
            Density::Noise(n) => n.density(p),
            Density::Grid(g) => g.at(p, lo, hi),
        }
    }

    /// The density's largest value (the thinning bound).
    pub(crate) fn bound(&self) -> f64 {
        match self {
            Density::Uniform => 1.0,
            Density::Gradient { start, end, .. } => start.max(*end),
            Density::Noise(n) => 1.0 + n.contrast,
            Density::Grid(g) => g.max,
        }
    }

    /// The density's mean over the box: exact for the uniform, linear and grid ones, a midpoint rule over
    /// [`MEAN_POINTS_PER_AXIS`]³ points for noise (it sets only the expected count, see `Cloud`).
    pub(crate) fn mean(&self, lo: [f64; 3], hi: [f64; 3]) -> f64 {
        match self {
            Density::Uniform => 1.0,
            Density::Gradient { start, end, .. } => 0.5 * (start + end),
            Density::Grid(g) => g.mean,
            Density::Noise(_) => {
                let m = MEAN_POINTS_PER_AXIS;
                let sum: f64 = (0..m * m * m)
                    .into_par_iter()
                    .map(|k| {
                        let idx = [k % m, (k / m) % m, k / (m * m)];
                        let p = [0, 1, 2]
                            .map(|a| lo[a] + (hi[a] - lo[a]) * (idx[a] as f64 + 0.5) / m as f64);
                        self.at(p, lo, hi)
                    })
                    .sum();
                sum / (m * m * m) as f64
            }
        }
    }
}

/// What a cloud is made of: its box, density, species (share, size distribution) and seed.
#[derive(Clone, Debug)]
pub struct CloudSpec {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    pub density: Density,
    pub species: Vec<(f64, Psd)>,
    pub seed: u64,
}

/// One generated particle: centre (the spec's coordinates), radius (µm) and species index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grain {
    pub centre: [f64; 3],
    pub radius_um: f64,
    pub species: u32,
}

/// The tiles of a cloud of a given expected count: how the box is cut and each tile's mean number of
/// candidates.
#[derive(Clone, Debug)]
pub struct Tiling {
    pub dims: [usize; 3],
    pub(crate) lo: [f64; 3],
    pub(crate) size: [f64; 3],
    /// Poisson mean of each tile's candidate count.
    candidates: f64,
}

impl Tiling {
    /// Poisson mean of each tile's candidate count.
    pub(crate) fn candidates(&self) -> f64 {
        self.candidates
    }
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub(crate) fn tile_lo(&self, t: usize) -> [f64; 3] {
        let d = self.dims;
        let idx = [t % d[0], (t / d[0]) % d[1], t / (d[0] * d[1])];
        [0, 1, 2].map(|a| self.lo[a] + self.size[a] * idx[a] as f64)
    }
}

impl CloudSpec {
    pub(crate) fn check(&self) -> Result<(), OpticsError> {
        for a in 0..3 {
            require("lo", self.lo[a], self.lo[a].is_finite(), "finite")?;
            require(
                "hi",
                self.hi[a],
                self.hi[a].is_finite() && self.hi[a] > self.lo[a],
                "finite and > lo",
            )?;
        }
        require(
            "species (count)",
            self.species.len() as f64,
            !self.species.is_empty(),
            ">= 1",
        )?;
        for (share, _) in &self.species {
            require(
                "share",
                *share,
                share.is_finite() && *share >= 0.0,
                "finite and >= 0",
            )?;
        }
        let largest = self.species.iter().map(|s| s.0).fold(0.0, f64::max);
        require(
            "share",
            largest,
            largest > 0.0,
            "> 0 for at least one species",
        )
    }

    /// Each species' fraction of the particles ([`crate::ensemble::share_fractions`]).
    pub(crate) fn share_fractions(&self) -> Vec<f64> {
        crate::ensemble::share_fractions(&self.species.iter().map(|s| s.0).collect::<Vec<_>>())
    }

    /// The tiles of a Poisson cloud of `expected` particles (about [`CANDIDATES_PER_TILE`] candidates
    /// each, cut in proportion to the box's sides).
    pub fn tiling(&self, expected: f64) -> Tiling {
        self.tiling_at_least(expected, 0.0, CANDIDATES_PER_TILE)
    }

    /// [`Self::tiling`] with tiles of about `per_tile` candidates and no edge shorter than `min_edge`
    /// where the box is that wide (a procedural cloud's tiles must be at least as wide as a particle's
    /// inclusion ball: `crate::render::procedural`).
    pub(crate) fn tiling_at_least(&self, expected: f64, min_edge: f64, per_tile: f64) -> Tiling {
        let ext = [0, 1, 2].map(|a| self.hi[a] - self.lo[a]);
        let candidates = expected * self.density.bound() / self.density.mean(self.lo, self.hi);
        let tiles = (candidates / per_tile).clamp(1.0, MAX_TILES);
        // Cubes of equal volume where the box allows; an axis thinner than a cube's edge gets one tile
        // and the others share the count (a 1e-6 x 1e6 x 1e6 box must not make 1e9 tiles of 47).
        let mut dims = [1usize; 3];
        let mut free: Vec<usize> = (0..3).collect();
        loop {
            let area: f64 = free.iter().map(|&a| ext[a]).product();
            let edge = (area / tiles).powf(1.0 / free.len() as f64);
            let thin: Vec<usize> = free.iter().copied().filter(|&a| ext[a] < edge).collect();
            if thin.is_empty() || thin.len() == free.len() {
                for &a in &free {
                    dims[a] = ((ext[a] / edge).round() as usize).max(1);
                    if min_edge > 0.0 {
                        dims[a] = dims[a].min(((ext[a] / min_edge) as usize).max(1));
                    }
                }
                break;
            }
            free.retain(|a| !thin.contains(a));
        }
        let n = (dims[0] * dims[1] * dims[2]) as f64;
        Tiling {
            dims,
            lo: self.lo,
            size: [0, 1, 2].map(|a| ext[a] / dims[a] as f64),
            candidates: candidates / n,
        }
    }

    /// Each species' radius sampler, prepared once for every tile ([`Self::visit_tile`]).
    pub(crate) fn samplers(&self) -> Vec<RadiusSampler<'_>> {
        self.species.iter().map(|s| s.1.sampler()).collect()
    }

    /// The particles of tile `t`, in order, as `emit(grain)` with radii from `samplers` (None: only
    /// counted, the species and radius are not computed). Returns how many there are.
    pub(crate) fn visit_tile(
        &self,
        tiling: &Tiling,
        t: usize,
        samplers: Option<&[RadiusSampler]>,
        mut emit: impl FnMut(Grain),
    ) -> usize {
        let fractions = self.share_fractions();
        self.visit_candidates(tiling, t, |centre, u| {
            if let Some(samplers) = samplers {
                let species = pick_species(&fractions, u[4]);
                let radius_um = samplers[species].draw(u[5], u[6]);
                emit(Grain {
                    centre,
                    radius_um,
                    species: species as u32,
                });
            }
        })
    }

    /// The kept candidates of tile `t`, in order, as `emit(centre, u)` with `u` the candidate's numbers
    /// (`u[4..7]` unused by the placement: the marks a caller draws from). Returns how many there are.
    pub(crate) fn visit_candidates(
        &self,
        tiling: &Tiling,
        t: usize,
        mut emit: impl FnMut([f64; 3], &[f64; DRAWS_PER_CANDIDATE]),
    ) -> usize {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(splitmix64(
            self.seed ^ splitmix64(TILE_STREAM ^ t as u64),
        ));
        let k = if tiling.candidates > 0.0 {
            Poisson::new(tiling.candidates).map_or(0, |p| p.sample(&mut rng) as u64)
        } else {
            0
        };
        let (lo, size) = (tiling.tile_lo(t), tiling.size);
        let bound = self.density.bound();
        let uniform = matches!(self.density, Density::Uniform);
        let mut kept = 0;
        for _ in 0..k {
            let mut u = [0f64; DRAWS_PER_CANDIDATE];
            for x in u.iter_mut() {
                *x = (((rng.next_u64() >> 11) as f64) + 0.5) / (1u64 << 53) as f64;
            }
            let centre = [0, 1, 2].map(|a| lo[a] + size[a] * u[a]);
            if !uniform && u[3] * bound >= self.density.at(centre, self.lo, self.hi) {
                continue;
            }
            kept += 1;
            emit(centre, &u);
        }
        kept
    }
}

/// The species whose interval of the fractions ([`CloudSpec::share_fractions`]) holds u.
fn pick_species(fractions: &[f64], u: f64) -> usize {
    let mut acc = 0.0;
    for (i, f) in fractions.iter().enumerate() {
        acc += f;
        if u < acc {
            return i;
        }
    }
    fractions.iter().rposition(|&f| f > 0.0).unwrap_or(0)
}

/// A stored cloud: N particles in tile order, centres mapped by `transform` (3×4, row-major: x' = A x + b).
#[derive(Debug, Default)]
pub struct Cloud {
    pub centres: Vec<[f64; 3]>,
    pub radius_um: Vec<f64>,
    pub species: Vec<u32>,
}

/// The identity as a 3×4 transform.
pub const IDENTITY: [[f64; 4]; 3] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
];

/// x' = A x + b for a 3×4 affine map.
pub fn apply(m: &[[f64; 4]; 3], p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
}

/// Determinant of an affine map's linear part.
pub fn det3(m: &[[f64; 4]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// The inverse of an affine map (3×4), or None when singular.
#[allow(clippy::needless_range_loop)] // cofactors index rows and columns together
pub fn invert_affine(m: &[[f64; 4]; 3]) -> Option<[[f64; 4]; 3]> {
    let a = |r: usize, c: usize| m[r][c];
    let det = det3(m);
    if !(det.abs() > 0.0 && det.is_finite()) {
        return None;
    }
    let mut inv = [[0.0; 4]; 3];
    for r in 0..3 {
        for c in 0..3 {
            // Cofactor (c, r) / det.
            let (r1, r2) = ((c + 1) % 3, (c + 2) % 3);
            let (c1, c2) = ((r + 1) % 3, (r + 2) % 3);
            inv[r][c] = (a(r1, c1) * a(r2, c2) - a(r1, c2) * a(r2, c1)) / det;
        }
    }
    let t = [m[0][3], m[1][3], m[2][3]];
    for r in 0..3 {
        inv[r][3] = -(inv[r][0] * t[0] + inv[r][1] * t[1] + inv[r][2] * t[2]);
    }
    Some(inv)
}

/// Indices, sorted, of `d` distinct numbers of 0..m drawn uniformly (Floyd's algorithm: d draws).
fn dropped(m: u64, d: u64, seed: u64) -> Vec<u64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(splitmix64(seed ^ DROP_STREAM));
    let mut set = rustc_hash::FxHashSet::default();
    for j in m - d..m {
        let t = rng.next_u64() % (j + 1); // bias below 2^-40 for j < 2^24; irrelevant beyond
        if !set.insert(t) {
            set.insert(j);
        }
    }
    let mut v: Vec<u64> = set.into_iter().collect();
    v.sort_unstable();
    v
}

/// Exactly `count` particles of `spec` (module docs), centres through `transform`.
pub fn generate(
    spec: &CloudSpec,
    count: u64,
    transform: &[[f64; 4]; 3],
) -> Result<Cloud, OpticsError> {
    spec.check()?;
    require("count", count as f64, count >= 1, ">= 1")?;
    for row in transform {
        for &x in row {
            require("transform", x, x.is_finite(), "finite")?;
        }
    }
    let (tiling, counts, m) = candidates(spec, count)?;
    let drop = dropped(m, m - count, spec.seed);
    let mut cloud = Cloud {
        centres: vec![[0.0; 3]; count as usize],
        radius_um: vec![0.0; count as usize],
        species: vec![0; count as usize],
    };
    place(spec, &tiling, &counts, &drop, transform, &mut cloud);
    Ok(cloud)
}

/// The tiling of `spec`'s candidates, each tile's candidate count and their total, at least `count`.
fn candidates(spec: &CloudSpec, count: u64) -> Result<(Tiling, Vec<u32>, u64), OpticsError> {
    let n = count as f64;
    // The density must be positive somewhere, and not so concentrated that candidates outnumber the
    // particles by more than MAX_CONCENTRATION (a noise carved to nothing over the box).
    let (bound, mean) = (spec.density.bound(), spec.density.mean(spec.lo, spec.hi));
    require(
        "density",
        mean,
        mean > 0.0 && bound / mean <= MAX_CONCENTRATION,
        "positive over enough of the box (its mean at least 1e-4 of its largest value)",
    )?;
    // A noise density's mean is estimated: 1 % more covers its error; a shortfall (a 6-sigma one, or
    // the estimate's) is made up by asking again for proportionally more.
    let slack = if matches!(spec.density, Density::Noise(_)) {
        1.01
    } else {
        1.0
    };
    let mut expected = (n + MARGIN_SIGMAS * n.sqrt() + 20.0) * slack;
    let mut attempt = 0;
    loop {
        let tiling = spec.tiling(expected);
        require(
            "count",
            n,
            (tiling.len() as f64) < MAX_TILES,
            "small enough for 4e9 tiles",
        )?;
        let counts: Vec<u32> = (0..tiling.len())
            .into_par_iter()
            .map(|t| spec.visit_tile(&tiling, t, None, |_| {}) as u32)
            .collect();
        let m: u64 = counts.iter().map(|&c| c as u64).sum();
        if m >= count {
            return Ok((tiling, counts, m));
        }
        attempt += 1;
        require(
            "density",
            attempt as f64,
            attempt < 8,
            "a density whose mean can be estimated",
        )?;
        expected *= 1.05 * n / (m.max(1) as f64);
        expected += MARGIN_SIGMAS * n.sqrt() + 20.0;
    }
}

/// The candidates of `tiling` (`counts` per tile) but the `drop`ped ones (global indices, sorted) into
/// `cloud`, centres through `transform`, in tile order.
fn place(
    spec: &CloudSpec,
    tiling: &Tiling,
    counts: &[u32],
    drop: &[u64],
    transform: &[[f64; 4]; 3],
    cloud: &mut Cloud,
) {
    // Each tile's first global index, and its first output index (minus the drops before it).
    let mut first = Vec::with_capacity(counts.len() + 1);
    let mut acc = 0u64;
    for &c in counts {
        first.push(acc);
        acc += c as u64;
    }
    first.push(acc);
    let out_first: Vec<usize> = first
        .iter()
        .map(|&g| (g - drop.partition_point(|&d| d < g) as u64) as usize)
        .collect();
    // Tiles in groups, each group writing its own slice of the outputs.
    const GROUP: usize = 256;
    let groups = counts.len().div_ceil(GROUP);
    let mut slices = Vec::with_capacity(groups);
    let (mut c_rest, mut r_rest, mut s_rest) = (
        &mut cloud.centres[..],
        &mut cloud.radius_um[..],
        &mut cloud.species[..],
    );
    for g in 0..groups {
        let len = out_first[((g + 1) * GROUP).min(counts.len())] - out_first[g * GROUP];
        let (c, cr) = std::mem::take(&mut c_rest).split_at_mut(len);
        let (r, rr) = std::mem::take(&mut r_rest).split_at_mut(len);
        let (s, sr) = std::mem::take(&mut s_rest).split_at_mut(len);
        (c_rest, r_rest, s_rest) = (cr, rr, sr);
        slices.push((g, c, r, s));
    }
    let samplers = spec.samplers();
    slices.into_par_iter().for_each(|(g, c, r, s)| {
        let mut k = 0;
        for t in g * GROUP..((g + 1) * GROUP).min(counts.len()) {
            let mut global = first[t];
            let mut next_drop = drop.partition_point(|&d| d < global);
            spec.visit_tile(tiling, t, Some(&samplers), |grain| {
                let skip = next_drop < drop.len() && drop[next_drop] == global;
                global += 1;
                if skip {
                    next_drop += 1;
                    return;
                }
                c[k] = apply(transform, grain.centre);
                r[k] = grain.radius_um;
                s[k] = grain.species;
                k += 1;
            });
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(density: Density, seed: u64) -> CloudSpec {
        CloudSpec {
            lo: [-1.0; 3],
            hi: [1.0; 3],
            density,
            species: vec![
                (3.0, Psd::Monodisperse { radius_um: 10.0 }),
                (
                    1.0,
                    Psd::Uniform {
                        r_min_um: 100.0,
                        r_max_um: 200.0,
                    },
                ),
            ],
            seed,
        }
    }

    #[test]
    fn exact_count_reproducible_and_independent_of_threads() {
        let s = spec(Density::Uniform, 7);
        let a = generate(&s, 10_007, &IDENTITY).unwrap();
        assert_eq!(a.centres.len(), 10_007);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let b = pool.install(|| generate(&s, 10_007, &IDENTITY).unwrap());
        assert_eq!(a.centres, b.centres);
        assert_eq!(a.radius_um, b.radius_um);
        let c = generate(&spec(Density::Uniform, 8), 10_007, &IDENTITY).unwrap();
        assert_ne!(a.centres, c.centres);
        assert!(a
            .centres
            .iter()
            .all(|p| p.iter().all(|x| (-1.0..1.0).contains(x))));
    }

    /// Species shares and each species' radii: 3:1 within 4 sigma; radii from the right PSD.
    #[test]
    fn species_follow_their_shares_and_distributions() {
        let a = generate(&spec(Density::Uniform, 1), 40_000, &IDENTITY).unwrap();
        let first = a.species.iter().filter(|&&s| s == 0).count() as f64;
        let sd = (40_000.0 * 0.75 * 0.25f64).sqrt();
        assert!((first - 30_000.0).abs() < 4.0 * sd, "{first}");
        for (s, r) in a.species.iter().zip(&a.radius_um) {
            assert!(if *s == 0 {
                *r == 10.0
            } else {
                (100.0..=200.0).contains(r)
            });
        }
    }

    /// Counts per slab along a gradient against its integral (chi-square, 10 slabs, generous bound).
    #[test]
    fn gradient_counts_follow_the_density() {
        let n = 100_000u64;
        let a = generate(
            &spec(Density::gradient(2, 1.0, 0.0).unwrap(), 3),
            n,
            &IDENTITY,
        )
        .unwrap();
        let mut slabs = [0f64; 10];
        for p in &a.centres {
            slabs[(((p[2] + 1.0) / 0.2) as usize).min(9)] += 1.0;
        }
        let chi2: f64 = (0..10)
            .map(|k| {
                // ∫ over the slab of (1 − t) dt, t = (z + 1) / 2, normalised by 1/2.
                let (t0, t1) = (k as f64 / 10.0, (k + 1) as f64 / 10.0);
                let e = n as f64 * 2.0 * ((t1 - t0) - 0.5 * (t1 * t1 - t0 * t0));
                (slabs[k] - e).powi(2) / e
            })
            .sum();
        assert!(chi2 < 30.0, "chi2 = {chi2}, slabs {slabs:?}");
    }

    /// A grid density: the cell centres hold the values, its mean is the interpolant's integral
    /// (a fine midpoint rule), and the generated counts per cell follow the interpolant's integral
    /// over the cell (chi-square).
    #[test]
    fn grid_density_is_trilinear_and_counts_follow_it() {
        let dims = [5usize, 3, 4];
        let values: Vec<f32> = (0..60).map(|k| ((k * 37 % 11) as f32) * 0.3).collect();
        assert!(DensityGrid::new([5, 3, 3], values.clone()).is_err());
        assert!(DensityGrid::new(dims, vec![-1.0; 60]).is_err());
        let g = DensityGrid::new(dims, values.clone()).unwrap();
        let (lo, hi) = ([-1.0; 3], [1.0; 3]);
        let centre =
            |i: [usize; 3]| [0, 1, 2].map(|a| -1.0 + 2.0 * (i[a] as f64 + 0.5) / dims[a] as f64);
        for k in 0..60 {
            let i = [k % 5, (k / 5) % 3, k / 15];
            assert!((g.at(centre(i), lo, hi) - values[k] as f64).abs() < 1e-12);
        }
        let m = 60;
        let mut sum = 0.0;
        let mut cells = vec![0.0f64; 60];
        for k in 0..m * m * m {
            let idx = [k % m, (k / m) % m, k / (m * m)];
            let p = [0, 1, 2].map(|a| -1.0 + 2.0 * (idx[a] as f64 + 0.5) / m as f64);
            let v = g.at(p, lo, hi);
            sum += v;
            let c = [0, 1, 2].map(|a| ((p[a] + 1.0) / 2.0 * dims[a] as f64) as usize);
            cells[c[0] + 5 * (c[1] + 3 * c[2])] += v;
        }
        let mean = sum / (m * m * m) as f64;
        assert!(
            (mean - g.mean).abs() < 1e-3 * g.mean,
            "{mean} vs {}",
            g.mean
        );
        let n = 200_000u64;
        let a = generate(&spec(Density::Grid(Arc::new(g)), 6), n, &IDENTITY).unwrap();
        let mut counts = vec![0.0f64; 60];
        for p in &a.centres {
            let c = [0, 1, 2]
                .map(|a| (((p[a] + 1.0) / 2.0 * dims[a] as f64) as usize).min(dims[a] - 1));
            counts[c[0] + 5 * (c[1] + 3 * c[2])] += 1.0;
        }
        let chi2: f64 = (0..60)
            .filter(|&k| cells[k] > 0.0)
            .map(|k| {
                let e = n as f64 * cells[k] / sum;
                (counts[k] - e).powi(2) / e
            })
            .sum();
        // 60 cells: the 99.9th percentile of chi-square with 59 degrees of freedom is ~100.
        assert!(chi2 < 100.0, "chi2 = {chi2}");
    }

    /// A transform maps the centres.
    #[test]
    fn transform_applies() {
        let s = spec(Density::Uniform, 2);
        let m = [
            [2.0, 0.0, 0.0, 10.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, -5.0],
        ];
        let (a, b) = (
            generate(&s, 500, &IDENTITY).unwrap(),
            generate(&s, 500, &m).unwrap(),
        );
        for (p, q) in a.centres.iter().zip(&b.centres) {
            assert_eq!(*q, [2.0 * p[0] + 10.0, p[1], p[2] - 5.0]);
        }
    }

    /// A tile is the same generated alone as within the whole cloud (what a procedural cloud relies on).
    #[test]
    fn a_tile_alone_is_the_tile_in_the_cloud() {
        let s = spec(Density::Noise(ValueNoise::new(0.5, 3, 9, 0.8).unwrap()), 4);
        let tiling = s.tiling(5000.0);
        let mut all = Vec::new();
        for t in 0..tiling.len() {
            s.visit_tile(&tiling, t, Some(&s.samplers()), |g| all.push((t, g)));
        }
        let t = tiling.len() / 2;
        let mut alone = Vec::new();
        s.visit_tile(&tiling, t, Some(&s.samplers()), |g| alone.push((t, g)));
        let inside: Vec<_> = all.iter().filter(|(u, _)| *u == t).cloned().collect();
        assert_eq!(alone, inside);
        let total = all.len() as f64;
        assert!(
            (total - 5000.0).abs() < 5.0 * 5000f64.sqrt() + 60.0,
            "{total}"
        );
    }

    /// The precomputed sampler draws what the distribution's own inverse CDF draws.
    #[test]
    fn radius_sampler_matches_draw() {
        let p = Psd::LogNormal {
            median_um: 50.0,
            sigma_g: 1.5,
            r_min_um: 5.0,
            r_max_um: 300.0,
        };
        let s = p.sampler();
        for k in 0..1000 {
            let u = (k as f64 + 0.5) / 1000.0;
            let (a, b) = (s.draw(0.3, u), p.draw(0.3, u));
            assert!((a - b).abs() <= 1e-12 * b, "{a} {b}");
        }
    }

    /// A box much thinner along one axis than a tile is wide gets one tile across it, not billions.
    #[test]
    fn thin_boxes_get_few_tiles() {
        let mut s = spec(Density::Uniform, 1);
        (s.lo, s.hi) = ([0.0; 3], [1e-6, 1e6, 1e6]);
        let t = s.tiling(3000.0);
        assert!(
            t.len() as f64 <= 3.0 * 3000.0 / CANDIDATES_PER_TILE + 8.0,
            "{:?}",
            t.dims
        );
        assert_eq!(t.dims[0], 1);
        assert_eq!(generate(&s, 3000, &IDENTITY).unwrap().centres.len(), 3000);
    }

    #[test]
    fn errors_name_the_argument() {
        let mut s = spec(Density::Uniform, 0);
        s.hi = [1.0, -2.0, 1.0];
        assert!(generate(&s, 10, &IDENTITY)
            .unwrap_err()
            .to_string()
            .contains("hi"));
        assert!(generate(&spec(Density::Uniform, 0), 0, &IDENTITY)
            .unwrap_err()
            .to_string()
            .contains("count"));
        assert!(ValueNoise::new(0.0, 2, 0, 1.0)
            .unwrap_err()
            .to_string()
            .contains("scale"));
        assert!(Density::gradient(3, 1.0, 0.0)
            .unwrap_err()
            .to_string()
            .contains("axis"));
    }
}
