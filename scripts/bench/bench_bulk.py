"""Bulk optical properties (issue 3): build time of the paper's ice medium at 8 wavelengths, quadrature
against Monte Carlo over sampled radii, tabulated phase functions against direct evaluation, and
Fig. 8-style ensemble phase functions.

    .venv/bin/python scripts/bench/bench_bulk.py [--quick] [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

LAM8 = np.linspace(0.40, 0.75, 8)
N0 = 1e4


def build_cost(motes, ice):
    """Print the build-cost table (with and without phase tables, and from the disk cache); return the three times."""
    import os  # noqa: PLC0415
    import tempfile  # noqa: PLC0415

    os.environ["MOTES_CACHE_DIR"] = tempfile.mkdtemp(prefix="motes-bench-cache-")
    t_full, b = C.best_of(lambda: motes.bulk_properties(ice, N0, LAM8, cache=False), 3)
    t_coef, _ = C.best_of(lambda: motes.bulk_properties(ice, N0, LAM8, phase=False, cache=False), 3)
    motes.bulk_properties(ice, N0, LAM8)  # fills the cache
    t_hit, _ = C.best_of(lambda: motes.bulk_properties(ice, N0, LAM8), 5)
    C.print_table("Build cost, ice (eta 1.31), log-normal r_g = 800 um, sigma_g = 4, 8 wavelengths 0.40–0.75 um (best of 3)",
                  ["what", "seconds", "angles per table", "radius nodes"],
                  [["coefficients + phase tables", t_full, b["theta"].size, len(ice.psd.quadrature()[0])],
                   ["coefficients only", t_coef, 0, len(ice.psd.quadrature()[0])],
                   ["coefficients + phase tables, from the disk cache", t_hit, b["theta"].size, len(ice.psd.quadrature()[0])]])
    return t_full, t_coef, t_hit


def quadrature_vs_monte_carlo(motes, quick: bool) -> None:
    """Print the table of the quadrature's sigma_t, sigma_s against Monte Carlo over sampled radii."""
    n_mc = 100_000 if quick else 1_000_000
    rows = []
    for psd, eta in [(motes.LogNormal(800.0, 4.0), 1.31), (motes.LogNormal(5.0, 2.0), 1.33), (motes.LogNormal(50.0, 1.2), 1.5 + 0.001j),
                     (motes.Mixture([(0.995, motes.LogNormal(100.0, 1.0)), (0.005, motes.LogNormal(800.0, 2.0))]), 1.31)]:
        q = motes.bulk_properties(motes.Species(psd, eta), N0, 0.55, phase=False)
        r = psd.sample(n_mc, seed=9)
        cs = motes.cross_sections(r, 0.55, eta, asymmetry=False)
        row = [type(psd).__name__ + str(getattr(psd, "median_um", "")) + "/" + str(getattr(psd, "sigma_g", "")), C.eta_label(eta)]
        for key, col in (("sigma_t", "ext"), ("sigma_s", "sca")):
            mc = N0 * cs[col] * 1e-12
            row += [q[key][0] / mc.mean() - 1, mc.std() / np.sqrt(mc.size) / mc.mean()]
        rows.append(row)
    C.print_table(f"Quadrature vs Monte Carlo over {n_mc:g} sampled radii (lambda 0.55 um): relative difference and MC standard error",
                  ["PSD", "eta", "sigma_t diff", "sigma_t MC s.e.", "sigma_s diff", "sigma_s MC s.e."], rows)


