//! The inside of the closed shapes that hold a medium (issue 43): which points lie in them, the volume
//! they enclose, and points spread uniformly over it (a `discrete` medium without a `to_world` fills
//! the shapes that hold it, as Mitsuba's `homogeneous` does).
//!
//! * [`Mesh`]: a closed triangle mesh in world space. A point is inside when a ray from it along +x
//!   crosses the surface an odd number of times (ray parity, Jordan). The crossings are counted in the
//!   (y, z) projection with the rasteriser's fill rule: each edge function is computed from the edge's
//!   endpoints in one canonical order, so two triangles sharing an edge see its value with opposite signs
//!   bit for bit, and a ray through an edge or a vertex counts it once (or, at a fold of the projection,
//!   twice or not at all): the parity is exact for rays that meet edges and vertices, without jitter.
//!   Triangles are binned in a uniform 2D grid of their projected boxes (about one cell per triangle), so
//!   a query tests the few triangles of one column. [`Mesh::contains_brute`] tests every triangle with the
//!   same predicate (the O(N·T) oracle; the grid only drops triangles whose box cannot hold the point).
//!   Parity needs every edge to be shared by an even number of triangles ([`open_edges`] counts those
//!   that are not, after welding vertices at the same position: a mesh with per-face normals repeats them).
//! * [`Solid::Ellipsoid`], [`Solid::Cylinder`]: Mitsuba's analytic `sphere` (the unit ball) and
//!   `cylinder` (x² + y² ≤ 1, 0 ≤ z ≤ 1, taken solid) through their `to_world`.
//! * [`Holders`]: several solids holding one medium; their union is the inside. [`Holders::fill`] draws
//!   candidates uniformly over the solids' boxes (a box chosen in proportion to its volume) and keeps a
//!   candidate from box i where the first solid holding it is solid i: uniform over the union, each point
//!   once. Counter-based ([`crate::rng::stream_bits`] of the seed and the candidate's index), evaluated in
//!   fixed chunks in parallel and kept in index order, so the points depend on the seed only.
//!
//! Geometry; implements no equation of the paper.

use crate::error::{require, OpticsError};
use crate::rng::{stream_bits, stream_key, unit_f64};
use crate::space::cloud::{apply, det3, invert_affine};
use crate::space::grid::counting_sort_by;
use rayon::prelude::*;

/// The stream of [`Holders::fill`]'s candidates under a seed ("FILL" in ASCII).
const FILL_CALL: u64 = 0x4649_4C4C;

/// Candidates evaluated side by side per step of [`Holders::fill`] (fixed: the result must not depend on
/// the thread count).
const CHUNK: u64 = 1 << 16;

/// Candidates the Monte Carlo volume of overlapping holders draws ([`Holders::volume`]).
pub const VOLUME_SAMPLES: u64 = 1 << 20;

type P2 = [f64; 2];

