"""Issue 43, deliverable 7: how long 10^8 stored grains take to load, against numpy's argsort of as many float64
keys on the same machine, in one run.

Each measurement runs in a fresh subprocess, which reports its wall time and its peak resident memory (VmHWM):

* ``argsort``: ``np.argsort`` of ``count`` random float64 keys (uniform, seeded), timed alone (the keys drawn
  before the clock starts); run before the loads and again after them, so that the ratios see the machine's
  load at both ends;
* ``load``: ``mi.load_dict`` of ``scripts/bench/bench_scale.py``'s dust room (a ``discrete`` medium of
  ``count`` grains in a 10 cm cube, log-normal radii, median 50 um, sigma_g 1.5, ice, ``query_radius`` 0.02),
  no render. Configurations (``--configs``), each ``SOURCE-REGIME-STORAGE``:

  * SOURCE ``gen`` (the plugin generates the grains: part of the load) or ``npz`` (read from an uncompressed .npz
    of float64 positions, float64 radii and uint32 species written beforehand by another process from the same
    generator; the reading is part of the load);
  * REGIME ``discrete`` (``continuous_count`` = inf: every grain stored in the grid) or ``default`` (the
    plugin's default ``continuous_count``: at these counts most size classes are continuous);
  * STORAGE ``compact`` (the default) or ``full``.

  The child also reports the plugin's own log lines ("optics tables: ... s", "grid: ... s"): the Python optics
  tables and the Rust build (``DiscreteMedium::build``: storage classes, grid, fields); the rest of the load is
  generating or reading the grains and Mitsuba's own scene load.

The table gives each load's seconds, its ratio to the mean of the two argsorts, the CPU seconds of the process
(every thread's: on a machine shared with other jobs the wall times vary with their load, the CPU seconds
much less) and their ratio to the argsorts', and its peak (10^9 bytes; the interpreter, Mitsuba and Dr.Jit
included, ~0.3 GB before any particle).

    .venv/bin/python scripts/bench/bench_load.py [--count 1e8] [--configs gen-discrete-compact,npz-discrete-compact]
    .venv/bin/python scripts/bench/bench_load.py --packages /tmp/base/mitsuba_plugin,mitsuba_plugin  # two builds

``BENCH_LOAD_SKIP_MEMORY_CHECK=1`` skips the plugin's estimate of the memory a load needs (10^8 grains: 14 GiB),
which refuses the load while other jobs hold memory.
"""

from __future__ import annotations

import json
import logging
import os
import pathlib
import re
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import _common as C  # noqa: E402

HALF = 5.0  # cm: the cube's half-size (bench_scale.py's)
CONFIGS = [f"{s}-{r}-{t}" for s in ("gen", "npz") for r in ("discrete", "default") for t in ("compact", "full")]
DEFAULT_CONFIGS = "gen-discrete-compact,npz-discrete-compact,gen-default-compact,gen-discrete-full"


def peak_gb() -> float:
    """This process's peak resident memory (VmHWM), 10^9 bytes."""
    for line in pathlib.Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024 / 1e9
    return float("nan")


def child_argsort(count: float) -> dict:
    import numpy as np  # noqa: PLC0415

    keys = np.random.default_rng(0).random(int(count))
    t, c = time.perf_counter(), time.process_time()
    order = np.argsort(keys)
    dt, cpu = time.perf_counter() - t, time.process_time() - c
    return {"argsort_s": dt, "cpu_s": cpu, "peak_gb": peak_gb(), "check": int(order[0])}


def child_load(count: float, config: str, filename: str | None, variant: str) -> dict:
    motes = C.import_motes()
    if os.environ.get("BENCH_LOAD_SKIP_MEMORY_CHECK"):
        # The plugin refuses a load it estimates at more than the memory available (14 GiB for 10^8 grains
        # against a measured peak of ~7.2 GB): on a machine shared with other jobs, skip that estimate.
        motes._memory.require = lambda *a, **k: None
    motes.set_variant(variant)
    import mitsuba as mi  # noqa: PLC0415

    import bench_render as BR  # noqa: PLC0415

    _source, regime, storage = config.split("-")
    logs: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            logs.append(record.getMessage())

    log = logging.getLogger("motes")
    log.setLevel(logging.INFO)
    log.addHandler(Keep())
    medium = {"type": "discrete", "count": int(count), "radius_median": 50.0, "radius_sigma_g": 1.5,
              "material": "ice", "scale_m": 0.01, "query_radius": 0.02, "phase": {"type": "particle"},
              "to_world": mi.ScalarTransform4f().scale(HALF), "storage": storage}
    if filename:
        medium = {k: v for k, v in medium.items() if k not in ("count", "radius_median", "radius_sigma_g")}
        medium["filename"] = filename
    if regime == "discrete":
        medium["continuous_count"] = float("inf")
    scene = BR.room(mi, medium, 16, 1, max_depth=6)
    scene["cube"]["to_world"] = mi.ScalarTransform4f().scale(HALF)
    before = peak_gb()
    t, c = time.perf_counter(), time.process_time()
    sc = mi.load_dict(scene)
    load, cpu = time.perf_counter() - t, time.process_time() - c
    med = next(s.interior_medium() for s in sc.shapes() if s.interior_medium() is not None)
    phases = {}
    for msg in logs:
        m = re.match(r"(optics tables|grid): .* ([0-9.]+) s$", msg)
        if m:
            phases[m.group(1)] = float(m.group(2))
    return {"load_s": load, "cpu_s": cpu, "peak_gb": peak_gb(), "before_gb": before, "medium_mb": med.data.bytes / 1e6,
            "continuous": float(med.data.continuous_particles), "optics_s": phases.get("optics tables"),
            "build_s": phases.get("grid")}


