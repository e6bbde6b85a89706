//! What each particle of a discrete medium carries besides its centre (issue 24): the disk a ray sees
//! (inclusion radius R_i, optical depth τ_i), the extinction cross section C_t,i of Eq. 24 and the
//! optics bin (albedo, phase function), kept either per particle or per *class*.
//!
//! * [`Storage::Full`]: one entry per particle, its radius as given (f32 at render).
//! * [`Storage::Compact`] (the default): a particle is a code, an index into a table of classes. A
//!   class is an optics bin and one of [`LEVELS_PER_BIN`] radius levels spaced evenly in ln r over the
//!   radii of the bin's particles; each particle takes the level its radius lies in and the class's
//!   radius, the level's geometric centre (only the classes some particle is in are kept), so radii move by at most half a level (a factor
//!   (r_max / r_min)^(1 / 2048) within a bin: 2·10⁻⁴ for a bin 1.5 wide, 0.5 % for one 10⁴ wide).
//!   C_t,i follows as π r² Q̄_ext of the bin (every particle of a bin has its bin's mean efficiency,
//!   `motes.DiscreteMedium`), so a class is what a particle of that radius is, not an average. The grid,
//!   the continuous fields and the optics all see the class's values: the free flight is exact for the
//!   particles as stored. Four bytes per particle instead of seventeen. The grid quantises its
//!   centres (`crate::space::grid`, "Quantised slots": a lattice of 2^14 steps per cell edge, radii
//!   and τ by code) and names its particles by their position in it (`ParticleGrid::positional`);
//!   from 2^16 discrete grains (`render::discrete`, `CENTRE_CELLS_FROM`) it stores every class by its
//!   centres' cells, 8 bytes a particle, so a particle walked one by one keeps its slot and a 16-bit
//!   class code by position (this table's `codes`; the continuous ones are named by class in their field and keep
//!   nothing), and the grains' continuous equivalent only its cells' pick tables: 11–14 bytes per
//!   discrete particle (`scripts/bench/bench_storage.py`; 60–69 with spheres and overlap slots, 34–44
//!   with quantised overlap slots).

use crate::error::{require, OpticsError};
use crate::render::continuous::{Column, CLASS_FLAG};
use rayon::prelude::*;
use std::f64::consts::PI;

/// How a discrete medium stores its particles (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Storage {
    /// Per-class optics, quantised radii: the default.
    #[default]
    Compact,
    /// Per-particle optics, radii as given.
    Full,
}

impl Storage {
    pub fn parse(name: &str) -> Result<Self, OpticsError> {
        match name {
            "compact" => Ok(Storage::Compact),
            "full" => Ok(Storage::Full),
            _ => Err(OpticsError::InvalidOption {
                argument: "storage",
                value: name.to_string(),
                allowed: "compact or full",
            }),
        }
    }
}

/// Each radius's optics bin among the increasing bin `edges`: numpy's
/// `searchsorted(edges, r, side="right") - 1` clipped to the bins `0..edges.len() - 1` (one bin where
/// there are two edges or fewer), mapped through `lookup` (a global bin per bin) where given. In
/// parallel: at 10^8 particles numpy's one thread took ~20 s for this and the mapping.
pub fn size_bins(radius: &[f64], edges: &[f64], lookup: Option<&[u32]>) -> Vec<u32> {
    let last = edges.len().saturating_sub(2);
    radius
        .par_iter()
        .map(|&r| {
            let b = edges
                .partition_point(|&e| e <= r)
                .saturating_sub(1)
                .min(last);
            lookup.map_or(b as u32, |l| l[b])
        })
        .collect()
}

/// Radius levels per optics bin of compact storage.
pub const LEVELS_PER_BIN: usize = 1024;

/// The optics a particle carries, looked up by its code: the particle's index (full storage) or its
/// class (compact).
pub(crate) struct ParticleOptics {
    /// Grey optical depth of the disk, −ln(1 − x) (`render::discrete` module docs).
    pub tau: Vec<f32>,
    /// Inclusion radius R (scene units).
    pub reach: Vec<f32>,
    /// Grey extinction cross section C_t (scene units²).
    pub c_ext: Vec<f32>,
    /// Optics bin.
    pub bin: Vec<u32>,
    /// Sampled as part of the continuous field (its size class is continuous).
    pub in_field: Vec<bool>,
    /// The class of each particle the grid walks, by its position in the grid (compact storage:
    /// `ParticleGrid::positional`); None: the code is the particle's index (full storage).
    codes: Option<Codes>,
    particles: usize,
}

/// Each particle's class code, in 16 bits where the classes are at most 65 536 (2 bytes per
/// particle at render; the build hands them over in 32).
enum Codes {
    Narrow(Vec<u16>),
    Wide(Vec<u32>),
}

