"""Issue 25: the shipped scenes against Mitsuba's `homogeneous` + `tabphase` equivalent of their grains, side by
side in one process (ratios only; this machine is shared).

Each scene is loaded with its defaults (at ``--res`` and ``--spp``); its homogeneous twin is the same XML with
the discrete medium replaced by ``motes.equivalent_xml`` of ``motes.homogeneous_equivalent`` for the same
species and number density (count over the medium's box), truncated at the same pixel footprint. Both are
rendered ``--reps`` times, interleaved, after a warm-up; the best times are compared. The image means are
printed beside (a check that the twin is a twin: they agree where the grains are many and small).

    .venv/bin/python scripts/bench/bench_gallery.py [--scenes lamp,cornell,...] [--res 96] [--spp 16] [--reps 2]
        [--set count=300000 --set radius=2000]   (a scene's XML defaults overridden, twin included)
"""

from __future__ import annotations

import pathlib
import re
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
import numpy as np  # noqa: E402

import _common as C  # noqa: E402
import _paper as P  # noqa: E402
import bench_surface  # noqa: E402

SCENES = ("dust_box", "lamp", "cornell", "bench", "footprint", "staircase", "limit", "house")
#: `--set name=value`: the scenes' XML defaults replaced (the discrete scene and its twin alike).
OVERRIDES: dict[str, str] = {}


def defaults(name: str) -> dict:
    xml = P.scene_file(name).read_text()
    return {**{k: v for k, v in re.findall(r'<default name="(\w+)" value="([^"]*)"/>', xml)}, **OVERRIDES}


def medium_values(name: str) -> dict:
    """The medium block's literal and default-substituted values, by parameter name."""
    xml = P.scene_file(name).read_text()
    a, b = P.medium_block(xml)
    block, dv = xml[a:b], defaults(name)
    block = re.sub(r"\$(\w+)", lambda m: dv.get(m.group(1), m.group(0)), block)
    values = dict(re.findall(r'<(?:float|integer|string) name="(\w+)" value=\'?"?([^"\']*)', block))
    scale = re.search(r'<transform name="to_world">\s*<scale ([^/]*)/>', block)
    axes = dict(re.findall(r'(\w+)="([^"]*)"', scale.group(1)))
    if "value" in axes:
        axes = {k: axes["value"] for k in "xyz"}
    values["half_extent"] = [float(axes.get(k, 1.0)) for k in "xyz"]
    values["block"] = block
    return values


def species_of(motes, v: dict) -> list:
    """The medium's species from its parameters (the parameter styles the shipped scenes use)."""
    import json  # noqa: PLC0415

    def eta(entry):
        if "material" in entry:
            return motes.Material(entry["material"])
        return complex(float(entry.get("eta", 1.33)), float(entry.get("eta_k", 0.0)))

    if "species" in v:
        m = re.search(r"name=\"species\" value='([^']*)'", v["block"])
        out = []
        for e in json.loads(m.group(1)):
            psd = e["psd"]
            out.append(motes.Species(motes.LogNormal(float(psd["median_um"]), float(psd["sigma_g"])), eta(e),
                                     share=float(e.get("share", 1.0))))
        return out
    if "psd" in v:
        m = re.search(r"name=\"psd\" value='([^']*)'", v["block"])
        psd = json.loads(m.group(1))
        return [motes.Species(motes.Monodisperse(float(psd["radius_um"])), eta(v))]
    return [motes.Species(motes.LogNormal(float(v["radius_median"]), float(v["radius_sigma_g"])), eta(v))]


def equivalent(motes, name: str, res: int) -> str:
    v = medium_values(name)
    scale_m = float(v.get("scale_m", 1.0))
    volume_m3 = np.prod([2 * h * scale_m for h in v["half_extent"]])
    d = motes.homogeneous_equivalent(species_of(motes, v), float(v["count"]) / volume_m3, scale_m=scale_m,
                                     fov=float(v["fov"]), film_width=res)
    return motes.equivalent.equivalent_xml(d)


def best_of(mi, scene, spp: int, reps: int) -> tuple[float, float]:
    best, mean = np.inf, 0.0
    for s in range(reps):
        t = time.perf_counter()
        img = np.asarray(mi.render(scene, spp=spp, seed=s), dtype=np.float64)
        best = min(best, time.perf_counter() - t)
        mean = float(img[..., :3].mean())
    return best, mean


def main() -> None:
    ap = bench_surface.scene_parser(__doc__, SCENES)
    ap.add_argument("--reps", type=int, default=2)
    bench_surface.add_overrides(ap)
    args = ap.parse_args()
    bench_surface.read_overrides(args, OVERRIDES)
    out, sw = C.out_dir(args.out), C.Stopwatch()
    mi = P.setup(args.variant)
    import motes  # noqa: PLC0415

    rows = []
    for name in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        disc = mi.load_file(str(P.scene_file(name)), **OVERRIDES, spp=str(args.spp), res=str(args.res))
        xml = P.scene_file(name).read_text()
        a, b = P.medium_block(xml)
        outside = {k: v for k, v in OVERRIDES.items() if f"${k}" in xml[:a] + xml[b:]}
        hom = P.load_with_medium(mi, name, equivalent(motes, name, args.res), args.spp, args.res, **outside)
        for sc in (disc, hom):  # warm-up: compiles the kernels
            mi.render(sc, spp=args.spp, seed=999)
        times = {"discrete": [], "homogeneous": []}
        means = {}
        for _ in range(max(1, args.reps)):
            for key, sc in (("homogeneous", hom), ("discrete", disc)):
                t, means[key] = best_of(mi, sc, args.spp, 1)
                times[key].append(t)
        row = {"scene": name, "res": args.res, "spp": args.spp, **{f"seconds_{k}": min(v) for k, v in times.items()},
               "ratio": min(times["discrete"]) / min(times["homogeneous"]),
               **{f"mean_{k}": v for k, v in means.items()}}
        print(f"[{name}] discrete {row['seconds_discrete']:.2f} s, homogeneous {row['seconds_homogeneous']:.2f} s: "
              f"{row['ratio']:.2f}x (means {means['discrete']:.4g} / {means['homogeneous']:.4g})", flush=True)
        rows.append(row)
        del disc, hom
    C.print_table(f"{args.variant}, {args.res}x{args.res}, {args.spp} spp: shipped scenes / homogeneous equivalent",
                  ["scene", "discrete (s)", "homogeneous (s)", "ratio", "means discrete / homogeneous"],
                  [[r["scene"], f"{r['seconds_discrete']:.2f}", f"{r['seconds_homogeneous']:.2f}", f"{r['ratio']:.2f}x",
                    f"{r['mean_discrete']:.4g} / {r['mean_homogeneous']:.4g}"] for r in rows])
    C.finish(args, sw, out / f"bench_gallery_{args.variant}.json", rows=rows)


if __name__ == "__main__":
    main()
