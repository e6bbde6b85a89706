"""What polarisation costs (issue 45): a shipped scene rendered in a polarised variant against the unpolarised
variant of the same family, side by side in one run (each variant in its own process, the two alternated
`--rounds` times), e.g.

    .venv/bin/python scripts/bench/bench_polarized.py --scene dust_box --res 96 --spp 16

Prints per family the seconds per render of each variant (mean of `--renders` after a compiling warm-up),
their ratio (target <= 2), and the image means: the polarised render's S0 (what `mi.render` returns there)
against the unpolarised image, with the standard error of their difference over the renders' seeds.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))

FAMILIES = ("llvm_ad_spectral", "scalar_spectral")


def worker(variant: str, scene: str, res: int, spp: int, renders: int) -> dict:
    """Seconds per render and per-seed image means of `scene` in `variant` (this process only)."""
    import numpy as np  # noqa: PLC0415

    import _common as C  # noqa: PLC0415
    import _paper as P  # noqa: PLC0415

    motes = C.import_motes()
    motes.set_variant(variant)
    import mitsuba as mi  # noqa: PLC0415

    sc = mi.load_file(str(P.scene_file(scene)), spp=str(spp), res=str(res))
    mi.render(sc, spp=spp, seed=10_000)  # compile
    means, t = [], time.perf_counter()
    for s in range(renders):
        img = np.asarray(mi.render(sc, spp=spp, seed=s), dtype=np.float64)
        means.append(float(img[..., :3].mean()))
    return {"seconds": (time.perf_counter() - t) / renders, "means": means,
            "native": variant in motes.native_variants()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="dust_box")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--renders", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.scene, args.res, args.spp, args.renders)))
        return
    import numpy as np  # noqa: PLC0415

    print(f"{args.scene} {args.res} px, {args.spp} spp, {args.renders} renders x {args.rounds} rounds a variant")
    for family in args.families.split(","):
        runs: dict[str, list[dict]] = {family: [], family + "_polarized": []}
        for _ in range(args.rounds):
            for variant in runs:
                out = subprocess.run([sys.executable, __file__, "--worker", variant, "--scene", args.scene,
                                      "--res", str(args.res), "--spp", str(args.spp), "--renders", str(args.renders)],
                                     capture_output=True, text=True, check=True)
                runs[variant].append(json.loads(out.stdout.strip().splitlines()[-1]))
        (a, b) = runs.values()
        ta, tb = (float(np.mean([r["seconds"] for r in x])) for x in (a, b))
        ma, mb = (np.concatenate([r["means"] for r in x]) for x in (a, b))
        se = float(np.hypot(ma.std(ddof=1), mb.std(ddof=1)) / np.sqrt(ma.size))
        print(f"  {family:18s} {ta:8.3f} s  polarized {tb:8.3f} s  ratio {tb / ta:5.2f}  "
              f"(native {a[0]['native']}/{b[0]['native']})")
        print(f"  {'':18s} mean {ma.mean():.5f}  S0 {mb.mean():.5f}  difference {mb.mean() - ma.mean():+.5f} "
              f"+- {se:.5f} (z {(mb.mean() - ma.mean()) / se:+.2f})")


if __name__ == "__main__":
    main()