def run_child(args_list: list[str], timeout: float, package: str | None = None) -> dict:
    env = None
    if package:  # another build of the package first on the path (A/B of two builds in one run)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([package, os.environ.get("PYTHONPATH", "")]))
    t = time.perf_counter()
    try:
        run = subprocess.run([sys.executable, __file__, *args_list], capture_output=True, text=True, timeout=timeout,
                             env=env)
        lines = [ln for ln in run.stdout.splitlines() if ln.startswith("RESULT ")]
        if run.returncode == 0 and lines:
            row = json.loads(lines[-1][7:])
        else:
            tail = (run.stderr.strip().splitlines() or ["(no output)"])[-1]
            row = {"error": f"rc {run.returncode}: {tail[:200]}"}
    except subprocess.TimeoutExpired:
        row = {"error": f"over {timeout:.0f} s"}
    row["wall_s"] = time.perf_counter() - t
    return row


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--count", type=float, default=1e8)
    ap.add_argument("--configs", default=DEFAULT_CONFIGS, help=f"comma-separated, of {CONFIGS}")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per child")
    ap.add_argument("--packages", default="", help="comma-separated folders holding other builds of the motes "
                    "package (put first on PYTHONPATH): each load runs once per build, side by side")
    ap.add_argument("--child", default=None, help=_hidden())
    ap.add_argument("--file", default=None, help=_hidden())
    args = ap.parse_args()
    if args.child == "argsort":
        print("RESULT " + json.dumps(child_argsort(args.count)))
        return
    if args.child == "write":
        import bench_scale as BS  # noqa: PLC0415

        BS.write_file(args.count, args.file)
        return
    if args.child is not None:
        print("RESULT " + json.dumps(child_load(args.count, args.child, args.file, args.variant)))
        return
    configs = C.choose_configs(ap, args.configs, CONFIGS)
    out, sw = C.out_dir(args.out), C.Stopwatch()
    base = ["--count", repr(args.count), "--variant", args.variant]
    sorts = [run_child(["--child", "argsort", *base], args.timeout)]
    print(f"argsort: {sorts[0]}", flush=True)
    path = None
    if any(c.startswith("npz") for c in configs):
        path = str(out / f"bench_load_{args.count:.0e}.npz")
        subprocess.run([sys.executable, __file__, "--child", "write", "--file", path, *base], check=True,
                       timeout=args.timeout)
    rows = []
    packages = [p for p in args.packages.split(",") if p] or [None]
    for config in configs:
        extra = ["--file", path] if config.startswith("npz") else []
        for package in packages:
            row = run_child(["--child", config, *extra, *base], args.timeout, package)
            row["config"] = config + (f" [{package}]" if package else "")
            rows.append(row)
            print(f"{row['config']}: {row}", flush=True)
    if path:
        pathlib.Path(path).unlink(missing_ok=True)
    sorts.append(run_child(["--child", "argsort", *base], args.timeout))
    print(f"argsort: {sorts[1]}", flush=True)
    ok = [s["argsort_s"] for s in sorts if "argsort_s" in s]
    ref = sum(ok) / len(ok) if ok else float("nan")
    cpus = [s["cpu_s"] for s in sorts if "cpu_s" in s]
    ref_cpu = sum(cpus) / len(cpus) if cpus else float("nan")
    table = [["argsort", " / ".join(f"{s:.1f}" for s in ok), 1.0, " / ".join(f"{s:.1f}" for s in cpus), 1.0,
              max(s.get("peak_gb", 0) for s in sorts), "-", "-"]]
    for r in rows:
        if "error" in r:
            table.append([r["config"], r["error"], "-", "-", "-", "-", "-", "-"])
        else:
            table.append([r["config"], r["load_s"], r["load_s"] / ref, r["cpu_s"], r["cpu_s"] / ref_cpu, r["peak_gb"],
                          r["optics_s"], r["build_s"]])
    C.print_table(f"{args.count:.0e} grains, {args.variant}; load against np.argsort of as many float64 keys",
                  ["what", "seconds", "/ argsort", "CPU s", "CPU / argsort's", "peak (GB)", "optics tables (s)",
                   "Rust build (s)"], table)
    C.finish(args, sw, out / f"bench_load_{args.count:.0e}.json", rows=rows, argsort=sorts)


def _hidden() -> str:
    import argparse  # noqa: PLC0415

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
