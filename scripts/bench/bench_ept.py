"""The `discrete` medium against explicit path tracing (EPT, the paper's baseline) of the SAME particles.

Glass grains (index 1.5, radii 0.2-2 mm, uniform PSD) at rejection-sampled, non-overlapping positions in a
10 cm box (scene unit = 1 cm, ``scale_m = 0.01``); every grain lies wholly inside the box. EPT renders
them as Mitsuba ``sphere`` shapes with a ``dielectric`` BSDF (``path``); the discrete medium reads the
same positions and radii from a particle file (``filename``, .npz; positions in cm, radii in um, no
``to_world``) inside a null-BSDF cube 1 cm larger on every side than the box (so that a query cylinder
r_c + r_p never reaches past the medium's boundary), rendered with ``volpath``. Both: max_depth 64,
llvm_ad_rgb, orthographic cameras covering the cube's face, black background.

The light: EPT's BSDFs are all delta functions, so a delta light (``directional``) could never be reached.
The source is instead a far disk emitter (radiance 1) on the +x axis, 1000 cm away, subtending a cone of
half-angle 45 deg (side view; 30 deg for the transmittance) as seen from the cloud: a beam travelling along
-x, spread over that cone. Every image mean is then a fraction of the camera's rays (radiance 1 = all):

(a) side: camera on +z looking along -z, perpendicular to the beam: light scattered by 45-135 deg;
(b) trans: camera on -x looking along +x into the source through the cloud: total transmittance into
    the 30 deg cone (unscattered + forward-scattered);
(c) direct: as (b) with a 0.5 deg source: EPT counts (almost only) unscattered rays, the discrete
    medium is rendered with ``albedo = 0`` (its direct transmittance exp(-tau)); also the geometric
    unblocked fraction of the camera's rays (no sphere hit; brute-force ray-disk test on a jittered
    grid). Without forward-peak truncation the discrete medium's extinction includes diffraction
    (C_ext ~ 2 pi r^2, the extinction paradox), so its direct transmittance is expected BELOW the
    geometric one; with truncate_below >> lambda / r the diffraction peak counts as unscattered.

Standard errors: each render is done twice with different sampler (and free-flight) seeds on the same
particles; SE of the mean of the two = sqrt(var_pixels(A - B) / (4 N_pixels)), the Monte Carlo error
given the particles (the particles are shared by both methods, so their arrangement is no noise).

Discrete configurations: the medium's DEFAULTS (no query_radius, no truncate_below), and for reference
query_radius = 0.3 (3 mm), truncate_below = 0.03 rad, both, and truncate_below = 0 (no forward-peak
truncation: diffraction counts as scattering, so the direct transmittance falls below the geometric one).

EPT renders in Mitsuba's symbolic mode (evaluated mode, which the plugin needs, dispatches every call over
the 1000s of sphere shapes one kernel each: ~100 s per image instead of ~1 s) and with 4x the spp.

    .venv/bin/python scripts/bench/bench_ept.py [--count N] [--spp N] [--res N] [--dense] [--quick] [--configs a,b]

Run time on 2 shared cores: ~2.5 min (default: 1000 grains, 96x96, 64 spp), ~5.5 min (--dense: 4000
grains), ~10 s (--quick: 300 grains, 48x48, 16 spp).
"""

from __future__ import annotations

import gc
import json
import math
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

HALF = 5.0  # cm: particles (whole spheres) inside [-HALF, HALF]^3
MARGIN = 1.0  # cm: the discrete medium's cube and the cameras' view extend this far beyond
ETA = 1.5
R_MIN_UM, R_MAX_UM = 200.0, 2000.0
SCALE_M = 0.01  # 1 scene unit = 1 cm
SOURCE_DIST = 1000.0  # cm
CONE_DEG = {"side": 45.0, "trans": 30.0, "direct": 0.5}  # source half-angle per view
CAM_DIST = 50.0
MAX_DEPTH = 64
EPT_SPP_FACTOR = 4  # EPT (symbolic mode, no Python) is cheap: more samples for it

#: discrete configurations: name -> extra medium parameters
CONFIGS = {
    "default": {},
    "qr=0.3": {"query_radius": 0.3},
    "trunc=0.03": {"truncate_below": 0.03},
    "qr=0.3+trunc=0.03": {"query_radius": 0.3, "truncate_below": 0.03},
    "trunc=0": {"truncate_below": 0.0},
}


