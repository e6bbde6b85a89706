//! One size class of a grid and its build: the storage order, overlap slots or centre cells, and
//! quantised slots.

use super::settings::{
    bounding_box_by, cell_spacing, is_sparse, BOX_MARGIN, CENTRE_CELLS_FACTOR,
    FREE_PATH_CELLS_PER_PARTICLE_MAX, MAX_CELLS_PER_AXIS,
};
use super::slots::{
    ball_contribution, lattice_point, QBlock, QSlots, Spheres, LANES, LATTICE_PER_CELL,
    PADDING_SLOT,
};
use super::{GridSettings, Particles};
use crate::space::dda::GridFrame;
use crate::space::ray::RaySegment;
use rayon::prelude::*;

/// Slot data above which a traversal prefetches every block of a batch (below it the blocks stay
/// cached and the prefetches only cost: sparse dust 0.47 -> 0.55 us per ray; dense haze 4.3 -> 3.7, in
/// `benches/traverse.rs`).
pub(super) const PREFETCH_SLOTS_ABOVE_BYTES: usize = 4 << 20;

/// One size class of a [`ParticleGrid`]: particles of similar inclusion radius in a uniform grid whose cells are at least
/// as large as that radius (so a traversal scans only the 3×3×3 cells around each ray cell).
pub struct SubGrid {
    /// Centre (scene units) and inclusion radius R_i = r_c + r_i of each stored particle, stored in
    /// cell order.
    pub(super) particles: Spheres,
    /// Optical depth contributed per particle, C_t / (π R_i²) in scene units⁰, [particle][channel].
    pub(super) tau: Vec<f32>,
    /// Original index of each stored particle.
    pub(super) index: Vec<u32>,
    pub(super) channels: usize,
    /// Cell `c` holds slots `start[c]..start[c+1]`: k = 0, its own copies of the spheres of every
    /// particle whose ball overlaps it (`inline`, with `slot_tau`, `slot_index`), so a step reads one contiguous
    /// run; k = 1, the particles whose centre it holds (slot = stored particle).
    pub(super) start: Vec<u32>,
    pub(super) inline: Spheres,
    /// Per slot (k = 0): the particle's τ per channel and its original index, so that a hit reads
    /// them next to the slot instead of through the stored particle (two dependent cache misses per
    /// hit on clouds that overflow the cache). Empty for k = 1, whose slots are the stored particles.
    pub(super) slot_tau: Vec<f32>,
    pub(super) slot_index: Vec<u32>,
    /// The class's slots quantised (compact storage, [`GridSettings::quantise`]): in place of
    /// `inline` and `slot_tau` (k = 0), or of `particles` and `tau` (k = 1).
    pub(super) quant: Option<QSlots>,
    /// The cells (cubes) as a DDA walks them.
    pub(super) frame: GridFrame,
    /// Largest inclusion radius.
    pub(super) reach_max: f64,
    /// Neighbourhood half-width in cells scanned per traversal step: 0 (sparse) or 1 (dense).
    pub(super) k: i64,
    /// Are the slots too many to stay in cache (then a batch prefetches every block it will test)?
    pub(super) prefetch_slots: bool,
    /// Particles of the class (`particles`, `tau` and `index` are emptied by `release_stored` where the
    /// slots hold copies of everything a walk reads).
    pub(super) count: usize,
    /// Positional identities ([`ParticleGrid::positional`]): a k = 1 class with no `index` reports
    /// stored particle j as `first_id + j`.
    pub(super) first_id: u32,
}

/// Counting sort of items by key (O(N)): the start of each key's run and the items in key order.
pub(super) fn counting_sort(keys: &[u32], n_keys: usize) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; n_keys + 1];
    for &c in keys {
        start[c as usize + 1] += 1;
    }
    for c in 0..n_keys {
        start[c + 1] += start[c];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; keys.len()];
    for (i, &c) in keys.iter().enumerate() {
        order[fill[c as usize] as usize] = i as u32;
        fill[c as usize] += 1;
    }
    (start, order)
}

