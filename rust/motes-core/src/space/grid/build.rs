//! A size class's build: its cells, the storage order, overlap slots or centre cells, and quantised
//! slots.

use super::settings::{
    bounding_box_by, cell_spacing, is_sparse, BOX_MARGIN, CELLS_DRIVER, CENTRE_CELLS_FACTOR,
    FREE_PATH_CELLS_PER_PARTICLE_MAX, MAX_CELLS, MAX_CELLS_PER_AXIS,
};
use super::slots::{lattice_point, QBlock, QSlots, Spheres, LANES, LATTICE_PER_CELL, PADDING_SLOT};
use super::{GridSettings, Particles, SubGrid};
use crate::error::{try_filled, OpticsError};
use crate::space::dda::GridFrame;
use rayon::prelude::*;

/// Slot data above which a traversal prefetches every block of a batch (below it the blocks stay
/// cached and the prefetches only cost).
pub(super) const PREFETCH_SLOTS_ABOVE_BYTES: usize = 4 << 20;

/// Counting sort of items by key (O(N)): the start of each key's run and the items in key order. The
/// keys are a grid's cells (an allocation that fails names [`CELLS_DRIVER`]).
pub(super) fn counting_sort(
    keys: &[u32],
    n_keys: usize,
) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
    counting_sort_by(keys, n_keys, |i| i as u32, CELLS_DRIVER)
}

/// Items per chunk below which a parallel pass over items is not worth its threads.
const PAR_CHUNK_MIN: usize = 1 << 15;

/// A raw pointer that threads may share, to write disjoint entries of one slice (the scatter of a
/// counting sort: each position is written by exactly one item).
struct SharedOut(*mut u32);
// SAFETY: the writers through it write disjoint positions (see its uses), and the slice outlives them.
unsafe impl Send for SharedOut {}
unsafe impl Sync for SharedOut {}
impl SharedOut {
    /// The pointer (a method, so that closures capture the whole `Sync` wrapper).
    #[inline(always)]
    fn at(&self, i: usize) -> *mut u32 {
        self.0.wrapping_add(i)
    }
}

/// [`counting_sort`] of the items `item(0..)` whose keys are `keys`: stable (a key's items in the
/// order of their indices). In parallel: each of up to one chunk per thread counts its keys, the
/// counts' prefix sums give each chunk its slots in each key's run (chunks in order), and the chunks
/// scatter their items side by side: the same result as one thread's. Chunks are fewer where their
/// histograms (`n_keys` counts each) would outweigh the items. The arrays of `n_keys` (a grid's cells,
/// up to 2·10⁸) are allocated fallibly: a failure is an [`OpticsError::OutOfMemory`] naming `driver`,
/// the input that sets `n_keys`.
pub(crate) fn counting_sort_by(
    keys: &[u32],
    n_keys: usize,
    item: impl Fn(usize) -> u32 + Sync,
    driver: &'static str,
) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
    let n = keys.len();
    let chunks = rayon::current_num_threads()
        .min(n / PAR_CHUNK_MIN)
        .min(n / n_keys.max(1))
        .max(1);
    let len = n.div_ceil(chunks).max(1);
    // Each chunk's count of each key, then (in place) the first slot of its items of that key.
    let mut fill: Vec<Vec<u32>> = keys
        .par_chunks(len)
        .map(|ks| {
            let mut h = try_filled(n_keys, 0u32, driver, "a counting sort's histogram")?;
            for &c in ks {
                h[c as usize] += 1;
            }
            Ok(h)
        })
        .collect::<Result<_, OpticsError>>()?;
    let mut start = try_filled(n_keys + 1, 0u32, driver, "the cells' starts")?;
    let mut acc = 0u32;
    for c in 0..n_keys {
        start[c] = acc;
        for h in fill.iter_mut() {
            let k = h[c];
            h[c] = acc;
            acc += k;
        }
    }
    start[n_keys] = acc;
    let mut order = vec![0u32; n];
    let out = SharedOut(order.as_mut_ptr());
    keys.par_chunks(len)
        .zip(fill.par_iter_mut())
        .enumerate()
        .for_each(|(t, (ks, fill))| {
            for (k, &c) in ks.iter().enumerate() {
                let at = fill[c as usize];
                // SAFETY: `at` < n, and the prefix sums give every (chunk, key) its own range of
                // slots, so that each slot is written once, by one chunk.
                unsafe { *out.at(at as usize) = item(t * len + k) };
                fill[c as usize] = at + 1;
            }
        });
    Ok((start, order))
}

