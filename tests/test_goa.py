"""Geometrical optics approximation (GOA, Guo et al.) against Lorenz–Mie and against its own closed forms.

Error measure (paper Sec. 3.3): RelMSE of (|S1|+|S2|)/2 on theta = linspace(0, pi, 1800), lambda = 0.6 um.
Values measured with the default options (p_max = 3, regularise, edge correction) when this file was
written; the bounds carry a margin of ~1.5x over them:

    r (um)        2        3        5        10       30       100
    eta=1.33    1.60e-2  9.75e-3  3.54e-3  1.66e-3  3.75e-4  5.20e-5
    eta=1.49    1.78e-2  7.11e-3  6.84e-3  1.77e-3  5.01e-4  7.44e-5
    eta=1.56    1.61e-2  7.44e-3  5.75e-3  1.98e-3  5.01e-4  6.65e-5
    eta=0.75    6.02e-3  5.16e-3  2.23e-3  1.01e-3  2.54e-4  3.38e-5
    1.5+0.01j   1.15e-2  5.91e-3  3.17e-3  1.25e-3  3.08e-4  4.96e-5

(re-measured after commit 5dc4d02, "pole-symmetric glory rays"; before it the numbers differed by < 15 %).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import relmse

import motes

LAM = 0.6
THETA = np.linspace(0.0, math.pi, 1800)


def goa_vs_mie(r, eta, **goa_options) -> float:
    return relmse(motes.goa_amplitudes(r, LAM, eta, THETA, **goa_options), motes.mie_amplitudes(r, LAM, eta, THETA))


# --- GOA against Mie --------------------------------------------------------------------------------


@pytest.mark.parametrize("eta", [1.33, 1.49, 1.56])
@pytest.mark.parametrize("r", [5.0, 10.0, 30.0, 100.0])
def test_relmse_below_one_percent(r, eta):
    """The paper's accuracy claim holds from r = 5 um up: RelMSE(GOA, Mie) <= 0.01 for water, PMMA-like
    and glass-like indices."""
    assert goa_vs_mie(r, eta) <= 0.01


@pytest.mark.parametrize("eta", [1.33, 1.49, 1.56])
@pytest.mark.parametrize(("r", "bound"), [(2.0, 0.025), (3.0, 0.0125)])
def test_relmse_small_particles_as_achieved(r, eta, bound):
    """At the paper's hybrid threshold the paper claims RelMSE <= 0.01; what this implementation
    actually achieves is 1.6e-2..1.8e-2 at r = 2 um and 7.1e-3..9.8e-3 at r = 3 um (measured). This test
    pins the achieved level (r = 2: <= 0.025, r = 3: <= 0.0125) so a regression shows; it does NOT
    confirm the paper's 0.01 at r = 2 um, which is missed."""
    assert goa_vs_mie(r, eta) <= bound


