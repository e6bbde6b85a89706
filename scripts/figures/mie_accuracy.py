"""Lorenz–Mie accuracy against the independent oracle miepython (and mpmath at 40 digits where the two
disagree by more than 1e-6: there the motes error is taken against mpmath): Q_ext, Q_sca relative error
and the normalised phase function's relative error where f > 1e-8 max f, over random indices (absorbing
included) and size parameters up to 1e4.

    .venv/bin/python scripts/figures/mie_accuracy.py [--quick] [--out out]
"""

from __future__ import annotations

import sys
import pathlib

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

sys.path.insert(0, str(C.ROOT / "tests"))
from conftest import mie_reference  # noqa: E402  (40-digit mpmath Lorenz–Mie, the referee)


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    import miepython  # noqa: PLC0415

    rng = np.random.default_rng(20261122)
    n_cases = 12 if args.quick else 40
    fixed_x = [0.1, 1.0, 10.0, 100.0, 1000.0, 1e4]
    xs = np.concatenate([fixed_x, 10 ** rng.uniform(-1, 4, n_cases - len(fixed_x))])
    n_re = rng.uniform(1.05, 2.5, n_cases)
    kappa = np.where(rng.random(n_cases) < 0.3, 0.0, 10 ** rng.uniform(-4, np.log10(0.5), n_cases))
    theta = np.linspace(0.0, np.pi, 50)
    rows, worst = [], dict(q_ext=0.0, q_sca=0.0, phase=0.0)
    for x, n, k in zip(xs, n_re, kappa):
        m = complex(n, k)
        r = x * C.LAM / (2 * np.pi)
        cs = motes.cross_sections(r, C.LAM, m, method="mie")
        qe, qs = float(cs["ext"]) / (np.pi * r * r), float(cs["sca"]) / (np.pi * r * r)
        ref = miepython.efficiencies_mx(m, x)
        s1, s2 = miepython.S1_S2(m, x, np.cos(theta), norm="one")
        f_ref = (np.abs(s1) ** 2 + np.abs(s2) ** 2) / 2
        f = motes.phase_function(r, C.LAM, m, theta, method="mie")
        mask = f_ref > 1e-8 * f_ref.max()
        e = dict(q_ext=abs(qe / ref[0] - 1), q_sca=abs(qs / ref[1] - 1), phase=float(np.max(np.abs(f[mask] / f_ref[mask] - 1))))
        referee = ""
        if e["phase"] > 1e-6:
            # Disagreement above 1e-6: ask the 40-digit reference which code is right at those angles.
            bad = np.flatnonzero(mask & (np.abs(f / np.where(f_ref > 0, f_ref, 1) - 1) > 1e-6))
            f_mp, _, _ = mie_reference(float(x), m, np.cos(theta[bad]))
            ours = float(np.max(np.abs(f[bad] / f_mp - 1)))
            theirs = float(np.max(np.abs(f_ref[bad] / f_mp - 1)))
            referee = f"mpmath: motes {ours:.1e}, miepython {theirs:.1e}"
            e["phase"] = max(ours, float(np.max(np.abs(np.delete(f[mask] / f_ref[mask] - 1, np.searchsorted(np.flatnonzero(mask), bad))), initial=0.0)))
        for key in worst:
            worst[key] = max(worst[key], e[key])
        rows.append([f"{x:.4g}", f"{n:.3f}+{k:.2g}i", e["q_ext"], e["q_sca"], e["phase"], referee])
    C.print_table(f"Mie vs miepython {miepython.__version__}: relative errors over {n_cases} random (m, x), 50 angles",
                  ["x", "m", "Q_ext", "Q_sca", "phase fn (f > 1e-8 max)", "referee where miepython is off > 1e-6"], rows)
    C.print_table("worst case", ["Q_ext", "Q_sca", "phase function"], [[worst["q_ext"], worst["q_sca"], worst["phase"]]])
    C.finish(args, sw, out / "mie_accuracy.json", worst=worst, rows=rows)


if __name__ == "__main__":
    main()
