"""Issue 12.3: what a caller-owned `GoaCache` saves when a discrete medium builds its optics tables.

A medium's build computes one bulk table per size bin (`motes.discrete._bin_optics`); with a constant
refractive index every bin has the same GOA ray geometry. This times the 16 bins of 200-1000 um ice-like
grains (eta 1.31) at 3 and 8 wavelengths, the disk cache off, each bin's `bulk_properties` with one shared
`motes._motes.GoaCache` and without (each call its own geometry), interleaved, best of `--reps`; results
must be identical.

    .venv/bin/python scripts/bench/bench_goa_cache.py [--reps 3]
"""

from __future__ import annotations

import os
import time

os.environ["MOTES_CACHE_DIR"] = ""  # the disk cache off: every table computed

import numpy as np  # noqa: E402


def build_tables(motes, lam, shared: bool):
    from motes import _motes  # noqa: PLC0415

    cache = _motes.GoaCache() if shared else None
    edges = np.geomspace(200.0, 1000.0, 17)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sp = motes.Species(motes.Uniform(float(lo), float(hi)), complex(1.31, 0.0))
        out.append(motes.bulk_properties(sp, 1.0, lam, truncate_below_rad=0.031, cache=False, goa_cache=cache))
    return out


def main() -> None:
    import argparse  # noqa: PLC0415

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default="out", help="unused (run_benchmarks.sh passes it to every script)")
    args = ap.parse_args()
    import motes  # noqa: PLC0415

    for lam in ([0.65, 0.55, 0.45], list(np.linspace(0.4, 0.7, 8))):
        best = {True: np.inf, False: np.inf}
        tables = {}
        for _ in range(args.reps):
            for shared in (True, False):
                t = time.perf_counter()
                tables[shared] = build_tables(motes, lam, shared)
                best[shared] = min(best[shared], time.perf_counter() - t)
        same = all(np.array_equal(a[k], b[k]) for a, b in zip(tables[True], tables[False])
                   for k in ("sigma_t", "g", "phase"))
        print(f"{len(lam)} wavelengths, 16 bins: shared GoaCache {best[True]:.3f} s, none {best[False]:.3f} s "
              f"({best[False] / best[True]:.2f}x); identical results: {same}", flush=True)


if __name__ == "__main__":
    main()
