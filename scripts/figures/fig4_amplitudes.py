"""Paper Fig. 4 (eta = 1.33) and Fig. 24 / 25 (eta = 1.49, 1.56): log10|S1| and log10|S2| against the
scattering angle, Lorenz-Mie vs GOA (p_max = 3, defaults), lambda = 0.6 um, r = 0.1, 1, 2, 10, 100 um.

    .venv/bin/python scripts/figures/fig4_amplitudes.py [--out out/] [--quick]

1800 angles in [0, pi] (--quick: 600). Outputs ``fig4_amplitudes_eta1.33.png`` (|S1| upper row, |S2|
lower row, as the paper), ``fig24_S1_eta1.49_1.56.png``, ``fig25_S2_eta1.49_1.56.png`` and
``fig4_amplitudes.json``. Prints the RelMSE (GOA vs Mie) of (|S1|+|S2|)/2, |S1| and |S2| per r and eta.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

RADII = [0.1, 1.0, 2.0, 10.0, 100.0]
ETAS = [1.33, 1.49, 1.56]


def log10_abs(s):
    a = np.abs(s)
    with np.errstate(divide="ignore"):
        return np.where(a > 0, np.log10(np.where(a > 0, a, 1.0)), np.nan)


def panel(ax, deg, mie, goa, title, ylabel):
    ax.plot(deg, log10_abs(mie), color="tab:blue", lw=0.8, label="Lorenz–Mie")
    ax.plot(deg, log10_abs(goa), color="tab:red", lw=0.7, alpha=0.85, label="GOA (p=3)")
    ax.set_xlim(0, 180)
    ax.set_xticks([0, 45, 90, 135, 180])
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("θ (deg)")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)


def main() -> None:
    args, out, sw, motes = C.start(__doc__)

    theta = np.linspace(0.0, np.pi, 600) if args.quick else C.THETA
    deg = np.degrees(theta)
    res = {}
    rows = []
    bad = []
    for eta in ETAS:
        for r in RADII:
            m1, m2 = motes.mie_amplitudes(r, C.LAM, eta, theta)
            g1, g2 = motes.goa_amplitudes(r, C.LAM, eta, theta, p_max=3)
            for name, arr in (("mie", (m1, m2)), ("goa", (g1, g2))):
                if not (np.all(np.isfinite(arr[0])) and np.all(np.isfinite(arr[1]))):
                    bad.append(dict(eta=eta, r=r, method=name))
            rm = C.relmse(C.amp_mean(g1, g2), C.amp_mean(m1, m2))
            rm1 = C.relmse(np.abs(g1), np.abs(m1))
            rm2 = C.relmse(np.abs(g2), np.abs(m2))
            res[(eta, r)] = dict(m1=m1, m2=m2, g1=g1, g2=g2)
            rows.append([eta, r, float(motes.size_parameter(r, C.LAM)), rm, rm1, rm2])

    C.print_table(
        f"Fig. 4 / 24 / 25: RelMSE of GOA (p=3) vs Lorenz–Mie, lambda = {C.LAM} µm, {theta.size} angles",
        ["eta", "r (µm)", "x", "RelMSE (|S1|+|S2|)/2", "RelMSE |S1|", "RelMSE |S2|"],
        rows,
    )
    if bad:
        print(f"NON-FINITE amplitudes: {bad}")

    plt = C.plt()
    # Fig. 4: eta = 1.33, |S1| upper row, |S2| lower row
    fig, axes = plt.subplots(2, len(RADII), figsize=(17, 6.4))
    for j, r in enumerate(RADII):
        d = res[(1.33, r)]
        panel(axes[0, j], deg, d["m1"], d["g1"], f"r = {r:g} µm", "log10 |S1|")
        panel(axes[1, j], deg, d["m2"], d["g2"], f"r = {r:g} µm", "log10 |S2|")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Fig. 4: η = 1.33, λ = {C.LAM} µm (blue Mie, red GOA)")
    C.save_fig(fig, out / "fig4_amplitudes_eta1.33.png", rect=(0, 0, 1, 0.97))

    # Fig. 24 (|S1|) and Fig. 25 (|S2|): eta = 1.49 upper row, 1.56 lower row
    for fig_no, comp in ((24, 1), (25, 2)):
        fig, axes = plt.subplots(2, len(RADII), figsize=(17, 6.4))
        for i, eta in enumerate(ETAS[1:]):
            for j, r in enumerate(RADII):
                d = res[(eta, r)]
                panel(axes[i, j], deg, d[f"m{comp}"], d[f"g{comp}"], f"η = {eta}, r = {r:g} µm", f"log10 |S{comp}|")
        axes[0, 0].legend(fontsize=8)
        fig.suptitle(f"Fig. {fig_no}: log10|S{comp}|, η = 1.49 (top), 1.56 (bottom), λ = {C.LAM} µm (blue Mie, red GOA)")
        C.save_fig(fig, out / f"fig{fig_no}_S{comp}_eta1.49_1.56.png", rect=(0, 0, 1, 0.97))

    relmse = [dict(eta=row[0], r_um=row[1], x=row[2], relmse_mean=row[3], relmse_S1=row[4], relmse_S2=row[5]) for row in rows]
    C.finish(args, sw, out / "fig4_amplitudes.json", wavelength_um=C.LAM, n_angles=int(theta.size), relmse=relmse, nonfinite=bad)


if __name__ == "__main__":
    main()
