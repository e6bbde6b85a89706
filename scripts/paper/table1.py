"""Paper Table 1 re-measured: for each gallery scene of the table, N, the paper's spp, peak memory and
render time, ours and explicit path tracing's (EPT, LAMP and CORNELL), beside the paper's numbers.

Each measurement runs in its own subprocess (peak resident memory of that process: load + render):
the shipped scene at its default resolution and parameters is loaded, rendered once at 2 spp (JIT and
caches), then rendered at ``--spp`` and the time scaled linearly to the paper's spp. EPT: the same
grains (read once from the scene loaded with ``storage = full``) written as one Mitsuba ``sphere`` per
grain with a ``dielectric`` BSDF (index 1.31) into an XML file, loaded and rendered by a separate
process. Each is rendered twice (sampler seeds 0 and 1): the faster time is reported, and the relative
Monte Carlo noise per pixel (RMS of the two images' difference / sqrt 2, over the mean) gives the time
to equal noise, time x noise^2 (EPT's heavy-tailed noise makes its two-seed estimate optimistic). The
paper's machine: 16-core i7-6900K, spectral (8 wavelengths), image size not stated; ours:
2 cores, RGB. Prints a markdown table (BENCHMARKS.md) and writes docs/gallery/table1.json.

    .venv/bin/python scripts/paper/table1.py [--spp N] [--variants scalar_rgb,llvm_ad_rgb] [--no-ept]

About 15 minutes on 2 cores (--spp 16). Timing: run it alone.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

#: Table 1 of the paper: N, spp, memory (MB), EPT and ours (minutes).
PAPER = {"lamp": ("LAMP", 5e5, 1024, 49, 44, 36), "cornell": ("CORNELL BOX", 1e5, 1024, 60, 16, 13),
         "bench": ("BENCH", 2e5, 2048, 52, None, 20), "staircase": ("STAIRCASE", 3e6, 4096, 138, None, 53),
         "house": ("HOUSE", 4e6, 1024, 545, None, 38)}
EPT_SCENES = ("lamp", "cornell")
ICE_REAL_INDEX = 1.31


def child(argv) -> int:
    """One measurement in this process: ``motes NAME VARIANT SPP`` or ``ept XMLFILE VARIANT SPP``."""
    kind, what, variant, spp = argv[0], argv[1], argv[2], int(argv[3])
    mi = P.setup(variant)
    import numpy as np  # noqa: PLC0415

    t0 = time.perf_counter()
    if kind == "motes":
        scene = mi.load_file(str(P.scene_file(what)))
    else:
        scene = mi.load_file(what)
    t_load = time.perf_counter() - t0
    np.asarray(mi.render(scene, spp=2, seed=99))
    imgs, times = [], []
    for seed in (0, 1):
        t1 = time.perf_counter()
        imgs.append(np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)[..., :3])
        times.append(time.perf_counter() - t1)
    a, b = (P.luminance(i) for i in imgs)
    mean = float(0.5 * (a.mean() + b.mean()))
    # Relative Monte Carlo noise per pixel at this spp (from the two seeds): time x noise^2 is the cost
    # of a given noise level, whatever the spp.
    noise = float(np.sqrt(np.mean((a - b) ** 2) / 2) / mean)
    print(json.dumps({"load_s": t_load, "render_s": min(times), "peak_mb": P.peak_memory_mb(),
                      "res": list(imgs[0].shape[:2]), "mean": mean, "noise": noise}))
    return 0


def run_child(*argv) -> dict:
    r = subprocess.run([sys.executable, __file__, "--child", *map(str, argv)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{argv}: {r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def ept_file(name: str, folder: pathlib.Path) -> tuple[pathlib.Path, int]:
    mi = P.setup("scalar_rgb")
    xml, n = P.ept_xml(mi, name, ICE_REAL_INDEX, 4, 64)
    path = folder / f"{name}_ept.xml"
    # The scene's parameters keep their defaults ($spp, $res), as in the motes scene.
    path.write_text(xml)
    return path, n


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        return child(sys.argv[2:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", type=int, default=16, help="spp rendered (scaled to the paper's) (16)")
    ap.add_argument("--variants", default="scalar_rgb,llvm_ad_rgb")
    ap.add_argument("--no-ept", action="store_true")
    ap.add_argument("--out", default=str(P.GALLERY))
    args = ap.parse_args()
    variants = [v for v in args.variants.split(",") if v]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, (label, n, spp_paper, mem_paper, ept_paper, ours_paper) in PAPER.items():
            row = {"scene": name, "label": label, "N": n, "paper_spp": spp_paper, "paper_memory_mb": mem_paper,
                   "paper_ept_min": ept_paper, "paper_ours_min": ours_paper}
            for v in variants:
                m = run_child("motes", name, v, args.spp)
                m["minutes_at_paper_spp"] = m["render_s"] * spp_paper / args.spp / 60
                row[v] = m
                print(f"{label:12s} {v:12s} load {m['load_s']:.1f} s, {args.spp} spp {m['render_s']:.1f} s "
                      f"(noise {m['noise']:.3f}) "
                      f"-> {m['minutes_at_paper_spp']:.1f} min at {spp_paper} spp; peak {m['peak_mb']:.0f} MB", flush=True)
            if name in EPT_SCENES and not args.no_ept:
                path, count = ept_file(name, pathlib.Path(tmp))
                e = run_child("ept", path, "scalar_rgb", args.spp)
                e["minutes_at_paper_spp"] = e["render_s"] * spp_paper / args.spp / 60
                e["spheres"] = count
                row["ept_scalar_rgb"] = e
                print(f"{label:12s} EPT scalar   load {e['load_s']:.1f} s, {args.spp} spp {e['render_s']:.1f} s "
                      f"(noise {e['noise']:.3f}) "
                      f"-> {e['minutes_at_paper_spp']:.1f} min; peak {e['peak_mb']:.0f} MB ({count} spheres)", flush=True)
            results.append(row)
    out = pathlib.Path(args.out)
    P.save_numbers(out, "table1", {"spp": args.spp, "variants": variants, "rows": results})
    print()
    head = "| scene | N | res | paper spp | paper: memory, EPT, ours (min) |"
    for v in variants:
        head += f" ours {v}: memory, min at paper spp |"
    head += " EPT scalar_rgb: memory, min | ours/EPT time, equal spp (scalar) | ours/EPT time, equal noise | paper ours/EPT |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for r in results:
        res = r[variants[0]]["res"]
        line = (f"| {r['label']} | {r['N']:.0e} | {res[1]}x{res[0]} | {r['paper_spp']} | {r['paper_memory_mb']} MB, "
                f"{r['paper_ept_min'] or '-'}, {r['paper_ours_min']} |")
        for v in variants:
            m = r[v]
            line += f" {m['peak_mb']:.0f} MB, {m['minutes_at_paper_spp']:.1f} |"
        if "ept_scalar_rgb" in r:
            e = r["ept_scalar_rgb"]
            ours = r.get("scalar_rgb", r[variants[0]])
            at_noise = (ours["render_s"] * ours["noise"] ** 2) / (e["render_s"] * e["noise"] ** 2)
            line += (f" {e['peak_mb']:.0f} MB, {e['minutes_at_paper_spp']:.1f} | "
                     f"{ours['minutes_at_paper_spp'] / e['minutes_at_paper_spp']:.2f} | {at_noise:.2f} | "
                     f"{r['paper_ours_min'] / r['paper_ept_min']:.2f} |")
        else:
            line += " - | - | - |"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
