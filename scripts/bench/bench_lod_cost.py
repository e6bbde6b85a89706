"""The level of detail's cost cliff (a known limitation, found under issue 43): a haze of 0.5 um grains (the sky
gallery's middle panel, `scripts/paper/sky_polarisation.py`, unpolarised here: llvm_ad_spectral) rendered at a
few (res, spp). Doubling
spp doubles the rays, but each ray costs about ten times more; a finer film does the same. The camera rule (walk
the grains where a pixel's footprint holds fewer than 2.5 spp of them) sends a tenth of the camera rays from the
grains' field to walking this dense haze there (the last column). That is what the rule asks for (a pixel's light then
carries the grains' Poisson texture, relative ~1/sqrt(N), which more samples would resolve); what is open is the
cost of walking ~1e4 grains per mm^3.
Prints seconds, the medium's ray and event counts per setting, and the share of rays from no event (camera rays
among them) that saw the field.

    .venv/bin/python scripts/bench/bench_lod_cost.py
"""

from __future__ import annotations

import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT / "scripts" / "paper"))
import _common as C  # noqa: E402

SETTINGS = ((128, 64), (128, 128), (160, 64))


def main() -> None:
    motes = C.import_motes()
    motes.set_variant("llvm_ad_spectral")
    import mitsuba as mi  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    import sky_polarisation as S  # noqa: PLC0415

    for res, spp in SETTINGS:
        d = S.scene_dict(mi, 0.5, 1.5, res, spp)
        d["integrator"] = d["integrator"]["integrator"]  # volpath alone
        scene = mi.load_dict(d)
        medium = scene.shapes()[0].interior_medium()
        t = time.perf_counter()
        np.asarray(mi.render(scene, spp=spp, seed=1))
        seconds = time.perf_counter() - t
        st = medium.stats
        checked, saw = medium.data.core.surface_counts  # rays from no event: how many saw the field
        print(f"{res} px {spp:4d} spp: {seconds:6.1f} s, rays {st.get('rays')}, events {st.get('events')}, "
              f"{1e6 * seconds / max(st.get('rays') or 1, 1):.2f} us per ray; rays from no event that saw the field "
              f"{saw / max(checked, 1):.3f} of {checked}", flush=True)


if __name__ == "__main__":
    main()
