"""Mueller matrices of single spheres (``mueller_matrix``) and of ensembles (``bulk_properties(mueller=True)``).

Convention (Bohren & Huffman 1983, §4.4; motes uses m = n + i kappa and exp(-i omega t)):
F11 = (|S2|^2 + |S1|^2)/2, F12 = (|S2|^2 - |S1|^2)/2, F33 = Re(S2 S1*), F34 = Im(S2 S1*).

Oracles: ``miepython`` 3.3.0 (independent Mie code, m = n - i kappa: its amplitudes are the complex
conjugates of Bohren & Huffman's, so its Im(S2 S1*) is -F34), the Rayleigh limit in closed form, and, for
ensembles, numpy sums of single-particle elements over the PSD's atoms (independent of the core's
coefficient-space sums).
"""

from __future__ import annotations

import math

import miepython
import numpy as np
import pytest
from conftest import hsettings, log_uniform
from hypothesis import example, given
from hypothesis import strategies as st

import motes

LAM = 0.55


def radius(x: float) -> float:
    return x * LAM / (2.0 * math.pi)


def ratios(m: np.ndarray) -> np.ndarray:
    """(F12, F33, F34) / F11 of elements (..., 4)."""
    return m[..., 1:] / m[..., :1]


# --- (a) Mie against miepython ---------------------------------------------------------------------

MIE_CASES = [(x, m) for x in (0.1, 1.0, 10.0, 50.0) for m in (1.33 + 0j, 1.5 + 0.1j, 0.75 + 0j, 2.0 + 1.0j, 1.33 + 1e-3j)]


@pytest.mark.parametrize("x,m", MIE_CASES)
def test_mie_elements_match_miepython(x, m):
    """All four raw elements (``normalize=False``) equal those of miepython's amplitudes to 1e-6 of max F11.
    ``norm="wiscombe"`` makes miepython return Bohren & Huffman's unnormalised amplitudes; it takes
    m = n - i kappa, so we pass conj(m) and get conj(S1), conj(S2): F11, F12, F33 are unchanged and its
    Im(S2 S1*) is -F34 — the sign flip is asserted, not hidden."""
    theta = np.linspace(0.0, math.pi, 721)
    got = motes.mueller_matrix(radius(x), LAM, m, theta, method="mie", normalize=False)
    s1, s2 = miepython.S1_S2(m.conjugate(), x, np.cos(theta), norm="wiscombe")
    c = s2 * np.conj(s1)
    ref = np.stack([0.5 * (abs(s2) ** 2 + abs(s1) ** 2), 0.5 * (abs(s2) ** 2 - abs(s1) ** 2), c.real, -c.imag], axis=-1)
    scale = ref[:, 0].max()
    err = np.abs(got - ref).max(axis=0) / scale
    assert np.all(err < 1e-6), f"x={x} m={m}: errors of F11, F12, F33, F34 relative to max F11: {err}"
    if m.imag > 0.05 and x >= 10:
        # F34 is far from 0 here, so the flip matters: miepython's Im(S2 S1*) taken as F34 would fail.
        assert np.abs(got[:, 3] - c.imag).max() > 0.01 * scale


def test_normalised_f11_integrates_to_one():
    """``normalize=True``: F11 in 1/sr, integral over the sphere 1; all four scaled by one factor."""
    theta = np.linspace(0.0, math.pi, 20001)
    for r, m in ((0.3, 1.5 + 0.01j), (2.0, 1.33 + 0j)):
        f = motes.mueller_matrix(r, LAM, m, theta, method="mie")
        raw = motes.mueller_matrix(r, LAM, m, theta, method="mie", normalize=False)
        assert np.trapezoid(f[:, 0] * 2 * np.pi * np.sin(theta), theta) == pytest.approx(1.0, rel=1e-6)
        big = np.abs(raw) > 1e-3 * raw[:, :1]  # F12, F33, F34 cross 0: compare elsewhere
        scale = f[big] / raw[big]  # one factor for every element and angle
        assert np.ptp(scale) < 1e-12 * scale.mean()


# --- (b) F11 is the phase function ------------------------------------------------------------------


@pytest.mark.parametrize("method", ["mie", "goa", "auto", "hybrid"])
def test_f11_is_the_phase_function(method):
    """F11 of ``mueller_matrix`` equals ``phase_function`` exactly, and broadcasts like it."""
    r = np.array([[0.4], [3.0], [25.0], [120.0]])
    theta = np.linspace(0.0, math.pi, 181)
    eta = 1.33 + 1e-4j
    m = motes.mueller_matrix(r, LAM, eta, theta, method)
    f = motes.phase_function(r, LAM, eta, theta, method)
    assert m.shape == f.shape + (4,) == (4, 181, 4)
    np.testing.assert_array_equal(m[..., 0], f)


