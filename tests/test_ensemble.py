"""Bulk properties of particle clouds (issue 3, Eq. 16-17): the monodisperse limit, Monte Carlo over
sampled radii, ripple resolution against brute force, phase-function normalisation and energy, errors."""

from __future__ import annotations

import os
import pathlib
import re

# The miepython reference of test_default_table_against_fine_mie_reference (conftest.lognormal_mie_phase: ~1.3e4
# radii, two miepython calls each) in miepython's numba backend, the same algorithm as its pure-Python default
# and ~100x faster per call (the two agree to 1.3e-11 relative; see test_mie.py). Set before miepython is first
# imported (conftest imports it lazily); a value already in the environment is kept.
os.environ.setdefault("MIEPYTHON_USE_JIT", "1")

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

import motes
from conftest import hsettings, lognormal_mie_phase, log_uniform

N0 = 1e4  # particles per m^3


def test_monodisperse_limit_is_exact():
    """A monodisperse cloud has sigma = N0 * C of the single particle, to the last bit for sigma_t."""
    for r, eta in ((10.0, 1.33 + 1e-3j), (300.0, 1.31)):
        b = motes.bulk_properties(motes.Species(motes.Monodisperse(r), eta), N0, 0.55, phase=False)
        cs = motes.cross_sections(r, 0.55, eta, asymmetry=False)
        assert b["sigma_t"][0] == N0 * float(cs["ext"]) * 1e-12
        assert b["sigma_a"][0] == pytest.approx(N0 * float(cs["abs"]) * 1e-12, rel=1e-12, abs=1e-30)
        assert b["sigma_s"][0] == pytest.approx(N0 * float(cs["sca"]) * 1e-12, rel=1e-12)


@pytest.mark.parametrize(
    ("psd", "eta", "draws"),
    # The narrow PSD of large absorbing grains (x ~ 570: Mie is the suite's slowest loop) with 2.5e5 draws: its
    # C_t varies by ~40 % across it, so the mean's standard error is ~8e-4 of it, well inside 0.5 %.
    [(motes.LogNormal(800.0, 4.0), 1.31, 1_000_000), (motes.LogNormal(5.0, 2.0), 1.33, 1_000_000),
     (motes.LogNormal(50.0, 1.2), 1.5 + 0.001j, 250_000)],
)
def test_quadrature_matches_monte_carlo(psd, eta, draws):
    """sigma_t and sigma_s by the quadrature agree within 0.5 % with the average over 1e6 radii (2.5e5 for the
    narrow PSD) drawn from the same PSD (and within 4 standard errors of it)."""
    b = motes.bulk_properties(motes.Species(psd, eta), N0, 0.55, phase=False)
    r = psd.sample(draws, seed=9)
    cs = motes.cross_sections(r, 0.55, eta, asymmetry=False)
    for key, col in (("sigma_t", "ext"), ("sigma_s", "sca")):
        mc = N0 * cs[col] * 1e-12
        mean, se = mc.mean(), mc.std() / np.sqrt(mc.size)
        assert abs(b[key][0] / mean - 1) < 5e-3, (key, b[key][0], mean)
        assert abs(b[key][0] - mean) < 4 * se + 1e-12 * mean, (key, b[key][0], mean, se)


@pytest.mark.parametrize(("sigma_g", "tol_default", "tol_fine"), [(1.1, 1e-3, 3e-4), (1.05, 2e-3, 5e-4)])
def test_ripple_is_resolved(sigma_g, tol_default, tol_fine):
    """A narrow PSD in the ripple regime (r ~ 3 um, C_t varies by > 5 % across it): the default quadrature
    agrees with brute force (panels 100x finer in ln r) within 0.1-0.2 %, a 5x finer one within 0.03-0.05 %.
    What remains is Mie's narrow high-Q resonances, which only brute force samples."""
    species = motes.Species(motes.LogNormal(3.0, sigma_g), 1.33)
    # mie_dx=0: the panels in ln r alone (the default also puts a grid uniform in x under them, issue 9.3).
    sigma = lambda step: motes.bulk_properties(species, N0, 0.6, phase=False, max_log_step=step, mie_dx=0.0)["sigma_t"][0]  # noqa: E731
    fine = sigma(5e-4)
    assert abs(sigma(0.05) / fine - 1) < tol_default
    assert abs(sigma(0.01) / fine - 1) < tol_fine
    r = np.linspace(2.5, 3.5, 200)
    ct = motes.cross_sections(r, 0.6, 1.33, asymmetry=False)["ext"] / (np.pi * r**2)
    assert ct.max() / ct.min() > 1.05


