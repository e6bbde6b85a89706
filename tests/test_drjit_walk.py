"""The walk of the particle grid in Dr.Jit (issue 46, ``mitsuba_plugin/motes/drjit_walk.py``) against the Rust
core and an O(N) numpy oracle, in ``llvm_ad_rgb``:

* optical depths (Eq. 18, the transmittance's exponent) of random segments through several clouds (a few
  large grains, many small ones, grains as wide as the cells and straddling them, several size classes,
  a compact discrete medium's quantised grains), from inside the grid and from outside, along the axes,
  with t_max = 0 and inf: equal to the core's ``optical_depth`` to 1e-5 in double precision, and in single
  precision wherever no grain lies within rounding of its disk's edge or of the segment's ends (those rays
  differ by at most those grains' depths, and are few);
* the same against a loop over every grain in numpy (from the particles as given, not the grid);
* free flights along one fixed line: a chi-square test of which grain each flight stops at (or none)
  against the exact discrete law prod_{i<j} exp(-tau_i) (1 - exp(-tau_j)), and the t each returns is its
  grain's projection.
"""

from __future__ import annotations

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

import motes  # noqa: E402
from motes import _motes  # noqa: E402

#: Absolute band (scene units; clouds in the unit cube, origins within 3 of it) within which a single-
#: precision walk may decide a grain either way: its disk's edge, the segment's ends.
F32_BAND = 2e-5


@pytest.fixture(scope="module", autouse=True)
def jit_variant():
    """``llvm_ad_rgb``, or ``MOTES_TEST_VARIANT`` (``cuda_ad_rgb`` on a GPU: ``scripts/device/run.sh``)."""
    import os

    variant = os.environ.get("MOTES_TEST_VARIANT", "llvm_ad_rgb")
    if variant not in mi.variants():
        pytest.skip(f"Mitsuba has no {variant} variant here")
    if variant.startswith("llvm"):
        # Not motes.set_variant: the kernels need no plugin (whose native half would be compiled first).
        from motes.plugins import _llvm_problem, configure_llvm

        configure_llvm()
        problem = _llvm_problem()
        if problem is not None:
            pytest.skip(f"{variant} cannot run here: {problem}")
    mi.set_variant(variant)
    global DrJitGrid
    from motes.drjit_walk import DrJitGrid
    yield


def _cloud(name: str, seed: int = 0):
    """(positions, geometric radii, C_ext, query radius, cells per particle) of a named test cloud in the unit
    cube (scene units)."""
    rng = np.random.default_rng(seed)
    if name == "few_large":  # sparse large grains
        n, r, rc, cpp = 40, rng.uniform(0.04, 0.12, 40), 0.01, 0.125
    elif name == "many_small":
        n, r, rc, cpp = 20000, rng.uniform(0.001, 0.003, 20000), 0.002, 0.125
    elif name == "straddling":  # inclusion balls as wide as the cells: every grain straddles cells
        n, r, rc, cpp = 3000, rng.uniform(0.03, 0.05, 3000), 0.03, 4.0
    elif name == "mixed":  # a haze with a few large grains: several size classes
        n = 30030
        r = np.concatenate([rng.uniform(0.002, 0.004, 30000), rng.uniform(0.05, 0.1, 30)])
        rc, cpp = 0.01, 0.125
    else:
        raise ValueError(name)
    pos = rng.random((n, 3))
    c_ext = 2 * np.pi * r * r * rng.uniform(0.5, 1.5, n)
    if name == "mixed":
        c_ext[r > 0.01] *= 0.3  # large grains of depth ~0.6 (a free flight's law then spreads over the line)
    return pos, r, c_ext, rc, cpp


def _grid(name: str):
    pos, r, c, rc, cpp = _cloud(name)
    return _motes.ParticleGrid(pos.ravel(), r, c, 1, rc, cpp), (pos, r, c, rc)


