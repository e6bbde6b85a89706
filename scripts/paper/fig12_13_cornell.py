"""Paper Figs. 12 and 13: 1e5 ice grains of 1000 um in the CORNELL box: explicit path tracing (EPT) of
the same grains as glass spheres, motes with and without Fraunhofer diffraction, and motes with the
Henyey-Greenstein phase function of the same g in place of the grains' own.

motes's knobs: "FD" renders the full phase function (``truncate = 0``: every diffraction event is a
scattering event); "-FD" folds the diffraction lobe into unscattered light (``truncate = 0.004`` rad,
about ten Airy rings of a 1 mm grain at 550 nm: what EPT's spheres see); "default" is the medium's own
default (the pixel footprint); "HG" is ``phase_model = hg``. EPT (``--ept``, on by default): every
grain a Mitsuba ``sphere`` with a ``dielectric`` BSDF (index 1.31), same positions and radii.
Claims (Sec. 6.2-6.3): at this size the grains look alike with or without diffraction, which adds
only subtle differences; motes without diffraction resembles EPT; HG differs slightly from the
grains' own phase function. Numbers (two sampler seeds per image, same grains): each image's mean +-
SE, and for each pair the relative difference of means (+- SE) and RMS(difference) / noise floor (1:
equal to their noise). Also a plot of the phase functions (the grains' and HG of the same g).
Writes docs/gallery/fig12_13_cornell.png, fig13_phase.png and fig12_13_cornell.json.

    .venv/bin/python scripts/paper/fig12_13_cornell.py [--full] [--spp N] [--res N] [--no-ept]

Runs in scalar_rgb by default (EPT's 1e5 spheres are slow in LLVM, where each is its own shape).
Preview (32 spp, 128 px): about 4 minutes on 2 cores; --full: 512 spp, 512 px.
"""

from __future__ import annotations

import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

CONFIGS = {"default": {}, "FD": {"truncate": 0}, "-FD": {"truncate": 0.004}, "HG": {"phase_model": "hg"}}
PAIRS = (("FD", "-FD"), ("default", "HG"), ("-FD", "EPT"), ("FD", "EPT"))
ICE_REAL_INDEX = 1.31


def compare(a, b):
    (a1, a2), (b1, b2) = a, b
    ma, sa = P.mean_and_se(a1, a2)
    mb, sb = P.mean_and_se(b1, b2)
    diff = P.luminance(0.5 * (a1 + a2)) - P.luminance(0.5 * (b1 + b2))
    noise = np.mean(0.25 * (P.luminance(a1) - P.luminance(a2)) ** 2 + 0.25 * (P.luminance(b1) - P.luminance(b2)) ** 2)
    return dict(rel_diff=(ma - mb) / mb, rel_diff_se=math.hypot(sa, sb) / mb, rms_over_noise=float(np.sqrt(np.mean(diff**2) / noise)))


def phase_plot(path: pathlib.Path) -> dict:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    import motes  # noqa: PLC0415

    sp = motes.Species(motes.Monodisperse(1000.0), motes.Material("ice"))
    b = motes.bulk_properties([sp], 1.0, [0.532])
    theta, f = np.asarray(b["theta"]), np.asarray(b["phase"])[0]
    g = motes._motes.PhaseTable(theta, f).mean_cosine()
    hg = motes._motes.henyey_greenstein(g, theta)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.semilogy(np.degrees(theta), f, "r-", label="ice grain, r = 1000 um (GOA, Eq. 17)")
    ax.semilogy(np.degrees(theta), hg, "b-", label=f"Henyey-Greenstein, same g = {g:.3f}")
    ax.set_xlabel("scattering angle (deg)")
    ax.set_ylabel("phase function (1/sr), 532 nm")
    ax.legend(fontsize=8)
    ax.set_title("Fig. 13: the grains' phase function and the HG of the same g", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return {"g": float(g)}


def main() -> int:
    args, spp, res, mi = P.ept_start(__doc__, spp=32, res=128, full_spp=512, full_res=512)
    imgs, numbers = {}, {"spp": spp, "res": res, "variant": args.variant, "images": {}, "pairs": {}}
    for name, params in CONFIGS.items():
        pair, t_load, times = P.render(mi, "cornell", spp, res, seeds=(0, 1), **params)
        imgs[name] = pair
        m, se = P.mean_and_se(*pair)
        numbers["images"][name] = dict(params, mean=m, se=se, load_s=t_load, render_s=min(times))
        print(f"{name:8s} mean {m:.5g} +- {se:.2g}  (load {t_load:.1f} s, render {min(times):.1f} s)", flush=True)
    if not args.no_ept:
        pair, t_load, times, n = P.render_ept(mi, "cornell", ICE_REAL_INDEX, spp, res)
        imgs["EPT"] = pair
        m, se = P.mean_and_se(*pair)
        numbers["images"]["EPT"] = dict(spheres=n, mean=m, se=se, load_s=t_load, render_s=min(times))
        print(f"EPT      mean {m:.5g} +- {se:.2g}  ({n} spheres; load {t_load:.1f} s, render {min(times):.1f} s)", flush=True)
    for a, b in PAIRS:
        if a in imgs and b in imgs:
            c = compare(imgs[a], imgs[b])
            numbers["pairs"][f"{a} vs {b}"] = c
            print(f"{a:>7s} vs {b:<4s}: mean {c['rel_diff']:+.4f} +- {c['rel_diff_se']:.4f}, "
                  f"RMS(diff)/noise {c['rms_over_noise']:.2f}")
    out = pathlib.Path(args.out)
    mean = {k: 0.5 * (v[0] + v[1]) for k, v in imgs.items()}
    fd_only = np.abs(mean["FD"] - mean["-FD"]) * 3
    row = [(f"{k}\nmean {numbers['images'][k]['mean']:.3g}", mean[k]) for k in ("EPT", "-FD", "FD", "default", "HG")
           if k in mean]
    row.append(("|FD - (-FD)| x 3\n(FD only)", fd_only))
    ref = next(i for i, (label, _) in enumerate(row) if label.startswith("default"))
    P.sheet([row], out / "fig12_13_cornell.png",
            f"CORNELL (Figs. 12-13): 1e5 ice grains of 1000 um; EPT, motes -FD / FD / default, HG; {spp} spp",
            reference=(0, ref))
    numbers["phase"] = phase_plot(out / "fig13_phase.png")
    P.save_numbers(out, "fig12_13_cornell", numbers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
