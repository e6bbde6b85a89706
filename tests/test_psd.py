"""Particle size distributions (issue 3, part 1): Eq. 15 against scipy's log-normal, sampling against the
CDF, the sigma_g = 1 limit, quadrature moments against Monte Carlo, and parameter errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from scipy import stats

import motes
from conftest import hsettings, log_uniform


def test_lognormal_pdf_matches_scipy():
    """Eq. 15 (normalised, truncated to [r_min, r_max]) equals scipy.stats.lognorm renormalised."""
    psd = motes.LogNormal(median_um=50.0, sigma_g=2.5, r_min_um=1.0, r_max_um=2000.0)
    ref = stats.lognorm(s=np.log(2.5), scale=50.0)
    r = np.geomspace(1.0, 2000.0, 500)
    mass = ref.cdf(2000.0) - ref.cdf(1.0)
    np.testing.assert_allclose(psd.pdf(r), ref.pdf(r) / mass, rtol=1e-10)
    np.testing.assert_allclose(psd.cdf(r), (ref.cdf(r) - ref.cdf(1.0)) / mass, rtol=1e-9, atol=1e-14)
    assert psd.pdf(0.5) == 0.0 and psd.pdf(2500.0) == 0.0


def test_sigma_one_is_monodisperse():
    """sigma_g = 1 does not divide by ln 1: it is the monodisperse distribution exactly."""
    a, b = motes.LogNormal(800.0, 1.0), motes.Monodisperse(800.0)
    for psd in (a, b):
        r, w = psd.quadrature()
        assert r.tolist() == [800.0] and w.tolist() == [1.0]
        assert np.all(psd.sample(1000, seed=3) == 800.0)
        assert psd.atoms() == [(800.0, 1.0)]
        assert psd.pdf(800.0) == 0.0
    # and the limit sigma_g -> 1 approaches it
    near = motes.LogNormal(800.0, 1.0 + 1e-9)
    assert abs(near.mean(1) - 800.0) < 1e-3


@pytest.mark.parametrize(
    "psd",
    [
        motes.LogNormal(800.0, 4.0),
        motes.LogNormal(0.5, 1.2, r_min_um=0.01),
        motes.Uniform(1.0, 100.0),
        motes.Histogram([1.0, 2.0, 5.0, 10.0], [3.0, 0.0, 1.0]),
    ],
)
def test_samples_follow_cdf(psd):
    """Kolmogorov-Smirnov test (scipy) of 2e5 samples against the distribution's own CDF, p > 1e-3; and the
    same seed gives the same radii."""
    x = psd.sample(200_000, seed=11)
    assert np.array_equal(x, psd.sample(200_000, seed=11))
    lo, hi = psd.support()
    assert x.min() >= lo and x.max() <= hi
    assert stats.kstest(x, psd.cdf).pvalue > 1e-3


def test_bimodal_snow_mixture():
    """The paper's bimodal snow (Fig. 19): shares are number shares; the atom of the sigma_g = 1 mode
    keeps its share in samples (binomial 5-sigma bound) and in the quadrature."""
    snow = motes.Mixture([(1.99e7, motes.LogNormal(100.0, 1.0)), (1e5, motes.LogNormal(800.0, 2.0))])
    share = 1.99e7 / (1.99e7 + 1e5)
    assert snow.atoms() == [(100.0, pytest.approx(share, rel=1e-15))]
    x = snow.sample(1_000_000, seed=5)
    frac = np.mean(x == 100.0)
    assert abs(frac - share) < 5 * np.sqrt(share * (1 - share) / x.size)
    r, w = snow.quadrature()
    assert w.sum() == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_quadrature_moments_match_monte_carlo(k):
    """E[r^k] by the quadrature agrees with the mean over 1e6 sampled radii within 5 standard errors."""
    psd = motes.LogNormal(800.0, 4.0)
    x = psd.sample(1_000_000, seed=2)
    mc, se = np.mean(x**k), np.std(x**k) / np.sqrt(x.size)
    assert abs(psd.mean(k) - mc) < 5 * se


@given(median=log_uniform(0.05, 2000.0), sigma=st.floats(1.0, 10.0), u=st.floats(0.0, 1.0))
@example(median=0.05, sigma=1.0, u=0.0)
@example(median=2000.0, sigma=10.0, u=1.0)
@example(median=2000.0, sigma=1.0, u=0.5)
@hsettings(200)
def test_lognormal_properties(median, sigma, u):
    """Over r_g in [0.05, 2000] um and sigma_g in [1, 10]: everything finite, quantile inverts the CDF,
    quadrature weights are non-negative and sum to 1, moments within the support."""
    psd = motes.LogNormal(median, sigma)
    lo, hi = psd.support()
    q = float(psd.quantile(u))
    assert np.isfinite(q) and lo <= q <= hi
    if sigma > 1.0:
        assert abs(float(psd.cdf(q)) - u) < 1e-9
    r, w = psd.quadrature()
    assert np.all(np.isfinite(r)) and np.all(w >= 0) and abs(w.sum() - 1.0) < 1e-9
    m = psd.mean(1)
    assert lo * (1 - 1e-12) <= m <= hi * (1 + 1e-12)
    assert np.all(np.isfinite(psd.pdf(np.geomspace(lo, hi, 50))))


@pytest.mark.parametrize(
    ("factory", "name"),
    [
        (lambda: motes.LogNormal(-1.0, 2.0), "median_um"),
        (lambda: motes.LogNormal(10.0, 0.9), "sigma_g"),
        (lambda: motes.LogNormal(10.0, float("nan")), "sigma_g"),
        (lambda: motes.LogNormal(10.0, 1.0, r_min_um=20.0, r_max_um=30.0), "median_um"),
        (lambda: motes.LogNormal(10.0, 2.0, r_min_um=30.0, r_max_um=20.0), "r_max_um"),
        (lambda: motes.Monodisperse(0.0), "radius_um"),
        (lambda: motes.Uniform(5.0, 1.0), "r_max_um"),
        (lambda: motes.Histogram([1.0, 2.0], [1.0, 2.0]), "counts"),
        (lambda: motes.Histogram([2.0, 1.0], [1.0]), "edges_um"),
        (lambda: motes.Histogram([1.0, 2.0], [0.0]), "counts"),
        (lambda: motes.Mixture([]), "components"),
        (lambda: motes.Mixture([(-1.0, motes.Monodisperse(1.0))]), "weights"),
        (lambda: motes.Mixture([(1.0, "not a psd")]), "Mixture"),
    ],
)
def test_invalid_parameters_name_the_parameter(factory, name):
    with pytest.raises(ValueError, match=name):
        factory()


def test_invalid_calls():
    psd = motes.LogNormal(10.0, 2.0)
    with pytest.raises(ValueError, match="u"):
        psd.quantile(1.5)
    with pytest.raises(ValueError, match="n must"):
        psd.sample(-1)
    with pytest.raises(ValueError, match="seed"):
        psd.sample(10, seed=-3)
    with pytest.raises(ValueError, match="max_log_step"):
        psd.quadrature(0.0)
    with pytest.raises(ValueError, match="radius_um"):
        psd.cdf(np.nan)
