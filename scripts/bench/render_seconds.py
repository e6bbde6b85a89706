"""Seconds per render of one `bench_native` configuration (llvm_ad_rgb, symbolic mode): the measurement
behind this project's A/B comparisons of two builds, run alternately on this shared machine, e.g.

    for i in 1 2 3; do
      PYTHONPATH=/tmp/basepkg .venv/bin/python scripts/bench/render_seconds.py sparse   # the other build
      .venv/bin/python scripts/bench/render_seconds.py sparse                           # this checkout
    done

(`pip install --no-deps --target /tmp/basepkg <checkout of the other commit>` installs the other build.)
Prints the mean of `--renders` renders after a compiling warm-up, and the medium's ray and event counts.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _common as C  # noqa: E402
import bench_native as B  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", choices=B.KNOWN)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--renders", type=int, default=10)
    args = ap.parse_args()
    motes = C.import_motes()
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi  # noqa: PLC0415

    _, scene = B.scenes(motes, mi, args.config, args.res, args.spp)
    B.render(mi, scene, args.spp)
    t = time.perf_counter()
    for i in range(args.renders):
        B.render(mi, scene, args.spp, seed=i)
    per = (time.perf_counter() - t) / args.renders
    media = [s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None]
    stats = getattr(media[0], "stats", {}) if media else {}
    print(f"{args.config} {args.res}px {args.spp}spp: {per:.4f} s per render; rays {stats.get('rays')}, "
          f"events {stats.get('events')}")


if __name__ == "__main__":
    main()