/// The items `item(0..n)` in `buckets` (at most 256) lists by `bucket(0..n)`, each list in the order
/// of the items' indices (as pushing them one by one would make them), with no spare capacity. In
/// parallel: each item's bucket (a byte), then chunks count their items per bucket, then each fills
/// its own part of every list.
pub(super) fn buckets(
    n: usize,
    buckets: usize,
    bucket: impl Fn(usize) -> usize + Sync,
    item: impl Fn(usize) -> u32 + Sync,
) -> Vec<Vec<u32>> {
    assert!(buckets <= 256, "{buckets} buckets");
    let key: Vec<u8> = (0..n).into_par_iter().map(|j| bucket(j) as u8).collect();
    let bucket = |j: usize| key[j] as usize;
    let chunk = PAR_CHUNK_MIN.max(n.div_ceil(64 * rayon::current_num_threads()));
    let chunks = n.div_ceil(chunk);
    let range = |t: usize| t * chunk..((t + 1) * chunk).min(n);
    let counts: Vec<Vec<usize>> = (0..chunks)
        .into_par_iter()
        .map(|t| {
            let mut h = vec![0usize; buckets];
            range(t).for_each(|j| h[bucket(j)] += 1);
            h
        })
        .collect();
    let mut lists: Vec<Vec<u32>> = (0..buckets)
        .map(|b| vec![0u32; counts.iter().map(|h| h[b]).sum()])
        .collect();
    // Each chunk's part of each list, side by side.
    let mut parts: Vec<Vec<&mut [u32]>> = (0..chunks).map(|_| Vec::new()).collect();
    for (b, list) in lists.iter_mut().enumerate() {
        let mut rest = &mut list[..];
        for (t, part) in parts.iter_mut().enumerate() {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(counts[t][b]);
            part.push(head);
            rest = tail;
        }
    }
    parts.into_par_iter().enumerate().for_each(|(t, mut part)| {
        let mut at = vec![0usize; buckets];
        for j in range(t) {
            let b = bucket(j);
            part[b][at[b]] = item(j);
            at[b] += 1;
        }
    });
    lists
}

/// `items`, laid out in runs `start[c]..start[c + 1]` (from 0), split into groups of whole runs of
/// about [`PAR_CHUNK_MIN`] items or more: (first run, end of the runs, the group's items).
#[allow(clippy::type_complexity)]
fn run_groups<'a, T>(items: &'a mut [T], start: &[u32]) -> Vec<(usize, usize, &'a mut [T])> {
    let runs = start.len().saturating_sub(1);
    let mut groups = Vec::new();
    let (mut rest, mut at, mut first) = (items, 0usize, 0usize);
    for c in 1..=runs {
        let end = start[c] as usize;
        if end - at >= PAR_CHUNK_MIN || c == runs {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(end - at);
            groups.push((first, c, head));
            (rest, at, first) = (tail, end, c);
        }
    }
    groups
}

/// Sort each run `items[start[c]..start[c + 1]]` largest `key` first, in parallel over groups of
/// runs: each run ends as `run.sort_unstable_by(|a, b| key(*b).total_cmp(&key(*a)))` leaves it (the
/// run's positions sorted by the same comparisons, as u32s: the same algorithm, the same ties).
pub(super) fn sort_runs_descending(
    items: &mut [u32],
    start: &[u32],
    key: impl Fn(u32) -> f64 + Sync,
) {
    run_groups(items, start)
        .into_par_iter()
        .for_each(|(c0, c1, group)| {
            let base = start[c0] as usize;
            let (mut keys, mut pos, mut tmp) = (Vec::new(), Vec::new(), Vec::new());
            for c in c0..c1 {
                let run = &mut group[start[c] as usize - base..start[c + 1] as usize - base];
                if run.len() < 2 {
                    continue;
                }
                keys.clear();
                keys.extend(run.iter().map(|&j| key(j)));
                pos.clear();
                pos.extend(0..run.len() as u32);
                pos.sort_unstable_by(|a, b| keys[*b as usize].total_cmp(&keys[*a as usize]));
                tmp.clear();
                tmp.extend(pos.iter().map(|&p| run[p as usize]));
                run.copy_from_slice(&tmp);
            }
        });
}

