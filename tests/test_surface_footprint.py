"""Rays from surfaces and their pixel footprint (issue 25; ``rust/motes-core/src/render/footprint.rs``): the
scene's cameras reach its discrete media at load and at every ``mi.render``; camera rays always walk the
grains; rays from surfaces see the grains' continuous equivalent only where their footprint holds many
grains; and doing so keeps the furnace at 1 and changes no expected value."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import motes

mi = pytest.importorskip("mitsuba")

from motes.plugins.cameras import discrete_media  # noqa: E402


def _grains(count: int = 200_000, r_over_spacing: float = 0.05, **extra) -> dict:
    """Grains in the unit cube (local units of 1 mm), radius a twentieth of their spacing: few per camera
    query cylinder (discrete), hundreds per pixel footprint on a floor 5 units from the camera."""
    spacing = (8.0 / count) ** (1.0 / 3.0)
    r_um = r_over_spacing * spacing * 1e3
    return {"type": "discrete", "count": count, "eta": 1.31, "scale_m": 1e-3, "size_bins": 4, "seed": 5,
            "radius_median": r_um, "radius_sigma_g": 1.1, "phase": {"type": "particle"}, **extra}


def _scene(medium: dict, res: int, spp: int, sensor: str = "perspective", albedo_floor: float = 1.0):
    """The grains in a null cube above a two-sided floor, under a constant white sky; volpath without depth
    limit or roulette."""
    T = mi.ScalarTransform4f
    sensor_d = {"type": sensor, "to_world": T().look_at(origin=[0, 1.5, 5], target=[0, -0.6, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": spp}}
    if sensor != "orthographic":
        sensor_d["fov"] = 40
    if sensor == "thinlens":
        sensor_d.update(aperture_radius=0.05, focus_distance=5.0)
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1_000_000},
        "sensor": sensor_d,
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "floor": {"type": "rectangle", "to_world": T().translate([0, -1.3, 0]).rotate([1, 0, 0], -90).scale(4),
                  "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo_floor}}}},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium},
    })


def _pixels(scene, spp: int, seeds) -> np.ndarray:
    return np.concatenate([np.asarray(mi.render(scene, spp=spp, seed=s), dtype=np.float64).mean(axis=2).ravel()
                           for s in seeds])


def test_cameras_reach_the_medium():
    """Pinhole and thin-lens cameras arrive with their position, narrowest pixel angle and aperture, an
    orthographic one with its axis and pixel width; a camera moved through mi.traverse is seen at the next
    mi.render, with the spp it renders."""
    motes.set_variant("scalar_rgb")
    med = _grains(2000)
    (data,) = discrete_media(_scene(med, 24, 1))
    ((pos, angle, aperture, axis, width),) = data.cameras
    assert np.allclose(pos, (0, 1.5, 5)) and aperture == 0.0 and axis == (0, 0, 0) and width == 0
    tan_half = math.tan(math.radians(20))
    assert angle == pytest.approx(2 * tan_half / 24 / (1 + 2 * tan_half**2), rel=1e-9)
    assert discrete_media(_scene(med, 24, 1, "thinlens"))[0].cameras[0][2] == pytest.approx(0.05)
    ((pos, angle, aperture, axis, width),) = discrete_media(_scene(med, 24, 1, "orthographic"))[0].cameras
    assert angle == 0 and np.allclose(axis, np.array((0, -2.1, -5)) / np.hypot(2.1, 5)) and width > 0
    scene = _scene(med, 8, 1)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("to_world") and "sensor" in k.lower() or k == "PerspectiveCamera.to_world")
    params[key] = mi.ScalarTransform4f().look_at(origin=[3, 0, 4], target=[0, 0, 0], up=[0, 1, 0])
    params.update()
    assert discrete_media(scene)[0].samples_per_pixel == 1  # the sampler's, at load
    mi.render(scene, spp=3)
    assert np.allclose(discrete_media(scene)[0].cameras[0][0], (3, 0, 4), atol=1e-5)
    assert discrete_media(scene)[0].samples_per_pixel == 3  # the render's
    with pytest.raises(ValueError, match="pixel_angle"):
        data.set_cameras([((0, 0, 0), 0.0, 0.0)])
    with pytest.raises((ValueError, RuntimeError), match="surface_footprint"):
        _scene(dict(med, surface_footprint=1.5), 8, 1)


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_lights_are_placed(variant):
    """Point and spot lights by position, area lights by a sphere around their shape, the sky and distant lights
    not at all; an emitter that cannot be placed leaves the lights unknown (None)."""
    motes.set_variant(variant)
    from motes.plugins.cameras import light_of, lights_of

    T = mi.ScalarTransform4f
    scene = mi.load_dict({
        "type": "scene", "point": {"type": "point", "position": [1, 2, 3]},
        "spot": {"type": "spot", "to_world": T().look_at(origin=[-8, 19, -15], target=[0, 0, 0], up=[0, 1, 0])},
        "sky": {"type": "constant"}, "sun": {"type": "directional", "direction": [0, -1, 0]},
        "panel": {"type": "rectangle", "to_world": T().translate([0, 5, 0]).scale(2), "emitter": {"type": "area"}},
        "bulb": {"type": "sphere", "center": [3, 3, 3], "radius": 0.5, "emitter": {"type": "area"}}})
    lights = sorted(lights_of(scene))
    # (centre, radius, disc on the light, its normal): the panel's inscribed disc, the bulb's outline.
    none = (0, 0, 0)
    expect = sorted([((1, 2, 3), 0.0, 0.0, none), ((-8, 19, -15), 0.0, 0.0, none),
                     ((0, 5, 0), math.sqrt(8), 2.0, (0, 0, 1)), ((3, 3, 3), math.sqrt(0.75), 0.5, none)])
    assert len(lights) == 4
    for (c, r, disc, n, axis, cos_cutoff), (ce, re, de, ne) in zip(lights, expect):
        assert np.allclose(c, ce, atol=1e-5) and r == pytest.approx(re, rel=1e-5)
        assert disc == pytest.approx(de, rel=1e-5) and np.allclose(np.abs(n), ne, atol=1e-6)
        # The spot's cone (Mitsuba's default cutoff, 20 degrees) along its look_at; every way for the others.
        if np.allclose(c, (-8, 19, -15)):
            assert np.allclose(axis, np.array([8, -19, 15]) / np.linalg.norm([8, -19, 15]), atol=1e-6)
            assert cos_cutoff == pytest.approx(math.cos(math.radians(20.0)), rel=1e-6)
        else:
            assert axis == (0, 0, 0) and cos_cutoff == -1.0
    assert all(light_of(e) == () for e in scene.emitters() if e.is_environment())
    # A tilted, stretched disk: its least semi-axis and its normal; any other shape: no disc.
    tilted = mi.load_dict({"type": "scene", "lamp": {
        "type": "disk", "to_world": T().translate([1, 1, 1]).rotate([1, 0, 0], 90).scale([3, 0.5, 1]),
        "emitter": {"type": "area"}}, "box": {"type": "cube", "emitter": {"type": "area"}}})
    by_disc = sorted(lights_of(tilted), key=lambda light: light[2])
    assert by_disc[0][2] == 0.0 and by_disc[1][2] == pytest.approx(0.5, rel=1e-5)
    assert np.allclose(np.abs(by_disc[1][3]), (0, 1, 0), atol=1e-6)
    # Behind a mirror or glass a ray towards a light shows the grains against it: no disc counts there.
    shiny = mi.load_dict({"type": "scene", "panel": {"type": "rectangle", "emitter": {"type": "area"}},
                          "mirror": {"type": "disk", "bsdf": {"type": "conductor"},
                                     "to_world": T().translate([0, 0, -3])}})
    assert [light[2] for light in lights_of(shiny)] == [0.0]
    shiny = mi.load_dict({"type": "scene", "panel": {"type": "rectangle", "emitter": {"type": "area"}},
                          "pane": {"type": "cube", "bsdf": {"type": "roughplastic"}}})
    assert [light[2] for light in lights_of(shiny)] == [0.0]
    # A collimated or a textured area light casts sharp shadows: no disc; a uniform one has its disc.
    kinds = mi.load_dict({"type": "scene", "a": {"type": "rectangle", "emitter": {"type": "directionalarea"}},
                          "b": {"type": "rectangle", "to_world": T().translate([0, 3, 0]), "emitter": {
                              "type": "area", "radiance": {"type": "bitmap",
                                                           "bitmap": mi.Bitmap(np.ones((2, 2, 3), dtype=np.float32))}}},
                          "c": {"type": "rectangle", "to_world": T().translate([0, 6, 0]), "emitter": {"type": "area"}}})
    assert sorted((light[0][1], light[2]) for light in lights_of(kinds)) == [(0.0, 0.0), (3.0, 0.0), (6.0, 1.0)]
    # Not diffuse only: a glass cube, an instance (its shape group unseen), a fog of another medium.
    from motes.plugins.cameras import diffuse_only
    assert not diffuse_only(mi.load_dict({"type": "scene", "box": {"type": "cube", "bsdf": {"type": "dielectric"}}}))
    assert not diffuse_only(mi.load_dict({"type": "scene", "g": {"type": "shapegroup", "s": {"type": "sphere"}},
                                          "i": {"type": "instance", "shapegroup": {"type": "ref", "id": "g"}}}))
    assert not diffuse_only(mi.load_dict({"type": "scene", "fog": {"type": "cube", "bsdf": {"type": "null"},
                                                                   "interior": {"type": "homogeneous"}}}))
    assert diffuse_only(mi.load_dict({"type": "scene", "floor": {
        "type": "rectangle", "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse"}}}}))
    # A sun or an environment map casts sharp shadows: no blur from diffuse surfaces there; a uniform sky does not.
    from motes.plugins.cameras import uniform_distant_light
    assert not uniform_distant_light(scene) and not uniform_distant_light(mi.load_dict(
        {"type": "scene", "sun": {"type": "directional", "direction": [0, -1, 0]}}))
    assert uniform_distant_light(mi.load_dict({"type": "scene", "sky": {"type": "constant"}, "lamp": {"type": "point"}}))
    # The core keeps both forms; a disc wider than the light's sphere is refused, naming it.
    data = motes.DiscreteMedium(np.zeros((3, 3)), np.full(3, 5.0), np.zeros(3, dtype=np.int64),
                                [motes.Species(motes.LogNormal(5, 1.2), 1.31)], [0.55])
    data.set_cameras([((0, 0, 5), 0.01, 0.0)], [((0, 1, 0), 2.0), ((0, 2, 0), 2.0, 1.0, (0, 0, 2)),
                                                ((0, 3, 0), 0.0, 0.0, (0, 0, 0), (0, -3, 0), 0.5)])
    assert data.lights == [((0, 1, 0), 2.0, 0.0, (0, 0, 0), (0, 0, 0), -1.0),
                           ((0, 2, 0), 2.0, 1.0, (0, 0, 1), (0, 0, 0), -1.0),
                           ((0, 3, 0), 0.0, 0.0, (0, 0, 0), (0, -1, 0), 0.5)]
    with pytest.raises(ValueError, match="light disc"):
        data.set_cameras([((0, 0, 5), 0.01, 0.0)], [((0, 2, 0), 2.0, 3.0, (0, 0, 1))])
    with pytest.raises(ValueError, match="spot cos_cutoff"):
        data.set_cameras([((0, 0, 5), 0.01, 0.0)], [((0, 2, 0), 0.0, 0.0, (0, 0, 0), (0, 1, 0), 1.5)])


def test_camera_rays_see_the_field_by_their_spp_surface_rays_by_their_footprint():
    """Through the core's free flights, two media alike but for the rule (the same random numbers call by
    call): rays on the camera's lines (re-spawned anywhere along them) sample other sites (the field) with the
    rule on at the scene's 1 spp, where their pixels hold hundreds of grains, and the same sites at 4096 spp
    (10^4 grains needed); rays from the floor towards the cloud sample others (the field) with it on, and the
    same without cameras, with an infinite continuous_count (exact), or through sparse large grains."""
    motes.set_variant("scalar_rgb")
    rng = np.random.default_rng(1)
    n = 4000
    cam = np.array([0.0, 1.5, 5.0])
    target = rng.uniform(-0.8, 0.8, (n, 3))
    d_cam = target - cam
    d_cam /= np.linalg.norm(d_cam, axis=1)[:, None]
    o_cam = cam + rng.uniform(0.0, 3.5, n)[:, None] * d_cam  # re-spawned at a boundary on the way
    o_floor = np.column_stack([rng.uniform(-2, 2, n), np.full(n, -1.3), rng.uniform(-2, 2, n)])
    d_floor = target - o_floor
    d_floor /= np.linalg.norm(d_floor, axis=1)[:, None]

    def pair(**grains):
        return [discrete_media(_scene(_grains(**grains, surface_footprint=on), 64, 1))[0] for on in (True, False)]

    def flights(data, o, d):
        t = data.core.sample_sites(o.astype(np.float32).ravel(), d.astype(np.float32).ravel(),
                                   np.full(len(o), np.inf), np.zeros(len(o), dtype=bool))[0]
        return np.asarray(t)

    def many_samples(data):
        data.set_cameras(data.cameras, data.lights, data.diffuse_surfaces, samples_per_pixel=4096)

    on, off = pair()
    assert on.continuous_particles == 0  # every class discrete for the camera
    assert np.mean(flights(on, o_cam, d_cam) != flights(off, o_cam, d_cam)) > 0.3
    many_samples(on)
    assert np.array_equal(flights(on, o_cam, d_cam), flights(off, o_cam, d_cam), equal_nan=True)
    assert np.mean(flights(on, o_floor, d_floor) != flights(off, o_floor, d_floor)) > 0.3
    on.set_cameras([])
    assert np.array_equal(flights(on, o_floor, d_floor), flights(off, o_floor, d_floor), equal_nan=True)
    on, off = pair(continuous_count=math.inf)
    assert np.array_equal(flights(on, o_floor, d_floor), flights(off, o_floor, d_floor), equal_nan=True)
    # A query radius thirteen times the grains' (Eq. 23's usual regime): the disks alone hold ~10 grains
    # per cylinder of the length the classes are chosen by (discrete), and more along the longest camera
    # rays; at 4096 spp camera rays still walk them, rays from the floor still see the field.
    on, off = pair(r_over_spacing=0.02, query_radius=0.009)
    assert on.continuous_particles == 0
    many_samples(on)
    assert np.array_equal(flights(on, o_cam, d_cam), flights(off, o_cam, d_cam), equal_nan=True)
    assert np.mean(flights(on, o_floor, d_floor) != flights(off, o_floor, d_floor)) > 0.1
    # Sparse large grains (a few per footprint of a 64-pixel image): rays from the floor keep walking them where
    # the floor could be a mirror; off this diffuse floor under a uniform sky, whose lobe blurs them over a cone a
    # quarter of the distance wide, they see the field.
    on, off = pair(count=300, r_over_spacing=0.2)
    assert on.diffuse_surfaces
    assert np.mean(flights(on, o_floor, d_floor) != flights(off, o_floor, d_floor)) > 0.1
    on.set_cameras(on.cameras, on.lights, diffuse_surfaces=False)
    assert np.array_equal(flights(on, o_floor, d_floor), flights(off, o_floor, d_floor), equal_nan=True)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb", "scalar_spectral", "llvm_ad_spectral"])
def test_furnace_with_surfaces(variant):
    """Non-absorbing grains above a white two-sided floor under a white sky, no roulette: every pixel's
    expectation is 1 with rays from the floor seeing the field (3 SE + 1e-3), and they do see it."""
    motes.set_variant(variant)
    res, spp = (24, 32) if variant.startswith("llvm") else (12, 16)
    scene = _scene(_grains(albedo=1.0), res, spp)
    pix = _pixels(scene, spp, (0,))
    m, se = pix.mean(), pix.std(ddof=1) / math.sqrt(pix.size)
    assert abs(m - 1.0) < 3 * se + 1e-3, f"{variant}: {m:.4f} +- {se:.4f}"
    checked, saw_field = discrete_media(scene)[0].core.surface_counts
    assert 0 < saw_field < checked


def test_surface_rule_changes_no_expected_value():
    """Absorbing grains over a grey floor: the image (the floor in the cloud's shadow, the cloud lit by the
    floor) has the same mean with rays from the floor seeing the field as with every ray walking grains,
    within 4 SE of the difference."""
    motes.set_variant("llvm_ad_rgb")
    means = {}
    for on in (True, False):
        scene = _scene(_grains(eta_k=0.002, surface_footprint=on), 32, 32, albedo_floor=0.7)
        pix = _pixels(scene, 32, (0, 1))
        means[on] = (pix.mean(), pix.std(ddof=1) / math.sqrt(pix.size))
        assert (discrete_media(scene)[0].core.surface_counts[1] > 0) == on
    (a, sa), (b, sb) = means[True], means[False]
    assert b < 0.9  # the cloud and floor absorb visibly
    assert abs(a - b) < 4 * math.hypot(sa, sb), (means, (a - b) / math.hypot(sa, sb))


_finite = st.floats(-1e6, 1e6, allow_nan=False)
_cameras = st.lists(st.tuples(st.tuples(_finite, _finite, _finite), st.floats(1e-9, math.pi), st.floats(0.0, 1e3)),
                    max_size=3)
# Lights as (centre, radius) or with a disc on them, (centre, radius, disc <= radius, normal of any length or 0).
_light = st.tuples(st.tuples(_finite, _finite, _finite), st.floats(0.0, 1e6))
_light_with_disc = st.builds(lambda c, r, f, n: (c, r, f * r, n), st.tuples(_finite, _finite, _finite),
                             st.floats(0.0, 1e6), st.floats(0.0, 1.0),
                             st.sampled_from([(0.0, 0.0, 0.0)]) | st.tuples(_finite, _finite, _finite))
_spot = st.builds(lambda c, axis, cos: (c, 0.0, 0.0, (0.0, 0.0, 0.0), axis, cos), st.tuples(_finite, _finite, _finite),
                  st.tuples(_finite, _finite, _finite), st.floats(-1.0, 1.0))
_lights = st.none() | st.lists(_light | _light_with_disc | _spot, max_size=3)


@pytest.fixture(scope="module")
def rule_pair():
    """Two media alike but for the rule, over dense grains (the rule passes for many rays)."""
    motes.set_variant("scalar_rgb")
    return [discrete_media(_scene(_grains(20_000, **{"surface_footprint": on}), 8, 1))[0] for on in (True, False)]


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(cameras=_cameras, lights=_lights, diffuse=st.booleans(), seed=st.integers(0, 2**32 - 1),
       t_max=st.sampled_from([math.inf, float(np.finfo(np.float32).max), 1e-6, 0.5, 3.0, 1e6]))
def test_any_cameras_and_lights(rule_pair, cameras, lights, diffuse, seed, t_max):
    """Over the full ranges of the cameras and lights (none to three, at 1e6 units, pixel angles 1e-9 to pi,
    apertures to 1e3, light radii to 1e6, discs on them with any normal, spots of any axis and cutoff, surfaces
    diffuse or not, rays that end anywhere): free flights stay finite and inside (0, t_max), and a ray that starts at a camera samples what it
    samples without the rule."""
    on, off = rule_pair
    for data in (on, off):
        data.set_cameras(cameras, lights, diffuse)
    rng = np.random.default_rng(seed)
    n = 64
    o = rng.uniform(-3, 3, (n, 3))
    if cameras:
        o[: n // 2] = np.asarray(cameras[0][0])  # camera rays
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    args = (o.astype(np.float32).ravel(), d.astype(np.float32).ravel(), np.full(n, t_max), np.zeros(n, dtype=bool))
    t_on, t_off = (np.asarray(data.core.sample_sites(*args)[0]) for data in (on, off))
    for t in (t_on, t_off):
        hit = ~np.isnan(t)
        assert np.all(t[hit] > 0) and np.all(t[hit] <= t_max * (1 + 1e-9)) and np.all(np.isfinite(t[hit]))
    if cameras and cameras[0][2] == 0.0:
        assert np.array_equal(t_on[: n // 2], t_off[: n // 2], equal_nan=True)
