"""Issue 43.6: the automatic level of detail for camera rays. A procedural cloud of 10^12 grains (radius
0.5 mm, glass, a 200 m cube: 1.25e5 grains per m^3, every size class discrete at the defaults) under a sun
and a sky, seen from 430 m (fov 37: a pixel covers ~4.5 m of cloud) and from 5 m inside it (16 px, 64 spp: there the camera rays walk the grains). Each row is a
fresh process at the defaults (nothing about the camera given: the medium reads the scene's sensor and the
render's spp): load time, render time, peak memory (VmHWM, the whole process), and the share of rays from no
event that saw the continuous equivalent (camera rays among them). ``--off`` adds the same scene with
``surface_footprint`` false (every camera ray walks the grains, as before the rule) at a small size, to show
what the rule saves.

    .venv/bin/python scripts/bench/bench_camera_lod.py [--variant llvm_ad_rgb] [--res 64] [--spp 4] [--off]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import _common as C  # noqa: E402

HALF = 100.0  # m: the cube's half-size


def scene(mi, count: float, res: int, spp: int, origin, target, footprint: bool) -> dict:
    T = mi.ScalarTransform4f
    medium = {"type": "discrete", "count": float(count), "radius_median": 500.0, "radius_sigma_g": 1.2, "eta": 1.5,
              "scale_m": 1.0, "storage": "procedural", "to_world": T().scale(HALF), "surface_footprint": footprint}
    sensor = {"type": "perspective", "fov": 37, "to_world": T().look_at(origin=origin, target=target, up=[0, 1, 0]),
              "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
              "sampler": {"type": "independent", "sample_count": spp}}
    if max(abs(x) for x in origin) < HALF:  # a camera inside the cloud sees it from its first ray on
        sensor["medium"] = {"type": "ref", "id": "grains"}
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": 8},
        "grains": medium,
        "sensor": sensor,
        "sun": {"type": "directional", "direction": [0.4, -0.7, -0.5], "irradiance": {"type": "rgb", "value": [9, 8.5, 7.5]}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.05, 0.06, 0.08]}},
        "cloud": {"type": "cube", "to_world": T().scale(HALF), "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "grains"}},
    }


VIEWS = {"afar": ([0.0, 0.0, HALF + 430.0], [0.0, 0.0, 0.0]), "inside": ([0.0, 0.0, HALF - 5.0], [0.0, 0.0, 0.0])}


def child(variant: str, count: float, res: int, spp: int, view: str, footprint: bool) -> dict:
    import numpy as np  # noqa: PLC0415

    motes = C.import_motes()
    motes.set_variant(variant)
    import mitsuba as mi  # noqa: PLC0415

    from motes import _memory  # noqa: PLC0415
    from motes.plugins.cameras import discrete_media  # noqa: PLC0415

    t0 = time.perf_counter()
    sc = mi.load_dict(scene(mi, count, res, spp, *VIEWS[view], footprint))
    load = time.perf_counter() - t0
    t0 = time.perf_counter()
    img = np.asarray(mi.render(sc, spp=spp), dtype=np.float64)
    render = time.perf_counter() - t0
    (data,) = discrete_media(sc)
    checked, saw = data.core.surface_counts
    row = {"view": view, "footprint": footprint, "res": res, "spp": spp, "load_s": round(load, 2),
           "render_s": round(render, 2), "peak_gb": round(_memory.peak_resident_mb() / 1e3, 2),
           "mean": float(img.mean()), "finite": bool(np.isfinite(img).all()),
           "saw_field": round(saw / max(checked, 1), 3)}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--count", type=float, default=1e12)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--off", action="store_true", help="also the rule off, at 8 px and 1 spp")
    ap.add_argument("--out", default="out", help="unused (run_benchmarks.sh passes it); results are printed")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(**json.loads(a.child))))
        return
    runs = [dict(view="afar", footprint=True, res=a.res, spp=a.spp), dict(view="inside", footprint=True, res=16, spp=64)]
    if a.off:
        runs += [dict(view="afar", footprint=False, res=8, spp=1), dict(view="afar", footprint=True, res=8, spp=1)]
    print(f"{a.variant}, {a.count:g} grains (procedural), defaults; each row a fresh process")
    for r in runs:
        arg = json.dumps(dict(variant=a.variant, count=a.count, **r))
        out = subprocess.run([sys.executable, __file__, "--child", arg], capture_output=True, text=True, timeout=3600)
        if out.returncode != 0:
            print(f"{r}: failed\n{out.stderr[-2000:]}")
            continue
        print(json.dumps(json.loads(out.stdout.strip().splitlines()[-1])))


if __name__ == "__main__":
    main()