/// The slots of a k = 0 class: every cell references each stored particle whose inclusion ball
/// overlaps it, padded to whole blocks. Returns each cell's first slot (and the end) and the stored
/// particle of each slot (`PADDING_SLOT` for padding).
pub(super) fn inline_slots(
    at: &(impl Fn(usize) -> [f64; 3] + Sync),
    reach: &(impl Fn(usize) -> f64 + Sync),
    order: &[u32],
    lo: [f64; 3],
    cell: f64,
    dims: [usize; 3],
) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
    let n_cells = dims[0] * dims[1] * dims[2];
    let cell_index = |idx: [usize; 3]| (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
    // Cell ranges (per axis) overlapped by each stored particle's inclusion ball, then a second
    // counting sort of the (cell, particle) references.
    let axis_range = |x: f64, r: f64, a: usize| -> [usize; 2] {
        [x - r, x + r].map(|y| (((y - lo[a]) / cell).floor().max(0.0) as usize).min(dims[a] - 1))
    };
    let range_of = |j: usize| {
        let i = order[j] as usize;
        let (p, r) = (at(i), reach(i) * BOX_MARGIN.0);
        [0, 1, 2].map(|a| axis_range(p[a], r, a))
    };
    // In parallel: each chunk of particles counts its references, then writes them into its own
    // part of the lists, in the order one thread would push them (particles, then z, y, x).
    let (n, chunk) = (order.len(), PAR_CHUNK_MIN);
    let chunk_of = |t: usize| t * chunk..((t + 1) * chunk).min(n);
    let counts: Vec<usize> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|t| {
            chunk_of(t)
                .map(|j| {
                    range_of(j)
                        .iter()
                        .map(|r| r[1] + 1 - r[0])
                        .product::<usize>()
                })
                .sum()
        })
        .collect();
    let refs: usize = counts.iter().sum();
    // A reference per cell each ball overlaps: cells finer than the balls make many.
    let what = "the cells' references to the balls overlapping them";
    let (mut ref_cell, mut ref_particle) = (
        try_filled(refs, 0u32, CELLS_DRIVER, what)?,
        try_filled(refs, 0u32, CELLS_DRIVER, what)?,
    );
    let mut parts = Vec::with_capacity(counts.len());
    let (mut cells_left, mut particles_left) = (&mut ref_cell[..], &mut ref_particle[..]);
    for &k in &counts {
        let (c, c_rest) = std::mem::take(&mut cells_left).split_at_mut(k);
        let (p, p_rest) = std::mem::take(&mut particles_left).split_at_mut(k);
        parts.push((c, p));
        (cells_left, particles_left) = (c_rest, p_rest);
    }
    parts
        .into_par_iter()
        .enumerate()
        .for_each(|(t, (cells, particles))| {
            let mut k = 0;
            for j in chunk_of(t) {
                let rg = range_of(j);
                for z in rg[2][0]..=rg[2][1] {
                    for y in rg[1][0]..=rg[1][1] {
                        for x in rg[0][0]..=rg[0][1] {
                            (cells[k], particles[k]) = (cell_index([x, y, z]) as u32, j as u32);
                            k += 1;
                        }
                    }
                }
            }
        });
    let (refs_start, slot_order) = counting_sort(&ref_cell, n_cells)?;
    drop(ref_cell);
    padded_slots(&refs_start, &slot_order, &ref_particle, n_cells)
}

