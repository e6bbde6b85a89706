"""The Python API: broadcasting, index forms, the host medium, input validation and method policies."""

from __future__ import annotations

import math

import numpy as np
import pytest

import motes

LAM = 0.6
THETA5 = np.linspace(0.0, math.pi, 5)


# --- broadcasting -------------------------------------------------------------------------------------


@pytest.mark.parametrize("func", ["mie_amplitudes", "goa_amplitudes", "phase_function"])
def test_broadcast_radius_column_against_theta_row(func):
    """r of shape (3, 1) with theta of shape (5,) gives (3, 5) arrays, and element [i, j] equals the
    scalar call with r[i], theta[j] (bit for bit: the batch groups equal particles, nothing else)."""
    r = np.array([[0.5], [3.0], [20.0]])
    out = getattr(motes, func)(r, LAM, 1.33, THETA5)
    outs = out if isinstance(out, tuple) else (out,)
    for o in outs:
        assert o.shape == (3, 5)
    for i in range(3):
        for j in range(5):
            single = getattr(motes, func)(float(r[i, 0]), LAM, 1.33, THETA5[j])
            singles = single if isinstance(single, tuple) else (single,)
            for o, s in zip(outs, singles):
                assert np.shape(s) == ()
                assert o[i, j] == s


def test_broadcast_cross_sections_grid():
    """cross_sections over r (3, 1) x lambda (4,) returns four (3, 4) arrays equal to the scalar calls."""
    r = np.array([[0.2], [2.0], [15.0]])
    lam = np.array([0.4, 0.5, 0.6, 0.7])
    cs = motes.cross_sections(r, lam, 1.5 + 0.01j)
    assert set(cs) == {"ext", "sca", "abs", "g"}
    for key in cs:
        assert cs[key].shape == (3, 4)
    for i in range(3):
        for j in range(4):
            single = motes.cross_sections(float(r[i, 0]), float(lam[j]), 1.5 + 0.01j)
            for key in cs:
                assert cs[key][i, j] == single[key]


def test_scalar_inputs_give_zero_dim_arrays():
    """All-scalar inputs give 0-d arrays (shape ()), not length-1 vectors."""
    s1, s2 = motes.mie_amplitudes(1.0, LAM, 1.33, 0.3)
    assert s1.shape == () and s2.shape == ()
    assert motes.phase_function(1.0, LAM, 1.33, 0.3).shape == ()
    assert all(v.shape == () for v in motes.cross_sections(1.0, LAM, 1.33).values())


def test_repeated_particles_in_a_batch():
    """A batch with repeated (and unsorted) particles gives each element the value of its own scalar
    call: the de-duplication inside does not mix particles up."""
    r = np.array([5.0, 1.0, 5.0, 80.0, 1.0, 80.0, 5.0])
    eta = np.array([1.33, 1.33, 1.5 + 0.1j, 1.33, 1.33, 0.75, 1.33])
    cs = motes.cross_sections(r, LAM, eta)
    f = motes.phase_function(r, LAM, eta, 0.2)
    for k in range(r.size):
        single = motes.cross_sections(r[k], LAM, eta[k])
        assert cs["ext"][k] == single["ext"] and cs["g"][k] == single["g"]
        assert f[k] == motes.phase_function(r[k], LAM, eta[k], 0.2)


def test_empty_input():
    """Empty arrays give empty results (not an error, not a crash)."""
    cs = motes.cross_sections(np.array([]), LAM, 1.33)
    assert all(v.shape == (0,) for v in cs.values())
    assert motes.phase_function(1.0, LAM, 1.33, np.array([])).shape == (0,)


# --- refractive index forms ---------------------------------------------------------------------------


def test_eta_float_equals_complex_with_zero_imaginary_part():
    """A float eta is the complex n + 0i, and an int works too."""
    a = motes.cross_sections(3.0, LAM, 2)
    b = motes.cross_sections(3.0, LAM, 2.0 + 0j)
    c = motes.cross_sections(3.0, LAM, 2.0)
    for key in a:
        assert a[key] == b[key] == c[key]


def test_eta_per_wavelength():
    """A per-wavelength index array broadcasts element-wise against the wavelength array, and each entry
    equals the scalar call with that (lambda, eta) pair."""
    lam = np.array([0.4, 0.55, 0.7])
    eta = np.array([1.34 + 1e-9j, 1.333 + 2e-9j, 1.331 + 3e-8j])
    for method in ("mie", "goa"):
        cs = motes.cross_sections(50.0, lam, eta, method=method)
        f = motes.phase_function(50.0, lam, eta, 0.1, method=method)
        for k in range(3):
            single = motes.cross_sections(50.0, lam[k], eta[k], method=method)
            assert cs["ext"][k] == single["ext"] and cs["abs"][k] == single["abs"]
            assert f[k] == motes.phase_function(50.0, lam[k], eta[k], 0.1, method=method)
        assert np.all(cs["abs"] > 0)


