"""Time to reach a given image error: the `discrete` medium against explicit path tracing (EPT) of the
same particles, on simplified versions of the paper's LAMP and CORNELL BOX scenes (Sec. 6.1, Table 1).

Scene unit = 1 cm (``scale_m = 0.01``), grains at rejection-sampled, non-overlapping positions (radii from
a uniform PSD, every grain wholly inside its box; ``bench_ept.make_particles``):

* LAMP: ice-like grains (index 1.31, radii 200-1000 um; 4000, ``--quick`` 300) in an 8 cm cube around
  a spherical area lamp (radius 1 cm, radiance 5, at the cube's centre; no grain within 0.3 cm of it)
  above a diffuse grey floor (reflectance 0.5, 1 cm below the medium's cube), seen from the front and
  slightly above (perspective, fov 35 deg, 28 cm away).
* CORNELL: glass grains (index 1.5, radii 300-800 um; 3000, ``--quick`` 300) in a 6 cm cube in the middle
  of a 10 cm Cornell box (white floor, ceiling and back wall 0.725, red left and green right walls with
  the classic Cornell reflectances, open front) lit by a 3 cm square area light just below the ceiling
  (radiance (12.8, 10.8, 5.6)), seen through the open front (perspective, fov 38 deg, 20 cm away).

EPT renders the grains as Mitsuba ``sphere`` shapes with a ``dielectric`` BSDF (``path``, Mitsuba's
symbolic mode); the discrete medium reads the same positions and radii from a particle file (.npz) inside
a null-BSDF cube 1 cm larger on every side than the grains' box (``volpath``, the native render path; the
LAMP's lamp lies inside that cube, so its exterior medium is the cloud), with the medium's DEFAULT
parameters (no query_radius, default truncation, tau_max, bins and grid) apart from what the geometry sets
(filename, psd, eta, scale_m). Both: llvm_ad_rgb, max_depth 64, box filter. Pixels in which a camera ray
meets an emitter directly (found by a render of the emission alone) are left out of every error: their
anti-aliased edges would dominate both methods' error alike, and in front of the lamp the two count the
grains' forward scattering differently (EPT's refraction vs the medium's transmittance and truncated
forward peak); only light that met the grains or the walls is measured. Area lights only: EPT's BSDFs
are delta functions, so a delta light could never be reached. One scene is alive at a time (Mitsuba's
symbolic calls trace every live shape, so the EPT scene's spheres would otherwise enter the discrete
scene's kernels): each batch of renders loads its scene (the kernel cache makes reloads cheap; load
times are reported apart).

Measurement per scene: a reference rendered by EPT at high spp (two halves with different seeds, cached
as ``ref_<scene>_<key>.npy`` under ``--out``, so reruns skip it; the halves' difference gives the
reference's own noise), then each method at spp = 1, 2, 4, ... (methods interleaved spp by spp, after one
warm-up render each so that kernel compilation is not timed; several renders, up to 8, at low spp, where
the error of one render is itself noisy; every render has its own seed, the same for both methods),
timing each ``mi.render`` (wall clock, including the conversion to numpy). RMSE = sqrt(mean over pixels
and channels of (image - reference)^2), averaged as MSE over the renders of one spp (``--downsample N``:
over the means of N x N pixel blocks of both images instead, so that where exactly within a block a
grain glints no longer counts). Fits per method: RMSE^2 = b^2 + c/spp (b, the floor: for EPT about the
reference's noise; for the discrete medium its model bias against EPT plus the reference's noise;
"bias" = sqrt(b^2 - reference noise^2)) and seconds per render = t0 + a spp (t0, the fixed cost per
render: for EPT Mitsuba's tracing of its thousands of sphere shapes, ~1 s at 3000-4000 grains, whatever
the spp).

Time to equal error: target RMSE levels are EPT's fitted RMSE at 16 spp (``--quick`` 4) and at max-spp / 4
spp, each raised to 1.5 b_discrete where lower (a level the discrete medium can reach). For each method
the time to reach a level is interpolated log-log between the two measured points that bracket it
("measured"; "<=" when 1 spp already gets there) and computed from the fits (t0 + a spp*, spp* = c /
(level^2 - b^2)); also "sampling only" (a spp*, without t0). Ratio EPT / discrete > 1: the discrete
medium is faster. Printed: markdown tables (every spp: seconds, RMSE; per scene: reference, floors, time
model; per target: the times and ratios) and notes where the discrete floor is above EPT's error
everywhere. Written to ``--out``: ``ept_time_to_error.png`` (RMSE against time, log-log, both methods,
both scenes; stars at the times to the targets), ``ept_time_to_error_images.png`` (reference, EPT and
discrete at their highest spp) and ``ept_time_to_error.json``.

    .venv/bin/python scripts/bench/ept_time_to_error.py [--quick] [--out DIR] [--res N] [--ref-spp N]
        [--max-spp N] [--count N] [--scenes lamp,cornell] [--seed N] [--downsample N]

Run time on 2 shared cores: ~7 min (default: 80x80, reference 2 x 4096 spp, sweep to 1024 spp; ~1.5 min
less with a cached reference; the CORNELL BOX is 2/3 of it), ~10 s (--quick: 300 grains, 48x48, reference
2 x 512 spp, sweep to 64 spp); ~80 s with --max-spp 128 --ref-spp 512 at the default grain counts.
"""

