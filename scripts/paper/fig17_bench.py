"""Paper Fig. 17: render time of the BENCH scene (2e5 grains, r_g 800 um, sigma_g 4) against the
grid's resolution.

Claim (Sec. 6.5): "a grid resolution yielding roughly one particle per voxel achieves the optimum"
(60^3 cells for 2e5 grains). motes's grid is set by ``cells_per_particle`` (cells = that x N, shaped
to the cloud's box); its cells hold blocks of eight spheres tested together (SIMD), so its optimum
need not sit at one per cell. Each resolution is loaded once and rendered three times (sampler seed
0); the number is the fastest render, with the load (grid build) time beside it. The script reports
where the optimum lies and the time at one particle per cell relative to it.
Writes docs/gallery/fig17_bench.png (a render and the time curve) and .json.

    .venv/bin/python scripts/paper/fig17_bench.py [--full] [--spp N] [--res N]

Preview (32 spp, 160 px): about 2 minutes on 2 cores; --full: 256 spp, 512 px. Timing: run it alone.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

CELLS_PER_PARTICLE = (1 / 64, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0)
N = 200_000


def main() -> int:
    args = P.parser(__doc__, spp=32, res=160, full_spp=256, full_res=512).parse_args()
    spp, res = P.quality(args)
    mi = P.setup(args.variant)
    P.render(mi, "bench", 4, 32)  # warm-up: optics tables, JIT
    rows, default_img = [], None
    for c in CELLS_PER_PARTICLE:
        imgs, t_load, times = P.render(mi, "bench", spp, res, seeds=(0, 0, 0), cells=f"{c:.6g}")
        rows.append(dict(cells_per_particle=c, particles_per_cell=1 / c, cells=c * N,
                         cells_per_axis_cubic=(c * N) ** (1 / 3), load_s=t_load, render_s=min(times)))
        if c == 1 / 8:
            default_img = imgs[0]
        print(f"{1 / c:6.3g} particles per cell ({c * N:9.0f} cells, ~{(c * N) ** (1 / 3):4.0f}^3): "
              f"render {min(times):.2f} s (load {t_load:.1f} s)", flush=True)
    best = min(rows, key=lambda r: r["render_s"])
    one = next(r for r in rows if r["cells_per_particle"] == 1.0)
    print(f"fastest at {best['particles_per_cell']:.3g} particles per cell ({best['render_s']:.2f} s); "
          f"one per cell (the paper's optimum) takes {one['render_s'] / best['render_s']:.2f}x that")
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9, 4))
    exp = P.exposure_of(default_img)
    ax0.imshow(P._display(default_img, *exp))
    ax0.set_axis_off()
    ax0.set_title(f"BENCH, 2e5 grains (default grid), {spp} spp", fontsize=9)
    ax1.plot([r["particles_per_cell"] for r in rows], [r["render_s"] for r in rows], "o-")
    ax1.set_xscale("log", base=2)
    ax1.set_xlabel("particles per cell (1 / cells_per_particle)")
    ax1.set_ylabel(f"render time, s ({res}x{res}, {spp} spp)")
    ax1.axvline(1.0, color="grey", ls=":", label="paper's optimum: 1 per cell")
    ax1.axvline(8.0, color="tab:orange", ls="--", label="motes default: 8 per cell")
    ax1.legend(fontsize=8)
    ax1.set_title("Fig. 17: render time against grid resolution", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "fig17_bench.png", dpi=100)
    P.save_numbers(out, "fig17_bench", {"spp": spp, "res": res, "variant": args.variant, "count": N, "rows": rows,
                                        "fastest_particles_per_cell": best["particles_per_cell"],
                                        "one_per_cell_over_fastest": one["render_s"] / best["render_s"]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
