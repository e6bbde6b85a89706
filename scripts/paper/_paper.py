"""Shared helpers of the gallery scripts in ``scripts/paper/`` (issue 26): render a shipped scene with
scene parameters, measure what the paper claims about it, and lay the renders out as a labelled
contact sheet under ``docs/gallery/``.

Not a script. Conventions:

* Scenes are the shipped ones (``motes scenes``), loaded with ``mi.load_file(path, **params)``; every
  render is timed on its own (load and render separately) after the scene is built.
* A sheet's panels share ONE exposure (the log-average and white point of a reference panel), so that
  "brighter" and "dimmer" between panels mean what they say.
* Standard errors of image means come from the difference of two renders over 4x4-pixel blocks (the
  reconstruction filter correlates neighbouring pixels' noise).
* Graininess and convergence are measured free of Monte Carlo noise: each configuration is rendered
  twice with different sampler seeds on the same grains (A, B); the covariance over pixels of A and B
  estimates the variance of the noise-free image (the grains' texture plus the scene's own structure),
  and (A - B) / 2 gives the noise of their mean.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import resource
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
GALLERY = ROOT / "docs" / "gallery"
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def parser(doc: str, spp: int, res: int, full_spp: int, full_res: int) -> argparse.ArgumentParser:
    """The common flags: preview quality by default, ``--full`` for the paper's quality."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=doc)
    ap.add_argument("--full", action="store_true", help=f"full quality ({full_spp} spp, {full_res} px) instead of "
                                                        f"the preview ({spp} spp, {res} px)")
    ap.add_argument("--spp", type=int, help="samples per pixel (overrides the quality's)")
    ap.add_argument("--res", type=int, help="image width and height in pixels (overrides the quality's)")
    ap.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (llvm_ad_rgb)")
    ap.add_argument("--out", default=str(GALLERY), help="folder of the sheet and its numbers (docs/gallery)")
    ap.set_defaults(preview=(spp, res), full_quality=(full_spp, full_res))
    return ap


def quality(args) -> tuple[int, int]:
    spp, res = args.full_quality if args.full else args.preview
    return args.spp or spp, args.res or res


def ept_start(doc: str, spp: int, res: int, full_spp: int, full_res: int):
    """The start of a script that sets explicit path tracing (EPT) beside motes: the common flags plus
    ``--no-ept``, in scalar_rgb by default (EPT's spheres are slow in LLVM, where each is its own shape).
    Returns (parsed arguments, spp, res, ``mitsuba`` in the chosen variant)."""
    ap = parser(doc, spp=spp, res=res, full_spp=full_spp, full_res=full_res)
    ap.add_argument("--no-ept", action="store_true", help="skip explicit path tracing")
    ap.set_defaults(variant="scalar_rgb")
    args = ap.parse_args()
    spp, res = quality(args)
    return args, spp, res, setup(args.variant)


def setup(variant: str):
    sys.path.insert(0, str(ROOT / "mitsuba_plugin"))
    import motes  # noqa: PLC0415

    motes.set_variant(variant)
    import mitsuba as mi  # noqa: PLC0415

    return mi


def scene_file(name: str) -> pathlib.Path:
    from motes.cli import shipped_scenes  # noqa: PLC0415

    return shipped_scenes()[name]


def render_seeds(mi, scene, spp: int, seeds) -> tuple[list, list]:
    """Render ``scene`` once per sampler seed: (RGB images as float64 arrays, seconds per render)."""
    imgs, times = [], []
    for s in seeds:
        t1 = time.perf_counter()
        imgs.append(np.asarray(mi.render(scene, spp=spp, seed=int(s)), dtype=np.float64)[..., :3])
        times.append(time.perf_counter() - t1)
    return imgs, times


def render(mi, name: str, spp: int, res: int, seeds=(0,), measure=None, **params):
    """Render shipped scene ``name`` with scene parameters ``params`` once per sampler seed in ``seeds``.
    Returns (images as float64 arrays, load seconds, render seconds per image), and ``measure(scene)``
    as a fourth item when ``measure`` is given."""
    t0 = time.perf_counter()
    scene = mi.load_file(str(scene_file(name)), spp=str(spp), res=str(res), **{k: str(v) for k, v in params.items()})
    t_load = time.perf_counter() - t0
    imgs, times = render_seeds(mi, scene, spp, seeds)
    if measure is not None:
        return imgs, t_load, times, measure(scene)
    del scene
    return imgs, t_load, times


def luminance(img: np.ndarray) -> np.ndarray:
    return np.asarray(img)[..., :3] @ _LUMINANCE


#: Pixels per side of the blocks the standard error is estimated over: the scenes' Gaussian
#: reconstruction filter (radius 2 px) correlates the noise of neighbouring pixels, which makes a per-pixel
#: variance understate the error of the mean (about 1.8x); 4x4 blocks are nearly independent.
SE_BLOCK = 4


