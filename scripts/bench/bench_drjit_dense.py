"""Issue 46, parent exclusion where balls overlap: a dense cloud (20 000 grains of 20 um with query radius 0.02,
reach 0.04, uniform in the unit cube [-0.5, 0.5]^3, about 5 balls holding a point) in a null cube of half-size 1,
lit by a point light to its left and a dim sky, rendered by ``kernel = drjit`` and by the native kernel exact
(``continuous_count = inf``), seeds alternating. Printed: the image means, their relative difference and its z
(difference of the means over the renders' spread), and the per-pixel RMS difference over the noise.

    .venv/bin/python scripts/bench/bench_drjit_dense.py [--seeds 32] [--res 24] [--spp 16] [--max-depth 8]
        [--exclusion origin|ball] [--camera-distance 5]
    .venv/bin/python scripts/bench/bench_drjit_dense.py --far

``--camera-distance``: the camera that far from the cloud on the z axis (5 by default), its field of view
narrowed so that the cloud fills the frame as from 5 (20 degrees there), and the null cube holding the medium
grown to half-size ``camera-distance`` - 4 (at least 1, the default's): camera rays enter the medium that far
from the cloud, so first events come from flights of about that length, where the origin tag's search steps by
t's ulp (the lamp, at 3 units, is then inside the medium).

``--far``: instead, the origin tag's search (``DrJitKernel._tag_search``) on 8192 flights into the cloud from
points 2, 5, 20 and 100 units (about that many extents) from a site: the share that finds no tag inside its
grain's ball (the site then keeps its point and its rays may meet their grain again), the shifts along the ray
(in scene units and in the search's steps), and the phase function's site search from the shifted site alone
(``mei.t`` = t*): the share where it finds no grain and the mean number of members (1 but for coincident grains
and grains of the site's tag that pass within the search's largest shift).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np


def dense_file(count: int = 20000, seed: int = 5, offset: float = 0.0) -> str:
    rng = np.random.default_rng(seed)
    path = os.path.join(tempfile.mkdtemp(), "dense.npz")
    np.savez(path, positions=rng.uniform(-0.5, 0.5, (count, 3)) + np.array([offset, 0.0, 0.0]),
             radii_um=np.full(count, 20.0))
    return path


def dense_scene(mi, path: str, kernel: str, res: int, max_depth: int, camera_distance: float = 5.0,
                offset: float = 0.0, sky: float = 0.05):
    """The dense cloud's scene, its camera ``camera_distance`` from the cloud's centre on the z axis, its field of
    view narrowed so that the frame spans what 20 degrees span from 5 units (the cloud fills it), and the null
    cube that bounds the medium grown to reach within 4 units of the camera: camera rays enter the medium there
    and fly to the cloud from that far (a cube of half-size 1 would start them 1-2 units from it). ``offset``: the
    whole scene (grains, cube, camera, lamp) moved that far along x (the grains' file must be moved alike)."""
    T = mi.ScalarTransform4f
    x0 = float(offset)
    half = max(1.0, camera_distance - 4.0)
    fov = 2 * np.degrees(np.arctan(5 * np.tan(np.radians(10)) / camera_distance))
    medium = {"type": "discrete", "filename": path, "eta": 1.5, "albedo": 0.9, "scale_m": 1e-3, "query_radius": 0.02,
              "continuous_count": float("inf"), "kernel": kernel, "phase": {"type": "particle"}}
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath", "max_depth": max_depth},
        "sensor": {"type": "perspective", "fov": float(fov),
                   "to_world": T().look_at(origin=[x0, 0, camera_distance], target=[x0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "lamp": {"type": "point", "position": [x0 - 3.0, 0.5, 0.0], "intensity": {"type": "rgb", "value": 10.0}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": float(sky)}},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                 "to_world": T().translate([x0, 0, 0]) @ T().scale(half)}})


def far(mi, path: str, offset: float = 0.0) -> None:
    import drjit as dr  # noqa: PLC0415

    from motes.drjit_walk import grain_hash, origin_hash, point_exponent, tag_bits, tags_agree  # noqa: PLC0415

    med = mi.load_dict({"type": "discrete", "filename": path, "eta": 1.5, "scale_m": 1e-3, "query_radius": 0.02,
                        "continuous_count": float("inf"), "kernel": "drjit", "phase": {"type": "particle"}})
    k = med._drjit.ready()
    rng = np.random.default_rng(1)
    m = 8192
    for dist in (2.0, 5.0, 20.0, 100.0):
        v = rng.normal(size=(m, 3))
        v /= np.linalg.norm(v, axis=1)[:, None]
        org = (rng.uniform(-0.4, 0.4, (m, 3)) - dist * v + np.array([offset, 0.0, 0.0])).astype(np.float32)
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(org[:, a]) for a in range(3)]),
                       mi.Vector3f(*[mi.Float(v[:, a].astype(np.float32)) for a in range(3)]))
        valid, mint, _ = k.intersect_aabb(ray)
        # The same flight before its tag search (same seed, same walk): its t, grain and ball.
        t, _, _, g, (centre, radius) = k.grid.sample_free_flight(
            ray.o, ray.d, ray.maxt, k._ray_seed(ray), exclude_origin=True, want_index=False,
            tagged=True, want_grain=True, want_ball=True)
        p = dr.fma(ray.d, mint, ray.o)
        # The phase function's site search from the site alone (p, its ray, mei.t = t*): members found.
        _, members, _ = k._site(p, ray.d, k._waves(None), active=valid, t=mint)
        step = k._tag_step(t, k._largest(dr.fma(ray.d, t, ray.o)), k._largest(ray.d))
        dr.eval(valid, mint, t, g, centre, radius, members, step)
        ok = np.asarray(valid)
        c = np.array([np.asarray(centre[a]) for a in range(3)])[:, ok]
        q = np.array([np.asarray(p[a]) for a in range(3)])[:, ok]
        inside = np.sum((q - c) ** 2, axis=0) < np.asarray(radius)[ok] ** 2
        m_p = point_exponent(p.x, p.y, p.z)
        agree = tags_agree(origin_hash(p.x, p.y, p.z), grain_hash(g), radius, m_p, k.grid.tag_thresholds)
        bits = np.asarray(tag_bits(radius, m_p, k.grid.tag_thresholds))[ok]
        miss = ~np.asarray(agree)[ok] | ~inside
        shift = np.abs(np.asarray(mint)[ok] - np.asarray(t)[ok])
        steps = shift / np.asarray(step)[ok]
        found = np.asarray(members)[ok]
        print(f"flights from {dist:5.0f} units: {ok.sum()} sites, tag bits {np.median(bits):.0f} (median), no tag "
              f"found {miss.mean():.5f} (balls holding a point {k.grid.holders:.2f}); shift median "
              f"{np.median(shift):.2e}, largest {shift.max():.2e} ({np.median(steps):.0f} and {steps.max():.0f} "
              f"steps of {np.median(np.asarray(step)[ok]):.1e}); site search: none found {np.mean(found == 0):.5f}, "
              f"members {found.mean():.4f} (extent {k.extent:.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--res", type=int, default=24)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--exclusion", choices=("origin", "ball"), default="origin")
    ap.add_argument("--far", action="store_true", help="the tag search's failures from far origins")
    ap.add_argument("--camera-distance", type=float, default=5.0,
                    help="the camera's distance from the cloud (its field of view narrowed to keep the frame)")
    ap.add_argument("--sky", type=float, default=0.05, help="the sky's radiance (0: the lamp's scattered light alone)")
    ap.add_argument("--count", type=int, default=20000,
                    help="grains in the unit cube (20 000: about 5 balls hold a point)")
    ap.add_argument("--offset", type=float, default=0.0,
                    help="the whole scene moved this far along x: the grains' R over their coordinates shrinks")
    args = ap.parse_args()
    import motes  # noqa: PLC0415

    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi  # noqa: PLC0415

    from motes.plugins import drjit_medium  # noqa: PLC0415

    drjit_medium.EXCLUSION = args.exclusion
    path = dense_file(args.count, offset=args.offset)
    if args.far:
        far(mi, path, args.offset)
        return
    scenes = {k: dense_scene(mi, path, k, args.res, args.max_depth, args.camera_distance,
                                 args.offset, args.sky) for k in ("drjit", "native")}
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
    print(f"cloud of {args.count} grains, exclusion {args.exclusion}, camera at {args.camera_distance:g}, "
          f"offset {args.offset:g}, sky {args.sky:g}, {args.seeds} seeds, "
          f"{args.res} px, {args.spp} spp, depth {args.max_depth}: drjit {ma.mean():.6f}, native exact "
          f"{mb.mean():.6f}, {100 * (ma.mean() / mb.mean() - 1):+.3f} %, z {z:+.2f}, RMS/noise {rms:.2f} "
          f"({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
