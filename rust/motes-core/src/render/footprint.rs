//! Rays from surfaces and the pixel footprint they carry (issue 25).
//!
//! A path that has scattered in the cloud sees the grains' continuous equivalent
//! (`crate::render::discrete`, "Grains along a path"). Rays that start on a surface (a wall's shadow ray towards
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
//! backward half-line.
//!
//! Camera rays (issue 43). A ray whose backward half-line passes within the lens aperture (plus float
//! rounding) of a camera is that camera's ray, or one re-spawned along its line at a boundary: the
//! pixel's cone widens from the camera, ρ(t) = (α/2) (z₀ + t − aperture) at the distance z₀ + t from
//! it (a thin lens's footprint is at least the pinhole's, its defocus only widens it), and the window
//! of least count is at the start of the ray's chord through the grains' box. So a cloud seen from
//! afar, whose grains a pixel holds many of, is seen as its continuous equivalent; one seen from
//! nearby walks its grains (Eq. 23's question, asked per ray at the ray's own distance). A ray on a
//! camera's line is also read as a surface's ray for every other camera, and passes only where all
//! readings pass. What a pixel shows of the grains is the texture of their realisation, relative
//! variance ~1/N over the N grains its cone holds; the render's own noise has relative variance at
//! least ~1/spp (each sample follows one of those grains). A camera ray passes where N is at least
//! `continuous_count` and [`CAMERA_COUNT_PER_SAMPLE`] × spp, so that the texture stays below the
//! noise (RMS(default − exact) / noise ≤ 1.1); with the render's spp unknown camera rays walk the
//! grains. Orthographic cameras: a pixel's footprint is `pixel_width / 2` in radius at every
//! distance, camera rays are those parallel to the axis, rays from surfaces keep that radius unless
//! they head for a light (then 0: the surface point could lie anywhere behind them). Either way a ray
//! passes only where its footprint, not the grains' own disks, is what holds the grains: the footprint
//! must at least double the effective count the disks alone hold over the same window (a query radius
//! far wider than the grains, Eq. 23's usual case, with the classes pooled, would otherwise pass a ray
//! just off a camera's line, through a glass pane say).
//!
//! An area light blurs each grain's shadow further: every point of the light casts its own, so at a
//! distance t from W along a ray towards the light the grains' shadows reaching W spread over the light's
//! outline seen from W, projected to t: a cone widening from W with radius c t, c = (least half-width of
//! the light as seen from W) / (distance to its far side). A light that holds a disc of radius b with
//! normal n (a rectangle's or disk's inscribed disc, a sphere's outline with no normal) shows at least
//! b |n·u| in every direction from W along u, and |n·u| over every W on the backward half-line is least at
//! one of its ends (or 0 where n·u changes sign). The pixel's cone and the penumbra's combine by
//! convolution, whose effective area (∫w)² / ∫w² is at least that of either (Young's inequality), so the
//! rule takes ρ(t) = max(K (a − t), c t): V-shaped, narrowest between W and the light, and the window
//! counted is the one of least count (where ρ is equal at both its ends). A grain near W still casts a
//! shadow as sharp as the pixel's footprint: the window reaches it where that is the narrowest part.
//! The penumbra counts only for a ray that ends on the light itself (a flat light's plane crossed
//! within its radius of the centre, a sphere's outline), and the caller gives a light its disc only
//! where that is safe (`motes.plugins.cameras`: a light that shines alike from all its surface, in a
//! scene whose surfaces are all diffuse).
//!
//! Diffuse surfaces. A pixel that sees a diffuse surface at W integrates the light arriving there over
//! the cosine lobe: a ray bounced off W is one sample of that integral, and the grains along it reach
//! the pixel blurred over the lobe, a cone of radius of order t at a distance t from W. The rule takes
//! a quarter of that, ρ(t) = max(K, c t) with c = [`DIFFUSE_LOBE_SLOPE`] (the lobe's effective solid
//! angle, (∫cos)² / ∫cos² = 3π/2 sr, is a cone of half-angle ~1.2 rad), and counts the window of least
//! count (at the ray's start, near W, where ρ is the pixel's). It does so only when told that every
//! surface of the scene is diffuse, every light placed and every light at infinity a uniform sky
//! ([`View::diffuse_surfaces`], from the scene: `motes.plugins.cameras`): behind a mirror a bounced
//! ray is seen as sharply as a camera ray, and a sun's shadows are as sharp as the grains. Rays towards
//! a light keep the pixel's cone and the light's penumbra: the surface does not blur its own shadows.
//!
//! Spots: a shadow ray from a point that a spot light leaves dark (outside its cone) carries nothing,
//! whatever it meets, yet Mitsuba traces it (its sample has a pdf, and a zero value); such a ray sees
//! the field, whatever its footprint (the cheapest flight; the camera's lines excepted).
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
//! medium, or the box's mean chord if shorter; less where the ray's own chord is shorter) where the
//! count is least, with each size class's mean density over the particles' box: that count with the
//! ray's own footprint added to each disk. Where the cone's radius changes along the window each grain
//! weighs 1 / (its disk and the cone's area) at its distance, and the count is the effective one of
//! those weights, N = n π ℓ² / ∫ dt / (ρ + R̄)²: the grains in the window where ρ is constant, fewer
//! elsewhere (Cauchy–Schwarz), the grains where the cone is narrowest weighing most.
//! Several classes count as an *effective* number, N_eff = (Σ_k τ_k)² / Σ_k τ_k² / N_k, with N_k
//! the class's expected count and τ_k its expected optical depth: what a viewer would see of the
//! grains is the grain-to-grain texture of the transmittance over the footprint, whose relative
//! spread is τ / √N for one class and τ / √N_eff for a mixture. So a rare class of small grains
//! (a few in a footprint, but little of the extinction) does not keep a ray walking, and a rare class
//! of large grains (few, but much of the extinction) does. Curved mirrors that focus, and clouds much
//! denser in places than on average, are where the bound is not conservative; `surface_footprint` off
//! (or an infinite `continuous_count`) keeps every surface ray walking the grains.

use crate::error::{require, OpticsError};
use crate::space::dda::Bounds3;
use crate::space::ray::RaySegment;
use crate::space::vec3;
use std::f64::consts::PI;

