"""Benchmark: amplitude evaluations per second at 1800 angles — motes Mie, motes GOA and miepython.

    .venv/bin/python scripts/bench/bench_amplitudes.py [--out out/] [--quick]

One evaluation = (S1, S2) of one sphere at the 1800 angles of ``np.linspace(0, pi, 1800)``; eta = 1.33,
lambda = 0.6 um, r = 1, 10, 100, 1000 um, plus x = 1000 exactly (r = 1000 lambda / 2 pi). All three
codes are timed side by side in the same run, best of n (``time.perf_counter``; n adapted so that each
measurement takes ~0.5 s, at least 3; miepython at r = 1000 um, x ~ 10472, runs once and is skipped
with --quick). miepython: ``miepython.S1_S2(m, x, mu, norm='bohren')``, warmed up (numba JIT) before
timing. GOA *warm* = ray geometry cached by motes for the angle array (the case of a sweep over radii);
*cold* = a fresh angle array every call (geometry prepared each time).

Also checks agreement: miepython 3.3.0's ``norm='bohren'`` returns ``2 conj(S_BH)`` (its own
normalisation and the exp(+i w t) convention), so ``max|S_motes - conj(S_mp)/2| / max|S_motes|`` is printed.
Outputs ``bench_amplitudes.json`` and ``bench_amplitudes.png``.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

ETA = 1.33
_counter = [0]


def fresh_theta() -> np.ndarray:
    _counter[0] += 1
    th = C.THETA.copy()
    v = th[-1]
    for _ in range(_counter[0] + 1):
        v = np.nextafter(v, 0.0)
    th[-1] = v
    return th


def timed(fn, budget_s: float, n_min: int = 3, n_max: int = 200, once: bool = False):
    """Best time of n calls; n chosen from a first call so that the total is ~budget_s."""
    t0, res = C.best_of(fn, 1)
    if once:
        return t0, res, 1
    n = int(min(n_max, max(n_min, budget_s / max(t0, 1e-9))))
    t, res = C.best_of(fn, n)
    return min(t, t0), res, n + 1


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    import miepython  # noqa: PLC0415

    budget = 0.2 if args.quick else 0.5
    theta = C.THETA
    mu = np.cos(theta)
    miepython.S1_S2(ETA, 10.0, mu, norm="bohren")  # numba JIT warm-up
    motes.goa_amplitudes(1.0, C.LAM, ETA, theta)  # GOA geometry cache warm-up for this (eta, theta)

    cases = [(f"r = {r:g} µm", r) for r in (1.0, 10.0, 100.0, 1000.0)]
    cases.append(("x = 1000", 1000.0 * C.LAM / (2 * np.pi)))
    rows = []
    records = []
    for label, r in cases:
        x = float(motes.size_parameter(r, C.LAM))
        t_mie, (m1, m2), n_mie = timed(lambda: motes.mie_amplitudes(r, C.LAM, ETA, theta), budget)
        t_goa, _, n_goa = timed(lambda: motes.goa_amplitudes(r, C.LAM, ETA, theta), budget)
        t_goa_cold, _, n_cold = timed(lambda: motes.goa_amplitudes(r, C.LAM, ETA, fresh_theta()), budget, n_max=50)
        big = x > 5000
        if big and args.quick:
            t_mp, agree, n_mp = None, None, 0
            note = "miepython skipped (--quick)"
        else:
            t_mp, (p1, p2), n_mp = timed(lambda: miepython.S1_S2(ETA, x, mu, norm="bohren"), budget, once=big, n_max=50)
            scale = max(np.abs(m1).max(), np.abs(m2).max())
            agree = float(max(np.abs(m1 - np.conj(p1) / 2).max(), np.abs(m2 - np.conj(p2) / 2).max()) / scale)
            note = "miepython run once" if big else ""
        rec = dict(case=label, r_um=r, x=x, t_mie_s=t_mie, t_goa_warm_s=t_goa, t_goa_cold_s=t_goa_cold, t_miepython_s=t_mp,
                   n=dict(mie=n_mie, goa=n_goa, goa_cold=n_cold, miepython=n_mp), miepython_rel_diff=agree, note=note)
        records.append(rec)
        rows.append([label, x, 1 / t_mie, 1 / t_goa, 1 / t_goa_cold, (1 / t_mp) if t_mp else None,
                     (t_mp / t_mie) if t_mp else None, t_mie / t_goa, t_mie / t_goa_cold, agree, note])

    C.print_table(
        f"Amplitude evaluations per second (1800 angles, eta = {ETA}, lambda = {C.LAM} µm, single particle per call, best of n)",
        ["case", "x", "motes Mie /s", "motes GOA warm /s", "motes GOA cold /s", "miepython /s",
         "Mie: motes / miepython", "motes Mie / GOA warm", "motes Mie / GOA cold", "max rel diff vs miepython", "note"],
        rows,
    )

    plt = C.plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    xs = [r["x"] for r in records[:4]]
    ax.loglog(xs, [1 / r["t_mie_s"] for r in records[:4]], "o-", label="motes Mie")
    ax.loglog(xs, [1 / r["t_goa_warm_s"] for r in records[:4]], "s-", label="motes GOA (warm)")
    ax.loglog(xs, [1 / r["t_goa_cold_s"] for r in records[:4]], "s--", label="motes GOA (cold)")
    pts = [(r["x"], 1 / r["t_miepython_s"]) for r in records[:4] if r["t_miepython_s"]]
    if pts:
        ax.loglog(*zip(*pts), "^-", label="miepython 3.3.0")
    C.label(ax, "size parameter x (η = 1.33, λ = 0.6 µm, r = 1…1000 µm)", "evaluations / s (1800 angles)", "Amplitude throughput, best of n", legend=8)
    C.save_fig(fig, out / "bench_amplitudes.png")

    C.finish(args, sw, out / "bench_amplitudes.json", eta=ETA, wavelength_um=C.LAM, n_angles=int(theta.size),
             miepython=miepython.__version__, results=records)


if __name__ == "__main__":
    main()