#[inline]
fn orient(a: P2, b: P2, p: P2) -> f64 {
    (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
}

/// The edge function of the directed edge a → b at p, computed from the endpoints in lexicographic order:
/// the edge b → a gets exactly its negative.
#[inline]
fn edge(a: P2, b: P2, p: P2) -> f64 {
    if a[0] < b[0] || (a[0] == b[0] && a[1] <= b[1]) {
        orient(a, b, p)
    } else {
        -orient(b, a, p)
    }
}

/// The fill rule's tie break: a point on an edge belongs to the side that traverses the edge along `d`
/// (exactly one of d and -d passes, for d ≠ 0).
#[inline]
fn owns(d: P2) -> bool {
    d[1] < 0.0 || (d[1] == 0.0 && d[0] < 0.0)
}

/// Does the ray from `p` along +x cross the triangle `t` (fill rule at its edges and vertices)?
#[inline]
fn crosses(t: &[[f64; 3]; 3], p: [f64; 3]) -> bool {
    let q = [[t[0][1], t[0][2]], [t[1][1], t[1][2]], [t[2][1], t[2][2]]];
    let pp = [p[1], p[2]];
    let area = orient(q[0], q[1], q[2]);
    if area == 0.0 || !area.is_finite() {
        return false; // edge-on to the ray: its neighbours count the crossing
    }
    let s = area.signum();
    let mut w = [0.0; 3];
    for i in 0..3 {
        let (a, b) = (q[(i + 1) % 3], q[(i + 2) % 3]);
        let v = s * edge(a, b, pp);
        let d = if s > 0.0 {
            [b[0] - a[0], b[1] - a[1]]
        } else {
            [a[0] - b[0], a[1] - b[1]]
        };
        if v < 0.0 || (v == 0.0 && !owns(d)) {
            return false;
        }
        w[i] = v;
    }
    let sum = w[0] + w[1] + w[2];
    if sum <= 0.0 {
        return false;
    }
    let x = (w[0] * t[0][0] + w[1] * t[1][0] + w[2] * t[2][0]) / sum;
    x > p[0]
}

/// A closed triangle mesh in world space, ready for inside tests (module docs).
#[derive(Debug, Clone)]
pub struct Mesh {
    tris: Vec<[[f64; 3]; 3]>,
    lo: [f64; 3],
    hi: [f64; 3],
    /// The (y, z) grid: cells per axis, cell size, and each cell's triangles (CSR).
    n: [usize; 2],
    cell: [f64; 2],
    start: Vec<u32>,
    items: Vec<u32>,
    /// Signed volume by the divergence theorem, and whether the faces are consistently oriented.
    signed_volume: f64,
    oriented: bool,
}

/// Edges of a mesh (vertices welded by position) shared by an odd number of its faces: 0 for a closed
/// mesh, whose inside ray parity tells.
pub fn open_edges(vertices: &[[f64; 3]], faces: &[[u32; 3]]) -> usize {
    edge_counts(vertices, faces).0
}

/// (edges used by an odd number of faces, whether every edge is used as often in each direction).
fn edge_counts(vertices: &[[f64; 3]], faces: &[[u32; 3]]) -> (usize, bool) {
    use rustc_hash::FxHashMap;
    let mut weld: FxHashMap<[u64; 3], u32> = FxHashMap::default();
    let ids: Vec<u32> = vertices
        .iter()
        .map(|v| {
            // +0.0 and -0.0 are one position.
            let key = v.map(|x| (x + 0.0).to_bits());
            let next = weld.len() as u32;
            *weld.entry(key).or_insert(next)
        })
        .collect();
    // (a, b) with a < b -> (faces using it, forward minus backward uses).
    let mut edges: FxHashMap<(u32, u32), (u32, i64)> = FxHashMap::default();
    for f in faces {
        for i in 0..3 {
            let (a, b) = (ids[f[i] as usize], ids[f[(i + 1) % 3] as usize]);
            if a == b {
                continue;
            }
            let e = edges.entry((a.min(b), a.max(b))).or_insert((0, 0));
            e.0 += 1;
            e.1 += if a < b { 1 } else { -1 };
        }
    }
    let odd = edges.values().filter(|e| e.0 % 2 == 1).count();
    let oriented = edges.values().all(|e| e.1 == 0);
    (odd, oriented)
}

/// The checks of a mesh: a triangle at least, vertex indices in range, finite vertices.
fn check_mesh(vertices: &[[f64; 3]], faces: &[[u32; 3]]) -> Result<(), OpticsError> {
    require(
        "faces",
        faces.len() as f64,
        !faces.is_empty(),
        "at least one triangle",
    )?;
    let nv = vertices.len();
    for f in faces {
        for &i in f {
            require(
                "faces",
                i as f64,
                (i as usize) < nv,
                "vertex indices below the number of vertices",
            )?;
        }
    }
    for v in vertices {
        require(
            "vertices",
            v.iter().map(|x| x.abs()).fold(0.0, f64::max),
            v.iter().all(|x| x.is_finite()),
            "finite",
        )?;
    }
    Ok(())
}

/// The bounding box of triangles.
fn bounds_of(tris: &[[[f64; 3]; 3]]) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for t in tris {
        for v in t {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
    }
    (lo, hi)
}

/// The 2D grid over the box's (y, z) extent: about one cell per triangle (cells per axis, cell sizes).
fn projected_grid(lo: [f64; 3], hi: [f64; 3], triangles: usize) -> ([usize; 2], [f64; 2]) {
    let ext = [hi[1] - lo[1], hi[2] - lo[2]];
    let t = triangles as f64;
    let n = if ext[0] > 0.0 && ext[1] > 0.0 {
        let h = (ext[0] * ext[1] / t).sqrt();
        [
            ((ext[0] / h).ceil() as usize).clamp(1, 4096),
            ((ext[1] / h).ceil() as usize).clamp(1, 4096),
        ]
    } else {
        [1, 1]
    };
    let cell = [0, 1].map(|a| {
        if ext[a] > 0.0 {
            ext[a] / n[a] as f64
        } else {
            1.0
        }
    });
    (n, cell)
}

/// The volume a closed mesh encloses, signed by its orientation (the divergence theorem: the sum of
/// the tetrahedra from the origin).
fn signed_volume(tris: &[[[f64; 3]; 3]]) -> f64 {
    tris.iter()
        .map(|t| {
            let (a, b, c) = (t[0], t[1], t[2]);
            a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0])
        })
        .sum::<f64>()
        / 6.0
}

