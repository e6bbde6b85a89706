//! Where a site certainly blocks a shadow ray (issue 25): the convex shapes that hold a medium.
//!
//! Next-event estimation at a scattering event traces a shadow ray towards a light, then evaluates the
//! phase function towards it and multiplies the two (Mitsuba's `volpath` and `volpathmis`: the light's
//! value, already zero for a blocked ray, times the phase value and a MIS weight). In a dense cloud most
//! shadow rays end at a site of the medium, and the evaluation after them (6 % of a dense Cornell box's
//! render) computes a number that is multiplied by zero. The medium may skip it only where the site
//! blocks the ray for certain: Mitsuba keeps a site only if no surface comes first along the ray, and
//! the core does not see surfaces. It sees them here, in the one form it needs: regions whose boundary
//! the ray cannot have crossed. A convex shape whose interior is the medium holds the whole segment from
//! an event inside it to a site inside it, so the ray never left the medium before the site; the
//! renderer adds a region only where no surface inside it lets a shadow ray through (a null or
//! thin-glass boundary of a nested medium), since any other surface blocks the ray itself.
//!
//! Regions: a convex polyhedron from a triangle mesh (a `cube` shape, any convex mesh: its faces'
//! planes) or a ball (a `sphere` shape). A point counts as inside only [`MARGIN`] of the region's
//! size away from its boundary, so that float rounding of the site's position (Mitsuba's single
//! precision) or of the boundary's intersection cannot put the site on the wrong side.
//!
//! Infrastructure for the renderer's next-event estimation: implements no equation of the paper.

use crate::error::{require, OpticsError};
use crate::space::vec3::{cross, dot, sub};

/// How far inside its boundary a point must be, as a fraction of the region's size (its bounding
/// box's diagonal, or a ball's radius): Mitsuba's ray–surface distances and positions carry single
/// precision, ~1e-7 relative.
pub const MARGIN: f64 = 1e-4;

/// Most faces a polyhedron may have (each point is tested against every face plane).
pub const MAX_FACES: usize = 64;

/// The checks of a mesh's vertices and faces, each naming its argument.
fn check_mesh(vertices: &[[f64; 3]], faces: &[[u32; 3]]) -> Result<(), OpticsError> {
    require(
        "vertices (count)",
        vertices.len() as f64,
        vertices.len() >= 4,
        ">= 4",
    )?;
    require(
        "faces (count)",
        faces.len() as f64,
        faces.len() >= 4,
        ">= 4",
    )?;
    for v in vertices {
        for &x in v {
            require("vertex", x, x.is_finite(), "finite")?;
        }
    }
    for f in faces {
        for &i in f {
            require(
                "face vertex index",
                i as f64,
                (i as usize) < vertices.len(),
                "< number of vertices",
            )?;
        }
    }
    Ok(())
}

/// The distinct planes of a closed mesh's faces, each oriented away from the vertices' `centroid` and
/// shrunk by [`MARGIN`] of the mesh's size (degenerate triangles hold none); None where a vertex lies
/// in front of a face's plane (the mesh is not convex).
fn face_planes(
    vertices: &[[f64; 3]],
    faces: &[[u32; 3]],
    centroid: [f64; 3],
) -> Option<Vec<([f64; 3], f64)>> {
    let (lo, hi) = vertices.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), v| {
            (
                [0, 1, 2].map(|a| lo[a].min(v[a])),
                [0, 1, 2].map(|a| hi[a].max(v[a])),
            )
        },
    );
    let size = dot(sub(hi, lo), sub(hi, lo)).sqrt();
    let margin = MARGIN * size;
    let mut planes: Vec<([f64; 3], f64)> = Vec::new();
    for f in faces {
        let [a, b, c] = f.map(|i| vertices[i as usize]);
        let nrm = cross(sub(b, a), sub(c, a));
        let len = dot(nrm, nrm).sqrt();
        if !(len > 1e-12 * size * size) {
            continue; // a degenerate triangle holds no plane
        }
        let mut nrm = nrm.map(|x| x / len);
        let mut off = dot(nrm, a);
        if dot(nrm, centroid) > off {
            nrm = nrm.map(|x| -x);
            off = -off;
        }
        if vertices.iter().any(|&v| dot(nrm, v) - off > margin) {
            return None;
        }
        let known = planes
            .iter()
            .any(|(m, c)| dot(*m, nrm) > 1.0 - 1e-9 && (c + margin - off).abs() <= margin);
        if !known {
            planes.push((nrm, off - margin));
        }
    }
    Some(planes)
}

