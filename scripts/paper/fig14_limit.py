"""Paper Figs. 14-15: the continuous limit. The LIMIT scene's cube of N monodisperse ice grains at a
fixed optical depth (radius = 800 um x sqrt(1e4 / N)) beside Mitsuba's ``homogeneous`` medium with the
same bulk properties (``motes.homogeneous_equivalent``: sigma_t = C_t N / V, tabulated phase function,
the same forward-peak truncation), for N = 1e4 ... 1e8 (1e8 with ``storage = procedural``).

Claim (Sec. 6.4): "as N_tot increases, the appearance ... converges to that of a continuous medium";
Fig. 15: 1e8 grains match the continuous counterpart. Numbers per N, each configuration rendered twice
(sampler seeds 0 and 1, same grains):
* the relative difference of the image means, discrete - homogeneous, with its standard error;
* RMS over pixels of (discrete - homogeneous) divided by its Monte Carlo noise floor (from the two
  seeds): 1 when the images agree to their noise, > 1 by the grains' texture;
* the mean transmittance along the pixels' query cylinders over the homogeneous medium's (exact, no Monte
  Carlo noise; the grains' disks each remove exactly their C_ext, so this is 1 up to the grains' layout);
* the medium's graininess: std / mean over the cube's pixels of the optical depth per unit length along
  each pixel's query cylinder (exact, no Monte Carlo noise), expected ~1/sqrt(grains per cylinder).
Checks: the RMS ratio falls with N until it reaches the noise floor (within 10 % of 1) and stays there
(within 15 %), the graininess falls with N, and at the largest N the means agree within 2 SE and the
RMS ratio is within 10 % of 1. Writes docs/gallery/fig14_limit.png and .json.

    .venv/bin/python scripts/paper/fig14_limit.py [--full] [--spp N] [--res N]

Preview (128 spp, 128 px): about 3 minutes on 2 cores; --full: 1024 spp, 512 px.
"""

from __future__ import annotations

import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

COUNTS = (10**4, 10**5, 10**6, 10**7, 10**8)
SIDE_M = 0.2  # the cube of grains, 20 cm
FOV = 36.0  # the scene's
BOX = ((-10.0, 0.0, -10.0), (10.0, 20.0, 10.0))  # the cube of grains, scene units (cm)


def radius_um(n: int) -> float:
    return 800.0 * math.sqrt(1e4 / n)


def transmittance_ratio(tau_and_length, d: dict) -> tuple[float, float]:
    """Mean transmittance exp(-tau) along the camera's pixel cylinders through the grains (rays crossing at
    least a quarter of the longest path) over the homogeneous medium's exp(-sigma_t L) on the same rays,
    with its standard error over rays (``d``: the homogeneous equivalent): the extinction half of the comparison, free of Monte Carlo noise."""
    tau, length = tau_and_length
    keep = length > 0.25 * length.max()
    sigma = float(np.mean(np.asarray(d["sigma_t"]["value"]) * d["scale"]))
    t_d, t_h = np.exp(-tau[keep]), np.exp(-sigma * length[keep]).mean()
    return float(t_d.mean() / t_h), float(t_d.std() / np.sqrt(t_d.size) / t_h)


def reaches_noise_floor(ratios, floor_tol: float = 0.1, stay_tol: float = 0.15) -> bool:
    """RMS(D - H) / noise falls while above the floor (1: the images agree to their noise) and, once
    within ``floor_tol`` of it, stays within ``stay_tol`` (the estimate's own scatter at preview spp)."""
    k = next((i for i, r in enumerate(ratios) if abs(r - 1.0) < floor_tol), None)
    if k is None:
        return False
    return P.monotone(ratios[:k + 1], decreasing=True) and all(abs(r - 1.0) < stay_tol for r in ratios[k:])


def homogeneous(n: int, res: int) -> dict:
    """The homogeneous equivalent of the cube of N grains (``motes.homogeneous_equivalent``)."""
    import motes  # noqa: PLC0415

    sp = motes.Species(motes.Monodisperse(radius_um(n)), motes.Material("ice"))
    return motes.homogeneous_equivalent([sp], n / SIDE_M**3, scale_m=0.01, fov=FOV, film_width=res)


