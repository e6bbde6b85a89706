//! A lane's site between calls of the packet interface: where its last free flight ended, where the
//! renderer will put that site, and whether a call finds the lane there.

use super::events::Parent;
use crate::space::grid::Site;
use crate::space::vec3;

/// A lane's site of its last free flight in the packet interface, until a call finds the lane there
/// ([`DiscreteMedium::settle`]) or its next free flight replaces it.
#[derive(Clone, Copy, Default)]
pub(super) struct PendingLane {
    pub(super) site: Option<Site>,
    pub(super) parent: Parent,
    /// Where the renderer puts the site ([`site_position`]).
    pub(super) at: [f32; 3],
}

impl PendingLane {
    /// Whether a call at `p` finds the lane at its pending site (then `DiscreteMedium::settle_in`).
    /// Three calls of four do not (no pending site, or one elsewhere: a shadow ray's): told in the
    /// caller, not in a call (one call for all has a big frame).
    #[inline(always)]
    pub(super) fn settles_at(&self, p: [f32; 3]) -> bool {
        self.site.is_some() && at_site(p, self.at)
    }

    pub(super) fn new(site: Option<Site>, parent: Parent) -> Self {
        PendingLane {
            site,
            parent,
            at: [0.0; 3],
        }
    }
}

/// Where the renderer puts a site at distance `t` along a ray: Mitsuba's `Ray3f` evaluates o + t d as
/// a float32 fma of the float32 t it received. Here in f64 (the product is exact, the sum rounds twice:
/// at most an ulp off, which [`at_site`] allows), since f32::mul_add is a libm call in this build.
pub(super) fn site_position(o: [f32; 3], d: [f32; 3], t: f64) -> [f32; 3] {
    let t = t as f32 as f64;
    [0, 1, 2].map(|a| (d[a] as f64 * t + o[a] as f64) as f32)
}

/// Float32 ulps by which a call's position may differ from a lane's predicted site ([`at_site`]).
const SITE_ULPS: f32 = 4.0;

/// Whether a call's position `p` is a lane's site predicted at `at`: the same bits, or within
/// [`SITE_ULPS`] × |x| ε per axis (4–8 float32 ulps) (Mitsuba's tentative distance is the site's t plus E / majorant,
/// below an ulp unless t is tiny; the prediction may be an ulp off).
pub(super) fn at_site(p: [f32; 3], at: [f32; 3]) -> bool {
    p == at
        || (0..3).all(|a| {
            let ulp = p[a].abs().max(at[a].abs()) * f32::EPSILON;
            (p[a] - at[a]).abs() <= SITE_ULPS * ulp.max(f32::MIN_POSITIVE)
        })
}

/// Are two directions the same up to single-precision rounding (|a| = |b| = 1 within it)? The
/// shadow ray's direction and the light's direction that Mitsuba evaluates the phase function at are
/// the same difference of positions, normalised alike.
pub(super) fn same_direction(a: [f32; 3], b: [f32; 3]) -> bool {
    let (a, b) = (a.map(|x| x as f64), b.map(|x| x as f64));
    let c = vec3::cross(a, b);
    // Within 1e-6 rad: single precision rounds a unit vector's direction by ~1e-7.
    vec3::dot(a, b) > 0.0 && vec3::dot(c, c) <= 1e-12 * vec3::dot(a, a) * vec3::dot(b, b)
}
