//! How a grid is laid over its particles: its settings, the cells' size, the size classes and the
//! checks of its inputs.

use super::Particles;
use crate::error::{require, require_len, shown, OpticsError};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// The input that sets a grid's number of cells, which an allocation of its cells that fails names.
pub(crate) const CELLS_DRIVER: &str = "cells_per_particle";

/// Axis-aligned bounding box of the centres (in parallel: 10^8 centres are 2.4 GB to read).
pub fn bounding_box(positions: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    bounding_box_by(positions.len(), |i| positions[i])
}

/// [`bounding_box`] of the `n` centres `at(0..n)`.
pub(super) fn bounding_box_by(
    n: usize,
    at: impl Fn(usize) -> [f64; 3] + Sync,
) -> ([f64; 3], [f64; 3]) {
    let empty = || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    const CHUNK: usize = 1 << 16;
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (mut lo, mut hi) = empty();
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let p = at(i);
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
            (lo, hi)
        })
        .reduce(empty, |x, y| {
            (
                [0, 1, 2].map(|a| x.0[a].min(y.0[a])),
                [0, 1, 2].map(|a| x.1[a].max(y.1[a])),
            )
        })
}

/// The first index of `0..n` where `bad` holds: chunks scanned in order, side by side.
pub(crate) fn first_where(n: usize, bad: impl Fn(usize) -> bool + Sync) -> Option<usize> {
    const CHUNK: usize = 1 << 16;
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .filter_map(|c| (c * CHUNK..((c + 1) * CHUNK).min(n)).find(|&i| bad(i)))
        .min()
}

/// Margin by which the grid box and a particle's referencing range grow beyond R_max (relative, then
/// absolute): a ball touching a face must not round outside the box.
pub(super) const BOX_MARGIN: (f64, f64) = (1.0001, 1e-9);

/// Particles per occupied cell of the grid that measures the occupied volume (`occupied_volume`): a
/// uniform cloud leaves e^-16 of those cells empty by chance.
pub(super) const OCCUPANCY_PARTICLES_PER_CELL: f64 = 16.0;

/// Cells per particle of centre-cell classes ([`GridSettings::centre_cells`]) relative to the
/// setting: a centre-cell step works out which cells of its slab the ray comes near before it tests
/// any, so fewer, larger cells pay (32 particles a cell at the default).
pub(super) const CENTRE_CELLS_FACTOR: f64 = 0.25;

/// Most cells per axis (the counting sorts index cells with u32).
pub(super) const MAX_CELLS_PER_AXIS: usize = 1 << 20;

/// Most cells in all (a sparse cloud of 2e8 particles at one cell each: 800 MB of cell starts). A
/// setting that asks for more (`cells_per_particle` times the particles) is an error naming it
/// ([`check_cells_per_particle`]); the clamps below it only bound the internal choices (the occupancy
/// grid, the cells sized by the free path, a cloud that fills a sliver of its box).
pub const MAX_CELLS: f64 = 2.0e8;

/// Largest length or coordinate a grid takes (scene units): the largest f32, the precision its slots and
/// the renderer keep them in (beyond it a centre or a disk would be infinite there).
pub const MAX_LENGTH: f64 = f32::MAX as f64;

/// Default grid resolution, in cells per particle: about eight particles per cell. A step tests its
/// cell's spheres eight per pre-test in whole blocks, so larger cells than the paper's one particle
/// per voxel (Sec. 6.5) pay: fewer DDA steps for a few more (cheap) sphere tests, and less memory
/// (`cargo bench -p motes-core --bench traverse` compares resolutions).
pub const DEFAULT_CELLS_PER_PARTICLE: f64 = 0.125;

