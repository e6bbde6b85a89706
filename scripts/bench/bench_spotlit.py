"""Forward peak and fireflies: a spot light through a cloud of grains onto a white floor.

A cloud of 400 000 grains (log-normal radii, median 80 um, sigma_g 1.5, index 1.31) fills a 10 cm cube
(scene unit = 1 cm, ``scale_m = 0.01``) 2 cm above a white ``diffuse`` floor (reflectance 0.8); a
``spot`` light from the upper left shines through the cloud onto the floor; a perspective camera sees
floor and cloud; black background, ``volpath`` (max_depth 32), llvm_ad_rgb. The diffraction peak of
80 um grains is a few mrad wide: a delta light (the spot) can only be reached through it by phase
sampling, i.e. as fireflies, unless the peak is truncated (folded into unscattered transmission).

Renders (all at ``--spp``, each twice with different seeds: the discrete ones with different particle
seeds, so the spread includes the particle arrangement):

* ``discrete default``: the medium's defaults (no query_radius, no truncate_below);
* ``discrete trunc=0.031``: ``truncate_below = 0.031`` rad (one bin of a 4096-value tabphase);
* ``discrete trunc=0``: no truncation (the forward peak left in the phase function), for reference;
* ``homogeneous``: Mitsuba's ``homogeneous`` + ``tabphase`` of ``motes.homogeneous_equivalent`` (number
  density = count / box volume in m^3; its tabphase truncates below one bin, 0.031 rad);
* ``reference``: the homogeneous equivalent at ``--ref-spp`` (two seeds), Mitsuba's symbolic mode.

For each: image mean and the mean over the lit floor (pixels where the floor without the cloud is at
least half as bright as its brightest), SE from the two seeds (sqrt(var_pixels(A - B) / (4 N))), and the
relative bias against the reference with its SE.

    .venv/bin/python scripts/bench/bench_spotlit.py [--count N] [--res W] [--spp N] [--ref-spp N] [--quick] [--out DIR]

Run time on 2 shared cores: ~2.5 min (default: 400 000 grains, 128x96, 64 spp, reference 2 x 4096 spp),
~7 s (--quick: 100 000 grains, 64x48, 16 spp, reference 2 x 256). Images: DIR/spotlit_*.png.
"""

from __future__ import annotations

import gc
import math
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

MEDIAN_UM, SIGMA_G, ETA = 80.0, 1.5, 1.31
HALF = 5.0  # cm: cloud cube half-size
CENTER = (0.0, 7.0, 0.0)  # cm: cube from y = 2 to 12 above the floor at y = 0
SCALE_M = 0.01
MAX_DEPTH = 32

#: discrete configurations: name -> extra medium parameters
CONFIGS = {
    "default": {},
    "trunc=0.031": {"truncate_below": 0.031},
    "trunc=0": {"truncate_below": 0.0},
}


def box_transform(mi):
    T = mi.ScalarTransform4f
    return T().translate(list(CENTER)) @ T().scale(HALF)


def discrete_medium(mi, count: int, seed: int, **params) -> dict:
    d = {"type": "discrete", "count": int(count), "radius_median": MEDIAN_UM, "radius_sigma_g": SIGMA_G, "eta": ETA,
         "scale_m": SCALE_M, "to_world": box_transform(mi), "seed": int(seed), "phase": {"type": "particle"}}
    d.update(params)
    return d


def homogeneous_medium(motes, count: int) -> dict:
    n_m3 = count / (2 * HALF * SCALE_M) ** 3
    return motes.homogeneous_equivalent(motes.Species(motes.LogNormal(MEDIAN_UM, SIGMA_G), ETA), n_m3, scale_m=SCALE_M)


def scene_dict(mi, medium: dict | None, width: int, height: int, spp: int, seed: int) -> dict:
    T = mi.ScalarTransform4f
    d = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": MAX_DEPTH},
        "sensor": {"type": "perspective", "fov": 45, "fov_axis": "x",
                   "to_world": T().look_at(origin=[0, 20, 38], target=[0, 4, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
        "spot": {"type": "spot", "to_world": T().look_at(origin=[-16, 30, -4], target=[4, 0, 2], up=[0, 1, 0]),
                 "intensity": {"type": "rgb", "value": 4000.0}, "cutoff_angle": 10, "beam_width": 8},
        "floor": {"type": "rectangle", "to_world": T().scale(25) @ T().rotate([1, 0, 0], -90),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.8}}},
    }
    if medium is not None:
        d["cloud"] = {"type": "cube", "to_world": box_transform(mi), "bsdf": {"type": "null"}, "interior": medium}
    return d


def render(mi, scene_d: dict, spp: int, seed: int):
    t = time.perf_counter()
    scene = mi.load_dict(scene_d)
    img = np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float64).mean(axis=2)
    del scene
    gc.collect()
    return img, time.perf_counter() - t