/// The axis-aligned box six `planes` bound, if they are axis-aligned (a `cube` shape scaled and
/// moved, not rotated: six comparisons per point).
fn axis_box(planes: &[([f64; 3], f64)]) -> Option<Region> {
    let axis = |n: &[f64; 3]| (0..3).find(|&a| n[a].abs() == 1.0);
    if planes.len() != 6 || !planes.iter().all(|(n, _)| axis(n).is_some()) {
        return None;
    }
    let (mut lo, mut hi) = ([f64::NAN; 3], [f64::NAN; 3]);
    for (n, c) in planes {
        let a = axis(n).unwrap();
        if n[a] > 0.0 {
            hi[a] = *c;
        } else {
            lo[a] = -c;
        }
    }
    lo.iter()
        .chain(&hi)
        .all(|x| !x.is_nan())
        .then_some(Region::Box { lo, hi })
}

/// One convex region.
#[derive(Clone, Debug, PartialEq)]
pub enum Region {
    /// Points with n · x < c for every face plane (n unit, pointing out; c shrunk by the margin).
    Polyhedron { planes: Vec<([f64; 3], f64)> },
    /// A polyhedron whose faces are the six axis-aligned planes (shrunk): lo < x < hi.
    Box { lo: [f64; 3], hi: [f64; 3] },
    /// Points within `radius` − margin of `centre`.
    Ball { centre: [f64; 3], radius: f64 },
}

impl Region {
    /// The convex polyhedron a closed triangle mesh bounds, shrunk by [`MARGIN`]; None where the mesh
    /// is open (an edge not shared by exactly two faces, vertices matched by position: Mitsuba's `cube`
    /// gives each face its own), not convex (a vertex in front of a face's plane), has more than
    /// [`MAX_FACES`] distinct face planes or encloses no volume (then no site is certainly inside it).
    /// Faces may wind either way: each plane is oriented away from the vertices' centroid.
    pub fn convex_mesh(
        vertices: &[[f64; 3]],
        faces: &[[u32; 3]],
    ) -> Result<Option<Self>, OpticsError> {
        check_mesh(vertices, faces)?;
        if !closed(vertices, faces) {
            return Ok(None);
        }
        let n = vertices.len() as f64;
        let centroid = [0, 1, 2].map(|a| vertices.iter().map(|v| v[a]).sum::<f64>() / n);
        let Some(planes) = face_planes(vertices, faces, centroid) else {
            return Ok(None);
        };
        // The centroid must lie inside every shrunk plane: a flat or open mesh bounds nothing.
        if planes.len() < 4
            || planes.len() > MAX_FACES
            || planes.iter().any(|(m, c)| dot(*m, centroid) >= *c)
        {
            return Ok(None);
        }
        Ok(Some(
            axis_box(&planes).unwrap_or(Region::Polyhedron { planes }),
        ))
    }

    /// The ball of `radius` around `centre`, shrunk by [`MARGIN`] of the radius.
    pub fn ball(centre: [f64; 3], radius: f64) -> Result<Self, OpticsError> {
        for x in centre {
            require("ball centre", x, x.is_finite(), "finite")?;
        }
        require(
            "ball radius",
            radius,
            radius.is_finite() && radius > 0.0,
            "finite and > 0",
        )?;
        Ok(Region::Ball {
            centre,
            radius: radius * (1.0 - MARGIN),
        })
    }

    /// Is `p` inside (by the margin)?
    pub fn holds(&self, p: [f64; 3]) -> bool {
        match self {
            Region::Polyhedron { planes } => planes.iter().all(|(n, c)| dot(*n, p) < *c),
            Region::Box { lo, hi } => (0..3).all(|a| p[a] > lo[a] && p[a] < hi[a]),
            Region::Ball { centre, radius } => {
                let v = sub(p, *centre);
                dot(v, v) < radius * radius
            }
        }
    }
}

/// Is every edge of the mesh shared by exactly two of its (non-degenerate) faces, vertices that lie at
/// the same position taken as one?
fn closed(vertices: &[[f64; 3]], faces: &[[u32; 3]]) -> bool {
    let mut by_position: std::collections::HashMap<[u64; 3], u32> = Default::default();
    let id: Vec<u32> = vertices
        .iter()
        .map(|v| {
            let n = by_position.len() as u32;
            *by_position
                .entry(v.map(|x| (x + 0.0).to_bits()))
                .or_insert(n)
        })
        .collect();
    let mut edges: std::collections::HashMap<(u32, u32), u32> = Default::default();
    for f in faces {
        let [a, b, c] = f.map(|i| id[i as usize]);
        if a == b || b == c || a == c {
            continue;
        }
        for (x, y) in [(a, b), (b, c), (c, a)] {
            *edges.entry((x.min(y), x.max(y))).or_insert(0) += 1;
        }
    }
    !edges.is_empty() && edges.values().all(|&k| k == 2)
}

/// The convex regions that hold a medium and that no surface inside them lets a shadow ray through
/// (module docs): empty where the renderer knows none (then no evaluation is skipped).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Enclosure {
    pub regions: Vec<Region>,
}

