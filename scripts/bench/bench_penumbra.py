"""Issue 25: what diffuse surfaces blur in the surface-ray rule (``rust/motes-core/src/render/footprint.rs``: an
area light's penumbra, a diffuse surface's lobe), on against off on the same medium with the same seeds,
interleaved.

"On" is what a user gets: in a scene whose every surface is diffuse (``motes.plugins.cameras.diffuse_only``) the
lights handed to the medium carry a disc that lies on each area light (rectangles, disks, spheres), whose penumbra
blurs the grains' shadows reaching a pixel, and rays bounced off a surface carry the grains blurred by its cosine
lobe. "Off" takes the scene's surfaces for possible mirrors (the rule as it was: the pixel's cone alone). Reported per
scene: seconds per render on over off, the share of rays from no event that saw the grains' continuous
equivalent on each side, the image means' difference in standard errors and the per-pixel RMS difference over
the renders' own seed-to-seed RMS difference, on all pixels and on the lit ones (above twice the median), where
the grains' shadows on walls and floors would show (``bench_surface.pair_stats``); the mean difference also in
units of its paired standard error (the two sides share their seeds: ``paired_se``).

    .venv/bin/python scripts/bench/bench_penumbra.py [--scenes cornell,staircase,...] [--seeds 8]
        [--set count=300000] [--variant scalar_rgb]
"""

from __future__ import annotations

import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "paper"))
import numpy as np  # noqa: E402

import _paper as P  # noqa: E402
import bench_surface  # noqa: E402

SCENES = ("dust_box", "lamp", "cornell", "bench", "staircase", "house")


def paired_se(on: list, off: list) -> float:
    """Standard error of the relative difference of the image means from the per-seed differences: the two
    sides share their seeds, so their paths agree until a ray from a surface sees the field on one side only,
    and the pairs' spread is far smaller than either side's (``pair_stats`` takes them as independent)."""
    a, b = (np.asarray(x).mean(axis=(1, 2)) for x in (on, off))
    return float((a - b).std(ddof=1) / np.sqrt(len(a)) / b.mean())


def in_paired_se(row: dict) -> str:
    """The mean difference in paired SEs ("same images" where every pair is equal)."""
    return f"{row['rel_diff'] / row['paired_se']:+.1f}" if row["paired_se"] > 0 else "same images"


def run_scene(mi, name: str, args) -> dict:
    from motes.plugins import cameras  # noqa: PLC0415

    scene = mi.load_file(str(P.scene_file(name)), **bench_surface.OVERRIDES, spp=str(args.spp), res=str(args.res))
    core = P.discrete_medium_of(scene).data.core
    diffuse_only = cameras.diffuse_only
    mi.render(scene, spp=args.spp, seed=999)  # compiles the kernels
    imgs, best, counts = {True: [], False: []}, {True: np.inf, False: np.inf}, {True: [0, 0], False: [0, 0]}
    try:
        for s in range(args.seeds):
            for on in (True, False):
                # mi.render hands the scene's lights and surfaces to the medium again: diffuse or not.
                cameras.diffuse_only = diffuse_only if on else (lambda _scene: False)
                before = core.surface_counts
                t = time.perf_counter()
                img = np.asarray(mi.render(scene, spp=args.spp, seed=s), dtype=np.float64)[..., :3]
                best[on] = min(best[on], time.perf_counter() - t)
                after = core.surface_counts
                counts[on] = [counts[on][k] + after[k] - before[k] for k in range(2)]
                imgs[on].append(P.luminance(img))
    finally:
        cameras.diffuse_only = diffuse_only
    share = {on: counts[on][1] / max(counts[on][0], 1) for on in (True, False)}
    row = {"scene": name, "res": args.res, "spp": args.spp, "seeds": args.seeds, "seconds_on": best[True],
           "seconds_off": best[False], "speed_ratio": best[True] / best[False], "field_share_on": share[True],
           "field_share_off": share[False], "diffuse": diffuse_only(scene),
           **bench_surface.pair_stats(imgs[True], imgs[False]), "paired_se": paired_se(imgs[True], imgs[False])}
    print(f"[{name}] on/off {row['speed_ratio']:.2f} ({best[True]:.2f} / {best[False]:.2f} s), field "
          f"{share[True]:.0%} / {share[False]:.0%} of rays from no event, mean {row['rel_diff']:+.3%} "
          f"({row['diff_se']:+.1f} SE; {in_paired_se(row)} paired SE), rms/noise {row['rms_over_noise']:.2f} lit {row['rms_over_noise_lit']:.2f}",
          flush=True)
    return row


def main() -> None:
    args, names, seeds, out, sw, mi = bench_surface.start(__doc__, SCENES, seeds=8)
    args.seeds = seeds  # what run_scene and the JSON's record of the arguments use
    rows = [run_scene(mi, n, args) for n in names]
    bench_surface.report(args, seeds, rows, "diffuse surfaces' blur on against off",
                         {"rays seeing the field on / off":
                              lambda r: f"{r['field_share_on']:.0%} / {r['field_share_off']:.0%}",
                          "mean diff (SE; paired SE)":
                              lambda r: f"{r['rel_diff']:+.3%} ({r['diff_se']:+.1f}; {in_paired_se(r)})"},
                         sw, out / f"bench_penumbra_{args.variant}.json")


if __name__ == "__main__":
    main()
