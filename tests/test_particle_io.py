"""Particle-set files (issue 4): round trips in every format, precise errors for bad content, and a bounded
fuzz run — corrupted files only ever raise ValueError naming the file, nothing else escapes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import motes

SUFFIXES = [".npz", ".npy", ".csv", ".ply"]


def _set(n=50, seed=0):
    rng = np.random.default_rng(seed)
    return motes.ParticleSet(rng.random((n, 3)), rng.random(n) * 100 + 1, rng.integers(0, 3, n))


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_round_trip(tmp_path, suffix):
    p = _set()
    path = tmp_path / f"p{suffix}"
    motes.save_particles(path, p)
    q = motes.load_particles(path, n_species=3)
    rtol = 1e-6 if suffix == ".ply" else 0  # meshio writes PLY as float32 unless the data is float64
    np.testing.assert_allclose(q.positions, p.positions, rtol=rtol)
    np.testing.assert_allclose(q.radii_um, p.radii_um, rtol=rtol)
    np.testing.assert_array_equal(q.species, p.species)


def test_ply_ascii_and_houdini_pscale(tmp_path):
    """ASCII PLY with Houdini's pscale (scene units) becomes micrometres through scale_m."""
    path = tmp_path / "h.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                    "property float pscale\nend_header\n0 0 0 0.01\n1 2 3 0.02\n")
    q = motes.load_particles(path, scale_m=0.01)  # 1 unit = 1 cm: pscale 0.01 -> 100 um
    np.testing.assert_allclose(q.radii_um, [100.0, 200.0], rtol=1e-6)
    np.testing.assert_array_equal(q.species, [0, 0])


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("x,y,z,radius_um\n0,0,0,1\n0,nan,0,1\n", r"particle 1: field y"),
        ("x,y,z,radius_um\n0,0,0,1\n0,0,0,-2\n", r"particle 1: field radius"),
        ("x,y,z,radius_um,species\n0,0,0,1,7\n", r"particle 0: field species.*have 3"),
        ("x,y,z,radius_um\n", r"empty"),
        ("x,y,radius_um\n0,0,1\n", r"line 1.*'z'"),
        ("x,y,z,radius_um\n0,0,0,1\n0,0,abc,1\n", r"malformed CSV"),
    ],
)
def test_csv_errors_name_the_element(tmp_path, content, match):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(ValueError, match=match) as exc:
        motes.load_particles(path, n_species=3)
    assert "bad.csv" in str(exc.value)


def test_other_errors(tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        motes.load_particles(tmp_path / "missing.npz")
    with pytest.raises(ValueError, match="unknown particle file type"):
        motes.load_particles(__file__)
    np.savez(tmp_path / "a.npz", positions=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="radii_um"):
        motes.load_particles(tmp_path / "a.npz")
    np.save(tmp_path / "b.npy", np.zeros((3, 2)))
    with pytest.raises(ValueError, match="shape"):
        motes.load_particles(tmp_path / "b.npy")
    (tmp_path / "c.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                                    "property float z\nend_header\n0 0 0\n")
    with pytest.raises(ValueError, match="radius.*pscale"):
        motes.load_particles(tmp_path / "c.ply")


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(suffix=st.sampled_from(SUFFIXES), cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=8))
def test_fuzz_corrupted_files_raise_value_error(tmp_path_factory, suffix, cut, flips):
    """Valid files truncated at a random point and with random bytes overwritten: loading either returns a
    valid set or raises ValueError naming the file — never another exception, never a crash."""
    d = tmp_path_factory.mktemp("fuzz")
    path = d / f"f{suffix}"
    motes.save_particles(path, _set(n=20, seed=1))
    data = bytearray(path.read_bytes())
    data = data[: max(1, int(len(data) * cut))] if cut < 1.0 else data
    for pos, byte in flips:
        data[min(len(data) - 1, int(pos * len(data)))] = byte
    path.write_bytes(bytes(data))
    try:
        p = motes.load_particles(path, n_species=3)
    except ValueError as exc:
        assert path.name in str(exc)
    else:
        assert len(p) > 0 and np.all(np.isfinite(p.positions)) and np.all(p.radii_um > 0)