impl Mesh {
    /// A mesh of `faces` (vertex indices) over `vertices` (world space). Errors: an index out of range,
    /// a vertex not finite, no face.
    pub fn new(vertices: &[[f64; 3]], faces: &[[u32; 3]]) -> Result<Self, OpticsError> {
        check_mesh(vertices, faces)?;
        let tris: Vec<[[f64; 3]; 3]> = faces
            .iter()
            .map(|f| f.map(|i| vertices[i as usize]))
            .collect();
        let (lo, hi) = bounds_of(&tris);
        let (n, cell) = projected_grid(lo, hi, tris.len());
        let mut mesh = Mesh {
            tris,
            lo,
            hi,
            n,
            cell,
            start: Vec::new(),
            items: Vec::new(),
            signed_volume: 0.0,
            oriented: false,
        };
        (mesh.start, mesh.items) = mesh.bin_triangles()?;
        mesh.signed_volume = signed_volume(&mesh.tris);
        mesh.oriented = edge_counts(vertices, faces).1;
        Ok(mesh)
    }

    /// Each grid cell's triangles (those whose projected box overlaps it): per-cell starts (a prefix
    /// sum of the counts) and the triangle indices in cell order.
    fn bin_triangles(&self) -> Result<(Vec<u32>, Vec<u32>), OpticsError> {
        let n = self.n;
        let ranges: Vec<[usize; 4]> = self
            .tris
            .iter()
            .map(|t| {
                let (y0, y1) = (
                    t.iter().map(|v| v[1]).fold(f64::INFINITY, f64::min),
                    t.iter().map(|v| v[1]).fold(f64::NEG_INFINITY, f64::max),
                );
                let (z0, z1) = (
                    t.iter().map(|v| v[2]).fold(f64::INFINITY, f64::min),
                    t.iter().map(|v| v[2]).fold(f64::NEG_INFINITY, f64::max),
                );
                let (a0, b0) = self.cell_of(y0, z0);
                let (a1, b1) = self.cell_of(y1, z1);
                [a0, a1, b0, b1]
            })
            .collect();
        // One (cell, triangle) reference per cell a triangle's box overlaps, in triangle order; a
        // stable counting sort by cell keeps that order within each cell.
        let mut ref_cell = Vec::new();
        let mut ref_tri = Vec::new();
        for (k, r) in ranges.iter().enumerate() {
            for a in r[0]..=r[1] {
                for b in r[2]..=r[3] {
                    ref_cell.push((a * n[1] + b) as u32);
                    ref_tri.push(k as u32);
                }
            }
        }
        counting_sort_by(&ref_cell, n[0] * n[1], |j| ref_tri[j], "meshes (triangles)")
    }

    /// The grid cell of the projected point (y, z), clamped to the grid (the same formula for a
    /// triangle's box and a query: monotonic, so a point in a triangle's box is in one of its cells).
    #[inline]
    fn cell_of(&self, y: f64, z: f64) -> (usize, usize) {
        let a = ((y - self.lo[1]) / self.cell[0]).floor();
        let b = ((z - self.lo[2]) / self.cell[1]).floor();
        (
            (a.max(0.0) as usize).min(self.n[0] - 1),
            (b.max(0.0) as usize).min(self.n[1] - 1),
        )
    }

    #[inline]
    fn in_box(&self, p: [f64; 3]) -> bool {
        (0..3).all(|a| p[a] >= self.lo[a] && p[a] <= self.hi[a])
    }