/// The slots of a k = 0 class: every cell references each stored particle whose inclusion ball
/// overlaps it, padded to whole blocks. Returns each cell's first slot (and the end) and the stored
/// particle of each slot (`PADDING_SLOT` for padding).
pub(super) fn inline_slots(
    at: &(impl Fn(usize) -> [f64; 3] + Sync),
    reach: &impl Fn(usize) -> f64,
    order: &[u32],
    lo: [f64; 3],
    cell: f64,
    dims: [usize; 3],
) -> (Vec<u32>, Vec<u32>) {
    let n_cells = dims[0] * dims[1] * dims[2];
    let cell_index = |idx: [usize; 3]| (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
    // Cell ranges (per axis) overlapped by each stored particle's inclusion ball, then a second
    // counting sort of the (cell, particle) references.
    let axis_range = |x: f64, r: f64, a: usize| -> [usize; 2] {
        [x - r, x + r].map(|y| (((y - lo[a]) / cell).floor().max(0.0) as usize).min(dims[a] - 1))
    };
    let mut ref_cell = Vec::new();
    let mut ref_particle = Vec::new();
    for (j, &i) in order.iter().enumerate() {
        let (p, r) = (at(i as usize), reach(i as usize) * BOX_MARGIN.0);
        let rg = [0, 1, 2].map(|a| axis_range(p[a], r, a));
        for z in rg[2][0]..=rg[2][1] {
            for y in rg[1][0]..=rg[1][1] {
                for x in rg[0][0]..=rg[0][1] {
                    ref_cell.push(cell_index([x, y, z]) as u32);
                    ref_particle.push(j as u32);
                }
            }
        }
    }
    let (refs_start, slot_order) = counting_sort(&ref_cell, n_cells);
    // Each cell's run padded to whole blocks, so that a step tests whole blocks of its own
    // (no lane masks, and a cell of eight never straddles two blocks). Padding lanes have NaN
    // centres: every comparison with them is false, so they contribute to no ray.
    let mut start = vec![0u32; n_cells + 1];
    for c in 0..n_cells {
        let len = refs_start[c + 1] - refs_start[c];
        start[c + 1] = start[c] + len.div_ceil(LANES as u32) * LANES as u32;
    }
    let mut slot_particle = vec![PADDING_SLOT; start[n_cells] as usize];
    for c in 0..n_cells {
        let (from, to) = (refs_start[c] as usize, refs_start[c + 1] as usize);
        for (k, &r) in slot_order[from..to].iter().enumerate() {
            slot_particle[start[c] as usize + k] = ref_particle[r as usize];
        }
    }
    (start, slot_particle)
}

/// Each slot's copy of its particle's sphere (padding: NaN centres, which no test passes).
pub(super) fn slot_spheres(slot_particle: &[u32], particles: &Spheres) -> Spheres {
    Spheres::from_iter(slot_particle.len(), |s| match slot_particle[s] {
        PADDING_SLOT => [f32::NAN, f32::NAN, f32::NAN, 0.0],
        j => particles.get(j as usize),
    })
}

/// The quantised slots ([`QSlots`]) of a class of particles at `positions` (storage order `order`) on
/// the lattice of `step` from `lo` (each at its nearest point), or None where they have more distinct
/// (R, τ) pairs than a u16 code holds (then the class keeps spheres). `slot_particle`: each slot's
/// stored particle (k = 0), or None where slot j is stored particle j (k = 1).
#[allow(clippy::too_many_arguments)]
pub(super) fn build_qslots(
    position: impl Fn(usize) -> [f64; 3],
    reach: impl Fn(usize) -> f64,
    tau: impl Fn(usize, usize) -> f32,
    channels: usize,
    order: &[u32],
    start: &[u32],
    slot_particle: Option<&[u32]>,
    lo: [f64; 3],
    step: f64,
    dims: [usize; 3],
) -> Option<QSlots> {
    if channels > 3 {
        return None;
    }
    // Codes by (R, τ) of each stored particle j; code 0 is padding.
    let mut table: rustc_hash::FxHashMap<[u32; 4], u16> = Default::default();
    let mut q_reach = vec![f32::NAN];
    let mut q_tau = vec![0f32; channels];
    let mut code_of = Vec::with_capacity(order.len());
    for &i in order {
        let r = reach(i as usize) as f32;
        let mut t = [0f32; 3];
        for (ch, x) in t.iter_mut().enumerate().take(channels) {
            *x = tau(i as usize, ch);
        }
        let t = &t[..channels];
        let mut key = [r.to_bits(), 0, 0, 0];
        for (k, x) in t.iter().enumerate() {
            key[k + 1] = x.to_bits();
        }
        let code = match table.get(&key) {
            Some(&c) => c,
            None => {
                if q_reach.len() > u16::MAX as usize {
                    return None;
                }
                let c = q_reach.len() as u16;
                table.insert(key, c);
                q_reach.push(r);
                q_tau.extend_from_slice(t);
                c
            }
        };
        code_of.push(code);
    }
    let slots = slot_particle.map_or(order.len(), <[u32]>::len);
    let mut blocks = vec![QBlock::default(); slots.div_ceil(LANES)];
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let c = (z * dims[1] + y) * dims[0] + x;
                let origin = [x, y, z].map(|i| (i as i64 - 1) * LATTICE_PER_CELL);
                for s in start[c] as usize..start[c + 1] as usize {
                    let j = slot_particle.map_or(s as u32, |sp| sp[s]);
                    if j == PADDING_SLOT {
                        continue; // code 0, R = NaN
                    }
                    let g = lattice_point(position(order[j as usize] as usize), lo, step);
                    // The coordinates modulo 2^16 (`LATTICE_PER_CELL`), read relative to a corner
                    // within four cells below.
                    // From the slot's cell's corner: [L, 2L) for a centre cell (its own centre),
                    // [0, 2^16) for an overlap slot (a ball that reaches into the cell).
                    let q = [0, 1, 2].map(|a| {
                        let rel = g[a] - origin[a];
                        let own = LATTICE_PER_CELL..2 * LATTICE_PER_CELL;
                        debug_assert!(
                            if slot_particle.is_none() {
                                own.contains(&rel)
                            } else {
                                (0..=u16::MAX as i64).contains(&rel)
                            },
                            "lattice offset {rel}"
                        );
                        g[a] as u16
                    });
                    let (b, l) = (&mut blocks[s / LANES], s % LANES);
                    (b.x[l], b.y[l], b.z[l], b.code[l]) = (q[0], q[1], q[2], code_of[j as usize]);
                }
            }
        }
    }
    let block_reach = blocks
        .iter()
        .map(|b| {
            b.code
                .iter()
                .filter(|&&c| c != 0)
                .map(|&c| q_reach[c as usize])
                .fold(0.0f32, f32::max)
        })
        .collect();
    Some(QSlots {
        blocks,
        block_reach,
        reach: q_reach,
        tau: q_tau,
        step,
    })
}

