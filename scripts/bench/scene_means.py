"""Image means of shipped scenes over sampler seeds, with their standard error: the check that a change meant
to be exact in distribution (a faster pick, a cache) leaves the images alone. Run it on two commits (each with
its own build) and compare the means within their SEs; each render is also timed (after a warm-up render).

    .venv/bin/python scripts/bench/scene_means.py [--scenes staircase,house,limit] [--seeds 16] [--res 96] [--spp 16]
"""

from __future__ import annotations

import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import _paper as P  # noqa: E402
import bench_surface  # noqa: E402


def main() -> None:
    ap = bench_surface.scene_parser(__doc__, ("staircase", "house", "limit"))
    ap.add_argument("--seeds", type=int, default=16)
    bench_surface.add_overrides(ap)
    args = ap.parse_args()
    overrides: dict[str, str] = {}
    bench_surface.read_overrides(args, overrides)
    seeds = 2 if args.quick else max(2, args.seeds)
    out, sw = C.out_dir(args.out), C.Stopwatch()
    mi = P.setup(args.variant)
    rows = []
    for name in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        scene = mi.load_file(str(P.scene_file(name)), **overrides, spp=str(args.spp), res=str(args.res))
        mi.render(scene, spp=args.spp, seed=999)  # compiles the kernels
        means, times = [], []
        for s in range(seeds):
            t = time.perf_counter()
            img = np.asarray(mi.render(scene, spp=args.spp, seed=100 + s), dtype=np.float64)[..., :3]
            times.append(time.perf_counter() - t)
            means.append(float(P.luminance(img).mean()))
        row = {"scene": name, "mean": float(np.mean(means)), "se": float(np.std(means, ddof=1) / np.sqrt(seeds)),
               "seconds_median": float(np.median(times)), "seeds": seeds}
        print(f"[{name}] mean {row['mean']:.7g} +- {row['se']:.2g} ({seeds} seeds), "
              f"{row['seconds_median']:.3f} s per render (median)", flush=True)
        rows.append(row)
    C.print_table(f"{args.variant}, {args.res}x{args.res}, {args.spp} spp, {seeds} seeds", ["scene", "mean", "SE", "s/render"],
                  [[r["scene"], f"{r['mean']:.7g}", f"{r['se']:.2g}", f"{r['seconds_median']:.3f}"] for r in rows])
    C.finish(args, sw, out / f"scene_means_{args.variant}.json", rows=rows)


if __name__ == "__main__":
    main()
