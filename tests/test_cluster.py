"""Frame sequences and the Dask cluster (issue 27): ``motes render --frames``, ``--workers N`` (a real
``LocalCluster`` of worker processes), ``--scheduler``, the equality of distributed and single-process
renders, a worker killed in the middle of its task, frames skipped on a second run."""

from __future__ import annotations

import os
import pathlib
import signal
import time

import numpy as np
import pytest

import motes
from _scenes import discrete_xml, sensor_xml
from motes import cluster as C
from motes.cli import main

distributed = pytest.importorskip("distributed")

SCENE = """<scene version="3.0.0">
    <default name="spp" value="8"/>
    <default name="count" value="400"/>
    {frame_default}
    <integrator type="volpath"><integer name="max_depth" value="4"/></integrator>
""" + sensor_xml(40, "0, 0, 5", indent="    ").replace("{", "{{").replace("}", "}}") + """    <emitter type="constant"/>
    <shape type="cube">
        <bsdf type="null"/>
        {medium}
    </shape>
</scene>
"""


def scene_file(folder: pathlib.Path, uses_frame: bool = False) -> pathlib.Path:
    """A small scene; with ``uses_frame`` its medium's seed is ``$frame`` (a scene that changes per frame)."""
    seed = '<integer name="seed" value="$frame"/>' if uses_frame else ""
    text = SCENE.format(frame_default='<default name="frame" value="0"/>' if uses_frame else "",
                        medium=discrete_xml("$count", 300, seed))
    path = folder / "tiny.xml"
    path.write_text(text)
    return path


def read(path) -> np.ndarray:
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi

    return np.asarray(mi.Bitmap(str(path)), dtype=np.float64)


@pytest.fixture(scope="module")
def local_cluster():
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                           env={"MOTES_WORKER_THREADS": "1", "RAYON_NUM_THREADS": "1"}, silence_logs=40)
    client = Client(cluster)
    yield cluster, client
    client.close()
    cluster.close()


def test_pass_plan_and_frames_parse():
    assert C.pass_plan(20, 8, 1) == [(8, 100003), (8, 100004), (4, 100005)]
    assert all(0 <= s < 2**32 for _, s in C.pass_plan(16, 8, 10**6))  # Mitsuba's seeds are 32-bit
    assert list(C.parse_frames("3:7:2")) == [3, 5, 7] and list(C.parse_frames("4")) == [4]
    for bad in ("a:b", "5:3", "1:4:0", "1:2:3:4"):
        with pytest.raises(ValueError, match="frames"):
            C.parse_frames(bad)
    assert C.frame_output("out/snow_{frame:05d}.exr", "x", 7) == pathlib.Path("out/snow_00007.exr")
    assert C.frame_output("img.exr", "x", 7) == pathlib.Path("img_0007.exr")
    assert C.frame_output(None, "snow", 12) == pathlib.Path("out/snow_0012.exr")
    assert C.frame_defines({"a": "1"}, 12, 24.0, "$frame $time") == {"a": "1", "frame": "12", "time": "0.5"}
    assert C.frame_defines({}, 12, 24.0, "$framerate") == {}


def test_shipped_files_fill_in_parameters_and_stay_in_the_scene_folder(tmp_path):
    text = '<scene version="3.0.0"><default name="frame" value="1"/><default name="set" value="a"/>' \
           '<medium type="discrete"><string name="filename" value="g_$set_$frame.npz"/></medium></scene>'
    (tmp_path / "s.xml").write_text(text)
    (tmp_path / "g_a_1.npz").write_bytes(b"one")
    (tmp_path / "g_a_2.npz").write_bytes(b"two")
    assert C.referenced_files(tmp_path / "s.xml", {})["g_a_1.npz"] == b"one"  # the scene's defaults
    assert C.referenced_files(tmp_path / "s.xml", {"frame": "2"})["g_a_2.npz"] == b"two"
    with pytest.raises(FileNotFoundError, match="g_a_3.npz"):
        C.referenced_files(tmp_path / "s.xml", {"frame": "3"})
    (tmp_path / "o.xml").write_text(text.replace("g_$set_$frame.npz", "../elsewhere.npz"))
    with pytest.raises(ValueError, match="outside"):
        C.referenced_files(tmp_path / "o.xml", {})


def test_frames_are_written_then_skipped_and_a_static_scene_does_not_flicker(tmp_path, capsys):
    scene = scene_file(tmp_path)
    pattern = str(tmp_path / "f_{frame:03d}.exr")
    assert main(["render", str(scene), "--frames", "1:2", "-o", pattern]) == 0
    a, b = read(tmp_path / "f_001.exr"), read(tmp_path / "f_002.exr")
    # Same grains, same sampler seed: the same image (to float rounding: LLVM traces each loaded scene's
    # kernel anew, and its arithmetic may round differently in the last bit).
    assert a.mean() > 0
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    stamp = (tmp_path / "f_001.exr").stat().st_mtime_ns
    capsys.readouterr()
    assert main(["render", str(scene), "--frames", "1:3", "-o", pattern]) == 0
    assert "2 of 3 frames already on disk" in capsys.readouterr().err
    assert (tmp_path / "f_001.exr").stat().st_mtime_ns == stamp and (tmp_path / "f_003.exr").exists()
    assert main(["render", str(scene), "--frames", "1:1", "-o", pattern, "--overwrite"]) == 0
    assert (tmp_path / "f_001.exr").stat().st_mtime_ns != stamp


