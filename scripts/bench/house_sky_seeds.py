"""The HOUSE scene's sky band (the measure of scripts/paper/fig19_house.py) over many sampler seeds: mean +- SE of
the band and of the whole image, and how many renders hold a firefly (a pixel above 20). Fig. 19's preview checks
use two seeds each, which a single glint of the snow can move by several of their own SEs; this says whether a change
moved the scene or the seeds. Run it on two builds and compare.

    .venv/bin/python scripts/bench/house_sky_seeds.py [--first 100] [--seeds 32] [--sigma-g 1.6] [--radius 100]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
import numpy as np  # noqa: E402

import _paper as P  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--first", type=int, default=100, help="first sampler seed")
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--sigma-g", type=float, default=1.6)
    ap.add_argument("--radius", type=float, default=100, help="radius_median, um")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()
    mi = P.setup(args.variant)
    res, spp = 160, 16  # fig19_house.py's preview
    rows = np.s_[int(0.03 * res):int(0.22 * res)]
    sc = mi.load_file(str(P.scene_file("house")), radius_median=str(args.radius), sigma_g=str(args.sigma_g),
                      spp=str(spp), res=str(res))
    sky, whole, peak = [], [], []
    for s in range(args.first, args.first + args.seeds):
        img = np.asarray(mi.render(sc, spp=spp, seed=s), dtype=np.float64)[..., :3]
        sky.append(img[rows].mean())
        whole.append(img.mean())
        peak.append(img.max())
    sky, whole, peak = map(np.array, (sky, whole, peak))
    n = args.seeds
    print(f"[house r_g {args.radius:g} um, sigma_g {args.sigma_g:g}, seeds {args.first}..{args.first + n - 1}] "
          f"sky {sky.mean():.5f} +- {sky.std(ddof=1) / np.sqrt(n):.5f} (median {np.median(sky):.5f}), whole "
          f"{whole.mean():.5f} +- {whole.std(ddof=1) / np.sqrt(n):.5f}, renders with a firefly (pixel > 20) "
          f"{int((peak > 20).sum())}/{n}, brightest pixel {peak.max():.1f}")


if __name__ == "__main__":
    main()
