"""Issue 24.2: compact particle storage against full precision, same particles, same sampler seeds.

Compact storage makes each particle a class (its optics bin and one of 1024 radius levels per bin;
``rust/motes-core/src/render/storage.rs``). This script measures what that changes:

* the quantisation: the largest radius shift it allows (half a level of the widest bin) against the
  particles' radii;
* images: ``bench_dense.py``'s scene (a 12 cm cube of grains in a spot beam in a closed grey room,
  ``volpath`` max_depth 8) rendered with ``storage`` = ``full`` and ``compact`` over ``--seeds`` sampler
  seeds each: the difference of the image means in standard errors (SE from the per-seed means) and the
  per-pixel RMS difference between the two storages (every pair of distinct seeds) against full
  storage's own seed-to-seed RMS difference (1 = at noise level), on all pixels and on lit grains (pixels
  above twice the median);
* the white furnace (albedo 1, Russian roulette off, constant environment) of both;
* bytes the medium keeps per particle, and seconds per render (interleaved).

Rows: ``4e5x80`` (4·10^5 grains, median 80 µm: discrete), ``1e5x300`` (large grains, each a visible
glint: the radius matters most), ``4e6x20`` (20 µm: its classes are continuous).

    .venv/bin/python scripts/bench/bench_storage.py [--rows 4e5x80] [--seeds 8] [--variant scalar_rgb]
"""

from __future__ import annotations

import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import bench_dense as BD  # noqa: E402

ROWS = {"4e5x80": (400_000, 80.0), "1e5x300": (100_000, 300.0), "4e6x20": (4_000_000, 20.0)}
LEVELS = 1024


def furnace(mi, medium: dict, res: int, spp: int) -> tuple[float, float]:
    sc = mi.load_dict({"type": "scene", "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 10**6},
                       "sensor": {"type": "perspective", "fov": 30,
                                  "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 30], target=[0, 0, 0], up=[0, 1, 0]),
                                  "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                                  "sampler": {"type": "independent", "sample_count": spp}},
                       "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
                       "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                                "to_world": medium["to_world"]}})
    img = np.asarray(mi.render(sc), dtype=np.float64).mean(axis=2)
    return float(img.mean()), float(img.std(ddof=1) / np.sqrt(img.size))


def run_row(mi, name: str, res: int, spp: int, seeds: int) -> dict:
    count, median = ROWS[name]
    media = {s: BD.discrete(mi, count, median, storage=s) for s in ("full", "compact")}
    scenes = {s: mi.load_dict(BD.scene(mi, m, res, spp, 8)) for s, m in media.items()}
    data = {s: next(sh.interior_medium() for sh in sc.shapes() if sh.interior_medium() is not None).data
            for s, sc in scenes.items()}
    lo, hi = np.array(data["full"].bin_radius_um).T
    half_level = float(np.max(np.log(hi / lo))) / (2 * LEVELS)
    imgs = {s: [] for s in scenes}
    secs = {s: [] for s in scenes}
    for seed in range(seeds):  # interleaved
        for s, sc in scenes.items():
            t, img = BD.render(mi, sc, spp, seed=seed)
            imgs[s].append(img)
            secs[s].append(t)
    means = {s: np.array([i.mean() for i in v]) for s, v in imgs.items()}
    se = np.hypot(means["full"].std(ddof=1), means["compact"].std(ddof=1)) / np.sqrt(seeds)
    diff = means["compact"].mean() - means["full"].mean()
    # Over every pair of distinct seeds (one heavy-tailed pixel makes a single pair's RMS noisy): full
    # against full is the noise, compact against full (other seed) the difference.
    f, c = imgs["full"], imgs["compact"]
    lit = np.mean(f, axis=0) > 2 * np.median(np.mean(f, axis=0))
    pairs = [(i, j) for i in range(seeds) for j in range(seeds) if i != j]
    noise = lambda m: np.sqrt(np.mean([np.mean(((f[i] - f[j])[m]) ** 2) for i, j in pairs]))  # noqa: E731
    rms = lambda m: np.sqrt(np.mean([np.mean(((c[i] - f[j])[m]) ** 2) for i, j in pairs]))  # noqa: E731
    every = np.ones_like(lit)
    medium = BD.discrete(mi, count, median, albedo=1.0)
    furn = {s: furnace(mi, dict(medium, storage=s), 32, 32) for s in ("full", "compact")}
    row = {"row": name, "count": count, "half_level_rel": half_level, "mean_full": float(means["full"].mean()),
           "diff_rel": float(diff / means["full"].mean()), "diff_se": float(diff / se),
           "rms_over_noise": float(rms(every) / noise(every)), "rms_over_noise_lit": float(rms(lit) / noise(lit)),
           "furnace": furn, "bytes_per_particle": {s: d.bytes / count for s, d in data.items()},
           "seconds": {s: float(np.median(v[1:] if len(v) > 1 else v)) for s, v in secs.items()}}
    print(f"[{name}] radius shift <= {half_level:.1e} (relative); compact - full {row['diff_rel']:+.2%} "
          f"({row['diff_se']:+.1f} SE); rms/noise {row['rms_over_noise']:.2f} lit {row['rms_over_noise_lit']:.2f}; "
          f"furnace full {furn['full'][0]:.4f}+-{furn['full'][1]:.4f} compact {furn['compact'][0]:.4f}+-{furn['compact'][1]:.4f}; "
          f"B/particle full {row['bytes_per_particle']['full']:.1f} compact {row['bytes_per_particle']['compact']:.1f}; "
          f"s/render full {row['seconds']['full']:.2f} compact {row['seconds']['compact']:.2f}", flush=True)
    return row


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--rows", default=",".join(ROWS), help=f"rows, of {list(ROWS)}")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    out, sw = C.out_dir(args.out), C.Stopwatch()
    motes = C.import_motes()
    motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415

    rows = [run_row(mi, r, args.res, args.spp, args.seeds) for r in args.rows.split(",")]
    C.print_table(f"**{args.variant}, {args.res}^2 px, {args.spp} spp x {args.seeds} seeds: compact against full**",
                  ["row", "radius shift <=", "mean diff", "(SE)", "RMS/noise all", "lit", "furnace full", "furnace compact",
                   "B/particle full", "compact"],
                  [[r["row"], f"{r['half_level_rel']:.1e}", f"{r['diff_rel']:+.2%}", f"{r['diff_se']:+.1f}",
                    r["rms_over_noise"], r["rms_over_noise_lit"],
                    f"{r['furnace']['full'][0]:.4f} ± {r['furnace']['full'][1]:.4f}",
                    f"{r['furnace']['compact'][0]:.4f} ± {r['furnace']['compact'][1]:.4f}",
                    r["bytes_per_particle"]["full"], r["bytes_per_particle"]["compact"]] for r in rows])
    C.finish(args, sw, out / f"bench_storage_{args.variant}.json", rows=rows)


if __name__ == "__main__":
    main()
