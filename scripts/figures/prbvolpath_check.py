"""Does Mitsuba's prbvolpath render the `discrete` medium? A white furnace (non-absorbing particles in a
box under a constant environment, expected 1.0) with volpath and prbvolpath side by side.

    .venv/bin/python scripts/figures/prbvolpath_check.py [--quick] [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi

    res, spp = (24, 16) if args.quick else (48, 64)
    rows = []
    for integrator in ("volpath", "prbvolpath"):
        scene = mi.load_dict({
            "type": "scene", "integrator": {"type": integrator, "max_depth": 200},
            "sensor": {"type": "perspective", "fov": 28,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": spp}},
            "env": {"type": "constant"},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "interior": {"type": "discrete", "count": 5000, "radius_median": 20.0, "eta": 1.31, "scale_m": 1e-3,
                                  "query_radius": 0.02, "phase": {"type": "particle"}}}})
        img = np.asarray(mi.render(scene), dtype=np.float64)
        pix = img.mean(axis=2).ravel()
        finite = np.isfinite(pix)
        m, se = pix[finite].mean(), pix[finite].std() / np.sqrt(finite.sum())
        rows.append([integrator, f"{m:.4f}", f"{se:.4f}", f"{(m - 1) / se:+.1f}", int((~finite).sum())])
    C.print_table(f"White furnace (expected 1), llvm_ad_rgb, {res}x{res} px, {spp} spp",
                  ["integrator", "image mean", "standard error", "z", "non-finite pixels"], rows)
    print(f"runtime {sw():.1f} s")


if __name__ == "__main__":
    main()
