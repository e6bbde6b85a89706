"""GOA's polarisation against Mie's (issue 45): the degree of polarisation P = -F12/F11, F33/F11 and F34/F11 of
single spheres, averaged over 5-degree windows (GOA has no Mie ripple: only angle-averaged polarisation can
agree), at lambda = 0.55 um for radii 20..60 um (x = 228..685), water (1.33) and glass (1.5), plus an
absorbing sphere (2 + 1i) whose F34 is large. Prints, per region, the worst and RMS differences and the
correlation of P over all angles; `tests/test_mueller.py` asserts bounds just above these.

    .venv/bin/python scripts/figures/mueller_goa_vs_mie.py
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _common as C  # noqa: E402

LAM = 0.55
THETA = np.radians(np.linspace(0.0, 180.0, 36001))


def windowed(motes, r_um, eta, method, width_deg=5.0):
    """Window centres (deg) and (P, F33/F11, F34/F11) of the window-averaged elements."""
    m = motes.mueller_matrix(r_um, LAM, eta, THETA, method)
    n = int(round(width_deg / 0.005))
    k = (THETA.size - 1) // n
    mean = m[: k * n].reshape(k, n, 4).mean(axis=1)
    centres = np.degrees(THETA[: k * n].reshape(k, n).mean(axis=1))
    return centres, np.stack([-mean[:, 1] / mean[:, 0], mean[:, 2] / mean[:, 0], mean[:, 3] / mean[:, 0]], axis=1)


def main() -> None:
    motes = C.import_motes()
    print(f"{'sphere':18s} {'region':22s} {'max|dP|':>8s} {'rms dP':>8s} {'max|dF33|':>9s} {'max|dF34|':>9s}  corr(P)")
    cases = [(r, eta) for eta in (1.33, 1.5) for r in (20.0, 30.0, 40.0, 50.0, 60.0)] + [(40.0, 2 + 1j), (60.0, 2 + 1j)]
    for r, eta in cases:
        c, mie = windowed(motes, r, eta, "mie")
        _, goa = windowed(motes, r, eta, "goa")
        d = np.abs(goa - mie)
        corr = np.corrcoef(mie[:, 0], goa[:, 0])[0, 1]
        regions = {"10-60 deg": (c > 10) & (c < 60)}
        if eta == 1.33:
            regions["rainbow 137-150 deg"] = (c > 137) & (c < 150)
        if isinstance(eta, complex):
            regions = {"10-170 deg": (c > 10) & (c < 170)}
        for name, sel in regions.items():
            print(f"r {r:4.0f} um eta {str(eta):7s} {name:22s} {d[sel, 0].max():8.3f} "
                  f"{np.sqrt(np.mean(d[sel, 0] ** 2)):8.3f} {d[sel, 1].max():9.3f} {d[sel, 2].max():9.3f}  {corr:.3f}")


if __name__ == "__main__":
    main()