impl Enclosure {
    /// Does one region hold both ends of the segment (and so, being convex, all of it)?
    pub fn holds_segment(&self, a: [f64; 3], b: [f64; 3]) -> bool {
        self.regions.iter().any(|r| r.holds(a) && r.holds(b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cube mesh [lo, hi]³ as Mitsuba's `cube` shape makes it: 24 vertices, 12 triangles.
    fn cube(lo: f64, hi: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let mut v = Vec::new();
        let mut f = Vec::new();
        for axis in 0..3 {
            for side in [lo, hi] {
                let base = v.len() as u32;
                let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                for (a, b) in [(lo, lo), (hi, lo), (hi, hi), (lo, hi)] {
                    let mut p = [0.0; 3];
                    (p[axis], p[u], p[w]) = (side, a, b);
                    v.push(p);
                }
                f.push([base, base + 1, base + 2]);
                f.push([base, base + 2, base + 3]);
            }
        }
        (v, f)
    }

    #[test]
    fn a_cube_holds_its_inside_by_the_margin() {
        let (v, f) = cube(-2.0, 2.0);
        let r = Region::convex_mesh(&v, &f).unwrap().unwrap();
        let Region::Box { lo, hi } = &r else {
            panic!("an axis-aligned box")
        };
        assert!(lo.iter().zip(hi).all(|(l, h)| *l > -2.0 && *h < 2.0));
        let margin = MARGIN * 4.0 * 3f64.sqrt();
        assert!(r.holds([0.0; 3]));
        assert!(r.holds([2.0 - 1.01 * margin, -2.0 + 1.01 * margin, 1.0]));
        assert!(!r.holds([2.0 - 0.99 * margin, 0.0, 0.0]));
        assert!(!r.holds([0.0, 0.0, 2.5]));
        let e = Enclosure {
            regions: vec![r.clone()],
        };
        assert!(e.holds_segment([0.0; 3], [1.9, 1.9, -1.9]));
        assert!(!e.holds_segment([0.0; 3], [2.1, 0.0, 0.0]));
        assert!(!Enclosure::default().holds_segment([0.0; 3], [0.0; 3]));
    }

    #[test]
    fn a_rotated_cube_is_its_own_planes_not_its_box() {
        // 45° about z: the corner of the axis-aligned box around it is outside the cube.
        let (v, f) = cube(-1.0, 1.0);
        let (c, s) = (
            std::f64::consts::FRAC_1_SQRT_2,
            std::f64::consts::FRAC_1_SQRT_2,
        );
        let v: Vec<[f64; 3]> = v
            .iter()
            .map(|p| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]])
            .collect();
        let r = Region::convex_mesh(&v, &f).unwrap().unwrap();
        let Region::Polyhedron { planes } = &r else {
            panic!("a polyhedron")
        };
        assert_eq!(planes.len(), 6);
        assert!(r.holds([1.3, 0.0, 0.0]));
        assert!(!r.holds([1.0, 1.0, 0.0]));
    }

    #[test]
    fn non_convex_open_or_flat_meshes_hold_nothing() {
        // A dent: the corner (1, 1, 1) of the cube (in every face's copy of it) pushed to near the centre.
        let (mut v, f) = cube(-1.0, 1.0);
        assert!(Region::convex_mesh(&v, &f).unwrap().is_some());
        v.iter_mut()
            .filter(|p| **p == [1.0; 3])
            .for_each(|p| *p = [0.1; 3]);
        assert_eq!(Region::convex_mesh(&v, &f).unwrap(), None);
        // Open: only the four side faces (no planes closing z).
        let (v, f) = cube(-1.0, 1.0);
        assert_eq!(Region::convex_mesh(&v, &f[..8]).unwrap(), None);
        // Flat: a square twice.
        let flat = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let faces = vec![[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]];
        assert_eq!(Region::convex_mesh(&flat, &faces).unwrap(), None);
    }

    #[test]
    fn bad_input_is_named() {
        let (v, f) = cube(-1.0, 1.0);
        let mut bad = v.clone();
        bad[3][1] = f64::NAN;
        let e = Region::convex_mesh(&bad, &f).unwrap_err();
        assert!(e.to_string().contains("vertex"), "{e}");
        let e =
            Region::convex_mesh(&v, &[[0, 1, 99], [0, 1, 2], [0, 2, 3], [1, 2, 3]]).unwrap_err();
        assert!(e.to_string().contains("face vertex index"), "{e}");
        assert!(Region::ball([0.0; 3], 0.0).is_err());
        assert!(Region::ball([f64::INFINITY, 0.0, 0.0], 1.0).is_err());
    }

    #[test]
    fn a_ball_holds_its_inside_by_the_margin() {
        let r = Region::ball([1.0, 0.0, 0.0], 2.0).unwrap();
        assert!(r.holds([2.9, 0.0, 0.0]));
        assert!(!r.holds([1.0 + 2.0 * (1.0 - 0.5 * MARGIN), 0.0, 0.0]));
        assert!(!r.holds([-1.5, 0.0, 0.0]));
    }
}
