//! What a re-implementation of a procedural cloud's generator needs (issue 46: the Dr.Jit kernel
//! regenerates a tile's grains on the device, where it cannot call this core), and the grains this
//! core generates for given tiles, to check it against.
//!
//! A tile's grains (`ProceduralGrains::tile_particles`, `CloudSpec::visit_candidates`): the tile's
//! xoshiro256++ stream seeded by SplitMix64 from `splitmix64(seed ^ splitmix64(TILE_STREAM ^ t))`, a
//! Poisson count of candidates (rand_distr 0.4's sampler: Knuth's product of uniforms below a mean of
//! 12, Numerical Recipes' rejection from a Cauchy above; its constants are [`ProceduralExport::poisson`]),
//! seven numbers per candidate (position, thinning, class, two unused), thinning by the density, the
//! discrete class from the mark's CDF, the key, the transform and the drift. Per class the inclusion
//! radius and disk optical depth as the bricks' grids store them (f32).

use super::{apply, ProceduralGrains, TILE_INDEX_BITS};
use crate::error::{require, OpticsError};
use crate::space::cloud::{Density, ValueNoise, TILE_STREAM};
use std::f64::consts::PI;

/// A value noise's terms ([`ValueNoise::terms`]).
#[derive(Clone, Debug)]
pub struct NoiseTerms {
    pub scale: f64,
    pub contrast: f64,
    pub offsets: Vec<[f64; 3]>,
    pub bases: Vec<u64>,
}

impl NoiseTerms {
    fn of(n: &ValueNoise) -> Self {
        let (scale, contrast, offsets, bases) = n.terms();
        NoiseTerms {
            scale,
            contrast,
            offsets: offsets.to_vec(),
            bases: bases.to_vec(),
        }
    }
}

/// The density the candidates are thinned by (None: a grid density, not exported).
#[derive(Clone, Debug)]
pub enum DensityTerms {
    Uniform,
    Gradient { axis: usize, start: f64, end: f64 },
    Noise(NoiseTerms),
    Grid,
}

/// A procedural cloud's discrete process as numbers (module docs).
#[derive(Clone, Debug)]
pub struct ProceduralExport {
    pub seed: u64,
    pub tile_stream: u64,
    /// Tiles per axis, the tiling's low corner and a tile's size (the cloud's coordinates).
    pub dims: [usize; 3],
    pub lo: [f64; 3],
    pub size: [f64; 3],
    /// Tiles per axis a grain's inclusion ball (plus the drift) reaches across: a ray meets only grains
    /// of tiles within this of the tiles it crosses (or of the ring of this many around the tiling).
    pub halo: [usize; 3],
    /// The cloud's box (what a gradient's t and the grid density are relative to).
    pub box_lo: [f64; 3],
    pub box_hi: [f64; 3],
    /// Poisson mean of a tile's candidate count.
    pub lambda: f64,
    /// rand_distr's constants for it: exp(−λ), ln λ, √(2λ), λ ln λ − ln Γ(1 + λ).
    pub poisson: [f64; 4],
    pub density: DensityTerms,
    /// The thinning bound (the density's largest value).
    pub bound: f64,
    /// Discrete class codes and the running sum of their probabilities.
    pub codes: Vec<u32>,
    pub cdf: Vec<f64>,
    /// Per class code (all codes, discrete or not): inclusion radius and disk optical depth as the
    /// bricks' grids store them.
    pub reach: Vec<f32>,
    pub tau: Vec<f32>,
    pub to_scene: [[f64; 4]; 3],
    /// The drift: the potential's three noises, turbulence, scale (scene units) and time (s).
    pub motion: Option<([NoiseTerms; 3], f64, f64, f64)>,
    pub tile_index_bits: u32,
}

/// The grains of some tiles, in the order asked, each tile's in its stream's order.
#[derive(Clone, Debug, Default)]
pub struct TileGrains {
    /// Per tile asked: its candidates (before thinning).
    pub candidates: Vec<u32>,
    pub tile: Vec<u64>,
    pub key: Vec<u64>,
    pub code: Vec<u32>,
    /// Centre in the cloud's coordinates (at rest) and in scene units (moved).
    pub centre: Vec<[f64; 3]>,
    pub position: Vec<[f64; 3]>,
}

