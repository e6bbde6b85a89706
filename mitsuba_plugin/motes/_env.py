"""The ``MOTES_*`` environment switches the Python package reads, in one place: one function per switch, reading
the environment at each call (so that a switch set after ``import motes``, or by a test's ``monkeypatch``, counts).

==========================  ====================================================  ================================
switch                      what it does                                          default (unset)
==========================  ====================================================  ================================
``MOTES_CACHE_DIR``         motes's disk cache: ``bulk_properties``' tables       ``~/.cache/motes``
                            (``motes.ensemble``), the libLLVM probe's verdicts
                            (``motes.plugins.llvm``) and the native plugin's
                            builds (``motes.native``, under ``native/``).
                            ``""`` keeps no tables and no verdicts; the native
                            plugin, which needs a folder, then builds under the
                            default.
``MOTES_NATIVE``            ``0`` (or ``false``, ``no``, ``off``) turns the       on
                            native render path off (``motes.native``): the
                            plugins then render through the evaluated-mode
                            Python path.
``MOTES_WORKER_THREADS``    threads of each Dask worker's Dr.Jit pool             Dr.Jit's own (every core)
                            (``motes.cluster``); ``motes render --workers N``
                            sets it to the worker's share of the cores.
``MOTES_LLVM_SEARCH``       the libLLVMs to try, separated by ``os.pathsep``,     the installed ones
                            instead of the installed ones                         (``llvm.SEARCH_GLOBS``)
                            (``motes.plugins.llvm``; the tests use it).
==========================  ====================================================  ================================

The Rust core reads its own switches (``MOTES_SIMD``, ``MOTES_BEAM``, ``MOTES_QUANTISE``, ``MOTES_CENTRE_CELLS``,
``MOTES_UNIFORM_MAJORANT``: which of its code paths runs, for comparisons and benchmarks) in ``rust/motes-core``,
not here.
"""

from __future__ import annotations

import os
import pathlib

CACHE_DIR = "MOTES_CACHE_DIR"
NATIVE = "MOTES_NATIVE"
WORKER_THREADS = "MOTES_WORKER_THREADS"
LLVM_SEARCH = "MOTES_LLVM_SEARCH"


def default_cache_dir() -> pathlib.Path:
    """``~/.cache/motes``: the cache when ``MOTES_CACHE_DIR`` is unset."""
    return pathlib.Path.home() / ".cache" / "motes"


def cache_dir() -> pathlib.Path | None:
    """``$MOTES_CACHE_DIR``, else ``default_cache_dir()``; None where it is set to ``""`` (no disk cache)."""
    env = os.environ.get(CACHE_DIR)
    if env is not None:
        return pathlib.Path(env) if env else None
    return default_cache_dir()


def native_requested() -> bool:
    """Whether the native render path is wanted (``MOTES_NATIVE=0``, ``false``, ``no`` or ``off`` turns it off)."""
    return os.environ.get(NATIVE, "1").strip() not in ("0", "false", "no", "off")


def worker_threads() -> int | None:
    """``$MOTES_WORKER_THREADS`` as an integer, or None where it is unset or empty (a ValueError where it is not
    an integer)."""
    threads = os.environ.get(WORKER_THREADS)
    return int(threads) if threads else None


def llvm_search() -> list[str] | None:
    """The paths in ``$MOTES_LLVM_SEARCH`` (separated by ``os.pathsep``), or None where it is unset."""
    search = os.environ.get(LLVM_SEARCH)
    return search.split(os.pathsep) if search is not None else None


__all__ = ["cache_dir", "default_cache_dir", "llvm_search", "native_requested", "worker_threads"]
