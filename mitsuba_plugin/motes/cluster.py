"""Frame sequences and renders spread over processes or machines (``motes render --frames``, ``--workers``,
``--scheduler``), with Dask's ``distributed`` as the engine.

Work units
----------
* **A pass**: ``spp`` samples of one image with one sampler seed. One image of S spp is cut into passes
  of ``pass_spp`` samples with seeds ``seed * 100003 + i`` (the same plan as the single-process
  ``motes render``); the passes are merged by sample count, in pass order, in float64. A render is a
  function of (scene, seed, spp), so the merged image equals the single-process one.
* **A frame**: all passes of one frame of a sequence, rendered by one worker (scene parameters
  ``$frame`` and ``$time`` = frame / fps), written by the client as soon as it arrives.

Workers keep the scenes they loaded (keyed by file, parameters and variant), so that the passes of one
image do not reload it. A worker that dies in the middle of a task (killed, out of memory) loses only
that task: the scheduler runs it again on another worker, with the same seed, so nothing changes in the
result. Files reach workers by path (a file system every worker sees, e.g. NFS on a cluster) or, with
``ship_files``, by value: the scene XML and every file it names in a ``filename`` parameter travel with
each task and are written to a per-worker temporary folder.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import re
import tempfile
import threading
from dataclasses import dataclass, field

import numpy as np

from . import _env
from ._output import check_film, output_path

#: Frames per second of ``motes render --frames`` ($time = frame / fps; ``frame_defines``).
DEFAULT_FPS = 24.0
#: Sampler seed of pass ``i`` of an image rendered with ``--seed s``: ``s * PASS_SEED_STRIDE + i`` (mod 2^32).
PASS_SEED_STRIDE = 100003


def pass_plan(spp: int, pass_spp: int, seed: int) -> list[tuple[int, int]]:
    """(samples, sampler seed) of each pass of an image of ``spp`` samples."""
    if spp < 1 or pass_spp < 1:
        raise ValueError(f"spp and pass_spp must be >= 1, got {spp} and {pass_spp}")
    per = min(pass_spp, spp)
    plan, done = [], 0
    for i in range((spp + per - 1) // per):
        k = min(per, spp - done)
        # Mitsuba's sampler seed is 32-bit: wrapped, so that any --seed works (distinct below 42 950).
        plan.append((k, (seed * PASS_SEED_STRIDE + i) % 2**32))
        done += k
    return plan


def samples_per_pixel(spp: int | None, scene_spp: int) -> int:
    """The samples per pixel of a render: ``spp`` (``-s``; checked >= 1 with the other options), else the
    scene's sampler's, which must be >= 1 too."""
    if spp is not None:
        return spp
    if scene_spp < 1:
        raise ValueError(f"the scene's sampler has sample_count {scene_spp}: give -s N (N >= 1)")
    return scene_spp


def merge_passes(images, counts) -> np.ndarray:
    """The average of pass images weighted by their sample counts, summed in the order given (float64)."""
    acc, total = None, 0
    for img, k in zip(images, counts):
        img = np.asarray(img, dtype=np.float64)
        acc = img * k if acc is None else acc + img * k
        total += k
    if acc is None:
        raise ValueError("no passes to merge")
    return acc / total


def parse_frames(spec: str) -> range:
    """``A:B[:STEP]`` (inclusive of B) or a single frame ``A``, as a ``range``: never expanded, so that any
    range is checked at once and its frames come one at a time (``frame_count`` counts them)."""
    parts = spec.split(":")
    try:
        nums = [int(p) for p in parts]
    except ValueError:
        raise ValueError(f"--frames expects A:B[:STEP] with integers, got {spec!r}") from None
    if len(nums) == 1:
        nums = [nums[0], nums[0]]
    if len(nums) not in (2, 3):
        raise ValueError(f"--frames expects A:B[:STEP], got {spec!r}")
    a, b, step = nums[0], nums[1], nums[2] if len(nums) == 3 else 1
    if step < 1 or b < a:
        raise ValueError(f"--frames {spec!r}: need A <= B and STEP >= 1")
    return range(a, b + 1, step)


def frame_count(frames: range) -> int:
    """The number of frames of ``parse_frames``'s range (``len`` takes at most 2^63 - 1)."""
    return max(0, (frames.stop - frames.start + frames.step - 1) // frames.step)


def frame_output(pattern: str | None, stem: str, frame: int) -> pathlib.Path:
    """Where frame ``frame`` goes: ``pattern`` with ``{frame}`` (format specs allowed: ``{frame:05d}``)
    filled in, or ``_0001`` inserted before the suffix when it has none; default ``out/STEM_0001.exr``
    (the rules, a folder included: ``motes._output.output_path``)."""
    return output_path(pattern, stem, frame)


def frame_defines(defines: dict, frame: int, fps: float, scene_text: str) -> dict:
    """The scene parameters of a frame: the user's, plus ``frame`` and ``time`` = frame / fps (seconds)
    where the scene uses them (Mitsuba refuses parameters a scene does not use)."""
    d = dict(defines)
    if re.search(r"\$frame\b", scene_text):
        d["frame"] = str(frame)
    if re.search(r"\$time\b", scene_text):
        d["time"] = repr(frame / fps)
    return d


# --- files by value -----------------------------------------------------------------------------------

_FILENAME = re.compile(r'name\s*=\s*"filename"\s+value\s*=\s*"([^"]+)"|value\s*=\s*"([^"]+)"\s+name\s*=\s*"filename"')


def _xml_defaults(text: str) -> dict:
    """The scene's ``<default name=... value=.../>`` parameters."""
    out = {}
    for m in re.finditer(r"<default\s+([^>]*)/>", text):
        attrs = dict(re.findall(r'(\w+)\s*=\s*"([^"]*)"', m.group(1)))
        if "name" in attrs and "value" in attrs:
            out[attrs["name"]] = attrs["value"]
    return out


def referenced_files(scene_path: pathlib.Path, defines: dict) -> dict[str, bytes]:
    """The scene XML and every file it names in a ``filename`` parameter (``$name`` filled in from
    ``defines`` over the scene's defaults; relative to the scene's folder), as {path relative to the
    scene's folder: bytes}. Files are sent under the scene's folder only: an absolute path, one with
    ``..`` or a missing file is an error naming it."""
    text = scene_path.read_text()
    params = {**_xml_defaults(text), **{k: str(v) for k, v in defines.items()}}
    files = {scene_path.name: text.encode()}
    for m in _FILENAME.finditer(text):
        value = m.group(1) or m.group(2)
        for k, v in sorted(params.items(), key=lambda kv: -len(kv[0])):
            value = value.replace(f"${k}", v)
        p = pathlib.Path(value)
        if p.is_absolute() or ".." in p.parts:
            raise ValueError(f"--ship-files sends files from the scene's folder; {value!r} is outside it: move it "
                             "there, or let the workers read it from a shared file system (no --ship-files)")
        full = scene_path.parent / p
        if not full.is_file():
            raise FileNotFoundError(f"--ship-files: the scene names {value!r}, which is not a file in {scene_path.parent}")
        files[str(p)] = full.read_bytes()
    return files


def _materialise(files: dict[str, bytes], scene_name: str) -> pathlib.Path:
    """Write shipped files into a folder named by their content hash (once per worker); the scene's path."""
    h = hashlib.sha256()
    for k in sorted(files):
        h.update(k.encode())
        h.update(files[k])
    folder = pathlib.Path(tempfile.gettempdir()) / f"motes-shipped-{h.hexdigest()[:16]}"
    for rel, data in files.items():
        target = folder / rel
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, target)
    return folder / scene_name


