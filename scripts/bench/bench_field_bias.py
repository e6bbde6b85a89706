"""Issue 24.3 finding: the transmittance of a stored cloud's continuous field against the same grains walked
one by one, and against a procedural cloud of the same distribution (its field is the exact expectation,
no shot noise). A 10 cm cube (scale 1 cm) of ``--count`` ice grains (log-normal, median 50 um, sigma_g 1.5),
``query_radius`` 0.02; 40 000 rays along z through the cube's middle, transmittance over 0.5, 2 and 4 cm
from the face (optical depth ~0.57 / 2.3 / 4.5 at 10^7). The field's cell size is the core's
``PARTICLES_PER_CELL`` (``rust/motes-core/src/render/continuous/build.rs``): measure other values by changing it.

    .venv/bin/python scripts/bench/bench_field_bias.py [--count 1e7]
"""
import argparse

import numpy as np

import motes
from motes.discrete import DiscreteMedium

ap = argparse.ArgumentParser()
ap.add_argument("--out", default="out", help="unused (run_benchmarks.sh passes it); results are printed")
ap.add_argument("--count", type=float, default=1e7)
a = ap.parse_args()
n = int(a.count)
sp = motes.Species(motes.LogNormal(50.0, 1.5), motes.Material("ice"))
lam = motes.RGB_WAVELENGTHS_UM
M = np.diag([5.0, 5.0, 5.0, 1.0])
rng = np.random.default_rng(2)
m = 40000
o = np.column_stack([rng.uniform(-4.5, 4.5, m), rng.uniform(-4.5, 4.5, m), np.full(m, -10.0)])
d = np.tile([0, 0, 1.0], (m, 1))
lengths = (0.5, 2.0, 4.0)


def transmittances(medium):
    return [np.exp(-medium.optical_depth(o, d, 5.0, 5.0 + L)) for L in lengths]


pos, r, si = motes._motes.generate_cloud(n, [-1.0] * 3, [1.0] * 3, "uniform", [], 0, [sp.psd._core], [1.0], 3,
                                         M[:3, :4].tolist())
res = {}
for name, cc in (("field", 1e-9), ("grains", np.inf)):  # every class continuous / every grain walked
    st = DiscreteMedium(pos.reshape(-1, 3), r, si, [sp], lam, scale_m=0.01, query_radius=0.02, continuous_count=cc)
    res[name] = transmittances(st)
    del st
proc = DiscreteMedium.procedural(n, [sp], [1.0], lam, to_world=M, scale_m=0.01, query_radius=0.02,
                                 continuous_count=1e-9)
res["expected"] = transmittances(proc)
print(f"{n:.0e} grains, transmittance over 0.5 / 2 / 4 cm:")
for k, L in enumerate(lengths):
    f, g, e = (res[x][k].mean() for x in ("field", "grains", "expected"))
    se = res["grains"][k].std() / np.sqrt(m) / g
    print(f"  L = {L}: field {f:.5f}, grains {g:.5f} (field/grains {f / g - 1:+.2%} +- {se:.2%}), "
          f"procedural expectation {e:.5f} (grains/expectation {g / e - 1:+.2%})")