/// Each cell's run of (cell, particle) references (`refs_start`, `slot_order` into `ref_particle`)
/// padded to whole blocks, so that a step tests whole blocks of its own (no lane masks, and a cell of
/// eight never straddles two blocks). Padding lanes have NaN centres: every comparison with them is
/// false, so they contribute to no ray. Returns each cell's first slot (and the end) and the slots'
/// particles.
fn padded_slots(
    refs_start: &[u32],
    slot_order: &[u32],
    ref_particle: &[u32],
    n_cells: usize,
) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
    let mut start = try_filled(n_cells + 1, 0u32, CELLS_DRIVER, "the cells' starts")?;
    for c in 0..n_cells {
        let len = refs_start[c + 1] - refs_start[c];
        start[c + 1] = start[c] + len.div_ceil(LANES as u32) * LANES as u32;
    }
    let slots = start[n_cells] as usize;
    let mut slot_particle = try_filled(slots, PADDING_SLOT, CELLS_DRIVER, "the cells' slots")?;
    run_groups(&mut slot_particle, &start)
        .into_par_iter()
        .for_each(|(c0, c1, group)| {
            let base = start[c0] as usize;
            for c in c0..c1 {
                let (from, to) = (refs_start[c] as usize, refs_start[c + 1] as usize);
                for (k, &r) in slot_order[from..to].iter().enumerate() {
                    group[start[c] as usize - base + k] = ref_particle[r as usize];
                }
            }
        });
    Ok((start, slot_particle))
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
    position: impl Fn(usize) -> [f64; 3] + Sync,
    reach: impl Fn(usize) -> f64 + Sync,
    tau: impl Fn(usize, usize) -> f32 + Sync,
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
/// Codes are numbered in the order of each pair's first particle: in parallel, each chunk of particles
/// numbers its own pairs so, the chunks' numberings are merged in chunk order (a pair's first chunk
/// holds its first particle) and each chunk's codes renamed.
fn qslot_codes(
    order: &[u32],
    reach: impl Fn(usize) -> f64 + Sync,
    tau: impl Fn(usize, usize) -> f32 + Sync,
    channels: usize,
) -> Option<(Vec<u16>, Vec<f32>, Vec<f32>)> {
    let pair = |i: u32| {
        let r = reach(i as usize) as f32;
        let mut key = [r.to_bits(), 0, 0, 0];
        for ch in 0..channels {
            key[ch + 1] = tau(i as usize, ch).to_bits();
        }
        key
    };
    // Each chunk: its particles' codes within the chunk, and its pairs in order of first particle.
    let mut code_of = vec![0u16; order.len()];
    let chunk = PAR_CHUNK_MIN;
    let local: Vec<Option<Vec<[u32; 4]>>> = code_of
        .par_chunks_mut(chunk)
        .zip(order.par_chunks(chunk))
        .map(|(codes, items)| {
            let mut table: rustc_hash::FxHashMap<[u32; 4], u16> = Default::default();
            let mut pairs = Vec::new();
            for (code, &i) in codes.iter_mut().zip(items) {
                let key = pair(i);
                *code = match table.get(&key) {
                    Some(&c) => c,
                    None => {
                        if pairs.len() >= u16::MAX as usize {
                            return None; // more pairs than codes in this chunk alone
                        }
                        let c = pairs.len() as u16;
                        table.insert(key, c);
                        pairs.push(key);
                        c
                    }
                };
            }
            Some(pairs)
        })
        .collect();
    let mut table: rustc_hash::FxHashMap<[u32; 4], u16> = Default::default();
    let mut q_reach = vec![f32::NAN];
    let mut q_tau = vec![0f32; channels];
    let mut rename = Vec::with_capacity(local.len());
    for pairs in local {
        let mut to = Vec::new();
        for key in pairs? {
            let c = match table.get(&key) {
                Some(&c) => c,
                None => {
                    if q_reach.len() > u16::MAX as usize {
                        return None;
                    }
                    let c = q_reach.len() as u16;
                    table.insert(key, c);
                    q_reach.push(f32::from_bits(key[0]));
                    q_tau.extend(key[1..=channels].iter().map(|&t| f32::from_bits(t)));
                    c
                }
            };
            to.push(c);
        }
        rename.push(to);
    }
    code_of
        .par_chunks_mut(chunk)
        .zip(rename.par_iter())
        .for_each(|(codes, to)| codes.iter_mut().for_each(|c| *c = to[*c as usize]));
    Some((code_of, q_reach, q_tau))
}

