//! Rays from surfaces and the pixel footprint they carry (issue 25).
//!
//! A path that has scattered in the cloud sees the grains' continuous equivalent
//! (`discrete.rs`, "Grains along a path"). Rays that start on a surface (a wall's shadow ray towards
//! the light, a bounce off the floor) start at no event, so until now they walked the grains one by
//! one, and in a closed room most rays start on a surface. Whether a viewer can see the grains along
//! such a ray is the question Eq. 23 answers for camera rays: the pixel that the ray's light reaches
//! integrates over a footprint, and grains that the footprint holds many of are seen only as their
//! mean (the paper's query cylinder; the continuous size classes of issue 10.3 use the same count).
//!
//! The medium cannot follow a path back to its pixel, so it bounds the footprint from below with what
//! it knows: the ray (origin o, unit direction d, end t_max) and the cameras (position c, angular
//! pixel width α, lens aperture a). The surface point W that the ray's light reaches the camera from
//! lies on the ray's backward half-line, W = o − s d with s ≥ 0 (Mitsuba re-spawns rays at index-matched
//! boundaries, so o itself may be a boundary point between W and the cloud). The pixel's footprint at
//! W is at least α |W − c| across, wider after curved or rough reflections and at grazing views, and
//! never narrower after flat mirrors (the path is longer than |W − c|). If the ray is a shadow ray
//! towards a light at distance a along it (a point or spot light, or a point of a small area light),
//! the cone from that footprint to the light has radius ρ(t) = (α/2) |W − c| (a − t) / (a + s) at t:
//! the grains' shadows grow towards the wall, and a grain near a lamp casts a large one. Its least
//! value over every possible W is ρ(t) = K (a − t) with K = (α/2) min_{s ≥ 0} |o − c − s d| / (a + s),
//! which has a closed form ([`cone_slope`]). Any other ray (a bounce, a shadow ray towards the sky or
//! a distant light) keeps ρ = (α/2) min_{s ≥ 0} |o − c − s d|, the distance from the camera to the
//! backward half-line. A camera ray's backward half-line passes through its camera, so its footprint
//! bound is 0. Its grains' own disks could still pass the count (a query radius far wider than the
//! grains, Eq. 23's usual case, with the classes pooled), so a ray whose backward half-line passes
//! within the lens aperture (plus float rounding) of a camera is refused outright, and a ray passes only
//! where its footprint, not the disks, is what holds the grains: the footprint must at least double the
//! effective count the disks alone hold over the same window (a ray just off a camera's line, through a
//! glass pane say, keeps walking them).
//!
//! Which rays head for a light: those whose forward line passes within a light's radius of its centre
//! ([`Light`]: the scene's point and spot lights, and a sphere around each area light's shape). The
//! ray's own t_max says nothing here (Mitsuba ends a ray at the medium's boundary, not at the light);
//! without a list of lights every ray with a finite t_max is taken to end at a point light there, which
//! keeps the rule safe and makes it rarely apply.
//!
//! The rule: a ray that starts at no event sees the grains' continuous equivalent when the grains
//! that stay discrete would hold at least `continuous_count` of them in that cone, counted over the
//! length [`crate::render::continuous::resolvable`] counts over (one mean free path of the whole
//! medium, or the box's mean chord if shorter; less where the ray's own chord is shorter) at the
//! cone's narrow end, with each size class's mean density over the particles' box: that count with
//! the ray's own footprint added to each disk.
//! Several classes count as an *effective* number, N_eff = (Σ_k τ_k)² / Σ_k τ_k² / N_k, with N_k
//! the class's expected count and τ_k its expected optical depth: what a viewer would see of the
//! grains is the grain-to-grain texture of the transmittance over the footprint, whose relative
//! spread is τ / √N for one class and τ / √N_eff for a mixture. So a rare class of small grains
//! (a few in a footprint, but little of the extinction) does not keep a ray walking, and a rare class
//! of large grains (few, but much of the extinction) does. Curved mirrors that focus, and clouds much
//! denser in places than on average, are where the bound is not conservative (area lights are: their
//! penumbrae blur the shadows more than the cone to their near side assumes); `surface_footprint` off
//! (or an infinite `continuous_count`) keeps every surface ray walking the grains.