@pytest.mark.parametrize(
    "psd",
    [motes.Monodisperse(r) for r in (0.5, 2.0, 10.0, 100.0, 1000.0)]
    + [motes.LogNormal(20.0, s) for s in (1.2, 2.0, 4.0)],
)
def test_phase_function_normalised_and_energy_conserving(psd):
    """The ensemble phase function integrates to 1 within 1e-3 (independent trapezoid in numpy); with
    Mie (exact C_sca) the angle grid integrates |S|^2 to C_sca within 3e-3 (energy_ratio), so the graded
    grid resolves the forward peak; GOA keeps > 98 % of the energy (p <= 3)."""
    b = motes.bulk_properties(motes.Species(psd, 1.33), N0, 0.6)
    th, f = b["theta"], b["phase"][0]
    assert abs(np.trapezoid(f * 2 * np.pi * np.sin(th), th) - 1) < 1e-3
    assert np.all(f >= 0) and np.all(np.isfinite(f))
    mie = motes.bulk_properties(motes.Species(psd, 1.33), N0, 0.6, method="mie") if psd.support()[1] <= 200 else None
    if mie is not None:
        assert abs(mie["energy_ratio"][0] - 1) < 3e-3
    assert 0.98 < b["energy_ratio"][0] < 1.02


def test_species_shares_and_per_wavelength_index():
    """Two species mix by number share; eta may be given per wavelength."""
    a = motes.Species(motes.LogNormal(10.0, 1.5), [1.33, 1.32], share=3.0)
    b = motes.Species(motes.Monodisperse(100.0), 1.5 + 0.01j, share=1.0)
    lam = [0.45, 0.65]
    both = motes.bulk_properties([a, b], 4 * N0, lam, phase=False)
    only_a = motes.bulk_properties(a, 3 * N0, lam, phase=False)
    only_b = motes.bulk_properties(b, N0, lam, phase=False)
    np.testing.assert_allclose(both["sigma_t"], only_a["sigma_t"] + only_b["sigma_t"], rtol=1e-12)
    np.testing.assert_allclose(both["sigma_a"], only_a["sigma_a"] + only_b["sigma_a"], rtol=1e-12)
    assert both["albedo"].shape == (2,) and np.all((0 < both["albedo"]) & (both["albedo"] < 1))


@given(median=log_uniform(0.05, 2000.0), sigma=st.floats(1.0, 10.0))
@example(median=0.05, sigma=1.0)
@example(median=2000.0, sigma=10.0)
@example(median=2000.0, sigma=1.0)
@hsettings(25)
def test_no_nan_over_psd_range(median, sigma):
    """sigma_g in [1, 10], r_g in [0.05, 2000] um: finite, ordered coefficients and a finite g."""
    b = motes.bulk_properties(motes.Species(motes.LogNormal(median, sigma), 1.31 + 1e-6j), N0, 0.55)
    for key in ("sigma_t", "sigma_s", "sigma_a", "g", "albedo"):
        assert np.all(np.isfinite(b[key])), key
    assert b["sigma_t"][0] >= b["sigma_s"][0] >= 0 and b["sigma_a"][0] >= 0
    assert -1 <= b["g"][0] <= 1


