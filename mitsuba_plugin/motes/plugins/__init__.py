"""Mitsuba 3 plugins of motes: medium ``discrete`` and phase function ``particle``.

``motes.set_variant(name)`` picks a Mitsuba variant and makes it ready for the plugins:

* LLVM variants need a libLLVM that Dr.Jit can compile with, which loading it does not prove (Debian 12's
  libLLVM-15 loads, then aborts the process on the first kernel). ``import motes`` tries each candidate once
  in a subprocess, caches the verdict and points ``DRJIT_LIBLLVM_PATH`` at one that works (``motes.plugins.llvm``;
  it must happen before Dr.Jit loads); without one, a ``llvm_*`` request falls back to the matching
  ``scalar_*`` variant with one warning naming the fix.
* In ``scalar_rgb``, ``scalar_spectral``, ``llvm_ad_rgb`` and ``llvm_ad_spectral`` the plugins render through
  the native C++ plugin (``motes.native``; built on first use), in Mitsuba's default symbolic mode. In the
  other variants (or with ``MOTES_NATIVE=0``, or when it cannot be built: a warning says why) they hand
  numpy batches to Rust, which in LLVM variants needs the evaluated ("wavefront") mode: ``SymbolicLoops``
  and ``SymbolicCalls`` are then switched off on the calling thread. CUDA variants render with
  ``kernel = "drjit"`` (``drjit_medium.py``), Dr.Jit code that runs in Mitsuba's symbolic mode.
* Mitsuba's scene loaders (``mi.load_file``, ``load_dict``, ``load_string``) warn when a ``discrete``
  medium's particles lie mostly outside the shape that holds it (``motes.plugins.scene_checks``).
* The plugins are registered for the variant (registration is per variant; ``register()`` does only that,
  and ``import motes`` calls it when a variant is already set).
"""

from __future__ import annotations

import os
import warnings

from .. import native as _native
from . import llvm as _llvm

_registered: set[str] = set()


def native_variants() -> frozenset[str]:
    """Variants registered with the native render path (``motes.native``); the others use the
    evaluated-mode Python path."""
    return _native.loaded_variants()


def configure_llvm() -> str | None:
    """Point Dr.Jit at a libLLVM it can compile with (``motes.plugins.llvm.choose``); returns the path in use,
    or None when there is none."""
    return _llvm.choose()


def _llvm_problem() -> str | None:
    """Why the LLVM variants cannot run in this process, or None when they can. When Dr.Jit was imported
    before motes, the library it loaded is probed now (cached), so that a bad one is never asked to compile."""
    if not _llvm.usable():
        return _llvm.problem
    loaded = _llvm.loaded_library()
    if loaded is not None:
        verdict = _llvm.probe(loaded)
        if not verdict["ok"]:
            return f"the libLLVM Dr.Jit loaded ({loaded}) cannot compile its kernels: {verdict['reason']}"
    return None


def register() -> None:
    """Register ``discrete`` and ``particle`` for the current Mitsuba variant."""
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise RuntimeError("motes.register(): set a Mitsuba variant first (motes.set_variant(...))")
    if variant not in _registered:
        if not _native.load(variant) and variant in _native.NATIVE_VARIANTS and _native.requested():
            warnings.warn(f"motes: the native render path is unavailable ({_native.failure()}); {variant} renders "
                          "through the slower evaluated-mode Python path", RuntimeWarning, stacklevel=2)
    if variant.startswith("llvm_") and variant not in _native.loaded_variants():
        # The Python path hands numpy batches to Rust: evaluated mode, on this thread (Dr.Jit's flags are
        # per thread; a render from another thread must call motes.set_evaluated_mode() there first).
        set_evaluated_mode(True)
    # Mitsuba may re-import its Python integrators on a variant change: guard the class in use each time.
    _warn_under_prbvolpath()
    from .cameras import wrap_render
    from .scene_checks import wrap_loaders

    wrap_loaders()  # a medium outside its shape warns at load; cameras set (cameras.py)
    wrap_render()  # mi.render sets the cameras again (a camera moved through mi.traverse), and enclosure.py's skips
    if variant in _registered:
        return
    from . import discrete_medium, particle_phase

    medium, phase = discrete_medium.factory(), particle_phase.plugin_class()
    mi.register_medium("discrete", lambda props: medium(props))
    mi.register_phase("particle", lambda props: phase(props))
    _registered.add(variant)


