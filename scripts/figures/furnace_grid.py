"""White-furnace grid of the `discrete` medium (issue 9.1): grains small and large against their spacing
x query radius x box transform x variant, Russian roulette off. Prints mean +- SE and (mean - 1) / SE.

    .venv/bin/python scripts/figures/furnace_grid.py            # full grid (~15 min on 2 cores)
    .venv/bin/python scripts/figures/furnace_grid.py --quick    # llvm_ad_rgb only, fewer samples

Imported by ``tests/test_furnace.py`` (the CI subset).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

#: Local units of the generated cube [-1, 1]^3 per world unit; the world has scale_m = 1 mm.
SCALE_M = 1e-3


def furnace_medium(count: int, radius_over_spacing: float, query_radius=None, seed=0) -> dict:
    """A `discrete` medium of `count` grains whose radius is `radius_over_spacing` times their mean
    spacing (in local units of the unit cube), radii uniform within +-20 %."""
    spacing = (8.0 / count) ** (1.0 / 3.0)
    r_um = radius_over_spacing * spacing * SCALE_M * 1e6
    med = {"type": "discrete", "count": count, "eta": 1.31, "scale_m": SCALE_M, "albedo": 1.0, "size_bins": 4,
           "psd": json.dumps({"type": "uniform", "r_min_um": 0.8 * r_um, "r_max_um": 1.2 * r_um}), "seed": seed,
           "phase": {"type": "particle"}}
    if query_radius is not None:
        med["query_radius"] = query_radius
    return med


def box_transform(kind: str):
    import mitsuba as mi  # noqa: PLC0415

    if kind == "identity":
        return mi.ScalarTransform4f()
    return mi.ScalarTransform4f().rotate([1, 1, 0], 35).scale([1.0, 0.6, 1.3])


def render_furnace(medium: dict, transform: str, res: int, spp: int) -> tuple[float, float]:
    import mitsuba as mi  # noqa: PLC0415

    img = np.asarray(mi.render(furnace_scene(medium, transform, res, spp), spp=spp), dtype=np.float64)
    pix = img.reshape(-1, img.shape[-1]).mean(axis=1)
    return float(pix.mean()), float(pix.std(ddof=1) / np.sqrt(pix.size))


def furnace_scene(medium: dict, transform: str, res: int, spp: int):
    """The medium in a null-BSDF cube (`transform`) under a constant white environment, volpath without
    depth limit or Russian roulette."""
    import mitsuba as mi  # noqa: PLC0415

    to_world = box_transform(transform)
    medium = dict(medium, to_world=to_world)
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1_000_000},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "cube": {"type": "cube", "to_world": to_world, "bsdf": {"type": "null"}, "interior": medium},
    })


# (count, radius / spacing): a sparse haze, grains a third of their spacing, overlapping inclusion balls.
REGIMES = [(20000, 0.01), (2000, 0.1), (400, 0.3), (60, 1.5)]
QUERY_RADII = [None, 0.05, 0.3]
TRANSFORMS = ["identity", "rotated_scaled"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="out", help="unused (run_benchmarks.sh passes it to every script)")
    args = ap.parse_args()
    import warnings  # noqa: PLC0415

    import motes  # noqa: PLC0415

    warnings.filterwarnings("ignore", message="query_radius")
    variants = ["llvm_ad_rgb"] if args.quick else ["llvm_ad_rgb", "llvm_ad_spectral", "scalar_rgb", "scalar_spectral"]
    print(f"{'variant':17s} {'count':>6s} {'r/spacing':>9s} {'r_c':>5s} {'box':15s} {'mean':>7s} {'se':>6s} {'z':>5s} {'s':>6s}")
    worst = 0.0
    for variant in variants:
        motes.set_variant(variant)
        scalar = variant.startswith("scalar")
        res, spp = (8, 32) if scalar else ((16, 32) if args.quick else (32, 64))
        for count, ratio in REGIMES:
            for qr in QUERY_RADII if not scalar else [None]:
                for tr in TRANSFORMS:
                    t0 = time.perf_counter()
                    m, se = render_furnace(furnace_medium(count, ratio, qr), tr, res, spp)
                    z = (m - 1.0) / se
                    worst = max(worst, abs(z))
                    print(f"{variant:17s} {count:6d} {ratio:9.2f} {str(qr):>5s} {tr:15s} {m:7.4f} {se:6.4f} {z:5.1f} {time.perf_counter() - t0:6.1f}", flush=True)
    if not args.quick:
        # The issue's case: 40 000 grains of 100-400 um in a 4 mm box (radius / spacing ~2), llvm_ad_rgb.
        motes.set_variant("llvm_ad_rgb")
        t0 = time.perf_counter()
        m, se = render_furnace(furnace_medium(40000, 2.0), "identity", 8, 32)
        z = (m - 1.0) / se
        worst = max(worst, abs(z))
        print(f"{'llvm_ad_rgb':17s} {40000:6d} {2.0:9.2f} {'None':>5s} {'identity':15s} {m:7.4f} {se:6.4f} {z:5.1f} {time.perf_counter() - t0:6.1f}")
    print(f"largest |mean - 1| / SE: {worst:.2f}")


if __name__ == "__main__":
    main()
