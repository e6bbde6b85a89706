"""What a Mitsuba user meets first (issue 11): import order, threads, package metadata."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
import weakref
import tomllib
import pathlib

import numpy as np
import pytest

import motes
from conftest import cube_scene

mi = pytest.importorskip("mitsuba")
ROOT = pathlib.Path(__file__).resolve().parent.parent


def small_scene():
    # An explicit to_world: the medium is built with the scene (a medium that fills its holders is built after it
    # loads, and its native medium's str() in scalar variants keeps saying so).
    return cube_scene({"type": "discrete", "count": 300, "phase": {"type": "particle"},
                       "to_world": mi.ScalarTransform4f()})


def test_mitsuba_variant_first_then_import_motes():
    """`mi.set_variant(...)` then `import motes` (the README's second form) renders in a fresh process."""
    code = textwrap.dedent("""
        import os
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
        import mitsuba as mi
        mi.set_variant("llvm_ad_rgb")
        import motes
        scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpath"},
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}},
            "env": {"type": "constant"},
            "cube": {"type": "cube", "to_world": mi.ScalarTransform4f().translate([0, 0, 4]),
                     "bsdf": {"type": "null"},
                     "interior": {"type": "discrete", "count": 300, "phase": {"type": "particle"}}}})
        import numpy as np
        print("mean", float(np.mean(mi.render(scene, spp=2))))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "mean" in out.stdout


def test_native_render_is_deterministic_and_works_from_a_thread():
    """The native path (Mitsuba's symbolic mode) needs no per-thread switch: a render from another thread
    works, and a render is a function of (scene, seed, spp): the same seed gives the same image up to
    float rounding of the film's sums, from any thread: free flights hash the ray, no call counters."""
    motes.set_variant("llvm_ad_rgb")
    if "llvm_ad_rgb" not in motes.native_variants():
        pytest.skip(f"native path unavailable: {motes.native.failure()}")
    motes.set_evaluated_mode(False)
    scene = small_scene()
    first = np.asarray(mi.render(scene, spp=4, seed=3))
    again = np.asarray(mi.render(scene, spp=4, seed=3))
    other = np.asarray(mi.render(scene, spp=4, seed=4))
    out = []
    t = threading.Thread(target=lambda: out.append(np.asarray(mi.render(scene, spp=4, seed=3))))
    t.start()
    t.join()
    # Equal up to the rounding of the film's parallel sums (Mitsuba accumulates samples atomically, in
    # thread order): a different free flight would change pixels by far more.
    assert np.allclose(first, again, rtol=1e-5, atol=0)
    assert len(out) == 1 and np.allclose(first, out[0], rtol=1e-5, atol=0)
    assert not np.allclose(first, other, rtol=1e-3, atol=0)


def _cpu_flags() -> set[str]:
    try:
        text = pathlib.Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    return {f for line in text.splitlines() if line.startswith("flags") for f in line.split(":", 1)[1].split()}


def _render_with_simd(tmp_path, simd: str, medium: str, seeds=(5,), spp: int = 16) -> tuple[np.ndarray, str]:
    """A cube of grains rendered in a fresh process under MOTES_SIMD=`simd`, once per sampler seed: the images
    (stacked) and the walk the process took."""
    code = textwrap.dedent(f"""
        import numpy as np, motes, mitsuba as mi, sys
        sys.path.insert(0, {str(ROOT / "tests")!r})
        motes.set_variant("llvm_ad_rgb")
        from conftest import cube_scene
        scene = cube_scene({medium}, res=24)
        np.save(sys.argv[1], np.stack([np.asarray(mi.render(scene, spp={spp}, seed=s)) for s in {list(seeds)!r}]))
        print(motes.native.simd())
    """)
    path = tmp_path / f"{simd}.npy"
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=600,
                         env=dict(os.environ, MOTES_SIMD=simd))
    assert out.returncode == 0, out.stderr[-2000:]
    return np.load(path), out.stdout.split()[-1]


def test_sse_and_avx2_walks_render_the_same_image(tmp_path):
    """MOTES_SIMD=sse forces the SSE walk that CPUs without AVX2 run: it renders the same image as the
    AVX2 walk (the same hits in the same order; equal up to the film's parallel float sums).
    MOTES_SIMD=avx2 stops there (no AVX-512 lockstep of the field's free flights, whose exponentials
    differ: the next test)."""
    if not {"avx2", "fma"} <= _cpu_flags():
        pytest.skip("no AVX2 + FMA on this CPU: both runs would take the SSE walk")
    medium = '{"type": "discrete", "count": 3000, "phase": {"type": "particle"}}'
    images = []
    for simd in ("sse", "avx2"):
        image, walk = _render_with_simd(tmp_path, simd, medium)
        assert walk == simd
        images.append(image[0])
    assert images[0].mean() > 0
    assert np.allclose(images[0], images[1], rtol=1e-5, atol=0)


def test_lockstep_field_flights_render_the_same_image_in_distribution(tmp_path):
    """On CPUs with AVX-512 (F, DQ, VL) a packet's free flights through the grains' continuous equivalent
    step together in SIMD lanes, with their own logarithm (`render/continuous/lockstep.rs`,
    `sample_free_flights`; the Rust test `packet_free_flights_match_one_ray_at_a_time` shows the same
    hits ray by ray from the same exponentials). Against one ray at a time (MOTES_SIMD=avx2) the image
    of a cube of grey grains dense enough that paths scatter many times in the field agrees in its mean
    within 5 SE (paired by seed, eight seeds each: a false alarm once in ~600 runs)."""
    if not {"avx512f", "avx512dq", "avx512vl"} <= _cpu_flags():
        pytest.skip("no AVX-512 F/DQ/VL on this CPU: field flights go one ray at a time")
    # Optical depth ~25 across, grey grains (albedo 0.8): the image depends on how far paths fly.
    medium = ('{"type": "discrete", "count": 40000, "radius_median": 200.0, "radius_sigma_g": 1.2, '
              '"scale_m": 0.01, "albedo": 0.8, "phase": {"type": "particle"}}')
    means = {simd: _render_with_simd(tmp_path, simd, medium, seeds=range(8), spp=32)[0].mean(axis=(1, 2, 3))
             for simd in ("avx2", "auto")}
    a, b = means["avx2"], means["auto"]
    assert a.mean() > 0 and not np.array_equal(a, b)  # the two modes draw different exponentials
    # Paired by seed (the camera rays' first events are the same in both): the difference's own spread.
    d = b - a
    assert abs(d.mean()) < 5 * d.std(ddof=1) / np.sqrt(d.size) + 1e-3 * a.mean(), (a, b)


def test_evaluated_path_from_a_thread_fails_with_one_sentence():
    """Without the native path (MOTES_NATIVE=0) the plugins need Dr.Jit's evaluated mode, whose flags are
    per thread: a render from a thread that did not switch fails with motes' one-sentence instruction,
    and works once the thread calls set_evaluated_mode."""
    code = textwrap.dedent("""
        import os, threading
        os.environ["MOTES_NATIVE"] = "0"
        import numpy as np
        import motes, mitsuba as mi
        motes.set_variant("llvm_ad_rgb")
        assert not motes.native_variants()
        scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpath"},
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8},
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])},
            "env": {"type": "constant"},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "interior": {"type": "discrete", "count": 300, "phase": {"type": "particle"}}}})
        errors, means = [], []
        def work(switch):
            try:
                if switch:
                    motes.set_evaluated_mode()
                means.append(float(np.mean(mi.render(scene, spp=2))))
            except Exception as e:
                while e.__cause__ is not None:
                    e = e.__cause__
                errors.append(str(e))
        for switch in (False, True):
            t = threading.Thread(target=work, args=(switch,))
            t.start()
            t.join()
        print("errors", len(errors), "motes.set_evaluated_mode()" in (errors or [""])[0], "means", len(means), np.isfinite(means).all())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "errors 1 True means 1 True" in out.stdout, out.stdout + out.stderr[-2000:]


def test_native_plugin_built_for_another_mitsuba_is_refused_in_one_sentence(tmp_path):
    """A native plugin whose recorded Mitsuba version differs from the running one is not loaded: build()
    raises NativeBuildError naming both versions and the fix (here a copy of the real plugin is put where a
    faked Mitsuba version would look for it)."""
    code = textwrap.dedent(f"""
        import os, pathlib, shutil
        import motes.native as n
        real = n.build() / "plugins" / "motes_native.so"
        os.environ["MOTES_CACHE_DIR"] = {str(tmp_path)!r}
        mi_v, dr_v = n._versions()
        n._versions = lambda: ("0.0.0", dr_v)
        fake = n._cache_root() / n._key() / "plugins"
        fake.mkdir(parents=True)
        shutil.copy(real, fake / "motes_native.so")
        try:
            n.build()
            print("loaded")
        except n.NativeBuildError as e:
            print("refused:", e)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    line = out.stdout.strip()
    assert line.startswith("refused:"), line
    assert f"built for Mitsuba {mi.__version__}, this is Mitsuba 0.0.0" in line, line
    assert "build(force=True)" in line and line.count("\n") == 0, line


def test_package_metadata():
    """`pip install .` alone gives a working plugin: Mitsuba and Dr.Jit are runtime dependencies, the
    licence file exists, and the plugins are declared under Mitsuba's entry-point group."""
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = [d.split(">")[0].split("=")[0].split("<")[0].strip() for d in meta["dependencies"]]
    assert "mitsuba" in names and "drjit" in names
    assert (ROOT / meta["license"]["file"]).is_file()
    assert meta["entry-points"]["mitsuba"]["motes"] == "motes"



def test_scalar_scene_medium_is_the_native_plugin():
    """In scalar_rgb the scene's medium is the native C++ medium itself (no Python call per ray), and it
    still answers what the Python plugin answers: .data, .stats, str(); other media have no .data; the
    data is freed with the scene (the native plugin holds the only references left)."""
    import gc

    from motes import _motes

    motes.set_variant("scalar_rgb")
    if "scalar_rgb" not in motes.native_variants():
        pytest.skip(f"native path unavailable: {motes.native.failure()}")
    from motes.plugins.discrete_medium import plugin_class

    scene = small_scene()
    med = scene.shapes()[0].interior_medium()
    assert not isinstance(med, plugin_class())
    assert len(med.data) == 300 and str(med).startswith("DiscreteMedium[particles=300")
    assert str(med.phase_function()).startswith("ParticlePhase[")
    img = np.asarray(mi.render(scene, spp=4))
    assert np.isfinite(img).all() and img.mean() > 0
    assert med.stats["rays"] > med.stats["events"] > 0
    assert not hasattr(mi.load_dict({"type": "homogeneous"}), "data")
    core, data = med.data.core, weakref.ref(med.data)
    assert core.native_references == 2  # the medium and its phase function
    del med, scene, img
    gc.collect()
    assert core.native_references == 0 and data() is None  # freed with the scene, not at a later call
    assert _motes.native_owner(12345) is None  # an unknown handle is never dereferenced


def test_scalar_native_medium_keeps_its_id_and_leaves_other_media_alone():
    """The native medium a scalar scene holds keeps the XML id (so mi.traverse keys and <ref> stay the
    user's names), and the .data accessor on mi.Medium does not stop a Python medium from setting its
    own .data."""
    motes.set_variant("scalar_rgb")
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath"}, "env": {"type": "constant"},
        "smoke": {"type": "discrete", "count": 300, "phase": {"type": "particle"}},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "smoke"}}})
    assert scene.shapes()[0].interior_medium().id() == "smoke"
    assert "smoke.albedo_scale" in mi.traverse(scene).keys()

    class Mine(mi.Medium):
        def __init__(self, props):
            mi.Medium.__init__(self, props)
            self.data = "mine"

    assert Mine(mi.Properties()).data == "mine"