impl Codes {
    fn new(codes: Vec<u32>) -> Self {
        if codes.par_iter().all(|&c| c <= u16::MAX as u32) {
            Codes::Narrow(codes.into_par_iter().map(|c| c as u16).collect())
        } else {
            Codes::Wide(codes)
        }
    }
    fn bytes(&self) -> usize {
        match self {
            Codes::Narrow(c) => c.capacity() * 2,
            Codes::Wide(c) => c.capacity() * 4,
        }
    }
}

/// Particles as classes: each particle's code and, per class, the radius, cross section and bin.
pub(crate) struct Classes {
    pub codes: Vec<u32>,
    pub radius: Vec<f64>,
    pub c_ext: Vec<f64>,
    pub bin: Vec<u32>,
}

/// The classes of particles with radii `radius`, cross sections `c_ext` and bins `bin` (module docs).
pub(crate) fn classes(
    radius: Column,
    c_ext: Column,
    bin: &[u32],
    bins: usize,
) -> Result<Classes, OpticsError> {
    let classes = bins as f64 * LEVELS_PER_BIN as f64;
    require(
        "bins (compact storage)",
        bins as f64,
        classes < u32::MAX as f64,
        "< 4e6 (or storage = full)",
    )?;
    // Per bin: the radius range and the mean efficiency C / (π r²) of its particles.
    let mut lo = vec![f64::INFINITY; bins];
    let mut hi = vec![0.0f64; bins];
    let mut q = vec![0.0f64; bins];
    let mut count = vec![0usize; bins];
    for (i, &b) in bin.iter().enumerate() {
        let (r, b, c) = (radius(i), b as usize, c_ext(i));
        lo[b] = lo[b].min(r);
        hi[b] = hi[b].max(r);
        q[b] += c / (PI * r * r);
        count[b] += 1;
    }
    let levels = LEVELS_PER_BIN as f64;
    let step: Vec<f64> = (0..bins)
        .map(|b| {
            if hi[b] > lo[b] {
                (hi[b] / lo[b]).ln() / levels
            } else {
                0.0
            }
        })
        .collect();
    let level_of = |r: f64, b: usize| -> usize {
        if step[b] > 0.0 {
            (((r / lo[b]).ln() / step[b]) as usize).min(LEVELS_PER_BIN - 1)
        } else {
            0
        }
    };
    // Only the classes some particle is in, numbered densely (a small medium keeps a small table).
    let mut dense = vec![u32::MAX; bins * LEVELS_PER_BIN];
    let (mut radius_c, mut c_c, mut bin_c) = (Vec::new(), Vec::new(), Vec::new());
    let q_mean: Vec<f64> = (0..bins)
        .map(|b| {
            if count[b] > 0 {
                q[b] / count[b] as f64
            } else {
                0.0
            }
        })
        .collect();
    // Each particle's class (bin and level; in parallel), then the classes numbered densely in the
    // order of their first particle (in place: no column of levels for 10^8 particles).
    let mut codes: Vec<u32> = bin
        .par_iter()
        .enumerate()
        .map(|(i, &b)| (b as usize * LEVELS_PER_BIN + level_of(radius(i), b as usize)) as u32)
        .collect();
    for code in codes.iter_mut() {
        let k = *code as usize;
        if dense[k] == u32::MAX {
            let (b, l) = (k / LEVELS_PER_BIN, k % LEVELS_PER_BIN);
            let r = lo[b] * ((l as f64 + 0.5) * step[b]).exp();
            dense[k] = radius_c.len() as u32;
            radius_c.push(r);
            c_c.push(PI * r * r * q_mean[b]);
            bin_c.push(b as u32);
        }
        *code = dense[k];
    }
    Ok(Classes {
        codes,
        radius: radius_c,
        c_ext: c_c,
        bin: bin_c,
    })
}

impl ParticleOptics {
    /// The table of `particles` particles: per code (disk (R, τ), C_t, bin, continuous), and each
    /// particle's code (None: the code is the index).
    pub(crate) fn new(
        disks: &[(f64, f64)],
        c_ext: &[f64],
        bin: Vec<u32>,
        in_field: Vec<bool>,
        codes: Option<Vec<u32>>,
        particles: usize,
    ) -> Self {
        let codes = codes.map(Codes::new);
        ParticleOptics {
            tau: disks.iter().map(|d| d.1 as f32).collect(),
            reach: disks.iter().map(|d| d.0 as f32).collect(),
            c_ext: c_ext.iter().map(|&c| c as f32).collect(),
            bin,
            in_field,
            codes,
            particles,
        }
    }

