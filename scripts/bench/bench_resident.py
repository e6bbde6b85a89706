"""Bytes per particle as the process holds them: the medium's own accounting (`DiscreteMedium.bytes`, the
sum of its arrays' lengths) against the resident memory it adds, in a fresh process per row.

Each row builds a medium from generated grains, drops the inputs and the Python wrapper (which keeps the
inputs in full storage, by design), and reads how much the process's resident size (Linux
``/proc/self/status`` VmRSS, after ``malloc_trim`` hands freed heap pages back) falls when the Rust medium
is dropped: the memory the medium holds. What its accounting misses (spare capacity, a table left over
from the build, fixed tables of a few MB that weigh on small clouds) shows as resident > accounted.

    .venv/bin/python scripts/bench/bench_resident.py [--n 1000000] [--rows sparse-compact,dense-compact,...]

Rows: ``sparse``: 40 µm grains in a 20 m box (balls far narrower than their spacing); ``dense``: the same
grains in a 2 cm box; each in ``compact`` and ``full`` storage. Prints one line per row: accounted and
resident bytes per particle and their ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys

CODE = """
import ctypes, gc, numpy as np, motes
def rss():
    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)  # hand freed heap pages back, so only what is held counts
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmRSS:"))
n, half, storage = {n}, {half}, "{storage}"
sp = motes.Species(motes.LogNormal(40.0, 1.5), 1.55)
r = sp.psd.sample(n, seed=1)
pos = np.random.default_rng(0).uniform(-half, half, (n, 3))
m = motes.DiscreteMedium(pos, r, np.zeros(n, int), sp, motes.RGB_WAVELENGTHS_UM, scale_m=0.01,
                         query_radius=0.03 * half / 10, storage=storage)
del r, pos
core = m._core  # the Rust medium: the Python wrapper's own arrays (full storage keeps the inputs) aside
del m
held, accounted = rss(), core.bytes
del core
print(accounted, held - rss())
"""

ROWS = {"sparse-compact": (10.0, "compact"), "dense-compact": (0.01, "compact"),
        "sparse-full": (10.0, "full"), "dense-full": (0.01, "full")}


def measure(n: int, half: float, storage: str) -> tuple[float, float]:
    """(accounted, resident) bytes per particle of one medium built in a fresh process."""
    out = subprocess.run([sys.executable, "-c", CODE.format(n=n, half=half, storage=storage)],
                         capture_output=True, text=True, timeout=600)
    if out.returncode:
        raise SystemExit(out.stderr[-2000:])
    accounted, resident = map(float, out.stdout.split()[-2:])
    return accounted / n, resident / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--rows", default=",".join(ROWS))
    args = ap.parse_args()
    print(f"{'row':>15} {'accounted B':>12} {'resident B':>11} {'ratio':>6}   (n = {args.n})")
    for row in args.rows.split(","):
        half, storage = ROWS[row]
        acc, res = measure(args.n, half, storage)
        print(f"{row:>15} {acc:12.1f} {res:11.1f} {res / acc:6.2f}")


if __name__ == "__main__":
    main()
