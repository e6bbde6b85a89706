"""Rendering with the `discrete` medium in Mitsuba's own volpath (issue 5), side by side in one run:

1. Time: a sparse (visible grains) and a dense (hazy) dust room, the discrete medium against Mitsuba's
   `homogeneous` + `tabphase` equivalent (motes.homogeneous_equivalent of the same particles' PSD and
   density) at equal spp, same variant (llvm_ad_rgb) and integrator; the homogeneous one both in the
   evaluated ("wavefront") mode the plugin needs and in Mitsuba's default symbolic mode. Also: null
   collisions per real collision, and the time inside the Rust queries against the rest (Dr.Jit, Mitsuba,
   numpy conversions). Images of both configurations go to the output folder.
2. Continuous limit (paper Fig. 14-15): a fixed PSD and a fixed bulk sigma_t (in scene units) with
   N = 1e3 ... 1e6 particles (the scene's metres per unit grow as sqrt(N), so particles get many and
   small against a fixed query radius); relative image difference to the homogeneous equivalent, with the
   noise floor measured between two homogeneous renders of different seeds.
3. Graininess: contrast between pixels in the light beam at low and high spp, discrete vs homogeneous (grains
   persist as spp grow, Monte Carlo noise does not).

    .venv/bin/python scripts/bench/bench_render.py [--quick] [--only timing|limit|grains] [--out out]
"""

from __future__ import annotations

import gc
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

TAB_SIZE = 4096
TRUNCATE = float(np.arccos(1.0 - 2.0 / (TAB_SIZE - 1)))  # what homogeneous_equivalent's tabphase cannot resolve


def cube_volume_m3(half_units: float, scale_m: float) -> float:
    return (2 * half_units * scale_m) ** 3


def timed(f, owner):
    """``f`` wrapped to add its wall time to ``owner.seconds``."""
    def run(*a, **k):
        t = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            owner.seconds += time.perf_counter() - t
    return run


class CoreTimer:
    """Wraps the Rust medium to time its queries."""

    def __init__(self, core):
        self.core, self.seconds = core, 0.0

    def __getattr__(self, name):
        f = getattr(self.core, name)
        return timed(f, self) if callable(f) else f


class BridgeTimer:
    """Times the plugins' Dr.Jit <-> numpy conversions (motes.plugins._bridge functions)."""

    NAMES = ("vec3", "mask", "floats", "vector3", "spectrum", "channel_wavelengths")

    def __init__(self):
        from motes.plugins import discrete_medium, particle_phase

        self.seconds = 0.0
        for mod in (discrete_medium, particle_phase):
            for name in self.NAMES:
                if hasattr(mod, name):
                    setattr(mod, name, timed(getattr(mod, name), self))


def room(mi, medium: dict, res: int, spp: int, seed: int = 0, max_depth: int = 6) -> dict:
    """The dust room (centimetres; the default scene before its room grew walls and a ceiling) as a dict,
    with the cube's medium given."""
    T = mi.ScalarTransform4f
    wall = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.55, 0.52, 0.48]}}
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": max_depth},
        "sensor": {"type": "perspective", "fov": 40, "to_world": T().look_at(origin=[0, 2, 42], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "gaussian"}},
                   "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
        "spot": {"type": "spot", "to_world": T().look_at(origin=[-8, 19, -15], target=[2, -3, 12], up=[0, 1, 0]),
                 "intensity": {"type": "rgb", "value": [120000, 110000, 94000]}, "cutoff_angle": 8, "beam_width": 6},
        "panel": {"type": "rectangle", "to_world": T().translate([0, 19.9, -8]).rotate([1, 0, 0], 90).scale(4),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.04, 0.042, 0.05]}}},
        "floor": {"type": "rectangle", "to_world": T().translate([0, -12, 0]).scale(20).rotate([1, 0, 0], -90), "bsdf": wall},
        "back": {"type": "rectangle", "to_world": T().translate([0, 0, -16]).scale(20), "bsdf": wall},
        "cube": {"type": "cube", "to_world": T().scale(10), "bsdf": {"type": "null"}, "interior": medium},
    }