# --------------------------------------------------------------------------------------------- particles
def make_particles(count: int, seed: int = 1, half: float = HALF, r_min_um: float = R_MIN_UM,
                   r_max_um: float = R_MAX_UM, max_tries: int = 10_000):
    """``count`` non-overlapping spheres wholly inside [-half, half]^3: radii (um) from the uniform PSD
    (kept; only positions are redrawn on rejection, so the PSD is not biased), positions in cm."""
    import motes  # noqa: PLC0415

    r_um = motes.Uniform(r_min_um, r_max_um).sample(count, seed=seed)
    r = r_um * 1e-4  # cm
    rng = np.random.default_rng(seed + 1000)
    pos = np.empty((count, 3))
    for i in range(count):
        for _ in range(max_tries):
            p = rng.uniform(-half + r[i], half - r[i], size=3)
            if i == 0 or np.all(np.sum((pos[:i] - p) ** 2, axis=1) > (r[:i] + r[i]) ** 2):
                pos[i] = p
                break
        else:
            raise RuntimeError(f"could not place sphere {i} of {count} without overlap (too dense)")
    return pos, r_um


def save_particle_file(path, pos, r_um) -> str:
    import motes  # noqa: PLC0415

    motes.save_particles(path, motes.ParticleSet(pos, r_um, np.zeros(len(r_um), dtype=np.int64)))
    return str(path)


def psd_json(r_min_um: float = R_MIN_UM, r_max_um: float = R_MAX_UM) -> str:
    return json.dumps({"type": "uniform", "r_min_um": r_min_um, "r_max_um": r_max_um})


# ------------------------------------------------------------------------------------------------ scenes
def discrete_medium(filename: str, seed: int = 0, **params) -> dict:
    """The discrete medium of the particle file; ``params`` e.g. query_radius, truncate_below, albedo."""
    d = {"type": "discrete", "filename": filename, "psd": psd_json(), "eta": ETA, "scale_m": SCALE_M,
         "seed": int(seed), "phase": {"type": "particle"}}
    d.update(params)
    return d