/// The blocks of quantised slots: each slot's lattice coordinates modulo 2^16 and its particle's code
/// (`code_of`, by stored particle), the arguments as [`build_qslots`]'s.
fn qslot_blocks(
    position: impl Fn(usize) -> [f64; 3] + Sync,
    order: &[u32],
    start: &[u32],
    slot_particle: Option<&[u32]>,
    layout: &ClassLayout,
    step: f64,
    code_of: &[u16],
) -> Vec<QBlock> {
    let (lo, dims) = (layout.lo, layout.dims);
    let slots = slot_particle.map_or(order.len(), <[u32]>::len);
    // Slot s's particle (None: padding, code 0 and R = NaN) and lattice point.
    let lattice = |s: usize| {
        let j = slot_particle.map_or(s as u32, |sp| sp[s]);
        (j != PADDING_SLOT).then(|| {
            (
                j,
                lattice_point(position(order[j as usize] as usize), lo, step),
            )
        })
    };
    // The coordinates modulo 2^16 (`LATTICE_PER_CELL`), read relative to a corner within four cells
    // below: from the slot's cell's corner, [L, 2L) for a centre cell (its own centre), [0, 2^16) for
    // an overlap slot (a ball that reaches into the cell).
    if cfg!(debug_assertions) {
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let c = (z * dims[1] + y) * dims[0] + x;
                    let origin = [x, y, z].map(|i| (i as i64 - 1) * LATTICE_PER_CELL);
                    for s in start[c] as usize..start[c + 1] as usize {
                        let Some((_, g)) = lattice(s) else { continue };
                        for a in 0..3 {
                            let rel = g[a] - origin[a];
                            let own = LATTICE_PER_CELL..2 * LATTICE_PER_CELL;
                            assert!(
                                if slot_particle.is_none() {
                                    own.contains(&rel)
                                } else {
                                    (0..=u16::MAX as i64).contains(&rel)
                                },
                                "lattice offset {rel}"
                            );
                        }
                    }
                }
            }
        }
    }
    // The cells' slots are slots 0.. in order: each block filled on its own, in parallel.
    let mut blocks = vec![QBlock::default(); slots.div_ceil(LANES)];
    blocks.par_iter_mut().enumerate().for_each(|(k, b)| {
        for l in 0..LANES.min(slots - k * LANES) {
            if let Some((j, g)) = lattice(k * LANES + l) {
                let q = g.map(|x| x as u16);
                (b.x[l], b.y[l], b.z[l], b.code[l]) = (q[0], q[1], q[2], code_of[j as usize]);
            }
        }
    });
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
    tau: impl Fn(usize, usize) -> f32 + Sync,
    channels: usize,
) -> Vec<f32> {
    let mut out = vec![0f32; order.len() * channels];
    out.par_chunks_mut(channels.max(1))
        .zip(order.par_iter())
        .for_each(|(t, &i)| {
            for (ch, x) in t.iter_mut().enumerate() {
                *x = tau(i as usize, ch);
            }
        });
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
    let slot_index = || {
        slot_particle
            .par_iter()
            .map(|sp| slot_of(sp).map_or(u32::MAX, |j| index[j]))
            .collect()
    };
    if tau.is_empty() {
        return (Vec::new(), slot_index());
    }
    let mut slot_tau = vec![0f32; slot_particle.len() * channels];
    slot_tau
        .par_chunks_mut(channels.max(1))
        .zip(slot_particle.par_iter())
        .for_each(|(t, sp)| {
            if let Some(j) = slot_of(sp) {
                t.copy_from_slice(&tau[j * channels..(j + 1) * channels]);
            }
        });
    let slot_index = slot_index();
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
        let (k, mut cell) = class_cells(settings, volume, n, free_path_cell, reach_max);
        // Cells sized by the occupied volume of a cloud that fills a sliver of its box (two tight
        // clusters far apart) could number far more over the box than the particles ask for: no
        // grid takes more than MAX_CELLS, coarser cells then (wider cells keep either layout valid).
        let box_cells = ext[0] * ext[1] * ext[2] / cell.powi(3);
        if box_cells > MAX_CELLS {
            cell *= (box_cells / MAX_CELLS).cbrt();
        }
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
    reach: impl Fn(usize) -> f64 + Sync,
) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
    let cells: Vec<u32> = (0..n)
        .into_par_iter()
        .map(|i| layout.cell_of(position(i)) as u32)
        .collect();
    let (centre_start, mut order) = counting_sort(&cells, layout.cells())?;
    drop(cells);
    if layout.step.is_some() && layout.k == 1 {
        sort_runs_descending(&mut order, &centre_start, |j| reach(j as usize));
    }
    Ok((centre_start, order))
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
    reach: impl Fn(usize) -> f64 + Sync,
) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
    if layout.k == 1 {
        return Ok((centre_start, Vec::new()));
    }
    let (lo, cell, dims) = (layout.lo, layout.cell, layout.dims);
    // The centre cells' starts are not needed past here (a k = 0 class's cells are its slots').
    drop(centre_start);
    let (start, mut slot_particle) = inline_slots(at, &reach, order, lo, cell, dims)?;
    if layout.step.is_some() {
        let key = |j: &u32| match *j {
            PADDING_SLOT => -1.0,
            j => reach(order[j as usize] as usize),
        };
        sort_runs_descending(&mut slot_particle, &start, |j| key(&j));
    }
    Ok((start, slot_particle))
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
    ) -> Result<Self, OpticsError> {
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
        let (centre_start, order) = storage_order(&layout, n, position, reach)?;
        let (start, slot_particle) = class_slots(&layout, centre_start, &order, &at, reach)?;
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
        let index: Vec<u32> = order.par_iter().map(|&i| ids[i as usize]).collect();
        let slot_bytes = quant.as_ref().map_or(inline.bytes(), QSlots::bytes);
        let prefetch_slots = slot_bytes.max(particles.bytes()) > PREFETCH_SLOTS_ABOVE_BYTES;
        // Quantised slots read τ by code.
        let slot_tau_of: &[f32] = if quant.is_some() { &[] } else { &tau };
        let (slot_tau, slot_index) = slot_hits(&slot_particle, slot_tau_of, &index, channels);
        Ok(SubGrid {
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
        })
    }
}

