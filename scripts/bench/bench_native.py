"""Issue 10: the native render path against Mitsuba's own `homogeneous` + `tabphase` equivalent, side by
side in one process, interleaved (ratios only; this machine is shared).

For each configuration -- `sparse` (the default scene's dust in the dust room), `dense` (haze: many
larger grains, wider query cylinder) and `default` (scenes_xml/dust_box.xml itself; its homogeneous twin is
the same XML with the medium replaced by `motes.equivalent.equivalent_xml`) -- and each variant
(llvm_ad_rgb in Mitsuba's default symbolic mode; scalar_rgb), it renders at equal spp:

* `homogeneous`: Mitsuba's `homogeneous` + `tabphase` (symbolic mode in LLVM);
* `discrete native`: the `discrete` medium through the native C++ plugin (symbolic mode in LLVM);
* `discrete evaluated`: the `discrete` medium through the evaluated-mode Python path (LLVM only; what
  every render used before the native path: the "before" of issue 10).

Reported: seconds (best of `--reps` interleaved repetitions after a warm-up render that compiles the
kernels), the ratio to `homogeneous`, and the image means of the discrete paths with their standard
errors (the two paths must agree). `--memory` also measures the peak resident memory of the default
scene's render in a fresh process per path (see `memory`).

    .venv/bin/python scripts/bench/bench_native.py [--quick] [--configs sparse,dense,default] [--memory]
    .venv/bin/python scripts/bench/bench_native.py --configs sparse --res 256 --spp 64 --native-only
"""

from __future__ import annotations

import json
import pathlib
import re
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import bench_render as BR  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes_xml" / "dust_box.xml"
KNOWN = ("sparse", "dense", "default")


def default_medium_density_m3() -> tuple[dict, float]:
    """The default scene's dust (median, sigma_g, count) and its number density, read from dust_box.xml:
    generated particles fill the medium's local cube [-1, 1]^3 placed by its to_world scale (cm)."""
    import xml.etree.ElementTree as ET  # noqa: PLC0415

    root = ET.parse(SCENE).getroot()
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    medium = next(m for m in root.iter("medium") if m.get("type") == "discrete")
    value = lambda name: next(c.get("value") for c in medium if c.get("name") == name)  # noqa: E731
    scale = next(medium.iter("scale"))
    half = [float(scale.get(a, scale.get("value", 1))) for a in "xyz"]
    count = int(defaults[value("count").lstrip("$")] if value("count").startswith("$") else value("count"))
    volume_m3 = float(np.prod([2 * h * float(value("scale_m")) for h in half]))
    cfg = dict(count=count, median=float(value("radius_median")), sigma_g=float(value("radius_sigma_g")))
    return cfg, count / volume_m3


def default_scene_xml(motes, homogeneous: bool) -> str:
    """dust_box.xml, or the same scene with its medium replaced by the homogeneous equivalent."""
    text = SCENE.read_text()
    if not homogeneous:
        return text
    cfg, n_m3 = default_medium_density_m3()
    sp = motes.Species(motes.LogNormal(cfg["median"], cfg["sigma_g"]), complex(1.55, 0.0005))
    d = motes.homogeneous_equivalent(sp, n_m3, color="rgb", scale_m=0.01, tabphase_size=BR.TAB_SIZE)
    snippet = motes.equivalent.equivalent_xml(d)
    return re.sub(r'<medium type="discrete".*?</medium>', lambda _: snippet, text, flags=re.S)


def scenes(motes, mi, name: str, res: int, spp: int):
    """(homogeneous scene, discrete scene) of a configuration."""
    if name == "default":
        params = {"res": str(res), "spp": str(spp)}
        load = lambda xml: mi.load_string(xml, **params)  # noqa: E731
        # load_string resolves no relative paths: the scene uses none.
        return load(default_scene_xml(motes, True)), load(default_scene_xml(motes, False))
    cfg = BR.configs(True)[name]
    return (mi.load_dict(BR.room(mi, BR.homogeneous_dict(motes, cfg), res, spp)),
            mi.load_dict(BR.room(mi, BR.discrete_dict(mi, cfg, res), res, spp)))


def render(mi, scene, spp: int, seed: int = 0):
    t = time.perf_counter()
    img = np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    return time.perf_counter() - t, img


def mean_se(img: np.ndarray) -> tuple[float, float]:
    px = img.mean(axis=2).ravel()
    return float(px.mean()), float(px.std() / np.sqrt(px.size))


