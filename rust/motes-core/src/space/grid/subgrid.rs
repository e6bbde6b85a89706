//! One size class of a grid and its build: the storage order, overlap slots or centre cells, and
//! quantised slots.

use super::slots::{QSlots, Spheres};
use crate::space::dda::GridFrame;
#[cfg(any(test, feature = "oracles"))]
use crate::space::ray::RaySegment;

/// One size class of a [`ParticleGrid`](super::ParticleGrid): particles of similar inclusion radius in a uniform grid whose cells are at least
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
    /// The class's slots quantised (compact storage, [`GridSettings::quantise`](super::GridSettings::quantise)): in place of
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
    /// Positional identities ([`ParticleGrid::positional`](super::ParticleGrid::positional)): a k = 1 class with no `index` reports
    /// stored particle j as `first_id + j`.
    pub(super) first_id: u32,
}

impl SubGrid {
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

    /// Heap bytes of the grid and the particles it stores (allocated: capacities, not lengths).
    pub fn bytes(&self) -> usize {
        self.particles.bytes()
            + self.inline.bytes()
            + self.quant.as_ref().map_or(0, QSlots::bytes)
            + self.slot_tau.capacity() * 4
            + self.slot_index.capacity() * 4
            + self.tau.capacity() * 4
            + self.index.capacity() * 4
            + self.start.capacity() * 4
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
            if let Some(t) = super::slots::ball_contribution(c, r, ray) {
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
