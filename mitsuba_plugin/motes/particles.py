"""Particles in space (paper Sec. 5.2-5.3): a uniform grid over particle centres, optical depth along
query cylinders (Eq. 18) and exact free-flight sampling.

``ParticleGrid(positions, radii_um, c_ext_um2, scale_m=1.0, query_radius=..., cells_per_particle=1.0)``

==========================  ==========================================================================
``positions``               (n, 3) particle centres, scene units
``radii_um``                (n,) particle radii, micrometres
``c_ext_um2``               (n,) or (n, channels) extinction cross sections, um^2 (e.g. one per RGB
                            channel or wavelength; ``extinction_um2`` computes them from species)
``scale_m``                 metres per scene unit, so um radii and scene positions combine correctly
``query_radius``            r_c of the query cylinder, scene units (Eq. 23 gives it from a camera)
``cells_per_particle``      grid resolution; the paper's optimum is about one particle per voxel
==========================  ==========================================================================

A particle contributes ``C_t / (pi R^2)`` to a segment when the ray passes within ``R = r_c + r_p`` of
its centre and the centre's projection lies on the segment: the expected optical depth per unit length is
then exactly the bulk sigma_t, for any r_c (see ``rust/motes-core/src/grid.rs``). Queries are batched over
rays (numpy arrays), run in Rust with the GIL released.
"""

from __future__ import annotations

import numpy as np

from . import _motes
from ._optics import cross_sections


def extinction_um2(radii_um, species_index, species, wavelength_um, eta_medium: float = 1.0, method: str = "auto") -> np.ndarray:
    """C_ext (um^2) of each particle at each wavelength: shape (n, len(wavelength_um)). ``species_index``
    picks each particle's entry of ``species`` (a list of ``motes.Species``; only its index is used)."""
    r = np.asarray(radii_um, dtype=np.float64).ravel()
    idx = np.asarray(species_index, dtype=np.int64).ravel()
    lam = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
    if idx.shape != r.shape:
        raise ValueError("species_index must have one entry per particle")
    if idx.size and (idx.min() < 0 or idx.max() >= len(species)):
        bad = int(np.flatnonzero((idx < 0) | (idx >= len(species)))[0])
        raise ValueError(f"unknown species {int(idx[bad])} for particle {bad} (have {len(species)} species)")
    out = np.zeros((r.size, lam.size))
    for k, sp in enumerate(species):
        sel = idx == k
        if sel.any():
            eta = sp.index_at(lam)
            out[sel] = cross_sections(r[sel][:, None], lam[None, :], eta[None, :], method, eta_medium, asymmetry=False)["ext"]
    return out


class ParticleGrid:
    """Uniform grid over particles with batched optical-depth and free-flight queries (module docs)."""

    def __init__(self, positions, radii_um, c_ext_um2, *, scale_m: float = 1.0, query_radius: float = 0.0,
                 cells_per_particle: float = 1.0):
        pos = np.ascontiguousarray(np.asarray(positions, dtype=np.float64))
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise ValueError(f"positions must have shape (n, 3), got {pos.shape}")
        n = pos.shape[0]
        if n == 0:
            raise ValueError("positions: the particle set is empty")
        r = np.asarray(radii_um, dtype=np.float64).ravel()
        if r.size != n:
            raise ValueError(f"radii_um must have one entry per particle ({n}), got {r.size}")
        c = np.asarray(c_ext_um2, dtype=np.float64)
        c = c.reshape(n, -1) if c.size % n == 0 and c.size else c
        if c.ndim != 2 or c.shape[0] != n:
            raise ValueError(f"c_ext_um2 must have shape (n,) or (n, channels) with n = {n}")
        if not (np.isfinite(scale_m) and scale_m > 0):
            raise ValueError(f"invalid scale_m = {scale_m}: must be finite and > 0")
        um = 1e-6 / scale_m  # scene units per micrometre
        self.scale_m = float(scale_m)
        self._grid = _motes.ParticleGrid(pos.ravel(), np.ascontiguousarray(r * um), np.ascontiguousarray(c.ravel() * um * um),
                                         int(c.shape[1]), float(query_radius), float(cells_per_particle))

    def __len__(self) -> int:
        return len(self._grid)

    @property
    def channels(self) -> int:
        return self._grid.channels

    @property
    def dims(self) -> tuple[int, int, int]:
        return self._grid.dims

    @property
    def bytes(self) -> int:
        """Heap bytes of the grid with its particles."""
        return self._grid.bytes

    @staticmethod
    def _rays(origins, directions, *ts):
        o = np.ascontiguousarray(np.atleast_2d(np.asarray(origins, dtype=np.float64)))
        d = np.ascontiguousarray(np.atleast_2d(np.asarray(directions, dtype=np.float64)))
        o, d = np.broadcast_arrays(o, d)
        n = o.shape[0]
        ts = [np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (n,))) for t in ts]
        return np.ascontiguousarray(o).ravel(), np.ascontiguousarray(d).ravel(), ts, n

    def optical_depth(self, origins, directions, t0, t1, *, brute: bool = False) -> np.ndarray:
        """Optical depth of the segments [t0, t1) of the rays (directions need not be unit; t is in units
        of the normalised direction), shape (n_rays, channels). ``brute=True``: the O(N) loop."""
        o, d, (a, b), n = self._rays(origins, directions, t0, t1)
        return self._grid.optical_depth(o, d, a, b, bool(brute)).reshape(n, self.channels)

    def occupied_interval(self, origins, directions, t0, t1, *, brute: bool = False):
        """(first, last): the smallest and largest t on [t0, t1) where a particle contributes, NaN where
        none — everything outside can be skipped (empty-space skipping)."""
        o, d, (a, b), n = self._rays(origins, directions, t0, t1)
        return self._grid.occupied_interval(o, d, a, b, bool(brute))

    def transmittance(self, origins, directions, t0, t1) -> np.ndarray:
        return np.exp(-self.optical_depth(origins, directions, t0, t1))

    def free_flight(self, origins, directions, t0, t1, u, channel: int = 0):
        """Exact free-flight sampling: (t, particle index, transmittance up to t); t = NaN and index = -1
        where the ray leaves [t0, t1) without interacting (then the transmittance is the segment's)."""
        o, d, (a, b, uu), n = self._rays(origins, directions, t0, t1, u)
        return self._grid.free_flight(o, d, a, b, uu, int(channel))


def uniform_box(n: int, lo, hi, psd, seed: int = 0):
    """n particle centres uniform in the box [lo, hi] (scene units) and radii (um) drawn from ``psd``,
    reproducible from ``seed``."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or np.any(hi <= lo):
        raise ValueError("lo and hi must be 3-vectors with hi > lo")
    rng = np.random.default_rng(seed)
    pos = lo + (hi - lo) * rng.random((int(n), 3))
    return pos, psd.sample(int(n), seed=seed)


__all__ = ["ParticleGrid", "extinction_um2", "uniform_box"]