def main() -> int:
    args = P.parser(__doc__, spp=128, res=128, full_spp=1024, full_res=512).parse_args()
    spp, res = P.quality(args)
    mi = P.setup(args.variant)
    rows, top, bottom = [], [], []
    for n in COUNTS:
        params = dict(count=n, radius=f"{radius_um(n):.6g}", storage="procedural" if n > 10**7 else "compact")
        (d1, d2), t_load, times, tau = P.render(mi, "limit", spp, res, seeds=(0, 1),
                                                measure=lambda sc: P.pixel_optical_depth(mi, sc, BOX), **params)
        import motes  # noqa: PLC0415

        hom = homogeneous(n, res)
        scene = P.load_with_medium(mi, "limit", motes.equivalent.equivalent_xml(hom), spp, res)
        h1, h2 = (np.asarray(mi.render(scene, spp=spp, seed=s), dtype=np.float64)[..., :3] for s in (0, 1))
        md, sd = P.mean_and_se(d1, d2)
        mh, sh = P.mean_and_se(h1, h2)
        rel, rel_se = (md - mh) / mh, math.hypot(sd, sh) / mh
        diff = P.luminance(0.5 * (d1 + d2)) - P.luminance(0.5 * (h1 + h2))
        noise = np.mean(0.25 * (P.luminance(d1) - P.luminance(d2)) ** 2 + 0.25 * (P.luminance(h1) - P.luminance(h2)) ** 2)
        ratio = float(np.sqrt(np.mean(diff**2) / noise))
        g = P.medium_graininess(tau)
        t_ratio, t_se = transmittance_ratio(tau, hom)
        rows.append(dict(count=n, radius_um=radius_um(n), storage=params["storage"], mean_discrete=md,
                         mean_homogeneous=mh, rel_diff=rel, rel_diff_se=rel_se, rms_over_noise=ratio,
                         graininess=g, transmittance_ratio=t_ratio, transmittance_ratio_se=t_se, load_s=t_load,
                         render_s=min(times)))
        print(f"N {n:>9.0e}  r {radius_um(n):6.1f} um  mean D/H - 1 = {rel:+.4f} +- {rel_se:.4f}  "
              f"RMS(D-H)/noise {ratio:.2f}  graininess {g:.3f}  T_D/T_H {t_ratio:.4f} +- {t_se:.4f}  (load {t_load:.1f} s, render {min(times):.1f} s)",
              flush=True)
        top.append((f"N = {n:.0e}, r = {radius_um(n):.0f} um\nRMS/noise {ratio:.2f}, grain. {g:.2f}", 0.5 * (d1 + d2)))
        bottom.append((f"homogeneous\nmean D/H-1 = {rel:+.3f} +- {rel_se:.3f}", 0.5 * (h1 + h2)))
    falls = reaches_noise_floor([r["rms_over_noise"] for r in rows])
    grain_falls = P.monotone([r["graininess"] for r in rows], decreasing=True)
    last = rows[-1]
    converged = abs(last["rel_diff"]) < 2 * last["rel_diff_se"] and abs(last["rms_over_noise"] - 1) < 0.1
    print(f"RMS(D-H)/noise falls with N to the noise floor: {'PASS' if falls else 'FAIL'}; graininess falls with N: "
          f"{'PASS' if grain_falls else 'FAIL'}; N = {last['count']:.0e} matches homogeneous (mean within 2 SE, "
          f"RMS/noise within 10 % of 1): {'PASS' if converged else 'FAIL'}")
    out = pathlib.Path(args.out)
    P.sheet([top, bottom], out / "fig14_limit.png",
            f"LIMIT (Figs. 14-15): discrete (top) against homogeneous (bottom), optical depth ~1; {spp} spp",
            row_titles=["discrete", "homogeneous"], reference=(1, 0))
    P.save_numbers(out, "fig14_limit", {"spp": spp, "res": res, "variant": args.variant, "rows": rows,
                                        "rms_falls": falls, "graininess_falls": grain_falls, "converged": converged})
    return 0 if falls and grain_falls and converged else 1


if __name__ == "__main__":
    sys.exit(main())