# --- host medium ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["mie", "goa", "auto", "hybrid"])
@pytest.mark.parametrize(
    ("r", "eta", "eta_medium"),
    [(0.37, 1.33, 1.333), (3.3, 1.0, 1.333), (20.1, 1.5 + 0.01j, 1.2), (100.3, 0.9, 1.1), (7.0, 2.0 + 0.5j, 1.6)],
)
def test_eta_medium_is_a_rescaling(method, r, eta, eta_medium):
    """Only the relative index and the wavelength in the host matter:
    C(r, lambda, eta, eta_m) = C(r, lambda/eta_m, eta/eta_m, 1) and the same for f(theta), to 1e-12.
    (E.g. an air bubble in water, eta = 1, eta_m = 1.333, is eta = 1/1.333 at lambda/1.333.)"""
    a = motes.cross_sections(r, LAM, eta, method=method, eta_medium=eta_medium)
    b = motes.cross_sections(r, LAM / eta_medium, eta / eta_medium, method=method)
    for key in a:
        assert float(a[key]) == pytest.approx(float(b[key]), rel=1e-12, abs=1e-300), key
    fa = motes.phase_function(r, LAM, eta, THETA5, method=method, eta_medium=eta_medium)
    fb = motes.phase_function(r, LAM / eta_medium, eta / eta_medium, THETA5, method=method)
    np.testing.assert_allclose(fa, fb, rtol=1e-12)


def test_air_bubble_in_water_differs_from_vacuum():
    """eta_medium is not ignored: an air bubble in water (eta = 1, eta_m = 1.333) scatters, an "air
    sphere" in air (eta = 1, eta_m = 1) does not (Mie C_sca ~ 0), and the bubble's size parameter is
    2 pi eta_m r / lambda."""
    water = motes.cross_sections(10.0, LAM, 1.0, method="mie", eta_medium=1.333)
    air = motes.cross_sections(10.0, LAM, 1.0, method="mie")
    assert float(water["sca"]) > math.pi * 100.0
    assert float(air["sca"]) < 1e-20
    assert motes.size_parameter(10.0, LAM, 1.333) == pytest.approx(2 * math.pi * 1.333 * 10.0 / LAM, rel=1e-15)


# --- invalid input ------------------------------------------------------------------------------------

_GOOD = dict(radius_um=1.0, wavelength_um=LAM, eta=1.33)


def _call(func, **override):
    """Call a public function with valid arguments except those overridden."""
    kw = {**_GOOD, **override}
    args = [kw.pop("radius_um"), kw.pop("wavelength_um"), kw.pop("eta")]
    if func in ("mie_amplitudes", "goa_amplitudes", "phase_function"):
        args.append(kw.pop("theta", 0.5))
    else:
        kw.pop("theta", None)
    return getattr(motes, func)(*args, **kw)


ALL_FUNCS = ["mie_amplitudes", "goa_amplitudes", "phase_function", "cross_sections"]

INVALID = [
    # (override, name that the message must contain)
    (dict(radius_um=0.0), "radius_um"),
    (dict(radius_um=-1.0), "radius_um"),
    (dict(radius_um=np.nan), "radius_um"),
    (dict(radius_um=np.inf), "radius_um"),
    (dict(radius_um=[1.0, -2.0]), "radius_um"),
    (dict(wavelength_um=0.0), "wavelength_um"),
    (dict(wavelength_um=-0.5), "wavelength_um"),
    (dict(wavelength_um=np.inf), "wavelength_um"),
    (dict(wavelength_um=np.nan), "wavelength_um"),
    (dict(eta=1.33 - 0.01j), "eta"),
    (dict(eta=0.0), "eta"),
    (dict(eta=0.0 + 0.1j), "eta"),
    (dict(eta=-1.5), "eta"),
    (dict(eta=np.nan), "eta"),
    (dict(eta=complex(1.5, np.inf)), "eta"),
    (dict(eta="1.33"), "eta"),
    (dict(eta_medium=0.0), "eta_medium"),
    (dict(eta_medium=-1.0), "eta_medium"),
    (dict(eta_medium=np.nan), "eta_medium"),
    (dict(eta_medium=1.0 + 0.1j), "eta_medium"),
    (dict(radius_um=1.0 + 0j), "radius_um"),
    (dict(radius_um=1e5, wavelength_um=0.38), "radius_um"),  # size parameter beyond 1e5
]