    /// Whether the triangle `k` can cross the ray from `p` (its projected box holds p's projection).
    #[inline]
    fn near(&self, k: usize, p: [f64; 3]) -> bool {
        let t = &self.tris[k];
        (1..3).all(|a| {
            let lo = t[0][a].min(t[1][a]).min(t[2][a]);
            let hi = t[0][a].max(t[1][a]).max(t[2][a]);
            p[a] >= lo && p[a] <= hi
        }) && t.iter().any(|v| v[0] > p[0])
    }

    /// Is `p` inside the mesh (ray parity through the grid)?
    pub fn contains(&self, p: [f64; 3]) -> bool {
        if !self.in_box(p) {
            return false;
        }
        let (a, b) = self.cell_of(p[1], p[2]);
        let c = a * self.n[1] + b;
        let mut odd = false;
        for &k in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
            let k = k as usize;
            if self.near(k, p) && crosses(&self.tris[k], p) {
                odd = !odd;
            }
        }
        odd
    }

    /// [`Mesh::contains`] testing every triangle (the oracle of the grid: the same predicate).
    pub fn contains_brute(&self, p: [f64; 3]) -> bool {
        if !self.in_box(p) {
            return false;
        }
        (0..self.tris.len())
            .filter(|&k| self.near(k, p) && crosses(&self.tris[k], p))
            .count()
            % 2
            == 1
    }

    /// The enclosed volume by the divergence theorem, where the faces are consistently oriented (None
    /// otherwise: the sign of each face's share is unknown).
    pub fn volume(&self) -> Option<f64> {
        self.oriented.then_some(self.signed_volume.abs())
    }

    /// The mesh's box (lo, hi).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.lo, self.hi)
    }

    pub fn triangles(&self) -> usize {
        self.tris.len()
    }
}

/// One shape that holds a medium.
#[derive(Debug, Clone)]
pub enum Solid {
    Mesh(Mesh),
    /// The unit ball through `to_world` (3×4); `inv` its inverse.
    Ellipsoid {
        to_world: [[f64; 4]; 3],
        inv: [[f64; 4]; 3],
    },
    /// The solid unit cylinder x² + y² ≤ 1, 0 ≤ z ≤ 1 through `to_world`.
    Cylinder {
        to_world: [[f64; 4]; 3],
        inv: [[f64; 4]; 3],
    },
}

impl Solid {
    fn quadric(to_world: [[f64; 4]; 3]) -> Result<[[f64; 4]; 3], OpticsError> {
        let det = det3(&to_world);
        let inv = invert_affine(&to_world);
        require(
            "to_world",
            det,
            inv.is_some() && to_world.iter().flatten().all(|x| x.is_finite()),
            "finite and invertible",
        )?;
        Ok(inv.unwrap())
    }

    pub fn ellipsoid(to_world: [[f64; 4]; 3]) -> Result<Self, OpticsError> {
        Ok(Solid::Ellipsoid {
            inv: Self::quadric(to_world)?,
            to_world,
        })
    }

    pub fn cylinder(to_world: [[f64; 4]; 3]) -> Result<Self, OpticsError> {
        Ok(Solid::Cylinder {
            inv: Self::quadric(to_world)?,
            to_world,
        })
    }

    pub fn contains(&self, p: [f64; 3]) -> bool {
        match self {
            Solid::Mesh(m) => m.contains(p),
            Solid::Ellipsoid { inv, .. } => {
                let q = apply(inv, p);
                q[0] * q[0] + q[1] * q[1] + q[2] * q[2] <= 1.0
            }
            Solid::Cylinder { inv, .. } => {
                let q = apply(inv, p);
                q[0] * q[0] + q[1] * q[1] <= 1.0 && (0.0..=1.0).contains(&q[2])
            }
        }
    }

    /// The exact volume, where known (a mesh whose faces are not consistently oriented: None).
    pub fn volume(&self) -> Option<f64> {
        match self {
            Solid::Mesh(m) => m.volume(),
            Solid::Ellipsoid { to_world, .. } => {
                Some(4.0 / 3.0 * std::f64::consts::PI * det3(to_world).abs())
            }
            Solid::Cylinder { to_world, .. } => Some(std::f64::consts::PI * det3(to_world).abs()),
        }
    }

