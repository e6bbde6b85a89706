//! Walking a ray through a uniform grid: an axis-aligned box with one slab test ([`Bounds3`]) and a
//! 3D-DDA iterator over the cells a ray crosses ([`Dda`], Amanatides & Woo 1987), in t order, each
//! with the t interval the ray spends inside it (as pbrt-v4's `DDAMajorantIterator` does).
//!
//! Paper: the grid traversal behind the query cylinders of Eq. 18 and the particle gathering of Sec. 5.3
//! (the paper uses a uniform grid, Sec. 6.5); no equation of its own.

use crate::space::ray::RaySegment;

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds3 {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

impl Bounds3 {
    /// The part [ta, tb) of the segment where its ray is inside the box (slab test), or None. A
    /// direction component of 0 keeps the slab whole when the origin lies within it, else misses.
    pub fn clip(&self, ray: &RaySegment) -> Option<(f64, f64)> {
        self.clip_inv(ray, inverse(ray.d))
    }

    /// [`Bounds3::clip`] with the direction's reciprocals `inv_d` (from [`inverse`]) computed once
    /// by a caller that walks several grids along one ray.
    #[inline]
    pub fn clip_inv(&self, ray: &RaySegment, inv_d: [f64; 3]) -> Option<(f64, f64)> {
        let (o, d) = (ray.o, ray.d);
        let (mut ta, mut tb) = (ray.t0, ray.t1);
        for a in 0..3 {
            if d[a] == 0.0 {
                if o[a] < self.lo[a] || o[a] > self.hi[a] {
                    return None;
                }
            } else {
                let (u, v) = (
                    (self.lo[a] - o[a]) * inv_d[a],
                    (self.hi[a] - o[a]) * inv_d[a],
                );
                ta = ta.max(u.min(v));
                tb = tb.min(u.max(v));
            }
        }
        (tb > ta).then_some((ta, tb))
    }
}

/// The reciprocals of a direction's components (±inf for a zero component, which the walks treat
/// separately): one division per axis and ray, shared by every grid the ray walks (the setup of a
/// walk is several percent of a sparse render).
#[inline]
pub fn inverse(d: [f64; 3]) -> [f64; 3] {
    d.map(|x| 1.0 / x)
}

/// A uniform grid as a DDA walks it: its box, cell edges and cells per axis.
#[derive(Clone, Copy, Debug)]
pub struct GridFrame {
    pub bounds: Bounds3,
    pub cell: [f64; 3],
    pub dims: [usize; 3],
}

impl GridFrame {
    pub fn new(lo: [f64; 3], cell: [f64; 3], dims: [usize; 3]) -> Self {
        GridFrame {
            bounds: Bounds3 {
                lo,
                hi: [0, 1, 2].map(|a| lo[a] + dims[a] as f64 * cell[a]),
            },
            cell,
            dims,
        }
    }
}

/// One cell a ray crosses: its integer coordinates and the t interval [t_enter, t_exit) inside it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdaCell {
    pub cell: [usize; 3],
    /// The cell's index in x-fastest order, `(z dims_y + y) dims_x + x` (kept up to date by the walk
    /// rather than recomputed per step).
    pub index: usize,
    pub t_enter: f64,
    pub t_exit: f64,
}

/// The cells of a grid ([`GridFrame`]) that a ray segment crosses, in order. The first interval
/// starts at the box entry and the last ends at the box exit (both clipped to the segment).
pub struct Dda {
    c: [i64; 3],
    step: [i64; 3],
    t_next: [f64; 3],
    t_delta: [f64; 3],
    dims: [i64; 3],
    /// Linear index of `c`, and how it changes by a step along each axis.
    index: i64,
    index_step: [i64; 3],
    t_enter: f64,
    t_end: f64,
    done: bool,
}

impl Dda {
    /// The walk of `ray` through the grid `g`.
    pub fn new(g: &GridFrame, ray: &RaySegment) -> Self {
        Self::new_in(g, ray, inverse(ray.d))
    }