/// rand_distr 0.4's `log_gamma` (Lanczos, the same operations in the same order).
fn log_gamma(x: f64) -> f64 {
    let coefficients = [
        76.18009172947146,
        -86.50532032941677,
        24.01409824083091,
        -1.231739572450155,
        0.1208650973866179e-2,
        -0.5395239384953e-5,
    ];
    let tmp = x + 5.5;
    let log = (x + 0.5) * tmp.ln() - tmp;
    let mut a = 1.000000000190015;
    let mut denom = x;
    for coeff in coefficients {
        denom += 1.0;
        a += coeff / denom;
    }
    log + (2.5066282746310005 * a / x).ln()
}

impl ProceduralGrains {
    /// The discrete process as numbers (module docs).
    pub fn export(&self) -> ProceduralExport {
        let lambda = self.tiling.candidates();
        let ln = lambda.ln();
        let density = match &self.cloud.density {
            Density::Uniform => DensityTerms::Uniform,
            Density::Gradient { axis, start, end } => DensityTerms::Gradient {
                axis: *axis,
                start: *start,
                end: *end,
            },
            Density::Noise(n) => DensityTerms::Noise(NoiseTerms::of(n)),
            Density::Grid(_) => DensityTerms::Grid,
        };
        let qr = self.settings.query_radius;
        let (reach, tau) = self
            .grid_radius
            .iter()
            .zip(&self.grid_c)
            .map(|(&r, &c)| {
                // The grid's R (query radius plus radius) and `disk_tau` (space/grid/build.rs).
                let reach = qr + r;
                (reach as f32, (c / (PI * reach * reach)) as f32)
            })
            .unzip();
        let motion = self.motion.as_ref().and_then(|(m, time)| {
            let (potential, wrapped) = m.potential();
            assert!(!wrapped, "a procedural cloud's drift does not wrap");
            potential.map(|p| {
                (
                    [0, 1, 2].map(|a| NoiseTerms::of(&p[a])),
                    m.turbulence,
                    m.scale,
                    *time,
                )
            })
        });
        ProceduralExport {
            seed: self.cloud.seed,
            tile_stream: TILE_STREAM,
            dims: self.tiling.dims,
            lo: self.tiling.lo,
            size: self.tiling.size,
            halo: self.halo,
            box_lo: self.cloud.lo,
            box_hi: self.cloud.hi,
            lambda,
            poisson: [
                (-lambda).exp(),
                ln,
                (2.0 * lambda).sqrt(),
                lambda * ln - log_gamma(1.0 + lambda),
            ],
            density,
            bound: self.cloud.density.bound(),
            codes: self.codes.clone(),
            cdf: self.cdf.clone(),
            reach,
            tau,
            to_scene: self.to_scene,
            motion,
            tile_index_bits: TILE_INDEX_BITS,
        }
    }

    /// The grains of `tiles` (linear indices) as the bricks generate them (module docs).
    pub fn tile_grains(&self, tiles: &[u64]) -> Result<TileGrains, OpticsError> {
        let n = self.tiling.len() as u64;
        let mut out = TileGrains::default();
        for &t in tiles {
            require(
                "tiles",
                t as f64,
                t < n,
                "tile indices below the tiles' count",
            )?;
            out.candidates.push(self.tile_candidates(t as usize));
            self.tile_particles(t as usize, |c, code, key| {
                let p = apply(&self.to_scene, c);
                let p = self
                    .motion
                    .as_ref()
                    .map_or(p, |(m, time)| m.position(p, *time));
                out.tile.push(t);
                out.key.push(key);
                out.code.push(code);
                out.centre.push(c);
                out.position.push(p);
            });
        }
        Ok(out)
    }

