"""Polarisation (issue 45): the `discrete` medium in Mitsuba's polarised variants.

Single scattering of an unpolarised beam (a directional light along +x) by a thin cube of grains, seen by an
orthographic camera at scattering angle theta in the plane y = 0 with `up` = y: the image's horizontal axis lies
in the scattering plane, so the Stokes integrator's S1 / S0 is Bohren & Huffman's F12 / F11 there (their Q is
I_parallel - I_perpendicular) — negative for Rayleigh grains, which polarise perpendicular to the plane. Oracles:
the Rayleigh limit -sin^2 / (1 + cos^2), and `motes.mueller_matrix` (tested against miepython in
test_mueller.py) for Mie grains. Multiple scattering: S0 of a polarised render equals the unpolarised variant's
image, and a white furnace stays 1 (Russian roulette off), both within noise.
"""

from __future__ import annotations

import json
import os
import pathlib
import sys
import textwrap

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "scripts" / "figures"))
from furnace_grid import furnace_medium, render_furnace  # noqa: E402
from _scenes import interactions_at_origin, phase_chi2, run_json  # noqa: E402

# Channels of a Stokes render with a luminance film: Y, then S0..S3 as R, G, B each.
S0, S1, S2, S3 = 1, 4, 7, 10
LAM_UM = 0.55


def _grains(radius_um: float, eta: float = 1.5, **extra) -> dict:
    med = {"type": "discrete", "sigma_t": 0.1, "eta": eta, "wavelengths": str(LAM_UM),
           "psd": json.dumps({"type": "monodisperse", "radius_um": radius_um}), "phase": {"type": "particle"}}
    med.update(extra)
    return med


def _single_scattering(medium: dict, theta_deg: float, spp: int = 64, res: int = 8, depth: int = 2,
                       polarizer_deg: float | None = None) -> np.ndarray:
    """The Stokes image (res, res, 13) of `medium` in a unit cube lit along +x, seen at `theta_deg`."""
    t = np.radians(theta_deg)
    eye = 6.0 * np.array([np.cos(t), 0.0, np.sin(t)])
    scene = {
        "type": "scene",
        "integrator": {"type": "stokes", "integrator": {"type": "volpath", "max_depth": depth}},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=[0, 0, 0], up=[0, 1, 0])
                   @ mi.ScalarTransform4f().scale([0.3, 0.3, 1.0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "luminance",
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "light": {"type": "directional", "direction": [1, 0, 0], "irradiance": 1.0},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                 "to_world": mi.ScalarTransform4f().scale(0.5)},
    }
    return np.asarray(mi.render(mi.load_dict(scene), spp=spp), dtype=np.float64)


def _ratio(img: np.ndarray, k: int) -> tuple[float, float]:
    """S_k / S0 over the image, and its standard error (pixels as independent estimates, delta method)."""
    s0, sk = img[..., S0].ravel(), img[..., k].ravel()
    r = sk.mean() / s0.mean()
    resid = sk - r * s0
    return float(r), float(resid.std(ddof=1) / np.sqrt(s0.size) / s0.mean())


@pytest.mark.parametrize("theta_deg", [45.0, 90.0, 135.0])
def test_rayleigh_grains_polarise_as_rayleigh(theta_deg):
    """Grains of x = 0.057 (Rayleigh within 1e-3): S1 / S0 = -sin^2 / (1 + cos^2), fully polarised at 90 deg."""
    motes.set_variant("llvm_ad_mono_polarized")
    img = _single_scattering(_grains(0.005, storage="procedural"), theta_deg)
    c = np.cos(np.radians(theta_deg))
    want = -(1 - c * c) / (1 + c * c)
    got, se = _ratio(img, S1)
    assert img[..., S0].mean() > 0
    # 2e-3: Rayleigh's own error at x = 0.057 and the tables' interpolation (measured: 1e-4 at 45 and 135 deg).
    assert abs(got - want) < 3 * se + 2e-3, f"theta {theta_deg}: S1/S0 {got:.5f} +- {se:.5f}, Rayleigh {want:.5f}"
    u, use = _ratio(img, S2)
    assert abs(u) < 3 * use + 0.01, f"unpolarised light gains no U: {u:.4f} +- {use:.4f}"