def _blocks(x: np.ndarray, k: int = SE_BLOCK) -> np.ndarray:
    h, w = (x.shape[0] // k) * k, (x.shape[1] // k) * k
    return x[:h, :w].reshape(h // k, k, w // k, k).mean(axis=(1, 3))


def mean_and_se(a: np.ndarray, b: np.ndarray, region=np.s_[...]) -> tuple[float, float]:
    """Mean luminance of (A + B) / 2 over ``region`` and its Monte Carlo standard error (from A - B, over
    blocks of ``SE_BLOCK``² pixels, whose noise is nearly independent)."""
    la, lb = luminance(a)[region], luminance(b)[region]
    m = 0.5 * (la + lb)
    d = _blocks(la - lb) if la.ndim == 2 and min(la.shape) >= 2 * SE_BLOCK else la - lb
    se = float(np.sqrt(np.var(d) / (4 * d.size)))
    return float(m.mean()), se


def texture_variance(a: np.ndarray, b: np.ndarray, region=np.s_[...]) -> float:
    """Variance over pixels of the noise-free luminance image (covariance of two independent renders)."""
    la, lb = luminance(a)[region].ravel(), luminance(b)[region].ravel()
    return float(np.mean((la - la.mean()) * (lb - lb.mean())))


def graininess(a: np.ndarray, b: np.ndarray, region=np.s_[...]) -> float:
    """Relative texture: sqrt(texture variance) / mean, the grains' contrast at equal mean."""
    m = 0.5 * (luminance(a)[region].mean() + luminance(b)[region].mean())
    return float(np.sqrt(max(texture_variance(a, b, region), 0.0)) / max(m, 1e-300))


def pixel_optical_depth(mi, scene, box, rows=None) -> tuple[np.ndarray, np.ndarray]:
    """Optical depth of the scene's discrete medium along the camera ray of each pixel centre (rows
    ``rows``, a slice, of the image), as the renderer's free flights see it: each pixel's query cylinder
    (Eq. 18) through the grains, plus the continuous classes' expected extinction; no Monte Carlo noise.
    Also each ray's length inside ``box`` = (lo, hi), the medium's axis-aligned box in scene units.
    Returns (tau, length), each (rows, width)."""
    sensor = scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().crop_size())
    ys = np.arange(h)[rows if rows is not None else slice(None)]
    px, py = np.meshgrid((np.arange(w) + 0.5) / w, (ys + 0.5) / h)
    n = px.size
    ray, _ = sensor.sample_ray(mi.Float(np.zeros(n)), mi.Float(np.full(n, 0.5)),
                               mi.Point2f(px.ravel(), py.ravel()), mi.Point2f(np.full(n, 0.5), np.full(n, 0.5)))
    o = np.stack([np.asarray(ray.o[i], dtype=np.float64) * np.ones(n) for i in range(3)], axis=1)
    d = np.stack([np.asarray(ray.d[i], dtype=np.float64) * np.ones(n) for i in range(3)], axis=1)
    tau = np.asarray(discrete_medium_of(scene).data.optical_depth(o, d, 0.0, 1e7))
    lo, hi = (np.asarray(v, dtype=np.float64) for v in box)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    near = np.nanmax(np.minimum(t0, t1), axis=1).clip(0.0, None)
    far = np.nanmin(np.maximum(t0, t1), axis=1)
    length = np.clip(far - near, 0.0, None)
    return tau.reshape(px.shape), length.reshape(px.shape)


def medium_graininess(tau_and_length, min_share: float = 0.25) -> float:
    """The medium's graininess at equal mean: std / mean over pixels of the optical depth per unit length
    (tau / L: the box's geometry divided out), over the pixels whose ray crosses at least ``min_share``
    of the longest path through the box (grazing rays hold too few grains to mean anything)."""
    tau, length = (np.asarray(v) for v in tau_and_length)
    keep = length > min_share * length.max()
    k = tau[keep] / length[keep]
    return float(np.std(k) / max(np.mean(k), 1e-300))


def peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _display(img: np.ndarray, log_avg: float, white: float) -> np.ndarray:
    """``motes.cli.reinhard`` with a given exposure, then the sRGB transfer curve (for matplotlib)."""
    from motes.cli import reinhard  # noqa: PLC0415

    srgb = reinhard(np.asarray(img)[..., :3], log_avg, white)
    return np.where(srgb <= 0.0031308, 12.92 * srgb, 1.055 * srgb ** (1 / 2.4) - 0.055)


def exposure_of(img: np.ndarray) -> tuple[float, float]:
    """(log-average luminance, white point) of a reference image (``motes.cli.exposure``)."""
    from motes.cli import exposure  # noqa: PLC0415

    return exposure(np.asarray(img)[..., :3])


def sheet(rows, path: pathlib.Path, title: str, row_titles=None, reference=(0, 0), exposures=None) -> pathlib.Path:
    """A contact sheet: ``rows`` of (label, image) panels, the label under each; one exposure for the
    whole sheet (that of panel ``reference``) unless ``exposures`` gives one per row."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    ncol = max(len(r) for r in rows)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(2.6 * ncol, 2.9 * len(rows) + 0.5), squeeze=False)
    ref = exposure_of(rows[reference[0]][reference[1]][1])
    for i, row in enumerate(rows):
        exp = exposures[i] if exposures is not None else ref
        for j in range(ncol):
            ax = axes[i][j]
            ax.set_xticks([])
            ax.set_yticks([])
            for s in ax.spines.values():
                s.set_visible(False)
            if j >= len(row):
                continue
            label, img = row[j]
            ax.imshow(_display(img, *exp), interpolation="nearest")
            ax.set_xlabel(label, fontsize=8)
        if row_titles:
            axes[i][0].set_ylabel(row_titles[i], fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def save_numbers(out: pathlib.Path, name: str, numbers: dict) -> pathlib.Path:
    """The figure's measured numbers as JSON beside its sheet (what docs/gallery.md quotes)."""
    path = out / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(numbers, indent=1) + "\n")
    return path


