"""Particles in space (issue 4): the density-field generator follows its density (chi-square against the
integrated density), is reproducible and rejects bad input; the query radius of Eq. 23 and the medium's
nearest depth from a camera."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import motes

PSD = motes.LogNormal(300.0, 2.0)
UNIT = ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
# chi-square upper quantiles at 1 - 1e-4 (fixed seeds, so these are deterministic checks with a bound a
# correct sampler exceeds with probability 1e-4): df = 7 -> 29.88, df = 63 -> 112.4
CHI2_DF7 = 29.88
CHI2_DF63 = 112.4


def _chi2(counts, probs):
    expected = counts.sum() * probs
    return float(((counts - expected) ** 2 / expected).sum())


@pytest.mark.parametrize(("axis", "start", "end", "lo", "hi"), [
    (2, 1.0, 0.0, [0, 0, 0], [1, 1, 1]),
    (0, 0.2, 3.0, [-2, 1, 5], [3, 1.5, 6]),
    ("y", 1.0, 1.0, [0, -1, 0], [1, 1, 1]),
])
def test_gradient_matches_integrated_density(axis, start, end, lo, hi):
    """Counts in 8 equal slabs along the gradient axis against the linear density integrated over each
    slab: chi-square (7 dof) below its 1 - 1e-4 quantile; the other axes stay uniform (same bound)."""
    n = 40_000
    pos, r = motes.density_box(n, lo, hi, motes.Gradient(axis=axis, start=start, end=end), PSD, seed=11)
    ax = {"y": 1}.get(axis, axis)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    t = (pos - lo) / (hi - lo)
    mid = (np.arange(8) + 0.5) / 8
    dens = start + (end - start) * mid  # exact slab integral of a linear density (midpoint rule)
    probs = dens / dens.sum()
    counts = np.histogram(t[:, ax], bins=8, range=(0, 1))[0]
    assert _chi2(counts, probs) < CHI2_DF7
    other = (ax + 1) % 3
    assert _chi2(np.histogram(t[:, other], bins=8, range=(0, 1))[0], np.full(8, 1 / 8)) < CHI2_DF7
    assert pos.shape == (n, 3) and r.shape == (n,)


def test_noise_matches_cell_averaged_density():
    """Counts in a 4x4x4 cell grid against the Noise density averaged over each cell (10^3-point midpoint
    rule per cell, well below the statistical noise): chi-square (63 dof) below its 1 - 1e-4 quantile.
    The density must actually vary across cells for this to test anything."""
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 1.0, 3.0])
    noise = motes.Noise(scale=0.8, octaves=3, seed=5, contrast=0.9)
    n = 60_000
    pos, _ = motes.density_box(n, lo, hi, noise, PSD, seed=2)
    cells, sub = 4, 10
    g = (np.arange(cells * sub) + 0.5) / (cells * sub)
    q = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    d = noise(lo + (hi - lo) * q).reshape(cells, sub, cells, sub, cells, sub)
    avg = d.mean(axis=(1, 3, 5)).ravel()
    assert avg.max() / avg.min() > 1.5  # a real spatial variation
    idx = np.minimum(((pos - lo) / (hi - lo) * cells).astype(int), cells - 1)
    counts = np.bincount((idx[:, 0] * cells + idx[:, 1]) * cells + idx[:, 2], minlength=cells**3)
    assert _chi2(counts, avg / avg.sum()) < CHI2_DF63


def test_callable_density_and_support():
    """A callable density: points only where it is non-zero, and a known moment (density x^2 on [0, 1]:
    E[x] = 3/4, sd sqrt(3/80)/sqrt(n))."""
    n = 20_000
    pos, _ = motes.density_box(n, *UNIT, lambda p: p[:, 0] ** 2, PSD, seed=4)
    assert abs(pos[:, 0].mean() - 0.75) < 4 * math.sqrt(3 / 80 / n)
    ball = lambda p: (np.linalg.norm(p - 0.5, axis=1) < 0.3).astype(float)  # noqa: E731
    pos, _ = motes.density_box(2000, *UNIT, ball, PSD, seed=4)
    assert np.all(np.linalg.norm(pos - 0.5, axis=1) < 0.3)


def test_noise_is_smooth_deterministic_and_bounded():
    x = np.random.default_rng(0).random((5000, 3)) * 4 - 2
    a = motes.Noise(scale=0.5, octaves=4, seed=7)
    np.testing.assert_array_equal(a(x), motes.Noise(scale=0.5, octaves=4, seed=7)(x))
    assert not np.array_equal(a(x), motes.Noise(scale=0.5, octaves=4, seed=8)(x))
    v = a.value(x)
    assert v.min() >= 0 and v.max() <= 1 and v.std() > 0.05
    assert np.abs(a.value(x + 1e-7) - v).max() < 1e-4  # continuous (C2 interpolation)
    d = motes.Noise(scale=0.5, contrast=3.0, seed=7)(x)
    assert d.min() == 0 and d.max() <= 4.0  # high contrast carves empty regions, bound 1 + contrast


def test_reproducible_from_seed():
    for dens in (motes.Gradient(0, 0.1, 1.0), motes.Noise(scale=0.3), lambda p: 1 + p[:, 1]):
        a = motes.density_box(500, *UNIT, dens, PSD, seed=9)
        b = motes.density_box(500, *UNIT, dens, PSD, seed=9)
        c = motes.density_box(500, *UNIT, dens, PSD, seed=10)
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
        assert not np.array_equal(a[0], c[0])


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(n=0), "n must be an integer >= 1"),
    (dict(n=-3), "n must be an integer >= 1"),
    (dict(n=2.5), "n must be an integer >= 1"),
    (dict(lo=[0, 0]), "lo and hi must be 3-vectors"),
    (dict(hi=[1, 0, 1]), r"hi > lo.*lo\[1\]"),
    (dict(hi=[1, 1, np.inf]), "lo and hi must be finite"),
    (dict(density=lambda p: np.ones((p.shape[0], 1))), r"density must return an array of shape \(\d+,\)"),
    (dict(density=lambda p: 1.0), "density must return an array of shape"),
    (dict(density=lambda p: np.where(p[:, 0] > 0.5, np.nan, 1.0)), r"density returned \d+ non-finite .*at position \["),
    (dict(density=lambda p: np.where(p[:, 0] > 0.5, np.inf, 1.0)), "non-finite"),
    (dict(density=lambda p: p[:, 0] - 0.5), r"density returned \d+ negative .*e\.g\. -.* at position \["),
    (dict(density=lambda p: np.zeros(p.shape[0])), "density is 0 at all"),
    (dict(density=lambda p: np.zeros(p.shape[0]), max_density=1.0), "density is 0 at all"),
    (dict(density=lambda p: 2 * np.ones(p.shape[0]), max_density=1.0), "exceeds max_density = 1.*pass a larger max_density"),
    (dict(density=motes.Gradient(0, 1, 3), max_density=2.0), "exceeds max_density"),
    (dict(max_density=0.0), "max_density must be > 0"),
    (dict(max_density=np.nan), "max_density must be finite"),
])
def test_density_box_errors(kwargs, match):
    args = dict(n=100, lo=UNIT[0], hi=UNIT[1], density=motes.Gradient(), psd=PSD, seed=0) | kwargs
    with pytest.raises(ValueError, match=match):
        motes.density_box(**args)


def test_density_box_rejects_non_callable():
    with pytest.raises(TypeError, match="density must be a callable"):
        motes.density_box(10, *UNIT, 3.0, PSD)


def test_estimated_bound_is_verified():
    """A density that grows after the probe (here: with the call count) exceeds the estimated bound:
    the sampler raises instead of silently biasing."""
    calls = []

    def sneaky(p):
        calls.append(1)
        return np.full(p.shape[0], 1.0 if len(calls) == 1 else 10.0)

    with pytest.raises(ValueError, match="exceeds the estimated bound .*pass a larger max_density"):
        motes.density_box(100, *UNIT, sneaky, PSD)


@pytest.mark.parametrize(("cls", "kwargs", "match"), [
    (motes.Gradient, dict(axis=3), "axis must be"),
    (motes.Gradient, dict(axis="w"), "axis must be"),
    (motes.Gradient, dict(start=-1.0), "start and end must be >= 0"),
    (motes.Gradient, dict(start=0.0, end=0.0), "both 0"),
    (motes.Gradient, dict(end=np.nan), "end must be finite"),
    (motes.Noise, dict(scale=0.0), "scale must be > 0"),
    (motes.Noise, dict(octaves=0), r"octaves must be an integer in \[1, 16\]"),
    (motes.Noise, dict(seed=-1), "seed must be an integer"),
    (motes.Noise, dict(contrast=-0.5), "contrast must be >= 0"),
])
def test_preset_errors(cls, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cls(**kwargs)


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(
    lo=st.lists(st.floats(-100, 100), min_size=3, max_size=3),
    size=st.lists(st.floats(1e-3, 50), min_size=3, max_size=3),
    n=st.integers(1, 300),
    axis=st.integers(0, 2),
    start=st.floats(0, 5),
    end=st.floats(0, 5),
    seed=st.integers(0, 2**32),
)
def test_density_box_property(lo, size, n, axis, start, end, seed):
    """Random boxes, n and gradients: every centre finite and inside the box, shapes right."""
    if start == 0 and end == 0:
        end = 1.0
    lo = np.array(lo)
    hi = lo + np.array(size)
    pos, r = motes.density_box(n, lo, hi, motes.Gradient(axis, start, end), PSD, seed=seed)
    assert pos.shape == (n, 3) and r.shape == (n,) and pos.dtype == np.float64
    assert np.all(np.isfinite(pos)) and np.all(np.isfinite(r)) and np.all(r > 0)
    assert np.all(pos >= lo) and np.all(pos <= hi)


# ---- Eq. 23: query radius from a camera -------------------------------------------------------------


def test_query_radius_analytic():
    assert motes.query_radius_from_camera(1.0, 90.0, 2, 1.0) == pytest.approx(0.5, rel=1e-14)
    # 60 degrees, 1920 px, z_med 10, k = 0.5: 0.5 tan(30 deg) 10 / 1920
    assert motes.query_radius_from_camera(0.5, 60.0, 1920, 10.0) == pytest.approx(0.5 * math.tan(math.pi / 6) * 10 / 1920, rel=1e-14)


def test_query_radius_monotone():
    base = dict(k=0.75, fov_deg=40.0, width_px=800, z_med=3.0)
    r0 = motes.query_radius_from_camera(**base)
    for key, bigger in (("k", 1.0), ("fov_deg", 80.0), ("z_med", 6.0)):
        assert motes.query_radius_from_camera(**(base | {key: bigger})) > r0
    assert motes.query_radius_from_camera(**(base | {"width_px": 1600})) == pytest.approx(r0 / 2)
    assert motes.query_radius_from_camera(**(base | {"z_med": 6.0})) == pytest.approx(2 * r0)  # linear in depth


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(k=0.0), r"k must be in \(0, 2\]"),
    (dict(k=2.5), r"k must be in \(0, 2\]"),
    (dict(k=np.nan), "k must be finite"),
    (dict(fov_deg=0.0), r"fov_deg must be in \(0, 180\)"),
    (dict(fov_deg=180.0), r"fov_deg must be in \(0, 180\)"),
    (dict(width_px=0), "width_px must be an integer >= 1"),
    (dict(width_px=640.5), "width_px must be an integer >= 1"),
    (dict(z_med=0.0), "z_med must be > 0"),
    (dict(z_med=-1.0), "z_med must be > 0"),
    (dict(z_med=np.inf), "z_med must be finite"),
])
def test_query_radius_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        motes.query_radius_from_camera(**(dict(k=1.0, fov_deg=45.0, width_px=512, z_med=2.0) | kwargs))


def test_nearest_depth():
    lo, hi = [-1, -1, -1], [1, 1, 1]
    assert motes.nearest_depth([0, 0, -5], [0, 0, 1], lo, hi) == pytest.approx(4.0)
    assert motes.nearest_depth([0, 0, -5], [0, 0, 7], lo, hi) == pytest.approx(4.0)  # forward need not be unit
    assert motes.nearest_depth([10, 0, 0], [-1, 0, 0], lo, hi) == pytest.approx(9.0)
    # off-axis: the nearest corner along a diagonal view direction
    d = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    assert motes.nearest_depth([-5, -5, 0], d, lo, hi) == pytest.approx(4 * math.sqrt(2))
    # camera inside or box behind: the floor (default 1e-4 x diagonal, or min_depth)
    diag = math.sqrt(12)
    assert motes.nearest_depth([0, 0, 0], [0, 0, 1], lo, hi) == pytest.approx(1e-4 * diag)
    assert motes.nearest_depth([0, 0, 5], [0, 0, 1], lo, hi) == pytest.approx(1e-4 * diag)
    assert motes.nearest_depth([0, 0, 0], [0, 0, 1], lo, hi, min_depth=0.01) == 0.01
    # composes with Eq. 23
    z = motes.nearest_depth([0, 0, -5], [0, 0, 1], lo, hi)
    assert motes.query_radius_from_camera(1.0, 90.0, 2, z) == pytest.approx(2.0)


@pytest.mark.parametrize(("args", "kwargs", "match"), [
    (([0, 0], [0, 0, 1]), {}, "camera_origin must be a finite 3-vector"),
    (([0, 0, np.nan], [0, 0, 1]), {}, "camera_origin must be a finite 3-vector"),
    (([0, 0, -5], [0, 0, 0]), {}, "camera_forward must be a finite non-zero 3-vector"),
    (([0, 0, -5], [0, 0, 1]), dict(min_depth=0.0), "min_depth must be > 0"),
])
def test_nearest_depth_errors(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        motes.nearest_depth(*args, [-1, -1, -1], [1, 1, 1], **kwargs)
    with pytest.raises(ValueError, match="hi > lo"):
        motes.nearest_depth([0, 0, -5], [0, 0, 1], [1, 1, 1], [1, 2, 2])


# -- The core's tiled generator (issue 24), which the discrete plugin's ``count`` uses -------------------------
IDENTITY = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0]]


def _cloud(n, kind, params, seed=3, noise_seed=0, psds=(PSD,), shares=(1.0,), transform=IDENTITY, box=((-1,) * 3, (1,) * 3)):
    c, r, s = motes._motes.generate_cloud(n, list(box[0]), list(box[1]), kind, list(params), noise_seed,
                                          [p._core for p in psds], list(shares), seed, transform)
    return c.reshape(-1, 3), r, s


@pytest.mark.parametrize("n", [1, 2, 17, 1000, 65_537])
def test_core_cloud_has_exactly_count_particles_in_its_box(n):
    pos, r, s = _cloud(n, "uniform", [])
    assert pos.shape == (n, 3) and r.shape == (n,) and s.shape == (n,)
    assert np.all(np.abs(pos) <= 1) and np.all(r > 0) and np.all(s == 0)


def test_core_cloud_is_uniform_and_reproducible():
    """Counts in 4^3 cells of a uniform cloud (chi-square, 63 dof); same seed same cloud, other seed other."""
    pos, _, _ = _cloud(60_000, "uniform", [], seed=9)
    idx = np.minimum(((pos + 1) / 2 * 4).astype(int), 3)
    counts = np.bincount((idx[:, 0] * 4 + idx[:, 1]) * 4 + idx[:, 2], minlength=64)
    assert _chi2(counts, np.full(64, 1 / 64)) < CHI2_DF63
    again, _, _ = _cloud(60_000, "uniform", [], seed=9)
    np.testing.assert_array_equal(pos, again)
    assert not np.array_equal(pos, _cloud(60_000, "uniform", [], seed=10)[0])


def test_core_cloud_follows_the_gradient():
    n = 40_000
    pos, _, _ = _cloud(n, "gradient", [2, 1.0, 0.0], seed=11)
    mid = (np.arange(8) + 0.5) / 8
    counts = np.histogram((pos[:, 2] + 1) / 2, bins=8, range=(0, 1))[0]
    assert _chi2(counts, (1 - mid) / (1 - mid).sum()) < CHI2_DF7


def test_core_cloud_follows_the_noise():
    """Counts in 4^3 cells against motes.Noise (the same seed, scale, octaves, contrast) averaged per cell."""
    noise = motes.Noise(scale=0.8, octaves=3, seed=5, contrast=0.9)
    pos, _, _ = _cloud(60_000, "noise", [0.8, 3, 0.9], seed=2, noise_seed=5)
    lo, hi, cells, sub = np.full(3, -1.0), np.full(3, 1.0), 4, 10
    g = (np.arange(cells * sub) + 0.5) / (cells * sub)
    q = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    avg = noise(lo + (hi - lo) * q).reshape(cells, sub, cells, sub, cells, sub).mean(axis=(1, 3, 5)).ravel()
    assert avg.max() / avg.min() > 1.5
    idx = np.minimum(((pos - lo) / (hi - lo) * cells).astype(int), cells - 1)
    counts = np.bincount((idx[:, 0] * cells + idx[:, 1]) * cells + idx[:, 2], minlength=cells**3)
    assert _chi2(counts, avg / avg.sum()) < CHI2_DF63


def test_core_cloud_species_shares_radii_and_transform():
    """Two species 1:3 (binomial, 4 sigma), each radius from its own PSD (KS-free: the supports do not
    overlap), and the transform applied to the same centres."""
    a, b = motes.Monodisperse(5.0), motes.Uniform(100.0, 200.0)
    pos, r, s = _cloud(20_000, "uniform", [], psds=(a, b), shares=(1.0, 3.0))
    share = np.mean(s == 1)
    assert abs(share - 0.75) < 4 * math.sqrt(0.75 * 0.25 / 20_000)
    assert np.all(r[s == 0] == 5.0) and np.all((r[s == 1] >= 100) & (r[s == 1] <= 200))
    m = [[0, 2.0, 0, 1.0], [1.0, 0, 0, 0], [0, 0, 3.0, -1.0]]
    moved, _, _ = _cloud(20_000, "uniform", [], psds=(a, b), shares=(1.0, 3.0), transform=m)
    np.testing.assert_allclose(moved, np.stack([2 * pos[:, 1] + 1, pos[:, 0], 3 * pos[:, 2] - 1], axis=1), rtol=1e-15)


@pytest.mark.parametrize(("kwargs", "argument"), [
    (dict(n=0, kind="uniform", params=[]), "count"),
    (dict(n=10, kind="spiral", params=[]), "density"),
    (dict(n=10, kind="gradient", params=[1.0]), "params"),
    (dict(n=10, kind="gradient", params=[5, 1.0, 0.0]), "axis"),
    (dict(n=10, kind="noise", params=[-1.0, 2, 1.0]), "scale"),
    (dict(n=10, kind="uniform", params=[], shares=(-1.0,)), "share"),
    (dict(n=10, kind="uniform", params=[], box=((0, 0, 0), (1, 0, 1))), "hi"),
])
def test_core_cloud_errors_name_the_argument(kwargs, argument):
    with pytest.raises(motes.MotesError) as e:
        _cloud(**kwargs)
    assert e.value.argument.startswith(argument)


_SIDE = st.floats(min_value=1e-6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 3000), seed=st.integers(0, 2**64 - 1), noise_seed=st.integers(0, 2**64 - 1),
       lo=st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)] * 3),
       size=st.tuples(_SIDE, _SIDE, _SIDE),
       kind=st.sampled_from(["uniform", "gradient", "noise"]),
       axis=st.integers(0, 2), start=st.floats(0, 10), end=st.floats(0, 10),
       scale=st.floats(1e-3, 1e3), octaves=st.integers(1, 16), contrast=st.floats(0, 5),
       shares=st.lists(st.floats(0, 1e6), min_size=1, max_size=3).filter(lambda v: sum(v) > 0))
def test_core_cloud_property(n, seed, noise_seed, lo, size, kind, axis, start, end, scale, octaves, contrast, shares):
    """Any valid input, endpoints included (one particle, seeds up to 2^64 - 1, boxes from 1e-6 to 1e6 wide,
    a gradient from 0, 16 octaves, contrast 0 or carving): exactly n particles, inside the box, each with a
    radius of its own species' support and a species of positive share; the same again from the same seed."""
    if kind == "gradient" and start + end == 0:
        end = 1.0
    params = {"uniform": [], "gradient": [axis, start, end], "noise": [scale, octaves, contrast]}[kind]
    lo = np.array(lo)
    hi = lo + np.array(size)
    psds = [motes.Uniform(1.0 + 10 * k, 2.0 + 10 * k) for k in range(len(shares))]
    box = (tuple(lo), tuple(hi))
    try:
        pos, r, s = _cloud(n, kind, params, seed=seed, noise_seed=noise_seed, psds=psds, shares=shares, box=box)
    except motes.MotesError as e:
        # A noise of contrast > 1 is zero where v < (1 - 1/contrast) / 2: over a small box it can be zero
        # (or almost) everywhere, which the generator refuses by name.
        assert kind == "noise" and contrast > 1 and e.argument == "density", e
        return
    assert pos.shape == (n, 3) and np.all(np.isfinite(pos))
    assert np.all(pos >= lo - 1e-9 * np.abs(lo)) and np.all(pos <= hi + 1e-9 * np.abs(hi))
    assert np.all(np.asarray(shares)[s] > 0)
    assert np.all((r >= 1.0 + 10 * s) & (r <= 2.0 + 10 * s))
    again = _cloud(n, kind, params, seed=seed, noise_seed=noise_seed, psds=psds, shares=shares, box=box)
    np.testing.assert_array_equal(pos, again[0])
