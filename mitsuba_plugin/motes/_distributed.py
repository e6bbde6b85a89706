"""The client side of ``motes render --workers N`` / ``--scheduler ADDRESS`` (Dask ``distributed``): submits
frames or passes (``motes.cluster``), shows a progress bar over tasks, writes what arrives, and on Ctrl-C
cancels the cluster's tasks and keeps what finished. Needs the ``cluster`` extra (``pip install
motes[cluster]``: dask and distributed)."""

from __future__ import annotations

import os
import pathlib
import signal
import sys
import time

import numpy as np

from . import _env
from . import cluster as C
from ._output import progress, write_images


def _client(args):
    try:
        from dask.distributed import Client, LocalCluster  # noqa: PLC0415
    except ImportError:
        raise RuntimeError("--workers / --scheduler need dask and distributed: pip install 'motes[cluster]'") from None
    # distributed registers its numpy serialisers (importing numpy.ma) the first time it sends an array, on
    # its communication thread; under CPython 3.11.7 that import's ast.parse there can fail with "AST
    # constructor recursion depth mismatch" (CPython gh-106905; seen once in the test suite). Here it runs
    # on the calling thread.
    import distributed.protocol.numpy  # noqa: F401, PLC0415
    if args.scheduler:
        return Client(args.scheduler, timeout="30s"), None
    # Each worker process gets its share of the cores for Dr.Jit's and rayon's thread pools.
    threads = max(1, (os.cpu_count() or 1) // args.workers)
    env = {_env.WORKER_THREADS: str(threads), "RAYON_NUM_THREADS": str(threads)}
    cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                           env=env, silence_logs=40)
    return Client(cluster), cluster


def render(args, mi, variant: str, scene_path: pathlib.Path, defines: dict) -> int:
    scene_arg = str(scene_path.resolve())
    files = C.referenced_files(scene_path, defines) if args.ship_files and not args.frames else None
    spp = args.spp or _scene_spp(mi, scene_path, defines)
    plan = C.pass_plan(spp, args.pass_spp, args.seed)
    client, cluster = _client(args)
    # Ctrl-C raises KeyboardInterrupt here, whatever handler the cluster's start-up left behind.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    futures, results, t0 = [], {}, time.perf_counter()
    try:
        n_workers = len(client.scheduler_info()["workers"])
        print(f"motes: Dask cluster {client.scheduler.address} with {n_workers} workers", file=sys.stderr)
        if args.frames:
            frames = C.parse_frames(args.frames)
            outs = {f: C.frame_output(args.output, scene_path.stem, f) for f in frames}
            todo = [f for f in frames if args.overwrite or not outs[f].exists()]
            if len(todo) < len(frames):
                print(f"motes: {len(frames) - len(todo)} of {len(frames)} frames already on disk, skipped "
                      "(--overwrite renders them again)", file=sys.stderr)
            fps, text = args.fps or C.DEFAULT_FPS, scene_path.read_text()
            futures = []
            for f in todo:
                d = C.frame_defines(defines, f, fps, text)
                # Each frame's own files by value (filename="grains_$frame.npz").
                frame_files = C.referenced_files(scene_path, d) if args.ship_files else None
                futures.append(client.submit(C.render_image, scene_arg, d, variant, plan, frame_files,
                                             key=f"motes-frame-{f}-{os.getpid()}-{time.time_ns()}", pure=False))
            owner = {fut.key: f for fut, f in zip(futures, todo)}
            done = 0
            from dask.distributed import as_completed  # noqa: PLC0415

            for fut in as_completed(futures):
                f = owner[fut.key]
                write_images(mi, outs[f], fut.result(), args.png)
                done += 1
                progress(done, len(todo), time.perf_counter() - t0, "frames")
            sys.stderr.write("\n")
            print(f"motes: {len(todo)} frames in {time.perf_counter() - t0:.1f} s on {n_workers} workers",
                  file=sys.stderr)
            return 0
        out = pathlib.Path(args.output) if args.output else pathlib.Path(scene_path.stem + ".exr")
        futures = [client.submit(C.render_pass, scene_arg, defines, variant, k, s, files,
                                 key=f"motes-pass-{i}-{os.getpid()}-{time.time_ns()}", pure=False)
                   for i, (k, s) in enumerate(plan)]
        _gather_passes(futures, plan, t0, results)
        img = C.merge_passes([results[i] for i in range(len(plan))], [k for k, _ in plan])
        written = write_images(mi, out, img.astype(np.float32), args.png)
        print(f"motes: {spp} spp in {len(plan)} passes in {time.perf_counter() - t0:.1f} s on {n_workers} workers; "
              f"seeds {plan[0][1]}..{plan[-1][1]}; wrote {', '.join(written)}", file=sys.stderr)
        return 0
    except KeyboardInterrupt:
        pending = [f for f in futures if not f.done()]
        client.cancel(pending)
        print(f"\nmotes: interrupted (Ctrl-C): cancelled {len(pending)} tasks on the cluster", file=sys.stderr)
        if not args.frames:
            # Passes that finished but had not been collected yet: fetched if their worker still lives.
            for i, f in enumerate(futures):
                if i not in results and f.status == "finished":
                    try:
                        results[i] = f.result(timeout=5)
                    except Exception:  # noqa: BLE001 - a worker gone with the interrupt: that pass is lost
                        pass
            _keep_finished(mi, args, scene_path, results, plan)
        return 130
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _scene_spp(mi, scene_path, defines) -> int:
    """The scene's own spp, read from its sampler without building its media (a scene without shapes)."""
    import xml.etree.ElementTree as ET  # noqa: PLC0415

    root = ET.parse(scene_path).getroot()
    for el in root.iter("sampler"):
        for child in el:
            if child.get("name") == "sample_count":
                value = child.get("value", "")
                if value.startswith("$"):
                    key = value[1:]
                    if key in defines:
                        return int(defines[key])
                    for d in root.iter("default"):
                        if d.get("name") == key:
                            return int(d.get("value"))
                return int(value)
    return 4  # Mitsuba's default for the independent sampler


def _gather_passes(futures, plan, t0, results: dict) -> None:
    """Each pass's image into ``results`` (pass index -> image) as it arrives: what Ctrl-C keeps is
    already here, even if the workers die with the interrupt."""
    from dask.distributed import as_completed  # noqa: PLC0415

    index = {f.key: i for i, f in enumerate(futures)}
    for fut in as_completed(futures):
        results[index[fut.key]] = fut.result()
        progress(len(results), len(plan), time.perf_counter() - t0)
    sys.stderr.write("\n")


def _keep_finished(mi, args, scene_path, results: dict, plan) -> None:
    """After Ctrl-C: the passes that arrived, merged in pass order, written as the image so far."""
    done = sorted(results.items())
    if not done:
        print("motes: no pass had finished; nothing written", file=sys.stderr)
        return
    out = pathlib.Path(args.output) if args.output else pathlib.Path(scene_path.stem + ".exr")
    img = C.merge_passes([r for _, r in done], [plan[i][0] for i, _ in done])
    written = write_images(mi, out, img.astype(np.float32), args.png)
    print(f"motes: kept {sum(plan[i][0] for i, _ in done)} spp from {len(done)} finished passes; wrote "
          f"{', '.join(written)}", file=sys.stderr)
