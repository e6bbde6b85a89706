"""Particles in space (issue 4, first part): the grid equals a brute-force loop, the expected optical
depth equals the bulk sigma_t, free flights follow the transmittance, and bad inputs raise."""

from __future__ import annotations

import numpy as np
import pytest

import motes

PSD = motes.LogNormal(300.0, 2.0)
SPECIES = [motes.Species(PSD, 1.31), motes.Species(motes.Monodisperse(50.0), 1.5 + 0.01j)]


def _grid(n=20_000, seed=1, query_radius=0.01, cells_per_particle=1.0, scale_m=0.01, psd=PSD):
    pos, r = motes.uniform_box(n, [0, 0, 0], [1, 1, 1], psd, seed=seed)
    kind = np.random.default_rng(seed).integers(0, 2, n)
    cext = motes.extinction_um2(r, kind, SPECIES, [0.45, 0.65])
    return motes.ParticleGrid(pos, r, cext, scale_m=scale_m, query_radius=query_radius, cells_per_particle=cells_per_particle), pos, r, cext


@pytest.mark.parametrize(("query_radius", "cells_per_particle"), [(0.0, 1.0), (0.01, 1.0), (0.05, 0.1), (0.002, 8.0)])
def test_grid_equals_brute_force(query_radius, cells_per_particle):
    """Random rays, rays along each axis (both ways), rays starting inside, rays on voxel faces and
    through particle centres, zero-length segments and rays missing the grid: identical to the O(N) loop."""
    g, pos, _, _ = _grid(n=5000, query_radius=query_radius, cells_per_particle=cells_per_particle)
    rng = np.random.default_rng(3)
    o = rng.random((300, 3)) * 3 - 1
    d = rng.normal(size=(300, 3))
    t0 = np.zeros(300)
    t1 = rng.random(300) * 4
    axes = np.vstack([np.eye(3), -np.eye(3)])
    o_ax = np.array([0.5, 0.5, 0.5]) - 2 * axes
    o_face = np.tile(pos[:6], 1).reshape(6, 3)
    o_face[:, 0] = 0.25  # a plane through many cells
    origins = np.vstack([o, o_ax, o_face, pos[:10], [[0.5, 0.5, 0.5]], [[5.0, 5.0, 5.0]]])
    dirs = np.vstack([d, axes, axes, rng.normal(size=(10, 3)), [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]])
    a = np.concatenate([t0, np.zeros(6), np.zeros(6), -0.5 * np.ones(10), [0.3], [0.0]])
    b = np.concatenate([t1, 4 * np.ones(6), np.ones(6), 0.5 * np.ones(10), [0.3], [10.0]])
    fast = g.optical_depth(origins, dirs, a, b)
    slow = g.optical_depth(origins, dirs, a, b, brute=True)
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(np.array(g.occupied_interval(origins, dirs, a, b)), np.array(g.occupied_interval(origins, dirs, a, b, brute=True)))
    lo, hi = g.occupied_interval(origins, dirs, a, b)
    assert np.array_equal(np.isnan(lo), fast[:, 0] == 0)  # empty exactly where nothing contributes
    assert np.all(fast[-2:] == 0)  # zero length, miss
    assert np.any(fast > 0)


