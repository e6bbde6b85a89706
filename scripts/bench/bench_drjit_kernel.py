"""Issue 46: ``kernel = "drjit"`` (``mitsuba_plugin/motes/plugins/drjit_medium.py``) against the native kernel
on the shipped scenes (``scenes_xml/*.xml``) in ``llvm_ad_rgb`` (or ``--variant``), side by side in one process.

Per scene four configurations of its discrete medium: ``drjit`` (the drjit kernel at the scene's defaults: the
size classes no pixel resolves as their field), ``drjit-exact`` (continuous_count = inf; rendered only where the
scene's defaults leave continuous classes, else it is ``drjit``), ``native-exact`` (continuous_count = inf) and
``native`` (the scene's defaults); ``native-null`` (only when asked with ``--configs``) is ``native-exact`` again
with its own seeds, a null test: its z and RMS/noise show how far the statistics stray where nothing differs
(heavy-tailed pixels make the noise estimate low). Each renders ``--seeds`` times
at ``--res`` px and ``--spp`` spp after one warm-up render (the kernels compile there); the configurations
take turns seed by seed, so that a busy machine slows them alike. Seeds differ between configurations
(independent noise). Printed per configuration: the image mean, its z against ``native-exact`` (difference
of the means over the renders' spread), the per-pixel RMS difference of the mean images over their noise
(about 1 where they differ by noise alone; estimated from the seeds' spread), and seconds per render with
the ratio to ``native-exact``, wall-clock and the process's CPU time (steadier where other work shares the
machine: a render waiting for a core spends none; medians over the seeds); then z and RMS/noise of ``drjit``
against ``native`` (the same settings) and against ``drjit-exact``. ``-D KEY=VALUE`` sets a scene
parameter, e.g. ``-D storage=procedural`` (cornell, house, lamp, limit: the drjit kernel then regenerates the
grains, ``motes.drjit_procedural``). ``sidelit`` (not a shipped scene) is ``bench_lod.py``'s side-lit cloud of 300
grains of 200-450 um that touch the faces of their cube (``--max-depth``, 16); ``mixed`` (not shipped either) a
procedural cloud whose small grains are continuous and large ones discrete (``-D count=5000 -D storage=procedural``;
``mixed``'s docs); ``--exclusion ball`` renders the
drjit kernel with every ray skipping the grains whose ball holds its origin (``drjit_medium.EXCLUSION``, against
its origin tag, ``origin``). A scene whose ``cells`` parameter sets ``cells_per_particle`` (``bench``: 0.125, the native
kernel's default) renders the drjit configuration at the drjit kernel's own default
(``drjit_medium.DRJIT_CELLS_PER_PARTICLE``: its walk tests every grain of a cell it passes near, so coarse cells
cost it more), unless ``--drjit-cells scene``; a number sets it.

    .venv/bin/python scripts/bench/bench_drjit_kernel.py [--scenes dust_box,cornell,sidelit] [--res 32] [--spp 16]
        [--seeds 4] [--first-seed 0] [--configs drjit,drjit-exact,native-exact,native,native-null]
        [--exclusion origin|ball]
        [--max-depth 16] [--drjit-cells kernel|scene|<number>]
        [--variant llvm_ad_rgb|llvm_ad_spectral|llvm_ad_mono] [-D storage=procedural]
"""

from __future__ import annotations

import argparse
import pathlib
import re
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONFIGS = {"drjit": {"kernel": "drjit"}, "drjit-exact": {"kernel": "drjit", "continuous_count": "inf"},
           "native-exact": {"continuous_count": "inf"}, "native": {},
           "native-null": {"continuous_count": "inf"}}
REFERENCE = "native-exact"
#: Pairs compared after the table: the same settings on both kernels, and drjit's field against its exact walk.
PAIRS = (("drjit", "native"), ("drjit", "drjit-exact"))


#: ``--drjit-cells``: the ``cells`` parameter the drjit configuration loads scenes that declare one with (None:
#: the scene's).
DRJIT_CELLS: list = [None]


