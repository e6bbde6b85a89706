"""Malformed `discrete` medium parameters become one clear error or warning naming the parameter (issue 11)."""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

import motes
from motes import _memory
from conftest import cube_scene

mi = pytest.importorskip("mitsuba")


def load(**kw):
    motes.set_variant("scalar_rgb")
    d = {"type": "discrete", "phase": {"type": "particle"}}
    if "filename" not in kw:
        d["count"] = 200
    d.update(kw)
    return mi.load_dict(d)


@pytest.mark.parametrize("kw,words", [
    ({"material": "ice", "eta": 1.5}, ["material", "eta"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "materail": "ice"}])}, ["materail", "allowed"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "eta": [1.5]}])}, ["eta", "[n, k]"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "eta": 1.5, "share": "lots"}])}, ["share"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "eta": 1.5, "material": "ice"}])}, ["material", "eta"]),
    ({"to_world": "flat"}, ["to_world", "singular"]),
    ({"phase_model": "rayleigh"}, ["phase_model", "tabulated", "hg"]),
    ({"truncate_below": float("nan")}, ["truncate_below"]),
    ({"truncate_below": 4.0}, ["truncate_below"]),
])
def test_bad_parameters_name_themselves(kw, words):
    motes.set_variant("scalar_rgb")
    if kw.get("to_world") == "flat":
        kw = dict(kw, to_world=mi.ScalarTransform4f().scale([1, 0, 1]))
    with pytest.raises(Exception) as e:
        load(**kw)
    msg = str(e.value)
    assert all(w in msg for w in words), msg


def test_query_radius_as_large_as_the_box_warns():
    with pytest.warns(UserWarning, match="comparable to the particles' extent"):
        load(query_radius=1.5)


def test_query_radius_overridden_by_tau_max_warns():
    """r_c far below the grains' own radius: every disk would be opaque and is widened, which is said."""
    with pytest.warns(UserWarning, match=r"widened.*tau_max"):
        load(query_radius=1e-9)


def test_default_scene_loads_without_warnings():
    """What a user gets from the main job: no warning (a few widened tail grains are not worth one)."""
    import warnings

    motes.set_variant("llvm_ad_rgb")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mi.load_file(str(pathlib.Path(__file__).resolve().parents[1] / "scenes_xml" / "dust_box.xml"))


def test_relative_filename_resolves_against_the_scene_folder(tmp_path):
    motes.set_variant("scalar_rgb")
    sub = tmp_path / "scene"
    sub.mkdir()
    pos = np.random.default_rng(0).uniform(-1, 1, (100, 3))
    motes.save_particles(sub / "grains.npz", motes.ParticleSet(pos, np.full(100, 30.0), np.zeros(100, dtype=np.int64)))
    (sub / "s.xml").write_text('<scene version="3.0.0"><shape type="cube"><bsdf type="null"/>'
                               '<medium type="discrete" name="interior"><string name="filename" value="grains.npz"/>'
                               '<phase type="particle"/></medium></shape></scene>')
    scene = mi.load_file(str(sub / "s.xml"))
    assert len(scene.shapes()[0].interior_medium().data) == 100


def test_houdini_pscale_is_scaled_the_same_both_ways(tmp_path):
    """A PLY whose `pscale` radii are in scene units: load_particles(scale_m) and the plugin (scale_m) agree."""
    meshio = pytest.importorskip("meshio")
    motes.set_variant("scalar_rgb")
    pos = np.random.default_rng(1).uniform(-1, 1, (50, 3))
    path = tmp_path / "houdini.ply"
    meshio.write_points_cells(str(path), pos, [], point_data={"pscale": np.full(50, 3e-4)})
    api = motes.load_particles(path, scale_m=0.01).radii_um
    med = load(filename=str(path), scale_m=0.01, storage="full")
    assert np.allclose(api, 3.0) and np.allclose(med.data.radii_um, api)


def test_implausible_radius_names_the_file(tmp_path):
    meshio = pytest.importorskip("meshio")
    motes.set_variant("scalar_rgb")
    path = tmp_path / "huge.ply"
    meshio.write_points_cells(str(path), np.zeros((3, 3)) + [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [],
                              point_data={"pscale": np.full(3, 3.0)})
    with pytest.raises(RuntimeError, match="huge.ply.*implausible"):
        load(filename=str(path), scale_m=1.0)


def test_radius_median_outside_the_psd_range_names_it():
    with pytest.raises(Exception, match="radius_median"):
        load(radius_median=50000.0)


def test_particle_phase_outside_a_discrete_medium_fails_in_one_sentence():
    motes.set_variant("scalar_rgb")
    scene = cube_scene({"type": "homogeneous", "sigma_t": 1.0, "phase": {"type": "particle"}}, res=4)
    with pytest.raises(Exception) as e:
        mi.render(scene, spp=1)
    chain = []
    err = e.value
    while err is not None:
        chain.append(str(err))
        err = err.__cause__ or err.__context__
    assert any('works only inside a <medium type="discrete">' in c for c in chain), chain


def test_no_aborts_memory_is_estimated_first():
    """Issue 11: inputs that used to abort the process in the Rust allocator raise MemoryError naming the
    input and the estimate (or a ValueError for a range tightened to what is usable)."""
    import subprocess
    import sys

    code = """
import motes
motes.set_variant("scalar_rgb")
import mitsuba as mi
for f in (lambda: motes.LogNormal(10.0, 1.5).sample(10**12),
          lambda: mi.load_dict({"type": "discrete", "count": 10**9, "phase": {"type": "particle"}}),
          lambda: motes.goa_amplitudes(100.0, 0.5, 1.33, [0.1], p_max=1000)):
    try:
        f()
        print("no error")
    except (MemoryError, ValueError, RuntimeError) as e:  # Mitsuba's loader wraps a plugin's error
        print(type(e).__name__, str(e).strip().splitlines()[-1][:200])
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 3 and "no error" not in r.stdout, r.stdout
    assert lines[0].startswith("MemoryError") and "sample(n=1000000000000)" in lines[0]
    assert "MemoryError: discrete medium: count = 1000000000" in lines[1] and "GiB" in lines[1]
    assert lines[2].startswith("ValueError") and "p_max" in lines[2]


def test_memory_estimate_bounds_the_build():
    """The per-particle estimates the memory check uses bound what building a medium really takes (peak
    resident memory in a fresh process, inputs included; Linux /proc), sparse and dense, full and compact
    storage."""
    if not pathlib.Path("/proc/self/clear_refs").exists():
        pytest.skip("needs Linux /proc to reset and read the peak resident size")
    import subprocess
    import sys

    code = """
import numpy as np, motes
from motes import _memory
def status(key):
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith(key))
n = 1_000_000
sp = motes.Species(motes.LogNormal(40.0, 1.5), 1.55)
base = status("VmRSS:")
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # reset the peak (VmHWM) to the current resident size
r = sp.psd.sample(n, seed=1)
pos = np.random.default_rng(0).uniform(-10, 10, (n, 3))
m = motes.DiscreteMedium(pos, r, np.zeros(n, int), sp, motes.RGB_WAVELENGTHS_UM, scale_m=0.01, query_radius=0.03,
                         storage="STORAGE")