/// The optical depth of a particle's disk in one channel: C_ext / (π R²), R its inclusion radius
/// (the caller has already capped it at tau_max by widening R).
#[inline]
pub(super) fn disk_tau(c_ext: f64, reach: f64) -> f32 {
    (c_ext / (std::f64::consts::PI * reach * reach)) as f32
}

/// Each particle's [`disk_tau`] per channel, in storage order `order`.
pub(super) fn disk_taus(
    order: &[u32],
    tau: impl Fn(usize, usize) -> f32,
    channels: usize,
) -> Vec<f32> {
    let mut out = vec![0f32; order.len() * channels];
    for (j, &i) in order.iter().enumerate() {
        for ch in 0..channels {
            out[j * channels + ch] = tau(i as usize, ch);
        }
    }
    out
}

/// What a hit reads, per slot of a k = 0 class: its particle's τ per channel and original index
/// (padding slots: τ = 0, index unused); no τ where `tau` is empty (quantised slots: τ by code).
pub(super) fn slot_hits(
    slot_particle: &[u32],
    tau: &[f32],
    index: &[u32],
    channels: usize,
) -> (Vec<f32>, Vec<u32>) {
    let slot_of = |sp: &u32| (*sp != PADDING_SLOT).then_some(*sp as usize);
    if tau.is_empty() {
        let index = slot_particle
            .iter()
            .map(|sp| slot_of(sp).map_or(u32::MAX, |j| index[j]))
            .collect();
        return (Vec::new(), index);
    }
    let mut slot_tau = vec![0f32; slot_particle.len() * channels];
    for (s, sp) in slot_particle.iter().enumerate() {
        if let Some(j) = slot_of(sp) {
            slot_tau[s * channels..(s + 1) * channels]
                .copy_from_slice(&tau[j * channels..(j + 1) * channels]);
        }
    }
    let slot_index = slot_particle
        .iter()
        .map(|sp| slot_of(sp).map_or(u32::MAX, |j| index[j]))
        .collect();
    (slot_tau, slot_index)
}

