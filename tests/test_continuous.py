"""Grains nobody can see (issue 10.3): size classes with many particles per query cylinder are sampled as a
continuous medium. The switch must conserve energy, change no expected value, be chosen by the default
criterion in the regimes it is meant for, and combine exactly with the classes that stay discrete."""

from __future__ import annotations

import json
import math
import pathlib
import sys

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "scripts"))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "scripts" / "figures"))
from furnace_grid import furnace_medium, furnace_scene  # noqa: E402


def _medium(scene):
    return next(s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None)


def _two_sizes(count: int, continuous_count: float, albedo=None, query_radius=0.04) -> dict:
    """A haze of small grains (continuous at the default threshold) with a few large ones (discrete), in a
    6 mm cube (its query disks' edge share 1.8 %, below CONTINUOUS_MAX_EDGE_SHARE)."""
    med = {"type": "discrete", "count": count, "eta": 1.31, "scale_m": 3e-3, "size_bins": 4, "seed": 3,
           "query_radius": query_radius, "continuous_count": continuous_count, "phase": {"type": "particle"},
           "psd": json.dumps({"type": "mixture", "weights": [0.995, 0.005], "components": [
               {"type": "uniform", "r_min_um": 8.0, "r_max_um": 12.0},
               {"type": "uniform", "r_min_um": 150.0, "r_max_um": 200.0}]})}
    if albedo is not None:
        med["albedo"] = albedo
    return med


def _env_scene(medium: dict, res: int, spp: int):
    return furnace_scene(medium, "identity", res, spp)


def _mean_se(scene, spp: int, seeds=(0, 1)) -> tuple[float, float]:
    pix = np.concatenate([np.asarray(mi.render(scene, spp=spp, seed=s), dtype=np.float64).mean(axis=2).ravel() for s in seeds])
    return float(pix.mean()), float(pix.std(ddof=1) / math.sqrt(pix.size))


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb"])
def test_furnace_with_continuous_classes(variant):
    """Non-absorbing haze, all continuous and mixed with discrete grains: the furnace reads 1 (no
    roulette, 3 SE + 1e-3)."""
    motes.set_variant(variant)
    res, spp = (24, 32) if variant.startswith("llvm") else (8, 16)
    for med in (dict(furnace_medium(20000, 0.01, 0.04), continuous_count=1.0), _two_sizes(20000, 16.0, albedo=1.0)):
        scene = _env_scene(med, res, spp)
        assert _medium(scene).data.continuous_particles > 0
        m, se = _mean_se(scene, spp, seeds=(0,))
        assert abs(m - 1.0) < 3 * se + 1e-3, f"{variant}: {m:.4f} +- {se:.4f}"


def test_continuous_changes_no_expected_value():
    """An absorbing haze with a few large grains under a constant environment: the image (what the cloud
    absorbs, through every order of scattering) is the same with the haze continuous (default) and
    with every grain discrete, within 4 SE of the two renders' difference."""
    motes.set_variant("llvm_ad_rgb")
    means = {}
    for cc in (math.inf, 16.0):
        # Absorbing grains (k = 0.003): the large ones absorb far more than the small, so the albedo of
        # each interaction depends on which class it comes from.
        scene = _env_scene(dict(_two_sizes(20000, cc), eta_k=0.003), 32, 64)
        n_cont = _medium(scene).data.continuous_particles
        assert (n_cont > 0) == math.isfinite(cc)
        means[cc] = _mean_se(scene, 64)
    (a, sa), (b, sb) = means[math.inf], means[16.0]
    assert a < 0.97  # the cloud absorbs visibly
    assert abs(a - b) < 4 * math.hypot(sa, sb), (means, abs(a - b) / math.hypot(sa, sb))


