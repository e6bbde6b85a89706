"""Moving generated grains (issue 27.2): ``time``, ``velocity``, ``turbulence`` on the ``discrete`` medium.
Each grain keeps its identity (radius, species) and its position is a deterministic function of time."""

from __future__ import annotations

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")


@pytest.fixture(autouse=True)
def _scalar():
    motes.set_variant("scalar_rgb")


def medium(**kw):
    motes.set_variant("scalar_rgb")
    d = {"type": "discrete", "phase": {"type": "particle"}, "storage": "full", "radius_median": 100.0,
         "scale_m": 0.01}
    d.update(kw)
    return mi.load_dict(d)


def test_one_grain_moves_by_velocity_times_dt():
    v = [3.0, -1.5, 0.25]
    a = medium(count=1, velocity=mi.ScalarVector3f(v), time=0.5).data
    b = medium(count=1, velocity=mi.ScalarVector3f(v), time=2.0).data
    np.testing.assert_allclose(b.positions - a.positions, [np.array(v) * 1.5], rtol=0, atol=1e-12)
    assert a.radii_um[0] == b.radii_um[0]


def test_turbulence_keeps_identity_and_moves_smoothly():
    rest = medium(count=2000).data
    t1 = medium(count=2000, turbulence=0.05, turbulence_scale=0.5, time=1.0).data
    t2 = medium(count=2000, turbulence=0.05, turbulence_scale=0.5, time=1.001).data
    np.testing.assert_array_equal(rest.radii_um, t1.radii_um)  # same grains, same order
    d1 = np.linalg.norm(t1.positions - rest.positions, axis=1)
    assert 0.005 < d1.mean() < 0.5, d1.mean()  # of the order of the amplitude
    assert np.linalg.norm(t2.positions - t1.positions, axis=1).max() < 0.01 * d1.max()  # smooth in time
    again = medium(count=2000, turbulence=0.05, turbulence_scale=0.5, time=1.0).data
    np.testing.assert_array_equal(again.positions, t1.positions)  # deterministic


def test_time_zero_is_the_rest_position():
    rest = medium(count=500).data
    still = medium(count=500, velocity=mi.ScalarVector3f(1, 2, 3), turbulence=0.1, time=0.0).data
    np.testing.assert_array_equal(rest.positions, still.positions)


def test_procedural_cloud_moves_with_its_velocity():
    """tau along a ray at time t equals tau along the same ray moved back by v t at time 0."""
    v = np.array([0.4, 0.0, -0.2])
    kw = dict(count=5000, storage="procedural", radius_median=400.0, query_radius=0.01)
    a = medium(**kw).data
    b = medium(**kw, velocity=mi.ScalarVector3f(v.tolist()), time=1.5).data
    rng = np.random.default_rng(3)
    o = np.column_stack([rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.5, 0.5, 200), np.full(200, -3.0)])
    d = np.tile([0.0, 0.0, 1.0], (200, 1))
    tau_b = b.optical_depth(o, d, 0.0, 10.0)
    tau_a = a.optical_depth(o - v * 1.5, d, 0.0, 10.0)
    assert tau_a.max() > 0
    np.testing.assert_allclose(tau_b, tau_a, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("kw,words", [
    (dict(turbulence=-1.0), ["turbulence"]),
    (dict(turbulence=0.1, turbulence_scale=0.0), ["turbulence_scale"]),
    (dict(time=float("nan")), ["time"]),
    (dict(storage="procedural", wrap=True), ["wrap", "procedural"]),
])
def test_bad_motion_parameters_name_themselves(kw, words):
    with pytest.raises(Exception) as e:
        medium(count=100, **kw)
    assert all(w in str(e.value) for w in words), str(e.value)


def test_a_particle_file_does_not_move(tmp_path):
    path = tmp_path / "g.npz"
    motes.save_particles(path, motes.ParticleSet(np.zeros((3, 3)), np.full(3, 50.0), np.zeros(3, dtype=np.int64)))
    with pytest.raises(Exception, match="one file per frame"):
        medium(filename=str(path), velocity=mi.ScalarVector3f(1, 0, 0), time=1.0)


def test_procedural_grains_drift_like_stored_ones():
    """A procedural cloud with turbulence: still the Beer-Lambert mean optical depth of its density (the
    drift is divergence-free), but the grains along a ray have moved (tau changes ray by ray)."""
    kw = dict(count=20000, storage="procedural", radius_median=400.0, query_radius=0.005)
    rest = medium(**kw).data
    moved = medium(**kw, turbulence=0.05, turbulence_scale=0.3, time=2.0).data
    rng = np.random.default_rng(5)
    n = 4000
    o = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.6, 0.6, n), np.full(n, -3.0)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    a, b = rest.optical_depth(o, d, 0.0, 10.0), moved.optical_depth(o, d, 0.0, 10.0)
    assert not np.allclose(a, b)
    # Equal means to a few standard errors of the per-ray scatter.
    se = np.hypot(a.std(), b.std()) / np.sqrt(n)
    assert abs(a.mean() - b.mean()) < 4 * se, (a.mean(), b.mean(), se)
