"""Compact particle storage (issue 24.2): each particle a class of its optics bin and a radius level
(``rust/motes-core/src/render/storage.rs``). Radii move by at most half a level; a medium stored compactly
renders what the full one renders (image means within noise, a furnace of 1); the parameter is checked by
name; compact storage keeps fewer bytes and no per-particle Python arrays."""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np
import pytest

import motes

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import mitsuba as mi  # noqa: E402
from test_continuous import _medium, _two_sizes  # noqa: E402

LEVELS = 1024  # radius levels per optics bin (storage.rs LEVELS_PER_BIN)


def _spot_scene(medium: dict, res: int, spp: int, seed: int = 0) -> dict:
    """Grains lit by a spot in a box seen from the front: lit grains, their shadows, multiple scattering."""
    T = mi.ScalarTransform4f
    return {"type": "scene", "integrator": {"type": "volpath", "max_depth": 8},
            "sensor": {"type": "perspective", "fov": 35, "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
            "spot": {"type": "spot", "to_world": T().look_at(origin=[-2, 3, 2], target=[0, 0, 0], up=[0, 1, 0]),
                     "intensity": {"type": "rgb", "value": 40.0}, "cutoff_angle": 25},
            "floor": {"type": "rectangle", "to_world": T().translate([0, -1.5, 0]).scale(4).rotate([1, 0, 0], -90),
                      "bsdf": {"type": "diffuse"}},
            "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium}}


def _env_scene(medium: dict, res: int, spp: int) -> dict:
    """The medium in a unit cube under a constant white environment; Russian roulette off."""
    return {"type": "scene", "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 100000},
            "sensor": {"type": "perspective", "fov": 28,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": spp}},
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
            "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium}}


def _grains(storage: str | None, count: int = 3000) -> dict:
    """Visible grains (log-normal, discrete at the default continuous_count) with a spread of radii."""
    d = {"type": "discrete", "count": count, "radius_median": 60.0, "radius_sigma_g": 2.0, "eta": 1.5,
         "scale_m": 1e-2, "query_radius": 0.01, "seed": 4, "phase": {"type": "particle"}}
    if storage is not None:
        d["storage"] = storage
    return d


def test_default_is_compact_and_keeps_no_particle_arrays():
    motes.set_variant("scalar_rgb")
    compact = _medium(mi.load_dict(_env_scene(_grains(None), 4, 1))).data
    full = _medium(mi.load_dict(_env_scene(_grains("full"), 4, 1))).data
    assert compact.storage == "compact" and full.storage == "full"
    assert compact.radii_um is None and compact.positions is None and compact.particle_bin is None
    assert full.radii_um.shape == (3000,)
    assert len(compact) == len(full) == 3000
    assert compact.continuous_particles == full.continuous_particles == 0


def test_compact_keeps_fewer_bytes():
    """13 bytes of optics per particle fewer once the particles outnumber the classes (200 000 grains in
    16 bins of 1024 levels; at a few thousand grains nearly every grain is its own class)."""
    motes.set_variant("scalar_rgb")
    n = 200_000
    full, compact = (_medium(mi.load_dict(_env_scene(_grains(s, n), 4, 1))).data for s in ("full", "compact"))
    assert full.bytes - compact.bytes > 10 * n, (full.bytes, compact.bytes)


@pytest.mark.parametrize("median_um, query_radius", [(60.0, 0.01), (30.0, 0.002), (400.0, 0.05)])
def test_compact_keeps_at_most_16_bytes_per_discrete_grain(median_um, query_radius):
    """Issue 24.2 with nothing set but what makes every grain discrete (continuous_count = inf): at most 16
    bytes per particle at render time (besides the optics tables, a fixed cost), for grains small and large against their spacing (100 000 grains
    in a unit cube: spacing 0.02, inclusion radii 0.002-0.05), wide radius spreads included."""
    motes.set_variant("scalar_rgb")
    n = 100_000
    medium = dict(_grains(None, n), radius_median=median_um, query_radius=query_radius,
                  continuous_count=float("inf"))
    data = _medium(mi.load_dict(_env_scene(medium, 4, 1))).data
    assert data.continuous_particles == 0
    per_grain = (data.core.bytes - data.core.table_bytes) / n  # the optics tables are a fixed cost
    assert 0 < data.core.table_bytes < data.core.bytes
    assert per_grain <= 16.0, per_grain


def test_quantised_radii_stay_within_half_a_level():
    """The disks the core walks: compact storage changes no particle's inclusion radius by more than half
    a radius level of its bin (read back through the largest inclusion radius of each bin's medium)."""
    motes.set_variant("scalar_rgb")
    full = _medium(mi.load_dict(_env_scene(_grains("full"), 4, 1))).data
    compact = _medium(mi.load_dict(_env_scene(_grains("compact"), 4, 1))).data
    lo, hi = np.array(full.bin_radius_um).T
    half_level = float(np.max(np.log(hi / lo))) / (2 * LEVELS)
    assert half_level < 1e-3
    r_full, r_compact = full.core.reach_max, compact.core.reach_max
    assert abs(np.log(r_compact / r_full)) <= half_level * 1.01


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_compact_renders_what_full_renders(variant):
    """Same particles, same sampler seeds: the two storages' image means agree within 3 combined SE
    (SE from four seeds each), and the images' per-pixel difference is at the noise level."""
    motes.set_variant(variant)
    imgs = {}
    for storage in ("full", "compact"):
        imgs[storage] = np.stack([np.asarray(mi.render(mi.load_dict(_spot_scene(_grains(storage), 24, 8, seed=s))),
                                             dtype=np.float64) for s in range(4)])
    means = {k: v.mean(axis=(1, 2, 3)) for k, v in imgs.items()}
    diff = means["compact"].mean() - means["full"].mean()
    se = np.hypot(means["compact"].std(ddof=1), means["full"].std(ddof=1)) / 2
    assert means["full"].mean() > 0
    assert abs(diff) < 3 * se + 1e-4 * means["full"].mean(), (means, diff, se)
    noise = np.sqrt(np.mean((imgs["full"][0] - imgs["full"][1]) ** 2))
    rms = np.sqrt(np.mean((imgs["compact"][0] - imgs["full"][0]) ** 2))
    assert rms < 1.5 * noise, (rms, noise)


def test_compact_furnace_with_continuous_classes():
    """Compact storage with a continuous haze and discrete grains, albedo 1: white furnace (roulette off)."""
    motes.set_variant("scalar_rgb")
    med = _two_sizes(20000, 16.0, albedo=1.0)
    s = mi.load_dict(_env_scene(med, 16, 16))
    assert _medium(s).data.storage == "compact" and _medium(s).data.continuous_particles > 0
    img = np.asarray(mi.render(s), dtype=np.float64).mean(axis=-1)
    m, se = img.mean(), img.std(ddof=1) / np.sqrt(img.size)
    assert abs(m - 1.0) < 3 * se + 1e-3, (m, se)


@pytest.mark.parametrize("value", ["tiny", "Compact", ""])
def test_storage_errors_name_the_parameter(value):
    motes.set_variant("scalar_rgb")
    with pytest.raises(Exception, match="storage"):
        mi.load_dict(_grains(value))
    with pytest.raises(ValueError, match="storage"):
        motes.DiscreteMedium(np.zeros((1, 3)), [10.0], [0], motes.Species(motes.Monodisperse(10.0), 1.5),
                             motes.RGB_WAVELENGTHS_UM, storage=value)


def test_more_than_65536_classes_store_wide_codes_and_walk_like_full_storage():
    """More than 64 occupied optics bins (340 here, every grain continuous) give class codes beyond 16 bits
    (bins x 1024 levels): the continuous field keeps 32-bit codes (``Members::WideClasses``). Its optical
    depths along rays equal full storage's (radii within half a level), and its furnace is 1 with
    roulette off."""
    motes.set_variant("scalar_rgb")
    meds = {}
    for storage in ("full", "compact"):
        # A wide PSD over many occupied bins: small grains continuous, the largest discrete (a 6 mm cube: the
        # query disks' edge share 1.8 %, below CONTINUOUS_MAX_EDGE_SHARE).
        meds[storage] = {"type": "discrete", "count": 60000, "radius_median": 8.0, "radius_sigma_g": 1.5,
                         "eta": 1.31, "scale_m": 3e-3, "size_bins": 400, "seed": 3, "query_radius": 0.04,
                         "albedo": 1.0, "storage": storage, "phase": {"type": "particle"}}
    full = _medium(mi.load_dict(_env_scene(meds["full"], 4, 1))).data
    compact_scene = mi.load_dict(_env_scene(meds["compact"], 16, 16))
    compact = _medium(compact_scene).data
    assert compact.continuous_particles > 0 and full.n_bins > 64
    rng = np.random.default_rng(2)
    n = 2000
    o = np.column_stack([rng.uniform(-0.9, 0.9, n), rng.uniform(-0.9, 0.9, n), np.full(n, -2.0)])
    d = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n), np.ones(n)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, b = full.optical_depth(o, d, 0.0, 5.0), compact.optical_depth(o, d, 0.0, 5.0)
    assert a.max() > 0
    np.testing.assert_allclose(b, a, rtol=2e-3, atol=1e-6)
    img = np.asarray(mi.render(compact_scene), dtype=np.float64).mean(axis=-1)
    m, se = img.mean(), img.std(ddof=1) / np.sqrt(img.size)
    assert abs(m - 1.0) < 3 * se + 1e-3, (m, se)
