//! A built grid's grains as flat arrays, for a walk written outside the core (issue 46: a Dr.Jit
//! kernel, `mitsuba_plugin/motes/drjit_walk.py`, which cannot call host code from a CUDA kernel).
//!
//! ## Layout ([`FlatGrid`])
//! Every size class of the grid keeps its own frame (corner, cubic cell edge, cells per axis) and is
//! stored by its centres' cells (the centre-cell layout, k = 1 in the module docs): each grain once,
//! in the order of the cell that holds its centre, with `start` giving each cell's run. A class's
//! cells are at least as wide as its largest inclusion radius R_max (a k = 1 class by its build, a
//! k = 0 class because its balls are narrower than half a cell), so a ball that reaches a ray inside
//! cell c has its centre in the 3×3×3 block around c: a walk tests, per DDA step, the cells of that
//! block no earlier step tested (the first step the whole block, each later one the 3×3 slab its
//! move adds on the far side), every grain near the ray exactly once, as `SubGrid::step_rows` does.
//! A grain that straddles cells is stored once, in its centre's cell, and found from any of them.
//!
//! Per grain: its centre and inclusion radius R_i = r_c + r_i as the walk tests them (f32, the
//! spheres' own values; quantised slots decoded from their lattice), the optical depth τ_i its disk
//! adds (Eq. 18 normalised by the disk, module docs; one channel) and the index the grid reports (its
//! original index, or its position for a positional grid). 16 bytes a grain are what a walk reads
//! per grain it tests (centre and R), τ (4) only for the grains that pass, the index (4) only for
//! the one a free flight stops at: 24 bytes a grain stored, plus 4 per cell.

use super::build::counting_sort;
use super::{ParticleGrid, SubGrid};
use crate::error::{require, OpticsError};

/// One size class of a [`FlatGrid`]: its cells and where its grains and cell starts lie in the flat
/// arrays.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatClass {
    /// The corner of the class's box (scene units).
    pub lo: [f64; 3],
    /// The cells' edge (cubes), at least `reach`.
    pub cell: f64,
    /// Cells per axis (x fastest).
    pub dims: [usize; 3],
    /// The largest inclusion radius of the class's grains (as stored, f32) grown by the grid's
    /// margin: no grain reaches a ray from further than this.
    pub reach: f64,
    /// Where the class's cell starts begin in [`FlatGrid::start`] (dims product + 1 entries).
    pub start_offset: usize,
    /// The class's grains: `first_grain..first_grain + count` of the grain arrays.
    pub first_grain: usize,
    pub count: usize,
}

/// A grid's grains as flat arrays (module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlatGrid {
    pub classes: Vec<FlatClass>,
    /// Per class, per cell (x fastest) and one more: the cell's first grain (global), so that the
    /// grains of cell c of class k are `start[o + c]..start[o + c + 1]`, o its `start_offset`.
    pub start: Vec<u32>,
    /// Per grain: centre x, y, z and inclusion radius R_i (scene units).
    pub spheres: Vec<[f32; 4]>,
    /// Per grain: the optical depth τ_i of its disk in the channel exported.
    pub tau: Vec<f32>,
    /// Per grain: the index the grid reports for it (`ParticleGrid::walk`).
    pub index: Vec<u32>,
}

impl FlatGrid {
    /// Bytes of the arrays: per grain and per cell as the module docs count them.
    pub fn bytes(&self) -> usize {
        self.spheres.len() * 16 + (self.tau.len() + self.index.len() + self.start.len()) * 4
    }
}

/// A grain of a class as a walk sees it: sphere, τ in the channel, reported index.
type Grain = ([f32; 4], f32, u32);

impl SubGrid {
    /// Each grain of the class once, as its slots hold it (`Self::slot_ball`, `hit_tau`,
    /// `hit_index`): overlap slots (k = 0) name a grain in every cell its ball overlaps, and only its
    /// first is kept.
    fn flat_grains(&self, channel: usize) -> Vec<Grain> {
        let dims = self.frame.dims;
        let mut out = Vec::with_capacity(self.count);
        let mut seen: Vec<u64> = Vec::new();
        if self.k == 0 {
            let most = self.slot_index.iter().filter(|&&i| i != u32::MAX).max();
            seen = vec![0; most.map_or(0, |&m| m as usize / 64 + 1)];
        }
        for c in 0..dims[0] * dims[1] * dims[2] {
            let cell = [c % dims[0], c / dims[0] % dims[1], c / (dims[0] * dims[1])];
            for s in self.start[c] as usize..self.start[c + 1] as usize {
                let i = self.hit_index(s);
                if self.k == 0 {
                    if i == u32::MAX {
                        continue; // padding
                    }
                    let (w, b) = (i as usize / 64, 1u64 << (i % 64));
                    if seen[w] & b != 0 {
                        continue;
                    }
                    seen[w] |= b;
                }
                let (p, r) = self.slot_ball(s, cell);
                let sphere = [p[0] as f32, p[1] as f32, p[2] as f32, r as f32];
                out.push((sphere, self.hit_tau(s)[channel], i));
            }
        }
        out
    }
}

