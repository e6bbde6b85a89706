"""Issue 24: clouds at the paper's scale and past it. For each count, in a fresh subprocess (so that peak
memory is the load's own): load time, peak resident memory of the whole process, bytes per particle the
medium keeps at render time, and the render time.

The scene is what a new user writes: a ``discrete`` medium in a 10 cm cube (``count`` generated grains,
log-normal radii, median 50 um, sigma_g 1.5, ``material`` ice, scale 1 cm, ``query_radius`` 0.02) lit by a
spot light in a grey room (``scripts/bench/bench_render.py``'s dust room), ``volpath`` max_depth 6,
128 x 128 px, 8 spp, ``llvm_ad_rgb`` (``--variant``).

* ``load``: ``mi.load_dict`` of the scene (particles generated, optics tables, grid), seconds;
* ``peak``: the process's peak resident memory (VmHWM) after the load and the render, GB (the interpreter,
  Mitsuba and Dr.Jit included: ~0.3 GB before any particle);
* ``B/particle``: the medium's own bytes (``DiscreteMedium.bytes``) over the count;
* ``render``: one render after the load (the first, JIT compilation included), then a second one.

With ``--scene nave`` (for ``--storage procedural``, counts up to 10^12): dust in a cathedral nave, a
40 x 20 x 20 m box (scale 1 m) seen from half a metre outside one end (fov 60), lit by a low sun and a dim
sky: a mixture of fine dust (log-normal, median 2 um, sigma_g 1.6, eta 1.5) and, one grain in 10^5,
motes (median 100 um, sigma_g 1.3), query radius from Eq. 23 (k 0.7 at 0.5 m). Whatever is continuous
(``continuous`` in the JSON rows) is the density field's expected extinction, whatever stays discrete is
generated brick by brick where rays go; ``B/particle`` is then the medium's bytes after the renders (the
bricks in its cache) over the count.

With ``--discrete`` every grain of the room's cube stays discrete and stored (``continuous_count`` = inf: no
size class is seen as a continuous medium), the case where the grid holds every particle.

With ``--source file`` the grains come from a particle file instead (``filename``: an uncompressed .npz of
float64 positions in [-1, 1]^3, float64 radii and uint32 species, written beforehand by another process
from the same generator; its reading is part of the load); with ``--source ply`` a binary PLY (float64
x y z radius, int32 species; read with meshio) instead.

    .venv/bin/python scripts/bench/bench_scale.py [--counts 1e6,1e7] [--storage compact] [--variant scalar_rgb] [--source file|ply]
    .venv/bin/python scripts/bench/bench_scale.py --discrete --counts 1e6,1e7,1e8
    .venv/bin/python scripts/bench/bench_scale.py --storage procedural [--counts 1e6,1e8]
    .venv/bin/python scripts/bench/bench_scale.py --storage procedural --scene nave --counts 1e10,1e11,1e12
    .venv/bin/python scripts/bench/bench_scale.py --storage procedural --scene nave --counts 1e8 --res 32 --spp 1 [--cache-mb 16000]
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import _common as C  # noqa: E402

HALF = 5.0  # cm: the cube's half-size


def write_file(count: float, path: str) -> None:
    """An .npz (or, for a path ending in .ply, a binary PLY) of ``count`` grains (the plugin's generator, in
    the local cube), written in this process."""
    import numpy as np  # noqa: PLC0415

    motes = C.import_motes()
    psd = motes.LogNormal(50.0, 1.5)
    ident = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0]]
    c, r, s = motes._motes.generate_cloud(int(count), [-1.0] * 3, [1.0] * 3, "uniform", [], 0, [psd._core], [1.0], 0,
                                          ident)
    if path.endswith(".ply"):  # binary PLY: float64 x y z radius, int32 species (motes.save_particles)
        motes.save_particles(path, motes.ParticleSet(c.reshape(-1, 3), r, s.astype(np.int64)))
    else:
        np.savez(path, positions=c.reshape(-1, 3), radii_um=r, species=s)


def nave(mi, count: float, res: int, spp: int, cache_mb: float | None = None) -> dict:
    """Dust in a cathedral nave (module docs) as a scene dict."""
    T = mi.ScalarTransform4f
    species = json.dumps([{"psd": {"type": "lognormal", "median_um": 2.0, "sigma_g": 1.6}, "eta": 1.5, "share": 1.0},
                          {"psd": {"type": "lognormal", "median_um": 100.0, "sigma_g": 1.3}, "eta": 1.5, "share": 1e-5}])
    box = T().translate([0, 0, 10]).scale([20, 10, 10])
    medium = {"type": "discrete", "count": int(count), "species": species, "scale_m": 1.0, "footprint_k": 0.7,
              "fov": 60.0, "film_width": res, "z_med": 0.5, "storage": "procedural", "to_world": box,
              "phase": {"type": "particle"}}
    if cache_mb:
        medium["cache_mb"] = float(cache_mb)
    stone = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.45, 0.42, 0.38]}}
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 60, "to_world": T().look_at(origin=[-20.5, 0, 1.7], target=[0, 0, 4], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "gaussian"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sun": {"type": "directional", "direction": [0.5, 0.6, -0.45], "irradiance": {"type": "rgb", "value": [9, 8.5, 7.5]}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.05, 0.06, 0.08]}},
        "floor": {"type": "rectangle", "to_world": T().scale([20, 10, 1]), "bsdf": stone},
        "air": {"type": "cube", "to_world": box, "bsdf": {"type": "null"}, "interior": medium},
    }


def child(count: float, storage: str, variant: str, res: int, spp: int, filename: str | None = None,
          scene_name: str = "room", cache_mb: float | None = None, discrete: bool = False) -> dict:
    """One row, measured in this (fresh) process."""
    import numpy as np  # noqa: PLC0415

    motes = C.import_motes()
    motes.set_variant(variant)
    import mitsuba as mi  # noqa: PLC0415

    import bench_render as BR  # noqa: PLC0415

    from motes import _memory  # noqa: PLC0415

    before = _memory.peak_resident_mb()
    if scene_name == "nave":
        return measure(mi, np, _memory, nave(mi, count, res, spp, cache_mb), count, storage, variant, before)
    medium = {"type": "discrete", "count": int(count), "radius_median": 50.0, "radius_sigma_g": 1.5,
              "material": "ice", "scale_m": 0.01, "query_radius": 0.02, "phase": {"type": "particle"},
              "to_world": mi.ScalarTransform4f().scale(HALF)}  # the cube's own (the medium does not inherit it)
    if filename:
        medium = {k: v for k, v in medium.items() if k not in ("count", "radius_median", "radius_sigma_g")}
        medium["filename"] = filename
    if storage:
        medium["storage"] = storage
    if discrete:
        medium["continuous_count"] = float("inf")
    scene = BR.room(mi, medium, res, spp, max_depth=6)
    scene["cube"]["to_world"] = mi.ScalarTransform4f().scale(HALF)
    return measure(mi, np, _memory, scene, count, storage, variant, before)


def measure(mi, np, _memory, scene: dict, count: float, storage: str, variant: str, before: float) -> dict:
    """Load ``scene``, render it twice; the row."""
    t = time.perf_counter()
    sc = mi.load_dict(scene)
    load = time.perf_counter() - t
    med = next(s.interior_medium() for s in sc.shapes() if s.interior_medium() is not None)
    kept = med.data.bytes
    times = []
    for _ in range(2):
        t = time.perf_counter()
        img = np.asarray(mi.render(sc), dtype=np.float64)
        times.append(time.perf_counter() - t)
    # A procedural medium's bytes grow with the bricks a render builds: counted after the renders.
    kept = max(kept, med.data.bytes)
    return {"count": count, "storage": storage or "default", "variant": variant, "load_s": load,
            "peak_gb": _memory.peak_resident_mb() * 2**20 / 1e9, "before_gb": before * 2**20 / 1e9,
            "bytes_per_particle": kept / count, "medium_mb": kept / 1e6, "render_first_s": times[0],
            "render_s": times[1], "continuous": float(med.data.continuous_particles),
            "image_mean": float(img.mean()), "finite": bool(np.all(np.isfinite(img)))}


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--counts", default="1e6,3e6,1e7,3e7,1e8", help="comma-separated counts")
    ap.add_argument("--storage", default="", help="the medium's storage parameter (default: not set)")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per row")
    ap.add_argument("--source", default="generated", choices=["generated", "file", "ply"],
                    help="generated grains, or grains read from an .npz (file) or a binary PLY (ply) file")
    ap.add_argument("--scene", default="room", choices=["room", "nave"])
    ap.add_argument("--cache-mb", type=float, default=None, help="the nave's cache_mb (default: the plugin's)")
    ap.add_argument("--discrete", action="store_true", help="every grain discrete (continuous_count = inf)")
    ap.add_argument("--child", type=float, default=None, help=argparse_hidden())
    ap.add_argument("--file", default=None, help=argparse_hidden())
    ap.add_argument("--write", action="store_true", help=argparse_hidden())
    args = ap.parse_args()
    if args.child is not None and args.write:
        write_file(args.child, args.file)
        return
    if args.child is not None:
        print("RESULT " + json.dumps(child(args.child, args.storage, args.variant, args.res, args.spp, args.file,
                                           args.scene, args.cache_mb, args.discrete)))
        return
    out, sw = C.out_dir(args.out), C.Stopwatch()
    rows = []
    for count in [float(c) for c in args.counts.split(",")]:
        cmd = [sys.executable, __file__, "--child", repr(count), "--storage", args.storage, "--variant",
               args.variant, "--res", str(args.res), "--spp", str(args.spp), "--scene", args.scene]
        if args.cache_mb:
            cmd += ["--cache-mb", str(args.cache_mb)]
        if args.discrete:
            cmd += ["--discrete"]
        path = None
        if args.source in ("file", "ply"):
            path = str(out / f"bench_scale_{count:.0e}.{'npz' if args.source == 'file' else 'ply'}")
            subprocess.run(cmd + ["--write", "--file", path], check=True, timeout=args.timeout)
            cmd += ["--file", path]
        t = time.perf_counter()
        try:
            run = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
            lines = [ln for ln in run.stdout.splitlines() if ln.startswith("RESULT ")]
            if run.returncode == 0 and lines:
                row = json.loads(lines[-1][7:])
            else:
                tail = (run.stderr.strip().splitlines() or ["(no output)"])[-1]
                row = {"count": count, "error": tail[:200]}
        except subprocess.TimeoutExpired:
            row = {"count": count, "error": f"over {args.timeout:.0f} s"}
        row["wall_s"] = time.perf_counter() - t
        row["source"] = args.source
        if path:
            pathlib.Path(path).unlink(missing_ok=True)
        rows.append(row)
        if "error" in row:
            print(f"[{count:.0e}] {row['error']}", flush=True)
        else:
            print(f"[{count:.0e}] load {row['load_s']:.1f} s, peak {row['peak_gb']:.2f} GB, "
                  f"{row['bytes_per_particle']:.3g} B/particle ({row['medium_mb']:.0f} MB), render "
                  f"{row['render_first_s']:.2f} s (again {row['render_s']:.2f} s), continuous "
                  f"{row['continuous']:.3g}, mean {row['image_mean']:.4g}", flush=True)
    C.print_table(f"**{args.variant}, {args.scene}{' (all discrete)' if args.discrete else ''}, {args.source} grains, "
                  f"storage {args.storage or 'default'}, "
                  f"{args.res}^2 px, {args.spp} spp**",
                  ["count", "load (s)", "peak (GB)", "B/particle", "medium (MB)", "render (s)", "again (s)"],
                  [[f"{r['count']:.0e}", r.get("load_s", r.get("error")), r.get("peak_gb", "-"),
                    r.get("bytes_per_particle", "-"), r.get("medium_mb", "-"), r.get("render_first_s", "-"),
                    r.get("render_s", "-")] for r in rows])
    tag = (f"_cache{args.cache_mb:.0f}" if args.cache_mb else "") + ("_discrete" if args.discrete else "")
    C.finish(args, sw, out / f"bench_scale_{args.variant}_{args.scene}_{args.source}_{args.storage or 'default'}{tag}.json",
             rows=rows)


def argparse_hidden() -> str:
    import argparse  # noqa: PLC0415

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
