"""Issue 27.5: frames and passes per minute with 1 and 2 local Dask workers against the single-process
render (same machine, same run), and what one task costs on a cluster (overhead, bytes moved).

Everything goes through the ``motes`` command as a user runs it (``motes.cli.main`` in a subprocess, so
that each configuration starts cold, cluster start-up included, and that start-up is reported apart):
* frames: ``motes render house --frames 1:F`` (the shipped blowing-snow scene, moving grains) at a
  small size, single process / ``--workers 1`` / ``--workers 2``;
* passes: one image of S spp in passes of P, the same three ways;
* per task: a 1-spp, 8x8 render of a tiny scene submitted 40 times to a warm 2-worker cluster against
  the same renders in-process (the scheduler's round trip per task), and the bytes a task moves (its
  pickled arguments, by path and with ``--ship-files``, and its result image).

    .venv/bin/python scripts/bench/bench_cluster.py [--frames 8] [--res 160] [--spp 32] [--quick]

About 3 minutes on 2 cores. Timing: run it alone.
"""

from __future__ import annotations

import argparse
import pathlib
import pickle
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]


def motes_cmd(args, cwd) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "motes", "render", *args], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"motes render {' '.join(args)}: {r.stderr[-1500:]}")
    return time.perf_counter() - t0


def startup_seconds(workers: int) -> float:
    code = ("import time; t=time.perf_counter(); from dask.distributed import Client, LocalCluster; "
            f"c=LocalCluster(n_workers={workers}, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40); "
            "cl=Client(c); cl.run(lambda: __import__('motes')); print(time.perf_counter()-t); cl.close(); c.close()")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    return float(r.stdout.strip().splitlines()[-1])


def per_task(tmp: pathlib.Path) -> dict:
    sys.path.insert(0, str(ROOT / "mitsuba_plugin"))
    from dask.distributed import Client, LocalCluster  # noqa: PLC0415

    from motes import cluster as C  # noqa: PLC0415

    scene = tmp / "tiny.xml"
    scene.write_text((ROOT / "tests" / "test_cluster.py").read_text().split('SCENE = """')[1].split('"""')[0]
                     .format(frame_default="", frame_use="").replace('value="16"', 'value="8"'))
    n = 40
    t0 = time.perf_counter()
    for i in range(n):
        C.render_pass(str(scene), {}, "llvm_ad_rgb", 1, i)
    local = (time.perf_counter() - t0) / n
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40,
                           env={"MOTES_WORKER_THREADS": "1", "RAYON_NUM_THREADS": "1"})
    client = Client(cluster)
    client.gather([client.submit(C.render_pass, str(scene), {}, "llvm_ad_rgb", 1, 10**6 + i, pure=False) for i in range(4)])
    t0 = time.perf_counter()
    for i in range(n):  # one at a time: the round trip, not the throughput
        client.submit(C.render_pass, str(scene), {}, "llvm_ad_rgb", 1, i, pure=False).result()
    remote = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for i in range(n):  # a task that does nothing: the scheduler's own cost per task
        client.submit(C.parse_frames, str(i), pure=False).result()
    trivial = (time.perf_counter() - t0) / n
    client.close()
    cluster.close()
    files = C.referenced_files(scene, {})
    img = C.render_pass(str(scene), {}, "llvm_ad_rgb", 1, 0)
    return {"local_s": local, "cluster_s": remote, "trivial_s": trivial, "args_by_path_bytes": len(pickle.dumps((str(scene), {}, "llvm_ad_rgb", 1, 0))),
            "args_shipped_bytes": len(pickle.dumps((str(scene), {}, "llvm_ad_rgb", 1, 0, files))),
            "result_bytes_8x8": len(pickle.dumps(img))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--res", type=int, default=160)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--image-spp", type=int, default=256, help="spp of the single image cut into passes")
    ap.add_argument("--pass-spp", type=int, default=32)
    ap.add_argument("--quick", action="store_true", help="3 frames, 64 spp image")
    ap.add_argument("--out", default=None, help="(ignored; run_benchmarks passes it)")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.image_spp = 3, 64
    common = ["-D", f"res={args.res}", "-D", "count=400000", "-s", str(args.spp)]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        motes_cmd(["lamp", "-D", "res=16", "-s", "1", "-o", str(tmp / "warm.exr")], tmp)  # tables cached, JIT warm
        rows = []
        for label, extra in (("single process", []), ("--workers 1", ["--workers", "1"]), ("--workers 2", ["--workers", "2"])):
            d = tmp / label.replace(" ", "_").replace("-", "")
            t_frames = motes_cmd(["house", "--frames", f"1:{args.frames}", "-o", str(d / "f_{frame}.exr"), *common,
                                  *extra], tmp)
            t_image = motes_cmd(["house", "-D", f"res={args.res}", "-D", "count=400000", "-s", str(args.image_spp),
                                 "--pass-spp", str(args.pass_spp), "-o", str(d / "image.exr"), *extra], tmp)
            rows.append((label, t_frames, t_image))
            print(f"{label:15s} {args.frames} frames in {t_frames:6.1f} s ({60 * args.frames / t_frames:5.1f} frames/min); "
                  f"{args.image_spp // args.pass_spp} passes in {t_image:6.1f} s "
                  f"({60 * (args.image_spp // args.pass_spp) / t_image:5.1f} passes/min)", flush=True)
        base = rows[0]
        for label, tf, ti in rows[1:]:
            print(f"{label}: frames {base[1] / tf:.2f}x, passes {base[2] / ti:.2f}x the single process "
                  "(wall clock including the cluster's start-up)")
        for w in (1, 2):
            print(f"LocalCluster start-up with {w} worker(s), motes imported on each: {startup_seconds(w):.1f} s")
        t = per_task(tmp)
        print(f"per task: a task that does nothing {1e3 * t['trivial_s']:.1f} ms round trip on a warm 2-worker "
              f"cluster (the scheduler's cost per task); a 1-spp 8x8 render of a tiny scene {1e3 * t['cluster_s']:.1f} ms "
              f"there (one worker thread) against {1e3 * t['local_s']:.1f} ms in this process (two threads)")
        print(f"bytes per task: arguments {t['args_by_path_bytes']} B by path, {t['args_shipped_bytes']} B with "
              f"--ship-files (scene XML; particle files add their size); result {t['result_bytes_8x8']} B at 8x8 "
              f"= 12 B per pixel + {t['result_bytes_8x8'] - 8 * 8 * 12} B: a 1920x1080 pass or frame moves "
              f"{(1920 * 1080 * 12 + t['result_bytes_8x8'] - 768) / 1e6:.1f} MB back to the client")
    return 0


if __name__ == "__main__":
    sys.exit(main())
