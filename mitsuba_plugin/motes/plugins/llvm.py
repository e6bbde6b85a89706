"""Choose a libLLVM that Dr.Jit can really compile with, before Dr.Jit loads.

A libLLVM that loads is not necessarily one Dr.Jit can drive: Debian 12's libLLVM-15 loads, then aborts the
process inside instruction selection on Mitsuba's first kernel with pages of LLVM dump (and libLLVM-14 is
refused). No in-process check can catch an abort, so each candidate is tried once in a **subprocess** that
renders a tiny ``volpath`` + ``homogeneous`` scene in ``llvm_ad_rgb``; the verdict is cached in
``llvm-probe.json`` in motes's cache (``$MOTES_CACHE_DIR``, else ``~/.cache/motes``), keyed by the library's real path, size and
modification time, the Dr.Jit and Mitsuba versions and the CPU's feature flags, so the probe runs once per
machine and library (about a second).

Order of choice (``choose()``, called by ``import motes``):

1. ``DRJIT_LIBLLVM_PATH`` when set and its probe passes;
2. else the installed libLLVMs, 19 first (the version Dr.Jit 1.5 is built and tested against), then the
   others newest first; the first whose probe passes is put into ``DRJIT_LIBLLVM_PATH``;
3. else ``DRJIT_LIBLLVM_PATH`` is pointed at a path that does not exist (``NO_LLVM``), so that Dr.Jit's own
   search cannot pick up the bad library: LLVM variants then fail cleanly with an ``ImportError`` and
   ``motes.set_variant`` falls back to the scalar variant with one warning line naming the fix.

``MOTES_LLVM_SEARCH`` (paths separated by ``os.pathsep``) replaces the list of installed libLLVMs: the tests
use it to stand for a machine that has only old ones.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import subprocess
import sys
import time

from .. import _env

SEARCH_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
                "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*")
PREFERRED_MAJOR = 19
NO_LLVM = "/nonexistent/motes-found-no-usable-libLLVM.so"
FIX = ("install Debian's libllvm19 (apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH to a libLLVM that "
       "works with Dr.Jit")
PROBE_TIMEOUT_S = 180

# Runs in a fresh interpreter with DRJIT_LIBLLVM_PATH set to the candidate; it must not import motes.
PROBE = r"""
import mitsuba as mi, drjit as dr
mi.set_variant("llvm_ad_rgb")
scene = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "volpath", "max_depth": 4},
    "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4},
               "sampler": {"type": "independent", "sample_count": 2}},
    "light": {"type": "constant"},
    "cube": {"type": "cube", "bsdf": {"type": "null"},
             "interior": {"type": "homogeneous", "albedo": 0.8, "sigma_t": 1.0, "phase": {"type": "hg", "g": 0.5}},
             "to_world": mi.ScalarTransform4f().translate([0, 0, -4])},
})
image = mi.render(scene)
value = dr.mean(image, axis=None)
assert dr.all(dr.isfinite(value), axis=None)
print("motes-llvm-probe-ok")
"""

# What choose() found, for set_variant's warning: None when an LLVM that works is in use.
problem: str | None = None
_chosen: list[str | None] = []  # choose()'s answer, once made


def major_version(path: str) -> int:
    """LLVM major version from a library name (libLLVM-15.so, libLLVM.so.19.1, llvm-17/lib/libLLVM.so); 0 if none."""
    m = re.search(r"libLLVM-(\d+)", path) or re.search(r"libLLVM\.so\.(\d+)", path) or re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else 0


def candidates() -> list[str]:
    """Installed libLLVMs, one path per real file: 19 first, then newest first."""
    search = _env.llvm_search()
    paths = search if search is not None else [p for g in SEARCH_GLOBS for p in sorted(glob.glob(g))]
    seen, out = set(), []
    for p in paths:
        if not p or not os.path.isfile(p):
            continue
        real = os.path.realpath(p)
        if real not in seen:
            seen.add(real)
            out.append(p)
    out.sort(key=lambda p: (major_version(p) != PREFERRED_MAJOR, -major_version(p)))
    return out


def _cache_file() -> str | None:
    """``llvm-probe.json`` in motes's cache (``$MOTES_CACHE_DIR``, else ``~/.cache/motes``; ``""`` keeps none)."""
    base = _env.cache_dir()
    return None if base is None else os.path.join(base, "llvm-probe.json")


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return hashlib.sha1(line.encode()).hexdigest()[:12]
    except OSError:
        pass
    return "unknown-cpu"


