"""Why GOA misses RelMSE <= 0.01 at r = 2 µm: the same comparison under three definitions of RelMSE, and
with variants of the forward diffraction (no edge term, the edge term with its complex phase ±π/3,
a Kirchhoff obliquity factor (1 + cos θ)/2), plus where in θ the error sits.

    .venv/bin/python scripts/figures/r2_variants.py [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    th = C.THETA
    deg = np.degrees(th)
    rows_def, rows_var, rows_loc = [], [], []
    for eta in (1.33, 1.49, 1.56):
        for r in (2.0, 3.0):
            x = float(motes.size_parameter(r, C.LAM))
            m1, m2 = motes.mie_amplitudes(r, C.LAM, eta, th)
            g1, g2 = motes.goa_amplitudes(r, C.LAM, eta, th)
            mm, gg = C.amp_mean(m1, m2), C.amp_mean(g1, g2)
            per_angle = float(np.mean((gg - mm) ** 2 / mm**2))
            log_def = float(np.mean((np.log10(gg) - np.log10(mm)) ** 2) / np.mean(np.log10(mm) ** 2))
            rows_def.append([eta, r, C.relmse(gg, mm), per_angle, log_def])
            # Diffraction variants: rebuild S = rays + factor·S_D from the parts.
            d_on, _ = motes.goa_amplitudes(r, C.LAM, eta, th, p_max=0, edge_correction=False)
            d_off, _ = motes.goa_amplitudes(r, C.LAM, eta, th, p_max=0, diffraction=False)
            s_d = (d_on - d_off).real
            r1, r2 = motes.goa_amplitudes(r, C.LAM, eta, th, diffraction=False)
            variants = {"no edge term": 1.0, "edge, real (default)": np.sqrt(1 + (1.9923861 * x ** (-2 / 3) - 0.7153537 * x ** (-4 / 3)))}
            for name, psi in (("edge, phase +π/3", np.pi / 3), ("edge, phase −π/3", -np.pi / 3)):
                variants[name] = 1 + 0.996193 / np.cos(psi) * np.exp(1j * psi) * x ** (-2 / 3)
            variants["default × (1+cos θ)/2"] = variants["edge, real (default)"] * (1 + np.cos(th)) / 2
            vals = [C.relmse(C.amp_mean(r1 + f * s_d, r2 + f * s_d), mm) for f in variants.values()]
            rows_var.append([eta, r, *vals])
            err = (gg - mm) ** 2 / np.mean(mm**2) / len(th)
            bands = [(0, 5), (5, 20), (20, 60), (60, 120), (120, 170), (170, 180.01)]
            rows_loc.append([eta, r, *[float(err[(deg >= lo) & (deg < hi)].sum()) for lo, hi in bands]])
    C.print_table("RelMSE of (|S1|+|S2|)/2, GOA vs Mie, under three definitions", ["eta", "r (µm)", "global (ours)", "per-angle relative", "log10, global"], rows_def)
    C.print_table("RelMSE (global) with variants of the forward diffraction", ["eta", "r (µm)", *variants.keys()], rows_var)
    C.print_table("Where the RelMSE (global, default GOA) comes from: contribution per θ band (degrees)",
                  ["eta", "r (µm)", "0–5", "5–20", "20–60", "60–120", "120–170", "170–180"], rows_loc)
    C.finish(args, sw, out / "r2_variants.json", definitions=rows_def, variants=rows_var, bands=rows_loc)


if __name__ == "__main__":
    main()