@pytest.mark.parametrize("variant", ["llvm_ad_mono_polarized", "scalar_spectral_polarized"])
@pytest.mark.parametrize("theta_deg", [60.0, 110.0])
def test_mie_grains_polarise_as_f12(variant, theta_deg):
    """Glass grains of 0.3 um (x = 3.4: F12 changes sign across the angles) against the single-particle
    F12 / F11 of `motes.mueller_matrix` at the scattering angle (spectral variants render at 0.55 um only
    where the grains' tables hold that one wavelength: every channel sees the same ratios)."""
    motes.set_variant(variant)
    img = _single_scattering(_grains(0.3), theta_deg, spp=32 if variant.startswith("scalar") else 64,
                             res=6 if variant.startswith("scalar") else 8)
    f = motes.mueller_matrix(0.3, LAM_UM, 1.5, np.radians(theta_deg))
    want = float(f[1] / f[0])
    got, se = _ratio(img, S1)
    # 1e-3: the tables' interpolation between angles (measured: 5e-6).
    assert abs(got - want) < 3 * se + 1e-3, f"{variant} theta {theta_deg}: S1/S0 {got:.5f} +- {se:.5f}, F12/F11 {want:.5f}"


def test_native_and_evaluated_paths_agree_polarised():
    """The evaluated-mode Python path (`MOTES_NATIVE=0`) builds the same matrices as the native plugin
    (`_bridge.mueller_spectrum` and `motes_native.cpp` alike)."""
    code = textwrap.dedent("""
        import json, os, sys
        import numpy as np
        import motes
        sys.path.insert(0, os.path.join(os.path.dirname(motes.__file__), "..", "..", "tests"))
        import test_polarisation as t
        motes.set_variant("scalar_spectral_polarized")
        assert ("scalar_spectral_polarized" in motes.native_variants()) == (os.environ["MOTES_NATIVE"] == "1")
        img = t._single_scattering(t._grains(0.3), 70.0, spp=32, res=6)
        print(json.dumps(list(t._ratio(img, t.S1))))
    """)
    (a, sa), (b, sb) = (run_json(code, env=dict(os.environ, MOTES_NATIVE=flag)) for flag in ("1", "0"))
    assert abs(a - b) < 3 * np.hypot(sa, sb) + 1e-3, f"native {a:.4f} +- {sa:.4f}, evaluated {b:.4f} +- {sb:.4f}"
    assert a < -0.05 or a > 0.05, f"a polarising angle: {a:.4f}"


def test_a_users_phase_function_depolarises():
    """`phase = hg` (the grains' extinction, Henyey-Greenstein's phase) scatters no polarisation, as Mitsuba's hg."""
    motes.set_variant("llvm_ad_mono_polarized")
    img = _single_scattering(_grains(0.005, storage="procedural", phase_model="hg"), 90.0)
    got, se = _ratio(img, S1)
    assert img[..., S0].mean() > 0
    assert abs(got) < 3 * se + 1e-3, f"S1/S0 {got:.4f} +- {se:.4f}"


