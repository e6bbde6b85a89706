//! A field's build: its cells from the particles' centres (or a density), σ_t per cell, the pick
//! tables and the majorants.

use super::{Column, ContinuousField, Members, CLASS_FLAG};
use crate::error::OpticsError;
use crate::space::dda::GridFrame;
use crate::space::grid::counting_sort_by;
use rayon::prelude::*;

/// Particles per cell of the field. A cell spreads its particles' extinction over its whole cross
/// section, so a ray meets a cell's particles all together or not at all, and the cells' shot noise
/// (±1/√n each) lets light through: E[e^{−τ}] > e^{−E[τ]} (Jensen), whereas each grain's own disk
/// (−ln(1 − x), `discrete.rs`) keeps the grains' mean transmittance exact. Larger cells: less of that
/// bias, but less of the cloud's own density texture at the pixel scale
/// (`scripts/bench/bench_field_bias.py` and `bench_dense.py` weigh the two).
pub(super) const PARTICLES_PER_CELL: f64 = 64.0;

/// Cells per axis of a majorant block: [`ContinuousField::sample_free_flight`] walks blocks of this
/// many cells cubed, each with the largest σ_t of its cells, and looks up σ_t only at tentative
/// collisions (delta tracking) instead of crossing every cell (one exponential per cell). A block's
/// majorant is its largest cell's fluctuation: wider blocks mean fewer steps but more null collisions.
pub(super) const MAJORANT_BLOCK: usize = 2;

/// Most cells along one axis (and in all) of the field.
pub(super) const MAX_AXIS_CELLS: usize = 1 << 10;

pub(super) const MAX_CELLS: f64 = 1.0e8;

/// A field uses one majorant for all its cells (its largest σ_t) when that is at most this many times
/// the mean of the blocks' majorants (over all blocks, empty ones included: the rate of tentative
/// collisions a block walk would see over the field's box). A few more null collisions then cost less
/// than a block walk per free flight; far more (grains crowding one spot) do not.
pub(super) const UNIFORM_MAJORANT_RATIO: f64 = 4.0;

