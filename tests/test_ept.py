"""The `discrete` medium with its DEFAULT parameters against explicit path tracing (EPT) of the same glass
grains as Mitsuba spheres (a small `scripts/bench/bench_ept.py`; its docstring describes the scenes).

Side scattering (45-135 deg) and total transmittance (into a 30 deg cone) of the discrete medium must be
within 3 % + 3 standard errors of EPT. The standard errors are Monte Carlo errors from two seeds per
render; the tolerance is not tuned: with r_c = 0 and the paper's tau_i = C_ext / (pi R^2) the discrete
medium lost ~57 % of the side scattering, which this test catches.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "scripts"))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "scripts" / "bench"))
import bench_ept as B  # noqa: E402

COUNT, RES, SPP = 1000, 48, 32


@pytest.fixture(scope="module")
def grains(tmp_path_factory):
    pos, r_um = B.make_particles(COUNT, seed=1)
    path = B.save_particle_file(tmp_path_factory.mktemp("ept") / "grains.npz", pos, r_um)
    return pos, r_um, path


def test_grains_do_not_overlap_and_stay_inside(grains):
    pos, r_um, _ = grains
    r = r_um * 1e-4
    assert np.all(np.abs(pos) + r[:, None] <= B.HALF)
    d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(axis=2)
    np.fill_diagonal(d2, np.inf)
    assert np.all(d2 > (r[:, None] + r[None, :]) ** 2)
    assert motes.load_particles(grains[2]).positions.shape == (COUNT, 3)


def test_discrete_defaults_match_explicit_spheres(grains):
    """Default discrete medium (no query_radius, no truncate_below) vs EPT: side scattering and total
    transmittance within 3 % + 3 SE; and the EPT set-up itself: its direct transmittance (0.5 deg source)
    equals the geometric fraction of unblocked rays."""
    motes.set_variant("llvm_ad_rgb")
    pos, r_um, path = grains
    ept = B.measure_ept(mi, (pos, r_um), ("side", "trans", "direct"), RES, B.EPT_SPP_FACTOR * SPP)
    disc = B.measure_discrete(mi, path, {}, ("side", "trans"), RES, SPP)
    geo = B.geometric_unblocked(pos, r_um, n=2000)
    report = "; ".join(f"{v}: EPT {ept[v][0]:.5f} +- {ept[v][1]:.5f}, discrete {disc[v][0]:.5f} +- {disc[v][1]:.5f} "
                       f"({disc[v][0] / ept[v][0] - 1:+.1%})" for v in disc)
    print(report)
    # the harness: a real test (grains block a fair share of the rays), EPT direct = geometry
    assert 0.5 < geo[0] < 0.9
    assert B.within(ept["direct"], geo, rel_tol=0.01), (ept["direct"], geo)
    assert ept["side"][1] < 0.05 * ept["side"][0]
    for v in ("side", "trans"):
        assert B.within(disc[v], ept[v]), report
