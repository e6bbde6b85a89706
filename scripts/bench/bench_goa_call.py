"""Benchmark: the cost of one call of ``motes.goa_amplitudes`` against ``motes.mie_amplitudes``, as a user
calls them (issue 23.1).

    .venv/bin/python scripts/bench/bench_goa_call.py [--out out/] [--quick]

One call = (S1, S2) of one sphere at the 1800 angles of ``np.linspace(0, pi, 1800)``, eta = 1.33,
lambda = 0.6 um, r = 10, 100, 1000 um. Timed side by side in one process, best of n after a warm-up call:

* *GOA repeated*: the same call again, what a sweep or a loop sees (the free functions keep the ray
  geometry of the last 8 relative indices, with their prepared angle grids, in a cache owned by the
  binding; ``motes.clear_goa_cache()`` empties it);
* *GOA first*: the cache emptied before each call (the cost of a new relative index and angle grid);
* *Mie*: ``motes.mie_amplitudes``, the same arguments.

Acceptance (issue 23.1): Mie / GOA repeated >= 100 at r = 1 mm, and GOA's repeated-call times at
10 um and 1 mm within 3x of each other. The script prints PASS/FAIL for both and exits 1 on a FAIL.
Outputs ``bench_goa_call.json``.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import _common as C  # noqa: E402

ETA = 1.33
RADII_UM = (10.0, 100.0, 1000.0)


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    n = 5 if args.quick else 15
    theta = C.THETA
    rows, records = [], []
    times = {}
    for r in RADII_UM:
        goa = lambda: motes.goa_amplitudes(r, C.LAM, ETA, theta)  # noqa: E731
        goa()  # warm-up: the cache now holds this index and angle grid
        t_goa, _ = C.best_of(goa, n)

        def first():
            motes.clear_goa_cache()
            return goa()

        t_first, _ = C.best_of(first, n)
        t_mie, _ = C.best_of(lambda: motes.mie_amplitudes(r, C.LAM, ETA, theta), max(3, n // 3))
        times[r] = t_goa
        rows.append([f"{r:g}", f"{t_goa * 1e3:.3f}", f"{t_first * 1e3:.3f}", f"{t_mie * 1e3:.2f}",
                     f"{t_mie / t_goa:.0f}", f"{t_mie / t_first:.1f}"])
        records.append({"r_um": r, "goa_repeated_ms": t_goa * 1e3, "goa_first_ms": t_first * 1e3,
                        "mie_ms": t_mie * 1e3, "mie_over_goa_repeated": t_mie / t_goa,
                        "mie_over_goa_first": t_mie / t_first})
    C.print_table("One call at 1800 angles (eta 1.33, lambda 0.6 um)", ["r (µm)", "GOA repeated (ms)", "GOA first call (ms)", "Mie (ms)", "Mie/GOA repeated",
                   "Mie/GOA first"], rows)
    ratio_1mm = records[-1]["mie_over_goa_repeated"]
    spread = max(times[10.0], times[1000.0]) / min(times[10.0], times[1000.0])
    checks = {
        "Mie/GOA >= 100 at r = 1 mm": ratio_1mm >= 100,
        "GOA at 10 um and 1 mm within 3x": spread <= 3,
    }
    print(f"\nMie/GOA at 1 mm: {ratio_1mm:.0f}; GOA time 10 um vs 1 mm: {spread:.2f}x")
    for name, ok in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}  {name}")
    C.finish(args, sw, out / "bench_goa_call.json", rows=records, spread_10um_1mm=spread, checks=checks)
    sys.exit(0 if all(checks.values()) else 1)


if __name__ == "__main__":
    main()