/// How a [`ParticleGrid`](super::ParticleGrid) is laid over its particles: the query radius r_c (scene units; a particle
/// contributes to the rays passing within r_c + r_i of its centre, Sec. 5.3) and the resolution in
/// cells per particle (paper Sec. 6.5: about one particle per voxel; see
/// [`DEFAULT_CELLS_PER_PARTICLE`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridSettings {
    pub query_radius: f64,
    pub cells_per_particle: f64,
    /// Quantise every class's slots ([`QSlots`](super::slots::QSlots): centres on a lattice of 2^14 steps per cell, radii
    /// and τ by code): 8 bytes a slot (12 with an overlap slot's index) instead of 24.
    pub quantise: bool,
    /// Store every class by its centres' cells (k = 1: each particle once, the walk scanning the
    /// cells around the ray) instead of referencing sparse classes' balls from every cell they
    /// overlap: with `quantise`, eight bytes per particle instead of ~2.5 slots of twelve.
    pub centre_cells: bool,
    /// Free flights stop at their first interaction: where the cloud's mean free path is shorter
    /// than a cell, size the cells by it ([`FREE_PATHS_PER_CELL`]) instead of by the particle count
    /// (a renderer's grid; the queries along whole segments, Eq. 18, keep the count's cells).
    pub free_path_cells: bool,
}

impl GridSettings {
    pub fn new(query_radius: f64, cells_per_particle: f64) -> Self {
        GridSettings {
            query_radius,
            cells_per_particle,
            quantise: false,
            centre_cells: false,
            free_path_cells: false,
        }
    }
    /// The same settings, cells sized by the mean free path where it is the shorter or not.
    pub fn by_free_path(self, free_path_cells: bool) -> Self {
        GridSettings {
            free_path_cells,
            ..self
        }
    }
    /// The same settings, quantising the slots or not.
    pub fn quantised(self, quantise: bool) -> Self {
        GridSettings { quantise, ..self }
    }
    /// The same settings, every class stored by its centres' cells or not.
    pub fn centred(self, centre_cells: bool) -> Self {
        GridSettings {
            centre_cells,
            ..self
        }
    }
}

/// Cell edge in mean free paths where [`GridSettings::free_path_cells`] sizes the cells by it. A free
/// flight ends about one mean free path into the cloud; a centre-cell walk scans the cells around
/// the ray's, so cells much wider than that path test grains far beyond the interaction, and much
/// narrower ones cost DDA steps.
pub const FREE_PATHS_PER_CELL: f64 = 1.5;

/// The finest cells [`GridSettings::free_path_cells`] makes, in cells per particle (four particles a
/// cell: the cell index then costs a byte per particle).
pub(super) const FREE_PATH_CELLS_PER_PARTICLE_MAX: f64 = 0.25;

/// The mean free path 1 / σ_t of a grid's particles spread over `volume`: σ_t = Σ C_t,i / V (the mean
/// over channels), the walk's own extinction (each disk removes exactly C_t,i from a beam,
/// `render::discrete`).
pub(super) fn mean_free_path(p: &Particles, volume: f64) -> f64 {
    let channels = p.channels.max(1);
    let c_mean =
        |j: usize| (0..channels).map(|ch| (p.c_ext)(p.id(j), ch)).sum::<f64>() / channels as f64;
    // Summed in fixed chunks, in order: the same cells whatever the thread count.
    let chunk = 1 << 16;
    let parts: Vec<f64> = (0..p.len().div_ceil(chunk))
        .into_par_iter()
        .map(|k| {
            (k * chunk..((k + 1) * chunk).min(p.len()))
                .map(c_mean)
                .sum()
        })
        .collect();
    volume / parts.iter().sum::<f64>()
}

/// Size classes of a [`ParticleGrid`](super::ParticleGrid): factors of two in inclusion radius, the last one open below.
pub(crate) const SIZE_CLASSES: usize = 13;

/// The size class of an inclusion radius `reach` among radii up to `reach_max`: class c holds reach in
/// (R_max 2^-(c+1), R_max 2^-c]; everything below 2^-12 R_max shares the last.
pub(crate) fn size_class(reach_max: f64, reach: f64) -> usize {
    let x = reach_max / reach;
    if x.is_finite() && x > 1.0 {
        (x.log2().floor() as usize).min(SIZE_CLASSES - 1)
    } else {
        0
    }
}

/// The cell edge of `n` particles in `volume` at about `cells_per_particle` cells each.
pub(super) fn cell_spacing(volume: f64, n: usize, cells_per_particle: f64) -> f64 {
    (volume / (n as f64 * cells_per_particle).clamp(1.0, MAX_CELLS)).cbrt()
}