    /// The solid's box (lo, hi).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        match self {
            Solid::Mesh(m) => m.bounds(),
            Solid::Ellipsoid { to_world: m, .. } => {
                let c = [m[0][3], m[1][3], m[2][3]];
                let r =
                    [0, 1, 2].map(|a| (m[a][0].powi(2) + m[a][1].powi(2) + m[a][2].powi(2)).sqrt());
                (
                    [0, 1, 2].map(|a| c[a] - r[a]),
                    [0, 1, 2].map(|a| c[a] + r[a]),
                )
            }
            Solid::Cylinder { to_world: m, .. } => {
                let (c0, c1) = (apply(m, [0.0; 3]), apply(m, [0.0, 0.0, 1.0]));
                let r = [0, 1, 2].map(|a| (m[a][0].powi(2) + m[a][1].powi(2)).sqrt());
                (
                    [0, 1, 2].map(|a| c0[a].min(c1[a]) - r[a]),
                    [0, 1, 2].map(|a| c0[a].max(c1[a]) + r[a]),
                )
            }
        }
    }
}

/// The solids that hold one medium; the inside is their union (module docs).
#[derive(Debug, Clone)]
pub struct Holders {
    solids: Vec<Solid>,
    boxes: Vec<([f64; 3], [f64; 3])>,
    /// Running sums of the boxes' volumes.
    cum: Vec<f64>,
}

impl Holders {
    pub fn new(solids: Vec<Solid>) -> Result<Self, OpticsError> {
        require(
            "holders",
            solids.len() as f64,
            !solids.is_empty(),
            "at least one shape",
        )?;
        let boxes: Vec<_> = solids.iter().map(Solid::bounds).collect();
        let mut cum = Vec::with_capacity(boxes.len());
        let mut total = 0.0;
        for (lo, hi) in &boxes {
            total += (0..3).map(|a| hi[a] - lo[a]).product::<f64>();
            cum.push(total);
        }
        require(
            "holders",
            total,
            total > 0.0 && total.is_finite(),
            "shapes with a finite, non-zero volume (a flat shape holds nothing)",
        )?;
        Ok(Holders { solids, boxes, cum })
    }

    pub fn solids(&self) -> &[Solid] {
        &self.solids
    }