def monotone(values, decreasing: bool = False) -> bool:
    v = list(values)
    pairs = list(zip(v, v[1:]))
    return all(b < a for a, b in pairs) if decreasing else all(b > a for a, b in pairs)


def steps_beyond_noise(means, ses, decreasing: bool = False, z: float = 2.0) -> bool:
    """Each consecutive step moves the expected way by more than ``z`` combined standard errors."""
    sign = -1.0 if decreasing else 1.0
    return all(sign * (b - a) > z * float(np.hypot(sa, sb))
               for a, b, sa, sb in zip(means, means[1:], ses, ses[1:]))


def medium_block(xml: str) -> tuple[int, int]:
    """Start and end of the ``<medium type="discrete" ...> ... </medium>`` element in a scene's XML."""
    start = xml.index('<medium type="discrete"')
    end = xml.index("</medium>", start) + len("</medium>")
    return start, end


def load_with_medium(mi, name: str, medium_xml: str, spp: int, res: int, **params):
    """The shipped scene ``name`` with its discrete medium replaced by ``medium_xml`` (e.g. the
    homogeneous equivalent's ``motes.equivalent_xml``)."""
    path = scene_file(name)
    xml = path.read_text()
    a, b = medium_block(xml)
    xml = xml[:a] + medium_xml + xml[b:]
    return mi.load_string(xml, spp=str(spp), res=str(res), **{k: str(v) for k, v in params.items()})


def discrete_medium_of(scene):
    """The scene's (first) discrete medium: the Python plugin object holding ``.data``."""
    for shape in scene.shapes():
        m = shape.interior_medium()
        if m is not None and hasattr(m, "data"):
            return m
    raise LookupError("the scene has no discrete medium")


def ept_xml(mi, name: str, ior: float, spp: int, res: int, **params) -> tuple[str, int]:
    """Explicit path tracing (the paper's EPT) of the same grains: the shipped scene with its discrete
    medium's cube replaced by one Mitsuba ``sphere`` per grain with a ``dielectric`` BSDF of index
    ``ior`` (the grains' real index; EPT's "small transparent balls"). The grains are read from the
    scene loaded with ``storage = full`` (same seed, same positions and radii). Returns (XML, count)."""
    scene = mi.load_file(str(scene_file(name)), spp=str(spp), res=str(res), storage="full",
                         **{k: str(v) for k, v in params.items()})
    data = discrete_medium_of(scene).data
    pos, radii_um, scale_m = np.asarray(data.positions), np.asarray(data.radii_um), float(data.scale_m)
    del scene
    r = radii_um * 1e-6 / scale_m
    spheres = "\n".join(f'<shape type="sphere"><point name="center" x="{p[0]:.6g}" y="{p[1]:.6g}" z="{p[2]:.6g}"/>'
                        f'<float name="radius" value="{ri:.6g}"/><ref id="ept_grain"/></shape>'
                        for p, ri in zip(pos, r))
    xml = scene_file(name).read_text()
    a = xml.rindex('<shape type="cube">', 0, medium_block(xml)[0])
    b = xml.index("</shape>", medium_block(xml)[1]) + len("</shape>")
    grain = f'<bsdf type="dielectric" id="ept_grain"><float name="int_ior" value="{ior}"/></bsdf>\n'
    return xml[:a] + grain + spheres + xml[b:], int(r.size)


def render_ept(mi, name: str, ior: float, spp: int, res: int, seeds=(0, 1), **params):
    """EPT of the shipped scene ``name``'s grains (``ept_xml``) with the scene parameters ``params``,
    rendered once per sampler seed. Returns (images, load seconds, render seconds per image, spheres)."""
    xml, n = ept_xml(mi, name, ior, spp, res, **params)
    t0 = time.perf_counter()
    # Only the parameters the spheres' scene still uses (the medium's, e.g. radius_median, went with it).
    kept = {k: str(v) for k, v in params.items() if re.search(rf"\${re.escape(k)}\b", xml)}
    scene = mi.load_string(xml, spp=str(spp), res=str(res), **kept)
    t_load = time.perf_counter() - t0
    imgs, times = render_seeds(mi, scene, spp, seeds)
    return imgs, t_load, times, n
