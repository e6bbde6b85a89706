"""The ``method="auto"`` policy: at which size parameter x is GOA good enough?

    .venv/bin/python scripts/figures/hybrid_threshold.py [--out out/] [--quick]

For eta in {1.1, 1.33, 1.49, 1.56, 2.0, 0.75, 1.5+0.01i, 1.33+0.001i} and 80 log-spaced size parameters
x in [5, 400] (--quick: 30), with r = x lambda / 2 pi, lambda = 0.6 um and 1800 angles: the RelMSE of
(|S1|+|S2|)/2, GOA (defaults: p_max = 3, regularised, edge term) vs Lorenz-Mie. Reports per eta the
smallest tested x_c such that RelMSE < 0.01 at every tested x >= x_c, the overall max, and whether every
eta satisfies RelMSE < 0.01 above ``motes.AUTO_SIZE_PARAMETER``. The error of ``method="auto"`` is the max
RelMSE over the x where auto uses GOA (``motes.resolve_method``: x >= AUTO_SIZE_PARAMETER except near the
degenerate axial rays of ``AXIAL_CAUSTIC_WINDOW``; Mie, error 0, elsewhere) and that of
``method="hybrid"`` (the paper's r >= 2 um) the max over x >= 2 pi 2 / 0.6 = 20.9. The switch points
are checked with ``motes.phase_function(method="auto" | "hybrid")`` just below and above them.
Outputs ``hybrid_threshold.png`` and ``hybrid_threshold.json``.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

ETAS = [1.1, 1.33, 1.49, 1.56, 2.0, 0.75, 1.5 + 0.01j, 1.33 + 0.001j]
TOL = 0.01


def threshold(x: np.ndarray, rel: np.ndarray, tol: float = TOL) -> float:
    """Smallest tested x_c with rel < tol at every tested x >= x_c (inf if the largest x fails)."""
    fail = np.where(~(rel < tol))[0]
    if fail.size == 0:
        return float(x[0])
    k = int(fail[-1]) + 1
    return float(x[k]) if k < x.size else float("inf")


def switch_check(motes, eta) -> dict:
    """phase_function with auto / hybrid equals Mie just below the switch and GOA just above it."""
    th = C.THETA
    res = {}
    x_auto = float(motes.AUTO_SIZE_PARAMETER)
    r_hyb = float(motes.HYBRID_RADIUS_UM)
    for name, below, above in (
        ("auto", C.radius_of_x(x_auto * (1 - 1e-6)), C.radius_of_x(x_auto * (1 + 1e-6))),
        ("hybrid", r_hyb * (1 - 1e-6), r_hyb * (1 + 1e-6)),
    ):
        d = {}
        for side, r in (("below", float(below)), ("above", float(above))):
            f = motes.phase_function(r, C.LAM, eta, th, method=name)
            fm = motes.phase_function(r, C.LAM, eta, th, method="mie")
            fg = motes.phase_function(r, C.LAM, eta, th, method="goa")
            d[side] = "mie" if np.array_equal(f, fm) else ("goa" if np.array_equal(f, fg) else "neither")
        res[name] = d
    return res


def sweep(motes, radii, theta):
    """RelMSE of GOA vs Mie per eta at the radii, and the (eta, r) where an amplitude was not finite."""
    res = {}
    bad = []
    for eta in ETAS:
        rel = []
        for r in radii:
            m1, m2 = motes.mie_amplitudes(float(r), C.LAM, eta, theta)
            g1, g2 = motes.goa_amplitudes(float(r), C.LAM, eta, theta)
            if not all(np.all(np.isfinite(a)) for a in (m1, m2, g1, g2)):
                bad.append(dict(eta=C.eta_label(eta), r_um=float(r)))
            rel.append(C.relmse(C.amp_mean(g1, g2), C.amp_mean(m1, m2)))
        res[eta] = np.array(rel)
    return res, bad


def summary_table(motes, xs, radii, res: dict, x_auto: float, x_hyb: float) -> dict:
    """Print the table of x_c and of the auto / hybrid errors per eta; return the summary per eta."""
    rows = []
    summary = {}
    for eta in ETAS:
        rel = res[eta]
        xc = threshold(xs, rel)
        # Where auto really uses GOA (x >= AUTO_SIZE_PARAMETER, except near degenerate axial rays).
        above = (motes.resolve_method(radii, C.LAM, eta, method="auto") == "goa")
        hyb = xs >= x_hyb
        i_all = int(np.argmax(rel))
        e_auto = float(rel[above].max()) if above.any() else 0.0
        x_auto_worst = float(xs[above][np.argmax(rel[above])]) if above.any() else float("nan")
        e_hyb = float(rel[hyb].max())
        x_hyb_worst = float(xs[hyb][np.argmax(rel[hyb])])
        ok = bool(e_auto < TOL)
        summary[C.eta_label(eta)] = dict(x_c=xc, max_relmse=float(rel[i_all]), at_x=float(xs[i_all]), auto_error=e_auto, auto_worst_x=x_auto_worst,
                                         auto_ok=ok, hybrid_error=e_hyb, hybrid_worst_x=x_hyb_worst)
        rows.append([C.eta_label(eta), xc, rel[i_all], xs[i_all], e_auto, x_auto_worst, ok, e_hyb, x_hyb_worst])
    xcs = [s["x_c"] for s in summary.values()]
    rows.append(["**all**", max(xcs), max(s["max_relmse"] for s in summary.values()), None,
                 max(s["auto_error"] for s in summary.values()), None, all(s["auto_ok"] for s in summary.values()),
                 max(s["hybrid_error"] for s in summary.values()), None])
    C.print_table(
        f"auto policy: RelMSE of (|S1|+|S2|)/2, GOA vs Mie, {xs.size} x in [5, 400], lambda = {C.LAM} µm; "
        f"AUTO_SIZE_PARAMETER = {x_auto:g}, hybrid = r ≥ {motes.HYBRID_RADIUS_UM:g} µm (x ≥ {x_hyb:.1f})",
        ["eta", "x_c (RelMSE<0.01 for all x ≥ x_c)", "max RelMSE (x≥5)", "at x", "auto error (max where auto uses GOA)", "at x",
         f"auto < {TOL}", "hybrid error (max, r ≥ 2 µm)", "at x"],
        rows,
    )
    return summary


def plot(out: pathlib.Path, xs, res: dict, x_auto: float, x_hyb: float) -> None:
    """``hybrid_threshold.png``: RelMSE against x per eta, with the thresholds."""
    plt = C.plt()
    fig, ax = plt.subplots(figsize=(8, 5))
    for eta in ETAS:
        ax.loglog(xs, res[eta], lw=0.9, marker=".", ms=3, label=f"η = {C.eta_label(eta)}")
    ax.axhline(TOL, color="0.3", ls="--", lw=0.8, label=f"RelMSE = {TOL}")
    ax.axvline(x_auto, color="tab:red", ls="-", lw=1.0, label=f"AUTO_SIZE_PARAMETER = {x_auto:g}")
    ax.axvline(x_hyb, color="0.5", ls=":", lw=1.0, label=f"hybrid r = 2 µm (x = {x_hyb:.1f})")
    ax.set_xlabel("size parameter x = 2πr/λ")
    ax.set_ylabel("RelMSE of (|S1|+|S2|)/2, GOA vs Mie")
    ax.set_title(f"GOA error vs size parameter (λ = {C.LAM} µm, 1800 angles)")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(True, which="both", alpha=0.3)
    C.save_fig(fig, out / "hybrid_threshold.png")


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    x_auto = float(motes.AUTO_SIZE_PARAMETER)
    x_hyb = float(motes.size_parameter(motes.HYBRID_RADIUS_UM, C.LAM))

    nx = 30 if args.quick else 80
    xs = np.geomspace(5.0, 400.0, nx)
    radii = C.radius_of_x(xs)
    theta = C.THETA

    res, bad = sweep(motes, radii, theta)
    summary = summary_table(motes, xs, radii, res, x_auto, x_hyb)
    xcs = [s["x_c"] for s in summary.values()]
    worst_eta = max(summary, key=lambda k: summary[k]["x_c"])
    print(f"largest x_c = {max(xcs):.3g} (eta = {worst_eta}); AUTO_SIZE_PARAMETER = {x_auto:g}: "
          f"{'every eta has RelMSE < 0.01 above it' if all(s['auto_ok'] for s in summary.values()) else 'NOT every eta has RelMSE < 0.01 above it'}")
    checks = {C.eta_label(eta): switch_check(motes, eta) for eta in (1.33, 0.75)}
    print(f"switch check (phase_function just below / above the threshold): {checks}")
    if bad:
        print(f"NON-FINITE amplitudes: {bad}")

    plot(out, xs, res, x_auto, x_hyb)
    C.finish(
        args, sw, out / "hybrid_threshold.json", wavelength_um=C.LAM, tol=TOL, auto_size_parameter=x_auto, hybrid_x=x_hyb,
        x=xs, relmse={C.eta_label(e): v for e, v in res.items()}, summary=summary, largest_x_c=max(xcs), worst_eta=worst_eta,
        switch_check=checks, nonfinite=bad)


if __name__ == "__main__":
    main()
