"""Issue 46, parent exclusion where balls overlap: a dense cloud (20 000 grains of 20 um with query radius 0.02,
reach 0.04, uniform in the unit cube [-0.5, 0.5]^3, about 5 balls holding a point) in a null cube of half-size 1,
lit by a point light to its left and a dim sky, rendered by ``kernel = drjit`` and by the native kernel exact
(``continuous_count = inf``), seeds alternating. Printed: the image means, their relative difference and its z
(difference of the means over the renders' spread), and the per-pixel RMS difference over the noise.

    .venv/bin/python scripts/bench/bench_drjit_dense.py [--seeds 32] [--res 24] [--spp 16] [--max-depth 8]
        [--exclusion origin|ball]
    .venv/bin/python scripts/bench/bench_drjit_dense.py --far

``--far``: instead, the origin tag's search (``DrJitKernel._tag_search``) on 8192 flights into the cloud from
points 2, 5, 20 and 100 units (about that many extents) from a site: the share that finds no tag (the site then
keeps its point and its rays may meet their grain again) and the shifts along the ray.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np


def dense_file(count: int = 20000, seed: int = 5) -> str:
    rng = np.random.default_rng(seed)
    path = os.path.join(tempfile.mkdtemp(), "dense.npz")
    np.savez(path, positions=rng.uniform(-0.5, 0.5, (count, 3)), radii_um=np.full(count, 20.0))
    return path


def dense_scene(mi, path: str, kernel: str, res: int, max_depth: int):
    T = mi.ScalarTransform4f
    medium = {"type": "discrete", "filename": path, "eta": 1.5, "albedo": 0.9, "scale_m": 1e-3, "query_radius": 0.02,
              "continuous_count": float("inf"), "kernel": kernel, "phase": {"type": "particle"}}
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath", "max_depth": max_depth},
        "sensor": {"type": "perspective", "fov": 20, "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "lamp": {"type": "point", "position": [-3.0, 0.5, 0.0], "intensity": {"type": "rgb", "value": 10.0}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.05}},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium}})


def far(mi, path: str) -> None:
    import drjit as dr  # noqa: PLC0415

    from motes.drjit_walk import grain_tag, origin_tag  # noqa: PLC0415

    med = mi.load_dict({"type": "discrete", "filename": path, "eta": 1.5, "scale_m": 1e-3, "query_radius": 0.02,
                        "continuous_count": float("inf"), "kernel": "drjit", "phase": {"type": "particle"}})
    k = med._drjit.ready()
    rng = np.random.default_rng(1)
    m = 8192
    for dist in (2.0, 5.0, 20.0, 100.0):
        v = rng.normal(size=(m, 3))
        v /= np.linalg.norm(v, axis=1)[:, None]
        org = (rng.uniform(-0.4, 0.4, (m, 3)) - dist * v).astype(np.float32)
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(org[:, a]) for a in range(3)]),
                       mi.Vector3f(*[mi.Float(v[:, a].astype(np.float32)) for a in range(3)]))
        valid, mint, _ = k.intersect_aabb(ray)
        t, _, _, g = k.grid.sample_free_flight(ray.o, ray.d, ray.maxt, k._ray_seed(ray), exclude_origin=True,
                                               want_index=False, origin_tag=origin_tag(ray.o.x, ray.o.y, ray.o.z),
                                               slack=2 * k._shift_max(k._largest(ray.o)), want_grain=True)
        p = dr.fma(ray.d, mint, ray.o)
        ok = np.asarray(valid)
        miss = (np.asarray(origin_tag(p.x, p.y, p.z)) != np.asarray(grain_tag(g)))[ok]
        shift = np.abs(np.asarray(mint)[ok] - np.asarray(t)[ok])
        print(f"flights from {dist:5.0f} units: {ok.sum()} sites, no tag found {miss.mean():.5f}, shift median "
              f"{np.median(shift):.2e}, largest {shift.max():.2e} (extent {k.extent:.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--res", type=int, default=24)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--exclusion", choices=("origin", "ball"), default="origin")
    ap.add_argument("--far", action="store_true", help="the tag search's failures from far origins")
    args = ap.parse_args()
    import motes  # noqa: PLC0415

    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi  # noqa: PLC0415

    from motes.plugins import drjit_medium  # noqa: PLC0415

    drjit_medium.EXCLUSION = args.exclusion
    path = dense_file()
    if args.far:
        far(mi, path)
        return
    scenes = {k: dense_scene(mi, path, k, args.res, args.max_depth) for k in ("drjit", "native")}
    imgs = {k: [] for k in scenes}
    t0 = time.time()
    for s in range(args.seeds):
        for i, (k, sc) in enumerate(scenes.items()):
            imgs[k].append(np.asarray(mi.render(sc, spp=args.spp, seed=1000 * i + s), dtype=np.float64))
    a, b = np.stack(imgs["drjit"]), np.stack(imgs["native"])
    ma, mb = a.mean(axis=(1, 2, 3)), b.mean(axis=(1, 2, 3))
    z = (ma.mean() - mb.mean()) / np.hypot(ma.std(ddof=1), mb.std(ddof=1)) * np.sqrt(len(ma))
    noise = a.var(axis=0, ddof=1) / a.shape[0] + b.var(axis=0, ddof=1) / b.shape[0]
    rms = float(np.sqrt(np.mean((a.mean(0) - b.mean(0)) ** 2) / np.mean(noise)))
    print(f"dense cloud, exclusion {args.exclusion}, {args.seeds} seeds, {args.res} px, {args.spp} spp, depth "
          f"{args.max_depth}: drjit {ma.mean():.6f}, native exact {mb.mean():.6f}, "
          f"{100 * (ma.mean() / mb.mean() - 1):+.3f} %, z {z:+.2f}, RMS/noise {rms:.2f} ({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