/// A camera as the footprint rule sees it: a pinhole or thin lens (a pixel's footprint (α/2) z in
/// radius at a distance z, at least), or an orthographic camera (`pixel_width / 2` at every distance).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Centre of projection (scene units); an orthographic camera's origin.
    pub position: [f64; 3],
    /// Narrowest angular width of one pixel over the image (radians; 0 for an orthographic camera).
    pub pixel_angle: f64,
    /// Lens aperture radius (0: a pinhole): camera rays pass within it of `position`.
    pub aperture: f64,
    /// An orthographic camera's viewing direction (unit; zero for a perspective one): its rays are
    /// parallel to it.
    pub axis: [f64; 3],
    /// An orthographic camera's pixel width in scene units (0 for a perspective one).
    pub pixel_width: f64,
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
            axis: [0.0; 3],
            pixel_width: 0.0,
        })
    }

    /// An orthographic camera at `position` looking along `axis` (any length), its pixels
    /// `pixel_width` wide in scene units.
    pub fn orthographic(
        position: [f64; 3],
        axis: [f64; 3],
        pixel_width: f64,
    ) -> Result<Self, OpticsError> {
        for x in position {
            require("camera position", x, x.is_finite(), "finite")?;
        }
        let len = axis.iter().map(|x| x * x).sum::<f64>().sqrt();
        require(
            "camera axis length",
            len,
            len.is_finite() && len > 0.0,
            "finite and > 0",
        )?;
        require(
            "pixel_width",
            pixel_width,
            pixel_width.is_finite() && pixel_width > 0.0,
            "finite and > 0",
        )?;
        Ok(Camera {
            position,
            pixel_angle: 0.0,
            aperture: 0.0,
            axis: axis.map(|x| x / len),
            pixel_width,
        })
    }

    fn is_orthographic(&self) -> bool {
        self.axis != [0.0; 3]
    }

    /// An upper bound of the pixel's footprint radius on a ray from `o`, at most `far` along it:
    /// along the camera's own line (`on_line`), the cone at `far` beyond `o`; on any other ray the
    /// bound of [`cone_slope`] (the footprint at the nearest surface point it could come from).
    fn footprint_bound(&self, o: [f64; 3], on_line: bool, far: f64) -> f64 {
        let v = [0, 1, 2].map(|a| o[a] - self.position[a]);
        let dist = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let reach = if on_line { dist + far } else { dist };
        0.5 * (self.pixel_angle * reach + self.pixel_width)
    }
}

/// A light as the footprint rule sees it: a sphere that shadow rays towards it aim into (radius 0 for
/// a point or spot light), and a disc that lies on the light (an area light's penumbra: module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub centre: [f64; 3],
    pub radius: f64,
    /// Radius of a disc centred on `centre` that lies on the light (0: none known, as for a point).
    pub disc: f64,
    /// Unit normal of that disc, or zero where the light shows the whole disc from every side (a
    /// sphere's outline).
    pub normal: [f64; 3],
    /// A spot light's axis (unit; zero: it shines every way) and the cosine of the widest angle from
    /// it that it lights (-1: every way).
    pub axis: [f64; 3],
    pub cos_cutoff: f64,
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
        Ok(Light {
            centre,
            radius,
            disc: 0.0,
            normal: [0.0; 3],
            axis: [0.0; 3],
            cos_cutoff: -1.0,
        })
    }

    /// The light as a spot shining along `axis` (any length; zero: every way) within `cos_cutoff`
    /// (the cosine of the widest angle it lights, in [-1, 1]).
    pub fn with_spot(mut self, axis: [f64; 3], cos_cutoff: f64) -> Result<Self, OpticsError> {
        require(
            "spot cos_cutoff",
            cos_cutoff,
            (-1.0..=1.0).contains(&cos_cutoff),
            "in [-1, 1]",
        )?;
        let len = axis.iter().map(|x| x * x).sum::<f64>().sqrt();
        require("spot axis", len, len.is_finite(), "finite")?;
        self.axis = if len > 0.0 {
            axis.map(|x| x / len)
        } else {
            [0.0; 3]
        };
        self.cos_cutoff = if len > 0.0 { cos_cutoff } else { -1.0 };
        Ok(self)
    }

    /// Does the light leave the point `p` dark (a spot pointing elsewhere)? A shadow ray from there
    /// carries nothing, whatever it meets.
    fn leaves_dark(&self, p: [f64; 3]) -> bool {
        if self.cos_cutoff <= -1.0 || self.axis == [0.0; 3] {
            return false;
        }
        let v = [0, 1, 2].map(|a| p[a] - self.centre[a]);
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let cos = (v[0] * self.axis[0] + v[1] * self.axis[1] + v[2] * self.axis[2]) / l;
        // Outside the cone by a margin (float rounding of Mitsuba's own test).
        l > 0.0 && cos < self.cos_cutoff - SPOT_MARGIN
    }

    /// The light with a disc of radius `disc` (at most `radius`) and normal `normal` (any length; zero:
    /// seen whole from every side) lying on it.
    pub fn with_disc(mut self, disc: f64, normal: [f64; 3]) -> Result<Self, OpticsError> {
        require(
            "light disc",
            disc,
            disc.is_finite() && disc >= 0.0 && disc <= self.radius,
            "finite, >= 0 and <= the light's radius",
        )?;
        let len = normal.iter().map(|x| x * x).sum::<f64>().sqrt();
        require("light normal", len, len.is_finite(), "finite")?;
        self.disc = disc;
        self.normal = if len > 0.0 {
            normal.map(|x| x / len)
        } else {
            [0.0; 3]
        };
        Ok(self)
    }

    /// Does the ray (origin `o`, unit direction `d`) head for the light: its forward line within the
    /// light's radius of its centre (plus the float tolerance of Mitsuba's directions)? Then the
    /// centre's distance along the ray and the line's squared distance from it.
    fn aimed_at(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, f64)> {
        let v = [0, 1, 2].map(|a| self.centre[a] - o[a]);
        let along = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
        let off2 = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - along * along).max(0.0);
        let reach = self.radius + AIM_TOLERANCE * along.abs();
        (along + self.radius > 0.0 && off2 <= reach * reach).then_some((along, off2))
    }

    /// Does the ray (origin `o`, unit direction `d`, its line `off2` squared from the centre) end on
    /// the light: a flat light's plane crossed ahead within its radius of the centre, a sphere's
    /// outline (its disc) passed within?
    fn ends_on(&self, o: [f64; 3], d: [f64; 3], off2: f64) -> bool {
        let n = self.normal;
        if n == [0.0; 3] {
            return off2 <= self.disc * self.disc;
        }
        let v = [0, 1, 2].map(|a| self.centre[a] - o[a]);
        let nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
        let t = (n[0] * v[0] + n[1] * v[1] + n[2] * v[2]) / nd;
        if !(t > 0.0 && t.is_finite()) {
            return false;
        }
        let q2: f64 = (0..3)
            .map(|a| (o[a] + t * d[a] - self.centre[a]).powi(2))
            .sum();
        q2 <= self.radius * self.radius
    }

    /// Least half-width of the disc as seen from anywhere on the backward half-line W = o − s d (s ≥ 0)
    /// of a ray heading for it, over the distance from W to the light's far side: the slope of the
    /// penumbra cone from o (module docs). `along` and `off`: the centre's distance from o along d
    /// and from the ray's line. The cone's radius at distance t from o is at least this slope times t
    /// whatever s: |C − W| + radius ≤ along + s + off + radius, and (t + s) / (x + s) ≥ t / x for t ≤ x.
    fn penumbra_slope(&self, o: [f64; 3], d: [f64; 3], along: f64, off: f64) -> f64 {
        if self.disc <= 0.0 {
            return 0.0;
        }
        let n = self.normal;
        let cos = if n == [0.0; 3] {
            1.0
        } else {
            // From o − s d the centre lies along u(s), which sweeps the arc from u(0) to d: |n·u| is
            // least at an end, or 0 where n·u changes sign on the way.
            let v = [0, 1, 2].map(|a| self.centre[a] - o[a]);
            let vl = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
            let nu = if vl > 0.0 {
                (n[0] * v[0] + n[1] * v[1] + n[2] * v[2]) / vl
            } else {
                nd
            };
            if nu * nd <= 0.0 {
                0.0
            } else {
                nu.abs().min(nd.abs())
            }
        };
        let far = along + off + self.radius;
        if far > 0.0 {
            self.disc * cos / far
        } else {
            0.0
        }
    }
}

