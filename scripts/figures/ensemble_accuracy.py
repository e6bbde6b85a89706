"""Accuracy of ensemble tables (issue 9).

9.2: ``bulk_properties(theta=...)`` — g and f(theta) with a caller's angle list, now and as before the fix
(the old behaviour — the phase function normalised and g integrated by trapezoid over the caller's angles —
is re-derived from the same exact intensities), against miepython's g (water, r = 1.7 um, lambda 0.55 um).

9.3: default tables (no refine_tol) against an independent reference — miepython amplitudes integrated
over the log-normal PSD on a radius grid 0.005 apart in x (``tests/conftest.py: lognormal_mie_phase``) —
at 0, 30, 90, 150, 170, 179 and 180 deg, water (1.33) and ice-like (1.31) droplets, medians 1, 3, 10 um,
sigma_g 1.2, 1.5, 2.0, lambda 0.55 um: before (``mie_dx=0``: Gauss-Legendre panels of 0.05 in ln r) and
now (the default ``mie_dx``), for ``method="mie"`` (the table's numerical error) and the default
``"auto"`` (which adds GOA's own error above x = 60), with the build time of each table. The reference's
self-check is its difference to the same sum on every other radius. ``--quick``: three cases.
(r_g 10 um, sigma_g 2 is left out: its reference reaches x ~ 1e4, ~10 min of miepython.)

    .venv/bin/python scripts/figures/ensemble_accuracy.py [--quick] [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402


def trapezoid_on(theta, f):
    """The old behaviour: f normalised and g integrated by trapezoid over the caller's angles."""
    w = 2 * np.pi * np.sin(theta)
    f = f / np.trapezoid(f * w, theta)
    return f, float(np.trapezoid(f * w * np.cos(theta), theta))


def caller_angles(motes) -> None:
    import miepython  # noqa: PLC0415

    sp = motes.Species(motes.Monodisperse(1.7), 1.33)
    g_mie = miepython.efficiencies_mx(1.33, 2 * np.pi * 1.7 / 0.55)[3]
    table = motes.bulk_properties(sp, 1e6, 0.55, cache=False)
    rows = []
    for label, th in [("8 uniform in [0, pi]", np.linspace(0, np.pi, 8)),
                      ("8: 0, 10, 30, 60, 90, 120, 150, 180 deg", np.radians([0.0, 10, 30, 60, 90, 120, 150, 180])),
                      ("50 uniform in [0, pi]", np.linspace(0, np.pi, 50)),
                      ("default (internal grid)", None)]:
        b = motes.bulk_properties(sp, 1e6, 0.55, theta=th, cache=False)
        t, f = b["theta"], b["phase"][0]
        f_old, g_old = trapezoid_on(t, f)
        exact = motes.phase_function(1.7, 0.55, 1.33, t)  # single particle, exact Mie normalisation
        i10 = int(np.argmin(np.abs(t - np.radians(10.0))))
        dev = lambda ff: float(np.max(np.abs(ff / exact - 1)))  # noqa: E731
        rows.append([label, t.size, g_old, b["g"][0], f_old[i10] / exact[i10], f[i10] / exact[i10], dev(f_old), dev(f)])
    C.print_table(f"9.2: g and f with a caller's theta, water r = 1.7 um, lambda 0.55 um (miepython g = {g_mie:.6f}; "
                  f"default-grid g = {table['g'][0]:.6f}; f against the exact single-particle phase function at the "
                  "returned angles; 'before' = normalised and integrated by trapezoid on those angles)",
                  ["theta passed", "angles", "g before", "g now", "f(~10 deg)/exact before", "f(~10 deg)/exact now",
                   "max |f/exact - 1| before", "max |f/exact - 1| now"], rows, digits=6)


def default_accuracy(motes, quick: bool, out) -> dict:
    sys.path.insert(0, str(C.ROOT / "tests"))
    from conftest import lognormal_mie_phase  # noqa: PLC0415

    deg = np.array([0.0, 30.0, 90.0, 150.0, 170.0, 179.0, 180.0])
    theta = np.radians(deg)
    cases = [(eta, med, sg) for eta in (1.33, 1.31) for med in (1.0, 3.0, 10.0) for sg in (1.2, 1.5, 2.0) if (med, sg) != (10.0, 2.0)]
    if quick:
        cases = [(1.33, 1.0, 1.5), (1.33, 3.0, 1.2), (1.31, 3.0, 1.5)]
    rows, worst = [], {}
    for eta, med, sg in cases:
        cache = out / f"reference-{eta}-{med}-{sg}.npz"
        if cache.exists():
            with np.load(cache) as z:
                ref, half = z["ref"], z["half"]
        else:
            ref, half = lognormal_mie_phase(eta, 0.55, med, sg, theta)
            np.savez(cache, ref=ref, half=half)
        sp = motes.Species(motes.LogNormal(med, sg), eta)
        row = [f"{eta} / {med:g} um / {sg}", float(np.abs(half / ref - 1).max())]
        for method in ("mie", "auto"):
            for label, dx in (("before", 0.0), ("now", None)):
                t, b = C.best_of(lambda: motes.bulk_properties(sp, 1e4, 0.55, method=method, mie_dx=dx, cache=False), 2)  # noqa: B023
                err = np.abs(motes.PhaseTable.from_bulk(b).eval(theta) / ref - 1)
                worst[(method, label)] = max(worst.get((method, label), 0.0), float(err.max()))
                row += [float(err.max()), float(deg[np.argmax(err)]), float(err[-1]), t]
        rows.append(row)
        print(f"  {row[0]} done", flush=True)
    heads = ["eta / r_g / sigma_g", "reference self-check"]
    for method in ("mie", "auto"):
        for label in ("before", "now"):
            heads += [f"{method} {label}: max rel err", "at deg", "err at 180", "build s"]
    C.print_table("9.3: default ensemble tables vs miepython over the log-normal (0.005 in x), lambda 0.55 um; "
                  "max relative error over 0, 30, 90, 150, 170, 179, 180 deg", heads, rows)
    return {f"{m} {lab}": v for (m, lab), v in worst.items()}


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    caller_angles(motes)
    worst = default_accuracy(motes, args.quick, out)
    print("worst over the cases:", worst)
    C.finish(args, sw, out / "ensemble_accuracy.json", worst=worst)


if __name__ == "__main__":
    main()