def test_default_criterion_by_regime():
    """Defaults: the hazy class of a two-size cloud is continuous and its large grains discrete; sparse
    dust (a fraction of a grain per cylinder) stays discrete; a wider footprint (lower resolution) makes
    more classes continuous."""
    motes.set_variant("llvm_ad_rgb")
    med = {k: v for k, v in _two_sizes(20000, 16.0).items() if k != "continuous_count"}
    med["storage"] = "full"  # to read the radii back
    data = _medium(_env_scene(med, 8, 1)).data
    r = data.radii_um
    assert 0 < data.continuous_particles == int(np.sum(r < 50))
    dust = {"type": "discrete", "count": 2000, "radius_median": 40.0, "radius_sigma_g": 1.5, "scale_m": 1e-3,
            "phase": {"type": "particle"}}
    assert _medium(_env_scene(dust, 8, 1)).data.continuous_particles == 0
    counts = []
    for q in (0.01, 0.04):
        counts.append(_medium(_env_scene(_two_sizes(20000, 16.0, query_radius=q), 8, 1)).data.continuous_particles)
    assert counts[0] < counts[1]


def test_continuous_count_is_checked():
    motes.set_variant("llvm_ad_rgb")
    with pytest.raises(Exception, match="continuous_count"):
        _env_scene(_two_sizes(2000, 0.0), 8, 1)


def test_grain_depth_parameter():
    """``grain_depth`` (issue 25) reaches the medium as set (default 1), and a bad value names it."""
    motes.set_variant("scalar_rgb")
    for depth, expect in ((None, motes.DEFAULT_GRAIN_DEPTH), (3, 3)):
        med = _two_sizes(400, 16.0)
        if depth is not None:
            med["grain_depth"] = depth
        assert _medium(_env_scene(med, 4, 1)).data.core.grain_depth == expect
    assert motes.DEFAULT_GRAIN_DEPTH == 1
    for bad in (0, -2, 1.5):
        with pytest.raises((ValueError, RuntimeError), match="invalid grain_depth|grain_depth. must be"):
            _env_scene(dict(_two_sizes(400, 16.0), grain_depth=bad), 4, 1)


def test_field_removes_what_the_grains_remove_inside_their_box():
    """Issue 43: a grain walked one by one removes its C_ext over a disk of radius R across the ray, and
    near a face of the box that holds the grains part of that disk lies outside, on rays the medium never
    carries; the continuous equivalent (cells that fill the box) must leave out that share too. 3 mm
    query disks in a 160 mm cube of grains (an edge share of 1.75 %): the field's transmittance along
    rays inside the box, in random directions, removes within 0.6 % of what the grains remove. In a 20 mm cube (an edge share of
    14 %, which depends on the ray's direction and which a field cannot carry) they stay discrete whatever
    continuous_count."""
    rng = np.random.default_rng(7)
    n, half = 20000, 80.0
    pos = rng.uniform(-half, half, (n, 3))
    radii = rng.uniform(200.0, 450.0, n)
    species = [motes.Species(motes.psd.Uniform(200.0, 450.0), complex(1.5, 0.0))]

    def medium(continuous_count, pos=pos):
        return motes.DiscreteMedium(pos, radii, np.zeros(n, dtype=np.int64), species, [0.630, 0.532, 0.467],
                                    scale_m=1e-3, query_radius=3.0, continuous_count=continuous_count)

    assert medium(1e-9, pos / 8.0).continuous_particles == 0
    exact, field = medium(math.inf), medium(1e-9)  # every grain walked; every grain continuous
    assert field.continuous_particles == n and exact.continuous_particles == 0
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    m = 20000
    o = rng.uniform(lo, hi, (m, 3))
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    t1 = np.min(np.where(d > 0, (hi - o) / d, (lo - o) / d), axis=1)  # to the box's face
    # What a beam loses, 1 - T (each disk's depth is -ln(1 - C/(pi R^2)), so that it removes C: its mean
    # optical depth is 1 % above C here, its transmittance the field's).
    loss = [1.0 - np.exp(-m.optical_depth(o, d, 0.0, t1)).mean() for m in (field, exact)]
    assert abs(loss[0] / loss[1] - 1.0) < 0.006, loss
