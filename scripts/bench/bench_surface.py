"""Issue 25: the surface-ray rule (``surface_footprint``, ``rust/motes-core/src/render/footprint.rs``) on the
shipped scenes, as a user renders them: each scene loaded once, rendered with the rule on (the default) and
off (``set_surface_footprint(False)`` on the same medium: same particles, same seeds), interleaved.

Reported per scene: seconds per render with the rule on over off (best of the seeds' renders after a
warm-up), the share of rays starting at no event that saw the grains' continuous equivalent, the image means'
difference in standard errors (SE from the seed-to-seed spread of each side's image means), and the per-pixel
RMS difference over the renders' own seed-to-seed RMS difference (1 = at noise level) on all pixels and on
the lit ones (above twice the median): where the grains' shadows on walls and floors would show.

    .venv/bin/python scripts/bench/bench_surface.py [--scenes dust_box,lamp,...] [--res 96] [--spp 16] [--seeds 4]
        [--set count=300000]   (a scene's XML defaults overridden)
"""

from __future__ import annotations

import argparse  # noqa: F401 (the annotation of scene_parser)
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import _paper as P  # noqa: E402

SCENES = ("dust_box", "lamp", "cornell", "bench", "footprint", "staircase")
#: `--set name=value`: the scenes' XML defaults replaced.
OVERRIDES: dict[str, str] = {}


def pair_stats(on: list, off: list) -> dict:
    """Rule on against off: per-seed luminance images, as many seeds on each side (at least 2)."""
    a, b = np.asarray(on), np.asarray(off)
    k = len(a)
    ma, mb = a.mean(axis=(1, 2)), b.mean(axis=(1, 2))
    se = np.sqrt(ma.var(ddof=1) / k + mb.var(ddof=1) / k)
    diff = ma.mean() - mb.mean()
    lit = b.mean(axis=0) > 2 * np.median(b.mean(axis=0))

    def rms_over_noise(mask):
        # Independent seeds on both sides of every difference: on_i - off_{i+1} against off_i - off_{i+1}.
        d_pair = np.mean([np.mean((a[i] - b[(i + 1) % k])[mask] ** 2) for i in range(k)])
        d_noise = np.mean([np.mean((b[i] - b[(i + 1) % k])[mask] ** 2) for i in range(k)])
        return float(np.sqrt(d_pair / d_noise))

    return {"rel_diff": float(diff / mb.mean()), "diff_se": float(diff / se) if se > 0 else 0.0,
            "rms_over_noise": rms_over_noise(np.ones_like(lit)),
            "rms_over_noise_lit": rms_over_noise(lit) if lit.any() else float("nan")}


def run_scene(mi, name: str, res: int, spp: int, seeds: int) -> dict:
    scene = mi.load_file(str(P.scene_file(name)), **OVERRIDES, spp=str(spp), res=str(res))
    core = P.discrete_medium_of(scene).data.core
    mi.render(scene, spp=spp, seed=999)  # compiles the kernels
    imgs, best = {True: [], False: []}, {True: np.inf, False: np.inf}
    counts = (0, 0)
    for s in range(seeds):
        for on in (True, False):
            core.set_surface_footprint(on)
            before = core.surface_counts
            t = time.perf_counter()
            img = np.asarray(mi.render(scene, spp=spp, seed=s), dtype=np.float64)[..., :3]
            best[on] = min(best[on], time.perf_counter() - t)
            imgs[on].append(P.luminance(img))
            if on:
                after = core.surface_counts
                counts = (counts[0] + after[0] - before[0], counts[1] + after[1] - before[1])
    core.set_surface_footprint(True)
    row = {"scene": name, "res": res, "spp": spp, "seeds": seeds, "seconds_on": best[True],
           "seconds_off": best[False], "speed_ratio": best[True] / best[False],
           "field_share": counts[1] / max(counts[0], 1), **pair_stats(imgs[True], imgs[False])}
    print(f"[{name}] on/off {row['speed_ratio']:.2f} ({best[True]:.2f} / {best[False]:.2f} s), field "
          f"{row['field_share']:.0%} of rays from no event, mean {row['rel_diff']:+.2%} ({row['diff_se']:+.1f} SE), "
          f"rms/noise {row['rms_over_noise']:.2f} lit {row['rms_over_noise_lit']:.2f}", flush=True)
    return row


def scene_parser(doc: str, scenes) -> "argparse.ArgumentParser":
    """The arguments of the shipped-scene benchmarks (this one and ``bench_gallery.py``)."""
    ap = C.parser(doc)
    ap.add_argument("--scenes", default=",".join(scenes), help="comma-separated shipped scenes")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=16)
    return ap


def add_overrides(ap: "argparse.ArgumentParser") -> None:
    """``--set NAME=VALUE`` (repeatable): a scene default replaced (see ``read_overrides``)."""
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="replace a scene default (e.g. count=300000), in the discrete scene and any twin")


def read_overrides(args, into: dict) -> None:
    """The ``--set`` items of ``args`` into ``into`` (name -> value)."""
    for item in args.set:
        k, _, v = item.partition("=")
        if not k or not v:
            raise SystemExit(f"--set {item!r}: expected NAME=VALUE")
        into[k] = v


def start(doc: str, scenes, seeds: int):
    """The common start of the on-against-off benchmarks (this one and ``bench_penumbra.py``): the scene
    arguments, ``--seeds`` (default ``seeds``) and ``--set`` (read into ``OVERRIDES``). Returns (parsed
    arguments, scene names, seeds to run (at least 2; 2 with ``--quick``), output folder, stopwatch, ``mitsuba``)."""
    ap = scene_parser(doc, scenes)
    ap.add_argument("--seeds", type=int, default=seeds)
    add_overrides(ap)
    args = ap.parse_args()
    read_overrides(args, OVERRIDES)
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    seeds = 2 if args.quick else max(2, args.seeds)
    return args, names, seeds, C.out_dir(args.out), C.Stopwatch(), P.setup(args.variant)


def report(args, seeds: int, rows: list, what: str, columns: dict, sw, path: pathlib.Path) -> None:
    """The on-against-off table (scene, time on/off, the ``columns``: title -> cell of a row, RMS/noise on all
    pixels and the lit ones) printed, and the rows written to ``path`` with the run's provenance."""
    C.print_table(f"{args.variant}, {args.res}x{args.res}, {args.spp} spp, {seeds} seeds: {what}",
                  ["scene", "time on/off", *columns, "RMS/noise all; lit"],
                  [[r["scene"], f"{r['speed_ratio']:.2f}", *(cell(r) for cell in columns.values()),
                    f"{r['rms_over_noise']:.2f}; {r['rms_over_noise_lit']:.2f}"] for r in rows])
    C.finish(args, sw, path, rows=rows)


def main() -> None:
    args, names, seeds, out, sw, mi = start(__doc__, SCENES, seeds=4)
    rows = [run_scene(mi, n, args.res, args.spp, seeds) for n in names]
    report(args, seeds, rows, "surface rule on against off",
           {"rays seeing the field": lambda r: f"{r['field_share']:.0%}",
            "mean diff (SE)": lambda r: f"{r['rel_diff']:+.2%} ({r['diff_se']:+.1f})"},
           sw, out / f"bench_surface_{args.variant}.json")


if __name__ == "__main__":
    main()
