"""Paper Fig. 6: RelMSE of (|S1|+|S2|)/2, GOA vs Lorenz-Mie, against r (left) and the runtime ratio
t_Mie / t_GOA against r (right).

    .venv/bin/python scripts/figures/fig6_relmse_runtime.py [--out out/] [--quick]

lambda = 0.6 um, 1800 angles, GOA with the defaults (p_max = 3, regularised, edge term); the
paper-verbatim GOA (``regularise=False, edge_correction=False``) is shown dashed for comparison (its
glory singularity at theta = pi, which is on the grid, can dominate its RelMSE).

Radii: 60 log-spaced in [0.5, 200] um plus 1, 10, 100 um and, in full mode, 500 and 1000 um (--quick: 20 radii in
[0.5, 200] um plus 1, 10, 100 um). eta = 1.33, 1.49, 1.56 (paper), 0.75 (air bubble in a denser host,
relative index) and 1.5+0.01i (absorbing).

Timing: each (r, eta) is timed side by side in the same run, Mie and GOA each for the full 1800-angle
amplitude evaluation (``mie_amplitudes`` / ``goa_amplitudes``), best of 3 (``time.perf_counter``).
``motes`` caches the size-independent GOA ray geometry per (eta, p_max, angle array), so the GOA time
of a sweep over radii is the *warm* time (geometry reused); the *cold* time (a fresh angle array on
every call, so the geometry is prepared each time) is measured too and reported as a second ratio.

Outputs ``fig6_relmse_runtime.png`` and ``fig6_relmse_runtime.json``; prints, per eta, the max RelMSE
over r >= 2, 3, 5 um and the runtime ratios at r = 1, 10, 100, 1000 um.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

ETAS = [1.33, 1.49, 1.56, 0.75, 1.5 + 0.01j]
REPORT_R = [1.0, 10.0, 100.0, 1000.0]

_cold_counter = [0]


def fresh_theta() -> np.ndarray:
    """THETA with its last node nudged down by a new number of ulps: a new cache key every call."""
    _cold_counter[0] += 1
    th = C.THETA.copy()
    v = th[-1]
    for _ in range(_cold_counter[0] % 100000 + 1):
        v = np.nextafter(v, 0.0)
    th[-1] = v
    return th


def sweep(motes, radii, theta, reps: int) -> dict:
    """Per eta: RelMSE of GOA (ours and paper verbatim) vs Mie, and the Mie / GOA warm / GOA cold times, per radius."""
    res = {}
    for eta in ETAS:
        # warm the GOA geometry cache for this eta (the first call of a sweep pays it once)
        motes.goa_amplitudes(float(radii[0]), C.LAM, eta, theta)
        rel, rel_paper, t_mie, t_goa, t_goa_cold = [], [], [], [], []
        for r in radii:
            r = float(r)
            tm, (m1, m2) = C.best_of(lambda: motes.mie_amplitudes(r, C.LAM, eta, theta), reps)
            tg, (g1, g2) = C.best_of(lambda: motes.goa_amplitudes(r, C.LAM, eta, theta), reps)
            tc, _ = C.best_of(lambda: motes.goa_amplitudes(r, C.LAM, eta, fresh_theta()), reps)
            ok = all(np.all(np.isfinite(a)) for a in (m1, m2, g1, g2))
            if not ok:
                print(f"NON-FINITE amplitudes at eta={eta}, r={r}")
            rel.append(C.relmse(C.amp_mean(g1, g2), C.amp_mean(m1, m2)))
            p1, p2 = motes.goa_amplitudes(r, C.LAM, eta, theta, regularise=False, edge_correction=False)
            rel_paper.append(C.relmse(C.amp_mean(p1, p2), C.amp_mean(m1, m2)) if np.all(np.isfinite(p1)) and np.all(np.isfinite(p2)) else np.inf)
            t_mie.append(tm)
            t_goa.append(tg)
            t_goa_cold.append(tc)
        res[eta] = dict(relmse=np.array(rel), relmse_paper=np.array(rel_paper), t_mie=np.array(t_mie), t_goa=np.array(t_goa), t_goa_cold=np.array(t_goa_cold))
    return res


def relmse_table(res: dict, radii) -> None:
    """Print Fig. 6 (left) as a table: per eta, the max RelMSE over r >= 2, 3, 5 um."""
    rows = []
    for eta in ETAS:
        d = res[eta]
        row = [C.eta_label(eta)]
        for rmin in (2.0, 3.0, 5.0):
            sel = radii >= rmin
            i = int(np.argmax(d["relmse"][sel]))
            row += [d["relmse"][sel][i], radii[sel][i]]
        row.append(bool(d["relmse"][radii >= 2.0].max() < 0.01))
        row.append(d["relmse_paper"][radii >= 2.0].max())
        row.append(d["relmse_paper"][radii >= 5.0].max())
        rows.append(row)
    C.print_table(
        f"Fig. 6 (left): max RelMSE of (|S1|+|S2|)/2, GOA (p=3) vs Mie, lambda = {C.LAM} µm, {len(radii)} radii in [{radii[0]:g}, {radii[-1]:g}] µm",
        ["eta", "max r≥2", "at r (µm)", "max r≥3", "at r (µm)", "max r≥5", "at r (µm)", "< 0.01 for r ≥ 2",
         "paper-verbatim GOA: max r≥2", "paper-verbatim: max r≥5"],
        rows,
    )


def runtime_table(res: dict, radii) -> None:
    """Print Fig. 6 (right) as a table: the times and ratios at the radii of REPORT_R."""
    rows = []
    for eta in ETAS:
        d = res[eta]
        for rr in REPORT_R:
            k = np.where(np.isclose(radii, rr))[0]
            if k.size == 0:
                rows.append([C.eta_label(eta), rr, None, None, None, None, None])
                continue
            k = int(k[0])
            rows.append([C.eta_label(eta), rr, d["t_mie"][k] * 1e3, d["t_goa"][k] * 1e3, d["t_goa_cold"][k] * 1e3,
                         d["t_mie"][k] / d["t_goa"][k], d["t_mie"][k] / d["t_goa_cold"][k]])
    C.print_table(
        "Fig. 6 (right): runtime of one 1800-angle amplitude evaluation, best of 3, side by side (GOA warm = geometry cached, cold = fresh angle array)",
        ["eta", "r (µm)", "t_Mie (ms)", "t_GOA warm (ms)", "t_GOA cold (ms)", "t_Mie/t_GOA warm", "t_Mie/t_GOA cold"],
        rows,
    )


def plot(out: pathlib.Path, res: dict, radii) -> None:
    """``fig6_relmse_runtime.png``: RelMSE (left) and runtime ratio (right) against r."""
    plt = C.plt()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.6))
    ax = axes[0]
    for eta in ETAS:
        line, = ax.loglog(radii, res[eta]["relmse"], marker=".", ms=3, lw=0.9, label=f"η = {C.eta_label(eta)}")
        ax.loglog(radii, res[eta]["relmse_paper"], color=line.get_color(), lw=0.6, ls="--", alpha=0.6)
    ax.plot([], [], color="k", ls="--", lw=0.6, label="dashed: paper verbatim")
    ax.axhline(0.01, color="0.4", ls="--", lw=0.8, label="0.01")
    ax.axvline(2.0, color="0.6", ls=":", lw=0.8, label="r = 2 µm")
    C.label(ax, "r (µm)", "RelMSE of (|S1|+|S2|)/2", f"Fig. 6 left: GOA (p=3) vs Lorenz–Mie, λ = {C.LAM} µm", legend=8)
    ax = axes[1]
    for i, eta in enumerate(ETAS):
        col = f"C{i}"
        ax.loglog(radii, res[eta]["t_mie"] / res[eta]["t_goa"], color=col, lw=0.9, label=f"η = {C.eta_label(eta)} (warm)")
        ax.loglog(radii, res[eta]["t_mie"] / res[eta]["t_goa_cold"], color=col, lw=0.7, ls="--", alpha=0.7)
    ax.plot([], [], color="k", ls="--", lw=0.7, label="dashed: GOA cold")
    ax.axhline(1.0, color="0.5", lw=0.6)
    C.label(ax, "r (µm)", "t_Mie / t_GOA", "Fig. 6 right: runtime ratio, 1800 angles, best of 3", legend=7)
    C.save_fig(fig, out / "fig6_relmse_runtime.png")


def main() -> None:
    args, out, sw, motes = C.start(__doc__)

    n = 20 if args.quick else 60
    radii = list(np.geomspace(0.5, 200.0, n)) + [1.0, 10.0, 100.0] + ([] if args.quick else [500.0, 1000.0])
    radii = np.unique(np.round(radii, 12))
    reps = 3
    theta = C.THETA

    res = sweep(motes, radii, theta, reps)
    relmse_table(res, radii)
    runtime_table(res, radii)
    plot(out, res, radii)

    results = {C.eta_label(eta): {k: v for k, v in d.items()} for eta, d in res.items()}
    C.finish(args, sw, out / "fig6_relmse_runtime.json", wavelength_um=C.LAM, n_angles=int(theta.size), repetitions=reps,
             radii_um=radii, results=results)


if __name__ == "__main__":
    main()
