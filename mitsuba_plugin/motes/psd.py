"""Particle size distributions (paper Sec. 4.1, Eq. 15), radii in micrometres.

==================  ======================================================================================
``LogNormal``       Eq. 15: median ``r_g`` (the paper's geometric mean radius) and geometric standard
                    deviation ``sigma_g >= 1``, truncated to ``[r_min_um, r_max_um]`` (default
                    [0.001, 2000] um). ``sigma_g = 1`` is exactly monodisperse.
``Monodisperse``    every particle of ``radius_um``
``Uniform``         uniform in r on ``[r_min_um, r_max_um]`` (the paper's Fig. 8)
``Histogram``       ``counts[i]`` particles spread evenly over ``[edges_um[i], edges_um[i+1]]``
``Radii``           an explicit list of particle radii (e.g. from a simulation), one particle each;
                    at least two (one radius is ``Monodisperse``)
``Mixture``         number-weighted mixture, e.g. the bimodal snow of Fig. 19:
                    ``Mixture([(0.995, LogNormal(100, 1)), (0.005, LogNormal(800, 2))])``
==================  ======================================================================================

Every distribution offers ``cdf(r)``, ``pdf(r)`` (density of the continuous part, 1/um), ``atoms()``
(point masses), ``quantile(u)``, ``sample(n, seed)`` (reproducible, any thread count),
``quadrature(max_log_step)`` (nodes and weights with ``sum(w * g(r)) ~ E[g(R)]``), ``support()`` and
``mean(k)`` (E[r^k]). The numbers are computed in Rust; these classes only describe the distribution and
validate it there (a bad parameter raises ``ValueError`` naming it).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from . import _memory, _motes


def _check_finite(spec: dict) -> None:
    """NaN/inf cannot travel as JSON: name the parameter here."""
    for key, value in spec.items():
        values = value if isinstance(value, list) else [value]
        for v in values:
            if isinstance(v, dict):
                _check_finite(v)
            elif isinstance(v, float) and not np.isfinite(v):
                raise ValueError(f"invalid {key} = {v}: must be finite")


class Psd:
    """Base class: a distribution of the radius of one particle."""

    def spec(self) -> dict:  # pragma: no cover - overridden
        raise NotImplementedError

    def _json(self) -> str:
        spec = self.spec()
        _check_finite(spec)
        return json.dumps(spec)

    def __post_init__(self) -> None:
        # Parsed and validated once; every query below reuses the Rust object (frozen dataclasses:
        # an attribute outside the fields, so it takes no part in ==, hash or repr).
        object.__setattr__(self, "_core", _motes.Psd(self._json()))

    def _eval(self, what: str, x):
        x = np.asarray(x, dtype=np.float64)
        return self._core.eval(what, np.ascontiguousarray(x).ravel()).reshape(x.shape)

    def cdf(self, radius_um):
        """P(R <= r)."""
        return self._eval("cdf", radius_um)

    def pdf(self, radius_um):
        """Density of the continuous part (1/um); point masses are in :meth:`atoms`."""
        return self._eval("pdf", radius_um)

    def quantile(self, u):
        """Radius r with P(R <= r) = u, u in [0, 1]."""
        return self._eval("quantile", u)

    def sample(self, n: int, seed: int = 0) -> np.ndarray:
        """``n`` radii (um), reproducible from ``seed`` whatever the number of threads."""
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be a non-negative integer, got {n!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**64:
            raise ValueError(f"seed must be an integer in [0, 2**64), got {seed!r}")
        _memory.require(16.0 * n, f"sample(n={n})")
        return self._core.sample(int(n), int(seed))

    def quadrature(self, max_log_step: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (um) and weights summing to 1: Gauss-Legendre in ln r on panels of at most
        ``max_log_step``, plus one node per atom."""
        return self._core.quadrature(float(max_log_step))

    def support(self) -> tuple[float, float]:
        """Smallest and largest radius with non-zero probability."""
        return self._core.support()[0]

    def atoms(self) -> list[tuple[float, float]]:
        """Point masses as (radius_um, probability)."""
        return self._core.support()[1]

    def mean(self, k: float = 1.0, max_log_step: float = 0.02) -> float:
        """E[R^k] in um^k (k = 2: mean cross-section area / pi; k = 3: mean volume * 3/(4 pi))."""
        r, w = self.quadrature(max_log_step)
        return float(np.sum(w * r**k))


