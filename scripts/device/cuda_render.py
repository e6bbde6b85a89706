"""Issue 46 on a GPU: scenes rendered with ``kernel = "drjit"`` in ``cuda_ad_rgb`` against references.

* ``dust_box`` (the shipped scene, every grain walked: the drjit kernel's exact medium) at ``--res`` px and
  ``--spp`` spp, ``--seeds`` sampler seeds, against the same renders made on the CPU in ``llvm_ad_rgb`` with the
  same kernel (``--reference DIR`` writes them, here; the device has no libLLVM): z of the image means (SE from
  the seeds), per-pixel RMS difference over the noise (1 = at noise level), seconds per render of each;
* a generated cloud of ``--count`` grains (10^8 by default; glass, median radius 20 um, in a 10 cm cube of 2 cm
  scene units: optical depth ~20 across at 10^8, under a uniform sky), ``kernel = drjit`` in
  ``cuda_ad_rgb`` against the native kernel with ``continuous_count = inf`` in ``scalar_rgb`` on the same
  machine's CPUs (same grains: same ``seed``): z, RMS/noise, seconds, load time and GPU memory of the grains.

Writes ``render.json`` and ``kernel_history.json`` to ``--out`` and prints a table.

    python3 scripts/device/cuda_render.py --reference .device/reference     # here, before packing
    python3 scripts/device/cuda_render.py --out $OUT [--count 1e8]           # there (scripts/device/run.sh)
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "mitsuba_plugin"))
sys.path.insert(0, str(ROOT / "scripts" / "bench"))
sys.path.insert(0, str(ROOT / "scripts" / "device"))

import bench_drjit_kernel  # noqa: E402
from cuda_check import write_kernel_history  # noqa: E402


def dust_box(mi, res: int, kernel_tags: str):
    text = (ROOT / "scenes_xml" / "dust_box.xml").read_text()
    text = re.sub(r'(<medium type="discrete"[^>]*>)', lambda m: m.group(1) + kernel_tags, text)
    return mi.load_string(text, res=res)


def cloud(mi, count: float, res: int, extra: dict):
    T = mi.ScalarTransform4f
    medium = {"type": "discrete", "count": float(count), "radius_median": 20.0, "eta": 1.5,
              "scale_m": 0.02, "seed": 7, **extra}
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath", "max_depth": 8},
        "sensor": {"type": "perspective", "fov": 35, "to_world": T().look_at(origin=[0, 1, 9], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.9, 0.95, 1.0]}},
        "box": {"type": "cube", "to_world": T().scale(2.5), "bsdf": {"type": "null"}, "interior": medium}})


def renders(mi, scene, spp: int, seeds: int) -> tuple[np.ndarray, float]:
    import drjit as dr

    np.asarray(mi.render(scene, spp=spp, seed=10_000))  # warm-up: the kernels compile
    imgs, t0 = [], time.perf_counter()
    for s in range(seeds):
        imgs.append(np.asarray(mi.render(scene, spp=spp, seed=s), dtype=np.float64))
    dr.sync_thread()
    return np.stack(imgs), (time.perf_counter() - t0) / seeds


def compare(a: np.ndarray, b: np.ndarray) -> dict:
    """Image means, z and RMS/noise (``bench_drjit_kernel.compare``) of renders ``a`` against ``b``."""
    z, rms = bench_drjit_kernel.compare(a, b)
    return {"mean": float(a.mean()), "reference_mean": float(b.mean()), "z": z, "rms_over_noise": rms}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reference", default="", help="write the llvm_ad_rgb references to this folder (here)")
    ap.add_argument("--out", default=os.environ.get("OUT", "out"))
    ap.add_argument("--references", default=str(ROOT / ".device" / "reference"), help="where --reference wrote them")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--count", type=float, default=1e8)
    ap.add_argument("--cloud-res", type=int, default=64)
    ap.add_argument("--cloud-spp", type=int, default=16)
    ap.add_argument("--variant", default="cuda_ad_rgb")
    args = ap.parse_args()
    import drjit as dr
    import motes

    drjit_tags = '<string name="kernel" value="drjit"/>'
    if args.reference:
        ref = pathlib.Path(args.reference)
        ref.mkdir(parents=True, exist_ok=True)
        import mitsuba as mi

        motes.set_variant("llvm_ad_rgb")
        imgs, sec = renders(mi, dust_box(mi, args.res, drjit_tags), args.spp, args.seeds)
        np.save(ref / "dust_box_llvm_drjit.npy", imgs.astype(np.float32))
        (ref / "dust_box.json").write_text(json.dumps({"res": args.res, "spp": args.spp, "seeds": args.seeds,
                                                       "seconds_per_render": sec}))
        print(f"dust_box reference: {args.seeds} x {args.res} px x {args.spp} spp in llvm_ad_rgb, {sec:.2f} s a render")
        return 0

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    import mitsuba as mi

    motes.set_variant(args.variant)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    result = {"variant": args.variant}
    ref_dir = pathlib.Path(args.references)
    meta = json.loads((ref_dir / "dust_box.json").read_text())
    reference = np.load(ref_dir / "dust_box_llvm_drjit.npy").astype(np.float64)
    imgs, sec = renders(mi, dust_box(mi, meta["res"], drjit_tags), meta["spp"], meta["seeds"])
    result["dust_box"] = {**compare(imgs, reference), "seconds_per_render": sec,
                          "llvm_seconds_per_render_there": meta["seconds_per_render"]}
    print("dust_box, drjit:", result["dust_box"], flush=True)
    (out / "render.json").write_text(json.dumps(result, indent=1))

    t0 = time.perf_counter()
    scene = cloud(mi, args.count, args.cloud_res, {"kernel": "drjit"})
    load = time.perf_counter() - t0
    gpu, sec = renders(mi, scene, args.cloud_spp, args.seeds)
    medium = next(s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None)
    result["cloud"] = {"count": args.count, "load_s": load, "seconds_per_render": sec,
                       "grain_bytes": int(getattr(medium.data, "bytes", 0))}
    print("cloud, drjit:", result["cloud"], flush=True)
    (out / "render.json").write_text(json.dumps(result, indent=1))
    del scene, medium
    motes.set_variant("scalar_rgb")
    t0 = time.perf_counter()
    scene = cloud(mi, args.count, args.cloud_res, {"continuous_count": float("inf")})
    cpu_load = time.perf_counter() - t0
    cpu, cpu_sec = renders(mi, scene, args.cloud_spp, args.seeds)
    result["cloud"].update(compare(gpu, cpu), cpu_seconds_per_render=cpu_sec, cpu_load_s=cpu_load)
    print("cloud against scalar_rgb native exact:", result["cloud"], flush=True)
    (out / "render.json").write_text(json.dumps(result, indent=1))
    write_kernel_history(out)
    ok = abs(result["dust_box"]["z"]) < 3 and abs(result["cloud"]["z"]) < 3
    print("OK" if ok else "MISMATCH")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