def test_errors_name_the_argument():
    sp = motes.Species(motes.Monodisperse(1.0), 1.33)
    with pytest.raises(ValueError, match="species"):
        motes.bulk_properties([], N0, 0.5)
    with pytest.raises(ValueError, match="number_density_m3"):
        motes.bulk_properties(sp, -1.0, 0.5)
    with pytest.raises(ValueError, match="wavelength_um"):
        motes.bulk_properties(sp, N0, [0.5, -0.6])
    with pytest.raises(ValueError, match="eta"):
        motes.bulk_properties(motes.Species(motes.Monodisperse(1.0), [1.3, 1.31, 1.32]), N0, [0.5, 0.6])
    with pytest.raises(ValueError, match="eta"):
        motes.bulk_properties(motes.Species(motes.Monodisperse(1.0), 1.3 - 0.1j), N0, 0.5)
    with pytest.raises(ValueError, match="psd"):
        motes.Species("not a psd", 1.33)
    with pytest.raises(ValueError, match="theta"):
        motes.bulk_properties(sp, N0, 0.5, theta=[0.0, 0.2, 0.1])


@pytest.mark.parametrize(("eta", "median", "sigma_g"), [(1.33, 1.0, 1.2), (1.33, 3.0, 1.2), (1.31, 2.0, 1.2)])
def test_default_table_against_fine_mie_reference(eta, median, sigma_g):
    """Issue 9.3: the default table (no refine_tol, default method) is within 1 % of an independent
    reference at every angle, 0 and pi included: miepython amplitudes integrated over the log-normal on
    a radius grid 0.005 apart in x (conftest.lognormal_mie_phase). Before the fix (Gauss-Legendre panels
    of 0.05 in ln r alias Mie's ripple) water 3/1.2 was 2.6 % off at 90 deg and ice 2/1.2 2.4 % off."""
    theta = np.radians([0.0, 30.0, 90.0, 150.0, 170.0, 179.0, 180.0])
    ref, ref_half = lognormal_mie_phase(eta, 0.55, median, sigma_g, theta)
    assert np.abs(ref_half / ref - 1).max() < 0.01  # the reference resolves the ripple itself
    b = motes.bulk_properties(motes.Species(motes.LogNormal(median, sigma_g), eta), N0, 0.55, cache=False)
    table = motes.PhaseTable.from_bulk(b).eval(theta)
    np.testing.assert_allclose(table, ref, rtol=0.01)
    assert b["theta"][0] == 0.0 and b["theta"][-1] == np.pi


def test_caller_angles_only_choose_where_f_is_reported():
    """Issue 9.2: ``theta=`` does not change the physics. g, the normalisation, energy_ratio and the
    truncation come from the internal grid; f at an angle is the same whichever other angles are asked
    for (8 angles, 50 uniform, the internal grid's own nodes), and g is Mie's for a monodisperse cloud
    (water, r = 1.7 um, lambda = 0.55 um; miepython's g is normalisation free). Before the fix, 8 angles
    gave g = 0.73 and 50 uniform angles f(10 deg) ~4x too high."""
    import miepython

    sp = motes.Species(motes.Monodisperse(1.7), 1.33)
    run = lambda **kw: motes.bulk_properties(sp, N0, 0.55, cache=False, **kw)  # noqa: E731
    table = run()
    eight = np.radians([0.0, 10.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0])
    uniform = np.linspace(0.0, np.pi, 50)
    nodes = table["theta"][::97]
    both = np.union1d(np.union1d(eight, uniform), nodes)
    together = run(theta=both)
    g_mie = miepython.efficiencies_mx(1.33, 2 * np.pi * 1.7 / 0.55)[3]
    assert table["g"][0] == pytest.approx(g_mie, abs=1e-4)
    for angles in (eight, uniform, nodes):
        b = run(theta=angles)
        np.testing.assert_array_equal(b["theta"], angles)
        for key in ("g", "sigma_t", "sigma_s", "energy_ratio"):
            assert b[key][0] == pytest.approx(table[key][0], rel=1e-6, abs=1e-12), key
        f_together = together["phase"][0][np.searchsorted(both, angles)]
        np.testing.assert_allclose(b["phase"][0], f_together, rtol=1e-6)
    np.testing.assert_allclose(run(theta=nodes)["phase"][0], table["phase"][0][::97], rtol=1e-6)
    # Exact values, not interpolation: the single-particle phase function (exact Mie normalisation).
    np.testing.assert_allclose(run(theta=eight)["phase"][0], motes.phase_function(1.7, 0.55, 1.33, eight), rtol=1e-3)


