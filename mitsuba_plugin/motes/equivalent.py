"""Continuous equivalents of discrete media, for A/B comparisons in Mitsuba 3.

``homogeneous_equivalent(species, number_density_m3, ...)`` returns a dict for ``mi.load_dict``: Mitsuba's
``homogeneous`` medium with a ``tabphase`` phase function and the bulk sigma_t and albedo of the particle
cloud (Eq. 16-17). It needs no Mitsuba import; load it in any variant.

==========================  =========================================================================
``color="rgb"``             sigma_t and albedo as ``rgb`` at ``RGB_WAVELENGTHS_UM`` (R, G, B)
``color="spectral"``        as ``spectrum`` at ``wavelength_um`` (default: 8 wavelengths 380-780 nm,
                            the paper's count), interpolated by Mitsuba in between
``scale_m``                 metres per scene unit (sigma_t is per scene unit in the dict: the medium's
                            ``scale`` times its normalised ``sigma_t`` colour)
``tabphase_size``           number of tabphase values, regular in cos(theta) from backward to forward
``polarized``               True: the phase function is ``motes_tabphase_polarized`` (the native library's, made
                            findable by ``motes.set_variant``), which carries the ensemble's Mueller matrix in
                            polarised variants (Mitsuba's ``tabphase`` depolarises): F11 as ``tabphase`` takes
                            it, F12/F11, F33/F11, F34/F11 (Bohren & Huffman) on the same grid, each the
                            sigma_s-weighted average over the wavelengths like F11
``truncate_below_rad``      forward-peak truncation angle; default: the pixel footprint ``fov / film_width``
                            when ``fov`` (degrees) and ``film_width`` (pixels) are given, otherwise one
                            tabphase bin (``DEFAULT_TRUNCATE_RAD`` for 4096 values; see below) — the
                            same defaults as the ``discrete`` medium
==========================  =========================================================================

Notes:

* ``tabphase`` is one phase function for all wavelengths: we give it the sigma_s-weighted average of the
  per-wavelength ensemble phase functions.
* ``tabphase`` is piecewise linear in cos(theta) on a regular grid; a diffraction peak a few micro-radians
  wide cannot live in one of its bins. By default the part of the peak narrower than one bin
  (theta_c = acos(1 - 2/(n-1))) is folded into unscattered transmission (forward-peak truncation,
  ``bulk_properties(truncate_below_rad=...)``): sigma_t and albedo are reduced accordingly, which is
  exact for directions resolved by the bins. Pass ``truncate_below_rad=0`` to keep the peak smeared into
  the first bin instead, or the pixel footprint to match a discrete render truncated the same way.
* Each tabphase value is the exact average of our tabulated phase function over its bin, so no energy is
  gained or lost in the resampling.
"""

from __future__ import annotations

import numpy as np

from . import _motes
from .ensemble import RGB_WAVELENGTHS_UM, SPECTRAL_WAVELENGTHS_UM, bulk_properties, pixel_footprint_rad