@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb"])
def test_albedo_scale_is_a_scene_parameter(variant):
    """mi.traverse lists the medium's albedo_scale (issue 12.1); setting it between renders acts like
    loading the scene with that albedo, and setting it back restores the image exactly."""
    motes.set_variant(variant)

    def scene(**medium):
        return mi.load_dict({
            "type": "scene", "integrator": {"type": "volpath", "max_depth": 8},
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 16, "height": 16},
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])},
            "env": {"type": "constant"},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "interior": {"type": "discrete", "count": 20000, "radius_median": 40.0, "albedo": 0.9,
                                  "phase": {"type": "particle"}, **medium}}})

    s = scene()
    params = mi.traverse(s)
    key = next(k for k in params.keys() if k.endswith("interior_medium.albedo_scale"))
    full = np.asarray(mi.render(s, spp=16, seed=2))
    params[key] = mi.TensorXf(np.array([0.5], dtype=np.float32))
    params.update()
    half = np.asarray(mi.render(s, spp=16, seed=2))
    loaded_half = np.asarray(mi.render(scene(albedo=0.45), spp=16, seed=2))
    params[key] = mi.TensorXf(np.array([1.0], dtype=np.float32))
    params.update()
    again = np.asarray(mi.render(s, spp=16, seed=2))
    assert half.mean() < 0.9 * full.mean()  # the cloud darkens the background when its grains absorb
    assert abs(half.mean() - loaded_half.mean()) < 0.02 * loaded_half.mean()
    if variant.startswith("llvm"):
        # A native LLVM render is a function of (scene, seed, spp), up to the film's float rounding.
        assert np.allclose(full, again, rtol=1e-5, atol=0)
    else:
        # Scalar variants keep events per render thread, and which thread renders which block (so which
        # events a full map evicts) follows the schedule: back to within noise, not bit for bit (one
        # clean-clone CI run differed). Events of an older albedo are dropped (DiscreteMedium epoch).
        assert abs(again.mean() - full.mean()) < 0.01 * full.mean()
    with pytest.raises(ValueError, match="albedo_scale"):
        params[key] = mi.TensorXf(np.array([2.0], dtype=np.float32))
        params.update()
    assert float(np.asarray(mi.traverse(s)[key]).ravel()[0]) == 1.0  # back to the value in use


def test_readme_psd_and_species_examples_load():
    """Every PSD example in the README's table parses, and its species example loads as a medium."""
    import re

    text = (ROOT / "README.md").read_text()
    rows = [ln for ln in text.splitlines() if ln.startswith("| `") and '{"type"' in ln]
    examples = [re.findall(r"`(\{.*\})`", ln)[-1] for ln in rows]
    assert len(examples) >= 6
    for spec in examples:
        assert motes.psd.from_spec(spec).support()[1] > 0
    species = re.search(r"`(\[\{\"psd\".*\}\])`", text).group(1)
    motes.set_variant("scalar_rgb")
    assert len(mi.load_dict({"type": "discrete", "count": 300, "species": species,
                             "phase": {"type": "particle"}}).data) == 300