@pytest.mark.parametrize("family", ["llvm_ad_spectral", "scalar_spectral"])
def test_s0_of_a_polarised_render_is_the_unpolarised_image(family):
    """Multiple scattering (depth 8) in a cloud of 1 um grains: the polarised variant's S0 (what `mi.render`
    returns there) equals the unpolarised variant's image within noise, in mean and pixel by pixel."""
    res, spp = (16, 64) if family.startswith("llvm") else (10, 32)
    imgs = []
    for variant in (family, family + "_polarized"):
        motes.set_variant(variant)
        med = _grains(1.0, sigma_t=2.0)
        med.pop("wavelengths")
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": 8},
            "sensor": {"type": "perspective", "fov": 30,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1, 4], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": spp}},
            "light": {"type": "directional", "direction": [1, -0.5, -0.3], "irradiance": 3.0},
            "env": {"type": "constant", "radiance": 0.2},
            "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": med},
        })
        img = np.asarray(mi.render(scene, spp=spp), dtype=np.float64)
        imgs.append(img.reshape(-1, img.shape[-1])[:, :3].mean(axis=1))
    (a, b) = imgs
    se = np.hypot(a.std(ddof=1), b.std(ddof=1)) / np.sqrt(a.size)
    assert abs(a.mean() - b.mean()) < 3 * se, f"{family}: unpolarised {a.mean():.4f}, polarised S0 {b.mean():.4f} +- {se:.4f}"


def test_white_furnace_polarised():
    """Non-absorbing grains under a white environment render 1 in a polarised variant (Russian roulette off)."""
    motes.set_variant("llvm_ad_spectral_polarized")
    m, se = render_furnace(furnace_medium(400, 0.3), "rotated_scaled", 16, 32)
    assert abs(m - 1.0) < 3 * se + 1e-3, f"{m:.4f} +- {se:.4f}"
    assert se < 0.03


def test_drjit_kernel_polarises_as_f12():
    """``kernel = "drjit"`` (issue 46) renders the same single scattering: S1 / S0 = F12 / F11 at 110 degrees."""
    motes.set_variant("llvm_ad_mono_polarized")
    img = _single_scattering(_grains(0.3, kernel="drjit"), 110.0)
    f = motes.mueller_matrix(0.3, LAM_UM, 1.5, np.radians(110.0))
    want = float(f[1] / f[0])
    got, se = _ratio(img, S1)
    assert img[..., S0].mean() > 0
    assert abs(got - want) < 3 * se + 1e-3, f"S1/S0 {got:.5f} +- {se:.5f}, F12/F11 {want:.5f}"


def test_sampled_weight_is_the_matrix_over_the_pdf():
    """`sample` draws from F11 and weighs by the Mueller matrix there over the pdf: weight * pdf = eval_pdf's
    matrix at the sampled direction, element by element, and the (0, 0) element is F11 / pdf."""
    motes.set_variant("llvm_ad_mono_polarized")
    species = [motes.Species(motes.Monodisperse(0.3), 1.5)]
    data = motes.DiscreteMedium(np.zeros((1, 3)), [0.3], [0], species, [LAM_UM], query_radius=1e-6, size_bins=1,
                                polarized=True)
    assert data.core.polarizes
    data.core.insert_event((0.0, 0.0, 0.0), [0])
    phase = mi.load_dict({"type": "particle"})
    phase.attach(data)
    n = 2000
    mei = dr.zeros(mi.MediumInteraction3f, n)
    mei.wi = mi.Vector3f(0.3, -0.2, 0.9327379)
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.p = mi.Point3f(0, 0, 0)
    rng = np.random.default_rng(1)
    ctx = mi.PhaseFunctionContext()
    wo, w, pdf = phase.sample(ctx, mei, mi.Float(rng.random(n)), mi.Point2f(mi.Float(rng.random(n)), mi.Float(rng.random(n))))
    value, pdf2 = phase.eval_pdf(ctx, mei, wo)
    w, value = np.asarray(w), np.asarray(value)
    pdf, pdf2 = np.asarray(pdf), np.asarray(pdf2)
    ok = pdf > 0
    assert ok.mean() > 0.99
    np.testing.assert_allclose(pdf2[ok], pdf[ok], rtol=1e-5)
    np.testing.assert_allclose(w[..., ok] * pdf[ok], value[..., ok], rtol=1e-4, atol=1e-6)
    # Physical: |M_ij| <= M_00 for a sphere's matrix in any frames (rotations mix Q and U only).
    assert np.all(np.abs(value[..., ok]) <= value[0, 0][..., ok] * (1 + 1e-5) + 1e-7)
    # Not a depolarizer: unpolarised light leaves strongly polarised at some angles.
    assert (np.hypot(value[1, 0], value[2, 0])[..., ok] / value[0, 0][..., ok]).max() > 0.3


