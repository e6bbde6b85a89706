"""Memory estimates checked before large allocations: an input that would not fit raises ``MemoryError``
with the estimate, instead of the process aborting inside the Rust allocator (issue 11)."""

from __future__ import annotations

import os

#: Peak bytes per particle of building a discrete medium: the caller's arrays (positions, radii: 32 B),
#: the copies made while they are sorted into the grid, and the grid itself (~57 B kept). Measured:
#: 319 B of peak resident memory per particle for 1e6 log-normal dust grains (inputs and species index
#: included), so 400 leaves a 25 % margin; the test
#: `tests/test_plugin_inputs.py::test_memory_estimate_bounds_the_build` keeps this bound honest.
BYTES_PER_PARTICLE = 400


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
