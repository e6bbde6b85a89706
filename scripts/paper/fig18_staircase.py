"""Paper Fig. 18: dust in the STAIRCASE scene as the grains' absorption eta_i grows.

Claim (Sec. 6.6): "an increase of eta_i will increasingly dim the intensity of scattering". Each
eta_i is rendered twice (sampler seeds 0 and 1, same grains); the number is the image's mean luminance
with its Monte Carlo standard error, and the check is that every step of eta_i dims the image by more
than 2 combined standard errors. Writes docs/gallery/fig18_staircase.png and .json.

    .venv/bin/python scripts/paper/fig18_staircase.py [--full] [--spp N] [--res N]

Preview (16 spp, 160 px): about 3 minutes on 2 cores; --full: 256 spp, 512 px.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

#: Absorption lengths lambda / (4 pi eta_i) from infinite to 44 um, through the grains' size (0.8 mm at
#: eta_i ~ 5e-5): beyond ~1e-3 the grains are opaque and more absorption changes only their surface
#: reflection, so the sweep stops there.
ETA_K = (0.0, 1e-6, 1e-5, 1e-4, 1e-3)


def main() -> int:
    args = P.parser(__doc__, spp=16, res=160, full_spp=256, full_res=512).parse_args()
    spp, res = P.quality(args)
    mi = P.setup(args.variant)
    panels, rows = [], []
    for k in ETA_K:
        (a, b), t_load, times = P.render(mi, "staircase", spp, res, seeds=(0, 1), eta_k=k)
        m, se = P.mean_and_se(a, b)
        rows.append({"eta_k": k, "mean": m, "se": se, "load_s": t_load, "render_s": min(times)})
        panels.append((f"eta_i = {k:g}\nmean {m:.4g} +- {se:.2g}", 0.5 * (a + b)))
        print(f"eta_i {k:<8g} mean {m:.5g} +- {se:.2g}  (load {t_load:.1f} s, render {min(times):.1f} s)", flush=True)
    dims = P.steps_beyond_noise([r["mean"] for r in rows], [r["se"] for r in rows], decreasing=True)
    print(f"scattering dims with eta_i at every step (beyond 2 SE): {'PASS' if dims else 'FAIL'}")
    out = pathlib.Path(args.out)
    P.sheet([panels], out / "fig18_staircase.png",
            f"STAIRCASE (Fig. 18): 3e6 dust grains, r_g 800 um, sigma_g 4, eta = 1.5 + i eta_i; {spp} spp")
    P.save_numbers(out, "fig18_staircase", {"spp": spp, "res": res, "variant": args.variant, "rows": rows,
                                            "dims_monotonically": dims})
    return 0 if dims else 1


if __name__ == "__main__":
    sys.exit(main())