def load(mi, name: str, res: int, extra: dict, defines: dict | None = None):
    """Scene ``name`` at ``res`` px with ``extra`` set on its discrete media (added after the tag) and the scene's
    parameters ``defines`` (``-D``)."""
    if name == "sidelit":
        import sys  # noqa: PLC0415

        sys.path.insert(0, str(ROOT / "scripts" / "bench"))
        sys.path.insert(0, str(ROOT / "scripts"))
        import bench_lod  # noqa: PLC0415

        return mi.load_dict(bench_lod.sidelit(mi, res, 0.0, {k: float(v) if k != "kernel" else v
                                                            for k, v in extra.items()}))
    if name == "mixed":
        return mi.load_dict(mixed(mi, res, extra, defines or {}))
    text = (ROOT / "scenes_xml" / f"{name}.xml").read_text()
    tags = "".join(f'<{"string" if k == "kernel" else "float"} name="{k}" value="{v}"/>' for k, v in extra.items())
    text = re.sub(r'(<medium type="discrete"[^>]*>)', lambda m: m.group(1) + tags, text)
    params = {"res": res, **(defines or {})}
    if extra.get("kernel") == "drjit" and DRJIT_CELLS[0] is not None and '<default name="cells"' in text:
        params["cells"] = DRJIT_CELLS[0]
    return mi.load_string(text, **params)


#: ``mixed``'s grains (``tests/test_drjit_medium.py``'s MIXED_SPECIES, more large ones): small ones continuous at
#: ``continuous_count`` = 1 and a few large ones discrete, at 1 mm a unit.
MIXED_SPECIES = ('[{"psd": {"type": "uniform", "r_min_um": 15, "r_max_um": 25}, "eta": [1.33, 0], "share": 0.99},'
                 ' {"psd": {"type": "uniform", "r_min_um": 60, "r_max_um": 90}, "eta": [1.5, 0], "share": 0.01}]')


def mixed(mi, res: int, extra: dict, defines: dict) -> dict:
    """``mixed``: a cloud whose small grains are continuous and large ones discrete (``continuous_count`` 1,
    ``-D count=...``, 5000; ``-D storage=...``, procedural; ``-D turbulence=... -D time=...``, a drift that moves the
    grains while the field stays at rest) in the cube [-1, 1]^3, lit by a point light to its left under a dim sky.
    Rays never switch to the grains' equivalent (``grain_depth`` at its maximum, no surface footprint), so native
    and drjit render the same model."""
    from motes.plugins.discrete_medium import MAX_GRAIN_DEPTH  # noqa: PLC0415

    T = mi.ScalarTransform4f
    medium = {"type": "discrete", "count": int(float(defines.get("count", 5000))), "species": MIXED_SPECIES,
              "scale_m": 1e-3, "query_radius": 0.02, "continuous_count": 1.0, "size_bins": 2,
              "storage": defines.get("storage", "procedural"), "grain_depth": MAX_GRAIN_DEPTH,
              "surface_footprint": False, "phase": {"type": "particle"}}
    medium.update({k: float(defines[k]) for k in ("turbulence", "time") if k in defines})  # a drift
    medium.update({k: v if k == "kernel" else float(v) for k, v in extra.items()})
    return {"type": "scene", "integrator": {"type": "volpath", "max_depth": 16},
            "sensor": {"type": "perspective", "fov": 30,
                       "to_world": T().look_at(origin=[0, 0, 6], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent"}},
            "lamp": {"type": "point", "position": [-2.2, 0.0, 0.0], "intensity": {"type": "rgb", "value": 4.0}},
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.1}},
            "cloud": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium}}