def _rays(rng, m: int, centres):
    """m rays (origins, unit directions, t_max) with f32-exact components: from inside the cube and from
    outside aimed through it, along the axes (some through grain centres), from grain centres, t_max random,
    0 and inf."""
    inside = rng.random((m, 3))
    outside = rng.uniform(-1.0, 2.0, (m, 3))
    origin = np.where((np.arange(m) % 2 == 0)[:, None], inside, outside)
    target = rng.random((m, 3))
    d = target - origin
    d[np.linalg.norm(d, axis=1) < 1e-3] = [0.0, 0.0, 1.0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    axis = np.arange(m) % 7 == 3  # one ray in seven along an axis
    ax = rng.integers(0, 3, m)
    d[axis] = 0.0
    d[axis, ax[axis]] = rng.choice([-1.0, 1.0], axis.sum())
    through = axis & (np.arange(m) % 14 == 3)  # half of those through a grain's centre
    c = centres[rng.integers(0, len(centres), m)]
    for a in range(3):
        sel = through & (ax != a)
        origin[sel, a] = c[sel, a]
    at_centre = np.arange(m) % 13 == 6  # from a grain's centre (f32, as the grid stores it): its t_i = 0 counts
    origin[at_centre] = centres[rng.integers(0, len(centres), at_centre.sum())].astype(np.float32)
    tmax = rng.uniform(0.0, 3.0, m)
    tmax[np.arange(m) % 11 == 5] = 0.0
    tmax[np.arange(m) % 11 == 7] = np.inf
    origin = origin.astype(np.float32).astype(np.float64)
    d = d.astype(np.float32).astype(np.float64)
    return origin, d, tmax


def _brute(origin, d, tmax, centres, reach, tau, band: float):
    """Optical depth of each segment [0, tmax) by a loop over every grain (numpy, double precision), and
    per ray the summed depth of the grains within ``band`` of the disk's edge or of the segment's ends."""
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    out = np.zeros(len(origin))
    amb = np.zeros(len(origin))
    cc = (centres * centres).sum(axis=1)
    at = {tuple(c): j for j, c in enumerate(centres)}
    own = np.array([at.get(tuple(x), -1) for x in origin])  # the grain a ray starts at the centre of
    for s in range(0, len(origin), 64):
        o, dd, tm = origin[s:s + 64], d[s:s + 64], tmax[s:s + 64, None]
        # t = (c - o).d and |c - o|^2 - t^2 (the distance across the ray) without the (rays, grains, 3) arrays
        t = centres @ dd.T - (o * dd).sum(axis=1)
        t = t.T
        vv = cc[None, :] - 2 * (o @ centres.T) + (o * o).sum(axis=1)[:, None]
        dist = np.sqrt(np.maximum(vv - t * t, 0.0))
        hit = (dist < reach[None, :]) & (t >= 0) & (t < tm)
        near = (np.abs(dist - reach[None, :]) < band) & (t > -band) & (t < tm + band)
        near |= (dist < reach[None, :] + band) & ((np.abs(t) < band) | (np.abs(t - tm) < band))
        k = np.flatnonzero(own[s:s + 64] >= 0)
        near[k, own[s:s + 64][k]] = False  # a ray from the centre itself: t = 0 exactly, in any precision
        out[s:s + 64] = np.where(hit, tau[None, :], 0.0).sum(axis=1)
        amb[s:s + 64] = np.where(near, tau[None, :], 0.0).sum(axis=1)
    return out, amb


def _walk_depth(w, origin, d, tmax):
    F = mi.Float64
    tau = w.optical_depth([F(origin[:, a]) for a in range(3)], [F(d[:, a]) for a in range(3)], F(tmax))
    return tau.numpy()


def _check_depths(name, got, want, amb, exact: bool, clear_share: float = 0.9):
    """``got`` equals ``want`` to 1e-5 where no grain is ambiguous (``exact``: everywhere), and within the
    ambiguous grains' depth elsewhere; at least ``clear_share`` of the rays have no ambiguous grain."""
    tol = 1e-5 * np.abs(want) + 1e-9
    err = np.abs(got - want)
    clear = amb == 0 if not exact else np.ones(len(want), bool)
    assert np.all(err[clear] <= tol[clear]), (name, np.flatnonzero(clear & (err > tol))[:5], err.max())
    assert np.all(err <= amb * (1 + 1e-5) + tol), (name, err.max())
    assert clear.mean() > clear_share, (name, clear.mean())


@pytest.mark.parametrize("name", ["few_large", "many_small", "straddling", "mixed"])
def test_optical_depth_equals_the_core_and_a_loop_over_every_grain(name):
    grid, (pos, r, c, rc) = _grid(name)
    flat = grid.flat_arrays(0)
    assert len(flat["index"]) == len(pos) and sorted(flat["index"]) == list(range(len(pos)))
    if name == "mixed":
        assert len(flat["class_cell"]) >= 2
    if name == "straddling":  # balls as wide as the cells
        assert flat["spheres"][:, 3].max() > 0.9 * flat["class_cell"].min()
    rng = np.random.default_rng(7)
    m = 1200
    origin, d, tmax = _rays(rng, m, pos)
    core = grid.optical_depth((origin.ravel(), d.ravel(), np.zeros(m), tmax), False)
    reach = rc + r
    # The oracle from the particles as given (the grid keeps centres and radii in single precision: the
    # grains within rounding of an edge are ambiguous), and the grains as the grid keeps them.
    brute, amb = _brute(origin, d, tmax, pos, reach, c / (np.pi * reach * reach), F32_BAND)
    s = flat["spheres"].astype(np.float64)
    _, amb_grid = _brute(origin, d, tmax, s[:, :3], s[:, 3], flat["tau"].astype(np.float64), F32_BAND)
    assert core.max() > 1.0 and np.mean(core > 0) > 0.3, (core.max(), np.mean(core > 0))
    assert np.all(core[tmax == 0] == 0)
    double = DrJitGrid(grid, double=True)
    single = DrJitGrid(grid)
    got64, got32 = _walk_depth(double, origin, d, tmax), _walk_depth(single, origin, d, tmax)
    _check_depths(name + " double vs core", got64, core, amb_grid, exact=True)
    _check_depths(name + " single vs core", got32, core, amb_grid, exact=False)
    # (Rays from a grain's centre are ambiguous for the loop: it has the centre in double precision.)
    _check_depths(name + " double vs loop", got64, brute, amb, exact=False, clear_share=0.8)
    _check_depths(name + " single vs loop", got32, brute, amb, exact=False, clear_share=0.8)
    tr = single.transmittance([mi.Float64(origin[:, a]) for a in range(3)], [mi.Float64(d[:, a]) for a in range(3)],
                              mi.Float64(tmax)).numpy()
    np.testing.assert_allclose(tr, np.exp(-got32), rtol=1e-6)


def test_a_compact_discrete_medium_walks_as_its_core():
    """A discrete medium's grains (compact storage: quantised centres decoded from their lattice, disks
    widened to tau_max, grey tau) as the medium's own optical depth sees them, every grain discrete."""
    rng = np.random.default_rng(3)
    n = 4000
    pos = rng.random((n, 3))
    sp = motes.Species(motes.Uniform(50.0, 150.0), 1.5)
    radii = rng.uniform(50.0, 150.0, n)
    med = motes.DiscreteMedium(pos, radii, np.zeros(n, dtype=np.int64), [sp], motes.RGB_WAVELENGTHS_UM,
                               scale_m=1e-2, query_radius=0.003, continuous_count=np.inf, size_bins=3)
    assert med._core.widened > 0  # disks widened to tau_max
    flat = med._core.flat_arrays()
    assert len(flat["index"]) == n and set(flat["bin"]) <= {0, 1, 2}
    origin, d, tmax = _rays(rng, 1000, pos)
    core = med.optical_depth(origin, d, 0.0, tmax)
    assert core.max() > 1.0
    # The lattice centres differ from the f32 centres exported by ~1e-7 of the coordinates: no exact band.
    centres, reach = flat["spheres"][:, :3].astype(np.float64), flat["spheres"][:, 3].astype(np.float64)
    _, amb = _brute(origin, d, tmax, centres, reach, flat["tau"].astype(np.float64), F32_BAND)
    # Compact storage's grains are walked from the lattice layout (8 bytes a grain and small tables: the
    # issue's bound is 16), and walk as from the spheres.
    assert DrJitGrid(med).layout == "lattice" and DrJitGrid(med).bytes_per_grain <= 16
    for layout in ("lattice", "spheres"):
        got64 = _walk_depth(DrJitGrid(med, double=True, layout=layout), origin, d, tmax)
        got32 = _walk_depth(DrJitGrid(med, layout=layout), origin, d, tmax)
        _check_depths(f"medium double {layout}", got64, core, amb, exact=False)
        _check_depths(f"medium single {layout}", got32, core, amb, exact=False)


def _line_grains(flat, o, d, tmax):
    """The grains the segment [0, tmax) of the ray o + t d meets (flat arrays' spheres, double precision, as
    the core tests them), in t order: (t, tau, index, flat position)."""
    s = flat["spheres"].astype(np.float64)
    v = s[:, :3] - o
    t = v @ d
    q = v - t[:, None] * d
    dist2 = (q * q).sum(axis=1)
    hit = (dist2 < s[:, 3] ** 2) & (t >= 0) & (t < tmax)
    # No grain within rounding of its edge or the ends: the law is the same in either precision.
    assert not np.any((np.abs(np.sqrt(dist2) - s[:, 3]) < F32_BAND) & (t > -1) & (t < tmax + 1))
    k = np.flatnonzero(hit)
    k = k[np.argsort(t[k])]
    return t[k], flat["tau"][k].astype(np.float64), flat["index"][k]


@pytest.mark.parametrize("double", [True, False])
def test_free_flights_follow_the_exact_discrete_law(double):
    scipy_stats = pytest.importorskip("scipy.stats")
    grid, (pos, r, c, rc) = _grid("mixed")
    flat = grid.flat_arrays(0)
    # An oblique line (the walk then finds grains out of t order) through the cube, crossing a large grain,
    # stopped before the far side (t_max inside).
    big = pos[np.argmax(r)]
    d = np.array([-0.4, 0.3, 0.86])
    d /= np.linalg.norm(d)
    o = big + np.array([0.01, -0.005, 0.0]) - (big[2] + 0.3) / d[2] * d
    tmax = 1.2
    t_line, tau_line, idx_line = _line_grains(flat, o, d, tmax)
    core = grid.optical_depth((o, d, np.zeros(1), np.array([tmax])), False)[0]
    assert abs(tau_line.sum() - core) < 1e-9 * core
    assert len(t_line) >= 8 and 1.0 < core < 6.0, (len(t_line), core)
    # Several size classes on the line.
    per_class = np.searchsorted(flat["class_grains"], np.flatnonzero(np.isin(flat["index"], idx_line)), "right")
    assert len(set(per_class)) >= 2
    survive = np.exp(-np.concatenate([[0.0], np.cumsum(tau_line)]))
    p = np.append(survive[:-1] * -np.expm1(-tau_line), survive[-1])  # each grain, then none
    n = 120000
    w = DrJitGrid(grid, double=double)
    F = mi.Float64
    rays = ([F(np.full(n, o[a])) for a in range(3)], [F(np.full(n, d[a])) for a in range(3)], F(np.full(n, tmax)))
    for u in (mi.UInt32(np.arange(n, dtype=np.uint32) * 7919 + 12345),
              mi.Float(np.random.default_rng(1).permutation(n).astype(np.float32) / np.float32(n))):
        t, index, valid = w.sample_free_flight(*rays, u)
        t, index, valid = t.numpy(), index.numpy(), valid.numpy()
        assert np.all(np.isinf(t[~valid])) and np.all(index[~valid] == 0xFFFFFFFF)
        assert np.all(np.isfinite(t[valid]))
        # The t returned is the projection of the grain returned.
        where = {int(i): k for k, i in enumerate(idx_line)}
        k = np.array([where.get(int(i), -1) for i in index[valid]])
        assert np.all(k >= 0)
        np.testing.assert_allclose(t[valid], t_line[k], rtol=0, atol=1e-5)
        counts = np.append(np.bincount(k, minlength=len(t_line)), (~valid).sum())
        expected = n * p
        keep = expected >= 5
        obs = np.append(counts[keep], counts[~keep].sum())
        exp_ = np.append(expected[keep], expected[~keep].sum())
        obs, exp_ = obs[exp_ > 0], exp_[exp_ > 0]
        chi2 = ((obs - exp_) ** 2 / exp_).sum()
        pval = scipy_stats.chi2.sf(chi2, len(obs) - 1)
        assert pval > 1e-4, (double, chi2, len(obs), pval, counts, np.round(expected))


def test_free_flights_of_rays_that_miss_or_have_no_length():
    grid, _ = _grid("few_large")
    w = DrJitGrid(grid)
    F = mi.Float64
    o = np.array([[5.0, 5.0, 5.0], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    tmax = np.array([np.inf, 0.0, -1.0])
    t, index, valid = w.sample_free_flight([F(o[:, a]) for a in range(3)], [F(d[:, a]) for a in range(3)], F(tmax),
                                           mi.UInt32([1, 2, 3]))
    assert not valid.numpy().any() and np.all(np.isinf(t.numpy()))
    assert np.all(_walk_depth(w, o, d, tmax) == 0)
