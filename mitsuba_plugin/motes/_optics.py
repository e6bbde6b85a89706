"""Numpy front of the single-particle optics in ``motes._motes``.

This layer only broadcasts, validates types and shapes, and reshapes; all physics is in Rust.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from . import _motes

Method = Literal["auto", "mie", "goa", "hybrid"]

AUTO_SIZE_PARAMETER, HYBRID_RADIUS_UM, AXIAL_CAUSTIC_WINDOW = _motes.policy_constants()


def _real(name: str, value) -> np.ndarray:
    arr = np.asarray(value)
    if np.iscomplexobj(arr):
        raise ValueError(f"{name} must be real, got a complex value")
    try:
        return arr.astype(np.float64, copy=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real number or array of real numbers") from exc


def _index(value) -> tuple[np.ndarray, np.ndarray]:
    arr = np.asarray(value)
    if arr.dtype.kind not in "biufc":
        raise ValueError("eta must be a real or complex number or array")
    arr = arr.astype(np.complex128)
    return arr.real.copy(), arr.imag.copy()


def _broadcast(**named):
    try:
        arrays = np.broadcast_arrays(*named.values())
    except ValueError as exc:
        shapes = ", ".join(f"{k}{np.shape(v)}" for k, v in named.items())
        raise ValueError(f"arguments do not broadcast together: {shapes}") from exc
    shape = arrays[0].shape
    return shape, [np.ascontiguousarray(a, dtype=np.float64).ravel() for a in arrays]


def _p_max(p_max) -> int:
    if isinstance(p_max, (bool, np.bool_)) or not isinstance(p_max, (int, np.integer)):
        raise ValueError(f"p_max must be an integer in [0, 500], got {p_max!r}")
    # Memory grows with p_max^2 (1000 aborted the process; 600 needs 84 MB per call, 500 about 60).
    if not 0 <= int(p_max) <= 500:
        raise ValueError(f"p_max must be an integer in [0, 500], got {p_max}")
    return int(p_max)


def _particle_args(radius_um, wavelength_um, eta, eta_medium, theta=None):
    er, ei = _index(eta)
    named = dict(
        radius_um=_real("radius_um", radius_um),
        wavelength_um=_real("wavelength_um", wavelength_um),
        eta_re=er,
        eta_im=ei,
        eta_medium=_real("eta_medium", eta_medium),
    )
    if theta is not None:
        named["theta"] = _real("theta", theta)
    return _broadcast(**named)


def _positive(name: str, value) -> np.ndarray:
    arr = _real(name, value)
    if not np.all(np.isfinite(arr) & (arr > 0)):
        raise ValueError(f"invalid {name}: every value must be finite and > 0")
    return arr


def size_parameter(radius_um, wavelength_um, eta_medium=1.0):
    """``alpha = 2 pi eta_medium r / lambda``."""
    r, lam, em = (_positive(n, v) for n, v in (("radius_um", radius_um), ("wavelength_um", wavelength_um), ("eta_medium", eta_medium)))
    return 2.0 * np.pi * em * r / lam


def _flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def mie_amplitudes(radius_um, wavelength_um, eta, theta, eta_medium=1.0):
    """Lorenz-Mie scattering amplitudes ``(S1, S2)`` (complex arrays, Bohren-Huffman convention)."""
    shape, cols = _particle_args(radius_um, wavelength_um, eta, eta_medium, theta)
    s1, s2 = _motes.mie_amplitudes(*cols)
    return s1.reshape(shape), s2.reshape(shape)


def goa_amplitudes(radius_um, wavelength_um, eta, theta, p_max=3, diffraction=True, eta_medium=1.0, *,
                   regularise=True, edge_correction=True):
    """Geometrical-optics amplitudes ``(S1, S2)``: Fraunhofer diffraction (Eq. 4, forward hemisphere)
    plus every ray of order ``p <= p_max`` (Eq. 7-11), in the Bohren-Huffman convention.

    ``regularise=False`` gives the paper's formulas verbatim (infinite at caustics and glories);
    ``edge_correction=False`` leaves out the edge term that the paper's GOA lacks (see BENCHMARKS.md)."""
    shape, cols = _particle_args(radius_um, wavelength_um, eta, eta_medium, theta)
    s1, s2 = _motes.goa_amplitudes(*cols, _p_max(p_max), _flag("diffraction", diffraction), _flag("regularise", regularise), _flag("edge_correction", edge_correction))
    return s1.reshape(shape), s2.reshape(shape)


def clear_goa_cache() -> None:
    """Free the GOA ray geometry that ``goa_amplitudes``, ``cross_sections`` and ``phase_function`` keep
    between calls. They keep it for the 8 most recently used relative indices (with each one's angle grids,
    at most 256 MiB in all per index), so that a sweep over radii or repeated calls at the same angles cost
    only the size-dependent part (~0.3 ms at 1800 angles instead of ~1-3 ms); ``goa_cache_info()`` says
    what it holds. Results never depend on it."""
    _motes.clear_goa_cache()


def goa_cache_info() -> dict:
    """``{"indices": n, "bytes": b}``: what the free functions' GOA cache holds (see ``clear_goa_cache``)."""
    n, b = _motes.goa_cache_info()
    return {"indices": n, "bytes": b}