def test_arguments_are_checked_like_phase_function():
    for bad in (dict(theta=-0.1), dict(method="rayleigh"), dict(normalize=1)):
        args = dict(radius_um=1.0, wavelength_um=LAM, eta=1.33, theta=0.5) | bad
        with pytest.raises(ValueError):
            motes.mueller_matrix(**args)


def test_index_matched_sphere_is_isotropic_and_unpolarised():
    m = motes.mueller_matrix(5.0, LAM, 1.0, [0.0, 1.0, math.pi], "mie")
    np.testing.assert_array_equal(m, np.tile([1 / (4 * np.pi), 0.0, 1 / (4 * np.pi), 0.0], (3, 1)))


# --- (c) Rayleigh limit -----------------------------------------------------------------------------


@pytest.mark.parametrize("eta", [1.5 + 0j, 1.33 + 0.1j, 0.75 + 0j])
def test_rayleigh_limit(eta):
    """x = 0.01: F12/F11 = -sin^2/(1+cos^2) (negative at 90 deg: the degree of polarisation -F12/F11 is
    +1 there), F33/F11 = 2 cos/(1+cos^2), F34 ~ 0; corrections are O(x^2) ~ 1e-4."""
    theta = np.linspace(0.0, math.pi, 181)
    r = ratios(motes.mueller_matrix(radius(0.01), LAM, eta, theta, "mie"))
    c, s2 = np.cos(theta), np.sin(theta) ** 2
    np.testing.assert_allclose(r[:, 0], -s2 / (1 + c * c), atol=1e-3)
    np.testing.assert_allclose(r[:, 1], 2 * c / (1 + c * c), atol=1e-3)
    np.testing.assert_allclose(r[:, 2], 0.0, atol=1e-3)
    assert r[90, 0] == pytest.approx(-1.0, abs=1e-3)


# --- (d) GOA against Mie ----------------------------------------------------------------------------

THETA_FINE = np.radians(np.linspace(0.0, 180.0, 36001))


def _window_ratios(r_um, eta, method, width_deg=5.0):
    """Window centres (deg) and the ratios of the elements averaged over ``width_deg`` windows: GOA has
    no Mie ripple, so only angle-averaged polarisation can agree."""
    m = motes.mueller_matrix(r_um, LAM, eta, THETA_FINE, method)
    n = int(round(width_deg / 0.005))
    k = (THETA_FINE.size - 1) // n
    mean = m[: k * n].reshape(k, n, 4).mean(axis=1)
    return np.degrees(THETA_FINE[: k * n].reshape(k, n).mean(axis=1)), ratios(mean)


@pytest.mark.parametrize("eta", [1.33, 1.5])
@pytest.mark.parametrize("r_um", [20.0, 40.0, 60.0])
def test_goa_polarisation_follows_mie(r_um, eta):
    """Measured with 5-degree windows at lambda = 0.55 um (x = 228..685), radii 20..60 um in steps of 10:

    * 10..60 deg (beyond the diffraction peak, before the p = 1 edge at 2 acos(1/eta) = 83 deg for water,
      96 deg for glass): |d(-F12/F11)| <= 0.083 (glass, r = 20 um; <= 0.053 elsewhere), rms <= 0.038,
      |d(F33/F11)| <= 0.018;
    * water's primary rainbow, 137..150 deg: |dP| <= 0.06, |d(F33/F11)| <= 0.072;
    * over all angles the windowed degrees of polarisation correlate at 0.94..0.97.
    Elsewhere GOA is far off (0.3..1 near the p = 1 edge, the dark band, the glory: surface waves and
    edge effects that ray optics lacks), so no claim is made there. Tolerances: the measured worst plus a
    margin; a wrong sign of F12 or a swapped S1/S2 in GOA would fail every one of them."""
    c, mie = _window_ratios(r_um, eta, "mie")
    _, goa = _window_ratios(r_um, eta, "goa")
    d = np.abs(goa - mie)
    fwd = (c > 10) & (c < 60)
    assert d[fwd, 0].max() < 0.1, d[fwd, 0].max()
    assert np.sqrt(np.mean(d[fwd, 0] ** 2)) < 0.05
    assert d[fwd, 1].max() < 0.03, d[fwd, 1].max()
    if eta == 1.33:
        bow = (c > 137) & (c < 150)
        assert d[bow, 0].max() < 0.08, d[bow, 0].max()
        assert d[bow, 1].max() < 0.1, d[bow, 1].max()
        assert mie[bow, 0].min() < -0.3  # the rainbow is strongly polarised (F12 << 0): the test sees it
    assert np.corrcoef(mie[:, 0], goa[:, 0])[0, 1] > 0.9