@pytest.mark.parametrize("func", ALL_FUNCS)
@pytest.mark.parametrize(("override", "name"), INVALID, ids=[f"{n}={list(o.values())[0]!r}" for o, n in INVALID])
def test_invalid_particle_raises_value_error_naming_argument(func, override, name):
    """Every invalid particle argument raises ValueError (not TypeError, not a crash, not NaN output)
    and the message names the offending argument."""
    with pytest.raises(ValueError, match=name):
        _call(func, **override)


@pytest.mark.parametrize("func", ["mie_amplitudes", "goa_amplitudes", "phase_function"])
@pytest.mark.parametrize("theta", [-0.1, math.pi + 1e-9, 4.0, np.nan, np.inf, -1e-300, [0.1, 3.5]])
def test_invalid_theta(func, theta):
    """theta outside [0, pi] or non-finite raises ValueError naming theta."""
    with pytest.raises(ValueError, match="theta"):
        _call(func, theta=theta)


def test_theta_end_points_are_valid():
    """theta = 0 and theta = pi exactly are inside the domain."""
    for func in ("mie_amplitudes", "goa_amplitudes", "phase_function"):
        out = _call(func, theta=np.array([0.0, math.pi]))
        for o in out if isinstance(out, tuple) else (out,):
            assert np.all(np.isfinite(o))


@pytest.mark.parametrize("func", ["phase_function", "cross_sections"])
@pytest.mark.parametrize("method", ["MIE", "", "exact", None, 3])
def test_unknown_method(func, method):
    """An unknown method raises ValueError naming "method" (case-sensitive; no silent default)."""
    with pytest.raises(ValueError, match="method"):
        _call(func, method=method)


@pytest.mark.parametrize("func", ["goa_amplitudes", "phase_function", "cross_sections", "goa_extinction_efficiency"])
@pytest.mark.parametrize("p_max", [-1, 2.0, 1.5, "3", True, None, 1001, 10**30])
def test_invalid_p_max(func, p_max):
    """p_max negative, non-integer (float, str, bool, None) or beyond 1000 raises ValueError naming p_max."""
    with pytest.raises(ValueError, match="p_max"):
        if func == "goa_extinction_efficiency":
            motes.goa_extinction_efficiency(10.0, 1.33, p_max=p_max)
        else:
            _call(func, p_max=p_max)


def test_valid_p_max_forms():
    """p_max = 0 and numpy integers are accepted; p_max = 0 (reflection only) differs from p_max = 3."""
    s0 = _call("goa_amplitudes", p_max=0, theta=2.0)
    s3 = _call("goa_amplitudes", p_max=np.int64(3), theta=2.0)
    assert np.isfinite(s0[0]) and s0[0] != s3[0]


@pytest.mark.parametrize("hybrid_radius_um", [-1.0, np.nan, np.inf])
def test_invalid_hybrid_radius(hybrid_radius_um):
    """A negative or non-finite hybrid threshold raises ValueError naming hybrid_radius_um."""
    with pytest.raises(ValueError, match="hybrid_radius_um"):
        motes.cross_sections(1.0, LAM, 1.33, method="hybrid", hybrid_radius_um=hybrid_radius_um)


@pytest.mark.parametrize("func", ALL_FUNCS)
def test_arrays_that_do_not_broadcast(func):
    """Arrays that do not broadcast raise ValueError naming the arguments and their shapes."""
    with pytest.raises(ValueError, match=r"broadcast.*radius_um\(3,\).*wavelength_um\(2,\)"):
        _call(func, radius_um=[1.0, 2.0, 3.0], wavelength_um=[0.5, 0.6])
    if func != "cross_sections":
        with pytest.raises(ValueError, match=r"theta\(3,\)"):
            _call(func, radius_um=[1.0, 2.0], theta=[0.1, 0.2, 0.3])


@pytest.mark.parametrize(
    ("alpha", "eta", "name"),
    [(0.0, 1.33, "alpha"), (-1.0, 1.33, "alpha"), (np.nan, 1.33, "alpha"), (10.0, 1.33 - 1j, "eta"), (10.0, 0.0, "eta")],
)
def test_goa_extinction_efficiency_validates(alpha, eta, name):
    """``goa_extinction_efficiency`` rejects a non-positive/NaN size parameter and an invalid index with a
    ValueError naming it, like the rest of the API (it once returned NaN or negative numbers)."""
    try:
        out = motes.goa_extinction_efficiency(alpha, eta)
    except ValueError as exc:
        assert name in str(exc)
    else:
        raise AssertionError(f"goa_extinction_efficiency({alpha!r}, {eta!r}) returned {out!r} instead of raising")