def test_relmse_improves_with_size():
    """GOA is asymptotic in size: at eta = 1.33 its RelMSE falls monotonically over r = 2..100 um and is
    below 1e-4 at r = 100 um."""
    errs = [goa_vs_mie(r, 1.33) for r in (2.0, 3.0, 5.0, 10.0, 30.0, 100.0)]
    assert all(a > b for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 1e-4


@pytest.mark.parametrize(
    ("r", "bound"),
    [(2.0, 9e-3), (3.0, 7.5e-3), (5.0, 3.3e-3), (10.0, 1.5e-3), (30.0, 3.8e-4), (100.0, 5.1e-5)],
)
def test_relmse_bubble(r, bound):
    """Air bubble in a denser host (relative eta = 0.75, total internal reflection, no edge term):
    RelMSE within 1.5x of the measured 6.0e-3, 5.2e-3, 2.2e-3, 1.0e-3, 2.5e-4, 3.4e-5."""
    assert goa_vs_mie(r, 0.75) <= bound


@pytest.mark.parametrize(
    ("r", "bound"),
    [(2.0, 1.8e-2), (3.0, 9e-3), (5.0, 4.8e-3), (10.0, 1.9e-3), (30.0, 4.6e-4), (100.0, 7.5e-5)],
)
def test_relmse_absorbing(r, bound):
    """Absorbing sphere eta = 1.5 + 0.01i (App. C inhomogeneous waves): RelMSE within 1.5x of the
    measured 1.15e-2 (1.2e-2 before 5dc4d02), 5.9e-3, 3.2e-3, 1.25e-3, 3.1e-4, 5.0e-5."""
    assert goa_vs_mie(r, 1.5 + 0.01j) <= bound


def test_regularisation_is_what_makes_small_spheres_work():
    """The paper's formulas verbatim (``regularise=False``) are singular at the caustics/glories that
    the 1800-angle grid hits: at eta = 1.56, r = 2 um RelMSE is > 1 (measured ~4e3), while the default
    regularised GOA is < 0.03 (measured 1.6e-2)."""
    assert goa_vs_mie(2.0, 1.56, regularise=False) > 1.0
    assert goa_vs_mie(2.0, 1.56, regularise=True) < 0.03


def test_goa_cross_sections_close_to_mie():
    """Large spheres: GOA's C_ext, C_sca and g agree with Mie to 1 % (ext, sca) and 0.01 (g) at r = 100 um
    for a non-absorbing, an absorbing and a bubble index."""
    for eta in (1.33, 1.5 + 0.01j, 0.75):
        goa = motes.cross_sections(100.0, LAM, eta, method="goa")
        mie = motes.cross_sections(100.0, LAM, eta, method="mie")
        assert float(goa["ext"]) == pytest.approx(float(mie["ext"]), rel=0.01), eta
        assert float(goa["sca"]) == pytest.approx(float(mie["sca"]), rel=0.01), eta
        assert float(goa["g"]) == pytest.approx(float(mie["g"]), abs=0.01), eta


# --- extinction (Eq. 12) ----------------------------------------------------------------------------


def test_extinction_p1_vs_p3():
    """Eq. 12 converges in the ray order: C_ext with p_max = 1 and p_max = 3 differ by a relative mean
    square (C3-C1)^2/C3^2 < 1e-5 on a log grid of r in (1, 1000] um at eta = 1.33 (measured on this grid: mean 4e-8,
    worst 5e-7; on a fine grid the worst is 2.4e-6 at r ~ 1.08 um), and every point is below 1e-5 as well."""
    r = np.logspace(math.log10(1.0001), 3.0, 48)
    c1 = motes.cross_sections(r, LAM, 1.33, method="goa", p_max=1)["ext"]
    c3 = motes.cross_sections(r, LAM, 1.33, method="goa", p_max=3)["ext"]
    err = (c3 - c1) ** 2 / c3**2
    assert np.mean(err) < 1e-5
    assert np.max(err) < 1e-5
    assert np.any(c3 != c1)  # p = 3 does contribute


def test_extinction_tends_to_twice_geometric():
    """Extinction paradox: C_ext(GOA) / (2 pi r^2) -> 1, |ratio - 1| < 0.01 at r = 2000 um (measured
    1.3e-3), falling monotonically over r = 10, 100, 300, 1000, 2000 um (measured 4.4e-2 .. 1.3e-3)."""
    r = np.array([10.0, 100.0, 300.0, 1000.0, 2000.0])
    ext = motes.cross_sections(r, LAM, 1.33, method="goa")["ext"]
    dev = np.abs(ext / (2.0 * math.pi * r**2) - 1.0)
    assert dev[-1] < 0.01
    assert np.all(np.diff(dev) < 0), dev


def test_extinction_eq12_matches_cross_sections():
    """``cross_sections(method="goa")["ext"]`` is pi r^2 times ``goa_extinction_efficiency`` (Eq. 12) for
    a non-absorbing particle (where the C_ext >= C_abs clamp cannot act)."""
    r = np.array([3.0, 30.0, 300.0])
    alpha = 2.0 * math.pi * r / LAM
    for eta in (1.33, 0.75, 2.4):
        ext = motes.cross_sections(r, LAM, eta, method="goa")["ext"]
        q = motes.goa_extinction_efficiency(alpha, eta)
        np.testing.assert_allclose(ext, q * math.pi * r**2, rtol=1e-12)


def test_extinction_eq14_for_eta_above_one():
    """For eta > 1 and p_max = 1 without regularisation or edge term, Eq. 12 reduces to the paper's closed
    form Eq. 14: C = 2 pi r^2 + 4 r lambda eta^2 / ((eta+1)^2 (eta-1)) sin(4 pi r (1-eta)/lambda)."""
    r = np.array([2.0, 7.3, 40.0, 333.0])
    alpha = 2.0 * math.pi * r / LAM
    for eta in (1.33, 1.6, 2.2):
        q = motes.goa_extinction_efficiency(alpha, eta, p_max=1, regularise=False, edge_correction=False)
        eq14 = 2 * math.pi * r**2 + 4 * r * LAM * eta**2 / ((eta + 1) ** 2 * (eta - 1)) * np.sin(
            4 * math.pi * r / LAM * (1 - eta)
        )
        np.testing.assert_allclose(q * math.pi * r**2, eq14, rtol=1e-10)


# --- total internal reflection ----------------------------------------------------------------------


def test_bubble_total_internal_reflection_amplitude():
    """External reflection (p = 0) off a bubble, eta = 0.75: for scattering angles theta < pi - 2 asin(0.75)
    the incidence angle theta_i = (pi - theta)/2 exceeds the critical angle, |r_perp| = |r_par| = 1, and
    Eq. 7 gives |S_j|^2 = alpha^2 sin(2 theta_i) / (4 sin theta) (|d theta/d theta_i| = 2), i.e. alpha^2/4.
    Checked to 1e-9 with the paper's formulas verbatim (regularise=False), diffraction off."""
    r = 10.0
    alpha = 2.0 * math.pi * r / LAM
    theta_tir = math.pi - 2.0 * math.asin(0.75)
    theta = np.array([0.05, 0.3, 0.7, 1.0, 1.3, theta_tir - 1e-3])
    s1, s2 = motes.goa_amplitudes(r, LAM, 0.75, theta, p_max=0, diffraction=False, regularise=False)
    theta_i = 0.5 * (math.pi - theta)
    expected = alpha * np.sqrt(np.sin(2 * theta_i) / (4.0 * np.sin(theta)))
    np.testing.assert_allclose(np.abs(s1), expected, rtol=1e-9)
    np.testing.assert_allclose(np.abs(s2), expected, rtol=1e-9)


def test_bubble_partial_reflection_amplitude():
    """Outside the TIR range (theta > pi - 2 asin(0.75)) the p = 0 amplitude is alpha/2 |r_j| with the
    Fresnel coefficients r_perp = (cos ti - b)/(cos ti + b), r_par = (m^2 cos ti - b)/(m^2 cos ti + b),
    b = sqrt(m^2 - sin^2 ti) (regularise=False, diffraction off), to 1e-9."""
    r, m = 10.0, 0.75
    alpha = 2.0 * math.pi * r / LAM
    theta = np.array([1.6, 2.0, 2.5, 3.0])
    s1, s2 = motes.goa_amplitudes(r, LAM, m, theta, p_max=0, diffraction=False, regularise=False)
    ti = 0.5 * (math.pi - theta)
    c = np.cos(ti)
    b = np.sqrt(m**2 - np.sin(ti) ** 2)
    r_perp = (c - b) / (c + b)
    r_par = (m**2 * c - b) / (m**2 * c + b)
    np.testing.assert_allclose(np.abs(s1), alpha / 2 * np.abs(r_perp), rtol=1e-9)
    np.testing.assert_allclose(np.abs(s2), alpha / 2 * np.abs(r_par), rtol=1e-9)


# --- absorption ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1.33, 1.5, 2.0, 0.75])
def test_weak_absorption_matches_eq13(n):
    """When alpha*kappa << 1 (r = 10 um, kappa = 1e-5: alpha*kappa = 1e-3) the GOA absorption cross
    section equals the paper's Eq. 13, C_a = 16 pi^2 r^3 kappa / (3 lambda n) [n^3 - (n^2-1)^{3/2}], to 1 %
    (measured 0.2 %; for n < 1 the (n^2-1)^{3/2} term is 0)."""
    r, kappa = 10.0, 1e-5
    cs = motes.cross_sections(r, LAM, n + 1j * kappa, method="goa")
    eq13 = 16 * math.pi**2 * r**3 * kappa / (3 * LAM * n) * (n**3 - max(n * n - 1, 0.0) ** 1.5)
    assert float(cs["abs"]) == pytest.approx(eq13, rel=0.01)


@pytest.mark.parametrize("eta", [1.33 + 0.1j, 1.5 + 0.5j, 2.0 + 1.0j, 0.8 + 0.3j, 1.05 + 0.01j])
@pytest.mark.parametrize("r", [1.0, 10.0, 100.0, 1000.0])
def test_absorption_bounded(r, eta):
    """Absorption never exceeds what the geometric cross section can take: 0 < C_abs <= pi r^2, and
    C_abs <= C_ext, C_sca = C_ext - C_abs >= 0 (GOA)."""
    cs = motes.cross_sections(r, LAM, eta, method="goa")
    area = math.pi * r * r
    assert 0.0 < float(cs["abs"]) <= area
    assert float(cs["abs"]) <= float(cs["ext"])
    assert float(cs["sca"]) >= 0.0
    assert float(cs["ext"]) - float(cs["abs"]) == pytest.approx(float(cs["sca"]), rel=1e-12, abs=1e-12 * area)


def test_strong_absorption_saturates():
    """A large, strongly absorbing sphere absorbs all refracted light: C_abs/(pi r^2) = 1 - (reflectance
    averaged over the disc), which is in (0.5, 1) for eta = 1.5 + 0.5i, and is independent of r once
    alpha*kappa >> 1 (r = 10 vs 1000 um to 1e-9)."""
    q = [float(motes.cross_sections(r, LAM, 1.5 + 0.5j, method="goa")["abs"]) / (math.pi * r * r) for r in (10.0, 1000.0)]
    assert 0.5 < q[0] < 1.0
    assert q[0] == pytest.approx(q[1], rel=1e-9)


def test_goa_absorption_close_to_mie():
    """GOA's absorption agrees with Mie to 2 % for a large absorbing sphere (r = 100 um, eta = 1.33 + 1e-4i,
    alpha*kappa ~ 0.1, neither limit of Eq. 13)."""
    goa = motes.cross_sections(100.0, LAM, 1.33 + 1e-4j, method="goa")
    mie = motes.cross_sections(100.0, LAM, 1.33 + 1e-4j, method="mie")
    assert float(goa["abs"]) == pytest.approx(float(mie["abs"]), rel=0.02)


# --- regressions of fixed bugs -------------------------------------------------------------------------

def test_bubble_weak_absorption_is_continuous():
    """A bubble with a negligible absorption (eta = 0.75 + 1e-8 i, alpha*kappa ~ 1e-6) scatters like the
    non-absorbing bubble: GOA amplitudes within RelMSE 1e-4 of the eta = 0.75 ones, RelMSE vs Mie within the
    non-absorbing bubble's bound (1.5e-3 at r = 10 um), and g within 0.02 of Mie's.

    Regression: evanescent waves beyond the critical angle were once treated as refracted rays as soon as
    kappa > 0 (RelMSE 9.5e-2, g 0.552); the transmission factor now follows the energy balance."""
    r, weak = 10.0, 0.75 + 1e-8j
    goa_weak = motes.goa_amplitudes(r, LAM, weak, THETA)
    assert relmse(goa_weak, motes.goa_amplitudes(r, LAM, 0.75, THETA)) < 1e-4
    assert relmse(goa_weak, motes.mie_amplitudes(r, LAM, weak, THETA)) <= 1.5e-3
    g_goa = float(motes.cross_sections(r, LAM, weak, method="goa")["g"])
    g_mie = float(motes.cross_sections(r, LAM, weak, method="mie")["g"])
    assert abs(g_goa - g_mie) < 0.02


@pytest.mark.parametrize("method", ["goa", "auto", "hybrid"])
def test_bubble_tiny_absorption_cross_sections_finite(method):
    """Cross sections of bubbles with a tiny absorption (0.75 + 1e-14i, 0.9 + 1e-15i) are finite and
    their absorption is >= 0 and negligible (< 1e-9 of C_ext). Regression: 0/0 gave NaN here."""
    for r, eta in ((1.0, 0.75 + 1e-14j), (100.0, 0.9 + 1e-15j)):
        cs = motes.cross_sections(r, 0.5, eta, method=method)
        assert all(np.isfinite(float(cs[k])) for k in cs), (r, eta, cs)
        assert 0.0 <= float(cs["abs"]) < 1e-9 * float(cs["ext"]), (r, eta, cs)


def test_invisible_sphere_has_no_extinction():
    """A sphere with the host's index (eta = eta_medium) does not scatter: GOA's Q_ext -> 0 (module docs,
    regularisation 4: "tends to zero extinction as eta -> 1"), so Q_ext(GOA) < 1e-6 at eta = 1 for
    alpha = 10..1e4 (also through cross_sections), the default method agrees with Mie (C_ext < 1e-6 pi r^2)
    also for eta = eta_medium = 1.333, and Q_ext is continuous across eta = 1 (|Q(1+1e-4) - Q(1-1e-4)|
    < 1e-3 at alpha = 104.7).

    Regression test: before commit 5dc4d02 the edge term was added at eta = 1 (Q_ext = 0.088 at
    alpha = 104.7, and 0.088 vs 0.0004 on either side of eta = 1)."""
    alpha = np.array([10.0, 100.0, 1e3, 1e4])
    assert np.all(np.abs(motes.goa_extinction_efficiency(alpha, 1.0)) < 1e-6)
    r = alpha * LAM / (2.0 * math.pi)
    assert np.all(motes.cross_sections(r, LAM, 1.0, method="goa")["ext"] < 1e-6 * math.pi * r**2)
    for eta, eta_medium in ((1.0, 1.0), (1.333, 1.333)):
        ext = float(motes.cross_sections(10.0, LAM, eta, eta_medium=eta_medium)["ext"])
        assert ext < 1e-6 * math.pi * 100.0
    a = 2.0 * math.pi * 10.0 / LAM
    assert abs(motes.goa_extinction_efficiency(a, 1.0001) - motes.goa_extinction_efficiency(a, 0.9999)) < 1e-3


def test_free_functions_keep_goa_geometry_between_calls():
    """Issue 23.1: goa_amplitudes / phase_function / cross_sections reuse the ray geometry of a relative
    index from one call to the next (a bounded cache owned by the binding, not the core); clearing it
    changes no number."""
    theta = np.linspace(0.0, np.pi, 181)
    motes.clear_goa_cache()
    assert motes.goa_cache_info()["indices"] == 0
    s1, s2 = motes.goa_amplitudes(500.0, 0.6, 1.33, theta)
    info = motes.goa_cache_info()
    assert info["indices"] == 1 and info["bytes"] > 0
    t1, t2 = motes.goa_amplitudes(800.0, 0.6, 1.33, theta)  # same index: no new entry
    assert motes.goa_cache_info()["indices"] == 1
    motes.clear_goa_cache()
    u1, u2 = motes.goa_amplitudes(800.0, 0.6, 1.33, theta)
    np.testing.assert_array_equal(t1, u1)
    np.testing.assert_array_equal(t2, u2)
    f = motes.phase_function(800.0, 0.6, 1.5, theta, method="goa")
    assert motes.goa_cache_info()["indices"] == 2
    motes.clear_goa_cache()
    np.testing.assert_array_equal(f, motes.phase_function(800.0, 0.6, 1.5, theta, method="goa"))


def test_free_function_goa_cache_is_bounded():
    """Many relative indices do not grow the free functions' cache without bound."""
    theta = np.linspace(0.0, np.pi, 19)
    motes.clear_goa_cache()
    for n in np.linspace(1.2, 1.8, 20):
        motes.goa_amplitudes(300.0, 0.6, float(n), theta)
    assert motes.goa_cache_info()["indices"] <= 8
