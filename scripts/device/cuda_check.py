"""Issue 46 on a GPU: the Dr.Jit walk of the particle grid (``mitsuba_plugin/motes/drjit_walk.py``) in
``cuda_ad_rgb`` against the Rust core's batch calls on the same machine's CPUs, in one process.

For each cloud (``--grains``; ``bench_drjit_walk.cloud``: grains uniform in the unit cube, one size class,
optical depth ~5 across it, so a 10^8-grain cloud is as deep as a 10^5 one, only finer) and ``--rays``
rays (``bench_drjit_walk.rays``: half from inside, half from a shell around it):

* optical depths: the largest and mean relative difference of the Dr.Jit walk (single precision) from the Rust
  core's (double), and the share of rays within 1e-3 relative;
* free flights (same distribution, other random numbers: module docs of ``drjit_walk``): the escape
  fraction and mean distance of each, with their difference in standard errors;
* seconds of each (best of ``--reps`` after a warm-up that compiles the kernels; ``dr.sync_thread`` waits
  for the GPU), the GPU memory of the flat arrays, the Rust grid's build time and bytes.

Writes ``summary.json`` and ``kernel_history.json`` (``dr.kernel_history()``: each kernel's backend, size
and times) to ``--out`` (the device tool's $OUT) and prints the table. Runs in ``llvm_ad_rgb`` too
(``--variant llvm_ad_rgb``, a dry run of the script on any machine).

    python3 scripts/device/cuda_check.py --out $OUT [--grains 1e5,1e6,1e8] [--rays 1e6] [--variant cuda_ad_rgb]

On the device machine through ``scripts/device/run.sh`` (packed by ``scripts/device/pack.sh``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts" / "bench"))
sys.path.insert(0, str(ROOT / "mitsuba_plugin"))


def best(f, reps: int):
    out = f()  # warm-up: the kernels compile here
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return min(times), out


def write_kernel_history(out: pathlib.Path) -> None:
    """``dr.kernel_history()`` (each kernel's backend, size and times) as ``out/kernel_history.json``."""
    import drjit as dr

    (out / "kernel_history.json").write_text(json.dumps(
        [{k: (v if isinstance(v, (int, float, str, bool)) or v is None else str(v)) for k, v in h.items()}
         for h in dr.kernel_history()], indent=1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grains", default="1e5,1e6,1e8")
    ap.add_argument("--rays", type=float, default=1e6)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--variant", default="cuda_ad_rgb")
    ap.add_argument("--out", default=os.environ.get("OUT", "out"))
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    import drjit as dr
    import mitsuba as mi

    import bench_drjit_walk as B
    from motes import _motes

    if args.variant.startswith("llvm"):
        from motes.plugins import configure_llvm

        configure_llvm()
    if args.variant not in mi.variants():
        print(f"Mitsuba here has no {args.variant} variant (has: {', '.join(mi.variants())})")
        return 2
    mi.set_variant(args.variant)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    from motes.drjit_walk import DrJitGrid

    m = int(args.rays)
    o, d, u = B.rays(m)
    O, D = [mi.Float(o[:, a].astype(np.float32)) for a in range(3)], [mi.Float(d[:, a].astype(np.float32))
                                                                        for a in range(3)]
    T = mi.Float(np.full(m, np.inf, dtype=np.float32))
    U = mi.Float(u.astype(np.float32))
    seg = (o.ravel(), d.ravel(), np.zeros(m), np.full(m, np.inf))
    dr.eval(O, D, T, U)
    rows = []
    print(f"{m:.0e} rays; {os.cpu_count()} CPU cores; Dr.Jit {dr.__version__}, Mitsuba {mi.__version__}, {args.variant}")
    for n in (int(float(x)) for x in args.grains.split(",")):
        t0 = time.perf_counter()
        pos, radius, c_ext, rc = B.cloud(n)
        grid = _motes.ParticleGrid(pos.ravel(), radius, c_ext, 1, rc, _motes.DEFAULT_CELLS_PER_PARTICLE)
        del pos, radius, c_ext
        build = time.perf_counter() - t0
        t_rust_tau, rust_tau = best(lambda: grid.optical_depth(seg, False), args.reps)
        t_rust_ff, (rust_t, _, _) = best(lambda: grid.free_flight(seg, u, 0), args.reps)
        t0 = time.perf_counter()
        w = DrJitGrid(grid)
        dr.eval()
        dr.sync_thread()
        upload = time.perf_counter() - t0

        def depths():
            tau = w.optical_depth(O, D, T)
            dr.eval(tau)
            dr.sync_thread()
            return tau

        def flights():
            t, _, v = w.sample_free_flight(O, D, T, U)
            dr.eval(t, v)
            dr.sync_thread()
            return t, v

        t_dj_tau, tau = best(depths, args.reps)
        t_dj_ff, (t_dj, v_dj) = best(flights, args.reps)
        tau = tau.numpy().astype(np.float64)
        rel = np.abs(tau - rust_tau) / np.maximum(rust_tau, 1e-12)
        hit_r = ~np.isnan(rust_t)
        hit_d = v_dj.numpy().astype(bool)
        t_d = t_dj.numpy()[hit_d].astype(np.float64)
        t_r = rust_t[hit_r]
        esc_r, esc_d = 1 - hit_r.mean(), 1 - hit_d.mean()
        z_esc = (esc_d - esc_r) / np.sqrt(esc_r * (1 - esc_r) * 2 / m + 1e-300)
        z_t = (t_d.mean() - t_r.mean()) / np.sqrt(t_d.var() / t_d.size + t_r.var() / t_r.size)
        row = {"grains": n, "rays": m, "rust_build_s": build, "rust_grid_bytes": int(grid.bytes),
               "upload_s": upload, "flat_bytes": int(w.count * w.bytes_per_grain + 4 * w.cells),
               "tau_rust_s": t_rust_tau, "tau_drjit_s": t_dj_tau, "flight_rust_s": t_rust_ff,
               "flight_drjit_s": t_dj_ff, "tau_mean": float(rust_tau.mean()), "tau_rel_max": float(rel.max()),
               "tau_rel_mean": float(rel.mean()), "tau_within_1e-3": float((rel < 1e-3).mean()),
               "escape_rust": float(esc_r), "escape_drjit": float(esc_d), "escape_z": float(z_esc),
               "t_mean_rust": float(t_r.mean()), "t_mean_drjit": float(t_d.mean()), "t_mean_z": float(z_t)}
        rows.append(row)
        print(f"{n:8.0e} grains: build {build:.1f} s ({grid.bytes / 1e9:.2f} GB), upload {upload:.2f} s "
              f"({row['flat_bytes'] / 1e9:.2f} GB); optical depth Rust {t_rust_tau:.3f} s, Dr.Jit {t_dj_tau:.4f} s "
              f"(x{t_rust_tau / t_dj_tau:.1f} faster), rel diff max {rel.max():.1e} mean {rel.mean():.1e}, "
              f"{100 * row['tau_within_1e-3']:.2f} % within 1e-3; free flight Rust {t_rust_ff:.3f} s, "
              f"Dr.Jit {t_dj_ff:.4f} s, escapes {esc_r:.4f} / {esc_d:.4f} (z {z_esc:+.2f}), "
              f"mean t z {z_t:+.2f}", flush=True)
        del w, grid
        dr.flush_malloc_cache()
    write_kernel_history(out)
    (out / "summary.json").write_text(json.dumps({"variant": args.variant, "rows": rows}, indent=1))
    bad = [r for r in rows if r["tau_within_1e-3"] < 0.99 or abs(r["escape_z"]) > 4 or abs(r["t_mean_z"]) > 4]
    print("OK" if not bad else f"MISMATCH in {[r['grains'] for r in bad]}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