PRBVOLPATH_WARNING = ("motes: prbvolpath does not support the discrete medium (it loses ~4 % of the energy in a "
                      "white furnace: scripts/figures/prbvolpath_check.py); render with volpath or volpathmis")


def _scene_has_discrete_medium(scene) -> bool:
    from ._scene import discrete_media

    return bool(discrete_media(scene))


def _warn_under_prbvolpath() -> None:
    """Make Mitsuba's prbvolpath warn when a scene holds a ``discrete`` medium: it runs but
    is not supported. Its ``sample`` is wrapped once per process (under both names Mitsuba imports the class
    by); other scenes are untouched."""
    import importlib

    for name in ("mitsuba.python.ad.integrators.prbvolpath", "mitsuba.ad.integrators.prbvolpath"):
        try:
            _guard(importlib.import_module(name).PRBVolpathIntegrator)
        except (ImportError, AttributeError):  # not an AD variant, or a Mitsuba without it
            pass


def _guard(cls) -> None:
    if getattr(cls.sample, "_motes_guard", False):
        return
    sample = cls.sample

    def guarded(self, mode, scene, *args, **kwargs):
        # Every render (Python's warning filters show it once per call site by default).
        if _scene_has_discrete_medium(scene):
            warnings.warn(PRBVOLPATH_WARNING, RuntimeWarning, stacklevel=2)
        return sample(self, mode, scene, *args, **kwargs)

    guarded._motes_guard = True
    cls.sample = guarded


def set_evaluated_mode(on: bool = True) -> None:
    """Evaluated ("wavefront") loops and calls in JIT variants (what the plugins need), or back to
    Mitsuba's default symbolic mode."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.SymbolicLoops, not on)
    dr.set_flag(dr.JitFlag.SymbolicCalls, not on)


def set_variant(name: str = "llvm_ad_rgb") -> str:
    """Set the Mitsuba variant ``name`` ready for the plugins (module docs); returns the variant in use."""
    configure_llvm()
    import mitsuba as mi

    if name not in mi.variants():
        raise ValueError(f"unknown Mitsuba variant {name!r}; available: {', '.join(mi.variants())}")
    problem = _llvm_problem() if name.startswith("llvm_") else None
    try:
        if problem is not None:
            raise RuntimeError(problem)  # never hand a kernel to a libLLVM that aborts the process
        mi.set_variant(name)
        if name.startswith("llvm_"):
            import drjit as dr

            dr.eval(mi.Float([1.0, 2.0]) * 2)  # any other failure of the backend shows on the first kernel
    except Exception as e:  # noqa: BLE001 - any failure of the LLVM backend
        if name.startswith("cuda_"):
            reason = " ".join(str(e).split())
            raise RuntimeError(f"{name} needs an NVIDIA GPU and its CUDA driver, which Dr.Jit did not find here "
                               f"({reason}); render in {name.replace('cuda_', 'llvm_', 1)} on the CPU "
                               "instead") from None
        if not name.startswith("llvm_"):
            raise
        fallback = "scalar_" + name.split("_", 2)[-1]
        fallback = fallback if fallback in mi.variants() else "scalar_rgb"
        reason = " ".join(str(e).split())
        warnings.warn(f"motes: {name} cannot run here ({reason}); rendering in {fallback} instead. To use the "
                      f"LLVM variants, {_llvm.FIX}.", RuntimeWarning, stacklevel=2)
        mi.set_variant(fallback)
        name = fallback
    else:
        if name.startswith("llvm_") and _llvm.problem is not None:  # a bad DRJIT_LIBLLVM_PATH was replaced
            warnings.warn(f"motes: {_llvm.problem}", RuntimeWarning, stacklevel=2)
    register()
    return name


__all__ = ["configure_llvm", "native_variants", "register", "set_evaluated_mode", "set_variant"]
