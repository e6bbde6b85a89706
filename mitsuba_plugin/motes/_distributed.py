"""The client side of ``motes render --workers N`` / ``--scheduler ADDRESS`` (Dask ``distributed``): submits
frames or passes (``motes.cluster``), shows a progress bar over tasks, writes what arrives, and on Ctrl-C
cancels the cluster's tasks and keeps what finished. Needs the ``cluster`` extra (``pip install
motes[cluster]``: dask and distributed)."""

from __future__ import annotations

import contextlib
import logging
import os
import pathlib
import signal
import sys
import time

import numpy as np

from . import _env
from . import cluster as C
from ._output import frames_summary, output_path, progress, write_images

#: Frame tasks in flight per worker: frames are submitted as others finish (any number of frames, none
#: expanded up front), enough ahead that no worker waits.
FRAMES_AHEAD = 2


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
    # The workers' logs (a failed task's traceback, before the one line that says what failed) only with --debug.
    # The worker processes start with SIGINT ignored (a disposition they inherit): a terminal's Ctrl-C, sent
    # to the whole process group, reaches this process, which cancels the tasks and closes the cluster,
    # instead of ending each worker with a traceback of its own. Ctrl-C during these seconds of start-up is
    # ignored too.
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               env=env, silence_logs=logging.WARNING if args.debug else logging.CRITICAL)
    finally:
        signal.signal(signal.SIGINT, old)
    return Client(cluster), cluster


@contextlib.contextmanager
def _quiet_logs(debug: bool):
    """This process's Dask logs (the scheduler's and the client's, which repeat a failed task's traceback)
    silenced unless ``--debug``; their levels restored after (``main`` may run in-process)."""
    loggers = [logging.getLogger(name) for name in ("distributed", "dask")]
    levels = [lg.level for lg in loggers]
    if not debug:
        for lg in loggers:
            lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def render(args, mi, variant: str, scene_path: pathlib.Path, defines: dict, frames: range | None = None) -> int:
    """Frames ``frames`` (a sequence), or else one image's passes, on a Dask cluster."""
    files = C.referenced_files(scene_path, defines) if args.ship_files and frames is None else None
    spp = args.spp if args.spp is not None else C.samples_per_pixel(None, _scene_spp(scene_path, defines))
    plan = C.pass_plan(spp, args.pass_spp, args.seed)
    with _quiet_logs(args.debug):
        client, cluster = _client(args)
        try:
            return _render_on(client, args, mi, variant, scene_path, defines, frames, plan, files)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def _submit_frames(client, args, variant, scene_path, defines, frames: range, plan):
    """(frame, future) of each frame in turn, submitted when the caller asks for it; (frame, None) for a frame
    already on disk (without ``--overwrite``)."""
    scene_arg, fps, text = str(scene_path.resolve()), args.fps or C.DEFAULT_FPS, scene_path.read_text()
    for f in frames:
        if not args.overwrite and C.frame_output(args.output, scene_path.stem, f).exists():
            yield f, None
            continue
        d = C.frame_defines(defines, f, fps, text)
        # Each frame's own files by value (filename="grains_$frame.npz").
        frame_files = C.referenced_files(scene_path, d) if args.ship_files else None
        yield f, client.submit(C.render_image, scene_arg, d, variant, plan, frame_files,
                               key=f"motes-frame-{f}-{os.getpid()}-{time.time_ns()}", pure=False)