/// [`ContinuousField::uniform_majorant`] of block majorants. `MOTES_UNIFORM_MAJORANT=0` at build keeps
/// the blocks (`scripts/bench/bench_quantise.py --switch MOTES_UNIFORM_MAJORANT`'s comparison).
pub(super) fn uniform_majorant(majorant: &[f32]) -> Option<f64> {
    if !crate::options::uniform_majorant() {
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
    /// (compact storage). Its cells' arrays are allocated fallibly ([`OpticsError::OutOfMemory`]
    /// naming `count`, which sets their number).
    pub fn build(
        positions: &[[f64; 3]],
        reach: Column,
        weight: Column,
        ids: Option<&[u32]>,
        classes: Option<&[u32]>,
    ) -> Result<Self, OpticsError> {
        let n = ids.map_or(positions.len(), <[u32]>::len);
        let id = |j: usize| ids.map_or(j, |v| v[j] as usize);
        let (lo, hi) = field_box(n, |j| positions[id(j)], |j| reach(id(j)));
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
        // The original indices in cell order, by a counting sort in u32 (the field takes at most
        // 2^32 particles, as the grid does).
        let which: Vec<u32> = (0..n)
            .into_par_iter()
            .map(|j| cell_of(&positions[id(j)]) as u32)
            .collect();
        let (start, order) = counting_sort_by(&which, n_cells, |j| id(j) as u32, "count")?;
        drop(which);
        let cell_volume = cell[0] * cell[1] * cell[2];
        // Each particle's extinction as rays inside the box meet it (`inside_share`).
        let inside = |i: usize| weight(i) * inside_share(positions[i], reach(i), lo, hi);
        let (sigma, cdf) = cell_shares(&order, &start, &inside, cell_volume);
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
        Ok(Self::with_cells(lo, cell, dims, sigma, start, members, cdf))
    }

    /// The field confined to the inside of the shapes that hold its medium (`inside(p)`: a medium that
    /// fills them, `crate::space::inside`): each cell's σ_t over the share of the cell inside them, where
    /// its particles lie and the only part of it rays cross (the shapes bound the medium). Without it a
    /// cell the shapes' surface cuts spreads its particles' extinction over its outside too, and a sphere
    /// of 20 µm grains at 1 mm per unit renders 3–7 % brighter than `homogeneous`
    /// (`tests/test_dropin.py`). The share: 1 where the cell's corners and centre are inside, else the
    /// share of 8³ points at the centres of its sub-cells (at least one).
    pub fn confined(mut self, inside: &(dyn Fn([f64; 3]) -> bool + Sync)) -> Self {
        let (lo, cell, dims) = (self.frame.bounds.lo, self.frame.cell, self.frame.dims);
        self.sigma.par_iter_mut().enumerate().for_each(|(c, s)| {
            if *s <= 0.0 {
                return;
            }
            let idx = [
                c % dims[0],
                (c / dims[0]) % dims[1],
                c / (dims[0] * dims[1]),
            ];
            let at = |f: [f64; 3]| [0, 1, 2].map(|a| lo[a] + (idx[a] as f64 + f[a]) * cell[a]);
            let probes = (0..9).map(|k| {
                if k == 8 {
                    [0.5; 3]
                } else {
                    [0, 1, 2].map(|a| ((k >> a) & 1) as f64)
                }
            });
            if probes.into_iter().all(|f| inside(at(f))) {
                return;
            }
            const N: usize = 8;
            let hits = (0..N * N * N)
                .filter(|&k| {
                    let f = [k % N, (k / N) % N, k / (N * N)].map(|i| (i as f64 + 0.5) / N as f64);
                    inside(at(f))
                })
                .count()
                .max(1);
            *s = (*s as f64 * (N * N * N) as f64 / hits as f64) as f32;
        });
        let (block_frame, majorant) = block_majorants(lo, cell, dims, &self.sigma);
        self.uniform_majorant = uniform_majorant(&majorant);
        self.block_frame = block_frame;
        self.majorant = majorant;
        self
    }

    /// The field of cells `dims` of edges `cell` from `lo` with σ_t `sigma`, its members, each cell's
    /// first member (`start`) and their running shares (`cdf`), and its majorants (read here:
    /// `MOTES_UNIFORM_MAJORANT`).
    fn with_cells(
        lo: [f64; 3],
        cell: [f64; 3],
        dims: [usize; 3],
        sigma: Vec<f32>,
        start: Vec<u32>,
        members: Members,
        cdf: Vec<u16>,
    ) -> Self {
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
        Self::with_cells(
            lo,
            cell,
            dims,
            sigma,
            Vec::new(),
            Members::Shared(members),
            cdf,
        )
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
}

/// The box of the `n` centres `position(0..n)` whose inclusion radii are `reach(0..n)`, as the field
/// fills it: exactly the centres' box, cells fitted to it per axis (a cell straddling the box face would
/// spread its particles' extinction over volume a bounded medium, a null-BSDF cube around generated
/// particles, never reaches, and darken the cloud's edges); an axis the centres do not span gets the
/// thickness of a ball, 2 R_max.
fn field_box(
    n: usize,
    position: impl Fn(usize) -> [f64; 3],
    reach: impl Fn(usize) -> f64,
) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let mut reach_max = 0.0f64;
    for j in 0..n {
        let p = position(j);
        reach_max = reach_max.max(reach(j));
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    for a in 0..3 {
        let pad = (reach_max - 0.5 * (hi[a] - lo[a])).max(0.0) + 1e-9 * (hi[a] - lo[a]).max(1e-300);
        lo[a] -= pad;
        hi[a] += pad;
    }
    (lo, hi)
}

/// The share of a particle's extinction that rays inside the box [lo, hi] meet, the mean over ray
/// directions. A grain walked one by one removes C_t,i from a beam over its disk of radius R (`reach`)
/// perpendicular to the ray (`discrete` docs); where the disk reaches past a face of the box that holds
/// the grains, the part beyond falls on rays outside it, which a medium held by that box never carries
/// (a query radius of 3 mm over a 20 mm cube: 16 % of the grains' extinction; issue 43). A point
/// spread uniformly over a disk of random orientation has a component along the face normal u R with
/// u = ρ c, ρ of density 2ρ on [0, 1] and c uniform on [−1, 1], so the share of the disk beyond a
/// face at distance d = u R from the centre is P(ρ c > u) = (1 − u)² / 2. The field keeps C_t,i
/// times 1 − Σ_faces (1 − d / R)₊² / 2: its cells, which fill only the box, then remove what the
/// grains remove from rays inside it (over a face the mean of R / 6 per unit area of face).
pub(super) fn inside_share(p: [f64; 3], reach: f64, lo: [f64; 3], hi: [f64; 3]) -> f64 {
    if reach.is_nan() || reach <= 0.0 {
        return 1.0;
    }
    let beyond = |d: f64| {
        let u = (1.0 - d / reach).clamp(0.0, 1.0);
        0.5 * u * u
    };
    let out: f64 = (0..3)
        .map(|a| beyond(p[a] - lo[a]) + beyond(hi[a] - p[a]))
        .sum();
    (1.0 - out).max(0.0)
}

/// σ_t of each cell (its particles' summed `weight` over `cell_volume`) and each particle's running
/// share of its cell's extinction in units of 1/65535 (the last of a cell 65535; a cell without
/// extinction shares it evenly), the particles `order` in cells `start`.
fn cell_shares(
    order: &[u32],
    start: &[u32],
    weight: Column,
    cell_volume: f64,
) -> (Vec<f32>, Vec<u16>) {
    let n_cells = start.len() - 1;
    let mut sigma = vec![0f32; n_cells];
    let mut cdf = vec![0u16; order.len()];
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
    (sigma, cdf)
}

/// Each cell's distinct groups of classes (`group` of a class code) of a [`Members::Classes`] list
/// (cells `start`), with their summed shares of the cell's extinction and the first class of each,
/// packed as the list is: (first entry per cell, entries), or None where a cell holds more than
/// sixteen groups or the whole would not be at most a quarter of the list.
pub(super) fn distinct_classes(
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
pub(super) fn block_majorants(
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