from __future__ import annotations

import gc
import math
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402

SCALE_M = 0.01  # 1 scene unit = 1 cm
MARGIN = 1.0  # cm: the discrete medium's cube extends this far beyond the grains' box
MAX_DEPTH = 64
MID_SPP = {"full": 16, "quick": 4}  # targets: EPT's (fitted) RMSE at this spp and at max_spp / 4
FLOOR_FACTOR = 1.5  # the target is at least this times the discrete medium's fitted floor
REF_SEEDS = (100_001, 100_002)
WARMUP_SEED = 7
SCENE_VERSION = 2  # part of the cached reference's name: change it with the scenes

#: scene parameters (lengths in cm, radii in um)
SCENES = {
    "lamp": {"title": "LAMP", "half": 4.0, "center": (0.0, 0.0, 0.0), "eta": 1.31, "r_um": (200.0, 1000.0),
             "count": 4000, "quick_count": 300, "lamp_radius": 1.0, "lamp_clearance": 0.3, "lamp_radiance": 5.0},
    "cornell": {"title": "CORNELL BOX", "half": 3.0, "center": (0.0, 0.0, 0.0), "eta": 1.5, "r_um": (300.0, 800.0),
                "count": 3000, "quick_count": 300, "box": 5.0, "light_half": 1.5, "light_radiance": (12.8, 10.8, 5.6)},
}
WHITE, RED, GREEN = 0.725, (0.63, 0.065, 0.05), (0.14, 0.45, 0.091)


# --------------------------------------------------------------------------------------------- particles
def make_scene_particles(name: str, count: int, seed: int):
    """(pos_cm, r_um) of ``count`` non-overlapping grains in the scene's box (bench_ept's rejection
    sampling); for LAMP, grains closer than ``lamp_clearance`` to the lamp are dropped (more are drawn
    so that ``count`` remain; the dropping is independent of the radius to within r / lamp distance)."""
    import bench_ept as B  # noqa: PLC0415

    p = SCENES[name]
    lo, hi = p["r_um"]
    if name != "lamp":
        pos, r_um = B.make_particles(count, seed=seed, half=p["half"], r_min_um=lo, r_max_um=hi)
        return pos + np.asarray(p["center"]), r_um
    excl = p["lamp_radius"] + p["lamp_clearance"]
    frac = 1.0 - (4 / 3 * math.pi * (excl + hi * 1e-4) ** 3) / (2 * p["half"]) ** 3
    n = int(math.ceil(count / frac * 1.05)) + 20
    while True:
        pos, r_um = B.make_particles(n, seed=seed, half=p["half"], r_min_um=lo, r_max_um=hi)
        keep = np.linalg.norm(pos, axis=1) > excl + r_um * 1e-4
        if keep.sum() >= count:
            idx = np.flatnonzero(keep)[:count]
            return pos[idx] + np.asarray(p["center"]), r_um[idx]
        n = int(n * 1.2) + 10


def geometry_summary(name: str, pos, r_um) -> dict:
    p = SCENES[name]
    r = r_um * 1e-4
    vol = (2 * p["half"]) ** 3
    return {"count": len(r), "volume_fraction": float((4 / 3 * np.pi * r**3).sum() / vol),
            "geometric_tau": float(np.pi * (r**2).sum() / vol * 2 * p["half"])}


