"""Memory estimates checked before large allocations: an input that would not fit raises ``MemoryError``
with the estimate, instead of the process aborting inside the Rust allocator (issue 11)."""

from __future__ import annotations

import os

#: Peak bytes per particle of building a discrete medium: the caller's arrays (positions, radii: 32 B),
#: the per-particle columns and sorts of the build, and what the medium keeps. Measured (issue 24, the
#: test below, 1e6 log-normal 40 um grains, inputs included): sparse grains 274 B (compact storage) /
#: 261 B (full), a dense cloud 166 / 170 B; the build's temporaries dominate, so one estimate serves both
#: storages, with a 28 % margin over the larger. The test
#: `tests/test_plugin_inputs.py::test_memory_estimate_bounds_the_build` keeps this bound honest.
BYTES_PER_PARTICLE = 350


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