def test_caller_angles_with_truncation_and_refinement():
    """With truncation and refinement the values at the caller's angles are those of the internal table at
    its nodes (clipped at f(theta_c), divided by the kept fraction), with the same g and F."""
    sp = motes.Species(motes.LogNormal(100.0, 1.5), 1.31)
    for kw in (dict(truncate_below_rad=0.01), dict(refine_tol=0.01), dict(truncate_below_rad=0.003, refine_tol=0.01)):
        table = motes.bulk_properties(sp, N0, 0.55, cache=False, **kw)
        idx = np.arange(0, table["theta"].size, 53)
        b = motes.bulk_properties(sp, N0, 0.55, cache=False, theta=table["theta"][idx], **kw)
        np.testing.assert_allclose(b["phase"][0], table["phase"][0][idx], rtol=1e-9)
        for key in ("g", "sigma_t", "sigma_s", "peak_fraction"):
            assert b[key][0] == pytest.approx(table[key][0], rel=1e-12), key


def test_forward_peak_truncation():
    """Truncation removes exactly the clipped fraction F from sigma_s and sigma_t, keeps sigma_a, keeps the
    phase function normalised, lowers g, and grows monotonically with the cone angle; theta_c = 0 is the
    identity. It needs the phase function."""
    sp = motes.Species(motes.LogNormal(800.0, 4.0), 1.31 + 1e-5j)
    full = motes.bulk_properties(sp, N0, 0.55)
    prev = 0.0
    for theta_c in (0.0, 1e-4, 1e-3, 1e-2):
        t = motes.bulk_properties(sp, N0, 0.55, truncate_below_rad=theta_c)
        f = t["peak_fraction"][0]
        assert f >= prev
        prev = f
        assert t["sigma_a"][0] == full["sigma_a"][0]
        assert t["sigma_s"][0] == pytest.approx(full["sigma_s"][0] * (1 - f), rel=1e-12)
        assert t["sigma_t"][0] == pytest.approx(full["sigma_t"][0] - full["sigma_s"][0] * f, rel=1e-12)
        th = t["theta"]
        assert abs(np.trapezoid(t["phase"][0] * 2 * np.pi * np.sin(th), th) - 1) < 1e-3
        if theta_c == 0.0:
            assert f == 0.0
        else:
            assert t["g"][0] < full["g"][0]
    assert 0.3 < prev < 0.7  # large grains: about half of the scattering is diffraction
    with pytest.raises(ValueError, match="phase"):
        motes.bulk_properties(sp, N0, 0.55, phase=False, truncate_below_rad=1e-3)
    with pytest.raises(ValueError, match="truncate_below_rad"):
        motes.bulk_properties(sp, N0, 0.55, truncate_below_rad=-1.0)
    assert motes.pixel_footprint_rad(40.0, 800) == pytest.approx(np.radians(40) / 800)


