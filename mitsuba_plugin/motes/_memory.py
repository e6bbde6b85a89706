"""Memory estimates checked before large allocations: an input that would not fit raises ``MemoryError``
with the estimate, instead of the process aborting inside the Rust allocator (issue 11)."""

from __future__ import annotations

import os

#: Peak bytes per particle of building a discrete medium whose grains the grid references from every
#: cell their balls overlap (sparse grains: balls narrower than the grid's cells): the caller's arrays
#: (positions, radii: 32 B), the cell references and slot copies of the build, and what the medium
#: keeps. Measured (issue 24; the test below, 1e6 log-normal 40 um grains, inputs included): 274 B
#: (compact storage), 261 B (full); a 28 % margin over the larger.
BYTES_PER_PARTICLE = 350
#: The same for grains wider than their spacing or continuous (a dense cloud, the paper-scale clouds):
#: 74 B measured at 3e7 generated grains (scripts/bench/bench_scale.py), 75 B in the test below, 125 B
#: for 1.5e8 grains of the default scene with 4.97 GB of grid (18.8 GB peak); the least any medium
#: needs, so what the plugin checks before it generates a cloud.
BYTES_PER_PARTICLE_DENSE = 150
#: The tests `tests/test_plugin_inputs.py::test_memory_estimate_bounds_the_build` keep both honest.


def bytes_per_particle(n: int, extent: float, reach_max: float) -> int:
    """The estimate for ``n`` particles in a box of largest side ``extent`` whose largest inclusion radius
    (query radius + particle radius) is ``reach_max`` (scene units): sparse when it is below the grid's
    cells (about eight particles each), dense otherwise."""
    cell = 2.0 * extent / max(n, 1) ** (1.0 / 3.0)
    return BYTES_PER_PARTICLE if reach_max < cell else BYTES_PER_PARTICLE_DENSE


def available_bytes() -> int | None:
    """Memory the system can give without swapping (Linux ``MemAvailable``), else physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def default_cache_bytes() -> int:
    """A procedural cloud's default brick cache: a quarter of the memory available at load (at least
    256 MiB; 1 GiB where it cannot be read). Enough to keep every brick of 10^8 visible discrete grains
    (40 B each: scripts/bench/bench_scale.py --scene nave) on a 24 GB machine, so that only a render's
    first pass generates them."""
    avail = available_bytes()
    return max(256 * 2**20, avail // 4) if avail else 2**30


def peak_resident_mb() -> float:
    """This process's peak resident memory in MiB: VmHWM on Linux (``ru_maxrss`` would include the
    parent's resident set at fork, which Linux carries over exec), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as f:
            return next(int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration, ValueError):
        import resource  # noqa: PLC0415

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def require(nbytes: float, what: str) -> None:
    """Raise ``MemoryError`` naming ``what`` when ``nbytes`` exceeds the memory available."""
    avail = available_bytes()
    if avail is not None and nbytes > avail:
        raise MemoryError(f"{what} needs about {nbytes / 2**30:.1f} GiB, more than the {avail / 2**30:.1f} GiB "
                          "of memory available")
