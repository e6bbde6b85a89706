//! A size class's build: its cells, the storage order, overlap slots or centre cells, and quantised
//! slots.

use super::settings::{
    bounding_box_by, cell_spacing, is_sparse, BOX_MARGIN, CENTRE_CELLS_FACTOR,
    FREE_PATH_CELLS_PER_PARTICLE_MAX, MAX_CELLS_PER_AXIS,
};
use super::slots::{lattice_point, QBlock, QSlots, Spheres, LANES, LATTICE_PER_CELL, PADDING_SLOT};
use super::{GridSettings, Particles, SubGrid};
use crate::space::dda::GridFrame;
use rayon::prelude::*;

/// Slot data above which a traversal prefetches every block of a batch (below it the blocks stay
/// cached and the prefetches only cost).
pub(super) const PREFETCH_SLOTS_ABOVE_BYTES: usize = 4 << 20;

/// Counting sort of items by key (O(N)): the start of each key's run and the items in key order.
pub(super) fn counting_sort(keys: &[u32], n_keys: usize) -> (Vec<u32>, Vec<u32>) {
    counting_sort_by(keys, n_keys, |i| i as u32)
}

/// [`counting_sort`] of the items `item(0..)` whose keys are `keys`.
pub(crate) fn counting_sort_by(
    keys: &[u32],
    n_keys: usize,
    item: impl Fn(usize) -> u32,
) -> (Vec<u32>, Vec<u32>) {
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
        order[fill[c as usize] as usize] = item(i);
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

/// The quantised slots ([`QSlots`]) of a class of particles at `positions` (storage order `order`)
/// on the lattice of its `layout` (each at its nearest point), or None where the layout is not
/// quantised or they have more distinct (R, τ) pairs than a u16 code holds (then the class keeps
/// spheres). `slot_particle`: each slot's stored particle (k = 0), or None where slot j is stored
/// particle j (k = 1).
#[allow(clippy::too_many_arguments)]
fn build_qslots(
    position: impl Fn(usize) -> [f64; 3],
    reach: impl Fn(usize) -> f64,
    tau: impl Fn(usize, usize) -> f32,
    channels: usize,
    order: &[u32],
    start: &[u32],
    slot_particle: Option<&[u32]>,
    layout: &ClassLayout,
) -> Option<QSlots> {
    let step = layout.step?;
    if channels > 3 {
        return None;
    }
    let (code_of, q_reach, q_tau) = qslot_codes(order, reach, tau, channels)?;
    let blocks = qslot_blocks(
        position,
        order,
        start,
        slot_particle,
        layout,
        step,
        &code_of,
    );
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

/// The code of each stored particle (storage order `order`) by its (R, τ) pair, and each code's R and τ
/// per channel (code 0 is padding: R = NaN, τ = 0); None where the pairs outnumber a u16's codes.
fn qslot_codes(
    order: &[u32],
    reach: impl Fn(usize) -> f64,
    tau: impl Fn(usize, usize) -> f32,
    channels: usize,
) -> Option<(Vec<u16>, Vec<f32>, Vec<f32>)> {
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
    Some((code_of, q_reach, q_tau))
}

/// The blocks of quantised slots: each slot's lattice coordinates modulo 2^16 and its particle's code
/// (`code_of`, by stored particle), the arguments as [`build_qslots`]'s.
fn qslot_blocks(
    position: impl Fn(usize) -> [f64; 3],
    order: &[u32],
    start: &[u32],
    slot_particle: Option<&[u32]>,
    layout: &ClassLayout,
    step: f64,
    code_of: &[u16],
) -> Vec<QBlock> {
    let (lo, dims) = (layout.lo, layout.dims);
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
    blocks
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

/// Where a class's cells lie and how it stores its particles: the grid's corner, cell edge and cells
/// per axis, the layout (k = 0: overlap slots; 1: centre cells) and, where its slots are quantised,
/// the lattice step of its centres.
#[derive(Clone, Copy)]
struct ClassLayout {
    lo: [f64; 3],
    cell: f64,
    dims: [usize; 3],
    k: i64,
    step: Option<f64>,
}

impl ClassLayout {
    /// The layout of a class of `n` particles at `position(0..n)` whose inclusion radii reach up to
    /// `reach_max`: its box is the centres' box grown by R_max (and, quantised, by two lattice steps).
    fn new(
        n: usize,
        position: impl Fn(usize) -> [f64; 3] + Sync,
        reach_max: f64,
        settings: &GridSettings,
        volume_hint: Option<f64>,
        free_path_cell: Option<f64>,
    ) -> Self {
        let (mut lo, mut hi) = bounding_box_by(n, position);
        for a in 0..3 {
            lo[a] -= reach_max * BOX_MARGIN.0 + BOX_MARGIN.1;
            hi[a] += reach_max * BOX_MARGIN.0 + BOX_MARGIN.1;
        }
        let mut ext: Vec<f64> = (0..3).map(|a| hi[a] - lo[a]).collect();
        let volume = volume_hint
            .unwrap_or(ext[0] * ext[1] * ext[2])
            .max(ext[0] * ext[1] * ext[2] * 1e-9);
        let (k, cell) = class_cells(settings, volume, n, free_path_cell, reach_max);
        // Compact storage quantises a class's centres to a lattice of its cells (`QSlots`): from here
        // on the particles are those lattice points, the box grown by two steps to hold them.
        let step = settings.quantise.then(|| cell / LATTICE_PER_CELL as f64);
        if let Some(step) = step {
            for a in 0..3 {
                lo[a] -= 2.0 * step;
                hi[a] += 2.0 * step;
                ext[a] = hi[a] - lo[a];
            }
        }
        let dims =
            [0, 1, 2].map(|a| ((ext[a] / cell).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS));
        ClassLayout {
            lo,
            cell,
            dims,
            k,
            step,
        }
    }

    fn cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// A particle's centre as stored, from its centre `p` (quantised: the nearest lattice point).
    #[inline]
    fn stored(&self, p: [f64; 3]) -> [f64; 3] {
        if let Some(step) = self.step {
            let g = lattice_point(p, self.lo, step);
            [0, 1, 2].map(|a| self.lo[a] + g[a] as f64 * step)
        } else {
            p
        }
    }

    /// The cell that stores a particle centred at `p`. A quantised centre's cell comes from its
    /// lattice coordinates, in integers: a lattice point on a cell face must be in the cell whose
    /// corner its slots are read from (in floating point (lo + g h − lo) / L can round below the face,
    /// and the wrapped offset from a row's corner 3 cells down would read 2^16 as 0: the centre 4
    /// cells away).
    #[inline]
    fn cell_of(&self, p: [f64; 3]) -> usize {
        let (lo, dims) = (self.lo, self.dims);
        let idx = if let Some(step) = self.step {
            let g = lattice_point(p, lo, step);
            [0, 1, 2].map(|a| (g[a].div_euclid(LATTICE_PER_CELL).max(0) as usize).min(dims[a] - 1))
        } else {
            [0, 1, 2].map(|a| (((p[a] - lo[a]) / self.cell) as usize).min(dims[a] - 1))
        };
        (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0]
    }
}

/// The layout (k) and cell edge of a class of `n` particles in `volume` whose inclusion radii reach
/// up to `reach_max`: about `cells_per_particle` cells per particle. Sparse classes (inclusion diameter
/// below the cell) reference each particle from every cell its ball overlaps (k = 0: a traversal
/// tests only the ray's own cells). Dense classes (balls wider than the spacing) would need many
/// references per particle; there cells are at least R_max wide, each particle is referenced by its
/// centre's cell only, and a traversal scans the 3×3×3 cells around the ray's cell (k = 1). With
/// `centre_cells` every class is stored by its centres' cells (k = 1; compact storage: each particle
/// once, in eight bytes).
fn class_cells(
    settings: &GridSettings,
    volume: f64,
    n: usize,
    free_path_cell: Option<f64>,
    reach_max: f64,
) -> (i64, f64) {
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
    (k, spacing.max(reach_max).max(1e-12))
}

/// The storage order of a class of `n` particles: each cell's first stored particle (and the end),
/// and the particles sorted by the cell of their centre (quantised centre cells: largest balls first
/// in each cell, as a block's pre-test radius is its largest).
fn storage_order(
    layout: &ClassLayout,
    n: usize,
    position: impl Fn(usize) -> [f64; 3] + Sync,
    reach: impl Fn(usize) -> f64,
) -> (Vec<u32>, Vec<u32>) {
    let cells: Vec<u32> = (0..n)
        .into_par_iter()
        .map(|i| layout.cell_of(position(i)) as u32)
        .collect();
    let (centre_start, mut order) = counting_sort(&cells, layout.cells());
    drop(cells);
    if layout.step.is_some() && layout.k == 1 {
        for c in 0..layout.cells() {
            order[centre_start[c] as usize..centre_start[c + 1] as usize]
                .sort_unstable_by(|a, b| reach(*b as usize).total_cmp(&reach(*a as usize)));
        }
    }
    (centre_start, order)
}

/// Each cell's first slot (and the end) and, k = 0, the stored particle of each slot: centre cells'
/// slots are their own particles, already in cell order (`centre_start`); overlap slots reference
/// every ball that overlaps the cell (quantised: largest first, padding last, so that blocks of like
/// radii test tightly).
fn class_slots(
    layout: &ClassLayout,
    centre_start: Vec<u32>,
    order: &[u32],
    at: &(impl Fn(usize) -> [f64; 3] + Sync),
    reach: impl Fn(usize) -> f64,
) -> (Vec<u32>, Vec<u32>) {
    if layout.k == 1 {
        return (centre_start, Vec::new());
    }
    let (lo, cell, dims) = (layout.lo, layout.cell, layout.dims);
    let (start, mut slot_particle) = inline_slots(at, &reach, order, lo, cell, dims);
    if layout.step.is_some() {
        let key = |j: &u32| match *j {
            PADDING_SLOT => -1.0,
            j => reach(order[j as usize] as usize),
        };
        for c in 0..layout.cells() {
            slot_particle[start[c] as usize..start[c + 1] as usize]
                .sort_unstable_by(|a, b| key(b).total_cmp(&key(a)));
        }
    }
    (start, slot_particle)
}

impl SubGrid {
    /// Build one class from already validated inputs (see [`ParticleGrid::build`](super::ParticleGrid::build)): the particles
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
        let layout = ClassLayout::new(
            n,
            position,
            reach_max,
            settings,
            volume_hint,
            free_path_cell,
        );
        // Each particle's centre as stored, computed where needed (no copy of the positions).
        let at = |i: usize| layout.stored(position(i));
        let (centre_start, order) = storage_order(&layout, n, position, reach);
        let (start, slot_particle) = class_slots(&layout, centre_start, &order, &at, reach);
        let slot_of = (layout.k == 0).then_some(&slot_particle[..]);
        let quant = build_qslots(
            position, reach, tau, channels, &order, &start, slot_of, &layout,
        );
        // Spheres of the stored particles, but where quantised centre cells are them (unless their
        // (R, τ) pairs were too many for codes: spheres after all).
        let particles = if layout.k == 1 && quant.is_some() {
            Spheres::default()
        } else {
            Spheres::from_iter(n, |j| {
                let i = order[j] as usize;
                let p = at(i);
                [p[0] as f32, p[1] as f32, p[2] as f32, reach(i) as f32]
            })
        };
        // τ per stored particle where no code holds it.
        let tau = if quant.is_some() {
            Vec::new()
        } else {
            disk_taus(&order, tau, channels)
        };
        let inline = if layout.k == 0 && quant.is_none() {
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
            frame: GridFrame::new(layout.lo, [layout.cell; 3], layout.dims),
            reach_max,
            k: layout.k,
            prefetch_slots,
            count: n,
            first_id: 0,
        }
    }
}