@pytest.mark.parametrize("r_um", [40.0, 60.0])
def test_goa_f34_sign_follows_mie_for_an_absorbing_sphere(r_um):
    """eta = 2 + 1i: nothing crosses the sphere, external reflection and diffraction alone — and F34/F11
    reaches 0.5 (Fresnel phases of an absorber). Measured |d(F34/F11)| <= 0.163 (10..170 deg, 5-degree
    windows); an F34 of the wrong sign would be off by up to 1."""
    c, mie = _window_ratios(r_um, 2.0 + 1.0j, "mie")
    _, goa = _window_ratios(r_um, 2.0 + 1.0j, "goa")
    s = (c > 10) & (c < 170)
    assert np.abs(mie[s, 2]).max() > 0.4
    assert np.abs(goa[s] - mie[s]).max(axis=0)[2] < 0.2


# --- (e) properties over the whole parameter range -------------------------------------------------


@example(x=1e-3, n=0.7, kappa=0.0, method="auto")
@example(x=1e3, n=2.5, kappa=1.0, method="auto")
@example(x=300.0, n=1.33, kappa=0.0, method="goa")
@example(x=1.0, n=1.0, kappa=0.0, method="mie")
@given(x=log_uniform(1e-3, 1e3), n=st.floats(0.7, 2.5), kappa=st.one_of(st.just(0.0), log_uniform(1e-6, 1.0)),
       method=st.sampled_from(["auto", "mie", "goa"]))
@hsettings(80)
def test_elements_are_a_pure_sphere_matrix(x, n, kappa, method):
    """Finite everywhere (theta = 0 and pi included), F11 >= 0, |F12|, |F33|, |F34| <= F11, and
    F12^2 + F33^2 + F34^2 <= F11^2 — an equality for one sphere (a pure Mueller matrix), so both sides
    are checked to 1e-9 of F11^2."""
    theta = np.concatenate([[0.0, 1e-9], np.linspace(0.0, math.pi, 257), [math.pi - 1e-9, math.pi]])
    for normalize in (True, False):
        m = motes.mueller_matrix(radius(x), LAM, complex(n, kappa), theta, method, normalize=normalize)
        assert np.all(np.isfinite(m))
        f11 = m[:, 0]
        assert np.all(f11 >= 0)
        assert np.all(np.abs(m[:, 1:]) <= f11[:, None] * (1 + 1e-9))
        pol = (m[:, 1:] ** 2).sum(axis=1)
        assert np.all(np.abs(pol - f11**2) <= 1e-9 * f11**2 + 1e-300)


# --- (f) ensembles ---------------------------------------------------------------------------------


def _bulk(psd, eta=1.33 + 0j, lam=(LAM,), **kw):
    return motes.bulk_properties(motes.Species(psd, eta), 1e6, list(lam), cache=False, **kw)


@pytest.mark.parametrize("r_um,method", [(2.0, "mie"), (0.05, "auto"), (150.0, "auto"), (60.0, "goa")])
def test_monodisperse_ensemble_is_the_single_particle(r_um, method):
    """One radius: the ensemble ratios are the particle's (``mueller_matrix``) at every tabulated angle
    where F11 is not near a zero (> 1e-6 of its max). r = 2 um under Mie goes through the
    coefficient-space sums, r = 150 um (GOA) and 60 um under "goa" through the amplitudes."""
    b = _bulk(motes.Monodisperse(r_um), method=method, mueller=True)
    theta = b["theta"]
    single = motes.mueller_matrix(r_um, LAM, 1.33, theta, method)
    keep = single[:, 0] > 1e-6 * single[:, 0].max()
    assert b["mueller"].shape == (1, 3, theta.size)
    np.testing.assert_allclose(b["mueller"][0].T[keep], ratios(single)[keep], rtol=0, atol=1e-6)


@pytest.mark.parametrize("radii,method", [([0.3, 1.1, 2.9, 4.4, 8.0], "auto"), ([30.0, 49.0, 54.0, 70.0, 90.0], "mie")])
def test_polydisperse_sums_equal_direct_sums(radii, method):
    """A ``Radii`` cloud (equal-weight atoms, the quadrature exactly): the core's ratios equal numpy's
    sums of single-particle raw elements (``normalize=False``, from the amplitudes) over the radii. In the
    first cloud every node is summed in coefficient space; in the second (x = 343..1028 under Mie) the
    nodes up to x = 600 are and the others are not, so both paths and their sum are checked."""
    b = _bulk(motes.Radii(radii), method=method, mueller=True)
    theta = b["theta"]
    raw = motes.mueller_matrix(np.asarray(radii)[:, None], LAM, 1.33, theta, method, normalize=False).sum(axis=0)
    keep = raw[:, 0] > 1e-6 * raw[:, 0].max()
    np.testing.assert_allclose(b["mueller"][0].T[keep], ratios(raw)[keep], rtol=0, atol=1e-9)
    # A polydisperse cloud's matrix is no longer pure: the ratios say so somewhere.
    r = b["mueller"][0]
    assert ((r**2).sum(axis=0)[keep] < 0.99).any()