def compare(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(z of the mean of ``a`` against ``b``, per-pixel RMS difference of their mean images over the noise)."""
    ma, mb = a.mean(axis=(1, 2, 3)), b.mean(axis=(1, 2, 3))
    se = np.hypot(ma.std(ddof=1), mb.std(ddof=1)) / np.sqrt(len(ma))
    noise = a.var(axis=0, ddof=1) / a.shape[0] + b.var(axis=0, ddof=1) / b.shape[0]
    return float((ma.mean() - mb.mean()) / se), float(np.sqrt(np.mean((a.mean(0) - b.mean(0)) ** 2) / np.mean(noise)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(sorted(p.stem for p in (ROOT / "scenes_xml").glob("*.xml"))))
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--first-seed", type=int, default=0, help="the first seed of each configuration's run")
    ap.add_argument("--configs", default=",".join(c for c in CONFIGS if c != "native-null"),
                    help=f"the configurations rendered, of {','.join(CONFIGS)} ({REFERENCE} always)")
    ap.add_argument("--exclusion", choices=("origin", "ball"), default="origin")
    ap.add_argument("--max-depth", type=int, default=16, help="the side-lit cloud's integrator depth")
    ap.add_argument("--drjit-cells", default="kernel",
                    help="cells_per_particle of the drjit configuration where a scene's cells parameter sets it: "
                         "kernel (the drjit kernel's default), scene, or a number")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene parameter, e.g. -D storage=procedural (cornell, house, lamp, limit)")
    ap.add_argument("--variant", choices=("llvm_ad_rgb", "llvm_ad_spectral", "llvm_ad_mono"), default="llvm_ad_rgb")
    args = ap.parse_args()
    defines = dict(d.split("=", 1) for d in args.defines)
    import motes  # noqa: PLC0415

    motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415

    from motes.plugins import drjit_medium  # noqa: PLC0415

    drjit_medium.EXCLUSION = args.exclusion
    DRJIT_CELLS[0] = {"kernel": drjit_medium.DRJIT_CELLS_PER_PARTICLE, "scene": None}.get(args.drjit_cells,
                                                                                        args.drjit_cells)

    print(f"{args.variant}, {args.res} px, {args.spp} spp, {args.seeds} seeds, exclusion {args.exclusion}; z and RMS/noise "
          f"against {REFERENCE}; drjit's cells where a scene sets them: {DRJIT_CELLS[0] or 'the scene'}")
    print(f"{'scene':10s} {'config':13s} {'mean':>10s} {'z':>6s} {'RMS/noise':>9s} {'s/render':>9s} {'ratio':>6s} "
          f"{'cpu s':>8s} {'cpu ratio':>9s}")
    for name in args.scenes.split(","):
        if name == "sidelit":
            import sys  # noqa: PLC0415

            sys.path.insert(0, str(ROOT / "scripts" / "bench"))
            sys.path.insert(0, str(ROOT / "scripts"))
            import bench_lod  # noqa: PLC0415

            bench_lod.MAX_DEPTH[0] = args.max_depth
        wanted = set(args.configs.split(",")) | {REFERENCE}
        scenes = {c: load(mi, name, args.res, extra, defines) for c, extra in CONFIGS.items() if c in wanted}
        if "drjit-exact" in scenes and "drjit" in scenes and not any(
                getattr(getattr(sh.interior_medium(), "data", None), "continuous_particles", 0)
                for sh in scenes["drjit"].shapes() if sh.interior_medium() is not None):
            del scenes["drjit-exact"]  # no continuous class: the same medium as drjit
        imgs: dict = {c: [] for c in scenes}
        secs: dict = {c: [] for c in scenes}
        cpu: dict = {c: [] for c in scenes}
        for c, sc in scenes.items():
            mi.render(sc, spp=args.spp, seed=999)  # warm-up: the kernels compile
        for s in range(args.seeds):
            for c, sc in scenes.items():
                i = list(CONFIGS).index(c)  # a configuration's seeds whichever others are rendered
                t0, c0 = time.perf_counter(), time.process_time()
                img = np.asarray(mi.render(sc, spp=args.spp, seed=1000 * i + args.first_seed + s), dtype=np.float64)
                secs[c].append(time.perf_counter() - t0)
                cpu[c].append(time.process_time() - c0)
                imgs[c].append(img)
        ref = np.stack(imgs[REFERENCE])
        t_ref, cpu_ref = float(np.median(secs[REFERENCE])), float(np.median(cpu[REFERENCE]))
        for c in scenes:
            a = np.stack(imgs[c])
            z, rms = compare(a, ref) if c != REFERENCE else (0.0, 0.0)
            t, tc = float(np.median(secs[c])), float(np.median(cpu[c]))
            print(f"{name:10s} {c:13s} {a.mean():10.5g} {z:6.2f} {rms:9.2f} {t:9.3f} {t / t_ref:6.2f} {tc:8.3f} "
                  f"{tc / cpu_ref:9.2f}", flush=True)
        # The same model by both kernels, and the field against every grain walked: z and RMS/noise per pair.
        for c, ref_c in PAIRS:
            if c in imgs and ref_c in imgs:
                z, rms = compare(np.stack(imgs[c]), np.stack(imgs[ref_c]))
                print(f"{name:10s} {c + ' vs ' + ref_c:27s} z {z:6.2f} RMS/noise {rms:5.2f}", flush=True)


if __name__ == "__main__":
    main()
