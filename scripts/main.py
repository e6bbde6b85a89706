"""The main job until the renderer lands: cross sections of ice spheres at three wavelengths and the bulk
properties of the paper's ice cloud (tables on stdout), single-particle and ensemble phase functions (PNG
in out/).

    .venv/bin/python scripts/main.py [--out out]
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

import motes

# Complex refractive index of ice (Warren & Brandt 2008, J. Geophys. Res. 113, D14220), tabulated in motes.
ICE = {lam: complex(motes.Material("ice").index(lam)[0]) for lam in (0.45, 0.55, 0.65)}
RADII_UM = [0.1, 1.0, 2.0, 10.0, 100.0, 800.0, 2000.0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="out", help="folder for the figures")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    print(f"{'lambda/um':>9} {'eta':>6} {'r/um':>8} {'alpha':>10} {'method':>6} {'C_ext/um^2':>13} {'Q_ext':>8} {'g':>7}")
    for lam, eta in ICE.items():
        cs = motes.cross_sections(RADII_UM, lam, eta, method="auto")
        methods = motes.resolve_method(RADII_UM, lam, eta, method="auto")
        for i, r in enumerate(RADII_UM):
            alpha = float(motes.size_parameter(r, lam))
            method = methods[i]
            q = cs["ext"][i] / (np.pi * r * r)
            print(f"{lam:9.2f} {eta.real:6.4f} {r:8.1f} {alpha:10.2f} {method:>6} {cs['ext'][i]:13.5g} {q:8.4f} {cs['g'][i]:7.4f}")

    cloud = motes.Species(motes.LogNormal(800.0, 4.0), motes.Material("ice"))
    bulk = motes.bulk_properties(cloud, 1e4, list(ICE))
    print("\nIce cloud, log-normal r_g = 800 um, sigma_g = 4, 1e4 particles per m^3 (paper Sec. 6):")
    print(f"{'lambda/um':>9} {'sigma_t/m^-1':>13} {'albedo':>10} {'g':>7}")
    for i, lam in enumerate(ICE):
        print(f"{lam:9.2f} {bulk['sigma_t'][i]:13.5g} {bulk['albedo'][i]:10.7f} {bulk['g'][i]:7.4f}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    theta = np.linspace(0.0, np.pi, 3601)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in [0.5, 2.0, 10.0, 100.0]:
        f = motes.phase_function(r, 0.55, ICE[0.55], theta)
        ax.semilogy(np.degrees(theta), f, label=f"r = {r:g} um")
    ax.set_xlabel("scattering angle (deg)")
    ax.set_ylabel("phase function f_p (1/sr)")
    ax.set_title("Ice spheres at 550 nm (motes, method='auto')")
    ax.legend()
    fig.tight_layout()
    path = out / "ice_phase_functions.png"
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, lam in enumerate(ICE):
        ax.loglog(np.degrees(bulk["theta"][1:]), bulk["phase"][i][1:], label=f"{lam} um")
    ax.set_xlabel("scattering angle (deg)")
    ax.set_ylabel("ensemble phase function (1/sr)")
    ax.set_title("Ice cloud r_g = 800 um, sigma_g = 4 (motes.bulk_properties)")
    ax.legend()
    fig.tight_layout()
    path = out / "ice_cloud_phase_function.png"
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
