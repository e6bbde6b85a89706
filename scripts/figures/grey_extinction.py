"""What the `discrete` medium's grey free flight approximates: the spread of the bulk extinction over the RGB
channels for a few PSDs, and the resulting error of the transmittance colour at optical thickness 1 and 3
(exp(-tau_c) against exp(-mean tau)). Albedo and phase function stay per channel, so energy is exact.

    .venv/bin/python scripts/figures/grey_extinction.py [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    cases = [
        ("dust (default scene): log-normal 60 um, 1.6, n = 1.55", motes.LogNormal(60, 1.6), complex(1.55, 0.0005)),
        ("continuous-limit test: log-normal 20 um, 1.5, n = 1.31", motes.LogNormal(20, 1.5), 1.31),
        ("fog: log-normal 5 um, 1.5, water", motes.LogNormal(5, 1.5), motes.Material("water")),
        ("haze: log-normal 0.5 um, 1.5, water", motes.LogNormal(0.5, 1.5), motes.Material("water")),
    ]
    rows = []
    for name, psd, eta in cases:
        b = motes.bulk_properties(motes.Species(psd, eta), 1.0, motes.RGB_WAVELENGTHS_UM)
        st = b["sigma_t"]
        spread = (st.max() - st.min()) / st.mean()
        err = []
        for tau in (1.0, 3.0):
            t_true = np.exp(-tau * st / st.mean())
            t_grey = np.exp(-tau)
            err.append(np.max(np.abs(t_grey / t_true - 1)))
        rows.append([name, " / ".join(f"{v / st.mean():.4f}" for v in st), f"{spread:.2%}", f"{err[0]:.2%}", f"{err[1]:.2%}"])
    C.print_table("Grey free flight: bulk sigma_t per channel (R / G / B, relative to their mean) and the largest "
                  "relative error of a channel's transmittance", ["PSD", "sigma_t R / G / B", "spread",
                                                                  "error at tau = 1", "error at tau = 3"], rows)
    print(f"runtime {sw():.1f} s")


if __name__ == "__main__":
    main()
