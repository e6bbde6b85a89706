"""Issue 43, deliverable 5: is the level of detail invisible? Each approximation on by default (``grain_depth``
1: a path's rays after its first scattering event see the grains' continuous equivalent; continuous size
classes, ``continuous_count``; the surface-ray rule) against the fully discrete render (``continuous_count`` =
inf), per scene: the image means, their difference in standard errors (z) and the per-pixel RMS difference
over the exact render's own seed-to-seed noise (1 = at noise level).

Scenes (``--scenes``, comma-separated):

* ``sidelit``: the reported failure: a sparse cloud of 300 glass grains (eta 1.5, radii uniform in 0.2-0.45 mm,
  scene unit 1 mm) in a 20 mm cube, a point lamp beside it (12 mm from its -x face), the camera across
  (+z), seeing side-scattered light against black; ``volpath`` max_depth 16. Rendered at the default
  ``query_radius`` (0) and at 3 mm (``sidelit3mm``), where the size classes go continuous;
* ``rotated``: a crate (a cube with a rotated ``to_world`` holding the medium) of 8e3 grains, discrete over
  its ``homogeneous`` twin (``scripts/bench/bench_dropin.py --rotated-study``'s crate);
* ``haze[-nCOUNT][-rRADIUS_UM]``: the dust room (``bench_render.room``: a spot beam and a dim panel) holding a haze
  at the defaults but its grains (3e5 glass grains of 100 um); ``--spp``, every config asked for;
* any scene of ``scenes_xml/`` by its name (``lamp``, ``cornell``, ...), at small res and spp.

``--configs ...,exact2`` adds the exact render again with other sampler seeds (2000 + s instead of 1000 + s): the
spread of the metric itself between two renders of one method (heavy-tailed noise, e.g. a lamp's glints, lets
RMS/noise reach 1.2-1.4 and z 1 between two exact renders at these settings).

Per scene it renders ``default``, ``exact`` (``continuous_count`` = inf) and, as a diagnostic, ``depth64``
(``grain_depth`` = 64: rays see grains until a path's 64th event, the size classes and the surface rule
still on), each with ``--seeds`` independent sampler seeds (the same grains), in ``--variants`` (scalar_rgb
and llvm_ad_rgb). z = (mean_a - mean_exact) / sqrt(SE_a^2 + SE_exact^2), the SEs from the seeds' spread;
rms/noise: the seeds split in two halves, RMS over pixels of (a_0 - exact_1, a_1 - exact_0) over RMS of
(exact_0 - exact_1), as ``bench_dense.py``'s (1: at noise level). Shipped scenes and the crate: ``--spp``;
the side-lit cloud: ``--sidelit-spp``. The whole default run: about 12 minutes on 2 cores.

Scene-name suffixes of the side-lit cloud: ``-h5`` (a 10 mm cube), ``-ball`` (grains in a ball held by a
sphere), ``-s4`` (cloud seed 4; default 3), ``-pad4`` (the holder 4 mm larger than the grains' box), ``-q3`` (query radius
3 mm), ``-n3000`` (3000 grains; default 300).
``--configs ...,nosurface``: ``surface_footprint`` off (rays from surfaces and cameras walk the grains; side-lit and
haze scenes). ``--rule-spp total``: the camera rule is told the comparison's samples per pixel (spp x seeds, as one
render of that many spp) instead of each render's spp; the rule is per render, and averaging many renders of few
spp brings the noise below the texture of the grains it lets camera rays see as their field.
``--clouds N``: instead, default over exact for N independent clouds and the mean over them (the part one cloud's
arrangement does not set).

    PYTHONPATH=mitsuba_plugin .venv/bin/python scripts/bench/bench_lod.py [--scenes sidelit,sidelit3mm,lamp]
        [--variants scalar_rgb,llvm_ad_rgb] [--res 32] [--spp 16] [--seeds 8] [--configs default,exact,depth64]
    ... bench_lod.py --scenes sidelit-h5 --variants scalar_rgb --clouds 16 --res 24 --spp 64 --seeds 4
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

HALF = 10.0  # mm: the side-lit cloud's half-size
SIDELIT_COUNT = 300
INF = float("inf")
MAX_DEPTH = [16]
SHIPPED = ("cornell", "lamp", "dust_box", "footprint", "limit", "bench", "staircase", "house")
CONFIGS = {"default": {}, "exact": {"continuous_count": INF}, "depth64": {"grain_depth": 64},
           "nosurface": {"surface_footprint": False},  # rays from surfaces and cameras walk the grains
           "homogeneous": None,  # the rotated crate's homogeneous original
           "exact2": {"continuous_count": INF}}  # exact again, other sampler seeds: the metric's own spread
#: Sampler seeds: 1000 + s, for exact2 2000 + s.
SEED_BASE = {"exact2": 2000}


def sidelit_particles(shape: str, count: int = SIDELIT_COUNT, seed: int = 3) -> pathlib.Path:
    """The side-lit cloud's grains in the medium's local cube [-1, 1]^3 (uniform in the cube, or in the
    ball inscribed in it), radii uniform in 200-450 um, written to a particle file."""
    import tempfile  # noqa: PLC0415

    rng = np.random.default_rng(seed)
    if shape == "ball":
        p = rng.uniform(-1, 1, (8 * count, 3))
        p = p[np.einsum("ij,ij->i", p, p) < 1][:count]
    else:
        p = rng.uniform(-1, 1, (count, 3))
    path = pathlib.Path(tempfile.gettempdir()) / f"bench_lod_{shape}_{count}_{seed}.npz"
    np.savez(path, positions=p, radii_um=rng.uniform(200.0, 450.0, count))
    return path


def sidelit(mi, res: int, query_radius: float, medium_extra: dict, shape: str = "cube", half: float = HALF,
            cloud_seed: int = 3, pad: float = 0.0, count: int = SIDELIT_COUNT) -> dict:
    T = mi.ScalarTransform4f
    medium = {"type": "discrete", "filename": str(sidelit_particles(shape, count, seed=cloud_seed)), "eta": 1.5, "scale_m": 1e-3,
              "to_world": T().scale(half), "phase": {"type": "particle"}, **medium_extra}
    if query_radius > 0:
        medium["query_radius"] = query_radius
    holder = ({"type": "sphere", "radius": half + pad} if shape == "ball"
              else {"type": "cube", "to_world": T().scale(half + pad)})
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": MAX_DEPTH[0]},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": T().look_at(origin=[0, 0, 6 * half], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "lamp": {"type": "point", "position": [-2.2 * half, 0.0, 0.0],
                 "intensity": {"type": "rgb", "value": 4.0 * half * half}},
        "cloud": {**holder, "bsdf": {"type": "null"}, "interior": medium},
    }


def xml_scene(mi, name: str, res: int, medium_extra: dict):
    """A shipped scene at resolution ``res`` with ``medium_extra`` set on its discrete media (added after
    each ``<medium type="discrete" ...>`` tag; the scene gives none of them)."""
    import re  # noqa: PLC0415

    text = (ROOT / "scenes_xml" / f"{name}.xml").read_text()
    tags = "".join(f'<{"integer" if isinstance(v, int) else "float"} name="{k}" value="{v}"/>'
                   for k, v in medium_extra.items())
    text = re.sub(r'(<medium type="discrete"[^>]*>)', lambda m: m.group(1) + tags, text)
    return mi.load_string(text, res=res)


def rotated(mi, res: int, medium_extra: dict):
    """``tests/test_dropin.py``'s rotated crate at the default scale_m (1 mm: 8e3 grains); ``medium_extra`` None:
    its ``homogeneous`` original."""
    sys.path.insert(0, str(ROOT / "tests"))
    import warnings  # noqa: PLC0415

    import test_dropin as T  # noqa: PLC0415

    xml, _, _ = T.SCENES["rotated"]
    if medium_extra is not None:
        tags = "".join(f'<{"integer" if isinstance(v, int) else "float"} name="{k}" value="{v}"/>'
                       for k, v in medium_extra.items())
        xml = T.dropin(xml, T.ROTATION + tags)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mi.load_string(xml.format(spp=1, res=res))


def haze(mi, scene: str, res: int, extra: dict):
    """The dust room (``bench_render.room``) holding a haze at the defaults but its grains (count, median radius):
    ``haze[-nCOUNT][-rRADIUS_UM]``, 3e5 glass grains of 100 um by default, whose size classes the default makes
    continuous (the continuous classes' threshold, ``continuous_count``, against the exact render)."""
    sys.path.insert(0, str(ROOT / "scripts" / "bench"))
    import bench_render as BR  # noqa: PLC0415

    parts = scene.split("-")
    count = next((int(float(x[1:])) for x in parts[1:] if x.startswith("n")), 300_000)
    radius = next((float(x[1:]) for x in parts[1:] if x.startswith("r")), 100.0)
    medium = {"type": "discrete", "count": count, "radius_median": radius, "radius_sigma_g": 1.2, "eta": 1.55,
              "eta_k": 0.0005, "scale_m": 0.01, "to_world": mi.ScalarTransform4f().scale(10), **extra}
    return mi.load_dict(BR.room(mi, medium, res, 1))


def load(mi, scene: str, res: int, extra: dict):
    if scene == "rotated":
        return rotated(mi, res, extra)
    if scene.startswith("haze"):
        return haze(mi, scene, res, extra)
    if scene.startswith("sidelit"):
        # sidelit[3mm][-ball][-hHALF][-sSEED][-padPAD][-qQUERY_RADIUS][-nCOUNT]
        parts = scene.split("-")
        half = next((float(x[1:]) for x in parts if x.startswith("h")), HALF)
        shape = "ball" if "ball" in parts else "cube"
        cloud_seed = next((int(x[1:]) for x in parts[1:] if x.startswith("s")), 3)
        pad = next((float(x[3:]) for x in parts[1:] if x.startswith("pad")), 0.0)
        query = next((float(x[1:]) for x in parts[1:] if x.startswith("q")), 3.0 if parts[0] == "sidelit3mm" else 0.0)
        count = next((int(x[1:]) for x in parts[1:] if x.startswith("n")), SIDELIT_COUNT)
        return mi.load_dict(sidelit(mi, res, query, extra, shape, half, cloud_seed, pad, count))
    return xml_scene(mi, scene, res, extra)


def renders(mi, sc, spp: int, seeds: int, base: int = 1000) -> np.ndarray:
    return np.stack([np.asarray(mi.render(sc, spp=spp, seed=base + s), dtype=np.float64).mean(axis=2)
                     for s in range(seeds)])


def compare(a: np.ndarray, e: np.ndarray) -> dict:
    """Renders ``a`` (seeds x pixels) against the exact ``e``: z of the means, RMS(difference)/noise."""
    ma, me = a.mean(axis=(1, 2)), e.mean(axis=(1, 2))
    se = math.sqrt(ma.var(ddof=1) / len(ma) + me.var(ddof=1) / len(me))
    z = (ma.mean() - me.mean()) / se if se > 0 else 0.0
    # Halves of the seeds: the exact render's noise (e0 - e1) and a's difference from it (a0 - e1, a1 - e0).
    h = len(e) // 2
    a0, a1, e0, e1 = a[:h].mean(0), a[h:2 * h].mean(0), e[:h].mean(0), e[h:2 * h].mean(0)
    noise = np.sqrt(np.mean((e0 - e1) ** 2))
    rms = np.sqrt((np.mean((a0 - e1) ** 2) + np.mean((a1 - e0) ** 2)) / 2)
    return {"mean": ma.mean(), "se": ma.std(ddof=1) / math.sqrt(len(ma)), "rel": ma.mean() / me.mean() - 1,
            "z": z, "rms": rms / noise if noise > 0 else float("nan")}


def over_clouds(args) -> None:
    """Default over exact for ``args.clouds`` independent clouds of the side-lit scene: one cloud's own
    arrangement of 300 grains (which grain shadows which) is what the continuous equivalent cannot
    carry, so one cloud's ratio scatters around the systematic part, which the mean over clouds shows."""
    import mitsuba as mi  # noqa: PLC0415
    import motes  # noqa: PLC0415

    for variant in args.variants.split(","):
        motes.set_variant(variant)
        for scene in args.scenes.split(","):
            rel = []
            for k in range(args.clouds):
                m = {c: renders(mi, load(mi, f"{scene}-s{10 + k}", args.res, CONFIGS[c]), args.spp, args.seeds).mean()
                     for c in ("default", "exact")}
                rel.append(m["default"] / m["exact"] - 1)
            rel = np.array(rel)
            print(f"{variant} {scene}: {args.clouds} clouds, {args.res} px, {args.spp} spp x {args.seeds} seeds: "
                  f"default / exact - 1 = {rel.mean():+.2%} +- {rel.std(ddof=1) / math.sqrt(len(rel)):.2%} "
                  f"(one cloud: sd {rel.std(ddof=1):.2%}, from {rel.min():+.2%} to {rel.max():+.2%})", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="sidelit,sidelit3mm,rotated," + ",".join(SHIPPED))
    ap.add_argument("--variants", default="scalar_rgb,llvm_ad_rgb")
    ap.add_argument("--configs", default="default,exact,depth64")
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--spp", type=int, default=16, help="spp of the shipped scenes and the crate (16)")
    ap.add_argument("--sidelit-spp", type=int, default=256, help="spp of the side-lit cloud (256)")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--max-depth", type=int, default=16, help="the side-lit scenes' volpath max_depth (16)")
    ap.add_argument("--clouds", type=int, default=0, help="instead: the side-lit scenes (--scenes) with this many "
                    "clouds (seeds 10, 11, ...) of 300 grains each, default over exact per cloud and their mean")
    ap.add_argument("--rule-spp", default="", help="the samples per pixel the camera rule is told: 'total' (spp x "
                    "seeds, the noise of the comparison: as one render of that many spp) or a number; default: each "
                    "render's own spp")
    args = ap.parse_args()
    MAX_DEPTH[0] = args.max_depth
    if args.rule_spp:
        import motes.plugins.cameras as cameras  # noqa: PLC0415

        told = args.spp * args.seeds if args.rule_spp == "total" else int(args.rule_spp)
        cameras.samples_per_pixel = lambda *a, **k: told
    if args.clouds:
        return over_clouds(args)
    import mitsuba as mi  # noqa: PLC0415

    configs = [c for c in args.configs.split(",") if c]
    if "exact" not in configs:
        configs.append("exact")
    for variant in args.variants.split(","):
        import motes  # noqa: PLC0415

        motes.set_variant(variant)
        for scene in args.scenes.split(","):
            t0 = time.perf_counter()
            side = scene.startswith(("sidelit", "haze"))  # every config asked for
            spp = args.sidelit_spp if scene.startswith("sidelit") else args.spp
            # The diagnostic depth64 on the side-lit cloud only (the other scenes: default and exact).
            cfgs = configs if side else (["default", "exact"] + (["homogeneous"] if scene == "rotated" else [])
                                         + (["exact2"] if "exact2" in configs else []))
            imgs = {c: renders(mi, load(mi, scene, args.res, CONFIGS[c]), spp, args.seeds, SEED_BASE.get(c, 1000))
                    for c in cfgs if CONFIGS[c] is not None or scene == "rotated"}
            print(f"{variant} {scene} ({args.res} px, {spp} spp x {args.seeds} seeds, "
                  f"{time.perf_counter() - t0:.0f} s)")
            print(f"  {'config':<9} {'mean':>11} {'SE':>10} {'rel':>8} {'z':>7} {'rms/noise':>9}")
            for c in imgs:
                r = compare(imgs[c], imgs["exact"])
                print(f"  {c:<9} {r['mean']:11.5g} {r['se']:10.3g} {r['rel']:+8.2%} {r['z']:+7.2f} {r['rms']:9.3f}",
                      flush=True)


if __name__ == "__main__":
    main()
