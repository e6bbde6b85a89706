"""Property tests (hypothesis) over the whole documented domain:

r in [0.01, 2000] um (log-uniform), lambda in [0.38, 0.78] um, Re eta in [0.7, 2.5] with eta = 1 exactly
drawn on purpose (the invisible sphere) and bubbles (Re eta < 1, kappa = 0) covered, Im eta in [0, 0.5],
theta in [0, pi] with both end points always evaluated.

Example budgets are small where one example can cost seconds (GOA normalisation at alpha ~ 3e4 integrates
~5e5 angles); everything is derandomised. Weakly absorbing bubbles (a 0/0 once found here by hypothesis)
are pinned as explicit examples.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import hsettings, log_uniform
from hypothesis import assume, example, given
from hypothesis import strategies as st

import motes

R_MIN, R_MAX = 0.01, 2000.0

radii = log_uniform(R_MIN, R_MAX)
wavelengths = st.floats(0.38, 0.78)
# eta = 1 exactly (the invisible sphere) in ~1 draw of 5, otherwise uniform in [0.7, 2.5].
eta_re = st.integers(0, 4).flatmap(lambda k: st.just(1.0) if k == 0 else st.floats(0.7, 2.5))
eta_im = st.one_of(st.just(0.0), st.floats(0.0, 0.5), log_uniform(1e-8, 0.5))
angles = st.lists(st.floats(0.0, math.pi), min_size=1, max_size=16)

METHODS = ("auto", "mie", "goa", "hybrid")


def _eta(re: float, im: float) -> complex:
    return complex(re, im)


def _domain_examples(test):
    """End points of every range, eta = 1 exactly, a bubble and the most absorbing index, at both ends of
    the size range (the largest size costs ~1 s per GOA call, so fewer combinations there)."""
    for r, lam, er, ei in (
        (R_MAX, 0.38, 1.0, 0.0),
        (R_MAX, 0.38, 0.7, 0.0),
        (R_MAX, 0.38, 2.5, 0.5),
        (R_MIN, 0.78, 1.0, 0.0),
        (R_MIN, 0.78, 0.7, 0.0),
        (R_MIN, 0.78, 2.5, 0.5),
        (R_MIN, 0.38, 0.7, 0.5),
        (R_MAX, 0.78, 1.33, 0.0),
    ):
        test = example(r=r, lam=lam, er=er, ei=ei)(test)
    return test


def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(a)) for a in arrays)


# --- amplitudes ---------------------------------------------------------------------------------------


@example(r=R_MAX, lam=0.38, er=1.0, ei=0.0, theta=[0.0, math.pi])
@example(r=R_MIN, lam=0.78, er=0.7, ei=0.0, theta=[0.0, math.pi])
@example(r=R_MAX, lam=0.38, er=0.7, ei=0.0, theta=[1e-300, math.pi - 1e-15, math.pi / 2])
@example(r=R_MAX, lam=0.38, er=2.5, ei=0.5, theta=[5e-324, 1e-12, 1e-9])
@example(r=5.0, lam=0.6, er=1.0, ei=1e-8, theta=[0.0, 1e-10, 0.3])
@given(r=radii, lam=wavelengths, er=eta_re, ei=eta_im, theta=angles)
@hsettings(200)
def test_amplitudes_finite(r, lam, er, ei, theta):
    """``mie_amplitudes`` and ``goa_amplitudes`` (defaults, and p_max = 0 / 5) return finite complex
    numbers at every theta in [0, pi], end points included, over the whole parameter domain."""
    th = np.array([0.0, math.pi, *theta])
    eta = _eta(er, ei)
    s1, s2 = motes.mie_amplitudes(r, lam, eta, th)
    assert _finite(s1, s2), (s1, s2)
    for p_max in (3, 0, 5):
        s1, s2 = motes.goa_amplitudes(r, lam, eta, th, p_max=p_max)
        assert _finite(s1, s2), (p_max, s1, s2)


# --- cross sections -----------------------------------------------------------------------------------


def check_cross_sections(r, lam, eta, ei):
    for method in METHODS:
        cs = motes.cross_sections(r, lam, eta, method=method)
        ext, sca, ab, g = (float(cs[k]) for k in ("ext", "sca", "abs", "g"))
        assert _finite(ext, sca, ab, g), (method, r, lam, eta, cs)
        tol = 1e-9 * abs(ext)
        assert ext >= sca - tol, (method, cs)
        assert sca >= -tol, (method, cs)
        assert ab >= -tol, (method, cs)
        assert abs(ext - sca - ab) <= tol, (method, cs)
        assert -1.0 - 1e-12 <= g <= 1.0 + 1e-12, (method, cs)
        if ei == 0.0:
            assert ab <= tol, (method, cs)


@example(r=1.0, lam=0.5, er=0.75, ei=1e-14)  # regression: 0/0 in the GOA absorption series (fixed)
@example(r=100.0, lam=0.5, er=0.9, ei=1e-15)
@_domain_examples
@given(r=radii, lam=wavelengths, er=eta_re, ei=eta_im)
@hsettings(100)
def test_cross_sections_finite_and_ordered(r, lam, er, ei):
    """For every method (auto, mie, goa, hybrid) all of ext, sca, abs, g are finite, and
    C_ext >= C_sca >= 0, C_abs >= 0, C_ext = C_sca + C_abs, |g| <= 1 — up to rounding (1e-9 of C_ext) —
    over the whole domain, weakly absorbing bubbles included."""
    check_cross_sections(r, lam, _eta(er, ei), ei)



@given(lam=wavelengths, er=st.floats(0.7, 2.5).filter(lambda v: abs(v - 1.0) >= 0.01), ei=eta_im)
@example(lam=0.38, er=1.33, ei=0.0)
@example(lam=0.78, er=0.7, ei=0.0)
@example(lam=0.38, er=2.5, ei=0.5)
@example(lam=0.6, er=1.01, ei=0.0)
@hsettings(200)
def test_goa_extinction_tends_to_twice_geometric(lam, er, ei):
    """Extinction paradox with its rate: |Q_ext(GOA)/2 - 1| <= 2 (alpha^{-2/3} + 1/(alpha |Re eta - 1|))
    for r in [1, 2000] um — the edge term ~ alpha^{-2/3} plus the anomalous-diffraction ripple
    ~ 1/rho, rho = 2 alpha |eta - 1| (measured worst ratio 1.38 over 2e5 random draws) — so C_ext -> 2 pi r^2
    as r grows; and at r = 2000 um with |Re eta - 1| >= 0.05, within 1 %."""
    eta = _eta(er, ei)
    r = np.logspace(0.0, math.log10(R_MAX), 40)
    alpha = 2.0 * math.pi * r / lam
    q = motes.goa_extinction_efficiency(alpha, eta)
    envelope = alpha ** (-2.0 / 3.0) + 1.0 / (alpha * abs(er - 1.0))
    assert np.all(np.abs(q / 2.0 - 1.0) <= 2.0 * envelope), np.max(np.abs(q / 2 - 1) / envelope)
    if abs(er - 1.0) >= 0.05:
        assert abs(q[-1] / 2.0 - 1.0) < 0.01


# --- phase function -----------------------------------------------------------------------------------

_GL_X, _GL_W = np.polynomial.legendre.leggauss(6)


def sphere_integral(r, lam, eta, method):
    """2 pi int_0^pi f sin(theta) d theta by composite 6-point Gauss–Legendre on max(200, ceil(2.5 alpha))
    equal panels: the diffraction lobe (width ~1/alpha) and fringes (period ~pi/alpha) get ~8 nodes per
    half-period. (Deliberately a different grid from the library's own normaliser — 8 nodes on panels of
    pi/(2 alpha) — so the test checks the normalisation rather than reproducing it.) Returns the integral
    and the phase function values on the grid with theta = 0 and pi appended."""
    alpha = 2.0 * math.pi * r / lam
    n = int(max(200, math.ceil(2.5 * alpha)))
    edges = np.linspace(0.0, math.pi, n + 1)
    h = np.diff(edges)[:, None]
    nodes = (edges[:-1, None] + 0.5 * h * (1.0 + _GL_X[None, :])).ravel()
    weights = (0.5 * h * _GL_W[None, :]).ravel()
    theta = np.concatenate([nodes, [0.0, math.pi]])
    f = motes.phase_function(r, lam, eta, theta, method=method)
    return 2.0 * math.pi * float(np.sum(weights * f[:-2] * np.sin(nodes))), f


@example(r=R_MAX, lam=0.38, er=1.0, ei=0.0, method="goa")
@example(r=R_MAX, lam=0.38, er=0.7, ei=0.0, method="auto")
@example(r=150.0, lam=0.38, er=2.0, ei=0.0, method="auto")  # alpha ~ 2.5e3, Mie (ball-lens window)
@example(r=R_MIN, lam=0.78, er=1.0, ei=0.0, method="goa")
@example(r=R_MIN, lam=0.38, er=2.5, ei=0.5, method="goa")
@example(r=R_MIN, lam=0.38, er=0.7, ei=0.0, method="auto")
@example(r=9.0, lam=0.6, er=1.33, ei=0.0, method="auto")  # alpha ~ 94: GOA under "auto"
@example(r=5.0, lam=0.6, er=0.75, ei=0.0, method="auto")  # alpha ~ 52: Mie under "auto"
@example(r=300.0, lam=0.5, er=1.5, ei=1e-3, method="goa")
@given(r=radii, lam=wavelengths, er=eta_re, ei=eta_im, method=st.sampled_from(["auto", "goa"]))
@hsettings(100)
def test_phase_function_normalised_and_finite(r, lam, er, ei, method):
    """``phase_function`` (method auto — Mie below alpha = 60 and near degenerate axial rays, GOA
    otherwise — and goa) is finite and non-negative everywhere including theta = 0, pi, and integrates to
    1 over the sphere within 1e-3 (measured <= 2e-4; GOA's normaliser is its own quadrature, Mie's is the
    exact C_sca).

    Draws where "auto" resolves to Mie at alpha > 3000 are rejected for cost only (the grid costs
    ~75 ns alpha^2: 80 s at alpha = 3.3e4); Mie's normalisation up to x = 1e4 is covered by
    test_mie.py, which compares the normalised phase function with miepython's."""
    eta = _eta(er, ei)
    alpha = 2.0 * math.pi * r / lam
    assume(not (alpha > 3000.0 and motes.resolve_method(r, lam, eta, method=method).item() == "mie"))
    total, f = sphere_integral(r, lam, eta, method)
    assert np.all(np.isfinite(f)), f[~np.isfinite(f)][:5]
    assert np.all(f >= 0.0)
    # GOA far below its domain (alpha < 1, where "auto" never uses it): 1.0e-3 measured at alpha = 0.21,
    # eta 0.88 + 0.125i (a discontinuity of the regularised orders that neither grid resolves exactly).
    assert abs(total - 1.0) <= (2e-3 if method == "goa" and alpha < 1.0 else 1e-3), total