def test_materials_and_spectral_table():
    """Tabulated ice and water indices (Warren & Brandt 2008, Hale & Querry 1973) reproduce their samples,
    ice absorbs more in the red than the blue, and a SpectralTable returns its nodes exactly, interpolates
    in between (bounded by its neighbours for sigma_t) and refuses wavelengths outside its range."""
    ice, water = motes.Material("ice"), motes.Material("water")
    assert ice.index(0.55)[0] == pytest.approx(1.3110 + 2.289e-9j, rel=1e-12)
    assert water.index([0.4])[0] == pytest.approx(1.339 + 1.86e-9j, rel=1e-12)
    assert ice.index(0.75)[0].imag > 10 * ice.index(0.45)[0].imag
    with pytest.raises(ValueError, match="wavelength_um"):
        ice.index(0.3)
    with pytest.raises(ValueError, match="material"):
        motes.Material("glass")
    sp = motes.Species(motes.LogNormal(20.0, 2.0), ice)
    table = motes.SpectralTable(sp, N0, [0.4, 0.5, 0.6, 0.7], phase=False)
    nodes = table.at([0.4, 0.6])
    np.testing.assert_array_equal(nodes["sigma_t"], table.bulk["sigma_t"][[0, 2]])
    mid = table.at(0.55)["sigma_t"][0]
    lo, hi = sorted(table.bulk["sigma_t"][1:3])
    assert lo <= mid <= hi
    with pytest.raises(ValueError, match="range"):
        table.at(0.8)


def test_disk_cache(tmp_path, monkeypatch):
    """A second identical call is served from disk with identical arrays; any changed parameter misses;
    a damaged cache file is rebuilt, not an error; cache=False and MOTES_CACHE_DIR="" bypass it."""
    monkeypatch.setenv("MOTES_CACHE_DIR", str(tmp_path))
    sp = motes.Species(motes.LogNormal(30.0, 2.0), 1.31)
    a = motes.bulk_properties(sp, N0, [0.5, 0.6])
    files = list(tmp_path.glob("bulk-*.npz"))
    assert len(files) == 1
    b = motes.bulk_properties(sp, N0, [0.5, 0.6])
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    motes.bulk_properties(sp, N0, [0.5, 0.61])
    motes.bulk_properties(motes.Species(motes.LogNormal(30.0, 2.0), 1.32), N0, [0.5, 0.6])
    motes.bulk_properties(sp, N0, [0.5, 0.6], truncate_below_rad=1e-3)
    assert len(list(tmp_path.glob("bulk-*.npz"))) == 4
    files[0].write_bytes(b"not an npz")
    c = motes.bulk_properties(sp, N0, [0.5, 0.6])
    np.testing.assert_array_equal(a["sigma_t"], c["sigma_t"])
    monkeypatch.setenv("MOTES_CACHE_DIR", "")
    assert motes.ensemble.cache_dir() is None
    motes.bulk_properties(sp, N0, [0.45])
    assert len(list(tmp_path.glob("bulk-*.npz"))) == 4


def _source_hash() -> str:
    """FNV-1a 64 of the Rust sources as rust/motes-py/build.rs computes it (paths relative to rust/)."""
    rust = pathlib.Path(__file__).resolve().parents[1] / "rust"
    files = sorted((p.relative_to(rust).as_posix(), p) for d in ("motes-core/src", "motes-py/src") for p in (rust / d).rglob("*") if p.is_file())
    h = 0xCBF29CE484222325
    for rel, path in files:
        content = path.read_bytes()
        for b in rel.encode() + b"\0" + len(content).to_bytes(8, "little") + content:
            h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def test_cache_is_keyed_by_the_core_sources(tmp_path, monkeypatch):
    """Issue 9.5: the disk cache is keyed by a hash of the Rust sources embedded at build time, so a table
    computed by other code is never served. The hash is that of the sources in this tree (fails if the
    build script stops hashing them, or if the extension is stale: rebuild), and an entry written under
    one hash is served under it but not under another."""
    assert re.fullmatch(r"[0-9a-f]{16}", motes.CORE_HASH)
    assert motes.CORE_HASH == motes._motes.core_hash() == _source_hash(), "extension built from other sources: rebuild"
    monkeypatch.setenv("MOTES_CACHE_DIR", str(tmp_path))
    sp = motes.Species(motes.LogNormal(5.0, 1.5), 1.33)
    a = motes.bulk_properties(sp, N0, 0.5, phase=False)["sigma_t"][0]
    (entry,) = tmp_path.glob("bulk-*.npz")
    with np.load(entry) as z:
        doctored = {k: z[k] for k in z.files}
    doctored["sigma_t"] = 2 * doctored["sigma_t"]
    np.savez(entry, **doctored)
    assert motes.bulk_properties(sp, N0, 0.5, phase=False)["sigma_t"][0] == 2 * a  # served from the entry
    monkeypatch.setattr(motes.ensemble, "CORE_HASH", "0123456789abcdef")
    assert motes.bulk_properties(sp, N0, 0.5, phase=False)["sigma_t"][0] == a  # other code: recomputed
    assert len(list(tmp_path.glob("bulk-*.npz"))) == 2