def configs(quick: bool):
    # sparse: the default scene's dust; dense: many more, larger grains and a wider query cylinder (haze).
    return {
        "sparse": dict(count=60_000, median=60.0, sigma_g=1.6, k=0.7),
        "dense": dict(count=300_000 if quick else 1_000_000, median=100.0, sigma_g=1.2, k=1.0),
    }


def discrete_dict(mi, cfg: dict, res: int, seed: int = 0) -> dict:
    return {"type": "discrete", "count": cfg["count"], "radius_median": cfg["median"], "radius_sigma_g": cfg["sigma_g"],
            "eta": 1.55, "eta_k": 0.0005, "scale_m": 0.01, "footprint_k": cfg["k"], "fov": 40.0, "film_width": res,
            "z_med": 32.0, "to_world": mi.ScalarTransform4f().scale(10),
            "truncate_below": TRUNCATE, "seed": seed, "phase": {"type": "particle"}}


def homogeneous_dict(motes, cfg: dict, color: str = "rgb") -> dict:
    sp = motes.Species(motes.LogNormal(cfg["median"], cfg["sigma_g"]), complex(1.55, 0.0005))
    n_m3 = cfg["count"] / cube_volume_m3(10, 0.01)
    return motes.homogeneous_equivalent(sp, n_m3, color=color, scale_m=0.01, tabphase_size=TAB_SIZE)


def render(mi, scene):
    t = time.perf_counter()
    img = np.asarray(mi.render(scene), dtype=np.float64)
    return time.perf_counter() - t, img


def save_png(mi, img, path, exposure=None):
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    e = exposure if exposure is not None else 1.0 / max(float(np.percentile(lum, 99.7)), 1e-12)
    mi.util.write_bitmap(str(path), mi.TensorXf((np.clip(img * e, 0, None)).astype(np.float32)))
    return e


def timing(motes, mi, out, quick):
    res, spp = (128, 16) if quick else (192, 32)
    rows = []
    bridge = BridgeTimer()
    for name, cfg in configs(quick).items():
        t0 = time.perf_counter()
        sd = mi.load_dict(room(mi, discrete_dict(mi, cfg, res), res, spp))
        t_build = time.perf_counter() - t0
        med = [sh.interior_medium() for sh in sd.shapes() if sh.interior_medium() is not None][0]
        sh = mi.load_dict(room(mi, homogeneous_dict(motes, cfg), res, spp))
        # warm up (kernel compilation), then alternate and keep the best of two
        motes.set_evaluated_mode(True)
        render(mi, mi.load_dict(room(mi, homogeneous_dict(motes, cfg), 16, 1)))
        render(mi, mi.load_dict(room(mi, discrete_dict(mi, cfg, 16), 16, 1)))
        timer = CoreTimer(med.data._core)
        med.data._core = timer
        t_d, t_h, t_sym = [], [], []
        for rep in range(2):
            timer.seconds = bridge.seconds = 0.0
            med._stats.update(intersect_calls=0, rays=0, events=0, nulls=0)
            td, img_d = render(mi, sd)
            t_d.append((td, timer.seconds, bridge.seconds))
            th, img_h = render(mi, sh)
            t_h.append(th)
        st, q_r = dict(med.stats), med.data.query_radius
        # Symbolic mode traces every live medium instance, so the Python one must be gone first.
        del sd, med, timer
        gc.collect()
        motes.set_evaluated_mode(False)
        render(mi, sh)  # compile
        for rep in range(2):
            ts, img_s = render(mi, sh)
            t_sym.append(ts)
        motes.set_evaluated_mode(True)
        td, rust, conv = min(t_d)
        th, ts = min(t_h), min(t_sym)
        e = save_png(mi, img_h, out / f"render_{name}_homogeneous.png")
        save_png(mi, img_d, out / f"render_{name}_discrete.png", e)
        rows.append([name, cfg["count"], f"{q_r:.3g}", f"{t_build:.2f}", f"{td:.2f}", f"{th:.2f}", f"{ts:.2f}",
                     f"{td / th:.2f}", f"{td / ts:.1f}", f"{st['nulls'] / max(st['events'], 1):.3g}", st["events"],
                     f"{st['rays'] / max(st['events'], 1):.2f}", f"{rust / td:.0%}", f"{conv / td:.0%}", f"{img_d.mean() / img_h.mean():.3f}"])
        print(f"[{name}] discrete {td:.2f} s (Rust {rust:.2f} s, conversions {conv:.2f} s), homogeneous {th:.2f} s evaluated / {ts:.2f} s symbolic", flush=True)
    C.print_table(f"Render time, llvm_ad_rgb, volpath (max_depth 6), {res}x{res} px, {spp} spp, 2 cores; best of 2",
                  ["config", "particles", "r_c (cm)", "build s", "discrete s", "homog. eval. s", "homog. symb. s",
                   "discrete / homog. (eval.)", "discrete / homog. (symb.)", "null / real collisions", "real collisions",
                   "rays per real collision", "time in Rust queries", "time in numpy conversions", "image mean ratio"], rows)


