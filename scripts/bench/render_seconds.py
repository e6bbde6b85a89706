"""Seconds per render of one `bench_native` configuration, or of the discrete medium in one of
`ept_time_to_error`'s scenes (`lamp`, `cornell`: 80 px, its default grains), in llvm_ad_rgb's symbolic
mode: the measurement behind this project's A/B comparisons of two builds, run alternately on this
shared machine, e.g.

    for i in 1 2 3; do
      PYTHONPATH=/tmp/basepkg .venv/bin/python scripts/bench/render_seconds.py sparse   # the other build
      .venv/bin/python scripts/bench/render_seconds.py sparse                           # this checkout
    done

(`pip install --no-deps --target /tmp/basepkg <checkout of the other commit>` installs the other build.)
Or a shipped scene at its defaults with some replaced, in either RGB variant (96 px, 16 spp):

    .venv/bin/python scripts/bench/render_seconds.py --scene cornell --set count=1000000 --set radius=2000 \
        --variant scalar_rgb --renders 5

Prints the mean of `--renders` renders after a compiling warm-up (and per sample per pixel), and the
medium's ray and event counts. Under `perf record -e cpu-clock` it shows where a render's time goes.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))

import _common as C  # noqa: E402
import bench_native as B  # noqa: E402
import bench_surface as BS  # noqa: E402


EPT_SCENES = ("lamp", "cornell")


def ept_scene(mi, name: str, res: int):
    """The discrete-medium scene of ``ept_time_to_error`` (its grains, seed 0), and the temporary folder
    holding the particle file (keep it alive while the scene is)."""
    import tempfile  # noqa: PLC0415

    import bench_ept as BE  # noqa: PLC0415
    import ept_time_to_error as E  # noqa: PLC0415

    pos, r_um = E.make_scene_particles(name, E.SCENES[name]["count"], 0)
    tmp = tempfile.TemporaryDirectory()
    fname = BE.save_particle_file(pathlib.Path(tmp.name) / "grains.npz", pos, r_um)
    return mi.load_dict(E.scene_dict(mi, name, res=res, filename=fname)), tmp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", nargs="?", choices=(*B.KNOWN, *EPT_SCENES))
    ap.add_argument("--scene", help="a shipped scene (`motes scenes`) instead of a configuration")
    BS.add_overrides(ap)
    ap.add_argument("--variant", default="llvm_ad_rgb", help="llvm_ad_rgb, or scalar_rgb with --scene")
    ap.add_argument("--res", type=int, default=None, help="film width (default 128; EPT scenes 80; --scene 96)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--renders", type=int, default=10)
    args = ap.parse_args()
    if (args.config is None) == (args.scene is None):
        ap.error("give a configuration or --scene, not both")
    if args.variant != "llvm_ad_rgb" and args.scene is None:
        ap.error("--variant: the configurations render in llvm_ad_rgb only")
    motes = C.import_motes()
    motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415

    if args.scene is not None:
        import _paper as P  # noqa: PLC0415

        overrides: dict[str, str] = {}
        BS.read_overrides(args, overrides)
        args.res = args.res or 96
        args.config = args.scene + "".join(f" {k}={v}" for k, v in overrides.items())
        scene = mi.load_file(str(P.scene_file(args.scene)), **overrides, spp=str(args.spp), res=str(args.res))
    elif args.config in EPT_SCENES:
        args.res = args.res or 80
        scene, keep = ept_scene(mi, args.config, args.res)
    else:
        args.res = args.res or 128
        _, scene = B.scenes(motes, mi, args.config, args.res, args.spp)
    B.render(mi, scene, args.spp)
    t = time.perf_counter()
    for i in range(args.renders):
        B.render(mi, scene, args.spp, seed=i)
    per = (time.perf_counter() - t) / args.renders
    media = [s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None]
    stats = getattr(media[0], "stats", {}) if media else {}
    print(f"{args.config} {args.res}px {args.spp}spp: {per:.4f} s per render ({1e3 * per / args.spp:.2f} ms per spp); "
          f"rays {stats.get('rays')}, "
          f"events {stats.get('events')}")


if __name__ == "__main__":
    main()