@dataclass(frozen=True)
class LogNormal(Psd):
    median_um: float
    sigma_g: float
    r_min_um: float = 1e-3
    r_max_um: float = 2000.0

    def spec(self) -> dict:
        return {"type": "lognormal", "median_um": float(self.median_um), "sigma_g": float(self.sigma_g),
                "r_min_um": float(self.r_min_um), "r_max_um": float(self.r_max_um)}


@dataclass(frozen=True)
class Monodisperse(Psd):
    radius_um: float

    def spec(self) -> dict:
        return {"type": "monodisperse", "radius_um": float(self.radius_um)}


@dataclass(frozen=True)
class Uniform(Psd):
    r_min_um: float
    r_max_um: float

    def spec(self) -> dict:
        return {"type": "uniform", "r_min_um": float(self.r_min_um), "r_max_um": float(self.r_max_um)}


@dataclass(frozen=True)
class Histogram(Psd):
    edges_um: Sequence[float]
    counts: Sequence[float]

    def spec(self) -> dict:
        return {"type": "histogram", "edges_um": [float(e) for e in self.edges_um], "counts": [float(c) for c in self.counts]}


@dataclass(frozen=True)
class Radii(Psd):
    radii_um: Sequence[float]

    def spec(self) -> dict:
        return {"type": "radii", "radii_um": [float(r) for r in np.asarray(self.radii_um, dtype=np.float64).ravel()]}


@dataclass(frozen=True)
class Mixture(Psd):
    """``components`` is a sequence of ``(number_share, Psd)``; shares need not sum to 1."""

    components: Sequence[tuple[float, Psd]] = field(default_factory=tuple)

    def spec(self) -> dict:
        for item in self.components:
            if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[1], Psd)):
                raise ValueError(f"Mixture components must be (share, Psd) pairs, got {item!r}")
        return {"type": "mixture", "weights": [float(w) for w, _ in self.components],
                "components": [c.spec() for _, c in self.components]}


def from_spec(spec) -> Psd:
    """A distribution from its ``spec()`` dict (or that dict as a JSON string), e.g.
    ``{"type": "lognormal", "median_um": 20, "sigma_g": 1.5}``."""
    if isinstance(spec, str):
        try:
            spec = json.loads(spec)
        except json.JSONDecodeError as e:
            raise ValueError(f"psd: not valid JSON ({e})") from None
    if not isinstance(spec, dict) or "type" not in spec:
        raise ValueError(f'psd: expected a dict with a "type" key, got {spec!r}')
    kind = spec["type"]
    args = {k: v for k, v in spec.items() if k != "type"}
    classes = {"lognormal": LogNormal, "monodisperse": Monodisperse, "uniform": Uniform, "histogram": Histogram,
               "radii": Radii}
    if kind == "mixture":
        w, comps = args.get("weights"), args.get("components")
        if not isinstance(w, list) or not isinstance(comps, list) or len(w) != len(comps):
            raise ValueError("psd: a mixture needs equally long lists \"weights\" and \"components\"")
        return Mixture(tuple((float(a), from_spec(c)) for a, c in zip(w, comps)))
    if kind not in classes:
        raise ValueError(f"psd: unknown type {kind!r} (one of {sorted(classes) + ['mixture']})")
    try:
        return classes[kind](**args)
    except TypeError as e:
        raise ValueError(f"psd {kind!r}: {e}") from None


__all__ = ["from_spec", "Psd", "LogNormal", "Monodisperse", "Uniform", "Histogram", "Radii", "Mixture"]
