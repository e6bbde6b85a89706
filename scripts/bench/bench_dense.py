"""Issue 25: dense clouds of visible grains against Mitsuba's `homogeneous` + `tabphase`, side by side in one
process (ratios only; this machine is shared), with the accuracy of each speed-up beside it.

The scene (the issue's): a 12 cm cube of grains (log-normal radii, sigma_g 1.3, index 1.5, scene unit 1 cm,
``query_radius`` 0.02 = 0.2 mm) lit by a spot beam in a grey room (``scripts/bench/bench_render.py``'s dust
room), ``volpath`` max_depth 8, llvm_ad_rgb (Mitsuba's default symbolic mode, the native path) or
scalar_rgb. Rows (``--rows``): ``1e5x80`` (10^5 grains, median 80 um), ``4e5x80``, ``1.6e6x80``,
``4e6x20`` (20 um: its classes are continuous by default).

For each row it renders, interleaved, best of ``--reps`` after a warm-up render:

* ``homogeneous``: the equivalent ``homogeneous`` + ``tabphase`` (``motes.homogeneous_equivalent``);
* ``exact``: the discrete medium with ``continuous_count`` = inf (every grain walked, every bounce);
* ``default``: the discrete medium as a user gets it (``grain_depth`` 1: a path's rays see grains until
  its first scattering event, its continuous equivalent after; ``surface_footprint``: rays from the walls
  see that equivalent where their narrowest pixel footprint holds many grains);
* ``no surface rule`` (with ``--surface``): ``default`` with ``surface_footprint`` off (rays from
  surfaces walk the grains);
* ``depth 2`` (with ``--depths 2``, and so on): rays see grains until the path's 2nd event.

Accuracy of each against ``exact`` (two sampler seeds each, same particles): the image means' difference in
standard errors (SE from the two seeds' difference), and the per-pixel RMS difference against the exact
render's own seed-to-seed RMS difference (1 = at noise level; on all pixels and on the lit grains, the
pixels where the exact render exceeds 2x its median).

    .venv/bin/python scripts/bench/bench_dense.py [--quick] [--rows 1e5x80,4e5x80] [--variant scalar_rgb]

A row may also be any ``COUNTxMEDIAN`` (grains x median radius in um, e.g. ``2.56e7x80``); ``--speed-only``
renders only ``homogeneous`` and ``default`` (no exact render, no accuracy columns: clouds whose exact
render would take long).
"""

from __future__ import annotations

import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import bench_render as BR  # noqa: E402

ROWS = {"1e5x80": (100_000, 80.0), "4e5x80": (400_000, 80.0), "1.6e6x80": (1_600_000, 80.0),
        "4e6x20": (4_000_000, 20.0),
        # Stress rows for the surface-ray rule: grains large against their spacing, whose shadows on the
        # walls and floor a pixel can resolve (not in the default set).
        "2e4x500": (20_000, 500.0), "2e5x300": (200_000, 300.0)}
DEFAULT_ROWS = "1e5x80,4e5x80,1.6e6x80,4e6x20"
HALF = 6.0  # cm: the cube's half-size (12 cm across)
SIGMA_G, ETA, QUERY_RADIUS = 1.3, 1.5, 0.02


def scene(mi, medium: dict, res: int, spp: int, max_depth: int) -> dict:
    d = BR.room(mi, medium, res, spp, max_depth=max_depth)
    T = mi.ScalarTransform4f
    d["cube"]["to_world"] = T().scale(HALF)
    d["spot"]["to_world"] = T().look_at(origin=[-8, 19, -15], target=[0, 0, 0], up=[0, 1, 0])
    # A closed grey room: walls, ceiling and a wall behind the camera, so that light bounces back into
    # the cloud from every side (the dust room has only a floor and a back wall).
    wall = d["floor"]["bsdf"]
    d["ceiling"] = {"type": "rectangle", "to_world": T().translate([0, 20, 0]).scale(30).rotate([1, 0, 0], 90),
                    "bsdf": wall}
    d["left"] = {"type": "rectangle", "to_world": T().translate([-20, 0, 0]).scale(30).rotate([0, 1, 0], 90),
                 "bsdf": wall}
    d["right"] = {"type": "rectangle", "to_world": T().translate([20, 0, 0]).scale(30).rotate([0, 1, 0], -90),
                  "bsdf": wall}
    d["front"] = {"type": "rectangle", "to_world": T().translate([0, 0, 45]).scale(30).rotate([0, 1, 0], 180),
                  "bsdf": wall}
    return d