/// Can a class with inclusion radii up to `reach_max` reference each ball from every cell it overlaps
/// (k = 0, balls narrower than the cells), at cell edge `spacing`?
pub(super) fn is_sparse(reach_max: f64, spacing: f64) -> bool {
    2.0 * reach_max <= spacing
}

/// Size classes merged, largest first, while the merged set is still sparse (its largest inclusion
/// diameter at most its cell spacing, `SubGrid::build_class`'s k = 0 rule). A sparse grid references
/// each ball from every cell it overlaps, so it needs no split by size; each class a ray walks costs a
/// DDA set-up and a merge of its hits in t, several percent of a sparse render per extra class.
/// The set of particles a ray meets is the same either way.
pub(super) fn merge_sparse_classes(
    members: Vec<Vec<u32>>,
    reach_of: impl Fn(&u32) -> f64 + Sync,
    volume: f64,
    cells_per_particle: f64,
) -> Vec<Vec<u32>> {
    let sparse = |n: usize, reach_max: f64| {
        is_sparse(reach_max, cell_spacing(volume, n, cells_per_particle))
    };
    let mut out: Vec<(Vec<u32>, f64)> = Vec::new();
    for ids in members.into_iter().filter(|m| !m.is_empty()) {
        let reach_max = ids.par_iter().map(&reach_of).reduce(|| 0.0, f64::max);
        match out.last_mut() {
            // Classes come largest first: the group keeps its first class's largest reach.
            // (sparse for more particles implies sparse for fewer: a dense group stays apart)
            Some((group, r)) if sparse(group.len() + ids.len(), *r) => group.extend(ids),
            _ => out.push((ids, reach_max)),
        }
    }
    out.into_iter().map(|(ids, _)| ids).collect()
}

/// The volume the centres occupy, to size the cells by: their bounding box, less the cells that hold no
/// centre, measured at [`OCCUPANCY_PARTICLES_PER_CELL`] per occupied cell (so few cells of a uniform
/// cloud are empty by chance) and refined twice. A cloud that fills a
/// slanted column, a noise density or a Houdini sim covers a fraction of its bounding box; sized by the
/// box, its occupied cells would hold several times the intended particles each (a column around the
/// default scene's beam: ~40 instead of ~8 per cell).
pub(super) fn occupied_volume_by(
    n: usize,
    at: impl Fn(usize) -> [f64; 3] + Sync,
) -> Result<f64, OpticsError> {
    let (lo, hi) = bounding_box_by(n, &at);
    let ext = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(1e-12));
    let mut volume = ext[0] * ext[1] * ext[2];
    let target = (n as f64 / OCCUPANCY_PARTICLES_PER_CELL).clamp(1.0, MAX_CELLS);
    for _ in 0..2 {
        let cell = (volume / target).cbrt();
        let dims = ext.map(|e| ((e / cell).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS));
        let n_cells = dims[0] * dims[1] * dims[2];
        if n_cells as f64 > 8.0 * MAX_CELLS {
            break;
        }
        // Marked in parallel (the same bits in any order).
        let words = n_cells.div_ceil(64);
        let mut occupied: Vec<AtomicU64> = Vec::new();
        occupied
            .try_reserve_exact(words)
            .map_err(|_| OpticsError::OutOfMemory {
                argument: "count",
                what: "the grid's occupancy bits",
                bytes: words as f64 * 8.0,
            })?;
        occupied.extend((0..words).map(|_| AtomicU64::new(0)));
        (0..n).into_par_iter().for_each(|j| {
            let p = at(j);
            let c = [0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1));
            let i = (c[2] * dims[1] + c[1]) * dims[0] + c[0];
            occupied[i / 64].fetch_or(1 << (i % 64), Ordering::Relaxed);
        });
        let count: u64 = occupied
            .iter()
            .map(|w| w.load(Ordering::Relaxed).count_ones() as u64)
            .sum();
        let v = (count as f64 * cell.powi(3)).min(volume);
        // Mostly occupied (a box-shaped cloud): the box it is.
        if v >= 0.9 * volume {
            break;
        }
        volume = v;
    }
    Ok(volume)
}

