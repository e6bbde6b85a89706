"""What the exact skips for ``volpath`` / ``volpathmis`` save (``motes/plugins/enclosure.py``, issue 25): a shipped scene
rendered with them (the default) and without them (the integrator not recognised: no enclosure, no ray clipping),
alternating in one process, and whether the images are the same (they must be: both skips are exact).

    .venv/bin/python scripts/bench/bench_skips.py [--scene cornell] [--variant llvm_ad_rgb] [--reps 4]
        [--set count=300000 --set radius=2000] [--res 96] [--spp 16]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
import numpy as np  # noqa: E402

import _paper as P  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--reps", type=int, default=4)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="scene parameter")
    args = ap.parse_args()
    mi = P.setup(args.variant)
    import motes.plugins.enclosure as E

    overrides = dict(kv.split("=", 1) for kv in args.set)
    scene = mi.load_file(str(P.scene_file(args.scene)), res=str(args.res), spp=str(args.spp), **overrides)
    media = [s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None]
    skipping = E.SKIPPING_INTEGRATORS
    mi.render(scene, spp=args.spp, seed=99)  # warm-up (kernel compile)
    times: dict[bool, list[float]] = {True: [], False: []}
    images: dict[bool, np.ndarray] = {}
    for _ in range(args.reps):
        for on in (True, False):
            E.SKIPPING_INTEGRATORS = skipping if on else ()
            t = time.perf_counter()
            img = np.asarray(mi.render(scene, spp=args.spp, seed=7))
            times[on].append(time.perf_counter() - t)
            images.setdefault(on, img)
            if on:
                regions = [m.data.enclosure_regions for m in media]
    E.SKIPPING_INTEGRATORS = skipping
    on, off = np.median(times[True]), np.median(times[False])
    same = np.array_equal(images[True], images[False])
    rel = float(np.abs(images[True] - images[False]).max() / max(np.abs(images[False]).max(), 1e-30))
    label = f"{args.scene} {' '.join(args.set)} {args.variant} {args.res}px {args.spp}spp"
    print(f"[{label}] regions {regions}: with the skips {on:.3f} s, without {off:.3f} s per render (median of "
          f"{args.reps}), ratio {on / off:.3f}; images {'identical' if same else f'differ (max rel {rel:.2g})'}")


if __name__ == "__main__":
    main()
