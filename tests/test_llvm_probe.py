"""A libLLVM that loads but cannot compile must never reach a render (issue 23.2).

Debian 12's libLLVM-15 loads into Dr.Jit 1.5 and then aborts the process on Mitsuba's first kernel with pages of
LLVM dump; libLLVM-14 is refused at load. These tests run motes in subprocesses against the real old libraries
when they are installed (skipped otherwise), with ``MOTES_LLVM_SEARCH`` standing for a machine that has only
those, and a private probe cache (``MOTES_CACHE_DIR``).
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import textwrap

import pytest

from motes.plugins import llvm

LIB = pathlib.Path("/usr/lib/x86_64-linux-gnu")
OLD = [str(LIB / f"libLLVM-{v}.so") for v in (15, 14) if (LIB / f"libLLVM-{v}.so").exists()]
GOOD = next((p for p in (str(LIB / "libLLVM-19.so"), str(LIB / "libLLVM.so.19.1")) if os.path.exists(p)), None)
needs_old = pytest.mark.skipif(not OLD, reason="no old libLLVM (Debian 12's libllvm14/15) installed here")
needs_19 = pytest.mark.skipif(GOOD is None, reason="libLLVM 19 is not installed here")
DUMP_MARKS = ("In function: drjit_", "LLVM ERROR", "Stack dump", "TargetConstantPool")


def share_native_build(cache: pathlib.Path) -> None:
    """Point ``cache/native`` at the test session's ``native`` folder. The probe cache stays private; the native
    plugin (``motes.native``: ``<cache>/native/<key>/``, keyed by its C++ source, the Mitsuba and Dr.Jit
    versions and the compiler flags, and built without libLLVM) is compiled once per session instead of once
    per subprocess that sets a variant (~20 s each: 5 of the tests here)."""
    session = os.environ.get("MOTES_CACHE_DIR")
    link = cache / "native"
    if not session or link.exists() or link.is_symlink() or pathlib.Path(session).resolve() == cache.resolve():
        return
    target = pathlib.Path(session) / "native"
    target.mkdir(parents=True, exist_ok=True)
    link.symlink_to(target, target_is_directory=True)


def run(code_or_args, cache: pathlib.Path, **env):
    share_native_build(cache)
    full = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "MOTES_LLVM_SEARCH")}
    full.update(env, MOTES_CACHE_DIR=str(cache))
    args = code_or_args if isinstance(code_or_args, list) else [sys.executable, "-c", textwrap.dedent(code_or_args)]
    return subprocess.run(args, env=full, capture_output=True, text=True, timeout=600, cwd=cache)


def motes_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if "libllvm19" in ln or "DRJIT_LIBLLVM_PATH" in ln]


def test_candidates_put_19_first_then_newest(tmp_path, monkeypatch):
    names = ["libLLVM-14.so", "libLLVM-19.so", "libLLVM-17.so", "libLLVM.so.20.1", "libLLVM-15.so"]
    for n in names:
        (tmp_path / n).write_bytes(b"x")
    monkeypatch.setenv("MOTES_LLVM_SEARCH", os.pathsep.join(str(tmp_path / n) for n in names + ["missing.so"]))
    assert [os.path.basename(p) for p in llvm.candidates()] == [
        "libLLVM-19.so", "libLLVM.so.20.1", "libLLVM-17.so", "libLLVM-15.so", "libLLVM-14.so"]
    assert llvm.major_version("/usr/lib/llvm-18/lib/libLLVM.so") == 18


def test_a_file_that_is_no_library_fails_the_probe_and_the_verdict_is_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("MOTES_CACHE_DIR", str(tmp_path))
    fake = tmp_path / "libLLVM-99.so"
    fake.write_bytes(b"not a shared object")
    verdict = llvm.probe(str(fake))
    assert verdict["ok"] is False and verdict["reason"]
    cache = json.loads((tmp_path / "llvm-probe.json").read_text())
    (key,) = cache
    assert key.startswith(str(fake.resolve())) and "drjit" in key and cache[key]["ok"] is False


@needs_old
def test_only_old_libllvms_render_falls_back_to_scalar_with_one_line(tmp_path):
    """The issue's machine: only libLLVM-14/15. `motes render` finishes in scalar_rgb with one line naming
    the fix, and no LLVM dump."""
    r = run([sys.executable, "-m", "motes", "render", "dust_box", "-D", "spp=2", "-D", "res=16", "-o",
             str(tmp_path / "out.exr")], tmp_path, MOTES_LLVM_SEARCH=os.pathsep.join(OLD))
    assert r.returncode == 0, r.stderr[-3000:]
    assert not any(m in r.stderr + r.stdout for m in DUMP_MARKS), r.stderr[-3000:]
    lines = motes_lines(r.stderr)
    assert len(lines) == 1 and "scalar_rgb" in lines[0] and "apt-get install libllvm19" in lines[0], r.stderr
    assert (tmp_path / "out.exr").exists()


@needs_old
def test_drjit_libllvm_path_at_an_old_library_never_aborts(tmp_path):
    """DRJIT_LIBLLVM_PATH pointing at libLLVM-15 (or 14) with nothing better installed: a clean fallback."""
    r = run("""
        import motes, mitsuba as mi
        variant = motes.set_variant("llvm_ad_rgb")
        scene = mi.load_dict(mi.cornell_box())
        print("variant", variant, float(mi.render(scene, spp=1).numpy().mean()) >= 0)
        """, tmp_path, DRJIT_LIBLLVM_PATH=OLD[0], MOTES_LLVM_SEARCH=os.pathsep.join(OLD))
    assert r.returncode == 0, r.stderr[-3000:]
    assert "variant scalar_rgb True" in r.stdout
    assert not any(m in r.stderr for m in DUMP_MARKS)
    assert len(motes_lines(r.stderr)) == 1, r.stderr


@needs_old
def test_drjit_loaded_before_motes_with_an_old_library_falls_back(tmp_path):
    """Dr.Jit imported first (its libLLVM already chosen): motes probes the library it loaded."""
    r = run("""
        import drjit, mitsuba as mi
        import motes
        print("variant", motes.set_variant("llvm_ad_rgb"))
        """, tmp_path, DRJIT_LIBLLVM_PATH=OLD[0], MOTES_LLVM_SEARCH=os.pathsep.join(OLD))
    assert r.returncode == 0, r.stderr[-3000:]
    assert "variant scalar_rgb" in r.stdout
    assert not any(m in r.stderr for m in DUMP_MARKS)


@needs_old
@needs_19
def test_a_bad_drjit_libllvm_path_is_replaced_by_one_that_works(tmp_path):
    r = run("""
        import os, motes
        print("variant", motes.set_variant("llvm_ad_rgb"), os.environ["DRJIT_LIBLLVM_PATH"])
        """, tmp_path, DRJIT_LIBLLVM_PATH=OLD[0], MOTES_LLVM_SEARCH=os.pathsep.join(OLD + [GOOD]))
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"variant llvm_ad_rgb {GOOD}" in r.stdout
    lines = motes_lines(r.stderr)
    assert len(lines) == 1 and OLD[0] in lines[0] and GOOD in lines[0], r.stderr


@needs_19
def test_a_cached_verdict_is_used_without_probing_again(tmp_path):
    """A cached 'fails' for the only candidate is believed (no subprocess): the LLVM variant falls back. This
    also shows the cache key: real path, size, mtime, versions, CPU."""
    cache = tmp_path / "llvm-probe.json"
    r = run("""
        from motes.plugins import llvm
        print("KEY", llvm._key(llvm.candidates()[0]))
        """, tmp_path, MOTES_LLVM_SEARCH=GOOD)
    key = r.stdout.split("KEY ", 1)[1].strip()
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({key: {"ok": False, "reason": "marked bad by the test"}}))
    r = run("""
        import motes
        print("variant", motes.set_variant("llvm_ad_rgb"))
        """, tmp_path, MOTES_LLVM_SEARCH=GOOD)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "variant scalar_rgb" in r.stdout and "marked bad by the test" in r.stderr