def _render_on(client, args, mi, variant, scene_path, defines, frames, plan, files) -> int:
    from dask.distributed import as_completed  # noqa: PLC0415

    scene_arg = str(scene_path.resolve())
    # Ctrl-C raises KeyboardInterrupt here, whatever handler the cluster's start-up left behind.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    futures, results, t0 = [], {}, time.perf_counter()
    try:
        n_workers = len(client.scheduler_info()["workers"])
        print(f"motes: Dask cluster {client.scheduler.address} with {n_workers} workers", file=sys.stderr)
        if frames is not None:
            total, skipped, done, shown = C.frame_count(frames), 0, 0, []
            submitted, owner = _submit_frames(client, args, variant, scene_path, defines, frames, plan), {}
            pending = as_completed()

            def submit_one() -> None:
                nonlocal skipped
                for f, fut in submitted:
                    if fut is None:
                        skipped += 1
                        continue
                    owner[fut.key] = f
                    futures.append(fut)
                    pending.add(fut)
                    return

            for _ in range(FRAMES_AHEAD * max(n_workers, 1)):
                submit_one()
            for fut in pending:
                f = owner.pop(fut.key)
                futures.remove(fut)
                out = C.frame_output(args.output, scene_path.stem, f)
                write_images(mi, out, fut.result(), args.png)
                done += 1
                shown += [out] * (len(shown) < 3)
                submit_one()
                progress(done, total - skipped, time.perf_counter() - t0, "frames")
            if done:
                sys.stderr.write("\n")
            frames_summary(done, skipped, total, time.perf_counter() - t0, shown, f" on {n_workers} workers")
            return 0
        out = output_path(args.output, scene_path.stem)
        futures = [client.submit(C.render_pass, scene_arg, defines, variant, k, s, files,
                                 key=f"motes-pass-{i}-{os.getpid()}-{time.time_ns()}", pure=False)
                   for i, (k, s) in enumerate(plan)]
        _gather_passes(futures, plan, t0, results)
        img = C.merge_passes([results[i] for i in range(len(plan))], [k for k, _ in plan])
        written = write_images(mi, out, img.astype(np.float32), args.png)
        print(f"motes: {sum(k for k, _ in plan)} spp in {len(plan)} passes in {time.perf_counter() - t0:.1f} s on "
              f"{n_workers} workers; seeds {plan[0][1]}..{plan[-1][1]}; wrote {', '.join(written)}", file=sys.stderr)
        return 0
    except KeyboardInterrupt:
        pending = [f for f in futures if not f.done()]
        client.cancel(pending)
        print(f"\nmotes: interrupted (Ctrl-C): cancelled {len(pending)} tasks on the cluster", file=sys.stderr)
        if frames is None:
            # Passes that finished but had not been collected yet: fetched if their worker still lives.
            for i, f in enumerate(futures):
                if i not in results and f.status == "finished":
                    try:
                        results[i] = f.result(timeout=5)
                    except Exception:  # noqa: BLE001 - a worker gone with the interrupt: that pass is lost
                        pass
            _keep_finished(mi, args, scene_path, results, plan)
        return 130


def _scene_spp(scene_path, defines) -> int:
    """The scene's own spp, read from its sampler without building its media (the client loads no scene);
    a file that is not XML or a sample count that is not an integer is a ValueError worded as Mitsuba's
    loader words it (``motes._errors.named_property``)."""
    import xml.etree.ElementTree as ET  # noqa: PLC0415

    from ._errors import how_to_write  # noqa: PLC0415

    try:
        root = ET.parse(scene_path).getroot()
    except ET.ParseError as e:
        raise ValueError(f'Parsing of XML file "{scene_path}" failed: {e}') from None
    for el in root.iter("sampler"):
        for child in el:
            if child.get("name") == "sample_count":
                raw = value = child.get("value", "")
                if value.startswith("$"):
                    key = value[1:]
                    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
                    value = defines.get(key, defaults.get(key, value))
                try:
                    return int(value)
                except ValueError:
                    raise ValueError(f'Error while loading {scene_path}: <{child.tag} name="sample_count" '
                                     f'value="{raw}"/>: could not parse integer value "{value}"; '
                                     f'{how_to_write(child.tag, value)}') from None
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
    out = output_path(args.output, scene_path.stem)
    img = C.merge_passes([r for _, r in done], [plan[i][0] for i, _ in done])
    written = write_images(mi, out, img.astype(np.float32), args.png)
    print(f"motes: kept {sum(plan[i][0] for i, _ in done)} spp from {len(done)} finished passes; wrote "
          f"{', '.join(written)}", file=sys.stderr)