/// The checks of a particle set and its grid settings, each naming its argument: done once, where the
/// particles enter the core ([`ParticleGrid::build`](super::ParticleGrid::build), `DiscreteMedium::build`); what is derived from
/// checked inputs is built without checking again (`ParticleGrid::from_checked`).
pub fn check_particles(
    positions: &[[f64; 3]],
    radius: &[f64],
    settings: &GridSettings,
) -> Result<(), OpticsError> {
    let GridSettings {
        query_radius,
        cells_per_particle,
        ..
    } = *settings;
    let n = positions.len();
    require("positions (count)", n as f64, n >= 1, ">= 1")?;
    require_len("radius (length)", radius.len(), n, "one per particle")?;
    require(
        "query_radius",
        query_radius,
        (0.0..=MAX_LENGTH).contains(&query_radius),
        "finite, >= 0 and at most 3.4e38 scene units (the renderer's single precision)",
    )?;
    check_cells_per_particle(cells_per_particle, n as f64)?;
    // The first particle that fails either check (found in parallel), checked as in order.
    let in_range = |p: &[f64; 3]| p.iter().all(|x| x.abs() <= MAX_LENGTH);
    let bad = |i: usize| !(in_range(&positions[i]) && radius[i].is_finite() && radius[i] > 0.0);
    if let Some(i) = first_where(n, bad) {
        let p = &positions[i];
        require(
            "positions (index of the first non-finite particle)",
            i as f64,
            in_range(p),
            "finite coordinates, at most 3.4e38 in magnitude (the renderer's single precision)",
        )?;
        require(
            "radius",
            radius[i],
            radius[i].is_finite() && radius[i] > 0.0,
            "finite and > 0",
        )?;
    }
    Ok(())
}

/// The check of a grid's resolution for `n` particles: finite, > 0, and at most [`MAX_CELLS`] cells in
/// all (`n` × `cells_per_particle`; more would take gigabytes of cells, or before this check were
/// capped without a word). `n`: the particles of one grid (a stored medium's, or a procedural
/// cloud's brick's).
pub fn check_cells_per_particle(cells_per_particle: f64, n: f64) -> Result<(), OpticsError> {
    let most = MAX_CELLS / n.max(1.0);
    if !(cells_per_particle > 0.0 && cells_per_particle <= most) {
        return Err(OpticsError::OutOfRange {
            argument: CELLS_DRIVER,
            value: cells_per_particle,
            requirement: format!(
                "finite and in (0, {}] for {n} particles: a grid takes at most {MAX_CELLS:e} \
                 cells (particles x cells_per_particle; the default is {DEFAULT_CELLS_PER_PARTICLE})",
                shown(most)
            ),
        });
    }
    Ok(())
}

/// The checks of extinction cross sections, `[particle][channel]` row-major, of `n` particles.
pub fn check_cross_sections(c_ext: &[f64], n: usize, channels: usize) -> Result<(), OpticsError> {
    require("channels", channels as f64, channels >= 1, ">= 1")?;
    require(
        "c_ext (length)",
        c_ext.len() as f64,
        c_ext.len() == n * channels,
        "particles × channels",
    )?;
    for &c in c_ext {
        require("c_ext", c, c.is_finite() && c >= 0.0, "finite and >= 0")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cells a setting asks for are bounded by an error naming it and its range, not a silent cap.
    #[test]
    fn cells_per_particle_beyond_the_grid_is_an_error_stating_the_range() {
        check_cells_per_particle(DEFAULT_CELLS_PER_PARTICLE, 1e9).unwrap();
        check_cells_per_particle(2e4, 1e4).unwrap();
        for (bad, n) in [
            (1e15, 1e4),
            (2.0001e4, 1e4),
            (f64::INFINITY, 1.0),
            (0.0, 1.0),
            (-1.0, 1.0),
        ] {
            let e = check_cells_per_particle(bad, n).unwrap_err();
            let text = e.to_string();
            assert!(
                text.contains("cells_per_particle") && text.contains("(0, "),
                "{text}"
            );
        }
        assert!(check_cells_per_particle(1e15, 1e4)
            .unwrap_err()
            .to_string()
            .contains("(0, 20000"));
    }
}