def scene_dict(mi, view: str, *, res: int, spp: int, seed: int = 0, particles=None, medium: dict | None = None) -> dict:
    """One measurement scene. Exactly one of ``particles`` ((pos_cm, r_um): EPT spheres) and ``medium``
    (a ``discrete`` dict) is given. ``view``: side, trans or direct (module docs)."""
    if (particles is None) == (medium is None):
        raise ValueError("give particles (EPT) or medium (discrete), one of them")
    T = mi.ScalarTransform4f
    w = HALF + MARGIN
    if view == "side":
        cam = T().look_at(origin=[0, 0, CAM_DIST], target=[0, 0, 0], up=[0, 1, 0])
    elif view in ("trans", "direct"):
        cam = T().look_at(origin=[-CAM_DIST, 0, 0], target=[0, 0, 0], up=[0, 0, 1])
    else:
        raise ValueError(f"unknown view {view!r}")
    src_r = SOURCE_DIST * math.tan(math.radians(CONE_DEG[view]))
    d = {
        "type": "scene",
        "integrator": {"type": "path" if medium is None else "volpath", "max_depth": MAX_DEPTH},
        "sensor": {"type": "orthographic", "to_world": cam @ T().scale([w, w, 1]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
        "source": {"type": "disk",
                   "to_world": T().look_at(origin=[SOURCE_DIST, 0, 0], target=[0, 0, 0], up=[0, 0, 1]) @ T().scale(src_r),
                   "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}},
    }
    if medium is not None:
        d["cube"] = {"type": "cube", "to_world": T().scale(w), "bsdf": {"type": "null"}, "interior": medium}
    else:
        pos, r_um = particles
        d["glass"] = {"type": "dielectric", "id": "glass", "int_ior": ETA, "ext_ior": 1.0}
        for i, (p, r) in enumerate(zip(pos, r_um * 1e-4)):
            d[f"grain{i:06d}"] = {"type": "sphere", "center": [float(x) for x in p], "radius": float(r),
                                  "bsdf": {"type": "ref", "id": "glass"}}
    return d


# ------------------------------------------------------------------------------------------- measurement
def _pixels(img) -> np.ndarray:
    a = np.asarray(img, dtype=np.float64)
    return a.reshape(-1, a.shape[-1]).mean(axis=1)  # channel-averaged


def render_two_seeds(mi, make_scene, spp: int, seeds=(1, 2)):
    """Render ``make_scene(seed)`` for two seeds: (mean, SE, seconds) of the mean of both images, the SE
    from the per-pixel differences (Monte Carlo error only; module docs)."""
    t0 = time.perf_counter()
    pix = []
    for s in seeds:
        scene = mi.load_dict(make_scene(s))
        pix.append(_pixels(mi.render(scene, spp=spp, seed=s)))
        del scene
        gc.collect()
    a, b = pix
    mean = 0.5 * (a.mean() + b.mean())
    se = math.sqrt(np.var(a - b, ddof=1) / (4 * a.size))
    return float(mean), float(se), time.perf_counter() - t0


def measure_ept(mi, particles, views, res: int, spp: int) -> dict:
    """Per view (mean, SE, s). Rendered in Mitsuba's symbolic mode: in the evaluated mode the plugins
    need, every call dispatches over the 1000s of sphere shapes one kernel each (minutes per image).
    Symbolic mode traces every live Python medium, so none may exist while this runs."""
    import motes  # noqa: PLC0415

    gc.collect()
    motes.set_evaluated_mode(False)
    try:
        return {v: render_two_seeds(mi, lambda s, v=v: scene_dict(mi, v, res=res, spp=spp, seed=s, particles=particles), spp)
                for v in views}
    finally:
        motes.set_evaluated_mode(True)


def measure_discrete(mi, filename: str, params: dict, views, res: int, spp: int) -> dict:
    """Per view (mean, SE, s); the view ``direct`` is rendered with ``albedo = 0``."""
    out = {}
    for v in views:
        extra = dict(params, albedo=0.0) if v == "direct" else dict(params)
        out[v] = render_two_seeds(mi, lambda s, v=v, e=extra: scene_dict(
            mi, v, res=res, spp=spp, seed=s, medium=discrete_medium(filename, seed=s, **e)), spp)
    return out


def geometric_unblocked(pos, r_um, n: int = 3000, seed: int = 5):
    """Fraction (and binomial SE) of the ``trans`` camera's rays (along +x, uniform over the film
    [-w, w]^2 in (y, z)) that hit no sphere: jittered n x n grid, exact ray-disk test per sphere."""
    w = HALF + MARGIN
    h = 2 * w / n
    rng = np.random.default_rng(seed)
    y = -w + (np.arange(n)[:, None] + rng.random((n, n))) * h
    z = -w + (np.arange(n)[None, :] + rng.random((n, n))) * h
    hit = np.zeros((n, n), dtype=bool)
    for (_, cy, cz), r in zip(pos, r_um * 1e-4):
        i0, i1 = max(int((cy - r + w) / h) - 1, 0), min(int((cy + r + w) / h) + 2, n)
        j0, j1 = max(int((cz - r + w) / h) - 1, 0), min(int((cz + r + w) / h) + 2, n)
        hit[i0:i1, j0:j1] |= (y[i0:i1, j0:j1] - cy) ** 2 + (z[i0:i1, j0:j1] - cz) ** 2 < r * r
    f = 1.0 - hit.mean()
    return float(f), float(math.sqrt(f * (1 - f) / hit.size))


def compare(d, e):
    """(relative difference d/e - 1, its SE) of (mean, SE) pairs."""
    (md, sd), (me, se) = d[:2], e[:2]
    rel = md / me - 1.0
    return rel, math.hypot(sd / me, md * se / me**2)


def within(d, e, rel_tol: float = 0.03, n_se: float = 3.0) -> bool:
    """|d - e| <= rel_tol * e + n_se * SE of the difference."""
    return abs(d[0] - e[0]) <= rel_tol * abs(e[0]) + n_se * math.hypot(d[1], e[1])


def pm(v) -> str:
    """'mean ± SE' with the SE to 2 significant digits."""
    m, se = v[:2]
    dec = max(0, 1 - int(math.floor(math.log10(se)))) if se > 0 else 4
    return f"{m:.{dec}f} ± {se:.{dec}f}"


def geometry_summary(pos, r_um) -> dict:
    r = r_um * 1e-4
    vol = (2 * HALF) ** 3
    return {"count": len(r), "volume_fraction": float((4 / 3 * np.pi * r**3).sum() / vol),
            "geometric_tau": float(np.pi * (r**2).sum() / vol * 2 * HALF)}


def main() -> None:
    ap = C.parser(__doc__)
    ap.add_argument("--count", type=int, help="number of grains (default 1000; --dense 4000; --quick 300)")
    ap.add_argument("--spp", type=int, help="samples per pixel per seed (default 64; --quick 16)")
    ap.add_argument("--res", type=int, help="image width = height (default 96; --quick 48)")
    ap.add_argument("--dense", action="store_true", help="4x more grains (geometric optical depth ~2 across the box)")
    ap.add_argument("--configs", default=",".join(CONFIGS), help=f"discrete configurations, comma-separated, of {list(CONFIGS)}")
    ap.add_argument("--seed", type=int, default=1, help="particle seed")
    args = ap.parse_args()
    sw, motes = C.Stopwatch(), C.import_motes()
    count = args.count or (300 if args.quick else 4000 if args.dense else 1000)
    spp = args.spp or (16 if args.quick else 64)
    res = args.res or (48 if args.quick else 96)
    configs = C.choose_configs(ap, args.configs, CONFIGS)
    motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi

    t = time.perf_counter()
    pos, r_um = make_particles(count, seed=args.seed)
    geo = geometry_summary(pos, r_um)
    print(f"{count} grains placed in {time.perf_counter() - t:.1f} s: volume fraction {geo['volume_fraction']:.3%}, "
          f"geometric optical depth across the box {geo['geometric_tau']:.3f}", flush=True)
    views = ("side", "trans", "direct")
    with tempfile.TemporaryDirectory() as tmp:
        fname = save_particle_file(pathlib.Path(tmp) / "grains.npz", pos, r_um)
        ept = measure_ept(mi, (pos, r_um), views, res, EPT_SPP_FACTOR * spp)
        print("EPT: " + ", ".join(f"{v} {pm((m, s))} ({t:.0f} s)" for v, (m, s, t) in ept.items()), flush=True)
        disc = {}
        for c in configs:
            disc[c] = measure_discrete(mi, fname, CONFIGS[c], views, res, spp)
            print(f"discrete {c}: " + ", ".join(f"{v} {pm((m, s))} ({t:.0f} s)" for v, (m, s, t) in disc[c].items()),
                  flush=True)
    geo_f = geometric_unblocked(pos, r_um)

    label = {"side": "(a) side scattering (45-135 deg)", "trans": "(b) total transmittance (30 deg)",
             "direct": "(c) direct transmittance (0.5 deg; discrete albedo 0)"}
    rows = []
    for v in views:
        e = ept[v]
        for c in configs:
            d = disc[c][v]
            rel, rel_se = compare(d, e)
            rows.append([label[v], c, pm(e), pm(d), f"{rel:+.2%} ± {rel_se:.2%}", "yes" if within(d, e) else "no"])
    for c in configs:
        d = disc[c]["direct"]
        rel, rel_se = compare(d, geo_f)
        rows.append(["(c') direct vs geometric unblocked fraction", c, pm(geo_f) + " (geom.)", pm(d),
                     f"{rel:+.2%} ± {rel_se:.2%}", "yes" if within(d, geo_f) else "no"])
    C.print_table(f"discrete medium vs EPT, same {count} glass grains (eta {ETA}, r {R_MIN_UM:g}-{R_MAX_UM:g} um uniform, "
                  f"volume fraction {geo['volume_fraction']:.2%}, geometric tau {geo['geometric_tau']:.2f}) in a 10 cm box; "
                  f"llvm_ad_rgb, {res}x{res} px, 2 x {spp} spp (EPT 2 x {EPT_SPP_FACTOR * spp}), max_depth {MAX_DEPTH}; SE from two seeds",
                  ["quantity", "discrete config", "EPT mean ± SE", "discrete mean ± SE", "discrete / EPT − 1",
                   "within 3 % + 3 SE"], rows)
    print(f"runtime {sw():.1f} s")


if __name__ == "__main__":
    main()