/// What the rule knows of the scene: its cameras, its lights at finite distance (None: unknown), and
/// whether every surface reflects and transmits only diffusely (module docs, "Diffuse surfaces").
#[derive(Clone, Debug, Default, PartialEq)]
pub struct View {
    pub cameras: Vec<Camera>,
    pub lights: Option<Vec<Light>>,
    pub diffuse_surfaces: bool,
    /// Samples per pixel of the render (0: unknown, and camera rays walk the grains): a camera ray
    /// sees the field only where its pixel holds [`CAMERA_COUNT_PER_SAMPLE`] grains per sample.
    pub samples_per_pixel: f64,
}

/// How far outside a spot's cone (in cosine) a point must be for the rule to take it as dark.
const SPOT_MARGIN: f64 = 1e-4;

/// The cone a diffuse surface's reflection blurs a ray's grains over, per unit distance from the
/// surface: a conservative fraction of the cosine lobe's width (module docs, "Diffuse surfaces").
pub const DIFFUSE_LOBE_SLOPE: f64 = 0.25;

/// Fraction of the distance along a ray by which a shadow ray may miss its light's centre (float
/// rounding of the directions Mitsuba computes in single precision).
const AIM_TOLERANCE: f64 = 1e-4;

impl View {
    /// Where along the ray the footprint cone converges: the nearest light the ray heads for (module
    /// docs), or infinity; with the lights unknown, `t_max`.
    pub fn convergence(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> f64 {
        self.target(o, d, t_max).0
    }

    /// Does the ray head for a light that leaves its origin dark (a spot pointing elsewhere)?
    pub fn heads_for_darkness(&self, o: [f64; 3], d: [f64; 3]) -> bool {
        self.lights.iter().flatten().any(|l| {
            l.aimed_at(o, d)
                .is_some_and(|(along, _)| along > 0.0 && l.leaves_dark(o))
        })
    }

    /// [`Self::convergence`] and the slope of the nearest light's penumbra cone from o (0 for a point
    /// light, an unknown light, or none).
    pub fn target(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> (f64, f64) {
        let Some(lights) = &self.lights else {
            return (t_max, 0.0);
        };
        lights
            .iter()
            .filter_map(|l| {
                let (along, off2) = l.aimed_at(o, d)?;
                // The penumbra only where the ray ends on the light itself, not merely in the
                // sphere around it (a rectangle fills little of that).
                let slope = if l.ends_on(o, d, off2) {
                    l.penumbra_slope(o, d, along, off2.sqrt())
                } else {
                    0.0
                };
                Some(((along - l.radius).max(0.0), slope))
            })
            .fold(
                (f64::INFINITY, 0.0),
                |best, x| if x.0 < best.0 { x } else { best },
            )
    }

    /// The widest disc of any light (bounds a penumbra cone's radius).
    fn widest_disc(&self) -> f64 {
        self.lights
            .iter()
            .flatten()
            .fold(0.0, |m: f64, l| m.max(l.disc))
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
    /// The expected number of grains in the discrete classes over the box (read per event ray).
    discrete_count: f64,
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
        let e = [0, 1, 2].map(|a| (bounds.hi[a] - bounds.lo[a]).max(0.0));
        let discrete_count = classes.iter().map(|c| c.density).sum::<f64>() * e[0] * e[1] * e[2];
        let mut rule = SurfaceFootprint {
            classes,
            bounds,
            length,
            min_count,
            least_radius: 0.0,
            discrete_count,
        };
        // The effective count grows with the radius: bisect for where it reaches min_count.
        let e = [0, 1, 2].map(|a| (bounds.hi[a] - bounds.lo[a]).max(0.0));
        let len = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt().min(length);
        let passes = |r: f64| rule.passes(&Window::constant(len, r));
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

    /// The expected number of grains in the discrete classes over the box.
    pub fn discrete_count(&self) -> f64 {
        self.discrete_count
    }

    /// Does a window of the cone pass: an effective count of at least `min_count`, at least twice
    /// what the disks alone hold (module docs)? Monotone in ρ and, at constant ρ, in the window's
    /// length, as the early rejection needs.
    fn passes(&self, w: &Window) -> bool {
        let n = self.effective_count(w, true);
        n >= self.min_count && n >= FOOTPRINT_SHARE * self.effective_count(w, false)
    }

    /// The grains' effective count (module docs) in a window of the cone (`cone` false: of the disks
    /// alone, ρ = 0).
    fn effective_count(&self, w: &Window, cone: bool) -> f64 {
        // Per class: what a viewer sees of the grains is the spread of their summed weights over the
        // footprint, each grain weighing 1 / (its disk and the cone's area) at its distance: an
        // effective count N = n π ℓ² / ∫ dt / (ρ + R̄)² over the window (Cauchy–Schwarz: at most the
        // grains in it, n π ∫ (ρ + R̄)² dt, equal to it where ρ is constant; with R̄, not E[1/(ρ + R)²],
        // which a class's narrow spread of radii barely changes). Then the classes pooled by their
        // optical depths per unit length.
        let (mut tau, mut spread) = (0.0, 0.0);
        for c in &self.classes {
            let h = w.harmonic(c.mean_radius, cone);
            let count = c.density * PI * w.len * w.len / h;
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
    /// continuous equivalent? (Module docs; false without cameras.) A ray on a camera's line is taken
    /// both as that camera's ray (its pixel's cone from the camera) and as a ray from a surface for
    /// every other camera: it passes only where every reading passes.
    pub fn sees_field(&self, view: &View, o: [f64; 3], d: [f64; 3], t_max: f64) -> bool {
        if view.cameras.is_empty() {
            return false;
        }
        let on_line: Vec<bool> = view
            .cameras
            .iter()
            .map(|c| is_camera_ray(c, o, d))
            .collect();
        let camera_ray = on_line.iter().any(|&x| x);
        if camera_ray && !(view.samples_per_pixel > 0.0) {
            return false; // the render's noise unknown: camera rays walk the grains
        }
        // A shadow ray towards a spot that leaves its origin dark carries nothing, whatever it meets:
        // the field is the cheapest (module docs). Not a camera ray's line, whatever it heads for.
        if !camera_ray && view.heads_for_darkness(o, d) {
            return true;
        }
        // ρ(t) ≤ (α/2) |o − c| on a surface's ray, ≤ (α/2) (|o − c| + the box's far corner) on a
        // camera's, or the widest light's disc in a penumbra (module docs): most rays of a sparse
        // cloud stop here.
        let far = self.farthest(o);
        let bound = view
            .cameras
            .iter()
            .zip(&on_line)
            .map(|(c, &line)| c.footprint_bound(o, line, far))
            .fold(f64::INFINITY, f64::min)
            .max(view.widest_disc())
            .max(DIFFUSE_LOBE_SLOPE * far * view.diffuse_surfaces as u8 as f64);
        if bound.is_nan() || bound < self.least_radius {
            return false;
        }
        let Some((ta, tb)) = self.bounds.clip(&RaySegment::new(o, d, 0.0, t_max)) else {
            return false; // misses the grains: nothing to save
        };
        let others = || view.cameras.iter().zip(&on_line).filter(|(_, &l)| !l);
        (!camera_ray || self.camera_window_passes(view, &on_line, o, d, ta, tb))
            && (others().next().is_none()
                || self.surface_window_passes(view, others().map(|(c, _)| c), o, d, t_max, ta, tb))
    }

    /// The distance from `o` to the grains' box's farthest corner.
    fn farthest(&self, o: [f64; 3]) -> f64 {
        let far2: f64 = (0..3)
            .map(|a| {
                let x = (o[a] - self.bounds.lo[a])
                    .abs()
                    .max((o[a] - self.bounds.hi[a]).abs());
                x * x
            })
            .sum();
        far2.sqrt()
    }

    /// Does a camera ray's own pixel cone pass (module docs, "Camera rays")? The cone of the
    /// narrowest of the cameras on whose line it is, counted over the window at the start of its
    /// chord [ta, tb] through the grains' box (the cone only widens away from the camera).
    fn camera_window_passes(
        &self,
        view: &View,
        on_line: &[bool],
        o: [f64; 3],
        d: [f64; 3],
        ta: f64,
        tb: f64,
    ) -> bool {
        let (mut half_angle, mut half_width, mut z0, mut aperture) =
            (f64::INFINITY, f64::INFINITY, f64::INFINITY, 0.0f64);
        for (c, _) in view.cameras.iter().zip(on_line).filter(|(_, &l)| l) {
            half_angle = half_angle.min(0.5 * c.pixel_angle);
            half_width = half_width.min(0.5 * c.pixel_width);
            // The distance from the camera to o along the ray (orthographic: irrelevant).
            let along: f64 = (0..3).map(|a| (o[a] - c.position[a]) * d[a]).sum();
            z0 = z0.min(along.max(0.0));
            aperture = aperture.max(c.aperture);
        }
        // ρ(t) = (α/2) max(0, z0 + t − aperture) + w/2: the lens aperture taken off the distance.
        let rho = |t: f64| half_angle * (z0 + t - aperture).max(0.0) + half_width;
        let len = (tb - ta).min(self.length);
        if !(len > 0.0 && len.is_finite() && z0.is_finite()) {
            return false;
        }
        let end = ta + len;
        let kink = (aperture - z0).clamp(ta, end);
        let window = Window {
            len,
            pieces: [
                (rho(ta), rho(kink), kink - ta),
                (rho(kink), rho(end), end - kink),
            ],
        };
        let count = self.effective_count(&window, true);
        count
            >= self
                .min_count
                .max(CAMERA_COUNT_PER_SAMPLE * view.samples_per_pixel)
            && count >= FOOTPRINT_SHARE * self.effective_count(&window, false)
    }

    /// Does the footprint of a ray from a surface pass for `cameras` (module docs)?
    #[allow(clippy::too_many_arguments)]
    fn surface_window_passes<'c>(
        &self,
        view: &View,
        cameras: impl Iterator<Item = &'c Camera>,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        ta: f64,
        tb: f64,
    ) -> bool {
        let (a, mut c) = view.target(o, d, t_max);
        if !a.is_finite() && view.diffuse_surfaces {
            c = DIFFUSE_LOBE_SLOPE; // a bounce off a diffuse surface
        }
        let tb = tb.min(a); // a shadow ray ends at its light
        if tb <= ta {
            return false;
        }
        let k = cameras
            .map(|cam| cone_slope(cam, o, d, a))
            .fold(f64::INFINITY, f64::min);
        window(k, a, c, ta, tb, self.length).is_some_and(|w| self.passes(&w))
    }
}

/// A window of the footprint cone: its length and ρ along it, linear in at most two pieces
/// (ρ at the piece's start, at its end, its length).
#[derive(Clone, Copy, Debug)]
struct Window {
    len: f64,
    pieces: [(f64, f64, f64); 2],
}

impl Window {
    fn constant(len: f64, rho: f64) -> Self {
        Window {
            len,
            pieces: [(rho, rho, len), (rho, rho, 0.0)],
        }
    }

    /// ∫ dt / (ρ + r)² over the window (`cone` false: ρ = 0), piece by piece in closed form.
    fn harmonic(&self, r: f64, cone: bool) -> f64 {
        self.pieces
            .iter()
            .filter(|p| p.2 > 0.0)
            .map(|&(ra, rb, l)| {
                let (a, b) = if cone { (ra + r, rb + r) } else { (r, r) };
                l / (a * b) // ∫ dt / (a + s t)² over l = l / (a (a + s l))
            })
            .sum()
    }
}

/// The window of the footprint cone that holds the fewest grains (module docs) on [ta, tb], at most
/// `length` long. Towards a light at `a`: ρ(t) = max(k (a − t), c t), the pixel's cone narrowing to the
/// light and an area light's penumbra widening from the surface (slope `c`, 0 for a point light).
/// Otherwise (`a` infinite): ρ(t) = max(k, c t), the pixel's footprint and a diffuse surface's blur
/// (`c`, 0 where the surfaces may be specular). The effective count is least where ∫ dt / (ρ + R)² is
/// largest, whose integrand is unimodal in t: where ρ is equal at both ends (at the start where ρ only
/// grows, at the light where it only shrinks).
fn window(k: f64, a: f64, c: f64, ta: f64, tb: f64, length: f64) -> Option<Window> {
    let len = (tb - ta).min(length);
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    // Mitsuba's unbounded rays end at the largest float, so a − t is never formed alone.
    let toward_light = a.is_finite();
    let start = if !toward_light {
        ta
    } else if c > 0.0 {
        ((k * a - c * len) / (k + c)).min(tb - len).max(ta)
    } else {
        tb - len // the narrow end: at the light
    };
    let rho = |t: f64| {
        let pixel = if toward_light {
            k * (a - t).max(0.0)
        } else {
            k
        };
        pixel.max(c * t)
    };
    // ρ is linear on each side of where the two cones cross.
    let cross = match (toward_light, c > 0.0) {
        (true, _) if k + c > 0.0 => k * a / (k + c),
        (true, _) => a,
        (false, true) => k / c,
        (false, false) => f64::INFINITY,
    };
    let end = start + len;
    let mid = cross.clamp(start, end);
    let piece = |t0: f64, t1: f64| (rho(t0), rho(t1), (t1 - t0).max(0.0));
    Some(Window {
        len,
        pieces: [piece(start, mid), piece(mid, end)],
    })
}

/// Does the ray's backward half-line pass within the lens aperture of the camera (a camera ray, or
/// one re-spawned along a camera ray's line at a boundary)? The tolerance covers single-precision
/// origins and Mitsuba's offsets of re-spawned rays.
pub fn is_camera_ray(cam: &Camera, o: [f64; 3], d: [f64; 3]) -> bool {
    let v = [0, 1, 2].map(|a| o[a] - cam.position[a]);
    if cam.is_orthographic() {
        // Parallel to the axis (a ray towards the sky along it has the same footprint bound).
        let cos = d[0] * cam.axis[0] + d[1] * cam.axis[1] + d[2] * cam.axis[2];
        return cos >= 1.0 - ORTHO_AXIS_TOLERANCE;
    }
    let vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let b = (v[0] * d[0] + v[1] * d[1] + v[2] * d[2]).max(0.0);
    // Distance from the camera to the nearest point o − s d (s = b ≥ 0), from the cross product.
    let x = vec3::cross(v, d);
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

/// Grains a camera ray's pixel must hold per sample of the render to see the field (module docs,
/// "Camera rays"): the grains' pixel-to-pixel texture, relative variance ~1/N, then stays below
/// 0.4 of the render's own relative variance per pixel (at least ~1/spp: a path samples one grain
/// of those the pixel holds), so that RMS(default − exact) stays within 1.1 of the noise of their
/// difference: √(1 + 0.4 / 2) ≈ 1.1.
pub const CAMERA_COUNT_PER_SAMPLE: f64 = 2.5;

/// How much the footprint must raise the effective count over the disks' own (module docs).
const FOOTPRINT_SHARE: f64 = 2.0;

/// Relative tolerance of [`is_camera_ray`] (of the scene's coordinates).
const CAMERA_LINE_TOLERANCE: f64 = 1e-4;

/// How far from an orthographic camera's axis (1 − cos) its rays' directions may be (single-precision
/// directions).
const ORTHO_AXIS_TOLERANCE: f64 = 1e-6;

/// The footprint cone's radius per unit distance to where it converges (`t_end` finite: a light), or
/// its constant radius (`t_end` infinite), bounded below over every surface point on the backward
/// half-line (module docs); the lens aperture is taken off the distance.
pub fn cone_slope(cam: &Camera, o: [f64; 3], d: [f64; 3], t_end: f64) -> f64 {
    if cam.is_orthographic() {
        // Every pixel's footprint is `pixel_width` across; towards a light it converges over a
        // distance the rule cannot bound (the surface point may be anywhere behind o).
        return if t_end.is_finite() {
            0.0
        } else {
            0.5 * cam.pixel_width
        };
    }
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

    /// `v` scaled to unit length.
    fn unit(v: [f64; 3]) -> [f64; 3] {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / l)
    }

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
            seed = crate::rng::splitmix64(seed);
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

    #[test]
    fn the_window_holds_the_fewest_grains() {
        let mut seed = 5u64;
        let mut next = || {
            seed = crate::rng::splitmix64(seed);
            crate::rng::unit_f64(seed)
        };
        for _ in 0..300 {
            let (k, c) = (0.02 * next(), if next() < 0.3 { 0.0 } else { 0.3 * next() });
            let light = next() < 0.7;
            let a = 5.0 + 50.0 * next();
            let (ta, tb) = (a * 0.5 * next(), a * (0.5 + 0.5 * next()));
            let a = if light { a } else { f64::INFINITY };
            let length = 1.0 + 30.0 * next();
            let r = 0.3 * next();
            let rho = |t: f64| {
                let pixel = if light { k * (a - t).max(0.0) } else { k };
                pixel.max(c * t)
            };
            // Brute force: every start on a fine grid, the count ∫(ρ + R)² by the midpoint rule.
            let len = (tb - ta).min(length);
            // The effective count of a window: len² / ∫ dt / (ρ + r)², by the midpoint rule.
            let count = |t0: f64| {
                let m = 4000;
                let h = (0..m)
                    .map(|i| (rho(t0 + (i as f64 + 0.5) * len / m as f64) + r).powi(-2))
                    .sum::<f64>()
                    * len
                    / m as f64;
                len * len / h
            };
            let best = (0..=400)
                .map(|j| count(ta + (tb - ta - len) * j as f64 / 400.0))
                .fold(f64::INFINITY, f64::min);
            let w = window(k, a, c, ta, tb, length).unwrap();
            let got = len * len / w.harmonic(r, true);
            assert!((w.len - len).abs() < 1e-12);
            assert!(got <= best * (1.0 + 1e-6), "{got} > {best}");
            assert!(got >= best * (1.0 - 2e-3), "{got} << {best}");
        }
    }

    #[test]
    fn the_penumbra_is_the_least_over_the_backward_half_line() {
        let mut seed = 9u64;
        let mut next = || {
            seed = crate::rng::splitmix64(seed);
            crate::rng::unit_f64(seed) * 2.0 - 1.0
        };
        for _ in 0..300 {
            let centre = [10.0 * next(), 10.0 * next(), 10.0 * next()];
            let normal = if next() > 0.8 {
                [0.0; 3]
            } else {
                unit([next(), next(), next()])
            };
            let radius = 0.5 + 3.0 * (next() + 1.0);
            let light = Light::new(centre, radius)
                .unwrap()
                .with_disc(radius * 0.5 * (next() + 1.0), normal)
                .unwrap();
            let o = [20.0 * next(), 20.0 * next(), 20.0 * next()];
            // Aim at a point of the light's sphere.
            let p = [0, 1, 2].map(|a| centre[a] + 0.7 * radius * next());
            let d = unit([0, 1, 2].map(|a| p[a] - o[a]));
            let along: f64 = (0..3).map(|a| (centre[a] - o[a]) * d[a]).sum();
            if along <= radius {
                continue;
            }
            let off = {
                let v = [0, 1, 2].map(|a| centre[a] - o[a]);
                (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - along * along)
                    .max(0.0)
                    .sqrt()
            };
            let slope = light.penumbra_slope(o, d, along, off);
            // From W = o − s d the disc shows a least half-width b |n·u| at distance |C − W|: at a
            // distance t from o (t + s from W) its cone is b |n·u| (t + s) / (|C − W| + radius) wide.
            for t in [0.1, 0.5, 0.9].map(|f| f * (along - radius)) {
                let brute = (0..20_000)
                    .map(|i| {
                        let s = (i as f64 * 1e-3).exp() - 1.0;
                        let v = [0, 1, 2].map(|a| centre[a] - (o[a] - s * d[a]));
                        let vl = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                        let cos = if normal == [0.0; 3] {
                            1.0
                        } else {
                            (0..3).map(|a| normal[a] * v[a]).sum::<f64>().abs() / vl
                        };
                        light.disc * cos * (t + s) / (vl + radius)
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    slope * t <= brute * (1.0 + 1e-9) + 1e-12,
                    "{} > {brute}",
                    slope * t
                );
            }
        }
        // Validation names the parameter.
        let l = Light::new([0.0; 3], 1.0).unwrap();
        assert!(l.with_disc(2.0, [0.0, 0.0, 1.0]).is_err());
        assert!(l.with_disc(-0.1, [0.0, 0.0, 1.0]).is_err());
        assert!(l.with_disc(0.5, [f64::NAN, 0.0, 1.0]).is_err());
    }

    #[test]
    fn an_area_light_blurs_what_a_point_light_shows() {
        // The Cornell box (scene units cm): 3·10^5 grains of 1 mm in a 56 cm box, the camera at 106 cm,
        // a 14 cm ceiling light. A shadow ray from the floor to the light: the pixel's cone alone holds
        // few grains where it converges to the light; the light's penumbra many.
        let bounds = Bounds3 {
            lo: [-28.0; 3],
            hi: [28.0; 3],
        };
        let class = ClassMoments {
            density: 3e5 / 56f64.powi(3),
            mean_radius: 0.3,
            mean_square_radius: 0.09,
            mean_extinction: 2.0 * PI * 0.01,
        };
        let rule = SurfaceFootprint::new(vec![class], bounds, 18.0, 16.0).unwrap();
        let point = Light::new([0.0, 27.9, 0.0], 9.9).unwrap();
        let panel = point.with_disc(7.0, [0.0, 1.0, 0.0]).unwrap();
        let camera = vec![Camera::new([0.0, 0.0, 106.0], 0.0071, 0.0).unwrap()];
        let view = |l: Light| View {
            cameras: camera.clone(),
            lights: Some(vec![l]),
            diffuse_surfaces: false,
            samples_per_pixel: 0.0,
        };
        let o = [5.0, -28.0, -10.0];
        let d = unit([0.0 - o[0], 27.9 - o[1], 0.0 - o[2]]);
        assert!(!rule.sees_field(&view(point), o, d, f64::INFINITY));
        assert!(rule.sees_field(&view(panel), o, d, f64::INFINITY));
        // Seen edge-on the panel shows no width in one direction: no blur.
        let edge = point.with_disc(7.0, [d[1], -d[0], 0.0]).unwrap();
        assert!(!rule.sees_field(&view(edge), o, d, f64::INFINITY));
        // Sparse grains: still nothing.
        let sparse = ClassMoments {
            density: 1e3 / 56f64.powi(3),
            ..class
        };
        let rule = SurfaceFootprint::new(vec![sparse], bounds, 1e3, 16.0).unwrap();
        assert!(!rule.sees_field(&view(panel), o, d, f64::INFINITY));
    }

    #[test]
    fn a_diffuse_surface_blurs_its_bounces_not_its_shadows() {
        // The haze of `scripts/bench/bench_native.py`'s dense room: 3·10^5 grains of ~0.07 cm reach in a
        // 20 cm cube, the camera 42 cm away at 256 px; a bounce off the floor up through the cloud, and
        // a shadow ray from the same point to the spot.
        let bounds = Bounds3 {
            lo: [-10.0; 3],
            hi: [10.0; 3],
        };
        let class = ClassMoments {
            density: 3e5 / 8000.0,
            mean_radius: 0.068,
            mean_square_radius: 0.068f64.powi(2),
            mean_extinction: 2.0 * PI * 0.01f64.powi(2),
        };
        // Counted over one mean free path, 5 cm.
        let rule = SurfaceFootprint::new(vec![class], bounds, 5.0, 16.0).unwrap();
        let spot = [-8.0, 19.0, -15.0];
        let view = |diffuse_surfaces| View {
            cameras: vec![Camera::new([0.0, 2.0, 42.0], 0.0027, 0.0).unwrap()],
            lights: Some(vec![Light::new(spot, 0.0).unwrap()]),
            diffuse_surfaces,
            samples_per_pixel: 0.0,
        };
        let o = [2.0, -12.0, 3.0];
        let bounce = unit([0.3, 1.0, -0.2]);
        assert!(!rule.sees_field(&view(false), o, bounce, f64::INFINITY));
        assert!(rule.sees_field(&view(true), o, bounce, f64::INFINITY));
        // The point light's shadow stays as sharp as the pixel: no blur from the surface, though the
        // same ray would pass as a bounce (the light unknown to the view).
        let shadow = unit([0, 1, 2].map(|a| spot[a] - o[a]));
        assert!(!rule.sees_field(&view(true), o, shadow, f64::INFINITY));
        let no_light = View {
            lights: Some(vec![]),
            ..view(true)
        };
        assert!(rule.sees_field(&no_light, o, shadow, f64::INFINITY));
        // Sparse grains: nothing either way.
        let sparse = ClassMoments {
            density: 10.0 / 8000.0,
            ..class
        };
        let rule = SurfaceFootprint::new(vec![sparse], bounds, 1e3, 16.0).unwrap();
        assert!(!rule.sees_field(&view(true), o, bounce, f64::INFINITY));
    }

    #[test]
    fn rays_towards_a_spot_that_leaves_them_dark_see_the_field() {
        let (bounds, view) = cube_and_camera(None);
        let class = ClassMoments {
            density: 5.0,
            mean_radius: 0.028,
            mean_square_radius: 0.028f64.powi(2),
            mean_extinction: 2.0 * PI * 0.008f64.powi(2),
        };
        let rule = SurfaceFootprint::new(vec![class], bounds, 1.0 / 0.37, 16.0).unwrap();
        // A spot above the cube pointing down at its centre, 8 degrees wide.
        let spot = Light::new([0.0, 20.0, 0.0], 0.0)
            .unwrap()
            .with_spot([0.0, -1.0, 0.0], 8f64.to_radians().cos())
            .unwrap();
        let view = View {
            lights: Some(vec![spot]),
            ..view
        };
        let towards = |o: [f64; 3]| unit([0, 1, 2].map(|a| spot.centre[a] - o[a]));
        // From the floor inside the beam: a sharp shadow, walked; from outside it: dark, the field.
        let lit = [0.5, -12.0, 0.5];
        let dark = [8.0, -12.0, 0.0];
        assert!(!rule.sees_field(&view, lit, towards(lit), f64::INFINITY));
        assert!(rule.sees_field(&view, dark, towards(dark), f64::INFINITY));
        // Another direction from the dark point: a bounce, walked as before.
        assert!(!rule.sees_field(&view, dark, unit([-0.3, 1.0, 0.1]), f64::INFINITY));
        // Without the spot's cone: walked.
        let everywhere = View {
            lights: Some(vec![Light::new(spot.centre, 0.0).unwrap()]),
            ..view.clone()
        };
        assert!(!rule.sees_field(&everywhere, dark, towards(dark), f64::INFINITY));
        assert!(Light::new([0.0; 3], 0.0)
            .unwrap()
            .with_spot([0.0, 0.0, 1.0], 1.5)
            .is_err());
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
            diffuse_surfaces: false,
            samples_per_pixel: 0.0,
        };
        (bounds, view)
    }

    #[test]
    fn the_early_rejection_changes_no_answer() {
        for diffuse_surfaces in [false, true] {
            let (bounds, view) =
                cube_and_camera(Some(vec![Light::new([-8.0, 19.0, -15.0], 0.0).unwrap()]));
            early_rejection_changes_no_answer(
                bounds,
                View {
                    diffuse_surfaces,
                    ..view
                },
            );
        }
        // A panel with its disc, half the rays aimed at points of it.
        let panel = Light::new([0.0, 9.0, 0.0], 5.7)
            .unwrap()
            .with_disc(4.0, [0.0, 1.0, 0.0])
            .unwrap();
        let (bounds, view) = cube_and_camera(Some(vec![panel]));
        early_rejection_changes_no_answer(bounds, view);
    }

    fn early_rejection_changes_no_answer(bounds: Bounds3, view: View) {
        let mut seed = 11u64;
        let mut next = || {
            seed = crate::rng::splitmix64(seed);
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
                let mut t = [6.0 * next(), 6.0 * next(), 6.0 * next()];
                // Aim at a light's surface half the time (its disc's plane, within its radius).
                if let Some(l) = view.lights.iter().flatten().find(|l| l.disc > 0.0) {
                    if next() > 0.0 {
                        t = [
                            l.centre[0] + 4.0 * next(),
                            l.centre[1],
                            l.centre[2] + 4.0 * next(),
                        ];
                    }
                }
                let d = unit([0, 1, 2].map(|a| t[a] - o[a]));
                let t_max = if next() > 0.0 { f64::INFINITY } else { 60.0 };
                let a = rule.sees_field(&view, o, d, t_max);
                assert_eq!(a, full.sees_field(&view, o, d, t_max));
                passed += a as usize;
                n += 1;
            }
            // Sparse grains pass nowhere, dense ones nearly everywhere; some in between. (Behind
            // diffuse surfaces or in an area light's penumbra, sparse grains far from the surface do:
            // the blur averages many.)
            let blurred = view.diffuse_surfaces || view.widest_disc() > 0.0;
            assert!(
                blurred || density > 1.0 || passed == 0,
                "{density}: {passed}/{n}"
            );
            assert!(
                density < 5000.0 || passed > n / 2,
                "{density}: {passed}/{n}"
            );
        }
    }

    /// A query radius ten times the grains' radius (Eq. 23's usual case): the disks alone hold ~10
    /// grains per cylinder of resolvable's length (8, the cube's mean chord); two such classes pooled.
    fn two_wide_classes(bounds: Bounds3) -> SurfaceFootprint {
        let class = |r: f64| ClassMoments {
            density: 10.0 / (PI * (0.02 + r).powi(2) * 8.0),
            mean_radius: 0.02 + r,
            mean_square_radius: (0.02 + r).powi(2),
            mean_extinction: 2.0 * PI * r * r,
        };
        SurfaceFootprint::new(vec![class(0.002), class(0.0015)], bounds, 8.0, 16.0).unwrap()
    }

    #[test]
    fn camera_rays_see_the_field_where_their_pixel_holds_many_grains() {
        let (bounds, _) = cube_and_camera(None);
        let rule = two_wide_classes(bounds);
        let c = [20.0, 20.0, 20.0];
        let s3 = 1.0 / 3f64.sqrt();
        let d = [-s3, -s3, -s3];
        let view = |cameras: Vec<Camera>, diffuse_surfaces| View {
            cameras,
            lights: Some(vec![]),
            diffuse_surfaces,
            samples_per_pixel: 16.0,
        };
        for diffuse in [false, true] {
            // From 24 units a pixel of 0.01 rad is 0.24 across: ~400 grains per window.
            let afar = view(vec![Camera::new(c, 0.01, 0.0).unwrap()], diffuse);
            // From the camera, re-spawned at the cube's corner, and with an offset of 1e-5.
            for o in [c, [6.0, 6.0, 6.0], [6.00001, 6.0, 5.99999]] {
                assert!(rule.sees_field(&afar, o, d, f64::INFINITY));
                assert!(rule.sees_field(&afar, o, d, 1e6));
            }
            // Pixels far narrower than the disks: the disks alone hold the grains, and walk them.
            let sharp = view(vec![Camera::new(c, 1e-5, 0.0).unwrap()], diffuse);
            for o in [c, [6.0, 6.0, 6.0]] {
                assert!(!rule.sees_field(&sharp, o, d, f64::INFINITY));
            }
            // Inside the cloud the cone starts at nothing: the grains near the camera are seen.
            let inside = view(vec![Camera::new([0.0; 3], 1e-3, 0.0).unwrap()], diffuse);
            assert!(!rule.sees_field(&inside, [0.0; 3], d, f64::INFINITY));
            // Many samples per pixel: the texture would show above the noise.
            let fine = View {
                samples_per_pixel: 1e4,
                ..afar.clone()
            };
            assert!(!rule.sees_field(&fine, c, d, f64::INFINITY));
            // The render's samples unknown: camera rays walk.
            let unknown = View {
                samples_per_pixel: 0.0,
                ..afar.clone()
            };
            assert!(!rule.sees_field(&unknown, c, d, f64::INFINITY));
            // A second, sharp camera elsewhere: the ray may come from its surfaces too, and walks
            // (unless they are diffuse: their lobe blurs a bounce from 24 units away).
            let both = view(
                vec![
                    Camera::new(c, 0.01, 0.0).unwrap(),
                    Camera::new([-20.0, 20.0, -20.0], 1e-7, 0.0).unwrap(),
                ],
                diffuse,
            );
            assert_eq!(rule.sees_field(&both, c, d, f64::INFINITY), diffuse);
        }
        // Orthographic: wide pixels pass along the axis, narrow ones do not; a ray towards a point
        // light off the axis has no bound (its surface point may be anywhere behind it).
        let ortho = |w: f64| View {
            cameras: vec![Camera::orthographic(c, d, w).unwrap()],
            lights: Some(vec![Light::new([0.0, -30.0, 0.0], 0.0).unwrap()]),
            diffuse_surfaces: false,
            samples_per_pixel: 16.0,
        };
        assert!(rule.sees_field(&ortho(0.3), [7.0, 6.0, 7.0], d, f64::INFINITY));
        assert!(!rule.sees_field(&ortho(1e-5), [7.0, 6.0, 7.0], d, f64::INFINITY));
        assert!(!rule.sees_field(&ortho(0.3), [0.0, 30.0, 0.0], [0.0, -1.0, 0.0], 60.0));
        // ... and keeps the pixel's width on a bounce.
        assert!(rule.sees_field(
            &ortho(0.3),
            [-40.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            f64::INFINITY
        ));
        assert!(Camera::orthographic(c, [0.0; 3], 1.0).is_err());
        assert!(Camera::orthographic(c, d, 0.0).is_err());
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
        // A camera ray: its pixel's cone holds ~150 grains over a mean free path at the cloud, enough
        // at 4 samples per pixel (10 needed), too few at 256 (640); unknown samples: it walks.
        let o = [0.0, 2.0, 42.0];
        let dc = [0.0, -2.0 / 42.0f64.hypot(2.0), -42.0 / 42.0f64.hypot(2.0)];
        assert!(!rule(926.0).sees_field(&cam, o, dc, f64::INFINITY));
        let spp = |samples_per_pixel| View {
            samples_per_pixel,
            ..cam.clone()
        };
        assert!(rule(926.0).sees_field(&spp(4.0), o, dc, f64::INFINITY));
        assert!(!rule(926.0).sees_field(&spp(256.0), o, dc, f64::INFINITY));
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