def test_mean_optical_depth_is_sigma_t():
    """Over random segments well inside a dense random set, <tau>/L equals sigma_t = N/V <C_ext> within
    1 %, and within 4 standard errors of the mean over rays. A narrow PSD keeps the particle set's own
    sampling noise (a few big grains dominating C_ext) below the bound."""
    g, _, _, cext = _grid(n=200_000, seed=5, query_radius=0.01, psd=motes.LogNormal(100.0, 1.2))
    rng = np.random.default_rng(7)
    n = 4000
    o = 0.3 + 0.4 * rng.random((n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = 0.1  # every segment stays > 0.1 (> the largest inclusion radius) inside the box
    tau = g.optical_depth(o, d, 0.0, length)
    sigma_t = cext.sum(0) * 1e-12 / 0.01**2  # per scene unit, V = 1
    mean = tau.mean(0) / length
    se = tau.std(0) / np.sqrt(n) / length
    assert np.all(np.abs(mean / sigma_t - 1) < 0.01), mean / sigma_t
    assert np.all(np.abs(mean - sigma_t) < 4 * se + 1e-12)


def test_free_flight_follows_transmittance():
    """The escape probability equals exp(-tau), and the hit positions follow the distribution the
    transmittance implies, P(t_hit <= t) = 1 - T(0, t) (KS distance below the 1 % critical value): the
    sampling is exact, with no majorant."""
    g, _, _, _ = _grid(n=20_000, seed=2, query_radius=0.05, scale_m=0.1)
    rng = np.random.default_rng(4)
    n = 20_000
    o = np.tile([0.5, 0.5, -0.2], (n, 1))
    d = np.tile([0.1, 0.2, 1.0], (n, 1))
    u = rng.random(n)
    t, idx, tr = g.free_flight(o, d, 0.0, 2.0, u, channel=1)
    tau = g.optical_depth(o[:1], d[:1], 0.0, 2.0)[0, 1]
    assert 0.2 < tau < 5
    escaped = np.isnan(t)
    assert np.all(idx[escaped] == -1) and np.all(idx[~escaped] >= 0)
    p = np.exp(-tau)
    assert abs(escaped.mean() - p) < 5 * np.sqrt(p * (1 - p) / n)
    np.testing.assert_allclose(tr[escaped], p, rtol=1e-12)
    # interaction at the first particle whose accumulated depth exceeds -ln(1-u): -ln(T) <= -ln(1-u)
    assert np.all(-np.log(tr[~escaped]) <= -np.log1p(-u[~escaped]) + 1e-9)
    # The hit positions follow P(t_hit <= t) = 1 - exp(-tau[0, t]) (particle at t included): one-sample
    # Kolmogorov-Smirnov distance on the (discrete) distribution, 1 % critical value 1.63/sqrt(n).
    th = np.sort(t[~escaped])
    ts = np.unique(th)
    empirical = np.searchsorted(th, ts, side="right") / n
    exact = 1 - np.exp(-g.optical_depth(np.tile(o[0], (ts.size, 1)), np.tile(d[0], (ts.size, 1)), 0.0, np.nextafter(ts, np.inf))[:, 1])
    assert np.max(np.abs(empirical - exact)) < 1.63 / np.sqrt(n)


def test_memory_and_errors():
    g, *_ = _grid(n=50_000)
    assert g.bytes / len(g) <= 40
    with pytest.raises(ValueError, match="positions"):
        motes.ParticleGrid(np.zeros((0, 3)), [], [])
    with pytest.raises(ValueError, match="positions"):
        motes.ParticleGrid([[0, 0, np.nan]], [1.0], [1.0])
    # the error names the first bad particle by its index in the caller's arrays
    big = np.tile([[0.1, 0.2, 0.3]], (5, 1))
    big[3, 1] = np.inf
    with pytest.raises(ValueError, match=r"positions.*= 3"):
        motes.ParticleGrid(big, [1.0, 1.0, 1.0, 1.0, 2000.0], np.ones(5))
    with pytest.raises(ValueError, match="radius"):
        motes.ParticleGrid([[0, 0, 0]], [-1.0], [1.0])
    with pytest.raises(ValueError, match="radii_um"):
        motes.ParticleGrid([[0, 0, 0], [1, 1, 1]], [1.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="species"):
        motes.extinction_um2([1.0, 2.0], [0, 5], SPECIES, [0.5])
    with pytest.raises(ValueError, match="channel"):
        g.free_flight([[0, 0, 0]], [[0, 0, 1]], 0.0, 1.0, 0.5, channel=3)
    with pytest.raises(ValueError, match="ray"):
        g.optical_depth([[0, 0, 0]], [[0, 0, 0]], 0.0, 1.0)
