"""Bulk optical properties of particle clouds (paper Sec. 4.2, Eq. 16-17), per wavelength.

``bulk_properties(species, number_density_m3, wavelength_um, ...)`` returns a dict of numpy arrays:

==================  ===================================================================================
``sigma_t``         extinction coefficient, 1/m (Eq. 16), one per wavelength
``sigma_s``         scattering coefficient, 1/m
``sigma_a``         absorption coefficient, 1/m
``albedo``          sigma_s / sigma_t (0 where sigma_t = 0)
``g``               asymmetry parameter of the ensemble phase function (on the internal grid)
``theta``           the angles of ``phase`` (radians): the internal grid — 0, log-spaced through the
                    diffraction lobe of the largest particle, then uniform to pi, refined with
                    ``refine_tol`` — or exactly the ``theta`` you pass
``phase``           ensemble phase function f(theta), 1/sr, shape (n_wavelengths, n_theta), with
                    integral 1 over the sphere on the internal grid (Eq. 17)
``energy_ratio``    integral of the amplitudes' |S|^2 over the ensemble divided by its C_sca (a check:
                    1 for Mie up to grid error, slightly below 1 for GOA, which keeps p <= p_max)
``peak_fraction``   with ``truncate_below_rad``: the fraction F of scattering folded into unscattered
                    transmission (0 otherwise)
``mueller``         only with ``mueller=True``: shape (n_wavelengths, 3, n_theta), the ensemble's Mueller
                    ratios F12/F11, F33/F11, F34/F11 at the angles ``theta`` (row i aligned with
                    ``phase[i]``), see below
==================  ===================================================================================

Polarisation (``mueller=True``): the ensemble's Mueller matrix is, in Bohren & Huffman's convention
(1983, section 4.4; F34 for m = n + i kappa), ``phase * [[1, r12, 0, 0], [r12, 1, 0, 0], [0, 0, r33, r34],
[0, 0, -r34, r33]]`` with ``r12, r33, r34 = mueller[i]``: each element summed over the radius nodes with
the weights of Eq. 17 (the Mie nodes in coefficient space, the others from S1, S2) and divided by the same
sum of F11 (``mueller_matrix`` gives a single particle's). They are evaluated exactly at every angle of
``theta``, always lie in [-1, 1], and are (0, 1, 0) where F11 sums to 0 (never NaN). Forward-peak
truncation clips F11 only: the ratios stay those of the untruncated ensemble.

Forward-peak truncation (``truncate_below_rad=theta_c``, e.g. ``pixel_footprint_rad(fov, width)``):
scattering by less than theta_c cannot be told from no scattering at the pixel's resolution, so the
phase function is clipped at f(theta_c) inside the cone and the clipped fraction F is removed from
sigma_s and sigma_t (sigma_a unchanged) — the delta-M scaling of atmospheric radiative transfer. It saves
the scattering events spent in the diffraction peak of large grains; ``scripts/figures/truncation_experiment.py``
measures what it saves and what it changes.

``theta=`` only chooses where f is reported: the normalisation, g, ``energy_ratio`` and the truncation
always come from the internal grid, and f at each of your angles is the exact ensemble intensity there
divided by the internal-grid total (truncated the same way), so it does not depend on which other angles
you ask for — a coarse list gives exact samples of the same f, not a coarser f.

A ``Species`` is a particle material with a PSD: ``Species(psd, eta, share=1.0)``; ``eta`` is one complex
index or one per wavelength; ``share`` is its share of the particle count. ``number_density_m3`` is the
total particle count per cubic metre.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
import tempfile
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from . import _env, _motes, _version
from ._optics import HYBRID_RADIUS_UM, _method, _p_max
from .psd import Psd


@dataclass(frozen=True)
class Material:
    """A tabulated particle material: ``Material("ice")`` (Warren & Brandt 2008, -7 C) or
    ``Material("water")`` (Hale & Querry 1973, 25 C), 0.35-0.85 um; see ``rust/motes-core/src/optics/materials.rs``."""

    name: str

    def __post_init__(self) -> None:
        self.index([0.55])

    def index(self, wavelength_um) -> np.ndarray:
        """Complex refractive index n + i kappa at the wavelengths (um)."""
        lam = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
        return _motes.material_index(self.name, np.ascontiguousarray(lam.ravel())).reshape(lam.shape)


@dataclass(frozen=True)
class Species:
    """A particle species: a PSD and a refractive index — one complex value, one per wavelength, or a
    tabulated ``Material`` — and its share of the particle count."""

    psd: Psd
    eta: complex | Sequence[complex] | Material
    share: float = 1.0
    name: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.psd, Psd):
            raise ValueError(f"Species.psd must be a motes.psd distribution, got {self.psd!r}")
        if not (np.isfinite(self.share) and self.share >= 0):
            raise ValueError(f"invalid share = {self.share}: must be finite and >= 0")

    def index_at(self, wavelength_um) -> np.ndarray:
        lam = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
        n_wavelengths = lam.size
        if isinstance(self.eta, Material):
            return self.eta.index(lam)
        eta = np.atleast_1d(np.asarray(self.eta, dtype=np.complex128))
        if eta.ndim != 1 or eta.size not in (1, n_wavelengths):
            raise ValueError(f"Species {self.name or ''} eta must be one value or one per wavelength ({n_wavelengths}), got shape {eta.shape}")
        eta = np.broadcast_to(eta, (n_wavelengths,))
        if np.any(~np.isfinite(eta)) or np.any(eta.real <= 0) or np.any(eta.imag < 0):
            raise ValueError("invalid eta: real part must be > 0 and imaginary part >= 0, all finite")
        return eta


#: Representative wavelengths (um) of the R, G, B channels: the monochromatic primaries of ITU-R BT.2020
#: (630, 532, 467 nm). ``SPECTRAL_WAVELENGTHS_UM``: the paper's 8 spectral samples over 380-780 nm
#: (Sec. 6). Both from ``rust/motes-core/src/ensemble/wavelengths.rs``, the one home of the defaults.
RGB_WAVELENGTHS_UM, SPECTRAL_WAVELENGTHS_UM = (tuple(v) for v in _motes.default_wavelengths())


def pixel_footprint_rad(fov_deg: float, width_px: int) -> float:
    """Angular size of one pixel (radians) of a camera with horizontal field of view ``fov_deg``."""
    if not (0 < fov_deg < 180) or int(width_px) < 1:
        raise ValueError("fov_deg must be in (0, 180) and width_px >= 1")
    return float(np.radians(fov_deg) / int(width_px))


#: Default forward-peak truncation angle (radians) of the discrete medium and of
#: ``homogeneous_equivalent``: one bin of a 4096-value ``tabphase`` (acos(1 - 2/4095) = 0.0313 rad).
#: Scattering by less than this is folded into unscattered transmission; it removes the diffraction
#: lobe of grains above ~20 um that a delta light could otherwise only reach as fireflies (issue 9.4).
DEFAULT_TRUNCATE_RAD: float = float(np.arccos(1.0 - 2.0 / 4095.0))

_CACHE_FORMAT = 1
_KEYS = ("wavelength_um", "sigma_t", "sigma_s", "sigma_a", "albedo", "g", "theta", "phase", "energy_ratio", "peak_fraction")
_MUELLER_KEYS = _KEYS + ("mueller",)


def cache_dir() -> pathlib.Path | None:
    """Where ``bulk_properties`` caches its tables: ``$MOTES_CACHE_DIR``, else ``~/.cache/motes``;
    ``MOTES_CACHE_DIR=""`` disables the cache (``motes._env``)."""
    return _env.cache_dir()


#: Hash of the Rust sources the extension was built from (``rust/motes-py/build.rs``): the disk cache is
#: keyed by it, so a change of the physics never serves tables computed by older code.
CORE_HASH: str = _motes.core_hash()


def _cache_key(payload: dict) -> str:
    text = json.dumps({"format": _CACHE_FORMAT, "version": _version.__version__, "core": CORE_HASH, **payload}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _cache_load(path: pathlib.Path, keys: tuple = _KEYS) -> dict | None:
    try:
        with np.load(path) as z:
            return {k: z[k] for k in keys}
    except (OSError, ValueError, KeyError, EOFError):
        return None  # missing or damaged entry: recompute (and overwrite)


def _cache_store(path: pathlib.Path, result: dict) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **result)
        os.replace(tmp, path)  # atomic: readers never see a half-written table
    except OSError:
        pass  # a read-only or full disk only costs the rebuild next time


def species_list(species) -> list:
    """``species`` (one Species or several) as a non-empty list of Species, or ValueError."""
    if isinstance(species, Species):
        species = [species]
    species = list(species)
    if not species or not all(isinstance(s, Species) for s in species):
        raise ValueError("species must be a Species or a non-empty list of Species")
    return species


def bulk_properties(species, number_density_m3: float, wavelength_um, eta_medium: float = 1.0, method="auto", *,
                    theta=None, phase: bool = True, max_log_step: float = 0.05, mie_dx: float | None = None, p_max: int = 3,
                    hybrid_radius_um: float = HYBRID_RADIUS_UM, truncate_below_rad: float | None = None,
                    refine_tol: float = 0.0, refine_max_nodes: int = 200_000, cache: bool = True,
                    goa_cache=None, mueller: bool = False) -> dict:
    """Bulk coefficients and the ensemble phase function of a cloud of ``species`` (see module docs).

    Results are cached on disk (``cache_dir()``), keyed by every argument, each species' PSD spec and
    refractive index at each wavelength, the package version and ``CORE_HASH`` (the Rust sources);
    ``cache=False`` bypasses the cache. ``goa_cache`` (a ``motes._motes.GoaCache``) lets several calls
    over the same materials share GOA ray geometry (results are identical with or without it).

    ``refine_tol`` (e.g. 0.01) refines the angle grid adaptively until the tabulated (piecewise-linear in
    cos theta) phase function is within that relative error of direct evaluation between its nodes,
    wherever f > 1e-6 max, up to ``refine_max_nodes`` angles.

    ``mie_dx`` is the largest step in size parameter x = k r of the radius quadrature where Mie is used
    (2 < x <= 600; the step grows in proportion to x above 300): ``None`` is the core's default (0.02,
    fine enough to average Mie's ripple and keep the tables within 1 % at every angle, backscatter
    included); 0 uses the panels in ln r alone.

    ``mueller=True`` adds ``"mueller"``, the ensemble's Mueller ratios F12/F11, F33/F11, F34/F11 at the
    angles ``theta`` (shape (n_wavelengths, 3, n_theta); see the module docs: Bohren & Huffman's
    convention, untouched by ``truncate_below_rad``). It needs ``phase=True``; ``mueller=False`` results
    are the same with or without it."""
    species = species_list(species)
    lam = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
    if lam.ndim != 1 or lam.size == 0:
        raise ValueError("wavelength_um must be a number or a 1-D array")
    if not (np.isfinite(number_density_m3) and number_density_m3 >= 0):
        raise ValueError(f"invalid number_density_m3 = {number_density_m3}: must be finite and >= 0")
    if not (np.isfinite(eta_medium) and eta_medium > 0):
        raise ValueError(f"invalid eta_medium = {eta_medium}: must be finite and > 0")
    eta = np.stack([s.index_at(lam) for s in species])
    th = np.zeros(0) if theta is None else np.ascontiguousarray(np.asarray(theta, dtype=np.float64).ravel())
    cut = 0.0 if truncate_below_rad is None else float(truncate_below_rad)
    if not (np.isfinite(cut) and 0.0 <= cut < np.pi):
        raise ValueError(f"invalid truncate_below_rad = {truncate_below_rad}: must be in [0, pi)")
    if truncate_below_rad is not None and not phase:
        raise ValueError("truncate_below_rad needs phase=True (the peak is measured on the phase function)")
    if not isinstance(mueller, (bool, np.bool_)):
        raise ValueError(f"mueller must be True or False, got {mueller!r}")
    if mueller and not phase:
        raise ValueError("mueller=True needs phase=True (the ratios are given at the phase function's angles)")
    payload = {
        "species": [[s.psd.spec(), [[float(e.real), float(e.imag)] for e in row], float(s.share)] for s, row in zip(species, eta)],
        "n0": float(number_density_m3), "lam": lam.tolist(), "eta_medium": float(eta_medium), "method": str(method),
        "theta": th.tolist(), "phase": bool(phase), "max_log_step": float(max_log_step), "mie_dx": mie_dx if mie_dx is None else float(mie_dx), "p_max": int(p_max),
        "hybrid_radius_um": float(hybrid_radius_um), "truncate": cut, "refine_tol": float(refine_tol),
        "refine_max_nodes": int(refine_max_nodes), "mueller": bool(mueller),
    }
    where = cache_dir() if cache else None
    path = where / f"bulk-{_cache_key(payload)}.npz" if where is not None else None
    if path is not None and path.exists():
        hit = _cache_load(path, _MUELLER_KEYS if mueller else _KEYS)
        if hit is not None:
            return hit
    st, ss, sa, g, ph, ratio, th, frac, mm = _motes.bulk_properties(
        [s.psd._json() for s in species], [float(s.share) for s in species],
        np.ascontiguousarray(eta.real.ravel()), np.ascontiguousarray(eta.imag.ravel()), lam,
        float(number_density_m3), float(eta_medium), _method(method), float(hybrid_radius_um), _p_max(p_max),
        float(max_log_step), mie_dx if mie_dx is None else float(mie_dx), th, bool(phase), cut, float(refine_tol), int(refine_max_nodes),
        goa_cache, bool(mueller))
    albedo = np.divide(ss, st, out=np.zeros_like(st), where=st > 0)
    result = {"wavelength_um": lam, "sigma_t": st, "sigma_s": ss, "sigma_a": sa, "albedo": albedo, "g": g,
              "theta": th, "phase": ph, "energy_ratio": ratio, "peak_fraction": frac}
    if mueller:
        result["mueller"] = mm
    if path is not None:
        _cache_store(path, result)
    return result


class SpectralTable:
    """Bulk properties tabulated at a few wavelengths (>= 2; the paper uses 8 over the visible) and
    interpolated linearly in wavelength at any wavelength inside the tabulated range — what a spectral
    renderer needs per sampled wavelength. ``scripts/figures/spectral_interpolation.py`` measures the error.

    ``SpectralTable(species, number_density_m3, wavelength_um=SPECTRAL_WAVELENGTHS_UM, **bulk_kwargs)``"""

    def __init__(self, species, number_density_m3: float, wavelength_um=None, **kwargs):
        if wavelength_um is None:
            wavelength_um = SPECTRAL_WAVELENGTHS_UM
        lam = np.sort(np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64)))
        if lam.size < 2 or np.any(np.diff(lam) <= 0):
            raise ValueError("wavelength_um must hold at least 2 distinct wavelengths")
        self.bulk = bulk_properties(species, number_density_m3, lam, **kwargs)
        self.wavelength_um = lam

    def at(self, wavelength_um) -> dict:
        """sigma_t, sigma_s, sigma_a (1/m), albedo, g and phase (n, n_theta) at the given wavelengths."""
        q = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
        lo, hi = self.wavelength_um[0], self.wavelength_um[-1]
        if np.any(~np.isfinite(q)) or np.any(q < lo) or np.any(q > hi):
            raise ValueError(f"wavelength_um must lie in the tabulated range [{lo}, {hi}] um")
        out = {k: np.interp(q, self.wavelength_um, self.bulk[k]) for k in ("sigma_t", "sigma_s", "sigma_a", "g")}
        out["albedo"] = np.divide(out["sigma_s"], out["sigma_t"], out=np.zeros_like(q), where=out["sigma_t"] > 0)
        if self.bulk["phase"].size:
            i = np.clip(np.searchsorted(self.wavelength_um, q) - 1, 0, self.wavelength_um.size - 2)
            w = (q - self.wavelength_um[i]) / (self.wavelength_um[i + 1] - self.wavelength_um[i])
            out["phase"] = (1 - w)[:, None] * self.bulk["phase"][i] + w[:, None] * self.bulk["phase"][i + 1]
            out["theta"] = self.bulk["theta"]
        out["wavelength_um"] = q
        return out


class PhaseTable:
    """A tabulated phase function, piecewise linear in cos(theta) between the nodes ``theta`` (from 0 to
    pi, increasing), normalised over the sphere. ``eval``/``pdf`` give f (1/sr) and ``sample`` draws
    scattering angles from exactly that density (inverse CDF, O(log n) per sample).

    ``PhaseTable.from_bulk(b, i)`` takes wavelength ``i`` of a ``bulk_properties`` result."""

    def __init__(self, theta, f):
        self.theta = np.ascontiguousarray(np.asarray(theta, dtype=np.float64))
        self.f = np.ascontiguousarray(np.asarray(f, dtype=np.float64))
        self._core = _motes.PhaseTable(self.theta, self.f)  # validated and prepared once

    @classmethod
    def from_bulk(cls, bulk: dict, index: int = 0) -> "PhaseTable":
        return cls(bulk["theta"], bulk["phase"][index])

    def eval(self, theta):
        q = np.asarray(theta, dtype=np.float64)
        return self._core.eval(np.ascontiguousarray(q).ravel()).reshape(q.shape)

    pdf = eval

    def sample(self, u):
        """Scattering angles (radians) for uniform numbers ``u`` in [0, 1]."""
        u = np.asarray(u, dtype=np.float64)
        return self._core.sample(np.ascontiguousarray(u).ravel()).reshape(u.shape)


__all__ = ["CORE_HASH", "DEFAULT_TRUNCATE_RAD", "RGB_WAVELENGTHS_UM", "SPECTRAL_WAVELENGTHS_UM", "cache_dir", "Material", "PhaseTable", "SpectralTable", "Species", "bulk_properties", "pixel_footprint_rad"]