    /// The code of particle `j`, or of a class member of a compact continuous field (`j` with
    /// [`CLASS_FLAG`]: the code itself).
    #[inline(always)]
    pub(crate) fn code(&self, j: u32) -> usize {
        if j & CLASS_FLAG != 0 {
            return (j & !CLASS_FLAG) as usize;
        }
        match &self.codes {
            Some(Codes::Narrow(c)) => c[j as usize] as usize,
            Some(Codes::Wide(c)) => c[j as usize] as usize,
            None => j as usize,
        }
    }
    pub(crate) fn tau(&self, j: u32) -> f64 {
        self.tau[self.code(j)] as f64
    }
    pub(crate) fn reach(&self, j: u32) -> f64 {
        self.reach[self.code(j)] as f64
    }
    pub(crate) fn c_ext(&self, j: u32) -> f64 {
        self.c_ext[self.code(j)] as f64
    }
    pub(crate) fn bin(&self, j: u32) -> usize {
        self.bin[self.code(j)] as usize
    }
    pub(crate) fn in_field(&self, j: u32) -> bool {
        self.in_field[self.code(j)]
    }
    pub(crate) fn len(&self) -> usize {
        self.particles
    }
    /// How many particle identities there are: every particle, or (compact storage) the particles
    /// the grid walks, by position (`ParticleGrid::positional`).
    pub(crate) fn ids(&self) -> usize {
        match &self.codes {
            Some(Codes::Narrow(c)) => c.len(),
            Some(Codes::Wide(c)) => c.len(),
            None => self.particles,
        }
    }
    /// Heap bytes.
    pub(crate) fn bytes(&self) -> usize {
        self.tau.capacity() * 17 + self.codes.as_ref().map_or(0, Codes::bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Radii move by at most half a level; cross sections keep their bin's efficiency; codes are per bin.
    #[test]
    fn classes_quantise_within_half_a_level() {
        let radius: Vec<f64> = (0..5000)
            .map(|i| 1.0 + 99.0 * (i as f64 / 4999.0).powi(3))
            .collect();
        let bin: Vec<u32> = radius
            .iter()
            .map(|&r| if r < 10.0 { 0 } else { 1 })
            .collect();
        let c_ext: Vec<f64> = radius
            .iter()
            .zip(&bin)
            .map(|(&r, &b)| PI * r * r * (2.0 + b as f64))
            .collect();
        let c = classes(&|i| radius[i], &|i| c_ext[i], &bin, 2).unwrap();
        for (i, &k) in c.codes.iter().enumerate() {
            let k = k as usize;
            assert_eq!(c.bin[k], bin[i]);
            let (lo, hi) = if bin[i] == 0 {
                (1.0f64, 9.99f64)
            } else {
                (10.0f64, 100.0f64)
            };
            let half = 0.5 * (hi / lo).ln() / LEVELS_PER_BIN as f64 * 1.01;
            assert!(
                (c.radius[k] / radius[i]).ln().abs() <= half,
                "{} {}",
                c.radius[k],
                radius[i]
            );
            let q = c.c_ext[k] / (PI * c.radius[k] * c.radius[k]);
            assert!((q - (2.0 + bin[i] as f64)).abs() < 1e-12);
        }
        assert!(Storage::parse("tiny")
            .unwrap_err()
            .to_string()
            .contains("storage"));
    }

    /// A bin whose particles share one radius keeps it exactly.
    #[test]
    fn a_monodisperse_bin_is_exact() {
        let c = classes(&|_| 3.0, &|_| PI * 18.0, &[0; 10], 1).unwrap();
        assert!(c.codes.iter().all(|&k| k == 0) && c.radius.len() == 1);
        assert_eq!(c.radius[0], 3.0);
        assert!((c.c_ext[0] - PI * 18.0).abs() < 1e-12);
    }

    /// Codes of at most 65 536 classes are kept in 16 bits, more in 32; either way a particle's code
    /// reads back as given, and the bytes follow the width.
    #[test]
    fn codes_narrow_where_they_fit() {
        for (classes, width) in [(65_536usize, 2usize), (65_537, 4)] {
            let codes: Vec<u32> = (0..100_000u32).map(|i| i % classes as u32).collect();
            let disks = vec![(1.0, 0.5); classes];
            let optics = ParticleOptics::new(
                &disks,
                &vec![1.0; classes],
                vec![0; classes],
                vec![false; classes],
                Some(codes.clone()),
                codes.len(),
            );
            for (j, &k) in codes.iter().enumerate().step_by(997) {
                assert_eq!(optics.code(j as u32), k as usize);
            }
            let tables = optics.tau.len() * 17;
            assert_eq!(optics.bytes() - tables, codes.len() * width);
        }
    }
}