    /// [`Dda::new`] with the direction's reciprocals (no division).
    #[inline]
    pub fn new_in(g: &GridFrame, ray: &RaySegment, inv_d: [f64; 3]) -> Self {
        let (lo, cell) = (g.bounds.lo, g.cell);
        let (o, d) = (ray.o, ray.d);
        let dims_i = g.dims.map(|x| x as i64);
        let Some((ta, tb)) = g.bounds.clip_inv(ray, inv_d) else {
            return Dda {
                c: [0; 3],
                step: [0; 3],
                t_next: [0.0; 3],
                t_delta: [0.0; 3],
                dims: dims_i,
                index: 0,
                index_step: [0; 3],
                t_enter: 0.0,
                t_end: 0.0,
                done: true,
            };
        };
        let p = [0, 1, 2].map(|a| o[a] + ta * d[a]);
        let (mut c, mut step, mut t_next, mut t_delta) =
            ([0i64; 3], [0i64; 3], [f64::INFINITY; 3], [f64::INFINITY; 3]);
        for a in 0..3 {
            // The entry point rounds into the box: clamp its cell (truncation is floor once clamped
            // at 0, and needs no libm call). A division, not a product with 1/cell: a ray lying on
            // a cell face must start in the cell the face opens.
            c[a] = (((p[a] - lo[a]) / cell[a]) as i64).clamp(0, dims_i[a] - 1);
            let inv = inv_d[a];
            if d[a] > 0.0 {
                step[a] = 1;
                t_next[a] = ta + ((lo[a] + (c[a] + 1) as f64 * cell[a]) - p[a]) * inv;
                t_delta[a] = cell[a] * inv;
            } else if d[a] < 0.0 {
                step[a] = -1;
                t_next[a] = ta + ((lo[a] + c[a] as f64 * cell[a]) - p[a]) * inv;
                t_delta[a] = -cell[a] * inv;
            }
        }
        Dda {
            c,
            step,
            t_next,
            t_delta,
            dims: dims_i,
            index: (c[2] * dims_i[1] + c[1]) * dims_i[0] + c[0],
            index_step: [
                step[0],
                step[1] * dims_i[0],
                step[2] * dims_i[0] * dims_i[1],
            ],
            t_enter: ta,
            t_end: tb,
            done: false,
        }
    }
}

impl Dda {
    /// Has the ray left the grid (the last cell returned was the last one)?
    #[inline]
    pub fn finished(&self) -> bool {
        self.done
    }
}

impl Iterator for Dda {
    type Item = DdaCell;

    #[inline]
    fn next(&mut self) -> Option<DdaCell> {
        if self.done {
            return None;
        }
        // The axis whose next face comes first, by selects rather than branches (the branch is a coin
        // toss per step and mispredicts).
        let a01 = usize::from(self.t_next[1] < self.t_next[0]);
        let axis = if self.t_next[2] < self.t_next[a01] {
            2
        } else {
            a01
        };
        let t_exit = self.t_next[axis].min(self.t_end);
        let out = DdaCell {
            cell: self.c.map(|x| x as usize),
            index: self.index as usize,
            t_enter: self.t_enter,
            t_exit,
        };
        if self.t_next[axis] >= self.t_end {
            self.done = true;
        } else {
            self.t_enter = t_exit;
            self.c[axis] += self.step[axis];
            self.index += self.index_step[axis];
            self.t_next[axis] += self.t_delta[axis];
            self.done = self.c[axis] < 0 || self.c[axis] >= self.dims[axis];
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::{lcg, random_direction};

    /// The cells' intervals tile the clipped segment without gaps, each cell holds the midpoint of its
    /// interval, and rays along the axes, on cell faces and missing the box behave.
    #[test]
    fn cells_tile_the_segment() {
        let (lo, cell, dims) = ([-1.0, 0.0, 2.0], [0.25, 0.2, 0.3], [8usize, 5, 7]);
        let mut s = 3u64;
        let mut rays = Vec::new();
        for _ in 0..500 {
            let o = [
                lcg(&mut s) * 4.0 - 3.0,
                lcg(&mut s) * 3.0 - 1.0,
                lcg(&mut s) * 4.0,
            ];
            rays.push((o, random_direction(&mut s)));
        }
        for a in 0..3 {
            let mut d = [0.0; 3];
            d[a] = 1.0;
            rays.push(([-0.5, 0.5, 2.5], d)); // on cell faces
            rays.push(([-0.4, 0.6, 3.1], d.map(|x| -x)));
        }
        let hi = [lo[0] + 2.0, 1.0, 4.1];
        let grid = GridFrame::new(lo, cell, dims);
        for (o, d) in rays {
            let ray = RaySegment::new(o, d, 0.0, 10.0);
            let cells: Vec<DdaCell> = Dda::new(&grid, &ray).collect();
            match (Bounds3 { lo, hi }).clip(&ray) {
                None => assert!(cells.is_empty()),
                Some((ta, tb)) => {
                    assert_eq!(cells[0].t_enter, ta);
                    assert!((cells.last().unwrap().t_exit - tb).abs() < 1e-12);
                    for w in cells.windows(2) {
                        assert_eq!(w[0].t_exit, w[1].t_enter);
                    }
                    for c in &cells {
                        assert!(c.t_exit >= c.t_enter);
                        let [x, y, z] = c.cell;
                        assert_eq!(c.index, (z * dims[1] + y) * dims[0] + x, "{c:?}");
                        let t = 0.5 * (c.t_enter + c.t_exit);
                        for a in 0..3 {
                            let x = ((o[a] + t * d[a] - lo[a]) / cell[a]).floor() as i64;
                            assert!(
                                (x - c.cell[a] as i64).abs() <= 1 && c.cell[a] < dims[a],
                                "{c:?}"
                            );
                            if c.t_exit - c.t_enter > 1e-9 {
                                assert_eq!(x.clamp(0, dims[a] as i64 - 1), c.cell[a] as i64);
                            }
                        }
                    }
                }
            }
        }
        let miss = RaySegment::new([5.0, 5.0, 5.0], [1.0, 0.0, 0.0], 0.0, 10.0);
        assert_eq!(Dda::new(&grid, &miss).count(), 0);
    }
}