def _versions() -> str:
    from importlib import metadata

    out = []
    for pkg in ("drjit", "mitsuba"):
        try:
            out.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            out.append(f"{pkg} ?")
    return ", ".join(out)


def _key(path: str) -> str:
    real = os.path.realpath(path)
    st = os.stat(real)
    return f"{real}|{st.st_size}|{st.st_mtime_ns}|{_versions()}|{_cpu_flags()}"


def _load_cache() -> dict:
    if _cache_file() is None:
        return {}
    try:
        with open(_cache_file()) as f:
            data = json.load(f)
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def _store(key: str, verdict: dict) -> None:
    path = _cache_file()
    if path is None:
        return
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        data = _load_cache()
        data[key] = verdict
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            json.dump(data, f, indent=1)
        os.replace(tmp, path)  # atomic: concurrent test processes never read half a file
    except OSError:
        pass  # a read-only home: probe again next time


def probe(path: str) -> dict:
    """``{"ok": bool, "reason": str}`` for Dr.Jit compiling Mitsuba kernels with the libLLVM at ``path``
    (cached; a subprocess on a miss)."""
    if not os.path.isfile(path):
        return {"ok": False, "reason": "no such file"}
    key = _key(path)
    cached = _load_cache().get(key)
    if isinstance(cached, dict) and "ok" in cached:
        return cached
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=path)
    t0 = time.perf_counter()
    try:
        run = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                             timeout=PROBE_TIMEOUT_S)
        ok = run.returncode == 0 and "motes-llvm-probe-ok" in run.stdout
        if ok:
            reason = "compiles"
        elif run.returncode < 0:
            reason = f"a probe kernel crashed the process (signal {-run.returncode})"
        else:
            last = ([ln for ln in run.stderr.strip().splitlines() if ln.strip()][-1:] or ["no output"])[0]
            reason = f"a probe kernel failed ({last.split('!')[0][:120]})"
    except subprocess.TimeoutExpired:
        ok, reason = False, f"the probe took over {PROBE_TIMEOUT_S} s"
    verdict = {"ok": ok, "reason": reason, "seconds": round(time.perf_counter() - t0, 2)}
    _store(key, verdict)
    return verdict


def _quiet_import_drjit() -> None:
    """Import Dr.Jit with file descriptor 2 silenced: with ``NO_LLVM`` it logs two lines about the missing
    library at import, which would say less than motes's one line."""
    sys.stderr.flush()
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        import drjit  # noqa: F401
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def choose() -> str | None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a libLLVM that works (module docs); returns it, or None when there is
    none (``problem`` then says why). Does nothing once Dr.Jit is loaded: its choice is made."""
    global problem
    if _chosen:
        return _chosen[0]
    if "drjit" in sys.modules:
        return os.environ.get("DRJIT_LIBLLVM_PATH")
    _chosen.append(_choose())
    return _chosen[0]


def _choose() -> str | None:
    global problem
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    rejected = []
    if given and given != NO_LLVM:
        verdict = probe(given)
        if verdict["ok"]:
            problem = None
            return given
        rejected.append(f"DRJIT_LIBLLVM_PATH={given}: {verdict['reason']}")
    for path in candidates():
        if given and os.path.realpath(path) == os.path.realpath(given):
            continue
        verdict = probe(path)
        if verdict["ok"]:
            os.environ["DRJIT_LIBLLVM_PATH"] = path
            problem = f"{rejected[0]}; using {path} instead" if rejected else None
            return path
        rejected.append(f"{path}: {verdict['reason']}")
    os.environ["DRJIT_LIBLLVM_PATH"] = NO_LLVM
    found = "; ".join(rejected) if rejected else "no libLLVM is installed"
    problem = f"no libLLVM that Dr.Jit can compile with ({found})"
    _quiet_import_drjit()
    return None


def loaded_library() -> str | None:
    """The libLLVM mapped into this process (Dr.Jit loads it at import), from ``/proc/self/maps``; None
    if none is or the platform has no such file."""
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                path = line.split(maxsplit=5)[-1].strip() if line.count(" ") >= 5 else ""
                if "libLLVM" in os.path.basename(path):
                    return path
    except OSError:
        pass
    return None


def usable() -> bool:
    """Whether the LLVM variants can run in this process (as far as choose() found)."""
    return os.environ.get("DRJIT_LIBLLVM_PATH") != NO_LLVM


__all__ = ["FIX", "NO_LLVM", "candidates", "choose", "loaded_library", "major_version", "probe", "problem", "usable"]
