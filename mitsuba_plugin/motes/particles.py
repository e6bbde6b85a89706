"""Particles in space (paper Sec. 5.2-5.3): a uniform grid over particle centres, optical depth along
query cylinders (Eq. 18) and exact free-flight sampling; generators of particle sets and the query radius
from a camera (Eq. 23).

``ParticleGrid(positions, radii_um, c_ext_um2, scale_m=1.0, query_radius=..., cells_per_particle=0.125)``

==============================  ======================================================================
``positions``                   (n, 3) particle centres, scene units
``radii_um``                    (n,) particle radii, micrometres
``c_ext_um2``                   (n,) or (n, channels) extinction cross sections, um^2 (e.g. one per RGB
                                channel or wavelength; ``extinction_um2`` computes them from species)
``scale_m``                     metres per scene unit, so um radii and scene positions combine correctly
``query_radius``                r_c of the query cylinder, scene units (Eq. 23 gives it from a camera:
                                ``query_radius_from_camera``)
``cells_per_particle``          grid resolution (``DEFAULT_CELLS_PER_PARTICLE`` = 0.125: about eight
                                particles per cell, each cell's spheres tested four at a time)
``uniform_box``                 ``(n, lo, hi, psd, seed)``: n centres uniform in the box [lo, hi], radii
                                (um) from ``psd``
``density_box``                 ``(n, lo, hi, density, psd, seed, max_density)``: n centres in [lo, hi]
                                with probability proportional to ``density(x)`` (spatially varying
                                concentration), by batched rejection sampling against ``max_density``
``Gradient``                    preset density: linear ramp from ``start`` on the ``lo`` face to ``end``
                                on the ``hi`` face along ``axis``
``Noise``                       preset density: smooth fBm value noise, ``1 + contrast * (2 v - 1)``
                                clipped at 0, v in [0, 1]; ``scale`` is the coarsest feature size
``query_radius_from_camera``    ``(k, fov_deg, width_px, z_med)``: r_c = k tan(fov/2) z_med / width_px,
                                Eq. 23 with S_A read as the cylinder's diameter
``nearest_depth``               ``(camera_origin, camera_forward, lo, hi)``: z_med, the smallest depth of
                                the medium's bounding box, floored at a small positive depth
==============================  ======================================================================

A particle contributes ``C_t / (pi R^2)`` to a segment when the ray passes within ``R = r_c + r_p`` of
its centre and the centre's projection lies on the segment: the expected optical depth per unit length is
then exactly the bulk sigma_t, for any r_c (see ``rust/motes-core/src/space/grid/mod.rs``). Queries are batched over
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
                 cells_per_particle: float = _motes.DEFAULT_CELLS_PER_PARTICLE):
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
        return self._grid.optical_depth((o, d, a, b), bool(brute)).reshape(n, self.channels)

    def occupied_interval(self, origins, directions, t0, t1, *, brute: bool = False):
        """(first, last): the smallest and largest t on [t0, t1) where a particle contributes, NaN where
        none — everything outside can be skipped (empty-space skipping)."""
        o, d, (a, b), n = self._rays(origins, directions, t0, t1)
        return self._grid.occupied_interval((o, d, a, b), bool(brute))

    def transmittance(self, origins, directions, t0, t1) -> np.ndarray:
        return np.exp(-self.optical_depth(origins, directions, t0, t1))

    def free_flight(self, origins, directions, t0, t1, u, channel: int = 0):
        """Exact free-flight sampling: (t, particle index, transmittance up to t); t = NaN and index = -1
        where the ray leaves [t0, t1) without interacting (then the transmittance is the segment's)."""
        o, d, (a, b, uu), n = self._rays(origins, directions, t0, t1, u)
        return self._grid.free_flight((o, d, a, b), uu, int(channel))


def uniform_box(n: int, lo, hi, psd, seed: int = 0):
    """n particle centres uniform in the box [lo, hi] (scene units) and radii (um) drawn from ``psd``,
    reproducible from ``seed``."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or np.any(hi <= lo):
        raise ValueError("lo and hi must be 3-vectors with hi > lo")
    rng = np.random.default_rng(seed)
    pos = lo + (hi - lo) * rng.random((int(n), 3))
    return pos, psd.sample(int(n), seed=seed)



def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    try:
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"lo and hi must be 3-vectors of numbers, got lo={lo!r}, hi={hi!r}") from None
    if lo.shape != (3,) or hi.shape != (3,):
        raise ValueError(f"lo and hi must be 3-vectors, got shapes {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"lo and hi must be finite, got lo={lo.tolist()}, hi={hi.tolist()}")
    if np.any(hi <= lo):
        ax = int(np.flatnonzero(hi <= lo)[0])
        raise ValueError(f"box must have hi > lo on every axis, got lo[{ax}] = {lo[ax]} >= hi[{ax}] = {hi[ax]}")
    return lo, hi


def _positive_int(value, name: str, least: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
        raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
    return int(value)


def _finite(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


class Gradient:
    """Preset density for ``density_box``: relative density ``start`` on the box's ``lo`` face along
    ``axis`` (0/1/2 or "x"/"y"/"z") rising (or falling) linearly to ``end`` on its ``hi`` face; both >= 0,
    not both 0. Its maximum, ``max(start, end)``, is the exact rejection bound."""

    def __init__(self, axis=2, start: float = 1.0, end: float = 0.0):
        axes = {"x": 0, "y": 1, "z": 2}
        if isinstance(axis, str) and axis.lower() in axes:
            axis = axes[axis.lower()]
        if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or axis not in (0, 1, 2):
            raise ValueError(f"axis must be 0, 1, 2 or 'x', 'y', 'z', got {axis!r}")
        self.axis = int(axis)
        self.start, self.end = _finite(start, "start"), _finite(end, "end")
        if self.start < 0 or self.end < 0:
            raise ValueError(f"start and end must be >= 0, got start={self.start}, end={self.end}")
        if self.start == 0 and self.end == 0:
            raise ValueError("start and end are both 0: the density is zero everywhere")

    def __repr__(self) -> str:
        return f"Gradient(axis={self.axis}, start={self.start}, end={self.end})"

    def bound(self, lo, hi) -> float:
        return max(self.start, self.end)

    def evaluate(self, positions, lo, hi) -> np.ndarray:
        p = np.asarray(positions, dtype=np.float64)
        t = np.clip((p[:, self.axis] - lo[self.axis]) / (hi[self.axis] - lo[self.axis]), 0.0, 1.0)
        d = self.start + (self.end - self.start) * t
        return np.clip(d, min(self.start, self.end), max(self.start, self.end))


class Noise:
    """Preset density for ``density_box``: smooth procedural fBm value noise, deterministic from ``seed``.

    v(x) in [0, 1] is the amplitude-weighted mean of ``octaves`` octaves of value noise (lattice values
    hashed from the integer cell and the seed, quintic-smoothstep interpolation, so C2), octave o having
    lattice spacing ``scale / 2**o`` (scene units) and weight ``2**-o``. The density is
    ``max(0, 1 + contrast * (2 v - 1))``: ``contrast`` in [0, 1] keeps it positive everywhere, larger
    values carve empty regions. ``1 + contrast`` is the exact rejection bound. Call it on an (m, 3)
    array to evaluate it."""

    def __init__(self, scale: float = 1.0, octaves: int = 4, seed: int = 0, contrast: float = 1.0):
        self.scale = _finite(scale, "scale")
        if self.scale <= 0:
            raise ValueError(f"scale must be > 0, got {scale!r}")
        if isinstance(octaves, bool) or not isinstance(octaves, (int, np.integer)) or not 1 <= octaves <= 16:
            raise ValueError(f"octaves must be an integer in [1, 16], got {octaves!r}")
        self.octaves = int(octaves)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**64:
            raise ValueError(f"seed must be an integer in [0, 2**64), got {seed!r}")
        self.seed = int(seed)
        self.contrast = _finite(contrast, "contrast")
        if self.contrast < 0:
            raise ValueError(f"contrast must be >= 0, got {contrast!r}")
    def __repr__(self) -> str:
        return f"Noise(scale={self.scale}, octaves={self.octaves}, seed={self.seed}, contrast={self.contrast})"

    def value(self, positions) -> np.ndarray:
        """v(x) in [0, 1], shape (m,) (computed in the core: ``motes_core::space::cloud::ValueNoise``, the
        same noise the ``discrete`` plugin's ``distribution="noise"`` generates from)."""
        p = np.ascontiguousarray(np.asarray(positions, dtype=np.float64).reshape(-1, 3))
        return _motes.value_noise(p.ravel(), self.scale, self.octaves, self.seed, 1.0)

    def __call__(self, positions) -> np.ndarray:
        return np.clip(1.0 + self.contrast * (2.0 * self.value(positions) - 1.0), 0.0, 1.0 + self.contrast)

    def bound(self, lo, hi) -> float:
        return 1.0 + self.contrast

    def evaluate(self, positions, lo, hi) -> np.ndarray:
        return self(positions)


def _check_density(d, pos: np.ndarray) -> np.ndarray:
    m = pos.shape[0]
    try:
        d = np.asarray(d, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"density must return real numbers, got {type(d).__name__}") from None
    if d.shape != (m,):
        raise ValueError(f"density must return an array of shape ({m},) for positions of shape ({m}, 3), got shape {d.shape}")
    for bad, what in ((~np.isfinite(d), "non-finite (NaN or inf)"), (d < 0, "negative")):
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            raise ValueError(f"density returned {int(bad.sum())} {what} value(s) of {m}, e.g. {d[j]} at position {pos[j].tolist()}")
    return d


_PROBE_GRID = 17  # 17^3 lattice points including the faces, plus as many random points
_INFLATE = 1.5
_MAX_PROPOSALS = 2**27


def density_box(n: int, lo, hi, density, psd, seed: int = 0, max_density: float | None = None):
    """n particle centres in the box [lo, hi] (scene units) with probability density proportional to
    ``density(x)``, and radii (um) drawn from ``psd`` (as in ``uniform_box``); reproducible from ``seed``.

    ``density`` is a preset (``Gradient``, ``Noise``) or a vectorised callable taking an (m, 3) array of
    positions and returning m finite, non-negative relative densities. Centres are drawn by batched
    rejection sampling: uniform proposals ``x`` kept when ``u * max_density < density(x)``. Presets know
    their exact maximum; for a callable, ``max_density=None`` estimates it as 1.5 x the largest value on a
    17^3 lattice plus 4913 random points. Every proposal is checked against the bound, and a value above it
    raises (pass a larger ``max_density``) rather than silently biasing the distribution."""
    n = _positive_int(n, "n")
    lo, hi = _box(lo, hi)
    preset = isinstance(density, (Gradient, Noise))
    if not preset and not callable(density):
        raise TypeError(f"density must be a callable, Gradient or Noise, got {type(density).__name__}")
    evaluate = (lambda p: density.evaluate(p, lo, hi)) if preset else density
    rng = np.random.default_rng(seed)

    def dens(p):
        return _check_density(evaluate(p), p)

    estimated = False
    if max_density is not None:
        bound = _finite(max_density, "max_density")
        if bound <= 0:
            raise ValueError(f"max_density must be > 0, got {max_density!r}")
    elif preset:
        bound = float(density.bound(lo, hi))
    else:
        g = (np.arange(_PROBE_GRID) / (_PROBE_GRID - 1))
        lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        probe = lo + (hi - lo) * np.vstack([lattice, rng.random((lattice.shape[0], 3))])
        peak = float(dens(probe).max())
        if peak == 0:
            raise ValueError(f"density is 0 at all {probe.shape[0]} probe positions in the box; if it is non-zero "
                             "only on a small region, pass max_density")
        bound, estimated = _INFLATE * peak, True

    out = np.empty((n, 3))
    filled = proposed = 0
    positive = False
    rate = 0.5
    while filled < n:
        if proposed >= _MAX_PROPOSALS:
            raise ValueError(f"acceptance too low: {filled} of {proposed} proposals accepted (mean density / "
                             f"max_density ~ {filled / proposed:.2e}); pass a tighter max_density")
        batch = int(np.clip(np.ceil(1.2 * (n - filled) / rate) + 64, 1024, 2**20))
        p = lo + (hi - lo) * rng.random((batch, 3))
        u = rng.random(batch)
        d = dens(p)
        over = d > bound
        if over.any():
            j = int(np.flatnonzero(over)[0])
            how = (f"the estimated bound {bound:.6g} ({_INFLATE} x the largest probed value)" if estimated
                   else f"max_density = {bound:.6g}")
            raise ValueError(f"density {d[j]:.6g} at position {p[j].tolist()} exceeds {how}; pass a larger max_density")
        positive = positive or bool((d > 0).any())
        keep = p[u * bound < d]
        take = min(keep.shape[0], n - filled)
        out[filled:filled + take] = keep[:take]
        filled += take
        proposed += batch
        if not positive and proposed >= 2**16:
            raise ValueError(f"density is 0 at all {proposed} proposed positions in the box: nothing to sample")
        rate = max(filled / proposed, 1e-6) if filled else rate / 8
    return out, psd.sample(n, seed=seed)


def query_radius_from_camera(k: float, fov_deg: float, width_px: int, z_med: float) -> float:
    """Query-cylinder radius r_c (scene units) for a pinhole camera (paper Sec. 5.2, Eq. 23).

    Eq. 23: ``S_A = k * S_pix * z_med / z_near``. S_A is read as the cylinder's cross-section diameter (a
    length: it scales linearly with depth) and S_pix as the pixel's side on the near plane,
    ``2 z_near tan(fov/2) / width_px``, so z_near cancels and ``r_c = S_A / 2 = k tan(fov/2) z_med / width_px``:
    the cylinder covers the fraction k of a pixel's footprint at depth z_med (``nearest_depth``). The paper
    finds k in [0.5, 1] gives satisfactory results; k in (0, 2] is accepted. ``fov_deg`` is the horizontal
    field of view in (0, 180) degrees, ``width_px`` the image width in pixels (integer >= 1), z_med > 0."""
    k = _finite(k, "k")
    if not 0 < k <= 2:
        raise ValueError(f"k must be in (0, 2] (the paper advises [0.5, 1]), got {k!r}")
    fov = _finite(fov_deg, "fov_deg")
    if not 0 < fov < 180:
        raise ValueError(f"fov_deg must be in (0, 180) degrees, got {fov_deg!r}")
    w = _positive_int(width_px, "width_px")
    z = _finite(z_med, "z_med")
    if z <= 0:
        raise ValueError(f"z_med must be > 0, got {z_med!r}")
    # Eq. 23 with S_pix = 2 z_near tan(fov/2) / width_px and r_c = S_A / 2
    return float(k * np.tan(np.radians(fov) / 2) * z / w)


def nearest_depth(camera_origin, camera_forward, lo, hi, min_depth: float | None = None) -> float:
    """z_med of Eq. 23: the smallest depth ``dot(p - camera_origin, forward / |forward|)`` over the
    medium's bounding box [lo, hi], i.e. the minimum over its 8 corners (exact for a box; it may be smaller
    than the depth of the box's part inside the view frustum, which only makes r_c more conservative).

    When the camera is inside the box or the box reaches behind the camera, that minimum is <= 0; it is
    then clamped to ``min_depth`` (default 1e-4 x the box's diagonal), a small positive floor that keeps
    Eq. 23 finite — the resulting r_c is tiny, so with the camera inside the medium choose z_med (e.g.
    the near-clip distance) yourself."""
    try:
        o = np.asarray(camera_origin, dtype=np.float64)
        f = np.asarray(camera_forward, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("camera_origin and camera_forward must be 3-vectors of numbers") from None
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise ValueError(f"camera_origin must be a finite 3-vector, got {camera_origin!r}")
    if f.shape != (3,) or not np.all(np.isfinite(f)) or not np.linalg.norm(f) > 0:
        raise ValueError(f"camera_forward must be a finite non-zero 3-vector, got {camera_forward!r}")
    lo, hi = _box(lo, hi)
    if min_depth is None:
        floor = 1e-4 * float(np.linalg.norm(hi - lo))
    else:
        floor = _finite(min_depth, "min_depth")
        if floor <= 0:
            raise ValueError(f"min_depth must be > 0, got {min_depth!r}")
    f = f / np.linalg.norm(f)
    corners = np.array([[(hi if (c >> a) & 1 else lo)[a] for a in range(3)] for c in range(8)])
    return max(float(((corners - o) @ f).min()), floor)


__all__ = ["ParticleGrid", "extinction_um2", "uniform_box", "density_box", "Gradient", "Noise",
           "query_radius_from_camera", "nearest_depth"]
