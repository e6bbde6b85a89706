"""Shared helpers for the motes test suite.

* ``relmse`` — the paper's error measure of GOA against Mie.
* ``mie_reference`` — an independent 40-digit (mpmath) Lorenz–Mie evaluation, used as a referee
  where the primary oracle ``miepython`` is itself not accurate enough (e.g. back-scattering at x ~ 1e3,
  where miepython 3.3.0 is off by ~2e-6 relative).
* hypothesis settings: one profile ("motes") that every property test uses — derandomised so CI is
  reproducible, no deadline (example cost varies by orders of magnitude with the size parameter), no
  example database (nothing written into the tree).
* strategies shared by the property tests.
* ``cube_scene`` — the small Mitsuba scene of the plugin tests: a medium in a cube under a constant sky.
"""

from __future__ import annotations

import math

import os
import tempfile

import numpy as np

# Tests never touch the user's cache: a fresh one per test session.
os.environ["MOTES_CACHE_DIR"] = tempfile.mkdtemp(prefix="motes-test-cache-")
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

settings.register_profile(
    "motes",
    derandomize=True,
    deadline=None,
    database=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("motes")


def hsettings(max_examples: int) -> settings:
    """Per-test hypothesis settings: the "motes" profile with an explicit example budget."""
    return settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow],
    )


def relmse(goa, mie) -> float:
    """RelMSE = mean((G - M)^2) / mean(M^2) with G, M = (|S1| + |S2|)/2 of GOA and Mie on one grid.

    ``goa`` and ``mie`` are ``(S1, S2)`` pairs as returned by ``goa_amplitudes`` / ``mie_amplitudes``."""
    g = 0.5 * (np.abs(goa[0]) + np.abs(goa[1]))
    m = 0.5 * (np.abs(mie[0]) + np.abs(mie[1]))
    return float(np.mean((g - m) ** 2) / np.mean(m**2))


def log_uniform(lo: float, hi: float, buckets: int = 256) -> st.SearchStrategy[float]:
    """Floats spread uniformly in log10 between ``lo`` and ``hi`` (both reachable; clipped to [lo, hi]).

    Drawn as a bucket index plus a position inside the bucket: hypothesis draws small bounded integers
    nearly uniformly, whereas ``st.floats(a, b)`` concentrates on "simple" values (0, 1, the bounds), which
    would leave the top decades of r — the expensive, most asymptotic ones — almost untested."""
    a, b = math.log10(lo), math.log10(hi)

    def value(bucket_and_offset):
        bucket, offset = bucket_and_offset
        e = a + (b - a) * (bucket + offset) / buckets
        return min(max(10.0**e, lo), hi)

    return st.tuples(st.integers(0, buckets - 1), st.floats(0.0, 1.0)).map(value)


# --- a small Mitsuba scene ---------------------------------------------------------------------------


def cube_scene(interior: dict, res: int = 8):
    """A volpath scene: a unit cube with a null BSDF and the medium ``interior``, under a constant
    environment, seen by a ``res`` x ``res`` perspective camera at z = 5 (Mitsuba's current variant)."""
    import mitsuba as mi

    return mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath"},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": res, "height": res},
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])},
        "env": {"type": "constant"},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": interior}})


# --- an independent high-precision Mie reference -------------------------------------------------