# ------------------------------------------------------------------------------------------------ scenes
def _rgb(v) -> dict:
    return {"type": "rgb", "value": list(v) if isinstance(v, (tuple, list)) else float(v)}


def _diffuse(v) -> dict:
    return {"type": "diffuse", "reflectance": _rgb(v)}


def scene_dict(mi, name: str, *, res: int, particles=None, filename: str | None = None) -> dict:
    """The scene ``name`` (module docs) with the grains as EPT spheres (``particles`` = (pos_cm, r_um)) or
    as a ``discrete`` medium read from ``filename``; exactly one of the two."""
    if (particles is None) == (filename is None):
        raise ValueError("give particles (EPT) or filename (discrete), one of them")
    T = mi.ScalarTransform4f
    p = SCENES[name]
    lo, hi = p["r_um"]
    ept = particles is not None
    if name == "lamp":
        cam = T().look_at(origin=[0, 6, 28], target=[0, -1, 0], up=[0, 1, 0])
        fov = 35.0
    else:
        cam = T().look_at(origin=[0, 0, 20], target=[0, 0, 0], up=[0, 1, 0])
        fov = 38.0
    d = {
        "type": "scene",
        "integrator": {"type": "path" if ept else "volpath", "max_depth": MAX_DEPTH},
        "sensor": {"type": "perspective", "fov": fov, "to_world": cam,
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": 1}},
    }
    cloud_ref = None
    if not ept:
        d["cloud"] = {"type": "discrete", "id": "cloud", "filename": filename, "eta": p["eta"], "scale_m": SCALE_M,
                      "psd": f'{{"type": "uniform", "r_min_um": {lo}, "r_max_um": {hi}}}', "phase": {"type": "particle"}}
        cloud_ref = {"type": "ref", "id": "cloud"}
        w = p["half"] + MARGIN
        d["cube"] = {"type": "cube", "to_world": T().translate(list(p["center"])) @ T().scale(w),
                     "bsdf": {"type": "null"}, "interior": cloud_ref}
    else:
        pos, r_um = particles
        d["glass"] = {"type": "dielectric", "id": "glass", "int_ior": p["eta"], "ext_ior": 1.0}
        for i, (c, r) in enumerate(zip(pos, r_um * 1e-4)):
            d[f"grain{i:06d}"] = {"type": "sphere", "center": [float(x) for x in c], "radius": float(r),
                                  "bsdf": {"type": "ref", "id": "glass"}}
    if name == "lamp":
        y_floor = p["center"][1] - p["half"] - MARGIN - 0.01
        d["lamp"] = {"type": "sphere", "center": list(p["center"]), "radius": p["lamp_radius"],
                     "emitter": {"type": "area", "radiance": _rgb(p["lamp_radiance"])}, "bsdf": _diffuse(0.0)}
        if cloud_ref is not None:
            d["lamp"]["exterior"] = dict(cloud_ref)  # the lamp sits inside the medium's cube
        d["floor"] = {"type": "rectangle", "bsdf": _diffuse(0.5),
                      "to_world": T().translate([0, y_floor, 0]) @ T().rotate([1, 0, 0], -90) @ T().scale(20)}
    else:
        b = p["box"]
        wall = lambda tr, refl: {"type": "rectangle", "to_world": tr @ T().scale(b), "bsdf": _diffuse(refl)}  # noqa: E731
        d["floor"] = wall(T().translate([0, -b, 0]) @ T().rotate([1, 0, 0], -90), WHITE)
        d["ceiling"] = wall(T().translate([0, b, 0]) @ T().rotate([1, 0, 0], 90), WHITE)
        d["back"] = wall(T().translate([0, 0, -b]), WHITE)
        d["left"] = wall(T().translate([-b, 0, 0]) @ T().rotate([0, 1, 0], 90), RED)
        d["right"] = wall(T().translate([b, 0, 0]) @ T().rotate([0, 1, 0], -90), GREEN)
        d["light"] = {"type": "rectangle", "bsdf": _diffuse(0.0),
                      "to_world": T().translate([0, b - 0.01, 0]) @ T().rotate([1, 0, 0], 90) @ T().scale(p["light_half"]),
                      "emitter": {"type": "area", "radiance": _rgb(p["light_radiance"])}}
    return d


# ------------------------------------------------------------------------------------------- measurement
def render(mi, scene, spp: int, seed: int):
    """(image as float64 (h, w, 3), seconds): wall clock of ``mi.render`` and the conversion to numpy."""
    t0 = time.perf_counter()
    img = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    return img[..., :3], time.perf_counter() - t0


def blocks(img, k: int):
    """Means over k x k pixel blocks (k = 1: the image itself); the error at a coarser scale, where the
    exact placement of each grain's glint within a few pixels no longer counts."""
    if k <= 1:
        return img
    h, w = (img.shape[0] // k) * k, (img.shape[1] // k) * k
    return img[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def masked_mse(img, ref, mask, ds: int) -> float:
    """Mean over channels and over the (ds x ds blocks of) pixels that ``mask`` leaves in (no masked pixel
    in the block) of (img - ref)^2."""
    keep = blocks(mask[..., None].astype(float), ds)[..., 0] == 0
    return float(np.mean((blocks(img, ds) - blocks(ref, ds))[keep] ** 2))


def emitter_mask(mi, name: str, res: int):
    """Pixels in which any camera ray meets an emitter directly (without the grains: the lamp or light
    itself, occluded only by walls), from a render of the scene's emission alone (max_depth 1, 256 spp;
    the box filter keeps every sample in its own pixel)."""
    d = scene_dict(mi, name, res=res, particles=(np.zeros((0, 3)), np.zeros(0)))
    del d["glass"]
    d["integrator"] = {"type": "path", "max_depth": 1}
    img, _ = render(mi, mi.load_dict(d), 256, 3)
    gc.collect()
    return img.max(axis=-1) > 0


def fit_floor(spp, err):
    """Least squares of RMSE^2 = b^2 + c / spp, relative (weights 1 / RMSE^2): (b, c), b >= 0."""
    spp, e2 = np.asarray(spp, float), np.asarray(err, float) ** 2
    A = np.stack([np.ones_like(spp), 1.0 / spp], axis=1) / e2[:, None]
    (b2, c), *_ = np.linalg.lstsq(A, np.ones_like(spp), rcond=None)
    if b2 < 0:  # no visible floor: pure 1/spp
        b2, c = 0.0, float(np.sum(1.0 / spp / e2) / np.sum((1.0 / spp / e2) ** 2))
    return math.sqrt(b2), float(c)


def fit_time(spp, secs):
    """Least squares of seconds = t0 + a * spp (relative), t0, a >= 0: (t0, the fixed cost per render; a, seconds
    per spp)."""
    spp, secs = np.asarray(spp, float), np.asarray(secs, float)
    A = np.stack([np.ones_like(spp), spp], axis=1) / secs[:, None]
    (t0, a), *_ = np.linalg.lstsq(A, np.ones_like(spp), rcond=None)
    if a < 0:  # no visible cost per sample (timing noise): constant
        t0, a = float(np.sum(1 / secs) / np.sum(1 / secs**2)), 0.0
    elif t0 < 0:  # no visible fixed cost: proportional
        t0, a = 0.0, float(np.sum(spp / secs) / np.sum((spp / secs) ** 2))
    return float(t0), float(a)


def interp_time(spp, secs, err, target: float):
    """(seconds, note) where the measured RMSE first falls to ``target``, log-log between the two measured
    points that bracket it: note "" ; "<=" when the first point (1 spp) is already below it (its time);
    (None, "not reached") when no measured point is."""
    spp, secs, err = (np.asarray(a, float) for a in (spp, secs, err))
    if err[0] <= target:
        return float(secs[0]), "<="
    for i in range(len(err) - 1):
        if err[i] >= target >= err[i + 1]:
            if err[i] == err[i + 1]:
                return float(secs[i]), ""
            f = (math.log(target) - math.log(err[i])) / (math.log(err[i + 1]) - math.log(err[i]))
            return float(math.exp(math.log(secs[i]) + f * (math.log(secs[i + 1]) - math.log(secs[i])))), ""
    return None, "not reached"


def fit_time_to_error(target: float, err_fit, time_fit):
    """From the fits: spp* = c / (target^2 - b^2) (at least 1), (spp*, t0 + a spp*, a spp*); Nones when the
    target is at or below the floor b."""
    (b, c), (t0, a) = err_fit, time_fit
    if target <= b * 1.0001:
        return None, None, None
    n = max(c / (target**2 - b**2), 1.0)
    return float(n), float(t0 + a * n), float(a * n)


def ratio(x, y):
    return x / y if x and y else None


def reference(mi, name: str, scene, out: pathlib.Path, key: str, spp: int):
    """The two EPT reference halves (2, h, w, 3), cached as .npy, and the seconds spent (0 if cached)."""
    path = out / f"ref_{name}_{key}.npy"
    if path.exists():
        print(f"[{name}] reference from {path}", flush=True)
        return np.load(path), 0.0
    t0 = time.perf_counter()
    halves = np.stack([render(mi, scene, spp, s)[0] for s in REF_SEEDS])
    np.save(path, halves)
    dt = time.perf_counter() - t0
    print(f"[{name}] reference: EPT 2 x {spp} spp in {dt:.0f} s -> {path}", flush=True)
    return halves, dt


def run_scene(mi, name: str, args, out: pathlib.Path, spps: list[int], level_spps) -> dict:
    """One scene (module docs): the grains, the reference and the sweep of both methods, the fits, the targets."""
    p = SCENES[name]
    count = args.count or (p["quick_count"] if args.quick else p["count"])
    t = time.perf_counter()
    pos, r_um = make_scene_particles(name, count, args.seed)
    geo = geometry_summary(name, pos, r_um)
    print(f"[{name}] {count} grains placed in {time.perf_counter() - t:.1f} s: volume fraction "
          f"{geo['volume_fraction']:.3%}, geometric optical depth across the box {geo['geometric_tau']:.3f}", flush=True)
    res, ref_spp, ds = args.res, args.ref_spp, args.downsample
    key = f"v{SCENE_VERSION}_n{count}_s{args.seed}_r{res}_spp{ref_spp}x2_d{MAX_DEPTH}"
    rows, load, last, ref, ref_noise, ref_s, mask = sweep(mi, name, pos, r_um, out, key, res, ref_spp, ds, spps)
    gc.collect()

    fits = {m: fit_floor([r[0] for r in rows[m]], [r[2] for r in rows[m]]) for m in rows}
    timing = {m: fit_time([r[0] for r in rows[m]], [r[1] for r in rows[m]]) for m in rows}
    b_disc = fits["discrete"][0]
    targets = target_times(rows, fits, timing, b_disc, spps, level_spps)
    below, problems = floor_problems(rows, b_disc)
    return {"name": name, "title": p["title"], "count": count, "geometry": geo, "res": res, "downsample": ds,
            "ref_spp": 2 * ref_spp, "ref_seconds": ref_s, "ref_mean": float(ref[~mask].mean()),
            "masked_fraction": float(mask.mean()), "ref_noise_rmse": ref_noise,
            "load_s": {m: float(np.median(v)) for m, v in load.items()}, "timing": timing,
            "rows": rows, "fits": fits, "bias": math.sqrt(max(b_disc**2 - ref_noise**2, 0.0)),
            "targets": targets, "problems": problems,
            "ept_below_floor_from": (below[0][0], below[0][1]) if below else None, "images": {"reference": ref, **last}, "mask": mask}


def sweep(mi, name: str, pos, r_um, out: pathlib.Path, key: str, res: int, ref_spp: int, ds: int, spps: list[int]):
    """Warm-up, reference and the interleaved renders of both methods at every spp: (rows per method (spp,
    seconds, RMSE, renders), scene load times, last image per method, reference, its own noise (RMSE),
    seconds spent on it, emitter mask)."""
    import bench_ept as B  # noqa: PLC0415

    methods = ("EPT", "discrete")
    rows = {m: [] for m in methods}
    load = {m: [] for m in methods}
    last = {}
    with tempfile.TemporaryDirectory() as tmp:
        fname = B.save_particle_file(pathlib.Path(tmp) / "grains.npz", pos, r_um)
        dicts = {"EPT": lambda: scene_dict(mi, name, res=res, particles=(pos, r_um)),
                 "discrete": lambda: scene_dict(mi, name, res=res, filename=fname)}

        def loaded(m):
            # One scene alive at a time: Mitsuba's symbolic calls trace every live instance of a class (the
            # other scene's thousands of spheres would enter this scene's kernels). Reloading the same scene
            # hits the kernel cache.
            gc.collect()
            t = time.perf_counter()
            sc = mi.load_dict(dicts[m]())
            load[m].append(time.perf_counter() - t)
            return sc

        mask = emitter_mask(mi, name, res)
        for m in methods:  # warm-up: compile (and cache) the kernels
            sc = loaded(m)
            _, dt = render(mi, sc, 1, WARMUP_SEED)
            print(f"[{name}] {m}: scene loaded in {load[m][-1]:.1f} s, warm-up render (compiling) {dt:.1f} s", flush=True)
            if m == "EPT":
                halves, ref_s = reference(mi, name, sc, out, key, ref_spp)
            del sc
        ref = halves.mean(axis=0)
        ref_noise = math.sqrt(masked_mse(halves[0], halves[1], mask, ds)) / 2  # RMSE of the mean of the halves

        for k, spp in enumerate(spps):
            reps = int(np.clip(spps[-1] // (16 * spp), 1, 8))  # several renders where they are cheap and noisy
            for m in methods if k % 2 == 0 else methods[::-1]:  # interleaved, alternating who goes first
                sc = loaded(m)
                secs, mse = [], []
                for j in range(reps):
                    img, dt = render(mi, sc, spp, 1000 + 97 * k + j)
                    secs.append(dt)
                    mse.append(masked_mse(img, ref, mask, ds))
                del sc
                rows[m].append((spp, float(np.mean(secs)), float(np.sqrt(np.mean(mse))), reps))
                last[m] = img
            print(f"[{name}] spp {spp} (x{reps}): " + ", ".join(
                f"{m} {rows[m][-1][1]:.3g} s RMSE {rows[m][-1][2]:.4g}" for m in methods), flush=True)
    return rows, load, last, ref, ref_noise, ref_s, mask


def target_times(rows: dict, fits: dict, timing: dict, b_disc: float, spps: list[int], level_spps) -> list[dict]:
    """The target RMSE levels (module docs) and each method's time to reach them, measured and fitted."""
    targets = []
    for level_spp in sorted({min(s, spps[-1]) for s in level_spps}):
        (b, c) = fits["EPT"]
        level, src = math.sqrt(b * b + c / level_spp), f"EPT at {level_spp} spp"
        if level < FLOOR_FACTOR * b_disc:
            level, src = FLOOR_FACTOR * b_disc, f"{FLOOR_FACTOR} x discrete floor"
        if any(abs(t["level"] - level) <= 1e-9 * level for t in targets):
            continue
        tt = {}
        for m in rows:
            t_int, note = interp_time(*list(zip(*rows[m]))[:3], level)
            n_fit, t_fit, t_samp = fit_time_to_error(level, fits[m], timing[m])
            tt[m] = {"interp_s": t_int, "interp_note": note, "fit_spp": n_fit, "fit_s": t_fit, "fit_sampling_s": t_samp}
        targets.append({"level": level, "from": src, "tte": tt,
                        "ratio_interp": ratio(tt["EPT"]["interp_s"], tt["discrete"]["interp_s"]),
                        "ratio_fit": ratio(tt["EPT"]["fit_s"], tt["discrete"]["fit_s"]),
                        "ratio_sampling": ratio(tt["EPT"]["fit_sampling_s"], tt["discrete"]["fit_sampling_s"])})
    return targets


def floor_problems(rows: dict, b_disc: float):
    """(EPT's rows below the discrete floor, notes where that floor or EPT's error leaves no meaningful target)."""
    below = [r for r in rows["EPT"] if r[2] < b_disc]  # where EPT is already better than the discrete medium can be
    problems = []
    if len(below) == len(rows["EPT"]):
        problems.append("the discrete medium's floor is above EPT's RMSE at every spp measured (from 1)")
    if all(r[2] < FLOOR_FACTOR * b_disc for r in rows["EPT"]):
        problems.append(f"EPT's RMSE is below {FLOOR_FACTOR} x the discrete floor at every spp measured (from 1): "
                        "the targets are set by the discrete floor")
    if min(r[2] for r in rows["discrete"]) > max(r[2] for r in rows["EPT"]):
        problems.append("the discrete medium's RMSE is above EPT's at every spp measured")
    return below, problems


# ------------------------------------------------------------------------------------------------ output
def plot(results: list[dict], out: pathlib.Path) -> None:
    plt = C.plt()
    fig, axes = plt.subplots(1, len(results), figsize=(4.8 * len(results), 4.0), squeeze=False)
    colors = {"EPT": "tab:blue", "discrete": "tab:red"}
    for ax, r in zip(axes[0], results):
        for m, rows in r["rows"].items():
            spp, secs, err = (np.array(a) for a in list(zip(*rows))[:3])
            ax.loglog(secs, err, "o-", color=colors[m], ms=3.5, label=f"{m}, spp {spp[0]}-{spp[-1]}")
            for s_, t_, e_ in zip(spp, secs, err):
                if s_ in (spp[0], spp[-1]) or s_ in (16, 256):
                    ax.annotate(str(s_), (t_, e_), fontsize=6, color=colors[m], xytext=(2, 2), textcoords="offset points")
        for i, tg in enumerate(r["targets"]):
            ax.axhline(tg["level"], color="0.35", ls="--", lw=0.7, label="target RMSE" if i == 0 else None)
            for m in r["rows"]:
                t = tg["tte"][m]["interp_s"]
                if t is not None:
                    ax.plot([t], [tg["level"]], "*", color=colors[m], ms=10, mec="k", mew=0.5)
        ax.axhline(r["fits"]["discrete"][0], color=colors["discrete"], ls=":", lw=0.9, label="discrete floor (fit)")
        ax.axhline(r["ref_noise_rmse"], color=colors["EPT"], ls=":", lw=0.9, label="reference's own noise")
        C.label(ax, "wall-clock render time (s)", "RMSE against EPT reference",
                f"{r['title']}: {r['count']} grains, {r['res']}x{r['res']} px"
                + (f" (RMSE over {r['downsample']}x{r['downsample']} blocks)" if r["downsample"] > 1 else "")
                + f", reference {r['ref_spp']} spp", legend=7)
        ax.title.set_fontsize(8)
        ax.xaxis.set_minor_formatter(plt.NullFormatter())
    C.save_fig(fig, out / "ept_time_to_error.png")

    fig, axes = plt.subplots(len(results), 3, figsize=(7.5, 2.7 * len(results)), squeeze=False)
    for row, r in zip(axes, results):
        imgs = r["images"]
        scale = np.percentile(imgs["reference"][~r["mask"]], 99.5) or 1.0  # the lamps saturate
        for ax, (label, key) in zip(row, [("EPT reference", "reference"), ("EPT", "EPT"), ("discrete", "discrete")]):
            spp = f", {r['ref_spp']} spp" if key == "reference" else f", {r['rows'][key][-1][0]} spp"
            ax.imshow(np.clip(imgs[key] / scale, 0, 1) ** (1 / 2.2))
            ax.set_title(f"{r['title']}: {label}{spp}", fontsize=8)
            ax.axis("off")
    C.save_fig(fig, out / "ept_time_to_error_images.png")


def _s(t, note: str = "") -> str:
    if t is None:
        return note or "—"
    return ("≤ " if note == "<=" else "") + f"{t:.3g}"


def bound(note_ept: str, note_disc: str, value) -> str:
    """The ratio EPT / discrete of two times, either of which may be an upper bound ("<=")."""
    if value is None:
        return "—"
    mark = {(False, True): "≥ ", (True, False): "≤ ", (True, True): "~ "}.get((note_ept == "<=", note_disc == "<="), "")
    return mark + f"{value:.3g}"


def report(results: list[dict]) -> None:
    rows = []
    for r in results:
        for m in r["rows"]:
            for spp, secs, err, reps in r["rows"][m]:
                rows.append([r["title"], m, spp, f"{secs:.3g}", f"{err:.4g}", reps])
    C.print_table("each spp: wall-clock seconds per render (kernels compiled beforehand) and RMSE against the EPT "
                  "reference (root of the mean squared error over `renders` independent renders)",
                  ["scene", "method", "spp", "seconds", "RMSE", "renders"], rows)
    rows = [[r["title"], r["count"], f"{r['geometry']['geometric_tau']:.3g}", f"{r['masked_fraction']:.1%}",
             f"{r['ref_mean']:.4g}",
             f"{r['ref_noise_rmse']:.3g}", f"{r['fits']['EPT'][0]:.3g}", f"{r['fits']['discrete'][0]:.3g}",
             f"{r['bias']:.3g}", "not reached" if r["ept_below_floor_from"] is None else
             "%d spp (%.3g s)" % r["ept_below_floor_from"], f"{r['timing']['EPT'][0]:.3g} + {r['timing']['EPT'][1] * 1e3:.3g} ms x spp",
             f"{r['timing']['discrete'][0]:.3g} + {r['timing']['discrete'][1] * 1e3:.3g} ms x spp",
             f"{r['load_s']['EPT']:.2g} / {r['load_s']['discrete']:.2g}"] for r in results]
    C.print_table("per scene: reference, error floors (fit RMSE^2 = b^2 + c/spp), render time model (fit t0 + a spp)",
                  ["scene", "grains", "geometric tau", "emitter px left out", "ref. mean (rest)", "ref. noise RMSE", "EPT floor b", "discrete floor b",
                   "discrete bias", "EPT below discrete floor from", "EPT s per render", "discrete s per render", "load s EPT / discrete"], rows)
    rows = []
    for r in results:
        for tg in r["targets"]:
            e, d = tg["tte"]["EPT"], tg["tte"]["discrete"]
            f = lambda x: "—" if x is None else f"{x:.3g}"  # noqa: E731
            rows.append([r["title"], f"{tg['level']:.3g} ({tg['from']})",
                         _s(e["interp_s"], e["interp_note"]), _s(d["interp_s"], d["interp_note"]),
                         bound(e["interp_note"], d["interp_note"], tg["ratio_interp"]),
                         f"{f(e['fit_s'])} / {f(d['fit_s'])}", f(tg["ratio_fit"]),
                         f"{f(e['fit_spp'])} / {f(d['fit_spp'])}", f(tg["ratio_sampling"])])
    C.print_table("time to equal RMSE (seconds; EPT / discrete > 1: the discrete medium gets there faster). "
                  "Measured: log-log between measured points; fit: from both fits; sampling only: without the "
                  "fixed cost t0 per render",
                  ["scene", "target RMSE", "EPT s", "discrete s", "EPT / discrete", "fit s EPT / discrete",
                   "EPT / discrete (fit)", "spp EPT / discrete (fit)", "EPT / discrete (sampling only)"], rows)
    for r in results:
        for msg in r["problems"]:
            print(f"NOTE {r['title']}: {msg}")


def main() -> None:
    ap = C.parser(__doc__)
    ap.set_defaults(out=str(C.ROOT / "scripts" / "out" / "ept_time_to_error"))
    ap.add_argument("--res", type=int, help="image width = height (default 80; --quick 48)")
    ap.add_argument("--ref-spp", type=int, help="reference spp per half (default 4096; --quick 512)")
    ap.add_argument("--max-spp", type=int, help="highest spp of the sweep, a power of 2 (default 1024; --quick 64)")
    ap.add_argument("--count", type=int, help="grains per scene (default LAMP 4000, CORNELL 3000; --quick 300)")
    ap.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated, of {list(SCENES)}")
    ap.add_argument("--seed", type=int, default=1, help="particle seed")
    ap.add_argument("--downsample", type=int, default=1, help="RMSE over means of N x N pixel blocks (default 1: pixels)")
    args = ap.parse_args()
    sw, motes = C.Stopwatch(), C.import_motes()
    out = C.out_dir(args.out)
    args.res = args.res or (48 if args.quick else 80)
    args.ref_spp = args.ref_spp or (512 if args.quick else 4096)
    max_spp = args.max_spp or (64 if args.quick else 1024)
    spps = [2**k for k in range(int(math.log2(max_spp)) + 1)]
    names = C.choose_configs(ap, args.scenes, SCENES)
    variant = motes.set_variant("llvm_ad_rgb")
    import mitsuba as mi

    if variant not in motes.native_variants():
        sys.exit(f"the discrete medium's native render path is unavailable in {variant}: this timing comparison "
                 "needs it (the evaluated-mode Python path is a different, much slower implementation)")
    motes.set_evaluated_mode(False)  # EPT and the native medium both run in Mitsuba's symbolic mode
    levels = (MID_SPP["quick" if args.quick else "full"], max_spp // 4)
    results = [run_scene(mi, n, args, out, spps, levels) for n in names]
    report(results)
    plot(results, out)
    C.write_json(out / "ept_time_to_error.json", {
        "meta": C.meta(args, sw()), "spps": spps, "max_depth": MAX_DEPTH, "scenes": SCENES,
        "results": [{k: v for k, v in r.items() if k not in ("images", "mask")} for r in results]})
    print(f"runtime {sw():.1f} s")


if __name__ == "__main__":
    main()