def discrete(mi, count: int, median: float, **extra) -> dict:
    return {"type": "discrete", "count": count, "radius_median": median, "radius_sigma_g": SIGMA_G, "eta": ETA,
            "scale_m": 0.01, "query_radius": QUERY_RADIUS, "to_world": mi.ScalarTransform4f().scale(HALF),
            "phase": {"type": "particle"}, **extra}


def homogeneous(motes, count: int, median: float) -> dict:
    sp = motes.Species(motes.LogNormal(median, SIGMA_G), complex(ETA, 0.0))
    n_m3 = count / (2 * HALF * 0.01) ** 3
    return motes.homogeneous_equivalent(sp, n_m3, color="rgb", scale_m=0.01, tabphase_size=BR.TAB_SIZE)


def render(mi, sc, spp: int, seed: int):
    t = time.perf_counter()
    img = np.asarray(mi.render(sc, spp=spp, seed=seed), dtype=np.float64)
    return time.perf_counter() - t, img.mean(axis=2)


def accuracy(a0, a1, e0, e1) -> dict:
    """Image a (seeds 0, 1) against the exact render e (seeds 0, 1)."""
    n = a0.size
    se = np.sqrt(np.var((a0 - a1).ravel()) / (4 * n) + np.var((e0 - e1).ravel()) / (4 * n))
    diff = (a0 + a1).mean() / 2 - (e0 + e1).mean() / 2
    lit = e0 + e1 > 2 * np.median(e0 + e1)
    noise = lambda m: np.sqrt(np.mean(((e0 - e1)[m]) ** 2))  # noqa: E731
    # a0 - e1 and a1 - e0: independent seeds on both sides, as the noise reference e0 - e1.
    rms = lambda m: np.sqrt(np.mean(((a0 - e1)[m]) ** 2 + ((a1 - e0)[m]) ** 2) / 2)  # noqa: E731
    every = np.ones_like(lit)
    return {"mean": float((a0 + a1).mean() / 2), "diff_se": float(diff / se) if se > 0 else 0.0,
            "rel_diff": float(diff / max((e0 + e1).mean() / 2, 1e-30)),
            "rms_over_noise": float(rms(every) / noise(every)),
            "rms_over_noise_lit": float(rms(lit) / noise(lit)) if lit.any() else float("nan")}


def row_spec(name: str) -> tuple[int, float]:
    """A row's grain count and median radius (um): a named row, or ``COUNTxMEDIAN``."""
    if name in ROWS:
        return ROWS[name]
    count, _, median = name.partition("x")
    return int(float(count)), float(median)