    /// Is `p` inside any of the solids?
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.solids.iter().any(|s| s.contains(p))
    }

    /// The box of all the solids (lo, hi).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (l, h) in &self.boxes {
            for a in 0..3 {
                lo[a] = lo[a].min(l[a]);
                hi[a] = hi[a].max(h[a]);
            }
        }
        (lo, hi)
    }

    /// The `k`-th candidate under `key` where it is kept (module docs), else None.
    #[inline]
    fn candidate(&self, key: u64, k: u64) -> Option<[f64; 3]> {
        let total = *self.cum.last().unwrap();
        let u = unit_f64(stream_bits(key, 4 * k)) * total;
        let i = self
            .cum
            .partition_point(|&c| c <= u)
            .min(self.cum.len() - 1);
        let (lo, hi) = self.boxes[i];
        let p = [0, 1, 2]
            .map(|a| lo[a] + unit_f64(stream_bits(key, 4 * k + 1 + a as u64)) * (hi[a] - lo[a]));
        (self.solids[i].contains(p) && !self.solids[..i].iter().any(|s| s.contains(p))).then_some(p)
    }

    /// Exactly `count` points uniform over the union, reproducible from `seed` whatever the thread
    /// count. Errors when the candidates keep (almost) nothing (fewer than one in 10^4 after 10^6).
    pub fn fill(&self, count: u64, seed: u64) -> Result<Vec<[f64; 3]>, OpticsError> {
        let key = stream_key(seed, FILL_CALL);
        let mut out: Vec<[f64; 3]> = Vec::with_capacity(count as usize);
        let mut k0 = 0u64;
        while (out.len() as u64) < count {
            let kept: Vec<[f64; 3]> = (k0..k0 + CHUNK)
                .into_par_iter()
                .filter_map(|k| self.candidate(key, k))
                .collect();
            let need = (count - out.len() as u64) as usize;
            out.extend(kept.into_iter().take(need));
            k0 += CHUNK;
            require(
                "holders",
                out.len() as f64,
                k0 < (1 << 20) || (out.len() as u64) * 10_000 >= k0,
                "shapes with an inside (fewer than one point in 10^4 of their boxes lies inside: \
                 are they closed, and not flat?)",
            )?;
        }
        Ok(out)
    }

    /// The union's volume, and whether it is exact: the sum of the solids' exact volumes where their
    /// boxes do not overlap; else the share of [`VOLUME_SAMPLES`] candidates kept times the boxes' volume
    /// (relative error about 1/sqrt(VOLUME_SAMPLES · share)).
    pub fn volume(&self, seed: u64) -> (f64, bool) {
        let disjoint = (0..self.boxes.len()).all(|i| {
            (0..i).all(|j| {
                let (a, b) = (self.boxes[i], self.boxes[j]);
                (0..3).any(|x| a.1[x] <= b.0[x] || b.1[x] <= a.0[x])
            })
        });
        let exact: Option<Vec<f64>> = self.solids.iter().map(Solid::volume).collect();
        if let (true, Some(v)) = (disjoint, exact) {
            return (v.iter().sum(), true);
        }
        let key = stream_key(seed, FILL_CALL);
        let kept = (0..VOLUME_SAMPLES)
            .into_par_iter()
            .filter(|&k| self.candidate(key, k).is_some())
            .count();
        (
            *self.cum.last().unwrap() * kept as f64 / VOLUME_SAMPLES as f64,
            false,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::cloud::IDENTITY;

    /// A UV sphere of radius r (closed, consistently oriented outward).
    fn uv_sphere(r: f64, c: [f64; 3], nu: usize, nv: usize) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let mut v = vec![[c[0], c[1], c[2] + r], [c[0], c[1], c[2] - r]];
        for i in 1..nv {
            let th = std::f64::consts::PI * i as f64 / nv as f64;
            for j in 0..nu {
                let ph = 2.0 * std::f64::consts::PI * j as f64 / nu as f64;
                v.push([
                    c[0] + r * th.sin() * ph.cos(),
                    c[1] + r * th.sin() * ph.sin(),
                    c[2] + r * th.cos(),
                ]);
            }
        }
        let ring = |i: usize, j: usize| (2 + (i - 1) * nu + j % nu) as u32;
        let mut f = Vec::new();
        for j in 0..nu {
            f.push([0, ring(1, j), ring(1, j + 1)]);
            f.push([1, ring(nv - 1, j + 1), ring(nv - 1, j)]);
        }
        for i in 1..nv - 1 {
            for j in 0..nu {
                f.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
                f.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
            }
        }
        (v, f)
    }

    /// Mitsuba's cube: 24 vertices (per-face normals), 12 triangles, [-1, 1]^3.
    fn cube() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let mut v = Vec::new();
        let mut f = Vec::new();
        for axis in 0..3 {
            for side in [-1.0, 1.0] {
                let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                let base = v.len() as u32;
                for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    let mut p = [0.0; 3];
                    p[axis] = side;
                    p[u] = a;
                    p[w] = b;
                    v.push(p);
                }
                if side > 0.0 {
                    f.push([base, base + 1, base + 2]);
                    f.push([base, base + 2, base + 3]);
                } else {
                    f.push([base, base + 2, base + 1]);
                    f.push([base, base + 3, base + 2]);
                }
            }
        }
        (v, f)
    }

    fn lcg(s: &mut u64) -> f64 {
        *s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        unit_f64(crate::rng::splitmix64(*s))
    }

    #[test]
    fn grid_matches_brute_force_and_the_analytic_ball() {
        let (v, f) = uv_sphere(1.0, [0.2, -0.1, 0.3], 24, 12);
        let m = Mesh::new(&v, &f).unwrap();
        assert_eq!(open_edges(&v, &f), 0);
        let mut s = 7u64;
        let mut wrong = 0;
        for _ in 0..20000 {
            let p = [0, 1, 2].map(|_| -1.2 + 2.4 * lcg(&mut s));
            assert_eq!(m.contains(p), m.contains_brute(p), "{p:?}");
            let d = ((p[0] - 0.2).powi(2) + (p[1] + 0.1).powi(2) + (p[2] - 0.3).powi(2)).sqrt();
            // The facets cut inside the ball by at most 1 - cos(pi / 12) ~ 3.4 %.
            if (d < 0.96 || d > 1.0) && m.contains(p) != (d < 1.0) {
                wrong += 1;
            }
        }
        assert_eq!(wrong, 0);
        let vol = m.volume().unwrap();
        // The inscribed 24x12 UV sphere holds 4.07 of the ball's 4.19.
        assert!(
            (vol - 4.0 / 3.0 * std::f64::consts::PI).abs() < 0.15,
            "{vol}"
        );
    }

    #[test]
    fn rays_through_edges_and_vertices_count_once() {
        // Points on the cube's lattice: their rays along +x meet edges and vertices exactly.
        let (v, f) = cube();
        assert_eq!(open_edges(&v, &f), 0);
        let m = Mesh::new(&v, &f).unwrap();
        assert_eq!(m.volume(), Some(8.0));
        for y in [-0.5, 0.0, 0.5] {
            for z in [-0.5, 0.0, 0.5] {
                for x in [-0.5, 0.0, 0.5] {
                    assert!(m.contains([x, y, z]) && m.contains_brute([x, y, z]));
                }
                assert!(!m.contains([1.5, y, z]) && !m.contains([-1.5, y, z]));
            }
        }
        // An octahedron: rays along +x from its inside pass through its vertex (1, 0, 0) and edges.
        let ov = [
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ];
        let mut of = Vec::new();
        for (a, sa) in [(0u32, 1.0), (1, -1.0)] {
            for (b, c) in [(2u32, 4u32), (4, 3), (3, 5), (5, 2)] {
                of.push(if sa > 0.0 { [a, b, c] } else { [a, c, b] });
            }
        }
        let o = Mesh::new(&ov, &of).unwrap();
        assert_eq!(open_edges(&ov, &of), 0);
        assert!((o.volume().unwrap() - 4.0 / 3.0).abs() < 1e-12);
        for x in [-0.5, 0.0, 0.25, 0.5] {
            assert!(o.contains([x, 0.0, 0.0]), "{x}");
            assert!(o.contains([x, 0.1, 0.0]) && o.contains([x, 0.0, -0.1]));
        }
        assert!(!o.contains([0.0, 0.6, 0.6]));
    }

    #[test]
    fn open_meshes_and_bad_input_are_named() {
        let (v, mut f) = cube();
        f.pop();
        assert_eq!(open_edges(&v, &f), 3);
        assert!(Mesh::new(&v, &[[0, 1, 99]]).is_err());
        assert!(Mesh::new(&v, &[]).is_err());
    }

    #[test]
    fn fill_is_uniform_over_the_union_and_deterministic() {
        let (v, f) = cube();
        // The cube [-1, 1]^3 and a ball of radius 1 at (1.5, 0, 0) overlapping it.
        let ball = [
            [1.0, 0.0, 0.0, 1.5],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let h = Holders::new(vec![
            Solid::Mesh(Mesh::new(&v, &f).unwrap()),
            Solid::ellipsoid(ball).unwrap(),
        ])
        .unwrap();
        let pts = h.fill(100_000, 3).unwrap();
        assert_eq!(pts.len(), 100_000);
        assert_eq!(pts, h.fill(100_000, 3).unwrap());
        assert!(pts.iter().all(|&p| h.contains(p)));
        // Density: points in the unit cube [0, 1]^3 (inside the mesh, partly in the ball) vs its share.
        let (vol, exact) = h.volume(3);
        assert!(!exact);
        // Exact union: 8 + ball volume - overlap (cap of the ball for x in [0.5, 1]: h = 0.5).
        let cap = std::f64::consts::PI * 0.25 * (3.0 - 0.5) / 3.0;
        let union = 8.0 + 4.0 / 3.0 * std::f64::consts::PI - cap;
        assert!((vol / union - 1.0).abs() < 0.005, "{vol} vs {union}");
        let inside = pts
            .iter()
            .filter(|p| p.iter().all(|&x| (0.0..1.0).contains(&x)))
            .count();
        let expect = 100_000.0 / union;
        assert!(
            (inside as f64 - expect).abs() < 5.0 * expect.sqrt(),
            "{inside} vs {expect}"
        );
        // Disjoint holders: exact volumes.
        let far = [
            [2.0, 0.0, 0.0, 9.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let cyl = Holders::new(vec![
            Solid::cylinder(far).unwrap(),
            Solid::ellipsoid(IDENTITY).unwrap(),
        ])
        .unwrap();
        let (v2, exact2) = cyl.volume(0);
        assert!(
            exact2
                && (v2 - (2.0 * std::f64::consts::PI + 4.0 / 3.0 * std::f64::consts::PI)).abs()
                    < 1e-12
        );
    }
}
