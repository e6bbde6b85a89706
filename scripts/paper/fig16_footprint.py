"""Paper Fig. 16: the query cylinder's radius r_c = k x (pixel footprint at the medium's nearest depth),
Eq. 23, in the FOOTPRINT scene, for k = 0.2, 0.5, 1, 2 and N = 1e4 and 1e5 grains.

Claims (Sec. 6.5): k in [0.5, 1] gives a faithful grainy look; a larger k keeps the overall brightness
but blurs the glints; a small k misses grains along a ray, which is inefficient in a sparse cloud
(1e4), while in a denser one (1e5) k = 0.2 looks like k = 0.5. Numbers per (N, k), each rendered twice
(sampler seeds 0 and 1, same grains): the image mean +- SE (the brightness), the relative Monte Carlo
noise per pixel (std of (A - B) / sqrt 2 over the mean: the inefficiency at equal spp), the medium's
graininess (std / mean over pixels of the optical depth per unit length along each pixel's query
cylinder: the blur), and the render time.
Checks: at each N the means agree with k = 0.5's within 3 combined SE or 3 %; the graininess falls as k
grows. Writes docs/gallery/fig16_footprint.png and .json.

    .venv/bin/python scripts/paper/fig16_footprint.py [--full] [--spp N] [--res N]

Preview (128 spp, 160 px): about 1 minute on 2 cores; --full: 1024 spp, 512 px.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

KS = (0.2, 0.5, 1.0, 2.0)
COUNTS = (10**4, 10**5)
BOX = ((-15.0,) * 3, (15.0,) * 3)  # the cube of grains, scene units (cm)


def main() -> int:
    args = P.parser(__doc__, spp=128, res=160, full_spp=1024, full_res=512).parse_args()
    spp, res = P.quality(args)
    mi = P.setup(args.variant)
    sheet_rows, results, ok = [], [], True
    for n in COUNTS:
        panels, rows = [], []
        for k in KS:
            (a, b), t_load, times, tl = P.render(mi, "footprint", spp, res, seeds=(0, 1), count=n, k=k,
                                                 measure=lambda sc: P.pixel_optical_depth(mi, sc, BOX))
            m, se = P.mean_and_se(a, b)
            noise = float(np.sqrt(np.mean((P.luminance(a) - P.luminance(b)) ** 2) / 2) / m)
            g = P.medium_graininess(tl)
            rows.append(dict(count=n, k=k, mean=m, se=se, mc_noise=noise, graininess=g, render_s=min(times)))
            panels.append((f"N {n:.0e}, k = {k:g}\nmean {m:.3g} +- {se:.1g}\nnoise {noise:.2f}, graininess {g:.2f}",
                           0.5 * (a + b)))
            print(f"N {n:.0e}  k {k:<4g} mean {m:.5g} +- {se:.2g}  MC noise/pixel {noise:.2f}  graininess {g:.3f}  "
                  f"render {min(times):.1f} s", flush=True)
        ref = next(r for r in rows if r["k"] == 0.5)
        same = all(abs(r["mean"] - ref["mean"]) < max(3 * np.hypot(r["se"], ref["se"]), 0.03 * ref["mean"])
                   for r in rows)
        blurs = P.monotone([r["graininess"] for r in rows], decreasing=True)
        print(f"N {n:.0e}: brightness independent of k: {'PASS' if same else 'FAIL'}; graininess falls as k grows: "
              f"{'PASS' if blurs else 'FAIL'}")
        ok = ok and same and blurs
        sheet_rows.append(panels)
        results.append(dict(count=n, rows=rows, same_brightness=same, graininess_falls=blurs))
    out = pathlib.Path(args.out)
    P.sheet(sheet_rows, out / "fig16_footprint.png",
            f"FOOTPRINT (Fig. 16): query radius r_c = k x pixel footprint (Eq. 23); {spp} spp",
            row_titles=[f"N = {n:.0e}" for n in COUNTS], reference=(0, 1),
            exposures=[P.exposure_of(r[1][1]) for r in sheet_rows])
    P.save_numbers(out, "fig16_footprint", {"spp": spp, "res": res, "variant": args.variant, "results": results})
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