impl ParticleGrid {
    /// The grid's grains as flat arrays in the centre-cell layout (module docs), optical depths of
    /// `channel`.
    pub fn flat(&self, channel: usize) -> Result<FlatGrid, OpticsError> {
        require(
            "channel",
            channel as f64,
            channel < self.channels,
            "below the grid's channels",
        )?;
        let mut flat = FlatGrid::default();
        for c in &self.classes {
            let grains = c.flat_grains(channel);
            let (lo, cell, dims) = (c.frame.bounds.lo, c.frame.cell[0], c.frame.dims);
            let cell_of = |p: &[f32; 4]| {
                let at = |a: usize| {
                    let x = ((p[a] as f64 - lo[a]) / cell).floor();
                    (x.max(0.0) as usize).min(dims[a] - 1)
                };
                ((at(2) * dims[1] + at(1)) * dims[0] + at(0)) as u32
            };
            let keys: Vec<u32> = grains.iter().map(|g| cell_of(&g.0)).collect();
            let (start, order) = counting_sort(&keys, dims[0] * dims[1] * dims[2])?;
            let first = flat.spheres.len();
            let r_max = grains.iter().map(|g| g.0[3] as f64).fold(0.0, f64::max);
            flat.classes.push(FlatClass {
                lo,
                cell,
                dims,
                reach: r_max * super::settings::BOX_MARGIN.0 + super::settings::BOX_MARGIN.1,
                start_offset: flat.start.len(),
                first_grain: first,
                count: grains.len(),
            });
            flat.start.extend(start.iter().map(|&s| s + first as u32));
            for &j in &order {
                let (sphere, tau, index) = grains[j as usize];
                flat.spheres.push(sphere);
                flat.tau.push(tau);
                flat.index.push(index);
            }
        }
        Ok(flat)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::grid::{slots::ball_contribution, GridSettings};
    use crate::space::ray::RaySegment;
    use crate::test_rng::{lcg, random_direction, random_particles};
    use std::f64::consts::PI;

    /// The optical depth of `ray` by the flat arrays' walk rule (each class's DDA cells, the 3×3×3
    /// block around each step's cell, every cell once): what a kernel written from the arrays alone
    /// computes.
    fn flat_walk_depth(f: &FlatGrid, ray: &RaySegment) -> f64 {
        let mut tau = 0.0;
        for k in &f.classes {
            let frame = crate::space::dda::GridFrame::new(k.lo, [k.cell; 3], k.dims);
            let mut tested = std::collections::HashSet::new();
            for step in crate::space::dda::Dda::new(&frame, ray) {
                for dz in -1i64..=1 {
                    for dy in -1i64..=1 {
                        for dx in -1i64..=1 {
                            let c = [0, 1, 2].map(|a| step.cell[a] as i64 + [dx, dy, dz][a]);
                            if (0..3).any(|a| c[a] < 0 || c[a] >= k.dims[a] as i64) {
                                continue;
                            }
                            let c = [0, 1, 2].map(|a| c[a] as usize);
                            let cell = (c[2] * k.dims[1] + c[1]) * k.dims[0] + c[0];
                            if !tested.insert(cell) {
                                continue;
                            }
                            let (s0, s1) = (
                                f.start[k.start_offset + cell],
                                f.start[k.start_offset + cell + 1],
                            );
                            for g in s0 as usize..s1 as usize {
                                let p = f.spheres[g];
                                let c = [p[0] as f64, p[1] as f64, p[2] as f64];
                                if let Some(t) = ball_contribution(c, p[3] as f64, ray) {
                                    if ray.contains(t) {
                                        tau += f.tau[g] as f64;
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        tau
    }

    /// Every grain is exported exactly once, in the cell that holds its centre, with the radius the
    /// class's cells cover and the τ the grid reports; the walk rule over the flat arrays gives the
    /// grid's optical depths. Over the layouts a grid takes: spheres and quantised slots, overlap
    /// slots (kept and released) and centre cells, several size classes, positional names.
    #[test]
    fn flat_grains_are_each_grain_once_in_its_centre_cell() {
        let mut s = 29u64;
        // Two populations: many small grains and a few large ones (several size classes).
        let (mut pos, mut rad) = random_particles(&mut s, 3000, 0.001, 0.01);
        let (p2, r2) = random_particles(&mut s, 40, 0.05, 0.05);
        pos.extend(p2);
        rad.extend(r2);
        let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
        let n = pos.len();
        let layouts = [
            (0.01, 0.125, false, false, false),
            (0.0, 1.0, false, false, true),
            (0.01, 1.0, true, false, false),
            (0.01, 1.0, true, true, false),
            (0.02, 0.125, true, true, true),
            (0.05, 1.0, false, false, false),
            (0.0, 1.0, false, true, false),
        ];
        // (k, quantised) of the classes met: every layout a class takes.
        let mut kinds = std::collections::HashSet::new();
        for (rc, cpp, quantise, centred, release) in layouts {
            let settings = GridSettings::new(rc, cpp)
                .quantised(quantise)
                .centred(centred);
            let mut g = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
            let mut order: Option<Vec<u32>> = None;
            if centred {
                let (p, o) = g.positional();
                g = p;
                order = Some(o);
            }
            if release {
                g.release_stored();
            }
            let f = g.flat(0).unwrap();
            let what = format!("layout {rc} {cpp} {quantise} {centred} {release}");
            assert_eq!(f.spheres.len(), n, "{what}");
            assert_eq!((f.tau.len(), f.index.len()), (n, n), "{what}");
            assert_eq!(f.classes.len(), g.class_count(), "{what}");
            kinds.extend(g.classes.iter().map(|c| (c.k, c.quant.is_some())));
            assert!(f.classes.len() >= 2, "{what}");
            assert!(f.bytes() <= 24 * n + 4 * f.start.len());
            // Every reported index once.
            let mut seen = vec![0u32; n];
            f.index.iter().for_each(|&i| seen[i as usize] += 1);
            assert!(seen.iter().all(|&k| k == 1), "{what}");
            let mut first = 0;
            for k in &f.classes {
                assert_eq!(k.first_grain, first);
                first += k.count;
                let cells = k.dims[0] * k.dims[1] * k.dims[2];
                let st = &f.start[k.start_offset..k.start_offset + cells + 1];
                assert_eq!(st[0] as usize, k.first_grain);
                assert_eq!(st[cells] as usize, k.first_grain + k.count);
                assert!(st.windows(2).all(|w| w[0] <= w[1]));
                for c in 0..cells {
                    let cell = [
                        c % k.dims[0],
                        c / k.dims[0] % k.dims[1],
                        c / (k.dims[0] * k.dims[1]),
                    ];
                    for g in st[c] as usize..st[c + 1] as usize {
                        let p = f.spheres[g];
                        assert!(p[3] as f64 <= k.cell && p[3] as f64 <= k.reach, "{what}");
                        for a in 0..3 {
                            let x = ((p[a] as f64 - k.lo[a]) / k.cell).floor();
                            assert_eq!(x as usize, cell[a], "{what}: grain {g}");
                        }
                    }
                }
            }
            assert_eq!(first, n);
            // τ and R as the grid has them (radius: r_c + r_i of the particle the index names).
            for j in (0..n).step_by(37) {
                let i = f.index[j];
                assert_eq!(f.tau[j] as f64, g.tau_of(i, 0), "{what}");
                let original = order.as_ref().map_or(i, |o| o[i as usize]) as usize;
                let r = (rc + rad[original]) as f32;
                assert!((f.spheres[j][3] - r).abs() <= 1e-6 * r, "{what}");
            }
            for _ in 0..200 {
                let o = [
                    lcg(&mut s) * 2.0 - 0.5,
                    lcg(&mut s) * 2.0 - 0.5,
                    lcg(&mut s),
                ];
                let ray =
                    RaySegment::new(o, random_direction(&mut s), 0.0, 0.3 + 2.0 * lcg(&mut s));
                let mut want = [0.0];
                g.optical_depth(&ray, &mut want);
                let got = flat_walk_depth(&f, &ray);
                assert!(
                    (got - want[0]).abs() <= 1e-9 * want[0].max(1e-30),
                    "{what}: {got} {want:?}"
                );
            }
        }
    }
}
