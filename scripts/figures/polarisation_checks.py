"""The numbers behind `tests/test_polarisation.py`'s single-scattering checks (issue 45), printed: S1/S0 of
Mitsuba's `stokes` integrator for a thin cube of grains lit along +x and seen at scattering angle theta, against
Rayleigh's -sin^2 / (1 + cos^2) (0.005 um grains), `motes.mueller_matrix`'s F12/F11 (0.3 um glass, two variants),
and the discrete field against `homogeneous_equivalent(polarized=True)` (0.1 um grains).

    .venv/bin/python scripts/figures/polarisation_checks.py
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "scripts"))
import _common as C  # noqa: E402


def main() -> None:
    motes = C.import_motes()
    import test_polarisation as T  # noqa: PLC0415

    motes.set_variant("llvm_ad_mono_polarized")
    print("Rayleigh (0.005 um, llvm_ad_mono_polarized): theta, S1/S0 +- SE, -sin^2/(1+cos^2)")
    for th in (45.0, 90.0, 135.0):
        img = T._single_scattering(T._grains(0.005, storage="procedural"), th)
        c = np.cos(np.radians(th))
        r, se = T._ratio(img, T.S1)
        print(f"  {th:5.0f}  {r:+.8f} +- {se:.1e}  {-(1 - c * c) / (1 + c * c):+.8f}")
    print("Mie (0.3 um glass): variant, theta, S1/S0, F12/F11")
    for variant in ("llvm_ad_mono_polarized", "scalar_spectral_polarized"):
        motes.set_variant(variant)
        for th in (60.0, 110.0):
            img = T._single_scattering(T._grains(0.3), th, spp=32, res=6)
            f = motes.mueller_matrix(0.3, T.LAM_UM, 1.5, np.radians(th))
            print(f"  {variant:26s} {th:5.0f}  {T._ratio(img, T.S1)[0]:+.6f}  {f[1] / f[0]:+.6f}")
    motes.set_variant("llvm_ad_mono_polarized")
    sp = motes.Species(motes.Monodisperse(0.1), 1.5)
    d = motes.homogeneous_equivalent(sp, 1e12, color="spectral", wavelength_um=[T.LAM_UM], polarized=True)
    hom = {"type": "homogeneous", "sigma_t": 0.1, "albedo": 1.0, "phase": d["phase"]}
    print("continuous equivalents (0.1 um): theta, S1/S0 of the discrete field, of homogeneous_equivalent; S0 of each")
    for th in (50.0, 90.0, 140.0):
        a = T._single_scattering(T._grains(0.1, storage="procedural"), th, spp=128)
        b = T._single_scattering(hom, th, spp=128)
        print(f"  {th:5.0f}  {T._ratio(a, T.S1)[0]:+.6f}  {T._ratio(b, T.S1)[0]:+.6f}  "
              f"{a[..., T.S0].mean():.5f}  {b[..., T.S0].mean():.5f}")


if __name__ == "__main__":
    main()