extent = float(np.max(pos.max(axis=0) - pos.min(axis=0)))
print((status("VmHWM:") - base) / n, _memory.bytes_per_particle(n, extent, 0.03 + r.max() * 1e-4, "STORAGE"))
"""
    for spread, storage, sparse_full in ((10, "full", True), (1, "full", False), (10, "compact", False),
                                         (1, "compact", False)):
        # Sparse grains (balls narrower than the cells) and a dense cloud (the same grains in a box 1000x
        # smaller), in each storage: each within its own estimate, and the estimate picks the right one.
        src = code.replace("uniform(-10, 10", f"uniform(-{spread}, {spread}").replace("STORAGE", storage)
        r = subprocess.run([sys.executable, "-c", src], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        used, chosen = map(float, r.stdout.split())
        assert chosen == (_memory.BYTES_PER_PARTICLE if sparse_full else _memory.BYTES_PER_PARTICLE_DENSE)
        assert 50 <= used <= chosen, (spread, storage, used, chosen)


def _cube_scene(integrator: str) -> dict:
    return {"type": "scene", "integrator": {"type": integrator},
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "interior": {"type": "discrete", "count": 100, "phase": {"type": "particle"}}}}


def test_prbvolpath_warns_that_it_is_unsupported():
    import warnings

    motes.set_variant("llvm_ad_rgb")
    with pytest.warns(RuntimeWarning, match="prbvolpath does not support the discrete medium"):
        mi.render(mi.load_dict(_cube_scene("prbvolpath")), spp=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mi.render(mi.load_dict(_cube_scene("volpath")), spp=1)


def test_negative_truncate_below_is_the_default():
    """A scene parameter can ask for the default truncation (the gallery's cornell scene does)."""
    a, b, none = load(truncate_below=-1.0), load(), load(truncate_below=0.0)
    assert np.array_equal(a.data.bin_q_ext, b.data.bin_q_ext)
    assert not np.array_equal(a.data.bin_q_ext, none.data.bin_q_ext)  # truncation changes what the grains remove


def test_phase_model_hg_keeps_g_and_is_henyey_greenstein():
    """phase_model = hg: each bin's table is Henyey-Greenstein (formula written here) with the g of the
    tabulated phase function it replaces; extinction and albedo unchanged."""
    from motes.discrete import _BinTables
    from motes.ensemble import Species
    from motes.psd import LogNormal

    lam = np.array([0.467, 0.532, 0.630])
    sp = Species(LogNormal(300.0, 1.3), complex(1.31, 0.0))
    tab, hg = (_BinTables(lam, np.arange(3), 1.0, "auto", 0.003, None, m) for m in ("tabulated", "hg"))
    for t in (tab, hg):
        t.add(0, sp, 250.0, 350.0)
    assert tab.grey_q == hg.grey_q and np.array_equal(tab.albedos[0], hg.albedos[0])
    for theta, f_tab, f_hg in zip(tab.theta, tab.f, hg.f):
        w = motes._motes.PhaseTable(theta, f_tab)
        g = w.mean_cosine()
        assert 0.5 < g < 1.0
        mu = np.cos(theta)
        expect = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)
        np.testing.assert_allclose(f_hg, expect, rtol=1e-12)
        assert abs(motes._motes.PhaseTable(theta, f_hg).mean_cosine() - g) < 2e-3
    with pytest.raises(ValueError, match="phase_model"):
        _BinTables(lam, np.arange(3), 1.0, "auto", 0.003, None, "HG")


@pytest.mark.parametrize("g", [-0.99, -0.3, 0.0, 0.5, 0.9, 0.99])
def test_henyey_greenstein_is_normalised(g):
    theta = np.linspace(0.0, np.pi, 200001)
    f = motes._motes.henyey_greenstein(g, theta)
    integrand = 2 * np.pi * f * np.sin(theta)
    assert abs(np.trapezoid(integrand, theta) - 1.0) < 1e-3
    for bad in (1.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="g"):
            motes._motes.henyey_greenstein(bad, theta)