#[cfg(test)]
mod tests {
    //! The parallel passes of a class's build against the one-thread loops they replaced (brute-force
    //! oracles), on random inputs and edge cases.
    use super::*;
    use crate::test_rng::lcg;

    /// The serial counting sort the parallel one replaced.
    fn counting_sort_serial(keys: &[u32], n_keys: usize) -> (Vec<u32>, Vec<u32>) {
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

    /// Random keys: `n` of `n_keys`, skewed (every fourth in key 0) where `skew`.
    fn random_keys(s: &mut u64, n: usize, n_keys: usize, skew: bool) -> Vec<u32> {
        (0..n)
            .map(|i| {
                if skew && i % 4 == 0 {
                    0
                } else {
                    (lcg(s) * n_keys as f64) as u32 % n_keys as u32
                }
            })
            .collect()
    }

    fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(f)
    }

    /// Stable and equal to the serial sort, on one thread or several: empty, one key, every item in
    /// one key, more keys than items, and random keys in chunks of every size.
    #[test]
    fn parallel_counting_sort_equals_serial() {
        let mut s = 5u64;
        let cases: Vec<(Vec<u32>, usize)> = vec![
            (Vec::new(), 0),
            (Vec::new(), 7),
            (vec![0; 200_000], 1),
            (vec![3; 150_001], 9),
            (random_keys(&mut s, 1000, 50_000, false), 50_000),
            (random_keys(&mut s, 300_000, 1, false), 1),
            (random_keys(&mut s, 300_000, 3_000, false), 3_000),
            (random_keys(&mut s, 262_147, 10, true), 10),
            (random_keys(&mut s, 500_000, 400_000, true), 400_000),
        ];
        for (keys, n_keys) in &cases {
            let want = counting_sort_serial(keys, *n_keys);
            for threads in [1, 2, 3, 8] {
                let got = in_pool(threads, || counting_sort(keys, *n_keys).unwrap());
                assert!(
                    got == want,
                    "{} keys of {n_keys}, {threads} threads",
                    keys.len()
                );
                let by = in_pool(threads, || {
                    counting_sort_by(keys, *n_keys, |i| 7 * i as u32, "n").unwrap()
                });
                assert_eq!(by.0, want.0);
                assert!(by.1.iter().zip(&want.1).all(|(a, b)| *a == 7 * b));
            }
        }
    }

