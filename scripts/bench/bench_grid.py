"""The particle grid (issue 4): build time and bytes per particle against N, optical-depth queries and
exact free flights per second, a grid-resolution sweep (cf. paper Fig. 17), and 1 vs 2 threads.

    .venv/bin/python scripts/bench/bench_grid.py [--quick] [--out out]
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

SCALE_M = 0.01  # 1 scene unit = 1 cm
QUERY_RADIUS = 0.002


def make(motes, n, seed=1, cells_per_particle=1.0):
    psd = motes.LogNormal(100.0, 2.0)
    pos, r = motes.uniform_box(n, [0, 0, 0], [1, 1, 1], psd, seed=seed)
    # one channel: C_ext ~ 2 pi r^2 (GOA limit) keeps the setup cost O(N) for 1e7 particles
    cext = 2 * np.pi * r**2
    sw = C.Stopwatch()
    g = motes.ParticleGrid(pos, r, cext, scale_m=SCALE_M, query_radius=QUERY_RADIUS, cells_per_particle=cells_per_particle)
    return g, sw()


def rays(n, seed=0):
    rng = np.random.default_rng(seed)
    o = rng.random((n, 3)) * 0.5 + 0.25
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True), rng.random(n)


def throughput(g, n_rays):
    o, d, u = rays(n_rays)
    t_q, _ = C.best_of(lambda: g.optical_depth(o, d, 0.0, 0.5), 3)
    t_f, _ = C.best_of(lambda: g.free_flight(o, d, 0.0, 0.5, u), 3)
    return n_rays / t_q, n_rays / t_f


def main() -> None:
    if os.environ.get("BENCH_GRID_CHILD"):
        _, _, _, motes = C.start(__doc__)
        g, _ = make(motes, 100_000)
        q, f = throughput(g, 20_000)
        print(f"{q} {f}")
        return
    args, out, sw, motes = C.start(__doc__)
    sizes = [10_000, 100_000, 1_000_000] + ([] if args.quick else [10_000_000])
    rows = []
    for n in sizes:
        g, t_build = make(motes, n)
        q, f = throughput(g, 20_000)
        rows.append([n, t_build, g.bytes / len(g), "x".join(map(str, g.dims)), q, f])
        del g
    C.print_table("Particle grid against N (log-normal r_g = 100 µm, sigma_g = 2, unit box, 1 cm per unit, r_c = 0.2 mm; "
                  "segments of 0.5 units from random points, 2 threads)",
                  ["N", "build s", "bytes / particle", "grid", "optical-depth queries / s", "free flights / s"], rows)
    sweep = []
    for cpp in [0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0]:
        g, t_build = make(motes, 100_000, cells_per_particle=cpp)
        q, f = throughput(g, 20_000)
        sweep.append([cpp, "x".join(map(str, g.dims)), 1.0 / cpp, q, f, t_build])
    C.print_table("Grid resolution sweep, N = 1e5 (cf. paper Fig. 17: optimum near one particle per voxel)",
                  ["cells per particle", "grid", "particles per voxel", "queries / s", "free flights / s", "build s"], sweep)
    threads = []
    for k in ("1", "2"):
        env = dict(os.environ, RAYON_NUM_THREADS=k, BENCH_GRID_CHILD="1")
        res = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, check=True)
        q, f = map(float, res.stdout.split()[-2:])
        threads.append([k, q, f])
    C.print_table("Threads (N = 1e5, separate processes with RAYON_NUM_THREADS)", ["threads", "queries / s", "free flights / s"], threads)
    C.finish(args, sw, out / "bench_grid.json", sizes=rows, sweep=sweep, threads=threads)


if __name__ == "__main__":
    main()