# --- the worker side ----------------------------------------------------------------------------------

@dataclass
class _SceneCache:
    """Scenes a worker process has loaded, by (file, parameters, variant); the newest few are kept."""

    keep: int = 2
    threads_set: bool = False
    scenes: dict = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def get(self, path: str, defines: dict, variant: str):
        import motes  # noqa: PLC0415

        motes.set_variant(variant)
        import mitsuba as mi  # noqa: PLC0415

        threads = _env.worker_threads()
        if threads is not None and not self.threads_set:  # a local cluster's share of the cores per worker
            import drjit as dr  # noqa: PLC0415

            dr.set_thread_count(threads)
            self.threads_set = True

        key = (path, tuple(sorted(defines.items())), variant)
        with self.lock:
            if key not in self.scenes:
                while len(self.scenes) >= self.keep:
                    self.scenes.pop(next(iter(self.scenes)))
                scene = mi.load_file(path, **defines)
                check_film(scene.sensors()[0].film(), defines)
                self.scenes[key] = scene
            return mi, self.scenes[key]


_CACHE = _SceneCache()


def _scene_file(scene: str, files: dict | None) -> str:
    return str(_materialise(files, pathlib.Path(scene).name)) if files else scene


def render_pass(scene: str, defines: dict, variant: str, spp: int, seed: int, files: dict | None = None) -> np.ndarray:
    """One pass (a Dask task): ``spp`` samples with sampler ``seed``; float32 image."""
    mi, sc = _CACHE.get(_scene_file(scene, files), defines, variant)
    return np.asarray(mi.render(sc, spp=int(spp), seed=int(seed)), dtype=np.float32)


def render_image(scene: str, defines: dict, variant: str, plan, files: dict | None = None) -> np.ndarray:
    """All passes of one image (a frame task), merged as ``merge_passes`` does; float32 image."""
    imgs = [render_pass(scene, defines, variant, k, s, files) for k, s in plan]
    return merge_passes(imgs, [k for k, _ in plan]).astype(np.float32)


__all__ = ["DEFAULT_FPS", "PASS_SEED_STRIDE", "frame_count", "frame_defines", "frame_output", "merge_passes",
           "parse_frames", "pass_plan", "referenced_files", "render_image", "render_pass", "samples_per_pixel"]
