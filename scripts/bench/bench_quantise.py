"""Issue 24.2: compact storage's quantised slots against spheres, side by side in one process.

A sparse class's slots are quantised under compact storage (``rust/motes-core/src/space/grid/mod.rs``,
"Quantised slots"); ``MOTES_QUANTISE=0`` at load keeps them as f32 spheres with per-slot τ (the layout
before, for this comparison only). Each scene is loaded both ways, rendered alternately ``--reps`` times after a
warm-up (this machine is shared: the best of each is compared), with the same sampler seeds:

* ``cornell``, ``dust_box``: the shipped scenes at ``--res`` (their defaults otherwise);
* ``4e5``, ``1.6e6``: ``bench_dense.py``'s cube of 80 µm grains in the spot-lit room.

Prints seconds per render, their ratio, the image means (sampler seeds 0.. ``--reps``) and the medium's
bytes per particle.

    .venv/bin/python scripts/bench/bench_quantise.py [--variant scalar_rgb] [--scenes cornell,4e5] [--reps 4]

``--switch MOTES_CENTRE_CELLS`` compares compact storage's centre cells (every class stored once, by its
centres' cells, eight bytes a particle) against the sparse classes' overlap slots (``=0``) instead.

``--switch MOTES_UNIFORM_MAJORANT`` (issue 25) compares continuous fields of even density sampled against one
majorant for all their cells with their blocks' majorants (``=0``); ``--switch MOTES_BEAM`` a packet's rays
from no event walked as beams where they make one with every ray walked alone (``=0``; the same sites, so the
same images). Scenes: any shipped scene, ``bench_dense.py``'s rows and ``haze`` (``bench_native.py``'s dense
haze); the image means come with their standard errors over the ``--reps`` seeds and their difference in
standard errors.

``--furnace ROW`` (a ``bench_storage.py`` row, e.g. ``1e5x300``) instead: the white furnace (albedo 1, roulette
off, ``bench_storage.furnace``, 32² px, 64 spp) of ``--clouds`` clouds of that row, quantised and spheres.
"""

from __future__ import annotations

import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

DENSE = {"4e5": (400_000, 80.0), "1.6e6": (1_600_000, 80.0)}
#: What each switch's "1" and "0" mean.
LABELS = {"MOTES_QUANTISE": ("quantised", "spheres"), "MOTES_CENTRE_CELLS": ("centred", "overlap"),
          "MOTES_UNIFORM_MAJORANT": ("one majorant", "blocks"), "MOTES_BEAM": ("beams", "one by one")}


def loader(mi, kind: str, res: int, spp: int):
    import _paper as P  # noqa: PLC0415
    import bench_dense as BD  # noqa: PLC0415

    if kind in DENSE:
        n, r = DENSE[kind]
        return lambda: mi.load_dict(BD.scene(mi, BD.discrete(mi, n, r), res, spp, 8))
    if kind == "haze":
        import bench_native as BN  # noqa: PLC0415

        return lambda: BN.scenes(C.import_motes(), mi, "dense", res, spp)[1]
    return lambda: mi.load_file(str(P.scene_file(kind)), res=res)


