"""Spectral rendering from a few tabulated wavelengths (issue 3): error of linear interpolation in
wavelength of sigma_t, sigma_s, albedo, g and the phase function, against direct evaluation at 48
wavelengths over 360-830 nm, for tables of 8 (the paper's count) and 16 wavelengths. Media: the paper's
ice cloud, small ice crystals, fog droplets (tabulated indices of ice and water).

    .venv/bin/python scripts/figures/spectral_interpolation.py [--quick] [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    ice, water = motes.Material("ice"), motes.Material("water")
    media = [("ice cloud r_g 800 um, sigma_g 4", motes.Species(motes.LogNormal(800.0, 4.0), ice)),
             ("ice crystals r_g 10 um, sigma_g 2", motes.Species(motes.LogNormal(10.0, 2.0), ice)),
             ("fog droplets r_g 2 um, sigma_g 1.5", motes.Species(motes.LogNormal(2.0, 1.5), water))]
    q = np.linspace(0.36, 0.83, 12 if args.quick else 48)
    rows = []
    for label, sp in media:
        direct = motes.bulk_properties(sp, 1e4, q)
        for n_tab in (8, 16):
            table = motes.SpectralTable(sp, 1e4, np.linspace(0.36, 0.83, n_tab))
            got = table.at(q)
            rel = {k: float(np.max(np.abs(got[k] / direct[k] - 1))) for k in ("sigma_t", "sigma_s")}
            g_abs = float(np.max(np.abs(got["g"] - direct["g"])))
            th = direct["theta"]
            w = 2 * np.pi * np.sin(th)
            # phase: L1 distance between interpolated and direct phase functions (probability mass moved)
            l1 = float(np.max([np.trapezoid(np.abs(a - b) * w, th) for a, b in zip(got["phase"], direct["phase"])]))
            rows.append([label, n_tab, rel["sigma_t"], rel["sigma_s"], g_abs, l1])
    C.print_table("Linear interpolation in wavelength vs direct evaluation, max over 360-830 nm",
                  ["medium", "table wavelengths", "sigma_t max rel err", "sigma_s max rel err", "g max abs err", "phase max L1 distance"], rows)
    C.finish(args, sw, out / "spectral_interpolation.json", rows=rows)


if __name__ == "__main__":
    main()