def run_row(motes, mi, name: str, res: int, spp: int, reps: int, depths, max_depth: int, surface: bool = False,
            seeds: int = 2, exact: bool = True) -> dict:
    count, median = row_spec(name)
    media = {"homogeneous": homogeneous(motes, count, median),
             "exact": discrete(mi, count, median, continuous_count=float("inf")),
             "default": discrete(mi, count, median)}
    if not exact:
        del media["exact"]
    if surface:
        media["no surface rule"] = discrete(mi, count, median, surface_footprint=False)
    for d in depths:
        media[f"depth {d}"] = discrete(mi, count, median, grain_depth=d)
    scenes = {k: mi.load_dict(scene(mi, m, res, spp, max_depth)) for k, m in media.items()}
    best = {k: np.inf for k in scenes}
    imgs = {}
    for rep in range(reps + 1):  # rep 0 compiles the kernels
        for k, sc in scenes.items():
            t, img = render(mi, sc, spp, seed=rep)
            if rep > 0:
                best[k] = min(best[k], t)
    for k, sc in scenes.items() if exact else ():  # fixed seeds for the accuracy columns, in two halves
        halves = [[render(mi, sc, spp, seed=100 + s)[1] for s in range(h, seeds, 2)] for h in (0, 1)]
        imgs[k] = [np.mean(h, axis=0) for h in halves]
    row = {"row": name, "count": count, "median_um": median, "res": res, "spp": spp}
    for k in scenes:
        row[k] = {"seconds": best[k], "ratio": best[k] / best["homogeneous"]}
        if exact and k not in ("homogeneous", "exact"):
            row[k].update(accuracy(*imgs[k], *imgs["exact"]))
    cells = "  ".join(f"{k} {v['seconds']:.2f} s ({v['ratio']:.1f}x" +
                      (f", {v['diff_se']:+.1f} SE, rms/noise {v['rms_over_noise']:.2f} lit "
                       f"{v['rms_over_noise_lit']:.2f}" if "diff_se" in v else "") + ")"
                      for k, v in row.items() if isinstance(v, dict))
    print(f"[{name}] {cells}", flush=True)
    return row


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--rows", default=DEFAULT_ROWS, help=f"rows, of {list(ROWS)}")
    ap.add_argument("--surface", action="store_true", help="add the default without the surface-ray rule")
    ap.add_argument("--seeds", type=int, default=2, help="sampler seeds per image for the accuracy columns")
    ap.add_argument("--variant", default="llvm_ad_rgb", help="llvm_ad_rgb or scalar_rgb")
    ap.add_argument("--depths", default="", help="comma-separated grain depths to add (e.g. 2,3)")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--speed-only", action="store_true", help="no exact render and no accuracy columns")
    args = ap.parse_args()
    names = [r.strip() for r in args.rows.split(",") if r.strip()]
    for r in names:
        try:
            count, median = row_spec(r)
        except ValueError:
            ap.error(f"row {r!r}: one of {list(ROWS)} or COUNTxMEDIAN (e.g. 2.56e7x80)")
        if not (count > 0 and median > 0):
            ap.error(f"row {r!r}: count and median radius must be positive")
    depths = [int(x) for x in args.depths.split(",") if x.strip()]
    out, sw, motes = C.out_dir(args.out), C.Stopwatch(), C.import_motes()
    motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415

    reps = 1 if args.quick else args.reps
    rows = [run_row(motes, mi, n, args.res, args.spp, reps, depths, args.max_depth, args.surface, max(2, args.seeds),
                    exact=not args.speed_only)
            for n in names]
    keys = [k for k in rows[0] if isinstance(rows[0][k], dict)]
    C.print_table(f"{args.variant}, {args.res}x{args.res}, {args.spp} spp: seconds per render / homogeneous",
                  ["row"] + keys, [[r["row"]] + [f"{r[k]['ratio']:.2f}x" for k in keys] for r in rows])
    acc = [k for k in keys if k not in ("homogeneous", "exact")] if not args.speed_only else []
    if acc:
        C.print_table("against exact: mean difference (SE), per-pixel RMS / noise (all; lit grains)",
                      ["row"] + acc, [[r["row"]] + [f"{r[k]['diff_se']:+.1f} SE; {r[k]['rms_over_noise']:.2f}; "
                                                    f"{r[k]['rms_over_noise_lit']:.2f}" for k in acc] for r in rows])
    C.finish(args, sw, out / f"bench_dense_{args.variant}.json", rows=rows)


if __name__ == "__main__":
    main()