use crate::error::{require, OpticsError};
use crate::space::dda::Bounds3;
use crate::space::ray::RaySegment;
use std::f64::consts::PI;

/// A camera as the footprint rule sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Centre of projection (scene units).
    pub position: [f64; 3],
    /// Narrowest angular width of one pixel over the image (radians).
    pub pixel_angle: f64,
    /// Lens aperture radius (0: a pinhole): camera rays pass within it of `position`.
    pub aperture: f64,
}

impl Camera {
    pub fn new(position: [f64; 3], pixel_angle: f64, aperture: f64) -> Result<Self, OpticsError> {
        for x in position {
            require("camera position", x, x.is_finite(), "finite")?;
        }
        require(
            "pixel_angle",
            pixel_angle,
            pixel_angle.is_finite() && pixel_angle > 0.0,
            "finite and > 0",
        )?;
        require(
            "aperture",
            aperture,
            aperture.is_finite() && aperture >= 0.0,
            "finite and >= 0",
        )?;
        Ok(Camera {
            position,
            pixel_angle,
            aperture,
        })
    }
}

/// A light as the footprint rule sees it: a sphere that shadow rays towards it aim into (radius 0 for
/// a point or spot light).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub centre: [f64; 3],
    pub radius: f64,
}

impl Light {
    pub fn new(centre: [f64; 3], radius: f64) -> Result<Self, OpticsError> {
        for x in centre {
            require("light centre", x, x.is_finite(), "finite")?;
        }
        require(
            "light radius",
            radius,
            radius.is_finite() && radius >= 0.0,
            "finite and >= 0",
        )?;
        Ok(Light { centre, radius })
    }
}

/// What the rule knows of the scene: its cameras, and its lights at finite distance (None: unknown).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct View {
    pub cameras: Vec<Camera>,
    pub lights: Option<Vec<Light>>,
}

/// Fraction of the distance along a ray by which a shadow ray may miss its light's centre (float
/// rounding of the directions Mitsuba computes in single precision).
const AIM_TOLERANCE: f64 = 1e-4;

