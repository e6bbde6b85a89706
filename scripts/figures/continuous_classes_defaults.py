"""Where do size classes go continuous at the defaults? (issue 43.5: every approximation on by default)

A size class is sampled as a continuous medium when a query cylinder holds at least ``continuous_count`` (16)
of its particles over one mean free path or across the cloud (``rust/motes-core/src/render/continuous/``).
At the default query radius (0: each grain's disk is its own extinction cross section, widened only until
its optical depth is ``tau_max`` = 1) a disk's area is at most C_ext / (1 - e^-1), so over one mean free path
1 / (n C_ext) a ray crosses at most ~1.6 disks of a class, and across a thinner cloud fewer: the threshold
of 16 is out of reach. Continuous classes therefore arise only where a user widens the query cylinder
(``query_radius``, or Eq. 23's ``footprint_k``), and the level of detail a user gets without setting
anything is the path rules' (``grain_depth``, the surface and camera rules). This script loads the shipped
scenes and dust-room hazes from sparse to dense at the defaults and prints how many of their particles are
continuous, and the same hazes with Eq. 23's ``footprint_k`` = 1 for contrast.

    .venv/bin/python scripts/figures/continuous_classes_defaults.py

Run time on 2 cores: ~1 min (loads only, no render).
"""

from __future__ import annotations

import glob
import pathlib
import sys
import warnings

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT / "scripts" / "bench"))

import _common as C  # noqa: E402

HAZES = ((60_000, 60.0), (300_000, 100.0), (1_000_000, 40.0), (4_000_000, 20.0), (10_000_000, 10.0),
         (3_000_000, 5.0))


def medium_of(scene):
    return next(s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None)


def main() -> None:
    motes = C.import_motes()
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi  # noqa: PLC0415

    import bench_lod  # noqa: PLC0415

    print("| scene | particles | continuous at the defaults | continuous with footprint_k = 1 |")
    print("|---|---|---|---|")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for path in sorted(glob.glob(str(ROOT / "scenes_xml" / "*.xml"))):
            data = medium_of(mi.load_file(path)).data
            print(f"| {pathlib.Path(path).stem} | {len(data)} | {data.continuous_particles} | — |", flush=True)
        for count, radius in HAZES:
            row = []
            for extra in ({}, {"footprint_k": 1.0, "fov": 40.0, "film_width": 128, "z_med": 32.0}):
                data = medium_of(bench_lod.haze(mi, f"haze-n{count}-r{radius:g}", 128, extra)).data
                row.append(data.continuous_particles)
            print(f"| dust-room haze {count:.0e} x {radius:g} um | {count} | {row[0]} | {row[1]} |", flush=True)
        for count in (1e9, 1e12):  # bench_camera_lod.py's procedural cloud: glass grains of 0.5 mm in a 200 m cube
            medium = {"type": "discrete", "count": count, "radius_median": 500.0, "radius_sigma_g": 1.2, "eta": 1.5,
                      "scale_m": 1.0, "storage": "procedural", "to_world": mi.ScalarTransform4f().scale(100.0)}
            data = medium_of(mi.load_dict({"type": "scene", "cube": {"type": "cube", "to_world":
                                           mi.ScalarTransform4f().scale(100.0), "bsdf": {"type": "null"},
                                           "interior": medium}})).data
            print(f"| procedural cloud {count:.0e} x 500 um, 200 m cube | {count:.0e} | {data.continuous_particles:.3g} "
                  "| — |", flush=True)


if __name__ == "__main__":
    main()
