"""The native render path and the evaluated-mode Python path render the same absorbing cloud.

The native path returns sigma_s = sigma_t at every site and puts the grains' albedo into the phase
function's values and weights (motes_native.cpp); the evaluated-mode path returns sigma_s = albedo * sigma_t
and an unweighted phase function. Mitsuba's volpath and volpathmis multiply both into a path alike, so
their image means agree within the noise in every colour channel: in RGB variants (a phase sample's
direction, weights and pdf in one call; scalar_rgb with its own one-lane record) and spectral ones (four
channels: the sample's values from a second call; scalar_spectral too). The grains absorb more at short wavelengths (a channel
mix-up moves the channels apart), the camera and the light are off the cloud's axes (a mirrored direction
moves the image), and ignoring the albedo would move the mean by many standard errors (checked against the
same cloud of clear grains).
"""

from __future__ import annotations

import functools
import os
import textwrap

import numpy as np
import pytest

from _scenes import run_json

SEEDS = 6
ETA_K = 8e-5  # 300 um grains: the cloud 40 % as bright as clear grains, 5 % darker in blue than in red

CODE = textwrap.dedent("""
    import json, os, sys
    import numpy as np
    import motes, mitsuba as mi
    from _scenes import point_lit_cube
    variant, integrator, seeds = sys.argv[1], sys.argv[2], int(sys.argv[3])
    motes.set_variant(variant)
    if os.environ["MOTES_NATIVE"] == "0":
        motes.set_evaluated_mode()
    assert (variant in motes.native_variants()) == (os.environ["MOTES_NATIVE"] == "1")
    out = []
    for k in map(float, sys.argv[4:]):
        grains = {"type": "discrete", "count": 20000, "radius_median": 300, "radius_sigma_g": 1.2, "eta": 1.5,
                  "eta_k": k, "scale_m": 0.01, "phase": {"type": "particle"}}
        scene = mi.load_dict(point_lit_cube(mi, grains, integrator={"type": integrator, "max_depth": 16}, fov=40,
                                            res=12, origin=[1.6, 1.1, 3.6], target=[0, 0, 0], light=[2.5, 3.0, 1.0],
                                            intensity=12.0, sky=0.2))
        out.append([np.asarray(mi.render(scene, spp=32, seed=s), dtype=np.float64)[..., :3].mean(axis=(0, 1)).tolist()
                    for s in range(seeds)])
    print(json.dumps(out))
""")


def _means(variant: str, native: str, integrator: str, *eta_k: float) -> list[np.ndarray]:
    """Per-seed channel means (seeds x 3) of each cloud."""
    env = dict(os.environ, MOTES_NATIVE=native)
    return [np.array(m) for m in run_json(CODE, variant, integrator, str(SEEDS), *map(str, eta_k), env=env)]


@functools.lru_cache(maxsize=None)
def _evaluated(variant: str, integrator: str) -> np.ndarray:
    return _means(variant, "0", integrator, ETA_K)[0]


def _mean_se(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return x.mean(axis=0), x.std(axis=0, ddof=1) / np.sqrt(len(x))


@pytest.mark.parametrize("variant, integrator, reference", [
    ("llvm_ad_rgb", "volpath", "llvm_ad_rgb"),
    ("llvm_ad_spectral", "volpath", "llvm_ad_spectral"),
    ("scalar_rgb", "volpath", "llvm_ad_rgb"),
    ("scalar_spectral", "volpath", "llvm_ad_spectral"),
    ("llvm_ad_rgb", "volpathmis", "llvm_ad_rgb"),
])
def test_native_and_evaluated_paths_agree_on_absorbing_grains(variant, integrator, reference):
    clear, dark = _means(variant, "1", integrator, 0.0, ETA_K)
    (mn, sn), (me, se) = _mean_se(dark), _mean_se(_evaluated(reference, integrator))
    z = (mn - me) / np.hypot(sn, se)
    assert np.all(np.abs(z) < 4), (mn, sn, me, se)
    # The albedo matters, and more in blue than in red.
    (mc, sc), (md, sd) = _mean_se(clear), _mean_se(dark)
    assert np.all(mc - md > 10 * np.hypot(sc, sd)), (mc, sc, md, sd)
    assert md[2] / mc[2] < md[0] / mc[0], (mc, md)