def stats(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None):
    """(mean, SE) of (a + b) / 2 over the pixels (in mask), SE from the per-pixel differences."""
    if mask is not None:
        a, b = a[mask], b[mask]
    a, b = a.ravel(), b.ravel()
    return float(0.5 * (a.mean() + b.mean())), float(math.sqrt(np.var(a - b, ddof=1) / (4 * a.size)))


def rel(x, ref):
    r = x[0] / ref[0] - 1.0
    return r, math.hypot(x[1] / ref[0], x[0] * ref[1] / ref[0] ** 2)


def pm(v) -> str:
    m, se = v[:2]
    dec = max(0, 1 - int(math.floor(math.log10(se)))) if se > 0 else 4
    return f"{m:.{dec}f} ± {se:.{dec}f}"


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--count", type=int, help="grains (default 400000; --quick 100000)")
    ap.add_argument("--res", type=int, help="image width; height = 3/4 of it (default 128; --quick 64)")
    ap.add_argument("--spp", type=int, help="spp of the compared renders, per seed (default 64; --quick 16)")
    ap.add_argument("--ref-spp", type=int, help="spp of the homogeneous reference, per seed (default 4096; --quick 256)")
    ap.add_argument("--configs", default=",".join(CONFIGS), help=f"discrete configurations, of {list(CONFIGS)}")
    args = ap.parse_args()
    sw, motes = C.Stopwatch(), C.import_motes()
    count = args.count or (100_000 if args.quick else 400_000)
    width = args.res or (64 if args.quick else 128)
    height = width * 3 // 4
    spp = args.spp or (16 if args.quick else 64)
    ref_spp = args.ref_spp or (256 if args.quick else 4096)
    configs = C.choose_configs(ap, args.configs, CONFIGS)
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi

    seeds = (1, 2)
    imgs, secs = {}, {}
    # Homogeneous renders first, in Mitsuba's symbolic mode (no Python medium may be alive then).
    motes.set_evaluated_mode(False)
    bare, _ = render(mi, scene_dict(mi, None, width, height, 16, 0), 16, 0)
    lit = bare >= 0.5 * bare.max()
    hom = homogeneous_medium(motes, count)
    for name, n in (("reference", ref_spp), ("homogeneous", spp)):
        out = [render(mi, scene_dict(mi, hom, width, height, n, s + 10 * (name == "reference")), n,
                      s + 10 * (name == "reference")) for s in seeds]
        imgs[name], secs[name] = [o[0] for o in out], sum(o[1] for o in out)
        print(f"{name}: {2 * n} spp in {secs[name]:.1f} s", flush=True)
    motes.set_evaluated_mode(True)
    for c in configs:
        out = [render(mi, scene_dict(mi, discrete_medium(mi, count, s, **CONFIGS[c]), width, height, spp, s), spp, s)
               for s in seeds]
        imgs[c], secs[c] = [o[0] for o in out], sum(o[1] for o in out)
        print(f"discrete {c}: 2 x {spp} spp in {secs[c]:.1f} s (incl. loading)", flush=True)

    out_dir = C.out_dir(args.out)
    e = 1.0 / max(float(np.percentile(imgs["reference"][0], 99.5)), 1e-12)
    for name in imgs:
        mi.util.write_bitmap(str(out_dir / f"spotlit_{name.replace('=', '')}.png"),
                             mi.TensorXf(np.clip(imgs[name][0] * e, 0, None)[..., None].repeat(3, axis=2).astype(np.float32)))
    print(f"images (first seed, one exposure): {out_dir}/spotlit_*.png")
    ref_img, ref_lit = stats(*imgs["reference"]), stats(*imgs["reference"], lit)
    rows = []
    for name in ["reference", "homogeneous"] + configs:
        a, b = imgs[name]
        s_img, s_lit = stats(a, b), stats(a, b, lit)
        r_img, r_lit = rel(s_img, ref_img), rel(s_lit, ref_lit)
        label = name if name in ("reference", "homogeneous") else f"discrete {name}"
        n = ref_spp if name == "reference" else spp
        rows.append([label, f"2 x {n}", f"{secs[name]:.0f}", pm(s_img), pm(s_lit),
                     "—" if name == "reference" else f"{r_img[0]:+.2%} ± {r_img[1]:.2%}",
                     "—" if name == "reference" else f"{r_lit[0]:+.2%} ± {r_lit[1]:.2%}",
                     f"{max(a.max(), b.max()) / max(s_img[0], 1e-30):.0f}"])
    C.print_table(f"Spot-lit floor under {count} grains (log-normal {MEDIAN_UM:g} um, sigma_g {SIGMA_G}, eta {ETA}) "
                  f"in a 10 cm cube; llvm_ad_rgb volpath, {width}x{height} px; lit floor = {int(lit.sum())} px; "
                  "SE from two seeds; bias vs the homogeneous reference",
                  ["render", "spp", "s", "image mean ± SE", "lit-floor mean ± SE", "image bias", "lit-floor bias",
                   "max pixel / image mean"], rows)
    print(f"runtime {sw():.1f} s")


if __name__ == "__main__":
    main()