    /// Each run sorted exactly as `sort_unstable_by` on the run itself sorts it, ties included: runs
    /// of every length (none, one, a whole cell of equal keys, long ones).
    #[test]
    fn sorted_runs_equal_per_run_sorts() {
        let mut s = 9u64;
        for (n, runs, levels) in [
            (0usize, 1usize, 3usize),
            (1, 1, 1),
            (100_000, 1, 4),
            (200_000, 5_000, 3),
            (300_000, 40_000, 1000),
            (70_000, 70_000, 2),
        ] {
            // Run boundaries at random, items a random permutation-ish, keys with many ties.
            let mut cut: Vec<u32> = (0..runs.saturating_sub(1))
                .map(|_| (lcg(&mut s) * n as f64) as u32)
                .collect();
            cut.sort_unstable();
            let start: Vec<u32> = std::iter::once(0)
                .chain(cut)
                .chain(std::iter::once(n as u32))
                .collect();
            let items: Vec<u32> = (0..n as u32)
                .map(|i| i.wrapping_mul(2_654_435_761) % n.max(1) as u32)
                .collect();
            let key_of: Vec<f64> = (0..n)
                .map(|_| (lcg(&mut s) * levels as f64).floor())
                .collect();
            let key = |j: u32| key_of[j as usize];
            let mut want = items.clone();
            for c in 0..start.len() - 1 {
                want[start[c] as usize..start[c + 1] as usize]
                    .sort_unstable_by(|a, b| key(*b).total_cmp(&key(*a)));
            }
            for threads in [1, 2, 5] {
                let mut got = items.clone();
                in_pool(threads, || sort_runs_descending(&mut got, &start, key));
                assert!(got == want, "{n} items in {runs} runs, {threads} threads");
            }
        }
    }

    /// Lists by bucket, in index order, as pushing one by one makes them.
    #[test]
    fn buckets_equal_pushes() {
        let mut s = 3u64;
        for (n, k) in [
            (0usize, 13usize),
            (1, 13),
            (100_000, 1),
            (250_001, 13),
            (70_000, 3),
        ] {
            let key: Vec<usize> = (0..n).map(|_| (lcg(&mut s) * k as f64) as usize).collect();
            let mut want = vec![Vec::new(); k];
            for (j, &b) in key.iter().enumerate() {
                want[b].push(3 * j as u32);
            }
            for threads in [1, 2, 4] {
                let got = in_pool(threads, || buckets(n, k, |j| key[j], |j| 3 * j as u32));
                assert!(got == want, "{n} items in {k} buckets, {threads} threads");
            }
        }
    }