def _method(method) -> str:
    if method not in ("auto", "mie", "goa", "hybrid"):
        raise ValueError(f'method must be one of "auto", "mie", "goa", "hybrid", got {method!r}')
    return method


def cross_sections(radius_um, wavelength_um, eta, method: Method = "auto", eta_medium=1.0, *,
                   hybrid_radius_um=HYBRID_RADIUS_UM, p_max=3, regularise=True, edge_correction=True,
                   asymmetry=True) -> dict:
    """Extinction, scattering and absorption cross sections (um^2) and asymmetry ``g``.

    Returns ``{"ext", "sca", "abs", "g"}``, each an array of the broadcast shape of the inputs.
    ``asymmetry=False`` skips g (NaN), which for GOA saves an angular integral per particle."""
    shape, cols = _particle_args(radius_um, wavelength_um, eta, eta_medium)
    ext, sca, ab, g = _motes.cross_sections(*cols, _method(method), float(hybrid_radius_um), _p_max(p_max), _flag("regularise", regularise), _flag("edge_correction", edge_correction),
                                            _flag("asymmetry", asymmetry))
    return {"ext": ext.reshape(shape), "sca": sca.reshape(shape), "abs": ab.reshape(shape), "g": g.reshape(shape)}


def phase_function(radius_um, wavelength_um, eta, theta, method: Method = "auto", eta_medium=1.0, *,
                   hybrid_radius_um=HYBRID_RADIUS_UM, p_max=3, regularise=True, edge_correction=True):
    """Single-particle phase function ``f_p(theta)`` of Eq. 1 in sr^-1 (integral over the sphere = 1)."""
    shape, cols = _particle_args(radius_um, wavelength_um, eta, eta_medium, theta)
    f = _motes.phase_function(*cols, _method(method), float(hybrid_radius_um), _p_max(p_max), _flag("regularise", regularise), _flag("edge_correction", edge_correction))
    return f.reshape(shape)


def mueller_matrix(radius_um, wavelength_um, eta, theta, method: Method = "auto", eta_medium=1.0, *,
                   hybrid_radius_um=HYBRID_RADIUS_UM, p_max=3, regularise=True, edge_correction=True,
                   normalize=True):
    """Single-particle Mueller matrix elements of a sphere, shape ``theta.shape + (4,)`` (broadcast like
    ``phase_function``): ``[..., 0:4] = F11, F12, F33, F34`` in Bohren & Huffman's convention (1983, §4.4)::

        F11 = (|S2|^2 + |S1|^2) / 2      F12 = (|S2|^2 - |S1|^2) / 2
        F33 = Re(S2 S1*)                  F34 = Im(S2 S1*)

    with the amplitudes ``(S1, S2)`` of ``mie_amplitudes`` / ``goa_amplitudes`` (``method`` as in
    ``phase_function``). The full matrix is ``[[F11, F12, 0, 0], [F12, F11, 0, 0], [0, 0, F33, F34],
    [0, 0, -F34, F33]]``. motes uses m = n + i k (absorbing kappa >= 0) and exp(-i omega t) like Bohren &
    Huffman; codes with m = n - i k (e.g. miepython) have conjugate amplitudes and the opposite F34.
    For Rayleigh scattering F12 < 0 at 90 degrees: the degree of linear polarisation is -F12/F11.

    ``normalize=True``: all four are divided by the normaliser of ``phase_function``, so that F11 equals
    ``phase_function(...)`` exactly (1/sr, integral of F11 over the sphere = 1); a particle that scatters
    nothing (eta = eta_medium) gives (1/(4 pi), 0, 1/(4 pi), 0). ``normalize=False``: the raw
    dimensionless values of the amplitudes."""
    shape, cols = _particle_args(radius_um, wavelength_um, eta, eta_medium, theta)
    m = _motes.mueller_matrix(*cols, _method(method), float(hybrid_radius_um), _p_max(p_max), _flag("regularise", regularise), _flag("edge_correction", edge_correction),
                              _flag("normalize", normalize))
    return m.reshape(shape + (4,))


def resolve_method(radius_um, wavelength_um, eta, method: Method = "auto", eta_medium=1.0, *,
                   hybrid_radius_um=HYBRID_RADIUS_UM, p_max=3):
    """The theory (``"mie"`` or ``"goa"``) that ``method`` uses for each particle, as a string array."""
    shape, cols = _particle_args(radius_um, wavelength_um, eta, eta_medium)
    names = _motes.resolve_method(*cols, _method(method), float(hybrid_radius_um), _p_max(p_max))
    return np.asarray(names).reshape(shape)


def goa_extinction_efficiency(alpha, eta, p_max=3, regularise=True, edge_correction=True):
    """``Q_ext = C_ext / (pi r^2)`` of GOA by Eq. 12 for size parameter ``alpha`` and relative index ``eta``."""
    er, ei = _index(eta)
    shape, (a, r, i) = _broadcast(alpha=_real("alpha", alpha), eta_re=er, eta_im=ei)
    return _motes.goa_extinction_efficiency(a, r, i, _p_max(p_max), _flag("regularise", regularise), _flag("edge_correction", edge_correction)).reshape(shape)