def homogeneous_equivalent(species, number_density_m3: float, *, color: str = "rgb", wavelength_um=None,
                           eta_medium: float = 1.0, method: str = "auto", scale_m: float = 1.0,
                           tabphase_size: int = 4096, truncate_below_rad: float | None = None,
                           fov: float | None = None, film_width: int | None = None, polarized: bool = False) -> dict:
    """A ``mi.load_dict`` dict of the continuous medium equivalent to a particle cloud (module docs)."""
    if color not in ("rgb", "spectral"):
        raise ValueError(f'color must be "rgb" or "spectral", got {color!r}')
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise ValueError(f"invalid scale_m = {scale_m}: must be finite and > 0")
    if isinstance(tabphase_size, bool) or not isinstance(tabphase_size, (int, np.integer)) or tabphase_size < 2:
        raise ValueError(f"tabphase_size must be an integer >= 2, got {tabphase_size!r}")
    if wavelength_um is None:
        wavelength_um = RGB_WAVELENGTHS_UM if color == "rgb" else SPECTRAL_WAVELENGTHS_UM
    lam = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
    if color == "rgb" and lam.size != 3:
        raise ValueError("color='rgb' needs exactly 3 wavelengths (R, G, B)")
    if truncate_below_rad is None:
        if (fov is None) != (film_width is None):
            raise ValueError("fov and film_width go together (the pixel footprint fov / film_width)")
        truncate_below_rad = (pixel_footprint_rad(fov, film_width) if fov is not None
                              else float(np.arccos(1.0 - 2.0 / (tabphase_size - 1))))
    extra = {"mueller": True} if polarized else {}
    b = bulk_properties(species, number_density_m3, lam, eta_medium, method, truncate_below_rad=truncate_below_rad,
                        **extra)
    weights = b["sigma_s"] / b["sigma_s"].sum() if b["sigma_s"].sum() > 0 else np.full(lam.size, 1.0 / lam.size)
    phase = weights @ b["phase"]
    values = _motes.PhaseTable(np.ascontiguousarray(b["theta"]), np.ascontiguousarray(phase)).regular_mu(int(tabphase_size))
    phase_dict = {"type": "tabphase", "values": _numbers(values)}
    if polarized:
        phase_dict = {"type": "motes_tabphase_polarized", "values": phase_dict["values"],
                      **_mueller_rows(b, weights, phase, int(tabphase_size))}
    sigma_t = b["sigma_t"] * scale_m
    # Mitsuba reads colours as bounded (reflectance-like) spectra: pass sigma_t / max in [0, 1] and the
    # maximum as the medium's `scale` (the usual Mitsuba idiom).
    scale = float(sigma_t.max()) if sigma_t.max() > 0 else 1.0
    sigma_t = sigma_t / scale
    albedo = np.clip(b["albedo"], 0.0, 1.0)
    if color == "rgb":
        st = {"type": "rgb", "value": [float(v) for v in sigma_t]}
        al = {"type": "rgb", "value": [float(v) for v in albedo]}
    else:
        nm = lam * 1e3
        st = {"type": "spectrum", "value": [(float(w), float(v)) for w, v in zip(nm, sigma_t)]}
        al = {"type": "spectrum", "value": [(float(w), float(v)) for w, v in zip(nm, albedo)]}
    return {
        "type": "homogeneous",
        "sigma_t": st,
        "albedo": al,
        "scale": scale,
        "phase": phase_dict,
    }


def _numbers(values) -> str:
    return ", ".join(f"{v:.9g}" for v in values)


def _mueller_rows(b: dict, weights: np.ndarray, f11: np.ndarray, size: int) -> dict:
    """``motes_tabphase_polarized``'s m12, m33, m34: the wavelength-weighted elements over the weighted F11, at
    ``size`` values of cos(theta) from -1 to 1 (linear in cos(theta) between the bulk's angles; (0, 1, 0) where
    F11 vanishes)."""
    mu_grid = np.linspace(-1.0, 1.0, size)
    mu = np.cos(b["theta"])[::-1]  # increasing
    f = np.interp(mu_grid, mu, f11[::-1])
    rows = {}
    for k, (name, fill) in enumerate((("m12", 0.0), ("m33", 1.0), ("m34", 0.0))):
        element = weights @ (b["phase"] * b["mueller"][:, k, :])
        e = np.interp(mu_grid, mu, element[::-1])
        ratio = np.where(f > 0, e / np.where(f > 0, f, 1.0), fill)
        rows[name] = _numbers(np.clip(ratio, -1.0, 1.0))
    return rows




def equivalent_xml(d: dict, name: str = "interior") -> str:
    """The XML of a ``homogeneous_equivalent`` result (RGB): a ``homogeneous`` medium with a
    ``tabphase`` phase function, to paste into a scene (``motes equivalent`` prints it)."""
    sigma, albedo = d["sigma_t"], d["albedo"]
    return "\n".join([
        f'<medium type="homogeneous" name="{name}">',
        f'    <rgb name="sigma_t" value="{", ".join(f"{v:.6g}" for v in sigma["value"])}"/>',
        f'    <float name="scale" value="{d.get("scale", 1.0):.6g}"/>',
        f'    <rgb name="albedo" value="{", ".join(f"{v:.6g}" for v in albedo["value"])}"/>',
        _phase_xml(d["phase"]),
        "</medium>"])


def _phase_xml(phase: dict) -> str:
    strings = "".join(f'<string name="{k}" value="{v}"/>' for k, v in phase.items() if k != "type")
    return f'    <phase type="{phase["type"]}">{strings}</phase>'


__all__ = ["RGB_WAVELENGTHS_UM", "SPECTRAL_WAVELENGTHS_UM", "equivalent_xml", "homogeneous_equivalent"]