    /// The serial overlap slots the parallel ones replaced.
    fn inline_slots_serial(
        at: impl Fn(usize) -> [f64; 3],
        reach: impl Fn(usize) -> f64,
        order: &[u32],
        lo: [f64; 3],
        cell: f64,
        dims: [usize; 3],
    ) -> (Vec<u32>, Vec<u32>) {
        let n_cells = dims[0] * dims[1] * dims[2];
        let cell_index = |idx: [usize; 3]| (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
        let axis_range = |x: f64, r: f64, a: usize| -> [usize; 2] {
            [x - r, x + r]
                .map(|y| (((y - lo[a]) / cell).floor().max(0.0) as usize).min(dims[a] - 1))
        };
        let (mut ref_cell, mut ref_particle) = (Vec::new(), Vec::new());
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
        let (refs_start, slot_order) = counting_sort_serial(&ref_cell, n_cells);
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

    /// Overlap slots as one thread made them: balls of every size (some over many cells, some on
    /// the box's faces and beyond), in a storage order that is not the particles'.
    #[test]
    fn parallel_overlap_slots_equal_serial() {
        let mut s = 29u64;
        for (n, r_max, dims) in [
            (0usize, 0.01, [3usize, 2, 1]),
            (1, 0.3, [4, 4, 4]),
            (120_000, 0.004, [40, 30, 20]),
            (70_000, 0.05, [25, 25, 25]),
            (50_000, 0.001, [1, 1, 1]),
        ] {
            let pos: Vec<[f64; 3]> = (0..n)
                .map(|i| {
                    if i % 50 == 0 {
                        [0.0, 1.0, (i % 3) as f64 * 0.5] // on the faces
                    } else {
                        [lcg(&mut s), lcg(&mut s), lcg(&mut s)]
                    }
                })
                .collect();
            let reach: Vec<f64> = (0..n).map(|_| r_max * lcg(&mut s)).collect();
            let order: Vec<u32> = (0..n as u32).map(|j| (n as u32 - 1) - j).collect();
            let (lo, cell) = ([0.0; 3], 1.0 / dims[0] as f64);
            let want = inline_slots_serial(|i| pos[i], |i| reach[i], &order, lo, cell, dims);
            for threads in [1, 2, 4] {
                let got = in_pool(threads, || {
                    inline_slots(&|i| pos[i], &|i| reach[i], &order, lo, cell, dims).unwrap()
                });
                assert!(got == want, "{n} balls, {threads} threads");
            }
        }
    }

    /// The serial code table the parallel one replaced.
    #[allow(clippy::type_complexity)]
    fn qslot_codes_serial(
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

    /// Codes numbered in the order of each pair's first particle, as one thread numbers them, and
    /// None from 65 536 distinct pairs on (in one chunk or across chunks).
    #[test]
    fn parallel_codes_equal_serial() {
        let mut s = 17u64;
        for (n, pairs, channels) in [
            (0usize, 1usize, 1usize),
            (1, 1, 3),
            (200_000, 1, 1),
            (300_000, 5_000, 2),
            (300_000, 65_535, 1),
            (300_000, 65_536, 1),
            (40_000, 40_000, 1),
            (150_000, 150_000, 3),
        ] {
            let which: Vec<u32> = (0..n)
                .map(|i| {
                    // Every pair at least once (the first `pairs` particles), then at random.
                    if i < pairs {
                        i as u32
                    } else {
                        (lcg(&mut s) * pairs as f64) as u32
                    }
                })
                .collect();
            let order: Vec<u32> = (0..n as u32).rev().collect();
            let reach = |i: usize| 1.0 + (which[i] % 977) as f64 * 0.5;
            let tau = |i: usize, ch: usize| (which[i] / 977) as f32 + ch as f32 * 0.25;
            let want = qslot_codes_serial(&order, reach, tau, channels);
            assert_eq!(want.is_none(), pairs > 65_535);
            for threads in [1, 2, 4] {
                let got = in_pool(threads, || qslot_codes(&order, reach, tau, channels));
                let same = match (&got, &want) {
                    (None, None) => true,
                    (Some(a), Some(b)) => {
                        a.0 == b.0
                            && a.1.len() == b.1.len()
                            && a.1
                                .iter()
                                .zip(&b.1)
                                .all(|(x, y)| x.to_bits() == y.to_bits())
                            && a.2 == b.2
                    }
                    _ => false,
                };
                assert!(same, "{n} particles, {pairs} pairs, {threads} threads");
            }
        }
    }
}