def test_passes_on_a_local_cluster_equal_the_single_process_render(tmp_path):
    scene = scene_file(tmp_path)
    assert main(["render", str(scene), "-s", "24", "--pass-spp", "8", "-o", str(tmp_path / "one.exr")]) == 0
    assert main(["render", str(scene), "-s", "24", "--pass-spp", "8", "--workers", "2",
                 "-o", str(tmp_path / "two.exr")]) == 0
    one, two = read(tmp_path / "one.exr"), read(tmp_path / "two.exr")
    assert one.mean() > 0
    np.testing.assert_allclose(two, one, rtol=1e-6, atol=1e-7)


def test_frames_on_an_existing_scheduler_equal_local_frames_and_ship_files(tmp_path, local_cluster):
    cluster, _ = local_cluster
    scene = scene_file(tmp_path, uses_frame=True)
    assert main(["render", str(scene), "--frames", "1:3", "-o", str(tmp_path / "loc_{frame}.exr")]) == 0
    assert main(["render", str(scene), "--frames", "1:3", "--scheduler", cluster.scheduler_address, "--ship-files",
                 "-o", str(tmp_path / "dist_{frame}.exr")]) == 0
    for f in (1, 2, 3):
        np.testing.assert_allclose(read(tmp_path / f"dist_{f}.exr"), read(tmp_path / f"loc_{f}.exr"), rtol=1e-6, atol=1e-7)
    # $frame seeds the grains: frames differ.
    assert not np.array_equal(read(tmp_path / "loc_1.exr"), read(tmp_path / "loc_2.exr"))
    # A second run on the cluster skips the frames on disk.
    stamp = (tmp_path / "dist_2.exr").stat().st_mtime_ns
    assert main(["render", str(scene), "--frames", "1:3", "--scheduler", cluster.scheduler_address,
                 "-o", str(tmp_path / "dist_{frame}.exr")]) == 0
    assert (tmp_path / "dist_2.exr").stat().st_mtime_ns == stamp


def test_a_particle_file_per_frame(tmp_path):
    """filename="grains_$frame.npz": each frame reads its own file (here one grain that moves)."""
    for f in (1, 2):
        pos = np.array([[-0.5 + 0.5 * f, 0.0, 0.0]])
        motes.save_particles(tmp_path / f"grains_{f}.npz", motes.ParticleSet(pos, np.array([3e3]), np.zeros(1, np.int64)))
    text = SCENE.format(frame_default="", medium=discrete_xml("$count", 300, '<float name="albedo" value="0"/>')).replace(
        '<integer name="count" value="$count"/>', '<string name="filename" value="grains_$frame.npz"/>').replace(
        '<default name="count" value="400"/>', "")
    (tmp_path / "files.xml").write_text(text)
    assert main(["render", str(tmp_path / "files.xml"), "--frames", "1:2", "-o", str(tmp_path / "g_{frame}.exr")]) == 0
    a, b = read(tmp_path / "g_1.exr"), read(tmp_path / "g_2.exr")
    # The black grain (3 mm, 0.3 scene units) hides the bright background where it is: the darkest
    # column moves right with it.
    col = lambda img: int(np.argmin(img[..., 0].mean(axis=0)))  # noqa: E731
    assert col(b) > col(a)


def test_a_worker_killed_mid_task_loses_nothing(tmp_path, local_cluster):
    cluster, client = local_cluster
    scene = str(scene_file(tmp_path))
    plan = C.pass_plan(64, 8, 0)
    reference = C.merge_passes([C.render_pass(scene, {"count": "3000"}, "llvm_ad_rgb", k, s) for k, s in plan],
                               [k for k, _ in plan])
    futures = [client.submit(C.render_pass, scene, {"count": "3000"}, "llvm_ad_rgb", k, s, pure=False) for k, s in plan]
    pids = client.run(os.getpid)
    deadline = time.time() + 60
    while not any(client.processing().values()) and time.time() < deadline:
        time.sleep(0.05)
    busy = next(addr for addr, tasks in client.processing().items() if tasks)
    os.kill(pids[busy], signal.SIGKILL)  # a worker dies in the middle of its task
    results = client.gather(futures)
    merged = C.merge_passes(results, [k for k, _ in plan])
    np.testing.assert_allclose(merged, reference, rtol=1e-6, atol=1e-7)


def _sigint_default():
    """The child hears SIGINT whatever this test process inherited or set (a disposition or a mask)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_cancels_the_cluster_and_keeps_the_finished_passes(tmp_path):
    import re
    import subprocess
    import sys
    import threading

    scene, out = scene_file(tmp_path), tmp_path / "partial.exr"
    p = subprocess.Popen([sys.executable, "-m", "motes", "render", str(scene), "-s", "2000", "--pass-spp", "4",
                          "--workers", "2", "-D", "count=3000", "-o", str(out)], stderr=subprocess.PIPE,
                         preexec_fn=_sigint_default)
    err = bytearray()
    reader = threading.Thread(target=lambda: [err.extend(chunk) for chunk in iter(lambda: p.stderr.read(64), b"")])
    reader.start()
    deadline = time.time() + 120
    while time.time() < deadline and not re.search(rb"([2-9]|\d\d+)/500 passes", bytes(err)):
        time.sleep(0.1)
    p.send_signal(signal.SIGINT)
    rc = p.wait(timeout=120)
    reader.join(timeout=10)
    text = bytes(err).decode(errors="replace")
    assert rc == 130, text[-2000:]
    assert "cancelled" in text and "kept" in text, text[-2000:]
    kept = int(re.search(r"kept (\d+) spp", text).group(1))
    assert 8 <= kept < 2000 and out.exists() and read(out).mean() > 0