def continuous_limit(motes, mi, out, quick):
    res, spp = (48, 64) if quick else (64, 256)
    counts = [1_000, 10_000, 100_000] + ([] if quick else [1_000_000])
    sp = motes.Species(motes.LogNormal(20.0, 1.5), 1.31)
    b = motes.bulk_properties(sp, 1.0, motes.RGB_WAVELENGTHS_UM, truncate_below_rad=TRUNCATE)
    c_mean_um2 = float(np.mean(b["sigma_t"])) * 1e12  # n = 1 / m^3: sigma (1/m) is <C_t> in m^2
    sigma_t_scene, half = 1.0, 1.0  # per scene unit; cube [-1, 1]^3: optical thickness 2
    rc = motes.query_radius_from_camera(0.7, 30.0, res, 4.0)
    T = mi.ScalarTransform4f

    def scene(medium, seed):
        return {"type": "scene", "integrator": {"type": "volpath", "max_depth": 12},
                "sensor": {"type": "perspective", "fov": 30, "to_world": T().look_at(origin=[0, 1.5, 5.5], target=[0, -0.2, 0], up=[0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                           "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
                "sun": {"type": "directional", "direction": [0.6, -0.7, -0.4], "irradiance": {"type": "rgb", "value": 3.0}},
                "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.08, 0.1, 0.14]}},
                "floor": {"type": "rectangle", "to_world": T().translate([0, -1.01, 0]).scale(4).rotate([1, 0, 0], -90),
                          "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
                "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium}}

    def binned(img, k=8):
        h = img.shape[0] // k
        return img[: h * k, : h * k].reshape(h, k, h, k, -1).mean(axis=(1, 3))

    def rel(a, b_):
        return float(np.abs(binned(a) - binned(b_)).mean() / binned(b_).mean())

    rows, imgs = [], {}
    ref_dicts = []
    for n in counts:
        scale_m = float(np.sqrt(n * c_mean_um2 * 1e-12 / ((2 * half) ** 3 * sigma_t_scene)))
        n_m3 = n / cube_volume_m3(half, scale_m)
        hom = motes.homogeneous_equivalent(sp, n_m3, scale_m=scale_m, tabphase_size=TAB_SIZE)
        ref_dicts.append(hom)
        d = {"type": "discrete", "count": n, "psd": '{"type": "lognormal", "median_um": 20, "sigma_g": 1.5}', "eta": 1.31,
             "scale_m": scale_m, "query_radius": rc, "truncate_below": TRUNCATE, "seed": 1, "phase": {"type": "particle"}}
        t, img = render(mi, mi.load_dict(scene(d, 0)))
        imgs[n] = img
        rows.append([n, f"{scale_m:.3g}", f"{20e-6 / scale_m:.2g}", f"{float(hom['scale']):.4g}", f"{t:.1f}"])
    _, h0 = render(mi, mi.load_dict(scene(ref_dicts[-1], 0)))
    _, h1 = render(mi, mi.load_dict(scene(ref_dicts[-1], 7)))
    noise = rel(h1, h0)
    for row, n in zip(rows, counts):
        d_ = rel(imgs[n], h0)
        row += [f"{d_:.3%}", f"{imgs[n].mean() / h0.mean() - 1:+.2%}", f"{np.sqrt(max(d_**2 - noise**2, 0)):.2%}"]
    e = save_png(mi, h0, out / "continuous_limit_homogeneous.png")
    for n in counts:
        save_png(mi, imgs[n], out / f"continuous_limit_{n}.png", e)
    C.print_table(f"Continuous limit: fixed PSD (log-normal 20 um, 1.5; n = 1.31) and sigma_t = 1 per unit (cube "
                  f"thickness 2), r_c = {rc:.3g} units; llvm_ad_rgb volpath, {res}x{res} px, {spp} spp; image "
                  f"difference on 8x8-pixel blocks; noise floor (homogeneous vs homogeneous, another seed) = {noise:.3%}",
                  ["particles", "metres per unit", "radius (units)", "sigma_t of equivalent (1/unit)", "discrete render s",
                   "rel. image difference", "image mean difference", "difference beyond noise"], rows)


def graininess(motes, mi, out, quick):
    """Grains are structure, noise is not. Each medium is rendered twice with different seeds (A, B); on the
    high-pass image hp = X - (3x3 box blur of X), which removes the smooth beam profile, the noise variance is
    var(hp(A) - hp(B)) / 2 and the structure variance var(hp((A + B) / 2)) - noise variance / 2. Contrasts are
    relative to the mean, over the lit beam (brightest 10 % of the homogeneous image)."""
    res, spp = (64, 64) if quick else (96, 256)
    cfg = configs(quick)["sparse"]

    def hp(x):
        p = np.pad(x, 1, mode="edge")
        blur = sum(p[i:i + x.shape[0], j:j + x.shape[1]] for i in range(3) for j in range(3)) / 9.0
        return x - blur

    rows, imgs = [], {}
    for name, medium in (("discrete", discrete_dict(mi, cfg, res)), ("homogeneous", homogeneous_dict(motes, cfg))):
        for seed in (3, 4):
            _, img = render(mi, mi.load_dict(room(mi, medium, res, spp, seed=seed)))
            imgs[name, seed] = img.mean(axis=2)
        save_png(mi, img, out / f"grains_{name}_{spp}spp.png")
    ref = imgs["homogeneous", 3] + imgs["homogeneous", 4]
    beam = ref > np.percentile(ref, 90)
    for name in ("discrete", "homogeneous"):
        a, b = imgs[name, 3], imgs[name, 4]
        mean = float(((a + b) / 2)[beam].mean())
        noise = float(np.var((hp(a) - hp(b))[beam]) / 2)
        structure = float(np.var(hp((a + b) / 2)[beam]) - noise / 2)
        rows.append([name, f"{np.sqrt(max(structure, 0)) / mean:.3f}", f"{np.sqrt(noise) / mean:.3f}"])
    C.print_table(f"Graininess: high-pass pixel contrast in the lit beam, sparse dust room, {res}x{res} px, {spp} spp, "
                  "two seeds per medium", ["medium", "structure (grains), noise removed", "Monte Carlo noise per render"], rows)


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--only", choices=["timing", "limit", "grains"], help="run one part")
    args = ap.parse_args()
    out, sw, motes = C.out_dir(args.out), C.Stopwatch(), C.import_motes()
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi

    for part, run in (("timing", timing), ("limit", continuous_limit), ("grains", graininess)):
        if args.only in (None, part):
            run(motes, mi, out, args.quick)
    print(f"runtime {sw():.1f} s")


if __name__ == "__main__":
    main()
