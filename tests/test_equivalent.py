"""The continuous equivalent for A/B comparisons (issue 3): Mitsuba loads it in RGB and spectral
variants, its parameters are the bulk properties, its tabphase is our ensemble phase function, and a
non-absorbing cloud renders as a white furnace with Mitsuba's own volpath."""

from __future__ import annotations

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")

ICE = motes.Species(motes.LogNormal(800.0, 4.0), 1.31 + 1e-9j)


@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
@pytest.mark.parametrize("color", ["rgb", "spectral"])
def test_loads(variant, color):
    mi.set_variant(variant)
    medium = mi.load_dict(motes.homogeneous_equivalent(ICE, 1e4, color=color, scale_m=50.0))
    keys = set(mi.traverse(medium).keys())
    assert {"scale", "phase_function.values"} <= keys
    assert any(k.startswith("sigma_t.value") for k in keys) and any(k.startswith("albedo.value") for k in keys)


def test_parameters_are_the_bulk_properties():
    """scale x sigma_t colour = bulk sigma_t (after the default one-bin truncation) x metres per unit,
    albedo = bulk albedo, at the documented RGB wavelengths."""
    mi.set_variant("scalar_rgb")
    n, scale_m = 4096, 50.0
    d = motes.homogeneous_equivalent(ICE, 1e4, scale_m=scale_m, tabphase_size=n)
    b = motes.bulk_properties(ICE, 1e4, motes.RGB_WAVELENGTHS_UM, truncate_below_rad=np.arccos(1 - 2 / (n - 1)))
    np.testing.assert_allclose(np.array(d["sigma_t"]["value"]) * d["scale"], b["sigma_t"] * scale_m, rtol=1e-12)
    np.testing.assert_allclose(d["albedo"]["value"], b["albedo"], rtol=1e-12)
    assert 0.3 < b["peak_fraction"][0] < 0.7  # half of the scattering is the diffraction peak of mm grains


def test_tabphase_is_our_phase_function():
    """Mitsuba's tabphase, evaluated by Mitsuba, equals our (truncated, sigma_s-weighted) ensemble phase
    function: within 1e-4 where its bins are narrow against the function's variation (1-2.5 rad; 3e-3 at 0.5), within
    3 % near the forward cut and in the glory (bins of 0.004-0.01 rad average steep structure there)."""
    mi.set_variant("scalar_rgb")
    n = 4096
    cut = np.arccos(1 - 2 / (n - 1))
    d = motes.homogeneous_equivalent(ICE, 1e4, tabphase_size=n)
    phase = mi.load_dict(d["phase"])
    b = motes.bulk_properties(ICE, 1e4, motes.RGB_WAVELENGTHS_UM, truncate_below_rad=cut)
    w = b["sigma_s"] / b["sigma_s"].sum()
    table = motes.PhaseTable(b["theta"], w @ b["phase"])
    ctx = mi.PhaseFunctionContext(None)
    mei = mi.MediumInteraction3f()
    mei.wi = mi.Vector3f(0, 0, 1)
    mei.sh_frame = mi.Frame3f(mei.wi)
    for theta, tol in ((0.05, 0.03), (0.5, 5e-3), (1.0, 1e-4), (1.5, 1e-4), (2.0, 1e-4), (2.5, 1e-4), (3.0, 0.03)):
        wo = mi.Vector3f(np.sin(theta), 0.0, -np.cos(theta))  # forward is wo = -wi
        ours = float(table.eval(theta))
        theirs = float(phase.eval_pdf(ctx, mei, wo)[1])
        assert theirs == pytest.approx(ours, rel=tol), theta


def test_white_furnace_with_mitsuba_volpath():
    """A non-absorbing cloud (kappa = 0) in a cube under a constant environment of radiance 1 renders
    1 within 3 standard errors with Mitsuba's own volpath: the equivalent conserves energy."""
    mi.set_variant("scalar_rgb")
    medium = motes.homogeneous_equivalent(motes.Species(motes.LogNormal(100.0, 2.0), 1.31), 1e6, scale_m=1.0)
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1},
        "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium},
        "sensor": {"type": "perspective", "fov": 30, "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 6], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 64}},
    })
    img = np.array(mi.render(scene))
    values = img[..., 1].ravel()
    se = values.std() / np.sqrt(values.size)
    assert abs(values.mean() - 1.0) < 3 * se + 1e-3


def test_errors():
    with pytest.raises(ValueError, match="color"):
        motes.homogeneous_equivalent(ICE, 1e4, color="xyz")
    with pytest.raises(ValueError, match="scale_m"):
        motes.homogeneous_equivalent(ICE, 1e4, scale_m=0.0)
    with pytest.raises(ValueError, match="tabphase_size"):
        motes.homogeneous_equivalent(ICE, 1e4, tabphase_size=1)
    with pytest.raises(ValueError, match="3 wavelengths"):
        motes.homogeneous_equivalent(ICE, 1e4, wavelength_um=[0.5, 0.6])