def mie_reference(x: float, m: complex, mu, dps: int = 40):
    """Lorenz–Mie by mpmath at ``dps`` digits (Bohren–Huffman; ``m = n + i kappa``, kappa >= 0).

    Returns ``(f, q_ext, q_sca)`` with ``f`` the phase function (|S1|^2+|S2|^2)/(2 pi x^2 Q_sca)
    normalised to 1 over 4 pi at the cosines ``mu``. Written from Bohren & Huffman §4.8 only: downward
    recurrence of the logarithmic derivative from far beyond |mx|, upward Riccati–Bessel recurrence
    (its loss of a few digits for n > x is irrelevant at 40 digits). Costs ~0.3 s at x = 1e3."""
    import mpmath as mpm

    with mpm.workdps(dps):
        xm = mpm.mpf(x)
        mm = mpm.mpc(m.real, m.imag)
        nmax = int(x + 4.3 * x ** (1.0 / 3.0) + 20)
        mx = mm * xm
        amx = abs(complex(mx))
        nstart = int(max(nmax, amx + 16.0 * amx ** (1.0 / 3.0))) + 100
        d = [mpm.mpc(0)] * (nstart + 1)
        for n in range(nstart, 0, -1):
            nz = n / mx
            d[n - 1] = nz - 1 / (d[n] + nz)
        psi_prev, chi_prev = mpm.sin(xm), mpm.cos(xm)
        psi, chi = psi_prev / xm - chi_prev, chi_prev / xm + psi_prev
        a, b = [], []
        for n in range(1, nmax + 1):
            if n > 1:
                psi_n = (2 * n - 1) / xm * psi - psi_prev
                chi_n = (2 * n - 1) / xm * chi - chi_prev
                psi_prev, chi_prev, psi, chi = psi, chi, psi_n, chi_n
            xi, xi_prev = mpm.mpc(psi, -chi), mpm.mpc(psi_prev, -chi_prev)
            ta, tb = d[n] / mm + n / xm, d[n] * mm + n / xm
            a.append((ta * psi - psi_prev) / (ta * xi - xi_prev))
            b.append((tb * psi - psi_prev) / (tb * xi - xi_prev))
        q_ext = 2 / xm**2 * mpm.fsum((2 * n + 1) * (a[n - 1] + b[n - 1]).real for n in range(1, nmax + 1))
        q_sca = 2 / xm**2 * mpm.fsum((2 * n + 1) * (abs(a[n - 1]) ** 2 + abs(b[n - 1]) ** 2) for n in range(1, nmax + 1))
        f = []
        for u in np.atleast_1d(mu):
            u = mpm.mpf(float(u))
            p_prev, p = mpm.mpf(0), mpm.mpf(1)
            s1 = s2 = mpm.mpc(0)
            for n in range(1, nmax + 1):
                if n > 1:
                    p_prev, p = p, ((2 * n - 1) * u * p - n * p_prev) / (n - 1)
                tau = n * u * p - (n + 1) * p_prev
                c = mpm.mpf(2 * n + 1) / (n * (n + 1))
                s1 += c * (a[n - 1] * p + b[n - 1] * tau)
                s2 += c * (b[n - 1] * p + a[n - 1] * tau)
            f.append((abs(s1) ** 2 + abs(s2) ** 2) / (2 * mpm.pi * xm**2 * q_sca))
        return np.array([float(v) for v in f]), float(q_ext), float(q_sca)


# --- an independent ensemble (log-normal PSD) Mie reference ---------------------------------------


def lognormal_mie_phase(m: complex, wavelength_um: float, median_um: float, sigma_g: float, theta, dx: float = 0.005,
                        x_uniform_below: float = 50.0, z_half_width: float = 5.0, eta_medium: float = 1.0):
    """Ensemble phase function (1/sr, integral 1 over the sphere) of a log-normal PSD (Eq. 15) at the
    angles ``theta``, from miepython's amplitudes — the paper's Eq. 17 by a plain trapezoid rule on a
    radius grid of its own, independent of the motes quadrature and angle grid.

    The grid is uniform in the size parameter x (step ``dx``, fine enough to average Mie's resonances)
    up to ``x_uniform_below``, then uniform in ln x (step ``dx / x_uniform_below``), and spans
    +-``z_half_width`` standard deviations around the centre of the r^2-weighted (scattering) mass,
    ln r = ln r_g + 2 ln^2 sigma_g. With miepython's ``norm="qsca"`` the amplitudes integrate to Q_sca
    over the sphere, so ``f = sum w x^2 (|S1|^2+|S2|^2)/2 / sum w x^2 Q_sca`` (k^2 cancels).

    Returns ``(f, f_half)``: ``f_half`` from every other radius alone (trapezoid on the coarser grid), so
    ``|f / f_half - 1|`` bounds the reference's own sampling error."""
    import miepython

    mu = np.cos(np.asarray(theta, dtype=np.float64))
    s = math.log(sigma_g)
    k = 2.0 * np.pi * eta_medium / wavelength_um
    x_lo, x_hi = (k * median_um * math.exp(s * (2 * s + sign * z_half_width)) for sign in (-1, 1))
    x = np.arange(x_lo, min(x_hi, x_uniform_below), dx)
    if x_hi > x_uniform_below:
        start = max(x_lo, x_uniform_below)
        x = np.concatenate([x, start * np.exp(np.arange(0.0, math.log(x_hi / start), dx / x_uniform_below))])
    z = (np.log(x / k / median_um)) / s
    density = np.exp(-0.5 * z * z) / x  # number per unit x, up to a constant
    m = complex(m) / eta_medium
    p = np.empty((x.size, mu.size))
    q = np.empty(x.size)
    for i, xi in enumerate(x):
        s1, s2 = miepython.S1_S2(m, xi, mu, norm="qsca")
        p[i] = 0.5 * (np.abs(s1) ** 2 + np.abs(s2) ** 2)
        q[i] = miepython.efficiencies_mx(m, xi)[1]

    def trapezoid(idx):
        xs = x[idx]
        w = np.zeros(xs.size)
        w[1:] += 0.5 * np.diff(xs)
        w[:-1] += 0.5 * np.diff(xs)
        w *= density[idx] * xs * xs
        return (w @ p[idx]) / (w @ q[idx])

    return trapezoid(np.arange(x.size)), trapezoid(np.arange(0, x.size, 2))
