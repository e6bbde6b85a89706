"""What the integrator may skip around a ``discrete`` medium (motes.plugins.enclosure, issue 25): the phase
function's evaluation towards a light whose shadow ray a site blocks for certain, and the part of a ray beyond its
site (Mitsuba's ``is_homogeneous``). Both are exact: images rendered with them equal images rendered without them.

The scene is built where the skip could go wrong (with a point light; an area light and a sun are checked too): the grains fill a box 1.2 times wider than the null cube that holds
the medium, and a point light sits between the cube's top face and the grains' top. Shadow rays towards it leave the
cube, and the core finds sites beyond the cube's face that Mitsuba discards (the ray has left the medium). A skip that
trusted every site would darken the image: the negative control sets such an enclosure by hand and sees it.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from _scenes import run_json

CODE = textwrap.dedent("""
    import json, sys
    import numpy as np
    import motes, mitsuba as mi
    motes.set_variant(sys.argv[1])
    import motes.plugins.enclosure as E
    from _scenes import point_lit_cube

    def scene(extra=None, integrator="volpath", **integrator_props):
        grains = {"type": "discrete", "count": 8000, "radius_median": 300, "radius_sigma_g": 1.2, "eta": 1.5,
                  "scale_m": 0.01, "seed": 3, "to_world": mi.ScalarTransform4f().scale(1.2),
                  "phase": {"type": "particle"}}
        d = point_lit_cube(mi, grains, integrator={"type": integrator, "max_depth": 12, **integrator_props},
                           fov=45, res=16, origin=[0.7, 0.4, 5.0], target=[0, 0.3, 0], light=[0.1, 1.1, 0.05],
                           intensity=3.0, sky=0.05)
        if extra:
            d.update(extra)
        return mi.load_dict(d)

    def medium_of(sc):
        return [s for s in sc.shapes() if s.interior_medium() is not None][0].interior_medium()

    def render(sc, **kw):
        return np.asarray(mi.render(sc, spp=16, seed=5, **kw), dtype=np.float64)[..., :3]

    out = {}
    # The flag each render sets and clears, recorded where the renderer sets it.
    flags = []
    set_clips = E._set_clips_rays
    E._set_clips_rays = lambda m, on: (flags.append(bool(on)), set_clips(m, on))
    skipping = E.SKIPPING_INTEGRATORS
    for name, props in (("volpath", {}), ("volpathmis", {}), ("volpathmis_rgb_mis", {"use_spectral_mis": False})):
        sc = scene(integrator=name.split("_")[0], **props)
        med = medium_of(sc)
        out["after_load_" + name] = [med.data.enclosure_regions, bool(med.is_homogeneous())]
        flags.clear()
        on = render(sc)
        out["regions_" + name] = med.data.enclosure_regions
        out["flags_" + name] = list(flags)
        out["clips_after_" + name] = bool(med.is_homogeneous())
        E.SKIPPING_INTEGRATORS = ()
        flags.clear()
        off = render(sc)
        out["regions_off"] = med.data.enclosure_regions
        out["flags_off"] = list(flags)
        E.SKIPPING_INTEGRATORS = skipping
        out["max_rel_diff_" + name] = float(np.abs(on - off).max() / np.abs(off).max())
        out["mean_on"], out["mean_off"] = float(on.mean()), float(off.mean())
    # Other lights: an area light (a sampled point on it) and a sun (directional: a direction, no point).
    lights = {"area": {"light": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0.1, 1.1, 0.05])
                                 @ mi.ScalarTransform4f().rotate([1, 0, 0], 90) @ mi.ScalarTransform4f().scale(0.3),
                                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 8.0}}}},
              "sun": {"light": {"type": "directional", "direction": [-0.3, -1.0, -0.2],
                                "irradiance": {"type": "rgb", "value": 2.0}}}}
    for name, extra in lights.items():
        sc5 = scene(extra)
        on = render(sc5)
        E.SKIPPING_INTEGRATORS = ()
        off = render(sc5)
        E.SKIPPING_INTEGRATORS = skipping
        out["max_rel_diff_" + name] = float(np.abs(on - off).max() / max(np.abs(off).max(), 1e-30))
        out["mean_" + name] = float(on.mean())
    # Negative control (volpathmis): an enclosure wider than the cube (every site trusted), set with the
    # renderer's own setting of it switched off.
    import motes.plugins.cameras as C
    attach = C.attach
    C.attach = lambda *a, **k: None
    med.data.set_enclosure(balls=[((0.0, 0.0, 0.0), 10.0)])
    out["mean_wrong"] = float(render(sc).mean())
    C.attach = attach
    # prbvolpath (LLVM variants only; it computes a homogeneous medium's transmittance in closed form) and path.
    others = ["prbvolpath", "path"] if sys.argv[1].startswith("llvm") else ["path"]
    out["regions_others"], out["flags_others"] = [], []
    for other in others:
        flags.clear()
        render(sc, integrator=mi.load_dict({"type": other, "max_depth": 12}))
        out["regions_others"].append(med.data.enclosure_regions)
        out["flags_others"] += flags
    # A surface that lets shadow rays through inside the cube (a nested null sphere): no region.
    sc2 = scene({"inner": {"type": "sphere", "radius": 0.3, "bsdf": {"type": "null"}}})
    render(sc2)
    out["regions_nested"] = medium_of(sc2).data.enclosure_regions
    def small(**shapes):  # a 4 x 4 px volpath scene of these shapes
        return mi.load_dict({"type": "scene", "integrator": {"type": "volpath"},
                             "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4},
                                        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0],
                                                                                   up=[0, 1, 0])},
                             **shapes})
    # Two shapes holding the same medium, one inside the other: a shadow ray may leave the sphere (Mitsuba
    # then drops a site past its face), so neither is a region.
    d4 = {"med": {"type": "discrete", "count": 500, "phase": {"type": "particle"}},
          "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "med"}},
          "ball": {"type": "sphere", "radius": 0.5, "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "med"}}}
    sc4 = small(**d4)
    render(sc4)
    out["regions_two_holders"] = medium_of(sc4).data.enclosure_regions
    # A sphere holding the medium: a ball.
    d3 = {"ball": {"type": "sphere", "center": [0.2, 0.0, 0.0], "radius": 1.0, "bsdf": {"type": "null"},
                   "interior": {"type": "discrete", "count": 500, "phase": {"type": "particle"}}}}
    sc3 = small(**d3)
    render(sc3)
    out["regions_ball"] = medium_of(sc3).data.enclosure_regions
    print(json.dumps(out))
""")


@pytest.fixture(scope="module", params=["llvm_ad_rgb", "scalar_rgb", "llvm_ad_spectral", "scalar_spectral"])
def results(request):
    return request.param, run_json(CODE, request.param)


def test_volpath_and_volpathmis_get_the_cube_and_clipped_rays(results):
    """Set for the render, cleared after it; off after a load (a direct Integrator.render skips nothing)."""
    _, r = results
    for name in ("volpath", "volpathmis", "volpathmis_rgb_mis"):
        assert r["regions_" + name] == 1, r
        assert r["flags_" + name] == [True, False] and not r["clips_after_" + name], r
        assert r["after_load_" + name] == [0, False], r


def test_skips_leave_the_image_unchanged(results):
    variant, r = results
    # llvm_ad_rgb renders are deterministic; scalar_rgb ones differ by an ulp run to run in a few pixels.
    tol = 0.0 if variant.startswith("llvm") else 1e-5
    for name in ("volpath", "volpathmis", "volpathmis_rgb_mis", "area", "sun"):
        assert r["max_rel_diff_" + name] <= tol, r
    assert r["mean_area"] > 0 and r["mean_sun"] > 0, r
    assert r["regions_off"] == 0 and r["flags_off"] == [False, False], r


def test_trusting_every_site_would_lose_light(results):
    """The negative control: the test scene does tell a wrong enclosure apart."""
    _, r = results
    assert r["mean_wrong"] < 0.97 * r["mean_on"], r


def test_other_integrators_and_passing_surfaces_get_nothing(results):
    _, r = results
    assert r["regions_others"] and not any(r["regions_others"]) and not any(r["flags_others"]), r
    assert r["regions_nested"] == 0
    assert r["regions_two_holders"] == 0


def test_a_sphere_holds_a_ball(results):
    _, r = results
    assert r["regions_ball"] == 1


def test_render_looks_only_at_shapes_that_hold_media(monkeypatch):
    """``mi.render`` finds a scene's discrete media at every call: it asks for the media of the shapes that are medium
    transitions only, and the data of each medium object once, and a scene without discrete media is scanned once
    per render (a scene of 5·10^5 spheres for explicit path tracing spent 2.6 s per scan asking every shape's media
    for their data). Counted, not timed: 400 spheres and one cube holding a discrete medium (in two ways)."""
    import motes

    motes.set_variant("scalar_rgb")
    import mitsuba as mi

    from motes.plugins import _scene

    T = mi.ScalarTransform4f
    spheres = {f"s{i}": {"type": "sphere", "radius": 0.01, "to_world": T().translate([0.01 * i, 3.0, 0.0])}
               for i in range(400)}
    base = {"type": "scene", "integrator": {"type": "volpath"},
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4},
                       "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])},
            **spheres}
    medium = {"type": "discrete", "count": 500, "phase": {"type": "particle"}}
    calls = []
    real = _scene.data_of
    monkeypatch.setattr(_scene, "data_of", lambda m: (calls.append(m), real(m))[1])
    plain = mi.load_dict(base)
    calls.clear()
    mi.render(plain, spp=1)
    assert calls == []  # no shape is a medium transition: no medium looked at, and no second scan
    with_medium = mi.load_dict({**base, "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium}})
    calls.clear()
    objects = _scene.discrete_medium_objects(with_medium)
    assert len(objects) == 1 and len(calls) == 1
    calls.clear()
    img = np.asarray(mi.render(with_medium, spp=1))
    assert np.isfinite(img).all()
    assert 1 <= len(calls) <= 3  # the medium's data, a few times per render, not once per shape