impl SubGrid {
    /// Build one class from already validated inputs (see [`ParticleGrid::build`]): the particles
    /// `ids` of `p` (the caller's indices, which the class reports).
    pub(super) fn build_class(
        p: &Particles,
        ids: &[u32],
        settings: &GridSettings,
        volume_hint: Option<f64>,
        free_path_cell: Option<f64>,
    ) -> Self {
        let (n, channels) = (ids.len(), p.channels);
        // The class's particle j: the caller's ids[j], read where needed (no copies of the columns).
        let position = |j: usize| p.positions[ids[j] as usize];
        let reach = |j: usize| settings.query_radius + (p.radius)(ids[j] as usize);
        let tau = |j: usize, ch: usize| disk_tau((p.c_ext)(ids[j] as usize, ch), reach(j));
        let reach_max = (0..n).into_par_iter().map(reach).reduce(|| 0.0, f64::max);
        let (mut lo, mut hi) = bounding_box_by(n, position);
        for a in 0..3 {
            lo[a] -= reach_max * BOX_MARGIN.0 + BOX_MARGIN.1;
            hi[a] += reach_max * BOX_MARGIN.0 + BOX_MARGIN.1;
        }
        let mut ext: Vec<f64> = (0..3).map(|a| hi[a] - lo[a]).collect();
        let volume = volume_hint
            .unwrap_or(ext[0] * ext[1] * ext[2])
            .max(ext[0] * ext[1] * ext[2] * 1e-9);

        // About `cells_per_particle` cells per particle. Sparse classes (inclusion diameter below the
        // cell) reference each particle from every cell its ball overlaps (k = 0: a traversal tests only
        // the ray's own cells). Dense classes (balls wider than the spacing) would need many references
        // per particle; there cells are at least R_max wide, each particle is referenced by its centre's
        // cell only, and a traversal scans the 3×3×3 cells around the ray's cell (k = 1).
        // With `centre_cells` every class is stored by its centres' cells (k = 1; issue 24's compact
        // storage: each particle once, in eight bytes).
        let factor = if settings.centre_cells {
            CENTRE_CELLS_FACTOR
        } else {
            1.0
        };
        let mut spacing = cell_spacing(volume, n, settings.cells_per_particle * factor);
        if let Some(l) = free_path_cell {
            // An optically thick cloud: cells about its free flights' length (FREE_PATHS_PER_CELL).
            let finest = cell_spacing(volume, n, FREE_PATH_CELLS_PER_PARTICLE_MAX);
            spacing = spacing.min(l.max(finest));
        }
        let k: i64 = if !settings.centre_cells && is_sparse(reach_max, spacing) {
            0
        } else {
            1
        };
        let cell = spacing.max(reach_max).max(1e-12);
        // Compact storage quantises a class's centres to a lattice of its cells (`QSlots`): from here
        // on the particles are those lattice points, the box grown by two steps to hold them.
        let quantise = settings.quantise;
        let step = cell / LATTICE_PER_CELL as f64;
        if quantise {
            for a in 0..3 {
                lo[a] -= 2.0 * step;
                hi[a] += 2.0 * step;
                ext[a] = hi[a] - lo[a];
            }
        }
        // Each particle's centre as stored (computed where needed: no copy of the positions).
        let at = |i: usize| -> [f64; 3] {
            if quantise {
                let g = lattice_point(position(i), lo, step);
                [0, 1, 2].map(|a| lo[a] + g[a] as f64 * step)
            } else {
                position(i)
            }
        };
        let dims =
            [0, 1, 2].map(|a| ((ext[a] / cell).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS));
        let n_cells = dims[0] * dims[1] * dims[2];
        let cell_index = |idx: [usize; 3]| (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
        let cell_of = |p: &[f64; 3]| {
            cell_index([0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1)))
        };
        // The storage order: particles sorted by the cell of their centre. A quantised centre's cell
        // comes from its lattice coordinates, in integers: a lattice point on a cell face must be in
        // the cell whose corner its slots are read from (in floating point (lo + g h − lo) / L can
        // round below the face, and the wrapped offset from a row's corner 3 cells down would read
        // 2^16 as 0: the centre 4 cells away).
        let cells: Vec<u32> = (0..n)
            .into_par_iter()
            .map(|i| {
                if quantise {
                    let g = lattice_point(position(i), lo, step);
                    cell_index([0, 1, 2].map(|a| {
                        (g[a].div_euclid(LATTICE_PER_CELL).max(0) as usize).min(dims[a] - 1)
                    })) as u32
                } else {
                    cell_of(&at(i)) as u32
                }
            })
            .collect();
        let (centre_start, mut order) = counting_sort(&cells, n_cells);
        drop(cells);
        if quantise && k == 1 {
            // Largest balls first in each cell: a block's pre-test radius is its largest.
            for c in 0..n_cells {
                order[centre_start[c] as usize..centre_start[c + 1] as usize]
                    .sort_unstable_by(|a, b| reach(*b as usize).total_cmp(&reach(*a as usize)));
            }
        }
        let sphere_of = |i: usize| {
            let p = at(i);
            [p[0] as f32, p[1] as f32, p[2] as f32, reach(i) as f32]
        };
        // Quantised k = 1 slots are the stored particles: no spheres besides them.
        let particles = if quantise && k == 1 {
            Spheres::default()
        } else {
            Spheres::from_iter(n, |j| sphere_of(order[j] as usize))
        };
        let (start, mut slot_particle) = if k == 1 {
            // Each cell's slots are its own particles, already in cell order.
            (centre_start, Vec::new())
        } else {
            inline_slots(&at, &reach, &order, lo, cell, dims)
        };
        if quantise && k == 0 {
            // Largest balls first in each cell, padding last: a block's pre-test radius is its
            // largest, so blocks of like radii test tightly.
            let key = |j: &u32| match *j {
                PADDING_SLOT => -1.0,
                j => reach(order[j as usize] as usize),
            };
            for c in 0..n_cells {
                slot_particle[start[c] as usize..start[c + 1] as usize]
                    .sort_unstable_by(|a, b| key(b).total_cmp(&key(a)));
            }
        }
        let quant = quantise
            .then(|| {
                build_qslots(
                    position,
                    reach,
                    tau,
                    channels,
                    &order,
                    &start,
                    (k == 0).then_some(&slot_particle[..]),
                    lo,
                    step,
                    dims,
                )
            })
            .flatten();
        let particles = match (&quant, k) {
            // Too many codes: spheres after all.
            (None, 1) if particles.0.is_empty() && n > 0 => {
                Spheres::from_iter(n, |j| sphere_of(order[j] as usize))
            }
            _ => particles,
        };
        // τ per stored particle where no code holds it.
        let tau = if quant.is_some() {
            Vec::new()
        } else {
            disk_taus(&order, tau, channels)
        };
        let inline = if k == 0 && quant.is_none() {
            slot_spheres(&slot_particle, &particles)
        } else {
            Spheres::default()
        };
        let index: Vec<u32> = order.iter().map(|&i| ids[i as usize]).collect();
        let slot_bytes = quant.as_ref().map_or(inline.bytes(), QSlots::bytes);
        let prefetch_slots = slot_bytes.max(particles.bytes()) > PREFETCH_SLOTS_ABOVE_BYTES;
        // Quantised slots read τ by code.
        let slot_tau_of: &[f32] = if quant.is_some() { &[] } else { &tau };
        let (slot_tau, slot_index) = slot_hits(&slot_particle, slot_tau_of, &index, channels);
        SubGrid {
            particles,
            tau,
            index,
            channels,
            start,
            inline,
            slot_tau,
            slot_index,
            quant,
            frame: GridFrame::new(lo, [cell; 3], dims),
            reach_max,
            k,
            prefetch_slots,
            count: n,
            first_id: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Drop the stored particles of a class whose cells hold their own copies (k = 0): a walk, a
    /// point query and a hit read only the slots. The oracles then read the slots too.
    pub(super) fn release_stored(&mut self) {
        if self.k == 0 {
            self.particles = Spheres::default();
            self.tau = Vec::new();
            self.index = Vec::new();
        }
    }

    /// Each particle once with its sphere, τ per channel and original index: the stored particles,
    /// or (released) the first slot of each (the oracles' view).
    #[cfg(any(test, feature = "oracles"))]
    pub(super) fn each_particle(&self, mut visit: impl FnMut(([f64; 3], f64), &[f32], u32)) {
        let ball = |p: [f32; 4]| ([p[0] as f64, p[1] as f64, p[2] as f64], p[3] as f64);
        if self.index.len() == self.count && self.quant.is_none() {
            for j in 0..self.count {
                visit(
                    ball(self.particles.get(j)),
                    &self.tau[j * self.channels..(j + 1) * self.channels],
                    self.index[j],
                );
            }
            return;
        }
        // The slots (quantised: decoded in their cells), each particle at its first.
        let mut seen = std::collections::HashSet::new();
        let dims = self.frame.dims;
        for c in 0..dims[0] * dims[1] * dims[2] {
            let cell = [c % dims[0], c / dims[0] % dims[1], c / (dims[0] * dims[1])];
            for s in self.start[c] as usize..self.start[c + 1] as usize {
                let i = self.hit_index(s);
                if i != u32::MAX && seen.insert(i) {
                    visit(self.slot_ball(s, cell), self.hit_tau(s), i);
                }
            }
        }
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    pub fn dims(&self) -> [usize; 3] {
        self.frame.dims
    }

    /// Heap bytes of the grid and the particles it stores.
    pub fn bytes(&self) -> usize {
        self.particles.bytes()
            + self.inline.bytes()
            + self.quant.as_ref().map_or(0, QSlots::bytes)
            + self.slot_tau.len() * 4
            + self.slot_index.len() * 4
            + self.tau.len() * 4
            + self.index.len() * 4
            + self.start.len() * 4
    }

    /// The slots' spheres.
    #[inline(always)]
    pub(super) fn slots(&self) -> &Spheres {
        if self.k == 0 {
            &self.inline
        } else {
            &self.particles
        }
    }

    /// Centre and inclusion radius of slot `s` of cell `cell` (double precision).
    #[inline(always)]
    pub(super) fn slot_ball(&self, s: usize, cell: [usize; 3]) -> ([f64; 3], f64) {
        match &self.quant {
            Some(q) => q.ball(self.frame.bounds.lo, s, cell),
            None => {
                let p = self.slots().get(s);
                ([p[0] as f64, p[1] as f64, p[2] as f64], p[3] as f64)
            }
        }
    }

    /// τ per channel of the particle in slot `s` (what `walk` reports).
    #[inline(always)]
    pub(super) fn hit_tau(&self, s: usize) -> &[f32] {
        if let Some(q) = &self.quant {
            let c = q.code(s);
            return &q.tau[c * self.channels..(c + 1) * self.channels];
        }
        let tau = if self.k == 0 {
            &self.slot_tau
        } else {
            &self.tau
        };
        &tau[s * self.channels..(s + 1) * self.channels]
    }

    /// Original index of the particle in slot `s` (positional grids: its position).
    #[inline(always)]
    pub(super) fn hit_index(&self, s: usize) -> u32 {
        if self.k == 0 {
            self.slot_index[s]
        } else if self.index.is_empty() {
            self.first_id + s as u32
        } else {
            self.index[s]
        }
    }

    /// Optical depth of a ray segment, per channel, by a loop over every particle (the O(N) oracle of
    /// the tests).
    #[cfg(any(test, feature = "oracles"))]
    pub fn optical_depth_brute(&self, ray: &RaySegment, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        if ray.is_empty() {
            return;
        }
        self.each_particle(|(c, r), tau, _| {
            if let Some(t) = ball_contribution(c, r, ray) {
                if ray.contains(t) {
                    out.iter_mut().zip(tau).for_each(|(v, &x)| *v += x as f64);
                }
            }
        });
    }

    /// Per-stored-particle optical depth (channel), for tests.
    #[cfg(any(test, feature = "oracles"))]
    pub fn tau_of(&self, original: u32, channel: usize) -> f64 {
        let mut out = None;
        self.each_particle(|_, tau, i| {
            if i == original {
                out = Some(tau[channel] as f64);
            }
        });
        out.expect("a particle of this class")
    }

    pub fn reach_max(&self) -> f64 {
        self.reach_max
    }
}