impl View {
    /// Where along the ray the footprint cone converges: the nearest light the ray heads for (module
    /// docs), or infinity; with the lights unknown, `t_max`.
    pub fn convergence(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> f64 {
        let Some(lights) = &self.lights else {
            return t_max;
        };
        lights
            .iter()
            .filter_map(|l| {
                let v = [0, 1, 2].map(|a| l.centre[a] - o[a]);
                let along = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
                let off2 = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - along * along).max(0.0);
                let reach = l.radius + AIM_TOLERANCE * along.abs();
                (along + l.radius > 0.0 && off2 <= reach * reach)
                    .then(|| (along - l.radius).max(0.0))
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// One size class of the grains kept discrete: number density, the mean and mean square of the disk
/// radii R_i (inclusion radius r_c + r_i, widened by τ_max), and the mean extinction cross section.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClassMoments {
    pub density: f64,
    pub mean_radius: f64,
    pub mean_square_radius: f64,
    pub mean_extinction: f64,
}

impl ClassMoments {
    /// From sums over the class (weights w: 1 per stored particle, expected counts for a procedural
    /// cloud): Σw, Σw R, Σw R², Σw C_t, over the box's volume.
    pub fn from_sums(sums: [f64; 4], volume: f64) -> Self {
        if !(sums[0] > 0.0 && volume > 0.0) {
            return ClassMoments::default();
        }
        ClassMoments {
            density: sums[0] / volume,
            mean_radius: sums[1] / sums[0],
            mean_square_radius: sums[2] / sums[0],
            mean_extinction: sums[3] / sums[0],
        }
    }
}

/// When a ray from a surface may see the grains' continuous equivalent (module docs).
#[derive(Clone, Debug)]
pub struct SurfaceFootprint {
    classes: Vec<ClassMoments>,
    bounds: Bounds3,
    /// The longest window counted: `resolvable`'s cylinder length.
    length: f64,
    min_count: f64,
    /// The least footprint radius with which any ray could pass (a cylinder as long as the box's
    /// diagonal or a mean free path): rays whose footprint bound stays below it are turned away
    /// before any other work (sparse grains: nearly every ray).
    least_radius: f64,
}

impl SurfaceFootprint {
    /// The rule for the discrete classes `classes` of particles whose centres fill `bounds`, counted
    /// over windows of at most `length` (the cylinder length of `resolvable`); None when nothing
    /// could pass it (no discrete class, or an infinite `min_count`).
    pub fn new(
        classes: Vec<ClassMoments>,
        bounds: Bounds3,
        length: f64,
        min_count: f64,
    ) -> Option<Self> {
        let classes: Vec<ClassMoments> = classes.into_iter().filter(|c| c.density > 0.0).collect();
        if !(min_count.is_finite() && !classes.is_empty()) {
            return None;
        }
        let mut rule = SurfaceFootprint {
            classes,
            bounds,
            length,
            min_count,
            least_radius: 0.0,
        };
        // The effective count grows with the radius: bisect for where it reaches min_count.
        let e = [0, 1, 2].map(|a| (bounds.hi[a] - bounds.lo[a]).max(0.0));
        let len = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt().min(length);
        let passes = |r: f64| rule.passes(len, len * r, len * r * r);
        let (mut lo, mut hi) = (0.0, len.max(1e-300));
        while !passes(hi) && hi < 1e300 {
            (lo, hi) = (hi, hi * 4.0);
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if passes(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        rule.least_radius = lo;
        Some(rule)
    }

    /// Does a window (∫dt, ∫ρ dt, ∫ρ² dt) pass: an effective count of at least `min_count`, at least
    /// twice what the disks alone hold (module docs)? Monotone in ρ and, at constant ρ, in the window's
    /// length, as the early rejection needs.
    fn passes(&self, i0: f64, i1: f64, i2: f64) -> bool {
        let n = self.effective_count(i0, i1, i2);
        n >= self.min_count && n >= FOOTPRINT_SHARE * self.effective_count(i0, 0.0, 0.0)
    }

    /// The grains' effective count (module docs) in a window of the cone with ∫dt = `i0`, ∫ρ dt =
    /// `i1`, ∫ρ² dt = `i2`.
    fn effective_count(&self, i0: f64, i1: f64, i2: f64) -> f64 {
        // Per class: the expected count in the cone, E[(ρ + R)²] = ρ² + 2ρ E[R] + E[R²], and the
        // optical depth per unit length.
        let (mut tau, mut spread) = (0.0, 0.0);
        for c in &self.classes {
            let count =
                c.density * PI * (i2 + 2.0 * c.mean_radius * i1 + c.mean_square_radius * i0);
            let t = c.density * c.mean_extinction;
            if t > 0.0 {
                if count.is_nan() || count <= 0.0 {
                    return 0.0;
                }
                tau += t;
                spread += t * t / count;
            }
        }
        if spread > 0.0 {
            tau * tau / spread
        } else {
            0.0
        }
    }

    /// Does the ray (origin `o`, unit direction `d`, on [0, `t_max`)), started at no event, see the
    /// continuous equivalent? (Module docs; false without cameras.)
    pub fn sees_field(&self, view: &View, o: [f64; 3], d: [f64; 3], t_max: f64) -> bool {
        if view.cameras.is_empty() {
            return false;
        }
        // ρ(t) ≤ (α/2) |o − c| on every ray (module docs): most rays of a sparse cloud stop here.
        let bound2 = view
            .cameras
            .iter()
            .map(|c| {
                let v = [0, 1, 2].map(|a| o[a] - c.position[a]);
                (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) * (0.5 * c.pixel_angle).powi(2)
            })
            .fold(f64::INFINITY, f64::min);
        if bound2.is_nan() || bound2 < self.least_radius * self.least_radius {
            return false;
        }
        if view.cameras.iter().any(|c| is_camera_ray(c, o, d)) {
            return false;
        }
        let Some((ta, tb)) = self.bounds.clip(&RaySegment::new(o, d, 0.0, t_max)) else {
            return false; // misses the grains: nothing to save
        };
        let a = view.convergence(o, d, t_max);
        let tb = tb.min(a); // a shadow ray ends at its light
        if tb <= ta {
            return false;
        }
        let k = view
            .cameras
            .iter()
            .map(|c| cone_slope(c, o, d, a))
            .fold(f64::INFINITY, f64::min);
        // The window: `length` at the cone's narrow end (the far end of the chord).
        let ta = ta.max(tb - self.length);
        // ρ at the window's ends (linear between: k (a − t), or k for a cone without an end);
        // Mitsuba's unbounded rays end at the largest float, so a − t is never formed alone.
        let (ra, rb) = if a.is_finite() {
            (k * (a - ta).max(0.0), k * (a - tb).max(0.0))
        } else {
            (k, k)
        };
        let i0 = tb - ta;
        let (i1, i2) = (
            i0 * (ra + rb) / 2.0,
            i0 * (ra * ra + ra * rb + rb * rb) / 3.0,
        );
        if !(i0 > 0.0 && i0.is_finite()) {
            return false;
        }
        self.passes(i0, i1, i2)
    }
}

/// Does the ray's backward half-line pass within the lens aperture of the camera (a camera ray, or
/// one re-spawned along a camera ray's line at a boundary)? The tolerance covers single-precision
/// origins and Mitsuba's offsets of re-spawned rays.
pub fn is_camera_ray(cam: &Camera, o: [f64; 3], d: [f64; 3]) -> bool {
    let v = [0, 1, 2].map(|a| o[a] - cam.position[a]);
    let vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let b = (v[0] * d[0] + v[1] * d[1] + v[2] * d[2]).max(0.0);
    // Distance from the camera to the nearest point o − s d (s = b ≥ 0), from the cross product.
    let x = [
        v[1] * d[2] - v[2] * d[1],
        v[2] * d[0] - v[0] * d[2],
        v[0] * d[1] - v[1] * d[0],
    ];
    let dist2 = if b > 0.0 {
        x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
    } else {
        vv
    };
    let scale = 1.0
        + o.iter()
            .chain(&cam.position)
            .fold(0.0f64, |m, x| m.max(x.abs()));
    let tol = cam.aperture + CAMERA_LINE_TOLERANCE * scale;
    dist2 <= tol * tol
}

/// How much the footprint must raise the effective count over the disks' own (module docs).
const FOOTPRINT_SHARE: f64 = 2.0;

/// Relative tolerance of [`is_camera_ray`] (of the scene's coordinates).
const CAMERA_LINE_TOLERANCE: f64 = 1e-4;

/// The footprint cone's radius per unit distance to where it converges (`t_end` finite: a light), or
/// its constant radius (`t_end` infinite), bounded below over every surface point on the backward
/// half-line (module docs); the lens aperture is taken off the distance.
pub fn cone_slope(cam: &Camera, o: [f64; 3], d: [f64; 3], t_end: f64) -> f64 {
    let v = [0, 1, 2].map(|a| o[a] - cam.position[a]);
    let vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let b = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
    // |v − s d|² = vv − 2 b s + s² for W = o − s d.
    let dist = |s: f64| (vv - 2.0 * b * s + s * s).max(0.0).sqrt();
    let half = 0.5 * cam.pixel_angle;
    if !t_end.is_finite() {
        let s = b.max(0.0);
        return half * (dist(s) - cam.aperture).max(0.0);
    }
    let a = t_end;
    // f(s) = |v − s d| / (a + s): its one stationary point, the end s = 0 and the limit 1 (s → ∞).
    let mut f = (dist(0.0) / a).min(1.0);
    if a + b > 0.0 {
        let s = (vv + a * b) / (a + b);
        if s > 0.0 {
            f = f.min(dist(s) / (a + s));
        }
    }
    // |v − s d| − aperture over (a + s) is at least f − aperture / a.
    half * (f - cam.aperture / a).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_slope(cam: &Camera, o: [f64; 3], d: [f64; 3], a: f64) -> f64 {
        (0..200_000)
            .map(|i| {
                let s = (i as f64 * 1e-4).exp() - 1.0; // 0 .. e^20
                let w = [0, 1, 2].map(|k| o[k] - s * d[k] - cam.position[k]);
                let dist = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
                0.5 * cam.pixel_angle * dist / (a + s)
            })
            .fold(0.5 * cam.pixel_angle, f64::min)
    }

    #[test]
    fn cone_slope_is_the_least_over_the_backward_half_line() {
        let cam = Camera::new([0.3, -1.0, 4.0], 0.01, 0.0).unwrap();
        let mut seed = 7u64;
        let mut next = || {
            seed = crate::rng::splitmix64_finalise(seed.wrapping_add(crate::rng::GOLDEN_GAMMA));
            crate::rng::unit_f64(seed) * 2.0 - 1.0
        };
        for _ in 0..200 {
            let o = [5.0 * next(), 5.0 * next(), 5.0 * next()];
            let d0 = [next(), next(), next()];
            let n = (d0[0] * d0[0] + d0[1] * d0[1] + d0[2] * d0[2]).sqrt();
            let d = d0.map(|x| x / n);
            let a = 0.1 + 20.0 * (next() + 1.0);
            let k = cone_slope(&cam, o, d, a);
            let brute = brute_slope(&cam, o, d, a);
            assert!(k <= brute * (1.0 + 1e-9) + 1e-12, "{k} > {brute}");
            assert!(k >= brute * (1.0 - 1e-3) - 1e-9, "{k} << {brute}");
        }
    }

    /// The 12 cm cube of `scripts/bench/bench_dense.py` (centimetres) and its camera.
    fn cube_and_camera(lights: Option<Vec<Light>>) -> (Bounds3, View) {
        let bounds = Bounds3 {
            lo: [-6.0; 3],
            hi: [6.0; 3],
        };
        let view = View {
            cameras: vec![Camera::new([0.0, 2.0, 42.0], 0.0076, 0.0).unwrap()],
            lights,
        };
        (bounds, view)
    }

    #[test]
    fn the_early_rejection_changes_no_answer() {
        let (bounds, view) =
            cube_and_camera(Some(vec![Light::new([-8.0, 19.0, -15.0], 0.0).unwrap()]));
        let mut seed = 11u64;
        let mut next = || {
            seed = crate::rng::splitmix64_finalise(seed.wrapping_add(crate::rng::GOLDEN_GAMMA));
            crate::rng::unit_f64(seed) * 2.0 - 1.0
        };
        for density in [0.5, 5.0, 100.0, 926.0, 5000.0] {
            let c = ClassMoments {
                density,
                mean_radius: 0.028,
                mean_square_radius: 0.028f64.powi(2),
                mean_extinction: 2.0 * PI * 0.008f64.powi(2),
            };
            let rule =
                SurfaceFootprint::new(vec![c], bounds, 1.0 / (density * 4e-4), 16.0).unwrap();
            let full = SurfaceFootprint {
                least_radius: 0.0,
                ..rule.clone()
            };
            let (mut passed, mut n) = (0, 0);
            for _ in 0..4000 {
                let o = [30.0 * next(), 30.0 * next(), 30.0 * next()];
                let t = [6.0 * next(), 6.0 * next(), 6.0 * next()];
                let v = [0, 1, 2].map(|a| t[a] - o[a]);
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                let d = v.map(|x| x / l);
                let t_max = if next() > 0.0 { f64::INFINITY } else { 60.0 };
                let a = rule.sees_field(&view, o, d, t_max);
                assert_eq!(a, full.sees_field(&view, o, d, t_max));
                passed += a as usize;
                n += 1;
            }
            // Sparse grains pass nowhere, dense ones nearly everywhere; some in between.
            assert!(density > 1.0 || passed == 0, "{density}: {passed}/{n}");
            assert!(
                density < 5000.0 || passed > n / 2,
                "{density}: {passed}/{n}"
            );
        }
    }

    #[test]
    fn camera_rays_never_see_the_field() {
        // A query radius ten times the grains' radius (Eq. 23's usual case): the disks alone hold ~10
        // grains per cylinder of resolvable's length (8, the cube's mean chord), and a camera ray along
        // the cube's diagonal crosses 20.8; two such classes pooled would pass 16.
        let (bounds, _) = cube_and_camera(None);
        let class = |r: f64| ClassMoments {
            density: 10.0 / (PI * (0.02 + r).powi(2) * 8.0),
            mean_radius: 0.02 + r,
            mean_square_radius: (0.02 + r).powi(2),
            mean_extinction: 2.0 * PI * r * r,
        };
        let one = SurfaceFootprint::new(vec![class(0.002)], bounds, 8.0, 16.0).unwrap();
        let two =
            SurfaceFootprint::new(vec![class(0.002), class(0.0015)], bounds, 8.0, 16.0).unwrap();
        let c = [20.0, 20.0, 20.0];
        let view = View {
            cameras: vec![Camera::new(c, 0.01, 0.0).unwrap()],
            lights: Some(vec![]),
        };
        let s3 = 1.0 / 3f64.sqrt();
        let d = [-s3, -s3, -s3];
        // From the camera, re-spawned at the cube's corner, and re-spawned with an offset of 1e-5.
        for o in [c, [6.0, 6.0, 6.0], [6.00001, 6.0, 5.99999]] {
            for rule in [&one, &two] {
                assert!(!rule.sees_field(&view, o, d, f64::INFINITY));
                assert!(!rule.sees_field(&view, o, d, 1e6));
            }
        }
        // A wall's ray across the same cube, far from the camera's lines, does.
        assert!(two.sees_field(&view, [-40.0, 0.0, 0.0], [1.0, 0.0, 0.0], f64::INFINITY));
    }

    #[test]
    fn camera_rays_have_no_footprint() {
        let cam = Camera::new([0.0, 2.0, 42.0], 0.0076, 0.0).unwrap();
        assert!(Light::new([0.0; 3], -1.0).is_err() && Camera::new([0.0; 3], 0.0, 0.0).is_err());
        // A camera ray re-spawned at a boundary 30 units along: its line passes through the camera.
        let d = [0.1f64, -0.05, -1.0];
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let d = d.map(|x| x / n);
        let o = [0, 1, 2].map(|k| cam.position[k] + 30.0 * d[k]);
        assert!(cone_slope(&cam, o, d, f64::INFINITY) < 1e-12);
        assert!(cone_slope(&cam, o, d, 12.0) < 1e-12);
        // A wall's ray towards the same place is not.
        assert!(cone_slope(&cam, [20.0, 0.0, 0.0], [-1.0, 0.0, 0.0], f64::INFINITY) > 0.1);
    }

    #[test]
    fn dense_classes_pass_sparse_ones_do_not() {
        let (bounds, cam) = cube_and_camera(None);
        let rule = |density: f64| {
            let c = ClassMoments {
                density,
                mean_radius: 0.028,
                mean_square_radius: 0.028f64.powi(2),
                mean_extinction: 2.0 * PI * 0.008f64.powi(2),
            };
            SurfaceFootprint::new(vec![c], bounds, 1.0 / 0.37, 16.0).unwrap()
        };
        // A bounce from the left wall across the cloud: footprint 0.0038 × ~20 = 0.076 wide.
        let (o, d) = ([-20.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        assert!(rule(926.0).sees_field(&cam, o, d, f64::INFINITY));
        assert!(!rule(5.0).sees_field(&cam, o, d, f64::INFINITY));
        // Mitsuba's unbounded rays end at the largest float: the same as no end.
        assert!(rule(926.0).sees_field(&cam, o, d, f32::MAX as f64));
        assert!(!rule(5.0).sees_field(&cam, o, d, f32::MAX as f64));
        // A camera ray counts the grains of its query cylinder alone (fewer than 16: a discrete class).
        let o = [0.0, 2.0, 42.0];
        let dc = [0.0, -2.0 / 42.0f64.hypot(2.0), -42.0 / 42.0f64.hypot(2.0)];
        assert!(!rule(926.0).sees_field(&cam, o, dc, f64::INFINITY));
        // No camera known: never.
        assert!(!rule(1e9).sees_field(&View::default(), [-20.0, 0.0, 0.0], d, f64::INFINITY));
        // Lights unknown: a ray's end is taken for a light. One ending in the cloud: the cone narrows
        // to nothing there.
        let near_light = rule(926.0).sees_field(&cam, [-20.0, 0.0, 0.0], d, 20.0);
        let far_light = rule(926.0).sees_field(&cam, [-20.0, 0.0, 0.0], d, 200.0);
        assert!(far_light && !near_light);
        // Lights known: a shadow ray aimed at a lamp in the cloud keeps the grains; the same ray ending
        // at the cloud's boundary (Mitsuba's t_max) with no light ahead sees the field.
        let lamp = |x: f64, r: f64| View {
            lights: Some(vec![Light::new([x, 0.0, 0.0], r).unwrap()]),
            ..cam.clone()
        };
        assert!(!rule(926.0).sees_field(&lamp(0.0, 0.0), [-20.0, 0.0, 0.0], d, 20.0));
        assert!(!rule(926.0).sees_field(&lamp(0.0, 0.0), [-20.0, 0.0, 0.0], d, 26.0));
        assert!(!rule(926.0).sees_field(&lamp(0.0, 1.0), [-20.0, 0.5, 0.0], d, 26.0));
        assert!(rule(926.0).sees_field(&lamp(0.0, 0.3), [-20.0, 0.5, 0.0], d, 26.0));
        assert!(rule(926.0).sees_field(&lamp(200.0, 0.0), [-20.0, 0.0, 0.0], d, 26.0));
        assert!(rule(926.0).sees_field(&lamp(-30.0, 0.0), [-20.0, 0.0, 0.0], d, 26.0));
        assert!(SurfaceFootprint::new(vec![], bounds, 1.0, 16.0).is_none());
        // A rare class of small grains beside the dense one changes little; a rare class of large
        // grains (under one per footprint) carrying a quarter of the extinction keeps the ray walking.
        let mixed = |r: f64, density: f64| {
            let dense = ClassMoments {
                density: 926.0,
                mean_radius: 0.028,
                mean_square_radius: 0.028f64.powi(2),
                mean_extinction: 2.0 * PI * 0.008f64.powi(2),
            };
            let rare = ClassMoments {
                density,
                mean_radius: 0.02 + r,
                mean_square_radius: (0.02 + r).powi(2),
                mean_extinction: 2.0 * PI * r * r,
            };
            SurfaceFootprint::new(vec![dense, rare], bounds, 1.0 / 0.37, 16.0).unwrap()
        };
        let (o, d) = ([-20.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        assert!(mixed(0.004, 2.0).sees_field(&cam, o, d, f64::INFINITY));
        let share = 0.5 * 0.2f64.powi(2) / (926.0 * 0.008f64.powi(2) + 0.5 * 0.2f64.powi(2));
        assert!(share > 0.25);
        assert!(!mixed(0.2, 0.5).sees_field(&cam, o, d, f64::INFINITY));
        assert!(SurfaceFootprint::new(
            vec![ClassMoments::from_sums([1.0, 0.1, 0.01, 0.001], 1.0)],
            bounds,
            1.0,
            f64::INFINITY
        )
        .is_none());
    }
}