# --- method policies ---------------------------------------------------------------------------------


def _same(a, b):
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_hybrid_policy():
    """method="hybrid" is Mie strictly below hybrid_radius_um (default 2 um = motes.HYBRID_RADIUS_UM) and GOA
    at and above it, for cross sections and phase functions, also with a custom threshold."""
    assert motes.HYBRID_RADIUS_UM == 2.0
    below, at, above = np.array([0.5, 1.999999]), np.array([2.0]), np.array([2.000001, 50.0])
    for eta in (1.33, 0.75 + 0.01j):
        _same(motes.cross_sections(below, LAM, eta, method="hybrid"), motes.cross_sections(below, LAM, eta, method="mie"))
        _same(motes.cross_sections(at, LAM, eta, method="hybrid"), motes.cross_sections(at, LAM, eta, method="goa"))
        _same(motes.cross_sections(above, LAM, eta, method="hybrid"), motes.cross_sections(above, LAM, eta, method="goa"))
        for r, ref in ((1.999999, "mie"), (2.0, "goa"), (50.0, "goa")):
            np.testing.assert_array_equal(
                motes.phase_function(r, LAM, eta, THETA5, method="hybrid"), motes.phase_function(r, LAM, eta, THETA5, method=ref)
            )
    _same(
        motes.cross_sections([4.9, 5.0], LAM, 1.33, method="hybrid", hybrid_radius_um=5.0),
        {k: np.array([motes.cross_sections(4.9, LAM, 1.33, method="mie")[k], motes.cross_sections(5.0, LAM, 1.33, method="goa")[k]]) for k in ("ext", "sca", "abs", "g")},
    )
    # Mie and GOA really differ there, so the equalities above are informative.
    assert motes.cross_sections(1.9, LAM, 1.33, method="mie")["ext"] != motes.cross_sections(1.9, LAM, 1.33, method="goa")["ext"]


def test_auto_policy():
    """method="auto" is Mie below the size parameter motes.AUTO_SIZE_PARAMETER (alpha = 2 pi eta_m r/lambda,
    so the host index counts) and GOA above it."""
    a0 = motes.AUTO_SIZE_PARAMETER
    assert a0 > 0
    for eta_medium in (1.0, 1.333):
        r_edge = a0 * LAM / (2 * math.pi * eta_medium)
        for factor, ref in ((0.5, "mie"), (0.999, "mie"), (1.001, "goa"), (3.0, "goa")):
            r = factor * r_edge
            assert (motes.size_parameter(r, LAM, eta_medium) < a0) == (ref == "mie")
            _same(
                motes.cross_sections(r, LAM, 1.5 + 0.001j, method="auto", eta_medium=eta_medium),
                motes.cross_sections(r, LAM, 1.5 + 0.001j, method=ref, eta_medium=eta_medium),
            )
            np.testing.assert_array_equal(
                motes.phase_function(r, LAM, 1.5, THETA5, method="auto", eta_medium=eta_medium),
                motes.phase_function(r, LAM, 1.5, THETA5, method=ref, eta_medium=eta_medium),
            )


def test_default_method_is_auto():
    """Leaving method out is method="auto"."""
    for r in (1.0, 30.0):
        _same(motes.cross_sections(r, LAM, 1.33), motes.cross_sections(r, LAM, 1.33, method="auto"))


def test_goa_options_change_results():
    """The GOA switches do something: diffraction=False removes the forward peak, edge_correction=False
    lowers C_ext (the edge term is positive for eta > 1), regularise=False
    changes the amplitudes near the rainbow."""
    theta = np.array([0.0, 2.4])
    with_d = motes.goa_amplitudes(30.0, LAM, 1.33, theta)
    no_d = motes.goa_amplitudes(30.0, LAM, 1.33, theta, diffraction=False)
    assert abs(with_d[0][0]) > 10 * abs(no_d[0][0])  # alpha^2/2 ~ 4.9e4 vs the axial rays ~ 6e2
    a = motes.cross_sections(30.0, LAM, 1.33, method="goa")["ext"]
    b = motes.cross_sections(30.0, LAM, 1.33, method="goa", edge_correction=False)["ext"]
    assert a > b
    reg = motes.goa_amplitudes(30.0, LAM, 1.33, np.linspace(2.3, 2.5, 50))
    raw = motes.goa_amplitudes(30.0, LAM, 1.33, np.linspace(2.3, 2.5, 50), regularise=False)
    assert np.any(reg[0] != raw[0])