def test_bin_tables_refuse_bad_ratios():
    lam = np.array([550.0])
    theta = np.linspace(0, np.pi, 5)
    f = np.full(5, 1 / (4 * np.pi))
    args = (np.array([1.0]), theta, f, np.array([0, 5], dtype=np.uint64), lam)
    motes._motes.BinTables(*args, np.zeros(15))
    with pytest.raises(ValueError, match="three ratios per"):
        motes._motes.BinTables(*args, np.zeros(14))
    bad = np.zeros(15)
    bad[2] = 1.5
    with pytest.raises(ValueError, match="F12/F11"):
        motes._motes.BinTables(*args, bad)
    bad[2] = np.nan
    with pytest.raises(ValueError, match="F12/F11"):
        motes._motes.BinTables(*args, bad)


@pytest.mark.parametrize("theta_deg", [50.0, 140.0])
def test_continuous_equivalents_carry_the_matrices(theta_deg):
    """Deliverable 3: a procedural cloud of 0.1 um grains (their continuous field: every class continuous) and
    `homogeneous_equivalent(polarized=True)` (Mitsuba's homogeneous medium with `motes_tabphase_polarized`) of
    the same grains scatter the same polarisation and, within noise, the same light."""
    motes.set_variant("llvm_ad_mono_polarized")
    sp = motes.Species(motes.Monodisperse(0.1), 1.5)
    d = motes.homogeneous_equivalent(sp, 1e12, color="spectral", wavelength_um=[LAM_UM], polarized=True)
    assert d["phase"]["type"] == "motes_tabphase_polarized"
    hom = {"type": "homogeneous", "sigma_t": 0.1, "albedo": 1.0, "phase": d["phase"]}
    a = _single_scattering(_grains(0.1, storage="procedural"), theta_deg, spp=128)
    b = _single_scattering(hom, theta_deg, spp=128)
    (ra, sa), (rb, sb) = _ratio(a, S1), _ratio(b, S1)
    assert abs(ra - rb) < 3 * np.hypot(sa, sb) + 1e-3, f"S1/S0 discrete {ra:.5f}, homogeneous {rb:.5f}"
    assert abs(ra) > 0.1
    pa, pb = a[..., S0].ravel(), b[..., S0].ravel()
    se = np.hypot(pa.std(ddof=1), pb.std(ddof=1)) / np.sqrt(pa.size)
    assert abs(pa.mean() - pb.mean()) < 3 * se, f"S0 discrete {pa.mean():.5f}, homogeneous {pb.mean():.5f} +- {se:.5f}"
    from motes.equivalent import equivalent_xml

    xml = equivalent_xml(motes.homogeneous_equivalent(sp, 1e12, polarized=True))  # RGB, as `motes equivalent` prints
    assert '<phase type="motes_tabphase_polarized">' in xml and '<string name="m12"' in xml


def _chi2(phase, mei_of, variant_note: str) -> None:
    passed, messages = phase_chi2(mi, dr, phase, mei_of, sample_count=200_000)
    assert passed, f"{variant_note}: {messages}"


def test_chi2_of_the_particle_phase_in_a_polarised_variant():
    """The `particle` phase function samples what it evaluates in a polarised variant (a site of two sizes)."""
    motes.set_variant("llvm_ad_spectral_polarized")
    species = [motes.Species(motes.Uniform(0.4, 0.6), 1.33), motes.Species(motes.Uniform(2.5, 3.0), 1.5)]
    data = motes.DiscreteMedium(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), [0.5, 2.7], [0, 1], species,
                                motes.SPECTRAL_WAVELENGTHS_UM, query_radius=1e-6, size_bins=1, polarized=True)
    assert data.core.polarizes
    data.core.insert_event((0.0, 0.0, 0.0), [0, 1])
    phase = mi.load_dict({"type": "particle"})
    phase.attach(data)
    _chi2(phase, interactions_at_origin(mi, dr, mi.Vector3f(0.3, -0.2, 0.9327379)), "particle")