def furnace(mi, args, out, sw) -> None:
    import bench_dense as BD  # noqa: PLC0415
    import bench_storage as BS  # noqa: PLC0415

    count, median = BS.ROWS[args.furnace]
    res = {}
    on, off = LABELS[args.switch]
    for q in ("1", "0"):
        os.environ[args.switch] = q
        vals = [BS.furnace(mi, BD.discrete(mi, count, median, albedo=1.0, seed=seed), 32, 64)
                for seed in range(args.clouds)]
        m, e = np.array([v[0] for v in vals]), np.array([v[1] for v in vals])
        res[q] = (float(m.mean()), float(np.sqrt((e ** 2).sum()) / len(e)))
        print(f"[{args.variant} {args.furnace}] {on if q == '1' else off}: furnace "
              + " ".join(f"{a:.4f}+-{b:.4f}" for a, b in vals) + f"; mean {res[q][0]:.4f} +- {res[q][1]:.4f}",
              flush=True)
    os.environ.pop(args.switch)
    C.finish(args, sw, out / f"bench_quantise_furnace_{args.switch}_{args.variant}.json",
             furnace={on: res["1"], off: res["0"]})


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--scenes", default="cornell,dust_box,4e5,1.6e6")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--reps", type=int, default=4)
    ap.add_argument("--furnace", default="", help="a bench_storage row: the white furnace instead")
    ap.add_argument("--clouds", type=int, default=3)
    ap.add_argument("--switch", default="MOTES_QUANTISE", choices=sorted(LABELS))
    args = ap.parse_args()
    out, sw = C.out_dir(args.out), C.Stopwatch()
    motes = C.import_motes()
    motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415

    if args.furnace:
        furnace(mi, args, out, sw)
        return
    rows = []
    on, off = LABELS[args.switch]
    for kind in args.scenes.split(","):
        scenes, data = {}, {}
        for q in ("1", "0"):
            os.environ[args.switch] = q
            scenes[q] = loader(mi, kind, args.res, args.spp)()
            data[q] = next(s.interior_medium() for s in scenes[q].shapes() if s.interior_medium() is not None).data
            mi.render(scenes[q], spp=args.spp)  # warm-up
        os.environ.pop(args.switch)
        secs, means = {"1": [], "0": []}, {"1": [], "0": []}
        for rep in range(args.reps):
            for q in ("1", "0"):
                t = time.perf_counter()
                # Converted inside the timing: an LLVM render is evaluated when its image is read.
                img = np.asarray(mi.render(scenes[q], spp=args.spp, seed=rep), dtype=np.float64)
                secs[q].append(time.perf_counter() - t)
                means[q].append(float(img.mean()))
        n = len(data["1"]._core)
        se = {q: float(np.std(means[q], ddof=1) / np.sqrt(len(means[q]))) if len(means[q]) > 1 else 0.0
              for q in means}
        gap = float(np.mean(means["1"]) - np.mean(means["0"]))
        row = {"scene": kind, "quantised_s": min(secs["1"]), "spheres_s": min(secs["0"]),
               "ratio": min(secs["1"]) / min(secs["0"]), "mean_quantised": float(np.mean(means["1"])),
               "mean_spheres": float(np.mean(means["0"])), "se_quantised": se["1"], "se_spheres": se["0"],
               "difference_se": gap / np.hypot(se["1"], se["0"]) if gap else 0.0,
               "bytes_quantised": data["1"].bytes / n, "bytes_spheres": data["0"].bytes / n}
        print(f"[{args.variant} {kind}] {on} {row['quantised_s']:.3f} s, {off} {row['spheres_s']:.3f} s: "
              f"{row['ratio']:.3f}x; means {row['mean_quantised']:.5g} +- {se['1']:.2g} / "
              f"{row['mean_spheres']:.5g} +- {se['0']:.2g} ({row['difference_se']:+.1f} SE); "
              f"B/particle {row['bytes_quantised']:.1f} / {row['bytes_spheres']:.1f}", flush=True)
        rows.append(row)
    C.print_table(f"**{args.variant}, {args.res}^2 px, {args.spp} spp: {on} / {off} (best of {args.reps})**",
                  ["scene", f"{on} (s)", f"{off} (s)", "ratio", f"mean {on}", f"mean {off}", "difference (SE)",
                   f"B/particle {on}", off],
                  [[r["scene"], r["quantised_s"], r["spheres_s"], r["ratio"], r["mean_quantised"], r["mean_spheres"],
                    f"{r['difference_se']:+.1f}", r["bytes_quantised"], r["bytes_spheres"]] for r in rows])
    C.finish(args, sw, out / f"bench_quantise_{args.switch}_{args.variant}.json", rows=rows)


if __name__ == "__main__":
    main()
