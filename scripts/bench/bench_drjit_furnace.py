"""Issue 46: the white furnace of ``kernel = "drjit"`` in each LLVM variant family: non-absorbing grains (albedo 1)
in a null-bounded cube under a constant white sky, Russian roulette off (``rr_depth`` 10^5, ``max_depth`` -1), so
every path's weight stays near 1 and a loss of energy shows as a mean below 1. Printed per variant: the image
mean over its pixels and ``--seeds`` renders (seeds 1, 2, ...), its standard error (pixels as independent
estimates) and z = (mean - 1) / SE.

    .venv/bin/python scripts/bench/bench_drjit_furnace.py [--variants llvm_ad_rgb,llvm_ad_spectral,...]
        [--res 32] [--spp 64] [--count 20000] [--seeds 1] [--storage procedural] [--continuous-count 16]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def furnace(mi, res: int, spp: int, count: int, kernel: str = "drjit", medium_extra: dict | None = None):
    """The furnace scene (as ``tests/test_drjit_medium.py``'s, larger); ``medium_extra`` set on its medium."""
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 100000},
        "sensor": {"type": "perspective", "fov": 28, "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "cube": {"type": "cube", "bsdf": {"type": "null"},
                 "interior": {"type": "discrete", "count": count, "radius_median": 20.0, "scale_m": 1e-3,
                              "query_radius": 0.02, "albedo": 1.0, "kernel": kernel, "size_bins": 4,
                              "phase": {"type": "particle"}, **(medium_extra or {})}}})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", default="llvm_ad_rgb,llvm_ad_mono,llvm_ad_spectral,llvm_ad_mono_polarized,"
                                          "llvm_ad_spectral_polarized")
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--count", type=int, default=20000)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--storage", default=None, help="the medium's storage (procedural: regenerated grains)")
    ap.add_argument("--continuous-count", type=float, default=None,
                    help="the medium's continuous_count (the size classes rendered as their field)")
    args = ap.parse_args()
    import motes  # noqa: PLC0415

    print(f"white furnace, kernel = drjit, {args.count} grains, {args.res} px, {args.spp} spp, {args.seeds} seed(s), "
          "roulette off")
    print(f"{'variant':28s} {'mean':>8s} {'SE':>8s} {'z':>6s} {'s':>6s}")
    for variant in args.variants.split(","):
        motes.set_variant(variant)
        import mitsuba as mi  # noqa: PLC0415

        extra = {} if args.storage is None else {"storage": args.storage}
        if args.continuous_count is not None:
            extra["continuous_count"] = args.continuous_count
        sc = furnace(mi, args.res, args.spp, args.count, medium_extra=extra)
        medium = next(sh.interior_medium() for sh in sc.shapes() if sh.interior_medium() is not None)
        print(f"{variant}: {medium.data.continuous_particles} of {len(medium.data.core)} grains continuous", flush=True)
        t0 = time.perf_counter()
        imgs = [np.asarray(mi.render(sc, spp=args.spp, seed=1 + s), dtype=np.float64) for s in range(args.seeds)]
        secs = (time.perf_counter() - t0) / args.seeds
        # polarised variants: mi.render returns S0
        pix = np.concatenate([img.reshape(args.res * args.res, -1).mean(axis=1) for img in imgs])
        m, se = pix.mean(), pix.std(ddof=1) / np.sqrt(pix.size)
        print(f"{variant:28s} {m:8.5f} {se:8.5f} {(m - 1) / se:6.2f} {secs:6.1f}", flush=True)


if __name__ == "__main__":
    main()