def tabulated_vs_direct(motes) -> None:
    """Print the table of tabulated phase functions against direct evaluation at off-node angles."""
    rows = []
    for label, psd in [("mono 1000 um, lobe θ < 10/α", motes.Monodisperse(1000.0)), ("mono 1000 um", motes.Monodisperse(1000.0)),
                       ("mono 100 um", motes.Monodisperse(100.0)), ("mono 2 um", motes.Monodisperse(2.0)),
                       ("lognormal 800/1.2", motes.LogNormal(800.0, 1.2)), ("lognormal 800/2", motes.LogNormal(800.0, 2.0)),
                       ("lognormal 800/4", motes.LogNormal(800.0, 4.0)), ("lognormal 20/2", motes.LogNormal(20.0, 2.0)),
                       ("lognormal 20/4", motes.LogNormal(20.0, 4.0))]:
        sp = motes.Species(psd, 1.31)
        for refine in (0.0, 0.005):
            t0 = C.Stopwatch()
            bb = motes.bulk_properties(sp, N0, 0.55, refine_tol=refine, cache=False)
            build = t0()
            th = bb["theta"]
            mid = 0.5 * (th[1:] + th[:-1])
            width = np.diff(th)
            if isinstance(psd, motes.Monodisperse):
                direct = motes.phase_function(psd.radius_um, 0.55, 1.31, mid)
            else:
                direct = motes.bulk_properties(sp, N0, 0.55, theta=np.concatenate([[0.0], mid, [np.pi]]), cache=False)["phase"][0][1:-1]
            m = direct > 1e-6 * direct.max()
            if "lobe" in label:
                m &= mid < 10 / (2 * np.pi * psd.radius_um / 0.55)
            rel = np.abs(motes.PhaseTable.from_bulk(bb).eval(mid)[m] / direct[m] - 1)
            jump = width[m] < 1e-9  # intervals bisected down onto a discontinuity of GOA (rainbow edge, pi/2)
            rows.append([label, refine, th.size, build, float(np.mean(rel < 0.01)), float(np.quantile(rel, 0.99)), float(rel.max()),
                         float(rel[~jump].max()) if (~jump).any() else 0.0, int(jump.sum())])
    C.print_table("Tabulated phase function vs direct evaluation at the mid-points between nodes, where f > 1e-6 max (λ 0.55 µm)",
                  ["case", "refine_tol", "angles", "build s", "fraction within 1 %", "99th pct", "max", "max off GOA's jumps", "intervals on a jump"], rows)


def plot_ensemble_phase(motes, out: pathlib.Path) -> None:
    """``fig8_ensemble_phase.png``: ensemble phase functions of ice clouds (cf. paper Fig. 8)."""
    plt = C.plt()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for psd in [motes.LogNormal(1.0, 1.5), motes.LogNormal(10.0, 2.0), motes.LogNormal(100.0, 2.0), motes.LogNormal(800.0, 4.0), motes.Uniform(1.0, 100.0)]:
        bb = motes.bulk_properties(motes.Species(psd, 1.31), N0, 0.55)
        ax.loglog(np.degrees(bb["theta"][1:]), bb["phase"][0][1:], lw=0.8, label=f"{psd!r}"[:40] + f"  g={bb['g'][0]:.3f}")
    C.label(ax, "θ (deg)", "ensemble phase function (1/sr)", "Ensemble phase functions of ice clouds, λ = 0.55 µm (cf. paper Fig. 8)", legend=6)
    C.save_fig(fig, out / "fig8_ensemble_phase.png")


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    ice = motes.Species(motes.LogNormal(800.0, 4.0), 1.31)

    # 1. build cost, side by side: with and without phase tables, and served from the disk cache
    t_full, t_coef, t_hit = build_cost(motes, ice)
    # 2. quadrature vs Monte Carlo
    quadrature_vs_monte_carlo(motes, args.quick)
    # 3. tabulated vs direct at off-node angles (mid-points), where f > 1e-6 max; default grid and the
    #    adaptively refined one (refine_tol = 0.005). "Direct" = the single-particle phase function (exact
    #    normalisation) for monodisperse grains, the ensemble evaluated at the mid-points otherwise.
    tabulated_vs_direct(motes)
    # 4. Fig. 8-style plot
    plot_ensemble_phase(motes, out)
    C.finish(args, sw, out / "bench_bulk.json", build_s=t_full, build_coefficients_s=t_coef, cache_hit_s=t_hit)


if __name__ == "__main__":
    main()
