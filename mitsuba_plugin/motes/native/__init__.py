"""The native render path: ``motes_native.cpp``, a thin C++ Mitsuba plugin over the Rust core that runs
inside Mitsuba's default *symbolic* LLVM kernels (and per ray in the scalar variants).

It is compiled against the Mitsuba and Dr.Jit wheels installed next to motes, once per (source, Mitsuba
version, Dr.Jit version), into ``<cache>/native/<key>/plugins/`` (``$MOTES_CACHE_DIR`` or
``~/.cache/motes``; the README's set-up command builds it, otherwise the first render does, ~20 s). It
needs ``g++`` (``$CXX``) and the nanobind 2.9 headers (a dependency of motes). ``motes.set_variant`` /
``import motes`` use it for ``scalar_rgb``, ``scalar_spectral``, ``llvm_ad_rgb``, ``llvm_ad_spectral`` and
the polarised variants ``scalar_spectral_polarized``, ``llvm_ad_spectral_polarized`` and
``llvm_ad_mono_polarized`` unless ``MOTES_NATIVE=0``; elsewhere, or when it cannot be built (a warning says why), the plugins fall
back to the evaluated-mode Python path, which needs Dr.Jit's evaluated ("wavefront") mode.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

from .. import _env

#: Variants the native library is built for.
NATIVE_VARIANTS = ("scalar_rgb", "scalar_spectral", "llvm_ad_rgb", "llvm_ad_spectral", "scalar_spectral_polarized",
                   "llvm_ad_spectral_polarized", "llvm_ad_mono_polarized")
#: Plugin names it registers (one library, one symlink per name).
PLUGIN_NAMES = ("motes_discrete_native", "motes_particle_native", "motes_tabphase_polarized")
SOURCE = pathlib.Path(__file__).with_name("motes_native.cpp")
#: The wheels are built for AVX2/FMA/F16C/BMI; Dr.Jit lays out small static arrays (a scalar Color3f) as
#: SIMD packets when these are on, so the plugin must be compiled with the same flags or scalar variants
#: disagree with libmitsuba about those types' layout (their native renders would then depart from the Python
#: path's, which ``tests/test_render_paths.py`` compares in scalar_rgb and scalar_spectral).
ISA_FLAGS = ("-mavx2", "-mfma", "-mf16c", "-mbmi", "-mbmi2")
CXX_FLAGS = ("-std=c++17", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-DNDEBUG") + ISA_FLAGS

_folder: pathlib.Path | None = None
_failure: str | None = None
_library: ctypes.CDLL | None = None
#: Variants ``load`` made the native plugins findable for (``motes.native_variants()``).
_loaded: set[str] = set()


class NativeBuildError(RuntimeError):
    """The native plugin could not be compiled (the message says what is missing)."""


def requested() -> bool:
    """Whether the native path is wanted (``MOTES_NATIVE=0`` turns it off; ``motes._env``)."""
    return _env.native_requested()


def _versions() -> tuple[str, str]:
    import drjit
    import mitsuba

    return mitsuba.__version__, drjit.__version__


def _key() -> str:
    mi_v, dr_v = _versions()
    h = hashlib.sha256(SOURCE.read_bytes())
    h.update(f"{mi_v}|{dr_v}|{' '.join(CXX_FLAGS)}|{sys.platform}".encode())
    return h.hexdigest()[:16]


def _cache_root() -> pathlib.Path:
    base = _env.cache_dir() or _env.default_cache_dir()  # MOTES_CACHE_DIR="" keeps the default here
    return base / "native"


def _command(out: pathlib.Path) -> list[str]:
    import mitsuba

    try:
        import nanobind
    except ImportError:
        raise NativeBuildError("the nanobind headers are missing (pip install 'nanobind>=2.9,<2.10')") from None
    site = pathlib.Path(mitsuba.__file__).parent.parent
    cxx = os.environ.get("CXX", "g++")
    if shutil.which(cxx) is None:
        raise NativeBuildError(f"no C++ compiler '{cxx}' on PATH (apt-get install g++)")
    return [cxx, *CXX_FLAGS, f"-I{site / 'mitsuba' / 'include'}", f"-I{site / 'drjit' / 'include'}",
            f"-I{nanobind.include_dir()}", str(SOURCE), "-o", str(out), f"-L{site / 'mitsuba'}", f"-L{site / 'drjit'}",
            "-lmitsuba", "-ldrjit-core", "-ldrjit-extra", "-lnanothread",
            f"-Wl,-rpath,{site / 'mitsuba'}", f"-Wl,-rpath,{site / 'drjit'}"]


def build(force: bool = False, verbose: bool = False) -> pathlib.Path:
    """Compile the native plugins if needed; returns the folder to prepend to Mitsuba's file resolver
    (it holds ``plugins/<name>.so``). Raises ``NativeBuildError`` with the reason."""
    folder = _cache_root() / _key()
    lib = folder / "plugins" / "motes_native.so"
    if force or not lib.exists():
        (folder / "plugins").mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            out = pathlib.Path(tmp) / "motes_native.so"
            cmd = _command(out)
            if verbose:
                print("motes: compiling the native plugin:", " ".join(cmd), file=sys.stderr, flush=True)
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                tail = "\n".join(res.stderr.strip().splitlines()[-15:])
                raise NativeBuildError(f"compiling {SOURCE.name} failed:\n{tail}")
            os.replace(out, lib)  # atomic: a concurrent build never sees half a library
    for name in PLUGIN_NAMES:
        link = folder / "plugins" / f"{name}.so"
        if not link.is_symlink():
            try:
                link.symlink_to("motes_native.so")
            except FileExistsError:
                pass
    global _library
    library = ctypes.CDLL(str(lib))
    built_for = library.motes_native_mitsuba_version
    built_for.restype = ctypes.c_char_p
    mi_v, _ = _versions()
    if built_for().decode() != mi_v:
        raise NativeBuildError(f"{lib} was built for Mitsuba {built_for().decode()}, this is Mitsuba {mi_v}: "
                               "delete it or call motes.native.build(force=True)")
    library.motes_native_medium_handle.restype = ctypes.c_void_p
    library.motes_native_medium_handle.argtypes = [ctypes.c_void_p]
    library.motes_native_set_clips_rays.restype = ctypes.c_int
    library.motes_native_set_clips_rays.argtypes = [ctypes.c_void_p, ctypes.c_int]
    library.motes_native_set_description.restype = ctypes.c_int
    library.motes_native_set_description.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
    _library = library
    return folder


def folder() -> pathlib.Path | None:
    """The built plugin folder (building it on first use), or None when the native path is off or cannot
    be built (``failure()`` says why)."""
    global _folder, _failure
    if _folder is None and _failure is None:
        if not requested():
            _failure = "MOTES_NATIVE=0"
        else:
            try:
                _folder = build()
            except (NativeBuildError, OSError, AttributeError) as e:
                _failure = str(e)
    return _folder


def medium_handle(obj) -> int | None:
    """The core medium handle of a native ``discrete`` medium object (a Mitsuba object), or None for any other
    object (or when the native library is not loaded)."""
    import mitsuba as mi

    if _library is None or not isinstance(obj, mi.Object):
        return None
    ptr = obj.ptr
    return _library.motes_native_medium_handle(ptr) or None


def set_clips_rays(obj, on: bool) -> bool:
    """Let Mitsuba's integrators clip a ray at the site a native ``discrete`` medium object returns (its
    ``is_homogeneous`` flag; ``motes.plugins.enclosure``): True if ``obj`` is one (else nothing changes)."""
    import mitsuba as mi

    if _library is None or not isinstance(obj, mi.Object):
        return False
    return bool(_library.motes_native_set_clips_rays(obj.ptr, int(bool(on))))


def set_description(obj, text: str) -> bool:
    """What a native ``discrete`` medium object's ``str()`` reports from now on (a medium that fills its holders
    learns its particles after it was made): True if ``obj`` is one (else nothing changes)."""
    import mitsuba as mi

    if _library is None or not isinstance(obj, mi.Object):
        return False
    return bool(_library.motes_native_set_description(obj.ptr, text.encode()))


def simd() -> str:
    """The particle walk the core runs on this CPU: ``"avx2"`` (AVX2 + FMA, eight spheres per pre-test) or
    ``"sse"`` (CPUs without them, or ``MOTES_SIMD=sse``); both find the same particles."""
    from motes import _motes

    return _motes.simd_walk()


def failure() -> str | None:
    """Why the native path is unavailable (None when it is available or not yet tried)."""
    return _failure


def available(variant: str) -> bool:
    """Whether ``variant`` renders through the native path (building the library if needed)."""
    return variant in NATIVE_VARIANTS and folder() is not None


def load(variant: str) -> bool:
    """Make Mitsuba find the native plugins (file resolver) for ``variant``; False when unavailable."""
    if not available(variant):
        return False
    import mitsuba as mi

    path = str(folder())
    fr = mi.file_resolver()
    if path not in [str(p) for p in fr]:
        fr.prepend(path)
    _loaded.add(variant)
    return True


def loaded_variants() -> frozenset[str]:
    """The variants ``load`` has made render through the native path in this process (``motes.native_variants()``);
    the others use the evaluated-mode Python path."""
    return frozenset(_loaded)


__all__ = ["NATIVE_VARIANTS", "NativeBuildError", "available", "build", "failure", "folder", "load", "loaded_variants", "medium_handle", "set_description", "simd",
           "requested"]