def run_variant(motes, mi, variant: str, names, res: int, spp: int, reps: int, evaluated: bool = True) -> list[dict]:
    motes.set_variant(variant)
    jit = variant.startswith("llvm_")
    rows = []
    for name in names:
        sh, sd = scenes(motes, mi, name, res, spp)
        paths = {"homogeneous": (sh, False), "discrete native": (sd, False)}
        if jit and evaluated:
            paths["discrete evaluated"] = (sd, True)
        best = {k: np.inf for k in paths}
        imgs = {}
        for rep in range(reps + 1):  # rep 0 compiles the kernels
            for key, (scene, evaluated) in paths.items():
                if jit:
                    motes.set_evaluated_mode(evaluated)
                t, img = render(mi, scene, spp, seed=rep)
                if rep > 0:
                    best[key] = min(best[key], t)
                    imgs[key] = img
        if jit:
            motes.set_evaluated_mode(False)
        row = {"config": name, "variant": variant, "res": res, "spp": spp}
        for key in paths:
            m, se = mean_se(imgs[key])
            row[key] = {"seconds": best[key], "ratio": best[key] / best["homogeneous"], "mean": m, "se": se}
        rows.append(row)
        cells = "  ".join(f"{k} {v['seconds']:.2f} s ({v['ratio']:.2f}x, mean {v['mean']:.4g} +- {v['se']:.2g})"
                          for k, v in row.items() if isinstance(v, dict))
        print(f"[{variant} {name} {res}px {spp}spp] {cells}", flush=True)
        del sh, sd
    return rows


MEMORY_CHILD = """
import sys, time
import numpy as np
import motes
motes.set_variant("llvm_ad_rgb")
motes.set_evaluated_mode(sys.argv[1] == "evaluated")
import mitsuba as mi
params = {"res": sys.argv[3], "spp": sys.argv[4]} if len(sys.argv) > 3 else {}
scene = mi.load_file(sys.argv[2], **params)
t = time.perf_counter()
# Always the spp asked for (a render with spp= changes the sampler's count for later ones).
img = np.asarray(mi.render(scene, spp=scene.sensors()[0].sampler().sample_count()))
from motes._memory import peak_resident_mb  # this process's own peak (VmHWM)
print("RESULT", time.perf_counter() - t, peak_resident_mb(), float(img.mean()))
"""


def memory() -> dict:
    """Peak resident memory (MiB) and time of the main job's render: the native path at the scene's own
    settings (what `motes render` does, but in one pass), and both paths at 256 px, 48 spp (the evaluated
    path keeps ~1.7 kB per sample: at the scene's own settings it would need ~20 GB)."""
    out = {}
    for path, res, spp in (("native", None, None), ("native", "256", "48"), ("evaluated", "256", "48")):
        extra = [res, spp] if res else []
        res_ = subprocess.run([sys.executable, "-c", MEMORY_CHILD, path, str(SCENE), *extra], capture_output=True, text=True, timeout=3600)
        line = [ln for ln in res_.stdout.splitlines() if ln.startswith("RESULT")]
        if res_.returncode != 0 or not line:
            raise RuntimeError(f"memory child ({path}) failed:\n{res_.stderr[-2000:]}")
        _, secs, mib, mean = line[0].split()
        key = f"{path} {res or 'scene'} px {spp or 'scene'} spp"
        out[key] = {"seconds": float(secs), "peak_mib": float(mib), "mean": float(mean)}
        print(f"[memory] default scene, {key}: peak {float(mib):.0f} MiB, {float(secs):.1f} s, mean {float(mean):.4g}", flush=True)
    out["ratio"] = out["evaluated 256 px 48 spp"]["peak_mib"] / out["native 256 px 48 spp"]["peak_mib"]
    print(f"[memory] evaluated / native peak memory at 256 px 48 spp: {out['ratio']:.2f}x", flush=True)
    return out


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--memory", action="store_true", help="also the default scene's peak memory (slow)")
    ap.add_argument("--configs", default=",".join(KNOWN), help=f"configurations, of {list(KNOWN)}")
    ap.add_argument("--res", type=int, default=None, help="film width and height (default 128; --quick 96)")
    ap.add_argument("--spp", type=int, default=None, help="samples per pixel (default 16; --quick 8)")
    ap.add_argument("--native-only", action="store_true",
                    help="llvm_ad_rgb native against homogeneous only (no evaluated path, no scalar_rgb)")
    args = ap.parse_args()
    names = C.choose_configs(ap, args.configs, KNOWN)
    motes = C.import_motes()
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi  # noqa: PLC0415
    t0 = time.perf_counter()
    res, spp = (96, 8) if args.quick else (128, 16)
    res, spp = args.res or res, args.spp or spp
    rows = run_variant(motes, mi, "llvm_ad_rgb", names, res, spp, args.reps, evaluated=not args.native_only)
    if not args.native_only:
        # The same film and spp: scalar_rgb's scene medium is the native plugin itself (no Python per ray).
        rows += run_variant(motes, mi, "scalar_rgb", names, res, spp, args.reps)
    result = {"rows": rows, "meta": C.meta(args, time.perf_counter() - t0)}
    if args.memory:
        result["memory"] = memory()
    out = C.out_dir(args.out)
    C.write_json(out / "bench_native.json", result)
    print(json.dumps({"written": str(out / "bench_native.json")}))


if __name__ == "__main__":
    main()