def test_chi2_of_motes_tabphase_polarized():
    motes.set_variant("llvm_ad_mono_polarized")
    mu = np.linspace(-1, 1, 257)
    f = 1.0 + 3.0 * np.exp(8.0 * (mu - 1.0)) + 0.3 * mu
    text = lambda a: ", ".join(f"{x:.7g}" for x in a)  # noqa: E731
    phase = mi.load_dict({"type": "motes_tabphase_polarized", "values": text(f), "m12": text(-(1 - mu**2) / 2)})
    _chi2(phase, interactions_at_origin(mi, dr, mi.Vector3f(0.6, 0.0, 0.8)), "motes_tabphase_polarized")


def test_motes_tabphase_polarized_names_bad_values():
    motes.set_variant("llvm_ad_mono_polarized")
    for bad, match in ((dict(values="1"), "at least two"), (dict(values="1, -1"), ">= 0"),
                       (dict(values="1, 1", m12="0.5"), "'m12' has 1"), (dict(values="1, 1", m33="1, 2"), "'m33' holds"),
                       (dict(values="1, x"), "not a number")):
        with pytest.raises(Exception, match=match):
            mi.load_dict({"type": "motes_tabphase_polarized", **bad})


def test_importance_transport_swaps_the_directions():
    """In importance transport light arrives along -wi and leaves along wo (Mitsuba's polarised BSDFs'
    convention): the matrix for (wi = a, wo = b) is radiance transport's for (wi = b, wo = a), in the C++
    `motes_tabphase_polarized` and in the evaluated path's `mueller_spectrum` alike; and it is not the same
    matrix as radiance transport's for (a, b), so the swap is seen."""
    motes.set_variant("llvm_ad_mono_polarized")
    from motes.plugins._bridge import mueller_spectrum

    mu = np.linspace(-1, 1, 129)
    text = lambda v: ", ".join(f"{x:.7g}" for x in v)  # noqa: E731
    phase = mi.load_dict({"type": "motes_tabphase_polarized", "values": text(0.75 * (1 + mu**2)),
                          "m12": text(-(1 - mu**2) / (1 + mu**2)), "m33": text(2 * mu / (1 + mu**2)),
                          "m34": text(0.3 * (1 - mu**2))})
    rng = np.random.default_rng(3)
    a, b = (rng.normal(size=(64, 3)) for _ in range(2))
    a, b = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in (a, b))
    elements = rng.uniform(-0.5, 0.5, size=(64, 1, 4))
    elements[..., 0] = 1.0

    def matrices(mode, wi, wo):
        mei = _mei_at(wi)
        ctx = mi.PhaseFunctionContext()
        ctx.mode = mode
        wo_v = mi.Vector3f(*(mi.Float(wo[:, k]) for k in range(3)))
        return np.asarray(phase.eval_pdf(ctx, mei, wo_v)[0]), np.asarray(mueller_spectrum(elements, 64, ctx, mei, wo_v))

    imp = matrices(mi.TransportMode.Importance, a, b)
    rad_swapped = matrices(mi.TransportMode.Radiance, b, a)
    rad = matrices(mi.TransportMode.Radiance, a, b)
    for m_imp, m_swapped, m_rad in zip(imp, rad_swapped, rad):
        np.testing.assert_allclose(m_imp, m_swapped, atol=1e-5)
        assert np.abs(m_imp - m_rad).max() > 0.05


def _mei_at(wi):
    mei = dr.zeros(mi.MediumInteraction3f, wi.shape[0])
    mei.wi = mi.Vector3f(*(mi.Float(wi[:, k]) for k in range(3)))
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.p = mi.Point3f(0, 0, 0)
    return mei