def test_one_home_for_the_default_wavelengths():
    """Issue 9.6: the default RGB and spectral wavelengths come from the Rust core, and every default
    uses them: SpectralTable's default is SPECTRAL_WAVELENGTHS_UM (it was 0.36-0.83 um), as is
    homogeneous_equivalent's spectral default; the values are the documented ones."""
    assert motes.RGB_WAVELENGTHS_UM == (0.630, 0.532, 0.467)
    assert motes.SPECTRAL_WAVELENGTHS_UM == tuple(np.linspace(0.38, 0.78, 8))
    assert motes.RGB_WAVELENGTHS_UM == tuple(motes._motes.default_wavelengths()[0])
    assert motes.equivalent.SPECTRAL_WAVELENGTHS_UM is motes.ensemble.SPECTRAL_WAVELENGTHS_UM
    sp = motes.Species(motes.LogNormal(5.0, 1.5), motes.Material("water"))
    table = motes.SpectralTable(sp, N0, phase=False)
    np.testing.assert_array_equal(table.wavelength_um, motes.SPECTRAL_WAVELENGTHS_UM)
    medium = motes.homogeneous_equivalent(sp, N0, color="spectral", tabphase_size=64)
    nm = [w for w, _ in medium["sigma_t"]["value"]]
    np.testing.assert_allclose(nm, np.array(motes.SPECTRAL_WAVELENGTHS_UM) * 1e3, rtol=1e-15)


def test_explicit_radius_lists():
    """Bulk properties from an explicit list of radii equal the sum over those particles (the monodisperse
    values averaged); empty and one-particle lists raise errors saying what to do."""
    radii = [5.0, 20.0, 20.0, 80.0]
    b = motes.bulk_properties(motes.Species(motes.Radii(radii), 1.33), N0, 0.55, phase=False)
    cs = motes.cross_sections(np.array(radii), 0.55, 1.33, asymmetry=False)
    assert b["sigma_t"][0] == pytest.approx(N0 * cs["ext"].mean() * 1e-12, rel=1e-12)
    assert motes.Radii(radii).atoms() == [(5.0, 0.25), (20.0, 0.5), (80.0, 0.25)]
    assert set(motes.Radii(radii).sample(1000, seed=1)) == {5.0, 20.0, 80.0}
    with pytest.raises(ValueError, match="radii_um.*>= 2"):
        motes.Radii([])
    with pytest.raises(ValueError, match="Monodisperse"):
        motes.Radii([10.0])
    with pytest.raises(ValueError, match="radii_um"):
        motes.Radii([10.0, -1.0])


def test_goa_cache_is_shared_and_changes_nothing():
    """A caller-owned GoaCache (what a discrete medium's size bins share) gives bit-identical bulk
    properties and holds one entry per relative index used (no process-wide state)."""
    from motes import _motes

    sp = motes.Species(motes.Uniform(300.0, 600.0), complex(1.31, 1e-5))
    lam = [0.45, 0.65]
    cache = _motes.GoaCache()
    assert len(cache) == 0
    shared = [motes.bulk_properties(sp, 1e6, lam, cache=False, goa_cache=cache) for _ in range(2)]
    alone = motes.bulk_properties(sp, 1e6, lam, cache=False)
    assert len(cache) == 1  # one index (constant eta) at both wavelengths, reused by the second call
    for key in ("sigma_t", "sigma_s", "g", "phase", "peak_fraction"):
        np.testing.assert_array_equal(shared[0][key], alone[key])
        np.testing.assert_array_equal(shared[1][key], alone[key])