@given(r=radii, lam=wavelengths, er=eta_re, ei=eta_im, theta=angles)
@example(r=R_MAX, lam=0.38, er=1.0, ei=0.0, theta=[0.0, math.pi])
@example(r=R_MIN, lam=0.78, er=0.7, ei=0.0, theta=[0.0, math.pi])
@hsettings(100)
def test_mie_phase_function_matches_amplitudes(r, lam, er, ei, theta):
    """``phase_function(method="mie")`` is (|S1|^2+|S2|^2)/(2 k^2 C_sca) of ``mie_amplitudes`` and
    ``cross_sections`` (k = 2 pi/lambda) to 1e-9 — the three entry points agree on one particle. Skipped
    (vacuously) only when C_sca underflows to 0, e.g. eta = 1."""
    eta = _eta(er, ei)
    th = np.array([0.0, math.pi, *theta])
    f = motes.phase_function(r, lam, eta, th, method="mie")
    s1, s2 = motes.mie_amplitudes(r, lam, eta, th)
    sca = float(motes.cross_sections(r, lam, eta, method="mie")["sca"])
    k = 2.0 * math.pi / lam
    assert np.all(np.isfinite(f))
    if sca > 0.0 and np.isfinite(1.0 / (2 * k * k * sca)):
        expected = (np.abs(s1) ** 2 + np.abs(s2) ** 2) / (2 * k * k * sca)
        np.testing.assert_allclose(f, expected, rtol=1e-9, atol=1e-300)
