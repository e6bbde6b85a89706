"""Issue 10.3: where may a size class be rendered as a continuous medium? Measured against the fully
discrete render of the same particles.

The `discrete` medium samples a size class as a continuous medium (its cells' mean extinction and phase
mixture) when a query cylinder holds at least `continuous_count` of its particles over one mean free path
or across the cloud (`rust/motes-core/src/render/continuous/`). What that drops is the grain texture: the
per-pixel fluctuation of the particle count, of relative size 1/sqrt(N). This script renders the dust
room (`bench_render.room`, llvm_ad_rgb, native path) with particle clouds whose N spans the threshold,
once fully discrete (`continuous_count = inf`) and once at each threshold, two sampler seeds each, and
reports per configuration:

* N: particles per query cylinder of the cloud (its one size class), from the medium's own criterion;
* which thresholds make it continuous, and the render time of each against the discrete one;
* `bias/noise`: the RMS per-pixel difference that is not Monte Carlo noise,
  sqrt(max(0, rms(H_a - D_b)^2 - rms(H_a - H_b)^2 / 2 - rms(D_a - D_b)^2 / 2)), over the RMS noise
  of one discrete render at the same spp, rms(D_a - D_b) / sqrt(2). Below 1 the switch changes the image
  by less than the noise of the render; `mean diff` is the relative difference of image means with its
standard error (pixel noise only: the particles are the same in both).

    .venv/bin/python scripts/figures/continuous_switch.py [--spp 64] [--res 128] [--quick]

Run time on 2 shared cores: ~4 min (default), ~40 s (--quick).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "bench"))  # bench_render
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import bench_render as BR  # noqa: E402

THRESHOLDS = (64.0, 16.0, 4.0)


def clouds(quick: bool) -> dict:
    """Dust-room clouds from sparse to hazy (count, median radius um, sigma_g, footprint k)."""
    scale = 0.3 if quick else 1.0
    return {
        "haze 3e5 x 100 um": dict(count=int(300_000 * scale), median=100.0, sigma_g=1.2, k=1.0),
        "haze 1e6 x 40 um": dict(count=int(1_000_000 * scale), median=40.0, sigma_g=1.3, k=1.0),
        "dust 6e4 x 60 um": dict(count=int(60_000 * scale), median=60.0, sigma_g=1.6, k=0.7),
    }


def per_cylinder(mi, cfg: dict, res: int) -> float:
    """N of the cloud's largest class by the medium's criterion (particles per query cylinder)."""
    for cc in (2.0 ** k for k in range(12, -4, -1)):
        d = BR.discrete_dict(mi, cfg, res)
        d["continuous_count"] = cc
        sc = mi.load_dict(BR.room(mi, d, res, 1))
        med = next(s.interior_medium() for s in sc.shapes() if s.interior_medium() is not None)
        if med.data.continuous_particles > 0:
            return cc  # the largest power of two the cloud reaches
    return 0.0


def render(mi, scene, spp: int, seed: int):
    t = time.perf_counter()
    img = np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    return time.perf_counter() - t, img


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a * a)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--clouds", default="", help="comma-separated prefixes of the clouds to run (default: all)")
    ap.add_argument("--thresholds", default="", help="comma-separated continuous_count values (default: 64,16,4)")
    ap.add_argument("--out", default="out", help="accepted for run_benchmarks.sh; the table goes to stdout")
    a = ap.parse_args()
    spp = 16 if a.quick else a.spp
    res = 64 if a.quick else a.res
    motes = C.import_motes()
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi  # noqa: PLC0415
    print(f"# continuous switch: dust room, llvm_ad_rgb, {res} px, {spp} spp, 2 seeds per render\n")
    print("| cloud | N per cylinder (>=) | continuous_count | continuous particles | seconds | x discrete | mean diff | bias/noise |")
    print("|---|---|---|---|---|---|---|---|")
    only = [c.strip() for c in a.clouds.split(",") if c.strip()]
    thresholds = tuple(float(x) for x in a.thresholds.split(",") if x.strip()) or THRESHOLDS
    for name, cfg in clouds(a.quick).items():
        if only and not any(name.startswith(c) for c in only):
            continue
        n_cyl = per_cylinder(mi, cfg, res)
        rows = {}
        for cc in (math.inf,) + thresholds:
            d = BR.discrete_dict(mi, cfg, res)
            d["continuous_count"] = cc
            scene = mi.load_dict(BR.room(mi, d, res, spp))
            med = next(s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None)
            render(mi, scene, 1, 99)  # compile
            ta, ia = render(mi, scene, spp, 0)
            tb, ib = render(mi, scene, spp, 1)
            rows[cc] = (min(ta, tb), ia, ib, med.data.continuous_particles)
        t_d, da, db, _ = rows[math.inf]
        noise2 = rms(da - db) ** 2 / 2
        for cc in (math.inf,) + thresholds:
            t, ha, hb, ncont = rows[cc]
            if cc == math.inf:
                ratio = "1"
                diff = bias = "—"
            else:
                b2 = rms(ha - db) ** 2 - rms(ha - hb) ** 2 / 2 - noise2
                bias = f"{math.sqrt(max(b2, 0.0) / noise2):.2f}"
                # SE of the difference of the two-seed means, from each path's seed-to-seed pixel noise.
                se = math.sqrt(((ha - hb).var() + (da - db).var()) / (4 * ha.size)) / (da.mean() + db.mean()) * 2
                diff = f"{(ha.mean() + hb.mean()) / (da.mean() + db.mean()) - 1:+.2%} ± {se:.2%}"
                ratio = f"{t / t_d:.2f}"
            print(f"| {name} | {n_cyl:g} | {cc:g} | {ncont} | {t:.2f} | {ratio} | {diff} | {bias} |", flush=True)


if __name__ == "__main__":
    main()