    /// Candidates of tile `t` before thinning (its stream's Poisson draw).
    fn tile_candidates(&self, t: usize) -> u32 {
        use crate::rng::splitmix64;
        use rand_distr::{Distribution, Poisson};
        use rand_xoshiro::rand_core::SeedableRng;
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(splitmix64(
            self.cloud.seed ^ splitmix64(TILE_STREAM ^ t as u64),
        ));
        let lambda = self.tiling.candidates();
        if lambda > 0.0 {
            Poisson::new(lambda).map_or(0, |p| p.sample(&mut rng) as u32)
        } else {
            0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{build_parts, ProceduralSpec};
    use super::*;
    use crate::ensemble::psd::Psd;
    use crate::render::discrete::particle_disk;
    use crate::space::cloud::CloudSpec;
    use crate::space::motion::Motion;

    /// rand_distr's log Γ (the Poisson constants' last term): ln n! at integers.
    #[test]
    fn log_gamma_matches_factorials() {
        for n in 1..20u32 {
            let f: f64 = (1..=n).map(|k| k as f64).product();
            assert!((log_gamma(n as f64 + 1.0) - f.ln()).abs() < 1e-9, "{n}");
        }
    }

    /// Every grain of a brick's grid is a grain `tile_grains` gives, with its position (as the grid
    /// stores it, f32), and its class's exported R and τ; the counts are the kept grains' for a
    /// uniform density; a drift moves them.
    #[test]
    fn bricks_hold_the_exported_grains() {
        for drift in [0.0, 0.02] {
            let psd = Psd::LogNormal {
                median_um: 20_000.0,
                sigma_g: 1.5,
                r_min_um: 2500.0,
                r_max_um: 160_000.0,
            };
            let (lo, hi) = psd.support();
            let edges = (0..=4)
                .map(|i| lo * (hi / lo).powf(i as f64 / 4.0))
                .collect();
            let spec = ProceduralSpec {
                cloud: CloudSpec {
                    lo: [0.0; 3],
                    hi: [1.0; 3],
                    density: Density::Uniform,
                    species: vec![(1.0, psd)],
                    seed: 11,
                },
                count: 5000.0,
                transform: [
                    [1.2, -1.6, 0.0, 0.3],
                    [1.6, 1.2, 0.0, -0.1],
                    [0.0, 0.0, 2.0, 0.5],
                ],
                scene_per_um: 1e-6,
                bin_edges_um: vec![edges],
                first_bin: vec![0],
                q_ext: vec![2.0; 4],
                motion: (drift > 0.0).then(|| (Motion::new([0.0; 3], drift, 0.5, 9).unwrap(), 1.7)),
            };
            let qr = 0.01;
            let parts = build_parts(
                &spec,
                |r, c| particle_disk(r, c, qr, 1.0),
                qr,
                0.125,
                f64::INFINITY,
                1 << 30,
            )
            .unwrap();
            let g = parts.grains.unwrap();
            let e = g.export();
            assert_eq!(e.motion.is_some(), drift > 0.0);
            let all: Vec<u64> = (0..g.tiles() as u64).collect();
            let grains = g.tile_grains(&all).unwrap();
            let total: u32 = grains.candidates.iter().sum();
            assert_eq!(total as usize, grains.key.len());
            let by_key: std::collections::HashMap<u64, usize> = grains
                .key
                .iter()
                .enumerate()
                .map(|(i, &k)| (k, i))
                .collect();
            let dims = g.frame.dims;
            let mut seen = 0;
            for index in [0, dims[0] * dims[1] * dims[2] / 2 + dims[0] / 2] {
                let cell = [
                    index % dims[0],
                    (index / dims[0]) % dims[1],
                    index / (dims[0] * dims[1]),
                ];
                let b = g.brick(cell, index);
                let Some(grid) = &b.grid else { continue };
                let f = grid.flat(0).unwrap();
                for (j, &i) in f.index.iter().enumerate() {
                    let i = i as usize;
                    let k = by_key[&b.key[i]];
                    let code = grains.code[k] as usize;
                    assert_eq!(code as u32, b.code[i]);
                    let p = grains.position[k].map(|x| x as f32);
                    assert_eq!(f.spheres[j], [p[0], p[1], p[2], e.reach[code]]);
                    assert_eq!(f.tau[j], e.tau[code]);
                    seen += 1;
                }
            }
            assert!(seen > 100, "{seen}");
        }
    }
}
