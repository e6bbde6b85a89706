"""The native render path and the evaluated-mode Python path render the same absorbing cloud.

The native path returns sigma_s = sigma_t at every site and puts the grains' albedo into the phase
function's values and weights (motes_native.cpp); the evaluated-mode path returns sigma_s = albedo * sigma_t
and an unweighted phase function. Mitsuba's volpath multiplies both into a path alike, so their image means
agree within the noise, in RGB (sample weights in one call) and spectral variants (four channels: the
sample's values from a second call). The grains absorb enough that ignoring their albedo would move the
mean by many standard errors (checked against the same cloud of clear grains).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

SEEDS = 6

CODE = textwrap.dedent("""
    import json, os, sys
    import numpy as np
    import motes, mitsuba as mi
    motes.set_variant(sys.argv[1])
    if os.environ["MOTES_NATIVE"] == "0":
        motes.set_evaluated_mode()
    assert (sys.argv[1] in motes.native_variants()) == (os.environ["MOTES_NATIVE"] == "1")
    means = {}
    for k in (0.0, float(sys.argv[2])):
        scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpath", "max_depth": 16},
            "sensor": {"type": "perspective", "fov": 40,
                       "film": {"type": "hdrfilm", "width": 12, "height": 12, "rfilter": {"type": "box"}},
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])},
            "env": {"type": "constant"},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "interior": {"type": "discrete", "count": 20000, "radius_median": 300, "radius_sigma_g": 1.2,
                                  "eta": 1.5, "eta_k": k, "scale_m": 0.01, "phase": {"type": "particle"}}}})
        means[k] = [float(np.mean(mi.render(scene, spp=32, seed=s))) for s in range(int(sys.argv[3]))]
    print(json.dumps(list(means.values())))
""")


def _means(variant: str, native: str, eta_k: float) -> list[list[float]]:
    env = dict(os.environ, MOTES_NATIVE=native)
    out = subprocess.run([sys.executable, "-c", CODE, variant, str(eta_k), str(SEEDS)], capture_output=True,
                         text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral"])
def test_native_and_evaluated_paths_agree_on_absorbing_grains(variant):
    eta_k = 2e-4  # 300 um grains: single-scattering albedo about 0.7
    (clear_n, dark_n), (clear_e, dark_e) = (_means(variant, n, eta_k) for n in ("1", "0"))

    def mean_se(x):
        return float(np.mean(x)), float(np.std(x, ddof=1) / np.sqrt(len(x)))

    (mn, sn), (me, se) = mean_se(dark_n), mean_se(dark_e)
    both = np.hypot(sn, se)
    assert abs(mn - me) < 4 * both, (mn, sn, me, se)
    # The albedo matters: the clear cloud is far brighter on both paths.
    for clear, dark in ((clear_n, dark_n), (clear_e, dark_e)):
        (mc, sc), (md, sd) = mean_se(clear), mean_se(dark)
        assert mc - md > 10 * np.hypot(sc, sd), (mc, sc, md, sd)
