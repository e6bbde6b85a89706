"""Issue 46: the Dr.Jit walk of the particle grid (``mitsuba_plugin/motes/drjit_walk.py``, ``llvm_ad_rgb``)
against the Rust core's batch calls (``ParticleGrid.optical_depth``, ``ParticleGrid.free_flight``), side by
side in one process, on every core of this machine for both.

Clouds: ``--grains`` (default 1e5 and 1e6) grains uniform in the unit cube, radii uniform in [r, 3r] and a
query radius of 3r, r set so that a ray crosses about 20 disks per unit length (optical depth ~5 across the
cube): a haze of one size class. Rays: ``--rays`` (1e6), half from inside the cube and half from a shell
around it, aimed at random points in it, t_max = inf; free flights draw one uniform each.

Each query runs ``--reps`` times after a warm-up (the Dr.Jit kernels compile there; the machine may be
shared: the best time of each is compared). Prints seconds per batch and per 1e6 rays, and the ratio
Dr.Jit / Rust (above 1: Dr.Jit is slower), for the walk in single precision (the variant's Float) and, with
``--double``, in double. The optical depths of the two are compared (the largest relative difference of the
rays without a grain within single-precision rounding of its disk's edge is not computed here: see
``tests/test_drjit_walk.py``; this prints the mean difference as a sanity check).

    .venv/bin/python scripts/bench/bench_drjit_walk.py [--grains 1e5,1e6] [--rays 1e6] [--reps 3] [--double]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def cloud(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    crossings = 20.0  # disks a ray crosses per unit length: n pi R^2 with R ~ 5 r
    r = np.sqrt(crossings / (np.pi * n)) / 5.0
    radius = rng.uniform(r, 3 * r, n)
    pos = rng.random((n, 3))
    return pos, radius, 2 * np.pi * radius * radius, 3 * r


def rays(m: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    inside = rng.random((m, 3))
    u = rng.normal(size=(m, 3))
    shell = 0.5 + 1.5 * u / np.linalg.norm(u, axis=1, keepdims=True)
    o = np.where((np.arange(m) % 2 == 0)[:, None], inside, shell)
    d = rng.random((m, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d, rng.random(m)


def best(f, reps: int):
    f()  # warm-up (and the kernels' compilation)
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grains", default="1e5,1e6")
    ap.add_argument("--rays", type=float, default=1e6)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--double", action="store_true", help="also the walk in double precision")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    from motes import _motes
    from motes.plugins import configure_llvm

    configure_llvm()
    mi.set_variant("llvm_ad_rgb")
    from motes.drjit_walk import DrJitGrid

    m = int(args.rays)
    o, d, u = rays(m)
    F = mi.Float64
    O, D = [F(o[:, a]) for a in range(3)], [F(d[:, a]) for a in range(3)]
    T = F(np.full(m, np.inf))
    U = mi.Float(u.astype(np.float32))
    seg = (o.ravel(), d.ravel(), np.zeros(m), np.full(m, np.inf))
    dr.eval(O, D, T, U)
    print(f"{m:.0e} rays; {os.cpu_count()} cores; Dr.Jit {dr.__version__}, Mitsuba {mi.__version__}, llvm_ad_rgb")
    print(f"{'grains':>8} {'query':>14} {'walk':>7} {'Rust s':>8} {'Dr.Jit s':>9} {'ratio':>6}  check")
    for n in (int(float(x)) for x in args.grains.split(",")):
        pos, radius, c_ext, rc = cloud(n)
        grid = _motes.ParticleGrid(pos.ravel(), radius, c_ext, 1, rc, _motes.DEFAULT_CELLS_PER_PARTICLE)
        rust_tau = grid.optical_depth(seg, False)
        t_rust_tau = best(lambda: grid.optical_depth(seg, False), args.reps)
        t_rust_ff = best(lambda: grid.free_flight(seg, u, 0), args.reps)
        rust_escape = np.mean(np.isnan(grid.free_flight(seg, u, 0)[0]))
        for double in ([False, True] if args.double else [False]):
            w = DrJitGrid(grid, double=double)
            walk = "double" if double else "single"
            tau = w.optical_depth(O, D, T).numpy()
            def depths():
                dr.eval(w.optical_depth(O, D, T))
                dr.sync_thread()  # (the LLVM backend launches its kernels asynchronously)

            t_dj_tau = best(depths, args.reps)
            diff = np.mean(np.abs(tau - rust_tau)) / np.mean(rust_tau)
            print(f"{n:8.0e} {'optical depth':>14} {walk:>7} {t_rust_tau:8.3f} {t_dj_tau:9.3f} "
                  f"{t_dj_tau / t_rust_tau:6.2f}  mean tau {np.mean(rust_tau):.3f}, mean |diff| / mean {diff:.1e}")

            def flights():
                t, i, v = w.sample_free_flight(O, D, T, U)
                dr.eval(t, i, v)
                dr.sync_thread()
                return v

            escape = 1 - np.mean(flights().numpy())
            t_dj_ff = best(flights, args.reps)
            print(f"{n:8.0e} {'free flight':>14} {walk:>7} {t_rust_ff:8.3f} {t_dj_ff:9.3f} "
                  f"{t_dj_ff / t_rust_ff:6.2f}  escapes: Rust {rust_escape:.4f}, Dr.Jit {escape:.4f}")
        print(f"{n:8.0e} flat arrays {w.count * w.bytes_per_grain / 1e6:.1f} MB ({w.bytes_per_grain:.1f} B/grain, "
              f"{w.layout} layout) + "
              f"{4 * w.cells / 1e6:.1f} MB cell starts; {w.classes} class(es)")


if __name__ == "__main__":
    main()