@pytest.mark.parametrize("eta_medium", [1.0, 1.333])
def test_auto_uses_mie_near_degenerate_axial_rays(eta_medium):
    """method="auto" also picks Mie at any size when an axial ray is degenerate, |2p/Re(m) - 2| <
    motes.AXIAL_CAUSTIC_WINDOW for some p <= max(p_max, 2) with m = eta/eta_medium: the retro-reflecting
    ball lens m = 2 (p = 2) and the invisible sphere m = 1 (p = 1); just outside the window it is GOA."""
    w = motes.AXIAL_CAUSTIC_WINDOW
    assert 0 < w < 0.1
    r = 200.0  # alpha ~ 2e3 >> AUTO_SIZE_PARAMETER
    inside = [2.0, 2.0 / (1 + 0.45 * w), 2.0 / (1 - 0.45 * w), 1.0, 1.0 / (1 + 0.45 * w), 1.0 / (1 - 0.45 * w)]
    outside = [2.0 / (1 + 0.6 * w), 2.0 / (1 - 0.6 * w), 1.0 / (1 + 0.6 * w), 1.0 / (1 - 0.6 * w), 1.5]
    for m_rel, ref in [(m, "mie") for m in inside] + [(m, "goa") for m in outside]:
        eta = m_rel * eta_medium
        assert motes.resolve_method(r, LAM, eta, eta_medium=eta_medium).item() == ref, m_rel
        _same(
            motes.cross_sections(r, LAM, eta, eta_medium=eta_medium),
            motes.cross_sections(r, LAM, eta, method=ref, eta_medium=eta_medium),
        )
    # p = 3 (m = 3) counts only when p_max >= 3.
    assert motes.resolve_method(r, LAM, 3.0, p_max=3).item() == "mie"
    assert motes.resolve_method(r, LAM, 3.0, p_max=2).item() == "goa"


def test_resolve_method_matches_what_methods_do():
    """``resolve_method`` reports, element by element and with broadcasting, the theory each method uses:
    "mie"/"goa" for those methods, the radius rule for "hybrid" and the size/axial rule for "auto"."""
    r = np.array([[0.5], [1.999], [2.0], [30.0]])
    eta = np.array([1.33, 2.0, 0.75 + 0.01j])
    assert motes.resolve_method(r, LAM, eta, method="mie").shape == (4, 3)
    assert np.all(motes.resolve_method(r, LAM, eta, method="mie") == "mie")
    assert np.all(motes.resolve_method(r, LAM, eta, method="goa") == "goa")
    hybrid = motes.resolve_method(r, LAM, eta, method="hybrid")
    assert np.all(hybrid[:2] == "mie") and np.all(hybrid[2:] == "goa")
    auto = motes.resolve_method(r, LAM, eta)
    alpha = motes.size_parameter(r, LAM) * np.ones(eta.shape)
    expected = np.where((alpha < motes.AUTO_SIZE_PARAMETER) | (eta.real == 2.0), "mie", "goa")
    np.testing.assert_array_equal(auto, expected)
    with pytest.raises(ValueError, match="method"):
        motes.resolve_method(1.0, LAM, 1.33, method="fast")
    with pytest.raises(ValueError, match="radius_um"):
        motes.resolve_method(-1.0, LAM, 1.33)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"radius_um": -1.0}, "radius_um"), ({"wavelength_um": 0.0}, "wavelength_um"), ({"eta_medium": np.nan}, "eta_medium")],
)
def test_size_parameter_validates(kwargs, name):
    """size_parameter rejects non-positive or NaN inputs with a ValueError naming the argument."""
    args = {"radius_um": 1.0, "wavelength_um": 0.6, "eta_medium": 1.0, **kwargs}
    with pytest.raises(ValueError, match=name):
        motes.size_parameter(**args)


@pytest.mark.parametrize("flag", ["diffraction", "regularise", "edge_correction"])
def test_goa_flags_must_be_bool(flag):
    """A non-boolean switch (e.g. the string "no", which is truthy) is an error, not silently True."""
    with pytest.raises(ValueError, match=flag):
        motes.goa_amplitudes(10.0, 0.6, 1.33, 0.5, **{flag: "no"})
