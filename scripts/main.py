"""The main job: render the default scene (scenes_xml/dust_box.xml, dust grains glinting in a light beam)
with Mitsuba's own volpath and the motes `discrete` medium, to EXR (linear) and PNG (auto-exposed sRGB).

    .venv/bin/python scripts/main.py [--scene scenes_xml/dust_box.xml] [--variant llvm_ad_rgb]
                                     [--spp 48] [--res 256] [--out out]
"""

from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np

import motes


def main() -> None:
    root = pathlib.Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=str(root / "scenes_xml" / "dust_box.xml"))
    ap.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (LLVM falls back to scalar if unusable)")
    ap.add_argument("--spp", type=int, default=None, help="samples per pixel (scene default if omitted)")
    ap.add_argument("--res", type=int, default=None, help="image width = height (scene default if omitted)")
    ap.add_argument("--out", default="out", help="output folder")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    variant = motes.set_variant(args.variant)
    import mitsuba as mi

    params = {k: str(v) for k, v in (("spp", args.spp), ("res", args.res)) if v is not None}
    t0 = time.perf_counter()
    scene = mi.load_file(args.scene, **params)
    t1 = time.perf_counter()
    img = mi.render(scene)
    t2 = time.perf_counter()
    media = [s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None]
    for m in media:
        print(m.to_string())
    stem = pathlib.Path(args.scene).stem
    exr = out / f"{stem}.exr"
    mi.util.write_bitmap(str(exr), img)
    # PNG: expose so that the 99.7th percentile of luminance is white (the EXR keeps linear values).
    a = np.asarray(img, dtype=np.float64)
    lum = a @ np.array([0.2126, 0.7152, 0.0722])
    scale = 1.0 / max(float(np.percentile(lum, 99.7)), 1e-12)
    png = out / f"{stem}.png"
    mi.util.write_bitmap(str(png), mi.TensorXf(np.clip(a * scale, 0, None).astype(np.float32)))
    print(f"variant {variant}: loaded in {t1 - t0:.1f} s (particles, optics tables, grid), rendered in {t2 - t1:.1f} s")
    print(f"wrote {exr} and {png} (exposure x{scale:.3g})")


if __name__ == "__main__":
    main()
