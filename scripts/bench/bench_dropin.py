"""A drop-in medium (issue 43): the three third-party-shaped scenes of ``tests/test_dropin.py`` (two shapes sharing
one medium, a rotated crate with Henyey-Greenstein grains, a ball with a coloured sigma_t), each rendered with its
``homogeneous`` medium and turned ``discrete`` (type changed and a grain size added; no ``to_world``: the grains fill
the shapes that hold the medium, as ``homogeneous`` does). Prints per
scene and medium the per-channel means over the pixels that see the medium (those where the homogeneous image is
not the bare sky), discrete over homogeneous per channel, and load and render seconds (the render timed after a
warm-up render of the same scene, which compiles the kernels in LLVM variants).

    .venv/bin/python scripts/bench/bench_dropin.py [--variant scalar_rgb] [--res 32] [--spp 64] [--scenes shared,rotated,ball]
    .venv/bin/python scripts/bench/bench_dropin.py --rotated-study [--spp 256]
    .venv/bin/python scripts/bench/bench_dropin.py --heterogeneous [--variant llvm_ad_rgb]

A benchmark for later: the defaults (32 px, 64 spp) take seconds; the grey scenes' ratios are the test's check
(within 5 %), the coloured ball's is what its grey extinction (the mean of sigma_t over the channels) makes of it.
It also prints the grains' mean C_ext (radius_median 20 um, the default PSD and index, RGB wavelengths) with and
without forward-peak truncation: how much too little extinction sigma_t would make through the textbook one.
``--rotated-study``: the rotated crate (discrete over homogeneous) with the grains of the test (scale_m = 1 cm,
8e5 grains), with the default scale_m (1 mm, 8e3 grains), the same with continuous_count = inf (every grain
walked), and the crate unrotated: the grains' continuous equivalent (cells aligned with the scene) over a tilted
face (docs/rendering.md, "From a homogeneous medium"). ``--heterogeneous``: tests/test_dropin.py's puff, a
``gridvolume`` sigma_t rendered ``heterogeneous`` and turned ``discrete`` (isotropic phase on both), by default and
exact (``continuous_count`` = inf).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
import warnings

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--scenes", default="shared,rotated,ball")
    ap.add_argument("--rotated-study", action="store_true", help="the rotated crate's grain count and continuous "
                    "equivalent (module docs)")
    ap.add_argument("--heterogeneous", action="store_true", help="a gridvolume puff (heterogeneous) turned discrete "
                    "(module docs)")
    args = ap.parse_args()
    import motes  # noqa: PLC0415

    variant = motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415
    import test_dropin as T  # noqa: PLC0415  (the scenes, written once)

    if args.rotated_study:
        rotated_study(mi, T, args, variant)
        return
    if args.heterogeneous:
        heterogeneous(mi, T, variant)
        return
    from motes.discrete import mean_extinction_um2  # noqa: PLC0415
    from motes.ensemble import RGB_WAVELENGTHS_UM  # noqa: PLC0415

    grains = [motes.Species(motes.LogNormal(20.0, 1.5), 1.31)]
    c, c_textbook = (mean_extinction_um2(grains, RGB_WAVELENGTHS_UM, **kw) for kw in ({}, {"truncate_below_rad": None}))
    print(f"grains' mean C_ext: {c:.5g} um^2 as the medium gives it (truncated), {c_textbook:.5g} um^2 untruncated "
          f"(textbook): sigma_t through the textbook one makes {1 - c / c_textbook:.1%} too little extinction")
    rows = []
    for name in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        if name not in T.SCENES:
            ap.error(f"unknown scene {name!r}; choose from {', '.join(T.SCENES)}")
        xml, box, grey = T.SCENES[name]
        images, said = {}, []
        for kind, text in (("homogeneous", xml), ("discrete", T.dropin(xml, box))):
            t = time.perf_counter()
            with warnings.catch_warnings(record=True) as record:
                warnings.simplefilter("always")
                scene = mi.load_string(text.format(spp=args.spp, res=args.res))
            said += [str(w.message) for w in record]
            t_load = time.perf_counter() - t
            mi.render(scene, spp=1, seed=999)  # warm-up: compiles the kernels
            t = time.perf_counter()
            images[kind] = np.array(mi.render(scene, spp=args.spp, seed=0), dtype=np.float64)[..., :3]
            rows.append([name, kind, t_load, time.perf_counter() - t])
        mask = np.any(np.abs(images["homogeneous"] - 0.3) > 1e-3, axis=-1)
        means = {k: img[mask].mean(axis=0) for k, img in images.items()}
        ratio = means["discrete"] / means["homogeneous"]
        for row in rows[-2:]:
            row[2:2] = [means[row[1]], ratio if row[1] == "discrete" else None]
        rows[-1].append("grey" if grey else "coloured sigma_t")
        for s in said:
            print(f"[{name}] {s}", flush=True)
    print(f"\n{variant}, {args.res}x{args.res}, {args.spp} spp; means over the pixels that see the medium")
    print(f"{'scene':<8} {'medium':<12} {'R':>8} {'G':>8} {'B':>8}   {'ratio R, G, B':<22} {'load s':>7} {'render s':>8}")
    for row in rows:
        name, kind, mean, ratio, t_load, t_render = row[:6]
        r = "" if ratio is None else ", ".join(f"{v:.4f}" for v in ratio)
        note = f"  ({row[6]})" if len(row) > 6 else ""
        print(f"{name:<8} {kind:<12} {mean[0]:8.5f} {mean[1]:8.5f} {mean[2]:8.5f}   {r:<22} {t_load:7.2f} {t_render:8.2f}{note}")


def heterogeneous(mi, T, variant, seeds: int = 8) -> None:
    """test_dropin's puff: a gridvolume sigma_t (8x5x6 Gaussian, scale 30, isotropic phase, sun and sky) rendered
    ``heterogeneous`` and turned ``discrete``: image means over ``seeds`` renders (16 px, 64 spp) and their ratio."""
    import tempfile  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as folder:
        vol = T._smoke_vol(pathlib.Path(folder) / "puff.vol")
        means = {}
        for kind, extra in (("heterogeneous", {}), ("discrete", {}), ("discrete exact", {"continuous_count": np.inf})):
            scene = T._heterogeneous(kind.split()[0], vol, **extra)
            m = [float(np.asarray(mi.render(scene, spp=64, seed=s), dtype=np.float64)[..., :3].mean())
                 for s in range(seeds)]
            means[kind] = (np.mean(m), np.std(m, ddof=1) / np.sqrt(seeds))
            print(f"{kind:<14} mean {means[kind][0]:.5f} +- {means[kind][1]:.5f}", flush=True)
    (a, sa) = means["heterogeneous"]
    for kind in ("discrete", "discrete exact"):
        b, sb = means[kind]
        print(f"{variant}: {kind} / heterogeneous {b / a:.4f} (z {(b - a) / np.hypot(sa, sb):+.1f})")


def rotated_study(mi, T, args, variant) -> None:
    xml, box, _ = T.SCENES["rotated"]
    cases = [("test's grains (scale_m = 1 cm)", xml, box), ("scale_m = 1 mm (default)", xml, ""),
             ("1 mm, continuous_count = inf", xml, '<float name="continuous_count" value="inf"/>'),
             ("unrotated, 1 mm", xml.replace(T.ROTATION, ""), ""),
             ("unrotated, 1 mm, continuous_count = inf", xml.replace(T.ROTATION, ""),
              '<float name="continuous_count" value="inf"/>')]
    print(f"{variant}, {args.res}x{args.res}, {args.spp} spp; the rotated crate, discrete over homogeneous "
          "(means over the pixels that see the medium)")
    reference = {}
    for label, scene_xml, extra in cases:
        if scene_xml not in reference:
            a = np.array(mi.render(mi.load_string(scene_xml.format(spp=args.spp, res=args.res)), spp=args.spp, seed=0))
            mask = np.any(np.abs(a[..., :3] - 0.3) > 1e-3, axis=-1)
            reference[scene_xml] = (a[mask, :3].mean(), mask)
        mean_a, mask = reference[scene_xml]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = mi.load_string(T.dropin(scene_xml, extra).format(spp=args.spp, res=args.res))
        grains = len(scene.shapes()[0].interior_medium().data)
        b = np.array(mi.render(scene, spp=args.spp, seed=0))
        print(f"  {label:<42} {grains:>8} grains  ratio {b[mask, :3].mean() / mean_a:.4f}", flush=True)


if __name__ == "__main__":
    main()
