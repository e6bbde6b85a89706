"""The GOA edge term alone (part (e) of ``scripts/figures/singularities.py``, cited by
``rust/motes-core/src/optics/goa.rs``).

    .venv/bin/python scripts/figures/edge_term.py [--out out/] [--quick]

Measures (1) the mean relative C_ext error of GOA (p = 3, regularised) vs Lorenz-Mie with and without
``edge_correction`` over log-spaced radii in [10, 100] and [100, 1000] um for eta = 1.33, 1.5 and 0.75
(where the code leaves the term out), lambda = 0.6 um; (2) the ripple-averaged coefficient
c = mean((Q_ext - 2) x^(2/3)) of Mie over x in [200, 400] (expected ~1.29 for eta = 0.75 and ~1.99 for
1.33; Nussenzveig-Wiscombe give 1.9924 for eta > 1). Outputs ``edge_term.png`` and ``edge_term.json``.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import _common as C  # noqa: E402
from singularities import edge_term_study  # noqa: E402


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    res = edge_term_study(motes, args.quick, out, C.plt())
    C.finish(args, sw, out / "edge_term.json", wavelength_um=C.LAM, **res)


if __name__ == "__main__":
    main()
