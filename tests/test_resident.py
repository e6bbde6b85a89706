"""Issue 42: the bytes a discrete medium reports (``DiscreteMedium.bytes``, the figure BENCHMARKS quotes per
particle) are the resident memory it holds: dropping the Rust medium gives back what it says it holds, within
10 %, in compact and full storage, sparse and dense (``scripts/bench/bench_resident.py``, each a fresh process)."""

from __future__ import annotations

import importlib.util
import pathlib

import pytest

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "scripts" / "bench" / "bench_resident.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_resident", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("row", ["sparse-compact", "dense-compact", "sparse-full", "dense-full"])
def test_reported_bytes_are_resident_memory(row):
    if not pathlib.Path("/proc/self/status").exists():
        pytest.skip("needs Linux /proc to read the resident size")
    b = _bench()
    half, storage = b.ROWS[row]
    accounted, resident = b.measure(300_000, half, storage)
    assert 0.9 <= resident / accounted <= 1.1, (row, accounted, resident)