def test_ratios_are_bounded_finite_and_untouched_by_truncation():
    psd = motes.LogNormal(20.0, 1.6)
    lam = motes.RGB_WAVELENGTHS_UM
    plain = _bulk(psd, 1.31 + 1e-8j, lam, mueller=True)
    cut = _bulk(psd, 1.31 + 1e-8j, lam, mueller=True, truncate_below_rad=0.03)
    for b in (plain, cut):
        r = b["mueller"]
        assert r.shape == (len(lam), 3, b["theta"].size) and b["phase"].shape == (len(lam), b["theta"].size)
        assert np.all(np.isfinite(r)) and np.all(np.abs(r) <= 1.0)
    np.testing.assert_array_equal(plain["theta"], cut["theta"])
    assert not np.array_equal(plain["phase"], cut["phase"])  # the truncation did clip F11 ...
    np.testing.assert_array_equal(plain["mueller"], cut["mueller"])  # ... and only F11
    # Forward: unpolarising (r33 -> 1); backward: r33 -> -1 (S2 = -S1 at pi for every sphere).
    assert np.all(plain["mueller"][:, 1, 0] > 0.999) and np.all(plain["mueller"][:, 1, -1] < -0.999)


def test_mueller_leaves_everything_else_bitwise_equal():
    psd = motes.LogNormal(3.0, 1.5)
    for kw in (dict(), dict(truncate_below_rad=0.02), dict(theta=np.linspace(0, np.pi, 50))):
        off = _bulk(psd, lam=(0.45, 0.6), **kw)
        on = _bulk(psd, lam=(0.45, 0.6), mueller=True, **kw)
        assert "mueller" not in off and set(on) == set(off) | {"mueller"}
        for k in off:
            np.testing.assert_array_equal(on[k], off[k], err_msg=k)


def test_query_angles_give_the_tables_ratios():
    """At angles asked for (``theta=``), the ratios are evaluated exactly there: the table's own values."""
    psd = motes.LogNormal(5.0, 1.4)
    table = _bulk(psd, mueller=True)
    q = table["theta"][::37]
    at = _bulk(psd, theta=q, mueller=True)
    np.testing.assert_allclose(at["mueller"], table["mueller"][:, :, ::37], rtol=0, atol=1e-12)


def test_refined_grids_and_the_cache():
    """Refined grids that differ between wavelengths: the ratios are evaluated on their union (aligned
    with ``phase``). The disk cache keys on ``mueller``: a cached result without it is not served."""
    species = motes.Species(motes.Monodisperse(3.0), 1.33)
    kw = dict(refine_tol=0.01, refine_max_nodes=6000)
    off = motes.bulk_properties(species, 1e6, [0.45, 0.65], **kw)
    on = motes.bulk_properties(species, 1e6, [0.45, 0.65], mueller=True, **kw)
    again = motes.bulk_properties(species, 1e6, [0.45, 0.65], mueller=True, **kw)
    assert "mueller" not in off
    assert on["mueller"].shape == (2, 3, on["theta"].size)
    own = motes.bulk_properties(species, 1e6, [0.45], cache=False, **kw)["theta"]
    assert own.size < on["theta"].size  # the union holds angles that 0.45 um did not refine
    np.testing.assert_array_equal(again["mueller"], on["mueller"])
    single = [motes.bulk_properties(species, 1e6, [lam], theta=on["theta"], mueller=True, cache=False)["mueller"][0] for lam in (0.45, 0.65)]
    np.testing.assert_allclose(on["mueller"], np.stack(single), rtol=0, atol=1e-12)


def test_no_scattering_gives_identity_ratios():
    b = _bulk(motes.LogNormal(2.0, 1.5), mueller=True)
    empty = motes.bulk_properties(motes.Species(motes.LogNormal(2.0, 1.5), 1.33), 0.0, [LAM], cache=False, mueller=True)
    assert b["mueller"].shape == empty["mueller"].shape
    np.testing.assert_array_equal(empty["mueller"][0].T, np.tile([0.0, 1.0, 0.0], (empty["theta"].size, 1)))


def test_mueller_needs_the_phase_function():
    with pytest.raises(ValueError, match="mueller"):
        _bulk(motes.LogNormal(2.0, 1.5), phase=False, mueller=True)
    with pytest.raises(ValueError, match="mueller"):
        _bulk(motes.LogNormal(2.0, 1.5), mueller="yes")
