"""The discrete medium's core queries without Mitsuba: Eq. 24 at points, local-mixture sampling and site
sampling robustness (issue 4/5)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import motes


@pytest.fixture(scope="module")
def medium():
    rng = np.random.default_rng(5)
    n = 6000
    pos = rng.uniform(0, 1, (n, 3))
    species = [motes.Species(motes.LogNormal(3.0, 1.3), 1.33), motes.Species(motes.Uniform(20, 40), 1.5 + 0.002j)]
    idx = rng.integers(0, 2, n)
    radii = np.where(idx == 0, species[0].psd.sample(n, seed=1), species[1].psd.sample(n, seed=2))
    return motes.DiscreteMedium(pos, radii, idx, species, motes.RGB_WAVELENGTHS_UM, scale_m=1e-3,
                                query_radius=0.01, size_bins=6, storage="full")


def test_local_sigma_s_is_the_bulk_on_average(medium):
    """E[sigma_s(p)] over interior points = sum_i C_s,i / V (each particle's C_s spread over its ball)."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.1, 0.9, (100_000, 3))
    sigma, q = medium.local_scattering(pts, 0.5)
    alb = np.array(medium.bin_albedo)  # (bins, channels)
    bulk = (medium.c_ext_scene[:, None] * alb[medium.particle_bin]).sum(axis=0)  # the box has volume 1
    se = sigma.std(axis=0) / np.sqrt(len(pts))
    assert np.all(np.abs(sigma.mean(axis=0) - bulk) < 5 * se), (sigma.mean(axis=0), bulk, se)
    assert np.all(q >= 0) and np.all((sigma > 0) | (q == 0))


def test_sample_local_follows_its_pdf(medium):
    """Directions sampled from the local mixture at one point follow the pdf that evaluation gives
    (Kolmogorov-Smirnov on cos theta against the numerically integrated pdf)."""
    rng = np.random.default_rng(2)
    pts = rng.uniform(0.2, 0.8, (50, 3))
    sig, _ = medium.local_scattering(pts, 0.0)
    p = pts[np.argmax((sig > 0).all(axis=1) * sig.sum(axis=1))]
    n = 40_000
    w_in = np.array([0.0, 0.6, 0.8])
    wo, w, pdf = medium.sample_local(np.repeat(p[None], n, 0), w_in, rng.random(n), rng.random((n, 2)))
    assert np.all(pdf > 0) and np.all(np.isfinite(w))
    mu = wo @ w_in
    grid = np.concatenate([np.linspace(-1, 0.99, 20000), 1 - np.geomspace(1e-2, 1e-10, 4000), [1.0]])  # graded at the peak
    s, qg = medium.local_scattering(np.repeat(p[None], grid.size, 0), grid)
    dens = 2 * np.pi * (qg / s).mean(axis=1)  # density in mu of the channel-mean pdf
    cdf = np.concatenate([[0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(grid))])
    assert abs(cdf[-1] - 1) < 1e-3
    emp = np.searchsorted(np.sort(mu), grid, side="right") / n
    assert np.max(np.abs(emp - cdf)) < 1.63 / np.sqrt(n) + 2e-3  # KS at 1 %, plus table resolution


@settings(max_examples=60, deadline=None)
@given(o=st.tuples(*[st.sampled_from([-0.5, 0.0, 0.25, 0.5, 1.0, 1.5])] * 3),
       d=st.sampled_from([(1, 0, 0), (0, -1, 0), (0, 0, 1), (1, 1, 0), (0.3, -0.4, 0.5), (0, 0, 0)]),
       t_max=st.sampled_from([0.0, 1e-9, 0.5, 10.0, np.inf]))
def test_sample_sites_is_robust(medium, o, d, t_max):
    """Rays from grid corners, faces and outside, along axes, zero directions, empty segments: finite results,
    a site only inside (0, t_max), never NaN optical depth."""
    oo = np.array(o, dtype=np.float32)
    dd = np.array(d, dtype=np.float32)
    t, tau = medium.core.sample_sites(np.tile(oo, 64), np.tile(dd, 64), np.full(64, t_max), np.ones(64, bool))
    assert np.all(np.isfinite(tau)) and np.all(tau >= 0)
    hit = np.isfinite(t)
    assert np.all((t[hit] >= 0) & (t[hit] < t_max))
    if not np.any(dd) or t_max == 0.0:
        assert not hit.any()


def test_local_scattering_errors(medium):
    with pytest.raises(ValueError, match="points"):
        medium.local_scattering(np.zeros((3, 2)), 0.0)
    with pytest.raises(ValueError, match="cos_theta"):
        medium.local_scattering(np.zeros((3, 3)), 1.5)


def _box_mesh(lo, hi, rotate=0.0):
    """A closed box [lo, hi]^3 as Mitsuba's cube gives it (24 vertices, 12 triangles), turned by ``rotate``
    radians about z."""
    v, f = [], []
    for axis in range(3):
        for side in (lo, hi):
            base = len(v)
            u, w = (axis + 1) % 3, (axis + 2) % 3
            for a, b in ((lo, lo), (hi, lo), (hi, hi), (lo, hi)):
                p = [0.0, 0.0, 0.0]
                p[axis], p[u], p[w] = side, a, b
                v.append(p)
            f += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    v = np.array(v)
    c, s = np.cos(rotate), np.sin(rotate)
    v = v @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    return v, np.array(f, dtype=np.uint32)


@settings(max_examples=40, deadline=None)
@given(lo=st.floats(-1e6, 1e6), size=st.floats(1e-6, 1e6), rotate=st.floats(0.0, 2 * np.pi),
       radius=st.floats(1e-9, 1e9))
def test_set_enclosure_takes_boxes_and_balls(medium, lo, size, rotate, radius):
    """Closed boxes (any size, position and turn) and balls are regions; no arguments clears them."""
    hi = lo + size
    if not hi > lo:  # size lost in lo's rounding
        return
    v, f = _box_mesh(lo, hi, rotate)
    assert medium.set_enclosure([(v, f)], [((lo, 0.0, 0.0), radius)]) == 2
    assert medium.enclosure_regions == 2
    assert medium.set_enclosure() == 0 and medium.enclosure_regions == 0


def test_set_enclosure_rejects_bad_input_by_name(medium):
    v, f = _box_mesh(-1.0, 1.0)
    open_box = (v, f[:8])  # the z faces missing
    flat = (np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1],
                                                                                        [0, 3, 2]], np.uint32))
    assert medium.set_enclosure([open_box, flat]) == 0  # not closed, no volume: hold nothing
    bad = v.copy()
    bad[5, 1] = np.nan
    for meshes, balls, name in (([(bad, f)], [], "vertex"), ([(v, np.where(f == 3, 99, f))], [], "face vertex index"),
                                ([], [((0.0, 0.0, 0.0), 0.0)], "ball radius"),
                                ([], [((np.inf, 0.0, 0.0), 1.0)], "ball centre"),
                                ([(v, f.ravel()[:-1])], [], "faces")):
        with pytest.raises(motes.MotesError) as e:
            medium.set_enclosure(meshes, balls)
        assert e.value.argument == name, (name, str(e.value))
    with pytest.raises(ValueError, match="pairs"):
        medium.set_enclosure([(v,)])
