"""Paper Fig. 22 / 23 (App. E): (|S1|+|S2|)/2 of GOA with p_max = 1, 2, 3, 4 and 100.

    .venv/bin/python scripts/figures/fig22_orders.py [--out out/] [--quick]

eta = 1.33 (Fig. 22) and 1.40 (Fig. 23), (r, lambda) in {10, 100} um x {0.4, 0.6} um, 1800 angles
(--quick: 600 angles, only lambda = 0.6 um). GOA with the defaults (regularised, edge term).
Outputs ``fig22_orders_eta1.33.png``, ``fig23_orders_eta1.40.png`` and ``fig22_orders.json``. Prints the
RelMSE of (|S1|+|S2|)/2 with p_max = 1..4 against p_max = 100, and (for context) of p_max = 3 and 100
against Lorenz-Mie.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

ETAS = [(1.33, 22), (1.40, 23)]
P_LIST = [1, 2, 3, 4, 100]


def main() -> None:
    args, out, sw, motes = C.start(__doc__)

    theta = np.linspace(0.0, np.pi, 600) if args.quick else C.THETA
    deg = np.degrees(theta)
    combos = [(r, lam) for r in (10.0, 100.0) for lam in ((0.6,) if args.quick else (0.4, 0.6))]

    plt = C.plt()
    rows = []
    records = []
    bad = []
    for eta, fig_no in ETAS:
        fig, axes = plt.subplots(len(combos), 1, figsize=(11, 2.9 * len(combos)), squeeze=False)
        for ax, (r, lam) in zip(axes[:, 0], combos):
            amps = {}
            for p in P_LIST:
                s1, s2 = motes.goa_amplitudes(r, lam, eta, theta, p_max=p)
                if not (np.all(np.isfinite(s1)) and np.all(np.isfinite(s2))):
                    bad.append(dict(eta=eta, r=r, lam=lam, p_max=p))
                amps[p] = C.amp_mean(s1, s2)
            mie = C.amp_mean(*motes.mie_amplitudes(r, lam, eta, theta))
            ref = amps[100]
            rel = {p: C.relmse(amps[p], ref) for p in P_LIST[:-1]}
            rel_mie3 = C.relmse(amps[3], mie)
            rel_mie100 = C.relmse(amps[100], mie)
            rows.append([eta, r, lam, float(motes.size_parameter(r, lam))] + [rel[p] for p in P_LIST[:-1]] + [rel_mie3, rel_mie100])
            records.append(dict(eta=eta, r_um=r, wavelength_um=lam, relmse_vs_p100={str(p): v for p, v in rel.items()},
                                relmse_p3_vs_mie=rel_mie3, relmse_p100_vs_mie=rel_mie100))
            styles = {1: ("tab:green", 0.8), 2: ("tab:orange", 0.8), 3: ("tab:red", 0.9), 4: ("tab:purple", 0.8), 100: ("k", 1.1)}
            ax.plot(deg, np.log10(mie), color="tab:blue", lw=0.5, alpha=0.35, label="Lorenz–Mie")
            for p in P_LIST:
                col, lw = styles[p]
                ax.plot(deg, np.log10(amps[p]), color=col, lw=lw, ls="-" if p != 100 else "--", label=f"p = {p}")
            ax.set_xlim(0, 180)
            ax.set_xticks(range(0, 181, 15))
            ax.set_ylabel("log10 (|S1|+|S2|)/2")
            ax.set_title(f"η = {eta}, r = {r:g} µm, λ = {lam} µm", fontsize=9)
            ax.grid(True, alpha=0.3)
        axes[0, 0].legend(fontsize=7, ncol=6)
        axes[-1, 0].set_xlabel("θ (deg)")
        fig.suptitle(f"Fig. {fig_no}: GOA (|S1|+|S2|)/2 with increasing p_max, η = {eta}")
        C.save_fig(fig, out / f"fig{fig_no}_orders_eta{eta:.2f}.png", rect=(0, 0, 1, 0.97))

    C.print_table(
        f"Fig. 22 / 23: RelMSE of GOA (|S1|+|S2|)/2 with p_max = 1..4 against p_max = 100 ({theta.size} angles)",
        ["eta", "r (µm)", "λ (µm)", "x", "p=1", "p=2", "p=3", "p=4", "p=3 vs Mie", "p=100 vs Mie"],
        rows,
    )
    if bad:
        print(f"NON-FINITE amplitudes: {bad}")

    C.finish(args, sw, out / "fig22_orders.json", n_angles=int(theta.size), results=records, nonfinite=bad)


if __name__ == "__main__":
    main()
